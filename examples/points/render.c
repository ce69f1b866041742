/* render.c — surfel splats, heat maps and plots through cairo (render.h). */
#include "render.h"

#include "chart.h"

#include <cairo.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The fixed camera: in front of the open side of the box, looking +z. */
static const double camera[3] = {0.5, 0.5, -1.35};

typedef struct Image {
  int w, h;
  float *rgb;   /* w x h x 3, linear */
  float *depth; /* w x h */
  unsigned char *covered;
} Image;

static int image_new(Image *im, int w, int h) {
  im->w = w, im->h = h;
  im->rgb = calloc((size_t)w * (size_t)h * 3, sizeof(float));
  im->depth = malloc(sizeof(float) * (size_t)w * (size_t)h);
  im->covered = calloc((size_t)w * (size_t)h, 1);
  if (!im->rgb || !im->depth || !im->covered) {
    free(im->rgb), free(im->depth), free(im->covered);
    return -1;
  }
  for (long k = 0; k < (long)w * h; k++) im->depth[k] = INFINITY;
  return 0;
}

static void image_free(Image *im) { free(im->rgb), free(im->depth), free(im->covered); }

/* Each surfel a disc of radius 1.2 √w in its plane, ray-cast per pixel of
 * its screen bounding square, nearest disc wins. */
static void splat(Image *im, const Surfels *s, const double *color /* n x 3 */) {
  double focal = 0.5 * im->w / (0.5 / -camera[2]) * 0.98;
  for (long i = 0; i < s->n; i++) {
    double c[3] = {s->x[i], s->y[i], s->z[i]}, nrm[3] = {s->nx[i], s->ny[i], s->nz[i]};
    double to_cam[3] = {camera[0] - c[0], camera[1] - c[1], camera[2] - c[2]};
    double facing = to_cam[0] * nrm[0] + to_cam[1] * nrm[1] + to_cam[2] * nrm[2];
    double depth = c[2] - camera[2];
    if (facing <= 0 || depth <= 0) continue;
    double r = 1.2 * sqrt(s->w[i]);
    double u = 0.5 * im->w + focal * (c[0] - camera[0]) / depth, v = 0.5 * im->h - focal * (c[1] - camera[1]) / depth;
    double rp = focal * r / depth + 1.5;
    int u0 = (int)floor(u - rp), u1 = (int)ceil(u + rp), v0 = (int)floor(v - rp), v1 = (int)ceil(v + rp);
    if (u0 < 0) u0 = 0;
    if (v0 < 0) v0 = 0;
    if (u1 >= im->w) u1 = im->w - 1;
    if (v1 >= im->h) v1 = im->h - 1;
    for (int py = v0; py <= v1; py++)
      for (int px = u0; px <= u1; px++) {
        double dir[3] = {(px + 0.5 - 0.5 * im->w) / focal, -(py + 0.5 - 0.5 * im->h) / focal, 1.0};
        double den = dir[0] * nrm[0] + dir[1] * nrm[1] + dir[2] * nrm[2];
        if (fabs(den) < 1e-12) continue;
        double tt = -(to_cam[0] * nrm[0] + to_cam[1] * nrm[1] + to_cam[2] * nrm[2]) / den; /* (c − cam)·n / dir·n */
        tt = ((c[0] - camera[0]) * nrm[0] + (c[1] - camera[1]) * nrm[1] + (c[2] - camera[2]) * nrm[2]) / den;
        double hit[3] = {camera[0] + tt * dir[0], camera[1] + tt * dir[1], camera[2] + tt * dir[2]};
        double e0 = hit[0] - c[0], e1 = hit[1] - c[1], e2 = hit[2] - c[2];
        if (e0 * e0 + e1 * e1 + e2 * e2 > r * r) continue;
        long k = (long)py * im->w + px;
        if (tt >= im->depth[k]) continue;
        im->depth[k] = (float)tt, im->covered[k] = 1;
        for (int ch = 0; ch < 3; ch++) im->rgb[3 * k + ch] = (float)color[3 * i + ch];
      }
  }
}

static unsigned char to_byte(double x) {
  x = x < 0 ? 0 : x > 1 ? 1 : x;
  return (unsigned char)lround(255 * x);
}

/* The image as a cairo surface: tone mapped (`exposure`, gamma 2.2) or, with
 * exposure 0, the colours taken as display values already. */
static cairo_surface_t *image_surface(const Image *im, double exposure) {
  cairo_surface_t *sf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, im->w, im->h);
  if (cairo_surface_status(sf) != CAIRO_STATUS_SUCCESS) return sf;
  cairo_surface_flush(sf);
  unsigned char *data = cairo_image_surface_get_data(sf);
  int stride = cairo_image_surface_get_stride(sf);
  for (int y = 0; y < im->h; y++)
    for (int x = 0; x < im->w; x++) {
      long k = (long)y * im->w + x;
      unsigned char px[3] = {24, 24, 28};
      if (im->covered[k])
        for (int ch = 0; ch < 3; ch++) {
          double v = im->rgb[3 * k + ch];
          px[ch] = to_byte(exposure > 0 ? pow(v * exposure, 1 / 2.2) : v);
        }
      uint32_t *dst = (uint32_t *)(data + (size_t)y * (size_t)stride) + x;
      *dst = (uint32_t)px[0] << 16 | (uint32_t)px[1] << 8 | px[2];
    }
  cairo_surface_mark_dirty(sf);
  return sf;
}

static int write_png(cairo_surface_t *sf, const char *path) {
  if (cairo_surface_write_to_png(sf, path) != CAIRO_STATUS_SUCCESS) {
    fprintf(stderr, "npg-points: cannot write %s\n", path);
    return -1;
  }
  return 0;
}

int render_radiosity(const Surfels *s, const double *b, double exposure, int width, const char *path) {
  Image im;
  if (image_new(&im, width, width)) return -1;
  splat(&im, s, b);
  cairo_surface_t *sf = image_surface(&im, exposure);
  int rc = write_png(sf, path);
  cairo_surface_destroy(sf);
  image_free(&im);
  return rc;
}

/* A perceptual-ish ramp (dark blue → magenta → orange → pale yellow). */
static void heat_color(double t, double rgb[3]) {
  static const double stops[5][3] = {{0.05, 0.03, 0.25}, {0.45, 0.10, 0.55}, {0.85, 0.25, 0.35}, {0.98, 0.60, 0.15},
                                     {0.99, 0.97, 0.70}};
  t = t < 0 ? 0 : t > 1 ? 1 : t;
  double x = t * 4;
  int k = x >= 4 ? 3 : (int)x;
  double f = x - k;
  for (int ch = 0; ch < 3; ch++) rgb[ch] = stops[k][ch] * (1 - f) + stops[k + 1][ch] * f;
}

static void draw_text(cairo_t *cr, double x, double y, double size, const char *text) {
  cairo_set_font_size(cr, size);
  cairo_move_to(cr, x, y);
  cairo_show_text(cr, text);
}

int render_comparison(const Surfels *s, const double *b_fmm, const double *b_dense, double exposure, int width,
                      const char *path, const char *title_a, const char *title_b) {
  long n = s->n;
  double bmax = 0, dmax = 0;
  for (long k = 0; k < 3 * n; k++) bmax = fmax(bmax, fabs(b_dense[k]));
  double *heat = malloc(sizeof(double) * 3 * (size_t)n);
  if (!heat) return -1;
  /* log10 of the relative difference, from 1e-7 to 1e-1 */
  const double lo = -7, hi = -1;
  for (long i = 0; i < n; i++) {
    double d = 0;
    for (int ch = 0; ch < 3; ch++) d = fmax(d, fabs(b_fmm[3 * i + ch] - b_dense[3 * i + ch]));
    d /= bmax;
    dmax = fmax(dmax, d);
    double t = ((d > 0 ? log10(d) : lo) - lo) / (hi - lo), rgb[3];
    heat_color(t, rgb);
    for (int ch = 0; ch < 3; ch++) heat[3 * i + ch] = 255 * rgb[ch] / 255.0;
  }
  Image im[3];
  int ok = 1;
  for (int k = 0; k < 3; k++) ok &= image_new(&im[k], width, width) == 0;
  if (!ok) {
    free(heat);
    return -1;
  }
  splat(&im[0], s, b_fmm);
  splat(&im[1], s, b_dense);
  splat(&im[2], s, heat);
  int margin = 40, bar = 70;
  cairo_surface_t *out = cairo_image_surface_create(CAIRO_FORMAT_RGB24, 3 * width + bar, width + margin + 24);
  cairo_t *cr = cairo_create(out);
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  char diff_title[160];
  snprintf(diff_title, sizeof diff_title, "|difference| / max b (right)");
  const char *titles[3] = {title_a, title_b, diff_title};
  for (int k = 0; k < 3; k++) {
    cairo_surface_t *sf = image_surface(&im[k], k < 2 ? exposure : 0);
    cairo_set_source_surface(cr, sf, k * width, margin);
    cairo_paint(cr);
    cairo_surface_destroy(sf);
    cairo_set_source_rgb(cr, 0, 0, 0);
    cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
    draw_text(cr, k * width + 10, 26, 18, titles[k]);
  }
  /* colour bar of the heat map, in decades */
  int bx = 3 * width + 12, by = margin + 10, bh = width - 20;
  for (int y = 0; y < bh; y++) {
    double rgb[3];
    heat_color(1 - (double)y / (bh - 1), rgb);
    cairo_set_source_rgb(cr, rgb[0], rgb[1], rgb[2]);
    cairo_rectangle(cr, bx, by + y, 14, 1);
    cairo_fill(cr);
  }
  cairo_set_source_rgb(cr, 0, 0, 0);
  for (int e = (int)lo; e <= (int)hi; e++) {
    char lab[16];
    snprintf(lab, sizeof lab, "1e%d", e);
    double y = by + (hi - e) / (hi - lo) * (bh - 1);
    draw_text(cr, bx + 18, y + 4, 11, lab);
  }
  char foot[128];
  snprintf(foot, sizeof foot, "N = %ld surfels; largest difference %.2e of max b", n, dmax);
  draw_text(cr, 10, width + margin + 17, 14, foot);
  cairo_destroy(cr);
  int rc = write_png(out, path);
  cairo_surface_destroy(out);
  for (int k = 0; k < 3; k++) image_free(&im[k]);
  free(heat);
  return rc;
}

/* ------------------------------------------------------------ plots */

int render_plot(const char *path, const char *title, const char *xlabel, const char *ylabel, int logx,
                const PlotSeries *series, int nseries) {
  ChartSeries cs[16];
  if (nseries > 16) nseries = 16;
  for (int k = 0; k < nseries; k++)
    cs[k] = (ChartSeries){series[k].label, series[k].n, series[k].x, series[k].y, -1, false, true};
  static const double palette[6][3] = {{0.12, 0.35, 0.75}, {0.85, 0.33, 0.10}, {0.15, 0.60, 0.25},
                                       {0.55, 0.25, 0.65}, {0.80, 0.65, 0.10}, {0.30, 0.30, 0.30}};
  Chart c = {.title = title, .xlabel = xlabel, .ylabel = ylabel, .logx = logx != 0, .logy = true, .nseries = nseries,
             .series = cs, .legend_inside = true, .palette = palette, .npalette = 6};
  char err[512];
  if (chart_png(&c, path, 720, 480, err, sizeof err) != 0) {
    fprintf(stderr, "npg-points: %s\n", err);
    return -1;
  }
  return 0;
}
