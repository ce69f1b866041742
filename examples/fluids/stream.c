/* stream.c — the projection on the divergence-free null space: a stream
 * function solved by CHOLMOD (see stream.h). */
#include "util.h"
#include "stream.h"
#include "npg.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/cholmod.h>
#include <time.h>

struct StreamProjection {
  const Ops *o;
  cholmod_common cc;
  int ndof;          /* stream function unknowns */
  int *dof;          /* [V] unknown of a vertex, -1 pinned (bottom wall) */
  cholmod_factor *Lphi; /* graph Laplacian of the cells, last cell pinned: factored once */
  cholmod_factor *Lpsi; /* C^T K C: analysed once, factored per geometry */
  cholmod_triplet *T;   /* C^T K C's upper triangle, fixed order */
  cholmod_dense *bphi, *bpsi;
  double *fp;        /* [F] particular solution */
};

int stream_number_dofs(const FluidMesh *m, int *dof) {
  int *comp = malloc(m->nv * sizeof *comp);
  for (int v = 0; v < m->nv; v++) comp[v] = -1;
  for (int b = 0; b < m->nb; b++) {
    int j = m->bface[b];
    for (int e = 0; e < 2; e++) {
      int v = m->vmaster[m->face[2 * j + e]];
      comp[v] = m->fkind[j] == BF_OBSTACLE ? 2 : m->g0[2 * v + 1] < m->spec.H / 2 ? 0 : 1;
    }
  }
  int top = -1, obstacle = -1, ndof = 0;
  for (int v = 0; v < m->nv; v++) {
    if (m->vmaster[v] != v) continue;
    if (comp[v] == 0) dof[v] = -1;
    else if (comp[v] == 1) dof[v] = top >= 0 ? top : (top = ndof++);
    else if (comp[v] == 2) dof[v] = obstacle >= 0 ? obstacle : (obstacle = ndof++);
    else dof[v] = ndof++;
  }
  for (int v = 0; v < m->nv; v++) dof[v] = dof[m->vmaster[v]];
  free(comp);
  return ndof;
}

/* Column q of Q is a_{q+1} - a_{q+2} with a_k = (centroid - g_k)/2 (stream.h). */
void stream_cell_curl(const FluidMesh *m, const double *g, int c, double Q[2][3], double a[3][2]) {
  const int *t = m->cell + 3 * c;
  double cen[2];
  for (int d = 0; d < 2; d++) cen[d] = (g[2 * t[0] + d] + g[2 * t[1] + d] + g[2 * t[2] + d]) / 3;
  for (int k = 0; k < 3; k++)
    for (int d = 0; d < 2; d++) a[k][d] = (cen[d] - g[2 * t[k] + d]) / 2;
  for (int q = 0; q < 3; q++)
    for (int d = 0; d < 2; d++) Q[d][q] = a[(q + 1) % 3][d] - a[(q + 2) % 3][d];
}

/* Fill s->T with C^T K C at the geometry of s->o (fixed entry order). */
static void assemble(StreamProjection *s) {
  const Ops *o = s->o;
  const FluidMesh *m = o->m;
  cholmod_triplet *T = s->T;
  int *ti = T->i, *tj = T->j;
  double *tx = T->x;
  size_t n = 0;
  for (int c = 0; c < m->nc; c++) {
    double Q[2][3], a[3][2];
    stream_cell_curl(m, o->g, c, Q, a);
    for (int p = 0; p < 3; p++) {
      int dp = s->dof[m->cell[3 * c + p]];
      if (dp < 0) continue;
      for (int q = 0; q < 3; q++) {
        int dq = s->dof[m->cell[3 * c + q]];
        if (dq < 0 || dq < dp) continue;
        ti[n] = dp, tj[n] = dq;
        tx[n++] = (Q[0][p] * Q[0][q] + Q[1][p] * Q[1][q]) / o->area[c]; /* (p,q) and (q,p) both land here when dp == dq */
      }
    }
  }
  T->nnz = n;
}

int stream_init(StreamProjection **out, const Ops *o, char *err, size_t errlen) {
  const FluidMesh *m = o->m;
  *out = NULL;
  StreamProjection *s = calloc(1, sizeof *s);
  s->o = o;
  cholmod_start(&s->cc);
  s->cc.print = 0;
  s->dof = malloc(m->nv * sizeof *s->dof);
  s->fp = calloc(m->nf, sizeof *s->fp);
  s->ndof = stream_number_dofs(m, s->dof);
  /* the cells' graph Laplacian G_i G_i^T over interior faces, last cell pinned */
  int nphi = m->nc - 1;
  cholmod_triplet *T = cholmod_allocate_triplet(nphi, nphi, 3 * (size_t)m->nf, 1, CHOLMOD_REAL, &s->cc);
  int *ti = T->i, *tj = T->j;
  double *tx = T->x;
  size_t n = 0;
  for (int j = 0; j < m->nf; j++) {
    if (m->fkind[j] != BF_INTERIOR) continue;
    int c0 = m->fcell[2 * j], c1 = m->fcell[2 * j + 1];
    if (c0 < nphi) ti[n] = tj[n] = c0, tx[n++] = 1;
    if (c1 < nphi) ti[n] = tj[n] = c1, tx[n++] = 1;
    if (c0 < nphi && c1 < nphi) ti[n] = c0 < c1 ? c0 : c1, tj[n] = c0 < c1 ? c1 : c0, tx[n++] = -1;
  }
  T->nnz = n;
  cholmod_sparse *A = cholmod_triplet_to_sparse(T, n, &s->cc);
  cholmod_free_triplet(&T, &s->cc);
  s->Lphi = A ? cholmod_analyze(A, &s->cc) : NULL;
  int ok = s->Lphi && cholmod_factorize(A, s->Lphi, &s->cc) && s->cc.status == CHOLMOD_OK;
  cholmod_free_sparse(&A, &s->cc);
  if (!ok) {
    stream_free(s);
    return npg_error_set(err, errlen,
                         "projection: the cells' graph Laplacian is not positive definite (is the mesh connected?)");
  }
  s->bphi = cholmod_zeros(nphi, 1, CHOLMOD_REAL, &s->cc);
  s->bpsi = cholmod_zeros(s->ndof, 1, CHOLMOD_REAL, &s->cc);
  /* C^T K C: pattern from the rest geometry, analysed once */
  s->T = cholmod_allocate_triplet(s->ndof, s->ndof, 9 * (size_t)m->nc, 1, CHOLMOD_REAL, &s->cc);
  assemble(s);
  A = cholmod_triplet_to_sparse(s->T, s->T->nnz, &s->cc);
  s->Lpsi = A ? cholmod_analyze(A, &s->cc) : NULL;
  cholmod_free_sparse(&A, &s->cc);
  if (!s->Lpsi) {
    stream_free(s);
    return npg_error_set(err, errlen, "projection: CHOLMOD could not analyse the stream function system");
  }
  *out = s;
  return 0;
}

void stream_free(StreamProjection *s) {
  if (!s) return;
  cholmod_free_factor(&s->Lphi, &s->cc);
  cholmod_free_factor(&s->Lpsi, &s->cc);
  cholmod_free_triplet(&s->T, &s->cc);
  cholmod_free_dense(&s->bphi, &s->cc);
  cholmod_free_dense(&s->bpsi, &s->cc);
  cholmod_finish(&s->cc);
  free(s->dof);
  free(s->fp);
  free(s);
}

int stream_solve(StreamProjection *s, const double *u_in, const double *h, double *f, double *u_out,
                 double *t_factor, double *t_solve, char *err, size_t errlen) {
  const Ops *o = s->o;
  const FluidMesh *m = o->m;
  double t0 = util_now();
  assemble(s);
  cholmod_sparse *A = cholmod_triplet_to_sparse(s->T, s->T->nnz, &s->cc);
  int ok = A && cholmod_factorize(A, s->Lpsi, &s->cc) && s->cc.status == CHOLMOD_OK;
  cholmod_free_sparse(&A, &s->cc);
  if (!ok)
    return npg_error_set(err, errlen,
                         "projection: C^T K C is not positive definite (CHOLMOD status %d): a degenerate cell?",
                         s->cc.status);
  double t1 = util_now();
  /* particular solution: f_p = f_b + G_i^T phi, G_i G_i^T phi = -G f_b */
  double *fp = s->fp, *bphi = s->bphi->x;
  for (int j = 0; j < m->nf; j++) fp[j] = (m->fkind[j] != BF_INTERIOR && h) ? h[j] : 0;
  for (int c = 0; c < m->nc - 1; c++) {
    double d = 0;
    for (int k = 0; k < 3; k++) d += m->csign[3 * c + k] * fp[m->cface[3 * c + k]];
    bphi[c] = -d;
  }
  cholmod_dense *phi = cholmod_solve(CHOLMOD_A, s->Lphi, s->bphi, &s->cc);
  if (!phi) return npg_error_set(err, errlen, "projection: CHOLMOD solve failed (status %d)", s->cc.status);
  const double *ph = phi->x;
  for (int j = 0; j < m->nf; j++) {
    if (m->fkind[j] != BF_INTERIOR) continue;
    int c0 = m->fcell[2 * j], c1 = m->fcell[2 * j + 1];
    fp[j] = (c0 < m->nc - 1 ? ph[c0] : 0) - (c1 < m->nc - 1 ? ph[c1] : 0);
  }
  cholmod_free_dense(&phi, &s->cc);
  /* right-hand side C^T (P^T u - K f_p), cell by cell */
  double *b = s->bpsi->x;
  memset(b, 0, s->ndof * sizeof *b);
  for (int c = 0; c < m->nc; c++) {
    double Q[2][3], a[3][2], r[2] = {u_in[2 * c], u_in[2 * c + 1]};
    stream_cell_curl(m, o->g, c, Q, a);
    for (int k = 0; k < 3; k++) {
      double out = m->csign[3 * c + k] * fp[m->cface[3 * c + k]];
      r[0] -= out * a[k][0] / o->area[c];
      r[1] -= out * a[k][1] / o->area[c];
    }
    for (int q = 0; q < 3; q++) {
      int d = s->dof[m->cell[3 * c + q]];
      if (d >= 0) b[d] += Q[0][q] * r[0] + Q[1][q] * r[1];
    }
  }
  cholmod_dense *psi = cholmod_solve(CHOLMOD_A, s->Lpsi, s->bpsi, &s->cc);
  if (!psi) return npg_error_set(err, errlen, "projection: CHOLMOD solve failed (status %d)", s->cc.status);
  const double *p = psi->x;
  for (int j = 0; j < m->nf; j++) {
    int da = s->dof[m->face[2 * j]], db = s->dof[m->face[2 * j + 1]];
    f[j] = fp[j] + (m->fkind[j] == BF_INTERIOR ? (db >= 0 ? p[db] : 0) - (da >= 0 ? p[da] : 0) : 0);
  }
  cholmod_free_dense(&psi, &s->cc);
  ops_velocity_from_flux(o, f, u_out);
  double t2 = util_now();
  *t_factor += t1 - t0;
  *t_solve += t2 - t1;
  return 0;
}
