/* nnls.c — Lawson–Hanson non-negative least squares and the convex
 * combination of the learned model for extern stages (paper §8.3, eq. 17).
 *
 * nnls_solve() is the active-set method of Lawson & Hanson, "Solving Least
 * Squares Problems" (1974), ch. 23: move the index of steepest descent
 * (per unit column norm: columns are equilibrated first) into the passive
 * set P, solve the unconstrained least-squares problem on the
 * columns of P, and while that solution has a non-positive entry step back
 * towards the previous iterate until an entry of P reaches zero and leaves
 * P. The subproblems share one Householder QR of the passive columns in
 * the order they entered P: an entering column is reduced by the reflectors
 * already there (dormqr) and gets its own (dlarfg) — exactly the QR that
 * refactorizing A_P from scratch would compute, so nothing accumulates —
 * and a column that leaves P has the rest refactorized (dgeqr2). Where that
 * QR does not resolve the subproblem (a new column within rounding of the
 * span of the others, or R so ill-conditioned that the solution grows past
 * ‖b‖ / √ε) the subproblem is solved by LAPACK dgelsy, rank-revealing, as
 * before. Every factorization is LAPACK's; the update only decides which
 * columns to factorize. (At the learned model's sizes, d + 1 rows, one
 * dgelsy call costs 1–4 µs, most of it call overhead; the update 0.3 µs.)
 *
 * The sum-to-one constraint of nnls_convex() is enforced exactly, not by a
 * penalty row of weight λ. Since Σ w = 1, the residual is
 *
 *     Xᵀ w − x = C w,   C = [x̂_1 − x̂, …, x̂_S − x̂]   (d × S),
 *
 * so eq. 17 asks for the point of the convex hull of C's columns nearest
 * the origin. That point comes from a single NNLS problem (the device
 * Lawson–Hanson use for least-distance programming, ch. 23):
 *
 *     u = argmin_{u ≥ 0} ‖[C; 1ᵀ] u − e_{d+1}‖₂,   w = u / Σ u.
 *
 * Why: with t = Σu and u = t v (v in the simplex) the objective is
 * t² ‖C v‖² + (t − 1)², minimized over v by the minimizers of eq. 17 whatever
 * t > 0 is, and over t by t = 1 / (1 + min ‖C v‖²) ∈ (0, 1]. So Σu never
 * vanishes, w ≥ 0 holds exactly (NNLS sets inactive entries to exact zeros)
 * and Σw = 1 to rounding. A penalty row λ·1ᵀ (target λ) instead leaves
 * Σw − 1 of order ‖C‖ ‖residual‖ / λ², worsens the conditioning of the
 * subproblems as λ grows, and needs λ chosen per problem. C is divided by its largest
 * column norm first (eq. 17 is invariant under scaling C), so that the
 * appended row of ones and C have the same scale: the result does not depend
 * on the units or origin of x̂. Accuracy degrades, roughly to
 * ε · dist(x̂, hull) / diameter(hull), only when x̂ is far outside a small
 * hull.
 */
#include <cblas.h>
#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "ast.h" /* mem_alloc_hook, error_set */
#include "nnls.h"
#include "scratch.h"


/* `count` elements of `size` bytes from the allocation hook; NULL on
 * overflow or failure. Never asks for 0 bytes (malloc may return NULL). */
static void *alloc_array(size_t count, size_t size) {
  if (count == 0) count = 1;
  if (count > SIZE_MAX / size) return NULL;
  return mem_alloc_hook(count * size);
}

static int max_int(int a, int b) { return a > b ? a : b; }

/* Index states of the active-set method. */
enum {
  AT_ZERO,   /* w_j = 0, may enter P */
  PASSIVE,   /* j in P: w_j > 0, solved for */
  REJECTED,  /* entered P but its least-squares value was ≤ 0 (rounding): skipped until w changes */
};

typedef struct Solver {
  int m, n;
  const double *A, *b;  /* the problem, A row-major m × n */
  double *cols;         /* passive columns A_P, column-major m × k; dgelsy overwrites it */
  double *rhs;          /* max(m, n) entries: b in, z_P out */
  double *work;         /* dgelsy workspace, grown on demand */
  lapack_int *jpvt;     /* dgelsy column pivots, n entries */
  double *qr;           /* Householder QR of the first nqr passive columns, column-major m × n */
  double *tau;          /* its reflectors' scalars, n entries */
  double *qtb, *qtb0;   /* Qᵀ b (m entries) and its value before the last append */
  int nqr;              /* columns of P that qr factorizes, -1 when it is not usable */
  bool use_qr;          /* false: every subproblem by dgelsy */
  long gelsy;           /* subproblems dgelsy solved */
  size_t nwork;
  Err *err;
} Solver;

/* Make the dgelsy workspace hold `nwork` doubles. */
static int reserve(Solver *s, size_t nwork) {
  if (nwork > s->nwork) {
    free(s->work);
    s->work = alloc_array(nwork, sizeof(double));
    s->nwork = s->work ? nwork : 0;
  }
  if (!s->work)
    return err_set(s->err, "nnls: out of memory for the LAPACK workspace (%d × %d problem)", s->m, s->n);
  return 0;
}

/* z ← argmin ‖A_P z_P − b‖₂, z = 0 off the passive set `P` (`k` indices),
 * by dgelsy (QR with column pivoting, then a complete orthogonal factorization
 * where the rank is deficient: the minimum-norm solution) rather than dgels
 * (QR): a passive set that is numerically rank deficient — two training
 * samples that nearly coincide — then gives a bounded answer instead of
 * garbage. (An SVD, dgelsd, does the same at several times the cost.) */
static int solve_gelsy(Solver *s, const int *P, int k, double *z) {
  int m = s->m, n = s->n;
  s->gelsy++;
  int ld = max_int(max_int(m, k), 1);
  for (int c = 0; c < k; c++)
    for (int i = 0; i < m; i++) s->cols[(size_t)c * m + i] = s->A[(size_t)i * n + P[c]];
  for (int i = 0; i < ld; i++) s->rhs[i] = i < m ? s->b[i] : 0;
  for (int c = 0; c < k; c++) s->jpvt[c] = 0;

  /* Columns whose part beyond the span of the earlier ones is below
   * rcond · the largest count as dependent: only rounding-level dependence
   * is cut, so a well-conditioned A_P gets its exact LS solution. */
  double rcond = 10.0 * ld * DBL_EPSILON;
  lapack_int rank = 0;
  if (s->nwork == 0) { /* one workspace query, for the largest passive set */
    double wq = 0;
    lapack_int info = LAPACKE_dgelsy_work(LAPACK_COL_MAJOR, m, n, 1, s->cols, max_int(m, 1), s->rhs,
                                          max_int(max_int(m, n), 1), s->jpvt, rcond, &rank, &wq, -1);
    if (info != 0)
      return err_set(s->err, "nnls: LAPACK dgelsy rejected argument %d in its workspace query (a bug in npg)",
                  (int)-info);
    if (reserve(s, (size_t)wq + (size_t)(4 * (m + n)) + 1)) return -1;
  }
  lapack_int info = LAPACKE_dgelsy_work(LAPACK_COL_MAJOR, m, k, 1, s->cols, max_int(m, 1), s->rhs, ld, s->jpvt, rcond,
                                        &rank, s->work, (lapack_int)s->nwork);
  if (info != 0) return err_set(s->err, "nnls: LAPACK dgelsy rejected argument %d (a bug in npg)", (int)-info);
  for (int j = 0; j < n; j++) z[j] = 0;
  for (int c = 0; c < k; c++) z[P[c]] = s->rhs[c];
  return 0;
}

/* Columns of unit norm whose part beyond the span of the earlier passive
 * columns is below this count as dependent (dgelsy's rcond below). */
static double dependent_below(const Solver *s, int k) { return 10.0 * max_int(max_int(s->m, k), 1) * DBL_EPSILON; }

/* Qᵀ y for the first `r` reflectors of qr, y of `rows` entries starting at
 * row `first` of the factorization. LWORK 1 keeps dormqr on its unblocked
 * path, the right one for a single column. */
static void apply_qt(Solver *s, int first, int rows, int r, double *y) {
  double scratch;
  LAPACKE_dormqr_work(LAPACK_COL_MAJOR, 'L', 'T', rows, 1, r, &s->qr[(size_t)first * s->m + first], s->m,
                      &s->tau[first], y, max_int(rows, 1), &scratch, 1);
}

/* Append passive column P[k-1] to the QR of P[0..k-2]; false when it is
 * dependent on them (or there is no row left for it). */
static bool qr_append(Solver *s, const int *P, int k) {
  int m = s->m, c = k - 1;
  if (s->nqr != c || c >= m) return false;
  double *col = &s->qr[(size_t)c * m];
  for (int i = 0; i < m; i++) col[i] = s->A[(size_t)i * s->n + P[c]];
  if (c > 0) apply_qt(s, 0, m, c, col);
  LAPACKE_dlarfg_work(m - c, &col[c], &col[c + 1], 1, &s->tau[c]);
  if (!(fabs(col[c]) > dependent_below(s, k))) return false;
  for (int i = 0; i < m; i++) s->qtb0[i] = s->qtb[i];
  apply_qt(s, c, m - c, 1, &s->qtb[c]);
  s->nqr = k;
  return true;
}

/* Factorize A_P afresh; false when a column is dependent on the earlier
 * ones. */
static bool qr_rebuild(Solver *s, const int *P, int k) {
  int m = s->m;
  s->nqr = -1;
  if (k > m) return false;
  for (int c = 0; c < k; c++)
    for (int i = 0; i < m; i++) s->qr[(size_t)c * m + i] = s->A[(size_t)i * s->n + P[c]];
  for (int i = 0; i < m; i++) s->qtb[i] = s->b[i];
  if (k > 0) {
    LAPACKE_dgeqr2_work(LAPACK_COL_MAJOR, m, k, s->qr, m, s->tau, s->rhs);
    apply_qt(s, 0, m, k, s->qtb);
  }
  for (int c = 0; c < k; c++)
    if (!(fabs(s->qr[(size_t)c * m + c]) > dependent_below(s, k))) return false;
  s->nqr = k;
  return true;
}

/* After P[k-1] was appended and then refused (its value ≤ 0), drop it:
 * the QR of the first k-1 columns is unchanged by an append. */
static void qr_drop_last(Solver *s, int k) {
  if (s->nqr != k) {
    s->nqr = -1;
    return;
  }
  for (int i = 0; i < s->m; i++) s->qtb[i] = s->qtb0[i];
  s->nqr = k - 1;
}

/* z ← argmin ‖A_P z_P − b‖₂, z = 0 off P (`k` indices; `appended`: P[k-1]
 * is new since the last call). R z_P = (Qᵀb)[0..k-1] when the QR of A_P is
 * usable and the solution stays within ‖b‖ / √ε, else dgelsy. */
static int solve_passive(Solver *s, const int *P, int k, double *z, bool appended) {
  if (!s->use_qr) return solve_gelsy(s, P, k, z);
  bool ok = appended && s->nqr == k - 1 ? qr_append(s, P, k) : qr_rebuild(s, P, k);
  if (!ok) {
    s->nqr = -1;
    return solve_gelsy(s, P, k, z);
  }
  double *x = s->rhs, big = 0, rhs2 = 0;
  for (int c = 0; c < k; c++) x[c] = s->qtb[c], rhs2 += x[c] * x[c];
  cblas_dtrsv(CblasColMajor, CblasUpper, CblasNoTrans, CblasNonUnit, k, s->qr, s->m, x, 1);
  for (int c = 0; c < k; c++) big += x[c] * x[c];
  if (!(big * DBL_EPSILON <= rhs2)) return solve_gelsy(s, P, k, z); /* ‖z‖ > ‖Qᵀb‖ / √ε */
  for (int j = 0; j < s->n; j++) z[j] = 0;
  for (int c = 0; c < k; c++) z[P[c]] = x[c];
  return 0;
}

/* r ← b − A w, g ← Aᵀ r (the negative gradient of ½‖A w − b‖²). */
static void residual_gradient(const Solver *s, const double *w, double *r, double *g) {
  for (int i = 0; i < s->m; i++) r[i] = s->b[i];
  if (s->m == 0) {
    for (int j = 0; j < s->n; j++) g[j] = 0;
    return;
  }
  cblas_dgemv(CblasRowMajor, CblasNoTrans, s->m, s->n, -1.0, s->A, s->n, w, 1, 1.0, r, 1);
  cblas_dgemv(CblasRowMajor, CblasTrans, s->m, s->n, 1.0, s->A, s->n, r, 1, 0.0, g, 1);
}

int nnls_solve(int m, int n, const double *A, const double *b, double *w, Err *err) {
  return nnls_solve_with(&(NnlsProblem){m, n, A, b}, w, &(NnlsMethod){.use_qr = true}, err);
}

/* Lawson–Hanson's inner loop: while the passive solution z leaves the
 * feasible set, move w towards z as far as feasibility allows and drop the
 * indices P[0..*k) that reach zero (their state back to AT_ZERO). Each pass
 * removes at least one index, so it ends. 0, or -1 with the solve's message. */
static int move_to_feasible(Solver *s, int *P, int *k, double *w, double *z, unsigned char *state) {
  for (;;) {
    double alpha = INFINITY;
    int q = -1;
    for (int c = 0; c < *k; c++) {
      int i = P[c];
      if (z[i] > 0) continue;
      double den = w[i] - z[i];
      double a = den > 0 ? w[i] / den : 0;
      if (a < alpha) alpha = a, q = i;
    }
    if (q < 0) return 0; /* z_P > 0: feasible */
    for (int c = 0; c < *k; c++) {
      int i = P[c];
      w[i] += alpha * (z[i] - w[i]);
    }
    w[q] = 0;
    int kept = 0;
    for (int c = 0; c < *k; c++) {
      int i = P[c];
      if (w[i] > 0) {
        P[kept++] = i;
      } else {
        w[i] = 0;
        state[i] = AT_ZERO;
      }
    }
    *k = kept;
    if (kept == 0) return 0;
    if (solve_passive(s, P, kept, z, false)) return -1;
  }
}

/* The arrays of one solve besides the Solver's. */
typedef struct NnlsWork {
  double *unit, *z, *r, *g, *colnorm;
  int *P;
  unsigned char *state;
} NnlsWork;

/* `count` elements (at least one) of `size` bytes from the solve's scratch. */
static void *work_array(Scratch *sc, size_t count, size_t size) { return scratch_array(sc, count ? count : 1, size); }

/* Lawson–Hanson on s (its arrays allocated) from w = 0, for the scaled problem: w is ŵ = D w
 * on return (nnls_solve_with scales back). -1 with the Solver's error. */
static int lawson_hanson(Solver *s, const double *A, double *w, const NnlsWork *wk) {
  int m = s->m, n = s->n, ld = max_int(m, n);
  const double *b = s->b;
  Err *err = s->err;
  double *unit = wk->unit, *z = wk->z, *r = wk->r, *g = wk->g, *colnorm = wk->colnorm;
  int *P = wk->P;
  unsigned char *state = wk->state;
  int rc = 0;
  for (int j = 0; j < n; j++) state[j] = AT_ZERO;

  /* Solve for ŵ = D w with unit columns Â = A D⁻¹, D = diag(‖a_j‖): the
   * problem and w ≥ 0 are unchanged, but the subproblems are equilibrated,
   * one stopping tolerance fits every column (g_j of a column many decades
   * below the largest is not lost in its rounding), and the entering column
   * is the steepest per unit of column norm. A zero column never enters. */
  for (int j = 0; j < n; j++) {
    colnorm[j] = m > 0 ? cblas_dnrm2(m, &A[j], n) : 0;
    for (int i = 0; i < m; i++) unit[(size_t)i * n + j] = colnorm[j] > 0 ? A[(size_t)i * n + j] / colnorm[j] : 0;
  }
  s->A = unit;
  for (int i = 0; i < m; i++) s->qtb[i] = b[i]; /* the QR of no column: Q = I */
  s->nqr = 0;
  double bnorm = m > 0 ? cblas_dnrm2(m, b, 1) : 0;

  int max_iter = max_int(3 * n, 30), iter = 0, k = 0; /* k = |P| */
  for (;;) {
    residual_gradient(s, w, r, g);
    /* The rounding error of ĝ_j = â_jᵀ r is about ε · max(m, n) · (‖b‖ + Σ ŵ). */
    double wsum = 0;
    for (int t = 0; t < n; t++) wsum += w[t];
    double tol = 10.0 * DBL_EPSILON * ld * (bnorm + wsum);

    /* KKT: stop when no index at zero has a descent direction beyond
     * rounding; otherwise take the steepest one (Lawson–Hanson). */
    int j = -1;
    for (int t = 0; t < n; t++)
      if (state[t] == AT_ZERO && g[t] > tol && (j < 0 || g[t] > g[j])) j = t;
    if (j < 0) break;
    if (iter == max_iter) {
      rc = err_set(err, "nnls: no convergence in %d iterations (%d × %d problem, largest gradient %.2e, tolerance %.2e)",
                max_iter, m, n, g[j], tol);
      break;
    }
    iter++;

    P[k++] = j;
    state[j] = PASSIVE;
    if (solve_passive(s, P, k, z, true)) {
      rc = -1;
      break;
    }
    if (!(z[j] > 0)) {
      /* In exact arithmetic g_j > 0 implies z_j > 0 (Lawson–Hanson, ch.
       * 23); here it failed by rounding. Taking j would cycle, so skip it
       * until the iterate moves. */
      qr_drop_last(s, k);
      k--;
      state[j] = REJECTED;
      continue;
    }
    for (int t = 0; t < n; t++)
      if (state[t] == REJECTED) state[t] = AT_ZERO;

    if (move_to_feasible(s, P, &k, w, z, state)) return -1;
    for (int c = 0; c < k; c++) w[P[c]] = z[P[c]];
  }
  return rc;
}

int nnls_solve_with(const NnlsProblem *p, double *w, NnlsMethod *how, Err *err) {
  int m = p->m, n = p->n;
  const double *A = p->A, *b = p->b;
  if (err_held(err)) err->msg[0] = '\0';
  how->gelsy_solves = 0;
  if (m < 0 || n < 0) return err_set(err, "nnls: bad problem size %d × %d", m, n);
  if ((m > 0 && n > 0 && !A) || (m > 0 && !b) || (n > 0 && !w)) return err_set(err, "nnls: NULL argument");
  for (int i = 0; i < m; i++) {
    for (int j = 0; j < n; j++)
      if (!isfinite(A[(size_t)i * n + j]))
        return err_set(err, "nnls: A[%d][%d] is not finite (%g)", i, j, A[(size_t)i * n + j]);
    if (!isfinite(b[i])) return err_set(err, "nnls: b[%d] is not finite (%g)", i, b[i]);
  }
  for (int j = 0; j < n; j++) w[j] = 0;
  if (n == 0) return 0;

  Solver s = {.m = m, .n = n, .b = b, .err = err, .use_qr = how->use_qr};
  int ld = max_int(m, n);
  Scratch sc = SCRATCH_OF(NULL);
  NnlsWork wk = {.unit = work_array(&sc, (size_t)m * (size_t)n, sizeof(double))};
  s.cols = work_array(&sc, (size_t)max_int(m, 1) * (size_t)n, sizeof(double));
  s.rhs = work_array(&sc, (size_t)ld, sizeof(double));
  s.jpvt = work_array(&sc, (size_t)n, sizeof(lapack_int));
  s.qr = work_array(&sc, (size_t)m * (size_t)n, sizeof(double));
  s.tau = work_array(&sc, (size_t)n, sizeof(double));
  s.qtb = work_array(&sc, (size_t)m, sizeof(double));
  s.qtb0 = work_array(&sc, (size_t)m, sizeof(double));
  wk.z = work_array(&sc, (size_t)n, sizeof(double));
  wk.r = work_array(&sc, (size_t)m, sizeof(double));
  wk.g = work_array(&sc, (size_t)n, sizeof(double));
  wk.P = work_array(&sc, (size_t)n, sizeof(int));
  wk.colnorm = work_array(&sc, (size_t)n, sizeof(double));
  wk.state = work_array(&sc, (size_t)n, 1);
  int rc;
  if (!wk.unit || !s.cols || !s.rhs || !s.jpvt || !s.qr || !s.tau || !s.qtb || !s.qtb0 || !wk.z || !wk.r || !wk.g ||
      !wk.P || !wk.colnorm || !wk.state)
    rc = err_set(err, "nnls: out of memory (%d × %d problem)", m, n);
  else {
    rc = lawson_hanson(&s, A, w, &wk);
    for (int j = 0; j < n; j++) /* back to w = D⁻¹ ŵ; a zero column has ŵ_j = 0 */
      w[j] = wk.colnorm[j] > 0 ? w[j] / wk.colnorm[j] : 0;
  }
  how->gelsy_solves = s.gelsy;
  free(s.work); /* grown by reserve */
  scratch_release(&sc);
  return rc;
}

/* paper §8.3, eq. 17: w = argmin ‖Xᵀ w − x‖ over the simplex, as one NNLS
 * problem (see the top of this file). */
int nnls_convex(int S, int d, const double *X, const double *x, double *w, Err *err) {
  if (err_held(err)) err->msg[0] = '\0';
  if (S < 1) return err_set(err, "learned model: no training samples (S = %d)", S);
  if (d < 0) return err_set(err, "learned model: bad input dimension %d", d);
  if ((d > 0 && (!X || !x)) || !w) return err_set(err, "learned model: NULL argument");
  for (int s = 0; s < S; s++)
    for (int i = 0; i < d; i++)
      if (!isfinite(X[(size_t)s * d + i]))
        return err_set(err, "learned model: component %d of training input %d is not finite (%g)", i, s,
                    X[(size_t)s * d + i]);
  for (int i = 0; i < d; i++)
    if (!isfinite(x[i]))
      return err_set(err, "learned model: component %d of the input to predict is not finite (%g)", i, x[i]);

  int m = d + 1;
  Scratch sc = SCRATCH_OF(NULL);
  double *E = work_array(&sc, (size_t)m * (size_t)S, sizeof(double));
  double *f = work_array(&sc, (size_t)m, sizeof(double));
  if (!E || !f)
    return scratch_release(&sc),
           err_set(err, "learned model: out of memory for %d training samples of dimension %d", S, d);

  /* E = [C / σ; 1ᵀ], σ the largest column norm of C = X − x (0 when every
   * training input equals x: then any convex combination is exact). */
  double sigma = 0;
  for (int s = 0; s < S; s++) {
    double c = 0;
    for (int i = 0; i < d; i++) {
      double diff = X[(size_t)s * d + i] - x[i];
      c += diff * diff;
    }
    sigma = fmax(sigma, sqrt(c));
  }
  double inv = sigma > 0 && isfinite(1 / sigma) ? 1 / sigma : 1;
  for (int i = 0; i < d; i++)
    for (int s = 0; s < S; s++) E[(size_t)i * S + s] = (X[(size_t)s * d + i] - x[i]) * inv;
  for (int s = 0; s < S; s++) E[(size_t)d * S + s] = 1;
  for (int i = 0; i < d; i++) f[i] = 0;
  f[d] = 1;

  char why[512];
  int rc = nnls_solve(m, S, E, f, w, ERR_OF(why, sizeof why));
  scratch_release(&sc);

  double t = 0;
  for (int s = 0; s < S; s++) t += w[s];
  if (t > 0)
    for (int s = 0; s < S; s++) w[s] /= t;
  if (rc) return err_set(err, "learned model (%d training samples of dimension %d): %s", S, d, why);
  if (!(t > 0)) /* Σu ≥ 1 / (1 + 1) after scaling: cannot happen */
    return err_set(err, "learned model: the weights of the convex combination vanished (Σu = %g; a bug in npg)",
                t);
  return 0;
}
