/* fmm.h — the FMM gather of paper 002 §2.2.3 with point-based visibility
 * in its interaction lists (§2.2.4.6):
 *
 *   g_i = Σ_j K(x_i, y_j) v_ij w_j b_j        (kernel.h for K)
 *
 * Expansions are kernel-independent (Fong & Darve's black-box FMM): the
 * tensor H(x − y) of kernel.h is interpolated on p x p x p Chebyshev nodes
 * of the source cube and of the target cube, so
 *
 *   multipole  M_m,b,c = Σ_j S_m(y_j) n_y,j,b w_j b_j,c    (node m, normal
 *              component b, colour c: 3p³ x 3 numbers per node)
 *   M2L        L_l,a,c += Σ_m,b H_ab(x̄_l − ȳ_m) M_m,b,c   (one 3p³ x 3p³
 *              matrix K_o per relative position o of two cubes of one
 *              level, scaled by 1/h² at half width h because H is
 *              homogeneous), compressed as in Fong & Darve §3: K_o ≈
 *              U (Uᵀ K_o U) Uᵀ with one basis U of r columns, the dominant
 *              left singular vectors of [K_o] over the 316 positions of the
 *              plain interaction list (the right ones are the same: K_oᵀ =
 *              K_−o), so an M2L is an r x r product on the projected
 *              expansions Uᵀ M, and the local expansion gets U times their
 *              sum; r keeps singular values above 10^(1−p) of the largest
 *              (p ≤ 5; higher orders keep the dense matrices)
 *   evaluation g_i,c  = Σ_l,a S_l(x_i) n_x,i,a L_l,a,c.
 *
 * The octree is traversed as a dual tree from (root, root): a pair of cubes
 * separated by at least the larger one's width whose points all face each
 * other (normal cones and boxes, kernel.h) and, with visibility, whose
 * sampled point pairs are all visible is "valid" and becomes an M2L (same
 * level), M2P or P2L (a leaf against a smaller cube); a pair that cannot
 * see or face at all is dropped; anything else is split, and two leaves
 * that are left interact directly (P2P), with the kernel clamped per pair
 * and the pair's visible fraction as v (§2.2.4.4: leaves are the finest
 * visibility), in single precision (the sum over one source node is
 * short; its rounding, ~1e-6 relative, is far below the expansions'). fmm_plan builds those lists once; fmm_gather runs them. */
#ifndef POINTS_FMM_H
#define POINTS_FMM_H

#include <stddef.h>

#include "octree.h"
#include "visibility.h"

typedef struct FmmPair {
  int tgt, src;
  int key;  /* M2L: the relative position of the cubes, encoded */
  float v;  /* visible fraction applied to the interaction */
} FmmPair;

typedef struct FmmList {
  FmmPair *pair;
  long n, cap;
  long *first; /* after fmm_plan: CSR over targets (leaves for P2P/M2P, nodes for P2L) */
} FmmList;

typedef struct FmmStats {
  long m2l, m2p, p2l, p2p, p2p_points; /* list lengths; point pairs P2P evaluates */
  long dropped_facing, dropped_hidden;  /* pairs dropped: nothing faces / nothing visible */
  long m2l_offsets;                     /* distinct M2L matrices */
  long visibility_tests;                /* point–point visibility tests */
  double plan_seconds;
} FmmStats;

typedef struct Fmm {
  const Surfels *s;
  const Octree *t;
  int p, p3;       /* order, p³ */
  double cheb[16]; /* the p Chebyshev nodes cos((2k+1)π/2p) */
  double *m2m[8];  /* p³ x p³, column-major: child octant o's nodes in the parent's interpolant */
  FmmList m2l, m2p, p2l, p2p;
  int nkeys;
  int *key;        /* distinct M2L keys, ascending; the m2l list is sorted by key */
  long *key_first; /* nkeys + 1 */
  int rank;        /* r: columns of U (3p³ when U is NULL) */
  double *U;       /* 3p³ x r, orthonormal columns (column-major); NULL: no compression */
  double **op;     /* nkeys matrices of r x r: Uᵀ K_o U (K_o itself when U is NULL) */
  double *M, *L;   /* nnode x 9p³ each: node q's expansion is a 3p³ x 3 column-major block */
  double *Mc, *Lc; /* nnode x 3r each: Uᵀ M, and the M2L sums that L gets U times (M, L when U is NULL) */
  int nthreads;    /* the gather's OpenMP threads; each takes whole M2L positions */
  double **work;   /* per thread: two 3r x chunk buffers and (but thread 0) its own M2L sums, nnode x 3r */
  double *q;       /* strengths w_j b_j: three arrays of n, one per colour */
  /* The near field (P2P) in single precision: x, y, z (relative to the
   * root cube's centre), nx, ny, nz, w as seven arrays of n + 8 (zero
   * padded), and the strengths as three; each target's sum over one source node is a float,
   * added into the double g. */
  float *pf, *qf;
  FmmStats stats;
} Fmm;

/* Plan the gather over `s` ordered by `t` (octree_build) at order `p`
 * (2..12). `vis` NULL: the kernel's facing clamp only (v = 1); otherwise
 * point-based visibility decides what is kept, dropped and split. 0, or -1
 * when `p` is out of range or memory runs out (then `f` is freed). */
int fmm_plan(Fmm *f, const Surfels *s, const Octree *t, int p, const Visibility *vis);

/* g (n x 3) = the gather of b (n x 3), both in the tree's point order. */
void fmm_gather(Fmm *f, const double *b, double *g);

/* The leaf-pair visibility the plan implies: vis[a * nleaf + b] is the v
 * of the entry that covers target leaf a and source leaf b (0 when dropped),
 * so a dense gather with it has exactly the FMM's visibility. NULL when out
 * of memory. */
float *fmm_leaf_visibility(const Fmm *f);

/* The default leaf size for n points. Measured (sweep, the Cornell box, p = 4, visibility
 * on, CPU seconds of one gather / of the plan, a machine shared with other work, load
 * about 6): at N = 5,000 leaves of 16, 32, 64, 128, 256 gave 0.022 / 1.8, 0.023-0.040 /
 * 1.1-1.3, 0.042-0.044 / 0.3-1.0, 0.0056 / 0.52, 0.0099 / 0.18 s; at N = 20,000 0.14 / 12.7,
 * 0.13-0.14 / 8.5-10, 0.065 / 1.6-4.6, 0.050 / 2.4, 0.039 / 0.58 s. Leaves of 256 gather in
 * about the time of 128 (wall 7.7 against 9.3 ms at 5,000, 32 against 36 ms at 20,000; the
 * CPU figures disagree at 5,000 within this noise) and plan 3-4x faster, which is most of
 * a small run (a solve is about 11 gathers); below about 10,000 points either has no
 * expansions (fmm_falls_back). At 110,528 points 96, 128 and 192 were within the noise of
 * each other (examples/points/README.md), so 128 from 30,000 points on. */
int fmm_leaf_for(long n);

/* Whether the plan falls back to direct sums: 1 when it uses no expansion
 * (no M2L, M2P or P2L: with few points against the leaf size the octree is
 * too shallow for any two cubes to be well separated, so every kept pair is
 * P2P and a gather costs what the dense gather over the kept pairs costs,
 * plus the plan). Then `msg` (may be NULL) says so and what to change. */
int fmm_falls_back(const Fmm *f, char *msg, size_t len);

void fmm_free(Fmm *f);

#endif
