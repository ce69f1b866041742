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
#include "scratch.h"

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

/* The arrays of one ooc_coefficients (its scratch's) and what they hold. */
typedef struct Coef {
  const double *C; /* R_A: K x K upper triangular, column-major */
  long K;
  double *Q;       /* K x K: every member's orthonormal columns, member after member */
  double *tmp, *t2; /* room for K each (inner) */
  double *work;    /* room for K K + K (member_r) */
  double *R;       /* room for K x K: a member's R factor, then its inverse */
  double *v, *cc;  /* room for K each: the column under way, its coefficients */
  int *kept;       /* per member: its columns in Q */
  long *first;     /* per member: its first column in Q */
} Coef;

/* Every member's columns of A orthonormalized in order into w->Q (their
 * count in *nq; the member's report's kept set): each member's
 * Cholesky-QR, its [μ, U] in order (pca_in_order). 0, or -1 with the
 * training's error. */
static int member_columns(Ooc *o, int c, Coef *w, long *nq_out) {
  Stream *st = &o->st[c];
  RClass *rc = &o->t->m->classes[c];
  long K = w->K, nq = 0;
  const double *C = w->C;
  double tol_member = st->blockwise ? OOC_BLOCKWISE_TOL : PCA_DEPENDENT_TOL;
  double *Q = w->Q, *R = w->R, *v = w->v, *cc = w->cc, *tmp = w->tmp, *t2 = w->t2;
  for (int i = 0; i < rc->nmembers; i++) {
    RMember *mb = &rc->members[i];
    long k = st->k[i], cu = st->col[i] + (mb->center ? 1 : 0), q0 = nq;
    w->first[i] = q0;
    /* QR of U: U R⁻¹, R from the QR of R_A's block of U */
    if (k > 0 && (member_r(C, K, cu, k, R, w->work) != 0 ||
                  LAPACKE_dtrtri(LAPACK_COL_MAJOR, 'U', 'N', (lapack_int)k, R, (lapack_int)k) != 0))
      return err_set(o->t->err,
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
    w->kept[i] = (int)(nq - q0);
    mb->kept = w->kept[i];
  }
  *nq_out = nq;
  return 0;
}

/* The members' columns of w->Q merged into T (K x nq room) as pca_merge
 * merges: interleaved (the first of every member, then the second, …) and
 * orthonormalized in that order, twice, each kept when its remainder is
 * above `tol` of its norm, and at most n kept. Their count. */
static long merge_columns(const RClass *rc, const Coef *w, double tol, double *T) {
  long K = w->K, m = 0, kmax = 0;
  double *v = w->v, *cc = w->cc, *tmp = w->tmp, *t2 = w->t2;
  for (int i = 0; i < rc->nmembers; i++) kmax = w->kept[i] > kmax ? w->kept[i] : kmax;
  for (long j = 0; j < kmax; j++)
    for (int i = 0; i < rc->nmembers && m < rc->n; i++) {
      if (j >= w->kept[i]) continue;
      memcpy(v, w->Q + (w->first[i] + j) * K, sizeof(double) * (size_t)K);
      double norm0 = inner(w->C, K, v, NULL, tmp, t2);
      if (!(norm0 > 0)) continue;
      for (int pass = 0; pass < 2 && m > 0; pass++) {
        for (long a = 0; a < m; a++) cc[a] = inner(w->C, K, T + a * K, v, tmp, t2);
        for (long a = 0; a < m; a++) cblas_daxpy((int)K, -cc[a], T + a * K, 1, v, 1);
      }
      double norm = inner(w->C, K, v, NULL, tmp, t2);
      if (!(norm > tol * norm0)) continue;
      cblas_dscal((int)K, 1 / norm, v, 1);
      memcpy(T + m * K, v, sizeof(double) * (size_t)K);
      m++;
    }
  return m;
}

/* T (K x *m column-major, malloc'd): the class basis is B = A T, by the
 * in-memory steps acting on A's columns through C = AᵀA: each member's
 * Cholesky-QR, its [μ, U] in order (pca_in_order), the members merged as
 * pca_merge merges them (interleaved, in order). */
int ooc_coefficients(Ooc *o, int c, double **Tout, long *mout) {
  Stream *st = &o->st[c];
  const RClass *rc = &o->t->m->classes[c];
  long K = st->K, nq = 0, m = 0;
  double *C = st->RA;
  for (long j = 0; j < K; j++) /* the upper triangle only: below it dtpqrt leaves nothing of use */
    for (long i = j + 1; i < K; i++) C[j * K + i] = 0;
  Scratch s = SCRATCH_OF(o->t->err);
  size_t k = (size_t)K;
  Coef w = {.C = C, .K = K, .Q = scratch_array(&s, k * k + 1, sizeof(double)),
            .tmp = scratch_array(&s, 2 * k + 1, sizeof(double)), .work = scratch_array(&s, k * k + k + 1, sizeof(double)),
            .R = scratch_array(&s, k * k + 1, sizeof(double)), .v = scratch_array(&s, k + 1, sizeof(double)),
            .cc = scratch_array(&s, k + 1, sizeof(double)), .kept = scratch_array(&s, (size_t)rc->nmembers + 1, sizeof(int)),
            .first = scratch_array(&s, (size_t)rc->nmembers + 1, sizeof(long))};
  w.t2 = w.tmp ? w.tmp + K : NULL;
  bool room = w.Q && w.tmp && w.work && w.R && w.v && w.cc && w.kept && w.first;
  int status = room ? member_columns(o, c, &w, &nq) : -1;
  double *T = status == 0 ? mem_malloc(sizeof(double) * (k * (size_t)nq + 1)) : NULL; /* the caller's */
  if (!room || (status == 0 && !T))
    status = err_set(o->t->err, "out of memory orthonormalizing the basis of class %s", rc->label);
  else if (status == 0 && (rc->nmembers == 1 || nq == 0)) memcpy(T, w.Q, sizeof(double) * k * (size_t)nq), m = nq;
  else if (status == 0) m = merge_columns(rc, &w, st->blockwise ? OOC_BLOCKWISE_TOL : PCA_MERGE_TOL, T);
  scratch_release(&s);
  if (status == 0) *Tout = T, *mout = m;
  return status;
}
