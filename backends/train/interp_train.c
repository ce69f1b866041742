/* interp_train.c — making a stage interpolated (interp.h, DESIGN §12):
 * select k entries from its class basis, factor the selected rows once, and
 * record the formula at those entries as a table of monomials read from the
 * tensor builders (the streams pre-multiplication reads). */
#include <lapacke.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"
#include "interp.h"
#include "scratch.h"
#include "train.h"

/* A fixed-seed generator (splitmix64): the same training gives the same
 * entries. */
static double next_unit(uint64_t *s) {
  uint64_t z = (*s += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return (double)((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
}

/* select_rows' counts when k < n: count[e] the times entry e is pivoted
 * or drawn, cum[e] the leverages' running sum. 0, or -1 with `err`. */
static int count_rows(const RClass *c, long k, long *count, double *cum, Scratch *sc) {
  long n = c->n, m = c->m;
  double *A = scratch_array(sc, (size_t)(n * m + 1), sizeof(double)), *tau = scratch_array(sc, (size_t)(m + 1), sizeof(double));
  lapack_int *jpvt = scratch_array(sc, (size_t)n + 1, sizeof(lapack_int));
  if (!A || !tau || !jpvt)
    return err_set(sc->err, "out of memory selecting the interpolation entries of class %s", c->label);
  /* B row-major n x m is Bᵀ column-major m x n */
  memcpy(A, c->B, sizeof(double) * (size_t)(n * m));
  lapack_int info = LAPACKE_dgeqp3(LAPACK_COL_MAJOR, (lapack_int)m, (lapack_int)n, A, (lapack_int)m, jpvt, tau);
  if (info != 0)
    return err_set(sc->err, "class %s: pivoted QR of the basis failed (LAPACK dgeqp3 info %d)", c->label, (int)info);
  for (long j = 0; j < m; j++) count[jpvt[j] - 1]++;
  double total = 0;
  for (long e = 0; e < n; e++) {
    double v = 0;
    for (long j = 0; j < m; j++) v += c->B[e * m + j] * c->B[e * m + j];
    cum[e] = total += v;
  }
  uint64_t seed = 0x6e70672d6465696dULL; /* fixed: training is reproducible */
  for (long d = m; d < k && total > 0; d++) {
    double u = next_unit(&seed) * total;
    long lo = 0, hi = n - 1; /* the first e with cum[e] > u */
    while (lo < hi) {
      long mid = lo + (hi - lo) / 2;
      if (cum[mid] > u) hi = mid;
      else lo = mid + 1;
    }
    count[lo]++;
  }
  return 0;
}

/* The entries of B (n x m, row-major, orthonormal columns) to interpolate at
 * and their least-squares weights, into ip->rows / ip->weight (ip->k set to
 * the number of distinct entries, ascending).
 *
 * k >= n: every entry, weight 1 (the fit is then the projection Bᵀy).
 * Otherwise m entries by QR with column pivoting of Bᵀ (Q-DEIM, Drmač &
 * Gugercin 2016), which make P B invertible, and k − m draws, with
 * replacement, from the leverage distribution p_e = ‖B[e,:]‖² / m; entry e
 * drawn (or pivoted) c_e times is weighted √(c_e / (k p_e)). Weighted so,
 * (W P B)ᵀ(W P B) and (W P B)ᵀ W P r are sums whose expectations are BᵀB = I
 * and Bᵀr = 0 for the residual r = y − BBᵀy: the fit estimates the
 * projection without bias, and k of order m log m draws keep W P B well
 * conditioned (Cohen & Migliorati 2017, "Optimal weighted least-squares
 * methods"). Unweighted entries of largest leverage, the earlier rule, or
 * the greedy choice that maximizes σ_min(P B) (Peherstorfer, Drmač &
 * Gugercin 2020, GappyPOD+E) both concentrate on the entries where the
 * residual is largest — the near pairs of n-body gravity — and left the
 * stage 2.8–5× above its floor at N = 1,000 with 1,056 entries, the output
 * 3–219× (bench/interp.md); the weighted draws bring both within 1.1×. */
static int select_rows(const RClass *c, RInterp *ip, long k, Err *err) {
  long n = c->n;
  Scratch sc = SCRATCH_OF(err);
  long *count = scratch_array(&sc, (size_t)n + 1, sizeof(long));
  double *cum = k < n ? scratch_array(&sc, (size_t)n + 1, sizeof(double)) : NULL;
  int rc = count && (k >= n || cum) ? 0
                                    : err_set(err, "out of memory selecting the interpolation entries of class %s", c->label);
  for (long e = 0; rc == 0 && k >= n && e < n; e++) count[e] = 1;
  if (rc == 0 && k < n) rc = count_rows(c, k, count, cum, &sc);
  ip->k = 0;
  for (long e = 0; rc == 0 && e < n; e++) ip->k += count[e] > 0;
  if (rc == 0 && (!(ip->rows = mem_malloc(sizeof(long) * (size_t)(ip->k + 1))) ||
                  !(ip->weight = mem_malloc(sizeof(double) * (size_t)(ip->k + 1)))))
    rc = err_set(err, "out of memory selecting the interpolation entries of class %s", c->label);
  double total = rc == 0 && k < n && n > 0 ? cum[n - 1] : 0;
  for (long e = 0, s = 0; rc == 0 && e < n; e++) {
    if (!count[e]) continue;
    ip->rows[s] = e;
    if (k >= n) { /* every entry: the fit is the projection */
      ip->weight[s++] = 1;
      continue;
    }
    double p = (cum[e] - (e ? cum[e - 1] : 0)) / total;
    /* a pivot of zero leverage cannot occur with B of rank m; guarded */
    ip->weight[s++] = p > 0 ? sqrt((double)count[e] / ((double)k * p)) : 1;
  }
  scratch_release(&sc);
  return rc;
}

/* The fit (W P B)⁺ W = R⁻¹ Qᵀ W (m x k, row-major) from W P B = QR, and
 * ‖(W P B)⁺‖₂ = 1/σ_min(W P B). */
static int pseudo_inverse(const RClass *c, RInterp *ip, const char *stage, Err *err) {
  long k = ip->k, m = ip->m;
  Scratch sc = SCRATCH_OF(err);
  double *PB = scratch_array(&sc, (size_t)(k * m + 1), sizeof(double)), *S = scratch_array(&sc, (size_t)(k * m + 1), sizeof(double));
  double *tau = scratch_array(&sc, (size_t)(m + 1), sizeof(double)), *sv = scratch_array(&sc, (size_t)(m + 1), sizeof(double));
  int rc = 0;
  lapack_int info = 0;
  if (!PB || !S || !tau || !sv || !(ip->pinv = mem_malloc(sizeof(double) * (size_t)(m * k + 1))))
    rc = err_set(err, "out of memory factoring the interpolation of stage %s", stage);
  if (rc == 0) {
    for (long s = 0; s < k; s++) /* column-major k x m */
      for (long j = 0; j < m; j++) PB[j * k + s] = ip->weight[s] * c->B[ip->rows[s] * m + j];
    memcpy(S, PB, sizeof(double) * (size_t)(k * m));
    info = LAPACKE_dgesvd(LAPACK_COL_MAJOR, 'N', 'N', (lapack_int)k, (lapack_int)m, S, (lapack_int)k, sv, NULL, 1, NULL,
                          1, tau);
    if (info != 0)
      rc = err_set(err, "stage %s: singular values of the selected basis rows failed (LAPACK dgesvd info %d)", stage,
                   (int)info);
  }
  if (rc == 0 && m > 0 && !(sv[m - 1] > 1e-12 * sv[0]))
    rc = err_set(err,
                 "stage %s: the %ld selected entries do not determine its %ld basis coordinates (smallest singular "
                 "value %.3g of %.3g): raise the oversampling",
                 stage, k, m, sv[m - 1], sv[0]);
  if (rc == 0) {
    ip->pinv_norm = m > 0 ? 1 / sv[m - 1] : 0;
    info = LAPACKE_dgeqrf(LAPACK_COL_MAJOR, (lapack_int)k, (lapack_int)m, PB, (lapack_int)k, tau);
    /* X = R⁻¹ Qᵀ: Qᵀ (m x k) from the reflectors, then one triangular solve */
    if (info == 0) {
      memcpy(S, PB, sizeof(double) * (size_t)(k * m));
      info = LAPACKE_dorgqr(LAPACK_COL_MAJOR, (lapack_int)k, (lapack_int)m, (lapack_int)m, S, (lapack_int)k, tau);
    }
    /* Qᵀ column-major m x k is Q column-major k x m transposed: row-major m x k of pinv */
    double *QT = ip->pinv, *tmp = info == 0 ? scratch_array(&sc, (size_t)(m * k + 1), sizeof(double)) : NULL;
    if (info == 0 && !tmp) rc = err_set(err, "out of memory factoring the interpolation of stage %s", stage);
    if (tmp) {
      for (long s = 0; s < k; s++)
        for (long j = 0; j < m; j++) tmp[s * m + j] = S[j * k + s]; /* Qᵀ column-major m x k */
      info = LAPACKE_dtrtrs(LAPACK_COL_MAJOR, 'U', 'N', 'N', (lapack_int)m, (lapack_int)k, PB, (lapack_int)k, tmp,
                            (lapack_int)m);
      for (long j = 0; info == 0 && j < m; j++)
        for (long s = 0; s < k; s++) QT[j * k + s] = tmp[s * m + j] * ip->weight[s];
    }
    if (info != 0)
      rc = err_set(err, "stage %s: factoring the selected basis rows failed (LAPACK dgeqrf/dorgqr/dtrtrs info %d)",
                   stage, (int)info);
  }
  scratch_release(&sc);
  return rc;
}

/* The estimate's check entries of fit ip (docs/estimates.md, interp_check): every entry the fit
 * does not select up to max(INTERP_CHECK_MIN, k, 2m) of them, else that many drawn uniformly without
 * replacement (a fixed seed: training is reproducible), in ip->check->rows and slot[] (from ip->k
 * on); their basis rows, after the fit's, in ip->check->brows (zero when c has no basis in memory:
 * out of core the sweep fills them, estimate_stream.c). 0, or -1 out of memory. */
static int check_rows(const RClass *c, RInterp *ip, long *slot) {
  RInterp *ck = ip->check;
  long n = c->n, m = c->m, rest = n - ip->k, want = ip->k > 2 * m ? ip->k : 2 * m, j = 0;
  if (want < INTERP_CHECK_MIN) want = INTERP_CHECK_MIN;
  Scratch sc = SCRATCH_OF(NULL);
  long *pool = scratch_array(&sc, (size_t)(rest + 1), sizeof(long));
  if (!pool) return -1;
  for (long e = 0; e < n; e++)
    if (slot[e] < 0) pool[j++] = e;
  ck->k = rest < want ? rest : want;
  uint64_t seed = 0x6e70672d63686b31ULL;
  for (long d = 0; d < ck->k; d++) { /* a partial Fisher–Yates shuffle */
    long pick = d + (long)(next_unit(&seed) * (double)(rest - d));
    if (pick >= rest) pick = rest - 1;
    long t = pool[d];
    pool[d] = pool[pick], pool[pick] = t;
  }
  ck->rows = mem_malloc(sizeof(long) * (size_t)(ck->k + 1));
  ck->brows = mem_calloc((size_t)((ip->k + ck->k) * m + 1), sizeof(double));
  for (long d = 0; ck->rows && ck->brows && d < ck->k; d++) ck->rows[d] = pool[d], slot[pool[d]] = ip->k + d;
  for (long s = 0; c->B && ck->rows && ck->brows && s < ip->k + ck->k; s++) /* no basis (out of core): the sweep's */
    memcpy(ck->brows + s * m, c->B + (s < ip->k ? ip->rows[s] : ck->rows[s - ip->k]) * m, sizeof(double) * (size_t)m);
  scratch_release(&sc);
  return ck->rows && ck->brows ? 0 : -1;
}

/* A check table's read_rows from the bases of the quantities it reads: 0, 1 when one has no basis
 * in memory (the check is then left out), -1 out of memory. */
static int check_read_rows(const Model *m, RInterp *ck) {
  long len = 0;
  for (long r = 0; r < ck->nreads; r++) {
    const RClass *c = &m->classes[m->qclass[ck->read_q[r]]];
    if (!c->B && c->m > 0) return 1;
    len += c->m;
  }
  if (!(ck->read_rows = mem_malloc(sizeof(double) * (size_t)(len + 1)))) return -1;
  for (long r = 0, at = 0; r < ck->nreads; r++) {
    const RClass *c = &m->classes[m->qclass[ck->read_q[r]]];
    if (c->m > 0) memcpy(ck->read_rows + at, c->B + ck->read_e[r] * c->m, sizeof(double) * (size_t)c->m);
    at += c->m;
  }
  return 0;
}

/* The monomial table under construction. */
typedef struct Table {
  Model *m;
  RInterp *ip;
  const long *slot;         /* per entry of the stage: its selected index, or -1 */
  long **read_of;           /* per quantity: per entry its read index + 1 (0: not read yet), made on first use */
  Scratch *sc;              /* where read_of's arrays come from (train_tables') */
  long mono_cap, read_cap;
  int term, factor;
  struct Table *check;      /* the estimate's check table: slots from ip->k on are its entries */
  int nin;
  int in_q[RT_MAX_IN];      /* the quantity of each builder input */
  bool oom;                 /* an entry refused because an allocation failed (not a malformed entry) */
  Err *err;
} Table;

static long read_index(Table *tb, int q, long e) {
  RInterp *ip = tb->ip;
  if (!tb->read_of[q] &&
      !(tb->read_of[q] = scratch_array(tb->sc, (size_t)tb->m->classes[tb->m->qclass[q]].n + 1, sizeof(long))))
    return -1;
  if (tb->read_of[q][e]) return tb->read_of[q][e] - 1;
  if (ip->nreads == tb->read_cap) {
    long cap = tb->read_cap ? 2 * tb->read_cap : 64;
    int *rq = mem_realloc(ip->read_q, sizeof(int) * (size_t)cap);
    if (rq) ip->read_q = rq;
    long *re = rq ? mem_realloc(ip->read_e, sizeof(long) * (size_t)cap) : NULL;
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
    RInterpMono *mo = mem_realloc(ip->mono, sizeof(RInterpMono) * (size_t)cap);
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
  if (add_mono(s >= tb->ip->k ? tb->check : tb, s >= tb->ip->k ? s - tb->ip->k : s, coef, nin, tb->in_q, in) == 0)
    return 0;
  tb->oom = true;
  return -1;
}

static int stream_tensor(Table *tb, Full *f, const RTensor *x, const char *stage) {
  const TensorGroup *g = x->group;
  tb->nin = g->ninputs;
  for (int i = 0; i < g->ninputs && i < RT_MAX_IN; i++) tb->in_q[i] = vec_position(&tb->m->prog->quantities, g->inputs[i]);
  NpgSink sink = {tb, on_entry, 0, 1, 0, 0};
  tb->oom = false;
  if (full_build(f, x->builder, &sink) != 0)
    return err_set(tb->err, "stage %s: reading tensor %s for interpolation: %s", stage, x->name,
                     tb->oom || !full_error(f)[0] ? "out of memory" : full_error(f));
  return 0;
}

/* Every term's tensors of stage rs read into tb's table (entries at the fit's rows) and its check
 * table's. 0, or -1 with the error record. */
static int read_terms(Table *tb, Full *f, const RStage *rs, const char *sn) {
  RInterp *ip = tb->ip;
  Table *tbx = tb->check;
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    tb->term = tbx->term = t, tb->factor = tbx->factor = 0;
    if (rt->named_q >= 0) { /* the numerator is the named quantity itself, entry for entry */
      int q = rt->named_q;
      for (long s = 0; s < ip->k + ip->check->k; s++) {
        npg_idx e = (npg_idx)(s < ip->k ? ip->rows[s] : ip->check->rows[s - ip->k]);
        if (add_mono(s < ip->k ? tb : tbx, s < ip->k ? s : s - ip->k, 1.0, 1, &q, &e))
          return err_set(tb->err, "out of memory making stage %s interpolated", sn);
      }
    }
    for (int g = 0; g < rt->nnum; g++)
      if (stream_tensor(tb, f, &rt->num[g], sn)) return -1;
    for (int o = 0; o < rt->nops; o++) {
      tb->factor = tbx->factor = o + 1;
      for (int g = 0; g < rt->ops[o].ntensors; g++)
        if (stream_tensor(tb, f, &rt->ops[o].t[g], sn)) return -1;
    }
  }
  return 0;
}

/* interp_train_stage, or with oversample 0 interp_train_check: no fit (k = 0), the check table
 * drawn from all n entries into rs->check; with `defer` too (interp_train_check_rows) the check
 * table handed out in *defer before its basis rows are read and it is packed. */
static int train_tables(Model *m, Full *f, int stage, double oversample, RInterp **defer, Err *err) {
  RStage *rs = &m->stages[stage];
  const char *sn = rs->st->sym->name;
  const RClass *c = &m->classes[m->qclass[rs->q]];
  if (!lower_interp_eligible(rs->st))
    return err_set(err, "stage %s cannot be interpolated: %s", sn,
                     rs->st->kind == ST_INVERSE || rs->st->kind == ST_ROOT
                        ? "one of its operators is a declared op, not diagonal (npgc check says which stages can)"
                        : "it applies no diagonal operator (npgc check says which stages can)");
  if (!(oversample >= 1) && oversample != 0)
    return err_set(err, "interpolation oversampling %g: must be at least 1", oversample);
  Scratch sc = SCRATCH_OF(err);
  RInterp *ip = mem_calloc(1, sizeof *ip); /* the stage's, once made; freed here until then */
  Table tb = {.m = m, .ip = ip, .sc = &sc, .err = err}, tbx = {.m = m, .sc = &sc, .err = err};
  long *slot = scratch_array(&sc, (size_t)c->n + 1, sizeof(long));
  tb.read_of = scratch_array(&sc, (size_t)m->nq + 1, sizeof(long *));
  tbx.read_of = scratch_array(&sc, (size_t)m->nq + 1, sizeof(long *));
  int rc = ip && slot && tb.read_of && tbx.read_of ? 0 : err_set(err, "out of memory making stage %s interpolated", sn);
  if (rc == 0) {
    ip->m = c->m;
    long draws = (long)ceil(oversample * (double)c->m);
    if (draws < c->m) draws = c->m;
    if (oversample > 0 && (select_rows(c, ip, draws, err) || pseudo_inverse(c, ip, sn, err))) rc = -1;
  }
  for (long e = 0; rc == 0 && e < c->n; e++) slot[e] = -1;
  for (long s = 0; rc == 0 && s < ip->k; s++) slot[ip->rows[s]] = s;
  if (rc == 0 && (!(ip->check = mem_calloc(1, sizeof *ip->check)) || check_rows(c, ip, slot)))
    rc = err_set(err, "out of memory making stage %s interpolated", sn);
  if (rc == 0) {
    tb.slot = slot, tb.check = &tbx, tbx.ip = ip->check;
    rc = read_terms(&tb, f, rs, sn);
  }
  if (rc == 0 && defer) { /* out of core: the basis rows come from the sweep */
    *defer = ip->check, ip->check = NULL;
    interp_free(ip);
    scratch_release(&sc);
    return 0;
  }
  int rows = rc == 0 ? check_read_rows(m, ip->check) : 0;
  if (rc == 0 && (rows < 0 || interp_pack(m, rs, ip) || (rows == 0 && interp_pack(m, rs, ip->check))))
    rc = err_set(err, "out of memory making stage %s interpolated", sn);
  if (rc == 0 && rows > 0) interp_free(ip->check), ip->check = NULL; /* a read class without its basis: no check */
  if (rc == 0 && oversample == 0) { /* the check table replaces the stage's */
    interp_free(rs->check);
    rs->check = ip->check, ip->check = NULL;
  } else if (rc == 0) { /* the fit replaces the stage's */
    interp_free(rs->interp);
    rs->interp = ip;
    ip = NULL;
  }
  interp_free(ip); /* a half-made fit, or the check table's shell */
  scratch_release(&sc);
  return rc;
}

static bool named(const char *const *list, int n, const char *name) {
  for (int i = 0; i < n; i++)
    if (strcmp(list[i], name) == 0) return true;
  return false;
}

int interp_open_choices(const Program *prog, int ninterp, const char *const *interp, int ngalerkin,
                        const char *const *galerkin) {
  int open = 0;
  /* an extern's learned model is fitted after the choice is made: the
   * reduced model cannot be evaluated on held-out samples then (both
   * reductions fail, Galerkin is kept), so holding samples out would only
   * take them from training */
  if (prog->externs.n > 0) return 0;
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    open += lower_interp_eligible(st) && st->sym->reduce == STAGE_REDUCE_DEFAULT &&
            !named(interp, ninterp, st->sym->name) && !named(galerkin, ngalerkin, st->sym->name);
  }
  return open;
}

Model *interp_train_with_choice(Program *prog, Full *f, const SampleSource *all, const TrainOptions *opt,
                                Model *chosen, Err *err) {
  int n = chosen->nstages, ni = 0, ng = 0;
  Scratch sc = SCRATCH_OF(err);
  const char **ilist = scratch_array(&sc, (size_t)(n + opt->user->ninterp + 1), sizeof(char *));
  const char **glist = scratch_array(&sc, (size_t)(n + opt->user->ngalerkin + 1), sizeof(char *));
  double *errs = scratch_array(&sc, (size_t)(2 * n + 1), sizeof(double));
  const char **reason = scratch_array(&sc, (size_t)n + 1, sizeof(char *));
  bool room = ilist && glist && errs && reason;
  if (!room) err_set(err, "out of memory");
  for (int j = 0; room && j < opt->user->ninterp; j++) ilist[ni++] = opt->user->interp_stage[j];
  for (int j = 0; room && j < opt->user->ngalerkin; j++) glist[ng++] = opt->user->galerkin_stage[j];
  for (int i = 0; room && i < n; i++) { /* stage names belong to the program, which outlives both models */
    const RStage *rs = &chosen->stages[i];
    if (!rs->choice_reason || rs->choice_reason == interp_reasons[INTERP_FORCED]) continue;
    if (rs->interp) ilist[ni++] = rs->st->sym->name;
    else glist[ng++] = rs->st->sym->name;
    reason[i] = rs->choice_reason, errs[2 * i] = rs->choice_err[0], errs[2 * i + 1] = rs->choice_err[1];
  }
  char failure[sizeof chosen->choice_failure];
  snprintf(failure, sizeof failure, "%s", chosen->choice_failure);
  model_free(chosen); /* before the second training: never both in memory */
  NpgTrainOptions user = *opt->user; /* the choice fixed: every stage it made forced its way */
  user.ninterp = ni, user.interp_stage = ilist;
  user.ngalerkin = ng, user.galerkin_stage = glist;
  TrainOptions o = *opt;
  o.user = &user;
  o.valid = NULL;
  Model *m = room ? train_model(prog, f, all, &o, err) : NULL;
  if (m) snprintf(m->choice_failure, sizeof m->choice_failure, "%s", failure);
  for (int i = 0; m && i < n && i < m->nstages; i++) /* the measured errors and reason, not "forced" */
    if (reason[i]) {
      m->stages[i].choice_err[0] = errs[2 * i], m->stages[i].choice_err[1] = errs[2 * i + 1];
      m->stages[i].choice_reason = reason[i];
    }
  scratch_release(&sc);
  return m;
}

int interp_train_stage(Model *m, Full *f, int stage, double oversample, Err *err) {
  if (!(oversample >= 1)) return err_set(err, "interpolation oversampling %g: must be at least 1", oversample);
  return train_tables(m, f, stage, oversample, NULL, err);
}

int interp_train_check(Model *m, Full *f, int stage, Err *err) {
  return train_tables(m, f, stage, 0, NULL, err);
}

int interp_train_check_rows(Model *m, Full *f, int stage, RInterp **check, Err *err) {
  *check = NULL;
  return train_tables(m, f, stage, 0, check, err);
}
