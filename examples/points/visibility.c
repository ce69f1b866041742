/* visibility.c — point-based visibility and the Embree reference
 * (visibility.h). */
#include "visibility.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

void visibility_init(Visibility *v, const Surfels *s, const Octree *t) {
  memset(v, 0, sizeof *v);
  v->s = s, v->t = t;
  v->radius_scale = 0.8;
  double wmax = 0;
  for (long i = 0; i < s->n; i++) wmax = fmax(wmax, s->w[i]);
  v->delta = 1.25 * v->radius_scale * sqrt(wmax);
  v->samples_far = 4;
  v->samples_leaf = 8;
}

/* Does the segment p + t d, t ∈ [0, 1], meet the box [lo − r, hi + r]? */
static int segment_meets_box(const double p[3], const double d[3], const double lo[3], const double hi[3], double r) {
  double t0 = 0, t1 = 1;
  for (int k = 0; k < 3; k++) {
    double a = lo[k] - r - p[k], b = hi[k] + r - p[k];
    if (fabs(d[k]) < 1e-300) {
      if (a > 0 || b < 0) return 0;
      continue;
    }
    double ta = a / d[k], tb = b / d[k];
    if (ta > tb) {
      double x = ta;
      ta = tb, tb = x;
    }
    if (ta > t0) t0 = ta;
    if (tb < t1) t1 = tb;
    if (t0 > t1) return 0;
  }
  return 1;
}

/* The ramp of §2.2.4.1's "visibility look up": how much an occluder whose
 * tangent plane is crossed at `ratio` disc radii from it lets through. */
static double pass_fraction(double ratio) {
  double x = (ratio - 0.75) / 0.5;
  return x <= 0 ? 0 : x >= 1 ? 1 : x;
}

int visibility_points(const Visibility *v, long ip, long iq) {
  const Surfels *s = v->s;
  const Octree *t = v->t;
  double p[3] = {s->x[ip], s->y[ip], s->z[ip]}, q[3] = {s->x[iq], s->y[iq], s->z[iq]};
  double d[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
  double cos_p = s->nx[ip] * d[0] + s->ny[ip] * d[1] + s->nz[ip] * d[2];
  double cos_q = -(s->nx[iq] * d[0] + s->ny[iq] * d[1] + s->nz[iq] * d[2]);
  if (cos_p <= 0 || cos_q <= 0) return 0; /* FacingEachOther */
  double len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
  double delta = v->delta, best[3] = {INFINITY, INFINITY, INFINITY};
  int stack[128], top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const OctNode *nd = &t->node[stack[--top]];
    if (!segment_meets_box(p, d, nd->lo, nd->hi, delta)) continue;
    if (!octree_is_leaf(nd)) {
      for (int o = 0; o < 8; o++)
        if (nd->child[o] >= 0 && top < 128) stack[top++] = nd->child[o];
      continue;
    }
    for (long j = nd->start; j < nd->start + nd->count; j++) {
      if (j == ip || j == iq) continue;
      double x[3] = {s->x[j] - p[0], s->y[j] - p[1], s->z[j] - p[2]};
      /* within Δ of the segment */
      double tt = (x[0] * d[0] + x[1] * d[1] + x[2] * d[2]) / len2;
      double tc = tt < 0 ? 0 : tt > 1 ? 1 : tt;
      double e0 = x[0] - tc * d[0], e1 = x[1] - tc * d[1], e2 = x[2] - tc * d[2];
      if (e0 * e0 + e1 * e1 + e2 * e2 > delta * delta) continue;
      /* its tangent plane must cut pq strictly inside */
      double denom = s->nx[j] * d[0] + s->ny[j] * d[1] + s->nz[j] * d[2];
      if (fabs(denom) < 1e-9 * sqrt(len2)) continue;
      double tp = (s->nx[j] * x[0] + s->ny[j] * x[1] + s->nz[j] * x[2]) / denom;
      if (tp <= 1e-6 || tp >= 1 - 1e-6) continue;
      /* distance along the tangent plane, in disc radii */
      double c0 = tp * d[0] - x[0], c1 = tp * d[1] - x[1], c2 = tp * d[2] - x[2];
      double ratio = sqrt(c0 * c0 + c1 * c1 + c2 * c2) / (v->radius_scale * sqrt(s->w[j]));
      if (ratio >= 1.25) continue;
      if (ratio <= 0.75) return 0; /* a full occluder: the product is 0 */
      if (ratio < best[2]) { /* keep the three closest */
        best[2] = ratio;
        for (int k = 2; k > 0 && best[k] < best[k - 1]; k--) {
          double x2 = best[k];
          best[k] = best[k - 1], best[k - 1] = x2;
        }
      }
    }
  }
  double visible = 1;
  for (int k = 0; k < 3; k++)
    if (isfinite(best[k])) visible *= pass_fraction(best[k]);
  return visible > 0.5;
}

double visibility_nodes(const Visibility *v, int ia, int ib, int m, int *nfacing) {
  const OctNode *a = &v->t->node[ia], *b = &v->t->node[ib];
  const Surfels *s = v->s;
  long ma = a->count < m ? a->count : m, mb = b->count < m ? b->count : m;
  int facing = 0, visible = 0;
  for (long u = 0; u < ma; u++) {
    long i = a->start + (2 * u + 1) * a->count / (2 * ma);
    for (long w = 0; w < mb; w++) {
      long j = b->start + (2 * w + 1) * b->count / (2 * mb);
      double d[3] = {s->x[j] - s->x[i], s->y[j] - s->y[i], s->z[j] - s->z[i]};
      if (s->nx[i] * d[0] + s->ny[i] * d[1] + s->nz[i] * d[2] <= 0) continue;
      if (s->nx[j] * d[0] + s->ny[j] * d[1] + s->nz[j] * d[2] >= 0) continue;
      facing++;
      visible += visibility_points(v, i, j);
    }
  }
  *nfacing = facing;
  return facing ? (double)visible / facing : 1.0;
}

/* ------------------------------------------------------------ Embree reference */

static void embree_error(void *user, enum RTCError code, const char *str) {
  (void)user;
  fprintf(stderr, "npg-points: embree error %d: %s\n", (int)code, str ? str : "");
}

int raycast_open(RayCaster *rc, const TriScene *scene) {
  memset(rc, 0, sizeof *rc);
  RTCDevice dev = rtcNewDevice(NULL);
  if (!dev) {
    fprintf(stderr, "npg-points: embree: no device (error %d)\n", (int)rtcGetDeviceError(NULL));
    return -1;
  }
  rtcSetDeviceErrorFunction(dev, embree_error, NULL);
  RTCScene sc = rtcNewScene(dev);
  RTCGeometry geom = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                      (size_t)scene->nv);
  unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                         (size_t)scene->nt);
  if (!sc || !geom || !vb || !ib) {
    if (geom) rtcReleaseGeometry(geom);
    if (sc) rtcReleaseScene(sc);
    rtcReleaseDevice(dev);
    return -1;
  }
  for (int k = 0; k < 3 * scene->nv; k++) vb[k] = (float)scene->v[k];
  for (int k = 0; k < 3 * scene->nt; k++) ib[k] = (unsigned)scene->tri[k];
  rtcCommitGeometry(geom);
  rtcAttachGeometry(sc, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(sc);
  rc->device = dev, rc->scene = sc;
  return 0;
}

void raycast_close(RayCaster *rc) {
  if (rc->scene) rtcReleaseScene((RTCScene)rc->scene);
  if (rc->device) rtcReleaseDevice((RTCDevice)rc->device);
  memset(rc, 0, sizeof *rc);
}

int raycast_points(const RayCaster *rc, const Surfels *s, long ip, long iq) {
  const double eps = 1e-5;
  double p[3] = {s->x[ip] + eps * s->nx[ip], s->y[ip] + eps * s->ny[ip], s->z[ip] + eps * s->nz[ip]};
  double q[3] = {s->x[iq] + eps * s->nx[iq], s->y[iq] + eps * s->ny[iq], s->z[iq] + eps * s->nz[iq]};
  struct RTCRay ray;
  memset(&ray, 0, sizeof ray);
  ray.org_x = (float)p[0], ray.org_y = (float)p[1], ray.org_z = (float)p[2];
  ray.dir_x = (float)(q[0] - p[0]), ray.dir_y = (float)(q[1] - p[1]), ray.dir_z = (float)(q[2] - p[2]);
  ray.tnear = 1e-4f, ray.tfar = 1.0f - 1e-4f;
  ray.mask = 0xffffffffu, ray.flags = 0;
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  rtcOccluded1((RTCScene)rc->scene, &ctx, &ray);
  return ray.tfar >= 0; /* −inf when something was hit */
}
