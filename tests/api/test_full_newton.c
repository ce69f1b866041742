/* test_full_newton.c — npg_full_newton through npg.h alone (DESIGN §17, implicit steps): a
 * backward-Euler step of a nonlinear 1D heat equation (sparse Jacobian: UMFPACK) solved to its
 * tolerance, its history and verbose lines, the residual vanishing at the returned unknown; a
 * dense Jacobian (LAPACK); and the refusals, each naming its argument, sample and iteration.
 * Leaks are checked here (the Python tests run without LeakSanitizer). */
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

enum { N = 200 }; /* 3 entries a row: 1.5% of the Jacobian's, solved by UMFPACK (dense above 2%) */

/* v − u − dt (k(v) v')' on a line, k(v) = 1/(1 + v²), no flux at the ends */
static const char *HEAT = "dim N\n"
                          "param dt : real\n"
                          "input u : real[N]\n"
                          "input v : real[N]\n"
                          "k[i:N] = 1 / (1 + v[i]^2)\n"
                          "output r[i:N] = v[i] - u[i] - dt * (if(i > 0, 0.5 * (k[i] + k[i - 1]) * (v[i - 1] - v[i]), 0)"
                          " + if(i < N - 1, 0.5 * (k[i] + k[i + 1]) * (v[i + 1] - v[i]), 0))\n";

static NpgFull *heat(NpgProgram **p, double *u) {
  NpgOptions o = {.source = HEAT};
  *p = npg_compile("heat_newton.npg", &o);
  if (!npg_ok(*p)) fail_msg("%s", npg_error(*p));
  NpgFull *f = npg_full_new(*p, NPG_TCC);
  double dt = 50;
  long n = N;
  for (int i = 0; i < N; i++) u[i] = 2 * exp(-(i - 12.0) * (i - 12.0) / 20.0);
  assert_int_equal(npg_full_set_param(f, "dt", 0, NULL, &dt, "dt"), 0);
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u"), 0);
  assert_int_equal(npg_full_set(f, "v", 1, &n, u, "v"), 0);
  return f;
}

static void converges(void **state) {
  (void)state;
  NpgProgram *p;
  double u[N], hist[64];
  NpgFull *f = heat(&p, u);
  char *text = NULL;
  size_t len = 0;
  FILE *log = open_memstream(&text, &len);
  NpgNewton o = {.tol = 1e-12, .max_iter = 20, .verbose = log, .history = hist, .history_cap = 64};
  int rc = npg_full_newton(f, 5, "r", "v", &o);
  fclose(log);
  if (rc) fail_msg("%s", npg_full_error(f));
  assert_true(o.iterations >= 2 && o.iterations < 20);
  assert_true(o.residual <= 1e-12 && o.residual == hist[o.iterations]);
  for (int i = 1; i <= o.iterations; i++) /* quadratic once in the basin */
    if (hist[i - 1] < 0.1 && hist[i] > 1e-13) assert_true(hist[i] <= 10 * hist[i - 1] * hist[i - 1]);
  char first[128];
  snprintf(first, sizeof first, "newton sample 5 iteration 0: |r| = %.3e\n", hist[0]);
  assert_int_equal(strncmp(text, first, strlen(first)), 0);
  int lines = 0;
  for (char *c = text; *c; c++) lines += *c == '\n';
  assert_int_equal(lines, o.iterations + 1);
  free(text);
  size_t n = 0;
  const double *r = npg_full_get(f, "r", &n), *v = npg_full_get(f, "v", NULL);
  double sum_u = 0, sum_v = 0, norm = 0;
  for (size_t i = 0; i < n; i++) sum_u += u[i], sum_v += v[i], norm += r[i] * r[i];
  assert_true(sqrt(norm) <= 1e-12);
  assert_true(fabs(sum_u - sum_v) <= 1e-10); /* no flux at the ends: the total is kept */
  npg_full_free(f);
  npg_free(p);
}

static void dense(void **state) {
  (void)state;
  NpgOptions so = {.source = "dim N\ninput u : real[N]\ninput v : real[N]\nm = sum(j = 0..N-1, v[j]) / N\n"
                             "output r[i:N] = v[i] + 0.5 * v[i]^3 + 2 * m * v[i] - u[i]\n"};
  NpgProgram *p = npg_compile("dense_newton.npg", &so);
  assert_true(npg_ok(p));
  NpgFull *f = npg_full_new(p, NPG_TCC);
  double u[6] = {0.5, 1, 1.5, 0.7, 1.2, 0.9}, v[6] = {0};
  long n = 6;
  assert_int_equal(npg_full_set(f, "u", 1, &n, u, "u"), 0);
  assert_int_equal(npg_full_set(f, "v", 1, &n, v, "v"), 0);
  NpgNewton o = {.tol = 1e-13, .max_iter = 20};
  if (npg_full_newton(f, 0, "r", "v", &o)) fail_msg("%s", npg_full_error(f));
  assert_true(o.residual <= 1e-13);
  npg_full_free(f);
  npg_free(p);
}

static void expect(NpgFull *f, const char *want) {
  if (!strstr(npg_full_error(f), want)) fail_msg("expected '%s' in '%s'", want, npg_full_error(f));
  npg_full_clear_error(f);
}

static void refusals(void **state) {
  (void)state;
  NpgProgram *p;
  double u[N];
  NpgFull *f = heat(&p, u);
  NpgNewton o = {.tol = 1e-30, .max_iter = 1};
  assert_int_equal(npg_full_newton(f, 7, "r", "v", &o), -1);
  expect(f, "npg_full_newton: Newton on residual 'r' for 'v' did not converge at sample 7: iteration 1, residual ");
  assert_int_equal(npg_full_newton(f, 0, "r", "v", NULL), -1);
  expect(f, "npg_full_newton: argument 'o' is NULL");
  o.tol = 1e-10;
  assert_int_equal(npg_full_newton(f, 0, NULL, "v", &o), -1);
  expect(f, "argument 'residual' is NULL");
  assert_int_equal(npg_full_newton(f, 0, "r", "k", &o), -1);
  expect(f, "npg_full_newton: argument 'unknown': 'k' is not an input");
  o.tol = NAN;
  assert_int_equal(npg_full_newton(f, 0, "r", "v", &o), -1);
  expect(f, "npg_full_newton: tolerance nan: it must be positive and finite");
  o.tol = 1e-10, o.max_iter = 0;
  assert_int_equal(npg_full_newton(f, 0, "r", "v", &o), -1);
  expect(f, "npg_full_newton: max_iter 0: at least one iteration");
  npg_full_free(f);
  npg_free(p);
  /* singular at v = 0: r = v² + 1 (diagonal, 0.5% filled: UMFPACK) */
  NpgOptions so = {.source = "dim N\ninput v : real[N]\noutput r[i:N] = v[i]^2 + 1\n"};
  p = npg_compile("singular.npg", &so);
  f = npg_full_new(p, NPG_TCC);
  double z[N] = {0};
  long n = N;
  assert_int_equal(npg_full_set(f, "v", 1, &n, z, "v"), 0);
  o.max_iter = 10;
  assert_int_equal(npg_full_newton(f, 3, "r", "v", &o), -1);
  expect(f, "npg_full_newton: sample 3, iteration 0: the Jacobian of 'r' by 'v' is singular (UMFPACK");
  npg_full_free(f);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {cmocka_unit_test(converges), cmocka_unit_test(dense), cmocka_unit_test(refusals)};
  return cmocka_run_group_tests(tests, NULL, NULL);
}
