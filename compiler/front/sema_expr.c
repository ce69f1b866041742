/* sema_expr.c — checking and typing expressions (DESIGN §3): constants,
 * types and broadcasting, names (define before use), indexing, calls
 * (solve, roots, if, builtins; fn calls through sema_inline.c), sums,
 * powers and binary operators. */
#include <math.h>
#include <string.h>

#include "sema.h"

/* ---------------------------------------------------------------- constants */

/* Integer interval of a constant index expression, when it is known at
 * compile time (literals, sums with literal bounds, + - *). */
static bool int_range(const Node *n, long *lo, long *hi) {
  long a0, a1, b0, b1;
  switch (n->kind) {
  case N_NUM:
    if (!n->is_int) return false;
    *lo = *hi = (long)n->num;
    return true;
  case N_NAME:
    if (n->sym && n->sym->kind == SYM_SUMVAR && !n->sym->range && n->sym->body) {
      /* body holds the literal bounds as a 2-arg VEC (see check_sum) */
      *lo = (long)n->sym->body->args[0]->num;
      *hi = (long)n->sym->body->args[1]->num;
      return true;
    }
    return false;
  case N_NEG:
    if (!int_range(n->a, &a0, &a1)) return false;
    *lo = -a1;
    *hi = -a0;
    return true;
  case N_ADD:
  case N_SUB:
    if (!int_range(n->a, &a0, &a1) || !int_range(n->b, &b0, &b1)) return false;
    if (n->kind == N_ADD) *lo = a0 + b0, *hi = a1 + b1;
    else *lo = a0 - b1, *hi = a1 - b0;
    return true;
  case N_MUL: {
    if (!int_range(n->a, &a0, &a1) || !int_range(n->b, &b0, &b1)) return false;
    long c[4] = {a0 * b0, a0 * b1, a1 * b0, a1 * b1};
    *lo = *hi = c[0];
    for (int i = 1; i < 4; i++) {
      if (c[i] < *lo) *lo = c[i];
      if (c[i] > *hi) *hi = c[i];
    }
    return true;
  }
  default: return false;
  }
}

static long gcd(long a, long b) {
  if (a < 0) a = -a;
  if (b < 0) b = -b;
  while (b) {
    long t = a % b;
    a = b;
    b = t;
  }
  return a;
}

/* A rational exponent literal: 2, -1, (1/2), (-3/2), -(1/2). */
static bool rational_literal(const Node *n, long *p, long *q) {
  long a, b, c, d;
  switch (n->kind) {
  case N_NUM:
    if (!n->is_int || fabs(n->num) > 1e6) return false;
    *p = (long)n->num;
    *q = 1;
    return true;
  case N_RAT:
    *p = n->p;
    *q = n->q;
    return true;
  case N_NEG:
    if (!rational_literal(n->a, &a, &b)) return false;
    *p = -a;
    *q = b;
    return true;
  case N_DIV:
    if (!rational_literal(n->a, &a, &b) || !rational_literal(n->b, &c, &d) || c == 0) return false;
    *p = a * d;
    *q = b * c;
    if (*q < 0) *p = -*p, *q = -*q;
    long g = gcd(*p, *q);
    if (g > 1) *p /= g, *q /= g;
    return true;
  default: return false;
  }
}

/* ---------------------------------------------------------------- types */

static Type scalar_type(Var var) {
  Type t = {0};
  t.var = var;
  return t;
}

static Var max_var(Var a, Var b) { return a > b ? a : b; }

static bool same_static(const Type *a, const Type *b) {
  if (a->nstatic != b->nstatic) return false;
  for (int i = 0; i < a->nstatic; i++)
    if (a->shape[i] != b->shape[i]) return false;
  return true;
}

static bool same_whole(const Type *a, const Type *b) {
  if (a->nwhole != b->nwhole) return false;
  for (int i = 0; i < a->nwhole; i++)
    if (a->whole[i] != b->whole[i]) return false;
  return true;
}

/* The first varying quantity an expression reads, for messages. */
static const Sym *first_varying(const Node *n) {
  if (!n) return NULL;
  if ((n->kind == N_NAME || n->kind == N_INDEX) && n->sym &&
      (n->sym->kind == SYM_INPUT || n->sym->kind == SYM_STAGE || n->sym->kind == SYM_EXTERN) &&
      n->ty.var == V_VARYING)
    return n->sym;
  const Sym *s;
  if ((s = first_varying(n->a))) return s;
  if ((s = first_varying(n->b))) return s;
  if ((s = first_varying(n->c))) return s;
  for (int i = 0; i < n->nargs; i++)
    if ((s = first_varying(n->args[i]))) return s;
  return NULL;
}

void sema_expr_no_op_value(Checker *ck, const Node *n, const char *where) {
  if (n->ty.op)
    error_node(ck->ctx, n, "operator '%s' cannot be used %s: apply it with '%s * x', solve(%s, x) or root(%s, q) * x",
               n->ty.op->name, where, n->ty.op->name, n->ty.op->name, n->ty.op->name);
}

void sema_expr_no_whole(Checker *ck, const Node *n, const char *where) {
  if (n->ty.nwhole)
    error_node(ck->ctx, n, "'%s' is a whole quantity over %s; index it (%s[...]) %s", node_str(ck->ctx, n),
               sema_shape_str(ck->ctx, &n->ty), node_str(ck->ctx, n), where);
}

void sema_expr_no_bool(Checker *ck, const Node *n, const char *where) {
  if (n->ty.is_bool) error_node(ck->ctx, n, "a condition cannot be used %s; use if(cond, a, b)", where);
}

/* Elementwise broadcast of two value types (scalars broadcast over static
 * axes; whole quantities must agree on their dims). */
static Type broadcast(Checker *ck, const Node *at, const char *opname, const Node *a, const Node *b) {
  Type t = {0};
  const Type *x = &a->ty, *y = &b->ty;
  if (x->nwhole || y->nwhole) {
    if (x->nwhole && y->nwhole && !same_whole(x, y))
      error_node(ck->ctx, at, "shape mismatch in '%s': %s and %s", opname, sema_shape_str(ck->ctx, x), sema_shape_str(ck->ctx, y));
    if ((x->nwhole && !y->nwhole && y->var == V_VARYING) || (y->nwhole && !x->nwhole && x->var == V_VARYING))
      error_node(ck->ctx, at, "shape mismatch in '%s': %s and %s (index the whole quantity)", opname,
                 sema_shape_str(ck->ctx, x), sema_shape_str(ck->ctx, y));
    const Type *w = x->nwhole ? x : y;
    t.nwhole = w->nwhole;
    memcpy(t.whole, w->whole, sizeof t.whole);
  }
  if (x->nstatic == 0) {
    t.nstatic = y->nstatic;
    memcpy(t.shape, y->shape, sizeof t.shape);
  } else if (y->nstatic == 0 || same_static(x, y)) {
    t.nstatic = x->nstatic;
    memcpy(t.shape, x->shape, sizeof t.shape);
  } else {
    error_node(ck->ctx, at, "shape mismatch in '%s': %s and %s", opname, sema_shape_str(ck->ctx, x), sema_shape_str(ck->ctx, y));
  }
  t.var = max_var(x->var, y->var);
  t.is_int = x->is_int && y->is_int;
  return t;
}

/* ---------------------------------------------------------------- names */

/* Resolve an identifier: summation variables (innermost first), then the
 * index variables of the definition being checked, then globals. */
static Sym *resolve(Checker *ck, Node *n) {
  for (int i = ck->sums.n - 1; i >= 0; i--) {
    Sym *s = ck->sums.v[i];
    if (n->global_only && !strchr(s->name, '#')) continue;
    if (strcmp(s->name, n->name) == 0) return s;
  }
  if (ck->cur && !n->global_only)
    for (int i = 0; i < ck->cur->nivars; i++)
      if (ck->cur->ivars[i] && strcmp(ck->cur->ivars[i]->name, n->name) == 0) return ck->cur->ivars[i];
  return sema_find_global(ck, n->name);
}

static int order_of(Checker *ck, const Sym *s) { return s->id; }


static void type_name(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  Sym *s = resolve(ck, n);
  if (!s) {
    if (strcmp(n->name, "pi") == 0) {
      n->kind = N_NUM;
      n->num = 3.14159265358979323846;
      n->is_int = false;
      n->ty = scalar_type(V_CONST);
      return;
    }
    if (builtin_lookup(n->name))
      error_node(ctx, n, "'%s' is a builtin function: call it with arguments", n->name);
    error_node(ctx, n, "unknown name '%s'%s", n->name, sema_did_you_mean(ck, n->name, SUGGEST_VALUE));
  }
  n->sym = s;
  Type t = {0};
  switch (s->kind) {
  case SYM_DIM:
    t.var = V_CONST;
    t.is_int = true;
    break;
  case SYM_IVAR:
  case SYM_SUMVAR:
    t.var = V_CONST;
    t.is_int = true;
    break;
  case SYM_FN:
    error_node(ctx, n, "'%s' is a fn: call it with arguments, %s(...)", s->name, s->name);
  case SYM_FNARG:
    internal_error(ctx, __FILE__, __LINE__, "unsubstituted fn argument");
  case SYM_OP:
    if (ck->cur && order_of(ck, s) >= ck->cur_order)
      error_note(ctx, n->loc, s->loc, "defined here", "operator '%s' is used before its definition", s->name);
    t.var = V_VARYING;
    t.op = s;
    break;
  case SYM_PARAM:
  case SYM_INPUT:
  case SYM_STAGE:
  case SYM_EXTERN:
    if (s->kind != SYM_PARAM && s->kind != SYM_INPUT && ck->cur && order_of(ck, s) >= ck->cur_order) {
      if (s == ck->cur) error_node(ctx, n, "'%s' is used in its own definition", s->name);
      error_note(ctx, n->loc, s->loc, "defined here", "'%s' is used before its definition", s->name);
    }
    t.var = s->kind == SYM_PARAM ? V_PARAM : V_VARYING;
    if (s->kind == SYM_STAGE && s->body) t.var = s->body->ty.var;  /* a constant definition */
    t.is_int = s->is_int;
    t.nwhole = s->ndims;
    memcpy(t.whole, s->dims, sizeof t.whole);
    t.nstatic = s->nstatic;
    memcpy(t.shape, s->shape, sizeof t.shape);
    break;
  }
  n->ty = t;
}

/* ---------------------------------------------------------------- indexing */

static void check_index_arg(Checker *ck, Node *arg, const Sym *base, int axis) {
  Ctx *ctx = ck->ctx;
  sema_expr_no_op_value(ck, arg, "as an index");
  sema_expr_no_whole(ck, arg, "in an index");
  sema_expr_no_bool(ck, arg, "as an index");
  if (arg->ty.nstatic)
    error_node(ctx, arg, "an index must be a scalar, found a %s value", sema_shape_str(ctx, &arg->ty));
  if (arg->ty.var == V_VARYING) {
    const Sym *v = first_varying(arg);
    error_node(ctx, arg, "an index cannot depend on '%s', which varies: indices may use index variables, params and numbers",
               v ? v->name : "an input");
  }
  if (!arg->ty.is_int) {
    if (arg->kind == N_INDEX && arg->sym && arg->sym->kind == SYM_PARAM)
      error_node(ctx, arg, "gather through real param '%s': an index must be an integer (declare it int[...])",
                 arg->sym->name);
    error_node(ctx, arg, "an index must be an integer expression, found '%s'", node_str(ctx, arg));
  }
  if (!base) return;
  if (axis < base->ndims) {
    Sym *dim = base->dims[axis];
    if (arg->kind == N_NAME && arg->sym && (arg->sym->kind == SYM_IVAR || arg->sym->kind == SYM_SUMVAR) &&
        arg->sym->range && arg->sym->range != dim)
      error_node(ctx, arg, "index '%s' ranges over %s, but axis %d of '%s' has dim %s", arg->sym->name,
                 arg->sym->range->name, axis, base->name, dim->name);
    if (arg->kind == N_NAME && arg->sym && arg->sym->kind == SYM_DIM)
      error_node(ctx, arg, "index '%s' is a dim (a size), out of range for axis %d of '%s'; did you mean %s-1?",
                 arg->sym->name, axis, base->name, arg->sym->name);
    long lo, hi;
    if (int_range(arg, &lo, &hi) && lo < 0)
      error_node(ctx, arg, "index %ld is out of range for axis %d of '%s' (dim %s)", lo, axis, base->name, dim->name);
  } else {
    int size = base->shape[axis - base->ndims];
    long lo, hi;
    if (!int_range(arg, &lo, &hi))
      error_node(ctx, arg, "axis %d of '%s' is static (size %d): its index must be a constant, found '%s'", axis,
                 base->name, size, node_str(ctx, arg));
    if (lo < 0 || hi >= size)
      error_node(ctx, arg, "index %ld is out of range for axis %d of '%s' (size %d)", lo < 0 ? lo : hi, axis,
                 base->name, size);
  }
}

static void check_index(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  Node *base = n->a = sema_expr_check(ck, n->a);
  for (int i = 0; i < n->nargs; i++) n->args[i] = sema_expr_check(ck, n->args[i]);
  if (base->ty.op)
    error_node(ctx, n, "operator '%s' cannot be indexed: apply it with '%s * x' or solve(%s, x)", base->ty.op->name,
               base->ty.op->name, base->ty.op->name);
  sema_expr_no_bool(ck, base, "as a value");
  Type t = base->ty;
  if ((base->kind == N_NAME) && base->sym &&
      (base->sym->kind == SYM_PARAM || base->sym->kind == SYM_INPUT || base->sym->kind == SYM_STAGE ||
       base->sym->kind == SYM_EXTERN)) {
    Sym *q = base->sym;
    int naxes = q->ndims + q->nstatic;
    if (n->nargs > naxes) {
      if (naxes == 0) error_node(ctx, n, "'%s' is a scalar (%s) and cannot be indexed", q->name, sema_sym_type_str(ctx, q));
      error_node(ctx, n, "'%s' has %d ax%s (%s) but %d ind%s given", q->name, naxes, naxes == 1 ? "is" : "es",
                 sema_sym_type_str(ctx, q), n->nargs, n->nargs == 1 ? "ex is" : "ices are");
    }
    if (n->nargs < q->ndims)
      error_node(ctx, n, "'%s' has %d dim ax%s (%s): index all of them (only static axes may be left out)", q->name,
                 q->ndims, q->ndims == 1 ? "is" : "es", sema_sym_type_str(ctx, q));
    for (int i = 0; i < n->nargs; i++) check_index_arg(ck, n->args[i], q, i);
    n->sym = q;
    t.nwhole = 0;
    int used_static = n->nargs - q->ndims;
    t.nstatic = q->nstatic - used_static;
    for (int i = 0; i < t.nstatic; i++) t.shape[i] = q->shape[used_static + i];
    for (int i = 0; i < n->nargs; i++) t.var = max_var(t.var, n->args[i]->ty.var);
    n->ty = t;
    return;
  }
  /* Component selection of a vector-valued expression. */
  if (base->ty.nwhole)
    error_node(ctx, base, "'%s' is a whole quantity over %s and cannot be indexed here; define it as a stage first "
               "(name = %s) and index the stage", node_str(ctx, base), sema_shape_str(ctx, &base->ty), node_str(ctx, base));
  if (n->nargs > base->ty.nstatic)
    error_node(ctx, n, "too many indices: '%s' is a %s value", node_str(ctx, base), sema_shape_str(ctx, &base->ty));
  for (int i = 0; i < n->nargs; i++) {
    Node *arg = n->args[i];
    check_index_arg(ck, arg, NULL, 0);
    long lo, hi;
    if (!int_range(arg, &lo, &hi))
      error_node(ctx, arg, "a component index must be a constant, found '%s'", node_str(ctx, arg));
    if (lo < 0 || hi >= base->ty.shape[i])
      error_node(ctx, arg, "index %ld is out of range for a vector of size %d", lo < 0 ? lo : hi, base->ty.shape[i]);
  }
  t.nstatic = base->ty.nstatic - n->nargs;
  for (int i = 0; i < t.nstatic; i++) t.shape[i] = base->ty.shape[n->nargs + i];
  n->ty = t;
}

/* ---------------------------------------------------------------- calls */

static char *op_cols(Ctx *ctx, const Sym *op) {
  char *s = "";
  for (int i = op->nrow; i < op->nivars; i++) s = arena_printf(ctx, "%s%s%s", s, i > op->nrow ? ", " : "", op->ivars[i]->range->name);
  return s;
}

static bool op_square(const Sym *op) {
  if (op->nrow * 2 != op->nivars) return false;
  for (int i = 0; i < op->nrow; i++)
    if (op->ivars[i]->range != op->ivars[op->nrow + i]->range) return false;
  return true;
}

/* Operators are reduced with the result's basis on both axes (DESIGN §4),
 * which needs a square operator. */
static void check_op_power(Checker *ck, const Node *opn, const char *how) {
  Sym *op = opn->ty.op;
  if (!op_square(op))
    error_node(ck->ctx, opn,
               "operator '%s' is not square (rows [%s], columns [%s]) and cannot be %s: an operator is reduced with "
               "its result's basis on both axes; write the product as a sum over the columns instead",
               op->name, op->nrow ? op->ivars[0]->range->name : "", op_cols(ck->ctx, op), how);
}

static Node *check_solve(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  Node *m = n->args[0] = sema_expr_check(ck, n->args[0]);
  Node *x = n->args[1] = sema_expr_check(ck, n->args[1]);
  if (!m->ty.op)
    error_node(ctx, m, "solve() takes an operator declared with 'op' as its first argument; for elementwise division write a / b");
  Sym *op = m->ty.op;
  int nrow = op->nrow, ncol = op->nivars - op->nrow;
  if (!op_square(op)) error_node(ctx, m, "solve() needs a square operator, but '%s' is not square", op->name);
  sema_expr_no_op_value(ck, x, "as the right-hand side of solve()");
  const char *xs = node_str(ctx, x);
  if (!x->ty.nwhole || x->ty.nstatic)
    error_node(ctx, x, "the right-hand side of solve(%s, %s) must be a whole quantity over [%s], found %s", op->name, xs,
               op_cols(ctx, op), sema_shape_str(ctx, &x->ty));
  for (int i = 0; i < ncol; i++)
    if (x->ty.nwhole != ncol || x->ty.whole[i] != op->ivars[nrow + i]->range)
      error_node(ctx, x, "shape mismatch in solve(%s, %s): the columns of '%s' are [%s] but '%s' is %s", op->name, xs,
                 op->name, op_cols(ctx, op), xs, sema_shape_str(ctx, &x->ty));
  Type t = {0};
  t.var = V_VARYING;
  t.nwhole = nrow;
  for (int i = 0; i < nrow; i++) t.whole[i] = op->ivars[i]->range;
  n->builtin = B_SOLVE;
  n->ty = t;
  return n;
}

/* root(M, q) is M^(1/q): an operator value. */
static Node *check_root(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  Node *m = n->args[0] = sema_expr_check(ck, n->args[0]);
  Node *q = n->args[1] = sema_expr_check(ck, n->args[1]);
  if (!m->ty.op)
    error_node(ctx, m, "root() takes a square operator declared with 'op'; for an elementwise root write x^(1/2)");
  Sym *op = m->ty.op;
  if (!op_square(op)) error_node(ctx, m, "root() needs a square operator, but '%s' is not square", op->name);
  long p, d;
  if (!rational_literal(q, &p, &d) || d != 1 || p < 1)
    error_node(ctx, q, "the degree of root(M, q) must be a positive integer literal");
  Node *pw = new_node(ctx, N_POW, n->loc);
  pw->inl = n->inl;
  pw->a = m;
  pw->b = new_node(ctx, N_RAT, q->loc);
  pw->b->p = 1;
  pw->b->q = p;
  pw->ty = m->ty;
  return pw;
}

static void need_cond(Checker *ck, Node *c, const char *where) {
  Ctx *ctx = ck->ctx;
  if (!c->ty.is_bool)
    error_node(ctx, c, "%s must be a condition (a comparison), found '%s'", where, node_str(ctx, c));
  if (c->ty.var == V_VARYING) {
    const Sym *v = first_varying(c);
    error_node(ctx, c,
               "condition depends on '%s', which varies: conditions may use only index variables and params "
               "(a branch on an input's value is not an elementary algebraic operation; use 'extern')",
               v ? v->name : "an input");
  }
}

static Node *check_call(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  Sym *fn = sema_find_global(ck, n->name);
  if (fn && fn->kind == SYM_FN) return sema_inline_fn(ck, n, fn);
  if (fn) error_node(ctx, n, "'%s' is %s, not a function", n->name, sema_kind_word(fn));
  Builtin b = builtin_lookup(n->name);
  if (!b || b == B_SUMF) {
    if (strcmp(n->name, "sum") == 0) error_node(ctx, n, "sum needs the form sum(k = a..b, expr)");
    const char *module = sema_module_of_fn(ck, n->name);
    if (module)
      error_node(ctx, n, "unknown function '%s': it is a fn of the stdlib module %s, which this program does not use "
                 "(add 'use %s')", n->name, module, module);
    error_node(ctx, n, "unknown function '%s'%s", n->name, sema_did_you_mean(ck, n->name, SUGGEST_FUNCTION));
  }
  const BuiltinInfo *bi = &builtin_info[b];
  if (bi->arity >= 0 && n->nargs != bi->arity)
    error_node(ctx, n, "'%s' takes %d argument%s, but %d %s given", bi->name, bi->arity, bi->arity == 1 ? "" : "s",
               n->nargs, n->nargs == 1 ? "was" : "were");
  switch (b) {
  case B_SOLVE: return check_solve(ck, n);
  case B_ROOT: return check_root(ck, n);
  case B_SQRT: {
    Node *pw = new_node(ctx, N_POW, n->loc);
    pw->inl = n->inl;
    pw->a = n->args[0];
    pw->b = new_node(ctx, N_RAT, n->loc);
    pw->b->p = 1;
    pw->b->q = 2;
    return sema_expr_check(ck, pw);
  }
  case B_IFF: {
    Node *f = new_node(ctx, N_IF, n->loc);
    f->inl = n->inl;
    f->a = n->args[0];
    f->b = n->args[1];
    f->c = n->args[2];
    return sema_expr_check(ck, f);
  }
  default: break;
  }
  n->builtin = b;
  Type t = scalar_type(V_CONST);
  for (int i = 0; i < n->nargs; i++) {
    Node *a = n->args[i] = sema_expr_check(ck, n->args[i]);
    sema_expr_no_op_value(ck, a, arena_printf(ctx, "as an argument of %s()", bi->name));
    sema_expr_no_whole(ck, a, arena_printf(ctx, "in %s()", bi->name));
    sema_expr_no_bool(ck, a, arena_printf(ctx, "as an argument of %s()", bi->name));
    if (a->ty.var == V_VARYING && !bi->algebraic) {
      const Sym *v = first_varying(a);
      error_node(ctx, n,
                 "'%s' is not an elementary algebraic operation (+ - * / and rational powers), and '%s' varies: "
                 "compute it outside npg and declare it with 'extern'",
                 bi->name, v ? v->name : "its argument");
    }
    t.var = max_var(t.var, a->ty.var);
    if (a->ty.nstatic && b != B_DELTA) {
      if (t.nstatic && !same_static(&t, &a->ty))
        error_node(ctx, a, "shape mismatch in %s(): %s and %s", bi->name, sema_shape_str(ctx, &t), sema_shape_str(ctx, &a->ty));
      t.nstatic = a->ty.nstatic;
      memcpy(t.shape, a->ty.shape, sizeof t.shape);
    }
  }
  if (b == B_DELTA) {
    for (int i = 0; i < 2; i++) {
      if (!n->args[i]->ty.is_int || n->args[i]->ty.nstatic)
        error_node(ctx, n->args[i], "delta() compares two integer index expressions");
      if (n->args[i]->ty.var == V_VARYING)
        error_node(ctx, n->args[i], "delta() compares index expressions; they cannot depend on varying quantities");
    }
    t.nstatic = 0;
  }
  if (b == B_FLOOR) t.is_int = n->args[0]->ty.is_int;
  n->ty = t;
  return n;
}

/* ---------------------------------------------------------------- expressions */

/* The most copies of a body that nested sums with literal bounds unroll to. */
#define MAX_UNROLLED 100000
/* The most expression nodes the sums with literal bounds of a whole program unroll to (each sum's copies
 * times its body's nodes, its own nested literal sums counted by themselves). Lowering keeps about 0.75 kB
 * per unrolled node: five nested 0..9 sums over x[0]*a*e (10^5 copies of 6 nodes) took 1.0 s and 500 MB,
 * four over a 15-node body 0.45 s and 115 MB, so 2·10^5 nodes stay near 150 MB and half a second. */
#define MAX_UNROLLED_NODES 200000

/* The nodes of `n` lowering visits once per copy of the sum holding it: a nested sum with literal bounds
 * counts as one (its own body is counted when that sum is checked). */
static long unrolled_nodes(const Node *n, long limit) {
  if (!n || limit <= 0) return 0;
  if (n->kind == N_SUM && n->sym && n->sym->body) return 1;
  long c = 1 + unrolled_nodes(n->a, limit - 1);
  c += unrolled_nodes(n->b, limit - c);
  c += unrolled_nodes(n->c, limit - c);
  for (int i = 0; i < n->nargs && c < limit; i++) c += unrolled_nodes(n->args[i], limit - c);
  return c;
}

static Node *check_sum(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  n->a = sema_expr_check(ck, n->a);
  n->b = sema_expr_check(ck, n->b);
  for (int i = 0; i < 2; i++) {
    Node *bnd = i ? n->b : n->a;
    if (!bnd->ty.is_int || bnd->ty.var != V_CONST || bnd->ty.nstatic || bnd->ty.nwhole || bnd->ty.op)
      error_node(ctx, bnd, "the bounds of a sum must be integer expressions of numbers and dims, found '%s'",
                 node_str(ctx, bnd));
  }
  if (!strchr(n->name, '#')) {
    for (int i = 0; i < ck->sums.n; i++)
      if (strcmp(((Sym *)ck->sums.v[i])->name, n->name) == 0)
        error_node(ctx, n, "summation variable '%s' shadows the variable of an enclosing sum", n->name);
    if (ck->cur)
      for (int i = 0; i < ck->cur->nivars; i++)
        if (ck->cur->ivars[i] && strcmp(ck->cur->ivars[i]->name, n->name) == 0)
          error_node(ctx, n, "summation variable '%s' shadows the index variable '%s' of '%s'", n->name, n->name,
                     ck->cur->name);
  }
  Sym *v = sema_new_sym(ck, SYM_SUMVAR, n->name, n->loc);
  v->id = ++ctx->uniq;  /* distinct C names for generated loops */
  long lo, hi, lo2, hi2;
  if (int_range(n->a, &lo, &lo2) && int_range(n->b, &hi, &hi2) && lo == lo2 && hi == hi2) {
    if (hi < lo) error_node(ctx, n, "empty sum: the bounds %ld..%ld are inclusive and decreasing", lo, hi);
    if (hi - lo >= 4096) error_node(ctx, n, "a sum with literal bounds is unrolled; %ld..%ld is too long", lo, hi);
    /* Nested, they unroll to the product of their lengths: seven 0..9 sums
     * are 10^7 copies of the body, which exhausted 24 GB. 10^5 (five 0..9)
     * lowers in about a second. */
    double copies = (double)(hi - lo + 1);
    for (int i = 0; i < ck->sums.n; i++) {
      const Sym *o = ck->sums.v[i];
      if (o->body) copies *= o->body->args[1]->num - o->body->args[0]->num + 1;
    }
    if (copies > MAX_UNROLLED)
      error_node(ctx, n, "nested sums with literal bounds are unrolled: this one makes %.0f copies of its body, more "
                 "than %d; sum over a dim (0..D-1) instead", copies, MAX_UNROLLED);
    Node *bounds = new_node(ctx, N_VEC, n->loc);  /* remembered for int_range */
    bounds->nargs = 2;
    bounds->args = arena_alloc(ctx, sizeof(Node *) * 2);
    bounds->args[0] = new_num(ctx, (double)lo, true, n->loc);
    bounds->args[1] = new_num(ctx, (double)hi, true, n->loc);
    v->body = bounds;
  } else {
    /* Range over a dim when the bounds are 0..D-1. */
    if (n->a->kind == N_NUM && n->a->num == 0 && n->b->kind == N_SUB && n->b->a->kind == N_NAME &&
        n->b->a->sym && n->b->a->sym->kind == SYM_DIM && n->b->b->kind == N_NUM && n->b->b->num == 1)
      v->range = n->b->a->sym;
  }
  n->sym = v;
  vec_push(ctx, &ck->sums, v);
  n->c = sema_expr_check(ck, n->c);
  ck->sums.n--;
  if (v->body) { /* the program's unrolled work, bounded as one sum's length is */
    double copies = 1;
    for (int i = 0; i <= ck->sums.n; i++) {
      const Sym *o = i < ck->sums.n ? ck->sums.v[i] : v;
      if (o->body) copies *= o->body->args[1]->num - o->body->args[0]->num + 1;
    }
    double nodes = copies * (double)unrolled_nodes(n->c, MAX_UNROLLED_NODES + 1);
    ck->unrolled += nodes;
    if (nodes > MAX_UNROLLED_NODES)
      error_node(ctx, n, "nested sums with literal bounds are unrolled: this one makes %.0f copies of a body of %.0f "
                 "expression nodes, %.0f nodes, more than the %d a program may unroll; sum over a dim (0..D-1) instead",
                 copies, nodes / copies, nodes, MAX_UNROLLED_NODES);
    if (ck->unrolled > MAX_UNROLLED_NODES)
      error_node(ctx, n, "the sums with literal bounds of this program unroll to %.0f expression nodes (this one %.0f), "
                 "more than the %d a program may unroll; sum over a dim (0..D-1) instead, or name a repeated sum as a "
                 "stage", ck->unrolled, nodes, MAX_UNROLLED_NODES);
  }
  sema_expr_no_op_value(ck, n->c, "inside a sum");
  sema_expr_no_whole(ck, n->c, "inside a sum");
  sema_expr_no_bool(ck, n->c, "as the body of a sum");
  n->ty = n->c->ty;
  n->ty.is_int = n->c->ty.is_int;
  return n;
}

static Node *check_pow(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  n->a = sema_expr_check(ck, n->a);
  Node *e = n->b = sema_expr_check(ck, n->b);
  sema_expr_no_whole(ck, n->a, "before raising it to a power");
  sema_expr_no_bool(ck, n->a, "as a base");
  sema_expr_no_op_value(ck, e, "as an exponent");
  if (e->ty.var == V_VARYING) {
    const Sym *v = first_varying(e);
    error_node(ctx, e, "an exponent cannot depend on '%s', which varies (x^y is not algebraic; use 'extern')",
               v ? v->name : "an input");
  }
  if (e->ty.nstatic) error_node(ctx, e, "an exponent must be a scalar");
  if (n->a->ty.var != V_VARYING) {  /* a coefficient: any exponent */
    n->ty = n->a->ty;
    n->ty.var = max_var(n->a->ty.var, e->ty.var);
    n->ty.is_int = n->a->ty.is_int && e->kind == N_NUM && e->is_int && e->num >= 0;
    return n;
  }
  long p, q;
  if (e->kind == N_NUM && e->is_int && fabs(e->num) > 64)
    error_node(ctx, e, "exponent %s is too large (at most 64 in magnitude)", node_str(ctx, e));
  if (e->kind == N_DIV && e->b->kind == N_NUM && e->b->num == 0)
    error_node(ctx, e->b, "zero denominator in the exponent");
  if (!rational_literal(e, &p, &q)) {
    if (e->kind == N_NUM && e->is_int)
      error_node(ctx, e, "exponent %s is too large (at most 64 in magnitude)", node_str(ctx, e));
    if (e->kind == N_NUM)
      error_node(ctx, e, "non-integer exponent %s is not a rational literal: write it as a fraction, e.g. x^(1/2)",
                 node_str(ctx, e));
    error_node(ctx, e, "the exponent of a varying quantity must be an integer or rational literal such as 2, -1 or (1/2), found '%s'",
               node_str(ctx, e));
  }
  if (q > 64 || p > 64 || p < -64)
    error_node(ctx, e, "exponent %ld/%ld is too large (numerator and denominator at most 64)", p, q);
  Node *r = new_node(ctx, N_RAT, e->loc);
  r->p = p;
  r->q = q;
  r->ty = scalar_type(V_CONST);
  n->b = r;
  n->ty = n->a->ty;
  if (n->a->ty.op) {
    if (p == 0) error_node(ctx, e, "an operator to the power 0 is the identity; leave it out");
    check_op_power(ck, n->a, "raised to a power");
    return n;  /* an operator value M^(p/q) */
  }
  n->ty.is_int = false;
  return n;
}

/* The value of `n` when it is numbers joined by + − × ÷ and negation only
 * (1 - 1): a literal division by zero is an error, however it is written. */
static bool literal_value(const Node *n, double *v) {
  double a, b;
  switch (n->kind) {
  case N_NUM: *v = n->num; return true;
  case N_NEG: return literal_value(n->a, &a) && (*v = -a, true);
  case N_ADD: return literal_value(n->a, &a) && literal_value(n->b, &b) && (*v = a + b, true);
  case N_SUB: return literal_value(n->a, &a) && literal_value(n->b, &b) && (*v = a - b, true);
  case N_MUL: return literal_value(n->a, &a) && literal_value(n->b, &b) && (*v = a * b, true);
  case N_DIV: return literal_value(n->a, &a) && literal_value(n->b, &b) && b != 0 && (*v = a / b, true);
  default: return false;
  }
}

static Node *check_binary(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  Node *a = n->a = sema_expr_check(ck, n->a);
  Node *b = n->b = sema_expr_check(ck, n->b);
  const char *sym = node_kind_sym[n->kind];
  switch (n->kind) {
  case N_AND:
  case N_OR:
    for (int i = 0; i < 2; i++) {
      Node *x = i ? b : a;
      if (!x->ty.is_bool) error_node(ctx, x, "operands of '%s' must be conditions", sym);
    }
    n->ty = scalar_type(max_var(a->ty.var, b->ty.var));
    n->ty.is_bool = true;
    return n;
  case N_EQ: case N_NE: case N_LT: case N_LE: case N_GT: case N_GE:
    for (int i = 0; i < 2; i++) {
      Node *x = i ? b : a;
      sema_expr_no_op_value(ck, x, "in a comparison");
      sema_expr_no_whole(ck, x, "in a comparison");
      sema_expr_no_bool(ck, x, "in a comparison");
      if (x->ty.nstatic) error_node(ctx, x, "comparisons take scalars, found a %s value", sema_shape_str(ctx, &x->ty));
    }
    n->ty = scalar_type(max_var(a->ty.var, b->ty.var));
    n->ty.is_bool = true;
    return n;
  default: break;
  }
  sema_expr_no_bool(ck, a, arena_printf(ctx, "as an operand of '%s'", sym));
  sema_expr_no_bool(ck, b, arena_printf(ctx, "as an operand of '%s'", sym));
  if (n->kind == N_MUL && a->ty.op) {  /* operator application M * x */
    Sym *op = a->ty.op;
    int nrow = op->nrow, ncol = op->nivars - op->nrow;
    sema_expr_no_op_value(ck, b, "as the operand of an operator");
    if (b->ty.nwhole != ncol || b->ty.nstatic)
      error_node(ctx, b, "'%s * %s' needs a whole quantity over the operator's columns [%s], found %s", op->name,
                 node_str(ctx, b), op_cols(ctx, op), sema_shape_str(ctx, &b->ty));
    for (int i = 0; i < ncol; i++)
      if (b->ty.whole[i] != op->ivars[nrow + i]->range)
        error_node(ctx, b, "shape mismatch in '%s * %s': the columns of '%s' are [%s] but '%s' is %s", op->name,
                   node_str(ctx, b), op->name, op_cols(ctx, op), node_str(ctx, b), sema_shape_str(ctx, &b->ty));
    check_op_power(ck, a, "applied with '*'");
    Type t = {0};
    t.var = V_VARYING;
    t.nwhole = nrow;
    for (int i = 0; i < nrow; i++) t.whole[i] = op->ivars[i]->range;
    n->ty = t;
    return n;
  }
  if (b->ty.op) {
    if (n->kind == N_MUL)
      error_node(ctx, b, "operator '%s' must be on the left of '*' (M * x applies M to x)", b->ty.op->name);
    if (n->kind == N_DIV)
      error_node(ctx, b, "division by operator '%s': write solve(%s, x) to apply its inverse", b->ty.op->name, b->ty.op->name);
    error_node(ctx, b, "operators cannot be added or subtracted; declare an op whose entries are the sum");
  }
  if (a->ty.op) error_node(ctx, a, "operators cannot be added or subtracted; declare an op whose entries are the sum");
  n->ty = broadcast(ck, n, sym, a, b);
  if (n->kind == N_DIV) {
    n->ty.is_int = false;
    double v;
    if (literal_value(b, &v) && v == 0) error_node(ctx, b, "division by zero");
  }
  return n;
}

static Node *check_node(Checker *ck, Node *n);

Node *sema_expr_check(Checker *ck, Node *n) {
  if (n->checked) return n;
  n = check_node(ck, n);
  n->checked = true;
  return n;
}

static Node *check_node(Checker *ck, Node *n) {
  Ctx *ctx = ck->ctx;
  switch (n->kind) {
  case N_NUM:
    n->ty = scalar_type(V_CONST);
    n->ty.is_int = n->is_int;
    return n;
  case N_RAT:
    n->ty = scalar_type(V_CONST);
    return n;
  case N_NAME:
    type_name(ck, n);
    return n;
  case N_INDEX:
    check_index(ck, n);
    return n;
  case N_CALL: return check_call(ck, n);
  case N_SUM: return check_sum(ck, n);
  case N_POW: return check_pow(ck, n);
  case N_NEG:
    n->a = sema_expr_check(ck, n->a);
    sema_expr_no_op_value(ck, n->a, "with unary '-'");
    sema_expr_no_bool(ck, n->a, "with unary '-'");
    n->ty = n->a->ty;
    return n;
  case N_NOT:
    n->a = sema_expr_check(ck, n->a);
    if (!n->a->ty.is_bool) error_node(ctx, n, "'!' takes a condition");
    n->ty = n->a->ty;
    return n;
  case N_VEC: {
    Type t = {0};
    for (int i = 0; i < n->nargs; i++) {
      Node *c = n->args[i] = sema_expr_check(ck, n->args[i]);
      sema_expr_no_op_value(ck, c, "in a vector literal");
      sema_expr_no_whole(ck, c, "in a vector literal");
      sema_expr_no_bool(ck, c, "in a vector literal");
      if (i && !same_static(&t, &c->ty))
        error_node(ctx, c, "components of a vector literal must have one shape: %s and %s", sema_shape_str(ctx, &t),
                   sema_shape_str(ctx, &c->ty));
      if (i == 0) {
        t.nstatic = c->ty.nstatic;
        memcpy(t.shape, c->ty.shape, sizeof t.shape);
        t.is_int = c->ty.is_int;
      }
      t.var = max_var(t.var, c->ty.var);
      t.is_int = t.is_int && c->ty.is_int;
    }
    if (t.nstatic + 1 > MAX_STATIC) error_node(ctx, n, "vector literal nested too deeply (at most %d axes)", MAX_STATIC);
    memmove(t.shape + 1, t.shape, sizeof(int) * (size_t)t.nstatic);
    t.shape[0] = n->nargs;
    t.nstatic++;
    n->ty = t;
    return n;
  }
  case N_IF: {
    n->a = sema_expr_check(ck, n->a);
    need_cond(ck, n->a, "the first argument of if()");
    n->b = sema_expr_check(ck, n->b);
    n->c = sema_expr_check(ck, n->c);
    for (int i = 0; i < 2; i++) {
      Node *x = i ? n->c : n->b;
      sema_expr_no_op_value(ck, x, "in a branch of if()");
      sema_expr_no_bool(ck, x, "as a branch of if()");
    }
    n->ty = broadcast(ck, n, "if", n->b, n->c);
    n->ty.var = max_var(n->ty.var, n->a->ty.var);
    return n;
  }
  default: return check_binary(ck, n);
  }
}
