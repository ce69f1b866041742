/* output.h — what every subcommand writes besides its folders and report.json (those are
 * examples/common/report.h's): .npy arrays through npg.h (npg_npy_write,
 * npg_npy_write_i64), the scene's arrays, renders, and the statistics of report.json.
 * Functions returning int give 0, or -1 after printing the reason. */
#ifndef RADIOSITY_OUTPUT_H
#define RADIOSITY_OUTPUT_H

#include <stdio.h>

#include "render.h"
#include "report.h"
#include "scene.h"

/* DIR/NAME.npy from float64 data. */
int out_npy(const char *dir, const char *name, int nd, const long *shape, const double *data);
/* DIR/tri.npy (int64 F x 3), rho.npy, e.npy (F). */
int out_scene_arrays(const char *dir, const Scene *s);
/* The render of b on the scene's current g from the fixed camera, with a colour bar of b
 * labelled `bar` under it, to `path`; the view is kept in *keep when non-NULL (free with
 * render_view_free). */
int out_render_frame(const Scene *s, const double *b, double exposure, int ss, const char *bar, const char *path,
                     View *keep);
/* Three renders side by side, labelled `labels`, to `path`: b and bt shaded at `exposure`
 * (colour bars "radiosity b") and |b - bt| with white at 10 % of the bright walls' radiosity
 * (colour bar `err_bar`). */
int out_render_compare(const Scene *s, const double *b, const double *bt, double exposure, int ss,
                       const char *const labels[3], const char *err_bar, const char *path);
double out_median(const double *x, int n);

#endif
