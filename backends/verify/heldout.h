/* heldout.h — the auto-check's numerics (`npgc verify`, DESIGN §7): on
 * held-out samples, every quantity of the full evaluator against the reduced
 * one lifted to full space; the projection floor ‖y − BBᵀy‖/‖y‖ (the best any
 * method can do in that basis: Arvo's discretization error), the reduction's
 * own error, the online estimate against the true error, and the stage where
 * error grows most. The facade (compiler/api/verify.c) sets and evaluates
 * each sample in full and hands over its values; this measures.
 *
 *   Heldout *h = heldout_new(m, err, errlen);
 *   for each sample k: full[q] = the full values of quantity q (rc->n each),
 *     heldout_reduce(h, k, full)   inputs projected, the reduced model evaluated;
 *     heldout_measure(h, k, f, full)  the errors, floors and estimates summed;
 *   heldout_finish(h, S)           the means per quantity, the growth;
 *   heldout_free(h). */
#ifndef NPG_HELDOUT_H
#define NPG_HELDOUT_H

#include "estimate.h"
#include "full.h"
#include "reduced.h"

/* One quantity's figures, as npg.h's NpgVerifyRow (which the facade copies them to). */
typedef struct HeldoutRow {
  const char *name;
  const char *kind;         /* "input", "extern", or the stage kind */
  long m;                   /* basis size */
  bool output;
  double l2, floor, own;    /* means over samples: ‖y − Bŷ‖/‖y‖, ‖y − BBᵀy‖/‖y‖, their difference */
  double l2_max;            /* the worst sample's L2 error */
  long l2_max_sample;
  double linf, linf_floor;  /* the same in the max norm */
  bool streamed;            /* basis streamed in training: l2, own, l2_max, linf NaN; floors training's */
  double est, err;          /* the online estimate and the true absolute error, means (est NaN: none) */
  double eff_min, eff_max;  /* effectivity est / err over the samples with err > 0 */
  long est_samples;         /* samples with an estimate */
  bool est_bound;           /* every sample's estimate was a rigorous bound (EST_BOUND) */
} HeldoutRow;

typedef struct HeldoutSum HeldoutSum;
typedef struct Heldout {
  Model *m;
  Reduced *r;               /* the reduced evaluator, roots by Krylov where they converge (what users run) */
  HeldoutRow *rows;         /* m->nq rows, program order */
  const char *grows_at;     /* after heldout_finish: the stage where error grows most (NULL: none) */
  double growth;            /* by how much over the worst quantity it reads */
  HeldoutSum *sum;          /* per quantity: the sums over samples */
  double *y, *proj, *in_err;
  EstimateResult *est;
  struct ProductNorm **pn;  /* per class with a product K0: its norm, made at first use */
} Heldout;

/* The check of model `m`: NULL with the message in `err` (out of memory, or
 * the reduced evaluator's refusal). */
Heldout *heldout_new(Model *m, char *err, size_t errlen);
/* Sample k: its inputs projected from their full values full[q] and the
 * reduced model evaluated. 0, or -1 with reduced_error(h->r). */
int heldout_reduce(Heldout *h, long k, const double *const *full);
/* Sample k's errors, floors and estimates (after heldout_reduce) added to
 * the sums; full[q]: every quantity's full values (a streamed class's are
 * not read), `f` the full evaluator that computed them (a class's product
 * norm is made from its params). 0, or -1 with the message in `err` (its
 * first: `err` empty before the first sample). */
int heldout_measure(Heldout *h, long k, Full *f, const double *const *full, char *err, size_t errlen);
/* The rows' means over `samples` samples, and where error grows most. */
void heldout_finish(Heldout *h, long samples);
void heldout_free(Heldout *h);

#endif
