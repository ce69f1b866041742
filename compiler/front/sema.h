/* sema.h — what the semantic checks share across compiler/front/sema.c
 * (declarations, sema_program), sema_expr.c (expressions) and
 * sema_inline.c (fn inlining); private to the three. */
#ifndef NPG_SEMA_H
#define NPG_SEMA_H

#include "compile.h"

typedef struct Checker {
  Ctx *ctx;
  Program *prog;
  PtrVec globals;        /* Sym*: dims, params, inputs, stages, ops, externs, fns */
  Sym *cur;              /* stage/op/extern being checked */
  int cur_order;         /* position of cur in source order */
  PtrVec sums;           /* Sym* of enclosing sums, innermost last */
  int depth;             /* fn expansion depth */
  long expanded;         /* nodes created by fn expansion, bounded */
  double unrolled;       /* expression nodes the sums with literal bounds unroll to, bounded */
  bool in_cond;          /* checking a condition (for messages) */
} Checker;

/* Source order of quantities, for define-before-use. */
typedef struct Order { Sym *sym; int order; } Order;

/* sema.c: a new symbol with the defaults of `basis` and no class yet. */
Sym *sema_new_sym(Checker *ck, SymKind kind, const char *name, Loc loc);
/* sema.c: what a name is, with its article: "an input", "a stage". */
const char *sema_kind_word(const Sym *s);
Sym *sema_find_global(Checker *ck, const char *name);
/* What a misspelt name may have meant: a value in an expression (sum and index variables, globals but fns,
 * pi), a function (the algebraic builtins and the fns), a quantity with a basis (input, stage, extern; for
 * `basis`, `share`, `inline`, `on`), or an output (a quantity or an op). */
typedef enum SemaSuggest { SUGGEST_VALUE, SUGGEST_FUNCTION, SUGGEST_QUANTITY, SUGGEST_OUTPUT } SemaSuggest;
/* sema.c: the known name of that kind nearest `name` by edit distance (at most a third of its length, 1 to
 * 3), or NULL. */
const char *sema_suggest(Checker *ck, const char *name, SemaSuggest what);
/* sema.c: the stdlib module (<std_dir>/npg/<module>.npg, the first in name order) defining fn `name`, or
 * NULL: for a call of a fn whose module the program does not use. */
const char *sema_module_of_fn(Checker *ck, const char *name);
/* "; did you mean 'solve'?" for sema_suggest's answer, or "" (for the end of an "unknown" message). */
const char *sema_did_you_mean(Checker *ck, const char *name, SemaSuggest what);
char *sema_shape_str(Ctx *ctx, const Type *t);
char *sema_sym_type_str(Ctx *ctx, const Sym *s);

/* sema_expr.c: check and type expression `n` (once: a checked node is
 * returned as is); the node that replaces it (fn calls are inlined, sqrt,
 * root and if calls rewritten). */
Node *sema_expr_check(Checker *ck, Node *n);
/* sema_expr.c: user errors unless `n`, at `where`, is not an operator value,
 * not a whole quantity, not a condition. */
void sema_expr_no_op_value(Checker *ck, const Node *n, const char *where);
void sema_expr_no_whole(Checker *ck, const Node *n, const char *where);
void sema_expr_no_bool(Checker *ck, const Node *n, const char *where);
/* sema_inline.c: the body of fn `fn` for `call`, its arguments substituted
 * (checked in the caller's scope), its summation variables renamed, checked. */
Node *sema_inline_fn(Checker *ck, Node *call, Sym *fn);

#endif
