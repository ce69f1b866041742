/* demand.c — the entries an evaluation must compute, propagated backwards
 * through the full evaluator's steps (demand.h). */
#include <stdlib.h>
#include <string.h>

#include "demand.h"

/* More boxes than this for one quantity or step: it is demanded whole. */
#define DEMAND_MAX_BOXES 64

typedef enum BoxState {
  BOX_NONE,   /* nothing demanded */
  BOX_SOME,   /* the boxes v[0..n) */
  BOX_ALL,    /* every entry */
} BoxState;

/* Boxes over `nax` axes, each 2·nax npg_idx: lo[0..nax), then hi[0..nax). */
typedef struct Boxes {
  BoxState state;
  int nax, n, cap;
  npg_idx *v;
} Boxes;

struct Demand {
  const Program *prog;
  const FullPlan *plan;
  const npg_idx *dims;
  Boxes *slot;      /* per slot of prog */
  Boxes *step;      /* per step of plan: where it runs */
  bool oom;
};

Demand *demand_new(const Program *prog, const FullPlan *plan) {
  Demand *d = mem_calloc(1, sizeof *d);
  if (!d) return NULL;
  d->prog = prog;
  d->plan = plan;
  d->slot = mem_calloc((size_t)prog->slots.n + 1, sizeof(Boxes));
  d->step = mem_calloc((size_t)plan->n + 1, sizeof(Boxes));
  if (!d->slot || !d->step) {
    demand_free(d);
    return NULL;
  }
  return d;
}

void demand_free(Demand *d) {
  if (!d) return;
  for (int i = 0; d->slot && i < d->prog->slots.n; i++) free(d->slot[i].v);
  for (int i = 0; d->step && i < d->plan->n; i++) free(d->step[i].v);
  free(d->slot);
  free(d->step);
  free(d);
}

void demand_reset(Demand *d, const npg_idx *dims) {
  d->dims = dims;
  d->oom = false;
  for (int i = 0; i < d->prog->slots.n; i++) d->slot[i].state = BOX_NONE, d->slot[i].n = 0;
  for (int i = 0; i < d->plan->n; i++) d->step[i].state = BOX_NONE, d->step[i].n = 0;
}

static npg_idx dim_size(const Demand *d, const Sym *dim) { return d->dims[vec_position(&d->prog->dims, dim)]; }

static bool contains(const npg_idx *outer, const npg_idx *inner, int nax) {
  for (int k = 0; k < nax; k++)
    if (inner[k] < outer[k] || inner[nax + k] > outer[nax + k]) return false;
  return true;
}

/* Add box `x` to `b` (nax axes): nothing when it is empty or inside a box
 * of b, and the boxes inside it dropped; too many make b whole. */
static void boxes_add(Demand *d, Boxes *b, int nax, const npg_idx *x) {
  if (b->state == BOX_ALL) return;
  for (int k = 0; k < nax; k++)
    if (x[k] >= x[nax + k]) return;
  b->nax = nax;
  int w = 2 * nax;
  for (int i = 0; i < b->n; i++)
    if (contains(b->v + i * w, x, nax)) return;
  for (int i = 0; i < b->n;)
    if (contains(x, b->v + i * w, nax)) memmove(b->v + i * w, b->v + (b->n - 1) * w, sizeof(npg_idx) * (size_t)w), b->n--;
    else i++;
  if (b->n >= DEMAND_MAX_BOXES) {
    b->state = BOX_ALL;
    return;
  }
  if (b->n == b->cap) {
    int cap = b->cap ? 2 * b->cap : 4;
    npg_idx *v = mem_realloc(b->v, sizeof(npg_idx) * (size_t)(cap * w));
    if (!v) {
      d->oom = true;
      b->state = BOX_ALL;
      return;
    }
    b->v = v, b->cap = cap;
  }
  memcpy(b->v + b->n * w, x, sizeof(npg_idx) * (size_t)w);
  b->n++;
  b->state = BOX_SOME;
}

static int slot_of(const Demand *d, const Sym *q) { return vec_position(&d->prog->slots, q); }

void demand_all(Demand *d, const Sym *q) {
  int s = slot_of(d, q);
  if (s >= 0) d->slot[s].state = BOX_ALL;
}

void demand_box(Demand *d, const Sym *q, const npg_idx *lo, const npg_idx *hi) {
  int s = slot_of(d, q);
  if (s < 0) return;
  if (q->ndims == 0) {
    d->slot[s].state = BOX_ALL;
    return;
  }
  npg_idx x[2 * MAX_AXES];
  for (int k = 0; k < q->ndims; k++) {
    npg_idx n = dim_size(d, q->dims[k]);
    x[k] = lo[k] < 0 ? 0 : lo[k];
    x[q->ndims + k] = hi[k] > n ? n : hi[k];
  }
  boxes_add(d, &d->slot[s], q->ndims, x);
}

/* Flat entries [a, b) over the dim axes from `axis` on, the earlier axes
 * fixed by lo/hi. */
static void entries_from(Demand *d, const Sym *q, int axis, npg_idx *lo, npg_idx *hi, npg_idx a, npg_idx b) {
  if (a >= b) return;
  if (axis == q->ndims - 1) {
    lo[axis] = a, hi[axis] = b;
    demand_box(d, q, lo, hi);
    return;
  }
  npg_idx inner = 1;
  for (int k = axis + 1; k < q->ndims; k++) inner *= dim_size(d, q->dims[k]);
  if (inner <= 0) return;
  npg_idx i0 = a / inner, i1 = (b - 1) / inner;
  if (i0 == i1) {
    lo[axis] = i0, hi[axis] = i0 + 1;
    entries_from(d, q, axis + 1, lo, hi, a - i0 * inner, b - i0 * inner);
    return;
  }
  npg_idx start = i0, end = i1;
  if (a % inner) { /* a partial first row */
    lo[axis] = i0, hi[axis] = i0 + 1;
    entries_from(d, q, axis + 1, lo, hi, a % inner, inner);
    start = i0 + 1;
  }
  if (b - i1 * inner == inner) end = i1 + 1; /* the last row whole */
  if (start < end) {
    lo[axis] = start, hi[axis] = end;
    for (int k = axis + 1; k < q->ndims; k++) lo[k] = 0, hi[k] = dim_size(d, q->dims[k]);
    demand_box(d, q, lo, hi);
  }
  if (end == i1) { /* a partial last row */
    lo[axis] = i1, hi[axis] = i1 + 1;
    entries_from(d, q, axis + 1, lo, hi, 0, b - i1 * inner);
  }
}

void demand_entries(Demand *d, const Sym *q, size_t e0, size_t e1) {
  if (q->ndims == 0) {
    if (e0 < e1) demand_all(d, q);
    return;
  }
  size_t nc = 1;
  for (int k = 0; k < q->nstatic; k++) nc *= (size_t)q->shape[k];
  npg_idx lo[MAX_AXES], hi[MAX_AXES];
  entries_from(d, q, 0, lo, hi, (npg_idx)(e0 / nc), (npg_idx)((e1 + nc - 1) / nc));
}

/* ---------------------------------------------------------------- the reads of an expression */

/* Index variables in scope: var[k] ranges over axis[k] of the step's box
 * (-1: over its whole dim); `def` is the definition being read, whose
 * whole references take its own index variables. */
typedef struct Env {
  const Sym *def;
  int n;
  const Sym *var[MAX_AXES];
  int axis[MAX_AXES];
} Env;

typedef struct Walk {
  Demand *d;
  const FullStep *step;
  int member;               /* the member being read; earlier members are fused values */
  const npg_idx *box;       /* the step's box: lo[0..nax), hi[0..nax); NULL: every entry */
  int nax;
  int depth;
} Walk;

static void walk(Walk *w, const Node *n, const Env *env);

static int env_axis(const Env *env, const Sym *v) {
  for (int i = 0; env && i < env->n; i++)
    if (env->var[i] == v) return env->axis[i];
  return -1;
}

/* q's definition read with its index variables on axes map[]. */
static void substitute(Walk *w, const Sym *q, const int *map) {
  Env e2 = {q, q->nivars, {0}, {0}};
  for (int k = 0; k < q->nivars && k < MAX_AXES; k++) e2.var[k] = q->ivars[k], e2.axis[k] = k < q->ndims ? map[k] : -1;
  if (++w->depth > 32) { /* deeper than the emitter rematerializes: every read of q whole */
    const npg_idx *box = w->box;
    w->box = NULL;
    walk(w, q->body, &e2);
    w->box = box;
  } else {
    walk(w, q->body, &e2);
  }
  w->depth--;
}

/* The read q[args] (nargs 0: a whole reference of the definition's entry). */
static void read_q(Walk *w, const Sym *q, Node *const *args, int nargs, const Env *env) {
  int map[MAX_AXES];
  for (int k = 0; k < q->ndims; k++) {
    const Sym *v = NULL;
    if (nargs) v = k < nargs && args[k]->kind == N_NAME ? args[k]->sym : NULL;
    else if (env && env->def && k < env->def->nivars) v = env->def->ivars[k];
    map[k] = v && w->box ? env_axis(env, v) : -1;
  }
  if (q->kind == SYM_STAGE && q->inlined && !q->stage) { /* a constant definition: substituted */
    substitute(w, q, map);
    return;
  }
  for (int m = 0; m < w->member && w->step->kind == STEP_FUSED; m++)
    if (w->step->members[m]->sym == q) {
      bool identity = true;
      for (int k = 0; k < q->ndims; k++) identity &= map[k] == k;
      if (!identity) substitute(w, q, map); /* rematerialized at that entry */
      return;
    }
  int s = slot_of(w->d, q);
  if (s < 0) return;
  npg_idx lo[MAX_AXES], hi[MAX_AXES];
  for (int k = 0; k < q->ndims; k++) {
    lo[k] = map[k] >= 0 ? w->box[map[k]] : 0;
    hi[k] = map[k] >= 0 ? w->box[w->nax + map[k]] : dim_size(w->d, q->dims[k]);
  }
  if (q->ndims == 0) w->d->slot[s].state = BOX_ALL;
  else demand_box(w->d, q, lo, hi);
}

static bool holds_values(const Sym *s) {
  return s && (s->kind == SYM_STAGE || s->kind == SYM_INPUT || s->kind == SYM_EXTERN);
}

static void walk(Walk *w, const Node *n, const Env *env) {
  if (!n) return;
  if (n->kind == N_INDEX && n->a && n->a->kind == N_NAME && holds_values(n->sym)) {
    read_q(w, n->sym, n->args, n->nargs, env);
    return;
  }
  if (n->kind == N_NAME && holds_values(n->sym)) {
    read_q(w, n->sym, NULL, 0, env);
    return;
  }
  if ((n->kind == N_NAME || n->kind == N_INDEX) && n->sym && n->sym->kind == SYM_OP) {
    Env none = {n->sym, 0, {0}, {0}};
    walk(w, n->sym->body, &none);
  }
  walk(w, n->a, env);
  walk(w, n->b, env);
  walk(w, n->c, env);
  for (int i = 0; i < n->nargs; i++) walk(w, n->args[i], env);
}

static void field_all(Demand *d, const Field *f) {
  for (int c = 0; f && c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++)
      for (int a = 0; a < f->comp[c].m[i]->natoms; a++) demand_all(d, f->comp[c].m[i]->atoms[a].q);
}

/* Everything a step reads where it computes its members over `box` (NULL:
 * everywhere). */
static void step_reads(Demand *d, const FullStep *st, const npg_idx *box, int nax) {
  for (int m = 0; m < st->n; m++) {
    const Stage *sg = st->members[m];
    if (!emit_direct_ok(sg)) { /* the canonical form: what its atoms read, whole */
      for (int t = 0; t < sg->nterms; t++) {
        const Term *tm = sg->terms[t];
        field_all(d, tm->num);
        for (int k = 0; k < tm->nops; k++)
          if (tm->ops[k].kind == OPK_DIAG) field_all(d, tm->ops[k].diag);
          else if (tm->ops[k].op->opdef) field_all(d, tm->ops[k].op->opdef->entries);
      }
      continue;
    }
    Walk w = {d, st, m, box, nax, 0};
    Env env = {sg->sym, sg->sym->nivars, {0}, {0}};
    for (int k = 0; k < sg->sym->nivars && k < MAX_AXES; k++) env.var[k] = sg->sym->ivars[k], env.axis[k] = k;
    walk(&w, sg->sym->body, &env);
  }
}

/* ---------------------------------------------------------------- the steps */

static int cmp_idx(const void *a, const void *b) {
  npg_idx x = *(const npg_idx *)a, y = *(const npg_idx *)b;
  return (x > y) - (x < y);
}

static bool same_tails(const npg_idx *a, const npg_idx *b, int nax) {
  for (int k = 1; k < nax; k++)
    if (a[k] != b[k] || a[nax + k] != b[nax + k]) return false;
  return true;
}

/* Boxes that overlap on the first axis cut into slabs of it (each slab
 * holding the other axes' boxes once, inner ones dropped), equal
 * neighbouring slabs joined: overlapping row ranges are computed once. */
static void normalize(Demand *d, Boxes *b) {
  int nax = b->nax, w = 2 * nax;
  if (b->state != BOX_SOME || b->n < 2) return;
  npg_idx *t = mem_malloc(sizeof(npg_idx) * (size_t)(2 * b->n));
  if (!t) {
    d->oom = true;
    return;
  }
  int nt = 0;
  for (int i = 0; i < b->n; i++) t[nt++] = b->v[i * w], t[nt++] = b->v[i * w + nax];
  qsort(t, (size_t)nt, sizeof *t, cmp_idx);
  Boxes out = {BOX_NONE, nax, 0, 0, NULL};
  int prev = -1; /* first box of the previous slab in out */
  npg_idx x[2 * MAX_AXES];
  for (int k = 0; k + 1 < nt; k++) {
    if (t[k] == t[k + 1]) continue;
    int start = out.n;
    for (int i = 0; i < b->n; i++) {
      const npg_idx *y = b->v + i * w;
      if (y[0] > t[k] || y[nax] < t[k + 1]) continue;
      memcpy(x, y, sizeof(npg_idx) * (size_t)w);
      x[0] = t[k], x[nax] = t[k + 1];
      boxes_add(d, &out, nax, x);
    }
    if (out.state == BOX_ALL) break;
    /* the same boxes as the slab before, which ends here: one slab */
    bool same = prev >= 0 && out.n - start == start - prev && out.v[prev * w + nax] == t[k];
    for (int i = start; same && i < out.n; i++) {
      bool found = false;
      for (int j = prev; j < start && !found; j++) found = same_tails(out.v + i * w, out.v + j * w, nax);
      same = found;
    }
    if (same) {
      for (int j = prev; j < start; j++) out.v[j * w + nax] = t[k + 1];
      out.n = start;
    } else if (out.n > start) {
      prev = start;
    } else {
      prev = -1;
    }
  }
  free(t);
  if (out.state == BOX_ALL || d->oom) {
    free(out.v);
    b->state = BOX_ALL;
    return;
  }
  free(b->v);
  *b = out;
  b->cap = out.cap;
}

int demand_propagate(Demand *d) {
  for (int k = 0; k < d->plan->n; k++) d->step[k].state = BOX_NONE, d->step[k].n = 0;
  for (int k = d->plan->n - 1; k >= 0; k--) {
    const FullStep *st = &d->plan->steps[k];
    Boxes *r = &d->step[k];
    const Sym *first = st->members[0]->sym;
    int nax = first->nivars;
    for (int m = 0; m < st->n && r->state != BOX_ALL; m++) {
      const Boxes *q = &d->slot[slot_of(d, st->members[m]->sym)];
      if (q->state == BOX_ALL || (q->state == BOX_SOME && q->nax != nax)) r->state = BOX_ALL;
      for (int i = 0; q->state == BOX_SOME && i < q->n; i++) boxes_add(d, r, nax, q->v + i * 2 * nax);
    }
    if (r->state == BOX_NONE) continue;
    if (!st->boxed) r->state = BOX_ALL;
    normalize(d, r);
    if (r->state == BOX_SOME) { /* boxes covering the domain: whole */
      double vol = 0, all = 1;
      for (int i = 0; i < r->n; i++) {
        double v = 1;
        for (int a = 0; a < nax; a++) v *= (double)(r->v[i * 2 * nax + nax + a] - r->v[i * 2 * nax + a]);
        vol += v;
      }
      for (int a = 0; a < nax; a++) all *= (double)dim_size(d, first->ivars[a]->range);
      if (vol >= all) r->state = BOX_ALL;
    }
    if (r->state == BOX_ALL) step_reads(d, st, NULL, nax);
    else
      for (int i = 0; i < r->n; i++) step_reads(d, st, r->v + i * 2 * nax, nax);
  }
  /* what inputs and externs are read, without overlaps (demand_ranges) */
  for (int s = 0; s < d->prog->slots.n; s++) normalize(d, &d->slot[s]);
  return d->oom ? -1 : 0;
}

static int cmp_range(const void *a, const void *b) {
  const size_t *x = a, *y = b;
  return (x[0] > y[0]) - (x[0] < y[0]);
}

long demand_ranges(const Demand *d, const Sym *q, size_t *r, long cap) {
  int s = slot_of(d, q);
  if (s < 0 || d->slot[s].state == BOX_ALL || q->ndims == 0) return s >= 0 && d->slot[s].state == BOX_NONE ? 0 : -1;
  const Boxes *b = &d->slot[s];
  if (b->state == BOX_NONE) return 0;
  int nax = q->ndims;
  size_t nc = 1;
  for (int k = 0; k < q->nstatic; k++) nc *= (size_t)q->shape[k];
  long n = 0;
  for (int i = 0; i < b->n; i++) {
    const npg_idx *lo = b->v + i * 2 * nax, *hi = lo + nax;
    npg_idx at[MAX_AXES];
    memcpy(at, lo, sizeof(npg_idx) * (size_t)nax);
    for (;;) { /* every index of the axes but the last in the box: one range along the last */
      size_t row = 0;
      for (int k = 0; k + 1 < nax; k++) row = row * (size_t)dim_size(d, q->dims[k]) + (size_t)at[k];
      size_t last = (size_t)dim_size(d, q->dims[nax - 1]);
      size_t e0 = (row * last + (size_t)lo[nax - 1]) * nc, e1 = (row * last + (size_t)hi[nax - 1]) * nc;
      if (n > 0 && r[2 * n - 1] == e0) r[2 * n - 1] = e1; /* continues the previous range */
      else if (n == cap) return -1;
      else r[2 * n] = e0, r[2 * n + 1] = e1, n++;
      int k = nax - 2;
      while (k >= 0 && ++at[k] == hi[k]) at[k] = lo[k], k--;
      if (k < 0) break;
    }
  }
  qsort(r, (size_t)n, 2 * sizeof *r, cmp_range);
  return n;
}

long demand_range_bound(const Demand *d, const Sym *q) {
  int s = slot_of(d, q);
  if (s < 0 || d->slot[s].state == BOX_ALL || q->ndims == 0) return s >= 0 && d->slot[s].state == BOX_NONE ? 0 : -1;
  const Boxes *b = &d->slot[s];
  if (b->state == BOX_NONE) return 0;
  long n = 0;
  for (int i = 0; i < b->n; i++) { /* one range per index of the axes but the last */
    const npg_idx *lo = b->v + i * 2 * q->ndims, *hi = lo + q->ndims;
    long rows = 1;
    for (int k = 0; k + 1 < q->ndims; k++) rows *= (long)(hi[k] - lo[k]);
    n += rows;
  }
  return n;
}

int demand_step(const Demand *d, int k, const npg_idx **box) {
  const Boxes *r = &d->step[k];
  *box = r->v;
  return r->state == BOX_NONE ? -1 : r->state == BOX_ALL ? 0 : r->n;
}
