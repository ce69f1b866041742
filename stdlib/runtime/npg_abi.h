/* npg_abi.h — the one interface between libnpg and generated C.
 *
 * This file is compiled into libnpg AND embedded verbatim (by CMake, as a
 * string) at the top of every generated C file, so the two can never
 * disagree. It includes no system header: libtcc compiles generated code
 * in memory without them, and the libm functions generated code uses are
 * declared here with their standard prototypes (the host resolves them).
 *
 * Data layout: every array is C order over its dim axes, then its static
 * axes: q[i, j, c] of q : real[F, F, 3] is q[(i*F + j)*3 + c].
 */
#ifndef NPG_ABI_H
#define NPG_ABI_H

#define NPG_ABI_VERSION 3

typedef long npg_idx;

double sqrt(double);
double cbrt(double);
double pow(double, double);
double exp(double);
double log(double);
double sin(double);
double cos(double);
double tan(double);
double atan(double);
double atan2(double, double);
double tanh(double);
double fabs(double);
double floor(double);
double fmin(double, double);
double fmax(double, double);

typedef struct NpgRt NpgRt;

/* The elementwise operation of a row kernel (NpgRt.row_*). */
typedef enum NpgRowOp {
  NPG_ROW_ADD, /* x + y */
  NPG_ROW_SUB, /* x - y */
  NPG_ROW_MUL, /* x * y */
  NPG_ROW_DIV, /* x / y */
  NPG_ROW_NEG, /* -x (row_unary) */
  NPG_ROW_COPY /* x (row_unary) */
} NpgRowOp;

/* One evaluation context: bound data and where values go. */
typedef struct NpgCtx {
  const npg_idx *dims;          /* size of every dim, in program order */
  const double *const *params;  /* real params, in program order (NULL for int ones) */
  const npg_idx *const *iparams; /* int params, in program order (NULL for real ones) */
  double *const *q;             /* every quantity with a basis, in program order:
                                   inputs and externs are read, stages written */
  const NpgRt *rt;
  long sample;                  /* sample number, for messages */
  void *host;                   /* the runtime's own state */
} NpgCtx;

/* A tensor entry sink for the tensor builder: entries of one tensor arrive
 * in output-major order (non-decreasing `row`). `col` is the column of an
 * operator tensor, -1 for a contraction. `in` holds `nin` flat offsets into
 * the contracted quantities, in the tensor's input order. With nparts > 1
 * the builder enumerates only the rows ≡ part (mod nparts) — one MPI rank's
 * share, the others' never visited; nparts 0 or 1 (a sink initialized
 * with its first two members only): every row. */
typedef struct NpgSink {
  void *user;
  int (*entry)(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef);
  long part, nparts;
} NpgSink;

struct NpgRt {
  /* y <- M^(p/q) y for dense row-major n x n M (overwritten). Negative
   * integer powers by LU (info checked); fractional powers of a symmetric
   * positive semidefinite M by eigendecomposition. Non-zero on failure,
   * after recording a message naming `stage` and `op`. */
  int (*op_power)(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, long p, long q, double *y);
  /* Scratch memory for one evaluation (zeroed); NULL after recording an error. */
  double *(*scratch)(const NpgCtx *c, npg_idx count);
  void (*release)(const NpgCtx *c, double *p);
  /* Bind-time check of a gather: `value` indexes dim `dim`; `param` is the
   * param read (or -1 when the index is a compound expression) at entry
   * `entry[0..nentry)`; `stage` is where it is used, `at` ("file:line:col")
   * and `excerpt` (the source line and a caret under the column) the use
   * in the program. Records the message. */
  void (*gather_error)(const NpgCtx *c, const char *stage, const char *at, const char *excerpt, int param,
                       int nentry, const npg_idx *entry, npg_idx value, int dim);
  /* Row kernels, for libtcc code (which neither vectorizes nor keeps
   * values in registers): out[k] = x[k] op y[k], x[k] op s, s op x[k],
   * op x[k], or s, for 0 <= k < n. Each does exactly the IEEE operation
   * of the scalar C expression (no contraction into fused multiply-add),
   * so results are bit-identical to the loop they replace. `out` never
   * overlaps an input. */
  void (*row_vv)(npg_idx n, NpgRowOp op, const double *x, const double *y, double *out);
  void (*row_vs)(npg_idx n, NpgRowOp op, const double *x, double s, double *out);
  void (*row_sv)(npg_idx n, NpgRowOp op, double s, const double *y, double *out);
  void (*row_unary)(npg_idx n, NpgRowOp op, const double *x, double *out);
  void (*row_fill)(npg_idx n, double s, double *out);
};

/* Entry points of generated code (prefixed when several programs share a
 * process). Each returns 0, or -1 after the runtime recorded an error. */
typedef int (*NpgStageFn)(const NpgCtx *c);
/* Step `step` of the full evaluator's plan (backends/emit/emit.h FullPlan):
 * with nbox < 0 the whole step, else its members only over the boxes
 * box[b * 2 * nivars ...] (lo per index variable, then hi; half-open). */
typedef int (*NpgStepFn)(const NpgCtx *c, int step, int nbox, const npg_idx *box);
typedef int (*NpgBuildFn)(const NpgCtx *c, NpgSink *sink);

/* ---------------------------------------------------------------- the reduced evaluator
 *
 * `npgc emit --reduced MODEL/` (backends/model/emit_reduced.c) writes C for one
 * trained model, every size a literal. The reduced tensors are not in the
 * code (they can be megabytes): the host passes them, with the coordinates
 * and scratch memory, in an NpgReducedCtx. The generated file says what it
 * expects: P_npg_reduced_coords = {number of quantities, m of each},
 * P_npg_reduced_tensors = {number of tensors, then the element count (rows
 * × cols) of each, in the order of NpgReducedCtx.t; their rows and columns
 * are listed in a comment at the file's top}, and
 * P_npg_reduced_work, the doubles of scratch. P is the program's file stem
 * (every external symbol of generated code carries it, so two programs'
 * code links into one binary: emit_symbol in backends/emit/emit.h). Every reduced vector and
 * tensor is dense, row-major (backends/model/model.h). */
typedef struct NpgReducedCtx NpgReducedCtx;

typedef struct NpgReducedRt {
  /* v <- M^(p/q) v, M (m x m, destroyed) the reduced operator number `op`
   * of term `term` of stage number `stage` (0-based, the model's stage
   * order, externs included). Negative integer powers by Cholesky or LU,
   * fractional ones by eigendecomposition. Non-zero on failure, after the
   * host recorded a message. */
  int (*op_power)(const NpgReducedCtx *c, int stage, int term, int op, npg_idx m, double *M, long p, long q,
                  double *v);
  /* Write the coordinates of stage number `stage` that the generated code
   * does not compute: an extern (its learned map, paper §8.3) or an
   * interpolated stage (its formula at the selected entries, fitted: DESIGN
   * §12). Non-zero on failure, as op_power. */
  int (*learned)(const NpgReducedCtx *c, int stage);
} NpgReducedRt;

struct NpgReducedCtx {
  double *const *x;             /* reduced coordinates of every quantity, program order:
                                   inputs read, stages and externs written */
  const double *const *t;       /* every reduced tensor, in the generated file's order */
  double *work;                 /* P_npg_reduced_work doubles of scratch */
  const NpgReducedRt *rt;
  long sample;                  /* sample number, for messages */
  void *host;                   /* the runtime's own state */
};

/* The entry points of generated reduced code: P_npg_reduced, every stage in
 * order; P_npg_reduced_stage, stage number `stage` alone. Each returns 0, or
 * -1 after the host recorded an error (or for a stage number out of range). */
typedef int (*NpgReducedFn)(const NpgReducedCtx *c);
typedef int (*NpgReducedStageFn)(const NpgReducedCtx *c, int stage);

#endif
