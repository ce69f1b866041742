/* emit_builder.c — the tensor builders (DESIGN §6): for every tensor of
 * every term, a function that streams its sparse entries
 *
 *     (row, col, offsets of the contracted entries, coefficient)
 *
 * to an NpgSink in output-major order, ready for pre-multiplication — the
 * rows of one MPI rank's share only when the sink asks (NpgSink.nparts). A
 * numerator tensor's row is the flat entry of the stage (col -1); a
 * diagonal operator's entries lie on its diagonal (row == col); a declared
 * operator's row and column are flat over its row and column index
 * variables. The inputs of an entry come in the tensor's input order
 * (TensorGroup.inputs). */
#include <stdlib.h>
#include <string.h>

#include "emit.h"

static char *c_ident(Ctx *ctx, const char *s) {
  char *n = arena_strdup(ctx, s);
  for (char *c = n; *c; c++)
    if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') || *c == '_')) *c = '_';
  return n;
}

char *emit_builder_name(Ctx *ctx, const Program *prog, const Stage *st, int term, int field, int group, const Sym *op) {
  if (!st) return emit_symbol_name(ctx, prog, arena_printf(ctx, "build_op_%s_g%d", c_ident(ctx, op->name), group));
  return emit_symbol_name(ctx, prog,
                          arena_printf(ctx, "build_%s_t%d_f%d_g%d", c_ident(ctx, st->sym->name), term, field, group));
}

static int cmp_sym(const Sym *x, const Sym *y) {
  if (x->id != y->id) return x->id < y->id ? -1 : 1;
  return strcmp(x->name, y->name);
}

/* The atoms of m in the tensor's input order; false if m is not in `g`. */
static bool mono_in_group(const Mono *m, const TensorGroup *g, int *order) {
  if (m->natoms != g->ninputs) return false;
  bool used[64] = {0};
  for (int k = 0; k < g->ninputs; k++) {
    int found = -1;
    for (int a = 0; a < m->natoms && found < 0; a++)
      if (!used[a] && cmp_sym(m->atoms[a].q, g->inputs[k]) == 0) found = a;
    if (found < 0) return false;
    used[found] = true;
    order[k] = found;
  }
  return true;
}

typedef struct BuildArgs {
  const Field *field;
  const TensorGroup *group;
  const Sym *domain;     /* whose index variables are looped over */
  int kind;              /* 0 numerator, 1 diagonal operator, 2 declared operator */
  int ncomp;
} BuildArgs;

void emit_flat(Emit *e, FILE *out, const Sym *s, int from, int to) {
  if (from >= to) {
    fputc('0', out);
    return;
  }
  for (int i = from + 1; i < to; i++) fputc('(', out);
  for (int i = from; i < to; i++) {
    if (i > from) {
      emit_use(e, s->ivars[i]->range);
      fprintf(out, " * %s + ", emit_name(e, s->ivars[i]->range));
    }
    fputs(emit_name(e, s->ivars[i]), out);
    if (i > from) fputc(')', out);
  }
}

/* in_[k] = the offset of the contracted entry of atom order[k], k < n. */
static void emit_inputs(Emit *e, FILE *out, const Mono *m, const int *order, int n, int depth) {
  for (int k = 0; k < n; k++) {
    const Atom *a = &m->atoms[order[k]];
    emit_indent(out, depth);
    fprintf(out, "in_[%d] = ", k);
    emit_offset(e, out, a->q, a->idx, a->nidx);
    fputs(";\n", out);
  }
}

/* The innermost statements of one part of a sparse operator's entry in a
 * builder: the guard, the coefficient, the contracted entries' offsets,
 * then the entry. */
static void sparse_entry_body(Emit *e, FILE *out, const Mono *m, const MonoPart *pt, const Sym *op, int d,
                              const void *arg) {
  const int *order = arg;
  emit_part_guard(e, out, m, d);
  emit_part_coef(e, out, pt, d);
  emit_inputs(e, out, m, order, m->natoms, d);
  emit_indent(out, d);
  fputs("if (sink->entry(sink->user, e_, ", out);
  emit_flat(e, out, op, op->nrow, op->nivars);
  fprintf(out, ", %d, in_, w_)) return -1;\n", m->natoms);
}

/* A sparse operator's tensor (DESIGN §13): its rows in order as in the
 * dense builder, then each part of each monomial over the points its
 * equalities leave (K per row, not N): nnz work, not rows × cols. */
static void build_body_sparse(Emit *e, FILE *out, const BuildArgs *b) {
  const Sym *s = b->domain;
  const TensorGroup *g = b->group;
  int nrow = s->nrow;
  fputs("  const npg_idx np_ = sink->nparts > 1 ? sink->nparts : 1, part_ = np_ > 1 ? sink->part : 0;\n", out);
  fputs("  (void)np_, (void)part_;\n", out);
  /* a block of rows (NpgSink.lo, .hi): the rows outside skipped before their entries are made */
  fputs("  const npg_idx lo_ = sink->hi > sink->lo ? sink->lo : 0, hi_ = sink->hi > sink->lo ? sink->hi : -1;\n", out);
  fputs("  (void)lo_, (void)hi_;\n", out);
  if (nrow == 0) fputs("  if (part_ != 0) return 0;\n", out);
  for (int i = 0; i < nrow; i++) {
    const char *v = emit_name(e, s->ivars[i]);
    emit_use(e, s->ivars[i]->range);
    emit_indent(out, 1 + i);
    fprintf(out, "for (npg_idx %s = 0; %s < %s; %s++) {\n", v, v, emit_name(e, s->ivars[i]->range), v);
  }
  int depth = 1 + nrow;
  emit_indent(out, depth);
  fputs("const npg_idx e_ = ", out);
  emit_flat(e, out, s, 0, nrow);
  fputs(";\n", out);
  if (nrow > 0) {
    emit_indent(out, depth);
    fputs("if (hi_ >= 0 && (e_ < lo_ || e_ >= hi_)) continue;\n", out);
  }
  emit_indent(out, depth);
  fputs("if (np_ > 1 && e_ % np_ != part_) continue;\n", out);
  emit_indent(out, depth);
  fprintf(out, "npg_idx in_[%d] = {0};\n", g->ninputs ? g->ninputs : 1);
  emit_indent(out, depth);
  fputs("(void)in_;\n", out);
  const Poly *p = &b->field->comp[0];
  for (int i = 0; i < p->n; i++) {
    int order[64];
    if (!mono_in_group(p->m[i], g, order)) continue;
    MonoPart parts[TENSOR_MAXPARTS];
    int np = tensor_mono_parts(e->ctx, p->m[i], s->ivars, s->nivars, parts);
    for (int k = 0; k < np; k++) emit_part(e, out, s, p->m[i], &parts[k], depth, nrow, &(PartEmit){NULL, sparse_entry_body, order});
  }
  for (int i = nrow; i >= 1; i--) {
    emit_indent(out, i);
    fputs("}\n", out);
  }
  memset(e->used_q, 0, sizeof(bool) * (size_t)e->prog->slots.n);
}

static void build_body(Emit *e, FILE *out, const void *arg) {
  const BuildArgs *b = arg;
  if (b->kind == 2 && b->domain->opdef && b->domain->opdef->sparse && emit_sparse_rows_free(e->ctx, b->domain->opdef)) {
    build_body_sparse(e, out, b);
    return;
  }
  const Sym *s = b->domain;
  const TensorGroup *g = b->group;
  int nrow = b->kind == 2 ? s->nrow : s->nivars;
  /* one rank's share (NpgSink.part, .nparts): the rows ≡ part_ (mod np_)
   * only. A stage of one component (row e_) steps its last loop by np_
   * from the first such row; one of several tests each component's row
   * e_ * ncomp + c; a declared operator tests its row once its row
   * variables are set, its column loops never entered for another's. */
  bool stride = b->kind != 2 && b->ncomp == 1 && s->nivars > 0;
  int guard = b->kind != 2 && !stride; /* the per-component test opens a block */
  fputs("  const npg_idx np_ = sink->nparts > 1 ? sink->nparts : 1, part_ = np_ > 1 ? sink->part : 0;\n", out);
  fputs("  (void)np_, (void)part_;\n", out);
  /* a block of rows (NpgSink.lo, .hi): the rows outside skipped before their entries are made */
  fputs("  const npg_idx lo_ = sink->hi > sink->lo ? sink->lo : 0, hi_ = sink->hi > sink->lo ? sink->hi : -1;\n", out);
  fputs("  (void)lo_, (void)hi_;\n", out);
  if (b->kind == 2 && nrow == 0) fputs("  if (part_ != 0) return 0;\n", out);
  for (int i = 0; i < s->nivars; i++) {
    const char *v = emit_name(e, s->ivars[i]), *range = emit_name(e, s->ivars[i]->range);
    emit_use(e, s->ivars[i]->range);
    emit_indent(out, 1 + i);
    if (stride && i == s->nivars - 1) {
      fprintf(out, "for (npg_idx %s = np_ == 1 ? 0 : ((part_ - ", v);
      emit_flat(e, out, s, 0, i);
      fprintf(out, " * %s) %% np_ + np_) %% np_; %s < %s; %s += np_) {\n", range, v, range, v);
    } else {
      fprintf(out, "for (npg_idx %s = 0; %s < %s; %s++) {\n", v, v, range, v);
    }
    if (b->kind == 2 && i == nrow - 1) {
      emit_indent(out, 2 + i);
      fputs("if (np_ > 1 && ", out);
      emit_flat(e, out, s, 0, nrow);
      fputs(" % np_ != part_) continue;\n", out);
      emit_indent(out, 2 + i);
      fputs("if (hi_ >= 0 && (", out);
      emit_flat(e, out, s, 0, nrow);
      fputs(" < lo_ || ", out);
      emit_flat(e, out, s, 0, nrow);
      fputs(" >= hi_)) continue;\n", out);
    }
  }
  int depth = 1 + s->nivars;
  emit_indent(out, depth);
  fputs("const npg_idx e_ = ", out);
  emit_flat(e, out, s, 0, nrow);
  fputs(";\n", out);
  if (b->kind != 2 && s->nivars > 0) { /* no component of this entry's rows in the block */
    emit_indent(out, depth);
    fprintf(out, "if (hi_ >= 0 && ((e_ + 1) * %d <= lo_ || e_ * %d >= hi_)) continue;\n", b->ncomp, b->ncomp);
  }
  if (b->kind == 2) {
    emit_indent(out, depth);
    fputs("const npg_idx col_ = ", out);
    emit_flat(e, out, s, nrow, s->nivars);
    fputs(";\n", out);
  }
  emit_indent(out, depth);
  fprintf(out, "npg_idx in_[%d] = {0};\n", g->ninputs ? g->ninputs : 1);
  emit_indent(out, depth);
  fputs("(void)in_;\n", out);
  for (int c = 0; c < b->ncomp; c++) {
    const Poly *p = &b->field->comp[c];
    int order[64];
    bool any = false;
    for (int i = 0; i < p->n && !any; i++) any = mono_in_group(p->m[i], g, order);
    if (!any) continue;
    if (guard) {
      emit_indent(out, depth);
      fprintf(out, "if (np_ == 1 || (e_ * %d + %d) %% np_ == part_) {\n", b->ncomp, c);
    }
    for (int i = 0; i < p->n; i++) {
      const Mono *m = p->m[i];
      if (!mono_in_group(m, g, order)) continue;
      int d = depth + guard;
      emit_indent(out, d++);
      fputs("{\n", out);
      for (int k = 0; k < m->nsums; k++) emit_sum_loop(e, out, &m->sums[k], d++, true);
      if (m->guard) {
        emit_indent(out, d++);
        fputs("if (", out);
        emit_cexpr(e, out, m->guard);
        fputs(") {\n", out);
      }
      emit_inputs(e, out, m, order, g->ninputs, d);
      emit_indent(out, d);
      const char *row = arena_printf(e->ctx, "e_ * %d + %d", b->ncomp, c);
      const char *col = b->kind == 0 ? "-1" : b->kind == 1 ? row : "col_";
      if (m->coef->kind == N_NUM) {
        fprintf(out, "if (sink->entry(sink->user, %s, %s, %d, in_, ", row, col, g->ninputs);
        emit_cexpr(e, out, m->coef);
        fputs(")) return -1;\n", out);
      } else { /* coefficients such as delta(i, j) are zero off their support: not an entry */
        fputs("{ const double k_ = ", out);
        emit_cexpr(e, out, m->coef);
        fprintf(out, "; if (k_ != 0.0 && sink->entry(sink->user, %s, %s, %d, in_, k_)) return -1; }\n", row, col,
                g->ninputs);
      }
      for (int k = d - 1; k >= depth + guard; k--) {
        emit_indent(out, k);
        fputs("}\n", out);
      }
    }
    if (guard) {
      emit_indent(out, depth);
      fputs("}\n", out);
    }
  }
  for (int i = s->nivars; i >= 1; i--) {
    emit_indent(out, i);
    fputs("}\n", out);
  }
  /* a builder reads offsets, never values: declare no quantity */
  memset(e->used_q, 0, sizeof(bool) * (size_t)e->prog->slots.n);
}

static void emit_one(Emit *e, const char *name, const char *what, BuildArgs *b) {
  fprintf(e->out, "/* %s: order %d, %d monomial%s, nnz %s%s */\n", what, b->group->order, b->group->nmono,
          b->group->nmono == 1 ? "" : "s", b->group->nnz_bound ? "<= " : "", b->group->nnz);
  emit_function_sig(e, e->out, arena_printf(e->ctx, "int %s(const NpgCtx *c, NpgSink *sink)", name), NULL, build_body, b);
}

/* Builders after the full evaluator, in the same translation unit. */
void emit_builders(Ctx *ctx, const Program *prog, FILE *out) {
  Emit *e = emit_new(ctx, prog, out);
  fputs("/* ---------------------------------------------------------------- tensor builders */\n\n", out);
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    for (int t = 0; t < st->nterms; t++) {
      const Term *tm = st->terms[t];
      if (!tm->named_num)
        for (int g = 0; g < tm->num_tensors.n; g++) {
          BuildArgs b = {tm->num, &tm->num_tensors.g[g], st->sym, 0, st->ncomp};
          emit_one(e, emit_builder_name(ctx, prog, st, t, 0, g, NULL),
                   arena_printf(ctx, "%s term %d numerator, tensor %d", st->sym->name, t + 1, g + 1), &b);
        }
      for (int k = 0; k < tm->nops; k++) {
        if (tm->ops[k].kind != OPK_DIAG) continue;
        for (int g = 0; g < tm->op_tensors[k].n; g++) {
          BuildArgs b = {tm->ops[k].diag, &tm->op_tensors[k].g[g], st->sym, 1, st->ncomp};
          emit_one(e, emit_builder_name(ctx, prog, st, t, k + 1, g, NULL),
                   arena_printf(ctx, "%s term %d diagonal operator %d, tensor %d", st->sym->name, t + 1, k + 1, g + 1), &b);
        }
      }
    }
  }
  for (int i = 0; i < prog->opdefs.n; i++) {
    const OpDef *od = prog->opdefs.v[i];
    for (int g = 0; g < od->tensors.n; g++) {
      BuildArgs b = {od->entries, &od->tensors.g[g], od->sym, 2, 1};
      emit_one(e, emit_builder_name(ctx, prog, NULL, 0, 0, g, od->sym),
               arena_printf(ctx, "operator %s, tensor %d", od->sym->name, g + 1), &b);
    }
  }
}
