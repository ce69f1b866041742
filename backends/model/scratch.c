/* scratch.c — the temporary memory of one model-layer operation (scratch.h): a block per
 * allocation (so the sanitizers see each buffer's bounds), chained and freed at once. */
#include "scratch.h"

#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>

struct ScratchBlock {
  ScratchBlock *next;
  void *adopted; /* a block made elsewhere and given to the scratch (scratch_adopt), or NULL */
  max_align_t data[];
};

/* A block of `bytes` chained into `s`, zeroed when `zeroed`. */
static void *block(Scratch *s, size_t bytes, bool zeroed) {
  ScratchBlock *b = NULL;
  if (bytes <= (size_t)-1 - sizeof *b) b = zeroed ? mem_calloc(1, sizeof *b + bytes) : mem_malloc(sizeof *b + bytes);
  if (!b) return err_set(s->err, "out of memory (%zu bytes of scratch)", bytes), NULL;
  b->adopted = NULL;
  b->next = s->head, s->head = b;
  return b->data;
}

/* count x size, or (size_t)-1 with the refusal in `s` when it overflows. */
static size_t array_bytes(Scratch *s, size_t count, size_t size) {
  size_t n;
  if (!__builtin_mul_overflow(count, size, &n) && n != (size_t)-1) return n;
  err_set(s->err, "out of memory (%zu x %zu bytes of scratch)", count, size);
  return (size_t)-1;
}

void *scratch_alloc(Scratch *s, size_t bytes) { return block(s, bytes, true); }

void *scratch_array(Scratch *s, size_t count, size_t size) {
  size_t n = array_bytes(s, count, size);
  return n == (size_t)-1 ? NULL : block(s, n, true);
}

void *scratch_array_unzeroed(Scratch *s, size_t count, size_t size) {
  size_t n = array_bytes(s, count, size);
  return n == (size_t)-1 ? NULL : block(s, n, false);
}

void *scratch_adopt(Scratch *s, void *p) {
  if (!p) return NULL;
  ScratchBlock *b = mem_calloc(1, sizeof *b);
  if (!b) return free(p), err_set(s->err, "out of memory (scratch)"), NULL;
  b->adopted = p;
  b->next = s->head, s->head = b;
  return p;
}

void *scratch_keep(Scratch *s, void *p) {
  for (ScratchBlock *b = s->head; p && b; b = b->next)
    if (b->adopted == p) {
      b->adopted = NULL;
      break;
    }
  return p;
}

char *scratch_printf(Scratch *s, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(NULL, 0, fmt, ap);
  va_end(ap);
  char *text = n < 0 ? NULL : scratch_alloc(s, (size_t)n + 1);
  if (!text) return n < 0 ? (err_set(s->err, "cannot format '%s'", fmt), NULL) : NULL;
  va_start(ap, fmt);
  vsnprintf(text, (size_t)n + 1, fmt, ap);
  va_end(ap);
  return text;
}

void scratch_release(Scratch *s) {
  for (ScratchBlock *b = s->head, *next; b; b = next) next = b->next, free(b->adopted), free(b);
  s->head = NULL;
}
