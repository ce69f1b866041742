/* scene.h — the parametric two-room scene of paper §9 (Fig. 7): a living room and a
 * bedroom joined by a door in a thick partition wall, a window in the back wall of each
 * room, a skylight in the living-room ceiling, a living-room ceiling that tilts, and
 * furniture blocks (a sofa and a table in the living room, a bed and a cabinet in the
 * bedroom) that occlude.
 *
 * Coordinates in metres, z up. Living room x in [0, 6], y in [0, 4.5]; partition wall
 * x in [6, 6.15]; bedroom x in [6.15, 10.15], y in [0, 4.5]. The living-room ceiling
 * pivots about its edge on the partition (height 2.6) and rises towards the outer wall
 * x = 0 with the tilt angle; the bedroom ceiling is flat at 2.6.
 *
 * Fixed topology. The scene is a list of planar quadrilateral patches (every wall with an
 * opening is a 3 x 3 or 3 x 2 grid of patches around it, the opening itself one patch);
 * each patch is a regular nu x nv grid of cells, two triangles per cell, with vertices of
 * its own. The parameters only move patch corners, and the grid counts come from the
 * nominal (mid-box) parameters, so tri, rho and V, F never depend on the parameters:
 * every parameter vector gives a sample g of one npg input over one param tri.
 *
 * Light. Window and skylight patches are the openings: emitting faces of albedo 0 (an
 * overcast sky seen through them), with one radiance per opening, so e changes with the
 * radiances (and only with them: which faces emit is fixed by the topology).
 *
 * Every triangle is wound so that its area vector (g1 - g0) x (g2 - g0) points into the
 * room it bounds (furniture: out of the block). */
#ifndef RADIOSITY_SCENE_H
#define RADIOSITY_SCENE_H

#include <stddef.h>

/* The parameter box (scene_param_at over [0, 1]^SCENE_NGEOM): sizes in metres, tilt in
 * degrees. Every point of the box gives a valid mesh (no degenerate or inverted triangle:
 * scene_min_area, as `npg-radiosity scene` checks it). The three radiances are not
 * geometry: they change e only (any value >= 0). */
typedef struct SceneParams {
  double win_living_w, win_living_h; /* living-room window (back wall, sill 0.9): [0.8, 3.0] x [0.6, 1.5] */
  double win_bed_w, win_bed_h;       /* bedroom window (back wall, sill 0.9):     [0.6, 2.2] x [0.6, 1.4] */
  double sky_w, sky_d;               /* skylight in the living ceiling (x, y):   [0.4, 1.6] x [0.4, 1.6] */
  double door_w, door_h;             /* door in the partition:                    [0.6, 1.4] x [1.8, 2.3] */
  double tilt_deg;                   /* living-ceiling tilt about the partition:  [0, 15] degrees */
  double rad_living, rad_bed, rad_sky; /* sky radiance through each opening (e on its faces) */
} SceneParams;

enum { SCENE_NGEOM = 9 }; /* the geometric parameters: the first 9 fields, in order */

/* What a face is made of. Emitters are the three openings. */
typedef enum Material {
  MAT_LIVING_WALL,  /* light walls and ceiling of the living room */
  MAT_LIVING_FLOOR, /* living-room floor */
  MAT_BED_WALL,     /* darker walls and ceiling of the bedroom */
  MAT_BED_FLOOR,    /* bedroom floor */
  MAT_DOOR,         /* the faces of the door opening in the partition */
  MAT_FURNITURE,    /* sofa, table, bed, cabinet */
  MAT_WIN_LIVING,   /* living-room window: emitter, albedo 0 */
  MAT_WIN_BED,      /* bedroom window: emitter, albedo 0 */
  MAT_SKYLIGHT,     /* skylight: emitter, albedo 0 */
  MAT_COUNT
} Material;

typedef struct Patch {
  int nu, nv;      /* grid cells along the two edges (fixed) */
  long v0, f0;     /* first vertex and first face of the patch */
  Material mat;
} Patch;

typedef struct Scene {
  long V, F;
  int npatch;
  Patch *patch;
  double *g;     /* V x 3 vertex positions at the current parameters */
  int *tri;      /* F x 3 */
  double *rho;   /* F albedos */
  int *mat;      /* F materials (Material) */
  double *e;     /* F emission at the current radiances */
  SceneParams params;
} Scene;

/* The box's far corner (every parameter at its upper end) and its nominal point (the
 * middle, radiances 1, 1, 1.5). */
void scene_param_hi(SceneParams *p);
void scene_param_nominal(SceneParams *p);
/* The point lo + t (hi - lo) of the box, t[k] in [0, 1] per geometric parameter
 * (SCENE_NGEOM values); radiances nominal. */
void scene_param_at(const double *t, SceneParams *p);
/* Field k (0 .. SCENE_NGEOM-1) of p, and its name ("win_living_w", ...). */
double *scene_param_field(SceneParams *p, int k);
const char *scene_param_name(int k);

/* Build the scene with about `faces` triangles (at least the ~130 of one cell per patch)
 * at parameters `p` (NULL: nominal). 0 on success; -1 with a message in err. */
int scene_new(long faces, const SceneParams *p, Scene *s, char *err, size_t errlen);
void scene_free(Scene *s);

/* Move the vertices to parameters `p` (g into `g`, V x 3; s->g when g is NULL) and set
 * s->e from p's radiances when g is NULL. The topology never changes. */
void scene_place(Scene *s, const SceneParams *p, double *g);
/* e (F values) for the radiances of `p`. */
void scene_emission(const Scene *s, const SceneParams *p, double *e);

/* Check every triangle of g: returns the minimum triangle area, and in *worst the face
 * having it. When `ref` (a g of the same scene, e.g. nominal) is given, also returns in
 * *min_cos the minimum cosine between each face's normal in g and in ref (an inverted
 * triangle has a negative one). */
double scene_min_area(const Scene *s, const double *g, const double *ref, long *worst, double *min_cos);

/* Material name ("living wall", ...). */
const char *scene_material_name(Material m);

#endif
