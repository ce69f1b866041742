/* emit_reduced.c — the reduced evaluator as C, specialized to one trained
 * model (DESIGN §6; paper §4), from its description (ReducedCode, emit.h),
 * which backends/model/reduced_code.c fills; backends/model/reduced_jit.c
 * compiles and runs it.
 *
 * The generated code does what reduced_eval() does (backends/model/reduced.c is
 * the reference), with every size a literal: for each stage
 *
 *     ŷ = Σ_t  (M̂_{t,k})^{r_k} ⋯ (M̂_{t,1})^{r_1} ŵ_t,
 *
 * each contraction a loop nest over the last axis first (the first step
 * reads its tensor once; rows are dot products with independent partial
 * sums, which gcc turns into vector lanes without reassociating; tcc does
 * not optimize, so the bodies stay simple with hoisted pointers and
 * literal offsets). Dense linear algebra — inverse powers (Cholesky or
 * LU), roots (eigendecomposition) — the externs' learned maps and the
 * interpolated stages (DESIGN §12) are not hand-rolled: they call back into the runtime evaluator through
 * NpgReducedRt (npg_abi.h), so both agree to rounding. The reduced tensors (megabytes) are not literals: the host
 * passes pointers in NpgReducedCtx.t, each tensor's `slot`. */
#include <setjmp.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"

/* ---------------------------------------------------------------- emitter state */

typedef struct RedEmit {
  const ReducedCode *m;
  Ctx *ctx;
  FILE *out;
  /* scratch (NpgReducedCtx.work) offsets, in doubles */
  long off_v, off_w, off_acc, off_M, off_buf[2], off_z, nwork;
  /* what the stage being written uses, so its prologue declares exactly that */
  bool use_v, use_w, use_acc, use_M;
  bool *use_q;
} RedEmit;

static long qm(const ReducedCode *m, int q) { return m->qm[q]; }

static const char *qname(const ReducedCode *m, int q) { return ((const Sym *)m->prog->quantities.v[q])->name; }

/* A C identifier: `prefix` then `name` with other characters as '_'. */
static char *c_ident(Ctx *ctx, const char *prefix, const char *name) {
  char *n = arena_printf(ctx, "%s%s", prefix, name);
  for (char *c = n; *c; c++)
    if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') || *c == '_')) *c = '_';
  return n;
}

static const char *qvar(RedEmit *e, int q) {
  e->use_q[q] = true;
  return c_ident(e->ctx, "Q_", qname(e->m, q));
}

/* The largest packed powers (maxz) and contraction intermediate (maxbuf) of `x`'s. */
static void tensors_work(const RcTensor *x, int n, long *maxz, long *maxbuf) {
  for (int g = 0; g < n; g++, x++) {
    long zs = 0, inter = x->rows;
    for (int j = 0; j < x->nin; j++)
      if (x->in_mult[j] > 1) zs += x->in_len[j];
    for (int j = 0; j + 1 < x->nin; j++) inter *= x->in_len[j];
    *maxz = zs > *maxz ? zs : *maxz;
    if (x->nin > 1) *maxbuf = inter > *maxbuf ? inter : *maxbuf;
  }
}

/* Scratch sizes, as reduced_new() sizes the runtime evaluator's buffers. */
static void plan_work(RedEmit *e) {
  const ReducedCode *m = e->m;
  long maxm = 1, maxbuf = 0, maxz = 0;
  for (int c = 0; c < m->nclasses; c++) maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      const RcTerm *rt = &m->stages[i].terms[t];
      tensors_work(rt->num, rt->nnum, &maxz, &maxbuf);
      for (int k = 0; k < rt->nops; k++) tensors_work(rt->ops[k].t, rt->ops[k].ntensors, &maxz, &maxbuf);
    }
  e->off_v = 0;
  e->off_w = maxm;
  e->off_acc = 2 * maxm;
  e->off_M = e->off_acc + maxm * maxm;
  e->off_buf[0] = e->off_M + maxm * maxm;
  e->off_buf[1] = e->off_buf[0] + maxbuf;
  e->off_z = e->off_buf[1] + maxbuf;
  e->nwork = e->off_z + maxz;
}

/* ---------------------------------------------------------------- loops */

/* A product to write: dst[i] (+)= Σ_j A[i·n + j] z[j] for i < lead. */
typedef struct Gemv {
  long lead, n;
  const char *A, *z, *dst;
  bool add;                 /* += (else =) */
} Gemv;

/* Partial sums s<r>_<k> of `rows` rows of `g` from row i, `acc` per row,
 * summed as a balanced tree into dst[i + r]. */
static void emit_dot_rows(FILE *out, int d, const Gemv *g, int rows, int acc) {
  long n = g->n;
  const char *A = g->A, *z = g->z, *dst = g->dst, *op = g->add ? "+=" : "=";
  long nk = n / acc * acc;
  for (int r = 0; r < rows; r++) {
    emit_indent(out, d);
    if (r) fprintf(out, "const double *const a%d = a%d + %ld;\n", r, r - 1, n);
    else fprintf(out, "const double *const a0 = %s + i * %ld;\n", A, n);
  }
  for (int r = 0; r < rows; r++) {
    emit_indent(out, d);
    fputs("double ", out);
    for (int k = 0; k < acc; k++) fprintf(out, "%ss%d_%d = 0.0", k ? ", " : "", r, k);
    fputs(";\n", out);
  }
  emit_indent(out, d);
  fprintf(out, "for (npg_idx j = 0; j < %ld; j += %d) {\n", nk, acc);
  for (int r = 0; r < rows; r++)
    for (int k = 0; k < acc; k++) {
      emit_indent(out, d + 1);
      if (k) fprintf(out, "s%d_%d += a%d[j + %d] * %s[j + %d];\n", r, k, r, k, z, k);
      else fprintf(out, "s%d_0 += a%d[j] * %s[j];\n", r, r, z);
    }
  emit_indent(out, d);
  fputs("}\n", out);
  for (int r = 0; r < rows; r++)
    for (long j = nk; j < n; j++) {
      emit_indent(out, d);
      fprintf(out, "s%d_%ld += a%d[%ld] * %s[%ld];\n", r, j - nk, r, j, z, j);
    }
  for (int r = 0; r < rows; r++) {
    emit_indent(out, d);
    if (r) fprintf(out, "%s[i + %d] %s ", dst, r, op);
    else fprintf(out, "%s[i] %s ", dst, op);
    if (acc == 4) fprintf(out, "(s%d_0 + s%d_1) + (s%d_2 + s%d_3);\n", r, r, r, r);
    else fprintf(out, "((s%d_0 + s%d_1) + (s%d_2 + s%d_3)) + ((s%d_4 + s%d_5) + (s%d_6 + s%d_7));\n", r, r, r, r, r, r, r, r);
  }
}

/* dst[i] (+)= Σ_j A[i·n + j] z[j] for i < lead: one dgemv of the runtime
 * evaluator. Rows of at most 8 are one unrolled sum each. Longer rows keep
 * independent partial sums, which gcc makes vector lanes without
 * reassociating anything: four rows at once with four sums each (their
 * chains interleave, z is loaded once for four rows), or one row with
 * eight sums when rows are long (64 and more). */
static void emit_gemv(FILE *out, int d, const Gemv *g) {
  long lead = g->lead, n = g->n;
  const char *A = g->A, *z = g->z, *dst = g->dst, *op = g->add ? "+=" : "=";
  if (n <= 8) {
    emit_indent(out, d);
    fprintf(out, "for (npg_idx i = 0; i < %ld; i++) {\n", lead);
    emit_indent(out, d + 1);
    if (n == 0) {
      fprintf(out, "%s[i] %s 0.0;\n", dst, op);
    } else {
      fprintf(out, "const double *const a = %s + i * %ld;\n", A, n);
      emit_indent(out, d + 1);
      fprintf(out, "%s[i] %s ", dst, op);
      for (long j = 0; j < n; j++) fprintf(out, "%sa[%ld] * %s[%ld]", j ? " + " : "", j, z, j);
      fputs(";\n", out);
    }
    emit_indent(out, d);
    fputs("}\n", out);
    return;
  }
  int rows = n >= 64 ? 1 : 4, acc = n >= 64 ? 8 : 4;
  long full = lead / rows * rows;
  if (full > 0) {
    emit_indent(out, d);
    if (rows > 1) fprintf(out, "for (npg_idx i = 0; i < %ld; i += %d) {\n", full, rows);
    else fprintf(out, "for (npg_idx i = 0; i < %ld; i++) {\n", full);
    emit_dot_rows(out, d + 1, g, rows, acc);
    emit_indent(out, d);
    fputs("}\n", out);
  }
  if (full < lead) { /* the rows left over */
    emit_indent(out, d);
    fprintf(out, "for (npg_idx i = %ld; i < %ld; i++) {\n", full, lead);
    emit_dot_rows(out, d + 1, g, 1, acc);
    emit_indent(out, d);
    fputs("}\n", out);
  }
}

static void emit_fill(FILE *out, int d, long n, const char *dst, const char *value) {
  emit_indent(out, d);
  fprintf(out, "for (npg_idx i = 0; i < %ld; i++) %s[i] = %s;\n", n, dst, value);
}

/* z[α] = Π_l x[α_l] over sorted multi-indices α, lexicographic (sym_power). */
static void emit_sym_power(FILE *out, int d, long m, int k, const char *x, const char *z) {
  emit_indent(out, d);
  fprintf(out, "double *p_ = %s;\n", z);
  for (int l = 0; l < k; l++) {
    emit_indent(out, d + l);
    if (l) fprintf(out, "for (npg_idx a%d = a%d; a%d < %ld; a%d++)\n", l, l - 1, l, m, l);
    else fprintf(out, "for (npg_idx a0 = 0; a0 < %ld; a0++)\n", m);
  }
  emit_indent(out, d + k);
  fputs("*p_++ = ", out);
  for (int l = 0; l < k; l++) fprintf(out, "%s%s[a%d]", l ? " * " : "", x, l);
  fputs(";\n", out);
}

/* out[0..rows) += T ⊗ z_1 ⊗ … ⊗ z_n (contract() of the runtime): the last
 * axis first, alternating between two scratch buffers. */
static void emit_contract(RedEmit *e, int d, const RcTensor *t, const char *dst) {
  FILE *out = e->out;
  long slot = t->slot;
  emit_indent(out, d);
  fprintf(out, "{ /* %s: %ld x %ld", t->name, t->rows, t->cols);
  for (int j = 0; j < t->nin; j++)
    fprintf(out, ", %s%s (%ld)", qname(e->m, t->in_q[j]),
            t->in_mult[j] > 1 ? arena_printf(e->ctx, "^%d packed", t->in_mult[j]) : "", t->in_len[j]);
  fputs(" */\n", out);
  emit_indent(out, d + 1);
  fprintf(out, "const double *const T = c->t[%ld];\n", slot);
  if (t->nin == 0) {
    emit_indent(out, d + 1);
    fprintf(out, "for (npg_idx i = 0; i < %ld; i++) %s[i] += T[i];\n", t->rows, dst);
    emit_indent(out, d);
    fputs("}\n", out);
    return;
  }
  const char *z[RC_MAX_IN];
  long zoff = e->off_z;
  for (int j = 0; j < t->nin; j++) {
    const char *x = qvar(e, t->in_q[j]);
    if (t->in_mult[j] == 1) {
      z[j] = x;
      continue;
    }
    z[j] = arena_printf(e->ctx, "z%d", j);
    emit_indent(out, d + 1);
    fprintf(out, "double *const z%d = c->work + %ld; /* %s^%d packed */\n", j, zoff, qname(e->m, t->in_q[j]),
            t->in_mult[j]);
    emit_indent(out, d + 1);
    fputs("{\n", out);
    emit_sym_power(out, d + 2, qm(e->m, t->in_q[j]), t->in_mult[j], x, z[j]);
    emit_indent(out, d + 1);
    fputs("}\n", out);
    zoff += t->in_len[j];
  }
  if (t->nin > 1) { /* intermediates: b0 after the first step, b1 after the second, ... */
    emit_indent(out, d + 1);
    fprintf(out, "double *const b0 = c->work + %ld;\n", e->off_buf[0]);
  }
  if (t->nin > 2) {
    emit_indent(out, d + 1);
    fprintf(out, "double *const b1 = c->work + %ld;\n", e->off_buf[1]);
  }
  long lead = t->rows;
  for (int j = 0; j + 1 < t->nin; j++) lead *= t->in_len[j];
  const char *src = "T";
  int b = 0;
  for (int j = t->nin - 1; j >= 0; j--) {
    const char *to = j == 0 ? dst : b ? "b1" : "b0";
    emit_gemv(out, d + 1, &(Gemv){lead, t->in_len[j], src, z[j], to, j == 0});
    src = to;
    b ^= 1;
    if (j > 0) lead /= t->in_len[j - 1];
  }
  emit_indent(out, d);
  fputs("}\n", out);
}

/* "M^(-1)", "(diagonal operator 1)^(-1/2)" */
static const char *op_label(const RcOp *ro, int k, char *buf, size_t n) {
  char pw[64];
  if (ro->op->q == 1) snprintf(pw, sizeof pw, "%ld", ro->op->p);
  else snprintf(pw, sizeof pw, "%ld/%ld", ro->op->p, ro->op->q);
  if (ro->op->kind == OPK_DECL) snprintf(buf, n, "%s^(%s)", ro->op->op->name, pw);
  else snprintf(buf, n, "(diagonal operator %d)^(%s)", k + 1, pw);
  return buf;
}

/* v <- (M̂)^(p/q) v for operator k of term t of stage number i. */
static void emit_op(RedEmit *e, int i, int t, int k, const RcOp *ro, long my) {
  FILE *out = e->out;
  char lab[256];
  const OpPow *op = ro->op;
  fprintf(out, "  /* %s%s */\n", op_label(ro, k, lab, sizeof lab), ro->spd ? ", positive definite in training" : "");
  e->use_M = true;
  if (op->kind == OPK_DIAG) { /* packed upper triangle, unpacked */
    e->use_acc = true;
    emit_fill(out, 1, my * (my + 1) / 2, "acc", "0.0");
    for (int g = 0; g < ro->ntensors; g++) emit_contract(e, 1, &ro->t[g], "acc");
    fprintf(out,
            "  {\n"
            "    const double *p_ = acc;\n"
            "    for (npg_idx a = 0; a < %ld; a++)\n"
            "      for (npg_idx b = a; b < %ld; b++) {\n"
            "        const double d_ = *p_++;\n"
            "        M[a * %ld + b] = d_;\n"
            "        M[b * %ld + a] = d_;\n"
            "      }\n"
            "  }\n",
            my, my, my, my);
  } else {
    emit_fill(out, 1, my * my, "M", "0.0");
    for (int g = 0; g < ro->ntensors; g++) emit_contract(e, 1, &ro->t[g], "M");
  }
  if (op->q == 1 && op->p > 0) { /* positive integer powers: products */
    e->use_w = true;
    fprintf(out, "  for (int r_ = 0; r_ < %ld; r_++) {\n", op->p);
    emit_gemv(out, 2, &(Gemv){my, my, "M", "v", "w", false});
    emit_fill(out, 2, my, "v", "w[i]");
    fputs("  }\n", out);
    return;
  }
  fprintf(out, "  if (c->rt->op_power(c, %d, %d, %d, %ld, M, %ld, %ld, v)) return -1;\n", i, t, k, my, op->p, op->q);
}

static void emit_stage_body(RedEmit *e, int i) {
  const ReducedCode *m = e->m;
  FILE *out = e->out;
  const RcStage *rs = &m->stages[i];
  long my = qm(m, rs->q);
  e->use_v = true;
  emit_fill(out, 1, my, "y", "0.0");
  for (int t = 0; t < rs->nterms; t++) {
    const RcTerm *rt = &rs->terms[t];
    fprintf(out, "  /* term %d of %d */\n", t + 1, rs->nterms);
    if (rt->named_q >= 0 && rt->proj_slot >= 0) {
      fprintf(out, "  { /* %s, projected: B(%s)^T B(%s), %ld x %ld */\n", qname(m, rt->named_q), qname(m, rs->q),
              qname(m, rt->named_q), my, qm(m, rt->named_q));
      fprintf(out, "    const double *const P = c->t[%ld];\n", rt->proj_slot);
      emit_gemv(out, 2, &(Gemv){my, qm(m, rt->named_q), "P", qvar(e, rt->named_q), "v", false});
      fputs("  }\n", out);
    } else if (rt->named_q >= 0) {
      emit_fill(out, 1, my, "v", arena_printf(e->ctx, "%s[i]", qvar(e, rt->named_q)));
    } else {
      emit_fill(out, 1, my, "v", "0.0");
      for (int g = 0; g < rt->nnum; g++) emit_contract(e, 1, &rt->num[g], "v");
    }
    for (int k = 0; k < rt->nops; k++) emit_op(e, i, t, k, &rt->ops[k], my); /* innermost first (DESIGN §4) */
    fprintf(out, "  for (npg_idx i = 0; i < %ld; i++) y[i] += v[i];\n", my);
  }
  fputs("  return 0;\n", out);
}

/* One stage: its body into memory first, so the prologue declares exactly
 * what it used. */
static void emit_stage(RedEmit *e, int i, const char *fname) {
  const ReducedCode *m = e->m;
  const RcStage *rs = &m->stages[i];
  const Sym *s = rs->st->sym;
  const RcClass *rc = &m->classes[rs->klass];
  FILE *out = e->out;
  e->use_v = e->use_w = e->use_acc = e->use_M = false;
  memset(e->use_q, 0, sizeof(bool) * (size_t)m->nq);
  char *body = NULL;
  size_t len = 0;
  FILE *mem = open_memstream(&body, &len);
  iassert(e->ctx, mem);
  e->ctx->open_file = mem; /* closed if an allocation failure jumps out */
  e->out = mem;
  emit_stage_body(e, i);
  e->out = out;
  e->ctx->open_file = NULL;
  fclose(mem);
  e->ctx->pending_free = body;
  const char *file = emit_loc_file(e->ctx, s->loc);
  if (s->introduced)
    fprintf(out, "/* %s: introduced for %s, from %s:%d; class %s, m = %ld\n   %s */\n", s->name,
            s->introduced_for->name, file, s->loc.line, rc->label, rc->m, emit_source_line(e->ctx, s->loc));
  else
    fprintf(out, "/* %s: %s, %s:%d; class %s, m = %ld\n   %s */\n", s->name, stage_kind_name[rs->st->kind], file,
            s->loc.line, rc->label, rc->m, emit_source_line(e->ctx, s->loc));
  fprintf(out, "static int %s(const NpgReducedCtx *c) {\n", fname);
  fprintf(out, "  double *const y = c->x[%d]; /* %s */\n", rs->q, s->name);
  for (int q = 0; q < m->nq; q++)
    if (e->use_q[q]) fprintf(out, "  const double *const %s = c->x[%d];\n", qvar(e, q), q);
  if (e->use_v) fprintf(out, "  double *const v = c->work + %ld; /* a term */\n", e->off_v);
  if (e->use_w) fprintf(out, "  double *const w = c->work + %ld;\n", e->off_w);
  if (e->use_acc) fprintf(out, "  double *const acc = c->work + %ld; /* a diagonal operator, packed */\n", e->off_acc);
  if (e->use_M) fprintf(out, "  double *const M = c->work + %ld; /* an operator, %ld x %ld */\n", e->off_M, rc->m, rc->m);
  fwrite(body, 1, len, out);
  fputs("}\n\n", out);
  e->ctx->pending_free = NULL;
  free(body);
}

static void emit_unit(RedEmit *e) {
  const ReducedCode *m = e->m;
  FILE *out = e->out;
  fprintf(out, "/* Reduced evaluator of %s, generated by npgc: one trained model (%ld samples,\n"
               "   program hash %016llx), every size a literal.\n",
          emit_comment_text(m->prog->ctx, m->prog->main->name), m->samples, (unsigned long long)m->program_hash);
  for (int c = 0; c < m->nclasses; c++)
    fprintf(out, "     class %-24s n = %-8ld m = %ld\n", m->classes[c].label, m->classes[c].n, m->classes[c].m);
  fputs("*/\n\n", out);
  fputs(npg_abi_header, out);
  fputs("\n/* What the host passes (npg_abi.h, NpgReducedCtx): c->x[q] the coordinates of\n"
        "   quantity q, c->t[k] tensor k (rows x cols, row-major):\n",
        out);
  for (long k = 0; k < m->nslots; k++)
    fprintf(out, "     %4ld  %-28s %ld x %ld\n", k, m->slots[k].name, m->slots[k].rows, m->slots[k].cols);
  const char *coords = emit_symbol_name(e->ctx, m->prog, "reduced_coords");
  const char *tensors = emit_symbol_name(e->ctx, m->prog, "reduced_tensors");
  const char *work = emit_symbol_name(e->ctx, m->prog, "reduced_work");
  fprintf(out, "   and c->work %s doubles of scratch. */\n", work);
  fprintf(out, "const npg_idx %s[] = {%d", coords, m->nq);
  for (int q = 0; q < m->nq; q++) fprintf(out, ", %ld", qm(m, q));
  fputs("};\n", out);
  fprintf(out, "const npg_idx %s[] = {%ld", tensors, m->nslots);
  for (long k = 0; k < m->nslots; k++) fprintf(out, ", %ld", m->slots[k].rows * m->slots[k].cols);
  fputs("};\n", out);
  fprintf(out, "const npg_idx %s = %ld;\n\n", work, e->nwork);

  const char **fname = arena_alloc(e->ctx, sizeof(char *) * (size_t)(m->nstages + 1));
  for (int i = 0; i < m->nstages; i++) {
    if (m->stages[i].st->kind == ST_EXTERN || m->stages[i].interp) continue; /* the host's (NpgReducedRt.learned) */
    fname[i] = c_ident(e->ctx, "stage_", m->stages[i].st->sym->name);
    emit_stage(e, i, fname[i]);
  }
  fprintf(out,
          "/* Every stage in evaluation order; externs (their learned maps) and interpolated stages through the host. */\n"
          "int %s(const NpgReducedCtx *c) {\n",
          emit_symbol_name(e->ctx, m->prog, "reduced"));
  for (int i = 0; i < m->nstages; i++) {
    if (fname[i]) fprintf(out, "  if (%s(c)) return -1;\n", fname[i]);
    else fprintf(out, "  if (c->rt->learned(c, %d)) return -1; /* %s %s */\n", i,
                 m->stages[i].interp ? "interpolated" : "extern", m->stages[i].st->sym->name);
  }
  fputs("  return 0;\n}\n\n", out);
  fprintf(out,
          "/* Stage number i alone (the model's order), from the current coordinates. */\n"
          "int %s(const NpgReducedCtx *c, int i) {\n"
          "  switch (i) {\n",
          emit_symbol_name(e->ctx, m->prog, "reduced_stage"));
  for (int i = 0; i < m->nstages; i++) {
    if (fname[i]) fprintf(out, "  case %d: return %s(c);\n", i, fname[i]);
    else fprintf(out, "  case %d: return c->rt->learned(c, %d);\n", i, i);
  }
  fputs("  default: return -1;\n  }\n}\n", out);
}

/* The arena may jump out on allocation failure: catch it here (as
 * npg_emit_full does), since the reduced code is written outside npg_compile. */
static int guarded_unit(RedEmit *e, Err *err) {
  Ctx *ctx = e->ctx;
  jmp_buf env, *saved = ctx->on_error;
  ctx->on_error = &env;
  int rc = 0;
  if (setjmp(env) == 0) {
    emit_unit(e);
  } else {
    err_set(err, "%s", ctx->msg ? ctx->msg : "error: generating the reduced evaluator failed");
    if (ctx->open_file) fclose(ctx->open_file);
    ctx->open_file = NULL;
    rc = -1;
  }
  ctx->on_error = saved;
  free(ctx->pending_free);
  ctx->pending_free = NULL;
  return rc;
}

int emit_reduced_code(const ReducedCode *m, FILE *out, Err *err) {
  RedEmit e = {.m = m, .ctx = m->prog->ctx, .out = out};
  if (!(e.use_q = calloc((size_t)m->nq + 1, sizeof *e.use_q)))
    return err_set(err, "out of memory while generating the reduced evaluator");
  plan_work(&e);
  int rc = guarded_unit(&e, err);
  if (rc == 0 && ferror(out)) rc = err_set(err, "cannot write the reduced evaluator");
  free(e.use_q);
  return rc;
}
