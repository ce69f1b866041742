/* pca.c — bases from snapshots (DESIGN §5; paper §8.2).
 *
 * One PCA per member, truncated at an energy fraction and a cap. Centered
 * by default (pca_basis): the member's mean μ is always kept and the
 * leading left singular vectors of the snapshots minus μ fill the rest, as
 * many as reach the energy fraction of the *centered* energy — on a
 * deforming mesh the rest shape dominates the uncentered energy, and the
 * paper's uncentered rule (the mean a direction like any other) then drops
 * the deformation modes. The basis stays linear: [μ, U_c] orthonormalized.
 * A class's member bases are concatenated and re-orthonormalized, dropping
 * dependent directions (paper §6.1: two 60-vector bases gave a 120-vector
 * one). All factorizations through LAPACKE.
 *
 * Tall snapshot matrices (n ≥ 4 columns) go through their Gram matrix, the
 * method of snapshots of DESIGN §5: G = XᵀX (one dsyrk or dgemm per block
 * pair), its eigenvalues and the kept eigenvectors V (pca_top_eigen),
 * U = X V Σ⁻¹ (dgemm), one Cholesky-QR
 * pass to restore orthonormality — an order of magnitude faster than a
 * tall SVD, whose QR is bandwidth-bound. The Gram matrix resolves singular
 * values only down to about √ε σ_max, so when a direction the result needs
 * (kept, or to be told apart from a dependent one) lies below
 * PCA_GRAM_TOL σ_max, the SVD (dgesdd) decides instead. */
#include <cblas.h>
#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "train.h"

/* Singular values below this fraction of the largest are dependent
 * directions, not data. */
#define PCA_RANK_TOL 1e-10
/* Singular values the Gram route resolves: above this fraction of the largest. */
#define PCA_GRAM_TOL 1e-6
/* A direction whose remainder after removing the previous ones is below
 * this fraction of its norm is dependent on them (pca_in_order). */
#define PCA_DEPENDENT_TOL 1e-8

/* Snapshots whose largest entry lies outside [PCA_SCALE_MIN, 1/PCA_SCALE_MIN]
 * are scaled to O(1) before a PCA: beyond it, sums of squares over up to
 * 1e30 entries would leave the range of doubles (1e-308..1e308). */
#define PCA_SCALE_MIN 1e-100

/* A Gram matrix whose largest diagonal entry (a snapshot's squared norm) is
 * below this lost its small entries to underflow. */
#define PCA_GRAM_MIN 1e-290

/* A block of columns of a snapshot matrix with n rows: column-major (ld n)
 * or row-major (ld k). */
typedef struct Cols {
  const double *p;
  long k;
  bool colmajor;
} Cols;

static CBLAS_TRANSPOSE as_rows(const Cols *c) { return c->colmajor ? CblasTrans : CblasNoTrans; }
static long ld(const Cols *c, long n) { return c->colmajor ? n : c->k; }

/* pca_top_eigen goes the whole way (dsyevd) when it is asked for more than
 * this fraction of the eigenvectors: from about three quarters on, the
 * back-transformation of the partial route costs what divide and conquer
 * saves (bench/gram.md: at S 1,000 and 3,000, k = S/2 is still 1.1 and 1.5
 * times faster, k = S 0.85 and 0.94 times as fast).
 * A build may set it to compare the routes: 2 always partial, 0 never
 * (dsyevd for every k > 0). */
#ifndef PCA_EIGEN_PARTIAL_MAX
#define PCA_EIGEN_PARTIAL_MAX 0.5
#endif

/* The eigenvectors of the k largest eigenvalues of the tridiagonal matrix
 * with diagonal d[0..S) and off-diagonal e[0..S-1), ascending, into V
 * (S x k column-major): by MRRR (dstemr), or where that fails, by
 * bisection and inverse iteration (dstebz, dstein), as dsyevr does. d and
 * e are left as they were. 0, or LAPACK's info (-1 when out of memory). */
static lapack_int tridiagonal_top_vectors(long S, const double *d, const double *e, long k, double *V) {
  double *d2 = mem_malloc(sizeof(double) * (size_t)S), *e2 = mem_malloc(sizeof(double) * (size_t)S);
  double *w = mem_malloc(sizeof(double) * (size_t)S);
  lapack_int *iw = mem_malloc(sizeof(lapack_int) * (size_t)(2 * S + 2)), m = 0, nsplit = 0, info = -1;
  if (!d2 || !e2 || !w || !iw) goto done;
  memcpy(d2, d, sizeof(double) * (size_t)S);
  memcpy(e2, e, sizeof(double) * (size_t)S);
  lapack_logical tryrac = 1;
  info = LAPACKE_dstemr(LAPACK_COL_MAJOR, 'V', 'I', (lapack_int)S, d2, e2, 0, 0, (lapack_int)(S - k + 1), (lapack_int)S,
                        &m, w, V, (lapack_int)S, (lapack_int)k, iw, &tryrac);
  if (info == 0 && m == k) goto done;
  /* iw: the blocks of the eigenvalues, then where T splits */
  info = LAPACKE_dstebz('I', 'B', (lapack_int)S, 0, 0, (lapack_int)(S - k + 1), (lapack_int)S, 0, d, e, &m, &nsplit, w,
                        iw, iw + S);
  if (info == 0 && m != k) info = -1;
  if (info == 0) {
    lapack_int *ifail = mem_malloc(sizeof(lapack_int) * (size_t)k);
    info = ifail ? LAPACKE_dstein(LAPACK_COL_MAJOR, (lapack_int)S, d, e, m, w, iw, iw + S, V, (lapack_int)S, ifail) : -1;
    free(ifail);
  }
  for (long j = 0; info == 0 && j < k; j++) { /* by block to ascending */
    long lo = j;
    for (long i = j + 1; i < k; i++) lo = w[i] < w[lo] ? i : lo;
    if (lo == j) continue;
    double t = w[j];
    w[j] = w[lo], w[lo] = t;
    cblas_dswap((int)S, V + j * S, 1, V + lo * S, 1);
  }
done:
  free(d2), free(e2), free(w), free(iw);
  return info;
}

int pca_top_eigen(long S, double *G, long k, double *lam, double *V) {
  if (S <= 0) return 0;
  if (k > S) k = S;
  if (k > PCA_EIGEN_PARTIAL_MAX * (double)S) {
    lapack_int info = LAPACKE_dsyevd(LAPACK_COL_MAJOR, 'V', 'U', (lapack_int)S, G, (lapack_int)S, lam);
    if (info != 0) return (int)info;
    for (long j = 0; j < k; j++) memcpy(V + j * S, G + (S - 1 - j) * S, sizeof(double) * (size_t)S);
    return 0;
  }
  /* G = Q T Qᵀ (dsytrd), T's every eigenvalue (dsterf on a copy), the top
   * k eigenvectors of T, then Q applied to them (dormtr) */
  double *d = mem_malloc(sizeof(double) * (size_t)S), *e = mem_calloc((size_t)S, sizeof(double));
  double *tau = mem_malloc(sizeof(double) * (size_t)S), *w = mem_malloc(sizeof(double) * (size_t)S);
  lapack_int info = -1;
  if (!d || !e || !tau || !w) goto done;
  if ((info = LAPACKE_dsytrd(LAPACK_COL_MAJOR, 'U', (lapack_int)S, G, (lapack_int)S, d, e, tau)) != 0) goto done;
  memcpy(lam, d, sizeof(double) * (size_t)S);
  memcpy(w, e, sizeof(double) * (size_t)S);
  if ((info = LAPACKE_dsterf((lapack_int)S, lam, w)) != 0 || k == 0) goto done;
  if ((info = tridiagonal_top_vectors(S, d, e, k, V)) != 0) goto done;
  if ((info = LAPACKE_dormtr(LAPACK_COL_MAJOR, 'L', 'U', 'N', (lapack_int)S, (lapack_int)k, G, (lapack_int)S, tau, V,
                             (lapack_int)S)) != 0)
    goto done;
  for (long j = 0; j < k / 2; j++) /* ascending to descending */
    cblas_dswap((int)S, V + j * S, 1, V + (k - 1 - j) * S, 1);
done:
  free(d), free(e), free(tau), free(w);
  return (int)info;
}

typedef enum { GRAM_DONE, GRAM_UNRESOLVED, GRAM_FAILED } GramResult;

/* Left singular vectors of X = [X_0 … X_{r-1}] (n rows, K columns) through
 * the Gram matrix: on GRAM_DONE, *U (n x kept, row-major) and the singular
 * values s[0..K) descending. `choose` picks how many to keep from s, at
 * most `kmax` (only that many eigenvectors are formed: pca_top_eigen); it
 * is told unresolved ones are below resolved (s below PCA_GRAM_TOL s[0]
 * unreliable): GRAM_UNRESOLVED when it needs one. */
typedef long (*ChooseFn)(const double *s, long K, const void *arg, bool *unresolved);

static GramResult gram_basis(long n, int r, const Cols *X, ChooseFn choose, const void *arg, long kmax, double *s,
                             double **U, long *kept_out) {
  long K = 0;
  for (int i = 0; i < r; i++) K += X[i].k;
  if (kmax > K) kmax = K;
  double *G = mem_calloc((size_t)(K * K), sizeof(double)), *lam = mem_malloc(sizeof(double) * (size_t)K);
  double *V = mem_malloc(sizeof(double) * (size_t)(K * (kmax ? kmax : 1))), *W = NULL, *Ut = NULL;
  GramResult res = GRAM_FAILED;
  if (!G || !lam || !V) goto done;
  /* G = XᵀX, column-major K x K, upper triangle */
  for (int i = 0, oi = 0; i < r; oi += (int)X[i].k, i++)
    for (int j = i, oj = oi; j < r; oj += (int)X[j].k, j++) {
      double *Gij = G + (size_t)oj * (size_t)K + (size_t)oi;
      if (i == j)
        cblas_dsyrk(CblasColMajor, CblasUpper, as_rows(&X[i]), (int)X[i].k, (int)n, 1.0,
                    X[i].p, (int)ld(&X[i], n), 0.0, Gij, (int)K);
      else
        cblas_dgemm(CblasColMajor, as_rows(&X[i]), X[j].colmajor ? CblasNoTrans : CblasTrans, (int)X[i].k,
                    (int)X[j].k, (int)n, 1.0, X[i].p, (int)ld(&X[i], n), X[j].p, (int)ld(&X[j], n), 0.0, Gij, (int)K);
    }
  if (pca_top_eigen(K, G, kmax, lam, V) != 0) goto done;
  for (long i = 0; i < K; i++) s[i] = sqrt(fmax(lam[K - 1 - i], 0.0)); /* descending */
  bool unresolved = false;
  long kept = choose(s, K, arg, &unresolved);
  if (kept > kmax) goto done; /* `choose` keeps at most kmax: a bug if not */
  if (unresolved || (kept > 0 && !(s[kept - 1] > PCA_GRAM_TOL * s[0]))) {
    res = GRAM_UNRESOLVED;
    goto done;
  }
  long kk = kept ? kept : 1;
  /* W = V_kept Σ⁻¹ (K x kept, column-major), then Uᵀ = Σ_i W_iᵀ X_iᵀ
   * (kept x n column-major = U row-major) */
  W = mem_malloc(sizeof(double) * (size_t)(K * kk));
  Ut = mem_calloc((size_t)(n * kk), sizeof(double));
  if (!W || !Ut) goto done;
  for (long j = 0; j < kept; j++)
    for (long i = 0; i < K; i++) W[j * K + i] = V[j * K + i] / s[j];
  for (int i = 0, oi = 0; i < r && kept > 0; oi += (int)X[i].k, i++)
    cblas_dgemm(CblasColMajor, CblasTrans, as_rows(&X[i]), (int)kept, (int)n, (int)X[i].k, 1.0, W + oi, (int)K,
                X[i].p, (int)ld(&X[i], n), 1.0, Ut, (int)kk);
  if (kept > 0) { /* Cholesky-QR: C = UᵀU = RᵀR, U <- U R⁻¹ */
    double *C = G; /* K x K >= kept x kept, no longer needed */
    cblas_dsyrk(CblasColMajor, CblasUpper, CblasNoTrans, (int)kept, (int)n, 1.0, Ut, (int)kept, 0.0, C, (int)kept);
    if (LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'U', (lapack_int)kept, C, (lapack_int)kept) != 0) {
      res = GRAM_UNRESOLVED;
      goto done;
    }
    cblas_dtrsm(CblasColMajor, CblasLeft, CblasUpper, CblasTrans, CblasNonUnit, (int)kept, (int)n, 1.0, C, (int)kept,
                Ut, (int)kept);
  }
  *U = Ut;
  Ut = NULL;
  *kept_out = kept;
  res = GRAM_DONE;
done:
  free(G);
  free(lam);
  free(V);
  free(W);
  free(Ut);
  return res;
}

/* Σ (s_i / s_0)²: the energy of singular values `s` (descending) relative
 * to the largest's, so that it neither underflows (data at 1e-200, whose
 * squares are 0) nor overflows (1e200) — the truncation is scale-invariant
 * (issue 24). Energies in the choices below are in these units. */
static double energy_total(const double *s, long K) {
  double total = 0;
  if (K > 0 && s[0] > 0 && isfinite(s[0]))
    for (long i = 0; i < K; i++) total += (s[i] / s[0]) * (s[i] / s[0]);
  return total;
}

/* The truncation rule (train.h) every route to a member's basis takes:
 * the SVD and the Gram route below, the method of snapshots (snapshots.c),
 * out of core (ooc.c). It was written three times with three floors: the
 * SVD stopped at PCA_RANK_TOL, the method of snapshots there or where the
 * energy left is the Gram matrix's rounding, the Gram routes here and out
 * of core at PCA_GRAM_TOL. Now the floor is what the values resolve:
 * PCA_RANK_TOL for all, and for eigenvalues of a Gram matrix (`gram`) the
 * rounding of its trace, K ε of the total — an eigenvalue is exact only to
 * about ε of the largest, so at energy 1 the count would otherwise run
 * on through eigen-noise to the cap. One rounding floor for both cannot
 * be had: at K ε the SVD would stop at σ 5.6e-8 of the largest on
 * test_reduce's pca_gram_matches_svd (k 29, which asks 30..40); at ε the
 * Gram routes keep noise (out of core at energy 1: 12 vectors where the
 * SVD finds 2).
 *
 * Below energy 1 − 1e-12 K (every default, every test) the change
 * decides nothing, the energy is reached first: every model the tests and
 * demos write is bit for bit as before. At energy 1 out of core now stops
 * as the method of snapshots does, measured on formfactors.npg (96 faces,
 * 30 samples, cap 20): c, d, p 6 -> 7 vectors (as in memory), s 2 -> 6 and
 * r 3 -> 5 (in memory 2 and 3: values below PCA_GRAM_TOL, fewer digits),
 * the energy lost from 1.0e-14..3.5e-14 to 2.3e-15..6.3e-15. */
long pca_choose(const double *s, long K, int cap, double energy, bool gram, bool *unresolved) {
  double total = energy_total(s, K), run = 0;
  long kept = 0;
  if (!(total > 0)) return 0;
  for (;;) {
    if (kept == K || kept == cap) break;
    /* what is left is the Gram matrix's rounding (of the trace, of the
     * snapshots): no direction below carries energy it resolves */
    if (gram && kept > 0 && total - run <= (double)K * DBL_EPSILON * total) break;
    /* kept or dropped, a direction this small only the SVD can tell */
    if (!(s[kept] > PCA_GRAM_TOL * s[0]) && unresolved) *unresolved = true;
    if (!(s[kept] > PCA_RANK_TOL * s[0])) break; /* a dependent direction */
    run += (s[kept] / s[0]) * (s[kept] / s[0]);
    kept++;
    if (run >= energy * total) break;
  }
  return kept;
}

typedef struct MemberChoice {
  int cap;
  double energy;
} MemberChoice;

/* pca_choose as the Gram route's ChooseFn. */
static long choose_member(const double *s, long K, const void *arg, bool *unresolved) {
  const MemberChoice *mc = arg;
  return pca_choose(s, K, mc->cap, mc->energy, true, unresolved);
}

/* Keep every direction above the rank tolerance: the small ones cannot be
 * told from dependent ones through the Gram matrix. */
static long choose_independent(const double *s, long K, const void *arg, bool *unresolved) {
  (void)arg;
  for (long i = 0; i < K; i++)
    if (!(s[i] > PCA_GRAM_TOL * s[0])) *unresolved = true;
  return *unresolved ? 0 : K;
}

/* pca_member, also handing back the singular values (descending, *nsv of
 * them, malloc'd) when `sv` is not NULL. */
static int pca_core(long n, long S, const double *X, int cap, double energy, double **U, int *k, double *captured,
                    double **sv, long *nsv, char *err, size_t errlen) {
  *U = NULL;
  *k = 0;
  *captured = 1;
  if (sv) *sv = NULL, *nsv = 0;
  /* Snapshots far from 1 (issue 24: 1e-200 or 1e200 times O(1) data): the
   * Gram matrix's products underflow to 0 or overflow to inf, so they are
   * scaled by a power of two (exact) into [1, 2) first; the basis does not
   * change with the scale, and the singular values are scaled back. */
  double big = 0;
  for (size_t i = 0; i < (size_t)n * (size_t)S; i++) big = fmax(big, fabs(X[i]));
  if (big > 0 && isfinite(big) && (big < PCA_SCALE_MIN || big > 1 / PCA_SCALE_MIN)) {
    int e = ilogb(big);
    double *Xs = malloc(sizeof(double) * ((size_t)n * (size_t)S + 1));
    if (!Xs) {
      snprintf(err, errlen, "out of memory for a PCA of %ld x %ld snapshots", n, S);
      return -1;
    }
    for (size_t i = 0; i < (size_t)n * (size_t)S; i++) Xs[i] = ldexp(X[i], -e);
    int rc = pca_core(n, S, Xs, cap, energy, U, k, captured, sv, nsv, err, errlen);
    free(Xs);
    if (rc == 0 && sv && *sv)
      for (long i = 0; i < *nsv; i++) (*sv)[i] = ldexp((*sv)[i], e);
    return rc;
  }
  long r = n < S ? n : S;
  if (n >= 4 * S && S > 0) {
    double *sg = mem_malloc(sizeof(double) * (size_t)S), *Ug = NULL;
    long kept = 0;
    MemberChoice mc = {cap, energy};
    Cols X1 = {X, S, true};
    GramResult g = sg ? gram_basis(n, 1, &X1, choose_member, &mc, cap, sg, &Ug, &kept) : GRAM_FAILED;
    if (g == GRAM_DONE) {
      double total = energy_total(sg, S), run = energy_total(sg, kept);
      *captured = total > 0 ? run / total : 1;
      *U = Ug;
      *k = (int)kept;
      if (sv) *sv = sg, *nsv = S;
      else free(sg);
      return 0;
    }
    free(sg);
    free(Ug);
    /* unresolved or out of memory: the SVD below decides */
  }
  double *A = mem_malloc(sizeof(double) * (size_t)(n * S + 1));
  double *s = mem_malloc(sizeof(double) * (size_t)(r + 1));
  double *u = mem_malloc(sizeof(double) * (size_t)(n * r + 1));
  double *vt = mem_malloc(sizeof(double) * (size_t)(r * S + 1));
  if (!A || !s || !u || !vt) {
    free(A), free(s), free(u), free(vt);
    snprintf(err, errlen, "out of memory for a PCA of %ld x %ld snapshots", n, S);
    return -1;
  }
  memcpy(A, X, sizeof(double) * (size_t)(n * S));
  /* X is n x S column-major: its left singular vectors are the basis */
  lapack_int info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)n, (lapack_int)S, A, (lapack_int)n, s, u,
                                   (lapack_int)n, vt, (lapack_int)(r ? r : 1));
  free(A);
  free(vt);
  if (info != 0) {
    free(s), free(u);
    snprintf(err, errlen, "the SVD of %ld x %ld snapshots did not converge (LAPACK info %d)", n, S, (int)info);
    return -1;
  }
  double total = energy_total(s, r);
  int kept = (int)pca_choose(s, r, cap, energy, false, NULL);
  if (total > 0) *captured = energy_total(s, kept) / total;
  double *out = mem_malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  if (!out) {
    free(s), free(u);
    snprintf(err, errlen, "out of memory for a basis of %ld x %d", n, kept);
    return -1;
  }
  for (long i = 0; i < n; i++)
    for (int j = 0; j < kept; j++) out[i * kept + j] = u[(size_t)j * (size_t)n + (size_t)i];
  if (sv) *sv = s, *nsv = r;
  else free(s);
  free(u);
  *U = out;
  *k = kept;
  return 0;
}

int pca_member(long n, long S, const double *X, int cap, double energy, double **U, int *k, double *captured,
               char *err, size_t errlen) {
  return pca_core(n, S, X, cap, energy, U, k, captured, NULL, NULL, err, errlen);
}

int pca_in_order(long n, int r, double *const *A, const int *k, double **Q, int *m, char *err, size_t errlen) {
  long K = 0;
  for (int i = 0; i < r; i++) K += k[i];
  double *q = mem_malloc(sizeof(double) * (size_t)(n * (K ? K : 1))), *v = mem_malloc(sizeof(double) * (size_t)(n + 1));
  double *c = mem_malloc(sizeof(double) * (size_t)(K + 1));
  *Q = NULL;
  *m = 0;
  if (!q || !v || !c) {
    free(q), free(v), free(c);
    snprintf(err, errlen, "out of memory orthonormalizing a basis of %ld entries", n);
    return -1;
  }
  /* q is n x K row-major with leading dimension K; its first `kept` columns are the basis so far */
  int kept = 0;
  for (int i = 0; i < r; i++)
    for (int j = 0; j < k[i]; j++) {
      for (long e = 0; e < n; e++) v[e] = A[i][e * k[i] + j];
      double norm0 = cblas_dnrm2((int)n, v, 1);
      if (!(norm0 > 0)) continue;
      for (int pass = 0; pass < 2 && kept > 0; pass++) { /* twice is enough (Kahan–Parlett) */
        cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, kept, 1.0, q, (int)K, v, 1, 0.0, c, 1);
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, kept, -1.0, q, (int)K, c, 1, 1.0, v, 1);
      }
      double norm = cblas_dnrm2((int)n, v, 1);
      if (!(norm > PCA_DEPENDENT_TOL * norm0)) continue; /* numerically in the span of the previous ones */
      for (long e = 0; e < n; e++) q[e * K + kept] = v[e] / norm;
      kept++;
    }
  free(v), free(c);
  double *out = mem_malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  if (!out) {
    free(q);
    snprintf(err, errlen, "out of memory orthonormalizing a basis of %ld entries", n);
    return -1;
  }
  for (long e = 0; e < n; e++) memcpy(out + e * kept, q + e * K, sizeof(double) * (size_t)kept);
  free(q);
  *Q = out;
  *m = kept;
  return 0;
}

/* A plain loop, not daxpy: every entry's arithmetic is then the same
 * whatever n is, so the mean of a block of rows (out-of-core training) is
 * bit for bit the mean of those rows of the whole. */
void pca_mean(long n, long S, const double *X, double *mu) {
  double w = 1.0 / (double)S;
  memset(mu, 0, sizeof(double) * (size_t)n);
  for (long s = 0; s < S; s++)
    for (long e = 0; e < n; e++) mu[e] += w * X[s * n + e];
}

void pca_weigh(long n, long S, double *X, const double *w, double *mu) {
  if (mu && !w) pca_mean(n, S, X, mu);
  if (mu && w) { /* pca_mean's loop, weighted */
    double W = 0;
    for (long s = 0; s < S; s++) W += w[s];
    memset(mu, 0, sizeof(double) * (size_t)n);
    for (long s = 0; s < S; s++)
      for (long e = 0; e < n; e++) mu[e] += w[s] / W * X[s * n + e];
  }
  for (long s = 0; s < S; s++) {
    double r = w ? sqrt(w[s]) : 1;
    for (long e = 0; mu && e < n; e++) X[s * n + e] -= mu[e];
    for (long e = 0; w && e < n; e++) X[s * n + e] *= r;
  }
}

int pca_basis(long n, long S, const double *X, int cap, double energy, bool center, const double *w, PcaMember *out,
              char *err, size_t errlen) {
  memset(out, 0, sizeof *out);
  double captured = 1;
  if (!center) {
    double *Xw = w ? mem_malloc(sizeof(double) * (size_t)(n * S + 1)) : NULL;
    if (w && !Xw) {
      snprintf(err, errlen, "out of memory for a PCA of %ld x %ld snapshots", n, S);
      return -1;
    }
    if (Xw) memcpy(Xw, X, sizeof(double) * (size_t)(n * S)), pca_weigh(n, S, Xw, w, NULL);
    int rc = pca_core(n, S, Xw ? Xw : X, cap, energy, &out->U, &out->k, &captured, &out->sv, &out->nsv, err, errlen);
    out->lost = fmax(0, 1 - captured);
    free(Xw);
    return rc;
  }
  /* centered: [μ, U_c] with U_c the leading directions of X − μ1ᵀ, at most cap − 1 (weighted: of
   * (X − μ1ᵀ) diag(√w), μ the weighted mean) */
  double *mu = mem_malloc(sizeof(double) * (size_t)(n + 1)), *Xc = mem_malloc(sizeof(double) * (size_t)(n * S + 1));
  double *Uc = NULL;
  int kc = 0, rc = -1;
  if (!mu || !Xc) {
    snprintf(err, errlen, "out of memory for a PCA of %ld x %ld snapshots", n, S);
    goto done;
  }
  memcpy(Xc, X, sizeof(double) * (size_t)(n * S));
  pca_weigh(n, S, Xc, w, mu);
  if (pca_core(n, S, Xc, cap > 1 ? cap - 1 : 0, energy, &Uc, &kc, &captured, &out->sv, &out->nsv, err, errlen))
    goto done;
  double *parts[2] = {mu, Uc};
  int ks[2] = {1, kc};
  rc = pca_in_order(n, 2, parts, ks, &out->U, &out->k, err, errlen);
  out->lost = fmax(0, 1 - captured);
done:
  free(mu);
  free(Xc);
  free(Uc);
  if (rc) {
    free(out->sv);
    out->sv = NULL;
  }
  return rc;
}

int pca_merge(long n, int r, double *const *U, const int *k, double **B, long *m, char *err, size_t errlen) {
  *B = NULL;
  *m = 0;
  long K = 0;
  for (int i = 0; i < r; i++) K += k[i];
  if (K == 0) {
    *B = mem_malloc(sizeof(double));
    return *B ? 0 : -1;
  }
  if (r == 1) { /* already orthonormal */
    *B = mem_malloc(sizeof(double) * (size_t)(n * K));
    if (!*B) goto oom;
    memcpy(*B, U[0], sizeof(double) * (size_t)(n * K));
    *m = K;
    return 0;
  }
  if (n >= 4 * K) {
    Cols X[64];
    double *sg = mem_malloc(sizeof(double) * (size_t)K), *Ug = NULL;
    long kept = 0;
    GramResult g = GRAM_FAILED;
    if (r <= (int)(sizeof X / sizeof *X) && sg) {
      for (int i = 0; i < r; i++) X[i] = (Cols){U[i], k[i], false};
      g = gram_basis(n, r, X, choose_independent, NULL, K, sg, &Ug, &kept);
    }
    free(sg);
    if (g == GRAM_DONE) {
      *B = Ug;
      *m = kept;
      return 0;
    }
    free(Ug);
  }
  long rk = n < K ? n : K;
  double *A = mem_malloc(sizeof(double) * (size_t)(n * K)), *s = mem_malloc(sizeof(double) * (size_t)rk);
  double *u = mem_malloc(sizeof(double) * (size_t)(n * rk)), *vt = mem_malloc(sizeof(double) * (size_t)(rk * K));
  if (!A || !s || !u || !vt) {
    free(A), free(s), free(u), free(vt);
    goto oom;
  }
  long col = 0;
  for (int i = 0; i < r; i++) {
    for (long row = 0; row < n; row++)
      for (int j = 0; j < k[i]; j++) A[row * K + col + j] = U[i][row * k[i] + j];
    col += k[i];
  }
  lapack_int info = LAPACKE_dgesdd(LAPACK_ROW_MAJOR, 'S', (lapack_int)n, (lapack_int)K, A, (lapack_int)K, s, u,
                                   (lapack_int)rk, vt, (lapack_int)K);
  free(A);
  free(vt);
  if (info != 0) {
    free(s), free(u);
    snprintf(err, errlen, "re-orthonormalizing a merged basis: SVD did not converge (LAPACK info %d)", (int)info);
    return -1;
  }
  long kept = 0;
  while (kept < rk && s[kept] > PCA_RANK_TOL * s[0]) kept++;
  double *out = mem_malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  if (!out) {
    free(s), free(u);
    goto oom;
  }
  for (long row = 0; row < n; row++)
    for (long j = 0; j < kept; j++) out[row * kept + j] = u[row * rk + j];
  free(s);
  free(u);
  *B = out;
  *m = kept;
  return 0;
oom:
  snprintf(err, errlen, "out of memory merging bases of %ld entries", n);
  return -1;
}

/* The first entry (in row order) whose magnitude is at least half of the
 * column's largest: its sign decides the column's. Unlike the sign of the
 * largest entry it is not a tie between mirror-image entries of a
 * symmetric mode, so two routes to one basis agreeing to rounding agree on
 * it. */
void pca_sign_scan(long n, long m, const double *B, double *big, int *sign, bool decide) {
  for (long e = 0; e < n; e++)
    for (long j = 0; j < m; j++) {
      double v = B[e * m + j];
      if (!decide) big[j] = fmax(big[j], fabs(v));
      else if (!sign[j] && big[j] > 0 && fabs(v) >= 0.5 * big[j]) sign[j] = v > 0 ? 1 : -1;
    }
}

int pca_fix_signs(long n, long m, double *B) {
  double *big = mem_calloc((size_t)m + 1, sizeof(double));
  int *sign = mem_calloc((size_t)m + 1, sizeof(int));
  if (!big || !sign) return free(big), free(sign), -1;
  pca_sign_scan(n, m, B, big, sign, false);
  pca_sign_scan(n, m, B, big, sign, true);
  for (long j = 0; j < m; j++)
    if (sign[j] < 0)
      for (long e = 0; e < n; e++) B[e * m + j] = -B[e * m + j];
  free(big), free(sign);
  return 0;
}

const char *pca_gram_out_of_range(long S, const double *G, double big) {
  double diag = 0;
  for (long a = 0; a < S; a++) {
    double g = G[a * S + a];
    if (!isfinite(g)) return "values beyond about 1e154, whose squares overflow the Gram matrix";
    diag = fmax(diag, g);
  }
  if (diag < PCA_GRAM_MIN && (diag > 0 || big > 0))
    return "values below about 1e-145, whose squares underflow in the Gram matrix (the truncation would see no energy)";
  return NULL;
}
