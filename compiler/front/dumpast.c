/* dumpast.c — -dp: the declarations as parsed. */
#include "compile.h"

static const char *const decl_names[] = {"dim", "param", "input", "stage", "op", "extern",
                                         "fn", "share", "basis", "inline", "use", "output"};

void dump_decls(FILE *out, const Decl *d) {
  fputs("declarations (parsed):\n", out);
  for (; d; d = d->next) {
    fprintf(out, "  %s:%d: %s", d->loc.file ? d->loc.file->name : "?", d->loc.line, decl_names[d->kind]);
    if (d->name) fprintf(out, " %s", d->name);
    if (d->nivars) {
      fputc('[', out);
      for (int i = 0; i < d->nivars; i++) fprintf(out, "%s%s:%s", i ? ", " : "", d->ivars[i].name, d->ivars[i].dim);
      fputc(']', out);
    }
    for (int i = 0; i < d->nnames; i++) fprintf(out, "%s%s", i ? ", " : " ", d->names[i]);
    if (d->body) {
      fputs(" = ", out);
      print_node(out, d->body);
    }
    if (d->is_output) fputs("  (output)", out);
    fputc('\n', out);
  }
}

/* -ds: every definition after checking: fn calls inlined, sqrt/root/if
 * rewritten, exponents as rational literals. */
void dump_checked(FILE *out, const Program *prog) {
  fputs("definitions (checked):\n", out);
  for (const Decl *d = prog->decls; d; d = d->next) {
    if (d->kind != D_STAGE && d->kind != D_OP) continue;
    const Sym *s = NULL;
    for (int i = 0; i < prog->quantities.n && !s; i++)
      if (((Sym *)prog->quantities.v[i])->decl == d) s = prog->quantities.v[i];
    for (int i = 0; i < prog->ops.n && !s; i++)
      if (((Sym *)prog->ops.v[i])->decl == d) s = prog->ops.v[i];
    fprintf(out, "  %s%s %s", d->kind == D_OP ? "op " : "", d->name, s && s->inlined ? "(inlined) " : "");
    if (s && s->body) {
      fputs("= ", out);
      print_node(out, s->body);
    }
    fputc('\n', out);
  }
}
