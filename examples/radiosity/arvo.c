/* arvo.c — Arvo's error split and the a-posteriori bounds (arvo.h). */
#include "arvo.h"

#include <math.h>
#include <stdlib.h>

#include "radiosity.h"

static double dist2(long n, const double *x, const double *y) {
  double s = 0;
  for (long i = 0; i < n; i++) s += (x[i] - y[i]) * (x[i] - y[i]);
  return sqrt(s);
}

int arvo_split(long F, const double *rho, const double *p, const double *e, const double *b, const double *b_red,
               const double *b_given, const double *Pb, ArvoSplit *out, char *err, size_t errlen) {
  double nb = 0, nind = dist2(F, b, e);
  for (long i = 0; i < F; i++) nb += b[i] * b[i];
  nb = sqrt(nb);
  out->total = dist2(F, b, b_red) / nb;
  out->total_indirect = dist2(F, b, b_red) / nind;
  out->boundary = dist2(F, b_red, b_given) / nb;
  out->discretization = dist2(F, b, Pb) / nb;
  out->computation = dist2(F, b_given, Pb) / nb;
  double einf = 0, rinf = 0, rowmax = 0;
  for (long i = 0; i < F; i++) {
    const double *row = p + (size_t)i * (size_t)F;
    double ax = 0, rs = 0;
    for (long j = 0; j < F; j++) ax += row[j] * b_red[j], rs += fabs(row[j]);
    double r = e[i] - (b_red[i] - rho[i] * ax);
    rinf = fmax(rinf, fabs(r));
    rowmax = fmax(rowmax, rho[i] * rs);
    einf = fmax(einf, fabs(b[i] - b_red[i]));
  }
  out->err_inf = einf;
  out->residual_inf = rinf;
  out->rho_f_inf = rowmax;
  out->bound_arvo = rowmax < 1 ? rinf / (1 - rowmax) : NAN;
  double *one = calloc((size_t)F, sizeof(double)), *w = calloc((size_t)F, sizeof(double));
  if (!one || !w) {
    free(one), free(w);
    return -1;
  }
  for (long i = 0; i < F; i++) one[i] = 1;
  int rc = radiosity_solve_gmres(F, rho, p, one, w, 1e-13, 3000, err, errlen);
  if (rc < 0) rc = radiosity_solve_lu(F, rho, p, one, w, err, errlen);
  double winf = 0, wmin = INFINITY;
  for (long i = 0; i < F; i++) winf = fmax(winf, w[i]), wmin = fmin(wmin, w[i]);
  free(one), free(w);
  if (rc < 0) return -1;
  /* w > 0 is what the Neumann series gives; a negative entry means the spectral radius
   * of ρF is not below 1 and the bound does not apply */
  out->w_inf = winf;
  out->bound_neumann = wmin > 0 ? rinf * winf : NAN;
  return 0;
}
