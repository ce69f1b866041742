/* emit_sparse.c — the loops over a sparse operator's entries (DESIGN §13).
 * An equality in a monomial's guard or coefficient (`nbr[i, k] == j`,
 * `delta(j, tab[i, k])`) determines a variable, so the generated C computes
 * it instead of looping over its dim: K·N points, not N^2. The full
 * evaluator's entry enumeration and bind-time checks (emit_full.c, emit_checks.c) and the
 * tensor builders (emit_builder.c) share these loops. */
#include "emit.h"

static void indent(FILE *out, int depth) {
  for (int i = 0; i < depth; i++) fputs("  ", out);
}

static const SumVar *sum_of(const Mono *m, const Sym *var) {
  for (int k = 0; k < m->nsums; k++)
    if (m->sums[k].var == var) return &m->sums[k];
  return NULL;
}

void emit_part(Emit *e, FILE *out, const Sym *op, const Mono *m, const MonoPart *pt, int depth, int nouter,
               const PartEmit *how) {
  int d = depth;
  indent(out, d++);
  fputs("{\n", out);
  for (int o = 0; o < pt->nvars; o++) {
    int v = pt->order[o];
    if (pt->fixed_by[v] || v < nouter) continue;
    const Sym *var = pt->vars[v];
    if (var->kind == SYM_SUMVAR) {
      emit_sum_loop(e, out, sum_of(m, var), d++, true);
    } else {
      const char *name = emit_name(e, var);
      emit_use(e, var->range);
      indent(out, d++);
      fprintf(out, "for (npg_idx %s = 0; %s < %s; %s++) {\n", name, name, emit_name(e, var->range), name);
    }
  }
  int loops = d;
  indent(out, d++);
  fputs("do {\n", out);
  for (int o = 0; o < pt->nvars; o++) {
    int v = pt->order[o];
    if (!pt->fixed_by[v]) continue;
    const Sym *var = pt->vars[v];
    const char *name = emit_name(e, var);
    if (how->fixed) how->fixed(e, out, pt->fixed_by[v], op, d);
    indent(out, d);
    fprintf(out, "const npg_idx %s = (npg_idx)(", name);
    emit_cexpr(e, out, pt->fixed_by[v]);
    fputs(");\n", out);
    indent(out, d);
    const SumVar *sv = var->kind == SYM_SUMVAR ? sum_of(m, var) : NULL;
    if (sv) {
      fprintf(out, "if (%s < ", name);
      emit_cexpr(e, out, sv->lo);
      fprintf(out, " || %s > ", name);
      emit_cexpr(e, out, sv->hi);
      fputs(") continue;\n", out);
    } else {
      emit_use(e, var->range);
      fprintf(out, "if (%s < 0 || %s >= %s) continue;\n", name, name, emit_name(e, var->range));
    }
  }
  how->body(e, out, m, pt, op, d, how->arg);
  indent(out, loops);
  fputs("} while (0);\n", out);
  for (int k = loops - 1; k >= depth; k--) {
    indent(out, k);
    fputs("}\n", out);
  }
}

void emit_part_guard(Emit *e, FILE *out, const Mono *m, int depth) {
  if (!m->guard) return;
  indent(out, depth);
  fputs("if (!(", out);
  emit_cexpr(e, out, m->guard);
  fputs(")) continue;\n", out);
}

void emit_part_coef(Emit *e, FILE *out, const MonoPart *pt, int depth) {
  indent(out, depth);
  fprintf(out, "const double w_ = %d.0", pt->sign);
  for (int f = 0; f < pt->nfactors; f++) {
    fputs(" * ", out);
    emit_cexpr(e, out, pt->factors[f]);
  }
  fputs(";\n", out);
  indent(out, depth);
  fputs("if (w_ == 0.0) continue;\n", out);
}

bool emit_sparse_rows_free(Ctx *ctx, const OpDef *od) {
  const Poly *p = &od->entries->comp[0];
  for (int i = 0; i < p->n; i++) {
    MonoPart parts[TENSOR_MAXPARTS];
    int np = tensor_mono_parts(ctx, p->m[i], od->sym->ivars, od->sym->nivars, parts);
    for (int k = 0; k < np; k++)
      for (int v = 0; v < od->sym->nrow; v++)
        if (parts[k].fixed_by[v]) return false;
  }
  return true;
}
