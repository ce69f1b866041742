/* interp_train.c — making a stage interpolated (interp.h, DESIGN §12):
 * select k entries from its class basis, factor the selected rows once, and
 * record the formula at those entries as a table of monomials read from the
 * tensor builders (the streams pre-multiplication reads). */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"
#include "interp.h"
#include "train.h"

/* The k rows of B (n x m, row-major, orthonormal columns) to interpolate at:
 * the first min(m, k) by QR with column pivoting of Bᵀ (Q-DEIM, Drmač &
 * Gugercin 2016: ‖(PB)⁻¹‖ ≤ √(n − m + 1) O(2^m), in practice far less),
 * then, oversampling, the rows of largest leverage ‖B[e,:]‖ not chosen yet
 * (the directions least determined by the rows so far carry the most
 * weight there). */
static int select_rows(const RClass *c, long k, long *rows, char *err, size_t errlen) {
  long n = c->n, m = c->m;
  double *A = malloc(sizeof(double) * (size_t)(n * m + 1)), *tau = malloc(sizeof(double) * (size_t)(m + 1));
  lapack_int *jpvt = calloc((size_t)n + 1, sizeof(lapack_int));
  char *taken = calloc((size_t)n + 1, 1);
  int rc = 0;
  if (!A || !tau || !jpvt || !taken) {
    rc = npg_fail(err, errlen, "out of memory selecting the interpolation entries of class %s", c->label);
    goto done;
  }
  /* B row-major n x m is Bᵀ column-major m x n */
  memcpy(A, c->B, sizeof(double) * (size_t)(n * m));
  lapack_int info = LAPACKE_dgeqp3(LAPACK_COL_MAJOR, (lapack_int)m, (lapack_int)n, A, (lapack_int)m, jpvt, tau);
  if (info != 0) {
    rc = npg_fail(err, errlen, "class %s: pivoted QR of the basis failed (LAPACK dgeqp3 info %d)", c->label, (int)info);
    goto done;
  }
  long got = 0;
  for (; got < m && got < k; got++) rows[got] = jpvt[got] - 1, taken[rows[got]] = 1;
  while (got < k) {
    long best = -1;
    double bestv = -1;
    for (long e = 0; e < n; e++) {
      if (taken[e]) continue;
      double v = 0;
      for (long j = 0; j < m; j++) v += c->B[e * m + j] * c->B[e * m + j];
      if (v > bestv) bestv = v, best = e;
    }
    rows[got++] = best, taken[best] = 1;
  }
done:
  free(A);
  free(tau);
  free(jpvt);
  free(taken);
  return rc;
}

/* (P B)⁺ = R⁻¹ Qᵀ (m x k, row-major) from P B = QR, and ‖(P B)⁺‖₂ = 1/σ_min. */
static int pseudo_inverse(const RClass *c, RInterp *ip, const char *stage, char *err, size_t errlen) {
  long k = ip->k, m = ip->m;
  double *PB = malloc(sizeof(double) * (size_t)(k * m + 1)), *S = malloc(sizeof(double) * (size_t)(k * m + 1));
  double *tau = malloc(sizeof(double) * (size_t)(m + 1)), *sv = malloc(sizeof(double) * (size_t)(m + 1));
  int rc = 0;
  if (!PB || !S || !tau || !sv || !(ip->pinv = malloc(sizeof(double) * (size_t)(m * k + 1)))) {
    rc = npg_fail(err, errlen, "out of memory factoring the interpolation of stage %s", stage);
    goto done;
  }
  for (long s = 0; s < k; s++) /* column-major k x m */
    for (long j = 0; j < m; j++) PB[j * k + s] = c->B[ip->rows[s] * m + j];
  memcpy(S, PB, sizeof(double) * (size_t)(k * m));
  lapack_int info = LAPACKE_dgesvd(LAPACK_COL_MAJOR, 'N', 'N', (lapack_int)k, (lapack_int)m, S, (lapack_int)k, sv, NULL,
                                   1, NULL, 1, tau);
  if (info != 0) {
    rc = npg_fail(err, errlen, "stage %s: singular values of the selected basis rows failed (LAPACK dgesvd info %d)",
                  stage, (int)info);
    goto done;
  }
  if (m > 0 && !(sv[m - 1] > 1e-12 * sv[0])) {
    rc = npg_fail(err, errlen,
                  "stage %s: the %ld selected entries do not determine its %ld basis coordinates (smallest singular "
                  "value %.3g of %.3g): raise the oversampling",
                  stage, k, m, sv[m - 1], sv[0]);
    goto done;
  }
  ip->pinv_norm = m > 0 ? 1 / sv[m - 1] : 0;
  info = LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (lapack_int)k, (lapack_int)m, PB, (lapack_int)k, tau);
  /* X = R⁻¹ Qᵀ: Qᵀ (m x k) from the reflectors, then one triangular solve */
  if (info == 0) {
    memcpy(S, PB, sizeof(double) * (size_t)(k * m));
    info = LAPACKE_dorgqr(LAPACK_COL_MAJOR, (lapack_int)k, (lapack_int)m, (lapack_int)m, S, (lapack_int)k, tau);
  }
  if (info == 0) {
    /* Qᵀ column-major m x k is Q column-major k x m transposed: row-major m x k of pinv */
    double *QT = ip->pinv; /* column-major m x k, transposed to row-major below */
    double *tmp = malloc(sizeof(double) * (size_t)(m * k + 1));
    if (!tmp) {
      rc = npg_fail(err, errlen, "out of memory factoring the interpolation of stage %s", stage);
      goto done;
    }
    for (long s = 0; s < k; s++)
      for (long j = 0; j < m; j++) tmp[s * m + j] = S[j * k + s]; /* Qᵀ column-major m x k */
    info = LAPACKE_dtrtrs(LAPACK_COL_MAJOR, 'U', 'N', 'N', (lapack_int)m, (lapack_int)k, PB, (lapack_int)k, tmp,
                          (lapack_int)m);
    for (long j = 0; info == 0 && j < m; j++)
      for (long s = 0; s < k; s++) QT[j * k + s] = tmp[s * m + j];
    free(tmp);
  }
  if (info != 0)
    rc = npg_fail(err, errlen, "stage %s: factoring the selected basis rows failed (LAPACK dgeqrf/dorgqr/dtrtrs info %d)",
                  stage, (int)info);
done:
  free(PB);
  free(S);
  free(tau);
  free(sv);
  return rc;
}

/* The monomial table under construction. */
typedef struct Table {
  Model *m;
  RInterp *ip;
  const long *slot;         /* per entry of the stage: its selected index, or -1 */
  long **read_of;           /* per quantity: per entry its read index + 1 (0: not read yet), made on first use */
  long mono_cap, read_cap;
  int term, factor;
  int nin;
  int in_q[RT_MAX_IN];      /* the quantity of each builder input */
  char *err;
  size_t errlen;
} Table;

static long read_index(Table *tb, int q, long e) {
  RInterp *ip = tb->ip;
  if (!tb->read_of[q] && !(tb->read_of[q] = calloc((size_t)tb->m->classes[tb->m->qclass[q]].n + 1, sizeof(long))))
    return -1;
  if (tb->read_of[q][e]) return tb->read_of[q][e] - 1;
  if (ip->nreads == tb->read_cap) {
    long cap = tb->read_cap ? 2 * tb->read_cap : 64;
    int *rq = realloc(ip->read_q, sizeof(int) * (size_t)cap);
    if (rq) ip->read_q = rq;
    long *re = rq ? realloc(ip->read_e, sizeof(long) * (size_t)cap) : NULL;
    if (!re) return -1;
    ip->read_e = re, tb->read_cap = cap;
  }
  ip->read_q[ip->nreads] = q, ip->read_e[ip->nreads] = e;
  tb->read_of[q][e] = ++ip->nreads;
  return ip->nreads - 1;
}

static int add_mono(Table *tb, long slot, double coef, int nin, const int *q, const npg_idx *e) {
  RInterp *ip = tb->ip;
  if (ip->nmono == tb->mono_cap) {
    long cap = tb->mono_cap ? 2 * tb->mono_cap : 256;
    RInterpMono *mo = realloc(ip->mono, sizeof(RInterpMono) * (size_t)cap);
    if (!mo) return -1;
    ip->mono = mo, tb->mono_cap = cap;
  }
  RInterpMono *mo = &ip->mono[ip->nmono];
  mo->term = tb->term, mo->factor = tb->factor, mo->slot = slot, mo->coef = coef, mo->nin = nin;
  for (int i = 0; i < nin; i++)
    if ((mo->read[i] = read_index(tb, q[i], (long)e[i])) < 0) return -1;
  ip->nmono++;
  return 0;
}

static int on_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Table *tb = user;
  (void)col; /* a diagonal's column is its row */
  long s = tb->slot[row];
  if (s < 0 || coef == 0) return 0;
  if (nin != tb->nin) return -1;
  return add_mono(tb, s, coef, nin, tb->in_q, in);
}

static int stream_tensor(Table *tb, NpgFull *f, const RTensor *x, const char *stage) {
  const TensorGroup *g = x->group;
  tb->nin = g->ninputs;
  for (int i = 0; i < g->ninputs && i < RT_MAX_IN; i++) tb->in_q[i] = emit_index_of(&tb->m->prog->quantities, g->inputs[i]);
  NpgSink sink = {tb, on_entry, 0, 1, 0, 0};
  if (full_build(f, x->builder, &sink) != 0)
    return npg_fail(tb->err, tb->errlen, "stage %s: reading tensor %s for interpolation: %s", stage, x->name,
                    npg_full_error(f)[0] ? npg_full_error(f) : "out of memory");
  return 0;
}

int interp_train_stage(Model *m, NpgFull *f, int stage, double oversample, char *err, size_t errlen) {
  RStage *rs = &m->stages[stage];
  const char *sn = rs->st->sym->name;
  const RClass *c = &m->classes[m->qclass[rs->q]];
  if (!lower_interp_eligible(rs->st))
    return npg_fail(err, errlen, "stage %s cannot be interpolated: %s", sn,
                    rs->st->kind == ST_INVERSE || rs->st->kind == ST_ROOT
                        ? "one of its operators is a declared op, not diagonal (npgc check says which stages can)"
                        : "it applies no diagonal operator (npgc check says which stages can)");
  if (!(oversample >= 1)) return npg_fail(err, errlen, "interpolation oversampling %g: must be at least 1", oversample);
  RInterp *ip = calloc(1, sizeof *ip);
  Table tb = {.m = m, .ip = ip, .err = err, .errlen = errlen};
  long *slot = NULL;
  int rc = -1;
  if (!ip) goto oom;
  ip->m = c->m;
  ip->k = (long)ceil(oversample * (double)c->m);
  if (ip->k < c->m) ip->k = c->m;
  if (ip->k > c->n) ip->k = c->n;
  if (!(ip->rows = malloc(sizeof(long) * (size_t)(ip->k + 1))) || !(slot = malloc(sizeof(long) * (size_t)(c->n + 1))) ||
      !(tb.read_of = calloc((size_t)m->nq + 1, sizeof(long *))))
    goto oom;
  if (select_rows(c, ip->k, ip->rows, err, errlen) || pseudo_inverse(c, ip, sn, err, errlen)) goto done;
  for (long e = 0; e < c->n; e++) slot[e] = -1;
  for (long s = 0; s < ip->k; s++) slot[ip->rows[s]] = s;
  tb.slot = slot;
  for (int t = 0; t < rs->nterms; t++) {
    RTerm *rt = &rs->terms[t];
    tb.term = t, tb.factor = 0;
    if (rt->named_q >= 0) { /* the numerator is the named quantity itself, entry for entry */
      int q = rt->named_q;
      for (long s = 0; s < ip->k; s++) {
        npg_idx e = (npg_idx)ip->rows[s];
        if (add_mono(&tb, s, 1.0, 1, &q, &e)) goto oom;
      }
    }
    for (int g = 0; g < rt->nnum; g++)
      if (stream_tensor(&tb, f, &rt->num[g], sn)) goto done;
    for (int o = 0; o < rt->nops; o++) {
      tb.factor = o + 1;
      for (int g = 0; g < rt->ops[o].ntensors; g++)
        if (stream_tensor(&tb, f, &rt->ops[o].t[g], sn)) goto done;
    }
  }
  interp_free(rs->interp);
  rs->interp = ip;
  ip = NULL;
  rc = 0;
  goto done;
oom:
  npg_fail(err, errlen, "out of memory making stage %s interpolated", sn);
done:
  for (int q = 0; tb.read_of && q < m->nq; q++) free(tb.read_of[q]);
  free(tb.read_of);
  free(slot);
  interp_free(ip);
  return rc;
}
