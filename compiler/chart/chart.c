/* chart.c — line charts as PNG with cairo (chart.h). */
#define _DEFAULT_SOURCE /* M_PI, getpid */
#include "chart.h"

#include <cairo.h>
#include <fontconfig/fontconfig.h>
#include <math.h>
#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

/* A point's coordinate on an axis, NAN when it cannot be drawn there. */
static double axis_value(double v, bool log) {
  if (!isfinite(v)) return NAN;
  if (log) return v > 0 ? log10(v) : NAN;
  return v;
}

/* Distinct, readable colours (Tableau 10). */
static const double palette[10][3] = {
    {0.12, 0.47, 0.71}, {1.00, 0.50, 0.05}, {0.17, 0.63, 0.17}, {0.84, 0.15, 0.16}, {0.58, 0.40, 0.74},
    {0.55, 0.34, 0.29}, {0.89, 0.47, 0.76}, {0.50, 0.50, 0.50}, {0.74, 0.74, 0.13}, {0.09, 0.75, 0.81}};

/* Series s's colour: the chart's palette or Tableau 10, in turn; past the palette the
 * colours repeat, dashed. */
static const double *series_colour(const Chart *c, int s) {
  return c->palette && c->npalette > 0 ? c->palette[s % c->npalette] : palette[s % 10];
}

static bool series_dashed(const Chart *c, int s) {
  return s >= (c->palette && c->npalette > 0 ? c->npalette : 10);
}

/* Tick positions over [lo, hi]: decades on a log axis, 1-2-5 steps else; on an axis of
 * counts (every value whole) at least 1, so no tick falls between two counts. */
static double tick_step(double lo, double hi, bool log, bool counts) {
  if (log) return fmax(1, ceil((hi - lo) / 8));
  double raw = (hi - lo) / 6, mag = pow(10, floor(log10(raw))), r = raw / mag;
  double step = (r < 1.5 ? 1 : r < 3.5 ? 2 : r < 7.5 ? 5 : 10) * mag;
  return counts && step < 1 ? 1 : step;
}

/* Every drawable x of the chart a whole number. */
static bool x_counts(const Chart *c) {
  for (int s = 0; s < c->nseries; s++)
    for (int i = 0; i < c->series[s].n; i++) {
      double x = c->series[s].x[i];
      if (isfinite(x) && x != floor(x)) return false;
    }
  return !c->logx;
}

/* The legend's width: its longest label, the sample line and the margins. */
static double legend_width(cairo_t *cr, const Chart *c) {
  double w = 0;
  cairo_text_extents_t te;
  for (int s = 0; s < c->nseries; s++)
    if (c->series[s].label) {
      cairo_text_extents(cr, c->series[s].label, &te);
      w = fmax(w, te.x_advance);
    }
  return w > 0 ? w + 62 : 20;
}

static void dot(cairo_t *cr, double x, double y, double r) {
  cairo_new_sub_path(cr);
  cairo_arc(cr, x, y, r, 0, 2 * M_PI);
  cairo_fill(cr);
}

void chart_cleanup(void) {
  cairo_debug_reset_static_data();
  FcFini();
}

static void tick_label(char *buf, size_t n, double v, bool log) {
  if (log) snprintf(buf, n, "1e%+d", (int)lround(v));
  else snprintf(buf, n, "%g", fabs(v) < 1e-12 ? 0.0 : v);
}

/* cairo's PNG writer into a FILE, keeping the first write error's errno (cairo's own file writer
 * reports a full disk as "error while writing to output stream", without the cause) */
typedef struct {
  FILE *f;
  int err; /* errno of the first failed write, 0 while all went well */
} PngSink;

static cairo_status_t png_write(void *closure, const unsigned char *data, unsigned int n) {
  PngSink *s = closure;
  if (s->err) return CAIRO_STATUS_WRITE_ERROR;
  errno = 0;
  if (fwrite(data, 1, n, s->f) != n) {
    s->err = errno ? errno : EIO;
    return CAIRO_STATUS_WRITE_ERROR;
  }
  return CAIRO_STATUS_SUCCESS;
}

/* The legend at x = lx: right of the plot, or inside its upper right corner on a light box. */
static void draw_legend(cairo_t *cr, const Chart *c, double lx, double T, double lw, const double *dash) {
  if (c->legend_inside) {
    cairo_set_source_rgba(cr, 1, 1, 1, 0.85);
    cairo_rectangle(cr, lx - 6, T + 4, lw - 14, 18.0 * c->nseries + 6), cairo_fill(cr);
  }
  for (int s = 0; s < c->nseries; s++) {
    const double *rgb = series_colour(c, s);
    double ly = T + 10 + 18.0 * s;
    if (!c->series[s].label) continue;
    cairo_set_source_rgb(cr, rgb[0], rgb[1], rgb[2]);
    cairo_set_line_width(cr, 2);
    if (series_dashed(c, s)) cairo_set_dash(cr, dash, 2, 0);
    cairo_move_to(cr, lx, ly), cairo_line_to(cr, lx + 24, ly), cairo_stroke(cr);
    cairo_set_dash(cr, NULL, 0, 0);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_move_to(cr, lx + 30, ly + 4), cairo_show_text(cr, c->series[s].label);
  }
}

int chart_png(const Chart *c, const char *path, int width, int height, char *err, size_t errlen) {
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  for (int s = 0; s < c->nseries; s++)
    for (int i = 0; i < c->series[s].n; i++) {
      double x = axis_value(c->series[s].x[i], c->logx), y = axis_value(c->series[s].y[i], c->logy);
      if (isnan(x) || isnan(y)) continue;
      x0 = fmin(x0, x), x1 = fmax(x1, x), y0 = fmin(y0, y), y1 = fmax(y1, y);
    }
  if (!(x0 <= x1)) x0 = 0, x1 = 1, y0 = 0, y1 = 1; /* nothing to draw: empty axes */
  double xpad = 0.03 * (x1 - x0);
  x0 -= xpad, x1 += xpad;
  if (x1 - x0 < 1e-12) x0 -= 0.5, x1 += 0.5;
  if (y1 - y0 < 1e-12) y0 -= 0.5, y1 += 0.5;
  if (c->logy) y0 = floor(y0), y1 = ceil(y1);
  double pad = 0.04 * (y1 - y0);
  if (!c->logy) y0 -= pad, y1 += pad;
  if (!c->logy && c->ymin < c->ymax) y0 = c->ymin, y1 = c->ymax;
  cairo_surface_t *surf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, width, height);
  cairo_t *cr = cairo_create(surf);
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, 12);
  /* plot area; the legend right of it, as wide as its labels (at most half the width) */
  double lw = fmin(legend_width(cr, c), width / 2.0);
  double L = 80, R = width - (c->legend_inside ? 20 : lw), T = 40, B = height - 55.0;
#define PX(v) (L + ((v) - x0) / (x1 - x0) * (R - L))
#define PY(v) (B - ((v) - y0) / (y1 - y0) * (B - T))
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  /* grid and ticks */
  char buf[64];
  cairo_text_extents_t te;
  double ys = tick_step(y0, y1, c->logy, false), xs = tick_step(x0, x1, c->logx, x_counts(c));
  cairo_set_line_width(cr, 1);
  for (double v = ceil(y0 / ys) * ys; v <= y1 + 1e-9 * ys; v += ys) {
    cairo_set_source_rgb(cr, 0.9, 0.9, 0.9);
    cairo_move_to(cr, L, PY(v)), cairo_line_to(cr, R, PY(v)), cairo_stroke(cr);
    tick_label(buf, sizeof buf, v, c->logy);
    cairo_text_extents(cr, buf, &te);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_move_to(cr, L - 6 - te.width, PY(v) + te.height / 2), cairo_show_text(cr, buf);
  }
  for (double v = ceil(x0 / xs) * xs; v <= x1 + 1e-9 * xs; v += xs) {
    cairo_set_source_rgb(cr, 0.9, 0.9, 0.9);
    cairo_move_to(cr, PX(v), T), cairo_line_to(cr, PX(v), B), cairo_stroke(cr);
    tick_label(buf, sizeof buf, v, c->logx);
    cairo_text_extents(cr, buf, &te);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_move_to(cr, PX(v) - te.width / 2, B + 16), cairo_show_text(cr, buf);
  }
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_rectangle(cr, L, T, R - L, B - T), cairo_stroke(cr);
  /* labels */
  cairo_text_extents(cr, c->xlabel, &te);
  cairo_move_to(cr, (L + R) / 2 - te.width / 2, B + 38), cairo_show_text(cr, c->xlabel);
  cairo_save(cr);
  cairo_text_extents(cr, c->ylabel, &te);
  cairo_move_to(cr, 20, (T + B) / 2 + te.width / 2);
  cairo_rotate(cr, -M_PI / 2);
  cairo_show_text(cr, c->ylabel);
  cairo_restore(cr);
  cairo_set_font_size(cr, 14);
  cairo_text_extents(cr, c->title, &te);
  cairo_move_to(cr, (L + R) / 2 - te.width / 2, T - 14), cairo_show_text(cr, c->title);
  cairo_set_font_size(cr, 12);
  /* curves and marks, clipped to the plot */
  const double dash[] = {6, 3};
  for (int s = 0; s < c->nseries; s++) {
    const ChartSeries *cs = &c->series[s];
    const double *rgb = series_colour(c, s);
    cairo_save(cr);
    cairo_rectangle(cr, L, T, R - L, B - T);
    cairo_clip(cr);
    cairo_set_source_rgb(cr, rgb[0], rgb[1], rgb[2]);
    cairo_set_line_width(cr, 2);
    if (series_dashed(c, s)) cairo_set_dash(cr, dash, 2, 0);
    bool pen = false;
    for (int i = 0; i < cs->n; i++) {
      double x = axis_value(cs->x[i], c->logx), y = axis_value(cs->y[i], c->logy);
      if (isnan(x) || isnan(y)) {
        pen = false;
        continue;
      }
      if (cs->points) {
        dot(cr, PX(x), PY(y), 2.5);
        continue;
      }
      if (pen) cairo_line_to(cr, PX(x), PY(y));
      else cairo_move_to(cr, PX(x), PY(y));
      pen = true;
      if (cs->n == 1) cairo_arc(cr, PX(x), PY(y), 2, 0, 2 * M_PI);
    }
    cairo_stroke(cr);
    for (int i = 0; cs->dots && i < cs->n; i++) {
      double x = axis_value(cs->x[i], c->logx), y = axis_value(cs->y[i], c->logy);
      if (!isnan(x) && !isnan(y)) dot(cr, PX(x), PY(y), 3.5);
    }
    if (cs->mark >= 0 && cs->mark < cs->n) {
      double x = axis_value(cs->x[cs->mark], c->logx), y = axis_value(cs->y[cs->mark], c->logy);
      if (!isnan(x) && !isnan(y)) dot(cr, PX(x), PY(y), 5);
    }
    cairo_restore(cr);
  }
  draw_legend(cr, c, c->legend_inside ? R - lw + 8 : R + 12, T, lw, dash);
#undef PX
#undef PY
  cairo_status_t drawn = cairo_status(cr);
  cairo_destroy(cr);
  cairo_surface_flush(surf);
  if (drawn == CAIRO_STATUS_SUCCESS) drawn = cairo_surface_status(surf);
  if (drawn != CAIRO_STATUS_SUCCESS) {
    cairo_surface_destroy(surf);
    snprintf(err, errlen, "%s: cannot draw the chart: %s", path, cairo_status_to_string(drawn));
    return -1;
  }
  /* written to a temporary name and renamed: a reader never sees half a chart */
  char tmp[4200];
  snprintf(tmp, sizeof tmp, "%s.tmp.%ld.png", path, (long)getpid());
  FILE *f = fopen(tmp, "wb");
  if (!f) {
    cairo_surface_destroy(surf);
    snprintf(err, errlen, "%s: cannot create %s: %s", path, tmp, strerror(errno));
    return -1;
  }
  PngSink sink = {f, 0};
  cairo_status_t st = cairo_surface_write_to_png_stream(surf, png_write, &sink);
  cairo_surface_destroy(surf);
  /* the buffered tail reaches the disk at fflush/fclose: a full disk shows there as often as in fwrite */
  if (fflush(f) != 0 && !sink.err) sink.err = errno ? errno : EIO;
  if (fclose(f) != 0 && !sink.err) sink.err = errno ? errno : EIO;
  if (st != CAIRO_STATUS_SUCCESS || sink.err) {
    remove(tmp);
    snprintf(err, errlen, "%s: cannot write the PNG: %s", path,
             sink.err ? strerror(sink.err) : cairo_status_to_string(st));
    return -1;
  }
  if (rename(tmp, path) != 0) {
    snprintf(err, errlen, "%s: %s", path, strerror(errno));
    remove(tmp);
    return -1;
  }
  return 0;
}
