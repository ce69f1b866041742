/* emit_direct.c — a stage's checked source expression as C, evaluated
 * directly at each entry (the full evaluator's fast path).
 *
 * The canonical form expands products into monomials (63 per pair for the
 * radiosity distances), which is what the tensors need but not how to
 * evaluate a stage quickly; the source expression keeps the user's
 * factorization (centroids, dot products). It is built as values of the
 * loop nest (cse.c), so each subexpression is computed once and in the
 * outermost loop it can be, as in hand-written code. Stages whose terms
 * apply declared operators keep the canonical path (emit_full.c).
 * test_builder checks the two against each other: the tensor form must
 * equal this direct evaluation. */
#include <stdlib.h>
#include <string.h>

#include "emit.h"

static void indent(FILE *out, int depth) {
  for (int i = 0; i < depth; i++) fputs("  ", out);
}

typedef struct DEnv {
  const Sym *var;
  int val;              /* its value (cse), when not constant */
  bool is_const;
  long value;           /* when is_const (unrolled sums) */
  const struct DEnv *next;
} DEnv;

/* A varying denominator v as v + (v − v): the same bits when v is finite (v − v is +0), NaN when
 * it is infinite, so an infinite intermediate is not absorbed into a finite quotient (1/(1/x) at a
 * subnormal x would be 0): the stage is then not finite and refused where it arises, as the
 * named-stage form 1/r is. */
static int cured(Cse *cs, int v) { return cse_op(cs, VAL_ADD, v, cse_op(cs, VAL_SUB, v, v, -1), -1); }

static int build(Emit *e, const Node *n, int comp, const DEnv *env);

static const DEnv *lookup(const DEnv *env, const Sym *s) {
  for (; env; env = env->next)
    if (env->var == s) return env;
  return NULL;
}

static const DEnv *bind(Emit *e, const DEnv *env, const Sym *var, int val, bool is_const, long value) {
  DEnv *d = arena_alloc(e->ctx, sizeof *d);
  d->var = var;
  d->val = val;
  d->is_const = is_const;
  d->value = value;
  d->next = env;
  return d;
}

/* The value of a constant integer index (component indices are constants
 * after checking; summation variables of unrolled sums are bound). */
static long const_value(Emit *e, const Node *n, const DEnv *env) {
  switch (n->kind) {
  case N_NUM: return (long)n->num;
  case N_NAME: {
    const DEnv *d = lookup(env, n->sym);
    iassert(e->ctx, d && d->is_const);
    return d->value;
  }
  case N_NEG: return -const_value(e, n->a, env);
  case N_ADD: return const_value(e, n->a, env) + const_value(e, n->b, env);
  case N_SUB: return const_value(e, n->a, env) - const_value(e, n->b, env);
  case N_MUL: return const_value(e, n->a, env) * const_value(e, n->b, env);
  default: internal_error(e->ctx, __FILE__, __LINE__, "component index is not constant");
  }
}

/* A quantity over one dim with static axes (small vectors per face, per
 * vertex), read in the innermost loop of a nest at that loop's entry, is
 * read from a copy with one array per component (e->soa): unit stride, so
 * the loop vectorizes without shuffles. The copy is made once per call. */
static const char *soa_name(Emit *e, const Sym *q, int flat) {
  return arena_printf(e->ctx, "S%d_%s", flat, emit_name(e, q) + 2);
}

/* The value of an index or summation variable. */
static int var_value(Emit *e, const Sym *s, const DEnv *env) {
  const DEnv *d = lookup(env, s);
  iassert(e->ctx, d);
  return d->is_const ? cse_num(e->cse, (double)d->value, true) : d->val;
}

static int ncomp_of_sym(const Sym *q) {
  int c = 1;
  for (int i = 0; i < q->nstatic; i++) c *= q->shape[i];
  return c;
}

/* q's body at the entry idx (dim axes), component flat: a definition
 * substituted, its index variables bound to idx. */
static int substitute(Emit *e, const Sym *q, const int *idx, int flat) {
  const DEnv *e2 = NULL;
  for (int i = 0; i < q->ndims; i++) e2 = bind(e, e2, q->ivars[i], idx[i], false, 0);
  const Sym *saved = e->direct_for;
  e->direct_for = q;
  int v = build(e, q->body, flat, e2);
  e->direct_for = saved;
  return v;
}

/* Entry of param or quantity q indexed by args (dim axes, some static
 * axes); comp enumerates the static axes left. Inlined and constant
 * definitions are substituted. */
static int entry(Emit *e, const Sym *q, Node *const *args, int nargs, int comp, const DEnv *env) {
  Cse *cs = e->cse;
  int naxes = q->ndims + q->nstatic;
  int *idx = arena_alloc(e->ctx, sizeof(int) * (size_t)(naxes + 1));
  int given_static = nargs > q->ndims ? nargs - q->ndims : 0;
  bool in_range = true;
  for (int i = 0; i < q->ndims; i++) {
    if (nargs) idx[i] = build(e, args[i], 0, env);
    else { /* whole reference: the definition's own index variables */
      iassert(e->ctx, e->direct_for && i < e->direct_for->nivars);
      idx[i] = var_value(e, e->direct_for->ivars[i], env);
    }
    in_range &= cse_in_range(cs, idx[i], q->dims[i]);
  }
  long sidx[MAX_STATIC];
  for (int i = 0; i < given_static; i++) sidx[i] = const_value(e, args[q->ndims + i], env);
  for (int i = q->nstatic - 1, c = comp; i >= given_static; i--) {
    sidx[i] = c % q->shape[i];
    c /= q->shape[i];
  }
  int flat = 0;
  for (int i = 0; i < q->nstatic; i++) flat = flat * q->shape[i] + (int)sidx[i];
  if (q->kind == SYM_STAGE && !q->inlined && e->fuse) {
    int k = -1;
    for (int m = 0; m < e->fuse_upto; m++)
      if (e->fuse[m]->sym == q) k = m;
    if (k >= 0) {
      bool identity = true;
      for (int i = 0; i < q->ndims; i++) identity &= idx[i] == e->loopvar[i];
      if (identity) return e->fused_val[k][flat]; /* computed at this entry already */
      return substitute(e, q, idx, flat); /* another entry of a member: rematerialized */
    }
  }
  if (q->kind == SYM_STAGE && q->inlined && (!q->stage || e->deriv))
    return substitute(e, q, idx, flat); /* a constant definition; any inlined one in derivative code */
  emit_use(e, q);
  int nl = cse_nloops(cs);
  if (nl >= 2 && !e->deriv && q->ndims == 1 && q->nstatic && !q->is_int && idx[0] == e->loopvar[nl - 1] &&
      cse_in_range(cs, idx[0], q->dims[0])) {
    if (vec_position(&e->soa, q) < 0) vec_push(e->ctx, &e->soa, (void *)q);
    return cse_load(cs, soa_name(e, q, flat), false, idx[0], true);
  }
  /* the flat offset ((i0 * D1 + i1) * S0 + c0) ... */
  int off = -1;
  for (int i = 0; i < naxes; i++) {
    int x = i < q->ndims ? idx[i] : cse_num(cs, (double)sidx[i - q->ndims], true);
    if (i == 0) {
      off = x;
      continue;
    }
    int size;
    if (i < q->ndims) {
      emit_use(e, q->dims[i]);
      size = cse_leaf(cs, emit_name(e, q->dims[i]), true, 0, NULL);
    } else {
      size = cse_num(cs, q->shape[i - q->ndims], true);
    }
    off = cse_op(cs, VAL_ADD, cse_op(cs, VAL_MUL, off, size, -1), x, -1);
  }
  if (off < 0) off = cse_num(cs, 0, true);
  return cse_load(cs, emit_name(e, q), q->kind == SYM_PARAM && q->is_int, off, in_range);
}

static int ncomp_of(const Type *t) {
  int c = 1;
  for (int i = 0; i < t->nstatic; i++) c *= t->shape[i];
  return c;
}

static int select_flat(Emit *e, const Node *n, int comp, const DEnv *env) {
  const Type *bt = &n->a->ty;
  int flat = 0;
  for (int i = 0; i < bt->nstatic; i++) {
    int v;
    if (i < n->nargs) v = (int)const_value(e, n->args[i], env);
    else {
      int inner = 1;
      for (int k = i + 1; k < bt->nstatic; k++) inner *= bt->shape[k];
      v = (comp / inner) % bt->shape[i];
    }
    flat = flat * bt->shape[i] + v;
  }
  return flat;
}

static int sub(Emit *e, const Node *n, int comp, const DEnv *env) { return build(e, n, n->ty.nstatic ? comp : 0, env); }

static int binop(Emit *e, const Node *n, int comp, const DEnv *env, ValOp op) {
  int a = sub(e, n->a, comp, env);
  return cse_op(e->cse, op, a, sub(e, n->b, comp, env), -1);
}

static int build(Emit *e, const Node *n, int comp, const DEnv *env) {
  Cse *cs = e->cse;
  switch (n->kind) {
  case N_NUM: return cse_num(cs, n->num, n->ty.is_int && n->is_int);
  case N_RAT: return cse_num(cs, (double)n->p / (double)n->q, false);
  case N_NAME: {
    const Sym *s = n->sym;
    if (s->kind == SYM_IVAR || s->kind == SYM_SUMVAR) return var_value(e, s, env);
    if (s->kind == SYM_DIM) {
      emit_use(e, s);
      return cse_leaf(cs, emit_name(e, s), true, 0, NULL);
    }
    return entry(e, s, NULL, 0, comp, env);
  }
  case N_INDEX:
    if (n->a->kind == N_NAME && n->sym && n->sym->kind != SYM_OP) return entry(e, n->sym, n->args, n->nargs, comp, env);
    return build(e, n->a, select_flat(e, n, comp, env), env);
  case N_VEC: {
    int per = ncomp_of(&n->args[0]->ty);
    return build(e, n->args[comp / per], comp % per, env);
  }
  case N_NEG: return cse_op(cs, VAL_NEG, sub(e, n->a, comp, env), -1, -1);
  case N_NOT: return cse_op(cs, VAL_NOT, build(e, n->a, 0, env), -1, -1);
  case N_ADD: return binop(e, n, comp, env, VAL_ADD);
  case N_SUB: return binop(e, n, comp, env, VAL_SUB);
  case N_MUL: return binop(e, n, comp, env, VAL_MUL);
  case N_DIV: {
    int a = sub(e, n->a, comp, env), b = sub(e, n->b, comp, env);
    /* dividing by a coefficient is multiplying by it (DESIGN §3): the
     * reciprocal is loop invariant */
    if (n->b->ty.var != V_VARYING) b = cse_op(cs, VAL_DIV, cse_num(cs, 1.0, false), b, -1);
    return cse_op(cs, n->b->ty.var != V_VARYING ? VAL_MUL : VAL_DIV, a, n->b->ty.var != V_VARYING ? b : cured(cs, b), -1);
  }
  case N_EQ: return binop(e, n, comp, env, VAL_EQ);
  case N_NE: return binop(e, n, comp, env, VAL_NE);
  case N_LT: return binop(e, n, comp, env, VAL_LT);
  case N_LE: return binop(e, n, comp, env, VAL_LE);
  case N_GT: return binop(e, n, comp, env, VAL_GT);
  case N_GE: return binop(e, n, comp, env, VAL_GE);
  case N_AND: return binop(e, n, comp, env, VAL_AND);
  case N_OR: return binop(e, n, comp, env, VAL_OR);
  case N_IF: {
    int cond = build(e, n->a, 0, env);
    cse_guard(cs, 1);
    int a = sub(e, n->b, comp, env), b = sub(e, n->c, comp, env);
    cse_guard(cs, -1);
    return cse_op(cs, VAL_SELECT, cond, a, b);
  }
  case N_POW:
    if (n->b->kind == N_RAT) {
      long p = n->b->p, q = n->b->q;
      int a = sub(e, n->a, comp, env);
      if (q == 1 && p == 1) return a;
      if (q == 2 && (p == 1 || p == -1)) {
        int r = cse_call(cs, "sqrt", a, -1);
        return p < 0 ? cse_op(cs, VAL_DIV, cse_num(cs, 1.0, false), cured(cs, r), -1) : r;
      }
      /* x^(±3/2) as emit_apply_diag's x·sqrt(x): libm's pow was 4x the hand-written C of
       * n-body pairs (bench_shapes); sqrt and one product are exact or one rounding */
      if (q == 2 && (p == 3 || p == -3)) {
        int r = cse_op(cs, VAL_MUL, a, cse_call(cs, "sqrt", a, -1), -1);
        return p < 0 ? cse_op(cs, VAL_DIV, cse_num(cs, 1.0, false), cured(cs, r), -1) : r;
      }
      /* x² as x·x: the same bits as pow(x, 2) (one rounding), and no libm call under libtcc */
      if (q == 1 && p == 2) return cse_op(cs, VAL_MUL, a, a, -1);
      if (q == 1 && p == -1) return cse_op(cs, VAL_DIV, cse_num(cs, 1.0, false), cured(cs, a), -1);
      /* no cbrt for q = 3: a root of a negative number is NaN (emit_apply_diag) */
    }
    return cse_call(cs, "pow", sub(e, n->a, comp, env), build(e, n->b, 0, env));
  case N_SUM: {
    const Sym *v = n->sym;
    if (v->body) { /* literal bounds: unrolled */
      long lo = (long)v->body->args[0]->num, hi = (long)v->body->args[1]->num;
      int acc = -1;
      for (long k = lo; k <= hi; k++) {
        int t = sub(e, n->c, comp, bind(e, env, v, -1, true, k));
        acc = acc < 0 ? t : cse_op(cs, VAL_ADD, acc, t, -1);
      }
      return acc < 0 ? cse_num(cs, 0.0, false) : acc;
    }
    int lo = build(e, n->a, 0, env), hi = build(e, n->b, 0, env);
    int var = cse_sumvar(cs, emit_name(e, v));
    cse_guard(cs, 1); /* the body is not evaluated when the range is empty */
    int body = sub(e, n->c, comp, bind(e, env, v, var, false, 0));
    cse_guard(cs, -1);
    return cse_sum(cs, var, lo, hi, body);
  }
  case N_CALL:
    if (n->builtin == B_DELTA) {
      int a = build(e, n->args[0], 0, env);
      return cse_op(cs, VAL_DOUBLE, cse_op(cs, VAL_EQ, a, build(e, n->args[1], 0, env), -1), -1, -1);
    }
    if (emit_math_name(n->builtin)) {
      iassert(e->ctx, n->nargs >= 1 && n->nargs <= 2);
      int a = sub(e, n->args[0], comp, env);
      int b = n->nargs > 1 ? sub(e, n->args[1], comp, env) : -1;
      return cse_call(cs, emit_math_name(n->builtin), a, b);
    }
    break;
  default: break;
  }
  internal_error(e->ctx, __FILE__, __LINE__, "expression not emitted directly");
}

bool emit_direct_ok(const Stage *st) {
  if (st->sym->introduced) return false;
  for (int t = 0; t < st->nterms; t++)
    for (int k = 0; k < st->terms[t]->nops; k++)
      if (st->terms[t]->ops[k].kind == OPK_DECL) return false;
  return true;
}

/* ---------------------------------------------------------------- fusion */

static bool same_domain(const Sym *a, const Sym *b) {
  if (a->nivars != b->nivars || a->nivars == 0) return false;
  for (int i = 0; i < a->nivars; i++)
    if (a->ivars[i]->range != b->ivars[i]->range) return false;
  return true;
}

static int member_of(const Stage *const *members, int n, const Sym *q) {
  for (int m = 0; m < n; m++)
    if (members[m]->sym == q) return m;
  return -1;
}

static bool remat_ok(const Stage *const *members, int n, const Stage *q, int depth);

/* Every read of a member inside `x` is at the entry of `self` (identity)
 * when `identity_ok`, or rematerializable. */
static bool reads_ok(const Stage *const *members, int n, const Node *x, const Sym *self, bool identity_ok, int depth) {
  if (!x) return true;
  if ((x->kind == N_INDEX || x->kind == N_NAME) && x->sym && x->sym->kind == SYM_STAGE && !x->sym->inlined) {
    int m = member_of(members, n, x->sym);
    if (m >= 0) {
      bool identity = identity_ok && x->kind == N_INDEX && x->nargs >= x->sym->ndims;
      for (int i = 0; identity && i < x->sym->ndims; i++)
        identity = x->args[i]->kind == N_NAME && x->args[i]->sym == self->ivars[i];
      if (x->kind == N_NAME && identity_ok && x->sym->ndims == 0) identity = true;
      if (!identity && !remat_ok(members, n, members[m], depth + 1)) return false;
    }
  }
  if (x->kind == N_INDEX && x->a && x->a->kind == N_NAME) {
    for (int i = 0; i < x->nargs; i++)
      if (!reads_ok(members, n, x->args[i], self, identity_ok, depth)) return false;
    return true;
  }
  if (!reads_ok(members, n, x->a, self, identity_ok, depth) || !reads_ok(members, n, x->b, self, identity_ok, depth) ||
      !reads_ok(members, n, x->c, self, identity_ok, depth))
    return false;
  for (int i = 0; i < x->nargs; i++)
    if (!reads_ok(members, n, x->args[i], self, identity_ok, depth)) return false;
  return true;
}

/* Recomputing q at another entry needs only what was computed before the
 * group (reads of members inside it are rematerialized in turn). */
static bool remat_ok(const Stage *const *members, int n, const Stage *q, int depth) {
  if (depth > 4) return false;
  return reads_ok(members, n, q->sym->body, q->sym, false, depth);
}

bool emit_fusable(const Stage *const *members, int n, const Stage *cand) {
  if (!emit_direct_ok(cand) || cand->sym->body->ty.nwhole) return false;
  if (n == 0) return cand->sym->nivars > 0;
  if (!same_domain(members[0]->sym, cand->sym)) return false;
  return reads_ok(members, n, cand->sym->body, cand->sym, true, 0);
}

/* The component arrays of e->soa, in one scratch block `soa_` (released
 * by the caller when this returns true). */
static bool emit_soa_copies(Emit *e, FILE *out) {
  if (!e->soa.n) return false;
  fputs("  /*", out);
  for (int i = 0; i < e->soa.n; i++) fprintf(out, "%s %s", i ? "," : "", ((Sym *)e->soa.v[i])->name);
  fputs(": one array per component, read with unit stride by the innermost loop */\n", out);
  fputs("  double *const soa_ = c->rt->scratch(c, ", out);
  for (int i = 0; i < e->soa.n; i++) {
    const Sym *q = e->soa.v[i];
    emit_use(e, q->dims[0]);
    fprintf(out, "%s%s * %d", i ? " + " : "", emit_name(e, q->dims[0]), ncomp_of_sym(q));
  }
  fputs(");\n  if (!soa_) return -1;\n", out);
  for (int i = 0; i < e->soa.n; i++) {
    const Sym *q = e->soa.v[i];
    const char *base = emit_name(e, q) + 2, *dim = emit_name(e, q->dims[0]);
    int nc = ncomp_of_sym(q);
    fprintf(out, "  double *const S_%s = soa_", base);
    for (int k = 0; k < i; k++) {
      const Sym *p = e->soa.v[k];
      fprintf(out, " + %s * %d", emit_name(e, p->dims[0]), ncomp_of_sym(p));
    }
    fputs(";\n", out);
    fprintf(out, "  for (npg_idx k_ = 0; k_ < %s; k_++)\n", dim);
    fprintf(out, "    for (npg_idx c_ = 0; c_ < %d; c_++) S_%s[c_ * %s + k_] = %s[k_ * %d + c_];\n", nc, base, dim,
            emit_name(e, q), nc);
    for (int f = 0; f < nc; f++)
      if (cse_reads(e->cse, soa_name(e, q, f)))
        fprintf(out, "  const double *restrict const %s = S_%s + %s%s%d;\n", soa_name(e, q, f), base, f ? dim : "",
                f ? " * " : "", f);
  }
  return true;
}

/* A new nest of nl loops (e->cse, e->loopvar) over ranges[], the first `nflat` of them the
 * index variables ivars[] (C names in names[]; a loop beyond them is a summation's, over its
 * dim); the flat entry index over the first nflat returned. */
static int open_nest(Emit *e, int nl, int nflat, const Sym *const *ranges, Sym *const *ivars, const char **names) {
  Cse *cs = e->cse = cse_new(e->ctx, nl);
  e->loopvar = arena_alloc(e->ctx, sizeof(int) * (size_t)(nl + 1));
  int flat = -1;
  for (int i = 0; i < nl; i++) {
    const Sym *dim = ranges[i];
    if (i < nflat) names[i] = emit_name(e, ivars[i]);
    else names[i] = arena_printf(e->ctx, "l_%d_", i);
    e->loopvar[i] = cse_leaf(cs, names[i], true, i + 1, dim);
    emit_use(e, dim);
    if (i >= nflat) continue;
    int size = cse_leaf(cs, emit_name(e, dim), true, 0, NULL);
    flat = i ? cse_op(cs, VAL_ADD, cse_op(cs, VAL_MUL, flat, size, -1), e->loopvar[i], -1) : e->loopvar[i];
  }
  return flat < 0 ? cse_num(cs, 0, true) : flat;
}

/* The values of members[0..n) at the current entry of their common
 * domain, each member's components stored at e_; a read of a member at this
 * entry is its value, at another entry its expression again. */
void emit_direct_group(Emit *e, FILE *out, const Stage *const *members, int n) {
  const Sym *first = members[0]->sym;
  int nl = first->nivars;
  const char **names = arena_alloc(e->ctx, sizeof(char *) * (size_t)(nl + 1));
  const Sym **ranges = arena_alloc(e->ctx, sizeof(Sym *) * (size_t)(nl + 1));
  for (int i = 0; i < nl; i++) ranges[i] = first->ivars[i]->range;
  int flat = open_nest(e, nl, nl, ranges, first->ivars, names);
  Cse *cs = e->cse;
  e->fuse = members;
  e->fused_val = arena_alloc(e->ctx, sizeof(int *) * (size_t)n);
  int **offset = arena_alloc(e->ctx, sizeof(int *) * (size_t)n);
  for (int m = 0; m < n; m++) {
    const Stage *st = members[m];
    const Sym *s = st->sym;
    const DEnv *env = NULL;
    for (int i = 0; i < s->nivars; i++) env = bind(e, env, s->ivars[i], e->loopvar[i], false, 0);
    e->fuse_upto = m;
    e->direct_for = s;
    e->fused_val[m] = arena_alloc(e->ctx, sizeof(int) * (size_t)st->ncomp);
    offset[m] = arena_alloc(e->ctx, sizeof(int) * (size_t)st->ncomp);
    for (int c = 0; c < st->ncomp; c++) {
      int v = e->fused_val[m][c] = build(e, s->body, c, env);
      if (cse_is_int(cs, v)) v = e->fused_val[m][c] = cse_op(cs, VAL_DOUBLE, v, -1, -1);
      const char *base = emit_name(e, s) + 2; /* without Q_ */
      cse_hint(cs, v, st->ncomp > 1 ? arena_printf(e->ctx, "l_%s_%d", base, c) : arena_printf(e->ctx, "l_%s", base));
      offset[m][c] = cse_op(cs, VAL_ADD, cse_op(cs, VAL_MUL, flat, cse_num(cs, st->ncomp, true), -1),
                            cse_num(cs, c, true), -1);
      cse_root(cs, v);
      cse_root(cs, offset[m][c]);
    }
  }
  e->fuse = NULL;
  e->direct_for = NULL;
  int nst = 0;
  for (int m = 0; m < n; m++) nst += members[m]->ncomp;
  CseStore *st = arena_alloc(e->ctx, sizeof(CseStore) * (size_t)nst);
  const char **comment = arena_alloc(e->ctx, sizeof(char *) * (size_t)nst);
  nst = 0;
  for (int m = 0; m < n; m++)
    for (int c = 0; c < members[m]->ncomp; c++) {
      emit_use(e, members[m]->sym);
      comment[nst] = n > 1 && c == 0 ? members[m]->sym->name : NULL;
      st[nst++] = (CseStore){emit_name(e, members[m]->sym), offset[m][c], e->fused_val[m][c], CSE_SET, -1};
    }
  emit_direct_nest(e, out, nl, names, ranges, st, nst, comment);
}

/* The dim a summation runs over from 0 to its last entry (`sum(j = 0..N-1, ...)`), or NULL. */
static const Sym *sum_range(const Node *n) {
  if (n->kind != N_SUM || n->sym->body) return NULL;
  if (n->sym->range) return n->sym->range;
  const Node *hi = n->b;
  if (n->a->kind != N_NUM || n->a->num != 0 || hi->kind != N_SUB || hi->b->kind != N_NUM || hi->b->num != 1) return NULL;
  return hi->a->kind == N_NAME && hi->a->sym->kind == SYM_DIM ? hi->a->sym : NULL;
}

/* The component values of stage `st` at the current entry of a new nest over its domain
 * (e->cse; nothing rooted), for its derivatives (emit_ddirect.c): val[c], the flat
 * offset of component c in offset[c], the loops' variables and dims in names[] and
 * ranges[] (room for one more than the stage's index variables), their number returned.
 * With `sum_loop`, a body that is a summation over a whole dim is its summand in a loop
 * more (val[c] the summand). Inlined definitions are substituted, and quantities read in
 * place (no copies per component). */
int emit_direct_values(Emit *e, const Stage *st, bool sum_loop, const char **names, const Sym **ranges, int *val,
                       int *offset) {
  const Sym *s = st->sym;
  int nl = s->nivars;
  const Sym *sr = sum_loop ? sum_range(s->body) : NULL;
  for (int i = 0; i < nl; i++) ranges[i] = s->ivars[i]->range;
  if (sr) ranges[nl] = sr;
  int flat = open_nest(e, nl + (sr != NULL), nl, ranges, s->ivars, names);
  Cse *cs = e->cse;
  const DEnv *env = NULL;
  for (int i = 0; i < nl; i++) env = bind(e, env, s->ivars[i], e->loopvar[i], false, 0);
  e->direct_for = s;
  for (int c = 0; c < st->ncomp; c++) {
    if (sr) {
      const Node *body = s->body->c;
      val[c] = build(e, body, body->ty.nstatic ? c : 0, bind(e, env, s->body->sym, e->loopvar[nl], false, 0));
    } else {
      val[c] = build(e, s->body, c, env);
    }
    offset[c] = cse_op(cs, VAL_ADD, cse_op(cs, VAL_MUL, flat, cse_num(cs, st->ncomp, true), -1), cse_num(cs, c, true), -1);
  }
  e->direct_for = NULL;
  return nl + (sr != NULL);
}

/* The loop nest of e->cse, nl loops over ranges[] (loop variables names[]), storing
 * st[0..nst) in its innermost loop (comment[k]: a comment before store k, or NULL); the
 * stores of kind CSE_REDUCE (an offset outside the innermost loop) summed over it in a
 * local first. */
void emit_direct_nest(Emit *e, FILE *out, int nl, const char **names, const Sym *const *ranges, const CseStore *st,
                      int nst, const char *const *comment) {
  Cse *cs = e->cse;
  cse_plan(cs);
  if (cse_guarded_gathers(cs)) e->scalar = true;
  /* libtcc computes the innermost loop a row at a time when it can (cse.c, rows) */
  bool plain = true, independent = true;
  for (int k = 0; k < nst; k++) {
    plain &= st[k].kind == CSE_SET;
    /* two entries adding into one gathered entry: the iterations depend on each other */
    independent &= (st[k].kind != CSE_ADD && st[k].kind != CSE_ADD_IF) || !cse_gathers(cs, st[k].offset);
  }
  int nrows = nl >= 2 && plain ? cse_rows_plan(cs, st, nst) : -1;
  const char *len = nl ? emit_name(e, ranges[nl - 1]) : NULL;
  bool scratch = emit_soa_copies(e, out);
  if (nrows > 0) {
    fputs("#ifdef __TINYC__\n  /* scratch rows of the row kernels, 64-byte aligned, a stride apart */\n", out);
    fprintf(out, "  const npg_idx rs_ = ((%s + 7) & ~(npg_idx)7) + 8;\n", len);
    fprintf(out, "  double *const rows_ = c->rt->scratch(c, %d * rs_ + 8);\n", nrows);
    fprintf(out, "  if (!rows_) {\n%s    return -1;\n  }\n", scratch ? "    c->rt->release(c, soa_);\n" : "");
    fputs("  double *const row0_ = (double *)(((npg_idx)rows_ + 63) & ~(npg_idx)63);\n", out);
    for (int k = 1; k < nrows; k++) fprintf(out, "  double *const row%d_ = row0_ + %d * rs_;\n", k, k);
    fputs("#endif\n", out);
  }
  cse_emit_level(cs, out, 0, 1);
  /* the box twin: the same nest over each box (emit_full.c), its loops
   * from lo_ to hi_; libtcc's row kernels where a box holds whole rows */
  int b = e->box ? 1 : 0;
  if (e->box)
    fprintf(out, "  for (int b_ = 0; b_ < nbox_; b_++) {\n    const npg_idx *const lo_ = box_ + (npg_idx)b_ * %d, "
                 "*const hi_ = lo_ + %d;\n", 2 * nl, nl);
  for (int i = 0; i < nl; i++) {
    const char *v = names[i];
    if (i == nl - 1 && nrows >= 0) {
      fputs("#ifdef __TINYC__\n", out);
      if (e->box) {
        indent(out, i + 1 + b);
        fprintf(out, "if (lo_[%d] == 0 && hi_[%d] == %s) {\n", i, i, len);
        cse_emit_rows(cs, out, st, nst, len, i + 2 + b);
        indent(out, i + 1 + b);
        fputs("} else\n#endif\n", out);
      } else {
        cse_emit_rows(cs, out, st, nst, len, i + 1);
        fputs("#else\n", out);
      }
    }
    if (i == nl - 1)
      for (int k = 0; k < nst; k++)
        if (st[k].kind == CSE_REDUCE) {
          indent(out, i + 1 + b);
          fprintf(out, "double r%d_ = 0.0;\n", k);
        }
    if (i == nl - 1 && independent) {
      indent(out, i + 1 + b);
      fputs("NPG_INDEPENDENT\n", out);
    }
    indent(out, i + 1 + b);
    if (e->box) fprintf(out, "for (npg_idx %s = lo_[%d]; %s < hi_[%d]; %s++) {\n", v, i, v, i, v);
    else fprintf(out, "for (npg_idx %s = 0; %s < %s; %s++) {\n", v, v, emit_name(e, ranges[i]), v);
    if (i + 1 < nl) cse_emit_level(cs, out, i + 1, i + 2 + b);
  }
  int depth = nl + 1 + b;
  for (int k = 0; k < nst; k++) {
    if (comment && comment[k]) {
      indent(out, depth);
      fprintf(out, "/* %s */\n", comment[k]);
    }
    if (st[k].kind == CSE_REDUCE) cse_emit_update(cs, out, arena_printf(e->ctx, "r%d_", k), -1, st[k].val, NULL, depth);
    else if (st[k].kind == CSE_ADD_IF) cse_emit_update_if(cs, out, st[k].array, st[k].offset, st[k].val, st[k].cond, depth);
    else if (st[k].kind == CSE_ADD) cse_emit_update(cs, out, st[k].array, st[k].offset, st[k].val, NULL, depth);
    else cse_emit_store(cs, out, st[k].array, st[k].offset, st[k].val, depth);
  }
  for (int i = nl; i >= 1; i--) {
    indent(out, i + b);
    fputs("}\n", out);
    if (i == nl)
      for (int k = 0; k < nst; k++)
        if (st[k].kind == CSE_REDUCE)
          cse_emit_update(cs, out, st[k].array, st[k].offset, -1, arena_printf(e->ctx, "r%d_", k), i + b);
    if (i == nl && nrows >= 0 && !e->box) fputs("#endif\n", out);
  }
  if (e->box) fputs("  }\n", out);
  if (nrows > 0) fputs("#ifdef __TINYC__\n  c->rt->release(c, rows_);\n#endif\n", out);
  if (scratch) fputs("  c->rt->release(c, soa_);\n", out);
  e->cse = NULL;
  e->soa.n = 0;
}
