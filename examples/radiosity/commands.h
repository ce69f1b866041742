/* commands.h — the options of npg-radiosity and its subcommands: full (full.c) and the
 * reduced ones (demo.c). */
#ifndef RADIOSITY_COMMANDS_H
#define RADIOSITY_COMMANDS_H

#define RADIOSITY_MAX_BASIS 16

typedef struct Options {
  long faces;
  int frames, k, threads, checks, ss;
  const char *out;
  const char *vis_mode, *solver;
  int samples, cap, reps; /* training samples, basis cap per member, timing repetitions per frame */
  double energy;          /* PCA energy per member */
  int nbasis;             /* --basis NAME:cap=N,energy=E,center=on|off overrides, in the order given */
  char *basis_name[RADIOSITY_MAX_BASIS];    /* malloc'd (npg_parse_basis) */
  int basis_cap[RADIOSITY_MAX_BASIS];       /* -1: --cap */
  double basis_energy[RADIOSITY_MAX_BASIS]; /* -1: --energy */
  int basis_center[RADIOSITY_MAX_BASIS];    /* 1 on, 0 off, -1: centered (the default) */
  long mem_mb;            /* the trainer's memory for snapshots and cached samples */
  double structured_weight; /* --structured-weight: each structured design point's weight in the PCA
                               (npg_trainer_weight); 0 (default): balanced (design_structured_weight) */
  const char *model;      /* run: the model folder */
  const char *program;    /* formfactors.npg */
} Options;

/* full: both animations in full, the visibility modes and solvers timed, pictures, plots and
 * DIR/report.json. */
int cmd_full(const Options *o);
/* train: the design's samples streamed into a trainer, the model to DIR/MODEL and the
 * precomputation figures to DIR/train.json. */
int cmd_train(const Options *o);
/* run: both animations through a trained model and in full, timed per frame. */
int cmd_run(const Options *o);
/* demo: scene, training, both animations full and reduced, the error split and bounds,
 * pictures, arrays and DIR/report.json. */
int cmd_demo(const Options *o);

#endif
