/* api_full.c — the full evaluator's `output op` operators as CSR (npg.h),
 * and the .npy writers of the public API.
 *
 * An operator's entries are polynomials in stage values; its tensor
 * builders stream them as (row, column, inputs, coefficient), the entries
 * pre-multiplication consumes. Summing coefficient × inputs at the values
 * of the last evaluation gives the operator itself, sparse as the program
 * wrote it: no dense n × n matrix is formed. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "compile.h"
#include "emit.h"
#include "full.h"
#include "npg.h"
#include "npy.h"

typedef struct Entry {
  long row, col;
  double v;
} Entry;

typedef struct Entries {
  const double *in[16];     /* the tensor group's input quantities */
  Entry *e;
  long n, cap;
  bool oom;
} Entries;

static int add_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Entries *s = user;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  if (s->n == s->cap) {
    long cap = s->cap ? 2 * s->cap : 1024;
    Entry *e = realloc(s->e, sizeof(Entry) * (size_t)cap);
    if (!e) {
      s->oom = true;
      return -1;
    }
    s->e = e;
    s->cap = cap;
  }
  s->e[s->n++] = (Entry){row, col, v};
  return 0;
}

static int by_row_col(const void *a, const void *b) {
  const Entry *x = a, *y = b;
  if (x->row != y->row) return x->row < y->row ? -1 : 1;
  return (x->col > y->col) - (x->col < y->col);
}

/* Product of the sizes of ivars [from, to) of `op`. */
static long axis_size(NpgFull *f, const Sym *op, int from, int to) {
  long n = 1;
  for (int i = from; i < to; i++) n *= npg_full_dim(f, op->ivars[i]->range->name);
  return n;
}

/* Sorted entries, duplicates summed, into CSR. */
static int to_csr(Entries *s, long rows, long cols, NpgCsr *out) {
  qsort(s->e, (size_t)s->n, sizeof(Entry), by_row_col);
  long nnz = 0;
  for (long i = 0; i < s->n; i++) {
    if (nnz > 0 && s->e[nnz - 1].row == s->e[i].row && s->e[nnz - 1].col == s->e[i].col) s->e[nnz - 1].v += s->e[i].v;
    else s->e[nnz++] = s->e[i];
  }
  out->rows = rows;
  out->cols = cols;
  out->nnz = nnz;
  out->indptr = calloc((size_t)rows + 1, sizeof(long));
  out->indices = malloc(sizeof(long) * (size_t)(nnz + 1));
  out->data = malloc(sizeof(double) * (size_t)(nnz + 1));
  if (!out->indptr || !out->indices || !out->data) return -1;
  for (long i = 0; i < nnz; i++) {
    out->indptr[s->e[i].row + 1]++;
    out->indices[i] = s->e[i].col;
    out->data[i] = s->e[i].v;
  }
  for (long r = 0; r < rows; r++) out->indptr[r + 1] += out->indptr[r];
  return 0;
}

int npg_full_op(NpgFull *f, const char *name, NpgCsr *out) {
  NPG_REFUSE_NULL(f, NULL, 0, -1);
  if (!out || !name) return full_fail(f, (npg_refuse(NULL, 0, __func__, "argument '%s' is NULL", !out ? "out" : "name"),
                                          npg_refusal()));
  memset(out, 0, sizeof *out);
  const char *err = npg_full_error(f);
  if (err[0]) return -1;
  const Program *prog = full_program(f);
  const Sym *op = NULL;
  for (int i = 0; i < prog->ops.n; i++)
    if (strcmp(((Sym *)prog->ops.v[i])->name, name) == 0) op = prog->ops.v[i];
  char msg[512];
  if (!op || !op->is_output) {
    snprintf(msg, sizeof msg, "'%s' is not an output op of the program", name);
    return full_fail(f, msg);
  }
  const OpDef *od = op->opdef;
  Entries s = {0};
  int rc = 0;
  for (int g = 0; g < od->tensors.n && rc == 0; g++) {
    const TensorGroup *tg = &od->tensors.g[g];
    for (int i = 0; i < tg->ninputs && i < 16; i++)
      if (!(s.in[i] = npg_full_get(f, tg->inputs[i]->name, NULL))) {
        snprintf(msg, sizeof msg, "operator %s reads '%s', which has no value: evaluate first", name,
                 tg->inputs[i]->name);
        rc = full_fail(f, msg);
      }
    NpgSink sink = {&s, add_entry, 0, 1, 0, 0}; /* every row */
    if (rc == 0 && full_build(f, emit_builder_name(prog->ctx, prog, NULL, 0, 0, g, op), &sink) != 0) rc = -1;
  }
  if (rc == 0 && (s.oom || to_csr(&s, axis_size(f, op, 0, op->nrow), axis_size(f, op, op->nrow, op->nivars), out)))
    rc = full_fail(f, "out of memory for the operator's entries");
  free(s.e);
  if (rc != 0) npg_csr_free(out);
  return rc;
}

int npg_full_check_finite(NpgFull *f, long sample) {
  NPG_REFUSE_NULL(f, NULL, 0, -1);
  if (npg_full_error(f)[0]) return -1;
  const Sym *s;
  char at[256], msg[1024];
  double v;
  if (!full_first_nonfinite(f, &s, at, sizeof at, &v)) return 0;
  snprintf(msg, sizeof msg, "sample %ld: %s '%s' is not finite: %s%s is %s%s", sample,
           s->kind == SYM_INPUT ? "input" : s->kind == SYM_EXTERN ? "extern" : "stage", s->name, s->name, at,
           isnan(v) ? "NaN" : "an infinity",
           s->kind == SYM_STAGE ? " (a division by zero or a root of a negative number at this sample?)" : "");
  return full_fail(f, msg);
}

void npg_csr_free(NpgCsr *c) {
  if (!c) return;
  free(c->indptr);
  free(c->indices);
  free(c->data);
  memset(c, 0, sizeof *c);
}

/* npy_write refuses NULL data for a non-empty shape itself, naming the file. */
int npg_npy_write(const char *path, int ndim, const long *shape, const double *data, char *err, size_t errlen) {
  NPG_REFUSE_NULL(path, err, errlen, -1);
  if (ndim > 0) NPG_REFUSE_NULL(shape, err, errlen, -1);
  return npy_write(path, NPY_F64, ndim, shape, data, err, errlen);
}

int npg_npy_write_i64(const char *path, int ndim, const long *shape, const long *data, char *err, size_t errlen) {
  NPG_REFUSE_NULL(path, err, errlen, -1);
  if (ndim > 0) NPG_REFUSE_NULL(shape, err, errlen, -1);
  return npy_write(path, NPY_I64, ndim, shape, data, err, errlen);
}

_Static_assert(NPG_NPY_MAX_DIMS == NPY_MAX_DIMS, "npg.h's bound on .npy axes is the reader's");

double *npg_npy_read(const char *path, int *ndim, long shape[NPG_NPY_MAX_DIMS], size_t *count, char *err,
                     size_t errlen) {
  if (err && errlen) err[0] = 0;
  if (!path || !ndim || !shape || !count) {
    if (err && errlen)
      snprintf(err, errlen, "npg_npy_read: %s is NULL", !path ? "path" : !ndim ? "ndim" : !shape ? "shape" : "count");
    return NULL;
  }
  NpyArray a;
  if (npy_read(path, &a, err, errlen) != 0) return NULL;
  double *v = malloc(sizeof(double) * (a.count ? a.count : 1));
  if (!v) {
    if (err && errlen) snprintf(err, errlen, "%s: out of memory for %zu values", path, a.count);
    npy_free(&a);
    return NULL;
  }
  const long long exact = 1LL << 53; /* every integer up to 2^53 in magnitude is a double */
  for (size_t k = 0; k < a.count; k++) {
    if (a.type == NPY_F64) v[k] = ((const double *)a.data)[k];
    else {
      long long x = a.type == NPY_I32 ? ((const int *)a.data)[k] : ((const long long *)a.data)[k];
      if (x > exact || x < -exact) {
        if (err && errlen)
          snprintf(err, errlen, "%s: entry %zu (%lld) is beyond 2^53 and has no exact float64", path, k, x);
        free(v);
        npy_free(&a);
        return NULL;
      }
      v[k] = (double)x;
    }
  }
  *ndim = a.ndim;
  for (int d = 0; d < a.ndim; d++) shape[d] = a.shape[d];
  *count = a.count;
  npy_free(&a);
  return v;
}
