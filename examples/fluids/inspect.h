/* inspect.h — npg-fluids mesh, cavity-mesh and cavity-projection: one part of the
 * example looked at alone, its figures printed as one JSON object on stdout. Each
 * returns the process's exit status (0, or 1 after printing the reason). */
#ifndef FLUIDS_INSPECT_H
#define FLUIDS_INSPECT_H

#include "cavity.h"
#include "mesh.h"

/* The tunnel's mesh at `spec`: counts of cells, faces and vertices by kind, the minimum
 * quality, the fluid area, the time gmsh took. */
int inspect_mesh(const TunnelSpec *spec);
/* The cavity's mesh and one deformation (the deepest of the training and test scales). */
int inspect_cavity_mesh(const CavitySpec *spec);
/* The full step's projection timed per method (which: 1 kkt, 2 al, 3 both) over `steps`
 * steps of training run 6 from u = 0; with both, their largest flux difference. */
int inspect_cavity_projection(const CavitySpec *spec, int steps, int which);

#endif
