/* mesh.h — the simplicial mesh the solver runs on (triangles in 2D,
 * tetrahedra in 3D: `dim`), and the 2D periodic wind tunnel with a
 * triangular obstacle (paper §7.1, Fig. 5), meshed by gmsh, with its
 * deformation: the obstacle changing size with fixed topology. The 3D
 * deforming cavity (paper §7.2) is cavity.h; it fills the same FluidMesh.
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
 * Conventions in 3D (those of fluids3d.npg): cells are positively oriented
 * tetrahedra; face cface[c][k] is the triangle opposite vertex cell[c][k];
 * the face's area vector is 0.5 (g1 - g0) x (g2 - g0) of face[j] and the
 * flux f[j] is along it; csign, nbr as below.
 *
 * Conventions in 2D (those of fluids2d.npg): cells are counter-clockwise; face
 * cface[c][k] is the edge opposite vertex cell[c][k]; edge j runs from
 * face[j][0] to face[j][1] and its normal is (dy, -dx), to the right; the
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

/* The fluid's simplicial mesh (triangles or tetrahedra) with its faces and boundary; not
 * examples/common/meshgen.h's Mesh, a radiosity room. */
typedef struct FluidMesh {
  int dim;             /* 2: triangles and edges; 3: tetrahedra and triangles */
  int nk;              /* dim + 1: vertices (and faces) of a cell */
  TunnelSpec spec;     /* 2D tunnel only */
  int nv, nc, nf, nb;  /* vertices, cells, faces, boundary faces */
  double *g0;          /* [nv][dim] rest positions */
  int *cell;           /* [nc][nk] vertices: counter-clockwise (2D), positive volume (3D) */
  int *face;           /* [nf][dim] vertices; their order orients the face */
  int *cface;          /* [nc][nk] the face opposite cell[c][k] */
  double *csign;       /* [nc][nk] +1: the face normal points out of c */
  int *nbr;            /* [nc][nk] the cell across, -1 on the boundary */
  int *nshift;         /* [nc][nk] (2D) x of a point in c's frame + nshift*L = its x in nbr's frame */
  int *bface;          /* [nb] boundary faces, the rows of D */
  int *fkind;          /* [nf] FaceKind (3D: BF_INTERIOR or BF_WALL) */
  int *fcell;          /* [nf][2] the cell the normal points out of, the other (-1 on the boundary) */
  int *vmaster;        /* [nv] the vertex itself, or for a vertex on x = L its periodic copy on x = 0 */
  int obstacle[3];     /* the obstacle's corner vertices */
  double obstacle_area0; /* obstacle area at rest */
  double blend_r1, blend_r2; /* deformation blend: 1 inside r1, 0 outside r2 (mesh_deform) */
} FluidMesh;

/* The default tunnel of the example: L 4, H 1, obstacle at (1, 0.48) (a
 * little below the centre line, so the wake is not symmetric). */
TunnelSpec tunnel_spec_default(void);
/* The obstacle's scale at frame `frame` of a run pulsing about `scale`:
 * scale + pulse sin(2 pi frame / period) (paper §7.1, Fig. 5's runs). */
double tunnel_obstacle_scale(double scale, double pulse, double period, int frame);

/* Mesh `spec` with gmsh (initialized and finalized inside) and build the
 * topology. 0 on success; otherwise -1 with the reason in `err` and `m`
 * zeroed. */
int mesh_tunnel(FluidMesh *m, const TunnelSpec *spec, char *err, size_t errlen);
void mesh_free(FluidMesh *m);

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
int mesh_deform(const FluidMesh *m, double sigma, double sigma_ref, double *g, char *err, size_t errlen);

/* How a mesh's cells, faces and vertices are numbered once meshed. The
 * solver's loops and npg's generated ones gather f, h, u and g through nbr,
 * cface, face and cell: a numbering in which neighbours get close numbers
 * keeps those gathers in cache, where the mesher's scatters them. */
typedef enum MeshOrder {
  MO_HILBERT, /* cells along a Hilbert curve through their rest centroids (the cavity's default) */
  MO_RCM,     /* cells by reverse Cuthill-McKee on the cell graph (gathers a little faster still, but
                 CHOLMOD's own ordering of the projection then fills more: README, cavity) */
  MO_MESHER,  /* as the mesher numbered them (mesh_renumber leaves m unchanged) */
} MeshOrder;

/* Renumber m's cells by `order`, then its faces in order of first use by
 * the cells in their new order (cell by cell, k = 0..nk-1) and its vertices
 * likewise. Nothing but the numbers changes: each cell keeps its vertices
 * in their order (its orientation), each face its vertices in their order
 * and its fcell pair (so its normal still points out of fcell[0]); cface,
 * csign, nbr, nshift and fkind follow their cell or face; bface lists the
 * same boundary faces in increasing new number; vmaster and obstacle
 * follow the vertices. */
void mesh_renumber(FluidMesh *m, MeshOrder order);

/* Face f is face k0 of cell c0 (its normal out of c0) and face k1 of cell
 * c1 (c1 = -1 on the boundary): cface, csign, nbr, fcell, and fkind
 * BF_INTERIOR for two cells (a boundary face's kind is the caller's). */
void mesh_link_face(FluidMesh *m, int f, int c0, int k0, int c1, int k1);
/* Signed area (2D) or volume (3D) of cell c at positions g. */
double mesh_volume(const FluidMesh *m, const double *g, int c);
/* Minimum over cells of the quality, 1 for a regular simplex, 0 degenerate,
 * negative inverted: 4 sqrt(3) A / sum of l^2 in 2D, 6 sqrt(2) V / l_rms^3
 * in 3D (l_rms the root mean square of the six edges), and the worst cell
 * in *worst (when not NULL). */
double mesh_min_quality(const FluidMesh *m, const double *g, int *worst);
/* Fluid area or volume (sum of cell volumes) at g. */
double mesh_fluid_volume(const FluidMesh *m, const double *g);
/* The mean length of a 2D mesh's faces (its edges) at rest (g0): the length
 * the time step is chosen by. */
double mesh_mean_edge(const FluidMesh *m);

#endif
