/* tensor.c — the tensors of a polynomial field: its monomials grouped by
 * the multiset of quantities they read (one tensor per group, DESIGN §1),
 * with tensor order and a symbolic nonzero count in terms of dims. */
#include <stdlib.h>
#include <string.h>

#include "ir.h"

#define MAXV (MAX_AXES + 16)

typedef struct Count {      /* coefficient × Π dims, one term of a nonzero count */
  long k;
  char *dims;               /* "F^2·V", "" for a pure number */
} Count;

static bool is_var(const Node *n) {
  return n && n->kind == N_NAME && n->sym && (n->sym->kind == SYM_IVAR || n->sym->kind == SYM_SUMVAR);
}

typedef struct Eqs {
  const Sym *a[32], *b[32];
  int n;
  bool other;               /* the guard has conditions that are not equalities */
} Eqs;

static void guard_eqs(const Node *g, Eqs *e) {
  if (!g) return;
  if (g->kind == N_AND) {
    guard_eqs(g->a, e);
    guard_eqs(g->b, e);
  } else if (g->kind == N_EQ && is_var(g->a) && is_var(g->b) && e->n < 32) {
    e->a[e->n] = g->a->sym;
    e->b[e->n++] = g->b->sym;
  } else {
    e->other = true;
  }
}

static void coef_deltas(const Node *c, Eqs *e) {
  if (!c) return;
  if (c->kind == N_MUL) {
    coef_deltas(c->a, e);
    coef_deltas(c->b, e);
  } else if (c->kind == N_CALL && c->builtin == B_DELTA && is_var(c->args[0]) && is_var(c->args[1]) && e->n < 32) {
    e->a[e->n] = c->args[0]->sym;
    e->b[e->n++] = c->args[1]->sym;
  }
}

static int cmp_str(const void *a, const void *b) { return strcmp(*(char *const *)a, *(char *const *)b); }

/* Count of the entries one monomial touches. */
static Count mono_count(Ctx *ctx, const Mono *m, Sym *const *ivars, int nivars, bool *bound) {
  const Sym *vars[MAXV];
  const char *dim[MAXV];
  long lit[MAXV];
  bool fixed[MAXV] = {0};
  int nv = 0;
  for (int i = 0; i < nivars && nv < MAXV; i++, nv++) {
    vars[nv] = ivars[i];
    dim[nv] = ivars[i]->range ? ivars[i]->range->name : "?";
    lit[nv] = 0;
  }
  for (int s = 0; s < m->nsums && nv < MAXV; s++, nv++) {
    const SumVar *sv = &m->sums[s];
    vars[nv] = sv->var;
    lit[nv] = 0;
    if (sv->var->range) dim[nv] = sv->var->range->name;
    else if (sv->lo->kind == N_NUM && sv->hi->kind == N_NUM) dim[nv] = NULL, lit[nv] = (long)(sv->hi->num - sv->lo->num + 1);
    else dim[nv] = arena_printf(ctx, "(%s-%s+1)", node_str(ctx, sv->hi), node_str(ctx, sv->lo)), *bound = true;
  }
  Eqs e = {0};
  guard_eqs(m->guard, &e);
  coef_deltas(m->coef, &e);
  if (e.other) *bound = true;
  for (int k = 0; k < e.n; k++) {
    int ia = -1, ib = -1;
    for (int i = 0; i < nv; i++) {
      if (vars[i] == e.a[k]) ia = i;
      if (vars[i] == e.b[k]) ib = i;
    }
    if (ia >= 0 && ib >= 0 && ia != ib && !fixed[ia] && !fixed[ib]) fixed[ib] = true;
  }
  Count c = {1, ""};
  const char *names[MAXV];
  int nn = 0;
  for (int i = 0; i < nv; i++) {
    if (fixed[i]) continue;
    if (dim[i]) names[nn++] = dim[i];
    else c.k *= lit[i];
  }
  qsort(names, (size_t)nn, sizeof names[0], cmp_str);
  char *s = "";
  for (int i = 0; i < nn;) {
    int j = i;
    while (j < nn && strcmp(names[j], names[i]) == 0) j++;
    s = arena_printf(ctx, "%s%s%s", s, *s ? "·" : "", names[i]);
    if (j - i > 1) s = arena_printf(ctx, "%s^%d", s, j - i);
    i = j;
  }
  c.dims = s;
  return c;
}

static char *count_str(Ctx *ctx, Count *cs, int n) {
  char *s = "";
  for (int i = 0; i < n; i++) {
    if (cs[i].k == 0) continue;
    const char *sep = *s ? " + " : "";
    if (!*cs[i].dims) s = arena_printf(ctx, "%s%s%ld", s, sep, cs[i].k);
    else if (cs[i].k == 1) s = arena_printf(ctx, "%s%s%s", s, sep, cs[i].dims);
    else s = arena_printf(ctx, "%s%s%ld·%s", s, sep, cs[i].k, cs[i].dims);
  }
  return *s ? s : "0";
}

static int cmp_sym(const void *a, const void *b) {
  const Sym *x = *(Sym *const *)a, *y = *(Sym *const *)b;
  if (x->id != y->id) return x->id < y->id ? -1 : 1;
  return strcmp(x->name, y->name);
}

void tensor_groups(Ctx *ctx, const Sym *owner, const Field *f, int base_order, TensorList *out) {
  Sym *const *ivars = owner->ivars;
  int nivars = owner->nivars;
  TensorGroup g[64];
  Count counts[64][16];
  int ncount[64] = {0};
  int ng = 0;
  for (int c = 0; c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++) {
      const Mono *m = f->comp[c].m[i];
      Sym *in[16];
      int nin = m->natoms < 16 ? m->natoms : 16;
      for (int a = 0; a < nin; a++) in[a] = m->atoms[a].q;
      qsort(in, (size_t)nin, sizeof in[0], cmp_sym);
      int k;
      for (k = 0; k < ng; k++)
        if (g[k].ninputs == nin && (nin == 0 || memcmp(g[k].inputs, in, sizeof(Sym *) * (size_t)nin) == 0)) break;
      if (k == ng) {
        if (ng == 64)
          error_at(ctx, owner->loc, "'%s' needs more than 64 distinct tensors (monomials reading 64 different "
                                    "combinations of quantities): split it into named definitions", owner->name);
        memset(&g[k], 0, sizeof g[k]);
        g[k].ninputs = nin;
        if (nin) memcpy(g[k].inputs, in, sizeof(Sym *) * (size_t)nin);
        g[k].order = base_order + nin;
        for (int a = 1; a < nin; a++)
          if (in[a] == in[a - 1]) g[k].symmetric = true;
        ng++;
      }
      g[k].nmono++;
      bool bound = false;
      Count cnt = mono_count(ctx, m, ivars, nivars, &bound);
      g[k].nnz_bound |= bound;
      int j;
      for (j = 0; j < ncount[k]; j++)
        if (strcmp(counts[k][j].dims, cnt.dims) == 0) break;
      if (j == ncount[k]) {
        if (j == 16) {
          g[k].nnz_bound = true;
          continue;
        }
        counts[k][j] = (Count){0, cnt.dims};
        ncount[k]++;
      }
      counts[k][j].k += cnt.k;
    }
  out->n = ng;
  out->g = arena_alloc(ctx, sizeof(TensorGroup) * (size_t)(ng + 1));
  for (int k = 0; k < ng; k++) {
    g[k].nnz = count_str(ctx, counts[k], ncount[k]);
    out->g[k] = g[k];
  }
}
