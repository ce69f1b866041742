/* estimate.h — online error estimates of a reduced evaluation and the trust
 * signal of its inputs (DESIGN §16, issue 41; docs/estimates.md says which
 * figures are bounds and which estimates).
 *
 * A term t of a Galerkin stage y with basis B is either a projection
 * (ŷ_t = Bᵀ w_t, no operator) or one inverse (ŷ_t = (BᵀMB)⁻¹ Bᵀ w_t). Its
 * residual r_t = w_t − M B ŷ_t (M = I for a projection) is C_t z_t: z_t the
 * reduced numerator coordinates (the packed input products of its tensors,
 * or a named numerator's coordinates ŵ) followed by ŷ_t ⊗ (each operator
 * tensor's packed input product), C_t the full-space columns of those
 * monomials. Galerkin makes r_t orthogonal to B, so training stores R_t of
 * the QR of the projected columns, C'_t = Q_t R_t with C'_t = (I − BBᵀ) C_t
 * (no cancellation against ‖Bᵀ r‖, no squaring as a Gram matrix would), and
 *
 *     ‖r_t‖ = ‖R_t z_t‖,   ‖y_t − B ŷ_t‖ ≤ ‖r_t‖ / σ_min(M),
 *
 * a polynomial in the reduced inputs evaluated in O(D²), D the length of
 * z_t. A projection term's ‖r_t‖ is its error exactly (M = I). For an
 * inverse, σ_min(M) is estimated as c · σ_min(BᵀMB): c the smallest ratio
 * σ_min(M)/σ_min(BᵀMB) over training samples (dense SVDs in training, up to
 * ESTIMATE_DENSE_MAX rows, sparse Lanczos above). An operator affine in one
 * input with semidefinite terms uses instead the min-θ lower bound of its
 * λ_min (anchors stored in training), a rigorous bound (docs/estimates.md says
 * exactly when). A stage's estimate is the sum of its terms'.
 *
 * In a class orthonormal in a product K0 (BᵀK0B = I) an inverse term's figure is
 * ‖y_t − B ŷ_t‖_K0 ≤ ‖r_t‖_{K0⁻¹} / α_LB: R_t is then of the Riesz representatives'
 * columns (backends/train/estimate_product.c), the same ‖R_t z_t‖ online, over the min-θ
 * bound relative to K0 (one anchor x̄ with M(x̄) = K0, λ = 1, or the pencil's anchors,
 * λ = λ_min(M(x̄), K0)); no σ_min fallback there. A projection term's (ŷ_t = BᵀK0 w_t) is
 * ‖(I − BBᵀK0) w_t‖_K0 = ‖R_t z_t‖, R_t of the columns weighted by K0's Cholesky factor; an operator
 * application's (ŷ_t = (DᵀMB)^p Dᵀw_t) the chain below in K0's norm (estimate_term_applies). A
 * named numerator's error e_w enters as RTerm.est_carry · e_w when a product is involved.
 *
 * Chaining: a named numerator w carries its own estimate e_w into the term
 * (plus e_w for a projection, plus e_w / σ for an inverse); an input x of a
 * tensor that carries an error e_x adds its propagation, max(‖∂ŷ/∂x̂‖₂ e_x,
 * the secant along the worst direction) from the stage's local reduced
 * Jacobian (an estimate: estimate.c's propagate). An interpolated stage's
 * own figure is its formula's residual at the fit's entries and at check
 * entries drawn from the others (interp_check), as is a Galerkin stage's of
 * diagonal operators whose terms lack tables (roots, several operators).
 * An operator application y = M^p w, or a term of several declared operators (estimate_term_chains),
 * chains each operator's projection residual ‖(I − BBᵀ) M B v‖ (exact, its own block of the table)
 * through the steps, the error before each step multiplied by ‖M‖ or divided by σ_min(M)
 * (estimated from training samples). A root M^α w integrates the same residual of the shifted systems
 * (s + M̂)⁻¹ŵ over s for its fractional part β (α = k + β, 0 < |β| < 1), carried through M^k, and chains
 * its integer part k as an application's or an inverse's (estimate.c's root_step), alone or among the
 * operators of a term. Externs, and terms with a diagonal operator among several, have none. */
#ifndef NPG_ESTIMATE_H
#define NPG_ESTIMATE_H

#include <stdbool.h>

#include "model.h"
#include "model_store.h"
#include "reduced.h"

#define EST_BOUND 1u    /* a rigorous bound of the error (up to roundoff); unset: an estimate */
#define EST_OUTSIDE 2u  /* an input it depends on lies outside the training range (estimate_outside) */
#define EST_ROUNDOFF 4u /* the residual is below the roundoff of its expansion: the figure is that level */
#define EST_NONE 8u     /* no estimate (the figure is NaN): EstimateResult.why says why */

/* Operators up to this many rows get their σ_min measured in training by a dense SVD (an SPD
 * one by its smallest eigenvalue, dsyevr): at 1444 rows that took 0.5 s of CPU a sample (26 s
 * of wall time for 12 samples on the loaded 2-core machine, training 0.2 s without), so at 800
 * rows the 8 samples take under 1 s. Larger operators are assembled sparse and measured by Lanczos
 * on K⁻¹ (one CHOLMOD Cholesky a sample) or on (KᵀK)⁻¹ (one UMFPACK LU), up to ESTIMATE_SPARSE_MAX
 * rows; beyond it their stage gets no estimate. The bound is memory: Lanczos keeps up to 61 vectors
 * of n doubles (240 MB at 500,000 rows) beside the factorization. At 20,201 rows (pyMOR's thermal
 * block, 30 samples) the estimate's tables took 2 s of training's CPU time (1.6 s → 3.5 s). */
#define ESTIMATE_DENSE_MAX 800
#define ESTIMATE_SPARSE_MAX 500000
/* A term of several operators gets its ratios (one manifest line, estops) for at most this many: one of more has
 * no estimate. */
#define ESTIMATE_OPS_MAX 64
/* The min-θ bound's input has at most this many entries (θ_j = x_j). */
#define ESTIMATE_THETA_MAX 64
/* Training samples whose operator σ_min is measured, spread over the set. */
#define ESTIMATE_SIGMA_SAMPLES 8
/* The trust signal's margin: a coordinate is outside the training range when it lies
 * more than this fraction of the range (or of its magnitude, for a range of one value)
 * beyond the training samples' min or max. */
#define ESTIMATE_RANGE_MARGIN 0.1

/* Whether term `t` of stage number `i` can carry an estimate: a Galerkin
 * stage (not an extern or interpolated), the term a projection or one
 * inverse (power −1), its tensors and named numerator of classes whose
 * bases exist. Else false with the reason in `why`. */
bool estimate_term_eligible(const Model *m, int i, int t, char *why, size_t n);
/* D, the length of z_t (above) for term `t` of stage `i`. */
long estimate_term_dim(const Model *m, int i, int t);
/* Whether term `rt`'s figure is chained operator by operator: one declared operator applied to a
 * positive integer power, y_t = M^p w_t (an operator application), to a power p ≤ −2 (|p| solves, each
 * step an inverse's: estimate.c's inverse_steps, σ_min the min-θ bound where it applies), or to a power p/q, q > 1 (a root:
 * its step is root_step's quadrature with its integer part chained, its ratio σ_min's, and for p/q > 1
 * also ‖M‖'s), or up to ESTIMATE_OPS_MAX declared operators, each to a positive integer power,
 * inverted (to any power), or a root (M^p K⁻¹ L^(1/2) w_t, applied right to left). Its table is block diagonal (ChainLayout): R of the QR of each block of projected columns
 * apart — the numerator's (w_t's own projection error), each applied operator's ((I − BBᵀ) M B ⊗
 * its tensors' monomials), and each inverse's, joined with what produced its operand (the
 * numerator, or an applied operator of power 1): the Galerkin residual of that operand, as an
 * inverse term's. Per operator a ratio c_k at training samples: the largest ‖M‖₂/‖BᵀMB‖₂ of an
 * applied one, the smallest σ_min(M)/σ_min(BᵀMB) of an inverted one (est_sigma for a term of one
 * operator, est_opc for several; NaN: not measured). Online, from e = the numerator's error, each
 * step of an applied M from v to M̂v gives e ← ‖M‖ e + ‖(I − BBᵀ) M B v‖ (the second part in the
 * next inverse's residual when joined), ‖M‖ ≈ c ‖M̂‖₂, and each inverse from v to v' = M̂⁻¹v gives
 * e ← (e + ‖r‖) / σ_min(M), r = (I − BBᵀ)(g − M B v'), g the operand's full-space producer, σ_min ≈
 * c σ_min(M̂): an estimate, exact only for y = M w of an exact numerator (no ratio enters). */
bool estimate_term_chains(const RTerm *rt);
/* The ratios a chained term keeps in RTerm.est_opc (the manifest's estops line): one per operator for a term of
 * several (as above; a root's is σ_min's), then one ‖M‖ ratio (the largest ‖M‖₂/‖BᵀMB‖₂) per root of power p/q >
 * 1, in the order of the operators; 0 for a term of one operator and no such root (its ratio is est_sigma). */
int estimate_term_ratios(const RTerm *rt);
/* Where operator k's ‖M‖ ratio is in est_opc (a root of power above 1 of a chained term), else -1. */
int estimate_norm_slot(const RTerm *rt, int k);
/* Whether term rt only applies declared operators, each to a positive integer power (M^p N^q w): in a class with a
 * product K0 it is then reduced by K0-projections, (DᵀMB)^p Dᵀw (model_term_projects), and its figure is the chain
 * above in K0's norm: each residual ‖(I − BBᵀK0) M B v‖_K0 (the table's columns weighted by K0's Cholesky factor,
 * as a projection's: backends/train/estimate_product.c), ‖M‖_K0 ≈ c ‖DᵀMB‖₂. */
bool estimate_term_applies(const RTerm *rt);
/* Whether chained term rt has an estimate in a class with a product K0: declared operators each applied to a positive
 * integer power or inverted, at most one inverse, right after the numerator or after an operator applied once (its
 * operand's producer g, whose Galerkin right-hand side Bᵀg the reduction gives it: model_term_projects). The inverse
 * divides by the min-θ bound relative to K0 (estimate_product.c's anchors), an error entering it is in K0⁻¹'s norm. */
bool estimate_product_chains(const RTerm *rt);
/* A chained term's columns: the numerator's [0, nnum), operator k's [off[k], off[k] + len[k]); an
 * inverse's block starts at start[k] (0: the numerator's, off[k − 1]: the applied operator of power
 * 1 before it, whose columns it joins; else off[k]); `joins[k + 1]`: the numerator (k = −1) or
 * applied operator k is joined with the inverse after it, and has no block of its own. */
typedef struct ChainLayout {
  long nnum, off[ESTIMATE_OPS_MAX], len[ESTIMATE_OPS_MAX], start[ESTIMATE_OPS_MAX];
  bool joins[ESTIMATE_OPS_MAX + 1];
} ChainLayout;
void estimate_chain_layout(const Model *m, int i, int t, ChainLayout *L);
/* The numerator's part of z_t: a named numerator's m, or the numerator tensors' columns. */
long estimate_term_num_dim(const Model *m, int i, int t);
/* How training makes a term's residual table. Whole when its columns (n x D doubles) and their R
 * (D x D, kept in the model) take at most ESTIMATE_MAX_BYTES together: the columns projected and
 * factored at once (estimate_train.c qr_factor). Beyond, only R must fit ESTIMATE_MAX_TABLE_BYTES
 * (the model's size, and the online O(D²)): in a class without a product the table is made by row
 * chunks (estimate_train.c chunked_table: a tall-skinny QR of [B C], about ESTIMATE_CHUNK_BYTES of C
 * at a time; memory R, the working factor (D + m)² and a chunk); in a class with a product the
 * columns are weighted by K0's Cholesky factor, which mixes rows, so they are made whole up to
 * ESTIMATE_MAX_PRODUCT_BYTES. The cost is 2 n D² flops either way. A term beyond gets no table, and
 * its evaluations say so with the figures. D grows with the basis (1 + 10 m on a 3 x 3 thermal
 * block: 1,901 at m = 190, 20,201 x 1,901 columns = 293 MiB, R 27.6 MiB), R with D² (the heat
 * example's implicit step, D = 3600 and n = 16,384: R 99 MiB, stays without one). */
#define ESTIMATE_MAX_BYTES ((size_t)256 << 20)
#define ESTIMATE_MAX_TABLE_BYTES ((size_t)64 << 20)
#define ESTIMATE_MAX_PRODUCT_BYTES ((size_t)1 << 30)
#define ESTIMATE_CHUNK_BYTES ((size_t)16 << 20)
typedef enum { EST_MAKE_NONE, EST_MAKE_WHOLE, EST_MAKE_CHUNKS } EstMake;
EstMake estimate_term_make(const Model *m, int i, int t);
/* Tests only: NPG_TEST_ESTIMATE_CHUNKS=ROWS in the environment makes every table that could be made
 * by chunks made so, ROWS rows a chunk (tests/cli/estimate_chunks.py compares it with the whole
 * route); 0 when unset. */
long estimate_test_chunk_rows(void);
/* The bytes of term `t` of stage `i`'s columns and R: 8 (n D + D²) (SIZE_MAX on overflow). */
size_t estimate_term_bytes(const Model *m, int i, int t);
/* The packed input product of tensor `x` (its columns' monomials) at
 * coordinates `coords` (per quantity) into z[0..x->cols); `scratch` holds
 * Σ in_len doubles. */
void estimate_input_product(const Model *m, double *const *coords, const RTensor *x, double *z, double *scratch);

/* Per quantity: the estimated error of the last evaluation (absolute, 2-norm of the lifted
 * values, or its class's product norm; NaN: none), its EST_ flags, and why there is none. */
typedef struct EstimateResult {
  int nq;
  double *err;
  unsigned *flags;
  char why[512];            /* the first quantity without an estimate and why ("" if every one has one) */
  char (*why_q)[256];       /* per quantity: why it has none ("" if it has one) */
} EstimateResult;

EstimateResult *estimate_result_new(const Model *m);
void estimate_result_free(EstimateResult *e);
/* Every quantity's estimate after reduced_eval(r) succeeded. `input_err`
 * (per quantity, NULL: every input exact) is each input's own error
 * ‖x − B x̂‖ (npg_reduced_set measures it). 0, or -1 out of memory. */
int estimate_eval(Reduced *r, const double *input_err, EstimateResult *e);
/* Whether input `q`'s coordinates lie outside the training range with the
 * margin: true with the first such coordinate in *coord. False when the
 * model recorded no range. */
bool estimate_outside(const Model *m, int q, const double *coords, long *coord);

/* The estimate tables to and from MODEL/: lines `estimate STAGE TERM dim D
 * sigma C qr`, arrays est_STAGE_tTERM ((D + 1) x D: R_t, then the unprojected
 * columns' norms, for the roundoff level), for a term of several operators `estops STAGE TERM c_1 …
 * c_K` (its ratios, estimate_term_chains), `range Q` lines with arrays
 * range_Q (2 x m: each coordinate's min, then max). A model without them
 * has no estimates; a line that does not match the layout is refused. */
int estimate_save(const Model *m, ModelStore *s);
int estimate_load(Model *m, const ModelStore *s, const char *dir, Err *err);

#endif
