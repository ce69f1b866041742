/* runtime.h — the C runtime generated code calls (through NpgRt), and the
 * host-side state it records errors in. */
#ifndef NPG_RUNTIME_H
#define NPG_RUNTIME_H

#include <stddef.h>

#include "npg_abi.h"

/* What the runtime needs to word its messages. */
typedef struct NpgHost {
  char msg[1024];                   /* the first error, "" if none */
  const char *const *dim_names;     /* program order */
  const char *const *param_names;
  const char *const *param_files;   /* the .npy each param came from */
  const npg_idx *const *param_shapes;
  const int *param_ndims;
} NpgHost;

/* stdlib/runtime/rows.c: the row kernels of NpgRt. */
void rows_vv(npg_idx n, NpgRowOp op, const double *restrict x, const double *restrict y, double *restrict out);
void rows_vs(npg_idx n, NpgRowOp op, const double *restrict x, double s, double *restrict out);
void rows_sv(npg_idx n, NpgRowOp op, double s, const double *restrict y, double *restrict out);
void rows_unary(npg_idx n, NpgRowOp op, const double *restrict x, double *restrict out);
void rows_fill(npg_idx n, double s, double *restrict out);

/* The runtime function table (NpgCtx.rt). */
extern const NpgRt npg_runtime;

#endif
