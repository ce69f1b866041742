/* krylov.c — M^(p/q) v by the Lanczos process (krylov.h). */
#include "krylov.h"
#include "alloc.h" /* mem_malloc */

#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

int krylov_init_steps(Krylov *k, long maxn, long maxsteps) {
  memset(k, 0, sizeof *k);
  if (maxsteps > maxn) maxsteps = maxn;
  k->maxn = maxn;
  k->maxsteps = maxsteps;
  size_t n = (size_t)(maxn > 0 ? maxn : 1), s = (size_t)(maxsteps > 0 ? maxsteps : 1);
  k->Q = mem_malloc(sizeof(double) * (s + 1) * n);
  k->alpha = mem_malloc(sizeof(double) * (s + 1));
  k->beta = mem_malloc(sizeof(double) * (s + 1));
  k->d = mem_malloc(sizeof(double) * (s + 1));
  k->e = mem_malloc(sizeof(double) * (s + 1));
  k->S = mem_malloc(sizeof(double) * s * s);
  k->lwork = (long)(1 + 4 * s + s * s);
  k->work = mem_malloc(sizeof(double) * (size_t)k->lwork);
  k->iwork = mem_malloc(sizeof(lapack_int) * (3 + 5 * s));
  _Static_assert(sizeof(lapack_int) == sizeof(int), "dstedc's iwork is held as int");
  k->cprev = mem_malloc(sizeof(double) * (s + 1));
  k->c = mem_malloc(sizeof(double) * (s + 1));
  k->w = mem_malloc(sizeof(double) * s);
  k->cheb = mem_malloc(sizeof(double) * (5 * (KRYLOV_MAX_DEGREE + 1) + 5 * s + 8));
  return k->Q && k->alpha && k->beta && k->d && k->e && k->S && k->work && k->iwork && k->cprev && k->c && k->w &&
                 k->cheb
             ? 0
             : -1;
}

int krylov_init(Krylov *k, long maxn) { return krylov_init_steps(k, maxn, maxn); }

void krylov_free(Krylov *k) {
  free(k->Q), free(k->alpha), free(k->beta), free(k->d), free(k->e), free(k->S), free(k->work), free(k->iwork);
  free(k->cprev);
  free(k->c), free(k->w), free(k->cheb);
  memset(k, 0, sizeof *k);
}

/* c = f(T_K) e₁ by the Chebyshev expansion of f(λ) = λ^r on an interval
 * [a, b] that holds T_K's spectrum, when that is cheaper than T_K's
 * eigendecomposition: a few O(K) passes instead of O(K³). b is Gershgorin's
 * bound; a is T_K's smallest eigenvalue by bisection (dstebz) to 10⁻⁴ of b,
 * less that tolerance. f is analytic but at 0, so the expansion on [a, b]
 * converges like ρ⁻ⁿ, ρ = s + √(s² − 1), s = (b + a)/(b − a): n terms with
 * ρ⁻ⁿ ≤ e⁻³⁸ (10⁻¹⁶·⁵) plus 4 leave it exact to rounding. The coefficients
 * are the discrete cosine sums over n + 1 Chebyshev points (by the
 * three-term recurrence in the degree), and Σ c_j T_j(X) e₁, X = (T_K −
 * mid)/half, by the same recurrence on vectors (T_j(X) e₁ has j + 1
 * nonzeros). 0 done; 1 when the expansion would cost more than the
 * eigendecomposition (n (n + 4K) > 2K³, or n above KRYLOV_MAX_DEGREE) or
 * the interval reaches 0: then the caller decomposes; -1 when LAPACK
 * failed. */
static int chebyshev(Krylov *k, int K, double r) {
  const double *al = k->alpha, *be = k->beta;
  double b = 0;
  for (int i = 0; i < K; i++)
    b = fmax(b, al[i] + (i > 0 ? fabs(be[i - 1]) : 0) + (i + 1 < K ? fabs(be[i]) : 0));
  if (!(b > 0)) return 1;
  double tolb = 1e-4 * b;
  lapack_int m = 0, nsplit = 0, *iw = k->iwork; /* dstebz's W (k->w) and IBLOCK, ISPLIT hold K each */
  if (LAPACKE_dstebz_work('I', 'E', K, 0, 0, 1, 1, tolb, al, be, &m, &nsplit, k->w, iw, iw + K, k->work, iw + 2 * K) !=
          0 ||
      m != 1)
    return -1;
  double a = k->w[0] - tolb;
  if (!(a > 1e-12 * b)) return 1;
  double s = (b + a) / (b - a), rho = s + sqrt(s * s - 1);
  int n = (int)ceil(38.0 / log(rho)) + 4;
  if (n > KRYLOV_MAX_DEGREE || (double)n * (n + 4.0 * K) > 2.0 * K * K * K) return 1;
  int N = n + 1;
  /* k->cheb: the points y, f at them, the coefficients, T_i at the points
   * (two rows); 2X's diagonal and off-diagonal (padded with a 0 at each
   * end); three vectors, each with a 0 before and after it */
  double *y = k->cheb, *fx = y + N, *co = fx + N, *t0 = co + N, *t1 = t0 + N, *dg = t1 + N, *od = dg + K;
  double *v0 = od + K + 2, *v1 = v0 + K + 2, *v2 = v1 + K + 2, *c = k->c;
  double mid = 0.5 * (a + b), half = 0.5 * (b - a);
  for (int j = 0; j < N; j++) {
    y[j] = cos(M_PI * (j + 0.5) / N);
    fx[j] = pow(mid + half * y[j], r);
    t0[j] = 1, t1[j] = y[j];
  }
  /* co_i = (2 − δ_i0)/N Σ_j f(x_j) T_i(y_j), row i of T_i(y_j) from the two before */
  co[0] = cblas_ddot(N, fx, 1, t0, 1) / N;
  co[1] = 2 * cblas_ddot(N, fx, 1, t1, 1) / N;
  for (int i = 2; i < N; i++) {
    for (int j = 0; j < N; j++) t0[j] = 2 * y[j] * t1[j] - t0[j];
    double *t = t0;
    t0 = t1, t1 = t;
    co[i] = 2 * cblas_ddot(N, fx, 1, t1, 1) / N;
  }
  /* c = Σ co_j T_j(X) e₁: T_j(X) e₁ = 2X T_{j−1}(X) e₁ − T_{j−2}(X) e₁ has j + 1 nonzeros */
  double scale = 2 / half;
  for (int i = 0; i < K; i++) dg[i] = (al[i] - mid) * scale;
  od[0] = od[K] = 0;
  for (int i = 1; i < K; i++) od[i] = be[i - 1] * scale;
  memset(v0 - 1, 0, sizeof(double) * 3 * (size_t)(K + 2));
  v0[0] = 1, v1[0] = 0.5 * dg[0];
  if (K > 1) v1[1] = 0.5 * od[1];
  memset(c, 0, sizeof(double) * (size_t)K);
  c[0] = co[0] + co[1] * v1[0];
  if (K > 1) c[1] = co[1] * v1[1];
  for (int j = 2; j < N; j++) {
    int nz = j + 1 < K ? j + 1 : K;
    for (int i = 0; i < nz; i++) {
      v2[i] = dg[i] * v1[i] + od[i] * v1[i - 1] + od[i + 1] * v1[i + 1] - v0[i];
      c[i] += co[j] * v2[i];
    }
    double *t = v0;
    v0 = v1, v1 = v2, v2 = t;
  }
  return 0;
}

/* c = f(T_K) e₁ from the first K steps: by chebyshev() where it is cheaper,
 * else c = S f(Λ) Sᵀ e₁ (T_K = S Λ Sᵀ by divide and conquer, dstedc: at
 * K = 30–40 about half the time of dstev's QR iteration); the approximation
 * is β Q_K c. 1 when T_K looks singular or indefinite, -1 when LAPACK
 * failed. */
static int approximate(Krylov *k, int K, long p, long q) {
  double r = (double)p / (double)q;
  int rc = chebyshev(k, K, r);
  if (rc <= 0) {
    k->expansions += rc == 0;
    return rc;
  }
  k->decompositions++;
  memcpy(k->d, k->alpha, sizeof(double) * (size_t)K);
  memcpy(k->e, k->beta, sizeof(double) * (size_t)(K > 1 ? K - 1 : 1));
  lapack_int info = LAPACKE_dstedc_work(LAPACK_COL_MAJOR, 'I', K, k->d, k->e, k->S, K, k->work,
                                        (lapack_int)k->lwork, k->iwork, (lapack_int)(3 + 5 * k->maxsteps));
  if (info != 0) return -1;
  /* eigenvalues ascending: the smallest Ritz value bounds M's from above */
  if (!(k->d[0] > 1e-12 * fabs(k->d[K - 1]))) return 1;
  for (int i = 0; i < K; i++) k->w[i] = k->S[(size_t)i * (size_t)K] * pow(k->d[i], r); /* S[0, i] f(λ_i) */
  cblas_dgemv(CblasColMajor, CblasNoTrans, K, K, 1.0, k->S, K, k->w, 1, 0.0, k->c, 1);
  return 0;
}

/* ‖x‖₂ as √(x·x), which is faster than dnrm2's scaled sum, unless x·x is
 * near under- or overflow. */
static double norm2(int n, const double *x) {
  double s = cblas_ddot(n, x, 1, x, 1);
  return s > 1e-280 && s < 1e280 ? sqrt(s) : cblas_dnrm2(n, x, 1);
}

/* Where the next, similar call should converge, after this one converged at
 * step K with `estimate` (at its first check when `at_first`): as few as 4
 * steps fewer, as far as the estimate, assumed to fall by k->shrink every 4
 * steps (geometrically in between), would still meet tol with a margin of
 * 2 there. Before any factor was seen, 4 fewer after a first-check
 * convergence (the call after a miss measures the factor). */
static long next_start(const Krylov *k, int K, bool at_first, double estimate, double tol) {
  if (K <= 12) return K;
  if (!(k->shrink > 1)) return at_first ? K - 4 : K;
  int fewer = 0;
  while (fewer < 4 && estimate * pow(k->shrink, (fewer + 1) / 4.0) <= 0.5 * tol) fewer++;
  return K - fewer;
}

typedef struct Dense {
  const double *M;
} Dense;

static void dense_matvec(void *user, int n, const double *x, double *y) {
  cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, ((Dense *)user)->M, n, x, 1, 0.0, y, 1);
}

int krylov_power(Krylov *k, int n, const double *M, long p, long q, double tol, int max_steps, double *v, int *steps,
                 double *estimate) {
  Dense d = {M};
  return krylov_power_op(k, n, dense_matvec, &d, p, q, tol, max_steps, v, steps, estimate);
}

int krylov_power_op(Krylov *k, int n, KrylovMatvec matvec, void *user, long p, long q, double tol, int max_steps,
                    double *v, int *steps, double *estimate) {
  *steps = 0;
  *estimate = INFINITY;
  if (n <= 0 || n > k->maxn) return 1;
  double beta0 = cblas_dnrm2(n, v, 1);
  if (beta0 == 0) {
    *estimate = 0;
    return 0;
  }
  if (max_steps > n) max_steps = n;
  if (max_steps > k->maxsteps) max_steps = (int)k->maxsteps;
  for (int i = 0; i < n; i++) k->Q[i] = v[i] / beta0;
  /* The estimate compares approximations 4 steps apart; with full
   * reorthogonalization Q_K is orthonormal to rounding, so it is taken on
   * the coefficients, ‖y_K − y_{K−4}‖ / ‖y_K‖ = ‖c_K − (c_{K−4}, 0)‖ / ‖c_K‖,
   * and only the accepted c is lifted. Each check computes f(T_K) e₁, so
   * they are few: every 4 steps from step 8, or from 4 before k->start when
   * the caller knows where a similar call may converge (then two checks, at
   * k->start − 4 and k->start, usually suffice). */
  int first = k->start - 4 > 8 ? (int)k->start - 4 : 8, prevK = 0;
  double lastest = 0; /* the estimate of the previous check (0: none) */
  for (int j = 0; j < max_steps; j++) {
    double *qj = k->Q + (size_t)j * (size_t)n, *w = k->Q + (size_t)(j + 1) * (size_t)n;
    matvec(user, n, qj, w);
    k->alpha[j] = cblas_ddot(n, qj, 1, w, 1);
    /* the three-term recurrence, then full reorthogonalization against
     * q_0 … q_j: one pass, and a second only when the first removed more
     * than a rounding-sized part of w (‖w‖ fell below 1/√2 of itself,
     * Daniel–Gragg–Kaufman–Stewart: "twice is enough") */
    cblas_daxpy(n, -k->alpha[j], qj, 1, w, 1);
    if (j > 0) cblas_daxpy(n, -k->beta[j - 1], qj - n, 1, w, 1);
    double b = norm2(n, w);
    for (int pass = 0; pass < 2; pass++) {
      cblas_dgemv(CblasRowMajor, CblasNoTrans, j + 1, n, 1.0, k->Q, n, w, 1, 0.0, k->c, 1);
      cblas_dgemv(CblasRowMajor, CblasTrans, j + 1, n, -1.0, k->Q, n, k->c, 1, 1.0, w, 1);
      double before = b;
      b = norm2(n, w);
      if (b >= M_SQRT1_2 * before) break;
    }
    k->beta[j] = b;
    int K = j + 1;
    /* the Krylov space is invariant (or complete): the approximation is exact */
    bool invariant = b <= 1e-13 * (fabs(k->alpha[j]) + (j > 0 ? k->beta[j - 1] : 0) + 1e-300) || K == n;
    if (invariant || (K >= first && (K - first) % 4 == 0)) {
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
        if (lastest > 0 && *estimate > 0) k->shrink = lastest / *estimate;
        lastest = *estimate;
      }
      if (invariant || (prevK > 0 && *estimate <= tol)) {
        cblas_dgemv(CblasRowMajor, CblasTrans, K, n, beta0, k->Q, n, k->c, 1, 0.0, v, 1);
        *steps = K;
        k->start = invariant ? K : next_start(k, K, prevK == first, *estimate, tol);
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
