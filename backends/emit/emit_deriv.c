/* emit_deriv.c — the derivatives of the full evaluator as C (DESIGN §17), from the
 * canonical form of every stage, y = Σ_t M_{t,k}^{r_k} ⋯ M_{t,1}^{r_1} q_t (ir.h):
 *
 *   a polynomial:   d(coef · Π_a A_a) = coef · Σ_a (Π_{b≠a} A_b) dA_a, entry by entry;
 *   a diagonal:     d(t · d^r) = dt · d^r + t · r d^(r-1) · dd;
 *   a declared op:  y = M^r v, dy = M^r dv + D(M^r)[dM] v (NpgRt.power_jvp: one LU for
 *                   an inverse, d(M^-1 f) = M^-1 (df - dM M^-1 f); Daleckii-Krein from the
 *                   eigendecomposition for a root).
 *
 * The forward product (P_npg_full_jvp) runs the stages in evaluation order, each
 * writing its tangent from the tangents of what it reads; the reverse product
 * (P_npg_full_vjp) runs them backwards, each adding its cotangent times its partial
 * derivatives into the cotangents of what it reads (a gather's transpose is a scatter,
 * so the loops are the forward loops with the statement turned around) and a declared
 * operator's entries getting the cotangent of M from NpgRt.power_vjp (transposed solves).
 * Both run after the evaluation whose values they read (NpgCtx c); the derivatives live
 * in a second context d (npg_abi.h NpgDerivFn). Declared operators are assembled dense,
 * as the evaluator assembles them; a sparse one's tangent or cotangent lives on its
 * pattern, listed by a derivative enumerator of its entries (NpgOpDerivFn), its solves
 * by SuiteSparse (NpgRt.sparse_power_jvp / sparse_power_vjp). */
#include <stdlib.h>
#include <string.h>

#include "emit.h"

typedef enum DerivMode {
  DERIV_TANGENT, /* acc += ∂(poly) · tangents */
  DERIV_ADJOINT, /* cotangents += acc · ∂(poly) */
} DerivMode;

/* The C name of quantity q's derivative array (tangent or cotangent), dQ_<name>: a local
 * the function's prologue loads from d->q (deriv_function). */
static const char *dname(Emit *e, const Sym *q) {
  e->used_deriv[vec_position(&e->prog->slots, q)] = true;
  return arena_printf(e->ctx, "d%s", emit_name(e, q));
}

/* A derivative function's body, and the derivative arrays it uses loaded into locals
 * before it (libtcc would reload d->q[k] at every access). */
typedef struct DerivBody {
  void (*body)(Emit *, FILE *, const void *);
  const void *arg;
  bool *used;               /* per slot, from a first pass over the body */
} DerivBody;

static void deriv_body(Emit *e, FILE *out, const void *arg) {
  const DerivBody *b = arg;
  for (int k = 0; k < e->prog->slots.n; k++)
    if (b->used[k]) fprintf(out, "  double *restrict const d%s = d->q[%d];\n", emit_name(e, e->prog->slots.v[k]), k);
  b->body(e, out, b->arg);
}

/* emit_function_sig's function with deriv_body: the body emitted once into scratch text
 * to learn the arrays it uses, then for real. */
static void deriv_function(Emit *e, FILE *out, const char *signature, void (*body)(Emit *, FILE *, const void *),
                           const void *arg) {
  char *buf = NULL;
  size_t len = 0;
  FILE *scratch = open_memstream(&buf, &len);
  if (!scratch) error_plain(e->ctx, "out of memory");
  int nslots = e->prog->slots.n;
  memset(e->used_deriv, 0, sizeof(bool) * (size_t)(nslots + 1));
  e->ctx->pending_free = buf;
  body(e, scratch, arg);
  fclose(scratch);
  e->ctx->pending_free = NULL;
  free(buf);
  DerivBody b = {body, arg, arena_alloc(e->ctx, sizeof(bool) * (size_t)(nslots + 1))};
  memcpy(b.used, e->used_deriv, sizeof(bool) * (size_t)(nslots + 1));
  emit_function_sig(e, out, signature, NULL, deriv_body, &b);
}

/* The entry (tangent or cotangent) of atom `a`'s quantity. */
static void emit_datom(Emit *e, FILE *out, const Atom *a) {
  fprintf(out, "%s[", dname(e, a->q));
  int k = vec_position(&e->prog->slots, a->q);
  bool used = e->used_q[k]; /* the offset reads the dims, not the values */
  emit_offset(e, out, a->q, a->idx, a->nidx);
  e->used_q[k] = used;
  fputc(']', out);
}

/* For each atom a of monomial m = coef · Π_a A_a, one statement: the tangent
 * `acc += coef · Π_{b≠a} A_b · dA_a`, or the adjoint `dA_a += acc · coef · Π_{b≠a} A_b`;
 * `coef` the C text of the coefficient, or NULL for m's own. */
static void emit_mono_partials(Emit *e, FILE *out, const Mono *m, const char *coef, const char *acc, DerivMode mode,
                               int d) {
  for (int a = 0; a < m->natoms; a++) {
    emit_indent(out, d);
    if (mode == DERIV_TANGENT) fprintf(out, "%s += ", acc);
    else {
      emit_datom(e, out, &m->atoms[a]);
      fprintf(out, " += %s * ", acc);
    }
    if (coef) fputs(coef, out);
    else emit_cexpr(e, out, m->coef);
    for (int b = 0; b < m->natoms; b++)
      if (b != a) {
        fputs(" * ", out);
        emit_atom(e, out, &m->atoms[b]);
      }
    if (mode == DERIV_TANGENT) {
      fputs(" * ", out);
      emit_datom(e, out, &m->atoms[a]);
    }
    fputs(";\n", out);
  }
}

/* emit_mono_partials for every monomial of p, its sums as loops and its guard tested. */
static void emit_dpoly(Emit *e, FILE *out, const Poly *p, const char *acc, DerivMode mode, int depth) {
  for (int i = 0; i < p->n; i++) {
    const Mono *m = p->m[i];
    if (!m->natoms) continue;
    int d = depth;
    for (int s = 0; s < m->nsums; s++) emit_sum_loop(e, out, &m->sums[s], d++, true);
    if (m->guard) {
      emit_indent(out, d++);
      fputs("if (", out);
      emit_cexpr(e, out, m->guard);
      fputs(") {\n", out);
    }
    emit_mono_partials(e, out, m, NULL, acc, mode, d);
    emit_close_loops(out, d, depth);
  }
}

/* ---------------------------------------------------------------- sparse operators */

/* One contribution of a sparse operator's entries (emit_full.c's entry_body, in the same
 * order): its tangent into val_, or val_'s cotangent through its partial derivatives. */
static void dentry_body(Emit *e, FILE *out, const Mono *m, const MonoPart *pt, const Sym *op, int d, const void *arg) {
  (void)op, (void)arg;
  emit_part_guard(e, out, m, d);
  emit_part_coef(e, out, pt, d);
  if (!m->natoms) { /* a constant entry: no derivative, but a contribution all the same */
    emit_indent(out, d);
    fputs("cnt_++;\n", out);
    return;
  }
  emit_indent(out, d);
  fputs("if (cnt_ < cap_ && mode_ == 0) {\n", out);
  emit_indent(out, d + 1);
  fputs("double t_ = 0.0;\n", out);
  emit_mono_partials(e, out, m, "w_", "t_", DERIV_TANGENT, d + 1);
  emit_indent(out, d + 1);
  fputs("val_[slot_[cnt_]] += t_;\n", out);
  emit_indent(out, d);
  fputs("} else if (cnt_ < cap_) {\n", out);
  emit_indent(out, d + 1);
  fputs("const double g_ = val_[slot_[cnt_]];\n", out);
  emit_mono_partials(e, out, m, "w_", "g_", DERIV_ADJOINT, d + 1);
  emit_indent(out, d);
  fputs("}\n", out);
  emit_indent(out, d);
  fputs("cnt_++;\n", out);
}

static void dentries_cb(Emit *e, FILE *out, const void *arg) {
  const OpDef *od = arg;
  const Poly *p = &od->entries->comp[0];
  fputs("  npg_idx cnt_ = 0;\n  (void)d, (void)mode_, (void)cap_, (void)slot_, (void)val_;\n", out);
  for (int i = 0; i < p->n; i++) {
    MonoPart parts[TENSOR_MAXPARTS];
    int np = tensor_mono_parts(e->ctx, p->m[i], od->sym->ivars, od->sym->nivars, parts);
    for (int k = 0; k < np; k++) emit_part(e, out, od->sym, p->m[i], &parts[k], 1, 0, &(PartEmit){NULL, dentry_body, NULL});
  }
  fputs("  return cnt_;\n", out);
}

/* The entries function of every sparse operator (as the evaluator's), and its derivative
 * enumerator (NpgOpDerivFn). */
static void emit_sparse_derivs(Emit *e) {
  emit_sparse_ops(e);
  for (int i = 0; i < e->prog->opdefs.n; i++) {
    const OpDef *od = e->prog->opdefs.v[i];
    if (!od->sparse || !emit_op_applied(e->prog, od)) continue;
    fprintf(e->out, "/* derivatives of the entries of sparse operator %s */\n", od->sym->name);
    deriv_function(e, e->out,
                   arena_printf(e->ctx, "static npg_idx %s(const NpgCtx *c, const NpgCtx *d, int mode_, npg_idx cap_, "
                                "const npg_idx *slot_, double *val_)", emit_fn_name(e->ctx, "dentries_", od->sym)),
                   dentries_cb, od);
  }
}

static const char *ratio(Ctx *ctx, const OpPow *o) { return arena_printf(ctx, "(%ld.0 / %ld.0)", o->p, o->q); }

/* `const double pw<k>_ = d^r, dpw<k>_ = r d^(r-1);` for the diagonal d<k>_ (k < 0: no
 * suffix), the common powers without pow() (as the evaluator's emit_apply_diag): the
 * derivative as r pw / d where d is not 0. */
static void emit_power_pair(Emit *e, FILE *out, const OpPow *o, int k, int depth) {
  const char *sfx = k < 0 ? "_" : arena_printf(e->ctx, "%d_", k), *r = ratio(e->ctx, o);
  const char *d = arena_printf(e->ctx, "d%s", sfx), *pw;
  if (o->q == 1 && o->p == -1) pw = arena_printf(e->ctx, "1.0 / %s", d);
  else if (o->q == 1 && o->p == -2) pw = arena_printf(e->ctx, "1.0 / (%s * %s)", d, d);
  else if (o->q == 2 && o->p == -1) pw = arena_printf(e->ctx, "1.0 / sqrt(%s)", d);
  else if (o->q == 2 && o->p == 1) pw = arena_printf(e->ctx, "sqrt(%s)", d);
  else if (o->q == 2 && o->p == -3) pw = arena_printf(e->ctx, "1.0 / (%s * sqrt(%s))", d, d);
  else pw = arena_printf(e->ctx, "pow(%s, %s)", d, r);
  emit_indent(out, depth);
  fprintf(out, "const double pw%s = %s;\n", sfx, pw);
  emit_indent(out, depth);
  fprintf(out, "const double dpw%s = %s != 0.0 ? %s * pw%s / %s : %s * pow(%s, %s - 1.0);\n", sfx, d, r, sfx, d, r, d, r);
}

/* t_ and its tangent dt_ (declared by the caller) multiplied by the diagonals of term
 * `tm` (component c), each d^r: dt_ <- dt_ d^r + t_ r d^(r-1) dd. */
static void emit_diags_tangent(Emit *e, FILE *out, const Term *tm, int c, int depth) {
  for (int k = 0; k < tm->nops; k++) {
    const OpPow *o = &tm->ops[k];
    if (o->kind != OPK_DIAG) continue;
    emit_indent(out, depth);
    fputs("{\n", out);
    emit_indent(out, depth + 1);
    fputs("double d_ = 0.0, dd_ = 0.0;\n", out);
    emit_poly(e, out, &o->diag->comp[c], "d_", depth + 1);
    emit_dpoly(e, out, &o->diag->comp[c], "dd_", DERIV_TANGENT, depth + 1);
    emit_power_pair(e, out, o, -1, depth + 1);
    emit_indent(out, depth + 1);
    fputs("dt_ = dt_ * pw_ + t_ * dpw_ * dd_;\n", out);
    emit_indent(out, depth + 1);
    fputs("t_ *= pw_;\n", out);
    emit_indent(out, depth);
    fputs("}\n", out);
  }
}

/* The cotangent `g` of t = q_c · Π_k d_k^(r_k) (term `tm`'s numerator and diagonals,
 * component c) sent into the cotangents of what they read. */
static void emit_diags_adjoint(Emit *e, FILE *out, const Term *tm, int c, const char *g, int depth) {
  emit_indent(out, depth);
  fputs("{\n", out);
  emit_indent(out, depth + 1);
  fputs("double t_ = 0.0;\n", out);
  emit_poly(e, out, &tm->num->comp[c], "t_", depth + 1);
  emit_indent(out, depth + 1);
  fputs("(void)t_;\n", out);
  for (int k = 0; k < tm->nops; k++) {
    const OpPow *o = &tm->ops[k];
    if (o->kind != OPK_DIAG) continue;
    emit_indent(out, depth + 1);
    fprintf(out, "double d%d_ = 0.0;\n", k);
    emit_poly(e, out, &o->diag->comp[c], arena_printf(e->ctx, "d%d_", k), depth + 1);
    emit_power_pair(e, out, o, k, depth + 1);
  }
  /* the partial derivative in the numerator, then in each diagonal */
  for (int j = -1; j < tm->nops; j++) {
    if (j >= 0 && tm->ops[j].kind != OPK_DIAG) continue;
    emit_indent(out, depth + 1);
    fprintf(out, "{\n");
    emit_indent(out, depth + 2);
    fprintf(out, "const double g_ = %s%s", g, j >= 0 ? arena_printf(e->ctx, " * t_ * dpw%d_", j) : "");
    for (int k = 0; k < tm->nops; k++)
      if (k != j && tm->ops[k].kind == OPK_DIAG) fprintf(out, " * pw%d_", k);
    fputs(";\n", out);
    emit_indent(out, depth + 2);
    fputs("(void)g_;\n", out);
    emit_dpoly(e, out, j < 0 ? &tm->num->comp[c] : &tm->ops[j].diag->comp[c], "g_", DERIV_ADJOINT, depth + 2);
    emit_indent(out, depth + 1);
    fprintf(out, "}\n");
  }
  emit_indent(out, depth);
  fputs("}\n", out);
}

static bool term_has_decl(const Term *t) {
  for (int k = 0; k < t->nops; k++)
    if (t->ops[k].kind == OPK_DECL) return true;
  return false;
}

/* `npg_idx n_` = the entries of stage s (a vector a declared operator acts on). */
static void emit_count(Emit *e, FILE *out, const Sym *s) {
  fputs("    npg_idx n_ = 1;\n", out);
  for (int i = 0; i < s->nivars; i++) {
    emit_use(e, s->ivars[i]->range);
    fprintf(out, "    n_ *= %s;\n", emit_name(e, s->ivars[i]->range));
  }
}

/* m_ (and with `tangent` dm_) <- the dense entries of declared operator `op`. */
static void emit_assemble(Emit *e, FILE *out, const Sym *op, bool tangent, int depth) {
  int od = emit_open_entry_loops(e, out, op, depth);
  emit_indent(out, od);
  fputs(tangent ? "double t_ = 0.0, dt_ = 0.0;\n" : "double t_ = 0.0;\n", out);
  emit_poly(e, out, &op->opdef->entries->comp[0], "t_", od);
  if (tangent) emit_dpoly(e, out, &op->opdef->entries->comp[0], "dt_", DERIV_TANGENT, od);
  emit_indent(out, od);
  fputs(tangent ? "m_[e_] = t_;\n" : "m_[e_] = t_;\n", out);
  if (tangent) {
    emit_indent(out, od);
    fputs("dm_[e_] = dt_;\n", out);
  }
  emit_close_loops(out, od, depth);
}

/* The tangent of a term with declared operators: v = the numerator times the inner
 * diagonals, then each operator's power applied with its tangent. */
static void emit_decl_tangent(Emit *e, FILE *out, const Stage *st, int t) {
  const Sym *s = st->sym;
  const Term *tm = st->terms[t];
  fprintf(out, "  { /* term %d: declared operators */\n", t + 1);
  emit_count(e, out, s);
  fputs("    double *v_ = c->rt->scratch(c, n_), *dv_ = c->rt->scratch(c, n_);\n", out);
  fputs("    if (!v_ || !dv_) { c->rt->release(c, v_); c->rt->release(c, dv_); return -1; }\n", out);
  int d = emit_open_entry_loops(e, out, s, 2);
  emit_indent(out, d);
  fputs("double t_ = 0.0, dt_ = 0.0;\n", out);
  emit_poly(e, out, &tm->num->comp[0], "t_", d);
  emit_dpoly(e, out, &tm->num->comp[0], "dt_", DERIV_TANGENT, d);
  emit_diags_tangent(e, out, tm, 0, d);
  emit_indent(out, d);
  fputs("v_[e_] = t_;\n", out);
  emit_indent(out, d);
  fputs("dv_[e_] = dt_;\n", out);
  emit_close_loops(out, d, 2);
  for (int k = 0; k < tm->nops; k++) {
    if (tm->ops[k].kind != OPK_DECL) continue;
    const Sym *op = tm->ops[k].op;
    if (op->opdef->sparse) {
      fprintf(out, "    /* %s^(%ld/%ld), sparse, and its tangent */\n", op->name, tm->ops[k].p, tm->ops[k].q);
      fprintf(out, "    if (c->rt->sparse_power_jvp(c, d, \"%s\", \"%s\", %d, n_, %s, %s, %ld, %ld, v_, dv_)) {\n", s->name,
              op->name, vec_position(&e->prog->opdefs, op->opdef), emit_fn_name(e->ctx, "entries_", op),
              emit_fn_name(e->ctx, "dentries_", op), tm->ops[k].p, tm->ops[k].q);
      fputs("      c->rt->release(c, v_);\n      c->rt->release(c, dv_);\n      return -1;\n    }\n", out);
      continue;
    }
    fprintf(out, "    { /* %s^(%ld/%ld) and its tangent */\n", op->name, tm->ops[k].p, tm->ops[k].q);
    fputs("      double *m_ = c->rt->scratch(c, n_ * n_), *dm_ = c->rt->scratch(c, n_ * n_);\n", out);
    fputs("      if (!m_ || !dm_) { c->rt->release(c, m_); c->rt->release(c, dm_); c->rt->release(c, v_); "
          "c->rt->release(c, dv_); return -1; }\n",
          out);
    emit_assemble(e, out, op, true, 3);
    fprintf(out, "      int bad_ = c->rt->power_jvp(c, \"%s\", \"%s\", n_, m_, dm_, %ld, %ld, v_, dv_);\n", s->name,
            op->name, tm->ops[k].p, tm->ops[k].q);
    fputs("      c->rt->release(c, m_);\n      c->rt->release(c, dm_);\n", out);
    fputs("      if (bad_) { c->rt->release(c, v_); c->rt->release(c, dv_); return -1; }\n    }\n", out);
  }
  fprintf(out, "    for (npg_idx e_ = 0; e_ < n_; e_++) %s[e_] += dv_[e_];\n", dname(e, s));
  fputs("    c->rt->release(c, v_);\n    c->rt->release(c, dv_);\n  }\n", out);
}

/* The tangent of stage `st`: entrywise terms entry by entry, then the terms with
 * declared operators added. */
static void emit_stage_tangent(Emit *e, FILE *out, const void *arg) {
  const Stage *st = arg;
  if (emit_ddirect_tangent(e, out, st)) return; /* on the evaluator's value graph */
  const Sym *s = st->sym;
  int nc = st->ncomp;
  int depth = emit_open_entry_loops(e, out, s, 1);
  for (int c = 0; c < nc; c++) {
    emit_indent(out, depth);
    fprintf(out, "double dy%d_ = 0.0;\n", c);
  }
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    if (term_has_decl(tm)) continue;
    for (int c = 0; c < nc; c++) {
      emit_indent(out, depth);
      fprintf(out, "{ /* term %d, component %d */\n", t + 1, c);
      emit_indent(out, depth + 1);
      fputs("double t_ = 0.0, dt_ = 0.0;\n", out);
      emit_poly(e, out, &tm->num->comp[c], "t_", depth + 1);
      emit_dpoly(e, out, &tm->num->comp[c], "dt_", DERIV_TANGENT, depth + 1);
      emit_diags_tangent(e, out, tm, c, depth + 1);
      emit_indent(out, depth + 1);
      fprintf(out, "(void)t_;\n");
      emit_indent(out, depth + 1);
      fprintf(out, "dy%d_ += dt_;\n", c);
      emit_indent(out, depth);
      fputs("}\n", out);
    }
  }
  for (int c = 0; c < nc; c++) {
    emit_indent(out, depth);
    fprintf(out, "%s[e_ * %d + %d] = dy%d_;\n", dname(e, s), nc, c, c);
  }
  emit_close_loops(out, depth, 1);
  for (int t = 0; t < st->nterms; t++)
    if (term_has_decl(st->terms[t])) {
      iassert(e->ctx, nc == 1);
      emit_decl_tangent(e, out, st, t);
    }
}

/* A sparse operator's step of emit_decl_adjoint: with `pass` 0 its power applied to
 * w_[jj] into w_[jj + 1]; with pass 1 (`first`: the last operator, vb_ loaded from the
 * stage's cotangent first) vb_ sent back through it, its entries' cotangents scattered by
 * its derivative enumerator. */
static void emit_sparse_adjoint(Emit *e, FILE *out, const Sym *s, const OpPow *o, int pass, int jj, bool first) {
  const char *entries = emit_fn_name(e->ctx, "entries_", o->op);
  int opid = vec_position(&e->prog->opdefs, o->op->opdef);
  fprintf(out, "    /* %s^(%ld/%ld), sparse%s */\n", o->op->name, o->p, o->q, pass ? ", reverse" : "");
  if (!pass) {
    fprintf(out, "    for (npg_idx e_ = 0; e_ < n_; e_++) w_[n_ * %d + e_] = w_[n_ * %d + e_];\n", jj + 1, jj);
    fprintf(out, "    if (c->rt->sparse_power(c, \"%s\", \"%s\", %d, n_, %s, %ld, %ld, w_ + n_ * %d)) {\n", s->name,
            o->op->name, opid, entries, o->p, o->q, jj + 1);
  } else {
    if (first) fprintf(out, "    for (npg_idx e_ = 0; e_ < n_; e_++) vb_[e_] = %s[e_];\n", dname(e, s));
    fprintf(out, "    if (c->rt->sparse_power_vjp(c, d, \"%s\", \"%s\", %d, n_, %s, %s, %ld, %ld, w_ + n_ * %d, vb_)) {\n",
            s->name, o->op->name, opid, entries, emit_fn_name(e->ctx, "dentries_", o->op), o->p, o->q, jj);
  }
  fputs("      c->rt->release(c, w_);\n      c->rt->release(c, vb_);\n      return -1;\n    }\n", out);
}

/* The reverse product of a term with declared operators: the forward vectors
 * w_[j] (the numerator with its diagonals, then after each operator) recomputed, then
 * the operators backwards (transposed solves, the cotangent of each operator's entries
 * scattered into what they read), then the numerator and its diagonals. */
static void emit_decl_adjoint(Emit *e, FILE *out, const Stage *st, int t) {
  const Sym *s = st->sym;
  const Term *tm = st->terms[t];
  int nd = 0;
  for (int k = 0; k < tm->nops; k++) nd += tm->ops[k].kind == OPK_DECL;
  fprintf(out, "  { /* term %d: declared operators, reverse */\n", t + 1);
  emit_count(e, out, s);
  fprintf(out, "    double *w_ = c->rt->scratch(c, n_ * %d), *vb_ = c->rt->scratch(c, n_);\n", nd);
  fputs("    if (!w_ || !vb_) { c->rt->release(c, w_); c->rt->release(c, vb_); return -1; }\n", out);
  int d = emit_open_entry_loops(e, out, s, 2);
  emit_indent(out, d);
  fputs("double t_ = 0.0, dt_ = 0.0;\n", out);
  emit_poly(e, out, &tm->num->comp[0], "t_", d);
  emit_diags_tangent(e, out, tm, 0, d);
  emit_indent(out, d);
  fputs("(void)dt_;\n", out);
  emit_indent(out, d);
  fputs("w_[e_] = t_;\n", out);
  emit_close_loops(out, d, 2);
  for (int pass = 0; pass < 2; pass++) /* 0: forward vectors; 1: backwards */
    for (int j = 0; j < nd; j++) {
      int jj = pass ? nd - 1 - j : j, k = -1;
      if (!pass && jj == nd - 1) continue; /* the last vector is not read: the reverse step recomputes it */
      for (int seen = -1; seen < jj;) seen += tm->ops[++k].kind == OPK_DECL;
      const OpPow *o = &tm->ops[k];
      if (o->op->opdef->sparse) {
        emit_sparse_adjoint(e, out, s, o, pass, jj, j == 0);
        continue;
      }
      fprintf(out, "    { /* %s^(%ld/%ld)%s */\n", o->op->name, o->p, o->q, pass ? ", reverse" : "");
      fputs("      double *m_ = c->rt->scratch(c, n_ * n_);\n", out);
      fputs("      if (!m_) { c->rt->release(c, w_); c->rt->release(c, vb_); return -1; }\n", out);
      emit_assemble(e, out, o->op, false, 3);
      if (!pass) {
        fprintf(out, "      for (npg_idx e_ = 0; e_ < n_; e_++) w_[n_ * %d + e_] = w_[n_ * %d + e_];\n", jj + 1, jj);
        fprintf(out, "      int bad_ = c->rt->op_power(c, \"%s\", \"%s\", n_, m_, %ld, %ld, w_ + n_ * %d);\n", s->name,
                o->op->name, o->p, o->q, jj + 1);
        fputs("      c->rt->release(c, m_);\n", out);
        fputs("      if (bad_) { c->rt->release(c, w_); c->rt->release(c, vb_); return -1; }\n    }\n", out);
        continue;
      }
      if (j == 0) fprintf(out, "      for (npg_idx e_ = 0; e_ < n_; e_++) vb_[e_] = %s[e_];\n", dname(e, s));
      fputs("      double *mb_ = c->rt->scratch(c, n_ * n_);\n", out);
      fprintf(out, "      int bad_ = !mb_ || c->rt->power_vjp(c, \"%s\", \"%s\", n_, m_, mb_, %ld, %ld, w_ + n_ * %d, vb_);\n",
              s->name, o->op->name, o->p, o->q, jj);
      fputs("      c->rt->release(c, m_);\n", out);
      fputs("      if (bad_) { c->rt->release(c, mb_); c->rt->release(c, w_); c->rt->release(c, vb_); return -1; }\n", out);
      int od = emit_open_entry_loops(e, out, o->op, 3);
      emit_indent(out, od);
      fputs("const double g_ = mb_[e_];\n", out);
      emit_indent(out, od);
      fputs("if (g_ != 0.0) {\n", out);
      emit_dpoly(e, out, &o->op->opdef->entries->comp[0], "g_", DERIV_ADJOINT, od + 1);
      emit_indent(out, od);
      fputs("}\n", out);
      emit_close_loops(out, od, 3);
      fputs("      c->rt->release(c, mb_);\n    }\n", out);
    }
  d = emit_open_entry_loops(e, out, s, 2);
  emit_indent(out, d);
  fputs("const double yb_ = vb_[e_];\n", out);
  emit_diags_adjoint(e, out, tm, 0, "yb_", d);
  emit_close_loops(out, d, 2);
  fputs("    c->rt->release(c, w_);\n    c->rt->release(c, vb_);\n  }\n", out);
}

/* The reverse product of stage `st`: its cotangent times each term's partial
 * derivatives, added into the cotangents of what the term reads. */
static void emit_stage_adjoint(Emit *e, FILE *out, const void *arg) {
  const Stage *st = arg;
  if (emit_ddirect_adjoint(e, out, st)) return; /* on the evaluator's value graph */
  const Sym *s = st->sym;
  int nc = st->ncomp;
  bool any_entrywise = false;
  for (int t = 0; t < st->nterms; t++) any_entrywise |= !term_has_decl(st->terms[t]);
  if (any_entrywise) {
    int depth = emit_open_entry_loops(e, out, s, 1);
    for (int c = 0; c < nc; c++) {
      emit_indent(out, depth);
      fprintf(out, "const double yb%d_ = %s[e_ * %d + %d];\n", c, dname(e, s), nc, c);
      emit_indent(out, depth);
      fprintf(out, "if (yb%d_ != 0.0) { /* component %d */\n", c, c);
      emit_indent(out, depth + 1);
      fprintf(out, "const double yb_ = yb%d_;\n", c);
      for (int t = 0; t < st->nterms; t++)
        if (!term_has_decl(st->terms[t])) emit_diags_adjoint(e, out, st->terms[t], c, "yb_", depth + 1);
      emit_indent(out, depth);
      fputs("}\n", out);
    }
    emit_close_loops(out, depth, 1);
  }
  for (int t = 0; t < st->nterms; t++)
    if (term_has_decl(st->terms[t])) {
      iassert(e->ctx, nc == 1);
      emit_decl_adjoint(e, out, st, t);
    }
}

/* Whether the stage has a value to differentiate (inputs and externs are given). */
static bool computed(const Stage *st) { return st->kind != ST_INPUT && st->kind != ST_EXTERN; }

void emit_deriv(Ctx *ctx, const Program *prog, FILE *out) {
  if (prog->externs.n)
    error_plain(ctx, "extern '%s' is a black box: the program has no derivative (DESIGN §17); derivatives "
                     "need every stage in closed form",
                ((Sym *)prog->externs.v[0])->name);
  Emit *e = emit_new(ctx, prog, out);
  e->used_deriv = arena_alloc(ctx, sizeof(bool) * (size_t)(prog->slots.n + 1));
  emit_header(e, "Derivatives of the full evaluator");
  emit_sparse_derivs(e);
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (!computed(st)) continue;
    const Sym *s = st->sym;
    fprintf(out, "/* %s: %s, %s:%d\n   %s */\n", s->name, stage_kind_name[st->kind], emit_loc_file(ctx, s->loc),
            s->loc.line, emit_source_line(ctx, s->loc));
    deriv_function(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c, const NpgCtx *d)", emit_fn_name(ctx, "jvp_", s)),
                   emit_stage_tangent, st);
    deriv_function(e, out, arena_printf(ctx, "static int %s(const NpgCtx *c, const NpgCtx *d)", emit_fn_name(ctx, "vjp_", s)),
                   emit_stage_adjoint, st);
  }
  fputs("/* Tangents of every stage, in evaluation order. */\n", out);
  fprintf(out, "int %s(const NpgCtx *c, const NpgCtx *d) {\n", emit_symbol_name(ctx, prog, "full_jvp"));
  for (int i = 0; i < prog->stages.n; i++)
    if (computed(prog->stages.v[i]))
      fprintf(out, "  if (%s(c, d)) return -1;\n", emit_fn_name(ctx, "jvp_", ((Stage *)prog->stages.v[i])->sym));
  fputs("  return 0;\n}\n\n", out);
  fputs("/* Cotangents, every stage in reverse evaluation order. */\n", out);
  fprintf(out, "int %s(const NpgCtx *c, const NpgCtx *d) {\n", emit_symbol_name(ctx, prog, "full_vjp"));
  for (int i = prog->stages.n - 1; i >= 0; i--)
    if (computed(prog->stages.v[i]))
      fprintf(out, "  if (%s(c, d)) return -1;\n", emit_fn_name(ctx, "vjp_", ((Stage *)prog->stages.v[i])->sym));
  fputs("  return 0;\n}\n", out);
}
