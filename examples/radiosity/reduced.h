/* reduced.h — the reduced radiosity of the scene through npg.h alone (paper §8–§9):
 * formfactors.npg compiled, its full evaluator bound to the scene (params tri, rho) with
 * the visibility extern given by a callback that ray-casts (visibility.h), training
 * streamed into an NpgTrainer over the design (design.h), and the run-time frame
 *     parameters -> g -> ĝ -> reduced chain (learned visibility, §8.3) -> b̂ -> b.
 *
 * A second reduced evaluator keeps the visibility given instead of learned
 * (npg_reduced_given_externs): the same chain fed the ray-cast v projected onto its
 * basis, which separates the error of the learned visibility (boundary data, Arvo) from
 * the rest. */
#ifndef RADIOSITY_REDUCED_H
#define RADIOSITY_REDUCED_H

#include <stddef.h>

#include "commands.h"
#include "npg.h"
#include "scene.h"
#include "visibility.h"

/* The reduced radiosity of one scene: program, evaluators, model (not the library's internal
 * Reduced of backends/model). */
typedef struct ReducedRadiosity {
  NpgProgram *prog;
  NpgFull *full;        /* the full evaluator training replays (params bound, v by callback) */
  Visibility *vis;      /* the callback's caster */
  NpgModel *model;
  NpgReduced *learned;  /* v from the learned map */
  NpgReduced *given;    /* v given (projected) */
  /* the model keeps v's basis as coefficients C of its training values (trained out of core, issue
   * 30: 25 M rows at the paper's size): the trainer kept to give v's coordinates Cᵀ(Xᵀv) from
   * its records (npg_trainer_dots); NULL when the model has v's basis */
  NpgTrainer *trainer;
  const double *vcoef;  /* C, S x m (the model's) */
  long vS, vm;
  double *dots, *vcoords; /* S, m */
  long V, F;
  double *g;            /* V x 3 scratch of the run-time frame */
  double ray_seconds;   /* in the visibility callback, over training */
  long ray_calls;
  char err[1024];       /* the callback's last error */
} ReducedRadiosity;

/* The time split of training (seconds). */
typedef struct TrainTimes {
  double samples;       /* npg_trainer_add over the design: scene placement, the full
                           program's first evaluation and the ray casting */
  double rays;          /* of which in the visibility callback */
  /* npg_trainer_finish's phases, as the library times them (npg_model_train_seconds) */
  double snapshots;     /* the passes over the cached samples */
  double pca;           /* the member bases */
  double premultiply;   /* every tensor pre-multiplied */
  double externs;       /* the learned visibility's fit */
  double finish;        /* npg_trainer_finish in all: the four phases and writing the model */
  double total;
} TrainTimes;

/* Compile `program` and bind the scene's tri and rho into a full evaluator whose
 * visibility extern calls a ray caster of k points per face on `threads` threads.
 * 0, or -1 with err. */
int reduced_open(ReducedRadiosity *r, const Scene *s, const char *program, int k, int threads, char *err, size_t errlen);
/* Train over the first `o->samples` points of the design, basis cap `o->cap` and PCA energy
 * `o->energy` per member but where o's --basis overrides say otherwise, snapshots in at
 * most `o->mem_mb` MB; the model to `model_dir` (NULL: not written). Moves the scene's g
 * and e. 0, or -1 with err. */
int reduced_train(ReducedRadiosity *r, Scene *s, const Options *o, const char *model_dir, TrainTimes *t, char *err,
                  size_t errlen);
/* Load a model trained for this scene instead (its dims checked). 0, or -1 with err. */
int reduced_load(ReducedRadiosity *r, const char *model_dir, char *err, size_t errlen);
/* The run-time frame: parameters p -> g -> ĝ, e -> ê, the reduced chain with the learned
 * visibility, b = B b̂ lifted into b (F values). `sample` names the frame in messages. */
int reduced_frame(ReducedRadiosity *r, const Scene *s, const SceneParams *p, long sample, double *b, char *err,
                  size_t errlen);
/* The same chain fed the visibility v (F x F, projected) instead of the learned one, at
 * vertex positions g and emission e. */
int reduced_frame_given(ReducedRadiosity *r, const double *g, const double *e, const double *v, long sample, double *b,
                        char *err, size_t errlen);
/* B Bᵀ b: the projection of b (F values) onto the basis of its class (discretization). */
int reduced_project_b(const ReducedRadiosity *r, const double *b, double *out);
void reduced_close(ReducedRadiosity *r);

#endif
