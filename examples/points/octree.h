/* octree.h — the adaptive octree of the FMM (paper 002 §2.2.3, step 1).
 *
 * octree_build reorders the surfels so that every node owns a contiguous
 * range of them, splits every cube holding more than `leaf_size` points into
 * its non-empty octants, and numbers the nodes breadth first, so the nodes
 * of one level are contiguous and a parent precedes its children.
 *
 * Node 0 is a grouping root: its children are one octree per orientation
 * group (the dominant axis of the normal and its sign, ±x ±y ±z), all over
 * the same root cube at level 0. The radiosity kernel is clamped where
 * points face away, and expansions may only join points that all face the
 * target; grouping by orientation keeps the normal cone of every cube narrow
 * so that far cubes are provably facing (fmm.c). Node 0 has no expansion. */
#ifndef POINTS_OCTREE_H
#define POINTS_OCTREE_H

#include "surfels.h"

typedef struct OctNode {
  double c[3], h;     /* the cube: centre and half width */
  int level;          /* root 0 */
  int parent;         /* -1 at the root */
  int child[8];       /* by octant (bit 0: x, 1: y, 2: z), -1 when empty */
  int nchild;
  long start, count;  /* the points [start, start + count) */
  int leaf_first, nleaf; /* its leaves: leaf order is point order */
  double lo[3], hi[3];   /* tight box of its points */
  double axis[3];        /* normal cone: unit axis ... */
  double spread;         /* ... and 2 sin(α/2) ≥ |n − axis| for every normal n in the node */
} OctNode;

typedef struct Octree {
  int nnode, nleaf, depth;
  OctNode *node;  /* breadth first: node 0 is the root */
  int *leaf;      /* nleaf node ids in point order */
  int *level_first; /* depth + 2 entries: the nodes of level l are [level_first[l], level_first[l+1]) */
  long *perm;     /* perm[k]: the original index of the point now at k */
  int leaf_size;
  int grouped;    /* node 0 is the grouping root (always, from octree_build) */
} Octree;

/* Build the tree of `s` (reordered in place; `perm` records how). The root
 * is the smallest cube around the points, grown by a relative 1e-9 so no
 * point sits on its faces; splitting stops at depth 30 whatever `leaf_size`.
 * 0, or -1 when out of memory (then `s` may be partly reordered). */
int octree_build(Surfels *s, int leaf_size, Octree *t);
void octree_free(Octree *t);

static inline int octree_is_leaf(const OctNode *n) { return n->nchild == 0; }

#endif
