/* npgpy.h — the CPython extension module `npg` (issue 27): shared types and
 * helpers of its files, one per concern — module.c (the module, errors,
 * arrays), program.c (npg.compile), full.c (full evaluation and externs),
 * trainer.c (npg.Trainer), model.c (models, reduced evaluation, verify).
 *
 * The module is a client of npg.h alone, like npgc. Ownership follows the
 * C API's: a full evaluator keeps pointers into its program, a trainer into
 * its full evaluator, a model into its program, a reduced evaluator into its
 * model; each Python object holds a reference to the object whose memory
 * its C object points into, and frees its C object before dropping that
 * reference, so any order of `del` is safe.
 *
 * Threads: the GIL is released around evaluation, training, projection,
 * lifting and verification. Each object that owns a C evaluator has a lock,
 * so two threads calling the same object take turns instead of racing
 * (the C API wants one evaluator per thread; a model is shared freely). */
#ifndef NPGPY_H
#define NPGPY_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdbool.h>

#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#define PY_ARRAY_UNIQUE_SYMBOL npgpy_ARRAY_API
#ifndef NPGPY_MODULE_C
#define NO_IMPORT_ARRAY
#endif
#include <numpy/arrayobject.h>

#include "npg.h"

/* ---------------------------------------------------------------- module.c */
extern PyObject *npgpy_Error;         /* npg.Error: every library error */
extern PyObject *npgpy_CompileError;  /* npg.CompileError(npg.Error): a diagnostic with its caret */
extern const char *npgpy_std_dir;     /* the stdlib installed with the package, or NULL */

/* A lock that is taken with the GIL released when another thread holds it.
 * `holder` is the thread that holds it (an extern callback runs in that
 * thread and may read values, but not evaluate again). */
typedef struct Busy {
  PyThread_type_lock lock;
  unsigned long holder;
} Busy;
int npgpy_busy_init(Busy *b);
void npgpy_busy_free(Busy *b);
void npgpy_busy_enter(Busy *b);
void npgpy_busy_leave(Busy *b);
bool npgpy_busy_mine(const Busy *b);

/* `obj` as a float64 C-contiguous aligned array: `obj` itself (a new
 * reference, no copy) when it already is one; another layout of float64 is
 * copied; an array of another dtype raises TypeError naming `what`
 * (Python lists and numbers are converted). NULL with an exception set. */
PyArrayObject *npgpy_values(PyObject *obj, const char *what);
/* The shape of `a` as the C API takes it (long[], at most NPY_MAXDIMS). */
void npgpy_long_shape(PyArrayObject *a, long *shape);
/* A flag option (`what`: "Trainer: center"): True, False, numpy.bool_, or the int 0 or 1; anything
 * else (a str such as 'off', None, 2) is a TypeError naming `what`. 0, or -1 with the exception. */
int npgpy_flag(PyObject *v, const char *what, bool *out);
/* A number option (`what`: "Trainer: energy"): an int or float (numpy's too) as a double; None, a
 * bool, a str is a TypeError naming `what`. 0, or -1 with the exception. */
int npgpy_real(PyObject *v, const char *what, double *out);
/* A library message as npg.Error (or `type`). Returns NULL. */
PyObject *npgpy_raise(PyObject *type, const char *msg);
/* The UTF-8 of str `str` (PyUnicode_AsUTF8), refused with ValueError naming it when it holds a NUL
 * character: the library would read "x\0junk" as "x" (a quiet wrong answer). NULL with the exception. */
const char *npgpy_utf8(PyObject *str);
/* The name a one-argument method was given, as UTF-8; NULL with a TypeError naming `method`
 * ("Model.interpolated") when it is not a str. */
const char *npgpy_name(PyObject *arg, const char *method);
/* ValueError with a printf message (PyErr_Format has no %g); NULL. */
PyObject *npgpy_value_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* The shape of symbol `s` with its dims sized by `dim(ctx, name)` (-1 if
 * unknown); returns its ndim, or -1. */
int npgpy_shape(const NpgSymbol *s, long (*dim)(const void *ctx, const char *name), const void *ctx, npy_intp *shape);
/* The program's symbols (malloc'd, *n of them), NULL with MemoryError. */
NpgSymbol *npgpy_symbols(NpgProgram *p, int *n);

/* ---------------------------------------------------------------- program.c */
typedef struct ProgramObject {
  PyObject_HEAD
  NpgProgram *p;
  PyObject *path;           /* str: the file, or the name given to source text */
  PyObject *report;         /* dict: `npgc check --json`, made on first use */
  int nsym;
  NpgSymbol *sym;
} ProgramObject;
extern PyTypeObject npgpy_ProgramType;
PyObject *npgpy_compile(PyObject *self, PyObject *args, PyObject *kw);

/* ---------------------------------------------------------------- full.c */
typedef struct ExternSlot ExternSlot;
typedef struct FullObject {
  PyObject_HEAD
  ProgramObject *prog;
  NpgFull *f;
  Busy busy;
  ExternSlot *externs;      /* linked list of callables registered as externs */
  PyObject *cb_error;       /* the exception an extern callable raised (an exception instance), or NULL */
  bool evaluated;           /* one evaluation happened since the last binding */
  int in_callback;          /* extern callables running (changed with the GIL held) */
  unsigned long cb_threads[64]; /* the Python threads that existed when the running callable started */
  int ncb_threads;          /* their number, -1 when more than 64 */
  long calls;               /* evaluations so far: the sample number of the next (messages, extern callables) */
} FullObject;
extern PyTypeObject npgpy_FullType;
PyObject *npgpy_full_new(ProgramObject *prog, PyObject *params, const char *backend);
/* Takes `self`'s lock for the call `what` ("Trainer.add"), waiting its turn. false with npg.Error
 * naming `what` when called from an extern callable of `self` (it is evaluating), or from a thread
 * started while one of its callables runs: that callable may be waiting for the thread it started,
 * and waiting for the lock would then never end (issue 38). A thread that existed before the
 * callable started waits its turn. Reads (Full.get) need no lock and stay allowed. */
bool npgpy_full_enter(FullObject *self, const char *what);
/* After a failed call of the library on `self`: npg.Error with `msg`, its
 * __cause__ the exception an extern callable raised, if any. */
PyObject *npgpy_full_raise(FullObject *self, const char *msg);

/* Samples given as {name: array whose first axis is the sample} (model.verify's test=, Trainer's
 * valid=), set one sample at a time into an evaluator by npgpy_samples_set (an NpgSampleFn: plain C,
 * it runs with the GIL released). The arrays are held until npgpy_samples_free. */
typedef struct NpgpySamples {
  int n;
  long count;               /* samples */
  const char *arg;          /* the argument's name in messages ("test") */
  const char **name;        /* into key[i], held */
  PyObject **key;
  PyArrayObject **a;
  char (*from)[128];
} NpgpySamples;
/* 0, or -1 with an exception naming `who` and `arg` (no sample axis, counts that differ, none, a
 * name that is one of `prog`'s params: setting it would rebind the evaluator). */
int npgpy_samples(const ProgramObject *prog, PyObject *dict, const char *who, const char *arg, NpgpySamples *out);
int npgpy_samples_set(void *user, NpgFull *f, long k);
void npgpy_samples_free(NpgpySamples *t);

/* ---------------------------------------------------------------- simulate.c */
/* A rollout's keyword arrays (DESIGN §15): states' initial values, inputs held or per step. */
typedef struct NpgpyRollInput {
  const char *name;         /* the program's (outlives the call) */
  char what[160];           /* "Full.simulate argument 'u'" */
  PyArrayObject *a;
  bool state, per_step;
  int ndim;                 /* of one value */
  long shape[NPY_MAXDIMS];
  size_t each;              /* entries of one value */
  double *out;              /* a state: saves x each, what the rollout kept */
} NpgpyRollInput;
typedef struct NpgpyRoll {
  int n;
  NpgpyRollInput *in;
  long steps, every, saves;
  double blowup;            /* blowup=F of the call, -1 when not given (the default, 10) */
  double newton_tol;        /* newton_tol=, newton_max_iter=, newton_verbose= of the call: an implicit */
  int newton_max_iter;      /* step's Newton (npg_full_set_newton); 1e-10, 30, False when not given */
  bool newton_verbose;
  NpgFull *f;               /* the full rollout's evaluator (and a trainer's: t) */
  NpgReduced *r;            /* or the reduced one's */
  NpgTrainer *t;            /* add_trajectory: the visited states added, nothing kept */
} NpgpyRoll;
/* Read `kw` for a rollout of `steps` steps keeping every `every`-th; 0, or -1 with an exception
 * naming `who`. With the GIL. */
int npgpy_roll(const ProgramObject *prog, PyObject *kw, long steps, long every, const char *who, NpgpyRoll *r);
/* The same from a method's (steps, every=1, **inputs). */
int npgpy_roll_args(const ProgramObject *prog, PyObject *args, PyObject *kw, const char *who, NpgpyRoll *r);
/* Set step 0's values and run (r->f, r->r or r->t set by the caller): 0, or -1 with the
 * library's error in the evaluator or trainer. Without the GIL. */
int npgpy_roll_run(NpgpyRoll *r, long sample);
/* {state: array [saves, ...]}; NULL with an exception. */
PyObject *npgpy_roll_result(const NpgpyRoll *r);
void npgpy_roll_free(NpgpyRoll *r);
/* model.verify(test, steps=T, every=K): npg_verify_rollout over test's trajectories ({name: array}
 * with a leading trajectory axis; inputs held or per step): {state: {trajectory, floor, final, max,
 * max_at, error_per_save, floor_per_save[, ok]}}. NULL with an exception. */
struct ModelObject;
PyObject *npgpy_verify_rollout(const ProgramObject *prog, const NpgModel *m, FullObject *full, PyObject *test,
                               long steps, long every, bool progress, double tol);

/* ---------------------------------------------------------------- trainer.c */
extern PyTypeObject npgpy_TrainerType;

/* ---------------------------------------------------------------- model.c */
typedef struct ModelObject {
  PyObject_HEAD
  ProgramObject *prog;
  NpgModel *m;
  FullObject *full;         /* the evaluator it was trained with (verify's default), or NULL */
} ModelObject;
extern PyTypeObject npgpy_ModelType;
extern PyTypeObject npgpy_ReducedType;
/* A model object owning `m` (stolen), NULL with an exception. */
PyObject *npgpy_model_wrap(ProgramObject *prog, NpgModel *m, FullObject *full);
PyObject *npgpy_load(PyObject *self, PyObject *args, PyObject *kw);

#endif
