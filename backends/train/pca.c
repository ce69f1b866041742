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

#include "scratch.h"
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
  Scratch sc = SCRATCH_OF(NULL);
  double *d2 = scratch_array(&sc, (size_t)S, sizeof(double)), *e2 = scratch_array(&sc, (size_t)S, sizeof(double));
  double *w = scratch_array(&sc, (size_t)S, sizeof(double));
  lapack_int *iw = scratch_array(&sc, (size_t)(2 * S + 2), sizeof(lapack_int)), m = 0, nsplit = 0, info = -1;
  bool room = d2 && e2 && w && iw;
  if (room) {
    memcpy(d2, d, sizeof(double) * (size_t)S);
    memcpy(e2, e, sizeof(double) * (size_t)S);
    lapack_logical tryrac = 1;
    info = LAPACKE_dstemr(LAPACK_COL_MAJOR, 'V', 'I', (lapack_int)S, d2, e2, 0, 0, (lapack_int)(S - k + 1),
                          (lapack_int)S, &m, w, V, (lapack_int)S, (lapack_int)k, iw, &tryrac);
  }
  if (room && (info != 0 || m != k)) { /* iw: the blocks of the eigenvalues, then where T splits */
    info = LAPACKE_dstebz('I', 'B', (lapack_int)S, 0, 0, (lapack_int)(S - k + 1), (lapack_int)S, 0, d, e, &m, &nsplit,
                          w, iw, iw + S);
    if (info == 0 && m != k) info = -1;
    lapack_int *ifail = info == 0 ? scratch_array(&sc, (size_t)k, sizeof(lapack_int)) : NULL;
    if (info == 0)
      info = ifail ? LAPACKE_dstein(LAPACK_COL_MAJOR, (lapack_int)S, d, e, m, w, iw, iw + S, V, (lapack_int)S, ifail)
                   : -1;
    for (long j = 0; info == 0 && j < k; j++) { /* by block to ascending */
      long lo = j;
      for (long i = j + 1; i < k; i++) lo = w[i] < w[lo] ? i : lo;
      if (lo == j) continue;
      double t = w[j];
      w[j] = w[lo], w[lo] = t;
      cblas_dswap((int)S, V + j * S, 1, V + lo * S, 1);
    }
  }
  scratch_release(&sc);
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
  Scratch sc = SCRATCH_OF(NULL);
  double *d = scratch_array(&sc, (size_t)S, sizeof(double)), *e = scratch_array(&sc, (size_t)S, sizeof(double));
  double *tau = scratch_array(&sc, (size_t)S, sizeof(double)), *w = scratch_array(&sc, (size_t)S, sizeof(double));
  lapack_int info = d && e && tau && w ? LAPACKE_dsytrd(LAPACK_COL_MAJOR, 'U', (lapack_int)S, G, (lapack_int)S, d, e, tau)
                                       : -1;
  if (info == 0) {
    memcpy(lam, d, sizeof(double) * (size_t)S);
    memcpy(w, e, sizeof(double) * (size_t)S);
    info = LAPACKE_dsterf((lapack_int)S, lam, w);
  }
  if (info == 0 && k > 0) info = tridiagonal_top_vectors(S, d, e, k, V);
  if (info == 0 && k > 0)
    info = LAPACKE_dormtr(LAPACK_COL_MAJOR, 'L', 'U', 'N', (lapack_int)S, (lapack_int)k, G, (lapack_int)S, tau, V,
                          (lapack_int)S);
  for (long j = 0; info == 0 && j < k / 2; j++) /* ascending to descending */
    cblas_dswap((int)S, V + j * S, 1, V + (k - 1 - j) * S, 1);
  scratch_release(&sc);
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

/* s[0..r) descending; t's arrays from `keep` (the caller's scratch: they
 * live on for tall_svd_vectors), what only the SVD needs from its own.
 * 0, or -1 with keep's error record. */
static int tall_svd(TallSvd *t, long n, long S, const double *X, double *s, Scratch *keep) {
  Err *err = keep->err;
  Scratch sc = SCRATCH_OF(err);
  *t = (TallSvd){.n = n, .S = S, .r = n < S ? n : S};
  long r = t->r;
  bool wide = n < S; /* wide: the SVD whole, U beside the copy, which it overwrites */
  double *vt = scratch_array(&sc, (size_t)(r * S + 1), sizeof(double));
  double *A = scratch_array(wide ? &sc : keep, (size_t)(n * S + 1), sizeof(double)), *R = NULL;
  if (wide) t->A = scratch_array(keep, (size_t)(n * r + 1), sizeof(double));
  else {
    t->A = A;
    t->tau = scratch_array(keep, (size_t)(S + 1), sizeof(double));
    R = scratch_array(&sc, (size_t)(S * S + 1), sizeof(double));
    t->ur = scratch_array(keep, (size_t)(S * S + 1), sizeof(double));
  }
  lapack_int info = 0;
  const char *what = wide ? "SVD" : "QR";
  int rc = 0;
  if (!vt || !A || !t->A || (!wide && (!t->tau || !R || !t->ur)))
    rc = err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
  else if (wide) {
    memcpy(A, X, sizeof(double) * (size_t)(n * S));
    info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)n, (lapack_int)S, A, (lapack_int)n, s, t->A,
                          (lapack_int)n, vt, (lapack_int)r);
  } else {
    memcpy(A, X, sizeof(double) * (size_t)(n * S));
    info = LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (lapack_int)n, (lapack_int)S, t->A, (lapack_int)n, t->tau);
    for (long j = 0; info == 0 && j < S; j++) memcpy(R + j * S, t->A + j * n, sizeof(double) * (size_t)(j + 1));
    if (info == 0) {
      what = "SVD";
      info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)S, (lapack_int)S, R, (lapack_int)S, s, t->ur,
                            (lapack_int)S, vt, (lapack_int)S);
    }
  }
  if (info != 0)
    rc = err_set(err, "the %s of %ld x %ld snapshots did not converge (LAPACK info %d)", what, n, S, (int)info);
  scratch_release(&sc);
  return rc;
}

/* The first k left singular vectors into *U (n x k row-major, malloc'd).
 * 0, or -1 with `err`. */
static int tall_svd_vectors(const TallSvd *t, long k, double **U, Err *err) {
  long n = t->n, S = t->S;
  Scratch sc = SCRATCH_OF(err);
  double *C = t->ur ? scratch_array(&sc, (size_t)(n * (k ? k : 1)), sizeof(double)) : NULL;
  const double *u = t->A; /* n x k column-major: the vectors */
  lapack_int info = 0;
  int rc = t->ur && !C ? err_set(err, "out of memory for a basis of %ld x %ld", n, k) : 0;
  if (rc == 0 && t->ur && k > 0) { /* C = Q [U_R(:, 0:k); 0] */
    for (long j = 0; j < k; j++) memcpy(C + j * n, t->ur + j * S, sizeof(double) * (size_t)S);
    info = LAPACKE_dormqr(LAPACK_COL_MAJOR, 'L', 'N', (lapack_int)n, (lapack_int)k, (lapack_int)S, t->A, (lapack_int)n,
                          t->tau, C, (lapack_int)n);
    if (info != 0) rc = err_set(err, "applying the QR of %ld x %ld snapshots failed (LAPACK info %d)", n, S, (int)info);
    u = C;
  }
  double *out = rc == 0 ? mem_malloc(sizeof(double) * (size_t)(n * (k ? k : 1))) : NULL;
  if (rc == 0 && !out) rc = err_set(err, "out of memory for a basis of %ld x %ld", n, k);
  for (long i = 0; out && i < n; i++)
    for (long j = 0; j < k; j++) out[i * k + j] = u[(size_t)j * (size_t)n + (size_t)i];
  if (out) *U = out;
  scratch_release(&sc);
  return rc;
}

void pca_member_free(PcaMember *p) {
  free(p->U);
  free(p->sv);
  memset(p, 0, sizeof *p);
}

/* pca_core of snapshots within range: out->U, out->k, out->lost, out->sv
 * (out->nsv), or on failure nothing. */
static int svd_basis(long n, long S, const double *X, const PcaRule *rule, PcaMember *out, Err *err) {
  long r = n < S ? n : S;
  Scratch sc = SCRATCH_OF(err);
  TallSvd t = {0};
  out->sv = mem_malloc(sizeof(double) * (size_t)(r + 1)), out->nsv = r;
  int rc = out->sv ? tall_svd(&t, n, S, X, out->sv, &sc)
                   : err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
  if (rc == 0) {
    double total = energy_total(out->sv, r), captured = 1;
    out->k = (int)pca_choose(out->sv, r, rule->cap, rule->energy, false);
    if (total > 0) captured = energy_total(out->sv, out->k) / total;
    out->lost = fmax(0, 1 - captured);
    rc = tall_svd_vectors(&t, out->k, &out->U, err);
  }
  if (rc) pca_member_free(out); /* the half-made basis */
  scratch_release(&sc);
  return rc;
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
  if (!(big > 0 && isfinite(big) && (big < PCA_SCALE_MIN || big > 1 / PCA_SCALE_MIN)))
    return svd_basis(n, S, X, rule, out, err);
  int e = ilogb(big);
  Scratch sc = SCRATCH_OF(err);
  double *Xs = scratch_array(&sc, (size_t)n * (size_t)S + 1, sizeof(double));
  int rc = Xs ? 0 : err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
  for (size_t i = 0; Xs && i < (size_t)n * (size_t)S; i++) Xs[i] = ldexp(X[i], -e);
  if (rc == 0) rc = svd_basis(n, S, Xs, rule, out, err);
  for (long i = 0; rc == 0 && i < out->nsv; i++) out->sv[i] = ldexp(out->sv[i], e);
  scratch_release(&sc);
  return rc;
}

/* pca_in_order with the dependence tolerance `tol`. */
static int in_order(long n, PcaBlocks a, double tol, double **Q, int *m, Err *err) {
  int r = a.r;
  double *const *A = a.A;
  const int *k = a.k;
  long K = 0;
  for (int i = 0; i < r; i++) K += k[i];
  Scratch sc = SCRATCH_OF(err);
  double *q = scratch_array(&sc, (size_t)(n * (K ? K : 1)), sizeof(double));
  double *v = scratch_array(&sc, (size_t)(n + 1), sizeof(double)), *c = scratch_array(&sc, (size_t)(K + 1), sizeof(double));
  *Q = NULL;
  *m = 0;
  if (!q || !v || !c)
    return scratch_release(&sc), err_set(err, "out of memory orthonormalizing a basis of %ld entries", n);
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
  double *out = mem_malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  for (long e = 0; out && e < n; e++) memcpy(out + e * kept, q + e * K, sizeof(double) * (size_t)kept);
  scratch_release(&sc);
  if (!out) return err_set(err, "out of memory orthonormalizing a basis of %ld entries", n);
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
  Scratch sc = SCRATCH_OF(err);
  int rc = 0;
  if (!rule->center) {
    double *Xw = w ? scratch_array(&sc, (size_t)(n * S + 1), sizeof(double)) : NULL;
    if (w && !Xw) rc = err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
    if (Xw) memcpy(Xw, X, sizeof(double) * (size_t)(n * S)), pca_weigh(n, S, Xw, w, NULL);
    if (rc == 0) rc = pca_core(n, S, Xw ? Xw : X, rule, out, err);
    scratch_release(&sc);
    return rc;
  }
  /* centered: [μ, U_c] with U_c the leading directions of X − μ1ᵀ, at most cap − 1 (weighted: of
   * (X − μ1ᵀ) diag(√w), μ the weighted mean) */
  double *mu = scratch_array(&sc, (size_t)(n + 1), sizeof(double));
  double *Xc = scratch_array(&sc, (size_t)(n * S + 1), sizeof(double));
  PcaMember c = {0}; /* the centered snapshots' */
  if (!mu || !Xc) rc = err_set(err, "out of memory for a PCA of %ld x %ld snapshots", n, S);
  if (rc == 0) {
    memcpy(Xc, X, sizeof(double) * (size_t)(n * S));
    pca_weigh(n, S, Xc, w, mu);
    rc = pca_core(n, S, Xc, &(PcaRule){.cap = rule->cap > 1 ? rule->cap - 1 : 0, .energy = rule->energy}, &c, err);
  }
  if (rc == 0) {
    out->sv = c.sv, out->nsv = c.nsv, c.sv = NULL; /* the spectrum is the centered snapshots' */
    double *parts[2] = {mu, c.U};
    int ks[2] = {1, c.k};
    rc = pca_in_order(n, (PcaBlocks){2, parts, ks}, &out->U, &out->k, err);
    out->lost = c.lost;
  }
  pca_member_free(&c);
  if (rc) pca_member_free(out); /* the half-made basis */
  scratch_release(&sc);
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
  if (K == 0 || r == 1) { /* no vector, or already orthonormal */
    if (!(*B = mem_malloc(sizeof(double) * (size_t)(K ? n * K : 1))))
      return err_set(err, "out of memory merging bases of %ld entries", n);
    if (K) memcpy(*B, U[0], sizeof(double) * (size_t)(n * K));
    *m = K;
    return 0;
  }
  /* the members' vectors interleaved (the first of each, then the second of each, …), then
   * Gram–Schmidt in that order: the first vectors of the result span the members' first ones */
  Scratch sc = SCRATCH_OF(err);
  double *A = scratch_array(&sc, (size_t)(n * K), sizeof(double));
  if (!A) return scratch_release(&sc), err_set(err, "out of memory merging bases of %ld entries", n);
  long col = 0;
  for (int j = 0; j < kmax; j++)
    for (int i = 0; i < r; i++) {
      if (j >= k[i]) continue;
      for (long row = 0; row < n; row++) A[row * K + col] = U[i][row * k[i] + j];
      col++;
    }
  int kk = (int)K, mm = 0;
  int rc = in_order(n, (PcaBlocks){1, &A, &kk}, PCA_MERGE_TOL, B, &mm, err);
  scratch_release(&sc);
  *m = mm;
  return rc;
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
  Scratch sc = SCRATCH_OF(NULL);
  double *big = scratch_array(&sc, (size_t)m + 1, sizeof(double));
  int *sign = scratch_array(&sc, (size_t)m + 1, sizeof(int));
  if (big && sign) {
    pca_sign_scan(n, m, B, big, sign, false);
    pca_sign_scan(n, m, B, big, sign, true);
  }
  for (long j = 0; big && sign && j < m; j++)
    if (sign[j] < 0)
      for (long e = 0; e < n; e++) B[e * m + j] = -B[e * m + j];
  scratch_release(&sc);
  return big && sign ? 0 : -1;
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
  Scratch sc = SCRATCH_OF(NULL);
  double *T = scratch_array(&sc, (size_t)(nb * S), sizeof(double));
  lapack_int info = T ? LAPACKE_dtpqrt(LAPACK_COL_MAJOR, (lapack_int)rows, (lapack_int)S, 0, (lapack_int)nb, R,
                                       (lapack_int)S, B, (lapack_int)ldb, T, (lapack_int)nb)
                      : -1;
  scratch_release(&sc);
  return (int)info;
}

int pca_fold_r(long S, int nr, const double *Rs, double *R) {
  memset(R, 0, sizeof(double) * (size_t)(S * S));
  Scratch sc = SCRATCH_OF(NULL);
  double *B = scratch_array(&sc, (size_t)(S * S + 1), sizeof(double));
  int info = B ? 0 : -1;
  for (int i = 0; info == 0 && i < nr; i++) {
    memcpy(B, Rs + (size_t)i * (size_t)(S * S), sizeof(double) * (size_t)(S * S));
    info = pca_fold_rows(S, R, S, B, S);
  }
  scratch_release(&sc);
  return info;
}

int pca_r_basis(long S, const double *R, const PcaRule *rule, double *s, double *W, long *k) {
  Scratch sc = SCRATCH_OF(NULL);
  double *A = scratch_array(&sc, (size_t)(S * S + 1), sizeof(double));
  double *u = scratch_array(&sc, (size_t)(S * S + 1), sizeof(double));
  double *vt = scratch_array(&sc, (size_t)(S * S + 1), sizeof(double));
  int info = -1;
  for (long j = 0; A && j < S; j++) /* the upper triangle only: below it dtpqrt leaves nothing of use */
    for (long i = 0; i < S; i++) A[j * S + i] = i <= j ? R[j * S + i] : 0;
  if (A && u && vt)
    info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)S, (lapack_int)S, A, (lapack_int)S, s, u, (lapack_int)S,
                          vt, (lapack_int)S);
  if (info == 0) *k = pca_choose(s, S, rule->cap, rule->energy, false);
  for (long j = 0; info == 0 && j < *k; j++) /* W(:, j) = V(:, j) / σ_j, V(e, j) = vt(j, e) */
    for (long e = 0; e < S; e++) W[j * S + e] = vt[e * S + j] / s[j];
  scratch_release(&sc);
  return info;
}
