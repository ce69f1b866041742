/* memsamples.h — random training and test samples held in memory (tests):
 * every param bound in an evaluator, S samples of every input and extern,
 * handed out through the trainer's SampleSource callback. */
#ifndef NPG_MEMSAMPLES_H
#define NPG_MEMSAMPLES_H

#include "full.h"

typedef struct MemSamples {
  int n;
  const Sym *sym[64];
  int nd[64];
  long shape[64][MAX_AXES + MAX_STATIC];
  size_t count[64];
  double *val[64];   /* samples x count */
  long S;
} MemSamples;

/* Entries of `s` with every dim of size n; its shape into `shape`. */
size_t mem_count(const Sym *s, long n, long *shape);
/* Random params into `f` (when non-NULL), then S samples of every input
 * and extern (randdata.h), every dim of size n. 0, or -1 when binding a
 * param failed (npg_full_error(f) says why). */
int mem_fill(MemSamples *ms, const Program *prog, NpgFull *f, long n, long S, unsigned seed);
/* SampleSource callback: sets sample k. */
int mem_set(void *user, NpgFull *f, long k);
void mem_free(MemSamples *ms);

#endif
