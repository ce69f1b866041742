/* lower.c — checked stages to the canonical form of ir.h (DESIGN §4):
 * lower_program() lowers every definition's expression (lower_expr.c), makes
 * it a stage (its kind, like monomials combined, its tensor groups), and
 * lists the quantities with a basis in evaluation order. `inline` is
 * checked here: only a linear quantity of one input folds into its
 * consumers.
 */
#include <stdlib.h>
#include <string.h>

#include "lower.h"

/* ---------------------------------------------------------------- stages */

static StageKind kind_of_terms(Term **terms, int n) {
  StageKind k = ST_CONTRACT;
  for (int i = 0; i < n; i++)
    for (int j = 0; j < terms[i]->nops; j++) {
      const OpPow *o = &terms[i]->ops[j];
      if (o->q != 1) return ST_ROOT;
      if (o->p < 0) k = ST_INVERSE;
      else if (k == ST_CONTRACT) k = ST_APPLY;
    }
  return k;
}

bool lower_interp_eligible(const Stage *st) {
  if (st->kind != ST_INVERSE && st->kind != ST_ROOT) return false;
  for (int t = 0; t < st->nterms; t++)
    for (int k = 0; k < st->terms[t]->nops; k++)
      if (st->terms[t]->ops[k].kind != OPK_DIAG) return false;
  return true;
}

/* Mark `s` in `marked` (per prog->quantities) and, recursively, every
 * quantity its stage's terms read. */
static void mark_reads(const Program *prog, const Sym *s, bool *marked) {
  int q = 0;
  while (q < prog->quantities.n && prog->quantities.v[q] != s) q++;
  if (q == prog->quantities.n || marked[q]) return;
  marked[q] = true;
  const Stage *st = s->stage;
  for (int t = 0; st && t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    if (tm->named_num) mark_reads(prog, tm->named_num, marked);
    for (int g = 0; g < tm->num_tensors.n; g++)
      for (int k = 0; k < tm->num_tensors.g[g].ninputs; k++) mark_reads(prog, tm->num_tensors.g[g].inputs[k], marked);
    for (int o = 0; o < tm->nops && tm->op_tensors; o++)
      for (int g = 0; g < tm->op_tensors[o].n; g++)
        for (int k = 0; k < tm->op_tensors[o].g[g].ninputs; k++)
          mark_reads(prog, tm->op_tensors[o].g[g].inputs[k], marked);
  }
}

bool *lower_under_powers(const Program *prog) {
  if (prog->externs.n > 0) return NULL;
  bool *marked = mem_calloc((size_t)prog->quantities.n + 1, sizeof(bool));
  bool any = false;
  for (int i = 0; marked && i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (!lower_interp_eligible(st)) continue;
    for (int t = 0; t < st->nterms; t++)
      for (int o = 0; o < st->terms[t]->nops; o++)
        for (int g = 0; g < st->terms[t]->op_tensors[o].n; g++)
          for (int k = 0; k < st->terms[t]->op_tensors[o].g[g].ninputs; k++, any = true)
            mark_reads(prog, st->terms[t]->op_tensors[o].g[g].inputs[k], marked);
  }
  if (!any) free(marked);
  return any ? marked : NULL;
}

/* Is the term's polynomial exactly a named quantity of the stage's shape,
 * entry for entry (the identity map)? Then it shares the stage's basis. */
static Sym *named_numerator(const Sym *s, const Field *f) {
  Sym *q = NULL;
  for (int c = 0; c < f->ncomp; c++) {
    const Poly *p = &f->comp[c];
    if (p->n != 1) return NULL;
    const Mono *m = p->m[0];
    if (m->guard || m->nsums || m->natoms != 1 || !coef_is_num(m->coef, 1)) return NULL;
    const Atom *a = &m->atoms[0];
    if (q && a->q != q) return NULL;
    q = a->q;
    if (q->ndims != s->nivars || q->nstatic != s->nstatic) return NULL;
    for (int i = 0; i < s->nstatic; i++)
      if (q->shape[i] != s->shape[i]) return NULL;
    for (int i = 0; i < q->ndims; i++)
      if (a->idx[i]->kind != N_NAME || a->idx[i]->sym != s->ivars[i]) return NULL;
    for (int i = 0, cc = c, div = f->ncomp; i < q->nstatic; i++) {
      div /= q->shape[i];
      if (!coef_is_num(a->idx[q->ndims + i], cc / div)) return NULL;
      cc %= div;
    }
  }
  return q;
}

void tensor_groups(Ctx *ctx, const Sym *owner, const Field *f, int base_order, TensorList *out);

Stage *lower_stage(Lowerer *L, Sym *s, Value *v) {
  Ctx *ctx = L->ctx;
  Stage *st = arena_alloc(ctx, sizeof *st);
  st->sym = s;
  st->ncomp = v->ncomp;
  st->klass = -1;
  st->nterms = v->terms.n;
  st->terms = (Term **)v->terms.v;
  st->kind = kind_of_terms(st->terms, st->nterms);
  for (int i = 0; i < st->nterms; i++) {
    Term *t = st->terms[i];
    field_combine_like(L->ctx, t->num);
    for (int k = 0; k < t->nops; k++)
      if (t->ops[k].kind == OPK_DIAG) field_combine_like(L->ctx, t->ops[k].diag);
    if (t->nops) t->named_num = named_numerator(s, t->num);
    if (!t->named_num) tensor_groups(ctx, s, t->num, 1, &t->num_tensors);
    t->op_tensors = arena_alloc(ctx, sizeof(TensorList) * (size_t)(t->nops + 1));
    for (int k = 0; k < t->nops; k++)
      if (t->ops[k].kind == OPK_DIAG) tensor_groups(ctx, s, t->ops[k].diag, 2, &t->op_tensors[k]);
  }
  if (st->nterms == 0)
    vec_push(ctx, &L->prog->notes,
             arena_printf(ctx, "%s:%d:%d: stage '%s' is identically zero", s->loc.file ? s->loc.file->name : "?",
                          s->loc.line, s->loc.col, s->name));
  s->stage = st;
  return st;
}

static void lower_op(Lowerer *L, Sym *op) {
  Ctx *ctx = L->ctx;
  L->cur = op;
  L->nintro = 0;
  PtrVec open = {0};
  L->open_sums = &open;
  Value *v = lower_expr(L, op->body, NULL);
  /* divisions and roots inside the entries: named elementwise, not the whole N x N entry (issue 38) */
  if (v->terms.n > 1 || (v->terms.n == 1 && ((Term *)v->terms.v[0])->nops)) {
    Value *e = lower_expr_op_entries(L, v, op->body);
    if (e) v = e;
  }
  if (v->terms.n > 1 || (v->terms.n == 1 && ((Term *)v->terms.v[0])->nops)) v = lower_expr_introduce(L, v, op->body, NULL);
  OpDef *od = arena_alloc(ctx, sizeof *od);
  od->sym = op;
  op->opdef = od;
  od->entries = v->terms.n ? ((Term *)v->terms.v[0])->num : field_new(ctx, 1);
  field_combine_like(L->ctx, od->entries);
  tensor_groups(ctx, op, od->entries, 2, &od->tensors);
  /* DESIGN §13: fewer entries than rows × cols grow as — every tensor's
     count of lower degree in the dims than the op's index variables, or
     its columns fixed per row by a padded row table (TensorGroup.rows_bound) */
  od->sparse = op->nivars >= 2;
  for (int g = 0; g < od->tensors.n; g++)
    od->sparse &= od->tensors.g[g].nnz_degree < op->nivars || od->tensors.g[g].rows_bound;
  vec_push(ctx, &L->prog->opdefs, od);
}

/* `inline c` folds c into its consumers; DESIGN §4 allows it only for a
 * linear quantity (otherwise folding raises the consumers' tensor orders
 * behind the user's back). */
static void check_inline(Lowerer *L, Sym *s) {
  L->cur = s;
  PtrVec open = {0};
  L->open_sums = &open;
  Value *v = lower_expr(L, s->body, NULL);
  if (s->body->ty.var == V_VARYING) { /* a temp of the full evaluator */
    s->stage = lower_stage(L, s, v);
    vec_push(L->ctx, &L->prog->temps, s);
  }
  for (int i = 0; i < v->terms.n; i++) {
    Term *t = v->terms.v[i];
    if (t->nops)
      error_at(L->ctx, s->inline_loc, "cannot inline '%s': it is not polynomial (it divides or takes a root); "
               "only a linear quantity can be folded into its consumers", s->name);
    int deg = field_degree(t->num);
    if (deg > 1)
      error_at(L->ctx, s->inline_loc, "cannot inline '%s': it has degree %d in its inputs; only a linear quantity "
               "can be folded into its consumers", s->name, deg);
    const Sym *first = NULL;
    for (int c = 0; c < t->num->ncomp; c++)
      for (int m = 0; m < t->num->comp[c].n; m++)
        for (int a = 0; a < t->num->comp[c].m[m]->natoms; a++) {
          const Sym *q = t->num->comp[c].m[m]->atoms[a].q;
          if (first && q != first)
            error_at(L->ctx, s->inline_loc, "cannot inline '%s': it reads both '%s' and '%s'; only a linear quantity "
                     "of one input can be folded into its consumers (paper §4.2)", s->name, first->name, q->name);
          first = q;
        }
  }
}

void lower_program(Ctx *ctx, Program *prog) {
  Lowerer L = {0};
  L.ctx = ctx;
  L.prog = prog;
  for (int i = 0; i < prog->inlined.n; i++) check_inline(&L, prog->inlined.v[i]);
  /* temps are computed in definition order (a temp may read an earlier one) */
  for (int i = 1; i < prog->temps.n; i++)
    for (int j = i; j > 0 && ((Sym *)prog->temps.v[j - 1])->id > ((Sym *)prog->temps.v[j])->id; j--) {
      void *t = prog->temps.v[j];
      prog->temps.v[j] = prog->temps.v[j - 1];
      prog->temps.v[j - 1] = t;
    }
  for (Decl *d = prog->decls; d; d = d->next) {
    if (d->kind != D_STAGE && d->kind != D_OP && d->kind != D_EXTERN) continue;
    Sym *s = NULL;
    for (int i = 0; i < prog->quantities.n && !s; i++)
      if (((Sym *)prog->quantities.v[i])->decl == d) s = prog->quantities.v[i];
    for (int i = 0; i < prog->ops.n && !s; i++)
      if (((Sym *)prog->ops.v[i])->decl == d) s = prog->ops.v[i];
    if (!s) continue; /* an inlined or constant definition */
    if (s->kind == SYM_OP) {
      lower_op(&L, s);
    } else if (s->kind == SYM_EXTERN) {
      Stage *st = arena_alloc(ctx, sizeof *st);
      st->sym = s;
      st->kind = ST_EXTERN;
      st->ncomp = 1;
      st->klass = -1;
      s->stage = st;
      vec_push(ctx, &prog->stages, st);
    } else {
      L.cur = s;
      L.nintro = 0;
      PtrVec open = {0};
      L.open_sums = &open;
      Value *v = lower_expr(&L, s->body, NULL);
      vec_push(ctx, &prog->stages, lower_stage(&L, s, v));
    }
  }
  L.open_sums = NULL;
  /* An output operator hands back B_row^T M B_col: it needs bases. */
  for (int i = 0; i < prog->ops.n; i++) {
    Sym *op = prog->ops.v[i];
    if (op->is_output && !op->applied && !op->on_from)
      error_at(ctx, op->loc, "output operator '%s' has no bases: it is never applied in the program; name the "
               "quantities whose bases reduce it with 'on u -> p'", op->name);
  }
  /* Quantities with a basis, in evaluation order: inputs, then stages. */
  PtrVec q = {0};
  for (int i = 0; i < prog->inputs.n; i++) vec_push(ctx, &q, prog->inputs.v[i]);
  for (int i = 0; i < prog->stages.n; i++) vec_push(ctx, &q, ((Stage *)prog->stages.v[i])->sym);
  prog->quantities = q;
  /* `basis w: reduce interp` (DESIGN §12) asks for what only a stage of diagonal operators can do */
  for (int i = 0; i < q.n; i++) {
    const Sym *s = q.v[i];
    if (s->reduce != STAGE_REDUCE_INTERP || (s->stage && lower_interp_eligible(s->stage))) continue;
    error_at(ctx, s->reduce_loc, "'reduce interp': '%s' %s", s->name,
             !s->stage || s->stage->kind == ST_INPUT ? "is not a stage (only a stage is reduced)"
             : s->stage->kind == ST_EXTERN           ? "is an extern (its reduction is a learned map)"
             : s->stage->kind == ST_INVERSE || s->stage->kind == ST_ROOT
                 ? "applies a declared operator: only a stage whose every operator is diagonal can be interpolated"
                 : "applies no diagonal operator: only a stage whose every operator is diagonal can be interpolated");
  }
  for (int i = 0; i < prog->inlined.n; i++) {
    const Sym *s = prog->inlined.v[i];
    if (s->reduce == STAGE_REDUCE_INTERP) error_at(ctx, s->reduce_loc, "'reduce interp': '%s' is inlined", s->name);
  }
  PtrVec slots = {0};
  for (int i = 0; i < q.n; i++) vec_push(ctx, &slots, q.v[i]);
  for (int i = 0; i < prog->temps.n; i++) vec_push(ctx, &slots, prog->temps.v[i]);
  prog->slots = slots;
}
