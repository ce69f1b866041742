/* kernel.h — the radiosity kernel of paper 002 Eq. 2.4 for points.
 *
 *   K(x, y) = [n_y·(x−y)] [n_x·(y−x)] / (π |x−y|⁴),
 *
 * the point-to-point form factor per unit source area, clamped to 0 when
 * either cosine is ≤ 0 (the two points do not face each other), and with
 * one regularization: |x−y|⁴ is read as |x−y|² max(|x−y|², w_y) for the
 * source's area weight w_y, i.e. closer than √w_y (a surfel's own spacing)
 * the source counts as a disc, not a point. Without it the 1/r² of two
 * points across a corner makes rows of the form-factor matrix sum far above
 * 1 and the radiosity iteration diverge; beyond √w_y — everywhere the
 * expansions are used — K is the exact point kernel. With
 * d = x − y it is n_xᵀ H(d) n_y for the 3 x 3 tensor
 *
 *   H(d) = −d dᵀ / (π |d|⁴),
 *
 * smooth away from d = 0 and homogeneous of degree −2: H(s d) = H(d)/s².
 * That is how the normals enter the expansions (fmm.h): H is interpolated
 * in x and y, one Chebyshev coefficient per normal component, and the clamp
 * is honoured exactly by using expansions only between nodes whose points
 * all face each other (fmm_plan's facing test). */
#ifndef POINTS_KERNEL_H
#define POINTS_KERNEL_H

#define KERNEL_INV_PI 0.31830988618379067

/* K(x, y) clamped, for a source of area weight `wy`. The 1e-300 keeps
 * x = y at 0 instead of 0/0. */
static inline double kernel_ff(double xx, double xy, double xz, double nxx, double nxy, double nxz, double yx,
                               double yy, double yz, double nyx, double nyy, double nyz, double wy) {
  double dx = xx - yx, dy = xy - yy, dz = xz - yz;
  double r2 = dx * dx + dy * dy + dz * dz;
  double cos_y = nyx * dx + nyy * dy + nyz * dz;    /* n_y·(x−y) */
  double cos_x = -(nxx * dx + nxy * dy + nxz * dz); /* n_x·(y−x) */
  cos_y = cos_y > 0 ? cos_y : 0;
  cos_x = cos_x > 0 ? cos_x : 0;
  return cos_x * cos_y * KERNEL_INV_PI / (r2 * (r2 > wy ? r2 : wy) + 1e-300);
}

/* kernel_ff in single precision, for the FMM's near field: positions
 * relative to a common origin (the root cube's centre), so that a float's
 * 2⁻²⁴ of the scene size is all the rounding a difference x − y carries.
 * 1e-30f keeps x = y at 0. */
static inline float kernel_ff_float(float xx, float xy, float xz, float nxx, float nxy, float nxz, float yx, float yy,
                                    float yz, float nyx, float nyy, float nyz, float wy) {
  float dx = xx - yx, dy = xy - yy, dz = xz - yz;
  float r2 = dx * dx + dy * dy + dz * dz;
  float cos_y = nyx * dx + nyy * dy + nyz * dz;
  float cos_x = -(nxx * dx + nxy * dy + nxz * dz);
  cos_y = cos_y > 0 ? cos_y : 0;
  cos_x = cos_x > 0 ? cos_x : 0;
  return cos_x * cos_y * (float)KERNEL_INV_PI / (r2 * (r2 > wy ? r2 : wy) + 1e-30f);
}

/* The six distinct entries of H(d): xx yy zz xy xz yz. */
static inline void kernel_tensor(const double d[3], double hv[6]) {
  double r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
  double s = -KERNEL_INV_PI / (r2 * r2);
  hv[0] = s * d[0] * d[0], hv[1] = s * d[1] * d[1], hv[2] = s * d[2] * d[2];
  hv[3] = s * d[0] * d[1], hv[4] = s * d[0] * d[2], hv[5] = s * d[1] * d[2];
}

/* u = H v for the symmetric H of kernel_tensor. */
static inline void kernel_tensor_apply(const double hv[6], const double v[3], double u[3]) {
  u[0] = hv[0] * v[0] + hv[3] * v[1] + hv[4] * v[2];
  u[1] = hv[3] * v[0] + hv[1] * v[1] + hv[5] * v[2];
  u[2] = hv[4] * v[0] + hv[5] * v[1] + hv[2] * v[2];
}

#endif
