/* test_reduced_derivatives.c — npg_reduced_jvp, npg_reduced_vjp and npg_reduced_jacobian
 * through npg.h alone (DESIGN §17), on the semi-implicit heat step
 * (examples/heat/heat_implicit.npg: u' = A(k(u))⁻¹ u, an inverse stage whose operator depends
 * on the state through the inverse stage k): the Jacobian of the next state against central
 * differences of the reduced step (error shrinking as h²), against forward and reverse
 * products (to 1e-12), and the refusals, each naming its argument. Leaks are checked here
 * (the Python tests run without LeakSanitizer). */
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

enum { SIDE = 3, N = SIDE * SIDE, S = 24, CAP = 5 };

static double nbr_d[N * 4];

static NpgModel *trained(NpgProgram **p) {
  for (int i = 0; i < SIDE; i++)
    for (int j = 0; j < SIDE; j++) {
      int c = i * SIDE + j;
      nbr_d[c * 4 + 0] = i > 0 ? c - SIDE : -1;
      nbr_d[c * 4 + 1] = i < SIDE - 1 ? c + SIDE : -1;
      nbr_d[c * 4 + 2] = j > 0 ? c - 1 : -1;
      nbr_d[c * 4 + 3] = j < SIDE - 1 ? c + 1 : -1;
    }
  *p = npg_compile("examples/heat/heat_implicit.npg", NULL);
  assert_true(npg_ok(*p));
  NpgFull *f = npg_full_new(*p, NPG_TCC);
  long shape[2] = {N, 4}, n = N;
  double dt = 0.2;
  assert_int_equal(npg_full_set_param(f, "nbr", 2, shape, nbr_d, "nbr"), 0);
  assert_int_equal(npg_full_set_param(f, "dt", 0, NULL, &dt, "dt"), 0);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = CAP; /* bases smaller than the grid: a reduced Jacobian, not the full one */
  NpgTrainer *t = npg_trainer_new(f, &o);
  uint64_t seed = 7;
  for (long k = 0; k < S; k++) {
    double u[N];
    for (int i = 0; i < N; i++) {
      seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
      u[i] = 1.5 * (double)(seed >> 11) / 9007199254740992.0;
    }
    assert_int_equal(npg_trainer_set(t, "u", 1, &n, u), 0);
    assert_int_equal(npg_trainer_add(t), 0);
  }
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
  npg_full_free(f);
  return m;
}

/* u.next's coordinates at u's coordinates c. */
static void step_at(NpgReduced *r, const double *c, size_t m, double *out) {
  assert_int_equal(npg_reduced_set_coords(r, "u", m, c), 0);
  assert_int_equal(npg_reduced_eval(r, -1), 0);
  size_t mo;
  const double *y = npg_reduced_coords(r, "u.next", &mo);
  memcpy(out, y, sizeof(double) * mo);
}

static void test_jacobian_against_differences_and_products(void **state) {
  (void)state;
  NpgProgram *p;
  NpgModel *model = trained(&p);
  NpgReduced *r = npg_reduced_new(model);
  double u0[N];
  long n = N;
  for (int i = 0; i < N; i++) u0[i] = 0.4 + 0.1 * sin(1.0 + i);
  assert_int_equal(npg_reduced_set(r, "u", (size_t)n, u0), 0);
  assert_int_equal(npg_reduced_eval(r, -1), 0);
  size_t m = 0, mo = 0;
  double c[CAP * 4], J[CAP * CAP * 16], plus[CAP * 4], minus[CAP * 4];
  const double *cu = npg_reduced_coords(r, "u", &m);
  assert_true(cu && m <= (size_t)CAP * 4);
  memcpy(c, cu, sizeof(double) * m);
  npg_reduced_coords(r, "u.next", &mo);
  assert_true(m >= 2 && m == mo && m <= (size_t)CAP * 4);
  assert_int_equal(npg_reduced_jacobian(r, -1, "u.next", "u", J), 0);
  double scale = 0;
  for (size_t e = 0; e < m * m; e++) scale = fmax(scale, fabs(J[e]));
  assert_true(scale > 0.1);
  double err[2] = {0, 0}, hs[2] = {1e-3, 1e-4};
  for (int h = 0; h < 2; h++)
    for (size_t b = 0; b < m; b++) {
      double cp[CAP * 4];
      memcpy(cp, c, sizeof cp);
      cp[b] = c[b] + hs[h];
      step_at(r, cp, m, plus);
      cp[b] = c[b] - hs[h];
      step_at(r, cp, m, minus);
      for (size_t a = 0; a < m; a++)
        err[h] = fmax(err[h], fabs((plus[a] - minus[a]) / (2 * hs[h]) - J[a * m + b]) / scale);
    }
  step_at(r, c, m, plus);
  if (!(err[1] < 1e-7)) fail_msg("finite differences: %.3g at h 1e-3, %.3g at 1e-4 (Jacobian scale %.3g)", err[0], err[1], scale);
  assert_true(err[0] < 1e-11 || err[1] < err[0] / 30); /* O(h²) */
  /* forward and reverse products of unit vectors: J's columns and rows */
  const char *in = "u", *out = "u.next";
  for (size_t b = 0; b < m; b++) {
    double e[CAP * 4] = {0}, col[CAP * 4], row[CAP * 4];
    e[b] = 1;
    const double *dir = e;
    assert_int_equal(npg_reduced_jvp(r, -1, 1, &in, &dir, "u.next", col), 0);
    assert_int_equal(npg_reduced_vjp(r, -1, 1, &out, &dir, "u", row), 0);
    for (size_t a = 0; a < m; a++) {
      assert_true(fabs(col[a] - J[a * m + b]) <= 1e-12 * scale);
      assert_true(fabs(row[a] - J[b * m + a]) <= 1e-12 * scale);
    }
  }
  npg_reduced_free(r);
  npg_model_free(model);
  npg_free(p);
}

static void test_refusals_name_the_argument(void **state) {
  (void)state;
  NpgProgram *p;
  NpgModel *model = trained(&p);
  NpgReduced *r = npg_reduced_new(model);
  double J[CAP * CAP * 16], one[CAP * 4] = {1};
  const char *in = "u", *bad = "nosuch";
  const double *dir = one;
  /* nothing set: the evaluation says which input */
  assert_int_equal(npg_reduced_jacobian(r, -1, "u.next", "u", J), -1);
  assert_non_null(strstr(npg_reduced_error(r), "'u' was never set (npg_reduced_set or npg_reduced_set_coords)"));
  npg_reduced_clear_error(r);
  double u0[N] = {0.5};
  assert_int_equal(npg_reduced_set(r, "u", N, u0), 0);
  assert_int_equal(npg_reduced_jacobian(r, -1, "u.next", "k", J), -1);
  assert_non_null(strstr(npg_reduced_error(r), "npg_reduced_jacobian: argument 'input': 'k' is not an input"));
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_jvp(r, -1, 1, &bad, &dir, "u.next", J), -1);
  assert_non_null(strstr(npg_reduced_error(r), "npg_reduced_jvp: argument 'inputs[0]': the program has no quantity "
                                               "'nosuch'"));
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_jvp(r, -1, 0, &in, &dir, "u.next", J), -1);
  assert_non_null(strstr(npg_reduced_error(r), "npg_reduced_jvp: 0 inputs given"));
  npg_reduced_clear_error(r);
  const double *none = NULL;
  assert_int_equal(npg_reduced_vjp(r, -1, 1, &in, &none, "u", J), -1);
  assert_non_null(strstr(npg_reduced_error(r), "npg_reduced_vjp: argument 'cotangents[0]' is NULL"));
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_jacobian(r, -1, "u.next", "u", NULL), -1);
  assert_non_null(strstr(npg_reduced_error(r), "argument 'out' is NULL"));
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_jacobian(r, -1, "u.next", "u", J), 0); /* usable again */
  npg_reduced_free(r);
  npg_model_free(model);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_jacobian_against_differences_and_products),
      cmocka_unit_test(test_refusals_name_the_argument),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
