/* api.h — what the public API's files share inside the facade layer: the
 * refusal of bad arguments, the structs behind NpgFull and NpgModel, and the
 * param hashes a model records. */
#ifndef NPG_API_INTERNAL_H
#define NPG_API_INTERNAL_H

#include "full.h"
#include "npg.h"
#include "reduced.h"
#include "train.h"

/* ---------------------------------------------------------------- refusals (api_refuse.c)
 * The public API's argument checks (STYLE: CHOLMOD's RETURN_IF_NULL):
 * every npg_ entry point refuses a NULL pointer argument, or one out of its
 * documented range, before touching anything, with "FUNC: argument 'ARG'
 * is NULL" (or the reason given). The message goes to `err` when given (the
 * object's own error, so its getter returns it) and is kept as this
 * thread's last refusal, which the error getters (npg_full_error,
 * npg_trainer_error, npg_reduced_error, npg_model_error) return when the
 * object itself is the NULL argument. It replaces a message already there:
 * a call refused is the latest thing the caller should hear about. -1. */
int api_refuse(char *err, size_t errlen, const char *func, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
/* This thread's last refusal ("" when none). */
const char *api_refusal(void);
/* Return `ret` after refusing `arg` when it is NULL; `err`/`errlen` as for
 * api_refuse (NULL, 0 when the object itself is checked). */
#define API_REFUSE_NULL(arg, err, errlen, ret)                                    \
  do {                                                                            \
    if (!(arg)) {                                                                 \
      api_refuse((err), (errlen), __func__, "argument '%s' is NULL", #arg);       \
      return ret;                                                                 \
    }                                                                             \
  } while (0)

/* An extern's callback as npg.h gives it, called by the internal evaluator
 * through api_full.c's trampoline with the NpgFull the caller knows. */
typedef struct ExternClosure {
  NpgExternFn fn;
  void *user;
  const NpgFull *f;
} ExternClosure;

/* A rollout's bookkeeping (DESIGN §15), shared by the full and the reduced step: steps taken since
 * a state was last set, the states' energies then, and the blow-up factor (0: energy unchecked). */
typedef struct Rollout {
  long steps;
  double blowup;            /* set: 10 by default (api_rollout_blowup) */
  bool blowup_set;
  double *start;            /* per state (Program.states): ‖u‖² when the rollout started */
  double newton_tol;        /* an implicit step's Newton (`residual next u`): relative tolerance, */
  int newton_max_iter;      /* corrections at most and the verbose stream; set: defaults otherwise */
  FILE *newton_verbose;
  bool newton_set;
  /* an implicit step solved, before the state advances (u and u.next the step's pair, every
   * quantity at the solution): training from trajectories records here */
  int (*solved)(void *user, long step);
  void *solved_user;
} Rollout;
/* The blow-up factor in effect. */
double api_rollout_blowup(const Rollout *ro);

/* The public full evaluator: the internal one (backends/jit/full.h), which
 * every layer below evaluates with, wrapped as NpgModel wraps Model. */
struct NpgFull {
  Full *full;               /* never NULL */
  ExternClosure *externs;   /* per quantity (Program.quantities); NULL when full has no program */
  Rollout roll;             /* simulations (simulate.c) */
};

struct NpgReduced {
  const NpgModel *nm;
  Reduced *r;
  bool given_externs;
  bool exact_roots;
  double *z;                /* npg_reduced_op: one tensor's input product (2 zcap) */
  bool *given;              /* per quantity: set by the caller (an input never set is an error, not a zero) */
  bool evaluated;           /* an evaluation has succeeded: every quantity has coordinates to lift */
  long zcap;
  Rollout roll;             /* simulations (simulate.c) */
  NpgModel *own;            /* npg_reduced_new_sizes: the model at those sizes, freed with the evaluator */
  double *in_err;           /* per quantity: an input's own error ‖x − B x̂‖ as last set (0: by coordinates) */
  struct EstimateResult *est; /* the last evaluation's estimates (estimate.h), once asked for */
  bool est_fresh;           /* est is of the last evaluation */
  char error[1024];
};

struct NpgModel {
  Model *m;                 /* NULL when loading failed */
  char error[2048];
};

/* A caller's NpgSampleFn as a SampleSource's `set` (train.h), handed the
 * NpgFull the caller knows rather than the internal evaluator the trainer
 * holds (f->full). */
typedef struct SampleClosure {
  NpgSampleFn fn;
  void *user;
  NpgFull *f;
} SampleClosure;
int api_sample_set(void *closure, Full *full, long k);

/* A model object owning `m` (NULL: out of memory, `m` freed). */
NpgModel *api_model_wrap(Model *m);
/* Training's options (train.h): a view of `o`, which must outlive it (read as given, never
 * copied), with what the facade derives: dist from o->mpi, the bases streamed; for npg_trainer
 * and npg_tune (`valid`, `weights` and `shared_prefix`, which `o` does not hold, NULL). */
void api_train_options(const NpgTrainOptions *o, TrainOptions *to);
/* Greedy training's trainer: every input's basis defaults to energy 1 (TrainOptions.inputs_whole),
 * so that it holds every direction of the samples chosen (docs/estimates.md, "Greedy training"). */
void api_trainer_inputs_whole(NpgTrainer *t);
/* Greedy training's trainer: the snapshots of its samples taken from `cache` where it holds them,
 * and left in it (TrainOptions.cache; the caller owns the cache). */
void api_trainer_cache(NpgTrainer *t, SnapshotCache *cache);
/* The interpolation and streaming fields of `o` (DESIGN §12, issue 30) in their documented ranges:
 * 0, or -1 with a message naming the field, for `func`, in err. */
int api_refuse_reduce_options(const NpgTrainOptions *o, const char *func, char *err, size_t errlen);
/* The index of quantity `name` in Program.quantities, -1 if none. */
int api_quantity(const Program *prog, const char *name);
/* Shape of quantity `s` as bound in `f`: dims then static axes; ndim. */
int api_shape(const Full *f, const Sym *s, long *shape);

/* api_deriv.c: the slot of quantity `name` in `f`'s program (Program.slots): an input
 * (want_input), or any quantity (an output: a stage, or an input itself); -1 after refusing
 * for `func`, naming argument `arg`. */
int api_full_slot(NpgFull *f, const char *func, const char *arg, const char *name, bool want_input);
/* The sparse Jacobian d output / d input of the full evaluator, planned once per pattern:
 * its structural pattern (CSR, rows = count(output), cols = count(input)) and a greedy
 * coloring of its columns (ncolors forward products fill it). */
typedef struct ApiJacPlan {
  long rows, cols, ncolors;
  long *indptr, *indices, *color;
} ApiJacPlan;
/* After an evaluation: the plan, 0; or -1 with full_error(). */
int api_jac_plan(NpgFull *f, const char *output, const char *input, ApiJacPlan *p);
/* After an evaluation at sample `sample`: the Jacobian's values on the plan's pattern into
 * `data` (indptr[rows] entries); ko, ki the slots of output and input. 0, or -1 with full_error(). */
int api_jac_values(NpgFull *f, long sample, int ko, int ki, const ApiJacPlan *p, double *data);
void api_jac_plan_free(ApiJacPlan *p);

/* 0 when every reduced coordinate held by `r` is finite; else -1 with a
 * message naming the first quantity in evaluation order that is not. */
int api_reduced_not_finite(const Model *m, Reduced *r, long sample, char *err, size_t errlen);

/* words.c: `msg`, a training message in npgc's words (its flags: "--basis x: ..."), into `out` in
 * the words of interface `words` (NpgTrainOptions.words): npg.h's fields or Python's keywords. */
void api_words(const char *msg, int words, char *out, size_t len);

#endif
