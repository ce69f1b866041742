/* particles.c — marker particles (see particles.h). */
#include "particles.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void particles_free(Particles *p) {
  free(p->x);
  free(p->cell);
  free(p->tag);
  memset(p, 0, sizeof *p);
}

static double rnd(unsigned *s) {
  *s = *s * 1103515245u + 12345u;
  return ((*s >> 8) & 0xffffff) / 16777216.0;
}

void particles_seed(Particles *p, const Mesh *m, const double *g, int n, unsigned seed) {
  memset(p, 0, sizeof *p);
  p->n = n;
  p->x = malloc(2 * (size_t)n * sizeof *p->x);
  p->cell = malloc(n * sizeof *p->cell);
  p->tag = malloc(n * sizeof *p->tag);
  double *cum = malloc(m->nc * sizeof *cum), total = 0;
  for (int c = 0; c < m->nc; c++) cum[c] = total += mesh_area(m, g, c);
  double ymin = 1e300, ymax = -1e300;
  for (int v = 0; v < m->nv; v++) {
    if (g[2 * v + 1] < ymin) ymin = g[2 * v + 1];
    if (g[2 * v + 1] > ymax) ymax = g[2 * v + 1];
  }
  /* streaks: 12 horizontal bands a fifth of their spacing wide, alternately
   * tagged, so the picture shows how the flow shears and mixes them */
  double spacing = (ymax - ymin) / 12;
  for (int i = 0; i < n; i++) {
  again:;
    double r = rnd(&seed) * total;
    int lo = 0, hi = m->nc - 1;
    while (lo < hi) {
      int mid = (lo + hi) / 2;
      if (cum[mid] < r) lo = mid + 1;
      else hi = mid;
    }
    double a = rnd(&seed), b = rnd(&seed);
    if (a + b > 1) a = 1 - a, b = 1 - b;
    const int *t = m->tri + 3 * lo;
    for (int d = 0; d < 2; d++)
      p->x[2 * i + d] = g[2 * t[0] + d] + a * (g[2 * t[1] + d] - g[2 * t[0] + d]) + b * (g[2 * t[2] + d] - g[2 * t[0] + d]);
    double band = (p->x[2 * i + 1] - ymin) / spacing;
    if (band - floor(band) > 0.2) goto again;
    p->cell[i] = lo;
    p->tag[i] = (int)band % 2;
  }
  free(cum);
}

void particles_cell_velocity(const Mesh *m, const double *g, const double *f, int c, double u[2]) {
  const int *t = m->tri + 3 * c;
  double cen[2], area = mesh_area(m, g, c);
  for (int d = 0; d < 2; d++) cen[d] = (g[2 * t[0] + d] + g[2 * t[1] + d] + g[2 * t[2] + d]) / 3;
  u[0] = u[1] = 0;
  for (int k = 0; k < 3; k++) {
    double out = m->csign[3 * c + k] * f[m->cface[3 * c + k]];
    for (int d = 0; d < 2; d++) u[d] += out * (cen[d] - g[2 * t[k] + d]) / 2;
  }
  u[0] /= area;
  u[1] /= area;
}

/* Barycentric coordinates of x in cell c. */
static void barycentric(const Mesh *m, const double *g, int c, const double x[2], double lam[3]) {
  const int *t = m->tri + 3 * c;
  double area2 = 2 * mesh_area(m, g, c);
  for (int k = 0; k < 3; k++) {
    const double *a = g + 2 * t[(k + 1) % 3], *b = g + 2 * t[(k + 2) % 3];
    lam[k] = ((a[0] - x[0]) * (b[1] - x[1]) - (a[1] - x[1]) * (b[0] - x[0])) / area2;
  }
}

int particles_locate(const Mesh *m, const double *g, double x[2], int *cell) {
  int c = *cell, steps = 0;
  for (; steps < 4 * m->nc; steps++) {
    double lam[3];
    barycentric(m, g, c, x, lam);
    int k = 0;
    for (int q = 1; q < 3; q++)
      if (lam[q] < lam[k]) k = q;
    if (lam[k] >= -1e-12) break;
    int n = m->nbr[3 * c + k];
    if (n >= 0) { /* cross face k, the edge opposite vertex k */
      x[0] += m->nshift[3 * c + k] * m->spec.L;
      c = n;
      continue;
    }
    /* a wall: back onto the cell (clamp the barycentric coordinates) */
    double s = 0;
    for (int q = 0; q < 3; q++) s += lam[q] = lam[q] > 0 ? lam[q] : 0;
    const int *t = m->tri + 3 * c;
    for (int d = 0; d < 2; d++)
      x[d] = (lam[0] * g[2 * t[0] + d] + lam[1] * g[2 * t[1] + d] + lam[2] * g[2 * t[2] + d]) / s;
    break;
  }
  *cell = c;
  return steps;
}

void particles_advect(Particles *p, const Mesh *m, const double *g, const double *f, double dt, int substeps) {
  double h = dt / substeps;
  for (int i = 0; i < p->n; i++) {
    double *x = p->x + 2 * i;
    p->walk_steps += particles_locate(m, g, x, &p->cell[i]); /* the mesh moved under it */
    for (int s = 0; s < substeps; s++) {
      double u[2];
      particles_cell_velocity(m, g, f, p->cell[i], u);
      x[0] += h * u[0];
      x[1] += h * u[1];
      p->walk_steps += particles_locate(m, g, x, &p->cell[i]);
    }
  }
}
