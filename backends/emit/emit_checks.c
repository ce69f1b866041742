/* emit_checks.c — the bind-time gather checker as C (DESIGN §6): every index
 * into a dim of a param gather, where its guard holds, checked once per
 * binding before any evaluation, so the evaluators' gathers need no bounds
 * checks; a failure names the program's line (the outermost inlined call) and
 * the offending index values through the runtime's gather_error. Dense stages
 * and operators are checked over their index domain, sparse operators at
 * their entries' points (emit_sparse.c's parts). */
#include <stdlib.h>
#include <string.h>

#include "emit.h"

/* ---------------------------------------------------------------- gather checks */

/* Check every dim-axis index inside n (a param gather) before it is used. */
static void emit_node_checks(Emit *e, FILE *out, const Node *n, const Sym *where, int depth);
static void sparse_op_checks(Emit *e, FILE *out, const OpDef *od);

/* `s` as a C string literal: printable ASCII as is, everything else (and
 * '"', '\\', '?' against trigraphs) as octal escapes. */
static void emit_c_string(FILE *out, const char *s) {
  fputc('"', out);
  for (const unsigned char *c = (const unsigned char *)s; *c; c++)
    if (*c >= 32 && *c < 127 && *c != '"' && *c != '\\' && *c != '?') fputc(*c, out);
    else fprintf(out, "\\%03o", *c);
  fputc('"', out);
}

/* The first node of `n` (itself, then its operands) that has a source
 * location: a compound index made by lowering has none, its param has. */
static const Node *located(const Node *n) {
  if (!n || n->loc.file) return n;
  const Node *kids[3] = {n->a, n->b, n->c};
  for (int i = 0; i < 3; i++)
    if (located(kids[i])) return located(kids[i]);
  for (int i = 0; i < n->nargs; i++)
    if (located(n->args[i])) return located(n->args[i]);
  return NULL;
}

/* The location of the use `idx` in the user's program (the outermost fn
 * call it was inlined from, if any; else the stage's definition) as the
 * arguments `at, excerpt` of gather_error. */
static void emit_use_site(Emit *e, FILE *out, const Node *idx, const Sym *where) {
  const Node *use = located(idx);
  Loc loc = use ? use->loc : where->loc;
  for (const Node *c = use ? use->inl : NULL; c; c = c->inl) loc = c->loc;
  emit_c_string(out, loc.file ? arena_printf(e->ctx, "%s:%d:%d", loc.file->name, loc.line, loc.col) : where->name);
  fputs(", ", out);
  emit_c_string(out, diag_excerpt(e->ctx, loc));
}

/* idx indexes axis `axis` (a dim) of q: report if out of range. */
static void emit_index_check(Emit *e, FILE *out, const Sym *q, int axis, const Node *idx, const Sym *where,
                             int depth) {
  emit_node_checks(e, out, idx, where, depth);
  const Sym *dim = q->dims[axis];
  /* An index variable over the same dim is in range by construction. */
  if (idx->kind == N_NAME && idx->sym && (idx->sym->kind == SYM_IVAR || idx->sym->kind == SYM_SUMVAR) &&
      idx->sym->range == dim)
    return;
  emit_use(e, dim);
  int t = e->tmp++;
  emit_indent(out, depth);
  fprintf(out, "{ const npg_idx v%d_ = ", t);
  emit_cexpr(e, out, idx);
  fprintf(out, "; if (v%d_ < 0 || v%d_ >= %s) { ", t, t, emit_name(e, dim));
  int dim_id = vec_position(&e->prog->dims, dim);
  if (idx->kind == N_INDEX && idx->sym && idx->sym->kind == SYM_PARAM) {
    const Sym *p = idx->sym;
    fprintf(out, "npg_idx w_[%d] = {", idx->nargs);
    for (int i = 0; i < idx->nargs; i++) {
      if (i) fputs(", ", out);
      emit_cexpr(e, out, idx->args[i]);
    }
    fprintf(out, "}; c->rt->gather_error(c, \"%s\", ", where->name);
    emit_use_site(e, out, idx, where);
    fprintf(out, ", %d, %d, w_, v%d_, %d); return -1; } }\n", vec_position(&e->prog->params, p), idx->nargs, t, dim_id);
  } else {
    fprintf(out, "npg_idx w_[%d] = {", where->nivars ? where->nivars : 1);
    for (int i = 0; i < where->nivars; i++) fprintf(out, "%s%s", i ? ", " : "", emit_name(e, where->ivars[i]));
    if (!where->nivars) fputc('0', out);
    fprintf(out, "}; c->rt->gather_error(c, \"%s\", ", where->name);
    emit_use_site(e, out, idx, where);
    fprintf(out, ", -1, %d, w_, v%d_, %d); return -1; } }\n", where->nivars, t, dim_id);
  }
}

static void emit_node_checks(Emit *e, FILE *out, const Node *n, const Sym *where, int depth) {
  if (!n) return;
  if (n->kind == N_INDEX && n->sym && n->sym->kind == SYM_PARAM) {
    for (int i = 0; i < n->nargs && i < n->sym->ndims; i++) emit_index_check(e, out, n->sym, i, n->args[i], where, depth);
    return;
  }
  if (n->kind == N_SUM || n->kind == N_IF) return; /* inner guards/loops: checked when evaluated (rare) */
  emit_node_checks(e, out, n->a, where, depth);
  emit_node_checks(e, out, n->b, where, depth);
  emit_node_checks(e, out, n->c, where, depth);
  for (int i = 0; i < n->nargs; i++) emit_node_checks(e, out, n->args[i], where, depth);
}

static void emit_poly_checks(Emit *e, FILE *out, const Poly *p, const Sym *where, int depth) {
  for (int i = 0; i < p->n; i++) {
    const Mono *m = p->m[i];
    int d = depth;
    emit_indent(out, d++);
    fputs("{\n", out);
    for (int s = 0; s < m->nsums; s++) emit_sum_loop(e, out, &m->sums[s], d++, true);
    emit_node_checks(e, out, m->guard, where, d);
    if (m->guard) {
      emit_indent(out, d++);
      fputs("if (", out);
      emit_cexpr(e, out, m->guard);
      fputs(") {\n", out);
    }
    emit_node_checks(e, out, m->coef, where, d);
    for (int a = 0; a < m->natoms; a++)
      for (int k = 0; k < m->atoms[a].q->ndims; k++) emit_index_check(e, out, m->atoms[a].q, k, m->atoms[a].idx[k], where, d);
    emit_close_loops(out, d, depth + 1);
    emit_indent(out, depth);
    fputs("}\n", out);
  }
}

static void emit_field_checks(Emit *e, FILE *out, const Field *f, const Sym *where, int depth) {
  for (int c = 0; c < f->ncomp; c++) emit_poly_checks(e, out, &f->comp[c], where, depth);
}

static void check_stage_cb(Emit *e, FILE *out, const void *arg) {
  const Stage *st = arg;
  int d = emit_open_entry_loops(e, out, st->sym, 1);
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    emit_field_checks(e, out, tm->num, st->sym, d);
    for (int k = 0; k < tm->nops; k++)
      if (tm->ops[k].kind == OPK_DIAG) emit_field_checks(e, out, tm->ops[k].diag, st->sym, d);
  }
  emit_close_loops(out, d, 1);
}

static void check_op_cb(Emit *e, FILE *out, const void *arg) {
  const OpDef *od = arg;
  if (od->sparse) {
    sparse_op_checks(e, out, od);
    return;
  }
  int d = emit_open_entry_loops(e, out, od->sym, 1);
  emit_field_checks(e, out, od->entries, od->sym, d);
  emit_close_loops(out, d, 1);
}

/* The bind-time gather checks at the same points: the guard's gathers, then
 * (where it holds) the coefficient's and the atoms' indices. */
static void check_body(Emit *e, FILE *out, const Mono *m, const MonoPart *pt, const Sym *op, int d, const void *arg) {
  (void)arg;
  emit_node_checks(e, out, m->guard, op, d);
  emit_part_guard(e, out, m, d);
  for (int f = 0; f < pt->nfactors; f++) emit_node_checks(e, out, pt->factors[f], op, d);
  for (int a = 0; a < m->natoms; a++)
    for (int k = 0; k < m->atoms[a].q->ndims; k++) emit_index_check(e, out, m->atoms[a].q, k, m->atoms[a].idx[k], op, d);
}

static void check_fixed(Emit *e, FILE *out, const Node *expr, const Sym *op, int d) { emit_node_checks(e, out, expr, op, d); }

/* Bind-time gather checks of a sparse operator, at its entries' points. */
static void sparse_op_checks(Emit *e, FILE *out, const OpDef *od) {
  const Poly *p = &od->entries->comp[0];
  for (int i = 0; i < p->n; i++) {
    MonoPart parts[TENSOR_MAXPARTS];
    int np = tensor_mono_parts(e->ctx, p->m[i], od->sym->ivars, od->sym->nivars, parts);
    for (int k = 0; k < np; k++) emit_part(e, out, od->sym, p->m[i], &parts[k], 1, 0, &(PartEmit){check_fixed, check_body, NULL});
  }
}

/* ---------------------------------------------------------------- the entry point */

/* Bind-time gather checks: every index into a dim, where its guard holds;
 * the entry point that runs them all. */
void emit_checks(Emit *e) {
  Ctx *ctx = e->ctx;
  const Program *prog = e->prog;
  FILE *out = e->out;
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (st->kind == ST_EXTERN) continue;
    fprintf(out, "/* gathers of %s */\n", st->sym->name);
    emit_function_sig(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c)", emit_fn_name(e->ctx, "check_", st->sym)), NULL,
                  check_stage_cb, st);
  }
  for (int i = 0; i < prog->temps.n; i++) {
    const Sym *s = prog->temps.v[i];
    fprintf(out, "/* gathers of %s */\n", s->name);
    emit_function_sig(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c)", emit_fn_name(e->ctx, "check_temp_", s)), NULL,
                      check_stage_cb, s->stage);
  }
  for (int i = 0; i < prog->opdefs.n; i++) {
    const OpDef *od = prog->opdefs.v[i];
    fprintf(out, "/* gathers of operator %s */\n", od->sym->name);
    emit_function_sig(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c)", emit_fn_name(e->ctx, "check_op_", od->sym)), NULL,
                  check_op_cb, od);
  }
  fputs("/* Every gather in range of its dim where its guard holds: run once per binding. */\n", out);
  fprintf(out, "int %s(const NpgCtx *c) {\n", emit_symbol_name(ctx, prog, "check"));
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (st->kind == ST_EXTERN) continue;
    fprintf(out, "  if (%s(c)) return -1;\n", emit_fn_name(e->ctx, "check_", st->sym));
  }
  for (int i = 0; i < prog->temps.n; i++)
    fprintf(out, "  if (%s(c)) return -1;\n", emit_fn_name(e->ctx, "check_temp_", prog->temps.v[i]));
  for (int i = 0; i < prog->opdefs.n; i++)
    fprintf(out, "  if (%s(c)) return -1;\n", emit_fn_name(e->ctx, "check_op_", ((OpDef *)prog->opdefs.v[i])->sym));
  fputs("  return 0;\n}\n", out);
}
