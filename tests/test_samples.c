/* test_samples.c — a data directory's samples (compiler/api/samples.c, npg.h NpgSamples):
 * every input and extern as DIR/<name>.npy with a leading sample axis, read once, checked
 * once (float64, the program's static axes, one sample count, no NaN or infinity, each
 * problem named by file, sample and index), then handed to the full evaluator one sample
 * at a time: sample k set is exactly the file's k-th slice. */
#include <math.h>
#include <stdio.h>

#include "support/failing_alloc.h"
#include "testutil.h"

enum { S = 4, NN = 3 };

static const char *program_text = "dim N\n"
                                   "param w : real[N]\n"
                                   "input x : real[N, 2]\n"
                                   "extern v[i:N] of x\n"
                                   "output y[i:N] = (x[i, 0] * x[i, 1] + v[i]) * w[i]\n";

static char data[512], other[512];

static int setup(void **state) {
  (void)state;
  if (scratch_make("test_samples") != 0) return -1;
  scratch_path(data, "DATA");
  scratch_path(other, "OTHER");
  return mkdir(data, 0700) || mkdir(other, 0700);
}

static int teardown(void **state) {
  (void)state;
  failing_alloc_off();
  remove_tree(scratch);
  return 0;
}

static void put(const char *dir, const char *name, int nd, const long *shape, const double *v) {
  char path[1024], err[512];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  if (npg_npy_write(path, nd, shape, v, err, sizeof err) != 0) fail_msg("%s", err);
}

static void rm(const char *dir, const char *name) {
  char path[1024];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  unlink(path);
}

static double xs[S][NN][2], vs[S][NN];

/* DATA/x.npy (S, N, 2) and DATA/v.npy (S, N), every value distinct. */
static void good_files(void) {
  for (int k = 0; k < S; k++)
    for (int i = 0; i < NN; i++) {
      xs[k][i][0] = 1 + k + 0.1 * i, xs[k][i][1] = 2 - 0.01 * k + 0.3 * i, vs[k][i] = 0.5 * k - i;
    }
  put(data, "x", 3, (long[]){S, NN, 2}, &xs[0][0][0]);
  put(data, "v", 2, (long[]){S, NN}, &vs[0][0]);
}

/* The set opens, counts S samples, gives each slice bit for bit, and a sample set into the
 * full evaluator (its extern too) evaluates to the definition. */
static void slices_and_evaluation(void **state) {
  (void)state;
  good_files();
  NpgProgram *p = compile_text("samples.npg", program_text);
  ir_ok(p);
  char err[1024];
  NpgSamples *s = npg_samples_open(p, data, NULL, true, err, sizeof err);
  if (!s) fail_msg("%s", err);
  assert_int_equal(npg_samples_count(s), S);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  double w[NN] = {2, 3, 5};
  assert_int_equal(npg_full_set(f, "w", 1, (long[]){NN}, w, "w"), 0);
  for (long k = 0; k < S; k++) {
    size_t n;
    const double *x = npg_samples_get(s, "x", k, &n);
    assert_non_null(x);
    assert_int_equal(n, NN * 2);
    assert_memory_equal(x, xs[k], sizeof xs[k]);
    const double *v = npg_samples_get(s, "v", k, &n);
    assert_int_equal(n, NN);
    assert_memory_equal(v, vs[k], sizeof vs[k]);
    assert_int_equal(npg_samples_set(s, f, k), 0);
    if (npg_full_eval(f, k) != 0) fail_msg("%s", npg_full_error(f));
    const double *y = npg_full_get(f, "y", &n);
    for (int i = 0; i < NN; i++) assert_true(y[i] == (xs[k][i][0] * xs[k][i][1] + vs[k][i]) * w[i]);
  }
  assert_null(npg_samples_get(s, "x", S, NULL));
  assert_null(npg_samples_get(s, "x", -1, NULL));
  assert_null(npg_samples_get(s, "w", 0, NULL)); /* a param is no sample */
  assert_null(npg_samples_get(s, "nosuch", 0, NULL));
  assert_int_equal(npg_samples_set(s, f, S), -1);
  assert_string_equal(npg_full_error(f), "npg_samples_set: argument 'k' is 4, but the set holds 4 samples (0 to 3)");
  npg_full_free(f);
  npg_samples_free(s);
  /* without externs, v.npy is not read: a missing one is no error */
  rm(data, "v");
  s = npg_samples_open(p, data, NULL, false, err, sizeof err);
  if (!s) fail_msg("%s", err);
  assert_null(npg_samples_get(s, "v", 0, NULL));
  npg_samples_free(s);
  assert_null(npg_samples_open(p, data, NULL, true, err, sizeof err));
  assert_non_null(strstr(err, "/DATA/v.npy"));
  npg_free(p);
}

/* A file missing from DIR is read from the fallback folder (the training data for a test
 * set's externs); one missing from both is named where it was last looked for. */
static void fallback_folder(void **state) {
  (void)state;
  good_files();
  rm(data, "v");
  put(other, "v", 2, (long[]){S, NN}, &vs[0][0]);
  NpgProgram *p = compile_text("samples.npg", program_text);
  ir_ok(p);
  char err[1024];
  NpgSamples *s = npg_samples_open(p, data, other, true, err, sizeof err);
  if (!s) fail_msg("%s", err);
  assert_memory_equal(npg_samples_get(s, "v", 2, NULL), vs[2], sizeof vs[2]);
  npg_samples_free(s);
  rm(other, "v");
  assert_null(npg_samples_open(p, data, other, true, err, sizeof err));
  assert_non_null(strstr(err, "/OTHER/v.npy"));
  npg_free(p);
}

/* Each malformed file refused once, with the file, the problem and where it is. */
static void malformed_files(void **state) {
  (void)state;
  NpgProgram *p = compile_text("samples.npg", program_text);
  ir_ok(p);
  char err[1024], want[2048];
  double big[S * NN * 3] = {0};
  struct {
    const char *what;
    int nd;
    long shape[3];
    const char *message; /* after "<DATA>/x.npy: " */
  } cases[] = {
      {"rank", 2, {S, 6}, "input 'x' needs the shape (samples, N, 2) (a leading sample axis, then its 2 axes), the "
                          "array's shape is (4, 6)"},
      {"static axis", 3, {S, NN, 3}, "axis 1 of 'x' is static with size 2, but axis 2 of the array (after the sample "
                                     "axis) has 3"},
      {"no sample axis", 1, {NN}, "input 'x' needs the shape (samples, N, 2) (a leading sample axis, then its 2 "
                                  "axes), the array's shape is (3,)"},
  };
  for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
    good_files();
    put(data, "x", cases[c].nd, cases[c].shape, big);
    assert_null(npg_samples_open(p, data, NULL, true, err, sizeof err));
    snprintf(want, sizeof want, "%s/x.npy: %s", data, cases[c].message);
    if (strcmp(err, want)) fail_msg("%s: '%s', expected '%s'", cases[c].what, err, want);
  }
  /* a NaN and an infinity named by sample and index */
  good_files();
  xs[2][1][0] = NAN;
  put(data, "x", 3, (long[]){S, NN, 2}, &xs[0][0][0]);
  assert_null(npg_samples_open(p, data, NULL, true, err, sizeof err));
  snprintf(want, sizeof want, "%s/x.npy: input 'x' holds NaN at sample 2, [1, 0]", data);
  assert_string_equal(err, want);
  good_files();
  vs[3][2] = -INFINITY;
  put(data, "v", 2, (long[]){S, NN}, &vs[0][0]);
  assert_null(npg_samples_open(p, data, NULL, true, err, sizeof err));
  snprintf(want, sizeof want, "%s/v.npy: extern 'v' holds an infinity at sample 3, [2]", data);
  assert_string_equal(err, want);
  /* one sample count across the files */
  good_files();
  put(data, "v", 2, (long[]){S - 1, NN}, &vs[0][0]);
  assert_null(npg_samples_open(p, data, NULL, true, err, sizeof err));
  snprintf(want, sizeof want, "%s/x.npy has 4 samples but %s/v.npy has 3", data, data);
  assert_string_equal(err, want);
  /* float64 only */
  good_files();
  char path[1024];
  snprintf(path, sizeof path, "%s/x.npy", data);
  long ix[S * NN * 2] = {0};
  assert_int_equal(npg_npy_write_i64(path, 3, (long[]){S, NN, 2}, ix, err, sizeof err), 0);
  assert_null(npg_samples_open(p, data, NULL, true, err, sizeof err));
  snprintf(want, sizeof want, "%s/x.npy: input 'x' must be float64, the array is int64", data);
  assert_string_equal(err, want);
  npg_free(p);
}

/* Every allocation that fails while a set opens is reported as such, never a crash or a
 * leak; then the set opens whole. */
static void allocation_failure(void **state) {
  (void)state;
  good_files();
  NpgProgram *p = compile_text("samples.npg", program_text);
  ir_ok(p);
  char err[1024];
  int k;
  for (k = 0; k < 100; k++) {
    failing_alloc_after(k);
    NpgSamples *s = npg_samples_open(p, data, NULL, true, err, sizeof err);
    failing_alloc_off();
    if (s) {
      assert_int_equal(npg_samples_count(s), S);
      assert_memory_equal(npg_samples_get(s, "x", 1, NULL), xs[1], sizeof xs[1]);
      npg_samples_free(s);
      break;
    }
    if (!strstr(err, "out of memory")) fail_msg("allocation %d failing: %s", k, err);
  }
  assert_true(k > 0 && k < 100);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(slices_and_evaluation),
      cmocka_unit_test(fallback_folder),
      cmocka_unit_test(malformed_files),
      cmocka_unit_test(allocation_failure),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
