/* projection.c — the constrained pressure projection by UMFPACK on the KKT
 * system (see projection.h). */
#include "util.h"
#include "projection.h"

#include "stream.h"

#include <math.h>
#include <stdbool.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>
#include <time.h>

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
  return method == PROJ_STREAM_CHOLMOD ? "stream-cholmod" : "kkt-umfpack";
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
  pr->rhs = malloc(pr->n * sizeof *pr->rhs);
  pr->x = malloc(pr->n * sizeof *pr->x);
  pr->work_f = malloc(m->nf * sizeof *pr->work_f);
  pr->work_f2 = malloc(m->nf * sizeof *pr->work_f2);
  pr->work_u = malloc(m->dim * m->nc * sizeof *pr->work_u);
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

int projection_solve(Projection *pr, const double *u_in, const double *h, double *f, double *u_out, char *err,
                     size_t errlen) {
  if (pr->stream)
    return stream_solve(pr->stream, u_in, h, f, u_out, &pr->seconds_numeric, &pr->seconds_solve, err, errlen);
  const Ops *o = pr->o;
  const Mesh *m = o->m;
  double t0 = util_now();
  triplets(pr, true);
  memset(pr->Ax, 0, pr->nt * sizeof *pr->Ax);
  for (int t = 0; t < pr->nt; t++) pr->Ax[pr->map[t]] += pr->tx[t];
  if (pr->numeric) umfpack_di_free_numeric(&pr->numeric);
  int st = umfpack_di_numeric(pr->Ap, pr->Ai, pr->Ax, pr->symbolic, &pr->numeric, pr->control, NULL);
  if (st != UMFPACK_OK)
    return util_fail(err, errlen, "projection: UMFPACK numeric factorization failed (status %d%s)", st,
                st == UMFPACK_WARNING_singular_matrix ? ": singular KKT matrix" : "");
  double t1 = util_now();
  /* fb: the boundary fluxes (D f = D h), zero elsewhere */
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
  st = umfpack_di_solve(UMFPACK_A, pr->Ap, pr->Ai, pr->Ax, pr->x, pr->rhs, pr->numeric, pr->control, NULL);
  if (st != UMFPACK_OK) return util_fail(err, errlen, "projection: UMFPACK solve failed (status %d)", st);
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
