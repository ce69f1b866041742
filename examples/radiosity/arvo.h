/* arvo.h — the error of a reduced radiosity frame in Arvo's terms (seed 004: boundary
 * data, discretization, computation) and the a-posteriori bound from the full-space
 * residual.
 *
 * With b the full solution (ray-cast v), b̃ the reduced one (learned v), b̃_v the reduced
 * chain given the ray-cast v (projected), and P = B Bᵀ the projection onto b's basis,
 * all relative L2 to ‖b‖:
 *   total          ‖b − b̃‖
 *   boundary       ‖b̃ − b̃_v‖    what the learned visibility costs (the chain's boundary
 *                                 data: v perturbed)
 *   discretization ‖b − P b‖     the projection floor: no reduced answer in the basis is closer
 *   computation    ‖b̃_v − P b‖  the reduction's own error (the chain's Galerkin steps, with
 *                                 exact boundary data) beyond the floor
 * (total ≤ boundary + ‖b − b̃_v‖ and ‖b − b̃_v‖² = discretization² + computation² when
 * b̃_v lies in the basis, as it does: b is lifted from its class.)
 *
 * The bound. r = e − (I − ρF) b̃ with the full F of the ray-cast v. Since (I − ρF)(b − b̃) = r,
 *   ‖b − b̃‖∞ ≤ ‖r‖∞ / (1 − ‖ρF‖∞)   where ‖ρF‖∞ = max_i ρ_i Σ_j |F_ij| < 1   (Arvo's bound),
 * and, as ρF ≥ 0 entrywise, whenever its spectral radius is below 1 (the Neumann series
 * converges, (I − ρF)⁻¹ ≥ 0):
 *   |b − b̃| ≤ (I − ρF)⁻¹ |r| ≤ ‖r‖∞ w,   w = (I − ρF)⁻¹ 1,
 * so ‖b − b̃‖∞ ≤ ‖r‖∞ ‖w‖∞ (the Neumann bound, which needs no row sum below 1 and is never
 * larger than Arvo's). */
#ifndef RADIOSITY_ARVO_H
#define RADIOSITY_ARVO_H

#include <stddef.h>

typedef struct ArvoSplit {
  double total, total_indirect;   /* ‖b − b̃‖ / ‖b‖ and / ‖b − e‖ */
  double boundary, discretization, computation;
  double err_inf;                 /* ‖b − b̃‖∞ */
  double residual_inf;            /* ‖r‖∞ */
  double rho_f_inf;               /* ‖ρF‖∞ */
  double bound_arvo;              /* ‖r‖∞ / (1 − ‖ρF‖∞), NaN where ‖ρF‖∞ ≥ 1 */
  double w_inf;                   /* ‖(I − ρF)⁻¹ 1‖∞ */
  double bound_neumann;           /* ‖r‖∞ ‖w‖∞ */
} ArvoSplit;

/* The split of one frame: F faces, albedo rho, form factors p (F x F, the full frame's),
 * emission e, the full b, the reduced b_red (learned v), b_given (v given) and Pb (b
 * projected onto its basis). 0, or -1 with err (the solve for w failed). */
int arvo_split(long F, const double *rho, const double *p, const double *e, const double *b, const double *b_red,
               const double *b_given, const double *Pb, ArvoSplit *out, char *err, size_t errlen);

#endif
