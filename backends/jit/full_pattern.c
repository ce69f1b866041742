/* full_pattern.c — the structural sparsity pattern of a Jacobian of the full evaluator
 * (DESIGN §17): which entries of an input each entry of a quantity reads, through every
 * stage, at the params as bound.
 *
 * A stage's tensor builders list, for each of its entries, the entries of the quantities
 * its monomials contract (backends/emit/emit_builder.c: numerators and diagonal operators
 * row by row). The dependencies of a stage entry are the union of those entries'
 * dependencies; an input's entry depends on itself. A declared operator's power mixes the
 * whole vector (an inverse is dense), so every entry of such a term depends on everything
 * its numerator and its operator's entries depend on. Guards that fail and coefficients
 * that vanish at the bound params list no entry: the pattern holds at every sample of
 * this binding, and a Jacobian entry outside it is zero there. */
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "emit.h"
#include "full.h"

/* Dependencies as sorted, deduplicated lists per entry (CSR). */
typedef struct Deps {
  size_t n;        /* entries */
  long *ptr;       /* n + 1 */
  long *idx;
} Deps;

/* (entry, dependency) pairs being gathered for one stage. */
typedef struct Pairs {
  long *v;         /* 2 per pair */
  size_t n, cap;
  bool oom;
} Pairs;

static void pair_add(Pairs *p, long row, long dep) {
  if (p->oom) return;
  if (p->n == p->cap) {
    size_t cap = p->cap ? 2 * p->cap : 1024;
    long *v = mem_realloc(p->v, sizeof(long) * 2 * cap);
    if (!v) {
      p->oom = true;
      return;
    }
    p->v = v;
    p->cap = cap;
  }
  p->v[2 * p->n] = row;
  p->v[2 * p->n + 1] = dep;
  p->n++;
}

static void deps_free(Deps *d) {
  if (!d) return;
  free(d->ptr);
  free(d->idx);
  d->ptr = NULL;
  d->idx = NULL;
}

/* What the sink of one tensor group adds: each entry's row gets the dependencies of the
 * entries it contracts (of quantities with any). */
typedef struct PatternSink {
  const Deps *in[16];  /* per input of the group: its dependencies, NULL when none */
  Pairs *pairs;
  bool all;            /* a declared operator's entry: row -1 (the whole term) */
} PatternSink;

static int pattern_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  (void)col, (void)coef;
  PatternSink *s = user;
  for (int i = 0; i < nin && i < 16; i++) {
    const Deps *d = s->in[i];
    if (!d || in[i] < 0 || (size_t)in[i] >= d->n) continue;
    for (long k = d->ptr[in[i]]; k < d->ptr[in[i] + 1]; k++) pair_add(s->pairs, s->all ? -1 : (long)row, d->idx[k]);
  }
  return s->pairs->oom ? -1 : 0;
}

static int cmp_pair(const void *a, const void *b) {
  const long *x = a, *y = b;
  if (x[0] != y[0]) return x[0] < y[0] ? -1 : 1;
  return (x[1] > y[1]) - (x[1] < y[1]);
}

/* The pairs as Deps over n entries; a row of -1 (a declared operator's term) goes to every
 * entry. 0, or -1 when out of memory. */
static int pairs_to_deps(Pairs *p, size_t n, Deps *out) {
  if (p->n) qsort(p->v, p->n, 2 * sizeof(long), cmp_pair);
  size_t all = 0, nall = 0, end = 0; /* the rows -1 come first: deduplicated in place */
  while (end < p->n && p->v[2 * end] == -1) {
    if (nall == 0 || p->v[2 * (nall - 1) + 1] != p->v[2 * end + 1]) {
      p->v[2 * nall] = -1;
      p->v[2 * nall + 1] = p->v[2 * end + 1];
      nall++;
    }
    end++;
  }
  size_t q = end;
  size_t cap = p->n + nall * n + 1;
  out->n = n;
  out->ptr = mem_calloc(n + 1, sizeof(long));
  out->idx = mem_malloc(sizeof(long) * cap);
  if (!out->ptr || !out->idx) return -1;
  long k = 0;
  for (size_t r = 0; r < n; r++) {
    out->ptr[r] = k;
    /* merge the term-wide dependencies with this row's, both sorted */
    all = 0;
    long last = -1;
    while (all < nall || (q < p->n && p->v[2 * q] == (long)r)) {
      bool take_all = all < nall && (q >= p->n || p->v[2 * q] != (long)r || p->v[2 * all + 1] <= p->v[2 * q + 1]);
      long dep = take_all ? p->v[2 * all++ + 1] : p->v[2 * q++ + 1];
      if (dep != last) out->idx[k++] = dep, last = dep;
    }
  }
  out->ptr[n] = k;
  return 0;
}

/* The dependencies of stage `st` (n entries) from the stages and inputs before it. */
static int stage_deps(Full *f, const Program *prog, const Stage *st, Deps *deps, size_t n, Deps *out) {
  Pairs pairs = {0};
  int rc = 0;
  for (int t = 0; t < st->nterms && rc == 0; t++) {
    const Term *tm = st->terms[t];
    bool mixed = false;
    for (int k = 0; k < tm->nops; k++) mixed |= tm->ops[k].kind == OPK_DECL;
    for (int field = 0; field <= tm->nops && rc == 0; field++) {
      const OpPow *op = field ? &tm->ops[field - 1] : NULL;
      const TensorList *tl = !op ? &tm->num_tensors : op->kind == OPK_DIAG ? &tm->op_tensors[field - 1] : &op->op->opdef->tensors;
      if (!op && tm->named_num) { /* the numerator is a quantity itself */
        const Deps *d = &deps[vec_position(&prog->slots, tm->named_num)];
        for (size_t e = 0; e < d->n && e < n && d->ptr; e++)
          for (long k = d->ptr[e]; k < d->ptr[e + 1]; k++) pair_add(&pairs, mixed ? -1 : (long)e, d->idx[k]);
        continue;
      }
      for (int g = 0; g < tl->n && rc == 0; g++) {
        const TensorGroup *tg = &tl->g[g];
        PatternSink s = {{NULL}, &pairs, mixed};
        for (int i = 0; i < tg->ninputs && i < 16; i++) {
          const Deps *d = &deps[vec_position(&prog->slots, tg->inputs[i])];
          s.in[i] = d->ptr && d->ptr[d->n] > 0 ? d : NULL;
        }
        NpgSink sink = {&s, pattern_entry, 0, 1, 0, 0};
        const char *name = op && op->kind == OPK_DECL ? emit_builder_name(prog->ctx, prog, NULL, 0, 0, g, op->op)
                                                      : emit_builder_name(prog->ctx, prog, st, t, field, g, NULL);
        rc = full_build(f, name, &sink);
      }
    }
  }
  if (rc == 0 && pairs.oom) rc = full_fail(f, "out of memory");
  if (rc == 0 && pairs_to_deps(&pairs, n, out) != 0) rc = full_fail(f, "out of memory");
  free(pairs.v);
  return rc;
}

int full_jacobian_pattern(Full *f, const char *output, const char *input, long **indptr, long **indices) {
  const Program *prog = full_program(f);
  *indptr = *indices = NULL;
  if (!prog || full_error(f)[0]) return -1;
  int nslots = prog->slots.n, ko = -1, ki = -1;
  for (int k = 0; k < nslots; k++) {
    const char *name = ((Sym *)prog->slots.v[k])->name;
    if (strcmp(name, output) == 0) ko = k;
    if (strcmp(name, input) == 0) ki = k;
  }
  if (ko < 0 || ki < 0) return full_fail(f, "derivatives: no such quantity (a bug in npg: the facade checks names)");
  Deps *deps = mem_calloc((size_t)nslots + 1, sizeof *deps);
  if (!deps) return full_fail(f, "out of memory");
  size_t nin = 0;
  full_get(f, input, &nin);
  int rc = 0;
  deps[ki].n = nin; /* the input's entry depends on itself */
  deps[ki].ptr = mem_malloc(sizeof(long) * (nin + 1));
  deps[ki].idx = mem_malloc(sizeof(long) * (nin + 1));
  if (!deps[ki].ptr || !deps[ki].idx) rc = full_fail(f, "out of memory");
  for (size_t e = 0; e <= nin && rc == 0; e++) deps[ki].ptr[e] = (long)e, deps[ki].idx[e] = (long)e;
  for (int i = 0; i < prog->stages.n && rc == 0; i++) {
    const Stage *st = prog->stages.v[i];
    if (st->kind == ST_INPUT || st->kind == ST_EXTERN) continue;
    int k = vec_position(&prog->slots, st->sym);
    size_t n = 0;
    full_get(f, st->sym->name, &n);
    rc = stage_deps(f, prog, st, deps, n, &deps[k]);
  }
  if (rc == 0) {
    *indptr = deps[ko].ptr;
    *indices = deps[ko].idx;
    deps[ko].ptr = NULL;
    deps[ko].idx = NULL;
    if (!*indptr) rc = full_fail(f, "derivatives: the output has no pattern (a bug in npg)");
  }
  for (int k = 0; k < nslots; k++) deps_free(&deps[k]);
  free(deps);
  return rc;
}
