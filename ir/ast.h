/* ast.h — the expression graph and symbols (source text, the arena and
 * diagnostics: context.h).
 *
 * This is the shared vocabulary of every stage of the compiler: the parser
 * (compiler/front/parse.c) builds Nodes and Decls, the checker (compiler/front/sema.c)
 * resolves names to Syms and types every Node, the lowering (ir/lower.c)
 * turns checked stages into the canonical form of ir/ir.h. Reading files and
 * the lexer's tokens belong to the front end (compiler/front/compile.h).
 *
 * Memory: every Node, Decl and Sym lives in the compilation's arena
 * (Ctx.arena), released at once by ctx_free(). User errors longjmp to
 * ctx->on_error (context.h).
 */
#ifndef NPG_AST_H
#define NPG_AST_H

#include "context.h"

typedef struct Node Node;
typedef struct Decl Decl;
typedef struct Sym Sym;
typedef struct Program Program;

/* An error at a node: adds "note: inlined from here" lines for fn calls. */
_Noreturn void error_node(Ctx *ctx, const Node *n, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* ---------------------------------------------------------------- nodes */

typedef enum NodeKind {
#define NODE(k, name, sym) N_##k,
#include "ops.def"
#undef NODE
  N__COUNT
} NodeKind;

typedef enum Builtin {
  B_NONE = 0,
#define BUILTIN(id, name, arity, alg) B_##id,
#include "ops.def"
#undef BUILTIN
  B__COUNT
} Builtin;

extern const char *const node_kind_name[N__COUNT];
extern const char *const node_kind_sym[N__COUNT];
typedef struct BuiltinInfo {
  const char *name;
  int arity;
  bool algebraic;
} BuiltinInfo;
extern const BuiltinInfo builtin_info[B__COUNT];
Builtin builtin_lookup(const char *name);

/* Variability of an expression: what it depends on. Ordered. */
typedef enum Var {
  V_CONST,    /* numbers, dims, index variables */
  V_PARAM,    /* also params: a coefficient, computed at bind time */
  V_VARYING,  /* depends on an input, stage or extern: algebraic rules apply */
} Var;

#define MAX_STATIC 4
#define MAX_AXES 8

/* The type of a checked expression. */
typedef struct Type {
  int nstatic;                 /* static (trailing, small) shape, e.g. [3] */
  int shape[MAX_STATIC];
  Var var;
  bool is_int;                 /* integer valued (index arithmetic) */
  bool is_bool;                /* a condition */
  int nwhole;                  /* >0: a whole quantity over these dims */
  Sym *whole[MAX_AXES];
  Sym *op;                     /* non-NULL: an operator value (op, op^r) */
} Type;

struct Node {
  NodeKind kind;
  Loc loc;
  Node *inl;           /* the fn call this node was inlined from, or NULL */
  /* N_NUM */
  double num;
  bool is_int;
  /* N_NAME, N_CALL (callee), N_SUM (variable) */
  const char *name;
  bool global_only;    /* N_NAME from a fn body: skips the caller's index vars */
  bool checked;        /* typed by sema (a substituted fn argument is not checked twice) */
  /* operands: N_INDEX base=a, args; N_CALL args; binary a, b; unary a;
   * N_SUM: a=lo, b=hi, c=body; N_IF: a=cond, b=then, c=else */
  Node *a, *b, *c;
  Node **args;
  int nargs;
  /* N_RAT */
  long p, q;
  /* after sema */
  Sym *sym;            /* N_NAME/N_INDEX: the quantity, param, dim or variable */
  Builtin builtin;     /* N_CALL */
  Type ty;
};

Node *new_node(Ctx *ctx, NodeKind kind, Loc loc);
Node *new_num(Ctx *ctx, double v, bool is_int, Loc loc);
Node *clone_node(Ctx *ctx, const Node *n);      /* deep copy */
/* The height of the tree at `n` (a leaf is 1), found without recursion,
 * and `limit` + 1 as soon as it exceeds `limit`: the passes recurse over
 * expressions, so a taller tree is refused before they run. -1 when out of
 * memory. */
int node_height(const Node *n, int limit);
/* Whether the tree at `n` names the symbol `s` (an index variable, a
 * quantity, a param) anywhere. */
bool node_uses(const Node *n, const Sym *s);
void print_node(FILE *out, const Node *n);      /* source-like text */
char *node_str(Ctx *ctx, const Node *n);        /* the same, in the arena */
/* Text printed by `print(out, x)`, in the arena. */
char *print_to_arena(Ctx *ctx, void (*print)(FILE *, const void *), const void *x);

/* ---------------------------------------------------------------- decls */

/* How a `basis` statement asks a stage be reduced (DESIGN §12). */
enum {
  STAGE_REDUCE_DEFAULT,   /* training decides (Galerkin, or by validation) */
  STAGE_REDUCE_GALERKIN,  /* reduce galerkin */
  STAGE_REDUCE_INTERP,    /* reduce interp: empirical interpolation */
};

typedef enum DeclKind {
  D_DIM,      /* dim F, V */
  D_PARAM,    /* param tri : int[F, 3] */
  D_INPUT,    /* input g : real[V, 3]; state u : real[N] (is_state) */
  D_STAGE,    /* name[i:N, ...] = expr  (and output name... = expr) */
  D_OP,       /* op M[i:N, j:N] = expr */
  D_EXTERN,   /* extern v[i:F, j:F] of g */
  D_FN,       /* fn name(a, b) = expr */
  D_SHARE,    /* share a, b */
  D_BASIS,    /* basis a, b: max 60, energy 0.999 */
  D_INLINE,   /* inline c */
  D_USE,      /* use geometry */
  D_OUTPUT,   /* output name  (marks an existing quantity) */
} DeclKind;

typedef struct IndexVarDecl {
  const char *name;
  const char *dim;
  Loc loc, dim_loc;
} IndexVarDecl;

typedef struct Axis {       /* one axis of a declared type */
  const char *dim;          /* NULL for a static axis */
  int size;                 /* static size */
  Loc loc;
} Axis;

struct Decl {
  DeclKind kind;
  Loc loc;                  /* the keyword or the defined name */
  const char *name;
  Loc name_loc;
  /* D_PARAM / D_INPUT: element type and axes */
  bool is_int;
  Axis axes[MAX_AXES];
  int naxes;
  /* D_STAGE / D_OP / D_EXTERN: index variables */
  IndexVarDecl ivars[MAX_AXES];
  int nivars;
  Node *body;               /* D_STAGE / D_OP / D_FN */
  /* D_FN parameters; D_DIM/D_SHARE/D_BASIS/D_INLINE/D_EXTERN(of) names */
  const char **names;
  Loc *name_locs;
  int nnames;
  bool is_output;
  bool is_state;            /* D_INPUT: `state u : ...`, carried from step to step */
  const char *next_of;      /* D_STAGE: `next u = ...` defines the state u's next value; D_INPUT: the
                             * unknown `u.next` of an implicit step (lowered from `residual next u`) */
  Loc next_of_loc;
  const char *residual_of;  /* D_STAGE: `residual next u = ...`, the residual whose zero is u.next */
  /* D_BASIS options (negative when not given) */
  int basis_max;
  double basis_energy;
  int basis_center;             /* 1 on, 0 off */
  int basis_reduce;             /* STAGE_REDUCE_*: `reduce interp|galerkin` (DESIGN §12) */
  const char *basis_product;    /* `product K0`: the class orthonormal in K0's inner product (NULL: Euclidean) */
  Loc basis_product_loc;
  /* D_OP: "on u -> p" */
  const char *on_from, *on_to;
  Loc on_loc, on_to_loc;
  Decl *next;
};

/* ---------------------------------------------------------------- symbols */

typedef enum SymKind {
  SYM_DIM,      /* a size bound from data */
  SYM_PARAM,    /* data fixed at train time */
  SYM_INPUT,    /* varies per evaluation, gets a basis */
  SYM_STAGE,    /* a named definition: gets a basis unless inlined */
  SYM_OP,       /* a linear operator: entries polynomial in stages */
  SYM_EXTERN,   /* a black-box stage */
  SYM_FN,       /* an inlined helper */
  SYM_IVAR,     /* an index variable of a stage or op */
  SYM_SUMVAR,   /* the variable of a sum */
  SYM_FNARG,    /* a fn argument during checking */
} SymKind;

struct Sym {
  SymKind kind;
  const char *name;
  Loc loc;
  Decl *decl;
  int id;                       /* index in its program list */
  /* shape of a quantity: dim axes then static axes */
  int ndims;
  Sym *dims[MAX_AXES];
  int nstatic;
  int shape[MAX_STATIC];
  bool is_int;
  /* SYM_IVAR / SYM_SUMVAR: the dim the variable ranges over (NULL: a sum
   * with explicit bounds) */
  Sym *range;
  /* SYM_STAGE, SYM_OP, SYM_EXTERN */
  Sym *ivars[MAX_AXES];         /* the stage's index variables (implicit ones too) */
  int nivars;
  Node *body;                   /* checked body */
  bool is_output;
  /* a state (`state u`, SYM_INPUT) and the stage of its next value (`next u`, SYM_STAGE `u.next`) */
  Sym *next;
  Sym *state_of;
  Sym *residual;                /* a state stepped implicitly: the residual stage `u.residual` (its next
                                 * value `u.next` is then an input, the residual's zero) */
  bool inlined;                 /* `inline name`, or a constant definition */
  Loc inline_loc;               /* the `inline` statement naming it (line 0: constant) */
  bool introduced;              /* created by the compiler (y.t1; an implicit index variable of y = 2 * x) */
  Loc introduced_at;
  Sym *introduced_for;
  /* SYM_EXTERN */
  Sym **of;
  int nof;
  /* SYM_OP: row dims are ivars[0..nrow), columns ivars[nrow..nivars) */
  int nrow;
  Sym *on_from, *on_to;
  bool applied;                 /* used in some stage */
  /* SYM_FN */
  int nargs;
  const char **argnames;
  bool expanding;               /* recursion detection */
  /* basis options from `basis` (negative: default) */
  int basis_max;
  double basis_energy;
  int basis_center;             /* 1 on, 0 off (centered truncation, DESIGN §5) */
  /* the same for this quantity's whole class, from `basis m_<name>: ...` (the class's name as
   * `npgc check` and --basis write it) */
  int class_basis_max;
  double class_basis_energy;
  int class_basis_center;
  /* `basis x: product K0`: x's class orthonormal in the inner product of the op K0 (NULL: Euclidean) */
  struct Sym *product;
  Loc product_loc;
  int reduce;                   /* STAGE_REDUCE_*: how the program asks the stage be reduced (DESIGN §12) */
  Loc reduce_loc;               /* where it asks */
  struct Stage *stage;          /* canonical form, after lowering */
  struct OpDef *opdef;          /* SYM_OP: its lowered entries */
  int klass;                    /* basis class, after basis_classes() */
};

#endif
