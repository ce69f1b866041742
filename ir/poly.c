/* poly.c — monomials, polynomials and fields of the canonical form, and
 * their canonical text (which doubles as a structural key). */
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
