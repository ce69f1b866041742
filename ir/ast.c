/* ast.c — the tables of node kinds and builtins, expression nodes, their
 * diagnostics and their printer (the arena and the context: context.c). */
#include "ast.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ---------------------------------------------------------------- tables */

const char *const node_kind_name[N__COUNT] = {
#define NODE(k, name, sym) name,
#include "ops.def"
#undef NODE
};

const char *const node_kind_sym[N__COUNT] = {
#define NODE(k, name, sym) sym,
#include "ops.def"
#undef NODE
};

const BuiltinInfo builtin_info[B__COUNT] = {
    {NULL, 0, false},
#define BUILTIN(id, name, arity, alg) {name, arity, alg},
#include "ops.def"
#undef BUILTIN
};

Builtin builtin_lookup(const char *name) {
  for (int b = 1; b < B__COUNT; b++)
    if (strcmp(builtin_info[b].name, name) == 0) return (Builtin)b;
  return B_NONE;
}

/* ---------------------------------------------------------------- diagnostics at nodes */

_Noreturn void error_node(Ctx *ctx, const Node *n, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = n->loc;
  ctx->msg = diag_format(ctx, "", n->loc, "error", msg);
  for (const Node *c = n->inl; c; c = c->inl)
    ctx->msg = diag_format(ctx, ctx->msg, c->loc, "note", arena_printf(ctx, "in the call of '%s' here", c->name));
  ctx_fail(ctx);
}

/* ---------------------------------------------------------------- nodes */

Node *new_node(Ctx *ctx, NodeKind kind, Loc loc) {
  Node *n = arena_alloc(ctx, sizeof *n);
  n->kind = kind;
  n->loc = loc;
  return n;
}

bool node_uses(const Node *n, const Sym *s) {
  if (!n) return false;
  if (n->kind == N_NAME && n->sym == s) return true;
  if (node_uses(n->a, s) || node_uses(n->b, s) || node_uses(n->c, s)) return true;
  for (int i = 0; i < n->nargs; i++)
    if (node_uses(n->args[i], s)) return true;
  return false;
}

int node_height(const Node *n, int limit) {
  if (!n) return 0;
  typedef struct Frame {
    const Node *n;
    int depth;
  } Frame;
  size_t cap = 256, top = 0;
  Frame *st = malloc(sizeof(Frame) * cap);
  if (!st) return -1;
  st[top++] = (Frame){n, 1};
  int height = 0;
  while (top > 0) {
    Frame f = st[--top];
    if (f.depth > height) height = f.depth;
    if (height > limit) break;
    const Node *kids[3] = {f.n->a, f.n->b, f.n->c};
    size_t need = top + 3 + (size_t)(f.n->nargs > 0 ? f.n->nargs : 0);
    if (need > cap) {
      while (cap < need) cap *= 2;
      Frame *g = realloc(st, sizeof(Frame) * cap);
      if (!g) {
        free(st);
        return -1;
      }
      st = g;
    }
    for (int k = 0; k < 3; k++)
      if (kids[k]) st[top++] = (Frame){kids[k], f.depth + 1};
    for (int k = 0; k < f.n->nargs; k++)
      if (f.n->args[k]) st[top++] = (Frame){f.n->args[k], f.depth + 1};
  }
  free(st);
  return height > limit ? limit + 1 : height;
}

Node *new_num(Ctx *ctx, double v, bool is_int, Loc loc) {
  Node *n = new_node(ctx, N_NUM, loc);
  n->num = v;
  n->is_int = is_int;
  n->ty.is_int = is_int;
  return n;
}

Node *clone_node(Ctx *ctx, const Node *n) {
  if (!n) return NULL;
  Node *c = arena_alloc(ctx, sizeof *c);
  *c = *n;
  c->a = clone_node(ctx, n->a);
  c->b = clone_node(ctx, n->b);
  c->c = clone_node(ctx, n->c);
  if (n->nargs) {
    c->args = arena_alloc(ctx, sizeof(Node *) * (size_t)n->nargs);
    for (int i = 0; i < n->nargs; i++) c->args[i] = clone_node(ctx, n->args[i]);
  }
  return c;
}

static void print_num(FILE *out, double v) {
  if (v > -1e15 && v < 1e15 && v == (double)(long long)v) /* range first: no out-of-range cast */
    fprintf(out, "%lld", (long long)v);
  else
    fprintf(out, "%.17g", v);
}

static int prec(const Node *n) {
  switch (n->kind) {
  case N_OR: return 1;
  case N_AND: return 2;
  case N_EQ: case N_NE: case N_LT: case N_LE: case N_GT: case N_GE: return 3;
  case N_ADD: case N_SUB: return 4;
  case N_MUL: case N_DIV: return 5;
  case N_NEG: case N_NOT: return 6;
  case N_POW: return 7;
  case N_NUM: return n->num < 0 ? 6 : 9;
  case N_RAT: return 5;
  default: return 9;
  }
}

static void print_sub(FILE *out, const Node *n, int min_prec) {
  bool paren = prec(n) < min_prec;
  if (paren) fputc('(', out);
  print_node(out, n);
  if (paren) fputc(')', out);
}

static void print_args(FILE *out, const Node *n, char open, char close) {
  fputc(open, out);
  for (int i = 0; i < n->nargs; i++) {
    if (i) fputs(", ", out);
    print_node(out, n->args[i]);
  }
  fputc(close, out);
}

void print_node(FILE *out, const Node *n) {
  if (!n) {
    fputs("<null>", out);
    return;
  }
  switch (n->kind) {
  case N_NUM: print_num(out, n->num); break;
  case N_RAT: fprintf(out, "%ld/%ld", n->p, n->q); break;
  case N_NAME: fputs(n->sym ? n->sym->name : n->name, out); break;
  case N_INDEX:
    print_sub(out, n->a, 9);
    print_args(out, n, '[', ']');
    break;
  case N_CALL:
    fputs(n->name, out);
    print_args(out, n, '(', ')');
    break;
  case N_VEC: print_args(out, n, '[', ']'); break;
  case N_SUM:
    fprintf(out, "sum(%s = ", n->sym ? n->sym->name : n->name);
    print_node(out, n->a);
    fputs("..", out);
    print_node(out, n->b);
    fputs(", ", out);
    print_node(out, n->c);
    fputc(')', out);
    break;
  case N_IF:
    fputs("if(", out);
    print_node(out, n->a);
    fputs(", ", out);
    print_node(out, n->b);
    fputs(", ", out);
    print_node(out, n->c);
    fputc(')', out);
    break;
  case N_NEG:
  case N_NOT:
    fputs(node_kind_sym[n->kind], out);
    print_sub(out, n->a, 7);
    break;
  case N_POW:
    print_sub(out, n->a, 8);
    fputc('^', out);
    print_sub(out, n->b, 9);
    break;
  default: {
    int p = prec(n);
    print_sub(out, n->a, p);
    fprintf(out, " %s ", node_kind_sym[n->kind]);
    print_sub(out, n->b, p + 1);
    break;
  }
  }
}

char *print_to_arena(Ctx *ctx, void (*print)(FILE *, const void *), const void *x) {
  char *buf = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&buf, &len);
  if (!f) error_plain(ctx, "out of memory");
  print(f, x);
  fclose(f);
  /* arena_alloc may jump out on allocation failure: npg_compile frees
   * the pending buffer then. */
  ctx->pending_free = buf;
  char *s = arena_strndup(ctx, buf ? buf : "", buf ? len : 0);
  ctx->pending_free = NULL;
  free(buf);
  return s;
}

static void print_node_cb(FILE *out, const void *n) { print_node(out, n); }

char *node_str(Ctx *ctx, const Node *n) { return print_to_arena(ctx, print_node_cb, n); }
