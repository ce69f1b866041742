/* verify.c — the auto-check through npg.h (`npgc verify`, DESIGN §7): on
 * held-out samples, every quantity of the full evaluator against the
 * reduced one lifted to full space; the projection floor ‖y − BBᵀy‖/‖y‖
 * (the best any method can do in that basis: Arvo's discretization error),
 * the reduction's own error, and the stage where error grows most. */
#include <cblas.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"
#include "estimate.h"
#include "interp.h"
#include "compile.h"
#include "exact.h"

typedef struct ErrSum {
  double l2, linf, floor2, floorinf;    /* sums over samples */
} ErrSum;

#define vfail(rep, ...) error_set_first((rep)->error, sizeof (rep)->error, __VA_ARGS__)

/* The worst mean error among the quantities stage `rs` reads (tensor
 * inputs, named numerators, an extern's inputs); NaN when one of them was
 * not measured (its basis streamed): then how much the stage adds is
 * unknown, and fmax would have ignored it (trial3). */
static double worst_input(const Model *m, const RStage *rs, const NpgVerifyRow *row) {
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

/* Errors of quantity q at one sample: full value `full`, reduced `r`. */
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

/* ‖v‖ in the norm quantity q's estimate is in: class rc's product K0 (pn[class], made at its first
 * use: params are bound then) or the 2-norm. NaN when K0 cannot be made (rep->error says why). */
static double error_norm(Model *m, const RClass *rc, NpgFull *f, ProductNorm **pn, const double *v,
                         NpgVerifyReport *rep) {
  if (!rc->product) return cblas_dnrm2((int)rc->n, v, 1);
  ProductNorm **p = &pn[rc - m->classes];
  if (!*p && !(*p = product_norm_new(m, f->full, rc, rep->error, sizeof rep->error))) return NAN;
  return product_norm(*p, v);
}

/* Each input's own error ‖x − B x̂‖ (npg_reduced_set's), the estimates, and every quantity's
 * estimate against its true absolute error `full` − lifted (in its class's product K0's norm when
 * it has one, as the estimate), into the rows' sums. */
static int sample_estimates(Model *m, Reduced *r, NpgFull *f, EstimateResult *e, double *in_err, double *y,
                            ProductNorm **pn, NpgVerifyReport *rep) {
  for (int q = 0; q < m->nq; q++) {
    const RClass *rc = &m->classes[m->qclass[q]];
    in_err[q] = 0;
    if (((Sym *)m->prog->quantities.v[q])->kind != SYM_INPUT || rc->streamed) continue;
    const double *x = npg_full_get(f, ((Sym *)m->prog->quantities.v[q])->name, NULL);
    reduced_lift(r, q, y);
    double d = 0, xn = 0;
    for (long i = 0; i < rc->n; i++) d += (x[i] - y[i]) * (x[i] - y[i]), xn += x[i] * x[i];
    in_err[q] = sqrt(d) <= 64 * DBL_EPSILON * sqrt((double)rc->n) * sqrt(xn) ? 0 : sqrt(d);
  }
  if (estimate_eval(r, in_err, e)) return -1;
  for (int q = 0; q < m->nq; q++) {
    const RClass *rc = &m->classes[m->qclass[q]];
    NpgVerifyRow *row = &rep->rows[q];
    if (rc->streamed || isnan(e->err[q])) continue;
    const double *full = npg_full_get(f, ((Sym *)m->prog->quantities.v[q])->name, NULL);
    reduced_lift(r, q, y);
    for (long i = 0; i < rc->n; i++) y[i] = full[i] - y[i];
    double d = error_norm(m, rc, f, pn, y, rep), fn = error_norm(m, rc, f, pn, full, rep);
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

static void fill_rows(const Model *m, const ErrSum *sum, long S, NpgVerifyReport *rep) {
  const Program *prog = m->prog;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = prog->quantities.v[q];
    NpgVerifyRow *row = &rep->rows[q];
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
    double g = rep->rows[rs->q].l2 - worst_input(m, rs, rep->rows);
    if (g > rep->growth) {
      rep->growth = g;
      rep->grows_at = rs->st->sym->name;
    }
  }
}

int npg_verify(const NpgModel *nm, NpgFull *f, long S, NpgSampleFn set, void *user, bool progress,
               NpgVerifyReport *rep) {
  API_REFUSE_NULL(rep, NULL, 0, -1);
  memset(rep, 0, sizeof *rep);
  API_REFUSE_NULL(nm, rep->error, sizeof rep->error, -1);
  API_REFUSE_NULL(f, rep->error, sizeof rep->error, -1);
  API_REFUSE_NULL(set, rep->error, sizeof rep->error, -1);
  if (!nm->m) return vfail(rep, "%s", nm->error);
  Model *m = nm->m;
  if (npg_full_error(f)[0]) return vfail(rep, "%s", npg_full_error(f));
  if (npg_model_check_params(nm, f, rep->error, sizeof rep->error) != 0) return -1;
  if (S < 1) return vfail(rep, "no samples to verify on");
  long maxn = 1, maxm = 1;
  for (int k = 0; k < m->nclasses; k++) {
    maxn = m->classes[k].n > maxn ? m->classes[k].n : maxn;
    maxm = m->classes[k].m > maxm ? m->classes[k].m : maxm;
  }
  ErrSum *sum = calloc((size_t)m->nq + 1, sizeof *sum);
  double *y = malloc(sizeof(double) * (size_t)maxn), *proj = malloc(sizeof(double) * (size_t)maxm);
  rep->rows = calloc((size_t)m->nq + 1, sizeof *rep->rows);
  char err[1024] = "";
  Reduced *r = reduced_new(m, err, sizeof err);
  if (r) reduced_krylov_roots(r, true); /* what users run */
  EstimateResult *est = estimate_result_new(m);
  double *in_err = calloc((size_t)m->nq + 1, sizeof(double));
  ProductNorm **pn = calloc((size_t)m->nclasses + 1, sizeof *pn);
  int rc = 0;
  if (!sum || !y || !proj || !rep->rows || !r || !est || !in_err || !pn) rc = vfail(rep, "%s", err[0] ? err : "out of memory");
  rep->nrows = m->nq;
  for (long k = 0; k < S && rc == 0; k++) {
    /* only what `set` gives counts as this sample's: a value left out is refused, not the previous one's */
    char what[64];
    snprintf(what, sizeof what, "test sample %ld", k);
    full_forget_given(f->full);
    if (set(user, f, k) != 0 || full_check_given(f->full, what) != 0 || npg_full_eval(f, k) != 0 ||
        npg_full_check_finite(f, k) != 0) {
      rc = vfail(rep, "%s", npg_full_error(f));
      break;
    }
    /* `set` may set a param too (npg_full_set takes one): the model would then be compared with
     * a full evaluation of other params (trial3) */
    if (npg_model_check_params(nm, f, rep->error, sizeof rep->error) != 0) {
      rc = -1;
      break;
    }
    for (int q = 0; q < m->nq; q++)
      if (((Sym *)m->prog->quantities.v[q])->kind == SYM_INPUT)
        reduced_project(r, q, npg_full_get(f, ((Sym *)m->prog->quantities.v[q])->name, NULL));
    if (reduced_eval(r, k) != 0) {
      rc = vfail(rep, "%s", reduced_error(r));
      break;
    }
    if (api_reduced_not_finite(m, r, k, rep->error, sizeof rep->error)) {
      rc = -1;
      break;
    }
    for (int q = 0; q < m->nq; q++) {
      const RClass *rc_ = &m->classes[m->qclass[q]];
      size_t n = 0;
      const double *full = npg_full_get(f, ((Sym *)m->prog->quantities.v[q])->name, &n);
      if (!full || (long)n != rc_->n) {
        rc = vfail(rep, "sample %ld: '%s' has %zu entries, the model was trained with %ld",
                   k, ((Sym *)m->prog->quantities.v[q])->name, n, rc_->n);
        break;
      }
      if (rc_->streamed) continue; /* fill_rows: the training's floors */
      double e[4];
      sample_errors(rc_, full, r, q, y, proj, e);
      sum[q].l2 += e[0];
      sum[q].linf += e[1];
      sum[q].floor2 += e[2];
      sum[q].floorinf += e[3];
      if (e[0] > rep->rows[q].l2_max || k == 0) rep->rows[q].l2_max = e[0], rep->rows[q].l2_max_sample = k;
    }
    if (rc == 0 && sample_estimates(m, r, f, est, in_err, y, pn, rep)) rc = vfail(rep, "out of memory estimating errors");
    progress_show(progress, "verification", k + 1, S);
  }
  if (rc == 0) {
    rep->samples = S;
    fill_rows(m, sum, S, rep);
  }
  free(sum);
  free(y);
  free(proj);
  free(in_err);
  for (int c = 0; pn && c < m->nclasses; c++) product_norm_free(pn[c]);
  free(pn);
  estimate_result_free(est);
  reduced_free(r);
  return rc;
}

void npg_verify_free(NpgVerifyReport *rep) {
  if (!rep) return;
  free(rep->rows);
  rep->rows = NULL;
  rep->nrows = 0;
}

int npg_verify_exact(NpgProgram *p, long size, NpgBackend backend, bool progress, FILE *out, char *err,
                     size_t errlen) {
  API_REFUSE_NULL(p, err, errlen, -1);
  API_REFUSE_NULL(out, err, errlen, -1);
  if (size < 0)
    return api_refuse(err, errlen, __func__, "argument 'size' is %ld (the size of every dim, at least 1, or 0 for the "
                                             "defaults)", size);
  ExactOptions o = {size, size, 1u, backend == NPG_CC ? JIT_CC : JIT_TCC, progress};
  return exact_check(p, &o, out, err, errlen);
}

int npg_verify_warnings(const NpgModel *nm, const NpgVerifyReport *rep, double tol, FILE *out) {
  API_REFUSE_NULL(nm, NULL, 0, 0);
  API_REFUSE_NULL(rep, NULL, 0, 0);
  API_REFUSE_NULL(out, NULL, 0, 0);
  const Model *m = nm->m;
  if (!m || rep->nrows != m->nq) return 0;
  double *means = malloc(sizeof(double) * 2 * (size_t)(m->nq + 1)); /* errors and floors */
  if (!means) return 0;
  for (int q = 0; q < m->nq; q++) means[q] = rep->rows[q].l2, means[m->nq + q] = rep->rows[q].floor;
  interp_report(m, out); /* the reduction of each eligible stage, as training chose it (DESIGN §12) */
  int n = report_verify_warnings(m, means, means + m->nq, tol, out);
  free(means);
  return n;
}
