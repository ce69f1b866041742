/* meshgen.h — deterministic closed triangulated room for the radiosity benchmarks.
 *
 * mesh_room(F, t, ...) builds an axis-aligned box room (reference size 5 x 4 x 3, z up) whose
 * six walls are covered by one conforming (watertight) structured grid of nx x ny x nz cells.
 * Every grid quad is split into 2 triangles; to reach exactly F faces, k = (F - F0) / 2 quads
 * (spread evenly over the walls) are instead split into a fan of 4 triangles around an extra
 * centre vertex, which keeps the mesh conforming. Any even F >= 12 is reachable.
 *
 * All triangles are wound so that their normals point INTO the room. The room is convex for
 * every t, so the visibility of every pair of faces is 1.
 *
 * The deformation t in [0, 1] moves the wall x = Lx outwards (x' = x (1 + 0.3 t)) and tilts
 * the ceiling (z' = z (1 + 0.25 t x / Lx)); the floor stays at z = 0. Every wall stays planar
 * and the room stays convex. The topology (tri, V, F) does not depend on t, so meshes for
 * different t are samples of one program input g with one fixed param tri.
 */
#ifndef NPG_BENCH_MESHGEN_H
#define NPG_BENCH_MESHGEN_H

#include <stddef.h>

typedef struct Mesh {
    long V, F;
    double *g;   /* V*3, row-major vertex positions */
    int *tri;    /* F*3, vertex indices, normals (g1-g0) x (g2-g0) point into the room */
} Mesh;

/* Build the room with exactly F faces (F even, F >= 12) for deformation t (finite; meant for
 * [0, 1]). Returns 0 on success; on failure returns -1, writes a message into err (if err and
 * errlen > 0) and leaves *out zeroed. */
int mesh_room(long F, double t, Mesh *out, char *err, size_t errlen);

/* Free a mesh built by mesh_room (safe on a zeroed Mesh) and zero it. */
void mesh_free(Mesh *m);

/* Which wall face f lies on, from the dominant component of its normal:
 * 0 floor, 1 ceiling, 2 wall x = 0, 3 wall x = Lx, 4 wall y = 0, 5 wall y = Ly. */
int mesh_face_wall(const Mesh *m, long f);

/* Albedo per face (F values), by wall: floor 0.3, ceiling 0.8, walls 0.5 / 0.6 / 0.7 / 0.55. */
void mesh_rho(const Mesh *m, double *rho);

/* Emission per face (F values): 1 for the ceiling faces whose centroid lies in the central
 * third of the ceiling in x and y (at least one face: the ceiling face nearest the centre),
 * 0 elsewhere. Returns the number of emitting faces. Depends only on the topology and the
 * reference shape, so it is the same for every t of a given F. */
long mesh_emission(const Mesh *m, double *e);

#endif
