/* full.h — internals of the full evaluator shared with the trainer and
 * tests (the public API is in npg.h). */
#ifndef NPG_FULL_H
#define NPG_FULL_H

#include "ir.h"
#include "npg.h"
#include "npg_abi.h"

/* Run the tensor builder `name` on the current binding (after an
 * evaluation bound everything). 0, or -1 with npg_full_error(). */
int full_build(NpgFull *f, const char *name, NpgSink *sink);
/* The bound size of dim number k (program order). */
long full_dim_size(const NpgFull *f, int k);

#endif
