/* train_steps.h — the steps of training shared by the files that make it:
 * train.c the pipeline, train_set.c the tune sample set, snapshots.c the
 * method of snapshots, joint.c the joint bases. Private to backends/train
 * (train.h is the interface): Snapshots and these steps are the
 * pipeline's own, not an API. */
#ifndef NPG_TRAIN_STEPS_H
#define NPG_TRAIN_STEPS_H

#include "train.h"

/* Every member's snapshots, or (method of snapshots) its basis. */
typedef struct Snapshots {
  long S;
  double ***X;      /* [class][member] n x S column-major (NULL: method of snapshots) */
  double ***U;      /* [class][member] its PCA basis, n x k row-major (method of snapshots) */
  int **k;          /* [class][member] its basis's vectors (method of snapshots) */
} Snapshots;
void train_free_snapshots(Model *m, Snapshots *sn);

/* The steps of train_model (train.c) the tune sample set (train_set.c)
 * runs too. The model's layout for the dims sample 0 binds, every member's
 * options set and the --basis names checked: NULL with `err`. */
Model *train_begin(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen);
/* Step 1: every member's snapshots in memory (sn->X), or, when they need
 * more than opt->mem, their bases by the method of snapshots (sn->U, sn->k;
 * *gram set). Marks which diagonal operators stay SPD. */
int train_take_snapshots(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, Snapshots *sn,
                         bool *gram, char *err, size_t errlen);
/* Step 3: the projections between classes and every tensor pre-multiplied. */
int train_premultiply_all(Model *m, Full *f, bool progress, bool dist, char *err, size_t errlen);
/* Step 4: with `externs` every extern's learned map from the snapshots
 * (or, `gram`, recomputed), with `floors` the streamed classes' training
 * floors, in one pass over the samples. */
int train_fit_externs(Model *m, Full *f, const SampleSource *src, const Snapshots *sn, bool gram, bool externs, bool floors,
                      bool progress, bool dist, char *err, size_t errlen);

/* Streamed bases (issue 30; train.c), shared with the tune sample set:
 * the classes streamed marked (true when some still need their training
 * floors), sample k's floors of their quantities added to the means over
 * S samples, and (step 5) their bases dropped. */
bool train_mark_streamed(Model *m, const TrainOptions *opt);
void train_take_floors(Model *m, Full *f, const Snapshots *sn, bool gram, long k, long S, double *proj, double *y);
void train_drop_bases(Model *m);

/* The method of snapshots (snapshots.c): every member's basis of `m` from
 * S x S Gram matrices, recomputing the samples of `src` in passes within
 * opt->mem; U[c][i] (n x kk[c][i] row-major, malloc'd) and kk[c][i] per
 * member, the member reports set, the SPD marks checked on every sample
 * (`tmp`: room for max(largest class, S) doubles). 0, or -1 with `err`. */
int train_snapshot_bases(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, double ***U, int **kk,
                         double *tmp, char *err, size_t errlen);

/* --merge joint (joint.c): class `rc`'s basis (rc->B, rc->m) and every
 * member's report from one PCA of its members' snapshots X[i] (n x S
 * column-major), each block scaled to unit norm. 0, or -1 with `err`. */
int train_joint_basis(RClass *rc, long S, double *const *X, char *err, size_t errlen);

#endif
