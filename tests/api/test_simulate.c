/* test_simulate.c — simulations through npg.h alone (DESIGN §15), on the heat examples
 * (examples/heat/): the full rollout against the same step written in C, with a source given
 * per step; training from trajectories with whole bases (as many random initial states as
 * cells), whose reduced rollout in coordinates then equals the full one; blow-ups named by step
 * and state in both; an implicit step solved by Newton; the refusals of the simulation calls. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "npg.h"

enum { SIDE = 4, N = SIDE * SIDE, STEPS = 100 };

static long nbr[N][4];
static double nbr_d[N * 4];

static void grid(void) {
  for (int i = 0; i < SIDE; i++)
    for (int j = 0; j < SIDE; j++) {
      int c = i * SIDE + j;
      nbr[c][0] = i > 0 ? c - SIDE : -1;
      nbr[c][1] = i < SIDE - 1 ? c + SIDE : -1;
      nbr[c][2] = j > 0 ? c - 1 : -1;
      nbr[c][3] = j < SIDE - 1 ? c + 1 : -1;
      for (int k = 0; k < 4; k++) nbr_d[c * 4 + k] = (double)nbr[c][k];
    }
}

static NpgFull *heat(const char *path, NpgProgram **p, double dt) {
  *p = npg_compile(path, NULL);
  if (!npg_ok(*p)) fputs(npg_error(*p), stderr);
  assert_true(npg_ok(*p));
  NpgFull *f = npg_full_new(*p, NPG_TCC);
  long shape[2] = {N, 4};
  assert_int_equal(npg_full_set_param(f, "nbr", 2, shape, nbr_d, "nbr"), 0);
  assert_int_equal(npg_full_set_param(f, "dt", 0, NULL, &dt, "dt"), 0);
  return f;
}

static double source(long step, int i) { return 0.01 * sin(0.1 * (double)step + i); }

typedef struct Run {
  NpgFull *f;
  double saved[STEPS + 1][N];
} Run;

static int set_source(void *user, long step) {
  Run *r = user;
  double f[N];
  for (int i = 0; i < N; i++) f[i] = source(step, i);
  long n = N;
  return npg_full_set(r->f, "f", 1, &n, f, "source");
}

static int save(void *user, long step) {
  Run *r = user;
  size_t n = 0;
  const double *u = npg_full_get(r->f, "u", &n);
  assert_int_equal(n, N);
  memcpy(r->saved[step], u, sizeof r->saved[step]);
  return 0;
}

/* heat_linear.npg's rollout, with f given per step, equals the step written in C. */
static void test_full_rollout_matches_c(void **state) {
  (void)state;
  NpgProgram *p;
  double dt = 0.2;
  NpgFull *f = heat("examples/heat/heat_linear.npg", &p, dt);
  static Run r;
  r.f = f;
  double u[N], v[N];
  for (int i = 0; i < N; i++) u[i] = cos(1.3 * i);
  long n = N;
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u0"), 0);
  NpgRollout ro = {.steps = STEPS, .every = 1, .before_step = set_source, .at_save = save, .user = &r};
  if (npg_full_simulate(f, 0, &ro) != 0) fputs(npg_full_error(f), stderr);
  assert_int_equal(npg_full_steps(f), STEPS);
  double worst = 0;
  for (int t = 0; t <= STEPS; t++) {
    for (int i = 0; i < N; i++) worst = fmax(worst, fabs(r.saved[t][i] - u[i]));
    for (int i = 0; i < N; i++) {
      double lap = 0;
      for (int k = 0; k < 4; k++)
        if (nbr[i][k] >= 0) lap += u[nbr[i][k]] - u[i];
      v[i] = u[i] + dt * (lap + source(t, i));
    }
    memcpy(u, v, sizeof u);
  }
  assert_true(worst <= 1e-12);
  /* npg_full_step continues the same rollout; the state is the value after the steps */
  assert_int_equal(npg_full_step(f, 3, 0), 0);
  assert_int_equal(npg_full_steps(f), STEPS + 3);
  npg_full_free(f);
  npg_free(p);
}

/* Trained on as many random states as cells with energy 1, the bases are whole: the reduced
 * rollout in coordinates equals the full one to rounding. */
static void test_whole_bases_reduced_equals_full(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = heat("examples/heat/heat.npg", &p, 0.2);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.energy = 1;
  o.cap = N;
  o.progress = false;
  NpgTrainer *t = npg_trainer_new(f, &o);
  srand(7);
  long n = N;
  for (int s = 0; s < 2 * N; s++) {
    double u[N];
    for (int i = 0; i < N; i++) u[i] = (double)rand() / RAND_MAX - 0.5;
    assert_int_equal(npg_full_set(f, "u", 1, &n, u, "random state"), 0);
    NpgRollout ro = {.steps = 2, .every = 1};
    if (npg_trainer_add_trajectory(t, f, s, &ro) != 0) fprintf(stderr, "%s / %s\n", npg_trainer_error(t), npg_full_error(f));
    assert_string_equal(npg_trainer_error(t), "");
  }
  assert_int_equal(npg_trainer_samples(t), 2 * N * 3);
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) fputs(npg_trainer_error(t), stderr);
  assert_non_null(m);
  NpgReduced *r = npg_reduced_new(m);
  double u0[N], full[N], red[N];
  for (int i = 0; i < N; i++) u0[i] = 0.8 * exp(-0.3 * (double)((i % SIDE - 1) * (i % SIDE - 1) + (i / SIDE - 2) * (i / SIDE - 2)));
  assert_int_equal(npg_full_set(f, "u", 1, &n, u0, "u0"), 0);
  assert_int_equal(npg_full_step(f, STEPS, 0), 0);
  memcpy(full, npg_full_get(f, "u", NULL), sizeof full);
  assert_int_equal(npg_reduced_set(r, "u", N, u0), 0);
  if (npg_reduced_step(r, STEPS, 0) != 0) fputs(npg_reduced_error(r), stderr);
  assert_int_equal(npg_reduced_steps(r), STEPS);
  assert_int_equal(npg_reduced_lift(r, "u", red, N), 0);
  double err = 0, norm = 0;
  for (int i = 0; i < N; i++) err = fmax(err, fabs(red[i] - full[i])), norm = fmax(norm, fabs(full[i]));
  assert_true(norm > 1e-3);
  assert_true(err <= 1e-10 * norm);
  npg_reduced_free(r);
  npg_model_free(m);
  npg_trainer_free(t);
  npg_full_free(f);
  npg_free(p);
}

/* Trajectory k's initial state: a bump of height 0.6 + 0.1 k (an NpgTrajectoryFn; nothing per step). */
static int bump(void *user, NpgFull *f, long k, long t) {
  (void)user;
  if (t > 0) return 0;
  double u[N];
  for (int i = 0; i < N; i++) {
    double x = (double)(i % SIDE) - 1.5, y = (double)(i / SIDE) - 1.5 + 0.3 * (double)k;
    u[i] = (0.6 + 0.1 * (double)k) * exp(-0.4 * (x * x + y * y));
  }
  long n = N;
  return npg_full_set(f, "u", 1, &n, u, "bump");
}

/* The semi-implicit step (a solve with a state-dependent operator): trained from trajectories,
 * checked over held-out ones by npg_verify_rollout. */
static void test_semi_implicit_verified_over_the_trajectory(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = heat("examples/heat/heat_implicit.npg", &p, 0.5);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.progress = false;
  NpgTrainer *t = npg_trainer_new(f, &o);
  NpgRollout ro = {.steps = 40, .every = 2};
  for (long k = 0; k < 4; k++) {
    assert_int_equal(bump(NULL, f, 2 * k, 0), 0);
    if (npg_trainer_add_trajectory(t, f, k, &ro) != 0) fputs(npg_trainer_error(t), stderr);
  }
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) fputs(npg_trainer_error(t), stderr);
  assert_non_null(m);
  NpgRolloutReport rep;
  if (npg_verify_rollout(m, f, 3, 40, 5, bump, NULL, false, &rep) != 0) fputs(rep.error, stderr);
  assert_int_equal(rep.nstates, 1);
  assert_string_equal(rep.rows[0].state, "u");
  assert_int_equal(rep.saves, 9);
  const NpgRolloutRow *row = &rep.rows[0];
  assert_true(row->traj_floor <= row->traj_err * (1 + 1e-9));
  assert_true(row->traj_err > 0 && row->traj_err < 0.05);
  assert_true(row->err_max >= row->err_final && row->err_max >= row->err[0]);
  npg_verify_rollout_free(&rep);
  /* refusals */
  assert_int_equal(npg_verify_rollout(m, f, 0, 40, 5, bump, NULL, false, &rep), -1);
  assert_non_null(strstr(rep.error, "'trajectories' is 0"));
  assert_int_equal(npg_verify_rollout(m, f, 1, 40, 0, bump, NULL, false, &rep), -1);
  assert_non_null(strstr(rep.error, "'every' is 0"));
  npg_model_free(m);
  npg_trainer_free(t);
  npg_full_free(f);
  npg_free(p);
}

/* Explicit Euler past its stability limit: the full step stops, naming the step and the state. */
static void test_blowup_named(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = heat("examples/heat/heat_linear.npg", &p, 1.5);
  double u[N], src[N] = {0};
  for (int i = 0; i < N; i++) u[i] = (i % 2) ? 1 : -1;
  long n = N;
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u0"), 0);
  assert_int_equal(npg_full_set(f, "f", 1, &n, src, "f"), 0);
  assert_int_equal(npg_full_step(f, 1000, 0), -1);
  const char *e = npg_full_error(f);
  assert_non_null(strstr(e, "state 'u' blew up"));
  assert_non_null(strstr(e, "step "));
  long at = atol(strstr(e, "step ") + 5);
  assert_true(at >= 1 && at < 1000);
  /* finiteness only: the energy grows without a stop until it overflows */
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u0"), 0);
  assert_int_equal(npg_full_set_blowup(f, 0), 0);
  assert_int_equal(npg_full_step(f, 1000, 0), -1);
  assert_non_null(strstr(npg_full_error(f), "is an infinity") ? strstr(npg_full_error(f), "is an infinity")
                                                               : strstr(npg_full_error(f), "is NaN"));
  npg_full_free(f);
  npg_free(p);
}

/* An implicit step (examples/heat/heat_backward.npg, backward Euler at 100x the explicit limit):
 * each npg_full_step a Newton solve, the residual at the solution tiny, verbose lines written,
 * a failure named by step; npg_full_set_newton's refusals. */
static void test_implicit_step(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = heat("examples/heat/heat_backward.npg", &p, 25);
  double u[N];
  for (int i = 0; i < N; i++) u[i] = i == 5 ? 2.0 : 0.1 * (i % 3);
  long n = N;
  FILE *log = tmpfile();
  assert_non_null(log);
  assert_int_equal(npg_full_set_newton(f, 1e-10, 30, log), 0);
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u0"), 0);
  assert_int_equal(npg_full_step(f, 5, 0), 0);
  assert_int_equal(npg_full_steps(f), 5);
  size_t count = 0;
  const double *x = npg_full_get(f, "u", &count), *r = npg_full_get(f, "u.residual", NULL);
  assert_int_equal(count, N);
  double sum = 0, sum0 = 0, rn = 0;
  for (int i = 0; i < N; i++) sum += x[i], sum0 += u[i], rn += r[i] * r[i];
  assert_true(fabs(sum - sum0) <= 1e-9 * fabs(sum0)); /* conservative fluxes: the heat is kept */
  assert_true(sqrt(rn) <= 1e-8);
  rewind(log);
  char line[200];
  int lines = 0;
  while (fgets(line, sizeof line, log)) lines += strncmp(line, "newton sample 0 iteration ", 26) == 0;
  assert_true(lines >= 5 * 2);
  fclose(log);
  /* one correction cannot reach 1e-14 of the first residual: the step, iteration and residual named */
  assert_int_equal(npg_full_set_newton(f, 1e-14, 1, NULL), 0);
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u0"), 0);
  assert_int_equal(npg_full_step(f, 3, 0), -1);
  assert_non_null(strstr(npg_full_error(f), "step 1: npg_full_newton: Newton on residual 'u.residual' for 'u.next' "
                                            "did not converge at sample 0: iteration 1, residual "));
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set_newton(f, 0, 30, NULL), -1);
  assert_non_null(strstr(npg_full_error(f), "argument 'tol' is 0"));
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set_newton(f, 1e-10, 0, NULL), -1);
  assert_non_null(strstr(npg_full_error(f), "argument 'max_iter' is 0"));
  assert_int_equal(npg_full_set_newton(NULL, 1e-10, 30, NULL), -1);
  assert_int_equal(npg_reduced_set_newton(NULL, 1e-10, 30, NULL), -1);
  npg_full_free(f);
  npg_free(p);
}

static void test_refusals(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = heat("examples/heat/heat_linear.npg", &p, 0.2);
  assert_int_equal(npg_full_set_blowup(f, 0.5), -1);
  assert_non_null(strstr(npg_full_error(f), "must exceed 1"));
  npg_full_clear_error(f);
  assert_int_equal(npg_full_step(f, -1, 0), -1);
  assert_non_null(strstr(npg_full_error(f), "'steps' is -1"));
  npg_full_clear_error(f);
  assert_int_equal(npg_full_step(f, 1, 0), -1); /* no state set */
  assert_non_null(strstr(npg_full_error(f), "not set"));
  npg_full_clear_error(f);
  NpgRollout bad = {.steps = 3, .every = 0};
  assert_int_equal(npg_full_simulate(f, 0, &bad), -1);
  assert_non_null(strstr(npg_full_error(f), "every"));
  npg_full_free(f);
  npg_free(p);
  /* a program without state */
  p = npg_compile("tests/programs/heat_neighbours.npg", NULL);
  assert_true(npg_ok(p));
  f = npg_full_new(p, NPG_TCC);
  assert_int_equal(npg_full_step(f, 1, 0), -1);
  assert_non_null(strstr(npg_full_error(f), "has no state"));
  npg_full_free(f);
  npg_free(p);
  assert_int_equal(npg_full_step(NULL, 1, 0), -1);
  assert_int_equal(npg_reduced_step(NULL, 1, 0), -1);
}

int main(void) {
  grid();
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_full_rollout_matches_c),
      cmocka_unit_test(test_whole_bases_reduced_equals_full),
      cmocka_unit_test(test_semi_implicit_verified_over_the_trajectory),
      cmocka_unit_test(test_blowup_named),
      cmocka_unit_test(test_implicit_step),
      cmocka_unit_test(test_refusals),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
