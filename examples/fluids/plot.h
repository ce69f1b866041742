/* plot.h — line plots as PNG with cairo (Debian libcairo2-dev). */
#ifndef FLUIDS_PLOT_H
#define FLUIDS_PLOT_H

#include <stddef.h>

/* nseries lines of n[i] points (x[i][k], y[i][k]), labelled; logy: a log10 y
 * axis (non-positive values skipped). 0, or -1 with the reason in err. */
int plot_lines(const char *path, const char *title, const char *xlabel, const char *ylabel, int nseries,
               const int *n, const double *const *x, const double *const *y, const char *const *labels, int logy,
               char *err, size_t errlen);
/* Two PNG files side by side with captions into one PNG. */
int plot_side_by_side(const char *path, const char *left, const char *right, const char *cap_left,
                      const char *cap_right, char *err, size_t errlen);

/* A colour bar drawn into rows y0 .. y0 + 39 of an RGB image `width` pixels
 * wide: `map` from 0 to vmax (t = value / vmax in [0, 1]), its ticks labelled
 * in the values' units, and `label` beside it. 0, or -1 when out of memory. */
#define PLOT_COLORBAR_HEIGHT 40
int plot_colorbar(unsigned char *rgb, int width, int y0, void (*map)(double t, unsigned char rgb[3]), double vmax,
                  const char *label);

/* Release cairo's and fontconfig's caches (at exit: a leak checker then
 * sees nothing left). */
void plot_cleanup(void);

#endif
