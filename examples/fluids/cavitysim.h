/* cavitysim.h — npg-fluids cavity: paper §7.2 (Fig. 6, Table 1) on the
 * deforming cavity of cavity.h. Full training simulations compressing and
 * re-inflating one or two side chambers, streamed into npg's trainer
 * through npg.h; a test sequence not in the training set (one chamber
 * expanding while another stays compressed) run full and reduced side by
 * side, with marker particles through the reduced flow, VTK and PNG frames,
 * the reduced trajectory error per frame, and Table 1 in report.json. */
#ifndef FLUIDS_CAVITYSIM_H
#define FLUIDS_CAVITYSIM_H

#include <stddef.h>

#include "cavity.h"
#include "npg.h"
#include "projection.h"

#define CAVITY_MAX_WORKERS 64

typedef struct CavityOptions {
  const char *out;
  CavitySpec spec;
  int frames;       /* per run; 0: cavity_frames_for(cells) */
  int runs;         /* training runs (14; 0: the full test run only) */
  int particles, png_every, vtk_every, width;
  double dt, nu;    /* time step; viscosity mu = nu * the smallest cell's volume */
  int mf, mu, mg;   /* basis caps: fluxes, velocities (the whole shared class), geometry */
  double dtol;      /* rank tolerance of D̂ (red_constraints) */
  ProjectionMethod projection; /* of the full step (PROJ_AL_CHOLMOD) */
  int workers;      /* threads running the training runs (the online CPUs) */
  int train_threads; /* OpenBLAS's threads in npg_trainer_finish (0: `workers`) */
  int particle_threads; /* threads advecting the marker particles (the online CPUs) */
  int sample_every; /* every K-th frame of a training run is a sample (0: cavity_sample_every_for) */
  size_t buffer_bytes; /* bound on the samples queued by runs the trainer is not taking yet (2 GB) */
  NpgBackend backend; /* the trainer's full evaluator (NPG_CC: replays 2-3x faster than libtcc's code) */
  int single_advection; /* the reduced step's advection skew parts in single precision (red_single_advection; 0) */
} CavityOptions;

/* What the training runs did. */
typedef struct CavityTraining {
  int workers;          /* threads that ran them (o->workers, at most o->runs) */
  double seconds;       /* wall time of all the runs, solvers' set-up included */
  double seconds_runs;  /* the runs' own steps, summed over the runs */
  double min_quality;   /* over every frame of every run */
} CavityTraining;

void cavity_options_default(CavityOptions *o);
/* The deformation of training run r (0 .. 13) or of the test (r = -1) at
 * frame t of T: side scales sigma[3]. */
void cavity_schedule(int r, int t, int T, double sigma[CAVITY_SIDES]);
/* The positions g of run r (-1: the test) at frame t of T (cavity_schedule, then
 * cavity_deform); the time cavity_deform takes is added to *seconds. 0, or -1 with `err`. */
int cavity_deform_at(const Cavity *cv, int r, int t, int T, double *g, double *seconds, char *err, size_t errlen);
/* Frames per run for a mesh of `cells` cells: 100 at 1,000 cells, growing
 * as the cells' edge (cells^(-1/3)) shrinks, so a frame's deformation moves
 * a vertex a similar fraction of its cells' size: at 17,300 cells 100 frames
 * diverge and 260 do not (README). */
int cavity_frames_for(int cells);
/* The default sample stride for runs of `frames` frames: at most
 * CAVITY_SAMPLES_PER_RUN samples per run. The frames per run grow with the
 * mesh for the step's stability, not for what the bases need: at 5,356
 * cells every 2nd and every 4th frame gave the same errors as every frame
 * to 3 % (README), while the trainer's Gram and eigen costs grow as S^2
 * and S^3. 1 up to 120 frames, 3 at 260, 4 at 450. */
#define CAVITY_SAMPLES_PER_RUN 120
int cavity_sample_every_for(int frames);
/* The o->runs training runs of o->frames frames each (o->frames > 0) on
 * the mesh of `cv`, every o->sample_every-th frame added to `tr`: run 1's
 * samples, then run 2's, ..., whatever o->workers is, so the trainer gets
 * the same samples in the same order as with one worker (each run's
 * simulation does not depend on the thread that runs it). With more than
 * one worker OpenBLAS runs one thread meanwhile (put back after), and the
 * samples of the runs after the oldest unfinished one wait in memory, up to
 * o->buffer_bytes (plus one sample per worker). 0, or -1 when a run failed
 * or the trainer refused a sample (said on stderr with the run's number;
 * the other runs stop at their next frame). */
int cavity_train(const Cavity *cv, const CavityOptions *o, double mu, NpgTrainer *tr, CavityTraining *out);
int cavity_run(const CavityOptions *o);

#endif
