/* ooc_basis.c — a class basis out of core as coefficients of A (ooc.h):
 * B = A T, where A holds the class's mean and Gram directions, found by the
 * in-memory steps (gram_basis, pca_in_order, pca_merge) acting on A's
 * columns through C = AᵀA, never on A itself. */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "ooc.h"

/* y = C x (C symmetric K x K, full). */
static double quad(const double *C, long K, const double *x, const double *y, double *tmp) {
  cblas_dgemv(CblasColMajor, CblasNoTrans, (int)K, (int)K, 1.0, C, (int)K, y, 1, 0.0, tmp, 1);
  return cblas_ddot((int)K, x, 1, tmp, 1);
}

/* T (K x *m column-major, malloc'd): the class basis is B = A T, by the
 * in-memory steps acting on A's columns through C = AᵀA: each member's
 * Cholesky-QR (gram_basis), its [μ, U] in order (pca_in_order), the
 * members merged (pca_merge's Gram route). */
int ooc_coefficients(Ooc *o, int c, double **Tout, long *mout) {
  Stream *st = &o->st[c];
  RClass *rc = &o->m->classes[c];
  long K = st->K;
  double *C = st->C;
  for (long j = 0; j < K; j++) /* the lower triangle from the upper */
    for (long i = j + 1; i < K; i++) C[j * K + i] = C[i * K + j];
  double *Q = mem_calloc((size_t)(K * K) + 1, sizeof(double)), *tmp = mem_malloc(sizeof(double) * (size_t)(K + 1));
  double *R = mem_malloc(sizeof(double) * (size_t)(K * K) + 8), *v = mem_malloc(sizeof(double) * (size_t)(K + 1));
  double *cc = mem_malloc(sizeof(double) * (size_t)(K + 1));
  long nq = 0;
  int *kept = mem_calloc((size_t)rc->nmembers + 1, sizeof(int));
  if (!Q || !tmp || !R || !v || !cc || !kept) goto oom;
  for (int i = 0; i < rc->nmembers; i++) {
    RMember *mb = &rc->members[i];
    long k = st->k[i], cu = st->col[i] + (mb->center ? 1 : 0), q0 = nq;
    /* Cholesky-QR of U: U R⁻¹, R from C's block of U */
    if (k > 0) {
      for (long a = 0; a < k; a++)
        for (long b = 0; b < k; b++) R[b * k + a] = C[(cu + b) * K + cu + a];
      if (LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'U', (lapack_int)k, R, (lapack_int)k) != 0 ||
          LAPACKE_dtrtri(LAPACK_COL_MAJOR, 'U', 'N', (lapack_int)k, R, (lapack_int)k) != 0)
        return free(Q), free(tmp), free(R), free(v), free(cc), free(kept),
               error_set(o->err, o->errlen,
                         "class %s, member %s: its directions are numerically dependent out of core (Cholesky failed): "
                         "lower its cap or its energy fraction",
                         rc->label, mb->name);
    }
    /* the member's columns in order: μ first when centered, then U R⁻¹;
     * each kept when its remainder after the previous ones (twice) is above
     * OOC_DEPENDENT_TOL of its norm */
    long ncols = k + (mb->center ? 1 : 0);
    for (long j = 0; j < ncols; j++) {
      memset(v, 0, sizeof(double) * (size_t)K);
      if (mb->center && j == 0) v[st->col[i]] = 1;
      else {
        long u = mb->center ? j - 1 : j;
        for (long a = 0; a <= u; a++) v[cu + a] = R[u * k + a];
      }
      if (nq - q0 >= rc->n) break; /* n columns span the class's rows: any further one is dependent */
      if (!mb->center) { /* uncentered: U R⁻¹ is the member's basis as it is */
        memcpy(Q + nq * K, v, sizeof(double) * (size_t)K);
        nq++;
        continue;
      }
      double norm0 = sqrt(fmax(quad(C, K, v, v, tmp), 0));
      if (!(norm0 > 0)) continue;
      for (int pass = 0; pass < 2 && nq > q0; pass++) {
        for (long a = q0; a < nq; a++) cc[a - q0] = quad(C, K, Q + a * K, v, tmp);
        for (long a = q0; a < nq; a++) cblas_daxpy((int)K, -cc[a - q0], Q + a * K, 1, v, 1);
      }
      double norm = sqrt(fmax(quad(C, K, v, v, tmp), 0));
      if (!(norm > OOC_DEPENDENT_TOL * norm0)) continue;
      cblas_dscal((int)K, 1 / norm, v, 1);
      memcpy(Q + nq * K, v, sizeof(double) * (size_t)K);
      nq++;
    }
    kept[i] = (int)(nq - q0);
    mb->kept = kept[i];
  }
  free(v), free(cc);
  if (rc->nmembers == 1 || nq == 0) {
    free(tmp), free(R), free(kept);
    *Tout = Q, *mout = nq;
    return 0;
  }
  /* merged: the left singular vectors of [Q_1 … Q_r] through their Gram
   * matrix Qᵀ C Q, dropping dependent directions and at most n kept, and
   * one Cholesky-QR. The Gram matrix resolves σ only down to about √ε σ_max
   * (in memory a direction below 1e-6 σ_max sends pca_merge to the SVD,
   * which out of core is not at hand): below OOC_DEPENDENT_TOL σ_max a
   * direction is rounding (members sharing every row of a small class gave
   * n + 8 directions and a failed Cholesky-QR at the 1e-10 of the SVD's rule). */
  double *Y = mem_malloc(sizeof(double) * (size_t)(K * nq)), *Cq = mem_malloc(sizeof(double) * (size_t)(nq * nq));
  double *lam = mem_malloc(sizeof(double) * (size_t)nq), *T = NULL;
  long m = 0;
  if (!Y || !Cq || !lam) goto merge_done;
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)K, (int)nq, (int)K, 1.0, C, (int)K, Q, (int)K, 0.0, Y, (int)K);
  cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, (int)nq, (int)nq, (int)K, 1.0, Q, (int)K, Y, (int)K, 0.0, Cq, (int)nq);
  if (LAPACKE_dsyevd(LAPACK_COL_MAJOR, 'V', 'U', (lapack_int)nq, Cq, (lapack_int)nq, lam) != 0) goto merge_done;
  double s0 = sqrt(fmax(lam[nq - 1], 0));
  while (m < nq && m < rc->n && sqrt(fmax(lam[nq - 1 - m], 0)) > OOC_DEPENDENT_TOL * s0) m++;
  double *Wq = mem_malloc(sizeof(double) * (size_t)(nq * (m ? m : 1)));
  T = mem_malloc(sizeof(double) * (size_t)(K * (m ? m : 1)));
  if (!Wq || !T) {
    free(Wq);
    goto merge_done;
  }
  for (long j = 0; j < m; j++)
    for (long a = 0; a < nq; a++) Wq[j * nq + a] = Cq[(nq - 1 - j) * nq + a] / sqrt(lam[nq - 1 - j]);
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)K, (int)m, (int)nq, 1.0, Q, (int)K, Wq, (int)nq, 0.0, T, (int)K);
  free(Wq);
  if (m > 0) { /* Cholesky-QR: Tᵀ C T = RᵀR, T <- T R⁻¹ */
    double *Yt = mem_malloc(sizeof(double) * (size_t)(K * m));
    if (!Yt) goto merge_done;
    cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)K, (int)m, (int)K, 1.0, C, (int)K, T, (int)K, 0.0, Yt, (int)K);
    cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, (int)m, (int)m, (int)K, 1.0, T, (int)K, Yt, (int)K, 0.0, Cq, (int)m);
    free(Yt);
    if (LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'U', (lapack_int)m, Cq, (lapack_int)m) != 0) goto merge_done;
    cblas_dtrsm(CblasColMajor, CblasRight, CblasUpper, CblasNoTrans, CblasNonUnit, (int)K, (int)m, 1.0, Cq, (int)m, T,
                (int)K);
  }
  free(Y), free(Cq), free(lam), free(Q), free(tmp), free(R), free(kept);
  *Tout = T, *mout = m;
  return 0;
merge_done:
  free(Y), free(Cq), free(lam), free(T), free(Q), free(tmp), free(R), free(kept);
  return error_set(o->err, o->errlen, "class %s: merging its member bases out of core failed", rc->label);
oom:
  free(Q), free(tmp), free(R), free(v), free(cc), free(kept);
  return error_set(o->err, o->errlen, "out of memory orthonormalizing the basis of class %s", rc->label);
}
