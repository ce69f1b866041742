/* poly.c — monomials, polynomials and fields of the canonical form: their
 * arithmetic, like monomials combined, and their canonical text (which
 * doubles as a structural key). */
#include <stdlib.h>
#include <string.h>

#include "ir.h"

Mono *mono_const(Ctx *ctx, Node *coef) {
  Mono *m = arena_alloc(ctx, sizeof *m);
  m->coef = coef;
  return m;
}

Poly *poly_new(Ctx *ctx) { return arena_alloc(ctx, sizeof(Poly)); }

void poly_push(Ctx *ctx, Poly *p, Mono *m) {
  if (p->n == p->cap) {
    int cap = p->cap ? p->cap * 2 : 4;
    p->m = arena_grow(ctx, p->m, sizeof(Mono *) * (size_t)p->cap, sizeof(Mono *) * (size_t)cap);
    p->cap = cap;
  }
  p->m[p->n++] = m;
}

bool poly_is_zero(const Poly *p) { return p->n == 0; }

Field *field_new(Ctx *ctx, int ncomp) {
  Field *f = arena_alloc(ctx, sizeof *f);
  f->ncomp = ncomp;
  f->comp = arena_alloc(ctx, sizeof(Poly) * (size_t)(ncomp > 0 ? ncomp : 1));
  return f;
}

/* ---------------------------------------------------------------- arithmetic */
static Node *subst_node(Ctx *ctx, Node *n, Sym *from, Sym *to) {
  if (!n) return NULL;
  if (n->kind == N_NAME && n->sym == from) return coef_name(ctx, to);
  Node *c = arena_alloc(ctx, sizeof *c);
  *c = *n;
  c->a = subst_node(ctx, n->a, from, to);
  c->b = subst_node(ctx, n->b, from, to);
  c->c = subst_node(ctx, n->c, from, to);
  if (n->nargs) {
    c->args = arena_alloc(ctx, sizeof(Node *) * (size_t)n->nargs);
    for (int i = 0; i < n->nargs; i++) c->args[i] = subst_node(ctx, n->args[i], from, to);
  }
  return c;
}

Mono *mono_copy(Ctx *ctx, const Mono *m) {
  Mono *c = arena_alloc(ctx, sizeof *c);
  *c = *m;
  c->sums = arena_alloc(ctx, sizeof(SumVar) * (size_t)(m->nsums + 1));
  if (m->nsums) memcpy(c->sums, m->sums, sizeof(SumVar) * (size_t)m->nsums);
  c->atoms = arena_alloc(ctx, sizeof(Atom) * (size_t)(m->natoms + 1));
  if (m->natoms) memcpy(c->atoms, m->atoms, sizeof(Atom) * (size_t)m->natoms);
  return c;
}

/* Rename summation variable `from` to a fresh one in a copy of m. */
Mono *mono_rename(Ctx *ctx, const Mono *m, Sym *from) {
  Sym *to = arena_alloc(ctx, sizeof *to);
  *to = *from;
  to->name = arena_printf(ctx, "%s'%d", from->name, ++ctx->uniq);
  to->id = ctx->uniq;
  Mono *c = mono_copy(ctx, m);
  c->guard = subst_node(ctx, m->guard, from, to);
  c->coef = subst_node(ctx, m->coef, from, to);
  for (int s = 0; s < c->nsums; s++) {
    if (c->sums[s].var == from) c->sums[s].var = to;
    c->sums[s].lo = subst_node(ctx, c->sums[s].lo, from, to);
    c->sums[s].hi = subst_node(ctx, c->sums[s].hi, from, to);
  }
  for (int a = 0; a < c->natoms; a++) {
    Atom *at = &c->atoms[a];
    Node **idx = arena_alloc(ctx, sizeof(Node *) * (size_t)at->nidx);
    for (int i = 0; i < at->nidx; i++) idx[i] = subst_node(ctx, at->idx[i], from, to);
    at->idx = idx;
  }
  return c;
}

Mono *mono_mul(Ctx *ctx, const Mono *a, const Mono *b) {
  for (int i = 0; i < a->nsums; i++)
    for (int j = 0; j < b->nsums; j++)
      if (a->sums[i].var == b->sums[j].var) return mono_mul(ctx, a, mono_rename(ctx, b, b->sums[j].var));
  Mono *m = arena_alloc(ctx, sizeof *m);
  m->guard = coef_and(ctx, a->guard, b->guard);
  m->coef = coef_bin(ctx, N_MUL, a->coef, b->coef);
  m->nsums = a->nsums + b->nsums;
  m->sums = arena_alloc(ctx, sizeof(SumVar) * (size_t)(m->nsums + 1));
  if (a->nsums) memcpy(m->sums, a->sums, sizeof(SumVar) * (size_t)a->nsums);
  if (b->nsums) memcpy(m->sums + a->nsums, b->sums, sizeof(SumVar) * (size_t)b->nsums);
  m->natoms = a->natoms + b->natoms;
  m->atoms = arena_alloc(ctx, sizeof(Atom) * (size_t)(m->natoms + 1));
  /* Merge by quantity id so x*y and y*x print (and key) alike. */
  int i = 0, j = 0, k = 0;
  while (i < a->natoms || j < b->natoms) {
    if (j >= b->natoms || (i < a->natoms && a->atoms[i].q->id <= b->atoms[j].q->id)) m->atoms[k++] = a->atoms[i++];
    else m->atoms[k++] = b->atoms[j++];
  }
  return m;
}

Mono *mono_guarded(Ctx *ctx, const Mono *m, Node *guard) {
  if (!guard) return (Mono *)m;
  Mono *c = mono_copy(ctx, m);
  c->guard = coef_and(ctx, guard, m->guard);
  return c;
}

void poly_add(Ctx *ctx, Poly *dst, const Poly *src, Node *guard) {
  for (int i = 0; i < src->n; i++) poly_push(ctx, dst, mono_guarded(ctx, src->m[i], guard));
}

Poly poly_mul(Ctx *ctx, const Poly *a, const Poly *b) {
  Poly p = {0};
  for (int i = 0; i < a->n; i++)
    for (int j = 0; j < b->n; j++) poly_push(ctx, &p, mono_mul(ctx, a->m[i], b->m[j]));
  return p;
}

Field *field_ones(Ctx *ctx, int ncomp) {
  Field *f = field_new(ctx, ncomp);
  for (int c = 0; c < ncomp; c++) poly_push(ctx, &f->comp[c], mono_const(ctx, coef_num(ctx, 1)));
  return f;
}


bool field_is_coef(const Field *f) {
  for (int c = 0; c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++)
      if (f->comp[c].m[i]->natoms) return false;
  return true;
}

/* ---------------------------------------------------------------- like monomials */
static char *text_of(Ctx *ctx, void (*print)(FILE *, const void *), const void *x) {
  return print_to_arena(ctx, print, x);
}

static void print_atom(FILE *out, const void *p) {
  const Atom *a = p;
  fprintf(out, "%s[", a->q->name);
  for (int i = 0; i < a->nidx; i++) {
    if (i) fputc(',', out);
    print_node(out, a->idx[i]);
  }
  fputc(']', out);
}

static void print_mono_shape(FILE *out, const void *p) {  /* everything but the coefficient */
  const Mono *m = p;
  if (m->guard) print_node(out, m->guard);
  fputc('|', out);
  for (int s = 0; s < m->nsums; s++) {
    fprintf(out, "%s=", m->sums[s].var->name);
    print_node(out, m->sums[s].lo);
    fputs("..", out);
    print_node(out, m->sums[s].hi);
    fputc(';', out);
  }
  fputc('|', out);
  for (int a = 0; a < m->natoms; a++) print_atom(out, &m->atoms[a]);
}

/* Sort each monomial's atoms into a canonical order and add the
 * coefficients of monomials that read the same entries (g_a g_b and g_b g_a
 * are one tensor entry); drop monomials whose coefficients cancel. */
static void combine_like(Ctx *ctx, Poly *p) {
  char **keys = arena_alloc(ctx, sizeof(char *) * (size_t)(p->n + 1));
  Poly out = {0};
  char **out_keys = arena_alloc(ctx, sizeof(char *) * (size_t)(p->n + 1));
  for (int i = 0; i < p->n; i++) {
    Mono *m = mono_copy(ctx, p->m[i]);
    char **ak = arena_alloc(ctx, sizeof(char *) * (size_t)(m->natoms + 1));
    for (int a = 0; a < m->natoms; a++) ak[a] = text_of(ctx, print_atom, &m->atoms[a]);
    for (int a = 1; a < m->natoms; a++)
      for (int b = a; b > 0 && strcmp(ak[b - 1], ak[b]) > 0; b--) {
        char *tk = ak[b];
        ak[b] = ak[b - 1];
        ak[b - 1] = tk;
        Atom ta = m->atoms[b];
        m->atoms[b] = m->atoms[b - 1];
        m->atoms[b - 1] = ta;
      }
    keys[i] = text_of(ctx, print_mono_shape, m);
    int j;
    for (j = 0; j < out.n; j++)
      if (strcmp(out_keys[j], keys[i]) == 0) break;
    if (j < out.n) {
      Mono *o = mono_copy(ctx, out.m[j]);
      o->coef = coef_bin(ctx, N_ADD, o->coef, m->coef);
      out.m[j] = o;
    } else {
      out_keys[out.n] = keys[i];
      poly_push(ctx, &out, m);
    }
  }
  Poly kept = {0};
  for (int i = 0; i < out.n; i++)
    if (!coef_is_num(out.m[i]->coef, 0)) poly_push(ctx, &kept, out.m[i]);
  *p = kept;
}

void field_combine_like(Ctx *ctx, Field *f) {
  for (int c = 0; c < f->ncomp; c++) combine_like(ctx, &f->comp[c]);
}

/* ---------------------------------------------------------------- degree and text */

int mono_degree(const Mono *m) { return m->natoms; }

int field_degree(const Field *f) {
  int d = 0;
  for (int c = 0; c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++)
      if (f->comp[c].m[i]->natoms > d) d = f->comp[c].m[i]->natoms;
  return d;
}

void print_mono(FILE *out, const Mono *m) {
  if (m->guard) {
    fputs("[", out);
    print_node(out, m->guard);
    fputs("] ", out);
  }
  for (int s = 0; s < m->nsums; s++) {
    fprintf(out, "sum(%s = ", m->sums[s].var->name);
    print_node(out, m->sums[s].lo);
    fputs("..", out);
    print_node(out, m->sums[s].hi);
    fputs(") ", out);
  }
  bool one = m->coef->kind == N_NUM && m->coef->num == 1;
  if (!one || m->natoms == 0) {
    bool paren = m->coef->kind == N_ADD || m->coef->kind == N_SUB;
    if (paren) fputc('(', out);
    print_node(out, m->coef);
    if (paren) fputc(')', out);
  }
  for (int a = 0; a < m->natoms; a++) {
    if (a || !one || m->natoms == 0) fputc('*', out);
    const Atom *at = &m->atoms[a];
    fputs(at->q->name, out);
    if (at->nidx) {
      fputc('[', out);
      for (int i = 0; i < at->nidx; i++) {
        if (i) fputs(", ", out);
        print_node(out, at->idx[i]);
      }
      fputc(']', out);
    }
  }
}

void print_poly(FILE *out, const Poly *p) {
  if (p->n == 0) {
    fputc('0', out);
    return;
  }
  for (int i = 0; i < p->n; i++) {
    if (i) fputs(" + ", out);
    print_mono(out, p->m[i]);
  }
}

void print_field(FILE *out, const Field *f) {
  if (f->ncomp == 1) {
    print_poly(out, &f->comp[0]);
    return;
  }
  fputc('[', out);
  for (int c = 0; c < f->ncomp; c++) {
    if (c) fputs(", ", out);
    print_poly(out, &f->comp[c]);
  }
  fputc(']', out);
}

void print_term(FILE *out, const Term *t) {
  for (int k = t->nops - 1; k >= 0; k--) {
    const OpPow *o = &t->ops[k];
    if (o->kind == OPK_DECL) fputs(o->op->name, out);
    else {
      fputs("diag(", out);
      print_field(out, o->diag);
      fputc(')', out);
    }
    if (o->q == 1) fprintf(out, "^%ld ", o->p);
    else fprintf(out, "^(%ld/%ld) ", o->p, o->q);
  }
  if (t->nops) fputc('(', out);
  print_field(out, t->num);
  if (t->nops) fputc(')', out);
}

static void print_field_cb(FILE *out, const void *f) { print_field(out, f); }

char *field_key(Ctx *ctx, const Field *f) { return print_to_arena(ctx, print_field_cb, f); }
