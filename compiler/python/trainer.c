/* trainer.c — npg.Trainer: samples streamed from Python into the library's
 * trainer (npg_trainer_set / npg_trainer_add), then one call trains and
 * writes MODEL/ exactly as `npgc train` does (the same code: the same
 * samples give the same model, byte for byte). */
#include "npgpy.h"

#include <stdint.h>
#include <string.h>

typedef struct TrainerObject {
  PyObject_HEAD
  FullObject *full;         /* the trainer replays its samples through full->f */
  NpgTrainer *t;
  int nbasis;               /* per-name overrides (basis=), owned here: the trainer keeps the pointers */
  char **basis_name;
  int *basis_cap;
  double *basis_energy;
  int *basis_center;
  char **basis_product;     /* product=OP per override, or NULL */
  char *keep_bases;         /* keep_bases= (owned here for the same reason) */
  char **interp, **galerkin; /* interp=, galerkin=: stage names (NULL-ended, owned here) */
  PyObject *valid_dict;     /* valid=: a copy of the dict, which holds the names NpgpySamples points to */
  NpgpySamples valid;
  NpgTrainOptions opt;      /* the options it was made with (greedy() trains with them) */
} TrainerObject;

static PyObject *raise_words(TrainerObject *self, const char *prefix, const char *msg);

static void free_names(char **v) {
  for (int i = 0; v && v[i]; i++) PyMem_Free(v[i]);
  PyMem_Free(v);
}

static void free_reduce(TrainerObject *self) {
  free_names(self->interp), free_names(self->galerkin);
  self->interp = self->galerkin = NULL;
  npgpy_samples_free(&self->valid);
  Py_CLEAR(self->valid_dict);
}

/* interp=["w"], galerkin=[...]: stage names (DESIGN §12, as npgc train --reduce STAGE:interp|galerkin);
 * a str alone is one name. NULL-ended copies into *out, their count into *n. */
static int stage_names(PyObject *v, const char *what, char ***out, int *n) {
  *out = NULL, *n = 0;
  if (v == Py_None) return 0;
  PyObject *seq = PyUnicode_Check(v) ? PyTuple_Pack(1, v) : PySequence_Fast(v, "");
  if (!seq) {
    PyErr_Clear();
    return PyErr_Format(PyExc_TypeError, "Trainer: %s must be a stage name or a list of them, not %s", what,
                        Py_TYPE(v)->tp_name), -1;
  }
  Py_ssize_t k = PySequence_Fast_GET_SIZE(seq);
  if (!(*out = PyMem_Calloc((size_t)k + 1, sizeof **out))) return Py_DECREF(seq), PyErr_NoMemory(), -1;
  for (Py_ssize_t i = 0; i < k; i++) {
    PyObject *e = PySequence_Fast_GET_ITEM(seq, i);
    const char *name = PyUnicode_Check(e) ? npgpy_utf8(e) : NULL;
    if (!name) {
      if (!PyErr_Occurred())
        PyErr_Format(PyExc_TypeError, "Trainer: %s[%zd] must be a stage name (str), not %s", what, i, Py_TYPE(e)->tp_name);
      return Py_DECREF(seq), -1;
    }
    if (!((*out)[i] = PyMem_Malloc(strlen(name) + 1))) return Py_DECREF(seq), PyErr_NoMemory(), -1;
    strcpy((*out)[i], name);
    (*n)++;
  }
  Py_DECREF(seq);
  return 0;
}

/* The interpolated stages' options (DESIGN §12; NpgTrainOptions' fields of the same names). */
static int parse_reduce(TrainerObject *self, PyObject *full, PyObject *interp, PyObject *galerkin, PyObject *valid,
                        double oversample, double holdout, NpgTrainOptions *o) {
  free_reduce(self);
  if (stage_names(interp, "interp", &self->interp, &o->ninterp) != 0 ||
      stage_names(galerkin, "galerkin", &self->galerkin, &o->ngalerkin) != 0)
    return -1;
  o->interp_stage = (const char *const *)self->interp, o->galerkin_stage = (const char *const *)self->galerkin;
  if (oversample != 0 && !(oversample >= 1 && oversample <= 1000)) /* npgc train --interp-oversample's range */
    return npgpy_value_error("Trainer: interp_oversample %g: entries per basis vector, 1..1000 (0: the "
                        "default)", oversample), -1;
  o->interp_oversample = oversample;
  if (valid != Py_None && holdout > 0)
    return PyErr_SetString(PyExc_ValueError, "Trainer: valid= and valid_holdout= both given (one or the other)"), -1;
  o->valid_holdout = holdout;
  if (valid == Py_None) return 0;
  if (!PyDict_Check(valid))
    return PyErr_Format(PyExc_TypeError, "Trainer: valid={'x': array of samples x ...}, not %s",
                        Py_TYPE(valid)->tp_name), -1;
  if (!(self->valid_dict = PyDict_Copy(valid)) ||
      npgpy_samples(((FullObject *)full)->prog, self->valid_dict, "Trainer", "valid", &self->valid))
    return -1;
  o->valid_count = self->valid.count, o->valid_set = npgpy_samples_set, o->valid_user = &self->valid;
  return 0;
}

static void free_basis(TrainerObject *self) {
  for (int i = 0; i < self->nbasis; i++) free(self->basis_name[i]), free(self->basis_product[i]); /* the parser's */
  PyMem_Free(self->basis_name);
  PyMem_Free(self->basis_product);
  PyMem_Free(self->basis_cap);
  PyMem_Free(self->basis_energy);
  PyMem_Free(self->basis_center);
  self->nbasis = 0;
  self->basis_name = NULL, self->basis_cap = NULL, self->basis_energy = NULL, self->basis_center = NULL;
  self->basis_product = NULL;
}

/* A basis size, as `npgc train --cap`: a whole number in 1..1000000; an
 * error naming `what` otherwise (a huge int is named, not just "too large"). */
static int cap_value(PyObject *v, const char *what, int *out) {
  PyObject *iv = PyBool_Check(v) ? NULL : PyNumber_Index(v); /* an int, numpy's too */
  if (!iv) {
    PyErr_Clear();
    PyErr_Format(PyExc_TypeError, "Trainer: %s must be an int, not %s", what, Py_TYPE(v)->tp_name);
    return -1;
  }
  int overflow = 0;
  long c = PyLong_AsLongAndOverflow(iv, &overflow);
  Py_DECREF(iv);
  if (c == -1 && PyErr_Occurred()) return -1;
  if (overflow || c < 1 || c > 1000000) {
    PyErr_Format(PyExc_ValueError, "Trainer: %s %R: expected 1..1000000", what, v);
    return -1;
  }
  *out = (int)c;
  return 0;
}

/* basis=["NAME:cap=N,energy=E,center=on|off,product=OP", ...] (or one such string) as the C
 * options: each string read by npg_parse_basis_product, as `npgc train --basis` reads it (NAME a quantity, a
 * class m_x, a numerator y.num1 or '*'; the library checks the names). */
static int parse_basis(TrainerObject *self, PyObject *basis, NpgTrainOptions *o) {
  free_basis(self); /* a second __init__ after a failed one */
  if (basis == Py_None) return 0;
  PyObject *list = PyUnicode_Check(basis) ? PyTuple_Pack(1, basis)
                   : PyList_Check(basis) || PyTuple_Check(basis) ? PySequence_Tuple(basis) : NULL;
  if (!list) {
    if (!PyErr_Occurred())
      PyErr_Format(PyExc_TypeError, "Trainer: basis is a list of 'NAME:cap=N,energy=E,center=on|off' strings (as npgc "
                   "train --basis), not %s", Py_TYPE(basis)->tp_name);
    return -1;
  }
  Py_ssize_t n = PyTuple_GET_SIZE(list);
  self->basis_name = PyMem_Calloc((size_t)n + 1, sizeof *self->basis_name);
  self->basis_cap = PyMem_Calloc((size_t)n + 1, sizeof *self->basis_cap);
  self->basis_energy = PyMem_Calloc((size_t)n + 1, sizeof *self->basis_energy);
  self->basis_center = PyMem_Calloc((size_t)n + 1, sizeof *self->basis_center);
  self->basis_product = PyMem_Calloc((size_t)n + 1, sizeof *self->basis_product);
  int rc = 0;
  if (!self->basis_name || !self->basis_cap || !self->basis_energy || !self->basis_center || !self->basis_product)
    rc = -1, PyErr_NoMemory();
  for (Py_ssize_t i = 0; i < n && rc == 0; i++) {
    PyObject *item = PyTuple_GET_ITEM(list, i);
    const char *spec = PyUnicode_Check(item) ? npgpy_utf8(item) : NULL;
    char err[1024];
    int k = self->nbasis;
    if (!spec) {
      if (!PyErr_Occurred())
        PyErr_Format(PyExc_TypeError, "Trainer: basis[%zd] is a 'NAME:cap=N,energy=E,center=on|off' string, not %s", i,
                     Py_TYPE(item)->tp_name);
      rc = -1;
    } else if (npg_parse_basis_product(spec, &self->basis_name[k], &self->basis_cap[k], &self->basis_energy[k],
                                       &self->basis_center[k], &self->basis_product[k], err, sizeof err) != 0) {
      PyErr_Format(PyExc_ValueError, "Trainer: basis %s", err);
      rc = -1;
    } else {
      self->nbasis++;
    }
  }
  Py_DECREF(list);
  if (rc != 0) return -1;
  o->nbasis = self->nbasis;
  o->basis_name = (const char *const *)self->basis_name;
  o->basis_cap = self->basis_cap;
  o->basis_energy = self->basis_energy;
  o->basis_center = self->basis_center;
  o->basis_product = (const char *const *)self->basis_product;
  return 0;
}

static int trainer_init(TrainerObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"full", "energy", "cap", "center", "mem", "joint", "progress", "basis", "keep_bases",
                           "interp", "galerkin", "interp_oversample", "valid", "valid_holdout", NULL};
  PyObject *full, *center = Py_True, *joint = Py_False, *progress = Py_False, *mem = Py_None, *basis = Py_None;
  PyObject *interp = Py_None, *galerkin = Py_None, *valid = Py_None, *holdouto = Py_None;
  PyObject *energyo = NULL, *oversampleo = NULL;
  double oversample = 0;
  PyObject *keepo = Py_None;
  PyObject *capo = NULL;
  /* every default is the library's (npgc train's and npg.h's: one source, issue 38) */
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.words = NPG_WORDS_PYTHON; /* the library's messages name Trainer's keywords (its one table of words) */
  if (!PyArg_ParseTupleAndKeywords(args, kw, "O!|OOOOOOOO$OOOOO:Trainer", kwlist, &npgpy_FullType, &full, &energyo,
                                   &capo, &center, &mem, &joint, &progress, &basis, &keepo, &interp, &galerkin,
                                   &oversampleo, &valid, &holdouto))
    return -1;
  if ((energyo && npgpy_real(energyo, "Trainer: energy", &o.energy)) ||
      (oversampleo && npgpy_real(oversampleo, "Trainer: interp_oversample", &oversample)))
    return -1;
  double holdout = o.valid_holdout; /* None: the library's automatic choice */
  if (holdouto != Py_None) {
    if (npgpy_real(holdouto, "Trainer: valid_holdout (a fraction, or None)", &holdout)) return -1;
    if (!(holdout >= 0 && holdout <= 0.5))
      return npgpy_value_error("Trainer: valid_holdout %g: a fraction in (0, 0.5] of the samples added (0: none; None: "
                               "the automatic choice)", holdout), -1;
  }
  if (capo && cap_value(capo, "cap", &o.cap) != 0) return -1;
  if (keepo != Py_None && !PyUnicode_Check(keepo))
    return PyErr_Format(PyExc_TypeError, "Trainer: keep_bases must be a str ('h,m_r' or 'all'), not %s",
                        Py_TYPE(keepo)->tp_name), -1;
  const char *keep = keepo == Py_None ? NULL : npgpy_utf8(keepo);
  if (keepo != Py_None && !keep) return -1;
  if (keep && !keep[0])
    return PyErr_SetString(PyExc_ValueError, "Trainer: keep_bases is '': quantities or classes m_x separated by "
                           "commas, 'all', or None for none"), -1;
  if (self->t) {
    PyErr_SetString(PyExc_RuntimeError, "Trainer: already initialized");
    return -1;
  }
  if (!(o.energy > 0 && o.energy <= 1)) {
    npgpy_value_error("Trainer: energy %g: a fraction in (0, 1]", o.energy);
    return -1;
  }
  if (mem != Py_None) { /* bytes, as npgc train --mem: a whole number >= 1 */
    PyObject *iv = PyBool_Check(mem) ? NULL : PyNumber_Index(mem);
    if (!iv) {
      PyErr_Clear();
      return PyErr_Format(PyExc_TypeError, "Trainer: mem must be an int (bytes) or None (half the RAM), not %s",
                          Py_TYPE(mem)->tp_name), -1;
    }
    int overflow = 0;
    long long b = PyLong_AsLongLongAndOverflow(iv, &overflow);
    Py_DECREF(iv);
    if (b == -1 && PyErr_Occurred()) return -1;
    if (overflow || b < 1 || (unsigned long long)b > SIZE_MAX)
      return PyErr_Format(PyExc_ValueError, "Trainer: mem %R: bytes of memory for training, 1 to %zu (None: half the "
                          "RAM)", mem, (size_t)SIZE_MAX), -1;
    o.mem = (size_t)b;
  }
  bool c, j, p;
  if (npgpy_flag(center, "Trainer: center", &c) || npgpy_flag(joint, "Trainer: joint", &j) ||
      npgpy_flag(progress, "Trainer: progress", &p))
    return -1;
  o.uncentered = !c;
  o.joint = j;
  o.progress = p;
  if (parse_basis(self, basis, &o) != 0 || parse_reduce(self, full, interp, galerkin, valid, oversample, holdout, &o) != 0)
    return -1;
  if (keep) { /* streamed bases (issue 30): as npgc train --keep-bases */
    PyMem_Free(self->keep_bases);
    if (!(self->keep_bases = PyMem_Malloc(strlen(keep) + 1))) return PyErr_NoMemory(), -1;
    strcpy(self->keep_bases, keep);
    o.keep_bases = self->keep_bases;
  }
  Py_XSETREF(self->full, (FullObject *)Py_NewRef(full));
  self->opt = o;
  self->t = npg_trainer_new(self->full->f, &o);
  if (!self->t) {
    PyErr_NoMemory();
    return -1;
  }
  if (npg_trainer_error(self->t)[0]) return raise_words(self, "Trainer: ", npg_trainer_error(self->t)), -1;
  return 0;
}

static int trainer_traverse(TrainerObject *self, visitproc visit, void *arg) {
  Py_VISIT(self->full);
  Py_VISIT(self->valid_dict);
  return 0;
}

static void trainer_dealloc(TrainerObject *self) {
  PyObject_GC_UnTrack(self);
  npg_trainer_free(self->t); /* before the evaluator it points into, and the overrides */
  free_basis(self);
  free_reduce(self);
  PyMem_Free(self->keep_bases);
  Py_XDECREF(self->full);
  Py_TYPE(self)->tp_free((PyObject *)self);
}

static bool ready(TrainerObject *self) {
  if (!self->t) PyErr_SetString(PyExc_RuntimeError, "Trainer: not initialized");
  else if (npgpy_busy_mine(&self->full->busy))
    PyErr_SetString(npgpy_Error, "Trainer: called from an extern callable of its evaluator");
  else return true;
  return false;
}

/* `msg` (the library's, in Python's words: NPG_WORDS_PYTHON) as npg.Error (the cause: the extern
 * callable's exception), prefixed. */
static PyObject *raise_words(TrainerObject *self, const char *prefix, const char *msg) {
  size_t len = strlen(prefix) + strlen(msg) + 1;
  char *text = PyMem_Malloc(len);
  if (text) snprintf(text, len, "%s%s", prefix, msg);
  if (!text) return PyErr_NoMemory();
  if (self->full) npgpy_full_raise(self->full, text);
  else npgpy_raise(npgpy_Error, text);
  PyMem_Free(text);
  return NULL;
}

/* The library refused a call: its message (the extern callable's exception as the cause). The
 * refused sample is forgotten and the trainer takes samples again (npg_trainer_clear_error),
 * unless the failure left its records incomplete; its evaluator is made usable again for
 * evaluations and other trainers. */
static PyObject *fail(TrainerObject *self) {
  raise_words(self, "", npg_trainer_error(self->t));
  npg_trainer_clear_error(self->t);
  npg_full_clear_error(self->full->f);
  return NULL;
}

/* tr.add(**inputs): stream one sample (every input; externs given or computed by their callables). */
static PyObject *trainer_add(TrainerObject *self, PyObject *args, PyObject *kw) {
  if (PyTuple_GET_SIZE(args) > 0) {
    PyErr_SetString(PyExc_TypeError, "Trainer.add takes the sample's arrays by name: tr.add(x=array, ...)");
    return NULL;
  }
  if (!ready(self)) return NULL;
  if (!npgpy_full_enter(self->full, "Trainer.add")) return NULL;
  PyObject *key, *value, *res = NULL;
  Py_ssize_t pos = 0;
  while (kw && PyDict_Next(kw, &pos, &key, &value)) {
    const char *name = npgpy_utf8(key);
    if (!name) goto done;
    char what[256];
    snprintf(what, sizeof what, "Trainer.add: argument '%s'", name);
    PyArrayObject *a = npgpy_values(value, what);
    if (!a) goto done;
    long shape[NPY_MAXDIMS];
    npgpy_long_shape(a, shape);
    int rc = npg_trainer_set(self->t, name, PyArray_NDIM(a), shape, PyArray_DATA(a));
    Py_DECREF(a);
    if (rc) {
      fail(self);
      goto done;
    }
  }
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_trainer_add(self->t);
  Py_END_ALLOW_THREADS
  if (rc) fail(self);
  else res = Py_NewRef(Py_None);
done:
  npgpy_busy_leave(&self->full->busy);
  return res;
}

/* tr.weight(w): the weight of the next sample added (npg_trainer_weight). */
static PyObject *trainer_weight(TrainerObject *self, PyObject *arg) {
  double w;
  if (npgpy_real(arg, "Trainer.weight: the weight", &w)) return NULL;
  if (!ready(self)) return NULL;
  if (npg_trainer_weight(self->t, w)) return fail(self);
  Py_RETURN_NONE;
}

/* tr.add_full(): the inputs and externs the evaluator holds after full(...). */
static PyObject *trainer_add_full(TrainerObject *self, PyObject *unused) {
  if (!ready(self)) return NULL;
  if (!npgpy_full_enter(self->full, "Trainer.add_full")) return NULL;
  int rc;
  if (!self->full->evaluated) {
    npgpy_busy_leave(&self->full->busy);
    PyErr_SetString(npgpy_Error, "Trainer.add_full: the evaluator holds no evaluated sample (none was evaluated yet, "
                    "or its last call failed)");
    return NULL;
  }
  Py_BEGIN_ALLOW_THREADS
  rc = npg_trainer_add_full(self->t, self->full->f);
  Py_END_ALLOW_THREADS
  npgpy_busy_leave(&self->full->busy);
  if (rc) return fail(self);
  Py_RETURN_NONE;
}

/* tr.finish(model_dir=None) -> Model */
static PyObject *trainer_finish(TrainerObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"model_dir", NULL};
  PyObject *dir = Py_None, *b = NULL;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "|O:finish", kwlist, &dir)) return NULL;
  if (!ready(self)) return NULL;
  if (dir != Py_None && !PyUnicode_FSConverter(dir, &b)) return NULL;
  if (!npgpy_full_enter(self->full, "Trainer.finish")) return Py_XDECREF(b), NULL;
  NpgModel *m;
  const char *path = b ? PyBytes_AS_STRING(b) : NULL;
  Py_BEGIN_ALLOW_THREADS
  m = npg_trainer_finish(self->t, path);
  Py_END_ALLOW_THREADS
  npgpy_busy_leave(&self->full->busy);
  Py_XDECREF(b);
  if (!m) return fail(self);
  return npgpy_model_wrap(self->full->prog, m, self->full);
}

/* tr.greedy(start, pool, tol, budget=0, model_dir=None, absolute=False) -> Model: greedy training
 * with this trainer's options (npg_train_greedy; docs/estimates.md): `start` and `pool` dicts of arrays with
 * a leading sample axis; the samples added to the trainer itself are not used. The result's
 * record: model.greedy (chosen, worst, converged); the dict adds the run's full evaluations. */
static PyObject *trainer_greedy(TrainerObject *self, PyObject *args, PyObject *kw) {
  static char *kwlist[] = {"start", "pool", "tol", "budget", "model_dir", "absolute", NULL};
  PyObject *start, *pool, *dir = Py_None, *b = NULL;
  double tol;
  long budget = 0;
  int absolute = 0;
  if (!PyArg_ParseTupleAndKeywords(args, kw, "O!O!d|lOp:greedy", kwlist, &PyDict_Type, &start, &PyDict_Type, &pool,
                                   &tol, &budget, &dir, &absolute))
    return NULL;
  if (!ready(self)) return NULL;
  if (dir != Py_None && !PyUnicode_FSConverter(dir, &b)) return NULL;
  NpgpySamples s = {0}, p = {0};
  PyObject *res = NULL;
  if (npgpy_samples(self->full->prog, start, "Trainer.greedy", "start", &s) ||
      npgpy_samples(self->full->prog, pool, "Trainer.greedy", "pool", &p))
    goto done;
  NpgGreedyOptions g = {tol, budget, self->opt.progress, absolute != 0};
  NpgGreedyResult r;
  NpgModel *m;
  const char *path = b ? PyBytes_AS_STRING(b) : NULL;
  npgpy_busy_enter(&self->full->busy);
  Py_BEGIN_ALLOW_THREADS
  m = npg_train_greedy(self->full->f, &self->opt, s.count, npgpy_samples_set, &s, p.count, npgpy_samples_set, &p, &g,
                       path, &r);
  Py_END_ALLOW_THREADS
  self->full->evaluated = false; /* the evaluator holds the last candidate's inputs, not an evaluated sample */
  npgpy_busy_leave(&self->full->busy);
  if (!m) {
    PyErr_SetString(npgpy_Error, r.error);
    free(r.chosen);
    goto done;
  }
  PyObject *chosen = PyList_New(r.nchosen);
  for (long j = 0; chosen && j < r.nchosen; j++) PyList_SET_ITEM(chosen, j, PyLong_FromLong(r.chosen[j]));
  free(r.chosen);
  PyObject *model = chosen ? npgpy_model_wrap(self->full->prog, m, self->full) : NULL;
  if (model)
    res = Py_BuildValue("(N{s:N,s:d,s:O,s:l})", model, "chosen", chosen, "worst", r.worst, "converged",
                        r.converged ? Py_True : Py_False, "evaluations", r.evaluations);
  else Py_XDECREF(chosen);
done:
  npgpy_samples_free(&s);
  npgpy_samples_free(&p);
  Py_XDECREF(b);
  return res;
}

/* tr.dots(name, values) -> array of samples: the inner products of one value of an input or
 * extern with every training sample's value, from the trainer's own records (npg_trainer_dots);
 * with model.coefficients(name) C, the coordinates Cᵀ(Xᵀv) of a class kept as coefficients. */
static PyObject *trainer_dots(TrainerObject *self, PyObject *args) {
  const char *name;
  PyObject *obj;
  if (!PyArg_ParseTuple(args, "sO:dots", &name, &obj)) return NULL;
  if (!ready(self)) return NULL;
  char what[256];
  snprintf(what, sizeof what, "Trainer.dots: the values of '%s'", name);
  PyArrayObject *a = npgpy_values(obj, what);
  if (!a) return NULL;
  if (!npgpy_full_enter(self->full, "Trainer.dots")) return Py_DECREF(a), NULL;
  /* sized under the lock: a tr.add on another thread adds a sample until it is taken */
  npy_intp S = npg_trainer_samples(self->t);
  PyObject *out = PyArray_SimpleNew(1, &S, NPY_DOUBLE);
  if (!out) return npgpy_busy_leave(&self->full->busy), Py_DECREF(a), NULL;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_trainer_dots(self->t, name, (size_t)PyArray_SIZE(a), PyArray_DATA(a),
                        PyArray_DATA((PyArrayObject *)out));
  Py_END_ALLOW_THREADS
  npgpy_busy_leave(&self->full->busy);
  Py_DECREF(a);
  if (rc) return Py_DECREF(out), fail(self);
  return out;
}

static PyObject *get_samples(TrainerObject *self, void *unused) {
  return PyLong_FromLong(self->t ? npg_trainer_samples(self->t) : 0);
}

static PyGetSetDef trainer_getset[] = {
  {"samples", (getter)get_samples, NULL, "samples added so far", NULL},
  {NULL},
};

/* tr.add_trajectory(steps, every=1, **inputs): the trainer's evaluator runs the rollout (Full.simulate's
 * arguments) and every `every`-th visited state is added (DESIGN §15). */
static PyObject *trainer_add_trajectory(TrainerObject *self, PyObject *args, PyObject *kw) {
  if (!ready(self)) return NULL;
  NpgpyRoll roll;
  if (npgpy_roll_args(self->full->prog, args, kw, "Trainer.add_trajectory", &roll) != 0) return NULL;
  if (!npgpy_full_enter(self->full, "Trainer.add_trajectory")) return npgpy_roll_free(&roll), NULL;
  roll.f = self->full->f, roll.t = self->t;
  long sample = self->full->calls;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npgpy_roll_run(&roll, sample);
  Py_END_ALLOW_THREADS
  self->full->calls += roll.steps;
  PyObject *res = NULL;
  if (rc && npg_trainer_error(self->t)[0]) fail(self);
  else if (rc) {
    npgpy_full_raise(self->full, npg_full_error(self->full->f));
    npg_full_clear_error(self->full->f);
  } else res = Py_NewRef(Py_None);
  npgpy_busy_leave(&self->full->busy);
  npgpy_roll_free(&roll);
  return res;
}

static PyMethodDef trainer_methods[] = {
  {"greedy", (PyCFunction)(void (*)(void))trainer_greedy, METH_VARARGS | METH_KEYWORDS,
   "greedy(start, pool, tol, budget=0, model_dir=None, absolute=False) -> (Model, {chosen, worst, converged, evaluations}):\n"
   "greedy training with this trainer's options (npgc train --greedy): start and pool are dicts of arrays with a\n"
   "leading sample axis; full evaluations only at start and at the chosen candidates of pool, once each; tol bounds the\n"
   "estimated relative error, with absolute=True the absolute one (npgc train --absolute); the inputs' bases\n"
   "keep every direction (energy 1 unless basis= or the program sets it)"},
  {"add_trajectory", (PyCFunction)(void (*)(void))trainer_add_trajectory, METH_VARARGS | METH_KEYWORDS,
   "add_trajectory(steps, every=1, **inputs): run the full step `steps` times from the states' initial values\n"
   "(Full.simulate's arguments) and add every `every`-th visited state; nothing is kept but the samples.\n"
   "A state stepped implicitly (`residual next u = ...`): every `every`-th solved step, the pair (u, u.next)"},
  {"add", (PyCFunction)(void (*)(void))trainer_add, METH_VARARGS | METH_KEYWORDS,
   "add(**arrays): stream one sample: every input, and externs (else computed by their callables)"},
  {"weight", (PyCFunction)trainer_weight, METH_O,
   "weight(w): the weight of the next sample added (positive, 1 if not given): the PCA counts it w times"},
  {"add_full", (PyCFunction)trainer_add_full, METH_NOARGS,
   "add_full(): the sample the evaluator evaluated last (full(x=...) then tr.add_full())"},
  {"finish", (PyCFunction)(void (*)(void))trainer_finish, METH_VARARGS | METH_KEYWORDS,
   "finish(model_dir=None) -> Model: train on the samples added; with model_dir, write MODEL/ as npgc train"},
  {"dots", (PyCFunction)trainer_dots, METH_VARARGS,
   "dots(name, values) -> array (samples): the inner products of one value of an input or extern with\n"
   "every training sample's (from the trainer's records; also after finish). With model.coefficients(name)\n"
   "C, C.T @ tr.dots(name, v) are the reduced coordinates of v for reduced.set_coords (a class kept as\n"
   "coefficients of its training values: an extern's pair class out of core)"},
  {NULL},
};

PyTypeObject npgpy_TrainerType = {
  PyVarObject_HEAD_INIT(NULL, 0)
  .tp_name = "npg.Trainer",
  .tp_basicsize = sizeof(TrainerObject),
  .tp_dealloc = (destructor)trainer_dealloc,
  .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
  .tp_doc = "Trainer(full, energy=0.999, cap=60, center=True, mem=None, joint=False, progress=False, basis=None,\n"
            "        keep_bases=None, *, interp=None, galerkin=None, interp_oversample=0, valid=None, valid_holdout=None)\n\n"
            "Streams samples into the library's trainer; finish() trains as npgc train does, and every default is\n"
            "the library's (npg_train_options_default: the same as npgc train's and npg.h's, so the same samples\n"
            "give the same model byte for byte). mem: bytes for the samples in memory (beyond: a scratch file;\n"
            "None: half the RAM). center=False: the paper's uncentered truncation; center, joint and progress take\n"
            "True or False (or 0/1), never a str. basis=['NAME:cap=N,energy=E,center=on|off', ...]: per quantity,\n"
            "class (m_x), numerator (y.num1) or '*', as npgc train --basis. keep_bases='h,m_r' or 'all': keep\n"
            "those bases in the model too, as npgc train --keep-bases (by default the bases the reduced\n"
            "model never reads, of pair quantities, are used in training and not kept).\n"
            "Interpolated stages (DESIGN §12), keywords only: interp=['w'] / galerkin=['w'] force a stage's\n"
            "reduction (npgc train --reduce w:interp|galerkin); interp_oversample=X entries per basis vector\n"
            "(default 32); valid={'x': array of samples x ...} validation samples (the trainer's params), or\n"
            "valid_holdout=F a fraction of the samples added held out (0: none; None: the automatic choice of\n"
            "npgc train, every 10th of 30 or more samples when a stage's reduction is open to a choice): every\n"
            "other eligible stage is reduced both ways and the lower output error kept (model.interpolated(stage)\n"
            "reads the choice).\n"
            "Every option, names included, is checked here, when the trainer is made. A refused call (a sample\n"
            "with a NaN, an extern without a callable left out, a bad weight) raises and leaves the trainer\n"
            "usable: the refused sample is forgotten, the samples added before are kept.",
  .tp_traverse = (traverseproc)trainer_traverse,
  .tp_init = (initproc)trainer_init,
  .tp_new = PyType_GenericNew,
  .tp_methods = trainer_methods,
  .tp_getset = trainer_getset,
};
