/* randdata.h — random but well-posed data for a program: the exactness
 * checks of `npgc verify --exact` (exact.c) and tests. */
#ifndef NPG_RANDDATA_H
#define NPG_RANDDATA_H

#include <stdbool.h>
#include <stddef.h>

#include "ir.h"

/* What the data is drawn for: a program whose every dim has size n, from
 * *seed (advanced by every draw); `padded`: see randdata_fill. */
typedef struct RandData {
  const Program *prog;
  long n;
  unsigned *seed;
  bool padded;
} RandData;

/* Fill `out` (count values) for param, input or extern `s` of r->prog, every
 * dim of size r->n: inputs and externs in [0.5, 1.5]; real params in
 * [0.1, 0.3] (keeps operators like I - rho p well conditioned); int params
 * in [0, n) with distinct entries along the last axis and no two rows the
 * same set (no degenerate triangles or tetrahedra); with r->padded, int
 * params that some guard tests get -1 in about one entry in four. Returns
 * true when it padded. */
bool randdata_fill(const RandData *r, const Sym *s, double *out, size_t count);
double randdata_uniform(unsigned *seed, double lo, double hi);

#endif
