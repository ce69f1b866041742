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
 *   cavity_train_workers three short training runs on 2 and 3 workers (the
 *                        second worker made to wait for the first run by a
 *                        queue bound of one byte) give the model one worker
 *                        gives, bit for bit: every basis, and the reduced
 *                        stages evaluated at the same coordinates; a run
 *                        that diverges fails the training on 1, 2 and 3
 *                        workers (the others stop); with --sample-every 2
 *                        the trainer gets ceil(T/2) samples per run
 *   cavity_numbering     gmsh's numbering, reverse Cuthill-McKee's and the
 *                        Hilbert curve's (mesh_renumber) each keep every
 *                        relation of mesh.h (checked from scratch: faces
 *                        opposite their vertex and oriented by csign, nbr
 *                        symmetric, positive cells, a closed boundary
 *                        oriented out of the fluid), and the renumbered
 *                        meshes have gmsh's cells and faces as vertex sets
 *   cavity_particles_sorted  particles_sort_by_cell orders by cell and keeps
 *                        each particle whole; a reversed copy advected by a
 *                        frame ends as the same set of particles
 *   cavity_numbering_energy  six full steps on each numbering through the
 *                        same positions: the same energies to 1e-11
 *                        relative
 *   cavity_particles_threads  particles through a reduced flux B_f f̂
 *                        (single precision) lifted face by face move, bit
 *                        for bit, as through the whole lift (the same row
 *                        products), on 1 and 3 threads, over frames whose
 *                        f̂ changes; faces shared by visited cells are
 *                        lifted once
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

#include "test_mesh.h"
#include "test_named.h"

#include "cavitysim.h"
#include "npg.h"
#include "npgbind.h"
#include "particles.h"
#include "reduced.h"
#include "solver.h"

#ifndef FLUIDS_NPG3
#define FLUIDS_NPG3 "examples/fluids/fluids3d.npg"
#endif

#define FRAMES 60

static Cavity cavity_of_order(int cells, MeshOrder order) {
  Cavity cv;
  CavitySpec spec = cavity_spec_default();
  spec.cells = cells;
  spec.order = order;
  char err[512];
  if (cavity_mesh(&cv, &spec, err, sizeof err) != 0) fail_msg("%s", err);
  return cv;
}

static Cavity cavity_of(int cells) { return cavity_of_order(cells, cavity_spec_default().order); }

static void test_cavity_deform(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const FluidMesh *m = &cv.m;
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
  const FluidMesh *m = &cv.m;
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
static double flux_difference(const FluidMesh *m, const double *ref, const double *f, double *fmx) {
  double diff = 0;
  *fmx = 0;
  for (int j = 0; j < m->nf; j++) *fmx = fmax(*fmx, fabs(ref[j])), diff = fmax(diff, fabs(f[j] - ref[j]));
  assert_true(*fmx > 0);
  return diff / *fmx;
}

static void test_cavity_projection_methods(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const FluidMesh *m = &cv.m;
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

/* The relations mesh.h states, checked from scratch at the rest positions:
 * positive cells; face cface[c][k] is the triangle opposite cell[c][k], its
 * area vector pointing out of c when csign[c][k] is +1 and into it when -1;
 * nbr is symmetric, the neighbour seeing the same face with the opposite
 * sign; fcell names the cells in that order; a face with one cell is a
 * BF_WALL listed once in bface, every other face BF_INTERIOR; and the
 * boundary is closed and oriented out of the fluid: its area vectors sum to
 * zero and Σ_b n_b · x_b / 3 (x_b the centroid) is the fluid volume (the
 * divergence theorem for div x = 3, exact on flat faces). */
static void check_topology(const FluidMesh *m) {
  const double *g = m->g0;
  int *uses = calloc(m->nf, sizeof *uses), *listed = calloc(m->nf, sizeof *listed);
  for (int c = 0; c < m->nc; c++) {
    assert_true(mesh_volume(m, g, c) > 0);
    for (int k = 0; k < 4; k++) {
      int j = m->cface[4 * c + k], b = m->nbr[4 * c + k];
      const int *v = m->face + 3 * j;
      double cs = m->csign[4 * c + k];
      uses[j]++;
      int shared = 0; /* the face's vertices are the cell's others */
      for (int q = 0; q < 3; q++)
        for (int l = 0; l < 4; l++) shared += l != k && m->cell[4 * c + l] == v[q];
      assert_int_equal(shared, 3);
      const double *a = g + 3 * v[0], *p = g + 3 * v[1], *d = g + 3 * v[2], *o = g + 3 * m->cell[4 * c + k];
      double e[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]}, w[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
      double n[3] = {e[1] * w[2] - e[2] * w[1], e[2] * w[0] - e[0] * w[2], e[0] * w[1] - e[1] * w[0]};
      assert_true(cs * (n[0] * (a[0] - o[0]) + n[1] * (a[1] - o[1]) + n[2] * (a[2] - o[2])) > 0);
      assert_int_equal(m->fcell[2 * j + (cs > 0 ? 0 : 1)], c);
      assert_int_equal(m->fcell[2 * j + (cs > 0 ? 1 : 0)], b);
      if (b < 0) {
        assert_true(cs == 1 && m->fkind[j] == BF_WALL);
        continue;
      }
      assert_int_equal(m->fkind[j], BF_INTERIOR);
      int back = 0;
      for (int l = 0; l < 4; l++)
        back += m->nbr[4 * b + l] == c && m->cface[4 * b + l] == j && m->csign[4 * b + l] == -cs;
      assert_int_equal(back, 1);
    }
  }
  double sum[3] = {0, 0, 0}, size = 0, flux = 0;
  for (int i = 0; i < m->nb; i++) {
    int j = m->bface[i];
    assert_true(j >= 0 && j < m->nf && uses[j] == 1 && listed[j]++ == 0);
    const int *v = m->face + 3 * j;
    const double *a = g + 3 * v[0], *p = g + 3 * v[1], *d = g + 3 * v[2];
    double e[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]}, w[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
    double n[3] = {e[1] * w[2] - e[2] * w[1], e[2] * w[0] - e[0] * w[2], e[0] * w[1] - e[1] * w[0]};
    for (int q = 0; q < 3; q++) { /* the area vector n / 2, the centroid's coordinate (a + p + d) / 3 */
      sum[q] += n[q] / 2, size += fabs(n[q]) / 2;
      flux += n[q] * (a[q] + p[q] + d[q]) / 18;
    }
  }
  for (int j = 0; j < m->nf; j++) assert_true(uses[j] == 2 || (uses[j] == 1 && listed[j] == 1));
  assert_true(fabs(sum[0]) + fabs(sum[1]) + fabs(sum[2]) <= 1e-13 * size);
  double vol = mesh_fluid_volume(m, g);
  assert_true(fabs(flux - vol) <= 1e-12 * vol);
  free(uses), free(listed);
}

/* b is a renumbering of a: the same rest positions, and under the vertex
 * map they define, the same cells, faces and boundary faces as vertex sets. */
static void check_same_mesh(const FluidMesh *a, const FluidMesh *b) {
  assert_int_equal(a->nc, b->nc), assert_int_equal(a->nf, b->nf), assert_int_equal(a->nb, b->nb);
  int *to_a = vertex_map(a, b), *bf_a = malloc(a->nb * 3 * sizeof *bf_a), *bf_b = malloc(b->nb * 3 * sizeof *bf_b);
  for (int i = 0; i < a->nb; i++) memcpy(bf_a + 3 * i, a->face + 3 * a->bface[i], 3 * sizeof *bf_a);
  for (int i = 0; i < b->nb; i++) memcpy(bf_b + 3 * i, b->face + 3 * b->bface[i], 3 * sizeof *bf_b);
  assert_same_sets(a->cell, b->cell, a->nc, 4, to_a, NULL, NULL);
  assert_same_sets(a->face, b->face, a->nf, 3, to_a, a->fkind, b->fkind);
  assert_same_sets(bf_a, bf_b, a->nb, 3, to_a, NULL, NULL);
  free(to_a), free(bf_a), free(bf_b);
}

/* Each numbering's mesh keeps every relation of mesh.h and is gmsh's mesh
 * renumbered; a numbering that dropped a relation or a cell fails here. */
static void test_cavity_numbering(void **state) {
  (void)state;
  const MeshOrder orders[3] = {MO_MESHER, MO_RCM, MO_HILBERT};
  Cavity cv[3];
  for (int o = 0; o < 3; o++) {
    cv[o] = cavity_of_order(300, orders[o]);
    check_topology(&cv[o].m);
    if (o > 0) check_same_mesh(&cv[0].m, &cv[o].m);
  }
  /* and a numbering changes something: the cells' vertex lists differ */
  for (int o = 1; o < 3; o++)
    assert_true(memcmp(cv[0].m.cell, cv[o].m.cell, 4 * (size_t)cv[0].m.nc * sizeof(int)) != 0);
  print_message("%d cells, %d faces, %d boundary faces, %d vertices: consistent in the three numberings\n", cv[0].m.nc,
                cv[0].m.nf, cv[0].m.nb, cv[0].m.nv);
  for (int o = 0; o < 3; o++) cavity_free(&cv[o]);
}

/* The full solver on gmsh's numbering and on the renumbered meshes, six
 * steps of training run 6 with the cavity's projection (augmented
 * Lagrangian + CHOLMOD) through the same positions (gmsh's mesh deformed,
 * carried to the others by the vertex map): the same energies to 1e-11
 * relative (measured 3e-12). Not to rounding alone: the projection drops
 * the last cell's divergence row (the rows sum to the boundary flux), so
 * the boundary fluxes' sum, zero only to rounding, lands as that cell's
 * divergence (1.6e-13 here), and the numbering chooses the cell. Each mesh
 * deformed by itself would differ a little more: cavity_deform's central
 * scale κ then differs in its last bits, and h = ġ · n, ġ a difference
 * over dt, by 1e-12 of h (energies 1.2e-11 apart after six steps). */
static void test_cavity_numbering_energy(void **state) {
  (void)state;
  const MeshOrder orders[3] = {MO_MESHER, MO_RCM, MO_HILBERT};
  const ProjectionMethod method = PROJ_AL_CHOLMOD;
  const double zero[3] = {0, 0, 0};
  char err[512];
  Cavity cv[3];
  FullSolver s[3];
  int *to0[3] = {NULL, NULL, NULL};
  double *g[3], sigma[CAVITY_SIDES], worst = 0;
  for (int o = 0; o < 3; o++) {
    cv[o] = cavity_of_order(300, orders[o]);
    g[o] = malloc(3 * (size_t)cv[o].m.nv * sizeof *g[o]);
    if (o > 0) to0[o] = vertex_map(&cv[0].m, &cv[o].m);
  }
  int nv = cv[0].m.nv;
  for (int t = 0; t <= 6; t++) {
    cavity_schedule(6, t, FRAMES, sigma);
    if (cavity_deform(&cv[0], sigma, g[0], NULL, err, sizeof err) != 0) fail_msg("%s", err);
    for (int o = 1; o < 3; o++)
      for (int v = 0; v < nv; v++) memcpy(g[o] + 3 * v, g[0] + 3 * to0[o][v], 3 * sizeof *g[o]);
    double e0 = 0;
    for (int o = 0; o < 3; o++) {
      int rc = t == 0 ? solver_init_at(&s[o], &cv[o].m, method, 1e-5, 0.01, g[o], zero, err, sizeof err)
                      : solver_step_to(&s[o], g[o], err, sizeof err);
      if (rc != 0) fail_msg("%s", err);
      double e = solver_energy(&s[o]);
      if (o == 0) e0 = e;
      if (t > 0) assert_true(e0 > 0), worst = fmax(worst, fabs(e - e0) / e0);
    }
  }
  print_message("energy after 6 steps %.6g; largest relative difference between numberings %.3g\n",
                solver_energy(&s[0]), worst);
  assert_true(worst <= 1e-11);
  for (int o = 0; o < 3; o++) solver_free(&s[o]), free(g[o]), free(to0[o]), cavity_free(&cv[o]);
}

static void test_cavity_projection_reuse(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const FluidMesh *m = &cv.m;
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

static void test_cavity_reduced_step(void **state) {
  (void)state;
  Cavity cv = cavity_of(150);
  const FluidMesh *m = &cv.m;
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
    red_lift(R.Bg, ng, R.mg, R.g, gl);
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
    red_lift(R.Bf, nf, R.mf, R.f, probe.f);
    red_lift(R.Bu, nu, R.mu, R.u, probe.u);
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
    /* the advection's skew parts in single precision (red_single_advection):
     * Â ⊗ f̂ and the step from the same state within single precision's
     * rounding, the skew parts' bytes halved */
    double *A64 = malloc(R.mu * R.mu * sizeof *A64), *A32 = malloc(R.mu * R.mu * sizeof *A32), da = 0, amax = 0;
    RedBytes b64, b32;
    red_step_bytes(&R, 1, &b64);
    red_advection(&R, R.f, A64);
    assert_int_equal(red_single_advection(&R, err, sizeof err), 0);
    assert_null(R.Ask);
    red_advection(&R, R.f, A32);
    for (long i = 0; i < R.mu * R.mu; i++) da = fmax(da, fabs(A64[i] - A32[i])), amax = fmax(amax, fabs(A64[i]));
    red_step_bytes(&R, 1, &b32);
    red_state_restore(&R, &st);
    if (red_step(&R, gn, gdc, err, sizeof err) != 0) fail_msg("%s", err);
    for (long i = 0; i < R.mu; i++) ub[i] = uc[i] - R.u[i];
    double du = red_energy(&R, gn, ub) / red_energy(&R, gn, uc);
    print_message("single-precision advection: Â ⊗ f̂ within %.3g of its largest entry, the step's û within %.3g "
                  "(energy, relative); bytes %.0f -> %.0f\n", da / amax, du, b64.total, b32.total);
    assert_true(da > 0 && da <= 1e-6 * amax);
    assert_true(du <= 1e-10);
    assert_true(fabs(b64.bytes[0] - 2 * b32.bytes[0]) <= 8 && b32.total < b64.total);
    free(A64), free(A32);
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

typedef struct Marker {
  double x[3];
  int cell, tag;
} Marker;

static int marker_cmp(const void *a, const void *b) {
  const Marker *u = a, *v = b;
  for (int d = 0; d < 3; d++)
    if (u->x[d] != v->x[d]) return u->x[d] < v->x[d] ? -1 : 1;
  return u->cell != v->cell ? (u->cell < v->cell ? -1 : 1) : (u->tag > v->tag) - (u->tag < v->tag);
}

static Marker *markers(const Particles *p) {
  Marker *mk = malloc((size_t)p->n * sizeof *mk);
  for (int i = 0; i < p->n; i++) {
    memcpy(mk[i].x, p->x + 3 * i, sizeof mk[i].x);
    mk[i].cell = p->cell[i], mk[i].tag = p->tag[i];
  }
  qsort(mk, (size_t)p->n, sizeof *mk, marker_cmp);
  return mk;
}

/* particles_sort_by_cell puts the particles in cell order and keeps each
 * particle whole (position, cell and tag together); advected by a frame,
 * a reversed copy ends as the same set of particles. */
static void test_cavity_particles_sorted(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const FluidMesh *m = &cv.m;
  Particles a = {0}, b = {0};
  particles_seed(&a, m, m->g0, 200, 5);
  particles_seed(&b, m, m->g0, 200, 5);
  for (int i = 0, j = b.n - 1; i < j; i++, j--) { /* b reversed */
    for (int d = 0; d < 3; d++) {
      double t = b.x[3 * i + d];
      b.x[3 * i + d] = b.x[3 * j + d], b.x[3 * j + d] = t;
    }
    int c = b.cell[i], t = b.tag[i];
    b.cell[i] = b.cell[j], b.tag[i] = b.tag[j], b.cell[j] = c, b.tag[j] = t;
  }
  Marker *before = markers(&a);
  particles_sort_by_cell(&a, m);
  for (int i = 1; i < a.n; i++) assert_true(a.cell[i - 1] <= a.cell[i]);
  Marker *after = markers(&a);
  assert_memory_equal(before, after, (size_t)a.n * sizeof *before);
  double *f = calloc(m->nf, sizeof *f);
  for (int j = 0; j < m->nf; j++) f[j] = 0.01 * sin(0.37 * j);
  particles_advect_cached(&a, m, m->g0, f, 0.05, 10);
  particles_advect_cached(&b, m, m->g0, f, 0.05, 10);
  Marker *ma = markers(&a), *mb = markers(&b);
  assert_memory_equal(ma, mb, (size_t)a.n * sizeof *ma);
  assert_true(memcmp(ma, before, (size_t)a.n * sizeof *ma) != 0); /* they moved */
  free(before), free(after), free(ma), free(mb), free(f);
  particles_free(&a), particles_free(&b);
  cavity_free(&cv);
}

/* Particles through f = B_f f̂: the lazy lift (ParticleFlow's B_f) on 1 and
 * 3 threads against the whole flux lifted by the same row products. */
static void test_cavity_particles_threads(void **state) {
  (void)state;
  Cavity cv = cavity_of(300);
  const FluidMesh *m = &cv.m;
  const int mf = 6, n = 1200;
  float *Bf = malloc((size_t)m->nf * mf * sizeof *Bf), fh[6];
  double *f = malloc(m->nf * sizeof *f);
  for (int j = 0; j < m->nf; j++)
    for (int k = 0; k < mf; k++) Bf[(size_t)j * mf + k] = (float)0.5 * sin(0.37 * j + 1.3 * k) * cos(0.11 * j * (k + 1));
  Particles a = {0}, b = {0}, c = {0};
  particles_seed(&a, m, m->g0, n, 9);
  particles_seed(&b, m, m->g0, n, 9);
  particles_seed(&c, m, m->g0, n, 9);
  c.threads = 3;
  for (int frame = 0; frame < 4; frame++) {
    for (int k = 0; k < mf; k++) fh[k] = (float)cos(0.7 * frame + k);
    for (int j = 0; j < m->nf; j++) f[j] = cblas_sdot(mf, Bf + (size_t)j * mf, 1, fh, 1);
    ParticleFlow whole = {.g = m->g0, .f = f}, lazy = {.g = m->g0, .Bf = Bf, .fh = fh, .mf = mf};
    assert_int_equal(particles_advect_flow(&a, m, &whole, 0.05, 10), 0);
    assert_int_equal(particles_advect_flow(&b, m, &lazy, 0.05, 10), 0);
    assert_int_equal(particles_advect_flow(&c, m, &lazy, 0.05, 10), 0);
    assert_memory_equal(a.x, b.x, 3 * (size_t)n * sizeof *a.x);
    assert_memory_equal(a.x, c.x, 3 * (size_t)n * sizeof *a.x);
    assert_memory_equal(a.cell, b.cell, (size_t)n * sizeof *a.cell);
    assert_memory_equal(a.cell, c.cell, (size_t)n * sizeof *a.cell);
  }
  assert_true(a.walk_steps > 4L * n); /* they crossed several faces a frame */
  assert_int_equal(a.walk_steps, b.walk_steps);
  assert_int_equal(a.walk_steps, c.walk_steps);
  assert_true(b.faces_lifted > 0 && b.faces_lifted < 4 * b.cells_visited && b.cells_visited == a.cells_visited);
  free(Bf), free(f);
  particles_free(&a), particles_free(&b), particles_free(&c);
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
      cmocka_unit_test(test_cavity_train_workers),
      cmocka_unit_test(test_cavity_numbering),
      cmocka_unit_test(test_cavity_numbering_energy),
      cmocka_unit_test(test_cavity_particles_sorted),
      cmocka_unit_test(test_cavity_particles_threads),
  };
  return run_named_tests("test_cavity", argc, argv, all, (int)(sizeof all / sizeof all[0]));
}
