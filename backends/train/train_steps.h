/* train_steps.h — the steps of training shared by the files that make it:
 * train.c the pipeline, train_set.c the tune sample set, snapshots.c the
 * method of snapshots, joint.c the joint bases. Private to backends/train
 * (train.h is the interface): Snapshots and these steps are the
 * pipeline's own, not an API. */
#ifndef NPG_TRAIN_STEPS_H
#define NPG_TRAIN_STEPS_H

#include <time.h>

#include "scratch.h"
#include "train.h"

/* Every member's snapshots, or (method of snapshots) its basis. */
typedef struct Snapshots {
  long S;
  double ***X;      /* [class][member] n x S column-major (NULL: method of snapshots) */
  double ***U;      /* [class][member] its PCA basis, n x k row-major (method of snapshots) */
  int **k;          /* [class][member] its basis's vectors (method of snapshots) */
} Snapshots;
void train_free_snapshots(Model *m, Snapshots *sn);

/* The training context (DESIGN §5): what every step of train_model reads
 * and writes, one per training (the tune sample set keeps one for its
 * snapshots). A step is a function of it returning 0, or -1 with the
 * failure's message in the error record `err` (the first failure's: a
 * step that fails returns at once). */
typedef struct Train {
  Program *prog;
  Full *f;                  /* bound to the training params */
  const SampleSource *src;  /* the training samples */
  const TrainOptions *opt;
  Model *m;                 /* the model trained (train_begin makes it) */
  Snapshots sn;             /* step 1's */
  bool gram;                /* no snapshot is kept (the method of snapshots, out of core): later passes recompute */
  struct timespec clock[2]; /* the current phase's start, wall and CPU */
  Err *err;                 /* the error record */
  Scratch scratch;          /* the current step's (train_scratch), released after every step */
  bool sample0_set_only;    /* train_begin set sample 0 without evaluating it (opt->cache holds it) */
} Train;

/* `bytes` of zeroed scratch (the model layer's Scratch, scratch.h) that
 * lives until the step that asked for it ends (train_model releases it
 * after every step, whether the step failed or not, so a step frees none
 * of it by hand). NULL with "out of memory" in the error record. */
void *train_scratch(Train *t, size_t bytes);
void train_scratch_free(Train *t);

/* The steps of train_model (train.c) the tune sample set (train_set.c)
 * runs too. The model's layout for the dims sample 0 binds into t->m,
 * every member's options set and the --basis names checked. */
int train_begin(Train *t);
/* Step 1: every member's snapshots in memory (t->sn.X), or, when they need
 * more than opt->user->mem, their bases by the method of snapshots (t->sn.U,
 * t->sn.k; t->gram set). Marks which diagonal operators stay SPD. */
int train_take_snapshots(Train *t);
/* Step 3: the projections between classes and every tensor of t->m pre-multiplied. */
int train_premultiply_all(Train *t);
/* Step 4: with `externs` every extern's learned map from the snapshots
 * (or, t->gram, recomputed), with `floors` the streamed classes' training
 * floors, in one pass over the samples. */
int train_fit_externs(Train *t, bool externs, bool floors);

/* Streamed bases (issue 30; train.c), shared with the tune sample set:
 * the classes streamed marked (true when some still need their training
 * floors), sample k's floors of their quantities added to the means over
 * S samples, and (step 5) their bases dropped. */
bool train_mark_streamed(Model *m, const TrainOptions *opt);
void train_take_floors(const Train *t, long k, double *proj, double *y);
void train_drop_bases(Model *m);

/* The steps of one training sample, shared with the method of snapshots and out of core: */
/* Over ranks (t->opt->dist), the test hook of dist_fail_here at rank r's
 * first sample k == r: -1 with `err` saying so; 0 otherwise. */
int train_fail_hook(const Train *t, long k);
/* Unmark every diagonal operator whose diagonal is not positive in the
 * current evaluation of t->f (`tmp`: room for the largest class). */
int train_check_spd(Train *t, double *tmp);
/* Member `mb`'s value (a quantity, or an unnamed numerator) after an
 * evaluation of sample k into out[0..n); refused, naming where, when not finite. */
int train_member_value(Train *t, const RMember *mb, long k, long n, double *out);

/* Snapshots kept between trainings (snapshot_cache.c, TrainOptions.cache), found by the hashes of
 * the samples' inputs and externs. Whether the cache can serve t (one given). A training begins
 * (train_begin, sample 0 set): whether to leave sample 0 unevaluated, as the cache holds columns,
 * so the pass sets every sample to find them, then evaluates those it does not hold, sample 0 as
 * well (over ranks, one owned by another rank is never evaluated here: this one evaluates its own
 * share before the evaluator is read). */
bool snapshot_cache_usable(const Train *t);
bool snapshot_cache_begin(Train *t);
/* Before the in-memory pass (t->sn allocated for S samples): when the cache's program, params and
 * layout are t's, the snapshots of every sample of this process's share it holds (each set to
 * hash it) copied into t->sn.X and their SPD marks and-ed into spd[0..nspd) (FOR_DIAG_OPS order);
 * the samples taken (0: none, the cache emptied). Whether sample k was taken. */
long snapshot_cache_take(Train *t, bool *spd, int nspd);
bool snapshot_cache_kept(const Train *t, long k);
/* Sample k, set in t->f and evaluated by the pass, noted with its own SPD marks spd[0..nspd). */
void snapshot_cache_note(Train *t, long k, const bool *spd, int nspd);
/* At the end of training: t->sn.X moved into the cache (t->sn.X[c][i] NULL) with the samples'
 * hashes and marks, the columns it did not take kept once more; out of core or by the method of
 * snapshots, the cache emptied. */
void snapshot_cache_keep(Train *t);

/* The method of snapshots (snapshots.c): every member's basis of t->m from
 * S x S Gram matrices, recomputing the samples of t->src in passes within
 * opt->user->mem; t->sn.U[c][i] (n x t->sn.k[c][i] row-major, malloc'd) per
 * member, the member reports set, the SPD marks checked on every sample
 * (`tmp`: room for max(largest class, S) doubles). */
int train_snapshot_bases(Train *t, double *tmp);

/* Out of core (ooc.c): every class basis of t->m (rc->B, rc->m, member reports, SPD marks) with
 * at most opt->user->mem bytes of snapshots, Gram matrices and basis rows in
 * memory, by passes over the samples that keep a block of rows of the
 * large classes (DESIGN §11); large bases are left in unnamed files and
 * memory-mapped read-only (rc->B_mapped). Unless a stage may yet be made
 * interpolated (opt->valid, interpolation asked for), the large classes'
 * bases are formed block by block (stream.c) and every tensor that reads
 * one is pre-multiplied here (t->data set; train_premultiply_all does the
 * others): a class the model drops (RClass.streamed) is never stored
 * (rc->B stays NULL, rc->m its size), one it keeps is mapped. The result is the
 * in-memory training's (pca_basis, pca_merge through their Gram route) up
 * to rounding. */
int ooc_bases(Train *t);

/* --merge joint (joint.c): class `rc`'s basis (rc->B, rc->m) and every
 * member's report from one PCA of its members' snapshots X[i] (n x S
 * column-major), each block scaled to unit norm. 0, or -1 with `err`. */
int train_joint_basis(RClass *rc, long S, double *const *X, Err *err);

#endif
