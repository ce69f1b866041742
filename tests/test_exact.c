/* test_exact.c — lowering is exact (DESIGN §4): for every example program and
 * every program in tests/programs, each stage's canonical form evaluated in
 * full space equals the stage's source expression evaluated directly, to
 * 1e-12 relative (max norm), on random data of several sizes. */
#include <math.h>
#include <stdio.h>

#include "support/refeval.h"
#include "testutil.h"

/* A stage introduced for a division or root inside an op's entries, over fewer indices than the
 * op (ir/lower_expr.c, lower_expr_op_entries: 1 / h[i] in K[i, j]): its value is a piece of the
 * entries, not a source expression of its own. */
static bool entrywise(const Sym *s) {
  return s->introduced && s->introduced_for && s->introduced_for->kind == SYM_OP &&
         s->nivars < s->introduced_for->nivars;
}

static int check_program(NpgProgram *p, const char *path, void *arg) {
  (void)arg;
  Program *prog = program_ir(p);
  int failures = 0, nchecked = 0, npadded = 0;
  double worst = 0;
  /* Two sizes; then, with -1 padding in the int params, once more: kept
   * only when the program guards its gathers (no index out of range). */
  long sizes[] = {6, 8, 7};
  for (int si = 0; si < 3; si++) {
    bool padded = si == 2;
    RefData *d = ref_new(prog, sizes[si]);
    if (!bind_random(d, prog, sizes[si], 1234u + (unsigned)si, padded, NULL, NULL) && padded) {
      ref_free(d);
      break;  /* nothing to pad */
    }
    for (int i = 0; i < prog->stages.n; i++) {
      const Stage *st = prog->stages.v[i];
      if (st->kind == ST_EXTERN) continue;
      size_t n = ref_count(d, st->sym);
      double *direct = ref_values(d, st->sym);
      double *canon = malloc(sizeof(double) * (n ? n : 1));
      if (entrywise(st->sym)) { /* no source expression of its own: its users are checked against theirs */
        ref_eval_canonical(d, st, direct);
        free(canon);
        continue;
      }
      ref_eval_direct(d, st->sym, direct);
      if (padded && ref_error(d)) {  /* unguarded gathers: padding does not apply */
        free(canon);
        break;
      }
      ref_eval_canonical(d, st, canon);
      double e = rel_diff(direct, canon, n);
      if (padded && i == prog->stages.n - 1 && !ref_error(d)) npadded++;
      if (ref_error(d)) {
        print_message("%s (N=%ld): stage %s: evaluation problem: %s\n", path, sizes[si], st->sym->name, ref_error(d));
        failures++;
      } else if (e <= 1e-12) {
        nchecked++;
        worst = fmax(worst, e);
      } else {
        print_message("%s (N=%ld): stage %s: canonical form differs from the source by %.3g (relative)\n", path,
                      sizes[si], st->sym->name, e);
        failures++;
      }
      free(canon);
    }
    ref_free(d);
  }
  print_message("%-40s %3d stage checks, worst relative difference %.2g%s\n", path, nchecked, worst,
                npadded ? ", with -1 padding" : "");
  return failures;
}

static void examples_exact(void **state) {
  (void)state;
  int n = 0, failures = check_programs(corpus_examples, check_program, NULL, &n);
  assert_true(n >= 2);
  assert_int_equal(failures, 0);
}

static void test_programs_exact(void **state) {
  (void)state;
  int n = 0;
  int failures = check_programs((const char *const[]){"tests/programs", NULL}, check_program, NULL, &n);
  assert_true(n >= 20);
  assert_int_equal(failures, 0);
}

/* The oracle itself must be able to fail: a deliberately wrong canonical
 * form (a coefficient changed) is caught. */
static void detects_a_wrong_lowering(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/rational/rational.npg");
  Program *prog = ir_ok(p);
  RefData *d = ref_new(prog, 3);
  bind_random(d, prog, 3, 7u, false, NULL, NULL);
  Stage *y = prog->stages.v[0];
  Mono *m = y->terms[0]->num->comp[0].m[0];
  Node *saved = m->coef;
  m->coef = new_num(prog->ctx, 1.0 + 1e-9, false, (Loc){0});
  double direct[2], canon[2];
  ref_eval_direct(d, y->sym, direct);
  ref_eval_canonical(d, y, canon);
  assert_true(rel_diff(direct, canon, 2) > 1e-12);
  m->coef = saved;
  ref_eval_canonical(d, y, canon);
  assert_true(rel_diff(direct, canon, 2) <= 1e-12);
  ref_free(d);
  npg_free(p);
}

/* npgc verify --exact (exact.c), the product's own form of these checks:
 * every example and test program passes both; a coefficient of the
 * canonical form changed after compilation (so the tensor builders, made
 * from it, disagree with the full evaluator, made from the source) fails
 * both, and the report names the stage. */
/* exact_check with the defaults; its report in *report (to free). */
static int run_exact(NpgProgram *p, char *err, size_t errlen, char **report) {
  ExactOptions o = {0, 0, 1u, JIT_TCC, false};
  size_t len = 0;
  FILE *out = open_memstream(report, &len);
  int rc = exact_check(p, &o, out, err, errlen);
  fclose(out);
  return rc;
}

static int exact_cb(NpgProgram *p, const char *path, void *arg) {
  (void)arg;
  char err[2048] = "", *report = NULL;
  int rc = run_exact(p, err, sizeof err, &report);
  if (rc != 0) print_message("%s: exact_check %d: %s\n%s", path, rc, err, report);
  free(report);
  return rc != 0;
}

static void verify_exact_passes_and_fails(void **state) {
  (void)state;
  int n = 0, failures = check_programs(corpus_all, exact_cb, NULL, &n);
  assert_true(n >= 20);
  assert_int_equal(failures, 0);

  NpgProgram *p = compile_file("examples/rational/rational.npg");
  Program *prog = ir_ok(p);
  Stage *y = prog->stages.v[0];
  Mono *m = y->terms[0]->num->comp[0].m[0];
  m->coef = new_num(prog->ctx, 1.0 + 1e-9, false, (Loc){0});
  char err[2048] = "", *report = NULL;
  int rc = run_exact(p, err, sizeof err, &report);
  if (rc != 1) fail_msg("a wrong lowering passed (%d, %s):\n%s", rc, err, report);
  assert_non_null(strstr(report, "FAIL: the tensor form differs"));
  assert_non_null(strstr(report, "FAIL: the full-rank reduced value differs"));
  assert_non_null(strstr(report, "\n     y "));
  free(report);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(detects_a_wrong_lowering),
      cmocka_unit_test(examples_exact),
      cmocka_unit_test(test_programs_exact),
      cmocka_unit_test(verify_exact_passes_and_fails),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
