/* projection.h — pressure projection in full space (paper §5.3, Eq. 10, with
 * the moving-boundary constraints of §5.4):
 *
 *     f = argmin 1/2 || u - V(g)^-1 P(g) f ||^2_V(g)
 *         subject to  div f = 0  and  D f - D h = 0,
 *
 * then u = V^-1 P f (Eq. 13). The boundary fluxes are fixed by D f = D h, so
 * the unknowns are the interior faces' fluxes; the objective's Hessian
 * K = P^T V^-1 P couples the faces of a cell, so the Schur complement
 * G K^-1 G^T is dense and the sparse route is the KKT system
 *
 *     [ K  G^T ] [ f ]   [ P^T u - K_ib h_b ]
 *     [ G   0  ] [ l ] = [ -G_b h_b         ]
 *
 * factored by UMFPACK (symmetric indefinite, so LU): the symbolic analysis
 * once per mesh (the pattern never changes), the numeric factorization once
 * per geometry. The divergence rows of all cells sum to the boundary flux, so
 * one row (the last cell's) is dropped; it holds when sum_b h_b = 0, which
 * mesh_deform's area-preserving deformation guarantees.
 *
 * PROJ_AL_CHOLMOD reaches the same minimizer through an SPD system on the
 * interior faces alone (the augmented Lagrangian method): with w large,
 *
 *     (K + w D^T D) f_k = r - D^T l_k + w D^T b,   l_{k+1} = l_k + w (D f_k - b),
 *
 * where D f = b are the KKT system's constraint rows. Every iterate solves
 * K f_k + D^T l_{k+1} = r exactly; the constraint residual shrinks by about
 * 1/(1 + w s_min(D K^-1 D^T)) per iteration, so a few solves with one
 * Cholesky factor (CHOLMOD, supernodal, analysed once) reach D f = b to
 * rounding. D^T D couples the faces of a cell as K does: the pattern is K's.
 *
 * The iterations run in residual form on the current geometry's KKT system,
 * so a factor of an earlier geometry's K + w D^T D (D is topological: only K
 * moves) still converges to the same fluxes, only more slowly (a stationary
 * iteration preconditioned by it), to the same stopping test. The factor is
 * kept across steps while that pays: refactored before a step once the last
 * step's solves exceeded the mean cost per step since the factorization
 * (the factorization counted in solves, estimated from CHOLMOD's flop counts),
 * and within a step as soon as a stale factor's corrections stop
 * contracting fast enough to beat refactoring.
 */
#ifndef FLUIDS_PROJECTION_H
#define FLUIDS_PROJECTION_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#include "operators.h"

/* How the projection is solved: the same minimizer either way (tested). */
typedef enum ProjectionMethod {
  PROJ_KKT_UMFPACK,    /* LU of the KKT system (any dimension) */
  PROJ_STREAM_CHOLMOD, /* Cholesky on the stream function's null space (2D; stream.h) */
  PROJ_AL_CHOLMOD,     /* Cholesky of K + w D^T D, augmented Lagrangian iterations (any dimension) */
} ProjectionMethod;

typedef struct StreamProjection StreamProjection;
typedef struct AugLagrangian AugLagrangian;

typedef struct Projection {
  const Ops *o;
  ProjectionMethod method;
  StreamProjection *stream; /* PROJ_STREAM_CHOLMOD */
  AugLagrangian *al;        /* PROJ_AL_CHOLMOD */
  /* PROJ_AL_CHOLMOD: the factor's reuse (set after projection_init) */
  bool al_refactor_every_step; /* factor K + w D^T D at every projection (the reference) */
  /* a factorization's cost in solves for the reuse policy; 0: estimated from
   * CHOLMOD's flop counts (the same on every run: fluxes bit for bit) */
  double al_factor_cost;
  /* PROJ_AL_CHOLMOD: counts */
  int iterations;              /* solves of the last projection */
  long projections, solves;    /* accumulated */
  long factorizations;         /* accumulated, with the stale ones below */
  long stale_refactorizations; /* of them: mid-projection, a stale factor's iterations stopped contracting */
  long reuses;                 /* projections that started from an earlier geometry's factor */
  int ni, n;        /* interior faces; KKT size ni + C - 1 */
  int *fidx;        /* [F] interior index of a face, -1 on the boundary */
  int nt;           /* triplets */
  int *ti, *tj;     /* [nt] */
  double *tx;       /* [nt] */
  int *map;         /* [nt] triplet -> position in the column form */
  int *Ap, *Ai;     /* column form */
  double *Ax;
  void *symbolic, *numeric;
  double control[20];   /* UMFPACK_CONTROL */
  double *rhs, *x, *work_f, *work_u, *work_f2;
  double seconds_numeric, seconds_solve;  /* accumulated */
} Projection;

/* Pattern and symbolic analysis. 0, or -1 with the reason in `err`. */
int projection_init(Projection *pr, const Ops *o, ProjectionMethod method, char *err, size_t errlen);
/* "kkt-umfpack" / "stream-cholmod" / "al-cholmod". */
const char *projection_method_name(ProjectionMethod method);
void projection_free(Projection *pr);
/* Project u_in [C][dim] with the geometry in `o` (ops_set_geometry: g_{t+1})
 * and boundary fluxes from h [F] (only the boundary entries are read; NULL
 * for zero). Writes f [F] (boundary entries = h) and u_out = V^-1 P f.
 * 0, or -1 with UMFPACK's status in `err`. */
int projection_solve(Projection *pr, const double *u_in, const double *h, double *f, double *u_out, char *err,
                     size_t errlen);
/* The factor's reuse as JSON members, each followed by ",\n" (PROJ_AL_CHOLMOD;
 * nothing otherwise): projections, solves per projection, factorizations,
 * of them stale ones, projections that reused a factor. */
void projection_report_counts(FILE *fp, const Projection *pr);
/* max_c |sum of cell c's outward fluxes|. */
double projection_max_divergence(const Ops *o, const double *f);

#endif
