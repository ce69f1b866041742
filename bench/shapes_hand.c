/* shapes_hand.c — shapes_hand.h. */
#include "shapes_hand.h"

#include <math.h>

void hand_heat_step(long n, const int *nbr, double dt, const double *u, double *out) {
  for (long i = 0; i < n; i++) {
    double ui = u[i], s = 0;
    for (int j = 0; j < 4; j++) {
      int m = nbr[4 * i + j];
      if (m >= 0) s += u[m] - ui;
    }
    out[i] = ui + dt * (1 / (1 + ui * ui)) * s;
  }
}

void hand_pair_forces(long P, const int *a, const int *b, double eps, const double *x, double *f) {
  for (long p = 0; p < P; p++) {
    const double *xa = x + 3 * a[p], *xb = x + 3 * b[p];
    double d0 = xb[0] - xa[0], d1 = xb[1] - xa[1], d2 = xb[2] - xa[2];
    double r2 = d0 * d0 + d1 * d1 + d2 * d2 + eps, w = 1 / (r2 * sqrt(r2));
    f[3 * p] = d0 * w, f[3 * p + 1] = d1 * w, f[3 * p + 2] = d2 * w;
  }
}
