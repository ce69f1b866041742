/* projection.c — the constrained pressure projection by UMFPACK on the KKT
 * system, or by CHOLMOD and augmented Lagrangian iterations (see
 * projection.h). */
#include "util.h"
#include "projection.h"

#include "stream.h"

#include <math.h>
#include <stdbool.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/cholmod.h>
#include <suitesparse/umfpack.h>
#include <time.h>

/* w = AL_WEIGHT times K's largest diagonal entry: large enough that a few
 * iterations converge, small enough that K + w D^T D keeps K's digits */
#define AL_WEIGHT 1e8
#define AL_MAXIT 50

struct AugLagrangian {
  cholmod_common cc;
  cholmod_triplet *T;  /* upper triangle of K + w D^T D, fixed order */
  cholmod_factor *L;   /* analysed once, factored per geometry */
  cholmod_dense *b;
  double *lambda, *res; /* [C - 1] multipliers, constraint residual */
};

/* Triplets in a fixed order: for every cell, its nk x nk block of K
 * (interior faces only), then (but the last cell) its divergence row and
 * column. */
static void triplets(Projection *pr, bool values) {
  const Ops *o = pr->o;
  const Mesh *m = o->m;
  int dim = m->dim, nk = m->nk, t = 0;
  for (int c = 0; c < m->nc; c++) {
    const double *P = o->P.val + dim * nk * c; /* rows dim c + d; columns the faces k */
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk < 0) continue;
      for (int l = 0; l < nk; l++) {
        int fl = pr->fidx[m->cface[nk * c + l]];
        if (fl < 0) continue;
        if (values) {
          double s = 0;
          for (int d = 0; d < dim; d++) s += P[nk * d + k] * P[nk * d + l];
          pr->tx[t] = s / o->area[c];
        } else {
          pr->ti[t] = fk, pr->tj[t] = fl;
        }
        t++;
      }
    }
    if (c == m->nc - 1) continue;
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk < 0) continue;
      if (values) pr->tx[t] = pr->tx[t + 1] = m->csign[nk * c + k];
      else pr->ti[t] = pr->ni + c, pr->tj[t] = fk, pr->ti[t + 1] = fk, pr->tj[t + 1] = pr->ni + c;
      t += 2;
    }
  }
  pr->nt = t;
}

const char *projection_method_name(ProjectionMethod method) {
  return method == PROJ_STREAM_CHOLMOD ? "stream-cholmod" : method == PROJ_AL_CHOLMOD ? "al-cholmod" : "kkt-umfpack";
}

/* K + w D^T D's upper triangle into al->T, cell by cell (the last cell has
 * no constraint row); w = AL_WEIGHT times K's largest diagonal entry, or
 * the pattern alone when `values` is false. Returns w. */
static double al_assemble(Projection *pr, bool values) {
  const Ops *o = pr->o;
  const Mesh *m = o->m;
  int dim = m->dim, nk = m->nk;
  double w = 0;
  for (int c = 0; values && c < m->nc; c++)
    for (int k = 0; k < nk; k++) {
      const double *P = o->P.val + dim * nk * c;
      double s = 0;
      for (int d = 0; d < dim; d++) s += P[nk * d + k] * P[nk * d + k];
      w = fmax(w, s / o->area[c]);
    }
  w *= AL_WEIGHT;
  cholmod_triplet *T = pr->al->T;
  int *ti = T->i, *tj = T->j;
  double *tx = T->x;
  size_t n = 0;
  for (int c = 0; c < m->nc; c++) {
    const double *P = o->P.val + dim * nk * c;
    double wc = c < m->nc - 1 ? w : 0;
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk < 0) continue;
      for (int l = 0; l < nk; l++) {
        int fl = pr->fidx[m->cface[nk * c + l]];
        if (fl < fk) continue;
        ti[n] = fk, tj[n] = fl;
        double s = 0;
        for (int d = 0; d < dim; d++) s += P[nk * d + k] * P[nk * d + l];
        tx[n++] = values ? s / o->area[c] + wc * m->csign[nk * c + k] * m->csign[nk * c + l] : 1;
      }
    }
  }
  T->nnz = n;
  return w;
}

static int al_init(Projection *pr, char *err, size_t errlen) {
  const Mesh *m = pr->o->m;
  AugLagrangian *al = pr->al = calloc(1, sizeof *al);
  cholmod_start(&al->cc);
  al->cc.print = 0;
  al->T = cholmod_allocate_triplet(pr->ni, pr->ni, (size_t)m->nk * (m->nk + 1) / 2 * m->nc, 1, CHOLMOD_REAL, &al->cc);
  al->b = cholmod_zeros(pr->ni, 1, CHOLMOD_REAL, &al->cc);
  al->lambda = malloc(m->nc * sizeof *al->lambda);
  al->res = malloc(m->nc * sizeof *al->res);
  if (!al->T || !al->b) return util_fail(err, errlen, "projection: CHOLMOD allocation failed (status %d)", al->cc.status);
  al_assemble(pr, false);
  cholmod_sparse *A = cholmod_triplet_to_sparse(al->T, al->T->nnz, &al->cc);
  al->L = A ? cholmod_analyze(A, &al->cc) : NULL;
  cholmod_free_sparse(&A, &al->cc);
  if (!al->L) return util_fail(err, errlen, "projection: CHOLMOD analysis failed (status %d)", al->cc.status);
  return 0;
}

static void al_free(AugLagrangian *al) {
  if (!al) return;
  cholmod_free_factor(&al->L, &al->cc);
  cholmod_free_triplet(&al->T, &al->cc);
  cholmod_free_dense(&al->b, &al->cc);
  cholmod_finish(&al->cc);
  free(al->lambda);
  free(al->res);
  free(al);
}

int projection_init(Projection *pr, const Ops *o, ProjectionMethod method, char *err, size_t errlen) {
  memset(pr, 0, sizeof *pr);
  const Mesh *m = o->m;
  pr->o = o;
  pr->method = method;
  if (method == PROJ_STREAM_CHOLMOD) return stream_init(&pr->stream, o, err, errlen);
  pr->fidx = malloc(m->nf * sizeof *pr->fidx);
  for (int j = 0; j < m->nf; j++) pr->fidx[j] = m->fkind[j] == BF_INTERIOR ? pr->ni++ : -1;
  pr->n = pr->ni + m->nc - 1;
  pr->rhs = malloc(pr->n * sizeof *pr->rhs);
  pr->x = malloc(pr->n * sizeof *pr->x);
  pr->work_f = malloc(m->nf * sizeof *pr->work_f);
  pr->work_f2 = malloc(m->nf * sizeof *pr->work_f2);
  pr->work_u = malloc(m->dim * m->nc * sizeof *pr->work_u);
  if (method == PROJ_AL_CHOLMOD) return al_init(pr, err, errlen);
  int cap = (m->nk * m->nk + 2 * m->nk) * m->nc;
  pr->ti = malloc(cap * sizeof *pr->ti);
  pr->tj = malloc(cap * sizeof *pr->tj);
  pr->tx = calloc(cap, sizeof *pr->tx);
  pr->map = malloc(cap * sizeof *pr->map);
  triplets(pr, false);
  for (int t = 0; t < pr->nt; t++) pr->tx[t] = 1; /* the pattern only */
  pr->Ap = malloc((pr->n + 1) * sizeof *pr->Ap);
  pr->Ai = malloc(pr->nt * sizeof *pr->Ai);
  pr->Ax = malloc(pr->nt * sizeof *pr->Ax);
  int st = umfpack_di_triplet_to_col(pr->n, pr->n, pr->nt, pr->ti, pr->tj, pr->tx, pr->Ap, pr->Ai, pr->Ax, pr->map);
  if (st != UMFPACK_OK) return util_fail(err, errlen, "projection: UMFPACK triplet_to_col failed (status %d)", st);
  /* UMFPACK's default (automatic) strategy: measured faster here than the
   * symmetric one on this KKT matrix (README) */
  umfpack_di_defaults(pr->control);
  st = umfpack_di_symbolic(pr->n, pr->n, pr->Ap, pr->Ai, pr->Ax, &pr->symbolic, pr->control, NULL);
  if (st != UMFPACK_OK) return util_fail(err, errlen, "projection: UMFPACK symbolic analysis failed (status %d)", st);
  return 0;
}

void projection_free(Projection *pr) {
  stream_free(pr->stream);
  al_free(pr->al);
  if (pr->numeric) umfpack_di_free_numeric(&pr->numeric);
  if (pr->symbolic) umfpack_di_free_symbolic(&pr->symbolic);
  free(pr->fidx);
  free(pr->ti);
  free(pr->tj);
  free(pr->tx);
  free(pr->map);
  free(pr->Ap);
  free(pr->Ai);
  free(pr->Ax);
  free(pr->rhs);
  free(pr->x);
  free(pr->work_f);
  free(pr->work_f2);
  free(pr->work_u);
  memset(pr, 0, sizeof *pr);
}

/* The KKT right-hand side into pr->rhs: P^T u - K_ib h_b on the interior
 * faces, then -G_b h_b per cell but the last; the boundary fluxes into
 * pr->work_f (zero on the interior faces). */
static void kkt_rhs(Projection *pr, const double *u_in, const double *h) {
  const Ops *o = pr->o;
  const Mesh *m = o->m;
  double *fb = pr->work_f, *r = pr->work_f2, *w = pr->work_u;
  for (int j = 0; j < m->nf; j++) fb[j] = (pr->fidx[j] < 0 && h) ? h[j] : 0;
  /* r = P^T u - P^T V^-1 P fb */
  int dim = m->dim, nk = m->nk;
  csr_mv(&o->P, fb, w);
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < dim; d++) w[dim * c + d] = u_in[dim * c + d] - w[dim * c + d] / o->area[c];
  csr_mtv(&o->P, w, r);
  for (int j = 0; j < m->nf; j++)
    if (pr->fidx[j] >= 0) pr->rhs[pr->fidx[j]] = r[j];
  for (int c = 0; c < m->nc - 1; c++) {
    double s = 0;
    for (int k = 0; k < nk; k++) s += m->csign[nk * c + k] * fb[m->cface[nk * c + k]];
    pr->rhs[pr->ni + c] = -s;
  }
}

/* The augmented Lagrangian iterations (projection.h) with the factor of
 * K + w D^T D, in residual form (the right-hand side of each solve is the
 * exact KKT system's residual, so rounding in the factor is refined away);
 * the interior fluxes into pr->x. */
static int al_solve(Projection *pr, double w, char *err, size_t errlen) {
  const Ops *o = pr->o;
  const Mesh *m = o->m;
  AugLagrangian *al = pr->al;
  int dim = m->dim, nk = m->nk, ni = pr->ni, nc1 = m->nc - 1;
  const double *r = pr->rhs, *bc = pr->rhs + ni;
  double *x = pr->x, *lam = al->lambda, *b = al->b->x, *ff = pr->work_f2, *uu = pr->work_u, *res = al->res;
  memset(lam, 0, nc1 * sizeof *lam);
  memset(x, 0, ni * sizeof *x);
  memcpy(res, bc, nc1 * sizeof *res);
  double hmax = 0, prev = INFINITY;
  for (int j = 0; j < m->nf; j++) hmax = fmax(hmax, fabs(pr->work_f[j]));
  for (pr->iterations = 1;; pr->iterations++) {
    /* b = r - K x - D^T lam + w D^T (bc - D x), with res = bc - D x */
    for (int j = 0; j < m->nf; j++) ff[j] = pr->fidx[j] >= 0 ? x[pr->fidx[j]] : 0;
    csr_mv(&o->P, ff, uu);
    for (int c = 0; c < m->nc; c++)
      for (int d = 0; d < dim; d++) uu[dim * c + d] /= o->area[c];
    csr_mtv(&o->P, uu, ff);
    for (int j = 0; j < m->nf; j++)
      if (pr->fidx[j] >= 0) b[pr->fidx[j]] = r[pr->fidx[j]] - ff[j];
    for (int c = 0; c < nc1; c++)
      for (int k = 0; k < nk; k++) {
        int fk = pr->fidx[m->cface[nk * c + k]];
        if (fk >= 0) b[fk] += m->csign[nk * c + k] * (w * res[c] - lam[c]);
      }
    cholmod_dense *sol = cholmod_solve(CHOLMOD_A, al->L, al->b, &al->cc);
    if (!sol) return util_fail(err, errlen, "projection: CHOLMOD solve failed (status %d)", al->cc.status);
    const double *dx = sol->x;
    double dmax = 0, fmx = hmax;
    for (int i = 0; i < ni; i++) x[i] += dx[i], dmax = fmax(dmax, fabs(dx[i])), fmx = fmax(fmx, fabs(x[i]));
    cholmod_free_dense(&sol, &al->cc);
    /* res = bc - D x; lam -= w res */
    double rmax = 0;
    for (int c = 0; c < nc1; c++) {
      double s = bc[c];
      for (int k = 0; k < nk; k++) {
        int fk = pr->fidx[m->cface[nk * c + k]];
        if (fk >= 0) s -= m->csign[nk * c + k] * x[fk];
      }
      res[c] = s;
      lam[c] -= w * s;
      rmax = fmax(rmax, fabs(s));
    }
    /* to rounding, or until the corrections stop falling */
    double size = fmax(dmax, rmax);
    if (size <= 1e-15 * fmx) break;
    if (size >= 0.5 * prev && size <= 1e-10 * fmx) break; /* at rounding, stagnating */
    if (pr->iterations == AL_MAXIT || size >= 0.5 * prev)
      return util_fail(err, errlen, "projection: augmented Lagrangian iterations did not converge "
                                    "(correction %.3g of the largest flux after %d)", size / fmx, pr->iterations);
    prev = size;
  }
  return 0;
}

int projection_solve(Projection *pr, const double *u_in, const double *h, double *f, double *u_out, char *err,
                     size_t errlen) {
  if (pr->stream)
    return stream_solve(pr->stream, u_in, h, f, u_out, &pr->seconds_numeric, &pr->seconds_solve, err, errlen);
  const Ops *o = pr->o;
  const Mesh *m = o->m;
  double t0 = util_now(), w = 0;
  if (pr->al) {
    AugLagrangian *al = pr->al;
    w = al_assemble(pr, true);
    cholmod_sparse *A = cholmod_triplet_to_sparse(al->T, al->T->nnz, &al->cc);
    int ok = A && cholmod_factorize(A, al->L, &al->cc) && al->cc.status == CHOLMOD_OK;
    cholmod_free_sparse(&A, &al->cc);
    if (!ok)
      return util_fail(err, errlen, "projection: K + w D^T D is not positive definite (CHOLMOD status %d)",
                       al->cc.status);
  } else {
    triplets(pr, true);
    memset(pr->Ax, 0, pr->nt * sizeof *pr->Ax);
    for (int t = 0; t < pr->nt; t++) pr->Ax[pr->map[t]] += pr->tx[t];
    if (pr->numeric) umfpack_di_free_numeric(&pr->numeric);
    int st = umfpack_di_numeric(pr->Ap, pr->Ai, pr->Ax, pr->symbolic, &pr->numeric, pr->control, NULL);
    if (st != UMFPACK_OK)
      return util_fail(err, errlen, "projection: UMFPACK numeric factorization failed (status %d%s)", st,
                       st == UMFPACK_WARNING_singular_matrix ? ": singular KKT matrix" : "");
  }
  double t1 = util_now();
  kkt_rhs(pr, u_in, h);
  if (pr->al) {
    if (al_solve(pr, w, err, errlen) != 0) return -1;
  } else {
    int st = umfpack_di_solve(UMFPACK_A, pr->Ap, pr->Ai, pr->Ax, pr->x, pr->rhs, pr->numeric, pr->control, NULL);
    if (st != UMFPACK_OK) return util_fail(err, errlen, "projection: UMFPACK solve failed (status %d)", st);
  }
  const double *fb = pr->work_f;
  for (int j = 0; j < m->nf; j++) f[j] = pr->fidx[j] >= 0 ? pr->x[pr->fidx[j]] : fb[j];
  ops_velocity_from_flux(o, f, u_out);
  double t2 = util_now();
  pr->seconds_numeric += t1 - t0;
  pr->seconds_solve += t2 - t1;
  return 0;
}

double projection_max_divergence(const Ops *o, const double *f) {
  const Mesh *m = o->m;
  int nk = m->nk;
  double worst = 0;
  for (int c = 0; c < m->nc; c++) {
    double s = 0;
    for (int k = 0; k < nk; k++) s += m->csign[nk * c + k] * f[m->cface[nk * c + k]];
    if (fabs(s) > worst) worst = fabs(s);
  }
  return worst;
}
