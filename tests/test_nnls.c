/* test_nnls.c — backends/model/nnls.c: Lawson–Hanson NNLS and the convex
 * combination of the learned model for extern stages (paper §8.3, eq. 17).
 *
 * Oracles, independent of the solver's own code path:
 *  - known answers worked out by hand (small cases, exact geometry);
 *  - the KKT conditions, checked by brute force with plain loops;
 *  - for small problems, exhaustive enumeration of every passive set, each
 *    solved with a different LAPACK routine: dgels (QR) for NNLS, and dgglse
 *    (equality-constrained least squares, Σw = 1 imposed directly) for the
 *    convex problem — so the exact sum-to-one reduction of nnls.c is checked
 *    against a method that does not use it.
 * The first test shows the oracles reject wrong answers, so a passing run
 * means something. Random problems use a fixed seed. */
#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "support/failing_alloc.h"
#include "nnls.h"

/* ---------------------------------------------------------------- random data */

static uint64_t rng_state;

static void seed(uint64_t s) { rng_state = s; }

/* splitmix64 */
static uint64_t next_u64(void) {
  uint64_t z = (rng_state += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

static double uniform01(void) { return (double)(next_u64() >> 11) * 0x1.0p-53; }

static double gauss(void) {
  double u = uniform01(), v = uniform01();
  return sqrt(-2 * log(u > 0 ? u : 0x1.0p-60)) * cos(2 * M_PI * v);
}

static double *gauss_matrix(int rows, int cols) {
  size_t count = (size_t)rows * (size_t)cols;
  double *a = malloc(sizeof(double) * (count ? count : 1));
  assert_non_null(a);
  for (int i = 0; i < rows * cols; i++) a[i] = gauss();
  return a;
}

static double *zeros(int n) {
  double *a = calloc((size_t)(n ? n : 1), sizeof(double));
  assert_non_null(a);
  return a;
}

/* ---------------------------------------------------------------- oracles: NNLS */

/* ‖A w − b‖² */
static double nnls_objective(int m, int n, const double *A, const double *b, const double *w) {
  double f = 0;
  for (int i = 0; i < m; i++) {
    double r = -b[i];
    for (int j = 0; j < n; j++) r += A[i * n + j] * w[j];
    f += r * r;
  }
  return f;
}

/* Largest violation of the KKT conditions of min ‖A w − b‖, w ≥ 0: with
 * g = Aᵀ(A w − b), g_j ≥ 0 where w_j = 0 and g_j = 0 where w_j > 0. Each
 * g_j is taken relative to its own scale ‖a_j‖ (‖b‖ + Σ_k ‖a_k‖ w_k), so a
 * column many decades smaller than the others is checked as strictly as
 * the largest. A negative entry is infinitely wrong. */
static double nnls_kkt(int m, int n, const double *A, const double *b, const double *w) {
  double *norm = malloc(sizeof(double) * (size_t)n), scale = 0;
  for (int i = 0; i < m; i++) scale += b[i] * b[i];
  scale = sqrt(scale);
  for (int j = 0; j < n; j++) {
    double c = 0;
    for (int i = 0; i < m; i++) c += A[i * n + j] * A[i * n + j];
    norm[j] = sqrt(c);
    scale += norm[j] * fabs(w[j]);
  }
  double worst = 0;
  for (int j = 0; j < n && worst < INFINITY; j++) {
    if (!(w[j] >= 0)) worst = INFINITY;
    if (norm[j] == 0) continue;
    long double g = 0;
    for (int i = 0; i < m; i++) {
      long double r = -(long double)b[i];
      for (int k = 0; k < n; k++) r += (long double)A[i * n + k] * w[k];
      g += (long double)A[i * n + j] * r;
    }
    double v = w[j] > 0 ? fabs((double)g) : fmax(0, -(double)g);
    worst = fmax(worst, v / (norm[j] * (scale > 0 ? scale : 1)));
  }
  free(norm);
  return worst;
}

/* min ‖A w − b‖² over w ≥ 0 by enumerating every passive set P: the
 * optimum is the LS solution on its support (A of full column rank), so it
 * is the best feasible one of those. Each solved by dgels. */
static double nnls_brute_force(int m, int n, const double *A, const double *b) {
  assert_true(n <= 12 && m >= n);
  double best = nnls_objective(m, n, A, b, (double[12]){0});
  double *Ap = malloc(sizeof(double) * (size_t)(m * n)), *z = malloc(sizeof(double) * (size_t)m);
  double w[12];
  for (unsigned mask = 1; mask < (1u << n); mask++) {
    int k = 0, P[12];
    for (int j = 0; j < n; j++)
      if (mask & (1u << j)) P[k++] = j;
    for (int i = 0; i < m; i++)
      for (int c = 0; c < k; c++) Ap[i * k + c] = A[i * n + P[c]];
    memcpy(z, b, sizeof(double) * (size_t)m);
    lapack_int info = LAPACKE_dgels(LAPACK_ROW_MAJOR, 'N', m, k, 1, Ap, k, z, 1);
    assert_true(info >= 0);
    if (info > 0) continue;
    bool feasible = true;
    for (int j = 0; j < n; j++) w[j] = 0;
    for (int c = 0; c < k; c++) {
      feasible = feasible && z[c] >= 0;
      w[P[c]] = z[c];
    }
    if (feasible) best = fmin(best, nnls_objective(m, n, A, b, w));
  }
  free(Ap);
  free(z);
  return best;
}

/* The unconstrained LS solution by dgels (A of full column rank, m ≥ n). */
static void least_squares(int m, int n, const double *A, const double *b, double *x) {
  double *Ac = malloc(sizeof(double) * (size_t)(m * n)), *bc = malloc(sizeof(double) * (size_t)m);
  memcpy(Ac, A, sizeof(double) * (size_t)(m * n));
  memcpy(bc, b, sizeof(double) * (size_t)m);
  assert_int_equal(LAPACKE_dgels(LAPACK_ROW_MAJOR, 'N', m, n, 1, Ac, n, bc, 1), 0);
  memcpy(x, bc, sizeof(double) * (size_t)n);
  free(Ac);
  free(bc);
}

/* ---------------------------------------------------------------- oracles: convex combination */

/* ‖Xᵀ w − x‖² */
static double convex_objective(int S, int d, const double *X, const double *x, const double *w) {
  double f = 0;
  for (int i = 0; i < d; i++) {
    double r = -x[i];
    for (int s = 0; s < S; s++) r += w[s] * X[s * d + i];
    f += r * r;
  }
  return f;
}

/* max_s ‖x̂_s − x̂‖², the scale of the gradient and objective. */
static double convex_scale(int S, int d, const double *X, const double *x) {
  double sc = 0;
  for (int s = 0; s < S; s++) {
    double c = 0;
    for (int i = 0; i < d; i++) c += (X[s * d + i] - x[i]) * (X[s * d + i] - x[i]);
    sc = fmax(sc, c);
  }
  return sc > 0 ? sc : 1;
}

/* Largest violation of the KKT conditions of eq. 17, relative to
 * convex_scale(): with g_s = (x̂_s − x̂)ᵀ(Xᵀ w − x̂) and μ = Σ w_s g_s (the
 * multiplier of Σw = 1), g_s ≥ μ everywhere and g_s = μ where w_s > 0.
 * Feasibility — w ≥ 0, |Σw − 1| ≤ 1e-12 — is asserted. */
static double convex_kkt(int S, int d, const double *X, const double *x, const double *w) {
  long double sum = 0;
  for (int s = 0; s < S; s++) {
    if (!(w[s] >= 0)) fail_msg("w[%d] = %g < 0", s, w[s]);
    sum += w[s];
  }
  if (!(fabsl(sum - 1) <= 1e-12)) fail_msg("sum of weights - 1 = %.3Le", sum - 1);
  long double r[64];
  assert_true(d <= 64);
  for (int i = 0; i < d; i++) {
    r[i] = 0;
    for (int s = 0; s < S; s++) r[i] += (long double)w[s] * ((long double)X[s * d + i] - x[i]);
  }
  double *g = malloc(sizeof(double) * (size_t)S);
  long double mu = 0;
  for (int s = 0; s < S; s++) {
    long double gs = 0;
    for (int i = 0; i < d; i++) gs += ((long double)X[s * d + i] - x[i]) * r[i];
    g[s] = (double)gs;
    mu += w[s] * gs;
  }
  double worst = 0;
  for (int s = 0; s < S; s++) worst = fmax(worst, w[s] > 0 ? fabs(g[s] - (double)mu) : fmax(0, (double)mu - g[s]));
  free(g);
  return worst / convex_scale(S, d, X, x);
}

/* min ‖Xᵀw − x‖² over the simplex by enumerating supports P with |P| ≤ d+1
 * (Carathéodory), each an equality-constrained LS problem solved by dgglse. */
static double convex_brute_force(int S, int d, const double *X, const double *x) {
  assert_true(S <= 12 && d >= 1);
  double best = INFINITY, w[12];
  double *A = malloc(sizeof(double) * (size_t)(d * S)), *c = malloc(sizeof(double) * (size_t)d);
  for (unsigned mask = 1; mask < (1u << S); mask++) {
    int k = 0, P[12];
    for (int s = 0; s < S; s++)
      if (mask & (1u << s)) P[k++] = s;
    if (k > d + 1) continue;
    double B[12], one = 1, z[12];
    for (int i = 0; i < d; i++)
      for (int q = 0; q < k; q++) A[i * k + q] = X[P[q] * d + i];
    for (int q = 0; q < k; q++) B[q] = 1;
    memcpy(c, x, sizeof(double) * (size_t)d);
    lapack_int info = LAPACKE_dgglse(LAPACK_ROW_MAJOR, d, k, 1, A, k, B, k, c, &one, z);
    assert_true(info >= 0);
    if (info > 0) continue;
    bool feasible = true;
    for (int s = 0; s < S; s++) w[s] = 0;
    for (int q = 0; q < k; q++) {
      feasible = feasible && z[q] >= -1e-13;
      w[P[q]] = z[q];
    }
    if (feasible) best = fmin(best, convex_objective(S, d, X, x, w));
  }
  free(A);
  free(c);
  return best;
}

static void solve_convex(int S, int d, const double *X, const double *x, double *w) {
  char err[512];
  int rc = nnls_convex(S, d, X, x, w, ERR_OF(err, sizeof err));
  if (rc != 0) fail_msg("nnls_convex(S=%d, d=%d) failed: %s", S, d, err);
}

static void solve_nnls(int m, int n, const double *A, const double *b, double *w) {
  char err[512];
  int rc = nnls_solve(m, n, A, b, w, ERR_OF(err, sizeof err));
  if (rc != 0) fail_msg("nnls_solve(%d × %d) failed: %s", m, n, err);
}

/* ---------------------------------------------------------------- the oracles can fail */

static void oracles_reject_wrong_answers(void **state) {
  (void)state;
  seed(11);
  /* NNLS: the solution passes; moving off it in either direction fails. */
  int m = 10, n = 6;
  double *A = gauss_matrix(m, n), *b = gauss_matrix(m, 1), w[6], bad[6];
  solve_nnls(m, n, A, b, w);
  assert_true(nnls_kkt(m, n, A, b, w) < 1e-12);
  int zero = -1, pos = -1;
  for (int j = 0; j < n; j++) {
    if (w[j] == 0) zero = j;
    if (w[j] > 0) pos = j;
  }
  assert_true(zero >= 0 && pos >= 0);
  memcpy(bad, w, sizeof w);
  bad[pos] *= 1.001;
  assert_true(nnls_kkt(m, n, A, b, bad) > 1e-6);
  memcpy(bad, w, sizeof w);
  bad[zero] = 1e-3;
  assert_true(nnls_kkt(m, n, A, b, bad) > 1e-6 || nnls_objective(m, n, A, b, bad) > nnls_objective(m, n, A, b, w));
  memcpy(bad, w, sizeof w);
  bad[zero] = -1e-9;
  assert_true(isinf(nnls_kkt(m, n, A, b, bad)));
  free(A);
  free(b);

  /* Convex: an outside point; shifting weight between the support and off
   * it, or spreading it uniformly, fails. */
  int S = 7, d = 3;
  double *X = gauss_matrix(S, d), x[3] = {4, -3, 2}, v[7], u[7];
  solve_convex(S, d, X, x, v);
  assert_true(convex_kkt(S, d, X, x, v) < 1e-12);
  int on = -1, off = -1;
  for (int s = 0; s < S; s++) {
    if (v[s] > 0) on = s;
    if (v[s] == 0) off = s;
  }
  assert_true(on >= 0 && off >= 0);
  memcpy(u, v, sizeof v);
  u[on] -= 1e-3, u[off] += 1e-3;
  assert_true(convex_objective(S, d, X, x, u) > convex_objective(S, d, X, x, v));
  for (int s = 0; s < S; s++) u[s] = 1.0 / S;
  assert_true(convex_kkt(S, d, X, x, u) > 1e-3);
  assert_true(convex_objective(S, d, X, x, u) > convex_brute_force(S, d, X, x) + 1e-6);
  free(X);
}

/* ---------------------------------------------------------------- (a) NNLS, known answers */

/* The unconstrained LS solution is positive: NNLS must return exactly it. */
static void nnls_interior_equals_least_squares(void **state) {
  (void)state;
  seed(1);
  const int sizes[][2] = {{8, 5}, {30, 10}, {100, 40}, {61, 61}};
  for (size_t t = 0; t < sizeof sizes / sizeof *sizes; t++) {
    int m = sizes[t][0], n = sizes[t][1];
    double *A = gauss_matrix(m, n), *b = zeros(m), *ls = zeros(n), *w = zeros(n);
    for (int i = 0; i < m; i++) {
      for (int j = 0; j < n; j++) b[i] += A[i * n + j] * (1 + 0.5 * sin(j + 1.0));
      b[i] += 0.01 * gauss();
    }
    least_squares(m, n, A, b, ls);
    for (int j = 0; j < n; j++) assert_true(ls[j] > 0.1); /* the case is what it claims */
    solve_nnls(m, n, A, b, w);
    for (int j = 0; j < n; j++)
      if (!(fabs(w[j] - ls[j]) <= 1e-12)) fail_msg("%d × %d: w[%d] = %.17g, LS %.17g", m, n, j, w[j], ls[j]);
    free(A), free(b), free(ls), free(w);
  }

  /* Columns scaled over 8 decades (κ(A) ~ 1e8), b = A·1: the subproblem
   * solve must not cut small singular values that are signal. (The rounding
   * of b alone, ~ε‖b‖ ≈ 1e-11, moves w_0 of the 1e-4 column by ~1e-7.) */
  int m = 20, n = 9;
  double *A = gauss_matrix(m, n), *b = zeros(m), *w = zeros(n);
  for (int i = 0; i < m; i++)
    for (int j = 0; j < n; j++) {
      A[i * n + j] *= pow(10, j - 4);
      b[i] += A[i * n + j];
    }
  solve_nnls(m, n, A, b, w);
  for (int j = 0; j < n; j++)
    if (!(fabs(w[j] - 1) <= 1e-6)) fail_msg("column scale 1e%d: w = %.17g, expected 1", j - 4, w[j]);
  free(A), free(b), free(w);
}

static void nnls_known_active_sets(void **state) {
  (void)state;
  double w[3];
  /* A = I: w = max(b, 0). */
  const double identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, b1[3] = {1, -2, 3};
  solve_nnls(3, 3, identity, b1, w);
  assert_true(w[0] == 1 && w[1] == 0 && w[2] == 3);

  /* Unconstrained (4/3, -5/3); with w_2 = 0, w_1 = a_1ᵀb / ‖a_1‖² = 1/2, and
   * g_2 = a_2ᵀ(b − A w) = -5/2 < 0 keeps w_2 at zero. */
  const double A2[6] = {1, 0, 0, 1, 1, 1}, b2[3] = {1, -2, 0};
  solve_nnls(3, 2, A2, b2, w);
  assert_true(fabs(w[0] - 0.5) <= 1e-15 && w[1] == 0);

  /* Every column points away from b: w = 0. */
  const double A3[6] = {1, 2, 3, 4, 5, 6}, b3[3] = {-1, -1, -1};
  w[0] = w[1] = 7;
  solve_nnls(3, 2, A3, b3, w);
  assert_true(w[0] == 0 && w[1] == 0);

  /* b in the cone of two of three columns: exact fit on those two. */
  const double A4[9] = {1, 0, 1, 0, 1, 1, 0, 0, 1}, b4[3] = {2, 3, 0};
  solve_nnls(3, 3, A4, b4, w);
  assert_true(fabs(w[0] - 2) <= 1e-14 && fabs(w[1] - 3) <= 1e-14 && w[2] == 0);
}

/* Random problems whose LS solution has negative entries: the KKT
 * conditions hold, some constraints are active, and the objective is the
 * optimum found by enumerating all 2^n passive sets. */
static void nnls_active_constraints_random(void **state) {
  (void)state;
  seed(2);
  int active_cases = 0;
  for (int trial = 0; trial < 40; trial++) {
    int m = 6 + trial % 9, n = 2 + trial % 9;
    if (n > m) n = m;
    double *A = gauss_matrix(m, n), *b = gauss_matrix(m, 1), *ls = zeros(n), *w = zeros(n);
    least_squares(m, n, A, b, ls);
    bool negative = false;
    for (int j = 0; j < n; j++) negative = negative || ls[j] < 0;
    solve_nnls(m, n, A, b, w);
    double kkt = nnls_kkt(m, n, A, b, w);
    if (!(kkt <= 1e-12)) fail_msg("trial %d (%d × %d): KKT violation %.3e", trial, m, n, kkt);
    double f = nnls_objective(m, n, A, b, w), best = nnls_brute_force(m, n, A, b);
    if (!(fabs(f - best) <= 1e-12 * (1 + best)))
      fail_msg("trial %d (%d × %d): objective %.17g, brute force %.17g", trial, m, n, f, best);
    if (negative) {
      int zeros_ = 0;
      for (int j = 0; j < n; j++) zeros_ += w[j] == 0;
      assert_true(zeros_ > 0);
      active_cases++;
    }
    free(A), free(b), free(ls), free(w);
  }
  assert_true(active_cases >= 20); /* most trials exercise active constraints */
}

/* The shared QR and dgelsy solve the same subproblems: on the random
 * problems of nnls_active_constraints_random both reach the same w with
 * the same active set (the QR path never needing dgelsy there), and so
 * they do on a problem with an ill-conditioned pair of columns. */
static void nnls_qr_and_gelsy_agree(void **state) {
  (void)state;
  seed(2);
  double worst = 0;
  long gelsy_total = 0;
  for (int trial = 0; trial < 40; trial++) {
    int m = 6 + trial % 9, n = 2 + trial % 9;
    if (n > m) n = m;
    double *A = gauss_matrix(m, n), *b = gauss_matrix(m, 1), *wq = zeros(n), *wg = zeros(n);
    char err[512];
    NnlsMethod qr = {true, -1}, gelsy = {false, -1};
    assert_int_equal(nnls_solve_with(&(NnlsProblem){m, n, A, b}, wq, &qr, ERR_OF(err, sizeof err)), 0);
    assert_int_equal(nnls_solve_with(&(NnlsProblem){m, n, A, b}, wg, &gelsy, ERR_OF(err, sizeof err)), 0);
    assert_int_equal(qr.gelsy_solves, 0);
    gelsy_total += gelsy.gelsy_solves;
    double scale = 0;
    for (int j = 0; j < n; j++) scale = fmax(scale, fabs(wg[j]));
    for (int j = 0; j < n; j++) {
      assert_true((wq[j] == 0) == (wg[j] == 0)); /* the same active set */
      worst = fmax(worst, fabs(wq[j] - wg[j]) / fmax(scale, 1e-300));
    }
    free(A), free(b), free(wq), free(wg);
  }
  if (!(worst <= 1e-12)) fail_msg("QR and dgelsy paths differ by %.3e", worst);
  assert_true(gelsy_total >= 40); /* the other path did run */

  /* a1 = e1, a2 = (1, 1e-10, 0, -1e-9) (the pair's condition ≈ 1e9),
   * a3 = e3, b = (1, 4e-9, 0.5, 0). */
  double A[4 * 3] = {1, 1, 0, 0, 1e-10, 0, 0, 0, 1, 0, -1e-9, 0}, b[4] = {1, 4e-9, 0.5, 0}, wq[3], wg[3];
  char err[512];
  assert_int_equal(nnls_solve_with(&(NnlsProblem){4, 3, A, b}, wq, &(NnlsMethod){true, 0}, ERR_OF(err, sizeof err)), 0);
  assert_int_equal(nnls_solve_with(&(NnlsProblem){4, 3, A, b}, wg, &(NnlsMethod){false, 0}, ERR_OF(err, sizeof err)),
                   0);
  assert_true(nnls_kkt(4, 3, A, b, wq) < 1e-12);
  for (int j = 0; j < 3; j++) assert_true(fabs(wq[j] - wg[j]) <= 1e-12);
}

/* ---------------------------------------------------------------- (b) convex combination */

static void convex_training_sample_gets_all_weight(void **state) {
  (void)state;
  seed(3);
  /* Affinely independent samples (d ≥ S): the representation is unique. */
  int S = 5, d = 8;
  double *X = gauss_matrix(S, d), w[12];
  for (int j = 0; j < S; j++) {
    solve_convex(S, d, X, &X[j * d], w);
    for (int s = 0; s < S; s++)
      if (!(fabs(w[s] - (s == j)) <= 1e-10)) fail_msg("x = sample %d: w[%d] = %.17g", j, s, w[s]);
  }
  free(X);

  /* S > d + 1, but every sample is a vertex (points on a circle). */
  S = 12, d = 2;
  double C[24];
  for (int s = 0; s < S; s++) C[2 * s] = cos(2 * M_PI * s / S + 0.1), C[2 * s + 1] = sin(2 * M_PI * s / S + 0.1);
  for (int j = 0; j < S; j++) {
    solve_convex(S, d, C, &C[j * d], w);
    for (int s = 0; s < S; s++)
      if (!(fabs(w[s] - (s == j)) <= 1e-10)) fail_msg("circle, x = sample %d: w[%d] = %.17g", j, s, w[s]);
  }
}

/* x = Σ of 3 samples in general position with d ≥ S: those weights, exactly. */
static void convex_recovers_weights(void **state) {
  (void)state;
  seed(4);
  const int shapes[][2] = {{6, 8}, {10, 10}, {4, 60}, {20, 25}};
  for (size_t t = 0; t < sizeof shapes / sizeof *shapes; t++) {
    int S = shapes[t][0], d = shapes[t][1];
    double *X = gauss_matrix(S, d), *x = zeros(d), *truth = zeros(S), *w = zeros(S);
    int pick[3] = {1, S - 1, S / 2};
    double lambda[3] = {0.2, 0.5, 0.3};
    for (int q = 0; q < 3; q++) {
      truth[pick[q]] = lambda[q];
      for (int i = 0; i < d; i++) x[i] += lambda[q] * X[pick[q] * d + i];
    }
    solve_convex(S, d, X, x, w);
    for (int s = 0; s < S; s++)
      if (!(fabs(w[s] - truth[s]) <= 1e-10)) fail_msg("S=%d d=%d: w[%d] = %.17g, expected %g", S, d, s, w[s], truth[s]);
    free(X), free(x), free(truth), free(w);
  }
}

/* Points outside the hull: the nearest point of the hull, by hand for a
 * triangle, by KKT and enumeration for random data. */
static void convex_outside_hull(void **state) {
  (void)state;
  const double T[6] = {0, 0, 1, 0, 0, 1};
  const struct {
    double x[2], w[3];
  } cases[] = {
      {{2, 2}, {0, 0.5, 0.5}},       /* nearest: midpoint of the hypotenuse */
      {{-1, -1}, {1, 0, 0}},         /* vertex (0,0) */
      {{3, -1}, {0, 1, 0}},          /* vertex (1,0): (2,-1) lies in its normal cone */
      {{0.25, -1}, {0.75, 0.25, 0}}, /* (0.25, 0) on the bottom edge */
      {{0.2, 0.3}, {0.5, 0.2, 0.3}}, /* inside: exact barycentric weights */
  };
  double w[3];
  for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
    solve_convex(3, 2, T, cases[c].x, w);
    for (int s = 0; s < 3; s++)
      if (!(fabs(w[s] - cases[c].w[s]) <= 1e-12))
        fail_msg("triangle case %zu: w[%d] = %.17g, expected %g", c, s, w[s], cases[c].w[s]);
  }

  seed(5);
  for (int trial = 0; trial < 30; trial++) {
    int S = 4 + trial % 7, d = 1 + trial % 4;
    double *X = gauss_matrix(S, d), *x = zeros(d), *w = zeros(S);
    for (int i = 0; i < d; i++) x[i] = 4 * gauss();
    solve_convex(S, d, X, x, w);
    double kkt = convex_kkt(S, d, X, x, w);
    if (!(kkt <= 1e-12)) fail_msg("trial %d (S=%d d=%d): KKT violation %.3e", trial, S, d, kkt);
    double f = convex_objective(S, d, X, x, w), best = convex_brute_force(S, d, X, x);
    double sc = convex_scale(S, d, X, x);
    if (!(fabs(f - best) <= 1e-12 * sc))
      fail_msg("trial %d (S=%d d=%d): objective %.17g, dgglse enumeration %.17g", trial, S, d, f, best);
    free(X), free(x), free(w);
  }
}

/* The weights do not depend on the units or the origin of x̂ (the scaling
 * step of nnls_convex), even at scales where a fixed penalty λ would be
 * wrong by orders of magnitude. */
static void convex_invariance(void **state) {
  (void)state;
  seed(6);
  int S = 15, d = 4;
  double *X = gauss_matrix(S, d), x[4], w0[15], w[15], Y[60], y[4];
  for (int i = 0; i < d; i++) x[i] = 3 * gauss();
  solve_convex(S, d, X, x, w0);
  assert_true(convex_objective(S, d, X, x, w0) > 0.1); /* outside: the solution is unique */
  const double scales[] = {1e6, 1e-6, 1e150, 1e-150, 3.0};
  for (size_t t = 0; t < sizeof scales / sizeof *scales; t++) {
    double c = scales[t], shift = t == 4 ? 1e4 : 0;
    for (int k = 0; k < S * d; k++) Y[k] = c * X[k] + shift * (k % d + 1);
    for (int i = 0; i < d; i++) y[i] = c * x[i] + shift * (i + 1);
    solve_convex(S, d, Y, y, w);
    for (int s = 0; s < S; s++)
      if (!(fabs(w[s] - w0[s]) <= 1e-9))
        fail_msg("scale %g shift %g: w[%d] = %.17g, unscaled %.17g", c, shift, s, w[s], w0[s]);
  }
  free(X);
}

/* Degenerate training sets: duplicated samples, all samples equal, d = 0. */
static void convex_degenerate(void **state) {
  (void)state;
  seed(7);
  int S = 6, d = 3;
  double *X = gauss_matrix(S, d), w[6];
  memcpy(&X[3 * d], &X[0], sizeof(double) * (size_t)d);
  solve_convex(S, d, X, &X[0], w);
  assert_true(fabs(w[0] + w[3] - 1) <= 1e-10);
  assert_true(convex_kkt(S, d, X, &X[0], w) <= 1e-12);

  for (int s = 1; s < S; s++) memcpy(&X[s * d], &X[0], sizeof(double) * (size_t)d);
  double x[3] = {1, 2, 3};
  solve_convex(S, d, X, x, w);
  assert_true(convex_kkt(S, d, X, x, w) <= 1e-12);
  solve_convex(S, d, X, &X[0], w);
  assert_true(convex_kkt(S, d, X, &X[0], w) <= 1e-12);

  solve_convex(S, 0, NULL, NULL, w);
  double sum = 0;
  for (int s = 0; s < S; s++) {
    assert_true(w[s] >= 0);
    sum += w[s];
  }
  assert_true(fabs(sum - 1) <= 1e-12);
  free(X);
}

/* ---------------------------------------------------------------- (c) random problems */

static void nnls_random(void **state) {
  (void)state;
  seed(8);
  const int sizes[][2] = {{10, 5}, {5, 10}, {12, 12}, {40, 8}, {61, 200}, {200, 60}, {60, 200}, {100, 100}};
  for (size_t t = 0; t < sizeof sizes / sizeof *sizes; t++)
    for (int trial = 0; trial < 4; trial++) {
      int m = sizes[t][0], n = sizes[t][1];
      double *A = gauss_matrix(m, n), *b = gauss_matrix(m, 1), *w = zeros(n);
      if (trial % 2) /* non-negative, strongly correlated columns: the hard case for active sets */
        for (int k = 0; k < m * n; k++) A[k] = fabs(A[k]) + 1;
      if (trial >= 2) /* columns scaled over 16 decades */
        for (int j = 0; j < n; j++) {
          double c = pow(10, 16 * uniform01() - 8);
          for (int i = 0; i < m; i++) A[i * n + j] *= c;
        }
      solve_nnls(m, n, A, b, w);
      double kkt = nnls_kkt(m, n, A, b, w);
      if (!(kkt <= 1e-12)) fail_msg("%d × %d trial %d: KKT violation %.3e", m, n, trial, kkt);
      if (n <= 12 && m >= n) {
        double f = nnls_objective(m, n, A, b, w), best = nnls_brute_force(m, n, A, b);
        if (!(fabs(f - best) <= 1e-10 * (1 + best)))
          fail_msg("%d × %d: objective %.17g, brute force %.17g", m, n, f, best);
      }
      free(A), free(b), free(w);
    }
}

static void convex_random(void **state) {
  (void)state;
  seed(9);
  const int sizes[][2] = {{5, 3},   {8, 2},   {9, 4},   {20, 5},  {50, 10}, {100, 60},
                          {200, 60}, {200, 5}, {200, 1}, {10, 60}, {60, 60}};
  for (size_t t = 0; t < sizeof sizes / sizeof *sizes; t++)
    for (int trial = 0; trial < 6; trial++) {
      int S = sizes[t][0], d = sizes[t][1];
      double *X = gauss_matrix(S, d), *x = zeros(d), *w = zeros(S);
      int kind = trial % 3;
      if (kind == 0) { /* inside: a random convex combination of a random subset */
        double total = 0, *lambda = zeros(S);
        for (int s = 0; s < S; s++) total += lambda[s] = uniform01() < 0.3 ? uniform01() : 0;
        if (total == 0) total += lambda[0] = 1;
        for (int s = 0; s < S; s++)
          for (int i = 0; i < d; i++) x[i] += lambda[s] / total * X[s * d + i];
        free(lambda);
      } else if (kind == 1) { /* outside */
        for (int i = 0; i < d; i++) x[i] = 3 * gauss();
      } else { /* near a training sample */
        int j = (int)(next_u64() % (uint64_t)S);
        for (int i = 0; i < d; i++) x[i] = X[j * d + i] + 1e-3 * gauss();
      }
      solve_convex(S, d, X, x, w);
      double kkt = convex_kkt(S, d, X, x, w), sc = convex_scale(S, d, X, x);
      if (!(kkt <= 1e-12)) fail_msg("S=%d d=%d kind %d: KKT violation %.3e", S, d, kind, kkt);
      double f = convex_objective(S, d, X, x, w);
      if (kind == 0 && !(f <= 1e-20 * sc)) fail_msg("S=%d d=%d: x in the hull but residual² %.3e", S, d, f);
      if (S <= 12) {
        double best = convex_brute_force(S, d, X, x);
        if (!(fabs(f - best) <= 1e-10 * sc))
          fail_msg("S=%d d=%d: objective %.17g, dgglse enumeration %.17g", S, d, f, best);
      }
      free(X), free(x), free(w);
    }
}

/* ---------------------------------------------------------------- errors */

static void bad_input(void **state) {
  (void)state;
  char err[256];
  double X[6] = {0, 0, 1, 0, 0, 1}, x[2] = {0.1, 0.1}, w[3];
  assert_int_equal(nnls_convex(0, 2, X, x, w, ERR_OF(err, sizeof err)), -1);
  assert_non_null(strstr(err, "no training samples"));
  X[3] = NAN;
  assert_int_equal(nnls_convex(3, 2, X, x, w, ERR_OF(err, sizeof err)), -1);
  assert_string_equal(err, "learned model: component 1 of training input 1 is not finite (nan)");
  X[3] = 0, x[1] = INFINITY;
  assert_int_equal(nnls_convex(3, 2, X, x, w, ERR_OF(err, sizeof err)), -1);
  assert_non_null(strstr(err, "input to predict is not finite"));
  assert_int_equal(nnls_convex(3, 2, X, x, w, NULL), -1); /* no buffer: still just -1 */
  char tiny[8];
  assert_int_equal(nnls_convex(3, 2, X, x, w, ERR_OF(tiny, sizeof tiny)), -1);
  assert_int_equal(strlen(tiny), sizeof tiny - 1);

  double A[4] = {1, 2, 3, NAN}, b[2] = {1, 1};
  assert_int_equal(nnls_solve(2, 2, A, b, w, ERR_OF(err, sizeof err)), -1);
  assert_string_equal(err, "nnls: A[1][1] is not finite (nan)");
  assert_int_equal(nnls_solve(-1, 2, A, b, w, ERR_OF(err, sizeof err)), -1);
  /* Empty problems are fine. */
  assert_int_equal(nnls_solve(2, 0, A, b, w, ERR_OF(err, sizeof err)), 0);
  assert_int_equal(nnls_solve(0, 2, A, b, w, ERR_OF(err, sizeof err)), 0);
  assert_true(w[0] == 0 && w[1] == 0);
}

/* Every allocation failure is reported, never a crash, and (under ASan)
 * never a leak. */

static void allocation_failure(void **state) {
  (void)state;
  seed(10);
  int S = 30, d = 6;
  double *X = gauss_matrix(S, d), x[6], w[30], ref[30];
  for (int i = 0; i < d; i++) x[i] = 2 * gauss();
  solve_convex(S, d, X, x, ref);
  char err[256];
  int k;
  for (k = 0; k < 100; k++) {
    failing_alloc_after(k);
    int rc = nnls_convex(S, d, X, x, w, ERR_OF(err, sizeof err));
    failing_alloc_off();
    if (rc == 0) break;
    if (!strstr(err, "out of memory")) fail_msg("failing allocation %d: %s", k, err);
  }
  assert_true(k > 2 && k < 100); /* allocations happened, and then it succeeded */
  assert_memory_equal(w, ref, sizeof w);
  free(X);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(oracles_reject_wrong_answers),
      cmocka_unit_test(nnls_interior_equals_least_squares),
      cmocka_unit_test(nnls_known_active_sets),
      cmocka_unit_test(nnls_active_constraints_random),
      cmocka_unit_test(nnls_qr_and_gelsy_agree),
      cmocka_unit_test(convex_training_sample_gets_all_weight),
      cmocka_unit_test(convex_recovers_weights),
      cmocka_unit_test(convex_outside_hull),
      cmocka_unit_test(convex_invariance),
      cmocka_unit_test(convex_degenerate),
      cmocka_unit_test(nnls_random),
      cmocka_unit_test(convex_random),
      cmocka_unit_test(bad_input),
      cmocka_unit_test(allocation_failure),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
