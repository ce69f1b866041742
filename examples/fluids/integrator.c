/* integrator.c — RK4 of advection and diffusion (see integrator.h). */
#include "integrator.h"

#include <stdlib.h>
#include <string.h>

void integrator_init(Integrator *it, const Ops *o) {
  memset(it, 0, sizeof *it);
  it->o = o;
  int nc = o->m->nc, nnz = o->A.rowptr[nc];
  it->M.nrow = it->M.ncol = nc;
  it->M.rowptr = malloc((nc + 1) * sizeof *it->M.rowptr);
  it->M.col = malloc(nnz * sizeof *it->M.col);
  it->M.val = malloc(nnz * sizeof *it->M.val);
  memcpy(it->M.rowptr, o->A.rowptr, (nc + 1) * sizeof *it->M.rowptr);
  memcpy(it->M.col, o->A.col, nnz * sizeof *it->M.col);
  int n = o->m->dim * nc;
  for (int s = 0; s < 4; s++) it->k[s] = malloc(n * sizeof(double));
  it->tmp = malloc(n * sizeof(double));
}

void integrator_free(Integrator *it) {
  csr_free(&it->M);
  for (int s = 0; s < 4; s++) free(it->k[s]);
  free(it->tmp);
  memset(it, 0, sizeof *it);
}

/* M = A + mu lap: A and lap share the cell pattern (operators.c) */
static void combine(Integrator *it, double mu) {
  const Ops *o = it->o;
  int nnz = o->A.rowptr[o->m->nc];
  for (int p = 0; p < nnz; p++) it->M.val[p] = o->A.val[p] + mu * o->lap.val[p];
}

static void rate(Integrator *it, const double *u, double *du) {
  const Ops *o = it->o;
  int dim = o->m->dim;
  csr_mvd(&it->M, dim, u, du);
  for (int c = 0; c < o->m->nc; c++)
    for (int d = 0; d < dim; d++) du[dim * c + d] /= o->area[c];
}

void integrator_rate(Integrator *it, double mu, const double *u, double *du) {
  combine(it, mu);
  rate(it, u, du);
}

void integrator_rk4(Integrator *it, double mu, double dt, double *u) {
  combine(it, mu);
  int n = it->o->m->dim * it->o->m->nc;
  double *t = it->tmp;
  rate(it, u, it->k[0]);
  for (int i = 0; i < n; i++) t[i] = u[i] + 0.5 * dt * it->k[0][i];
  rate(it, t, it->k[1]);
  for (int i = 0; i < n; i++) t[i] = u[i] + 0.5 * dt * it->k[1][i];
  rate(it, t, it->k[2]);
  for (int i = 0; i < n; i++) t[i] = u[i] + dt * it->k[2][i];
  rate(it, t, it->k[3]);
  for (int i = 0; i < n; i++) u[i] += dt / 6 * (it->k[0][i] + 2 * it->k[1][i] + 2 * it->k[2][i] + it->k[3][i]);
}
