/* testutil.h — compiling programs in tests. */
#ifndef NPG_TESTUTIL_H
#define NPG_TESTUTIL_H

#include <math.h>
#include <dirent.h>
#include <errno.h>
#include <sys/stat.h>
#include <unistd.h>
#include <setjmp.h>
#include <stdio.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "compile.h"
#include "exact.h"
#include "npg.h"
#include "support/corpus.h" /* for_each_program, check_programs, bind_random */

/* Compile source text named `name`; the stdlib is the repository's. */
static inline NpgProgram *compile_text(const char *name, const char *text) {
  NpgOptions opt = {0};
  opt.source = text;
  opt.std_dir = "stdlib";
  return npg_compile(name, &opt);
}

static inline NpgProgram *compile_file(const char *path) {
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  return npg_compile(path, &opt);
}

static inline Program *ir_ok(NpgProgram *p) {
  if (!npg_ok(p)) fail_msg("compilation failed:\n%s", npg_error(p));
  return program_ir(p);
}

static inline const Stage *find_stage(const Program *prog, const char *name) {
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (strcmp(st->sym->name, name) == 0) return st;
  }
  fail_msg("no stage '%s'", name);
  return NULL;
}

static inline const Sym *find_quantity(const Program *prog, const char *name) {
  for (int i = 0; i < prog->quantities.n; i++) {
    const Sym *s = prog->quantities.v[i];
    if (strcmp(s->name, name) == 0) return s;
  }
  fail_msg("no quantity '%s'", name);
  return NULL;
}

/* The class of `name` as a sorted, comma separated list of members. */
static inline char *class_of(const Program *prog, const char *name, char *buf, size_t n) {
  const Sym *s = find_quantity(prog, name);
  const BasisClass *c = prog->classes.v[s->klass];
  const char *names[64];
  int k = 0;
  for (int i = 0; i < c->members.n && k < 64; i++) names[k++] = ((Sym *)c->members.v[i])->name;
  for (int i = 0; i < k; i++)
    for (int j = i + 1; j < k; j++)
      if (strcmp(names[j], names[i]) < 0) {
        const char *t = names[i];
        names[i] = names[j];
        names[j] = t;
      }
  buf[0] = 0;
  for (int i = 0; i < k; i++) {
    strncat(buf, names[i], n - strlen(buf) - 1);
    if (i + 1 < k) strncat(buf, ",", n - strlen(buf) - 1);
  }
  return buf;
}

/* Largest tensor order among all tensors of a stage (numerators, diagonal
 * operators and declared operators' entries). */
static inline int max_order(const Program *prog, const Stage *st) {
  int m = 0;
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    for (int g = 0; g < tm->num_tensors.n; g++)
      if (tm->num_tensors.g[g].order > m) m = tm->num_tensors.g[g].order;
    for (int k = 0; k < tm->nops; k++) {
      const TensorList *tl = &tm->op_tensors[k];
      if (tm->ops[k].kind == OPK_DECL) tl = &tm->ops[k].op->opdef->tensors;
      for (int g = 0; g < tl->n; g++)
        if (tl->g[g].order > m) m = tl->g[g].order;
    }
  }
  return m;
}

/* Relative max-norm difference of b from a; NaN where exactly one side is
 * NaN (exact.h's, the measure npgc verify --exact reports). */
static inline double rel_diff(const double *a, const double *b, size_t n) { return exact_rel_max_diff(a, b, n); }

/* ---------------------------------------------------------------- scratch files
 * A test program's scratch directory (made by its group setup, removed by
 * its teardown) and whole-file helpers. */

__attribute__((unused)) static char scratch[256];

/* scratch <- a new directory "$TMPDIR/<name>.XXXXXX"; 0 or -1. */
static inline int scratch_make(const char *name) {
  const char *tmpdir = getenv("TMPDIR");
  snprintf(scratch, sizeof scratch, "%s/%s.XXXXXX", tmpdir && *tmpdir ? tmpdir : "/tmp", name);
  return mkdtemp(scratch) ? 0 : -1;
}

/* Remove `path` and everything under it (scratch only; no symlinks are
 * followed since lstat sees them as files). */
static inline void remove_tree(const char *path) {
  struct stat st;
  if (lstat(path, &st) != 0) return;
  if (S_ISDIR(st.st_mode)) {
    chmod(path, 0700);
    DIR *d = opendir(path);
    struct dirent *e;
    while (d && (e = readdir(d))) {
      if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
      size_t len = strlen(path) + strlen(e->d_name) + 2;
      char *sub = malloc(len);
      if (!sub) break;
      snprintf(sub, len, "%s/%s", path, e->d_name);
      remove_tree(sub);
      free(sub);
    }
    if (d) closedir(d);
    rmdir(path);
  } else {
    unlink(path);
  }
}

/* "<scratch>/<name>" in `out` (512 bytes). */
static inline char *scratch_path(char *out, const char *name) {
  snprintf(out, 512, "%s/%s", scratch, name);
  return out;
}

static inline void write_file(const char *path, const void *bytes, size_t n) {
  FILE *f = fopen(path, "wb");
  if (!f) fail_msg("cannot create %s: %s", path, strerror(errno));
  if (fwrite(bytes, 1, n, f) != n || fclose(f) != 0) fail_msg("cannot write %s", path);
}

/* The whole of `path`, malloc'd and NUL-terminated, its size in `*n`. */
static inline char *slurp(const char *path, size_t *n) {
  FILE *f = fopen(path, "rb");
  if (!f) fail_msg("cannot open %s: %s", path, strerror(errno));
  char *buf = NULL;
  size_t cap = 0;
  *n = 0;
  for (;;) {
    buf = realloc(buf, (cap = 2 * cap + 4096) + 1);
    size_t k = fread(buf + *n, 1, cap - *n, f);
    *n += k;
    if (k == 0) break;
  }
  fclose(f);
  buf[*n] = '\0';
  return buf;
}

#endif
