/* full.c — npg.Full, the full evaluator: params bound from a dict or a
 * folder, inputs as keyword arrays, every output back as an array, extern
 * stages given by Python callables.
 *
 * Inputs that are float64 C-contiguous arrays are read in place; the
 * evaluator copies them into its own buffers (npg_full_set keeps the values
 * for the evaluation and for training). Outputs are fresh arrays, one copy
 * of each output: the evaluator's buffers are overwritten by the next
 * evaluation, and a view would change under the caller's feet. */
#include "npgpy.h"

#include <stdlib.h>

struct ExternSlot {
  ExternSlot *next;
  FullObject *owner;        /* borrowed: a slot is only called during an operation on its owner */
  PyObject *fn;             /* fn(full, sample) -> the extern's values; NULL once cleared by the GC */
  char *name;
};

static long full_dim(const void *f, const char *name) { return npg_full_dim(f, name); }

PyObject *npgpy_full_raise(FullObject *self, const char *msg) {
  npgpy_raise(npgpy_Error, msg);
  if (self->cb_error) { /* the callable's own exception is why the library failed */
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    PyException_SetCause(value, self->cb_error); /* steals */
    self->cb_error = NULL;
    PyErr_Restore(type, value, tb);
  }
  return NULL;
}

/* The library's failure on `self`: its message, then the evaluator is made
 * usable again (the C API refuses work after an error until cleared). */
static PyObject *fail(FullObject *self) {
  npgpy_full_raise(self, npg_full_error(self->f));
  npg_full_clear_error(self->f);
  return NULL;
}

/* An NpgExternFn calling the Python callable of slot `user`. Runs in the
 * thread that evaluates, with the GIL released: it takes the GIL. An
 * exception of the callable is kept in owner->cb_error and becomes the
 * __cause__ of the npg.Error the failed evaluation raises. */
static int call_extern(void *user, const NpgFull *f, long sample, double *out, size_t count) {
  ExternSlot *x = user;
  PyGILState_STATE g = PyGILState_Ensure();
  if (x->owner->in_callback++ == 0) { /* changed with the GIL held: while another thread holds it, the callable runs */
    FullObject *o = x->owner; /* the threads that exist now: one started by the callable is none of them */
    o->ncb_threads = 0;
    for (PyThreadState *ts = PyInterpreterState_ThreadHead(PyThreadState_GetInterpreter(PyThreadState_Get())); ts;
         ts = PyThreadState_Next(ts))
      if (o->ncb_threads >= 0 && o->ncb_threads < 64) o->cb_threads[o->ncb_threads++] = ts->thread_id;
      else o->ncb_threads = -1;
  }
  int rc = -1;
  if (!x->fn) {
    PyErr_Format(npgpy_Error, "extern '%s': its callable was cleared (the evaluator is being collected)", x->name);
  } else {
    PyObject *r = PyObject_CallFunction(x->fn, "Ol", (PyObject *)x->owner, sample);
    char what[256];
    snprintf(what, sizeof what, "extern '%s': the value its callable returned", x->name);
    PyArrayObject *a = r ? npgpy_values(r, what) : NULL;
    Py_XDECREF(r);
    if (a && (size_t)PyArray_SIZE(a) != count)
      PyErr_Format(PyExc_ValueError, "extern '%s': its callable returned %zd values, the extern has %zu at sample %ld",
                   x->name, (Py_ssize_t)PyArray_SIZE(a), count, sample);
    else if (a) {
      if (count) memcpy(out, PyArray_DATA(a), sizeof(double) * count); /* out may be NULL when empty */
      rc = 0;
    }
    Py_XDECREF(a);
  }
  if (rc != 0) {
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    if (value && tb) PyException_SetTraceback(value, tb);
    Py_XDECREF(type);
    Py_XDECREF(tb);
    Py_XSETREF(x->owner->cb_error, value);
  }
  x->owner->in_callback--;
  PyGILState_Release(g);
  return rc;
}

/* Bind `params`: a dict name -> array (integer arrays for int params, as
 * whole doubles), or a directory of <param>.npy. 0, or -1 with an exception. */
static int bind(FullObject *self, PyObject *params) {
  if (params == Py_None) return 0;
  if (PyUnicode_Check(params) || PyObject_HasAttrString(params, "__fspath__")) {
    PyObject *b;
    if (!PyUnicode_FSConverter(params, &b)) return -1;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = npg_full_bind_params(self->f, PyBytes_AS_STRING(b));
    Py_END_ALLOW_THREADS
    Py_DECREF(b);
    if (rc) return fail(self), -1;
    return 0;
  }
  if (!PyDict_Check(params)) {
    PyErr_SetString(PyExc_TypeError, "params: a dict name -> array, or a directory holding <param>.npy");
    return -1;
  }
  PyObject *key, *value;
  Py_ssize_t pos = 0;
  while (PyDict_Next(params, &pos, &key, &value)) {
    const char *name = PyUnicode_Check(key) ? npgpy_utf8(key) : NULL;
    if (!name) {
      if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "params: keys are param names (str)");
      return -1;
    }
    char what[256];
    snprintf(what, sizeof what, "param '%s'", name);
    PyArrayObject *a;
    if (PyArray_Check(value) && PyArray_ISINTEGER((PyArrayObject *)value)) /* int params: whole doubles */
      a = (PyArrayObject *)PyArray_FROMANY(value, NPY_DOUBLE, 0, 0, NPY_ARRAY_IN_ARRAY | NPY_ARRAY_FORCECAST);
    else
      a = npgpy_values(value, what);
    if (!a) return -1;
    long shape[NPY_MAXDIMS];
    npgpy_long_shape(a, shape);
    int rc = npg_full_set_param(self->f, name, PyArray_NDIM(a), shape, PyArray_DATA(a), what);
    Py_DECREF(a);
    if (rc) return fail(self), -1;
  }
  return 0;
}

PyObject *npgpy_full_new(ProgramObject *prog, PyObject *params, const char *backend) {
  NpgBackend b;
  if (npg_backend_parse(backend, &b) != 0)
    return PyErr_Format(PyExc_ValueError, "backend '%s': 'auto' (cc where installed, else libtcc; $NPG_JIT "
                        "overrides), 'cc' (the system compiler, cached) or 'tcc' (libtcc, in memory)", backend);
  FullObject *self = PyObject_GC_New(FullObject, &npgpy_FullType);
  if (!self) return NULL;
  self->prog = (ProgramObject *)Py_NewRef(prog);
  self->f = NULL;
  self->externs = NULL;
  self->cb_error = NULL;
  self->evaluated = false;
  self->in_callback = 0;
  self->calls = 0;
  self->busy.lock = NULL;
  PyObject_GC_Track(self);
  if (npgpy_busy_init(&self->busy) != 0) goto fail;
  Py_BEGIN_ALLOW_THREADS
  self->f = npg_full_new(prog->p, b);
  Py_END_ALLOW_THREADS
  if (!self->f) {
    PyErr_NoMemory();
    goto fail;
  }
  if (npg_full_error(self->f)[0]) {
    npgpy_raise(npgpy_Error, npg_full_error(self->f));
    goto fail;
  }
  if (bind(self, params) != 0) goto fail;
  return (PyObject *)self;
fail:
  Py_DECREF(self);
  return NULL;
}

static int full_traverse(FullObject *self, visitproc visit, void *arg) {
  Py_VISIT(self->prog);
  Py_VISIT(self->cb_error);
  for (ExternSlot *x = self->externs; x; x = x->next) Py_VISIT(x->fn);
  return 0;
}

/* Breaks cycles through the callables (a closure that holds the evaluator);
 * the slots themselves stay until the evaluator is freed. */
static int full_clear(FullObject *self) {
  for (ExternSlot *x = self->externs; x; x = x->next) Py_CLEAR(x->fn);
  Py_CLEAR(self->cb_error);
  return 0;
}

static void full_dealloc(FullObject *self) {
  PyObject_GC_UnTrack(self);
  npg_full_free(self->f); /* first: it may hold the slots as callback data */
  while (self->externs) {
    ExternSlot *x = self->externs;
    self->externs = x->next;
    Py_XDECREF(x->fn);
    PyMem_Free(x->name);
    PyMem_Free(x);
  }
  Py_XDECREF(self->cb_error);
  npgpy_busy_free(&self->busy);
  Py_XDECREF(self->prog);
  PyObject_GC_Del(self);
}

bool npgpy_full_enter(FullObject *self, const char *what) {
  if (npgpy_busy_mine(&self->busy)) {
    PyErr_Format(npgpy_Error, "%s: called from an extern callable of the same evaluator, which is evaluating", what);
    return false;
  }
  /* in_callback changes only with the GIL held, which this thread holds: a callable that starts
   * after this test finds this thread waiting already, so did not start it */
  bool started = self->in_callback > 0 && self->ncb_threads >= 0;
  for (int i = 0; started && i < self->ncb_threads; i++)
    if (self->cb_threads[i] == PyThread_get_thread_ident()) started = false;
  if (started) {
    PyErr_Format(npgpy_Error, "%s: called from a thread started while an extern callable of the same evaluator "
                 "runs; the evaluation waits for the callable, so a callable that waits for this thread would never "
                 "return: evaluate after the callable returns, or give the thread an evaluator of its own "
                 "(program.full())", what);
    return false;
  }
  npgpy_busy_enter(&self->busy);
  return true;
}

/* The PyCapsule destructor of an array that owns a malloc'd buffer. */
static void free_buffer(PyObject *cap) { free(PyCapsule_GetPointer(cap, "npg.buffer")); }

/* An array of `nd` axes `shape` owning `data` (malloc'd): freed with the array (and on failure). */
static PyObject *owning(void *data, int nd, npy_intp *shape, int type) {
  PyObject *a = PyArray_SimpleNewFromData(nd, shape, type, data);
  PyObject *cap = a ? PyCapsule_New(data ? data : (void *)"", "npg.buffer", data ? free_buffer : NULL) : NULL;
  if (!cap || PyArray_SetBaseObject((PyArrayObject *)a, cap) < 0) {
    if (!cap) free(data);
    Py_XDECREF(a);
    return NULL;
  }
  return a;
}

/* A copy of quantity `name` (input, extern or stage) shaped by its dims. */
static PyObject *value_of(FullObject *self, const char *name) {
  size_t n = 0;
  const double *v = npg_full_get(self->f, name, &n);
  const NpgSymbol *s = NULL;
  for (int i = 0; i < self->prog->nsym && !s; i++)
    if (strcmp(self->prog->sym[i].name, name) == 0 && self->prog->sym[i].kind != NPG_PARAM) s = &self->prog->sym[i];
  if (!s) return PyErr_Format(npgpy_Error, "the program has no quantity '%s'", name);
  /* NULL: never set nor evaluated (a zero-size quantity still has a buffer). */
  if (!v) return PyErr_Format(npgpy_Error, "'%s' has no value yet: evaluate first", name);
  npy_intp shape[16];
  int nd = npgpy_shape(s, full_dim, self->f, shape);
  npy_intp total = 1;
  for (int i = 0; i < nd; i++) total *= shape[i];
  if (total != (npy_intp)n) { /* not bound yet */
    nd = 1;
    shape[0] = (npy_intp)n;
  }
  /* copied before anything that may run Python code (an allocation may collect, a finalizer
   * switch threads): read from a thread an extern callable waits for (full_get), the values
   * stay put only while this thread holds the GIL */
  double *copy = malloc(sizeof(double) * (n ? n : 1));
  if (!copy) return PyErr_NoMemory();
  if (n) memcpy(copy, v, sizeof(double) * n);
  return owning(copy, nd, shape, NPY_DOUBLE);
}

/* Set every keyword array as an input or extern of the next evaluation. */
static int set_inputs(FullObject *self, PyObject *kw) {
  PyObject *key, *value;
  Py_ssize_t pos = 0;
  while (kw && PyDict_Next(kw, &pos, &key, &value)) {
    const char *name = npgpy_utf8(key);
    if (!name) return -1;
    char what[256], from[300];
    snprintf(what, sizeof what, "argument '%s'", name);
    /* where it binds a dim: the sample the call evaluates, so that two calls that disagree are told apart */
    snprintf(from, sizeof from, "%s (sample %ld)", what, self->calls);
    PyArrayObject *a = npgpy_values(value, what);
    if (!a) return -1;
    long shape[NPY_MAXDIMS];
    npgpy_long_shape(a, shape);
    int rc = npg_full_set(self->f, name, PyArray_NDIM(a), shape, PyArray_DATA(a), from);
    Py_DECREF(a);
    if (rc) return fail(self), -1;
  }
  return 0;
}

/* full(**inputs) -> {output: array} */
static PyObject *full_call(FullObject *self, PyObject *args, PyObject *kw) {
  if (PyTuple_GET_SIZE(args) > 0) {
    PyErr_SetString(PyExc_TypeError, "Full(...) takes its inputs by name: full(x=array, ...)");
    return NULL;
  }
  if (!npgpy_full_enter(self, "Full.__call__")) return NULL;
  PyObject *out = NULL;
  if (set_inputs(self, kw) != 0) {
    self->evaluated = false;
    goto done;
  }
  int rc;
  long sample = self->calls++;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_full_eval(self->f, sample);
  if (rc == 0) rc = npg_full_check_finite(self->f, sample);
  Py_END_ALLOW_THREADS
  if (rc) {
    self->evaluated = false; /* its values are of no one sample: Trainer.add_full refuses them */
    fail(self);
    goto done;
  }
  self->evaluated = true;
  out = PyDict_New();
  for (int i = 0; out && i < self->prog->nsym; i++) {
    const NpgSymbol *s = &self->prog->sym[i];
    if (!s->output || s->kind == NPG_OP) continue;
    PyObject *v = value_of(self, s->name);
    if (!v || PyDict_SetItemString(out, s->name, v) < 0) Py_CLEAR(out);
    Py_XDECREF(v);
  }
done:
  npgpy_busy_leave(&self->busy);
  return out;
}

static PyObject *full_get(FullObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Full.get");
  if (!name) return NULL;
  /* From an extern callable the evaluation holds the lock; from another thread while a callable
   * runs (a helper it may wait for: taking the lock would wait forever, issue 38) the evaluation
   * is paused in the callable, which cannot return before this thread lets the GIL go: the
   * values are read without the lock (value_of copies them at once). */
  if (self->in_callback > 0) { /* the callables run before the stages: a stage or extern holds the last sample's */
    for (int i = 0; i < self->prog->nsym; i++)
      if (strcmp(self->prog->sym[i].name, name) == 0 && self->prog->sym[i].kind != NPG_INPUT &&
          self->prog->sym[i].kind != NPG_PARAM)
        return PyErr_Format(npgpy_Error, "Full.get('%s') while an extern callable runs: the callables run before the "
                            "stages and the other externs' callables, so only the inputs hold this sample's values "
                            "(an extern reads inputs: `extern v of g`)", name);
  }
  bool unlocked = npgpy_busy_mine(&self->busy) || self->in_callback > 0;
  if (!unlocked) npgpy_busy_enter(&self->busy);
  PyObject *v = value_of(self, name);
  if (!unlocked) npgpy_busy_leave(&self->busy);
  return v;
}

static PyObject *full_dim_method(FullObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Full.dim");
  if (!name) return NULL;
  return PyLong_FromLong(npg_full_dim(self->f, name));
}

static PyObject *full_bind(FullObject *self, PyObject *params) {
  if (!npgpy_full_enter(self, "Full.bind")) return NULL;
  npg_full_unbind(self->f);
  self->evaluated = false;
  int rc = bind(self, params);
  npgpy_busy_leave(&self->busy);
  if (rc) return NULL;
  Py_RETURN_NONE;
}

/* full.extern(name, fn): fn(full, sample) gives the extern's values at
 * every evaluation (None removes it). */
static PyObject *full_extern(FullObject *self, PyObject *args) {
  const char *name;
  PyObject *fn;
  if (!PyArg_ParseTuple(args, "sO:extern", &name, &fn)) return NULL;
  if (fn != Py_None && !PyCallable_Check(fn)) {
    PyErr_Format(PyExc_TypeError, "extern '%s': fn(full, sample) must be callable", name);
    return NULL;
  }
  if (!npgpy_full_enter(self, "Full.extern")) return NULL;
  ExternSlot *x = self->externs;
  while (x && strcmp(x->name, name) != 0) x = x->next;
  PyObject *res = NULL;
  if (!x && fn != Py_None) {
    x = PyMem_Calloc(1, sizeof *x);
    if (x) x->name = PyMem_Malloc(strlen(name) + 1);
    if (!x || !x->name) {
      PyMem_Free(x);
      PyErr_NoMemory();
      goto done;
    }
    strcpy(x->name, name);
    x->owner = self;
    x->next = self->externs;
    self->externs = x;
  }
  if (npg_full_set_extern_fn(self->f, name, fn == Py_None ? NULL : call_extern, fn == Py_None ? NULL : x) != 0) {
    fail(self);
    goto done;
  }
  if (x) Py_XSETREF(x->fn, fn == Py_None ? NULL : Py_NewRef(fn));
  res = Py_NewRef(Py_None);
done:
  npgpy_busy_leave(&self->busy);
  return res;
}

/* full.op(name) -> {'data', 'indices', 'indptr', 'shape'}: an `output op` as
 * CSR (scipy.sparse.csr_matrix((data, indices, indptr), shape)); the arrays
 * own the library's buffers (no copy). */
static PyObject *full_op(FullObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Full.op");
  if (!name) return NULL;
  if (!npgpy_full_enter(self, "Full.op")) return NULL;
  NpgCsr c = {0};
  int rc = npg_full_op(self->f, name, &c);
  PyObject *res = NULL;
  if (rc) fail(self);
  else {
    static_assert(sizeof(long) == sizeof(npy_int64), "long is int64");
    npy_intp nnz = (npy_intp)c.nnz, rows1 = (npy_intp)c.rows + 1;
    PyObject *data = owning(c.data, 1, &nnz, NPY_DOUBLE);
    PyObject *indices = owning(c.indices, 1, &nnz, NPY_INT64);
    PyObject *indptr = owning(c.indptr, 1, &rows1, NPY_INT64);
    if (data && indices && indptr)
      res = Py_BuildValue("{s:O,s:O,s:O,s:(ll)}", "data", data, "indices", indices, "indptr", indptr, "shape",
                          c.rows, c.cols);
    Py_XDECREF(data);
    Py_XDECREF(indices);
    Py_XDECREF(indptr);
  }
  npgpy_busy_leave(&self->busy);
  return res;
}

/* full.simulate(steps, every=1, **inputs) -> {state: array [steps // every + 1, ...]} (DESIGN §15) */
static PyObject *full_simulate(FullObject *self, PyObject *args, PyObject *kw) {
  NpgpyRoll roll;
  if (npgpy_roll_args(self->prog, args, kw, "Full.simulate", &roll) != 0) return NULL;
  if (!npgpy_full_enter(self, "Full.simulate")) return npgpy_roll_free(&roll), NULL;
  roll.f = self->f;
  long sample = self->calls;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npgpy_roll_run(&roll, sample);
  Py_END_ALLOW_THREADS
  self->calls += roll.steps;
  PyObject *out = NULL;
  if (rc) fail(self);
  else {
    self->evaluated = true;
    out = npgpy_roll_result(&roll);
  }
  npgpy_busy_leave(&self->busy);
  npgpy_roll_free(&roll);
  return out;
}

/* ---------------------------------------------------------------- derivatives (DESIGN §17) */

/* The names and float64 arrays of a dict {name: array} (a direction per input, a
 * cotangent per output), each of the quantity's count as bound; `what` names the
 * argument. Returns the number of entries, or -1 with an exception. */
static void free_named(int n, const char **names, PyArrayObject **arrays) {
  for (int i = 0; arrays && i < n; i++) Py_XDECREF(arrays[i]);
  PyMem_Free(names);
  PyMem_Free(arrays);
}

static int named_arrays(FullObject *self, PyObject *dict, const char *what, const char ***names,
                        PyArrayObject ***arrays) {
  if (!PyDict_Check(dict)) {
    PyErr_Format(PyExc_TypeError, "%s: a dict name -> array", what);
    return -1;
  }
  Py_ssize_t n = PyDict_Size(dict), pos = 0;
  int k = 0;
  *names = PyMem_Calloc((size_t)n + 1, sizeof **names);
  *arrays = PyMem_Calloc((size_t)n + 1, sizeof **arrays);
  if (!*names || !*arrays) {
    PyErr_NoMemory();
    goto fail;
  }
  PyObject *key, *value;
  while (PyDict_Next(dict, &pos, &key, &value)) {
    const char *name = PyUnicode_Check(key) ? PyUnicode_AsUTF8(key) : NULL;
    if (!name) {
      PyErr_Format(PyExc_TypeError, "%s: keys are quantity names (str)", what);
      goto fail;
    }
    char item[300];
    snprintf(item, sizeof item, "%s['%s']", what, name);
    size_t count = 0;
    const double *v = npg_full_get(self->f, name, &count);
    (*names)[k] = name;
    if (!((*arrays)[k] = npgpy_values(value, item))) goto fail;
    Py_ssize_t size = PyArray_SIZE((*arrays)[k]);
    k++;
    if (v && (size_t)size != count) {
      PyErr_Format(PyExc_ValueError, "%s: %zd values, but '%s' has %zu", item, size, name, count);
      goto fail;
    }
  }
  return k;
fail:
  free_named(k, *names, *arrays);
  *names = NULL;
  *arrays = NULL;
  return -1;
}

typedef enum DerivKind { DERIV_JVP, DERIV_VJP, DERIV_JACOBIAN } DerivKind;

/* jvp(output, {input: direction}), vjp({output: cotangent}, input), jacobian(output, input), each
 * with **inputs set first: the library's product at the inputs, shaped. */
static PyObject *derivative(FullObject *self, PyObject *args, PyObject *kw, DerivKind kind) {
  static const char *const method[] = {"Full.jvp", "Full.vjp", "Full.jacobian"};
  PyObject *a0, *a1;
  if (!PyArg_UnpackTuple(args, method[kind], 2, 2, &a0, &a1)) return NULL;
  const char *one = npgpy_name(kind == DERIV_VJP ? a1 : a0, method[kind]);
  const char *two = kind == DERIV_JACOBIAN ? npgpy_name(a1, method[kind]) : "";
  if (!one || !two) return NULL;
  if (!npgpy_full_enter(self, method[kind])) return NULL;
  PyObject *res = NULL, *shaped = NULL, *other = NULL;
  const char **names = NULL;
  PyArrayObject **arrays = NULL;
  int n = 0;
  if (set_inputs(self, kw) != 0) goto done;
  self->evaluated = false;
  long sample = self->calls++;
  int rc;
  /* evaluated first: the sizes the arrays are checked against are the point's (the library
   * evaluates again, at the same point) */
  Py_BEGIN_ALLOW_THREADS
  rc = npg_full_eval(self->f, sample);
  Py_END_ALLOW_THREADS
  if (rc) {
    fail(self);
    goto done;
  }
  if (kind != DERIV_JACOBIAN &&
      (n = named_arrays(self, kind == DERIV_JVP ? a1 : a0, kind == DERIV_JVP ? "directions" : "cotangents", &names,
                        &arrays)) < 0) {
    n = 0;
    goto done;
  }
  size_t c1 = 0, c2 = 1;
  npg_full_get(self->f, one, &c1);
  if (kind == DERIV_JACOBIAN) npg_full_get(self->f, two, &c2);
  size_t count = c1 * c2;
  const double **data = PyMem_Calloc((size_t)n + 1, sizeof *data);
  double *buf = malloc(sizeof(double) * (count ? count : 1));
  if (!data || !buf) {
    PyMem_Free(data);
    free(buf);
    PyErr_NoMemory();
    goto done;
  }
  for (int i = 0; i < n; i++) data[i] = PyArray_DATA(arrays[i]);
  Py_BEGIN_ALLOW_THREADS
  if (kind == DERIV_JVP) rc = npg_full_jvp(self->f, sample, n, names, data, one, buf);
  else if (kind == DERIV_VJP) rc = npg_full_vjp(self->f, sample, n, names, data, one, buf);
  else rc = npg_full_jacobian(self->f, sample, one, two, buf);
  Py_END_ALLOW_THREADS
  PyMem_Free(data);
  if (rc) {
    free(buf);
    fail(self);
    goto done;
  }
  self->evaluated = true;
  /* shaped like the quantities: their values' arrays give the shapes */
  if (!(shaped = value_of(self, one)) || (kind == DERIV_JACOBIAN && !(other = value_of(self, two)))) {
    free(buf);
    goto done;
  }
  if (kind != DERIV_JACOBIAN) {
    memcpy(PyArray_DATA((PyArrayObject *)shaped), buf, sizeof(double) * count);
    free(buf);
    res = Py_NewRef(shaped);
    goto done;
  }
  npy_intp shape[2 * NPY_MAXDIMS];
  int nd = 0, nd0 = PyArray_NDIM((PyArrayObject *)shaped), nd1 = PyArray_NDIM((PyArrayObject *)other);
  if (nd0 + nd1 > NPY_MAXDIMS) {
    free(buf);
    PyErr_Format(npgpy_Error, "Full.jacobian: '%s' and '%s' have %d axes together, more than NumPy's %d", one, two,
                 nd0 + nd1, NPY_MAXDIMS);
    goto done;
  }
  for (int i = 0; i < nd0; i++) shape[nd++] = PyArray_DIM((PyArrayObject *)shaped, i);
  for (int i = 0; i < nd1; i++) shape[nd++] = PyArray_DIM((PyArrayObject *)other, i);
  res = owning(buf, nd, shape, NPY_DOUBLE);
done:
  Py_XDECREF(shaped);
  Py_XDECREF(other);
  free_named(n, names, arrays);
  npgpy_busy_leave(&self->busy);
  return res;
}

/* jacobian_csr(output, input, **inputs) -> {'data', 'indices', 'indptr', 'shape'}: npg_full_jacobian_csr,
 * the arrays owning the library's buffers (as Full.op). */
static PyObject *full_jacobian_csr(FullObject *self, PyObject *args, PyObject *kw) {
  PyObject *a0, *a1;
  if (!PyArg_UnpackTuple(args, "Full.jacobian_csr", 2, 2, &a0, &a1)) return NULL;
  const char *out = npgpy_name(a0, "Full.jacobian_csr"), *in = out ? npgpy_name(a1, "Full.jacobian_csr") : NULL;
  if (!out || !in) return NULL;
  if (!npgpy_full_enter(self, "Full.jacobian_csr")) return NULL;
  PyObject *res = NULL;
  if (set_inputs(self, kw) != 0) goto done;
  self->evaluated = false;
  long sample = self->calls++;
  NpgCsr c = {0};
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_full_jacobian_csr(self->f, sample, out, in, &c);
  Py_END_ALLOW_THREADS
  if (rc) {
    fail(self);
    goto done;
  }
  self->evaluated = true;
  npy_intp nnz = (npy_intp)c.nnz, rows1 = (npy_intp)c.rows + 1;
  PyObject *data = owning(c.data, 1, &nnz, NPY_DOUBLE);
  PyObject *indices = owning(c.indices, 1, &nnz, NPY_INT64);
  PyObject *indptr = owning(c.indptr, 1, &rows1, NPY_INT64);
  if (data && indices && indptr)
    res = Py_BuildValue("{s:O,s:O,s:O,s:(ll)}", "data", data, "indices", indices, "indptr", indptr, "shape", c.rows,
                        c.cols);
  Py_XDECREF(data);
  Py_XDECREF(indices);
  Py_XDECREF(indptr);
done:
  npgpy_busy_leave(&self->busy);
  return res;
}

/* An option of Full.newton taken out of its keywords (the rest are inputs): a new reference, or NULL. */
static PyObject *pop_option(PyObject *kw, const char *name) {
  PyObject *v = kw ? PyDict_GetItemString(kw, name) : NULL;
  if (!v) return NULL;
  Py_INCREF(v);
  PyDict_DelItemString(kw, name);
  return v;
}

/* newton(residual, unknown, tol=1e-10, max_iter=20, verbose=False, sample=None, **inputs)
 * -> (unknown's value, shaped, [‖r‖ per iteration]): npg_full_newton, Reduced.newton's signature. */
static PyObject *full_newton(FullObject *self, PyObject *args, PyObject *kw) {
  PyObject *a0, *a1;
  if (!PyArg_UnpackTuple(args, "Full.newton", 2, 2, &a0, &a1)) return NULL;
  const char *res_name = npgpy_name(a0, "Full.newton"), *unk = res_name ? npgpy_name(a1, "Full.newton") : NULL;
  if (!res_name || !unk) return NULL;
  PyObject *inputs = kw ? PyDict_Copy(kw) : NULL, *out = NULL, *value = NULL, *hist_list = NULL;
  if (kw && !inputs) return NULL;
  PyObject *tolo = pop_option(inputs, "tol"), *ito = pop_option(inputs, "max_iter");
  PyObject *verbo = pop_option(inputs, "verbose"), *sampo = pop_option(inputs, "sample");
  NpgNewton o = {.tol = 1e-10, .max_iter = 20};
  bool verbose = false, entered = false;
  long sample = -1;
  if ((tolo && (o.tol = PyFloat_AsDouble(tolo), PyErr_Occurred())) ||
      (ito && (o.max_iter = (int)PyLong_AsLong(ito), PyErr_Occurred())) ||
      (verbo && npgpy_flag(verbo, "Full.newton: verbose", &verbose)) ||
      (sampo && sampo != Py_None && (sample = PyLong_AsLong(sampo), PyErr_Occurred())))
    goto done;
  if (!(entered = npgpy_full_enter(self, "Full.newton"))) goto done;
  if (set_inputs(self, inputs) != 0) goto done;
  self->evaluated = false;
  if (!sampo || sampo == Py_None) sample = self->calls;
  self->calls++;
  double hist[1024];
  o.history = hist, o.history_cap = 1024, o.verbose = verbose ? stderr : NULL;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_full_newton(self->f, sample, res_name, unk, &o);
  Py_END_ALLOW_THREADS
  if (rc) {
    fail(self);
    goto done;
  }
  self->evaluated = true;
  if (!(value = value_of(self, unk)) || !(hist_list = PyList_New(0))) goto done;
  for (int i = 0; i <= o.iterations && i < o.history_cap; i++) {
    PyObject *fl = PyFloat_FromDouble(hist[i]);
    int bad = !fl || PyList_Append(hist_list, fl) < 0;
    Py_XDECREF(fl);
    if (bad) goto done;
  }
  out = PyTuple_Pack(2, value, hist_list);
done:
  if (entered) npgpy_busy_leave(&self->busy);
  Py_XDECREF(value);
  Py_XDECREF(hist_list);
  Py_XDECREF(tolo);
  Py_XDECREF(ito);
  Py_XDECREF(verbo);
  Py_XDECREF(sampo);
  Py_XDECREF(inputs);
  return out;
}

static PyObject *full_jvp(FullObject *self, PyObject *args, PyObject *kw) { return derivative(self, args, kw, DERIV_JVP); }
static PyObject *full_vjp(FullObject *self, PyObject *args, PyObject *kw) { return derivative(self, args, kw, DERIV_VJP); }
static PyObject *full_jacobian(FullObject *self, PyObject *args, PyObject *kw) {
  return derivative(self, args, kw, DERIV_JACOBIAN);
}

static PyObject *full_repr(FullObject *self) { return PyUnicode_FromFormat("<npg.Full of %R>", self->prog->path); }

static PyObject *get_program(FullObject *self, void *unused) { return Py_NewRef(self->prog); }

/* npg_full_jit_info as a dict. */
static PyObject *get_jit(FullObject *self, void *unused) {
  NpgJitInfo ji;
  if (npg_full_jit_info(self->f, &ji) != 0) return PyErr_Format(PyExc_RuntimeError, "%s", npg_full_error(self->f));
  const char *cache = ji.cache == 1 ? "hit" : ji.cache == 0 ? "miss" : ji.cache == 2 ? "rebuilt" : "none";
  return Py_BuildValue("{s:s,s:d,s:s}", "backend", npg_backend_name(ji.backend), "compile_seconds",
                       ji.compile_seconds, "cache", cache);
}

static PyGetSetDef full_getset[] = {
  {"program", (getter)get_program, NULL, "the Program", NULL},
  {"jit", (getter)get_jit, NULL,
   "how the evaluator was compiled: {'backend': 'cc' or 'tcc', 'compile_seconds': float, 'cache': 'hit', "
   "'miss', 'rebuilt' (a damaged entry replaced) or 'none' (libtcc, cache off)}", NULL},
  {NULL},
};

static PyMethodDef full_methods[] = {
  {"get", (PyCFunction)full_get, METH_O,
   "get(name) -> array: a copy of any quantity (input, extern, stage) of the last evaluation"},
  {"simulate", (PyCFunction)(void (*)(void))full_simulate, METH_VARARGS | METH_KEYWORDS,
   "simulate(steps, every=1, **inputs) -> {state: array}: a program with state (DESIGN §15) stepped `steps`\n"
   "times from the states' initial values (state=array); every other input held (its shape) or given per\n"
   "step (a leading steps axis). Each state's array is [steps // every + 1, ...]: steps 0, every, 2 every, ...\n"
   "A blow-up (a state not finite, or its energy past 10x its start; blowup=F changes the factor for this\n"
   "call, 0 checks finiteness only) raises npg.Error naming the step. A state stepped implicitly\n"
   "(`residual next u = ...`) is solved by Newton at every step: newton_tol=1e-10 (relative to the first\n"
   "guess's residual), newton_max_iter=30, newton_verbose=False (|r| per iteration on stderr); a failure\n"
   "raises npg.Error naming the step, iteration and residual."},
  {"dim", (PyCFunction)full_dim_method, METH_O, "dim(name) -> int: the bound size of a dim (-1: unbound)"},
  {"bind", (PyCFunction)full_bind, METH_O, "bind(params): forget every binding and bind these params"},
  {"extern", (PyCFunction)full_extern, METH_VARARGS,
   "extern(name, fn): the extern's values from fn(full, sample) at every evaluation (None: from data again).\n"
   "fn reads what it needs with full.get() (from its own thread or one it starts); it may not evaluate the\n"
   "same evaluator: a call that evaluates with it (full(...), bind, op, simulate, its Trainers' methods,\n"
   "verify) raises npg.Error from fn's thread and from a thread started while fn runs (fn may be waiting for\n"
   "it); other threads wait their turn."},
  {"jacobian", (PyCFunction)(void (*)(void))full_jacobian, METH_VARARGS | METH_KEYWORDS,
   "jacobian(output, input, **inputs) -> array of shape output.shape + input.shape: d output / d input at the\n"
   "inputs given (the others as last set), exact (DESIGN §17)"},
  {"newton", (PyCFunction)(void (*)(void))full_newton, METH_VARARGS | METH_KEYWORDS,
   "newton(residual, unknown, tol=1e-10, max_iter=20, verbose=False, sample=None, **inputs) -> (value, residuals):\n"
   "Newton's method on the full residual for the unknown input (npg_full_newton: the sparse Jacobian by UMFPACK,\n"
   "LAPACK when dense), from its value as set (or given here); residuals: ‖r‖ per iteration; sample: the number\n"
   "failures name (default: the call's)"},
  {"jacobian_csr", (PyCFunction)(void (*)(void))full_jacobian_csr, METH_VARARGS | METH_KEYWORDS,
   "jacobian_csr(output, input, **inputs) -> dict(data, indices, indptr, shape): the Jacobian flattened to\n"
   "count(output) x count(input), on its structural pattern, as CSR (scipy.sparse.csr_matrix((data, indices,\n"
   "indptr), shape)); one forward product per color of its columns"},
  {"jvp", (PyCFunction)(void (*)(void))full_jvp, METH_VARARGS | METH_KEYWORDS,
   "jvp(output, {input: direction, ...}, **inputs) -> array of output's shape: the forward product\n"
   "sum of J(output, input) @ direction"},
  {"vjp", (PyCFunction)(void (*)(void))full_vjp, METH_VARARGS | METH_KEYWORDS,
   "vjp({output: cotangent, ...}, input, **inputs) -> array of input's shape: the reverse product\n"
   "sum of J(output, input)^T @ cotangent"},
  {"op", (PyCFunction)full_op, METH_O,
   "op(name) -> dict(data, indices, indptr, shape): an output op as CSR; the arrays own the library's buffers"},
  {NULL},
};

PyTypeObject npgpy_FullType = {
  PyVarObject_HEAD_INIT(NULL, 0)
  .tp_name = "npg.Full",
  .tp_basicsize = sizeof(FullObject),
  .tp_dealloc = (destructor)full_dealloc,
  .tp_repr = (reprfunc)full_repr,
  .tp_call = (ternaryfunc)full_call,
  .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
  .tp_doc = "A full evaluator (Program.full). full(x=array, ...) -> {output: array} (fresh arrays).\n\n"
            "The k-th call (from 0) is sample k in messages and for extern callables.",
  .tp_traverse = (traverseproc)full_traverse,
  .tp_clear = (inquiry)full_clear,
  .tp_methods = full_methods,
  .tp_getset = full_getset,
};
