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
int fluid_params(const Mesh *m, double mu, FluidParam out[FLUID_NPARAMS]);
void fluid_params_free(FluidParam p[FLUID_NPARAMS]);
/* Bind them in f. 0, or -1 with npg_full_error(f). */
int fluid_bind(NpgFull *f, const Mesh *m, double mu);

#endif
