/* estimate_train.c — the tables of the online estimate (estimate.h, DESIGN
 * §16, issue 41), built in training while the bases exist:
 *
 *   - per eligible term, the residual's columns C_t (n x D: the numerator's
 *     full-space monomials, then −M B_y ⊗ each operator tensor's monomials),
 *     streamed from the same tensor builders pre-multiplication reads,
 *     projected twice by I − BBᵀ and reduced to G_t = C'ᵀC' (dsyrk);
 *   - per inverse term, c = min over up to ESTIMATE_SIGMA_SAMPLES training
 *     samples of σ_min(M)/σ_min(BᵀMB), the full operator assembled dense
 *     from its builders (dgesvd), up to ESTIMATE_DENSE_MAX rows;
 *   - per input, each reduced coordinate's min and max over the training
 *     samples (the trust signal).
 * In memory only: out of core and over ranks the model gets no tables (its
 * evaluations then say so), and neither with externs, whose samples are
 * not set a second time (their callbacks may take seconds a sample). */
#include <cblas.h>
#include <lapacke.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "estimate.h"
#include "train.h"

/* Columns of a term no larger than this (bytes), and no more than ESTIMATE_MAX_DIM of them, are
 * built; a larger term gets no table (its G costs n D² flops: at D = 3600 and n = 16,384, the
 * heat example's implicit step, training took minutes longer and ran out of memory). */
#define ESTIMATE_MAX_BYTES ((size_t)64 << 20)
#define ESTIMATE_MAX_DIM 512

/* The sink filling one tensor's block of the columns: entries arrive as
 * (row, col, input offsets, coefficient). */
typedef struct ColSink {
  const Model *m;
  const RTensor *t;
  double *C;                /* n x D row-major */
  long n, D, off;           /* the block starts at column off */
  const double *By;         /* an operator's: the stage basis (n x my); NULL for a numerator */
  long my;
  double *v, *pack;         /* the entry's monomials (cols), a packed power's scratch */
} ColSink;

static int col_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  ColSink *s = user;
  const RTensor *t = s->t;
  const Model *m = s->m;
  if (row < 0 || row >= s->n) return -1;
  s->v[0] = coef;
  long len = 1;
  for (int pos = 0, j = 0; j < t->nin; j++) {
    const RClass *c = &m->classes[m->qclass[t->in_q[j]]];
    const double *rows[RT_MAX_IN];
    for (int l = 0; l < t->in_mult[j]; l++, pos++) {
      if (pos >= nin || in[pos] < 0 || in[pos] >= c->n) return -1;
      rows[l] = c->B + (long)in[pos] * c->m;
    }
    sym_outer(c->m, t->in_mult[j], rows, s->pack);
    long lj = t->in_len[j];
    for (long a = len - 1; a >= 0; a--) {
      double va = s->v[a];
      for (long b = lj - 1; b >= 0; b--) s->v[a * lj + b] = va * s->pack[b];
    }
    len *= lj;
  }
  double *Cr = s->C + (long)row * s->D + s->off;
  if (!s->By) {
    for (long c = 0; c < t->cols; c++) Cr[c] += s->v[c];
    return 0;
  }
  long k = t->kind == RT_DIAG ? (long)row : (long)col;
  if (k < 0 || k >= s->n) return -1;
  const double *b = s->By + k * s->my;
  for (long a = 0; a < s->my; a++)
    for (long c = 0; c < t->cols; c++) Cr[a * t->cols + c] -= b[a] * s->v[c];
  return 0;
}

static int fill_block(Model *m, Full *f, const RTensor *t, ColSink *s, char *err, size_t errlen) {
  s->t = t;
  NpgSink sink = {s, col_entry, 0, 1, 0, 0};
  if (full_build(f, t->builder, &sink) != 0)
    return error_set(err, errlen, "estimate tables: tensor %s: %s", t->name, full_error(f)[0] ? full_error(f) :
                     "an entry outside its rows (a bug in npg)");
  (void)m;
  return 0;
}

/* C (n x D) <- (I − BBᵀ) C, twice (one projection leaves ε‖C‖ of B's span). */
static int project_out(const RClass *rc, double *C, long D) {
  double *T = malloc(sizeof(double) * (size_t)(rc->m * D) + 1);
  if (!T) return -1;
  for (int pass = 0; pass < 2 && rc->m > 0; pass++) {
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)rc->m, (int)D, (int)rc->n, 1.0, rc->B, (int)rc->m, C,
                (int)D, 0.0, T, (int)D);
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)rc->n, (int)D, (int)rc->m, -1.0, rc->B, (int)rc->m, T,
                (int)D, 1.0, C, (int)D);
  }
  free(T);
  return 0;
}

/* Term t of stage i: its columns, their norms and the projected Gram into rt->est_G. */
static int term_table(Model *m, Full *f, int i, int t, char *err, size_t errlen) {
  RStage *rs = &m->stages[i];
  RTerm *rt = &rs->terms[t];
  const RClass *rc = &m->classes[m->qclass[rs->q]];
  long n = rc->n, D = estimate_term_dim(m, i, t), maxcols = 1, maxpack = 1;
  RTERM_FOR_TENSORS(rt, x) {
    maxcols = x->cols > maxcols ? x->cols : maxcols;
    for (int j = 0; j < x->nin; j++) maxpack = x->in_len[j] > maxpack ? x->in_len[j] : maxpack;
    for (int j = 0; j < x->nin; j++)
      if (!m->classes[m->qclass[x->in_q[j]]].B) return 0; /* an input's basis is not whole here */
  }
  if (rt->named_q >= 0 && (!m->classes[m->qclass[rt->named_q]].B || m->classes[m->qclass[rt->named_q]].n != n)) return 0;
  if ((size_t)n * (size_t)D * sizeof(double) > ESTIMATE_MAX_BYTES || D > ESTIMATE_MAX_DIM) return 0;
  ColSink s = {m, NULL, calloc((size_t)(n * D) + 1, sizeof(double)), n, D, 0, NULL, rc->m,
               malloc(sizeof(double) * (size_t)maxcols), malloc(sizeof(double) * (size_t)maxpack)};
  double *G = calloc((size_t)((D + 1) * D) + 1, sizeof(double));
  int rc_ = -1;
  if (!s.C || !s.v || !s.pack || !G) {
    error_set(err, errlen, "estimate tables: out of memory for stage %s (%ld x %ld columns)", rs->st->sym->name, n, D);
    goto done;
  }
  if (rt->named_q >= 0) {
    const RClass *cw = &m->classes[m->qclass[rt->named_q]];
    for (long row = 0; row < n; row++) memcpy(s.C + row * D, cw->B + row * cw->m, sizeof(double) * (size_t)cw->m);
    s.off = cw->m;
  }
  for (int g = 0; g < rt->nnum; g++, s.off += rt->num[g - 1].cols)
    if (fill_block(m, f, &rt->num[g], &s, err, errlen)) goto done;
  s.By = rc->B;
  for (int k = 0; k < rt->nops; k++)
    for (int g = 0; g < rt->ops[k].ntensors; g++, s.off += rc->m * rt->ops[k].t[g - 1].cols)
      if (fill_block(m, f, &rt->ops[k].t[g], &s, err, errlen)) goto done;
  for (long c = 0; c < D; c++) G[D * D + c] = cblas_dnrm2((int)n, s.C + c, (int)D);
  if (project_out(rc, s.C, D)) {
    error_set(err, errlen, "estimate tables: out of memory projecting stage %s", rs->st->sym->name);
    goto done;
  }
  cblas_dsyrk(CblasRowMajor, CblasUpper, CblasTrans, (int)D, (int)n, 1.0, s.C, (int)D, 0.0, G, (int)D);
  for (long a = 0; a < D; a++)
    for (long b = a + 1; b < D; b++) G[b * D + a] = G[a * D + b];
  rt->est_G = G, rt->est_D = D, rt->est_sigma = NAN;
  G = NULL;
  rc_ = 0;
done:
  free(s.C), free(s.v), free(s.pack), free(G);
  return rc_;
}

/* The dense full operator's sink: value coef · Π input entries at (row, col), or (row, row) for a diagonal one. */
typedef struct DenseSink {
  const double *in[64];
  double *M;
  long n;
  bool diag;
} DenseSink;

static int dense_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  DenseSink *s = user;
  long c = s->diag ? (long)row : (long)col;
  if (row < 0 || row >= s->n || c < 0 || c >= s->n || nin > 64) return -1;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  s->M[row * s->n + c] += v;
  return 0;
}

/* The full operator of term rt (one op) at the evaluator's current values, dense n x n into M. */
static int full_operator(Full *f, const RTerm *rt, double *M, long n, char *err, size_t errlen) {
  memset(M, 0, sizeof(double) * (size_t)(n * n));
  for (int g = 0; g < rt->ops[0].ntensors; g++) {
    const RTensor *t = &rt->ops[0].t[g];
    DenseSink s = {{0}, M, n, t->kind == RT_DIAG};
    for (int i = 0; i < t->group->ninputs && i < 64; i++) s.in[i] = full_get(f, t->group->inputs[i]->name, NULL);
    NpgSink sink = {&s, dense_entry, 0, 1, 0, 0};
    if (full_build(f, t->builder, &sink) != 0) return error_set(err, errlen, "estimate tables: %s", full_error(f));
  }
  return 0;
}

/* Smallest singular value of the n x n row-major A (destroyed); NaN if LAPACK fails. A symmetric
 * positive definite A (the usual inverse: Cholesky's) by its smallest eigenvalue alone (dsyevr,
 * about a quarter of the SVD's time), anything else by dgesvd. `sv` holds 2n doubles. */
static double smallest_sv(double *A, long n, double *sv) {
  double big = 0, asym = 0;
  for (long i = 0; i < n; i++)
    for (long j = 0; j < n; j++) big = fmax(big, fabs(A[i * n + j])), asym = fmax(asym, fabs(A[i * n + j] - A[j * n + i]));
  if (asym <= 1e-14 * big) {
    lapack_int found = 0, isuppz[2];
    double *copy = malloc(sizeof(double) * (size_t)(n * n) + 1);
    if (copy) {
      memcpy(copy, A, sizeof(double) * (size_t)(n * n));
      lapack_int info = LAPACKE_dsyevr(LAPACK_ROW_MAJOR, 'N', 'I', 'U', (int)n, copy, (int)n, 0, 0, 1, 1, 0, &found, sv,
                                       NULL, 1, isuppz);
      free(copy);
      if (info == 0 && found == 1 && sv[0] > 0) return sv[0];
    }
  }
  lapack_int info = LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'N', 'N', (int)n, (int)n, A, (int)n, sv, NULL, 1, NULL, 1,
                                   sv + n);
  return info == 0 ? sv[n - 1] : NAN;
}

/* c = min over spread training samples of σ_min(M)/σ_min(BᵀMB) for every inverse term with a table. */
static int sigma_ratios(Model *m, Full *f, const SampleSource *src, char *err, size_t errlen) {
  long S = src->count, nk = S < ESTIMATE_SIGMA_SAMPLES ? S : ESTIMATE_SIGMA_SAMPLES;
  for (long j = 0; j < nk; j++) {
    long k = nk > 1 ? j * (S - 1) / (nk - 1) : 0;
    if (train_eval_sample(src, f, k, err, errlen)) return -1;
    for (int i = 0; i < m->nstages; i++)
      for (int t = 0; t < m->stages[i].nterms; t++) {
        RTerm *rt = &m->stages[i].terms[t];
        const RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
        long n = rc->n, my = rc->m;
        if (!rt->est_G || rt->nops != 1 || n > ESTIMATE_DENSE_MAX) continue;
        double *M = malloc(sizeof(double) * (size_t)(n * n) + 1), *T = malloc(sizeof(double) * (size_t)(n * my) + 1),
               *R = malloc(sizeof(double) * (size_t)(my * my) + 1), *sv = malloc(sizeof(double) * (size_t)(2 * n + 1));
        int rc_ = M && T && R && sv ? full_operator(f, rt, M, n, err, errlen) : error_set(err, errlen, "estimate "
                  "tables: out of memory for the %ld x %ld operator of stage %s", n, n, m->stages[i].st->sym->name);
        if (rc_ == 0) {
          cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)my, (int)n, 1.0, M, (int)n, rc->B,
                      (int)my, 0.0, T, (int)my);
          cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)my, (int)my, (int)n, 1.0, rc->B, (int)my, T,
                      (int)my, 0.0, R, (int)my);
          double full = smallest_sv(M, n, sv), red = my > 0 ? smallest_sv(R, my, sv) : INFINITY;
          double ratio = full / red;
          if (!(ratio > 0)) ratio = 0; /* a singular operator or an SVD that failed: no bound */
          if (j == 0 || isnan(rt->est_sigma) || ratio < rt->est_sigma) rt->est_sigma = ratio;
        }
        free(M), free(T), free(R), free(sv);
        if (rc_) return -1;
      }
  }
  for (int i = 0; i < m->nstages; i++) /* a ratio of 0 is no lower bound: the term has no estimate */
    for (int t = 0; t < m->stages[i].nterms; t++)
      if (m->stages[i].terms[t].est_sigma == 0) m->stages[i].terms[t].est_sigma = NAN;
  return 0;
}

/* Each input's reduced coordinates' min and max over the training samples. */
static int input_ranges(Model *m, Full *f, const SampleSource *src, char *err, size_t errlen) {
  if (!(m->in_range = calloc((size_t)m->nq + 1, sizeof(double *))))
    return error_set(err, errlen, "estimate tables: out of memory");
  for (long k = 0; k < src->count; k++) {
    if (src->set(src->user, f, k) != 0) return error_set(err, errlen, "%s", full_error(f));
    for (int q = 0; q < m->nq; q++) {
      const Sym *sy = m->prog->quantities.v[q];
      const RClass *rc = &m->classes[m->qclass[q]];
      size_t cnt = 0;
      const double *x = sy->kind == SYM_INPUT && rc->B ? full_get(f, sy->name, &cnt) : NULL;
      if (!x || (long)cnt != rc->n) continue;
      long mq = rc->m;
      if (!m->in_range[q] && !(m->in_range[q] = malloc(sizeof(double) * (size_t)(2 * mq) + 1)))
        return error_set(err, errlen, "estimate tables: out of memory");
      double *rg = m->in_range[q], xh[mq + 1];
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)mq, 1.0, rc->B, (int)mq, x, 1, 0.0, xh, 1);
      for (long a = 0; a < mq; a++) {
        if (k == 0 || xh[a] < rg[a]) rg[a] = xh[a];
        if (k == 0 || xh[a] > rg[mq + a]) rg[mq + a] = xh[a];
      }
    }
  }
  return 0;
}

int train_estimates(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, char *err, size_t errlen) {
  if (opt->dist || m->nexterns > 0 || src->count < 1) return 0;
  char why[256];
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++)
      if (estimate_term_eligible(m, i, t, why, sizeof why) && m->classes[m->qclass[m->stages[i].q]].B &&
          term_table(m, f, i, t, err, errlen))
        return -1;
  return sigma_ratios(m, f, src, err, errlen) || input_ranges(m, f, src, err, errlen) ? -1 : 0;
}
