/* sema_inline.c — fn calls inlined by substitution: argument expressions
 * replace the parameters, the body's own free names see only the program's
 * globals, and the body's summation variables are renamed so they cannot
 * capture names of the caller. */
#include <string.h>

#include "sema.h"

typedef struct Subst {
  const char *name;
  Node *arg;           /* replace by a clone of this (fn argument) */
  const char *rename;  /* or rename (summation variable of the body) */
} Subst;

#define MAX_EXPANDED 2000000

/* Node count of a tree, stopping once past `limit`. */
static long count_nodes(const Node *n, long limit) {
  if (!n || limit <= 0) return 0;
  long c = 1 + count_nodes(n->a, limit - 1);
  c += count_nodes(n->b, limit - c);
  c += count_nodes(n->c, limit - c);
  for (int i = 0; i < n->nargs && c < limit; i++) c += count_nodes(n->args[i], limit - c);
  return c;
}

static Node *subst(Checker *ck, const Node *n, Subst *map, int nmap, Node *call) {
  if (!n) return NULL;
  if (++ck->expanded > MAX_EXPANDED)
    error_node(ck->ctx, call, "fn calls expand to more than %d expression nodes; define intermediate stages instead",
               MAX_EXPANDED);
  if (n->kind == N_NAME) {
    for (int i = nmap - 1; i >= 0; i--)
      if (strcmp(map[i].name, n->name) == 0) {
        if (map[i].arg) {
          ck->expanded += count_nodes(map[i].arg, MAX_EXPANDED + 1);
          if (ck->expanded > MAX_EXPANDED)
            error_node(ck->ctx, call, "fn calls expand to more than %d expression nodes; define intermediate stages instead",
                       MAX_EXPANDED);
          return clone_node(ck->ctx, map[i].arg);
        }
        Node *c = clone_node(ck->ctx, n);
        c->name = map[i].rename;
        c->inl = call;
        return c;
      }
    Node *c = clone_node(ck->ctx, n);
    c->global_only = true;
    c->inl = call;
    return c;
  }
  Node *c = arena_alloc(ck->ctx, sizeof *c);
  *c = *n;
  c->inl = call;
  if (n->kind == N_SUM) {
    c->a = subst(ck, n->a, map, nmap, call);
    c->b = subst(ck, n->b, map, nmap, call);
    Subst *m2 = arena_alloc(ck->ctx, sizeof(Subst) * (size_t)(nmap + 1));
    if (nmap) memcpy(m2, map, sizeof(Subst) * (size_t)nmap);
    m2[nmap].name = n->name;
    m2[nmap].rename = arena_printf(ck->ctx, "%s#%d", n->name, ++ck->ctx->uniq);
    c->name = m2[nmap].rename;
    c->c = subst(ck, n->c, m2, nmap + 1, call);
    return c;
  }
  c->a = subst(ck, n->a, map, nmap, call);
  c->b = subst(ck, n->b, map, nmap, call);
  c->c = subst(ck, n->c, map, nmap, call);
  if (n->nargs) {
    c->args = arena_alloc(ck->ctx, sizeof(Node *) * (size_t)n->nargs);
    for (int i = 0; i < n->nargs; i++) c->args[i] = subst(ck, n->args[i], map, nmap, call);
  }
  return c;
}

Node *sema_inline_fn(Checker *ck, Node *call, Sym *fn) {
  Ctx *ctx = ck->ctx;
  if (call->nargs != fn->nargs)
    error_note(ctx, call->loc, fn->loc, "defined here", "'%s' takes %d argument%s, but %d %s given", fn->name,
               fn->nargs, fn->nargs == 1 ? "" : "s", call->nargs, call->nargs == 1 ? "was" : "were");
  if (fn->expanding)
    error_note(ctx, call->loc, fn->loc, "defined here",
               "recursion in fn '%s': fns are inlined, so a fn cannot call itself", fn->name);
  if (ck->depth >= 64) error_node(ctx, call, "fn calls nested too deeply (more than 64)");
  /* Arguments are checked in the caller's scope first (f(f(a)) is not
   * recursion); the checked copies substituted into the body are not
   * checked again. */
  Subst *map = arena_alloc(ctx, sizeof(Subst) * (size_t)(fn->nargs + 1));
  for (int i = 0; i < fn->nargs; i++) {
    map[i].name = fn->argnames[i];
    map[i].arg = call->args[i] = sema_expr_check(ck, call->args[i]);
  }
  Node *body = subst(ck, fn->body, map, fn->nargs, call);
  int h = node_height(body, MAX_EXPR_HEIGHT);
  if (h < 0) error_plain(ctx, "out of memory");
  if (h > MAX_EXPR_HEIGHT)
    error_node(ctx, call, "expression too deep once fn '%s' is inlined (more than %d levels); split it into named "
                          "definitions", fn->name, MAX_EXPR_HEIGHT);
  fn->expanding = true;
  ck->depth++;
  body = sema_expr_check(ck, body);
  ck->depth--;
  fn->expanding = false;
  return body;
}
