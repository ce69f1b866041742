/* verify.c — the auto-check through npg.h (`npgc verify`, DESIGN §7): each
 * held-out sample set and evaluated in full, checked, and handed to the
 * backend's measurements (backends/verify/heldout.h), whose rows become the
 * report; the exactness checks (`--exact`) and the warnings. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"
#include "compile.h"
#include "exact.h"
#include "heldout.h"
#include "interp.h"

#define vfail(rep, ...) error_set_first((rep)->error, sizeof (rep)->error, __VA_ARGS__)

/* Sample k set by `set`, evaluated in full and checked (its params the model's); every
 * quantity's full values into full[q]. 0, or -1 with the report's error. */
static int full_sample(const NpgModel *nm, NpgFull *f, long k, NpgSampleFn set, void *user, const double **full,
                       NpgVerifyReport *rep) {
  const Model *m = nm->m;
  /* only what `set` gives counts as this sample's: a value left out is refused, not the previous one's */
  char what[64];
  snprintf(what, sizeof what, "test sample %ld", k);
  full_forget_given(f->full);
  if (set(user, f, k) != 0 || full_check_given(f->full, what) != 0 || npg_full_eval(f, k) != 0 ||
      npg_full_check_finite(f, k) != 0)
    return vfail(rep, "%s", npg_full_error(f));
  /* `set` may set a param too (npg_full_set takes one): the model would then be compared with
   * a full evaluation of other params (trial3) */
  if (npg_model_check_params(nm, f, rep->error, sizeof rep->error) != 0) return -1;
  for (int q = 0; q < m->nq; q++) {
    size_t n = 0;
    const char *name = ((Sym *)m->prog->quantities.v[q])->name;
    full[q] = npg_full_get(f, name, &n);
    if (!full[q] || (long)n != m->classes[m->qclass[q]].n)
      return vfail(rep, "sample %ld: '%s' has %zu entries, the model was trained with %ld", k, name, n,
                   m->classes[m->qclass[q]].n);
  }
  return 0;
}

/* The backend's rows as npg.h's. */
static int report_rows(const Heldout *h, NpgVerifyReport *rep) {
  const Model *m = h->m;
  if (!(rep->rows = calloc((size_t)m->nq + 1, sizeof *rep->rows))) return vfail(rep, "out of memory");
  rep->nrows = m->nq;
  for (int q = 0; q < m->nq; q++) {
    const HeldoutRow *a = &h->rows[q];
    rep->rows[q] = (NpgVerifyRow){
        .name = a->name, .kind = a->kind, .m = a->m, .output = a->output, .l2 = a->l2, .floor = a->floor,
        .own = a->own, .l2_max = a->l2_max, .l2_max_sample = a->l2_max_sample, .linf = a->linf,
        .linf_floor = a->linf_floor, .streamed = a->streamed, .est = a->est, .err = a->err,
        .eff_min = a->eff_min, .eff_max = a->eff_max, .est_samples = a->est_samples, .est_bound = a->est_bound};
  }
  rep->grows_at = h->grows_at;
  rep->growth = h->growth;
  return 0;
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
  Heldout *h = heldout_new(m, rep->error, sizeof rep->error);
  const double **full = calloc((size_t)m->nq + 1, sizeof *full);
  int rc = !h ? -1 : !full ? vfail(rep, "out of memory") : 0;
  for (long k = 0; k < S && rc == 0; k++) {
    if (full_sample(nm, f, k, set, user, full, rep) != 0) rc = -1;
    else if (heldout_reduce(h, k, full) != 0) rc = vfail(rep, "%s", reduced_error(h->r));
    else if (api_reduced_not_finite(m, h->r, k, rep->error, sizeof rep->error)) rc = -1;
    else rc = heldout_measure(h, k, f->full, full, rep->error, sizeof rep->error);
    progress_show(progress && rc == 0, "verification", k + 1, S);
  }
  if (rc == 0) {
    heldout_finish(h, S);
    rc = report_rows(h, rep);
    rep->samples = rc == 0 ? S : 0;
  }
  free(full);
  heldout_free(h);
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
