/* render.c — cutaway renders, error maps and composites (render.h). */
#include "util.h"
#include "render.h"
#include "npg.h"

#include <cairo.h>
#include <embree3/rtcore.h>
#include <errno.h>
#include <math.h>
#include <png.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

void render_camera_default(Camera *c) {
  *c = (Camera){.eye = {2.6, -6.2, 7.6}, .at = {5.3, 2.2, 0.5}, .up = {0, 0, 1}, .fov_deg = 46,
                .width = 840, .height = 430, .ss = 3};
}

static void cross3(const double *a, const double *b, double *c) {
  c[0] = a[1] * b[2] - a[2] * b[1];
  c[1] = a[2] * b[0] - a[0] * b[2];
  c[2] = a[0] * b[1] - a[1] * b[0];
}

static void normalize3(double *a) {
  double l = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  for (int d = 0; d < 3; d++) a[d] /= l;
}

/* Primary rays for subpixel rows t, t + nt, ... of the view (two threads share the scene,
 * which Embree allows for queries). */
typedef struct CastJob {
  const Camera *cam;
  RTCScene scene;
  const int *map;
  long nf;
  View *view;
  int W, H, t, nt;
} CastJob;

static void *cast_rows(void *arg) {
  const CastJob *job = arg;
  const Camera *cam = job->cam;
  int W = job->W, H = job->H;
  double fw[3], rt[3], up[3];
  for (int d = 0; d < 3; d++) fw[d] = cam->at[d] - cam->eye[d];
  normalize3(fw);
  cross3(fw, cam->up, rt);
  normalize3(rt);
  cross3(rt, fw, up);
  double th = tan(cam->fov_deg * M_PI / 360.0), tw = th * (double)W / H;
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  for (int y = job->t; y < H; y += job->nt)
    for (int x = 0; x < W; x++) {
      double sx = (2 * (x + 0.5) / W - 1) * tw, sy = (1 - 2 * (y + 0.5) / H) * th;
      struct RTCRayHit rh;
      rh.ray.org_x = (float)cam->eye[0];
      rh.ray.org_y = (float)cam->eye[1];
      rh.ray.org_z = (float)cam->eye[2];
      rh.ray.dir_x = (float)(fw[0] + sx * rt[0] + sy * up[0]);
      rh.ray.dir_y = (float)(fw[1] + sx * rt[1] + sy * up[1]);
      rh.ray.dir_z = (float)(fw[2] + sx * rt[2] + sy * up[2]);
      rh.ray.tnear = 0;
      rh.ray.tfar = INFINITY;
      rh.ray.time = 0;
      rh.ray.mask = 0xFFFFFFFFu;
      rh.ray.id = 0;
      rh.ray.flags = 0;
      rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
      rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
      rtcIntersect1(job->scene, &ctx, &rh);
      size_t at = (size_t)y * W + x;
      int hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID && job->nf;
      job->view->face[at] = hit ? job->map[rh.hit.primID] : -1;
      job->view->u[at] = hit ? rh.hit.u : 0;
      job->view->v[at] = hit ? rh.hit.v : 0;
    }
  return NULL;
}

int render_view(const Camera *cam, long V, long F, const double *g, const int *tri, View *view, char *err,
                size_t errlen) {
  memset(view, 0, sizeof *view);
  RTCDevice dev = rtcNewDevice("threads=1");
  if (!dev) return npg_error_set(err, errlen, "embree: cannot create a device");
  RTCScene scene = rtcNewScene(dev);
  RTCGeometry geom = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  /* only the faces whose front is towards the eye (a plane's side is the same for every
   * point of a perspective view) */
  long nf = 0;
  int *map = malloc(sizeof(int) * (F ? F : 1));
  for (long f = 0; f < F; f++) {
    const double *a = g + 3 * tri[3 * f], *b = g + 3 * tri[3 * f + 1], *c = g + 3 * tri[3 * f + 2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]}, n[3];
    cross3(u, w, n);
    double toeye = n[0] * (cam->eye[0] - a[0]) + n[1] * (cam->eye[1] - a[1]) + n[2] * (cam->eye[2] - a[2]);
    if (toeye > 0) map[nf++] = (int)f;
  }
  float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), V);
  unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                         nf ? nf : 1);
  for (long a = 0; a < 3 * V; a++) vb[a] = (float)g[a];
  for (long k = 0; k < nf; k++)
    for (int q = 0; q < 3; q++) ib[3 * k + q] = (unsigned)tri[3 * map[k] + q];
  if (!nf) ib[0] = ib[1] = ib[2] = 0;
  rtcCommitGeometry(geom);
  rtcAttachGeometry(scene, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(scene);

  int W = cam->width * cam->ss, H = cam->height * cam->ss;
  view->width = cam->width;
  view->height = cam->height;
  view->ss = cam->ss;
  view->face = malloc(sizeof(int) * (size_t)W * H);
  view->u = malloc(sizeof(float) * (size_t)W * H);
  view->v = malloc(sizeof(float) * (size_t)W * H);
  if (!view->face || !view->u || !view->v) {
    rtcReleaseScene(scene);
    rtcReleaseDevice(dev);
    free(map);
    render_view_free(view);
    return npg_error_set(err, errlen, "render: out of memory");
  }
  CastJob job[2];
  pthread_t th;
  for (int t = 0; t < 2; t++) job[t] = (CastJob){cam, scene, map, nf, view, W, H, t, 2};
  int threaded = pthread_create(&th, NULL, cast_rows, &job[1]) == 0;
  cast_rows(&job[0]);
  if (threaded)
    pthread_join(th, NULL);
  else
    cast_rows(&job[1]);
  rtcReleaseScene(scene);
  rtcReleaseDevice(dev);
  free(map);
  return 0;
}

void render_view_free(View *view) {
  free(view->face);
  free(view->u);
  free(view->v);
  memset(view, 0, sizeof *view);
}

void image_free(Image *img) {
  free(img->rgb);
  memset(img, 0, sizeof *img);
}

static unsigned char srgb(double x) {
  x = x < 0 ? 0 : x > 1 ? 1 : x;
  double s = x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1 / 2.4) - 0.055;
  return (unsigned char)lround(255 * s);
}

static const double background[3] = {0.018, 0.022, 0.03};

/* render_shade's tone l in [0, 1] as linear light: a warm white, for daylight on plaster */
static void shade_color(double l, float *rgb) {
  static const double tint[3] = {1.0, 0.97, 0.92};
  for (int d = 0; d < 3; d++) rgb[d] = (float)(l * tint[d]);
}


/* Average the subpixels of pixel (x, y) of per-subpixel linear colours. */
static void resolve(const View *view, const float *lin, Image *img) {
  int ss = view->ss, W = view->width * ss;
  for (int y = 0; y < view->height; y++)
    for (int x = 0; x < view->width; x++) {
      double acc[3] = {0, 0, 0};
      for (int j = 0; j < ss; j++)
        for (int i = 0; i < ss; i++) {
          size_t at = (size_t)(y * ss + j) * W + (x * ss + i);
          for (int d = 0; d < 3; d++) acc[d] += lin[3 * at + d];
        }
      for (int d = 0; d < 3; d++) img->rgb[3 * ((size_t)y * view->width + x) + d] = srgb(acc[d] / (ss * ss));
    }
}

int render_shade(const View *view, long V, long F, const int *tri, const double *g, const double *b, double exposure,
                 Image *img) {
  /* vertex radiosity: area-weighted mean of the faces around the vertex (vertices are per
   * patch, so walls, openings and furniture never blend into each other) */
  double *vb = calloc(V ? V : 1, sizeof(double)), *vw = calloc(V ? V : 1, sizeof(double));
  for (long f = 0; f < F; f++) {
    const double *a = g + 3 * tri[3 * f], *p = g + 3 * tri[3 * f + 1], *c = g + 3 * tri[3 * f + 2];
    double u[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]}, n[3];
    cross3(u, w, n);
    double area = 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int q = 0; q < 3; q++) {
      vb[tri[3 * f + q]] += area * b[f];
      vw[tri[3 * f + q]] += area;
    }
  }
  for (long a = 0; a < V; a++) vb[a] = vw[a] > 0 ? vb[a] / vw[a] : 0;
  int W = view->width * view->ss, H = view->height * view->ss;
  float *lin = malloc(sizeof(float) * 3 * (size_t)W * H);
  img->width = view->width;
  img->height = view->height;
  img->rgb = malloc(3 * (size_t)view->width * view->height);
  if (!lin || !img->rgb) {
    free(vb), free(vw), free(lin);
    image_free(img);
    return -1;
  }
  for (size_t at = 0; at < (size_t)W * H; at++) {
    int f = view->face[at];
    if (f < 0) {
      for (int d = 0; d < 3; d++) lin[3 * at + d] = (float)background[d];
      continue;
    }
    double u = view->u[at], v = view->v[at];
    double x = (1 - u - v) * vb[tri[3 * f]] + u * vb[tri[3 * f + 1]] + v * vb[tri[3 * f + 2]];
    shade_color(1 - exp(-exposure * fmax(x, 0)), lin + 3 * at);
  }
  resolve(view, lin, img);
  free(lin);
  free(vb);
  free(vw);
  return 0;
}

/* black -> red -> yellow -> white at 0, 1/3, 2/3, 1 */
static void heat(double t, float *rgb) {
  t = t < 0 ? 0 : t > 1 ? 1 : t;
  double r = fmin(1, 3 * t), g = fmin(1, fmax(0, 3 * t - 1)), b = fmax(0, 3 * t - 2);
  rgb[0] = (float)(r * r), rgb[1] = (float)(g * g), rgb[2] = (float)(b * b); /* linear light */
}

int render_error(const View *view, long F, const double *b_ref, const double *b, double scale, Image *img) {
  int W = view->width * view->ss, H = view->height * view->ss;
  float *lin = malloc(sizeof(float) * 3 * (size_t)W * H);
  img->width = view->width;
  img->height = view->height;
  img->rgb = malloc(3 * (size_t)view->width * view->height);
  if (!lin || !img->rgb) {
    free(lin);
    image_free(img);
    return -1;
  }
  for (size_t at = 0; at < (size_t)W * H; at++) {
    int f = view->face[at];
    if (f < 0 || f >= F) {
      for (int d = 0; d < 3; d++) lin[3 * at + d] = (float)background[d];
      continue;
    }
    heat(fabs(b[f] - b_ref[f]) / scale, lin + 3 * at);
  }
  resolve(view, lin, img);
  free(lin);
  return 0;
}

/* ---------------------------------------------------------------- colour bars */


int render_add_colorbar(Image *img, ColorScale scale, double param, const char *label) {
  const int strip = 50, bh = 12, margin = 14;
  int W = img->width, H = img->height + strip, bw = W - 2 * margin;
  if (bw < 16) return 0; /* too narrow for a bar */
  /* the value at the bar's right end: white for the error; 95 % of white for the tone */
  double vmax = scale == SCALE_ERROR ? param : -log(0.05) / param;
  cairo_surface_t *surf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, W, strip);
  cairo_t *cr = cairo_create(surf);
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  cairo_surface_flush(surf);
  unsigned char *data = cairo_image_surface_get_data(surf);
  int stride = cairo_image_surface_get_stride(surf);
  for (int x = 0; x < bw; x++) {
    double v = vmax * x / (bw - 1);
    float lin[3];
    if (scale == SCALE_ERROR) heat(v / param, lin);
    else shade_color(1 - exp(-param * v), lin);
    uint32_t px = (uint32_t)srgb(lin[0]) << 16 | (uint32_t)srgb(lin[1]) << 8 | srgb(lin[2]);
    for (int y = 4; y < 4 + bh; y++) ((uint32_t *)(data + (size_t)y * stride))[margin + x] = px;
  }
  cairo_surface_mark_dirty(surf);
  cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
  cairo_set_line_width(cr, 1);
  cairo_rectangle(cr, margin - 0.5, 3.5, bw + 1, bh + 1);
  cairo_stroke(cr);
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, 11);
  double step = util_tick_step(vmax, 4);
  cairo_text_extents_t ext;
  char text[64];
  for (double v = 0; v <= vmax * (1 + 1e-9); v += step) {
    double x = margin + (bw - 1) * v / vmax;
    cairo_move_to(cr, round(x) + 0.5, 4 + bh), cairo_line_to(cr, round(x) + 0.5, 8 + bh), cairo_stroke(cr);
    snprintf(text, sizeof text, "%g", v);
    cairo_text_extents(cr, text, &ext);
    double tx = fmin(fmax(x - ext.x_advance / 2, 0), W - ext.x_advance);
    cairo_move_to(cr, tx, 19 + bh), cairo_show_text(cr, text);
  }
  cairo_text_extents(cr, label ? label : "", &ext);
  cairo_move_to(cr, W / 2.0 - ext.x_advance / 2, strip - 4), cairo_show_text(cr, label ? label : "");
  cairo_destroy(cr);
  cairo_surface_flush(surf);
  unsigned char *rgb = realloc(img->rgb, 3 * (size_t)W * H);
  if (!rgb) {
    cairo_surface_destroy(surf);
    return -1;
  }
  for (int y = 0; y < strip; y++)
    for (int x = 0; x < W; x++) {
      uint32_t px = ((const uint32_t *)(data + (size_t)y * stride))[x];
      unsigned char *q = rgb + 3 * ((size_t)(img->height + y) * W + x);
      q[0] = (unsigned char)(px >> 16), q[1] = (unsigned char)(px >> 8), q[2] = (unsigned char)px;
    }
  cairo_surface_destroy(surf);
  img->rgb = rgb, img->height = H;
  return 0;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

double render_exposure(long F, const double *b, const double *rho) {
  double *x = malloc(sizeof(double) * (F ? F : 1));
  long n = 0;
  for (long f = 0; f < F; f++)
    if (rho[f] > 0) x[n++] = b[f];
  double hi = 0;
  if (n) {
    qsort(x, n, sizeof(double), cmp_double);
    hi = x[(long)(0.9 * (n - 1))];
  }
  free(x);
  return hi > 0 ? -log(0.4) / hi : 1.0;
}

/* ---------------------------------------------------------------- PNG through libpng */

int render_write_png(const char *path, const Image *img, char *err, size_t errlen) {
  char tmp[4096];
  snprintf(tmp, sizeof tmp, "%s.tmp.%ld", path, (long)getpid());
  FILE *fp = fopen(tmp, "wb");
  if (!fp) return npg_error_set(err, errlen, "%s: %s", path, strerror(errno));
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
  png_infop info = png ? png_create_info_struct(png) : NULL;
  png_bytep *rows = malloc(sizeof(png_bytep) * (size_t)img->height);
  if (!png || !info || !rows) {
    png_destroy_write_struct(&png, &info);
    free(rows);
    fclose(fp);
    remove(tmp);
    return npg_error_set(err, errlen, "%s: libpng: out of memory", path);
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    free(rows);
    fclose(fp);
    remove(tmp);
    return npg_error_set(err, errlen, "%s: libpng failed to write", path);
  }
  png_init_io(png, fp);
  png_set_IHDR(png, info, (png_uint_32)img->width, (png_uint_32)img->height, 8, PNG_COLOR_TYPE_RGB,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_set_sRGB_gAMA_and_cHRM(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
  for (int y = 0; y < img->height; y++) rows[y] = img->rgb + 3 * (size_t)y * img->width;
  png_write_info(png, info);
  png_write_image(png, rows);
  png_write_end(png, NULL);
  png_destroy_write_struct(&png, &info);
  free(rows);
  if (fclose(fp) != 0) {
    remove(tmp);
    return npg_error_set(err, errlen, "%s: %s", path, strerror(errno));
  }
  if (rename(tmp, path) != 0) {
    remove(tmp);
    return npg_error_set(err, errlen, "%s: %s", path, strerror(errno));
  }
  return 0;
}

/* ---------------------------------------------------------------- composites (cairo layout) */

int render_side_by_side(const char *path, const Image *const *imgs, const char *const *labels, int n, char *err,
                        size_t errlen) {
  const int gap = 8, bar = 26;
  int W = gap, H = 0;
  for (int k = 0; k < n; k++) {
    W += imgs[k]->width + gap;
    if (imgs[k]->height > H) H = imgs[k]->height;
  }
  H += bar + gap;
  cairo_surface_t *surf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, W, H);
  cairo_t *cr = cairo_create(surf);
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  int x = gap;
  for (int k = 0; k < n; k++) {
    const Image *im = imgs[k];
    cairo_surface_t *s = cairo_image_surface_create(CAIRO_FORMAT_RGB24, im->width, im->height);
    cairo_surface_flush(s);
    unsigned char *data = cairo_image_surface_get_data(s);
    int stride = cairo_image_surface_get_stride(s);
    for (int y = 0; y < im->height; y++)
      for (int i = 0; i < im->width; i++) {
        const unsigned char *p = im->rgb + 3 * ((size_t)y * im->width + i);
        ((uint32_t *)(data + (size_t)y * stride))[i] = (uint32_t)p[0] << 16 | (uint32_t)p[1] << 8 | p[2];
      }
    cairo_surface_mark_dirty(s);
    cairo_set_source_surface(cr, s, x, bar);
    cairo_paint(cr);
    cairo_surface_destroy(s);
    cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
    cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
    cairo_set_font_size(cr, 15);
    cairo_move_to(cr, x + 2, bar - 8);
    cairo_show_text(cr, labels && labels[k] ? labels[k] : "");
    x += im->width + gap;
  }
  cairo_destroy(cr);
  cairo_surface_flush(surf);
  Image out = {W, H, malloc(3 * (size_t)W * H)};
  unsigned char *data = cairo_image_surface_get_data(surf);
  int stride = cairo_image_surface_get_stride(surf);
  for (int y = 0; y < H; y++)
    for (int i = 0; i < W; i++) {
      uint32_t px = ((const uint32_t *)(data + (size_t)y * stride))[i];
      unsigned char *q = out.rgb + 3 * ((size_t)y * W + i);
      q[0] = (unsigned char)(px >> 16), q[1] = (unsigned char)(px >> 8), q[2] = (unsigned char)px;
    }
  cairo_surface_destroy(surf);
  int rc = render_write_png(path, &out, err, errlen);
  image_free(&out);
  return rc;
}
