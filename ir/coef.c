/* coef.c — coefficient nodes of the canonical form: expression Nodes over
 * numbers, params and index variables, built with the folding of constant
 * operands the evaluator would do (1·a = a, 0 + a = a, 2·3 = 6). */
#include <math.h>

#include "ir.h"

Node *coef_num(Ctx *ctx, double v) {
  bool is_int = fabs(v) < 9007199254740992.0 && v == floor(v);  /* no cast of out-of-range doubles */
  return new_num(ctx, v, is_int, (Loc){0});
}

bool coef_is_num(const Node *n, double v) { return n && n->kind == N_NUM && n->num == v; }

Node *coef_bin(Ctx *ctx, NodeKind k, Node *a, Node *b) {
  if (a->kind == N_NUM && b->kind == N_NUM) {
    switch (k) {
    case N_ADD: return coef_num(ctx, a->num + b->num);
    case N_SUB: return coef_num(ctx, a->num - b->num);
    case N_MUL: return coef_num(ctx, a->num * b->num);
    case N_DIV:
      if (b->num != 0) return coef_num(ctx, a->num / b->num);  /* the value the evaluator would compute */
      break;
    default: break;
    }
  }
  if (k == N_MUL) {
    if (coef_is_num(a, 1)) return b;
    if (coef_is_num(b, 1)) return a;
    if (coef_is_num(a, 0) || coef_is_num(b, 0)) return coef_num(ctx, 0);
    if (coef_is_num(a, -1) && b->kind == N_NEG) return b->a;
  }
  if (k == N_ADD) {
    if (coef_is_num(a, 0)) return b;
    if (coef_is_num(b, 0)) return a;
  }
  if (k == N_SUB && coef_is_num(b, 0)) return a;
  if (k == N_DIV && coef_is_num(b, 1)) return a;
  Node *n = new_node(ctx, k, (Loc){0});
  n->a = a;
  n->b = b;
  return n;
}

Node *coef_neg(Ctx *ctx, Node *a) {
  if (a->kind == N_NUM) return coef_num(ctx, -a->num);
  if (a->kind == N_NEG) return a->a;
  Node *n = new_node(ctx, N_NEG, (Loc){0});
  n->a = a;
  return n;
}

/* Conjunction of guards; NULL means true. */
Node *coef_and(Ctx *ctx, Node *a, Node *b) {
  if (!a) return b;
  if (!b) return a;
  return coef_bin(ctx, N_AND, a, b);
}

Node *coef_not(Ctx *ctx, Node *a) {
  Node *n = new_node(ctx, N_NOT, (Loc){0});
  n->a = a;
  return n;
}

Node *coef_name(Ctx *ctx, Sym *s) {
  Node *n = new_node(ctx, N_NAME, (Loc){0});
  n->name = s->name;
  n->sym = s;
  return n;
}
