/* lower_expr.c — expressions to the canonical form of ir.h (DESIGN §4), for
 * ir/lower.c, which makes stages of them.
 *
 * An expression lowers to a Value: a sum of Terms, each a chain of operator
 * powers applied to a polynomial Field, one polynomial per static component.
 *
 *   a / b, b^(p/q)    diag(b)^(-1), diag(b)^(p/q) — b's value at each entry of
 *                     the result, broadcast over what b does not depend on;
 *                     an unnamed polynomial b is folded into the operator's
 *                     tensor, a named one is one atom (paper §4.1, Table 2)
 *   solve(M, x), M*x  the declared operator M to the power -1 or 1
 *   [a/b, c], if(..)  split by operator structure; operators act as the
 *                     identity on components where they do not apply
 *
 * Where a divisor or root base is not a single operator-free polynomial
 * term (1/(a + 1/b)), a stage "y.tN" is introduced for it and reported.
 * Coefficients (anything over params, numbers and index variables) stay
 * expression Nodes with the index variables substituted.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lower.h"

static Node *env_lookup(Env *env, Sym *s) {
  for (; env; env = env->next)
    if (env->var == s) return env->val;
  return NULL;
}

static Env *env_bind(Lowerer *L, Env *env, Sym *var, Node *val) {
  Env *e = arena_alloc(L->ctx, sizeof *e);
  e->var = var;
  e->val = val;
  e->next = env;
  return e;
}

static int type_ncomp(const Type *t) {
  int n = 1;
  for (int i = 0; i < t->nstatic; i++) n *= t->shape[i];
  return n;
}

static int static_ncomp(const int *shape, int n) {
  int c = 1;
  for (int i = 0; i < n; i++) c *= shape[i];
  return c;
}

/* Index variables used for a whole quantity: those of the definition. */
static Node *whole_index(Lowerer *L, Env *env, int axis) {
  iassert(L->ctx, L->cur && axis < L->cur->nivars);
  Sym *v = L->cur->ivars[axis];
  Node *bound = env_lookup(env, v);
  return bound ? bound : coef_name(L->ctx, v);
}

static Node *coef(Lowerer *L, Node *n, Env *env, int comp);

/* Component `comp` of quantity `q` (a param or a constant definition)
 * indexed by `args` (dim axes, then some static axes), as read by the
 * source node `use` (whose location and inlining it keeps). */
static Node *coef_entry(Lowerer *L, const Node *use, Sym *q, Node **args, int nargs, Env *env, int comp) {
  Ctx *ctx = L->ctx;
  /* static axes not given explicitly (a whole quantity, nargs = 0, gives none) */
  int given = nargs > q->ndims ? nargs - q->ndims : 0;
  int rest = q->nstatic - given;
  int idx_static[MAX_STATIC];
  /* Unflatten comp over the remaining static axes. */
  for (int i = q->nstatic - 1, c = comp; i >= q->nstatic - rest; i--) {
    idx_static[i] = c % q->shape[i];
    c /= q->shape[i];
  }
  if (q->kind == SYM_STAGE) {  /* constant definition: substitute */
    Env *e2 = NULL;
    for (int i = 0; i < q->ndims; i++)
      e2 = env_bind(L, e2, q->ivars[i], nargs ? coef(L, args[i], env, 0) : whole_index(L, env, i));
    int flat = 0;
    for (int i = 0; i < q->nstatic; i++) {
      int v = q->ndims + i < nargs ? (int)coef(L, args[q->ndims + i], env, 0)->num : idx_static[i];
      flat = flat * q->shape[i] + v;
    }
    return coef(L, q->body, e2, flat);
  }
  int nidx = q->ndims + q->nstatic;
  if (nidx == 0) return coef_name(L->ctx, q);
  Node *n = new_node(ctx, N_INDEX, use->loc); /* bind-time index errors point at the use */
  n->inl = use->inl;
  n->a = coef_name(L->ctx, q);
  n->sym = q;
  n->nargs = nidx;
  n->args = arena_alloc(ctx, sizeof(Node *) * (size_t)nidx);
  for (int i = 0; i < nidx; i++) {
    if (i < nargs) n->args[i] = coef(L, args[i], env, 0);
    else if (i < q->ndims) n->args[i] = whole_index(L, env, i);
    else n->args[i] = coef_num(L->ctx, idx_static[i - q->ndims]);
  }
  return n;
}

/* Flat component of a vector-valued base selected by constant indices. */
static int select_flat(Lowerer *L, const Node *n, Env *env, int comp) {
  const Type *bt = &n->a->ty;
  int flat = 0;
  for (int i = 0; i < bt->nstatic; i++) {
    int v;
    if (i < n->nargs) {
      Node *a = coef(L, n->args[i], env, 0);
      iassert(L->ctx, a->kind == N_NUM);
      v = (int)a->num;
    } else {
      int inner = static_ncomp(bt->shape + i + 1, bt->nstatic - i - 1);
      v = (comp / inner) % bt->shape[i];
    }
    flat = flat * bt->shape[i] + v;
  }
  return flat;
}

/* A coefficient expression (no inputs or stages), component `comp`, with
 * index variables substituted from `env`. */
static Node *coef(Lowerer *L, Node *n, Env *env, int comp) {
  Ctx *ctx = L->ctx;
  switch (n->kind) {
  case N_NUM:
  case N_RAT: return n;
  case N_NAME: {
    Sym *s = n->sym;
    iassert(ctx, s);
    if (s->kind == SYM_IVAR || s->kind == SYM_SUMVAR) {
      Node *v = env_lookup(env, s);
      return v ? v : coef_name(L->ctx, s);
    }
    if (s->kind == SYM_DIM) return coef_name(L->ctx, s);
    return coef_entry(L, n, s, NULL, 0, env, comp);
  }
  case N_INDEX:
    if (n->a->kind == N_NAME && n->sym && (n->sym->kind == SYM_PARAM || n->sym->kind == SYM_STAGE))
      return coef_entry(L, n, n->sym, n->args, n->nargs, env, comp);
    return coef(L, n->a, env, select_flat(L, n, env, comp));
  case N_VEC: {
    int per = type_ncomp(&n->args[0]->ty);
    return coef(L, n->args[comp / per], env, comp % per);
  }
  case N_NEG: return coef_neg(L->ctx, coef(L, n->a, env, comp));
  case N_NOT: return coef_not(L->ctx, coef(L, n->a, env, 0));
  case N_IF: {
    Node *c = new_node(ctx, N_IF, (Loc){0});
    c->a = coef(L, n->a, env, 0);
    c->b = coef(L, n->b, env, n->b->ty.nstatic ? comp : 0);
    c->c = coef(L, n->c, env, n->c->ty.nstatic ? comp : 0);
    return c;
  }
  case N_SUM: {
    Node *c = new_node(ctx, N_SUM, (Loc){0});
    c->name = n->sym->name;
    c->sym = n->sym;
    c->a = coef(L, n->a, env, 0);
    c->b = coef(L, n->b, env, 0);
    c->c = coef(L, n->c, env, comp);
    return c;
  }
  case N_CALL: {
    Node *c = new_node(ctx, N_CALL, (Loc){0});
    c->name = n->name;
    c->builtin = n->builtin;
    c->nargs = n->nargs;
    c->args = arena_alloc(ctx, sizeof(Node *) * (size_t)n->nargs);
    for (int i = 0; i < n->nargs; i++)
      c->args[i] = coef(L, n->args[i], env, n->args[i]->ty.nstatic ? comp : 0);
    return c;
  }
  default: {
    Node *a = coef(L, n->a, env, n->a->ty.nstatic ? comp : 0);
    Node *b = coef(L, n->b, env, n->b->ty.nstatic ? comp : 0);
    return coef_bin(L->ctx, n->kind, a, b);
  }
  }
}

#define MAX_MONOMIALS 200000

static Field *field_mul(Lowerer *L, const Field *a, const Field *b) {
  Field *f = field_new(L->ctx, a->ncomp);
  for (int c = 0; c < a->ncomp; c++) {
    if ((long)a->comp[c].n * (long)b->comp[c].n > MAX_MONOMIALS)
      error_at(L->ctx, L->cur->loc,
               "'%s' expands to more than %d monomials per entry; name intermediate quantities (each name is a basis "
               "and keeps tensor orders low, paper §4.2)", L->cur->name, MAX_MONOMIALS);
    f->comp[c] = poly_mul(L->ctx, &a->comp[c], &b->comp[c]);
  }
  return f;
}

/* ---------------------------------------------------------------- terms */

static Term *term_new(Lowerer *L, int ncomp) {
  Term *t = arena_alloc(L->ctx, sizeof *t);
  t->num = field_new(L->ctx, ncomp);
  return t;
}

static bool has_decl(const Term *t) {
  for (int k = 0; k < t->nops; k++)
    if (t->ops[k].kind == OPK_DECL) return true;
  return false;
}

static bool same_op(Lowerer *L, const OpPow *a, const OpPow *b, bool content) {
  if (a->kind != b->kind || a->p != b->p || a->q != b->q) return false;
  if (a->kind == OPK_DECL) return a->op == b->op;
  if (!content) return true;
  return strcmp(field_key(L->ctx, a->diag), field_key(L->ctx, b->diag)) == 0;
}

static bool same_ops(Lowerer *L, const Term *a, const Term *b, bool content) {
  if (a->nops != b->nops) return false;
  for (int k = 0; k < a->nops; k++)
    if (!same_op(L, &a->ops[k], &b->ops[k], content)) return false;
  return true;
}

static void rat_norm(long *p, long *q) {
  long a = *p < 0 ? -*p : *p, b = *q;
  while (b) {
    long t = a % b;
    a = b;
    b = t;
  }
  if (a > 1) *p /= a, *q /= a;
}

/* Combine equal diagonal operators, drop zero powers and fold non-negative
 * integer powers of diagonals into the polynomial (they are polynomial). */
static void normalize_term(Lowerer *L, Term *t) {
  if (!has_decl(t)) {
    for (int i = 0; i < t->nops; i++)
      for (int j = i + 1; j < t->nops; j++)
        if (strcmp(field_key(L->ctx, t->ops[i].diag), field_key(L->ctx, t->ops[j].diag)) == 0) {
          t->ops[i].p = t->ops[i].p * t->ops[j].q + t->ops[j].p * t->ops[i].q;
          t->ops[i].q *= t->ops[j].q;
          rat_norm(&t->ops[i].p, &t->ops[i].q);
          memmove(&t->ops[j], &t->ops[j + 1], sizeof(OpPow) * (size_t)(t->nops - j - 1));
          t->nops--;
          j--;
        }
  }
  for (int k = 0; k < t->nops; k++) {
    OpPow *o = &t->ops[k];
    bool inner = true;  /* no declared operator applied before it */
    for (int j = 0; j < k; j++)
      if (t->ops[j].kind == OPK_DECL) inner = false;
    if (o->kind == OPK_DIAG && o->q == 1 && o->p >= 0 && inner) {
      for (long i = 0; i < o->p; i++) t->num = field_mul(L, t->num, o->diag);
      memmove(o, o + 1, sizeof(OpPow) * (size_t)(t->nops - k - 1));
      t->nops--;
      k--;
    }
  }
}

static void push_op(Lowerer *L, Term *t, OpPow op) {
  OpPow *ops = arena_alloc(L->ctx, sizeof(OpPow) * (size_t)(t->nops + 1));
  if (t->nops) memcpy(ops, t->ops, sizeof(OpPow) * (size_t)t->nops);
  ops[t->nops++] = op;
  t->ops = ops;
}

static Term *term_copy(Lowerer *L, const Term *t) {
  Term *c = arena_alloc(L->ctx, sizeof *c);
  *c = *t;
  c->ops = arena_alloc(L->ctx, sizeof(OpPow) * (size_t)(t->nops + 1));
  if (t->nops) memcpy(c->ops, t->ops, sizeof(OpPow) * (size_t)t->nops);
  Field *num = field_new(L->ctx, t->num->ncomp);
  for (int i = 0; i < t->num->ncomp; i++) poly_add(L->ctx, &num->comp[i], &t->num->comp[i], NULL);
  c->num = num;
  return c;
}

/* ---------------------------------------------------------------- values */

static Value *val_new(Lowerer *L, int ncomp) {
  Value *v = arena_alloc(L->ctx, sizeof *v);
  v->ncomp = ncomp;
  return v;
}

/* Terms with the same operators are one term: add their polynomials. */
static Value *val_merge(Lowerer *L, Value *v) {
  Value *r = val_new(L, v->ncomp);
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = v->terms.v[i];
    bool zero = true;
    for (int c = 0; c < t->num->ncomp; c++) zero = zero && t->num->comp[c].n == 0;
    if (zero) continue;
    Term *into = NULL;
    for (int j = 0; j < r->terms.n && !into; j++)
      if (same_ops(L, r->terms.v[j], t, true)) into = r->terms.v[j];
    if (into) {
      for (int c = 0; c < t->num->ncomp; c++) poly_add(L->ctx, &into->num->comp[c], &t->num->comp[c], NULL);
    } else {
      vec_push(L->ctx, &r->terms, term_copy(L, t));
    }
  }
  return r;
}

static Field *field_broadcast(Lowerer *L, Field *f, int ncomp) {
  if (f->ncomp == ncomp) return f;
  iassert(L->ctx, f->ncomp == 1);
  Field *g = field_new(L->ctx, ncomp);
  for (int c = 0; c < ncomp; c++) poly_add(L->ctx, &g->comp[c], &f->comp[0], NULL);
  return g;
}

static Value *val_broadcast(Lowerer *L, Value *v, int ncomp) {
  if (v->ncomp == ncomp) return v;
  iassert(L->ctx, v->ncomp == 1);
  Value *r = val_new(L, ncomp);
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = term_copy(L, v->terms.v[i]);
    t->num = field_broadcast(L, t->num, ncomp);
    for (int k = 0; k < t->nops; k++)
      if (t->ops[k].kind == OPK_DIAG) t->ops[k].diag = field_broadcast(L, t->ops[k].diag, ncomp);
    vec_push(L->ctx, &r->terms, t);
  }
  return r;
}

static Value *val_coef(Lowerer *L, Node *n, Env *env, int ncomp) {
  Value *v = val_new(L, ncomp);
  Term *t = term_new(L, ncomp);
  for (int c = 0; c < ncomp; c++) {
    Node *k = coef(L, n, env, n->ty.nstatic ? c : 0);
    if (!coef_is_num(k, 0)) poly_push(L->ctx, &t->num->comp[c], mono_const(L->ctx, k));
  }
  vec_push(L->ctx, &v->terms, t);
  return val_merge(L, v);
}

static Value *val_add(Lowerer *L, Value *a, Value *b) {
  int n = a->ncomp > b->ncomp ? a->ncomp : b->ncomp;
  a = val_broadcast(L, a, n);
  b = val_broadcast(L, b, n);
  Value *r = val_new(L, n);
  for (int i = 0; i < a->terms.n; i++) vec_push(L->ctx, &r->terms, a->terms.v[i]);
  for (int i = 0; i < b->terms.n; i++) vec_push(L->ctx, &r->terms, b->terms.v[i]);
  return val_merge(L, r);
}

static Value *val_scale(Lowerer *L, Value *v, Node *k) {
  Value *r = val_new(L, v->ncomp);
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = term_copy(L, v->terms.v[i]);
    for (int c = 0; c < t->num->ncomp; c++)
      for (int m = 0; m < t->num->comp[c].n; m++) {
        Mono *x = mono_copy(L->ctx, t->num->comp[c].m[m]);
        x->coef = coef_bin(L->ctx, N_MUL, k, x->coef);
        t->num->comp[c].m[m] = x;
      }
    vec_push(L->ctx, &r->terms, t);
  }
  return r;
}

static bool val_is_coef(const Value *v) {
  for (int i = 0; i < v->terms.n; i++) {
    const Term *t = v->terms.v[i];
    if (t->nops || !field_is_coef(t->num)) return false;
  }
  return true;
}

static Value *val_mul(Lowerer *L, Value *a, Value *b, const Node *at) {
  int n = a->ncomp > b->ncomp ? a->ncomp : b->ncomp;
  a = val_broadcast(L, a, n);
  b = val_broadcast(L, b, n);
  Value *r = val_new(L, n);
  for (int i = 0; i < a->terms.n; i++)
    for (int j = 0; j < b->terms.n; j++) {
      Term *s = a->terms.v[i], *t = b->terms.v[j];
      if ((has_decl(s) && !val_is_coef(b)) || (has_decl(t) && !val_is_coef(a)))
        error_node(L->ctx, at,
                   "the result of an operator (solve(), M * x) cannot be multiplied or divided elementwise by a "
                   "varying quantity; define it as a stage first and index it");
      Term *p = term_new(L, n);
      p->nops = 0;
      for (int k = 0; k < s->nops; k++) push_op(L, p, s->ops[k]);
      for (int k = 0; k < t->nops; k++) push_op(L, p, t->ops[k]);
      p->num = field_mul(L, s->num, t->num);
      normalize_term(L, p);
      vec_push(L->ctx, &r->terms, p);
    }
  return val_merge(L, r);
}

/* ---------------------------------------------------------------- introduced stages */

static bool mono_uses(const Mono *m, const Sym *s) {
  if (node_uses(m->guard, s) || node_uses(m->coef, s)) return true;
  for (int i = 0; i < m->nsums; i++)
    if (node_uses(m->sums[i].lo, s) || node_uses(m->sums[i].hi, s)) return true;
  for (int a = 0; a < m->natoms; a++)
    for (int i = 0; i < m->atoms[a].nidx; i++)
      if (node_uses(m->atoms[a].idx[i], s)) return true;
  return false;
}

static bool field_uses(const Field *f, const Sym *s) {
  for (int c = 0; c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++)
      if (mono_uses(f->comp[c].m[i], s)) return true;
  return false;
}

static bool value_uses(const Value *v, const Sym *s) {
  for (int i = 0; i < v->terms.n; i++) {
    const Term *t = v->terms.v[i];
    if (field_uses(t->num, s)) return true;
    for (int k = 0; k < t->nops; k++)
      if (t->ops[k].kind == OPK_DIAG && field_uses(t->ops[k].diag, s)) return true;
  }
  return false;
}

/* What an introduced stage `s` that names a whole `op` entry over two or
 * more of its index variables costs, and the cure (the note of `npgc
 * check`, and training's message when it does not fit in memory). */
const char *lower_dense_entry_cure(Ctx *ctx, const Sym *s) {
  char dims[128] = "";
  size_t len = 0;
  for (int i = 0; i < s->nivars && len + 40 < sizeof dims; i++)
    len += (size_t)snprintf(dims + len, sizeof dims - len, "%s%s", i ? " x " : "", s->dims[i]->name);
  return arena_printf(ctx, "stage '%s' names a whole entry of op '%s' (a division or root inside it whose base "
                      "depends on every index of the entry), so it is %s, and '%s' is dense: a base over fewer "
                      "indices (`a[i] / h[i]`, `a[i] / (h[i] + g[i])`) is named elementwise and keeps '%s' sparse; "
                      "divide by a quantity of the row or the column alone",
                      s->name, s->introduced_for->name, dims, s->introduced_for->name, s->introduced_for->name);
}

/* Name a non-polynomial divisor (or root base) as a stage "cur.tN" over the
 * index variables it uses (DESIGN §4), and return its entries. */
Value *lower_expr_introduce(Lowerer *L, Value *v, const Node *at, PtrVec *open_sums) {
  Ctx *ctx = L->ctx;
  for (int i = 0; open_sums && i < open_sums->n; i++)
    if (value_uses(v, open_sums->v[i]))
      error_node(ctx, at,
                 "this non-polynomial divisor depends on the summation variable '%s'; define the summand as a "
                 "stage over that index",
                 ((Sym *)open_sums->v[i])->name);
  Sym *s = arena_alloc(ctx, sizeof *s);
  s->kind = SYM_STAGE;
  s->name = arena_printf(ctx, "%s.t%d", L->cur->name, ++L->nintro);
  s->loc = at->loc;
  s->introduced = true;
  s->introduced_at = at->loc;
  s->introduced_for = L->cur;
  s->basis_max = s->basis_energy = -1;
  s->basis_center = -1;
  /* no `basis m_x:` of its own either (0 read as center=off: introduced stages were trained uncentered) */
  s->class_basis_max = -1, s->class_basis_energy = -1, s->class_basis_center = -1;
  s->klass = -1;
  s->id = L->cur->id;  /* evaluated just before its user */
  for (int i = 0; i < L->cur->nivars; i++)
    if (value_uses(v, L->cur->ivars[i])) {
      s->ivars[s->nivars] = L->cur->ivars[i];
      s->dims[s->nivars] = L->cur->ivars[i]->range;
      s->nivars++;
    }
  s->ndims = s->nivars;
  if (v->ncomp > 1) {
    s->nstatic = 1;
    s->shape[0] = v->ncomp;
  }
  s->body = (Node *)at;
  Stage *st = lower_stage(L, s, v);
  s->stage = st;
  vec_push(ctx, &L->prog->stages, st);
  vec_push(ctx, &L->prog->notes,
           arena_printf(ctx, "%s:%d:%d: stage '%s' introduced for '%s': a divisor or root whose value is not one polynomial term",
                        at->loc.file ? at->loc.file->name : "?", at->loc.line, at->loc.col, s->name, node_str(ctx, at)));
  /* an `op` entry named whole over two of its index variables: an N × N stage, and the op
   * dense (issue 38: at 40,000 unknowns "needs 12.8 GB"); say so, and the cure */
  if (L->cur->kind == SYM_OP && s->nivars >= 2)
    vec_push(ctx, &L->prog->notes,
             arena_printf(ctx, "%s:%d:%d: %s", at->loc.file ? at->loc.file->name : "?", at->loc.line, at->loc.col,
                          lower_dense_entry_cure(ctx, s)));
  Value *r = val_new(L, v->ncomp);
  Term *t = term_new(L, v->ncomp);
  for (int c = 0; c < v->ncomp; c++) {
    Mono *m = mono_const(ctx, coef_num(L->ctx, 1));
    m->natoms = 1;
    m->atoms = arena_alloc(ctx, sizeof(Atom));
    m->atoms[0].q = s;
    m->atoms[0].nidx = s->nivars + s->nstatic;
    m->atoms[0].idx = arena_alloc(ctx, sizeof(Node *) * (size_t)(m->atoms[0].nidx + 1));
    for (int i = 0; i < s->nivars; i++) m->atoms[0].idx[i] = coef_name(L->ctx, s->ivars[i]);
    if (s->nstatic) m->atoms[0].idx[s->nivars] = coef_num(L->ctx, c);
    poly_push(ctx, &t->num->comp[c], m);
  }
  vec_push(ctx, &r->terms, t);
  return r;
}

/* ---------------------------------------------------------------- op entries kept sparse */

/* The conjuncts of guard `g` (an && chain) into `out` as text, at most `cap`; their number. */
static int conjuncts(Ctx *ctx, const Node *g, const char **out, int n, int cap) {
  if (!g) return n;
  if (g->kind == N_AND) return conjuncts(ctx, g->b, out, conjuncts(ctx, g->a, out, n, cap), cap);
  if (n < cap) out[n] = node_str(ctx, g);
  return n + 1;
}

static bool listed(const char *s, const char *const *list, int n) {
  for (int i = 0; i < n; i++)
    if (strcmp(s, list[i]) == 0) return true;
  return false;
}

#define MAX_CONJUNCTS 32

/* Base `d` of a diagonal power taken where numerator `num` can be nonzero: there every guard all of
 * num's monomials carry holds (dropped from d's monomials) and its negation fails (a monomial guarded
 * by it, the identity an if's other branch put in the base, dropped). NULL when a guard has more
 * conjuncts than this reads. */
static Field *base_on_support(Lowerer *L, const Field *num, const Field *d) {
  Ctx *ctx = L->ctx;
  const char *common[MAX_CONJUNCTS], *mine[MAX_CONJUNCTS];
  int ncommon = -1;
  for (int c = 0; c < num->ncomp; c++)
    for (int i = 0; i < num->comp[c].n; i++) {
      int n = conjuncts(ctx, num->comp[c].m[i]->guard, mine, 0, MAX_CONJUNCTS);
      if (n > MAX_CONJUNCTS) return NULL;
      if (ncommon < 0) {
        memcpy(common, mine, sizeof(char *) * (size_t)n);
        ncommon = n;
        continue;
      }
      int k = 0;
      for (int j = 0; j < ncommon; j++)
        if (listed(common[j], mine, n)) common[k++] = common[j];
      ncommon = k;
    }
  if (ncommon < 0) ncommon = 0;
  Field *out = field_new(ctx, d->ncomp);
  for (int c = 0; c < d->ncomp; c++)
    for (int i = 0; i < d->comp[c].n; i++) {
      const Mono *m = d->comp[c].m[i];
      const char *part[MAX_CONJUNCTS];
      int n = conjuncts(ctx, m->guard, part, 0, MAX_CONJUNCTS);
      if (n > MAX_CONJUNCTS) return NULL;
      bool contradicts = false;
      Node *guard = NULL;
      const Node *rest[MAX_CONJUNCTS];
      int nrest = 0;
      /* the conjuncts as nodes again, in the order conjuncts() read them */
      const Node *stack[2 * MAX_CONJUNCTS + 2];
      int top = 0;
      if (m->guard) stack[top++] = m->guard;
      while (top) {
        const Node *g = stack[--top];
        if (g->kind == N_AND && top + 2 <= 2 * MAX_CONJUNCTS + 2) {
          stack[top++] = g->b, stack[top++] = g->a;
          continue;
        }
        if (nrest < MAX_CONJUNCTS) rest[nrest++] = g;
      }
      for (int j = 0; j < nrest && !contradicts; j++) {
        const char *text = node_str(ctx, rest[j]);
        if (listed(text, common, ncommon)) continue; /* holds wherever num is nonzero */
        if (rest[j]->kind == N_NOT && listed(node_str(ctx, rest[j]->a), common, ncommon)) contradicts = true;
        else guard = coef_and(ctx, guard, (Node *)rest[j]);
      }
      if (contradicts) continue;
      Mono *copy = arena_alloc(ctx, sizeof *copy);
      *copy = *m;
      copy->guard = guard;
      poly_push(ctx, &out->comp[c], copy);
    }
  return out;
}

Value *lower_expr_op_entries(Lowerer *L, Value *v, const Node *at) {
  Ctx *ctx = L->ctx;
  /* first every term's power and whether it saves anything, then the stages: none introduced
   * for entries that end up named whole */
  Value **power = arena_alloc(ctx, sizeof(Value *) * (size_t)(v->terms.n + 1));
  const char **key = arena_alloc(ctx, sizeof(char *) * (size_t)(v->terms.n + 1));
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = v->terms.v[i];
    if (!t->nops) continue;
    if (has_decl(t)) return NULL;
    Term *pt = term_new(L, v->ncomp);
    pt->num = field_ones(ctx, v->ncomp);
    key[i] = arena_printf(ctx, "%d", t->nops);
    for (int k = 0; k < t->nops; k++) {
      Field *d = base_on_support(L, t->num, t->ops[k].diag);
      if (!d) return NULL;
      push_op(L, pt, (OpPow){OPK_DIAG, d, NULL, t->ops[k].p, t->ops[k].q});
      key[i] = arena_printf(ctx, "%s|%ld/%ld:%s", key[i], t->ops[k].p, t->ops[k].q, field_key(ctx, d));
    }
    power[i] = val_new(L, v->ncomp);
    vec_push(ctx, &power[i]->terms, pt);
    int uses = 0;
    for (int k = 0; k < L->cur->nivars; k++) uses += value_uses(power[i], L->cur->ivars[k]);
    if (uses >= L->cur->nivars) return NULL; /* the power spans the whole entry: nothing gained */
  }
  Value *out = val_new(L, v->ncomp);
  Value **named = arena_alloc(ctx, sizeof(Value *) * (size_t)(v->terms.n + 1));
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = v->terms.v[i];
    if (!t->nops) {
      vec_push(ctx, &out->terms, t);
      continue;
    }
    for (int k = 0; k < i && !named[i]; k++) /* one stage per distinct power: the neighbours' 1 / h[i] once */
      if (named[k] && strcmp(key[k], key[i]) == 0) named[i] = named[k];
    if (!named[i]) {
      named[i] = lower_expr_introduce(L, power[i], at, NULL);
      /* its note says what it is: the introduced stage is the last one, its note the last */
      const Sym *s = ((Stage *)L->prog->stages.v[L->prog->stages.n - 1])->sym;
      char over[128] = "";
      size_t len = 0;
      for (int k = 0; k < s->nivars && len + 40 < sizeof over; k++)
        len += (size_t)snprintf(over + len, sizeof over - len, "%s%s", k ? ", " : "", s->ivars[k]->name);
      if (s->nivars < 2) /* else the last note is the dense entry's (lower_expr_introduce) */
        L->prog->notes.v[L->prog->notes.n - 1] =
            arena_printf(ctx, "%s:%d:%d: stage '%s' introduced for a division or root inside the entries of op '%s', "
                         "over %s alone (its base where the entry can be nonzero), so '%s' keeps its pattern",
                         at->loc.file ? at->loc.file->name : "?", at->loc.line, at->loc.col, s->name, L->cur->name,
                         s->nivars ? over : "no index", L->cur->name);
    }
    Term *p = term_new(L, v->ncomp);
    p->num = field_mul(L, t->num, ((Term *)named[i]->terms.v[0])->num);
    vec_push(ctx, &out->terms, p);
  }
  return val_merge(L, out);
}

/* v^(p/q) for a non-integer or negative power: diag operators. */

static Value *val_pow_diag(Lowerer *L, Value *b, long p, long q, const Node *at) {
  if (b->terms.n == 0)
    error_node(L->ctx, at, "division by (or negative power of) an expression that is identically zero");
  if (b->terms.n != 1 || has_decl(b->terms.v[0])) b = lower_expr_introduce(L, b, at, L->open_sums);
  Term *bt = b->terms.v[0];
  Term *t = term_new(L, b->ncomp);
  t->num = field_ones(L->ctx, b->ncomp);
  push_op(L, t, (OpPow){OPK_DIAG, bt->num, NULL, p, q});
  for (int k = 0; k < bt->nops; k++) {
    OpPow o = bt->ops[k];
    o.p *= p;
    o.q *= q;
    rat_norm(&o.p, &o.q);
    push_op(L, t, o);
  }
  normalize_term(L, t);
  Value *r = val_new(L, b->ncomp);
  vec_push(L->ctx, &r->terms, t);
  return r;
}

/* ---------------------------------------------------------------- pieces (vectors, if) */

typedef struct Piece {
  Value *v;
  Node *guard;
  int off;
} Piece;

/* Assemble values that cover component ranges (vector literal) or the same
 * components under complementary guards (if): terms with the same operator
 * structure become one term; an operator acts as the identity where its
 * term does not apply ([a/b, c] = diag([b, 1])^-1 [a, 0] + [0, c]). */
static Value *assemble(Lowerer *L, Piece *ps, int np, int ncomp) {
  Ctx *ctx = L->ctx;
  PtrVec rs = {0};       /* Term* */
  PtrVec filled = {0};   /* bool[np] per result term */
  for (int p = 0; p < np; p++) {
    Value *v = ps[p].v;
    for (int i = 0; i < v->terms.n; i++) {
      Term *t = v->terms.v[i];
      int r = -1;
      for (int j = 0; j < rs.n && r < 0; j++)
        if (!((bool *)filled.v[j])[p] && same_ops(L, rs.v[j], t, false)) r = j;
      if (r < 0) {
        Term *nt = term_new(L, ncomp);
        for (int k = 0; k < t->nops; k++) {
          OpPow o = t->ops[k];
          if (o.kind == OPK_DIAG) o.diag = field_new(ctx, ncomp);
          push_op(L, nt, o);
        }
        vec_push(ctx, &rs, nt);
        vec_push(ctx, &filled, arena_alloc(ctx, sizeof(bool) * (size_t)np));
        r = rs.n - 1;
      }
      Term *R = rs.v[r];
      ((bool *)filled.v[r])[p] = true;
      for (int c = 0; c < v->ncomp; c++) {
        poly_add(L->ctx, &R->num->comp[ps[p].off + c], &t->num->comp[c], ps[p].guard);
        for (int k = 0; k < t->nops; k++)
          if (t->ops[k].kind == OPK_DIAG) poly_add(L->ctx, &R->ops[k].diag->comp[ps[p].off + c], &t->ops[k].diag->comp[c], ps[p].guard);
      }
    }
  }
  Value *out = val_new(L, ncomp);
  for (int r = 0; r < rs.n; r++) {
    Term *R = rs.v[r];
    for (int p = 0; p < np; p++) {
      if (((bool *)filled.v[r])[p]) continue;
      for (int c = 0; c < ps[p].v->ncomp; c++)
        for (int k = 0; k < R->nops; k++)
          if (R->ops[k].kind == OPK_DIAG) {
            Mono *one = mono_const(ctx, coef_num(L->ctx, 1));
            one->guard = ps[p].guard;
            poly_push(ctx, &R->ops[k].diag->comp[ps[p].off + c], one);
          }
    }
    normalize_term(L, R);
    vec_push(ctx, &out->terms, R);
  }
  return val_merge(L, out);
}

/* The value whose component j is component src[j] of v. */
static Value *val_pick(Lowerer *L, const Value *v, int ncomp, const int *src) {
  Value *r = val_new(L, ncomp);
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = v->terms.v[i];
    Term *c = term_new(L, ncomp);
    for (int k = 0; k < t->nops; k++) {
      OpPow o = t->ops[k];
      if (o.kind == OPK_DIAG) {
        Field *d = field_new(L->ctx, ncomp);
        for (int j = 0; j < ncomp; j++) poly_add(L->ctx, &d->comp[j], &t->ops[k].diag->comp[src[j]], NULL);
        o.diag = d;
      }
      push_op(L, c, o);
    }
    for (int j = 0; j < ncomp; j++) poly_add(L->ctx, &c->num->comp[j], &t->num->comp[src[j]], NULL);
    vec_push(L->ctx, &r->terms, c);
  }
  return val_merge(L, r);
}

/* ---------------------------------------------------------------- references */

/* Entries of a varying quantity q: q[args...] with the remaining static
 * axes enumerated; a whole reference (nargs < ndims) uses the definition's
 * index variables. */
static Value *ref_value(Lowerer *L, Sym *q, Node **args, int nargs, Env *env) {
  Ctx *ctx = L->ctx;
  int given_static = nargs > q->ndims ? nargs - q->ndims : 0;
  int rest = q->nstatic - given_static;
  int ncomp = static_ncomp(q->shape + given_static, rest);
  Node **dimidx = arena_alloc(ctx, sizeof(Node *) * (size_t)(q->ndims + 1));
  for (int i = 0; i < q->ndims; i++) dimidx[i] = nargs ? coef(L, args[i], env, 0) : whole_index(L, env, i);
  int fixed[MAX_STATIC];
  for (int i = 0; i < given_static; i++) {
    Node *a = coef(L, args[q->ndims + i], env, 0);
    iassert(ctx, a->kind == N_NUM);
    fixed[i] = (int)a->num;
  }
  if (q->inlined) {  /* `inline q`: its definition, substituted */
    Env *e2 = NULL;
    for (int i = 0; i < q->ndims; i++) e2 = env_bind(L, e2, q->ivars[i], dimidx[i]);
    Sym *saved = L->cur;
    Value *full = lower_expr(L, q->body, e2);
    L->cur = saved;
    if (given_static == 0) return full;
    int base = 0;
    for (int i = 0; i < given_static; i++) base = base * q->shape[i] + fixed[i];
    int *src = arena_alloc(ctx, sizeof(int) * (size_t)ncomp);
    for (int j = 0; j < ncomp; j++) src[j] = base * ncomp + j;
    return val_pick(L, full, ncomp, src);
  }
  Value *v = val_new(L, ncomp);
  Term *t = term_new(L, ncomp);
  for (int c = 0; c < ncomp; c++) {
    Mono *m = mono_const(ctx, coef_num(L->ctx, 1));
    m->natoms = 1;
    m->atoms = arena_alloc(ctx, sizeof(Atom));
    Atom *a = &m->atoms[0];
    a->q = q;
    a->nidx = q->ndims + q->nstatic;
    a->idx = arena_alloc(ctx, sizeof(Node *) * (size_t)(a->nidx + 1));
    for (int i = 0; i < q->ndims; i++) a->idx[i] = dimidx[i];
    for (int i = 0; i < given_static; i++) a->idx[q->ndims + i] = coef_num(L->ctx, fixed[i]);
    for (int i = q->nstatic - 1, cc = c; i >= given_static; i--) {
      a->idx[q->ndims + i] = coef_num(L->ctx, cc % q->shape[i]);
      cc /= q->shape[i];
    }
    poly_push(ctx, &t->num->comp[c], m);
  }
  vec_push(ctx, &v->terms, t);
  return v;
}

/* The operator and power of an operator value: M, M^(p/q), root(M, q). */
static Sym *op_value(Lowerer *L, Node *n, long *p, long *q) {
  if (n->kind == N_NAME) {
    *p = *q = 1;
    return n->sym;
  }
  iassert(L->ctx, n->kind == N_POW && n->b->kind == N_RAT);
  Sym *op = op_value(L, n->a, p, q);
  *p *= n->b->p;
  *q *= n->b->q;
  rat_norm(p, q);
  return op;
}

static Value *apply_op(Lowerer *L, Sym *op, long p, long q, Value *x) {
  op->applied = true;
  Value *r = val_new(L, x->ncomp);
  for (int i = 0; i < x->terms.n; i++) {
    Term *t = term_copy(L, x->terms.v[i]);
    push_op(L, t, (OpPow){OPK_DECL, NULL, op, p, q});
    vec_push(L->ctx, &r->terms, t);
  }
  return val_merge(L, r);
}

/* ---------------------------------------------------------------- expressions */

static Value *lower_sum(Lowerer *L, Node *n, Env *env) {
  Ctx *ctx = L->ctx;
  Sym *v = n->sym;
  if (v->body) {  /* literal bounds: unrolled */
    long lo = (long)v->body->args[0]->num, hi = (long)v->body->args[1]->num;
    Value *acc = NULL;
    for (long k = lo; k <= hi; k++) {
      Value *term = lower_expr(L, n->c, env_bind(L, env, v, coef_num(L->ctx, (double)k)));
      acc = acc ? val_add(L, acc, term) : term;
    }
    return acc;
  }
  vec_push(ctx, L->open_sums, v);
  Value *body = lower_expr(L, n->c, env);
  L->open_sums->n--;
  SumVar sv = {v, coef(L, n->a, env, 0), coef(L, n->b, env, 0)};
  Value *r = val_new(L, body->ncomp);
  for (int i = 0; i < body->terms.n; i++) {
    Term *t = term_copy(L, body->terms.v[i]);
    for (int k = 0; k < t->nops; k++)
      if (t->ops[k].kind == OPK_DIAG && field_uses(t->ops[k].diag, v))
        error_node(ctx, n,
                   "a divisor inside this sum depends on the summation variable '%s'; define the summand as a stage",
                   v->name);
    for (int c = 0; c < t->num->ncomp; c++)
      for (int m = 0; m < t->num->comp[c].n; m++) {
        Mono *x = mono_copy(L->ctx, t->num->comp[c].m[m]);
        x->sums[x->nsums++] = sv;
        t->num->comp[c].m[m] = x;
      }
    vec_push(ctx, &r->terms, t);
  }
  return r;
}

/* Whether `n`, an expression over params and index variables in the entries of the operator
 * being lowered, holds a sum whose body reads one of the operator's column indices: a padded
 * row table (`sum(q = 0..W-1, delta(j, col[i, q]) * val[i, q])`). Such an expression is lowered
 * term by term instead of folded into one coefficient, so the sum stays a monomial's sum and
 * the delta fixes the column: the operator is then sparse, W entries per row (DESIGN §13). */
static bool op_row_table(const Lowerer *L, const Node *n) {
  const Sym *op = L->cur;
  if (!op || op->kind != SYM_OP || !n) return false;
  switch (n->kind) {
  case N_SUM:
    for (int c = op->nrow; c < op->nivars; c++)
      if (node_uses(n->c, op->ivars[c])) return true;
    return false;
  case N_ADD: case N_SUB: case N_MUL: return op_row_table(L, n->a) || op_row_table(L, n->b);
  case N_NEG: return op_row_table(L, n->a);
  default: return false;
  }
}

Value *lower_expr(Lowerer *L, Node *n, Env *env) {
  Ctx *ctx = L->ctx;
  int ncomp = type_ncomp(&n->ty);
  if (n->ty.var != V_VARYING && !n->ty.op && !op_row_table(L, n)) return val_coef(L, n, env, ncomp);
  switch (n->kind) {
  case N_NAME: return ref_value(L, n->sym, NULL, 0, env);
  case N_INDEX:
    if (n->a->kind == N_NAME && n->sym &&
        (n->sym->kind == SYM_INPUT || n->sym->kind == SYM_STAGE || n->sym->kind == SYM_EXTERN))
      return ref_value(L, n->sym, n->args, n->nargs, env);
    else {
      int *src = arena_alloc(ctx, sizeof(int) * (size_t)ncomp);
      for (int j = 0; j < ncomp; j++) src[j] = select_flat(L, n, env, j);
      return val_pick(L, lower_expr(L, n->a, env), ncomp, src);
    }
  case N_ADD: return val_add(L, lower_expr(L, n->a, env), lower_expr(L, n->b, env));
  case N_SUB: return val_add(L, lower_expr(L, n->a, env), val_scale(L, lower_expr(L, n->b, env), coef_num(L->ctx, -1)));
  case N_NEG: return val_scale(L, lower_expr(L, n->a, env), coef_num(L->ctx, -1));
  case N_MUL:
    if (n->a->ty.op) {
      long p, q;
      Sym *op = op_value(L, n->a, &p, &q);
      return apply_op(L, op, p, q, lower_expr(L, n->b, env));
    }
    return val_mul(L, lower_expr(L, n->a, env), lower_expr(L, n->b, env), n);
  case N_DIV:
    if (n->b->ty.var != V_VARYING) {
      int nb = type_ncomp(&n->b->ty);
      Value *inv = val_new(L, nb);
      Term *t = term_new(L, nb);
      for (int c = 0; c < nb; c++)
        poly_push(ctx, &t->num->comp[c], mono_const(ctx, coef_bin(L->ctx, N_DIV, coef_num(L->ctx, 1), coef(L, n->b, env, c))));
      vec_push(ctx, &inv->terms, t);
      return val_mul(L, lower_expr(L, n->a, env), inv, n);
    }
    return val_mul(L, lower_expr(L, n->a, env), val_pow_diag(L, lower_expr(L, n->b, env), -1, 1, n->b), n);
  case N_POW: {
    iassert(ctx, n->b->kind == N_RAT);
    long p = n->b->p, q = n->b->q;
    Value *base = lower_expr(L, n->a, env);
    if (q == 1 && p >= 0) {
      Value *acc = val_coef(L, new_num(ctx, 1, true, n->loc), env, 1);
      for (long i = 0; i < p; i++) acc = val_mul(L, acc, base, n);
      return val_broadcast(L, acc, base->ncomp);
    }
    return val_pow_diag(L, base, p, q, n->a);
  }
  case N_VEC: {
    Piece *ps = arena_alloc(ctx, sizeof(Piece) * (size_t)n->nargs);
    int per = type_ncomp(&n->args[0]->ty);
    for (int i = 0; i < n->nargs; i++) {
      ps[i].v = val_broadcast(L, lower_expr(L, n->args[i], env), per);
      ps[i].off = i * per;
    }
    return assemble(L, ps, n->nargs, ncomp);
  }
  case N_IF: {
    Node *cond = coef(L, n->a, env, 0);
    Piece ps[2] = {{val_broadcast(L, lower_expr(L, n->b, env), ncomp), cond, 0},
                   {val_broadcast(L, lower_expr(L, n->c, env), ncomp), coef_not(L->ctx, cond), 0}};
    return assemble(L, ps, 2, ncomp);
  }
  case N_SUM: return lower_sum(L, n, env);
  case N_CALL:
    if (n->builtin == B_SOLVE) {
      long p, q;
      Sym *op = op_value(L, n->args[0], &p, &q);
      return apply_op(L, op, -p, q, lower_expr(L, n->args[1], env));
    }
    internal_error(ctx, __FILE__, __LINE__, "varying builtin call survived checking");
  default: internal_error(ctx, __FILE__, __LINE__, "unexpected node in lowering");
  }
}
