/* test_fluids.c — the full-space solver's claims (paper §5, appendix A.1) on
 * a small tunnel mesh, one ctest each (argv[1] names the test):
 *
 *   advection_energy             A(f) antisymmetric for divergence-free f: the energy
 *                                1/2 u^T V u changes by < 1e-10 relative in an RK4 step
 *   diffusion_projection_energy  diffusion and projection never increase it; the
 *                                projection is V-orthogonal (Pythagoras)
 *   divergence_free              projected fluxes on a moving mesh: div f = 0 and
 *                                D f = D h to solver tolerance, with either solver
 *                                (stream function by CHOLMOD, KKT by UMFPACK), and the
 *                                two agree
 *   inversion_refused            a deformation that inverts an element is refused,
 *                                naming it; deformations keep the fluid area, and
 *                                fixed obstacles are linear in their scale
 *   operators_match_npg          every operator assembled here equals npg's full
 *                                evaluator of examples/fluids/fluids2d.npg (1e-12)
 *   tunnel_numbering             the tunnel renumbered along a Hilbert curve is the
 *                                same mesh, keeps its relations (periodic faces
 *                                included) and gives the same energies (1e-12)
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "test_mesh.h"
#include "test_named.h"

#include "npg.h"
#include "npgbind.h"
#include "solver.h"

static FluidMesh mesh;

static void small_mesh(void) {
  TunnelSpec spec = tunnel_spec_default();
  spec.cells = 300;
  char err[512];
  if (mesh_tunnel(&mesh, &spec, err, sizeof err) != 0) {
    fprintf(stderr, "test_fluids: %s\n", err);
    exit(1);
  }
}

static unsigned seed = 7;
static double rnd(void) {
  seed = seed * 1103515245u + 12345u;
  return ((seed >> 8) & 0xffffff) / 16777216.0 * 2 - 1;
}

static double energy_of(const Ops *o, const double *u) { return ops_energy(o, u); }

/* Random velocities projected: a divergence-free flux field with zero
 * boundary flux. */
static void divergence_free_flux(Ops *o, Projection *pr, double *f) {
  const FluidMesh *m = o->m;
  double *u = malloc(2 * m->nc * sizeof *u), *uo = malloc(2 * m->nc * sizeof *uo);
  for (int i = 0; i < 2 * m->nc; i++) u[i] = rnd() + (i % 2 == 0);
  char err[512];
  if (projection_solve(pr, u, NULL, f, uo, err, sizeof err) != 0) fail_msg("%s", err);
  free(u);
  free(uo);
}

/* Gershgorin bound on the spectral radius of V^-1 A. */
static double rate_bound(const Ops *o) {
  double worst = 0;
  for (int i = 0; i < o->A.nrow; i++) {
    double s = 0;
    for (int p = o->A.rowptr[i]; p < o->A.rowptr[i + 1]; p++) s += fabs(o->A.val[p]);
    if (s / o->area[i] > worst) worst = s / o->area[i];
  }
  return worst;
}

/* ---------------------------------------------------------------- tests */

static void test_advection_energy(void **state) {
  (void)state;
  const FluidMesh *m = &mesh;
  Ops o;
  Projection pr;
  Integrator it;
  char err[512];
  ops_init(&o, m);
  ops_set_geometry(&o, m->g0);
  assert_int_equal(projection_init(&pr, &o, PROJ_STREAM_CHOLMOD, err, sizeof err), 0);
  integrator_init(&it, &o);
  double *f = malloc(m->nf * sizeof *f), *u = malloc(2 * m->nc * sizeof *u), *du = malloc(2 * m->nc * sizeof *du);
  divergence_free_flux(&o, &pr, f);
  ops_set_advection(&o, f);
  for (int i = 0; i < 2 * m->nc; i++) u[i] = rnd();
  /* the semi-discrete claim (paper Eq. A.1): u^T V du = u^T A(f) u = 0 */
  integrator_rate(&it, 0, u, du);
  double dot = 0, scale = 0;
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < 2; d++) {
      dot += o.area[c] * u[2 * c + d] * du[2 * c + d];
      scale += o.area[c] * fabs(u[2 * c + d] * du[2 * c + d]);
    }
  print_message("u^T A(f) u = %.3g (relative %.3g)\n", dot, fabs(dot) / scale);
  assert_true(fabs(dot) <= 1e-13 * scale);
  /* one RK4 step, |lambda| dt = 0.02 (see integrator.h) */
  double dt = 0.02 / rate_bound(&o), e0 = energy_of(&o, u);
  for (int step = 0; step < 5; step++) {
    double ea = energy_of(&o, u);
    integrator_rk4(&it, 0, dt, u);
    double eb = energy_of(&o, u);
    print_message("step %d: relative energy change %.3g\n", step, eb / ea - 1);
    assert_true(fabs(eb / ea - 1) < 1e-10);
  }
  /* ... and it can fail: a flux field that is not divergence-free makes A(f)
   * lose antisymmetry, and the energy moves far beyond the tolerance */
  for (int j = 0; j < m->nf; j++) f[j] += 0.1 * rnd();
  ops_set_advection(&o, f);
  double ea = energy_of(&o, u);
  integrator_rk4(&it, 0, dt, u);
  print_message("non-solenoidal flux: relative energy change %.3g (must be large)\n", energy_of(&o, u) / ea - 1);
  assert_true(fabs(energy_of(&o, u) / ea - 1) > 1e-6);
  (void)e0;
  free(f);
  free(u);
  free(du);
  integrator_free(&it);
  projection_free(&pr);
  ops_free(&o);
}

static void test_diffusion_projection_energy(void **state) {
  (void)state;
  const FluidMesh *m = &mesh;
  Ops o;
  Projection pr;
  Integrator it;
  char err[512];
  ops_init(&o, m);
  double *g = malloc(2 * m->nv * sizeof *g);
  assert_int_equal(mesh_deform(m, 1.1, 1.0, g, err, sizeof err), 0);
  ops_set_geometry(&o, g);
  integrator_init(&it, &o);
  double *f = calloc(m->nf, sizeof *f), *u = malloc(2 * m->nc * sizeof *u), *up = malloc(2 * m->nc * sizeof *up);
  for (int i = 0; i < 2 * m->nc; i++) u[i] = rnd();
  /* diffusion alone (paper Eq. A.2): A = 0, mu > 0 */
  ops_set_advection(&o, f);
  double mu = 1e-3, dt = 0.02;
  for (int step = 0; step < 20; step++) {
    double ea = energy_of(&o, u);
    integrator_rk4(&it, mu, dt, u);
    double eb = energy_of(&o, u);
    assert_true(eb <= ea);
    if (step == 0) print_message("diffusion: relative energy change %.3g\n", eb / ea - 1);
  }
  /* projection (paper §A.1): E(u) = E(u') + E(u - u'), so E(u') <= E(u) */
  for (int round = 0; round < 4; round++) {
    ProjectionMethod method = round % 2 ? PROJ_KKT_UMFPACK : PROJ_STREAM_CHOLMOD;
    assert_int_equal(projection_init(&pr, &o, method, err, sizeof err), 0);
    for (int i = 0; i < 2 * m->nc; i++) u[i] = rnd() + 0.5;
    assert_int_equal(projection_solve(&pr, u, NULL, f, up, err, sizeof err), 0);
    double e = energy_of(&o, u), ep = energy_of(&o, up), eperp;
    double *d = malloc(2 * m->nc * sizeof *d);
    for (int i = 0; i < 2 * m->nc; i++) d[i] = u[i] - up[i];
    eperp = energy_of(&o, d);
    free(d);
    print_message("projection (%s): E %.6g -> %.6g, E(u - u') %.6g, Pythagoras defect %.3g\n",
                  projection_method_name(method), e, ep, eperp, (ep + eperp - e) / e);
    assert_true(ep <= e);
    assert_true(fabs(ep + eperp - e) <= 1e-10 * e);
    projection_free(&pr);
  }
  free(g);
  free(f);
  free(u);
  free(up);
  integrator_free(&it);
  ops_free(&o);
}

static void test_divergence_free(void **state) {
  (void)state;
  const FluidMesh *m = &mesh;
  char err[512];
  /* a real moving-mesh step: obstacle scale 1 -> 1.05, both solvers in
   * lockstep; they compute the same minimizer */
  FullSolver both[2];
  double u0[2] = {1, 0};
  assert_int_equal(solver_init(&both[1], m, PROJ_KKT_UMFPACK, 1e-3, 0.02, 1.0, u0, err, sizeof err), 0);
  for (int method = 0; method < 2; method++) {
  FullSolver s = both[method];
  if (method == 0) assert_int_equal(solver_init(&s, m, PROJ_STREAM_CHOLMOD, 1e-3, 0.02, 1.0, u0, err, sizeof err), 0);
  print_message("%s:\n", projection_method_name(s.pr.method));
  double maxf = 0;
  for (int j = 0; j < m->nf; j++) maxf = fmax(maxf, fabs(s.f[j]));
  double div0 = projection_max_divergence(&s.ops, s.f);
  print_message("initial projection: max |div f| %.3g, max |f| %.3g\n", div0, maxf);
  assert_true(div0 <= 1e-12 * maxf);
  for (int step = 1; step <= 3; step++) {
    assert_int_equal(solver_step(&s, 1 + 0.05 * step, err, sizeof err), 0);
    maxf = 0;
    double hmax = 0, bmax = 0;
    for (int j = 0; j < m->nf; j++) maxf = fmax(maxf, fabs(s.f[j]));
    for (int b = 0; b < m->nb; b++) {
      int j = m->bface[b];
      hmax = fmax(hmax, fabs(s.h[j]));
      bmax = fmax(bmax, fabs(s.f[j] - s.h[j]));
    }
    double div = projection_max_divergence(&s.ops, s.f);
    print_message("step %d: max |div f| %.3g, max |f| %.3g, max |h_b| %.3g, max |D f - D h| %.3g\n", step, div, maxf,
                  hmax, bmax);
    assert_true(hmax > 0); /* the boundary does move */
    assert_true(div <= 1e-12 * maxf);
    assert_true(bmax == 0);
  }
  both[method] = s;
  }
  /* the two solvers' states after three steps */
  double diff = 0, scale = 0;
  for (int j = 0; j < m->nf; j++) {
    diff = fmax(diff, fabs(both[0].f[j] - both[1].f[j]));
    scale = fmax(scale, fabs(both[1].f[j]));
  }
  print_message("stream-cholmod vs kkt-umfpack after 3 steps: max |f1 - f2| / max |f| = %.3g\n", diff / scale);
  assert_true(diff <= 1e-10 * scale);
  solver_free(&both[0]);
  solver_free(&both[1]);
}

static void test_inversion_refused(void **state) {
  (void)state;
  const FluidMesh *m = &mesh;
  char err[512] = "";
  double *g = malloc(2 * m->nv * sizeof *g);
  assert_int_equal(mesh_deform(m, 1.2, 1.0, g, err, sizeof err), 0);
  /* the walls give way: the fluid area of the reference scale is kept */
  double area = m->spec.L * m->spec.H - m->obstacle_area0;
  print_message("fluid area at scale 1.2: %.15g (rest %.15g)\n", mesh_fluid_volume(m, g), area);
  assert_true(fabs(mesh_fluid_volume(m, g) - area) <= 1e-12 * area);
  assert_int_equal(mesh_deform(m, 0.8, 1.0, g, err, sizeof err), 0);
  assert_true(fabs(mesh_fluid_volume(m, g) - area) <= 1e-12 * area);
  /* fixed obstacles (sigma = sigma_ref) are linear in the scale: the medium
   * one is the mean of the large and the small one (paper Fig. 5) */
  double *g1 = malloc(2 * m->nv * sizeof *g1), *g2 = malloc(2 * m->nv * sizeof *g2), worst = 0;
  assert_int_equal(mesh_deform(m, 0.8, 0.8, g1, err, sizeof err), 0);
  assert_int_equal(mesh_deform(m, 1.2, 1.2, g2, err, sizeof err), 0);
  assert_int_equal(mesh_deform(m, 1.0, 1.0, g, err, sizeof err), 0);
  for (int i = 0; i < 2 * m->nv; i++) worst = fmax(worst, fabs(g[i] - (g1[i] + g2[i]) / 2));
  print_message("fixed scale 1.0 vs the mean of 0.8 and 1.2: max difference %.3g\n", worst);
  assert_true(worst <= 1e-14);
  free(g1);
  free(g2);
  assert_int_equal(mesh_deform(m, 2.5, 1.0, g, err, sizeof err), -1);
  print_message("%s\n", err);
  const char *p = strstr(err, "inverts element ");
  assert_non_null(p);
  int c = atoi(p + strlen("inverts element "));
  assert_true(c >= 0 && c < m->nc);
  assert_true(mesh_volume(m, g, c) <= 0); /* the named element is the inverted one */
  /* the solver refuses the step and keeps its state */
  FullSolver s;
  double u0[2] = {1, 0};
  assert_int_equal(solver_init(&s, m, PROJ_STREAM_CHOLMOD, 1e-3, 0.02, 1.0, u0, err, sizeof err), 0);
  double e = solver_energy(&s);
  assert_int_equal(solver_step(&s, 2.5, err, sizeof err), -1);
  assert_non_null(strstr(err, "inverts element "));
  assert_true(solver_energy(&s) == e && s.sigma == 1.0);
  solver_free(&s);
  free(g);
}

/* ---------------------------------------------------------------- npg */

static double compare(NpgFull *f, const char *name, const double *mine, size_t n) {
  size_t count = 0;
  const double *theirs = npg_full_get(f, name, &count);
  assert_non_null(theirs);
  assert_int_equal(count, n);
  double diff = 0, scale = 0;
  for (size_t i = 0; i < n; i++) {
    diff = fmax(diff, fabs(mine[i] - theirs[i]));
    scale = fmax(scale, fabs(theirs[i]));
  }
  double rel = scale > 0 ? diff / scale : diff;
  print_message("%-5s %6zu values, max |assembled - npg| / max |npg| = %.3g\n", name, n, rel);
  assert_true(scale > 0);
  assert_true(rel <= 1e-12);
  return rel;
}

static void test_operators_match_npg(void **state) {
  (void)state;
  const FluidMesh *m = &mesh;
  NpgOptions opt = {0};
  NpgProgram *prog = npg_compile("examples/fluids/fluids2d.npg", &opt);
  if (!npg_ok(prog)) fail_msg("%s", npg_error(prog));
  NpgFull *ev = npg_full_new(prog, NPG_TCC);
  if (npg_full_error(ev)[0]) fail_msg("%s", npg_full_error(ev));
  double mu = 3e-3;
  long c3[2] = {m->nc, 3}, f2[2] = {m->nf, 2}, b1[1] = {m->nb};
  (void)c3, (void)f2, (void)b1;
  if (fluid_bind(ev, m, mu) != 0) fail_msg("%s", npg_full_error(ev));
  /* inputs: a deformed mesh, random vertex velocities, fluxes, velocities */
  char err[512];
  double *g = malloc(2 * m->nv * sizeof *g), *gdot = malloc(2 * m->nv * sizeof *gdot);
  double *f = malloc(m->nf * sizeof *f), *u = malloc(2 * m->nc * sizeof *u);
  assert_int_equal(mesh_deform(m, 1.15, 1.0, g, err, sizeof err), 0);
  for (int i = 0; i < 2 * m->nv; i++) gdot[i] = rnd();
  for (int j = 0; j < m->nf; j++) f[j] = rnd();
  for (int i = 0; i < 2 * m->nc; i++) u[i] = rnd();
  long sg[2] = {m->nv, 2}, su[1] = {2 * (long)m->nc}, sf[1] = {m->nf};
  if (npg_full_set(ev, "g", 2, sg, g, "g") || npg_full_set(ev, "gdot", 2, sg, gdot, "gdot") ||
      npg_full_set(ev, "f", 1, sf, f, "f") || npg_full_set(ev, "u", 1, su, u, "u") || npg_full_eval(ev, 0))
    fail_msg("%s", npg_full_error(ev));

  Ops o;
  Integrator it;
  ops_init(&o, m);
  integrator_init(&it, &o);
  ops_set_geometry(&o, g);
  size_t nu = 2 * m->nc;
  double *h = malloc(m->nf * sizeof *h), *phi = malloc(m->nf * sizeof *phi);
  double *a = malloc(nu * sizeof *a), *b = malloc(nu * sizeof *b);
  /* h: Eq. 11 */
  ops_induced_flux(m, g, gdot, h);
  compare(ev, "h", h, m->nf);
  /* p = P(g) f */
  csr_mv(&o.P, f, a);
  compare(ev, "p", a, nu);
  /* pv = V(g) u */
  for (int c = 0; c < m->nc; c++) a[2 * c] = o.area[c] * u[2 * c], a[2 * c + 1] = o.area[c] * u[2 * c + 1];
  compare(ev, "pv", a, nu);
  /* pdot = A(f) u - A_h(h) u = A(f - h) u */
  for (int j = 0; j < m->nf; j++) phi[j] = f[j] - h[j];
  ops_set_advection(&o, phi);
  csr_mv2(&o.A, u, a);
  compare(ev, "pdot", a, nu);
  /* lap */
  csr_mv2(&o.lap, u, b);
  compare(ev, "lap", b, nu);
  /* bf = D f, bh = D h */
  csr_mv(&o.D, f, a);
  compare(ev, "bf", a, m->nb);
  csr_mv(&o.D, h, a);
  compare(ev, "bh", a, m->nb);
  free(g);
  free(gdot);
  free(f);
  free(u);
  free(h);
  free(phi);
  free(a);
  free(b);
  integrator_free(&it);
  ops_free(&o);
  npg_full_free(ev);
  npg_free(prog);
}

/* The tunnel renumbered along a Hilbert curve (mesh_renumber; the tunnel
 * itself keeps gmsh's numbering) is gmsh's mesh: the same points, cells
 * and faces with their kinds, obstacle corners and periodic copies; it
 * keeps mesh.h's relations (counter-clockwise cells, the face opposite its
 * vertex and running counter-clockwise in its first cell, nbr symmetric,
 * a periodic face's shift opposite from its two sides); and three full
 * steps of a growing obstacle give the same energies to 1e-12. */
static void test_tunnel_numbering(void **state) {
  (void)state;
  const FluidMesh *a = &mesh;
  FluidMesh r;
  TunnelSpec spec = tunnel_spec_default();
  spec.cells = 300;
  char err[512];
  if (mesh_tunnel(&r, &spec, err, sizeof err) != 0) fail_msg("%s", err);
  mesh_renumber(&r, MO_HILBERT);
  assert_int_equal(a->nv, r.nv), assert_int_equal(a->nc, r.nc), assert_int_equal(a->nf, r.nf);
  assert_int_equal(a->nb, r.nb);
  int nv = a->nv, *to_a = vertex_map(a, &r);
  for (int v = 0; v < nv; v++) assert_int_equal(to_a[r.vmaster[v]], a->vmaster[to_a[v]]);
  for (int q = 0; q < 3; q++) assert_int_equal(to_a[r.obstacle[q]], a->obstacle[q]);
  assert_same_sets(a->cell, r.cell, a->nc, 3, to_a, NULL, NULL);
  assert_same_sets(a->face, r.face, a->nf, 2, to_a, a->fkind, r.fkind);
  int periodic = 0;
  for (int c = 0; c < r.nc; c++) {
    assert_true(mesh_volume(&r, r.g0, c) > 0);
    for (int k = 0; k < 3; k++) {
      int j = r.cface[3 * c + k], b = r.nbr[3 * c + k];
      int v0 = r.cell[3 * c + (k + 1) % 3], v1 = r.cell[3 * c + (k + 2) % 3];
      double cs = r.csign[3 * c + k];
      if (cs > 0) assert_true(r.face[2 * j] == v0 && r.face[2 * j + 1] == v1 && r.fcell[2 * j] == c);
      else assert_true(r.vmaster[r.face[2 * j]] == r.vmaster[v1] && r.vmaster[r.face[2 * j + 1]] == r.vmaster[v0]);
      if (b < 0) {
        assert_true(cs == 1 && r.fkind[j] != BF_INTERIOR && r.nshift[3 * c + k] == 0);
        continue;
      }
      int back = 0;
      for (int l = 0; l < 3; l++)
        back += r.nbr[3 * b + l] == c && r.cface[3 * b + l] == j && r.csign[3 * b + l] == -cs &&
                r.nshift[3 * b + l] == -r.nshift[3 * c + k];
      assert_int_equal(back, 1);
      periodic += r.nshift[3 * c + k] != 0;
    }
  }
  assert_true(periodic > 0); /* the periodic faces are there, seen from both sides */
  FullSolver s[2];
  double u0[2] = {1, 0}, worst = 0;
  const FluidMesh *ms[2] = {a, &r};
  for (int o = 0; o < 2; o++)
    if (solver_init(&s[o], ms[o], PROJ_STREAM_CHOLMOD, 1e-3, 0.02, 1.0, u0, err, sizeof err) != 0) fail_msg("%s", err);
  for (int step = 1; step <= 3; step++) {
    for (int o = 0; o < 2; o++)
      if (solver_step(&s[o], 1 + 0.05 * step, err, sizeof err) != 0) fail_msg("%s", err);
    worst = fmax(worst, fabs(solver_energy(&s[1]) / solver_energy(&s[0]) - 1));
  }
  print_message("%d cells, %d periodic face sides; energies after 3 steps %.3g apart (relative)\n", r.nc, periodic,
                worst);
  assert_true(worst <= 1e-12);
  for (int o = 0; o < 2; o++) solver_free(&s[o]);
  free(to_a);
  mesh_free(&r);
}

int main(int argc, char **argv) {
  const struct CMUnitTest all[] = {
      cmocka_unit_test(test_advection_energy),  cmocka_unit_test(test_diffusion_projection_energy),
      cmocka_unit_test(test_divergence_free),   cmocka_unit_test(test_inversion_refused),
      cmocka_unit_test(test_operators_match_npg), cmocka_unit_test(test_tunnel_numbering),
  };
  small_mesh();
  int rc = run_named_tests("test_fluids", argc, argv, all, (int)(sizeof all / sizeof all[0]));
  mesh_free(&mesh);
  return rc;
}
