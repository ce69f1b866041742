/* emit_ddirect.c — the derivatives of a stage the evaluator computes from its source
 * expression (emit_direct.c), on the same value graph (cse.c; DESIGN §17).
 *
 * Forward: every value v gets its tangent dv by the rule of its operation (+ − × ÷,
 * sqrt, constant powers, choices, sums), a read of a quantity the same read of its
 * tangent array; the tangents are values of the nest too, so they share subexpressions
 * and are hoisted and vectorized as the evaluation is, and the stage's tangent is stored
 * as its value is. Reverse: the stage's cotangent enters at its components and is sent
 * from each value into its operands', last value first; every read of a quantity becomes
 * `dQ[offset] += cotangent` (summed over the innermost loop first when the offset does
 * not move in it; under the choices that guard the read when it may fall outside its
 * array), and what a branch sends on is computed only where the branch is taken. A body
 * that sums over a whole dim is its summand in one loop more. A stage whose graph holds
 * what the rules do not cover (a summation inside the reverse nest, a libm function other
 * than sqrt and pow) is left to the canonical form's derivative (emit_deriv.c). */
#include <string.h>

#include "emit.h"

/* The derivative array of the quantity whose C name is `array`, NULL for a param. */
static const char *darray(void *arg, const char *array) {
  Emit *e = arg;
  for (int k = 0; k < e->prog->slots.n; k++)
    if (strcmp(emit_name(e, e->prog->slots.v[k]), array) == 0) {
      e->used_deriv[k] = true;
      return arena_printf(e->ctx, "d%s", array);
    }
  return NULL;
}

/* What building values marks as used, kept to be put back when the stage falls back. */
typedef struct Used {
  bool *dim, *param, *q, *deriv;
} Used;

static bool *copy(Ctx *ctx, const bool *v, int n) {
  bool *c = arena_alloc(ctx, sizeof(bool) * (size_t)(n + 1));
  memcpy(c, v, sizeof(bool) * (size_t)(n + 1));
  return c;
}

static Used save(Emit *e) {
  const Program *p = e->prog;
  return (Used){copy(e->ctx, e->used_dim, p->dims.n), copy(e->ctx, e->used_param, p->params.n),
                copy(e->ctx, e->used_q, p->slots.n), copy(e->ctx, e->used_deriv, p->slots.n)};
}

/* `(void)name;` for what building the values declared but the derivative does not read (a
 * value whose tangent is zero, a factor of a linear stage). */
static void unread(Emit *e, FILE *out, const Cse *cs, int nl, const Sym *const *ranges, const CseStore *st, int nst) {
  const Program *p = e->prog;
  bool *looped = arena_alloc(e->ctx, sizeof(bool) * (size_t)(p->dims.n + 1)), *stored = arena_alloc(e->ctx, sizeof(bool) * (size_t)(p->slots.n + 1));
  for (int i = 0; i < nl; i++) {
    int k = vec_position(&p->dims, ranges[i]);
    if (k >= 0) looped[k] = true;
  }
  for (int k = 0; k < p->slots.n; k++)
    for (int j = 0; j < nst; j++) stored[k] |= strcmp(st[j].array, arena_printf(e->ctx, "d%s", emit_name(e, p->slots.v[k]))) == 0;
  for (int k = 0; k < p->dims.n; k++)
    if (e->used_dim[k] && !looped[k] && !cse_mentions(cs, emit_name(e, p->dims.v[k]))) fprintf(out, "  (void)%s;\n", emit_name(e, p->dims.v[k]));
  for (int k = 0; k < p->params.n; k++)
    if (e->used_param[k] && !cse_mentions(cs, emit_name(e, p->params.v[k])))
      fprintf(out, "  (void)%s;\n", emit_name(e, p->params.v[k]));
  for (int k = 0; k < p->slots.n; k++) {
    const char *q = emit_name(e, p->slots.v[k]);
    if (e->used_q[k] && !cse_mentions(cs, q)) fprintf(out, "  (void)%s;\n", q);
    if (e->used_deriv[k] && !stored[k] && !cse_mentions(cs, arena_printf(e->ctx, "d%s", q))) fprintf(out, "  (void)d%s;\n", q);
  }
}

/* Falling back: the uses put back, the nest dropped. */
static bool give_up(Emit *e, const Used *u) {
  const Program *p = e->prog;
  memcpy(e->used_dim, u->dim, sizeof(bool) * (size_t)(p->dims.n + 1));
  memcpy(e->used_param, u->param, sizeof(bool) * (size_t)(p->params.n + 1));
  memcpy(e->used_q, u->q, sizeof(bool) * (size_t)(p->slots.n + 1));
  memcpy(e->used_deriv, u->deriv, sizeof(bool) * (size_t)(p->slots.n + 1));
  e->cse = NULL;
  e->soa.n = 0;
  e->deriv = false;
  return false;
}

/* A derivative sweep's start: the uses saved (give_up restores them), and
 * stage st's value graph built as the evaluator builds it (reverse: for the
 * adjoint), its nest's loop names and ranges, each component's value and
 * offset. */
typedef struct Graph {
  Used u;
  int nl, nc;
  const char **names;
  const Sym **ranges;
  int *val, *off;
} Graph;

static Graph graph_of(Emit *e, const Stage *st, bool reverse) {
  Graph g = {save(e), st->sym->nivars, st->ncomp, NULL, NULL, NULL, NULL};
  e->deriv = true;
  g.names = arena_alloc(e->ctx, sizeof(char *) * (size_t)(g.nl + 2));
  g.ranges = arena_alloc(e->ctx, sizeof(Sym *) * (size_t)(g.nl + 2));
  g.val = arena_alloc(e->ctx, sizeof(int) * (size_t)g.nc);
  g.off = arena_alloc(e->ctx, sizeof(int) * (size_t)g.nc);
  g.nl = emit_direct_values(e, st, reverse, g.names, g.ranges, g.val, g.off);
  return g;
}

bool emit_ddirect_tangent(Emit *e, FILE *out, const Stage *st) {
  if (!emit_direct_ok(st)) return false;
  const Sym *s = st->sym;
  Graph g = graph_of(e, st, false);
  Used u = g.u;
  int nl = g.nl, nc = g.nc, *val = g.val, *off = g.off;
  const char **names = g.names;
  const Sym **ranges = g.ranges;
  Cse *cs = e->cse;
  int n = cse_count(cs);
  int *memo = arena_alloc(e->ctx, sizeof(int) * (size_t)n);
  for (int i = 0; i < n; i++) memo[i] = -2;
  bool ok = true;
  CseStore *stv = arena_alloc(e->ctx, sizeof(CseStore) * (size_t)nc);
  const char *dy = darray(e, emit_name(e, s));
  for (int c = 0; c < nc && ok; c++) {
    int t = cse_tangent(cs, val[c], memo, darray, e, &ok);
    if (t < 0) t = cse_num(cs, 0.0, false);
    cse_root(cs, t);
    cse_root(cs, off[c]);
    stv[c] = (CseStore){dy, off[c], t, CSE_SET, -1};
  }
  if (!ok) return give_up(e, &u);
  e->deriv = false;
  emit_direct_nest(e, out, nl, names, ranges, stv, nc, NULL);
  unread(e, out, cs, nl, ranges, stv, nc);
  return true;
}

bool emit_ddirect_adjoint(Emit *e, FILE *out, const Stage *st) {
  if (!emit_direct_ok(st)) return false;
  const Sym *s = st->sym;
  Graph g = graph_of(e, st, true);
  Used u = g.u;
  int nl = g.nl, nc = g.nc, *val = g.val, *off = g.off;
  const char **names = g.names;
  const Sym **ranges = g.ranges;
  Cse *cs = e->cse;
  const char *dy = darray(e, emit_name(e, s));
  int *ybar = arena_alloc(e->ctx, sizeof(int) * (size_t)nc);
  for (int c = 0; c < nc; c++) ybar[c] = cse_load(cs, dy, false, off[c], true);
  int n = cse_count(cs);
  int *adj = arena_alloc(e->ctx, sizeof(int) * (size_t)n);
  for (int i = 0; i < n; i++) adj[i] = -1;
  for (int c = 0; c < nc; c++)
    if (!cse_is_int(cs, val[c])) adj[val[c]] = adj[val[c]] < 0 ? ybar[c] : cse_op(cs, VAL_ADD, adj[val[c]], ybar[c], -1);
  bool ok = true;
  int nupd = 0;
  CseStore *upd = arena_alloc(e->ctx, sizeof(CseStore) * (size_t)(n + 1));
  cse_adjoint(cs, adj, darray, e, upd, &nupd, &ok);
  if (!ok) return give_up(e, &u);
  e->deriv = false;
  for (int k = 0; k < nupd; k++) {
    if (nl && upd[k].kind == CSE_ADD && cse_level(cs, upd[k].offset) < nl) upd[k].kind = CSE_REDUCE;
    cse_root(cs, upd[k].val);
    cse_root(cs, upd[k].offset);
    if (upd[k].kind == CSE_ADD_IF) cse_root(cs, upd[k].cond);
  }
  emit_direct_nest(e, out, nl, names, ranges, upd, nupd, NULL);
  unread(e, out, cs, nl, ranges, upd, nupd);
  return true;
}
