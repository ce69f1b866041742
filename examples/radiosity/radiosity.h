/* radiosity.h — full-space radiosity: the form factors of paper Eq. 15 exactly as
 * examples/radiosity/formfactors.npg computes them, and the solve of
 * (I − ρF) b = e (paper Eq. 14) by dense LU, Gauss–Seidel or GMRES.
 *
 * Form factors, per pair (i, j), with n_i = ½ (g1 − g0) × (g2 − g0) the area vector
 * (|n_i| = A_i) and cen_i the centroid of face i:
 *     s_ij = n_i · (cen_j − cen_i)          r_ij = |cen_i − cen_j|² (1 when i = j)
 *     h_ij = s_ij / r_ij                    c_ij = h_ij h_ji / π
 *     d_ij = c_ij v_ij                      a_i  = n_i · n_i
 *     p_ij = d_ij a_i^(−1/2)  = A_j cosθ_i cosθ_j v_ij / (π |cen_i − cen_j|²)
 * the same operations in the same order as the npg program, so the two agree to rounding.
 * p_ii = 0 (s_ii = 0). */
#ifndef RADIOSITY_RADIOSITY_H
#define RADIOSITY_RADIOSITY_H

#include <stddef.h>

/* p (F x F, row-major) for vertices g (V x 3), faces tri (F x 3) and visibility v
 * (F x F), on `threads` threads. */
void radiosity_form_factors(long V, long F, const double *g, const int *tri, const double *v, double *p, int threads);

/* b with (I − diag(rho) p) b = e by LAPACK dgesv (partial pivoting) on a dense copy.
 * 0, or -1 with the reason in err (out of memory; a singular matrix names its pivot). */
int radiosity_solve_lu(long F, const double *rho, const double *p, const double *e, double *b, char *err,
                       size_t errlen);

/* b by Gauss–Seidel sweeps from b = e until the largest update is below tol times the
 * largest |b| (at most max_sweeps). It converges when every row of diag(rho) p sums to
 * less than 1 (energy conservation with albedo < 1). Returns the sweeps taken, or -1 with
 * the reason in err when it did not converge. */
int radiosity_solve_gauss_seidel(long F, const double *rho, const double *p, const double *e, double *b, double tol,
                                 int max_sweeps, char *err, size_t errlen);

/* b by restarted GMRES(30) from b = e until the true residual ‖e − (I − diag(rho) p) b‖₂
 * is below tol ‖e‖₂ (checked at every restart and at the end, not only estimated). Each
 * product is one pass over p through BLAS dgemv. Returns the matrix–vector products
 * used, or -1 with the reason in err after max_matvecs. */
int radiosity_solve_gmres(long F, const double *rho, const double *p, const double *e, double *b, double tol,
                          int max_matvecs, char *err, size_t errlen);

/* ‖e − (I − diag(rho) p) b‖₂ / ‖e‖₂. */
double radiosity_residual(long F, const double *rho, const double *p, const double *e, const double *b);

#endif
