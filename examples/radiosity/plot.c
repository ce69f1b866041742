/* plot.c — per-frame line charts (plot.h), drawn by examples/common/chart.c. */
#include "plot.h"

#include <math.h>
#include <stdlib.h>

#include "chart.h"
#include "util.h"
#include "npg.h"

/* the plots' colours: blue, red, green, orange first */
static const double palette[][3] = {
    {0.12, 0.47, 0.71}, {0.84, 0.15, 0.16}, {0.17, 0.63, 0.17}, {1.00, 0.50, 0.05},
    {0.58, 0.40, 0.74}, {0.55, 0.34, 0.29}, {0.89, 0.47, 0.76}, {0.50, 0.50, 0.50},
};

int plot_series(const char *path, const char *title, const char *ylabel, const PlotSeries *series, int nseries,
                double ymin, double ymax, char *err, size_t errlen) {
  int nmax = 1;
  double big = 0;
  for (int s = 0; s < nseries; s++) {
    if (series[s].n > nmax) nmax = series[s].n;
    for (int k = 0; k < series[s].n; k++)
      if (isfinite(series[s].y[k]) && series[s].y[k] > big) big = series[s].y[k];
  }
  if (!(ymin < ymax)) ymin = 0, ymax = big > 0 ? big * 1.15 : 1; /* from 0 to a little above the largest */
  double *frame = malloc(sizeof *frame * nmax);
  ChartSeries *cs = calloc(nseries > 0 ? nseries : 1, sizeof *cs);
  if (!frame || !cs) {
    free(frame), free(cs);
    return npg_error_set(err, errlen, "%s: out of memory", path);
  }
  for (int k = 0; k < nmax; k++) frame[k] = k;
  for (int s = 0; s < nseries; s++)
    cs[s] = (ChartSeries){series[s].name, series[s].n, frame, series[s].y, -1, false, series[s].n <= 60};
  Chart c = {.title = title, .xlabel = "frame", .ylabel = ylabel ? ylabel : "", .nseries = nseries, .series = cs,
             .ymin = ymin, .ymax = ymax, .legend_inside = true, .palette = palette, .npalette = 8};
  int rc = chart_png(&c, path, 760, 440, err, errlen);
  free(frame), free(cs);
  return rc;
}
