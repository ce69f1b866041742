/* failing_alloc.c — the library's allocations made to fail (failing_alloc.h). */
#include <execinfo.h>
#include <stdlib.h>

#include "alloc.h"
#include "failing_alloc.h"

static long left, calls, walk, trace = -1;

static void *failing_alloc(size_t n) {
  calls++;
  if (left-- > 0) return malloc(n);
  if (left == -1 && walk == trace) { /* the first allocation refused, on the step traced */
    void *frames[16];
    backtrace_symbols_fd(frames, backtrace(frames, 16), 2);
  }
  return NULL;
}

void failing_alloc_after(long k) {
  const char *t = getenv("NPG_ALLOC_TRACE");
  trace = t ? atol(t) : -1;
  walk = k;
  left = k;
  calls = 0;
  mem_alloc_hook = failing_alloc;
}

void failing_alloc_off(void) { mem_alloc_hook = malloc; }

long failing_alloc_calls(void) { return calls; }

long failing_alloc_traced(void) {
  const char *t = getenv("NPG_ALLOC_TRACE");
  return t ? atol(t) : -1;
}
