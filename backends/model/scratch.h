/* scratch.h — the temporary memory of one operation of the model layer (issue 39, STYLE:
 * "scratch arenas per stage, no scattered free"): a load, an estimate, a derivative sweep,
 * a JIT build takes its buffers from a Scratch and releases them all at its one exit, so no
 * error path frees by hand. What the operation returns (a Model, a Reduced) is not scratch:
 * it keeps its own free function, called once on a half-built object. */
#ifndef NPG_SCRATCH_H
#define NPG_SCRATCH_H

#include <stddef.h>

#include "context.h" /* Err */

typedef struct ScratchBlock ScratchBlock;
typedef struct Scratch {
  ScratchBlock *head; /* every block given out, newest first */
  Err *err;           /* where "out of memory" goes (NULL: dropped) */
} Scratch;

/* An empty scratch whose failures are reported in `err`. */
#define SCRATCH_OF(e) ((Scratch){NULL, (e)})

/* `bytes` of zeroed memory (through the allocation hook, alloc.h) that lives until
 * scratch_release; NULL with "out of memory" in the scratch's error record. */
void *scratch_alloc(Scratch *s, size_t bytes);
/* `count` elements of `size` bytes: scratch_alloc's, the product checked for overflow. */
void *scratch_array(Scratch *s, size_t count, size_t size);
/* scratch_array's block, not zeroed: for a buffer written whole before it is read, on a path
 * where zeroing costs (a derivative sweep's work arrays, a reduced Jacobian's tens of µs). */
void *scratch_array_unzeroed(Scratch *s, size_t count, size_t size);
/* `p`, memory from the allocation hook (a string a helper built, say), made the scratch's:
 * freed by scratch_release. NULL when `p` is NULL (a failure its maker reported), or, with
 * "out of memory", when the scratch cannot hold it (`p` is freed then). */
void *scratch_adopt(Scratch *s, void *p);
/* printf's text in a block of the scratch, or NULL with "out of memory" in its error record
 * (a path built for one operation: no string to free by hand on its error paths). */
__attribute__((format(printf, 2, 3))) char *scratch_printf(Scratch *s, const char *fmt, ...);
/* `p`, a pointer the scratch adopted (scratch_adopt), handed back: scratch_release no longer
 * frees it (what an operation built in its scratch and returns once it succeeded). `p` itself
 * when NULL or not adopted by `s` (nothing changes then). */
void *scratch_keep(Scratch *s, void *p);
/* Frees every block of the scratch; it is empty again. */
void scratch_release(Scratch *s);

#endif
