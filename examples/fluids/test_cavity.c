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
 *   cavity_train_workers three short training runs on 2 and 3 workers (the
 *                        second worker made to wait for the first run by a
 *                        queue bound of one byte) give the model one worker
 *                        gives, bit for bit: every basis, and the reduced
 *                        stages evaluated at the same coordinates; a run
 *                        that diverges fails the training on 1, 2 and 3
 *                        workers (the others stop); with --sample-every 2
 *                        the trainer gets ceil(T/2) samples per run
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
    double fmx = 0, diff = 0;
    for (int j = 0; j < m->nf; j++) fmx = fmax(fmx, fabs(s[0].f[j])), diff = fmax(diff, fabs(s[1].f[j] - s[0].f[j]));
    assert_true(fmx > 0);
    worst_diff = fmax(worst_diff, diff / fmx);
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

/* Three training runs of TRAIN_FRAMES frames on `workers` threads into a
 * fresh trainer: its samples counted (*samples) and, with `finish`, its
 * model (else NULL). */
#define TRAIN_FRAMES 61
static NpgModel *train_on(const Cavity *cv, NpgFull *fe, int workers, size_t buffer, int every, int finish,
                          long *samples) {
  CavityOptions o;
  cavity_options_default(&o);
  o.frames = TRAIN_FRAMES, o.runs = 3, o.workers = workers, o.buffer_bytes = buffer, o.sample_every = every;
  NpgTrainOptions to;
  FluidBasisOptions bo;
  fluid_train_options(&to, &bo, 12, 6, 5, 60);
  NpgTrainer *tr = npg_trainer_new(fe, &to);
  CavityTraining ct;
  if (cavity_train(cv, &o, 1e-4, tr, &ct) != 0) fail_msg("training runs on %d workers failed", workers);
  assert_int_equal(ct.workers, workers);
  assert_true(ct.min_quality > 0 && ct.seconds_runs > 0);
  *samples = npg_trainer_samples(tr);
  NpgModel *model = finish ? npg_trainer_finish(tr, NULL) : NULL;
  if (finish && !model) fail_msg("%s", npg_trainer_error(tr));
  npg_trainer_free(tr);
  return model;
}

/* Reduced coordinates of pdot, pv, h and bf at fixed coordinates of the inputs. */
static double *reduced_probe(const NpgModel *model, size_t *count) {
  NpgReduced *r = npg_reduced_new(model);
  const char *in[4] = {"g", "gdot", "f", "u"}, *out[4] = {"pdot", "pv", "h", "bf"};
  for (int i = 0; i < 4; i++) {
    NpgClassInfo ci;
    assert_int_equal(npg_model_class(model, npg_model_class_of(model, in[i]), &ci), 0);
    double x[512];
    assert_true(ci.m <= 512);
    for (long k = 0; k < ci.m; k++) x[k] = (k == 0 ? 1.0 : 0.1) / (k + 1 + i);
    if (npg_reduced_set_coords(r, in[i], (size_t)ci.m, x) != 0) fail_msg("%s", npg_reduced_error(r));
  }
  if (npg_reduced_eval(r, 0) != 0) fail_msg("%s", npg_reduced_error(r));
  double *all = NULL;
  *count = 0;
  for (int i = 0; i < 4; i++) {
    size_t m = 0;
    const double *y = npg_reduced_coords(r, out[i], &m);
    assert_non_null(y);
    all = realloc(all, (*count + m) * sizeof *all);
    memcpy(all + *count, y, m * sizeof *y);
    *count += m;
  }
  npg_reduced_free(r);
  return all;
}

static void test_cavity_train_workers(void **state) {
  (void)state;
  Cavity cv = cavity_of(150);
  NpgOptions no = {0};
  NpgProgram *prog = npg_compile(FLUIDS_NPG3, &no);
  if (!npg_ok(prog)) fail_msg("%s", npg_error(prog));
  NpgFull *fe = npg_full_new(prog, NPG_TCC);
  if (fluid_bind(fe, &cv.m, 1e-4) != 0) fail_msg("%s", npg_full_error(fe));
  long s1, s2, s3, s_every;
  NpgModel *one = train_on(&cv, fe, 1, (size_t)1 << 30, 1, 1, &s1);
  size_t n1;
  double *probe1 = reduced_probe(one, &n1);
  /* 2 workers, run 2 waiting for run 1 at every sample; 3 workers, no wait */
  NpgModel *more[2] = {train_on(&cv, fe, 2, 1, 1, 1, &s2), train_on(&cv, fe, 3, (size_t)1 << 30, 1, 1, &s3)};
  assert_int_equal(s1, 3 * TRAIN_FRAMES);
  assert_int_equal(s2, s1);
  assert_int_equal(s3, s1);
  for (int k = 0; k < 2; k++) {
    assert_int_equal(npg_model_nclasses(more[k]), npg_model_nclasses(one));
    for (int c = 0; c < npg_model_nclasses(one); c++) {
      NpgClassInfo a, b;
      assert_int_equal(npg_model_class(one, c, &a), 0);
      assert_int_equal(npg_model_class(more[k], c, &b), 0);
      assert_int_equal(a.n, b.n);
      assert_int_equal(a.m, b.m);
      assert_memory_equal(npg_model_basis(one, c), npg_model_basis(more[k], c), (size_t)(a.n * a.m) * sizeof(double));
    }
    size_t n;
    double *probe = reduced_probe(more[k], &n);
    assert_int_equal(n, n1);
    assert_memory_equal(probe, probe1, n * sizeof *probe);
    free(probe);
    npg_model_free(more[k]);
  }
  print_message("%d cells: %ld samples; 2 and 3 workers give one worker's bases and reduced stages bit for bit "
                "(%zu reduced coordinates compared)\n", cv.m.nc, s1, n1);
  /* a run that diverges (run 2 over 40 frames on this mesh) stops the
   * others, waiting on the queue's bound or not, and the training fails */
  for (int w = 1; w <= 3; w++) {
    CavityOptions o;
    cavity_options_default(&o);
    o.frames = 40, o.runs = 3, o.workers = w, o.buffer_bytes = 1;
    NpgTrainOptions to;
    FluidBasisOptions bo;
    fluid_train_options(&to, &bo, 12, 6, 5, 60);
    NpgTrainer *tr = npg_trainer_new(fe, &to);
    CavityTraining ct;
    assert_int_equal(cavity_train(&cv, &o, 1e-4, tr, &ct), -1);
    npg_trainer_free(tr);
  }
  /* every second frame: frames 0, 2, ..., TRAIN_FRAMES - 2 of each run */
  train_on(&cv, fe, 2, (size_t)1 << 30, 2, 0, &s_every);
  assert_int_equal(s_every, 3 * ((TRAIN_FRAMES + 1) / 2));
  free(probe1);
  npg_model_free(one);
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
      cmocka_unit_test(test_cavity_reduced_step),
      cmocka_unit_test(test_cavity_train_workers),
  };
  return run_named_tests("test_cavity", argc, argv, all, (int)(sizeof all / sizeof all[0]));
}
