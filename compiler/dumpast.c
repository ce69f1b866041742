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
