/* test_reduced.c — the reduced twin's claims (paper §6, appendix A.2), one
 * ctest each (argv[1] names the test):
 *
 *   reduced_energy       with B_u = B_p (share in fluids2d.npg) reduced advection
 *                        Â ⊗ f̂ is antisymmetric for a divergence-free flux with
 *                        no boundary flux, so the exponential integrator keeps
 *                        ½ ûᵀ V̂(ĝ) û to 1e-10 per step (the Padé approximant of a
 *                        V̂-skew matrix is V̂-orthogonal; measured ~1e-15); diffusion
 *                        and the reduced projection never increase it
 *   reduced_basis_divergence   every column of B_f of a model trained on projected
 *                        snapshots of the deforming tunnel is divergence-free to 1e-10
 *   reduced_full_rank    bases of full rank reproduce the full step with the same
 *                        integrator (RK4) to 1e-8
 *   reduced_expm         the Padé exponential against a Taylor series and the
 *                        squaring path, to 1e-12
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cblas.h>
#include <cmocka.h>

#include "test_named.h"
#include <lapacke.h>

#include "npg.h"
#include "npgbind.h"
#include "reduced.h"
#include "solver.h"

static unsigned seed = 11;
static double rnd(void) {
  seed = seed * 1103515245u + 12345u;
  return ((seed >> 8) & 0xffffff) / 16777216.0 * 2 - 1;
}

static FluidMesh mesh_of(int cells) {
  FluidMesh m;
  TunnelSpec spec = tunnel_spec_default();
  spec.cells = cells;
  char err[512];
  if (mesh_tunnel(&m, &spec, err, sizeof err) != 0) fail_msg("%s", err);
  return m;
}

typedef struct Ctx {
  NpgProgram *prog;
  NpgFull *fe;
  NpgTrainer *tr;
} Ctx;

static void ctx_open(Ctx *c, const FluidMesh *m, double mu, int ncaps, const char *const *names, const int *caps,
                     const double *energies) {
  NpgOptions opt = {0};
  c->prog = npg_compile("examples/fluids/fluids2d.npg", &opt);
  if (!npg_ok(c->prog)) fail_msg("%s", npg_error(c->prog));
  c->fe = npg_full_new(c->prog, NPG_TCC);
  if (npg_full_error(c->fe)[0] || fluid_bind(c->fe, m, mu) != 0) fail_msg("%s", npg_full_error(c->fe));
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.nbasis = ncaps, o.basis_name = names, o.basis_cap = caps, o.basis_energy = energies;
  c->tr = npg_trainer_new(c->fe, &o);
}

static void add_sample(Ctx *c, const FluidMesh *m, const double *g, const double *gdot, const double *f, const double *u) {
  long sg[2] = {m->nv, 2}, sf[1] = {m->nf}, su[1] = {2L * m->nc};
  if (npg_trainer_set(c->tr, "g", 2, sg, g) || npg_trainer_set(c->tr, "gdot", 2, sg, gdot) ||
      npg_trainer_set(c->tr, "f", 1, sf, f) || npg_trainer_set(c->tr, "u", 1, su, u) || npg_trainer_add(c->tr))
    fail_msg("%s", npg_trainer_error(c->tr));
}

static NpgModel *ctx_finish(Ctx *c) {
  NpgModel *model = npg_trainer_finish(c->tr, NULL);
  if (!model) fail_msg("%s", npg_trainer_error(c->tr));
  npg_trainer_free(c->tr);
  c->tr = NULL;
  return model;
}

static void ctx_close(Ctx *c, NpgModel *model) {
  npg_model_free(model);
  npg_full_free(c->fe);
  npg_free(c->prog);
}

/* A model of two short runs of the deforming tunnel (obstacle 1.1 and 0.9,
 * pulsing by 0.05), as npg-fluids tunnel trains, smaller. */
static NpgModel *tunnel_model(Ctx *c, const FluidMesh *m, double mu, double dt) {
  const char *names[] = {"u", "p", "pv", "pdot", "lap", "f", "g", "gdot", "h", "bf", "bh"};
  int caps[] = {20, 1, 1, 1, 1, 12, 5, 5, 5, 60, 60};
  double en[] = {1 - 1e-14, 1 - 1e-14, 1 - 1e-14, 1 - 1e-14, 1 - 1e-14, 1 - 1e-14,
                 1 - 1e-13, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13};
  ctx_open(c, m, mu, 11, names, caps, en);
  char err[512];
  double sc[2] = {1.1, 0.9};
  for (int r = 0; r < 2; r++) {
    FullSolver s;
    double u0[2] = {1, 0};
    if (solver_init(&s, m, PROJ_STREAM_CHOLMOD, mu, dt, sc[r], u0, err, sizeof err) != 0) fail_msg("%s", err);
    double *g = malloc(2 * m->nv * sizeof *g), *f = malloc(m->nf * sizeof *f), *u = malloc(2 * m->nc * sizeof *u);
    for (int t = 0; t < 40; t++) {
      memcpy(g, s.g, 2 * m->nv * sizeof *g), memcpy(f, s.f, m->nf * sizeof *f), memcpy(u, s.u, 2 * m->nc * sizeof *u);
      if (solver_step(&s, sc[r] + 0.05 * sin(2 * M_PI * (t + 1) / 40.0), err, sizeof err) != 0) fail_msg("%s", err);
      add_sample(c, m, g, s.gdot, f, u);
    }
    free(g), free(f), free(u);
    solver_free(&s);
  }
  return ctx_finish(c);
}

static double energy_matrix(int n, const double *V, const double *u) {
  double *t = malloc(n * sizeof *t);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, V, n, u, 1, 0.0, t, 1);
  double e = 0.5 * cblas_ddot(n, u, 1, t, 1);
  free(t);
  return e;
}

/* ---------------------------------------------------------------- tests */

static void test_reduced_energy(void **state) {
  (void)state;
  FluidMesh m = mesh_of(300);
  double mu = 0.002, dt = 0.25 * mesh_mean_edge(&m);
  Ctx c;
  NpgModel *model = tunnel_model(&c, &m, mu, dt);
  RedSolver s;
  char err[512];
  if (red_init(&s, model, 2, mu, dt, err, sizeof err) != 0) fail_msg("%s", err);
  int n = (int)s.mu;
  size_t uu = (size_t)n * n;
  print_message("m_u %ld, m_f %ld, m_g %ld, m_d %ld, rank of D̂ %ld\n", s.mu, s.mf, s.mg, s.mb, s.drank);
  /* the geometry of the medium obstacle */
  double *g = malloc(2 * m.nv * sizeof *g), *gc = malloc(s.mg * sizeof *gc);
  assert_int_equal(mesh_deform(&m, 1.0, 1.0, g, err, sizeof err), 0);
  red_project_g(&s, g, gc);
  double *V = malloc(uu * sizeof *V), *A = calloc(uu, sizeof *A), *M = malloc(uu * sizeof *M), *E = malloc(uu * sizeof *E);
  double *work = malloc(8 * uu * sizeof *work), *fc = calloc(s.mf, sizeof *fc), *u = malloc(n * sizeof *u);
  double *u1 = malloc(n * sizeof *u1), *y = malloc(s.nn * sizeof *y);
  red_volume(&s, gc, V);
  /* a flux of the null space of D̂: divergence-free, no boundary flux */
  for (long j = 0; j < s.nn; j++) y[j] = rnd();
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)s.mf, (int)s.nn, 1.0, s.N, (int)s.nn, y, 1, 0.0, fc, 1);
  red_advection(&s, fc, A);
  print_message("symmetric parts of the Â_k: rank %ld of m_f %ld\n", s.rs, s.mf);
  double asym = 0, norm = 0;
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++) asym = fmax(asym, fabs(A[i * n + j] + A[j * n + i])), norm = fmax(norm, fabs(A[i * n + j]));
  print_message("reduced advection: max |Â + Âᵀ| = %.3g of max |Â| %.3g\n", asym, norm);
  assert_true(asym <= 1e-12 * norm);
  /* M = V̂⁻¹Â; steps at |M| dt from 0.05 to 20 (squarings) */
  double scales[] = {0.05, 1, 20};
  for (int k = 0; k < 3; k++) {
    memcpy(M, A, uu * sizeof *M);
    double *Vc = malloc(uu * sizeof *Vc);
    memcpy(Vc, V, uu * sizeof *Vc);
    assert_int_equal(LAPACKE_dposv(LAPACK_ROW_MAJOR, 'L', n, n, Vc, n, M, n), 0);
    free(Vc);
    double mn = 0;
    for (int j = 0; j < n; j++) {
      double cs = 0;
      for (int i = 0; i < n; i++) cs += fabs(M[i * n + j]);
      mn = fmax(mn, cs);
    }
    for (size_t i = 0; i < uu; i++) M[i] *= scales[k] / mn;
    int pade, sq;
    assert_int_equal(red_expm(n, M, E, work, &pade, &sq), 0);
    /* the same exponential applied to one vector by Arnoldi (red_expmv, what
     * red_step uses): equal to E u, and energy-conserving to rounding */
    {
      double *Vf = malloc(uu * sizeof *Vf), *y1 = malloc(n * sizeof *y1), *y2 = malloc(n * sizeof *y2);
      memcpy(Vf, V, uu * sizeof *Vf);
      assert_int_equal(LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'L', n, Vf, n), 0);
      for (int i = 0; i < n; i++) u[i] = rnd();
      int steps = red_expmv(&s, A, Vf, scales[k] / mn, u, y1, 1e-12);
      if (k < 2) assert_true(steps > 0); /* at |ΔtM| 20 it may leave it to the whole exponential */
      if (steps > 0) {
        cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, E, n, u, 1, 0.0, y2, 1);
        double d = 0, yn = 0;
        for (int i = 0; i < n; i++) d += (y1[i] - y2[i]) * (y1[i] - y2[i]), yn += y2[i] * y2[i];
        double e0 = energy_matrix(n, V, u), e1 = energy_matrix(n, V, y1);
        print_message("Arnoldi, |dt V̂⁻¹Â|_1 = %g: %d steps, %.3g from the whole exponential, energy change %.3g\n",
                      scales[k], steps, sqrt(d / yn), fabs(e1 - e0) / e0);
        assert_true(sqrt(d / yn) <= 1e-10);
        assert_true(fabs(e1 - e0) <= 1e-12 * e0);
      }
      free(Vf), free(y1), free(y2);
    }
    for (int i = 0; i < n; i++) u[i] = rnd();
    double worst = 0;
    for (int step = 0; step < 5; step++) {
      double e0 = energy_matrix(n, V, u);
      cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, E, n, u, 1, 0.0, u1, 1);
      double e1 = energy_matrix(n, V, u1);
      worst = fmax(worst, fabs(e1 - e0) / e0);
      memcpy(u, u1, n * sizeof *u);
    }
    print_message("advection alone, |dt V̂⁻¹Â|_1 = %g (Padé %d, %d squarings): max relative energy change per step %.3g\n",
                  scales[k], pade, sq, worst);
    assert_true(worst <= 1e-10);
  }
  /* diffusion alone never increases the energy */
  memcpy(M, s.L, uu * sizeof *M);
  for (size_t i = 0; i < uu; i++) M[i] *= mu;
  {
    double *Vc = malloc(uu * sizeof *Vc);
    memcpy(Vc, V, uu * sizeof *Vc);
    assert_int_equal(LAPACKE_dposv(LAPACK_ROW_MAJOR, 'L', n, n, Vc, n, M, n), 0);
    free(Vc);
  }
  for (size_t i = 0; i < uu; i++) M[i] *= 50 * dt;
  assert_int_equal(red_expm(n, M, E, work, NULL, NULL), 0);
  for (int i = 0; i < n; i++) u[i] = rnd();
  for (int step = 0; step < 10; step++) {
    double e0 = energy_matrix(n, V, u);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, E, n, u, 1, 0.0, u1, 1);
    double e1 = energy_matrix(n, V, u1);
    assert_true(e1 <= e0 * (1 + 1e-14));
    if (step == 0) print_message("diffusion: energy %.6g -> %.6g\n", e0, e1);
    memcpy(u, u1, n * sizeof *u);
  }
  /* the reduced projection never increases it (no boundary flux: b = 0) */
  memset(s.b, 0, s.mb * sizeof *s.b);
  for (int trial = 0; trial < 5; trial++) {
    for (int i = 0; i < n; i++) u[i] = rnd();
    double e0 = energy_matrix(n, V, u);
    assert_int_equal(red_projection(&s, gc, u, err, sizeof err), 0);
    double e1 = energy_matrix(n, V, s.u);
    /* and projecting again changes nothing */
    memcpy(u1, s.u, n * sizeof *u1);
    assert_int_equal(red_projection(&s, gc, u1, err, sizeof err), 0);
    double d = 0;
    for (int i = 0; i < n; i++) d = fmax(d, fabs(s.u[i] - u1[i]));
    if (trial == 0) print_message("projection: energy %.6g -> %.6g; projecting again moves it by %.3g\n", e0, e1, d);
    assert_true(e1 <= e0 * (1 + 1e-12));
    assert_true(d <= 1e-10);
  }
  /* with boundary fluxes (b ≠ 0): the projection's û, formed from its parts (q + L⁻ᵀ X y), is
   * V̂⁻¹P̂ f̂ formed the direct way (P̂ assembled, V̂ solved) */
  double *P = malloc((size_t)n * s.mf * sizeof *P);
  for (long k = 0; k < s.mb; k++) s.b[k] = rnd();
  for (int i = 0; i < n; i++) u[i] = rnd();
  assert_int_equal(red_projection(&s, gc, u, err, sizeof err), 0);
  red_pmat(&s, gc, P);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, n, (int)s.mf, 1.0, P, (int)s.mf, s.f, 1, 0.0, u1, 1);
  memcpy(M, V, uu * sizeof *M);
  assert_int_equal(LAPACKE_dposv(LAPACK_ROW_MAJOR, 'L', n, 1, M, n, u1, 1), 0);
  double d = 0, sc = 0;
  for (int i = 0; i < n; i++) d = fmax(d, fabs(s.u[i] - u1[i])), sc = fmax(sc, fabs(u1[i]));
  print_message("projection with boundary fluxes (m_d %ld): |û - V̂⁻¹P̂f̂| = %.3g of %.3g\n", s.mb, d, sc);
  assert_true(s.mb > 0 && sc > 0 && d <= 1e-10 * sc);
  free(P);
  free(g), free(gc), free(V), free(A), free(M), free(E), free(work), free(fc), free(u), free(u1), free(y);
  red_free(&s);
  ctx_close(&c, model);
  mesh_free(&m);
}

static void test_reduced_basis_divergence(void **state) {
  (void)state;
  FluidMesh m = mesh_of(300);
  double mu = 0.002, dt = 0.25 * mesh_mean_edge(&m);
  Ctx c;
  NpgModel *model = tunnel_model(&c, &m, mu, dt);
  int cf = npg_model_class_of(model, "f");
  NpgClassInfo ci;
  assert_int_equal(npg_model_class(model, cf, &ci), 0);
  const double *B = npg_model_basis(model, cf);
  Ops o;
  ops_init(&o, &m);
  double *col = malloc(m.nf * sizeof *col), *d = malloc(m.nc * sizeof *d), worst = 0;
  for (long k = 0; k < ci.m; k++) {
    for (long j = 0; j < ci.n; j++) col[j] = B[j * ci.m + k];
    csr_mv(&o.div, col, d);
    for (int i = 0; i < m.nc; i++) worst = fmax(worst, fabs(d[i]));
  }
  print_message("B_f: %ld columns of %ld; max |div| %.3g\n", ci.m, ci.n, worst);
  assert_true(ci.m >= 8);
  assert_true(worst <= 1e-10);
  /* and the check can fail: a flux that is not divergence-free */
  for (long j = 0; j < ci.n; j++) col[j] = rnd();
  csr_mv(&o.div, col, d);
  double bad = 0;
  for (int i = 0; i < m.nc; i++) bad = fmax(bad, fabs(d[i]));
  assert_true(bad > 1e-3);
  free(col), free(d);
  ops_free(&o);
  ctx_close(&c, model);
  mesh_free(&m);
}

static void test_reduced_full_rank(void **state) {
  (void)state;
  FluidMesh m = mesh_of(30);
  double mu = 0.01, dt = 0.25 * mesh_mean_edge(&m);
  long U = 2L * m.nc;
  const char *names[] = {"u", "p", "pv", "pdot", "lap", "f", "g", "gdot", "h", "bf", "bh"};
  int caps[] = {(int)U, (int)U, (int)U, (int)U, (int)U, m.nf, 1, 4, 4, m.nb, m.nb};
  double en[] = {1 - 1e-15, 1 - 1e-15, 1 - 1e-15, 1 - 1e-15, 1 - 1e-15, 1 - 1e-20, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13};
  Ctx c;
  ctx_open(&c, &m, mu, 11, names, caps, en);
  char err[512];
  FullSolver fs;
  double u0[2] = {1, 0};
  if (solver_init(&fs, &m, PROJ_STREAM_CHOLMOD, mu, dt, 1.0, u0, err, sizeof err) != 0) fail_msg("%s", err);
  double *u = malloc(U * sizeof *u), *uo = malloc(U * sizeof *uo), *f = malloc(m.nf * sizeof *f);
  double *gdot = malloc(2 * m.nv * sizeof *gdot);
  int S = (int)U + 40;
  for (int k = 0; k < S; k++) {
    for (long i = 0; i < U; i++) u[i] = rnd();
    if (projection_solve(&fs.pr, u, NULL, f, uo, err, sizeof err) != 0) fail_msg("%s", err);
    for (long i = 0; i < U; i++) u[i] = rnd();
    for (int i = 0; i < 2 * m.nv; i++) gdot[i] = rnd();
    add_sample(&c, &m, fs.g, gdot, f, u);
  }
  NpgModel *model = ctx_finish(&c);
  RedSolver s;
  if (red_init(&s, model, 2, mu, dt, err, sizeof err) != 0) fail_msg("%s", err);
  s.integ = RED_RK4;
  print_message("%d cells: m_u %ld of %ld, m_f %ld of %d faces, m_g %ld, rank of D̂ %ld\n", m.nc, s.mu, U, s.mf, m.nf,
                s.mg, s.drank);
  assert_int_equal(s.mu, U);
  /* a state: divergence-free flux, any velocity */
  for (long i = 0; i < U; i++) u[i] = rnd() + (i % 2 == 0);
  if (projection_solve(&fs.pr, u, NULL, fs.f, uo, err, sizeof err) != 0) fail_msg("%s", err);
  for (long i = 0; i < U; i++) fs.u[i] = rnd();
  red_project_g(&s, fs.g, s.g);
  red_project_f(&s, fs.f, s.f);
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)U, (int)s.mu, 1.0, s.Bu, (int)s.mu, fs.u, 1, 0.0, s.u, 1);
  double *gn = malloc(s.mg * sizeof *gn);
  memcpy(gn, s.g, s.mg * sizeof *gn);
  for (int step = 0; step < 3; step++) {
    ops_set_geometry(&fs.ops, fs.g);
    if (solver_step(&fs, 1.0, err, sizeof err) != 0) fail_msg("%s", err);
    if (red_step(&s, gn, NULL, err, sizeof err) != 0) fail_msg("%s", err);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)U, (int)s.mu, 1.0, s.Bu, (int)s.mu, s.u, 1, 0.0, uo, 1);
    double d = 0, sc = 0;
    for (long i = 0; i < U; i++) d = fmax(d, fabs(uo[i] - fs.u[i])), sc = fmax(sc, fabs(fs.u[i]));
    double *fl = malloc(m.nf * sizeof *fl), df = 0, sf = 0;
    cblas_dgemv(CblasRowMajor, CblasNoTrans, m.nf, (int)s.mf, 1.0, s.Bf, (int)s.mf, s.f, 1, 0.0, fl, 1);
    for (int j = 0; j < m.nf; j++) df = fmax(df, fabs(fl[j] - fs.f[j])), sf = fmax(sf, fabs(fs.f[j]));
    free(fl);
    print_message("step %d: reduced (full-rank bases, RK4) vs full: velocity %.3g, flux %.3g relative\n", step, d / sc,
                  df / sf);
    assert_true(d <= 1e-8 * sc);
    assert_true(df <= 1e-8 * sf);
  }
  /* one more step from this state with the exponential integrator: applied
   * to û by Arnoldi (the default) and as the whole matrix exponential agree */
  {
    double *g0 = malloc(s.mg * sizeof *g0), *f0 = malloc(s.mf * sizeof *f0), *u0 = malloc(s.mu * sizeof *u0);
    double *ua = malloc(s.mu * sizeof *ua);
    memcpy(g0, s.g, s.mg * sizeof *g0), memcpy(f0, s.f, s.mf * sizeof *f0), memcpy(u0, s.u, s.mu * sizeof *u0);
    s.integ = RED_EXPMV;
    if (red_step(&s, gn, NULL, err, sizeof err) != 0) fail_msg("%s", err);
    int arnoldi = s.last_krylov;
    assert_true(arnoldi > 0);
    memcpy(ua, s.u, s.mu * sizeof *ua);
    memcpy(s.g, g0, s.mg * sizeof *g0), memcpy(s.f, f0, s.mf * sizeof *f0), memcpy(s.u, u0, s.mu * sizeof *u0);
    s.integ = RED_EXPM;
    if (red_step(&s, gn, NULL, err, sizeof err) != 0) fail_msg("%s", err);
    double d = 0, sc = 0;
    for (long i = 0; i < s.mu; i++) d = fmax(d, fabs(ua[i] - s.u[i])), sc = fmax(sc, fabs(s.u[i]));
    print_message("exponential step: Arnoldi (%d steps) vs the whole exponential (Padé %d): %.3g relative\n",
                  arnoldi, s.last_pade, d / sc);
    assert_true(d <= 1e-10 * sc);
    free(g0), free(f0), free(u0), free(ua);
  }
  free(u), free(uo), free(f), free(gdot), free(gn);
  red_free(&s);
  solver_free(&fs);
  ctx_close(&c, model);
  mesh_free(&m);
}

static void test_reduced_expm(void **state) {
  (void)state;
  int n = 12;
  double *X = malloc(n * n * sizeof *X), *E = malloc(n * n * sizeof *E), *T = calloc(n * n, sizeof *T);
  double *term = malloc(n * n * sizeof *term), *tmp = malloc(n * n * sizeof *tmp), *work = malloc(8 * n * n * sizeof *work);
  double norms[] = {0.01, 0.2, 0.9, 2, 5, 40};
  for (int k = 0; k < 6; k++) {
    for (int i = 0; i < n * n; i++) X[i] = rnd();
    double mn = 0;
    for (int j = 0; j < n; j++) {
      double cs = 0;
      for (int i = 0; i < n; i++) cs += fabs(X[i * n + j]);
      mn = fmax(mn, cs);
    }
    for (int i = 0; i < n * n; i++) X[i] *= norms[k] / mn;
    int pade, sq;
    assert_int_equal(red_expm(n, X, E, work, &pade, &sq), 0);
    /* reference: Taylor series of exp(X / 2^s) squared s times */
    int s = (int)ceil(log2(fmax(norms[k], 1) * 8));
    double sc = ldexp(1.0, -s);
    memset(T, 0, n * n * sizeof *T);
    memset(term, 0, n * n * sizeof *term);
    for (int i = 0; i < n; i++) T[i * n + i] = 1, term[i * n + i] = 1;
    for (int p = 1; p < 40; p++) {
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, n, n, n, sc / p, term, n, X, n, 0.0, tmp, n);
      memcpy(term, tmp, n * n * sizeof *term);
      for (int i = 0; i < n * n; i++) T[i] += term[i];
    }
    for (int q = 0; q < s; q++) {
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, n, n, n, 1.0, T, n, T, n, 0.0, tmp, n);
      memcpy(T, tmp, n * n * sizeof *T);
    }
    double d = 0, nt = 0;
    for (int i = 0; i < n * n; i++) d = fmax(d, fabs(E[i] - T[i])), nt = fmax(nt, fabs(T[i]));
    print_message("|X|_1 = %g: Padé %d, %d squarings; max |expm - Taylor| = %.3g of %.3g\n", norms[k], pade, sq, d, nt);
    assert_true(d <= 1e-12 * fmax(nt, 1) * fmax(1, norms[k]));
  }
  free(X), free(E), free(T), free(term), free(tmp), free(work);
}

int main(int argc, char **argv) {
  openblas_set_num_threads(1);
  const struct CMUnitTest all[] = {
      cmocka_unit_test(test_reduced_energy),
      cmocka_unit_test(test_reduced_basis_divergence),
      cmocka_unit_test(test_reduced_full_rank),
      cmocka_unit_test(test_reduced_expm),
  };
  return run_named_tests("test_reduced", argc, argv, all, (int)(sizeof all / sizeof all[0]));
}
