/* particles.c — marker particles (see particles.h). */
#include "particles.h"

#include <cblas.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

void particles_free(Particles *p) {
  for (int t = 0; t < PARTICLES_MAX_THREADS; t++) {
    ParticleCache *pc = &p->cache[t];
    free(pc->stamp), free(pc->fstamp), free(pc->vel), free(pc->bary), free(pc->fval);
  }
  free(p->order_count);
  free(p->order_int);
  free(p->order_x);
  free(p->x);
  free(p->cell);
  free(p->tag);
  memset(p, 0, sizeof *p);
}

static double rnd(unsigned *s) {
  *s = *s * 1103515245u + 12345u;
  return ((*s >> 8) & 0xffffff) / 16777216.0;
}

/* Signed volume (3D) of the tetrahedron a, b, c, d, times 6. */
static double det3(const double *a, const double *b, const double *c, const double *d) {
  double e[3][3];
  for (int k = 0; k < 3; k++) e[0][k] = b[k] - a[k], e[1][k] = c[k] - a[k], e[2][k] = d[k] - a[k];
  return e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1]) - e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0]) +
         e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0]);
}

int particles_seed(Particles *p, const FluidMesh *m, const double *g, int n, unsigned seed) {
  memset(p, 0, sizeof *p);
  int dim = m->dim, nk = m->nk;
  p->n = n;
  p->dim = dim;
  p->x = malloc(dim * (size_t)n * sizeof *p->x + 1);
  p->cell = malloc(n * sizeof *p->cell + 1);
  p->tag = malloc(n * sizeof *p->tag + 1);
  double *cum = malloc(m->nc * sizeof *cum + 1), total = 0;
  if (!p->x || !p->cell || !p->tag || !cum) {
    free(p->x), free(p->cell), free(p->tag), free(cum);
    memset(p, 0, sizeof *p);
    return -1;
  }
  for (int c = 0; c < m->nc; c++) cum[c] = total += mesh_volume(m, g, c);
  /* the streak axis: y in 2D, z in 3D */
  int ax = dim - 1;
  double ymin = 1e300, ymax = -1e300;
  for (int v = 0; v < m->nv; v++) {
    if (g[dim * v + ax] < ymin) ymin = g[dim * v + ax];
    if (g[dim * v + ax] > ymax) ymax = g[dim * v + ax];
  }
  /* streaks: 12 bands (horizontal lines in 2D, slabs in 3D) a fifth of
   * their spacing wide, alternately tagged, so the picture shows how the
   * flow shears and mixes them */
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
    const int *t = m->cell + nk * lo;
    if (dim == 2) {
      double a = rnd(&seed), b = rnd(&seed);
      if (a + b > 1) a = 1 - a, b = 1 - b;
      for (int d = 0; d < 2; d++)
        p->x[2 * i + d] = g[2 * t[0] + d] + a * (g[2 * t[1] + d] - g[2 * t[0] + d]) + b * (g[2 * t[2] + d] - g[2 * t[0] + d]);
    } else {
      /* uniform in the tetrahedron: the gaps of three sorted uniforms */
      double u[3] = {rnd(&seed), rnd(&seed), rnd(&seed)}, w[4];
      for (int a = 0; a < 2; a++)
        for (int b = 0; b < 2 - a; b++)
          if (u[b] > u[b + 1]) {
            double x = u[b];
            u[b] = u[b + 1];
            u[b + 1] = x;
          }
      w[0] = u[0], w[1] = u[1] - u[0], w[2] = u[2] - u[1], w[3] = 1 - u[2];
      for (int d = 0; d < 3; d++) {
        double x = 0;
        for (int k = 0; k < 4; k++) x += w[k] * g[3 * t[k] + d];
        p->x[3 * i + d] = x;
      }
    }
    double band = (p->x[dim * i + ax] - ymin) / spacing;
    if (band - floor(band) > 0.2) goto again;
    p->cell[i] = lo;
    p->tag[i] = (int)band % 2;
  }
  free(cum);
  return 0;
}

/* Eq. 13 in cell c from its faces' outward fluxes out[k] (face k opposite
 * vertex k). */
static void cell_velocity(const FluidMesh *m, const double *g, int c, const double *out, double *u) {
  int dim = m->dim, nk = m->nk;
  const int *t = m->cell + nk * c;
  double cen[3] = {0, 0, 0}, vol = mesh_volume(m, g, c);
  for (int d = 0; d < dim; d++) {
    for (int k = 0; k < nk; k++) cen[d] += g[dim * t[k] + d];
    cen[d] /= nk;
    u[d] = 0;
  }
  /* paper Eq. 13 in cell c: face k's centroid - the cell's = (cen - g_k) / dim */
  for (int k = 0; k < nk; k++)
    for (int d = 0; d < dim; d++) u[d] += out[k] * (cen[d] - g[dim * t[k] + d]) / dim;
  for (int d = 0; d < dim; d++) u[d] /= vol;
}

void particles_cell_velocity(const FluidMesh *m, const double *g, const double *f, int c, double *u) {
  double out[4];
  for (int k = 0; k < m->nk; k++) out[k] = m->csign[m->nk * c + k] * f[m->cface[m->nk * c + k]];
  cell_velocity(m, g, c, out, u);
}

/* Barycentric coordinates of x in cell c. */
static void barycentric(const FluidMesh *m, const double *g, int c, const double *x, double *lam) {
  if (m->dim == 3) {
    const int *t = m->cell + 4 * c;
    const double *v[4] = {g + 3 * t[0], g + 3 * t[1], g + 3 * t[2], g + 3 * t[3]};
    double vol6 = det3(v[0], v[1], v[2], v[3]);
    for (int k = 0; k < 4; k++) {
      const double *w[4] = {v[0], v[1], v[2], v[3]};
      w[k] = x;
      lam[k] = det3(w[0], w[1], w[2], w[3]) / vol6;
    }
    return;
  }
  const int *t = m->cell + 3 * c;
  double area2 = 2 * mesh_volume(m, g, c);
  for (int k = 0; k < 3; k++) {
    const double *a = g + 2 * t[(k + 1) % 3], *b = g + 2 * t[(k + 2) % 3];
    lam[k] = ((a[0] - x[0]) * (b[1] - x[1]) - (a[1] - x[1]) * (b[0] - x[0])) / area2;
  }
}

int particles_locate(const FluidMesh *m, const double *g, double *x, int *cell) {
  int dim = m->dim, nk = m->nk, c = *cell, steps = 0;
  for (int d = 0; d < dim; d++)
    if (!isfinite(x[d])) return 0; /* a diverged flow: nothing to find */
  for (; steps < 4 * m->nc; steps++) {
    double lam[4];
    barycentric(m, g, c, x, lam);
    int k = 0;
    for (int q = 1; q < nk; q++)
      if (lam[q] < lam[k]) k = q;
    if (lam[k] >= -1e-12) break;
    int n = m->nbr[nk * c + k];
    if (n >= 0) { /* cross face k, the one opposite vertex k */
      if (m->nshift) x[0] += m->nshift[nk * c + k] * m->spec.L;
      c = n;
      continue;
    }
    /* a wall: back onto the cell (clamp the barycentric coordinates) */
    double s = 0;
    for (int q = 0; q < nk; q++) s += lam[q] = lam[q] > 0 ? lam[q] : 0;
    const int *t = m->cell + nk * c;
    for (int d = 0; d < dim; d++) {
      double y = 0;
      for (int q = 0; q < nk; q++) y += lam[q] * g[dim * t[q] + d];
      x[d] = y / s;
    }
    break;
  }
  *cell = c;
  return steps;
}

void particles_advect(Particles *p, const FluidMesh *m, const double *g, const double *f, double dt, int substeps) {
  int dim = m->dim;
  double h = dt / substeps;
  for (int i = 0; i < p->n; i++) {
    double *x = p->x + dim * i;
    p->walk_steps += particles_locate(m, g, x, &p->cell[i]); /* the mesh moved under it */
    for (int s = 0; s < substeps; s++) {
      double u[3];
      particles_cell_velocity(m, g, f, p->cell[i], u);
      for (int d = 0; d < dim; d++) x[d] += h * u[d];
      p->walk_steps += particles_locate(m, g, x, &p->cell[i]);
    }
  }
}

/* ---------------------------------------------------------------- 3D, cached per frame */

/* Face j's flux: f_j, or row j of B_f times f̂ on its first use of the frame. */
static double face_flux(ParticleCache *pc, const ParticleFlow *fl, int frame, int j) {
  if (!fl->Bf) return fl->f[j];
  if (pc->fstamp[j] != frame) {
    pc->fstamp[j] = frame;
    pc->fval[j] = cblas_sdot(fl->mf, fl->Bf + (size_t)j * fl->mf, 1, fl->fh, 1);
    pc->faces++;
  }
  return pc->fval[j];
}

/* Cell c's velocity (Eq. 13) and barycentric map (λ_1..3 = M (x - g_0),
 * λ_0 = 1 - their sum), computed on the first visit of the frame. */
static void visit(ParticleCache *pc, const FluidMesh *m, const ParticleFlow *fl, int frame, int c) {
  if (pc->stamp[c] == frame) return;
  pc->stamp[c] = frame;
  pc->cells++;
  const double *g = fl->g;
  double out[4];
  for (int k = 0; k < 4; k++) out[k] = m->csign[4 * c + k] * face_flux(pc, fl, frame, m->cface[4 * c + k]);
  cell_velocity(m, g, c, out, pc->vel + 3 * c);
  const int *t = m->cell + 4 * c;
  const double *a = g + 3 * t[0];
  double e[3][3], *B = pc->bary + 12 * c;
  for (int k = 0; k < 3; k++)
    for (int d = 0; d < 3; d++) e[d][k] = g[3 * t[k + 1] + d] - a[d]; /* columns: the edges from g_0 */
  double det = e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1]) - e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0]) +
               e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0]);
  B[0] = (e[1][1] * e[2][2] - e[1][2] * e[2][1]) / det;
  B[1] = (e[0][2] * e[2][1] - e[0][1] * e[2][2]) / det;
  B[2] = (e[0][1] * e[1][2] - e[0][2] * e[1][1]) / det;
  B[3] = (e[1][2] * e[2][0] - e[1][0] * e[2][2]) / det;
  B[4] = (e[0][0] * e[2][2] - e[0][2] * e[2][0]) / det;
  B[5] = (e[0][2] * e[1][0] - e[0][0] * e[1][2]) / det;
  B[6] = (e[1][0] * e[2][1] - e[1][1] * e[2][0]) / det;
  B[7] = (e[0][1] * e[2][0] - e[0][0] * e[2][1]) / det;
  B[8] = (e[0][0] * e[1][1] - e[0][1] * e[1][0]) / det;
  B[9] = a[0], B[10] = a[1], B[11] = a[2];
}

static int locate3(ParticleCache *pc, const FluidMesh *m, const ParticleFlow *fl, int frame, double *x, int *cell) {
  const double *g = fl->g;
  int c = *cell, steps = 0;
  if (!isfinite(x[0]) || !isfinite(x[1]) || !isfinite(x[2])) return 0;
  for (; steps < 4 * m->nc; steps++) {
    visit(pc, m, fl, frame, c);
    const double *B = pc->bary + 12 * c;
    double y[3] = {x[0] - B[9], x[1] - B[10], x[2] - B[11]}, lam[4];
    lam[1] = B[0] * y[0] + B[1] * y[1] + B[2] * y[2];
    lam[2] = B[3] * y[0] + B[4] * y[1] + B[5] * y[2];
    lam[3] = B[6] * y[0] + B[7] * y[1] + B[8] * y[2];
    lam[0] = 1 - lam[1] - lam[2] - lam[3];
    int k = 0;
    for (int q = 1; q < 4; q++)
      if (lam[q] < lam[k]) k = q;
    if (lam[k] >= -1e-12) break;
    int n = m->nbr[4 * c + k];
    if (n >= 0) {
      c = n;
      continue;
    }
    /* a wall: back onto the cell */
    double s = 0;
    for (int q = 0; q < 4; q++) s += lam[q] = lam[q] > 0 ? lam[q] : 0;
    const int *t = m->cell + 4 * c;
    for (int d = 0; d < 3; d++)
      x[d] = (lam[0] * g[3 * t[0] + d] + lam[1] * g[3 * t[1] + d] + lam[2] * g[3 * t[2] + d] + lam[3] * g[3 * t[3] + d]) / s;
    break;
  }
  *cell = c;
  return steps;
}

void particles_sort_by_cell(Particles *p, const FluidMesh *m) {
  int n = p->n, dim = p->dim ? p->dim : m->dim;
  if (!p->order_count) {
    p->order_count = malloc(((size_t)m->nc + 1) * sizeof *p->order_count);
    p->order_int = malloc(2 * (size_t)n * sizeof *p->order_int);
    p->order_x = malloc((size_t)dim * n * sizeof *p->order_x);
  }
  int *cnt = p->order_count, *cell = p->order_int, *tag = p->order_int + n;
  memset(cnt, 0, ((size_t)m->nc + 1) * sizeof *cnt);
  for (int i = 0; i < n; i++) cnt[p->cell[i] + 1]++;
  for (int c = 0; c < m->nc; c++) cnt[c + 1] += cnt[c];
  for (int i = 0; i < n; i++) {
    int k = cnt[p->cell[i]]++;
    cell[k] = p->cell[i], tag[k] = p->tag[i];
    memcpy(p->order_x + (size_t)dim * k, p->x + (size_t)dim * i, (size_t)dim * sizeof *p->x);
  }
  memcpy(p->cell, cell, (size_t)n * sizeof *cell);
  memcpy(p->tag, tag, (size_t)n * sizeof *tag);
  memcpy(p->x, p->order_x, (size_t)dim * n * sizeof *p->x);
}

/* One thread's share of the particles, [lo, hi), through its own cache. */
typedef struct AdvectJob {
  Particles *p;
  const FluidMesh *m;
  const ParticleFlow *fl;
  ParticleCache *pc;
  int lo, hi, substeps;
  double h;
} AdvectJob;

static void *advect_range(void *arg) {
  AdvectJob *j = arg;
  ParticleCache *pc = j->pc;
  int frame = j->p->frame;
  for (int i = j->lo; i < j->hi; i++) {
    double *x = j->p->x + 3 * i;
    int *cell = j->p->cell + i;
    pc->walk_steps += locate3(pc, j->m, j->fl, frame, x, cell);
    for (int s = 0; s < j->substeps; s++) {
      const double *u = pc->vel + 3 * *cell;
      x[0] += j->h * u[0], x[1] += j->h * u[1], x[2] += j->h * u[2];
      pc->walk_steps += locate3(pc, j->m, j->fl, frame, x, cell);
    }
  }
  return NULL;
}

static int cache_alloc(ParticleCache *pc, const FluidMesh *m, int faces) {
  if (!pc->stamp) {
    pc->stamp = calloc(m->nc, sizeof *pc->stamp);
    pc->vel = malloc(3 * (size_t)m->nc * sizeof *pc->vel);
    pc->bary = malloc(12 * (size_t)m->nc * sizeof *pc->bary);
  }
  if (faces && !pc->fstamp) {
    pc->fstamp = calloc(m->nf, sizeof *pc->fstamp);
    pc->fval = malloc((size_t)m->nf * sizeof *pc->fval);
  }
  return pc->stamp && pc->vel && pc->bary && (!faces || (pc->fstamp && pc->fval)) ? 0 : -1;
}

int particles_advect_flow(Particles *p, const FluidMesh *m, const ParticleFlow *fl, double dt, int substeps) {
  if (m->dim != 3) {
    if (!fl->f) return -1;
    particles_advect(p, m, fl->g, fl->f, dt, substeps);
    return 0;
  }
  int nt = p->threads < 1 ? 1 : p->threads > PARTICLES_MAX_THREADS ? PARTICLES_MAX_THREADS : p->threads;
  if (nt > 1 && p->n < 256 * nt) nt = p->n / 256 > 1 ? p->n / 256 : 1; /* a thread's start costs more than a few particles */
  for (int t = 0; t < nt; t++)
    if (cache_alloc(&p->cache[t], m, fl->Bf != NULL) != 0) return -1;
  p->frame++;
  particles_sort_by_cell(p, m);
  AdvectJob job[PARTICLES_MAX_THREADS];
  pthread_t tid[PARTICLES_MAX_THREADS];
  int running[PARTICLES_MAX_THREADS] = {0};
  /* consecutive particles share cells: each thread a contiguous range */
  for (int t = 0; t < nt; t++) {
    p->cache[t].walk_steps = p->cache[t].cells = p->cache[t].faces = 0;
    job[t] = (AdvectJob){p, m, fl, &p->cache[t], (int)((long)p->n * t / nt), (int)((long)p->n * (t + 1) / nt),
                         substeps, dt / substeps};
  }
  for (int t = 1; t < nt; t++) running[t] = pthread_create(&tid[t], NULL, advect_range, &job[t]) == 0;
  advect_range(&job[0]);
  for (int t = 1; t < nt; t++) {
    if (running[t])
      pthread_join(tid[t], NULL);
    else
      advect_range(&job[t]); /* no thread could start: this one does its share */
  }
  for (int t = 0; t < nt; t++) {
    p->walk_steps += p->cache[t].walk_steps;
    p->cells_visited += p->cache[t].cells;
    p->faces_lifted += p->cache[t].faces;
  }
  return 0;
}

void particles_advect_cached(Particles *p, const FluidMesh *m, const double *g, const double *f, double dt, int substeps) {
  ParticleFlow fl = {.g = g, .f = f};
  particles_advect_flow(p, m, &fl, dt, substeps);
}
