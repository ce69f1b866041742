/* heldout.c — the auto-check's numerics on held-out samples (heldout.h,
 * DESIGN §7): per sample, every quantity's lifted reduced value against its
 * full value and the projection floor, and the online estimate against the
 * true error; their means per quantity. */
#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "heldout.h"
#include "train.h" /* the product norms */

struct HeldoutSum {
  double l2, linf, floor2, floorinf; /* sums over samples */
};

/* The worst mean error among the quantities stage `rs` reads (tensor
 * inputs, named numerators, an extern's inputs); NaN when one of them was
 * not measured (its basis streamed): then how much the stage adds is
 * unknown, and fmax would have ignored it (trial3). */
static double worst_input(const Model *m, const RStage *rs, const HeldoutRow *row) {
  double w = 0;
  bool unknown = false;
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    if (rt->named_q >= 0) w = fmax(w, row[rt->named_q].l2), unknown |= isnan(row[rt->named_q].l2);
    RTERM_FOR_TENSORS(rt, x)
      for (int j = 0; j < x->nin; j++) w = fmax(w, row[x->in_q[j]].l2), unknown |= isnan(row[x->in_q[j]].l2);
  }
  if (rs->st->kind == ST_EXTERN)
    for (int i = 0; i < m->nexterns; i++)
      if (m->externs[i].q == rs->q)
        for (int j = 0; j < m->externs[i].nin; j++) w = fmax(w, row[m->externs[i].in_q[j]].l2);
  return unknown ? NAN : w;
}

/* Relative errors of sample k's quantity q: the lifted reduced value's and
 * the projection floor's, L2 and Linf. The sums of squares are taken of
 * values divided by the largest |full| entry, so that data of any scale
 * (1e-200 or 1e200, where squares underflow to 0 or overflow to inf) gives
 * the same relative errors (issue 24: 1e-200 data verified as error 0). */
static void sample_errors(const RClass *rc, const double *full, Reduced *r, int q, double *y, double *proj,
                          double out[4]) {
  double ny = 0, nyinf = 0, e2 = 0, einf = 0;
  bool nan = false;
  reduced_lift(r, q, y);
  for (long e = 0; e < rc->n; e++) nyinf = fmax(nyinf, fabs(full[e]));
  double unit = nyinf > 0 && isfinite(nyinf) ? 1 / nyinf : 1;
  if (!isfinite(unit)) unit = 1; /* subnormal data: 1/nyinf overflows; their squares are lost anyway */
  for (long e = 0; e < rc->n; e++) {
    double d = (full[e] - y[e]) * unit, v = full[e] * unit;
    ny += v * v;
    e2 += d * d;
    einf = fmax(einf, fabs(full[e] - y[e]));
    nan |= d != d; /* fmax drops a NaN: the error is then not finite */
  }
  double fl[2];
  model_projection_floor(rc, full, proj, y, fl);
  out[0] = ny > 0 ? sqrt(e2 / ny) : sqrt(e2);
  out[1] = nan ? NAN : nyinf > 0 ? einf / nyinf : einf;
  out[2] = fl[0];
  out[3] = fl[1];
}

/* ‖v‖ in the norm quantity q's estimate is in: class rc's product K0 (h->pn[class], made at its
 * first use, from `f`: params are bound then) or the 2-norm. NaN when K0 cannot be made (`err`
 * says why). */
static double error_norm(Heldout *h, const RClass *rc, Full *f, const double *v, char *err, size_t errlen) {
  if (!rc->product) return cblas_dnrm2((int)rc->n, v, 1);
  ProductNorm **p = &h->pn[rc - h->m->classes];
  if (!*p && !(*p = product_norm_new(h->m, f, rc, ERR_OF(err, errlen)))) return NAN;
  return product_norm(*p, v);
}

/* Each input's own error ‖x − B x̂‖ (npg_reduced_set's; in a product K0's norm exactly, where
 * npg_reduced_set bounds it by √‖K0‖₁ ‖x − B x̂‖₂), the estimates, and every quantity's
 * estimate against its true absolute error `full` − lifted (in its class's product K0's norm when
 * it has one, as the estimate), into the rows' sums. */
static int sample_estimates(Heldout *h, Full *f, const double *const *fulls, char *err, size_t errlen) {
  const Model *m = h->m;
  Reduced *r = h->r;
  EstimateResult *e = h->est;
  double *in_err = h->in_err, *y = h->y;
  for (int q = 0; q < m->nq; q++) {
    const RClass *rc = &m->classes[m->qclass[q]];
    in_err[q] = 0;
    if (((Sym *)m->prog->quantities.v[q])->kind != SYM_INPUT || rc->streamed) continue;
    const double *x = fulls[q];
    reduced_lift(r, q, y);
    double d = 0, xn = 0;
    for (long i = 0; i < rc->n; i++) d += (x[i] - y[i]) * (x[i] - y[i]), xn += x[i] * x[i];
    in_err[q] = sqrt(d) <= 64 * DBL_EPSILON * sqrt((double)rc->n) * sqrt(xn) ? 0 : sqrt(d);
    if (in_err[q] == 0 || !rc->product) continue;
    for (long i = 0; i < rc->n; i++) y[i] = x[i] - y[i]; /* in K0's norm, exactly: K0 is at hand here */
    if (isnan(in_err[q] = error_norm(h, rc, f, y, err, errlen))) return -1;
  }
  if (estimate_eval(r, in_err, e)) return -1;
  for (int q = 0; q < m->nq; q++) {
    const RClass *rc = &m->classes[m->qclass[q]];
    HeldoutRow *row = &h->rows[q];
    if (rc->streamed || isnan(e->err[q])) continue;
    const double *full = fulls[q];
    reduced_lift(r, q, y);
    for (long i = 0; i < rc->n; i++) y[i] = full[i] - y[i];
    double d = error_norm(h, rc, f, y, err, errlen), fn = error_norm(h, rc, f, full, err, errlen);
    if (isnan(d) || isnan(fn)) return -1;
    fn *= fn;
    /* an error within the lift's own roundoff (an input its basis holds) has no effectivity */
    if (d <= 64 * DBL_EPSILON * sqrt((double)rc->n) * sqrt(fn)) d = 0;
    if (row->est_samples == 0) row->eff_min = INFINITY, row->eff_max = 0, row->est_bound = true;
    row->est_samples++;
    row->est += e->err[q], row->err += d;
    row->est_bound = row->est_bound && (e->flags[q] & EST_BOUND);
    if (d > 0) row->eff_min = fmin(row->eff_min, e->err[q] / d), row->eff_max = fmax(row->eff_max, e->err[q] / d);
  }
  return 0;
}

void heldout_finish(Heldout *h, long S) {
  const Model *m = h->m;
  const Program *prog = m->prog;
  const HeldoutSum *sum = h->sum;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = prog->quantities.v[q];
    HeldoutRow *row = &h->rows[q];
    row->name = s->name;
    row->kind = s->kind == SYM_INPUT ? "input" : s->kind == SYM_EXTERN ? "extern" : "stage";
    for (int i = 0; i < m->nstages; i++)
      if (m->stages[i].q == q && m->stages[i].st->kind != ST_EXTERN)
        row->kind = !m->stages[i].interp ? stage_kind_name[m->stages[i].st->kind]
                    : m->stages[i].st->kind == ST_ROOT ? "root, interp" : "inverse, interp"; /* DESIGN §12 */
    row->m = m->classes[m->qclass[q]].m;
    row->output = s->is_output;
    row->l2 = sum[q].l2 / (double)S;
    row->floor = sum[q].floor2 / (double)S;
    /* the lifted reduced value lies in B's span, whose closest point to y is BBᵀy: l2 ≥ floor sample by sample,
     * so a difference below 0 is rounding of two norms relative to ‖y‖ (-1.7e-18 was printed); one
     * beyond 1e-12 would be a defect and is kept in sight */
    row->own = row->l2 - row->floor;
    if (row->own < 0 && row->own > -1e-12) row->own = 0;
    row->linf = sum[q].linf / (double)S;
    row->linf_floor = sum[q].floorinf / (double)S;
    if (row->est_samples > 0) row->est /= (double)row->est_samples, row->err /= (double)row->est_samples;
    else row->est = row->err = row->eff_min = row->eff_max = NAN;
    if (!(row->eff_min <= row->eff_max)) row->eff_min = row->eff_max = NAN; /* no sample with an error above 0 */
    const RClass *rc = &m->classes[m->qclass[q]];
    for (int i = 0; rc->streamed && i < rc->nmembers; i++) /* no basis to lift with: training's floors */
      if (rc->members[i].q == q) {
        row->streamed = true;
        row->l2 = row->own = row->l2_max = row->linf = NAN;
        row->floor = rc->members[i].floor_l2, row->linf_floor = rc->members[i].floor_linf;
      }
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    double g = h->rows[rs->q].l2 - worst_input(m, rs, h->rows);
    if (g > h->growth) {
      h->growth = g;
      h->grows_at = rs->st->sym->name;
    }
  }
}


Heldout *heldout_new(Model *m, char *err, size_t errlen) {
  Heldout *h = calloc(1, sizeof *h);
  if (!h) return error_set(err, errlen, "out of memory"), NULL;
  h->m = m;
  long maxn = 1, maxm = 1;
  for (int k = 0; k < m->nclasses; k++) {
    maxn = m->classes[k].n > maxn ? m->classes[k].n : maxn;
    maxm = m->classes[k].m > maxm ? m->classes[k].m : maxm;
  }
  h->sum = calloc((size_t)m->nq + 1, sizeof *h->sum);
  h->y = malloc(sizeof(double) * (size_t)maxn);
  h->proj = malloc(sizeof(double) * (size_t)maxm);
  h->rows = calloc((size_t)m->nq + 1, sizeof *h->rows);
  h->in_err = calloc((size_t)m->nq + 1, sizeof(double));
  h->est = estimate_result_new(m);
  h->pn = calloc((size_t)m->nclasses + 1, sizeof *h->pn);
  char why[1024] = "";
  h->r = reduced_new(m, ERR_OF(why, sizeof why));
  if (h->r) reduced_krylov_roots(h->r, true); /* what users run */
  if (!h->sum || !h->y || !h->proj || !h->rows || !h->in_err || !h->est || !h->pn || !h->r) {
    error_set(err, errlen, "%s", why[0] ? why : "out of memory");
    heldout_free(h);
    return NULL;
  }
  return h;
}

int heldout_reduce(Heldout *h, long k, const double *const *full) {
  const Model *m = h->m;
  for (int q = 0; q < m->nq; q++)
    if (((Sym *)m->prog->quantities.v[q])->kind == SYM_INPUT) reduced_project(h->r, q, full[q]);
  return reduced_eval(h->r, k) != 0 ? -1 : 0;
}

int heldout_measure(Heldout *h, long k, Full *f, const double *const *full, char *err, size_t errlen) {
  const Model *m = h->m;
  for (int q = 0; q < m->nq; q++) {
    const RClass *rc = &m->classes[m->qclass[q]];
    if (rc->streamed) continue; /* heldout_finish: the training's floors */
    double e[4];
    sample_errors(rc, full[q], h->r, q, h->y, h->proj, e);
    h->sum[q].l2 += e[0];
    h->sum[q].linf += e[1];
    h->sum[q].floor2 += e[2];
    h->sum[q].floorinf += e[3];
    if (e[0] > h->rows[q].l2_max || k == 0) h->rows[q].l2_max = e[0], h->rows[q].l2_max_sample = k;
  }
  if (sample_estimates(h, f, full, err, errlen)) return error_set_first(err, errlen, "out of memory estimating errors");
  return 0;
}

void heldout_free(Heldout *h) {
  if (!h) return;
  free(h->sum);
  free(h->y);
  free(h->proj);
  free(h->rows);
  free(h->in_err);
  estimate_result_free(h->est);
  for (int c = 0; h->pn && c < h->m->nclasses; c++) product_norm_free(h->pn[c]);
  free(h->pn);
  reduced_free(h->r);
  free(h);
}
