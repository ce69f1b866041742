/* model.h — the reduced model: its layout derived from the stage program
 * and its files (DESIGN §1, §2, §5, §7; paper §4, §8.2–§8.3). Training
 * fills it (backends/train/train.h); the reduced evaluator runs it (reduced.h).
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
#ifndef NPG_MODEL_H
#define NPG_MODEL_H

#include <stdint.h>
#include <stdio.h>

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
  double premul_seconds;    /* training's wall time pre-multiplying it (the sum over ranks included); NAN when
                               pre-multiplied out of core by streamed bases; not saved */
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
  /* the residual's table of the online estimate (estimate.h, issue 41): (est_D + 1) x est_D,
   * R (upper triangular, of the projected columns' QR) then the unprojected columns' norms
   * (owned); NULL: the term has no estimate */
  double *est_G;
  long est_D;
  double est_sigma;         /* an inverse term: min over training samples of σ_min(M)/σ_min(BᵀMB); NaN: unknown; in a
                               class with a product: NaN, or 1 when its min-θ figure is an estimate (estimate_product.c); an
                               application's (estimate_term_chains): its ratio c (in a product ‖M‖_K0/‖DᵀMB‖₂) */
  /* the min-θ lower bound (estimate.h): M(x) = M_0 + Σ x_j M_j, x input est_theta_q (est_theta_n
   * entries), every M_j symmetric positive semidefinite; est_theta_k anchors, each x̄ then λ_min(M(x̄))
   * (in a class with a product K0: the pencil's λ_min(M(x̄), K0) on the error's rows)
   * (est_theta_k x (est_theta_n + 1), owned); NULL or est_theta_k = 0: no bound */
  double *est_theta;
  int est_theta_q, est_theta_k;
  long est_theta_n;
  /* a named numerator's error e_w enters the term's figure as est_carry · e_w when the term's class or
   * the numerator's has a product (the norms differ: estimate_product.c); 0: not measured (no
   * estimate then), and unused when neither class has a product (the factor is 1) */
  double est_carry;
  /* a chained term (estimate_term_chains): for several operators, per operator, c = the largest ‖M‖/‖BᵀMB‖
   * (an application; in a class with a product ‖M‖_K0/‖DᵀMB‖₂) or the smallest σ_min(M)/σ_min(BᵀMB) (an
   * inverse, a root) at training samples, then the ‖M‖ ratio of each root of power above 1; NaN: unknown
   * (estimate_term_ratios entries, owned; NULL when there are none: a term of one operator's c is est_sigma) */
  double *est_opc;
} RTerm;

/* Every tensor x of term `rt`: its numerator's, then each operator's in
 * order of application. */
#define RTERM_FOR_TENSORS(rt, x)                                                     \
  for (int k_ = -1; k_ < (rt)->nops; k_++)                                           \
    for (int g_ = 0; g_ < (k_ < 0 ? (rt)->nnum : (rt)->ops[k_].ntensors); g_++)      \
      for (RTensor *x = k_ < 0 ? &(rt)->num[g_] : &(rt)->ops[k_].t[g_]; x; x = NULL)
/* Visit every reduced tensor of a model. */
#define FOR_TENSORS(m, x)                                           \
  for (int i_ = 0; i_ < (m)->nstages; i_++)                         \
    for (int t_ = 0; t_ < (m)->stages[i_].nterms; t_++)             \
      for (RTerm *rt_ = &(m)->stages[i_].terms[t_]; rt_; rt_ = NULL) \
        RTERM_FOR_TENSORS(rt_, x)

typedef struct RStage {
  const Stage *st;
  int q;                    /* index in Program.quantities */
  int nterms;
  RTerm *terms;
  struct RInterp *interp;   /* reduced by interpolation (interp.h, DESIGN §12), or NULL: Galerkin (owned) */
  struct RInterp *check;    /* a Galerkin stage of diagonal operators: its estimate's check entries
                               (interp_check, over all n entries), or NULL (owned) */
  double choice_err[2];     /* training's choice, when made (not saved): the output error on the validation
                               samples by Galerkin and by interpolation */
  const char *choice_reason; /* a static string, or NULL: no choice measured */
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
  /* a streamed class's quantity (RClass.streamed): its projection floor ‖y − BBᵀy‖/‖y‖, L2 and L∞,
   * the mean over the training samples, measured by training while the basis existed (verify
   * reports it in place of the held-out floor it can no longer measure) */
  double floor_l2, floor_linf;
} RMember;

typedef struct RClass {
  const BasisClass *bc;
  char *label;              /* "{b,e}" */
  long n;                   /* full size (entries of every member) */
  long m;                   /* basis size */
  double *B;                /* n x m, row-major, orthonormal columns (owned); with a product
                               (`product`) K0-orthonormal: BᵀK0B = I */
  const Sym *product;        /* the op whose inner product B is orthonormal in (`basis u: product K0`,
                               --basis u:product=K0; the manifest's `product C K0`), or NULL */
  double *D;                /* with a product: K0 B, n x m row-major (owned), so the coordinates
                               of a value x are Dᵀx (its K0-projection); NULL otherwise */
  double *R;                /* training only, with a product: B (BᵀB)⁻¹, n x m row-major (owned; model_term_coords) */
  double k0_norm1;          /* with a product: ‖K0‖₁ ≥ λ_max(K0) (Gershgorin, K0 symmetric), so an input set in
                               full has ‖x − B x̂‖_K0 ≤ √k0_norm1 ‖x − B x̂‖₂ (npg_reduced_set); the manifest's
                               `productnorm C v`; 0: not stored (a model trained before it) */
  size_t B_mapped;          /* when non-zero, B is a read-only mapping of that many bytes of an
                               unnamed file (out-of-core training), unmapped instead of freed */
  bool streamed;            /* the basis is not kept (B NULL, m its size when trained): model_class_streamable */
  bool floors_known;        /* training: its members' floor_l2/floor_linf already measured (out of core) */
  /* an extern's class kept as coefficients of its training values instead of a basis (issue 30,
   * model_class_by_coefficients; streamed is set too): B = X C for X the n x S matrix of the
   * extern's S training values in training order, so a value v has the coordinates
   * Bᵀv = Cᵀ(Xᵀv) from its inner products with them (npg_trainer_dots). C: S x m row-major
   * (owned), NULL otherwise. coef_S > 0 with C NULL: training, out of core, is to form it. */
  double *coef;
  long coef_S;
  double *train_coords;     /* training only: the S training values' coordinates Bᵀx_k, S x m
                               row-major (owned), for the extern's learned map (B is never whole) */
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
  char *greedy;             /* greedy training's record, the manifest's `greedy` line without its key
                               (owned; NULL: not trained greedily) */
  double **in_range;        /* per quantity: an input's training range, 2 x m (each reduced coordinate's min,
                               then max; estimate.h), or NULL: not recorded */
  double phase_seconds[4];  /* training's wall time: snapshots, bases, pre-multiplication, externs (not saved) */
  double phase_cpu[4];      /* the same phases' CPU time, this process's threads (not saved) */
  char *param_hashes;       /* "tri=<hex> rho=<hex>": what DATA/ held at training; NULL: none recorded */
  char choice_failure[600]; /* training's choice: why the chosen reduction failed on a validation sample ("": it
                               did not, or no choice was made; not saved) */
  long self_check_sample;   /* training's own check: a training sample the reduced model failed on, or -1 */
  char self_check_failure[600]; /* and why ("": none failed; not saved) */
} Model;

/* ---------------------------------------------------------------- layout (model.c) */

/* The model's structure for `prog` (no numbers yet). NULL on allocation failure. */
Model *model_layout(Program *prog, const long *dims, Err *err);
void model_free(Model *m);
/* Once the classes' products are known (training's --basis NAME:product=, a model's product lines): a
 * term applying an operator to a named numerator of its own class, orthonormal in a product K0, gets the
 * projection BᵀB (RTerm.proj_name; the numerator's coordinates are BᵀK0w, its Galerkin right-hand side
 * Bᵀw = BᵀB ŵ). -1 with `err` out of memory. */
int model_named_projections(Model *m, Err *err);
/* Sizes of tensors once class sizes are known (rows, cols, in_len). */
void model_size_tensors(Model *m);
/* Bytes of every reduced tensor, basis, extern table. */
size_t model_bytes(const Model *m, size_t *tensor_bytes);
/* Streamed bases (issue 30). A class's basis is needed after training
 * when the reduced evaluator or the API reads it at run time: the class of
 * an input (npg_reduced_set projects it), of an output (npg_reduced_lift),
 * of an extern (npg_reduced_given_externs then npg_reduced_set projects
 * it), of the stage applying an `output op` (npg_reduced_op's rows and
 * columns are in its basis), of an interpolated stage or of a quantity one
 * reads (interp.c lifts rows of those bases). A class is streamed — its
 * basis used during training and then dropped, not stored in the model —
 * when it is not needed, some member's rows run over two or more dims (a
 * pair quantity: F² rows for F faces, the bases that dominate a model's
 * size; a class of single-dim rows costs little to keep, and keeping it
 * leaves lift, verify and the model files of such programs as they were),
 * and the user did not name it (--keep-bases). Lifting a quantity of a
 * streamed class is refused, naming --keep-bases. */
bool model_class_needed(const Model *m, int c);
/* Whether class `c` is not needed and has a member over two or more dims. */
bool model_class_streamable(const Model *m, int c);
/* Whether class `c` may be kept as coefficients of its training values (RClass.coef): its one
 * member an extern over two or more dims (radiosity's visibility v, F² rows), whose basis
 * nothing but npg_reduced_given_externs reads. */
bool model_class_by_coefficients(const Model *m, int c);
/* The projection floor of one value `full` (n = rc->n entries) in class
 * `rc`'s basis: out[0] = ‖y − BBᵀy‖₂/‖y‖₂, out[1] = ‖y − BBᵀy‖∞/‖y‖∞
 * (sums of squares taken of values over the largest |entry|, so any
 * scale gives the same ratios); `proj` holds rc->m, `y` rc->n doubles. */
void model_projection_floor(const RClass *rc, const double *full, double *proj, double *y, double out[2]);
/* What projects a value onto class rc's basis, coordinates = Pᵀx: D with a
 * product (BᵀK0 = Dᵀ), else B. */
static inline const double *model_projector(const RClass *rc) { return rc->D ? rc->D : rc->B; }
/* Whether term rt's numerator (k = -1) or operator k reduces to coordinates, whose lift B ŷ approximates its
 * value (a projection, an operator applied to a positive integer power whose result no solve takes next), rather
 * than to a Galerkin right-hand side Bᵀg (what an inverse or a root after it takes). Without a product both are
 * Bᵀ; with a product K0 coordinates are the K0-projection's, Dᵀ = BᵀK0, so that an application reduces to
 * (DᵀMB)^p Dᵀw, the K0-orthogonal projection of each step (issue 41; BᵀMB BᵀB ŵ was no approximation of M w there:
 * BᵀB ≠ I). */
static inline bool model_term_projects(const RTerm *rt, int k) {
  const OpPow *next = k + 1 < rt->nops ? rt->ops[k + 1].op : NULL;
  bool applied = k < 0 || (rt->ops[k].op->kind == OPK_DECL && rt->ops[k].op->q == 1 && rt->ops[k].op->p > 0);
  return applied && (!next || (next->kind == OPK_DECL && next->q == 1 && next->p > 0));
}
/* The power p of a declared operator to an integer power (p/1), else 0. */
static inline long model_op_power(const OpPow *o) { return o->kind == OPK_DECL && o->q == 1 ? o->p : 0; }
/* Whether term rt's numerator (k = -1) or operator k passes coordinates where Galerkin's B rows would pass a
 * right-hand side Bᵀg (issue 41): an operator applied to a power ≥ 2 whose result a solve takes next, a solve (power
 * -1) right after one or after another solve, an inverse power ≤ -2 (each of its solves after a solve), and the
 * numerator or an operator applied once that such a power takes. In a class with a product their rows are
 * R = B (BᵀB)⁻¹ (RClass.R): the power's steps are least-squares coordinates (RᵀMB)^p ŵ, and a solve
 * (RᵀKB)⁻¹ = (BᵀKB)⁻¹ BᵀB takes coordinates ĉ as Galerkin's right-hand side Bᵀ(B ĉ), so K^-p takes Rᵀg and solves
 * BᵀKB ẑ = Bᵀg, then BᵀKB ŷ = BᵀB ẑ, ... With B rows (BᵀMB)² ŵ, (BᵀKB)⁻¹ v̂ and (BᵀKB)^-p Bᵀg were no
 * approximation there (BᵀB ≠ I); without a product R = B. */
static inline bool model_term_coords(const RTerm *rt, int k) {
  if (k < -1 || k >= rt->nops) return false;
  long next = k + 1 < rt->nops ? model_op_power(rt->ops[k + 1].op) : 0;
  if (k < 0) return next <= -2;
  long p = model_op_power(rt->ops[k].op), prev = k > 0 ? model_op_power(rt->ops[k - 1].op) : 0;
  if (p >= 1) return p >= 2 ? next <= -1 : next <= -2;
  return p <= -2 || (p == -1 && (prev <= -1 || prev >= 2));
}
/* The rows that pre-multiply the output axis of term rt's numerator (k = -1) or operator k in class rc:
 * model_projector where it projects (model_term_projects), RClass.R in a product where it passes coordinates
 * (model_term_coords), else B. */
static inline const double *model_term_rows(const RClass *rc, const RTerm *rt, int k) {
  return model_term_projects(rt, k) ? model_projector(rc) : rc->R && model_term_coords(rt, k) ? rc->R : rc->B;
}
/* Whether term rt holds an inverse power ≤ -2 (its rows changed with issue 41's model_term_coords: the manifest's
 * `productpowers C` line tells a model of such a term in a product trained after). */
static inline bool model_term_inverse_power(const RTerm *rt) {
  for (int k = 0; k < rt->nops; k++)
    if (model_op_power(rt->ops[k].op) <= -2) return true;
  return false;
}
/* What pre-multiplies the output axis of term rt's tensor x in class rc: model_term_rows of the part of the term x
 * belongs to. */
const double *model_tensor_rows(const RClass *rc, const RTerm *rt, const RTensor *x);
/* FNV-1a 64 of the program's source files (main file and used modules). */
uint64_t model_program_hash(const Program *prog);

/* ---------------------------------------------------------------- packed symmetric powers (sym.c) */

/* Packed symmetric powers: C(m + k - 1, k). */
long sym_len(long m, int k);
/* z[α] = Π_l x[α_l] over sorted multi-indices α (lexicographic). */
void sym_power(long m, int k, const double *x, double *z);
/* v[α] = Σ over distinct arrangements π of α of Π_l row_l[π_l]: the packed
 * symmetrization of row_1 ⊗ … ⊗ row_k (rows of one basis at k offsets). */
void sym_outer(long m, int k, const double *const *rows, double *v);
/* The places among the packed coordinates of m (k-fold) of those whose
 * every index is below m2 <= m, in their order: map[0..sym_len(m2, k)).
 * The coordinates of the first m2 vectors of a basis of m (model_truncate). */
void sym_leading(long m, int k, long m2, long *map);

/* ---------------------------------------------------------------- smaller sizes (truncate.c) */

/* The model `src` at smaller basis sizes, without retraining (issue 41):
 * class c keeps the first sizes[c] vectors of its basis (sizes[c] < 0:
 * all), and every pre-multiplied tensor, projection and extern table its
 * leading block in those coordinates — what training at those sizes would
 * give where the class's first vectors are what a smaller cap keeps (one
 * member: its PCA in order, centered [μ, U_c] too). An interpolated stage's
 * own class keeps its size (its fit (PB)⁺ is of the whole basis; the
 * classes it reads may shrink). A new model (src unchanged), or NULL with
 * `err` naming the class: a size above the class's, or out of memory. */
Model *model_truncate(const Model *src, const long *sizes, Err *err);
/* Class sizes from "NAME=N,NAME=N" (`npgc eval --sizes`): NAME a class as
 * `npgc check` names it (m_u), m_<member>, its label {u,v}, or a member;
 * sizes[c] set for each named class, -1 for the others. 0, or -1 with
 * `err` naming the entry (no such class, N not a whole number ≥ 0). */
int model_parse_sizes(const Model *m, const char *spec, long *sizes, Err *err);

/* ---------------------------------------------------------------- files (model.c) */

int model_save(const Model *m, const char *dir, Err *err);
/* Every member's singular values as DIR/spectrum_<member>.npy and .csv
 * (k, singular value, energy lost keeping the first k), DIR created if
 * needed. The same files model_save lists in MODEL/. All or none: every
 * file is written to a temporary name and renamed when all are whole, so a
 * failure (a full disk) leaves DIR as it was, with `err` naming the file. */
int model_write_spectra(const Model *m, const char *dir, Err *err);
/* Load MODEL/ for `prog` (hash checked), every array checked. A manifest
 * without one of the lines model_save writes (dims, samples, params, bytes,
 * a class line per class, a member line per member) is refused, naming it:
 * param_hashes is then never NULL ("" when none were recorded). */
Model *model_load(Program *prog, const char *dir, Err *err);

#endif
