/* demand.h — which entries of which quantities an evaluation must compute
 * (restricted evaluation: out-of-core training keeps only some rows of the
 * pair quantities per pass, and need not compute the others).
 *
 * The caller demands entries of quantities as boxes — per dim axis a
 * half-open range [lo, hi) — or whole quantities. demand_propagate() walks
 * the full evaluator's steps (emit_full_plan) backwards: a step runs over
 * the union of its members' demanded boxes, and every read in its members'
 * expressions demands the entries it reads there. A read q[idx] whose index
 * on an axis is a plain index variable of the step (in any order, like
 * h[j,i] in c[i,j] = h[i,j]*h[j,i]/pi) maps the step's range of that
 * variable; any other index (a gather g[tri[f,1]], arithmetic, a constant, a
 * summation variable) demands the whole axis. A read of a fused stage at
 * another entry is rematerialized in the generated code, so it demands what
 * that stage's expression reads there. Steps that are not boxed (temps,
 * stages over fewer than two index variables, declared operators, solves)
 * run whole when anything of them is demanded, and demand everything they
 * read; steps nothing demands are skipped. Demand is kept as a short list
 * of boxes per quantity (h above needs rows [i0,i1) and columns [i0,i1):
 * two boxes, not their bounding box); a step whose boxes cover its domain,
 * or that gathers too many, runs whole. */
#ifndef NPG_DEMAND_H
#define NPG_DEMAND_H

#include <stddef.h>

#include "emit.h"
#include "ir.h"
#include "npg_abi.h"

typedef struct Demand Demand;

/* A demand over `prog`'s quantities for the steps of `plan` (both must
 * outlive it); empty. NULL when out of memory. */
Demand *demand_new(const Program *prog, const FullPlan *plan);
void demand_free(Demand *d);
/* Forget every demand; `dims` are the dims as bound (program order), read
 * until the next reset. */
void demand_reset(Demand *d, const npg_idx *dims);
/* Every entry of quantity (or temp) `q`. */
void demand_all(Demand *d, const Sym *q);
/* The entries lo[k] <= idx[k] < hi[k] of `q` (every static component). */
void demand_box(Demand *d, const Sym *q, const npg_idx *lo, const npg_idx *hi);
/* The flat entries [e0, e1) of `q` (dims then static axes, row-major, as a
 * basis row numbers them), as boxes: a partial first row, whole rows, a
 * partial last row (recursively over more axes). */
void demand_entries(Demand *d, const Sym *q, size_t e0, size_t e1);
/* Propagate through the steps: 0, or -1 when out of memory. */
int demand_propagate(Demand *d);
/* After demand_propagate: the flat entries of quantity `q` (dims then
 * static axes) demanded, as `n` half-open ranges r[2i] <= e < r[2i+1],
 * ascending, possibly overlapping; returns n (0: none), or -1 when every
 * entry is demanded or more than `cap` ranges would be needed. */
long demand_ranges(const Demand *d, const Sym *q, size_t *r, long cap);
/* A `cap` for demand_ranges that always suffices: -1 when every entry of
 * `q` is demanded (or `q` is no input or extern), 0 when none. */
long demand_range_bound(const Demand *d, const Sym *q);
/* After demand_propagate: step k is not needed (-1), runs whole (0), or
 * runs over n > 0 boxes at *box (as NpgStepFn takes them). */
int demand_step(const Demand *d, int k, const npg_idx **box);

#endif
