/* estimate_steps.h — what the estimate tables' two files share (private to backends/train):
 * estimate_train.c builds every term's table, estimate_product.c the part of a term whose class
 * is orthonormal in a product (`basis u: product K0`): the residual's Riesz representatives in
 * K0 and the min-θ bound relative to K0 (docs/estimates.md). */
#ifndef NPG_ESTIMATE_STEPS_H
#define NPG_ESTIMATE_STEPS_H

#include <stdbool.h>
#include <suitesparse/cholmod.h>

#include "estimate.h"
#include "train.h"

/* What the tables' steps share: the model, the evaluator (params bound), CHOLMOD's workspace, the
 * error record and the training samples (NULL: none; the pencil's anchors in a product need them). */
typedef struct EstWork {
  Model *m;
  Full *f;
  cholmod_common *cc;
  Err *err;
  const SampleSource *src;
} EstWork;

/* A term's residual columns: C (n x D row-major), its first nnum the numerator's. */
typedef struct ResidualCols {
  double *C;
  long D, nnum;
} ResidualCols;

/* Where a term's residual columns read basis rows (estimate_term_columns): class c's rows from
 * B[c] through map[c] (B NULL or B[c] NULL: its whole basis rc->B; map NULL or map[c] NULL: every
 * row at its index), for the stage's output rows [lo, hi) of its n. */
typedef struct ColRows {
  long lo, hi, n;
  const double *const *B;
  const RowMap *const *map;
} ColRows;
/* Rows [lo, hi) of term t of stage i's residual columns C (the numerator's full-space monomials,
 * then −M B_y ⊗ each operator tensor's: (hi − lo) x D row-major, D = estimate_term_dim, zeroed by
 * the caller), from the tensor builders restricted to those rows. 0, or -1 with w->err (an entry
 * reading a basis row `rows` does not hold among them). */
int estimate_term_columns(const EstWork *w, int i, int t, const ColRows *rows, double *C);
/* The column blocks of term t of stage i whose residuals are factored apart (estimate_train.c): b[2j], b[2j + 1]
 * the first and one past the last column of block j — [0, D) for a term not chained, a chained term's
 * ChainLayout blocks —; returns 2 × the blocks. */
int estimate_table_blocks(const Model *m, int i, int t, long b[2 * ESTIMATE_OPS_MAX + 2]);
/* Row r of class c's basis as `rows` holds it; NULL when it does not. */
const double *estimate_basis_row(const Model *m, const ColRows *rows, int c, long r);
/* norms[c] = ‖C(:, c)‖ of the n x D row-major C. */
void estimate_column_norms(const double *C, long n, long D, double *norms);
/* Term rt's first operator at the evaluator's current values, dense n x n row-major into M. 0, or -1 with `err`. */
int estimate_dense_operator(Full *f, const RTerm *rt, double *M, long n, Err *err);
/* The same as a CHOLMOD sparse matrix (unsymmetric storage, sorted, duplicates summed); NULL with `err`. */
cholmod_sparse *estimate_sparse_operator(Full *f, const RTerm *rt, long n, cholmod_common *cc, Err *err);
/* σ_min of the n x n row-major A (destroyed; `sv` 2n doubles): an SPD one by dsyevr, any other by
 * dgesvd; NaN when LAPACK fails. */
double estimate_smallest_sv(double *A, long n, double *sv);
/* *sigma = σ_min(M) of inverse term rt's operator at the evaluator's current values (dense up to
 * ESTIMATE_DENSE_MAX rows, sparse by Lanczos above; w->cc started by the caller); NaN when it is
 * singular. 0, or -1 with w->err (the operator not built, or out of memory). */
int estimate_operator_sigma(const EstWork *w, const RTerm *rt, long n, double *sigma);

/* The affine parts of inverse term rt's operator in its one input x (at most ESTIMATE_THETA_MAX
 * entries, one axis): K[0] = M(0), K[j + 1] = M(e_j) − M(0) (sorted, explicit zeros dropped),
 * checked affine, M(x) = K[0] + Σ x_j K[j + 1], at the current sample's x and at 2·1. Returns x's
 * quantity with *nx its entries, or -1 (K all NULL): an operator of several inputs or of a
 * stage, or not affine. Leaves x set elsewhere: the caller sets a sample again. */
int estimate_affine_parts(const EstWork *w, const RTerm *rt, long n, cholmod_sparse **K, size_t *nx);
/* The input x of inverse term rt (its operator of n rows) when the operator is M(x) = M_0 + Σ x_j M_j with
 * every M_j symmetric positive semidefinite by diagonal dominance (the min-θ bound's case); -1 otherwise.
 * Leaves the input set elsewhere: the caller sets its sample again. */
int estimate_affine_input(const EstWork *w, const RTerm *rt, long n);
/* An anchor of inverse term rt's min-θ bound appended to rt->est_theta (room made by the caller): the input x̄
 * (rt->est_theta_n entries; NULL: not measured) and λ_min(M(x̄)) = lmin, when x̄ and lmin are positive. */
void estimate_theta_anchor(RTerm *rt, const double *x, double lmin);
/* ‖A − B‖₁ ≤ 1e-12 ‖A‖₁. */
bool estimate_sparse_close(cholmod_sparse *A, cholmod_sparse *B, cholmod_common *cc);
/* A (sorted) symmetric to 1e-12 and positive semidefinite by diagonal dominance. */
bool estimate_symmetric_psd(cholmod_sparse *A, cholmod_common *cc);
/* Step j of a Lanczos run (estimate_train.c, at most 60 steps): the top Ritz value θ of the tridiagonal
 * al[0..j], be[0..j-1] and its residual bound |be[j] s| into *res (an eigenvalue lies within it); NaN
 * when LAPACK fails. */
double estimate_ritz_top(const double *al, const double *be, int j, double *res);
/* σ_min of the sparse n x n A by Lanczos (estimate_train.c: 1/λ_max(A⁻¹) for an SPD A, the figure
 * erring low); NaN when the factorization fails. */
double estimate_sparse_smallest_sv(cholmod_sparse *A, long n, cholmod_common *cc);

/* product.c: K0 of class rc's product as a CHOLMOD matrix (unsymmetric storage), and its
 * Cholesky factor (simplicial LLᵀ; sets A->stype to 1: A's upper triangle); NULL with `err`. */
cholmod_sparse *product_matrix(Model *m, Full *f, const RClass *rc, cholmod_common *cc, Err *err);
cholmod_factor *product_factor(const RClass *rc, cholmod_sparse *A, cholmod_common *cc, Err *err);

/* Term rt of a class rc with a product K0 (estimate_product.c; w->cc unused: CHOLMOD started
 * afresh). cols: the residual's columns (of a named numerator: its basis's columns first, nnum
 * of them). An inverse term's C becomes L⁻¹PC (K0 = PᵀLLᵀP, CHOLMOD), so that ‖C z‖ is the dual
 * norm ‖r‖_{K0⁻¹} of the residual r = C z; a projection's or an application's (estimate_term_applies) becomes
 * L⁻¹P K0C = LᵀPC, so that ‖C z‖ is the error's K0-norm ‖(I − BBᵀK0) w‖_K0 once projected; an application's ratios
 * ‖M‖_K0 / ‖DᵀMB‖₂ are measured at training samples (est_sigma, or est_opc for several operators); a term of several
 * operators with one solve gets each block as its part needs (the solve's a residual) and the solve's min-θ table.
 * Returns in *V (n x m, malloc'd)
 * L⁻¹P K0B = LᵀPB, orthonormal, the span the caller projects out (the Galerkin residual's Riesz
 * representative is K0-orthogonal to B's span; the projection's error is K0-orthogonal to it). For
 * an inverse sets rt's min-θ table relative to K0 when it applies (one anchor x̄ with M(x̄) = K0
 * on the rows the error lives on, λ = 1; else the pencil (M(x̄), K0)'s smallest eigenvalue at up
 * to ESTIMATE_SIGMA_SAMPLES training samples, w->src's), else leaves none. 0, or -1 with `err`.
 * Leaves the term's input set elsewhere: the caller sets a sample again. */
int estimate_product_columns(const EstWork *w, RTerm *rt, const RClass *rc, const ResidualCols *cols, double **V);
/* A named numerator's error e_w in the norm of the term's residual (estimate.c): sets rt->est_carry
 * to c with ‖δw‖ ≤ c e_w in the norm the term's figure adds it in, when class rc (the term's) or cw
 * (the numerator's) has a product; leaves it 0 (unused) when neither has. From λ_min of each product
 * (dense dsyevr up to ESTIMATE_DENSE_MAX rows, Lanczos above) and ‖K0‖₁ ≥ λ_max(K0) (Gershgorin).
 * 0, or -1 with `err`. */
int estimate_product_carry(const EstWork *w, RTerm *rt, const RClass *rc, const RClass *cw);

#endif
