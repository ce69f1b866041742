/* test_verify.c — the auto-check through npg.h (compiler/api/verify.c), through npg.h alone:
 *
 *   - the report: one row per quantity in program order, every sample counted; an input's
 *     error is its projection floor (its reduced coordinates are its projection), an output's
 *     mean error is at least its floor (Bŷ lies in the basis, BBᵀy is the nearest point of
 *     it), `own` their difference; with bases of every direction the output is exact;
 *   - each held-out sample checked before it counts: a value `set` leaves out, a param `set`
 *     changes, a non-finite sample and no samples at all are refused, naming the sample;
 *   - the warnings: none at a tolerance every floor meets, the input named at one it does not.
 *
 *     test_verify      (from the source root)
 */
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

#define N 6
#define S 12

static const char *text = "dim N\n"
                          "param s : real[N]\n"
                          "input x : real[N]\n"
                          "output y[i:N] = s[i] * x[i] * x[i] + x[i]\n";

static double xs[(S + 4) * N], svals[N];

/* Sample k: x from a seeded draw (k >= S: held out). */
static int set_x(void *user, NpgFull *f, long k) {
  (void)user;
  const long shape[1] = {N};
  return npg_full_set(f, "x", 1, shape, xs + N * k, "set_x");
}

typedef struct Fixture {
  NpgProgram *p;
  NpgFull *f;
  NpgModel *m;
} Fixture;

/* The program trained on S samples with caps of `cap`. */
static void fixture(Fixture *fx, int cap) {
  unsigned seed = 7u;
  for (size_t i = 0; i < sizeof xs / sizeof *xs; i++) xs[i] = 0.5 + (double)(seed = seed * 1103515245u + 12345u) / 4294967296.0;
  for (int i = 0; i < N; i++) svals[i] = 1.0 + 0.25 * i;
  NpgOptions o = {0};
  o.source = text;
  fx->p = npg_compile("verify.npg", &o);
  if (!npg_ok(fx->p)) fail_msg("%s", npg_error(fx->p));
  fx->f = npg_full_new(fx->p, NPG_TCC);
  const long shape[1] = {N};
  assert_int_equal(npg_full_set_param(fx->f, "s", 1, shape, svals, "s"), 0);
  NpgTrainOptions to;
  npg_train_options_default(&to);
  to.cap = cap;
  to.energy = 1.0;
  NpgTrainer *t = npg_trainer_new(fx->f, &to);
  for (long k = 0; k < S; k++) {
    assert_int_equal(set_x(NULL, fx->f, k), 0);
    assert_int_equal(npg_full_eval(fx->f, k), 0);
    if (npg_trainer_add_full(t, fx->f) != 0) fail_msg("%s", npg_trainer_error(t));
  }
  fx->m = npg_trainer_finish(t, NULL);
  if (!fx->m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
}

static void fixture_free(Fixture *fx) {
  npg_model_free(fx->m);
  npg_full_free(fx->f);
  npg_free(fx->p);
}

/* Held-out samples S.. S+3. */
static int set_held(void *user, NpgFull *f, long k) { return set_x(user, f, S + k); }

static const NpgVerifyRow *row(const NpgVerifyReport *r, const char *name) {
  for (int i = 0; i < r->nrows; i++)
    if (strcmp(r->rows[i].name, name) == 0) return &r->rows[i];
  fail_msg("no row %s", name);
  return NULL;
}

static void report_rows(void **state) {
  (void)state;
  Fixture fx;
  fixture(&fx, 2);
  NpgVerifyReport r;
  assert_int_equal(npg_verify(fx.m, fx.f, 4, set_held, NULL, false, &r), 0);
  assert_int_equal(r.samples, 4);
  assert_int_equal(r.nrows, 2);
  assert_string_equal(r.rows[0].name, "x");
  assert_string_equal(r.rows[1].name, "y");
  const NpgVerifyRow *x = row(&r, "x"), *y = row(&r, "y");
  print_message("caps 2: x error %.6g floor %.6g; y error %.6g floor %.6g own %.6g\n", x->l2, x->floor, y->l2, y->floor,
                y->own);
  assert_false(x->output);
  assert_true(y->output);
  assert_int_equal(x->m, 2);
  assert_true(x->floor > 1e-3);                     /* truncated: something to measure */
  assert_true(fabs(x->l2 - x->floor) <= 1e-12 * x->floor + 1e-15);
  assert_true(y->l2 >= y->floor * (1 - 1e-12));
  assert_true(fabs(y->own - (y->l2 - y->floor)) <= 1e-12 * y->l2);
  assert_true(y->l2_max >= y->l2 * (1 - 1e-12) && y->l2_max_sample >= 0 && y->l2_max_sample < 4);
  npg_verify_free(&r);
  npg_verify_free(&r); /* twice: nothing left to free */
  fixture_free(&fx);

  fixture(&fx, N); /* every direction: y = s x² + x is exact in the reduced coordinates of x */
  assert_int_equal(npg_verify(fx.m, fx.f, 4, set_held, NULL, false, &r), 0);
  y = row(&r, "y");
  print_message("caps %d: y error %.3g\n", N, y->l2);
  assert_true(y->l2 < 1e-10);
  npg_verify_free(&r);
  fixture_free(&fx);
}

static int set_nothing(void *user, NpgFull *f, long k) {
  (void)user, (void)f, (void)k;
  return 0;
}

static int set_param_too(void *user, NpgFull *f, long k) {
  static double other[N] = {9, 9, 9, 9, 9, 9};
  const long shape[1] = {N};
  return set_x(user, f, S + k) || (k == 1 && npg_full_set_param(f, "s", 1, shape, other, "other"));
}

static int set_infinite(void *user, NpgFull *f, long k) {
  double bad[N];
  memcpy(bad, xs + N * (S + k), sizeof bad);
  if (k == 2) bad[3] = 1e200; /* finite, its square not */
  const long shape[1] = {N};
  (void)user;
  return npg_full_set(f, "x", 1, shape, bad, "set_infinite");
}

static void samples_checked(void **state) {
  (void)state;
  Fixture fx;
  fixture(&fx, 2);
  NpgVerifyReport r;
  assert_int_equal(npg_verify(fx.m, fx.f, 4, set_nothing, NULL, false, &r), -1);
  print_message("left out: %s\n", r.error);
  assert_non_null(strstr(r.error, "test sample 0"));
  assert_non_null(strstr(r.error, "'x'"));
  assert_int_equal(r.samples, 0);
  npg_verify_free(&r);

  npg_full_clear_error(fx.f);
  assert_int_equal(npg_verify(fx.m, fx.f, 4, set_param_too, NULL, false, &r), -1);
  print_message("param changed: %s\n", r.error);
  assert_non_null(strstr(r.error, "'s'"));
  npg_verify_free(&r);
  const long shape[1] = {N};
  assert_int_equal(npg_full_set_param(fx.f, "s", 1, shape, svals, "s"), 0);

  npg_full_clear_error(fx.f);
  assert_int_equal(npg_verify(fx.m, fx.f, 4, set_infinite, NULL, false, &r), -1);
  print_message("infinite: %s\n", r.error);
  assert_non_null(strstr(r.error, "sample 2"));
  npg_verify_free(&r);

  npg_full_clear_error(fx.f);
  assert_int_equal(npg_verify(fx.m, fx.f, 0, set_held, NULL, false, &r), -1);
  assert_string_equal(r.error, "no samples to verify on");
  npg_verify_free(&r);
  fixture_free(&fx);
}

static void warnings(void **state) {
  (void)state;
  Fixture fx;
  fixture(&fx, 2);
  NpgVerifyReport r;
  assert_int_equal(npg_verify(fx.m, fx.f, 4, set_held, NULL, false, &r), 0);
  FILE *out = tmpfile();
  assert_non_null(out);
  assert_int_equal(npg_verify_warnings(fx.m, &r, 10.0, out), 0);
  int n = npg_verify_warnings(fx.m, &r, 1e-9, out);
  char text_out[8192] = "";
  rewind(out);
  size_t len = fread(text_out, 1, sizeof text_out - 1, out);
  text_out[len] = 0;
  fclose(out);
  print_message("%d warnings at 1e-9:\n%s", n, text_out);
  assert_true(n >= 1);
  assert_non_null(strstr(text_out, "x"));
  npg_verify_free(&r);
  fixture_free(&fx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(report_rows),
      cmocka_unit_test(samples_checked),
      cmocka_unit_test(warnings),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
