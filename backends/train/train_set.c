/* train_set.c — the tune sample set (TrainSet, train.h; npgc tune): the
 * snapshots kept in memory and every member's PCA made once at its cap,
 * then a model for any caps from truncations of those ordered bases, no
 * new snapshot or SVD. The search over caps (tune.c) builds a model per
 * trial; since a class basis is its members' vectors interleaved in order
 * (pca_merge), the model at caps c is the leading block of a model at
 * larger caps (model_truncate, issue 41): the set keeps one model
 * pre-multiplied at caps at least as large as any asked (doubled when a
 * trial asks more, so a sweep 1, 2, 3, … pre-multiplies about twice the
 * largest), and every trial costs a merge and a truncation. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scratch.h"
#include "train.h"
#include "train_steps.h"

struct TrainSet {
  Model *base;              /* layout, member options, SPD marks */
  Full *f;
  const SampleSource *src;
  bool progress;
  TrainOptions o;           /* the options of the snapshots (in memory, concatenated): o.user = &user */
  TrainOptions quiet;       /* those of the trials' models: no progress, on this process (quiet_user) */
  NpgTrainOptions user, quiet_user; /* the caller's, changed so */
  Train tr;                 /* the snapshots' training: tr.sn in memory */
  PcaMember **pm;           /* [class][member]: its ordered basis at its cap */
  Model *top;               /* pre-multiplied at caps top_cap, which cover every trial's so far */
  int *top_cap;
};

/* Steps 3b–5 for a truncation (npgc tune; issue 30): as train_model does,
 * the online estimate's tables (on the training samples, at the model's
 * sizes), the streamable classes --keep-bases does not name marked, their
 * training floors taken from the snapshots, their bases dropped. */
int train_set_stream(TrainSet *ts, Model *m, const TrainOptions *opt, Err *err) {
  if (train_estimates(m, ts->f, ts->src, &ts->quiet, err)) return -1;
  if (!train_mark_streamed(m, opt)) return 0;
  long maxn = 1, maxm = 1;
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].streamed)
      maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn, maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  Scratch s = SCRATCH_OF(err);
  double *y = scratch_array(&s, (size_t)maxn, sizeof(double)), *proj = scratch_array(&s, (size_t)maxm, sizeof(double));
  int rc = y && proj ? 0 : err_set(err, "out of memory measuring the training floors");
  Train trial = ts->tr; /* the set's snapshots, this truncation */
  trial.m = m, trial.scratch = SCRATCH_OF(err), trial.err = err;
  for (long k = 0; rc == 0 && k < ts->tr.sn.S; k++) train_take_floors(&trial, k, proj, y);
  if (rc == 0) train_drop_bases(m);
  scratch_release(&s);
  return rc;
}

void train_set_free(TrainSet *ts) {
  if (!ts) return;
  for (int c = 0; ts->pm && c < ts->base->nclasses; c++) {
    for (int i = 0; ts->pm[c] && i < ts->base->classes[c].nmembers; i++) pca_member_free(&ts->pm[c][i]);
    free(ts->pm[c]);
  }
  free(ts->pm);
  model_free(ts->top);
  free(ts->top_cap);
  if (ts->base) train_free_snapshots(ts->base, &ts->tr.sn);
  model_free(ts->base);
  free(ts);
}

/* Every member's PCA at its cap (ts->pm) from the set's snapshots. 0, or -1 with `err`. */
static int member_pcas(TrainSet *ts, Err *err) {
  Model *m = ts->base;
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].product) /* its truncations would need the weighted snapshots (product.c) */
      return err_set(err,
                     "basis %s: product %s is not implemented in tune (the sizes' sweep): train each size with "
                     "npgc train",
                     m->classes[c].bc->size_name, m->classes[c].product->name);
  if (!(ts->pm = mem_calloc((size_t)m->nclasses + 1, sizeof(PcaMember *))))
    return err_set(err, "out of memory while training");
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(ts->pm[c] = mem_calloc((size_t)rc->nmembers + 1, sizeof(PcaMember))))
      return err_set(err, "out of memory while training");
    for (int i = 0; i < rc->nmembers; i++) {
      RMember *mb = &rc->members[i];
      PcaRule rule = {.cap = mb->cap, .energy = mb->energy, .center = mb->center};
      if (pca_basis(rc->n, ts->tr.sn.S, ts->tr.sn.X[c][i], &rule, &ts->pm[c][i], err)) return -1;
    }
    progress_show(ts->progress, "member bases", c + 1, m->nclasses);
  }
  return 0;
}

TrainSet *train_set_new(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err) {
  TrainSet *ts = mem_calloc(1, sizeof *ts);
  if (err_held(err)) err->msg[0] = 0;
  if (!ts) return err_set(err, "out of memory while training"), NULL;
  ts->user = *opt->user;
  ts->user.mem = 0; /* truncations re-use the snapshots: they stay in memory */
  ts->user.joint = false;
  ts->quiet_user = ts->user;
  ts->quiet_user.progress = false;
  ts->o = *opt;
  ts->o.user = &ts->user;
  ts->quiet = ts->o;
  ts->quiet.user = &ts->quiet_user;
  ts->quiet.dist = false;
  ts->f = f, ts->src = src, ts->progress = opt->user->progress;
  ts->tr = (Train){.prog = prog, .f = f, .src = src, .opt = &ts->o, .err = err};
  int rc = train_begin(&ts->tr);
  ts->base = ts->tr.m;
  if (rc == 0) rc = train_take_snapshots(&ts->tr);
  train_scratch_free(&ts->tr);
  ts->tr.err = NULL; /* the caller's record may end with its block (ERR_OF): later calls pass theirs */
  if (rc == 0) rc = member_pcas(ts, err);
  if (rc == 0) return ts;
  err_set_first(err, "out of memory while training");
  train_set_free(ts); /* the half-built set: its own free */
  return NULL;
}

int train_set_classes(const TrainSet *ts) { return ts->base->nclasses; }

Program *train_set_program(const TrainSet *ts) { return ts->tr.prog; }

Full *train_set_full(const TrainSet *ts) { return ts->f; }

int train_set_max_cap(const TrainSet *ts, int c) {
  int k = 1;
  for (int i = 0; i < ts->base->classes[c].nmembers; i++) k = ts->pm[c][i].k > k ? ts->pm[c][i].k : k;
  return k;
}

/* Member `mb` keeping the first `k` of its ordered basis `p`: its report. */
static int truncated_member(RMember *mb, const PcaMember *p, int cap, int k) {
  double total = 0, run = 0;
  int r = mb->center ? k - 1 : k; /* a centered basis starts with the mean */
  for (long j = 0; j < p->nsv; j++) total += p->sv[j] * p->sv[j], run += j < r ? p->sv[j] * p->sv[j] : 0;
  mb->cap = cap;
  mb->kept = k;
  mb->lost = total > 0 ? fmax(0, 1 - run / total) : 0;
  mb->captured = 1 - mb->lost;
  mb->nsv = p->nsv;
  if (!(mb->sv = mem_malloc(sizeof(double) * (size_t)(p->nsv + 1)))) return -1;
  memcpy(mb->sv, p->sv, sizeof(double) * (size_t)p->nsv);
  return 0;
}

/* Class c of `m` (a layout of the set's) with its members' ordered bases cut at `cap`, merged:
 * its basis and every member's report. 0, or -1 (with `err` unless out of memory). */
static int class_basis(const TrainSet *ts, Model *m, int c, int cap, Err *err) {
  const RClass *bc = &ts->base->classes[c];
  RClass *rc = &m->classes[c];
  Scratch s = SCRATCH_OF(err);
  double **U = scratch_array(&s, (size_t)rc->nmembers + 1, sizeof(double *));
  int *kk = scratch_array(&s, (size_t)rc->nmembers + 1, sizeof(int)), ok = U && kk;
  for (int i = 0; ok && i < rc->nmembers; i++) {
    const PcaMember *p = &ts->pm[c][i];
    RMember *mb = &rc->members[i];
    mb->energy = bc->members[i].energy;
    mb->center = bc->members[i].center;
    kk[i] = cap < p->k ? cap : p->k;
    if (!(U[i] = scratch_array(&s, (size_t)(rc->n * (kk[i] ? kk[i] : 1)), sizeof(double))) ||
        truncated_member(mb, p, cap, kk[i]))
      ok = 0;
    for (long e = 0; ok && e < rc->n; e++) memcpy(U[i] + e * kk[i], p->U + e * p->k, sizeof(double) * (size_t)kk[i]);
  }
  int rc_ok = ok ? pca_merge(rc->n, (PcaBlocks){rc->nmembers, U, kk}, &rc->B, &rc->m, err) : -1;
  scratch_release(&s);
  return rc_ok || train_complete_basis(rc, false, err) ? -1 : 0;
}

/* The model whose members keep the first cap[c] of their ordered bases,
 * merged, with no tensor (its layout sized). */
static Model *set_bases(TrainSet *ts, const int *cap, Err *err) {
  const Model *b = ts->base;
  if (err_held(err)) err->msg[0] = 0;
  Model *m = model_layout(b->prog, b->dims, err);
  if (!m) return NULL;
  m->samples = b->samples;
  for (int i = 0; i < m->nstages; i++) /* the SPD marks the snapshots set */
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) m->stages[i].terms[t].ops[k].spd = b->stages[i].terms[t].ops[k].spd;
  for (int c = 0; c < m->nclasses; c++)
    if (class_basis(ts, m, c, cap[c], err)) {
      err_set_first(err, "out of memory building the basis of class %s", m->classes[c].label);
      model_free(m); /* the half-built model: its own free */
      return NULL;
    }
  model_size_tensors(m);
  return m;
}

/* ts->top at caps covering `cap`: kept when it does, else made at
 * max(cap, twice its caps), at most what the members have. 0, or -1 with `err`. */
static int cover(TrainSet *ts, const int *cap, Err *err) {
  int nc = ts->base->nclasses, grow = !ts->top;
  if (!ts->top_cap && !(ts->top_cap = mem_calloc((size_t)nc + 1, sizeof(int)))) return err_set(err, "out of memory");
  for (int c = 0; c < nc; c++) grow |= cap[c] > ts->top_cap[c] && ts->top_cap[c] < train_set_max_cap(ts, c);
  if (!grow) return 0;
  Scratch s = SCRATCH_OF(err);
  int *want = scratch_array(&s, (size_t)nc + 1, sizeof(int));
  for (int c = 0; want && c < nc; c++) {
    want[c] = cap[c] > 2 * ts->top_cap[c] ? cap[c] : 2 * ts->top_cap[c];
    if (want[c] > train_set_max_cap(ts, c)) want[c] = train_set_max_cap(ts, c);
    if (want[c] < 1) want[c] = 1;
  }
  Model *m = want ? set_bases(ts, want, err) : NULL;
  Train trial = ts->tr; /* the set's snapshots, this model */
  trial.opt = &ts->quiet, trial.m = m, trial.gram = false, trial.err = err, trial.scratch = SCRATCH_OF(err);
  if (m && (train_premultiply_all(&trial) || train_fit_externs(&trial, true, false))) model_free(m), m = NULL;
  train_scratch_free(&trial);
  if (m) {
    model_free(ts->top);
    ts->top = m;
    memcpy(ts->top_cap, want, sizeof(int) * (size_t)nc);
  }
  scratch_release(&s);
  return m ? 0 : -1;
}

Model *train_set_model(TrainSet *ts, const int *cap, Err *err) {
  Scratch s = SCRATCH_OF(err);
  Model *m = set_bases(ts, cap, err), *cut = NULL;
  long *sizes = m ? scratch_array(&s, (size_t)m->nclasses + 1, sizeof(long)) : NULL;
  if (m && !sizes) err_set(err, "out of memory");
  if (sizes && cover(ts, cap, err) == 0) {
    for (int c = 0; c < m->nclasses; c++) sizes[c] = m->classes[c].m;
    cut = model_truncate(ts->top, sizes, err);
  }
  for (int c = 0; cut && c < m->nclasses; c++) /* the members' reports at these caps */
    for (int i = 0; i < m->classes[c].nmembers; i++) {
      RMember *a = &cut->classes[c].members[i], *b = &m->classes[c].members[i];
      a->cap = b->cap, a->kept = b->kept, a->lost = b->lost, a->captured = b->captured;
    }
  scratch_release(&s);
  model_free(m);
  return cut;
}
