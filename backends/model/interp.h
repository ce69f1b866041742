/* interp.h — interpolated stages (DESIGN §12): empirical interpolation of a
 * stage whose every operator is diagonal (lower_interp_eligible), instead of
 * its Galerkin reduction.
 *
 * Galerkin reduces y = Σ_t Π_k diag(d_{t,k})^{r_k} q_t as Σ_t Π (BᵀD B)^r Bᵀq:
 * exact only when the basis is invariant under the diagonal operators. An
 * interpolated stage instead evaluates its formula exactly at k ≥ m selected
 * entries P of y (Q-DEIM: the first m by QR with column pivoting of Bᵀ,
 * Drmač & Gugercin 2016; the rest drawn from the leverage distribution
 * ‖B[e,:]‖²/m with least-squares weights W, Cohen & Migliorati 2017 —
 * oversampled "gappy POD", interp_train.c says why weighted) and takes the
 * weighted least-squares coordinates
 *
 *     ŷ = (W P B)⁺ W (P y),   ‖y − B ŷ‖² ≤ ‖r‖² + ‖(W P B)⁺‖₂² ‖W P r‖²,  r = y − B Bᵀ y
 *
 * plus the error of its inputs through the formula. (W P B)⁺ W (m × k) is
 * formed once at training (QR of W P B, R⁻¹ Qᵀ W) and stored.
 *
 * At entry P_s the formula reads a few entries of named quantities: the
 * tensor builders say exactly which (the same streams pre-multiplication
 * reads), with every coefficient a number (params are fixed at training).
 * Training keeps those entries as a table of monomials; the reduced
 * evaluator lifts only the entries the table reads (one row of the input's
 * basis each: B_x[e,:] x̂), evaluates the monomials, applies the diagonal
 * powers entry by entry and solves the small least-squares problem. Cost
 * O(k m + reads · m_input + monomials) per stage, nothing of order N unless
 * one selected entry itself reads O(N) entries (a sum over a dim).
 */
#ifndef NPG_INTERP_H
#define NPG_INTERP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>
#include <stdint.h>

#include "model.h"
#include "model_store.h"

/* One monomial of the formula at a selected entry: coef · Π read values,
 * added into factor `factor` (0: the numerator q_t; o + 1: the diagonal of
 * operator o) of term `term` at selected entry `slot`. */
typedef struct RInterpMono {
  int term, factor;
  long slot;
  double coef;
  int nin;
  long read[RT_MAX_IN];     /* indices into RInterp.read_q/read_e */
} RInterpMono;

typedef struct RInterp {
  long k;                   /* entries selected, m <= k <= n */
  long m;                   /* the stage's basis size when trained */
  long *rows;               /* k flat entries of the stage */
  double *pinv;             /* m x k row-major: the fit (W P B)⁺ W */
  double pinv_norm;         /* ‖(W P B)⁺‖₂: the factor of the error bound */
  double *weight;           /* k least-squares weights W (training only: not saved, NULL once loaded) */
  long nreads;
  int *read_q;              /* quantity (Program.quantities) of each entry lifted */
  long *read_e;             /* its flat entry */
  long nmono;
  RInterpMono *mono;
  /* the monomials packed for interp_eval (interp_pack), in runs that share an accumulator
   * (factor_base(term) + factor)·k + slot: per run its accumulator and the end of its
   * monomials; per monomial its coefficient and input count; the reads of every monomial in
   * turn (int32). Summed run by run in registers: accumulated in memory one by one, each
   * monomial waited for the previous one's store (a stage of 21,204 monomials spent 3/4 of
   * its time there), and RInterpMono's 16-read array made the table 5x larger. */
  long pk_nrun;
  /* the quantities read at a quarter of their entries or more are lifted whole, one dgemv
   * each (a ddot per entry cost more in calls than in work: 390 reads of m <= 13): their
   * quantity and offset in the lift scratch, whose size is pk_lift; per read its place in
   * the scratch, or -1 for a ddot of its basis row */
  int pk_nwhole;
  int *pk_whole_q;
  long *pk_whole_off, pk_lift, *pk_src;
  /* the other quantities read: their read rows of the basis gathered into one matrix each
   * (pk_gather_rows[g] rows of m, at pk_gather_B + pk_gather_at[g]), one dgemv each into the
   * scratch at pk_gather_off[g] (a ddot per read cost 40 µs a step in calls on 287 reads) */
  int pk_ngather;
  int *pk_gather_q;
  long *pk_gather_rows, *pk_gather_off, *pk_gather_at;
  double *pk_gather_B;
  long *pk_run_acc, *pk_run_end;
  double *pk_coef;
  unsigned char *pk_nin;
  int32_t *pk_read;
  /* The error estimate's entries (interp_check, docs/estimates.md): a table of its own
   * (rows, reads, monomials, packed; m 0 and no fit), k entries drawn uniformly from those
   * the fit does not select; NULL: none (a model trained before it). Owned. */
  struct RInterp *check;
  double *brows;            /* in a check table: the stage basis's rows at the fit's entries, then at
                             * the check's own ((k_fit + k) x m_stage, row-major) */
  double *read_rows;        /* in a check table: per read, its quantity's basis row (Σ m_q, in read
                             * order), which interp_eval gathers from: a class read only there may be
                             * streamed (its basis dropped) */
} RInterp;

/* The check table's size: every entry the fit does not select up to this many, else this many
 * drawn (or the fit's k, or 2m, when larger). */
#define INTERP_CHECK_MIN 64

void interp_free(RInterp *ip);
/* Fill ip's packed table (pk_*) from ip->mono and ip->read_* for stage rs of m: 0, or -1 out
 * of memory. */
int interp_pack(const Model *m, const RStage *rs, RInterp *ip);

/* Why a stage is reduced the way it is (RStage.choice_reason points into
 * this table; the manifest records the index). */
enum {
  INTERP_FORCED,          /* --reduce STAGE:interp */
  INTERP_LOWER,           /* interpolation measured lower at the output */
  GALERKIN_LOWER,         /* Galerkin measured lower */
  TIE_INTERP,             /* a tie, interpolation cheaper */
  TIE_GALERKIN,           /* a tie, Galerkin cheaper */
  BOTH_FAIL,              /* both fail on the validation samples: Galerkin */
  TOL_INTERP,             /* npgc tune: both meet the tolerance, interpolation cheaper */
  TOL_GALERKIN,           /* npgc tune: both meet the tolerance, Galerkin cheaper */
  INTERP_NREASONS
};
extern const char *const interp_reasons[INTERP_NREASONS];

/* The lines "stage w: interpolated at k of n entries …; output error … by
 * Galerkin …, by interpolation …: reason" for every stage that is
 * interpolated or whose reduction training chose (report_training, verify). */
void interp_report(const Model *m, FILE *out);
/* The warnings of interp_report: a kept reduction that failed on a validation sample, or
 * whose output error there is over 100 %. */
void interp_report_warnings(const Model *m, FILE *out);

/* Where an interpolated formula is evaluated. */
typedef struct InterpAt {
  double *const *x; /* every quantity's reduced coordinates */
  double *work;     /* interp_work_size(rs) doubles */
  long sample;      /* named in messages; < 0: no sample of a set */
} InterpAt;
/* The reduced coordinates of stage `rs` (whose rs->interp is set) from the
 * coordinates at->x[q] of the quantities it reads, into y (m entries).
 * 0, or -1 with `err` naming the stage and the selected entry where the
 * formula is not finite (a diagonal zero under a negative power, a root of
 * a negative value). */
size_t interp_work_size(const RStage *rs);
int interp_eval(const Model *m, const RStage *rs, const InterpAt *at, double *y, Err *err);

/* The estimated error ‖y − B ŷ‖ of stage rs at the coordinates x (its own, x[rs->q], from the
 * evaluation): with ρ = y − B ŷ the formula's residual at the fit's k entries P and at the check
 * table's k_c entries E (drawn uniformly from the n − k others),
 *
 *     est² = ‖ρ_P‖² + (n − k)/k_c ‖ρ_E‖²,
 *
 * whose expectation over the draw of E is ‖y − B ŷ‖²; exact when E holds every other entry.
 * An interpolated stage's check is rs->interp->check; a Galerkin stage of diagonal operators
 * has rs->check, with no fit (k = 0, E drawn from all n entries). `work` holds
 * interp_check_work_size(rs) doubles. 0, or -1 with `err` (no check table, or the formula not
 * finite at an entry). */
typedef struct InterpCheck {
  double est;
  bool exact;
} InterpCheck;
size_t interp_check_work_size(const RStage *rs);
int interp_check(const Model *m, const RStage *rs, double *const *x, double *work, InterpCheck *out, Err *err);

/* The model's interpolated stages in `s` (model_save): an `interp` line
 * per stage and its arrays; the store's format raised to 2, which builds
 * that do not know interpolated stages refuse; and a `choice` line per
 * stage whose reduction training measured (format 1 when every one kept
 * Galerkin: a build that ignores the line evaluates the model the same).
 * Nothing for a model without them. -1 when out of memory. */
int interp_save(const Model *m, ModelStore *s);
/* The `interp` and `choice` lines of a loaded store: every one checked against the
 * layout (stage eligible, sizes, entries in range, tables consistent) and
 * its arrays read into rs->interp. 0, or -1 with `err` naming the file. */
int interp_load(Model *m, const ModelStore *s, const char *dir, Err *err);

#endif
