/* solver.h — the full-space step of paper Fig. 2 (left column) on the
 * deforming tunnel:
 *
 *   deformation   g_{t+1} = mesh_deform(sigma_{t+1}) (refused if it inverts a
 *                 cell), gdot = (g_{t+1} - g_t)/dt, h = h(g_mid, gdot) (Eq. 11)
 *   advection     u' = u_t + RK4 over dt of V^-1(g_t)(A(f_t - h) + mu lap) u
 *   projection    f_{t+1} = argmin ||u' - V^-1 P f||_V(g_{t+1}) s.t. div f = 0,
 *                 D f = D h;  u_{t+1} = V^-1(g_{t+1}) P(g_{t+1}) f_{t+1}
 *
 * The reduced step (Fig. 2, right column) is meant to sit beside this one
 * with the same state layout (g, u, f, h), using the same mesh, particles
 * and output.
 */
#ifndef FLUIDS_SOLVER_H
#define FLUIDS_SOLVER_H

#include <stddef.h>

#include "integrator.h"
#include "projection.h"

typedef struct FullSolver {
  const FluidMesh *m;
  Ops ops;            /* geometry set at g (the current state) */
  Integrator it;
  Projection pr;
  double mu, dt;
  double sigma;       /* current obstacle scale (tunnel) */
  double sigma_ref;   /* the scale whose fluid area the deformation keeps (mesh_deform) */
  double *g, *g_next, *gmid, *gdot; /* [V][dim] */
  double *h, *phi, *f; /* [F] */
  double *u;          /* [C][dim] */
  double seconds_deformation, seconds_advection, seconds_projection;
  double min_quality; /* of the last deformation */
  int worst_cell;
} FullSolver;

/* Any mesh (2D or 3D) at positions g0 [V][dim], velocity u0 [dim]
 * everywhere, projected (h = 0). 0, or -1 with the reason in `err` (the
 * solver is then freed). */
int solver_init_at(FullSolver *s, const FluidMesh *m, ProjectionMethod method, double mu, double dt, const double *g0,
                   const double *u0, char *err, size_t errlen);
/* One step to the positions g_next [V][dim] (the caller's deformation,
 * e.g. cavity_deform): refused when a cell of g_next is not positively
 * oriented (the element named; the state is then unchanged), and then as
 * solver_step. */
int solver_step_to(FullSolver *s, const double *g_next, char *err, size_t errlen);
/* The tunnel: mesh at obstacle scale sigma0, velocity u0 everywhere, projected (h = 0);
 * every later deformation keeps the fluid area of scale sigma0.
 * 0, or -1 with the reason in `err` (the solver is then freed). */
int solver_init(FullSolver *s, const FluidMesh *m, ProjectionMethod method, double mu, double dt, double sigma0,
                const double u0[2], char *err, size_t errlen);
void solver_free(FullSolver *s);
/* One step to obstacle scale sigma_next. 0, or -1 with the reason (an
 * inverting deformation names the element; the state is then unchanged). */
int solver_step(FullSolver *s, double sigma_next, char *err, size_t errlen);
double solver_energy(const FullSolver *s);
/* A run that blew up: the energy `e` after frame `frame` not finite, or
 * above SOLVER_BLOWUP times the first frame's `e0` (the flow has no source
 * of energy but the obstacle's motion: the default tunnel's energy never
 * rose above its first frame's, 1.0x, over 200 frames, while --cfl 16 reached
 * 1e10x by frame 1). 0, or -1 with the message naming the remedies in `err`. */
#define SOLVER_BLOWUP 10.0
int solver_check_energy(double e0, double e, int frame, char *err, size_t errlen);

#endif
