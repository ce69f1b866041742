/* plot.c — line plots and side-by-side frames with cairo (see plot.h). */
#include "plot.h"
#include "util.h"

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include <cairo.h>
#include <fontconfig/fontconfig.h>

static const double palette[][3] = {{0.12, 0.47, 0.71}, {1.0, 0.5, 0.05}, {0.17, 0.63, 0.17}, {0.84, 0.15, 0.16},
                                    {0.58, 0.4, 0.74},  {0.55, 0.34, 0.29}, {0.89, 0.47, 0.76}, {0.5, 0.5, 0.5}};

int plot_lines(const char *path, const char *title, const char *xlabel, const char *ylabel, int nseries,
               const int *n, const double *const *x, const double *const *y, const char *const *labels, int logy,
               char *err, size_t errlen) {
  const int W = 940, H = 560, L = 110, R = 190, T = 50, B = 60;
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  for (int s = 0; s < nseries; s++)
    for (int k = 0; k < n[s]; k++) {
      double yv = y[s][k];
      if (logy) {
        if (!(yv > 0)) continue;
        yv = log10(yv);
      }
      if (!isfinite(yv)) continue;
      x0 = fmin(x0, x[s][k]), x1 = fmax(x1, x[s][k]), y0 = fmin(y0, yv), y1 = fmax(y1, yv);
    }
  if (!(x1 >= x0) || !(y1 >= y0)) {
    snprintf(err, errlen, "%s: nothing to plot", path);
    return -1;
  }
  if (x1 == x0) x0 -= 1, x1 += 1;
  if (logy) y0 = floor(y0), y1 = ceil(y1);
  if (y1 == y0) y0 -= 1, y1 += 1;
  cairo_surface_t *sf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, W, H);
  cairo_t *cr = cairo_create(sf);
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  double pw = W - L - R, ph = H - T - B;
#define PX(v) (L + ((v) - x0) / (x1 - x0) * pw)
#define PY(v) (T + ph - ((v) - y0) / (y1 - y0) * ph)
  /* grid and ticks */
  cairo_set_font_size(cr, 12);
  cairo_set_line_width(cr, 1);
  char buf[64];
  int ny = logy ? (int)(y1 - y0) : 5;
  for (int i = 0; i <= ny; i++) {
    double v = y0 + (y1 - y0) * i / ny;
    cairo_set_source_rgb(cr, 0.88, 0.88, 0.88);
    cairo_move_to(cr, L, PY(v)), cairo_line_to(cr, L + pw, PY(v)), cairo_stroke(cr);
    cairo_set_source_rgb(cr, 0, 0, 0);
    if (logy)
      snprintf(buf, sizeof buf, "1e%d", (int)lround(v));
    else
      snprintf(buf, sizeof buf, "%.3g", v);
    cairo_text_extents_t ext;
    cairo_text_extents(cr, buf, &ext);
    cairo_move_to(cr, L - 8 - ext.x_advance, PY(v) + 4), cairo_show_text(cr, buf);
  }
  /* x ticks at a round step; where every x is a whole number (frames, basis sizes: a
   * count) the step is too, so no tick falls between two counts */
  bool counts = true;
  for (int s = 0; s < nseries; s++)
    for (int k = 0; k < n[s]; k++) counts = counts && x[s][k] == floor(x[s][k]);
  double xs = util_tick_step(x1 - x0, 6);
  if (counts && xs < 1) xs = 1;
  for (double v = ceil(x0 / xs - 1e-9) * xs; v <= x1 + 1e-9 * xs; v += xs) {
    cairo_set_source_rgb(cr, 0.88, 0.88, 0.88);
    cairo_move_to(cr, PX(v), T), cairo_line_to(cr, PX(v), T + ph), cairo_stroke(cr);
    cairo_set_source_rgb(cr, 0, 0, 0);
    snprintf(buf, sizeof buf, "%.4g", fabs(v) < 1e-9 * xs ? 0.0 : v);
    cairo_text_extents_t ext;
    cairo_text_extents(cr, buf, &ext);
    cairo_move_to(cr, PX(v) - ext.x_advance / 2, T + ph + 18), cairo_show_text(cr, buf);
  }
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_rectangle(cr, L, T, pw, ph), cairo_stroke(cr);
  cairo_set_font_size(cr, 16);
  cairo_move_to(cr, L, 30), cairo_show_text(cr, title);
  cairo_set_font_size(cr, 13);
  cairo_move_to(cr, L + pw / 2 - 40, H - 15), cairo_show_text(cr, xlabel);
  cairo_save(cr);
  cairo_text_extents_t yl;
  cairo_text_extents(cr, ylabel, &yl);
  cairo_move_to(cr, 22, T + ph / 2 + yl.x_advance / 2), cairo_rotate(cr, -M_PI / 2), cairo_show_text(cr, ylabel);
  cairo_restore(cr);
  /* series */
  for (int s = 0; s < nseries; s++) {
    const double *c = palette[s % 8];
    cairo_set_source_rgb(cr, c[0], c[1], c[2]);
    cairo_set_line_width(cr, 1.6);
    int pen = 0;
    for (int k = 0; k < n[s]; k++) {
      double yv = y[s][k];
      if (logy) yv = yv > 0 ? log10(yv) : NAN;
      if (!isfinite(yv)) {
        pen = 0;
        continue;
      }
      if (pen)
        cairo_line_to(cr, PX(x[s][k]), PY(yv));
      else
        cairo_move_to(cr, PX(x[s][k]), PY(yv));
      pen = 1;
    }
    cairo_stroke(cr);
    if (n[s] <= 40)
      for (int k = 0; k < n[s]; k++) {
        double yv = logy ? (y[s][k] > 0 ? log10(y[s][k]) : NAN) : y[s][k];
        if (!isfinite(yv)) continue;
        cairo_arc(cr, PX(x[s][k]), PY(yv), 3.5, 0, 2 * M_PI), cairo_fill(cr);
      }
    if (labels && labels[s]) {
      cairo_rectangle(cr, L + pw + 15, T + 10 + 22 * s, 18, 4), cairo_fill(cr);
      cairo_set_source_rgb(cr, 0, 0, 0);
      cairo_move_to(cr, L + pw + 40, T + 16 + 22 * s), cairo_show_text(cr, labels[s]);
    }
  }
#undef PX
#undef PY
  cairo_status_t st = cairo_surface_write_to_png(sf, path);
  cairo_destroy(cr);
  cairo_surface_destroy(sf);
  if (st != CAIRO_STATUS_SUCCESS) {
    snprintf(err, errlen, "%s: %s", path, cairo_status_to_string(st));
    return -1;
  }
  return 0;
}

int plot_side_by_side(const char *path, const char *left, const char *right, const char *cap_left,
                      const char *cap_right, char *err, size_t errlen) {
  cairo_surface_t *a = cairo_image_surface_create_from_png(left), *b = cairo_image_surface_create_from_png(right);
  int rc = 0;
  if (cairo_surface_status(a) || cairo_surface_status(b)) {
    snprintf(err, errlen, "%s: cannot read", cairo_surface_status(a) ? left : right);
    rc = -1;
  } else {
    int wa = cairo_image_surface_get_width(a), ha = cairo_image_surface_get_height(a);
    int wb = cairo_image_surface_get_width(b), hb = cairo_image_surface_get_height(b);
    int cap = 24, gap = 8, W = wa + gap + wb, H = cap + (ha > hb ? ha : hb);
    cairo_surface_t *sf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, W, H);
    cairo_t *cr = cairo_create(sf);
    cairo_set_source_rgb(cr, 1, 1, 1), cairo_paint(cr);
    cairo_set_source_surface(cr, a, 0, cap), cairo_paint(cr);
    cairo_set_source_surface(cr, b, wa + gap, cap), cairo_paint(cr);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_BOLD);
    cairo_set_font_size(cr, 15);
    cairo_move_to(cr, 8, 18), cairo_show_text(cr, cap_left);
    cairo_move_to(cr, wa + gap + 8, 18), cairo_show_text(cr, cap_right);
    if (cairo_surface_write_to_png(sf, path) != CAIRO_STATUS_SUCCESS) {
      snprintf(err, errlen, "%s: cannot write", path);
      rc = -1;
    }
    cairo_destroy(cr);
    cairo_surface_destroy(sf);
  }
  cairo_surface_destroy(a);
  cairo_surface_destroy(b);
  return rc;
}

int plot_colorbar(unsigned char *rgb, int width, int y0, void (*map)(double t, unsigned char rgb[3]), double vmax,
                  const char *label) {
  const int H = PLOT_COLORBAR_HEIGHT, bh = 12, margin = 12;
  cairo_text_extents_t ext;
  cairo_surface_t *sf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, width, H);
  if (cairo_surface_status(sf)) return -1;
  cairo_t *cr = cairo_create(sf);
  cairo_set_source_rgb(cr, 1, 1, 1), cairo_paint(cr);
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, 11);
  cairo_text_extents(cr, label, &ext);
  int bw = width - 3 * margin - (int)ext.x_advance; /* the label right of the bar */
  if (bw < 16) bw = width - 2 * margin;
  cairo_surface_flush(sf);
  unsigned char *data = cairo_image_surface_get_data(sf);
  int stride = cairo_image_surface_get_stride(sf);
  for (int x = 0; x < bw; x++) {
    unsigned char c[3];
    map((double)x / (bw - 1), c);
    for (int y = 6; y < 6 + bh; y++)
      ((uint32_t *)(data + (size_t)y * stride))[margin + x] = (uint32_t)c[0] << 16 | (uint32_t)c[1] << 8 | c[2];
  }
  cairo_surface_mark_dirty(sf);
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_set_line_width(cr, 1);
  cairo_rectangle(cr, margin - 0.5, 5.5, bw + 1, bh + 1), cairo_stroke(cr);
  cairo_move_to(cr, 2 * margin + bw, 6 + bh), cairo_show_text(cr, label);
  double step = util_tick_step(vmax, 5);
  char buf[32];
  for (double v = 0; v <= vmax * (1 + 1e-9); v += step) {
    double x = margin + (bw - 1) * v / vmax;
    cairo_move_to(cr, round(x) + 0.5, 6 + bh), cairo_line_to(cr, round(x) + 0.5, 10 + bh), cairo_stroke(cr);
    snprintf(buf, sizeof buf, "%g", fabs(v) < 1e-9 * step ? 0.0 : v);
    cairo_text_extents(cr, buf, &ext);
    cairo_move_to(cr, fmin(fmax(x - ext.x_advance / 2, 0), width - ext.x_advance), 22 + bh), cairo_show_text(cr, buf);
  }
  cairo_destroy(cr);
  cairo_surface_flush(sf);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < width; x++) {
      uint32_t px = ((const uint32_t *)(data + (size_t)y * stride))[x];
      unsigned char *q = rgb + 3 * ((size_t)(y0 + y) * width + x);
      q[0] = (unsigned char)(px >> 16), q[1] = (unsigned char)(px >> 8), q[2] = (unsigned char)px;
    }
  cairo_surface_destroy(sf);
  return 0;
}

void plot_cleanup(void) {
  cairo_debug_reset_static_data();
  FcFini();
}
