/* reduced_jit.c — the generated reduced evaluator of one model
 * (backends/emit/emit_reduced.c) compiled (libtcc, or cc) and run on the coordinates of
 * a Reduced: its operator powers and learned externs call back into that
 * runtime evaluator (NpgReducedRt), which is the reference. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"
#include "jit.h"
#include "npg_abi.h"
#include "reduced.h"

static long qm(const Model *m, int q) { return m->classes[m->qclass[q]].m; }

struct RedJit {
  const Model *m;
  JitModule *jit;
  NpgReducedFn fn;
  NpgReducedStageFn stage_fn;
  long nslots;
  const double **t;         /* NpgReducedCtx.t */
  double **x;               /* NpgReducedCtx.x, from the Reduced of each call */
  double *work;
  Reduced *r;               /* the Reduced of the current call */
  char error[1024];
};

const char *reduced_jit_error(const RedJit *j) { return j ? j->error : "no reduced evaluator"; }

static int host_op_power(const NpgReducedCtx *c, int stage, int term, int op, npg_idx m, double *M, long p, long q,
                         double *v) {
  RedJit *j = c->host;
  (void)m;
  return reduced_apply_power(j->r, &(ReducedPower){stage, term, op, p, q, c->sample}, M, v);
}

static int host_learned(const NpgReducedCtx *c, int stage) {
  RedJit *j = c->host;
  if (stage < 0 || stage >= j->m->nstages || (j->m->stages[stage].st->kind != ST_EXTERN && !j->m->stages[stage].interp))
    return -1;
  return reduced_eval_stage(j->r, stage, c->sample);
}

static const NpgReducedRt host_rt = {host_op_power, host_learned};

void reduced_jit_free(RedJit *j) {
  if (!j) return;
  jit_free(j->jit);
  free(j->t);
  free(j->x);
  free(j->work);
  free(j);
}

/* The generated symbol `what` (emit_symbol: the program's prefix). */
static void *entry(RedJit *j, const char *what) {
  char name[1024];
  if (emit_symbol(j->m->prog, what, name, sizeof name) >= (int)sizeof name) return NULL;
  return jit_symbol(j->jit, name);
}

/* The generated code's stated layout (reduced_coords, _tensors) is the
 * model's: it was generated for this model. */
static bool layout_matches(RedJit *j, const ReducedSlot *slots) {
  const npg_idx *coords = entry(j, "reduced_coords");
  const npg_idx *tensors = entry(j, "reduced_tensors");
  if (!coords || !tensors || coords[0] != j->m->nq || tensors[0] != j->nslots) return false;
  for (int q = 0; q < j->m->nq; q++)
    if (coords[1 + q] != qm(j->m, q)) return false;
  for (long k = 0; k < j->nslots; k++)
    if (tensors[1 + k] != slots[k].rows * slots[k].cols) return false;
  return true;
}

RedJit *reduced_jit_new(const Model *m, bool cc, Err *err) {
  RedJit *j = mem_calloc(1, sizeof *j);
  char *src = NULL;
  size_t len = 0;
  ReducedSlot *slots = NULL;
  if (!j) goto oom;
  j->m = m;
  FILE *mem = open_memstream(&src, &len);
  if (!mem) goto oom;
  int rc = emit_reduced(m, mem, err);
  fclose(mem);
  if (rc != 0) goto fail;
  j->jit = jit_compile(src, cc ? JIT_CC : JIT_TCC, ERR_MSG(err), ERR_LEN(err));
  free(src);
  src = NULL;
  if (!j->jit) goto fail;
  j->fn = (NpgReducedFn)entry(j, "reduced");
  j->stage_fn = (NpgReducedStageFn)entry(j, "reduced_stage");
  const npg_idx *nwork = entry(j, "reduced_work");
  j->nslots = emit_reduced_slots(m, NULL);
  slots = mem_calloc((size_t)j->nslots + 1, sizeof *slots);
  j->t = mem_calloc((size_t)j->nslots + 1, sizeof *j->t);
  j->x = mem_calloc((size_t)m->nq + 1, sizeof *j->x);
  if (!slots || !j->t || !j->x) goto oom;
  emit_reduced_slots(m, slots);
  if (!j->fn || !j->stage_fn || !nwork || !layout_matches(j, slots)) {
    err_set(err, "generated reduced code lacks its entry points or disagrees with the model (a bug in npg)");
    goto fail;
  }
  for (long k = 0; k < j->nslots; k++) {
    if (!slots[k].data) {
      err_set(err, "reduced tensor %s has no data: the model is not trained",
              slots[k].t ? slots[k].t->name : "(projection)");
      goto fail;
    }
    j->t[k] = slots[k].data;
  }
  if (!(j->work = mem_calloc((size_t)*nwork + 1, sizeof(double)))) goto oom;
  free(slots);
  return j;
oom:
  err_set(err, "out of memory for the generated reduced evaluator");
fail:
  free(src);
  free(slots);
  reduced_jit_free(j);
  return NULL;
}

/* Run stage `stage` (all of them when -1) of the generated code on the
 * coordinates of `r`. */
static int run(RedJit *j, Reduced *r, int stage, long sample) {
  j->error[0] = 0;
  if (reduced_model(r) != j->m) {
    snprintf(j->error, sizeof j->error, "the reduced coordinates belong to another model than the generated code's");
    return -1;
  }
  if (stage < -1 || stage >= j->m->nstages) {
    snprintf(j->error, sizeof j->error, "no stage number %d: the model has %d", stage, j->m->nstages);
    return -1;
  }
  for (int q = 0; q < j->m->nq; q++) j->x[q] = reduced_coords(r, q);
  j->r = r;
  NpgReducedCtx c = {j->x, j->t, j->work, &host_rt, sample, j};
  int rc = stage < 0 ? j->fn(&c) : j->stage_fn(&c, stage);
  j->r = NULL;
  if (rc != 0) {
    snprintf(j->error, sizeof j->error, "%s", reduced_error(r)[0] ? reduced_error(r) : "generated reduced code failed");
    return -1;
  }
  return 0;
}

int reduced_jit_eval(RedJit *j, Reduced *r, long sample) { return run(j, r, -1, sample); }

int reduced_jit_eval_stage(RedJit *j, Reduced *r, int stage, long sample) { return run(j, r, stage, sample); }
