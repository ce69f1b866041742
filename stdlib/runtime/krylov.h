/* krylov.h — a rational power of a symmetric positive definite matrix
 * applied to one vector, M^(p/q) v, by the Lanczos process (with full
 * reorthogonalization) on the Krylov space of v: v ← β Q_k f(T_k) e₁, f(λ) =
 * λ^(p/q), f(T_k) e₁ by its Chebyshev expansion on T_k's spectrum where that
 * is cheaper than T_k's eigendecomposition by LAPACK (dstedc), else by
 * that. The reduced
 * evaluator's root stages (backends/model/reduced.c, apply_root) try it
 * first, at most n/2 + 8 steps for an n × n operator, and fall back to the
 * eigendecomposition of M (dsytrd, dstedc) where it has not converged by
 * then; the eigendecomposition alone is the exact reference
 * (npg_reduced_exact_roots, reduced_krylov_roots off). The full evaluator's
 * roots of sparse operators use it with M given by its product
 * (stdlib/runtime/sparse.c). */
#ifndef NPG_KRYLOV_H
#define NPG_KRYLOV_H

#include <stdbool.h>

/* The highest degree of the Chebyshev expansion of f(T_k) e₁ (krylov.c). */
#define KRYLOV_MAX_DEGREE 400

typedef struct Krylov {
  long maxn;                /* the largest n the workspace holds */
  long maxsteps;            /* the most Lanczos steps it holds */
  double *Q;                /* Lanczos vectors, one per row (maxsteps + 1 rows of maxn) */
  double *alpha, *beta;     /* T_k's diagonal and off-diagonal */
  double *d, *e, *S, *work; /* dstedc's copy of T_k, its eigenvectors, workspace */
  int *iwork;               /* dstedc's integer workspace (3 + 5 maxsteps) */
  long lwork;
  double *c, *cprev;        /* f(T_k) e₁ and the one of the previous check */
  double *w;                /* a scratch vector (maxsteps) */
  double *cheb;             /* the Chebyshev expansion's points, values, coefficients and three vectors */
  long start;               /* in: where a similar call converged (0: unknown), checks begin 4 steps before;
                               out: the same for the next call */
  double shrink;            /* in/out like start: the factor by which the estimate fell over 4 steps when last
                               seen (0: not yet) */
  long expansions, decompositions; /* f(T_k) e₁ by the Chebyshev expansion, by T_k's eigendecomposition */
} Krylov;

/* Workspace for n up to `maxn` and as many steps. 0, or -1 when out of
 * memory (then krylov_free is still safe). */
int krylov_init(Krylov *k, long maxn);
/* The same for at most `maxsteps` steps (a large sparse operator: the
 * Lanczos vectors take (maxsteps + 1) · maxn doubles). */
int krylov_init_steps(Krylov *k, long maxn, long maxsteps);
void krylov_free(Krylov *k);

/* y ← M x for the caller's symmetric n x n operator `user`. */
typedef void (*KrylovMatvec)(void *user, int n, const double *x, double *y);

/* v ← M^(p/q) v for the row-major symmetric n x n M (not changed), `q` > 1
 * or p < 0. Stops when two approximations 4 steps apart differ by less
 * than `tol` relative (an a-posteriori estimate, in *estimate), or when the
 * Krylov space is invariant (exact). Returns 0 when it converged (v
 * overwritten, *steps the Lanczos steps taken); 1, with v unchanged, when
 * it would take more than `max_steps` steps (or the workspace's) or T_k
 * looks singular or indefinite (the caller then decomposes M, which also
 * says why); -1 when LAPACK failed. */
int krylov_power(Krylov *k, int n, const double *M, long p, long q, double tol, int max_steps, double *v, int *steps,
                 double *estimate);
/* The same with M given by its product (a sparse operator). */
int krylov_power_op(Krylov *k, int n, KrylovMatvec matvec, void *user, long p, long q, double tol, int max_steps,
                    double *v, int *steps, double *estimate);

#endif
