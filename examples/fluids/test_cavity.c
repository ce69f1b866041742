/* test_cavity.c — the 3D deforming cavity's claims (paper §5, §6, §7.2) on a
 * mesh of a few hundred tetrahedra, one ctest each (argv[1] names it):
 *
 *   cavity_deform        the rest mesh and every frame of every training
 *                        deformation keep every tetrahedron positive and the
 *                        fluid volume to 1e-12; a deformation that turns a side
 *                        chamber inside out is refused, naming an element whose
 *                        volume is indeed not positive
 *   cavity_divergence    full steps of a training run: every cell's net flux is
 *                        zero to 1e-10 of the largest flux, the boundary fluxes
 *                        equal the induced ones exactly, and the induced
 *                        boundary fluxes sum to zero: |Σ h_b| dt ≤ 1e-13 of the
 *                        fluid volume (the swept volumes, exact; the deformation
 *                        keeps the volume to rounding)
 *   cavity_projection_methods  the full steps of cavity_divergence with both
 *                        projections in lockstep: the augmented Lagrangian one
 *                        (CHOLMOD, the cavity's default) gives UMFPACK's KKT
 *                        fluxes to 1e-10 of the largest flux, and is
 *                        divergence-free to 1e-10 of it
 *   cavity_projection_reuse  the augmented Lagrangian projection keeping its
 *                        factor across steps gives, on 12 steps of a training
 *                        run and a jump to another run's geometry, the fluxes
 *                        of refactoring at every step to 1e-12 of the largest
 *                        flux and their divergence; it reuses a factor, and
 *                        refactors both by its cost rule and when a stale
 *                        factor stops paying within a step
 *   cavity_reduced_step  a model trained through npg.h on one training run: V̂(ĝ)
 *                        from its cubic slices equals B_uᵀ V(B_g ĝ) B_u to 1e-12
 *                        of its largest entry; on
 *                        that trajectory, the reduced step (RK4, as the full one)
 *                        from the projected full state agrees with the full step
 *                        from the lifted state, projected onto the bases, to
 *                        1e-2 of its energy (relative, per frame; measured
 *                        1e-3: the bases are not complete, and a model with
 *                        wrongly extracted slices is off by 1e2); the same
 *                        step twice from a saved RedState gives the same û
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

#include "cavitysim.h"
#include "npg.h"
#include "npgbind.h"
#include "reduced.h"
#include "solver.h"

#ifndef FLUIDS_NPG3
#define FLUIDS_NPG3 "examples/fluids/fluids3d.npg"
#endif

#define FRAMES 60

static Cavity cavity_of(int cells) {
  Cavity cv;
  CavitySpec spec = cavity_spec_default();
  spec.cells = cells;
  char err[512];
  if (cavity_mesh(&cv, &spec, err, sizeof err) != 0) fail_msg("%s", err);
  return cv;
}

static void test_cavity_deform(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const Mesh *m = &cv.m;
  char err[512];
  double *g = malloc(3 * (size_t)m->nv * sizeof *g);
  for (int c = 0; c < m->nc; c++) assert_true(mesh_volume(m, m->g0, c) > 0);
  double worst = INFINITY;
  for (int r = -1; r < 14; r++)
    for (int t = 0; t <= FRAMES; t += 3) {
      double sigma[CAVITY_SIDES];
      cavity_schedule(r, t, FRAMES, sigma);
      if (cavity_deform(&cv, sigma, g, NULL, err, sizeof err) != 0) fail_msg("run %d frame %d: %s", r, t, err);
      for (int c = 0; c < m->nc; c++) worst = fmin(worst, mesh_volume(m, g, c));
      assert_true(fabs(mesh_fluid_volume(m, g) - cv.volume0) <= 1e-12 * cv.volume0);
    }
  print_message("%d cells; smallest cell volume over the deformations %.3g; min quality at rest %.3f\n", m->nc, worst,
                mesh_min_quality(m, m->g0, NULL));
  assert_true(worst > 0);
  double inside_out[CAVITY_SIDES] = {-0.5, 1, 1};
  assert_int_equal(cavity_deform(&cv, inside_out, g, NULL, err, sizeof err), -1);
  print_message("%s\n", err);
  int c = -1;
  assert_non_null(strstr(err, "inverts element"));
  assert_int_equal(sscanf(strstr(err, "inverts element"), "inverts element %d", &c), 1);
  assert_true(c >= 0 && c < m->nc);
  assert_false(mesh_volume(m, g, c) > 0);
  free(g);
  cavity_free(&cv);
}

/* n full solvers (one per method) at frame 0 of training run 6 from u = 0;
 * returns the positions' buffer for run6_step. */
static double *run6_start(const Cavity *cv, FullSolver *s, const ProjectionMethod *methods, int n) {
  char err[512];
  double *g = malloc(3 * (size_t)cv->m.nv * sizeof *g), sigma[CAVITY_SIDES];
  const double zero[3] = {0, 0, 0};
  cavity_schedule(6, 0, FRAMES, sigma);
  if (cavity_deform(cv, sigma, g, NULL, err, sizeof err) != 0) fail_msg("%s", err);
  for (int k = 0; k < n; k++)
    if (solver_init_at(&s[k], &cv->m, methods[k], 1e-5, 0.01, g, zero, err, sizeof err) != 0) fail_msg("%s", err);
  return g;
}

/* The n solvers' full step to frame t of training run 6. */
static void run6_step(const Cavity *cv, int t, double *g, FullSolver *s, int n) {
  char err[512];
  double sigma[CAVITY_SIDES];
  cavity_schedule(6, t, FRAMES, sigma);
  if (cavity_deform(cv, sigma, g, NULL, err, sizeof err) != 0) fail_msg("%s", err);
  for (int k = 0; k < n; k++)
    if (solver_step_to(&s[k], g, err, sizeof err) != 0) fail_msg("%s", err);
}

static void test_cavity_divergence(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const Mesh *m = &cv.m;
  const ProjectionMethod method = PROJ_KKT_UMFPACK;
  FullSolver s;
  double *g = run6_start(&cv, &s, &method, 1);
  double worst_div = 0, worst_sum = 0;
  for (int t = 1; t <= 6; t++) {
    run6_step(&cv, t, g, &s, 1);
    double fmax_ = 0, hmax = 0, hsum = 0;
    for (int j = 0; j < m->nf; j++) fmax_ = fmax(fmax_, fabs(s.f[j])), hmax = fmax(hmax, fabs(s.h[j]));
    for (int b = 0; b < m->nb; b++) {
      assert_true(s.f[m->bface[b]] == s.h[m->bface[b]]);
      hsum += s.h[m->bface[b]];
    }
    assert_true(fmax_ > 0);
    worst_div = fmax(worst_div, projection_max_divergence(&s.ops, s.f) / fmax_);
    assert_true(hmax > 0);
    worst_sum = fmax(worst_sum, fabs(hsum) * 0.01 / cv.volume0);
  }
  print_message("max |div f| / max |f| %.3g; |sum of boundary h| dt / volume %.3g\n", worst_div, worst_sum);
  assert_true(worst_div <= 1e-10);
  assert_true(worst_sum <= 1e-13);
  solver_free(&s);
  free(g);
  cavity_free(&cv);
}

/* max_j |f_j - ref_j| / max_j |ref_j| (asserted positive, into *fmx). */
static double flux_difference(const Mesh *m, const double *ref, const double *f, double *fmx) {
  double diff = 0;
  *fmx = 0;
  for (int j = 0; j < m->nf; j++) *fmx = fmax(*fmx, fabs(ref[j])), diff = fmax(diff, fabs(f[j] - ref[j]));
  assert_true(*fmx > 0);
  return diff / *fmx;
}

static void test_cavity_projection_methods(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const Mesh *m = &cv.m;
  const ProjectionMethod methods[2] = {PROJ_KKT_UMFPACK, PROJ_AL_CHOLMOD};
  FullSolver s[2];
  double *g = run6_start(&cv, s, methods, 2);
  double worst_diff = 0, worst_div = 0;
  for (int t = 1; t <= 6; t++) {
    run6_step(&cv, t, g, s, 2);
    double fmx;
    worst_diff = fmax(worst_diff, flux_difference(m, s[0].f, s[1].f, &fmx));
    worst_div = fmax(worst_div, projection_max_divergence(&s[1].ops, s[1].f) / fmx);
  }
  print_message("%s against %s: max |f difference| / max |f| %.3g; max |div f| / max |f| %.3g (%d iterations)\n",
                projection_method_name(methods[1]), projection_method_name(methods[0]), worst_diff, worst_div,
                s[1].pr.iterations);
  assert_true(worst_diff <= 1e-10);
  assert_true(worst_div <= 1e-10);
  for (int k = 0; k < 2; k++) solver_free(&s[k]);
  free(g);
  cavity_free(&cv);
}

static void test_cavity_projection_reuse(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const Mesh *m = &cv.m;
  const ProjectionMethod methods[2] = {PROJ_AL_CHOLMOD, PROJ_AL_CHOLMOD};
  FullSolver s[2];
  double *g = run6_start(&cv, s, methods, 2);
  s[0].pr.al_refactor_every_step = true;
  s[1].pr.al_factor_cost = 3; /* in solves: counts independent of timing */
  double worst_diff = 0, worst_div = 0, ref_div = 0;
  for (int t = 1; t <= 13; t++) {
    if (t < 13) {
      if (t == 12) s[1].pr.al_factor_cost = 1e9; /* keeps the factor for the jump */
      run6_step(&cv, t, g, s, 2);
    } else { /* a jump to training run 0's most compressed frame: the stale factor must be replaced mid-projection */
      char err[512];
      double sigma[CAVITY_SIDES];
      long stale = s[1].pr.stale_refactorizations;
      s[1].pr.al_factor_cost = 3;
      cavity_schedule(0, FRAMES / 2, FRAMES, sigma);
      if (cavity_deform(&cv, sigma, g, NULL, err, sizeof err) != 0) fail_msg("%s", err);
      for (int k = 0; k < 2; k++)
        if (solver_step_to(&s[k], g, err, sizeof err) != 0) fail_msg("%s", err);
      assert_int_equal(s[1].pr.stale_refactorizations, stale + 1);
    }
    double fmx;
    worst_diff = fmax(worst_diff, flux_difference(m, s[0].f, s[1].f, &fmx));
    worst_div = fmax(worst_div, projection_max_divergence(&s[1].ops, s[1].f) / fmx);
    ref_div = fmax(ref_div, projection_max_divergence(&s[0].ops, s[0].f) / fmx);
  }
  const Projection *pr = &s[1].pr, *ref = &s[0].pr;
  print_message("factor reused in %ld of %ld projections, %ld factorizations (%ld of a stale factor), %.3g solves per "
                "projection (refactoring every step: %ld factorizations, %.3g solves); max |f difference| / max |f| "
                "%.3g; max |div f| / max |f| %.3g (refactoring every step: %.3g)\n",
                pr->reuses, pr->projections, pr->factorizations, pr->stale_refactorizations,
                (double)pr->solves / pr->projections, ref->factorizations, (double)ref->solves / ref->projections,
                worst_diff, worst_div, ref_div);
  assert_int_equal(ref->factorizations, ref->projections);
  assert_int_equal(ref->reuses, 0);
  assert_true(pr->reuses >= 1);
  assert_true(pr->factorizations >= 2);
  assert_true(pr->factorizations < pr->projections);
  assert_true(worst_diff <= 1e-12);
  assert_true(worst_div <= 1e-10 && worst_div <= 2 * ref_div);
  for (int k = 0; k < 2; k++) solver_free(&s[k]);
  free(g);
  cavity_free(&cv);
}

static void lift(const double *B, long n, long k, const double *x, double *out) {
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)k, 1.0, B, (int)k, x, 1, 0.0, out, 1);
}

static void test_cavity_reduced_step(void **state) {
  (void)state;
  Cavity cv = cavity_of(150);
  const Mesh *m = &cv.m;
  char err[512];
  double mu = 1e-4, dt = 0.01;
  long ng = 3L * m->nv, nf = m->nf, nu = 3L * m->nc, C = m->nc;
  NpgOptions no = {0};
  NpgProgram *prog = npg_compile(FLUIDS_NPG3, &no);
  if (!npg_ok(prog)) fail_msg("%s", npg_error(prog));
  NpgFull *fe = npg_full_new(prog, NPG_TCC);
  if (fluid_bind(fe, m, mu) != 0) fail_msg("%s", npg_full_error(fe));
  NpgTrainOptions to;
  FluidBasisOptions bo;
  fluid_train_options(&to, &bo, 60, 40, 5, 60);
  NpgTrainer *tr = npg_trainer_new(fe, &to);
  /* one training run (chamber 0 compressed and re-inflated), its states kept */
  double *G = malloc((FRAMES + 1) * ng * sizeof *G), *Fx = malloc((FRAMES + 1) * nf * sizeof *Fx);
  double *U = malloc((FRAMES + 1) * nu * sizeof *U), *GD = malloc(FRAMES * ng * sizeof *GD);
  double *g = malloc(ng * sizeof *g), sigma[CAVITY_SIDES];
  const double zero[3] = {0, 0, 0};
  long sg[2] = {m->nv, 3}, sf[1] = {nf}, su[2] = {m->nc, 3};
  cavity_schedule(0, 0, FRAMES, sigma);
  if (cavity_deform(&cv, sigma, g, NULL, err, sizeof err) != 0) fail_msg("%s", err);
  FullSolver s, probe;
  if (solver_init_at(&s, m, PROJ_KKT_UMFPACK, mu, dt, g, zero, err, sizeof err) != 0 ||
      solver_init_at(&probe, m, PROJ_KKT_UMFPACK, mu, dt, g, zero, err, sizeof err) != 0)
    fail_msg("%s", err);
  for (int t = 0; t < FRAMES; t++) {
    memcpy(G + t * ng, s.g, ng * sizeof *G), memcpy(Fx + t * nf, s.f, nf * sizeof *Fx);
    memcpy(U + t * nu, s.u, nu * sizeof *U);
    cavity_schedule(0, t + 1, FRAMES, sigma);
    if (cavity_deform(&cv, sigma, g, NULL, err, sizeof err) != 0 || solver_step_to(&s, g, err, sizeof err) != 0)
      fail_msg("%s", err);
    memcpy(GD + t * ng, s.gdot, ng * sizeof *GD);
    if (npg_trainer_set(tr, "g", 2, sg, G + t * ng) || npg_trainer_set(tr, "gdot", 2, sg, s.gdot) ||
        npg_trainer_set(tr, "f", 1, sf, Fx + t * nf) || npg_trainer_set(tr, "u", 2, su, U + t * nu) ||
        npg_trainer_add(tr))
      fail_msg("%s", npg_trainer_error(tr));
  }
  memcpy(G + FRAMES * ng, s.g, ng * sizeof *G);
  NpgModel *model = npg_trainer_finish(tr, NULL);
  if (!model) fail_msg("%s", npg_trainer_error(tr));
  npg_trainer_free(tr);
  RedSolver R;
  if (red_init(&R, model, 3, mu, dt, err, sizeof err) != 0 || red_constraints(&R, 1e-3, err, sizeof err) != 0)
    fail_msg("%s", err);
  R.integ = RED_RK4;
  print_message("%d cells; m_u %ld, m_f %ld, m_g %ld, m_gdot %ld, m_d %ld (rank of D̂ %ld)\n", m->nc, R.mu, R.mf, R.mg,
                R.mgd, R.mb, R.drank);
  /* V̂(ĝ) from its slices (read off npg's pv by polarization) against
   * B_uᵀ V(B_g ĝ) B_u assembled here */
  {
    double *gl = malloc(ng * sizeof *gl), *V = malloc(R.mu * R.mu * sizeof *V), worst_v = 0, big = 0;
    red_project_g(&R, G + 30 * ng, R.g);
    lift(R.Bg, ng, R.mg, R.g, gl);
    red_volume(&R, R.g, V);
    for (long a = 0; a < R.mu; a++)
      for (long b = 0; b < R.mu; b++) {
        double x = 0;
        for (long c = 0; c < C; c++) {
          double vol = mesh_volume(m, gl, (int)c);
          for (int d = 0; d < 3; d++) x += R.Bu[(3 * c + d) * R.mu + a] * vol * R.Bu[(3 * c + d) * R.mu + b];
        }
        worst_v = fmax(worst_v, fabs(x - V[a * R.mu + b])), big = fmax(big, fabs(x));
      }
    print_message("V̂ from slices against B_uᵀ V B_u: %.3g of its largest entry\n", worst_v / big);
    assert_true(worst_v <= 1e-12 * big);
    free(gl), free(V);
  }
  double *pv = malloc(nu * sizeof *pv), *ub = malloc(nu * sizeof *ub), *uc = malloc(R.mu * sizeof *uc);
  double *gn = malloc(R.mg * sizeof *gn), *gdc = malloc(R.mgd * sizeof *gdc), worst = 0;
  for (int t = 1; t < FRAMES; t++) {
    /* the projected full state of frame t, lifted: the full step from it */
    ops_set_geometry(&probe.ops, G + t * ng);
    for (long c = 0; c < C; c++)
      for (int d = 0; d < 3; d++) pv[3 * c + d] = probe.ops.area[c] * U[t * nu + 3 * c + d];
    red_project_g(&R, G + t * ng, R.g);
    red_project_f(&R, Fx + t * nf, R.f);
    red_project_u(&R, R.g, pv, R.u);
    memcpy(probe.g, G + t * ng, ng * sizeof *G);
    lift(R.Bf, nf, R.mf, R.f, probe.f);
    lift(R.Bu, nu, R.mu, R.u, probe.u);
    if (solver_step_to(&probe, G + (t + 1) * ng, err, sizeof err) != 0) fail_msg("%s", err);
    /* ... and the reduced step from the same state */
    red_project_g(&R, G + (t + 1) * ng, gn);
    cblas_dgemv(CblasRowMajor, CblasTrans, (int)ng, (int)R.mgd, 1.0, R.Bgd, (int)R.mgd, GD + t * ng, 1, 0.0, gdc, 1);
    if (red_step(&R, gn, gdc, err, sizeof err) != 0) fail_msg("%s", err);
    /* the full result projected onto the bases (V-orthogonally, footnote 2) */
    for (long c = 0; c < C; c++)
      for (int d = 0; d < 3; d++) pv[3 * c + d] = probe.ops.area[c] * probe.u[3 * c + d];
    red_project_u(&R, gn, pv, uc);
    double e = 0, n = 0;
    for (long i = 0; i < R.mu; i++) ub[i] = uc[i] - R.u[i];
    e = red_energy(&R, gn, ub), n = red_energy(&R, gn, uc);
    if (n > 0) worst = fmax(worst, e / n);
  }
  print_message("largest one-step difference in energy, relative: %.3g\n", worst);
  assert_true(worst <= 1e-2);
  /* red_state_restore puts back all a step reads, the kept factor of V̂
   * included: the same step twice from a saved state gives the same û (R
   * holds V̂'s factor at gn from the last red_project_u; the step leaves it
   * at the step's target; a restore that missed it would advect with V̂ of
   * the wrong geometry) */
  {
    RedState st = {0};
    memcpy(R.g, gn, R.mg * sizeof *gn);
    assert_int_equal(red_state_save(&R, &st), 0);
    red_project_g(&R, G + 20 * ng, gn);
    if (red_step(&R, gn, gdc, err, sizeof err) != 0) fail_msg("%s", err);
    memcpy(uc, R.u, R.mu * sizeof *uc);
    red_state_restore(&R, &st);
    if (red_step(&R, gn, gdc, err, sizeof err) != 0) fail_msg("%s", err);
    assert_memory_equal(uc, R.u, R.mu * sizeof *uc);
    red_state_free(&st);
  }
  free(pv), free(ub), free(uc), free(gn), free(gdc), free(G), free(Fx), free(U), free(GD), free(g);
  red_free(&R);
  npg_model_free(model);
  solver_free(&s);
  solver_free(&probe);
  npg_full_free(fe);
  npg_free(prog);
  cavity_free(&cv);
}

int main(int argc, char **argv) {
  openblas_set_num_threads(1);
  const struct CMUnitTest all[] = {
      cmocka_unit_test(test_cavity_deform),
      cmocka_unit_test(test_cavity_divergence),
      cmocka_unit_test(test_cavity_projection_methods),
      cmocka_unit_test(test_cavity_projection_reuse),
      cmocka_unit_test(test_cavity_reduced_step),
  };
  return run_named_tests("test_cavity", argc, argv, all, (int)(sizeof all / sizeof all[0]));
}
