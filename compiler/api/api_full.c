/* api_full.c — the full evaluator of npg.h: NpgFull over the internal
 * Full (backends/jit/full.h), its `output op` operators as CSR, and the
 * .npy writers of the public API.
 *
 * NpgFull wraps Full as NpgModel wraps Model: every entry point checks its
 * arguments (ast.h's api_refuse: the evaluator itself, each pointer, a
 * shape) and calls in; the lower layers trust theirs. An extern's callback
 * gets the NpgFull its caller knows, through one closure per extern.
 *
 * An operator's entries are polynomials in stage values; its tensor
 * builders stream them as (row, column, inputs, coefficient), the entries
 * pre-multiplication consumes. Summing coefficient × inputs at the values
 * of the last evaluation gives the operator itself, sparse as the program
 * wrote it: no dense n × n matrix is formed. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"
#include "compile.h"
#include "emit.h"
#include "npy.h"

/* ---------------------------------------------------------------- the evaluator */

/* The argument checks of every npg_full_ entry point: the evaluator itself
 * (into this thread's refusal, which npg_full_error(NULL) returns), then
 * each pointer argument, refused into the evaluator's error. */
#define REFUSE_NULL_F(ret) API_REFUSE_NULL(f, NULL, 0, ret)
#define REFUSE_NULL(arg)                                                        \
  do {                                                                          \
    if (!(arg)) return refuse(f, __func__, "argument '%s' is NULL", #arg);      \
  } while (0)

__attribute__((format(printf, 3, 4))) static int refuse(NpgFull *f, const char *func, const char *fmt, ...) {
  char why[400];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(why, sizeof why, fmt, ap);
  va_end(ap);
  api_refuse(NULL, 0, func, "%s", why);
  return full_refuse(f->full, api_refusal());
}

/* A shape argument: `ndim` axes in [0, MAX_AXES + MAX_STATIC], `shape`
 * non-NULL when there are any, `values` non-NULL when they hold entries. */
static int refuse_shape(NpgFull *f, const char *func, int ndim, const long *shape, const double *values) {
  if (ndim < 0 || ndim > MAX_AXES + MAX_STATIC)
    return refuse(f, func, "argument 'ndim' is %d (0 to %d axes)", ndim, MAX_AXES + MAX_STATIC);
  if (ndim > 0 && !shape) return refuse(f, func, "argument 'shape' is NULL");
  size_t n = 1;
  for (int i = 0; i < ndim; i++) n = shape[i] > 0 ? n * (size_t)shape[i] : 0;
  if (n && !values) return refuse(f, func, "argument 'values' is NULL");
  return 0;
}

NpgFull *npg_full_new(NpgProgram *p, NpgBackend backend) {
  const char *refusal = NULL; /* an evaluator that refuses all work with this */
  if (!p) refusal = (api_refuse(NULL, 0, __func__, "argument 'p' is NULL"), api_refusal());
  else if (backend != NPG_TCC && backend != NPG_CC && backend != NPG_AUTO)
    refusal = (api_refuse(NULL, 0, __func__, "argument 'backend' is %d (NPG_AUTO, NPG_TCC or NPG_CC)", (int)backend),
               api_refusal());
  else if (!npg_ok(p)) refusal = npg_error(p);
  NpgFull *f = mem_calloc(1, sizeof *f);
  Full *full = f ? full_new(refusal ? NULL : program_ir(p), backend == NPG_CC ? JIT_CC : backend == NPG_TCC ? JIT_TCC : JIT_AUTO, refusal) : NULL;
  const Program *prog = full ? full_program(full) : NULL;
  ExternClosure *externs = prog ? mem_calloc((size_t)prog->quantities.n + 1, sizeof *externs) : NULL;
  if (!full || (prog && !externs)) {
    full_free(full);
    free(f);
    api_refuse(NULL, 0, __func__, "out of memory"); /* what npg_full_error(NULL) says */
    return NULL;
  }
  f->full = full;
  f->externs = externs;
  return f;
}

const char *npg_full_error(const NpgFull *f) {
  return f ? full_error(f->full) : api_refusal()[0] ? api_refusal() : "no evaluator";
}

int npg_full_jit_info(const NpgFull *f, NpgJitInfo *out) {
  if (!f || !out || !full_jit(f->full)) return -1;
  JitInfo i = jit_info(full_jit(f->full));
  out->backend = i.backend == JIT_CC ? NPG_CC : NPG_TCC;
  out->compile_seconds = i.seconds;
  out->cache = i.cache;
  return 0;
}

void npg_full_clear_error(NpgFull *f) {
  REFUSE_NULL_F();
  full_clear_error(f->full);
}

void npg_full_unbind(NpgFull *f) {
  REFUSE_NULL_F();
  full_unbind(f->full);
}

int npg_full_bind_params(NpgFull *f, const char *data_dir) {
  REFUSE_NULL_F(-1);
  REFUSE_NULL(data_dir);
  return full_bind_params(f->full, data_dir);
}

int npg_full_set_param(NpgFull *f, const char *name, int ndim, const long *shape, const double *values,
                       const char *from) {
  REFUSE_NULL_F(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(from);
  if (refuse_shape(f, __func__, ndim, shape, values)) return -1;
  return full_set_param(f->full, name, ndim, shape, values, from);
}

int npg_full_set(NpgFull *f, const char *name, int ndim, const long *shape, const double *values, const char *from) {
  REFUSE_NULL_F(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(from);
  if (refuse_shape(f, __func__, ndim, shape, values)) return -1;
  const Program *prog = full_program(f->full);
  for (int i = 0; prog && i < prog->states.n; i++)
    if (strcmp(((const Sym *)prog->states.v[i])->name, name) == 0) f->roll.steps = 0; /* a new rollout */
  return full_set(f->full, name, ndim, shape, values, from);
}

/* Full calls this for an extern given by npg_full_set_extern_fn. */
static int call_extern(void *user, const Full *full, long sample, double *out, size_t count) {
  (void)full;
  const ExternClosure *x = user;
  return x->fn(x->user, x->f, sample, out, count);
}

int npg_full_set_extern_fn(NpgFull *f, const char *name, NpgExternFn fn, void *user) {
  REFUSE_NULL_F(-1);
  REFUSE_NULL(name);
  const Program *prog = full_program(f->full);
  int q = prog ? api_quantity(prog, name) : -1;
  if (q < 0 || !fn) return full_set_extern_fn(f->full, name, NULL, NULL); /* refused by name, or removed */
  f->externs[q] = (ExternClosure){fn, user, f};
  return full_set_extern_fn(f->full, name, call_extern, &f->externs[q]);
}

int npg_full_eval(NpgFull *f, long sample) {
  REFUSE_NULL_F(-1);
  return full_eval(f->full, sample);
}

const double *npg_full_get(const NpgFull *f, const char *name, size_t *count) {
  REFUSE_NULL_F(NULL);
  API_REFUSE_NULL(name, NULL, 0, NULL);
  return full_get(f->full, name, count);
}

long npg_full_dim(const NpgFull *f, const char *name) {
  REFUSE_NULL_F(-1);
  API_REFUSE_NULL(name, NULL, 0, -1);
  return full_dim(f->full, name);
}

int api_sample_set(void *closure, Full *full, long k) {
  (void)full; /* closure->f->full */
  const SampleClosure *x = closure;
  /* what x->fn gives is sample k: a value it leaves out is refused, not the previous sample's */
  char what[64];
  snprintf(what, sizeof what, "sample %ld", k);
  full_forget_given(x->f->full);
  if (x->fn(x->user, x->f, k) != 0) return -1;
  return full_check_given(x->f->full, what);
}

void npg_full_free(NpgFull *f) {
  if (!f) return;
  full_free(f->full);
  free(f->externs);
  free(f->roll.start);
  free(f);
}

/* ---------------------------------------------------------------- operators */

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
static long axis_size(const Full *f, const Sym *op, int from, int to) {
  long n = 1;
  for (int i = from; i < to; i++) n *= full_dim(f, op->ivars[i]->range->name);
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
  REFUSE_NULL_F(-1);
  Full *full = f->full;
  if (!out || !name) {
    api_refuse(NULL, 0, __func__, "argument '%s' is NULL", !out ? "out" : "name");
    return full_fail(full, api_refusal());
  }
  memset(out, 0, sizeof *out);
  if (full_error(full)[0]) return -1;
  const Program *prog = full_program(full);
  const Sym *op = NULL;
  for (int i = 0; i < prog->ops.n; i++)
    if (strcmp(((Sym *)prog->ops.v[i])->name, name) == 0) op = prog->ops.v[i];
  char msg[512];
  if (!op || !op->is_output) {
    snprintf(msg, sizeof msg, "'%s' is not an output op of the program", name);
    return full_fail(full, msg);
  }
  const OpDef *od = op->opdef;
  Entries s = {0};
  int rc = 0;
  for (int g = 0; g < od->tensors.n && rc == 0; g++) {
    const TensorGroup *tg = &od->tensors.g[g];
    for (int i = 0; i < tg->ninputs && i < 16; i++)
      if (!(s.in[i] = full_get(full, tg->inputs[i]->name, NULL))) {
        snprintf(msg, sizeof msg, "operator %s reads '%s', which has no value: evaluate first", name,
                 tg->inputs[i]->name);
        rc = full_fail(full, msg);
      }
    NpgSink sink = {&s, add_entry, 0, 1, 0, 0}; /* every row */
    if (rc == 0 && full_build(full, emit_builder_name(prog->ctx, prog, NULL, 0, 0, g, op), &sink) != 0) rc = -1;
  }
  if (rc == 0 &&
      (s.oom || to_csr(&s, axis_size(full, op, 0, op->nrow), axis_size(full, op, op->nrow, op->nivars), out)))
    rc = full_fail(full, "out of memory for the operator's entries");
  free(s.e);
  if (rc != 0) npg_csr_free(out);
  return rc;
}

int npg_full_check_finite(NpgFull *f, long sample) {
  REFUSE_NULL_F(-1);
  Full *full = f->full;
  if (full_error(full)[0]) return -1;
  const Sym *s;
  char at[256], msg[1024], cause[512];
  double v;
  if (!full_first_nonfinite(full, &s, at, sizeof at, &v, cause, sizeof cause)) return 0;
  snprintf(msg, sizeof msg, "sample %ld: %s '%s' is not finite: %s%s is %s%s%s%s", sample,
           s->kind == SYM_INPUT ? "input" : s->kind == SYM_EXTERN ? "extern" : "stage", s->name, s->name, at,
           isnan(v) ? "NaN" : "an infinity", s->kind == SYM_STAGE ? " (" : "",
           cause[0]               ? cause
           : s->kind == SYM_STAGE ? "a division by zero or a root of a negative number at this sample?"
                                  : "",
           s->kind == SYM_STAGE ? ")" : "");
  return full_fail(full, msg);
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
  API_REFUSE_NULL(path, err, errlen, -1);
  if (ndim > 0) API_REFUSE_NULL(shape, err, errlen, -1);
  return npy_write(path, NPY_F64, ndim, shape, data, err, errlen);
}

int npg_npy_write_i64(const char *path, int ndim, const long *shape, const long *data, char *err, size_t errlen) {
  API_REFUSE_NULL(path, err, errlen, -1);
  if (ndim > 0) API_REFUSE_NULL(shape, err, errlen, -1);
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
