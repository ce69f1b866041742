/* mesh.c — the periodic wind tunnel meshed by gmsh (C API), its topology and
 * its deformation (see mesh.h). */
#include "util.h"
#include "mesh.h"
#include "gmshread.h"
#include "npg.h"

#include <gmshc.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

TunnelSpec tunnel_spec_default(void) {
  return (TunnelSpec){.L = 4.0, .H = 1.0, .cx = 1.0, .cy = 0.48, .size = 0.3, .cells = 2000};
}

double tunnel_obstacle_scale(double scale, double pulse, double period, int frame) {
  return scale + pulse * sin(2 * M_PI * frame / period);
}

void mesh_free(FluidMesh *m) {
  free(m->g0);
  free(m->cell);
  free(m->face);
  free(m->cface);
  free(m->csign);
  free(m->nbr);
  free(m->nshift);
  free(m->bface);
  free(m->fkind);
  free(m->fcell);
  free(m->vmaster);
  memset(m, 0, sizeof *m);
}

double mesh_volume(const FluidMesh *m, const double *g, int c) {
  if (m->dim == 3) {
    const int *t = m->cell + 4 * c;
    const double *a = g + 3 * t[0];
    double e[3][3];
    for (int k = 0; k < 3; k++)
      for (int d = 0; d < 3; d++) e[k][d] = g[3 * t[k + 1] + d] - a[d];
    return (e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1]) - e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0]) +
            e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0])) /
           6;
  }
  const double *a = g + 2 * m->cell[3 * c], *b = g + 2 * m->cell[3 * c + 1], *d = g + 2 * m->cell[3 * c + 2];
  return 0.5 * ((b[0] - a[0]) * (d[1] - a[1]) - (b[1] - a[1]) * (d[0] - a[0]));
}

void mesh_link_face(FluidMesh *m, int f, int c0, int k0, int c1, int k1) {
  int nk = m->nk;
  m->cface[nk * c0 + k0] = f;
  m->csign[nk * c0 + k0] = 1;
  m->fcell[2 * f] = c0;
  m->nbr[nk * c0 + k0] = c1;
  m->fcell[2 * f + 1] = c1;
  if (c1 < 0) return;
  m->cface[nk * c1 + k1] = f;
  m->csign[nk * c1 + k1] = -1;
  m->nbr[nk * c1 + k1] = c0;
  m->fkind[f] = BF_INTERIOR;
}

double mesh_fluid_volume(const FluidMesh *m, const double *g) {
  double s = 0;
  for (int c = 0; c < m->nc; c++) s += mesh_volume(m, g, c);
  return s;
}

/* Sum of the squared edge lengths of cell c. */
static double edge_squares(const FluidMesh *m, const double *g, int c) {
  int dim = m->dim, nk = m->nk;
  const int *t = m->cell + nk * c;
  double l2 = 0;
  for (int k = 0; k < nk; k++)
    for (int l = k + 1; l < nk; l++)
      for (int d = 0; d < dim; d++) {
        double x = g[dim * t[l] + d] - g[dim * t[k] + d];
        l2 += x * x;
      }
  return l2;
}

static double quality(const FluidMesh *m, const double *g, int c) {
  double l2 = edge_squares(m, g, c);
  if (m->dim == 3) return 6.0 * sqrt(2.0) * mesh_volume(m, g, c) / pow(l2 / 6, 1.5);
  return 4.0 * sqrt(3.0) * mesh_volume(m, g, c) / l2;
}

double mesh_min_quality(const FluidMesh *m, const double *g, int *worst) {
  double q = INFINITY;
  int w = -1;
  for (int c = 0; c < m->nc; c++) {
    double qc = quality(m, g, c);
    if (qc < q) q = qc, w = c;
  }
  if (worst) *worst = w;
  return q;
}

/* ---------------------------------------------------------------- gmsh */

/* The tunnel's geometry in gmsh's built-in kernel: outer loop with the
 * right edge a periodic copy of the left one, the obstacle a hole. */
static int gmsh_build(const TunnelSpec *s, double h, int *ierr) {
  double L = s->L, H = s->H, R = s->size / sqrt(3.0);
  int p1 = gmshModelGeoAddPoint(0, 0, 0, h, -1, ierr);
  int p2 = gmshModelGeoAddPoint(L, 0, 0, h, -1, ierr);
  int p3 = gmshModelGeoAddPoint(L, H, 0, h, -1, ierr);
  int p4 = gmshModelGeoAddPoint(0, H, 0, h, -1, ierr);
  int bottom = gmshModelGeoAddLine(p1, p2, -1, ierr);
  int right = gmshModelGeoAddLine(p2, p3, -1, ierr);
  int top = gmshModelGeoAddLine(p3, p4, -1, ierr);
  int left = gmshModelGeoAddLine(p1, p4, -1, ierr); /* upward, like `right` */
  int outer[4] = {bottom, right, top, -left};
  int lo = gmshModelGeoAddCurveLoop(outer, 4, -1, 0, ierr);
  double hq = h * 0.5; /* finer on the obstacle */
  int q1 = gmshModelGeoAddPoint(s->cx - R, s->cy, 0, hq, -1, ierr);
  int q2 = gmshModelGeoAddPoint(s->cx + R / 2, s->cy + s->size / 2, 0, hq, -1, ierr);
  int q3 = gmshModelGeoAddPoint(s->cx + R / 2, s->cy - s->size / 2, 0, hq, -1, ierr);
  int o[3] = {gmshModelGeoAddLine(q1, q3, -1, ierr), gmshModelGeoAddLine(q3, q2, -1, ierr),
              gmshModelGeoAddLine(q2, q1, -1, ierr)};
  int lh = gmshModelGeoAddCurveLoop(o, 3, -1, 0, ierr);
  int loops[2] = {lo, lh};
  gmshModelGeoAddPlaneSurface(loops, 2, -1, ierr);
  gmshModelGeoSynchronize(ierr);
  /* paper §7.1: a periodic tunnel. The mesh of `right` is the mesh of `left`
   * translated by L (affine transform: 4x4 matrix by rows). */
  double T[16] = {1, 0, 0, L, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  int rt[1] = {right}, lt[1] = {left};
  gmshModelMeshSetPeriodic(1, rt, 1, lt, 1, T, 16, ierr);
  return *ierr;
}

typedef struct TunnelBuild {
  const TunnelSpec *s;
  double h;
} TunnelBuild;

static int build_tunnel(const void *ctx, int *ierr) {
  const TunnelBuild *b = ctx;
  return gmsh_build(b->s, b->h, ierr);
}

static int gmsh_mesh(const TunnelSpec *s, RawMesh *raw, char *err, size_t errlen) {
  double area = s->L * s->H - sqrt(3.0) / 4 * s->size * s->size;
  /* equilateral cells of the mean area, a little larger: the obstacle is
   * meshed twice as fine and gmsh overshoots the count by about a third */
  TunnelBuild b = {s, 1.15 * sqrt(4.0 * area / (sqrt(3.0) * s->cells))};
  return gmsh_read("tunnel", 2, build_tunnel, &b, raw, err, errlen);
}

/* ---------------------------------------------------------------- topology */

typedef struct HalfEdge {
  int a, b;  /* the edge's key: periodic-identified vertex ids, a < b */
  int c, k;  /* cell and local face */
} HalfEdge;

static int cmp_half(const void *x, const void *y) {
  const HalfEdge *p = x, *q = y;
  if (p->a != q->a) return p->a < q->a ? -1 : 1;
  if (p->b != q->b) return p->b < q->b ? -1 : 1;
  if (p->c != q->c) return p->c < q->c ? -1 : 1;
  return p->k - q->k;
}

typedef struct YKey {
  double y;
  int v;
} YKey;

static int cmp_y(const void *x, const void *y) {
  const YKey *p = x, *q = y;
  return p->y < q->y ? -1 : p->y > q->y ? 1 : 0;
}

/* master[v]: v itself, or for a vertex on x = L its copy on x = 0. */
static int match_periodic(const RawMesh *raw, const TunnelSpec *s, int *master, char *err, size_t errlen) {
  double tol = 1e-9 * s->L;
  YKey *left = malloc(raw->nv * sizeof *left);
  int nl = 0, rc = 0;
  for (int v = 0; v < raw->nv; v++) {
    master[v] = v;
    if (fabs(raw->x[2 * v]) < tol) left[nl++] = (YKey){raw->x[2 * v + 1], v};
  }
  qsort(left, nl, sizeof *left, cmp_y);
  for (int v = 0; v < raw->nv && rc == 0; v++) {
    if (fabs(raw->x[2 * v] - s->L) >= tol) continue;
    double y = raw->x[2 * v + 1];
    int lo = 0, hi = nl;
    while (lo < hi) {
      int mid = (lo + hi) / 2;
      if (left[mid].y < y) lo = mid + 1;
      else hi = mid;
    }
    int best = -1;
    for (int i = lo - 1; i <= lo; i++)
      if (i >= 0 && i < nl && fabs(left[i].y - y) < 1e-9 * s->H) best = left[i].v;
    if (best < 0) rc = npg_error_set(err, errlen,
                                     "gmsh: node at (%g, %g) on the right edge has no periodic copy", s->L, y);
    else master[v] = best;
  }
  free(left);
  return rc;
}

static int build_topology(FluidMesh *m, const RawMesh *raw, char *err, size_t errlen) {
  const TunnelSpec *s = &m->spec;
  m->nv = raw->nv;
  m->nc = raw->nc;
  m->g0 = raw->x;
  m->cell = raw->cell;
  /* counter-clockwise cells */
  for (int c = 0; c < m->nc; c++)
    if (mesh_volume(m, m->g0, c) < 0) {
      int t = m->cell[3 * c + 1];
      m->cell[3 * c + 1] = m->cell[3 * c + 2];
      m->cell[3 * c + 2] = t;
    }
  int *master = malloc(m->nv * sizeof *master);
  m->vmaster = master;
  if (match_periodic(raw, s, master, err, errlen) != 0) return -1;
  int nh = 3 * m->nc;
  HalfEdge *he = malloc(nh * sizeof *he);
  for (int c = 0; c < m->nc; c++)
    for (int k = 0; k < 3; k++) {
      int a = master[m->cell[3 * c + (k + 1) % 3]], b = master[m->cell[3 * c + (k + 2) % 3]];
      he[3 * c + k] = (HalfEdge){a < b ? a : b, a < b ? b : a, c, k};
    }
  qsort(he, nh, sizeof *he, cmp_half);
  m->cface = malloc(nh * sizeof *m->cface);
  m->csign = malloc(nh * sizeof *m->csign);
  m->nbr = malloc(nh * sizeof *m->nbr);
  m->nshift = calloc(nh, sizeof *m->nshift);
  m->face = malloc(2 * nh * sizeof *m->face);
  m->fkind = malloc(nh * sizeof *m->fkind);
  m->fcell = malloc(2 * nh * sizeof *m->fcell);
  m->bface = malloc(nh * sizeof *m->bface);
  m->nf = m->nb = 0;
  int rc = 0;
  for (int i = 0; i < nh && rc == 0;) {
    int j = i + 1;
    while (j < nh && he[j].a == he[i].a && he[j].b == he[i].b) j++;
    if (j - i > 2) {
      rc = npg_error_set(err, errlen, "mesh: edge (%d, %d) is shared by %d cells", he[i].a, he[i].b, j - i);
      break;
    }
    int f = m->nf++;
    int c0 = he[i].c, k0 = he[i].k;
    int va = m->cell[3 * c0 + (k0 + 1) % 3], vb = m->cell[3 * c0 + (k0 + 2) % 3];
    m->face[2 * f] = va; /* counter-clockwise in c0: the normal points out of c0 */
    m->face[2 * f + 1] = vb;
    int c1 = j - i == 2 ? he[i + 1].c : -1, k1 = j - i == 2 ? he[i + 1].k : -1;
    mesh_link_face(m, f, c0, k0, c1, k1);
    if (c1 >= 0) {
      /* periodic face: c1 sees the edge L away from where c0 sees it */
      int wa = m->cell[3 * c1 + (k1 + 2) % 3]; /* c1 runs the edge the other way: its copy of va */
      if (master[wa] != master[va]) wa = m->cell[3 * c1 + (k1 + 1) % 3];
      double dx = m->g0[2 * wa] - m->g0[2 * va];
      int sh = (int)lround(dx / s->L);
      m->nshift[3 * c0 + k0] = sh;
      m->nshift[3 * c1 + k1] = -sh;
    } else {
      double ya = m->g0[2 * va + 1], yb = m->g0[2 * vb + 1], xa = m->g0[2 * va], xb = m->g0[2 * vb];
      double tol = 1e-9 * s->H;
      if ((fabs(ya) < tol && fabs(yb) < tol) || (fabs(ya - s->H) < tol && fabs(yb - s->H) < tol))
        m->fkind[f] = BF_WALL;
      else if ((fabs(xa) < tol && fabs(xb) < tol) || (fabs(xa - s->L) < tol && fabs(xb - s->L) < tol))
        rc = npg_error_set(err, errlen, "mesh: periodic edge at x = %g, y in [%g, %g] has no partner", xa, ya, yb);
      else
        m->fkind[f] = BF_OBSTACLE;
      m->bface[m->nb++] = f;
    }
    i = j;
  }
  free(he);
  /* the obstacle's corners */
  double R = s->size / sqrt(3.0);
  double corner[3][2] = {{s->cx - R, s->cy}, {s->cx + R / 2, s->cy + s->size / 2}, {s->cx + R / 2, s->cy - s->size / 2}};
  for (int q = 0; q < 3; q++) {
    m->obstacle[q] = -1;
    for (int v = 0; v < m->nv; v++)
      if (hypot(m->g0[2 * v] - corner[q][0], m->g0[2 * v + 1] - corner[q][1]) < 1e-9) m->obstacle[q] = v;
    if (m->obstacle[q] < 0 && rc == 0) rc = npg_error_set(err, errlen,
                                                          "mesh: obstacle corner %d not found among the nodes", q);
  }
  m->obstacle_area0 = sqrt(3.0) / 4 * s->size * s->size;
  double room = fmin(fmin(s->cy, s->H - s->cy), fmin(s->cx, s->L - s->cx));
  m->blend_r1 = 1.25 * R;
  m->blend_r2 = 0.9 * room;
  if (m->blend_r2 <= 1.1 * m->blend_r1 && rc == 0)
    rc = npg_error_set(err, errlen, "mesh: obstacle of size %g leaves no room for the deformation blend", s->size);
  return rc;
}

int mesh_tunnel(FluidMesh *m, const TunnelSpec *spec, char *err, size_t errlen) {
  memset(m, 0, sizeof *m);
  m->dim = 2;
  m->nk = 3;
  m->spec = *spec;
  if (!(spec->L > 0 && spec->H > 0 && spec->size > 0 && spec->cells >= 8))
    return npg_error_set(err, errlen, "tunnel: L, H and size must be positive and cells at least 8");
  double R = spec->size / sqrt(3.0);
  if (spec->cx - R <= 0 || spec->cx + R >= spec->L || spec->cy - spec->size / 2 <= 0 ||
      spec->cy + spec->size / 2 >= spec->H)
    return npg_error_set(err, errlen, "tunnel: an obstacle of size %g at (%g, %g) does not fit in the %g x %g tunnel",
                         spec->size, spec->cx, spec->cy, spec->L, spec->H);
  RawMesh raw = {0};
  if (gmsh_mesh(spec, &raw, err, errlen) != 0) {
    gmsh_raw_free(&raw);
    return -1;
  }
  if (build_topology(m, &raw, err, errlen) != 0) {
    mesh_free(m);
    return -1;
  }
  return 0;
}

/* ---------------------------------------------------------------- deformation */

/* C1 blend: 1 for r <= r1, 0 for r >= r2 (smoothstep between). */
static double blend(const FluidMesh *m, double r) {
  if (r <= m->blend_r1) return 1;
  if (r >= m->blend_r2) return 0;
  double t = (m->blend_r2 - r) / (m->blend_r2 - m->blend_r1);
  return t * t * (3 - 2 * t);
}

int mesh_deform(const FluidMesh *m, double sigma, double sigma_ref, double *g, char *err, size_t errlen) {
  const TunnelSpec *s = &m->spec;
  double A0 = m->obstacle_area0, LH = s->L * s->H;
  /* fluid area after the blend is LH - sigma^2 A0; the stretch kappa in y
   * scales every area by kappa: kappa (LH - sigma^2 A0) = LH - sigma_ref^2 A0 */
  double kappa = sigma == sigma_ref ? 1 : (LH - sigma_ref * sigma_ref * A0) / (LH - sigma * sigma * A0);
  for (int v = 0; v < m->nv; v++) {
    double x = m->g0[2 * v] - s->cx, y = m->g0[2 * v + 1] - s->cy;
    double w = 1 + (sigma - 1) * blend(m, hypot(x, y));
    g[2 * v] = s->cx + w * x;
    g[2 * v + 1] = s->cy + kappa * w * y;
  }
  for (int c = 0; c < m->nc; c++) {
    double a = mesh_volume(m, g, c);
    if (!(a > 0))
      return npg_error_set(err, errlen,
                           "deformation to obstacle scale %g inverts element %d (area %.3g, rest area %.3g)",
                           sigma, c, a, mesh_volume(m, m->g0, c));
  }
  return 0;
}

double mesh_mean_edge(const FluidMesh *m) {
  double s = 0;
  for (int j = 0; j < m->nf; j++) {
    const double *a = m->g0 + 2 * m->face[2 * j], *b = m->g0 + 2 * m->face[2 * j + 1];
    s += hypot(b[0] - a[0], b[1] - a[1]);
  }
  return s / m->nf;
}

/* ---------------------------------------------------------------- numbering */

/* The position of the point (x[0], .., x[n-1]) (b bits each, n b <= 64) along
 * the n-dimensional Hilbert curve (J. Skilling, "Programming the Hilbert
 * curve", AIP Conf. Proc. 707, 2004: the axes to the curve's transposed
 * index, then its bits interleaved). */
static uint64_t hilbert_index(uint32_t *x, int n, int b) {
  uint32_t M = 1u << (b - 1), t;
  for (uint32_t Q = M; Q > 1; Q >>= 1) {
    uint32_t P = Q - 1;
    for (int i = 0; i < n; i++)
      if (x[i] & Q) x[0] ^= P;
      else {
        t = (x[0] ^ x[i]) & P;
        x[0] ^= t;
        x[i] ^= t;
      }
  }
  for (int i = 1; i < n; i++) x[i] ^= x[i - 1];
  t = 0;
  for (uint32_t Q = M; Q > 1; Q >>= 1)
    if (x[n - 1] & Q) t ^= Q - 1;
  for (int i = 0; i < n; i++) x[i] ^= t;
  uint64_t h = 0;
  for (int bit = b - 1; bit >= 0; bit--)
    for (int i = 0; i < n; i++) h = h << 1 | ((x[i] >> bit) & 1);
  return h;
}

typedef struct CellKey {
  uint64_t key;
  int c;
} CellKey;

static int cmp_key(const void *x, const void *y) {
  const CellKey *p = x, *q = y;
  if (p->key != q->key) return p->key < q->key ? -1 : 1;
  return p->c - q->c;
}

/* old[i]: the cell numbered i, along the Hilbert curve through the rest
 * centroids (the bounding box's longest side scaled to the curve's grid, so
 * the curve is not stretched along the shorter ones). */
static void order_hilbert(const FluidMesh *m, int *old) {
  int dim = m->dim, nk = m->nk, bits = dim == 3 ? 21 : 31;
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  double *mid = malloc((size_t)m->nc * dim * sizeof *mid);
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < dim; d++) {
      double s = 0;
      for (int k = 0; k < nk; k++) s += m->g0[dim * m->cell[nk * c + k] + d];
      mid[dim * c + d] = s / nk;
      lo[d] = fmin(lo[d], s / nk), hi[d] = fmax(hi[d], s / nk);
    }
  double side = 0;
  for (int d = 0; d < dim; d++) side = fmax(side, hi[d] - lo[d]);
  double scale = side > 0 ? (double)((1u << bits) - 1) / side : 0;
  CellKey *key = malloc((size_t)m->nc * sizeof *key);
  for (int c = 0; c < m->nc; c++) {
    uint32_t x[3];
    for (int d = 0; d < dim; d++) x[d] = (uint32_t)((mid[dim * c + d] - lo[d]) * scale);
    key[c] = (CellKey){hilbert_index(x, dim, bits), c};
  }
  qsort(key, m->nc, sizeof *key, cmp_key);
  for (int i = 0; i < m->nc; i++) old[i] = key[i].c;
  free(key);
  free(mid);
}

static int degree(const FluidMesh *m, int c) {
  int n = 0;
  for (int k = 0; k < m->nk; k++) n += m->nbr[m->nk * c + k] >= 0;
  return n;
}

/* Breadth-first from `start` over the cells not yet in old[0..n), each
 * cell's neighbours taken by increasing degree (Cuthill-McKee); appends
 * them to old and returns the new count. */
static int cuthill_mckee(const FluidMesh *m, int start, int *old, int n, char *seen) {
  int head = n;
  old[n++] = start, seen[start] = 1;
  while (head < n) {
    int c = old[head++], next[4], nn = 0;
    for (int k = 0; k < m->nk; k++) {
      int b = m->nbr[m->nk * c + k];
      if (b < 0 || seen[b]) continue;
      int i = nn++;
      while (i > 0 && degree(m, next[i - 1]) > degree(m, b)) next[i] = next[i - 1], i--;
      next[i] = b;
    }
    for (int i = 0; i < nn; i++) old[n++] = next[i], seen[next[i]] = 1;
  }
  return n;
}

/* old[i]: the cell numbered i by reverse Cuthill-McKee, each connected part
 * started from a pseudo-peripheral cell (the last cell of a breadth-first
 * sweep, twice). */
static void order_rcm(const FluidMesh *m, int *old) {
  char *seen = calloc(m->nc, 1);
  int n = 0;
  for (int s = 0; s < m->nc; s++) {
    if (seen[s]) continue;
    int start = s;
    for (int sweep = 0; sweep < 2; sweep++) {
      int end = cuthill_mckee(m, start, old, n, seen);
      start = old[end - 1];
      for (int i = n; i < end; i++) seen[old[i]] = 0;
    }
    n = cuthill_mckee(m, start, old, n, seen);
  }
  for (int i = 0; i < m->nc / 2; i++) {
    int t = old[i];
    old[i] = old[m->nc - 1 - i], old[m->nc - 1 - i] = t;
  }
  free(seen);
}

static int *permuted_ints(const int *a, const int *old, int n, int width) {
  int *b = malloc((size_t)n * width * sizeof *b);
  for (int i = 0; i < n; i++) memcpy(b + (size_t)width * i, a + (size_t)width * old[i], width * sizeof *b);
  return b;
}

void mesh_renumber(FluidMesh *m, MeshOrder order) {
  if (order == MO_MESHER) return;
  int nc = m->nc, nf = m->nf, nv = m->nv, nk = m->nk, dim = m->dim;
  int *oldc = malloc((size_t)nc * sizeof *oldc), *newc = malloc((size_t)nc * sizeof *newc);
  int *oldf = malloc((size_t)nf * sizeof *oldf), *newf = malloc((size_t)nf * sizeof *newf);
  int *oldv = malloc((size_t)nv * sizeof *oldv), *newv = malloc((size_t)nv * sizeof *newv);
  if (order == MO_RCM) order_rcm(m, oldc);
  else order_hilbert(m, oldc);
  /* faces and vertices by first use */
  for (int j = 0; j < nf; j++) newf[j] = -1;
  for (int v = 0; v < nv; v++) newv[v] = -1;
  int fn = 0, vn = 0;
  for (int i = 0; i < nc; i++) {
    int c = oldc[i];
    newc[c] = i;
    for (int k = 0; k < nk; k++) {
      int j = m->cface[nk * c + k], v = m->cell[nk * c + k];
      if (newf[j] < 0) oldf[fn] = j, newf[j] = fn++;
      if (newv[v] < 0) oldv[vn] = v, newv[v] = vn++;
    }
  }
  /* the mesh's vertices are its cells' (gmsh's unused nodes are dropped) */
  for (int v = 0; v < nv; v++)
    if (newv[v] < 0) oldv[vn] = v, newv[v] = vn++;
  double *g0 = malloc((size_t)nv * dim * sizeof *g0), *csign = malloc((size_t)nc * nk * sizeof *csign);
  for (int v = 0; v < nv; v++) memcpy(g0 + (size_t)dim * v, m->g0 + (size_t)dim * oldv[v], dim * sizeof *g0);
  for (int c = 0; c < nc; c++) memcpy(csign + (size_t)nk * c, m->csign + (size_t)nk * oldc[c], nk * sizeof *csign);
  int *cell = permuted_ints(m->cell, oldc, nc, nk), *cface = permuted_ints(m->cface, oldc, nc, nk);
  int *nbr = permuted_ints(m->nbr, oldc, nc, nk), *face = permuted_ints(m->face, oldf, nf, dim);
  int *fkind = permuted_ints(m->fkind, oldf, nf, 1), *fcell = permuted_ints(m->fcell, oldf, nf, 2);
  for (int i = 0; i < nc * nk; i++) {
    cell[i] = newv[cell[i]], cface[i] = newf[cface[i]];
    if (nbr[i] >= 0) nbr[i] = newc[nbr[i]];
  }
  for (int i = 0; i < nf * dim; i++) face[i] = newv[face[i]];
  for (int i = 0; i < 2 * nf; i++)
    if (fcell[i] >= 0) fcell[i] = newc[fcell[i]];
  int nb = 0;
  for (int j = 0; j < nf; j++)
    if (fkind[j] != BF_INTERIOR) m->bface[nb++] = j;
  if (m->nshift) {
    int *nshift = permuted_ints(m->nshift, oldc, nc, nk);
    free(m->nshift), m->nshift = nshift;
  }
  if (m->vmaster) {
    int *vmaster = permuted_ints(m->vmaster, oldv, nv, 1);
    for (int v = 0; v < nv; v++) vmaster[v] = newv[vmaster[v]];
    free(m->vmaster), m->vmaster = vmaster;
  }
  if (dim == 2)
    for (int q = 0; q < 3; q++) m->obstacle[q] = newv[m->obstacle[q]];
  free(m->g0), m->g0 = g0;
  free(m->csign), m->csign = csign;
  free(m->cell), m->cell = cell;
  free(m->cface), m->cface = cface;
  free(m->nbr), m->nbr = nbr;
  free(m->face), m->face = face;
  free(m->fkind), m->fkind = fkind;
  free(m->fcell), m->fcell = fcell;
  free(oldc), free(newc), free(oldf), free(newf), free(oldv), free(newv);
}
