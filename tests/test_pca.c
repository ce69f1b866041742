/* test_pca.c — backends/train/pca.c: the Gram matrix's eigenproblem with
 * few eigenvectors (pca_top_eigen) against LAPACK's divide and conquer
 * (dsyevd, every eigenvector), on random symmetric positive semidefinite
 * Gram matrices G = Q diag(λ) Qᵀ (Q from the QR of a random matrix):
 *
 *   - every eigenvalue equal to dsyevd's to 1e-12 λ_max;
 *   - the kept eigenvectors orthonormal, and spanning what dsyevd's span:
 *     for every group of equal eigenvalues (to 1e-9 relative) wholly among
 *     the kept, the projectors onto the group equal to 1e-10 (a simple
 *     eigenvalue's vector up to its sign, a repeated one's space), where
 *     the group is at least 1e-5 λ_max from every other eigenvalue (an
 *     eigenspace is only determined to about ε λ_max / that gap, by either
 *     route);
 *   - spectra: a Gram matrix's decay (1 to 1e-12), low rank (10 of 160,
 *     the rest a null space of 150), repeated leading eigenvalues;
 *     k from 1 to the whole (the dsyevd branch included), and k = 0;
 *
 * and PCA of tall snapshots (pca_basis, pca_merge: a QR, then an SVD):
 * orthonormal bases of the optimal energy, reproducing the snapshots to
 * the accuracy of LAPACK's SVD of the same matrix down to 1e-12 (issue 41:
 * a Gram matrix stopped near 1e-8); and every allocation of pca_basis,
 * pca_merge and pca_top_eigen failing in turn (issue 39): a clean failure
 * each time, then the same basis. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include <cblas.h>
#include <cmocka.h>
#include <lapacke.h>

#include "randdata.h"
#include "support/failing_alloc.h"
#include "train.h"

typedef enum Spectrum {
  SP_DECAY,    /* 1 down to 1e-12, geometrically */
  SP_LOW_RANK, /* 10 eigenvalues 1 … 10, the rest 0 */
  SP_REPEATED, /* 5, 5, 5, 3, 3, then decaying from 1 */
} Spectrum;

static double eigenvalue(Spectrum sp, long i, long S) {
  switch (sp) {
  case SP_DECAY: return pow(1e-12, (double)i / (double)(S - 1));
  case SP_LOW_RANK: return i < 10 ? 10.0 - (double)i : 0;
  case SP_REPEATED: return i < 3 ? 5 : i < 5 ? 3 : pow(0.8, (double)(i - 5));
  }
  return 0;
}

/* Column-major S x S G = Q diag(λ) Qᵀ, λ of `sp` (λ_i at a random place). */
static double *gram_matrix(Spectrum sp, long S, unsigned seed) {
  double *Q = malloc(sizeof(double) * (size_t)(S * S)), *G = calloc((size_t)(S * S), sizeof(double));
  double *tau = malloc(sizeof(double) * (size_t)S);
  for (long i = 0; i < S * S; i++) Q[i] = randdata_uniform(&seed, -1, 1);
  assert_int_equal(LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (int)S, (int)S, Q, (int)S, tau), 0);
  assert_int_equal(LAPACKE_dorgqr(LAPACK_COL_MAJOR, (int)S, (int)S, (int)S, Q, (int)S, tau), 0);
  for (long i = 0; i < S; i++) {
    double l = eigenvalue(sp, i, S);
    for (long b = 0; b < S; b++)
      for (long a = 0; a < S; a++) G[b * S + a] += l * Q[i * S + a] * Q[i * S + b];
  }
  free(Q), free(tau);
  return G;
}

/* The largest difference of the projectors onto columns [j0, j1) of the
 * S x k column-major A and B. */
static double projector_distance(long S, const double *A, const double *B, long j0, long j1) {
  double worst = 0;
  for (long a = 0; a < S; a++)
    for (long b = 0; b < S; b++) {
      double pa = 0, pb = 0;
      for (long j = j0; j < j1; j++) pa += A[j * S + a] * A[j * S + b], pb += B[j * S + a] * B[j * S + b];
      worst = fmax(worst, fabs(pa - pb));
    }
  return worst;
}

/* pca_top_eigen(k) on G against dsyevd: the worst eigenvalue difference
 * (relative to λ_max), orthonormality and projector difference. */
static void check_one(Spectrum sp, long S, long k, double *dlam, double *dorth, double *dproj) {
  double *G = gram_matrix(sp, S, 17u + (unsigned)sp), *G2 = malloc(sizeof(double) * (size_t)(S * S));
  double *lam = malloc(sizeof(double) * (size_t)S), *ref = malloc(sizeof(double) * (size_t)S);
  double *V = malloc(sizeof(double) * (size_t)(S * (k ? k : 1))), *R = malloc(sizeof(double) * (size_t)(S * S));
  memcpy(G2, G, sizeof(double) * (size_t)(S * S));
  assert_int_equal(LAPACKE_dsyevd(LAPACK_COL_MAJOR, 'V', 'U', (int)S, G2, (int)S, ref), 0);
  for (long j = 0; j < S; j++) memcpy(R + j * S, G2 + (S - 1 - j) * S, sizeof(double) * (size_t)S); /* descending */
  for (long e = 0; e < S * S; e++) G2[e] = NAN;
  for (long b = 0; b < S; b++) memcpy(G2 + b * S, G + b * S, sizeof(double) * (size_t)(b + 1)); /* the upper triangle only */
  assert_int_equal(pca_top_eigen(S, G2, k, lam, V), 0);
  double big = ref[S - 1];
  *dlam = *dorth = *dproj = 0;
  for (long i = 0; i < S; i++) *dlam = fmax(*dlam, fabs(lam[i] - ref[i]) / big);
  for (long a = 0; a < k; a++)
    for (long b = 0; b < k; b++) {
      double d = 0;
      for (long e = 0; e < S; e++) d += V[a * S + e] * V[b * S + e];
      *dorth = fmax(*dorth, fabs(d - (a == b)));
    }
  /* groups of equal eigenvalues (descending), those wholly kept and apart from the rest */
  for (long j0 = 0, j1; j0 < k; j0 = j1) {
    for (j1 = j0 + 1; j1 < S && fabs(ref[S - 1 - j1] - ref[S - 1 - j0]) <= 1e-9 * big; j1++) {}
    double gap = INFINITY;
    if (j0 > 0) gap = fmin(gap, ref[S - j0] - ref[S - 1 - j0]);
    if (j1 < S) gap = fmin(gap, ref[S - j1] - ref[S - 1 - j1]);
    if (j1 <= k && gap >= 1e-5 * big) *dproj = fmax(*dproj, projector_distance(S, V, R, j0, j1));
  }
  free(G), free(G2), free(lam), free(ref), free(V), free(R);
}

static void top_eigen_matches_dsyevd(void **state) {
  (void)state;
  const long S = 160, ks[] = {0, 1, 3, 5, 10, 12, 40, 100, 160};
  const char *names[] = {"decay 1..1e-12", "rank 10 of 160", "repeated 5,5,5,3,3"};
  for (int sp = SP_DECAY; sp <= SP_REPEATED; sp++) {
    double wl = 0, wo = 0, wp = 0;
    for (size_t i = 0; i < sizeof ks / sizeof *ks; i++) {
      double dl, dor, dp;
      check_one((Spectrum)sp, S, ks[i], &dl, &dor, &dp);
      wl = fmax(wl, dl), wo = fmax(wo, dor), wp = fmax(wp, dp);
    }
    print_message("pca_top_eigen vs dsyevd, S %ld, %s, k 0..160: eigenvalues %.2g, orthonormal %.2g, projectors %.2g\n", S,
                  names[sp], wl, wo, wp);
    assert_true(wl < 1e-12);
    assert_true(wo < 1e-12);
    assert_true(wp < 1e-10);
  }
}

/* ---------------------------------------------------------------- PCA of tall snapshots */

/* X = Q diag(σ) Pᵀ with random orthonormal Q (n x S), P (S x S). */
static double *spectrum_matrix(long n, long S, const double *sigma, unsigned seed) {
  double *Q = malloc(sizeof(double) * (size_t)(n * S)), *P = malloc(sizeof(double) * (size_t)(S * S));
  double *X = calloc((size_t)(n * S), sizeof(double)), *tau = malloc(sizeof(double) * (size_t)S);
  for (long i = 0; i < n * S; i++) Q[i] = rand_r(&seed) / (double)RAND_MAX - 0.5;
  for (long i = 0; i < S * S; i++) P[i] = rand_r(&seed) / (double)RAND_MAX - 0.5;
  LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (int)n, (int)S, Q, (int)n, tau);
  LAPACKE_dorgqr(LAPACK_COL_MAJOR, (int)n, (int)S, (int)S, Q, (int)n, tau);
  LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (int)S, (int)S, P, (int)S, tau);
  LAPACKE_dorgqr(LAPACK_COL_MAJOR, (int)S, (int)S, (int)S, P, (int)S, tau);
  for (long k = 0; k < S; k++) /* X (column-major n x S) = Σ_k σ_k q_k p_kᵀ */
    for (long j = 0; j < S; j++)
      for (long i = 0; i < n; i++) X[j * n + i] += sigma[k] * Q[k * n + i] * P[k * S + j];
  free(Q), free(P), free(tau);
  return X;
}

/* ‖X − U UᵀX‖_F² / ‖X‖_F² for U n x k row-major, X column-major n x S. */
static double residual_energy(long n, long S, const double *X, const double *U, int k) {
  double *C = malloc(sizeof(double) * (size_t)(k * S + 1)), res = 0, tot = 0;
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, k, (int)S, (int)n, 1.0, U, k, X, (int)n, 0.0, C, k);
  for (long j = 0; j < S; j++)
    for (long i = 0; i < n; i++) {
      double v = X[j * n + i];
      for (int a = 0; a < k; a++) v -= U[i * k + a] * C[j * k + a];
      res += v * v;
      tot += X[j * n + i] * X[j * n + i];
    }
  free(C);
  return res / tot;
}

/* Tall snapshots: the bases are orthonormal and capture the optimal energy
 * (that of the leading singular vectors), every direction above the
 * rounding floor kept at energy 1. Merging overlapping member bases drops
 * the dependent directions. */
static void pca_gram_matches_svd(void **state) {
  (void)state;
  long n = 600, S = 40;
  double sigma[40];
  for (int i = 0; i < S; i++) sigma[i] = pow(10.0, -i / 4.0); /* 1 … 1e-9.75 */
  double *X = spectrum_matrix(n, S, sigma, 7u);
  int caps[] = {5, 20, 40};
  double worst_orth = 0, worst_energy = 0;
  for (int c = 0; c < 3; c++) {
    PcaMember p;
    char err[256];
    if (pca_basis(n, S, X, &(PcaRule){.cap = caps[c], .energy = 1.0}, &p, ERR_OF(err, sizeof err))) fail_msg("%s", err);
    double *U = p.U;
    int k = p.k;
    /* every σ here is above the rounding floor: energy 1 keeps them all */
    assert_int_equal(k, caps[c]);
    double opt = 0, tot = 0;
    for (int i = 0; i < S; i++) tot += sigma[i] * sigma[i], opt += i >= k ? sigma[i] * sigma[i] : 0;
    double res = residual_energy(n, S, X, U, k);
    worst_energy = fmax(worst_energy, fabs(res - opt / tot));
    for (int a = 0; a < k; a++)
      for (int b = 0; b < k; b++) {
        double d = 0;
        for (long i = 0; i < n; i++) d += U[i * k + a] * U[i * k + b];
        worst_orth = fmax(worst_orth, fabs(d - (a == b)));
      }
    assert_true(fabs(p.lost - opt / tot) < 1e-12);
    free(U), free(p.sv);
  }
  print_message("PCA of 600 x 40 snapshots, σ from 1 to 1e-9.75, caps 5/20/40: orthonormal to %.2g, residual "
                "energy optimal to %.2g\n", worst_orth, worst_energy);
  assert_true(worst_orth < 1e-12);
  assert_true(worst_energy < 1e-12);
  /* merging two bases that share 5 directions: 35 + 35 − 5 independent */
  PcaMember p1, p2;
  char err[256];
  double flat[40];
  for (int i = 0; i < S; i++) flat[i] = 1;
  free(X);
  X = spectrum_matrix(n, S, flat, 9u);
  double *Y = spectrum_matrix(n, S, flat, 10u);
  for (long j = 0; j < 5; j++) memcpy(Y + j * n, X + j * n, sizeof(double) * (size_t)n);
  if (pca_basis(n, 35, X, &(PcaRule){.cap = 40, .energy = 1.0}, &p1, ERR_OF(err, sizeof err))) fail_msg("%s", err);
  if (pca_basis(n, 35, Y, &(PcaRule){.cap = 40, .energy = 1.0}, &p2, ERR_OF(err, sizeof err))) fail_msg("%s", err);
  double *parts[2] = {p1.U, p2.U}, *B;
  int ks[2] = {p1.k, p2.k};
  long m;
  if (pca_merge(n, (PcaBlocks){2, parts, ks}, &B, &m, ERR_OF(err, sizeof err))) fail_msg("%s", err);
  assert_int_equal(p1.k, 35);
  assert_int_equal(p2.k, 35);
  assert_int_equal(m, 65);
  free(p1.U), free(p1.sv), free(p2.U), free(p2.sv), free(B), free(X), free(Y);
}

/* ‖X − U_j U_jᵀ X‖_F for the first j columns of U (n x k row-major), j = 0..k, into res[j]:
 * the projection of X is done once per j with the leading block of C = UᵀX. */
static void residual_norms(long n, long S, const double *X, const double *U, int k, double *res) {
  double *C = malloc(sizeof(double) * (size_t)(k * S + 1)), *v = malloc(sizeof(double) * (size_t)n);
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, k, (int)S, (int)n, 1.0, U, k, X, (int)n, 0.0, C, k);
  for (int j = 0; j <= k; j++) {
    double r2 = 0;
    for (long c = 0; c < S; c++) {
      memcpy(v, X + c * n, sizeof(double) * (size_t)n);
      cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, j, -1.0, U, k, C + c * k, 1, 1.0, v, 1);
      double nv = cblas_dnrm2((int)n, v, 1);
      r2 += nv * nv;
    }
    res[j] = sqrt(r2);
  }
  free(C), free(v);
}

/* Issue 41, bases to roundoff: snapshots whose singular values span 1 …
 * 1e-14 (geometrically, 29 of them) keep, at energy 1 (a tolerance of
 * 1e-24 of the energy, below ε: the floors decide), every direction of
 * 1e-12 and more, and each leading j of the basis reproduces the snapshots
 * as well as LAPACK's SVD of the same matrix does, to 1e-12 of ‖X‖: at
 * every j, ‖X − U_j U_jᵀ X‖_F equals √(Σ_{i≥j} σ_i²) of dgesdd's σ to
 * 1e-12 ‖X‖_F (centered: at most that, μ kept besides). Through the Gram
 * matrix the error stopped near 1e-8. Tall (QR then SVD) and wide (SVD
 * whole), uncentered and centered. */
static void pca_reaches_svd_accuracy(void **state) {
  (void)state;
  const long shapes[][2] = {{500, 29}, {20, 29}};
  for (int sh = 0; sh < 2; sh++)
    for (int center = 0; center < 2; center++) {
      long n = shapes[sh][0], S = shapes[sh][1], r = n < S ? n : S;
      double sigma[29];
      for (long i = 0; i < S; i++) sigma[i] = pow(10.0, -14.0 * (double)i / (double)(S - 1));
      double *X = spectrum_matrix(n, S, sigma, 11u + (unsigned)sh);
      if (sh == 1) /* wide: 20 rows hold 20 of the directions; scale them to span 1 … 1e-14 as well */
        for (long j = 0; j < S; j++)
          for (long i = 0; i < n; i++) X[j * n + i] *= pow(10.0, -14.0 * (double)i / (double)(n - 1));
      /* the reference: LAPACK's SVD of the same (centered) matrix */
      double *Xr = malloc(sizeof(double) * (size_t)(n * S)), *ref = malloc(sizeof(double) * (size_t)r), *mu = NULL;
      memcpy(Xr, X, sizeof(double) * (size_t)(n * S));
      if (center) mu = malloc(sizeof(double) * (size_t)n), pca_weigh(n, S, Xr, NULL, mu);
      double *Xc = malloc(sizeof(double) * (size_t)(n * S));
      memcpy(Xc, Xr, sizeof(double) * (size_t)(n * S));
      assert_int_equal(LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'N', (int)n, (int)S, Xr, (int)n, ref, NULL, 1, NULL, 1), 0);
      PcaMember p;
      char err[256];
      double energy = 1 - 1e-24; /* == 1 in doubles */
      if (pca_basis(n, S, X, &(PcaRule){.cap = (int)S + 1, .energy = energy, .center = center}, &p, ERR_OF(err, sizeof err))) fail_msg("%s", err);
      /* the kept directions, of the centered snapshots when centered (the basis is [μ, U_c]) */
      int k = p.k - center, need = 0;
      while (need < r && ref[need] >= 1e-12 * ref[0]) need++;
      double norm = 0, *res = malloc(sizeof(double) * (size_t)(p.k + 1)), worst = 0, orth = 0;
      for (long i = 0; i < r; i++) norm += ref[i] * ref[i];
      norm = sqrt(norm);
      /* centered, the basis is [μ, U_c] orthonormalized: its first 1 + j columns hold U_c's
       * first j, so on the centered snapshots they do at least as well as the SVD's first j
       * (μ may add a little); uncentered, exactly as well */
      residual_norms(n, S, Xc, p.U, p.k, res);
      for (int j = 0; j <= k; j++) {
        double opt = 0;
        for (long i = j; i < r; i++) opt += ref[i] * ref[i];
        double d = (res[j + center] - sqrt(opt)) / norm;
        worst = fmax(worst, center ? d : fabs(d));
      }
      for (int a = 0; a < p.k; a++)
        for (int b = 0; b < p.k; b++) {
          double d = cblas_ddot((int)n, p.U + a, p.k, p.U + b, p.k);
          orth = fmax(orth, fabs(d - (a == b)));
        }
      print_message("PCA of %ld x %ld snapshots, σ 1 … 1e-14, %s: %d of %ld directions kept (%d at ≥ 1e-12), "
                    "residual at every size against dgesdd %.2g of ‖X‖, orthonormal to %.2g\n",
                    n, S, center ? "centered" : "uncentered", k, r, need, worst, orth);
      assert_true(k >= need);
      assert_true(worst < 1e-12);
      assert_true(orth < 1e-12);
      free(p.U), free(p.sv), free(res), free(X), free(Xr), free(Xc), free(ref), free(mu);
    }
}

/* A case of pca_fails_cleanly: snapshots n x S, centered or not, weighted or not, their scale. */
typedef struct FailCase {
  long n, S;
  bool center, weighted;
  double scale;
} FailCase;

/* Every allocation of pca_basis failing in turn (support/failing_alloc.h; issue 39: its
 * temporaries from a Scratch, nothing freed by hand on an error path), then of pca_merge and
 * pca_top_eigen: each failure is -1 (with "out of memory" where an error record is given) and
 * leaves nothing behind — the member empty, and under the sanitizer build nothing leaked; once
 * every allocation succeeds the result is the one made without the hook, bit for bit. Tall and
 * wide snapshots, centered and weighted, and at 1e200 (scaled first). */
static void pca_fails_cleanly(void **state) {
  (void)state;
  const FailCase cases[] = {{60, 10, true, true, 1}, {60, 10, false, false, 1}, {8, 20, true, false, 1},
                            {60, 10, false, true, 1e200}};
  double w[20];
  for (int s = 0; s < 20; s++) w[s] = 1 + s % 3;
  for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
    const FailCase *fc = &cases[c];
    double *X = malloc(sizeof(double) * (size_t)(fc->n * fc->S));
    unsigned seed = 5u + (unsigned)c;
    for (long i = 0; i < fc->n * fc->S; i++) X[i] = fc->scale * randdata_uniform(&seed, -1, 1);
    PcaRule rule = {.cap = 6, .energy = 0.9999, .center = fc->center, .w = fc->weighted ? w : NULL};
    PcaMember ref, p;
    char err[256];
    if (pca_basis(fc->n, fc->S, X, &rule, &ref, ERR_OF(err, sizeof err))) fail_msg("%s", err);
    long k = 0;
    for (int rc = -1; rc != 0; k++) {
      failing_alloc_after(k);
      rc = pca_basis(fc->n, fc->S, X, &rule, &p, ERR_OF(err, sizeof err));
      failing_alloc_off();
      if (rc != 0 && !strstr(err, "out of memory")) fail_msg("case %zu, allocation %ld failing: \"%s\"", c, k, err);
      if (rc != 0 && (p.U || p.sv)) fail_msg("case %zu, allocation %ld failing: the member is not empty", c, k);
      if (k > 1000) fail_msg("case %zu: still failing after 1000 allocations", c);
    }
    assert_int_equal(p.k, ref.k);
    assert_int_equal(p.nsv, ref.nsv);
    assert_memory_equal(p.U, ref.U, sizeof(double) * (size_t)(fc->n * ref.k));
    assert_memory_equal(p.sv, ref.sv, sizeof(double) * (size_t)ref.nsv);
    print_message("pca_basis %ld x %ld%s%s: %ld allocations, each failing in turn\n", fc->n, fc->S,
                  fc->center ? " centered" : "", fc->weighted ? " weighted" : "", k - 1);
    /* two members merged: the second basis is the first's directions again, in reverse */
    double *U2 = malloc(sizeof(double) * (size_t)(fc->n * ref.k)), *parts[2] = {ref.U, U2}, *B = NULL, *B0;
    for (long e = 0; e < fc->n; e++)
      for (int j = 0; j < ref.k; j++) U2[e * ref.k + j] = ref.U[e * ref.k + ref.k - 1 - j];
    int ks[2] = {ref.k, ref.k};
    long m0, m = 0;
    if (pca_merge(fc->n, (PcaBlocks){2, parts, ks}, &B0, &m0, ERR_OF(err, sizeof err))) fail_msg("%s", err);
    for (int rc = -1; rc != 0; k++) {
      failing_alloc_after(k);
      rc = pca_merge(fc->n, (PcaBlocks){2, parts, ks}, &B, &m, ERR_OF(err, sizeof err));
      failing_alloc_off();
      if (rc != 0 && (!strstr(err, "out of memory") || B)) fail_msg("pca_merge, allocation %ld failing: \"%s\"", k, err);
    }
    assert_int_equal(m, m0);
    assert_memory_equal(B, B0, sizeof(double) * (size_t)(fc->n * m));
    pca_member_free(&p), pca_member_free(&ref);
    free(X), free(U2), free(B), free(B0);
  }
  /* the partial eigenproblem (5 of 40 eigenvectors: dsytrd, dstemr, dormtr) */
  long S = 40, kk = 5;
  double *G0 = gram_matrix(SP_DECAY, S, 3u), *G = malloc(sizeof(double) * (size_t)(S * S));
  double *lam0 = malloc(sizeof(double) * (size_t)S), *V0 = malloc(sizeof(double) * (size_t)(S * kk));
  double *lam = malloc(sizeof(double) * (size_t)S), *V = malloc(sizeof(double) * (size_t)(S * kk));
  memcpy(G, G0, sizeof(double) * (size_t)(S * S));
  assert_int_equal(pca_top_eigen(S, G, kk, lam0, V0), 0);
  for (int rc = -1, k = 0; rc != 0; k++) {
    memcpy(G, G0, sizeof(double) * (size_t)(S * S));
    failing_alloc_after(k);
    rc = pca_top_eigen(S, G, kk, lam, V);
    failing_alloc_off();
    if (rc != 0 && rc != -1) fail_msg("pca_top_eigen, allocation %d failing: info %d, not -1", k, rc);
  }
  assert_memory_equal(lam, lam0, sizeof(double) * (size_t)S);
  assert_memory_equal(V, V0, sizeof(double) * (size_t)(S * kk));
  free(G0), free(G), free(lam0), free(V0), free(lam), free(V);
}

/* A failed assertion must not leave the hook failing for the next test. */
static int hook_off(void **state) {
  (void)state;
  failing_alloc_off();
  return 0;
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(top_eigen_matches_dsyevd),
      cmocka_unit_test(pca_gram_matches_svd),
      cmocka_unit_test(pca_reaches_svd_accuracy),
      cmocka_unit_test_teardown(pca_fails_cleanly, hook_off),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
