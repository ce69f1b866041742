/* cexpr.c — C text of names, coefficients and offsets, shared by the
 * emitters. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"

const char *emit_name(Emit *e, const Sym *s) {
  const char *prefix = "x_";
  switch (s->kind) {
  case SYM_INPUT:
  case SYM_STAGE:
  case SYM_EXTERN: prefix = "Q_"; break;
  case SYM_PARAM: prefix = "P_"; break;
  case SYM_DIM: prefix = "D_"; break;
  case SYM_IVAR: prefix = "i_"; break;
  case SYM_SUMVAR: prefix = "k_"; break;
  case SYM_OP: prefix = "M_"; break;
  default: break;
  }
  char *n = arena_printf(e->ctx, "%s%s", prefix, s->name);
  for (char *c = n; *c; c++)
    if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') || *c == '_')) *c = '_';
  if (s->kind == SYM_SUMVAR) n = arena_printf(e->ctx, "%s_%d", n, s->id); /* renamed copies stay distinct */
  return n;
}

void emit_use(Emit *e, const Sym *s) {
  int k;
  switch (s->kind) {
  case SYM_DIM:
    if ((k = vec_position(&e->prog->dims, s)) >= 0) e->used_dim[k] = true;
    break;
  case SYM_PARAM:
    if ((k = vec_position(&e->prog->params, s)) >= 0) e->used_param[k] = true;
    break;
  case SYM_INPUT:
  case SYM_STAGE:
  case SYM_EXTERN:
    if ((k = vec_position(&e->prog->slots, s)) >= 0) e->used_q[k] = true;
    break;
  default: break;
  }
}

void emit_reset_used(Emit *e) {
  memset(e->used_dim, 0, sizeof(bool) * (size_t)(e->prog->dims.n + 1));
  memset(e->used_param, 0, sizeof(bool) * (size_t)(e->prog->params.n + 1));
  memset(e->used_q, 0, sizeof(bool) * (size_t)(e->prog->slots.n + 1));
}

void emit_double(FILE *out, double v) {
  /* A constant may fold to an infinity or NaN (1e300 * 1e300): C has no
   * literal for them without <math.h>, and "inf" is an undeclared name.
   * These expressions give them in any C compiler and in libtcc. */
  if (isnan(v)) {
    fputs("(0.0 / 0.0)", out);
    return;
  }
  if (isinf(v)) {
    fputs(v > 0 ? "(1e300 * 1e300)" : "(-1e300 * 1e300)", out);
    return;
  }
  if (v == floor(v) && fabs(v) < 1e15) {
    fprintf(out, "%.1f", v);
    return;
  }
  char buf[64];
  snprintf(buf, sizeof buf, "%.17g", v);
  fputs(buf, out);
  if (!strpbrk(buf, ".eEn")) fputs(".0", out);
}

static void offset_texts(Emit *e, FILE *out, const Sym *q, char *const *idx) {
  int naxes = q->ndims + q->nstatic;
  if (naxes == 0) {
    fputc('0', out);
    return;
  }
  /* ((i0 * D1 + i1) * S0 + c0) ... */
  for (int i = 1; i < naxes; i++) fputc('(', out);
  for (int i = 0; i < naxes; i++) {
    if (i) {
      if (i < q->ndims) {
        emit_use(e, q->dims[i]);
        fprintf(out, " * %s + ", emit_name(e, q->dims[i]));
      } else {
        fprintf(out, " * %d + ", q->shape[i - q->ndims]);
      }
    }
    fprintf(out, "(%s)", idx[i]);
    if (i) fputc(')', out);
  }
}

static void cexpr_cb(FILE *out, const void *arg) {
  const void *const *a = arg;
  emit_cexpr((Emit *)a[0], out, a[1]);
}

void emit_offset(Emit *e, FILE *out, const Sym *q, Node *const *idx, int nidx) {
  emit_use(e, q);
  int naxes = q->ndims + q->nstatic;
  char **texts = arena_alloc(e->ctx, sizeof(char *) * (size_t)(naxes + 1));
  for (int i = 0; i < naxes; i++) {
    const void *arg[2] = {e, i < nidx ? idx[i] : NULL};
    texts[i] = i < nidx ? print_to_arena(e->ctx, cexpr_cb, arg) : "0";
  }
  offset_texts(e, out, q, texts);
}

void emit_sum_loop(Emit *e, FILE *out, const SumVar *sv, int depth, bool brace) {
  const char *k = emit_name(e, sv->var);
  for (int i = 0; i < depth; i++) fputs("  ", out);
  fprintf(out, "for (npg_idx %s = ", k);
  emit_cexpr(e, out, sv->lo);
  fprintf(out, "; %s <= ", k);
  emit_cexpr(e, out, sv->hi);
  fprintf(out, "; %s++)%s\n", k, brace ? " {" : "");
}

static void bin(Emit *e, FILE *out, const Node *n, const char *op) {
  fputc('(', out);
  emit_cexpr(e, out, n->a);
  fprintf(out, " %s ", op);
  emit_cexpr(e, out, n->b);
  fputc(')', out);
}

const char *emit_math_name(Builtin b) {
  switch (b) {
  case B_EXP: return "exp";
  case B_LOG: return "log";
  case B_SIN: return "sin";
  case B_COS: return "cos";
  case B_TAN: return "tan";
  case B_ATAN: return "atan";
  case B_ATAN2: return "atan2";
  case B_ABS: return "fabs";
  case B_FLOOR: return "floor";
  case B_MIN: return "fmin";
  case B_MAX: return "fmax";
  case B_TANH: return "tanh";
  default: return NULL;
  }
}

void emit_cexpr(Emit *e, FILE *out, const Node *n) {
  switch (n->kind) {
  case N_NUM:
    if (n->is_int && fabs(n->num) < 9e15) fprintf(out, "%lld", (long long)n->num);
    else emit_double(out, n->num);
    return;
  case N_RAT: emit_double(out, (double)n->p / (double)n->q); return;
  case N_NAME: {
    const Sym *s = n->sym;
    if (s->kind == SYM_PARAM) {
      emit_use(e, s);
      fprintf(out, "%s[0]", emit_name(e, s));
      return;
    }
    emit_use(e, s);
    fputs(emit_name(e, s), out);
    return;
  }
  case N_INDEX:
    fprintf(out, "%s[", emit_name(e, n->sym));
    emit_offset(e, out, n->sym, n->args, n->nargs);
    fputc(']', out);
    return;
  case N_ADD: bin(e, out, n, "+"); return;
  case N_SUB: bin(e, out, n, "-"); return;
  case N_MUL: bin(e, out, n, "*"); return;
  case N_DIV:
    fputs("((double)", out);
    emit_cexpr(e, out, n->a);
    fputs(" / ", out);
    emit_cexpr(e, out, n->b);
    fputc(')', out);
    return;
  case N_EQ: bin(e, out, n, "=="); return;
  case N_NE: bin(e, out, n, "!="); return;
  case N_LT: bin(e, out, n, "<"); return;
  case N_LE: bin(e, out, n, "<="); return;
  case N_GT: bin(e, out, n, ">"); return;
  case N_GE: bin(e, out, n, ">="); return;
  case N_AND: bin(e, out, n, "&&"); return;
  case N_OR: bin(e, out, n, "||"); return;
  case N_NEG:
    fputs("(-", out);
    emit_cexpr(e, out, n->a);
    fputc(')', out);
    return;
  case N_NOT:
    fputs("(!", out);
    emit_cexpr(e, out, n->a);
    fputc(')', out);
    return;
  case N_POW:
    fputs("pow(", out);
    emit_cexpr(e, out, n->a);
    fputs(", ", out);
    emit_cexpr(e, out, n->b);
    fputc(')', out);
    return;
  case N_IF:
    fputc('(', out);
    emit_cexpr(e, out, n->a);
    fputs(" ? ", out);
    emit_cexpr(e, out, n->b);
    fputs(" : ", out);
    emit_cexpr(e, out, n->c);
    fputc(')', out);
    return;
  case N_SUM: {
    /* a coefficient sum: a GNU statement expression (gcc, clang and tcc) */
    const char *k = emit_name(e, n->sym);
    int t = e->tmp++;
    fprintf(out, "__extension__({ double s%d_ = 0.0; for (npg_idx %s = ", t, k);
    emit_cexpr(e, out, n->a);
    fprintf(out, "; %s <= ", k);
    emit_cexpr(e, out, n->b);
    fprintf(out, "; %s++) s%d_ += ", k, t);
    emit_cexpr(e, out, n->c);
    fprintf(out, "; s%d_; })", t);
    return;
  }
  case N_CALL:
    if (n->builtin == B_DELTA) {
      fputs("((double)(", out);
      emit_cexpr(e, out, n->args[0]);
      fputs(" == ", out);
      emit_cexpr(e, out, n->args[1]);
      fputs("))", out);
      return;
    }
    if (emit_math_name(n->builtin)) {
      fprintf(out, "%s(", emit_math_name(n->builtin));
      for (int i = 0; i < n->nargs; i++) {
        if (i) fputs(", ", out);
        fputs("(double)", out);
        emit_cexpr(e, out, n->args[i]);
      }
      fputc(')', out);
      return;
    }
    break;
  default: break;
  }
  internal_error(e->ctx, __FILE__, __LINE__, "expression kind not emitted");
}

void emit_prologue(Emit *e, FILE *out, bool write_stage, const Sym *stage) {
  const Program *prog = e->prog;
  for (int i = 0; i < prog->dims.n; i++)
    if (e->used_dim[i]) fprintf(out, "  const npg_idx %s = c->dims[%d];\n", emit_name(e, prog->dims.v[i]), i);
  for (int i = 0; i < prog->params.n; i++)
    if (e->used_param[i]) {
      const Sym *p = prog->params.v[i];
      if (p->is_int) fprintf(out, "  const npg_iparam *restrict const %s = c->iparams[%d];\n", emit_name(e, p), i);
      else fprintf(out, "  const double *restrict const %s = c->params[%d];\n", emit_name(e, p), i);
    }
  for (int i = 0; i < prog->slots.n; i++) {
    const Sym *q = prog->slots.v[i];
    /* restrict: the stage written never aliases what it reads, so the C
     * compiler may hoist loads out of the inner loops */
    if ((write_stage && q == stage) || (e->writes && e->writes[i]))
      fprintf(out, "  double *restrict const %s = c->q[%d];\n", emit_name(e, q), i);
    else if (e->used_q[i]) fprintf(out, "  const double *restrict const %s = c->q[%d];\n", emit_name(e, q), i);
  }
}
