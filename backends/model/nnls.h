/* nnls.h — the learned model of extern (black-box) stages, paper §8.3.
 *
 * An extern stage z = f(x) has no tensor form, so it is not reduced by
 * Galerkin projection. Instead, training pairs (x̂_s, ẑ_s), s = 1..S, of
 * reduced inputs and reduced extern values are kept, and a new x̂ is
 * predicted as ẑ = Σ_s w_s ẑ_s with the weights of the convex combination of
 * training inputs closest to x̂ (paper eq. 17):
 *
 *     w = argmin ‖Σ_s w_s x̂_s − x̂‖₂   subject to  w ≥ 0, Σ_s w_s = 1.
 *
 * nnls_convex() computes those weights; nnls_solve() is the Lawson–Hanson
 * non-negative least-squares solver under it. Both are plain library code:
 * no exit(), every failure is a return value with a message in `err`, and
 * all of their memory comes from mem_alloc_hook (ir/ast.h), so tests can
 * make allocation fail. */
#ifndef NPG_NNLS_H
#define NPG_NNLS_H

#include <stdbool.h>
#include <stddef.h>

#include "context.h" /* Err */

/* Lawson–Hanson NNLS: minimize ‖A w − b‖₂ subject to w ≥ 0. `A` is `m` × `n`
 * row-major, `b` has `m` entries, `w` receives `n`. Returns 0 on success; -1
 * with a message in `err` on bad input, allocation failure or a LAPACK
 * failure (then `w` is unspecified), or if it did not converge in
 * max(3n, 30) outer iterations (then `w` holds the best iterate so far, which
 * is feasible: w ≥ 0). */
int nnls_solve(int m, int n, const double *A, const double *b, double *w, Err *err);

/* nnls_solve() with its subproblem solver chosen, for tests. */
typedef struct NnlsProblem {
  int m, n;
  const double *A, *b; /* A m x n row-major, b m entries */
} NnlsProblem;
typedef struct NnlsMethod {
  bool use_qr;       /* false: every subproblem by dgelsy (no shared QR) */
  long gelsy_solves; /* set: how many subproblems dgelsy solved */
} NnlsMethod;
int nnls_solve_with(const NnlsProblem *p, double *w, NnlsMethod *how, Err *err);

/* The convex combination (paper §8.3, eq. 17): `X` is `S` × `d` row-major (the
 * training inputs x̂_s, one per row), `x` has `d` entries. Returns in `w` (`S`
 * entries) the weights with w ≥ 0 and Σw = 1 (exactly, up to rounding) that
 * minimize ‖Xᵀ w − x‖₂. 0 on success, -1 with a message in `err` (on
 * non-convergence `w` is still a convex combination, the best found). */
int nnls_convex(int S, int d, const double *X, const double *x, double *w, Err *err);

#endif
