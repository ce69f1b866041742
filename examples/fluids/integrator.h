/* integrator.h — advection and diffusion in full space (paper Fig. 2, §5.1,
 * §5.2): one RK4 step of
 *
 *     u' = V(g_t)^-1 (A(f - h) + mu lap) u
 *
 * with the geometry and the advecting flux fixed over the step, as Fig. 2
 * writes it. `o` must hold V(g_t) (ops_set_geometry) and A(f - h)
 * (ops_set_advection). RK4 does not conserve the energy 1/2 u^T V u exactly
 * even where the operator does (paper §A.1, advection alone): on the
 * imaginary axis its amplification is 1 - (lambda dt)^6 / 72 + ..., so the
 * per-step loss is below 1e-10 for |lambda| dt < 0.04.
 */
#ifndef FLUIDS_INTEGRATOR_H
#define FLUIDS_INTEGRATOR_H

#include "operators.h"

typedef struct Integrator {
  const Ops *o;
  Csr M;          /* A(f - h) + mu lap, on A's pattern */
  double *k[4];   /* stage derivatives [C][dim] */
  double *tmp;    /* [C][dim] */
} Integrator;

void integrator_init(Integrator *it, const Ops *o);
void integrator_free(Integrator *it);
/* u <- u + RK4 over dt of V^-1 (A + mu lap) u; u is [C][dim]. */
void integrator_rk4(Integrator *it, double mu, double dt, double *u);
/* du = V^-1 (A + mu lap) u (the right-hand side; for tests). */
void integrator_rate(Integrator *it, double mu, const double *u, double *du);

#endif
