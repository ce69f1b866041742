/* runtime.h — the C runtime generated code calls (through NpgRt), and the
 * host-side state it records errors in. */
#ifndef NPG_RUNTIME_H
#define NPG_RUNTIME_H

#include <stdbool.h>
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
  /* sparse declared operators (stdlib/runtime/sparse.c): per operator, its
     pattern and symbolic factorization for the current binding */
  struct SparseOp *sparse;
  int nsparse;
  long sparse_min_rows;             /* below this many rows, the dense path */
  long sparse_patterns, sparse_cholesky, sparse_lu;  /* counts, for tests */
} NpgHost;
typedef struct SparseOp SparseOp;

/* Records the first error of an evaluation in its host (NpgCtx.host). */
void runtime_record(const NpgCtx *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* stdlib/runtime/sparse.c: NpgRt.sparse_power, and dropping the patterns
 * when the binding changes (reset) or the host goes (free). */
int runtime_sparse_power(const NpgCtx *c, const char *stage, const char *op, int opid, npg_idx n,
                         NpgOpEntriesFn entries, long p, long q, double *y);
void runtime_sparse_reset(NpgHost *h);
void runtime_sparse_free(NpgHost *h);

/* stdlib/runtime/rows.c: the row kernels of NpgRt. */
void rows_vv(npg_idx n, NpgRowOp op, const double *restrict x, const double *restrict y, double *restrict out);
void rows_vs(npg_idx n, NpgRowOp op, const double *restrict x, double s, double *restrict out);
void rows_sv(npg_idx n, NpgRowOp op, double s, const double *restrict y, double *restrict out);
void rows_unary(npg_idx n, NpgRowOp op, const double *restrict x, double *restrict out);
void rows_fill(npg_idx n, double s, double *restrict out);

/* The runtime function table (NpgCtx.rt). */
extern const NpgRt npg_runtime;

#endif
