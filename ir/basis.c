/* basis.c — basis classes: union-find over the quantities that have a basis
 * (inputs, stages, externs), merged by the reduction rules and by `share`
 * (DESIGN §4). Every merge keeps its reason; every unnamed numerator of an
 * operator term is recorded with the class whose snapshots it joins. */
#include <string.h>

#include "ir.h"

typedef struct UF {
  int *parent;
  int n;
} UF;

static int find(UF *u, int i) {
  while (u->parent[i] != i) i = u->parent[i] = u->parent[u->parent[i]];
  return i;
}

static int index_of(const Program *prog, const Sym *s) {
  for (int i = 0; i < prog->quantities.n; i++)
    if (prog->quantities.v[i] == s) return i;
  return -1;
}

static const char *rule_of(const Term *t) {
  bool root = false, inv = false;
  for (int k = 0; k < t->nops; k++) {
    if (t->ops[k].q != 1) root = true;
    else if (t->ops[k].p < 0) inv = true;
  }
  if (root) return "a root's operand lives in its result's basis (paper §4, rule iii)";
  if (inv) return "an inverse's numerator lives in its result's basis (paper §4.1, B_n = B_y)";
  return "an operator is reduced with its result's basis on both axes (paper §4.1)";
}

/* "h = diag(r)^-1 s" — the term in a line, operators abbreviated. */
static char *term_brief(Ctx *ctx, const Stage *st, const Term *t) {
  char *s = arena_printf(ctx, "%s =", st->sym->name);
  for (int k = t->nops - 1; k >= 0; k--) {
    const OpPow *o = &t->ops[k];
    char *base;
    if (o->kind == OPK_DECL) base = arena_printf(ctx, "%s", o->op->name);
    else {
      /* a named quantity itself, or "degree-d polynomial in g, n" */
      const Field *f = o->diag;
      const Mono *m0 = f->comp[0].n ? f->comp[0].m[0] : NULL;
      bool single = f->ncomp >= 1 && m0 && f->comp[0].n == 1 && m0->natoms == 1 && !m0->guard;
      for (int c = 1; c < f->ncomp && single; c++)
        single = f->comp[c].n == 1 && f->comp[c].m[0]->natoms == 1 && f->comp[c].m[0]->atoms[0].q == m0->atoms[0].q;
      if (single) {
        base = arena_printf(ctx, "diag(%s)", m0->atoms[0].q->name);
      } else {
        char *in = "";
        for (int c = 0; c < f->ncomp; c++)
          for (int i = 0; i < f->comp[c].n; i++)
            for (int a = 0; a < f->comp[c].m[i]->natoms; a++) {
              const char *nm = f->comp[c].m[i]->atoms[a].q->name;
              if (!strstr(in, nm)) in = arena_printf(ctx, "%s%s%s", in, *in ? ", " : "", nm);
            }
        base = arena_printf(ctx, "diag(degree-%d polynomial in %s)", field_degree(f), *in ? in : "nothing");
      }
    }
    if (o->q == 1) s = arena_printf(ctx, "%s %s^%ld", s, base, o->p);
    else s = arena_printf(ctx, "%s %s^(%ld/%ld)", s, base, o->p, o->q);
  }
  return arena_printf(ctx, "%s %s", s, t->named_num ? t->named_num->name : "(...)");
}

static void merge(Ctx *ctx, Program *prog, UF *u, Sym *a, Sym *b, char *reason, Loc loc) {
  int ia = index_of(prog, a), ib = index_of(prog, b);
  iassert(ctx, ia >= 0 && ib >= 0);
  Merge *m = arena_alloc(ctx, sizeof *m);
  m->a = a;
  m->b = b;
  m->reason = reason;
  m->loc = loc;
  vec_push(ctx, &prog->merges, m);
  int ra = find(u, ia), rb = find(u, ib);
  if (ra == rb) return;
  if (ra < rb) u->parent[rb] = ra;
  else u->parent[ra] = rb;
}
/* `basis q: product K0` (issue 41): the product of q's class. K0 must be
 * square, rows and columns over the same dims, and those the dims of q; two
 * members naming different products are refused. */
static void class_product(Ctx *ctx, Program *prog, const Sym *q) {
  if (!q->product) return;
  BasisClass *c = prog->classes.v[q->klass];
  const Sym *op = q->product;
  bool square = op->nivars == 2 * op->nrow;
  for (int a = 0; square && a < op->nrow; a++) square = op->ivars[a]->range == op->ivars[op->nrow + a]->range;
  if (!square)
    error_at(ctx, q->product_loc, "basis %s: product %s is not a square operator (its rows and columns must run "
             "over the same dims)", q->name, op->name);
  bool same = op->nrow == q->ndims && q->nstatic == 0;
  for (int a = 0; same && a < op->nrow; a++) same = op->ivars[a]->range == q->dims[a];
  if (!same)
    error_at(ctx, q->product_loc, "basis %s: product %s is not an operator of %s's size: its rows and columns must "
             "run over %s's dims, in order", q->name, op->name, q->name, q->name);
  if (c->product && c->product != op)
    error_at(ctx, q->product_loc, "basis %s: product %s, but its class %s already has product %s: a class has one "
             "inner product", q->name, op->name, c->size_name, c->product->name);
  c->product = (Sym *)op;
}


void basis_classes(Ctx *ctx, Program *prog) {
  UF u;
  u.n = prog->quantities.n;
  u.parent = arena_alloc(ctx, sizeof(int) * (size_t)(u.n + 1));
  for (int i = 0; i < u.n; i++) u.parent[i] = i;

  for (int i = 0; i < prog->stages.n; i++) {
    Stage *st = prog->stages.v[i];
    for (int t = 0; t < st->nterms; t++) {
      Term *tm = st->terms[t];
      if (!tm->nops || !tm->named_num) continue;
      if (tm->named_num == st->sym) continue;
      merge(ctx, prog, &u, st->sym, tm->named_num,
            arena_printf(ctx, "%s: %s", term_brief(ctx, st, tm), rule_of(tm)), st->sym->loc);
    }
  }
  for (int i = 0; i < prog->shares.n; i++) {
    Decl *d = prog->shares.v[i];
    Sym *first = NULL;
    for (int k = 0; k < d->nnames; k++) {
      Sym *s = NULL;
      for (int q = 0; q < prog->quantities.n && !s; q++)
        if (strcmp(((Sym *)prog->quantities.v[q])->name, d->names[k]) == 0) s = prog->quantities.v[q];
      iassert(ctx, s);
      if (!first) first = s;
      else
        merge(ctx, prog, &u, first, s,
              arena_printf(ctx, "'share' at %s:%d", d->loc.file ? d->loc.file->name : "?", d->loc.line), d->loc);
    }
  }
  for (int i = 0; i < prog->states.n; i++) { /* the step's output is the next step's input (DESIGN §15) */
    Sym *st = prog->states.v[i];
    merge(ctx, prog, &u, st, st->next, arena_printf(ctx, "state '%s' and its next value", st->name),
          st->next->decl->next_of_loc);
    if (st->residual) /* an implicit step: the residual projected on the unknown's basis (Galerkin) */
      merge(ctx, prog, &u, st, st->residual, arena_printf(ctx, "state '%s' and the residual of its implicit step",
            st->name), st->residual->decl->next_of_loc);
  }
  /* Number the classes in order of their first member. */
  int *id = arena_alloc(ctx, sizeof(int) * (size_t)(u.n + 1));
  for (int i = 0; i < u.n; i++) id[i] = -1;
  for (int i = 0; i < u.n; i++) {
    int r = find(&u, i);
    if (id[r] < 0) {
      BasisClass *c = arena_alloc(ctx, sizeof *c);
      c->id = prog->classes.n;
      c->basis_max = -1;
      c->basis_energy = -1;
      c->basis_center = -1;
      id[r] = c->id;
      vec_push(ctx, &prog->classes, c);
    }
    BasisClass *c = prog->classes.v[id[r]];
    Sym *s = prog->quantities.v[i];
    s->klass = c->id;
    if (s->stage) s->stage->klass = c->id;
    vec_push(ctx, &c->members, s);
    if (!c->size_name) c->size_name = arena_printf(ctx, "m_%s", s->name);
  }
  /* `basis m_x: ...`: options of x's whole class (a quantity's own `basis x:` still wins for x) */
  for (int i = 0; i < prog->quantities.n; i++) {
    const Sym *s = prog->quantities.v[i];
    BasisClass *c = prog->classes.v[s->klass];
    if (s->class_basis_max > 0) c->basis_max = s->class_basis_max;
    if (s->class_basis_energy > 0) c->basis_energy = s->class_basis_energy;
    if (s->class_basis_center >= 0) c->basis_center = s->class_basis_center;
  }
  /* `basis m_x: ...`: options of x's whole class (a quantity's own `basis x:` still wins for x) */
  for (int i = 0; i < prog->quantities.n; i++) {
    const Sym *s = prog->quantities.v[i];
    BasisClass *c = prog->classes.v[s->klass];
    if (s->class_basis_max > 0) c->basis_max = s->class_basis_max;
    if (s->class_basis_energy > 0) c->basis_energy = s->class_basis_energy;
    if (s->class_basis_center >= 0) c->basis_center = s->class_basis_center;
  }
  for (int i = 0; i < prog->quantities.n; i++) class_product(ctx, prog, prog->quantities.v[i]);
  for (int i = 0; i < prog->stages.n; i++) {
    Stage *st = prog->stages.v[i];
    for (int t = 0; t < st->nterms; t++) {
      if (!st->terms[t]->nops || st->terms[t]->named_num) continue;
      Joiner *j = arena_alloc(ctx, sizeof *j);
      j->stage = st;
      j->term = t;
      vec_push(ctx, &((BasisClass *)prog->classes.v[st->klass])->joiners, j);
    }
  }
}
