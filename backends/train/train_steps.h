/* train_steps.h — the steps of training shared by the files of
 * backends/train that make it (train.c the pipeline, snapshots.c the method
 * of snapshots, joint.c the joint bases); private to backends/train, train.h is the interface. */
#ifndef NPG_TRAIN_STEPS_H
#define NPG_TRAIN_STEPS_H

#include "train.h"

/* The method of snapshots (snapshots.c): every member's basis of `m` from
 * S x S Gram matrices, recomputing the samples of `src` in passes within
 * opt->mem; U[c][i] (n x kk[c][i] row-major, malloc'd) and kk[c][i] per
 * member, the member reports set, the SPD marks checked on every sample
 * (`tmp`: room for max(largest class, S) doubles). 0, or -1 with `err`. */
int snapshot_bases(Model *m, NpgFull *f, const SampleSource *src, const TrainOptions *opt, double ***U, int **kk,
                   double *tmp, char *err, size_t errlen);

/* --merge joint (joint.c): class `rc`'s basis (rc->B, rc->m) and every
 * member's report from one PCA of its members' snapshots X[i] (n x S
 * column-major), each block scaled to unit norm. 0, or -1 with `err`. */
int joint_basis(RClass *rc, long S, double *const *X, char *err, size_t errlen);

#endif
