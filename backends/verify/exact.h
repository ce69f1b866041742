/* exact.h — the two exactness checks of DESIGN §4, on demand (DESIGN §7,
 * `npgc verify --exact`):
 *
 *   1. lowering: every stage rebuilt from the streamed entries of its
 *      tensors (the canonical form Σ_t Π M_t^r q_t that training
 *      pre-multiplies), operators applied densely, equals the full
 *      evaluator's value to 1e-12 relative (max norm);
 *   2. full rank: a model trained with every basis at its class's full
 *      dimension reproduces the full evaluator to 1e-10 on held-out samples
 *      (paper §7.1 convergence); and so does it with every stage eligible
 *      for interpolation interpolated at every entry (DESIGN §12).
 *
 * Both run on random well-posed data (randdata.h) with every dim of one
 * small size: a user's data fixes sizes at which a full-rank basis (n × n
 * for every class) would not fit. */
#ifndef NPG_EXACT_H
#define NPG_EXACT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#include "ir.h"
#include "jit.h"

#define EXACT_LOWERING_TOL 1e-12
#define EXACT_FULL_RANK_TOL 1e-10

typedef struct ExactOptions {
  long n_lowering;    /* size of every dim for check 1 (6 when 0) */
  long n_full_rank;   /* size of every dim for check 2 (4 when 0) */
  unsigned seed;      /* of the random data */
  JitBackend backend; /* of the full evaluator */
  bool progress;      /* training's progress bars */
} ExactOptions;

/* Run both checks on `prog` (compiled without errors) and print a report to
 * `out`: per stage the relative difference of check 1, per quantity that
 * of check 2. Returns 0 when both pass, 1 when one fails (the report names
 * where), -1 when a check cannot run (message in `err`: the full evaluator
 * failed on the random data, an operator is singular there, out of
 * memory). */
int exact_check_program(Program *prog, const ExactOptions *o, FILE *out, char *err, size_t errlen);

/* max |a − b| / max |a| over n entries (NaN when one side alone is NaN at
 * an entry): the relative difference both checks report. */
double exact_rel_max_diff(const double *a, const double *b, size_t n);

#endif
