/* train.h — training a model (DESIGN §5; paper §8.2–§8.3): snapshots of
 * every stage through the full evaluator, one PCA basis per class, every
 * tensor pre-multiplied by the bases, externs fitted. */
#ifndef NPG_TRAIN_H
#define NPG_TRAIN_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "full.h"
#include "model.h"
#include "npg.h"

typedef struct PcaMember PcaMember;

/* ---------------------------------------------------------------- training (train.c) */

/* Training's options: the user's NpgTrainOptions (npg.h), the one options type, read as given
 * (cap, energy, joint, uncentered, mem, progress, the basis overrides, the forced reductions,
 * valid_holdout, keep_bases, the rollouts), and the few things the facade derives from it or
 * from the trainer's records, or that training's own callers set and the user never does.
 * Training never writes through `user`: where it trains with other values (the hold-out's
 * retraining, a tune set's truncations, the facade's memory left after the records) it points a
 * copy's `user` at a changed copy of the NpgTrainOptions. */
typedef struct TrainOptions {
  const NpgTrainOptions *user; /* the options as given, read as they are (never NULL) */
  bool dist;                /* over the ranks of dist.h (after dist_start; NpgTrainOptions.mpi once the
                               facade started them): rank r takes the samples k ≡ r (mod ranks) and every
                               ranks-th row of each tensor; every rank ends with the same model. Out of
                               core (ooc.c), rank r takes its share of the row passes instead. False
                               where one rank trains alone (a tune set's trials) */
  const char *shared_prefix; /* out of core over ranks: the basis files all ranks map are named
                               PREFIX.ooc.XXXXXX (unlinked once every rank has opened them), so
                               PREFIX must be on a filesystem every rank sees (the model's path;
                               NULL: $TMPDIR/npg, or /tmp/npg) */
  /* validation samples (same params; the facade's from valid_count, valid_set, valid_user, or
   * the samples held out by valid_holdout): every eligible stage neither user->interp_stage nor
   * user->galerkin_stage names is reduced both ways and the lower output error kept
   * (tune_choose_reductions); NULL: Galerkin */
  const struct SampleSource *valid;
  const double *weights;    /* per sample (src->count, each > 0; the trainer's npg_trainer_weight): the PCA
                               minimizes Σ_k w_k ‖x_k − BBᵀx_k‖² (pca_weigh), weight 2 a sample taken
                               twice; NULL: every weight 1. The floors and reports stay per sample, unweighted */
  bool stream;              /* drop the streamable bases (model_class_streamable) once used (issue 30;
                               npg_trainer's always); false: every basis kept (the old layout; tests) */
  bool inputs_whole;        /* greedy training: an input's members default to energy 1 (every direction their
                               samples span; the program's `basis` and --basis still set it) */
  bool full_rank;           /* complete every basis to its class's full dimension (convergence tests) */
  bool choose_strict;       /* ties keep Galerkin: the choice never raises the error on `valid` (npgc tune) */
  struct SnapshotCache *cache; /* the snapshots of earlier trainings (greedy training): the samples it holds, by
                               their hashes, taken from it, not evaluated again, and this training's left in it
                               (snapshot_cache.c); with a hold-out as well, over ranks each rank's share; unused
                               out of core and by the method of snapshots (the samples replayed). NULL: none */
} TrainOptions;

/* ---------------------------------------------------------------- snapshots kept between trainings (snapshot_cache.c) */

/* A training's snapshots kept for the next one on the same samples and more (greedy training,
 * issue 41, retrains after each sample it adds): every member's values at each sample and which
 * diagonal operators stayed SPD, what training's first pass takes from a full evaluation. Given
 * as TrainOptions.cache, a training takes the snapshots of the samples it holds (a sample held when
 * its inputs and externs hash as one it holds, the program, params and layout the same: whatever
 * its position, so the automatic hold-out's trainings share them), evaluates the others (and its
 * last sample: the evaluator ends on the values it ended on without the cache), and leaves all of
 * its own in it; the model is the one replaying them gives, bit for bit. Over MPI ranks each rank
 * holds its share's. The snapshots stay in memory between trainings (the bytes training's
 * in-memory route takes, and the held-out samples' until the next training). */
typedef struct SnapshotCache SnapshotCache;
SnapshotCache *snapshot_cache_new(void); /* empty; NULL when out of memory */
long snapshot_cache_samples(const SnapshotCache *c); /* the samples it holds */
void snapshot_cache_free(SnapshotCache *c);
/* Every quantity's values (m's order, each its class's n entries) at the sample set in f, from the
 * column holding it, into out: false when the cache (NULL: none) does not hold it under m's program,
 * layout and f's params, or a quantity is no member of its class (the validation samples of the
 * automatic hold-out: held from the retraining before). */
bool snapshot_cache_values(SnapshotCache *c, Full *f, const Model *m, double *out);

/* Whether training keeps class c's basis whatever the rule (no opt->stream, or --keep-bases
 * names it; train.c). */
bool train_keeps_basis(const Model *m, const TrainOptions *opt, int c);

/* Draws per basis vector of an interpolated stage when not given
 * (bench/interp.md, k = X·m draws, fewer distinct entries): weighted, at 8
 * the output is within 1.02x of its floor in the small-motion gravity rows
 * and at 32 too, but at 32 springs reach their floor (1.00x against 1.07x),
 * Lennard-Jones and large-motion gravity gain 3-18 % more, and the reduced
 * evaluation still takes 0.2-0.5x the Galerkin one's time at 64 bodies. */
#define TRAIN_INTERP_OVERSAMPLE 32.0

/* The source of samples: sets every input and extern of sample k. */
typedef struct SampleSource {
  long count;
  void *user;
  int (*set)(void *user, Full *f, long k);
  /* Optional: as `set`, for a restricted evaluation (full_eval_demand) by
   * `d` after demand_propagate: only the entries of externs `d` demands need
   * be given (full_extern_values), the others may keep stale values. */
  int (*set_part)(void *user, Full *f, long k, const Demand *d);
  /* Optional, for a source that holds only this rank's samples (over MPI
   * ranks): make every sample available to `set` and `set_part` on every
   * rank (a collective call). Out of core over ranks a rank's passes
   * evaluate every sample; without it the source must hold them all. */
  int (*share)(void *user, Err *err);
} SampleSource;

/* The online estimate's tables (estimate.h, estimate_train.c): per eligible term R of the QR of
 * its projected residual columns and, for an inverse, the σ_min ratio of the training samples;
 * per input its training range. Needs the bases (before train_drop_bases); over ranks
 * (opt->dist) a collective call, each rank measuring the samples it holds. 0, or -1 with `err`. */
int train_estimates(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err);

/* Train: snapshots of every stage and joining numerator on every sample,
 * one basis per class, every tensor pre-multiplied, externs fitted. `f` is
 * bound to the training params. The weights (opt->weights) are divided by
 * the largest (over every rank): only their ratios count; the params'
 * hashes recorded (Model.param_hashes), and a param that a validation
 * sample changed refused. With
 * opt->user->valid_holdout, samples held out of training to choose the
 * reductions on (and with the automatic hold-out, the model trained again
 * on every sample with the choice fixed). NULL with `err` on failure. */
Model *train_model(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err);
/* "name=<hex> …": the hashes of the values of every param bound in `f`, as a model records them
 * (Model.param_hashes; malloc'd; NULL when out of memory). */
char *train_param_hashes(const Full *f);
/* After `before` = train_param_hashes(f): the name of the first param whose value changed since (a
 * sample function that set one: validation and test samples hold inputs and externs only), NULL if
 * none; *oom on a failed allocation. */
const char *train_param_changed(const Full *f, const char *before, bool *oom);
/* The names the options give (--basis, --keep-bases, --reduce STAGE:interp|galerkin) checked
 * against the program before any sample: each names a quantity, class or stage of `prog`, and a
 * stage forced to interpolation is eligible. Training checks the same again; this lets a
 * trainer refuse them when it is made instead of after every sample was streamed (issue 38).
 * 0, or -1 with `err` in the words of npgc train's options. */
int train_check_names(Program *prog, const TrainOptions *opt, Err *err);

/* ---------------------------------------------------------------- the tune sample set (train_set.c) */

/* Training for a search over basis sizes (npgc tune): the snapshots (in
 * memory) and every member's ordered basis at its cap (pca_basis: for a
 * centered member [μ, U_c,1, …]) once; then models whose members keep the
 * first cap[c] vectors of theirs — the basis that cap would give at energy
 * 1 — merged and re-pre-multiplied, with no new snapshot or SVD. */
typedef struct TrainSet TrainSet;
/* `opt` as for train_model (its energy should be 1: the caps decide); NULL
 * with `err`. `f` and `src` must outlive the set. */
TrainSet *train_set_new(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err);
int train_set_classes(const TrainSet *ts);
/* The program and the evaluator the set was made with. */
Program *train_set_program(const TrainSet *ts);
Full *train_set_full(const TrainSet *ts);
/* The most vectors a member of class `c` has: caps above it change nothing. */
int train_set_max_cap(const TrainSet *ts, int c);
/* The model whose members of class c keep min(cap[c], what they have)
 * vectors. NULL with `err`. */
Model *train_set_model(TrainSet *ts, const int *cap, Err *err);
/* The online estimate's tables of a truncation `m` (train_estimates, on
 * the set's training samples), then its streamed classes (issue 30,
 * train_model's rule: model_class_streamable, opt->stream, opt->user->keep_bases),
 * its reductions chosen: marked, their floors measured on the set's training
 * snapshots, their bases dropped. 0, or -1 with `err`. */
int train_set_stream(TrainSet *ts, Model *m, const TrainOptions *opt, Err *err);
void train_set_free(TrainSet *ts);

/* ---------------------------------------------------------------- steps shared with out of core (train.c) */

/* The steps of training that the out-of-core bases (ooc.c) share. */
/* Set and evaluate training sample k. */
int train_eval_sample(const SampleSource *src, Full *f, long k, Err *err);

/* Mark every diagonal operator SPD (until train_check_spd sees otherwise). */
void train_mark_spd(Model *m);
/* The class basis from its members' snapshots X[i] (n x S column-major):
 * one PCA per member, concatenated and re-orthonormalized; `pre` (over MPI
 * ranks): the members' PCAs already made, taken over, or NULL. */
int train_member_bases(RClass *rc, long S, double *const *X, const double *w, PcaMember *pre, Err *err);
/* One direction for a class whose every snapshot is zero; with `full_rank`
 * the basis completed to the class's dimension. */
int train_complete_basis(RClass *rc, bool full_rank, Err *err);
/* Class rc's basis orthonormal in the inner product of its product op
 * (rc->product: `basis u: product K0`, --basis u:product=K0; product.c): BᵀK0B = I, rc->D =
 * K0 B; K0 read from `f` (params bound); sn: the class's snapshots. */
typedef struct ClassSnapshots {
  long S;                   /* samples */
  double *const *X;         /* X[i]: member i's snapshots, n x S */
  const double *w;          /* the samples' weights, or NULL */
} ClassSnapshots;
int train_product_basis(Model *m, Full *f, RClass *rc, const ClassSnapshots *sn, bool full_rank, Err *err);
/* The norm of class rc's product, ‖v‖_K0 = √(vᵀK0v) (v: rc->n entries), for measuring errors in
 * it (verify: the true error next to the estimate, which is in that norm). K0 read from `f`
 * (params bound); NULL with `err` (as train_product_basis's messages). */
typedef struct ProductNorm ProductNorm;
ProductNorm *product_norm_new(Model *m, Full *f, const RClass *rc, Err *err);
double product_norm(const ProductNorm *p, const double *v);
void product_norm_free(ProductNorm *p);

/* ---------------------------------------------------------------- interpolated stages (interp_train.c) */

/* Training's step 3b (train.c), on `m` pre-multiplied: the stages forced to
 * interpolation (the program's `reduce interp`, opt->user->interp_stage) made
 * interpolated, the names of opt->user->galerkin_stage checked, and with
 * opt->valid every other eligible stage chosen (tune_choose_reductions).
 * 0, or -1 with `err`. */
int train_interpolate_stages(Model *m, Full *f, const TrainOptions *opt, Err *err);

/* Make stage number `stage` of `m` (bases built, `f` bound as for
 * pre-multiplication) interpolated: its entries selected from its class
 * basis, (PB)⁺ formed, its formula at those entries read from the tensor
 * builders into m->stages[stage].interp (replacing any). 0, or -1 with
 * `err` (the stage not eligible, the selected rows rank deficient, out of
 * memory). */
int interp_train_stage(Model *m, Full *f, int stage, double oversample, Err *err);
/* The estimate's check table of Galerkin stage `stage` of diagonal operators (lower_interp_eligible,
 * not interpolated): k_c entries drawn from all n, their monomials and basis rows, into
 * m->stages[stage].check (interp_check). 0, or -1 with `err`. */
int interp_train_check(Model *m, Full *f, int stage, Err *err);
/* interp_train_check's table without the bases' rows, for a stage whose class or reads have no basis
 * in memory (out of core: estimate_stream.c): entries and monomials made, brows zero where the
 * stage's class has no basis, read_rows NULL, not packed (interp_pack), into *check (the caller's
 * to free, interp_free). 0, or -1 with `err` (*check NULL). */
int interp_train_check_rows(Model *m, Full *f, int stage, struct RInterp **check, Err *err);

/* The stages of `prog` whose reduction is open to a choice: eligible for
 * interpolation and forced neither by the program (`reduce interp|galerkin`)
 * nor by the named lists; 0 for a program with externs (their learned model
 * is fitted after the choice, so it cannot be validated). Training holds
 * samples out to choose only when there is one (TRAIN_HOLDOUT_*): a program
 * without one trains as before. */
int interp_open_choices(const Program *prog, int ninterp, const char *const *interp, int ngalerkin,
                        const char *const *galerkin);

/* The automatic hold-out (NpgTrainOptions.valid_holdout < 0, the default):
 * every TRAIN_HOLDOUT_STRIDE-th sample validates the choice when the program
 * has an open choice and at least TRAIN_HOLDOUT_MIN samples are given (so at
 * least 3 validate); then the model is trained again on every sample with
 * the choice fixed (interp_train_with_choice; README "Interpolated stages"
 * says why). */
#define TRAIN_HOLDOUT_STRIDE 10
#define TRAIN_HOLDOUT_MIN 30

/* The model trained on every sample of `all` with `opt`, each stage whose
 * reduction `chosen` (trained on part of them, validated on the rest) chose
 * forced the way it chose, its measured errors and reason kept for the
 * reports. Frees `chosen`. NULL with `err`. */
Model *interp_train_with_choice(Program *prog, Full *f, const SampleSource *all, const TrainOptions *opt,
                                Model *chosen, Err *err);

/* ---------------------------------------------------------------- out-of-core bases (ooc.c) */

/* Whether the member bases of `m` at their caps (Σ n × cap doubles) exceed
 * opt->user->mem, so that training must keep them out of core; with sample weights
 * (opt->weights), also when the snapshots of the S samples exceed it (the
 * method of snapshots does not take weights). */
bool ooc_needed(const Model *m, const TrainOptions *opt, long S);
/* Bytes of every member's snapshots of S samples (train.c). */
size_t train_snapshot_bytes(const Model *m, long S);

/* ---------------------------------------------------------------- basis sizes by error (tune.c) */

typedef struct TuneTrial {
  int *cap;                 /* per class: its members' cap */
  long *m;                  /* per class: the basis size it gave */
  double cost;              /* reduced multiply-adds (ir/cost.c) */
  double err;               /* the worst output's mean relative L2 error on the validation samples */
  bool uniform;             /* one cap for every class */
  char *interp;             /* the stages interpolated at these caps, comma-separated ("" none) */
} TuneTrial;

typedef struct TuneResult {
  int nclasses;
  int ntrials;
  TuneTrial *trials;        /* in the order tried */
  int chosen;               /* the trial chosen, or -1 when the tolerance cannot be met */
  int *best_cap;            /* the caps chosen (when unmet: the largest tried) */
  int limiting;             /* when unmet: the class whose projection floor is the largest */
  double limiting_floor;
  bool limiting_saturated;  /* its members have no more directions in the training samples */
  Model *model;             /* the chosen trial's model, its reductions chosen (NULL when unmet); owned
                               until taken (set to NULL) */
} TuneResult;

/* What tune_search looks for: every output's mean relative L2 error on the
 * samples of `valid` at most `tol`, with caps at most `max_cap`. */
typedef struct TuneGoal {
  const SampleSource *valid;
  double tol;
  int max_cap;
} TuneGoal;
/* Choose every class's cap so that every output's mean relative L2 error
 * on the samples of goal->valid (evaluated in full by the set's `f`, bound
 * to the training params) is at most goal->tol at the least reduced cost,
 * caps at most goal->max_cap: uniform caps 1, 2, … up to the first that meets `tol`, then
 * each class bisected down with the others fixed, the costliest first. At
 * every candidate, the stages `opt` forces (interp_stage, the program's
 * `reduce`) reduced so, every other eligible stage both ways and the lower
 * error kept, the cheaper when both meet `tol` (DESIGN §12; opt->user->ngalerkin
 * excludes stages; opt may be NULL). out->model: the chosen trial's model.
 * 0 (`out` filled; out->chosen < 0 when `tol` cannot be met, naming the
 * limiting class), or -1 with `err`. tune_result_free() either way. */
int tune_search(TrainSet *ts, const TuneGoal *goal, const TrainOptions *opt, TuneResult *out, Err *err);
void tune_result_free(TuneResult *r);

/* Training's choice per stage (DESIGN §12): for every stage of `m` (bases
 * and tensors made, `f` bound to the training params) that is eligible and
 * not forced either way by `opt`, in evaluation order, the worst output's
 * mean relative L2 error on the samples of `valid` with the stage reduced
 * by Galerkin and interpolated (the choices of the stages before it made);
 * the lower kept, a tie (within 2 %, or both under 1e-12) going to the fewer
 * multiply-adds. A
 * configuration that fails on a validation sample counts as an infinite
 * error. The errors and the reason are left in rs->choice_err and
 * rs->choice_reason (and on stderr with opt->user->progress). 0, or -1 with `err`. */
int tune_choose_reductions(Model *m, Full *f, const SampleSource *valid, const TrainOptions *opt, Err *err);

/* ---------------------------------------------------------------- reports (report.c) */

/* The training table: per class its sizes, per member kept / cap and the
 * energy lost; a warning for every member that hit its cap with more than
 * 1e-3 of its energy lost. */
void report_training(const Model *m, FILE *out);
/* Verification warnings from the mean relative errors `err[q]` and
 * projection floors `floor[q]` of every quantity: a stage whose error
 * exceeds 3× its floor (naming what it reads worst and the remedies), an
 * input whose floor exceeds `tol`. Returns how many were printed. */
int report_verify_warnings(const Model *m, const double *err, const double *floor, double tol, FILE *out);

/* ---------------------------------------------------------------- the method of snapshots (snapshots.c) */

/* The method of snapshots' split of a budget of `fit` samples: a held
 * block of *b samples and a batch of *q later ones (*q 0: all S held). */
void train_gram_blocks(long S, long fit, long *b, long *q);

/* ---------------------------------------------------------------- the progress bar (progress.c) */

/* A progress bar on stderr ("what [####    ] done/total"), when `on`. */
void progress_show(bool on, const char *what, long done, long total);

/* ---------------------------------------------------------------- bases from snapshots (pca.c) */

/* How a member's basis is cut from its snapshots (its options, RMember):
 * at most `cap` vectors, the fewest reaching `energy` (pca_choose);
 * `center`ed: the mean kept and the rest by the centered energy; weighted by
 * w (one per sample, NULL: every weight 1; pca_weigh). */
typedef struct PcaRule {
  int cap;
  double energy;
  bool center;
  const double *w;
} PcaRule;
/* One member's basis (DESIGN §5). */
struct PcaMember {
  double *U;                /* n x k row-major, orthonormal (malloc'd) */
  int k;
  double lost;              /* energy fraction lost: of the centered energy when centered */
  double *sv;               /* singular values (of X − μ1ᵀ when centered), descending, nsv (malloc'd) */
  long nsv;
};

/* The basis of one member, X n x S column-major (sample s at X + s*n), by
 * `rule`: uncentered, the leading left singular vectors (n x k row-major in
 * out->U, malloc'd); `center`ed, the orthonormalization
 * of [μ, U_c,1 … U_c,r] in that order, μ the snapshots' mean (always kept),
 * U_c the left singular vectors of X − μ1ᵀ, r the fewest reaching `energy`
 * of the centered energy, at most cap − 1 (a direction dependent on the
 * previous ones dropped). Weighted (rule->w not NULL, S positive weights): the PCA of pca_weigh's
 * snapshots, μ their weighted mean. 0, or -1 with `err` and nothing allocated. */
int pca_basis(long n, long S, const double *X, const PcaRule *rule, PcaMember *out, Err *err);
/* A member's basis freed (its U and sv), *p left empty: the free function of what pca_basis returns. */
void pca_member_free(PcaMember *p);
/* Weighted snapshots (TrainOptions.weights, w NULL: every weight 1): with `mu`, the mean
 * Σ_s w_s X_s / Σ_s w_s into mu and subtracted from every column (pca_mean's arithmetic when w
 * is NULL); then column s times √w_s. X n x S column-major, in place. The PCA of the result
 * minimizes Σ_s w_s ‖x_s − BBᵀx_s‖²: weight k is sample s taken k times. */
void pca_weigh(long n, long S, double *X, const double *w, double *mu);
/* A direction whose remainder after removing the previous ones is below
 * this fraction of its norm is dependent on them (pca_in_order; out of
 * core ooc_coefficients, through the R factor of A, by the same rule). */
#define PCA_DEPENDENT_TOL 1e-8
/* Merging member bases (pca_merge; out of core ooc_coefficients alike),
 * whose vectors are orthonormal and accurate to rounding: a vector whose
 * remainder after the previous ones is below this fraction is a repeat of
 * them. Below 1e-8, so that a direction a member resolves to 1e-12 is not
 * dropped (it costs a vector of its rounding at most). */
#define PCA_MERGE_TOL 1e-12
/* Blocks of columns side by side, in order: A[i] n x k[i] row-major, i < r. */
typedef struct PcaBlocks {
  int r;
  double *const *A;
  const int *k;
} PcaBlocks;
/* Gram–Schmidt (twice) of the columns of the blocks A_0 … A_{r-1} in that
 * order, dropping a column whose remainder is below 1e-8 of its norm: n x m
 * row-major whose first j columns span the first independent columns given. */
int pca_in_order(long n, PcaBlocks a, double **Q, int *m, Err *err);
/* The truncation rule, one for every route to a member's basis (the SVD
 * of pca_basis, the method of snapshots, out of core): how many of the
 * singular values s[0..K) (descending) a member keeps — the leading ones,
 * at most `cap`, the fewest whose energy left out, Σ_{i≥k} s_i², is at most
 * (1 − energy) of the total (summed from the smallest, so tolerances far
 * below ε of the total hold), none at the floor of what the values
 * resolve: a singular value at most 100 ε of the largest (rounding), and
 * with `gram` (the values are square roots of a Gram matrix's eigenvalues)
 * the energy left within its rounding (K ε of the total). */
long pca_choose(const double *s, long K, int cap, double energy, bool gram);
/* The eigenproblem of a Gram matrix when few eigenvectors are kept: every
 * eigenvalue of the symmetric S x S matrix G (its upper triangle read,
 * column-major with leading dimension S — a matrix stored whole may be in
 * either layout), ascending in lam[0..S) (the spectrum a model reports),
 * and the eigenvectors of the k largest in V (S x k column-major, largest
 * first: column j belongs to lam[S-1-j]). Through the tridiagonal form,
 * eigenvectors only for those k (dsytrd, dsterf, dstemr — dstebz and
 * dstein where it fails — dormtr), or by divide and conquer (dsyevd) when
 * k is over half of S. G is overwritten. 0, or LAPACK's info (-1 when out
 * of memory). */
int pca_top_eigen(long S, double *G, long k, double *lam, double *V);
/* Snapshots by blocks of rows (out of core, over ranks), their R factor
 * built as a tall-skinny QR (TSQR) instead of their Gram matrix, which
 * squares their condition number (issue 41): R (S x S column-major, upper
 * triangle; start from zeros) becomes the R of the QR of [R; B], B the
 * next `rows` rows of the snapshots (rows x S column-major, leading
 * dimension ldb, overwritten). LAPACK dtpqrt. 0, or LAPACK's info (-1 out
 * of memory). */
int pca_fold_rows(long S, double *R, long rows, double *B, long ldb);
/* The R of nr factors Rs[i] (each S x S, one after the other) stacked, in
 * that order (every rank folding the same factors gets the same R). */
int pca_fold_r(long S, int nr, const double *Rs, double *R);
/* The right singular vectors of the snapshots from their R factor (its
 * SVD, dgesdd): s[0..S) descending, *k kept by pca_choose (rule's cap and
 * energy), and W = V_k Σ_k⁻¹ (S x *k column-major; room for S x min(cap, S)),
 * so that X W holds the kept left singular vectors, exact to ε σ_max in
 * every direction. 0, or LAPACK's info (-1 out of memory). */
int pca_r_basis(long S, const double *R, const PcaRule *rule, double *s, double *W, long *k);
/* The Gram matrix G (S x S, either layout) of snapshots too large or too
 * small for their squares (issue 24: 1e200 or 1e-200 data), `big` their
 * largest |entry| (0: not known): what is wrong, else NULL. The Gram routes
 * (method of snapshots, out of core) refuse them; the in-memory PCA scales
 * them instead. */
const char *pca_gram_out_of_range(long S, const double *G, double big);
/* The fraction of a column's largest magnitude that its sign-deciding entry
 * reaches: 1/φ, not 1/2, since structured data (radiosity's symmetric rooms)
 * has entries of exactly half the largest, which rounding puts on either
 * side of a threshold of 1/2 by route (in memory or out of core). */
#define PCA_SIGN_FRACTION 0.6180339887498949
/* The basis sign convention: every column of B (n x m row-major) turned so
 * that its first entry of at least PCA_SIGN_FRACTION of its largest magnitude is positive
 * (every route to a basis — SVD, Gram matrix, out of core — ends with it,
 * so they give the same vectors, not just the same span). 0, or -1 when
 * out of memory. */
int pca_fix_signs(long n, long m, double *B);
/* The convention by blocks of rows (out of core): with `decide` false,
 * big[j] = max(big[j], |B[e, j]|) over the block; then, over the blocks in
 * order with `decide` true, sign[j] (0 until found) set from the first
 * entry of at least PCA_SIGN_FRACTION big[j]. */
void pca_sign_scan(long n, long m, const double *B, double *big, int *sign, bool decide);
/* mu[0..n) = the mean of the S columns of X (n x S column-major). */
void pca_mean(long n, long S, const double *X, double *mu);

/* Orthonormal basis of the span of the blocks [U_1 … U_r] (each n x k_i,
 * row-major, orthonormal columns in order): their columns interleaved — the first of
 * every U_i, then the second, … (a U_i out of columns skipped) — and
 * orthonormalized in that order as pca_in_order does, dropping one whose
 * remainder is below 1e-12 of its norm:
 * n x m row-major whose first columns span the first c of every U_i (the
 * basis caps of c give), so a smaller cap is a truncation (issue 41). */
int pca_merge(long n, PcaBlocks U, double **B, long *m, Err *err);

/* ---------------------------------------------------------------- pre-multiplication (premul.c) */

/* What premultiply forms of a tensor: its product with the output basis
 * By (ny x my row-major); only the rows r ≡ part (mod nparts) of the output
 * (a rank's share: the others left zero, so the sum of the parts over the
 * ranks is the whole, to rounding; the builder enumerates only those rows'
 * entries, so the work divides; nparts 0 or 1: every row); a last x ⊗ x
 * axis unpacked (one GEMM of full basis rows per batch, folded into packed
 * form) when the group has at least unpack_min_monos monomials, packed per
 * entry otherwise (0: 8; tests force each path). */
typedef struct PremulOut {
  const double *By;
  const double *Bcol;       /* a declared operator's column axis (NULL: By): B where By is a product's dual D = K0B */
  long ny, my;
  int part, nparts;
  int unpack_min_monos;
} PremulOut;
/* Pre-multiply one tensor group: stream the builder's entries, accumulate
 * outer products of basis rows per output block, finish each block with a
 * GEMM against the output basis. `t` sized by model_size_tensors; fills
 * t->data. `flops` (optional) accumulates the useful arithmetic (that of
 * the packed products). */
int premultiply(Model *m, Full *f, RTensor *t, const PremulOut *out, double *flops, Err *err);
/* A set of rows of a class (stream.c): a bit per row, and per 64 rows the
 * number held before them, so that a buffer of the held rows only, in
 * ascending order, is indexed by row_map_at. */
typedef struct RowMap {
  long n;                   /* rows of the class */
  uint64_t *bits;           /* (n + 63) / 64 words */
  long *before;             /* per word: rows held in the words before it */
  long count;               /* rows held */
} RowMap;
/* Whether row r is held (a NULL map holds every row). */
static inline bool row_map_has(const RowMap *map, long r) {
  return !map || (map->bits[r >> 6] >> (r & 63) & 1);
}
/* Row r's place in the buffer of the held rows (a NULL map: r itself). */
static inline long row_map_at(const RowMap *map, long r) {
  if (!map) return r;
  uint64_t below = map->bits[r >> 6] & ((UINT64_C(1) << (r & 63)) - 1);
  return map->before[r >> 6] + __builtin_popcountll(below);
}
/* One block of a tensor's pre-multiplication (issue 30): the output rows
 * [lo, hi) only, their sum added to t->data (allocated and zeroed by the
 * caller: the blocks' sums add up to the whole tensor), the output basis
 * `By` (ny x my) and the inputs' bases Bin[j] (t's distinct inputs, their
 * class's m columns) read through row maps (NULL: every row, at its
 * index). Every basis row the block's entries read must be held: one that
 * is not fails, naming the tensor. */
typedef struct PremulBlock {
  long lo, hi;
  const double *By;
  long ny, my;
  const RowMap *ymap;
  const double *Bin[RT_MAX_IN];
  const RowMap *inmap[RT_MAX_IN];
} PremulBlock;
int premultiply_block(Model *m, Full *f, RTensor *t, const PremulBlock *b, double *flops, Err *err);
/* Output keys (rows, or (row, col) pairs) pre-multiplied per block of t. */
long premul_keys_per_block(const RTensor *t);

/* ---------------------------------------------------------------- over ranks (dist_train.c) */

/* After every rank r filled the columns k ≡ r (mod N = dist_size()) of
 * every member's n x S column-major X[c][i]: all columns on every rank
 * (a class whose X[c] is NULL is skipped). 0, or -1 with `err` (every rank alike). */
int dist_gather_snapshots(Model *m, double ***X, long S, Err *err);
/* Every diagonal operator's SPD mark: SPD on every rank's samples. */
void dist_and_spd(Model *m);
/* Every member's PCA (pca_basis of X[c][i], n x S, with its options),
 * each made on one rank (the largest first, to the least loaded rank) and
 * broadcast: (*out)[c][i] on every rank, bit-identical to one process's.
 * 0, or -1 with `err` (the rank that failed; the others then wait for it
 * to end the job). dist_free_pcas frees what is left of it. */
int dist_member_pcas(Model *m, long S, double ***X, const double *w, PcaMember ***out, Err *err);
void dist_free_pcas(Model *m, PcaMember **pcas);

#endif
