/* test_points.c — the numerical claims of examples/points (issue 17):
 *
 *   expansions  two well-separated clusters: the FMM's multipole, M2L and
 *               local expansions reproduce the direct kernel sum, the
 *               error falling geometrically in p
 *   fmm         the FMM gather equals the dense gather to a tolerance set by
 *               p on random point sets (a sphere seen from inside, random
 *               strengths) and on the Cornell box, without and with
 *               point-based visibility (the dense gather then uses the
 *               plan's leaf-pair visibility)
 *   visibility  point-based visibility agrees with Embree ray casting on two
 *               facing patches with a wall between them and without
 *
 * test_points GROUP runs one group (ctest runs each as its own test). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "dense.h"
#include "fmm.h"
#include "kernel.h"
#include "octree.h"
#include "rooms.h"
#include "surfels.h"
#include "visibility.h"

static double uniform(unsigned long long *st) {
  *st = *st * 6364136223846793005ULL + 1442695040888963407ULL;
  return (double)(*st >> 11) * 0x1.0p-53;
}

static double rel_error(const double *a, const double *ref, long n) {
  double d = 0, r = 0;
  for (long k = 0; k < n; k++) d += (a[k] - ref[k]) * (a[k] - ref[k]), r += ref[k] * ref[k];
  return sqrt(d / r);
}

/* n points in the box [lo, lo + size], normals within ~10° of `axis`,
 * equal weights, grey albedo, no emission. */
static void fill_cluster(Surfels *s, long from, long n, const double lo[3], const double size[3], const double axis[3],
                         unsigned long long *st) {
  for (long i = from; i < from + n; i++) {
    s->x[i] = lo[0] + size[0] * uniform(st), s->y[i] = lo[1] + size[1] * uniform(st);
    s->z[i] = lo[2] + size[2] * uniform(st);
    double nv[3], len = 0;
    for (int k = 0; k < 3; k++) nv[k] = axis[k] + 0.35 * (uniform(st) - 0.5), len += nv[k] * nv[k];
    len = sqrt(len);
    s->nx[i] = nv[0] / len, s->ny[i] = nv[1] / len, s->nz[i] = nv[2] / len;
    s->w[i] = 1e-4;
    for (int ch = 0; ch < 3; ch++) s->rho[3 * i + ch] = 0.5, s->e[3 * i + ch] = 0;
    s->tri[i] = 0;
  }
}

/* ------------------------------------------------------------ expansions */

/* Targets in one cluster, sources in the other, so every interaction goes
 * through P2M, M2L (cubes three apart) and L2P. */
static void test_expansions_converge(void **state) {
  (void)state;
  const long n = 3000;
  Surfels s;
  assert_int_equal(surfels_alloc(&s, 2 * n), 0);
  unsigned long long st = 7;
  const double size[3] = {0.2, 0.2, 0.2}, loA[3] = {0.0, 0.4, 0.4}, loB[3] = {0.8, 0.4, 0.4};
  fill_cluster(&s, 0, n, loA, size, (double[3]){1, 0, 0}, &st);
  fill_cluster(&s, n, n, loB, size, (double[3]){-1, 0, 0}, &st);
  for (long i = n; i < 2 * n; i++) s.e[3 * i] = uniform(&st), s.e[3 * i + 1] = 1, s.e[3 * i + 2] = uniform(&st);
  Octree t;
  assert_int_equal(octree_build(&s, 200, &t), 0);
  double *b = malloc(sizeof(double) * 6 * (size_t)n), *g = malloc(sizeof(double) * 6 * (size_t)n);
  double *ref = malloc(sizeof(double) * 6 * (size_t)n);
  for (long i = 0; i < 2 * n; i++) /* strengths on the sources only (tree order) */
    for (int ch = 0; ch < 3; ch++) b[3 * i + ch] = s.nx[i] < 0 ? s.e[3 * i + ch] : 0;
  dense_gather(&s, &t, NULL, b, ref);
  double err[8];
  for (int p = 2; p <= 7; p++) {
    Fmm f;
    assert_int_equal(fmm_plan(&f, &s, &t, p, NULL), 0);
    assert_true(f.stats.m2l > 0); /* the clusters meet through M2L … */
    for (long k = 0; k < f.p2p.n; k++) /* … and never directly */
      assert_true((t.node[f.p2p.pair[k].tgt].c[0] < 0.5) == (t.node[f.p2p.pair[k].src].c[0] < 0.5));
    fmm_gather(&f, b, g);
    err[p] = rel_error(g, ref, 6 * n);
    printf("expansions: p = %d, relative error %.3e\n", p, err[p]);
    fmm_free(&f);
  }
  /* geometric: every order gains at least a factor 2, and five orders 10³ */
  for (int p = 3; p <= 7; p++) assert_true(err[p] < 0.5 * err[p - 1]);
  assert_true(err[7] < 1e-3 * err[2]);
  assert_true(err[4] < 1e-3);
  free(b), free(g), free(ref);
  octree_free(&t);
  surfels_free(&s);
}

/* ------------------------------------------------------------ FMM against dense */

/* The tolerance order p buys: the expansions gain about a factor 10 per
 * order (test_expansions_converge), 10^(1/2 − p). */
static double tolerance(int p) { return pow(10.0, 0.5 - p); }

/* Random points on a sphere, normals inward: every pair faces. */
static void test_fmm_sphere(void **state) {
  (void)state;
  const long n = 6000;
  Surfels s;
  assert_int_equal(surfels_alloc(&s, n), 0);
  unsigned long long st = 11;
  for (long i = 0; i < n; i++) {
    double v[3], len;
    do {
      for (int k = 0; k < 3; k++) v[k] = 2 * uniform(&st) - 1;
      len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    } while (len > 1 || len < 0.1);
    s.x[i] = 0.5 * v[0] / len, s.y[i] = 0.5 * v[1] / len, s.z[i] = 0.5 * v[2] / len;
    s.nx[i] = -v[0] / len, s.ny[i] = -v[1] / len, s.nz[i] = -v[2] / len;
    s.w[i] = M_PI / (double)n;
    for (int ch = 0; ch < 3; ch++) s.rho[3 * i + ch] = 0.5, s.e[3 * i + ch] = 0;
    s.tri[i] = 0;
  }
  Octree t;
  assert_int_equal(octree_build(&s, 64, &t), 0);
  double *b = malloc(sizeof(double) * 3 * (size_t)n), *g = malloc(sizeof(double) * 3 * (size_t)n);
  double *ref = malloc(sizeof(double) * 3 * (size_t)n);
  for (long k = 0; k < 3 * n; k++) b[k] = uniform(&st);
  dense_gather(&s, &t, NULL, b, ref);
  for (int p = 3; p <= 6; p += p == 4 ? 2 : 1) {
    Fmm f;
    assert_int_equal(fmm_plan(&f, &s, &t, p, NULL), 0);
    assert_true(f.stats.m2l > 0);
    fmm_gather(&f, b, g);
    double e = rel_error(g, ref, 3 * n), tol = tolerance(p);
    printf("sphere: p = %d, %ld M2L, relative gather error %.3e (tolerance %.1e)\n", p, f.stats.m2l, e, tol);
    assert_true(e < tol);
    fmm_free(&f);
  }
  free(b), free(g), free(ref);
  octree_free(&t);
  surfels_free(&s);
}

/* The Cornell box, random b, without and with point-based visibility. */
/* One FMM gather of random strengths against the dense gather that uses
 * the plan's leaf-pair visibility (`vis` NULL: none): the relative error,
 * and the plan's M2L count and hidden pairs dropped. */
static double fmm_against_dense(const Surfels *s, const Octree *t, Visibility *vis, int p, unsigned long long seed,
                                long *m2l, long *hidden) {
  long n = s->n;
  double *b = malloc(sizeof(double) * 3 * (size_t)n), *g = malloc(sizeof(double) * 3 * (size_t)n);
  double *ref = malloc(sizeof(double) * 3 * (size_t)n);
  assert_true(b && g && ref);
  for (long k = 0; k < 3 * n; k++) b[k] = uniform(&seed);
  Fmm f;
  assert_int_equal(fmm_plan(&f, s, t, p, vis), 0);
  float *table = fmm_leaf_visibility(&f);
  assert_non_null(table);
  dense_gather(s, t, table, b, ref);
  fmm_gather(&f, b, g);
  double e = rel_error(g, ref, 3 * n);
  *m2l = f.stats.m2l, *hidden = f.stats.dropped_hidden;
  free(table);
  fmm_free(&f);
  free(b), free(g), free(ref);
  return e;
}

static void test_fmm_cornell(void **state) {
  (void)state;
  TriScene sc;
  assert_int_equal(scene_cornell_box(&sc), 0);
  Surfels s;
  assert_int_equal(scene_sample(&sc, 12000, 3, &s), 0);
  Octree t;
  assert_int_equal(octree_build(&s, 256, &t), 0);
  Visibility vis;
  visibility_init(&vis, &s, &t);
  for (int with_vis = 0; with_vis < 2; with_vis++)
    for (int p = 3 + with_vis; p <= 4; p++) {
      long m2l, hidden;
      double e = fmm_against_dense(&s, &t, with_vis ? &vis : NULL, p, 5, &m2l, &hidden), tol = tolerance(p);
      printf("cornell box, visibility %s: p = %d, %ld M2L, %ld hidden pairs dropped, relative error %.3e\n",
             with_vis ? "on" : "off", p, m2l, hidden, e);
      assert_true(m2l > 0);
      assert_true(e < tol);
      if (with_vis) assert_true(hidden > 0);
    }
  octree_free(&t);
  surfels_free(&s);
  triscene_free(&sc);
}

/* The two rooms of examples/radiosity, converted (rooms.c): the FMM with
 * point visibility against the dense gather with the plan's visibility, as
 * on the box; the partition, the furniture and the thick walls hide pairs. */
static void test_fmm_rooms(void **state) {
  (void)state;
  TriScene sc;
  char err[256];
  assert_int_equal(scene_rooms(&sc, 400, err, sizeof err), 0);
  assert_true(sc.nt >= 300);
  double emitted = 0;
  for (int f = 0; f < sc.nt; f++) emitted += sc.emission[3 * f];
  assert_true(emitted > 0); /* the windows and the skylight */
  Surfels s;
  assert_int_equal(scene_sample(&sc, 8000, 3, &s), 0);
  Octree t;
  assert_int_equal(octree_build(&s, 128, &t), 0);
  Visibility vis;
  visibility_init(&vis, &s, &t);
  long m2l, hidden;
  double e = fmm_against_dense(&s, &t, &vis, 4, 9, &m2l, &hidden);
  printf("two rooms (%d faces, %ld points): p = 4, %ld M2L, %ld hidden pairs dropped, relative error %.3e\n", sc.nt, s.n,
         m2l, hidden, e);
  assert_true(e < tolerance(4));
  assert_true(hidden > 0);
  octree_free(&t);
  surfels_free(&s);
  triscene_free(&sc);
}

/* A plan without expansions says that it falls back to direct sums (2,000
 * points in leaves of 256: one level, no cube well separated), and one with
 * expansions does not (12,000 points in leaves of 32). */
static void test_fmm_fallback(void **state) {
  (void)state;
  TriScene sc;
  assert_int_equal(scene_cornell_box(&sc), 0);
  for (int big = 0; big < 2; big++) {
    Surfels s;
    assert_int_equal(scene_sample(&sc, big ? 12000 : 2000, 3, &s), 0);
    Octree t;
    assert_int_equal(octree_build(&s, big ? 32 : 256, &t), 0);
    Fmm f;
    assert_int_equal(fmm_plan(&f, &s, &t, 3, NULL), 0);
    char msg[512] = "";
    int direct = fmm_falls_back(&f, msg, sizeof msg);
    printf("N = %ld, leaf %d: M2L %ld, M2P %ld, P2L %ld; %s\n", s.n, t.leaf_size, f.stats.m2l, f.stats.m2p,
           f.stats.p2l, direct ? msg : "expansions used");
    assert_int_equal(direct, !big);
    assert_int_equal(direct, f.stats.m2l + f.stats.m2p + f.stats.p2l == 0);
    if (direct) assert_non_null(strstr(msg, "falls back to direct sums"));
    fmm_free(&f);
    octree_free(&t);
    surfels_free(&s);
  }
  triscene_free(&sc);
}

/* ------------------------------------------------------------ visibility */

/* Pairs between the two patches, weighed by the form factor: the share on
 * which point-based visibility (point–point and the plan's hierarchical
 * leaf table) agrees with ray casting, and the visible share by rays. */
static void patches_agreement(int wall, double *point, double *hier, double *ray_visible) {
  TriScene sc;
  assert_int_equal(scene_two_patches(&sc, wall), 0);
  Surfels s;
  assert_int_equal(scene_sample(&sc, wall ? 6000 : 3000, 1, &s), 0);
  Octree t;
  assert_int_equal(octree_build(&s, 64, &t), 0);
  Visibility vis;
  visibility_init(&vis, &s, &t);
  Fmm f;
  assert_int_equal(fmm_plan(&f, &s, &t, 3, &vis), 0);
  float *table = fmm_leaf_visibility(&f);
  assert_non_null(table);
  RayCaster rc;
  assert_int_equal(raycast_open(&rc, &sc), 0);
  long *leaf_of = malloc(sizeof(long) * (size_t)s.n);
  for (long a = 0; a < t.nleaf; a++)
    for (long i = t.node[t.leaf[a]].start; i < t.node[t.leaf[a]].start + t.node[t.leaf[a]].count; i++) leaf_of[i] = a;
  double w = 0, wp = 0, wh = 0, wr = 0;
  for (long i = 0; i < s.n; i += 37) {
    if (fabs(s.y[i]) > 1e-9) continue; /* targets on the bottom patch */
    for (long j = 0; j < s.n; j++) {
      if (fabs(s.y[j] - 1) > 1e-9) continue; /* sources on the top patch */
      double k = s.w[j] * kernel_ff(s.x[i], s.y[i], s.z[i], s.nx[i], s.ny[i], s.nz[i], s.x[j], s.y[j], s.z[j],
                                    s.nx[j], s.ny[j], s.nz[j], s.w[j]);
      int ray = raycast_points(&rc, &s, i, j);
      w += k, wr += k * ray;
      wp += k * (visibility_points(&vis, i, j) == ray);
      wh += k * (1 - fabs(table[leaf_of[i] * t.nleaf + leaf_of[j]] - ray));
    }
  }
  *point = wp / w, *hier = wh / w, *ray_visible = wr / w;
  free(leaf_of);
  raycast_close(&rc);
  free(table);
  fmm_free(&f);
  octree_free(&t);
  surfels_free(&s);
  triscene_free(&sc);
}

static void test_visibility_wall(void **state) {
  (void)state;
  double point, hier, ray;
  patches_agreement(1, &point, &hier, &ray);
  printf("wall between the patches: rays see %.4f; agreement point-point %.4f, hierarchical %.4f\n", ray, point, hier);
  assert_true(ray < 1e-12); /* the wall hides everything */
  assert_true(point > 0.95);
  assert_true(hier > 0.95);
}

static void test_visibility_open(void **state) {
  (void)state;
  double point, hier, ray;
  patches_agreement(0, &point, &hier, &ray);
  printf("nothing between the patches: rays see %.4f; agreement point-point %.4f, hierarchical %.4f\n", ray, point,
         hier);
  assert_true(ray > 1 - 1e-12);
  assert_true(point > 0.999);
  assert_true(hier > 0.999);
}

int main(int argc, char **argv) {
  const char *group = argc > 1 ? argv[1] : "all";
  const struct CMUnitTest expansions[] = {cmocka_unit_test(test_expansions_converge)};
  const struct CMUnitTest fmm[] = {cmocka_unit_test(test_fmm_sphere), cmocka_unit_test(test_fmm_cornell),
                                    cmocka_unit_test(test_fmm_rooms), cmocka_unit_test(test_fmm_fallback)};
  const struct CMUnitTest visibility[] = {cmocka_unit_test(test_visibility_wall), cmocka_unit_test(test_visibility_open)};
  int failed = 0, all = !strcmp(group, "all");
  if (all || !strcmp(group, "expansions")) failed += cmocka_run_group_tests_name("expansions", expansions, NULL, NULL);
  if (all || !strcmp(group, "fmm")) failed += cmocka_run_group_tests_name("fmm", fmm, NULL, NULL);
  if (all || !strcmp(group, "visibility")) failed += cmocka_run_group_tests_name("visibility", visibility, NULL, NULL);
  return failed ? 1 : 0;
}
