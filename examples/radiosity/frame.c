/* frame.c — the full-space radiosity frame (frame.h). */
#include "frame.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "radiosity.h"

double frame_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

const char *frame_solver_name(Solver s) {
  return s == SOLVER_LU ? "lu" : s == SOLVER_GAUSS_SEIDEL ? "gauss-seidel" : "gmres";
}

int frame_new(FullRadiosity *fr, Scene *scene, int k, int threads, VisMode mode, Solver solver, char *err,
             size_t errlen) {
  memset(fr, 0, sizeof *fr);
  fr->scene = scene;
  fr->solver = solver;
  fr->threads = threads;
  size_t F = (size_t)scene->F;
  fr->v = malloc(sizeof(double) * F * F);
  fr->p = malloc(sizeof(double) * F * F);
  fr->b = malloc(sizeof(double) * F);
  if (!fr->v || !fr->p || !fr->b) {
    frame_free(fr);
    snprintf(err, errlen, "out of memory for %zu faces (two %zu x %zu matrices)", F, F, F);
    return -1;
  }
  fr->vis = vis_new(scene->V, scene->F, scene->tri, k, threads, mode, err, errlen);
  if (!fr->vis) {
    frame_free(fr);
    return -1;
  }
  return 0;
}

void frame_free(FullRadiosity *fr) {
  vis_free(fr->vis);
  free(fr->v);
  free(fr->p);
  free(fr->b);
  memset(fr, 0, sizeof *fr);
}

int frame_solve(FullRadiosity *fr, Solver solver, double *seconds, char *err, size_t errlen) {
  const Scene *s = fr->scene;
  double t0 = frame_now();
  int rc;
  if (solver == SOLVER_LU) {
    rc = radiosity_solve_lu(s->F, s->rho, fr->p, s->e, fr->b, err, errlen);
  } else {
    rc = solver == SOLVER_GMRES ? radiosity_solve_gmres(s->F, s->rho, fr->p, s->e, fr->b, 1e-13, 3000, err, errlen)
                                : radiosity_solve_gauss_seidel(s->F, s->rho, fr->p, s->e, fr->b, 1e-14, 2000, err, errlen);
    if (rc > 0) {
      fr->sweeps = rc, rc = 0;
    } else {
      /* Gauss–Seidel needs the spectral radius of diag(rho) F below 1; Eq. 15 can exceed
       * it on a mesh too coarse for its centroid approximation. LU does not care. */
      fr->sweeps = -1;
      rc = radiosity_solve_lu(s->F, s->rho, fr->p, s->e, fr->b, err, errlen);
    }
  }
  if (seconds) *seconds = frame_now() - t0;
  return rc;
}

int frame_compute(FullRadiosity *fr, const SceneParams *p, char *err, size_t errlen) {
  Scene *s = fr->scene;
  if (p) scene_place(s, p, NULL);
  double t0 = frame_now();
  if (vis_compute(fr->vis, s->g, fr->v, err, errlen) != 0) return -1;
  double t1 = frame_now();
  radiosity_form_factors(s->V, s->F, s->g, s->tri, fr->v, fr->p, fr->threads);
  double t2 = frame_now();
  fr->t_vis = t1 - t0;
  fr->t_ff = t2 - t1;
  return frame_solve(fr, fr->solver, &fr->t_solve, err, errlen);
}
