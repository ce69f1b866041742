/* ir.h — the stage program: canonical form of every stage and basis classes.
 *
 * DESIGN §4. Every stage value is a sum of terms
 *
 *     y = Σ_t  M_{t,k}^{r_k} ⋯ M_{t,1}^{r_1} q_t
 *
 * where q_t is a polynomial field (one polynomial per static component of y,
 * per entry of y's index domain) whose monomials are a coefficient times
 * entries of named quantities (atoms), and each M is either a diagonal
 * operator (its diagonal again a polynomial field over y's entries) or a
 * declared `op`, whose entries are a polynomial field over the op's rows and
 * columns. ops[0] is applied first (innermost).
 *
 * Coefficients, guards and index expressions are expression Nodes over index
 * variables (Sym SYM_IVAR/SYM_SUMVAR), dims, params and numbers.
 */
#ifndef NPG_IR_H
#define NPG_IR_H

#include "ast.h"

/* An entry of a named quantity: q[idx...], dim axes then static axes. */
typedef struct Atom {
  Sym *q;
  int nidx;
  Node **idx;
} Atom;

/* A summation variable of a monomial with dim-valued bounds (sums with
 * literal bounds are unrolled during lowering). */
typedef struct SumVar {
  Sym *var;
  Node *lo, *hi;   /* inclusive */
} SumVar;

/* guard ? coef * Π atoms : 0, summed over sums. */
typedef struct Mono {
  Node *guard;     /* boolean Node, NULL = always */
  Node *coef;      /* real Node (never NULL) */
  int nsums;
  SumVar *sums;
  int natoms;
  Atom *atoms;
} Mono;

typedef struct Poly {
  int n, cap;
  Mono **m;
} Poly;

/* One polynomial per static component (flattened, row-major). */
typedef struct Field {
  int ncomp;
  Poly *comp;
} Field;

typedef enum OpKind {
  OPK_DIAG,   /* diag(field): from `/` and negative or fractional powers */
  OPK_DECL,   /* a declared `op` */
} OpKind;

/* An operator to a rational power p/q (q > 0, gcd 1, p/q not a
 * non-negative integer for OPK_DIAG). */
typedef struct OpPow {
  OpKind kind;
  Field *diag;     /* OPK_DIAG */
  Sym *op;         /* OPK_DECL */
  long p, q;
} OpPow;

/* One tensor of a term: the monomials of a polynomial field that read the
 * same multiset of quantities (DESIGN §1: "one basis per input axis"). */
typedef struct TensorGroup {
  int order;        /* output axis (+ column axis for operators) + inputs */
  int ninputs;
  Sym *inputs[16];  /* sorted multiset of quantities contracted */
  int nmono;        /* monomials over all components */
  char *nnz;        /* symbolic nonzero count, e.g. "6·F" */
  bool nnz_bound;   /* guards make nnz an upper bound */
  int nnz_degree;   /* dims multiplied in nnz's largest term: 1 for "4·N" */
  bool rows_bound;  /* an operator's: every monomial's column indices are determined by equalities
                       and its free sums run over no dim of the operator's axes, so each row holds
                       a number of entries bounded independently of the column dims (a padded row
                       table `sum(q = 0..W-1, delta(j, col[i, q]) * val[i, q])`: W per row) */
  bool symmetric;   /* repeated inputs (x ⊗ x): stored packed */
} TensorGroup;

typedef struct TensorList {
  int n;
  TensorGroup *g;
} TensorList;

typedef struct Term {
  int nops;
  OpPow *ops;            /* ops[0] innermost */
  Field *num;            /* the polynomial q_t */
  /* analysis (lower.c) */
  Sym *named_num;        /* q_t is exactly a named quantity (identity map) */
  TensorList num_tensors;
  TensorList *op_tensors;  /* per op: its tensor groups (row, col, inputs) */
} Term;

typedef enum StageKind {
  ST_CONTRACT,  /* polynomial: Σ Q ⊗ x ⊗ … + c */
  ST_APPLY,     /* declared operators to positive integer powers */
  ST_INVERSE,   /* operators to negative integer powers */
  ST_ROOT,      /* operators to fractional powers (eigendecomposition) */
  ST_EXTERN,    /* black box, learned map in reduced space */
  ST_INPUT,     /* an input: only a basis */
} StageKind;
extern const char *const stage_kind_name[];

typedef struct Stage {
  Sym *sym;
  StageKind kind;
  int nterms;
  Term **terms;
  int ncomp;             /* product of static shape */
  int klass;             /* basis class id */
} Stage;

/* A declared operator's entries, lowered once. */
typedef struct OpDef {
  Sym *sym;
  Field *entries;        /* one component; over the op's ivars (rows, cols) */
  TensorList tensors;
  bool sparse;           /* its entries grow slower than rows × cols (an index-table
                            gather: K·N, not N^2): the full evaluator assembles
                            it in compressed form (DESIGN §13) */
} OpDef;

/* How the entries of one additive part of a monomial are enumerated
 * without visiting every index: its variables are the index variables of
 * its quantity, then its sum variables; fixed_by[v] is the expression an
 * equality of its guard or coefficient determines variable v by (`j` in
 * `if(nbr[i, k] == j, …)` is nbr[i, k]), NULL for one looped over; `order`
 * lists every free variable, then the fixed ones, each after the
 * variables its expression reads. The part's coefficient is
 * sign × Π factors (a coefficient that sums deltas, (δ(i,a) − δ(i,b))·…, is
 * enumerated part by part, each part fixing its own variables). */
#define TENSOR_MAXV (MAX_AXES + 16)   /* at most 64: the analysis keeps a bit per variable */
#define TENSOR_MAXPARTS 16
#define TENSOR_MAXFACTORS 8
typedef struct MonoPart {
  int nvars;
  const Sym *vars[TENSOR_MAXV];
  const Node *fixed_by[TENSOR_MAXV];
  int order[TENSOR_MAXV];
  int sign;
  int nfactors;
  const Node *factors[TENSOR_MAXFACTORS];
} MonoPart;
/* The parts of monomial `m` of a quantity with index variables `ivars`,
 * into out[0 .. TENSOR_MAXPARTS); returns how many. */
int tensor_mono_parts(Ctx *ctx, const Mono *m, Sym *const *ivars, int nivars, MonoPart *out);

/* A reason two quantities share a basis. */
typedef struct Merge {
  Sym *a, *b;
  char *reason;          /* "h = diag(r)^-1 s (inverse: numerator lives in the result's basis)" */
  Loc loc;
} Merge;

/* A numerator that has no basis of its own but whose snapshots join the
 * class of its result (DESIGN §4). */
typedef struct Joiner {
  Stage *stage;
  int term;
} Joiner;

typedef struct BasisClass {
  int id;
  PtrVec members;        /* Sym* */
  PtrVec joiners;        /* Joiner* */
  int basis_max;         /* -1: default */
  double basis_energy;   /* <0: default */
  int basis_center;      /* -1: default, 1 on, 0 off */
  Sym *product;          /* `basis x: product K0`: BᵀK0B = I (NULL: BᵀB = I) */
  char *size_name;       /* m_<first member> */
} BasisClass;

struct Program {
  Ctx *ctx;              /* the compilation this program lives in */
  const SrcFile *main;
  PtrVec dims, params, inputs, externs, ops, fns;  /* Sym* */
  PtrVec quantities;     /* Sym* with a basis, in evaluation order: inputs,
                            then stages and externs */
  PtrVec stages;         /* Stage*, in evaluation order (introduced ones too) */
  PtrVec opdefs;         /* OpDef* */
  PtrVec outputs;        /* Sym* */
  PtrVec states;         /* Sym*: the inputs declared `state`, each with its `next` stage (Sym.next) */
  PtrVec inlined;        /* Sym*: stages named by `inline` */
  PtrVec temps;          /* Sym*: inlined stages that read inputs: folded into the
                            tensors, but computed once by the full evaluator */
  PtrVec slots;          /* Sym*: what generated code holds values of (NpgCtx.q):
                            quantities, then temps */
  PtrVec shares;         /* Decl* */
  PtrVec merges;         /* Merge* */
  PtrVec classes;        /* BasisClass* */
  PtrVec notes;          /* char*: things the compiler did that the user should know */
  Decl *decls;
};

/* ---------------------------------------------------------------- coefficient nodes (coef.c) */

/* Nodes built with constant operands folded as the evaluator would. */
Node *coef_num(Ctx *ctx, double v);
bool coef_is_num(const Node *n, double v);
Node *coef_bin(Ctx *ctx, NodeKind k, Node *a, Node *b);
Node *coef_neg(Ctx *ctx, Node *a);
Node *coef_and(Ctx *ctx, Node *a, Node *b);  /* conjunction of guards; NULL means true */
Node *coef_not(Ctx *ctx, Node *a);
Node *coef_name(Ctx *ctx, Sym *s);

/* ---------------------------------------------------------------- polys */

Mono *mono_const(Ctx *ctx, Node *coef);
Poly *poly_new(Ctx *ctx);
void poly_push(Ctx *ctx, Poly *p, Mono *m);
bool poly_is_zero(const Poly *p);
/* Arithmetic (poly.c), every result in the arena; monomial products rename
 * clashing summation variables, guards are conjoined. */
Mono *mono_copy(Ctx *ctx, const Mono *m);
Mono *mono_rename(Ctx *ctx, const Mono *m, Sym *from);  /* summation variable `from` made fresh */
Mono *mono_mul(Ctx *ctx, const Mono *a, const Mono *b);
Mono *mono_guarded(Ctx *ctx, const Mono *m, Node *guard);  /* m itself when guard is NULL */
void poly_add(Ctx *ctx, Poly *dst, const Poly *src, Node *guard);
Poly poly_mul(Ctx *ctx, const Poly *a, const Poly *b);
Field *field_ones(Ctx *ctx, int ncomp);
bool field_is_coef(const Field *f);  /* no monomial reads a quantity */
/* Sort each monomial's atoms canonically, add the coefficients of
 * monomials reading the same entries, drop those that cancel (poly.c). */
void field_combine_like(Ctx *ctx, Field *f);
Field *field_new(Ctx *ctx, int ncomp);
int mono_degree(const Mono *m);
int field_degree(const Field *f);

/* Canonical text of polynomials, fields and terms (also used as a key for
 * structural equality). */
void print_mono(FILE *out, const Mono *m);
void print_poly(FILE *out, const Poly *p);
void print_field(FILE *out, const Field *f);
void print_term(FILE *out, const Term *t);
char *field_key(Ctx *ctx, const Field *f);

/* ---------------------------------------------------------------- passes */

/* ir/lower.c: canonical form of every stage and op (program->stages). */
void lower_program(Ctx *ctx, Program *prog);
/* ir/lower.c: may stage `st` be reduced by interpolation (DESIGN §12)? Yes
 * when it applies operators and every one is diagonal (an elementwise
 * inverse, root or power of a polynomial in named quantities): its value at
 * an entry then reads its inputs only near that entry, so it can be
 * evaluated exactly at a few selected entries. */
bool lower_interp_eligible(const Stage *st);
/* ir/lower.c: the quantities under a power (DESIGN §12), marks per
 * prog->quantities (malloc'd; NULL when none or out of memory): in a program
 * without extern, those the operators of an interpolation-eligible stage
 * read and those they are computed from. Training keeps their bases whole
 * by default (energy 1, up to the cap): their truncation error is raised to
 * the stage's negative or fractional power where their values are smallest,
 * a part of the snapshots an energy fraction weighs least. Kept at 0.999
 * they left Lennard-Jones 4-5x its output floor and gave springs a negative
 * reduced edge length on held-out samples; whole, 1.0-1.2x
 * (bench/interp.md). An extern's program is left alone: its pair classes
 * would grow (radiosity). */
bool *lower_under_powers(const Program *prog);
/* ir/basis.c: union-find basis classes with reasons. */
void basis_classes(Ctx *ctx, Program *prog);
/* ir/verify.c: structural invariants; internal_error on violation. */
void verify_program(Ctx *ctx, const Program *prog);
/* ir/dump.c: the human readable IR (npgc check) and its JSON form. */
void dump_program(FILE *out, const Program *prog);
void dump_stages(FILE *out, const Program *prog);
void dump_classes(FILE *out, const Program *prog);
void dump_json(FILE *out, const Program *prog);
/* ir/cost.c: reduced evaluation cost formula in basis sizes. */
char *cost_formula(Ctx *ctx, const Program *prog);
char *stage_cost(Ctx *ctx, const Program *prog, const Stage *st);
/* The same formula's value for class sizes m[c] (Program.classes order)
 * and S training samples (allocates its monomials in prog->ctx's arena). */
double cost_value(const Program *prog, const long *m, long S);

#endif
