/* inspect.c — the commands that look at one part of the fluids example and print JSON
 * (see inspect.h): the tunnel's mesh, the cavity's mesh and one deformation, the cavity's
 * projection timed per method. */
#include "inspect.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "cavitysim.h"
#include "solver.h"
#include "util.h"

#define ERRLEN 512

/* npg-fluids mesh: the tunnel's mesh statistics as JSON. */
int inspect_mesh(const TunnelSpec *spec) {
  char err[ERRLEN];
  FluidMesh m;
  double t0 = util_now();
  if (mesh_tunnel(&m, spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  double t1 = util_now();
  int walls = 0, obstacle = 0, periodic = 0;
  for (int j = 0; j < m.nf; j++) walls += m.fkind[j] == BF_WALL, obstacle += m.fkind[j] == BF_OBSTACLE;
  for (int i = 0; i < 3 * m.nc; i++) periodic += m.nshift[i] > 0;
  printf("{\"cells\": %d, \"faces\": %d, \"vertices\": %d, \"wall_faces\": %d, \"obstacle_faces\": %d, "
         "\"periodic_faces\": %d, \"min_quality\": %.4f, \"fluid_area\": %.12g, \"mesh_seconds\": %.4f}\n",
         m.nc, m.nf, m.nv, walls, obstacle, periodic, mesh_min_quality(&m, m.g0, NULL), mesh_fluid_volume(&m, m.g0),
         t1 - t0);
  mesh_free(&m);
  return 0;
}

/* npg-fluids cavity-mesh --cells N: the cavity's mesh statistics as JSON,
 * and one deformation (the deepest of the training and test scales). */
int inspect_cavity_mesh(const CavitySpec *spec) {
  char err[ERRLEN];
  Cavity cv;
  double t0 = util_now();
  if (cavity_mesh(&cv, spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  double t1 = util_now();
  double *g = malloc(3 * (size_t)cv.m.nv * sizeof *g), sigma[CAVITY_SIDES] = {0.75, 0.8, 1.0}, kappa = 1;
  int rc = cavity_deform(&cv, sigma, g, &kappa, err, sizeof err);
  double t2 = util_now();
  if (rc == 0)
    printf("{\"cells\": %d, \"faces\": %d, \"boundary_faces\": %d, \"vertices\": %d, \"mesh_seconds\": %.3f, "
           "\"min_quality\": %.4f, \"deformed_min_quality\": %.4f, \"deformation_seconds\": %.4f, \"kappa\": %.6f, "
           "\"volume_change_relative\": %.3g}\n",
           cv.m.nc, cv.m.nf, cv.m.nb, cv.m.nv, t1 - t0, mesh_min_quality(&cv.m, cv.m.g0, NULL),
           mesh_min_quality(&cv.m, g, NULL), t2 - t1, kappa, mesh_fluid_volume(&cv.m, g) / cv.volume0 - 1);
  else
    fprintf(stderr, "npg-fluids: %s\n", err);
  free(g);
  cavity_free(&cv);
  return rc ? 1 : 0;
}

/* npg-fluids cavity-projection: the full step's projection timed per
 * method on the cavity at --cells N, over --steps steps of training run 6
 * (two chambers compressed together) from u = 0; with both methods, the
 * largest difference of their fluxes relative to the largest flux. */
int inspect_cavity_projection(const CavitySpec *spec, int steps, int which) {
  char err[ERRLEN];
  Cavity cv;
  if (cavity_mesh(&cv, spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  const FluidMesh *m = &cv.m;
  double vmin = INFINITY, sigma[CAVITY_SIDES];
  for (int c = 0; c < m->nc; c++) vmin = fmin(vmin, mesh_volume(m, m->g0, c));
  const double zero[3] = {0, 0, 0}, dt = 0.01;
  const ProjectionMethod methods[2] = {PROJ_KKT_UMFPACK, PROJ_AL_CHOLMOD};
  FullSolver s[2];
  int want[2] = {which & 1, (which & 2) >> 1}, on[2] = {0, 0}, rc = 0, iterations = 0; /* on: initialized */
  double *g = malloc(3 * (size_t)m->nv * sizeof *g), diff = 0, div[2] = {0}, init[2] = {0}, fmx = 0;
  for (int k = 0; k < 2 && !rc; k++) {
    if (!want[k]) continue;
    double t0 = util_now();
    rc = solver_init_at(&s[k], m, methods[k], 5 * vmin, dt, m->g0, zero, err, sizeof err);
    init[k] = util_now() - t0;
    on[k] = !rc;
  }
  for (int t = 1; t <= steps && !rc; t++) {
    cavity_schedule(6, t, 100, sigma);
    rc = cavity_deform(&cv, sigma, g, NULL, err, sizeof err);
    for (int k = 0; k < 2 && !rc; k++) {
      if (!on[k]) continue;
      rc = solver_step_to(&s[k], g, err, sizeof err);
      if (rc) break;
      for (int j = 0; j < m->nf; j++) fmx = fmax(fmx, fabs(s[k].f[j]));
      div[k] = fmax(div[k], projection_max_divergence(&s[k].ops, s[k].f) / fmx);
      iterations = k == 1 ? s[k].pr.iterations : iterations;
    }
    if (!rc && on[0] && on[1])
      for (int j = 0; j < m->nf; j++) diff = fmax(diff, fabs(s[0].f[j] - s[1].f[j]) / fmx);
  }
  if (rc) fprintf(stderr, "npg-fluids: %s\n", err);
  else {
    printf("{\"cells\": %d, \"faces\": %d, \"interior_faces\": %d, \"projections\": %d", m->nc, m->nf,
           m->nf - m->nb, steps + 1);
    for (int k = 0; k < 2; k++)
      if (on[k])
        printf(", \"%s\": {\"init_seconds\": %.4g, \"factorization_seconds\": %.4g, \"solve_seconds\": %.4g, "
               "\"max_divergence_relative\": %.3g}",
               projection_method_name(methods[k]), init[k], s[k].pr.seconds_numeric / (steps + 1),
               s[k].pr.seconds_solve / (steps + 1), div[k]);
    if (on[1]) printf(", \"al_iterations_last\": %d", iterations);
    if (on[0] && on[1]) printf(", \"max_flux_difference_relative\": %.3g", diff);
    printf("}\n");
  }
  for (int k = 0; k < 2; k++)
    if (on[k]) solver_free(&s[k]);
  free(g);
  cavity_free(&cv);
  return rc ? 1 : 0;
}
