/* test_snapshots.c — the method of snapshots (backends/train/snapshots.c;
 * DESIGN §11), training under a memory budget too small for the snapshots:
 *
 *   - the split of the budget into a held block and a batch of later samples
 *     (train_gram_blocks) keeps to its rules;
 *   - the bases equal the in-memory SVD's: same sizes, same projectors.
 */
#include "emit.h"
#include "memsamples.h"
#include "meshgen.h"
#include "train.h"
#include "testutil.h"
#include "trained.h"

/* All held when they fit; otherwise a batch of an eighth of the budget (at most 32) beside a
 * held block of the rest, or, when that eighth is below 8, one later sample outside it. */
static void blocks_share_the_budget(void **state) {
  (void)state;
  for (long S = 1; S <= 300; S += 7)
    for (long fit = 1; fit <= 400; fit += 3) {
      long b, q;
      train_gram_blocks(S, fit, &b, &q);
      if (fit >= S) {
        if (b != S || q != 0) fail_msg("S %ld, fit %ld: held %ld, batch %ld (all fit)", S, fit, b, q);
        continue;
      }
      long eighth = fit / 8 < 32 ? fit / 8 : 32;
      bool ok = eighth < 8 ? b == fit && q == 1 : q == eighth && b + q == fit;
      if (!ok || b < 1) fail_msg("S %ld, fit %ld: held %ld, batch %ld", S, fit, b, q);
    }
}

/* Training with a memory budget too small for the snapshots (the method of
 * snapshots: Gram matrices by blocks of recomputed samples, then the basis
 * by recomputation) gives the same bases as the in-memory SVD: same sizes,
 * same projectors B Bᵀ. S samples, a budget of `fit` of them (--mem twice
 * that, below S: the snapshots do not fit); the split of it (held block,
 * batch of later samples) must be `b`, `q`. */
static void snapshots_match_memory(long S, long fit, long b, long q) {
  NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  RoomSamples train;
  room_samples(&train, f, 24, S, 0.0, 1.0 / (double)(S - 1));
  SampleSource src = {train.S, &train, room_set, NULL, NULL};
  long gb, gq;
  train_gram_blocks(S, fit, &gb, &gq);
  assert_int_equal(gb, b);
  assert_int_equal(gq, q);
  assert_true(2 * fit < S);
  for (int uncentered = 0; uncentered < 2; uncentered++) {
    Model *a = train_with(prog, f, &src, 8, 0.9999, uncentered, 0);
    /* per sample: Σ n over members; half the budget holds the blocks */
    size_t per = 0;
    for (int c = 0; c < a->nclasses; c++) per += sizeof(double) * (size_t)(a->classes[c].n * a->classes[c].nmembers);
    Model *m = train_with(prog, f, &src, 8, 0.9999, uncentered, per * (size_t)(2 * fit));
    double worst = 0;
    for (int c = 0; c < a->nclasses; c++) {
      const RClass *x = &a->classes[c], *y = &m->classes[c];
      assert_int_equal(x->m, y->m);
      for (long i = 0; i < x->n; i++)
        for (long j = 0; j < x->n; j++) {
          double px = 0, py = 0;
          for (long k = 0; k < x->m; k++) px += x->B[i * x->m + k] * x->B[j * x->m + k], py += y->B[i * y->m + k] * y->B[j * y->m + k];
          worst = fmax(worst, fabs(px - py));
        }
    }
    print_message("method of snapshots (%ld samples, blocks of %ld, batches of %ld) vs in-memory SVD, %s: projectors "
                  "differ by %.2g\n", S, b, q, uncentered ? "uncentered" : "centered", worst);
    assert_true(worst < 1e-7);
    model_free(a);
    model_free(m);
  }
  room_free(&train);
  full_free(f);
  npg_free(p);
}

/* 20 samples in blocks of 6 (4 passes), the later samples one at a time. */
static void method_of_snapshots_matches_memory(void **state) {
  (void)state;
  snapshots_match_memory(20, 6, 6, 1);
}

/* 131 samples (prime) in blocks of 56, 56 and 19, the later ones in
 * batches of 8: the first pass's 75 and the second's 19 end three into a
 * batch; 131 a multiple of neither. */
static void method_of_snapshots_batches_match_memory(void **state) {
  (void)state;
  snapshots_match_memory(131, 64, 56, 8);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(blocks_share_the_budget),
      cmocka_unit_test(method_of_snapshots_matches_memory),
      cmocka_unit_test(method_of_snapshots_batches_match_memory),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
