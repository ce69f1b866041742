/* estimate.c — the online error estimate of a reduced evaluation, chained
 * through the stages, the trust signal of its inputs, and their tables in
 * MODEL/ (estimate.h; training builds the tables: backends/train/estimate_train.c).
 *
 * Per term, ‖r_t‖² = z_tᵀ G_t z_t (estimate.h). Its floating-point value is
 * uncertain by about (8 ε Σ |z_i| ‖C_i‖)² (C_i the unprojected columns: each
 * projected column keeps about ε‖C_i‖ of what I − BBᵀ removed) plus
 * (√n + D) ε (Σ |z_i| √G_ii)² (the Gram sums of n products, the form's D);
 * below that level the figure is the level, flagged EST_ROUNDOFF, never the
 * square root of a negative number or of noise. */
#include <cblas.h>
#include <lapacke.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "estimate.h"
#include "interp.h"
#include "scratch.h"

static long qm(const Model *m, int q) { return m->classes[m->qclass[q]].m; }
static const char *qname(const Model *m, int q) { return ((Sym *)m->prog->quantities.v[q])->name; }

bool estimate_term_eligible(const Model *m, int i, int t, char *why, size_t n) {
  const RStage *rs = &m->stages[i];
  const RTerm *rt = &rs->terms[t];
  if (rs->st->kind == ST_EXTERN) return snprintf(why, n, "an extern's learned map has no estimate"), false;
  if (rs->interp) return snprintf(why, n, "an interpolated stage has no Galerkin terms' tables (its estimate is interp_check's)"), false;
  if (rt->nops > 1 && !estimate_term_chains(rt))
    return snprintf(why, n, "term %d applies %d operators (diagonal operators alone, or more than %d: integer powers "
                    "and roots with a declared operator among them have an estimate)", t + 1, rt->nops,
                    ESTIMATE_OPS_MAX), false;
  if (rt->nops == 1 && !(rt->ops[0].op->p == -1 && rt->ops[0].op->q == 1) && !estimate_term_chains(rt))
    return snprintf(why, n, "term %d applies a power %ld/%ld (%s)", t + 1, (long)rt->ops[0].op->p,
                    (long)rt->ops[0].op->q, rt->ops[0].op->q != 1 ? "a root has an estimate for a declared operator "
                    "only" : "of a diagonal operator only an inverse has an estimate"),
           false;
  const RClass *rc = &m->classes[m->qclass[rs->q]];
  if (rc->product && estimate_term_chains(rt) && !estimate_product_chains(rt))
    return snprintf(why, n, "term %d %s in class %s, orthonormal in the inner product of %s (there projections, "
                    "inverses, operators applied to positive powers and one solve right after the numerator or an "
                    "operator applied once have an estimate)", t + 1,
                    rt->nops > 1            ? "chains solves, roots or diagonal operators otherwise"
                    : rt->ops[0].op->q != 1 ? "takes a root, reduced as (BᵀMB)^α Bᵀw, no approximation in K0's norm,"
                                            : "chains solves (a power below -1)", rc->label, rc->product->name), false;
  /* in a product K0 the figure is ‖e‖_K0 (estimate_product.c): an inverse's from the residual's dual norm, a
   * projection's and an application's residuals exactly, ‖M‖_K0 estimated, a named numerator's error carried
   * across the norms (RTerm.est_carry) */
  if (!m->classes[m->qclass[rs->q]].B && !m->classes[m->qclass[rs->q]].streamed)
    return snprintf(why, n, "class %s has no basis", m->classes[m->qclass[rs->q]].label), false;
  return true;
}

bool estimate_term_chains(const RTerm *rt) {
  if (rt->nops == 1) { /* an application, or a root (root_step) */
    const OpPow *op = rt->ops[0].op;
    return op->kind == OPK_DECL && ((op->q == 1 && (op->p >= 1 || op->p <= -2)) || op->q > 1);
  }
  if (rt->nops < 2 || rt->nops > ESTIMATE_OPS_MAX) return false;
  bool declared = false; /* diagonal operators alone keep their stage's sampled check (galerkincheck) */
  for (int k = 0; k < rt->nops; k++) {
    const OpPow *op = rt->ops[k].op;
    if (op->q == 1 && op->p == 0) return false;
    declared = declared || op->kind == OPK_DECL;
  }
  return declared;
}

/* A root of power above 1: its integer part applied after its fractional part needs ‖M‖'s ratio. */
static bool root_above_one(const OpPow *op) { return op->q > 1 && op->p > op->q; }

int estimate_term_ratios(const RTerm *rt) {
  if (!estimate_term_chains(rt)) return 0;
  int n = rt->nops > 1 ? rt->nops : 0;
  for (int k = 0; k < rt->nops; k++) n += root_above_one(rt->ops[k].op);
  return n;
}

int estimate_norm_slot(const RTerm *rt, int k) {
  if (k < 0 || k >= rt->nops || !root_above_one(rt->ops[k].op) || !estimate_term_chains(rt)) return -1;
  int slot = rt->nops > 1 ? rt->nops : 0;
  for (int j = 0; j < k; j++) slot += root_above_one(rt->ops[j].op);
  return slot;
}

bool estimate_term_applies(const RTerm *rt) {
  for (int k = 0; k < rt->nops; k++)
    if (rt->ops[k].op->kind != OPK_DECL || rt->ops[k].op->q != 1 || rt->ops[k].op->p < 1) return false;
  return rt->nops > 0 && rt->nops <= ESTIMATE_OPS_MAX;
}

bool estimate_product_chains(const RTerm *rt) {
  int solves = 0;
  for (int k = 0; k < rt->nops; k++) {
    const OpPow *op = rt->ops[k].op;
    if (op->kind != OPK_DECL || op->q != 1 || !(op->p >= 1 || op->p == -1)) return false;
    /* a solve takes Bᵀg, g its operand's full-space producer: the numerator, or an operator applied once */
    if (op->p == -1 && (++solves > 1 || (k > 0 && rt->ops[k - 1].op->p != 1))) return false;
  }
  return rt->nops > 0 && rt->nops <= ESTIMATE_OPS_MAX;
}

void estimate_chain_layout(const Model *m, int i, int t, ChainLayout *L) {
  const RTerm *rt = &m->stages[i].terms[t];
  long my = qm(m, m->stages[i].q), off = L->nnum = estimate_term_num_dim(m, i, t);
  for (int k = -1; k < rt->nops; k++) /* the numerator or an applied M^1 right before an inverse: its operand's producer */
    L->joins[k + 1] = (k < 0 || (rt->ops[k].op->p == 1 && rt->ops[k].op->q == 1)) && k + 1 < rt->nops &&
                      rt->ops[k + 1].op->p < 0 && rt->ops[k + 1].op->q == 1;
  for (int k = 0; k < rt->nops; k++) {
    L->off[k] = off, L->len[k] = 0;
    for (int g = 0; g < rt->ops[k].ntensors; g++) L->len[k] += my * rt->ops[k].t[g].cols;
    off += L->len[k];
    L->start[k] = rt->ops[k].op->p > 0 || !L->joins[k] ? L->off[k] : k == 0 ? 0 : L->off[k - 1];
  }
}

long estimate_term_num_dim(const Model *m, int i, int t) {
  const RTerm *rt = &m->stages[i].terms[t];
  long d = 0;
  if (rt->named_q >= 0) return qm(m, rt->named_q);
  for (int g = 0; g < rt->nnum; g++) d += rt->num[g].cols;
  return d;
}

long estimate_term_dim(const Model *m, int i, int t) {
  const RTerm *rt = &m->stages[i].terms[t];
  long d = estimate_term_num_dim(m, i, t);
  for (int k = 0; k < rt->nops; k++)
    for (int g = 0; g < rt->ops[k].ntensors; g++) d += qm(m, m->stages[i].q) * rt->ops[k].t[g].cols;
  return d;
}

size_t estimate_term_bytes(const Model *m, int i, int t) {
  double n = (double)m->classes[m->qclass[m->stages[i].q]].n, D = (double)estimate_term_dim(m, i, t);
  double b = 8 * (n * D + D * D);
  return b < (double)SIZE_MAX / 2 ? (size_t)b : SIZE_MAX;
}

long estimate_test_chunk_rows(void) {
  const char *v = getenv("NPG_TEST_ESTIMATE_CHUNKS");
  return v && atol(v) > 0 ? atol(v) : 0;
}

EstMake estimate_term_make(const Model *m, int i, int t) {
  double D = (double)estimate_term_dim(m, i, t);
  bool product = m->classes[m->qclass[m->stages[i].q]].product, small = 8 * D * D <= (double)ESTIMATE_MAX_TABLE_BYTES;
  size_t bytes = estimate_term_bytes(m, i, t);
  if (bytes <= ESTIMATE_MAX_BYTES && !(small && !product && estimate_test_chunk_rows())) return EST_MAKE_WHOLE;
  if (!small) return EST_MAKE_NONE;
  return !product ? EST_MAKE_CHUNKS : bytes <= ESTIMATE_MAX_PRODUCT_BYTES ? EST_MAKE_WHOLE : EST_MAKE_NONE;
}

void estimate_input_product(const Model *m, double *const *coords, const RTensor *x, double *z, double *scratch) {
  z[0] = 1;
  long len = 1;
  for (int j = 0; j < x->nin; j++) {
    const double *v = coords[x->in_q[j]];
    if (x->in_mult[j] > 1) {
      sym_power(qm(m, x->in_q[j]), x->in_mult[j], v, scratch);
      v = scratch;
    }
    long lj = x->in_len[j];
    for (long a = len - 1; a >= 0; a--) { /* expand in place from the back, the last axis fastest */
      double za = z[a];
      for (long b = lj - 1; b >= 0; b--) z[a * lj + b] = za * v[b];
    }
    len *= lj;
  }
}

EstimateResult *estimate_result_new(const Model *m) {
  EstimateResult *e = calloc(1, sizeof *e);
  if (!e) return NULL;
  e->nq = m->nq;
  e->err = calloc((size_t)m->nq + 1, sizeof(double));
  e->flags = calloc((size_t)m->nq + 1, sizeof(unsigned));
  e->why_q = calloc((size_t)m->nq + 1, sizeof(char[256]));
  if (!e->err || !e->flags || !e->why_q) {
    estimate_result_free(e);
    return NULL;
  }
  return e;
}

void estimate_result_free(EstimateResult *e) {
  if (!e) return;
  free(e->why_q);
  free(e->err);
  free(e->flags);
  free(e);
}

bool estimate_outside(const Model *m, int q, const double *coords, long *coord) {
  const double *rg = m->in_range ? m->in_range[q] : NULL;
  if (!rg) return false;
  long mq = qm(m, q);
  for (long a = 0; a < mq; a++) {
    double lo = rg[a], hi = rg[mq + a], span = hi - lo;
    double margin = ESTIMATE_RANGE_MARGIN * (span > 0 ? span : fmax(fabs(lo), fabs(hi)));
    if (coords[a] < lo - margin || coords[a] > hi + margin) {
      if (coord) *coord = a;
      return true;
    }
  }
  return false;
}

/* One evaluation of the estimate: the evaluator, the figures so far, scratch, and the inputs
 * whose errors the current stage propagates. */
typedef struct Estimation {
  Reduced *r;         /* the evaluator, after reduced_eval */
  EstimateResult *e;  /* the figures so far (stages in order) */
  double *z, *Gz, *v, *M, *M2, *sv, *pack;
  long svlen;
  bool *carry;   /* per quantity: a tensor input of the current stage whose error it propagates */
  int *carried;  /* those quantities, ncarried of them */
  int ncarried;
} Estimation;

static void clear_carried(Estimation *s) {
  for (int k = 0; k < s->ncarried; k++) s->carry[s->carried[k]] = false;
  s->ncarried = 0;
}

/* ‖R_b z_b‖ for the diagonal block b = [off, off + len) of term rt's table (the whole of it: 0, est_D), z
 * in s->z, s->Gz its scratch (the same entries); *roundoff when below the roundoff of the expansion (the
 * figure is then that level). n: the stage's full size. */
static double table_norm(const RTerm *rt, long off, long len, long n, Estimation *s, bool *roundoff) {
  long D = rt->est_D;
  const double *R = rt->est_G + off * D + off, *cn = rt->est_G + D * D + off, *z = s->z + off;
  double *Rz = s->Gz + off;
  memcpy(Rz, z, sizeof(double) * (size_t)len);
  cblas_dtrmv(CblasRowMajor, CblasUpper, CblasNoTrans, CblasNonUnit, (int)len, R, (int)D, Rz, 1);
  double res = cblas_dnrm2((int)len, Rz, 1), a = 0, b = 0;
  for (long i = 0; i < len; i++) a += fabs(z[i]) * cn[i];
  /* the projected columns carry about ε‖C_i‖ each; the QR's backward error about (√n + D) ε of each column. R's
   * column i is the projected column's (a projection by an orthonormal basis: ‖R_i‖ ≤ ‖C_i‖), so b ≤ a, and
   * a residual above the level with 2a for b is above the level: R's column norms (as many flops as the
   * residual itself) are summed only near roundoff, the figure and its flag unchanged */
  double grow = (sqrt((double)n) + (double)len) * DBL_EPSILON;
  if (res > 8 * DBL_EPSILON * a + grow * 2 * a) return *roundoff = false, res;
  for (long i = 0; i < len; i++) b += fabs(z[i]) * cblas_dnrm2((int)(i + 1), R + i, (int)D);
  double level = 8 * DBL_EPSILON * a + grow * b;
  *roundoff = !(res > level);
  return *roundoff ? level : res;
}

/* The numerator's part of z_t (its first estimate_term_num_dim entries) into s->z. */
static void numerator_monomials(Reduced *r, const RTerm *rt, Estimation *s) {
  const Model *m = reduced_model(r);
  double *const *x = reduced_all_coords(r);
  long off = 0;
  if (rt->named_q >= 0) {
    memcpy(s->z, x[rt->named_q], sizeof(double) * (size_t)qm(m, rt->named_q));
    return;
  }
  for (int g = 0; g < rt->nnum; g++) {
    estimate_input_product(m, x, &rt->num[g], s->z + off, s->pack);
    off += rt->num[g].cols;
  }
}

/* The part of z_t of operator `op` of a term, v ⊗ each tensor's packed input product (v: my entries), into
 * s->z from entry `off`; returns the entry after it. */
static long operator_monomials(Reduced *r, const ROp *op, const double *v, long my, long off, Estimation *s) {
  const Model *m = reduced_model(r);
  for (int g = 0; g < op->ntensors; g++) {
    const RTensor *t = &op->t[g];
    estimate_input_product(m, reduced_all_coords(r), t, s->Gz, s->pack);
    for (long a = 0; a < my; a++)
      for (long c = 0; c < t->cols; c++) s->z[off + a * t->cols + c] = v[a] * s->Gz[c];
    off += my * t->cols;
  }
  return off;
}

/* ‖r_t‖ of term `rt` (of a stage of full size n, basis size my) with its
 * value ŷ_t in s->v; *roundoff when below the roundoff of the expansion
 * (the figure is then that level). */
static double residual_norm(Reduced *r, const RTerm *rt, long n, long my, Estimation *s, bool *roundoff) {
  const Model *m = reduced_model(r);
  numerator_monomials(r, rt, s);
  long off = rt->named_q >= 0 ? qm(m, rt->named_q) : 0;
  for (int g = 0; rt->named_q < 0 && g < rt->nnum; g++) off += rt->num[g].cols;
  for (int k = 0; k < rt->nops; k++) off = operator_monomials(r, &rt->ops[k], s->v, my, off, s);
  return table_norm(rt, 0, rt->est_D, n, s, roundoff);
}

/* λ_min of the symmetric my x my matrix G (its upper triangle; destroyed) by dsyevr, NaN if LAPACK fails. */
static double smallest_eigenvalue(double *G, long my, Estimation *s) {
  lapack_int found = 0, isuppz[2];
  return LAPACKE_dsyevr(LAPACK_ROW_MAJOR, 'N', 'I', 'U', (int)my, G, (int)my, 0, 0, 1, 1, 0, &found, s->sv, NULL, 1,
                        isuppz) == 0 && found == 1 ? s->sv[0] : NAN;
}

/* σ_min of the my x my matrix M (destroyed); NaN if LAPACK fails. A symmetric positive definite
 * M̂ (an SPD operator's) by its smallest eigenvalue alone (dsyevr); any other by √λ_min(M̂ᵀM̂) (dsyrk,
 * dsyevr: half of dgesvd's time, whose bidiagonalization is most of it) when the Gram matrix's
 * roundoff, (my + 8) ε ‖M̂‖_F² absolute, is below 1e-10 of λ_min (σ_min then within 1e-10 relative
 * of dgesvd's; the semi-implicit heat step's M̂ takes this route, its estimates unchanged to 4e-16);
 * else dgesvd's smallest singular value. */
static double sigma_min(double *M, long my, Estimation *s) {
  if (my == 0) return INFINITY;
  double big = 0, asym = 0, fro2 = 0, lam;
  for (long i = 0; i < my; i++)
    for (long j = i + 1; j < my; j++) big = fmax(big, fabs(M[i * my + j])), asym = fmax(asym, fabs(M[i * my + j] - M[j * my + i]));
  for (long i = 0; i < my; i++) big = fmax(big, fabs(M[i * my + i]));
  if (asym <= 1e-14 * big) {
    memcpy(s->M2, M, sizeof(double) * (size_t)(my * my)); /* dsyevr destroys it; M stays for dgesvd */
    if ((lam = smallest_eigenvalue(s->M2, my, s)) > 0) return lam;
  }
  for (long i = 0; i < my * my; i++) fro2 += M[i] * M[i];
  cblas_dsyrk(CblasRowMajor, CblasUpper, CblasTrans, (int)my, (int)my, 1.0, M, (int)my, 0.0, s->M2, (int)my);
  if ((double)(my + 8) * DBL_EPSILON * fro2 <= 1e-10 * (lam = smallest_eigenvalue(s->M2, my, s))) return sqrt(lam);
  lapack_int info = LAPACKE_dgesvd_work(LAPACK_ROW_MAJOR, 'N', 'N', (int)my, (int)my, M, (int)my, s->sv, NULL, 1, NULL,
                                        1, s->sv + my, (lapack_int)(s->svlen - my));
  return info == 0 ? s->sv[my - 1] : NAN;
}

/* ŷ of stage i, the sum of its terms (contractions: reduced_term cannot fail), into y; v scratch. */
static void stage_sum(Reduced *r, int i, double *y, double *v, long my) {
  memset(y, 0, sizeof(double) * (size_t)my);
  for (int t = 0; t < reduced_model(r)->stages[i].nterms; t++)
    if (reduced_term(r, i, t, v, NULL, -1) == 0) cblas_daxpy((int)my, 1.0, v, 1, y, 1);
}

/* σ_1 of the my x mq matrix J and its right singular vector into v (mq entries, its sign arbitrary):
 * the largest eigenpair of JᵀJ (dsyrk, then dsyevr for that one pair, on `G`, mq x mq scratch). Squaring
 * loses nothing there: λ_max is found to ε λ_max, so σ_1 to ε/2 relative, and v's sensitivity is the
 * relative gap (σ_1² − σ_2²)/σ_1² ≈ 2 (σ_1 − σ_2)/σ_1, the SVD's own. A tenth of dgesvd's time with
 * every right singular vector at the sizes of n-body's stages (docs/estimates.md, "Cost"). NaN when
 * LAPACK fails. */
static double top_singular(const double *J, long my, long mq, double *G, double *v) {
  cblas_dsyrk(CblasRowMajor, CblasUpper, CblasTrans, (int)mq, (int)my, 1.0, J, (int)mq, 0.0, G, (int)mq);
  lapack_int found = 0, isuppz[2];
  double w[1];
  if (LAPACKE_dsyevr(LAPACK_ROW_MAJOR, 'V', 'I', 'U', (int)mq, G, (int)mq, 0, 0, (int)mq, (int)mq, 0, &found, w, v, 1,
                     isuppz) != 0 || found != 1)
    return NAN;
  return sqrt(fmax(w[0], 0));
}

/* Stage i's propagation of input q's error e_q (DESIGN §16): the stage's local Jacobian J =
 * ∂ŷ/∂x̂_q at the evaluated coordinates (reduced_stage_jvp, or its transpose by reduced_stage_vjp when the
 * stage's basis is the smaller: reduced cost), its largest singular value σ_1 and right singular vector v
 * (top_singular); the figure is max(σ_1 e_q, ‖ŷ(x̂_q ± e_q v) − ŷ(x̂_q)‖), the
 * first order and, for a stage of contractions alone (their evaluation cannot fail), the secant
 * along v both ways, which holds the higher orders of the polynomial there. An estimate: J maps
 * B_q's span only (an error orthogonal to it is assumed to move the output as much as the worst
 * direction inside), and the second order is sampled along v. NaN with `why` on failure. */
typedef struct Propagation {
  int i, q;                      /* the stage, its input */
  double eq;                     /* the input's error */
  double *eye, *J, *G, *vt, *y0; /* buffers: mq × mq, my × mq, mq × mq, mq + my, 3·my + mq */
} Propagation;

/* J = ∂ŷ/∂x̂_q of propagation `b` into b->J by forward directions (my x mq, one direction per input
 * coordinate), or, `reverse`, Jᵀ (mq x my) by reverse ones (one per output coordinate). */
static int stage_partial(Reduced *r, const Propagation *b, bool reverse, Err *err) {
  const Model *m = reduced_model(r);
  long nd = reverse ? qm(m, m->stages[b->i].q) : qm(m, b->q);
  memset(b->eye, 0, sizeof(double) * (size_t)(nd * nd));
  for (long a = 0; a < nd; a++) b->eye[a * nd + a] = 1;
  const double *seed = b->eye;
  ReducedSeeds sd = {1, &b->q, &seed, nd, false};
  return reverse ? reduced_stage_vjp(r, b->i, &sd, b->J, -1, err) : reduced_stage_jvp(r, b->i, &sd, b->J, -1, err);
}

static double propagation(Reduced *r, const Propagation *b, char *why, size_t n) {
  int i = b->i, q = b->q;
  double eq = b->eq, *J = b->J, *G = b->G, *vt = b->vt, *y0 = b->y0;
  const Model *m = reduced_model(r);
  const RStage *rs = &m->stages[i];
  long my = qm(m, rs->q), mq = qm(m, q), k = my < mq ? my : mq;
  char err[256] = "";
  /* the fewer directions, and the smaller Gram matrix: J's top left singular vector u, then v = Jᵀu / σ_1 */
  bool reverse = my < mq;
  if (stage_partial(r, b, reverse, ERR_OF(err, sizeof err)))
    return snprintf(why, n, "the derivative in its input %s (whose error it propagates) failed: %.150s", qname(m, q),
                    err), NAN;
  if (k == 0) return 0;
  double s1 = reverse ? top_singular(J, mq, my, G, vt + mq) : top_singular(J, my, mq, G, vt);
  if (isnan(s1))
    return snprintf(why, n, "the largest singular value of its derivative in %s was not found (LAPACK)", qname(m, q)),
           NAN;
  double out = s1 * eq;
  bool contractions = true;
  for (int t = 0; t < rs->nterms; t++) contractions = contractions && rs->terms[t].nops == 0;
  if (!contractions || !(eq > 0)) return out;
  if (reverse && s1 > 0)
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)mq, (int)my, 1 / s1, J, (int)my, vt + mq, 1, 0.0, vt, 1);
  else if (reverse && (stage_partial(r, b, false, ERR_OF(err, sizeof err)) || isnan(top_singular(J, my, mq, G, vt))))
    return out; /* J = 0: v is any direction, the forward pass's as before (should it fail: the first order, 0) */
  double *y1 = y0 + my, *v = y0 + 2 * my, *save = y0 + 3 * my, *x = reduced_all_coords(r)[q];
  memcpy(save, x, sizeof(double) * (size_t)mq);
  stage_sum(r, i, y0, v, my); /* the base ŷ(x̂_q), by the same sum as the perturbed values */
  for (int sign = -1; sign <= 1; sign += 2) {
    for (long a = 0; a < mq; a++) x[a] = save[a] + sign * eq * vt[a];
    stage_sum(r, i, y1, v, my);
    cblas_daxpy((int)my, -1.0, y0, 1, y1, 1);
    out = fmax(out, cblas_dnrm2((int)my, y1, 1));
  }
  memcpy(x, save, sizeof(double) * (size_t)mq);
  return out;
}

/* propagation with its buffers, from a scratch released at its one exit. */
static double propagate(Reduced *r, int i, int q, double eq, char *why, size_t n) {
  const Model *m = reduced_model(r);
  long my = qm(m, m->stages[i].q), mq = qm(m, q);
  Scratch sc = SCRATCH_OF(NULL);
  Propagation b = {i, q, eq, scratch_array(&sc, (size_t)(mq * mq) + 1, sizeof(double)),
                   scratch_array(&sc, (size_t)(my * mq) + 1, sizeof(double)),
                   scratch_array(&sc, (size_t)(mq * mq) + 1, sizeof(double)),
                   scratch_array(&sc, (size_t)(mq + my) + 1, sizeof(double)),
                   scratch_array(&sc, (size_t)(3 * my + mq) + 1, sizeof(double))};
  double out = NAN;
  if (!b.eye || !b.J || !b.G || !b.vt || !b.y0)
    snprintf(why, n, "out of memory for the propagation of %s's error", qname(m, q));
  else
    out = propagation(r, &b, why, n);
  scratch_release(&sc);
  return out;
}

/* The min-θ lower bound of λ_min(M(x)) for a term whose operator is M_0 + Σ x_j M_j with every
 * M_j positive semidefinite: max over the anchors x̄ of min(1, min_j x_j / x̄_j) · λ_min(M(x̄)), x =
 * B x̂ the input; 0 when there is no table or an x_j is not positive. An error of x itself is the
 * propagation's (propagate): the bound is λ_min's at the evaluated x, whose full solve the residual
 * measures against. */
static double theta_bound(Reduced *r, const RTerm *rt) {
  if (!rt->est_theta || rt->est_theta_k < 1) return 0;
  const Model *m = reduced_model(r);
  const RClass *c = &m->classes[m->qclass[rt->est_theta_q]];
  const double *xh = reduced_all_coords(r)[rt->est_theta_q];
  long n = rt->est_theta_n;
  double x[ESTIMATE_THETA_MAX], best = 0;
  if (c->n != n || n > ESTIMATE_THETA_MAX || !c->B) return 0;
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)c->m, 1.0, c->B, (int)c->m, xh, 1, 0.0, x, 1);
  for (long j = 0; j < n; j++)
    if (!(x[j] > 0)) return 0;
  for (int k = 0; k < rt->est_theta_k; k++) {
    const double *a = rt->est_theta + (long)k * (n + 1);
    double rho = 1;
    for (long j = 0; j < n; j++) rho = fmin(rho, x[j] / a[j]);
    best = fmax(best, rho * a[n]);
  }
  return best;
}

/* Input iq of the stage being estimated: its trust flag into *flags, and, when it carries an
 * error, noted among those the stage propagates (once for all its terms). -1 with `why` when it
 * has no estimate. */
static int note_input(Estimation *s, int iq, unsigned *flags, char *why, size_t n) {
  const EstimateResult *e = s->e;
  const Model *m = reduced_model(s->r);
  *flags |= e->flags[iq] & EST_OUTSIDE;
  if (isnan(e->err[iq])) return snprintf(why, n, "its input %s has no estimate", qname(m, iq)), -1;
  if (e->err[iq] > 0 && !s->carry[iq]) s->carry[iq] = true, s->carried[s->ncarried++] = iq;
  return 0;
}

/* The propagation of the noted inputs' errors through stage i added to *sum (an estimate:
 * EST_BOUND cleared when there is any); the notes cleared. -1 with `why` on failure. */
static int add_propagation(Estimation *s, int i, double *sum, unsigned *flags, char *why, size_t n) {
  Reduced *r = s->r;
  const EstimateResult *e = s->e;
  for (int k = 0; k < s->ncarried; k++) {
    int iq = s->carried[k];
    double p = propagate(r, i, iq, e->err[iq], why, n);
    if (isnan(p)) return clear_carried(s), -1;
    *sum += p;
    *flags &= ~EST_BOUND;
    *flags |= e->flags[iq] & EST_ROUNDOFF;
  }
  clear_carried(s);
  return 0;
}

/* Quantity q's figure into e: v with its flags, or, with `why`, none (its trust flag kept). */
static void store(EstimateResult *e, Estimation *s, int q, double v, unsigned flags, const char *why) {
  clear_carried(s);
  snprintf(e->why_q[q], sizeof e->why_q[q], "%s", why ? why : "");
  e->err[q] = why ? NAN : v;
  e->flags[q] = why ? EST_NONE | (flags & EST_OUTSIDE) : flags;
}

/* A stage's figure as it is made: the estimate, its flags (EST_*), and why there is none. */
typedef struct Figure {
  double est;
  unsigned flags;
  char why[256];
} Figure;

/* The estimate of stage number i by its check entries into e (an interpolated stage, or a Galerkin
 * one of diagonal operators whose terms have no tables): interp_check's sampled residual (exact,
 * flagged a bound, when its entries are all those the fit leaves out), plus the propagation of
 * its inputs' errors. */
static int check_figure(Reduced *r, int i, Estimation *s, Figure *f) {
  double *est = &f->est;
  unsigned *flags = &f->flags;
  char *why = f->why;
  size_t n = sizeof f->why;
  const Model *m = reduced_model(r);
  const RStage *rs = &m->stages[i];
  const RInterp *ip = rs->interp ? rs->interp : rs->check, *ck = rs->interp ? rs->interp->check : NULL;
  InterpCheck ck_out = {NAN, false};
  for (long k = 0; k < ip->nreads + (ck ? ck->nreads : 0); k++)
    if (note_input(s, k < ip->nreads ? ip->read_q[k] : ck->read_q[k - ip->nreads], flags, why, n)) return -1;
  Scratch sc = SCRATCH_OF(NULL);
  double *work = scratch_alloc(&sc, sizeof(double) * interp_check_work_size(rs));
  int rc = work ? interp_check(m, rs, reduced_all_coords(r), work, &ck_out, ERR_OF(why, n))
                : (snprintf(why, n, "out of memory for the estimate"), -1);
  scratch_release(&sc);
  if (rc) return -1;
  *est = ck_out.est;
  if (!ck_out.exact) *flags &= ~EST_BOUND;
  return add_propagation(s, i, est, flags, why, n);
}

static void check_estimate(Reduced *r, int i, EstimateResult *e, Estimation *s) {
  Figure f = {NAN, EST_BOUND, ""};
  int rc = check_figure(r, i, s, &f);
  store(e, s, reduced_model(r)->stages[i].q, f.est, f.flags, rc ? f.why : NULL);
}

/* The factor a named numerator's error enters term rt of quantity q's figure with: 1 when neither its class
 * nor the numerator's has a product, else training's est_carry (NaN when the model holds none). */
static double carry_factor(const Model *m, int q, const RTerm *rt) {
  if (!m->classes[m->qclass[q]].product && !m->classes[m->qclass[rt->named_q]].product) return 1;
  return rt->est_carry > 0 ? rt->est_carry : NAN;
}

/* Operator k of a chained term (estimate_term_chains) as the evaluation applied it. */
typedef struct ChainOp {
  const RTerm *rt;
  int t, k;               /* the term's number (for messages), the operator's */
  const ReducedKept *kp;  /* its M̂ and chain of steps, kept by reduced_eval */
  long my, n;             /* the stage's basis size and full size */
  bool product;           /* the stage's class has a product K0: an inverse divides by product_alpha */
  const ChainLayout *L;   /* the term's columns */
  const ReducedKept *prev; /* operator k − 1's, NULL for the innermost */
} ChainOp;

/* The divisor of an inverse in a chained term of a class with a product K0 (estimate_product_chains): α_LB, the
 * min-θ bound of its operator relative to K0 (theta_bound, the anchors training stored: M(x̄) = K0 or the pencil's
 * λ_min), so that ‖K⁻¹ r‖_K0 ≤ ‖r‖_{K0⁻¹} / α_LB, a bound; its operand's error e comes in K0⁻¹'s norm (a named
 * numerator's carried there, or an applied M's ratio ‖L⁻¹ML⁻ᵀ‖₂ / ‖BᵀMB‖₂). NaN with f->why when there is none. */
static double product_alpha(const ChainOp *o, Estimation *s, Figure *f) {
  double a = theta_bound(s->r, o->rt);
  if (!(a > 0))
    snprintf(f->why, sizeof f->why, "no coercivity bound of operator %d of term %d relative to the class's product %s",
             o->k + 1, o->t + 1, o->rt->est_theta ? "at this input (an entry is not positive)" : "(training found it not "
             "affine in one input with semidefinite terms, or no positive sample)");
  return a > 0 ? a : NAN;
}

/* The figure of the operator that multiplies the error before it (an applied M: ‖M‖₂ ≈ c ‖M̂‖₂, c ≥ 1 since
 * ‖BᵀMB‖₂ ≤ ‖M‖₂ for an orthonormal B) or divides it (an inverse: σ_min(M) ≈ c σ_min(M̂)), c the ratio at
 * training samples (estimate_term_chains). NaN with f->why when training measured none or LAPACK failed. */
static double operator_figure(const ChainOp *o, Estimation *s, Figure *f) {
  const RTerm *rt = o->rt;
  bool inverse = rt->ops[o->k].op->p < 0;
  if (inverse && o->product) return product_alpha(o, s, f);
  double c = rt->nops == 1 ? rt->est_sigma : rt->est_opc ? rt->est_opc[o->k] : NAN, v;
  if (isnan(c))
    return snprintf(f->why, sizeof f->why, "no measure of %s for operator %d of term %d (training found it %s at a "
                    "sample, or its rows exceed %d, the sparse limit)", inverse ? "σ_min" : "‖M‖", o->k + 1, o->t + 1,
                    inverse ? "singular" : "zero", ESTIMATE_SPARSE_MAX), NAN;
  if (o->my == 0) return inverse ? INFINITY : 0;
  if (inverse) {
    memcpy(s->M, o->kp->M, sizeof(double) * (size_t)(o->my * o->my)); /* sigma_min destroys it */
    v = sigma_min(s->M, o->my, s);
  } else {
    v = top_singular(o->kp->M, o->my, o->my, s->M2, s->sv);
  }
  if (!(inverse ? v > 0 : v >= 0))
    return snprintf(f->why, sizeof f->why, "operator %d of term %d: its reduced matrix's %s is %.3g (LAPACK)",
                    o->k + 1, o->t + 1, inverse ? "σ_min" : "norm", v), NAN;
  return c * v;
}

/* Nodes per unit of ln s in root_step's quadrature, and the decades it covers beyond M̂'s spectrum on each side
 * (the tails beyond from the limits of ‖r(s)‖). The integrand is smooth in ln s, and the trapezoidal rule
 * converges geometrically there: on tests/cli/estimate_apply.py's roots (κ(M̂) about 10) these figures agree
 * with 16 nodes a unit over 8 decades to 1.2e-4 of the figure (2 nodes a unit: 2.2e-4), at 65 nodes. */
#define ROOT_NODES_PER_UNIT 4
#define ROOT_DECADES 3

/* A root's step as root_step finds it: operator o->k = M^α of the term, α = k + β (k the integer part toward
 * zero, 0 < |β| < 1: M^(3/2) = M · M^(1/2), M^(-3/2) = M⁻¹ · M^(-1/2)), M̂'s eigendecomposition (Q in s->M's
 * columns, its eigenvalues ascending in lam), the operand's coordinates Qᵀv in vt, λ_min's figure (the min-θ
 * bound, or c λ_min(M̂)) and ‖M‖'s (c' λ_max(M̂), c' the ratio of ‖M‖ at training samples; k ≥ 1 only). */
typedef struct RootParts {
  const ChainOp *o;
  const ChainLayout *L;
  double *lam, *vt;
  long k;
  double beta, lmin, lmax;
} RootParts;

/* ‖(I − BBᵀ) M B u‖, u = Q coef (my entries; consumed before s->Gz is written): the operator's block of the
 * table at u, exact and O(D²). */
static double root_residual(Reduced *r, const RootParts *p, const double *coef, Estimation *s, bool *roundoff) {
  long my = p->o->my;
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)my, (int)my, 1.0, s->M, (int)my, coef, 1, 0.0, s->v, 1);
  operator_monomials(r, &p->o->rt->ops[p->o->k], s->v, my, p->L->off[p->o->k], s);
  return table_norm(p->o->rt, p->L->off[p->o->k], p->L->len[p->o->k], p->o->n, s, roundoff);
}

/* The fractional part's error carried through M^k: with Balakrishnan's representation (root_step) M^k (M^β B v −
 * B M̂^β v) = ∓ (sin |β|π/π) ∫₀^∞ s^β M^k (s + M)⁻¹ r(s) ds, and ‖M^k (s + M)⁻¹‖ = max over M's spectrum of
 * λ^k / (s + λ) = μ^k / (s + μ), μ = ‖M‖ for k ≥ 1 (λ^k / (s + λ) grows with λ), μ = λ_min for k ≤ 0. The
 * trapezoidal rule in ln s over M̂'s spectrum (and μ) widened by ROOT_DECADES each side, ŷ_s = Q (Λ + s)⁻¹ Qᵀv
 * (O(m²) a node), the tails beyond from ‖r(s)‖'s limits (constant as s → 0, ‖(I − BBᵀ) M B v‖ / s as s → ∞). */
static double root_quadrature(Reduced *r, const RootParts *p, Estimation *s) {
  long my = p->o->my;
  double beta = p->beta, mu = p->k >= 1 ? p->lmax : p->lmin, scale = pow(mu, (double)p->k);
  double ulo = log(fmin(p->lmin, p->lam[0])) - ROOT_DECADES * M_LN10,
         uhi = log(fmax(mu, p->lam[my - 1])) + ROOT_DECADES * M_LN10;
  long K = (long)ceil((uhi - ulo) * ROOT_NODES_PER_UNIT);
  double h = (uhi - ulo) / (double)K, rho_lo = 0, rho = 0, sum = 0;
  bool part;
  for (long k = 0; k <= K; k++) {
    double u = ulo + h * (double)k, sn = exp(u);
    for (long a = 0; a < my; a++) s->Gz[a] = p->vt[a] / (p->lam[a] + sn);
    rho = root_residual(r, p, s->Gz, s, &part);
    if (k == 0) rho_lo = rho;
    sum += (k == 0 || k == K ? 0.5 : 1.0) * exp((beta + 1) * u) * rho * scale / (sn + mu);
  }
  double slo = exp(ulo), shi = exp(uhi); /* the tails: ‖r‖ constant below s_lo, ∝ 1/s above s_hi */
  double tails = scale * (rho_lo * pow(slo, beta + 1) / ((beta + 1) * mu) + rho * pow(shi, beta) / (1 - beta));
  return sin(fabs(beta) * M_PI) / M_PI * (h * sum + tails);
}

/* The integer part's error on ẑ = M̂^β v, taken exact: (M^k B − B M̂^k) ẑ chained as an application's (k ≥ 1:
 * e_j = ‖M‖ e_{j−1} + ‖(I − BBᵀ) M B M̂^{j−1} ẑ‖, e_0 = 0, so M^(3/2)'s needs no ‖M‖) or an inverse's (k ≤ −1:
 * e_j = (e_{j−1} + ‖(I − BBᵀ) M B M̂^{−j} ẑ‖) / λ_min, the residual of the Galerkin solve), the intermediate
 * vectors Q Λ^γ Qᵀ v from the eigendecomposition. */
static double root_integer_part(Reduced *r, const RootParts *p, Estimation *s) {
  long my = p->o->my;
  double e = 0, *coef = s->sv + 2 * my;
  bool part;
  for (long j = 1; j <= labs(p->k); j++) {
    double g = p->k > 0 ? p->beta + (double)(j - 1) : p->beta - (double)j;
    for (long a = 0; a < my; a++) coef[a] = p->vt[a] * pow(p->lam[a], g);
    double res = root_residual(r, p, coef, s, &part);
    e = p->k > 0 ? (j > 1 ? p->lmax * e : 0) + res : (e + res) / p->lmin;
  }
  return e;
}

/* Operator k's ratio of σ_min (`norm` false: a root's λ_min) or of ‖M‖ (a root of power above 1) at training
 * samples: est_sigma for a term of one operator, else est_opc (estimate_norm_slot); NaN when not measured. */
static double root_ratio(const RTerm *rt, int k, bool norm) {
  if (!norm) return rt->nops == 1 ? rt->est_sigma : rt->est_opc ? rt->est_opc[k] : NAN;
  int slot = estimate_norm_slot(rt, k);
  return rt->est_opc && slot >= 0 ? rt->est_opc[slot] : NAN;
}

/* The step of a root (estimate_term_chains: M declared, symmetric positive definite as a root's must be, α =
 * p/q not an integer) from v to M̂^α v, e the error of v. The integral representations (Balakrishnan's)
 *   M^β = (sin βπ/π) ∫₀^∞ s^{β−1} M (s + M)⁻¹ ds  (0 < β < 1),   M^β = (sin |β|π/π) ∫₀^∞ s^β (s + M)⁻¹ ds  (−1 < β < 0)
 * hold for M̂ as well, so that (with M(s + M)⁻¹ = I − s(s + M)⁻¹ for the first) in both cases
 *   M^β B v − B M̂^β v = ∓ (sin |β|π/π) ∫₀^∞ s^β (s + M)⁻¹ r(s) ds,   r(s) = B v − (s + M) B ŷ_s,
 * ŷ_s = (s + M̂)⁻¹ v the Galerkin solution of the shifted system: Bᵀr(s) = 0, so r(s) = −(I − BBᵀ) M B ŷ_s, the
 * operator's block of the table at ŷ_s. With α = k + β and M̂^α = M̂^k M̂^β,
 *   M^α B v − B M̂^α v = M^k (M^β B v − B M̂^β v) + (M^k B − B M̂^k) M̂^β v,
 * so the figure is ‖M^α‖ e + root_quadrature + root_integer_part: ‖M^α‖ = λ^α (α < 0), λ_max(M̂)^α (0 < α < 1:
 * the reduced Jacobian's, as the propagation's) or ‖M‖^α (α > 1), λ the min-θ bound or c λ_min(M̂) (the term's
 * ratio). NaN with f->why. */
static double root_step(Reduced *r, const ChainOp *o, const ChainLayout *L, double e, Estimation *s, Figure *f) {
  const RTerm *rt = o->rt;
  const OpPow *op = rt->ops[o->k].op;
  long my = o->my;
  double alpha = (double)op->p / (double)op->q;
  RootParts p = {o, L, s->sv, s->sv + my, op->p / op->q, 0, NAN, NAN};
  p.beta = alpha - (double)p.k;
  f->flags &= ~EST_BOUND; /* a ratio and a quadrature enter */
  if (my == 0) return alpha < 0 ? 0 : e;
  memcpy(s->M, o->kp->M, sizeof(double) * (size_t)(my * my));
  if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', (int)my, s->M, (int)my, p.lam) != 0 || !(p.lam[0] > 0))
    return snprintf(f->why, sizeof f->why, "term %d's reduced operator %d is not positive definite (LAPACK's "
                    "smallest eigenvalue %.3g): a root's estimate needs it", o->t + 1, o->k + 1, p.lam[0]), NAN;
  double theta = rt->nops == 1 ? theta_bound(r, rt) : 0, c = root_ratio(rt, o->k, false);
  if (!(theta > 0) && isnan(c))
    return snprintf(f->why, sizeof f->why, "no measure of σ_min for operator %d of term %d (training found it "
                    "singular at a sample, or its rows exceed %d, the sparse limit)", o->k + 1, o->t + 1,
                    ESTIMATE_SPARSE_MAX), NAN;
  p.lmin = theta > 0 ? theta : c * p.lam[0];
  if (p.k >= 1 && isnan(p.lmax = root_ratio(rt, o->k, true) * p.lam[my - 1]))
    return snprintf(f->why, sizeof f->why, "no measure of ‖M‖ for operator %d of term %d, a root of power above 1 "
                    "(training found it zero at a sample, or its rows exceed %d, the sparse limit)", o->k + 1,
                    o->t + 1, ESTIMATE_SPARSE_MAX), NAN;
  double out = e > 0 ? e * pow(alpha < 0 ? p.lmin : alpha > 1 ? p.lmax : p.lam[my - 1], alpha) : 0;
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)my, (int)my, 1.0, s->M, (int)my, o->kp->chain, 1, 0.0, p.vt, 1);
  return out + root_quadrature(r, &p, s) + root_integer_part(r, &p, s);
}

/* The step of an inverse power M^p (p ≤ −1: M^-2 w is |p| solves by one factorization, reduced.c's apply_inverse)
 * from v_0 to v_|p| = M̂^p v_0 (the kept chain), e the error of v_0. Each solve chains as an inverse: with z_j =
 * M⁻¹ z_{j−1} and v_j = M̂⁻¹ v_{j−1},
 *   z_j − B v_j = M⁻¹ (z_{j−1} − g_j) + M⁻¹ r_j,   r_j = g_j − M B v_j,
 * g_j the full-space producer of v_{j−1} (Bᵀ g_j = v_{j−1}, so Bᵀ r_j = 0 and r_j = (I − BBᵀ) r_j), so e_j =
 * (e_{j−1} + ‖r_j‖) / σ_min(M). The first solve's producer is the numerator or the applied M^1 before it
 * (L->joins: its columns joined in the block); a later one's is B v_{j−1} itself, r_j = −(I − BBᵀ) M B v_j: the same
 * block with the producer's entries zero (R is upper triangular: ‖R [0; z]‖ = ‖C' [0; z]‖, the operator's
 * projected columns alone). σ_min(M) is the min-θ bound for a term of this operator alone (each step a bound,
 * so is the chain), else c σ_min(M̂) (operator_figure: an estimate). *roundoff cleared unless every residual
 * is at roundoff. NaN with f->why. */
static double inverse_steps(Reduced *r, const ChainOp *o, double e, Estimation *s, Figure *f, bool *roundoff) {
  const RTerm *rt = o->rt;
  const ChainLayout *L = o->L;
  long k = o->k, my = o->my, start = L->start[k], end = L->off[k] + L->len[k];
  double sig = rt->nops == 1 && !o->product ? theta_bound(r, rt) : 0;
  if (!(sig > 0)) {
    if (isnan(sig = operator_figure(o, s, f))) return NAN;
    /* a ratio measured at training samples enters (in a product an inverse's α is a bound: est_sigma 1 when its
     * premise is not checked, estimate_product.c) */
    if (!(o->product && isnan(rt->est_sigma))) f->flags &= ~EST_BOUND;
  }
  bool part;
  for (long j = 1; j <= -rt->ops[k].op->p; j++) {
    memset(s->z + start, 0, sizeof(double) * (size_t)(L->off[k] - start));
    if (j == 1 && start == 0) numerator_monomials(r, rt, s);
    if (j == 1 && k > 0 && start == L->off[k - 1]) { /* g = M B v_prev: +, against the block's −M B */
      operator_monomials(r, &rt->ops[k - 1], o->prev->chain, my, L->off[k - 1], s);
      cblas_dscal((int)L->len[k - 1], -1.0, s->z + L->off[k - 1], 1);
    }
    operator_monomials(r, &rt->ops[k], o->kp->chain + j * my, my, L->off[k], s);
    double res = table_norm(rt, start, end - start, o->n, s, &part);
    *roundoff = *roundoff && part;
    e = (e + res) / sig;
  }
  return e;
}

/* Term t of stage i, chained operator by operator (estimate_term_chains, its ChainLayout): e = the numerator's
 * own projection error (its block; none for a named numerator of the class: its coordinates are exact) plus
 * `carried` (a named numerator's estimate), then, innermost operator first, each step of an applied M from v
 * gives e ← ‖M‖ e + ‖(I − BBᵀ) M B v‖ and each solve of an inverse power to v' (inverse_steps) gives e ←
 * (e + ‖r‖) / σ_min(M), r its operand's Galerkin residual (the producer's columns joined), v and v' the
 * evaluation's kept chain. The figure into
 * f->est; f->flags loses EST_BOUND where a ratio (an estimate) enters and gains EST_ROUNDOFF when every residual
 * is at roundoff. -1 with f->why. */
static int chain_figure(Reduced *r, int i, int t, Estimation *s, double carried, Figure *f) {
  const Model *m = reduced_model(r);
  const RStage *rs = &m->stages[i];
  const RTerm *rt = &rs->terms[t];
  long my = qm(m, rs->q), n = m->classes[m->qclass[rs->q]].n;
  ChainLayout L;
  estimate_chain_layout(m, i, t, &L);
  bool roundoff = true, part;
  double e = carried;
  if (!L.joins[0] && (rt->named_q < 0 || rt->proj)) {
    numerator_monomials(r, rt, s);
    e += table_norm(rt, 0, L.nnum, n, s, &part);
    roundoff = part;
  }
  const ReducedKept *prev = NULL;
  for (int k = 0; k < rt->nops; k++) {
    ChainOp o = {rt, t, k, reduced_kept(r, i, t, k), my, n, m->classes[m->qclass[rs->q]].product != NULL, &L, prev};
    if (!o.kp)
      return snprintf(f->why, sizeof f->why, "term %d's reduced operators are not kept from the evaluation (its "
                      "inputs changed since?)", t + 1), -1;
    if (rt->ops[k].op->q != 1) { /* a root: never joined with an inverse after it (its result is in the class) */
      if (isnan(e = root_step(r, &o, &L, e, s, f))) return -1;
      roundoff = false;
      prev = o.kp;
      continue;
    }
    long p = rt->ops[k].op->p;
    if (p < 0 && isnan(e = inverse_steps(r, &o, e, s, f, &roundoff))) return -1;
    double c = NAN;
    for (long j = 0; j < (p > 0 ? p : 0); j++) {
      if (e > 0 && isnan(c) && isnan(c = operator_figure(&o, s, f))) return -1;
      if (e > 0) f->flags &= ~EST_BOUND; /* a ratio measured at training samples enters */
      double res = 0;
      if (!L.joins[k + 1]) { /* an applied M joined with the inverse after it has its residual there */
        operator_monomials(r, &rt->ops[k], o.kp->chain + j * my, my, L.off[k], s);
        res = table_norm(rt, L.off[k], L.len[k], n, s, &part);
        roundoff = roundoff && part;
      }
      e = (e > 0 ? c * e : 0) + res;
    }
    prev = o.kp;
  }
  if (roundoff) f->flags |= EST_ROUNDOFF;
  f->est = e;
  return 0;
}

/* The estimate of stage number i into e (err, flags, why_q of its quantity). */
static int stage_figure(Reduced *r, int i, Estimation *s, Figure *f) {
  double *sump = &f->est;
  unsigned *flagsp = &f->flags;
  char *why = f->why;
  size_t whylen = sizeof f->why;
  const Model *m = reduced_model(r);
  const RStage *rs = &m->stages[i];
  const EstimateResult *e = s->e;
  int q = rs->q;
  long my = qm(m, q), n = m->classes[m->qclass[q]].n;
  double sum = 0;
  unsigned flags = EST_BOUND;
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    if (!estimate_term_eligible(m, i, t, why, whylen)) return *flagsp = flags, -1;
    if (!rt->est_G) {
      double D = (double)estimate_term_dim(m, i, t);
      if (estimate_term_make(m, i, t) == EST_MAKE_NONE && m->classes[m->qclass[q]].product &&
          8 * D * D <= (double)ESTIMATE_MAX_TABLE_BYTES)
        snprintf(why, whylen, "term %d's residual table (%ld x %.0f columns, whole in a class with a product, and their R) "
                 "takes %.1f MiB, above the bound of %zu MiB (ESTIMATE_MAX_PRODUCT_BYTES): smaller bases "
                 "(--basis NAME:cap=N) fit it", t + 1, m->classes[m->qclass[q]].n, D,
                 (double)estimate_term_bytes(m, i, t) / 1048576.0, ESTIMATE_MAX_PRODUCT_BYTES >> 20);
      else if (estimate_term_make(m, i, t) == EST_MAKE_NONE)
        snprintf(why, whylen, "term %d's residual table (R of %.0f columns) takes %.1f MiB, above the bound of %zu MiB "
                 "(ESTIMATE_MAX_TABLE_BYTES): smaller bases (--basis NAME:cap=N) fit it", t + 1, D,
                 8 * D * D / 1048576.0, ESTIMATE_MAX_TABLE_BYTES >> 20);
      else
        snprintf(why, whylen, "the model holds no estimate table for term %d (trained without one: see npgc train's "
                 "report, or a model older than the estimates)", t + 1);
      return *flagsp = flags, -1;
    }
    RTERM_FOR_TENSORS(rt, x)
      for (int j = 0; j < x->nin; j++)
        if (note_input(s, x->in_q[j], &flags, why, whylen)) return *flagsp = flags, -1;
    double carried = 0; /* a named numerator's own error */
    if (rt->named_q >= 0) {
      if (isnan(e->err[rt->named_q])) {
        snprintf(why, whylen, "its numerator %s has no estimate", qname(m, rt->named_q));
        return *flagsp = flags, -1;
      }
      carried = e->err[rt->named_q] * carry_factor(m, q, rt);
      if (!(carried >= 0)) {
        snprintf(why, whylen, "the model holds no factor carrying numerator %s's error into the norm of term %d (a "
                 "class with a product: retrain)", qname(m, rt->named_q), t + 1);
        return *flagsp = flags, -1;
      }
      flags |= e->flags[rt->named_q] & (EST_OUTSIDE | EST_ROUNDOFF);
      if (!(e->flags[rt->named_q] & EST_BOUND)) flags &= ~EST_BOUND;
    }
    if (estimate_term_chains(rt)) {
      Figure a = {0, flags, ""};
      if (chain_figure(r, i, t, s, carried, &a)) return snprintf(why, whylen, "%s", a.why), *flagsp = flags, -1;
      sum += a.est, flags = a.flags;
      continue;
    }
    /* ŷ_t: a stage of one term holds it (the evaluation's sum of one term), not solved again here; M, when
     * σ_min needs it, assembled below */
    if (rs->nterms == 1) memcpy(s->v, reduced_all_coords(r)[q], sizeof(double) * (size_t)my);
    else if (reduced_term(r, i, t, s->v, rt->nops ? s->M : NULL, -1)) {
      snprintf(why, whylen, "term %d failed: %.200s", t + 1, reduced_error(r));
      return *flagsp = flags, -1;
    }
    bool roundoff;
    double res = residual_norm(r, rt, n, my, s, &roundoff);
    if (roundoff) flags |= EST_ROUNDOFF;
    if (rt->nops == 0) {
      sum += res + carried;
      continue;
    }
    if (isnan(rt->est_sigma) && !(rt->est_theta && rt->est_theta_k > 0) && !m->classes[m->qclass[q]].product) {
      snprintf(why, whylen, "no lower bound of σ_min of term %d's operator (singular at a training sample, or its rows "
               "exceed %d, the sparse limit in training)", t + 1, ESTIMATE_SPARSE_MAX);
      return *flagsp = flags, -1;
    }
    double sig = theta_bound(r, rt);
    if (m->classes[m->qclass[q]].product && !(sig > 0)) { /* no Euclidean σ_min to fall back on */
      const char *k0 = m->classes[m->qclass[q]].product->name;
      if (rt->est_theta)
        snprintf(why, whylen, "no coercivity bound of term %d's operator relative to %s at this input (an entry is not "
                 "positive)", t + 1, k0);
      else
        snprintf(why, whylen, "no coercivity bound of term %d's operator relative to %s (training found its operator "
                 "not affine in one input with semidefinite terms, or no positive sample, or its pencil with %s above "
                 "%d rows)", t + 1, k0, k0, ESTIMATE_SPARSE_MAX);
      return *flagsp = flags, -1;
    }
    if (m->classes[m->qclass[q]].product && !isnan(rt->est_sigma))
      flags &= ~EST_BOUND; /* B's Dirichlet rows above roundoff: the bound's premise is not checked (estimate_product.c) */
    if (!(sig > 0)) {
      if (rs->nterms == 1 && reduced_term(r, i, t, NULL, s->M, -1)) {
        snprintf(why, whylen, "term %d failed: %.200s", t + 1, reduced_error(r));
        return *flagsp = flags, -1;
      }
      sig = rt->est_sigma * sigma_min(s->M, my, s);
      flags &= ~EST_BOUND; /* σ_min is estimated from the training samples */
    }
    if (!(sig > 0)) {
      snprintf(why, whylen, "term %d's reduced operator has σ_min %.3g: no estimate", t + 1, sig);
      return *flagsp = flags, -1;
    }
    sum += (res + carried) / sig;
  }
  *flagsp = flags;
  int rc = add_propagation(s, i, &sum, flagsp, why, whylen);
  *sump = sum;
  return rc;
}

static void stage_estimate(Reduced *r, int i, EstimateResult *e, Estimation *s) {
  const RStage *rs = &reduced_model(r)->stages[i];
  bool tables = true; /* every term has its residual's table (exact for contractions): else the check entries */
  for (int t = 0; t < rs->nterms; t++) tables = tables && rs->terms[t].est_G;
  if (rs->interp || (rs->check && !tables)) {
    check_estimate(r, i, e, s);
    return;
  }
  Figure f = {0, EST_BOUND, ""};
  int rc = stage_figure(r, i, s, &f);
  store(e, s, rs->q, f.est, f.flags, rc ? f.why : NULL);
}

int estimate_eval(Reduced *r, const double *input_err, EstimateResult *e) {
  const Model *m = reduced_model(r);
  long maxm = 1, maxD = 1, maxpack = 1, maxcols = 1;
  for (int c = 0; c < m->nclasses; c++) maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  FOR_TENSORS(m, x) {
    long z = 0;
    for (int j = 0; j < x->nin; j++) z += x->in_len[j];
    maxpack = z > maxpack ? z : maxpack;
    maxcols = x->cols > maxcols ? x->cols : maxcols;
  }
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++)
      maxD = m->stages[i].terms[t].est_D > maxD ? m->stages[i].terms[t].est_D : maxD;
  Estimation s = {.r = r, .e = e};
  s.svlen = maxm + 5 * maxm + 64;
  Scratch sc = SCRATCH_OF(NULL);
  s.z = scratch_array(&sc, (size_t)maxD, sizeof(double));
  s.Gz = scratch_array(&sc, (size_t)(maxD > maxcols ? maxD : maxcols), sizeof(double));
  s.v = scratch_array(&sc, (size_t)maxm, sizeof(double));
  s.M = scratch_array(&sc, (size_t)(maxm * maxm), sizeof(double));
  s.M2 = scratch_array(&sc, (size_t)(maxm * maxm), sizeof(double));
  s.sv = scratch_array(&sc, (size_t)s.svlen, sizeof(double));
  s.pack = scratch_array(&sc, (size_t)maxpack, sizeof(double));
  s.carry = scratch_array(&sc, (size_t)m->nq + 1, sizeof(bool));
  s.carried = scratch_array(&sc, (size_t)m->nq + 1, sizeof(int));
  int rc = s.z && s.Gz && s.v && s.M && s.M2 && s.sv && s.pack && s.carry && s.carried ? 0 : -1;
  e->why[0] = 0;
  /* m-sized LAPACK and D-sized BLAS: OpenBLAS's second thread only costs here (as in reduced.c) */
  int threads = openblas_get_num_threads();
  if (threads > 1) openblas_set_num_threads(1);
  for (int q = 0; rc == 0 && q < m->nq; q++) { /* inputs: their own error, and the trust signal */
    const Sym *sy = m->prog->quantities.v[q];
    e->err[q] = 0, e->flags[q] = EST_BOUND, e->why_q[q][0] = 0;
    if (sy->kind != SYM_INPUT) continue;
    e->err[q] = input_err ? input_err[q] : 0;
    if (estimate_outside(m, q, reduced_all_coords(r)[q], NULL)) e->flags[q] |= EST_OUTSIDE;
  }
  for (int i = 0; rc == 0 && i < m->nstages; i++) {
    if (m->stages[i].st->kind == ST_EXTERN) {
      int q = m->stages[i].q;
      e->err[q] = NAN, e->flags[q] = EST_NONE;
      snprintf(e->why_q[q], 256, "an extern's learned map has no estimate");
    } else {
      stage_estimate(r, i, e, &s);
    }
    int q = m->stages[i].q;
    if (isnan(e->err[q]) && !e->why[0]) snprintf(e->why, sizeof e->why, "%s: %s", qname(m, q), e->why_q[q]);
  }
  if (threads > 1) openblas_set_num_threads(threads);
  scratch_release(&sc);
  return rc;
}

/* ---------------------------------------------------------------- files */

static void est_name(char *buf, size_t n, const char *stage, int t) { snprintf(buf, n, "est_%s_t%d", stage, t); }

/* "estops STAGE T c_1 … c_K": a chained term's ratios (RTerm.est_opc, estimate_term_ratios of them), after its
 * estimate line. */
static int save_opc(const RTerm *rt, const char *stage, int t, ModelStore *s) {
  int K = estimate_term_ratios(rt);
  if (!rt->est_opc || K < 1) return 0; /* training measures none above ESTIMATE_OPS_MAX */
  char line[32 * (2 * ESTIMATE_OPS_MAX + 1)];
  int used = 0;
  for (int k = 0; k < K; k++) used += snprintf(line + used, sizeof line - (size_t)used, " %.17g", rt->est_opc[k]);
  return model_store_meta(s, "estops %s %d%s", stage, t, line);
}

int estimate_save(const Model *m, ModelStore *s) {
  int bad = 0;
  char name[600];
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      const RTerm *rt = &m->stages[i].terms[t];
      if (!rt->est_G) continue;
      const char *sn = m->stages[i].st->sym->name;
      bad |= model_store_meta(s, "estimate %s %d dim %ld sigma %.17g qr", sn, t, rt->est_D, rt->est_sigma);
      est_name(name, sizeof name, sn, t);
      long shape[2] = {rt->est_D + 1, rt->est_D};
      bad |= model_store_add(s, name, 2, shape, rt->est_G);
      if (rt->est_carry > 0) bad |= model_store_meta(s, "carry %s %d factor %.17g", sn, t, rt->est_carry);
      bad |= save_opc(rt, sn, t, s);
      if (!rt->est_theta || rt->est_theta_k < 1) continue;
      bad |= model_store_meta(s, "theta %s %d input %s anchors %d", sn, t, qname(m, rt->est_theta_q), rt->est_theta_k);
      snprintf(name, sizeof name, "theta_%s_t%d", sn, t);
      long tshape[2] = {rt->est_theta_k, rt->est_theta_n + 1};
      bad |= model_store_add(s, name, 2, tshape, rt->est_theta);
    }
  for (int q = 0; m->in_range && q < m->nq; q++) {
    if (!m->in_range[q]) continue;
    bad |= model_store_meta(s, "range %s", qname(m, q));
    snprintf(name, sizeof name, "range_%s", qname(m, q));
    long shape[2] = {2, qm(m, q)};
    bad |= model_store_add(s, name, 2, shape, m->in_range[q]);
  }
  return bad;
}

/* The array `name` of shape rows x cols, copied; NULL with `err`. */
static double *take(const ModelStore *s, const char *dir, const char *name, long rows, long cols, Err *err) {
  const NpyArray *a = model_store_array(s, name);
  if (!a || a->ndim != 2 || a->shape[0] != rows || a->shape[1] != cols) {
    err_set(err, "%s/%s.npy: %s, the model's layout needs %ld x %ld (a damaged or forged model; retrain)", dir,
            name, a ? "another shape" : "missing", rows, cols);
    return NULL;
  }
  double *d = malloc(sizeof(double) * (size_t)(rows * cols) + 1);
  if (!d) err_set(err, "%s/%s.npy: out of memory", dir, name);
  else memcpy(d, a->data, sizeof(double) * (size_t)(rows * cols));
  return d;
}

static int load_estimate_line(Model *m, const ModelStore *s, const char *line, const char *dir, Err *err) {
  char stage[512], name[600], why[256];
  int t, used = 0;
  long D;
  double sigma;
  bool ok = sscanf(line, "estimate %511s %d dim %ld sigma %lf%n", stage, &t, &D, &sigma, &used) == 4;
  if (ok && !line[used]) return 0; /* a Gram table (models before the QR form): left out, the term reports no table */
  ok = ok && strcmp(line + used, " qr") == 0;
  for (int i = 0; ok && i < m->nstages; i++) {
    if (strcmp(m->stages[i].st->sym->name, stage) != 0) continue;
    if (t < 0 || t >= m->stages[i].nterms || !estimate_term_eligible(m, i, t, why, sizeof why) ||
        D != estimate_term_dim(m, i, t) || !(isnan(sigma) || sigma > 0))
      break;
    RTerm *rt = &m->stages[i].terms[t];
    est_name(name, sizeof name, stage, t);
    free(rt->est_G);
    if (!(rt->est_G = take(s, dir, name, D + 1, D, err))) return -1;
    rt->est_D = D, rt->est_sigma = sigma;
    for (long k = 0; k < (D + 1) * D; k++)
      if (!isfinite(rt->est_G[k])) return err_set(err, "%s/%s.npy: not finite at entry %ld", dir, name, k);
    return 0;
  }
  return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                 dir, line);
}

static int load_range_line(Model *m, const ModelStore *s, const char *line, const char *dir, Err *err) {
  char qn[512], name[600];
  int used = 0;
  int q = -1;
  if (sscanf(line, "range %511s%n", qn, &used) == 1 && !line[used])
    for (int k = 0; k < m->nq; k++)
      if (strcmp(qname(m, k), qn) == 0 && ((Sym *)m->prog->quantities.v[k])->kind == SYM_INPUT) q = k;
  if (q < 0)
    return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                   dir, line);
  if (!m->in_range && !(m->in_range = calloc((size_t)m->nq + 1, sizeof(double *))))
    return err_set(err, "%s: out of memory", dir);
  snprintf(name, sizeof name, "range_%s", qn);
  free(m->in_range[q]);
  if (!(m->in_range[q] = take(s, dir, name, 2, qm(m, q), err))) return -1;
  for (long a = 0; a < qm(m, q); a++)
    if (!(m->in_range[q][a] <= m->in_range[q][qm(m, q) + a]))
      return err_set(err, "%s/%s.npy: coordinate %ld's min is not at most its max", dir, name, a);
  return 0;
}

/* "theta STAGE T input NAME anchors K": the min-θ table of an estimate line's term (after it). */
static int load_theta_line(Model *m, const ModelStore *s, const char *line, const char *dir, Err *err) {
  char stage[512], qn[512], name[1100];
  int t, k, used = 0, q = -1;
  bool ok = sscanf(line, "theta %511s %d input %511s anchors %d%n", stage, &t, qn, &k, &used) == 4 && !line[used] &&
            k > 0 && k <= ESTIMATE_SIGMA_SAMPLES;
  for (int j = 0; ok && j < m->nq; j++)
    if (strcmp(qname(m, j), qn) == 0 && ((Sym *)m->prog->quantities.v[j])->kind == SYM_INPUT) q = j;
  for (int i = 0; ok && q >= 0 && i < m->nstages; i++) {
    if (strcmp(m->stages[i].st->sym->name, stage) != 0) continue;
    if (t < 0 || t >= m->stages[i].nterms || !m->stages[i].terms[t].est_G) break;
    RTerm *rt = &m->stages[i].terms[t];
    long n = m->classes[m->qclass[q]].n;
    if (n > ESTIMATE_THETA_MAX) break;
    snprintf(name, sizeof name, "theta_%s_t%d", stage, t);
    free(rt->est_theta);
    if (!(rt->est_theta = take(s, dir, name, k, n + 1, err))) return -1;
    rt->est_theta_q = q, rt->est_theta_n = n, rt->est_theta_k = k;
    for (long e = 0; e < (long)k * (n + 1); e++)
      if (!(rt->est_theta[e] > 0) || !isfinite(rt->est_theta[e]))
        return err_set(err, "%s/%s.npy: entry %ld is not positive and finite", dir, name, e);
    return 0;
  }
  return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                 dir, line);
}

/* "carry STAGE T factor F": the factor of an estimate line's term carrying its named numerator's error across
 * norms (RTerm.est_carry; after the term's estimate line). A model without it (older than the factor) leaves
 * such a term without an estimate. */
static int load_carry_line(Model *m, const char *line, const char *dir, Err *err) {
  char stage[512];
  int t, used = 0;
  double c;
  bool ok = sscanf(line, "carry %511s %d factor %lf%n", stage, &t, &c, &used) == 3 && !line[used] && c > 0 &&
            isfinite(c);
  for (int i = 0; ok && i < m->nstages; i++) {
    if (strcmp(m->stages[i].st->sym->name, stage) != 0) continue;
    if (t < 0 || t >= m->stages[i].nterms || !m->stages[i].terms[t].est_G || m->stages[i].terms[t].named_q < 0) break;
    m->stages[i].terms[t].est_carry = c;
    return 0;
  }
  return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                 dir, line);
}

/* "estops STAGE T c_1 … c_K": the ratios of a chained term with a table (after its line): K = estimate_term_ratios,
 * one per operator of a term of several, then one ‖M‖ ratio per root of power above 1. */
static int load_opc_line(Model *m, const char *line, const char *dir, Err *err) {
  char stage[512];
  int t, used = 0;
  bool ok = sscanf(line, "estops %511s %d%n", stage, &t, &used) == 2;
  for (int i = 0; ok && i < m->nstages; i++) {
    if (strcmp(m->stages[i].st->sym->name, stage) != 0) continue;
    RTerm *rt = t >= 0 && t < m->stages[i].nterms ? &m->stages[i].terms[t] : NULL;
    int K = rt ? estimate_term_ratios(rt) : 0;
    if (!rt || !rt->est_G || K < 1) break;
    free(rt->est_opc);
    if (!(rt->est_opc = malloc(sizeof(double) * (size_t)K))) return err_set(err, "%s: out of memory", dir);
    const char *p = line + used;
    for (int k = 0; k < K; k++) {
      char *end;
      rt->est_opc[k] = strtod(p, &end);
      if (end == p || !(isnan(rt->est_opc[k]) || rt->est_opc[k] > 0)) ok = false;
      p = end;
    }
    if (!ok || *p) break;
    return 0;
  }
  return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                 dir, line);
}

int estimate_load(Model *m, const ModelStore *s, const char *dir, Err *err) {
  for (int i = 0; i < s->nmeta; i++) {
    const char *line = s->meta[i];
    if (strncmp(line, "estimate ", 9) == 0 && load_estimate_line(m, s, line, dir, err)) return -1;
    if (strncmp(line, "range ", 6) == 0 && load_range_line(m, s, line, dir, err)) return -1;
    if (strncmp(line, "theta ", 6) == 0 && load_theta_line(m, s, line, dir, err)) return -1;
    if (strncmp(line, "carry ", 6) == 0 && load_carry_line(m, line, dir, err)) return -1;
    if (strncmp(line, "estops ", 7) == 0 && load_opc_line(m, line, dir, err)) return -1;
  }
  return 0;
}
