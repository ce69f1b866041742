/* dense.c — dense gathers and the Jacobi iteration (dense.h). */
#include "dense.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "kernel.h"

/* Σ over sources [j0, j1) of K(x_i, y_j) q_j, q = w b as three arrays. */
static inline void row_sum(const Surfels *s, long i, long j0, long j1, const double *q0, const double *q1,
                           const double *q2, double acc[3]) {
  double xi = s->x[i], yi = s->y[i], zi = s->z[i], nxi = s->nx[i], nyi = s->ny[i], nzi = s->nz[i];
  double g0 = 0, g1 = 0, g2 = 0;
  const double *X = s->x, *Y = s->y, *Z = s->z, *NX = s->nx, *NY = s->ny, *NZ = s->nz, *W = s->w;
#pragma omp simd reduction(+ : g0, g1, g2)
  for (long j = j0; j < j1; j++) {
    double k = kernel_ff(xi, yi, zi, nxi, nyi, nzi, X[j], Y[j], Z[j], NX[j], NY[j], NZ[j], W[j]);
    g0 += k * q0[j], g1 += k * q1[j], g2 += k * q2[j];
  }
  acc[0] = g0, acc[1] = g1, acc[2] = g2;
}

static double *strengths(const Surfels *s, const double *b) {
  long n = s->n;
  double *q = malloc(sizeof(double) * 3 * (size_t)(n > 0 ? n : 1));
  if (!q) return NULL;
  for (long j = 0; j < n; j++)
    for (int ch = 0; ch < 3; ch++) q[(size_t)ch * (size_t)n + (size_t)j] = s->w[j] * b[3 * j + ch];
  return q;
}

void dense_gather(const Surfels *s, const Octree *t, const float *vis, const double *b, double *g) {
  long n = s->n, nl = t->nleaf;
  double *q = strengths(s, b);
  if (!q) return;
  const double *q0 = q, *q1 = q + n, *q2 = q + 2 * n;
#pragma omp parallel for schedule(dynamic, 1)
  for (long la = 0; la < nl; la++) {
    const OctNode *a = &t->node[t->leaf[la]];
    for (long i = a->start; i < a->start + a->count; i++) {
      double tot[3] = {0, 0, 0}, acc[3];
      if (!vis) {
        row_sum(s, i, 0, n, q0, q1, q2, tot);
      } else {
        for (long lb = 0; lb < nl; lb++) {
          const OctNode *bn = &t->node[t->leaf[lb]];
          double v = vis[la * nl + lb];
          row_sum(s, i, bn->start, bn->start + bn->count, q0, q1, q2, acc);
          for (int ch = 0; ch < 3; ch++) tot[ch] += v * acc[ch];
        }
      }
      for (int ch = 0; ch < 3; ch++) g[3 * i + ch] = tot[ch];
    }
  }
  free(q);
}

void dense_gather_bits(const Surfels *s, const unsigned char *bits, const double *b, double *g) {
  long n = s->n;
  double *q = strengths(s, b);
  if (!q) return;
#pragma omp parallel for schedule(dynamic, 16)
  for (long i = 0; i < n; i++) {
    double tot[3] = {0, 0, 0};
    for (long j = 0; j < n; j++) {
      size_t bit = (size_t)i * (size_t)n + (size_t)j;
      if (!(bits[bit >> 3] >> (bit & 7) & 1)) continue;
      double k = kernel_ff(s->x[i], s->y[i], s->z[i], s->nx[i], s->ny[i], s->nz[i], s->x[j], s->y[j], s->z[j],
                           s->nx[j], s->ny[j], s->nz[j], s->w[j]);
      for (int ch = 0; ch < 3; ch++) tot[ch] += k * q[(size_t)ch * (size_t)n + (size_t)j];
    }
    for (int ch = 0; ch < 3; ch++) g[3 * i + ch] = tot[ch];
  }
  free(q);
}

int radiosity_jacobi(const Surfels *s, GatherFn gather, void *ctx, double tol, int max_iter, double *b) {
  long n = s->n;
  double *g = malloc(sizeof(double) * 3 * (size_t)(n > 0 ? n : 1));
  if (!g) return -1;
  memcpy(b, s->e, sizeof(double) * 3 * (size_t)n);
  int it = 0;
  while (it < max_iter) {
    gather(ctx, b, g);
    it++;
    double diff = 0, norm = 0;
    for (long k = 0; k < 3 * n; k++) {
      double nb = s->e[k] + s->rho[k] * g[k];
      diff += (nb - b[k]) * (nb - b[k]), norm += nb * nb;
      b[k] = nb;
    }
    if (diff <= tol * tol * norm) break;
  }
  free(g);
  return it;
}
