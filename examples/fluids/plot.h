/* plot.h — what the frames add with cairo (Debian libcairo2-dev): two pictures side by
 * side, a colour bar. The line charts are examples/common/chart.h's, PLOT_WIDTH x
 * PLOT_HEIGHT pixels; chart_cleanup releases cairo's caches at exit. */
#ifndef FLUIDS_PLOT_H
#define FLUIDS_PLOT_H

#include <stddef.h>

#define PLOT_WIDTH 940
#define PLOT_HEIGHT 560

/* Two PNG files side by side with captions into one PNG. */
int plot_side_by_side(const char *path, const char *left, const char *right, const char *cap_left,
                      const char *cap_right, char *err, size_t errlen);

/* A colour bar drawn into rows y0 .. y0 + 39 of an RGB image `width` pixels
 * wide: `map` from 0 to vmax (t = value / vmax in [0, 1]), its ticks labelled
 * in the values' units, and `label` beside it. 0, or -1 when out of memory. */
#define PLOT_COLORBAR_HEIGHT 40
int plot_colorbar(unsigned char *rgb, int width, int y0, void (*map)(double t, unsigned char rgb[3]), double vmax,
                  const char *label);

#endif
