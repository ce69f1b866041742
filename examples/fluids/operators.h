/* operators.h — sparse assembly of the full-space fluid operators of paper
 * §5, exactly those fluids2d.npg (triangles) and fluids3d.npg (tetrahedra)
 * define (test_fluids compares every 2D one with npg's full evaluator of
 * fluids2d.npg); the mesh's `dim` picks the formulas:
 *
 *   V(g)      cell areas or volumes (Eq. 7; the volume tensor contracted with g) `area`
 *   P(g)      flux to momentum, p = P f (§5.3; stage p)                       `P`   dim C x F
 *   A(phi)    advection, pdot = A(f - h) u per component (Eq. 6, §5.4;
 *             stage pdot = A(f) u - A_h(h) u)                                  `A`   C x C
 *   lap       graph Laplacian (§5.2, as written: -|N_i| u_i + sum u_j)         `lap` C x C
 *   D         boundary selection (§5.4; stages bf, bh)                         `D`   B x F
 *   div       divergence: sum over a cell's faces of the outward flux         `div` C x F
 *   h(g,gdot) flux induced by the mesh motion (Eq. 11; stage h)
 *
 * Vectors: u, momenta: [C][dim] row-major (entry dim c + d); fluxes [F];
 * g [V][dim].
 */
#ifndef FLUIDS_OPERATORS_H
#define FLUIDS_OPERATORS_H

#include "mesh.h"

/* Compressed sparse rows. */
typedef struct Csr {
  int nrow, ncol;
  int *rowptr; /* [nrow + 1] */
  int *col;    /* [nnz] */
  double *val; /* [nnz] */
} Csr;

/* y = M x. */
void csr_mv(const Csr *M, const double *x, double *y);
/* y = M x for x, y of [n][2] (M applied to each component). */
void csr_mv2(const Csr *M, const double *x, double *y);
/* y = M x for x, y of [n][dim], dim 2 or 3. */
void csr_mvd(const Csr *M, int dim, const double *x, double *y);
/* y = M^T x. */
void csr_mtv(const Csr *M, const double *x, double *y);
void csr_free(Csr *M);

typedef struct Ops {
  const FluidMesh *m;
  const double *g; /* the positions last set (the caller's array, not copied) */
  double *area; /* [C] V(g) at the geometry last set */
  Csr P;        /* at the geometry last set */
  Csr A;        /* at the flux last set */
  Csr lap, D, div;
} Ops;

/* Patterns and the constant operators (lap, D, div). */
void ops_init(Ops *o, const FluidMesh *m);
void ops_free(Ops *o);
/* V(g) and P(g). */
void ops_set_geometry(Ops *o, const double *g);
/* A(phi) for the flux phi [F] (phi = f - h in the step, paper §5.4). */
void ops_set_advection(Ops *o, const double *phi);
/* h(g, gdot) [F], paper Eq. 11: h_j = n_j . (face centroid velocity) with
 * n_j the face's area vector (2D: the edge's normal scaled by its length).
 * In 2D, with g the midpoint of a linear motion and gdot its rate, h_j dt is
 * exactly the area edge j sweeps; in 3D the area vector is quadratic along
 * the motion and the midpoint is exact only to O(dt^2): ops_swept_flux. */
void ops_induced_flux(const FluidMesh *m, const double *g, const double *gdot, double *h);
/* The flux of the linear motion g0 -> g1 (midpoint gmid, rate gdot) over
 * the step, exactly: h_j dt is the volume face j sweeps (2D: h(gmid, gdot);
 * 3D: Simpson's rule on the area vector, exact for its quadratic). So the
 * boundary's h sums to the change of the fluid volume over dt. */
void ops_swept_flux(const FluidMesh *m, const double *g0, const double *g1, const double *gmid, const double *gdot,
                    double *h);
/* u = V^-1 P f (Eq. 13), with the geometry last set. */
void ops_velocity_from_flux(const Ops *o, const double *f, double *u);
/* Energy 1/2 u^T V u (paper §A.1), with the geometry last set. */
double ops_energy(const Ops *o, const double *u);

/* max over the columns of B (nf x m, row-major) of max_c |div column|: a
 * flux basis built from projected snapshots is divergence-free (§6.3). */
double ops_max_column_divergence(const Ops *o, const double *B, long nf, long m);

#endif
