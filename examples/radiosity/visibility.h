/* visibility.h — the visibility v_ij of every pair of faces of a triangle mesh, by ray
 * casting with Embree 3 (paper §8.3: visibility is the extern stage of the radiosity
 * program; the full frame computes it, training records it).
 *
 * How v is sampled, and why. Every triangle carries a fixed set of k = 4^m stratified
 * points: the centroids of the 4^m triangles of its m-fold midpoint subdivision (k = 1 is
 * the centroid itself). The pair (i, j) is joined by k segments, point s of i to point
 * k-1-s of j (an involution, so v_ij = v_ji), and v_ij is the fraction of those segments
 * that leave the front of both faces and reach the other face unoccluded. Where either
 * face lies behind the other at the centroids (n_i . (c_j - c_i) <= 0 or
 * n_j . (c_i - c_j) <= 0, the cosines of the form factor, Eq. 15) v_ij = 0, and v_ii = 0.
 * "Front" means a cosine above 1e-9, so that two faces of one flat wall (cosines 0, or
 * ±1e-16 after rounding) get v = 0 whatever the rounding.
 *   - Several points, not the centroid alone: a binary centroid-to-centroid test flips
 *     whole form factors on and off as the door or a window edge sweeps across a segment;
 *     the fraction changes in steps of 1/k instead, which is both closer to the true
 *     (area-averaged) visibility and easier for the learned visibility model of §8.3.
 *   - Deterministic points (no random jitter): v must be a function of g alone, the same on
 *     every call, so that training snapshots and held-out frames agree and a rerun
 *     reproduces them.
 *   - Segments, not one ray per point pair of a k x k product: k rays per pair keep the
 *     cost at k F^2 / 2 rays; the stratification spreads the k segments over both faces.
 * Segments start and end a distance 1e-4 x (the scene's bounding diagonal) inside their
 * endpoints, so neither endpoint's own face nor a face sharing its edge counts as a blocker.
 *
 * vis_compute() is callable per sample (g in, v out) and keeps the Embree scene between
 * calls (vertex positions are updated and the BVH rebuilt each call), so it can be the
 * callback of the visibility extern during training. One Visibility is not to be used by
 * two threads at once; it runs `threads` workers of its own. */
#ifndef RADIOSITY_VISIBILITY_H
#define RADIOSITY_VISIBILITY_H

#include <stddef.h>

typedef enum VisMode {
  VIS_SINGLE, /* rtcOccluded1, one ray at a time */
  VIS_STREAM, /* rtcOccluded1M, a stream of the rays of a block of pairs */
  VIS_PACKET, /* rtcOccluded8, packets of 8 rays */
} VisMode;

typedef struct Visibility Visibility;

/* A caster for meshes of V vertices and F triangles `tri` (F x 3, copied), with k
 * stratified points per face (k = 1, 4 or 16) and `threads` workers (>= 1). NULL on
 * failure with the reason in err. */
Visibility *vis_new(long V, long F, const int *tri, int k, int threads, VisMode mode, char *err, size_t errlen);
/* v (F x F, row-major) for vertex positions g (V x 3). 0, or -1 with the reason in err
 * (an Embree error). */
int vis_compute(Visibility *vis, const double *g, double *v, char *err, size_t errlen);
/* Rays cast by the last vis_compute. */
long vis_rays(const Visibility *vis);
void vis_free(Visibility *vis);
const char *vis_mode_name(VisMode m);

#endif
