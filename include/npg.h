/* npg.h — the public C API of libnpg.
 *
 * Compiling a program:
 *
 *     NpgOptions opt = {0};                 // defaults
 *     NpgProgram *p = npg_compile("prog.npg", &opt);
 *     if (!npg_ok(p)) fputs(npg_error(p), stderr);   // "file:line:col: error: ..."
 *     ...
 *     npg_free(p);                          // frees everything the program owns
 *
 * Ownership: an NpgProgram owns all memory it hands out (strings, reports);
 * pointers stay valid until npg_free(). npg_compile never returns NULL and
 * never exits the process: errors are reported through npg_error().
 *
 * Arguments: every function refuses a NULL pointer argument (other than the
 * optional ones documented, e.g. `count`, `cpu`, the free functions' NULL)
 * and an argument out of its documented range, before doing anything, with
 * "npg_FUNC: argument 'ARG' is NULL" (or the reason): in the object's error
 * (npg_full_error, npg_trainer_error, npg_reduced_error, npg_model_error,
 * a report's `error`, or `err`), and as this thread's last refusal, which
 * those error getters return when given NULL (a constructor's NULL result
 * when out of memory reads "npg_FUNC: out of memory" there).
 */
#ifndef NPG_H
#define NPG_H

#include <stdbool.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NPG_API __attribute__((visibility("default")))

typedef struct NpgProgram NpgProgram;

typedef struct NpgOptions {
  const char *std_dir;  /* directory holding npg/<module>.npg; NULL: the installed one
                           (<prefix>/share/npg/stdlib), else the source tree's */
  const char *dump;     /* letters of IR dumps to print to dump_out: p (parse),
                           s (checked), l (lowered), b (basis classes) */
  FILE *dump_out;       /* NULL: stderr */
  const char *source;   /* if non-NULL, compile this text instead of reading the file;
                           the path is still used as the name in diagnostics */
} NpgOptions;

/* Compile a .npg program: parse, check, lower, basis classes. */
NPG_API NpgProgram *npg_compile(const char *path, const NpgOptions *opt);
/* True when compilation succeeded. */
NPG_API bool npg_ok(const NpgProgram *p);
/* The diagnostic of a failed compilation ("file:line:col: error: msg\n<line>\n<caret>\n"),
 * or "" on success. */
NPG_API const char *npg_error(const NpgProgram *p);
/* The `npgc check` report, human readable (json=false) or JSON. */
NPG_API void npg_report(const NpgProgram *p, FILE *out, bool json);
NPG_API void npg_free(NpgProgram *p);
/* Whether `a` and `b` are the same program: compiled (both successfully) from the same source
 * text and modules, as a model's program hash reads them; the same file compiled twice is. */
NPG_API bool npg_same_program(const NpgProgram *a, const NpgProgram *b);

/* Write the generated C of the full evaluator (every stage, the bind-time
 * gather checker) and the tensor builders to `out`. Returns 0, or -1 with
 * the reason in npg_error(). The C compiles standalone (cc -c). */
NPG_API int npg_emit_full(NpgProgram *p, FILE *out);
/* The generated C of the full evaluator's derivatives (DESIGN §17): "<stem>_npg_full_jvp"
 * and "<stem>_npg_full_vjp" (NpgDerivFn in the ABI header), run after the evaluator's entry
 * point on the same context. Compiles standalone and links beside npg_emit_full's unit.
 * 0, or -1 with the reason in npg_error() (a program with an extern has no derivative). */
NPG_API int npg_emit_derivatives(NpgProgram *p, FILE *out);

/* ---------------------------------------------------------------- what a program declares */
typedef enum NpgKind {
  NPG_PARAM,   /* data fixed at training time */
  NPG_INPUT,   /* varies per evaluation, has a basis */
  NPG_EXTERN,  /* a black-box stage: given as data or by a callback */
  NPG_STAGE,   /* a named definition */
  NPG_OP,      /* a linear operator (`op`) */
} NpgKind;
typedef struct NpgSymbol {
  const char *name;
  NpgKind kind;
  bool output;                 /* declared `output` */
  int ndims;                   /* dim axes, named by dims[] */
  const char *dims[8];         /* an op: its row dims, then its column dims */
  int nrow;                    /* an op: how many of dims[] are rows */
  int nstatic;                 /* static axes after the dims */
  int shape[4];
  const char *next;            /* a state (`state u`): the stage of its next value ("u.next"); else NULL */
  const char *state_of;        /* that stage: the state it advances; else NULL */
} NpgSymbol;
/* Params, then quantities in evaluation order (inputs, stages and externs),
 * then operators. npg_symbol returns 0, or -1 when i is out of range. */
NPG_API int npg_nsymbols(const NpgProgram *p);
NPG_API int npg_symbol(const NpgProgram *p, int i, NpgSymbol *out);
/* Progress bar on stderr ("what [####    ] done/total"), when `on`. */
NPG_API void npg_progress(bool on, const char *what, long done, long total);

/* ---------------------------------------------------------------- full evaluation
 *
 *     NpgFull *f = npg_full_new(p, NPG_AUTO);      // generate + compile (cc if installed, else libtcc)
 *     npg_full_bind_params(f, "DATA");             // DATA/<param>.npy; dims from shapes
 *     npg_full_set(f, "g", 2, shape, values, "g"); // an input (or extern) of one sample
 *     if (npg_full_eval(f, 0)) fputs(npg_full_error(f), stderr);
 *     const double *b = npg_full_get(f, "b", &n); // every stage value is kept
 *     npg_full_free(f);
 *
 * The evaluator keeps pointers into `p`: free it before npg_free(p). Values
 * handed back belong to the evaluator and change with the next evaluation.
 * Every function returns 0, or -1 with a message in npg_full_error() naming
 * the file or the stage and sample; after an error the evaluator refuses
 * further work until npg_full_clear_error() (never, when npg_full_new itself
 * failed: no compiler, a bad TMPDIR; its error stays). */
typedef struct NpgFull NpgFull;
/* Which compiler builds the full evaluator's C (npgc's --jit, Python's backend=). */
typedef enum NpgBackend {
  NPG_TCC,  /* libtcc, in memory: milliseconds to compile, slower code */
  NPG_CC,   /* the system compiler ($CC, else cc on PATH) at -O3 -march=native, loaded
               with dlopen; the shared object kept in a content-addressed cache
               ($NPG_CACHE_DIR, else $XDG_CACHE_HOME/npg or ~/.cache/npg; at most
               $NPG_CACHE_MAX bytes, default 256M, 0 for no cache) */
  NPG_AUTO, /* the default: $NPG_JIT (auto, cc or tcc) when set, else cc when
               installed, else libtcc */
} NpgBackend;
/* "auto", "cc" or "tcc" into `out`: 0, or -1 for anything else. */
NPG_API int npg_backend_parse(const char *name, NpgBackend *out);
/* "auto", "cc", "tcc" (NULL for a value outside the enum). */
NPG_API const char *npg_backend_name(NpgBackend b);

NPG_API NpgFull *npg_full_new(NpgProgram *p, NpgBackend backend);
/* How the evaluator was compiled: the backend that built it (NPG_TCC or
 * NPG_CC, NPG_AUTO resolved), the seconds compiling and loading took (for a
 * cache hit: hashing the generated C and loading the entry), and `cache`: 1 loaded from the cache, 0 compiled and stored, 2 a
 * damaged or foreign entry found and rebuilt, -1 not cached (libtcc, cache off).
 * -1 when `f` failed to compile (its error says why). */
typedef struct NpgJitInfo {
  NpgBackend backend;
  double compile_seconds;
  int cache;
} NpgJitInfo;
NPG_API int npg_full_jit_info(const NpgFull *f, NpgJitInfo *out);
NPG_API const char *npg_full_error(const NpgFull *f);
NPG_API void npg_full_clear_error(NpgFull *f);
/* Forget every dim, param and value (to bind data of other sizes). */
NPG_API void npg_full_unbind(NpgFull *f);
/* Every param from DIR/<name>.npy (float64 for real, int32/int64 for int). */
NPG_API int npg_full_bind_params(NpgFull *f, const char *data_dir);
/* A param from memory (ints as whole doubles); `from` names it in messages. */
NPG_API int npg_full_set_param(NpgFull *f, const char *name, int ndim, const long *shape, const double *values,
                               const char *from);
/* An input or extern (or a param) for the next evaluation: dims then static axes. */
NPG_API int npg_full_set(NpgFull *f, const char *name, int ndim, const long *shape, const double *values,
                         const char *from);
/* Evaluate every stage; gathers are checked once per binding first. */
NPG_API int npg_full_eval(NpgFull *f, long sample);
/* The value of a quantity (input, extern or stage), C order; NULL if unknown. */
NPG_API const double *npg_full_get(const NpgFull *f, const char *name, size_t *count);
/* The bound size of a dim, -1 if unbound or unknown. */
NPG_API long npg_full_dim(const NpgFull *f, const char *name);
NPG_API void npg_full_free(NpgFull *f);

/* After an evaluation: 0 when every value is finite, else -1 with
 * npg_full_error() naming the first quantity in evaluation order that
 * holds a NaN or an infinity (where it arises, not where it spreads to),
 * the sample and the entry's index ("sample 3: stage 'p' is not finite:
 * p[2, 5] is NaN"). */
NPG_API int npg_full_check_finite(NpgFull *f, long sample);

/* Derivatives of the full evaluator (DESIGN §17), exact, from generated C (compiled on
 * first use with the evaluator's backend): each evaluates sample `sample` at the inputs as
 * bound (as npg_full_eval), then differentiates there. Derivatives are taken with respect
 * to inputs; an output may be any stage (or an input). Every array is C order, its count
 * the quantity's as bound.
 *   npg_full_jvp: out (output's count) = Σ_i J(output, inputs[i]) · directions[i];
 *   npg_full_vjp: out (input's count)  = Σ_i J(outputs[i], input)^T · cotangents[i];
 *   npg_full_jacobian: out = J(output, input), count(output) × count(input), row-major
 *   (by forward products per input entry, or reverse products per output entry,
 *   whichever are fewer).
 * Polynomial stages differentiate entry by entry; inverses reuse one LU for the
 * tangent's (or the transposed) solves; roots use the eigendecomposition (Daleckii-
 * Krein). A program with an extern has no derivative (refused, the message naming it);
 * declared operators are assembled dense here, sparse ones too. 0, or -1 with
 * npg_full_error() naming the argument or the stage and sample. */
NPG_API int npg_full_jvp(NpgFull *f, long sample, int nin, const char *const *inputs, const double *const *directions,
                         const char *output, double *out);
NPG_API int npg_full_vjp(NpgFull *f, long sample, int nout, const char *const *outputs,
                         const double *const *cotangents, const char *input, double *out);
NPG_API int npg_full_jacobian(NpgFull *f, long sample, const char *output, const char *input, double *out);

/* Simulations (DESIGN §15): a program with `state u` and `next u = ...` is one time step.
 * npg_full_step evaluates it `steps` times (sample `sample`, for messages and callbacks), every
 * state taking its next value after each (no copy: after a call, npg_full_get("u") is the state
 * after the steps, the other stages hold the last step's values). Set the states (npg_full_set)
 * and the other inputs first; inputs not set again are held. Setting a state starts a new rollout.
 * A step whose next value is not finite, or whose state's energy ‖u‖² exceeds the blow-up factor
 * (default 10; 0 checks finiteness only) times its value at the rollout's start, stops the call
 * with an error naming the step and the state. 0, or -1 with npg_full_error(). */
NPG_API int npg_full_step(NpgFull *f, long steps, long sample);
/* Steps taken since a state was last set. */
NPG_API long npg_full_steps(const NpgFull *f);
NPG_API int npg_full_set_blowup(NpgFull *f, double factor);
/* A program whose state is stepped implicitly (`residual next u[i:N] = ...`, the next value
 * u.next the zero of the residual u.residual) solves each step by Newton (npg_full_newton;
 * npg_reduced_newton in coordinates), from the state as first guess, until
 * ‖r‖₂ <= tol · max(‖r₀‖, 1e-4 ‖u‖) (r₀ the residual at the guess, u the state), at most
 * max_iter corrections (defaults 1e-10 and 30); verbose (or NULL) gets ‖r‖ per iteration. A
 * failure stops the step with Newton's message after "step N: ". 0, or -1 naming the argument. */
NPG_API int npg_full_set_newton(NpgFull *f, double tol, int max_iter, FILE *verbose);
/* A rollout of `steps` steps saving every `every`-th (steps 0, every, 2 every, …, so
 * steps/every + 1 saves): before_step (optional) runs before each step t = 0 … steps-1 to set
 * the inputs given per step; at_save runs at each saved step t, after the step that reached it
 * and before_step(t) (t = 0: before any step), to read the states. A callback's non-zero return stops the rollout (-1,
 * the error names the step). The same for the reduced step: npg_reduced_simulate. */
typedef struct NpgRollout {
  long steps, every;
  int (*before_step)(void *user, long step);
  int (*at_save)(void *user, long step);
  void *user;
} NpgRollout;
NPG_API int npg_full_simulate(NpgFull *f, long sample, const NpgRollout *ro);

/* Externs given by a C function instead of data: at every npg_full_eval
 * the evaluator calls fn(user, f, sample, out, count) to fill the extern's
 * `count` values (C order), unless npg_full_set gave it values since the
 * last evaluation (a trainer replaying cached values). The function reads
 * what it needs with npg_full_get: the extern's `of` quantities must be
 * inputs (refused otherwise: their values would not exist yet). It returns
 * 0, or non-zero to fail the evaluation ("extern 'v' failed at sample 3").
 * fn NULL removes the callback. 0, or -1 with npg_full_error(). */
typedef int (*NpgExternFn)(void *user, const NpgFull *f, long sample, double *out, size_t count);
NPG_API int npg_full_set_extern_fn(NpgFull *f, const char *name, NpgExternFn fn, void *user);

/* A sparse matrix in compressed sparse row form: row r holds the entries
 * indices[indptr[r] .. indptr[r+1]) (columns increasing) with values data[...]
 * (the layout scipy.sparse.csr_matrix reads). The arrays are malloc'd and
 * owned by the struct: free them with npg_csr_free. */
typedef struct NpgCsr {
  long rows, cols, nnz;
  long *indptr;    /* rows + 1 */
  long *indices;   /* nnz */
  double *data;    /* nnz */
} NpgCsr;
NPG_API void npg_csr_free(NpgCsr *c);
/* npg_full_jacobian as CSR (`out` overwritten; free it with npg_csr_free), on its
 * structural pattern at the params as bound (which input entries each output entry reads
 * through the stages; a declared operator's power makes its term dense): one forward
 * product per color of a greedy coloring of the columns (columns that share no row share a
 * color), so a Jacobian whose rows read few entries costs a few products, not one per
 * column. Entries on the pattern that are 0 at this point are kept. */
NPG_API int npg_full_jacobian_csr(NpgFull *f, long sample, const char *output, const char *input, NpgCsr *out);

/* The `output op` named `name` at the values of the last evaluation, as CSR
 * (rows: the product of its row dims, columns of its column dims; every
 * structurally non-zero entry, exact zeros included). `out` is overwritten
 * (free a previous operator first). 0, or -1 with npg_full_error()
 * (unknown name, not an output op, no evaluation yet); `out` then holds
 * nothing. */
NPG_API int npg_full_op(NpgFull *f, const char *name, NpgCsr *out);

/* ---------------------------------------------------------------- samples on disk
 *
 * A data directory holds DIR/<name>.npy for every param (no sample axis)
 * and every input and extern (a leading sample axis), float64 (ints for int
 * params). NpgSamples reads the inputs and externs once, checks them (type,
 * one sample count across files) and hands out one sample at a time. */
typedef struct NpgSamples NpgSamples;
/* Open DIR's inputs and, when `externs`, its externs (else FALLBACK/<name>.npy
 * when FALLBACK is non-NULL). NULL with a message naming the file in `err`. */
NPG_API NpgSamples *npg_samples_open(NpgProgram *p, const char *dir, const char *fallback, bool externs, char *err,
                                     size_t errlen);
NPG_API long npg_samples_count(const NpgSamples *s);
/* Sample k of `name` (count entries), NULL when the set does not hold it. */
NPG_API const double *npg_samples_get(const NpgSamples *s, const char *name, long k, size_t *count);
/* Set every input and extern of sample k in `f` (an NpgSampleFn); k out of
 * [0, count) is an error in `f`. */
NPG_API int npg_samples_set(void *samples, NpgFull *f, long k);
/* Bind the dims of `f` from the shapes of the set's files (after their sample
 * axis), setting no value: with no samples too, where npg_samples_set has no
 * sample to set, so the outputs of no samples get their shapes
 * (npg_full_dim). 0, or -1 with the disagreement (a dim 6 in DATA/rho.npy but
 * 5 in IN/x.npy) as `f`'s error. */
NPG_API int npg_samples_bind_dims(const NpgSamples *s, NpgFull *f);
NPG_API void npg_samples_free(NpgSamples *s);

/* Write a float64 array as a .npy file (to a temporary name, renamed when
 * complete). 0, or -1 with a message naming the file in `err`. */
NPG_API int npg_npy_write(const char *path, int ndim, const long *shape, const double *data, char *err, size_t errlen);
/* The same for int64 arrays (CSR index arrays). */
NPG_API int npg_npy_write_i64(const char *path, int ndim, const long *shape, const long *data, char *err,
                              size_t errlen);

/* Read a .npy file (the files npg_npy_write and numpy.save write: '<f8',
 * '<i4' or '<i8', C order, at most NPG_NPY_MAX_DIMS axes) as float64.
 * Returns the values, `*count` entries in C order (malloc'd, the caller
 * free()s them; non-NULL even for an empty array), the axes in `*ndim` and
 * `shape[0..*ndim)` (a 0-d array: ndim 0, one value). Integers are converted
 * exactly: one beyond ±2^53 is refused rather than rounded. NULL on any
 * failure (missing file, another dtype, Fortran order, a truncated or longer
 * file), with "<path>: <problem>" in `err`; the outputs are then untouched. */
#define NPG_NPY_MAX_DIMS 8
NPG_API double *npg_npy_read(const char *path, int *ndim, long shape[NPG_NPY_MAX_DIMS], size_t *count, char *err,
                             size_t errlen);

/* The library's way to fail, for a program's own functions too: printf(`fmt`, ...)
 * into `err` (when `err` and `errlen` are given, cut at `errlen`), and -1 to return
 * — the convention of every function here that takes `err`, `errlen`. */
NPG_API int npg_error_set(char *err, size_t errlen, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

/* Sets sample k's inputs and externs in `f` (npg_samples_set is one). */
typedef int (*NpgSampleFn)(void *user, NpgFull *f, long k);

/* ---------------------------------------------------------------- training
 *
 *     NpgTrainOptions o;
 *     npg_train_options_default(&o);
 *     NpgTrainer *t = npg_trainer_new(f, &o);   // f: params bound (externs may be callbacks)
 *     for (each sample of the simulation) {
 *       npg_full_set(f, "g", ...); npg_full_eval(f, k);   // the simulation's own step
 *       npg_trainer_add_full(t, f);              // or npg_trainer_set(...) + npg_trainer_add(t)
 *     }
 *     NpgModel *m = npg_trainer_finish(t, "MODEL");  // trains, writes MODEL/ as `npgc train` does
 *     npg_trainer_free(t);
 *
 * The trainer keeps every sample's inputs and extern values (not its
 * stages): in memory up to `mem` bytes, beyond that in an unnamed scratch
 * file that disappears with the trainer. Finishing replays them through the
 * full evaluator exactly as `npgc train` does (the same code), so the same
 * samples give the same model. Extern values are taken once per sample (a
 * callback is not called again when the samples are replayed, however many
 * passes training makes) and cached compactly: one bit per entry, plus
 * (index, value) for each entry that is not exactly 0 or 1, when that is
 * smaller than the doubles (visibility: fractional only where a face is
 * partly hidden); bit for bit what the callback gave. */
/* Options out of range are refused by npg_trainer_new naming the field
 * (cap < 1, energy outside (0, 1] or NaN, mem 0, overrides out of range),
 * never replaced by defaults: start from npg_train_options_default. */
typedef struct NpgTrainOptions {
  int cap;                  /* basis cap per member (60) */
  double energy;            /* PCA energy fraction per member (0.999) */
  bool joint;               /* merge a class's members by one joint PCA (default: concatenate) */
  size_t mem;               /* memory for snapshots and cached samples, bytes (half the RAM) */
  bool progress;            /* progress bars on stderr */
  bool uncentered;          /* the paper's uncentered truncation (default: centered — each member's
                               basis keeps its snapshots' mean and truncates the centered energy) */
  int nbasis;               /* overrides: name (a quantity, a class m_x, a numerator y.num1, or '*'),
                               cap (-1: default), energy (-1: default), center (1 on, 0 off, -1 default;
                               basis_center may be NULL) */
  const char *const *basis_name;
  const int *basis_cap;
  const double *basis_energy;
  const int *basis_center;
  const char *const *basis_product; /* per override: an op's name (product=OP), or NULL; the whole
                                       array may be NULL */
  bool mpi;                 /* train over the ranks of MPI_COMM_WORLD (a job started by mpirun; MPI
                               initialized here when the program has not). Every rank runs the same
                               code and adds the same samples; rank r keeps and evaluates the samples
                               k ≡ r (mod ranks) only (an extern callback runs for those and sample 0,
                               which binds the dims on every rank) and
                               pre-multiplies every ranks-th row; every rank gets the same model (equal
                               to one process's to rounding), rank 0 alone writes `model_dir`. In
                               memory the snapshots must fit in `mem`; when the bases exceed it,
                               the ranks share the out-of-core row passes, every sample's record is
                               then sent to every rank (callbacks are not called again) and the
                               basis files are created next to `model_dir` (README). When a rank fails it ends the whole job
                               (MPI_Abort, "npg: rank K of N failed: …" on stderr), since the others
                               wait for it; no model is written. A build without MPI refuses it
                               (npg_mpi_available). */
  /* -- interpolated stages (DESIGN §12; issue 26) -- */
  int ninterp;              /* the stages interp_stage[0..ninterp) are reduced by interpolation, not
                               Galerkin: each must be eligible (every operator diagonal: npgc check
                               says which); the array must outlive the trainer */
  const char *const *interp_stage;
  double interp_oversample; /* entries selected per basis vector, >= 1 (0: the default, 32) */
  int ngalerkin;            /* the stages galerkin_stage[0..ngalerkin) are reduced by Galerkin */
  const char *const *galerkin_stage;
  long valid_count;         /* validation samples (the training params), set by valid_set(valid_user, f, k):
                               every eligible stage neither list names is reduced both ways and the lower
                               output error on them kept (ties: the cheaper); 0: Galerkin. The choice is
                               in npg_model_report() */
  NpgSampleFn valid_set;
  void *valid_user;
  double valid_holdout;     /* instead of validation samples, hold out this fraction (0, 0.5] of the
                               samples added — every round(1/F)-th — from training to validate on
                               (not over MPI ranks); 0: none; negative (npg_train_options_default's -1):
                               automatic — when some eligible stage is forced neither way, the program
                               has no extern (its learned model is fitted after the choice) and at least 30
                               samples are added, every 10th is held out to choose on, then the model is
                               trained again on every sample with the choice fixed (twice the training);
                               otherwise none, and the model is the same as with 0 */
  const char *keep_bases;   /* streamed bases (issue 30): the bases the reduced model never reads (classes
                               of pair quantities that are no input, output or extern: F² rows for F
                               faces) are used in training and not kept in the model; this comma-separated
                               list of quantities or classes (m_x) keeps them too, "all" keeps every
                               basis (the old layout); NULL: none kept. An unknown name fails training;
                               the string must outlive the trainer */
  long rollout_steps;       /* npg_tune of a program with state (DESIGN §15): each candidate judged by the
                               reduced rollout of this many steps from every validation sample against the
                               full one (the states' trajectory error: ‖R − F‖ / ‖F‖ over the saved steps,
                               mean over the samples, the worst state), not one step; inputs are held.
                               0 (the default): one evaluation, the outputs' error */
  long rollout_every;       /* its states compared every this many steps (0: every step) */
  int words;                /* how messages (npg_trainer_error, npg_tune's report) name the options:
                               NPG_WORDS_C (the default) this struct's fields ("NpgTrainOptions.basis_name
                               nosuch: no quantity ..."), NPG_WORDS_NPGC npgc's flags ("--basis nosuch"),
                               NPG_WORDS_PYTHON npg.Trainer's keywords ("basis nosuch") */
} NpgTrainOptions;
enum { NPG_WORDS_C, NPG_WORDS_NPGC, NPG_WORDS_PYTHON };
NPG_API void npg_train_options_default(NpgTrainOptions *o);
/* Whether this build of libnpg has MPI (NpgTrainOptions.mpi). */
NPG_API bool npg_mpi_available(void);
/* This process's MPI rank and the number of ranks once a trainer with
 * `mpi` exists; 0 and 1 otherwise. */
NPG_API int npg_mpi_rank(void);
NPG_API int npg_mpi_size(void);

typedef struct NpgTrainer NpgTrainer;
typedef struct NpgModel NpgModel;
/* A trainer that replays its samples through `f` (params bound; it must
 * outlive the trainer). Never NULL but out of memory; errors through
 * npg_trainer_error(), after which it refuses further work. */
NPG_API NpgTrainer *npg_trainer_new(NpgFull *f, const NpgTrainOptions *o);
NPG_API const char *npg_trainer_error(const NpgTrainer *t);
/* After a refused call (a sample's values, npg_trainer_add, _add_full, _weight, _dots, or a
 * finish that failed before writing anything): forget the refused sample's staged values and
 * weight, and take samples again; the samples added before are kept. 0, or -1 keeping the error
 * when the trainer cannot go on: its construction was refused, a failure left its records
 * incomplete (out of memory, the scratch file), or it trains over MPI ranks. The option names
 * (basis_name, keep_bases, interp_stage, galerkin_stage) are checked by npg_trainer_new. */
NPG_API int npg_trainer_clear_error(NpgTrainer *t);
/* Stage the values of an input or extern of the next sample (C order). */
NPG_API int npg_trainer_set(NpgTrainer *t, const char *name, int ndim, const long *shape, const double *values);
/* Add the staged sample: every input must be staged; an extern not staged
 * is computed by its callback (npg_full_set_extern_fn), and one that has no
 * callback is refused, naming it (no value is carried over from the previous
 * sample). */
NPG_API int npg_trainer_add(NpgTrainer *t);
/* Add the inputs and externs now held by `g` (an evaluator of the same
 * program, after npg_full_eval). */
NPG_API int npg_trainer_add_full(NpgTrainer *t, const NpgFull *g);
/* Training from a trajectory (DESIGN §15): run `f`'s step ro->steps times from the states and
 * inputs it holds (ro->before_step sets inputs given per step) and add the visited states, every
 * ro->every-th step (steps 0, every, …), as npg_trainer_add_full does; ro->at_save, when given,
 * runs after each is added. Nothing is written to disk but the trainer's own records. 0, or -1
 * with npg_trainer_error(t) or, when the step failed (a blow-up), npg_full_error(f). */
NPG_API int npg_trainer_add_trajectory(NpgTrainer *t, NpgFull *f, long sample, const NpgRollout *ro);
/* The weight of the next sample added (positive and finite; 1 when not given, and again after
 * every add): the bases' PCA minimizes Σ_k w_k ‖x_k − BBᵀx_k‖², so weight 2 counts a sample
 * as if it had been added twice (a training design's rare points weighed up, e.g. the extremes
 * its interior points outnumber). The floors and reports stay per sample. Not with --merge
 * joint, nor when the snapshots take the method of snapshots (raise mem). */
NPG_API int npg_trainer_weight(NpgTrainer *t, double w);
NPG_API long npg_trainer_samples(const NpgTrainer *t);
/* Train on the samples added: snapshots, one basis per class, every tensor
 * pre-multiplied, externs fitted. When `model_dir` is non-NULL the model is
 * also written there (a temporary folder renamed when complete). NULL with
 * npg_trainer_error() on failure. The model belongs to the caller. */
NPG_API NpgModel *npg_trainer_finish(NpgTrainer *t, const char *model_dir);
NPG_API void npg_trainer_free(NpgTrainer *t);
/* dots[k] = <values, the value input or extern `name` had in training sample k> for every
 * sample added (npg_trainer_samples(t) of them, in order; `count` entries each), from the
 * trainer's own record of them (an extern's callback is not called again). Before or after
 * npg_trainer_finish, while the trainer lives; over MPI ranks a collective (every rank calls
 * it; each gets every dot). With npg_model_coefficients, the coordinates of a value of a class
 * kept as coefficients of its training values. 0, or -1 with npg_trainer_error(). */
NPG_API int npg_trainer_dots(NpgTrainer *t, const char *name, size_t count, const double *values, double *dots);
/* The wall time, in seconds, of the training that made `m` (0 for a
 * loaded model): seconds[0] snapshots, [1] bases, [2] pre-multiplication,
 * [3] externs; `cpu` (may be NULL) the same phases' CPU time of this
 * process (all its threads; over MPI ranks, this rank's). */
NPG_API void npg_model_train_seconds(const NpgModel *m, double seconds[4], double cpu[4]);

/* ---------------------------------------------------------------- models
 *
 * A model is read-only once made: any number of NpgReduced evaluators, on
 * any threads, may share one. It keeps pointers into its NpgProgram: free
 * it before npg_free(). */
NPG_API NpgModel *npg_model_load(NpgProgram *p, const char *dir);
/* "" when the model is usable, else why not (loading names the file). */
NPG_API const char *npg_model_error(const NpgModel *m);
NPG_API int npg_model_save(NpgModel *m, const char *dir);
NPG_API void npg_model_free(NpgModel *m);

typedef struct NpgClassInfo {
  const char *label;        /* "{b,e}" */
  long n;                   /* full dimension: entries of each member */
  long m;                   /* basis size */
  int nmembers;
} NpgClassInfo;
typedef struct NpgMemberInfo {
  const char *name;         /* a quantity, or "h.num1": the numerator of term 1 of h */
  int kept, cap;            /* PCA vectors kept, and the cap */
  double captured;          /* energy fraction captured */
} NpgMemberInfo;
/* The training table `npgc train` prints: per class its sizes, per member
 * kept / cap and the energy lost (of the centered part when centered), and
 * a warning where a member hit its cap with more than 1e-3 lost. */
NPG_API void npg_model_report(const NpgModel *m, FILE *out);
/* Every member's singular values into DIR as .npy and CSV (MODEL/ holds them
 * too). 0, or -1 with `err` naming the file; all or none: a failure (a full
 * disk) leaves DIR's files as they were. */
NPG_API int npg_model_write_spectra(const NpgModel *m, const char *dir, char *err, size_t errlen);
/* Every member's singular values as MODEL/ holds them, read without the
 * program (any model folder): `*out` (malloc'd, `*count` entries) until
 * npg_spectra_free. 0, or -1 with `err` naming the file. */
typedef struct NpgSpectrum {
  char *member;             /* "s", or "h.num1" */
  int kept, cap;            /* basis vectors kept, and the cap */
  bool centered;            /* kept counts the mean, which the spectrum (of the centered snapshots) does not hold */
  long n;
  double *sigma;            /* n singular values, largest first */
} NpgSpectrum;
NPG_API int npg_spectra_read(const char *model_dir, NpgSpectrum **out, int *count, char *err, size_t errlen);
NPG_API void npg_spectra_free(NpgSpectrum *s, int count);
/* -- interpolated stages (DESIGN §12; issue 26) --
 * How the model reduces stage `stage`: 1 by interpolation (then *entries,
 * when not NULL, is the number of entries it evaluates the stage at), 0 by
 * Galerkin projection, -1 when the model or the name is not valid. */
NPG_API int npg_model_stage_interpolated(const NpgModel *m, const char *stage, long *entries);
/* One line per stage that is interpolated or whose reduction training chose
 * by measurement: how, both errors and the reason (part of npg_model_report). */
NPG_API void npg_model_report_reductions(const NpgModel *m, FILE *out);
NPG_API int npg_model_nclasses(const NpgModel *m);
NPG_API int npg_model_class(const NpgModel *m, int c, NpgClassInfo *out);
NPG_API int npg_model_member(const NpgModel *m, int c, int i, NpgMemberInfo *out);
/* The class of a quantity (input, extern or stage), -1 if it has none. */
NPG_API int npg_model_class_of(const NpgModel *m, const char *quantity);
/* The orthonormal basis of class c, n x m row-major (owned by the model);
 * NULL for a class whose basis was streamed in training and not kept
 * (NpgTrainOptions.keep_bases). A class with a product (`basis u: product K0`,
 * --basis u:product=K0) is K0-orthonormal, BᵀK0B = I: a value x then has the
 * coordinates BᵀK0x = Dᵀx, D from npg_model_dual, not Bᵀx. */
NPG_API const double *npg_model_basis(const NpgModel *m, int c);
/* The dual K0 B of a class with a product, n x m row-major (owned by the
 * model), what projects a value onto its basis (npg_reduced_set does); NULL
 * for a class without a product (its basis projects: Bᵀx). */
NPG_API const double *npg_model_dual(const NpgModel *m, int c);
/* A class kept as coefficients of its training values instead of a basis (an extern over two or
 * more dims, trained out of core: radiosity's visibility, issue 30): its basis is B = X C, X the
 * n x S matrix of the extern's S training values in training order, C returned here, S x m
 * row-major (owned by the model), *samples (optional) set to S. A value v then has the
 * coordinates Bᵀv = Cᵀ(Xᵀv): its inner products with the training values (npg_trainer_dots)
 * times C, for npg_reduced_set_coords. NULL for a class that has its basis, or none. */
NPG_API const double *npg_model_coefficients(const NpgModel *m, int c, long *samples);
/* Bytes of the whole model; *tensor_bytes (optional) those of the reduced tensors. */
NPG_API size_t npg_model_bytes(const NpgModel *m, size_t *tensor_bytes);
NPG_API long npg_model_samples(const NpgModel *m);
/* The size dim `name` had in training, -1 if unknown. */
NPG_API long npg_model_dim(const NpgModel *m, const char *name);
/* Check that every input (and extern) of `s` has, per sample, the shape the
 * model `m` was trained on (its dims' sizes and the static axes): 0, or -1
 * with a message naming the file, the shape found and the one expected. */
NPG_API int npg_samples_check_model(const NpgSamples *s, const NpgModel *m, char *err, size_t errlen);
/* 0 when the params bound in `f` equal those the model was trained with
 * (hashes of their values), else -1 with a message in `err` naming the param. */
NPG_API int npg_model_check_params(const NpgModel *m, const NpgFull *f, char *err, size_t errlen);
/* The same for the param files DIR/<param>.npy that exist (a reduced
 * evaluation needs no params, but must not accept different ones). */
NPG_API int npg_model_check_params_dir(const NpgModel *m, const char *dir, char *err, size_t errlen);
/* The same for the params bound in `f` against the files in DIR. */
NPG_API int npg_full_check_params_dir(const NpgFull *f, const char *dir, char *err, size_t errlen);
/* The reduced evaluator of the model as C specialized to its sizes
 * (`npgc emit --reduced`). 0, or -1 with a message in `err`. */
NPG_API int npg_model_emit(const NpgModel *m, FILE *out, char *err, size_t errlen);

/* ---------------------------------------------------------------- reduced evaluation
 *
 *     NpgReduced *r = npg_reduced_new(m);
 *     npg_reduced_set(r, "g", n, g);            // full values, projected: ĝ = Bᵀg
 *     if (npg_reduced_eval(r, k)) fputs(npg_reduced_error(r), stderr);
 *     npg_reduced_lift(r, "b", b, n);           // b = B b̂ into the caller's buffer
 *
 * One evaluator per thread; it owns its coordinates and scratch memory and
 * only reads the model. Functions return 0, or -1 with npg_reduced_error()
 * (naming the quantity, stage and sample); after an error the evaluator
 * refuses further work until npg_reduced_clear_error(). */
typedef struct NpgReduced NpgReduced;
NPG_API NpgReduced *npg_reduced_new(const NpgModel *m);
/* The reduced evaluator of `m` at smaller basis sizes, without retraining (issue 41): `sizes`
 * is "NAME=N,NAME=N" (npgc's --sizes), NAME a class as `npgc check` names it (m_u), m_<member>,
 * its label {u,v} or a member, N from 1 to the class's size; the classes not named keep theirs.
 * Every class keeps the first N vectors of its basis and every pre-multiplied tensor its
 * leading block (npg_model_at_sizes; the evaluator owns that model). NULL or "" sizes: as
 * npg_reduced_new. A bad entry or an interpolated stage's class made smaller: the evaluator
 * holds the error (npg_reduced_error), naming the entry. */
NPG_API NpgReduced *npg_reduced_new_sizes(const NpgModel *m, const char *sizes);
/* The model `m` at smaller basis sizes (`sizes` as npg_reduced_new_sizes), a new model the
 * caller frees before `m`'s program; for one cut of a trained model: training at caps that keep
 * those first vectors (one member per class, or --merge joint) gives the same model to rounding.
 * An interpolated stage's own class keeps its size (its fit is of the whole basis; the classes
 * it reads may shrink). Never NULL but out of memory: the error through npg_model_error(). */
NPG_API NpgModel *npg_model_at_sizes(const NpgModel *m, const char *sizes);
NPG_API const char *npg_reduced_error(const NpgReduced *r);
NPG_API void npg_reduced_clear_error(NpgReduced *r);
/* An input (or an extern, see npg_reduced_given_externs) from its `count`
 * full-space values. */
NPG_API int npg_reduced_set(NpgReduced *r, const char *name, size_t count, const double *values);
/* The same from its `m` reduced coordinates (finite: NaN or an infinity is refused). */
NPG_API int npg_reduced_set_coords(NpgReduced *r, const char *name, size_t m, const double *coords);
/* With `on`, externs keep the values set by the caller instead of their
 * learned map. */
NPG_API void npg_reduced_given_externs(NpgReduced *r, bool on);
/* Every input (and given extern) must have been set: one never set is an
 * error naming it, not a zero. `sample` is the number of the sample in the
 * caller's set, for messages ("at sample 12"); a negative one: no set, and
 * messages say "at these inputs". */
NPG_API int npg_reduced_eval(NpgReduced *r, long sample);
/* Roots (fractional powers) of reduced operators are applied by the
 * Lanczos process to an a-posteriori estimate below 1e-8 relative (falling
 * back to the eigendecomposition where that is not faster); with `on`,
 * always by the eigendecomposition (the exact reference). */
NPG_API void npg_reduced_exact_roots(NpgReduced *r, bool on);
/* Reduced coordinates of any quantity (m of them), NULL if unknown or if it
 * was not set and nothing was evaluated yet. */
NPG_API const double *npg_reduced_coords(const NpgReduced *r, const char *name, size_t *m);
/* Lift a quantity to full space: out (count entries, the full size) = B x̂.
 * An error before any evaluation, unless the quantity was set. */
NPG_API int npg_reduced_lift(NpgReduced *r, const char *name, double *out, size_t count);
/* The online error estimate of quantity `name` at the last evaluation (DESIGN §16,
 * docs/estimates.md): *estimate the estimated absolute error of its lifted values in the
 * 2-norm, ‖y − B ŷ‖ (in the norm of the product K0 when its class has one, `basis u: product
 * K0`: ‖y − B ŷ‖_K0 = √(eᵀK0e)), computed at reduced cost from tables training stored in the model; NaN
 * when there is none (npg_reduced_estimate_why says why). *flags (may be NULL) holds
 * NPG_EST_ bits. An input's own figure is ‖x − B x̂‖ when it was set in full
 * (npg_reduced_set; 0 below its roundoff), 0 when set by coordinates (taken as exact). 0, or
 * -1 (an unknown name, no evaluation yet) with npg_reduced_error. */
#define NPG_EST_BOUND 1u    /* a rigorous bound (up to roundoff); unset: an estimate */
#define NPG_EST_OUTSIDE 2u  /* an input it depends on lies outside the training range (npg_reduced_outside) */
#define NPG_EST_ROUNDOFF 4u /* the residual is below the roundoff of its expansion: the figure is that level */
#define NPG_EST_NONE 8u     /* no estimate: the figure is NaN */
NPG_API int npg_reduced_estimate(NpgReduced *r, const char *name, double *estimate, unsigned *flags);
/* Why quantity `name` has no estimate ("" when it has one, or on an error). */
NPG_API const char *npg_reduced_estimate_why(NpgReduced *r, const char *name);
/* The trust signal: 1 when input `name`'s coordinates, as last set, lie outside the range of
 * the training samples' by more than a tenth of that range (*coord, may be NULL: the first
 * such coordinate), 0 inside or when the model recorded no range, -1 on an error (not an
 * input, never set). */
NPG_API int npg_reduced_outside(NpgReduced *r, const char *name, long *coord);
/* Lift `samples` sets of coordinates of a quantity at once: coords
 * (samples x m, row-major, finite) to out (samples x count, count the full
 * size) = coords Bᵀ, the basis read once for all of them (one dgemm); what
 * npg_reduced_lift gives for each, to rounding. Reads no evaluation. */
NPG_API int npg_reduced_lift_many(NpgReduced *r, const char *name, size_t samples, size_t m, const double *coords,
                                  double *out, size_t count);
/* The `output op` `name` reduced at the last evaluation: out (rows x cols,
 * row-major, at most `cap` entries) = B_rowᵀ M B_col, with the bases of the
 * classes *row_class and *col_class (npg_model_class). An error before any
 * evaluation, unless every quantity its entries read was set. */
NPG_API int npg_reduced_op(NpgReduced *r, const char *name, double *out, size_t cap, long *rows, long *cols,
                           int *row_class, int *col_class);
/* The reduced step (DESIGN §15): npg_full_step's contract with every state kept in reduced
 * coordinates (a state and its next value share one basis: the next value's coordinates become
 * the state's, nothing lifted); energy is ‖û‖² of the state's coordinates. */
/* Derivatives of the reduced evaluator in reduced coordinates (DESIGN §17), the contract of
 * npg_full_jvp/vjp/jacobian with every array a quantity's m coordinates instead of its full
 * entries: each evaluates (npg_reduced_eval at `sample`) and differentiates there, at reduced
 * cost (nothing of the full size).
 *   npg_reduced_jvp: out (output's m) = Σ_i J(output, inputs[i]) · directions[i] (inputs' m);
 *   npg_reduced_vjp: out (input's m)  = Σ_i J(outputs[i], input)^T · cotangents[i];
 *   npg_reduced_jacobian: out = J(output, input), m_output × m_input, row-major.
 * Contractions differentiate through their pre-multiplied tensors, inverse stages as
 * K̂⁻¹(df̂ − dK̂ ŷ), roots by the Daleckii–Krein formula on the reduced operator's
 * eigendecomposition, interpolated stages through their formula at the selected entries.
 * Derivatives are taken with respect to inputs; an output may be any quantity. An extern
 * that depends on the input (its learned map has no derivative) is refused, naming it; after
 * npg_reduced_given_externs(r, true) externs hold the caller's values and are constants.
 * 0, or -1 with npg_reduced_error() naming the argument or the stage. */
NPG_API int npg_reduced_jvp(NpgReduced *r, long sample, int nin, const char *const *inputs,
                            const double *const *directions, const char *output, double *out);
NPG_API int npg_reduced_vjp(NpgReduced *r, long sample, int nout, const char *const *outputs,
                            const double *const *cotangents, const char *input, double *out);
NPG_API int npg_reduced_jacobian(NpgReduced *r, long sample, const char *output, const char *input, double *out);
/* Newton's method on a reduced residual (DESIGN §17, implicit steps): the coordinates of input
 * `unknown` such that the coordinates of quantity `residual` vanish, from the unknown's current
 * coordinates (set them first: the previous state is the usual start). `residual` and `unknown`
 * must share one basis (`share r, v` in the program), so the reduced residual is the Galerkin
 * projection r̂ = Bᵀ r(B v̂) and its Jacobian m × m, solved by LAPACK dgesv. Stops when
 * ‖r̂‖₂ <= tol; fails after max_iter corrections, at a singular Jacobian or at a residual that is
 * not finite, naming the sample (a step's number), the iteration and the residual. On success
 * the unknown holds the solution and every quantity its value there. */
typedef struct NpgNewton {
  double tol;               /* on ‖r̂‖₂, > 0 */
  int max_iter;             /* corrections at most, >= 1 */
  FILE *verbose;            /* one line per iteration (the residual's norm), or NULL */
  double *history;          /* when not NULL: ‖r̂‖₂ of iteration i at history[i], i < history_cap */
  int history_cap;
  double rtol;              /* when > 0, Newton also stops at ‖r̂‖₂ <= rtol · ‖r̂₀‖ (the first guess's) */
  int iterations;           /* out: corrections made */
  double residual;          /* out: the last ‖r̂‖₂ */
} NpgNewton;
NPG_API int npg_reduced_newton(NpgReduced *r, long sample, const char *residual, const char *unknown, NpgNewton *o);
/* Newton's method on a full residual, npg_reduced_newton's contract on the full evaluator: the
 * values of input `unknown` such that quantity `residual` (as many entries) vanishes, from the
 * unknown's value as set. Each iteration evaluates, stops when ‖r‖₂ <= tol, and otherwise solves
 * J δ = r with the Jacobian on its structural pattern (npg_full_jacobian_csr's, planned once per
 * call): by UMFPACK (the pattern analysed once, factorized at every iteration), or by LAPACK
 * dgesv when more than 2% of its entries are on the pattern. Verbose lines, history and
 * failures (not converged after max_iter corrections, a singular Jacobian, a residual that is
 * not finite: each naming the sample, the iteration and the residual) as npg_reduced_newton's.
 * On success the unknown holds the solution and every quantity its value there. 0, or -1 with
 * npg_full_error(). */
NPG_API int npg_full_newton(NpgFull *f, long sample, const char *residual, const char *unknown, NpgNewton *o);
NPG_API int npg_reduced_step(NpgReduced *r, long steps, long sample);
NPG_API long npg_reduced_steps(const NpgReduced *r);
NPG_API int npg_reduced_set_blowup(NpgReduced *r, double factor);
NPG_API int npg_reduced_set_newton(NpgReduced *r, double tol, int max_iter, FILE *verbose);
NPG_API int npg_reduced_simulate(NpgReduced *r, long sample, const NpgRollout *ro);
NPG_API void npg_reduced_free(NpgReduced *r);
/* The BLAS threads of the process (reduced evaluation, training's GEMMs):
 * `n` >= 1 sets them, 0 only asks. Returns the number before the call. */
NPG_API int npg_blas_threads(int n);
/* Streaming read bandwidth measured here, in GB/s: the best of repeated sums over a buffer of
 * `bytes` (at least 64) on the calling thread for at least `min_seconds` (three sums at least).
 * A size that fits a cache measures that cache: the bound of a reduced evaluation is the bytes of
 * its tensors over the bandwidth at their size (`npgc bench` prints both). 0 when out of memory. */
NPG_API double npg_read_bandwidth(size_t bytes, double min_seconds);

/* ---------------------------------------------------------------- basis sizes by error
 *
 * `npgc tune`: every class's cap chosen so that every output's mean relative
 * L2 error on validation samples is at most `tol` at the least reduced cost
 * (the cost `npgc check` prints). One snapshot pass and one SVD per member;
 * every candidate is a truncation of those bases, its tensors the leading
 * blocks of one model pre-multiplied at caps covering the candidates. */
typedef struct NpgTuneTrial {
  const long *m;            /* per class: the basis size */
  double cost;              /* reduced multiply-adds */
  double err;               /* the worst output's mean relative L2 error on the validation samples */
  bool uniform;             /* one cap for every class */
  const char *interpolated; /* the stages reduced by interpolation at these sizes, comma-separated ("": none):
                               each eligible stage is measured both ways at every candidate (DESIGN §12) */
} NpgTuneTrial;
typedef struct NpgTuneReport {
  int nclasses;
  const char **class_name;  /* per class: its size name, "m_x" */
  int ntrials;
  NpgTuneTrial *trials;     /* in the order tried */
  int chosen;               /* the trial chosen; -1 when `tol` cannot be met */
  const char *limiting;     /* then: the class whose projection floor is the largest */
  double limiting_floor;
  bool limiting_saturated;  /* its members have no more directions in the training samples */
  char error[2048];         /* why the search failed, when it did */
  void *priv;
} NpgTuneReport;
/* Train on `ntrain` samples (train(tuser, f, k) sets sample k in `f`, its
 * params bound), validate on `nvalid` (valid(vuser, f, k)), caps at most
 * `max_cap`; `o` (may be NULL: npg_train_options_default's) is read as
 * npg_trainer reads it — centering, progress, the basis overrides, the stages
 * forced to interpolation or Galerkin (the others eligible are chosen at every
 * candidate), the oversampling, and the bases kept (keep_bases) — except what
 * the search sets itself: caps up to `max_cap` at every energy, in one
 * process (not mpi), concatenated members, snapshots in memory. The chosen
 * model, or NULL: report->error says why, or is "" when `tol` cannot be met
 * (report->limiting). npg_tune_free(report) either way. */
NPG_API NpgModel *npg_tune(NpgFull *f, long ntrain, NpgSampleFn train, void *tuser, long nvalid, NpgSampleFn valid,
                           void *vuser, double tol, int max_cap, const NpgTrainOptions *o, NpgTuneReport *report);
NPG_API void npg_tune_free(NpgTuneReport *report);

/* ---------------------------------------------------------------- greedy training
 *
 * The weak greedy (pyMOR's, DESIGN §16): train on the `nstart` samples `start` sets (as few as
 * one), then repeatedly evaluate the reduced model and its online estimate (npg_reduced_estimate)
 * on every candidate of the pool that `pool` sets, and add the one whose largest estimated
 * relative error over the outputs (estimate / ‖output‖; with `absolute` the estimate itself, in
 * the product's norm for an output whose class has one, as pyMOR's greedy's atol) is worst to the
 * training set, retraining;
 * stop when every candidate's is below `tol` or when the training set holds `budget` samples.
 * Full evaluations run only at the training samples (the start and the chosen), once each: a
 * retraining takes the earlier samples' snapshots from the last (NpgGreedyResult.evaluations
 * counts them; docs/estimates.md says where training keeps none and replays). A candidate
 * whose input the model's basis does not hold (its own error above roundoff) counts as worst
 * (infinite; among several, the one farthest outside, ‖x − B x̂‖ / ‖x‖): a full evaluation there
 * adds the direction. Each input's basis defaults to energy 1 here (every direction its samples
 * span), unless `o`'s overrides or the program's `basis` set it. Every output needs an estimate (the
 * reason is the error otherwise). Progress (one line an iteration) on
 * stderr with `progress`. The model is written to `model_dir` (when not NULL) with the manifest
 * line `greedy tol E relative|absolute budget N converged 0|1 worst X chosen k1,k2,...` (pool indices, in the
 * order chosen). */
typedef struct NpgGreedyOptions {
  double tol;               /* > 0 */
  long budget;              /* at most this many training samples (start included); 0: nstart + npool */
  bool progress;
  bool absolute;            /* tol bounds the estimate itself, not estimate / ‖output‖ */
} NpgGreedyOptions;
typedef struct NpgGreedyResult {
  long *chosen;             /* pool indices chosen, in order (malloc'd; free()) */
  long nchosen;
  double worst;             /* the worst candidate's estimated error (relative, or absolute) of the final model */
  long worst_at;            /* which candidate (-1: the pool was used up) */
  bool converged;           /* worst < tol (else the budget stopped it) */
  long evaluations;         /* full evaluations the run made: one per training sample (each retraining takes the
                               earlier samples' snapshots from the last one), more where training keeps no
                               snapshot or measures samples again (docs/estimates.md, "Greedy training") */
  char error[1024];
} NpgGreedyResult;
NPG_API NpgModel *npg_train_greedy(NpgFull *f, const NpgTrainOptions *o, long nstart, NpgSampleFn start, void *suser,
                                   long npool, NpgSampleFn pool, void *puser, const NpgGreedyOptions *g,
                                   const char *model_dir, NpgGreedyResult *res);

/* ---------------------------------------------------------------- verification
 *
 * The auto-check (`npgc verify`): on held-out samples, the full evaluator
 * against the reduced one lifted to full space, per quantity. */
typedef struct NpgVerifyRow {
  const char *name;
  const char *kind;         /* "input", "extern", or the stage kind */
  long m;                   /* basis size */
  bool output;
  double l2, floor, own;    /* means over samples: ‖y − Bŷ‖/‖y‖, ‖y − BBᵀy‖/‖y‖, their difference */
  double l2_max;            /* the worst sample's L2 error */
  long l2_max_sample;
  double linf, linf_floor;  /* the same in the max norm */
  bool streamed;            /* its basis was streamed in training, not kept: l2, own, l2_max and linf are
                               NaN (nothing to lift), floor and linf_floor the training samples' mean,
                               measured by training (out of core from ‖y‖² − ‖Bᵀy‖², resolved to about
                               1e-7, and linf_floor NaN: not measured) */
  /* the online estimate (npg_reduced_estimate) against the true error, absolute, in the 2-norm (in the norm
   * of the product K0 for a quantity whose class has one, `basis u: product K0`: docs/estimates.md): */
  double est, err;          /* means over the samples that had an estimate (est NaN: none had one) */
  double eff_min, eff_max;  /* effectivity est / err over those samples (where err > 0) */
  long est_samples;         /* samples with an estimate */
  bool est_bound;           /* every sample's estimate was a rigorous bound (NPG_EST_BOUND) */
} NpgVerifyRow;
typedef struct NpgVerifyReport {
  long samples;
  int nrows;
  NpgVerifyRow *rows;       /* every quantity, program order */
  const char *grows_at;     /* the stage where error grows most (NULL: none) */
  double growth;            /* by how much over the worst quantity it reads */
  char error[1024];         /* why the verification failed, when it returns -1 */
} NpgVerifyReport;
/* Run `samples` samples: set(user, f, k) sets sample k's inputs and externs
 * in `f` (params bound, equal to the model's: checked). 0, or -1 with
 * report->error. Free with npg_verify_free. */
NPG_API int npg_verify(const NpgModel *m, NpgFull *f, long samples, NpgSampleFn set, void *user, bool progress,
                       NpgVerifyReport *report);
NPG_API void npg_verify_free(NpgVerifyReport *report);
/* The check of a simulation (DESIGN §15, `npgc verify --steps`): for each of `trajectories`
 * trajectories the full and the reduced rollouts of `steps` steps, their states compared every
 * `every` steps with the trajectory's projection floor (the full states projected onto the model's
 * bases). set(user, f, k, t) sets trajectory k's values at step t in `f`: at t = 0 its states'
 * initial values and every input, at t > 0 the inputs given per step (or nothing); the reduced
 * rollout reads them from `f` (projected). Errors are relative L2: per state, the trajectory's
 * ‖R − F‖ / ‖F‖ over every trajectory and saved step, its floor the same for the projection, and
 * the largest per trajectory and saved step. A rollout that blows up fails the call, naming the
 * trajectory, the step and the state. 0, or -1 with report->error; npg_verify_rollout_free. */
typedef int (*NpgTrajectoryFn)(void *user, NpgFull *f, long trajectory, long step);
typedef struct NpgRolloutRow {
  const char *state;
  double *err, *floor;      /* per saved step: the largest over the trajectories (saves entries each) */
  double traj_err, traj_floor;
  double err_max, err_final;
  long max_trajectory, max_step;
} NpgRolloutRow;
typedef struct NpgRolloutReport {
  long trajectories, steps, every, saves;
  int nstates;
  NpgRolloutRow *rows;
  char error[2048];
} NpgRolloutReport;
NPG_API int npg_verify_rollout(const NpgModel *m, NpgFull *f, long trajectories, long steps, long every, NpgTrajectoryFn set,
                               void *user, bool progress, NpgRolloutReport *report);
NPG_API void npg_verify_rollout_free(NpgRolloutReport *report);
/* Warnings where they help: a stage whose own error exceeds 3x its
 * projection floor (naming what it reads worst and the remedies), an input
 * whose floor alone exceeds `tol`. Returns how many were printed. */
NPG_API int npg_verify_warnings(const NpgModel *m, const NpgVerifyReport *report, double tol, FILE *out);
/* The design's two exactness checks on random data (`npgc verify --exact`),
 * every dim of size `size` (0: defaults), report to `out`. 0 pass, 1 a
 * check failed, -1 a check could not run (message in `err`). */
NPG_API int npg_verify_exact(NpgProgram *p, long size, NpgBackend backend, bool progress, FILE *out, char *err,
                             size_t errlen);

/* ---------------------------------------------------------------- command lines
 *
 * One strict parser for the options of npgc and of the applications, so
 * every program takes `--opt value` and `--opt=value`, refuses a number
 * with trailing text or out of its range, and says which option is wrong:
 *
 *     NpgArgs a;
 *     npg_args_init(&a, argc, argv, 2, "npg-fluids tunnel");   // argv[2..] are options
 *     while (npg_args_next(&a)) {
 *       if (npg_args_int(&a, "--frames", 2, 100000, &frames)) continue;
 *       if (npg_args_double(&a, "--mu", 0, 10, true, &mu)) continue;
 *       if ((v = npg_args_string(&a, "--out"))) { out = v; continue; }
 *       if (npg_args_backend(&a, &backend)) continue;      // --jit auto|cc|tcc, --cc
 *       npg_args_unknown(&a);
 *     }
 *     if (a.error[0]) { fprintf(stderr, "%s\n", a.error); return 2; }
 *
 * A matcher that recognises the current argument consumes it (and its
 * value) and returns true even when the value is refused: the first problem
 * is kept in `error` and npg_args_next then stops. Nothing is printed. */
typedef struct NpgArgs {
  int argc;
  char **argv;
  int i;                    /* the argument being read */
  const char *prog;         /* the messages' prefix ("npgc train", "npg-points") */
  char error[512];          /* the first problem, "PROG: --opt: ...", or "" */
} NpgArgs;
NPG_API void npg_args_init(NpgArgs *a, int argc, char **argv, int first, const char *prog);
/* Advance to the next argument: false when none is left or after an error. */
NPG_API bool npg_args_next(NpgArgs *a);
/* The argument is the flag `name` ("--name=..." is refused: it takes no value). */
NPG_API bool npg_args_flag(NpgArgs *a, const char *name);
/* The argument is option `name`, as "NAME VALUE" or "NAME=VALUE": its value
 * (any text, "-1" included); NULL when it is another argument, or when NAME
 * ends the command line (then `error` says the value is missing). */
NPG_API const char *npg_args_string(NpgArgs *a, const char *name);
/* The option `name` with a whole number in [lo, hi] (a double in [lo, hi],
 * or (lo, hi] with `lo_open`), the whole value read: "300abc", "2.9", "",
 * "nan" and values outside the range are refused, the message giving it. */
NPG_API bool npg_args_long(NpgArgs *a, const char *name, long lo, long hi, long *out);
NPG_API bool npg_args_int(NpgArgs *a, const char *name, int lo, int hi, int *out);
NPG_API bool npg_args_double(NpgArgs *a, const char *name, double lo, double hi, bool lo_open, double *out);
/* The argument when it is not an option (does not start with '-', or is "-"), else NULL. */
NPG_API const char *npg_args_positional(NpgArgs *a);
/* `--jit auto|cc|tcc` (anything else refused, naming the choices), or its
 * alias `--cc` (= --jit cc), into `out`. */
NPG_API bool npg_args_backend(NpgArgs *a, NpgBackend *out);
/* No matcher took the argument: "unknown option '--x'" (an option) or
 * "unexpected argument 'x'" into `error`. */
NPG_API void npg_args_unknown(NpgArgs *a);
/* The same rules for one number outside an option (a positional argument, a
 * list entry, the value of --basis cap=N): 0, or -1 with "'300abc' is not a
 * whole number (expected 1..10000)" or "99 is out of range (expected (0, 1])" in `err`. */
NPG_API int npg_parse_long(const char *s, long lo, long hi, long *out, char *err, size_t errlen);
NPG_API int npg_parse_double(const char *s, double lo, double hi, bool lo_open, double *out, char *err,
                             size_t errlen);
/* One per-name basis option, as `npgc train --basis`, the applications' --basis and Python's
 * Trainer(basis=[...]) all take it: "NAME:KEY=VALUE,KEY=VALUE,...", NAME a quantity, a class
 * (m_x, as npgc check prints it), a numerator (y.num1) or '*' (training checks the name), and
 * at least one of the keys, each at most once: cap (a whole number 1..1000000; `max` is the
 * same key), energy (a fraction in (0, 1]), center (on or off). `KEY VALUE` reads as
 * `KEY=VALUE`, as in the language's basis statement; blanks around items are ignored. On
 * success `*name` is NAME (malloc'd: free() it) and `*cap`, `*energy`, `*center` what was
 * given, -1 for a key not given (one entry of NpgTrainOptions' basis_* arrays); 0. Else -1,
 * the outputs untouched, and "'SPEC': problem" in `err`, naming the key: "'x:cap=0': cap: 0
 * is out of range (expected 1..1000000)". */
NPG_API int npg_parse_basis(const char *spec, char **name, int *cap, double *energy, int *center, char *err,
                            size_t errlen);
/* The same reader with one more key, product=OP (issue 41): the class of NAME orthonormal in
 * the inner product of the program's SPD op OP (as the language's `basis u: product OP`);
 * `*product` is OP (malloc'd: free() it) or NULL when not given (NpgTrainOptions.basis_product).
 * npgc train and Python's Trainer(basis=[...]) read --basis with it; npg_parse_basis refuses
 * the key as unknown. */
NPG_API int npg_parse_basis_product(const char *spec, char **name, int *cap, double *energy, int *center,
                                    char **product, char *err, size_t errlen);

#ifdef __cplusplus
}
#endif
#endif
