/* alloc.h — the library's one allocation hook (STYLE: Lua ltests.c,
 * CHOLMOD's Tcov). It lives in the lowest layer so that the .npy reader and
 * the runtime allocate through it too: a test makes any allocation of
 * training and model loading fail in turn (tests/test_alloc.c). */
#ifndef NPG_ALLOC_H
#define NPG_ALLOC_H

#include <stddef.h>

/* Tests replace it to make allocation fail. It has malloc's contract. */
extern void *(*mem_alloc_hook)(size_t size);
/* malloc, calloc, realloc and strdup through the hook: the front end's
 * arenas, training, the full evaluator's buffers, models, their loading and
 * .npy files are allocated by these. Their memory is released with free(). mem_calloc checks
 * count * size for overflow; mem_realloc(NULL, n) is mem_malloc(n). */
void *mem_malloc(size_t size);
void *mem_calloc(size_t count, size_t size);
void *mem_realloc(void *p, size_t size);
char *mem_strdup(const char *s);

#endif
