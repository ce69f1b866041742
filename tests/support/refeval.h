/* refeval.h — reference evaluator for tests: direct (from the checked
 * source) and canonical (from the lowered terms) evaluation of stages. */
#ifndef NPG_REFEVAL_H
#define NPG_REFEVAL_H

#include <stdbool.h>
#include <stddef.h>

#include "ir.h"

typedef struct RefData RefData;

/* Data for `prog`, every dim bound to `dimsize`. */
RefData *ref_new(const Program *prog, long dimsize);
void ref_free(RefData *d);
long ref_dim(RefData *d, const Sym *dim);
/* Number of doubles of a param or quantity (dims × static). */
size_t ref_count(RefData *d, const Sym *q);
/* Storage of a param or quantity (ints stored as doubles), allocated on
 * first use, zeroed. */
double *ref_values(RefData *d, const Sym *q);
/* The stage value straight from its source expression. */
void ref_eval_direct(RefData *d, const Sym *s, double *out);
/* The stage value from its canonical form (reads upstream stages' storage). */
void ref_eval_canonical(RefData *d, const Stage *st, double *out);
/* x <- M^(p/q) x for a dense row-major n x n M (overwritten): LU for
 * integer powers, eigendecomposition for fractional ones. */
bool ref_apply_power(RefData *d, double *M, int n, long p, long q, double *x);
/* First evaluation problem (index out of range, singular operator), or NULL. */
const char *ref_error(RefData *d);

#endif
