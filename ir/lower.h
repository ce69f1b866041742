/* lower.h — what ir/lower.c (the stages) and ir/lower_expr.c (the
 * expressions) share while lowering one program; private to the two. */
#ifndef NPG_LOWER_H
#define NPG_LOWER_H

#include "ir.h"

/* Index variables bound to coefficient expressions. */
typedef struct Env {
  Sym *var;
  Node *val;
  struct Env *next;
} Env;

/* A lowered expression: a sum of terms over `ncomp` static components. */
typedef struct Value {
  int ncomp;
  PtrVec terms;   /* Term* */
} Value;

typedef struct Lowerer {
  Ctx *ctx;
  Program *prog;
  Sym *cur;            /* the top-level definition being lowered */
  int nintro;          /* introduced stages for cur */
  PtrVec *open_sums;   /* summation variables open around the expression being lowered */
} Lowerer;

/* lower_expr.c: expression `n` in the canonical form, index variables from `env`. */
Value *lower_expr(Lowerer *L, Node *n, Env *env);
/* lower_expr.c: a stage "cur.tN" introduced for `v` (a divisor or root base
 * that is not one operator-free polynomial term), `at` the expression it
 * came from; the value reading it. */
Value *lower_expr_introduce(Lowerer *L, Value *v, const Node *at, PtrVec *open_sums);
/* lower_expr.c: the entries `v` of the op being lowered (L->cur) with each term's divisions and roots
 * named as a stage over the index variables their base uses where the term's numerator can be nonzero
 * (r[i] = 1 / h[i] for kappa[i] / h[i] under if(nbr[i, k] == j, …)), read by the entries: one
 * polynomial term, so the op keeps its pattern (DESIGN §13). NULL when a term's power spans all the
 * op's index variables (naming it saves nothing) or applies a declared op. `at`: the op's body. */
Value *lower_expr_op_entries(Lowerer *L, Value *v, const Node *at);
/* The note on an introduced stage that names a whole `op` entry over two or more index
 * variables: its size, that the op is dense, and the cure (name the reciprocal). */
const char *lower_dense_entry_cure(Ctx *ctx, const Sym *s);
/* lower.c: the stage of quantity `s` from its value. */
Stage *lower_stage(Lowerer *L, Sym *s, Value *v);

#endif
