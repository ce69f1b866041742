/* exact.c — the exactness checks of DESIGN §4 on demand (exact.h).
 *
 * Check 1 rebuilds every stage from its tensor builders' entries, the same
 * entries pre-multiplication consumes, contracted with the full evaluator's
 * values of the stage's inputs; diagonal operators are applied entrywise,
 * declared ones densely by the runtime's operator power (the routine the
 * full evaluator calls). The full evaluator evaluates the source expression
 * directly (emit_direct.c), so agreement means the lowering to tensors is
 * exact. Check 2 trains on random samples with every basis completed to its
 * class's full dimension and compares the lifted reduced values of every
 * quantity with the full evaluator on held-out samples. */
#include "exact.h"

#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "ast.h"
#include "emit.h"
#include "full.h"
#include "interp.h"
#include "memsamples.h"
#include "reduced.h"
#include "runtime.h"
#include "train.h"

double exact_rel_max_diff(const double *a, const double *b, size_t n) {
  double num = 0, den = 0;
  for (size_t i = 0; i < n; i++) {
    if (isnan(a[i]) != isnan(b[i])) return NAN;
    if (isnan(a[i])) continue;
    num = fmax(num, fabs(a[i] - b[i]));
    den = fmax(den, fabs(a[i]));
  }
  return den > 0 ? num / den : num;
}

/* ---------------------------------------------------------------- 1. lowering */

typedef struct Sum {
  const double *in[16]; /* the group's input quantities */
  double *out, *mag;    /* Σ entry · inputs, and Σ |entry · inputs| (NULL: not kept) */
  long ncols;           /* 0: vectors; else row-major rows × ncols */
} Sum;

static int add_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Sum *s = user;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  long k = s->ncols ? row * s->ncols + col : row;
  s->out[k] += v;
  if (s->mag) s->mag[k] += fabs(v);
  return 0;
}

/* out += the entries of tensor group `g` (builder `name`) contracted with
 * the current values of its inputs; mag (when not NULL) += their moduli. */
static int sum_group(Full *f, const char *name, const TensorGroup *g, double *out, double *mag, long ncols,
                     char *err, size_t errlen) {
  Sum s = {.out = out, .mag = mag, .ncols = ncols};
  for (int i = 0; i < g->ninputs && i < 16; i++)
    if (!(s.in[i] = full_get(f, g->inputs[i]->name, NULL)))
      return error_set(err, errlen, "tensor %s reads '%s', which the full evaluator does not hold (a bug in npg)", name,
                       g->inputs[i]->name);
  NpgSink sink = {&s, add_entry, 0, 1, 0, 0}; /* every row */
  if (full_build(f, name, &sink) != 0) return error_set(err, errlen, "tensor %s: %s", name, full_error(f));
  return 0;
}

static double rational_pow(double b, long p, long q) { return q == 1 ? pow(b, (double)p) : pow(b, (double)p / (double)q); }

/* κ₁(M)^|r| for a dense row-major n × n M (LU and LAPACK's condition
 * estimate on a copy): how much a power r of M amplifies rounding-level
 * differences of M and of the vector it acts on. Infinity when singular. */
static double power_condition(const double *M, size_t n, long p, long q) {
  if (n == 0) return 1;
  double *A = malloc(sizeof(double) * n * n);
  lapack_int *piv = malloc(sizeof(lapack_int) * n);
  double kappa = INFINITY, rcond = 0;
  if (A && piv) {
    memcpy(A, M, sizeof(double) * n * n);
    /* row-major M is column-major Mᵀ: ‖M‖₁ = ‖Mᵀ‖∞ */
    double anorm = LAPACKE_dlange(LAPACK_COL_MAJOR, 'I', (lapack_int)n, (lapack_int)n, M, (lapack_int)n);
    if (LAPACKE_dgetrf(LAPACK_COL_MAJOR, (lapack_int)n, (lapack_int)n, A, (lapack_int)n, piv) == 0 &&
        LAPACKE_dgecon(LAPACK_COL_MAJOR, 'I', (lapack_int)n, A, (lapack_int)n, anorm, &rcond) == 0 && rcond > 0)
      kappa = pow(1 / rcond, fabs((double)p / (double)q));
  }
  free(A);
  free(piv);
  return kappa;
}

static double max_abs(const double *x, size_t n) {
  double m = 0;
  for (size_t i = 0; i < n; i++) m = fmax(m, fabs(x[i]));
  return m;
}

/* y (count entries) <- stage `st` from its canonical form Σ_t Π M^r q_t,
 * and scale <- the size of the rounding of that evaluation per entry (up to
 * the factor ε): Σ_t of the term's magnitude times its condition. A
 * polynomial's is Σ |coefficient · inputs| over its monomials (cancelling
 * monomials — a volume from vertex positions — make it larger than the
 * value); a diagonal power d^r adds |r| · Σ|monomials of d| / |d| of
 * relative condition; a declared operator's power multiplies the relative
 * condition of the whole vector by κ(M)^|r|. */
static int stage_from_tensors(const Program *prog, Full *f, const Stage *st, size_t count, double *y,
                              double *scale, char *err, size_t errlen) {
  size_t ne = count / (size_t)(st->ncomp > 0 ? st->ncomp : 1), n1 = count ? count : 1;
  double *num = calloc(n1, sizeof(double)), *mag = calloc(n1, sizeof(double));
  double *dg = calloc(n1, sizeof(double)), *dmag = calloc(n1, sizeof(double));
  int rc = 0;
  if (!num || !mag || !dg || !dmag) rc = error_set(err, errlen, "out of memory rebuilding stage %s", st->sym->name);
  memset(y, 0, sizeof(double) * count);
  memset(scale, 0, sizeof(double) * count);
  for (int t = 0; t < st->nterms && rc == 0; t++) {
    const Term *tm = st->terms[t];
    memset(num, 0, sizeof(double) * count);
    memset(mag, 0, sizeof(double) * count);
    if (tm->named_num) {
      const double *w = full_get(f, tm->named_num->name, NULL);
      if (!w) rc = error_set(err, errlen, "stage %s: numerator '%s' not held (a bug in npg)", st->sym->name,
                             tm->named_num->name);
      for (size_t e = 0; e < count && rc == 0; e++) num[e] = w[e], mag[e] = fabs(w[e]);
    }
    for (int g = 0; g < tm->num_tensors.n && rc == 0 && !tm->named_num; g++)
      rc = sum_group(f, emit_builder_name(prog->ctx, prog, st, t, 0, g, NULL), &tm->num_tensors.g[g], num, mag, 0, err,
                     errlen);
    for (int o = 0; o < tm->nops && rc == 0; o++) {
      const OpPow *op = &tm->ops[o];
      if (op->kind == OPK_DIAG) {
        memset(dg, 0, sizeof(double) * count);
        memset(dmag, 0, sizeof(double) * count);
        for (int g = 0; g < tm->op_tensors[o].n && rc == 0; g++)
          rc = sum_group(f, emit_builder_name(prog->ctx, prog, st, t, o + 1, g, NULL), &tm->op_tensors[o].g[g], dg, dmag, 0,
                         err, errlen);
        double r = fabs((double)op->p / (double)op->q);
        for (size_t e = 0; e < count && rc == 0; e++) {
          double pw = rational_pow(dg[e], op->p, op->q);
          num[e] *= pw;
          mag[e] = mag[e] * fabs(pw) + fabs(num[e]) * r * dmag[e] / fabs(dg[e]);
        }
        continue;
      }
      double *M = ne <= 50000 ? calloc(ne > 0 ? ne * ne : 1, sizeof(double)) : NULL;
      if (!M) {
        rc = error_set(err, errlen, "stage %s: operator %s of %zu × %zu entries too large for the check", st->sym->name,
                       op->op->name, ne, ne);
        break;
      }
      const OpDef *od = op->op->opdef;
      for (int g = 0; g < od->tensors.n && rc == 0; g++)
        rc = sum_group(f, emit_builder_name(prog->ctx, prog, NULL, 0, 0, g, op->op), &od->tensors.g[g], M, NULL, (long)ne,
                       err, errlen);
      double kappa = rc == 0 ? power_condition(M, ne, op->p, op->q) : 1;
      double cond_in = max_abs(mag, count) / fmax(max_abs(num, count), DBL_MIN);
      NpgHost host;
      memset(&host, 0, sizeof host);
      NpgCtx c = {.rt = &npg_runtime, .host = &host};
      if (rc == 0 && npg_runtime.op_power(&c, st->sym->name, op->op->name, (npg_idx)ne, M, op->p, op->q, num) != 0)
        rc = error_set(err, errlen, "on the random data: %s", host.msg);
      double out_mag = kappa * fmax(cond_in, 1) * max_abs(num, count);
      for (size_t e = 0; e < count && rc == 0; e++) mag[e] = out_mag;
      free(M);
    }
    for (size_t e = 0; e < count && rc == 0; e++) y[e] += num[e], scale[e] += mag[e];
  }
  free(num);
  free(mag);
  free(dg);
  free(dmag);
  return rc;
}

/* Check 1; *failed set when a stage differs. */
static int check_lowering(Program *prog, const ExactOptions *o, FILE *out, bool *failed, char *err, size_t errlen) {
  long n = o->n_lowering > 0 ? o->n_lowering : 6;
  fprintf(out, "  1. lowering: every stage from its tensors' entries against the full evaluator, every dim %ld (bar "
               "%.0e)\n",
          n, EXACT_LOWERING_TOL);
  Full *f = full_new(prog, o->backend, NULL);
  MemSamples ms;
  memset(&ms, 0, sizeof ms);
  int rc = 0;
  if (!f) rc = error_set(err, errlen, "out of memory for the full evaluator");
  else if (full_error(f)[0]) rc = error_set(err, errlen, "%s", full_error(f));
  else if ((rc = memsamples_fill(&ms, prog, f, n, 1, o->seed)) != 0)
    rc = error_set(err, errlen, "%s", rc == -1 ? full_error(f) : "out of memory for the random samples");
  else if (memsamples_set(&ms, f, 0) != 0 || full_eval(f, 0) != 0)
    rc = error_set(err, errlen, "the full evaluator on the random data: %s (every param and input is drawn at random: "
                               "a program whose evaluation needs structured params, such as a symmetric neighbour "
                               "table under a root, cannot be checked this way; that is not a defect of npg)",
                  full_error(f));
  for (int i = 0; i < prog->stages.n && rc == 0; i++) {
    const Stage *st = prog->stages.v[i];
    if (st->kind == ST_EXTERN) continue;
    long shape[MAX_AXES + MAX_STATIC];
    size_t count = memsamples_count(st->sym, n, shape);
    const double *full = full_get(f, st->sym->name, NULL);
    double *y = malloc(sizeof(double) * (count ? count : 1));
    if (!y || !full) {
      free(y);
      rc = error_set(err, errlen, "stage %s: %s", st->sym->name, y ? "not held by the full evaluator" : "out of memory");
      break;
    }
    double *scale = malloc(sizeof(double) * (count ? count : 1));
    rc = scale ? stage_from_tensors(prog, f, st, count, y, scale, err, errlen)
               : error_set(err, errlen, "out of memory rebuilding stage %s", st->sym->name);
    if (rc == 0) {
      /* the difference relative to the larger of the value and the rounding
       * scale of the canonical form: the two evaluate one function in
       * different orders, so they may differ by ε × that scale */
      double diff = 0, big = max_abs(full, count), sc = max_abs(scale, count);
      for (size_t e = 0; e < count; e++)
        diff = isnan(full[e]) != isnan(y[e]) ? NAN : fmax(diff, fabs(full[e] - y[e]));
      double d = diff / fmax(fmax(big, sc), DBL_MIN);
      bool bad = !(d <= EXACT_LOWERING_TOL);
      *failed |= bad;
      fprintf(out, "     %-16s %-11s %9.2e", st->sym->name, stage_kind_name[st->kind], d);
      if (sc > 10 * big) fprintf(out, "  (of its rounding scale, %.1e times its largest value)", sc / fmax(big, DBL_MIN));
      fprintf(out, "%s\n", bad ? "  FAIL: the tensor form differs from the source expression" : "");
    }
    free(scale);
    free(y);
  }
  memsamples_free(&ms);
  full_free(f);
  return rc;
}

/* ---------------------------------------------------------------- 2. full rank */

static int held_out_differences(const Program *prog, const Model *m, Full *f, Reduced *r, MemSamples *held,
                                long held_out, double *y, double *worst, char *err, size_t errlen);

static int check_full_rank(Program *prog, const ExactOptions *o, FILE *out, bool *failed, char *err, size_t errlen) {
  long n = o->n_full_rank > 0 ? o->n_full_rank : 4, S = 1;
  for (int i = 0; i < prog->quantities.n; i++) {
    long shape[MAX_AXES + MAX_STATIC];
    long c = (long)memsamples_count(prog->quantities.v[i], n, shape);
    S = c > S ? c : S;
  }
  S += 4; /* more samples than the largest class's dimension: every snapshot matrix has full rank */
  const long held_out = 3;
  fprintf(out, "  2. full rank: every basis at its class's full dimension (%ld training samples), %ld held-out "
               "samples, every dim %ld (bar %.0e)\n",
          S, held_out, n, EXACT_FULL_RANK_TOL);
  if (S > 20000)
    return error_set(err, errlen, "the full-rank check would train on %ld samples of %ld entries; give a smaller size", S,
                 S - 4);
  Full *f = full_new(prog, o->backend, NULL);
  MemSamples train, held;
  memset(&train, 0, sizeof train);
  memset(&held, 0, sizeof held);
  Model *m = NULL;
  Reduced *r = NULL;
  double *y = NULL, *worst = calloc((size_t)prog->quantities.n + 1, sizeof(double));
  int rc = 0;
  if (!worst || !f) rc = error_set(err, errlen, "out of memory");
  else if (full_error(f)[0]) rc = error_set(err, errlen, "%s", full_error(f));
  else if ((rc = memsamples_fill(&train, prog, f, n, S, o->seed + 1)) != 0 ||
           (rc = memsamples_fill(&held, prog, NULL, n, held_out, o->seed + 977)) != 0)
    rc = error_set(err, errlen, "%s", rc == -1 ? full_error(f) : "out of memory for the random samples");
  if (rc == 0) {
    SampleSource src = {S, &train, memsamples_set, NULL, NULL};
    NpgTrainOptions user = {.cap = 1 << 20, .energy = 1.0, .progress = o->progress};
    TrainOptions opt = {.user = &user, .full_rank = true};
    char why[2048] = "";
    if (!(m = train_model(prog, f, &src, &opt, ERR_OF(why, sizeof why))))
      rc = error_set(err, errlen, "training with full-rank bases on the random data: %s", why);
    else if (!(r = reduced_new(m, ERR_OF(why, sizeof why)))) rc = error_set(err, errlen, "%s", why);
    else if (!(y = malloc(sizeof(double) * (size_t)(S - 4))))
      rc = error_set(err, errlen, "out of memory");
  }
  if (rc == 0) rc = held_out_differences(prog, m, f, r, &held, held_out, y, worst, err, errlen);
  for (int q = 0; rc == 0 && q < m->nq; q++) {
    const Sym *s = prog->quantities.v[q];
    bool bad = !(worst[q] <= EXACT_FULL_RANK_TOL);
    *failed |= bad;
    fprintf(out, "     %-16s m = %-7ld %9.2e%s\n", s->name, m->classes[m->qclass[q]].m, worst[q],
            bad ? "  FAIL: the full-rank reduced value differs from the full one" : "");
  }
  /* DESIGN §12: the same model with every eligible stage interpolated at every entry */
  int neligible = 0;
  for (int i = 0; rc == 0 && i < m->nstages; i++) {
    if (!lower_interp_eligible(m->stages[i].st)) continue;
    char why[2048] = "";
    if (interp_train_stage(m, f, i, 1.0, ERR_OF(why, sizeof why)) != 0)
      rc = error_set(err, errlen, "interpolating stage %s at full rank: %s", m->stages[i].st->sym->name, why);
    neligible++;
  }
  if (rc == 0 && neligible > 0) {
    char why[2048] = "";
    reduced_free(r);
    if (!(r = reduced_new(m, ERR_OF(why, sizeof why)))) rc = error_set(err, errlen, "%s", why);
    if (rc == 0) rc = held_out_differences(prog, m, f, r, &held, held_out, y, worst, err, errlen);
    double all = 0;
    for (int q = 0; rc == 0 && q < m->nq; q++) all = isnan(worst[q]) || isnan(all) ? NAN : fmax(all, worst[q]);
    for (int i = 0; rc == 0 && i < m->nstages; i++)
      if (m->stages[i].interp)
        fprintf(out, "     %-16s interpolated at all %ld entries %9.2e\n", m->stages[i].st->sym->name,
                m->stages[i].interp->k, worst[m->stages[i].q]);
    if (rc == 0) {
      bool bad = !(all <= EXACT_FULL_RANK_TOL);
      *failed |= bad;
      fprintf(out, "     with them, every quantity    %9.2e%s\n", all,
              bad ? "  FAIL: the interpolated full-rank model differs from the full one" : "");
    }
  }
  free(y);
  free(worst);
  reduced_free(r);
  model_free(m);
  memsamples_free(&train);
  memsamples_free(&held);
  full_free(f);
  return rc;
}

/* worst[q] <- the largest relative difference of quantity q between the
 * reduced evaluator `r` of full-rank model `m` and the full evaluator `f`
 * over the held-out samples; y holds the largest class. */
static int held_out_differences(const Program *prog, const Model *m, Full *f, Reduced *r, MemSamples *held,
                                long held_out, double *y, double *worst, char *err, size_t errlen) {
  int rc = 0;
  memset(worst, 0, sizeof(double) * (size_t)m->nq);
  reduced_use_given_externs(r, true);
  for (long k = 0; k < held_out && rc == 0; k++) {
    if (memsamples_set(held, f, k) != 0 || full_eval(f, k) != 0) {
      rc = error_set(err, errlen, "the full evaluator on held-out sample %ld: %s", k, full_error(f));
      break;
    }
    for (int i = 0; i < held->n; i++)
      reduced_project(r, vec_position(&prog->quantities, held->sym[i]), held->val[i] + (size_t)k * held->count[i]);
    if (reduced_eval(r, k) != 0) {
      rc = error_set(err, errlen, "the reduced evaluator on held-out sample %ld: %s", k, reduced_error(r));
      break;
    }
    for (int q = 0; q < m->nq; q++) {
      size_t cnt = 0;
      const double *full = full_get(f, ((Sym *)prog->quantities.v[q])->name, &cnt);
      if (!full || (long)cnt != m->classes[m->qclass[q]].n) {
        rc = error_set(err, errlen, "quantity %s: full and reduced sizes differ (a bug in npg)",
                   ((Sym *)prog->quantities.v[q])->name);
        break;
      }
      reduced_lift(r, q, y);
      double d = exact_rel_max_diff(full, y, cnt);
      worst[q] = isnan(d) || isnan(worst[q]) ? NAN : fmax(worst[q], d);
    }
  }
  return rc;
}

int exact_check_program(Program *prog, const ExactOptions *o, FILE *out, char *err, size_t errlen) {
  if (err && errlen) err[0] = '\0';
  fprintf(out, "the exactness checks (README: npgc verify --exact) on random data (seed %u)\n", o->seed);
  bool failed = false;
  if (check_lowering(prog, o, out, &failed, err, errlen) != 0) return -1;
  if (check_full_rank(prog, o, out, &failed, err, errlen) != 0) return -1;
  fprintf(out, failed ? "FAIL: an exactness check failed (a bug in npg: please report it with the program)\n"
                      : "ok: the lowering is exact and full-rank bases reproduce the full evaluator\n");
  return failed ? 1 : 0;
}
