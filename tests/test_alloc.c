/* test_alloc.c — allocation failure in training and model loading (issue
 * 24; STYLE: one allocation hook, Lua's ltests.c). Each allocation of the
 * library (mem_alloc_hook, stdlib/runtime/alloc.h; tests/support/failing_alloc.h) fails in turn — the first, then the
 * second, ... — until the whole operation succeeds: every failure must end
 * in a message that says "out of memory" (never a crash or a quiet NULL),
 * and, under the sanitizer build, leak nothing (LeakSanitizer at exit).
 * The program is small (Eq. 3 of the paper) so the count stays bounded.
 * Derivatives of the reduced evaluator too (their temporaries from Scratch, issue 39): after a
 * failure the same evaluator gives, once memory is back, the Jacobian and the reverse product
 * of an evaluator that never failed.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>


#include <cmocka.h>

#include "support/failing_alloc.h"
#include "npg.h"

static const char *eq3 = "input  x : real[2]\n"
                         "output y = [ (x[0]*x[1] + x[1]^2) / x[0]^2,  x[0]^2 / x[1]^2 ]\n";

enum { SAMPLES = 12, MAX_FAILURES = 20000 };

/* A crash must not leave the hook failing for the next test. */
static int restore_hook(void **state) {
  (void)state;
  failing_alloc_off();
  return 0;
}

static double xs[2 * SAMPLES];
static char dir[256];

static NpgProgram *program(void) {
  NpgOptions o = {0};
  o.source = eq3;
  NpgProgram *p = npg_compile("eq3.npg", &o);
  if (!npg_ok(p)) fail_msg("%s", npg_error(p));
  return p;
}

/* Train through `f` on SAMPLES samples with options `o`, writing
 * `model_dir` when non-NULL: the model, or NULL with the message in `msg`. */
static NpgModel *train_with(NpgFull *f, const NpgTrainOptions *o, const char *model_dir, const char **msg) {
  NpgTrainer *t = npg_trainer_new(f, o);
  const long shape[1] = {2};
  NpgModel *m = NULL;
  int rc = 0;
  *msg = NULL;
  for (long k = 0; k < SAMPLES && rc == 0; k++)
    if (npg_full_set(f, "x", 1, shape, xs + 2 * k, "sample") || npg_full_eval(f, k)) rc = -1, *msg = npg_full_error(f);
    else if (npg_trainer_add_full(t, f)) rc = -1;
  if (rc == 0) m = npg_trainer_finish(t, model_dir);
  static char copy[2048];
  snprintf(copy, sizeof copy, "%s", *msg ? *msg : npg_trainer_error(t));
  *msg = copy;
  npg_trainer_free(t);
  return m;
}

/* The same with the default options. */
static NpgModel *train(NpgFull *f, const char *model_dir, const char **msg) {
  NpgTrainOptions o;
  npg_train_options_default(&o);
  return train_with(f, &o, model_dir, msg);
}

/* Training with options `o` (`route` names it), the k-th allocation
 * failing, for every k until training succeeds: every failure says "out of
 * memory". The allocations counted. */
static long train_fails_cleanly(const NpgTrainOptions *o, const char *route, const char *model_dir) {
  NpgProgram *p = program();
  NpgFull *f = npg_full_new(p, NPG_TCC); /* the JIT's own memory is libtcc's */
  assert_string_equal(npg_full_error(f), "");
  long k;
  for (k = 0; k < MAX_FAILURES; k++) {
    if (failing_alloc_traced() >= 0) fprintf(stderr, "%s, allocation %ld fails\n", route, k);
    failing_alloc_after(k);
    const char *msg;
    NpgModel *m = train_with(f, o, model_dir, &msg);
    failing_alloc_off();
    if (m) {
      npg_model_free(m);
      break;
    }
    if (!strstr(msg, "out of memory")) fail_msg("%s, allocation %ld failing: \"%s\"", route, k, msg);
    npg_full_clear_error(f);
    npg_full_unbind(f);
  }
  print_message("%s: %ld allocations, each failing in turn\n", route, k);
  npg_full_free(f);
  npg_free(p);
  return k;
}

/* The evaluator, the trainer, training itself and writing the model. */
static void training_fails_cleanly(void **state) {
  (void)state;
  NpgTrainOptions o;
  npg_train_options_default(&o);
  long k = train_fails_cleanly(&o, "training", dir);
  assert_true(k > 20 && k < MAX_FAILURES);
}

/* Training by the method of snapshots (backends/train/snapshots.c): the
 * snapshots (12 samples of 2 entries per member) exceed `mem`, the bases
 * (cap 2) do not. */
static void snapshots_fail_cleanly(void **state) {
  (void)state;
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = 2, o.mem = 150;
  long k = train_fails_cleanly(&o, "method of snapshots", NULL);
  assert_true(k > 20 && k < MAX_FAILURES);
}

/* Out of core (backends/train/ooc.c): bases by row blocks within a budget below the snapshots'. */
static void out_of_core_fails_cleanly(void **state) {
  (void)state;
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = 2, o.mem = 40;
  long k = train_fails_cleanly(&o, "out of core", NULL);
  assert_true(k > 20 && k < MAX_FAILURES);
}

/* Sample k of the tune test: the k-th of xs (the training samples), or
 * with `user` the k-th from its end (the validation samples). */
static int set_sample(void *user, NpgFull *f, long k) {
  const long shape[1] = {2};
  const double *x = user ? xs + 2 * (SAMPLES - 1 - k) : xs + 2 * k;
  return npg_full_set(f, "x", 1, shape, x, "sample");
}

/* npgc tune's search (backends/train/tune.c, train_set.c): the sample set,
 * every trial's model and validation. Every allocation fails in turn: the
 * search fails saying "out of memory", or returns the model. Its stage is
 * eligible for interpolation, so the choice trains both (interp_train.c, and
 * the interpolated model's tables loaded back by interp.c). */
static void tune_fails_cleanly(void **state) {
  (void)state;
  NpgProgram *p = program();
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  long k;
  for (k = 0; k < MAX_FAILURES; k++) {
    if (failing_alloc_traced() >= 0) fprintf(stderr, "tune, allocation %ld fails\n", k);
    failing_alloc_after(k);
    NpgTuneReport report;
    NpgModel *m = npg_tune(f, SAMPLES, set_sample, NULL, SAMPLES / 2, set_sample, (void *)xs, 1e-6, 3, &o, &report);
    failing_alloc_off();
    char msg[sizeof report.error];
    snprintf(msg, sizeof msg, "%s", report.error);
    npg_tune_free(&report);
    if (m) {
      npg_model_free(m);
      break;
    }
    if (!strstr(msg, "out of memory")) fail_msg("allocation %ld failing: \"%s\"", k, msg);
    npg_full_clear_error(f);
    npg_full_unbind(f);
  }
  print_message("tune: %ld allocations, each failing in turn\n", k);
  assert_true(k > 20 && k < MAX_FAILURES);
  npg_full_free(f);
  npg_free(p);
}

/* A model of `p` trained (memory never failing) and written to `dir`. */
static NpgModel *trained(NpgProgram *p) {
  NpgFull *f = npg_full_new(p, NPG_TCC);
  const char *why;
  NpgModel *m = train(f, dir, &why);
  if (!m) fail_msg("%s", why);
  npg_full_free(f);
  return m;
}

/* Loading the model of `p` in `model_dir` and evaluating with it, the k-th allocation failing, for
 * every k until both succeed: every failure says "out of memory". The allocations counted. */
static long load_fails_cleanly(NpgProgram *p, const char *model_dir, const char *route) {
  long k;
  for (k = 0; k < MAX_FAILURES; k++) {
    if (failing_alloc_traced() >= 0) fprintf(stderr, "%s, allocation %ld fails\n", route, k);
    failing_alloc_after(k);
    NpgModel *m = npg_model_load(p, model_dir);
    NpgReduced *r = NULL;
    const char *msg = npg_model_error(m);
    double y[2];
    if (!msg[0]) {
      r = npg_reduced_new(m);
      if (!r) msg = npg_reduced_error(NULL); /* "npg_reduced_new: out of memory" */
      else if (npg_reduced_set(r, "x", 2, xs) || npg_reduced_eval(r, 0) || npg_reduced_lift(r, "y", y, 2))
        msg = npg_reduced_error(r);
    }
    failing_alloc_off();
    bool done = !msg[0];
    if (!done && !strstr(msg, "out of memory")) fail_msg("%s, allocation %ld failing: \"%s\"", route, k, msg);
    npg_reduced_free(r);
    npg_model_free(m);
    if (done) break;
  }
  print_message("%s: %ld allocations, each failing in turn\n", route, k);
  return k;
}

/* Loading a model, and evaluating with it. */
static void loading_fails_cleanly(void **state) {
  (void)state;
  NpgProgram *p = program();
  npg_model_free(trained(p));
  long k = load_fails_cleanly(p, dir, "loading and evaluating");
  assert_true(k > 5 && k < MAX_FAILURES);
  npg_free(p);
}

/* An interpolated stage (backends/train/interp_train.c, backends/model/interp.c): trained with y
 * forced to interpolation, its monomial tables read from the tensor builders, then the model
 * loaded back and evaluated, each allocation failing in turn. */
static void interpolated_fails_cleanly(void **state) {
  (void)state;
  NpgTrainOptions o;
  npg_train_options_default(&o);
  static const char *const interp[] = {"y"};
  o.ninterp = 1, o.interp_stage = interp;
  char model_dir[300];
  snprintf(model_dir, sizeof model_dir, "%s.interp", dir);
  long k = train_fails_cleanly(&o, "interpolated", model_dir);
  assert_true(k > 20 && k < MAX_FAILURES);
  NpgProgram *p = program();
  NpgModel *m = npg_model_load(p, model_dir);
  long entries = 0;
  assert_int_equal(npg_model_stage_interpolated(m, "y", &entries), 1);
  npg_model_free(m);
  k = load_fails_cleanly(p, model_dir, "loading an interpolated model");
  assert_true(k > 5 && k < MAX_FAILURES);
  npg_free(p);
}

/* npg_reduced_jacobian and npg_reduced_vjp (forward and reverse sweeps through every stage) on
 * one evaluator, the k-th allocation failing, until both succeed; their values then equal those
 * computed before any failure. */
static void derivatives_fail_cleanly(void **state) {
  (void)state;
  NpgProgram *p = program();
  NpgModel *m = trained(p);
  NpgReduced *r = npg_reduced_new(m);
  assert_non_null(r);
  assert_int_equal(npg_reduced_set(r, "x", 2, xs), 0);
  const char *y = "y";
  const double cot[2] = {0.7, -1.3}, *cots = cot;
  double J0[4] = {0}, g0[2] = {0}; /* m_y x m_x, each at most 2 */
  if (npg_reduced_jacobian(r, 0, "y", "x", J0) || npg_reduced_vjp(r, 0, 1, &y, &cots, "x", g0))
    fail_msg("%s", npg_reduced_error(r));
  long k;
  for (k = 0; k < MAX_FAILURES; k++) {
    if (failing_alloc_traced() >= 0) fprintf(stderr, "derivatives, allocation %ld fails\n", k);
    double J[4] = {0}, g[2] = {0};
    failing_alloc_after(k);
    int rc = npg_reduced_jacobian(r, 0, "y", "x", J) || npg_reduced_vjp(r, 0, 1, &y, &cots, "x", g);
    failing_alloc_off();
    if (rc == 0) {
      assert_memory_equal(J, J0, sizeof J);
      assert_memory_equal(g, g0, sizeof g);
      break;
    }
    if (!strstr(npg_reduced_error(r), "out of memory")) fail_msg("allocation %ld failing: \"%s\"", k, npg_reduced_error(r));
    npg_reduced_clear_error(r);
  }
  print_message("derivatives: %ld allocations, each failing in turn\n", k);
  assert_true(k > 5 && k < MAX_FAILURES);
  npg_reduced_free(r);
  npg_model_free(m);
  npg_free(p);
}

static int setup(void **state) {
  (void)state;
  srand(5);
  for (int i = 0; i < 2 * SAMPLES; i++) xs[i] = 0.5 + (double)rand() / RAND_MAX;
  snprintf(dir, sizeof dir, "/tmp/npg_test_alloc_%d", (int)getpid());
  return 0;
}

static int teardown(void **state) {
  (void)state;
  char cmd[600];
  snprintf(cmd, sizeof cmd, "rm -rf %s %s.*", dir, dir);
  return system(cmd) == 0 ? 0 : -1;
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test_teardown(training_fails_cleanly, restore_hook),
      cmocka_unit_test_teardown(loading_fails_cleanly, restore_hook),
      cmocka_unit_test_teardown(derivatives_fail_cleanly, restore_hook),
      cmocka_unit_test_teardown(snapshots_fail_cleanly, restore_hook),
      cmocka_unit_test_teardown(out_of_core_fails_cleanly, restore_hook),
      cmocka_unit_test_teardown(tune_fails_cleanly, restore_hook),
      cmocka_unit_test_teardown(interpolated_fails_cleanly, restore_hook),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
