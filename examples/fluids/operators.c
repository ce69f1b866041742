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
static void cell_pattern(const Mesh *m, Csr *M) {
  int nnz = m->nc;
  for (int i = 0; i < 3 * m->nc; i++) nnz += m->nbr[i] >= 0;
  csr_alloc(M, m->nc, m->nc, nnz);
  int p = 0;
  for (int i = 0; i < m->nc; i++) {
    M->rowptr[i] = p;
    M->col[p++] = i;
    for (int k = 0; k < 3; k++)
      if (m->nbr[3 * i + k] >= 0) M->col[p++] = m->nbr[3 * i + k];
  }
  M->rowptr[m->nc] = p;
}

void ops_init(Ops *o, const Mesh *m) {
  memset(o, 0, sizeof *o);
  o->m = m;
  o->area = calloc(m->nc, sizeof *o->area);
  /* P: row 2c + d over the three faces of c */
  csr_alloc(&o->P, 2 * m->nc, m->nf, 6 * m->nc);
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < 2; d++) {
      int r = 2 * c + d;
      o->P.rowptr[r] = 3 * r;
      for (int k = 0; k < 3; k++) o->P.col[3 * r + k] = m->cface[3 * c + k];
    }
  o->P.rowptr[2 * m->nc] = 6 * m->nc;
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
  csr_alloc(&o->div, m->nc, m->nf, 3 * m->nc);
  for (int c = 0; c < m->nc; c++) {
    o->div.rowptr[c] = 3 * c;
    for (int k = 0; k < 3; k++) {
      o->div.col[3 * c + k] = m->cface[3 * c + k];
      o->div.val[3 * c + k] = m->csign[3 * c + k];
    }
  }
  o->div.rowptr[m->nc] = 3 * m->nc;
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
  const Mesh *m = o->m;
  o->g = g;
  for (int c = 0; c < m->nc; c++) {
    o->area[c] = mesh_area(m, g, c);
    const int *t = m->tri + 3 * c;
    double cen[2];
    for (int d = 0; d < 2; d++) cen[d] = (g[2 * t[0] + d] + g[2 * t[1] + d] + g[2 * t[2] + d]) / 3;
    /* paper §5.3: p_c = sum_k (outward flux)(edge midpoint - centroid); edge
     * k is opposite vertex k, so midpoint - centroid = (centroid - g_k) / 2 */
    for (int d = 0; d < 2; d++)
      for (int k = 0; k < 3; k++) o->P.val[6 * c + 3 * d + k] = m->csign[3 * c + k] * (cen[d] - g[2 * t[k] + d]) / 2;
  }
}

void ops_set_advection(Ops *o, const double *phi) {
  const Mesh *m = o->m;
  /* paper Eq. 6 with the minus sign explicit: csign*phi leaves cell i,
   * carrying the face value (u_e + u_i)/2; boundary faces carry nothing */
  for (int i = 0; i < m->nc; i++) {
    int p = o->A.rowptr[i];
    double diag = 0;
    int q = p + 1;
    for (int k = 0; k < 3; k++) {
      if (m->nbr[3 * i + k] < 0) continue;
      double out = m->csign[3 * i + k] * phi[m->cface[3 * i + k]];
      o->A.val[q++] = -0.5 * out;
      diag -= 0.5 * out;
    }
    o->A.val[p] = diag;
  }
}

void ops_induced_flux(const Mesh *m, const double *g, const double *gdot, double *h) {
  for (int j = 0; j < m->nf; j++) {
    int a = m->edge[2 * j], b = m->edge[2 * j + 1];
    double nx = g[2 * b + 1] - g[2 * a + 1], ny = g[2 * a] - g[2 * b];
    double vx = (gdot[2 * a] + gdot[2 * b]) / 2, vy = (gdot[2 * a + 1] + gdot[2 * b + 1]) / 2;
    h[j] = nx * vx + ny * vy;
  }
}

void ops_velocity_from_flux(const Ops *o, const double *f, double *u) {
  csr_mv(&o->P, f, u);
  for (int c = 0; c < o->m->nc; c++) {
    u[2 * c] /= o->area[c];
    u[2 * c + 1] /= o->area[c];
  }
}

double ops_energy(const Ops *o, const double *u) {
  double e = 0;
  for (int c = 0; c < o->m->nc; c++) e += o->area[c] * (u[2 * c] * u[2 * c] + u[2 * c + 1] * u[2 * c + 1]);
  return 0.5 * e;
}
