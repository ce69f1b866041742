/* pca.c — bases from snapshots (DESIGN §5; paper §8.2).
 *
 * One PCA per member, truncated at an energy fraction and a cap. Centered
 * by default (pca_basis): the member's mean μ is always kept and the
 * leading left singular vectors of the snapshots minus μ fill the rest, as
 * many as reach the energy fraction of the *centered* energy — on a
 * deforming mesh the rest shape dominates the uncentered energy, and the
 * paper's uncentered rule (the mean a direction like any other) then drops
 * the deformation modes. The basis stays linear: [μ, U_c] orthonormalized.
 * A class's member bases are merged, dropping dependent directions (paper
 * §6.1: two 60-vector bases gave a 120-vector one): their vectors
 * interleaved (the first of every member, then the second, …) and
 * orthonormalized in that order, so that the first vectors of the class
 * basis are what smaller caps would give — a model evaluated at a smaller
 * size (model_truncate) is the model trained at that cap. All
 * factorizations through LAPACKE.
 *
 * Every basis comes from an SVD of the snapshots themselves, never of
 * their Gram matrix XᵀX: the Gram matrix squares the snapshots' condition
 * number and resolves singular values only down to about √ε σ_max, so a
 * basis built from it stops near 1e-8 (issue 41). Tall snapshots (n ≥ S)
 * take a QR first (dgeqrf), the SVD of the S x S factor R (dgesdd), and
 * the kept vectors Q [U_R; 0] (dormqr): only the kept columns are formed,
 * and what is held beyond the snapshots is n x S for the factored copy
 * and n x k for the basis. Singular values are then exact to about ε σ_max,
 * and the basis reproduces the snapshots to that: the truncation keeps
 * directions down to PCA_ROUNDOFF_TOL σ_max. */
#include <cblas.h>
#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "train.h"

/* Singular values at most this fraction of the largest are rounding, not
 * data: a backward-stable SVD gives every singular value to about ε σ_max
 * times a small factor of the sizes, and a direction below that carries
 * nothing the snapshots resolve. 100 ε (2.2e-14) keeps every direction of
 * test_pca's spectrum 1 … 1e-14 down to 1e-13 and drops the 1e-14 one. */
#define PCA_ROUNDOFF_TOL (100 * DBL_EPSILON)

/* Snapshots whose largest entry lies outside [PCA_SCALE_MIN, 1/PCA_SCALE_MIN]
 * are scaled to O(1) before a PCA: beyond it, sums of squares over up to
 * 1e30 entries would leave the range of doubles (1e-308..1e308). */
#define PCA_SCALE_MIN 1e-100

/* A Gram matrix whose largest diagonal entry (a snapshot's squared norm) is
 * below this lost its small entries to underflow. */
#define PCA_GRAM_MIN 1e-290

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
 * the SVD here, the method of snapshots (snapshots.c), out of core
 * (ooc.c). The energy left out, Σ_{i≥k} (s_i/s_0)², is summed from the
 * smallest value up and compared with (1 − energy) of the total, so that a
 * tolerance far below ε of the total (energy 1 − 1e-24) is not lost to
 * the rounding of total − kept; at energy 1 the floors alone stop the
 * count. The floors are what the values resolve: PCA_ROUNDOFF_TOL σ_max
 * for singular values, and for square roots of a Gram matrix's eigenvalues
 * (`gram`) the rounding of its trace, K ε of the total — an eigenvalue is
 * exact only to about ε of the largest, so at energy 1 the count would
 * otherwise run on through eigen-noise to the cap. */
long pca_choose(const double *s, long K, int cap, double energy, bool gram) {
  double total = energy_total(s, K);
  if (!(total > 0)) return 0;
  long limit = 0; /* the cap, and the first value at the rounding floor */
  while (limit < K && limit < cap && s[limit] > PCA_ROUNDOFF_TOL * s[0]) limit++;
  double tol = (1 - energy) * total, tail = 0;
  if (gram) tol = fmax(tol, (double)K * DBL_EPSILON * total);
  long kept = K; /* the fewest whose tail is within tol: tails grow as k falls */
  for (long i = K - 1; i >= 0; i--) {
    tail += (s[i] / s[0]) * (s[i] / s[0]);
    if (tail > tol) break;
    kept = i;
  }
  if (kept == 0) kept = 1; /* total > tol: energy > 0 keeps the largest */
  return kept < limit ? kept : limit;
}

/* The SVD of tall snapshots X (n x S column-major, n ≥ S) by a QR first:
 * X = Q R (dgeqrf, reflectors kept in A), R = U_R Σ Vᵀ (dgesdd); the left
 * singular vectors are Q [U_R; 0], formed only for the kept columns
 * (tall_svd_vectors). Wide snapshots (n < S) take dgesdd whole. */
typedef struct TallSvd {
  long n, S, r;  /* r = min(n, S) singular values */
  double *A;     /* n x S: the QR's reflectors (tall), or the whole U (wide, n x r) */
  double *tau;   /* the reflectors' scales (tall) */
  double *ur;    /* S x S: R's left singular vectors (tall) */
} TallSvd;

static void tall_svd_free(TallSvd *t) { free(t->A), free(t->tau), free(t->ur); }

/* s[0..r) descending; 0, or -1 with `err`. */
static int tall_svd(TallSvd *t, long n, long S, const double *X, double *s, Err *err) {
  memset(t, 0, sizeof *t);
  t->n = n, t->S = S, t->r = n < S ? n : S;
  long r = t->r;
  double *R = NULL, *vt = mem_malloc(sizeof(double) * (size_t)(r * S + 1));
  t->A = mem_malloc(sizeof(double) * (size_t)(n * S + 1));
  lapack_int info = 0;
  const char *what = "SVD";
  if (!t->A || !vt) goto oom;
  memcpy(t->A, X, sizeof(double) * (size_t)(n * S));
  if (n < S) { /* wide: the SVD whole, U in place of the copy */
    double *A = t->A;
    if (!(t->A = mem_malloc(sizeof(double) * (size_t)(n * r + 1)))) {
      t->A = A;
      goto oom;
    }
    info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)n, (lapack_int)S, A, (lapack_int)n, s, t->A,
                          (lapack_int)n, vt, (lapack_int)r);
    free(A);
    goto done;
  }
  t->tau = mem_malloc(sizeof(double) * (size_t)(S + 1));
  R = mem_calloc((size_t)(S * S + 1), sizeof(double));
  t->ur = mem_malloc(sizeof(double) * (size_t)(S * S + 1));
  if (!t->tau || !R || !t->ur) goto oom;
  what = "QR";
  if ((info = LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (lapack_int)n, (lapack_int)S, t->A, (lapack_int)n, t->tau)) != 0)
    goto done;
  for (long j = 0; j < S; j++) memcpy(R + j * S, t->A + j * n, sizeof(double) * (size_t)(j + 1));
  what = "SVD";
  info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)S, (lapack_int)S, R, (lapack_int)S, s, t->ur,
                        (lapack_int)S, vt, (lapack_int)S);
done:
  free(R), free(vt);
  if (info != 0) {
    tall_svd_free(t);
    err_set(err, "the %s of %ld x %ld snapshots did not converge (LAPACK info %d)", what, n, S, (int)info);
    return -1;
  }
  return 0;
oom:
  free(R), free(vt);
  tall_svd_free(t);
  err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
  return -1;
}

/* The first k left singular vectors into *U (n x k row-major, malloc'd).
 * 0, or -1 with `err`. */
static int tall_svd_vectors(const TallSvd *t, long k, double **U, Err *err) {
  long n = t->n, S = t->S;
  double *out = mem_malloc(sizeof(double) * (size_t)(n * (k ? k : 1)));
  double *C = t->ur ? mem_calloc((size_t)(n * (k ? k : 1)), sizeof(double)) : NULL;
  if (!out || (t->ur && !C)) {
    free(out), free(C);
    err_set(err, "out of memory for a basis of %ld x %ld", n, k);
    return -1;
  }
  const double *u = t->A; /* n x k column-major: the vectors */
  if (t->ur && k > 0) {   /* C = Q [U_R(:, 0:k); 0] */
    for (long j = 0; j < k; j++) memcpy(C + j * n, t->ur + j * S, sizeof(double) * (size_t)S);
    lapack_int info = LAPACKE_dormqr(LAPACK_COL_MAJOR, 'L', 'N', (lapack_int)n, (lapack_int)k, (lapack_int)S, t->A,
                                     (lapack_int)n, t->tau, C, (lapack_int)n);
    if (info != 0) {
      free(out), free(C);
      err_set(err, "applying the QR of %ld x %ld snapshots failed (LAPACK info %d)", n, S, (int)info);
      return -1;
    }
    u = C;
  }
  for (long i = 0; i < n; i++)
    for (long j = 0; j < k; j++) out[i * k + j] = u[(size_t)j * (size_t)n + (size_t)i];
  free(C);
  *U = out;
  return 0;
}

/* The uncentered, unweighted basis of X by rule's cap and energy: out->U
 * (n x k row-major), out->k, out->lost, and the singular values out->sv
 * (descending, out->nsv of them), all malloc'd. */
static int pca_core(long n, long S, const double *X, const PcaRule *rule, PcaMember *out, Err *err) {
  memset(out, 0, sizeof *out);
  /* Snapshots far from 1 (issue 24: 1e-200 or 1e200 times O(1) data): the
   * energies' squares underflow to 0 or overflow to inf, so they are
   * scaled by a power of two (exact) into [1, 2) first; the basis does not
   * change with the scale, and the singular values are scaled back. */
  double big = 0;
  for (size_t i = 0; i < (size_t)n * (size_t)S; i++) big = fmax(big, fabs(X[i]));
  if (big > 0 && isfinite(big) && (big < PCA_SCALE_MIN || big > 1 / PCA_SCALE_MIN)) {
    int e = ilogb(big);
    double *Xs = malloc(sizeof(double) * ((size_t)n * (size_t)S + 1));
    if (!Xs) {
      err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
      return -1;
    }
    for (size_t i = 0; i < (size_t)n * (size_t)S; i++) Xs[i] = ldexp(X[i], -e);
    int rc = pca_core(n, S, Xs, rule, out, err);
    free(Xs);
    if (rc == 0 && out->sv)
      for (long i = 0; i < out->nsv; i++) out->sv[i] = ldexp(out->sv[i], e);
    return rc;
  }
  long r = n < S ? n : S;
  double *s = mem_malloc(sizeof(double) * (size_t)(r + 1));
  TallSvd t;
  if (!s) {
    err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
    return -1;
  }
  if (tall_svd(&t, n, S, X, s, err)) return free(s), -1;
  double total = energy_total(s, r), captured = 1;
  int kept = (int)pca_choose(s, r, rule->cap, rule->energy, false);
  if (total > 0) captured = energy_total(s, kept) / total;
  int rc = tall_svd_vectors(&t, kept, &out->U, err);
  tall_svd_free(&t);
  if (rc) return free(s), -1;
  out->sv = s, out->nsv = r;
  out->k = kept;
  out->lost = fmax(0, 1 - captured);
  return 0;
}

/* pca_in_order with the dependence tolerance `tol`. */
static int in_order(long n, PcaBlocks a, double tol, double **Q, int *m, Err *err) {
  int r = a.r;
  double *const *A = a.A;
  const int *k = a.k;
  long K = 0;
  for (int i = 0; i < r; i++) K += k[i];
  double *q = mem_malloc(sizeof(double) * (size_t)(n * (K ? K : 1))), *v = mem_malloc(sizeof(double) * (size_t)(n + 1));
  double *c = mem_malloc(sizeof(double) * (size_t)(K + 1));
  *Q = NULL;
  *m = 0;
  if (!q || !v || !c) {
    free(q), free(v), free(c);
    err_set(err, "out of memory orthonormalizing a basis of %ld entries", n);
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
      if (!(norm > tol * norm0)) continue; /* numerically in the span of the previous ones */
      for (long e = 0; e < n; e++) q[e * K + kept] = v[e] / norm;
      kept++;
    }
  free(v), free(c);
  double *out = mem_malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  if (!out) {
    free(q);
    err_set(err, "out of memory orthonormalizing a basis of %ld entries", n);
    return -1;
  }
  for (long e = 0; e < n; e++) memcpy(out + e * kept, q + e * K, sizeof(double) * (size_t)kept);
  free(q);
  *Q = out;
  *m = kept;
  return 0;
}

int pca_in_order(long n, PcaBlocks a, double **Q, int *m, Err *err) {
  return in_order(n, a, PCA_DEPENDENT_TOL, Q, m, err);
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

int pca_basis(long n, long S, const double *X, const PcaRule *rule, PcaMember *out, Err *err) {
  memset(out, 0, sizeof *out);
  const double *w = rule->w;
  if (!rule->center) {
    double *Xw = w ? mem_malloc(sizeof(double) * (size_t)(n * S + 1)) : NULL;
    if (w && !Xw) {
      err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
      return -1;
    }
    if (Xw) memcpy(Xw, X, sizeof(double) * (size_t)(n * S)), pca_weigh(n, S, Xw, w, NULL);
    int rc = pca_core(n, S, Xw ? Xw : X, rule, out, err);
    free(Xw);
    return rc;
  }
  /* centered: [μ, U_c] with U_c the leading directions of X − μ1ᵀ, at most cap − 1 (weighted: of
   * (X − μ1ᵀ) diag(√w), μ the weighted mean) */
  double *mu = mem_malloc(sizeof(double) * (size_t)(n + 1)), *Xc = mem_malloc(sizeof(double) * (size_t)(n * S + 1));
  PcaMember c = {0}; /* the centered snapshots' */
  int rc = -1;
  if (!mu || !Xc) {
    err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
    goto done;
  }
  memcpy(Xc, X, sizeof(double) * (size_t)(n * S));
  pca_weigh(n, S, Xc, w, mu);
  if (pca_core(n, S, Xc, &(PcaRule){.cap = rule->cap > 1 ? rule->cap - 1 : 0, .energy = rule->energy}, &c, err)) goto done;
  out->sv = c.sv, out->nsv = c.nsv;
  double *parts[2] = {mu, c.U};
  int ks[2] = {1, c.k};
  rc = pca_in_order(n, (PcaBlocks){2, parts, ks}, &out->U, &out->k, err);
  out->lost = c.lost;
done:
  free(mu);
  free(Xc);
  free(c.U);
  if (rc) {
    free(out->sv);
    out->sv = NULL;
  }
  return rc;
}

int pca_merge(long n, PcaBlocks u, double **B, long *m, Err *err) {
  int r = u.r;
  double *const *U = u.A;
  const int *k = u.k;
  *B = NULL;
  *m = 0;
  long K = 0;
  int kmax = 0;
  for (int i = 0; i < r; i++) K += k[i], kmax = k[i] > kmax ? k[i] : kmax;
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
  /* the members' vectors interleaved (the first of each, then the second of each, …), then
   * Gram–Schmidt in that order: the first vectors of the result span the members' first ones */
  double *A = mem_malloc(sizeof(double) * (size_t)(n * K));
  if (!A) goto oom;
  long col = 0;
  for (int j = 0; j < kmax; j++)
    for (int i = 0; i < r; i++) {
      if (j >= k[i]) continue;
      for (long row = 0; row < n; row++) A[row * K + col] = U[i][row * k[i] + j];
      col++;
    }
  int kk = (int)K, mm = 0;
  int rc = in_order(n, (PcaBlocks){1, &A, &kk}, PCA_MERGE_TOL, B, &mm, err);
  free(A);
  *m = mm;
  return rc;
oom:
  err_set(err, "out of memory merging bases of %ld entries", n);
  return -1;
}

/* The first entry (in row order) whose magnitude is at least
 * PCA_SIGN_FRACTION of the column's largest: its sign decides the column's. Unlike the sign of the
 * largest entry it is not a tie between mirror-image entries of a
 * symmetric mode, so two routes to one basis agreeing to rounding agree on
 * it. */
void pca_sign_scan(long n, long m, const double *B, double *big, int *sign, bool decide) {
  for (long e = 0; e < n; e++)
    for (long j = 0; j < m; j++) {
      double v = B[e * m + j];
      if (!decide) big[j] = fmax(big[j], fabs(v));
      else if (!sign[j] && big[j] > 0 && fabs(v) >= PCA_SIGN_FRACTION * big[j]) sign[j] = v > 0 ? 1 : -1;
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

int pca_fold_rows(long S, double *R, long rows, double *B, long ldb) {
  if (S <= 0 || rows <= 0) return 0;
  long nb = S < 32 ? S : 32;
  double *T = mem_malloc(sizeof(double) * (size_t)(nb * S));
  if (!T) return -1;
  lapack_int info = LAPACKE_dtpqrt(LAPACK_COL_MAJOR, (lapack_int)rows, (lapack_int)S, 0, (lapack_int)nb, R,
                                   (lapack_int)S, B, (lapack_int)ldb, T, (lapack_int)nb);
  free(T);
  return (int)info;
}

int pca_fold_r(long S, int nr, const double *Rs, double *R) {
  memset(R, 0, sizeof(double) * (size_t)(S * S));
  double *B = mem_malloc(sizeof(double) * (size_t)(S * S + 1));
  int info = B ? 0 : -1;
  for (int i = 0; info == 0 && i < nr; i++) {
    memcpy(B, Rs + (size_t)i * (size_t)(S * S), sizeof(double) * (size_t)(S * S));
    info = pca_fold_rows(S, R, S, B, S);
  }
  free(B);
  return info;
}

int pca_r_basis(long S, const double *R, const PcaRule *rule, double *s, double *W, long *k) {
  double *A = mem_malloc(sizeof(double) * (size_t)(S * S + 1)), *u = mem_malloc(sizeof(double) * (size_t)(S * S + 1));
  double *vt = mem_malloc(sizeof(double) * (size_t)(S * S + 1));
  int info = -1;
  if (!A || !u || !vt) goto done;
  for (long j = 0; j < S; j++) /* the upper triangle only: below it dtpqrt leaves nothing of use */
    for (long i = 0; i < S; i++) A[j * S + i] = i <= j ? R[j * S + i] : 0;
  info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)S, (lapack_int)S, A, (lapack_int)S, s, u, (lapack_int)S, vt,
                        (lapack_int)S);
  if (info != 0) goto done;
  *k = pca_choose(s, S, rule->cap, rule->energy, false);
  for (long j = 0; j < *k; j++) /* W(:, j) = V(:, j) / σ_j, V(e, j) = vt(j, e) */
    for (long e = 0; e < S; e++) W[j * S + e] = vt[e * S + j] / s[j];
done:
  free(A), free(u), free(vt);
  return info;
}
