/* ooc_basis.c — a class basis out of core as coefficients of A (ooc.h):
 * B = A T, where A holds the class's means and its members' directions X W
 * (W from the SVD of their R factors), found by the in-memory steps
 * (a QR of each member's directions, pca_in_order, pca_merge) acting on
 * A's columns through A's R factor R_A (A = Q_A R_A), never on A itself:
 * ⟨A x, A y⟩ = ⟨R_A x, R_A y⟩ and ‖A x‖ = ‖R_A x‖ to rounding, so the
 * remainders are resolved as from the vectors and the in-memory
 * tolerances apply (where AᵀA resolved them only to about √ε). */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "ooc.h"

/* ⟨A x, A y⟩ = ⟨R x, R y⟩ (R upper K x K column-major); t1, t2: room for
 * K. y NULL: ‖A x‖. */
static double inner(const double *R, long K, const double *x, const double *y, double *t1, double *t2) {
  memcpy(t1, x, sizeof(double) * (size_t)K);
  cblas_dtrmv(CblasColMajor, CblasUpper, CblasNoTrans, CblasNonUnit, (int)K, R, (int)K, t1, 1);
  if (!y) return cblas_dnrm2((int)K, t1, 1);
  memcpy(t2, y, sizeof(double) * (size_t)K);
  cblas_dtrmv(CblasColMajor, CblasUpper, CblasNoTrans, CblasNonUnit, (int)K, R, (int)K, t2, 1);
  return cblas_ddot((int)K, t1, 1, t2, 1);
}

/* The k x k R factor (positive diagonal, column-major in R) of a member's
 * directions, A's columns [cu, cu + k): the QR of R_A's columns there
 * (dgeqrf; `work`: room for K k + k). 0, or LAPACK's info. */
static int member_r(const double *RA, long K, long cu, long k, double *R, double *work) {
  double *B = work, *tau = work + K * k;
  memcpy(B, RA + cu * K, sizeof(double) * (size_t)(K * k));
  lapack_int info = LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (lapack_int)K, (lapack_int)k, B, (lapack_int)K, tau);
  if (info != 0) return (int)info;
  for (long b = 0; b < k; b++) /* row a times the sign of its diagonal: Q_u's column a flipped */
    for (long a = 0; a < k; a++) R[b * k + a] = a <= b ? (B[a * K + a] < 0 ? -B[b * K + a] : B[b * K + a]) : 0;
  return 0;
}

/* T (K x *m column-major, malloc'd): the class basis is B = A T, by the
 * in-memory steps acting on A's columns through C = AᵀA: each member's
 * Cholesky-QR, its [μ, U] in order (pca_in_order), the members merged as
 * pca_merge merges them (interleaved, in order). */
int ooc_coefficients(Ooc *o, int c, double **Tout, long *mout) {
  Stream *st = &o->st[c];
  RClass *rc = &o->t->m->classes[c];
  long K = st->K;
  double tol_member = st->blockwise ? OOC_BLOCKWISE_TOL : PCA_DEPENDENT_TOL;
  double tol_merge = st->blockwise ? OOC_BLOCKWISE_TOL : PCA_MERGE_TOL;
  double *C = st->RA;
  for (long j = 0; j < K; j++) /* the upper triangle only: below it dtpqrt leaves nothing of use */
    for (long i = j + 1; i < K; i++) C[j * K + i] = 0;
  double *Q = mem_calloc((size_t)(K * K) + 1, sizeof(double)), *tmp = mem_malloc(sizeof(double) * (size_t)(2 * K + 1));
  double *work = mem_malloc(sizeof(double) * (size_t)(K * K + K + 1)), *t2 = NULL;
  double *R = mem_malloc(sizeof(double) * (size_t)(K * K) + 8), *v = mem_malloc(sizeof(double) * (size_t)(K + 1));
  double *cc = mem_malloc(sizeof(double) * (size_t)(K + 1));
  long nq = 0;
  int *kept = mem_calloc((size_t)rc->nmembers + 1, sizeof(int));
  long *first = mem_calloc((size_t)rc->nmembers + 1, sizeof(long));
  if (!Q || !tmp || !work || !R || !v || !cc || !kept || !first) goto oom;
  t2 = tmp + K;
  for (int i = 0; i < rc->nmembers; i++) {
    RMember *mb = &rc->members[i];
    long k = st->k[i], cu = st->col[i] + (mb->center ? 1 : 0), q0 = nq;
    first[i] = q0;
    /* QR of U: U R⁻¹, R from the QR of R_A's block of U */
    if (k > 0 && (member_r(C, K, cu, k, R, work) != 0 ||
                  LAPACKE_dtrtri(LAPACK_COL_MAJOR, 'U', 'N', (lapack_int)k, R, (lapack_int)k) != 0))
      return free(Q), free(tmp), free(work), free(R), free(v), free(cc), free(kept), free(first),
             err_set(o->t->err,
                     "class %s, member %s: its directions are numerically dependent out of core (their R factor is "
                     "singular): lower its cap or its energy fraction",
                     rc->label, mb->name);
    /* the member's columns in order: μ first when centered, then U R⁻¹;
     * each kept when its remainder after the previous ones (twice) is above
     * PCA_DEPENDENT_TOL of its norm, as pca_in_order keeps it */
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
      double norm0 = inner(C, K, v, NULL, tmp, t2);
      if (!(norm0 > 0)) continue;
      for (int pass = 0; pass < 2 && nq > q0; pass++) {
        for (long a = q0; a < nq; a++) cc[a - q0] = inner(C, K, Q + a * K, v, tmp, t2);
        for (long a = q0; a < nq; a++) cblas_daxpy((int)K, -cc[a - q0], Q + a * K, 1, v, 1);
      }
      double norm = inner(C, K, v, NULL, tmp, t2);
      if (!(norm > tol_member * norm0)) continue;
      cblas_dscal((int)K, 1 / norm, v, 1);
      memcpy(Q + nq * K, v, sizeof(double) * (size_t)K);
      nq++;
    }
    kept[i] = (int)(nq - q0);
    mb->kept = kept[i];
  }
  if (rc->nmembers == 1 || nq == 0) {
    free(tmp), free(work), free(R), free(kept), free(first), free(v), free(cc);
    *Tout = Q, *mout = nq;
    return 0;
  }
  /* merged as pca_merge merges: the members' columns interleaved (the first of every member,
   * then the second, …) and orthonormalized in that order, twice, each kept when its remainder
   * is above PCA_MERGE_TOL of its norm, and at most n kept */
  double *T = mem_malloc(sizeof(double) * (size_t)(K * nq + 1));
  long m = 0, kmax = 0;
  if (!T) goto oom;
  for (int i = 0; i < rc->nmembers; i++) kmax = kept[i] > kmax ? kept[i] : kmax;
  for (long j = 0; j < kmax; j++)
    for (int i = 0; i < rc->nmembers && m < rc->n; i++) {
      if (j >= kept[i]) continue;
      memcpy(v, Q + (first[i] + j) * K, sizeof(double) * (size_t)K);
      double norm0 = inner(C, K, v, NULL, tmp, t2);
      if (!(norm0 > 0)) continue;
      for (int pass = 0; pass < 2 && m > 0; pass++) {
        for (long a = 0; a < m; a++) cc[a] = inner(C, K, T + a * K, v, tmp, t2);
        for (long a = 0; a < m; a++) cblas_daxpy((int)K, -cc[a], T + a * K, 1, v, 1);
      }
      double norm = inner(C, K, v, NULL, tmp, t2);
      if (!(norm > tol_merge * norm0)) continue;
      cblas_dscal((int)K, 1 / norm, v, 1);
      memcpy(T + m * K, v, sizeof(double) * (size_t)K);
      m++;
    }
  free(Q), free(tmp), free(work), free(R), free(kept), free(first), free(v), free(cc);
  *Tout = T, *mout = m;
  return 0;
oom:
  free(Q), free(tmp), free(work), free(R), free(v), free(cc), free(kept), free(first);
  return err_set(o->t->err, "out of memory orthonormalizing the basis of class %s", rc->label);
}
