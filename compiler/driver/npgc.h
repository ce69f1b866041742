/* npgc.h — the commands of the npgc driver, a client of npg.h only. */
#ifndef NPGC_H
#define NPGC_H

#include <stdbool.h>
#include <stdio.h>

#include "npg.h"

/* eval.c: `npgc eval --full` (the reduced form goes to npgc_reduce). */
int npgc_eval(int argc, char **argv);
/* simulate.c: npgc simulate PROG.npg DATA/ --steps T [--every K] [--model MODEL/] -o OUT/. */
int npgc_simulate(int argc, char **argv);
/* trajectories.c: the inputs of rollouts from a folder. Each input's file holds [S, ...] (held
 * for every step; a state: its initial value) or [S, T', ...] (one value per step, T' >= the
 * steps run); externs are refused. */
typedef struct TrajInput {
  NpgSymbol sym;
  char path[4096];
  double *v;
  int ndim, axes;           /* the file's axes; the value's (ndim less the sample and step axes) */
  long shape[8];
  size_t each;              /* entries of one value */
  bool per_step;
} TrajInput;
typedef struct Trajectories {
  TrajInput *in;
  int n;
  long samples;             /* trajectories */
} Trajectories;
int npgc_trajectories_open(NpgProgram *p, const char *dir, long steps, Trajectories *t, char *err, size_t errlen);
const double *npgc_trajectory_value(const TrajInput *in, long k, long step);
/* Trajectory k's inputs at `step`: every input (all), or only those given per step. */
int npgc_trajectories_set_full(const Trajectories *t, NpgFull *f, long k, long step, bool all);
int npgc_trajectories_set_reduced(const Trajectories *t, NpgReduced *r, long k, long step, bool all);
void npgc_trajectories_free(Trajectories *t);
/* The median and the quartiles of v[0..n) (sorted in place); reduce_use.c. */
void npgc_quartiles(double *v, long n, double q[3]);
/* bench's line naming the full evaluator's backend, its compile (or cache load) time
 * and whether the cache had it; reduce_use.c. */
void npgc_print_jit(const NpgFull *f);
/* An implicit step's Newton options (a program with `residual next u = ...`), shared by simulate,
 * train --steps and verify --steps: --newton-tol R (relative, 1e-10), --newton-max-iter N (30),
 * --newton-verbose (‖r‖ per iteration on stderr); npgc_util.c. */
typedef struct NpgcNewton {
  double tol;
  int max_iter;
  bool verbose;
} NpgcNewton;
#define NPGC_NEWTON_DEFAULT {1e-10, 30, false}
bool npgc_newton_arg(NpgArgs *a, NpgcNewton *nw);
void npgc_newton_full(const NpgcNewton *nw, NpgFull *f);
void npgc_newton_reduced(const NpgcNewton *nw, NpgReduced *r);
/* reduce_cmds.c: train, reduced eval, verify, bench. */
int npgc_reduce(int argc, char **argv);

/* plot.c: npgc plot MODEL/ -o spectra.png (cairo, linked into npgc only). */
int npgc_plot(int argc, char **argv);
/* tune.c: npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/. */
int npgc_tune(int argc, char **argv);
/* npgc_util.c: the usage of `cmd` (to stdout and 0 for --help, else to
 * stderr and 2), and of every command. */
int npgc_usage(const char *cmd, bool help);
void npgc_usage_all(FILE *out);
/* Print `msg` to stderr as an error: "error: msg", or as it is when it is
 * already a diagnostic at a program location ("file:line:col: error: ..."
 * and its source line, as a bind-time index error is). */
void npgc_error(const char *msg);
/* Numbers and options are parsed by npg.h's npg_args_* / npg_parse_*, the
 * parser the applications use too. The problem the parser kept, with a
 * pointer to `npgc CMD --help`; 2. */
int npgc_args_error(const NpgArgs *a, const char *cmd);
/* One positional argument too many: "more than one WHAT given ('FIRST' and 'this')". */
void npgc_args_extra(NpgArgs *a, const char *what, const char *first);
/* "npgc CMD: missing WHAT" and a pointer to the usage; 2. */
int npgc_missing(const char *cmd, const char *what);
/* BYTES with an optional suffix k, M, G, T (powers of 1000). */
bool npgc_parse_bytes(const char *s, size_t *out);
/* --reduce STAGE:interp|galerkin (DESIGN §12; npgc train and tune): STAGE
 * added to o->interp_stage or o->galerkin_stage (copies, freed by
 * npgc_free_reduce). false when it is neither form, or out of memory. */
bool npgc_parse_reduce(NpgTrainOptions *o, const char *s);
void npgc_free_reduce(NpgTrainOptions *o);
/* mkdir -p of the parent of `path` (and `path` itself with `self`);
 * -1 after printing which directory could not be made. */
int npgc_make_parents(const char *path, bool self);
/* Two paths naming one file (same device and inode). */
bool npgc_same_file(const char *a, const char *b);
/* `path` would be written inside directory `dir`. */
bool npgc_inside(const char *path, const char *dir);
/* `path` names `dir` or something under it at any depth, neither needing to
 * exist (outputs not written yet): compared as absolute paths with '.',
 * '..' and repeated '/' resolved by their text (symbolic links are not). */
bool npgc_under(const char *path, const char *dir);
/* Before loading MODEL/: the arguments swapped (a model given where the
 * data is, the data where the model is) or a data folder given as a model
 * are said as such, not as "MODEL/manifest: cannot open". `data` may be
 * NULL; `data_role` names it in the usage ("TEST/", "IN/"). -1 after the
 * message. */
int npgc_check_model_and_data(const char *cmd, const char *model, const char *data, const char *data_role);
/* The one rule for every path npgc writes (issue 24): `out`, given with
 * option `opt` ("-o", "--png", "--spectra") of command `cmd`, is absent or
 * a regular file (a directory when `dir`), never a symbolic link, FIFO or
 * device node; it is none of the NULL-ended `inputs` (files and folders the
 * command reads); a file does not lie in a folder of `inputs`, a folder
 * not in a model of `inputs`; an NPGC_OUT_DIR holds no model (a model
 * folder is the model store's to check and replace). -1 after printing
 * which rule it breaks. */
typedef enum NpgcOutput {
  NPGC_OUT_FILE,            /* one file (-o FILE.c, --png, plot -o) */
  NPGC_OUT_DIR,             /* a folder of outputs (eval -o OUT/, --spectra DIR) */
  NPGC_OUT_MODEL,           /* a model folder (train and tune -o MODEL/) */
} NpgcOutput;
int npgc_check_output(const char *cmd, const char *opt, const char *out, NpgcOutput kind, const char *const *inputs);
/* The temporary name a file output is written to ("<out>.tmp.<pid>"), and
 * its rename over `out` when `rc` is 0 (else its removal); the rc. */
void npgc_tmp_path(char *buf, size_t n, const char *out);
int npgc_commit(const char *cmd, const char *tmp, const char *out, int rc);

#endif
