/* surfels.c — the Cornell box, the two-patch visibility scene, and surfel
 * sampling (surfels.h). */
#include "surfels.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct Builder {
  TriScene *s;
  int cap_v, cap_t;
} Builder;

static int grow(Builder *b, int nv, int nt) {
  TriScene *s = b->s;
  if (s->nv + nv > b->cap_v) {
    b->cap_v = 2 * (s->nv + nv);
    double *v = realloc(s->v, sizeof(double) * 3 * (size_t)b->cap_v);
    if (!v) return -1;
    s->v = v;
  }
  if (s->nt + nt > b->cap_t) {
    b->cap_t = 2 * (s->nt + nt);
    int *t = realloc(s->tri, sizeof(int) * 3 * (size_t)b->cap_t);
    double *a = realloc(s->albedo, sizeof(double) * 3 * (size_t)b->cap_t);
    if (t) s->tri = t;
    if (a) s->albedo = a;
    double *e = a ? realloc(s->emission, sizeof(double) * 3 * (size_t)b->cap_t) : NULL;
    if (e) s->emission = e;
    if (!t || !a || !e) return -1;
  }
  return 0;
}

/* The quad p0 p1 p2 p3 (counter-clockwise seen from its front) as two
 * triangles. */
static int add_quad(Builder *b, const double q[4][3], const double albedo[3], const double emission[3]) {
  if (grow(b, 4, 2)) return -1;
  TriScene *s = b->s;
  int v0 = s->nv;
  for (int k = 0; k < 4; k++) memcpy(s->v + 3 * (s->nv++), q[k], sizeof(double) * 3);
  const int idx[2][3] = {{0, 1, 2}, {0, 2, 3}};
  for (int t = 0; t < 2; t++) {
    for (int k = 0; k < 3; k++) {
      s->tri[3 * s->nt + k] = v0 + idx[t][k];
      s->albedo[3 * s->nt + k] = albedo[k];
      s->emission[3 * s->nt + k] = emission[k];
    }
    s->nt++;
  }
  return 0;
}

/* An axis-aligned rectangle in the plane `axis` = `at`, spanning [lo,hi] in
 * the other two axes, facing +axis when `sign` > 0. */
static int add_rect(Builder *b, int axis, double at, int sign, const double lo[2], const double hi[2],
                    const double albedo[3], const double emission[3]) {
  int u = (axis + 1) % 3, v = (axis + 2) % 3; /* (u, v, axis) right-handed */
  double q[4][3];
  const double uv[4][2] = {{lo[0], lo[1]}, {hi[0], lo[1]}, {hi[0], hi[1]}, {lo[0], hi[1]}};
  for (int k = 0; k < 4; k++) {
    int kk = sign > 0 ? k : 3 - k;
    q[k][axis] = at, q[k][u] = uv[kk][0], q[k][v] = uv[kk][1];
  }
  return add_quad(b, q, albedo, emission);
}

/* A block standing on the floor: footprint centre (cx, cz), half sizes
 * (hx, hz), height `height`, turned by `angle` about y; four sides and a top. */
static int add_block(Builder *b, double cx, double cz, double hx, double hz, double height, double angle,
                     const double albedo[3]) {
  static const double black[3] = {0, 0, 0};
  double c = cos(angle), s = sin(angle), foot[4][2];
  const double corner[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}}; /* counter-clockwise seen from above (+y)… */
  for (int k = 0; k < 4; k++) {
    double lx = corner[k][0] * hx, lz = corner[k][1] * hz;
    foot[k][0] = cx + c * lx - s * lz, foot[k][1] = cz + s * lx + c * lz;
  }
  /* …in x–z with y up that order is clockwise from above, so the top takes
   * it reversed and each side (a, b) faces outwards as (a, b, b+h, a+h) reversed. */
  double top[4][3];
  for (int k = 0; k < 4; k++) top[k][0] = foot[3 - k][0], top[k][1] = height, top[k][2] = foot[3 - k][1];
  if (add_quad(b, top, albedo, black)) return -1;
  for (int k = 0; k < 4; k++) {
    const double *a = foot[k], *d = foot[(k + 1) % 4];
    double q[4][3] = {{d[0], 0, d[1]}, {a[0], 0, a[1]}, {a[0], height, a[1]}, {d[0], height, d[1]}};
    if (add_quad(b, q, albedo, black)) return -1;
  }
  return 0;
}

int scene_cornell_box(TriScene *s) {
  memset(s, 0, sizeof *s);
  Builder b = {s, 0, 0};
  static const double white[3] = {0.73, 0.73, 0.73}, red[3] = {0.65, 0.05, 0.05}, green[3] = {0.12, 0.45, 0.15};
  static const double black[3] = {0, 0, 0}, light[3] = {17.0, 12.0, 4.0}, light_albedo[3] = {0.78, 0.78, 0.78};
  const double full_lo[2] = {0, 0}, full_hi[2] = {1, 1};
  /* the light: a square hole in the ceiling, filled by the emitter */
  const double l0 = 0.37, l1 = 0.63;
  int rc = add_rect(&b, 1, 0.0, +1, (double[2]){0, 0}, (double[2]){1, 1}, white, black) /* floor (z,x) */
           || add_rect(&b, 2, 1.0, -1, full_lo, full_hi, white, black)                  /* back wall */
           || add_rect(&b, 0, 0.0, +1, full_lo, full_hi, red, black)                    /* left */
           || add_rect(&b, 0, 1.0, -1, full_lo, full_hi, green, black)                  /* right */
           /* ceiling, y = 1, facing down; its (u, v) = (z, x) */
           || add_rect(&b, 1, 1.0, -1, (double[2]){0, 0}, (double[2]){l0, 1}, white, black)
           || add_rect(&b, 1, 1.0, -1, (double[2]){l1, 0}, (double[2]){1, 1}, white, black)
           || add_rect(&b, 1, 1.0, -1, (double[2]){l0, 0}, (double[2]){l1, l0}, white, black)
           || add_rect(&b, 1, 1.0, -1, (double[2]){l0, l1}, (double[2]){l1, 1}, white, black)
           || add_rect(&b, 1, 1.0, -1, (double[2]){l0, l0}, (double[2]){l1, l1}, light_albedo, light)
           || add_block(&b, 0.66, 0.32, 0.15, 0.15, 0.30, -0.29, white)                   /* short block */
           || add_block(&b, 0.34, 0.62, 0.15, 0.15, 0.60, 0.30, white);                   /* tall block */
  if (rc) {
    triscene_free(s);
    return -1;
  }
  return 0;
}

int scene_two_patches(TriScene *s, int wall) {
  memset(s, 0, sizeof *s);
  Builder b = {s, 0, 0};
  static const double grey[3] = {0.5, 0.5, 0.5}, black[3] = {0, 0, 0};
  int rc = add_rect(&b, 1, 0.0, +1, (double[2]){0, 0}, (double[2]){1, 1}, grey, black) ||
           add_rect(&b, 1, 1.0, -1, (double[2]){0, 0}, (double[2]){1, 1}, grey, black);
  if (!rc && wall) /* both sides of the wall face a patch */
    rc = add_rect(&b, 1, 0.5, +1, (double[2]){-0.5, -0.5}, (double[2]){1.5, 1.5}, grey, black) ||
         add_rect(&b, 1, 0.5, -1, (double[2]){-0.5, -0.5}, (double[2]){1.5, 1.5}, grey, black);
  if (rc) {
    triscene_free(s);
    return -1;
  }
  return 0;
}

void triscene_free(TriScene *s) {
  free(s->v), free(s->tri), free(s->albedo), free(s->emission);
  memset(s, 0, sizeof *s);
}

int surfels_alloc(Surfels *p, long n) {
  memset(p, 0, sizeof *p);
  size_t m = (size_t)(n > 0 ? n : 1);
  p->n = n;
  double **arr[] = {&p->x, &p->y, &p->z, &p->nx, &p->ny, &p->nz, &p->w};
  for (size_t k = 0; k < sizeof arr / sizeof *arr; k++) *arr[k] = malloc(sizeof(double) * m);
  p->rho = malloc(sizeof(double) * 3 * m);
  p->e = malloc(sizeof(double) * 3 * m);
  p->tri = malloc(sizeof(int) * m);
  if (!p->x || !p->y || !p->z || !p->nx || !p->ny || !p->nz || !p->w || !p->rho || !p->e || !p->tri) {
    surfels_free(p);
    return -1;
  }
  return 0;
}

void surfels_free(Surfels *p) {
  free(p->x), free(p->y), free(p->z), free(p->nx), free(p->ny), free(p->nz), free(p->w);
  free(p->rho), free(p->e), free(p->tri);
  memset(p, 0, sizeof *p);
}

static double tri_area(const TriScene *s, int t, double nrm[3]) {
  const double *a = s->v + 3 * s->tri[3 * t], *b = s->v + 3 * s->tri[3 * t + 1], *c = s->v + 3 * s->tri[3 * t + 2];
  double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  double cr[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
  double len = sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
  for (int k = 0; k < 3; k++) nrm[k] = len > 0 ? cr[k] / len : 0;
  return 0.5 * len;
}

/* A small deterministic generator for the lattice shifts (splitmix64). */
static double unit_random(unsigned long long *state) {
  unsigned long long z = (*state += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  z ^= z >> 31;
  return (double)(z >> 11) * 0x1.0p-53;
}

int scene_sample(const TriScene *s, long n, unsigned seed, Surfels *out) {
  if (n < 1 || s->nt < 1) return -1;
  double *area = malloc(sizeof(double) * (size_t)s->nt), *frac = malloc(sizeof(double) * (size_t)s->nt);
  long *count = malloc(sizeof(long) * (size_t)s->nt);
  if (!area || !frac || !count || surfels_alloc(out, n)) {
    free(area), free(frac), free(count);
    return -1;
  }
  double total = 0, nrm[3];
  for (int t = 0; t < s->nt; t++) total += area[t] = tri_area(s, t, nrm);
  long assigned = 0;
  for (int t = 0; t < s->nt; t++) {
    double share = (double)n * area[t] / total;
    count[t] = (long)floor(share);
    frac[t] = share - (double)count[t];
    assigned += count[t];
  }
  /* largest remainders, ties to the lower index */
  while (assigned < n) {
    int best = 0;
    for (int t = 1; t < s->nt; t++)
      if (frac[t] > frac[best]) best = t;
    count[best]++, frac[best] = -1, assigned++;
  }
  unsigned long long state = 0x5eed0000ULL + seed;
  const double golden = 0.6180339887498949;
  long k = 0;
  for (int t = 0; t < s->nt; t++) {
    if (count[t] == 0) continue;
    const double *a = s->v + 3 * s->tri[3 * t], *b = s->v + 3 * s->tri[3 * t + 1], *c = s->v + 3 * s->tri[3 * t + 2];
    tri_area(s, t, nrm);
    double shift_u = unit_random(&state), shift_v = unit_random(&state);
    for (long i = 0; i < count[t]; i++, k++) {
      double r1 = fmod(((double)i + shift_u) / (double)count[t], 1.0);
      double r2 = fmod((double)i * golden + shift_v, 1.0);
      double sq = sqrt(r1), l0 = 1 - sq, l1 = sq * (1 - r2), l2 = sq * r2; /* area-preserving warp */
      out->x[k] = l0 * a[0] + l1 * b[0] + l2 * c[0];
      out->y[k] = l0 * a[1] + l1 * b[1] + l2 * c[1];
      out->z[k] = l0 * a[2] + l1 * b[2] + l2 * c[2];
      out->nx[k] = nrm[0], out->ny[k] = nrm[1], out->nz[k] = nrm[2];
      out->w[k] = area[t] / (double)count[t];
      for (int ch = 0; ch < 3; ch++) out->rho[3 * k + ch] = s->albedo[3 * t + ch], out->e[3 * k + ch] = s->emission[3 * t + ch];
      out->tri[k] = t;
    }
  }
  free(area), free(frac), free(count);
  return 0;
}
