/* tune.c — basis sizes chosen by the error they give (issue 11, npgc tune):
 * the fewest reduced multiply-adds (ir/cost.c's formula) at which every
 * output's mean relative L2 error on validation samples is under a
 * tolerance. Every trial truncates the members' bases of one TrainSet (one
 * snapshot pass and one SVD per member) and re-pre-multiplies; nothing is
 * retrained.
 *
 * The search: one cap for every class, 1, 2, … until the tolerance is met
 * (class sizes, hence the cost, grow with the cap, so the first uniform cap
 * that meets it is the cheapest uniform one); then, from there, each class
 * in turn — the one whose growth costs most first — bisected down to the
 * smallest cap that still meets it with the others fixed. Every accepted
 * step meets the tolerance and costs no more, so the result costs no more
 * than any uniform cap that meets the tolerance.
 *
 * The reduction of each stage eligible for interpolation (DESIGN §12) is
 * part of every trial, not chosen once the caps are fixed: at each
 * candidate's caps the stage is reduced by Galerkin and interpolated and
 * the lower output error kept, or the cheaper when both meet the tolerance
 * (choose), so a trial's error and cost are those of its best
 * configuration, and caps at which only interpolation meets the tolerance
 * can win (an interpolated stage's cost is its own, stage_work). Affordable:
 * with E eligible stages (none forced either way) a trial takes 1 + E
 * passes of reduced evaluations over the V validation samples and E
 * selections of rows (a pivoted QR of the stage's n x m basis), for
 * T = u + Σ_c ⌈log2 cap_c⌉ trials (u the uniform cap reached): T (1 + E)
 * validation passes in all, against T + 1 + E when the choice followed the
 * search; the snapshots and SVDs, which dominate, are made once either way.
 * The choice is greedy in evaluation order, not over all 2^E combinations. */
#include <math.h>
#include <setjmp.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"
#include "interp.h"
#include "reduced.h"
#include "scratch.h"
#include "train.h"

typedef struct Valid {
  long S;
  int nq;
  double **val;             /* [sample][q]: the full value of every quantity */
  long steps, every, saves; /* rollouts (NpgTrainOptions.rollout_steps): their length, the states compared every */
  double **traj;            /* [sample]: saves x (every state's entries): the full trajectory */
  long state_n;             /* the entries of every state */
} Valid;

typedef struct Search {
  TrainSet *ts;
  Program *prog;
  Full *f;
  Valid v;
  int nc;
  int max_cap;              /* the largest cap a class may have */
  int *maxk;                /* per class: the most vectors its members have, at most max_cap */
  TuneResult *out;
  TrainOptions copt;        /* the reductions forced and the choice's settings; no output, no valid */
  double tol;               /* the tolerance to meet */
  Model *last;              /* the model of the trial made last, until kept (keep_model) or dropped */
  int model_trial;          /* the trial whose model out->model is, or -1 */
  char why[1024];           /* why the last candidate that failed on a validation sample failed */
  Scratch mem;              /* the search's memory: the validation samples cached, the caps */
  NpgTrainOptions cuser;    /* tune_search's copt.user: the caller's options, quiet */
} Search;

static long qsize(const Model *m, int q) { return m->classes[m->qclass[q]].n; }

/* Full values of every quantity on every validation sample. */
static int cache_valid(Search *s, Full *f, const SampleSource *valid, const Model *layout, Err *err) {
  s->v.S = valid->count;
  s->v.nq = layout->nq;
  if (!(s->v.val = scratch_array(&s->mem, (size_t)valid->count + 1, sizeof(double *))))
    return err_set(err, "out of memory for the validation samples");
  long per = 0;
  for (int q = 0; q < layout->nq; q++) per += qsize(layout, q);
  for (long k = 0; k < valid->count; k++) {
    if (!(s->v.val[k] = scratch_array(&s->mem, (size_t)per, sizeof(double)))) return err_set(err, "out of memory");
    if (valid->set(valid->user, f, k) != 0) return err_set(err, "validation sample %ld: %s", k, full_error(f));
    /* greedy training's snapshots (not the last: the evaluator ends on its values, as without them) */
    if (k < valid->count - 1 && snapshot_cache_values(s->copt.cache, f, layout, s->v.val[k])) continue;
    if (full_eval(f, k) != 0) return err_set(err, "validation sample %ld: %s", k, full_error(f));
    long off = 0;
    for (int q = 0; q < layout->nq; q++) {
      memcpy(s->v.val[k] + off, full_get(f, ((Sym *)s->prog->quantities.v[q])->name, NULL),
             sizeof(double) * (size_t)qsize(layout, q));
      off += qsize(layout, q);
    }
  }
  return 0;
}

static long qoff(const Model *m, int q);

/* Rollouts: each validation sample's full trajectory, its states every v.every steps. */
static int cache_rollouts(Search *s, Full *f, const SampleSource *valid, const Model *layout, Err *err) {
  const Program *prog = s->prog;
  s->v.state_n = 0;
  for (int i = 0; i < prog->states.n; i++)
    s->v.state_n += qsize(layout, vec_position(&prog->quantities, prog->states.v[i]));
  s->v.saves = s->v.steps / s->v.every + 1;
  if (!(s->v.traj = scratch_array(&s->mem, (size_t)valid->count + 1, sizeof(double *))))
    return err_set(err, "out of memory");
  for (long k = 0; k < valid->count; k++) {
    if (!(s->v.traj[k] = scratch_array(&s->mem, (size_t)(s->v.saves * s->v.state_n + 1), sizeof(double))))
      return err_set(err, "out of memory");
    if (valid->set(valid->user, f, k) != 0) return err_set(err, "validation sample %ld: %s", k, full_error(f));
    for (long t = 0; t <= s->v.steps; t++) {
      if (t % s->v.every == 0) {
        double *at = s->v.traj[k] + (t / s->v.every) * s->v.state_n;
        for (int i = 0; i < prog->states.n; i++) {
          size_t n = 0;
          const double *u = full_get(f, ((const Sym *)prog->states.v[i])->name, &n);
          memcpy(at, u, sizeof(double) * n);
          at += n;
        }
      }
      if (t < s->v.steps && (full_eval(f, k) != 0 || full_advance(f) != 0))
        return err_set(err, "validation sample %ld, step %ld of its full rollout: %s", k, t + 1, full_error(f));
    }
  }
  return 0;
}

/* The worst state's trajectory error of `m`'s reduced rollouts, mean over the validation samples
 * (infinite where a rollout fails or blows up: that candidate meets nothing). */
static int validate_rollouts(Search *s, Model *m, double *worst, Err *err) {
  const Program *prog = s->prog;
  int ns = prog->states.n;
  Reduced *r = reduced_new(m, err);
  if (!r) return -1;
  long maxn = 1;
  for (int c = 0; c < m->nclasses; c++) maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
  Scratch sc = SCRATCH_OF(err);
  double *y = scratch_array(&sc, (size_t)maxn, sizeof(double)), *e = scratch_array(&sc, (size_t)ns + 1, sizeof(double));
  double *e2 = scratch_array(&sc, (size_t)ns + 1, sizeof(double)), *n2 = scratch_array(&sc, (size_t)ns + 1, sizeof(double));
  int rc = y && e && e2 && n2 ? 0 : err_set(err, "out of memory");
  for (long k = 0; rc == 0 && k < s->v.S; k++) {
    for (int q = 0; q < m->nq; q++)
      if (((Sym *)prog->quantities.v[q])->kind == SYM_INPUT) reduced_project(r, q, s->v.val[k] + qoff(m, q));
    memset(e2, 0, sizeof(double) * (size_t)ns);
    memset(n2, 0, sizeof(double) * (size_t)ns);
    bool blown = false;
    for (long t = 0; t <= s->v.steps && !blown; t++) {
      if (t % s->v.every == 0) {
        const double *full = s->v.traj[k] + (t / s->v.every) * s->v.state_n;
        for (int i = 0; i < ns; i++) {
          int q = vec_position(&prog->quantities, prog->states.v[i]);
          reduced_lift(r, q, y);
          for (long j = 0; j < qsize(m, q); j++) e2[i] += (full[j] - y[j]) * (full[j] - y[j]), n2[i] += full[j] * full[j];
          full += qsize(m, q);
        }
      }
      if (t == s->v.steps) break;
      if (reduced_eval(r, k) != 0) {
        blown = true;
        break;
      }
      for (int i = 0; i < ns; i++) {
        const Sym *u = prog->states.v[i];
        int q = vec_position(&prog->quantities, u), qn = vec_position(&prog->quantities, u->next);
        const double *next = reduced_coords(r, qn);
        long mq = m->classes[m->qclass[q]].m;
        for (long j = 0; j < mq; j++) blown |= !isfinite(next[j]);
        memcpy(reduced_coords(r, q), next, sizeof(double) * (size_t)mq);
      }
    }
    for (int i = 0; i < ns; i++)
      e[i] += blown ? INFINITY : (n2[i] > 0 ? sqrt(e2[i] / n2[i]) : sqrt(e2[i])) / (double)s->v.S;
    if (blown) { /* a fresh evaluator for the next sample: this one keeps its error */
      reduced_free(r);
      if (!(r = reduced_new(m, err))) rc = -1;
    }
  }
  *worst = 0;
  for (int i = 0; rc == 0 && i < ns; i++) *worst = fmax(*worst, e[i]);
  scratch_release(&sc);
  reduced_free(r);
  return rc;
}

/* The offset of quantity q in a cached sample. */
static long qoff(const Model *m, int q) {
  long off = 0;
  for (int i = 0; i < q; i++) off += qsize(m, i);
  return off;
}

/* Mean over validation samples of every output's relative L2 error (the
 * worst into *worst), and when `floor` is given every quantity's mean
 * projection floor ‖y − BBᵀy‖/‖y‖. */
static int validate(Search *s, Model *m, double *worst, double *floor, Err *err) {
  Reduced *r = reduced_new(m, err);
  if (!r) return -1;
  long maxn = 1;
  for (int c = 0; c < m->nclasses; c++) maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
  Scratch sc = SCRATCH_OF(err);
  double *y = scratch_array(&sc, (size_t)maxn, sizeof(double));
  double *e = scratch_array(&sc, (size_t)s->prog->outputs.n + 1, sizeof(double));
  int rc = y && e ? 0 : err_set(err, "out of memory");
  if (floor) memset(floor, 0, sizeof(double) * (size_t)m->nq);
  for (long k = 0; rc == 0 && k < s->v.S; k++) {
    for (int q = 0; q < m->nq; q++)
      if (((Sym *)s->prog->quantities.v[q])->kind == SYM_INPUT) reduced_project(r, q, s->v.val[k] + qoff(m, q));
    if (reduced_eval(r, k) != 0) {
      rc = err_set(err, "%s", reduced_error(r));
      break;
    }
    for (int o = 0; o < s->prog->outputs.n; o++) {
      int q = vec_position(&s->prog->quantities, s->prog->outputs.v[o]);
      if (q < 0) continue;
      const double *full = s->v.val[k] + qoff(m, q), *scale = full;
      const Sym *os = s->prog->outputs.v[o];
      if (os->state_of && os->state_of->residual == os) /* an implicit step's residual, 0 at the solution: */
        scale = s->v.val[k] + qoff(m, vec_position(&s->prog->quantities, os->state_of->next)); /* the unknown's */
      double num = 0, den = 0;
      reduced_lift(r, q, y);
      for (long i = 0; i < qsize(m, q); i++) num += (full[i] - y[i]) * (full[i] - y[i]), den += scale[i] * scale[i];
      e[o] += (den > 0 ? sqrt(num / den) : sqrt(num)) / (double)s->v.S;
    }
    for (int q = 0; floor && q < m->nq; q++) {
      const RClass *rc2 = &m->classes[m->qclass[q]];
      const double *full = s->v.val[k] + qoff(m, q);
      double *c = reduced_coords(r, q); /* scratch: Bᵀy, then y − BBᵀy */
      double num = 0, den = 0;
      for (long j = 0; j < rc2->m; j++) {
        c[j] = 0;
        for (long i = 0; i < rc2->n; i++) c[j] += rc2->B[i * rc2->m + j] * full[i];
      }
      for (long i = 0; i < rc2->n; i++) {
        double d = full[i];
        for (long j = 0; j < rc2->m; j++) d -= rc2->B[i * rc2->m + j] * c[j];
        num += d * d, den += full[i] * full[i];
      }
      floor[q] += (den > 0 ? sqrt(num / den) : sqrt(num)) / (double)s->v.S;
    }
  }
  *worst = 0;
  for (int o = 0; rc == 0 && o < s->prog->outputs.n; o++) *worst = fmax(*worst, e[o]);
  scratch_release(&sc);
  reduced_free(r);
  if (rc == 0 && s->v.steps > 0) return validate_rollouts(s, m, worst, err);
  return rc;
}

static int choose(Search *s, Model *m, double *out, char why[static 1024], Err *err);
static double stage_work(const Model *m, const RStage *rs);

/* cost_value at sizes `m` into *cost: its polynomial is built in the program's arena, whose out of memory
 * longjmps to ctx->on_error (the compile's jump buffer, long gone by tuning): armed here, so that a failure
 * returns -1 ("out of memory" for the caller to say) and leaves the program's state as it was. */
static int cost_at(Program *prog, const long *m, long samples, double *cost) {
  Ctx *ctx = prog->ctx;
  jmp_buf here, *outer = ctx->on_error;
  char *msg = ctx->msg;
  bool failed = ctx->failed;
  int rc = 0;
  ctx->on_error = &here;
  if (setjmp(here) == 0) *cost = cost_value(prog, m, samples);
  else rc = -1, ctx->msg = msg, ctx->failed = failed;
  ctx->on_error = outer;
  return rc;
}

/* The model at caps `cap` with every stage reduced as forced and the
 * others chosen (choose): its sizes, cost, error and interpolated stages
 * into `tr`. NULL with `err`. */
static Model *configure(Search *s, const int *cap, TuneTrial *tr, Err *err) {
  Model *m = train_set_model(s->ts, cap, err);
  if (!m) return NULL;
  for (int c = 0; c < s->nc; c++) tr->m[c] = m->classes[c].m;
  if (cost_at(s->prog, tr->m, m->samples, &tr->cost)) {
    model_free(m);
    return err_set(err, "out of memory pricing the trial"), NULL;
  }
  char why[1024];
  if (train_interpolate_stages(m, s->f, &s->copt, err) || choose(s, m, &tr->err, why, err)) {
    model_free(m);
    return NULL;
  }
  /* a candidate that fails on a validation sample (small caps can make a reduced root's operator
   * indefinite, an interpolated power's base negative) meets nothing; the search goes on */
  if (isinf(tr->err) && why[0]) snprintf(s->why, sizeof s->why, "%s", why);
  size_t len = 1;
  for (int i = 0; i < m->nstages; i++) len += m->stages[i].interp ? strlen(m->stages[i].st->sym->name) + 1 : 0;
  char *names = mem_malloc(len); /* the trial's (tune_result_free) */
  if (!names) {
    model_free(m); /* the half-made model: its own free */
    return err_set(err, "out of memory"), NULL;
  }
  free(tr->interp); /* a trial configured again (its model made anew): these names replace its last */
  tr->interp = names;
  tr->interp[0] = 0;
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    if (!rs->interp) continue;
    /* the cost: the stage's interpolated work in place of its Galerkin work */
    struct RInterp *ip = rs->interp;
    double wi = stage_work(m, rs);
    rs->interp = NULL;
    tr->cost += wi - stage_work(m, rs);
    rs->interp = ip;
    if (tr->interp[0]) strcat(tr->interp, ",");
    strcat(tr->interp, rs->st->sym->name);
  }
  return m;
}

/* Evaluate caps `cap`: a new trial (reusing an identical one), its model
 * left in s->last. Its index, or -1. */
static int trial(Search *s, const int *cap, bool uniform, Err *err) {
  TuneResult *out = s->out;
  for (int t = 0; t < out->ntrials; t++)
    if (memcmp(out->trials[t].cap, cap, sizeof(int) * (size_t)s->nc) == 0) return t;
  TuneTrial *grown = mem_realloc(out->trials, sizeof *grown * (size_t)(out->ntrials + 1));
  if (!grown) return err_set(err, "out of memory");
  out->trials = grown;
  TuneTrial *tr = &out->trials[out->ntrials++]; /* the result's from here on, made or not (tune_result_free) */
  memset(tr, 0, sizeof *tr);
  tr->cap = mem_malloc(sizeof(int) * (size_t)s->nc);
  tr->m = mem_malloc(sizeof(long) * (size_t)s->nc);
  if (!tr->cap || !tr->m) return err_set(err, "out of memory");
  memcpy(tr->cap, cap, sizeof(int) * (size_t)s->nc);
  tr->uniform = uniform;
  return (s->last = configure(s, cap, tr, err)) ? out->ntrials - 1 : -1;
}

/* Trial t's model (s->last, when it was just made) becomes the one the
 * search returns; `accept` false: dropped. */
static void keep_model(Search *s, int t, bool accept) {
  if (accept && s->last) {
    model_free(s->out->model);
    s->out->model = s->last, s->model_trial = t, s->last = NULL;
  }
  model_free(s->last);
  s->last = NULL;
}

void tune_result_free(TuneResult *r) {
  for (int t = 0; r->trials && t < r->ntrials; t++) free(r->trials[t].cap), free(r->trials[t].m), free(r->trials[t].interp);
  free(r->trials);
  model_free(r->model);
  free(r->best_cap);
  memset(r, 0, sizeof *r);
}

/* 1. The first uniform cap, 1, 2, … (each class's at most s->maxk), that
 * meets the tolerance, or the largest: its trial (caps in `cap`), or -1
 * with `err`. */
static int uniform_trial(Search *s, int *cap, Err *err) {
  int top = 1, t = -1;
  for (int c = 0; c < s->nc; c++) top = s->maxk[c] > top ? s->maxk[c] : top;
  for (int u = 1; u <= top; u++) {
    for (int c = 0; c < s->nc; c++) cap[c] = u < s->maxk[c] ? u : s->maxk[c];
    if ((t = trial(s, cap, true, err)) < 0) return -1;
    keep_model(s, t, s->out->trials[t].err <= s->tol);
    if (s->out->trials[t].err <= s->tol) break;
  }
  return t;
}

/* The tolerance unmet at the largest caps `cap`: the class whose
 * projection floor is worst limits (out->limiting, its floor, whether it
 * is saturated). 0, or -1 with `err`. */
static int limiting_class(Search *s, const int *cap, Err *err) {
  TuneResult *out = s->out;
  Scratch sc = SCRATCH_OF(err);
  Model *m = train_set_model(s->ts, cap, err);
  double *floor = m ? scratch_array(&sc, (size_t)m->nq + 1, sizeof(double)) : NULL;
  double worst;
  int rc = floor ? validate(s, m, &worst, floor, err) : -1;
  for (int q = 0; rc == 0 && q < m->nq; q++) {
    int c = m->qclass[q];
    if (out->limiting < 0 || floor[q] > out->limiting_floor) out->limiting = c, out->limiting_floor = floor[q];
  }
  if (rc == 0) out->limiting_saturated = out->limiting >= 0 && s->maxk[out->limiting] < s->max_cap;
  model_free(m);
  scratch_release(&sc);
  return rc;
}

/* 2. From trial t (caps `cap`, which meet the tolerance), each class
 * bisected down with the others fixed, the costliest to grow first: the
 * cheapest trial that still meets it, or -1 with `err`. */
static int bisect_classes(Search *s, int *cap, int t, const Model *layout, Err *err) {
  TuneResult *out = s->out;
  int nc = s->nc;
  Scratch sc = SCRATCH_OF(err);
  int *order = scratch_array(&sc, (size_t)nc, sizeof(int));
  double *gain = scratch_array(&sc, (size_t)nc, sizeof(double));
  long *m1 = scratch_array(&sc, (size_t)nc, sizeof(long));
  int best = order && gain && m1 ? t : -1;
  for (int c = 0; best >= 0 && c < nc; c++) {
    memcpy(m1, out->trials[t].m, sizeof(long) * (size_t)nc);
    m1[c]++;
    if (cost_at(s->prog, m1, layout->samples, &gain[c])) best = err_set(err, "out of memory pricing the trials");
    gain[c] -= out->trials[t].cost;
    order[c] = c;
  }
  for (int i = 0; best >= 0 && i < nc; i++) /* by gain, descending */
    for (int j = i + 1; j < nc; j++)
      if (gain[order[j]] > gain[order[i]]) {
        int x = order[i];
        order[i] = order[j], order[j] = x;
      }
  for (int i = 0; best >= 0 && i < nc; i++) {
    int c = order[i], lo = 1, hi = cap[c];
    while (best >= 0 && lo < hi) {
      int mid = (lo + hi) / 2, was = cap[c];
      cap[c] = mid;
      int k = trial(s, cap, false, err);
      if (k < 0) {
        best = -1;
        break;
      }
      bool ok = out->trials[k].err <= s->tol && out->trials[k].cost <= out->trials[best].cost;
      keep_model(s, k, ok);
      if (ok) hi = mid, best = k;
      else lo = mid + 1, cap[c] = was;
      cap[c] = hi;
    }
  }
  scratch_release(&sc);
  return best;
}

/* The search from the validation samples cached (steps 1 and 2), `cap`
 * room for the caps: out filled. 0, or -1 with `err`. */
static int search_caps(Search *s, int *cap, const Model *layout, Err *err) {
  TuneResult *out = s->out;
  int t = uniform_trial(s, cap, err);
  if (t < 0) return -1;
  if (isinf(out->trials[t].err) && s->why[0]) /* failed at the largest caps: why is the error */
    return err_set(err, "%s", s->why);
  if (out->trials[t].err > s->tol) { /* unmet at the largest caps */
    if (limiting_class(s, cap, err)) return -1;
    memcpy(out->best_cap, cap, sizeof(int) * (size_t)s->nc);
    return 0;
  }
  int best = bisect_classes(s, cap, t, layout, err);
  if (best < 0) return -1;
  out->chosen = best;
  memcpy(out->best_cap, out->trials[best].cap, sizeof(int) * (size_t)s->nc);
  if (s->model_trial != best) { /* a trial found again (trial's reuse): its model made anew */
    model_free(out->model);
    out->model = configure(s, out->best_cap, &out->trials[best], err);
    if (!out->model) return -1;
  }
  return 0;
}

int tune_search(TrainSet *ts, const TuneGoal *goal, const TrainOptions *opt, TuneResult *out, Err *err) {
  memset(out, 0, sizeof *out);
  out->chosen = out->limiting = -1;
  Full *f = train_set_full(ts);
  Search s = {.ts = ts, .prog = train_set_program(ts), .f = f, .nc = train_set_classes(ts), .max_cap = goal->max_cap,
              .out = out, .tol = goal->tol, .model_trial = -1, .mem = SCRATCH_OF(err)};
  if (opt) s.copt = *opt, s.cuser = *opt->user;
  s.cuser.progress = false;
  s.copt.user = &s.cuser, s.copt.valid = NULL, s.copt.choose_strict = true;
  out->nclasses = s.nc;
  int *cap = scratch_array(&s.mem, (size_t)s.nc + 1, sizeof(int));
  s.maxk = scratch_array(&s.mem, (size_t)s.nc + 1, sizeof(int));
  out->best_cap = mem_calloc((size_t)s.nc + 1, sizeof(int)); /* the result's (tune_result_free) */
  int rc = cap && s.maxk && out->best_cap ? 0 : err_set(err, "out of memory");
  for (int c = 0; rc == 0 && c < s.nc; c++) {
    s.maxk[c] = train_set_max_cap(ts, c) < s.max_cap ? train_set_max_cap(ts, c) : s.max_cap;
    cap[c] = 1;
  }
  s.v.steps = opt ? opt->user->rollout_steps : 0;
  s.v.every = opt && opt->user->rollout_every > 0 ? opt->user->rollout_every : 1;
  Model *layout = rc == 0 ? train_set_model(ts, cap, err) : NULL;
  if (!layout || cache_valid(&s, f, goal->valid, layout, err) ||
      (s.v.steps > 0 && cache_rollouts(&s, f, goal->valid, layout, err)) || search_caps(&s, cap, layout, err))
    rc = -1;
  model_free(s.last);
  model_free(layout);
  scratch_release(&s.mem);
  return rc;
}

/* ---------------------------------------------------------------- Galerkin or interpolation (DESIGN §12) */

/* Multiply-adds of one evaluation of stage `rs` as reduced now: its tensors'
 * contractions and, by Galerkin, a factorization or eigendecomposition per
 * operator (ir/cost.c's 9 m³ for a root, m³/3 for an inverse); interpolated,
 * the lifts, the monomials and the fit. */
static double stage_work(const Model *m, const RStage *rs) {
  const RInterp *ip = rs->interp;
  double w = 0;
  if (ip) {
    for (long r = 0; r < ip->nreads; r++) w += (double)m->classes[m->qclass[ip->read_q[r]]].m;
    for (long i = 0; i < ip->nmono; i++) w += 1 + ip->mono[i].nin;
    return w + (double)(ip->k * ip->m);
  }
  double my = (double)m->classes[m->qclass[rs->q]].m;
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    RTERM_FOR_TENSORS(rt, x) { w += (double)x->rows * (double)x->cols; }
    for (int k = 0; k < rt->nops; k++) w += rt->ops[k].op->q > 1 ? 9 * my * my * my : my * my * my / 3;
  }
  return w;
}

/* Output errors closer than this (relative), or both at rounding level, are
 * a tie, settled by cost. */
#define CHOOSE_TIE 0.02
#define CHOOSE_ROUNDING 1e-12

/* The choice for every stage of `m` eligible and not forced
 * (tune_choose_reductions' contract) on the samples cached in `s`; *out:
 * the worst output's error as chosen; when both ways meet `tol` (npgc
 * tune's; training's is -1), the cheaper is kept. Without such a stage,
 * one validation.
 * A configuration that fails on a sample counts as an infinite error; the
 * all-Galerkin one's failure is left in `why` (else ""). 0, or -1 with
 * `err` (interp_train_stage failed). The options are s->copt, the
 * tolerance s->tol. */
static int choose(Search *s, Model *m, double *out, char why[static 1024], Err *err) {
  const TrainOptions *opt = &s->copt;
  double tol = s->tol;
  double over = opt->user->interp_oversample > 0 ? opt->user->interp_oversample : TRAIN_INTERP_OVERSAMPLE;
  char why2[1024] = "";
  why[0] = 0;
  double current = INFINITY;
  /* a configuration that fails on a validation sample (a reduced root of an
   * indefinite operator, a power of a negative interpolated value) has an
   * infinite error: the other may still work */
  if (validate(s, m, &current, NULL, ERR_OF(why, 1024)) != 0) current = INFINITY;
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    if (!lower_interp_eligible(rs->st) || rs->interp) continue; /* forced interpolated: kept */
    bool forced = rs->st->sym->reduce == STAGE_REDUCE_GALERKIN; /* `basis w: reduce galerkin` */
    for (int j = 0; j < opt->user->ngalerkin; j++)
      forced |= strcmp(opt->user->galerkin_stage[j], rs->st->sym->name) == 0;
    if (forced) continue;
    double galerkin = current, interp = INFINITY, wg = stage_work(m, rs);
    if (interp_train_stage(m, s->f, i, over, err) != 0) return -1;
    if (validate(s, m, &interp, NULL, ERR_OF(why2, sizeof why2)) != 0) interp = INFINITY;
    double wi = stage_work(m, rs);
    /* strict (tune): only rounding-level differences tie, so a choice never raises the error measured */
    bool tie = fabs(interp - galerkin) <= (opt->choose_strict ? 0 : CHOOSE_TIE * fmin(interp, galerkin)) + CHOOSE_ROUNDING;
    bool both = galerkin <= tol && interp <= tol; /* the tune objective: the cheaper of two that meet it */
    bool keep = tie || both ? wi < wg : interp < galerkin;
    rs->choice_err[0] = galerkin, rs->choice_err[1] = interp;
    rs->choice_reason = interp_reasons[both   ? (keep ? TOL_INTERP : TOL_GALERKIN)
                                       : tie  ? (keep ? TIE_INTERP : TIE_GALERKIN)
                                       : keep ? INTERP_LOWER
                                       : isfinite(galerkin) || isfinite(interp) ? GALERKIN_LOWER
                                                                                : BOTH_FAIL];
    if (keep) {
      current = interp;
      if (!isfinite(interp)) snprintf(why, 1024, "%s", why2); /* the failure of the configuration kept */
    } else {
      interp_free(rs->interp);
      rs->interp = NULL;
    }
    if (opt->user->progress)
      fprintf(stderr, "stage %s: output error by Galerkin %.3e, by interpolation %.3e: %s\n", rs->st->sym->name,
              galerkin, interp, rs->choice_reason);
  }
  *out = current;
  return 0;
}

int tune_choose_reductions(Model *m, Full *f, const SampleSource *valid, const TrainOptions *opt, Err *err) {
  int candidates = 0;
  for (int i = 0; i < m->nstages; i++) candidates += lower_interp_eligible(m->stages[i].st) && !m->stages[i].interp;
  if (candidates == 0) return 0; /* nothing to measure: no validation pass */
  Search s = {.prog = m->prog, .f = f, .copt = *opt, .tol = -1, .mem = SCRATCH_OF(err)};
  double chosen;
  char why[1024];
  /* a model whose every configuration fails on a validation sample is kept (the reasons say so) */
  int rc = cache_valid(&s, f, valid, m, err) || choose(&s, m, &chosen, why, err) ? -1 : 0;
  /* kept, but never quietly: interp_report warns, naming this failure */
  if (rc == 0 && !isfinite(chosen)) snprintf(m->choice_failure, sizeof m->choice_failure, "%.590s", why);
  scratch_release(&s.mem);
  return rc;
}
