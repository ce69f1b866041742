/* model.c — npg.Model (a trained model: sizes, report, bases, verification)
 * and npg.Reduced (its reduced evaluator).
 *
 * The evaluation path copies nothing larger than a basis coordinate vector:
 * an input given as a float64 C-contiguous array is projected in place
 * (ĝ = Bᵀg reads the caller's buffer), red(...) returns each output's
 * reduced coordinates (m values, copied out of the evaluator, which reuses
 * its storage), and lift() writes B ŷ straight into the array it returns
 * (or into `out`). A basis (Model.basis) is a read-only view of the model's
 * memory that keeps the model alive. */
#include "npgpy.h"

#include <stdio.h>
#include <stdlib.h>

static long model_dim(const void *m, const char *name) { return npg_model_dim(m, name); }

/* ---------------------------------------------------------------- Model */

PyObject *npgpy_model_wrap(ProgramObject *prog, NpgModel *m, FullObject *full) {
  ModelObject *self = PyObject_GC_New(ModelObject, &npgpy_ModelType);
  if (!self) {
    npg_model_free(m);
    return NULL;
  }
  self->prog = (ProgramObject *)Py_NewRef(prog);
  self->m = m;
  self->full = full ? (FullObject *)Py_NewRef(full) : NULL;
  PyObject_GC_Track(self);
  return (PyObject *)self;
}

PyObject *npgpy_load(PyObject *mod, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"prog", "model_dir", "full", NULL};
  PyObject *prog, *dir, *full = Py_None, *b;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "O!O|O:load", kwlist, &npgpy_ProgramType, &prog, &dir, &full))
    return NULL;
  if (full != Py_None && !PyObject_TypeCheck(full, &npgpy_FullType))
    return PyErr_Format(PyExc_TypeError, "load: full must be an npg.Full, not %s", Py_TYPE(full)->tp_name);
  if (full != Py_None && !npg_same_program(((FullObject *)full)->prog->p, ((ProgramObject *)prog)->p))
    return PyErr_Format(npgpy_Error, "load: full evaluates another program than prog (the same source compiled "
                        "twice is the same program)");
  if (!PyUnicode_FSConverter(dir, &b)) return NULL;
  NpgModel *m;
  Py_BEGIN_ALLOW_THREADS
  m = npg_model_load(((ProgramObject *)prog)->p, PyBytes_AS_STRING(b));
  Py_END_ALLOW_THREADS
  Py_DECREF(b);
  if (!m) return PyErr_NoMemory();
  if (npg_model_error(m)[0]) {
    npgpy_raise(npgpy_Error, npg_model_error(m));
    npg_model_free(m);
    return NULL;
  }
  return npgpy_model_wrap((ProgramObject *)prog, m, full == Py_None ? NULL : (FullObject *)full);
}

static int model_traverse(ModelObject *self, visitproc visit, void *arg) {
  Py_VISIT(self->prog);
  Py_VISIT(self->full);
  return 0;
}

static void model_dealloc(ModelObject *self) {
  PyObject_GC_UnTrack(self);
  npg_model_free(self->m); /* before the program it points into */
  Py_XDECREF(self->full);
  Py_XDECREF(self->prog);
  PyObject_GC_Del(self);
}

/* {class label: basis size} */
static PyObject *get_basis_sizes(ModelObject *self, void *unused) {
  PyObject *d = PyDict_New();
  for (int c = 0; d && c < npg_model_nclasses(self->m); c++) {
    NpgClassInfo ci;
    npg_model_class(self->m, c, &ci);
    PyObject *v = PyLong_FromLong(ci.m);
    if (!v || PyDict_SetItemString(d, ci.label, v) < 0) Py_CLEAR(d);
    Py_XDECREF(v);
  }
  return d;
}

/* [{label, n, m, members: [{name, kept, cap, captured}]}] */
static PyObject *get_classes(ModelObject *self, void *unused) {
  int nc = npg_model_nclasses(self->m);
  PyObject *list = PyList_New(nc);
  for (int c = 0; list && c < nc; c++) {
    NpgClassInfo ci;
    npg_model_class(self->m, c, &ci);
    PyObject *members = PyList_New(ci.nmembers);
    for (int i = 0; members && i < ci.nmembers; i++) {
      NpgMemberInfo mi;
      npg_model_member(self->m, c, i, &mi);
      PyObject *d = Py_BuildValue("{s:s,s:i,s:i,s:d}", "name", mi.name, "kept", mi.kept, "cap", mi.cap, "captured",
                                  mi.captured);
      if (!d) Py_CLEAR(members);
      else PyList_SET_ITEM(members, i, d);
    }
    PyObject *d = members ? Py_BuildValue("{s:s,s:l,s:l,s:O}", "label", ci.label, "n", ci.n, "m", ci.m, "members",
                                          members)
                          : NULL;
    Py_XDECREF(members);
    if (!d) Py_CLEAR(list);
    else PyList_SET_ITEM(list, c, d);
  }
  return list;
}

static PyObject *get_samples(ModelObject *self, void *unused) { return PyLong_FromLong(npg_model_samples(self->m)); }
static PyObject *get_program(ModelObject *self, void *unused) { return Py_NewRef(self->prog); }

/* What `print` writes about the model, as a str. */
static PyObject *report_str(ModelObject *self, void (*print)(const NpgModel *, FILE *)) {
  char *buf = NULL;
  size_t len = 0;
  FILE *out = open_memstream(&buf, &len);
  if (!out) return PyErr_NoMemory();
  print(self->m, out);
  fclose(out);
  PyObject *s = PyUnicode_DecodeUTF8(buf ? buf : "", (Py_ssize_t)len, "replace");
  free(buf);
  return s;
}

static PyObject *model_report(ModelObject *self, PyObject *unused) { return report_str(self, npg_model_report); }

static PyObject *model_save(ModelObject *self, PyObject *dir) {
  PyObject *b;
  if (!PyUnicode_FSConverter(dir, &b)) return NULL;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_model_save(self->m, PyBytes_AS_STRING(b));
  Py_END_ALLOW_THREADS
  Py_DECREF(b);
  if (rc) return npgpy_raise(npgpy_Error, npg_model_error(self->m));
  Py_RETURN_NONE;
}

/* A read-only rows x cols view of the model's memory, keeping the model alive. */
static PyObject *matrix_view(ModelObject *self, long rows, long cols, const double *data) {
  npy_intp shape[2] = {rows, cols};
  PyObject *a = PyArray_New(&PyArray_Type, 2, shape, NPY_DOUBLE, NULL, (void *)data, 0,
                            NPY_ARRAY_C_CONTIGUOUS | NPY_ARRAY_ALIGNED, NULL);
  if (!a) return NULL;
  if (PyArray_SetBaseObject((PyArrayObject *)a, Py_NewRef(self)) < 0) {
    Py_DECREF(a);
    return NULL;
  }
  return a;
}

/* model.basis(name) -> n x m read-only view of the basis of name's class */
static PyObject *model_basis(ModelObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Model.basis");
  if (!name) return NULL;
  int c = npg_model_class_of(self->m, name);
  if (c < 0) return PyErr_Format(npgpy_Error, "the model has no basis for '%s'", name);
  NpgClassInfo ci;
  npg_model_class(self->m, c, &ci);
  const double *B = npg_model_basis(self->m, c);
  if (!B) /* NULL data would make numpy allocate an uninitialized array */
    return PyErr_Format(npgpy_Error, "the basis of '%s' (class %s) was streamed in training and not kept in the "
                        "model%s: retrain with --keep-bases %s (npg.Trainer(keep_bases=...))", name, ci.label,
                        npg_model_coefficients(self->m, c, NULL) ? " (its coefficients are: model.coefficients)" : "",
                        name);
  return matrix_view(self, ci.n, ci.m, B);
}

/* model.coefficients(name): C (samples x m), read-only view, of a class kept as coefficients
 * of its training values (npg_model_coefficients): its basis is X C, X the training values. */
static PyObject *model_coefficients(ModelObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Model.coefficients");
  if (!name) return NULL;
  int c = npg_model_class_of(self->m, name);
  if (c < 0) return PyErr_Format(npgpy_Error, "the model has no basis class for '%s'", name);
  NpgClassInfo ci;
  npg_model_class(self->m, c, &ci);
  long S = 0;
  const double *C = npg_model_coefficients(self->m, c, &S);
  if (!C)
    return PyErr_Format(npgpy_Error, "the class of '%s' (%s) is not kept as coefficients of its training values%s",
                        name, ci.label, npg_model_basis(self->m, c) ? ": it keeps its basis (model.basis)" : "");
  return matrix_view(self, S, ci.m, C);
}

/* model.interpolated(stage): how training reduced it (DESIGN §12; npg_model_stage_interpolated) */
static PyObject *model_interpolated(ModelObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Model.interpolated");
  if (!name) return NULL;
  long entries = 0;
  int how = npg_model_stage_interpolated(self->m, name, &entries);
  if (how < 0) return PyErr_Format(npgpy_Error, "the model has no stage '%s'", name);
  return how ? PyLong_FromLong(entries) : Py_NewRef(Py_None);
}

static PyObject *model_reductions(ModelObject *self, PyObject *unused) {
  return report_str(self, npg_model_report_reductions);
}

static PyObject *model_dim_method(ModelObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Model.dim");
  return name ? PyLong_FromLong(npg_model_dim(self->m, name)) : NULL;
}

/* -------------------------------------------------------- verify */

void npgpy_samples_free(NpgpySamples *t) {
  for (int i = 0; i < t->n; i++) Py_XDECREF(t->a[i]), Py_XDECREF(t->key[i]);
  PyMem_Free(t->key);
  PyMem_Free(t->name);
  PyMem_Free(t->a);
  PyMem_Free(t->from);
  memset(t, 0, sizeof *t);
}

int npgpy_samples_set(void *user, NpgFull *f, long k) {
  NpgpySamples *t = user;
  for (int i = 0; i < t->n; i++) {
    PyArrayObject *a = t->a[i];
    long shape[NPY_MAXDIMS];
    size_t per = 1;
    for (int d = 1; d < PyArray_NDIM(a); d++) per *= (size_t)(shape[d - 1] = (long)PyArray_DIM(a, d));
    snprintf(t->from[i], sizeof t->from[i], "%s['%s'] sample %ld", t->arg, t->name[i], k);
    if (npg_full_set(f, t->name[i], PyArray_NDIM(a) - 1, shape, (const double *)PyArray_DATA(a) + per * (size_t)k,
                     t->from[i]) != 0)
      return -1;
  }
  return 0;
}

static int samples_from(const ProgramObject *prog, PyObject *dict, const char *who, const char *arg, NpgpySamples *t);

int npgpy_samples(const ProgramObject *prog, PyObject *dict, const char *who, const char *arg, NpgpySamples *t) {
  /* read from a copy: converting a value (its __array__) may change the caller's dict */
  PyObject *copy = PyDict_Copy(dict);
  if (!copy) return memset(t, 0, sizeof *t), -1;
  int rc = samples_from(prog, copy, who, arg, t);
  Py_DECREF(copy);
  return rc;
}

static int samples_from(const ProgramObject *prog, PyObject *dict, const char *who, const char *arg, NpgpySamples *t) {
  memset(t, 0, sizeof *t);
  t->arg = arg;
  Py_ssize_t n = PyDict_GET_SIZE(dict);
  t->name = PyMem_Calloc((size_t)n + 1, sizeof *t->name);
  t->a = PyMem_Calloc((size_t)n + 1, sizeof *t->a);
  t->from = PyMem_Calloc((size_t)n + 1, sizeof *t->from);
  t->key = PyMem_Calloc((size_t)n + 1, sizeof *t->key);
  if (!t->name || !t->a || !t->from || !t->key) return PyErr_NoMemory(), npgpy_samples_free(t), -1;
  PyObject *key, *value;
  t->count = -1;
  for (Py_ssize_t pos = 0; PyDict_Next(dict, &pos, &key, &value) && t->n < n;) {
    if (!PyUnicode_Check(key)) {
      PyErr_Format(PyExc_TypeError, "%s: %s's keys are input and extern names (str), not %s", who, arg,
                   Py_TYPE(key)->tp_name);
      return npgpy_samples_free(t), -1;
    }
    const char *name = npgpy_utf8(key);
    if (!name) return npgpy_samples_free(t), -1;
    for (int i = 0; i < prog->nsym; i++) /* a param would rebind the evaluator for every later use (trial3) */
      if (prog->sym[i].kind == NPG_PARAM && strcmp(prog->sym[i].name, name) == 0) {
        PyErr_Format(npgpy_Error, "%s: %s['%s'] is a param: samples hold inputs and externs (the params are the "
                                  "evaluator's, bound by program.full(params=...) or full.bind)", who, arg, name);
        return npgpy_samples_free(t), -1;
      }
    char what[256];
    snprintf(what, sizeof what, "%s: %s['%s']", who, arg, name);
    PyArrayObject *a = npgpy_values(value, what);
    if (!a) return npgpy_samples_free(t), -1;
    /* the key held: `name` points into it, and an extern callable may clear the dict (issue 38) */
    t->key[t->n] = Py_NewRef(key);
    t->name[t->n] = name;
    t->a[t->n++] = a;
    if (PyArray_NDIM(a) < 1) {
      PyErr_Format(npgpy_Error, "%s: %s['%s'] has no sample axis (the first axis is the sample)", who, arg, name);
      return npgpy_samples_free(t), -1;
    }
    long S = (long)PyArray_DIM(a, 0);
    /* refused when given (Trainer's valid= at construction, not at finish after every sample) */
    const double *v = PyArray_DATA(a);
    size_t total = (size_t)PyArray_SIZE(a), per = S > 0 ? total / (size_t)S : 0;
    for (size_t e = 0; e < total; e++)
      if (!isfinite(v[e])) {
        PyErr_Format(npgpy_Error, "%s: %s['%s'] sample %zu holds %s at flat entry %zu", who, arg, name, e / per,
                     isnan(v[e]) ? "NaN" : "an infinity", e % per);
        return npgpy_samples_free(t), -1;
      }
    if (t->count >= 0 && S != t->count) {
      PyErr_Format(npgpy_Error, "%s: %s['%s'] has %ld samples, the arrays before it %ld", who, arg, name, S, t->count);
      return npgpy_samples_free(t), -1;
    }
    t->count = S;
  }
  if (t->count < 1) {
    PyErr_Format(npgpy_Error, "%s: no %s samples (give %s={'x': array of samples x ...})", who, arg, arg);
    return npgpy_samples_free(t), -1;
  }
  return 0;
}

static PyObject *row_dict(const NpgVerifyRow *r, double tol) {
  PyObject *d = Py_BuildValue("{s:s,s:l,s:O,s:d,s:d,s:d,s:d,s:l,s:d,s:d}", "kind", r->kind, "m", r->m, "output",
                              r->output ? Py_True : Py_False, "l2", r->l2, "floor", r->floor, "own", r->own, "l2_max",
                              r->l2_max, "l2_max_sample", r->l2_max_sample, "linf", r->linf, "linf_floor",
                              r->linf_floor);
  if (d && tol >= 0 && r->output && PyDict_SetItemString(d, "pass", r->l2 <= tol ? Py_True : Py_False) < 0)
    Py_CLEAR(d);
  return d;
}

/* model.verify(test, tol=None, full=None, progress=False) -> {quantity: {...}} */
static PyObject *model_verify(ModelObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"test", "tol", "full", "progress", "steps", "every", NULL};
  PyObject *test, *tolo = Py_None, *fullo = Py_None, *progresso = Py_False, *stepso = Py_None, *everyo = Py_None;
  bool progress;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "O!|OOOOO:verify", kwlist, &PyDict_Type, &test, &tolo, &fullo, &progresso,
                                   &stepso, &everyo) ||
      npgpy_flag(progresso, "verify: progress", &progress))
    return NULL;
  long steps = -1, every = 1;
  PyObject *ints[2] = {stepso, everyo};
  long *dst[2] = {&steps, &every};
  for (int i = 0; i < 2; i++) {
    if (ints[i] == Py_None) continue;
    if (!PyLong_Check(ints[i]) || PyBool_Check(ints[i]))
      return PyErr_Format(PyExc_TypeError, "verify: %s must be an int, not %s", i ? "every" : "steps",
                          Py_TYPE(ints[i])->tp_name);
    if ((*dst[i] = PyLong_AsLong(ints[i])) == -1 && PyErr_Occurred()) return NULL;
  }
  if (everyo != Py_None && stepso == Py_None)
    return PyErr_Format(PyExc_TypeError, "verify: every keeps every K-th step of a rollout: give steps too");
  double tol = -1;
  if (tolo != Py_None && npgpy_real(tolo, "verify: tol", &tol)) return NULL;
  /* As npgc verify --tol: a finite number >= 0 (-1 would otherwise mean "no tolerance" below). */
  if (tolo != Py_None && !(isfinite(tol) && tol >= 0))
    return npgpy_value_error("verify: tol is %g; expected a finite number >= 0", tol);
  FullObject *full = self->full;
  if (fullo != Py_None) {
    if (!PyObject_TypeCheck(fullo, &npgpy_FullType))
      return PyErr_Format(PyExc_TypeError, "verify: full must be an npg.Full, not %s", Py_TYPE(fullo)->tp_name);
    full = (FullObject *)fullo;
  }
  if (!full)
    return PyErr_Format(npgpy_Error, "verify: this model has no full evaluator (a loaded model): give full=, an "
                                     "evaluator with the model's params bound");
  if (!npg_same_program(full->prog->p, self->prog->p))
    return PyErr_Format(npgpy_Error, "verify: full evaluates another program than the model's (the same source "
                        "compiled twice is the same program)");
  if (stepso != Py_None) /* DESIGN §15: the trajectory, not one step */
    return npgpy_verify_rollout(self->prog, self->m, full, test, steps, every, progress, tol);
  NpgpySamples t;
  PyObject *res = NULL;
  if (npgpy_samples(self->prog, test, "verify", "test", &t) != 0) return NULL;
  if (!npgpy_full_enter(full, "Model.verify")) goto done;
  NpgVerifyReport rep;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_verify(self->m, full->f, t.count, npgpy_samples_set, &t, progress, &rep);
  Py_END_ALLOW_THREADS
  npg_full_clear_error(full->f);
  npgpy_busy_leave(&full->busy);
  if (rc) {
    npgpy_full_raise(full, rep.error);
    npg_verify_free(&rep);
    goto done;
  }
  res = PyDict_New();
  for (int i = 0; res && i < rep.nrows; i++) {
    PyObject *d = row_dict(&rep.rows[i], tol);
    if (!d || PyDict_SetItemString(res, rep.rows[i].name, d) < 0) Py_CLEAR(res);
    Py_XDECREF(d);
  }
  npg_verify_free(&rep);
done:
  npgpy_samples_free(&t);
  return res;
}

/* ---------------------------------------------------------------- Reduced */

typedef struct ReducedObject {
  PyObject_HEAD
  ModelObject *model;
  NpgReduced *r;
  Busy busy;
  int ninputs, noutputs;
  bool given_externs;       /* red.given_externs(True): externs are given like inputs */
  const NpgSymbol **input;  /* the program's inputs and externs, and for each: */
  PyObject **input_name;    /*   its name as str (keyword lookup by identity first) */
  npy_intp (*input_shape)[16];
  int *input_nd;
  size_t *input_count;
  bool *input_set;          /*   set at least once (an input never set is an error, not a zero) */
  const NpgSymbol **output; /* the outputs that are quantities (not ops) */
  PyObject **output_name;
  long sample;              /* steps simulated so far: the sample number of a rollout's next step (red(...)
                               evaluates no sample of a set: its messages say "at these inputs") */
} ReducedObject;

static int reduced_traverse(ReducedObject *self, visitproc visit, void *arg) {
  Py_VISIT(self->model);
  return 0;
}

static void reduced_dealloc(ReducedObject *self) {
  PyObject_GC_UnTrack(self);
  npg_reduced_free(self->r); /* before the model it reads */
  for (int i = 0; self->input_name && i < self->ninputs; i++) Py_XDECREF(self->input_name[i]);
  for (int i = 0; self->output_name && i < self->noutputs; i++) Py_XDECREF(self->output_name[i]);
  PyMem_Free(self->input);
  PyMem_Free(self->input_name);
  PyMem_Free(self->input_shape);
  PyMem_Free(self->input_nd);
  PyMem_Free(self->input_count);
  PyMem_Free(self->input_set);
  PyMem_Free(self->output);
  PyMem_Free(self->output_name);
  npgpy_busy_free(&self->busy);
  Py_XDECREF(self->model);
  PyObject_GC_Del(self);
}

/* The library failed: its message; the evaluator is usable again. */
static PyObject *rfail(ReducedObject *self) {
  npgpy_raise(npgpy_Error, npg_reduced_error(self->r));
  npg_reduced_clear_error(self->r);
  return NULL;
}

/* sizes={class: n, ...} as npgc's --sizes text "class=n,..." (malloc'd; NULL with a Python error). */
static char *sizes_spec(PyObject *sizes) {
  if (!PyDict_Check(sizes)) {
    PyErr_Format(PyExc_TypeError, "reduced: sizes must be a dict {class: size} (classes as npgc check names them, "
                 "m_u), not %.80s", Py_TYPE(sizes)->tp_name);
    return NULL;
  }
  size_t cap = 1, len = 0;
  char *spec = malloc(cap);
  if (!spec) return PyErr_NoMemory(), NULL;
  spec[0] = 0;
  Py_ssize_t pos = 0;
  PyObject *key, *val;
  while (PyDict_Next(sizes, &pos, &key, &val)) {
    const char *name = PyUnicode_Check(key) ? PyUnicode_AsUTF8(key) : NULL;
    if (!name || strchr(name, ',') || strchr(name, '=')) {
      if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "reduced: sizes: every key is a class name (str: m_u)");
      return free(spec), NULL;
    }
    if (!PyLong_Check(val) || PyBool_Check(val)) {
      PyErr_Format(PyExc_TypeError, "reduced: sizes['%s'] must be an int, not %.80s", name, Py_TYPE(val)->tp_name);
      return free(spec), NULL;
    }
    long n = PyLong_AsLong(val);
    if (n == -1 && PyErr_Occurred()) return free(spec), NULL;
    size_t need = len + strlen(name) + 32;
    if (need > cap) {
      char *grown = realloc(spec, need * 2);
      if (!grown) return free(spec), PyErr_NoMemory(), NULL;
      spec = grown, cap = need * 2;
    }
    len += (size_t)snprintf(spec + len, cap - len, "%s%s=%ld", len ? "," : "", name, n);
  }
  return spec;
}

static PyObject *model_reduced(ModelObject *model, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"exact_roots", "sizes", NULL};
  PyObject *exacto = Py_False, *sizes = Py_None;
  bool exact;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "|OO:reduced", kwlist, &exacto, &sizes) ||
      npgpy_flag(exacto, "reduced: exact_roots", &exact))
    return NULL;
  char *spec = sizes == Py_None ? NULL : sizes_spec(sizes);
  if (sizes != Py_None && !spec) return NULL;
  ReducedObject *self = PyObject_GC_New(ReducedObject, &npgpy_ReducedType);
  if (!self) return NULL;
  memset((char *)self + sizeof(PyObject), 0, sizeof *self - sizeof(PyObject));
  self->model = (ModelObject *)Py_NewRef(model);
  PyObject_GC_Track(self);
  const ProgramObject *p = model->prog;
  int n = p->nsym;
  if (npgpy_busy_init(&self->busy) != 0) goto fail;
  self->input = PyMem_Calloc((size_t)n + 1, sizeof *self->input);
  self->input_name = PyMem_Calloc((size_t)n + 1, sizeof *self->input_name);
  self->input_shape = PyMem_Calloc((size_t)n + 1, sizeof *self->input_shape);
  self->input_nd = PyMem_Calloc((size_t)n + 1, sizeof *self->input_nd);
  self->input_count = PyMem_Calloc((size_t)n + 1, sizeof *self->input_count);
  self->input_set = PyMem_Calloc((size_t)n + 1, sizeof *self->input_set);
  self->output = PyMem_Calloc((size_t)n + 1, sizeof *self->output);
  self->output_name = PyMem_Calloc((size_t)n + 1, sizeof *self->output_name);
  if (!self->input || !self->input_name || !self->input_shape || !self->input_nd || !self->input_count ||
      !self->input_set || !self->output || !self->output_name) {
    PyErr_NoMemory();
    goto fail;
  }
  for (int i = 0; i < n; i++) {
    const NpgSymbol *s = &p->sym[i];
    if (s->kind == NPG_INPUT || s->kind == NPG_EXTERN) { /* an extern: after red.given_externs(True) */
      int k = self->ninputs++;
      self->input[k] = s;
      if (!(self->input_name[k] = PyUnicode_InternFromString(s->name))) goto fail;
      self->input_nd[k] = npgpy_shape(s, model_dim, model->m, self->input_shape[k]);
      size_t c = 1;
      for (int d = 0; d < self->input_nd[k]; d++) c *= (size_t)self->input_shape[k][d];
      self->input_count[k] = c;
    }
    if (s->output && s->kind != NPG_OP && s->kind != NPG_INPUT) {
      int k = self->noutputs++;
      self->output[k] = s;
      if (!(self->output_name[k] = PyUnicode_InternFromString(s->name))) goto fail;
    }
  }
  self->r = npg_reduced_new_sizes(model->m, spec);
  free(spec), spec = NULL;
  if (!self->r) {
    PyErr_NoMemory();
    goto fail;
  }
  if (npg_reduced_error(self->r)[0]) {
    npgpy_raise(npgpy_Error, npg_reduced_error(self->r));
    goto fail;
  }
  npg_reduced_exact_roots(self->r, exact);
  return (PyObject *)self;
fail:
  free(spec);
  Py_DECREF(self);
  return NULL;
}

static int input_index(ReducedObject *self, PyObject *key) {
  for (int i = 0; i < self->ninputs; i++)
    if (self->input_name[i] == key) return i;
  for (int i = 0; i < self->ninputs; i++) {
    int eq = PyUnicode_Compare(self->input_name[i], key);
    if (eq == 0) return i;
  }
  return -1;
}

static PyObject *shape_text(const npy_intp *shape, int nd) {
  PyObject *t = PyTuple_New(nd);
  for (int d = 0; t && d < nd; d++) PyTuple_SET_ITEM(t, d, PyLong_FromSsize_t(shape[d]));
  return t;
}

/* red(**inputs) -> {output: reduced coordinates} */
static PyObject *reduced_call(ReducedObject *self, PyObject *args, PyObject *kw) {
  enum { MAXIN = 64 };
  if (PyTuple_GET_SIZE(args) > 0) {
    PyErr_SetString(PyExc_TypeError, "Reduced(...) takes its inputs by name: red(x=array, ...)");
    return NULL;
  }
  Py_ssize_t nkw = kw ? PyDict_GET_SIZE(kw) : 0;
  if (nkw > MAXIN) return PyErr_Format(PyExc_TypeError, "red(...): at most %d inputs", MAXIN);
  PyArrayObject *arr[MAXIN];
  int idx[MAXIN], na = 0;
  PyObject *key, *value, *res = NULL;
  Py_ssize_t pos = 0;
  while (kw && PyDict_Next(kw, &pos, &key, &value)) {
    int k = input_index(self, key);
    if (k < 0) {
      PyErr_Format(npgpy_Error, "red(...): the program has no input '%U' (outputs, stages and externs are computed)",
                   key);
      goto done;
    }
    if (self->input[k]->kind == NPG_EXTERN && !self->given_externs) {
      PyErr_Format(npgpy_Error, "red(...): '%U' is an extern, which the model computes from its inputs: give it "
                   "after red.given_externs(True)", key);
      goto done;
    }
    PyArrayObject *a;
    if (PyArray_CheckExact(value) && PyArray_TYPE((PyArrayObject *)value) == NPY_DOUBLE &&
        PyArray_ISCARRAY_RO((PyArrayObject *)value) && PyArray_ISNOTSWAPPED((PyArrayObject *)value)) {
      a = (PyArrayObject *)Py_NewRef(value); /* the common case: in place */
    } else {
      char what[256];
      snprintf(what, sizeof what, "input '%s'", self->input[k]->name);
      if (!(a = npgpy_values(value, what))) goto done;
    }
    arr[na] = a;
    idx[na++] = k;
    int nd = PyArray_NDIM(a);
    bool same = nd == self->input_nd[k];
    for (int d = 0; same && d < nd; d++) same = PyArray_DIM(a, d) == self->input_shape[k][d];
    /* a flat array of the right size is accepted: C order is the library's */
    if (!same && !(nd == 1 && (size_t)PyArray_DIM(a, 0) == self->input_count[k])) {
      PyObject *want = shape_text(self->input_shape[k], self->input_nd[k]);
      PyObject *got = shape_text(PyArray_DIMS(a), nd);
      if (want && got)
        PyErr_Format(npgpy_Error, "input '%s' has shape %R; the model was trained with %R", self->input[k]->name,
                     got, want);
      Py_XDECREF(want);
      Py_XDECREF(got);
      goto done;
    }
  }
  npgpy_busy_enter(&self->busy);
  for (int i = 0; i < na; i++) self->input_set[idx[i]] = true;
  for (int k = 0; k < self->ninputs; k++)
    if (!self->input_set[k] && self->input[k]->kind == NPG_INPUT) { /* an extern never given: the library says */
      npgpy_busy_leave(&self->busy);
      PyErr_Format(npgpy_Error, "input '%s' is not set: give it (red(%s=array)) at least once, or its coordinates "
                   "(red.set_coords('%s', coords))", self->input[k]->name, self->input[k]->name,
                   self->input[k]->name);
      goto done;
    }
  int rc = 0;
  /* no sample of a set: the library's messages say "at these inputs" (a count of calls called
   * "sample 2" misled, issue 38) */
  long sample = -1;
  Py_BEGIN_ALLOW_THREADS
  for (int i = 0; i < na && rc == 0; i++)
    rc = npg_reduced_set(self->r, self->input[idx[i]]->name, self->input_count[idx[i]], PyArray_DATA(arr[i]));
  if (rc == 0) rc = npg_reduced_eval(self->r, sample);
  Py_END_ALLOW_THREADS
  if (rc) {
    /* an input that failed to project keeps its old coordinates: it is set no more */
    for (int i = 0; i < na; i++) self->input_set[idx[i]] = false;
    rfail(self);
  } else {
    res = PyDict_New();
    for (int o = 0; res && o < self->noutputs; o++) {
      size_t m = 0;
      const double *c = npg_reduced_coords(self->r, self->output[o]->name, &m);
      npy_intp dm = (npy_intp)m;
      PyObject *a = PyArray_SimpleNew(1, &dm, NPY_DOUBLE);
      if (a && m) memcpy(PyArray_DATA((PyArrayObject *)a), c, sizeof(double) * m);
      if (!a || PyDict_SetItem(res, self->output_name[o], a) < 0) Py_CLEAR(res);
      Py_XDECREF(a);
    }
  }
  npgpy_busy_leave(&self->busy);
done:
  for (int i = 0; i < na; i++) Py_DECREF(arr[i]);
  return res;
}

/* The symbol of quantity `name` (not a param or op), NULL with npg.Error. */
static const NpgSymbol *quantity(ReducedObject *self, const char *name) {
  const ProgramObject *p = self->model->prog;
  for (int i = 0; i < p->nsym; i++)
    if (strcmp(p->sym[i].name, name) == 0 && p->sym[i].kind != NPG_PARAM && p->sym[i].kind != NPG_OP)
      return &p->sym[i];
  PyErr_Format(npgpy_Error, "the program has no quantity '%s'", name);
  return NULL;
}

/* red.lift(name, coords=C): the rows of C (samples x m) lifted at once
 * (npg_reduced_lift_many), samples x the quantity's shape. */
static PyObject *lift_many(ReducedObject *self, const NpgSymbol *s, const char *name, PyObject *coords) {
  PyArrayObject *c = (PyArrayObject *)PyArray_FROMANY(coords, NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
  if (!c) return PyErr_Format(PyExc_TypeError, "lift('%s', coords=...): coords must be a 2-D array of numbers "
                              "(samples x reduced coordinates)", name);
  npy_intp shape[17];
  shape[0] = PyArray_DIM(c, 0);
  int nd = 1 + npgpy_shape(s, model_dim, self->model->m, shape + 1);
  PyArrayObject *a = (PyArrayObject *)PyArray_SimpleNew(nd, shape, NPY_DOUBLE);
  if (!a) return Py_DECREF(c), NULL;
  size_t count = shape[0] ? (size_t)(PyArray_SIZE(a) / shape[0]) : 0;
  npgpy_busy_enter(&self->busy);
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_reduced_lift_many(self->r, name, (size_t)PyArray_DIM(c, 0), (size_t)PyArray_DIM(c, 1), PyArray_DATA(c),
                             PyArray_DATA(a), count);
  Py_END_ALLOW_THREADS
  if (rc) {
    rfail(self);
    Py_CLEAR(a);
  }
  npgpy_busy_leave(&self->busy);
  Py_DECREF(c);
  return (PyObject *)a;
}

/* red.lift(name, out=None) -> B ŷ, shaped like the quantity, written into
 * a new array (or `out`, float64 C-contiguous of the right size); with
 * coords=C, every row of C lifted at once (lift_many). */
static PyObject *reduced_lift(ReducedObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"name", "out", "coords", NULL};
  const char *name;
  PyObject *out = Py_None, *coords = Py_None;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "s|OO:lift", kwlist, &name, &out, &coords)) return NULL;
  const NpgSymbol *s = quantity(self, name);
  if (!s) return NULL;
  if (coords != Py_None) {
    if (out != Py_None) return PyErr_Format(PyExc_TypeError, "lift('%s'): give out= or coords=, not both", name);
    return lift_many(self, s, name, coords);
  }
  npy_intp shape[16];
  int nd = npgpy_shape(s, model_dim, self->model->m, shape);
  PyArrayObject *a;
  if (out == Py_None) {
    if (!(a = (PyArrayObject *)PyArray_SimpleNew(nd, shape, NPY_DOUBLE))) return NULL;
  } else {
    if (!PyArray_Check(out) || PyArray_TYPE((PyArrayObject *)out) != NPY_DOUBLE ||
        !PyArray_ISCARRAY((PyArrayObject *)out) || !PyArray_ISNOTSWAPPED((PyArrayObject *)out))
      return PyErr_Format(PyExc_TypeError, "lift('%s', out=...): out must be a writeable float64 C-contiguous array",
                          name);
    a = (PyArrayObject *)Py_NewRef(out);
  }
  npgpy_busy_enter(&self->busy);
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_reduced_lift(self->r, name, PyArray_DATA(a), (size_t)PyArray_SIZE(a));
  Py_END_ALLOW_THREADS
  if (rc) {
    rfail(self);
    Py_CLEAR(a);
  }
  npgpy_busy_leave(&self->busy);
  return (PyObject *)a;
}

/* red.coords(name) -> a copy of any quantity's reduced coordinates */
static PyObject *reduced_coords(ReducedObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Reduced.coords");
  if (!name || !quantity(self, name)) return NULL;
  npgpy_busy_enter(&self->busy);
  size_t m = 0;
  const double *c = npg_reduced_coords(self->r, name, &m);
  if (!c) {
    npgpy_busy_leave(&self->busy);
    return PyErr_Format(npgpy_Error, "coords('%s'): '%s' was not set and nothing was evaluated yet (red.eval)", name,
                        name);
  }
  npy_intp dm = (npy_intp)m;
  PyObject *a = PyArray_SimpleNew(1, &dm, NPY_DOUBLE);
  if (a && m) memcpy(PyArray_DATA((PyArrayObject *)a), c, sizeof(double) * m);
  npgpy_busy_leave(&self->busy);
  return a;
}

/* red.set_coords(name, coords): an input from its reduced coordinates */
static PyObject *reduced_set_coords(ReducedObject *self, PyObject *args) {
  const char *name;
  PyObject *v;
  if (!PyArg_ParseTuple(args, "sO:set_coords", &name, &v)) return NULL;
  char what[256];
  snprintf(what, sizeof what, "set_coords('%s')", name);
  PyArrayObject *a = npgpy_values(v, what);
  if (!a) return NULL;
  npgpy_busy_enter(&self->busy);
  int rc = npg_reduced_set_coords(self->r, name, (size_t)PyArray_SIZE(a), PyArray_DATA(a));
  PyObject *res = NULL;
  if (rc) rfail(self);
  else {
    PyObject *key = PyUnicode_FromString(name);
    int k = key ? input_index(self, key) : -1;
    Py_XDECREF(key);
    if (k >= 0) self->input_set[k] = true;
    res = Py_NewRef(Py_None);
  }
  npgpy_busy_leave(&self->busy);
  Py_DECREF(a);
  return res;
}

/* red.given_externs(on): with True, externs keep the values given (red(v=...), red.set_coords)
 * instead of the learned map's (npg_reduced_given_externs: the Arvo split of errors) */
static PyObject *reduced_given_externs(ReducedObject *self, PyObject *arg) {
  bool on;
  if (npgpy_flag(arg, "given_externs: on", &on)) return NULL;
  npgpy_busy_enter(&self->busy);
  npg_reduced_given_externs(self->r, on);
  self->given_externs = on;
  npgpy_busy_leave(&self->busy);
  Py_RETURN_NONE;
}

/* red.op(name) -> the reduced `output op` matrix B_rowᵀ M B_col (rows x cols) */
static PyObject *reduced_op(ReducedObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Reduced.op");
  if (!name) return NULL;
  size_t cap = 0;
  for (int c = 0; c < npg_model_nclasses(self->model->m); c++) {
    NpgClassInfo ci;
    npg_model_class(self->model->m, c, &ci);
    if ((size_t)(ci.m * ci.m) > cap) cap = (size_t)(ci.m * ci.m);
  }
  double *buf = malloc(sizeof(double) * (cap + 1));
  if (!buf) return PyErr_NoMemory();
  long rows = 0, cols = 0;
  npgpy_busy_enter(&self->busy);
  int rc = npg_reduced_op(self->r, name, buf, cap, &rows, &cols, NULL, NULL);
  PyObject *a = NULL;
  if (rc) rfail(self);
  else {
    npy_intp shape[2] = {rows, cols};
    if ((a = PyArray_SimpleNew(2, shape, NPY_DOUBLE)))
      memcpy(PyArray_DATA((PyArrayObject *)a), buf, sizeof(double) * (size_t)(rows * cols));
  }
  npgpy_busy_leave(&self->busy);
  free(buf);
  return a;
}

/* red.estimate(name) -> float: the online estimate of quantity `name` at the last evaluation,
 * absolute, the 2-norm of its lifted values' error, or its class's product norm (NaN: none;
 * npg_reduced_estimate) */
static PyObject *reduced_estimate(ReducedObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Reduced.estimate");
  if (!name || !quantity(self, name)) return NULL;
  npgpy_busy_enter(&self->busy);
  double e = NAN;
  int rc = npg_reduced_estimate(self->r, name, &e, NULL);
  PyObject *res = rc ? rfail(self) : PyFloat_FromDouble(e);
  npgpy_busy_leave(&self->busy);
  return res;
}

/* red.estimate_info(name) -> dict: the estimate with its flags and why there is none */
static PyObject *reduced_estimate_info(ReducedObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Reduced.estimate_info");
  if (!name || !quantity(self, name)) return NULL;
  npgpy_busy_enter(&self->busy);
  double e = NAN;
  unsigned f = 0;
  PyObject *res = NULL;
  if (npg_reduced_estimate(self->r, name, &e, &f)) res = rfail(self);
  else
    res = Py_BuildValue("{s:d,s:O,s:O,s:O,s:s}", "estimate", e, "bound", f & NPG_EST_BOUND ? Py_True : Py_False,
                        "outside", f & NPG_EST_OUTSIDE ? Py_True : Py_False, "roundoff",
                        f & NPG_EST_ROUNDOFF ? Py_True : Py_False, "why", npg_reduced_estimate_why(self->r, name));
  npgpy_busy_leave(&self->busy);
  return res;
}

/* red.outside(name) -> the first reduced coordinate of input `name` outside the training
 * range, or None (npg_reduced_outside) */
static PyObject *reduced_outside(ReducedObject *self, PyObject *arg) {
  const char *name = npgpy_name(arg, "Reduced.outside");
  if (!name) return NULL;
  npgpy_busy_enter(&self->busy);
  long coord = -1;
  int rc = npg_reduced_outside(self->r, name, &coord);
  PyObject *res = rc < 0 ? rfail(self) : rc ? PyLong_FromLong(coord) : Py_NewRef(Py_None);
  npgpy_busy_leave(&self->busy);
  return res;
}

/* ---------------------------------------------------------------- derivatives in reduced coordinates (DESIGN §17) */

/* The basis size of quantity `name` (its class's m), or -1 with npg.Error naming `method`. */
static long coords_size(ReducedObject *self, const char *name, const char *method) {
  if (!quantity(self, name)) return -1;
  int c = npg_model_class_of(self->model->m, name);
  NpgClassInfo ci;
  if (c < 0 || npg_model_class(self->model->m, c, &ci) != 0) {
    PyErr_Format(npgpy_Error, "%s: '%s' has no reduced coordinates", method, name);
    return -1;
  }
  return ci.m;
}

/* The inputs given by name to a derivative method: set and evaluated as red(**inputs) does. */
static int derivative_inputs(ReducedObject *self, PyObject *kw) {
  if (!kw || PyDict_GET_SIZE(kw) == 0) return 0;
  PyObject *empty = PyTuple_New(0);
  if (!empty) return -1;
  PyObject *res = reduced_call(self, empty, kw);
  Py_DECREF(empty);
  Py_XDECREF(res);
  return res ? 0 : -1;
}

/* {name: coordinates} of a jvp or vjp: names and float64 arrays of each one's m, into
 * names/arrs (n entries, references the caller drops). */
static int coords_dict(ReducedObject *self, PyObject *d, const char *method, const char *what, int max,
                       const char **names, PyArrayObject **arrs, int *n) {
  *n = 0;
  if (!PyDict_Check(d) || PyDict_GET_SIZE(d) == 0 || PyDict_GET_SIZE(d) > max) {
    PyErr_Format(PyExc_TypeError, "%s: %s must be a non-empty dict {name: coordinates} (at most %d)", method, what,
                 max);
    return -1;
  }
  PyObject *key, *value;
  Py_ssize_t pos = 0;
  while (PyDict_Next(d, &pos, &key, &value)) {
    const char *name = npgpy_name(key, method);
    if (!name) return -1;
    long m = coords_size(self, name, method);
    if (m < 0) return -1;
    char w[256];
    snprintf(w, sizeof w, "%s: %s['%s']", method, what, name);
    PyArrayObject *a = npgpy_values(value, w);
    if (!a) return -1;
    names[*n] = name, arrs[(*n)++] = a;
    if (PyArray_SIZE(a) != m) {
      PyErr_Format(npgpy_Error, "%s: %s['%s'] has %zd values; '%s' has %ld reduced coordinates", method, what, name,
                   (Py_ssize_t)PyArray_SIZE(a), name, m);
      return -1;
    }
  }
  return 0;
}

/* red.jvp(output, {input: direction}, **inputs) -> J(output, inputs) · directions, in coordinates */
static PyObject *reduced_jvp_method(ReducedObject *self, PyObject *args, PyObject *kw) {
  enum { MAXD = 64 };
  const char *out, *names[MAXD];
  PyObject *dirs;
  PyArrayObject *arrs[MAXD];
  int n = 0;
  PyObject *res = NULL;
  if (!PyArg_ParseTuple(args, "sO:jvp", &out, &dirs)) return NULL;
  long mo = coords_size(self, out, "jvp");
  if (mo < 0 || coords_dict(self, dirs, "jvp", "directions", MAXD, names, arrs, &n) || derivative_inputs(self, kw))
    goto done;
  npy_intp dm = (npy_intp)mo;
  if (!(res = PyArray_SimpleNew(1, &dm, NPY_DOUBLE))) goto done;
  const double *v[MAXD];
  for (int i = 0; i < n; i++) v[i] = PyArray_DATA(arrs[i]);
  npgpy_busy_enter(&self->busy);
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_reduced_jvp(self->r, -1, n, names, v, out, PyArray_DATA((PyArrayObject *)res));
  Py_END_ALLOW_THREADS
  if (rc) {
    rfail(self);
    Py_CLEAR(res);
  }
  npgpy_busy_leave(&self->busy);
done:
  for (int i = 0; i < n; i++) Py_DECREF(arrs[i]);
  return res;
}

/* red.vjp({output: cotangent}, input, **inputs) -> Σ J(output, input)ᵀ · cotangent, in coordinates */
static PyObject *reduced_vjp_method(ReducedObject *self, PyObject *args, PyObject *kw) {
  enum { MAXD = 64 };
  const char *in, *names[MAXD];
  PyObject *cots;
  PyArrayObject *arrs[MAXD];
  int n = 0;
  PyObject *res = NULL;
  if (!PyArg_ParseTuple(args, "Os:vjp", &cots, &in)) return NULL;
  long mi = coords_size(self, in, "vjp");
  if (mi < 0 || coords_dict(self, cots, "vjp", "cotangents", MAXD, names, arrs, &n) || derivative_inputs(self, kw))
    goto done;
  npy_intp dm = (npy_intp)mi;
  if (!(res = PyArray_SimpleNew(1, &dm, NPY_DOUBLE))) goto done;
  const double *v[MAXD];
  for (int i = 0; i < n; i++) v[i] = PyArray_DATA(arrs[i]);
  npgpy_busy_enter(&self->busy);
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_reduced_vjp(self->r, -1, n, names, v, in, PyArray_DATA((PyArrayObject *)res));
  Py_END_ALLOW_THREADS
  if (rc) {
    rfail(self);
    Py_CLEAR(res);
  }
  npgpy_busy_leave(&self->busy);
done:
  for (int i = 0; i < n; i++) Py_DECREF(arrs[i]);
  return res;
}

/* red.jacobian(output, input, **inputs) -> m_output x m_input */
static PyObject *reduced_jacobian_method(ReducedObject *self, PyObject *args, PyObject *kw) {
  const char *out, *in;
  if (!PyArg_ParseTuple(args, "ss:jacobian", &out, &in)) return NULL;
  long mo = coords_size(self, out, "jacobian"), mi = mo < 0 ? -1 : coords_size(self, in, "jacobian");
  if (mo < 0 || mi < 0 || derivative_inputs(self, kw)) return NULL;
  npy_intp shape[2] = {mo, mi};
  PyObject *res = PyArray_SimpleNew(2, shape, NPY_DOUBLE);
  if (!res) return NULL;
  npgpy_busy_enter(&self->busy);
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_reduced_jacobian(self->r, -1, out, in, PyArray_DATA((PyArrayObject *)res));
  Py_END_ALLOW_THREADS
  if (rc) {
    rfail(self);
    Py_CLEAR(res);
  }
  npgpy_busy_leave(&self->busy);
  return res;
}

/* An option of red.newton taken out of its keywords (the rest are inputs): a new reference, or NULL. */
static PyObject *pop_option(PyObject *kw, const char *name) {
  if (!kw) return NULL;
  PyObject *v = PyDict_GetItemString(kw, name);
  if (!v) return NULL;
  Py_INCREF(v);
  PyDict_DelItemString(kw, name);
  return v;
}

/* red.newton(residual, unknown, tol=1e-10, max_iter=20, verbose=False, sample=-1, **inputs)
 * -> (unknown's coordinates, [‖r̂‖ per iteration]) */
static PyObject *reduced_newton_method(ReducedObject *self, PyObject *args, PyObject *kw) {
  const char *res_name, *unk;
  if (!PyArg_ParseTuple(args, "ss:newton", &res_name, &unk)) return NULL;
  PyObject *inputs = kw ? PyDict_Copy(kw) : NULL, *out = NULL;
  if (kw && !inputs) return NULL;
  PyObject *tolo = pop_option(inputs, "tol"), *ito = pop_option(inputs, "max_iter");
  PyObject *verbo = pop_option(inputs, "verbose"), *sampo = pop_option(inputs, "sample");
  NpgNewton o = {.tol = 1e-10, .max_iter = 20};
  bool verbose = false;
  long sample = -1;
  if ((tolo && (o.tol = PyFloat_AsDouble(tolo), PyErr_Occurred())) ||
      (ito && (o.max_iter = (int)PyLong_AsLong(ito), PyErr_Occurred())) ||
      (verbo && npgpy_flag(verbo, "newton: verbose", &verbose)) ||
      (sampo && (sample = PyLong_AsLong(sampo), PyErr_Occurred())))
    goto done;
  long m = coords_size(self, unk, "newton");
  if (m < 0 || derivative_inputs(self, inputs)) goto done;
  double hist[1024];
  o.history = hist, o.history_cap = 1024, o.verbose = verbose ? stderr : NULL;
  npgpy_busy_enter(&self->busy);
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_reduced_newton(self->r, sample, res_name, unk, &o);
  Py_END_ALLOW_THREADS
  if (rc) rfail(self);
  else {
    size_t mu = 0;
    const double *x = npg_reduced_coords(self->r, unk, &mu);
    npy_intp dm = (npy_intp)mu;
    PyObject *a = PyArray_SimpleNew(1, &dm, NPY_DOUBLE), *h = PyList_New(0);
    if (a && mu) memcpy(PyArray_DATA((PyArrayObject *)a), x, sizeof(double) * mu);
    for (int i = 0; h && i <= o.iterations && i < o.history_cap; i++) {
      PyObject *f = PyFloat_FromDouble(hist[i]);
      if (!f || PyList_Append(h, f) < 0) Py_CLEAR(h);
      Py_XDECREF(f);
    }
    if (a && h) out = PyTuple_Pack(2, a, h);
    Py_XDECREF(a);
    Py_XDECREF(h);
  }
  npgpy_busy_leave(&self->busy);
done:
  Py_XDECREF(tolo);
  Py_XDECREF(ito);
  Py_XDECREF(verbo);
  Py_XDECREF(sampo);
  Py_XDECREF(inputs);
  return out;
}

static PyObject *get_model(ReducedObject *self, void *unused) { return Py_NewRef(self->model); }

static PyGetSetDef reduced_getset[] = {
  {"model", (getter)get_model, NULL, "the Model", NULL},
  {NULL},
};

/* red.simulate(steps, every=1, **inputs) -> {state: array}: the reduced step in coordinates (DESIGN §15);
 * the states projected once, lifted only at the kept steps. */
static PyObject *reduced_simulate(ReducedObject *self, PyObject *args, PyObject *kw) {
  NpgpyRoll roll;
  if (npgpy_roll_args(self->model->prog, args, kw, "Reduced.simulate", &roll) != 0) return NULL;
  npgpy_busy_enter(&self->busy);
  roll.r = self->r;
  long sample = self->sample;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npgpy_roll_run(&roll, sample);
  Py_END_ALLOW_THREADS
  self->sample += roll.steps;
  for (int k = 0; k < self->ninputs; k++)
    for (int i = 0; i < roll.n; i++)
      if (strcmp(roll.in[i].name, self->input[k]->name) == 0) self->input_set[k] = true;
  PyObject *out = rc ? rfail(self) : npgpy_roll_result(&roll);
  npgpy_busy_leave(&self->busy);
  npgpy_roll_free(&roll);
  return out;
}

static PyMethodDef reduced_methods[] = {
  {"simulate", (PyCFunction)(void (*)(void))reduced_simulate, METH_VARARGS | METH_KEYWORDS,
   "simulate(steps, every=1, **inputs) -> {state: array}: Full.simulate's contract, the reduced step in\n"
   "reduced coordinates: the states' initial values projected once, lifted only at the kept steps"},
  {"newton", (PyCFunction)(void (*)(void))reduced_newton_method, METH_VARARGS | METH_KEYWORDS,
   "newton(residual, unknown, tol=1e-10, max_iter=20, verbose=False, sample=-1, **inputs) -> (coords, residuals):\n"
   "Newton's method on the reduced residual for the unknown input's coordinates (npg_reduced_newton),\n"
   "from its current coordinates; residuals: ‖r̂‖ per iteration"},
  {"jacobian", (PyCFunction)(void (*)(void))reduced_jacobian_method, METH_VARARGS | METH_KEYWORDS,
   "jacobian(output, input, **inputs) -> m_output x m_input array: the derivative of output's reduced\n"
   "coordinates with respect to input's, at the inputs given (or as set)"},
  {"jvp", (PyCFunction)(void (*)(void))reduced_jvp_method, METH_VARARGS | METH_KEYWORDS,
   "jvp(output, {input: direction}, **inputs) -> array of output's m: Σ J(output, input) · direction"},
  {"vjp", (PyCFunction)(void (*)(void))reduced_vjp_method, METH_VARARGS | METH_KEYWORDS,
   "vjp({output: cotangent}, input, **inputs) -> array of input's m: Σ J(output, input)ᵀ · cotangent"},
  {"lift", (PyCFunction)(void (*)(void))reduced_lift, METH_VARARGS | METH_KEYWORDS,
   "lift(name, out=None, coords=None) -> array: B ŷ of any quantity, shaped like it; written into `out` when "
   "given; with coords (samples x m), every row lifted at once: samples x the quantity's shape"},
  {"coords", (PyCFunction)reduced_coords, METH_O, "coords(name) -> array: a copy of the reduced coordinates"},
  {"estimate", (PyCFunction)reduced_estimate, METH_O,
   "estimate(name) -> float: the online error estimate of `name` at the last evaluation, absolute, in the\n"
   "2-norm of its lifted values, or in the norm of its class's product K0 (basis u: product K0) (NaN: none;\n"
   "estimate_info says why; docs/estimates.md)"},
  {"estimate_info", (PyCFunction)reduced_estimate_info, METH_O,
   "estimate_info(name) -> dict(estimate, bound, outside, roundoff, why): the estimate and its flags"},
  {"outside", (PyCFunction)reduced_outside, METH_O,
   "outside(name) -> int or None: the first reduced coordinate of input `name` outside the training range"},
  {"set_coords", (PyCFunction)reduced_set_coords, METH_VARARGS,
   "set_coords(name, coords): set an input (or an extern after given_externs(True)) from its reduced coordinates"},
  {"op", (PyCFunction)reduced_op, METH_O,
   "op(name) -> array: the reduced output op B_rowᵀ M B_col at the last evaluation (npg.Error before any)"},
  {"given_externs", (PyCFunction)reduced_given_externs, METH_O,
   "given_externs(on): True: externs are given like inputs (red(v=array) projected, or\n"
   "red.set_coords('v', coords)) instead of the learned map's values; False: learned again"},
  {NULL},
};

PyTypeObject npgpy_ReducedType = {
  PyVarObject_HEAD_INIT(NULL, 0)
  .tp_name = "npg.Reduced",
  .tp_basicsize = sizeof(ReducedObject),
  .tp_dealloc = (destructor)reduced_dealloc,
  .tp_call = (ternaryfunc)reduced_call,
  .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
  .tp_doc = "A reduced evaluator (Model.reduced()). red(x=array, ...) -> {output: reduced coordinates}.\n\n"
            "Inputs are projected in place when float64 C-contiguous; an input not given keeps the value\n"
            "of the previous call; one never given raises. Outputs: copies of the coordinates (m values).",
  .tp_traverse = (traverseproc)reduced_traverse,
  .tp_methods = reduced_methods,
  .tp_getset = reduced_getset,
};

static PyGetSetDef model_getset[] = {
  {"basis_sizes", (getter)get_basis_sizes, NULL, "{class label: basis size}", NULL},
  {"classes", (getter)get_classes, NULL, "per class: label, n, m, members (name, kept, cap, captured)", NULL},
  {"samples", (getter)get_samples, NULL, "training samples", NULL},
  {"program", (getter)get_program, NULL, "the Program", NULL},
  {NULL},
};

static PyMethodDef model_methods[] = {
  {"report", (PyCFunction)model_report, METH_NOARGS, "report() -> str: the training table npgc train prints"},
  {"save", (PyCFunction)model_save, METH_O, "save(model_dir): write MODEL/"},
  {"basis", (PyCFunction)model_basis, METH_O, "basis(name) -> n x m read-only view of the basis of name's class"},
  {"dim", (PyCFunction)model_dim_method, METH_O, "dim(name) -> int: the size a dim had in training"},
  {"coefficients", (PyCFunction)model_coefficients, METH_O,
   "coefficients(name) -> samples x m read-only view C of a class kept as coefficients of its training\n"
   "values (its basis is X C; out of core, an extern's pair class): C.T @ trainer.dots(name, v) are v's\n"
   "reduced coordinates. npg.Error for a class that keeps its basis"},
  {"interpolated", (PyCFunction)model_interpolated, METH_O,
   "interpolated(stage) -> int or None: the entries stage is evaluated at when training reduced it by\n"
   "interpolation (DESIGN §12), None when by Galerkin projection; npg.Error for a name that is no stage"},
  {"reductions", (PyCFunction)model_reductions, METH_NOARGS,
   "reductions() -> str: per stage interpolated or chosen by measurement, how, both errors and the reason"},
  {"reduced", (PyCFunction)(void (*)(void))model_reduced, METH_VARARGS | METH_KEYWORDS,
   "reduced(exact_roots=False, sizes=None) -> Reduced: a reduced evaluator (one per thread); sizes={class: n}\n"
   "(classes as npgc check names them, m_u) evaluates at smaller basis sizes without retraining"},
  {"verify", (PyCFunction)(void (*)(void))model_verify, METH_VARARGS | METH_KEYWORDS,
   "verify(test, tol=None, full=None, progress=False) -> {quantity: {kind, m, output, l2, floor, own, l2_max,\n"
   "l2_max_sample, linf, linf_floor[, pass]}}: npgc verify on test samples (a dict name -> array whose\n"
   "first axis is the sample). full: an evaluator with the model's params (default: the trainer's).\n"
   "verify(test, steps=T, every=K, ...) -> {state: {trajectory, floor, final, max, max_at, error_per_save,\n"
   "floor_per_save[, ok]}}: npgc verify --steps (DESIGN §15): test holds each trajectory's initial states and\n"
   "inputs (a leading trajectory axis; an input per step: [trajectories, steps, ...])."},
  {NULL},
};

PyTypeObject npgpy_ModelType = {
  PyVarObject_HEAD_INIT(NULL, 0)
  .tp_name = "npg.Model",
  .tp_basicsize = sizeof(ModelObject),
  .tp_dealloc = (destructor)model_dealloc,
  .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
  .tp_doc = "A trained model (Trainer.finish, npg.load); read-only, shared by any number of Reduced.",
  .tp_traverse = (traverseproc)model_traverse,
  .tp_methods = model_methods,
  .tp_getset = model_getset,
};
