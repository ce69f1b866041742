/* randdata.c — random but well-posed data for a program (randdata.h). */
#include "randdata.h"

#include <math.h>

double randdata_uniform(unsigned *seed, double lo, double hi) {
  *seed = *seed * 1103515245u + 12345u;
  return lo + (hi - lo) * ((*seed >> 8) & 0xffffff) / (double)0x1000000;
}

static bool node_reads(const Node *n, const Sym *s) {
  if (!n) return false;
  if ((n->kind == N_NAME || n->kind == N_INDEX) && n->sym == s) return true;
  if (node_reads(n->a, s) || node_reads(n->b, s) || node_reads(n->c, s)) return true;
  for (int i = 0; i < n->nargs; i++)
    if (node_reads(n->args[i], s)) return true;
  return false;
}

static bool field_guards_read(const Field *f, const Sym *s) {
  for (int c = 0; c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++)
      if (node_reads(f->comp[c].m[i]->guard, s)) return true;
  return false;
}

/* Does some guard of the canonical form test this param (nbr[i,k] >= 0)? */
static bool guards_read(const Program *prog, const Sym *s) {
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    for (int t = 0; t < st->nterms; t++) {
      if (field_guards_read(st->terms[t]->num, s)) return true;
      for (int k = 0; k < st->terms[t]->nops; k++)
        if (st->terms[t]->ops[k].kind == OPK_DIAG && field_guards_read(st->terms[t]->ops[k].diag, s)) return true;
    }
  }
  for (int i = 0; i < prog->opdefs.n; i++)
    if (field_guards_read(((OpDef *)prog->opdefs.v[i])->entries, s)) return true;
  return false;
}

bool randdata_fill(const RandData *rd, const Sym *s, double *v, size_t k) {
  const Program *prog = rd->prog;
  long n = rd->n;
  unsigned *seed = rd->seed;
  bool did_pad = false;
  if (s->kind == SYM_INPUT || s->kind == SYM_EXTERN) {
    for (size_t j = 0; j < k; j++) v[j] = randdata_uniform(seed, 0.5, 1.5);
    return false;
  }
  if (!s->is_int) {
    for (size_t j = 0; j < k; j++) v[j] = randdata_uniform(seed, 0.1, 0.3);
    return false;
  }
  size_t row = s->nstatic ? (size_t)s->shape[s->nstatic - 1] : 1;
  /* rows of distinct entries, and no two rows the same set */
  for (size_t r0 = 0; r0 < k; r0 += row) {
    for (int tries = 0; tries < 200; tries++) {
      for (size_t j = r0; j < r0 + row; j++) {
        for (int t2 = 0; t2 < 100; t2++) {
          v[j] = floor(randdata_uniform(seed, 0, (double)n));
          bool repeated = false;
          for (size_t r = r0; r < j; r++) repeated |= v[r] == v[j];
          if (!repeated || row > (size_t)n) break;
        }
      }
      bool same_set = false;
      for (size_t q0 = 0; q0 < r0 && !same_set && row > 1; q0 += row) {
        size_t hits = 0;
        for (size_t a = 0; a < row; a++)
          for (size_t b = 0; b < row; b++) hits += v[q0 + a] == v[r0 + b];
        same_set = hits == row;
      }
      if (!same_set) break;
    }
  }
  /* -1 padding (a missing neighbour) in params the program tests in a guard */
  if (rd->padded && guards_read(prog, s)) {
    did_pad = true;
    for (size_t j = 0; j < k; j++)
      if (randdata_uniform(seed, 0, 1) < 0.25) v[j] = -1;
  }
  return did_pad;
}
