/* sparse.c — declared operators whose entries grow like K·N (an index-table
 * gather, a stencil, a mesh's incidence): assembled in compressed sparse
 * columns and solved through SuiteSparse (DESIGN §13).
 *
 *   pattern  once per param binding: the generated enumerator lists every
 *            contribution's (row, col) — guards and index tables depend on
 *            params and index variables only — and they are sorted into CSC
 *            with duplicates merged; map[k] is contribution k's slot.
 *   values   per evaluation: the same enumerator in the same order gives
 *            each contribution's value, and Ax[map[k]] += value.
 *   solve    M^-k y: CHOLMOD (supernodal Cholesky) when M is symmetric, its
 *            symbolic analysis kept across evaluations; when the
 *            factorization finds M not positive definite, UMFPACK from then
 *            on (its symbolic analysis kept too). M^k y: k products.
 *   roots    M^(p/q) y for symmetric positive definite M by the Lanczos
 *            process on sparse products (krylov.h, full reorthogonalization,
 *            an a-posteriori estimate below NPG_SPARSE_ROOT_TOL); one that
 *            does not converge within its steps is refused, naming the
 *            estimate reached.
 *
 * Small operators go to the dense path (op_power) below a size chosen by
 * measurement (NpgHost.sparse_min_rows). Every SuiteSparse status is
 * checked and worded for the user.
 */
#include "runtime.h"

#include "alloc.h"
#include "krylov.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <suitesparse/cholmod.h>
#include <suitesparse/umfpack.h>

/* A root by Lanczos stops when two approximations 4 steps apart differ by
 * less than this (relative): the dense eigendecomposition it replaces is
 * exact to about 1e-13 relative at the sizes tests compare. */
#define NPG_SPARSE_ROOT_TOL 1e-13
/* The Lanczos vectors of a root: at most this many steps, and at most
 * NPG_SPARSE_ROOT_BYTES of them (a million rows: 16 steps a 128 MB). */
#define NPG_SPARSE_ROOT_STEPS 400
#define NPG_SPARSE_ROOT_BYTES (2000L * 1000 * 1000)

struct SparseOp {
  bool ready;               /* pattern built for the current binding */
  npg_idx n;                /* rows = cols */
  npg_idx ncontrib;         /* contributions per evaluation */
  npg_idx *map;             /* contribution -> slot */
  SuiteSparse_long *Ap, *Ai;/* CSC pattern, nnz = Ap[n] */
  double *Ax;
  npg_idx *transpose;       /* slot of (j, i) for slot (i, j), -1 if absent */
  bool symmetric_pattern;
  bool not_spd;             /* CHOLMOD found it indefinite once: UMFPACK */
  /* CHOLMOD */
  cholmod_common cc;
  bool cc_started;
  cholmod_factor *L;
  /* UMFPACK */
  void *symbolic;
  double umf_control[UMFPACK_CONTROL];
};


static void op_clear(SparseOp *s) {
  if (s->L) cholmod_l_free_factor(&s->L, &s->cc);
  if (s->cc_started) cholmod_l_finish(&s->cc);
  if (s->symbolic) umfpack_dl_free_symbolic(&s->symbolic);
  free(s->map);
  free(s->Ap);
  free(s->Ai);
  free(s->Ax);
  free(s->transpose);
  memset(s, 0, sizeof *s);
}

void runtime_sparse_reset(NpgHost *h) {
  for (int i = 0; i < h->nsparse; i++) op_clear(&h->sparse[i]);
}

void runtime_sparse_free(NpgHost *h) {
  runtime_sparse_reset(h);
  free(h->sparse);
  h->sparse = NULL;
  h->nsparse = 0;
}

static SparseOp *op_slot(const NpgCtx *c, int opid) {
  NpgHost *h = c->host;
  if (opid >= h->nsparse) {
    SparseOp *grown = mem_realloc(h->sparse, sizeof(SparseOp) * (size_t)(opid + 1));
    if (!grown) return NULL;
    memset(grown + h->nsparse, 0, sizeof(SparseOp) * (size_t)(opid + 1 - h->nsparse));
    h->sparse = grown;
    h->nsparse = opid + 1;
  }
  return &h->sparse[opid];
}

/* A column's distinct rows Ai[0 .. len) put in increasing order; rank[r] = where
 * the entry at r went. Columns of a stencil or a row-ordered enumeration come
 * out of the column pass already sorted, so this is rarely more than a check. */
typedef struct RowAt {
  SuiteSparse_long row;
  npg_idx at;
} RowAt;

static int by_row(const void *a, const void *b) {
  SuiteSparse_long x = ((const RowAt *)a)->row, y = ((const RowAt *)b)->row;
  return (x > y) - (x < y);
}

static void sort_column(SuiteSparse_long *Ai, npg_idx len, npg_idx *rank, RowAt *scratch) {
  for (npg_idx r = 0; r < len; r++) scratch[r] = (RowAt){Ai[r], r};
  if (len <= 16) { /* insertion sort: the few entries of a stencil's column */
    for (npg_idx r = 1; r < len; r++) {
      RowAt x = scratch[r];
      npg_idx q = r;
      for (; q > 0 && scratch[q - 1].row > x.row; q--) scratch[q] = scratch[q - 1];
      scratch[q] = x;
    }
  } else {
    qsort(scratch, (size_t)len, sizeof *scratch, by_row);
  }
  for (npg_idx r = 0; r < len; r++) Ai[r] = scratch[r].row, rank[scratch[r].at] = r;
}

/* The slot of (j, i) for every slot (i, j), -1 when absent, in one pass: for
 * each column i, next[i] walks its sorted rows as the columns j that hold
 * row i go by in increasing order. */
static void transpose_slots(SparseOp *s, npg_idx n, npg_idx *next) {
  s->symmetric_pattern = true;
  for (npg_idx i = 0; i < n; i++) next[i] = s->Ap[i];
  for (npg_idx j = 0; j < n; j++)
    for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++) {
      npg_idx i = s->Ai[p], q = next[i];
      while (q < s->Ap[i + 1] && s->Ai[q] < j) q++;
      next[i] = q;
      s->transpose[p] = q < s->Ap[i + 1] && s->Ai[q] == j ? q : -1;
      if (s->transpose[p] < 0) s->symmetric_pattern = false;
    }
}

/* The contributions' slots in CSC, each column's rows in increasing order
 * and duplicates merged: the contributions counted by column and placed
 * there (one stable pass), then each column's distinct rows found with a
 * marker per row (last[r] >= the column's first slot) and sorted.
 * O(count + n) for the short columns of a stencil or a mesh. On return
 * s->Ap, Ai (nnz of them) and map are set; -1 when out of memory. */
static int csc_slots(SparseOp *s, const npg_idx *rows, const npg_idx *cols, npg_idx count, npg_idx n, npg_idx *nnz_out) {
  size_t m = (size_t)(count ? count : 1);
  npg_idx *start = mem_calloc((size_t)n + 1, sizeof(npg_idx)), *last = mem_malloc(sizeof(npg_idx) * ((size_t)n + 1));
  npg_idx *k_at = mem_malloc(sizeof(npg_idx) * m), *rank = mem_malloc(sizeof(npg_idx) * ((size_t)n + 1));
  SuiteSparse_long *Ai = mem_malloc(sizeof(SuiteSparse_long) * m); /* at most count slots; shrunk below */
  RowAt *scratch = mem_malloc(sizeof(RowAt) * ((size_t)n + 1));
  int rc = -1;
  if (!start || !last || !k_at || !rank || !Ai || !scratch) goto done;
  for (npg_idx k = 0; k < count; k++) start[cols[k] + 1]++;
  for (npg_idx j = 0; j < n; j++) start[j + 1] += start[j];
  for (npg_idx k = 0; k < count; k++) k_at[start[cols[k]]++] = k; /* start[j] is now column j's end */
  for (npg_idx r = 0; r < n; r++) last[r] = -1;
  npg_idx nnz = 0, from = 0;
  s->Ap[0] = 0;
  for (npg_idx j = 0; j < n; j++) {
    npg_idx first = nnz;
    bool sorted = true;
    for (npg_idx p = from; p < start[j]; p++) {
      npg_idx k = k_at[p], r = rows[k];
      if (last[r] < first) {
        sorted = sorted && (nnz == first || Ai[nnz - 1] < r);
        last[r] = nnz;
        Ai[nnz++] = r;
      }
      s->map[k] = last[r];
    }
    if (!sorted) {
      sort_column(Ai + first, nnz - first, rank, scratch);
      for (npg_idx p = from; p < start[j]; p++) s->map[k_at[p]] = first + rank[s->map[k_at[p]] - first];
    }
    from = start[j];
    s->Ap[j + 1] = nnz;
  }
  SuiteSparse_long *fit = mem_realloc(Ai, sizeof(SuiteSparse_long) * (size_t)(nnz ? nnz : 1));
  s->Ai = fit ? fit : Ai;
  Ai = NULL;
  *nnz_out = nnz;
  rc = 0;
done:
  free(start), free(last), free(k_at), free(rank), free(Ai), free(scratch);
  return rc;
}

/* The pattern: every contribution's (row, col) listed by the generated
 * enumerator, then placed in CSC (csc_slots) and the transposed slots found. */
static int build_pattern(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, npg_idx n,
                         NpgOpEntriesFn entries) {
  npg_idx count = entries(c, 0, NULL, NULL, NULL, NULL);
  size_t m = (size_t)(count ? count : 1);
  npg_idx *rows = mem_malloc(sizeof(npg_idx) * m), *cols = mem_malloc(sizeof(npg_idx) * m), nnz = 0;
  s->map = mem_malloc(sizeof(npg_idx) * m);
  s->Ap = mem_malloc(sizeof(SuiteSparse_long) * (size_t)(n + 1));
  int rc = -1;
  if (!rows || !cols || !s->map || !s->Ap) {
    runtime_record(c, "sample %ld: out of memory assembling operator %s of stage '%s' (%ld entries)", c->sample, op,
                   stage, (long)count);
    goto done;
  }
  if (entries(c, count, rows, cols, NULL, NULL) != count) {
    runtime_record(c, "sample %ld: operator %s: its entries changed between two enumerations (a bug in npg)", c->sample,
                   op);
    goto done;
  }
  if (csc_slots(s, rows, cols, count, n, &nnz) != 0) {
    runtime_record(c, "sample %ld: out of memory assembling operator %s of stage '%s' (%ld entries)", c->sample, op,
                   stage, (long)count);
    goto done;
  }
  free(rows), free(cols);
  rows = cols = NULL;
  s->Ax = mem_malloc(sizeof(double) * (size_t)(nnz ? nnz : 1));
  s->transpose = mem_malloc(sizeof(npg_idx) * (size_t)(nnz ? nnz : 1));
  npg_idx *next = mem_malloc(sizeof(npg_idx) * (size_t)(n + 1));
  if (!s->Ax || !s->transpose || !next) {
    free(next);
    runtime_record(c, "sample %ld: out of memory assembling operator %s of stage '%s' (%ld nonzeros)", c->sample, op,
                   stage, (long)nnz);
    goto done;
  }
  transpose_slots(s, n, next);
  free(next);
  rc = 0;
done:
  free(rows), free(cols);
  if (rc) return rc;
  s->n = n;
  s->ncontrib = count;
  s->ready = true;
  ((NpgHost *)c->host)->sparse_patterns++;
  return 0;
}

/* Ax from this evaluation's contributions, each added into its slot by
 * the generated enumerator; non-finite entries refused. */
static int fill_values(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, NpgOpEntriesFn entries) {
  memset(s->Ax, 0, sizeof(double) * (size_t)s->Ap[s->n]);
  if (entries(c, s->ncontrib, NULL, NULL, s->map, s->Ax) != s->ncontrib) {
    runtime_record(c, "sample %ld: operator %s: its entries changed between two enumerations (a bug in npg)", c->sample, op);
    return -1;
  }
  for (npg_idx j = 0; j < s->n; j++)
    for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++)
      if (!isfinite(s->Ax[p])) {
        runtime_record(c, "sample %ld: stage '%s': operator %s is not finite (row %ld, column %ld is %g): the sample makes it "
                  "undefined (a division by zero or a root of a negative number in its entries?)",
               c->sample, stage, op, (long)s->Ai[p], (long)j, s->Ax[p]);
        return -1;
      }
  return 0;
}

static bool values_symmetric(const SparseOp *s) {
  if (!s->symmetric_pattern) return false;
  double scale = 0, asym = 0;
  npg_idx nnz = s->Ap[s->n];
  for (npg_idx p = 0; p < nnz; p++) {
    scale = fmax(scale, fabs(s->Ax[p]));
    asym = fmax(asym, fabs(s->Ax[p] - s->Ax[s->transpose[p]]));
  }
  return asym <= 1e-14 * scale;
}

static cholmod_sparse csc_view(SparseOp *s, int stype) {
  cholmod_sparse A;
  memset(&A, 0, sizeof A);
  A.nrow = A.ncol = (size_t)s->n;
  A.nzmax = (size_t)s->Ap[s->n];
  A.p = s->Ap;
  A.i = s->Ai;
  A.x = s->Ax;
  A.stype = stype;       /* 1: CHOLMOD reads the upper triangle of a symmetric matrix */
  A.itype = CHOLMOD_LONG;
  A.xtype = CHOLMOD_REAL;
  A.dtype = CHOLMOD_DOUBLE;
  A.sorted = 1;
  A.packed = 1;
  return A;
}

/* LAPACK's 1-norm estimator (Hager, Higham), by reverse communication: the
 * one dgecon uses for the dense path. */
extern void dlacn2_(const int *n, double *v, double *x, int *isgn, double *est, int *kase, int *isave);

/* x <- M⁻¹ x (trans false) or M⁻ᵀ x (true) by a factorization already made:
 * 0, or -1 on failure. */
typedef int (*FactorSolve)(SparseOp *s, void *factor, bool trans, double *x, double *b);

/* rcond = 1 / (‖M‖₁ ‖M⁻¹‖₁), ‖M⁻¹‖₁ estimated with a few solves by the
 * factorization `factor`: the estimate the dense path's dgecon makes. -1 on
 * failure. */
static double factor_rcond(SparseOp *s, FactorSolve solve, void *factor) {
  int n = (int)s->n, kase = 0, isave[3] = {0, 0, 0};
  double est = 0, anorm = 0;
  for (npg_idx j = 0; j < s->n; j++) {
    double col = 0;
    for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++) col += fabs(s->Ax[p]);
    anorm = fmax(anorm, col);
  }
  double *x = mem_malloc(sizeof(double) * (size_t)(n ? n : 1)), *v = mem_malloc(sizeof(double) * (size_t)(n ? n : 1)),
         *b = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  int *isgn = mem_malloc(sizeof(int) * (size_t)(n ? n : 1));
  double rcond = -1;
  if (x && v && b && isgn) {
    for (;;) {
      dlacn2_(&n, v, x, isgn, &est, &kase, isave);
      if (kase == 0) break;
      memcpy(b, x, sizeof(double) * (size_t)n);
      if (solve(s, factor, kase != 1, x, b) != 0) break;
    }
    if (kase == 0) rcond = est > 0 && anorm > 0 ? 1 / (anorm * est) : 0;
  }
  free(x), free(v), free(b), free(isgn);
  return rcond;
}

static int umfpack_factor_solve(SparseOp *s, void *numeric, bool trans, double *x, double *b) {
  return umfpack_dl_solve(trans ? UMFPACK_At : UMFPACK_A, s->Ap, s->Ai, s->Ax, x, b, numeric, s->umf_control, NULL) ==
                 UMFPACK_OK
             ? 0
             : -1;
}

/* M is symmetric: Mᵀ = M. */
static int cholmod_factor_solve(SparseOp *s, void *factor, bool trans, double *x, double *b) {
  (void)trans;
  cholmod_dense d;
  memset(&d, 0, sizeof d);
  d.nrow = d.d = d.nzmax = (size_t)s->n;
  d.ncol = 1;
  d.xtype = CHOLMOD_REAL;
  d.dtype = CHOLMOD_DOUBLE;
  d.x = b;
  cholmod_dense *r = cholmod_l_solve(CHOLMOD_A, factor, &d, &s->cc);
  if (!r) return -1;
  memcpy(x, r->x, sizeof(double) * (size_t)s->n);
  cholmod_l_free_dense(&r, &s->cc);
  return 0;
}

/* y <- M^-k y by Cholesky; 1 when M is not positive definite (the caller
 * moves to UMFPACK), -1 on another failure. */
static int cholesky_solve(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, long k, double *y) {
  if (!s->cc_started) {
    cholmod_l_start(&s->cc);
    s->cc.print = 0;
    /* supernodal LL': an indefinite matrix fails (CHOLMOD_NOT_POSDEF) —
       the simplicial LDL' CHOLMOD picks for small matrices would factor
       some of them without pivoting, unstably */
    s->cc.supernodal = CHOLMOD_SUPERNODAL;
    s->cc_started = true;
  }
  cholmod_sparse A = csc_view(s, 1);
  if (!s->L) {
    s->L = cholmod_l_analyze(&A, &s->cc);
    if (!s->L) {
      runtime_record(c, "sample %ld: stage '%s': CHOLMOD could not analyze operator %s (status %d)", c->sample, stage, op,
             s->cc.status);
      return -1;
    }
  }
  if (!cholmod_l_factorize(&A, s->L, &s->cc) && s->cc.status != CHOLMOD_NOT_POSDEF) {
    runtime_record(c, "sample %ld: stage '%s': CHOLMOD could not factorize operator %s (status %d)", c->sample, stage, op,
           s->cc.status);
    return -1;
  }
  if (s->cc.status == CHOLMOD_NOT_POSDEF || s->L->minor < (size_t)s->n) return 1;
  ((NpgHost *)c->host)->sparse_cholesky++;
  /* CHOLMOD's rcond is the squared ratio of L's smallest to largest
     diagonal entry: a singular Laplacian of 150 rows left 2e-15 there, so
     below 1e-10 the dense path's estimate decides, as for UMFPACK */
  double rcond = cholmod_l_rcond(s->L, &s->cc);
  if (!(rcond > 1e-10)) rcond = factor_rcond(s, cholmod_factor_solve, s->L);
  if (!(rcond > 1e-15)) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is singular (CHOLMOD's rcond %.1e)", c->sample, stage, op, rcond);
    return -1;
  }
  cholmod_dense b;
  memset(&b, 0, sizeof b);
  b.nrow = b.d = b.nzmax = (size_t)s->n;
  b.ncol = 1;
  b.xtype = CHOLMOD_REAL;
  b.dtype = CHOLMOD_DOUBLE;
  for (long r = 0; r < k; r++) {
    b.x = y;
    cholmod_dense *x = cholmod_l_solve(CHOLMOD_A, s->L, &b, &s->cc);
    if (!x) {
      runtime_record(c, "sample %ld: stage '%s': CHOLMOD's solve with operator %s failed (status %d)", c->sample, stage, op,
             s->cc.status);
      return -1;
    }
    memcpy(y, x->x, sizeof(double) * (size_t)s->n);
    cholmod_l_free_dense(&x, &s->cc);
  }
  return 0;
}

/* M's numeric LU by UMFPACK into *numeric (its symbolic analysis kept per binding): 0, or
 * -1 after a message (singular, or a failure). */
static int lu_numeric(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, void **numeric) {
  if (!s->symbolic) {
    umfpack_dl_defaults(s->umf_control);
    int st = (int)umfpack_dl_symbolic((SuiteSparse_long)s->n, (SuiteSparse_long)s->n, s->Ap, s->Ai, s->Ax,
                                      &s->symbolic, s->umf_control, NULL);
    if (st != UMFPACK_OK) {
      runtime_record(c, "sample %ld: stage '%s': UMFPACK could not analyze operator %s (status %d)", c->sample, stage, op, st);
      return -1;
    }
  }
  *numeric = NULL;
  double info[UMFPACK_INFO];
  ((NpgHost *)c->host)->sparse_lu++;
  int st = (int)umfpack_dl_numeric(s->Ap, s->Ai, s->Ax, s->symbolic, numeric, s->umf_control, info);
  /* UMFPACK's own rcond is the ratio of U's smallest to largest pivot: a
     singular matrix leaves ~n·eps there after rounding, so below 1e-10 the
     dense path's estimate decides (a few more solves, only then) */
  double rcond = st == UMFPACK_OK ? info[UMFPACK_RCOND] : 0.0;
  if (st == UMFPACK_OK && !(rcond > 1e-10)) rcond = factor_rcond(s, umfpack_factor_solve, *numeric);
  if (st == UMFPACK_WARNING_singular_matrix || (st == UMFPACK_OK && !(rcond > 1e-15))) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is singular (rcond %.1e)", c->sample, stage, op, rcond);
    umfpack_dl_free_numeric(numeric);
    return -1;
  }
  if (st != UMFPACK_OK) {
    runtime_record(c, "sample %ld: stage '%s': UMFPACK could not factorize operator %s (status %d)", c->sample, stage, op, st);
    umfpack_dl_free_numeric(numeric);
    return -1;
  }
  return 0;
}

/* y <- M^-k y by UMFPACK's LU. */
static int lu_solve(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, long k, double *y) {
  void *numeric = NULL;
  if (lu_numeric(c, stage, op, s, &numeric) != 0) return -1;
  double *x = mem_malloc(sizeof(double) * (size_t)(s->n ? s->n : 1));
  if (!x) {
    umfpack_dl_free_numeric(&numeric);
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return -1;
  }
  int rc = 0;
  for (long r = 0; r < k && rc == 0; r++) {
    int st = (int)umfpack_dl_solve(UMFPACK_A, s->Ap, s->Ai, s->Ax, x, y, numeric, s->umf_control, NULL);
    if (st != UMFPACK_OK) {
      runtime_record(c, "sample %ld: stage '%s': UMFPACK's solve with operator %s failed (status %d)", c->sample, stage, op, st);
      rc = -1;
    } else {
      memcpy(y, x, sizeof(double) * (size_t)s->n);
    }
  }
  free(x);
  umfpack_dl_free_numeric(&numeric);
  return rc;
}

/* y <- M^k y, k products with the CSC matrix. */
static int sparse_products(const NpgCtx *c, const char *stage, SparseOp *s, long k, double *y) {
  double *t = mem_malloc(sizeof(double) * (size_t)(s->n ? s->n : 1));
  if (!t) {
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return -1;
  }
  for (long r = 0; r < k; r++) {
    memset(t, 0, sizeof(double) * (size_t)s->n);
    for (npg_idx j = 0; j < s->n; j++)
      for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++) t[s->Ai[p]] += s->Ax[p] * y[j];
    memcpy(y, t, sizeof(double) * (size_t)s->n);
  }
  free(t);
  return 0;
}

static void csc_matvec(void *user, int n, const double *x, double *y) {
  const SparseOp *s = user;
  memset(y, 0, sizeof(double) * (size_t)n);
  for (npg_idx j = 0; j < n; j++)
    for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++) y[s->Ai[p]] += s->Ax[p] * x[j];
}

/* y <- M^(p/q) y for symmetric positive definite M by Lanczos on sparse
 * products. */
static int krylov_root(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, long p, long q, double *y) {
  if (!values_symmetric(s)) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is not symmetric, so its power %ld/%ld is undefined",
                   c->sample, stage, op, p, q);
    return -1;
  }
  long steps = NPG_SPARSE_ROOT_STEPS;
  if (steps > NPG_SPARSE_ROOT_BYTES / 8 / (s->n + 1) - 1) steps = NPG_SPARSE_ROOT_BYTES / 8 / (s->n + 1) - 1;
  if (steps < 8) steps = 8;
  Krylov k;
  if (krylov_init_steps(&k, s->n, steps) != 0) {
    krylov_free(&k);
    runtime_record(c, "sample %ld: out of memory in stage '%s' (the Lanczos vectors of operator %s)", c->sample, stage,
                   op);
    return -1;
  }
  int done = 0;
  double estimate = 0;
  int rc = krylov_power_op(&k, (int)s->n, csc_matvec, s, p, q, NPG_SPARSE_ROOT_TOL, (int)k.maxsteps, y, &done,
                           &estimate);
  /* stopped before any step counted: a Ritz value, which bounds M's smallest eigenvalue from
   * above, was not positive (krylov.c approximate(): k.d ascending) — say so, as the dense path
   * does, rather than "stopped after 0 steps (estimate inf)" (trial3) */
  double ritz = rc > 0 && done == 0 && k.maxsteps > 0 ? k.d[0] : NAN;
  krylov_free(&k);
  if (rc < 0) {
    runtime_record(c, "sample %ld: stage '%s': LAPACK failed in the Lanczos root of operator %s", c->sample, stage, op);
    return -1;
  }
  if (rc > 0 && !isnan(ritz)) {
    runtime_record(c, "sample %ld: stage '%s': operator %s is %snot positive definite (an eigenvalue is at most "
                      "%.3g: a Lanczos Ritz value), so its power %ld/%ld is undefined",
                   c->sample, stage, op, ritz > 0 ? "numerically " : "", ritz, p, q);
    return -1;
  }
  if (rc > 0) {
    runtime_record(c, "sample %ld: stage '%s': the Lanczos process for the power %ld/%ld of operator %s stopped after %d "
                      "steps (estimate %.1e, wanted %.0e): the operator is not positive definite, or too ill "
                      "conditioned for that many steps",
                   c->sample, stage, p, q, op, done ? done : (int)k.maxsteps, estimate, NPG_SPARSE_ROOT_TOL);
    return -1;
  }
  return 0;
}

/* The assembled matrix as a dense row-major n x n array (for small
 * operators and roots). */
/* The dense row-major matrix of values Ax on s's pattern. */
static double *densify_values(const NpgCtx *c, const char *stage, const SparseOp *s, const double *Ax) {
  double *M = mem_calloc((size_t)s->n * (size_t)s->n, sizeof(double));
  if (!M) {
    runtime_record(c, "sample %ld: out of memory in stage '%s' (%ld x %ld operator)", c->sample, stage, (long)s->n, (long)s->n);
    return NULL;
  }
  for (npg_idx j = 0; j < s->n; j++)
    for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++) M[s->Ai[p] * s->n + j] = Ax[p];
  return M;
}

static double *densify(const NpgCtx *c, const char *stage, const SparseOp *s) { return densify_values(c, stage, s, s->Ax); }

int runtime_sparse_power(const NpgCtx *c, const char *stage, const char *op, int opid, npg_idx n,
                         NpgOpEntriesFn entries, long p, long q, double *y) {
  for (npg_idx i = 0; i < n; i++)
    if (!isfinite(y[i])) {
      runtime_record(c, "sample %ld: stage '%s': the vector operator %s acts on is not finite (entry %ld is %g)", c->sample,
             stage, op, (long)i, y[i]);
      return -1;
    }
  SparseOp *s = op_slot(c, opid);
  if (!s) {
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return -1;
  }
  if (!s->ready && build_pattern(c, stage, op, s, n, entries) != 0) {
    op_clear(s);
    return -1;
  }
  if (fill_values(c, stage, op, s, entries) != 0) return -1;
  NpgHost *h = c->host;
  if (n < h->sparse_min_rows) {
    double *M = densify(c, stage, s);
    if (!M) return -1;
    int rc = npg_runtime.op_power(c, stage, op, n, M, p, q, y);
    free(M);
    return rc;
  }
  if (q != 1 && p < 0 && values_symmetric(s)) {
    /* A negative root needs M nonsingular, and Lanczos cannot tell: with y
     * in M's range it never meets the null space and converges to the
     * pseudo-inverse's root; with rounding in it, to that noise amplified.
     * The factorization solve uses decides, with solve's tolerances. */
    int rc = cholesky_solve(c, stage, op, s, 0, y);
    if (rc < 0) return -1;
    if (rc > 0) {
      if (lu_solve(c, stage, op, s, 0, y) != 0) return -1;
      runtime_record(c, "sample %ld: stage '%s': operator %s is not positive definite (its Cholesky factorization "
                        "breaks down), so its power %ld/%ld is undefined",
                     c->sample, stage, op, p, q);
      return -1;
    }
  }
  if (q != 1) return krylov_root(c, stage, op, s, p, q, y);
  if (p > 0) return sparse_products(c, stage, s, p, y);
  if (!s->not_spd && values_symmetric(s)) {
    int rc = cholesky_solve(c, stage, op, s, -p, y);
    if (rc <= 0) return rc;
    s->not_spd = true;   /* indefinite: LU from now on */
  }
  return lu_solve(c, stage, op, s, -p, y);
}

/* ---------------------------------------------------------------- derivatives (DESIGN §17)
 *
 * y = M^r x for a sparse M: M's values, and its tangent dM's or the cotangent of its values,
 * live on M's pattern (the derivative enumerator, NpgOpDerivFn, lists M's contributions in
 * the order the entries function does, so contribution k lands in slot map[k] for both).
 * Integer powers: products by the CSC values, or one factorization (CHOLMOD when M is
 * symmetric positive definite, else UMFPACK) for every solve of the tangent's or the
 * transposed ones: d(M^-1 f) = M^-1 (df - dM M^-1 f). Roots, and operators under the dense
 * threshold: densified, then the dense derivatives (deriv.c, Daleckii-Krein). */

/* out <- V x (trans: V^T x) for values V on s's pattern. */
static void csc_apply(const SparseOp *s, const double *V, bool trans, const double *x, double *out) {
  memset(out, 0, sizeof(double) * (size_t)s->n);
  for (npg_idx j = 0; j < s->n; j++)
    for (SuiteSparse_long p = s->Ap[j]; p < s->Ap[j + 1]; p++) {
      if (trans) out[j] += V[p] * x[s->Ai[p]];
      else out[s->Ai[p]] += V[p] * x[j];
    }
}

/* M's factorization for solves with M and M^T. */
typedef struct SparseFactor {
  FactorSolve solve;
  void *factor;
} SparseFactor;

static int sparse_factor(const NpgCtx *c, const char *stage, const char *op, SparseOp *s, SparseFactor *f) {
  if (!s->not_spd && values_symmetric(s)) {
    int rc = cholesky_solve(c, stage, op, s, 0, NULL);
    if (rc < 0) return -1;
    if (rc == 0) {
      *f = (SparseFactor){cholmod_factor_solve, s->L};
      return 0;
    }
    s->not_spd = true; /* indefinite: LU from now on */
  }
  *f = (SparseFactor){umfpack_factor_solve, NULL};
  return lu_numeric(c, stage, op, s, &f->factor);
}

static void sparse_unfactor(SparseFactor *f) {
  if (f->solve == umfpack_factor_solve && f->factor) umfpack_dl_free_numeric(&f->factor);
}

/* M's pattern and values for this evaluation: the SparseOp, or NULL after a message. */
static SparseOp *sparse_ready(const NpgCtx *c, const char *stage, const char *op, int opid, npg_idx n,
                              NpgOpEntriesFn entries, const double *x) {
  for (npg_idx i = 0; i < n; i++)
    if (!isfinite(x[i])) {
      runtime_record(c, "sample %ld: stage '%s': the vector operator %s acts on is not finite (entry %ld is %g)", c->sample,
             stage, op, (long)i, x[i]);
      return NULL;
    }
  SparseOp *s = op_slot(c, opid);
  if (!s) {
    runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
    return NULL;
  }
  if (!s->ready && build_pattern(c, stage, op, s, n, entries) != 0) {
    op_clear(s);
    return NULL;
  }
  return fill_values(c, stage, op, s, entries) == 0 ? s : NULL;
}

int runtime_sparse_power_jvp(const NpgCtx *c, const NpgCtx *d, const char *stage, const char *op, int opid, npg_idx n,
                             NpgOpEntriesFn entries, NpgOpDerivFn dentries, long p, long q, double *x, double *dx) {
  SparseOp *s = sparse_ready(c, stage, op, opid, n, entries, x);
  if (!s) return -1;
  size_t nnz = (size_t)s->Ap[n];
  double *dA = mem_calloc(nnz ? nnz : 1, sizeof(double)), *t = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  double *u = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  int rc = !dA || !t || !u ? -1 : 0;
  if (rc) runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
  if (rc == 0) dentries(c, d, 0, s->ncontrib, s->map, dA);
  if (rc == 0 && (n < ((NpgHost *)c->host)->sparse_min_rows || q != 1)) {
    double *M = densify(c, stage, s), *dM = M ? densify_values(c, stage, s, dA) : NULL;
    rc = M && dM ? runtime_power_jvp(c, stage, op, n, M, dM, p, q, x, dx) : -1;
    free(M), free(dM), free(dA), free(t), free(u);
    return rc;
  }
  SparseFactor f = {NULL, NULL};
  if (rc == 0 && p < 0) rc = sparse_factor(c, stage, op, s, &f);
  for (long k = 0; k < labs(p) && rc == 0; k++) {
    if (p > 0) { /* x' = M x, dx' = M dx + dM x */
      csc_apply(s, s->Ax, false, x, t);
      csc_apply(s, s->Ax, false, dx, u);
      csc_apply(s, dA, false, x, dx);
      for (npg_idx i = 0; i < n; i++) dx[i] += u[i];
      memcpy(x, t, sizeof(double) * (size_t)n);
    } else { /* x' = M^-1 x, dx' = M^-1 (dx - dM x') */
      memcpy(t, x, sizeof(double) * (size_t)n);
      rc = f.solve(s, f.factor, false, x, t);
      if (rc == 0) {
        csc_apply(s, dA, false, x, u);
        for (npg_idx i = 0; i < n; i++) t[i] = dx[i] - u[i];
        rc = f.solve(s, f.factor, false, dx, t);
      }
      if (rc) runtime_record(c, "sample %ld: stage '%s': a solve with operator %s failed", c->sample, stage, op);
    }
  }
  sparse_unfactor(&f);
  free(dA), free(t), free(u);
  return rc;
}

int runtime_sparse_power_vjp(const NpgCtx *c, const NpgCtx *d, const char *stage, const char *op, int opid, npg_idx n,
                             NpgOpEntriesFn entries, NpgOpDerivFn dentries, long p, long q, const double *x,
                             double *ybar) {
  SparseOp *s = sparse_ready(c, stage, op, opid, n, entries, x);
  if (!s) return -1;
  size_t nnz = (size_t)s->Ap[n];
  long k = labs(p);
  double *Ab = mem_calloc(nnz ? nnz : 1, sizeof(double)), *t = mem_malloc(sizeof(double) * (size_t)(n ? n : 1));
  double *ws = mem_malloc(sizeof(double) * (size_t)(n ? n : 1) * (size_t)(k + 1));
  int rc = !Ab || !t || !ws ? -1 : 0;
  if (rc) runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
  if (rc == 0 && (n < ((NpgHost *)c->host)->sparse_min_rows || q != 1)) {
    double *M = densify(c, stage, s), *Mb = M ? mem_calloc((size_t)n * (size_t)n + 1, sizeof(double)) : NULL;
    rc = M && Mb ? runtime_power_vjp(c, stage, op, n, M, Mb, p, q, x, ybar) : -1;
    for (npg_idx j = 0; rc == 0 && j < n; j++) /* the cotangent of each value on the pattern */
      for (SuiteSparse_long pp = s->Ap[j]; pp < s->Ap[j + 1]; pp++) Ab[pp] = Mb[s->Ai[pp] * n + j];
    if (rc == 0) dentries(c, d, 1, s->ncontrib, s->map, Ab);
    free(M), free(Mb), free(Ab), free(t), free(ws);
    return rc;
  }
  SparseFactor f = {NULL, NULL};
  if (rc == 0 && p < 0) rc = sparse_factor(c, stage, op, s, &f);
  if (rc == 0) memcpy(ws, x, sizeof(double) * (size_t)n);
  for (long j = 0; j < k && rc == 0; j++) { /* ws[j] = M^(±j) x */
    double *from = ws + (size_t)j * (size_t)n, *to = from + n;
    if (p > 0) csc_apply(s, s->Ax, false, from, to);
    else rc = f.solve(s, f.factor, false, to, from);
  }
  for (long j = k - 1; j >= 0 && rc == 0; j--) {
    const double *from = ws + (size_t)j * (size_t)n, *to = from + n;
    if (p > 0) { /* y = M w: Mbar += ybar w^T on the pattern, ybar <- M^T ybar */
      for (npg_idx col = 0; col < n; col++)
        for (SuiteSparse_long pp = s->Ap[col]; pp < s->Ap[col + 1]; pp++) Ab[pp] += ybar[s->Ai[pp]] * from[col];
      csc_apply(s, s->Ax, true, ybar, t);
      memcpy(ybar, t, sizeof(double) * (size_t)n);
    } else { /* y = M^-1 w: ybar <- M^-T ybar, Mbar -= ybar y^T on the pattern */
      memcpy(t, ybar, sizeof(double) * (size_t)n);
      rc = f.solve(s, f.factor, true, ybar, t);
      for (npg_idx col = 0; rc == 0 && col < n; col++)
        for (SuiteSparse_long pp = s->Ap[col]; pp < s->Ap[col + 1]; pp++) Ab[pp] -= ybar[s->Ai[pp]] * to[col];
    }
  }
  if (rc > 0 || (rc < 0 && !((NpgHost *)c->host)->msg[0]))
    runtime_record(c, "sample %ld: stage '%s': a solve with operator %s failed", c->sample, stage, op), rc = -1;
  if (rc == 0) dentries(c, d, 1, s->ncontrib, s->map, Ab);
  sparse_unfactor(&f);
  free(Ab), free(t), free(ws);
  return rc;
}
