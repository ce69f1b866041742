/* npgbind.h — the mesh as the params of fluids2d.npg (triangles) or
 * fluids3d.npg (tetrahedra), for npg's full evaluator (npg_full_set_param)
 * and for the data directory `npgc train` reads. Velocities are flat in
 * 2D: U = 2C entries, entry 2c + d; in 3D u is real[C, 3]. */
#ifndef FLUIDS_NPGBIND_H
#define FLUIDS_NPGBIND_H

#include <stddef.h>

#include "mesh.h"
#include "npg.h"

/* One param of the program as whole doubles (ints included). */
typedef struct FluidParam {
  const char *name;
  int ndim;
  long shape[2];
  double *v;
  int is_int;
} FluidParam;

#define FLUID_NPARAMS 10
/* The params, their number returned: in 2D tri, edge, cface, csign, nbr,
 * bface, ucell, ucomp, unbr, mu; in 3D tet, tri, cface, csign, nbr, bface,
 * mu (the rest of `out` zeroed). */
int fluid_params(const FluidMesh *m, double mu, FluidParam out[FLUID_NPARAMS]);
void fluid_params_free(FluidParam p[FLUID_NPARAMS]);
/* Bind them in f. 0, or -1 with npg_full_error(f). */
int fluid_bind(NpgFull *f, const FluidMesh *m, double mu);

/* The trainer's options for the fluid programs: per-member caps of u (the
 * shared class gets one more vector from each of p, pv, pdot, lap, whose
 * caps are 1), f, g, gdot, h and the boundary class {bf, bh} (60: complete,
 * constraint reduction needs D B_f and D_h B_h inside span B_d). Energies:
 * the caps decide, except where the snapshots run out; directions below
 * these fractions are rounding noise (a B_f column of noise is not
 * divergence-free to 1e-10). `names` holds the arrays `to` points into. */
typedef struct FluidBasisOptions {
  const char *names[11];
  int caps[11];
  double energies[11];
} FluidBasisOptions;
void fluid_train_options(NpgTrainOptions *to, FluidBasisOptions *names, int cap_u, int cap_f, int cap_g, int cap_h);

#endif
