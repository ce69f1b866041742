/* failing_alloc.h — the library's allocations made to fail, for the tests of its failure
 * paths (the one allocation hook of stdlib/runtime/alloc.h; STYLE: Lua's ltests.c): after
 * failing_alloc_after(k) the next k allocations succeed and every later one fails, until
 * failing_alloc_off(). A test walks k = 0, 1, ... until the operation succeeds; each
 * failure before must be an error that says "out of memory" (and, under the sanitizers,
 * leak nothing). */
#ifndef NPG_FAILING_ALLOC_H
#define NPG_FAILING_ALLOC_H

void failing_alloc_after(long k);
/* malloc again (also a cmocka teardown's first line: a failed assertion must not leave
 * the hook failing for the next test). */
void failing_alloc_off(void);
/* The allocations asked for since failing_alloc_after. */
long failing_alloc_calls(void);
/* NPG_ALLOC_TRACE=k in the environment: the stack of the allocation refused first after
 * failing_alloc_after(k) is written to stderr (where a failure path goes wrong); k, or -1. */
long failing_alloc_traced(void);

#endif
