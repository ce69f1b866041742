/* train.h — training a model (DESIGN §5; paper §8.2–§8.3): snapshots of
 * every stage through the full evaluator, one PCA basis per class, every
 * tensor pre-multiplied by the bases, externs fitted. */
#ifndef NPG_TRAIN_H
#define NPG_TRAIN_H

#include <stdbool.h>
#include <stddef.h>

#include "full.h"
#include "model.h"

/* ---------------------------------------------------------------- training (train.c) */

typedef struct TrainOptions {
  int cap;                  /* default cap per member (60) */
  double energy;            /* default energy fraction per member (0.999) */
  bool joint;               /* --merge joint */
  bool full_rank;           /* complete every basis to its class's full dimension (convergence tests) */
  size_t mem;               /* memory budget for snapshots, bytes */
  bool progress;            /* progress bars on stderr */
  /* per quantity overrides from the command line: "name:cap" or "name:energy" */
  int noverride;
  const char **override_name;
  int *override_cap;
  double *override_energy;
} TrainOptions;

/* The source of samples: sets every input and extern of sample k. */
typedef struct SampleSource {
  long count;
  void *user;
  int (*set)(void *user, NpgFull *f, long k);
} SampleSource;

/* Train: snapshots of every stage and joining numerator on every sample,
 * one basis per class, every tensor pre-multiplied, externs fitted. `f` is
 * bound to the training params. NULL with `err` on failure. */
Model *train_model(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen);

/* A progress bar on stderr ("what [####    ] done/total"), when `on`. */
void progress_show(bool on, const char *what, long done, long total);

/* PCA of one member: X is n x S column-major (sample s at X + s*n). Keeps
 * at most `cap` left singular vectors, the fewest reaching `energy`.
 * Returns n x k row-major in *U (malloc'd), k, and the captured fraction. */
int pca_member(long n, long S, const double *X, int cap, double energy, double **U, int *k, double *captured,
               char *err, size_t errlen);
/* Orthonormal basis of the span of [U_1 … U_r] (each n x k_i, row-major),
 * dropping dependent directions (σ < 1e-10 σ_max): n x m row-major. */
int pca_merge(long n, int r, double *const *U, const int *k, double **B, long *m, char *err, size_t errlen);

/* Pre-multiply one tensor group: stream the builder's entries, accumulate
 * outer products of basis rows per output block, finish each block with a
 * GEMM against the output basis. `t` sized by model_size_tensors; fills
 * t->data. `flops` (optional) accumulates the useful arithmetic (that of
 * the packed products). */
int premultiply(Model *m, NpgFull *f, RTensor *t, const double *By, long ny, long my, double *flops, char *err,
                size_t errlen);
/* The same, choosing the path for a last x ⊗ x axis: unpacked (one GEMM of
 * full basis rows per batch, folded into packed form) when the group has at
 * least unpack_min_monos monomials, packed per entry otherwise. premultiply
 * uses 8; tests force each path. */
int premultiply_unpacking(Model *m, NpgFull *f, RTensor *t, const double *By, long ny, long my, int unpack_min_monos,
                          double *flops, char *err, size_t errlen);
/* Output keys (rows, or (row, col) pairs) pre-multiplied per block of t. */
long premul_keys_per_block(const RTensor *t);

#endif
