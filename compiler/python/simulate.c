/* simulate.c — rollouts from Python (DESIGN §15): Full.simulate, Reduced.simulate and
 * Trainer.add_trajectory share this. The keyword arrays of a call are read once, with the GIL:
 * a state's initial value (its declared shape), an input held (its shape) or given per step (a
 * leading steps axis, at least `steps` long). The rollout itself is plain C with the GIL released;
 * its callbacks only copy between these arrays and the evaluator. */
#include <math.h>
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

/* blowup=F, a keyword only: the blow-up factor of this call (npgc simulate --blowup), -1 when not
 * given. 0, or -1 with an exception. */
static int split_blowup(PyObject *inputs, const char *who, double *blowup) {
  *blowup = -1;
  PyObject *v = PyDict_GetItemString(inputs, "blowup");
  if (!v) return 0;
  if (PyBool_Check(v) || !(PyFloat_Check(v) || PyLong_Check(v)))
    return PyErr_Format(PyExc_TypeError, "%s: 'blowup' must be a number, not %s", who, Py_TYPE(v)->tp_name), -1;
  double f = PyFloat_AsDouble(v);
  if (f == -1 && PyErr_Occurred()) return -1;
  if (!(f == 0 || f > 1) || !isfinite(f))
    return npgpy_value_error("%s: blowup is %g (a blow-up factor > 1, or 0 to check finiteness only)", who, f), -1;
  *blowup = f;
  return PyDict_DelItemString(inputs, "blowup");
}

/* An implicit step's Newton options, keywords only (npgc simulate --newton-tol, --newton-max-iter,
 * --newton-verbose): into o when given. 0, or -1 with an exception. */
typedef struct RollOpts {
  double blowup, newton_tol;
  int newton_max_iter;
  bool newton_verbose;
} RollOpts;

static int split_newton(PyObject *inputs, const char *who, RollOpts *o) {
  PyObject *v = PyDict_GetItemString(inputs, "newton_tol");
  if (v) {
    if (PyBool_Check(v) || !(PyFloat_Check(v) || PyLong_Check(v)))
      return PyErr_Format(PyExc_TypeError, "%s: 'newton_tol' must be a number, not %s", who, Py_TYPE(v)->tp_name), -1;
    o->newton_tol = PyFloat_AsDouble(v);
    if (!(o->newton_tol > 0 && o->newton_tol < 1))
      return npgpy_value_error("%s: newton_tol is %g (a relative tolerance in (0, 1))", who, o->newton_tol), -1;
    if (PyDict_DelItemString(inputs, "newton_tol") < 0) return -1;
  }
  if ((v = PyDict_GetItemString(inputs, "newton_max_iter"))) {
    if (PyBool_Check(v) || !PyLong_Check(v))
      return PyErr_Format(PyExc_TypeError, "%s: 'newton_max_iter' must be an int, not %s", who, Py_TYPE(v)->tp_name),
             -1;
    long n = PyLong_AsLong(v);
    if (n < 1 || n > 100000)
      return npgpy_value_error("%s: newton_max_iter is %ld (1 to 100000 corrections)", who, n), -1;
    o->newton_max_iter = (int)n;
    if (PyDict_DelItemString(inputs, "newton_max_iter") < 0) return -1;
  }
  if ((v = PyDict_GetItemString(inputs, "newton_verbose"))) {
    if (!PyBool_Check(v))
      return PyErr_Format(PyExc_TypeError, "%s: 'newton_verbose' must be a bool, not %s", who, Py_TYPE(v)->tp_name),
             -1;
    o->newton_verbose = v == Py_True;
    if (PyDict_DelItemString(inputs, "newton_verbose") < 0) return -1;
  }
  return 0;
}

/* steps and every from the positional arguments or the keywords, and blowup; the other keywords, a
 * new dict, into *inputs. 0, or -1 with an exception. */
static int split_args(PyObject *args, PyObject *kw, const char *who, long *steps, long *every, RollOpts *o,
                      PyObject **inputs) {
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
  return split_blowup(*inputs, who, &o->blowup) || split_newton(*inputs, who, o) ? -1 : 0;
}

int npgpy_roll_args(const ProgramObject *prog, PyObject *args, PyObject *kw, const char *who, NpgpyRoll *r) {
  long steps, every;
  RollOpts o = {-1, 1e-10, 30, false};
  PyObject *inputs = NULL;
  int rc = split_args(args, kw, who, &steps, &every, &o, &inputs) ? -1 : npgpy_roll(prog, inputs, steps, every, who, r);
  r->blowup = o.blowup;
  r->newton_tol = o.newton_tol, r->newton_max_iter = o.newton_max_iter, r->newton_verbose = o.newton_verbose;
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
    const char *name = npgpy_utf8(key);
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
  /* The factor holds for this call only: an unset one is the library's default. */
  double blowup = r->blowup >= 0 ? r->blowup : 10;
  if (r->f && npg_full_set_blowup(r->f, blowup) != 0) return -1;
  if (r->r && npg_reduced_set_blowup(r->r, blowup) != 0) return -1;
  double tol = r->newton_tol > 0 ? r->newton_tol : 1e-10; /* 0: npgpy_roll without the options */
  int max_iter = r->newton_max_iter > 0 ? r->newton_max_iter : 30;
  FILE *verbose = r->newton_verbose ? stderr : NULL;
  if (r->f && npg_full_set_newton(r->f, tol, max_iter, verbose) != 0) return -1;
  if (r->r && npg_reduced_set_newton(r->r, tol, max_iter, verbose) != 0) return -1;
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

/* ---------------------------------------------------------------- model.verify(test, steps=T) */

typedef struct VerifyInput {
  const char *name;
  char what[160];
  PyArrayObject *a;         /* [trajectories, ...] or [trajectories, steps, ...] */
  bool per_step;
  int ndim;
  long shape[NPY_MAXDIMS];
  size_t each;
} VerifyInput;

typedef struct VerifyRoll {
  int n;
  VerifyInput *in;
  long trajectories, steps;
} VerifyRoll;

static void verify_roll_free(VerifyRoll *v) {
  for (int i = 0; i < v->n; i++) Py_XDECREF(v->in[i].a);
  PyMem_Free(v->in);
}

/* Trajectory k's values at step t (an NpgTrajectoryFn, without the GIL: it only reads the arrays). */
static int verify_set(void *user, NpgFull *f, long k, long t) {
  VerifyRoll *v = user;
  for (int i = 0; i < v->n; i++) {
    const VerifyInput *in = &v->in[i];
    if (t > 0 && !in->per_step) continue;
    size_t at = in->per_step ? (size_t)k * (size_t)PyArray_DIM(in->a, 1) + (size_t)t : (size_t)k;
    if (npg_full_set(f, in->name, in->ndim, in->shape, (const double *)PyArray_DATA(in->a) + at * in->each, in->what))
      return -1;
  }
  return 0;
}

static PyObject *array_of(const double *v, long n) {
  npy_intp dim = n;
  PyObject *a = PyArray_SimpleNew(1, &dim, NPY_DOUBLE);
  if (a) memcpy(PyArray_DATA((PyArrayObject *)a), v, sizeof(double) * (size_t)n);
  return a;
}

PyObject *npgpy_verify_rollout(const ProgramObject *prog, const NpgModel *m, FullObject *full, PyObject *test,
                               long steps, long every, bool progress, double tol) {
  const char *who = "verify";
  if (steps < 0) return npgpy_value_error("%s: steps is %ld (0 or more)", who, steps);
  if (every < 1) return npgpy_value_error("%s: every is %ld (1 or more)", who, every);
  VerifyRoll v = {0};
  PyObject *res = NULL;
  Py_ssize_t nkw = PyDict_Size(test);
  if (!(v.in = PyMem_Calloc((size_t)nkw + 1, sizeof *v.in))) return PyErr_NoMemory();
  v.trajectories = -1, v.steps = steps;
  PyObject *key, *value;
  Py_ssize_t pos = 0;
  while (PyDict_Next(test, &pos, &key, &value)) {
    const char *name = PyUnicode_Check(key) ? npgpy_utf8(key) : NULL;
    if (!name) {
      if (!PyErr_Occurred()) PyErr_Format(PyExc_TypeError, "%s: the keys of test are names (str)", who);
      goto done;
    }
    const NpgSymbol *s = NULL;
    for (int i = 0; i < prog->nsym && !s; i++)
      if (strcmp(prog->sym[i].name, name) == 0) s = &prog->sym[i];
    if (!s || s->kind != NPG_INPUT) {
      PyErr_Format(PyExc_TypeError, "%s: test['%s'] is %s: give the states' initial values and the inputs, a leading "
                   "trajectory axis", who, name, !s ? "not in the program" : "not an input");
      goto done;
    }
    VerifyInput *in = &v.in[v.n++];
    in->name = s->name;
    snprintf(in->what, sizeof in->what, "verify: test['%s']", name);
    if (!(in->a = npgpy_values(value, in->what))) goto done;
    int rank = s->ndims + s->nstatic, nd = PyArray_NDIM(in->a);
    if (nd != rank + 1 && (nd != rank + 2 || s->next)) {
      npgpy_value_error("%s: test['%s'] has %d axes: %s", who, name, nd,
                        s->next ? "a state's initial values are [trajectories, ...]"
                                : "an input is [trajectories, ...] (held) or [trajectories, steps, ...] (per step)");
      goto done;
    }
    in->per_step = nd == rank + 2;
    long shape[NPY_MAXDIMS];
    npgpy_long_shape(in->a, shape);
    in->ndim = rank;
    memcpy(in->shape, shape + (nd - rank), sizeof(long) * (size_t)rank);
    in->each = 1;
    for (int k = 0; k < rank; k++) in->each *= (size_t)in->shape[k];
    if (v.trajectories >= 0 && shape[0] != v.trajectories) {
      npgpy_value_error("%s: test['%s'] holds %ld trajectories, another array %ld", who, name, shape[0], v.trajectories);
      goto done;
    }
    v.trajectories = shape[0];
    if (in->per_step && shape[1] < steps) {
      npgpy_value_error("%s: test['%s'] is given for %ld steps, fewer than the %ld to run", who, name, shape[1], steps);
      goto done;
    }
  }
  if (v.trajectories < 1) {
    npgpy_value_error("%s: test holds no trajectory", who);
    goto done;
  }
  if (!npgpy_full_enter(full, "Model.verify")) goto done;
  NpgRolloutReport rep;
  int rc;
  Py_BEGIN_ALLOW_THREADS
  rc = npg_verify_rollout(m, full->f, v.trajectories, steps, every, verify_set, &v, progress, &rep);
  Py_END_ALLOW_THREADS
  npg_full_clear_error(full->f);
  npgpy_busy_leave(&full->busy);
  if (rc) {
    npgpy_full_raise(full, rep.error);
    goto done;
  }
  res = PyDict_New();
  for (int i = 0; res && i < rep.nstates; i++) {
    const NpgRolloutRow *row = &rep.rows[i];
    PyObject *err = array_of(row->err, rep.saves), *floor = array_of(row->floor, rep.saves);
    PyObject *d = err && floor ? Py_BuildValue("{s:d,s:d,s:d,s:d,s:(ll),s:O,s:O}", "trajectory", row->traj_err,
                                               "floor", row->traj_floor, "final", row->err_final, "max", row->err_max,
                                               "max_at", row->max_trajectory, row->max_step, "error_per_save", err,
                                               "floor_per_save", floor)
                               : NULL;
    if (d && tol >= 0 && PyDict_SetItemString(d, "ok", row->traj_err <= tol ? Py_True : Py_False) < 0) Py_CLEAR(d);
    if (!d || PyDict_SetItemString(res, row->state, d) < 0) Py_CLEAR(res);
    Py_XDECREF(d), Py_XDECREF(err), Py_XDECREF(floor);
  }
  npg_verify_rollout_free(&rep);
done:
  verify_roll_free(&v);
  return res;
}
