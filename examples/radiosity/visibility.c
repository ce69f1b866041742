/* visibility.c — pair visibility by ray casting with Embree 3 (visibility.h). */
#include "util.h"
#include "visibility.h"
#include "npg.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { BLOCK_RAYS = 256 }; /* rays per stream call */

struct Visibility {
  long V, F;
  int *tri;
  int k, threads;
  VisMode mode;
  RTCDevice device;
  RTCScene scene;
  RTCGeometry geom;
  float *vert;     /* Embree's vertex buffer (V x 3 floats, padded) */
  double *pts;     /* F x k x 3 sample points */
  double *nrm;     /* F x 3 area vectors */
  double *nlen;    /* F: their lengths */
  double *cen;     /* F x 3 centroids */
  double delta;    /* endpoint offset (absolute) */
  double *v;       /* output of the current call */
  atomic_long next_row;
  atomic_long rays;
  char error[256];
};

const char *vis_mode_name(VisMode m) {
  return m == VIS_SINGLE ? "single (rtcOccluded1)" : m == VIS_STREAM ? "stream (rtcOccluded1M)" : "packet (rtcOccluded8)";
}

static void on_error(void *user, enum RTCError code, const char *str) {
  Visibility *vis = user;
  if (!vis->error[0]) snprintf(vis->error, sizeof vis->error, "embree error %d: %s", (int)code, str ? str : "");
}

Visibility *vis_new(long V, long F, const int *tri, int k, int threads, VisMode mode, char *err, size_t errlen) {
  if (k != 1 && k != 4 && k != 16) {
    npg_error_set(err, errlen, "visibility samples per face must be 1, 4 or 16 (got %d)", k);
    return NULL;
  }
  Visibility *vis = calloc(1, sizeof *vis);
  if (!vis) return NULL;
  vis->V = V;
  vis->F = F;
  vis->k = k;
  vis->threads = threads < 1 ? 1 : threads;
  vis->mode = mode;
  vis->tri = malloc(sizeof(int) * 3 * F);
  vis->pts = malloc(sizeof(double) * 3 * F * k);
  vis->nrm = malloc(sizeof(double) * 3 * F);
  vis->nlen = malloc(sizeof(double) * F);
  vis->cen = malloc(sizeof(double) * 3 * F);
  if (!vis->tri || !vis->pts || !vis->nrm || !vis->nlen || !vis->cen) {
    vis_free(vis);
    npg_error_set(err, errlen, "out of memory");
    return NULL;
  }
  memcpy(vis->tri, tri, sizeof(int) * 3 * F);
  char config[64];
  snprintf(config, sizeof config, "threads=%d", vis->threads);
  vis->device = rtcNewDevice(config);
  if (!vis->device) {
    npg_error_set(err, errlen, "embree: cannot create a device (error %d)", (int)rtcGetDeviceError(NULL));
    vis_free(vis);
    return NULL;
  }
  rtcSetDeviceErrorFunction(vis->device, on_error, vis);
  vis->scene = rtcNewScene(vis->device);
  rtcSetSceneBuildQuality(vis->scene, RTC_BUILD_QUALITY_MEDIUM);
  vis->geom = rtcNewGeometry(vis->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  vis->vert = rtcSetNewGeometryBuffer(vis->geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), V);
  unsigned *ib = rtcSetNewGeometryBuffer(vis->geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), F);
  if (!vis->vert || !ib || vis->error[0]) {
    npg_error_set(err, errlen, "%s", vis->error[0] ? vis->error : "embree: cannot allocate buffers");
    vis_free(vis);
    return NULL;
  }
  for (long i = 0; i < 3 * F; i++) ib[i] = (unsigned)tri[i];
  rtcAttachGeometry(vis->scene, vis->geom); /* committed with its vertices in vis_compute */
  return vis;
}

void vis_free(Visibility *vis) {
  if (!vis) return;
  if (vis->geom) rtcReleaseGeometry(vis->geom);
  if (vis->scene) rtcReleaseScene(vis->scene);
  if (vis->device) rtcReleaseDevice(vis->device);
  free(vis->tri);
  free(vis->pts);
  free(vis->nrm);
  free(vis->nlen);
  free(vis->cen);
  free(vis);
}

long vis_rays(const Visibility *vis) { return atomic_load(&vis->rays); }

/* The k points of a triangle: centroids of its m-fold midpoint subdivision, in a fixed
 * order (recursively: the three corner triangles, then the middle one). */
static void subdivide(const double *a, const double *b, const double *c, int k, double *out) {
  if (k == 1) {
    for (int d = 0; d < 3; d++) out[d] = (a[d] + b[d] + c[d]) / 3;
    return;
  }
  double ab[3], bc[3], ca[3];
  for (int d = 0; d < 3; d++) {
    ab[d] = 0.5 * (a[d] + b[d]);
    bc[d] = 0.5 * (b[d] + c[d]);
    ca[d] = 0.5 * (c[d] + a[d]);
  }
  int q = k / 4;
  subdivide(a, ab, ca, q, out);
  subdivide(ab, b, bc, q, out + 3 * q);
  subdivide(ca, bc, c, q, out + 6 * q);
  subdivide(bc, ca, ab, q, out + 9 * q);
}

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* Whether d leaves face i's front and arrives at face j's front: both cosines above
 * COS_MIN. Not > 0: two faces of one flat wall have cosines of exactly 0 in exact
 * arithmetic and of ±1e-16 in floating point, and v must not depend on rounding noise
 * (the learned visibility of §8.3 sees every entry); a cosine of 1e-9 contributes 1e-9 of
 * a form factor, nothing. */
#define COS_MIN 1e-9

static int fronts(const Visibility *vis, long i, long j, const double *d) {
  double L = sqrt(dot3(d, d));
  return dot3(vis->nrm + 3 * i, d) > COS_MIN * vis->nlen[i] * L && -dot3(vis->nrm + 3 * j, d) > COS_MIN * vis->nlen[j] * L;
}

/* One segment of pair (i, j): fills `ray` and returns 1, or returns 0 when the segment
 * leaves either face from behind (it counts as blocked). */
static int segment(const Visibility *vis, long i, long j, int s, struct RTCRay *ray) {
  const double *x = vis->pts + 3 * ((size_t)i * vis->k + s);
  const double *y = vis->pts + 3 * ((size_t)j * vis->k + (vis->k - 1 - s));
  double d[3] = {y[0] - x[0], y[1] - x[1], y[2] - x[2]};
  if (!fronts(vis, i, j, d)) return 0;
  double L = sqrt(dot3(d, d)), t0 = vis->delta / L;
  if (t0 >= 0.25) t0 = 0.25;
  ray->org_x = (float)x[0];
  ray->org_y = (float)x[1];
  ray->org_z = (float)x[2];
  ray->dir_x = (float)d[0];
  ray->dir_y = (float)d[1];
  ray->dir_z = (float)d[2];
  ray->tnear = (float)t0;
  ray->tfar = (float)(1 - t0);
  ray->time = 0;
  ray->mask = 0xFFFFFFFFu;
  ray->id = 0;
  ray->flags = 0;
  return 1;
}

/* Whether the faces are in front of each other at their centroids (Eq. 15's cosines). */
static int facing(const Visibility *vis, long i, long j) {
  const double *ci = vis->cen + 3 * i, *cj = vis->cen + 3 * j;
  double d[3] = {cj[0] - ci[0], cj[1] - ci[1], cj[2] - ci[2]};
  return fronts(vis, i, j, d);
}

static void put(Visibility *vis, long i, long j, double value) {
  vis->v[(size_t)i * vis->F + j] = value;
  vis->v[(size_t)j * vis->F + i] = value;
}

/* Row i (pairs j > i), one ray at a time. */
static long row_single(Visibility *vis, long i) {
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  long rays = 0;
  for (long j = i + 1; j < vis->F; j++) {
    if (!facing(vis, i, j)) {
      put(vis, i, j, 0);
      continue;
    }
    int open = 0;
    for (int s = 0; s < vis->k; s++) {
      struct RTCRay ray;
      if (!segment(vis, i, j, s, &ray)) continue;
      rtcOccluded1(vis->scene, &ctx, &ray);
      rays++;
      open += ray.tfar >= 0;
    }
    put(vis, i, j, (double)open / vis->k);
  }
  return rays;
}

/* Row i as streams of up to BLOCK_RAYS rays (rtcOccluded1M). */
static long row_stream(Visibility *vis, long i) {
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  struct RTCRay ray[BLOCK_RAYS];
  long pair[BLOCK_RAYS];
  long rays = 0, j = i + 1;
  while (j < vis->F) {
    int n = 0;
    for (; j < vis->F && n + vis->k <= BLOCK_RAYS; j++) {
      put(vis, i, j, 0);
      if (!facing(vis, i, j)) continue;
      for (int s = 0; s < vis->k; s++)
        if (segment(vis, i, j, s, &ray[n])) pair[n++] = j;
    }
    if (n) rtcOccluded1M(vis->scene, &ctx, ray, (unsigned)n, sizeof(struct RTCRay));
    rays += n;
    for (int r = 0; r < n; r++)
      if (ray[r].tfar >= 0) {
        size_t at = (size_t)i * vis->F + pair[r];
        vis->v[at] += 1.0 / vis->k;
        vis->v[(size_t)pair[r] * vis->F + i] = vis->v[at];
      }
  }
  return rays;
}

/* Row i in packets of 8 rays (rtcOccluded8). */
static long row_packet(Visibility *vis, long i) {
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  long rays = 0, j = i + 1, pair[8];
  int s = 0;
  for (long f = i + 1; f < vis->F; f++) put(vis, i, f, 0);
  while (j < vis->F) {
    struct RTCRay8 pk; /* RTC_ALIGN(32) by its type */
    /* rtcOccluded8's valid mask must be 32-byte aligned like the packet
       (Embree's contract); the stack gives no such guarantee for int[8]. */
    _Alignas(32) int valid[8];
    int n = 0;
    while (n < 8 && j < vis->F) {
      if (s == 0 && !facing(vis, i, j)) {
        j++;
        continue;
      }
      struct RTCRay r;
      if (segment(vis, i, j, s, &r)) {
        pk.org_x[n] = r.org_x, pk.org_y[n] = r.org_y, pk.org_z[n] = r.org_z, pk.tnear[n] = r.tnear;
        pk.dir_x[n] = r.dir_x, pk.dir_y[n] = r.dir_y, pk.dir_z[n] = r.dir_z, pk.time[n] = 0;
        pk.tfar[n] = r.tfar, pk.mask[n] = 0xFFFFFFFFu, pk.id[n] = 0, pk.flags[n] = 0;
        pair[n++] = j;
      }
      if (++s == vis->k) s = 0, j++;
    }
    if (!n) break;
    for (int q = 0; q < 8; q++) valid[q] = q < n ? -1 : 0;
    rtcOccluded8(valid, vis->scene, &ctx, &pk);
    rays += n;
    for (int q = 0; q < n; q++)
      if (pk.tfar[q] >= 0) {
        size_t at = (size_t)i * vis->F + pair[q];
        vis->v[at] += 1.0 / vis->k;
        vis->v[(size_t)pair[q] * vis->F + i] = vis->v[at];
      }
  }
  return rays;
}

/* Rows are handed out one at a time (their lengths F - 1 - i differ). */
static void *worker(void *arg) {
  Visibility *vis = arg;
  long rays = 0;
  for (;;) {
    long i = atomic_fetch_add(&vis->next_row, 1);
    if (i >= vis->F) break;
    vis->v[(size_t)i * vis->F + i] = 0;
    rays += vis->mode == VIS_SINGLE ? row_single(vis, i) : vis->mode == VIS_STREAM ? row_stream(vis, i) : row_packet(vis, i);
  }
  atomic_fetch_add(&vis->rays, rays);
  return NULL;
}

int vis_compute(Visibility *vis, const double *g, double *v, char *err, size_t errlen) {
  long F = vis->F;
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (long a = 0; a < vis->V; a++)
    for (int d = 0; d < 3; d++) {
      double x = g[3 * a + d];
      if (!isfinite(x)) return npg_error_set(err, errlen, "visibility: vertex %ld is not finite", a);
      vis->vert[3 * a + d] = (float)x;
      lo[d] = fmin(lo[d], x);
      hi[d] = fmax(hi[d], x);
    }
  double diag = 0;
  for (int d = 0; d < 3; d++) diag += (hi[d] - lo[d]) * (hi[d] - lo[d]);
  vis->delta = 1e-4 * sqrt(diag);
  for (long f = 0; f < F; f++) {
    const int *t = vis->tri + 3 * f;
    const double *a = g + 3 * t[0], *b = g + 3 * t[1], *c = g + 3 * t[2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double *n = vis->nrm + 3 * f;
    n[0] = 0.5 * (u[1] * w[2] - u[2] * w[1]);
    n[1] = 0.5 * (u[2] * w[0] - u[0] * w[2]);
    n[2] = 0.5 * (u[0] * w[1] - u[1] * w[0]);
    vis->nlen[f] = sqrt(dot3(n, n));
    for (int d = 0; d < 3; d++) vis->cen[3 * f + d] = (a[d] + b[d] + c[d]) / 3;
    subdivide(a, b, c, vis->k, vis->pts + 3 * (size_t)f * vis->k);
  }
  vis->error[0] = 0;
  rtcUpdateGeometryBuffer(vis->geom, RTC_BUFFER_TYPE_VERTEX, 0);
  rtcCommitGeometry(vis->geom);
  rtcCommitScene(vis->scene);
  if (vis->error[0]) return npg_error_set(err, errlen, "%s", vis->error);
  vis->v = v;
  atomic_store(&vis->next_row, 0);
  atomic_store(&vis->rays, 0);
  pthread_t th[64];
  int nt = vis->threads > 64 ? 64 : vis->threads, started = 0;
  for (int t = 1; t < nt; t++)
    if (pthread_create(&th[started], NULL, worker, vis) == 0) started++;
  worker(vis);
  for (int t = 0; t < started; t++) pthread_join(th[t], NULL);
  vis->v = NULL;
  if (vis->error[0]) return npg_error_set(err, errlen, "%s", vis->error);
  return 0;
}
