/* alloc.c — the allocation hook and the allocators that go through it
 * (alloc.h). */
#include "alloc.h"

#include <malloc.h>
#include <stdlib.h>
#include <string.h>

void *(*mem_alloc_hook)(size_t size) = malloc;

void *mem_malloc(size_t size) { return mem_alloc_hook(size); }

void *mem_calloc(size_t count, size_t size) {
  size_t n;
  if (__builtin_mul_overflow(count, size, &n)) return NULL;
  void *p = mem_alloc_hook(n);
  if (p) memset(p, 0, n);
  return p;
}

void *mem_realloc(void *p, size_t size) {
  if (mem_alloc_hook == malloc) return realloc(p, size);
  /* a test's hook: a new block from it, the old contents copied */
  void *q = mem_alloc_hook(size);
  if (!q || !p) return q;
  size_t old = malloc_usable_size(p);
  memcpy(q, p, old < size ? old : size);
  free(p);
  return q;
}

char *mem_strdup(const char *s) {
  size_t n = strlen(s) + 1;
  char *p = mem_alloc_hook(n);
  if (p) memcpy(p, s, n);
  return p;
}
