/* gmshread.c — gmshread.h. */
#include "gmshread.h"

#include <gmshc.h>
#include <stdlib.h>
#include <string.h>

#include "util.h"
#include "npg.h"

void gmsh_raw_free(RawMesh *raw) {
  free(raw->x);
  free(raw->cell);
  memset(raw, 0, sizeof *raw);
}

/* Node tags -> dense indices, for the nodes the cells use, in order of first use. */
static int read_cells(int dim, const size_t *ntags, size_t nn, const double *coord, const size_t *enodes, size_t ne,
                      RawMesh *raw, char *err, size_t errlen) {
  int nk = dim + 1, rc = 0;
  size_t maxtag = 0;
  for (size_t i = 0; i < nn; i++) maxtag = ntags[i] > maxtag ? ntags[i] : maxtag;
  int *index = malloc((maxtag + 1) * sizeof *index);
  long *where = malloc((maxtag + 1) * sizeof *where);
  raw->x = malloc((size_t)dim * nn * sizeof *raw->x);
  raw->cell = malloc((size_t)nk * ne * sizeof *raw->cell);
  if (!index || !where || !raw->x || !raw->cell) {
    free(index), free(where);
    return npg_error_set(err, errlen, "gmsh: out of memory for %zu cells", ne);
  }
  for (size_t i = 0; i <= maxtag; i++) index[i] = -1, where[i] = -1;
  for (size_t i = 0; i < nn; i++) where[ntags[i]] = (long)i;
  raw->dim = dim;
  raw->nc = (int)ne;
  raw->nv = 0;
  for (size_t i = 0; i < nk * ne; i++) {
    size_t t = enodes[i];
    if (t > maxtag || where[t] < 0) {
      rc = npg_error_set(err, errlen, "gmsh: %s %zu uses unknown node %zu", dim == 2 ? "triangle" : "tetrahedron",
                         i / nk, t);
      break;
    }
    if (index[t] < 0) {
      index[t] = raw->nv++;
      memcpy(raw->x + (size_t)dim * index[t], coord + 3 * where[t], dim * sizeof(double));
    }
    raw->cell[i] = index[t];
  }
  free(index);
  free(where);
  return rc;
}

int gmsh_read(const char *name, int dim, GmshBuild build, const void *ctx, RawMesh *raw, char *err, size_t errlen) {
  int ierr = 0, rc = 0;
  memset(raw, 0, sizeof *raw);
  gmshInitialize(0, NULL, 0, &ierr);
  if (ierr) return npg_error_set(err, errlen, "gmsh: initialization failed");
  gmshOptionSetNumber("General.Terminal", 0, &ierr);
  gmshOptionSetNumber("General.Verbosity", 0, &ierr);
  gmshModelAdd(name, &ierr);
  size_t *ntags = NULL, *etags = NULL, *enodes = NULL, nn = 0, ne = 0, nen = 0, ncoord = 0, npar = 0;
  double *coord = NULL, *par = NULL;
  if (build(ctx, &ierr) != 0) {
    rc = npg_error_set(err, errlen, "gmsh: building the %s geometry failed (code %d)", name, ierr);
    goto done;
  }
  gmshModelMeshGenerate(dim, &ierr);
  if (ierr) {
    rc = npg_error_set(err, errlen, "gmsh: meshing failed (code %d)", ierr);
    goto done;
  }
  gmshModelMeshGetNodes(&ntags, &nn, &coord, &ncoord, &par, &npar, -1, -1, 0, 0, &ierr);
  /* element types 2 (3-node triangle) and 4 (4-node tetrahedron) */
  gmshModelMeshGetElementsByType(dim == 2 ? 2 : 4, &etags, &ne, &enodes, &nen, -1, 0, 1, &ierr);
  if (ierr || nn == 0 || ne == 0 || nen != (size_t)(dim + 1) * ne) {
    rc = npg_error_set(err, errlen, "gmsh: no %s (code %d)", dim == 2 ? "triangles" : "tetrahedra", ierr);
    goto done;
  }
  rc = read_cells(dim, ntags, nn, coord, enodes, ne, raw, err, errlen);
done:
  gmshFree(ntags);
  gmshFree(coord);
  gmshFree(par);
  gmshFree(etags);
  gmshFree(enodes);
  gmshFinalize(&ierr);
  return rc;
}
