/* model_store.c — MODEL/ directories: a text manifest and one .npy per array
 * (see model_store.h for the manifest's format): the store in memory and
 * reading it back. Writing and the directories are model_store_dir.c.
 *
 * Reading trusts nothing: every manifest line is parsed strictly, and every
 * array file is hashed against its checksum before npy_read sees it, so a
 * corrupted, truncated, missing or swapped file is named rather than loaded.
 */
#define _POSIX_C_SOURCE 200809L

#include "model_store_impl.h"
#include "alloc.h" /* mem_malloc: allocation through the hook */
#include "scratch.h"

#include <errno.h>
#include <inttypes.h>
#include <limits.h>
#include <stdbool.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* ---------------------------------------------------------------- errors */


/* "<path>: <problem>", or "<path>:<line>: <problem>" when `line` > 0. */
__attribute__((format(printf, 4, 5))) int model_store_fail(const StoreReport *r, const char *path, int line,
                                                      const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  npy_vfail(ERR_MSG(r->err), ERR_LEN(r->err), path, line, fmt, ap);
  va_end(ap);
  return -1;
}

/* `s` printable in a message (npy_excerpt). `buf` holds NPY_EXCERPT_SIZE. */
const char *model_store_excerpt(char *buf, const char *s) { return npy_excerpt(buf, s, strlen(s)); }

/* A malloc'd vprintf, or NULL when out of memory. */
static char *str_vprintf(const char *fmt, va_list ap) {
  va_list ap2;
  va_copy(ap2, ap);
  int n = vsnprintf(NULL, 0, fmt, ap);
  char *s = n < 0 ? NULL : mem_malloc((size_t)n + 1);
  if (s) vsnprintf(s, (size_t)n + 1, fmt, ap2);
  va_end(ap2);
  return s;
}

/* A malloc'd printf, or NULL when out of memory. */
__attribute__((format(printf, 1, 2))) char *model_store_printf(const char *fmt, ...) {
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
int model_store_hash_file(const StoreReport *r, const char *path, uint64_t *h) {
  FILE *f = fopen(path, "rb");
  if (!f) return model_store_fail(r, path, 0, "cannot open: %s", strerror(errno));
  unsigned char buf[1 << 14];
  uint64_t acc = model_hash_init();
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, f)) > 0) acc = model_hash_bytes(acc, buf, n);
  int bad = ferror(f);
  int saved = errno;
  fclose(f);
  if (bad) return model_store_fail(r, path, 0, "cannot read: %s", strerror(saved));
  *h = acc;
  return 0;
}

/* ---------------------------------------------------------------- names, lines, shapes */

/* An array name: [A-Za-z0-9_.-]+, not starting with '.', so it is one file
 * name in the model directory, never hidden, never "." or "..". */
int model_store_valid_name(const char *s) {
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
int model_store_valid_meta(const char *line) {
  return line && *line && *line != ' ' && *line != '\t' && !strchr(line, '\n') && !key_is(line, FORMAT_WORD) &&
         !key_is(line, "program") && !key_is(line, "array") && !key_is(line, "file") && !key_is(line, "manifest");
}

/* `shape` as "3x4" ("5" for one dim, "()" for none) into `buf` (SHAPE_TEXT). */
const char *model_store_format_shape(char *buf, int ndim, const long *shape) {
  if (ndim == 0) return strcpy(buf, "()");
  size_t o = 0;
  for (int i = 0; i < ndim; i++) o += (size_t)snprintf(buf + o, SHAPE_TEXT - o, i ? "x%ld" : "%ld", shape[i]);
  return buf;
}

/* The inverse of model_store_format_shape: 0, or -1 if `s` is not a shape. */
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
int model_store_parse_hex64(const char *s, uint64_t *v) {
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
int model_store_shape_count(int ndim, const long *shape, size_t *count) {
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
    if (!m->arrays[i].borrowed) npy_free(&m->arrays[i].a);
  }
  free(m->arrays);
  for (int i = 0; i < m->ntexts; i++) free(m->texts[i].name), free(m->texts[i].text);
  free(m->texts);
  model_store_init(m);
}

/* Append the malloc'd metadata line `line` (taken over: freed when it is no metadata line,
 * model_store_valid_meta, or on failure). */
static int append_meta(ModelStore *m, char *line) {
  char **grown = model_store_valid_meta(line) ? mem_realloc(m->meta, ((size_t)m->nmeta + 1) * sizeof *grown) : NULL;
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
  return line ? append_meta(m, line) : -1;
}

static int find_array(const ModelStore *m, const char *name) {
  for (int i = 0; i < m->narrays; i++)
    if (strcmp(m->arrays[i].name, name) == 0) return i;
  return -1;
}

/* Append `name` with the array `a` (taken over: freed on failure). The list grows first, so
 * the name's copy is the last thing that can fail. */
static int append_array(ModelStore *m, const char *name, NpyArray *a, uint64_t checksum) {
  ModelArray *grown = mem_realloc(m->arrays, ((size_t)m->narrays + 1) * sizeof *grown);
  if (grown) m->arrays = grown;
  char *copy = grown ? mem_strdup(name) : NULL;
  if (!copy) {
    npy_free(a);
    return -1;
  }
  m->arrays[m->narrays++] = (ModelArray){copy, *a, checksum, false};
  memset(a, 0, sizeof *a);
  return 0;
}

int model_store_add(ModelStore *m, const char *name, int ndim, const long *shape, const double *data) {
  size_t count;
  if (!model_store_valid_name(name) || find_array(m, name) >= 0 || ndim < 0 || ndim > NPY_MAX_DIMS ||
      (ndim > 0 && !shape) || model_store_shape_count(ndim, shape, &count) != 0 || (count && !data))
    return -1;
  NpyArray a = {.type = NPY_F64, .ndim = ndim, .count = count};
  for (int i = 0; i < ndim; i++) a.shape[i] = shape[i];
  a.data = mem_malloc(count ? count * sizeof(double) : 1);
  if (!a.data) return -1;
  if (count) memcpy(a.data, data, count * sizeof(double));
  return append_array(m, name, &a, 0);
}

int model_store_add_borrowed(ModelStore *m, const char *name, int ndim, const long *shape, const double *data) {
  size_t count;
  if (!model_store_valid_name(name) || find_array(m, name) >= 0 || ndim < 0 || ndim > NPY_MAX_DIMS ||
      (ndim > 0 && !shape) || model_store_shape_count(ndim, shape, &count) != 0 || !count || !data)
    return -1;
  NpyArray a = {.type = NPY_F64, .ndim = ndim, .count = count, .data = (void *)data};
  for (int i = 0; i < ndim; i++) a.shape[i] = shape[i];
  if (append_array(m, name, &a, 0)) return -1;
  m->arrays[m->narrays - 1].borrowed = true;
  return 0;
}

/* A text file's name: an array name ending in ".csv". */
static int valid_text_name(const char *name) {
  size_t n = name ? strlen(name) : 0;
  return model_store_valid_name(name) && n > 4 && strcmp(name + n - 4, ".csv") == 0;
}

static int append_text(ModelStore *m, const char *name, const char *text, size_t len, uint64_t checksum) {
  Scratch sc = SCRATCH_OF(NULL);
  char *n = scratch_adopt(&sc, mem_strdup(name)), *t = scratch_adopt(&sc, mem_malloc(len + 1));
  ModelText *grown = n && t ? mem_realloc(m->texts, ((size_t)m->ntexts + 1) * sizeof *grown) : NULL;
  if (grown) {
    memcpy(t, text, len);
    t[len] = '\0';
    m->texts = grown;
    m->texts[m->ntexts++] = (ModelText){scratch_keep(&sc, n), scratch_keep(&sc, t), checksum}; /* the store's now */
  }
  scratch_release(&sc);
  return grown ? 0 : -1;
}

int model_store_add_text(ModelStore *m, const char *name, const char *text) {
  if (!valid_text_name(name) || !text) return -1;
  for (int i = 0; i < m->ntexts; i++)
    if (strcmp(m->texts[i].name, name) == 0) return -1;
  return append_text(m, name, text, strlen(text), 0);
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
int model_store_slurp(const StoreReport *r, const char *path, char **text, size_t *len) {
  FILE *f = fopen(path, "rb");
  if (!f) return model_store_fail(r, path, 0, "cannot open: %s", strerror(errno));
  size_t cap = 4096, n = 0;
  char *buf = mem_malloc(cap + 1);
  int rc = buf ? 0 : model_store_fail(r, path, 0, "out of memory");
  while (rc == 0) {
    n += fread(buf + n, 1, cap - n, f);
    if (ferror(f)) rc = model_store_fail(r, path, 0, "cannot read: %s", strerror(errno));
    else if (n < cap) break;
    else if (cap >= MANIFEST_MAX) rc = model_store_fail(r, path, 0, "larger than %zu bytes: not a model manifest", MANIFEST_MAX);
    else {
      char *grown = mem_realloc(buf, 2 * cap + 1);
      if (!grown) rc = model_store_fail(r, path, 0, "out of memory");
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
static int parse_array_line(const StoreReport *r, const char *mpath, int ln, char *line, Listed *x) {
  char *w[5], buf[NPY_EXCERPT_SIZE];
  if (split_words(line, w, 5) != 5)
    return model_store_fail(r, mpath, ln, "expected 'array <name>.npy <shape> " CHECKSUM_KIND " <16 hex digits>'");
  size_t n = strlen(w[1]);
  if (n <= 4 || strcmp(w[1] + n - 4, ".npy") != 0)
    return model_store_fail(r, mpath, ln, "array file '%s' does not end in .npy", model_store_excerpt(buf, w[1]));
  w[1][n - 4] = '\0';
  if (!model_store_valid_name(w[1])) return model_store_fail(r, mpath, ln, "bad array name '%s'", model_store_excerpt(buf, w[1]));
  if (parse_shape(w[2], &x->ndim, x->shape) != 0)
    return model_store_fail(r, mpath, ln, "bad shape '%s' (expected sizes joined by 'x', like 3x4)", model_store_excerpt(buf, w[2]));
  if (strcmp(w[3], CHECKSUM_KIND) != 0)
    return model_store_fail(r, mpath, ln, "unknown checksum kind '%s' (expected " CHECKSUM_KIND ")", model_store_excerpt(buf, w[3]));
  if (model_store_parse_hex64(w[4], &x->checksum) != 0)
    return model_store_fail(r, mpath, ln, "bad checksum '%s' (expected 16 hex digits)", model_store_excerpt(buf, w[4]));
  x->name = w[1];
  x->line = ln;
  return 0;
}

/* What a manifest lists besides its metadata: its array and file lines
 * (room for one a line, listing_room), and the checksum line when the lines
 * before it do not hash to it (else 0). */
typedef struct Listing {
  Listed *listed;
  int nlisted;
  int changed_line;
} Listing;

/* Room in `sc` for a Listed per line of the manifest `text` (NULL: out of memory). */
static Listed *listing_room(Scratch *sc, const char *text, size_t len) {
  size_t lines = 1;
  for (const char *p = text; (p = memchr(p, '\n', (size_t)(text + len - p))); p++) lines++;
  return scratch_array(sc, lines, sizeof(Listed));
}

/* Parse the manifest `text` (modified in place: lines and words are cut out
 * of it) of file `mpath`: its program hash and metadata lines into `m`, the
 * rest into `out` (whose `listed` has room for a line each). */
static int parse_manifest(const StoreReport *r, const char *mpath, char *text, size_t len, ModelStore *m,
                          Listing *out) {
  char buf[NPY_EXCERPT_SIZE];
  int program_line = 0, ln = 0, checksum_line = 0;
  /* the hash of the bytes before the last line, which must be its checksum */
  size_t body = len;
  while (body > 0 && text[body - 1] == '\n') body--;
  while (body > 0 && text[body - 1] != '\n') body--;
  uint64_t expect = 0, actual = model_hash_bytes(model_hash_init(), text, body);
  out->nlisted = 0;
  if (len == 0) return model_store_fail(r, mpath, 1, "empty file: not a model manifest (expected '" FORMAT_LINE "')");
  for (char *line = text; line < text + len;) {
    char *nl = memchr(line, '\n', (size_t)(text + len - line));
    ln++;
    if (!nl) return model_store_fail(r, mpath, ln, "last line has no newline: the file was cut short?");
    *nl = '\0';
    char *next = nl + 1;
    if (strlen(line) != (size_t)(nl - line)) return model_store_fail(r, mpath, ln, "line holds a NUL byte");
    int version = 0, vend = 0;
    if (ln == 1 && (sscanf(line, FORMAT_WORD " %d%n", &version, &vend) != 1 || line[vend] || version < 1 ||
                    version > FORMAT_MAX || strncmp(line, FORMAT_WORD " ", strlen(FORMAT_WORD) + 1) != 0 ||
                    !(line[strlen(FORMAT_WORD) + 1] >= '1' && line[strlen(FORMAT_WORD) + 1] <= '9'))) {
      if (key_is(line, FORMAT_WORD))
        return model_store_fail(r, mpath, ln,
                                "model format '%s' is not supported (this npgc reads '" FORMAT_LINE "' to '" FORMAT_LINE_MAX
                                "': a newer npgc wrote it?)",
                    model_store_excerpt(buf, line));
      return model_store_fail(r, mpath, ln, "not a model manifest: first line is '%s', expected '" FORMAT_LINE "'",
                  model_store_excerpt(buf, line));
    } else if (ln == 1) {
      m->format = version;
    } else if (key_is(line, FORMAT_WORD)) {
      return model_store_fail(r, mpath, ln, "'" FORMAT_WORD "' may only be the first line");
    } else if (key_is(line, "manifest")) {
      char *w[3];
      if (next != text + len) return model_store_fail(r, mpath, ln, "the 'manifest' checksum line must be the last");
      if (split_words(line, w, 3) != 3 || strcmp(w[1], CHECKSUM_KIND) != 0 || model_store_parse_hex64(w[2], &expect) != 0)
        return model_store_fail(r, mpath, ln, "expected 'manifest " CHECKSUM_KIND " <16 hex digits>'");
      checksum_line = ln;
    } else if (key_is(line, "program")) {
      char *w[2];
      if (program_line) return model_store_fail(r, mpath, ln, "second 'program' line (the first is line %d)", program_line);
      if (split_words(line, w, 2) != 2 || model_store_parse_hex64(w[1], &m->program_hash) != 0)
        return model_store_fail(r, mpath, ln, "expected 'program <16 hex digits>'");
      program_line = ln;
    } else if (key_is(line, "array")) {
      Listed x;
      if (parse_array_line(r, mpath, ln, line, &x)) return -1;
      for (int i = 0; i < out->nlisted; i++)
        if (strcmp(out->listed[i].name, x.name) == 0)
          return model_store_fail(r, mpath, ln, "array %s.npy listed twice (first on line %d)", x.name, out->listed[i].line);
      out->listed[out->nlisted++] = x;
    } else if (key_is(line, "file")) {
      /* file <name>.csv fnv1a64 <16 hex digits>: kept as a Listed with ndim -1 */
      char *w[4];
      Listed x = {0};
      if (split_words(line, w, 4) != 4 || !valid_text_name(w[1]) || strcmp(w[2], CHECKSUM_KIND) != 0 ||
          model_store_parse_hex64(w[3], &x.checksum) != 0)
        return model_store_fail(r, mpath, ln, "expected 'file <name>.csv " CHECKSUM_KIND " <16 hex digits>'");
      x.name = w[1];
      x.ndim = -1;
      x.line = ln;
      for (int i = 0; i < out->nlisted; i++)
        if (strcmp(out->listed[i].name, x.name) == 0)
          return model_store_fail(r, mpath, ln, "file %s listed twice (first on line %d)", x.name, out->listed[i].line);
      out->listed[out->nlisted++] = x;
    } else if (*line == '\0') {
      return model_store_fail(r, mpath, ln, "empty line");
    } else if (*line == ' ' || *line == '\t') {
      return model_store_fail(r, mpath, ln, "line starts with a space (expected 'key value...')");
    } else {
      char *copy = mem_strdup(line);
      if (!copy || append_meta(m, copy) != 0) return model_store_fail(r, mpath, 0, "out of memory");
    }
    line = next;
  }
  if (!program_line) return model_store_fail(r, mpath, 0, "no 'program' line");
  if (!checksum_line)
    return model_store_fail(r, mpath, 0, "no 'manifest' checksum line: cut short, or written by an older npg (retrain)");
  /* compared by the caller once the arrays are checked: a changed file is
   * named as such even when its manifest line was changed to match */
  out->changed_line = expect != actual ? checksum_line : 0;
  return 0;
}

/* Check and load the text file `x` of directory `dir` into `m`. */
static int load_text(const StoreReport *r, const char *dir, const Listed *x, ModelStore *m) {
  Scratch sc = SCRATCH_OF(NULL);
  char *path = scratch_printf(&sc, "%s/%s", dir, x->name), *text = NULL;
  uint64_t h;
  size_t len = 0;
  int rc = path ? model_store_hash_file(r, path, &h) : model_store_fail(r, dir, 0, "out of memory");
  if (rc == 0 && h != x->checksum)
    rc = model_store_fail(r, path, 0, "checksum mismatch: the file is corrupted or was changed after training");
  if (rc == 0) rc = model_store_slurp(r, path, &text, &len);
  if (rc == 0 && !scratch_adopt(&sc, text)) rc = model_store_fail(r, path, 0, "out of memory");
  if (rc == 0 && append_text(m, x->name, text, len, h) != 0) rc = model_store_fail(r, path, 0, "out of memory");
  scratch_release(&sc);
  return rc;
}

/* Check and load the array file `x` of directory `dir` into `m`. */
static int load_array(const StoreReport *r, const char *dir, const Listed *x, ModelStore *m) {
  if (x->ndim < 0) return load_text(r, dir, x, m);
  Scratch sc = SCRATCH_OF(NULL);
  char *path = scratch_printf(&sc, "%s/%s.npy", dir, x->name);
  uint64_t h;
  NpyArray a = {0};
  char got[SHAPE_TEXT], want[SHAPE_TEXT];
  /* a file far larger than its shape allows (a sparse 8 GB file) is refused
   * before it is hashed: hashing it would take minutes */
  struct stat st;
  size_t count = 0;
  int rc = path ? 0 : model_store_fail(r, dir, 0, "out of memory");
  if (rc == 0 && stat(path, &st) == 0 && S_ISREG(st.st_mode) && model_store_shape_count(x->ndim, x->shape, &count) == 0 &&
      (uintmax_t)st.st_size > (uintmax_t)count * sizeof(double) + NPY_HEADER_MAX + 16)
    rc = model_store_fail(r, path, 0, "%jd bytes, more than an array of shape %s can take: the file is damaged or not "
                                      "the model's", (intmax_t)st.st_size, model_store_format_shape(want, x->ndim, x->shape));
  if (rc == 0) rc = model_store_hash_file(r, path, &h);
  if (rc == 0 && h != x->checksum)
    rc = model_store_fail(r, path, 0, "checksum mismatch: the file is corrupted or was changed after training");
  if (rc == 0) rc = npy_read(path, &a, ERR_MSG(r->err), ERR_LEN(r->err)) != 0 ? -1 : 0;
  if (rc == 0 && a.type != NPY_F64)
    rc = model_store_fail(r, path, 0, "holds %s elements; a model holds float64", npy_type_name(a.type));
  if (rc == 0 && (a.ndim != x->ndim || memcmp(a.shape, x->shape, (size_t)a.ndim * sizeof *a.shape) != 0))
    rc = model_store_fail(r, path, 0, "shape %s, manifest says %s", model_store_format_shape(got, a.ndim, a.shape),
              model_store_format_shape(want, x->ndim, x->shape));
  if (rc == 0 && append_array(m, x->name, &a, h) != 0) rc = model_store_fail(r, path, 0, "out of memory");
  npy_free(&a);
  scratch_release(&sc);
  return rc;
}

static int read_store(const char *dir_arg, bool check_program, uint64_t expect_program_hash, ModelStore *m, Err *err);

int model_store_read(const char *dir, uint64_t expect_program_hash, ModelStore *m, Err *err) {
  return read_store(dir, true, expect_program_hash, m, err);
}

int model_store_read_any(const char *dir, ModelStore *m, Err *err) {
  return read_store(dir, false, 0, m, err);
}

/* Test hook: NPG_TEST_REPLACE_DURING_LOAD=OTHER swaps the model being read
 * with the folder OTHER, once, after its manifest was read: what a training
 * of the same model in another process does to a model being loaded. */
static void test_replace(const char *dir) {
  static bool done;
  const char *other = getenv("NPG_TEST_REPLACE_DURING_LOAD");
  if (done || !other || !*other) return;
  done = true;
  Scratch sc = SCRATCH_OF(NULL);
  char *aside = scratch_printf(&sc, "%s.swap", dir);
  if (aside && rename(dir, aside) == 0 && rename(other, dir) == 0) rename(aside, other);
  scratch_release(&sc);
}

static int read_once(const char *dir_arg, bool check_program, uint64_t expect_program_hash, ModelStore *m, Err *err);

/* A model replaced while it is read (a training writing it: the store swaps
 * whole folders) fails its checksums half way; issue 24: that was reported
 * as a corrupted file. The folder's identity tells: read once more, and say
 * what happened if it changes again. */
static int read_store(const char *dir_arg, bool check_program, uint64_t expect_program_hash, ModelStore *m, Err *err) {
  for (int attempt = 0;; attempt++) {
    struct stat before, after;
    bool known = dir_arg && *dir_arg && stat(dir_arg, &before) == 0;
    int rc = read_once(dir_arg, check_program, expect_program_hash, m, err);
    if (rc == 0 || !known || stat(dir_arg, &after) != 0 || (after.st_ino == before.st_ino && after.st_dev == before.st_dev))
      return rc;
    if (attempt > 0) {
      StoreReport r = {err};
      return model_store_fail(&r, dir_arg, 0, "the model was replaced while it was being read, twice (a training is "
                              "writing it): load it when that training is done");
    }
  }
}

static int read_once(const char *dir_arg, bool check_program, uint64_t expect_program_hash, ModelStore *m, Err *err) {
  StoreReport r = {err};
  if (err_held(err)) err->msg[0] = '\0';
  model_store_init(m);
  if (!dir_arg || !*dir_arg) return model_store_fail(&r, "(model directory)", 0, "the directory name is empty");
  Scratch sc = SCRATCH_OF(NULL);
  char *dir = scratch_adopt(&sc, model_store_normalize_dir(dir_arg));
  if (dir) model_store_recover(dir, 0);
  char *mpath = dir ? scratch_printf(&sc, "%s/manifest", dir) : NULL;
  char *text = NULL;
  size_t len = 0;
  Listing ls = {0};
  int rc = 0;
  if (!mpath) rc = model_store_fail(&r, dir_arg, 0, "out of memory");
  if (rc == 0) rc = model_store_slurp(&r, mpath, &text, &len);
  if (rc == 0 && (!scratch_adopt(&sc, text) || !(ls.listed = listing_room(&sc, text, len))))
    rc = model_store_fail(&r, mpath, 0, "out of memory");
  if (rc == 0) rc = parse_manifest(&r, mpath, text, len, m, &ls);
  if (rc == 0 && check_program && m->program_hash != expect_program_hash)
    rc = model_store_fail(&r, mpath, 0,
              "model was trained for another program (program hash %016" PRIx64 ", this program %016" PRIx64
              "): retrain",
              m->program_hash, expect_program_hash);
  if (rc == 0) test_replace(dir);
  for (int i = 0; i < ls.nlisted && rc == 0; i++) rc = load_array(&r, dir, &ls.listed[i], m);
  if (rc == 0 && ls.changed_line)
    rc = model_store_fail(&r, mpath, ls.changed_line, "checksum mismatch: the manifest was changed after training");
  if (rc) model_store_free(m);
  scratch_release(&sc);
  return rc;
}
