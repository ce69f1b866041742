/* mesh.h — the 2D periodic wind tunnel with a triangular obstacle (paper
 * §7.1, Fig. 5), meshed by gmsh, and its deformation: the obstacle changing
 * size with fixed topology.
 *
 * Domain: [0, L] x [0, H], periodic in x (flow direction), walls at y = 0
 * and y = H; an equilateral triangle (side `size`, apex pointing upstream)
 * centred at (cx, cy) is cut out. gmsh meshes it with the right edge set as
 * the periodic copy of the left one (gmshModelMeshSetPeriodic), so the nodes
 * on x = L are translates of those on x = 0. Both copies are kept as
 * vertices: every cell reads only its own vertices, so areas, centroids and
 * P (paper §5.3) are right on either side, and the two copies of a periodic
 * edge are one face whose neighbours sit L apart (`nshift`).
 *
 * Conventions (those of fluids2d.npg): cells are counter-clockwise; face
 * cface[c][k] is the edge opposite vertex tri[c][k]; edge j runs from
 * edge[j][0] to edge[j][1] and its normal is (dy, -dx), to the right; the
 * flux f[j] is along that normal; csign[c][k] = +1 when that normal points
 * out of c; nbr[c][k] is the cell across the face, -1 on the boundary.
 * A boundary edge is oriented out of the fluid.
 */
#ifndef FLUIDS_MESH_H
#define FLUIDS_MESH_H

#include <stddef.h>

typedef struct TunnelSpec {
  double L, H;     /* tunnel length (periodic) and height */
  double cx, cy;   /* obstacle centroid */
  double size;     /* obstacle side length at rest (sigma = 1) */
  int cells;       /* target number of triangles (sets gmsh's element size) */
} TunnelSpec;

/* Face kinds: rows of D are the faces that are not BF_INTERIOR. */
typedef enum FaceKind {
  BF_INTERIOR, /* two cells (including the periodic faces) */
  BF_WALL,     /* tunnel wall, y = 0 or y = H at rest */
  BF_OBSTACLE, /* obstacle wall */
} FaceKind;

typedef struct Mesh {
  TunnelSpec spec;
  int nv, nc, nf, nb;  /* vertices, cells, faces (edges), boundary faces */
  double *g0;          /* [nv][2] rest positions */
  int *tri;            /* [nc][3] counter-clockwise */
  int *edge;           /* [nf][2] */
  int *cface;          /* [nc][3] the edge opposite tri[c][k] */
  double *csign;       /* [nc][3] +1: the face normal points out of c */
  int *nbr;            /* [nc][3] the cell across, -1 on the boundary */
  int *nshift;         /* [nc][3] x of a point in c's frame + nshift*L = its x in nbr's frame */
  int *bface;          /* [nb] boundary faces, the rows of D */
  int *fkind;          /* [nf] FaceKind */
  int *fcell;          /* [nf][2] the cell the normal points out of, the other (-1 on the boundary) */
  int *vmaster;        /* [nv] the vertex itself, or for a vertex on x = L its periodic copy on x = 0 */
  int obstacle[3];     /* the obstacle's corner vertices */
  double obstacle_area0; /* obstacle area at rest */
  double blend_r1, blend_r2; /* deformation blend: 1 inside r1, 0 outside r2 (mesh_deform) */
} Mesh;

/* The default tunnel of the example: L 4, H 1, obstacle at (1, 0.48) (a
 * little below the centre line, so the wake is not symmetric). */
TunnelSpec tunnel_spec_default(void);

/* Mesh `spec` with gmsh (initialized and finalized inside) and build the
 * topology. 0 on success; otherwise -1 with the reason in `err` and `m`
 * zeroed. */
int mesh_tunnel(Mesh *m, const TunnelSpec *spec, char *err, size_t errlen);
void mesh_free(Mesh *m);

/* Deformed positions `g` [nv][2] for obstacle scale `sigma` (1 = rest):
 * vertices within blend_r1 of the obstacle centroid scale by sigma about it,
 * the factor blends smoothly (C1) to 1 at blend_r2, and then the whole
 * tunnel stretches in y about cy by kappa so that the fluid area stays what
 * it is at scale `sigma_ref`, L*H - sigma_ref^2 obstacle_area0, exactly (an
 * incompressible fluid in a closed periodic tunnel cannot let the obstacle
 * grow otherwise: the walls give way). With sigma = sigma_ref, kappa = 1 and
 * g is linear in sigma (a run with a fixed obstacle: runs at different
 * scales then span each other, paper Fig. 5).
 * Checks every cell: 0 when none is inverted; otherwise -1 and `err` says
 * "deformation to obstacle scale S inverts element C (area A)", `g` then
 * holds the inverted positions (for inspection only). */
int mesh_deform(const Mesh *m, double sigma, double sigma_ref, double *g, char *err, size_t errlen);

/* Signed area of cell c at positions g. */
double mesh_area(const Mesh *m, const double *g, int c);
/* Minimum over cells of the quality 4 sqrt(3) A / (l1^2 + l2^2 + l3^2)
 * (1 for an equilateral triangle, 0 degenerate, negative inverted), and the
 * worst cell in *worst (when not NULL). */
double mesh_min_quality(const Mesh *m, const double *g, int *worst);
/* Fluid area (sum of cell areas) at g. */
double mesh_fluid_area(const Mesh *m, const double *g);

#endif
