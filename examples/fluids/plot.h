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

/* Release cairo's and fontconfig's caches (at exit: a leak checker then
 * sees nothing left). */
void plot_cleanup(void);

#endif
