/* surfels.h — triangle scenes and the point models sampled from them.
 *
 * A TriScene is what any triangle scene can hand to this example: vertex
 * positions, triangles, and per triangle an RGB albedo and an RGB emission
 * (radiosity units, W/m²). scene_sample turns it into Surfels, the point
 * model of the seed (paper 002 §2.2.2.3): position, unit normal, area weight,
 * albedo, emission, and no connectivity. */
#ifndef POINTS_SURFELS_H
#define POINTS_SURFELS_H

typedef struct TriScene {
  int nv, nt;
  double *v;        /* nv x 3 positions */
  int *tri;         /* nt x 3 vertex indices, counter-clockwise seen from the front */
  double *albedo;   /* nt x 3 RGB reflectance in [0,1) */
  double *emission; /* nt x 3 RGB emitted radiosity */
} TriScene;

/* Surfels as structure of arrays: the gathers read one coordinate of many
 * points at a time. */
typedef struct Surfels {
  long n;
  double *x, *y, *z;    /* positions */
  double *nx, *ny, *nz; /* unit normals (the front side of the source triangle) */
  double *w;            /* area weight: the surface area the point stands for */
  double *rho;          /* n x 3 albedo */
  double *e;            /* n x 3 emission */
  int *tri;             /* source triangle (for checks only; the solver never reads it) */
} Surfels;

/* The Cornell box of the seed (§2.3), in the unit cube, y up, open towards
 * -z where the camera stands: white floor, ceiling and back wall, red left
 * wall (x = 0), green right wall (x = 1), a square light in the ceiling and
 * two white blocks (no bottom faces) standing on the floor. 0 or -1 (memory). */
int scene_cornell_box(TriScene *s);

/* Two parallel unit squares facing each other across a gap of 1, and, when
 * `wall`, a square wall between them at half the gap, larger than both: the
 * known occluder of the visibility test. */
int scene_two_patches(TriScene *s, int wall);

void triscene_free(TriScene *s);

/* `n` surfels on `s`, area-proportional and stratified: each triangle gets
 * its share of n by area (largest remainders), and its points are a shifted
 * golden-ratio lattice of the unit square mapped onto it by the
 * area-preserving square-to-triangle warp, so any n is stratified. Every
 * point of triangle t carries the weight area(t)/n_t (§2.2.2.3: the area it
 * stands for; here the surface is known, so the weight is exact). `seed`
 * picks the lattice shifts. 0, or -1 when out of memory or n < 1. */
int scene_sample(const TriScene *s, long n, unsigned seed, Surfels *out);

/* Allocate `n` surfels (all arrays), 0 or -1. */
int surfels_alloc(Surfels *p, long n);
void surfels_free(Surfels *p);

#endif
