/* scene.c — the parametric two-room scene (scene.h).
 *
 * One generator, walk(), lists the scene's patches in a fixed order as quadrilaterals
 * whose corners depend on the parameters. scene_new() runs it once at the nominal
 * parameters to fix every patch's grid (cells of about the size that gives the requested
 * face count); scene_place() runs it again at any parameters and fills each patch's grid
 * by bilinear interpolation of its corners. Every patch is planar at every parameter (walls
 * are vertical, the tilted ceiling is one plane), so the triangles are too. */
#include "util.h"
#include "scene.h"
#include "npg.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Fixed dimensions (metres). */
#define LX 6.0         /* living room depth in x */
#define LY 4.5         /* both rooms' extent in y */
#define WALL 0.15      /* partition thickness */
#define BX0 (LX + WALL)
#define BX1 (BX0 + 4.0) /* bedroom x in [BX0, BX1] */
#define HEIGHT 2.6     /* ceiling height at the partition (and the whole bedroom) */
#define SILL 0.9       /* window sills */
#define WIN_LIVING_X 3.0
#define WIN_BED_X (BX0 + 2.0)
#define SKY_X 2.0
#define SKY_Y 2.25
#define DOOR_Y 1.5

static const double param_lo[SCENE_NGEOM] = {0.8, 0.6, 0.6, 0.6, 0.4, 0.4, 0.6, 1.8, 0.0};
static const double param_hi[SCENE_NGEOM] = {3.0, 1.5, 2.2, 1.4, 1.6, 1.6, 1.4, 2.3, 15.0};
static const char *param_names[SCENE_NGEOM] = {"win_living_w", "win_living_h", "win_bed_w", "win_bed_h", "sky_w",
                                               "sky_d",        "door_w",       "door_h",    "tilt_deg"};

static const double albedo[MAT_COUNT] = {
    [MAT_LIVING_WALL] = 0.75, [MAT_LIVING_FLOOR] = 0.45, [MAT_BED_WALL] = 0.35,
    [MAT_BED_FLOOR] = 0.3,    [MAT_DOOR] = 0.6,          [MAT_FURNITURE] = 0.55,
    [MAT_WIN_LIVING] = 0.0,   [MAT_WIN_BED] = 0.0,       [MAT_SKYLIGHT] = 0.0,
};
static const char *material_names[MAT_COUNT] = {
    "living wall", "living floor", "bedroom wall", "bedroom floor", "door",
    "furniture",   "living window", "bedroom window", "skylight",
};

const char *scene_material_name(Material m) { return m < MAT_COUNT ? material_names[m] : "?"; }

double *scene_param_field(SceneParams *p, int k) {
  double *f[SCENE_NGEOM] = {&p->win_living_w, &p->win_living_h, &p->win_bed_w, &p->win_bed_h, &p->sky_w,
                            &p->sky_d,        &p->door_w,       &p->door_h,    &p->tilt_deg};
  return f[k];
}

const char *scene_param_name(int k) { return param_names[k]; }

void scene_param_at(const double *t, SceneParams *p) {
  for (int k = 0; k < SCENE_NGEOM; k++) *scene_param_field(p, k) = param_lo[k] + t[k] * (param_hi[k] - param_lo[k]);
  p->rad_living = 1.0;
  p->rad_bed = 1.0;
  p->rad_sky = 1.5; /* an overcast sky is brighter at the zenith (CIE: 3x the horizon) */
}

void scene_param_hi(SceneParams *p) {
  double t[SCENE_NGEOM];
  for (int k = 0; k < SCENE_NGEOM; k++) t[k] = 1;
  scene_param_at(t, p);
}

void scene_param_nominal(SceneParams *p) {
  double t[SCENE_NGEOM];
  for (int k = 0; k < SCENE_NGEOM; k++) t[k] = 0.5;
  scene_param_at(t, p);
}

/* ---------------------------------------------------------------- the patch walk */

typedef struct Vec3 {
  double x, y, z;
} Vec3;

static Vec3 v3(double x, double y, double z) { return (Vec3){x, y, z}; }
static Vec3 sub(Vec3 a, Vec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static double len(Vec3 a) { return sqrt(a.x * a.x + a.y * a.y + a.z * a.z); }

/* walk() hands every patch, in order, to one of these. */
typedef struct Walker {
  void (*quad)(struct Walker *w, Vec3 p00, Vec3 p10, Vec3 p11, Vec3 p01, Material mat);
  int k; /* patches seen so far */
  /* sizing (scene_new): nominal edge lengths per patch */
  double *lu, *lv;
  Material *mat;
  /* placing (scene_place) */
  const Scene *s;
  double *g;
} Walker;

/* A quad whose area vector should point along (p10 - p00) x (p01 - p00) when !flip and the
 * opposite way when flip: flipping swaps the two edge directions. */
static void quad(Walker *w, Vec3 p00, Vec3 p10, Vec3 p11, Vec3 p01, int flip, Material mat) {
  if (flip)
    w->quad(w, p00, p01, p11, p10, mat);
  else
    w->quad(w, p00, p10, p11, p01, mat);
}

/* A vertical wall: points o + a u + z (0,0,1) for a in breaks a[0..na], z in z[0..nz],
 * where the top break follows top(a) when `top` is given. Cell (ia, iz) is skipped when it
 * is `hole` and gets material `open_mat` when it is `open`; -1 for neither. */
typedef double (*TopFn)(const SceneParams *p, Vec3 at);

static Vec3 wall_pt(Vec3 o, Vec3 u, double a, double z) { return v3(o.x + a * u.x, o.y + a * u.y, z); }

static void wall(Walker *w, const SceneParams *p, Vec3 o, Vec3 u, const double *a, int na, const double *z, int nz,
                 TopFn top, int flip, Material mat, int open_a, int open_z, Material open_mat, int hole_a, int hole_z) {
  for (int iz = 0; iz < nz; iz++)
    for (int ia = 0; ia < na; ia++) {
      if (ia == hole_a && iz == hole_z) continue;
      Vec3 c[4];
      const int da[4] = {0, 1, 1, 0}, dz[4] = {0, 0, 1, 1};
      for (int k = 0; k < 4; k++) {
        double zz = z[iz + dz[k]];
        c[k] = wall_pt(o, u, a[ia + da[k]], zz);
        if (iz + dz[k] == nz && top) c[k].z = top(p, c[k]);
      }
      Material m = (ia == open_a && iz == open_z) ? open_mat : mat;
      quad(w, c[0], c[1], c[2], c[3], flip, m);
    }
}

/* The living-room ceiling: HEIGHT at the partition, rising towards x = 0. */
static double living_top(const SceneParams *p, Vec3 at) {
  return HEIGHT + tan(p->tilt_deg * M_PI / 180.0) * (LX - at.x);
}

/* A horizontal grid at height z (or top(x)) over x breaks and y breaks. */
static void slab(Walker *w, const SceneParams *p, const double *x, int nx, const double *y, int ny, double z, TopFn top,
                 int flip, Material mat, int open_x, int open_y, Material open_mat) {
  for (int iy = 0; iy < ny; iy++)
    for (int ix = 0; ix < nx; ix++) {
      Vec3 c[4];
      const int dx[4] = {0, 1, 1, 0}, dy[4] = {0, 0, 1, 1};
      for (int k = 0; k < 4; k++) {
        c[k] = v3(x[ix + dx[k]], y[iy + dy[k]], z);
        if (top) c[k].z = top(p, c[k]);
      }
      quad(w, c[0], c[1], c[2], c[3], flip, (ix == open_x && iy == open_y) ? open_mat : mat);
    }
}

/* A block on the floor: its top and four sides, facing out (its bottom is never seen). */
static void block(Walker *w, double x0, double x1, double y0, double y1, double h) {
  double xs[2] = {x0, x1}, ys[2] = {y0, y1};
  slab(w, NULL, xs, 1, ys, 1, h, NULL, 0, MAT_FURNITURE, -1, -1, MAT_FURNITURE);
  double zs[2] = {0, h}, yy[2] = {y0, y1}, xx[2] = {x0, x1};
  wall(w, NULL, v3(x0, 0, 0), v3(0, 1, 0), yy, 1, zs, 1, NULL, 1, MAT_FURNITURE, -1, -1, MAT_FURNITURE, -1, -1);
  wall(w, NULL, v3(x1, 0, 0), v3(0, 1, 0), yy, 1, zs, 1, NULL, 0, MAT_FURNITURE, -1, -1, MAT_FURNITURE, -1, -1);
  wall(w, NULL, v3(0, y0, 0), v3(1, 0, 0), xx, 1, zs, 1, NULL, 0, MAT_FURNITURE, -1, -1, MAT_FURNITURE, -1, -1);
  wall(w, NULL, v3(0, y1, 0), v3(1, 0, 0), xx, 1, zs, 1, NULL, 1, MAT_FURNITURE, -1, -1, MAT_FURNITURE, -1, -1);
}

/* Every patch of the scene at parameters p, always in the same order. Orientation: a wall
 * spanned by u = +x has area vector -y (flip to face +y); u = +y gives +x; slabs face +z. */
static void walk(Walker *w, const SceneParams *p) {
  /* living room */
  double fx[2] = {0, LX}, fy[2] = {0, LY};
  slab(w, p, fx, 1, fy, 1, 0, NULL, 0, MAT_LIVING_FLOOR, -1, -1, MAT_LIVING_FLOOR);
  double cx[4] = {0, SKY_X - p->sky_w / 2, SKY_X + p->sky_w / 2, LX};
  double cy[4] = {0, SKY_Y - p->sky_d / 2, SKY_Y + p->sky_d / 2, LY};
  slab(w, p, cx, 3, cy, 3, 0, living_top, 1, MAT_LIVING_WALL, 1, 1, MAT_SKYLIGHT);
  double full_z[2] = {0, 0};
  wall(w, p, v3(0, 0, 0), v3(1, 0, 0), fx, 1, full_z, 1, living_top, 1, MAT_LIVING_WALL, -1, -1, MAT_LIVING_WALL, -1,
       -1); /* front wall y = 0 */
  double bx[4] = {0, WIN_LIVING_X - p->win_living_w / 2, WIN_LIVING_X + p->win_living_w / 2, LX};
  double bz[4] = {0, SILL, SILL + p->win_living_h, 0};
  wall(w, p, v3(0, LY, 0), v3(1, 0, 0), bx, 3, bz, 3, living_top, 0, MAT_LIVING_WALL, 1, 1, MAT_WIN_LIVING, -1,
       -1); /* back wall y = LY, window */
  wall(w, p, v3(0, 0, 0), v3(0, 1, 0), fy, 1, full_z, 1, living_top, 0, MAT_LIVING_WALL, -1, -1, MAT_LIVING_WALL, -1,
       -1); /* outer wall x = 0 */
  double dy[4] = {0, DOOR_Y - p->door_w / 2, DOOR_Y + p->door_w / 2, LY};
  double dz[3] = {0, p->door_h, HEIGHT};
  wall(w, p, v3(LX, 0, 0), v3(0, 1, 0), dy, 3, dz, 2, NULL, 1, MAT_LIVING_WALL, -1, -1, MAT_LIVING_WALL, 1,
       0); /* partition, living side, door hole */
  /* the door opening through the partition: floor, lintel, jambs */
  double tx[2] = {LX, BX0}, ty[2] = {dy[1], dy[2]}, tz[2] = {0, p->door_h};
  slab(w, p, tx, 1, ty, 1, 0, NULL, 0, MAT_DOOR, -1, -1, MAT_DOOR);
  slab(w, p, tx, 1, ty, 1, p->door_h, NULL, 1, MAT_DOOR, -1, -1, MAT_DOOR);
  wall(w, p, v3(0, dy[1], 0), v3(1, 0, 0), tx, 1, tz, 1, NULL, 1, MAT_DOOR, -1, -1, MAT_DOOR, -1, -1);
  wall(w, p, v3(0, dy[2], 0), v3(1, 0, 0), tx, 1, tz, 1, NULL, 0, MAT_DOOR, -1, -1, MAT_DOOR, -1, -1);
  /* bedroom */
  double gx[2] = {BX0, BX1}, hz[2] = {0, HEIGHT};
  slab(w, p, gx, 1, fy, 1, 0, NULL, 0, MAT_BED_FLOOR, -1, -1, MAT_BED_FLOOR);
  slab(w, p, gx, 1, fy, 1, HEIGHT, NULL, 1, MAT_BED_WALL, -1, -1, MAT_BED_WALL);
  wall(w, p, v3(0, 0, 0), v3(1, 0, 0), gx, 1, hz, 1, NULL, 1, MAT_BED_WALL, -1, -1, MAT_BED_WALL, -1, -1);
  double wx[4] = {BX0, WIN_BED_X - p->win_bed_w / 2, WIN_BED_X + p->win_bed_w / 2, BX1};
  double wz[4] = {0, SILL, SILL + p->win_bed_h, HEIGHT};
  wall(w, p, v3(0, LY, 0), v3(1, 0, 0), wx, 3, wz, 3, NULL, 0, MAT_BED_WALL, 1, 1, MAT_WIN_BED, -1, -1);
  wall(w, p, v3(BX1, 0, 0), v3(0, 1, 0), fy, 1, hz, 1, NULL, 1, MAT_BED_WALL, -1, -1, MAT_BED_WALL, -1, -1);
  wall(w, p, v3(BX0, 0, 0), v3(0, 1, 0), dy, 3, dz, 2, NULL, 0, MAT_BED_WALL, -1, -1, MAT_BED_WALL, 1, 0);
  /* furniture: sofa, table (living room), bed, cabinet (bedroom) */
  /* (at least 0.6 m from every wall: Eq. 15 takes the form factor of a face at its
   * centroid, which overshoots badly when another face is closer than its own size) */
  block(w, 0.6, 2.6, 0.7, 1.6, 0.8);
  block(w, 3.4, 4.2, 2.4, 3.2, 0.75);
  block(w, BX0 + 1.0, BX0 + 3.0, 1.9, 3.9, 0.55);
  block(w, BX1 - 1.3, BX1 - 0.7, 0.6, 1.2, 1.2);
}

/* sizing pass: record nominal edge lengths and materials */
static void size_quad(Walker *w, Vec3 p00, Vec3 p10, Vec3 p11, Vec3 p01, Material mat) {
  if (w->lu) {
    /* the longer of the two opposite edges, so a trapezoid's cells are never too long */
    double a = len(sub(p10, p00)), b = len(sub(p11, p01)), c = len(sub(p01, p00)), d = len(sub(p11, p10));
    w->lu[w->k] = a > b ? a : b;
    w->lv[w->k] = c > d ? c : d;
    w->mat[w->k] = mat;
  }
  w->k++;
}

/* placing pass: the patch's (nu+1) x (nv+1) grid by bilinear interpolation */
static void place_quad(Walker *w, Vec3 p00, Vec3 p10, Vec3 p11, Vec3 p01, Material mat) {
  const Patch *pt = &w->s->patch[w->k++];
  double *g = w->g + 3 * pt->v0;
  for (int j = 0; j <= pt->nv; j++)
    for (int i = 0; i <= pt->nu; i++) {
      double s = (double)i / pt->nu, t = (double)j / pt->nv;
      double c00 = (1 - s) * (1 - t), c10 = s * (1 - t), c11 = s * t, c01 = (1 - s) * t;
      *g++ = c00 * p00.x + c10 * p10.x + c11 * p11.x + c01 * p01.x;
      *g++ = c00 * p00.y + c10 * p10.y + c11 * p11.y + c01 * p01.y;
      *g++ = c00 * p00.z + c10 * p10.z + c11 * p11.z + c01 * p01.z;
    }
}

static int cells(double length, double h) {
  long n = lround(length / h);
  return n < 1 ? 1 : n > 4096 ? 4096 : (int)n;
}

static long count_faces(int np, const double *lu, const double *lv, double h) {
  long f = 0;
  for (int k = 0; k < np; k++) f += 2L * cells(lu[k], h) * cells(lv[k], h);
  return f;
}

int scene_new(long faces, const SceneParams *p, Scene *s, char *err, size_t errlen) {
  memset(s, 0, sizeof *s);
  SceneParams nominal;
  scene_param_nominal(&nominal);
  Walker w = {.quad = size_quad};
  walk(&w, &nominal);
  int np = w.k;
  double *lu = malloc(sizeof(double) * np), *lv = malloc(sizeof(double) * np);
  Material *mat = malloc(sizeof(Material) * np);
  if (!lu || !lv || !mat) {
    free(lu), free(lv), free(mat);
    return npg_error_set(err, errlen, "out of memory");
  }
  w = (Walker){.quad = size_quad, .lu = lu, .lv = lv, .mat = mat};
  walk(&w, &nominal);
  /* the cell size whose face count is nearest `faces`: bisection on log h (the count is
   * a non-increasing step function of h) */
  double lo = 1e-3, hi = 20.0;
  for (int it = 0; it < 100; it++) {
    double mid = sqrt(lo * hi);
    if (count_faces(np, lu, lv, mid) > faces)
      lo = mid;
    else
      hi = mid;
  }
  double h = fabs((double)count_faces(np, lu, lv, lo) - faces) < fabs((double)count_faces(np, lu, lv, hi) - faces) ? lo : hi;
  if (count_faces(np, lu, lv, h) > 200000) {
    free(lu), free(lv), free(mat);
    return npg_error_set(err, errlen, "--faces %ld: more than 200000 faces", faces);
  }
  s->npatch = np;
  s->patch = calloc(np, sizeof(Patch));
  long V = 0, F = 0;
  for (int k = 0; k < np; k++) {
    Patch *pt = &s->patch[k];
    pt->nu = cells(lu[k], h);
    pt->nv = cells(lv[k], h);
    if (albedo[mat[k]] == 0) { /* an opening: at least 2 x 2 cells, so its light leaves from
                                  more than two centroids */
      pt->nu = pt->nu < 2 ? 2 : pt->nu;
      pt->nv = pt->nv < 2 ? 2 : pt->nv;
    }
    pt->mat = mat[k];
    pt->v0 = V;
    pt->f0 = F;
    V += (long)(pt->nu + 1) * (pt->nv + 1);
    F += 2L * pt->nu * pt->nv;
  }
  free(lu), free(lv), free(mat);
  s->V = V;
  s->F = F;
  s->g = malloc(sizeof(double) * 3 * V);
  s->tri = malloc(sizeof(int) * 3 * F);
  s->rho = malloc(sizeof(double) * F);
  s->mat = malloc(sizeof(int) * F);
  s->e = malloc(sizeof(double) * F);
  if (!s->patch || !s->g || !s->tri || !s->rho || !s->mat || !s->e) {
    scene_free(s);
    return npg_error_set(err, errlen, "out of memory");
  }
  /* two triangles per cell, (v00, v10, v11) and (v00, v11, v01): their area vectors point
   * along (p10 - p00) x (p01 - p00), the side walk() chose */
  for (int k = 0; k < np; k++) {
    const Patch *pt = &s->patch[k];
    long f = pt->f0, row = pt->nu + 1;
    for (int j = 0; j < pt->nv; j++)
      for (int i = 0; i < pt->nu; i++) {
        int v00 = (int)(pt->v0 + j * row + i), v10 = v00 + 1, v01 = v00 + (int)row, v11 = v01 + 1;
        int t[6] = {v00, v10, v11, v00, v11, v01};
        memcpy(s->tri + 3 * f, t, sizeof t);
        for (int q = 0; q < 2; q++, f++) {
          s->rho[f] = albedo[pt->mat];
          s->mat[f] = pt->mat;
        }
      }
  }
  scene_place(s, p ? p : &nominal, NULL);
  return 0;
}

void scene_free(Scene *s) {
  free(s->patch);
  free(s->g);
  free(s->tri);
  free(s->rho);
  free(s->mat);
  free(s->e);
  memset(s, 0, sizeof *s);
}

void scene_place(Scene *s, const SceneParams *p, double *g) {
  Walker w = {.quad = place_quad, .s = s, .g = g ? g : s->g};
  walk(&w, p);
  if (!g) {
    s->params = *p;
    scene_emission(s, p, s->e);
  }
}

void scene_emission(const Scene *s, const SceneParams *p, double *e) {
  for (long f = 0; f < s->F; f++) {
    switch (s->mat[f]) {
    case MAT_WIN_LIVING: e[f] = p->rad_living; break;
    case MAT_WIN_BED: e[f] = p->rad_bed; break;
    case MAT_SKYLIGHT: e[f] = p->rad_sky; break;
    default: e[f] = 0;
    }
  }
}

static Vec3 area_vector(const double *g, const int *t) {
  const double *a = g + 3 * t[0], *b = g + 3 * t[1], *c = g + 3 * t[2];
  Vec3 u = v3(b[0] - a[0], b[1] - a[1], b[2] - a[2]), v = v3(c[0] - a[0], c[1] - a[1], c[2] - a[2]);
  return v3(0.5 * (u.y * v.z - u.z * v.y), 0.5 * (u.z * v.x - u.x * v.z), 0.5 * (u.x * v.y - u.y * v.x));
}

double scene_min_area(const Scene *s, const double *g, const double *ref, long *worst, double *min_cos) {
  double amin = INFINITY, cmin = 1;
  long wf = -1;
  for (long f = 0; f < s->F; f++) {
    Vec3 n = area_vector(g, s->tri + 3 * f);
    double a = len(n);
    if (!(a >= amin)) {
      amin = a;
      wf = f;
    }
    if (ref) {
      Vec3 m = area_vector(ref, s->tri + 3 * f);
      double c = (n.x * m.x + n.y * m.y + n.z * m.z) / (a * len(m));
      if (!(c >= cmin)) cmin = c; /* NaN (a zero area) counts as the worst */
    }
  }
  if (worst) *worst = wf;
  if (min_cos) *min_cos = ref ? cmin : 1;
  return amin;
}
