/* cavity_la.c — the dense linear algebra of one reduced cavity step at the paper's basis sizes
 * (examples/fluids/reduced.c, m_u 127 and a 58-column null space of D̂), timed alone on a
 * random SPD V̂, one thread, best of 200: the Cholesky factorization of V̂ (volume_factor),
 * the projection's dtrsm and dsyrk (red_projection), and 15 steps of the Arnoldi exponential's
 * operator (two dtrsv and a dgemv each, red_expmv). What the step costs beyond the bytes of its
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
  free(V), free(V0), free(X), free(X0), free(K), free(A), free(x), free(y);
  return 0;
}
