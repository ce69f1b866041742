/* cavity.c — the deforming cavity of paper §7.2 meshed by gmsh (C API,
 * OpenCASCADE kernel), its tetrahedral topology and its deformation (see
 * cavity.h). */
#include "util.h"
#include "cavity.h"
#include "gmshread.h"
#include "npg.h"

#include <gmshc.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

CavitySpec cavity_spec_default(void) {
  return (CavitySpec){.R = 1.0, .r = 0.5, .D = 2.4, .rt = 0.25, .cells = 20000, .order = MO_HILBERT};
}

void cavity_free(Cavity *cv) {
  mesh_free(&cv->m);
  memset(cv, 0, sizeof *cv);
}

static void side_direction(int i, double d[3]) {
  double a = 2 * M_PI * i / CAVITY_SIDES;
  d[0] = cos(a), d[1] = sin(a), d[2] = 0;
}

/* ---------------------------------------------------------------- gmsh */

/* The chambers and tunnels as OpenCASCADE solids, fused into one volume. */
static void gmsh_build(const CavitySpec *s, int *ierr) {
  int tools[2 * 2 * CAVITY_SIDES], nt = 0;
  int centre = gmshModelOccAddSphere(0, 0, 0, s->R, -1, -M_PI / 2, M_PI / 2, 2 * M_PI, ierr);
  for (int i = 0; i < CAVITY_SIDES; i++) {
    double d[3];
    side_direction(i, d);
    /* the tunnel starts inside the central sphere and ends inside the side one */
    double a = 0.9 * s->R, b = s->D - 0.9 * s->r;
    int cyl = gmshModelOccAddCylinder(a * d[0], a * d[1], a * d[2], (b - a) * d[0], (b - a) * d[1], (b - a) * d[2],
                                      s->rt, -1, 2 * M_PI, ierr);
    int sph = gmshModelOccAddSphere(s->D * d[0], s->D * d[1], s->D * d[2], s->r, -1, -M_PI / 2, M_PI / 2, 2 * M_PI,
                                    ierr);
    tools[nt++] = 3, tools[nt++] = cyl;
    tools[nt++] = 3, tools[nt++] = sph;
  }
  int obj[2] = {3, centre};
  int *ov = NULL, **ovv = NULL;
  size_t nov = 0, *novv = NULL, nn = 0;
  gmshModelOccFuse(obj, 2, tools, nt, &ov, &nov, &ovv, &novv, &nn, -1, 1, 1, ierr);
  for (size_t i = 0; i < nn; i++) gmshFree(ovv[i]);
  gmshFree(ovv);
  gmshFree(novv);
  gmshFree(ov);
  gmshModelOccSynchronize(ierr);
}

static double cavity_volume(const CavitySpec *s) {
  double v = 4.0 / 3.0 * M_PI * (s->R * s->R * s->R + CAVITY_SIDES * s->r * s->r * s->r);
  return v + CAVITY_SIDES * M_PI * s->rt * s->rt * (s->D - s->R - s->r);
}

typedef struct CavityBuild {
  const CavitySpec *s;
  double h;
} CavityBuild;

static int build_cavity(const void *ctx, int *ierr) {
  const CavityBuild *b = ctx;
  gmsh_build(b->s, ierr);
  if (*ierr) return *ierr;
  gmshOptionSetNumber("Mesh.MeshSizeMax", b->h, ierr);
  gmshOptionSetNumber("Mesh.MeshSizeMin", 0.5 * b->h, ierr);
  /* the tunnels are thin: keep at least ~4 elements across them */
  gmshOptionSetNumber("Mesh.MeshSizeFromCurvature", 10, ierr);
  return 0;
}

static int gmsh_mesh(const CavitySpec *s, double h, RawMesh *raw, char *err, size_t errlen) {
  CavityBuild b = {s, h};
  return gmsh_read("cavity", 3, build_cavity, &b, raw, err, errlen);
}

/* ---------------------------------------------------------------- topology */

typedef struct HalfFace {
  int v[3]; /* sorted vertices */
  int c, k; /* cell, and the vertex of c the face is opposite */
} HalfFace;

static int cmp_half(const void *pa, const void *pb) {
  const HalfFace *a = pa, *b = pb;
  for (int i = 0; i < 3; i++)
    if (a->v[i] != b->v[i]) return a->v[i] < b->v[i] ? -1 : 1;
  return a->c < b->c ? -1 : a->c > b->c;
}

static void sort3(int v[3]) {
  for (int i = 0; i < 2; i++)
    for (int j = 0; j < 2 - i; j++)
      if (v[j] > v[j + 1]) {
        int t = v[j];
        v[j] = v[j + 1];
        v[j + 1] = t;
      }
}

/* Face j = the triangle of cell c opposite its vertex k, oriented so that
 * its area vector points away from that vertex (out of c). */
static void orient_face(FluidMesh *m, int j, int c, int k) {
  int *t = m->cell + 4 * c, *f = m->face + 3 * j, q = 0;
  for (int l = 0; l < 4; l++)
    if (l != k) f[q++] = t[l];
  const double *g = m->g0, *a = g + 3 * f[0], *b = g + 3 * f[1], *d = g + 3 * f[2], *o = g + 3 * t[k];
  double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
  double n[3] = {e[1] * w[2] - e[2] * w[1], e[2] * w[0] - e[0] * w[2], e[0] * w[1] - e[1] * w[0]};
  double s = n[0] * (a[0] - o[0]) + n[1] * (a[1] - o[1]) + n[2] * (a[2] - o[2]);
  if (s < 0) {
    int x = f[1];
    f[1] = f[2];
    f[2] = x;
  }
}

static int build_topology(FluidMesh *m, RawMesh *raw, char *err, size_t errlen) {
  m->dim = 3;
  m->nk = 4;
  m->nv = raw->nv;
  m->nc = raw->nc;
  m->g0 = raw->x;
  m->cell = raw->cell;
  raw->x = NULL;
  raw->cell = NULL;
  /* positively oriented cells */
  for (int c = 0; c < m->nc; c++)
    if (mesh_volume(m, m->g0, c) < 0) {
      int t = m->cell[4 * c + 2];
      m->cell[4 * c + 2] = m->cell[4 * c + 3];
      m->cell[4 * c + 3] = t;
    }
  int nh = 4 * m->nc;
  HalfFace *hf = malloc(nh * sizeof *hf);
  for (int c = 0; c < m->nc; c++)
    for (int k = 0; k < 4; k++) {
      HalfFace *x = hf + 4 * c + k;
      int q = 0;
      for (int l = 0; l < 4; l++)
        if (l != k) x->v[q++] = m->cell[4 * c + l];
      sort3(x->v);
      x->c = c, x->k = k;
    }
  qsort(hf, nh, sizeof *hf, cmp_half);
  m->cface = malloc(nh * sizeof *m->cface);
  m->csign = malloc(nh * sizeof *m->csign);
  m->nbr = malloc(nh * sizeof *m->nbr);
  m->face = malloc(3 * nh * sizeof *m->face);
  m->fkind = malloc(nh * sizeof *m->fkind);
  m->fcell = malloc(2 * nh * sizeof *m->fcell);
  m->bface = malloc(nh * sizeof *m->bface);
  m->nf = m->nb = 0;
  int rc = 0;
  for (int i = 0; i < nh;) {
    int j = i + 1;
    while (j < nh && !memcmp(hf[j].v, hf[i].v, sizeof hf[i].v)) j++;
    if (j - i > 2) {
      rc = npg_error_set(err, errlen, "mesh: triangle (%d, %d, %d) is shared by %d cells", hf[i].v[0], hf[i].v[1],
                         hf[i].v[2], j - i);
      break;
    }
    int f = m->nf++, c0 = hf[i].c, k0 = hf[i].k;
    orient_face(m, f, c0, k0);
    int c1 = j - i == 2 ? hf[i + 1].c : -1, k1 = j - i == 2 ? hf[i + 1].k : -1;
    mesh_link_face(m, f, c0, k0, c1, k1);
    if (c1 < 0) {
      m->fkind[f] = BF_WALL;
      m->bface[m->nb++] = f;
    }
    i = j;
  }
  free(hf);
  return rc;
}

int cavity_mesh(Cavity *cv, const CavitySpec *spec, char *err, size_t errlen) {
  memset(cv, 0, sizeof *cv);
  cv->spec = *spec;
  const CavitySpec *s = spec;
  if (!(s->R > 0 && s->r > 0 && s->rt > 0 && s->rt < s->r && s->rt < s->R && s->D > s->R + s->r && s->cells >= 50))
    return npg_error_set(err, errlen,
                         "cavity: radii must be positive, the tunnel thinner than the chambers, the chambers apart "
                         "(D > R + r) and cells at least 50");
  cv->volume0 = cavity_volume(s);
  /* gmsh's tetrahedra of size h fill about h^3 / 6.1 each (measured), but
   * the curvature of the thin tunnels refines them further: up to two
   * corrections of h by the cube root of the count's ratio to the target */
  cv->h = cbrt(6.1 * cv->volume0 / s->cells);
  RawMesh raw = {0};
  for (int pass = 0;; pass++) {
    if (gmsh_mesh(s, cv->h, &raw, err, errlen) != 0) {
      gmsh_raw_free(&raw);
      cavity_free(cv);
      return -1;
    }
    double ratio = (double)raw.nc / s->cells;
    if (pass == 2 || (ratio > 0.8 && ratio < 1.25)) break;
    cv->h *= cbrt(ratio);
    gmsh_raw_free(&raw);
  }
  if (build_topology(&cv->m, &raw, err, errlen) != 0) {
    gmsh_raw_free(&raw);
    cavity_free(cv);
    return -1;
  }
  /* gmsh's numbering scatters every gather of the solver and of npg's
   * generated loops over the whole mesh */
  mesh_renumber(&cv->m, s->order);
  cv->volume0 = mesh_fluid_volume(&cv->m, cv->m.g0);
  for (int i = 0; i < CAVITY_SIDES; i++) {
    double d[3];
    side_direction(i, d);
    for (int k = 0; k < 3; k++) cv->centre[i][k] = s->D * d[k];
  }
  double tunnel = s->D - s->R - s->r;
  cv->side_r1 = s->r;
  cv->side_r2 = s->r + 0.55 * tunnel;
  cv->mid_r1 = s->R;
  cv->mid_r2 = s->R + 0.3 * tunnel;
  return 0;
}

/* ---------------------------------------------------------------- deformation */

/* C1 blend: 1 for r <= r1, 0 for r >= r2 (smoothstep between). */
static double blend(double r, double r1, double r2) {
  if (r <= r1) return 1;
  if (r >= r2) return 0;
  double t = (r2 - r) / (r2 - r1);
  return t * t * (3 - 2 * t);
}

/* Side maps, then the central one with scale kappa, of the rest positions. */
static void place(const Cavity *cv, const double sigma[CAVITY_SIDES], double kappa, double *g) {
  const FluidMesh *m = &cv->m;
  for (int v = 0; v < m->nv; v++) {
    double x[3] = {m->g0[3 * v], m->g0[3 * v + 1], m->g0[3 * v + 2]};
    for (int i = 0; i < CAVITY_SIDES; i++) {
      if (sigma[i] == 1) continue;
      const double *c = cv->centre[i];
      double r = sqrt((x[0] - c[0]) * (x[0] - c[0]) + (x[1] - c[1]) * (x[1] - c[1]) + (x[2] - c[2]) * (x[2] - c[2]));
      double w = 1 + (sigma[i] - 1) * blend(r, cv->side_r1, cv->side_r2);
      for (int k = 0; k < 3; k++) x[k] = c[k] + w * (x[k] - c[k]);
    }
    double r = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
    double w = 1 + (kappa - 1) * blend(r, cv->mid_r1, cv->mid_r2);
    for (int k = 0; k < 3; k++) g[3 * v + k] = w * x[k];
  }
}

int cavity_deform(const Cavity *cv, const double sigma[CAVITY_SIDES], double *g, double *kappa, char *err,
                  size_t errlen) {
  const FluidMesh *m = &cv->m;
  /* the volume is a cubic in kappa: secant iteration from kappa = 1 */
  double k0 = 1, k1 = 1.01, V0, V1;
  place(cv, sigma, k0, g);
  V0 = mesh_fluid_volume(m, g) - cv->volume0;
  for (int it = 0; it < 50 && V0 != 0; it++) {
    place(cv, sigma, k1, g);
    V1 = mesh_fluid_volume(m, g) - cv->volume0;
    if (fabs(V1) <= 1e-15 * cv->volume0 || V1 == V0 || fabs(k1 - k0) < 1e-15) {
      k0 = k1, V0 = V1;
      break;
    }
    double k2 = k1 - V1 * (k1 - k0) / (V1 - V0);
    k0 = k1, V0 = V1, k1 = k2;
  }
  place(cv, sigma, k0, g);
  if (kappa) *kappa = k0;
  for (int c = 0; c < m->nc; c++) {
    double v = mesh_volume(m, g, c);
    if (!(v > 0))
      return npg_error_set(err, errlen,
                           "deformation to side scales (%g, %g, %g) inverts element %d (volume %.3g, rest volume %.3g)",
                           sigma[0], sigma[1], sigma[2], c, v, mesh_volume(m, m->g0, c));
  }
  return 0;
}
