/* jit.c — libtcc in memory, or cc + dlopen. */
#include "jit.h"

#include <dlfcn.h>
#include <errno.h>
#include <libtcc.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#ifndef NPG_TCC_LIB_DIR
#define NPG_TCC_LIB_DIR "/usr/lib/x86_64-linux-gnu/tcc"
#endif

struct JitModule {
  TCCState *tcc;
  void *dl;
  char dir[256];   /* cc: the temporary directory of the shared object */
};

typedef struct TccErr {
  char *buf;
  size_t len;
} TccErr;

static void tcc_error(void *opaque, const char *msg) {
  TccErr *e = opaque;
  if (e->buf[0]) return; /* keep the first */
  snprintf(e->buf, e->len, "libtcc: %s", msg);
}

/* The libm functions npg_abi.h declares, resolved from this process. */
static const struct { const char *name; const void *fn; } math_symbols[] = {
    {"sqrt", (const void *)sqrt}, {"cbrt", (const void *)cbrt},   {"pow", (const void *)pow},
    {"exp", (const void *)exp},   {"log", (const void *)log},     {"sin", (const void *)sin},
    {"cos", (const void *)cos},   {"tan", (const void *)tan},     {"atan", (const void *)atan},
    {"atan2", (const void *)atan2}, {"tanh", (const void *)tanh}, {"fabs", (const void *)fabs},
    {"floor", (const void *)floor}, {"fmin", (const void *)fmin}, {"fmax", (const void *)fmax},
};

static JitModule *compile_tcc(const char *source, char *err, size_t errlen) {
  JitModule *m = calloc(1, sizeof *m);
  if (!m) {
    snprintf(err, errlen, "out of memory");
    return NULL;
  }
  TccErr te = {err, errlen};
  err[0] = 0;
  m->tcc = tcc_new();
  if (!m->tcc) {
    snprintf(err, errlen, "libtcc: cannot create a compilation state");
    free(m);
    return NULL;
  }
  tcc_set_error_func(m->tcc, &te, tcc_error);
  tcc_set_lib_path(m->tcc, NPG_TCC_LIB_DIR);
  tcc_set_options(m->tcc, "-nostdinc");
  tcc_set_output_type(m->tcc, TCC_OUTPUT_MEMORY);
  for (size_t i = 0; i < sizeof math_symbols / sizeof *math_symbols; i++)
    tcc_add_symbol(m->tcc, math_symbols[i].name, math_symbols[i].fn);
  if (tcc_compile_string(m->tcc, source) < 0 || tcc_relocate(m->tcc, TCC_RELOCATE_AUTO) < 0) {
    if (!err[0]) snprintf(err, errlen, "libtcc: compilation failed");
    tcc_delete(m->tcc);
    free(m);
    return NULL;
  }
  tcc_set_error_func(m->tcc, NULL, NULL);
  return m;
}

static int run(char *const argv[], char *err, size_t errlen, const char *log) {
  pid_t pid = fork();
  if (pid < 0) {
    snprintf(err, errlen, "cannot start %s: %s", argv[0], strerror(errno));
    return -1;
  }
  if (pid == 0) {
    FILE *f = freopen(log, "w", stderr);
    (void)f;
    execvp(argv[0], argv);
    _exit(127);
  }
  int status;
  while (waitpid(pid, &status, 0) < 0)
    if (errno != EINTR) {
      snprintf(err, errlen, "waiting for %s: %s", argv[0], strerror(errno));
      return -1;
    }
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return 0;
  char msg[512] = "";
  FILE *f = fopen(log, "r");
  if (f) {
    size_t n = fread(msg, 1, sizeof msg - 1, f);
    msg[n] = 0;
    fclose(f);
  }
  if (WIFEXITED(status) && WEXITSTATUS(status) == 127)
    snprintf(err, errlen, "cannot run the C compiler '%s' (set CC, or use the default libtcc backend)", argv[0]);
  else
    snprintf(err, errlen, "%s failed on generated code (a bug in npg): %s", argv[0], msg);
  return -1;
}

static void remove_dir(JitModule *m) {
  if (!m->dir[0]) return;
  char path[512];
  const char *files[] = {"gen.c", "gen.so", "cc.log"};
  for (size_t i = 0; i < 3; i++) {
    snprintf(path, sizeof path, "%s/%s", m->dir, files[i]);
    unlink(path);
  }
  rmdir(m->dir);
  m->dir[0] = 0;
}

static JitModule *compile_cc(const char *source, char *err, size_t errlen) {
  JitModule *m = calloc(1, sizeof *m);
  if (!m) {
    snprintf(err, errlen, "out of memory");
    return NULL;
  }
  const char *tmp = getenv("TMPDIR");
  tmp = tmp && *tmp ? tmp : "/tmp";
  /* the folder's name, then its files' (the longest "/cc.log" and "gen.so"
   * paths are built in 512 bytes below) must fit without being cut */
  if (strlen(tmp) + sizeof "/npg-cc-XXXXXX" > sizeof m->dir) {
    snprintf(err, errlen, "cannot create a temporary directory in TMPDIR (%.60s...): its path is %zu bytes long, "
             "more than the cc backend's %zu", tmp, strlen(tmp), sizeof m->dir - sizeof "/npg-cc-XXXXXX");
    free(m);
    return NULL;
  }
  snprintf(m->dir, sizeof m->dir, "%s/npg-cc-XXXXXX", tmp);
  if (!mkdtemp(m->dir)) {
    snprintf(err, errlen, "cannot create a temporary directory in %s (TMPDIR): %s", tmp, strerror(errno));
    m->dir[0] = 0;
    free(m);
    return NULL;
  }
  char src[512], so[512], log[512];
  snprintf(src, sizeof src, "%s/gen.c", m->dir);
  snprintf(so, sizeof so, "%s/gen.so", m->dir);
  snprintf(log, sizeof log, "%s/cc.log", m->dir);
  FILE *f = fopen(src, "w");
  if (!f || fputs(source, f) < 0 || fclose(f) != 0) {
    snprintf(err, errlen, "cannot write %s: %s", src, strerror(errno));
    remove_dir(m);
    free(m);
    return NULL;
  }
  const char *cc = getenv("CC");
  char *argv[] = {(char *)(cc && *cc ? cc : "cc"), "-O3", "-march=native", "-ffp-contract=off", "-fno-trapping-math", "-fno-math-errno", "-fPIC", "-shared", "-o", so, src, "-lm", NULL};
  if (run(argv, err, errlen, log) != 0) {
    remove_dir(m);
    free(m);
    return NULL;
  }
  m->dl = dlopen(so, RTLD_NOW | RTLD_LOCAL);
  if (!m->dl) {
    snprintf(err, errlen, "cannot load %s: %s", so, dlerror());
    remove_dir(m);
    free(m);
    return NULL;
  }
  remove_dir(m); /* the mapping stays valid */
  return m;
}

JitModule *jit_compile(const char *source, bool use_cc, char *err, size_t errlen) {
  return use_cc ? compile_cc(source, err, errlen) : compile_tcc(source, err, errlen);
}

void *jit_symbol(JitModule *m, const char *name) {
  if (!m) return NULL;
  return m->tcc ? tcc_get_symbol(m->tcc, name) : dlsym(m->dl, name);
}

void jit_free(JitModule *m) {
  if (!m) return;
  if (m->tcc) tcc_delete(m->tcc);
  if (m->dl) dlclose(m->dl);
  free(m);
}
