/* test_radiosity.c — the radiosity application's numerical claims, one ctest per group:
 *
 *   visibility  exact on scenes with known answers: two facing squares (1), the same with a
 *               blocker between them (0), back to back (0), a closed box (1 wherever the
 *               faces face each other, 0 elsewhere; also turned, so that coplanar faces
 *               have rounding-noise cosines), in every Embree mode and sampling
 *   solve       (I − ρF) b = e to 1e-10 relative on a small scene, by LU, Gauss–Seidel and GMRES
 *   rowsum      form-factor rows of a closed box sum to 1 within Eq. 15's known error
 *   scene       no degenerate or inverted triangle over the parameter box; fixed topology
 *   npg         the form factors and b equal npg's full evaluator of formfactors.npg
 *
 *   test_radiosity GROUP   (run from the repository root) */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "frame.h"
#include "npg.h"
#include "radiosity.h"
#include "scene.h"
#include "visibility.h"

/* ---------------------------------------------------------------- small meshes */

typedef struct Mesh {
  long V, F;
  double g[3 * 4096];
  int tri[3 * 4096];
} Mesh;

/* A quad p00, p10, p11, p01 split into n x n cells, two triangles each, area vectors
 * along (p10 - p00) x (p01 - p00). */
static void add_quad(Mesh *m, const double *p00, const double *p10, const double *p11, const double *p01, int n) {
  long v0 = m->V;
  for (int j = 0; j <= n; j++)
    for (int i = 0; i <= n; i++) {
      double s = (double)i / n, t = (double)j / n;
      for (int d = 0; d < 3; d++)
        m->g[3 * m->V + d] =
            (1 - s) * (1 - t) * p00[d] + s * (1 - t) * p10[d] + s * t * p11[d] + (1 - s) * t * p01[d];
      m->V++;
    }
  for (int j = 0; j < n; j++)
    for (int i = 0; i < n; i++) {
      int a = (int)(v0 + j * (n + 1) + i), b = a + 1, d = a + n + 1, c = d + 1;
      int t[6] = {a, b, c, a, c, d};
      memcpy(m->tri + 3 * m->F, t, sizeof t);
      m->F += 2;
    }
}

/* Horizontal square [x0, x0 + w]^2 at height z, facing up (+1) or down (-1). */
static void add_square(Mesh *m, double x0, double w, double z, int up, int n) {
  double a[3] = {x0, x0, z}, b[3] = {x0 + w, x0, z}, c[3] = {x0 + w, x0 + w, z}, d[3] = {x0, x0 + w, z};
  if (up > 0)
    add_quad(m, a, b, c, d, n);
  else
    add_quad(m, a, d, c, b, n);
}

/* The unit-ish box [0, 2] x [0, 1.5] x [0, 1], n x n cells per wall, facing in. */
static void box(Mesh *m, int n) {
  const double X = 2, Y = 1.5, Z = 1;
  double c[8][3];
  for (int k = 0; k < 8; k++) c[k][0] = (k & 1) * X, c[k][1] = (k >> 1 & 1) * Y, c[k][2] = (k >> 2 & 1) * Z;
  m->V = m->F = 0;
  add_quad(m, c[0], c[1], c[3], c[2], n); /* floor: x then y -> +z */
  add_quad(m, c[4], c[6], c[7], c[5], n); /* ceiling -> -z */
  add_quad(m, c[0], c[2], c[6], c[4], n); /* x = 0: y then z -> +x */
  add_quad(m, c[1], c[5], c[7], c[3], n); /* x = X -> -x */
  add_quad(m, c[0], c[4], c[5], c[1], n); /* y = 0: z then x -> +y */
  add_quad(m, c[2], c[3], c[7], c[6], n); /* y = Y -> -y */
}

static double *vis_of(const Mesh *m, int k, VisMode mode) {
  char err[256];
  Visibility *vis = vis_new(m->V, m->F, m->tri, k, 2, mode, err, sizeof err);
  if (!vis) fail_msg("%s", err);
  double *v = malloc(sizeof(double) * m->F * m->F);
  if (vis_compute(vis, m->g, v, err, sizeof err)) fail_msg("%s", err);
  vis_free(vis);
  return v;
}

static const VisMode modes[3] = {VIS_SINGLE, VIS_STREAM, VIS_PACKET};
static const int samples[3] = {1, 4, 16};

/* ---------------------------------------------------------------- visibility */

static void test_facing_squares(void **state) {
  for (int blocked = 0; blocked < 2; blocked++)
    for (int mi = 0; mi < 3; mi++)
      for (int ki = 0; ki < 3; ki++) {
        Mesh *m = calloc(1, sizeof *m);
        add_square(m, 0, 1, 0, +1, 2);  /* faces 0..7 */
        add_square(m, 0, 1, 1, -1, 2);  /* faces 8..15, above, facing down */
        if (blocked) add_square(m, -1, 3, 0.5, +1, 1); /* faces 16, 17 between them */
        double *v = vis_of(m, samples[ki], modes[mi]);
        for (long i = 0; i < m->F; i++)
          for (long j = 0; j < m->F; j++) {
            int lo_i = i < 8, hi_i = i >= 8 && i < 16, bl_i = i >= 16;
            int lo_j = j < 8, hi_j = j >= 8 && j < 16, bl_j = j >= 16;
            double want = 0;
            if ((lo_i && hi_j) || (hi_i && lo_j)) want = blocked ? 0 : 1;
            if ((bl_i && hi_j) || (hi_i && bl_j)) want = 1; /* the blocker's top sees the upper square */
            if (v[i * m->F + j] != want)
              fail_msg("blocked %d, %s, k %d: v[%ld][%ld] = %g, want %g", blocked, vis_mode_name(modes[mi]),
                       samples[ki], i, j, v[i * m->F + j], want);
          }
        free(v);
        free(m);
      }
}

static void test_back_to_back(void **state) {
  Mesh *m = calloc(1, sizeof *m);
  add_square(m, 0, 1, 0, -1, 1); /* facing down */
  add_square(m, 0, 1, 1, +1, 1); /* above it, facing up: each is behind the other */
  double *v = vis_of(m, 4, VIS_STREAM);
  for (long q = 0; q < m->F * m->F; q++) assert_true(v[q] == 0);
  free(v);
  free(m);
}

static void test_convex_box(void **state) {
  Mesh *m = calloc(1, sizeof *m);
  box(m, 4);
  for (int mi = 0; mi < 3; mi++)
    for (int ki = 0; ki < 3; ki++) {
      double *v = vis_of(m, samples[ki], modes[mi]);
      long ones = 0;
      for (long i = 0; i < m->F; i++)
        for (long j = 0; j < m->F; j++) {
          /* different walls face each other; faces of one wall are coplanar (cosine 0) */
          int same_wall = i / 32 == j / 32;
          double want = same_wall ? 0 : 1;
          ones += want == 1;
          if (v[i * m->F + j] != want)
            fail_msg("%s, k %d: v[%ld][%ld] = %g, want %g", vis_mode_name(modes[mi]), samples[ki], i, j,
                     v[i * m->F + j], want);
        }
      assert_true(ones == m->F * (m->F - 32));
      free(v);
    }
  /* the same box turned about an oblique axis: faces of one wall now have cosines of
   * ±1e-16 from rounding instead of exactly 0, and must still get v = 0 */
  const double ca = cos(0.7), sa = sin(0.7), cb = cos(0.3), sb = sin(0.3);
  for (long a = 0; a < m->V; a++) {
    double *x = m->g + 3 * a, y0 = ca * x[0] - sa * x[1], y1 = sa * x[0] + ca * x[1];
    x[0] = y0, x[1] = cb * y1 - sb * x[2], x[2] = sb * y1 + cb * x[2];
  }
  double *v = vis_of(m, 4, VIS_STREAM);
  for (long i = 0; i < m->F; i++)
    for (long j = 0; j < m->F; j++)
      if (v[i * m->F + j] != (i / 32 == j / 32 ? 0 : 1))
        fail_msg("turned box: v[%ld][%ld] = %g", i, j, v[i * m->F + j]);
  free(v);
  free(m);
}

/* The scene's furniture really occludes: some pairs are partly visible, v is symmetric. */
static void test_scene_partial(void **state) {
  Scene s;
  char err[256];
  assert_int_equal(scene_new(300, NULL, &s, err, sizeof err), 0);
  Mesh m = {0};
  (void)m;
  Visibility *vis = vis_new(s.V, s.F, s.tri, 4, 2, VIS_STREAM, err, sizeof err);
  assert_non_null(vis);
  double *v = malloc(sizeof(double) * s.F * s.F);
  assert_int_equal(vis_compute(vis, s.g, v, err, sizeof err), 0);
  long partial = 0, zero_facing = 0;
  for (long i = 0; i < s.F; i++)
    for (long j = 0; j < s.F; j++) {
      assert_true(v[i * s.F + j] == v[j * s.F + i]);
      partial += v[i * s.F + j] > 0 && v[i * s.F + j] < 1;
    }
  (void)zero_facing;
  assert_true(partial > 0);
  free(v);
  vis_free(vis);
  scene_free(&s);
}

/* ---------------------------------------------------------------- solve */

static void test_solve_residual(void **state) {
  Scene s;
  char err[256];
  assert_int_equal(scene_new(300, NULL, &s, err, sizeof err), 0);
  FullRadiosity fr;
  assert_int_equal(frame_new(&fr, &s, 4, 2, VIS_STREAM, SOLVER_LU, err, sizeof err), 0);
  if (frame_compute(&fr, NULL, err, sizeof err)) fail_msg("%s", err);
  double res_lu = radiosity_residual(s.F, s.rho, fr.p, s.e, fr.b);
  double *b_lu = malloc(sizeof(double) * s.F);
  memcpy(b_lu, fr.b, sizeof(double) * s.F);
  if (frame_solve(&fr, SOLVER_GAUSS_SEIDEL, NULL, err, sizeof err)) fail_msg("%s", err);
  double res_gs = radiosity_residual(s.F, s.rho, fr.p, s.e, fr.b);
  int sweeps = fr.sweeps;
  double diff = 0, big = 0;
  for (long f = 0; f < s.F; f++) diff = fmax(diff, fabs(fr.b[f] - b_lu[f])), big = fmax(big, fabs(b_lu[f]));
  if (frame_solve(&fr, SOLVER_GMRES, NULL, err, sizeof err)) fail_msg("%s", err);
  double res_gmres = radiosity_residual(s.F, s.rho, fr.p, s.e, fr.b), diff_gmres = 0;
  for (long f = 0; f < s.F; f++) diff_gmres = fmax(diff_gmres, fabs(fr.b[f] - b_lu[f]));
  print_message("F %ld: residual LU %.2e, Gauss-Seidel %.2e (%d sweeps), GMRES %.2e (%d products); "
                "max differences to LU %.2e, %.2e\n",
                s.F, res_lu, res_gs, sweeps, res_gmres, fr.sweeps, diff / big, diff_gmres / big);
  assert_true(sweeps > 0 && fr.sweeps > 0); /* neither fell back to LU */
  assert_true(res_lu <= 1e-10);
  assert_true(res_gs <= 1e-10);
  assert_true(res_gmres <= 1e-10);
  assert_true(diff <= 1e-10 * big);
  assert_true(diff_gmres <= 1e-10 * big);
  /* the light goes somewhere: every wall receives some, the openings keep their emission */
  for (long f = 0; f < s.F; f++) {
    assert_true(fr.b[f] >= s.e[f] - 1e-12);
    if (s.rho[f] == 0) assert_true(fabs(fr.b[f] - s.e[f]) <= 1e-12);
  }
  /* a wrong matrix is caught: the residual of b against another albedo is large */
  double *rho2 = malloc(sizeof(double) * s.F);
  for (long f = 0; f < s.F; f++) rho2[f] = 0.5 * s.rho[f];
  assert_true(radiosity_residual(s.F, rho2, fr.p, s.e, fr.b) > 1e-3);
  free(rho2);
  free(b_lu);
  frame_free(&fr);
  scene_free(&s);
}

/* ---------------------------------------------------------------- row sums */

/* Σ_j F_ij over a closed box (v = 1 between walls) is exactly 1 for the true form factors.
 * Eq. 15 evaluates the kernel A_j cosθ_i cosθ_j / (π r²) at the centroids only; for a
 * face of size h at distance r that is a midpoint rule with relative error O((h / r)²).
 * Summed over a row: O(h²) for a face far from every edge of its wall (all its r are
 * O(1)), O(1) for a face touching an edge (its neighbours across the edge have r ~ h),
 * and O(h) for the mean over all rows (a fraction O(h) of the faces touch an edge).
 * Measured: mean |Σ − 1| 0.060 at 6 x 6 cells per wall and 0.031 at 12 x 12 (ratio 0.52),
 * the most interior face 0.0060 and 0.0015 (ratio 0.25), the worst row 0.36 at both.
 * The bounds below hold those orders with margin: mean within 0.08 and falling at least
 * like h (ratio <= 0.6), interior within 0.01 and falling like h² (ratio <= 0.35), no row
 * outside [0.8, 1.5]. A missing π, A_i for A_j, a transposed row or a cosine of the wrong
 * sign each break them by far. */
static double rowsum_stats(int n, double *max_dev, double *interior) {
  Mesh *m = calloc(1, sizeof *m);
  box(m, n);
  long F = m->F;
  double *v = vis_of(m, 1, VIS_STREAM), *p = malloc(sizeof(double) * F * F);
  radiosity_form_factors(m->V, F, m->g, m->tri, v, p, 2);
  double mean = 0, mx = 0, best_interior = 1e9, best_dist = -1;
  for (long i = 0; i < F; i++) {
    double sum = 0;
    for (long j = 0; j < F; j++) sum += p[i * F + j];
    mean += fabs(sum - 1);
    mx = fmax(mx, fabs(sum - 1));
    if (sum > 1.5 || sum < 0.8) fail_msg("n %d: row %ld sums to %g", n, i, sum);
    /* distance of the centroid to the nearest edge of its wall */
    const int *t = m->tri + 3 * i;
    double c[3];
    for (int d = 0; d < 3; d++) c[d] = (m->g[3 * t[0] + d] + m->g[3 * t[1] + d] + m->g[3 * t[2] + d]) / 3;
    const double ext[3] = {2, 1.5, 1};
    double dist = 1e9;
    for (int d = 0; d < 3; d++) {
      if (c[d] < 1e-12 || c[d] > ext[d] - 1e-12) continue; /* the wall's own axis */
      dist = fmin(dist, fmin(c[d], ext[d] - c[d]));
    }
    if (dist > best_dist) best_dist = dist, best_interior = fabs(sum - 1);
  }
  *max_dev = mx;
  *interior = best_interior;
  free(v);
  free(p);
  free(m);
  return mean / F;
}

static void test_rowsum(void **state) {
  double mx6, in6, mx12, in12;
  double mean6 = rowsum_stats(6, &mx6, &in6), mean12 = rowsum_stats(12, &mx12, &in12);
  print_message("6x6 per wall: mean |sum-1| %.4f, max %.4f, interior %.4f; 12x12: mean %.4f, max %.4f, interior %.4f\n",
                mean6, mx6, in6, mean12, mx12, in12);
  assert_true(mean6 <= 0.08);
  assert_true(mean12 <= 0.6 * mean6);
  assert_true(in6 <= 0.01);
  assert_true(in12 <= 0.35 * in6);
  assert_true(mx6 <= 0.5 && mx12 <= 0.5);
}

/* ---------------------------------------------------------------- scene */

static void test_scene_box(void **state) {
  Scene s;
  char err[256];
  assert_int_equal(scene_new(800, NULL, &s, err, sizeof err), 0);
  print_message("scene: %ld faces, %ld vertices, %d patches\n", s.F, s.V, s.npatch);
  assert_true(s.F > 600 && s.F < 1000);
  double *g = malloc(sizeof(double) * 3 * s.V), *ref = malloc(sizeof(double) * 3 * s.V);
  SceneParams p;
  scene_param_nominal(&p);
  scene_place(&s, &p, ref);
  double a_nominal = scene_min_area(&s, ref, NULL, NULL, NULL);
  double amin = INFINITY, cmin = 1;
  unsigned long long rng = 12345;
  int corners = 1 << SCENE_NGEOM;
  for (int c = 0; c < corners + 300; c++) {
    double t[SCENE_NGEOM];
    for (int k = 0; k < SCENE_NGEOM; k++) {
      rng = rng * 6364136223846793005ull + 1442695040888963407ull;
      t[k] = c < corners ? (c >> k & 1) : (double)(rng >> 11) / 9007199254740992.0;
    }
    scene_param_at(t, &p);
    scene_place(&s, &p, g);
    double cs;
    long worst;
    double a = scene_min_area(&s, g, ref, &worst, &cs);
    if (!(a > 0.02 * a_nominal) || !(cs > 0.95))
      fail_msg("parameter point %d: face %ld has area %g (nominal minimum %g), normal cosine %g", c, worst, a,
               a_nominal, cs);
    amin = fmin(amin, a), cmin = fmin(cmin, cs);
  }
  print_message("minimum area %.4g m^2 (nominal %.4g), minimum normal cosine %.4f\n", amin, a_nominal, cmin);
  /* fixed topology: another starting point gives the same faces */
  Scene s2;
  scene_param_hi(&p);
  assert_int_equal(scene_new(800, &p, &s2, err, sizeof err), 0);
  assert_int_equal(s2.F, s.F);
  assert_int_equal(s2.V, s.V);
  assert_memory_equal(s2.tri, s.tri, sizeof(int) * 3 * s.F);
  assert_memory_equal(s2.rho, s.rho, sizeof(double) * s.F);
  /* openings emit, with albedo 0; nothing else emits */
  long emitters = 0;
  for (long f = 0; f < s.F; f++) {
    assert_true((s.e[f] > 0) == (s.rho[f] == 0));
    emitters += s.e[f] > 0;
  }
  assert_true(emitters >= 6);
  /* the area vectors point into the room: the floor's up, the living room's sky down */
  for (long f = 0; f < s.F; f++) {
    const int *t = s.tri + 3 * f;
    const double *a = s.g + 3 * t[0], *b = s.g + 3 * t[1], *c = s.g + 3 * t[2];
    double nz = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if (s.mat[f] == MAT_LIVING_FLOOR || s.mat[f] == MAT_BED_FLOOR) assert_true(nz > 0);
    if (s.mat[f] == MAT_SKYLIGHT) assert_true(nz < 0);
  }
  scene_free(&s2);
  free(g);
  free(ref);
  scene_free(&s);
}

/* ---------------------------------------------------------------- npg's full evaluator */

static void test_npg_full(void **state) {
  Scene s;
  char err[256];
  SceneParams prm;
  double t[SCENE_NGEOM] = {0.3, 0.7, 0.2, 0.9, 0.4, 0.6, 0.8, 0.1, 0.75};
  scene_param_at(t, &prm);
  assert_int_equal(scene_new(160, &prm, &s, err, sizeof err), 0);
  long F = s.F;
  FullRadiosity fr;
  assert_int_equal(frame_new(&fr, &s, 4, 2, VIS_STREAM, SOLVER_LU, err, sizeof err), 0);
  if (frame_compute(&fr, NULL, err, sizeof err)) fail_msg("%s", err);

  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  NpgProgram *prog = npg_compile("examples/radiosity/formfactors.npg", &opt);
  if (!npg_ok(prog)) fail_msg("%s", npg_error(prog));
  NpgFull *nf = npg_full_new(prog, NPG_TCC);
  assert_string_equal(npg_full_error(nf), "");
  double *tri = malloc(sizeof(double) * 3 * F);
  for (long q = 0; q < 3 * F; q++) tri[q] = s.tri[q];
  long st[2] = {F, 3}, sf[1] = {F}, sg[2] = {s.V, 3}, sv[2] = {F, F};
  if (npg_full_set_param(nf, "tri", 2, st, tri, "tri") || npg_full_set_param(nf, "rho", 1, sf, s.rho, "rho") ||
      npg_full_set(nf, "g", 2, sg, s.g, "g") || npg_full_set(nf, "e", 1, sf, s.e, "e") ||
      npg_full_set(nf, "v", 2, sv, fr.v, "v") || npg_full_eval(nf, 0))
    fail_msg("%s", npg_full_error(nf));
  size_t np = 0, nb = 0;
  const double *p = npg_full_get(nf, "p", &np), *b = npg_full_get(nf, "b", &nb);
  assert_non_null(p);
  assert_non_null(b);
  assert_int_equal(np, (size_t)(F * F));
  assert_int_equal(nb, (size_t)F);
  double dp = 0, pmax = 0, db = 0, bmax = 0;
  long nonzero = 0;
  for (long q = 0; q < F * F; q++) {
    dp = fmax(dp, fabs(p[q] - fr.p[q]));
    pmax = fmax(pmax, fabs(fr.p[q]));
    nonzero += fr.p[q] != 0;
    /* entrywise too, where the entry is not tiny */
    if (fabs(fr.p[q]) > 1e-8 * pmax && fabs(p[q] - fr.p[q]) > 1e-12 * fabs(fr.p[q]))
      fail_msg("p[%ld]: ours %.17g, npg %.17g", q, fr.p[q], p[q]);
  }
  for (long f = 0; f < F; f++) db = fmax(db, fabs(b[f] - fr.b[f])), bmax = fmax(bmax, fabs(fr.b[f]));
  print_message("F %ld: %ld nonzero form factors; max |p - p_npg| / max |p| = %.2e, b: %.2e\n", F, nonzero, dp / pmax,
                db / bmax);
  assert_true(nonzero > F * F / 10);
  assert_true(dp <= 1e-12 * pmax);
  assert_true(db <= 1e-12 * bmax);
  free(tri);
  npg_full_free(nf);
  npg_free(prog);
  frame_free(&fr);
  scene_free(&s);
}

int main(int argc, char **argv) {
  const char *group = argc > 1 ? argv[1] : "all";
  int all = !strcmp(group, "all"), rc = 0, ran = 0;
  if (all || !strcmp(group, "visibility")) {
    const struct CMUnitTest t[] = {cmocka_unit_test(test_facing_squares), cmocka_unit_test(test_back_to_back),
                                   cmocka_unit_test(test_convex_box), cmocka_unit_test(test_scene_partial)};
    rc |= cmocka_run_group_tests_name("visibility", t, NULL, NULL), ran = 1;
  }
  if (all || !strcmp(group, "solve")) {
    const struct CMUnitTest t[] = {cmocka_unit_test(test_solve_residual)};
    rc |= cmocka_run_group_tests_name("solve", t, NULL, NULL), ran = 1;
  }
  if (all || !strcmp(group, "rowsum")) {
    const struct CMUnitTest t[] = {cmocka_unit_test(test_rowsum)};
    rc |= cmocka_run_group_tests_name("rowsum", t, NULL, NULL), ran = 1;
  }
  if (all || !strcmp(group, "scene")) {
    const struct CMUnitTest t[] = {cmocka_unit_test(test_scene_box)};
    rc |= cmocka_run_group_tests_name("scene", t, NULL, NULL), ran = 1;
  }
  if (all || !strcmp(group, "npg")) {
    const struct CMUnitTest t[] = {cmocka_unit_test(test_npg_full)};
    rc |= cmocka_run_group_tests_name("npg", t, NULL, NULL), ran = 1;
  }
  if (!ran) {
    fprintf(stderr, "test_radiosity: unknown group '%s'\n", group);
    return 2;
  }
  return rc;
}
