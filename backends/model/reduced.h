/* reduced.h — the reduced evaluator of a model (paper §4: contractions,
 * inverse and root operators, learned externs of §8.3), and the same
 * evaluator generated as C specialized to one model. */
#ifndef NPG_REDUCED_H
#define NPG_REDUCED_H

#include <stdbool.h>

#include "model.h"

/* ---------------------------------------------------------------- reduced evaluation (reduced.c) */

typedef struct Reduced Reduced;
Reduced *reduced_new(Model *m, Err *err);
void reduced_free(Reduced *r);
/* Reduced coordinates of quantity q (set for inputs, computed for stages). */
double *reduced_coords(Reduced *r, int q);
/* Every quantity's coordinates (Program.quantities order). */
double *const *reduced_all_coords(Reduced *r);
/* x̂ = Bᵀx for an input or extern given in full. */
void reduced_project(Reduced *r, int q, const double *x);
/* Evaluate every stage. 0, or -1 with the message in reduced_error(). */
int reduced_eval(Reduced *r, long sample);
/* Evaluate stage number i (Model.stages) from the current coordinates. */
int reduced_eval_stage(Reduced *r, int i, long sample);
/* Term `t` of stage number `i` alone into v[0..m) (its class's m), from the
 * current coordinates; with `M` (m x m, may be NULL) the reduced matrix of
 * its last operator as assembled, before it was applied (the online
 * estimate's σ_min, estimate.h); with v NULL, that matrix alone, nothing
 * applied (for a term of one operator: the estimate of a one-term stage
 * reads the term's value from the stage's). 0, or -1 with reduced_error(). */
int reduced_term(Reduced *r, int i, int t, double *v, double *M, long sample);
/* With `on`, externs keep the coordinates the caller set (reduced_project)
 * instead of the learned map: for tests and for verifying the rest. */
void reduced_use_given_externs(Reduced *r, bool on);
bool reduced_given_externs(const Reduced *r);
/* With `on`, fractional powers (roots) of reduced operators are applied by
 * the Lanczos process (krylov.h) to an a-posteriori estimate of 1e-10
 * relative, falling back to the eigendecomposition where that would take
 * more than n/2 + 8 steps or the operator looks singular or indefinite.
 * Off (the default, and the exact reference of tests and `verify
 * --exact`): always the eigendecomposition. */
void reduced_krylov_roots(Reduced *r, bool on);
/* Roots applied since reduced_new, their Lanczos steps, and how many fell
 * back to the eigendecomposition. */
void reduced_root_stats(const Reduced *r, long *roots, long *steps, long *fallbacks);
const char *reduced_error(const Reduced *r);
/* y = B ŷ of quantity q into `y` (n entries). */
void reduced_lift(const Reduced *r, int q, double *y);
/* Y = Ŷ Bᵀ for `samples` coordinate vectors of quantity q: `coords`
 * (samples x m, row-major) lifted into `y` (samples x n), the basis read
 * once for all of them. One sample is reduced_lift's dgemv. */
void reduced_lift_many(const Model *m, int q, long samples, const double *coords, double *y);

/* ---------------------------------------------------------------- derivatives (reduced_deriv.c)
 *
 * Derivatives of the reduced evaluator in reduced coordinates (DESIGN §17),
 * at the coordinates `r` holds after reduced_eval (evaluate first): the
 * operators, factors and chains that evaluation kept (reduced_kept) are used,
 * or recomputed when any coordinate has changed since. Blocks of `nd` directions travel together,
 * every block m_q x nd row-major (ReducedSeeds).
 *   reduced_jvp: out (m_out x nd) = Σ_i ∂ŷ_out/∂x̂_{q[i]} · block[i] (m x nd each);
 *   reduced_vjp: out (m_in x nd)  = Σ_i (∂ŷ_{q[i]}/∂x̂_in)ᵀ · block[i];
 *   reduced_jacobian: J (m_out x m_in, row-major), one forward sweep with the
 *   identity as seed when m_in <= m_out, else one reverse sweep.
 * Seeds of jvp are inputs (a stage seeded is not recomputed); `in_q` of vjp
 * is an input. A stage reading a dependent extern's learned map is refused.
 * 0, or -1 with `err` naming the stage (a singular operator, a root at a
 * zero eigenvalue, out of memory); `out` is then undefined. */
typedef struct ReducedSeeds {
  int n;                      /* seeded quantities */
  const int *q;               /* each one's quantity */
  const double *const *block; /* each one's block, m_q x nd */
  long nd;                    /* directions carried */
  bool identity;              /* block[0] is the identity (nd = its m): J is added, not J·I computed */
} ReducedSeeds;
int reduced_jvp(Reduced *r, const ReducedSeeds *seeds, int out_q, double *out, long sample, Err *err);
int reduced_vjp(Reduced *r, const ReducedSeeds *seeds, int in_q, double *out, long sample, Err *err);
int reduced_jacobian(Reduced *r, int out_q, int in_q, double *J, long sample, Err *err);
/* The local partial of stage number `stage` alone: out (m_stage x nd) = ∂ŷ_stage/∂x̂_in · seed,
 * `in` one seed (in_q = in->q[0], seed = in->block[0], m_in x nd), every other quantity the stage
 * reads held fixed (the chain of error estimates, estimate.c, takes each stage's own sensitivity
 * to each input). 0, or -1 with `err`. */
int reduced_stage_jvp(Reduced *r, int stage, const ReducedSeeds *in, double *out, long sample, Err *err);
/* Its transpose: out (m_in x nd) = (∂ŷ_stage/∂x̂_in)ᵀ · seed, in_q = in->q[0] the input, seed =
 * in->block[0] on the stage's quantity (m_stage x nd); one reverse pass through the stage alone, fewer
 * directions than the forward one when the stage's basis is smaller than its input's. 0, or -1 with `err`. */
int reduced_stage_vjp(Reduced *r, int stage, const ReducedSeeds *in, double *out, long sample, Err *err);
/* What an evaluation keeps of each operator of a Galerkin term for the derivatives, so that
 * they neither contract its tensors nor factor it again: M̂ as assembled (row-major n x n),
 * the factor of an inverse power (Cholesky's L of M̂, or the LU factors of M̂ᵀ with piv,
 * column-major: apply_inverse's), and the chain of the power's steps (its operand, then each
 * step's result: (steps + 1) x n, steps |p| for integer powers, 1 for a root). */
typedef struct ReducedKept {
  double *M, *factor, *chain;
  int *piv;               /* lapack_int */
  bool chol;
} ReducedKept;
/* Operator `op` of term `term` of stage number `stage` as the last reduced_eval left it, or
 * NULL when that evaluation failed, evaluated no such operator (an interpolated stage), or
 * any quantity's coordinates have changed since (the derivatives then recompute it). */
const ReducedKept *reduced_kept(const Reduced *r, int stage, int term, int op);
/* With `on`, reduced_eval also keeps the local Jacobian J (rows x m) of its first input of
 * the tensors T of reduced_keeps_local_jacobian, from the evaluation's read of the tensor:
 *   one input taken twice (an operator's 1 + u²): J = Ŝ x̂, Ŝ the rows of T unpacked to
 *   symmetric matrices with doubled diagonals (reduced_deriv_square), and its value
 *   T·(x̂ ⊗ x̂) = ½ J x̂ (Ŝ holds twice T's entries: the evaluation costs more, the derivative
 *   that follows less);
 *   two inputs, the first of degree 1 (k ⊗ u): J = T·z_2, the contraction's first step.
 * For Jacobians and Newton's iterations (compiler/api/reduced_derivatives.c), off for
 * evaluations alone. */
void reduced_keep_local_jacobians(Reduced *r, bool on);
bool reduced_keeps_local_jacobian(const RTensor *t);
/* The local Jacobian of T's first input as the last reduced_eval kept it, or NULL (not kept,
 * or any coordinate changed since: reduced_kept's rule). */
const double *reduced_kept_local_jacobian(const Reduced *r, const RTensor *t);
/* Ŝ of a tensor of one input taken twice (rows·m x m), made on first use and kept in the
 * evaluator's derivative cache; NULL out of memory. */
const double *reduced_deriv_square(Reduced *r, const RTensor *t);
/* What the derivatives keep between calls in their evaluator (reduced_deriv.c): the
 * evaluator's slot for it, and its release (reduced_free calls it). */
struct DerivCache;
struct DerivCache **reduced_deriv_cache(Reduced *r);
void reduced_deriv_cache_free(struct DerivCache *c);

/* ---------------------------------------------------------------- generated reduced code (reduced_code.c)
 *
 * The reduced evaluator as C specialized to one model (DESIGN §6): one
 * function per stage, every size a literal, contractions as loops; the
 * tensors come through NpgReducedCtx (npg_abi.h), operator powers and
 * externs call back into the runtime evaluator (reduced_apply_power,
 * reduced_eval_stage), so both agree to rounding. The model is described
 * (ReducedCode) for the emitter, backends/emit/emit_reduced.c. */

/* Write the C translation unit of `m` to `out`. 0, or -1 with `err`. */
int emit_reduced(const Model *m, FILE *out, Err *err);

/* One entry of NpgReducedCtx.t: a reduced tensor, or the projection
 * B_yᵀB_w of a named numerator whose class differs from its stage's. */
typedef struct ReducedSlot {
  const RTensor *t;
  const RTerm *proj_of;
  long rows, cols;
  const double *data;
} ReducedSlot;

/* Every tensor in NpgReducedCtx.t order: stage by stage, term by term, the
 * projection, the numerator's tensors, then each operator's. Fills `s`
 * when non-NULL; returns the count. The emitter and reduced_jit.c share it. */
long emit_reduced_slots(const Model *m, ReducedSlot *s);

/* ---------------------------------------------------------------- compiled and run (reduced_jit.c) */

/* The generated reduced evaluator of `m`, compiled (libtcc, or cc -O3 with
 * `cc`). `m` must outlive it; it holds one scratch buffer, so one
 * evaluation at a time. NULL with `err` on failure. */
typedef struct RedJit RedJit;
RedJit *reduced_jit_new(const Model *m, bool cc, Err *err);
/* Evaluate every stage on the coordinates held in `r` (a Reduced of the
 * same model: inputs set by reduced_project, results left in
 * reduced_coords), as reduced_eval does. 0, or -1 with reduced_jit_error(j). */
int reduced_jit_eval(RedJit *j, Reduced *r, long sample);
/* Stage number `stage` (Model.stages) alone, as reduced_eval_stage does. */
int reduced_jit_eval_stage(RedJit *j, Reduced *r, int stage, long sample);
void reduced_jit_free(RedJit *j);

/* The message of reduced_jit_eval's last failure. */
const char *reduced_jit_error(const RedJit *j);

/* For generated code (reduced.c): the model of `r`; v <- M̂^(p/q) v for
 * the operator `pw` names (its p/q checked against the model), M̂ given
 * (m x m) — the runtime evaluator's own factorizations and messages. */
const Model *reduced_model(const Reduced *r);
typedef struct ReducedPower {
  int stage, term, op; /* operator `op` of term `term` of stage number `stage` */
  long p, q;           /* the power asked for */
  long sample;         /* for messages (reduced_eval's) */
} ReducedPower;
int reduced_apply_power(Reduced *r, const ReducedPower *pw, const double *M, double *v);

#endif
