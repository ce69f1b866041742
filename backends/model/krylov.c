/* krylov.c — M^(p/q) v by the Lanczos process (krylov.h). */
#include "krylov.h"

#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

int krylov_init(Krylov *k, long maxn) {
  memset(k, 0, sizeof *k);
  k->maxn = maxn;
  size_t n = (size_t)(maxn > 0 ? maxn : 1);
  k->Q = malloc(sizeof(double) * (n + 1) * n);
  k->alpha = malloc(sizeof(double) * (n + 1));
  k->beta = malloc(sizeof(double) * (n + 1));
  k->d = malloc(sizeof(double) * (n + 1));
  k->e = malloc(sizeof(double) * (n + 1));
  k->S = malloc(sizeof(double) * n * n);
  k->lwork = (long)(1 + 4 * n + n * n);
  k->work = malloc(sizeof(double) * (size_t)k->lwork);
  k->iwork = malloc(sizeof(lapack_int) * (3 + 5 * n));
  _Static_assert(sizeof(lapack_int) == sizeof(int), "dstedc's iwork is held as int");
  k->cprev = malloc(sizeof(double) * (n + 1));
  k->c = malloc(sizeof(double) * (n + 1));
  k->w = malloc(sizeof(double) * n);
  return k->Q && k->alpha && k->beta && k->d && k->e && k->S && k->work && k->iwork && k->cprev && k->c && k->w
             ? 0
             : -1;
}

void krylov_free(Krylov *k) {
  free(k->Q), free(k->alpha), free(k->beta), free(k->d), free(k->e), free(k->S), free(k->work), free(k->iwork);
  free(k->cprev);
  free(k->c), free(k->w);
  memset(k, 0, sizeof *k);
}

/* c = S f(Λ) Sᵀ e₁ = f(T_K) e₁ from the first K steps (T_K = S Λ Sᵀ by
 * divide and conquer, dstedc: at the K of the programs, 30–40, it takes
 * about half the time of dstev's QR iteration); the approximation is
 * β Q_K c. 1 when T_K looks singular or indefinite, -1 when LAPACK failed. */
static int approximate(Krylov *k, int K, long p, long q) {
  memcpy(k->d, k->alpha, sizeof(double) * (size_t)K);
  memcpy(k->e, k->beta, sizeof(double) * (size_t)(K > 1 ? K - 1 : 1));
  lapack_int info = LAPACKE_dstedc_work(LAPACK_COL_MAJOR, 'I', K, k->d, k->e, k->S, K, k->work,
                                        (lapack_int)k->lwork, k->iwork, (lapack_int)(3 + 5 * k->maxn));
  if (info != 0) return -1;
  /* eigenvalues ascending: the smallest Ritz value bounds M's from above */
  if (!(k->d[0] > 1e-12 * fabs(k->d[K - 1]))) return 1;
  double r = (double)p / (double)q;
  for (int i = 0; i < K; i++) k->w[i] = k->S[(size_t)i * (size_t)K] * pow(k->d[i], r); /* S[0, i] f(λ_i) */
  cblas_dgemv(CblasColMajor, CblasNoTrans, K, K, 1.0, k->S, K, k->w, 1, 0.0, k->c, 1);
  return 0;
}

int krylov_power(Krylov *k, int n, const double *M, long p, long q, double tol, int max_steps, double *v, int *steps,
                 double *estimate) {
  *steps = 0;
  *estimate = INFINITY;
  if (n <= 0 || n > k->maxn) return 1;
  double beta0 = cblas_dnrm2(n, v, 1);
  if (beta0 == 0) {
    *estimate = 0;
    return 0;
  }
  if (max_steps > n) max_steps = n;
  for (int i = 0; i < n; i++) k->Q[i] = v[i] / beta0;
  /* The estimate compares approximations 4 steps apart; with full
   * reorthogonalization Q_K is orthonormal to rounding, so it is taken on
   * the coefficients, ‖y_K − y_{K−4}‖ / ‖y_K‖ = ‖c_K − (c_{K−4}, 0)‖ / ‖c_K‖,
   * and only the accepted c is lifted. Checks are every 4 steps from step
   * 8, or from 4 before k->start (rounded down to a multiple of 4) when the
   * caller knows where a similar call converged. */
  int first = k->start / 4 * 4 - 4 > 8 ? (int)(k->start / 4 * 4 - 4) : 8, prevK = 0;
  for (int j = 0; j < max_steps; j++) {
    double *qj = k->Q + (size_t)j * (size_t)n, *w = k->Q + (size_t)(j + 1) * (size_t)n;
    cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, M, n, qj, 1, 0.0, w, 1);
    k->alpha[j] = cblas_ddot(n, qj, 1, w, 1);
    /* full reorthogonalization against q_0 … q_j, twice ("twice is enough") */
    for (int pass = 0; pass < 2; pass++) {
      cblas_dgemv(CblasRowMajor, CblasNoTrans, j + 1, n, 1.0, k->Q, n, w, 1, 0.0, k->c, 1);
      cblas_dgemv(CblasRowMajor, CblasTrans, j + 1, n, -1.0, k->Q, n, k->c, 1, 1.0, w, 1);
    }
    double b = cblas_dnrm2(n, w, 1);
    k->beta[j] = b;
    int K = j + 1;
    /* the Krylov space is invariant (or complete): the approximation is exact */
    bool invariant = b <= 1e-13 * (fabs(k->alpha[j]) + (j > 0 ? k->beta[j - 1] : 0) + 1e-300) || K == n;
    if (invariant || (K >= first && K % 4 == 0)) {
      int rc = approximate(k, K, p, q);
      if (rc != 0) {
        k->start = 0;
        return rc;
      }
      if (invariant) *estimate = 0;
      else if (prevK > 0) {
        double diff = 0, norm = 0;
        for (int i = 0; i < K; i++) {
          double d = k->c[i] - (i < prevK ? k->cprev[i] : 0);
          diff += d * d, norm += k->c[i] * k->c[i];
        }
        *estimate = sqrt(diff / (norm > 0 ? norm : 1));
      }
      if (invariant || (prevK > 0 && *estimate <= tol)) {
        cblas_dgemv(CblasRowMajor, CblasTrans, K, n, beta0, k->Q, n, k->c, 1, 0.0, v, 1);
        *steps = K;
        /* converged at the first estimate: the next call may try 4 steps fewer */
        k->start = !invariant && prevK == first && K > 12 ? K - 4 : K;
        return 0;
      }
      memcpy(k->cprev, k->c, sizeof(double) * (size_t)K);
      prevK = K;
    }
    cblas_dscal(n, 1.0 / b, w, 1);
  }
  *steps = max_steps;
  k->start = 0;
  return 1;
}
