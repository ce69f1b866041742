/* full.c — the full evaluator as a library object: generate C, compile it
 * (libtcc or cc), bind params and dims, check gathers once, evaluate
 * samples, hand back every stage value. */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "demand.h"
#include "emit.h"
#include "full.h"
#include "jit.h"
#include "npy.h"
#include "runtime.h"

struct Full {
  Program *prog;
  JitModule *jit;
  NpgStageFn full, check;
  NpgStepFn step;           /* one step of the plan, whole or over boxes */
  const FullPlan *plan;
  Demand *demand;           /* full_demand(), made on first use */
  char error[1024];
  npg_idx *dims;            /* -1 while unbound */
  char **dim_from;          /* which file or call bound each dim */
  double **params;          /* real params */
  npg_iparam **iparams;     /* int params (32 bits: npg_abi.h) */
  char **param_files;
  double **q;               /* every quantity */
  size_t *qcount;
  bool checked;             /* gathers checked for the current binding */
  bool *fresh;              /* set by full_set since the last evaluation */
  FullExternFn *extern_fn;  /* per slot: the callback of an extern, or NULL */
  void **extern_user;
  NpgHost host;
  const char **dim_names, **param_names;
  /* derivatives (DESIGN §17): their C compiled on first use with the evaluator's backend */
  JitBackend backend;
  JitModule *djit;
  NpgDerivFn jvp, vjp;
  double **dq;              /* per slot: its tangent or cotangent */
  size_t *dqcount;
  long evaluations[2];      /* whole evaluations and restricted ones (full_evaluations) */
};

static int fail(Full *f, const char *fmt, ...) {
  if (f->error[0]) return -1;
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(f->error, sizeof f->error, fmt, ap);
  va_end(ap);
  return -1;
}

const char *full_error(const Full *f) { return f->error; }

const JitModule *full_jit(const Full *f) { return f ? f->jit : NULL; }

static int find(const PtrVec *v, const char *name) {
  for (int i = 0; i < v->n; i++)
    if (strcmp(((Sym *)v->v[i])->name, name) == 0) return i;
  return -1;
}

int full_emit(Program *prog, FILE *out) {
  Ctx *ctx = prog->ctx;
  jmp_buf env;
  ctx->on_error = &env;
  bool ok = setjmp(env) == 0;
  if (ok) {
    emit_full(ctx, prog, out);
    emit_builders(ctx, prog, out);
  }
  ctx->on_error = NULL;
  free(ctx->pending_free);
  ctx->pending_free = NULL;
  return ok ? 0 : -1;
}

Full *full_new(Program *prog, JitBackend backend, const char *refusal) {
  Full *f = mem_calloc(1, sizeof *f);
  if (!f) return NULL;
  if (refusal) {
    fail(f, "%s", refusal);
    return f;
  }
  char *src = NULL;
  size_t len = 0;
  FILE *mem = open_memstream(&src, &len);
  if (!mem || full_emit(prog, mem) != 0) {
    if (mem) fclose(mem);
    free(src);
    fail(f, "%s", !mem ? "out of memory" : prog->ctx->msg ? prog->ctx->msg : "error: code generation failed\n");
    return f;
  }
  fclose(mem);
  char err[1024];
  f->jit = jit_compile(src, backend, err, sizeof err);
  free(src);
  if (!f->jit) {
    fail(f, "%s", err);
    return f;
  }
  char full[1024], check[1024], step[1024];
  bool named = emit_symbol(prog, "full", full, sizeof full) < (int)sizeof full &&
               emit_symbol(prog, "check", check, sizeof check) < (int)sizeof check &&
               emit_symbol(prog, "full_step", step, sizeof step) < (int)sizeof step;
  f->full = named ? (NpgStageFn)jit_symbol(f->jit, full) : NULL;
  f->check = named ? (NpgStageFn)jit_symbol(f->jit, check) : NULL;
  f->step = named ? (NpgStepFn)jit_symbol(f->jit, step) : NULL;
  f->plan = emit_full_plan(prog->ctx, prog);
  if (!f->full || !f->check || !f->step) {
    fail(f, "generated code lacks its entry points (a bug in npg)");
    return f;
  }
  int nd = prog->dims.n, np = prog->params.n, nq = prog->slots.n;
  f->dims = mem_calloc((size_t)nd + 1, sizeof *f->dims);
  f->dim_from = mem_calloc((size_t)nd + 1, sizeof *f->dim_from);
  f->params = mem_calloc((size_t)np + 1, sizeof *f->params);
  f->iparams = mem_calloc((size_t)np + 1, sizeof *f->iparams);
  f->param_files = mem_calloc((size_t)np + 1, sizeof *f->param_files);
  f->q = mem_calloc((size_t)nq + 1, sizeof *f->q);
  f->qcount = mem_calloc((size_t)nq + 1, sizeof *f->qcount);
  f->fresh = mem_calloc((size_t)nq + 1, sizeof *f->fresh);
  f->extern_fn = mem_calloc((size_t)nq + 1, sizeof *f->extern_fn);
  f->extern_user = mem_calloc((size_t)nq + 1, sizeof *f->extern_user);
  f->dim_names = mem_calloc((size_t)nd + 1, sizeof *f->dim_names);
  f->param_names = mem_calloc((size_t)np + 1, sizeof *f->param_names);
  if (!f->dims || !f->dim_from || !f->params || !f->iparams || !f->param_files || !f->q || !f->qcount ||
      !f->fresh || !f->extern_fn || !f->extern_user || !f->dim_names || !f->param_names) {
    fail(f, "out of memory");
    return f;
  }
  /* Only now: an evaluator whose construction failed has no program, so
   * full_free and every entry point know its arrays do not exist. */
  f->prog = prog;
  for (int i = 0; i < nd; i++) {
    f->dims[i] = -1;
    f->dim_names[i] = ((Sym *)prog->dims.v[i])->name;
  }
  for (int i = 0; i < np; i++) f->param_names[i] = ((Sym *)prog->params.v[i])->name;
  f->host.dim_names = f->dim_names;
  f->host.param_names = f->param_names;
  f->host.param_files = (const char *const *)f->param_files;
  f->host.sparse_min_rows = FULL_SPARSE_MIN_ROWS;
  f->backend = backend;
  return f;
}

void full_set_sparse_min_rows(Full *f, long rows) { f->host.sparse_min_rows = rows; }

void full_evaluations(const Full *f, long *whole, long *restricted) {
  *whole = f->evaluations[0];
  if (restricted) *restricted = f->evaluations[1];
}

void full_sparse_counts(const Full *f, long *patterns, long *cholesky, long *lu) {
  *patterns = f->host.sparse_patterns;
  *cholesky = f->host.sparse_cholesky;
  *lu = f->host.sparse_lu;
}

/* Bind the dims of `s` from a shape (dims then static axes); `from` names
 * the source in messages. */
static int bind_shape(Full *f, const Sym *s, int ndim, const long *shape, const char *from) {
  if (ndim != s->ndims + s->nstatic)
    return fail(f, "%s: '%s' has %d ax%s, but the array has %d", from, s->name, s->ndims + s->nstatic,
                s->ndims + s->nstatic == 1 ? "is" : "es", ndim);
  for (int i = 0; i < s->nstatic; i++)
    if (shape[s->ndims + i] != s->shape[i])
      return fail(f, "%s: axis %d of '%s' is static with size %d, but the array has %ld", from, s->ndims + i, s->name,
                  s->shape[i], shape[s->ndims + i]);
  for (int i = 0; i < s->ndims; i++) {
    int d = vec_position(&f->prog->dims, s->dims[i]);
    if (shape[i] < 0)
      return fail(f, "%s: axis %d of '%s' has a negative size (%ld)", from, i, s->name, shape[i]);
    if (f->dims[d] < 0) {
      f->dims[d] = shape[i];
      free(f->dim_from[d]);
      f->dim_from[d] = mem_strdup(from);
      f->checked = false;
    } else if (f->dims[d] != shape[i]) {
      /* the same source twice (a call's argument, then the next call's): which binding came first is the news */
      if (f->dim_from[d] && strcmp(f->dim_from[d], from) == 0)
        return fail(f, "dim %s is %ld in %s but was bound to %ld by an earlier value of it: a dim keeps the size "
                       "it was first bound to (give every value over it that size)", s->dims[i]->name, shape[i], from,
                    (long)f->dims[d]);
      return fail(f, "dim %s is %ld in %s but %ld in %s", s->dims[i]->name, (long)f->dims[d],
                  f->dim_from[d] ? f->dim_from[d] : "an earlier binding", shape[i], from);
    }
  }
  return 0;
}

/* "[2, 5]": the index of flat entry e of `s` as bound, into `buf`. */
static const char *index_text(Full *f, const Sym *s, size_t e, char *buf, size_t len) {
  long shape[MAX_AXES + MAX_STATIC], idx[MAX_AXES + MAX_STATIC];
  int nd = 0;
  for (int i = 0; i < s->ndims; i++) shape[nd++] = (long)f->dims[vec_position(&f->prog->dims, s->dims[i])];
  for (int i = 0; i < s->nstatic; i++) shape[nd++] = s->shape[i];
  for (int i = nd - 1; i >= 0; i--) {
    idx[i] = shape[i] > 0 ? (long)(e % (size_t)shape[i]) : 0;
    e = shape[i] > 0 ? e / (size_t)shape[i] : e;
  }
  size_t at = (size_t)snprintf(buf, len, "[");
  for (int i = 0; i < nd && at < len; i++) at += (size_t)snprintf(buf + at, len - at, "%s%ld", i ? ", " : "", idx[i]);
  if (at < len) snprintf(buf + at, len - at, "]");
  return buf;
}

/* The entries of `s` as bound; SIZE_MAX when their count overflows. */
static size_t count_of(Full *f, const Sym *s) {
  size_t n = 1;
  for (int i = 0; i < s->ndims; i++)
    if (__builtin_mul_overflow(n, (size_t)f->dims[vec_position(&f->prog->dims, s->dims[i])], &n)) return SIZE_MAX;
  for (int i = 0; i < s->nstatic; i++)
    if (__builtin_mul_overflow(n, (size_t)s->shape[i], &n)) return SIZE_MAX;
  return n;
}

/* A zeroed buffer for the `n` entries of quantity `s` (one at least): NULL
 * after a message naming it, its shape and the memory it needs, when that
 * is more than the machine has (a 1e12-entry stage is refused before it is
 * touched, not left to the kernel's out-of-memory killer) or the
 * allocation fails. */
static double *alloc_entries(Full *f, const Sym *s, size_t n) {
  size_t ram = physical_memory();
  bool fits = n < SIZE_MAX / sizeof(double) && (!ram || n * sizeof(double) <= ram);
  double *p = fits ? mem_calloc(n ? n : 1, sizeof(double)) : NULL;
  if (p) return p;
  /* "real[N, N, 3] with N = 1000000" */
  char shape[512], need[32], have[32];
  size_t len = (size_t)snprintf(shape, sizeof shape, "real[");
  for (int i = 0; i < s->ndims + s->nstatic && len + 40 < sizeof shape; i++)
    len += i < s->ndims ? (size_t)snprintf(shape + len, sizeof shape - len, "%s%s", i ? ", " : "", s->dims[i]->name)
                        : (size_t)snprintf(shape + len, sizeof shape - len, "%s%d", i ? ", " : "", s->shape[i - s->ndims]);
  len += (size_t)snprintf(shape + len, sizeof shape - len, "]");
  for (int i = 0; i < s->ndims && len + 40 < sizeof shape; i++) {
    bool again = false;
    for (int j = 0; j < i; j++) again |= s->dims[j] == s->dims[i];
    if (!again)
      len += (size_t)snprintf(shape + len, sizeof shape - len, "%s%s = %ld", len && shape[len - 1] == ']' ? " with " : ", ",
                              s->dims[i]->name, (long)f->dims[vec_position(&f->prog->dims, s->dims[i])]);
  }
  double entries = 1; /* exact enough for a message, and never overflows */
  for (int i = 0; i < s->ndims; i++) entries *= (double)f->dims[vec_position(&f->prog->dims, s->dims[i])];
  for (int i = 0; i < s->nstatic; i++) entries *= s->shape[i];
  const char *kind = s->kind == SYM_INPUT    ? "input"
                     : s->kind == SYM_EXTERN ? "extern"
                     : s->kind == SYM_PARAM  ? "param"
                                             : "stage";
  bytes_text(entries * sizeof(double), need, sizeof need);
  if (!fits && ram)
    fail(f, "out of memory: %s '%s', %s, has %.4g entries and needs %s, more than this machine's memory (%s)", kind,
         s->name, shape, entries, need, bytes_text((double)ram, have, sizeof have));
  else
    fail(f, "out of memory: %s '%s', %s, has %.4g entries and needs %s, which could not be allocated", kind, s->name,
         shape, entries, need);
  return NULL;
}

/* A param from memory: doubles (int params must hold whole numbers). */
int full_set_param(Full *f, const char *name, int ndim, const long *shape, const double *values, const char *from) {
  if (f->error[0]) return -1;
  int k = find(&f->prog->params, name);
  if (k < 0) return fail(f, "%s: the program has no param '%s'", from, name);
  const Sym *s = f->prog->params.v[k];
  if (bind_shape(f, s, ndim, shape, from)) return -1;
  size_t n = count_of(f, s);
  free(f->params[k]);
  free(f->iparams[k]);
  f->params[k] = NULL;
  f->iparams[k] = NULL;
  if (s->is_int) {
    f->iparams[k] = mem_malloc(sizeof(npg_iparam) * (n ? n : 1));
    if (!f->iparams[k]) return fail(f, "out of memory");
    for (size_t i = 0; i < n; i++) {
      char at[128];
      if (!(values[i] >= INT_MIN && values[i] <= INT_MAX)) /* NaN too */
        return fail(f, "%s: int param '%s' holds %.17g at %s, outside the range of an int param (%d to %d)", from,
                    name, values[i], index_text(f, s, i, at, sizeof at), INT_MIN, INT_MAX);
      if (values[i] != (double)(npg_iparam)values[i])
        return fail(f, "%s: int param '%s' holds %.17g at %s, not a whole number", from, name, values[i],
                    index_text(f, s, i, at, sizeof at));
      f->iparams[k][i] = (npg_iparam)values[i];
    }
  } else {
    if (!(f->params[k] = alloc_entries(f, s, n))) return -1;
    for (size_t i = 0; i < n; i++) {
      char at[128];
      if (values[i] != values[i] || values[i] - values[i] != 0)
        return fail(f, "%s: param '%s' holds %s at %s", from, name, values[i] != values[i] ? "NaN" : "an infinity",
                    index_text(f, s, i, at, sizeof at));
      f->params[k][i] = values[i];
    }
  }
  free(f->param_files[k]);
  f->param_files[k] = mem_strdup(from);
  f->checked = false;
  return 0;
}

int full_bind_params(Full *f, const char *data_dir) {
  if (f->error[0]) return -1;
  for (int k = 0; k < f->prog->params.n; k++) {
    const Sym *s = f->prog->params.v[k];
    char path[4096], err[1024];
    snprintf(path, sizeof path, "%s/%s.npy", data_dir, s->name);
    NpyArray a;
    if (npy_read(path, &a, err, sizeof err) != 0) return fail(f, "%s", err);
    if (s->is_int ? a.type == NPY_F64 : a.type != NPY_F64) {
      const char *type = npy_type_name(a.type); /* before npy_free forgets it */
      npy_free(&a);
      return fail(f, "%s: param '%s' is declared %s but the array is %s", path, s->name, s->is_int ? "int" : "real",
                  type);
    }
    /* int params travel as doubles: exact up to 2^53 */
    for (size_t i = 0; a.type == NPY_I64 && i < a.count; i++) {
      long long v = ((long long *)a.data)[i];
      if (v > (1LL << 53) || v < -(1LL << 53)) {
        npy_free(&a);
        return fail(f, "%s: int param '%s' holds %lld at flat entry %zu, beyond 2^53 (npg holds int params exactly "
                       "only up to 2^53)", path, s->name, v, i);
      }
    }
    double *v = mem_malloc(sizeof(double) * (a.count ? a.count : 1));
    if (!v) {
      npy_free(&a);
      return fail(f, "out of memory");
    }
    for (size_t i = 0; i < a.count; i++)
      v[i] = a.type == NPY_F64 ? ((double *)a.data)[i]
             : a.type == NPY_I32 ? (double)((int *)a.data)[i]
                                 : (double)((long long *)a.data)[i];
    int rc = full_set_param(f, s->name, a.ndim, a.shape, v, path);
    free(v);
    npy_free(&a);
    if (rc) return -1;
  }
  return 0;
}

int full_bind_shape(Full *f, const char *name, int ndim, const long *shape, const char *from) {
  if (f->error[0]) return -1;
  int k = find(&f->prog->slots, name);
  if (k < 0 || (((Sym *)f->prog->slots.v[k])->kind != SYM_INPUT && ((Sym *)f->prog->slots.v[k])->kind != SYM_EXTERN))
    return fail(f, "%s: the program has no input or extern '%s'", from, name);
  return bind_shape(f, f->prog->slots.v[k], ndim, shape, from);
}

int full_set(Full *f, const char *name, int ndim, const long *shape, const double *values, const char *from) {
  if (f->error[0]) return -1;
  int k = find(&f->prog->slots, name);
  if (k < 0) {
    if (find(&f->prog->params, name) >= 0) return full_set_param(f, name, ndim, shape, values, from);
    return fail(f, "%s: the program has no input or param '%s'", from, name);
  }
  const Sym *s = f->prog->slots.v[k];
  if (s->kind != SYM_INPUT && s->kind != SYM_EXTERN)
    return fail(f, "%s: '%s' is a stage; only inputs, externs and params are set", from, name);
  if (bind_shape(f, s, ndim, shape, from)) return -1;
  size_t n = count_of(f, s);
  if (f->qcount[k] != n || !f->q[k]) { /* a zero-size quantity still gets a buffer */
    free(f->q[k]);
    f->qcount[k] = 0;
    if (!(f->q[k] = alloc_entries(f, s, n))) return -1;
    f->qcount[k] = n;
  }
  for (size_t i = 0; i < n; i++) {
    char at[128];
    if (values[i] != values[i] || values[i] - values[i] != 0)
      return fail(f, "%s: '%s' holds %s at %s", from, name, values[i] != values[i] ? "NaN" : "an infinity",
                  index_text(f, s, i, at, sizeof at));
  }
  if (n) memcpy(f->q[k], values, sizeof(double) * n); /* values may be NULL when there are none */
  f->fresh[k] = true;
  return 0;
}

double *full_extern_values(Full *f, const char *name, size_t n) {
  if (f->error[0]) return NULL;
  int k = find(&f->prog->slots, name);
  const Sym *s = k >= 0 ? f->prog->slots.v[k] : NULL;
  if (!s || s->kind != SYM_EXTERN) return fail(f, "the program has no extern '%s'", name), NULL;
  if (n != count_of(f, s)) return fail(f, "extern '%s' has %zu entries as bound, not %zu", name, count_of(f, s), n), NULL;
  if (f->qcount[k] != n || !f->q[k]) {
    free(f->q[k]);
    f->qcount[k] = 0;
    if (!(f->q[k] = alloc_entries(f, s, n))) return NULL;
    f->qcount[k] = n;
  }
  f->fresh[k] = true;
  return f->q[k];
}

int full_set_extern_fn(Full *f, const char *name, FullExternFn fn, void *user) {
  if (f->error[0]) return -1;
  int k = find(&f->prog->slots, name);
  const Sym *s = k >= 0 ? f->prog->slots.v[k] : NULL;
  if (!s || s->kind != SYM_EXTERN) return fail(f, "the program has no extern '%s'", name);
  for (int i = 0; i < s->nof; i++)
    if (s->of[i]->kind != SYM_INPUT)
      return fail(f, "extern '%s' reads '%s', which is not an input: a callback runs before the stages, so give its "
                     "values with full_set instead", name, s->of[i]->name);
  f->extern_fn[k] = fn;
  f->extern_user[k] = user;
  return 0;
}

/* Externs with a callback and no value given since the last evaluation. */
static int call_externs(Full *f, long sample) {
  for (int k = 0; k < f->prog->slots.n; k++) {
    const Sym *s = f->prog->slots.v[k];
    if (!f->extern_fn[k] || f->fresh[k]) continue;
    size_t n = count_of(f, s);
    if (f->qcount[k] != n) {
      free(f->q[k]);
      f->qcount[k] = 0;
      if (!(f->q[k] = alloc_entries(f, s, n))) return -1;
      f->qcount[k] = n;
    }
    if (f->extern_fn[k](f->extern_user[k], f, sample, f->q[k], n) != 0)
      return fail(f, "extern '%s' failed at sample %ld (its callback returned an error)", s->name, sample);
    for (size_t i = 0; i < n; i++)
      if (!isfinite(f->q[k][i]))
        return fail(f, "extern '%s' at sample %ld: the callback wrote %s at flat entry %zu", s->name, sample,
                    isnan(f->q[k][i]) ? "NaN" : "an infinity", i);
  }
  return 0;
}

static NpgCtx context(Full *f, long sample) {
  NpgCtx c;
  c.dims = f->dims;
  c.params = (const double *const *)f->params;
  c.iparams = (const npg_iparam *const *)f->iparams;
  c.q = f->q;
  c.rt = &npg_runtime;
  c.sample = sample;
  c.host = &f->host;
  return c;
}

/* The steps a demand asks for, each whole or over its boxes. */
static int run_steps(Full *f, const NpgCtx *c, Demand *d) {
  if (demand_propagate(d)) return fail(f, "out of memory");
  for (int k = 0; k < f->plan->n; k++) {
    const npg_idx *box;
    int n = demand_step(d, k, &box);
    if (n >= 0 && f->step(c, k, n ? n : -1, box) != 0) return -1;
  }
  return 0;
}

/* Evaluate sample `sample`: everything, or (d non-NULL) what d demands. */
static int evaluate(Full *f, long sample, Demand *d) {
  if (f->error[0]) return -1;
  const Program *prog = f->prog;
  for (int i = 0; i < prog->dims.n; i++)
    if (f->dims[i] < 0) return fail(f, "dim %s is not bound: no param or input over it was given", f->dim_names[i]);
  for (int k = 0; k < prog->params.n; k++)
    if (!f->params[k] && !f->iparams[k])
      return fail(f, "param '%s' is not bound", ((Sym *)prog->params.v[k])->name);
  for (int k = 0; k < prog->slots.n; k++) {
    const Sym *s = prog->slots.v[k];
    size_t n = count_of(f, s);
    if (s->kind == SYM_EXTERN && f->extern_fn[k] && !f->fresh[k]) continue; /* call_externs */
    if (s->kind == SYM_INPUT || s->kind == SYM_EXTERN) {
      if (!f->q[k] || f->qcount[k] != n)
        return fail(f, "%s '%s' is not set for sample %ld", s->kind == SYM_INPUT ? "input" : "extern", s->name, sample);
    } else if (f->qcount[k] != n || !f->q[k]) {
      free(f->q[k]);
      f->qcount[k] = 0;
      if (!(f->q[k] = alloc_entries(f, s, n))) return -1;
      f->qcount[k] = n;
    }
  }
  if (call_externs(f, sample) != 0) return -1;
  f->evaluations[d != NULL]++;
  memset(f->fresh, 0, sizeof(bool) * (size_t)prog->slots.n);
  NpgCtx c = context(f, sample);
  f->host.msg[0] = 0;
  if (!f->checked) {
    runtime_sparse_reset(&f->host); /* sparse patterns belong to the old binding */
    if (f->check(&c) != 0) return fail(f, "%s", f->host.msg);
    f->checked = true;
  }
  if ((d ? run_steps(f, &c, d) : f->full(&c)) != 0) {
    if (f->error[0]) return -1;
    /* An operator that is not finite is where a NaN surfaced, not where it
     * arose: name the first stage holding one when another stage failed (a
     * zero-area triangle makes p = d·a^(-1/2) NaN, and b = solve(M, e) fails). */
    const Sym *s;
    char at[256], named[300], prefix[48], cause[512];
    double v;
    const char *then = f->host.msg;
    size_t np = (size_t)snprintf(prefix, sizeof prefix, "sample %ld: ", sample);
    if (strncmp(then, prefix, np) == 0) then += np;
    if (full_first_nonfinite(f, &s, at, sizeof at, &v, cause, sizeof cause) && s->kind == SYM_STAGE &&
        (snprintf(named, sizeof named, "stage '%s'", s->name), !strstr(then, named)))
      return fail(f, "sample %ld: stage '%s' is not finite: %s%s is %s (%s); then %s", sample, s->name, s->name, at,
                  isnan(v) ? "NaN" : "an infinity",
                  cause[0] ? cause : "a division by zero or a root of a negative number at this sample?", then);
    return fail(f, "%s", f->host.msg);
  }
  return 0;
}

int full_eval(Full *f, long sample) { return evaluate(f, sample, NULL); }

Demand *full_demand(Full *f) {
  if (f->error[0] || !f->plan) return NULL;
  if (!f->demand && !(f->demand = demand_new(f->prog, f->plan))) {
    fail(f, "out of memory");
    return NULL;
  }
  demand_reset(f->demand, f->dims);
  return f->demand;
}

int full_eval_demand(Full *f, long sample, Demand *d) { return evaluate(f, sample, d); }

int full_build(Full *f, const char *name, NpgSink *sink) {
  if (f->error[0]) return -1;
  NpgBuildFn fn = (NpgBuildFn)jit_symbol(f->jit, name);
  if (!fn) return fail(f, "no tensor builder '%s' in the generated code", name);
  NpgCtx c = context(f, 0);
  f->host.msg[0] = 0;
  if (fn(&c, sink) != 0) return fail(f, "%s", f->host.msg[0] ? f->host.msg : "the tensor sink refused an entry");
  return 0;
}

long full_dim_size(const Full *f, int k) { return (long)f->dims[k]; }

uint64_t full_hash_values(const double *v, size_t n) {
  /* FNV-1a over the values as doubles: an int param hashes alike from int32
   * and int64 files, and a param set from memory like one read from disk */
  uint64_t h = 0xcbf29ce484222325ull;
  for (size_t i = 0; i < n; i++) {
    unsigned char b[sizeof(double)];
    memcpy(b, &v[i], sizeof(double));
    for (size_t j = 0; j < sizeof(double); j++) h = (h ^ b[j]) * 0x100000001b3ull;
  }
  return h;
}

uint64_t full_param_hash(const Full *f, int k, const char **from) {
  const Sym *s = f->prog->params.v[k];
  if (from) *from = f->param_files[k] ? f->param_files[k] : s->name;
  if (!f->params[k] && !f->iparams[k]) return 0;
  size_t n = count_of((Full *)f, s);
  if (f->params[k]) return full_hash_values(f->params[k], n);
  double *v = mem_malloc(sizeof(double) * (n ? n : 1));
  if (!v) return 0;
  for (size_t i = 0; i < n; i++) v[i] = (double)f->iparams[k][i];
  uint64_t h = full_hash_values(v, n);
  free(v);
  return h;
}

const Program *full_program(const Full *f) { return f->prog; }

/* The value of index expression `n` of stage `s` at the stage's index `iv` into *x: a number, one of the
 * stage's index variables, an entry of an int param indexed by such (a gather: tri[f, 1]) or a sum,
 * difference or product of them; false otherwise (a sum variable, an entry out of range, an unbound param). */
static bool index_value(Full *f, const Sym *s, const long *iv, const Node *n, int depth, long *x) {
  if (depth > 16) return false;
  long a, b;
  switch (n->kind) {
  case N_NUM: *x = (long)n->num; return n->num == (double)*x;
  case N_NAME:
    for (int j = 0; j < s->nivars; j++)
      if (n->sym == s->ivars[j]) return *x = iv[j], true;
    return false;
  case N_ADD: case N_SUB: case N_MUL:
    if (!index_value(f, s, iv, n->a, depth + 1, &a) || !index_value(f, s, iv, n->b, depth + 1, &b)) return false;
    *x = n->kind == N_ADD ? a + b : n->kind == N_SUB ? a - b : a * b;
    return true;
  case N_INDEX: {
    const Sym *t = n->sym;
    int pk = t ? find(&f->prog->params, t->name) : -1;
    if (pk < 0 || !f->iparams[pk] || n->nargs != t->ndims + t->nstatic) return false;
    size_t flat = 0;
    for (int i = 0; i < n->nargs; i++) {
      long size = i < t->ndims ? (long)f->dims[vec_position(&f->prog->dims, t->dims[i])] : t->shape[i - t->ndims];
      if (!index_value(f, s, iv, n->args[i], depth + 1, &a) || a < 0 || a >= size) return false;
      flat = flat * (size_t)size + (size_t)a;
    }
    *x = (long)f->iparams[pk][flat];
    return true;
  }
  default: return false;
  }
}

/* The value of atom `a` (q[idx...]) of a monomial of stage `s` at the stage's index `iv` (one per index
 * variable), when its indices are numbers, the stage's index variables or gathers of them (index_value):
 * false otherwise (a sum variable), or when its quantity has no value. `where` gets the entry as "a[0]",
 * *flat_out its flat index. */
static bool atom_value(Full *f, const Sym *s, const long *iv, const Atom *a, double *v, char *where, size_t len,
                       size_t *flat_out) {
  const Sym *q = a->q;
  size_t flat = 0;
  size_t at = (size_t)snprintf(where, len, "%s[", q->name);
  for (int i = 0; i < q->ndims + q->nstatic; i++) {
    const Node *n = a->idx[i];
    long size = i < q->ndims ? (long)f->dims[vec_position(&f->prog->dims, q->dims[i])] : q->shape[i - q->ndims], x = -1;
    if (!index_value(f, s, iv, n, 0, &x) || x < 0 || x >= size) return false;
    flat = flat * (size_t)size + (size_t)x;
    if (at < len) at += (size_t)snprintf(where + at, len - at, "%s%ld", i ? ", " : "", x);
  }
  if (at < len) snprintf(where + at, len - at, "]");
  if (q->ndims + q->nstatic == 0) snprintf(where, len, "%s", q->name);
  int k = find(&f->prog->slots, q->name), pk = find(&f->prog->params, q->name);
  if (k >= 0 && f->q[k] && flat < f->qcount[k]) *v = f->q[k][flat];
  else if (pk >= 0 && f->params[pk]) *v = f->params[pk][flat];
  else if (pk >= 0 && f->iparams[pk]) *v = (double)f->iparams[pk][flat];
  else return false;
  *flat_out = flat;
  return true;
}

/* The base of a diagonal power at one entry: its value, whether it is plain (a polynomial of entries
 * atom_value reads), the entry itself when the base is one entry (a[i]^(-1/2)) and the entries that are 0. */
typedef struct PowerBase {
  double value;
  bool plain, named;
  char one[256];            /* the last entry read ("a[1]") */
  const Sym *one_sym;       /* its quantity, and its flat index */
  size_t one_flat;
  char zeros[256];          /* "a[1], b[0]": the entries of the base that are 0 */
} PowerBase;

static void power_base(Full *f, const Sym *s, const long *iv, const Poly *poly, PowerBase *b) {
  memset(b, 0, sizeof *b);
  b->plain = true;
  size_t zat = 0;
  for (int m = 0; m < poly->n && b->plain; m++) {
    const Mono *mo = poly->m[m];
    b->plain = !mo->guard && !mo->nsums && mo->coef->kind == N_NUM;
    double term = b->plain ? mo->coef->num : 0;
    for (int a = 0; a < mo->natoms && b->plain; a++) {
      double v = 0;
      b->plain = atom_value(f, s, iv, &mo->atoms[a], &v, b->one, sizeof b->one, &b->one_flat);
      b->one_sym = mo->atoms[a].q;
      term *= v;
      if (b->plain && v == 0 && !strstr(b->zeros, b->one) && zat + strlen(b->one) + 3 < sizeof b->zeros)
        zat += (size_t)snprintf(b->zeros + zat, sizeof b->zeros - zat, "%s%s", zat ? ", " : "", b->one);
    }
    b->value += term;
  }
  b->named = b->plain && poly->n == 1 && poly->m[0]->natoms == 1 && coef_is_num(poly->m[0]->coef, 1);
}

/* The index of stage `s`'s entry `e` into `iv`, and its component; false when a dim is not bound. */
static bool entry_index(Full *f, const Sym *s, size_t e, long *iv, size_t *comp) {
  const Stage *st = s->stage;
  *comp = st->ncomp > 0 ? e % (size_t)st->ncomp : 0;
  size_t rest = st->ncomp > 0 ? e / (size_t)st->ncomp : e;
  for (int i = s->nivars - 1; i >= 0; i--) {
    long size = (long)f->dims[vec_position(&f->prog->dims, s->ivars[i]->range)];
    if (size <= 0) return false;
    iv[i] = (long)(rest % (size_t)size);
    rest /= (size_t)size;
  }
  return true;
}

/* Why entry `e` of stage `s` is 0 when it is one product with a positive power of a zero base (a root
 * r = a^(1/3) of a zero area): "a[1] is 0, and r raises it to the power 1/3" into `cause`; false otherwise. */
static bool zero_cause(Full *f, const Sym *s, size_t e, char *cause, size_t len) {
  const Stage *st = s->stage;
  long iv[MAX_AXES] = {0};
  size_t comp;
  if (!st || s->kind != SYM_STAGE || st->nterms != 1 || !entry_index(f, s, e, iv, &comp)) return false;
  for (int k = 0; k < st->terms[0]->nops; k++) {
    const OpPow *op = &st->terms[0]->ops[k];
    if (op->kind != OPK_DIAG || op->diag->ncomp < 1 || op->p <= 0) continue;
    PowerBase b;
    power_base(f, s, iv, &op->diag->comp[op->diag->ncomp == st->ncomp ? comp : 0], &b);
    if (!b.plain || b.value != 0) continue;
    char power[64];
    snprintf(power, sizeof power, op->q == 1 ? "%ld" : "%ld/%ld", op->p, op->q);
    if (b.named) snprintf(cause, len, "%s is 0, and %s raises it to the power %s", b.one, s->name, power);
    else snprintf(cause, len, "%s raises a base that is 0 there to the power %s%s%s", s->name, power,
                  b.zeros[0] ? ": " : "", b.zeros[0] ? b.zeros : "");
    return true;
  }
  return false;
}

/* Why entry `e` of stage `s` is not finite, when a diagonal power of it (a division, a negative or fractional
 * power) has a base of 0 (negative power) or below 0 (root) there: "a division by zero: a[0] is 0, and p
 * raises it to the power -1/2", into `cause`; false when no such base is found (the value arose otherwise, or
 * the base is not a plain polynomial of entries at the stage's own indices or gathered by them). Names the
 * zero area or length itself, not only the stage where the NaN appears: in a base of several entries the
 * ones that are 0, and through a stage that is a root of it (r = a^(1/3), then 1/r) the entry under the root. */
static bool nonfinite_cause(Full *f, const Sym *s, size_t e, char *cause, size_t len) {
  const Stage *st = s->stage;
  long iv[MAX_AXES] = {0};
  size_t comp;
  if (!st || s->kind != SYM_STAGE || !entry_index(f, s, e, iv, &comp)) return false;
  for (int t = 0; t < st->nterms; t++)
    for (int k = 0; k < st->terms[t]->nops; k++) {
      const OpPow *op = &st->terms[t]->ops[k];
      if (op->kind != OPK_DIAG || op->diag->ncomp < 1) continue;
      PowerBase b;
      power_base(f, s, iv, &op->diag->comp[op->diag->ncomp == st->ncomp ? comp : 0], &b);
      char power[64];
      snprintf(power, sizeof power, op->q == 1 ? "%ld" : "%ld/%ld", op->p, op->q);
      if (!b.plain || !((op->p < 0 && b.value == 0) || (op->q % 2 == 0 && b.value < 0))) continue;
      char how[128], under[512] = "";
      if (op->p == -1 && op->q == 1) snprintf(how, sizeof how, "divides by it");
      else snprintf(how, sizeof how, "raises it to the power %s", power);
      const char *kind = b.value == 0 ? "a division by zero" : "a root of a negative number";
      if (b.named && b.value == 0 && zero_cause(f, b.one_sym, b.one_flat, under + 2, sizeof under - 2))
        memcpy(under, "; ", 2);
      if (b.named) snprintf(cause, len, "%s: %s is %g, and %s %s%s", kind, b.one, b.value, s->name, how, under);
      else snprintf(cause, len, "%s: the base of its power %s is %g there%s%s%s", kind, power, b.value,
                    b.value == 0 && b.zeros[0] ? ", where " : "", b.value == 0 ? b.zeros : "",
                    b.value != 0 || !b.zeros[0] ? "" : strchr(b.zeros, ',') ? " are 0" : " is 0");
      return true;
    }
  return false;
}

bool full_first_nonfinite(Full *f, const Sym **sym, char *index, size_t len, double *value, char *cause,
                          size_t causelen) {
  if (cause && causelen) cause[0] = 0;
  for (int q = 0; q < f->prog->quantities.n; q++) {
    const Sym *s = f->prog->quantities.v[q];
    int k = find(&f->prog->slots, s->name);
    for (size_t e = 0; k >= 0 && f->q[k] && e < f->qcount[k]; e++)
      if (!isfinite(f->q[k][e])) {
        *sym = s;
        *value = f->q[k][e];
        index_text(f, s, e, index, len);
        if (cause && causelen) nonfinite_cause(f, s, e, cause, causelen);
        return true;
      }
  }
  return false;
}

int full_fail(Full *f, const char *msg) { return fail(f, "%s", msg); }

int full_refuse(Full *f, const char *msg) {
  snprintf(f->error, sizeof f->error, "%s", msg);
  return -1;
}

int full_advance(Full *f) {
  if (f->error[0]) return -1;
  const Program *prog = f->prog;
  for (int i = 0; i < prog->states.n; i++) {
    const Sym *u = prog->states.v[i];
    int a = vec_position(&prog->slots, u), b = vec_position(&prog->slots, u->next);
    if (a < 0 || b < 0 || !f->q[b] || f->qcount[a] != f->qcount[b])
      return fail(f, "state '%s' cannot advance: its next value '%s' was not evaluated", u->name, u->next->name);
    double *t = f->q[a];
    f->q[a] = f->q[b];
    f->q[b] = t;
  }
  return 0;
}

const double *full_get(const Full *f, const char *name, size_t *count) {
  if (!f->prog) return NULL;
  int k = find(&f->prog->slots, name);
  if (k < 0) return NULL;
  if (count) *count = f->qcount[k];
  return f->q[k];
}

long full_dim(const Full *f, const char *name) {
  if (!f->prog) return -1;
  int k = find(&f->prog->dims, name);
  return k < 0 ? -1 : (long)f->dims[k];
}

/* An evaluator whose construction failed (no program) keeps its error. */
void full_clear_error(Full *f) {
  if (f->prog) f->error[0] = 0;
}

void full_unbind(Full *f) {
  if (!f->prog) return;
  for (int i = 0; i < f->prog->dims.n; i++) {
    f->dims[i] = -1;
    free(f->dim_from[i]);
    f->dim_from[i] = NULL;
  }
  for (int i = 0; i < f->prog->params.n; i++) {
    free(f->params[i]);
    free(f->iparams[i]);
    free(f->param_files[i]);
    f->params[i] = NULL;
    f->iparams[i] = NULL;
    f->param_files[i] = NULL;
  }
  for (int i = 0; i < f->prog->slots.n; i++) {
    free(f->q[i]);
    f->q[i] = NULL;
    f->qcount[i] = 0;
    f->fresh[i] = false;
  }
  f->checked = false;
  f->error[0] = 0;
}

void full_forget_given(Full *f) {
  if (f->prog) memset(f->fresh, 0, sizeof(bool) * (size_t)f->prog->slots.n);
}

int full_check_given(Full *f, const char *what) {
  if (f->error[0]) return -1;
  for (int k = 0; k < f->prog->slots.n; k++) {
    const Sym *s = f->prog->slots.v[k];
    if (f->fresh[k] || !(s->kind == SYM_INPUT || (s->kind == SYM_EXTERN && !f->extern_fn[k]))) continue;
    return fail(f, "%s: %s '%s' is not given%s: a sample gives every input%s (a value is never carried over from "
                   "the previous sample)", what, s->kind == SYM_INPUT ? "input" : "extern", s->name,
                s->kind == SYM_EXTERN ? " and has no callback" : "",
                s->kind == SYM_EXTERN ? ", and every extern that has no callback" : "");
  }
  return 0;
}

const char *full_unbound_param(const Full *f) {
  for (int k = 0; f->prog && k < f->prog->params.n; k++)
    if (!f->params[k] && !f->iparams[k]) return ((Sym *)f->prog->params.v[k])->name;
  return NULL;
}

bool full_has_extern_fn(const Full *f, const char *name) {
  int k = find(&f->prog->slots, name);
  return k >= 0 && f->extern_fn[k];
}

void full_free(Full *f) {
  if (!f) return;
  runtime_sparse_free(&f->host);
  jit_free(f->jit);
  jit_free(f->djit);
  if (f->prog && f->dq)
    for (int i = 0; i < f->prog->slots.n; i++) free(f->dq[i]);
  free(f->dq);
  free(f->dqcount);
  demand_free(f->demand);
  if (f->prog) {
    for (int i = 0; i < f->prog->dims.n; i++) free(f->dim_from[i]);
    for (int i = 0; i < f->prog->params.n; i++) {
      free(f->params[i]);
      free(f->iparams[i]);
      free(f->param_files[i]);
    }
    for (int i = 0; i < f->prog->slots.n; i++) free(f->q[i]);
  }
  free(f->dims);
  free(f->dim_from);
  free(f->params);
  free(f->iparams);
  free(f->param_files);
  free(f->q);
  free(f->qcount);
  free(f->fresh);
  free(f->extern_fn);
  free(f->extern_user);
  free(f->dim_names);
  free(f->param_names);
  free(f);
}

/* ---------------------------------------------------------------- derivatives */

int full_deriv_emit(Program *prog, FILE *out) {
  Ctx *ctx = prog->ctx;
  jmp_buf env;
  ctx->on_error = &env;
  bool ok = setjmp(env) == 0;
  if (ok) emit_deriv(ctx, prog, out);
  ctx->on_error = NULL;
  free(ctx->pending_free);
  ctx->pending_free = NULL;
  return ok ? 0 : -1;
}

/* The derivative code, compiled on first use. */
static int deriv_compile(Full *f) {
  Program *prog = f->prog;
  if (f->jvp && !f->dq) { /* compiled, but the arrays' allocation failed */
    f->dq = mem_calloc((size_t)prog->slots.n + 1, sizeof *f->dq);
    if (!f->dq) return fail(f, "out of memory");
  }
  if (f->jvp && !f->dqcount) {
    f->dqcount = mem_calloc((size_t)prog->slots.n + 1, sizeof *f->dqcount);
    if (!f->dqcount) return fail(f, "out of memory");
  }
  if (f->jvp) return 0;
  char *src = NULL;
  size_t len = 0;
  FILE *mem = open_memstream(&src, &len);
  if (!mem) return fail(f, "out of memory");
  if (full_deriv_emit(prog, mem) != 0) {
    fclose(mem);
    free(src);
    return fail(f, "%s", prog->ctx->msg ? prog->ctx->msg : "error: code generation failed\n");
  }
  fclose(mem);
  char err[1024], jvp[1024], vjp[1024];
  f->djit = jit_compile(src, f->backend, err, sizeof err);
  free(src);
  if (!f->djit) return fail(f, "%s", err);
  bool named = emit_symbol(prog, "full_jvp", jvp, sizeof jvp) < (int)sizeof jvp &&
               emit_symbol(prog, "full_vjp", vjp, sizeof vjp) < (int)sizeof vjp;
  f->jvp = named ? (NpgDerivFn)jit_symbol(f->djit, jvp) : NULL;
  f->vjp = named ? (NpgDerivFn)jit_symbol(f->djit, vjp) : NULL;
  if (!f->jvp || !f->vjp) return fail(f, "generated derivative code lacks its entry points (a bug in npg)");
  f->dq = mem_calloc((size_t)prog->slots.n + 1, sizeof *f->dq);
  f->dqcount = mem_calloc((size_t)prog->slots.n + 1, sizeof *f->dqcount);
  if (!f->dq || !f->dqcount) return fail(f, "out of memory");
  return 0;
}

double *const *full_deriv_arrays(Full *f) {
  if (f->error[0]) return NULL;
  if (!f->prog) {
    fail(f, "the evaluator has no program");
    return NULL;
  }
  if (deriv_compile(f) != 0) return NULL;
  for (int k = 0; k < f->prog->slots.n; k++) {
    if (!f->q[k]) {
      fail(f, "derivatives: '%s' has no value yet (evaluate the program first)", ((Sym *)f->prog->slots.v[k])->name);
      return NULL;
    }
    if (f->dqcount[k] != f->qcount[k]) {
      free(f->dq[k]);
      f->dqcount[k] = 0;
      if (!(f->dq[k] = mem_calloc(f->qcount[k] ? f->qcount[k] : 1, sizeof(double)))) {
        fail(f, "out of memory");
        return NULL;
      }
      f->dqcount[k] = f->qcount[k];
    } else memset(f->dq[k], 0, sizeof(double) * f->qcount[k]);
  }
  return f->dq;
}

/* Run a derivative entry point on the evaluation the values hold. */
static int deriv_run(Full *f, NpgDerivFn fn, long sample) {
  if (f->error[0]) return -1;
  if (!fn || !f->dq) return fail(f, "derivatives: full_deriv_arrays was not called (a bug in npg)");
  NpgCtx c = context(f, sample), d = context(f, sample);
  d.q = f->dq;
  f->host.msg[0] = 0;
  if (fn(&c, &d) != 0) return fail(f, "%s", f->host.msg);
  return 0;
}

int full_jvp(Full *f, long sample) { return deriv_run(f, f->jvp, sample); }
int full_vjp(Full *f, long sample) { return deriv_run(f, f->vjp, sample); }
