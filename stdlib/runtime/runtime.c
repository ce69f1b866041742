/* runtime.c — dense operator powers, scratch memory and error messages for
 * generated code. Every LAPACK call's info is checked and turned into a
 * message a user understands (STYLE). */
#include "runtime.h"
#include "alloc.h" /* mem_malloc: allocation through the hook */

#include <lapacke.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void runtime_record(const NpgCtx *c, const char *fmt, ...) {
  NpgHost *h = c->host;
  if (!h || h->msg[0]) return;  /* keep the first error */
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(h->msg, sizeof h->msg, fmt, ap);
  va_end(ap);
}

static double *scratch(const NpgCtx *c, npg_idx count) {
  if (count < 0 || (size_t)count > ((size_t)-1) / sizeof(double) / 2) {
    runtime_record(c, "sample %ld: scratch of %ld doubles is too large", c->sample, (long)count);
    return NULL;
  }
  double *p = mem_calloc(count ? (size_t)count : 1, sizeof(double));
  if (!p) runtime_record(c, "sample %ld: out of memory (%ld doubles of scratch)", c->sample, (long)count);
  return p;
}

static void release(const NpgCtx *c, double *p) {
  (void)c;
  free(p);
}

/* Largest absolute row sum of a row-major n x n matrix M: the 1-norm of M^T, the matrix
 * LAPACK factors (below), for the condition estimate. */
static double norm_rows(const double *M, npg_idx n) {
  double best = 0;
  for (npg_idx i = 0; i < n; i++) {
    double s = 0;
    for (npg_idx j = 0; j < n; j++) s += fabs(M[i * n + j]);
    if (s > best) best = s;
  }
  return best;
}

/* LU of the row-major M in place. The row-major M is the column-major M^T, so LAPACK
 * factors M^T in place: solves with 'T' apply M^-1, with 'N' M^-T. LAPACKE's row-major
 * interface would copy the matrix into column-major order and back (at 5,000 rows that
 * copy took 0.55 of the LU's 1.34 s). */
int runtime_lu(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, lapack_int *piv) {
  lapack_int ld = (lapack_int)(n ? n : 1);
  double anorm = norm_rows(M, n);
  lapack_int info = LAPACKE_dgetrf(LAPACK_COL_MAJOR, (lapack_int)n, (lapack_int)n, M, ld, piv);
  if (info < 0) {
    runtime_record(c, "sample %ld: stage '%s': LAPACK dgetrf rejected argument %d (a bug in npg)", c->sample, stage, (int)-info);
    return -1;
  }
  double rcond = 0;
  if (info == 0) LAPACKE_dgecon(LAPACK_COL_MAJOR, '1', (lapack_int)n, M, ld, anorm, &rcond);
  if (info > 0 || !(rcond > 1e-15)) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is singular (rcond %.1e)", c->sample, stage, op, rcond);
    return -1;
  }
  return 0;
}

int runtime_lu_solve(const NpgCtx *c, const char *stage, npg_idx n, const double *LU, const lapack_int *piv,
                     bool transpose, double *y) {
  lapack_int ld = (lapack_int)(n ? n : 1);
  lapack_int info = LAPACKE_dgetrs(LAPACK_COL_MAJOR, transpose ? 'N' : 'T', (lapack_int)n, 1, LU, ld, piv, y, ld);
  if (info != 0) {
    runtime_record(c, "sample %ld: stage '%s': LAPACK dgetrs failed (info %d)", c->sample, stage, (int)info);
    return -1;
  }
  return 0;
}

/* y <- M^-k y by LU: one factorization, k solves. */
static int inverse_power(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, long k, double *y) {
  lapack_int *piv = mem_malloc(sizeof(lapack_int) * (size_t)(n ? n : 1));
  if (!piv) {
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return -1;
  }
  int rc = runtime_lu(c, stage, op, n, M, piv);
  for (long r = 0; r < k && rc == 0; r++) rc = runtime_lu_solve(c, stage, n, M, piv, false, y);
  free(piv);
  return rc;
}

/* The eigendecomposition of symmetric M for its power p/q: M overwritten by the
 * eigenvectors (column k of the row-major M), w by the eigenvalues; refused when M is
 * not symmetric, not positive (semi)definite, or singular under a negative power. */
int runtime_sym_eigen(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, long p, long q,
                      double *w) {
  double asym = 0, scale = 0;
  for (npg_idx i = 0; i < n; i++)
    for (npg_idx j = 0; j < n; j++) {
      asym = fmax(asym, fabs(M[i * n + j] - M[j * n + i]));
      scale = fmax(scale, fabs(M[i * n + j]));
    }
  if (asym > 1e-12 * (scale > 0 ? scale : 1)) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is not symmetric (max |M - M^T| = %.1e), so its power %ld/%ld is undefined",
           c->sample, stage, op, asym, p, q);
    return -1;
  }
  lapack_int info = LAPACKE_dsyevd(LAPACK_ROW_MAJOR, 'V', 'U', (lapack_int)n, M, (lapack_int)n, w);
  if (info != 0) {
    runtime_record(c, "sample %ld: stage '%s': eigendecomposition of operator %s failed to converge (info %d)", c->sample, stage,
           op, (int)info);
    return -1;
  }
  /* An eigenvalue within 1e-12 of the largest is zero to rounding (dsyevd's
   * error is about n·eps·‖M‖; a singular 12 x 12 Laplacian gave +6e-15, whose
   * -1/2 power made the answer 1.3e7): a negative power of it is refused as
   * singular, as solve and the reduced evaluator (reduced.c apply_root, the
   * same tolerance) refuse it. */
  double wmax = 0, wmin = INFINITY;
  for (npg_idx i = 0; i < n; i++) wmax = fmax(wmax, fabs(w[i])), wmin = fmin(wmin, w[i]);
  double tol = 1e-12 * (wmax > 0 ? wmax : 1);
  if (n > 0 && wmin < -tol) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is not positive %sdefinite (eigenvalue %.3g), so its power %ld/%ld is undefined",
                   c->sample, stage, op, p < 0 ? "" : "semi", wmin, p, q);
    return -1;
  }
  if (n > 0 && p < 0 && wmin <= tol) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is singular (eigenvalue %.3g, largest %.3g), so its power %ld/%ld "
                      "is undefined",
                   c->sample, stage, op, wmin, wmax, p, q);
    return -1;
  }
  return 0;
}

/* y <- M^(p/q) y for symmetric positive semidefinite M: V diag(w^(p/q)) V^T y. */
static int sym_power(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, long p, long q, double *y) {
  double *w = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  double *t = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  if (!w || !t) {
    free(w);
    free(t);
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return -1;
  }
  int rc = runtime_sym_eigen(c, stage, op, n, M, p, q, w);
  if (rc == 0) {
    double r = (double)p / (double)q;
    for (npg_idx k = 0; k < n; k++) {
      double s = 0;
      for (npg_idx i = 0; i < n; i++) s += M[i * n + k] * y[i];
      double wk = w[k] < 0 ? 0 : w[k];
      t[k] = s * pow(wk, r);
    }
    for (npg_idx i = 0; i < n; i++) {
      double s = 0;
      for (npg_idx k = 0; k < n; k++) s += M[i * n + k] * t[k];
      y[i] = s;
    }
  }
  free(w);
  free(t);
  return rc;
}

int runtime_check_finite(const NpgCtx *c, const char *stage, const char *op, npg_idx n, const double *M,
                         const double *y) {
  /* LAPACKE refuses NaN as a bad argument: say what the data did instead */
  for (npg_idx i = 0; i < n * n; i++)
    if (!isfinite(M[i])) {
      runtime_record(c, "sample %ld: stage '%s': operator %s is not finite (row %ld, column %ld is %g): the sample makes it "
                "undefined (a division by zero or a root of a negative number in its entries?)",
             c->sample, stage, op, (long)(i / n), (long)(i % n), M[i]);
      return -1;
    }
  for (npg_idx i = 0; i < n; i++)
    if (!isfinite(y[i])) {
      runtime_record(c, "sample %ld: stage '%s': the vector operator %s acts on is not finite (entry %ld is %g)", c->sample,
             stage, op, (long)i, y[i]);
      return -1;
    }
  return 0;
}

static int op_power(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, long p, long q, double *y) {
  if (runtime_check_finite(c, stage, op, n, M, y)) return -1;
  if (q != 1) return sym_power(c, stage, op, n, M, p, q, y);
  if (p < 0) return inverse_power(c, stage, op, n, M, -p, y);
  /* positive integer power: repeated products */
  double *t = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  if (!t) {
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return -1;
  }
  for (long r = 0; r < p; r++) {
    for (npg_idx i = 0; i < n; i++) {
      double s = 0;
      for (npg_idx j = 0; j < n; j++) s += M[i * n + j] * y[j];
      t[i] = s;
    }
    memcpy(y, t, sizeof(double) * (size_t)n);
  }
  free(t);
  return 0;
}

/* "AT: error: D/tri.npy: entry [2, 1] = 9 is out of range ...\n<excerpt>": a
 * diagnostic at the use in the program, naming the data file and entry. */
static void gather_error(const NpgCtx *c, const char *stage, const char *at, const char *excerpt, int param,
                         int nentry, const npg_idx *entry, npg_idx value, int dim) {
  NpgHost *h = c->host;
  char where[256] = "";
  size_t len = 0;
  for (int i = 0; i < nentry && len + 24 < sizeof where; i++)
    len += (size_t)snprintf(where + len, sizeof where - len, "%s%ld", i ? ", " : "", (long)entry[i]);
  const char *dname = h && h->dim_names ? h->dim_names[dim] : "?";
  long dsize = (long)c->dims[dim];
  if (param >= 0 && h && h->param_files)
    runtime_record(c, "%s: error: %s: entry [%s] = %ld is out of range for dim %s (size %ld), used as an index in stage '%s'\n%s",
           at, h->param_files[param], where, (long)value, dname, dsize, stage, excerpt);
  else
    runtime_record(c, "%s: error: stage '%s' at [%s]: index %ld is out of range for dim %s (size %ld)\n%s", at, stage, where,
           (long)value, dname, dsize, excerpt);
}

const NpgRt npg_runtime = {op_power,   scratch,    release,   gather_error, rows_vv,
                           rows_vs,    rows_sv,    rows_unary, rows_fill,    runtime_sparse_power,
                           runtime_power_jvp, runtime_power_vjp, runtime_sparse_power_jvp,
                           runtime_sparse_power_vjp};
