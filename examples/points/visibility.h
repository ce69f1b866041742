/* visibility.h — point-based visibility (paper 002 §2.2.4) and its exact
 * reference, ray casting against the source triangles with Embree 3.
 *
 * Point–point (§2.2.4.1): p and q must face each other; the possible
 * occluders are the points within Δ of the segment pq whose tangent plane
 * cuts pq strictly between p and q; each is scored by the distance, in its
 * tangent plane, from the point to where pq crosses the plane, relative to
 * its disc radius r = radius_scale·√w; the three closest give factors of a
 * ramp (0 below 0.75 r, 1 above 1.25 r) whose product, above 1/2, means
 * visible. Node–node (§2.2.4.3–5) samples `m` points of each node evenly in
 * point order and tests the m² pairs that face each other; fmm_plan turns
 * the visible fraction into valid (1), invalid (0) or partial. */
#ifndef POINTS_VISIBILITY_H
#define POINTS_VISIBILITY_H

#include "octree.h"

typedef struct Visibility {
  const Surfels *s;
  const Octree *t;
  double radius_scale; /* disc radius r = radius_scale * sqrt(w) (0.8) */
  double delta;        /* search radius Δ around pq: 1.25 x the largest r */
  int samples_far;     /* m for a pair of cubes (4) */
  int samples_leaf;    /* m for a pair of leaves (8) */
} Visibility;

void visibility_init(Visibility *v, const Surfels *s, const Octree *t);

/* 1 when surfels `p` and `q` face each other and see each other. */
int visibility_points(const Visibility *v, long p, long q);

/* The visible fraction of the facing pairs among m x m samples of nodes `a`
 * and `b`; `*nfacing` gets how many faced (the fraction is 1 when none). */
double visibility_nodes(const Visibility *v, int a, int b, int m, int *nfacing);

/* The reference: Embree 3 ray casting against a triangle scene. */
typedef struct RayCaster {
  void *device, *scene; /* RTCDevice, RTCScene */
} RayCaster;

/* 0, or -1 when Embree cannot start (message on stderr). */
int raycast_open(RayCaster *rc, const TriScene *scene);
void raycast_close(RayCaster *rc);

/* 1 when nothing of the scene lies strictly between surfels p and q of `s`
 * (the segment is shortened by 1e-6 of the scene size at both ends; facing
 * is not tested: the kernel's clamp does that). */
int raycast_points(const RayCaster *rc, const Surfels *s, long p, long q);

#endif
