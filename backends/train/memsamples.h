/* memsamples.h — random samples held in memory: every param bound in an
 * evaluator, S samples of every input and extern, handed out through the
 * trainer's SampleSource callback. For the exactness checks of `npgc verify
 * --exact` (exact.c) and for tests. */
#ifndef NPG_MEMSAMPLES_H
#define NPG_MEMSAMPLES_H

#include "full.h"

#define MEM_MAX_QUANTITIES 64

typedef struct MemSamples {
  int n;
  const Sym *sym[MEM_MAX_QUANTITIES];
  int nd[MEM_MAX_QUANTITIES];
  long shape[MEM_MAX_QUANTITIES][MAX_AXES + MAX_STATIC];
  size_t count[MEM_MAX_QUANTITIES];
  double *val[MEM_MAX_QUANTITIES]; /* samples x count */
  long S;
} MemSamples;

/* Entries of `s` with every dim of size n; its shape into `shape`. */
size_t memsamples_count(const Sym *s, long n, long *shape);

/* Random params into `f` (when non-NULL), then S samples of every input
 * and extern (randdata.h), every dim of size n. 0; -1 when binding a
 * param failed (full_error(f) says why), -2 when memory ran out or the
 * program has more than MEM_MAX_QUANTITIES inputs and externs (then `ms`
 * holds nothing to free). */
int memsamples_fill(MemSamples *ms, const Program *prog, Full *f, long n, long S, unsigned seed);

/* SampleSource callback: sets sample k. */
int memsamples_set(void *user, Full *f, long k);

void memsamples_free(MemSamples *ms);

#endif
