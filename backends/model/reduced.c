/* reduced.c — the reduced evaluator (DESIGN §1, §6; paper §4).
 *
 * Every stage is evaluated on reduced coordinates in the order of the full
 * program:
 *
 *     ŷ = Σ_t  (M̂_{t,k})^{r_k} ⋯ (M̂_{t,1})^{r_1} ŵ_t,
 *
 * ŵ_t the term's reduced numerator (its pre-multiplied tensors contracted
 * with the reduced inputs, or a named numerator's coordinates), each M̂ =
 * BᵀMB contracted the same way. Contractions are dense matrix-vector
 * products over the last axis first (OpenBLAS dgemv), each reading its
 * tensor once; inverse powers factor M̂ once (Cholesky when training showed
 * the operator positive definite, LU otherwise, the condition estimated);
 * fractional powers tridiagonalize M̂ (dsytrd), diagonalize the tridiagonal
 * by divide and conquer (dstedc) and apply both to the one vector, never
 * forming M̂'s eigenvectors (apply_root). */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "emit.h"
#include "interp.h"
#include "krylov.h"
#include "nnls.h"
#include "reduced.h"
#include "scratch.h"

/* ---------------------------------------------------------------- reduced evaluation */

/* Below this many bytes of reduced tensors a whole evaluation runs its BLAS
 * on one OpenBLAS thread: at these sizes a second thread gains nothing
 * (bench_reduce, radiosity form factors, 2 cores: 0.08 MB 30 µs either
 * way, 0.63 MB 108–133 µs on 2 threads against 108–109 on 1) and its
 * pool thread, spinning after each threaded call, competes with the
 * evaluation (at F = 1000, m = 10, 41–58 µs against 40–41 µs per reduced
 * evaluation including the learned extern). From 4.95 MB on, two threads
 * are faster (4 %, and 20 % at 16.6 MB). */
#define REDUCED_ONE_THREAD_BYTES ((size_t)2 << 20)

/* The Lanczos roots' a-posteriori estimate is held below this (relative):
 * half the 1e-8 the reduced roots promise, itself five orders below the
 * reduction's own error of the programs measured (radiosity: 1e-3 to
 * 1e-2). The estimate compares approximations 4 steps apart, so it bounds
 * the earlier one's error; the accepted, later one is about 20 times closer
 * (radiosity's {d,p} operator). */
#define REDUCED_KRYLOV_TOL 5e-9

static long qm(const Model *m, int q) { return m->classes[m->qclass[q]].m; }

struct Reduced {
  Model *m;
  double **x;             /* reduced coordinates of every quantity */
  double *v, *acc;        /* a term's vector, a contraction's result (max m, max rows) */
  double *buf[2];         /* contraction intermediates */
  double *z;              /* packed powers of the inputs of one tensor */
  double *M, *M2, *w;     /* a reduced operator, its factor, a scratch vector */
  double *interp_work;    /* interp_eval's (interp.h), for the largest interpolated stage */
  lapack_int *piv;
  /* LAPACK workspace of apply_power, sized for maxm once */
  double *tau, *diag, *off; /* dsytrd: reflectors, T's diagonal and off-diagonal */
  double *work;
  lapack_int lwork, liwork, *iwork;
  long maxm;
  bool given_externs;     /* externs projected by the caller, not learned */
  bool krylov_roots;      /* roots by the Lanczos process where it converges (krylov.h), else exact */
  Krylov kr;
  long root_steps, roots, root_fallbacks; /* statistics of the Krylov roots */
  long *root_start;       /* per stage: Krylov.start after its last root */
  double *root_shrink;    /* per stage: Krylov.shrink after its last root */
  bool one_thread;        /* tensors small enough that reduced_eval runs BLAS on one thread */
  struct {                /* column-major copies of the tall, narrow tensors (contract) */
    const RTensor *t;
    double *data;
  } *colmajor;
  int ncolmajor;
  struct DerivCache *deriv_cache; /* reduced_deriv.c's, built on the first derivative (owned) */
  ReducedKept ***kept;    /* [stage][term][op]: what reduced_eval keeps for the derivatives */
  bool keeping;           /* inside reduced_eval: eval_term fills `kept` */
  bool kept_valid;        /* the last reduced_eval succeeded, and kept_x holds its coordinates */
  double *kept_x;         /* every quantity's coordinates after it, one after another */
  long kept_len;
  bool local_jac;         /* reduced_keep_local_jacobians */
  struct {                /* the local Jacobians of the tensors of one input taken twice */
    const RTensor *t;
    double *J;            /* rows x m */
    bool kept;            /* by the last reduced_eval */
  } *lj;
  int nlj;
  char error[1024];
};

const char *reduced_error(const Reduced *r) { return r->error; }

#define rfail(r, ...) error_set_first((r)->error, sizeof (r)->error, __VA_ARGS__)

_Static_assert(sizeof(lapack_int) == sizeof(int), "ReducedKept.piv is an int array");

static long kept_steps(const OpPow *op) { return op->q != 1 ? 1 : labs(op->p); }

static void kept_free(Reduced *r) {
  const Model *m = r->m;
  for (int i = 0; r->kept && i < m->nstages; i++) {
    for (int t = 0; r->kept[i] && t < m->stages[i].nterms; t++) {
      for (int k = 0; r->kept[i][t] && k < m->stages[i].terms[t].nops; k++) {
        ReducedKept *kp = &r->kept[i][t][k];
        free(kp->M), free(kp->factor), free(kp->chain), free(kp->piv);
      }
      free(r->kept[i][t]);
    }
    free(r->kept[i]);
  }
  free(r->kept);
  free(r->kept_x);
  for (int i = 0; i < r->nlj; i++) free(r->lj[i].J);
  free(r->lj);
}

/* The operators' kept state (ReducedKept), allocated once for every Galerkin term. */
static int kept_alloc(Reduced *r) {
  const Model *m = r->m;
  if (!(r->kept = mem_calloc((size_t)m->nstages + 1, sizeof *r->kept))) return -1;
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (rs->interp || rs->st->kind == ST_EXTERN) continue;
    long n = qm(m, rs->q);
    if (!(r->kept[i] = mem_calloc((size_t)rs->nterms + 1, sizeof **r->kept))) return -1;
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      if (!(r->kept[i][t] = mem_calloc((size_t)rt->nops + 1, sizeof ***r->kept))) return -1;
      for (int k = 0; k < rt->nops; k++) {
        ReducedKept *kp = &r->kept[i][t][k];
        kp->M = mem_malloc(sizeof(double) * (size_t)(n * n + 1));
        kp->factor = mem_malloc(sizeof(double) * (size_t)(n * n + 1));
        kp->chain = mem_malloc(sizeof(double) * (size_t)((kept_steps(rt->ops[k].op) + 1) * n + 1));
        kp->piv = mem_malloc(sizeof(int) * (size_t)(n + 1));
        if (!kp->M || !kp->factor || !kp->chain || !kp->piv) return -1;
      }
    }
  }
  int n = 0;
  FOR_TENSORS(m, t) n += reduced_keeps_local_jacobian(t);
  if (!(r->lj = mem_calloc((size_t)n + 1, sizeof *r->lj))) return -1;
  FOR_TENSORS(m, t) {
    if (!reduced_keeps_local_jacobian(t)) continue;
    r->lj[r->nlj].t = t;
    if (!(r->lj[r->nlj++].J = mem_malloc(sizeof(double) * (size_t)(t->rows * qm(m, t->in_q[0]) + 1)))) return -1;
  }
  r->kept_len = 0;
  for (int q = 0; q < m->nq; q++) r->kept_len += qm(m, q);
  return (r->kept_x = mem_malloc(sizeof(double) * (size_t)(r->kept_len + 1))) ? 0 : -1;
}

/* The coordinates of every quantity, compared with (`check`) or copied to kept_x. */
static bool kept_coords(Reduced *r, bool check) {
  long off = 0;
  for (int q = 0; q < r->m->nq; q++) {
    size_t bytes = sizeof(double) * (size_t)qm(r->m, q);
    if (check && memcmp(r->kept_x + off, r->x[q], bytes) != 0) return false;
    if (!check) memcpy(r->kept_x + off, r->x[q], bytes);
    off += qm(r->m, q);
  }
  return true;
}

void reduced_keep_local_jacobians(Reduced *r, bool on) { r->local_jac = on; }

bool reduced_keeps_local_jacobian(const RTensor *t) {
  return t->data && ((t->nin == 1 && t->in_mult[0] == 2) || (t->nin == 2 && t->in_mult[0] == 1));
}

/* The local Jacobian slot of t while reduced_eval keeps them, else NULL. */
static double *local_jacobian_slot(Reduced *r, const RTensor *t) {
  if (!r->keeping || !r->local_jac) return NULL;
  for (int i = 0; i < r->nlj; i++)
    if (r->lj[i].t == t) return r->lj[i].kept = true, r->lj[i].J;
  return NULL;
}

const double *reduced_kept_local_jacobian(const Reduced *r, const RTensor *t) {
  for (int i = 0; i < r->nlj; i++)
    if (r->lj[i].t == t) return r->lj[i].kept && r->kept_valid && kept_coords((Reduced *)r, true) ? r->lj[i].J : NULL;
  return NULL;
}

/* out += T·(x̂ ⊗ x̂) = ½ J x̂ for J = Ŝ x̂ kept (reduced_keep_local_jacobians): false when t is not
 * such a tensor or Ŝ could not be made (the plain contraction then). */
static bool contract_keeping_jacobian(Reduced *r, const RTensor *t, double *out) {
  if (t->nin != 1 || t->in_mult[0] != 2) return false;
  double *J = local_jacobian_slot(r, t);
  const double *S = J ? reduced_deriv_square(r, t) : NULL;
  if (!S) {
    for (int i = 0; J && i < r->nlj; i++) r->lj[i].kept = r->lj[i].t == t ? false : r->lj[i].kept;
    return false;
  }
  long m = qm(r->m, t->in_q[0]);
  const double *x = r->x[t->in_q[0]];
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)(t->rows * m), (int)m, 1.0, S, (int)m, x, 1, 0.0, J, 1);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)t->rows, (int)m, 0.5, J, (int)m, x, 1, 1.0, out, 1);
  return true;
}

const ReducedKept *reduced_kept(const Reduced *r, int stage, int term, int op) {
  if (!r->kept_valid || !r->kept[stage] || !kept_coords((Reduced *)r, true)) return NULL;
  return &r->kept[stage][term][op];
}

void reduced_free(Reduced *r) {
  if (!r) return;
  for (int q = 0; r->x && q < r->m->nq; q++) free(r->x[q]);
  free(r->x);
  free(r->v);
  free(r->acc);
  free(r->buf[0]);
  free(r->buf[1]);
  free(r->z);
  free(r->M);
  free(r->M2);
  free(r->w);
  free(r->interp_work);
  free(r->piv);
  free(r->tau);
  free(r->diag);
  free(r->off);
  free(r->work);
  free(r->iwork);
  krylov_free(&r->kr);
  free(r->root_start);
  free(r->root_shrink);
  for (int i = 0; i < r->ncolmajor; i++) free(r->colmajor[i].data);
  free(r->colmajor);
  reduced_deriv_cache_free(r->deriv_cache);
  kept_free(r);
  free(r);
}

/* apply_power's LAPACK workspace for operators up to maxm × maxm, once:
 * dsytrd's optimal lwork (its blocked path), dstedc's 1 + 4m + m² and
 * 3 + 5m, dpocon's 3m and dgecon's 4m. */
static int power_workspace(Reduced *r) {
  lapack_int n = (lapack_int)r->maxm;
  double query = 0;
  LAPACKE_dsytrd_work(LAPACK_COL_MAJOR, 'L', n, r->M, n, r->w, r->w, r->w, &query, -1);
  r->lwork = (lapack_int)query;
  if (r->lwork < 1 + 4 * n + n * n) r->lwork = 1 + 4 * n + n * n;
  r->liwork = 3 + 5 * n;
  r->tau = mem_calloc((size_t)n + 1, sizeof(double));
  r->diag = mem_calloc((size_t)n + 1, sizeof(double));
  r->off = mem_calloc((size_t)n + 1, sizeof(double));
  r->work = mem_calloc((size_t)r->lwork, sizeof(double));
  r->iwork = mem_calloc((size_t)r->liwork, sizeof(lapack_int));
  return r->tau && r->diag && r->off && r->work && r->iwork ? 0 : -1;
}

/* A tensor's first contraction step is one dgemv over the whole tensor,
 * lead × last (last: the last input's length). Row-major, that is `lead`
 * dot products of length `last`; where last is short and lead long (the
 * radiosity {d,p} operator's 7260 × 29, d's 2520 × 60) OpenBLAS's dgemv on
 * the column-major copy (`last` axpys of length lead) runs 15–20 % faster,
 * so those tensors get one, made once per evaluator. */
#define COLMAJOR_MAX_LAST 64
#define COLMAJOR_MIN_RATIO 16

static long first_step_lead(const RTensor *t) {
  long lead = t->rows;
  for (int j = 0; j + 1 < t->nin; j++) lead *= t->in_len[j];
  return lead;
}

static int colmajor_copies(Reduced *r) {
  const Model *m = r->m;
  int n = 0;
  for (int pass = 0; pass < 2; pass++) { /* count, then copy */
    for (int i = 0; i < m->nstages; i++)
      for (int t = 0; t < m->stages[i].nterms; t++) {
        RTerm *rt = &m->stages[i].terms[t];
        RTERM_FOR_TENSORS(rt, x) {
          long last = x->nin > 0 ? x->in_len[x->nin - 1] : 0, lead = first_step_lead(x);
          if (!x->data || last < 1 || last > COLMAJOR_MAX_LAST || lead < COLMAJOR_MIN_RATIO * last) continue;
          if (pass == 0) {
            n++;
            continue;
          }
          double *c = mem_malloc(sizeof(double) * (size_t)lead * (size_t)last);
          if (!c) return -1;
          r->colmajor[r->ncolmajor].t = x, r->colmajor[r->ncolmajor].data = c, r->ncolmajor++;
          for (long a = 0; a < lead; a++)
            for (long b = 0; b < last; b++) c[b * lead + a] = x->data[a * last + b];
        }
      }
    if (pass == 0 && !(r->colmajor = mem_calloc((size_t)n + 1, sizeof *r->colmajor))) return -1;
  }
  return 0;
}

static const double *colmajor_of(const Reduced *r, const RTensor *t) {
  for (int i = 0; i < r->ncolmajor; i++)
    if (r->colmajor[i].t == t) return r->colmajor[i].data;
  return NULL;
}

/* r's coordinates and work, sized for its model. -1 when out of memory. */
static int reduced_alloc(Reduced *r) {
  Model *m = r->m;
  if (!(r->x = mem_calloc((size_t)m->nq + 1, sizeof(double *)))) return -1;
  long maxm = 1, maxbuf = 1, maxz = 1;
  for (int c = 0; c < m->nclasses; c++) maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  for (int q = 0; q < m->nq; q++)
    if (!(r->x[q] = mem_calloc((size_t)qm(m, q) + 1, sizeof(double)))) return -1;
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      RTERM_FOR_TENSORS(rt, x) {
        long zs = 0, inter = x->rows;
        for (int j = 0; j < x->nin; j++) zs += x->in_len[j];
        for (int j = 0; j + 1 < x->nin; j++) inter *= x->in_len[j];
        maxz = zs > maxz ? zs : maxz;
        maxbuf = inter > maxbuf ? inter : maxbuf;
      }
    }
  }
  r->maxm = maxm;
  size_t interp_work = 1;
  for (int i = 0; i < m->nstages; i++)
    if (m->stages[i].interp && interp_work_size(&m->stages[i]) > interp_work) interp_work = interp_work_size(&m->stages[i]);
  if (!(r->interp_work = calloc(interp_work, sizeof(double)))) return -1;
  size_t tensor_bytes = 0;
  model_bytes(m, &tensor_bytes);
  r->one_thread = tensor_bytes < REDUCED_ONE_THREAD_BYTES;
  r->v = mem_calloc((size_t)maxm, sizeof(double));
  r->acc = mem_calloc((size_t)(maxm * maxm), sizeof(double));
  r->buf[0] = mem_calloc((size_t)maxbuf, sizeof(double));
  r->buf[1] = mem_calloc((size_t)maxbuf, sizeof(double));
  r->z = mem_calloc((size_t)maxz, sizeof(double));
  r->M = mem_calloc((size_t)(maxm * maxm), sizeof(double));
  r->M2 = mem_calloc((size_t)(maxm * maxm), sizeof(double));
  r->w = mem_calloc((size_t)maxm, sizeof(double));
  r->piv = mem_calloc((size_t)maxm, sizeof(lapack_int));
  r->root_start = mem_calloc((size_t)m->nstages + 1, sizeof(long));
  r->root_shrink = mem_calloc((size_t)m->nstages + 1, sizeof(double));
  if (!r->root_start || !r->root_shrink || !r->v || !r->acc || !r->buf[0] || !r->buf[1] || !r->z || !r->M || !r->M2 || !r->w || !r->piv) return -1;
  return power_workspace(r) || krylov_init(&r->kr, maxm) || colmajor_copies(r) || kept_alloc(r) ? -1 : 0;
}

Reduced *reduced_new(Model *m, Err *err) {
  Reduced *r = mem_calloc(1, sizeof *r);
  if (r) r->m = m;
  if (r && reduced_alloc(r) == 0) return r;
  err_set(err, "out of memory for the reduced evaluator");
  reduced_free(r); /* the half-built evaluator, once */
  return NULL;
}

double *reduced_coords(Reduced *r, int q) { return r->x[q]; }

double *const *reduced_all_coords(Reduced *r) { return r->x; }

struct DerivCache **reduced_deriv_cache(Reduced *r) { return &r->deriv_cache; }

void reduced_project(Reduced *r, int q, const double *x) {
  const RClass *c = &r->m->classes[r->m->qclass[q]];
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)c->n, (int)c->m, 1.0, model_projector(c), (int)c->m, x, 1, 0.0, r->x[q],
              1);
}

void reduced_lift(const Reduced *r, int q, double *y) {
  const RClass *c = &r->m->classes[r->m->qclass[q]];
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)c->n, (int)c->m, 1.0, c->B, (int)c->m, r->x[q], 1, 0.0, y, 1);
}

/* Y = Ŷ Bᵀ: B (n x m, row-major) is streamed once for all the samples
 * (one dgemm), where a dgemv per sample reads it once each. Measured at
 * n = 20,000, m = 20, one thread: 45 µs a sample by dgemv, 23 µs a sample
 * by one dgemm over 16 or 100 samples (bench/lift.py). */
void reduced_lift_many(const Model *m, int q, long samples, const double *coords, double *y) {
  const RClass *c = &m->classes[m->qclass[q]];
  if (samples == 1) {
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)c->n, (int)c->m, 1.0, c->B, (int)c->m, coords, 1, 0.0, y, 1);
    return;
  }
  cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)samples, (int)c->n, (int)c->m, 1.0, coords, (int)c->m,
              c->B, (int)c->m, 0.0, y, (int)c->n);
}

/* out[0..rows) += T ⊗ z_1 ⊗ … ⊗ z_n: the last axis first, each step one
 * dgemv; the first step reads the whole tensor once. */
static void contract(Reduced *r, const RTensor *t, double *out) {
  if (contract_keeping_jacobian(r, t, out)) return;
  if (t->nin == 0) {
    cblas_daxpy((int)t->rows, 1.0, t->data, 1, out, 1);
    return;
  }
  const double *z[RT_MAX_IN];
  double *zp = r->z;
  for (int j = 0; j < t->nin; j++) {
    const double *x = r->x[t->in_q[j]];
    if (t->in_mult[j] == 1) {
      z[j] = x;
      continue;
    }
    sym_power(qm(r->m, t->in_q[j]), t->in_mult[j], x, zp);
    z[j] = zp;
    zp += t->in_len[j];
  }
  long lead = first_step_lead(t);
  const double *src = t->data, *colmajor = colmajor_of(r, t);
  int b = 0;
  for (int j = t->nin - 1; j >= 0; j--) {
    long cols = t->in_len[j];
    double *dst = j == 0 ? out : r->buf[b];
    double beta = j == 0 ? 1.0 : 0.0;
    if (j == t->nin - 1 && colmajor)
      cblas_dgemv(CblasColMajor, CblasNoTrans, (int)lead, (int)cols, 1.0, colmajor, (int)lead, z[j], 1, beta, dst, 1);
    else cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)lead, (int)cols, 1.0, src, (int)cols, z[j], 1, beta, dst, 1);
    double *J0 = j == 1 && t->nin == 2 ? local_jacobian_slot(r, t) : NULL; /* T·z_1 = ∂(T·z)/∂x̂_0 */
    if (J0) memcpy(J0, dst, sizeof(double) * (size_t)lead);
    src = dst;
    b ^= 1;
    if (j > 0) lead /= t->in_len[j - 1];
  }
}

/* The reduced operator of one op of a term, dense my x my in r->M. */
static void assemble_op(Reduced *r, const ROp *ro, long my) {
  memset(r->acc, 0, sizeof(double) * (size_t)(my * my));
  for (int g = 0; g < ro->ntensors; g++) contract(r, &ro->t[g], r->acc);
  if (ro->op->kind == OPK_DIAG) { /* unpack the upper triangle */
    long p = 0;
    for (long a = 0; a < my; a++)
      for (long b = a; b < my; b++) {
        r->M[a * my + b] = r->M[b * my + a] = r->acc[p];
        p++;
      }
  } else {
    memcpy(r->M, r->acc, sizeof(double) * (size_t)(my * my));
  }
}

/* One operator power being applied: operator `k` of term `term` of stage
 * `rs`, on vectors of its class's size `n`, at `sample` (for messages). */
typedef struct OpAt {
  const RStage *rs;
  const ROp *ro;
  int term, k, n;
  long sample;
} OpAt;

static const char *op_label(const OpAt *at, char *buf, size_t n) {
  if (at->ro->op->kind == OPK_DECL) snprintf(buf, n, "%s", at->ro->op->op->name);
  else snprintf(buf, n, "diag (term %d, operator %d)", at->term + 1, at->k + 1);
  return buf;
}

/* ‖M‖₁, the largest column sum of row-major n × n M, summed row by row
 * so that M is read with unit stride; `sum` holds the n column sums. */
static double one_norm(const double *M, long n, double *sum) {
  memset(sum, 0, sizeof(double) * (size_t)n);
  for (long i = 0; i < n; i++)
    for (long j = 0; j < n; j++) sum[j] += fabs(M[i * n + j]);
  double best = 0;
  for (long j = 0; j < n; j++) best = sum[j] > best ? sum[j] : best;
  return best;
}

/* OpenBLAS's threads slow apply_root down at the sizes of reduced
 * operators (on 2 cores, 2 threads take 2 times as long as 1 at m = 20, 1.3
 * at 120, 1.1 at 240; most of it in dsytrd's small BLAS 2 calls), so it
 * runs on one thread and the count is put back after. (The inverse's
 * factorizations gain nothing from one thread: they keep the caller's
 * count.) The count is process-global: BLAS that another thread of the
 * host calls meanwhile runs on one thread too. */
static int blas_one_thread(void) {
  int threads = openblas_get_num_threads();
  if (threads > 1) openblas_set_num_threads(1);
  return threads;
}

static void blas_restore_threads(int threads) {
  if (threads > 1) openblas_set_num_threads(threads);
}

/* v <- M̂^p v for p < 0, M̂ in r->M (destroyed): one factorization, -p
 * solves. M̂ is row-major, so LAPACK's column-major view of it is M̂ᵀ: the
 * same matrix for Cholesky (M̂'s upper triangle is the view's lower one),
 * and for LU the factors of M̂ᵀ solve M̂ with trans 'T'. No copies but the
 * one that keeps M̂ for LU when Cholesky fails. */
/* The likely cause of a singular reduced operator of class `c`: a basis too
 * small to hold what the operator acts on — unless the basis is complete
 * (m = n), when the full operator itself is singular at this sample. */
static const char *singular_why(const RClass *c, char *buf, size_t n) {
  if (c->m >= c->n) snprintf(buf, n, "the full operator itself is singular here (class %s has its full dimension)",
                             c->label);
  else snprintf(buf, n, "basis of class %s too small?", c->label);
  return buf;
}

/* "at sample 12" for a sample of a set (npgc eval's IN/, training's and
 * verify's samples); "at these inputs" when the caller evaluates no set
 * (sample < 0: npg.h, Python's red(...), whose count of calls is no sample). */
static const char *at_sample(long sample, char *buf, size_t n) {
  if (sample >= 0) snprintf(buf, n, "at sample %ld", sample);
  else snprintf(buf, n, "at these inputs");
  return buf;
}

/* A reduced operator that is exactly zero: the full operator vanishes at
 * these inputs (a parameter scaling it is 0), whatever the basis. */
static int zero_operator(Reduced *r, const OpAt *o, const char *what) {
  const RClass *c = &r->m->classes[r->m->qclass[o->rs->q]];
  char lab[256], at[64];
  return rfail(r, "stage %s (class %s): reduced operator %s is zero %s: the operator itself vanishes there (every "
                  "entry 0, e.g. a factor of it that is 0 at these inputs), so its %s is undefined",
               o->rs->st->sym->name, c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at),
               what);
}

static int apply_inverse(Reduced *r, const OpAt *o, double *v, ReducedKept *kp) {
  const RClass *c = &r->m->classes[r->m->qclass[o->rs->q]];
  char lab[256], why[256], at[64];
  const char *sn = o->rs->st->sym->name;
  int n = o->n;
  double anorm = one_norm(r->M, n, r->w), rcond = 0; /* ‖M̂‖₁ = ‖M̂ᵀ‖∞ */
  if (n > 0 && anorm == 0) return zero_operator(r, o, "inverse");
  bool chol = false;
  if (o->ro->spd) { /* paper §4: BᵀMB of a positive definite M is positive definite */
    memcpy(r->M2, r->M, sizeof(double) * (size_t)n * (size_t)n);
    if (LAPACKE_dpotrf_work(LAPACK_COL_MAJOR, 'L', n, r->M2, n) == 0 &&
        LAPACKE_dpocon_work(LAPACK_COL_MAJOR, 'L', n, r->M2, n, anorm, &rcond, r->work, r->iwork) == 0 &&
        rcond > 1e-15)
      chol = true;
  }
  if (!chol) {
    lapack_int info = LAPACKE_dgetrf_work(LAPACK_COL_MAJOR, n, n, r->M, n, r->piv);
    if (info > 0)
      return rfail(r, "stage %s (class %s): reduced operator %s is singular %s (exact zero pivot %d): %s",
                   sn, c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at), (int)info,
                   singular_why(c, why, sizeof why));
    if (info < 0) return rfail(r, "stage %s: LAPACK dgetrf argument %d (a bug in npg)", sn, (int)-info);
    /* the ∞-norm condition of M̂ᵀ is the 1-norm condition of M̂ */
    LAPACKE_dgecon_work(LAPACK_COL_MAJOR, 'I', n, r->M, n, anorm, &rcond, r->work, r->iwork);
    if (!(rcond > 1e-15))
      return rfail(r, "stage %s (class %s): reduced operator %s is singular %s (rcond %.3g): %s", sn,
                   c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at), rcond,
                   singular_why(c, why, sizeof why));
  }
  for (long i = 0; i < -o->ro->op->p; i++) {
    if (chol) LAPACKE_dpotrs_work(LAPACK_COL_MAJOR, 'L', n, 1, r->M2, n, v, n);
    else LAPACKE_dgetrs_work(LAPACK_COL_MAJOR, 'T', n, 1, r->M, n, r->piv, v, n);
    if (kp) memcpy(kp->chain + (i + 1) * n, v, sizeof(double) * (size_t)n);
  }
  if (kp) {
    kp->chol = chol;
    memcpy(kp->factor, chol ? r->M2 : r->M, sizeof(double) * (size_t)n * (size_t)n);
    if (!chol) memcpy(kp->piv, r->piv, sizeof(lapack_int) * (size_t)n);
  }
  return 0;
}

/* v <- Q v (trans 'N') or Qᵀ v ('T'), Q dsytrd's reflectors in r->M and
 * r->tau. LWORK 1 keeps dormtr on its reflector-by-reflector path: for one
 * column the blocked path's triangular factors cost more than the product. */
static lapack_int reflect(Reduced *r, int n, char trans, double *v) {
  return LAPACKE_dormtr_work(LAPACK_COL_MAJOR, 'L', 'L', trans, n, 1, r->M, n, r->tau, v, n, r->work, 1);
}

/* v <- M̂^(p/q) v for symmetric positive semidefinite M̂ in r->M
 * (destroyed), q > 1 (paper §4, root stage): M̂ = Q T Qᵀ (dsytrd; M̂'s
 * row-major upper triangle is the column-major lower one), T = Z Λ Zᵀ
 * (dstedc, Z in r->M2), v <- Q Z Λ^(p/q) Zᵀ Qᵀ v. Q stays dsytrd's
 * reflectors: M̂'s eigenvectors QZ are never formed (dsyevd's back
 * transformation, a quarter of its time at m = 120). */
static int apply_root(Reduced *r, const OpAt *o, double *v) {
  const OpPow *op = o->ro->op;
  const RClass *c = &r->m->classes[r->m->qclass[o->rs->q]];
  char lab[256], why[256], at[64];
  const char *sn = o->rs->st->sym->name;
  int n = o->n;
  double *lam = r->diag, *Z = r->M2, *u = r->w;
  if (r->krylov_roots) { /* the eigendecomposition below only where Lanczos does not converge soon */
    int steps;
    double estimate;
    long si = o->rs - r->m->stages; /* the next sample's operator is a similar one */
    r->kr.start = r->root_start[si], r->kr.shrink = r->root_shrink[si];
    int rc = krylov_power(&r->kr, n, r->M, op->p, op->q, REDUCED_KRYLOV_TOL, n / 2 + 8, v, &steps, &estimate);
    r->root_start[si] = r->kr.start, r->root_shrink[si] = r->kr.shrink;
    r->roots++;
    if (rc == 0) {
      r->root_steps += steps;
      return 0;
    }
    r->root_fallbacks++;
  }
  for (long i = 0; i < (long)n * n; i++)
    if (!isfinite(r->M[i]))
      return rfail(r, "stage %s (class %s): eigendecomposition of reduced operator %s failed %s (entries "
                      "not finite)",
                   sn, c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at));
  lapack_int info = LAPACKE_dsytrd_work(LAPACK_COL_MAJOR, 'L', n, r->M, n, lam, r->off, r->tau, r->work, r->lwork);
  if (info == 0) info = reflect(r, n, 'T', v);
  if (info != 0) return rfail(r, "stage %s: LAPACK dsytrd or dormtr argument %d (a bug in npg)", sn, (int)-info);
  info = LAPACKE_dstedc_work(LAPACK_COL_MAJOR, 'I', n, lam, r->off, Z, n, r->work, r->lwork, r->iwork, r->liwork);
  if (info != 0)
    return rfail(r, "stage %s (class %s): eigendecomposition of reduced operator %s failed %s (LAPACK "
                    "dstedc info %d)",
                 sn, c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at), (int)info);
  double big = 0, low = lam[0];
  for (int i = 0; i < n; i++) big = fmax(big, fabs(lam[i])), low = fmin(low, lam[i]);
  double tol = 1e-12 * (big > 0 ? big : 1);
  if (low < -tol)
    return rfail(r, "stage %s (class %s): reduced operator %s is indefinite %s (eigenvalue %.3g, largest "
                    "%.3g): a root needs a positive semidefinite operator",
                 sn, c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at), low, big);
  if (op->p < 0 && big == 0) return zero_operator(r, o, "negative power");
  if (op->p < 0 && low <= tol)
    return rfail(r, "stage %s (class %s): reduced operator %s is singular %s (eigenvalue %.3g, largest "
                    "%.3g, condition estimate %.3g): %s",
                 sn, c->label, op_label(o, lab, sizeof lab), at_sample(o->sample, at, sizeof at), low, big,
                 low > 0 ? big / low : INFINITY,
                 singular_why(c, why, sizeof why));
  cblas_dgemv(CblasColMajor, CblasTrans, n, n, 1.0, Z, n, v, 1, 0.0, u, 1);
  for (int i = 0; i < n; i++) u[i] *= lam[i] > 0 ? pow(lam[i], (double)op->p / (double)op->q) : 0.0;
  cblas_dgemv(CblasColMajor, CblasNoTrans, n, n, 1.0, Z, n, u, 1, 0.0, v, 1);
  info = reflect(r, n, 'N', v);
  if (info != 0) return rfail(r, "stage %s: LAPACK dormtr argument %d (a bug in npg)", sn, (int)-info);
  return 0;
}

/* v <- M̂^(p/q) v, M̂ in r->M (destroyed); with `kp`, what the derivatives need kept there
 * (ReducedKept: M̂ itself for integer powers and roots, an inverse's factor, the chain). */
static int apply_power(Reduced *r, const OpAt *o, double *v, ReducedKept *kp) {
  const OpPow *op = o->ro->op;
  int n = o->n;
  if (n == 0) return 0;
  if (kp) {
    memcpy(kp->chain, v, sizeof(double) * (size_t)n);
    memcpy(kp->M, r->M, sizeof(double) * (size_t)n * (size_t)n); /* an inverse's too: the estimate's σ_min */
  }
  if (op->q == 1 && op->p > 0) {
    for (long i = 0; i < op->p; i++) {
      cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, r->M, n, v, 1, 0.0, r->w, 1);
      memcpy(v, r->w, sizeof(double) * (size_t)n);
      if (kp) memcpy(kp->chain + (i + 1) * n, v, sizeof(double) * (size_t)n);
    }
    return 0;
  }
  if (op->q == 1) return apply_inverse(r, o, v, kp);
  int threads = blas_one_thread();
  int rc = apply_root(r, o, v);
  blas_restore_threads(threads);
  if (kp && rc == 0) memcpy(kp->chain + n, v, sizeof(double) * (size_t)n);
  return rc;
}

static int eval_extern(Reduced *r, const RExtern *x, long sample) {
  Scratch sc = SCRATCH_OF(NULL);
  double *in = scratch_array(&sc, (size_t)(x->d + 1), sizeof(double)), *w = scratch_array(&sc, (size_t)(x->S + 1), sizeof(double));
  const char *name = ((Sym *)r->m->prog->quantities.v[x->q])->name;
  char err[512] = "", at[64];
  int rc = in && w ? 0 : rfail(r, "out of memory in extern '%s'", name);
  long off = 0;
  for (int j = 0; j < x->nin && rc == 0; j++) {
    long mj = qm(r->m, x->in_q[j]);
    memcpy(in + off, r->x[x->in_q[j]], sizeof(double) * (size_t)mj);
    off += mj;
  }
  if (rc == 0 && nnls_convex((int)x->S, (int)x->d, x->X, in, w, ERR_OF(err, sizeof err)) != 0)
    rc = rfail(r, "extern '%s' %s: %s", name, at_sample(sample, at, sizeof at), err);
  else if (rc == 0) {
    long mz = qm(r->m, x->q);
    cblas_dgemv(CblasRowMajor, CblasTrans, (int)x->S, (int)mz, 1.0, x->Z, (int)mz, w, 1, 0.0, r->x[x->q], 1);
  }
  scratch_release(&sc);
  return rc;
}

void reduced_use_given_externs(Reduced *r, bool on) { r->given_externs = on; }

bool reduced_given_externs(const Reduced *r) { return r->given_externs; }

void reduced_krylov_roots(Reduced *r, bool on) { r->krylov_roots = on; }

void reduced_root_stats(const Reduced *r, long *roots, long *steps, long *fallbacks) {
  *roots = r->roots;
  *steps = r->root_steps;
  *fallbacks = r->root_fallbacks;
}

/* v <- term t of stage rs: its reduced numerator, then each operator power
 * applied innermost first (DESIGN §4); with `M`, the last operator's reduced
 * matrix as assembled, before it is applied. */
static int eval_term(Reduced *r, const RStage *rs, int t, double *v, double *M, long sample) {
  const Model *m = r->m;
  const RTerm *rt = &rs->terms[t];
  long my = qm(m, rs->q);
  if (rt->named_q >= 0) {
    const double *w = r->x[rt->named_q];
    if (rt->proj)
      cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)my, (int)qm(m, rt->named_q), 1.0, rt->proj,
                  (int)qm(m, rt->named_q), w, 1, 0.0, v, 1);
    else memcpy(v, w, sizeof(double) * (size_t)my);
  } else {
    memset(v, 0, sizeof(double) * (size_t)my);
    for (int g = 0; g < rt->nnum; g++) contract(r, &rt->num[g], v);
  }
  ReducedKept *kept = r->keeping ? r->kept[rs - m->stages][t] : NULL;
  for (int k = 0; k < rt->nops; k++) { /* innermost first (DESIGN §4) */
    assemble_op(r, &rt->ops[k], my);
    if (M) memcpy(M, r->M, sizeof(double) * (size_t)(my * my));
    OpAt o = {rs, &rt->ops[k], t, k, (int)my, sample};
    if (apply_power(r, &o, v, kept ? &kept[k] : NULL)) return -1;
  }
  return 0;
}

int reduced_eval_stage(Reduced *r, int i, long sample) {
  if (r->error[0]) return -1;
  Model *m = r->m;
  const RStage *rs = &m->stages[i];
  if (rs->st->kind == ST_EXTERN) {
    if (r->given_externs) return 0;
    for (int k = 0; k < m->nexterns; k++)
      if (m->externs[k].q == rs->q) return eval_extern(r, &m->externs[k], sample);
    return rfail(r, "extern '%s' has no learned model (a bug in npg)", rs->st->sym->name);
  }
  long my = qm(m, rs->q);
  double *y = r->x[rs->q];
  if (rs->interp) { /* DESIGN §12: the formula at the selected entries, fitted */
    char err[512];
    InterpAt at = {r->x, r->interp_work, sample};
    if (interp_eval(m, rs, &at, y, ERR_OF(err, sizeof err))) return rfail(r, "%s", err);
    return 0;
  }
  memset(y, 0, sizeof(double) * (size_t)my);
  for (int t = 0; t < rs->nterms; t++) {
    if (eval_term(r, rs, t, r->v, NULL, sample)) return -1;
    cblas_daxpy((int)my, 1.0, r->v, 1, y, 1);
  }
  return 0;
}

int reduced_term(Reduced *r, int i, int t, double *v, double *M, long sample) {
  if (r->error[0]) return -1;
  const RTerm *rt = &r->m->stages[i].terms[t];
  if (!v) { /* the last operator's matrix alone, as eval_term assembles it, nothing applied */
    if (M && rt->nops > 0) {
      long my = qm(r->m, r->m->stages[i].q);
      assemble_op(r, &rt->ops[rt->nops - 1], my);
      memcpy(M, r->M, sizeof(double) * (size_t)(my * my));
    }
    return 0;
  }
  return eval_term(r, &r->m->stages[i], t, v, M, sample);
}

int reduced_eval(Reduced *r, long sample) {
  int threads = r->one_thread ? blas_one_thread() : 1;
  int rc = 0;
  r->kept_valid = false, r->keeping = true;
  for (int i = 0; i < r->nlj; i++) r->lj[i].kept = false;
  for (int i = 0; i < r->m->nstages && rc == 0; i++) rc = reduced_eval_stage(r, i, sample);
  r->keeping = false;
  if (rc == 0) r->kept_valid = kept_coords(r, false);
  if (r->one_thread) blas_restore_threads(threads);
  return rc;
}

/* ---------------------------------------------------------------- for generated reduced code (emit_reduced.c) */

const Model *reduced_model(const Reduced *r) { return r->m; }

int reduced_apply_power(Reduced *r, const ReducedPower *pw, const double *M, double *v) {
  if (r->error[0]) return -1;
  const Model *m = r->m;
  int stage = pw->stage, term = pw->term, op = pw->op;
  if (stage < 0 || stage >= m->nstages || term < 0 || term >= m->stages[stage].nterms || op < 0 ||
      op >= m->stages[stage].terms[term].nops || m->stages[stage].terms[term].ops[op].op->p != pw->p ||
      m->stages[stage].terms[term].ops[op].op->q != pw->q)
    return rfail(r, "generated reduced code asks for power %ld/%ld of operator %d of term %d of stage %d, which the "
                    "model lacks (code generated for another model?)", pw->p, pw->q, op, term, stage);
  const RStage *rs = &m->stages[stage];
  long my = qm(m, rs->q);
  memcpy(r->M, M, sizeof(double) * (size_t)(my * my));
  OpAt o = {rs, &rs->terms[term].ops[op], term, op, (int)my, pw->sample};
  return apply_power(r, &o, v, NULL);
}
