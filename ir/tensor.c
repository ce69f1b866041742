/* tensor.c — the tensors of a polynomial field: its monomials grouped by
 * the multiset of quantities they read (one tensor per group, DESIGN §1),
 * with tensor order and a symbolic nonzero count in terms of dims. */
#include <stdlib.h>
#include <string.h>

#include "ir.h"

#define MAXV TENSOR_MAXV

typedef struct Count {      /* coefficient × Π dims, one term of a nonzero count */
  long k;
  char *dims;               /* "F^2·V", "" for a pure number */
  int degree;               /* how many dims multiply: 3 for "F^2·V" */
} Count;

static bool is_var(const Node *n) {
  return n && n->kind == N_NAME && n->sym && (n->sym->kind == SYM_IVAR || n->sym->kind == SYM_SUMVAR);
}

/* The equalities of a monomial: `j == i`, `j == nbr[i, k]` in a guard
 * (`if(nbr[i, k] == j, …)`), `delta(j, tab[i, k])` in the coefficient. One
 * whose side is an index variable determines it as a function of the
 * variables the other side reads, so that variable is not a free axis of
 * the count: an index-table gather is how an operator reads its K
 * neighbours per row, and it makes K·N entries, not N^2 (DESIGN §13). */
typedef struct Eqs {
  const Node *a[32], *b[32];
  int n;
  bool other;               /* the guard has conditions that fix no variable */
} Eqs;

static void guard_eqs(const Node *g, Eqs *e) {
  if (!g) return;
  if (g->kind == N_AND) {
    guard_eqs(g->a, e);
    guard_eqs(g->b, e);
  } else if (g->kind == N_EQ && (is_var(g->a) || is_var(g->b)) && e->n < 32) {
    e->a[e->n] = g->a;
    e->b[e->n++] = g->b;
  } else {
    e->other = true;
  }
}

static void coef_deltas(const Node *c, Eqs *e) {
  if (!c) return;
  if (c->kind == N_MUL) {
    coef_deltas(c->a, e);
    coef_deltas(c->b, e);
  } else if (c->kind == N_CALL && c->builtin == B_DELTA && (is_var(c->args[0]) || is_var(c->args[1])) && e->n < 32) {
    e->a[e->n] = c->args[0];
    e->b[e->n++] = c->args[1];
  } else if (c->kind == N_NEG) {
    coef_deltas(c->a, e);
  } else if (c->kind == N_IF && c->c && c->c->kind == N_NUM && c->c->num == 0) {
    /* if(k != 0, delta(j, i + k*B), 0) * a[i]: nonzero only where the condition holds and the
     * delta does (a block's offsets in an affine sum; it counted N^2 and made the op dense) */
    guard_eqs(c->a, e);
    coef_deltas(c->b, e);
  } else if (c->kind == N_IF && c->b && c->b->kind == N_NUM && c->b->num == 0) {
    e->other = true; /* if(c, 0, delta(...)): the delta's entries, fewer where c holds */
    coef_deltas(c->c, e);
  }
}

/* Fixes variable `iv` as a function of `expr` unless that makes a cycle
 * (`i == f(j)` and `j == g(i)` fix only one of the two): `dep` holds, per
 * fixed variable, every variable it depends on, transitively. */
static bool fix_var(const Node *expr, int iv, const Sym *const *vars, int nv, const Node **fixed,
                    unsigned long long *dep) {
  if (fixed[iv] || node_uses(expr, vars[iv])) return false;
  unsigned long long d = 0;
  for (int i = 0; i < nv; i++)
    if (i != iv && node_uses(expr, vars[i])) d |= 1ull << i | dep[i];
  if (d >> iv & 1) return false;
  fixed[iv] = expr;
  dep[iv] = d;
  for (int i = 0; i < nv; i++)
    if (dep[i] >> iv & 1) dep[i] |= d;
  return true;
}

static int var_index(const Node *n, const Sym *const *vars, int nv) {
  if (!is_var(n)) return -1;
  for (int i = 0; i < nv; i++)
    if (vars[i] == n->sym) return i;
  return -1;
}

/* Marks the variables the equalities determine; `i == j` fixes j, the later
 * of the two. An equality that can fix no variable makes the count an
 * upper bound. */
static void fix_vars(const Eqs *e, const Sym *const *vars, int nv, const Node **fixed, bool *bound,
                     unsigned long long *dep) {
  for (int k = 0; k < e->n; k++) {
    int ib = var_index(e->b[k], vars, nv), ia = var_index(e->a[k], vars, nv);
    /* a gather (`nbr[i, k] == j`) may hold no index in range (-1 padding):
       its count bounds the entries */
    if (ib >= 0 && fix_var(e->a[k], ib, vars, nv, fixed, dep)) {
      if (ia < 0) *bound = true;
      continue;
    }
    if (ia >= 0 && fix_var(e->b[k], ia, vars, nv, fixed, dep)) {
      if (ib < 0) *bound = true;
      continue;
    }
    /* already implied (`i == j` twice) or circular */
    if (!(ia >= 0 && ib >= 0 && (fixed[ia] || fixed[ib]))) *bound = true;
  }
}

static int cmp_str(const void *a, const void *b) { return strcmp(*(char *const *)a, *(char *const *)b); }

/* Count of the entries one monomial touches when its coefficient is the
 * product of `factors` (deltas among them fix variables). */
static Count mono_count(Ctx *ctx, const Mono *m, const Node *const *factors, int nfactors, Sym *const *ivars,
                        int nivars, bool *bound) {
  const Sym *vars[MAXV];
  const char *dim[MAXV];
  long lit[MAXV];
  const Node *fixed[MAXV] = {0};
  unsigned long long dep[MAXV] = {0};
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
  for (int f = 0; f < nfactors; f++) coef_deltas(factors[f], &e);
  if (e.other) *bound = true;
  fix_vars(&e, vars, nv, fixed, bound, dep);
  Count c = {1, "", 0};
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
  c.degree = nn;
  return c;
}

/* The additive parts of a coefficient, products distributed over sums:
 * (δ(i,a) − δ(i,b))·(δ(j,a) − δ(j,b)) is four products of two deltas. At
 * most MAXPARTS parts of MAXFACTORS factors each; -1 beyond. */
enum { MAXPARTS = TENSOR_MAXPARTS, MAXFACTORS = TENSOR_MAXFACTORS };
typedef struct Part {
  const Node *f[MAXFACTORS];
  int n;
  int sign;                 /* the part is sign × Π f */
} Part;

static int coef_parts(const Node *c, Part *out) {
  if (c->kind == N_ADD || c->kind == N_SUB) {
    int na = coef_parts(c->a, out);
    if (na < 0) return -1;
    Part rest[MAXPARTS];
    int nb = coef_parts(c->b, rest);
    if (nb < 0 || na + nb > MAXPARTS) return -1;
    for (int i = 0; i < nb; i++) rest[i].sign *= c->kind == N_SUB ? -1 : 1;
    memcpy(out + na, rest, sizeof(Part) * (size_t)nb);
    return na + nb;
  }
  if (c->kind == N_NEG) {
    int n = coef_parts(c->a, out);
    for (int i = 0; i < n; i++) out[i].sign = -out[i].sign;
    return n;
  }
  if (c->kind == N_MUL) {
    Part pa[MAXPARTS], pb[MAXPARTS];
    int na = coef_parts(c->a, pa), nb = na < 0 ? -1 : coef_parts(c->b, pb);
    if (nb < 0 || na * nb > MAXPARTS) return -1;
    int n = 0;
    for (int i = 0; i < na; i++)
      for (int j = 0; j < nb; j++, n++) {
        if (pa[i].n + pb[j].n > MAXFACTORS) return -1;
        out[n] = pa[i];
        memcpy(out[n].f + pa[i].n, pb[j].f, sizeof(Node *) * (size_t)pb[j].n);
        out[n].n += pb[j].n;
        out[n].sign = pa[i].sign * pb[j].sign;
      }
    return n;
  }
  out[0] = (Part){{c}, 1, 1};
  return 1;
}

/* The counts of one monomial: its coefficient taken whole (the deltas of
 * its top-level product fix variables), or, where a sum inside the
 * coefficient hides deltas that would leave fewer free dims, one count per
 * additive part (their sum bounds the union of their entries). At most
 * MAXPARTS counts into `out`; returns how many. */
static int mono_counts(Ctx *ctx, const Mono *m, Sym *const *ivars, int nivars, bool *bound, Count *out) {
  const Node *whole = m->coef;
  bool whole_bound = false;
  out[0] = mono_count(ctx, m, &whole, whole ? 1 : 0, ivars, nivars, &whole_bound);
  Part parts[MAXPARTS];
  int np = whole ? coef_parts(whole, parts) : -1;
  if (np > 1) {
    Count split[MAXPARTS];
    bool split_bound = true;
    int worst = 0;
    for (int i = 0; i < np; i++) {
      split[i] = mono_count(ctx, m, parts[i].f, parts[i].n, ivars, nivars, &split_bound);
      if (split[i].degree > worst) worst = split[i].degree;
    }
    if (worst < out[0].degree) {
      memcpy(out, split, sizeof(Count) * (size_t)np);
      *bound = true;
      return np;
    }
  }
  *bound |= whole_bound;
  return 1;
}

/* The variables of monomial `m` (`ivars`, then its sum variables) and which
 * of them the equalities of its guard and of `factors` determine. */
static void part_plan(const Mono *m, const Node *const *factors, int nfactors, Sym *const *ivars, int nivars,
                      MonoPart *out) {
  int nv = 0;
  for (int i = 0; i < nivars && nv < MAXV; i++) out->vars[nv++] = ivars[i];
  for (int i = 0; i < m->nsums && nv < MAXV; i++) out->vars[nv++] = m->sums[i].var;
  out->nvars = nv;
  Eqs e = {0};
  guard_eqs(m->guard, &e);
  for (int f = 0; f < nfactors; f++) coef_deltas(factors[f], &e);
  unsigned long long dep[MAXV] = {0};
  bool bound = false;
  memset(out->fixed_by, 0, sizeof out->fixed_by);
  fix_vars(&e, out->vars, nv, out->fixed_by, &bound, dep);
  /* free variables first, in order; then each fixed one after what it reads */
  int n = 0;
  bool placed[MAXV] = {0};
  for (int i = 0; i < nv; i++)
    if (!out->fixed_by[i]) out->order[n++] = i, placed[i] = true;
  while (n < nv)
    for (int i = 0; i < nv; i++) {
      if (placed[i]) continue;
      bool ready = true;
      for (int j = 0; j < nv; j++)
        if ((dep[i] >> j & 1) && !placed[j]) ready = false;
      if (ready) out->order[n++] = i, placed[i] = true;
    }
  out->nfactors = nfactors;
  memcpy(out->factors, factors, sizeof(Node *) * (size_t)nfactors);
}

int tensor_mono_parts(Ctx *ctx, const Mono *m, Sym *const *ivars, int nivars, MonoPart *out) {
  bool bound = false;
  Count whole[MAXPARTS];
  int np = mono_counts(ctx, m, ivars, nivars, &bound, whole);
  if (np == 1) {
    part_plan(m, (const Node *const *)&m->coef, 1, ivars, nivars, &out[0]);
    out[0].sign = 1;
    return 1;
  }
  Part parts[MAXPARTS];
  np = coef_parts(m->coef, parts);
  for (int i = 0; i < np; i++) {
    part_plan(m, parts[i].f, parts[i].n, ivars, nivars, &out[i]);
    out[i].sign = parts[i].sign;
  }
  return np;
}

/* Whether every part of monomial `m` of operator `op`'s entries determines the column
 * indices by equalities (`delta(j, col[i, q])`) and sums freely over no range that grows
 * with a dim of the operator's axes: then a row holds a bounded number of entries however
 * large the column dims are (TensorGroup.rows_bound). */
static bool mono_rows_bound(Ctx *ctx, const Mono *m, const Sym *op) {
  MonoPart parts[MAXPARTS];
  int np = tensor_mono_parts(ctx, m, op->ivars, op->nivars, parts);
  for (int k = 0; k < np; k++) {
    const MonoPart *pt = &parts[k];
    for (int v = op->nrow; v < op->nivars; v++)
      if (!pt->fixed_by[v]) return false;
    for (int v = op->nivars; v < pt->nvars; v++) {
      if (pt->fixed_by[v]) continue;
      const SumVar *sv = NULL;
      for (int s = 0; s < m->nsums; s++)
        if (m->sums[s].var == pt->vars[v]) sv = &m->sums[s];
      for (int a = 0; a < op->nivars; a++) {
        const Sym *dim = op->ivars[a]->range;
        if (!dim) return false;
        if (pt->vars[v]->range == dim) return false;
        if (sv && (node_uses(sv->lo, dim) || node_uses(sv->hi, dim))) return false;
      }
    }
  }
  return true;
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
      if (g[k].nmono == 0) g[k].rows_bound = owner->kind == SYM_OP && owner->nrow < owner->nivars;
      if (g[k].rows_bound) g[k].rows_bound = mono_rows_bound(ctx, m, owner);
      g[k].nmono++;
      bool bound = false;
      Count cnt[MAXPARTS];
      int nc = mono_counts(ctx, m, ivars, nivars, &bound, cnt);
      g[k].nnz_bound |= bound;
      for (int c2 = 0; c2 < nc; c2++) {
        int j;
        for (j = 0; j < ncount[k]; j++)
          if (strcmp(counts[k][j].dims, cnt[c2].dims) == 0) break;
        if (j == ncount[k]) {
          if (j == 16) {
            g[k].nnz_bound = true;
            continue;
          }
          counts[k][j] = (Count){0, cnt[c2].dims, cnt[c2].degree};
          ncount[k]++;
        }
        counts[k][j].k += cnt[c2].k;
      }
    }
  out->n = ng;
  out->g = arena_alloc(ctx, sizeof(TensorGroup) * (size_t)(ng + 1));
  for (int k = 0; k < ng; k++) {
    g[k].nnz = count_str(ctx, counts[k], ncount[k]);
    for (int j = 0; j < ncount[k]; j++)
      if (counts[k][j].k && counts[k][j].degree > g[k].nnz_degree) g[k].nnz_degree = counts[k][j].degree;
    out->g[k] = g[k];
  }
}
