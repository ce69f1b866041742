/* gmshread.h — the one reader of gmsh's meshes (C API, gmshc.h) for both of the
 * example's domains: the 2D tunnel (mesh.c) and the 3D cavity (cavity.c). The caller
 * builds the geometry; the reader meshes it and keeps the cells of the top dimension with
 * the nodes they use. */
#ifndef FLUIDS_GMSHREAD_H
#define FLUIDS_GMSHREAD_H

#include <stddef.h>

/* A mesh as gmsh gives it, before any topology. */
typedef struct RawMesh {
  int dim;      /* 2: triangles; 3: tetrahedra */
  int nv, nc;   /* nodes the cells use, cells */
  double *x;    /* [nv][dim] positions, nodes numbered in order of first use */
  int *cell;    /* [nc][dim + 1] node indices as gmsh orders them */
} RawMesh;

/* Builds the geometry of model `name` in the gmsh session the reader opened (and sets any
 * meshing option); gmsh's error code. */
typedef int (*GmshBuild)(const void *ctx, int *ierr);

/* Initialize gmsh, build(ctx) in a new model `name`, mesh it in `dim` dimensions and read
 * its triangles (dim 2) or tetrahedra (dim 3) into `raw`; gmsh is finalized inside. 0, or
 * -1 with "gmsh: ..." in `err` (what `raw` holds is then freed by gmsh_raw_free). */
int gmsh_read(const char *name, int dim, GmshBuild build, const void *ctx, RawMesh *raw, char *err, size_t errlen);
void gmsh_raw_free(RawMesh *raw);

#endif
