/* emit_direct.c — a stage's checked source expression as C, evaluated
 * directly at each entry (the full evaluator's fast path).
 *
 * The canonical form expands products into monomials (63 per pair for the
 * radiosity distances), which is what the tensors need but not how to
 * evaluate a stage quickly; the source expression keeps the user's
 * factorization (centroids, dot products), and the C compiler hoists and
 * shares its subexpressions as in hand-written code. Stages whose terms
 * apply declared operators keep the canonical path (emit_full.c).
 * test_builder checks the two against each other: the tensor form must
 * equal this direct evaluation. */
#include <stdlib.h>
#include <string.h>

#include "emit.h"

typedef struct DEnv {
  const Sym *var;
  const char *c;        /* C text of its value */
  bool is_const;
  long value;           /* when is_const (unrolled sums) */
  const struct DEnv *next;
} DEnv;

static void direct(Emit *e, FILE *out, const Node *n, int comp, const DEnv *env);

static const DEnv *lookup(const DEnv *env, const Sym *s) {
  for (; env; env = env->next)
    if (env->var == s) return env;
  return NULL;
}

static const DEnv *bind(Emit *e, const DEnv *env, const Sym *var, const char *c, bool is_const, long value) {
  DEnv *d = arena_alloc(e->ctx, sizeof *d);
  d->var = var;
  d->c = c;
  d->is_const = is_const;
  d->value = value;
  d->next = env;
  return d;
}

static char *text(Emit *e, const Node *n, const DEnv *env) {
  char *buf = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&buf, &len);
  if (!f) error_plain(e->ctx, "out of memory");
  direct(e, f, n, 0, env);
  fclose(f);
  e->ctx->pending_free = buf;
  char *s = arena_strdup(e->ctx, buf ? buf : "");
  e->ctx->pending_free = NULL;
  free(buf);
  return s;
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

/* Entry of param or quantity q indexed by args (dim axes, some static
 * axes); comp enumerates the static axes left. Inlined and constant
 * definitions are substituted. */
static void entry(Emit *e, FILE *out, const Sym *q, Node *const *args, int nargs, int comp, const DEnv *env) {
  int naxes = q->ndims + q->nstatic;
  char **idx = arena_alloc(e->ctx, sizeof(char *) * (size_t)(naxes + 1));
  int given_static = nargs > q->ndims ? nargs - q->ndims : 0;
  for (int i = 0; i < q->ndims; i++) {
    if (nargs) idx[i] = text(e, args[i], env);
    else { /* whole reference: the definition's own index variables */
      iassert(e->ctx, e->direct_for && i < e->direct_for->nivars);
      idx[i] = (char *)emit_name(e, e->direct_for->ivars[i]);
    }
  }
  long sidx[MAX_STATIC];
  for (int i = 0; i < given_static; i++) sidx[i] = const_value(e, args[q->ndims + i], env);
  for (int i = q->nstatic - 1, c = comp; i >= given_static; i--) {
    sidx[i] = c % q->shape[i];
    c /= q->shape[i];
  }
  if (q->kind == SYM_STAGE && !q->inlined && e->fuse) {
    int k = -1;
    for (int m = 0; m < e->fuse_upto; m++)
      if (e->fuse[m]->sym == q) k = m;
    if (k >= 0) {
      bool identity = true;
      for (int i = 0; i < q->ndims; i++) identity &= strcmp(idx[i], e->loopvar[i]) == 0;
      int flat = 0;
      for (int i = 0; i < given_static; i++) flat = flat * q->shape[i] + (int)sidx[i];
      for (int i = given_static; i < q->nstatic; i++) flat = flat * q->shape[i] + (int)sidx[i];
      if (identity) { /* computed at this entry already */
        fprintf(out, "l_%d_%d", k, flat);
        return;
      }
      /* another entry of a member: rematerialized from its expression */
      const DEnv *e2 = NULL;
      for (int i = 0; i < q->ndims; i++) e2 = bind(e, e2, q->ivars[i], idx[i], false, 0);
      const Sym *saved = e->direct_for;
      e->direct_for = q;
      fputc('(', out);
      direct(e, out, q->body, flat, e2);
      fputc(')', out);
      e->direct_for = saved;
      return;
    }
  }
  if (q->kind == SYM_STAGE && q->inlined && !q->stage) { /* a constant definition: substituted */
    const DEnv *e2 = NULL;
    for (int i = 0; i < q->ndims; i++) e2 = bind(e, e2, q->ivars[i], idx[i], false, 0);
    int flat = 0;
    for (int i = 0; i < q->nstatic; i++) flat = flat * q->shape[i] + (int)sidx[i];
    const Sym *saved = e->direct_for;
    e->direct_for = q;
    fputc('(', out);
    direct(e, out, q->body, flat, e2);
    fputc(')', out);
    e->direct_for = saved;
    return;
  }
  for (int i = 0; i < q->nstatic; i++) idx[q->ndims + i] = arena_printf(e->ctx, "%ld", sidx[i]);
  emit_use(e, q);
  fprintf(out, "%s[", emit_name(e, q));
  emit_offset_texts(e, out, q, idx);
  fputc(']', out);
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

static void sub(Emit *e, FILE *out, const Node *n, int comp, const DEnv *env) {
  direct(e, out, n, n->ty.nstatic ? comp : 0, env);
}

static void binop(Emit *e, FILE *out, const Node *n, int comp, const DEnv *env, const char *op) {
  fputc('(', out);
  sub(e, out, n->a, comp, env);
  fprintf(out, " %s ", op);
  sub(e, out, n->b, comp, env);
  fputc(')', out);
}

static void direct(Emit *e, FILE *out, const Node *n, int comp, const DEnv *env) {
  switch (n->kind) {
  case N_NUM: emit_double(out, n->num); return;
  case N_RAT: emit_double(out, (double)n->p / (double)n->q); return;
  case N_NAME: {
    const Sym *s = n->sym;
    if (s->kind == SYM_IVAR || s->kind == SYM_SUMVAR) {
      const DEnv *d = lookup(env, s);
      if (d && d->is_const) fprintf(out, "%ld", d->value);
      else fputs(d ? d->c : emit_name(e, s), out);
      return;
    }
    if (s->kind == SYM_DIM) {
      emit_use(e, s);
      fputs(emit_name(e, s), out);
      return;
    }
    entry(e, out, s, NULL, 0, comp, env);
    return;
  }
  case N_INDEX:
    if (n->a->kind == N_NAME && n->sym && n->sym->kind != SYM_OP) {
      entry(e, out, n->sym, n->args, n->nargs, comp, env);
      return;
    }
    direct(e, out, n->a, select_flat(e, n, comp, env), env);
    return;
  case N_VEC: {
    int per = ncomp_of(&n->args[0]->ty);
    direct(e, out, n->args[comp / per], comp % per, env);
    return;
  }
  case N_NEG:
    fputs("(-", out);
    sub(e, out, n->a, comp, env);
    fputc(')', out);
    return;
  case N_NOT:
    fputs("(!", out);
    direct(e, out, n->a, 0, env);
    fputc(')', out);
    return;
  case N_ADD: binop(e, out, n, comp, env, "+"); return;
  case N_SUB: binop(e, out, n, comp, env, "-"); return;
  case N_MUL: binop(e, out, n, comp, env, "*"); return;
  case N_DIV:
    if (n->b->ty.var != V_VARYING) {
      /* dividing by a coefficient is multiplying by it (DESIGN §3): the
       * reciprocal is loop invariant and hoisted by the C compiler */
      fputc('(', out);
      sub(e, out, n->a, comp, env);
      fputs(" * (1.0 / ", out);
      sub(e, out, n->b, comp, env);
      fputs("))", out);
      return;
    }
    fputs("((double)", out);
    sub(e, out, n->a, comp, env);
    fputs(" / ", out);
    sub(e, out, n->b, comp, env);
    fputc(')', out);
    return;
  case N_EQ: binop(e, out, n, comp, env, "=="); return;
  case N_NE: binop(e, out, n, comp, env, "!="); return;
  case N_LT: binop(e, out, n, comp, env, "<"); return;
  case N_LE: binop(e, out, n, comp, env, "<="); return;
  case N_GT: binop(e, out, n, comp, env, ">"); return;
  case N_GE: binop(e, out, n, comp, env, ">="); return;
  case N_AND: binop(e, out, n, comp, env, "&&"); return;
  case N_OR: binop(e, out, n, comp, env, "||"); return;
  case N_IF:
    fputc('(', out);
    direct(e, out, n->a, 0, env);
    fputs(" ? ", out);
    sub(e, out, n->b, comp, env);
    fputs(" : ", out);
    sub(e, out, n->c, comp, env);
    fputc(')', out);
    return;
  case N_POW:
    if (n->b->kind == N_RAT) {
      long p = n->b->p, q = n->b->q;
      if (q == 1 && p == 1) return sub(e, out, n->a, comp, env);
      if (q == 2 && (p == 1 || p == -1)) {
        fputs(p < 0 ? "(1.0 / sqrt(" : "sqrt(", out);
        sub(e, out, n->a, comp, env);
        fputs(p < 0 ? "))" : ")", out);
        return;
      }
      if (q == 1 && p == -1) {
        fputs("(1.0 / ", out);
        sub(e, out, n->a, comp, env);
        fputc(')', out);
        return;
      }
      if (q == 3 && p == 1) {
        fputs("cbrt(", out);
        sub(e, out, n->a, comp, env);
        fputc(')', out);
        return;
      }
    }
    fputs("pow(", out);
    sub(e, out, n->a, comp, env);
    fputs(", ", out);
    direct(e, out, n->b, 0, env);
    fputc(')', out);
    return;
  case N_SUM: {
    const Sym *v = n->sym;
    if (v->body) { /* literal bounds: unrolled */
      long lo = (long)v->body->args[0]->num, hi = (long)v->body->args[1]->num;
      fputc('(', out);
      for (long k = lo; k <= hi; k++) {
        if (k > lo) fputs(" + ", out);
        sub(e, out, n->c, comp, bind(e, env, v, NULL, true, k));
      }
      fputc(')', out);
      return;
    }
    const char *k = emit_name(e, v);
    int t = e->tmp++;
    fprintf(out, "__extension__({ double s%d_ = 0.0; for (npg_idx %s = ", t, k);
    direct(e, out, n->a, 0, env);
    fprintf(out, "; %s <= ", k);
    direct(e, out, n->b, 0, env);
    fprintf(out, "; %s++) s%d_ += ", k, t);
    sub(e, out, n->c, comp, env);
    fprintf(out, "; s%d_; })", t);
    return;
  }
  case N_CALL:
    if (n->builtin == B_DELTA) {
      fputs("((double)(", out);
      direct(e, out, n->args[0], 0, env);
      fputs(" == ", out);
      direct(e, out, n->args[1], 0, env);
      fputs("))", out);
      return;
    }
    if (emit_math_name(n->builtin)) {
      fprintf(out, "%s(", emit_math_name(n->builtin));
      for (int i = 0; i < n->nargs; i++) {
        if (i) fputs(", ", out);
        fputs("(double)", out);
        sub(e, out, n->args[i], comp, env);
      }
      fputc(')', out);
      return;
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

void emit_direct_entry(Emit *e, FILE *out, const Stage *st, int comp) {
  e->direct_for = st->sym;
  direct(e, out, st->sym->body, comp, NULL);
  e->direct_for = NULL;
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

void emit_direct_group(Emit *e, FILE *out, const Stage *const *members, int n) {
  const Sym *first = members[0]->sym;
  e->loopvar = arena_alloc(e->ctx, sizeof(char *) * (size_t)(first->nivars + 1));
  for (int i = 0; i < first->nivars; i++) {
    const char *v = emit_name(e, first->ivars[i]);
    e->loopvar[i] = v;
    emit_use(e, first->ivars[i]->range);
    for (int k = 0; k <= i; k++) fputs("  ", out);
    fprintf(out, "for (npg_idx %s = 0; %s < %s; %s++) {\n", v, v, emit_name(e, first->ivars[i]->range), v);
  }
  int depth = first->nivars + 1;
  char pad[64];
  snprintf(pad, sizeof pad, "%*s", 2 * depth, "");
  fprintf(out, "%sconst npg_idx e_ = ", pad);
  for (int i = 1; i < first->nivars; i++) fputc('(', out);
  for (int i = 0; i < first->nivars; i++) {
    if (i) fprintf(out, " * %s + ", emit_name(e, first->ivars[i]->range));
    fputs(e->loopvar[i], out);
    if (i) fputc(')', out);
  }
  fputs(";\n", out);
  e->fuse = members;
  e->nfuse = n;
  for (int m = 0; m < n; m++) {
    const Stage *st = members[m];
    const Sym *s = st->sym;
    const DEnv *env = NULL;
    for (int i = 0; i < s->nivars; i++) env = bind(e, env, s->ivars[i], e->loopvar[i], false, 0);
    e->fuse_upto = m;
    fprintf(out, "%s/* %s */\n", pad, s->name);
    for (int c = 0; c < st->ncomp; c++) {
      e->direct_for = s;
      fprintf(out, "%sconst double l_%d_%d = ", pad, m, c);
      direct(e, out, s->body, c, env);
      fputs(";\n", out);
      emit_use(e, s);
      fprintf(out, "%s%s[e_ * %d + %d] = l_%d_%d;\n", pad, emit_name(e, s), st->ncomp, c, m, c);
    }
  }
  e->fuse = NULL;
  e->direct_for = NULL;
  for (int i = first->nivars; i >= 1; i--) {
    for (int k = 0; k < i; k++) fputs("  ", out);
    fputs("}\n", out);
  }
}
