/* reduced.h — the reduced step of paper Fig. 2 (right column), from a model
 * of fluids2d.npg or fluids3d.npg trained through npg.h:
 *
 *   advection   û' = exp(Δt V̂⁻¹(ĝ_t)(Â ⊗ (f̂, ĥ) + μ L̂)) û   (scaling and squaring, Padé)
 *   projection  f̂ = argmin ½‖û' − V̂⁻¹P̂ f̂‖²_V̂  s.t.  D̂ f̂ = D̂_h ĥ   at ĝ_{t+1} (Eq. 12)
 *               û = V̂⁻¹(ĝ_{t+1}) P̂(ĝ_{t+1}) f̂                       (Eq. 13)
 *
 * Every matrix comes from npg's reduced evaluation of the program, read off
 * by multilinearity once at set-up (reduced evaluations at unit
 * coordinates, and polarization for the polynomials of ĝ): Â ⊗ f̂ =
 * Σ_k f̂_k Â_k from pdot (linear in f̂ and û), the induced advection
 * −Â_h ⊗ ĥ and the boundary fluxes D̂_h ĥ as slices per monomial of ĝ of
 * degree dim - 1 times ĝdot_q (ĥ is npg's reduced h, along the replayed
 * trajectory, §6.2), Δ̂ from lap, V̂(ĝ) from pv (one slice per monomial of
 * ĝ of degree dim: paper Eq. 7's cubic volume tensor in 3D), P̂(ĝ) from p
 * (bilinear in ĝ and f̂). Per step the driver sums the slices (BLAS). D̂ (the stage bf, linear in f̂) is
 * constant; its null space and pseudo-inverse (SVD) are taken once: the
 * projection solves on f̂ = D̂⁺ b̂ + N y (constraint reduction, §6.4). B_f's
 * columns are divergence-free (checked by the caller), so divergence needs
 * no constraint (§6.3). Everything dense is LAPACK/BLAS.
 */
#ifndef FLUIDS_REDUCED_H
#define FLUIDS_REDUCED_H

#include <stddef.h>

#include "npg.h"

typedef enum RedIntegrator { RED_EXPM, RED_RK4 } RedIntegrator;

typedef struct RedSolver {
  const NpgModel *model;
  NpgReduced *r;
  int cg, cgd, cf, cu, cb;            /* classes of g, gdot, f, u, bf */
  long ng, ngd, nf, nu;               /* full sizes */
  long mg, mgd, mf, mu, mb;           /* basis sizes */
  const double *Bg, *Bgd, *Bf, *Bu;   /* n x m row-major (the model's) */
  int dim;        /* 2 or 3 */
  long nmv, nmh;  /* monomials of ĝ of degree dim (V̂) and dim - 1 (ĥ) */
  int (*mono_v)[3], (*mono_h)[3]; /* their indices (sorted, -1 unused) */
  double *mvals;  /* [nmv + 3 nmh] monomial values (scratch) */
  double *Vs;      /* [nmv][mu*mu]: V̂(ĝ) = Σ_a m_a(ĝ) Vs[a] */
  double *Ps;      /* [mg][mu*mf]:    P̂(ĝ) = Σ_l ĝ_l Ps[l] */
  double *L;       /* [mu*mu] the reduced Laplacian */
  double *As;      /* [mf][mu*mu]:  Â ⊗ f̂ = Σ_k f̂_k As[k] */
  double *Ahs;     /* [nmh*mgd][mu*mu]: −Â_h ⊗ ĥ(ĝ, ĝdot) = Σ_aq m_a(ĝ) ĝdot_q Ahs[a][q] */
  double *Bhs;     /* [nmh*mgd][mb]:    D̂_h ĥ(ĝ, ĝdot) likewise */
  double *wgt;     /* [nmh*mgd] */
  long evals;      /* reduced evaluations made by the set-up */
  double seconds_setup;
  double *D;       /* [mb*mf] D̂ */
  double *Dpinv;   /* [mf*mb] */
  double *N;       /* [mf*nn] null space of D̂ */
  long nn, drank;
  double visc, dt;
  RedIntegrator integ;
  /* state */
  double *g, *f, *u; /* coords */
  /* scratch */
  double *A, *M, *E, *V0, *V1, *P1, *W, *K, *KN, *Kn, *work, *tmp, *tmp2, *tmp3;
  double *gmid, *gdot, *b;
  double seconds_eval, seconds_advection, seconds_projection;
  long steps;
  int last_pade, last_squarings;
} RedSolver;

/* Set up from a model of fluids2d.npg (dim 2) or fluids3d.npg (dim 3)
 * (classes looked up by quantity name; m_g at most 16). 0, or -1 with the
 * reason in err. */
int red_init(RedSolver *s, const NpgModel *model, int dim, double visc, double dt, char *err, size_t errlen);
void red_free(RedSolver *s);
/* Constraint reduction with rank tolerance `tol` (relative to the largest
 * singular value of D̂; red_init uses 1e-10): constraints along smaller
 * singular values are dropped, since a boundary flux b̂ = D̂_h ĥ that is
 * off D̂'s range by rounding or by the truncation of ĥ would be amplified by
 * their inverse. 0, or -1. */
int red_constraints(RedSolver *s, double tol, char *err, size_t errlen);
/* Coordinates from full values: ĝ = B_gᵀ g, f̂ = B_fᵀ f, and the
 * energy-conserving projection û = V̂⁻¹(ĝ) B_uᵀ V(g) u (paper footnote 2),
 * where pv = V(g) u is given (full). */
void red_project_g(const RedSolver *s, const double *g, double *gc);
void red_project_f(const RedSolver *s, const double *f, double *fc);
void red_project_u(RedSolver *s, const double *gc, const double *pv, double *uc);
/* V̂(ĝ) and P̂(ĝ) from their slices. */
void red_volume(const RedSolver *s, const double *gc, double *V);
void red_pmat(const RedSolver *s, const double *gc, double *P);
/* One step from the state (s->g = ĝ_t, s->f, s->u) to ĝ_{t+1} = gnext with
 * mesh velocity coordinates gdotc (ĝdot; NULL: a mesh at rest). 0, or -1. */
int red_step(RedSolver *s, const double *gnext, const double *gdotc, char *err, size_t errlen);
/* The reduced projection (Eq. 12, constraints D̂ f̂ = s->b) at ĝ = gc of
 * velocity coordinates uin: sets s->f and s->u = V̂⁻¹P̂ f̂. 0, or -1. */
int red_projection(RedSolver *s, const double *gc, const double *uin, char *err, size_t errlen);
/* Energy ½ ûᵀ V̂(ĝ) û. */
double red_energy(const RedSolver *s, const double *gc, const double *uc);
/* exp(X) for n x n X (row-major) by scaling and squaring with Padé
 * (Higham 2005): out = e^X. pade/squarings report the choice. 0 or -1. */
int red_expm(int n, const double *X, double *out, double *work, int *pade, int *squarings);

#endif
