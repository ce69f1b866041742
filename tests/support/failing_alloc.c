/* failing_alloc.c — the library's allocations made to fail (failing_alloc.h). */
#include <stdlib.h>

#include "alloc.h"
#include "failing_alloc.h"

static long left, calls;

static void *failing_alloc(size_t n) {
  calls++;
  return left-- > 0 ? malloc(n) : NULL;
}

void failing_alloc_after(long k) {
  left = k;
  calls = 0;
  mem_alloc_hook = failing_alloc;
}

void failing_alloc_off(void) { mem_alloc_hook = malloc; }

long failing_alloc_calls(void) { return calls; }
