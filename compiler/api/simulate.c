/* simulate.c — simulations through npg.h (DESIGN §15): the full step and the reduced step in
 * coordinates, many steps per call, each checked for blow-up (a next value not finite, or a
 * state's energy grown past the blow-up factor times its start), and rollouts that save every
 * K-th step through the caller's callbacks. */
#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"

double api_rollout_blowup(const Rollout *ro) { return ro->blowup_set ? ro->blowup : 10; }

/* Where the blow-up check reads a state and its next value: the full evaluator's buffers or the
 * reduced coordinates. */
typedef struct StateView {
  const double *next;       /* the next value (or its coordinates) */
  size_t n;
} StateView;

/* "step 41: state 'u' ..." when the next value of state `u` (view `v`) blew up, into err; the
 * start energies are recorded at the rollout's first step. 0 when the step is sound. */
static int blown_up(Rollout *ro, int i, const Sym *u, StateView v, char *err, size_t errlen) {
  /* one pass over the next value when it is sound: a NaN or an infinite entry makes ‖u‖² NaN or
   * infinite (squares are never negative), and only then are the entries searched (the full
   * step of nonlinear heat at 128 x 128: 41 -> 36 µs, bench_shapes) */
  double e = v.n ? cblas_ddot((int)v.n, v.next, 1, v.next, 1) : 0, factor = api_rollout_blowup(ro);
  if (!isfinite(e))
    for (size_t k = 0; k < v.n; k++)
      if (!isfinite(v.next[k]))
        return snprintf(err, errlen, "step %ld: state '%s' blew up: its next value is %s at flat entry %zu",
                        ro->steps + 1, u->name, isnan(v.next[k]) ? "NaN" : "an infinity", k), -1;
  if (factor > 0 && ro->start[i] > 0 && e > factor * ro->start[i])
    return snprintf(err, errlen,
                    "step %ld: state '%s' blew up: its energy ‖%s‖² = %.4g is %.3g× its value %.4g at the "
                    "rollout's start (blow-up factor %g)", ro->steps + 1, u->name, u->name, e, e / ro->start[i],
                    ro->start[i], factor), -1;
  return 0;
}

/* The start energies of the states, at a rollout's first step. */
static int rollout_start(Rollout *ro, const Program *prog, StateView (*view)(void *, const Sym *, bool), void *at) {
  if (ro->steps > 0 && ro->start) return 0;
  if (!ro->start && !(ro->start = calloc((size_t)prog->states.n + 1, sizeof(double)))) return -1;
  for (int i = 0; i < prog->states.n; i++) {
    StateView v = view(at, prog->states.v[i], false);
    ro->start[i] = v.n ? cblas_ddot((int)v.n, v.next, 1, v.next, 1) : 0;
  }
  return 0;
}

/* After an evaluation of the step: the start energies at a rollout's first step, then every next
 * value checked for a blow-up. 0, or -1 with the message in err. */
static int check_step(Rollout *ro, const Program *prog, StateView (*view)(void *, const Sym *, bool), void *at,
                      char *err, size_t errlen) {
  if ((ro->steps == 0 || !ro->start) && rollout_start(ro, prog, view, at))
    return snprintf(err, errlen, "out of memory"), -1;
  for (int i = 0; i < prog->states.n; i++)
    if (blown_up(ro, i, prog->states.v[i], view(at, prog->states.v[i], true), err, errlen)) return -1;
  return 0;
}

static int set_blowup(Rollout *ro, double factor, char *err, size_t errlen, const char *func) {
  if (!(factor >= 0) || !isfinite(factor))
    return api_refuse(err, errlen, func, "argument 'factor' is %g (a blow-up factor > 1, or 0 to check finiteness only)",
                      factor);
  if (factor > 0 && factor <= 1)
    return api_refuse(err, errlen, func, "argument 'factor' is %g: a blow-up factor must exceed 1 (0 checks finiteness "
                      "only)", factor);
  ro->blowup = factor;
  ro->blowup_set = true;
  return 0;
}

static int refuse_steps(const Program *prog, long steps, char *err, size_t errlen, const char *func) {
  if (!prog) return -1;
  if (prog->states.n == 0)
    return api_refuse(err, errlen, func, "the program has no state: declare one with 'state u : ...' and its next value "
                      "with 'next u = ...' to step it");
  if (steps < 0) return api_refuse(err, errlen, func, "argument 'steps' is %ld (0 or more)", steps);
  return 0;
}

/* ---------------------------------------------------------------- implicit steps */

/* The state stepped implicitly (`residual next u = ...`: u.next an input, the zero of
 * u.residual), or NULL: the front end allows one per program. */
static const Sym *implicit_state(const Program *prog) {
  for (int i = 0; i < prog->states.n; i++)
    if (((const Sym *)prog->states.v[i])->residual) return prog->states.v[i];
  return NULL;
}

static int set_newton(Rollout *ro, double tol, int max_iter, FILE *verbose, char *err, size_t errlen,
                      const char *func) {
  if (!(tol > 0) || !isfinite(tol) || tol >= 1)
    return api_refuse(err, errlen, func, "argument 'tol' is %g (a relative tolerance in (0, 1))", tol);
  if (max_iter < 1) return api_refuse(err, errlen, func, "argument 'max_iter' is %d (1 or more)", max_iter);
  ro->newton_tol = tol, ro->newton_max_iter = max_iter, ro->newton_verbose = verbose, ro->newton_set = true;
  return 0;
}

/* Newton's options for one step from the state's norm: stop at ‖r‖ <= tol · max(‖r₀‖, 1e-4 ‖u‖)
 * (the floor: a state near rest, whose ‖r₀‖ is near the residual's rounding). */
static NpgNewton newton_options(const Rollout *ro, const double *u, size_t n) {
  double tol = ro->newton_set ? ro->newton_tol : 1e-10, norm = n ? cblas_dnrm2((int)n, u, 1) : 0;
  return (NpgNewton){.rtol = tol, .tol = fmax(1e-4 * tol * norm, DBL_MIN),
                     .max_iter = ro->newton_set ? ro->newton_max_iter : 30,
                     .verbose = ro->newton_set ? ro->newton_verbose : NULL};
}

/* The full implicit step: u.next from u by npg_full_newton, every quantity evaluated there. */
static int full_implicit(NpgFull *f, const Sym *u, long sample) {
  size_t n = 0;
  const double *x = full_get(f->full, u->name, &n);
  if (!x) return full_eval(f->full, sample); /* its message: the state has no value */
  long shape[MAX_AXES + MAX_STATIC];
  int nd = api_shape(f->full, u, shape);
  if (full_set(f->full, u->next->name, nd, shape, x, "the implicit step's first guess") != 0) return -1;
  NpgNewton o = newton_options(&f->roll, x, n);
  if (npg_full_newton(f, sample, u->residual->name, u->next->name, &o) == 0) return 0;
  char err[1200];
  snprintf(err, sizeof err, "step %ld: %s", f->roll.steps + 1, full_error(f->full));
  full_clear_error(f->full);
  return full_fail(f->full, err);
}

/* The reduced implicit step: u.next's coordinates from u's by npg_reduced_newton. */
static int reduced_implicit(NpgReduced *r, const Sym *u, long sample) {
  const Model *m = r->nm->m;
  int q = api_quantity(m->prog, u->name);
  const double *x = reduced_coords(r->r, q);
  size_t n = (size_t)m->classes[m->qclass[q]].m;
  if (npg_reduced_set_coords(r, u->next->name, n, x) != 0) return -1;
  NpgNewton o = newton_options(&r->roll, x, n);
  if (npg_reduced_newton(r, sample, u->residual->name, u->next->name, &o) == 0) return 0;
  char err[sizeof r->error + 40];
  snprintf(err, sizeof err, "step %ld: %s", r->roll.steps + 1, r->error);
  memcpy(r->error, err, sizeof r->error - 1);
  r->error[sizeof r->error - 1] = 0;
  return -1;
}

/* ---------------------------------------------------------------- the full step */

static StateView full_view(void *at, const Sym *u, bool next) {
  size_t n = 0;
  const double *v = full_get(at, next ? u->next->name : u->name, &n);
  return (StateView){v, v ? n : 0};
}

int npg_full_step(NpgFull *f, long steps, long sample) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  const Program *prog = full_program(f->full);
  char err[600];
  if (full_error(f->full)[0]) return -1;
  if (refuse_steps(prog, steps, err, sizeof err, __func__)) return full_fail(f->full, err);
  const Sym *implicit = implicit_state(prog);
  for (long t = 0; t < steps; t++) {
    if ((implicit ? full_implicit(f, implicit, sample) : full_eval(f->full, sample)) != 0) return -1;
    if (check_step(&f->roll, prog, full_view, f->full, err, sizeof err)) return full_fail(f->full, err);
    if (implicit && f->roll.solved && f->roll.solved(f->roll.solved_user, f->roll.steps) != 0)
      return npg_full_error(f)[0] ? -1 : full_fail(f->full, "recording the solved implicit step failed");
    if (full_advance(f->full) != 0) return -1;
    f->roll.steps++;
  }
  return 0;
}

long npg_full_steps(const NpgFull *f) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  return f->roll.steps;
}

int npg_full_set_blowup(NpgFull *f, double factor) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  char err[400];
  if (set_blowup(&f->roll, factor, err, sizeof err, __func__)) return full_refuse(f->full, err);
  return 0;
}

int npg_full_set_newton(NpgFull *f, double tol, int max_iter, FILE *verbose) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  char err[400];
  if (set_newton(&f->roll, tol, max_iter, verbose, err, sizeof err, __func__)) return full_refuse(f->full, err);
  return 0;
}

/* ---------------------------------------------------------------- the reduced step */

static StateView reduced_view(void *at, const Sym *u, bool next) {
  NpgReduced *r = at;
  const Model *m = r->nm->m;
  int q = api_quantity(m->prog, next ? u->next->name : u->name);
  return (StateView){reduced_coords(r->r, q), (size_t)m->classes[m->qclass[q]].m};
}

int npg_reduced_step(NpgReduced *r, long steps, long sample) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  if (npg_reduced_error(r)[0]) return -1;
  const Program *prog = r->nm->m->prog;
  char err[600];
  if (refuse_steps(prog, steps, err, sizeof err, __func__))
    return error_set_first(r->error, sizeof r->error, "%s", err);
  const Sym *implicit = implicit_state(prog);
  for (long t = 0; t < steps; t++) {
    if ((implicit ? reduced_implicit(r, implicit, sample) : npg_reduced_eval(r, sample)) != 0) return -1;
    if (check_step(&r->roll, prog, reduced_view, r, err, sizeof err))
      return error_set_first(r->error, sizeof r->error, "%s", err);
    for (int i = 0; i < prog->states.n; i++) { /* one class, one basis: the next coordinates are the state's */
      const Sym *u = prog->states.v[i];
      StateView next = reduced_view(r, u, true);
      memcpy((double *)reduced_view(r, u, false).next, next.next, sizeof(double) * next.n);
    }
    r->roll.steps++;
  }
  return 0;
}

long npg_reduced_steps(const NpgReduced *r) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  return r->roll.steps;
}

int npg_reduced_set_blowup(NpgReduced *r, double factor) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  return set_blowup(&r->roll, factor, r->error, sizeof r->error, __func__);
}

int npg_reduced_set_newton(NpgReduced *r, double tol, int max_iter, FILE *verbose) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  return set_newton(&r->roll, tol, max_iter, verbose, r->error, sizeof r->error, __func__);
}

/* ---------------------------------------------------------------- rollouts */

typedef int (*StepFn)(void *at, long steps, long sample);

static int rollout(void *at, StepFn step, long sample, const NpgRollout *ro, char *err, size_t errlen,
                   const char *func) {
  if (!ro) return api_refuse(err, errlen, func, "argument 'ro' is NULL");
  if (ro->steps < 0) return api_refuse(err, errlen, func, "ro->steps is %ld (0 or more)", ro->steps);
  if (ro->every < 1) return api_refuse(err, errlen, func, "ro->every is %ld (1 or more: save every K-th step)", ro->every);
  for (long t = 0; t <= ro->steps; t++) {
    if (t < ro->steps && ro->before_step && ro->before_step(ro->user, t) != 0)
      return snprintf(err, errlen, "step %ld: setting the inputs failed", t), -1;
    if (t % ro->every == 0 && ro->at_save && ro->at_save(ro->user, t) != 0)
      return snprintf(err, errlen, "step %ld: saving the states failed", t), -1;
    if (t == ro->steps) break;
    if (step(at, 1, sample) != 0) return 1;
  }
  return 0;
}

static int full_step1(void *at, long steps, long sample) { return npg_full_step(at, steps, sample); }
static int reduced_step1(void *at, long steps, long sample) { return npg_reduced_step(at, steps, sample); }

int npg_full_simulate(NpgFull *f, long sample, const NpgRollout *ro) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (full_error(f->full)[0]) return -1;
  char err[600] = "";
  int rc = rollout(f, full_step1, sample, ro, err, sizeof err, __func__);
  if (rc < 0 && !full_error(f->full)[0]) full_fail(f->full, err);
  return rc ? -1 : 0;
}

int npg_reduced_simulate(NpgReduced *r, long sample, const NpgRollout *ro) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  if (npg_reduced_error(r)[0]) return -1;
  char err[600] = "";
  int rc = rollout(r, reduced_step1, sample, ro, err, sizeof err, __func__);
  if (rc < 0 && !r->error[0]) error_set_first(r->error, sizeof r->error, "%s", err);
  return rc ? -1 : 0;
}

/* ---------------------------------------------------------------- training from trajectories */

typedef struct AddVisited {
  NpgTrainer *t;
  NpgFull *f;
  const NpgRollout *ro;
  long first;               /* the rollout's first step (npg_full_steps when it started) */
} AddVisited;

/* An implicit step: the pair (u, u.next) of every every-th step as solved, every quantity at the
 * solution (the states alone would leave the unknown's value and the residual's zero unseen). */
static int add_solved(void *user, long step) {
  AddVisited *a = user;
  long t = step - a->first;
  if (t % a->ro->every != 0) return 0;
  return npg_trainer_add_full(a->t, a->f) != 0 ? -1 : 0;
}

static int add_visited(void *user, long step) {
  AddVisited *a = user;
  if (npg_trainer_add_full(a->t, a->f) != 0) return -1;
  return a->ro->at_save ? a->ro->at_save(a->ro->user, step) : 0;
}

static int before_visit(void *user, long step) {
  AddVisited *a = user;
  return a->ro->before_step(a->ro->user, step);
}

int npg_trainer_add_trajectory(NpgTrainer *t, NpgFull *f, long sample, const NpgRollout *ro) {
  API_REFUSE_NULL(t, NULL, 0, -1);
  if (npg_trainer_error(t)[0]) return -1;
  if (!f) return npg_trainer_add_full(t, NULL); /* the trainer's own refusal of a NULL evaluator */
  if (!ro) return npg_full_simulate(f, sample, NULL); /* its refusal, in f */
  AddVisited a = {t, f, ro, 0};
  NpgRollout visit = *ro;
  visit.at_save = add_visited;
  visit.before_step = ro->before_step ? before_visit : NULL;
  visit.user = &a;
  const Program *prog = full_program(f->full);
  if (!prog || !implicit_state(prog)) return npg_full_simulate(f, sample, &visit);
  visit.at_save = ro->at_save; /* the caller's own saves; the samples are the solved steps */
  visit.user = ro->user;
  visit.before_step = ro->before_step;
  a.first = f->roll.steps;
  f->roll.solved = add_solved, f->roll.solved_user = &a;
  int rc = npg_full_simulate(f, sample, &visit);
  f->roll.solved = NULL, f->roll.solved_user = NULL;
  if (rc == 0 && npg_trainer_error(t)[0]) return -1;
  return rc;
}
