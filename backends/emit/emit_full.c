/* emit_full.c — the full evaluator as C (DESIGN §6; its bind-time gather
 * checker is emit_checks.c's). One function per stage, named after it, with its source line
 * in a comment; loops over the stage's index domain with gathers; tensors
 * are never materialized. Diagonal operators are applied entry by entry;
 * declared operators are assembled densely and applied through the runtime
 * (LAPACKE, info checked), or, when their entries grow like K·N (an
 * index-table gather), enumerated entry by entry for the runtime's
 * compressed assembly and SuiteSparse solves (DESIGN §13,
 * stdlib/runtime/sparse.c). */
#include <stdlib.h>
#include <string.h>

#include "emit.h"

/* ---------------------------------------------------------------- helpers */

void emit_indent(FILE *out, int depth) {
  for (int i = 0; i < depth; i++) fputs("  ", out);
}

/* The source line of a location, safe inside a C comment; its first 160
 * bytes and "..." when longer (a one-line program can be megabytes). */
char *emit_source_line(Ctx *ctx, Loc loc) {
  if (!loc.file) return "";
  const char *t = loc.file->text;
  size_t s = loc.off, e;
  while (s > 0 && t[s - 1] != '\n' && t[s - 1] != '\r') s--;
  while (s < loc.off && t[s] == ' ') s++;
  for (e = s; e < loc.file->len && t[e] != '\n' && t[e] != '\r'; e++) {}
  bool cut = e - s > 160;
  char *line = emit_comment_text(ctx, arena_printf(ctx, "%.*s%s", (int)(cut ? 160 : e - s), t + s, cut ? "..." : ""));
  while (*line == ' ') line++;
  return line;
}

char *emit_comment_text(Ctx *ctx, const char *text) {
  char *copy = arena_strdup(ctx, text);
  for (char *c = copy; *c; c++) {
    if (c[0] == '*' && c[1] == '/') c[1] = '|';
    if (c[0] == '/' && c[1] == '*') c[1] = '|';
    if ((unsigned char)*c < 32 || (unsigned char)*c > 126) *c = ' ';
  }
  return copy;
}

const char *emit_loc_file(Ctx *ctx, Loc loc) { return loc.file ? emit_comment_text(ctx, loc.file->name) : "?"; }

/* Loops over the index domain of `s`; the entry's flat index is e_.
 * Returns the depth inside. */
int emit_open_entry_loops(Emit *e, FILE *out, const Sym *s, int depth) {
  for (int i = 0; i < s->nivars; i++) {
    const char *v = emit_name(e, s->ivars[i]);
    emit_use(e, s->ivars[i]->range);
    emit_indent(out, depth + i);
    fprintf(out, "for (npg_idx %s = 0; %s < %s; %s++) {\n", v, v, emit_name(e, s->ivars[i]->range), v);
  }
  depth += s->nivars;
  emit_indent(out, depth);
  fputs("const npg_idx e_ = ", out);
  if (!s->nivars) fputc('0', out);
  for (int i = 1; i < s->nivars; i++) fputc('(', out);
  for (int i = 0; i < s->nivars; i++) {
    if (i) fprintf(out, " * %s + ", emit_name(e, s->ivars[i]->range));
    fputs(emit_name(e, s->ivars[i]), out);
    if (i) fputc(')', out);
  }
  fputs(";\n", out);
  emit_indent(out, depth);
  fputs("(void)e_;\n", out);
  return depth;
}

void emit_close_loops(FILE *out, int from, int to) {
  for (int d = from - 1; d >= to; d--) {
    emit_indent(out, d);
    fputs("}\n", out);
  }
}

void emit_atom(Emit *e, FILE *out, const Atom *a) {
  emit_use(e, a->q);
  fprintf(out, "%s[", emit_name(e, a->q));
  emit_offset(e, out, a->q, a->idx, a->nidx);
  fputc(']', out);
}

void emit_poly(Emit *e, FILE *out, const Poly *p, const char *acc, int depth) {
  for (int i = 0; i < p->n; i++) {
    const Mono *m = p->m[i];
    int d = depth;
    for (int s = 0; s < m->nsums; s++) emit_sum_loop(e, out, &m->sums[s], d++, false);
    if (m->guard) {
      emit_indent(out, d++);
      fputs("if (", out);
      emit_cexpr(e, out, m->guard);
      fputs(")\n", out);
    }
    emit_indent(out, d);
    fprintf(out, "%s += ", acc);
    bool one = m->coef->kind == N_NUM && m->coef->num == 1 && m->natoms;
    if (!one) emit_cexpr(e, out, m->coef);
    for (int a = 0; a < m->natoms; a++) {
      if (a || !one) fputs(" * ", out);
      emit_atom(e, out, &m->atoms[a]);
    }
    fputs(";\n", out);
  }
}

/* t <- t * d^(p/q), with the cheap forms for the common powers. A
 * fractional power (q > 1) of a negative d is NaN whatever p and q are
 * (grammar.txt: roots of negative numbers), so no cbrt: it would give x^(1/3)
 * a real value that x^(2/3) and x^(1/5), and the reduced evaluator, do not. */
static void emit_apply_diag(FILE *out, const char *t, const char *d, long p, long q, int depth) {
  emit_indent(out, depth);
  if (q == 1 && p == -1) fprintf(out, "%s /= %s;\n", t, d);
  else if (q == 1 && p == -2) fprintf(out, "%s /= %s * %s;\n", t, d, d);
  else if (q == 2 && p == -1) fprintf(out, "%s /= sqrt(%s);\n", t, d);
  else if (q == 2 && p == 1) fprintf(out, "%s *= sqrt(%s);\n", t, d);
  else if (q == 2 && p == -3) fprintf(out, "%s /= %s * sqrt(%s);\n", t, d, d);
  else fprintf(out, "%s *= pow(%s, %ld.0 / %ld.0);\n", t, d, p, q);
}

static bool term_has_decl(const Term *t) {
  for (int k = 0; k < t->nops; k++)
    if (t->ops[k].kind == OPK_DECL) return true;
  return false;
}


/* ---------------------------------------------------------------- sparse operators */

/* The innermost statements of one part of a sparse operator's entry: the
 * guard, the coefficient, then the contribution (rows_, cols_, slot_, vals_,
 * cnt_ of the entries function). */
static void entry_body(Emit *e, FILE *out, const Mono *m, const MonoPart *pt, const Sym *op, int d, const void *arg) {
  (void)arg;
  emit_part_guard(e, out, m, d);
  emit_part_coef(e, out, pt, d);
  emit_indent(out, d);
  fputs("if (rows_ && cnt_ < cap_) {\n", out);
  emit_indent(out, d + 1);
  fputs("rows_[cnt_] = ", out);
  emit_flat(e, out, op, 0, op->nrow);
  fputs(";\n", out);
  emit_indent(out, d + 1);
  fputs("cols_[cnt_] = ", out);
  emit_flat(e, out, op, op->nrow, op->nivars);
  fputs(";\n", out);
  emit_indent(out, d);
  fputs("}\n", out);
  emit_indent(out, d);
  fputs("if (vals_ && cnt_ < cap_) vals_[slot_[cnt_]] += w_", out);
  for (int a = 0; a < m->natoms; a++) {
    fputs(" * ", out);
    emit_atom(e, out, &m->atoms[a]);
  }
  fputs(";\n", out);
  emit_indent(out, d);
  fputs("cnt_++;\n", out);
}

/* The entries of sparse operator `od`, in a fixed order: with rows_ and
 * cols_ their flat row and column, with vals_ their values at this
 * evaluation added into the compressed matrix's values at slot_[k] (the
 * pattern's slot of contribution k), none past the first cap_; the count
 * returned either way (NpgOpEntriesFn). */
static void op_entries_cb(Emit *e, FILE *out, const void *arg) {
  const OpDef *od = arg;
  const Poly *p = &od->entries->comp[0];
  fputs("  npg_idx cnt_ = 0;\n", out);
  for (int i = 0; i < p->n; i++) {
    MonoPart parts[TENSOR_MAXPARTS];
    int np = tensor_mono_parts(e->ctx, p->m[i], od->sym->ivars, od->sym->nivars, parts);
    for (int k = 0; k < np; k++) emit_part(e, out, od->sym, p->m[i], &parts[k], 1, 0, &(PartEmit){NULL, entry_body, NULL});
  }
  fputs("  return cnt_;\n", out);
}

/* Whether a stage applies sparse operator `od` (an op only a basis's inner product names,
 * `basis u: product H`, is assembled by training from its tensors, not by the evaluator). */
bool emit_op_applied(const Program *prog, const OpDef *od) {
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    for (int t = 0; t < st->nterms; t++)
      for (int k = 0; k < st->terms[t]->nops; k++)
        if (st->terms[t]->ops[k].kind == OPK_DECL && st->terms[t]->ops[k].op->opdef == od) return true;
  }
  return false;
}

void emit_sparse_ops(Emit *e) {
  for (int i = 0; i < e->prog->opdefs.n; i++) {
    const OpDef *od = e->prog->opdefs.v[i];
    if (!od->sparse || !emit_op_applied(e->prog, od)) continue;
    fprintf(e->out, "/* entries of sparse operator %s (DESIGN §13) */\n", od->sym->name);
    emit_function_sig(e, e->out,
                      arena_printf(e->ctx, "static npg_idx %s(const NpgCtx *c, npg_idx cap_, npg_idx *rows_, npg_idx *cols_, const npg_idx *slot_, "
                                   "double *vals_)",
                                   emit_fn_name(e->ctx, "entries_", od->sym)),
                      NULL, op_entries_cb, od);
  }
}

/* ---------------------------------------------------------------- stages */

static void emit_stage_body(Emit *e, FILE *out, const Stage *st) {
  const Sym *s = st->sym;
  int nc = st->ncomp;
  const char *y = emit_name(e, s);
  emit_use(e, s);
  if (emit_direct_ok(st)) { /* the source expression, entry by entry */
    emit_direct_group(e, out, &st, 1);
    return;
  }
  bool any_entrywise = false;
  for (int t = 0; t < st->nterms; t++) any_entrywise |= !term_has_decl(st->terms[t]);
  int depth = emit_open_entry_loops(e, out, s, 1);
  for (int c = 0; c < nc; c++) {
    emit_indent(out, depth);
    fprintf(out, "double y%d_ = 0.0;\n", c);
  }
  for (int t = 0; t < st->nterms && any_entrywise; t++) {
    const Term *tm = st->terms[t];
    if (term_has_decl(tm)) continue;
    emit_indent(out, depth);
    fprintf(out, "{ /* term %d */\n", t + 1);
    for (int c = 0; c < nc; c++) {
      emit_indent(out, depth + 1);
      fputs("double t_ = 0.0;\n", out);
      emit_poly(e, out, &tm->num->comp[c], "t_", depth + 1);
      for (int k = 0; k < tm->nops; k++) {
        emit_indent(out, depth + 1);
        fprintf(out, "{\n");
        emit_indent(out, depth + 2);
        fputs("double d_ = 0.0;\n", out);
        emit_poly(e, out, &tm->ops[k].diag->comp[c], "d_", depth + 2);
        emit_apply_diag(out, "t_", "d_", tm->ops[k].p, tm->ops[k].q, depth + 2);
        emit_indent(out, depth + 1);
        fputs("}\n", out);
      }
      emit_indent(out, depth + 1);
      fprintf(out, "y%d_ += t_;\n", c);
      if (c + 1 < nc) {
        emit_indent(out, depth);
        fprintf(out, "}\n");
        emit_indent(out, depth);
        fprintf(out, "{\n");
      }
    }
    emit_indent(out, depth);
    fputs("}\n", out);
  }
  for (int c = 0; c < nc; c++) {
    emit_indent(out, depth);
    fprintf(out, "%s[e_ * %d + %d] = y%d_;\n", y, nc, c, c);
  }
  emit_close_loops(out, depth, 1);

  /* Terms with declared operators: the whole vector, then dense operators. */
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    if (!term_has_decl(tm)) continue;
    iassert(e->ctx, nc == 1);
    fprintf(out, "  { /* term %d: declared operators */\n", t + 1);
    fputs("    npg_idx n_ = 1;\n", out);
    for (int i = 0; i < s->nivars; i++) {
      emit_use(e, s->ivars[i]->range);
      fprintf(out, "    n_ *= %s;\n", emit_name(e, s->ivars[i]->range));
    }
    fputs("    double *v_ = c->rt->scratch(c, n_);\n    if (!v_) return -1;\n", out);
    int d = emit_open_entry_loops(e, out, s, 2);
    emit_indent(out, d);
    fputs("double t_ = 0.0;\n", out);
    emit_poly(e, out, &tm->num->comp[0], "t_", d);
    for (int k = 0; k < tm->nops; k++) {
      if (tm->ops[k].kind != OPK_DIAG) continue;
      /* a diagonal applied before every declared operator */
      bool inner = true;
      for (int j = 0; j < k; j++) inner &= tm->ops[j].kind == OPK_DIAG;
      iassert(e->ctx, inner);
      emit_indent(out, d);
      fputs("{\n", out);
      emit_indent(out, d + 1);
      fputs("double d_ = 0.0;\n", out);
      emit_poly(e, out, &tm->ops[k].diag->comp[0], "d_", d + 1);
      emit_apply_diag(out, "t_", "d_", tm->ops[k].p, tm->ops[k].q, d + 1);
      emit_indent(out, d);
      fputs("}\n", out);
    }
    emit_indent(out, d);
    fputs("v_[e_] = t_;\n", out);
    emit_close_loops(out, d, 2);
    for (int k = 0; k < tm->nops; k++) {
      if (tm->ops[k].kind != OPK_DECL) continue;
      const Sym *op = tm->ops[k].op;
      if (op->opdef->sparse) {
        fprintf(out, "    { /* %s^(%ld/%ld), sparse */\n", op->name, tm->ops[k].p, tm->ops[k].q);
        fprintf(out, "      if (c->rt->sparse_power(c, \"%s\", \"%s\", %d, n_, %s, %ld, %ld, v_)) { c->rt->release(c, v_); return -1; }\n",
                s->name, op->name, vec_position(&e->prog->opdefs, op->opdef), emit_fn_name(e->ctx, "entries_", op),
                tm->ops[k].p, tm->ops[k].q);
        fputs("    }\n", out);
        continue;
      }
      fprintf(out, "    { /* %s^(%ld/%ld) */\n", op->name, tm->ops[k].p, tm->ops[k].q);
      fputs("      double *m_ = c->rt->scratch(c, n_ * n_);\n", out);
      fputs("      if (!m_) { c->rt->release(c, v_); return -1; }\n", out);
      int od = emit_open_entry_loops(e, out, op, 3);
      emit_indent(out, od);
      fputs("double t_ = 0.0;\n", out);
      emit_poly(e, out, &op->opdef->entries->comp[0], "t_", od);
      emit_indent(out, od);
      fputs("m_[e_] = t_;\n", out);
      emit_close_loops(out, od, 3);
      fprintf(out, "      int bad_ = c->rt->op_power(c, \"%s\", \"%s\", n_, m_, %ld, %ld, v_);\n", s->name, op->name,
              tm->ops[k].p, tm->ops[k].q);
      fputs("      c->rt->release(c, m_);\n", out);
      fputs("      if (bad_) { c->rt->release(c, v_); return -1; }\n", out);
      fputs("    }\n", out);
    }
    fprintf(out, "    for (npg_idx e_ = 0; e_ < n_; e_++) %s[e_] += v_[e_];\n", y);
    fputs("    c->rt->release(c, v_);\n", out);
    fputs("  }\n", out);
  }
}

/* A function whose prologue declares exactly what its body used. */
void emit_function_sig(Emit *e, FILE *out, const char *signature, const Sym *writes,
                          void (*body)(Emit *, FILE *, const void *), const void *arg) {
  char *buf = NULL;
  size_t len = 0;
  FILE *b = open_memstream(&buf, &len);
  if (!b) error_plain(e->ctx, "out of memory");
  emit_reset_used(e);
  e->scalar = false;
  body(e, b, arg);
  fclose(b);
  e->ctx->pending_free = buf;
  fprintf(out, "%s%s {\n  (void)c;\n", e->scalar ? "NPG_SCALAR " : "", signature);
  emit_prologue(e, out, writes != NULL, writes);
  fputs(buf ? buf : "", out);
  fputs("  return 0;\n}\n\n", out);
  e->ctx->pending_free = NULL;
  free(buf);
}

static void stage_body_cb(Emit *e, FILE *out, const void *st) { emit_stage_body(e, out, st); }

/* ---------------------------------------------------------------- the unit */

/* `prefix` and the symbol's name, made a C identifier. */
const char *emit_fn_name(Ctx *ctx, const char *prefix, const Sym *s) {
  char *n = arena_printf(ctx, "%s%s", prefix, s->name);
  for (char *c = n; *c; c++)
    if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') || *c == '_')) *c = '_';
  return n;
}

void emit_header(Emit *e, const char *what) {
  fprintf(e->out, "/* %s of %s, generated by npgc. */\n\n", what, emit_comment_text(e->ctx, e->prog->main->name));
  fputs(npg_abi_header, e->out);
  fputs("\n", e->out);
  /* Restrict-qualified locals loaded from c->q do not tell gcc that the
   * arrays a loop writes are not the arrays it reads, and it gives up
   * vectorizing when it would need too many run-time overlap checks. */
  fputs("/* Before a loop whose iterations are independent: each writes its own\n"
        " * entries of arrays the loop does not read. */\n"
        "#if defined(__GNUC__) && !defined(__clang__) && !defined(__TINYC__)\n"
        "#define NPG_INDEPENDENT _Pragma(\"GCC ivdep\")\n"
        "#elif defined(__clang__)\n"
        "#define NPG_INDEPENDENT _Pragma(\"clang loop vectorize(assume_safety)\")\n"
        "#else\n"
        "#define NPG_INDEPENDENT\n"
        "#endif\n"
        "/* A function whose innermost loop reads through an int param's entries under a guard\n"
        " * (a stencil's `if(nbr >= 0, ...)`): gcc's masked vector gathers were slower than scalar\n"
        " * loads (AMD EPYC, -march=native: nonlinear heat 128 x 128, 33.9 -> 32.2 us; unguarded\n"
        " * gathers, n-body pairs, gain from vectors: 252 -> 216 us; bench/README.md, bench_shapes). */\n"
        "#if defined(__GNUC__) && !defined(__clang__) && !defined(__TINYC__)\n"
        "#define NPG_SCALAR __attribute__((optimize(\"no-tree-vectorize\")))\n"
        "#else\n"
        "#define NPG_SCALAR\n"
        "#endif\n\n",
        e->out);
}

Emit *emit_new(Ctx *ctx, const Program *prog, FILE *out) {
  Emit *e = arena_alloc(ctx, sizeof *e);
  e->ctx = ctx;
  e->prog = prog;
  e->out = out;
  e->used_dim = arena_alloc(ctx, sizeof(bool) * (size_t)(prog->dims.n + 1));
  e->used_param = arena_alloc(ctx, sizeof(bool) * (size_t)(prog->params.n + 1));
  e->used_q = arena_alloc(ctx, sizeof(bool) * (size_t)(prog->slots.n + 1));
  return e;
}

typedef struct Group {
  const Stage **members;
  int n;
} Group;

static void group_body_cb(Emit *e, FILE *out, const void *arg) {
  const Group *g = arg;
  emit_direct_group(e, out, g->members, g->n);
}

static bool node_reads_sym(const Node *n, const Sym *s) {
  if (!n) return false;
  if ((n->kind == N_NAME || n->kind == N_INDEX) && n->sym == s) return true;
  if (node_reads_sym(n->a, s) || node_reads_sym(n->b, s) || node_reads_sym(n->c, s)) return true;
  for (int i = 0; i < n->nargs; i++)
    if (node_reads_sym(n->args[i], s)) return true;
  return false;
}

/* A temp defined among the group's members that reads one of them must be
 * computed between them: the group cannot be fused across it. */
static bool temp_splits(const Program *prog, const Stage *const *members, int n, const Stage *next) {
  for (int t = 0; t < prog->temps.n; t++) {
    const Sym *tmp = prog->temps.v[t];
    if (tmp->id > members[0]->sym->id && tmp->id < next->sym->id)
      for (int m = 0; m < n; m++)
        if (node_reads_sym(tmp->body, members[m]->sym)) return true;
  }
  return false;
}

int emit_symbol(const Program *prog, const char *what, char *buf, size_t n) {
  const char *path = prog->main && prog->main->name ? prog->main->name : "program";
  const char *base = strrchr(path, '/') ? strrchr(path, '/') + 1 : path;
  const char *dot = strrchr(base, '.');
  size_t len = dot && dot > base ? (size_t)(dot - base) : strlen(base);
  bool letter = len > 0 && ((base[0] >= 'a' && base[0] <= 'z') || (base[0] >= 'A' && base[0] <= 'Z'));
  int total = snprintf(buf, n, "%s%.*s_npg_%s", letter ? "" : "p", (int)len, base, what);
  for (size_t i = letter ? 0 : 1; buf && i < n && i < (letter ? 0 : 1) + len; i++) {
    char c = buf[i];
    if (!c) break;
    if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_')) buf[i] = '_';
  }
  return total;
}

char *emit_symbol_name(Ctx *ctx, const Program *prog, const char *what) {
  int len = emit_symbol(prog, what, NULL, 0);
  char *name = arena_alloc(ctx, (size_t)len + 1);
  emit_symbol(prog, what, name, (size_t)len + 1);
  return name;
}

/* Temps: inlined stages that read inputs, computed once (the reduced
 * model folds them into its tensors; the full evaluator need not). */
static void emit_temps(Emit *e) {
  Ctx *ctx = e->ctx;
  const Program *prog = e->prog;
  FILE *out = e->out;
  for (int i = 0; i < prog->temps.n; i++) {
    const Sym *s = prog->temps.v[i];
    fprintf(out, "/* %s: inlined (computed once here), %s:%d\n   %s */\n", s->name, emit_loc_file(ctx, s->loc),
            s->loc.line, emit_source_line(ctx, s->loc));
    emit_function_sig(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c)", emit_fn_name(e->ctx, "temp_", s)), s,
                      stage_body_cb, s->stage);
  }
}

/* The calls of the entry point: consecutive stages over one domain fused
 * into one loop nest (each still written whole), reads of a fused stage at
 * another entry rematerialized from its expression; a stage that reads no
 * member of a group may be computed before it. */
static PtrVec plan_calls(Ctx *ctx, const Program *prog) {
  PtrVec calls = {0}; /* FullStep* */
  const Stage **st_all = (const Stage **)prog->stages.v;
  for (int i = 0; i < prog->stages.n;) {
    const Stage *st = st_all[i];
    if (st->kind == ST_EXTERN) {
      i++;
      continue;
    }
    const Stage **members = arena_alloc(ctx, sizeof(Stage *) * (size_t)(prog->stages.n + 1));
    const Stage **before = arena_alloc(ctx, sizeof(Stage *) * (size_t)(prog->stages.n + 1));
    int n = 0, nbefore = 0, end = i + 1;
    if (emit_fusable(members, 0, st)) {
      members[n++] = st;
      for (int j = i + 1; j < prog->stages.n; j++) {
        const Stage *x = st_all[j];
        if (x->kind == ST_EXTERN) continue; /* given, not computed */
        if (emit_fusable(members, n, x) && !temp_splits(prog, members, n, x)) {
          members[n++] = x;
          end = j + 1;
          continue;
        }
        /* a stage that reads no member can be computed before the group */
        bool independent = !temp_splits(prog, members, n, x);
        for (int m = 0; m < n && independent; m++) independent = !node_reads_sym(x->sym->body, members[m]->sym);
        for (int t = 0; t < x->nterms && independent; t++)
          for (int k = 0; k < x->terms[t]->nops && independent; k++)
            if (x->terms[t]->ops[k].kind == OPK_DECL)
              for (int m = 0; m < n && independent; m++)
                independent = !node_reads_sym(x->terms[t]->ops[k].op->body, members[m]->sym);
        if (!independent || x->sym->introduced) break;
        before[nbefore++] = x;
      }
      if (n < 2) nbefore = 0;
      /* only stages up to the last member move */
      while (nbefore > 0 && before[nbefore - 1]->sym->id > members[n - 1]->sym->id) nbefore--;
    }
    for (int b = 0; b < nbefore; b++) {
      FullStep *c = arena_alloc(ctx, sizeof *c);
      *c = (FullStep){STEP_STAGE, emit_fn_name(ctx, "stage_", before[b]->sym), before + b, 1, true, false};
      vec_push(ctx, &calls, c);
    }
    FullStep *c = arena_alloc(ctx, sizeof *c);
    if (n >= 2) {
      char *name = "fused";
      for (int m = 0; m < n; m++) name = arena_printf(ctx, "%s_%s", name, emit_fn_name(ctx, "", members[m]->sym));
      *c = (FullStep){STEP_FUSED, name, members, n, false, true};
      i = end;
    } else {
      members[0] = st;
      *c = (FullStep){STEP_STAGE, emit_fn_name(ctx, "stage_", st->sym), members, 1, false,
                      emit_direct_ok(st) && !st->sym->body->ty.nwhole};
      i++;
    }
    /* loop nests over pairs (and larger domains) are worth restricting */
    c->boxed = c->boxed && st->sym->nivars >= 2;
    vec_push(ctx, &calls, c);
  }
  return calls;
}

FullPlan *emit_full_plan(Ctx *ctx, const Program *prog) {
  PtrVec calls = plan_calls(ctx, prog);
  FullPlan *p = arena_alloc(ctx, sizeof *p);
  p->steps = arena_alloc(ctx, sizeof(FullStep) * (size_t)(calls.n + prog->temps.n + 1));
  /* each temp before the first call that needs it */
  bool *done = arena_alloc(ctx, sizeof(bool) * (size_t)(prog->temps.n + 1));
  for (int k = 0; k < calls.n; k++) {
    const FullStep *c = calls.v[k];
    const Stage *last = c->members[c->n - 1];
    for (int t = 0; t < prog->temps.n; t++) {
      const Sym *tmp = prog->temps.v[t];
      if (!done[t] && tmp->id < last->sym->id) {
        const Stage **m = arena_alloc(ctx, sizeof *m);
        m[0] = tmp->stage;
        p->steps[p->n++] = (FullStep){STEP_TEMP, emit_fn_name(ctx, "temp_", tmp), m, 1, false, false};
        done[t] = true;
      }
    }
    p->steps[p->n++] = *c;
  }
  return p;
}

static void box_body_cb(Emit *e, FILE *out, const void *arg) {
  const FullStep *c = arg;
  e->box = true;
  emit_direct_group(e, out, c->members, c->n);
  e->box = false;
}

/* A step's function, and for a boxed step its twin over boxes. */
static void emit_step(Emit *e, const FullStep *c) {
  Ctx *ctx = e->ctx;
  FILE *out = e->out;
  const Stage *st = c->members[0];
  const Sym *s = st->sym;
  if (c->kind == STEP_FUSED) {
    fprintf(out, "/* stages");
    for (int m = 0; m < c->n; m++) {
      const Sym *ms = c->members[m]->sym;
      fprintf(out, "%s %s (%s:%d: %s)", m ? "," : "", ms->name, emit_loc_file(ctx, ms->loc), ms->loc.line,
              emit_source_line(ctx, ms->loc));
    }
    fputs(", fused: one pass over their common domain */\n", out);
    e->writes = arena_alloc(ctx, sizeof(bool) * (size_t)(e->prog->slots.n + 1));
    for (int m = 0; m < c->n; m++) e->writes[vec_position(&e->prog->slots, c->members[m]->sym)] = true;
    Group g = {c->members, c->n};
    emit_function_sig(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c)", c->fn), NULL, group_body_cb, &g);
    e->writes = NULL;
  } else {
    if (c->before)
      fprintf(out, "/* %s: %s, %s:%d (computed before the fused stages it does not read)\n   %s */\n", s->name,
              stage_kind_name[st->kind], emit_loc_file(ctx, s->loc), s->loc.line,
              emit_source_line(ctx, s->loc));
    else if (s->introduced)
      fprintf(out, "/* %s: introduced for %s, from %s:%d\n   %s */\n", s->name, s->introduced_for->name,
              emit_loc_file(ctx, s->loc), s->loc.line, emit_source_line(ctx, s->loc));
    else
      fprintf(out, "/* %s: %s, %s:%d\n   %s */\n", s->name, stage_kind_name[st->kind],
              emit_loc_file(ctx, s->loc), s->loc.line, emit_source_line(ctx, s->loc));
    emit_function_sig(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c)", c->fn), s, stage_body_cb, st);
  }
  if (!c->boxed) return;
  fprintf(out, "/* %s over boxes of its domain */\n", c->fn);
  if (c->kind == STEP_FUSED) {
    e->writes = arena_alloc(ctx, sizeof(bool) * (size_t)(e->prog->slots.n + 1));
    for (int m = 0; m < c->n; m++) e->writes[vec_position(&e->prog->slots, c->members[m]->sym)] = true;
  }
  emit_function_sig(e, out,
                    arena_printf(ctx, "static int box_%s(const NpgCtx *c, int nbox_, const npg_idx *box_)", c->fn),
                    c->kind == STEP_FUSED ? NULL : s, box_body_cb, c);
  e->writes = NULL;
}

/* The entry point: every step in evaluation order; and the step entry
 * that runs one step, whole or over boxes. */
static void emit_entry(Emit *e, const FullPlan *p) {
  Ctx *ctx = e->ctx;
  FILE *out = e->out;
  fputs("/* Every stage in evaluation order (externs are given with the inputs). */\n", out);
  fprintf(out, "int %s(const NpgCtx *c) {\n", emit_symbol_name(ctx, e->prog, "full"));
  for (int k = 0; k < p->n; k++) fprintf(out, "  if (%s(c)) return -1;\n", p->steps[k].fn);
  fputs("  return 0;\n}\n\n", out);
  fputs("/* Step `step_` of the entry point above: whole (nbox_ < 0), or a boxed step over\n"
        " * nbox_ boxes (lo per index variable, then hi). */\n",
        out);
  fprintf(out, "int %s(const NpgCtx *c, int step_, int nbox_, const npg_idx *box_) {\n  (void)nbox_;\n  (void)box_;\n  switch (step_) {\n",
          emit_symbol_name(ctx, e->prog, "full_step"));
  for (int k = 0; k < p->n; k++) {
    const FullStep *c = &p->steps[k];
    if (c->boxed) fprintf(out, "  case %d: return nbox_ < 0 ? %s(c) : box_%s(c, nbox_, box_);\n", k, c->fn, c->fn);
    else fprintf(out, "  case %d: return %s(c);\n", k, c->fn);
  }
  fputs("  }\n  return -1;\n}\n\n", out);
}

void emit_full(Ctx *ctx, const Program *prog, FILE *out) {
  Emit *e = emit_new(ctx, prog, out);
  emit_header(e, "Full evaluator");
  emit_temps(e);
  emit_sparse_ops(e);
  FullPlan *p = emit_full_plan(ctx, prog);
  for (int k = 0; k < p->n; k++)
    if (p->steps[k].kind != STEP_TEMP) emit_step(e, &p->steps[k]);
  emit_entry(e, p);
  emit_checks(e);
}
