/* cavity.h — the 3D deforming cavity of paper §7.2 (Fig. 6, Table 1): a
 * large central chamber and three smaller side chambers joined to it by thin
 * tunnels, tetrahedralized by gmsh (OpenCASCADE kernel: spheres and
 * cylinders fused), and its analytic deformation.
 *
 * Geometry: a central sphere of radius R at the origin; side spheres of
 * radius r centred at distance D along the directions at 0, 120 and 240
 * degrees in the xy-plane; each joined to the central one by a cylinder of
 * radius rt along the same direction.
 *
 * Deformation (cavity_deform): side chamber i scales by sigma_i about its
 * centre (sigma_i < 1 compresses it): a radial map g -> c_i + (g - c_i)
 * (1 + (sigma_i - 1) w(|g - c_i|)) whose weight w is 1 inside the chamber
 * and blends (C1 smoothstep) to 0 along the tunnel, so vertices move
 * smoothly through the interior and the map stays monotone along every ray
 * when compressing (its radial derivative is at least sigma_i, since w
 * decreases outward); expansion is monotone while (sigma_i - 1) times the
 * blend's steepness stays below 1. The central chamber then scales about the origin by the
 * factor kappa, with its own blend into the tunnels, that makes the total
 * volume (the sum of the cells' volumes) equal to the rest volume to
 * rounding (a secant iteration on a cubic in kappa): an incompressible
 * fluid in a closed cavity cannot change its volume, and the projection's
 * constraints (div f = 0, D f = D h) are consistent only if the boundary's
 * induced fluxes sum to zero. Every cell is checked at every call.
 */
#ifndef FLUIDS_CAVITY_H
#define FLUIDS_CAVITY_H

#include <stddef.h>

#include "mesh.h"

#define CAVITY_SIDES 3

typedef struct CavitySpec {
  double R;      /* central chamber radius */
  double r;      /* side chamber radius */
  double D;      /* distance of the side chambers' centres from the origin */
  double rt;     /* tunnel radius */
  int cells;     /* target number of tetrahedra (sets gmsh's element size) */
  MeshOrder order; /* the numbering of cells, faces and vertices (mesh_renumber) */
} CavitySpec;

typedef struct Cavity {
  FluidMesh m;                       /* dim 3; fkind BF_WALL on the boundary */
  CavitySpec spec;
  double centre[CAVITY_SIDES][3];
  double volume0;               /* fluid volume at rest */
  double h;                     /* the element size gmsh was given */
  double side_r1, side_r2;      /* side blend: 1 within side_r1 of a side centre, 0 beyond side_r2 */
  double mid_r1, mid_r2;        /* central blend about the origin */
} Cavity;

/* R 1, r 0.5, D 2.4, rt 0.25, 20,000 cells, numbered along a Hilbert curve. */
CavitySpec cavity_spec_default(void);

/* Mesh `spec` with gmsh (initialized and finalized inside), build the
 * tetrahedral topology (faces oriented out of their first cell, boundary
 * faces out of the fluid) and renumber it by spec->order. 0, or -1 with the
 * reason in `err` and `cv` zeroed. */
int cavity_mesh(Cavity *cv, const CavitySpec *spec, char *err, size_t errlen);
void cavity_free(Cavity *cv);

/* Positions g [V][3] for side scales sigma[CAVITY_SIDES] (1 = rest), the
 * central chamber renormalizing the volume; *kappa (when not NULL) gets the
 * central scale. 0 when every cell keeps a positive volume; otherwise -1 and
 * `err` says "deformation to side scales (a, b, c) inverts element C
 * (volume V, rest volume W)" (g then holds the inverted positions). */
int cavity_deform(const Cavity *cv, const double sigma[CAVITY_SIDES], double *g, double *kappa, char *err,
                  size_t errlen);

#endif
