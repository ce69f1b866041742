/* verify.c — invariants of the stage program, checked after lowering and
 * after basis analysis (STYLE: check between stages). A violation is a bug
 * in the compiler, reported as an internal error. */
#include "ir.h"

static void verify_field(Ctx *ctx, const Field *f, int ncomp) {
  iassert(ctx, f && f->ncomp == ncomp);
  for (int c = 0; c < f->ncomp; c++)
    for (int i = 0; i < f->comp[c].n; i++) {
      const Mono *m = f->comp[c].m[i];
      iassert(ctx, m->coef);
      for (int a = 0; a < m->natoms; a++) {
        const Atom *at = &m->atoms[a];
        iassert(ctx, at->q && (at->q->kind == SYM_INPUT || at->q->kind == SYM_STAGE || at->q->kind == SYM_EXTERN));
        iassert(ctx, !at->q->inlined);
        iassert(ctx, at->nidx == at->q->ndims + at->q->nstatic);
        for (int k = 0; k < at->nidx; k++) iassert(ctx, at->idx[k]);
        for (int k = 0; k < at->q->nstatic; k++) iassert(ctx, at->idx[at->q->ndims + k]->kind == N_NUM);
      }
    }
}

void verify_program(Ctx *ctx, const Program *prog) {
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    iassert(ctx, st->sym && st->sym->stage == st);
    if (st->kind == ST_EXTERN) continue;
    for (int t = 0; t < st->nterms; t++) {
      const Term *tm = st->terms[t];
      verify_field(ctx, tm->num, st->ncomp);
      for (int k = 0; k < tm->nops; k++) {
        const OpPow *o = &tm->ops[k];
        iassert(ctx, o->q > 0);
        if (o->kind == OPK_DIAG) {
          verify_field(ctx, o->diag, st->ncomp);
          iassert(ctx, !(o->q == 1 && o->p >= 0));  /* folded into the polynomial */
        } else {
          iassert(ctx, o->op && o->op->kind == SYM_OP);
        }
      }
    }
    /* Operands are evaluated before the stage. */
    for (int t = 0; t < st->nterms; t++)
      for (int c = 0; c < st->terms[t]->num->ncomp; c++)
        for (int m = 0; m < st->terms[t]->num->comp[c].n; m++)
          for (int a = 0; a < st->terms[t]->num->comp[c].m[m]->natoms; a++) {
            const Sym *q = st->terms[t]->num->comp[c].m[m]->atoms[a].q;
            if (q->kind == SYM_INPUT) continue;
            bool before = false;
            for (int j = 0; j < i; j++)
              if (((Stage *)prog->stages.v[j])->sym == q) before = true;
            iassert(ctx, before);
          }
  }
  if (prog->classes.n) {
    for (int i = 0; i < prog->quantities.n; i++) {
      const Sym *s = prog->quantities.v[i];
      iassert(ctx, s->klass >= 0 && s->klass < prog->classes.n);
    }
    for (int i = 0; i < prog->stages.n; i++) {
      const Stage *st = prog->stages.v[i];
      for (int t = 0; t < st->nterms; t++)
        if (st->terms[t]->named_num) iassert(ctx, st->terms[t]->named_num->klass == st->klass);
    }
  }
}
