/* context.c — the compilation's context (context.h): the arena, pointer
 * vectors, library failures (error_set), and the diagnostics with their
 * source excerpts. */
#include "context.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ---------------------------------------------------------------- arena */

struct ArenaBlock {
  ArenaBlock *next;
  size_t size, used;
  max_align_t data[];
};


void *arena_alloc(Ctx *ctx, size_t size) {
  size = (size + 15) & ~(size_t)15;
  ArenaBlock *b = ctx->arena.head;
  if (!b || b->used + size > b->size) {
    size_t cap = size > 65536 ? size : 65536;
    b = mem_alloc_hook(sizeof(ArenaBlock) + cap);
    if (!b) {
      /* The message itself must not need the arena. */
      ctx->msg = "error: out of memory";
      ctx->failed = true;
      longjmp(*ctx->on_error, 1);
    }
    b->size = cap;
    b->used = 0;
    b->next = ctx->arena.head;
    ctx->arena.head = b;
  }
  void *p = (char *)b->data + b->used;
  b->used += size;
  ctx->arena.used_total += size;
  memset(p, 0, size);
  return p;
}

void arena_release(Arena *arena) {
  for (ArenaBlock *b = arena->head; b;) {
    ArenaBlock *next = b->next;
    free(b);
    b = next;
  }
  arena->head = NULL;
  arena->used_total = 0;
}

void *arena_grow(Ctx *ctx, void *old, size_t old_size, size_t new_size) {
  void *p = arena_alloc(ctx, new_size);
  if (old && old_size) memcpy(p, old, old_size < new_size ? old_size : new_size);
  return p;
}

char *arena_strndup(Ctx *ctx, const char *s, size_t n) {
  char *p = arena_alloc(ctx, n + 1);
  if (n) memcpy(p, s, n);
  p[n] = 0;
  return p;
}

char *arena_strdup(Ctx *ctx, const char *s) { return arena_strndup(ctx, s, strlen(s)); }

char *arena_vprintf(Ctx *ctx, const char *fmt, va_list ap) {
  va_list ap2;
  va_copy(ap2, ap);
  int n = vsnprintf(NULL, 0, fmt, ap2);
  va_end(ap2);
  char *p = arena_alloc(ctx, (size_t)n + 1);
  vsnprintf(p, (size_t)n + 1, fmt, ap);
  return p;
}

int error_vset(char *err, size_t errlen, const char *fmt, va_list ap) {
  if (err && errlen) vsnprintf(err, errlen, fmt, ap);
  return -1;
}

int error_set(char *err, size_t errlen, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  error_vset(err, errlen, fmt, ap);
  va_end(ap);
  return -1;
}

int error_set_first(char *err, size_t errlen, const char *fmt, ...) {
  if (err && errlen && err[0]) return -1;
  va_list ap;
  va_start(ap, fmt);
  error_vset(err, errlen, fmt, ap);
  va_end(ap);
  return -1;
}

int err_vset(Err *e, const char *fmt, va_list ap) {
  return e ? error_vset(e->msg, e->len, fmt, ap) : -1;
}

int err_set(Err *e, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  err_vset(e, fmt, ap);
  va_end(ap);
  return -1;
}

int err_set_first(Err *e, const char *fmt, ...) {
  if (err_held(e)) return -1;
  va_list ap;
  va_start(ap, fmt);
  err_vset(e, fmt, ap);
  va_end(ap);
  return -1;
}

bool err_held(const Err *e) { return e && e->msg && e->len && e->msg[0]; }

const char *bytes_text(double bytes, char *buf, size_t len) {
  static const char *const units[] = {"B", "kB", "MB", "GB", "TB", "PB", "EB"};
  int u = 0;
  while (bytes >= 1000 && u < 6) bytes /= 1000, u++;
  snprintf(buf, len, "%.3g %s", bytes, units[u]);
  return buf;
}

size_t physical_memory(void) {
  long pages = sysconf(_SC_PHYS_PAGES), psize = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && psize > 0 ? (size_t)pages * (size_t)psize : 0;
}

char *arena_printf(Ctx *ctx, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *p = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  return p;
}

void vec_push(Ctx *ctx, PtrVec *vec, void *p) {
  if (vec->n == vec->cap) {
    int cap = vec->cap ? vec->cap * 2 : 8;
    vec->v = arena_grow(ctx, vec->v, sizeof(void *) * (size_t)vec->cap, sizeof(void *) * (size_t)cap);
    vec->cap = cap;
  }
  vec->v[vec->n++] = p;
}

int vec_position(const PtrVec *vec, const void *p) {
  for (int i = 0; i < vec->n; i++)
    if (vec->v[i] == p) return i;
  return -1;
}

/* ---------------------------------------------------------------- diagnostics */

/* A source line longer than this many bytes is shown as a window around
 * the column, its cut ends marked with "…" (a 125 KB one-line program must
 * not print 125 KB per diagnostic). */
enum { DIAG_WINDOW = 100 };

static bool utf8_continuation(char c) { return ((unsigned char)c & 0xC0) == 0x80; }

char *diag_excerpt(Ctx *ctx, Loc loc) {
  if (!loc.file) return arena_strndup(ctx, "", 0);
  const char *text = loc.file->text;
  size_t start = loc.off <= loc.file->len ? loc.off : loc.file->len;
  while (start > 0 && text[start - 1] != '\n' && text[start - 1] != '\r') start--; /* CR alone ends a line too */
  size_t end = start;
  while (end < loc.file->len && text[end] != '\n' && text[end] != '\r') end++;
  size_t at = start + (size_t)(loc.col > 0 ? loc.col - 1 : 0); /* may lie past the end of the line */
  size_t from = start, to = end;
  if (end - start > DIAG_WINDOW) {
    size_t mid = at < end ? at : end;
    from = mid - start > DIAG_WINDOW / 2 ? mid - DIAG_WINDOW / 2 : start;
    if (end - from < DIAG_WINDOW) from = end - DIAG_WINDOW;
    to = from + DIAG_WINDOW;
    while (from > start && utf8_continuation(text[from])) from--;
    while (to < end && utf8_continuation(text[to])) to++;
  }
  bool cut_before = from > start, cut_after = to < end;
  /* Caret line: one column for a leading "…", then one per character. */
  char *caret = arena_alloc(ctx, (at - from) + 3);
  size_t nc = 0;
  if (cut_before) caret[nc++] = ' ';
  for (size_t k = from; k < at; k++) {
    if (k < end && utf8_continuation(text[k])) continue;
    caret[nc++] = (k < end && text[k] == '\t') ? '\t' : ' ';
  }
  caret[nc++] = '^';
  caret[nc] = 0;
  /* Replace non-printable bytes of the echoed line so output stays text. */
  char *line = arena_strndup(ctx, text + from, to - from);
  for (char *c = line; *c; c++)
    if ((unsigned char)*c < 32 && *c != '\t') *c = '?';
  return arena_printf(ctx, "%s%s%s\n%s", cut_before ? "…" : "", line, cut_after ? "…" : "", caret);
}

/* Append "file:line:col: kind: msg\n<source line>\n<caret>\n" to buf. */
char *diag_format(Ctx *ctx, const char *prefix, Loc loc, const char *kind, const char *msg) {
  if (!loc.file) return arena_printf(ctx, "%s%s: %s\n", prefix, kind, msg);
  return arena_printf(ctx, "%s%s:%d:%d: %s: %s\n%s\n", prefix, loc.file->name, loc.line, loc.col, kind, msg,
                      diag_excerpt(ctx, loc));
}

_Noreturn void ctx_fail(Ctx *ctx) {
  ctx->failed = true;
  longjmp(*ctx->on_error, 1);
}

_Noreturn void error_at(Ctx *ctx, Loc loc, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = loc;
  ctx->msg = diag_format(ctx, "", loc, "error", msg);
  ctx_fail(ctx);
}

_Noreturn void error_note(Ctx *ctx, Loc loc, Loc note, const char *note_msg, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = loc;
  ctx->msg = diag_format(ctx, "", loc, "error", msg);
  ctx->msg = diag_format(ctx, ctx->msg, note, "note", note_msg);
  ctx_fail(ctx);
}

_Noreturn void error_plain(Ctx *ctx, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = (Loc){0};
  ctx->msg = arena_printf(ctx, "error: %s\n", msg);
  ctx_fail(ctx);
}

_Noreturn void internal_error(Ctx *ctx, const char *file, int line, const char *what) {
  ctx->err_loc = (Loc){0};
  ctx->msg = arena_printf(ctx, "internal error: %s:%d: %s (a bug in npgc; please report it with the program)\n",
                          file, line, what);
  ctx_fail(ctx);
}
