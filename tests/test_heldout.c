/* test_heldout.c — the auto-check's numerics (backends/verify/heldout.c,
 * `npgc verify`, DESIGN §7) on a trained model: each quantity's mean error
 * equals the mean of ‖y − lift(ŷ)‖/‖y‖ computed here from the reduced
 * evaluator alone; no error is below its projection floor (own ≥ 0); an
 * input's error is its floor (its reduced value is its projection); a basis
 * spanning every sample reproduces them to rounding. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "testutil.h"
#include "trained.h"
#include "heldout.h"

enum { S = 12 };

/* The check of `tr`'s model over its own samples. */
static Heldout *check(Trained *tr) {
  char err[1024] = "";
  Heldout *h = heldout_new(tr->m, err, sizeof err);
  if (!h) fail_msg("heldout_new: %s", err);
  const double **full = calloc((size_t)tr->m->nq + 1, sizeof *full);
  for (long k = 0; k < S; k++) {
    if (memsamples_set(&tr->train, tr->f, k) || full_eval(tr->f, k)) fail_msg("%s", full_error(tr->f));
    for (int q = 0; q < tr->m->nq; q++) full[q] = full_get(tr->f, ((Sym *)tr->prog->quantities.v[q])->name, NULL);
    if (heldout_reduce(h, k, full)) fail_msg("%s", reduced_error(h->r));
    if (heldout_measure(h, k, tr->f, full, err, sizeof err)) fail_msg("heldout_measure: %s", err);
  }
  heldout_finish(h, S);
  free(full);
  return h;
}

static void means_are_the_reduced_evaluators_errors(void **state) {
  (void)state;
  Trained tr;
  train(&tr, "tests/programs/heat_division.npg", NULL, 9, S, 3);
  Heldout *h = check(&tr);
  int checked = 0;
  for (int q = 0; q < tr.m->nq; q++) {
    const Sym *s = tr.prog->quantities.v[q];
    const HeldoutRow *row = &h->rows[q];
    assert_string_equal(row->name, s->name);
    assert_int_equal(row->m, tr.m->classes[tr.m->qclass[q]].m);
    if (row->streamed) continue;
    double want = mean_error(tr.prog, tr.f, tr.m, &tr.train, memsamples_set, S, s->name);
    if (!(fabs(row->l2 - want) <= 1e-12 * fmax(want, 1e-300) + 1e-15))
      fail_msg("%s: mean error %.17g, the reduced evaluator's %.17g", s->name, row->l2, want);
    if (!(row->own >= 0 && row->floor <= row->l2 + 1e-12))
      fail_msg("%s: error %.3g below its floor %.3g", s->name, row->l2, row->floor);
    if (s->kind == SYM_INPUT && !(fabs(row->l2 - row->floor) <= 1e-12))
      fail_msg("input %s: error %.17g, floor %.17g", s->name, row->l2, row->floor);
    assert_true(row->l2_max >= row->l2 - 1e-15 && row->l2_max_sample >= 0 && row->l2_max_sample < S);
    checked++;
  }
  assert_true(checked >= 3);
  assert_true(h->growth >= 0);
  heldout_free(h);
  trained_free(&tr);
}

static void a_basis_of_every_sample_reproduces_them(void **state) {
  (void)state;
  Trained tr;
  train(&tr, "tests/programs/heat_division.npg", NULL, 9, S, S + 2);
  Heldout *h = check(&tr);
  for (int q = 0; q < tr.m->nq; q++)
    if (!h->rows[q].streamed && !(h->rows[q].l2 <= 1e-9))
      fail_msg("%s: error %.3g with a basis spanning every sample", h->rows[q].name, h->rows[q].l2);
  heldout_free(h);
  trained_free(&tr);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(means_are_the_reduced_evaluators_errors),
      cmocka_unit_test(a_basis_of_every_sample_reproduces_them),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
