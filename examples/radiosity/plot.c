/* plot.c — per-frame line plots with cairo (plot.h). */
#include "util.h"
#include "plot.h"

#include <cairo.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

static const double palette[][3] = {
    {0.12, 0.47, 0.71}, {0.84, 0.15, 0.16}, {0.17, 0.63, 0.17}, {1.00, 0.50, 0.05},
    {0.58, 0.40, 0.74}, {0.55, 0.34, 0.29}, {0.89, 0.47, 0.76}, {0.50, 0.50, 0.50},
};

int plot_series(const char *path, const char *title, const char *ylabel, const PlotSeries *series, int nseries,
                double ymin, double ymax, char *err, size_t errlen) {
  const int W = 760, H = 440;
  const double left = 78, right = 20, top = 44, bottom = 52;
  int nmax = 1;
  double big = 0;
  for (int s = 0; s < nseries; s++) {
    if (series[s].n > nmax) nmax = series[s].n;
    for (int k = 0; k < series[s].n; k++)
      if (isfinite(series[s].y[k]) && series[s].y[k] > big) big = series[s].y[k];
  }
  if (!(ymin < ymax)) {
    ymin = 0;
    ymax = big > 0 ? big * 1.15 : 1;
  }
  double xmax = nmax > 1 ? nmax - 1 : 1;
  double pw = W - left - right, ph = H - top - bottom;
#define PX(x) (left + (x) / xmax * pw)
#define PY(y) (top + ph - ((y) - ymin) / (ymax - ymin) * ph)
  cairo_surface_t *surf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, W, H);
  cairo_t *cr = cairo_create(surf);
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, 12);
  cairo_set_line_width(cr, 1);
  char label[64];
  cairo_text_extents_t ext;
  /* y grid and ticks */
  double ys = util_tick_step(ymax - ymin, 6);
  for (double y = ceil(ymin / ys) * ys; y <= ymax + 1e-9 * ys; y += ys) {
    cairo_set_source_rgb(cr, 0.9, 0.9, 0.9);
    cairo_move_to(cr, left, round(PY(y)) + 0.5);
    cairo_line_to(cr, left + pw, round(PY(y)) + 0.5);
    cairo_stroke(cr);
    snprintf(label, sizeof label, "%g", fabs(y) < 1e-12 * ys ? 0.0 : y);
    cairo_text_extents(cr, label, &ext);
    cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
    cairo_move_to(cr, left - 6 - ext.width, PY(y) + ext.height / 2);
    cairo_show_text(cr, label);
  }
  /* x ticks (frames) */
  double xs = util_tick_step(xmax, 8);
  if (xs < 1) xs = 1;
  for (double x = 0; x <= xmax + 1e-9; x += xs) {
    snprintf(label, sizeof label, "%g", x);
    cairo_text_extents(cr, label, &ext);
    cairo_move_to(cr, PX(x) - ext.width / 2, top + ph + 18);
    cairo_show_text(cr, label);
    cairo_move_to(cr, round(PX(x)) + 0.5, top + ph);
    cairo_line_to(cr, round(PX(x)) + 0.5, top + ph + 5);
    cairo_stroke(cr);
  }
  /* axes */
  cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
  cairo_rectangle(cr, left + 0.5, top + 0.5, pw, ph);
  cairo_stroke(cr);
  cairo_text_extents(cr, "frame", &ext);
  cairo_move_to(cr, left + pw / 2 - ext.width / 2, H - 12);
  cairo_show_text(cr, "frame");
  cairo_save(cr);
  cairo_text_extents(cr, ylabel ? ylabel : "", &ext);
  cairo_move_to(cr, 18, top + ph / 2 + ext.width / 2);
  cairo_rotate(cr, -M_PI / 2);
  cairo_show_text(cr, ylabel ? ylabel : "");
  cairo_restore(cr);
  cairo_set_font_size(cr, 15);
  cairo_text_extents(cr, title ? title : "", &ext);
  cairo_move_to(cr, left + pw / 2 - ext.width / 2, 26);
  cairo_show_text(cr, title ? title : "");
  cairo_set_font_size(cr, 12);
  /* the series, clipped to the plot area */
  cairo_save(cr);
  cairo_rectangle(cr, left, top, pw, ph);
  cairo_clip(cr);
  cairo_set_line_width(cr, 2);
  for (int s = 0; s < nseries; s++) {
    const double *c = palette[s % 8];
    cairo_set_source_rgb(cr, c[0], c[1], c[2]);
    int pen = 0;
    for (int k = 0; k < series[s].n; k++) {
      double y = series[s].y[k];
      if (!isfinite(y)) {
        pen = 0;
        continue;
      }
      if (pen)
        cairo_line_to(cr, PX(k), PY(y));
      else
        cairo_move_to(cr, PX(k), PY(y));
      pen = 1;
      if (series[s].n == 1) cairo_line_to(cr, PX(k) + 1, PY(y));
    }
    cairo_stroke(cr);
    for (int k = 0; k < series[s].n && series[s].n <= 60; k++)
      if (isfinite(series[s].y[k])) {
        cairo_arc(cr, PX(k), PY(series[s].y[k]), 2.5, 0, 2 * M_PI);
        cairo_fill(cr);
      }
  }
  cairo_restore(cr);
  /* legend, top right */
  double lw = 0;
  for (int s = 0; s < nseries; s++) {
    cairo_text_extents(cr, series[s].name ? series[s].name : "", &ext);
    if (ext.x_advance > lw) lw = ext.x_advance;
  }
  double lx = left + pw - lw - 44, ly = top + 10;
  cairo_set_source_rgba(cr, 1, 1, 1, 0.85);
  cairo_rectangle(cr, lx - 6, ly - 4, lw + 44, 18.0 * nseries + 6);
  cairo_fill(cr);
  for (int s = 0; s < nseries; s++) {
    const double *c = palette[s % 8];
    cairo_set_source_rgb(cr, c[0], c[1], c[2]);
    cairo_set_line_width(cr, 2);
    cairo_move_to(cr, lx, ly + 18 * s + 7);
    cairo_line_to(cr, lx + 26, ly + 18 * s + 7);
    cairo_stroke(cr);
    cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
    cairo_move_to(cr, lx + 32, ly + 18 * s + 11);
    cairo_show_text(cr, series[s].name ? series[s].name : "");
  }
#undef PX
#undef PY
  cairo_destroy(cr);
  char tmp[4096];
  snprintf(tmp, sizeof tmp, "%s.tmp.%ld.png", path, (long)getpid());
  cairo_status_t st = cairo_surface_write_to_png(surf, tmp);
  cairo_surface_destroy(surf);
  if (st != CAIRO_STATUS_SUCCESS) {
    remove(tmp);
    return util_fail(err, errlen, "%s: cairo: %s", path, cairo_status_to_string(st));
  }
  if (rename(tmp, path) != 0) {
    remove(tmp);
    return util_fail(err, errlen, "%s: %s", path, strerror(errno));
  }
  return 0;
}
