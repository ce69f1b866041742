/* cavity_la.c — the dense linear algebra of one reduced cavity step at the paper's basis sizes
 * (examples/fluids/reduced.c, m_u 127 and a 58-column null space of D̂), timed alone on a
 * random SPD V̂, one thread, best of 200: the Cholesky factorization of V̂ (volume_factor),
 * the projection's dtrsm and dsyrk (red_projection), 15 steps of the Arnoldi exponential's
 * operator (two dtrsv and a dgemv each, red_expmv), and the projection's other products the way
 * they were (P̂ formed) and are (projection_products). What the step costs beyond the bytes of its
 * tensors (examples/fluids/README.md, "The reduced step's bytes").
 *
 *     gcc -O2 bench/cavity_la.c -llapacke -lopenblas -o /tmp/cavity_la
 *     OPENBLAS_NUM_THREADS=1 /tmp/cavity_la [m_u [null space]]
 */
#define _POSIX_C_SOURCE 200809L
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* The projection's products besides dtrsm and dsyrk (red_projection), best of reps, two ways:
 * P̂ = Σ ĝ_l P̂_l formed, then P̂ f_p and P̂ f̂ each solved with V̂ (two dtrsv pairs: the way
 * before), against P̂ f_p by one dgemv over the stacked slices and û = q + L⁻ᵀ X y (the way
 * now: one dgemv over X and one dtrsv for the second half). m_g 5, m_f 64. */
static void projection_products(int mu, int nn, const double *L, const double *X, int reps, double best[2]) {
  enum { MG = 5, MF = 64 };
  double *Ps = malloc(sizeof(double) * MG * mu * MF), *P1 = malloc(sizeof(double) * mu * MF);
  double *t = malloc(sizeof(double) * MG * mu), *q = malloc(sizeof(double) * mu), *z = malloc(sizeof(double) * mu);
  double g[MG] = {1, 0.1, -0.2, 0.05, 0.3}, fp[MF], f[MF], y[MF];
  for (int i = 0; i < MG * mu * MF; i++) Ps[i] = rand() / (double)RAND_MAX;
  for (int i = 0; i < MF; i++) fp[i] = 1.0 / (i + 1), f[i] = 1.0 / (i + 2), y[i] = 1.0 / (i + 3);
  best[0] = best[1] = 1e9;
  for (int r = 0; r < reps; r++) {
    double t0 = now();
    memset(P1, 0, sizeof(double) * mu * MF);
    for (int l = 0; l < MG; l++) cblas_daxpy(mu * MF, g[l], Ps + (size_t)l * mu * MF, 1, P1, 1);
    for (int k = 0; k < 2; k++) {
      cblas_dgemv(CblasRowMajor, CblasNoTrans, mu, MF, 1.0, P1, MF, k ? f : fp, 1, 0.0, z, 1);
      cblas_dtrsv(CblasRowMajor, CblasLower, CblasNoTrans, CblasNonUnit, mu, L, mu, z, 1);
      cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, mu, L, mu, z, 1);
    }
    best[0] = fmin(best[0], now() - t0);
    t0 = now();
    cblas_dgemv(CblasRowMajor, CblasNoTrans, MG * mu, MF, 1.0, Ps, MF, fp, 1, 0.0, t, 1);
    memset(q, 0, sizeof(double) * mu);
    for (int l = 0; l < MG; l++) cblas_daxpy(mu, g[l], t + l * mu, 1, q, 1);
    cblas_dtrsv(CblasRowMajor, CblasLower, CblasNoTrans, CblasNonUnit, mu, L, mu, q, 1);
    cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, mu, L, mu, q, 1);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, mu, nn, 1.0, X, nn, y, 1, 0.0, z, 1);
    cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, mu, L, mu, z, 1);
    cblas_daxpy(mu, 1.0, z, 1, q, 1);
    best[1] = fmin(best[1], now() - t0);
  }
  free(Ps), free(P1), free(t), free(q), free(z);
}

int main(int argc, char **argv) {
  int mu = argc > 1 ? atoi(argv[1]) : 127, nn = argc > 2 ? atoi(argv[2]) : 58, reps = 200;
  if (mu < 2 || nn < 1 || nn > mu) {
    fputs("usage: cavity_la [m_u >= 2 [null space 1..m_u]]\n", stderr);
    return 2;
  }
  double *V = malloc(sizeof(double) * mu * mu), *V0 = malloc(sizeof(double) * mu * mu);
  double *X = malloc(sizeof(double) * mu * nn), *X0 = malloc(sizeof(double) * mu * nn);
  double *K = malloc(sizeof(double) * nn * nn), *A = malloc(sizeof(double) * mu * mu);
  double *x = malloc(sizeof(double) * mu), *y = malloc(sizeof(double) * mu);
  srand(1);
  for (int i = 0; i < mu * mu; i++) A[i] = rand() / (double)RAND_MAX;
  for (int i = 0; i < mu; i++) /* diagonally dominant, symmetric: SPD */
    for (int j = 0; j < mu; j++) V0[i * mu + j] = (i == j ? mu : 0) + 0.005 * (A[i * mu + j] + A[j * mu + i]);
  for (int i = 0; i < mu * nn; i++) X0[i] = rand() / (double)RAND_MAX;
  for (int i = 0; i < mu; i++) x[i] = 1.0 / (i + 1);
  double best[4] = {1e9, 1e9, 1e9, 1e9};
  for (int r = 0; r < reps; r++) {
    double t;
    memcpy(V, V0, sizeof(double) * mu * mu);
    t = now();
    if (LAPACKE_dpotrf_work(LAPACK_COL_MAJOR, 'U', mu, V, mu) != 0) {
      fputs("cavity_la: the test matrix is not positive definite\n", stderr);
      return 1;
    }
    best[0] = fmin(best[0], now() - t);
    memcpy(X, X0, sizeof(double) * mu * nn);
    t = now();
    cblas_dtrsm(CblasRowMajor, CblasLeft, CblasLower, CblasNoTrans, CblasNonUnit, mu, nn, 1.0, V, mu, X, nn);
    best[1] = fmin(best[1], now() - t);
    t = now();
    cblas_dsyrk(CblasRowMajor, CblasLower, CblasTrans, nn, mu, 1.0, X, nn, 0.0, K, nn);
    best[2] = fmin(best[2], now() - t);
    t = now();
    for (int k = 0; k < 15; k++) {
      cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, mu, V, mu, x, 1);
      cblas_dgemv(CblasRowMajor, CblasNoTrans, mu, mu, 1.0, A, mu, x, 1, 0.0, y, 1);
      cblas_dtrsv(CblasRowMajor, CblasLower, CblasNoTrans, CblasNonUnit, mu, V, mu, y, 1);
      double n = cblas_dnrm2(mu, y, 1);
      for (int i = 0; i < mu; i++) x[i] = y[i] / n;
    }
    best[3] = fmin(best[3], now() - t);
  }
  printf("m_u %d, null space %d, one thread, best of %d, microseconds: dpotrf %.1f; dtrsm %.1f; dsyrk %.1f; "
         "an Arnoldi step (2 dtrsv + dgemv) %.1f\n",
         mu, nn, reps, 1e6 * best[0], 1e6 * best[1], 1e6 * best[2], 1e6 * best[3] / 15);
  double pp[2];
  projection_products(mu, nn, V, X, reps, pp);
  printf("the projection's other products (m_g 5, m_f 64): P̂ formed, P̂ f_p and P̂ f̂ solved with V̂ %.1f; P̂ f_p over "
         "the stacked slices, û = q + L⁻ᵀ X y %.1f\n",
         1e6 * pp[0], 1e6 * pp[1]);
  free(V), free(V0), free(X), free(X0), free(K), free(A), free(x), free(y);
  return 0;
}
