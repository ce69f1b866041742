/* test_krylov.c — stdlib/runtime/krylov.c: M^(p/q) v by the Lanczos process
 * against the exact power U diag(λ^(p/q)) Uᵀ v of matrices built from a
 * known eigendecomposition (random orthogonal U by LAPACK's QR, chosen
 * spectra), so the oracle shares no code with the method. */
#include <lapacke.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "krylov.h"

static uint64_t rng = 12345;
static double uniform(void) {
  rng = rng * 6364136223846793005ull + 1442695040888963407ull;
  return (double)(rng >> 11) / 9007199254740992.0;
}

/* M = U diag(lam) Uᵀ (row-major n x n), U orthogonal (n x n, row-major). */
static void build(int n, const double *lam, double *U, double *M) {
  double *A = malloc(sizeof(double) * (size_t)(n * n)), *tau = malloc(sizeof(double) * (size_t)n);
  for (int i = 0; i < n * n; i++) A[i] = uniform() - 0.5;
  assert_int_equal(LAPACKE_dgeqrf(LAPACK_ROW_MAJOR, n, n, A, n, tau), 0);
  assert_int_equal(LAPACKE_dorgqr(LAPACK_ROW_MAJOR, n, n, n, A, n, tau), 0);
  memcpy(U, A, sizeof(double) * (size_t)(n * n));
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++) {
      double s = 0;
      for (int k = 0; k < n; k++) s += U[i * n + k] * lam[k] * U[j * n + k];
      M[i * n + j] = s;
    }
  free(A);
  free(tau);
}

/* y = U diag(lam^r) Uᵀ v */
static void exact(int n, const double *lam, const double *U, double r, const double *v, double *y) {
  for (int i = 0; i < n; i++) {
    double s = 0;
    for (int k = 0; k < n; k++) {
      double c = 0;
      for (int j = 0; j < n; j++) c += U[j * n + k] * v[j];
      s += U[i * n + k] * pow(lam[k], r) * c;
    }
    y[i] = s;
  }
}

static double rel(int n, const double *a, const double *b) {
  double d = 0, m = 0;
  for (int i = 0; i < n; i++) d += (a[i] - b[i]) * (a[i] - b[i]), m += b[i] * b[i];
  return sqrt(d / m);
}

/* Spectra spread over decades, clustered, and a few distinct values; the
 * powers of the programs (roots and inverse roots). */
static void powers_match_the_exact_ones(void **state) {
  (void)state;
  const int sizes[] = {5, 20, 60, 120};
  const long pq[][2] = {{-1, 2}, {1, 2}, {1, 3}, {-2, 3}};
  Krylov k;
  assert_int_equal(krylov_init(&k, 120), 0);
  double worst = 0;
  int converged = 0, total = 0;
  for (size_t si = 0; si < sizeof sizes / sizeof *sizes; si++) {
    int n = sizes[si];
    double *lam = malloc(sizeof(double) * (size_t)n), *U = malloc(sizeof(double) * (size_t)(n * n));
    double *M = malloc(sizeof(double) * (size_t)(n * n)), *v = malloc(sizeof(double) * (size_t)n);
    double *y = malloc(sizeof(double) * (size_t)n), *ref = malloc(sizeof(double) * (size_t)n);
    for (int spectrum = 0; spectrum < 3; spectrum++) {
      for (int i = 0; i < n; i++)
        lam[i] = spectrum == 0 ? pow(10.0, -3.0 * i / (n > 1 ? n - 1 : 1))   /* 1 … 1e-3 */
                 : spectrum == 1 ? 2.0 + 1e-3 * uniform()                    /* clustered */
                                 : 1.0 + (double)(i % 4);                    /* four values */
      build(n, lam, U, M);
      for (size_t t = 0; t < sizeof pq / sizeof *pq; t++) {
        for (int i = 0; i < n; i++) v[i] = uniform() - 0.5;
        exact(n, lam, U, (double)pq[t][0] / (double)pq[t][1], v, ref);
        memcpy(y, v, sizeof(double) * (size_t)n);
        int steps;
        double est;
        int rc = krylov_power(&k, n, M, pq[t][0], pq[t][1], 1e-10, n, y, &steps, &est);
        total++;
        assert_true(rc == 0 || rc == 1);
        if (rc == 1) {
          assert_memory_equal(y, v, sizeof(double) * (size_t)n); /* unchanged: the caller decomposes */
          continue;
        }
        converged++;
        double e = rel(n, y, ref);
        worst = fmax(worst, e);
        if (!(e <= 1e-8)) fail_msg("n %d spectrum %d power %ld/%ld: error %.3g after %d steps (estimate %.3g)", n,
                                   spectrum, pq[t][0], pq[t][1], e, steps, est);
        if (spectrum == 2) assert_true(steps <= 8); /* four eigenvalues: the Krylov space is invariant early */
      }
    }
    free(lam), free(U), free(M), free(v), free(y), free(ref);
  }
  print_message("      %d of %d converged, worst relative error %.2e (%ld expansions, %ld eigendecompositions)\n",
                converged, total, worst, k.expansions, k.decompositions);
  assert_true(converged == total); /* with n steps allowed every case converges */
  krylov_free(&k);
}

/* A spectrum of condition 20 at n = 120 (the radiosity root's operator has
 * about 18): f(T_k) e₁ by the Chebyshev expansion, not T_k's
 * eigendecomposition, and as exact; a second call on the same operator
 * starts from where the first converged and gives the same answer. */
static void well_conditioned_by_the_expansion(void **state) {
  (void)state;
  const int n = 120;
  const long pq[][2] = {{-1, 2}, {1, 2}, {1, 3}, {-2, 3}};
  Krylov k;
  assert_int_equal(krylov_init(&k, n), 0);
  double *lam = malloc(sizeof(double) * n), *U = malloc(sizeof(double) * n * n), *M = malloc(sizeof(double) * n * n);
  double v[120], y[120], y2[120], ref[120];
  for (int i = 0; i < n; i++) lam[i] = 1.0 + 19.0 * uniform();
  build(n, lam, U, M);
  double worst = 0;
  for (size_t t = 0; t < sizeof pq / sizeof *pq; t++) {
    for (int i = 0; i < n; i++) v[i] = uniform() - 0.5;
    exact(n, lam, U, (double)pq[t][0] / (double)pq[t][1], v, ref);
    memcpy(y, v, sizeof y);
    int steps, steps2;
    double est, est2;
    long before = k.expansions;
    k.start = 0;
    assert_int_equal(krylov_power(&k, n, M, pq[t][0], pq[t][1], 1e-10, n, y, &steps, &est), 0);
    assert_true(k.expansions > before);
    assert_true(est <= 1e-10 && steps < n / 2);
    double e = rel(n, y, ref);
    worst = fmax(worst, e);
    if (!(e <= 1e-10)) fail_msg("power %ld/%ld: error %.3g after %d steps (estimate %.3g)", pq[t][0], pq[t][1], e,
                                steps, est);
    memcpy(y2, v, sizeof y2);
    assert_int_equal(krylov_power(&k, n, M, pq[t][0], pq[t][1], 1e-10, n, y2, &steps2, &est2), 0);
    assert_true(steps2 <= steps && est2 <= 1e-10);
    assert_true(rel(n, y2, ref) <= 1e-10);
  }
  print_message("      worst relative error %.2e, %ld expansions, %ld eigendecompositions\n", worst, k.expansions,
                k.decompositions);
  free(lam), free(U), free(M);
  krylov_free(&k);
}

/* An indefinite or singular operator is left to the eigendecomposition. */
static void indefinite_and_singular_refused(void **state) {
  (void)state;
  const int n = 30;
  Krylov k;
  assert_int_equal(krylov_init(&k, n), 0);
  double lam[30], U[900], M[900], v[30], y[30];
  for (int kind = 0; kind < 2; kind++) {
    for (int i = 0; i < n; i++) lam[i] = 1.0 + i;
    lam[7] = kind == 0 ? -0.5 : 0.0;
    build(n, lam, U, M);
    for (int i = 0; i < n; i++) v[i] = uniform() - 0.5;
    memcpy(y, v, sizeof y);
    int steps;
    double est;
    assert_int_equal(krylov_power(&k, n, M, -1, 2, 1e-10, n, y, &steps, &est), 1);
    assert_memory_equal(y, v, sizeof y);
  }
  /* and a step limit too small to converge returns 1 */
  for (int i = 0; i < n; i++) lam[i] = pow(10.0, -4.0 * i / (n - 1));
  build(n, lam, U, M);
  memcpy(y, v, sizeof y);
  int steps;
  double est;
  assert_int_equal(krylov_power(&k, n, M, -1, 2, 1e-12, 9, y, &steps, &est), 1);
  krylov_free(&k);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(powers_match_the_exact_ones),
      cmocka_unit_test(well_conditioned_by_the_expansion),
      cmocka_unit_test(indefinite_and_singular_refused),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
