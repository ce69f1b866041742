/* reduced.c — the reduced step of paper Fig. 2, right column (see reduced.h). */
#include "util.h"
#include "reduced.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <cblas.h>
#include <lapacke.h>

static int fail(char *err, size_t errlen, const char *msg, const char *detail) {
  snprintf(err, errlen, "%s%s%s", msg, detail ? ": " : "", detail ? detail : "");
  return -1;
}

/* ---------------------------------------------------------------- set-up */

static int split_advection(RedSolver *s, char *err, size_t errlen);

static int class_info(const NpgModel *m, const char *q, int *c, long *n, long *mm_, const double **B, char *err,
                      size_t errlen) {
  *c = npg_model_class_of(m, q);
  NpgClassInfo ci;
  if (*c < 0 || npg_model_class(m, *c, &ci) != 0) return fail(err, errlen, "model has no class for", q);
  *n = ci.n, *mm_ = ci.m;
  *B = npg_model_basis(m, *c);
  if (!*B) return fail(err, errlen, "model has no basis for", q);
  return 0;
}

static int set_all(RedSolver *s, const double *gc, const double *gdc, const double *fc, const double *uc) {
  NpgReduced *r = s->r;
  if (npg_reduced_set_coords(r, "g", s->mg, gc) || npg_reduced_set_coords(r, "gdot", s->mgd, gdc) ||
      npg_reduced_set_coords(r, "f", s->mf, fc) || npg_reduced_set_coords(r, "u", s->mu, uc) ||
      npg_reduced_eval(r, s->evals++))
    return -1;
  return 0;
}

static int get_coords(RedSolver *s, const char *name, double *out, long m, char *err, size_t errlen) {
  size_t k = 0;
  const double *c = npg_reduced_coords(s->r, name, &k);
  if (!c || (long)k != m) return fail(err, errlen, "no reduced coordinates of", name);
  memcpy(out, c, (size_t)m * sizeof *out);
  return 0;
}

/* Column j of the matrix a stage's reduced coordinates are, for û = e_j
 * (the stage is linear in u): evaluate at (gc, gdc, fc, e_j) for every j
 * and gather coords of `name` into M (mu x mu, row-major). */
static int matrix_in_u(RedSolver *s, const char *name, const double *gc, const double *gdc, const double *fc,
                       double *M, double *uc, double *col, char *err, size_t errlen) {
  long mu = s->mu;
  for (long j = 0; j < mu; j++) {
    uc[j] = 1;
    if (set_all(s, gc, gdc, fc, uc) != 0) return fail(err, errlen, npg_reduced_error(s->r), NULL);
    uc[j] = 0;
    if (get_coords(s, name, col, mu, err, errlen)) return -1;
    for (long i = 0; i < mu; i++) M[i * mu + j] = col[i];
  }
  return 0;
}

/* ---------------------------------------------------------------- monomials in ĝ */

/* The monomials of degree s->deg_* in ĝ, listed as sorted index triples
 * (unused entries -1), and their values at a point. */
static long mono_list(int deg, long mg, int (*idx)[3]) {
  long n = 0;
  for (int i = 0; i < mg; i++) {
    if (deg == 1) {
      if (idx) idx[n][0] = i, idx[n][1] = idx[n][2] = -1;
      n++;
      continue;
    }
    for (int j = i; j < mg; j++) {
      if (deg == 2) {
        if (idx) idx[n][0] = i, idx[n][1] = j, idx[n][2] = -1;
        n++;
        continue;
      }
      for (int k = j; k < mg; k++) {
        if (idx) idx[n][0] = i, idx[n][1] = j, idx[n][2] = k;
        n++;
      }
    }
  }
  return n;
}

static void mono_values(long n, const int (*idx)[3], const double *x, double *out) {
  for (long a = 0; a < n; a++) {
    double v = x[idx[a][0]];
    if (idx[a][1] >= 0) v *= x[idx[a][1]];
    if (idx[a][2] >= 0) v *= x[idx[a][2]];
    out[a] = v;
  }
}

/* ---------------------------------------------------------------- slices */

/* sl from the slices S [n][len] (overwritten): S = U Σ Vᵀ, rank r = the
 * singular values above tol * ref; coef = U_r, basis = Σ_r V_rᵀ. */
static int slices_make(RedSlices *sl, double *S, long n, long len, double tol, double ref, char *err, size_t errlen) {
  long k = n < len ? n : len;
  double *sv = malloc((size_t)(k + 1) * sizeof *sv), *U = malloc((size_t)(n * k + 1) * sizeof *U);
  double *Vt = malloc((size_t)(k * len + 1) * sizeof *Vt), *sup = malloc((size_t)(k + 1) * sizeof *sup);
  int rc = 0;
  memset(sl, 0, sizeof *sl);
  sl->n = n, sl->len = len;
  if (!sv || !U || !Vt || !sup) rc = fail(err, errlen, "out of memory", NULL);
  else if (k > 0 && LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'S', 'S', (int)n, (int)len, S, (int)len, sv, U, (int)k, Vt,
                                   (int)len, sup) != 0)
    rc = fail(err, errlen, "SVD of the slices of a reduced operator failed", NULL);
  long r = 0;
  while (!rc && r < k && sv[r] > tol * ref) r++;
  sl->rank = r;
  sl->coef = malloc((size_t)(n * r + 1) * sizeof *sl->coef);
  sl->basis = malloc((size_t)(r * len + 1) * sizeof *sl->basis);
  sl->c = malloc((size_t)(r + 1) * sizeof *sl->c);
  if (!rc && (!sl->coef || !sl->basis || !sl->c)) rc = fail(err, errlen, "out of memory", NULL);
  for (long a = 0; a < n && !rc; a++)
    for (long i = 0; i < r; i++) sl->coef[a * r + i] = U[a * k + i];
  for (long i = 0; i < r && !rc; i++)
    for (long e = 0; e < len; e++) sl->basis[i * len + e] = sv[i] * Vt[i * len + e];
  free(sv), free(U), free(Vt), free(sup);
  return rc;
}

static void slices_free(RedSlices *sl) {
  free(sl->coef), free(sl->basis), free(sl->c);
  memset(sl, 0, sizeof *sl);
}

/* out = Σ_a w[a] S[a] + beta out. */
static void slices_apply(const RedSlices *sl, const double *w, double beta, double *out) {
  int r = (int)sl->rank, len = (int)sl->len;
  if (r == 0) {
    if (beta == 0) memset(out, 0, (size_t)len * sizeof *out);
    return;
  }
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)sl->n, r, 1.0, sl->coef, r, w, 1, 0.0, sl->c, 1);
  cblas_dgemv(CblasRowMajor, CblasTrans, r, len, 1.0, sl->basis, len, sl->c, 1, beta, out, 1);
}

/* A matrix-valued homogeneous polynomial of ĝ evaluated into `out` (len). */
typedef int (*PolyEval)(RedSolver *s, void *ctx, const double *gc, double *out, char *err, size_t errlen);

/* The coefficient of every monomial of degree `deg` (≤ 3) of a homogeneous
 * polynomial p of ĝ, by polarization: p(e_i) = c_iii; p(e_i ± e_j) give
 * c_iij and c_ijj; p(e_i + e_j + e_k) gives c_ijk. coef: [n][len]. */
static int poly_coefficients(RedSolver *s, int deg, long n, const int (*idx)[3], PolyEval fn, void *ctx, long len,
                             double *coef, char *err, size_t errlen) {
  long mg = s->mg;
  int *at = malloc((size_t)(mg * mg * mg) * sizeof *at);
  double *pt = calloc((size_t)mg, sizeof *pt), *buf = malloc((size_t)len * sizeof *buf), *b2 = malloc((size_t)len * sizeof *b2);
  for (long a = 0; a < n; a++) {
    int i = idx[a][0], j = idx[a][1] < 0 ? i : idx[a][1], k = idx[a][2] < 0 ? j : idx[a][2];
    at[(i * mg + j) * mg + k] = (int)a;
  }
#define AT(i, j, k) (coef + (size_t)at[((i)*mg + (deg > 1 ? (j) : (i))) * mg + (deg > 2 ? (k) : (deg > 1 ? (j) : (i)))] * len)
  int rc = 0;
  /* pure powers */
  for (long i = 0; i < mg && !rc; i++) {
    pt[i] = 1;
    rc = fn(s, ctx, pt, AT(i, i, i), err, errlen);
    pt[i] = 0;
  }
  /* pairs */
  for (long i = 0; i < mg && !rc && deg > 1; i++)
    for (long j = i + 1; j < mg && !rc; j++) {
      double *ci = AT(i, i, i), *cj = AT(j, j, j);
      pt[i] = pt[j] = 1;
      rc = fn(s, ctx, pt, buf, err, errlen);
      if (!rc && deg == 3) {
        pt[j] = -1;
        rc = fn(s, ctx, pt, b2, err, errlen);
      }
      pt[i] = pt[j] = 0;
      if (rc) break;
      if (deg == 2) {
        double *cij = AT(i, j, j);
        for (long e = 0; e < len; e++) cij[e] = buf[e] - ci[e] - cj[e];
      } else {
        double *ciij = AT(i, i, j), *cijj = AT(i, j, j);
        for (long e = 0; e < len; e++) {
          double sp = buf[e] - ci[e] - cj[e], sm = b2[e] - ci[e] + cj[e];
          ciij[e] = 0.5 * (sp - sm), cijj[e] = 0.5 * (sp + sm);
        }
      }
    }
  /* triples */
  for (long i = 0; i < mg && !rc && deg > 2; i++)
    for (long j = i + 1; j < mg && !rc; j++)
      for (long k = j + 1; k < mg && !rc; k++) {
        pt[i] = pt[j] = pt[k] = 1;
        rc = fn(s, ctx, pt, buf, err, errlen);
        pt[i] = pt[j] = pt[k] = 0;
        if (rc) break;
        const double *parts[9] = {AT(i, i, i), AT(j, j, j), AT(k, k, k), AT(i, i, j), AT(i, j, j),
                                  AT(i, i, k), AT(i, k, k), AT(j, j, k), AT(j, k, k)};
        double *cijk = AT(i, j, k);
        for (long e = 0; e < len; e++) {
          double v = buf[e];
          for (int q = 0; q < 9; q++) v -= parts[q][e];
          cijk[e] = v;
        }
      }
#undef AT
  free(at), free(pt), free(buf), free(b2);
  return rc;
}

/* pv at ĝ: V̂(ĝ) (mu x mu). */
static int eval_volume(RedSolver *s, void *ctx, const double *gc, double *out, char *err, size_t errlen) {
  double **w = ctx; /* zero gdot, zero f, unit u, a column */
  return matrix_in_u(s, "pv", gc, w[0], w[1], out, w[2], w[3], err, errlen);
}

/* pdot at ĝ, ĝdot = e_q, f̂ = 0 (−Â_h ⊗ ĥ, mu x mu) and then bh (D̂_h ĥ, mb). */
typedef struct InducedCtx {
  double *gdc, *fc, *uc, *col;
  long q;
} InducedCtx;

static int eval_induced(RedSolver *s, void *vctx, const double *gc, double *out, char *err, size_t errlen) {
  InducedCtx *c = vctx;
  c->gdc[c->q] = 1;
  int rc = matrix_in_u(s, "pdot", gc, c->gdc, c->fc, out, c->uc, c->col, err, errlen);
  if (!rc) rc = get_coords(s, "bh", out + s->mu * s->mu, s->mb, err, errlen);
  c->gdc[c->q] = 0;
  return rc;
}

/* Constraint reduction (paper §6.4): D̂ = U Σ Vᵀ, rank r = the singular
 * values above tol σ_0; N = V[:, r:] (the free directions), D̂⁺ = V_r Σ_r⁻¹
 * U_rᵀ. */
int red_constraints(RedSolver *s, double tol, char *err, size_t errlen) {
  long mb = s->mb, mf = s->mf;
  int rc = 0;
  double *D = malloc((size_t)(mb * mf) * sizeof(double) + 8);
  memcpy(D, s->D, (size_t)(mb * mf) * sizeof(double));
  {
    double *Uu = malloc((size_t)(mb * mb) * sizeof(double) + 8), *Vt = malloc((size_t)(mf * mf) * sizeof(double));
    double *sv = malloc((size_t)(mb < mf ? mb : mf) * sizeof(double) + 8), *sup = malloc((size_t)(mb + mf) * sizeof(double));
    long kmin = mb < mf ? mb : mf;
    if (LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'A', 'A', mb, mf, D, mf, sv, Uu, mb, Vt, mf, sup) != 0) {
      rc = fail(err, errlen, "SVD of the reduced boundary operator failed", NULL);
    } else {
      long r = 0;
      for (long i = 0; i < kmin; i++)
        if (sv[i] > tol * sv[0] && sv[i] > 1e-13) r++;
      s->drank = r;
      s->nn = mf - r;
      for (long k = 0; k < mf; k++)
        for (long j = 0; j < s->nn; j++) s->N[k * s->nn + j] = Vt[(r + j) * mf + k];
      for (long k = 0; k < mf; k++)
        for (long b = 0; b < mb; b++) {
          double v = 0;
          for (long i = 0; i < r; i++) v += Vt[i * mf + k] * Uu[b * mb + i] / sv[i];
          s->Dpinv[k * mb + b] = v;
        }
    }
    free(Uu), free(Vt), free(sv), free(sup);
  }
  free(D);
  /* P̂(ĝ) N, linear in ĝ like P̂: the projection's matrix on the null space of D̂ */
  free(s->PNs);
  s->PNs = NULL;
  if (!rc && s->nn > 0) {
    long mg = s->mg, mu = s->mu;
    size_t uf = (size_t)mu * (size_t)mf;
    s->PNs = malloc((size_t)mg * (size_t)mu * (size_t)s->nn * sizeof(double));
    if (!s->PNs) rc = fail(err, errlen, "out of memory", NULL);
    for (long l = 0; l < mg && !rc; l++)
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)mu, (int)s->nn, (int)mf, 1.0, s->Ps + (size_t)l * uf,
                  (int)mf, s->N, (int)s->nn, 0.0, s->PNs + (size_t)l * (size_t)mu * (size_t)s->nn, (int)s->nn);
  }
  return rc;
}

/* The reduced tensors' storage and the step's work arrays, sized by the bases (s->mg,
 * s->mu, ... and the monomial counts set); -1 when any allocation fails (red_free frees
 * what was allocated). */
static int alloc_state(RedSolver *s) {
  long mg = s->mg, mgd = s->mgd, mu = s->mu, mf = s->mf, mb = s->mb;
  long nh = s->nmh * mgd, ny = mu * (mu + 1) / 2;
  size_t uu = (size_t)(mu * mu), uf = (size_t)(mu * mf);
  s->Ps = calloc((size_t)mg * uf, sizeof(double));
  s->As = calloc((size_t)mf * uu, sizeof(double));
  s->Vp = malloc((size_t)ny * sizeof(double));
  s->Bhs = calloc((size_t)(nh * mb) + 1, sizeof(double));
  s->L = calloc(uu, sizeof(double));
  s->Dpinv = calloc((size_t)(mf * mb) + 1, sizeof(double));
  s->N = calloc((size_t)(mf * mf) + 1, sizeof(double));
  s->g = calloc((size_t)mg, sizeof(double));
  s->f = calloc((size_t)mf, sizeof(double));
  s->u = calloc((size_t)mu, sizeof(double));
  s->gmid = calloc((size_t)mg, sizeof(double));
  s->gdot = calloc((size_t)mgd, sizeof(double));
  s->wgt = calloc((size_t)nh, sizeof(double));
  s->mvals = calloc((size_t)(s->nmv + 3 * s->nmh), sizeof(double));
  s->b = calloc((size_t)mb + 1, sizeof(double));
  s->A = malloc(uu * sizeof(double));
  s->M = malloc(uu * sizeof(double));
  s->E = malloc(uu * sizeof(double));
  s->V0 = malloc(uu * sizeof(double));
  s->V1 = malloc(uu * sizeof(double));
  s->W = malloc(uf * sizeof(double));
  s->K = malloc((size_t)(mf * mf) * sizeof(double));
  s->KN = malloc((size_t)(mf * mf) * sizeof(double));
  s->Kn = malloc((size_t)(mf * mf) * sizeof(double));
  s->work = malloc(8 * uu * sizeof(double) + (size_t)(8 * (mu + mf) + (mg + 1) * mu) * sizeof(double));
  s->tmp = malloc((size_t)(4 * (mu + mf) + 8) * sizeof(double));
  s->tmp2 = malloc((size_t)(4 * (mu + mf) + 8) * sizeof(double));
  s->tmp3 = malloc((size_t)(4 * (mu + mf) + 8) * sizeof(double));
  s->kmax = mu < 64 ? (int)mu : 64;
  size_t kk = (size_t)s->kmax;
  s->Vf = malloc(uu * sizeof(double));
  s->Vfg = malloc((size_t)mg * sizeof(double) + 8);
  s->Q = malloc((kk + 1) * (size_t)mu * sizeof(double));
  s->H = malloc((kk + 1) * kk * sizeof(double));
  s->Hx = malloc(kk * kk * sizeof(double));
  s->hwork = malloc(9 * kk * kk * sizeof(double) + 8 * kk * sizeof(double));
  void *all[] = {s->Ps,  s->As, s->Vp, s->Bhs, s->L,  s->Dpinv, s->N,    s->g,    s->f,  s->u,  s->gmid,
                 s->gdot, s->wgt, s->mvals, s->b, s->A, s->M,  s->E,     s->V0,   s->V1, s->W,
                 s->K,   s->KN, s->Kn, s->work, s->tmp, s->tmp2, s->tmp3, s->Vf, s->Vfg, s->Q, s->H,
                 s->Hx,  s->hwork};
  for (size_t i = 0; i < sizeof all / sizeof *all; i++)
    if (!all[i]) return -1;
  return 0;
}

int red_init(RedSolver *s, const NpgModel *model, int dim, double visc, double dt, char *err, size_t errlen) {
  memset(s, 0, sizeof *s);
  s->model = model;
  s->visc = visc, s->dt = dt;
  s->integ = RED_EXPMV;
  long nb;
  const double *Bb;
  if (class_info(model, "g", &s->cg, &s->ng, &s->mg, &s->Bg, err, errlen) ||
      class_info(model, "gdot", &s->cgd, &s->ngd, &s->mgd, &s->Bgd, err, errlen) ||
      class_info(model, "f", &s->cf, &s->nf, &s->mf, &s->Bf, err, errlen) ||
      class_info(model, "u", &s->cu, &s->nu, &s->mu, &s->Bu, err, errlen) ||
      class_info(model, "bf", &s->cb, &nb, &s->mb, &Bb, err, errlen))
    return -1;
  s->r = npg_reduced_new(model);
  if (!s->r) return fail(err, errlen, "out of memory", NULL);
  if (s->mg > 16 || (dim != 2 && dim != 3)) {
    red_free(s);
    return fail(err, errlen, "the geometry basis is larger than 16 or dim is not 2 or 3", NULL);
  }
  double t0 = util_now();
  long mg = s->mg, mgd = s->mgd, mu = s->mu, mf = s->mf, mb = s->mb;
  /* paper §5.1, §5.4: V(g) has degree dim in g, h(g, gdot) degree dim - 1 */
  s->dim = dim;
  s->nmv = mono_list(dim, mg, NULL);
  s->nmh = mono_list(dim - 1, mg, NULL);
  s->mono_v = malloc((size_t)s->nmv * sizeof *s->mono_v);
  s->mono_h = malloc((size_t)s->nmh * sizeof *s->mono_h);
  if (!s->mono_v || !s->mono_h) {
    red_free(s);
    return fail(err, errlen, "out of memory", NULL);
  }
  mono_list(dim, mg, s->mono_v);
  mono_list(dim - 1, mg, s->mono_h);
  long nh = s->nmh * mgd, ny = mu * (mu + 1) / 2;
  size_t uu = (size_t)(mu * mu), uf = (size_t)(mu * mf);
  double *Vs = calloc((size_t)s->nmv * uu, sizeof(double)), *Ahs = calloc((size_t)nh * uu, sizeof(double));
  double *D = calloc((size_t)(mb * mf) + 1, sizeof(double));
  double *gc = calloc((size_t)mg, sizeof(double)), *fc = calloc((size_t)mf, sizeof(double));
  double *uc = calloc((size_t)mu, sizeof(double)), *gdc = calloc((size_t)mgd, sizeof(double));
  double *pc = malloc((size_t)mu * sizeof(double)), *bc = malloc((size_t)mb * sizeof(double) + 8);
  int rc = 0;
  if (alloc_state(s) || !Vs || !Ahs || !D || !gc || !fc || !uc || !gdc || !pc || !bc) {
    rc = fail(err, errlen, "out of memory", NULL);
    goto done;
  }
  /* Δ̂: lap at û = e_j (constant) */
  if ((rc = matrix_in_u(s, "lap", gc, gdc, fc, s->L, uc, pc, err, errlen))) goto done;
  /* Â_k: pdot at f̂ = e_k, ĝdot = 0 (so ĥ = 0), û = e_j */
  for (long k = 0; k < mf && !rc; k++) {
    fc[k] = 1;
    rc = matrix_in_u(s, "pdot", gc, gdc, fc, s->As + (size_t)k * uu, uc, pc, err, errlen);
    fc[k] = 0;
  }
  /* V̂ slices: pv, homogeneous of degree dim in ĝ, one slice per monomial */
  if (!rc) {
    double *w[4] = {gdc, fc, uc, pc};
    rc = poly_coefficients(s, dim, s->nmv, s->mono_v, eval_volume, w, (long)uu, Vs, err, errlen);
  }
  /* kept as their lower triangles (what the Cholesky factorization reads),
   * row by row, and compressed (RedSlices) */
  if (!rc) {
    double *lo = Vs; /* in place: row i of slice a's triangle ends before its full row i */
    for (long a = 0; a < s->nmv; a++)
      for (long i = 0; i < mu; i++)
        memmove(lo + a * ny + i * (i + 1) / 2, Vs + (size_t)a * uu + (size_t)(i * mu), (size_t)(i + 1) * sizeof *lo);
    rc = slices_make(&s->Vs, lo, s->nmv, ny, 1e-12, cblas_dnrm2((int)(s->nmv * ny), lo, 1), err, errlen);
  }
  /* −Â_h ⊗ ĥ(ĝ, ĝdot) slices: pdot at f̂ = 0, ĝdot = e_q (ĥ linear in ĝdot,
   * of degree dim - 1 in ĝ), û = e_j; and D̂_h ĥ: bh there */
  if (!rc) {
    double *buf = malloc((uu + (size_t)mb) * (size_t)s->nmh * sizeof *buf);
    InducedCtx ctx = {gdc, fc, uc, pc, 0};
    for (long q = 0; q < mgd && !rc; q++) {
      ctx.q = q;
      rc = poly_coefficients(s, dim - 1, s->nmh, s->mono_h, eval_induced, &ctx, (long)(uu + mb), buf, err, errlen);
      for (long a = 0; a < s->nmh && !rc; a++) {
        memcpy(Ahs + (size_t)(a * mgd + q) * uu, buf + (size_t)a * (uu + mb), uu * sizeof *buf);
        memcpy(s->Bhs + (size_t)(a * mgd + q) * mb, buf + (size_t)a * (uu + mb) + uu, (size_t)mb * sizeof *buf);
      }
    }
    free(buf);
  }
  if (!rc) rc = slices_make(&s->Ahs, Ahs, nh, (long)uu, 1e-12, cblas_dnrm2((int)(nh * (long)uu), Ahs, 1), err, errlen);
  /* P̂ slices: p at ĝ = e_l, f̂ = e_k (bilinear); D̂: bf at f̂ = e_k */
  for (long l = 0; l < mg && !rc; l++) {
    gc[l] = 1;
    for (long k = 0; k < mf; k++) {
      fc[k] = 1;
      if (set_all(s, gc, gdc, fc, uc) != 0) {
        rc = fail(err, errlen, npg_reduced_error(s->r), NULL);
        break;
      }
      fc[k] = 0;
      if ((rc = get_coords(s, "p", pc, mu, err, errlen))) break;
      for (long i = 0; i < mu; i++) s->Ps[(size_t)l * uf + (size_t)(i * mf + k)] = pc[i];
      if (l == 0) {
        if ((rc = get_coords(s, "bf", bc, mb, err, errlen))) break;
        for (long i = 0; i < mb; i++) D[i * mf + k] = bc[i];
      }
    }
    gc[l] = 0;
  }
  if (rc) goto done;
  s->D = D;
  D = NULL;
  rc = red_constraints(s, 1e-10, err, errlen);
  if (rc) goto done;
  /* Â ⊗ f̂ split into its skew part, stored as strict upper triangles, and its
   * symmetric part, which comes from the diagonal of A ⊗ f: half the net
   * interior outflow of each cell, i.e. (B_f's columns being divergence-free)
   * half its boundary flux, which the few vectors of B_d span; the SVD of
   * the symmetric parts finds that rank (singular values above 1e-12 of the
   * tensor's norm), so the step reads a little over half of the tensor. */
  rc = split_advection(s, err, errlen);
  free(s->As);
  s->As = NULL;
  if (rc) goto done;
  s->seconds_setup = util_now() - t0;
done:
  free(D), free(gc), free(fc), free(uc), free(gdc), free(pc), free(bc), free(Vs), free(Ahs);
  if (rc) red_free(s);
  return rc;
}

static int split_advection(RedSolver *s, char *err, size_t errlen) {
  long mu = s->mu, mf = s->mf, nk = mu * (mu - 1) / 2, ny = mu * (mu + 1) / 2;
  size_t uu = (size_t)(mu * mu);
  s->Ask = malloc((size_t)(mf * nk + 1) * sizeof(double));
  double *Y = malloc((size_t)(mf * ny + 1) * sizeof(double));
  if (!s->Ask || !Y) {
    free(Y);
    return fail(err, errlen, "out of memory", NULL);
  }
  for (long k = 0; k < mf; k++) {
    const double *Ak = s->As + (size_t)k * uu;
    double *kk = s->Ask + (size_t)(k * nk), *yk = Y + (size_t)(k * ny);
    for (long i = 0; i < mu; i++)
      for (long j = i; j < mu; j++) {
        double a = Ak[i * mu + j], b = Ak[j * mu + i];
        *yk++ = 0.5 * (a + b);
        if (j > i) *kk++ = 0.5 * (a - b);
      }
  }
  /* relative to the whole tensor: with fixed walls B_f carries no boundary
   * flux and the symmetric parts are rounding noise (rank 0) */
  double total = cblas_dnrm2((int)((size_t)mf * uu), s->As, 1);
  int rc = slices_make(&s->Asy, Y, mf, ny, 1e-12, total, err, errlen);
  s->rs = s->Asy.rank;
  free(Y);
  return rc;
}

int red_single_advection(RedSolver *s, char *err, size_t errlen) {
  long mf = s->mf, nk = s->mu * (s->mu - 1) / 2;
  if (s->Ask32) return 0;
  s->Ask32 = malloc((size_t)(mf * nk + 1) * sizeof *s->Ask32);
  s->f32 = malloc((size_t)(mf + 1) * sizeof *s->f32);
  s->sk32 = malloc((size_t)(nk + 1) * sizeof *s->sk32);
  if (!s->Ask32 || !s->f32 || !s->sk32) {
    free(s->Ask32), free(s->f32), free(s->sk32);
    s->Ask32 = NULL, s->f32 = s->sk32 = NULL;
    return fail(err, errlen, "out of memory", NULL);
  }
  for (long i = 0; i < mf * nk; i++) s->Ask32[i] = (float)s->Ask[i];
  free(s->Ask);
  s->Ask = NULL;
  return 0;
}

/* sk = Σ_k f̂_k Ask[k] into s->work (double), from the single-precision
 * copy when there is one. */
static double *advection_skew(const RedSolver *s, const double *fc) {
  int mf = (int)s->mf, nk = (int)(s->mu * (s->mu - 1) / 2);
  double *sk = s->work;
  if (!s->Ask32) {
    cblas_dgemv(CblasRowMajor, CblasTrans, mf, nk, 1.0, s->Ask, nk, fc, 1, 0.0, sk, 1);
    return sk;
  }
  for (int k = 0; k < mf; k++) s->f32[k] = (float)fc[k];
  cblas_sgemv(CblasRowMajor, CblasTrans, mf, nk, 1.0f, s->Ask32, nk, s->f32, 1, 0.0f, s->sk32, 1);
  for (int i = 0; i < nk; i++) sk[i] = s->sk32[i];
  return sk;
}

void red_advection(const RedSolver *s, const double *fc, double *A) {
  int mu = (int)s->mu, nk = mu * (mu - 1) / 2;
  double *sk = advection_skew(s, fc), *sy = s->work + nk;
  slices_apply(&s->Asy, fc, 0.0, sy);
  for (int i = 0; i < mu; i++) {
    A[(size_t)i * mu + i] = *sy++;
    for (int j = i + 1; j < mu; j++, sy++, sk++) A[(size_t)i * mu + j] = *sy + *sk, A[(size_t)j * mu + i] = *sy - *sk;
  }
}

void red_free(RedSolver *s) {
  if (s->r) npg_reduced_free(s->r);
  slices_free(&s->Vs), slices_free(&s->Asy), slices_free(&s->Ahs);
  free(s->Vp), free(s->Ps), free(s->As), free(s->Bhs), free(s->wgt), free(s->L), free(s->Dpinv);
  free(s->mono_v), free(s->mono_h), free(s->mvals), free(s->D);
  free(s->N), free(s->g), free(s->f), free(s->u);
  free(s->gmid), free(s->gdot), free(s->b), free(s->A), free(s->M), free(s->E), free(s->V0), free(s->V1);
  free(s->W), free(s->K), free(s->KN), free(s->Kn), free(s->work), free(s->tmp), free(s->tmp2), free(s->tmp3);
  free(s->Ask), free(s->Ask32), free(s->f32), free(s->sk32), free(s->PNs), free(s->Vf), free(s->Vfg), free(s->Q), free(s->H), free(s->Hx), free(s->hwork);
  memset(s, 0, sizeof *s);
}

/* ---------------------------------------------------------------- geometry-dependent operators */

/* V̂(ĝ)'s lower triangle, row by row, into s->Vp */
static const double *volume_lower(const RedSolver *s, const double *gc) {
  mono_values(s->nmv, s->mono_v, gc, s->mvals);
  slices_apply(&s->Vs, s->mvals, 0.0, s->Vp);
  return s->Vp;
}

void red_volume(const RedSolver *s, const double *gc, double *V) {
  long mu = s->mu;
  const double *lo = volume_lower(s, gc);
  for (long i = 0; i < mu; i++)
    for (long j = 0; j <= i; j++) V[i * mu + j] = V[j * mu + i] = lo[i * (i + 1) / 2 + j];
}

void red_pmat(const RedSolver *s, const double *gc, double *P) {
  size_t uf = (size_t)(s->mu * s->mf);
  memset(P, 0, uf * sizeof *P);
  for (long l = 0; l < s->mg; l++)
    if (gc[l] != 0) cblas_daxpy((int)uf, gc[l], s->Ps + (size_t)l * uf, 1, P, 1);
}

void red_lift(const double *B, long n, long m, const double *x, double *out) {
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)m, 1.0, B, (int)m, x, 1, 0.0, out, 1);
}

void red_coords(const double *B, long n, long m, const double *x, double *out) {
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, (int)m, 1.0, B, (int)m, x, 1, 0.0, out, 1);
}

void red_project_g(const RedSolver *s, const double *g, double *gc) {
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)s->ng, (int)s->mg, 1.0, s->Bg, (int)s->mg, g, 1, 0.0, gc, 1);
}

void red_project_f(const RedSolver *s, const double *f, double *fc) {
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)s->nf, (int)s->mf, 1.0, s->Bf, (int)s->mf, f, 1, 0.0, fc, 1);
}

/* The Cholesky factor of V̂(ĝ) in s->Vf (lower, row-major), kept for the
 * next call at the same ĝ: the projection of one step and the advection of
 * the next are both at ĝ_{t+1}. 0, or -1 when V̂ is not positive definite. */
static int volume_factor(RedSolver *s, const double *gc) {
  if (s->vf_ok && !memcmp(s->Vfg, gc, (size_t)s->mg * sizeof *gc)) return 0;
  s->vf_ok = 0;
  const double *lo = volume_lower(s, gc);
  for (long i = 0; i < s->mu; i++) memcpy(s->Vf + i * s->mu, lo + i * (i + 1) / 2, (size_t)(i + 1) * sizeof *lo);
  /* the row-major lower triangle is the column-major upper one: LAPACK's
   * own layout, without LAPACKE's row-major transposes (and NaN checks) */
  if (LAPACKE_dpotrf_work(LAPACK_COL_MAJOR, 'U', (int)s->mu, s->Vf, (int)s->mu) != 0) return -1;
  memcpy(s->Vfg, gc, (size_t)s->mg * sizeof *gc);
  s->vf_ok = 1;
  return 0;
}

/* x <- V̂⁻¹ x with the factor in s->Vf */
static void volume_solve(const RedSolver *s, double *x) {
  cblas_dtrsv(CblasRowMajor, CblasLower, CblasNoTrans, CblasNonUnit, (int)s->mu, s->Vf, (int)s->mu, x, 1);
  cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, (int)s->mu, s->Vf, (int)s->mu, x, 1);
}

void red_project_u(RedSolver *s, const double *gc, const double *pv, double *uc) {
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)s->nu, (int)s->mu, 1.0, s->Bu, (int)s->mu, pv, 1, 0.0, uc, 1);
  if (volume_factor(s, gc) == 0) volume_solve(s, uc);
  else {
    red_volume(s, gc, s->V1);
    LAPACKE_dposv(LAPACK_ROW_MAJOR, 'L', (int)s->mu, 1, s->V1, (int)s->mu, uc, 1);
  }
}

int red_state_save(const RedSolver *s, RedState *st) {
  size_t g = (size_t)s->mg * sizeof *st->g, uu = (size_t)(s->mu * s->mu) * sizeof *st->Vf;
  if (!st->g) {
    st->g = malloc(g), st->Vfg = malloc(g);
    st->f = malloc((size_t)s->mf * sizeof *st->f), st->u = malloc((size_t)s->mu * sizeof *st->u);
    st->Vf = malloc(uu);
  }
  if (!st->g || !st->Vfg || !st->f || !st->u || !st->Vf) return -1;
  memcpy(st->g, s->g, g), memcpy(st->Vfg, s->Vfg, g), memcpy(st->Vf, s->Vf, uu);
  memcpy(st->f, s->f, (size_t)s->mf * sizeof *st->f), memcpy(st->u, s->u, (size_t)s->mu * sizeof *st->u);
  st->vf_ok = s->vf_ok;
  return 0;
}

void red_state_restore(RedSolver *s, const RedState *st) {
  size_t g = (size_t)s->mg * sizeof *st->g, uu = (size_t)(s->mu * s->mu) * sizeof *st->Vf;
  memcpy(s->g, st->g, g), memcpy(s->Vfg, st->Vfg, g), memcpy(s->Vf, st->Vf, uu);
  memcpy(s->f, st->f, (size_t)s->mf * sizeof *st->f), memcpy(s->u, st->u, (size_t)s->mu * sizeof *st->u);
  s->vf_ok = st->vf_ok;
}

void red_state_free(RedState *st) {
  free(st->g), free(st->f), free(st->u), free(st->Vf), free(st->Vfg);
  memset(st, 0, sizeof *st);
}

double red_energy(const RedSolver *s, const double *gc, const double *uc) {
  double *V = malloc((size_t)(s->mu * s->mu) * sizeof *V), *t = malloc((size_t)s->mu * sizeof *t);
  red_volume(s, gc, V);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)s->mu, (int)s->mu, 1.0, V, (int)s->mu, uc, 1, 0.0, t, 1);
  double e = 0.5 * cblas_ddot((int)s->mu, uc, 1, t, 1);
  free(V), free(t);
  return e;
}

/* out = P̂(ĝ) x = Σ_l ĝ_l P̂_l x: the slices, stacked, are one (m_g m_u) × m_f matrix read
 * once by one dgemv (into t, m_g m_u long), then combined; P̂ itself is never formed. */
static void pmat_apply(const RedSolver *s, const double *gc, const double *x, double *out, double *t) {
  int mu = (int)s->mu, mf = (int)s->mf;
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)s->mg * mu, mf, 1.0, s->Ps, mf, x, 1, 0.0, t, 1);
  memset(out, 0, (size_t)mu * sizeof *out);
  for (long l = 0; l < s->mg; l++)
    if (gc[l] != 0) cblas_daxpy(mu, gc[l], t + l * mu, 1, out, 1);
}

/* The reduced projection (Eq. 12 with the reduced boundary constraints) at
 * ĝ = gc of the velocity coordinates uin, with the boundary fluxes s->b:
 * sets s->f and s->u. On f̂ = f_p + N y (f_p = D̂⁺ b̂) the minimizer of
 * ½‖û' − V̂⁻¹P̂ f̂‖²_V̂ solves (NᵀP̂ᵀV̂⁻¹P̂N) y = (P̂N)ᵀ(û' − V̂⁻¹P̂ f_p); with V̂ = LLᵀ
 * and X = L⁻¹P̂N its matrix is XᵀX. Then û = V̂⁻¹P̂ f̂ (Eq. 13) = q + L⁻ᵀ X y with
 * q = V̂⁻¹P̂ f_p, both already at hand: one triangular solve, no product with P̂. */
int red_projection(RedSolver *s, const double *gc, const double *uin, char *err, size_t errlen) {
  int mu = (int)s->mu, mf = (int)s->mf, mb = (int)s->mb, nn = (int)s->nn;
  if (volume_factor(s, gc) != 0)
    return fail(err, errlen, "reduced volume matrix V̂(ĝ_{t+1}) is not positive definite", NULL);
  double *fp = s->work, *y = s->work + mf, *q = s->work + 2 * (mu + mf), *t = q + mu, *z = s->tmp3;
  if (mb > 0) { /* q = V̂⁻¹P̂ f_p, the velocity of the particular flux */
    cblas_dgemv(CblasRowMajor, CblasNoTrans, mf, mb, 1.0, s->Dpinv, mb, s->b, 1, 0.0, fp, 1);
    pmat_apply(s, gc, fp, q, t);
    volume_solve(s, q);
  } else {
    memset(fp, 0, (size_t)mf * sizeof *fp);
    memset(q, 0, (size_t)mu * sizeof *q);
  }
  memcpy(s->u, q, (size_t)mu * sizeof *q);
  if (nn > 0) {
    double *X = s->W; /* mu x nn */
    size_t un = (size_t)mu * (size_t)nn;
    memset(X, 0, un * sizeof *X);
    for (long l = 0; l < s->mg; l++)
      if (gc[l] != 0) cblas_daxpy((int)un, gc[l], s->PNs + (size_t)l * un, 1, X, 1);
    /* z = û' − q; the right-hand side (P̂N)ᵀ z before X overwrites P̂N */
    for (int i = 0; i < mu; i++) z[i] = uin[i] - q[i];
    cblas_dgemv(CblasRowMajor, CblasTrans, mu, nn, 1.0, X, nn, z, 1, 0.0, y, 1);
    cblas_dtrsm(CblasRowMajor, CblasLeft, CblasLower, CblasNoTrans, CblasNonUnit, mu, nn, 1.0, s->Vf, mu, X, nn);
    cblas_dsyrk(CblasRowMajor, CblasLower, CblasTrans, nn, mu, 1.0, X, nn, 0.0, s->Kn, nn);
    if (LAPACKE_dposv_work(LAPACK_COL_MAJOR, 'U', nn, 1, s->Kn, nn, y, nn) != 0) /* as in volume_factor */
      return fail(err, errlen, "reduced projection matrix is not positive definite", NULL);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, mf, nn, 1.0, s->N, nn, y, 1, 1.0, fp, 1);
    /* û = q + L⁻ᵀ (X y) */
    cblas_dgemv(CblasRowMajor, CblasNoTrans, mu, nn, 1.0, X, nn, y, 1, 0.0, z, 1);
    cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, mu, s->Vf, mu, z, 1);
    cblas_daxpy(mu, 1.0, z, 1, s->u, 1);
  }
  memcpy(s->f, fp, (size_t)mf * sizeof *s->f);
  return 0;
}

/* ---------------------------------------------------------------- the step */

static double slices_bytes(const RedSlices *sl) {
  return (double)(sl->n * sl->rank + sl->rank * sl->len) * sizeof(double);
}

static void bytes_add(RedBytes *b, const char *name, double bytes) {
  b->name[b->n] = name, b->bytes[b->n++] = bytes;
  b->total += bytes;
}

void red_step_bytes(const RedSolver *s, int moving, RedBytes *b) {
  double d = sizeof(double);
  long mu = s->mu, mf = s->mf, nk = mu * (mu - 1) / 2;
  memset(b, 0, sizeof *b);
  bytes_add(b, s->Ask32 ? "advection, skew parts (Ask, single precision)" : "advection, skew parts (Ask)",
            (double)(mf * nk) * (s->Ask32 ? sizeof(float) : d));
  bytes_add(b, "advection, symmetric parts (Asy slices)", slices_bytes(&s->Asy));
  bytes_add(b, "Laplacian (L)", (double)(mu * mu) * d);
  /* V̂'s factor: at ĝ_t kept from the last projection, at ĝ_{t+1} new: one V̂ a step */
  bytes_add(b, "volume (Vs slices)", slices_bytes(&s->Vs));
  bytes_add(b, "P̂ slices (Ps, PNs)", (double)(s->mg * mu * (mf + s->nn)) * d);
  bytes_add(b, "constraints (D̂⁺, N)", (double)(mf * (s->mb + s->nn)) * d);
  if (moving) bytes_add(b, "induced flux (Ahs slices, Bhs)", slices_bytes(&s->Ahs) + (double)(s->nmh * s->mgd * s->mb) * d);
}

int red_step(RedSolver *s, const double *gnext, const double *gdotc, char *err, size_t errlen) {
  int mu = (int)s->mu, mb = (int)s->mb;
  long mg = s->mg, mgd = s->mgd;
  double t0 = util_now();
  for (long l = 0; l < mg; l++) s->gmid[l] = 0.5 * (s->g[l] + gnext[l]);
  if (gdotc)
    memcpy(s->gdot, gdotc, (size_t)mgd * sizeof *s->gdot);
  else
    memset(s->gdot, 0, (size_t)mgd * sizeof *s->gdot);
  /* Â ⊗ (f̂ − ĥ): Σ_k f̂_k Â_k + Σ_aq w_a ĝdot_q (−Â_h ĥ)_aq, and D̂_h ĥ
   * likewise, with ĥ the flux of the step's linear motion: the monomials of
   * ĝ by Simpson's rule over it, (m(ĝ_t) + 4 m(ĝ_mid) + m(ĝ_{t+1})) / 6 —
   * exact for h's degree (paper §5.4; 2D: the midpoint) */
  size_t uu = (size_t)mu * mu;
  red_advection(s, s->f, s->A);
  long nmh = s->nmh;
  double *m0 = s->mvals + s->nmv, *m1 = m0 + nmh, *m2 = m1 + nmh;
  mono_values(nmh, s->mono_h, s->g, m0);
  mono_values(nmh, s->mono_h, s->gmid, m1);
  mono_values(nmh, s->mono_h, gnext, m2);
  int moving = 0;
  for (long a = 0; a < nmh; a++) {
    double ma = (m0[a] + 4 * m1[a] + m2[a]) / 6;
    for (long q = 0; q < mgd; q++) {
      double w = ma * s->gdot[q];
      s->wgt[a * mgd + q] = w;
      moving |= w != 0;
    }
  }
  if (moving) {
    slices_apply(&s->Ahs, s->wgt, 1.0, s->A);
    if (mb > 0)
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)(nmh * mgd), mb, 1.0, s->Bhs, mb, s->wgt, 1, 0.0, s->b, 1);
  } else if (mb > 0)
    memset(s->b, 0, (size_t)mb * sizeof *s->b);
  double t1 = util_now();
  /* advection and diffusion at ĝ_t: û' = exp(Δt V̂⁻¹(Â + μ L̂)) û */
  for (size_t i = 0; i < uu; i++) s->A[i] += s->visc * s->L[i];
  if (volume_factor(s, s->g) != 0)
    return fail(err, errlen, "reduced volume matrix V̂(ĝ_t) is not positive definite", NULL);
  double *u1 = s->tmp;
  int krylov = s->integ == RED_EXPMV ? red_expmv(s, s->A, s->Vf, s->dt, s->u, u1, 1e-12) : -1;
  s->last_krylov = krylov > 0 ? krylov : 0;
  if (krylov < 0) {
    /* M = V̂⁻¹(Â + μ L̂) from the factor */
    memcpy(s->M, s->A, uu * sizeof *s->M);
    cblas_dtrsm(CblasRowMajor, CblasLeft, CblasLower, CblasNoTrans, CblasNonUnit, mu, mu, 1.0, s->Vf, mu, s->M, mu);
    cblas_dtrsm(CblasRowMajor, CblasLeft, CblasLower, CblasTrans, CblasNonUnit, mu, mu, 1.0, s->Vf, mu, s->M, mu);
  }
  if (krylov >= 0) {
    s->last_pade = 0, s->last_squarings = 0;
  } else if (s->integ != RED_RK4) { /* the whole exponential (RED_EXPM, or Arnoldi did not converge) */
    for (size_t i = 0; i < uu; i++) s->M[i] *= s->dt;
    if (red_expm(mu, s->M, s->E, s->work, &s->last_pade, &s->last_squarings) != 0)
      return fail(err, errlen, "matrix exponential: singular Padé denominator", NULL);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, mu, mu, 1.0, s->E, mu, s->u, 1, 0.0, u1, 1);
  } else {
    /* RK4 with the same operator (for comparison with the full step's integrator) */
    double *k = s->tmp2, *y = s->work, *acc = s->work + mu;
    memcpy(u1, s->u, (size_t)mu * sizeof *u1);
    memcpy(acc, s->u, (size_t)mu * sizeof *acc);
    const double c[4] = {0.5, 0.5, 1.0, 0}, w[4] = {1.0 / 6, 1.0 / 3, 1.0 / 3, 1.0 / 6};
    memcpy(y, s->u, (size_t)mu * sizeof *y);
    for (int st = 0; st < 4; st++) {
      cblas_dgemv(CblasRowMajor, CblasNoTrans, mu, mu, 1.0, s->M, mu, y, 1, 0.0, k, 1);
      for (int i = 0; i < mu; i++) acc[i] += s->dt * w[st] * k[i];
      if (st < 3)
        for (int i = 0; i < mu; i++) y[i] = s->u[i] + c[st] * s->dt * k[i];
    }
    memcpy(u1, acc, (size_t)mu * sizeof *u1);
  }
  double t2 = util_now();
  if (red_projection(s, gnext, u1, err, errlen) != 0) return -1;
  memcpy(s->g, gnext, (size_t)s->mg * sizeof *s->g);
  double t3 = util_now();
  s->seconds_eval += t1 - t0;
  s->seconds_advection += t2 - t1;
  s->seconds_projection += t3 - t2;
  s->steps++;
  return 0;
}
