/* npg.c — npg_compile(): the pipeline, one line per stage (STYLE: the
 * table of contents of the compiler). */
#define _GNU_SOURCE /* dladdr */
#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <stdio.h>

#include "api.h"
#include "compile.h"
#include "full.h"
#include "npg.h"
#include "reduced.h"
#include "train.h"

#ifndef NPG_STDLIB_DIR
#define NPG_STDLIB_DIR "stdlib"
#endif
/* Where an installed libnpg.so and npgc find the stdlib, relative to their
 * own directories (CMakeLists.txt: <datadir>/npg/stdlib). */
#ifndef NPG_LIB_TO_STDLIB
#define NPG_LIB_TO_STDLIB "../share/npg/stdlib"
#endif
#ifndef NPG_BIN_TO_STDLIB
#define NPG_BIN_TO_STDLIB "../share/npg/stdlib"
#endif

struct NpgProgram {
  Ctx ctx;
  Program *prog;
  const char *error;
  bool is_static;   /* the out-of-memory result, not allocated */
};

/* `rel` next to the file `path` (a library or executable), when that is a
 * directory; NULL otherwise. */
static const char *dir_beside(Ctx *ctx, const char *path, const char *rel) {
  const char *slash = strrchr(path, '/');
  if (!slash) return NULL;
  char *dir = arena_printf(ctx, "%.*s/%s", (int)(slash - path), path, rel);
  struct stat st;
  return stat(dir, &st) == 0 && S_ISDIR(st.st_mode) ? dir : NULL;
}

/* The stdlib when NpgOptions.std_dir is NULL: the one installed beside the
 * shared library holding this code (<prefix>/lib/libnpg.so), else beside the
 * executable (<prefix>/bin/npgc, or a program linking libnpg.a), else the
 * source tree's (the build tree: nothing is installed beside build/npgc). */
static const char *default_std_dir(Ctx *ctx) {
  const char *dir = NULL;
  char exe[PATH_MAX], lib[PATH_MAX];
  ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
  exe[n > 0 ? n : 0] = '\0';
  Dl_info info;
  if (dladdr((void *)npg_compile, &info) && info.dli_fname && realpath(info.dli_fname, lib) && strcmp(lib, exe) != 0)
    dir = dir_beside(ctx, lib, NPG_LIB_TO_STDLIB);
  if (!dir && exe[0]) dir = dir_beside(ctx, exe, NPG_BIN_TO_STDLIB);
  return dir ? dir : NPG_STDLIB_DIR;
}

static bool wants(const NpgOptions *opt, char letter) { return opt->dump && strchr(opt->dump, letter); }

/* A program is kilobytes; the cap stops a wrong path (/dev/zero, a data
 * file) from reading until memory runs out. */
#define SOURCE_MAX ((size_t)64 << 20)

/* The program `path`, read whole: a directory, an unreadable file and one
 * over SOURCE_MAX are user errors naming `path`. Files of unknown size
 * (devices, pipes) are read in pieces up to the cap. */
static const SrcFile *read_program(Ctx *ctx, const char *path) {
  FILE *fp = fopen(path, "rb");
  if (!fp) error_plain(ctx, "cannot read '%s': %s", path, strerror(errno));
  ctx->open_file = fp; /* closed by guarded_compile if an error jumps out */
  struct stat st;
  if (fstat(fileno(fp), &st) == 0 && S_ISDIR(st.st_mode))
    error_plain(ctx, "cannot read '%s': it is a directory, not a program", path);
  size_t cap = 4096, len = 0;
  char *buf = malloc(cap);
  if (!buf) error_plain(ctx, "out of memory reading '%s'", path);
  ctx->pending_free = buf; /* freed by guarded_compile if an error jumps out */
  for (;;) {
    if (len == cap) {
      if (cap >= SOURCE_MAX) error_plain(ctx, "'%s' is larger than %zu MB: not a program", path, SOURCE_MAX >> 20);
      char *grown = realloc(buf, cap * 2);
      if (!grown) error_plain(ctx, "out of memory reading '%s' (%zu bytes so far)", path, len);
      ctx->pending_free = buf = grown;
      cap *= 2;
    }
    size_t got = fread(buf + len, 1, cap - len, fp);
    len += got;
    if (got == 0) break;
  }
  if (ferror(fp)) error_plain(ctx, "cannot read '%s': %s", path, strerror(errno ? errno : EIO));
  ctx->open_file = NULL;
  fclose(fp);
  const SrcFile *file = source_from_string(ctx, path, buf, len);
  ctx->pending_free = NULL;
  free(buf);
  return file;
}

/* The pipeline proper; user errors longjmp out of it to npg_compile(). */
static void compile(NpgProgram *np, const char *path, const NpgOptions *opt) {
  Ctx *ctx = &np->ctx;
  FILE *dump = opt->dump_out ? opt->dump_out : stderr;
  const SrcFile *file;
  if (!ctx->std_dir) ctx->std_dir = default_std_dir(ctx);
  if (opt->source) {
    file = source_from_string(ctx, path, opt->source, strlen(opt->source));
  } else {
    file = read_program(ctx, path);
  }
  Decl *decls = parse_program(ctx, file);
  if (wants(opt, 'p')) dump_decls(dump, decls);
  Program *prog = sema_program(ctx, file, decls);
  if (wants(opt, 's')) dump_checked(dump, prog);
  lower_program(ctx, prog);
  verify_program(ctx, prog);
  if (wants(opt, 'l')) dump_stages(dump, prog);
  basis_classes(ctx, prog);
  verify_program(ctx, prog);
  if (wants(opt, 'b')) dump_classes(dump, prog);
  np->prog = prog;
  np->error = "";
}

/* Run the pipeline with ctx->on_error armed; false on a user error. */
static bool guarded_compile(NpgProgram *np, const char *path, const NpgOptions *opt) {
  jmp_buf env;
  np->ctx.on_error = &env;
  bool ok = setjmp(env) == 0;
  if (ok) compile(np, path, opt);
  np->ctx.on_error = NULL;
  if (np->ctx.open_file) {
    fclose(np->ctx.open_file);
    np->ctx.open_file = NULL;
  }
  free(np->ctx.pending_free);
  np->ctx.pending_free = NULL;
  return ok;
}

NpgProgram *npg_compile(const char *path, const NpgOptions *options) {
  static const NpgOptions defaults = {0};
  const NpgOptions *opt = options ? options : &defaults;
  NpgProgram *np = calloc(1, sizeof *np);
  if (!np) {
    static NpgProgram oom = {.error = "error: out of memory\n", .is_static = true};
    return &oom;
  }
  np->ctx.std_dir = opt->std_dir;
  if (!path) {
    api_refuse(NULL, 0, __func__, "argument 'path' is NULL");
    np->error = "error: npg_compile: argument 'path' is NULL\n";
    return np;
  }
  if (!guarded_compile(np, path, opt)) {
    np->error = np->ctx.msg ? np->ctx.msg : "error: compilation failed\n";
    np->prog = NULL;
  }
  return np;
}

bool npg_ok(const NpgProgram *p) { return p && p->prog != NULL; }

const char *npg_error(const NpgProgram *p) { return p ? p->error : "error: no program\n"; }

/* Printing allocates (cost formulas) in the program's arena, so the error
 * handler is armed here too: an allocation failure ends the report with a
 * message instead of a jump to nowhere. */
static bool guarded_report(NpgProgram *np, FILE *out, bool json) {
  jmp_buf env;
  np->ctx.on_error = &env;
  bool ok = setjmp(env) == 0;
  if (ok) {
    if (json) dump_json(out, np->prog);
    else dump_program(out, np->prog);
  }
  np->ctx.on_error = NULL;
  free(np->ctx.pending_free);
  np->ctx.pending_free = NULL;
  return ok;
}

void npg_report(const NpgProgram *p, FILE *out, bool json) {
  API_REFUSE_NULL(p, NULL, 0, );
  API_REFUSE_NULL(out, NULL, 0, );
  if (!npg_ok(p)) return;
  if (!guarded_report((NpgProgram *)p, out, json)) fprintf(out, "\n%s", p->ctx.msg ? p->ctx.msg : "error: out of memory\n");
}

int npg_emit_full(NpgProgram *p, FILE *out) {
  API_REFUSE_NULL(p, NULL, 0, -1);
  if (!npg_ok(p)) return -1;
  if (!out) {
    api_refuse(NULL, 0, __func__, "argument 'out' is NULL");
    p->error = "error: npg_emit_full: argument 'out' is NULL\n";
    return -1;
  }
  if (full_emit(p->prog, out) != 0) {
    p->error = p->ctx.msg ? p->ctx.msg : "error: code generation failed\n";
    return -1;
  }
  return 0;
}

int npg_emit_derivatives(NpgProgram *p, FILE *out) {
  API_REFUSE_NULL(p, NULL, 0, -1);
  if (!npg_ok(p)) return -1;
  if (!out) {
    api_refuse(NULL, 0, __func__, "argument 'out' is NULL");
    p->error = "error: npg_emit_derivatives: argument 'out' is NULL\n";
    return -1;
  }
  if (full_deriv_emit(p->prog, out) != 0) {
    p->error = p->ctx.msg ? p->ctx.msg : "error: code generation failed\n";
    return -1;
  }
  return 0;
}

void npg_free(NpgProgram *p) {
  if (!p || p->is_static) return;
  arena_release(&p->ctx.arena);
  free(p);
}

bool npg_same_program(const NpgProgram *a, const NpgProgram *b) {
  if (!a || !b || !a->prog || !b->prog) return false;
  if (a == b) return true;
  const PtrVec *fa = &a->prog->ctx->files, *fb = &b->prog->ctx->files;
  if (fa->n != fb->n) return false;
  for (int i = 0; i < fa->n; i++) { /* the texts, as a model's program hash reads them */
    const SrcFile *x = fa->v[i], *y = fb->v[i];
    if (x->len != y->len || memcmp(x->text, y->text, x->len) != 0) return false;
  }
  return true;
}

Program *program_ir(const NpgProgram *p) { return p ? p->prog : NULL; }

int npg_nsymbols(const NpgProgram *np) {
  API_REFUSE_NULL(np, NULL, 0, 0);
  const Program *prog = np->prog;
  return prog ? prog->params.n + prog->quantities.n + prog->ops.n : 0;
}

int npg_symbol(const NpgProgram *np, int i, NpgSymbol *out) {
  API_REFUSE_NULL(np, NULL, 0, -1);
  API_REFUSE_NULL(out, NULL, 0, -1);
  const Program *prog = np->prog;
  if (!prog || i < 0 || i >= npg_nsymbols(np)) return -1;
  const Sym *s = i < prog->params.n ? prog->params.v[i]
                 : i < prog->params.n + prog->quantities.n ? prog->quantities.v[i - prog->params.n]
                                                             : prog->ops.v[i - prog->params.n - prog->quantities.n];
  memset(out, 0, sizeof *out);
  out->name = s->name;
  out->kind = s->kind == SYM_PARAM ? NPG_PARAM : s->kind == SYM_INPUT ? NPG_INPUT : s->kind == SYM_EXTERN ? NPG_EXTERN
              : s->kind == SYM_OP ? NPG_OP : NPG_STAGE;
  out->output = s->is_output;
  out->next = s->next ? s->next->name : NULL;
  out->state_of = s->state_of ? s->state_of->name : NULL;
  if (s->kind == SYM_OP) {
    out->ndims = s->nivars;
    out->nrow = s->nrow;
    for (int k = 0; k < s->nivars && k < 8; k++) out->dims[k] = s->ivars[k]->range->name;
  } else {
    out->ndims = s->ndims;
    for (int k = 0; k < s->ndims && k < 8; k++) out->dims[k] = s->dims[k]->name;
  }
  out->nstatic = s->nstatic;
  for (int k = 0; k < s->nstatic && k < 4; k++) out->shape[k] = s->shape[k];
  return 0;
}

void npg_progress(bool on, const char *what, long done, long total) {
  API_REFUSE_NULL(what, NULL, 0, );
  progress_show(on, what, done, total);
}
