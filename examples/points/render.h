/* render.h — pictures (cairo): surfel splats of radiosity from the fixed
 * camera of the Cornell box, heat maps, and line plots of measurements. */
#ifndef POINTS_RENDER_H
#define POINTS_RENDER_H

#include "surfels.h"

/* Splats of `b` (n x 3 radiosity) as discs of radius √(w/π)·1.6 with a
 * depth test, tone mapped by b·exposure and gamma 2.2. 0 or -1. */
int render_radiosity(const Surfels *s, const double *b, double exposure, int width, const char *path);

/* Three panels side by side: b_fmm titled `title_a`, b_dense (the
 * reference) titled `title_b`, and |b_fmm − b_dense| / max|b_dense| as a
 * heat map on a log scale with its colour bar. 0 or -1. */
int render_comparison(const Surfels *s, const double *b_fmm, const double *b_dense, double exposure, int width,
                      const char *path, const char *title_a, const char *title_b);

typedef struct PlotSeries {
  const char *label;
  int n;
  const double *x, *y;
} PlotSeries;

/* Log–log (or log-y when !logx) line plot with markers. 0 or -1. */
int render_plot(const char *path, const char *title, const char *xlabel, const char *ylabel, int logx,
                const PlotSeries *series, int nseries);


#endif
