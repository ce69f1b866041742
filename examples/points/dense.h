/* dense.h — the O(N²) gather (the reference and the brute-force peer) and
 * the radiosity iteration b = e + ρ g(b) (paper 002 §2.2.3, "we iterate"). */
#ifndef POINTS_DENSE_H
#define POINTS_DENSE_H

#include "octree.h"

/* g (n x 3) = Σ_j K(x_i, y_j) v_ij w_j b_j over all pairs, in the tree's
 * point order, v_ij = vis[leaf(i) * nleaf + leaf(j)] (fmm_leaf_visibility;
 * NULL: 1). Threads over targets; the inner loop over sources vectorizes. */
void dense_gather(const Surfels *s, const Octree *t, const float *vis, const double *b, double *g);

/* The same with a visibility bit per pair: bit i·n + j of `bits`. */
void dense_gather_bits(const Surfels *s, const unsigned char *bits, const double *b, double *g);

typedef void (*GatherFn)(void *ctx, const double *b, double *g);

/* Jacobi: b ← e + ρ ⊙ gather(b) from b = e until the relative change
 * ‖Δb‖/‖b‖ ≤ `tol` or `max_iter` sweeps; returns the sweeps made (−1 when
 * out of memory). `b` (n x 3) holds the result. */
int radiosity_jacobi(const Surfels *s, GatherFn gather, void *ctx, double tol, int max_iter, double *b);

#endif
