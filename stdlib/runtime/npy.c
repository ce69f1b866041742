/* npy.c — reading and writing NumPy .npy files (see npy.h for the format).
 *
 * The reader trusts nothing in the file: every length is checked against
 * what the file holds before anything is allocated, and the header dict —
 * a Python literal that numpy itself reads with ast.literal_eval — is parsed
 * by hand without recursion, so no input can exhaust the stack, read out of
 * bounds or make us allocate more than the file holds. The writer reproduces
 * numpy.save's bytes exactly, so a file npgc writes is indistinguishable from
 * one the user made with numpy.
 */
#define _POSIX_C_SOURCE 200809L /* fileno, fstat, fsync, getpid */

#include "npy.h"
#include "alloc.h" /* mem_malloc: allocation through the hook */

#include <errno.h>
#include <limits.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define MAGIC "\x93NUMPY"
#define MAGIC_LEN 6

/* numpy.load refuses longer headers by default (format._MAX_HEADER_SIZE);
 * ours never exceed a few hundred bytes, and the cap bounds what a corrupted
 * length field can make us allocate. */
#define HEADER_MAX NPY_HEADER_MAX

/* numpy.save pads the header so the data starts on this boundary
 * (format.ARRAY_ALIGN), and leaves room after the dict for the first axis to
 * grow to this many digits (format.GROWTH_AXIS_MAX_DIGITS). */
#define ARRAY_ALIGN 64
#define GROWTH_AXIS_MAX_DIGITS 21

/* Files whose size is unknown (pipes) are read in pieces of at most this
 * many bytes, so a corrupted shape cannot make us allocate more than the
 * stream actually delivers. */
#define READ_CHUNK ((size_t)1 << 20)

static const struct {
  const char *kind; /* descr without its byte-order mark */
  NpyType type;
  size_t size;
  const char *name;
} types[] = {
    {"f8", NPY_F64, 8, "float64"},
    {"i4", NPY_I32, 4, "int32"},
    {"i8", NPY_I64, 8, "int64"},
};
#define NTYPES (sizeof types / sizeof *types)

#define SUPPORTED "(supported: '<f8' float64, '<i4' int32, '<i8' int64)"

const char *npy_type_name(NpyType t) {
  for (size_t i = 0; i < NTYPES; i++)
    if (types[i].type == t) return types[i].name;
  return "unknown";
}

void npy_free(NpyArray *a) {
  if (!a) return;
  free(a->data);
  memset(a, 0, sizeof *a);
}

/* ---------------------------------------------------------------- errors */

/* Where a message goes: every message is "<path>: <problem>". */
typedef struct Report {
  const char *path;
  char *err;
  size_t errlen;
} Report;

int npy_vfail(char *err, size_t errlen, const char *path, int line, const char *fmt, va_list ap) {
  if (!err || errlen == 0) return -1;
  int n = line > 0 ? snprintf(err, errlen, "%s:%d: ", path, line) : snprintf(err, errlen, "%s: ", path);
  if (n >= 0 && (size_t)n < errlen) vsnprintf(err + n, errlen - (size_t)n, fmt, ap);
  return -1;
}

__attribute__((format(printf, 2, 3))) static int fail(const Report *r, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  npy_vfail(r->err, r->errlen, r->path, 0, fmt, ap);
  va_end(ap);
  return -1;
}

const char *npy_excerpt(char *buf, const char *s, size_t n) {
  size_t o = 0;
  for (size_t i = 0; i < n && i < 40; i++) {
    unsigned char c = (unsigned char)s[i];
    if (c >= 0x20 && c < 0x7f) buf[o++] = (char)c;
    else o += (size_t)snprintf(buf + o, 5, "\\x%02x", c);
  }
  if (n > 40) o += (size_t)snprintf(buf + o, 4, "...");
  buf[o] = '\0';
  return buf;
}

/* ---------------------------------------------------------------- byte order */

static int host_is_little_endian(void) {
  const uint16_t one = 1;
  unsigned char first;
  memcpy(&first, &one, 1);
  return first == 1;
}

/* Reverse the bytes of each of the `count` `size`-byte elements of `p`. */
static void swap_bytes(unsigned char *p, size_t count, size_t size) {
  for (size_t i = 0; i < count; i++, p += size)
    for (size_t a = 0, b = size - 1; a < b; a++, b--) {
      unsigned char t = p[a];
      p[a] = p[b];
      p[b] = t;
    }
}

/* ---------------------------------------------------------------- header dict */

typedef struct Span {
  const char *s;
  size_t n;
} Span;

/* The three values of a header, as text, not yet interpreted. */
typedef struct HeaderDict {
  Span descr, fortran_order, shape;
  int seen[3];
} HeaderDict;

static const char *const keys[3] = {"descr", "fortran_order", "shape"};

static int is_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v'; }

/* Characters of numbers and names: 3, -3, 3.5, 1e9, 3L, True, None. */
static int is_bare(char c) {
  return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' || c == '.' ||
         c == '+' || c == '-';
}

static const char *skip_space(const char *p, const char *end) {
  while (p < end && is_space(*p)) p++;
  return p;
}

/* A Python string literal at `p` ('...' or "...", backslash escapes, on one
 * line): the byte after its closing quote, or NULL if it does not end. */
static const char *skip_string(const char *p, const char *end) {
  char quote = *p++;
  while (p < end) {
    if (*p == '\\') {
      if (end - p < 2) return NULL;
      p += 2;
    } else if (*p == quote) {
      return p + 1;
    } else if (*p == '\n') {
      return NULL;
    } else {
      p++;
    }
  }
  return NULL;
}

/* One Python literal at `p` — a string, a bare word or number, or a
 * bracketed group with balanced (), [], {} — returning the byte after it or
 * NULL. Only the brackets are checked here; what the value means is decided
 * by its key. Nesting is bounded, with an explicit stack, so hostile input
 * cannot exhaust the C stack. */
static const char *skip_value(const char *p, const char *end) {
  char closers[32];
  size_t depth = 0;
  do {
    if (p >= end) return NULL;
    char c = *p;
    if (c == '\'' || c == '"') {
      p = skip_string(p, end);
      if (!p) return NULL;
    } else if (c == '(' || c == '[' || c == '{') {
      if (depth == sizeof closers) return NULL;
      closers[depth++] = c == '(' ? ')' : c == '[' ? ']' : '}';
      p++;
    } else if (c == ')' || c == ']' || c == '}') {
      if (depth == 0 || closers[depth - 1] != c) return NULL;
      depth--;
      p++;
    } else if (is_bare(c)) {
      while (p < end && is_bare(*p)) p++;
    } else if (depth > 0 && (c == ',' || c == ':' || is_space(c))) {
      p++;
    } else {
      return NULL;
    }
  } while (depth > 0);
  return p;
}

static int malformed(const Report *r, const char *header, const char *at, const char *problem) {
  return fail(r, "malformed header dict at byte %zu: %s", (size_t)(at - header), problem);
}

/* dict := '{' (string ':' value ',')* [string ':' value] '}'   (spaces anywhere)
 * Exactly the keys 'descr', 'fortran_order' and 'shape', each once, as
 * numpy.load demands; only spaces may follow the '}' (numpy's padding). */
static int parse_dict(const Report *r, const char *header, size_t len, HeaderDict *d) {
  const char *end = header + len, *p = skip_space(header, end);
  char buf[NPY_EXCERPT_SIZE];
  if (p == end) return fail(r, "header is not a dict: it is blank");
  if (*p != '{') return fail(r, "header is not a dict: %s", npy_excerpt(buf, p, (size_t)(end - p)));
  p++;
  for (;;) {
    p = skip_space(p, end);
    if (p < end && *p == '}') break;
    if (p == end || (*p != '\'' && *p != '"')) return malformed(r, header, p, "expected a quoted key or '}'");
    const char *key = p;
    p = skip_string(p, end);
    if (!p) return malformed(r, header, key, "unterminated string");
    Span name = {key + 1, (size_t)(p - key) - 2};
    int k = 0;
    while (k < 3 && !(strlen(keys[k]) == name.n && memcmp(keys[k], name.s, name.n) == 0)) k++;
    if (k == 3) return fail(r, "header has unexpected key %s", npy_excerpt(buf, key, (size_t)(p - key)));
    if (d->seen[k]) return fail(r, "header has key '%s' twice", keys[k]);
    d->seen[k] = 1;
    p = skip_space(p, end);
    if (p == end || *p != ':') return malformed(r, header, p, "expected ':'");
    const char *value = skip_space(p + 1, end);
    p = skip_value(value, end);
    if (!p) {
      char problem[64];
      snprintf(problem, sizeof problem, "cannot parse the value of '%s'", keys[k]);
      return malformed(r, header, value, problem);
    }
    Span *slot = k == 0 ? &d->descr : k == 1 ? &d->fortran_order : &d->shape;
    *slot = (Span){value, (size_t)(p - value)};
    p = skip_space(p, end);
    if (p < end && *p == ',') {
      p++;
    } else if (p == end || *p != '}') {
      return malformed(r, header, p, "expected ',' or '}'");
    }
  }
  p = skip_space(p + 1, end);
  if (p != end) return malformed(r, header, p, "unexpected text after '}'");
  for (int k = 0; k < 3; k++)
    if (!d->seen[k]) return fail(r, "header has no '%s' key", keys[k]);
  return 0;
}

/* The descr string: one of ours with '<' or '=' order, else a message that
 * names what the file holds. `*swap` says the data must be byte-swapped for
 * this host. */
static int parse_descr(const Report *r, Span v, NpyType *type, size_t *size, int *swap) {
  char buf[NPY_EXCERPT_SIZE];
  if (v.n == 5 && (v.s[0] == '\'' || v.s[0] == '"')) {
    const char *s = v.s + 1; /* e.g. <f8 */
    for (size_t i = 0; i < NTYPES; i++) {
      if (memcmp(s + 1, types[i].kind, 2) != 0) continue;
      if (s[0] == '<' || s[0] == '=') {
        *type = types[i].type;
        *size = types[i].size;
        *swap = s[0] == '<' && !host_is_little_endian();
        return 0;
      }
      if (s[0] == '>')
        return fail(r, "big-endian dtype '>%s' is not supported; convert with a.astype('<%s')", types[i].kind,
                    types[i].kind);
    }
  }
  return fail(r, "unsupported dtype %s " SUPPORTED, npy_excerpt(buf, v.s, v.n));
}

static int parse_fortran_order(const Report *r, Span v, int *fortran) {
  char buf[NPY_EXCERPT_SIZE];
  if (v.n == 4 && memcmp(v.s, "True", 4) == 0) *fortran = 1;
  else if (v.n == 5 && memcmp(v.s, "False", 5) == 0) *fortran = 0;
  else return fail(r, "'fortran_order' is not True or False: %s", npy_excerpt(buf, v.s, v.n));
  return 0;
}

/* A Python int literal as numpy writes it: optional sign, decimal digits
 * (with '_' between digits, as Python 3 allows), and in format 1.0/2.0 an
 * 'L' suffix, which Python 2 numpy wrote and numpy.load still strips. */
static int parse_dim(const Report *r, Span v, int allow_long_suffix, long *dim) {
  char buf[NPY_EXCERPT_SIZE];
  const char *p = v.s, *end = v.s + v.n;
  int negative = 0;
  if (p < end && (*p == '+' || *p == '-')) negative = *p++ == '-';
  if (allow_long_suffix && end > p && (end[-1] == 'L' || end[-1] == 'l')) end--;
  unsigned long value = 0;
  int overflow = 0, digits = 0;
  for (; p < end; p++) {
    if (*p == '_' && digits && p + 1 < end && p[1] >= '0' && p[1] <= '9') continue;
    if (*p < '0' || *p > '9') return fail(r, "shape entry %s is not an integer", npy_excerpt(buf, v.s, v.n));
    unsigned d = (unsigned)(*p - '0');
    if (value > ((unsigned long)LONG_MAX - d) / 10) overflow = 1;
    else value = value * 10 + d;
    digits++;
  }
  if (!digits) return fail(r, "shape entry %s is not an integer", npy_excerpt(buf, v.s, v.n));
  if (negative && value != 0) return fail(r, "shape entry %s is negative", npy_excerpt(buf, v.s, v.n));
  if (overflow) return fail(r, "shape entry %s is too large", npy_excerpt(buf, v.s, v.n));
  *dim = (long)value;
  return 0;
}

/* The items of a tuple literal `v` into `items` (the first NPY_MAX_DIMS of
 * them) and their number into `*nitems`; 0 if `v` is not a tuple.
 *   tuple := '(' ')' | '(' value ',' ')' | '(' value (',' value)+ [','] ')'
 * "(5)" is the int 5, not a tuple (numpy.load refuses it too). */
static int split_tuple(Span v, Span *items, size_t *nitems) {
  if (v.n < 2 || v.s[0] != '(' || v.s[v.n - 1] != ')') return 0;
  const char *end = v.s + v.n - 1, *p = skip_space(v.s + 1, end);
  int trailing_comma = 0;
  *nitems = 0;
  while (p < end) {
    const char *item = p;
    p = skip_value(p, end);
    if (!p) return 0;
    if (*nitems < NPY_MAX_DIMS) items[*nitems] = (Span){item, (size_t)(p - item)};
    ++*nitems;
    p = skip_space(p, end);
    trailing_comma = p < end && *p == ',';
    if (trailing_comma) p = skip_space(p + 1, end);
    else if (p < end) return 0;
  }
  return *nitems != 1 || trailing_comma;
}

/* The shape tuple into `a`'s ndim, shape and count, checking that `count`
 * elements of `size` bytes can be addressed. */
static int parse_shape(const Report *r, Span v, int allow_long_suffix, size_t size, NpyArray *a) {
  char buf[NPY_EXCERPT_SIZE];
  Span items[NPY_MAX_DIMS];
  size_t nitems;
  if (!split_tuple(v, items, &nitems))
    return fail(r, "'shape' is not a tuple of integers: %s", npy_excerpt(buf, v.s, v.n));
  if (nitems > NPY_MAX_DIMS)
    return fail(r, "shape %s has %zu dimensions; at most %d are supported", npy_excerpt(buf, v.s, v.n), nitems,
                NPY_MAX_DIMS);
  a->ndim = (int)nitems;
  int empty = 0;
  for (int i = 0; i < a->ndim; i++) {
    if (parse_dim(r, items[i], allow_long_suffix, &a->shape[i])) return -1;
    empty |= a->shape[i] == 0;
  }
  /* A zero extent makes the array empty whatever the other extents are. */
  a->count = empty ? 0 : 1;
  for (int i = 0; i < a->ndim && !empty; i++) {
    if ((size_t)a->shape[i] > SIZE_MAX / size / a->count)
      return fail(r, "shape %s has too many elements", npy_excerpt(buf, v.s, v.n));
    a->count *= (size_t)a->shape[i];
  }
  return 0;
}

/* The header text of `len` bytes: fills `a`'s type, ndim, shape and count. */
static int parse_header(const Report *r, const char *header, size_t len, int major, NpyArray *a, size_t *size,
                        int *swap) {
  HeaderDict d = {0};
  int fortran = 0;
  if (parse_dict(r, header, len, &d) || parse_descr(r, d.descr, &a->type, size, swap) ||
      parse_fortran_order(r, d.fortran_order, &fortran) || parse_shape(r, d.shape, major < 3, *size, a))
    return -1;
  /* Fortran order lays the data out differently only when two or more axes
   * have more than one entry; otherwise the bytes are the same as C order. */
  int long_axes = 0;
  for (int i = 0; i < a->ndim; i++) long_axes += a->shape[i] > 1;
  if (fortran && a->count > 0 && long_axes > 1)
    return fail(r, "Fortran-order arrays are not supported; save with numpy.ascontiguousarray");
  return 0;
}

/* ---------------------------------------------------------------- reading */

/* Read up to `n` bytes; short only at the end of the file or on an error,
 * which is reported. `*got` is what was read. */
static int read_bytes(const Report *r, FILE *f, void *buf, size_t n, size_t *got) {
  *got = fread(buf, 1, n, f);
  if (*got < n && ferror(f)) return fail(r, "cannot read: %s", strerror(errno));
  return 0;
}

static int read_data(const Report *r, FILE *f, size_t offset, size_t expected, void **data) {
  /* A regular file's size tells truncation and trailing bytes before we
   * allocate anything, so a corrupted shape costs no memory. */
  struct stat st;
  int sized = fstat(fileno(f), &st) == 0 && S_ISREG(st.st_mode);
  if (sized) {
    uintmax_t avail = (uintmax_t)st.st_size > offset ? (uintmax_t)st.st_size - offset : 0;
    if (avail < expected) return fail(r, "truncated: expected %zu bytes of data, found %ju", expected, avail);
    if (avail > expected) return fail(r, "trailing garbage: expected %zu bytes of data, found %ju", expected, avail);
  }
  size_t cap = sized || expected < READ_CHUNK ? expected : READ_CHUNK, got = 0;
  unsigned char *buf = mem_malloc(cap ? cap : 1);
  if (!buf) return fail(r, "out of memory for %zu bytes of data", expected);
  while (got < expected) {
    if (got == cap) {
      size_t grown = expected - cap < cap ? expected : 2 * cap;
      unsigned char *bigger = mem_realloc(buf, grown);
      if (!bigger) {
        free(buf);
        return fail(r, "out of memory for %zu bytes of data", expected);
      }
      buf = bigger;
      cap = grown;
    }
    size_t n;
    if (read_bytes(r, f, buf + got, cap - got, &n)) {
      free(buf);
      return -1;
    }
    got += n;
    if (got < cap) break;
  }
  /* Count what follows the data, for files we could not measure (or that
   * changed while we read them). */
  size_t extra = 0;
  unsigned char scratch[4096];
  for (;;) {
    size_t n;
    if (read_bytes(r, f, scratch, sizeof scratch, &n)) {
      free(buf);
      return -1;
    }
    extra += n;
    if (n < sizeof scratch) break;
  }
  if (got < expected) {
    free(buf);
    return fail(r, "truncated: expected %zu bytes of data, found %zu", expected, got);
  }
  if (extra) {
    free(buf);
    return fail(r, "trailing garbage: expected %zu bytes of data, found %zu", expected, expected + extra);
  }
  *data = buf;
  return 0;
}

static int read_npy(const Report *r, FILE *f, NpyArray *a) {
  /* prefix: magic, major, minor, header length (2 or 4 bytes) */
  unsigned char prefix[MAGIC_LEN + 2 + 4];
  size_t got;
  if (read_bytes(r, f, prefix, MAGIC_LEN + 2, &got)) return -1;
  if (got == 0) return fail(r, "empty file");
  if (memcmp(prefix, MAGIC, got < MAGIC_LEN ? got : MAGIC_LEN) != 0) return fail(r, "not a .npy file (bad magic)");
  if (got < MAGIC_LEN + 2) return fail(r, "truncated header: expected %d bytes, found %zu", MAGIC_LEN + 2, got);
  int major = prefix[MAGIC_LEN], minor = prefix[MAGIC_LEN + 1];
  if (minor != 0 || major < 1 || major > 3)
    return fail(r, "unsupported .npy format version %d.%d (supported: 1.0, 2.0, 3.0)", major, minor);
  size_t lenbytes = major == 1 ? 2 : 4, need = MAGIC_LEN + 2 + lenbytes;
  if (read_bytes(r, f, prefix + MAGIC_LEN + 2, lenbytes, &got)) return -1;
  if (got < lenbytes) return fail(r, "truncated header: expected %zu bytes, found %zu", need, MAGIC_LEN + 2 + got);
  const unsigned char *l = prefix + MAGIC_LEN + 2;
  size_t len = (size_t)l[0] | (size_t)l[1] << 8;
  if (lenbytes == 4) len |= (size_t)l[2] << 16 | (size_t)l[3] << 24;
  if (len > HEADER_MAX)
    return fail(r, "header of %zu bytes is too long (numpy.load's limit is %d)", len, HEADER_MAX);

  char *header = mem_malloc(len + 1);
  if (!header) return fail(r, "out of memory for the header");
  size_t size = 0;
  int swap = 0;
  int rc = read_bytes(r, f, header, len, &got);
  if (rc == 0 && got < len) rc = fail(r, "truncated header: expected %zu bytes, found %zu", need + len, need + got);
  if (rc == 0) rc = parse_header(r, header, len, major, a, &size, &swap);
  free(header);
  if (rc) return rc;
  if (read_data(r, f, need + len, a->count * size, &a->data)) return -1;
  if (swap) swap_bytes(a->data, a->count, size);
  return 0;
}

int npy_read(const char *path, NpyArray *out, char *err, size_t errlen) {
  Report r = {path, err, errlen};
  memset(out, 0, sizeof *out);
  if (err && errlen) err[0] = '\0';
  FILE *f = fopen(path, "rb");
  if (!f) return fail(&r, "cannot open: %s", strerror(errno));
  int rc = read_npy(&r, f, out);
  fclose(f);
  if (rc) npy_free(out);
  return rc;
}

/* ---------------------------------------------------------------- writing */

/* The version 1.0 header numpy.save writes (format._write_array_header and
 * _wrap_header): the dict with sorted keys and repr() values, spaces for the
 * first axis to grow to GROWTH_AXIS_MAX_DIGITS digits, then spaces and a
 * '\n' up to the next ARRAY_ALIGN boundary — a whole extra ARRAY_ALIGN when
 * already aligned, as numpy does. Returns the length written to `out`. */
static size_t format_header(char *out, size_t outlen, NpyType type, int ndim, const long *shape) {
  char dict[512];
  const char *kind = "f8";
  for (size_t i = 0; i < NTYPES; i++)
    if (types[i].type == type) kind = types[i].kind;
  int n = snprintf(dict, sizeof dict, "{'descr': '<%s', 'fortran_order': False, 'shape': (", kind);
  for (int i = 0; i < ndim; i++) n += snprintf(dict + n, sizeof dict - (size_t)n, i ? ", %ld" : "%ld", shape[i]);
  n += snprintf(dict + n, sizeof dict - (size_t)n, "%s), }", ndim == 1 ? "," : "");
  if (ndim > 0) {
    int digits = snprintf(NULL, 0, "%ld", shape[0]);
    for (int i = digits; i < GROWTH_AXIS_MAX_DIGITS; i++) dict[n++] = ' ';
  }
  size_t hlen = (size_t)n + 1, pad = ARRAY_ALIGN - (MAGIC_LEN + 2 + 2 + hlen) % ARRAY_ALIGN;
  size_t total = MAGIC_LEN + 2 + 2 + hlen + pad;
  if (total > outlen) return 0;
  memcpy(out, MAGIC "\x01\x00", MAGIC_LEN + 2);
  out[MAGIC_LEN + 2] = (char)((hlen + pad) & 0xff);
  out[MAGIC_LEN + 3] = (char)((hlen + pad) >> 8);
  memcpy(out + MAGIC_LEN + 4, dict, (size_t)n);
  memset(out + MAGIC_LEN + 4 + n, ' ', pad);
  out[total - 1] = '\n';
  return total;
}

/* `count` `size`-byte elements, little-endian whatever the host. */
static int write_data(FILE *f, const unsigned char *data, size_t count, size_t size) {
  if (count == 0) return 0; /* `data` may then be NULL, which fwrite may not see */
  if (host_is_little_endian()) return fwrite(data, size, count, f) == count ? 0 : -1;
  unsigned char chunk[4096];
  size_t per = sizeof chunk / size;
  for (size_t i = 0; i < count; i += per) {
    size_t n = count - i < per ? count - i : per;
    memcpy(chunk, data + i * size, n * size);
    swap_bytes(chunk, n, size);
    if (fwrite(chunk, size, n, f) != n) return -1;
  }
  return 0;
}

int npy_write(const char *path, NpyType type, int ndim, const long *shape, const void *data, char *err,
              size_t errlen) {
  Report r = {path, err, errlen};
  if (err && errlen) err[0] = '\0';
  size_t size = 0;
  for (size_t i = 0; i < NTYPES; i++)
    if (types[i].type == type) size = types[i].size;
  if (!size) return fail(&r, "cannot write: invalid element type %d", (int)type);
  if (ndim < 0 || ndim > NPY_MAX_DIMS)
    return fail(&r, "cannot write %d dimensions; at most %d are supported", ndim, NPY_MAX_DIMS);
  size_t count = 1;
  for (int i = 0; i < ndim; i++)
    if (shape[i] < 0) return fail(&r, "cannot write: shape entry %d is negative (%ld)", i, shape[i]);
  for (int i = 0; i < ndim; i++) count = shape[i] == 0 ? 0 : count;
  for (int i = 0; i < ndim && count; i++) {
    if ((size_t)shape[i] > SIZE_MAX / size / count) return fail(&r, "cannot write: shape has too many elements");
    count *= (size_t)shape[i];
  }
  if (count && !data) return fail(&r, "cannot write: no data for %zu elements", count);

  /* the rename below would replace a link, FIFO or device node with a file
   * (as root, /dev/full itself): only a regular file is ever replaced */
  struct stat st;
  if (lstat(path, &st) == 0 && !S_ISREG(st.st_mode))
    return fail(&r, "is not a regular file (a %s): refusing to replace it",
                S_ISLNK(st.st_mode) ? "symbolic link" : S_ISDIR(st.st_mode) ? "directory" : "FIFO, socket or device node");
  char header[1024];
  size_t hlen = format_header(header, sizeof header, type, ndim, shape);
  size_t tmplen = strlen(path) + 32;
  char *tmp = mem_malloc(tmplen);
  if (!tmp) return fail(&r, "out of memory");
  snprintf(tmp, tmplen, "%s.tmp.%ld", path, (long)getpid());
  FILE *f = fopen(tmp, "wb");
  if (!f) {
    int rc = fail(&r, "cannot create %s: %s", tmp, strerror(errno));
    free(tmp);
    return rc;
  }
  /* Sync before the rename: otherwise a crash soon after could leave `path`
   * naming a file whose data never reached the disk. EINVAL means the file
   * cannot be synced at all (not an ordinary file system), not a failure. */
  int ok = fwrite(header, 1, hlen, f) == hlen && write_data(f, data, count, size) == 0 && fflush(f) == 0 &&
           (fsync(fileno(f)) == 0 || errno == EINVAL);
  int saved = errno;
  if (fclose(f) != 0 && ok) {
    ok = 0;
    saved = errno;
  }
  int rc = 0;
  if (!ok) rc = fail(&r, "cannot write %s: %s", tmp, strerror(saved));
  else if (rename(tmp, path) != 0) rc = fail(&r, "cannot replace it with %s: %s", tmp, strerror(errno));
  if (rc) remove(tmp);
  free(tmp);
  return rc;
}
