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

/* What the tables' steps share: the model, the evaluator (params bound), CHOLMOD's workspace and
 * the error record. */
typedef struct EstWork {
  Model *m;
  Full *f;
  cholmod_common *cc;
  Err *err;
} EstWork;

/* A term's residual columns: C (n x D row-major), its first nnum the numerator's. */
typedef struct ResidualCols {
  double *C;
  long D, nnum;
} ResidualCols;

/* The affine parts of inverse term rt's operator in its one input x (at most ESTIMATE_THETA_MAX
 * entries, one axis): K[0] = M(0), K[j + 1] = M(e_j) − M(0) (sorted, explicit zeros dropped),
 * checked affine, M(x) = K[0] + Σ x_j K[j + 1], at the current sample's x and at 2·1. Returns x's
 * quantity with *nx its entries, or -1 (K all NULL): an operator of several inputs or of a
 * stage, or not affine. Leaves x set elsewhere: the caller sets a sample again. */
int estimate_affine_parts(const EstWork *w, const RTerm *rt, long n, cholmod_sparse **K, size_t *nx);
/* ‖A − B‖₁ ≤ 1e-12 ‖A‖₁. */
bool estimate_sparse_close(cholmod_sparse *A, cholmod_sparse *B, cholmod_common *cc);
/* A (sorted) symmetric to 1e-12 and positive semidefinite by diagonal dominance. */
bool estimate_symmetric_psd(cholmod_sparse *A, cholmod_common *cc);

/* product.c: K0 of class rc's product as a CHOLMOD matrix (unsymmetric storage), and its
 * Cholesky factor (simplicial LLᵀ; sets A->stype to 1: A's upper triangle); NULL with `err`. */
cholmod_sparse *product_matrix(Model *m, Full *f, const RClass *rc, cholmod_common *cc, Err *err);
cholmod_factor *product_factor(const RClass *rc, cholmod_sparse *A, cholmod_common *cc, Err *err);

/* Term rt of a class rc with a product K0 (estimate_product.c; w->cc unused: CHOLMOD started
 * afresh). cols: the residual's columns. Replaces C by L⁻¹PC (K0 = PᵀLLᵀP, CHOLMOD),
 * so that ‖C z‖ is the dual norm ‖r‖_{K0⁻¹} of the residual r = C z, and returns in *V (n x m,
 * malloc'd) L⁻¹P K0B, orthonormal, the span the Galerkin residual's Riesz representative is
 * K0-orthogonal to. Sets rt's min-θ table relative to K0 when it applies (one anchor x̄ with
 * M(x̄) = K0 on the rows the error lives on, and λ = 1), else leaves none. 0, or -1 with `err`.
 * Leaves the term's input set elsewhere: the caller sets a sample again. */
int estimate_product_columns(const EstWork *w, RTerm *rt, const RClass *rc, const ResidualCols *cols, double **V);

#endif
