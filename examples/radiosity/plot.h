/* plot.h — line plots of per-frame values (paper Fig. 8: relative error over the frames
 * of an animation), drawn with cairo and written as PNG. */
#ifndef RADIOSITY_PLOT_H
#define RADIOSITY_PLOT_H

#include <stddef.h>

typedef struct PlotSeries {
  const char *name;  /* legend entry */
  const double *y;   /* n values, one per frame (frame k at x = k); NaN leaves a gap */
  int n;
} PlotSeries;

/* A PNG of the series as lines against the frame index, with axes, ticks, a title, the
 * y-axis label and a legend. ymin/ymax: the y range; pass ymin >= ymax for automatic
 * (0 to a little above the largest value). 0, or -1 with the reason in err. */
int plot_series(const char *path, const char *title, const char *ylabel, const PlotSeries *series, int nseries,
                double ymin, double ymax, char *err, size_t errlen);

#endif
