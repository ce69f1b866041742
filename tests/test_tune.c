/* test_tune.c — basis sizes chosen by error (backends/train/tune.c, npgc
 * tune):
 *
 *   - tune_search meets its tolerance on Eq. 3 and the radiosity room at a
 *     cost no uniform cap that meets it undercuts.
 */
#include "memsamples.h"
#include "train.h"
#include "testutil.h"
#include "trained.h"

/* ---------------------------------------------------------------- basis sizes by error (npgc tune) */

/* tune_search on `prog` meets `tol` (checked independently, by mean_error
 * on the validation samples), and no uniform cap 1..`umax` that meets it
 * (trained from scratch by train_model) costs less than its choice. */
static void check_tune(const char *name, Program *prog, Full *f, SampleSource *src, void *valid,
                       int (*set)(void *, Full *, long), long Sv, const char *out, double tol, int umax) {
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = 60;
  opt_user.energy = 1.0;
  char err[2048] = "";
  TrainSet *ts = train_set_new(prog, f, src, &opt, ERR_OF(err, sizeof err));
  if (!ts) fail_msg("%s: %s", name, err);
  SampleSource vsrc = {Sv, valid, set, NULL, NULL};
  TuneResult r;
  if (tune_search(ts, &(TuneGoal){&vsrc, tol, 60}, NULL, &r, ERR_OF(err, sizeof err))) fail_msg("%s: %s", name, err);
  assert_true(r.chosen >= 0 && r.model);
  /* the model tune returns, its reductions as chosen in the search */
  double chosen_err = mean_error(prog, f, r.model, valid, set, Sv, out), chosen_cost = r.trials[r.chosen].cost;
  print_message("%s: tune --tol %g chose cost %.6g, error %.3e (%d candidates); uniform caps:", name, tol, chosen_cost,
                chosen_err, r.ntrials);
  assert_true(chosen_err <= tol);
  long *sizes = malloc(sizeof(long) * (size_t)prog->classes.n);
  for (int u = 1; u <= umax; u++) {
    Model *mu = train_with(prog, f, src, u, 1.0, false, 0);
    for (int c = 0; c < mu->nclasses; c++) sizes[c] = mu->classes[c].m;
    double e = mean_error(prog, f, mu, valid, set, Sv, out), cost = cost_value(prog, sizes, mu->samples);
    print_message(" %d: %.3g/%.3e%s", u, cost, e, e <= tol ? " meets" : "");
    if (e <= tol) assert_true(chosen_cost <= cost * (1 + 1e-12));
    model_free(mu);
  }
  print_message("\n");
  free(sizes);
  tune_result_free(&r);
  train_set_free(ts);
}

static void tune_meets_tolerance_at_least_cost(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/rational/rational.npg");
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  MemSamples rtrain, rtest;
  if (memsamples_fill(&rtrain, prog, f, 2, 40, 3u) || memsamples_fill(&rtest, prog, NULL, 2, 20, 4u)) fail_msg("random samples");
  SampleSource src = {rtrain.S, &rtrain, memsamples_set, NULL, NULL};
  check_tune("rational", prog, f, &src, &rtest, memsamples_set, rtest.S, "y", 1e-8, 3);
  memsamples_free(&rtrain);
  memsamples_free(&rtest);
  full_free(f);
  npg_free(p);
  p = compile_file("examples/radiosity/formfactors.npg");
  prog = ir_ok(p);
  f = full_new(program_ir(p), JIT_TCC, NULL);
  RoomSamples train, test;
  room_samples(&train, f, 48, 48, 0.0, 1.0 / 47);
  room_samples(&test, NULL, 48, 12, 0.5 / 47, 4.0 / 47);
  SampleSource rsrc = {train.S, &train, room_set, NULL, NULL};
  /* uniform caps 10-12 meet 0.13 on these samples: the comparison is not vacuous */
  check_tune("radiosity", prog, f, &rsrc, &test, room_set, test.S, "b", 0.13, 12);
  room_free(&train);
  room_free(&test);
  full_free(f);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(tune_meets_tolerance_at_least_cost),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
