/* reduce_cmds.h — what the reduced-model commands share (reduce_cmds.c:
 * the options and train; reduce_use.c: eval, verify, bench). Private to
 * the driver. */
#ifndef NPGC_REDUCE_CMDS_H
#define NPGC_REDUCE_CMDS_H

#include <stdbool.h>

#include "npg.h"

/* The parsed command line of train, eval, verify and bench. */
typedef struct Common {
  const char *prog_path, *a, *b, *out;
  NpgOptions opt;
  NpgBackend backend; /* --jit (--cc), NPG_AUTO by default */
  int threads;        /* bench: BLAS threads (--threads, 1 by default) */
  bool exact;               /* verify: the exactness checks of DESIGN §4 */
  long exact_size;          /* their size of every dim (0: exact.c's defaults) */
  double tol;
  bool tol_set;
  const char *greedy;       /* train --greedy POOL/: the candidates of greedy training (DESIGN §16) */
  long budget;              /* train --budget N: its most training samples (0: no bound but the pool) */
  bool absolute;            /* train --absolute: greedy's --tol bounds the estimate itself, not estimate / ‖output‖ */
  long reps;                /* bench: passes over the samples */
  bool progress;            /* --progress: progress on stderr even when it is not a terminal */
  bool exact_roots;         /* eval, bench: roots by eigendecomposition, not Lanczos */
  NpgTrainOptions train;
  int nbasis;               /* --basis overrides */
  const char **basis_name;
  int *basis_cap;
  double *basis_energy;
  int *basis_center;
  const char **basis_product; /* product=OP, or NULL */
  const char *spectra;      /* train --spectra DIR */
  const char *params;       /* verify --params DIR: the params, when TEST/ holds only the samples */
  const char *sizes;        /* eval, verify, bench --sizes NAME=N,...: the model at smaller sizes */
  const char *valid;        /* train --valid DIR */
  const char *weights;      /* train --weights FILE.npy: one per sample of DATA/ */
  const char *png;          /* verify --png FILE: the rollout error against time */
  long steps, every;        /* --steps T --every K: rollouts of a program with state (DESIGN §15); steps < 0: none */
  NpgcNewton newton;        /* --newton-tol, --newton-max-iter, --newton-verbose: an implicit step's Newton */
  const char *jacobian[16]; /* eval --jacobian OUT:IN (repeatable): derivatives in reduced coordinates */
  int njacobian;
  const char *cmd;
} Common;

/* Seconds on the monotonic clock. */
double reduce_now(void);
/* PROG.npg compiled with the command's options; NULL after the message. */
NpgProgram *reduce_compile(Common *c);

/* reduce_use.c: npgc eval (reduced), verify, bench; the exit status. */
int cmd_eval_reduced(Common *c);
int cmd_verify(Common *c);
int cmd_bench(Common *c);
/* rollout_cmds.c: verify and bench with --steps (the trajectory, not one step). */
int cmd_verify_steps(Common *c);
int cmd_bench_steps(Common *c);

#endif
