/* frame.h — one full-space radiosity frame of the scene, what a user would run without
 * npg: parameters -> g -> ray-cast v -> form factors p -> b, each step timed.
 * The reduced frame (later: `train`, `run`, `demo`) replaces everything after g. */
#ifndef RADIOSITY_FRAME_H
#define RADIOSITY_FRAME_H

#include <stddef.h>

#include "scene.h"
#include "visibility.h"

typedef enum Solver {
  SOLVER_LU,           /* LAPACK dgesv on the dense F x F matrix */
  SOLVER_GAUSS_SEIDEL, /* sweeps to a relative update of 1e-14 */
  SOLVER_GMRES,        /* restarted GMRES(30) to a relative residual of 1e-13 */
  SOLVER_COUNT
} Solver;

typedef struct FullRadiosity {
  Scene *scene;          /* borrowed; its g and e are the frame's */
  Visibility *vis;
  Solver solver;
  int threads;
  double *v, *p, *b;     /* F x F, F x F, F: the last frame's */
  double t_vis, t_ff, t_solve; /* seconds of the last frame */
  int sweeps;            /* Gauss–Seidel sweeps or GMRES products of the last frame;
                            -1: the iteration failed and LU solved */
} FullRadiosity;

/* A full solver for `scene` with k visibility points per face (1, 4, 16). 0 or -1, err. */
int frame_new(FullRadiosity *fr, Scene *scene, int k, int threads, VisMode mode, Solver solver, char *err,
             size_t errlen);
void frame_free(FullRadiosity *fr);
/* Place the scene at p (NULL: keep g and e as they are) and solve: fills v, p, b. */
int frame_compute(FullRadiosity *fr, const SceneParams *p, char *err, size_t errlen);
/* Only the solve, with `solver`, of the current p (into b); its seconds into *seconds. */
int frame_solve(FullRadiosity *fr, Solver solver, double *seconds, char *err, size_t errlen);
const char *frame_solver_name(Solver s);
double frame_now(void);

#endif
