/* solver.c — the full-space step of paper Fig. 2 (see solver.h). */
#include "util.h"
#include "solver.h"
#include "npg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

int solver_init_at(FullSolver *s, const FluidMesh *m, ProjectionMethod method, double mu, double dt, const double *g0,
                   const double *u0, char *err, size_t errlen) {
  memset(s, 0, sizeof *s);
  s->m = m;
  s->mu = mu;
  s->dt = dt;
  int dim = m->dim;
  size_t gv = dim * (size_t)m->nv * sizeof(double);
  s->g = malloc(gv);
  s->g_next = malloc(gv);
  s->gmid = malloc(gv);
  s->gdot = calloc(dim * m->nv, sizeof(double));
  s->h = calloc(m->nf, sizeof(double));
  s->phi = calloc(m->nf, sizeof(double));
  s->f = calloc(m->nf, sizeof(double));
  s->u = malloc(dim * (size_t)m->nc * sizeof(double));
  memcpy(s->g, g0, gv);
  ops_init(&s->ops, m);
  integrator_init(&s->it, &s->ops);
  ops_set_geometry(&s->ops, s->g);
  if (projection_init(&s->pr, &s->ops, method, err, errlen) != 0) {
    solver_free(s);
    return -1;
  }
  s->min_quality = mesh_min_quality(m, s->g, &s->worst_cell);
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < dim; d++) s->u[dim * c + d] = u0[d];
  if (projection_solve(&s->pr, s->u, NULL, s->f, s->u, err, errlen) != 0) {
    solver_free(s);
    return -1;
  }
  return 0;
}

int solver_init(FullSolver *s, const FluidMesh *m, ProjectionMethod method, double mu, double dt, double sigma0,
                const double u0[2], char *err, size_t errlen) {
  double *g0 = malloc(2 * (size_t)m->nv * sizeof *g0);
  int rc = mesh_deform(m, sigma0, sigma0, g0, err, errlen);
  if (rc == 0) rc = solver_init_at(s, m, method, mu, dt, g0, u0, err, errlen);
  free(g0);
  if (rc == 0) s->sigma = s->sigma_ref = sigma0;
  return rc;
}

void solver_free(FullSolver *s) {
  ops_free(&s->ops);
  integrator_free(&s->it);
  projection_free(&s->pr);
  free(s->g);
  free(s->g_next);
  free(s->gmid);
  free(s->gdot);
  free(s->h);
  free(s->phi);
  free(s->f);
  free(s->u);
  memset(s, 0, sizeof *s);
}

int solver_step(FullSolver *s, double sigma_next, char *err, size_t errlen) {
  double t0 = util_now();
  if (mesh_deform(s->m, sigma_next, s->sigma_ref, s->g_next, err, errlen) != 0) return -1;
  s->seconds_deformation += util_now() - t0;
  if (solver_step_to(s, s->g_next, err, errlen) != 0) return -1;
  s->sigma = sigma_next;
  return 0;
}

int solver_step_to(FullSolver *s, const double *g_next, char *err, size_t errlen) {
  const FluidMesh *m = s->m;
  int dim = m->dim, nv = dim * m->nv;
  double t0 = util_now();
  if (g_next != s->g_next) memcpy(s->g_next, g_next, nv * sizeof *g_next);
  s->min_quality = mesh_min_quality(m, s->g_next, &s->worst_cell);
  if (!(s->min_quality > 0))
    return npg_error_set(err, errlen, "the step's geometry inverts element %d (volume %.3g, rest volume %.3g)",
                         s->worst_cell, mesh_volume(m, s->g_next, s->worst_cell), mesh_volume(m, m->g0, s->worst_cell));
  for (int i = 0; i < nv; i++) {
    s->gmid[i] = 0.5 * (s->g[i] + s->g_next[i]);
    s->gdot[i] = (s->g_next[i] - s->g[i]) / s->dt;
  }
  ops_swept_flux(m, s->g, s->g_next, s->gmid, s->gdot, s->h);
  double t1 = util_now();
  /* advection and diffusion at g_t (the geometry ops holds) */
  for (int j = 0; j < m->nf; j++) s->phi[j] = s->f[j] - s->h[j];
  ops_set_advection(&s->ops, s->phi);
  integrator_rk4(&s->it, s->mu, s->dt, s->u);
  double t2 = util_now();
  /* projection at g_{t+1} */
  ops_set_geometry(&s->ops, s->g_next);
  int rc = projection_solve(&s->pr, s->u, s->h, s->f, s->u, err, errlen);
  double t3 = util_now();
  double *t = s->g;
  s->g = s->g_next;
  s->g_next = t;
  s->seconds_deformation += t1 - t0;
  s->seconds_advection += t2 - t1;
  s->seconds_projection += t3 - t2;
  return rc;
}

double solver_energy(const FullSolver *s) { return ops_energy(&s->ops, s->u); }

int solver_check_energy(double e0, double e, int frame, char *err, size_t errlen) {
  if (isfinite(e) && !(e0 > 0 && e > SOLVER_BLOWUP * e0)) return 0;
  char grew[96];
  if (isfinite(e)) snprintf(grew, sizeof grew, "grew from %.3g to %.3g", e0, e);
  else snprintf(grew, sizeof grew, "is not finite");
  return npg_error_set(err, errlen,
                       "the flow's energy %s at frame %d: the run is unstable and was stopped (the explicit "
                       "RK4 step is stable only for a small enough time step: lower --cfl, or --mu, whose diffusion is "
                       "explicit too)", grew, frame);
}
