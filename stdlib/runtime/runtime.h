/* runtime.h — the C runtime generated code calls (through NpgRt), and the
 * host-side state it records errors in. */
#ifndef NPG_RUNTIME_H
#define NPG_RUNTIME_H

#include <stdbool.h>
#include <stddef.h>

#include <lapacke.h>

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

/* runtime.c, shared with deriv.c: M (row-major) and y finite, else a message naming
 * `stage` and `op`; LU of M in place (M^T factored column-major, so a solve without
 * `transpose` applies M^-1, with it M^-T), refused when singular (rcond <= 1e-15); the
 * eigendecomposition of symmetric M for its power p/q (eigenvectors the columns of M,
 * eigenvalues in w), refused when not symmetric, not positive (semi)definite, or singular
 * under a negative power. Each 0, or -1 after recording the message. */
int runtime_check_finite(const NpgCtx *c, const char *stage, const char *op, npg_idx n, const double *M,
                         const double *y);
int runtime_lu(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, lapack_int *piv);
int runtime_lu_solve(const NpgCtx *c, const char *stage, npg_idx n, const double *LU, const lapack_int *piv,
                     bool transpose, double *y);
int runtime_sym_eigen(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, long p, long q,
                      double *w);
/* stdlib/runtime/deriv.c: NpgRt.power_jvp and NpgRt.power_vjp (npg_abi.h). */
int runtime_power_jvp(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, const double *dM,
                      long p, long q, double *x, double *dx);
int runtime_power_vjp(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, double *Mbar,
                      long p, long q, const double *x, double *ybar);

/* stdlib/runtime/sparse.c: NpgRt.sparse_power_jvp and sparse_power_vjp (npg_abi.h). */
int runtime_sparse_power_jvp(const NpgCtx *c, const NpgCtx *d, const char *stage, const char *op, int opid, npg_idx n,
                             NpgOpEntriesFn entries, NpgOpDerivFn dentries, long p, long q, double *x, double *dx);
int runtime_sparse_power_vjp(const NpgCtx *c, const NpgCtx *d, const char *stage, const char *op, int opid, npg_idx n,
                             NpgOpEntriesFn entries, NpgOpDerivFn dentries, long p, long q, const double *x,
                             double *ybar);
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
