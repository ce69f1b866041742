/* module.c — the module `npg._npg` (wrapped by the package npg/__init__.py):
 * its functions, its exceptions and the helpers every type uses (locks,
 * arrays in, shapes). */
#define NPGPY_MODULE_C
#include "npgpy.h"

#include <stdarg.h>
#include <string.h>

PyObject *npgpy_Error, *npgpy_CompileError;
const char *npgpy_std_dir;

/* ---------------------------------------------------------------- locks */

int npgpy_busy_init(Busy *b) {
  b->holder = 0;
  b->lock = PyThread_allocate_lock();
  if (!b->lock) {
    PyErr_NoMemory();
    return -1;
  }
  return 0;
}

void npgpy_busy_free(Busy *b) {
  if (b->lock) PyThread_free_lock(b->lock);
  b->lock = NULL;
}

void npgpy_busy_enter(Busy *b) {
  if (!PyThread_acquire_lock(b->lock, NOWAIT_LOCK)) {
    Py_BEGIN_ALLOW_THREADS
    PyThread_acquire_lock(b->lock, WAIT_LOCK);
    Py_END_ALLOW_THREADS
  }
  b->holder = PyThread_get_thread_ident();
}

void npgpy_busy_leave(Busy *b) {
  b->holder = 0;
  PyThread_release_lock(b->lock);
}

bool npgpy_busy_mine(const Busy *b) { return b->holder == PyThread_get_thread_ident(); }

/* ---------------------------------------------------------------- arrays and errors */

PyArrayObject *npgpy_values(PyObject *obj, const char *what) {
  if (obj == Py_None) { /* numpy makes None a 0-d NaN: "has 0 axes" or "holds NaN" named the wrong problem */
    PyErr_Format(PyExc_TypeError, "%s: None, not an array of float64", what);
    return NULL;
  }
  if (PyArray_Check(obj)) {
    PyArrayObject *a = (PyArrayObject *)obj;
    if (PyArray_TYPE(a) != NPY_DOUBLE) {
      PyErr_Format(PyExc_TypeError, "%s: dtype %R, npg takes float64 arrays (convert with .astype(numpy.float64))",
                   what, (PyObject *)PyArray_DESCR(a));
      return NULL;
    }
    if (PyArray_ISCARRAY_RO(a) && PyArray_ISNOTSWAPPED(a)) {
      Py_INCREF(obj);
      return a; /* used in place: no copy */
    }
  }
  PyObject *arr = PyArray_FROMANY(obj, NPY_DOUBLE, 0, 0, NPY_ARRAY_IN_ARRAY);
  if (!arr) {
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_Format(PyExc_TypeError, "%s: not convertible to a float64 array (%S)", what, value ? value : Py_None);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    return NULL;
  }
  return (PyArrayObject *)arr;
}

void npgpy_long_shape(PyArrayObject *a, long *shape) {
  for (int i = 0; i < PyArray_NDIM(a); i++) shape[i] = (long)PyArray_DIM(a, i);
}

int npgpy_real(PyObject *v, const char *what, double *out) {
  /* PyArg's "d" said "must be real number, not str" without naming the option */
  if (v == Py_None || PyBool_Check(v) || PyUnicode_Check(v) || PyBytes_Check(v) || !PyNumber_Check(v)) {
    PyErr_Format(PyExc_TypeError, "%s must be a number, not %s", what, Py_TYPE(v)->tp_name);
    return -1;
  }
  double d = PyFloat_AsDouble(v);
  if (d == -1 && PyErr_Occurred()) {
    PyErr_Clear();
    PyErr_Format(PyExc_TypeError, "%s must be a real number, not %s %R", what, Py_TYPE(v)->tp_name, v);
    return -1;
  }
  *out = d;
  return 0;
}

int npgpy_flag(PyObject *v, const char *what, bool *out) {
  /* a str, None or any other object is true or false by Python's rule: center='off' was true (issue 38) */
  if (PyBool_Check(v) || PyArray_IsScalar(v, Bool)) {
    int t = PyObject_IsTrue(v);
    if (t < 0) return -1;
    *out = t;
    return 0;
  }
  if (PyLong_CheckExact(v)) {
    int overflow = 0;
    long x = PyLong_AsLongAndOverflow(v, &overflow);
    if (!overflow && (x == 0 || x == 1)) {
      *out = x == 1;
      return 0;
    }
  }
  PyErr_Format(PyExc_TypeError, "%s must be True or False, not %s %R", what, Py_TYPE(v)->tp_name, v);
  return -1;
}

const char *npgpy_utf8(PyObject *str) {
  Py_ssize_t n = 0;
  const char *s = PyUnicode_AsUTF8AndSize(str, &n);
  if (s && strlen(s) != (size_t)n) {
    PyErr_Format(PyExc_ValueError, "%R holds a NUL character at %zu: a name or option ends at none (the library "
                 "would read '%s')", str, strlen(s), s);
    return NULL;
  }
  return s;
}

const char *npgpy_name(PyObject *arg, const char *method) {
  if (PyUnicode_Check(arg)) return npgpy_utf8(arg);
  PyErr_Format(PyExc_TypeError, "%s(name): the name must be a str, not %s", method, Py_TYPE(arg)->tp_name);
  return NULL;
}

PyObject *npgpy_value_error(const char *fmt, ...) {
  char msg[1024];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  PyErr_SetString(PyExc_ValueError, msg);
  return NULL;
}

PyObject *npgpy_raise(PyObject *type, const char *msg) {
  size_t n = strlen(msg);
  while (n > 0 && msg[n - 1] == '\n') n--; /* the library's messages may end a line */
  PyObject *s = PyUnicode_DecodeUTF8(msg, (Py_ssize_t)n, "replace");
  if (s) {
    PyErr_SetObject(type ? type : npgpy_Error, s);
    Py_DECREF(s);
  }
  return NULL;
}

int npgpy_shape(const NpgSymbol *s, long (*dim)(const void *ctx, const char *name), const void *ctx, npy_intp *shape) {
  int nd = 0;
  for (int i = 0; i < s->ndims; i++) shape[nd++] = (npy_intp)dim(ctx, s->dims[i]);
  for (int i = 0; i < s->nstatic; i++) shape[nd++] = s->shape[i];
  return nd;
}

NpgSymbol *npgpy_symbols(NpgProgram *p, int *n) {
  *n = npg_nsymbols(p);
  NpgSymbol *s = PyMem_Calloc((size_t)*n + 1, sizeof *s);
  if (!s) {
    PyErr_NoMemory();
    return NULL;
  }
  for (int i = 0; i < *n; i++) npg_symbol(p, i, &s[i]);
  return s;
}

/* ---------------------------------------------------------------- module */

/* npg._set_std_dir(path): the stdlib the package installed beside itself
 * (npg/__init__.py calls it); None: the library's default. */
static PyObject *set_std_dir(PyObject *self, PyObject *arg) {
  static char *kept;
  if (arg == Py_None) {
    npgpy_std_dir = NULL;
    Py_RETURN_NONE;
  }
  const char *s = npgpy_utf8(arg);
  if (!s) return NULL;
  char *copy = PyMem_RawMalloc(strlen(s) + 1);
  if (!copy) return PyErr_NoMemory();
  strcpy(copy, s);
  PyMem_RawFree(kept);
  npgpy_std_dir = kept = copy;
  Py_RETURN_NONE;
}

static PyMethodDef functions[] = {
  {"compile", (PyCFunction)(void (*)(void))npgpy_compile, METH_VARARGS | METH_KEYWORDS,
   "compile(path_or_source, name=None, std_dir=None) -> Program\n\n"
   "Compile a .npg program: a path (str or os.PathLike naming a file), or the program's text\n"
   "(a str holding a newline, or one that names no file and does not end in .npg); `name`\n"
   "names source text in diagnostics. Raises npg.CompileError with the file:line:col message\n"
   "and the caret."},
  {"load", (PyCFunction)(void (*)(void))npgpy_load, METH_VARARGS | METH_KEYWORDS,
   "load(prog, model_dir, full=None) -> Model\n\n"
   "Load MODEL/ written by npgc train or Trainer.finish for `prog`. `full` (optional): a full\n"
   "evaluator with the model's params bound, the default of Model.verify."},
  {"_set_std_dir", set_std_dir, METH_O, "the default stdlib directory (the package sets it)"},
  {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
  PyModuleDef_HEAD_INIT, "npg._npg",
  "The npg compiler, full evaluation, training and reduced models (the C library npg.h).", -1, functions,
  NULL, NULL, NULL, NULL,
};

static int add_type(PyObject *m, PyTypeObject *t, const char *name) {
  if (PyType_Ready(t) < 0) return -1;
  Py_INCREF(t);
  if (PyModule_AddObject(m, name, (PyObject *)t) < 0) {
    Py_DECREF(t);
    return -1;
  }
  return 0;
}

PyMODINIT_FUNC PyInit__npg(void) {
  import_array();
  PyObject *m = PyModule_Create(&module);
  if (!m) return NULL;
  npgpy_Error = PyErr_NewExceptionWithDoc("npg.Error", "An error of the npg library; its text is the library's "
                                          "message.", NULL, NULL);
  npgpy_CompileError = npgpy_Error ? PyErr_NewExceptionWithDoc("npg.CompileError", "A diagnostic of npg.compile: "
                                     "file:line:col: error: message, the source line and a caret.", npgpy_Error, NULL)
                                   : NULL;
  if (!npgpy_CompileError || PyModule_AddObjectRef(m, "Error", npgpy_Error) < 0 ||
      PyModule_AddObjectRef(m, "CompileError", npgpy_CompileError) < 0 ||
      add_type(m, &npgpy_ProgramType, "Program") < 0 || add_type(m, &npgpy_FullType, "Full") < 0 ||
      add_type(m, &npgpy_TrainerType, "Trainer") < 0 || add_type(m, &npgpy_ModelType, "Model") < 0 ||
      add_type(m, &npgpy_ReducedType, "Reduced") < 0) {
    Py_DECREF(m);
    return NULL;
  }
  return m;
}
