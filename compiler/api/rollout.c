/* rollout.c — the check of a simulation (DESIGN §15, npg_verify_rollout): the full and the
 * reduced rollouts of each trajectory, the states compared at every saved step with the
 * trajectory's projection floor. The caller's NpgTrajectoryFn sets a trajectory's values in the full
 * evaluator; the reduced rollout reads them from there, so one callback serves both. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"

typedef struct Check {
  const Program *prog;
  NpgFull *f;
  NpgReduced *r, *proj;
  NpgTrajectoryFn set;
  void *user;
  long k, every, saves;
  int ns, ninputs;
  const Sym **state, **input; /* the states; every input (states too) */
  size_t *n;                /* per state: entries */
  double **full, *lift;     /* per state: saves x n of the full rollout; scratch */
  NpgRolloutRow *rows;
  double *e2, *f2, *n2;     /* per state: the sums over every trajectory and save */
} Check;

static int full_before(void *user, long t) {
  Check *c = user;
  return t ? c->set(c->user, c->f, c->k, t) : 0;
}

static int full_save(void *user, long t) {
  Check *c = user;
  for (int i = 0; i < c->ns; i++) {
    size_t n = 0;
    const double *v = full_get(c->f->full, c->state[i]->name, &n);
    if (!v || n != c->n[i]) return -1;
    memcpy(c->full[i] + (size_t)(t / c->every) * n, v, sizeof(double) * n);
  }
  return 0;
}

/* The values the callback set in f, into the reduced evaluator: every input (all) or those
 * that are not states. */
static int copy_inputs(Check *c, bool all) {
  for (int i = 0; i < c->ninputs; i++) {
    const Sym *s = c->input[i];
    if ((!all && s->next) || s->state_of) continue; /* state_of: u.next, solved by an implicit step */
    size_t n = 0;
    const double *v = full_get(c->f->full, s->name, &n);
    if (!v) return -1;
    if (npg_reduced_set(c->r, s->name, n, v) != 0) return -1;
  }
  return 0;
}

static int reduced_before(void *user, long t) {
  Check *c = user;
  return t ? (c->set(c->user, c->f, c->k, t) || copy_inputs(c, false) ? -1 : 0) : 0;
}

/* The reduced state at save t against the full one and its projection. */
static int reduced_save(void *user, long t) {
  Check *c = user;
  long s = t / c->every;
  for (int i = 0; i < c->ns; i++) {
    const char *name = c->state[i]->name;
    size_t n = c->n[i];
    const double *F = c->full[i] + (size_t)s * n;
    double e2 = 0, f2 = 0, n2 = 0;
    if (npg_reduced_lift(c->r, name, c->lift, n) != 0) return -1;
    for (size_t j = 0; j < n; j++) e2 += (c->lift[j] - F[j]) * (c->lift[j] - F[j]), n2 += F[j] * F[j];
    if (npg_reduced_set(c->proj, name, n, F) != 0 || npg_reduced_lift(c->proj, name, c->lift, n) != 0) return -1;
    for (size_t j = 0; j < n; j++) f2 += (c->lift[j] - F[j]) * (c->lift[j] - F[j]);
    NpgRolloutRow *row = &c->rows[i];
    double scale = n2 > 0 ? sqrt(n2) : 1, e = sqrt(e2) / scale, fl = sqrt(f2) / scale;
    c->e2[i] += e2, c->f2[i] += f2, c->n2[i] += n2;
    row->err[s] = fmax(row->err[s], e);
    row->floor[s] = fmax(row->floor[s], fl);
    if (e > row->err_max || (c->k == 0 && s == 0)) row->err_max = e, row->max_trajectory = c->k, row->max_step = t;
    if (s == c->saves - 1) row->err_final = fmax(row->err_final, e);
  }
  return 0;
}

static void free_check(Check *c) {
  for (int i = 0; c->full && i < c->ns; i++) free(c->full[i]);
  free(c->full), free(c->lift), free(c->state), free(c->input), free(c->n), free(c->e2), free(c->f2), free(c->n2);
  npg_reduced_free(c->r);
  npg_reduced_free(c->proj);
}

void npg_verify_rollout_free(NpgRolloutReport *rep) {
  if (!rep) return;
  for (int i = 0; rep->rows && i < rep->nstates; i++) free(rep->rows[i].err), free(rep->rows[i].floor);
  free(rep->rows);
  rep->rows = NULL, rep->nstates = 0;
}

int npg_verify_rollout(const NpgModel *m, NpgFull *f, long trajectories, long steps, long every, NpgTrajectoryFn set,
                       void *user, bool progress, NpgRolloutReport *rep) {
  API_REFUSE_NULL(rep, NULL, 0, -1);
  memset(rep, 0, sizeof *rep);
#define REFUSE(...) return api_refuse(rep->error, sizeof rep->error, __func__, __VA_ARGS__)
  if (!m) REFUSE("argument 'm' is NULL");
  if (!f) REFUSE("argument 'f' is NULL");
  if (!set) REFUSE("argument 'set' is NULL");
  if (!m->m) REFUSE("the model holds nothing: %s", m->error);
  if (trajectories < 1) REFUSE("argument 'trajectories' is %ld (at least one)", trajectories);
  if (steps < 0) REFUSE("argument 'steps' is %ld (0 or more)", steps);
  if (every < 1) REFUSE("argument 'every' is %ld (1 or more)", every);
#undef REFUSE
  if (npg_full_error(f)[0]) return snprintf(rep->error, sizeof rep->error, "%s", npg_full_error(f)), -1;
  const Program *prog = m->m->prog;
  if (prog->states.n == 0)
    return snprintf(rep->error, sizeof rep->error, "the program has no state: a rollout steps a program with "
                    "'state u' and 'next u = ...' (npg_verify checks one evaluation)"), -1;
  char err[600];
  if (npg_model_check_params(m, f, err, sizeof err) != 0) return snprintf(rep->error, sizeof rep->error, "%s", err), -1;
  Check c = {.prog = prog, .f = f, .set = set, .user = user, .every = every, .saves = steps / every + 1};
  c.ns = prog->states.n, c.ninputs = prog->inputs.n;
  rep->trajectories = trajectories, rep->steps = steps, rep->every = every, rep->saves = c.saves;
  c.state = calloc((size_t)c.ns, sizeof *c.state), c.input = calloc((size_t)c.ninputs + 1, sizeof *c.input);
  c.n = calloc((size_t)c.ns, sizeof *c.n), c.full = calloc((size_t)c.ns, sizeof *c.full);
  c.e2 = calloc((size_t)c.ns, sizeof(double)), c.f2 = calloc((size_t)c.ns, sizeof(double));
  c.n2 = calloc((size_t)c.ns, sizeof(double));
  rep->rows = c.rows = calloc((size_t)c.ns, sizeof *c.rows);
  c.r = npg_reduced_new(m), c.proj = npg_reduced_new(m);
  int rc = -1;
  if (!c.state || !c.input || !c.n || !c.full || !c.e2 || !c.f2 || !c.n2 || !c.rows || !c.r || !c.proj) goto oom;
  if (npg_reduced_error(c.r)[0]) {
    snprintf(rep->error, sizeof rep->error, "%s", npg_reduced_error(c.r));
    goto done;
  }
  rep->nstates = c.ns;
  c.r->roll.newton_tol = f->roll.newton_tol, c.r->roll.newton_max_iter = f->roll.newton_max_iter; /* f's Newton */
  c.r->roll.newton_verbose = f->roll.newton_verbose, c.r->roll.newton_set = f->roll.newton_set;
  size_t maxn = 1;
  for (int i = 0; i < c.ninputs; i++) c.input[i] = prog->inputs.v[i];
  for (int i = 0; i < c.ns; i++) {
    c.state[i] = prog->states.v[i];
    int q = api_quantity(prog, c.state[i]->name);
    c.n[i] = (size_t)m->m->classes[m->m->qclass[q]].n;
    maxn = c.n[i] > maxn ? c.n[i] : maxn;
    c.rows[i].state = c.state[i]->name;
    if (!(c.full[i] = malloc(sizeof(double) * (c.n[i] * (size_t)c.saves + 1))) ||
        !(c.rows[i].err = calloc((size_t)c.saves, sizeof(double))) ||
        !(c.rows[i].floor = calloc((size_t)c.saves, sizeof(double))))
      goto oom;
  }
  if (!(c.lift = malloc(sizeof(double) * maxn))) goto oom;
  NpgRollout fro = {.steps = steps, .every = every, .before_step = full_before, .at_save = full_save, .user = &c};
  NpgRollout rro = {.steps = steps, .every = every, .before_step = reduced_before, .at_save = reduced_save, .user = &c};
  for (c.k = 0; c.k < trajectories; c.k++) {
    if (c.set(user, f, c.k, 0) != 0 || npg_full_simulate(f, c.k, &fro) != 0) {
      snprintf(rep->error, sizeof rep->error, "trajectory %ld, full rollout: %s", c.k, npg_full_error(f));
      goto done;
    }
    if (c.set(user, f, c.k, 0) != 0 || copy_inputs(&c, true) != 0 || npg_reduced_simulate(c.r, c.k, &rro) != 0) {
      const char *why = npg_reduced_error(c.r)[0] ? npg_reduced_error(c.r)
                        : npg_reduced_error(c.proj)[0] ? npg_reduced_error(c.proj) : npg_full_error(f);
      snprintf(rep->error, sizeof rep->error, "trajectory %ld, reduced rollout: %s", c.k, why);
      goto done;
    }
    npg_progress(progress, "rollouts (full and reduced)", c.k + 1, trajectories);
  }
  for (int i = 0; i < c.ns; i++) {
    c.rows[i].traj_err = c.n2[i] > 0 ? sqrt(c.e2[i] / c.n2[i]) : sqrt(c.e2[i]);
    c.rows[i].traj_floor = c.n2[i] > 0 ? sqrt(c.f2[i] / c.n2[i]) : sqrt(c.f2[i]);
  }
  rc = 0;
  goto done;
oom:
  snprintf(rep->error, sizeof rep->error, "out of memory");
done:
  free_check(&c);
  if (rc) npg_verify_rollout_free(rep);
  return rc;
}
