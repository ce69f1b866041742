/* memsamples.c — random samples in memory (memsamples.h). */
#include <stdlib.h>
#include <string.h>

#include "memsamples.h"
#include "alloc.h" /* mem_malloc */
#include "randdata.h"
#include "scratch.h"

size_t memsamples_count(const Sym *s, long n, long *shape) {
  size_t c = 1;
  for (int a = 0; a < s->ndims; a++) shape[a] = n, c *= (size_t)n;
  for (int a = 0; a < s->nstatic; a++) shape[s->ndims + a] = s->shape[a], c *= (size_t)s->shape[a];
  return c;
}

int memsamples_fill(MemSamples *ms, const Program *prog, Full *f, long n, long S, unsigned seed) {
  memset(ms, 0, sizeof *ms);
  ms->S = S;
  for (int i = 0; i < prog->params.n && f; i++) {
    const Sym *s = prog->params.v[i];
    long shape[MAX_AXES + MAX_STATIC];
    size_t c = memsamples_count(s, n, shape);
    Scratch sc = SCRATCH_OF(NULL);
    double *v = scratch_array(&sc, c ? c : 1, sizeof(double));
    if (v) randdata_fill(&(RandData){.prog = prog, .n = n, .seed = &seed}, s, v, c);
    int rc = !v ? -2 : full_set_param(f, s->name, s->ndims + s->nstatic, shape, v, s->name) ? -1 : 0;
    scratch_release(&sc);
    if (rc) return rc;
  }
  for (int i = 0; i < prog->quantities.n; i++) {
    const Sym *s = prog->quantities.v[i];
    if (s->kind != SYM_INPUT && s->kind != SYM_EXTERN) continue;
    if (ms->n == MEM_MAX_QUANTITIES) {
      memsamples_free(ms);
      return -2;
    }
    int k = ms->n++;
    ms->sym[k] = s;
    ms->nd[k] = s->ndims + s->nstatic;
    ms->count[k] = memsamples_count(s, n, ms->shape[k]);
    ms->val[k] = mem_malloc(sizeof(double) * (ms->count[k] ? ms->count[k] : 1) * (size_t)(S > 0 ? S : 1));
    if (!ms->val[k]) {
      memsamples_free(ms);
      return -2;
    }
    for (long j = 0; j < S; j++)
      randdata_fill(&(RandData){.prog = prog, .n = n, .seed = &seed}, s, ms->val[k] + (size_t)j * ms->count[k], ms->count[k]);
  }
  return 0;
}

int memsamples_set(void *user, Full *f, long k) {
  MemSamples *ms = user;
  for (int i = 0; i < ms->n; i++)
    if (full_set(f, ms->sym[i]->name, ms->nd[i], ms->shape[i], ms->val[i] + (size_t)k * ms->count[i],
                 ms->sym[i]->name))
      return -1;
  return 0;
}

void memsamples_free(MemSamples *ms) {
  for (int i = 0; i < ms->n; i++) free(ms->val[i]), ms->val[i] = NULL;
  ms->n = 0;
}
