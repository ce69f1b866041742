/* test_full.c — the generated full evaluator: for every example and test
 * program, random data bound through the public API; every stage value
 * equals the reference evaluator's value of that stage computed from the
 * same upstream values (1e-12 relative; test_exact shows the reference's
 * canonical form equals the source expression), and the libtcc and cc
 * backends agree (1e-13 relative). */
#include <math.h>
#include <stdio.h>

#include "support/refeval.h"
#include "testutil.h"

/* Each given symbol's random values into both evaluators too (bind_random). */
static void set_both(void *user, const Sym *s, int ndim, const long *shape, const double *values) {
  NpgFull **fs = user;
  for (int f = 0; f < 2; f++)
    if (npg_full_set(fs[f], s->name, ndim, shape, values, s->name) != 0) fail_msg("%s", npg_full_error(fs[f]));
}

typedef struct Worst {
  double ref, cc;
} Worst;

static int check_program(NpgProgram *p, const char *path, void *arg) {
  Worst *w = arg;
  Program *prog = program_ir(p);
  NpgFull *fs[2] = {npg_full_new(p, NPG_TCC), npg_full_new(p, NPG_CC)};
  int failures = 0;
  for (int f = 0; f < 2; f++)
    if (npg_full_error(fs[f])[0]) {
      print_message("%s (%s): %s\n", path, f ? "cc" : "tcc", npg_full_error(fs[f]));
      failures++;
    }
  for (int round = 0; round < 2 && !failures; round++) {
    long n = round ? 7 : 6;
    RefData *d = ref_new(prog, n);
    for (int f = 0; f < 2; f++) npg_full_unbind(fs[f]);
    bind_random(d, prog, n, 99u + (unsigned)round, round == 1, set_both, fs);
    for (int f = 0; f < 2; f++)
      if (npg_full_eval(fs[f], round) != 0) {
        print_message("%s (%s): %s\n", path, f ? "cc" : "tcc", npg_full_error(fs[f]));
        failures++;
      }
    for (int i = 0; i < prog->stages.n && !failures; i++) {
      const Stage *st = prog->stages.v[i];
      if (st->kind == ST_EXTERN) continue;
      size_t count = ref_count(d, st->sym);
      double *ref = malloc(sizeof(double) * (count ? count : 1));
      ref_eval_canonical(d, st, ref);
      if (ref_error(d)) {
        free(ref);
        break;
      }
      size_t n0, n1;
      const double *a = npg_full_get(fs[0], st->sym->name, &n0);
      const double *b = npg_full_get(fs[1], st->sym->name, &n1);
      assert_int_equal(n0, count);
      assert_int_equal(n1, count);
      double e_ref = rel_diff(ref, a, count), e_cc = rel_diff(a, b, count);
      free(ref);
      /* the next stages read this stage's generated value */
      memcpy(ref_values(d, st->sym), a, sizeof(double) * count);
      if (!(e_ref <= 1e-12) || !(e_cc <= 1e-13)) {
        print_message("%s: stage %s: generated vs reference %.3g, tcc vs cc %.3g\n", path, st->sym->name, e_ref, e_cc);
        failures++;
      }
      w->ref = fmax(w->ref, e_ref);
      w->cc = fmax(w->cc, e_cc);
    }
    ref_free(d);
  }
  npg_full_free(fs[0]);
  npg_full_free(fs[1]);
  return failures;
}

static void generated_equals_reference(void **state) {
  (void)state;
  int n = 0;
  Worst w = {0, 0};
  int failures = check_programs(corpus_all, check_program, &w, &n);
  double wr = w.ref, wc = w.cc;
  print_message("%d programs: generated vs reference worst %.2g, tcc vs cc worst %.2g\n", n, wr, wc);
  assert_true(n >= 20);
  assert_int_equal(failures, 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(generated_equals_reference),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
