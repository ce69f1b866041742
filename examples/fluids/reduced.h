/* reduced.h — the reduced step of paper Fig. 2 (right column), from a model
 * of fluids2d.npg or fluids3d.npg trained through npg.h:
 *
 *   advection   û' = exp(Δt V̂⁻¹(ĝ_t)(Â ⊗ (f̂, ĥ) + μ L̂)) û   (Krylov: Padé on the Arnoldi projection;
 *                                                            or scaling and squaring, Padé, on the whole matrix)
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
 * (bilinear in ĝ and f̂). Per step the driver sums the slices (BLAS), the
 * slices of V̂ and of Â_h ⊗ ĥ through their truncated SVD (RedSlices). D̂ (the stage bf, linear in f̂) is
 * constant; its null space and pseudo-inverse (SVD) are taken once: the
 * projection solves on f̂ = D̂⁺ b̂ + N y (constraint reduction, §6.4). B_f's
 * columns are divergence-free (checked by the caller), so divergence needs
 * no constraint (§6.3). Everything dense is LAPACK/BLAS.
 */
#ifndef FLUIDS_REDUCED_H
#define FLUIDS_REDUCED_H

#include <stddef.h>

#include "npg.h"

/* RED_EXPMV: exp(ΔtM)û by the Arnoldi process on the Krylov space of û
 * (the default: the step needs the exponential applied to one vector);
 * RED_EXPM: the whole matrix exponential, then the product (the reference);
 * RED_RK4: the full step's integrator. */
typedef enum RedIntegrator { RED_EXPMV, RED_EXPM, RED_RK4 } RedIntegrator;

/* Matrices that are linear combinations of fixed slices, Σ_a w_a S[a] with
 * S [n][len], kept as their SVD truncated where the singular values are
 * rounding: S = C Y with C [n][rank], Y [rank][len], so a combination
 * reads rank slices instead of n (the slices of ĝ's monomials are far from
 * independent: in 3D V̂'s 35 cubic slices have rank 18, the 75 induced
 * advection slices rank 13, measured on the cavity). */
typedef struct RedSlices {
  long n, len, rank;
  double *coef;   /* [n][rank] */
  double *basis;  /* [rank][len] */
  double *c;      /* [rank] scratch: the combination's coordinates */
} RedSlices;

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
  double *Vp;     /* [mu(mu+1)/2] V̂'s lower triangle (scratch) */
  RedSlices Vs;    /* [nmv] slices of V̂'s lower triangle, row by row (mu(mu+1)/2): V̂(ĝ) = Σ_a m_a(ĝ) Vs[a] */
  double *Ps;      /* [mg][mu*mf]:    P̂(ĝ) = Σ_l ĝ_l Ps[l] */
  double *L;       /* [mu*mu] the reduced Laplacian */
  double *As;      /* [mf][mu*mu]:  Â ⊗ f̂ = Σ_k f̂_k As[k] (set-up only, then freed: the step reads the split below) */
  double *Ask;     /* [mf][mu(mu-1)/2]: the skew parts of the As[k], strict upper triangles */
  float *Ask32;    /* the same in single precision (red_single_advection; Ask then NULL) */
  float *f32, *sk32; /* [mf], [mu(mu-1)/2] scratch of the single-precision product */
  RedSlices Asy;   /* [mf] slices mu(mu+1)/2: their symmetric parts Σ_k f̂_k sym(As[k]), upper triangles row by row */
  long rs;         /* the rank of the symmetric parts (Asy.rank) */
  RedSlices Ahs;   /* [nmh*mgd] slices mu*mu: −Â_h ⊗ ĥ(ĝ, ĝdot) = Σ_aq m_a(ĝ) ĝdot_q Ahs[a][q] */
  double *Bhs;     /* [nmh*mgd][mb]:    D̂_h ĥ(ĝ, ĝdot) likewise */
  double *wgt;     /* [nmh*mgd] */
  long evals;      /* reduced evaluations made by the set-up */
  double seconds_setup;
  double *D;       /* [mb*mf] D̂ */
  double *Dpinv;   /* [mf*mb] */
  double *N;       /* [mf*nn] null space of D̂ */
  double *PNs;     /* [mg][mu*nn]: P̂(ĝ) N = Σ_l ĝ_l PNs[l] */
  double *Vf, *Vfg; /* the Cholesky factor of V̂ (lower, row-major) and the ĝ it belongs to */
  int vf_ok;
  double *Q, *H, *Hx, *hwork; /* Arnoldi: basis (kmax + 1 rows), Hessenberg, its exponential, workspace */
  int kmax;
  long nn, drank;
  double visc, dt;
  RedIntegrator integ;
  /* state */
  double *g, *f, *u; /* coords */
  /* scratch */
  double *A, *M, *E, *V0, *V1, *W, *K, *KN, *Kn, *work, *tmp, *tmp2, *tmp3;
  double *gmid, *gdot, *b;
  double seconds_eval, seconds_advection, seconds_projection;
  long steps;
  int last_pade, last_squarings, last_krylov; /* the last exponential: Padé degree, squarings, Arnoldi steps */
} RedSolver;

/* What a step reads and changes: ĝ, f̂, û and the Cholesky factor of V̂ it
 * keeps for the last ĝ. Saved before a step that must leave the run as it
 * was (a one-step error's probe, a repeated timing) and put back after, so
 * that the run's next step finds the factor it would have found. */
typedef struct RedState {
  double *g, *f, *u, *Vf, *Vfg;
  int vf_ok;
} RedState;

/* The bytes one step streams, array by array: what red_step reads of the
 * set-up's tensors (the mu x mu matrices it builds from them and reuses
 * within the step, A, the factor of V̂ and the Arnoldi basis, are not
 * counted: they stay in cache). `moving`: the step's mesh moves (ĝdot not
 * zero), so it reads the induced flux's slices. */
enum { RED_BYTES_MAX = 8 };
typedef struct RedBytes {
  int n;
  const char *name[RED_BYTES_MAX];
  double bytes[RED_BYTES_MAX];
  double total;
} RedBytes;
void red_step_bytes(const RedSolver *s, int moving, RedBytes *b);

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
/* Keep the advection's skew parts (the step's largest tensor, half its
 * bytes at m_u 127, m_f 64) in single precision: half their bytes, the
 * product accumulated in single precision (cblas_sgemv) and the assembled
 * Â ⊗ f̂ within about 1e-7 of its largest entry. Off unless called
 * (`npg-fluids cavity --single-advection 1`). 0, or -1 out of memory. */
int red_single_advection(RedSolver *s, char *err, size_t errlen);
/* Coordinates from full values: ĝ = B_gᵀ g, f̂ = B_fᵀ f, and the
 * energy-conserving projection û = V̂⁻¹(ĝ) B_uᵀ V(g) u (paper footnote 2),
 * where pv = V(g) u is given (full). */
/* The two products with a basis B [n][m] (row-major) every driver needs: out = B x
 * (lift: the full value of coordinates x) and out = Bᵀ x (coordinates of a full x). */
void red_lift(const double *B, long n, long m, const double *x, double *out);
void red_coords(const double *B, long n, long m, const double *x, double *out);
void red_project_g(const RedSolver *s, const double *g, double *gc);
void red_project_f(const RedSolver *s, const double *f, double *fc);
void red_project_u(RedSolver *s, const double *gc, const double *pv, double *uc);
/* Â ⊗ f̂ (mu x mu) from the skew and symmetric parts. */
void red_advection(const RedSolver *s, const double *fc, double *A);
/* V̂(ĝ) and P̂(ĝ) from their slices. */
void red_volume(const RedSolver *s, const double *gc, double *V);
void red_pmat(const RedSolver *s, const double *gc, double *P);
/* One step from the state (s->g = ĝ_t, s->f, s->u) to ĝ_{t+1} = gnext with
 * mesh velocity coordinates gdotc (ĝdot; NULL: a mesh at rest). 0, or -1. */
int red_step(RedSolver *s, const double *gnext, const double *gdotc, char *err, size_t errlen);
/* The reduced projection (Eq. 12, constraints D̂ f̂ = s->b) at ĝ = gc of
 * velocity coordinates uin: sets s->f and s->u = V̂⁻¹P̂ f̂. 0, or -1. */
int red_projection(RedSolver *s, const double *gc, const double *uin, char *err, size_t errlen);
/* Copy the state of `s` into `st` (allocated on first use: zero it before).
 * 0, or -1 when out of memory. */
int red_state_save(const RedSolver *s, RedState *st);
void red_state_restore(RedSolver *s, const RedState *st);
void red_state_free(RedState *st);
/* Energy ½ ûᵀ V̂(ĝ) û. */
double red_energy(const RedSolver *s, const double *gc, const double *uc);
/* y = exp(ΔtM)u with M = V̂⁻¹(ĝ)S for the n x n S, in the coordinates
 * w = Lᵀu of V̂ = LLᵀ (Vf, lower, row-major), where advection is skew:
 * Arnoldi on ΔtL⁻¹SL⁻ᵀ from w, exp of the Hessenberg matrix by red_expm.
 * Returns the Arnoldi steps, or -1 when it does not converge to `tol`
 * (relative) within s->kmax steps (the caller then takes the whole
 * exponential). */
int red_expmv(RedSolver *s, const double *S, const double *Vf, double dt, const double *u, double *y, double tol);
/* exp(X) for n x n X (row-major) by scaling and squaring with Padé
 * (Higham 2005): out = e^X. pade/squarings report the choice. 0 or -1. */
int red_expm(int n, const double *X, double *out, double *work, int *pade, int *squarings);

#endif
