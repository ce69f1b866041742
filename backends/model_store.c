/* model_store.c — MODEL/ directories: a text manifest and one .npy per array
 * (see model_store.h for the manifest's format).
 *
 * Writing never exposes a half model: everything goes to "<dir>.tmp.<pid>",
 * is synced, and only then swapped with `dir` by two renames. Removing the
 * replaced model deletes only files a model store writes, each checked by
 * name before anything is touched, so a mistyped -o never costs the user a
 * directory of their own.
 *
 * Reading trusts nothing: every manifest line is parsed strictly, and every
 * array file is hashed against its checksum before npy_read sees it, so a
 * corrupted, truncated, missing or swapped file is named rather than loaded.
 */
#define _GNU_SOURCE /* renameat2 (RENAME_EXCHANGE), fsync, O_DIRECTORY, lstat, getpid */

#include "model_store.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <limits.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define FORMAT_LINE "npg-model 1"
#define FORMAT_WORD "npg-model"
#define CHECKSUM_KIND "fnv1a64"

/* A manifest is a few lines per array; anything much larger is not one, and
 * the cap bounds what a wrong path makes us allocate. */
#define MANIFEST_MAX ((size_t)16 << 20)

/* Room for a shape as text: NPY_MAX_DIMS numbers of at most 20 digits and
 * their separators. */
enum { SHAPE_TEXT = NPY_MAX_DIMS * 21 + 4 };

/* ---------------------------------------------------------------- errors */

/* Where a message goes (`err` may be NULL or `errlen` 0: no message). */
typedef struct Report {
  char *err;
  size_t errlen;
} Report;

/* "<path>: <problem>", or "<path>:<line>: <problem>" when `line` > 0. */
__attribute__((format(printf, 4, 5))) static int fail(const Report *r, const char *path, int line,
                                                      const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  npy_vfail(r->err, r->errlen, path, line, fmt, ap);
  va_end(ap);
  return -1;
}

/* `s` printable in a message (npy_excerpt). `buf` holds NPY_EXCERPT_SIZE. */
static const char *excerpt(char *buf, const char *s) { return npy_excerpt(buf, s, strlen(s)); }

/* A malloc'd vprintf, or NULL when out of memory. */
static char *str_vprintf(const char *fmt, va_list ap) {
  va_list ap2;
  va_copy(ap2, ap);
  int n = vsnprintf(NULL, 0, fmt, ap);
  char *s = n < 0 ? NULL : malloc((size_t)n + 1);
  if (s) vsnprintf(s, (size_t)n + 1, fmt, ap2);
  va_end(ap2);
  return s;
}

/* A malloc'd printf, or NULL when out of memory. */
__attribute__((format(printf, 1, 2))) static char *str_printf(const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *s = str_vprintf(fmt, ap);
  va_end(ap);
  return s;
}

/* ---------------------------------------------------------------- hashing */

uint64_t model_hash_init(void) { return UINT64_C(0xcbf29ce484222325); /* FNV-1a 64 offset basis */ }

uint64_t model_hash_bytes(uint64_t h, const void *p, size_t n) {
  const unsigned char *b = p;
  for (size_t i = 0; i < n; i++) {
    h ^= b[i];
    h *= UINT64_C(0x100000001b3); /* FNV 64 prime */
  }
  return h;
}

/* The FNV-1a 64 hash of the whole file `path` into `*h`. */
static int hash_file(const Report *r, const char *path, uint64_t *h) {
  FILE *f = fopen(path, "rb");
  if (!f) return fail(r, path, 0, "cannot open: %s", strerror(errno));
  unsigned char buf[1 << 14];
  uint64_t acc = model_hash_init();
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, f)) > 0) acc = model_hash_bytes(acc, buf, n);
  int bad = ferror(f);
  int saved = errno;
  fclose(f);
  if (bad) return fail(r, path, 0, "cannot read: %s", strerror(saved));
  *h = acc;
  return 0;
}

/* ---------------------------------------------------------------- names, lines, shapes */

/* An array name: [A-Za-z0-9_.-]+, not starting with '.', so it is one file
 * name in the model directory, never hidden, never "." or "..". */
static int valid_name(const char *s) {
  if (!s || !*s || *s == '.') return 0;
  for (; *s; s++) {
    char c = *s;
    if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '.' ||
          c == '-'))
      return 0;
  }
  return 1;
}

/* Length of the first word of `line` (up to a space, a tab or the end). */
static size_t key_length(const char *line) { return strcspn(line, " \t"); }

static int key_is(const char *line, const char *key) {
  size_t n = key_length(line);
  return n == strlen(key) && memcmp(line, key, n) == 0;
}

/* A metadata line the manifest can hold and give back verbatim: one line,
 * starting with a key that is not one the manifest itself uses. */
static int valid_meta(const char *line) {
  return line && *line && *line != ' ' && *line != '\t' && !strchr(line, '\n') && !key_is(line, FORMAT_WORD) &&
         !key_is(line, "program") && !key_is(line, "array") && !key_is(line, "manifest");
}

/* `shape` as "3x4" ("5" for one dim, "()" for none) into `buf` (SHAPE_TEXT). */
static const char *format_shape(char *buf, int ndim, const long *shape) {
  if (ndim == 0) return strcpy(buf, "()");
  size_t o = 0;
  for (int i = 0; i < ndim; i++) o += (size_t)snprintf(buf + o, SHAPE_TEXT - o, i ? "x%ld" : "%ld", shape[i]);
  return buf;
}

/* The inverse of format_shape: 0, or -1 if `s` is not a shape. */
static int parse_shape(const char *s, int *ndim, long *shape) {
  if (strcmp(s, "()") == 0) {
    *ndim = 0;
    return 0;
  }
  int n = 0;
  for (;;) {
    if (n == NPY_MAX_DIMS || *s < '0' || *s > '9') return -1;
    long v = 0;
    for (; *s >= '0' && *s <= '9'; s++) {
      if (v > (LONG_MAX - (*s - '0')) / 10) return -1;
      v = v * 10 + (*s - '0');
    }
    shape[n++] = v;
    if (*s == '\0') break;
    if (*s++ != 'x') return -1;
  }
  *ndim = n;
  return 0;
}

/* Exactly 16 hex digits into `*v`; 0, or -1. */
static int parse_hex64(const char *s, uint64_t *v) {
  uint64_t x = 0;
  int i = 0;
  for (; s[i]; i++) {
    char c = s[i];
    int d = c >= '0' && c <= '9'   ? c - '0'
            : c >= 'a' && c <= 'f' ? c - 'a' + 10
            : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                   : -1;
    if (d < 0 || i == 16) return -1;
    x = x << 4 | (uint64_t)d;
  }
  if (i != 16) return -1;
  *v = x;
  return 0;
}

/* The number of elements of `shape` into `*count`: 0, or -1 if an extent
 * is negative or they could not be addressed as doubles. */
static int shape_count(int ndim, const long *shape, size_t *count) {
  size_t c = 1;
  for (int i = 0; i < ndim; i++)
    if (shape[i] < 0) return -1;
  for (int i = 0; i < ndim; i++) c = shape[i] == 0 ? 0 : c;
  for (int i = 0; i < ndim && c; i++) {
    if ((size_t)shape[i] > SIZE_MAX / sizeof(double) / c) return -1;
    c *= (size_t)shape[i];
  }
  *count = c;
  return 0;
}

/* ---------------------------------------------------------------- the store in memory */

void model_store_init(ModelStore *m) { memset(m, 0, sizeof *m); }

void model_store_free(ModelStore *m) {
  if (!m) return;
  for (int i = 0; i < m->nmeta; i++) free(m->meta[i]);
  free(m->meta);
  for (int i = 0; i < m->narrays; i++) {
    free(m->arrays[i].name);
    npy_free(&m->arrays[i].a);
  }
  free(m->arrays);
  model_store_init(m);
}

/* Append the malloc'd line `line` (taken over, freed on failure). */
static int append_meta(ModelStore *m, char *line) {
  char **grown = realloc(m->meta, ((size_t)m->nmeta + 1) * sizeof *grown);
  if (!grown) {
    free(line);
    return -1;
  }
  m->meta = grown;
  m->meta[m->nmeta++] = line;
  return 0;
}

int model_store_meta(ModelStore *m, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *line = str_vprintf(fmt, ap);
  va_end(ap);
  if (!line) return -1;
  if (!valid_meta(line)) {
    free(line);
    return -1;
  }
  return append_meta(m, line);
}

static int find_array(const ModelStore *m, const char *name) {
  for (int i = 0; i < m->narrays; i++)
    if (strcmp(m->arrays[i].name, name) == 0) return i;
  return -1;
}

/* Append `name` with the array `a` (taken over: freed on failure). */
static int append_array(ModelStore *m, const char *name, NpyArray *a, uint64_t checksum) {
  char *copy = strdup(name);
  ModelArray *grown = copy ? realloc(m->arrays, ((size_t)m->narrays + 1) * sizeof *grown) : NULL;
  if (!grown) {
    free(copy);
    npy_free(a);
    return -1;
  }
  m->arrays = grown;
  m->arrays[m->narrays++] = (ModelArray){copy, *a, checksum};
  memset(a, 0, sizeof *a);
  return 0;
}

int model_store_add(ModelStore *m, const char *name, int ndim, const long *shape, const double *data) {
  size_t count;
  if (!valid_name(name) || find_array(m, name) >= 0 || ndim < 0 || ndim > NPY_MAX_DIMS ||
      (ndim > 0 && !shape) || shape_count(ndim, shape, &count) != 0 || (count && !data))
    return -1;
  NpyArray a = {.type = NPY_F64, .ndim = ndim, .count = count};
  for (int i = 0; i < ndim; i++) a.shape[i] = shape[i];
  a.data = malloc(count ? count * sizeof(double) : 1);
  if (!a.data) return -1;
  if (count) memcpy(a.data, data, count * sizeof(double));
  return append_array(m, name, &a, 0);
}

const NpyArray *model_store_array(const ModelStore *m, const char *name) {
  int i = find_array(m, name);
  return i < 0 ? NULL : &m->arrays[i].a;
}

const char *model_store_find(const ModelStore *m, const char *key) {
  for (int i = 0; i < m->nmeta; i++) {
    const char *line = m->meta[i];
    if (!key_is(line, key)) continue;
    const char *rest = line + key_length(line);
    return rest + strspn(rest, " \t");
  }
  return NULL;
}

/* ---------------------------------------------------------------- directories */

/* Names a model store writes into a model directory: the manifest, the
 * arrays, and what an interrupted npy_write leaves ("x.npy.tmp.<pid>"). */
static int is_store_file(const char *name) {
  size_t n = strlen(name);
  if (strcmp(name, "manifest") == 0 || (n > 4 && strcmp(name + n - 4, ".npy") == 0)) return 1;
  const char *tmp = strstr(name, ".npy.tmp.");
  if (!tmp || tmp == name) return 0;
  const char *pid = tmp + strlen(".npy.tmp.");
  return *pid && strspn(pid, "0123456789") == strlen(pid);
}

/* Whether `path`'s first line says it is a model manifest. */
static int is_model_manifest(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f) return 0;
  char head[sizeof FORMAT_WORD] = {0};
  size_t n = fread(head, 1, sizeof head, f);
  fclose(f);
  return n == sizeof head && memcmp(head, FORMAT_WORD " ", sizeof head) == 0;
}

/* Check that the directory `path` holds only regular files a model store
 * writes; `what` ends the refusal ("refusing to replace it"). `*entries`
 * counts them and `*model` says whether one is a model manifest. */
static int scan_store_dir(const Report *r, const char *path, const char *what, int *entries, int *model) {
  DIR *d = opendir(path);
  if (!d) return fail(r, path, 0, "cannot open the directory: %s", strerror(errno));
  int rc = 0;
  *entries = *model = 0;
  struct dirent *e;
  while (rc == 0 && (e = readdir(d))) {
    if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
    char *file = str_printf("%s/%s", path, e->d_name);
    struct stat st;
    char buf[NPY_EXCERPT_SIZE];
    if (!file) rc = fail(r, path, 0, "out of memory");
    else if (lstat(file, &st) != 0) rc = fail(r, file, 0, "cannot examine: %s", strerror(errno));
    else if (!is_store_file(e->d_name) || !S_ISREG(st.st_mode))
      rc = fail(r, path, 0, "holds '%s', which a model store never writes: %s", excerpt(buf, e->d_name), what);
    else if (strcmp(e->d_name, "manifest") == 0) *model = is_model_manifest(file);
    ++*entries;
    free(file);
  }
  closedir(d);
  return rc;
}

/* Remove the directory `path` and the model files in it, after checking
 * that it holds nothing else (it is left untouched if it does). */
static int remove_store_dir(const Report *r, const char *path) {
  int entries, model;
  if (scan_store_dir(r, path, "refusing to remove it", &entries, &model)) return -1;
  DIR *d = opendir(path);
  if (!d) return fail(r, path, 0, "cannot open the directory: %s", strerror(errno));
  int rc = 0;
  struct dirent *e;
  while (rc == 0 && (e = readdir(d))) {
    if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0 || !is_store_file(e->d_name)) continue;
    char *file = str_printf("%s/%s", path, e->d_name);
    if (!file) rc = fail(r, path, 0, "out of memory");
    else if (unlink(file) != 0 && errno != ENOENT) rc = fail(r, file, 0, "cannot remove: %s", strerror(errno));
    free(file);
  }
  closedir(d);
  if (rc == 0 && rmdir(path) != 0) rc = fail(r, path, 0, "cannot remove the directory: %s", strerror(errno));
  return rc;
}

/* Remove `path` if it exists (a leftover of a process that had our pid). */
static int remove_stale(const Report *r, const char *path) {
  struct stat st;
  if (lstat(path, &st) != 0) return errno == ENOENT ? 0 : fail(r, path, 0, "cannot examine: %s", strerror(errno));
  if (!S_ISDIR(st.st_mode)) return fail(r, path, 0, "is in the way and is not a directory: refusing to remove it");
  return remove_store_dir(r, path);
}

static int slurp(const Report *r, const char *path, char **text, size_t *len);

/* Every .npy in the model directory `dir` is an array its manifest lists:
 * replacing the model removes those, so a file the user put there is
 * refused rather than lost. */
static int check_listed(const Report *r, const char *dir) {
  char *mpath = str_printf("%s/manifest", dir), *text = NULL;
  size_t len = 0;
  DIR *d = NULL;
  int rc = mpath ? slurp(r, mpath, &text, &len) : fail(r, dir, 0, "out of memory");
  if (rc == 0 && !(d = opendir(dir))) rc = fail(r, dir, 0, "cannot open the directory: %s", strerror(errno));
  struct dirent *e;
  while (rc == 0 && (e = readdir(d))) {
    size_t n = strlen(e->d_name);
    if (n <= 4 || strcmp(e->d_name + n - 4, ".npy") != 0) continue;
    char *line = str_printf("\narray %s ", e->d_name);
    char buf[NPY_EXCERPT_SIZE];
    if (!line) rc = fail(r, dir, 0, "out of memory");
    else if (!strstr(text, line))
      rc = fail(r, dir, 0, "holds '%s', which its manifest does not list: refusing to replace the model (move the "
                           "file elsewhere first)", excerpt(buf, e->d_name));
    free(line);
  }
  if (d) closedir(d);
  free(text);
  free(mpath);
  return rc;
}

/* Whether `dir` exists (`*exists`), and if so that it is a model directory
 * model_store_write may replace. */
static int check_replaceable(const Report *r, const char *dir, int *exists) {
  struct stat st;
  *exists = 0;
  if (lstat(dir, &st) != 0) return errno == ENOENT ? 0 : fail(r, dir, 0, "cannot examine: %s", strerror(errno));
  if (S_ISLNK(st.st_mode))
    return fail(r, dir, 0, "is a symbolic link: refusing to replace it (give the directory it points to)");
  if (!S_ISDIR(st.st_mode)) return fail(r, dir, 0, "exists and is not a directory: refusing to replace it");
  int entries, model;
  if (scan_store_dir(r, dir, "refusing to replace it", &entries, &model)) return -1;
  if (entries > 0 && !model)
    return fail(r, dir, 0, "exists and is not a model (it has no model manifest): refusing to replace it");
  *exists = 1;
  return model ? check_listed(r, dir) : 0;
}

/* Make the entries of directory `path` durable. Some file systems cannot
 * sync a directory (EINVAL): nothing more can be done there. */
static int sync_dir(const Report *r, const char *path) {
  int fd = open(path, O_RDONLY | O_DIRECTORY);
  if (fd < 0) return fail(r, path, 0, "cannot open the directory to sync it: %s", strerror(errno));
  int rc = 0;
  if (fsync(fd) != 0 && errno != EINVAL) rc = fail(r, path, 0, "cannot sync the directory: %s", strerror(errno));
  close(fd);
  return rc;
}

/* The directory holding `dir` (malloc'd): "." for a bare name. */
static char *parent_of(const char *dir) {
  const char *slash = strrchr(dir, '/');
  if (!slash) return strdup(".");
  if (slash == dir) return strdup("/");
  return str_printf("%.*s", (int)(slash - dir), dir);
}

/* `dir` without trailing slashes (malloc'd; "/" stays "/"), or NULL. */
static char *normalize_dir(const char *dir) {
  size_t n = strlen(dir);
  while (n > 1 && dir[n - 1] == '/') n--;
  return str_printf("%.*s", (int)n, dir);
}

/* ---------------------------------------------------------------- interruption
 *
 * A training killed while it writes leaves "<dir>.tmp.<pid>" (the new model,
 * maybe incomplete) and, on the two-rename path, "<dir>.old.<pid>" (the
 * previous one). SIGINT and SIGTERM remove the temporary folder before the
 * process dies; after a SIGKILL the next write (or read) of the model finds
 * what a dead process left: it moves a complete model into a missing `dir`,
 * saying so, and removes the rest. */

/* Test hook: NPG_TEST_INTERRUPT=<point>[:TERM|:INT] raises that signal
 * (SIGKILL by default) at a named point of model_store_write: "arrays" (half
 * the arrays written), "manifest" (all written, before the swap), "swap"
 * (between the two renames, with NPG_TEST_NO_EXCHANGE=1), "cleanup" (the
 * new model in place, the previous one not yet removed). */
static void test_point(const char *point) {
  const char *at = getenv("NPG_TEST_INTERRUPT");
  size_t n = strlen(point);
  if (!at || strncmp(at, point, n) != 0 || (at[n] && at[n] != ':')) return;
  raise(!at[n] ? SIGKILL : strcmp(at + n + 1, "TERM") == 0 ? SIGTERM : strcmp(at + n + 1, "INT") == 0 ? SIGINT : SIGKILL);
}

/* What the signal handler removes: every file write_contents may create in
 * the temporary folder, then the folder. Set before the handler is armed. */
static struct {
  char **paths;
  int n;
  char *dir;
  struct sigaction saved_int, saved_term;
  int armed;
} cleanup;

static void on_signal(int sig) {
  for (int i = 0; i < cleanup.n; i++) unlink(cleanup.paths[i]);
  rmdir(cleanup.dir);
  sigaction(sig, sig == SIGINT ? &cleanup.saved_int : &cleanup.saved_term, NULL);
  raise(sig);
}

static void disarm(void) {
  if (cleanup.armed) {
    sigaction(SIGINT, &cleanup.saved_int, NULL);
    sigaction(SIGTERM, &cleanup.saved_term, NULL);
    cleanup.armed = 0;
  }
  for (int i = 0; i < cleanup.n; i++) free(cleanup.paths[i]);
  free(cleanup.paths);
  cleanup.paths = NULL;
  cleanup.n = 0;
  cleanup.dir = NULL;
}

/* Arm SIGINT and SIGTERM to remove `tmp` and what `m` writes into it (one
 * model write at a time per process: a second one is not armed). */
static void arm(const char *tmp, const ModelStore *m) {
  if (cleanup.paths) return;
  char **paths = calloc((size_t)(2 * m->narrays + 1), sizeof *paths);
  if (!paths) return;
  cleanup.paths = paths;
  long pid = (long)getpid();
  for (int i = 0; i < m->narrays; i++) {
    if ((paths[cleanup.n] = str_printf("%s/%s.npy", tmp, m->arrays[i].name))) cleanup.n++;
    if ((paths[cleanup.n] = str_printf("%s/%s.npy.tmp.%ld", tmp, m->arrays[i].name, pid))) cleanup.n++;
  }
  if ((paths[cleanup.n] = str_printf("%s/manifest", tmp))) cleanup.n++;
  cleanup.dir = (char *)tmp;
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, &cleanup.saved_int);
  sigaction(SIGTERM, &sa, &cleanup.saved_term);
  cleanup.armed = 1;
}

/* A model directory whose manifest is whole: its last line is its checksum
 * and matches (the manifest is written last, so the arrays are there). */
static int is_complete(const char *path) {
  char *mpath = str_printf("%s/manifest", path), *text = NULL, ignored[16];
  Report quiet = {ignored, sizeof ignored};
  size_t len = 0;
  int ok = 0;
  if (mpath && slurp(&quiet, mpath, &text, &len) == 0) {
    char *last = len > 1 ? memrchr(text, '\n', len - 1) : NULL;
    uint64_t want;
    if (last && strncmp(last + 1, "manifest " CHECKSUM_KIND " ", strlen("manifest " CHECKSUM_KIND " ")) == 0) {
      char hex[17] = {0};
      memcpy(hex, last + 1 + strlen("manifest " CHECKSUM_KIND " "), 16);
      ok = parse_hex64(hex, &want) == 0 &&
           model_hash_bytes(model_hash_init(), text, (size_t)(last - text) + 1) == want;
    }
  }
  free(text);
  free(mpath);
  return ok;
}

/* "<base>.tmp.<pid>" or "<base>.old.<pid>" of a process that is gone: its
 * kind ('t' or 'o'), else 0. */
static int dead_leftover(const char *name, const char *base) {
  size_t n = strlen(base);
  if (strncmp(name, base, n) != 0 || (strncmp(name + n, ".tmp.", 5) != 0 && strncmp(name + n, ".old.", 5) != 0))
    return 0;
  const char *digits = name + n + 5;
  if (!*digits || strspn(digits, "0123456789") != strlen(digits) || strlen(digits) > 9) return 0;
  long pid = strtol(digits, NULL, 10);
  if (pid == (long)getpid() || kill((pid_t)pid, 0) == 0 || errno != ESRCH) return 0;
  return name[n + 1];
}

/* What dead trainings left beside `dir`: a complete new model (else the
 * previous one) moved into a missing `dir`, saying so on stderr; with
 * `clean`, the rest removed. Failures here are not errors of the caller. */
static void recover_interrupted(const char *dir, int clean) {
  char *parent = parent_of(dir), ignored[16];
  const char *slash = strrchr(dir, '/');
  const char *base = slash ? slash + 1 : dir;
  Report quiet = {ignored, sizeof ignored};
  DIR *d = parent ? opendir(parent) : NULL;
  struct stat st;
  int missing = lstat(dir, &st) != 0 && errno == ENOENT;
  for (int pass = 0; d && pass < 3; pass++) { /* complete new models, previous models, the rest */
    rewinddir(d);
    struct dirent *e;
    while ((e = readdir(d))) {
      int kind = dead_leftover(e->d_name, base);
      if (!kind) continue;
      char *path = str_printf("%s/%s", parent, e->d_name);
      if (!path) continue;
      if (pass < 2 && missing && (pass == 0 ? kind == 't' && is_complete(path) : kind == 'o') &&
          rename(path, dir) == 0) {
        fprintf(stderr, "npg: %s was missing after an interrupted training: moved in the %s model from %s\n", dir,
                pass == 0 ? "new (complete)" : "previous", path);
        missing = 0;
      } else if (pass == 2 && clean) {
        remove_store_dir(&quiet, path);
      }
      free(path);
    }
  }
  if (d) closedir(d);
  free(parent);
}

/* ---------------------------------------------------------------- writing */

/* Check that `m` can be written and read back as it is. */
static int check_store(const Report *r, const char *dir, const ModelStore *m) {
  char buf[NPY_EXCERPT_SIZE];
  for (int i = 0; i < m->nmeta; i++)
    if (!valid_meta(m->meta[i]))
      return fail(r, dir, 0, "metadata line %d is not a line 'key value...' with a key of its own: '%s'", i + 1,
                  m->meta[i] ? excerpt(buf, m->meta[i]) : "(null)");
  for (int i = 0; i < m->narrays; i++) {
    const ModelArray *x = &m->arrays[i];
    size_t count;
    if (!valid_name(x->name))
      return fail(r, dir, 0, "array name '%s' is not a file stem of [A-Za-z0-9_.-] not starting with '.'",
                  x->name ? excerpt(buf, x->name) : "(null)");
    for (int j = 0; j < i; j++)
      if (strcmp(m->arrays[j].name, x->name) == 0) return fail(r, dir, 0, "array name '%s' is used twice", x->name);
    if (x->a.type != NPY_F64)
      return fail(r, dir, 0, "array '%s' holds %s; a model holds float64 arrays", x->name, npy_type_name(x->a.type));
    if (x->a.ndim < 0 || x->a.ndim > NPY_MAX_DIMS || shape_count(x->a.ndim, x->a.shape, &count) != 0 ||
        count != x->a.count || (count && !x->a.data))
      return fail(r, dir, 0, "array '%s' has an inconsistent shape, count or data (a bug in npg)", x->name);
  }
  return 0;
}

/* Write the arrays of `m`, then the manifest with their checksums, into the
 * existing empty directory `tmp`, and sync it all. */
static int write_contents(const Report *r, const char *tmp, const ModelStore *m) {
  uint64_t *checksums = calloc((size_t)m->narrays + 1, sizeof *checksums);
  if (!checksums) return fail(r, tmp, 0, "out of memory");
  int rc = 0;
  for (int i = 0; i < m->narrays && rc == 0; i++) {
    const ModelArray *x = &m->arrays[i];
    char *path = str_printf("%s/%s.npy", tmp, x->name);
    if (!path) rc = fail(r, tmp, 0, "out of memory");
    else if (npy_write(path, NPY_F64, x->a.ndim, x->a.shape, x->a.data, r->err, r->errlen) != 0) rc = -1;
    /* The checksum is of the bytes on disk, read back, so it vouches for
     * what a later read will find rather than for what we meant to write. */
    else rc = hash_file(r, path, &checksums[i]);
    free(path);
    if (i == m->narrays / 2) test_point("arrays");
  }
  char *path = rc == 0 ? str_printf("%s/manifest", tmp) : NULL;
  if (rc == 0 && !path) rc = fail(r, tmp, 0, "out of memory");
  char *text = NULL;
  size_t len = 0;
  FILE *mem = rc == 0 ? open_memstream(&text, &len) : NULL;
  if (rc == 0 && !mem) rc = fail(r, tmp, 0, "out of memory");
  if (rc == 0) {
    fprintf(mem, FORMAT_LINE "\nprogram %016" PRIx64 "\n", m->program_hash);
    for (int i = 0; i < m->nmeta; i++) fprintf(mem, "%s\n", m->meta[i]);
    for (int i = 0; i < m->narrays; i++) {
      char shape[SHAPE_TEXT];
      const ModelArray *x = &m->arrays[i];
      fprintf(mem, "array %s.npy %s " CHECKSUM_KIND " %016" PRIx64 "\n", x->name,
              format_shape(shape, x->a.ndim, x->a.shape), checksums[i]);
    }
    if (fclose(mem) != 0 || !text) rc = fail(r, tmp, 0, "out of memory");
  }
  FILE *f = rc == 0 ? fopen(path, "wb") : NULL;
  if (rc == 0 && !f) rc = fail(r, path, 0, "cannot create: %s", strerror(errno));
  if (rc == 0) {
    /* the manifest vouches for itself too: its last line is the checksum of
     * the lines before it, so an edited line is caught like a changed file */
    fwrite(text, 1, len, f);
    fprintf(f, "manifest " CHECKSUM_KIND " %016" PRIx64 "\n", model_hash_bytes(model_hash_init(), text, len));
    /* EINVAL: a file that cannot be synced at all, as npy_write allows. */
    int ok = !ferror(f) && fflush(f) == 0 && (fsync(fileno(f)) == 0 || errno == EINVAL);
    int saved = errno;
    if (fclose(f) != 0 && ok) {
      ok = 0;
      saved = errno;
    }
    if (!ok) rc = fail(r, path, 0, "cannot write: %s", strerror(saved));
  }
  free(text);
  free(path);
  free(checksums);
  return rc == 0 ? sync_dir(r, tmp) : rc;
}

int model_store_write(const char *dir_arg, const ModelStore *m, char *err, size_t errlen) {
  Report r = {err, errlen};
  if (err && errlen) err[0] = '\0';
  if (!dir_arg || !*dir_arg) return fail(&r, "(model directory)", 0, "the directory name is empty");
  char *dir = normalize_dir(dir_arg);
  long pid = (long)getpid();
  char *tmp = dir ? str_printf("%s.tmp.%ld", dir, pid) : NULL;
  char *old = dir ? str_printf("%s.old.%ld", dir, pid) : NULL;
  char *parent = dir ? parent_of(dir) : NULL;
  int exists = 0, rc = 0;
  if (!dir || !tmp || !old || !parent) {
    rc = fail(&r, dir_arg, 0, "out of memory");
    goto done;
  }
  recover_interrupted(dir, 1);
  /* Everything that can be refused is refused before anything is written. */
  if (check_store(&r, dir, m) || check_replaceable(&r, dir, &exists) || remove_stale(&r, tmp) ||
      remove_stale(&r, old)) {
    rc = -1;
    goto done;
  }
  if (mkdir(tmp, 0777) != 0) {
    rc = fail(&r, dir, 0, "cannot create the model's temporary directory %s: %s", tmp, strerror(errno));
    goto done;
  }
  arm(tmp, m);
  if (write_contents(&r, tmp, m) != 0) {
    disarm();
    rc = -1;
    goto discard;
  }
  test_point("manifest");
  disarm();
  /* The swap: one atomic exchange where the file system has it (the old
   * model is then in `tmp`); otherwise two renames, between which `dir` is
   * briefly absent, never half written — a crash there leaves both models
   * whole, and the next read or write moves the new one in. */
  if (exists && !getenv("NPG_TEST_NO_EXCHANGE") && renameat2(AT_FDCWD, tmp, AT_FDCWD, dir, RENAME_EXCHANGE) == 0) {
    if (sync_dir(&r, parent) != 0) { /* as below: keep both */
      rc = -1;
      goto done;
    }
    test_point("cleanup");
    char ignored[16];
    Report quiet = {ignored, sizeof ignored};
    if (remove_store_dir(&quiet, tmp) != 0)
      rc = fail(&r, tmp, 0, "the new model in %s is complete, but the previous one could not be removed from here",
                dir);
    goto done;
  }
  if (exists && rename(dir, old) != 0) {
    rc = fail(&r, dir, 0, "cannot move the previous model aside to %s: %s", old, strerror(errno));
    goto discard;
  }
  if (exists) test_point("swap");
  if (rename(tmp, dir) != 0) {
    rc = fail(&r, dir, 0, "cannot move the new model in from %s: %s", tmp, strerror(errno));
    if (exists && rename(old, dir) != 0) {
      fail(&r, dir, 0, "cannot move the new model in from %s, nor the previous one back from %s: %s", tmp, old,
           strerror(errno));
      goto done; /* keep `tmp`: the message names both copies */
    }
    goto discard;
  }
  /* Until the parent is synced the swap may not survive a crash, so the
   * previous model is kept if that fails. */
  if (sync_dir(&r, parent) != 0) {
    size_t n = err ? strlen(err) : 0;
    if (err && n < errlen)
      snprintf(err + n, errlen - n, " (the new model is in %s%s%s)", dir,
               exists ? "; the previous one is kept in " : "", exists ? old : "");
    rc = -1;
    goto done;
  }
  if (exists) test_point("cleanup");
  if (exists && remove_store_dir(&r, old) != 0) {
    size_t n = err ? strlen(err) : 0;
    if (err && n < errlen)
      snprintf(err + n, errlen - n, " (the new model in %s is complete; remove %s by hand)", dir, old);
    rc = -1;
  }
  goto done;
discard:
  /* The temporary directory holds only our files; its removal cannot make
   * things worse, and its message is less useful than the first one. */
  {
    char ignored[16];
    Report quiet = {ignored, sizeof ignored};
    remove_store_dir(&quiet, tmp);
  }
done:
  free(dir);
  free(tmp);
  free(old);
  free(parent);
  return rc;
}

/* ---------------------------------------------------------------- reading */

/* An array line of the manifest, before its file is looked at. */
typedef struct Listed {
  char *name; /* file stem, pointing into the manifest text */
  int ndim;
  long shape[NPY_MAX_DIMS];
  uint64_t checksum;
  int line;
} Listed;

/* The whole of `path` into a malloc'd, NUL-terminated `*text` of `*len`
 * bytes. */
static int slurp(const Report *r, const char *path, char **text, size_t *len) {
  FILE *f = fopen(path, "rb");
  if (!f) return fail(r, path, 0, "cannot open: %s", strerror(errno));
  size_t cap = 4096, n = 0;
  char *buf = malloc(cap + 1);
  int rc = buf ? 0 : fail(r, path, 0, "out of memory");
  while (rc == 0) {
    n += fread(buf + n, 1, cap - n, f);
    if (ferror(f)) rc = fail(r, path, 0, "cannot read: %s", strerror(errno));
    else if (n < cap) break;
    else if (cap >= MANIFEST_MAX) rc = fail(r, path, 0, "larger than %zu bytes: not a model manifest", MANIFEST_MAX);
    else {
      char *grown = realloc(buf, 2 * cap + 1);
      if (!grown) rc = fail(r, path, 0, "out of memory");
      else buf = grown, cap *= 2;
    }
  }
  fclose(f);
  if (rc) {
    free(buf);
    return rc;
  }
  buf[n] = '\0';
  *text = buf;
  *len = n;
  return 0;
}

/* Split `line` at single spaces into at most `max` words; the number of
 * words, `max` + 1 if there are more, or -1 if two spaces meet or the line
 * begins or ends with one. */
static int split_words(char *line, char **words, int max) {
  int n = 0;
  for (char *p = line;;) {
    char *space = strchr(p, ' ');
    if (space == p || *p == '\0') return -1;
    if (n == max) return max + 1;
    words[n++] = p;
    if (!space) return n;
    *space = '\0';
    p = space + 1;
  }
}

/* array <name>.npy <shape> fnv1a64 <16 hex digits> */
static int parse_array_line(const Report *r, const char *mpath, int ln, char *line, Listed *x) {
  char *w[5], buf[NPY_EXCERPT_SIZE];
  if (split_words(line, w, 5) != 5)
    return fail(r, mpath, ln, "expected 'array <name>.npy <shape> " CHECKSUM_KIND " <16 hex digits>'");
  size_t n = strlen(w[1]);
  if (n <= 4 || strcmp(w[1] + n - 4, ".npy") != 0)
    return fail(r, mpath, ln, "array file '%s' does not end in .npy", excerpt(buf, w[1]));
  w[1][n - 4] = '\0';
  if (!valid_name(w[1])) return fail(r, mpath, ln, "bad array name '%s'", excerpt(buf, w[1]));
  if (parse_shape(w[2], &x->ndim, x->shape) != 0)
    return fail(r, mpath, ln, "bad shape '%s' (expected sizes joined by 'x', like 3x4)", excerpt(buf, w[2]));
  if (strcmp(w[3], CHECKSUM_KIND) != 0)
    return fail(r, mpath, ln, "unknown checksum kind '%s' (expected " CHECKSUM_KIND ")", excerpt(buf, w[3]));
  if (parse_hex64(w[4], &x->checksum) != 0)
    return fail(r, mpath, ln, "bad checksum '%s' (expected 16 hex digits)", excerpt(buf, w[4]));
  x->name = w[1];
  x->line = ln;
  return 0;
}

/* Parse the manifest `text` (modified in place: lines and words are cut out
 * of it) of file `mpath`: its program hash into `*program`, its metadata
 * lines into `m`, its array lines into `*listed` (malloc'd, `*nlisted`);
 * `*changed_line` is the checksum line when the lines before it do not
 * hash to it, else 0. */
static int parse_manifest(const Report *r, const char *mpath, char *text, size_t len, uint64_t *program,
                          ModelStore *m, Listed **listed, int *nlisted, int *changed_line) {
  char buf[NPY_EXCERPT_SIZE];
  int program_line = 0, ln = 0, checksum_line = 0;
  /* the hash of the bytes before the last line, which must be its checksum */
  size_t body = len;
  while (body > 0 && text[body - 1] == '\n') body--;
  while (body > 0 && text[body - 1] != '\n') body--;
  uint64_t expect = 0, actual = model_hash_bytes(model_hash_init(), text, body);
  *listed = NULL;
  *nlisted = 0;
  if (len == 0) return fail(r, mpath, 1, "empty file: not a model manifest (expected '" FORMAT_LINE "')");
  for (char *line = text; line < text + len;) {
    char *nl = memchr(line, '\n', (size_t)(text + len - line));
    ln++;
    if (!nl) return fail(r, mpath, ln, "last line has no newline: the file was cut short?");
    *nl = '\0';
    char *next = nl + 1;
    if (strlen(line) != (size_t)(nl - line)) return fail(r, mpath, ln, "line holds a NUL byte");
    if (ln == 1 && strcmp(line, FORMAT_LINE) != 0) {
      if (key_is(line, FORMAT_WORD))
        return fail(r, mpath, ln, "model format '%s' is not supported (this npgc reads '" FORMAT_LINE "')",
                    excerpt(buf, line));
      return fail(r, mpath, ln, "not a model manifest: first line is '%s', expected '" FORMAT_LINE "'",
                  excerpt(buf, line));
    } else if (ln == 1) {
      /* the format line: nothing more to it */
    } else if (key_is(line, FORMAT_WORD)) {
      return fail(r, mpath, ln, "'" FORMAT_WORD "' may only be the first line");
    } else if (key_is(line, "manifest")) {
      char *w[3];
      if (next != text + len) return fail(r, mpath, ln, "the 'manifest' checksum line must be the last");
      if (split_words(line, w, 3) != 3 || strcmp(w[1], CHECKSUM_KIND) != 0 || parse_hex64(w[2], &expect) != 0)
        return fail(r, mpath, ln, "expected 'manifest " CHECKSUM_KIND " <16 hex digits>'");
      checksum_line = ln;
    } else if (key_is(line, "program")) {
      char *w[2];
      if (program_line) return fail(r, mpath, ln, "second 'program' line (the first is line %d)", program_line);
      if (split_words(line, w, 2) != 2 || parse_hex64(w[1], program) != 0)
        return fail(r, mpath, ln, "expected 'program <16 hex digits>'");
      program_line = ln;
    } else if (key_is(line, "array")) {
      Listed x;
      if (parse_array_line(r, mpath, ln, line, &x)) return -1;
      for (int i = 0; i < *nlisted; i++)
        if (strcmp((*listed)[i].name, x.name) == 0)
          return fail(r, mpath, ln, "array %s.npy listed twice (first on line %d)", x.name, (*listed)[i].line);
      Listed *grown = realloc(*listed, ((size_t)*nlisted + 1) * sizeof *grown);
      if (!grown) return fail(r, mpath, 0, "out of memory");
      *listed = grown;
      grown[(*nlisted)++] = x;
    } else if (*line == '\0') {
      return fail(r, mpath, ln, "empty line");
    } else if (*line == ' ' || *line == '\t') {
      return fail(r, mpath, ln, "line starts with a space (expected 'key value...')");
    } else {
      char *copy = strdup(line);
      if (!copy || append_meta(m, copy) != 0) return fail(r, mpath, 0, "out of memory");
    }
    line = next;
  }
  if (!program_line) return fail(r, mpath, 0, "no 'program' line");
  if (!checksum_line)
    return fail(r, mpath, 0, "no 'manifest' checksum line: cut short, or written by an older npg (retrain)");
  /* compared by the caller once the arrays are checked: a changed file is
   * named as such even when its manifest line was changed to match */
  *changed_line = expect != actual ? checksum_line : 0;
  return 0;
}

/* Check and load the array file `x` of directory `dir` into `m`. */
static int load_array(const Report *r, const char *dir, const Listed *x, ModelStore *m) {
  char *path = str_printf("%s/%s.npy", dir, x->name);
  if (!path) return fail(r, dir, 0, "out of memory");
  uint64_t h;
  NpyArray a = {0};
  char got[SHAPE_TEXT], want[SHAPE_TEXT];
  /* a file far larger than its shape allows (a sparse 8 GB file) is refused
   * before it is hashed: hashing it would take minutes */
  struct stat st;
  size_t count = 0;
  int rc = 0;
  if (stat(path, &st) == 0 && S_ISREG(st.st_mode) && shape_count(x->ndim, x->shape, &count) == 0 &&
      (uintmax_t)st.st_size > (uintmax_t)count * sizeof(double) + NPY_HEADER_MAX + 16)
    rc = fail(r, path, 0, "%jd bytes, more than an array of shape %s can take: the file is damaged or not the model's",
              (intmax_t)st.st_size, format_shape(want, x->ndim, x->shape));
  if (rc == 0) rc = hash_file(r, path, &h);
  if (rc == 0 && h != x->checksum)
    rc = fail(r, path, 0, "checksum mismatch: the file is corrupted or was changed after training");
  if (rc == 0) rc = npy_read(path, &a, r->err, r->errlen) != 0 ? -1 : 0;
  if (rc == 0 && a.type != NPY_F64)
    rc = fail(r, path, 0, "holds %s elements; a model holds float64", npy_type_name(a.type));
  if (rc == 0 && (a.ndim != x->ndim || memcmp(a.shape, x->shape, (size_t)a.ndim * sizeof *a.shape) != 0))
    rc = fail(r, path, 0, "shape %s, manifest says %s", format_shape(got, a.ndim, a.shape),
              format_shape(want, x->ndim, x->shape));
  if (rc == 0 && append_array(m, x->name, &a, h) != 0) rc = fail(r, path, 0, "out of memory");
  npy_free(&a);
  free(path);
  return rc;
}

int model_store_read(const char *dir_arg, uint64_t expect_program_hash, ModelStore *m, char *err, size_t errlen) {
  Report r = {err, errlen};
  if (err && errlen) err[0] = '\0';
  model_store_init(m);
  if (!dir_arg || !*dir_arg) return fail(&r, "(model directory)", 0, "the directory name is empty");
  char *dir = normalize_dir(dir_arg);
  if (dir) recover_interrupted(dir, 0);
  char *mpath = dir ? str_printf("%s/manifest", dir) : NULL;
  char *text = NULL;
  size_t len = 0;
  Listed *listed = NULL;
  int nlisted = 0, rc = 0, changed_line = 0;
  if (!mpath) rc = fail(&r, dir_arg, 0, "out of memory");
  if (rc == 0) rc = slurp(&r, mpath, &text, &len);
  if (rc == 0) rc = parse_manifest(&r, mpath, text, len, &m->program_hash, m, &listed, &nlisted, &changed_line);
  if (rc == 0 && m->program_hash != expect_program_hash)
    rc = fail(&r, mpath, 0,
              "model was trained for another program (program hash %016" PRIx64 ", this program %016" PRIx64
              "): retrain",
              m->program_hash, expect_program_hash);
  for (int i = 0; i < nlisted && rc == 0; i++) rc = load_array(&r, dir, &listed[i], m);
  if (rc == 0 && changed_line)
    rc = fail(&r, mpath, changed_line, "checksum mismatch: the manifest was changed after training");
  if (rc) model_store_free(m);
  free(listed);
  free(text);
  free(mpath);
  free(dir);
  return rc;
}
