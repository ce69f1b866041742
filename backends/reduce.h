/* reduce.h — the reduced model: its layout derived from the stage program,
 * training (snapshots, PCA, pre-multiplication), the reduced evaluator, and
 * its files (DESIGN §1, §2, §5, §7; paper §4, §8.2–§8.3).
 *
 * A model is fully determined by the program (whose hash it records) plus
 * arrays: one orthonormal basis per basis class and one pre-multiplied
 * tensor per tensor group of every term. The layout — which tensor belongs
 * to which term, its axes and sizes — is recomputed from the program when a
 * model is loaded; the files hold only numbers and the manifest.
 *
 * Reduced tensors (RTensor) are dense, row-major rows x cols:
 *   rows: the reduced output coordinates — RT_NUM m (a numerator, in the
 *         result's basis), RT_DIAG m(m+1)/2 (a diagonal operator reduced as
 *         BᵀMB, symmetric: upper triangle packed row by row), RT_DECL m·m (a
 *         declared operator BᵀMB);
 *   cols: the product of one axis per distinct input; an input repeated k
 *         times (x ⊗ x) gets one packed symmetric axis of C(m+k-1, k)
 *         coordinates (sorted multi-indices in lexicographic order), so the
 *         tensor is stored once, not k! times.
 */
#ifndef NPG_REDUCE_H
#define NPG_REDUCE_H

#include <stdint.h>

#include "full.h"
#include "ir.h"

#define RT_MAX_IN 16

typedef enum RtKind {
  RT_NUM,   /* numerator tensor: rows = m_y */
  RT_DIAG,  /* diagonal operator: rows = m_y (m_y + 1) / 2, packed symmetric */
  RT_DECL,  /* declared operator: rows = m_y * m_y */
} RtKind;

typedef struct RTensor {
  RtKind kind;
  const TensorGroup *group;
  char *name;               /* file stem in MODEL/ */
  char *builder;            /* generated builder function */
  int nin;                  /* distinct inputs */
  int in_q[RT_MAX_IN];      /* their index in Program.quantities */
  int in_mult[RT_MAX_IN];   /* multiplicity: > 1 is a packed symmetric axis */
  long in_len[RT_MAX_IN];   /* C(m + k - 1, k) */
  long rows, cols;
  double *data;             /* rows x cols, row-major (owned) */
} RTensor;

typedef struct ROp {
  const OpPow *op;
  int ntensors;
  RTensor *t;
  bool spd;                 /* every training diagonal > 0: BᵀMB is SPD (Cholesky) */
} ROp;

typedef struct RTerm {
  const Term *term;
  int nnum;
  RTensor *num;             /* unnamed numerator: its tensors */
  int named_q;              /* named numerator: its quantity, else -1 */
  double *proj;             /* B_yᵀ B_w when w's class differs from y's (m_y x m_w), else NULL */
  char *proj_name;
  int nops;
  ROp *ops;
} RTerm;

/* Every tensor x of term `rt`: its numerator's, then each operator's in
 * order of application. */
#define RTERM_FOR_TENSORS(rt, x)                                                     \
  for (int k_ = -1; k_ < (rt)->nops; k_++)                                           \
    for (int g_ = 0; g_ < (k_ < 0 ? (rt)->nnum : (rt)->ops[k_].ntensors); g_++)      \
      for (RTensor *x = k_ < 0 ? &(rt)->num[g_] : &(rt)->ops[k_].t[g_]; x; x = NULL)

typedef struct RStage {
  const Stage *st;
  int q;                    /* index in Program.quantities */
  int nterms;
  RTerm *terms;
} RStage;

/* One member's contribution to a class basis: a quantity or an unnamed
 * numerator (joiner). */
typedef struct RMember {
  char *name;               /* "s", or "h.num1" for the numerator of term 1 of h */
  int q;                    /* quantity, or -1 for a joiner */
  const Joiner *joiner;
  int cap;                  /* basis cap */
  double energy;            /* energy fraction */
  bool center;              /* centered truncation: the mean kept, the rest by the centered energy */
  int kept;                 /* basis vectors kept (the mean included when centered) */
  double captured;          /* energy fraction captured: 1 − lost */
  double lost;              /* energy fraction lost (of the centered energy when centered) */
  double *sv;               /* singular values of its snapshots (centered when centered), descending (owned) */
  long nsv;
} RMember;

typedef struct RClass {
  const BasisClass *bc;
  char *label;              /* "{b,e}" */
  long n;                   /* full size (entries of every member) */
  long m;                   /* basis size */
  double *B;                /* n x m, row-major, orthonormal columns (owned) */
  int nmembers;
  RMember *members;
} RClass;

/* The learned map of an extern (paper §8.3). */
typedef struct RExtern {
  int q;                    /* the extern's quantity */
  int nin;
  int in_q[RT_MAX_IN];      /* the quantities it is `of` */
  long d;                   /* Σ m of its inputs */
  long S;                   /* training samples */
  double *X;                /* S x d: the samples' reduced inputs (owned) */
  double *Z;                /* S x m: the samples' reduced extern values (owned) */
} RExtern;

typedef struct Model {
  Program *prog;
  uint64_t program_hash;
  int ndims;
  long *dims;               /* bound sizes, program order */
  int nclasses;
  RClass *classes;
  int nq;
  int *qclass;              /* class of every quantity */
  int nstages;
  RStage *stages;           /* every stage in evaluation order (externs too) */
  int nexterns;
  RExtern *externs;
  long samples;             /* training samples */
  char *param_hashes;       /* "tri=<hex> rho=<hex>": what DATA/ held at training */
} Model;

/* ---------------------------------------------------------------- layout (reduced.c) */

/* The model's structure for `prog` (no numbers yet). NULL on allocation failure. */
Model *model_layout(Program *prog, const long *dims, char *err, size_t errlen);
void model_free(Model *m);
/* Sizes of tensors once class sizes are known (rows, cols, in_len). */
void model_size_tensors(Model *m);
/* Bytes of every reduced tensor, basis, extern table. */
size_t model_bytes(const Model *m, size_t *tensor_bytes);
/* FNV-1a 64 of the program's source files (main file and used modules). */
uint64_t model_program_hash(const Program *prog);

/* Packed symmetric powers: C(m + k - 1, k). */
long sym_len(long m, int k);
/* z[α] = Π_l x[α_l] over sorted multi-indices α (lexicographic). */
void sym_power(long m, int k, const double *x, double *z);
/* v[α] = Σ over distinct arrangements π of α of Π_l row_l[π_l]: the packed
 * symmetrization of row_1 ⊗ … ⊗ row_k (rows of one basis at k offsets). */
void sym_outer(long m, int k, const double *const *rows, double *v);

/* ---------------------------------------------------------------- training (train.c) */

typedef struct TrainOptions {
  int cap;                  /* default cap per member (60) */
  double energy;            /* default energy fraction per member (0.999) */
  bool joint;               /* --merge joint */
  bool uncentered;          /* --center off: the paper's uncentered truncation (default: centered, DESIGN §5) */
  bool full_rank;           /* complete every basis to its class's full dimension (convergence tests) */
  size_t mem;               /* memory budget for snapshots, bytes */
  bool progress;            /* progress bars on stderr */
  /* overrides from the command line (--basis NAME:cap=N,energy=E,center=on|off), NAME a
   * quantity, a class as `npgc check` names it (m_f), a numerator (f.num1) or '*';
   * the more specific wins ('*' < class < member); an unknown NAME fails training */
  int noverride;
  const char **override_name;
  int *override_cap;
  double *override_energy;
  int *override_center;     /* 1 on, 0 off, -1 not given (may be NULL: not given) */
} TrainOptions;

/* The source of samples: sets every input and extern of sample k. */
typedef struct SampleSource {
  long count;
  void *user;
  int (*set)(void *user, NpgFull *f, long k);
} SampleSource;

/* Train: snapshots of every stage and joining numerator on every sample,
 * one basis per class, every tensor pre-multiplied, externs fitted. `f` is
 * bound to the training params. NULL with `err` on failure. */
Model *train_model(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen);

/* Training for a search over basis sizes (npgc tune): the snapshots (in
 * memory) and every member's ordered basis at its cap (pca_basis: for a
 * centered member [μ, U_c,1, …]) once; then models whose members keep the
 * first cap[c] vectors of theirs — the basis that cap would give at energy
 * 1 — merged and re-pre-multiplied, with no new snapshot or SVD. */
typedef struct TrainSet TrainSet;
/* `opt` as for train_model (its energy should be 1: the caps decide); NULL
 * with `err`. `f` and `src` must outlive the set. */
TrainSet *train_set_new(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                        size_t errlen);
int train_set_classes(const TrainSet *ts);
/* The most vectors a member of class `c` has: caps above it change nothing. */
int train_set_max_cap(const TrainSet *ts, int c);
/* The model whose members of class c keep min(cap[c], what they have)
 * vectors. NULL with `err`. */
Model *train_set_model(TrainSet *ts, const int *cap, char *err, size_t errlen);
void train_set_free(TrainSet *ts);

/* ---------------------------------------------------------------- basis sizes by error (tune.c) */

typedef struct TuneTrial {
  int *cap;                 /* per class: its members' cap */
  long *m;                  /* per class: the basis size it gave */
  double cost;              /* reduced multiply-adds (ir/cost.c) */
  double err;               /* the worst output's mean relative L2 error on the validation samples */
  bool uniform;             /* one cap for every class */
} TuneTrial;

typedef struct TuneResult {
  int nclasses;
  int ntrials;
  TuneTrial *trials;        /* in the order tried */
  int chosen;               /* the trial chosen, or -1 when the tolerance cannot be met */
  int *best_cap;            /* the caps chosen (when unmet: the largest tried) */
  int limiting;             /* when unmet: the class whose projection floor is the largest */
  double limiting_floor;
  bool limiting_saturated;  /* its members have no more directions in the training samples */
} TuneResult;

/* Choose every class's cap so that every output's mean relative L2 error
 * on the samples of `valid` (evaluated in full by `f`, bound to the
 * training params) is at most `tol` at the least reduced cost, caps at most
 * `max_cap`: uniform caps 1, 2, … up to the first that meets `tol`, then
 * each class bisected down with the others fixed, the costliest first.
 * 0 (`out` filled; out->chosen < 0 when `tol` cannot be met, naming the
 * limiting class), or -1 with `err`. tune_result_free() either way. */
int tune_search(TrainSet *ts, Program *prog, NpgFull *f, const SampleSource *valid, double tol, int max_cap,
                bool progress, TuneResult *out, char *err, size_t errlen);
void tune_result_free(TuneResult *r);

/* A progress bar on stderr ("what [####    ] done/total"), when `on`. */
void progress_show(bool on, const char *what, long done, long total);

/* PCA of one member: X is n x S column-major (sample s at X + s*n). Keeps
 * at most `cap` left singular vectors, the fewest reaching `energy`.
 * Returns n x k row-major in *U (malloc'd), k, and the captured fraction. */
int pca_member(long n, long S, const double *X, int cap, double energy, double **U, int *k, double *captured,
               char *err, size_t errlen);
/* One member's basis (DESIGN §5). */
typedef struct PcaMember {
  double *U;                /* n x k row-major, orthonormal (malloc'd) */
  int k;
  double lost;              /* energy fraction lost: of the centered energy when centered */
  double *sv;               /* singular values (of X − μ1ᵀ when centered), descending, nsv (malloc'd) */
  long nsv;
} PcaMember;

/* The basis of one member, X n x S column-major: uncentered, the leading
 * left singular vectors as pca_member; `center`ed, the orthonormalization
 * of [μ, U_c,1 … U_c,r] in that order, μ the snapshots' mean (always kept),
 * U_c the left singular vectors of X − μ1ᵀ, r the fewest reaching `energy`
 * of the centered energy, at most cap − 1 (a direction dependent on the
 * previous ones dropped). 0, or -1 with `err` and nothing allocated. */
int pca_basis(long n, long S, const double *X, int cap, double energy, bool center, PcaMember *out, char *err,
              size_t errlen);
/* Gram–Schmidt (twice) of the columns of A_0 … A_{r-1} (each n x k_i,
 * row-major) in that order, dropping a column whose remainder is below 1e-8
 * of its norm: n x m row-major whose first j columns span the first
 * independent columns given. */
int pca_in_order(long n, int r, double *const *A, const int *k, double **Q, int *m, char *err, size_t errlen);
/* mu[0..n) = the mean of the S columns of X (n x S column-major). */
void pca_mean(long n, long S, const double *X, double *mu);

/* Orthonormal basis of the span of [U_1 … U_r] (each n x k_i, row-major),
 * dropping dependent directions (σ < 1e-10 σ_max): n x m row-major. */
int pca_merge(long n, int r, double *const *U, const int *k, double **B, long *m, char *err, size_t errlen);

/* Pre-multiply one tensor group: stream the builder's entries, accumulate
 * outer products of basis rows per output block, finish each block with a
 * GEMM against the output basis. `t` sized by model_size_tensors; fills
 * t->data. `flops` (optional) accumulates the useful arithmetic (that of
 * the packed products). */
int premultiply(Model *m, NpgFull *f, RTensor *t, const double *By, long ny, long my, double *flops, char *err,
                size_t errlen);
/* The same, choosing the path for a last x ⊗ x axis: unpacked (one GEMM of
 * full basis rows per batch, folded into packed form) when the group has at
 * least unpack_min_monos monomials, packed per entry otherwise. premultiply
 * uses 8; tests force each path. */
int premultiply_unpacking(Model *m, NpgFull *f, RTensor *t, const double *By, long ny, long my, int unpack_min_monos,
                          double *flops, char *err, size_t errlen);
/* Output keys (rows, or (row, col) pairs) pre-multiplied per block of t. */
long premul_keys_per_block(const RTensor *t);

/* ---------------------------------------------------------------- reduced evaluation (reduced.c) */

typedef struct Reduced Reduced;
Reduced *reduced_new(Model *m, char *err, size_t errlen);
void reduced_free(Reduced *r);
/* Reduced coordinates of quantity q (set for inputs, computed for stages). */
double *reduced_coords(Reduced *r, int q);
/* x̂ = Bᵀx for an input or extern given in full. */
void reduced_project(Reduced *r, int q, const double *x);
/* Evaluate every stage. 0, or -1 with the message in reduced_error(). */
int reduced_eval(Reduced *r, long sample);
/* Evaluate stage number i (Model.stages) from the current coordinates. */
int reduced_eval_stage(Reduced *r, int i, long sample);
/* With `on`, externs keep the coordinates the caller set (reduced_project)
 * instead of the learned map: for tests and for verifying the rest. */
void reduced_use_given_externs(Reduced *r, bool on);
const char *reduced_error(const Reduced *r);
/* y = B ŷ of quantity q into `y` (n entries). */
void reduced_lift(const Reduced *r, int q, double *y);

/* ---------------------------------------------------------------- reports (report.c) */

/* The training table: per class its sizes, per member kept / cap and the
 * energy lost; a warning for every member that hit its cap with more than
 * 1e-3 of its energy lost. */
void report_training(const Model *m, FILE *out);
/* Verification warnings from the mean relative errors `err[q]` and
 * projection floors `floor[q]` of every quantity: a stage whose error
 * exceeds 3× its floor (naming what it reads worst and the remedies), an
 * input whose floor exceeds `tol`. Returns how many were printed. */
int report_verify_warnings(const Model *m, const double *err, const double *floor, double tol, FILE *out);

/* ---------------------------------------------------------------- files (model.c) */

int model_save(const Model *m, const char *dir, char *err, size_t errlen);
/* Every member's singular values as DIR/spectrum_<member>.npy and .csv
 * (k, singular value, energy lost keeping the first k), DIR created if
 * needed. The same files model_save lists in MODEL/. */
int model_write_spectra(const Model *m, const char *dir, char *err, size_t errlen);
/* Load MODEL/ for `prog` (hash checked), every array checked. */
Model *model_load(Program *prog, const char *dir, char *err, size_t errlen);


/* ---------------------------------------------------------------- generated reduced code (emit_reduced.c)
 *
 * The reduced evaluator as C specialized to one model (DESIGN §6): one
 * function per stage, every size a literal, contractions as loops; the
 * tensors come through NpgReducedCtx (npg_abi.h), operator powers and
 * externs call back into the runtime evaluator (reduced_apply_power,
 * reduced_eval_stage), so both agree to rounding. */

/* Write the C translation unit of `m` to `out`. 0, or -1 with `err`. */
int emit_reduced(const Model *m, FILE *out, char *err, size_t errlen);

/* The generated reduced evaluator of `m`, compiled (libtcc, or cc -O3 with
 * `cc`). `m` must outlive it; it holds one scratch buffer, so one
 * evaluation at a time. NULL with `err` on failure. */
typedef struct RedJit RedJit;
RedJit *reduced_jit_new(const Model *m, bool cc, char *err, size_t errlen);
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
 * operator `op` of term `term` of stage number `stage` (p/q checked
 * against the model), M̂ given (m x m) — the runtime evaluator's own
 * factorizations and messages. */
const Model *reduced_model(const Reduced *r);
int reduced_apply_power(Reduced *r, int stage, int term, int op, long p, long q, const double *M, double *v,
                        long sample);

#endif
