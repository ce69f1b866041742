/* cavitysim.h — npg-fluids cavity: paper §7.2 (Fig. 6, Table 1) on the
 * deforming cavity of cavity.h. Full training simulations compressing and
 * re-inflating one or two side chambers, streamed into npg's trainer
 * through npg.h; a test sequence not in the training set (one chamber
 * expanding while another stays compressed) run full and reduced side by
 * side, with marker particles through the reduced flow, VTK and PNG frames,
 * the reduced trajectory error per frame, and Table 1 in report.json. */
#ifndef FLUIDS_CAVITYSIM_H
#define FLUIDS_CAVITYSIM_H

#include "cavity.h"
#include "projection.h"

typedef struct CavityOptions {
  const char *out;
  CavitySpec spec;
  int frames;       /* per run */
  int runs;         /* training runs (14; 0: the full test run only) */
  int particles, png_every, vtk_every, width;
  double dt, nu;    /* time step; viscosity mu = nu * the smallest cell's volume */
  int mf, mu, mg;   /* basis caps: fluxes, velocities (the whole shared class), geometry */
  double dtol;      /* rank tolerance of D̂ (red_constraints) */
  ProjectionMethod projection; /* of the full step (PROJ_AL_CHOLMOD) */
} CavityOptions;

void cavity_options_default(CavityOptions *o);
/* The deformation of training run r (0 .. 13) or of the test (r = -1) at
 * frame t of T: side scales sigma[3]. */
void cavity_schedule(int r, int t, int T, double sigma[CAVITY_SIDES]);
int cavity_run(const CavityOptions *o);

#endif
