/* dump.c — the stage program in readable form (npgc check, -dl, -db) and
 * as JSON (npgc check --json). */
#include <stdlib.h>
#include <string.h>

#include "ir.h"

const char *const stage_kind_name[] = {"contraction", "operator application", "inverse", "root", "extern", "input"};

static const char *const kind_json[] = {"contraction", "apply", "inverse", "root", "extern", "input"};

static void print_shape(FILE *out, const Sym *s, bool with_vars) {
  fputs(s->is_int ? "int" : "real", out);
  if (s->ndims + s->nstatic == 0) return;
  fputc('[', out);
  for (int i = 0; i < s->ndims; i++) {
    if (i) fputs(", ", out);
    /* an implicit index variable (y = 2 * x) is the compiler's, not the user's: real[N], not real[_i:N] */
    if (with_vars && i < s->nivars && s->ivars[i] && !s->ivars[i]->introduced) fprintf(out, "%s:", s->ivars[i]->name);
    fputs(s->dims[i]->name, out);
  }
  for (int i = 0; i < s->nstatic; i++) fprintf(out, "%s%d", s->ndims + i ? ", " : "", s->shape[i]);
  fputc(']', out);
}

static void print_axes(FILE *out, const TensorGroup *g, const char *first, bool op) {
  fprintf(out, "(%s", first);
  if (op) fputs(", col", out);
  for (int i = 0; i < g->ninputs; i++) fprintf(out, ", %s", g->inputs[i]->name);
  fputc(')', out);
}

static void print_group(FILE *out, const TensorGroup *g, const char *first, bool op) {
  fprintf(out, "order %d ", g->order);
  print_axes(out, g, first, op);
  fprintf(out, ", %d monomial%s, nnz %s%s", g->nmono, g->nmono == 1 ? "" : "s", g->nnz_bound ? "≤ " : "", g->nnz);
  if (g->symmetric) fputs(", symmetric (repeated input stored packed)", out);
  if (g->ninputs == 0) fputs(op ? ", constant" : ", constant vector c", out);
  fputc('\n', out);
}

/* Degree of the stage in each quantity it reads: the largest multiplicity
 * in any of its tensors. */
typedef struct Degrees {
  const Sym *q[64];
  int d[64];
  int n;
} Degrees;

static void note_degrees(Degrees *dg, const TensorList *tl) {
  for (int g = 0; g < tl->n; g++)
    for (int i = 0; i < tl->g[g].ninputs;) {
      int j = i;
      while (j < tl->g[g].ninputs && tl->g[g].inputs[j] == tl->g[g].inputs[i]) j++;
      int k;
      for (k = 0; k < dg->n; k++)
        if (dg->q[k] == tl->g[g].inputs[i]) break;
      if (k == dg->n && dg->n < 64) dg->q[dg->n++] = tl->g[g].inputs[i], dg->d[k] = 0;
      if (k < 64 && j - i > dg->d[k]) dg->d[k] = j - i;
      i = j;
    }
}

static Degrees stage_degrees(const Program *prog, const Stage *st) {
  Degrees dg = {0};
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    if (tm->named_num) {
      TensorGroup g = {0};
      g.ninputs = 1;
      g.inputs[0] = tm->named_num;
      TensorList tl = {1, &g};
      note_degrees(&dg, &tl);
    } else {
      note_degrees(&dg, &tm->num_tensors);
    }
    for (int k = 0; k < tm->nops; k++) {
      if (tm->ops[k].kind == OPK_DIAG) note_degrees(&dg, &tm->op_tensors[k]);
      else {
        const OpDef *od = tm->ops[k].op->opdef;
        if (od) note_degrees(&dg, &od->tensors);
      }
    }
  }
  if (st->kind == ST_EXTERN)
    for (int i = 0; i < st->sym->nof && dg.n < 64; i++) dg.q[dg.n] = st->sym->of[i], dg.d[dg.n++] = 1;
  return dg;
}

static void print_op_power(FILE *out, const OpPow *o) {
  if (o->kind == OPK_DECL) fputs(o->op->name, out);
  else fputs("diag", out);
  if (o->q == 1) fprintf(out, "^%ld", o->p);
  else fprintf(out, "^(%ld/%ld)", o->p, o->q);
}

static void print_stage(FILE *out, const Program *prog, const Stage *st, bool canonical) {
  const Sym *s = st->sym;
  fprintf(out, "  %s : ", s->name);
  print_shape(out, s, true);
  fprintf(out, "   %s", stage_kind_name[st->kind]);
  if (s->is_output) fputs(", output", out);
  if (s->introduced) fprintf(out, ", introduced for %s", s->introduced_for->name);
  if (s->loc.file) fprintf(out, "   (%s:%d)", s->loc.file->name, s->loc.line);
  fputc('\n', out);
  Degrees dg = stage_degrees(prog, st);
  fputs("    reads:", out);
  if (dg.n == 0) fputs(" nothing varying", out);
  for (int i = 0; i < dg.n; i++) fprintf(out, "%s %s (degree %d)", i ? "," : "", dg.q[i]->name, dg.d[i]);
  fputc('\n', out);
  if (lower_interp_eligible(st))
    fprintf(out, "    interpolation: eligible (every operator diagonal; `npgc train --reduce %s:interp`, DESIGN §12)\n",
            s->name);
  if (st->kind == ST_EXTERN) {
    fputs("    black box: full values come with the data; reduced: learned convex combination of training samples (paper §8.3)\n", out);
    return;
  }
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    fprintf(out, "    term %d: ", t + 1);
    for (int k = tm->nops - 1; k >= 0; k--) {
      print_op_power(out, &tm->ops[k]);
      fputc(' ', out);
    }
    fputs(tm->named_num ? tm->named_num->name : (tm->nops ? "q" : "polynomial"), out);
    fputc('\n', out);
    for (int k = 0; k < tm->nops; k++) {
      const OpPow *o = &tm->ops[k];
      fprintf(out, "      operator ");
      print_op_power(out, o);
      fputs(o->kind == OPK_DIAG ? " (diagonal, reduced with the stage's basis on both axes):\n"
                                : " (declared op, reduced with the stage's basis on both axes):\n",
            out);
      const TensorList *tl = o->kind == OPK_DIAG ? &tm->op_tensors[k] : &o->op->opdef->tensors;
      for (int g = 0; g < tl->n; g++) {
        fputs("        tensor ", out);
        print_group(out, &tl->g[g], "row", true);
      }
    }
    if (tm->named_num) {
      fprintf(out, "      numerator: the named quantity %s, in %s's basis (no tensor)\n", tm->named_num->name, s->name);
    } else {
      if (tm->nops) fprintf(out, "      numerator (unnamed, its snapshots join %s's class):\n", s->name);
      for (int g = 0; g < tm->num_tensors.n; g++) {
        fputs(tm->nops ? "        tensor " : "      tensor ", out);
        print_group(out, &tm->num_tensors.g[g], s->name, false);
      }
    }
    if (canonical) {
      fputs("      canonical: ", out);
      print_term(out, tm);
      fputc('\n', out);
    }
  }
  if (prog->classes.n) fprintf(out, "    reduced cost: %s\n", stage_cost(prog->ctx, prog, st));
}

void dump_stages(FILE *out, const Program *prog) {
  fputs("stages (evaluation order):\n", out);
  for (int i = 0; i < prog->stages.n; i++) print_stage(out, prog, prog->stages.v[i], true);
}

void dump_classes(FILE *out, const Program *prog) {
  fputs("basis classes:\n", out);
  for (int i = 0; i < prog->classes.n; i++) {
    const BasisClass *c = prog->classes.v[i];
    fprintf(out, "  %s: {", c->size_name);
    for (int k = 0; k < c->members.n; k++) {
      const Sym *m = c->members.v[k];
      fprintf(out, "%s%s", k ? ", " : "", m->name);
      if (m->basis_max > 0 || m->basis_energy > 0 || m->basis_center >= 0) {
        const char *sep = " (";
        if (m->basis_max > 0) fprintf(out, "%scap %d", sep, m->basis_max), sep = ", ";
        if (m->basis_energy > 0) fprintf(out, "%senergy %g", sep, m->basis_energy), sep = ", ";
        if (m->basis_center >= 0) fprintf(out, "%scenter %s", sep, m->basis_center ? "on" : "off");
        fputc(')', out);
      }
    }
    fputc('}', out);
    for (int k = 0; k < c->joiners.n; k++) {
      const Joiner *j = c->joiners.v[k];
      fprintf(out, "%s numerator of %s term %d", k ? "," : "   + snapshots of the", j->stage->sym->name, j->term + 1);
    }
    fputc('\n', out);
  }
  if (prog->merges.n) fputs("merges:\n", out);
  for (int i = 0; i < prog->merges.n; i++) {
    const Merge *m = prog->merges.v[i];
    fprintf(out, "  %s and %s share a basis: %s\n", m->a->name, m->b->name, m->reason);
  }
}

void dump_program(FILE *out, const Program *prog) {
  fprintf(out, "program %s\n", prog->main->name);
  if (prog->dims.n) {
    fputs("dims:", out);
    for (int i = 0; i < prog->dims.n; i++) fprintf(out, " %s", ((Sym *)prog->dims.v[i])->name);
    fputc('\n', out);
  }
  if (prog->params.n) fputs("params:\n", out);
  for (int i = 0; i < prog->params.n; i++) {
    const Sym *s = prog->params.v[i];
    fprintf(out, "  %s : ", s->name);
    print_shape(out, s, false);
    fputc('\n', out);
  }
  fputs("inputs:\n", out);
  for (int i = 0; i < prog->inputs.n; i++) {
    const Sym *s = prog->inputs.v[i];
    fprintf(out, "  %s : ", s->name);
    print_shape(out, s, false);
    if (s->next && s->residual)
      fprintf(out, "   state (next value: %s, the zero of %s by Newton)", s->next->name, s->residual->name);
    else if (s->next) fprintf(out, "   state (next value: %s)", s->next->name);
    if (s->state_of) fprintf(out, "   the unknown of state %s's implicit step", s->state_of->name);
    if (s->is_output) fputs("   output", out);
    fputc('\n', out);
  }
  fputs("stages (evaluation order):\n", out);
  for (int i = 0; i < prog->stages.n; i++) print_stage(out, prog, prog->stages.v[i], false);
  if (prog->opdefs.n) fputs("operators:\n", out);
  for (int i = 0; i < prog->opdefs.n; i++) {
    const OpDef *od = prog->opdefs.v[i];
    fprintf(out, "  %s[", od->sym->name);
    for (int k = 0; k < od->sym->nivars; k++)
      fprintf(out, "%s%s:%s", k ? ", " : "", od->sym->ivars[k]->name, od->sym->ivars[k]->range->name);
    fprintf(out, "]%s  (%d row axis%s; %s)\n", od->sym->is_output ? "  output" : "", od->sym->nrow,
            od->sym->nrow == 1 ? "" : "es",
            od->sparse ? "sparse: assembled in compressed form, solved by CHOLMOD or UMFPACK"
                       : "dense: assembled whole, solved by LAPACK");
    for (int g = 0; g < od->tensors.n; g++) {
      fputs("    tensor ", out);
      print_group(out, &od->tensors.g[g], "row", true);
    }
  }
  dump_classes(out, prog);
  for (int i = 0; i < prog->notes.n; i++) fprintf(out, "note: %s\n", (char *)prog->notes.v[i]);
  fputs("basis defaults: energy 0.999, cap 60 per member, centered (README: Reducing a program)\n", out);
  bool *powered = lower_under_powers(prog);
  if (powered) {
    fputs("  kept whole (energy 1, up to the cap) as under a power (DESIGN §12):", out);
    for (int q = 0; q < prog->quantities.n; q++)
      if (powered[q]) fprintf(out, " %s", ((Sym *)prog->quantities.v[q])->name);
    fputc('\n', out);
  }
  free(powered);
  fputs("reduced cost per evaluation (multiply-adds; m_X = basis size of class X, S = training samples):\n", out);
  fprintf(out, "  %s\n", cost_formula(prog->ctx, prog));
}

/* ---------------------------------------------------------------- JSON */

static void json_str(FILE *out, const char *s) {
  fputc('"', out);
  for (; *s; s++) {
    unsigned char c = (unsigned char)*s;
    if (c == '"' || c == '\\') fprintf(out, "\\%c", c);
    else if (c == '\n') fputs("\\n", out);
    else if (c < 32) fprintf(out, "\\u%04x", c);
    else fputc(c, out);
  }
  fputc('"', out);
}

static void json_shape(FILE *out, const Sym *s) {
  fputs("[", out);
  for (int i = 0; i < s->ndims; i++) {
    if (i) fputc(',', out);
    json_str(out, s->dims[i]->name);
  }
  for (int i = 0; i < s->nstatic; i++) fprintf(out, "%s%d", s->ndims + i ? "," : "", s->shape[i]);
  fputs("]", out);
}

static void json_tensors(FILE *out, const TensorList *tl) {
  fputc('[', out);
  for (int g = 0; g < tl->n; g++) {
    const TensorGroup *t = &tl->g[g];
    fprintf(out, "%s{\"order\":%d,\"inputs\":[", g ? "," : "", t->order);
    for (int i = 0; i < t->ninputs; i++) {
      if (i) fputc(',', out);
      json_str(out, t->inputs[i]->name);
    }
    fprintf(out, "],\"monomials\":%d,\"nnz\":", t->nmono);
    json_str(out, t->nnz);
    fprintf(out, ",\"nnz_upper_bound\":%s,\"symmetric\":%s}", t->nnz_bound ? "true" : "false",
            t->symmetric ? "true" : "false");
  }
  fputc(']', out);
}

void dump_json(FILE *out, const Program *prog) {
  fputs("{\"program\":", out);
  json_str(out, prog->main->name);
  fputs(",\"inputs\":[", out);
  for (int i = 0; i < prog->inputs.n; i++) {
    const Sym *s = prog->inputs.v[i];
    fprintf(out, "%s{\"name\":", i ? "," : "");
    json_str(out, s->name);
    fputs(",\"shape\":", out);
    json_shape(out, s);
    if (s->next) {
      fputs(",\"next\":", out);
      json_str(out, s->next->name);
    }
    fprintf(out, ",\"class\":%d}", s->klass);
  }
  fputs("],\"stages\":[", out);
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    fprintf(out, "%s{\"name\":", i ? "," : "");
    json_str(out, st->sym->name);
    fprintf(out, ",\"kind\":\"%s\",\"shape\":", kind_json[st->kind]);
    json_shape(out, st->sym);
    fprintf(out, ",\"class\":%d,\"output\":%s,\"introduced\":%s,\"line\":%d,\"reads\":{", st->klass,
            st->sym->is_output ? "true" : "false", st->sym->introduced ? "true" : "false", st->sym->loc.line);
    Degrees dg = stage_degrees(prog, st);
    for (int k = 0; k < dg.n; k++) {
      if (k) fputc(',', out);
      json_str(out, dg.q[k]->name);
      fprintf(out, ":%d", dg.d[k]);
    }
    fprintf(out, "},\"interp_eligible\":%s,\"terms\":[", lower_interp_eligible(st) ? "true" : "false");
    for (int t = 0; t < st->nterms; t++) {
      const Term *tm = st->terms[t];
      fprintf(out, "%s{\"operators\":[", t ? "," : "");
      for (int k = 0; k < tm->nops; k++) {
        const OpPow *o = &tm->ops[k];
        fprintf(out, "%s{\"kind\":\"%s\",", k ? "," : "", o->kind == OPK_DIAG ? "diag" : "op");
        if (o->kind == OPK_DECL) {
          fputs("\"op\":", out);
          json_str(out, o->op->name);
          fputc(',', out);
        }
        fprintf(out, "\"power\":[%ld,%ld],\"tensors\":", o->p, o->q);
        json_tensors(out, o->kind == OPK_DIAG ? &tm->op_tensors[k] : &o->op->opdef->tensors);
        fputc('}', out);
      }
      fputs("],\"numerator\":", out);
      if (tm->named_num) json_str(out, tm->named_num->name);
      else fputs("null", out);
      fputs(",\"tensors\":", out);
      json_tensors(out, &tm->num_tensors);
      fputc('}', out);
    }
    fputs("],\"cost\":", out);
    json_str(out, stage_cost(prog->ctx, prog, st));
    fputc('}', out);
  }
  fputs("],\"classes\":[", out);
  for (int i = 0; i < prog->classes.n; i++) {
    const BasisClass *c = prog->classes.v[i];
    fprintf(out, "%s{\"id\":%d,\"size\":", i ? "," : "", c->id);
    json_str(out, c->size_name);
    fputs(",\"members\":[", out);
    for (int k = 0; k < c->members.n; k++) {
      if (k) fputc(',', out);
      json_str(out, ((Sym *)c->members.v[k])->name);
    }
    fputs("],\"options\":{", out);
    int nopt = 0;
    for (int k = 0; k < c->members.n; k++) {
      const Sym *m = c->members.v[k];
      if (m->basis_max <= 0 && m->basis_energy <= 0 && m->basis_center < 0) continue;
      fprintf(out, "%s", nopt++ ? "," : "");
      json_str(out, m->name);
      fputs(":{", out);
      const char *sep = "";
      if (m->basis_max > 0) fprintf(out, "%s\"cap\":%d", sep, m->basis_max), sep = ",";
      if (m->basis_energy > 0) fprintf(out, "%s\"energy\":%.17g", sep, m->basis_energy), sep = ",";
      if (m->basis_center >= 0) fprintf(out, "%s\"center\":%s", sep, m->basis_center ? "true" : "false");
      fputc('}', out);
    }
    fputs("},\"numerators\":[", out);
    for (int k = 0; k < c->joiners.n; k++) {
      const Joiner *j = c->joiners.v[k];
      fprintf(out, "%s{\"stage\":", k ? "," : "");
      json_str(out, j->stage->sym->name);
      fprintf(out, ",\"term\":%d}", j->term + 1);
    }
    fputs("]}", out);
  }
  fputs("],\"merges\":[", out);
  for (int i = 0; i < prog->merges.n; i++) {
    const Merge *m = prog->merges.v[i];
    fprintf(out, "%s{\"a\":", i ? "," : "");
    json_str(out, m->a->name);
    fputs(",\"b\":", out);
    json_str(out, m->b->name);
    fputs(",\"reason\":", out);
    json_str(out, m->reason);
    fputc('}', out);
  }
  fputs("],\"notes\":[", out);
  for (int i = 0; i < prog->notes.n; i++) {
    if (i) fputc(',', out);
    json_str(out, prog->notes.v[i]);
  }
  fputs("],\"cost\":", out);
  json_str(out, cost_formula(prog->ctx, prog));
  fputs("}\n", out);
}
