/* interp.c — interpolated stages at run time and on disk (interp.h,
 * DESIGN §12): ŷ = (W P B)⁺ W (P y), P y the stage's formula evaluated exactly
 * at the selected entries from its inputs lifted only where it reads them.
 * Training (backends/train/interp_train.c) selects the entries and builds
 * the tables. */
#include <cblas.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "interp.h"
#include "scratch.h"

const char *const interp_reasons[INTERP_NREASONS] = {
    [INTERP_FORCED] = "forced (--reduce STAGE:interp, or basis STAGE: reduce interp in the program)",
    [INTERP_LOWER] = "interpolation: lower output error",
    [GALERKIN_LOWER] = "Galerkin: lower output error",
    [TIE_INTERP] = "errors tie, interpolation cheaper",
    [TIE_GALERKIN] = "errors tie, Galerkin cheaper",
    [BOTH_FAIL] = "both fail on the validation samples",
    [TOL_INTERP] = "both meet the tolerance, interpolation cheaper",
    [TOL_GALERKIN] = "both meet the tolerance, Galerkin cheaper",
};

static int reason_index(const char *r) {
  for (int i = 0; i < INTERP_NREASONS; i++)
    if (r == interp_reasons[i]) return i;
  return -1;
}

void interp_report(const Model *m, FILE *out) {
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (!rs->interp && !rs->choice_reason) continue;
    fprintf(out, "stage %s: %s", rs->st->sym->name, rs->interp ? "interpolated" : "Galerkin");
    if (rs->interp)
      fprintf(out, " at %ld of %ld entries (m %ld, ‖(WPB)⁺‖ %.3g)", rs->interp->k, m->classes[m->qclass[rs->q]].n,
              rs->interp->m, rs->interp->pinv_norm);
    if (rs->choice_reason && rs->choice_reason != interp_reasons[INTERP_FORCED])
      fprintf(out, "; output error on the validation samples by Galerkin %.3e, by interpolation %.3e: %s",
              rs->choice_err[0], rs->choice_err[1], rs->choice_reason);
    else if (rs->choice_reason) fprintf(out, ": %s", rs->choice_reason);
    fputc('\n', out);
  }
  interp_report_warnings(m, out);
}

/* A choice measured on validation samples whose kept reduction failed on
 * one of them, or whose output error is over 100 % (worse than answering
 * zero): the model is written, as the user may still want it, but never
 * quietly (a cloth bending stage was kept at 298 %, and every evaluation of
 * another failed, with no word). Saved with the model (its `choice`
 * lines), so verify and check say it too; the failure itself is known only
 * to the training that met it (Model.choice_failure). */
#define CHOICE_WARN_ERROR 1.0
void interp_report_warnings(const Model *m, FILE *out) {
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (!rs->choice_reason || rs->choice_reason == interp_reasons[INTERP_FORCED]) continue;
    const char *sn = rs->st->sym->name;
    double kept = rs->choice_err[rs->interp ? 1 : 0];
    if (!isfinite(kept)) {
      fprintf(out, "warning: stage %s: the reduced model fails on the validation samples by Galerkin and by "
                   "interpolation: it will fail on inputs like them; give what the stage reads larger bases "
                   "(--basis NAME:cap=N,energy=E) or train on more samples%s%s\n",
              sn, m->choice_failure[0] ? "; the failure: " : "", m->choice_failure);
    } else if (kept > CHOICE_WARN_ERROR) {
      fprintf(out, "warning: stage %s: output error %.3g (%.0f %%) on the validation samples as reduced by %s (%s %s): "
                   "the model is worse than answering zero there; give what the stage reads larger bases "
                   "(--basis NAME:cap=N,energy=E) or train on more samples\n",
              sn, kept, 100 * kept, rs->interp ? "interpolation" : "Galerkin", rs->interp ? "Galerkin" : "interpolation",
              isfinite(rs->choice_err[rs->interp ? 0 : 1]) ? "is worse" : "fails");
    }
  }
}

void interp_free(RInterp *ip) {
  if (!ip) return;
  free(ip->rows);
  free(ip->pinv);
  free(ip->weight);
  free(ip->read_q);
  free(ip->read_e);
  free(ip->mono);
  free(ip->pk_run_acc);
  free(ip->pk_run_end);
  free(ip->pk_whole_q);
  free(ip->pk_whole_off);
  free(ip->pk_src);
  free(ip->pk_gather_q), free(ip->pk_gather_rows), free(ip->pk_gather_off), free(ip->pk_gather_at);
  free(ip->pk_gather_B);
  free(ip->pk_coef);
  free(ip->pk_nin);
  free(ip->pk_read);
  interp_free(ip->check);
  free(ip->brows);
  free(ip->read_rows);
  free(ip);
}

/* Accumulators: one per (term, factor) per selected entry. */
static long factor_base(const RStage *rs, int term) {
  long f = 0;
  for (int t = 0; t < term; t++) f += 1 + rs->terms[t].nops;
  return f;
}

static size_t work_of(const RStage *rs, const RInterp *ip) {
  return (size_t)(ip->nreads + ip->k * (factor_base(rs, rs->nterms) + 1) + ip->pk_lift + 1);
}

size_t interp_work_size(const RStage *rs) { return work_of(rs, rs->interp); }

/* Monomial order for interp_pack: by accumulator, then as trained (a stable sort). */
typedef struct PackKey {
  long acc, index;
} PackKey;

static int by_acc(const void *a, const void *b) {
  const PackKey *x = a, *y = b;
  return x->acc != y->acc ? (x->acc > y->acc) - (x->acc < y->acc) : (x->index > y->index) - (x->index < y->index);
}

/* pack_lifts' tables of ip (allocated) filled: count, off and next its per-quantity scratch
 * (count and next zeroed). -1 out of memory. */
static int pack_reads(const Model *m, RInterp *ip, long *count, long *off, long *next) {
  for (long r = 0; r < ip->nreads; r++) count[ip->read_q[r]]++;
  ip->pk_nwhole = 0, ip->pk_lift = 0, ip->pk_ngather = 0;
  long gathered = 0;
  for (int q = 0; q < m->nq; q++) {
    const RClass *c = &m->classes[m->qclass[q]];
    off[q] = -1;
    if (count[q] == 0 || (!c->B && !ip->read_rows)) continue; /* no basis (streamed): read row by row, as trained */
    off[q] = ip->pk_lift;
    if (4 * count[q] >= c->n && !ip->read_rows) {
      ip->pk_whole_q[ip->pk_nwhole] = q, ip->pk_whole_off[ip->pk_nwhole++] = ip->pk_lift;
      ip->pk_lift += c->n;
    } else {
      int g = ip->pk_ngather++;
      ip->pk_gather_q[g] = q, ip->pk_gather_rows[g] = count[q], ip->pk_gather_off[g] = ip->pk_lift;
      ip->pk_gather_at[g] = gathered;
      ip->pk_lift += count[q];
      gathered += count[q] * c->m;
    }
  }
  if (!(ip->pk_gather_B = mem_malloc(sizeof(double) * (size_t)(gathered + 1)))) return -1;
  for (long r = 0, at = 0; r < ip->nreads; r++) {
    int q = ip->read_q[r];
    const RClass *c = &m->classes[m->qclass[q]];
    const double *row = ip->read_rows ? ip->read_rows + at : c->B + ip->read_e[r] * c->m;
    at += c->m;
    if (off[q] < 0) {
      ip->pk_src[r] = -1;
    } else if (4 * count[q] >= c->n && !ip->read_rows) {
      ip->pk_src[r] = off[q] + ip->read_e[r];
    } else {
      int g = 0;
      while (ip->pk_gather_q[g] != q) g++;
      long j = next[q]++;
      memcpy(ip->pk_gather_B + ip->pk_gather_at[g] + j * c->m, row, sizeof(double) * (size_t)c->m);
      ip->pk_src[r] = off[q] + j;
    }
  }
  return 0;
}

/* Which quantities interp_eval lifts whole (RInterp.pk_whole_*) and which it reads through their
 * gathered basis rows (pk_gather_*): 0, or -1 out of memory. */
static int pack_lifts(const Model *m, RInterp *ip) {
  free(ip->pk_whole_q), free(ip->pk_whole_off), free(ip->pk_src);
  free(ip->pk_gather_q), free(ip->pk_gather_rows), free(ip->pk_gather_off), free(ip->pk_gather_at);
  free(ip->pk_gather_B);
  ip->pk_gather_q = NULL, ip->pk_gather_rows = ip->pk_gather_off = ip->pk_gather_at = NULL, ip->pk_gather_B = NULL;
  Scratch sc = SCRATCH_OF(NULL);
  long *count = scratch_array(&sc, (size_t)m->nq + 1, sizeof(long)), *off = scratch_array(&sc, (size_t)m->nq + 1, sizeof(long));
  long *next = scratch_array(&sc, (size_t)m->nq + 1, sizeof(long));
  ip->pk_whole_q = mem_malloc(sizeof(int) * (size_t)(m->nq + 1));
  ip->pk_whole_off = mem_malloc(sizeof(long) * (size_t)(m->nq + 1));
  ip->pk_src = mem_malloc(sizeof(long) * (size_t)(ip->nreads + 1));
  ip->pk_gather_q = mem_malloc(sizeof(int) * (size_t)(m->nq + 1));
  ip->pk_gather_rows = mem_malloc(sizeof(long) * (size_t)(m->nq + 1));
  ip->pk_gather_off = mem_malloc(sizeof(long) * (size_t)(m->nq + 1));
  ip->pk_gather_at = mem_malloc(sizeof(long) * (size_t)(m->nq + 1));
  int rc = count && off && next && ip->pk_whole_q && ip->pk_whole_off && ip->pk_src && ip->pk_gather_q &&
                   ip->pk_gather_rows && ip->pk_gather_off && ip->pk_gather_at
               ? pack_reads(m, ip, count, off, next)
               : -1;
  scratch_release(&sc);
  return rc;
}

int interp_pack(const Model *m, const RStage *rs, RInterp *ip) {
  if (pack_lifts(m, ip)) return -1;
  long nread = 0, n = ip->nmono;
  for (long i = 0; i < n; i++) nread += ip->mono[i].nin;
  free(ip->pk_run_acc), free(ip->pk_run_end), free(ip->pk_coef), free(ip->pk_nin), free(ip->pk_read);
  Scratch sc = SCRATCH_OF(NULL);
  PackKey *key = scratch_array(&sc, (size_t)(n + 1), sizeof(PackKey));
  ip->pk_run_acc = mem_malloc(sizeof(long) * (size_t)(n + 1));
  ip->pk_run_end = mem_malloc(sizeof(long) * (size_t)(n + 1));
  ip->pk_coef = mem_malloc(sizeof(double) * (size_t)(n + 1));
  ip->pk_nin = mem_malloc((size_t)n + 1);
  ip->pk_read = mem_malloc(sizeof(int32_t) * (size_t)(nread + 1));
  int rc = key && ip->pk_run_acc && ip->pk_run_end && ip->pk_coef && ip->pk_nin && ip->pk_read ? 0 : -1;
  for (long i = 0; i < n && rc == 0; i++)
    key[i] = (PackKey){(factor_base(rs, ip->mono[i].term) + ip->mono[i].factor) * ip->k + ip->mono[i].slot, i};
  if (rc == 0) qsort(key, (size_t)n, sizeof *key, by_acc);
  int32_t *rd = ip->pk_read;
  ip->pk_nrun = 0;
  for (long i = 0; i < n && rc == 0; i++) {
    const RInterpMono *mo = &ip->mono[key[i].index];
    if (i == 0 || key[i].acc != key[i - 1].acc) ip->pk_run_acc[ip->pk_nrun++] = key[i].acc;
    ip->pk_run_end[ip->pk_nrun - 1] = i + 1;
    ip->pk_coef[i] = mo->coef;
    ip->pk_nin[i] = (unsigned char)mo->nin;
    for (int j = 0; j < mo->nin; j++) *rd++ = (int32_t)mo->read[j];
  }
  scratch_release(&sc);
  return rc;
}

/* b^(p/q): integer powers by multiplication and half-integer ones through one sqrt (an
 * interpolated stage takes one per selected entry and operator: pow() was a measurable part
 * of its time), others by pow(). */
static double rational_pow(double b, long p, long q) {
  if ((q == 1 || q == 2) && p >= -16 && p <= 16) {
    double base = q == 2 ? sqrt(b) : b, v = 1;
    for (long i = 0; i < labs(p); i++) v *= base;
    return p < 0 ? 1 / v : v;
  }
  return pow(b, (double)p / (double)q);
}

/* A packed monomial's value: its coefficient times the `nin` lifted entries *rd names (advanced
 * past them); the common degrees unrolled. */
static inline double mono_value(double coef, int nin, const int32_t **rd, const double *val) {
  const int32_t *r = *rd;
  *rd = r + nin;
  switch (nin) {
  case 0: return coef;
  case 1: return coef * val[r[0]];
  case 2: return coef * val[r[0]] * val[r[1]];
  case 3: return coef * val[r[0]] * val[r[1]] * val[r[2]];
  default:
    for (int j = 0; j < nin; j++) coef *= val[r[j]];
    return coef;
  }
}

int interp_eval(const Model *m, const RStage *rs, const InterpAt *at, double *y, Err *err) {
  double *const *x = at->x, *work = at->work;
  long sample = at->sample;
  const RInterp *ip = rs->interp;
  long k = ip->k, nf = factor_base(rs, rs->nterms);
  double *val = work, *acc = work + ip->nreads, *py = acc + k * nf, *lift = py + k;
  /* the entries the formula reads: the quantities read at many entries lifted whole, the
   * others one row of their basis each */
  for (int w = 0; w < ip->pk_nwhole; w++) {
    const RClass *c = &m->classes[m->qclass[ip->pk_whole_q[w]]];
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)c->n, (int)c->m, 1.0, c->B, (int)(c->m > 0 ? c->m : 1),
                x[ip->pk_whole_q[w]], 1, 0.0, lift + ip->pk_whole_off[w], 1);
  }
  for (int g = 0; g < ip->pk_ngather; g++) {
    const RClass *c = &m->classes[m->qclass[ip->pk_gather_q[g]]];
    if (c->m == 0) {
      memset(lift + ip->pk_gather_off[g], 0, sizeof(double) * (size_t)ip->pk_gather_rows[g]);
      continue;
    }
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)ip->pk_gather_rows[g], (int)c->m, 1.0,
                ip->pk_gather_B + ip->pk_gather_at[g], (int)c->m, x[ip->pk_gather_q[g]], 1, 0.0,
                lift + ip->pk_gather_off[g], 1);
  }
  for (long r = 0; r < ip->nreads; r++) {
    const RClass *c = &m->classes[m->qclass[ip->read_q[r]]];
    val[r] = ip->pk_src[r] >= 0 ? lift[ip->pk_src[r]]
                                : cblas_ddot((int)c->m, c->B + ip->read_e[r] * c->m, 1, x[ip->read_q[r]], 1);
  }
  memset(acc, 0, sizeof(double) * (size_t)(k * nf));
  const int32_t *rd = ip->pk_read;
  for (long r = 0, i = 0; r < ip->pk_nrun; r++) { /* two sums per run: half the dependent additions */
    double s0 = 0, s1 = 0;
    long end = ip->pk_run_end[r];
    for (; i + 1 < end; i += 2) {
      double v0 = mono_value(ip->pk_coef[i], ip->pk_nin[i], &rd, val);
      s1 += mono_value(ip->pk_coef[i + 1], ip->pk_nin[i + 1], &rd, val);
      s0 += v0;
    }
    if (i < end) s0 += mono_value(ip->pk_coef[i], ip->pk_nin[i], &rd, val), i++;
    acc[ip->pk_run_acc[r]] += s0 + s1;
  }
  /* y at the selected entries: Σ_t Π_o d_{t,o}^(p/q) q_t, entry by entry */
  memset(py, 0, sizeof(double) * (size_t)k);
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    const double *num = acc + factor_base(rs, t) * k;
    for (long s = 0; s < k; s++) {
      double v = num[s];
      for (int o = 0; o < rt->nops; o++) v *= rational_pow(num[(o + 1) * k + s], rt->ops[o].op->p, rt->ops[o].op->q);
      py[s] += v;
    }
  }
  char where[64];
  if (sample >= 0) snprintf(where, sizeof where, "at sample %ld", sample);
  else snprintf(where, sizeof where, "at these inputs"); /* no sample of a set (npg_reduced_eval) */
  for (long s = 0; s < k; s++)
    if (!isfinite(py[s]))
      return err_set(err, "stage %s (interpolated) is not finite at its selected entry %ld %s (a diagonal zero "
                     "under a negative power, or a root of a negative value, from its inputs' reduced values)",
                     rs->st->sym->name, ip->rows[s], where);
  if (ip->m == 0 || k == 0) memset(y, 0, sizeof(double) * (size_t)ip->m); /* (a forged model: BLAS wants lda >= 1) */
  else cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)ip->m, (int)k, 1.0, ip->pinv, (int)k, py, 1, 0.0, y, 1);
  return 0;
}

size_t interp_check_work_size(const RStage *rs) {
  const RInterp *ip = rs->interp, *ck = ip ? ip->check : rs->check;
  size_t a = ip ? work_of(rs, ip) : 0, b = ck ? work_of(rs, ck) : 0;
  return (a > b ? a : b) + (size_t)(ip ? ip->m : 0) + 1;
}

int interp_check(const Model *m, const RStage *rs, double *const *x, double *work, InterpCheck *out, Err *err) {
  const RInterp *ip = rs->interp, *ck = ip ? ip->check : rs->check;
  if (!ck)
    return err_set(err, "the model holds no check entries for stage %s (trained before its estimate: "
                   "retrain)", rs->st->sym->name);
  long mm = m->classes[m->qclass[rs->q]].m, n = m->classes[m->qclass[rs->q]].n, k = ip ? ip->k : 0;
  const double *yh = x[rs->q];
  double *fit = work, *w = work + (ip ? ip->m : 0), sum[2] = {0, 0};
  RStage one = *rs;
  for (int pass = ip ? 0 : 1; pass < 2; pass++) { /* the fit's entries, then the check's */
    const RInterp *t = pass ? ck : ip;
    one.interp = (RInterp *)t;
    if (interp_eval(m, &one, &(InterpAt){x, w, -1}, fit, err)) return -1;
    const double *py = w + t->nreads + t->k * factor_base(rs, rs->nterms), *B = ck->brows + (pass ? k * mm : 0);
    for (long j = 0; j < t->k; j++) {
      double d = py[j] - (mm > 0 ? cblas_ddot((int)mm, B + j * mm, 1, yh, 1) : 0);
      sum[pass] += d * d;
    }
  }
  out->exact = ck->k == n - k;
  out->est = sqrt(sum[0] + (ck->k > 0 ? (double)(n - k) / (double)ck->k * sum[1] : 0));
  return 0;
}

/* ---------------------------------------------------------------- on disk
 *
 * Per interpolated stage y, the manifest line
 *
 *   interp y k K m M reads R monos N norm ‖(WPB)⁺‖₂
 *
 * and the arrays (integers held exactly as float64, as every array of a model is):
 *   interp_y_rows   K        the selected entries
 *   interp_y_pinv   M x K    (W P B)⁺ W (the weighted fit)
 *   interp_y_reads  R x 2    (quantity, flat entry) lifted
 *   interp_y_monos  N x (5 + RT_MAX_IN): term, factor, slot, coefficient, inputs, reads (-1 padded)
 *
 * then, for the error estimate's check table (interp_check), the line
 *
 *   interpcheck y k K' reads R' monos N'
 *
 * with interp_y_check_rows, _check_reads, _check_monos as above and interp_y_check_brows
 * ((K + K') x M: the basis rows at the fit's entries, then at the check's) and
 * interp_y_check_readrows (per read of the check, its quantity's basis row, Σ m_q). A Galerkin
 * stage of diagonal operators has the same as `galerkincheck y k K' reads R' monos N'` (K = 0). */

#define MONO_COLS (5 + RT_MAX_IN)

static void stem(char *buf, size_t n, const char *stage, const char *what) {
  snprintf(buf, n, "interp_%s_%s", stage, what);
}

/* The length of a check table's read_rows: Σ over its reads of m of the quantity's class. */
static long check_row_len(const Model *m, const RInterp *ck) {
  long len = 0;
  for (long r = 0; r < ck->nreads; r++) len += m->classes[m->qclass[ck->read_q[r]]].m;
  return len;
}

/* Table ip's rows, reads and monomials as arrays interp_SN_PREFIXrows, …reads, …monos, each
 * staged in `t` (room for the largest). */
static int save_table_in(ModelStore *s, const char *sn, const char *pre, const RInterp *ip, double *t) {
  char name[600], what[64];
  int bad = 0;
  for (long j = 0; j < ip->k; j++) t[j] = (double)ip->rows[j];
  long shape[2] = {ip->k, 0};
  snprintf(what, sizeof what, "%srows", pre);
  stem(name, sizeof name, sn, what);
  bad |= model_store_add(s, name, 1, shape, t);
  for (long r = 0; r < ip->nreads; r++) t[2 * r] = ip->read_q[r], t[2 * r + 1] = (double)ip->read_e[r];
  shape[0] = ip->nreads, shape[1] = 2;
  snprintf(what, sizeof what, "%sreads", pre);
  stem(name, sizeof name, sn, what);
  bad |= model_store_add(s, name, 2, shape, t);
  for (long j = 0; j < ip->nmono; j++) {
    const RInterpMono *mo = &ip->mono[j];
    double *row = t + j * MONO_COLS;
    row[0] = mo->term, row[1] = mo->factor, row[2] = (double)mo->slot, row[3] = mo->coef, row[4] = mo->nin;
    for (int c = 0; c < RT_MAX_IN; c++) row[5 + c] = c < mo->nin ? (double)mo->read[c] : -1;
  }
  shape[0] = ip->nmono, shape[1] = MONO_COLS;
  snprintf(what, sizeof what, "%smonos", pre);
  stem(name, sizeof name, sn, what);
  bad |= model_store_add(s, name, 2, shape, t);
  return bad;
}

/* save_table_in with its table (`t`) from a scratch. */
static int save_table(ModelStore *s, const char *sn, const char *pre, const RInterp *ip) {
  Scratch sc = SCRATCH_OF(NULL);
  double *t = scratch_array(&sc, (size_t)(ip->k + 2 * ip->nreads + MONO_COLS * ip->nmono + 1), sizeof(double));
  int bad = t ? save_table_in(s, sn, pre, ip, t) : -1;
  scratch_release(&sc);
  return bad;
}

int interp_save(const Model *m, ModelStore *s) {
  int bad = 0;
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    int why = rs->choice_reason ? reason_index(rs->choice_reason) : -1;
    if (why >= 0)
      bad |= model_store_meta(s, "choice %s galerkin %.17g interp %.17g reason %d", rs->st->sym->name,
                              rs->choice_err[0], rs->choice_err[1], why);
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    const RInterp *ip = rs->interp;
    if (!ip) continue;
    const char *sn = rs->st->sym->name;
    s->format = s->format > 2 ? s->format : 2;
    bad |= model_store_meta(s, "interp %s k %ld m %ld reads %ld monos %ld norm %.17g", sn, ip->k, ip->m, ip->nreads,
                            ip->nmono, ip->pinv_norm);
    char name[600];
    long shape[2] = {ip->m, ip->k};
    stem(name, sizeof name, sn, "pinv");
    bad |= model_store_add(s, name, 2, shape, ip->pinv);
    bad |= save_table(s, sn, "", ip);
  }
  for (int i = 0; i < m->nstages; i++) { /* the estimate's check tables, after every interp line */
    const RStage *rs = &m->stages[i];
    const RInterp *ck = rs->interp ? rs->interp->check : rs->check;
    if (!ck) continue;
    const char *sn = rs->st->sym->name;
    long kfit = rs->interp ? rs->interp->k : 0;
    bad |= model_store_meta(s, "%s %s k %ld reads %ld monos %ld", rs->interp ? "interpcheck" : "galerkincheck", sn,
                            ck->k, ck->nreads, ck->nmono);
    bad |= save_table(s, sn, "check_", ck);
    char name[600];
    long shape[2] = {kfit + ck->k, m->classes[m->qclass[rs->q]].m};
    stem(name, sizeof name, sn, "check_brows");
    bad |= model_store_add(s, name, 2, shape, ck->brows);
    shape[0] = check_row_len(m, ck);
    stem(name, sizeof name, sn, "check_readrows");
    bad |= model_store_add(s, name, 1, shape, ck->read_rows);
  }
  return bad ? -1 : 0;
}

/* One stage's arrays in a store being loaded: the store, its folder (for
 * messages), the stage's name, and where a failure's message goes. */
typedef struct StageArrays {
  const ModelStore *s;
  const char *dir, *sn;
  Err *err;
} StageArrays;

/* Array `what` of the stage, of `rows` x `cols` (cols 0: a vector). */
static const double *array_of(const StageArrays *sa, const char *what, long rows, long cols) {
  const ModelStore *s = sa->s;
  const char *dir = sa->dir, *sn = sa->sn;
  Err *err = sa->err;
  char name[600];
  stem(name, sizeof name, sn, what);
  const NpyArray *a = model_store_array(s, name);
  if (!a) {
    err_set(err, "%s/manifest: no array '%s': the model is incomplete", dir, name);
    return NULL;
  }
  if (a->ndim != (cols ? 2 : 1) || a->shape[0] != rows || (cols && a->shape[1] != cols)) {
    err_set(err, "%s/%s.npy: wrong shape for the manifest's 'interp %s' line", dir, name, sn);
    return NULL;
  }
  return a->data;
}

/* An integer held as a double, in [lo, hi). */
static bool whole_in(double v, long lo, long hi) { return v == floor(v) && v >= (double)lo && v < (double)hi; }

/* Table ip's rows, reads and monomials (ip->k, nreads, nmono set) from arrays interp_SN_PREFIX…
 * of stage rs, every entry checked against the program. 0, or -1 with `err`. */
static int load_table(Model *m, const StageArrays *sa, const char *pre, RStage *rs, RInterp *ip) {
  const char *dir = sa->dir, *sn = sa->sn;
  Err *err = sa->err;
  const RClass *c = &m->classes[m->qclass[rs->q]];
  long k = ip->k, nreads = ip->nreads, nmono = ip->nmono;
  char w[3][64];
  snprintf(w[0], sizeof w[0], "%srows", pre), snprintf(w[1], sizeof w[1], "%sreads", pre);
  snprintf(w[2], sizeof w[2], "%smonos", pre);
  const double *rows = array_of(sa, w[0], k, 0);
  const double *reads = rows ? array_of(sa, w[1], nreads, 2) : NULL;
  const double *monos = reads ? array_of(sa, w[2], nmono, MONO_COLS) : NULL;
  if (!monos) return -1;
  ip->rows = mem_malloc(sizeof(long) * (size_t)(k + 1));
  ip->read_q = mem_malloc(sizeof(int) * (size_t)(nreads + 1));
  ip->read_e = mem_malloc(sizeof(long) * (size_t)(nreads + 1));
  ip->mono = mem_malloc(sizeof(RInterpMono) * (size_t)(nmono + 1));
  if (!ip->rows || !ip->read_q || !ip->read_e || !ip->mono)
    return err_set(err, "%s: out of memory loading the model", dir);
  const char *bad = NULL;
  for (long j = 0; j < k && !bad; j++) {
    if (!whole_in(rows[j], 0, c->n)) bad = w[0];
    ip->rows[j] = (long)rows[j];
  }
  for (long r = 0; r < nreads && !bad; r++) {
    if (!whole_in(reads[2 * r], 0, m->nq)) {
      bad = w[1];
      break;
    }
    ip->read_q[r] = (int)reads[2 * r];
    if (!whole_in(reads[2 * r + 1], 0, m->classes[m->qclass[ip->read_q[r]]].n)) bad = w[1];
    ip->read_e[r] = (long)reads[2 * r + 1];
  }
  for (long j = 0; j < nmono && !bad; j++) {
    const double *row = monos + j * MONO_COLS;
    RInterpMono *mo = &ip->mono[j];
    if (!whole_in(row[0], 0, rs->nterms) || !whole_in(row[4], 0, RT_MAX_IN + 1) || !isfinite(row[3]) ||
        !whole_in(row[2], 0, k)) {
      bad = w[2];
      break;
    }
    mo->term = (int)row[0];
    if (!whole_in(row[1], 0, rs->terms[mo->term].nops + 1)) {
      bad = w[2];
      break;
    }
    mo->factor = (int)row[1], mo->slot = (long)row[2], mo->coef = row[3], mo->nin = (int)row[4];
    for (int i = 0; i < mo->nin && !bad; i++) {
      if (!whole_in(row[5 + i], 0, nreads)) bad = w[2];
      mo->read[i] = (long)row[5 + i];
    }
  }
  if (bad)
    return err_set(err, "%s/interp_%s_%s.npy: an entry out of range for the stage (a damaged or forged model)",
                   dir, sn, bad);
  if (interp_pack(m, rs, ip)) return err_set(err, "%s: out of memory loading the model", dir);
  return 0;
}

static int load_stage(Model *m, const ModelStore *s, const char *dir, const char *line, Err *err) {
  char sn[512];
  long k, mm, nreads, nmono;
  double norm;
  int used = 0;
  if (sscanf(line, "interp %511s k %ld m %ld reads %ld monos %ld norm %lf%n", sn, &k, &mm, &nreads, &nmono, &norm,
             &used) != 6 ||
      line[used])
    return err_set(err, "%s/manifest: '%.200s' is not an 'interp' line this npgc reads", dir, line);
  RStage *rs = NULL;
  for (int i = 0; i < m->nstages && !rs; i++)
    if (strcmp(m->stages[i].st->sym->name, sn) == 0) rs = &m->stages[i];
  if (!rs || !lower_interp_eligible(rs->st) || rs->interp)
    return err_set(err, "%s/manifest: '%.200s': %s", dir, line,
                   !rs ? "the program has no such stage" : rs->interp ? "the stage is named twice"
                                                                     : "the stage is not eligible for interpolation");
  const RClass *c = &m->classes[m->qclass[rs->q]];
  if (mm != c->m || k < mm || k > c->n || nreads < 0 || nmono < 0 || nreads > 100000000 || nmono > 100000000 ||
      !(norm >= 0))
    return err_set(err, "%s/manifest: '%.200s' does not fit the stage's class %s (n %ld, m %ld)", dir, line,
                   c->label, c->n, c->m);
  StageArrays sa = {s, dir, sn, err};
  const double *pinv = array_of(&sa, "pinv", mm, k);
  if (!pinv) return -1;
  RInterp *ip = mem_calloc(1, sizeof *ip);
  if (!ip) return err_set(err, "%s: out of memory loading the model", dir);
  rs->interp = ip;
  ip->k = k, ip->m = mm, ip->nreads = nreads, ip->nmono = nmono, ip->pinv_norm = norm;
  if (!(ip->pinv = mem_malloc(sizeof(double) * (size_t)(mm * k + 1))))
    return err_set(err, "%s: out of memory loading the model", dir);
  memcpy(ip->pinv, pinv, sizeof(double) * (size_t)(mm * k));
  for (long j = 0; j < mm * k; j++)
    if (!isfinite(pinv[j]))
      return err_set(err, "%s/interp_%s_pinv.npy: not finite at entry %ld (a damaged or forged model)", dir,
                     sn, j);
  return load_table(m, &sa, "", rs, ip);
}

/* "interpcheck STAGE k K reads R monos N", after the stage's `interp` line, or "galerkincheck …" for
 * a Galerkin stage of diagonal operators: the stage's check table. */
static int load_check(Model *m, const ModelStore *s, const char *dir, const char *line, Err *err) {
  char sn[512], kind[16];
  long k, nreads, nmono;
  int used = 0;
  RStage *rs = NULL;
  if (sscanf(line, "%15s %511s k %ld reads %ld monos %ld%n", kind, sn, &k, &nreads, &nmono, &used) == 5 && !line[used])
    for (int i = 0; i < m->nstages && !rs; i++)
      if (strcmp(m->stages[i].st->sym->name, sn) == 0) rs = &m->stages[i];
  bool fit = rs && strcmp(kind, "interpcheck") == 0;
  long kfit = fit && rs->interp ? rs->interp->k : 0, mm = rs ? m->classes[m->qclass[rs->q]].m : 0;
  if (!rs || (fit ? !rs->interp || rs->interp->check : rs->interp || rs->check || !lower_interp_eligible(rs->st)) ||
      k < 0 || k > m->classes[m->qclass[rs->q]].n - kfit || nreads < 0 || nmono < 0 || nreads > 100000000 ||
      nmono > 100000000)
    return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                   dir, line);
  RInterp *ck = mem_calloc(1, sizeof *ck);
  if (!ck) return err_set(err, "%s: out of memory loading the model", dir);
  *(fit ? &rs->interp->check : &rs->check) = ck;
  ck->k = k, ck->nreads = nreads, ck->nmono = nmono;
  StageArrays sa = {s, dir, sn, err};
  const double *B = array_of(&sa, "check_brows", kfit + k, mm);
  if (!B) return -1;
  if (!(ck->brows = mem_malloc(sizeof(double) * (size_t)((kfit + k) * mm + 1))))
    return err_set(err, "%s: out of memory loading the model", dir);
  memcpy(ck->brows, B, sizeof(double) * (size_t)((kfit + k) * mm));
  if (load_table(m, &sa, "check_", rs, ck)) return -1;
  long len = check_row_len(m, ck);
  const double *rows = array_of(&sa, "check_readrows", len, 0);
  if (!rows) return -1;
  if (!(ck->read_rows = mem_malloc(sizeof(double) * (size_t)(len + 1))))
    return err_set(err, "%s: out of memory loading the model", dir);
  memcpy(ck->read_rows, rows, sizeof(double) * (size_t)len);
  if (interp_pack(m, rs, ck)) return err_set(err, "%s: out of memory loading the model", dir);
  return 0;
}

/* A `choice` line: the stage's measured errors and reason. */
static int load_choice(Model *m, const char *dir, const char *line, Err *err) {
  char sn[512];
  double g, e;
  int why, used = 0;
  RStage *rs = NULL;
  if (sscanf(line, "choice %511s galerkin %lf interp %lf reason %d%n", sn, &g, &e, &why, &used) == 4 && !line[used] &&
      why >= 0 && why < INTERP_NREASONS && !(g < 0) && !(e < 0))
    for (int i = 0; i < m->nstages && !rs; i++)
      if (strcmp(m->stages[i].st->sym->name, sn) == 0 && lower_interp_eligible(m->stages[i].st)) rs = &m->stages[i];
  if (!rs || rs->choice_reason)
    return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                   dir, line);
  rs->choice_err[0] = g, rs->choice_err[1] = e, rs->choice_reason = interp_reasons[why];
  return 0;
}

int interp_load(Model *m, const ModelStore *s, const char *dir, Err *err) {
  int n = 0;
  for (int i = 0; i < s->nmeta; i++) {
    if (strncmp(s->meta[i], "choice ", 7) == 0 && load_choice(m, dir, s->meta[i], err)) return -1;
    if ((strncmp(s->meta[i], "interpcheck ", 12) == 0 || strncmp(s->meta[i], "galerkincheck ", 14) == 0) &&
        load_check(m, s, dir, s->meta[i], err))
      return -1;
    if (strncmp(s->meta[i], "interp ", 7) != 0) continue;
    if (s->format < 2)
      return err_set(err, "%s/manifest: an 'interp' line in a model of format 1 (a damaged or forged manifest)",
                     dir);
    if (load_stage(m, s, dir, s->meta[i], err)) return -1;
    n++;
  }
  if (s->format == 2 && n == 0)
    return err_set(err, "%s/manifest: format 2 but no interpolated stage (a damaged or forged manifest)", dir);
  return 0;
}
