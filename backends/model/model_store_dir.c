/* model_store_dir.c — model directories (model_store.h): what a model store
 * may remove, writing a model whole or not at all, and recovering from a
 * write that was interrupted.
 *
 * Writing never exposes a half model: everything goes to "<dir>.tmp.<pid>",
 * is synced, and only then swapped with `dir` (one atomic exchange where the
 * file system has it, else two renames). Removing the replaced model
 * deletes only files a model store writes, each checked by name before
 * anything is touched, so a mistyped -o never costs the user a directory of
 * their own.
 *
 * Only folders this code made are ever removed or moved in: the temporary
 * folder and the previous model set aside each hold a marker file (MARKER)
 * written before they can be left behind. A folder that merely looks like a
 * leftover ("M.old.2024", "M.tmp.<a dead pid>" holding a user's files) has
 * none and is left alone (issue 24). */
#define _GNU_SOURCE /* renameat2 (RENAME_EXCHANGE), fsync, O_DIRECTORY, lstat, getpid */

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "model_store_impl.h"
#include "alloc.h" /* mem_malloc: allocation through the hook */
#include "scratch.h"

/* ---------------------------------------------------------------- directories */

/* The marker of a folder a model store made to be thrown away: the new
 * model being written ("<dir>.tmp.<pid>") or the previous one set aside
 * ("<dir>.old.<pid>", or the exchanged folder). */
#define MARKER "npg-model-store-leftover"

/* Names a model store writes into a model directory: the manifest, the
 * arrays, the marker, and what an interrupted npy_write leaves
 * ("x.npy.tmp.<pid>"). */
static int is_store_file(const char *name) {
  size_t n = strlen(name);
  if (strcmp(name, "manifest") == 0 || strcmp(name, MARKER) == 0 || (n > 4 && strcmp(name + n - 4, ".npy") == 0))
    return 1;
  if (n > 4 && strcmp(name + n - 4, ".csv") == 0) return 1;
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
static int scan_store_dir(const StoreReport *r, const char *path, const char *what, int *entries, int *model) {
  DIR *d = opendir(path);
  if (!d) return model_store_fail(r, path, 0, "cannot open the directory: %s", strerror(errno));
  int rc = 0;
  *entries = *model = 0;
  struct dirent *e;
  while (rc == 0 && (e = readdir(d))) {
    if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
    Scratch sc = SCRATCH_OF(NULL); /* an entry's path */
    char *file = scratch_printf(&sc, "%s/%s", path, e->d_name);
    struct stat st;
    char buf[NPY_EXCERPT_SIZE];
    if (!file) rc = model_store_fail(r, path, 0, "out of memory");
    else if (lstat(file, &st) != 0) rc = model_store_fail(r, file, 0, "cannot examine: %s", strerror(errno));
    else if (!is_store_file(e->d_name) || !S_ISREG(st.st_mode))
      rc = model_store_fail(r, path, 0, "holds '%s', which a model store never writes: %s", model_store_excerpt(buf, e->d_name), what);
    else if (strcmp(e->d_name, "manifest") == 0) *model = is_model_manifest(file);
    ++*entries;
    scratch_release(&sc);
  }
  closedir(d);
  return rc;
}

/* Whether the folder `path` holds the marker of a model store's leftover. */
static int has_marker(const char *path) {
  Scratch sc = SCRATCH_OF(NULL);
  char *file = scratch_printf(&sc, "%s/" MARKER, path);
  struct stat st;
  int yes = file && lstat(file, &st) == 0 && S_ISREG(st.st_mode);
  scratch_release(&sc);
  return yes;
}

/* Put the marker into the folder `path` (saying what it is, for a person
 * who finds it), or take it out (`put` 0; a missing marker is no error). */
static int mark(const StoreReport *r, const char *path, int put) {
  Scratch sc = SCRATCH_OF(NULL);
  char *file = scratch_printf(&sc, "%s/" MARKER, path);
  int rc = 0;
  if (!file) {
    rc = model_store_fail(r, path, 0, "out of memory");
  } else if (!put) {
    if (unlink(file) != 0 && errno != ENOENT) rc = model_store_fail(r, file, 0, "cannot remove: %s", strerror(errno));
  } else {
    FILE *f = fopen(file, "w");
    int ok = f && fprintf(f, "made by npg (process %ld) to be removed when its model write ends\n", (long)getpid()) > 0;
    if (f && fclose(f) != 0) ok = 0;
    if (!ok) rc = model_store_fail(r, file, 0, "cannot create: %s", strerror(errno));
  }
  scratch_release(&sc);
  return rc;
}

/* Remove the directory `path` and the model files in it, after checking
 * that a model store made it to be thrown away (its marker) and that it
 * holds nothing else (it is left untouched otherwise). */
static int remove_store_dir(const StoreReport *r, const char *path) {
  int entries, model;
  if (!has_marker(path))
    return model_store_fail(r, path, 0, "was not made by npg's model store (it has no %s marker): refusing to remove it",
                            MARKER);
  if (scan_store_dir(r, path, "refusing to remove it", &entries, &model)) return -1;
  DIR *d = opendir(path);
  if (!d) return model_store_fail(r, path, 0, "cannot open the directory: %s", strerror(errno));
  int rc = 0;
  struct dirent *e;
  while (rc == 0 && (e = readdir(d))) {
    if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0 || !is_store_file(e->d_name) ||
        strcmp(e->d_name, MARKER) == 0)
      continue; /* the marker goes last: a process killed in this loop leaves a folder still removable */
    Scratch sc = SCRATCH_OF(NULL); /* an entry's path */
    char *file = scratch_printf(&sc, "%s/%s", path, e->d_name);
    if (!file) rc = model_store_fail(r, path, 0, "out of memory");
    else if (unlink(file) != 0 && errno != ENOENT) rc = model_store_fail(r, file, 0, "cannot remove: %s", strerror(errno));
    scratch_release(&sc);
  }
  closedir(d);
  if (rc == 0) rc = mark(r, path, 0);
  if (rc == 0 && rmdir(path) != 0) rc = model_store_fail(r, path, 0, "cannot remove the directory: %s", strerror(errno));
  return rc;
}

/* Remove `path` if it exists (a leftover of a process that had our pid). */
static int remove_stale(const StoreReport *r, const char *path) {
  struct stat st;
  if (lstat(path, &st) != 0) return errno == ENOENT ? 0 : model_store_fail(r, path, 0, "cannot examine: %s", strerror(errno));
  if (!S_ISDIR(st.st_mode)) return model_store_fail(r, path, 0, "is in the way and is not a directory: refusing to remove it");
  if (!has_marker(path))
    return model_store_fail(r, path, 0, "is in the way and was not made by npg (it has no %s marker): refusing to remove "
                            "it; move it elsewhere", MARKER);
  return remove_store_dir(r, path);
}

/* Every .npy in the model directory `dir` is an array its manifest lists:
 * replacing the model removes those (and the .csv files it lists), so a
 * file the user put there is refused rather than lost. */
static int check_listed(const StoreReport *r, const char *dir) {
  Scratch sc = SCRATCH_OF(NULL);
  char *mpath = scratch_printf(&sc, "%s/manifest", dir), *text = NULL;
  size_t len = 0;
  DIR *d = NULL;
  int rc = mpath ? model_store_slurp(r, mpath, &text, &len) : model_store_fail(r, dir, 0, "out of memory");
  if (rc == 0 && !scratch_adopt(&sc, text)) rc = model_store_fail(r, dir, 0, "out of memory");
  if (rc == 0 && !(d = opendir(dir))) rc = model_store_fail(r, dir, 0, "cannot open the directory: %s", strerror(errno));
  struct dirent *e;
  while (rc == 0 && (e = readdir(d))) {
    size_t n = strlen(e->d_name);
    int csv = n > 4 && strcmp(e->d_name + n - 4, ".csv") == 0;
    if (!csv && (n <= 4 || strcmp(e->d_name + n - 4, ".npy") != 0)) continue;
    Scratch entry = SCRATCH_OF(NULL); /* its manifest line */
    char *line = scratch_printf(&entry, csv ? "\nfile %s " : "\narray %s ", e->d_name);
    char buf[NPY_EXCERPT_SIZE];
    if (!line) rc = model_store_fail(r, dir, 0, "out of memory");
    else if (!strstr(text, line))
      rc = model_store_fail(r, dir, 0, "holds '%s', which its manifest does not list: refusing to replace the model (move the "
                           "file elsewhere first)", model_store_excerpt(buf, e->d_name));
    scratch_release(&entry);
  }
  if (d) closedir(d);
  scratch_release(&sc);
  return rc;
}

/* Whether `dir` exists (`*exists`), and if so that it is a model directory
 * model_store_write may replace. */
static int check_replaceable(const StoreReport *r, const char *dir, int *exists) {
  struct stat st;
  *exists = 0;
  if (lstat(dir, &st) != 0) return errno == ENOENT ? 0 : model_store_fail(r, dir, 0, "cannot examine: %s", strerror(errno));
  if (S_ISLNK(st.st_mode))
    return model_store_fail(r, dir, 0, "is a symbolic link: refusing to replace it (give the directory it points to)");
  if (!S_ISDIR(st.st_mode)) return model_store_fail(r, dir, 0, "exists and is not a directory: refusing to replace it");
  int entries, model;
  if (scan_store_dir(r, dir, "refusing to replace it", &entries, &model)) return -1;
  if (entries > 0 && !model)
    return model_store_fail(r, dir, 0, "exists and is not a model (it has no model manifest): refusing to replace it");
  *exists = 1;
  return model ? check_listed(r, dir) : 0;
}

/* Make the entries of directory `path` durable. Some file systems cannot
 * sync a directory (EINVAL): nothing more can be done there. */
static int sync_dir(const StoreReport *r, const char *path) {
  int fd = open(path, O_RDONLY | O_DIRECTORY);
  if (fd < 0) return model_store_fail(r, path, 0, "cannot open the directory to sync it: %s", strerror(errno));
  int rc = 0;
  if (fsync(fd) != 0 && errno != EINVAL) rc = model_store_fail(r, path, 0, "cannot sync the directory: %s", strerror(errno));
  close(fd);
  return rc;
}

/* The directory holding `dir` (malloc'd): "." for a bare name. */
static char *parent_of(const char *dir) {
  const char *slash = strrchr(dir, '/');
  if (!slash) return mem_strdup(".");
  if (slash == dir) return mem_strdup("/");
  return model_store_printf("%.*s", (int)(slash - dir), dir);
}

/* `dir` without trailing slashes (malloc'd; "/" stays "/"), or NULL. */
char *model_store_normalize_dir(const char *dir) {
  size_t n = strlen(dir);
  while (n > 1 && dir[n - 1] == '/') n--;
  return model_store_printf("%.*s", (int)n, dir);
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
  char **paths = mem_calloc((size_t)(2 * m->narrays + m->ntexts + 2), sizeof *paths);
  if (!paths) return;
  cleanup.paths = paths;
  long pid = (long)getpid();
  for (int i = 0; i < m->narrays; i++) {
    if ((paths[cleanup.n] = model_store_printf("%s/%s.npy", tmp, m->arrays[i].name))) cleanup.n++;
    if ((paths[cleanup.n] = model_store_printf("%s/%s.npy.tmp.%ld", tmp, m->arrays[i].name, pid))) cleanup.n++;
  }
  for (int i = 0; i < m->ntexts; i++)
    if ((paths[cleanup.n] = model_store_printf("%s/%s", tmp, m->texts[i].name))) cleanup.n++;
  if ((paths[cleanup.n] = model_store_printf("%s/manifest", tmp))) cleanup.n++;
  if ((paths[cleanup.n] = model_store_printf("%s/" MARKER, tmp))) cleanup.n++;
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
  Scratch sc = SCRATCH_OF(NULL);
  char *mpath = scratch_printf(&sc, "%s/manifest", path), *text = NULL, ignored[16];
  StoreReport quiet = {ERR_OF(ignored, sizeof ignored)};
  size_t len = 0;
  int ok = 0;
  if (mpath && model_store_slurp(&quiet, mpath, &text, &len) == 0 && scratch_adopt(&sc, text)) {
    char *last = len > 1 ? memrchr(text, '\n', len - 1) : NULL;
    uint64_t want;
    if (last && strncmp(last + 1, "manifest " CHECKSUM_KIND " ", strlen("manifest " CHECKSUM_KIND " ")) == 0) {
      char hex[17] = {0};
      memcpy(hex, last + 1 + strlen("manifest " CHECKSUM_KIND " "), 16);
      ok = model_store_parse_hex64(hex, &want) == 0 &&
           model_hash_bytes(model_hash_init(), text, (size_t)(last - text) + 1) == want;
    }
  }
  scratch_release(&sc);
  return ok;
}

/* "<base>.tmp.<pid>" or "<base>.old.<pid>" of a process that is gone, in
 * `parent`, holding the marker: its kind ('t' or 'o'), else 0. */
static int dead_leftover(const char *parent, const char *name, const char *base) {
  size_t n = strlen(base);
  if (strncmp(name, base, n) != 0 || (strncmp(name + n, ".tmp.", 5) != 0 && strncmp(name + n, ".old.", 5) != 0))
    return 0;
  const char *digits = name + n + 5;
  if (!*digits || strspn(digits, "0123456789") != strlen(digits) || strlen(digits) > 9) return 0;
  long pid = strtol(digits, NULL, 10);
  if (pid == (long)getpid() || kill((pid_t)pid, 0) == 0 || errno != ESRCH) return 0;
  Scratch sc = SCRATCH_OF(NULL);
  char *path = scratch_printf(&sc, "%s/%s", parent, name);
  int ours = path && has_marker(path);
  if (path && !ours) rmdir(path); /* empty (rmdir takes nothing else): killed between its mkdir and its marker */
  scratch_release(&sc);
  return ours ? name[n + 1] : 0;
}

/* What dead trainings left beside `dir`: a complete new model (else the
 * previous one) moved into a missing `dir`, saying so on stderr; with
 * `clean`, the rest removed. Failures here are not errors of the caller. */
void model_store_recover(const char *dir, int clean) {
  Scratch sc = SCRATCH_OF(NULL);
  char *parent = scratch_adopt(&sc, parent_of(dir)), ignored[16];
  const char *slash = strrchr(dir, '/');
  const char *base = slash ? slash + 1 : dir;
  StoreReport quiet = {ERR_OF(ignored, sizeof ignored)};
  DIR *d = parent ? opendir(parent) : NULL;
  struct stat st;
  int missing = lstat(dir, &st) != 0 && errno == ENOENT;
  for (int pass = 0; d && pass < 3; pass++) { /* complete new models, previous models, the rest */
    rewinddir(d);
    struct dirent *e;
    while ((e = readdir(d))) {
      int kind = dead_leftover(parent, e->d_name, base);
      Scratch entry = SCRATCH_OF(NULL); /* a leftover's path */
      char *path = kind ? scratch_printf(&entry, "%s/%s", parent, e->d_name) : NULL;
      if (path && pass < 2 && missing && (pass == 0 ? kind == 't' && is_complete(path) : kind == 'o') &&
          rename(path, dir) == 0) {
        mark(&quiet, dir, 0);
        fprintf(stderr, "npg: %s was missing after an interrupted training: moved in the %s model from %s\n", dir,
                pass == 0 ? "new (complete)" : "previous", path);
        missing = 0;
      } else if (path && pass == 2 && clean) {
        remove_store_dir(&quiet, path);
      }
      scratch_release(&entry);
    }
  }
  if (d) closedir(d);
  scratch_release(&sc);
}

/* ---------------------------------------------------------------- writing */

/* Check that `m` can be written and read back as it is. */
static int check_store(const StoreReport *r, const char *dir, const ModelStore *m) {
  char buf[NPY_EXCERPT_SIZE];
  for (int i = 0; i < m->nmeta; i++)
    if (!model_store_valid_meta(m->meta[i]))
      return model_store_fail(r, dir, 0, "metadata line %d is not a line 'key value...' with a key of its own: '%s'", i + 1,
                  m->meta[i] ? model_store_excerpt(buf, m->meta[i]) : "(null)");
  for (int i = 0; i < m->narrays; i++) {
    const ModelArray *x = &m->arrays[i];
    size_t count;
    if (!model_store_valid_name(x->name))
      return model_store_fail(r, dir, 0, "array name '%s' is not a file stem of [A-Za-z0-9_.-] not starting with '.'",
                  x->name ? model_store_excerpt(buf, x->name) : "(null)");
    for (int j = 0; j < i; j++)
      if (strcmp(m->arrays[j].name, x->name) == 0) return model_store_fail(r, dir, 0, "array name '%s' is used twice", x->name);
    if (x->a.type != NPY_F64)
      return model_store_fail(r, dir, 0, "array '%s' holds %s; a model holds float64 arrays", x->name, npy_type_name(x->a.type));
    if (x->a.ndim < 0 || x->a.ndim > NPY_MAX_DIMS || model_store_shape_count(x->a.ndim, x->a.shape, &count) != 0 ||
        count != x->a.count || (count && !x->a.data))
      return model_store_fail(r, dir, 0, "array '%s' has an inconsistent shape, count or data (a bug in npg)", x->name);
  }
  return 0;
}

/* Write the arrays of `m`, then the manifest with their checksums, into the
 * existing empty directory `tmp`, and sync it all. */
static int write_contents(const StoreReport *r, const char *tmp, const ModelStore *m) {
  Scratch sc = SCRATCH_OF(NULL);
  uint64_t *checksums = scratch_array(&sc, (size_t)m->narrays + 1, sizeof *checksums);
  int rc = checksums ? 0 : model_store_fail(r, tmp, 0, "out of memory");
  for (int i = 0; i < m->narrays && rc == 0; i++) {
    const ModelArray *x = &m->arrays[i];
    Scratch entry = SCRATCH_OF(NULL); /* the array's path */
    char *path = scratch_printf(&entry, "%s/%s.npy", tmp, x->name);
    if (!path) rc = model_store_fail(r, tmp, 0, "out of memory");
    else if (npy_write(path, NPY_F64, x->a.ndim, x->a.shape, x->a.data, ERR_MSG(r->err), ERR_LEN(r->err)) != 0)
      rc = -1;
    /* The checksum is of the bytes on disk, read back, so it vouches for
     * what a later read will find rather than for what we meant to write. */
    else rc = model_store_hash_file(r, path, &checksums[i]);
    scratch_release(&entry);
    if (i == m->narrays / 2) test_point("arrays");
  }
  uint64_t *text_sums = rc == 0 ? scratch_array(&sc, (size_t)m->ntexts + 1, sizeof *text_sums) : NULL;
  if (rc == 0 && !text_sums) rc = model_store_fail(r, tmp, 0, "out of memory");
  for (int i = 0; i < m->ntexts && rc == 0; i++) {
    Scratch entry = SCRATCH_OF(NULL); /* the file's path */
    char *tpath = scratch_printf(&entry, "%s/%s", tmp, m->texts[i].name);
    FILE *tf = tpath ? fopen(tpath, "wb") : NULL;
    if (!tpath) rc = model_store_fail(r, tmp, 0, "out of memory");
    else if (!tf) rc = model_store_fail(r, tpath, 0, "cannot create: %s", strerror(errno));
    else {
      size_t len = strlen(m->texts[i].text);
      int ok = fwrite(m->texts[i].text, 1, len, tf) == len && fflush(tf) == 0 &&
               (fsync(fileno(tf)) == 0 || errno == EINVAL);
      if (fclose(tf) != 0) ok = 0;
      rc = ok ? model_store_hash_file(r, tpath, &text_sums[i]) : model_store_fail(r, tpath, 0, "cannot write: %s", strerror(errno));
    }
    scratch_release(&entry);
  }
  char *path = rc == 0 ? scratch_printf(&sc, "%s/manifest", tmp) : NULL;
  if (rc == 0 && !path) rc = model_store_fail(r, tmp, 0, "out of memory");
  char *text = NULL;
  size_t len = 0;
  FILE *mem = rc == 0 ? open_memstream(&text, &len) : NULL;
  if (rc == 0 && !mem) rc = model_store_fail(r, tmp, 0, "out of memory");
  if (rc == 0) {
    fprintf(mem, FORMAT_WORD " %d\nprogram %016" PRIx64 "\n", m->format > 1 ? m->format : 1, m->program_hash);
    for (int i = 0; i < m->nmeta; i++) fprintf(mem, "%s\n", m->meta[i]);
    for (int i = 0; i < m->narrays; i++) {
      char shape[SHAPE_TEXT];
      const ModelArray *x = &m->arrays[i];
      fprintf(mem, "array %s.npy %s " CHECKSUM_KIND " %016" PRIx64 "\n", x->name,
              model_store_format_shape(shape, x->a.ndim, x->a.shape), checksums[i]);
    }
    for (int i = 0; i < m->ntexts; i++)
      fprintf(mem, "file %s " CHECKSUM_KIND " %016" PRIx64 "\n", m->texts[i].name, text_sums[i]);
    int closed = fclose(mem); /* `text` is the stream's buffer even when closing failed */
    if (!scratch_adopt(&sc, text) || closed != 0) rc = model_store_fail(r, tmp, 0, "out of memory");
  }
  FILE *f = rc == 0 ? fopen(path, "wb") : NULL;
  if (rc == 0 && !f) rc = model_store_fail(r, path, 0, "cannot create: %s", strerror(errno));
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
    if (!ok) rc = model_store_fail(r, path, 0, "cannot write: %s", strerror(saved));
  }
  scratch_release(&sc);
  return rc == 0 ? sync_dir(r, tmp) : rc;
}

/* Adds to the message `err` holds (what the failure left behind). */
__attribute__((format(printf, 2, 3))) static void append(Err *err, const char *fmt, ...) {
  size_t n = err_held(err) ? strlen(err->msg) : 0;
  if (!err || !err->msg || n >= err->len) return;
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(err->msg + n, err->len - n, fmt, ap);
  va_end(ap);
}

/* The paths of one write: the model's directory, its temporary and set-aside names, its parent. */
typedef struct StorePaths {
  const char *dir, *tmp, *old, *parent;
} StorePaths;

/* The swap of the complete model in `tmp` into p->dir, whose previous model (`exists`) is
 * removed after it. -1 on failure with *discard when `tmp` holds only our files, to be removed
 * (else it is kept: it holds a model the message names). */
static int swap_in(const StoreReport *r, const StorePaths *p, int exists, bool *discard) {
  const char *dir = p->dir, *tmp = p->tmp, *old = p->old;
  Err *err = r->err;
  *discard = true;
  /* the previous model will be set aside (renamed or exchanged into `tmp`):
   * marked first, so that a crash leaves it removable */
  if (exists && mark(r, dir, 1) != 0) return -1;
  /* The swap: one atomic exchange where the file system has it (the old
   * model is then in `tmp`); otherwise two renames, between which `dir` is
   * briefly absent, never half written — a crash there leaves both models
   * whole, and the next read or write moves the new one in. */
  bool moved = false;
  if (!exists) {
    if (rename(tmp, dir) == 0) moved = true;
    else if (errno != ENOTEMPTY && errno != EEXIST)
      return model_store_fail(r, dir, 0, "cannot move the new model in from %s: %s", tmp, strerror(errno));
    else if (check_replaceable(r, dir, &exists) != 0 || !exists || mark(r, dir, 1) != 0) {
      /* issue 24: this said "Directory not empty" */
      append(err, " (it appeared while this model was being written: another training of the same model at once?)");
      return -1;
    }
    /* else another process wrote a model to `dir` while this one wrote its
     * own (two trainings of one model at once): it is replaced like any
     * model, the last one written wins */
  }
  if (!moved && !getenv("NPG_TEST_NO_EXCHANGE") && renameat2(AT_FDCWD, tmp, AT_FDCWD, dir, RENAME_EXCHANGE) == 0) {
    *discard = false;
    if (sync_dir(r, p->parent) != 0) return -1; /* as below: keep both */
    test_point("cleanup");
    char ignored[16];
    StoreReport quiet = {ERR_OF(ignored, sizeof ignored)};
    /* the previous model, now in our `tmp`, was marked above; marked again,
     * since a concurrent training of the same model that moved it in clears
     * the marker of whatever `dir` holds when it ends, and may have done so
     * between our mark and the exchange (seen in CI: the previous model was
     * then refused as "not made by npg's model store") */
    if (mark(&quiet, tmp, 1) != 0 || remove_store_dir(&quiet, tmp) != 0)
      return model_store_fail(r, tmp, 0, "the new model in %s is complete, but the previous one could not be removed from here",
                              dir);
    return 0;
  }
  if (!moved && exists && rename(dir, old) != 0)
    return model_store_fail(r, dir, 0, "cannot move the previous model aside to %s: %s", old, strerror(errno));
  if (exists) test_point("swap");
  if (!moved && rename(tmp, dir) != 0) {
    int rc = model_store_fail(r, dir, 0, "cannot move the new model in from %s: %s", tmp, strerror(errno));
    if (exists && rename(old, dir) != 0) {
      *discard = false; /* keep `tmp`: the message names both copies */
      return model_store_fail(r, dir, 0, "cannot move the new model in from %s, nor the previous one back from %s: %s", tmp,
                              old, strerror(errno));
    }
    return rc;
  }
  *discard = false;
  /* Until the parent is synced the swap may not survive a crash, so the
   * previous model is kept if that fails. */
  if (sync_dir(r, p->parent) != 0) {
    append(err, " (the new model is in %s%s%s)", dir, exists ? "; the previous one is kept in " : "", exists ? old : "");
    return -1;
  }
  if (exists) test_point("cleanup");
  if (exists && (mark(r, old, 1) != 0 || remove_store_dir(r, old) != 0)) { /* marked again: as above */
    append(err, " (the new model in %s is complete; remove %s by hand)", dir, old);
    return -1;
  }
  return 0;
}

/* model_store_write once its paths are made: refusals first, then the contents into `tmp`
 * and the swap. */
static int write_store(const StoreReport *r, const StorePaths *p, const ModelStore *m) {
  int exists = 0;
  model_store_recover(p->dir, 1);
  /* Everything that can be refused is refused before anything is written. */
  if (check_store(r, p->dir, m) || check_replaceable(r, p->dir, &exists) || remove_stale(r, p->tmp) ||
      remove_stale(r, p->old))
    return -1;
  if (mkdir(p->tmp, 0777) != 0)
    return model_store_fail(r, p->dir, 0, "cannot create the model's temporary directory %s: %s", p->tmp, strerror(errno));
  if (mark(r, p->tmp, 1) != 0) return rmdir(p->tmp), -1;
  arm(p->tmp, m);
  int written = write_contents(r, p->tmp, m);
  if (written == 0) test_point("manifest");
  disarm();
  bool discard = true;
  int rc = written == 0 ? swap_in(r, p, exists, &discard) : -1;
  char ignored[16];
  StoreReport quiet = {ERR_OF(ignored, sizeof ignored)};
  /* The temporary directory holds only our files; its removal cannot make
   * things worse, and its message is less useful than the first one. */
  if (rc != 0 && discard) remove_store_dir(&quiet, p->tmp);
  /* whichever model `dir` holds now is kept: not a leftover */
  if (written == 0) mark(&quiet, p->dir, 0);
  return rc;
}

int model_store_write(const char *dir_arg, const ModelStore *m, Err *err) {
  StoreReport r = {err};
  if (err_held(err)) err->msg[0] = '\0';
  if (!dir_arg || !*dir_arg) return model_store_fail(&r, "(model directory)", 0, "the directory name is empty");
  Scratch sc = SCRATCH_OF(NULL);
  const char *dir = scratch_adopt(&sc, model_store_normalize_dir(dir_arg));
  long pid = (long)getpid();
  StorePaths p = {dir, dir ? scratch_adopt(&sc, model_store_printf("%s.tmp.%ld", dir, pid)) : NULL,
                  dir ? scratch_adopt(&sc, model_store_printf("%s.old.%ld", dir, pid)) : NULL,
                  dir ? scratch_adopt(&sc, parent_of(dir)) : NULL};
  int rc = p.dir && p.tmp && p.old && p.parent ? write_store(&r, &p, m)
                                               : model_store_fail(&r, dir_arg, 0, "out of memory");
  scratch_release(&sc);
  return rc;
}
