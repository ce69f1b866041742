/* plot.c — side-by-side frames and colour bars with cairo (see plot.h). */
#include "plot.h"
#include "util.h"

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include <cairo.h>

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
