/* cost.c — reduced evaluation cost in multiply-adds, as a formula in basis
 * sizes m_<class> (DESIGN §1: reduced cost depends only on basis sizes).
 * Contraction of an order-(k+1) tensor: m_y · Π m_in; an operator tensor
 * (row, col, inputs): m_y² · Π m_in; LU of a reduced operator: (2/3) m_y³;
 * a root by eigendecomposition: about 9 m_y³; an extern's learned map:
 * S · (m_in + m_y) for S training samples. */
#include <stdlib.h>
#include <string.h>

#include "ir.h"

typedef struct Mon {
  double k;
  char *key;
} Mon;

typedef struct Poly2 {
  Mon m[256];
  int n;
} Poly2;

static int cmp_str(const void *a, const void *b) { return strcmp(*(char *const *)a, *(char *const *)b); }

static void add_mon(Ctx *ctx, Poly2 *p, double k, const char **syms, int n) {
  qsort(syms, (size_t)n, sizeof syms[0], cmp_str);
  char *key = "";
  for (int i = 0; i < n;) {
    int j = i;
    while (j < n && strcmp(syms[j], syms[i]) == 0) j++;
    key = arena_printf(ctx, "%s%s%s", key, *key ? "·" : "", syms[i]);
    if (j - i > 1) key = arena_printf(ctx, "%s^%d", key, j - i);
    i = j;
  }
  for (int i = 0; i < p->n; i++)
    if (strcmp(p->m[i].key, key) == 0) {
      p->m[i].k += k;
      return;
    }
  if (p->n < 256) p->m[p->n++] = (Mon){k, key};
}

static const char *size_of(const Program *prog, const Sym *q) {
  if (q->klass < 0) return "?";
  return ((BasisClass *)prog->classes.v[q->klass])->size_name;
}

static void tensors_cost(Ctx *ctx, const Program *prog, Poly2 *p, const TensorList *tl, const char *y, int nout) {
  for (int g = 0; g < tl->n; g++) {
    const char *syms[24];
    int n = 0;
    for (int i = 0; i < nout; i++) syms[n++] = y;
    for (int i = 0; i < tl->g[g].ninputs && n < 24; i++) syms[n++] = size_of(prog, tl->g[g].inputs[i]);
    add_mon(ctx, p, 1, syms, n);
  }
}

static void stage_poly(Ctx *ctx, const Program *prog, const Stage *st, Poly2 *p) {
  const char *y = size_of(prog, st->sym);
  if (st->kind == ST_EXTERN) {
    for (int i = 0; i < st->sym->nof; i++) {
      const char *s[2] = {"S", size_of(prog, st->sym->of[i])};
      add_mon(ctx, p, 1, s, 2);
    }
    const char *s[2] = {"S", y};
    add_mon(ctx, p, 1, s, 2);
    return;
  }
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    if (!tm->named_num) tensors_cost(ctx, prog, p, &tm->num_tensors, y, 1);
    for (int k = 0; k < tm->nops; k++) {
      const OpPow *o = &tm->ops[k];
      if (o->kind == OPK_DIAG) tensors_cost(ctx, prog, p, &tm->op_tensors[k], y, 2);
      else {
        const OpDef *od = o->op->opdef;
        if (od) tensors_cost(ctx, prog, p, &od->tensors, y, 2);
      }
      const char *s3[3] = {y, y, y};
      const char *s2[2] = {y, y};
      if (o->q != 1) add_mon(ctx, p, 9, s3, 3);                 /* eigendecomposition */
      else if (o->p < 0) {
        add_mon(ctx, p, 2.0 / 3.0, s3, 3);                       /* LU */
        add_mon(ctx, p, 2.0 * (double)(-o->p), s2, 2);          /* solves */
      } else add_mon(ctx, p, (double)o->p, s2, 2);              /* products */
    }
  }
}

static char *poly_str(Ctx *ctx, Poly2 *p) {
  /* highest total degree first */
  for (int i = 0; i < p->n; i++)
    for (int j = i + 1; j < p->n; j++) {
      int di = 1, dj = 1;
      for (char *c = p->m[i].key; *c; c++) di += *c == '^' ? (c[1] - '0') - 1 : (*c == '\xb7');
      for (char *c = p->m[j].key; *c; c++) dj += *c == '^' ? (c[1] - '0') - 1 : (*c == '\xb7');
      if (dj > di) {
        Mon t = p->m[i];
        p->m[i] = p->m[j];
        p->m[j] = t;
      }
    }
  char *s = "";
  for (int i = 0; i < p->n; i++) {
    const char *sep = *s ? " + " : "";
    double k = p->m[i].k;
    if (k == 1) s = arena_printf(ctx, "%s%s%s", s, sep, p->m[i].key);
    else if (k == 2.0 / 3.0) s = arena_printf(ctx, "%s%s(2/3)·%s", s, sep, p->m[i].key);
    else s = arena_printf(ctx, "%s%s%g·%s", s, sep, k, p->m[i].key);
  }
  return *s ? s : "0";
}

char *stage_cost(Ctx *ctx, const Program *prog, const Stage *st) {
  Poly2 *p = arena_alloc(ctx, sizeof *p);
  stage_poly(ctx, prog, st, p);
  return poly_str(ctx, p);
}

char *cost_formula(Ctx *ctx, const Program *prog) {
  Poly2 *p = arena_alloc(ctx, sizeof *p);
  for (int i = 0; i < prog->stages.n; i++) stage_poly(ctx, prog, prog->stages.v[i], p);
  return poly_str(ctx, p);
}

double cost_value(const Program *prog, const long *m, long S) {
  Ctx *ctx = prog->ctx;
  Poly2 *p = arena_alloc(ctx, sizeof *p);
  for (int i = 0; i < prog->stages.n; i++) stage_poly(ctx, prog, prog->stages.v[i], p);
  double total = 0;
  for (int i = 0; i < p->n; i++) {
    /* the key is "m_a^2·m_b·S": factors joined by a middle dot, each "name" or "name^e" */
    double v = p->m[i].k;
    for (const char *f = p->m[i].key; *f;) {
      const char *end = strstr(f, "\xc2\xb7"), *stop = end ? end : f + strlen(f), *hat = memchr(f, '^', (size_t)(stop - f));
      size_t len = (size_t)((hat ? hat : stop) - f);
      int e = hat ? atoi(hat + 1) : 1;
      double x = 0;
      if (len == 1 && *f == 'S') x = (double)S;
      for (int c = 0; c < prog->classes.n; c++) {
        const char *name = ((BasisClass *)prog->classes.v[c])->size_name;
        if (strlen(name) == len && memcmp(name, f, len) == 0) x = (double)m[c];
      }
      for (int k = 0; k < e; k++) v *= x;
      f = end ? end + 2 : stop;
    }
    total += v;
  }
  return total;
}
