/* jit.c — libtcc in memory, or cc + dlopen through the cache of jit_cache.h. */
#include "jit.h"
#include "jit_cache.h"

#include <dlfcn.h>
#include <limits.h>
#include <errno.h>
#include <libtcc.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#ifndef NPG_TCC_LIB_DIR
#define NPG_TCC_LIB_DIR "/usr/lib/x86_64-linux-gnu/tcc"
#endif

struct JitModule {
  TCCState *tcc;
  void *dl;
  char dir[256];   /* cc: the temporary directory of the shared object */
  JitBackend backend;
  double seconds;  /* JitInfo.seconds */
  int cache;       /* JitInfo.cache */
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
  m->backend = JIT_TCC;
  m->cache = -1;
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
    snprintf(err, errlen, "cannot run the C compiler '%s' (set CC, or choose libtcc: --jit tcc)", argv[0]);
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

/* The compiler cc runs: $CC, else "cc". */
static const char *cc_name(void) {
  const char *cc = getenv("CC");
  return cc && *cc ? cc : "cc";
}

/* `name` resolved on PATH into `path` (as given when it holds a '/'): 0 or -1. */
static int find_on_path(const char *name, char *path, size_t n) {
  if (strchr(name, '/')) {
    snprintf(path, n, "%s", name);
    return access(path, X_OK) == 0 ? 0 : -1;
  }
  const char *p = getenv("PATH");
  if (!p || !*p) p = "/usr/local/bin:/usr/bin:/bin";
  while (*p) {
    const char *e = strchr(p, ':');
    size_t len = e ? (size_t)(e - p) : strlen(p);
    if (len && (size_t)snprintf(path, n, "%.*s/%s", (int)len, p, name) < n) {
      struct stat st;
      if (stat(path, &st) == 0 && S_ISREG(st.st_mode) && access(path, X_OK) == 0) return 0;
    }
    p += len + (e != NULL);
  }
  return -1;
}

/* `path --version`'s output after "path\n" into `out`: 0 or -1. */
static int version_text(const char *path, char *out, size_t n) {
  int fd[2];
  if (pipe(fd) != 0) return -1;
  pid_t pid = fork();
  if (pid == 0) {
    dup2(fd[1], 1);
    close(fd[0]);
    close(fd[1]);
    execl(path, path, "--version", (char *)NULL);
    _exit(127);
  }
  close(fd[1]);
  size_t got = (size_t)snprintf(out, n, "%s\n", path);
  ssize_t r;
  while (got < n - 1 && ((r = read(fd[0], out + got, n - 1 - got)) > 0 || (r < 0 && errno == EINTR)))
    if (r > 0) got += (size_t)r;
  out[got] = 0;
  char sink[256];
  while ((r = read(fd[0], sink, sizeof sink)) > 0 || (r < 0 && errno == EINTR)) ; /* the rest, unread, would block the child */
  close(fd[0]);
  int status = 0;
  if (pid > 0)
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) ;
  return pid > 0 && WIFEXITED(status) && WEXITSTATUS(status) == 0 ? 0 : -1;
}

/* The compiler's identity for the cache key: its resolved path and what
 * `CC --version` prints. Running it costs 2-3 ms (measured from a Python
 * process), more than loading a cached evaluator, so it is computed once a
 * process per value of CC, and kept in the cache folder as cc-HASH.id, HASH
 * naming the compiler's file (real path, device, inode, size, mtime): a
 * compiler upgraded or switched is another file, another identity. A damaged
 * .id file can only change the key (a miss), never load a wrong object. */
static pthread_mutex_t identity_lock = PTHREAD_MUTEX_INITIALIZER;
static char identity_cc[256], identity[2048];

static int cc_identity(const char *cache_dir, char *out, size_t n, char *err, size_t errlen) {
  const char *cc = cc_name();
  pthread_mutex_lock(&identity_lock);
  if (!identity[0] || strcmp(identity_cc, cc) != 0) {
    char path[1024], real[PATH_MAX], memo[1400] = "";
    identity[0] = 0;
    if (find_on_path(cc, path, sizeof path) != 0) {
      pthread_mutex_unlock(&identity_lock);
      snprintf(err, errlen, "cannot run the C compiler '%s': not found on PATH (set CC, or choose libtcc: --jit tcc)", cc);
      return -1;
    }
    struct stat st;
    if (cache_dir[0] && realpath(path, real) && stat(real, &st) == 0) {
      char id[PATH_MAX + 200], hex[65];
      int len = snprintf(id, sizeof id, "%s %s %llu %llu %lld %lld.%09ld", path, real, (unsigned long long)st.st_dev,
                         (unsigned long long)st.st_ino, (long long)st.st_size, (long long)st.st_mtim.tv_sec,
                         st.st_mtim.tv_nsec);
      jit_cache_sha256_hex(id, (size_t)len, hex);
      snprintf(memo, sizeof memo, "%s/cc-%.32s.id", cache_dir, hex);
      FILE *f = fopen(memo, "rb");
      if (f) {
        size_t got = fread(identity, 1, sizeof identity - 1, f);
        identity[got] = 0;
        fclose(f);
        if (got == 0 || strncmp(identity, path, strlen(path)) != 0 || identity[strlen(path)] != '\n') identity[0] = 0;
      }
    }
    if (!identity[0]) {
      if (version_text(path, identity, sizeof identity) != 0) {
        identity[0] = 0;
        pthread_mutex_unlock(&identity_lock);
        snprintf(err, errlen, "cannot run the C compiler '%s --version' (set CC, or choose libtcc: --jit tcc)", path);
        return -1;
      }
      if (memo[0]) { /* a temporary name, renamed: another process reads it whole or not at all */
        char tmp[1500];
        snprintf(tmp, sizeof tmp, "%s.tmp.%ld", memo, (long)getpid());
        FILE *f = fopen(tmp, "wb");
        bool ok = f && fputs(identity, f) >= 0;
        if (f && fclose(f) != 0) ok = false;
        if (!ok || rename(tmp, memo) != 0) unlink(tmp);
      }
    }
    snprintf(identity_cc, sizeof identity_cc, "%s", cc);
  }
  snprintf(out, n, "%s", identity);
  pthread_mutex_unlock(&identity_lock);
  return 0;
}

/* The processor -march=native compiles for: its model and feature flags (the
 * first processor's lines of /proc/cpuinfo), once a process, never from the
 * disk: a cache folder in a home shared by machines must not hand one
 * machine's AVX-512 code to another. "" where /proc is absent. */
static pthread_once_t cpu_once = PTHREAD_ONCE_INIT;
static char cpu_identity[4096];

static void read_cpu_identity(void) {
  FILE *f = fopen("/proc/cpuinfo", "r");
  char line[8192];
  size_t n = 0;
  while (f && fgets(line, sizeof line, f)) {
    bool keep = strncmp(line, "vendor_id", 9) == 0 || strncmp(line, "model", 5) == 0 ||
                strncmp(line, "cpu family", 10) == 0 || strncmp(line, "flags", 5) == 0 ||
                strncmp(line, "Features", 8) == 0 || strncmp(line, "CPU ", 4) == 0;
    if (keep && n + strlen(line) < sizeof cpu_identity) {
      memcpy(cpu_identity + n, line, strlen(line) + 1);
      n += strlen(line);
    }
    if (line[0] == '\n' && n) break; /* the first processor's block ends */
  }
  if (f) fclose(f);
}

static double now_seconds(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

#define CC_FLAGS "-O3", "-march=native", "-ffp-contract=off", "-fno-trapping-math", "-fno-math-errno", "-fPIC", "-shared"

static JitModule *cc_fail(JitModule *m) {
  remove_dir(m);
  free(m);
  return NULL;
}

static JitModule *compile_cc(const char *source, char *err, size_t errlen) {
  JitModule *m = calloc(1, sizeof *m);
  if (!m) {
    snprintf(err, errlen, "out of memory");
    return NULL;
  }
  m->backend = JIT_CC;
  m->cache = -1;
  JitCache cache;
  char ident[2048 + sizeof cpu_identity], key[65] = "";
  if (jit_cache_open(&cache, err, errlen) != 0 || cc_identity(cache.dir, ident, sizeof ident, err, errlen) != 0) {
    free(m);
    return NULL;
  }
  if (cache.dir[0]) {
    static const char *const flags[] = {CC_FLAGS, "-lm"};
    char fl[256] = "";
    for (size_t i = 0; i < sizeof flags / sizeof *flags; i++) strcat(strcat(fl, flags[i]), " ");
    pthread_once(&cpu_once, read_cpu_identity); /* -march=native: the flags mean this processor */
    size_t len = strlen(ident);
    snprintf(ident + len, sizeof ident - len, "%s", cpu_identity);
    jit_cache_key(source, ident, fl, key);
    bool damaged;
    if ((m->dl = jit_cache_load(&cache, key, &damaged))) {
      m->cache = 1;
      return m;
    }
    m->cache = damaged ? 2 : 0;
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
  char src[512], so[1400], log[512];
  snprintf(src, sizeof src, "%s/gen.c", m->dir);
  snprintf(log, sizeof log, "%s/cc.log", m->dir);
  /* a new entry is built under a temporary name in the cache folder, so the
   * rename that publishes it is atomic */
  static unsigned counter;
  if (key[0])
    snprintf(so, sizeof so, "%s/%s.so.tmp.%ld.%u", cache.dir, key, (long)getpid(), __atomic_fetch_add(&counter, 1, __ATOMIC_RELAXED));
  else
    snprintf(so, sizeof so, "%s/gen.so", m->dir);
  FILE *f = fopen(src, "w");
  if (!f || fputs(source, f) < 0 || fclose(f) != 0) {
    snprintf(err, errlen, "cannot write %s: %s", src, strerror(errno));
    return cc_fail(m);
  }
  char *argv[] = {(char *)cc_name(), CC_FLAGS, "-o", so, src, "-lm", NULL};
  if (run(argv, err, errlen, log) != 0) {
    if (key[0]) unlink(so);
    return cc_fail(m);
  }
  if (key[0] && jit_cache_seal(so, key, err, errlen) != 0) {
    unlink(so);
    return cc_fail(m);
  }
  m->dl = dlopen(so, RTLD_NOW | RTLD_LOCAL);
  if (!m->dl) {
    snprintf(err, errlen, "cannot load %s: %s", so, dlerror());
    if (key[0]) unlink(so);
    return cc_fail(m);
  }
  if (key[0] && jit_cache_store(&cache, so, key, err, errlen) != 0) {
    err[0] = 0; /* not published (another user's file in the way): loaded all the same, not cached */
    m->cache = -1;
  }
  remove_dir(m); /* the mapping stays valid */
  return m;
}

int jit_resolve(JitBackend b, JitBackend *out, char *err, size_t errlen) {
  if (b == JIT_AUTO) {
    const char *env = getenv("NPG_JIT");
    if (env && *env && strcmp(env, "auto") != 0) {
      if (strcmp(env, "cc") == 0) b = JIT_CC;
      else if (strcmp(env, "tcc") == 0) b = JIT_TCC;
      else {
        snprintf(err, errlen, "NPG_JIT='%.60s' is not a backend (expected auto, cc or tcc)", env);
        return -1;
      }
    }
  }
  if (b == JIT_AUTO) {
    char path[1024];
    b = find_on_path(cc_name(), path, sizeof path) == 0 ? JIT_CC : JIT_TCC;
  }
  *out = b;
  return 0;
}

JitModule *jit_compile(const char *source, JitBackend backend, char *err, size_t errlen) {
  if (jit_resolve(backend, &backend, err, errlen) != 0) return NULL;
  double t0 = now_seconds();
  JitModule *m = backend == JIT_CC ? compile_cc(source, err, errlen) : compile_tcc(source, err, errlen);
  if (m) m->seconds = now_seconds() - t0;
  return m;
}

JitInfo jit_info(const JitModule *m) {
  JitInfo i = {m ? m->backend : JIT_TCC, m ? m->seconds : 0, m ? m->cache : -1};
  return i;
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
