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
#include "scratch.h"

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

static int jit_oom(Err *err) { return err_set(err, "out of memory for the generated reduced evaluator"); }

/* j's code generated and compiled, its entry points, tensors and work; the source and the
 * slots from `sc`. -1 with `err`. */
static int jit_build(RedJit *j, const Model *m, bool cc, Scratch *sc, Err *err) {
  char *src = NULL;
  size_t len = 0;
  FILE *mem = open_memstream(&src, &len);
  if (!mem) return jit_oom(err);
  int rc = emit_reduced(m, mem, err);
  fclose(mem);
  src = scratch_adopt(sc, src);
  if (rc != 0) return -1;
  if (!src) return jit_oom(err);
  j->jit = jit_compile(src, cc ? JIT_CC : JIT_TCC, ERR_MSG(err), ERR_LEN(err));
  if (!j->jit) return -1;
  j->fn = (NpgReducedFn)entry(j, "reduced");
  j->stage_fn = (NpgReducedStageFn)entry(j, "reduced_stage");
  const npg_idx *nwork = entry(j, "reduced_work");
  j->nslots = emit_reduced_slots(m, NULL);
  ReducedSlot *slots = scratch_array(sc, (size_t)j->nslots + 1, sizeof *slots);
  j->t = mem_calloc((size_t)j->nslots + 1, sizeof *j->t);
  j->x = mem_calloc((size_t)m->nq + 1, sizeof *j->x);
  if (!slots || !j->t || !j->x) return jit_oom(err);
  emit_reduced_slots(m, slots);
  if (!j->fn || !j->stage_fn || !nwork || !layout_matches(j, slots))
    return err_set(err, "generated reduced code lacks its entry points or disagrees with the model (a bug in npg)");
  for (long k = 0; k < j->nslots; k++) {
    if (!slots[k].data)
      return err_set(err, "reduced tensor %s has no data: the model is not trained",
                     slots[k].t ? slots[k].t->name : "(projection)");
    j->t[k] = slots[k].data;
  }
  if (!(j->work = mem_calloc((size_t)*nwork + 1, sizeof(double)))) return jit_oom(err);
  return 0;
}

RedJit *reduced_jit_new(const Model *m, bool cc, Err *err) {
  RedJit *j = mem_calloc(1, sizeof *j);
  if (!j) return jit_oom(err), NULL;
  j->m = m;
  Scratch sc = SCRATCH_OF(NULL);
  int rc = jit_build(j, m, cc, &sc, err);
  scratch_release(&sc);
  if (rc == 0) return j;
  reduced_jit_free(j); /* the half-built evaluator, once */
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
