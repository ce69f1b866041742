/* test_api_args.c — the public API's arguments and failure paths, through
 * npg.h alone: every npg_ function refuses a NULL argument with a message
 * naming the function and the argument (never a crash); training options
 * out of range are refused naming the field; a reduced input never set, a
 * lift before any evaluation, a negative exactness size, a NaN tuning
 * tolerance, an out-of-range sample are errors; an evaluator whose JIT
 * compilation failed (no C compiler, an unusable TMPDIR) is freed without
 * a crash; a program path holding a comment closer and constants folding
 * to infinities compile; a member name longer than its spectrum's CSV
 * buffer is written whole. An extern without a callback left out of a sample is refused (issue
 * 38), and a refused sample leaves the trainer usable.
 *
 *     test_api_args      (from the source root: it writes under /tmp)
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "npg.h"

static char scratch[256];

/* Eq. 3 of the paper: a small program with an inverse stage. */
static const char *eq3 = "input  x : real[2]\n"
                         "output y = [ (x[0]*x[1] + x[1]^2) / x[0]^2,  x[0]^2 / x[1]^2 ]\n";

static NpgProgram *compile_text(const char *name, const char *text) {
  NpgOptions o = {0};
  o.source = text;
  NpgProgram *p = npg_compile(name, &o);
  if (!npg_ok(p)) fail_msg("%s", npg_error(p));
  return p;
}

/* `msg` holds "FUNC: argument 'ARG' is NULL". */
static void refused(const char *msg, const char *func, const char *arg) {
  char want[256];
  snprintf(want, sizeof want, "%s: argument '%s' is NULL", func, arg);
  if (!msg || !strstr(msg, want)) fail_msg("expected \"%s\", got \"%s\"", want, msg ? msg : "(null)");
}

/* `msg` contains `part`. */
static void says(const char *msg, const char *part) {
  if (!msg || !strstr(msg, part)) fail_msg("expected \"%s\" in \"%s\"", part, msg ? msg : "(null)");
}

/* The thread's last refusal: what an error getter returns for a NULL object. */
static const char *last(void) { return npg_full_error(NULL); }

static double xs[2 * 40];

static void fill_samples(void) {
  srand(3);
  for (int k = 0; k < 2 * 40; k++) xs[k] = 0.5 + (double)rand() / RAND_MAX;
}

/* A model of Eq. 3 trained on `S` samples through `f` (into `dir` when non-NULL),
 * every stage by Galerkin (no held-out choice: these tests are of its evaluator). */
static NpgModel *train(NpgFull *f, long S, const char *dir) {
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.valid_holdout = 0;
  NpgTrainer *t = npg_trainer_new(f, &o);
  const long shape[1] = {2};
  for (long k = 0; k < S; k++) {
    assert_int_equal(npg_full_set(f, "x", 1, shape, xs + 2 * (k % 40), "sim"), 0);
    assert_int_equal(npg_full_eval(f, k), 0);
    assert_int_equal(npg_trainer_add_full(t, f), 0);
  }
  NpgModel *m = npg_trainer_finish(t, dir);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
  return m;
}

static int set_x(void *user, NpgFull *f, long k) {
  (void)user;
  const long shape[1] = {2};
  return npg_full_set(f, "x", 1, shape, xs + 2 * (k % 40), "set_x");
}

/* ---------------------------------------------------------------- NULL arguments */

static void null_program_and_full(void **state) {
  (void)state;
  NpgProgram *p0 = npg_compile(NULL, NULL);
  assert_false(npg_ok(p0));
  refused(npg_error(p0), "npg_compile", "path");
  npg_free(p0);

  npg_report(NULL, stdout, false);
  refused(last(), "npg_report", "p");
  assert_int_equal(npg_emit_full(NULL, stdout), -1);
  refused(last(), "npg_emit_full", "p");
  NpgProgram *p = compile_text("eq3.npg", eq3);
  npg_report(p, NULL, false);
  refused(last(), "npg_report", "out");
  assert_int_equal(npg_emit_full(p, NULL), -1);
  refused(npg_error(p), "npg_emit_full", "out");
  assert_int_equal(npg_nsymbols(NULL), 0);
  refused(last(), "npg_nsymbols", "np");
  NpgSymbol sym;
  assert_int_equal(npg_symbol(NULL, 0, &sym), -1);
  refused(last(), "npg_symbol", "np");
  assert_int_equal(npg_symbol(p, 0, NULL), -1);
  refused(last(), "npg_symbol", "out");
  npg_progress(true, NULL, 1, 2);
  refused(last(), "npg_progress", "what");

  NpgFull *f0 = npg_full_new(NULL, NPG_TCC);
  refused(npg_full_error(f0), "npg_full_new", "p");
  npg_full_clear_error(f0); /* an evaluator without a program keeps its error */
  refused(npg_full_error(f0), "npg_full_new", "p");
  const long shape[1] = {2};
  assert_int_equal(npg_full_set(f0, "x", 1, shape, xs, "a"), -1);
  assert_null(npg_full_get(f0, "x", NULL));
  assert_int_equal(npg_full_dim(f0, "x"), -1);
  npg_full_unbind(f0);
  npg_full_free(f0);
  NpgFull *fb = npg_full_new(p, (NpgBackend)7);
  says(npg_full_error(fb), "npg_full_new: argument 'backend' is 7");
  npg_full_free(fb);

  NpgFull *f = npg_full_new(p, NPG_TCC);
  assert_string_equal(npg_full_error(f), "");
  npg_full_clear_error(NULL);
  npg_full_unbind(NULL);
  npg_full_free(NULL);
  assert_int_equal(npg_full_bind_params(NULL, "D"), -1);
  refused(npg_full_error(NULL), "npg_full_bind_params", "f");
  assert_int_equal(npg_full_bind_params(f, NULL), -1);
  refused(npg_full_error(f), "npg_full_bind_params", "data_dir");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, NULL, 1, shape, xs, "a"), -1);
  refused(npg_full_error(f), "npg_full_set", "name");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, "x", 1, NULL, xs, "a"), -1);
  refused(npg_full_error(f), "npg_full_set", "shape");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, "x", 1, shape, NULL, "a"), -1);
  refused(npg_full_error(f), "npg_full_set", "values");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, "x", 1, shape, xs, NULL), -1);
  refused(npg_full_error(f), "npg_full_set", "from");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, "x", -1, shape, xs, "a"), -1);
  says(npg_full_error(f), "npg_full_set: argument 'ndim' is -1");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(NULL, "x", 1, shape, xs, "a"), -1);
  refused(last(), "npg_full_set", "f");
  assert_int_equal(npg_full_set_param(f, NULL, 1, shape, xs, "a"), -1);
  refused(npg_full_error(f), "npg_full_set_param", "name");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set_extern_fn(f, NULL, NULL, NULL), -1);
  refused(npg_full_error(f), "npg_full_set_extern_fn", "name");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_eval(NULL, 0), -1);
  refused(last(), "npg_full_eval", "f");
  assert_null(npg_full_get(NULL, "x", NULL));
  refused(last(), "npg_full_get", "f");
  assert_null(npg_full_get(f, NULL, NULL));
  refused(last(), "npg_full_get", "name");
  assert_int_equal(npg_full_dim(NULL, "N"), -1);
  assert_int_equal(npg_full_dim(f, NULL), -1);
  refused(last(), "npg_full_dim", "name");
  assert_int_equal(npg_full_check_finite(NULL, 0), -1);
  refused(last(), "npg_full_check_finite", "f");
  NpgCsr K;
  assert_int_equal(npg_full_op(NULL, "M", &K), -1);
  refused(last(), "npg_full_op", "f");
  assert_int_equal(npg_full_op(f, "M", NULL), -1);
  refused(npg_full_error(f), "npg_full_op", "out");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_op(f, NULL, &K), -1);
  refused(npg_full_error(f), "npg_full_op", "name");
  npg_full_clear_error(f);
  npg_csr_free(NULL);

  char err[512] = "";
  assert_int_equal(npg_npy_write(NULL, 1, shape, xs, err, sizeof err), -1);
  refused(err, "npg_npy_write", "path");
  char path[512];
  snprintf(path, sizeof path, "%s/a.npy", scratch);
  assert_int_equal(npg_npy_write(path, 1, NULL, xs, err, sizeof err), -1);
  refused(err, "npg_npy_write", "shape");
  assert_int_equal(npg_npy_write_i64(path, 1, NULL, NULL, err, sizeof err), -1);
  refused(err, "npg_npy_write_i64", "shape");

  assert_null(npg_samples_open(NULL, "D", NULL, true, err, sizeof err));
  refused(err, "npg_samples_open", "p");
  assert_null(npg_samples_open(p, NULL, NULL, true, err, sizeof err));
  refused(err, "npg_samples_open", "dir");
  assert_int_equal(npg_samples_count(NULL), -1);
  refused(last(), "npg_samples_count", "s");
  assert_null(npg_samples_get(NULL, "x", 0, NULL));
  refused(last(), "npg_samples_get", "s");
  assert_int_equal(npg_samples_set(NULL, f, 0), -1);
  refused(npg_full_error(f), "npg_samples_set", "samples");
  npg_full_clear_error(f);
  assert_int_equal(npg_samples_set(NULL, NULL, 0), -1);
  refused(last(), "npg_samples_set", "f");
  assert_int_equal(npg_samples_bind_dims(NULL, f), -1);
  refused(npg_full_error(f), "npg_samples_bind_dims", "s");
  npg_full_clear_error(f);
  assert_int_equal(npg_samples_bind_dims(NULL, NULL), -1);
  refused(last(), "npg_samples_bind_dims", "f");
  npg_samples_free(NULL);
  npg_full_free(f);
  npg_free(p);

  /* no entries: NULL values are fine (fuzz_api found memcpy(q, NULL, 0), UB) */
  p = compile_text("dim.npg", "dim N\ninput x : real[N]\noutput y[i:N] = x[i] * x[i]\n");
  f = npg_full_new(p, NPG_TCC);
  const long zero[1] = {0};
  assert_int_equal(npg_full_set(f, "x", 1, zero, NULL, "empty"), 0);
  assert_int_equal(npg_full_eval(f, 0), 0);
  npg_full_free(f);
  npg_free(p);
}

static void null_training_and_models(void **state) {
  (void)state;
  NpgProgram *p = compile_text("eq3.npg", eq3);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  npg_train_options_default(NULL);
  refused(last(), "npg_train_options_default", "o");
  NpgTrainer *t0 = npg_trainer_new(NULL, NULL);
  refused(npg_trainer_error(t0), "npg_trainer_new", "f");
  assert_int_equal(npg_trainer_add(t0), -1);
  assert_null(npg_trainer_finish(t0, NULL));
  npg_trainer_free(t0);
  assert_int_equal(npg_trainer_add(NULL), -1);
  refused(npg_trainer_error(NULL), "npg_trainer_add", "t");
  assert_int_equal(npg_trainer_samples(NULL), -1);
  refused(last(), "npg_trainer_samples", "t");
  assert_null(npg_trainer_finish(NULL, "M"));
  refused(last(), "npg_trainer_finish", "t");
  NpgTrainer *t = npg_trainer_new(f, NULL);
  const long shape[1] = {2};
  assert_int_equal(npg_trainer_set(NULL, "x", 1, shape, xs), -1);
  refused(last(), "npg_trainer_set", "t");
  assert_int_equal(npg_trainer_set(t, NULL, 1, shape, xs), -1);
  refused(npg_trainer_error(t), "npg_trainer_set", "name");
  npg_trainer_free(t);
  t = npg_trainer_new(f, NULL);
  assert_int_equal(npg_trainer_add_full(t, NULL), -1);
  refused(npg_trainer_error(t), "npg_trainer_add_full", "g");
  npg_trainer_free(t);
  npg_trainer_free(NULL);
  /* npg_trainer_dots: every pointer, then a name that is no input, a wrong count, no samples */
  double dots[4];
  assert_int_equal(npg_trainer_dots(NULL, "x", 2, xs, dots), -1);
  refused(last(), "npg_trainer_dots", "t");
  const char *const dot_args[3] = {"name", "values", "dots"};
  for (int a = 0; a < 3; a++) {
    t = npg_trainer_new(f, NULL);
    assert_int_equal(npg_trainer_dots(t, a == 0 ? NULL : "x", 2, a == 1 ? NULL : xs, a == 2 ? NULL : dots), -1);
    refused(npg_trainer_error(t), "npg_trainer_dots", dot_args[a]);
    npg_trainer_free(t);
  }
  t = npg_trainer_new(f, NULL);
  assert_int_equal(npg_trainer_dots(t, "x", 2, xs, dots), -1);
  says(npg_trainer_error(t), "no training samples were added");
  npg_trainer_free(t);
  t = npg_trainer_new(f, NULL);
  assert_int_equal(npg_trainer_set(t, "x", 1, shape, xs) || npg_trainer_add(t), 0);
  assert_int_equal(npg_trainer_dots(t, "zz", 2, xs, dots), -1);
  says(npg_trainer_error(t), "no input or extern 'zz'");
  npg_trainer_free(t);
  t = npg_trainer_new(f, NULL);
  assert_int_equal(npg_trainer_set(t, "x", 1, shape, xs) || npg_trainer_add(t), 0);
  assert_int_equal(npg_trainer_dots(t, "x", 3, xs, dots), -1);
  says(npg_trainer_error(t), "'x' has 2 entries a sample, 3 were given");
  npg_trainer_free(t);
  t = npg_trainer_new(f, NULL);
  double bad[2] = {1, NAN};
  assert_int_equal(npg_trainer_set(t, "x", 1, shape, xs) || npg_trainer_add(t), 0);
  assert_int_equal(npg_trainer_dots(t, "x", 2, bad, dots), -1);
  says(npg_trainer_error(t), "NaN at flat entry 1");
  npg_trainer_free(t);
  t = npg_trainer_new(f, NULL); /* two samples: the dots are the inner products with each */
  assert_int_equal(npg_trainer_set(t, "x", 1, shape, xs) || npg_trainer_add(t) ||
                       npg_trainer_set(t, "x", 1, shape, xs + 2) || npg_trainer_add(t), 0);
  assert_int_equal(npg_trainer_dots(t, "x", 2, xs + 4, dots), 0);
  for (int k = 0; k < 2; k++) assert_true(fabs(dots[k] - (xs[2 * k] * xs[4] + xs[2 * k + 1] * xs[5])) <= 1e-15 * 4);
  npg_trainer_free(t);

  NpgModel *m = train(f, 20, NULL);
  npg_model_train_seconds(m, NULL, NULL);
  refused(last(), "npg_model_train_seconds", "seconds");
  NpgModel *m0 = npg_model_load(NULL, "M");
  refused(npg_model_error(m0), "npg_model_load", "p");
  npg_model_free(m0);
  m0 = npg_model_load(p, NULL);
  refused(npg_model_error(m0), "npg_model_load", "dir");
  npg_model_free(m0);
  npg_model_free(NULL);
  assert_int_equal(npg_model_save(NULL, "M"), -1);
  refused(npg_model_error(NULL), "npg_model_save", "nm");
  assert_int_equal(npg_model_save(m, NULL), -1);
  refused(npg_model_error(m), "npg_model_save", "dir");
  npg_model_report(NULL, stdout);
  refused(last(), "npg_model_report", "nm");
  npg_model_report(m, NULL);
  refused(last(), "npg_model_report", "out");
  char err[512] = "";
  assert_int_equal(npg_model_write_spectra(NULL, "S", err, sizeof err), -1);
  refused(err, "npg_model_write_spectra", "nm");
  assert_int_equal(npg_model_write_spectra(m, NULL, err, sizeof err), -1);
  refused(err, "npg_model_write_spectra", "dir");
  NpgSpectrum *sp;
  int nsp;
  assert_int_equal(npg_spectra_read(NULL, &sp, &nsp, err, sizeof err), -1);
  refused(err, "npg_spectra_read", "dir");
  assert_int_equal(npg_spectra_read("M", NULL, &nsp, err, sizeof err), -1);
  refused(err, "npg_spectra_read", "out");
  assert_int_equal(npg_spectra_read("M", &sp, NULL, err, sizeof err), -1);
  refused(err, "npg_spectra_read", "count");
  npg_spectra_free(NULL, 0);
  assert_int_equal(npg_model_nclasses(NULL), -1);
  refused(last(), "npg_model_nclasses", "nm");
  NpgClassInfo ci;
  NpgMemberInfo mi;
  assert_int_equal(npg_model_class(NULL, 0, &ci), -1);
  assert_int_equal(npg_model_class(m, 0, NULL), -1);
  refused(last(), "npg_model_class", "out");
  assert_int_equal(npg_model_member(NULL, 0, 0, &mi), -1);
  assert_int_equal(npg_model_member(m, 0, 0, NULL), -1);
  refused(last(), "npg_model_member", "out");
  assert_int_equal(npg_model_class_of(NULL, "x"), -1);
  assert_int_equal(npg_model_class_of(m, NULL), -1);
  refused(last(), "npg_model_class_of", "quantity");
  assert_null(npg_model_basis(NULL, 0));
  refused(last(), "npg_model_basis", "nm");
  long cs = 7;
  assert_null(npg_model_coefficients(NULL, 0, &cs));
  refused(last(), "npg_model_coefficients", "nm");
  assert_int_equal(cs, 0);
  assert_null(npg_model_coefficients(m, 0, NULL)); /* a class with its basis: no coefficients */
  assert_null(npg_model_coefficients(m, 99, &cs));
  size_t tb = 7;
  assert_int_equal(npg_model_bytes(NULL, &tb), 0);
  assert_int_equal(tb, 0);
  assert_int_equal(npg_model_samples(NULL), -1);
  assert_int_equal(npg_model_dim(NULL, "N"), -1);
  assert_int_equal(npg_model_dim(m, NULL), -1);
  refused(last(), "npg_model_dim", "name");
  assert_int_equal(npg_model_check_params(NULL, f, err, sizeof err), -1);
  refused(err, "npg_model_check_params", "nm");
  assert_int_equal(npg_model_check_params(m, NULL, err, sizeof err), -1);
  refused(err, "npg_model_check_params", "f");
  assert_int_equal(npg_model_check_params_dir(m, NULL, err, sizeof err), -1);
  refused(err, "npg_model_check_params_dir", "dir");
  assert_int_equal(npg_full_check_params_dir(NULL, "D", err, sizeof err), -1);
  refused(err, "npg_full_check_params_dir", "f");
  assert_int_equal(npg_full_check_params_dir(f, NULL, err, sizeof err), -1);
  refused(err, "npg_full_check_params_dir", "dir");
  assert_int_equal(npg_model_emit(NULL, stdout, err, sizeof err), -1);
  refused(err, "npg_model_emit", "nm");
  assert_int_equal(npg_model_emit(m, NULL, err, sizeof err), -1);
  refused(err, "npg_model_emit", "out");

  /* reduced evaluation */
  NpgReduced *r0 = npg_reduced_new(NULL);
  refused(npg_reduced_error(r0), "npg_reduced_new", "m");
  npg_reduced_clear_error(r0);
  refused(npg_reduced_error(r0), "npg_reduced_new", "m");
  assert_int_equal(npg_reduced_eval(r0, 0), -1);
  npg_reduced_free(r0);
  NpgReduced *r = npg_reduced_new(m);
  assert_string_equal(npg_reduced_error(r), "");
  assert_int_equal(npg_reduced_set(NULL, "x", 2, xs), -1);
  refused(npg_reduced_error(NULL), "npg_reduced_set", "r");
  assert_int_equal(npg_reduced_set(r, NULL, 2, xs), -1);
  refused(npg_reduced_error(r), "npg_reduced_set", "name");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_set(r, "x", 2, NULL), -1);
  refused(npg_reduced_error(r), "npg_reduced_set", "values");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_set_coords(r, "x", 2, NULL), -1);
  refused(npg_reduced_error(r), "npg_reduced_set_coords", "coords");
  npg_reduced_clear_error(r);
  npg_reduced_given_externs(NULL, true);
  refused(last(), "npg_reduced_given_externs", "r");
  npg_reduced_exact_roots(NULL, true);
  refused(last(), "npg_reduced_exact_roots", "r");
  npg_reduced_clear_error(NULL);
  assert_int_equal(npg_reduced_eval(NULL, 0), -1);
  refused(last(), "npg_reduced_eval", "r");
  assert_null(npg_reduced_coords(NULL, "x", NULL));
  assert_null(npg_reduced_coords(r, NULL, NULL));
  refused(last(), "npg_reduced_coords", "name");
  double out[64];
  assert_int_equal(npg_reduced_lift(r, NULL, out, 2), -1);
  refused(npg_reduced_error(r), "npg_reduced_lift", "name");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_lift(r, "y", NULL, 2), -1);
  refused(npg_reduced_error(r), "npg_reduced_lift", "out");
  npg_reduced_clear_error(r);
  long rows, cols;
  assert_int_equal(npg_reduced_op(r, "M", out, 64, NULL, &cols, NULL, NULL), -1);
  refused(npg_reduced_error(r), "npg_reduced_op", "rows");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_op(NULL, "M", out, 64, &rows, &cols, NULL, NULL), -1);
  refused(last(), "npg_reduced_op", "r");
  npg_reduced_free(NULL);
  npg_reduced_free(r);

  /* verification and tuning */
  NpgVerifyReport vr;
  assert_int_equal(npg_verify(NULL, f, 2, set_x, NULL, false, &vr), -1);
  refused(vr.error, "npg_verify", "nm");
  assert_int_equal(npg_verify(m, NULL, 2, set_x, NULL, false, &vr), -1);
  refused(vr.error, "npg_verify", "f");
  assert_int_equal(npg_verify(m, f, 2, NULL, NULL, false, &vr), -1);
  refused(vr.error, "npg_verify", "set");
  assert_int_equal(npg_verify(m, f, 2, set_x, NULL, false, NULL), -1);
  refused(last(), "npg_verify", "rep");
  npg_verify_free(NULL);
  assert_int_equal(npg_verify_warnings(NULL, &vr, 0.1, stdout), 0);
  assert_int_equal(npg_verify_warnings(m, NULL, 0.1, stdout), 0);
  refused(last(), "npg_verify_warnings", "rep");
  assert_int_equal(npg_verify_exact(NULL, 3, NPG_TCC, false, stdout, err, sizeof err), -1);
  refused(err, "npg_verify_exact", "p");
  assert_int_equal(npg_verify_exact(p, 3, NPG_TCC, false, NULL, err, sizeof err), -1);
  refused(err, "npg_verify_exact", "out");
  NpgTuneReport tr;
  assert_null(npg_tune(NULL, 4, set_x, NULL, 4, set_x, NULL, 0.1, 4, NULL, &tr));
  refused(tr.error, "npg_tune", "f");
  npg_tune_free(&tr);
  assert_null(npg_tune(f, 4, NULL, NULL, 4, set_x, NULL, 0.1, 4, NULL, &tr));
  refused(tr.error, "npg_tune", "train");
  npg_tune_free(&tr);
  assert_null(npg_tune(f, 4, set_x, NULL, 4, NULL, NULL, 0.1, 4, NULL, &tr));
  refused(tr.error, "npg_tune", "valid");
  npg_tune_free(&tr);
  assert_null(npg_tune(f, 4, set_x, NULL, 4, set_x, NULL, 0.1, 4, NULL, NULL));
  refused(last(), "npg_tune", "rep");
  npg_tune_free(NULL);

  npg_model_free(m);
  npg_full_free(f);
  npg_free(p);
}

/* ---------------------------------------------------------------- values out of range */

static void train_options_refused(void **state) {
  (void)state;
  NpgProgram *p = compile_text("eq3.npg", eq3);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  static const char *const cases[] = {
      "NpgTrainOptions.cap is 0",      "NpgTrainOptions.cap is -3",    "NpgTrainOptions.energy is 0",
      "NpgTrainOptions.energy is 1.5", "NpgTrainOptions.energy is nan", "NpgTrainOptions.energy is -0.5",
      "NpgTrainOptions.mem is 0",      "NpgTrainOptions.nbasis is -1",
      "NpgTrainOptions.nbasis is 1 but basis_name is NULL",
  };
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    NpgTrainOptions o;
    npg_train_options_default(&o);
    switch (i) {
    case 0: o.cap = 0; break;
    case 1: o.cap = -3; break;
    case 2: o.energy = 0; break;
    case 3: o.energy = 1.5; break;
    case 4: o.energy = NAN; break;
    case 5: o.energy = -0.5; break;
    case 6: o.mem = 0; break;
    case 7: o.nbasis = -1; break;
    case 8: o.nbasis = 1; break;
    }
    NpgTrainer *t = npg_trainer_new(f, &o);
    says(npg_trainer_error(t), "npg_trainer_new: ");
    says(npg_trainer_error(t), cases[i]);
    npg_trainer_free(t);
  }
  /* an override out of range, named by its index and quantity */
  NpgTrainOptions o;
  npg_train_options_default(&o);
  const char *names[1] = {"y"};
  int caps[1] = {0};
  double energies[1] = {-1};
  o.nbasis = 1;
  o.basis_name = names;
  o.basis_cap = caps;
  o.basis_energy = energies;
  NpgTrainer *t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "NpgTrainOptions.basis_cap[0] (y) is 0");
  npg_trainer_free(t);
  caps[0] = -1;
  energies[0] = 2;
  t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "NpgTrainOptions.basis_energy[0] (y) is 2");
  npg_trainer_free(t);
  energies[0] = 0.99; /* valid: the trainer works */
  t = npg_trainer_new(f, &o);
  assert_string_equal(npg_trainer_error(t), "");
  npg_trainer_free(t);
  npg_full_free(f);
  npg_free(p);
}

/* npg_reduced_lift_many: every sample's coordinates lifted in one pass
 * give what npg_reduced_lift gives for each (to rounding); bad arguments
 * are refused naming the argument. */
static void reduced_lift_many(void **state) {
  (void)state;
  NpgProgram *p = compile_text("eq3.npg", eq3);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgModel *m = train(f, 20, NULL);
  NpgReduced *r = npg_reduced_new(m);
  enum { S = 5 };
  size_t my = 0;
  double coords[S * 2], one[S][2], many[S * 2];
  for (int k = 0; k < S; k++) {
    double x[2] = {0.6 + 0.2 * k, 1.4 - 0.15 * k};
    assert_int_equal(npg_reduced_set(r, "x", 2, x), 0);
    assert_int_equal(npg_reduced_eval(r, k), 0);
    const double *c = npg_reduced_coords(r, "y", &my);
    assert_true(my >= 1 && my <= 2);
    memcpy(coords + k * my, c, sizeof(double) * my);
    assert_int_equal(npg_reduced_lift(r, "y", one[k], 2), 0);
  }
  assert_int_equal(npg_reduced_lift_many(r, "y", S, my, coords, many, 2), 0);
  for (int k = 0; k < S; k++)
    for (int i = 0; i < 2; i++) assert_true(fabs(many[2 * k + i] - one[k][i]) <= 1e-14 * (1 + fabs(one[k][i])));
  /* the bad arguments */
  assert_int_equal(npg_reduced_lift_many(r, "y", S, my, NULL, many, 2), -1);
  refused(npg_reduced_error(r), "npg_reduced_lift_many", "coords");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_lift_many(r, "y", 0, my, coords, many, 2), -1);
  says(npg_reduced_error(r), "'samples' is 0");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_lift_many(r, "y", S, my + 1, coords, many, 2), -1);
  says(npg_reduced_error(r), "reduced coordinates");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_lift_many(r, "y", S, my, coords, many, 3), -1);
  says(npg_reduced_error(r), "'y' has 2 entries");
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_lift_many(r, "nosuch", S, my, coords, many, 2), -1);
  says(npg_reduced_error(r), "no quantity 'nosuch'");
  npg_reduced_clear_error(r);
  coords[my * 3] = NAN;
  assert_int_equal(npg_reduced_lift_many(r, "y", S, my, coords, many, 2), -1);
  says(npg_reduced_error(r), "NaN at sample 3, entry 0");
  npg_reduced_free(r);
  npg_model_free(m);
  npg_full_free(f);
  npg_free(p);
}

static void reduced_order_of_calls(void **state) {
  (void)state;
  NpgProgram *p = compile_text("eq3.npg", eq3);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgModel *m = train(f, 20, NULL);
  NpgReduced *r = npg_reduced_new(m);
  double y[2];
  /* lifting before anything was evaluated: an error, not zeros */
  assert_int_equal(npg_reduced_lift(r, "y", y, 2), -1);
  says(npg_reduced_error(r), "'y' has no value to lift");
  npg_reduced_clear_error(r);
  /* an input never set: an error naming it, not a computation with zeros */
  assert_int_equal(npg_reduced_eval(r, 0), -1);
  says(npg_reduced_error(r), "input 'x' was never set");
  npg_reduced_clear_error(r);
  /* once set, an input lifts (its projection) and evaluation works */
  assert_int_equal(npg_reduced_set(r, "x", 2, xs), 0);
  double x[2];
  assert_int_equal(npg_reduced_lift(r, "x", x, 2), 0);
  assert_int_equal(npg_reduced_lift(r, "y", y, 2), -1);
  npg_reduced_clear_error(r);
  assert_int_equal(npg_reduced_eval(r, 0), 0);
  assert_int_equal(npg_reduced_lift(r, "y", y, 2), 0);
  const double want = (xs[0] * xs[1] + xs[1] * xs[1]) / (xs[0] * xs[0]);
  assert_true(fabs(y[0] - want) < 1e-6 * fabs(want));
  npg_reduced_free(r);

  /* verify_exact: a negative size; tune: a NaN tolerance, no validation samples */
  char err[512] = "";
  assert_int_equal(npg_verify_exact(p, -2, NPG_TCC, false, stdout, err, sizeof err), -1);
  says(err, "npg_verify_exact: argument 'size' is -2");
  NpgTuneReport tr;
  assert_null(npg_tune(f, 10, set_x, NULL, 5, set_x, NULL, NAN, 4, NULL, &tr));
  says(tr.error, "npg_tune: argument 'tol' is nan");
  npg_tune_free(&tr);
  assert_null(npg_tune(f, 10, set_x, NULL, 0, set_x, NULL, 0.01, 4, NULL, &tr));
  says(tr.error, "npg_tune: argument 'nvalid' is 0");
  npg_tune_free(&tr);
  assert_null(npg_tune(f, 10, set_x, NULL, 5, set_x, NULL, 0.01, 0, NULL, &tr));
  says(tr.error, "npg_tune: argument 'max_cap' is 0");
  npg_tune_free(&tr);

  /* npg_samples_set: a sample out of range of the set */
  char dir[512], path[600];
  snprintf(dir, sizeof dir, "%s/samples", scratch);
  mkdir(dir, 0755);
  snprintf(path, sizeof path, "%s/x.npy", dir);
  const long shape[2] = {3, 2};
  assert_int_equal(npg_npy_write(path, 2, shape, xs, err, sizeof err), 0);
  NpgSamples *s = npg_samples_open(p, dir, NULL, true, err, sizeof err);
  if (!s) fail_msg("%s", err);
  assert_int_equal(npg_samples_count(s), 3);
  assert_int_equal(npg_samples_set(s, f, 2), 0);
  assert_int_equal(npg_samples_set(s, f, 3), -1);
  says(npg_full_error(f), "npg_samples_set: argument 'k' is 3, but the set holds 3 samples (0 to 2)");
  npg_full_clear_error(f);
  assert_int_equal(npg_samples_set(s, f, -1), -1);
  says(npg_full_error(f), "argument 'k' is -1");
  npg_full_clear_error(f);
  npg_samples_free(s);
  /* no samples, but a static axis of the wrong size: refused when opened */
  const long empty[2] = {0, 5};
  assert_int_equal(npg_npy_write(path, 2, empty, NULL, err, sizeof err), 0);
  assert_null(npg_samples_open(p, dir, NULL, true, err, sizeof err));
  says(err, "x.npy: axis 0 of 'x' is static with size 2, but axis 1 of the array (after the sample axis) has 5");

  npg_model_free(m);
  npg_full_free(f);
  npg_free(p);
}

/* ---------------------------------------------------------------- crashes */

/* A JIT compilation that fails leaves an evaluator with its message, which
 * refuses work (even after npg_full_clear_error) and frees cleanly. */
static void failed_full(NpgProgram *p, NpgBackend backend, const char *part) {
  NpgFull *f = npg_full_new(p, backend);
  says(npg_full_error(f), part);
  npg_full_clear_error(f);
  const long shape[1] = {2};
  assert_int_equal(npg_full_set(f, "x", 1, shape, xs, "a"), -1);
  assert_int_equal(npg_full_eval(f, 0), -1);
  assert_null(npg_full_get(f, "y", NULL));
  npg_full_unbind(f);
  NpgTrainer *t = npg_trainer_new(f, NULL);
  says(npg_trainer_error(t), part);
  npg_trainer_free(t);
  npg_full_free(f);
}

static void jit_failures(void **state) {
  (void)state;
  NpgProgram *p = compile_text("eq3.npg", eq3);
  char *cc = getenv("CC") ? strdup(getenv("CC")) : NULL;
  char *tmp = getenv("TMPDIR") ? strdup(getenv("TMPDIR")) : NULL;
  setenv("CC", "/nonexistent/cc", 1);
  failed_full(p, NPG_CC, "cannot run the C compiler '/nonexistent/cc'");
  if (cc) setenv("CC", cc, 1);
  else unsetenv("CC");
  setenv("TMPDIR", "/nonexistent/tmp", 1);
  failed_full(p, NPG_CC, "cannot create a temporary directory in /nonexistent/tmp");
  char longdir[1200];
  memset(longdir, 'd', sizeof longdir - 1);
  longdir[0] = '/';
  longdir[sizeof longdir - 1] = 0;
  setenv("TMPDIR", longdir, 1);
  failed_full(p, NPG_CC, "its path is 1199 bytes long");
  if (tmp) setenv("TMPDIR", tmp, 1);
  else unsetenv("TMPDIR");
  free(cc);
  free(tmp);
  npg_free(p);
}

/* The generated C is valid whatever the program's path holds and whatever
 * its constants fold to, with both backends. */
static void generated_c_robust(void **state) {
  (void)state;
  const char *paths[] = {"a*/b.npg", "/*x*/.npg", "we\"ird\\n.npg"};
  for (size_t i = 0; i < 3; i++)
    for (int b = 0; b < 2; b++) {
      NpgProgram *p = compile_text(paths[i], eq3);
      NpgFull *f = npg_full_new(p, b ? NPG_CC : NPG_TCC);
      if (npg_full_error(f)[0]) fail_msg("%s with %s: %s", paths[i], b ? "cc" : "tcc", npg_full_error(f));
      const long shape[1] = {2};
      assert_int_equal(npg_full_set(f, "x", 1, shape, xs, "a"), 0);
      assert_int_equal(npg_full_eval(f, 0), 0);
      npg_full_free(f);
      npg_free(p);
    }
  /* constants folding to an infinity and a NaN reach the generated C */
  NpgProgram *p = compile_text("inf.npg", "input x : real[2]\n"
                                          "output y = [x[0] * (1e300 * 1e300), x[1] * (1e300 * 1e300 - 1e300 * 1e300), x[0]]\n");
  for (int b = 0; b < 2; b++) {
    NpgFull *f = npg_full_new(p, b ? NPG_CC : NPG_TCC);
    if (npg_full_error(f)[0]) fail_msg("%s: %s", b ? "cc" : "tcc", npg_full_error(f));
    const long shape[1] = {2};
    assert_int_equal(npg_full_set(f, "x", 1, shape, xs, "a"), 0);
    assert_int_equal(npg_full_eval(f, 0), 0);
    size_t n;
    const double *y = npg_full_get(f, "y", &n);
    assert_int_equal(n, 3);
    assert_true(isinf(y[0]) && y[0] > 0);
    assert_true(isnan(y[1]));
    assert_true(y[2] == xs[0]);
    assert_int_equal(npg_full_check_finite(f, 0), -1);
    says(npg_full_error(f), "stage 'y' is not finite");
    npg_full_free(f);
  }
  npg_free(p);
}

/* One rule for roots of negative numbers (compiler/front/grammar.txt): a power
 * p/q with q > 1 of a negative value is undefined for every p and q, odd q
 * included, in the full evaluator (a NaN named by npg_full_check_finite),
 * the exactness checks and the reduced evaluator (an indefinite reduced
 * operator is refused). x^(1/3) was the real cube root while x^(-1/3),
 * x^(2/3) and x^(1/5) were NaN. */
static void roots_of_negatives(void **state) {
  (void)state;
  static const struct {
    const char *power;
    double at8;  /* the power of 8 (of 32 for fifths) */
  } cases[] = {{"1/3", 2}, {"-1/3", 0.5}, {"2/3", 4}, {"1/5", 2}, {"-2/5", 0.25}, {"1/2", 2.8284271247461903}};
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++)
    for (int form = 0; form < 2; form++) {
      char text[512];
      /* the power of a named input (a diagonal operator), and of an unnamed product */
      if (form == 0)
        snprintf(text, sizeof text, "input x : real[2]\noutput y = [x[0]^(%s) * x[1], x[1]]\n", cases[i].power);
      else
        snprintf(text, sizeof text, "input x : real[2]\noutput y = [(x[0] * x[1])^(%s), x[1]]\n", cases[i].power);
      NpgProgram *p = compile_text("root.npg", text);
      NpgFull *f = npg_full_new(p, NPG_TCC);
      assert_string_equal(npg_full_error(f), "");
      const long shape[1] = {2};
      const double base = strchr(cases[i].power, '5') ? 32 : 8;
      const double pos[2] = {base, 1}, neg[2] = {-base, 1};
      assert_int_equal(npg_full_set(f, "x", 1, shape, pos, "pos"), 0);
      assert_int_equal(npg_full_eval(f, 0), 0);
      size_t n;
      const double *y = npg_full_get(f, "y", &n);
      if (fabs(y[0] - cases[i].at8) > 1e-14 * cases[i].at8)
        fail_msg("%s: %.17g, not %.17g", text, y[0], cases[i].at8);
      assert_int_equal(npg_full_check_finite(f, 0), 0);
      assert_int_equal(npg_full_set(f, "x", 1, shape, neg, "neg"), 0);
      if (npg_full_eval(f, 1) == 0) {
        y = npg_full_get(f, "y", &n);
        if (!isnan(y[0])) fail_msg("%s at x = -%g: %.17g, not NaN", text, base, y[0]);
        assert_int_equal(npg_full_check_finite(f, 1), -1);
      }
      says(npg_full_error(f), "a root of a negative number");
      npg_full_free(f);
      npg_free(p);
    }

  /* the reduced evaluator: trained where the base is positive, an indefinite
   * reduced operator where it is not */
  NpgProgram *p = compile_text("root.npg", "input x : real[2]\noutput y = [x[0]^(1/3) * x[1], x[1]^(1/3) * x[0]]\n");
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgModel *m = train(f, 30, NULL);
  NpgReduced *r = npg_reduced_new(m);
  npg_reduced_exact_roots(r, true);
  const double neg[2] = {-8, -2};
  assert_int_equal(npg_reduced_set(r, "x", 2, xs), 0);
  assert_int_equal(npg_reduced_eval(r, 0), 0);
  assert_int_equal(npg_reduced_set(r, "x", 2, neg), 0);
  assert_int_equal(npg_reduced_eval(r, 1), -1);
  says(npg_reduced_error(r), "is indefinite at sample 1");
  npg_reduced_free(r);
  npg_model_free(m);
  /* the exactness checks pass (their random data make bases positive) */
  char err[512] = "";
  FILE *devnull = fopen("/dev/null", "w");
  int rc = npg_verify_exact(p, 0, NPG_TCC, false, devnull, err, sizeof err);
  fclose(devnull);
  if (rc != 0) fail_msg("exactness checks: %d %s", rc, err);
  npg_full_free(f);
  npg_free(p);
}

/* A quantity whose name (the longest the language allows, 128) is longer
 * than the spectrum CSV's row budget (one singular value: 64 + 80 bytes):
 * the CSV holds the whole name and its row. */
static void long_member_name(void **state) {
  (void)state;
  char name[129], text[1024], dir[512], csv[1024];
  memset(name, 'q', sizeof name - 1);
  name[sizeof name - 1] = 0;
  snprintf(text, sizeof text, "input %s : real[1]\noutput y = [%s[0] * %s[0], %s[0]]\n", name, name, name, name);
  NpgProgram *p = compile_text("long.npg", text);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  NpgTrainer *t = npg_trainer_new(f, &o);
  const long shape[1] = {1};
  for (long k = 0; k < 10; k++) {
    assert_int_equal(npg_full_set(f, name, 1, shape, xs + k, "sim"), 0);
    assert_int_equal(npg_full_eval(f, k), 0);
    assert_int_equal(npg_trainer_add_full(t, f), 0);
  }
  snprintf(dir, sizeof dir, "%s/LONG", scratch);
  NpgModel *m = npg_trainer_finish(t, dir);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
  snprintf(csv, sizeof csv, "%s/spectrum_%s.csv", dir, name);
  FILE *fp = fopen(csv, "r");
  if (!fp) fail_msg("cannot open %s", csv);
  char line[1024];
  assert_non_null(fgets(line, sizeof line, fp));
  says(line, name);
  says(line, ": singular values of its centered snapshots");
  int rows = 0;
  while (fgets(line, sizeof line, fp)) rows++;
  fclose(fp);
  assert_int_equal(rows, 1 + 1); /* the column names, then k = 1 */
  npg_model_free(m);
  npg_full_free(f);
  npg_free(p);
}

static int setup(void **state) {
  (void)state;
  fill_samples();
  snprintf(scratch, sizeof scratch, "/tmp/npg_test_api_args_%d", (int)getpid());
  mkdir(scratch, 0755);
  return 0;
}

/* Issue 38 in C: an extern without a callback left out of a sample is refused naming it (it
 * was evaluated with the previous sample's value), in npg_trainer_add and npg_verify; a refused
 * sample is forgotten by npg_trainer_clear_error and the trainer goes on; the option names are
 * refused by npg_trainer_new; the same source compiled twice is the same program. */
static void externs_left_out(void **state) {
  (void)state;
  const char *src = "dim N\ninput  x : real[N]\nextern v[i:N] of x\noutput y[i:N] = v[i] * x[i]\n";
  NpgProgram *p = compile_text("ext.npg", src), *q = compile_text("ext.npg", src);
  NpgProgram *other = compile_text("ext.npg", eq3);
  assert_true(npg_same_program(p, q));
  assert_false(npg_same_program(p, other));
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  const char *bad[] = {"nosuch"};
  int cap[] = {3};
  double energy[] = {-1};
  o.nbasis = 1, o.basis_name = bad, o.basis_cap = cap, o.basis_energy = energy;
  NpgTrainer *t = npg_trainer_new(f, &o);
  /* an option named as the caller spells it: npg.h's field, npgc's flag, Python's keyword (one table) */
  says(npg_trainer_error(t), "NpgTrainOptions.basis_name nosuch: no quantity");
  assert_null(strstr(npg_trainer_error(t), "--basis"));
  assert_int_equal(npg_trainer_clear_error(t), -1); /* a refused construction stays refused */
  npg_trainer_free(t);
  o.words = NPG_WORDS_NPGC;
  t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "--basis nosuch: no quantity");
  npg_trainer_free(t);
  o.words = NPG_WORDS_PYTHON;
  t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "basis nosuch: no quantity");
  assert_null(strstr(npg_trainer_error(t), "--basis"));
  npg_trainer_free(t);
  npg_train_options_default(&o);
  o.keep_bases = "hh";
  t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "NpgTrainOptions.keep_bases hh: no quantity or class of that name");
  npg_trainer_free(t);
  npg_train_options_default(&o);
  const char *nope[] = {"nope"};
  o.ninterp = 1, o.interp_stage = nope;
  t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "NpgTrainOptions.interp_stage nope: the program has no stage 'nope'");
  npg_trainer_free(t);
  npg_train_options_default(&o);
  o.words = 7;
  t = npg_trainer_new(f, &o);
  says(npg_trainer_error(t), "NpgTrainOptions.words is 7");
  npg_trainer_free(t);
  npg_train_options_default(&o);
  t = npg_trainer_new(f, &o);
  long two = 2;
  double v[2];
  for (int k = 0; k < 12; k++) {
    v[0] = 1 + xs[2 * k], v[1] = 2 - xs[2 * k + 1];
    assert_int_equal(npg_trainer_set(t, "x", 1, &two, xs + 2 * k), 0);
    if (k == 3) { /* v left out: refused, then forgotten */
      assert_int_equal(npg_trainer_add(t), -1);
      says(npg_trainer_error(t), "training sample 3: extern 'v' is not given and has no callback");
      assert_int_equal(npg_trainer_clear_error(t), 0);
      assert_int_equal(npg_trainer_samples(t), 3);
      assert_int_equal(npg_trainer_set(t, "x", 1, &two, xs + 2 * k), 0);
    }
    assert_int_equal(npg_trainer_set(t, "v", 1, &two, v), 0);
    assert_int_equal(npg_trainer_add(t), 0);
  }
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  assert_int_equal(npg_model_samples(m), 12);
  NpgVerifyReport rep;
  assert_int_equal(npg_verify(m, f, 2, set_x, NULL, false, &rep), -1); /* set_x gives x alone */
  says(rep.error, "test sample 0: extern 'v' is not given and has no callback");
  npg_verify_free(&rep);
  npg_full_clear_error(f);
  npg_model_free(m);
  npg_trainer_free(t);
  npg_full_free(f);
  npg_free(p), npg_free(q), npg_free(other);
}

static int teardown(void **state) {
  (void)state;
  char cmd[512];
  snprintf(cmd, sizeof cmd, "rm -rf %s", scratch);
  return system(cmd) == 0 ? 0 : -1;
}

/* npg_error_set: the library's message writer, for a program's own functions (the
 * applications' one): the message cut at the buffer, no buffer accepted, -1 always. */
static void error_set_for_callers(void **state) {
  (void)state;
  char err[8] = "old";
  assert_int_equal(npg_error_set(err, sizeof err, "%s %d", "abc", 12345), -1);
  assert_string_equal(err, "abc 123");
  assert_int_equal(npg_error_set(NULL, 0, "nothing %d", 1), -1);
  assert_int_equal(npg_error_set(err, 0, "not written"), -1);
  assert_string_equal(err, "abc 123");
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(null_program_and_full),  cmocka_unit_test(null_training_and_models),
      cmocka_unit_test(train_options_refused),  cmocka_unit_test(reduced_order_of_calls),
      cmocka_unit_test(jit_failures),           cmocka_unit_test(generated_c_robust),
      cmocka_unit_test(long_member_name),       cmocka_unit_test(roots_of_negatives),
      cmocka_unit_test(externs_left_out),       cmocka_unit_test(reduced_lift_many),
      cmocka_unit_test(error_set_for_callers),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
