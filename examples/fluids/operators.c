/* operators.c — the fluid operators of fluids2d.npg as sparse matrices
 * (see operators.h). */
#include "operators.h"

#include <stdlib.h>
#include <string.h>

void csr_mv(const Csr *M, const double *x, double *y) {
  for (int i = 0; i < M->nrow; i++) {
    double s = 0;
    for (int p = M->rowptr[i]; p < M->rowptr[i + 1]; p++) s += M->val[p] * x[M->col[p]];
    y[i] = s;
  }
}

void csr_mvd(const Csr *M, int dim, const double *x, double *y) {
  if (dim == 2) {
    csr_mv2(M, x, y);
    return;
  }
  for (int i = 0; i < M->nrow; i++) {
    double s[3] = {0, 0, 0};
    for (int p = M->rowptr[i]; p < M->rowptr[i + 1]; p++)
      for (int d = 0; d < dim; d++) s[d] += M->val[p] * x[dim * M->col[p] + d];
    for (int d = 0; d < dim; d++) y[dim * i + d] = s[d];
  }
}

void csr_mv2(const Csr *M, const double *x, double *y) {
  for (int i = 0; i < M->nrow; i++) {
    double s0 = 0, s1 = 0;
    for (int p = M->rowptr[i]; p < M->rowptr[i + 1]; p++) {
      const double *xj = x + 2 * M->col[p];
      s0 += M->val[p] * xj[0];
      s1 += M->val[p] * xj[1];
    }
    y[2 * i] = s0;
    y[2 * i + 1] = s1;
  }
}

void csr_mtv(const Csr *M, const double *x, double *y) {
  memset(y, 0, M->ncol * sizeof *y);
  for (int i = 0; i < M->nrow; i++)
    for (int p = M->rowptr[i]; p < M->rowptr[i + 1]; p++) y[M->col[p]] += M->val[p] * x[i];
}

void csr_free(Csr *M) {
  free(M->rowptr);
  free(M->col);
  free(M->val);
  memset(M, 0, sizeof *M);
}

static void csr_alloc(Csr *M, int nrow, int ncol, int nnz) {
  M->nrow = nrow;
  M->ncol = ncol;
  M->rowptr = calloc(nrow + 1, sizeof *M->rowptr);
  M->col = malloc((nnz ? nnz : 1) * sizeof *M->col);
  M->val = calloc(nnz ? nnz : 1, sizeof *M->val);
}

/* A cell's row over itself and its neighbours: the pattern of A and lap.
 * Entry 0 of row i is the diagonal, then one per face k with a neighbour. */
static void cell_pattern(const FluidMesh *m, Csr *M) {
  int nk = m->nk, nnz = m->nc;
  for (int i = 0; i < nk * m->nc; i++) nnz += m->nbr[i] >= 0;
  csr_alloc(M, m->nc, m->nc, nnz);
  int p = 0;
  for (int i = 0; i < m->nc; i++) {
    M->rowptr[i] = p;
    M->col[p++] = i;
    for (int k = 0; k < nk; k++)
      if (m->nbr[nk * i + k] >= 0) M->col[p++] = m->nbr[nk * i + k];
  }
  M->rowptr[m->nc] = p;
}

void ops_init(Ops *o, const FluidMesh *m) {
  memset(o, 0, sizeof *o);
  o->m = m;
  int dim = m->dim, nk = m->nk;
  o->area = calloc(m->nc, sizeof *o->area);
  /* P: row dim c + d over the nk faces of c */
  csr_alloc(&o->P, dim * m->nc, m->nf, dim * nk * m->nc);
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < dim; d++) {
      int r = dim * c + d;
      o->P.rowptr[r] = nk * r;
      for (int k = 0; k < nk; k++) o->P.col[nk * r + k] = m->cface[nk * c + k];
    }
  o->P.rowptr[dim * m->nc] = dim * nk * m->nc;
  cell_pattern(m, &o->A);
  /* lap (paper §5.2): -|N_i| u_i + sum of the neighbours */
  cell_pattern(m, &o->lap);
  for (int i = 0; i < m->nc; i++) {
    int p = o->lap.rowptr[i];
    o->lap.val[p] = -(o->lap.rowptr[i + 1] - p - 1);
    for (int q = p + 1; q < o->lap.rowptr[i + 1]; q++) o->lap.val[q] = 1;
  }
  /* D: one row per boundary face */
  csr_alloc(&o->D, m->nb, m->nf, m->nb);
  for (int b = 0; b < m->nb; b++) {
    o->D.rowptr[b] = b;
    o->D.col[b] = m->bface[b];
    o->D.val[b] = 1;
  }
  o->D.rowptr[m->nb] = m->nb;
  /* div: outward flux summed over the cell's faces */
  csr_alloc(&o->div, m->nc, m->nf, nk * m->nc);
  for (int c = 0; c < m->nc; c++) {
    o->div.rowptr[c] = nk * c;
    for (int k = 0; k < nk; k++) {
      o->div.col[nk * c + k] = m->cface[nk * c + k];
      o->div.val[nk * c + k] = m->csign[nk * c + k];
    }
  }
  o->div.rowptr[m->nc] = nk * m->nc;
}

void ops_free(Ops *o) {
  free(o->area);
  csr_free(&o->P);
  csr_free(&o->A);
  csr_free(&o->lap);
  csr_free(&o->D);
  csr_free(&o->div);
  memset(o, 0, sizeof *o);
}

void ops_set_geometry(Ops *o, const double *g) {
  const FluidMesh *m = o->m;
  o->g = g;
  int dim = m->dim, nk = m->nk;
  for (int c = 0; c < m->nc; c++) {
    o->area[c] = mesh_volume(m, g, c);
    const int *t = m->cell + nk * c;
    double cen[3] = {0, 0, 0};
    for (int d = 0; d < dim; d++) {
      for (int k = 0; k < nk; k++) cen[d] += g[dim * t[k] + d];
      cen[d] /= nk;
    }
    /* paper §5.3: p_c = sum_k (outward flux)(face centroid - cell centroid);
     * face k is opposite vertex k, so its centroid - the cell's is
     * (centroid - g_k) / dim (and reads only the cell's own vertices) */
    double *P = o->P.val + dim * nk * c;
    for (int d = 0; d < dim; d++)
      for (int k = 0; k < nk; k++) P[nk * d + k] = m->csign[nk * c + k] * (cen[d] - g[dim * t[k] + d]) / dim;
  }
}

void ops_set_advection(Ops *o, const double *phi) {
  const FluidMesh *m = o->m;
  /* paper Eq. 6 with the minus sign explicit: csign*phi leaves cell i,
   * carrying the face value (u_e + u_i)/2; boundary faces carry nothing */
  int nk = m->nk;
  for (int i = 0; i < m->nc; i++) {
    int p = o->A.rowptr[i];
    double diag = 0;
    int q = p + 1;
    for (int k = 0; k < nk; k++) {
      if (m->nbr[nk * i + k] < 0) continue;
      double out = m->csign[nk * i + k] * phi[m->cface[nk * i + k]];
      o->A.val[q++] = -0.5 * out;
      diag -= 0.5 * out;
    }
    o->A.val[p] = diag;
  }
}

/* Area vector of triangle face j at g (3D): 0.5 (g1 - g0) x (g2 - g0). */
static void area_vector(const FluidMesh *m, const double *g, int j, double n[3]) {
  const double *a = g + 3 * m->face[3 * j], *b = g + 3 * m->face[3 * j + 1], *c = g + 3 * m->face[3 * j + 2];
  double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, q[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  n[0] = 0.5 * (e[1] * q[2] - e[2] * q[1]);
  n[1] = 0.5 * (e[2] * q[0] - e[0] * q[2]);
  n[2] = 0.5 * (e[0] * q[1] - e[1] * q[0]);
}

void ops_induced_flux(const FluidMesh *m, const double *g, const double *gdot, double *h) {
  if (m->dim == 3) {
    for (int j = 0; j < m->nf; j++) {
      const int *t = m->face + 3 * j;
      double n[3];
      area_vector(m, g, j, n);
      h[j] = 0;
      for (int d = 0; d < 3; d++) h[j] += n[d] * (gdot[3 * t[0] + d] + gdot[3 * t[1] + d] + gdot[3 * t[2] + d]) / 3;
    }
    return;
  }
  for (int j = 0; j < m->nf; j++) {
    int a = m->face[2 * j], b = m->face[2 * j + 1];
    double nx = g[2 * b + 1] - g[2 * a + 1], ny = g[2 * a] - g[2 * b];
    double vx = (gdot[2 * a] + gdot[2 * b]) / 2, vy = (gdot[2 * a + 1] + gdot[2 * b + 1]) / 2;
    h[j] = nx * vx + ny * vy;
  }
}

void ops_swept_flux(const FluidMesh *m, const double *g0, const double *g1, const double *gmid, const double *gdot,
                    double *h) {
  ops_induced_flux(m, gmid, gdot, h);
  if (m->dim != 3) return; /* the edge's normal is linear in t: the midpoint is exact */
  /* the area vector is quadratic in t: Simpson's rule is exact */
  for (int j = 0; j < m->nf; j++) {
    const int *t = m->face + 3 * j;
    double n0[3], n1[3], v = 0;
    area_vector(m, g0, j, n0);
    area_vector(m, g1, j, n1);
    for (int d = 0; d < 3; d++) v += (n0[d] + n1[d]) * (gdot[3 * t[0] + d] + gdot[3 * t[1] + d] + gdot[3 * t[2] + d]) / 3;
    h[j] = (4 * h[j] + v) / 6;
  }
}

void ops_velocity_from_flux(const Ops *o, const double *f, double *u) {
  int dim = o->m->dim;
  csr_mv(&o->P, f, u);
  for (int c = 0; c < o->m->nc; c++)
    for (int d = 0; d < dim; d++) u[dim * c + d] /= o->area[c];
}

double ops_energy(const Ops *o, const double *u) {
  int dim = o->m->dim;
  double e = 0;
  for (int c = 0; c < o->m->nc; c++)
    for (int d = 0; d < dim; d++) e += o->area[c] * u[dim * c + d] * u[dim * c + d];
  return 0.5 * e;
}

double ops_max_column_divergence(const Ops *o, const double *B, long nf, long m) {
  double worst = 0, *col = malloc(nf * sizeof *col), *d = malloc(o->div.nrow * sizeof *d);
  for (long k = 0; k < m; k++) {
    for (long j = 0; j < nf; j++) col[j] = B[j * m + k];
    csr_mv(&o->div, col, d);
    for (int c = 0; c < o->div.nrow; c++) worst = d[c] > worst ? d[c] : -d[c] > worst ? -d[c] : worst;
  }
  free(col), free(d);
  return worst;
}
