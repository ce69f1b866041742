/* particles.h — massless marker particles (paper §6.5): each remembers the
 * cell that contains it; its velocity is the local evaluation of Eq. 13,
 * u_i = (V^-1(g) P(g) f)_i, from cell i's three vertices and three face
 * fluxes only, constant in the cell; it moves by explicit Euler substeps and
 * finds its new cell by walking across faces towards its new position (also
 * after the mesh deforms). The walk crosses periodic faces (shifting the
 * position by the tunnel length) and stops at walls, where the particle is
 * put back onto the wall.
 */
#ifndef FLUIDS_PARTICLES_H
#define FLUIDS_PARTICLES_H

#include "mesh.h"

typedef struct Particles {
  int n, dim;
  double *x;   /* [n][dim] */
  int *cell;   /* [n] */
  int *tag;    /* [n] colour class: the parity of the streak it started in */
  long walk_steps; /* faces crossed, summed */
  /* particles_advect_cached: per cell, the frame it was last visited in,
   * its velocity and barycentric map then (allocated on first use) */
  int frame, *stamp;
  double *vel, *bary;
  /* the particles put in cell order each frame: counts per cell, scratch */
  int *order_count, *order_int;
  double *order_x;
} Particles;

/* n particles uniformly distributed over 12 thin streaks of the fluid at
 * positions g (bands across y in 2D, slabs across z in 3D), tagged
 * alternately. */
void particles_seed(Particles *p, const Mesh *m, const double *g, int n, unsigned seed);
void particles_free(Particles *p);
/* Eq. 13 evaluated locally in cell c: u [dim]. */
void particles_cell_velocity(const Mesh *m, const double *g, const double *f, int c, double *u);
/* Walk from *cell towards x until a cell contains x (x is wrapped across
 * periodic faces and clamped onto walls). Returns the faces crossed. */
int particles_locate(const Mesh *m, const double *g, double *x, int *cell);
/* Advance every particle by dt in `substeps` Euler substeps through the flux
 * field f on the mesh at g (paper: ten substeps per frame). */
void particles_advect(Particles *p, const Mesh *m, const double *g, const double *f, double dt, int substeps);

/* The same in 3D with each visited cell's velocity and barycentric map
 * computed once per call (the flow and the mesh are fixed over the frame):
 * the cost follows the cells the particles visit, never the mesh size
 * (paper §6.5: Eq. 13 evaluated locally). In 2D it is particles_advect. */
void particles_advect_cached(Particles *p, const Mesh *m, const double *g, const double *f, double dt, int substeps);
/* Reorder the particles by their cells' numbers (a counting sort, stable):
 * on a mesh numbered for locality (mesh_renumber) consecutive particles
 * then visit nearby cells. particles_advect_cached does it every frame. */
void particles_sort_by_cell(Particles *p, const Mesh *m);

#endif
