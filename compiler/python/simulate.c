/* simulate.c — rollouts from Python (DESIGN §15): Full.simulate, Reduced.simulate and
 * Trainer.add_trajectory share this. The keyword arrays of a call are read once, with the GIL:
 * a state's initial value (its declared shape), an input held (its shape) or given per step (a
 * leading steps axis, at least `steps` long). The rollout itself is plain C with the GIL released;
 * its callbacks only copy between these arrays and the evaluator. */
#include <string.h>

#include "npgpy.h"

void npgpy_roll_free(NpgpyRoll *r) {
  for (int i = 0; i < r->n; i++) {
    Py_XDECREF(r->in[i].a);
    PyMem_Free(r->in[i].out);
  }
  PyMem_Free(r->in);
  memset(r, 0, sizeof *r);
}

/* steps and every from the positional arguments or the keywords; the other keywords, a new dict,
 * into *inputs. 0, or -1 with an exception. */
static int split_args(PyObject *args, PyObject *kw, const char *who, long *steps, long *every, PyObject **inputs) {
  *steps = -1, *every = 1;
  *inputs = kw ? PyDict_Copy(kw) : PyDict_New();
  if (!*inputs) return -1;
  Py_ssize_t n = PyTuple_GET_SIZE(args);
  if (n > 2) return PyErr_Format(PyExc_TypeError, "%s(steps, every=1, **inputs): %zd positional arguments", who, n), -1;
  const char *names[2] = {"steps", "every"};
  long *dst[2] = {steps, every};
  for (int i = 0; i < 2; i++) {
    PyObject *v = i < n ? PyTuple_GET_ITEM(args, i) : PyDict_GetItemString(*inputs, names[i]);
    if (i < n && PyDict_GetItemString(*inputs, names[i]))
      return PyErr_Format(PyExc_TypeError, "%s: '%s' given twice", who, names[i]), -1;
    if (!v) continue;
    if (!PyLong_Check(v) || PyBool_Check(v))
      return PyErr_Format(PyExc_TypeError, "%s: '%s' must be an int, not %s", who, names[i], Py_TYPE(v)->tp_name), -1;
    *dst[i] = PyLong_AsLong(v);
    if (*dst[i] == -1 && PyErr_Occurred()) return -1;
    if (i >= n && PyDict_DelItemString(*inputs, names[i]) < 0) return -1;
  }
  if (*steps < 0 && !PyErr_Occurred())
    return PyErr_Format(PyExc_TypeError, "%s: give steps, the steps to run (0 or more)", who), -1;
  return 0;
}

int npgpy_roll_args(const ProgramObject *prog, PyObject *args, PyObject *kw, const char *who, NpgpyRoll *r) {
  long steps, every;
  PyObject *inputs = NULL;
  int rc = split_args(args, kw, who, &steps, &every, &inputs) ? -1 : npgpy_roll(prog, inputs, steps, every, who, r);
  Py_XDECREF(inputs);
  return rc;
}

int npgpy_roll(const ProgramObject *prog, PyObject *kw, long steps, long every, const char *who, NpgpyRoll *r) {
  memset(r, 0, sizeof *r);
  if (steps < 0) return npgpy_value_error("%s: steps is %ld (0 or more)", who, steps), -1;
  if (every < 1) return npgpy_value_error("%s: every is %ld (1 or more: keep every K-th step)", who, every), -1;
  r->steps = steps, r->every = every, r->saves = steps / every + 1;
  int states = 0;
  for (int i = 0; i < prog->nsym; i++) states += prog->sym[i].next != NULL;
  if (states == 0) {
    PyErr_Format(npgpy_Error, "%s: the program has no state: declare one with 'state u : ...' and its next value "
                 "with 'next u = ...'", who);
    return -1;
  }
  Py_ssize_t nkw = kw ? PyDict_Size(kw) : 0;
  if (!(r->in = PyMem_Calloc((size_t)nkw + 1, sizeof *r->in))) return PyErr_NoMemory(), -1;
  PyObject *key, *value;
  Py_ssize_t pos = 0;
  while (kw && PyDict_Next(kw, &pos, &key, &value)) {
    const char *name = PyUnicode_AsUTF8(key);
    if (!name) goto fail;
    const NpgSymbol *s = NULL;
    for (int i = 0; i < prog->nsym && !s; i++)
      if (strcmp(prog->sym[i].name, name) == 0) s = &prog->sym[i];
    if (!s || s->kind != NPG_INPUT) {
      PyErr_Format(PyExc_TypeError, "%s: '%s' is %s: give the states' initial values and the inputs", who, name,
                   !s ? "not in the program" : s->kind == NPG_PARAM ? "a param (bound with the evaluator)"
                   : s->kind == NPG_EXTERN ? "an extern (rollouts of programs with externs are not supported)"
                                           : "not an input");
      goto fail;
    }
    NpgpyRollInput *in = &r->in[r->n++];
    snprintf(in->what, sizeof in->what, "%s argument '%s'", who, name);
    in->name = s->name;
    in->state = s->next != NULL;
    if (!(in->a = npgpy_values(value, in->what))) goto fail;
    int rank = s->ndims + s->nstatic, nd = PyArray_NDIM(in->a);
    if (nd != rank && (nd != rank + 1 || in->state)) {
      npgpy_value_error("%s: %s '%s' is %d-dimensional: give %s (%d axes)%s; the array has %d", who,
                        in->state ? "state" : "input", name, rank, in->state ? "its initial value" : "its value",
                        rank, in->state ? "" : ", or one per step with a leading steps axis", nd);
      goto fail;
    }
    in->per_step = nd == rank + 1;
    npgpy_long_shape(in->a, in->shape);
    in->ndim = in->per_step ? nd - 1 : nd;
    if (in->per_step) memmove(in->shape, in->shape + 1, sizeof(long) * (size_t)in->ndim);
    in->each = 1;
    for (int k = 0; k < in->ndim; k++) in->each *= (size_t)in->shape[k];
    if (in->per_step && PyArray_DIM(in->a, 0) < steps) {
      npgpy_value_error("%s: input '%s' is given for %ld steps, fewer than the %ld to run", who, name,
                        (long)PyArray_DIM(in->a, 0), steps);
      goto fail;
    }
    if (in->state && !(in->out = PyMem_Malloc(sizeof(double) * (in->each * (size_t)r->saves + 1)))) {
      PyErr_NoMemory();
      goto fail;
    }
  }
  for (int i = 0; i < prog->nsym; i++) {
    bool given = false;
    for (int k = 0; k < r->n; k++) given |= strcmp(r->in[k].name, prog->sym[i].name) == 0;
    if (prog->sym[i].next && !given) {
      PyErr_Format(PyExc_TypeError, "%s: state '%s' has no initial value: give %s=array", who, prog->sym[i].name,
                   prog->sym[i].name);
      goto fail;
    }
  }
  return 0;
fail:
  npgpy_roll_free(r);
  return -1;
}

static const double *value_at(const NpgpyRollInput *in, long step) {
  return (const double *)PyArray_DATA(in->a) + (in->per_step ? (size_t)step * in->each : 0);
}

/* The values of `step` into the evaluator: every input (all) or those given per step. */
static int set_step(NpgpyRoll *r, long step, bool all) {
  for (int i = 0; i < r->n; i++) {
    const NpgpyRollInput *in = &r->in[i];
    if (!all && !in->per_step) continue;
    int rc = r->f ? npg_full_set(r->f, in->name, in->ndim, in->shape, value_at(in, step), in->what)
                  : npg_reduced_set(r->r, in->name, in->each, value_at(in, step));
    if (rc) return -1;
  }
  return 0;
}

static int before_step(void *user, long step) { return step ? set_step(user, step, false) : 0; }

static int at_save(void *user, long step) {
  NpgpyRoll *r = user;
  for (int i = 0; i < r->n; i++) {
    NpgpyRollInput *in = &r->in[i];
    if (!in->state) continue;
    double *dst = in->out + (size_t)(step / r->every) * in->each;
    if (r->f) {
      size_t n = 0;
      const double *v = npg_full_get(r->f, in->name, &n);
      if (!v || n != in->each) return -1;
      memcpy(dst, v, sizeof(double) * n);
    } else if (npg_reduced_lift(r->r, in->name, dst, in->each) != 0) {
      return -1;
    }
  }
  return 0;
}

int npgpy_roll_run(NpgpyRoll *r, long sample) {
  NpgRollout ro = {.steps = r->steps, .every = r->every, .before_step = before_step, .user = r};
  ro.at_save = r->t ? NULL : at_save;
  if (set_step(r, 0, true) != 0) return -1;
  if (r->t) return npg_trainer_add_trajectory(r->t, r->f, sample, &ro);
  return r->f ? npg_full_simulate(r->f, sample, &ro) : npg_reduced_simulate(r->r, sample, &ro);
}

PyObject *npgpy_roll_result(const NpgpyRoll *r) {
  PyObject *out = PyDict_New();
  for (int i = 0; out && i < r->n; i++) {
    const NpgpyRollInput *in = &r->in[i];
    if (!in->state) continue;
    npy_intp shape[NPY_MAXDIMS + 1];
    shape[0] = (npy_intp)r->saves;
    for (int k = 0; k < in->ndim; k++) shape[k + 1] = (npy_intp)in->shape[k];
    PyObject *a = PyArray_SimpleNew(in->ndim + 1, shape, NPY_DOUBLE);
    if (a) memcpy(PyArray_DATA((PyArrayObject *)a), in->out, sizeof(double) * in->each * (size_t)r->saves);
    if (!a || PyDict_SetItemString(out, in->name, a) < 0) Py_CLEAR(out);
    Py_XDECREF(a);
  }
  return out;
}
