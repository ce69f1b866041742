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

#define PARTICLES_MAX_THREADS 16

/* One thread's cells and faces of the current frame (3D): per cell the
 * frame it was last visited in, its velocity and barycentric map then; per
 * face (reduced flows) the frame its flux was lifted in and the flux. */
typedef struct ParticleCache {
  int *stamp, *fstamp;
  double *vel, *bary, *fval;
  long walk_steps, cells, faces; /* this frame's: faces crossed, cells visited, faces lifted */
} ParticleCache;

/* The flow particles move through: vertex positions g [nv][dim] and either
 * the face fluxes f [nf], or (f NULL, 3D) a reduced flux f = B_f f̂, B_f
 * [nf][mf] row-major, whose rows are lifted one face at a time as the
 * particles reach them (paper §6.5: the full flux is never expanded). B_f
 * and f̂ in single precision: the lift reads half the bytes (the particles'
 * velocities then carry a relative error of about 1e-7, far below the
 * reduced flow's own). */
typedef struct ParticleFlow {
  const double *g, *f;
  const float *Bf, *fh;
  int mf;
} ParticleFlow;

typedef struct Particles {
  int n, dim;
  double *x;   /* [n][dim] */
  int *cell;   /* [n] */
  int *tag;    /* [n] colour class: the parity of the streak it started in */
  long walk_steps; /* faces crossed, summed */
  long cells_visited, faces_lifted; /* particles_advect_flow in 3D: cells visited and faces lifted, summed over frames */
  /* particles_advect_flow: threads (0 or 1: the calling one), the frame
   * counter and each thread's cache (allocated on first use) */
  int threads, frame;
  ParticleCache cache[PARTICLES_MAX_THREADS];
  /* the particles put in cell order each frame: counts per cell, scratch */
  int *order_count, *order_int;
  double *order_x;
} Particles;

/* n particles uniformly distributed over 12 thin streaks of the fluid at
 * positions g (bands across y in 2D, slabs across z in 3D), tagged
 * alternately. 0, or -1 (out of memory: `p` then holds no particles). */
int particles_seed(Particles *p, const FluidMesh *m, const double *g, int n, unsigned seed);
void particles_free(Particles *p);
/* Eq. 13 evaluated locally in cell c: u [dim]. */
void particles_cell_velocity(const FluidMesh *m, const double *g, const double *f, int c, double *u);
/* Walk from *cell towards x until a cell contains x (x is wrapped across
 * periodic faces and clamped onto walls). Returns the faces crossed. */
int particles_locate(const FluidMesh *m, const double *g, double *x, int *cell);
/* Advance every particle by dt in `substeps` Euler substeps through the flux
 * field f on the mesh at g (paper: ten substeps per frame). */
void particles_advect(Particles *p, const FluidMesh *m, const double *g, const double *f, double dt, int substeps);

/* The same in 3D with each visited cell's velocity and barycentric map
 * computed once per call (the flow and the mesh are fixed over the frame):
 * the cost follows the cells the particles visit, never the mesh size
 * (paper §6.5: Eq. 13 evaluated locally). The particles are put in cell
 * order and divided into p->threads contiguous ranges, one per thread with
 * its own cache: the motion is the same bit for bit for any number of
 * threads. In 2D it is particles_advect (f required). 0, or -1 when out of
 * memory or a 2D flow has no f (nothing moved). */
int particles_advect_flow(Particles *p, const FluidMesh *m, const ParticleFlow *fl, double dt, int substeps);
/* particles_advect_flow through the fluxes f. */
void particles_advect_cached(Particles *p, const FluidMesh *m, const double *g, const double *f, double dt, int substeps);
/* Reorder the particles by their cells' numbers (a counting sort, stable):
 * on a mesh numbered for locality (mesh_renumber) consecutive particles
 * then visit nearby cells. particles_advect_cached does it every frame. */
void particles_sort_by_cell(Particles *p, const FluidMesh *m);

#endif
