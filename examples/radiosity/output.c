/* output.c — what every subcommand writes besides report.json (examples/common/report.h):
 * .npy arrays (through npg.h), the scene's arrays, renders, and the median of report.json (output.h). */
#include "output.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "npg.h"

/* DIR/NAME.npy from float64 data, through npg.h. */
int out_npy(const char *dir, const char *name, int nd, const long *shape, const double *data) {
  char path[4096], err[1024];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  if (npg_npy_write(path, nd, shape, data, err, sizeof err) != 0) {
    fprintf(stderr, "npg-radiosity: %s\n", err);
    return -1;
  }
  return 0;
}

/* tri as int64 (npg_npy_write_i64; the scene holds int). */
int out_scene_arrays(const char *dir, const Scene *s) {
  long st[2] = {s->F, 3}, sf[1] = {s->F};
  long *tri = malloc(sizeof(long) * 3 * (size_t)s->F);
  char path[4096], err[1024];
  if (!tri) return -1;
  for (long i = 0; i < 3 * s->F; i++) tri[i] = s->tri[i];
  snprintf(path, sizeof path, "%s/tri.npy", dir);
  int rc = npg_npy_write_i64(path, 2, st, tri, err, sizeof err);
  free(tri);
  if (rc) {
    fprintf(stderr, "npg-radiosity: %s\n", err);
    return -1;
  }
  return out_npy(dir, "rho", 1, sf, s->rho) || out_npy(dir, "e", 1, sf, s->e) ? -1 : 0;
}


double out_median(const double *x, int n) {
  double *y = malloc(sizeof(double) * (n ? n : 1));
  memcpy(y, x, sizeof(double) * n);
  for (int i = 1; i < n; i++)
    for (int j = i; j > 0 && y[j - 1] > y[j]; j--) {
      double t = y[j];
      y[j] = y[j - 1];
      y[j - 1] = t;
    }
  double m = n ? (n % 2 ? y[n / 2] : 0.5 * (y[n / 2 - 1] + y[n / 2])) : NAN;
  free(y);
  return m;
}

int out_render_compare(const Scene *s, const double *b, const double *bt, double exposure, int ss,
                       const char *const labels[3], const char *err_bar, const char *path) {
  Camera cam;
  render_camera_default(&cam);
  cam.ss = ss;
  View view;
  Image im[3] = {{0}};
  char err[512];
  if (render_view(&cam, s->V, s->F, s->g, s->tri, &view, err, sizeof err)) {
    fprintf(stderr, "npg-radiosity: %s\n", err);
    return -1;
  }
  double scale = 0.1 * -log(0.4) / exposure; /* 10 % of the bright walls' radiosity */
  render_shade(&view, s->V, s->F, s->tri, s->g, b, exposure, &im[0]);
  render_shade(&view, s->V, s->F, s->tri, s->g, bt, exposure, &im[1]);
  render_error(&view, s->F, b, bt, scale, &im[2]);
  render_view_free(&view);
  for (int q = 0; q < 2; q++) render_add_colorbar(&im[q], SCALE_SHADE, exposure, "radiosity b");
  render_add_colorbar(&im[2], SCALE_ERROR, scale, err_bar);
  const Image *ims[3] = {&im[0], &im[1], &im[2]};
  int rc = render_side_by_side(path, ims, labels, 3, err, sizeof err);
  for (int q = 0; q < 3; q++) image_free(&im[q]);
  if (rc) fprintf(stderr, "npg-radiosity: %s\n", err);
  return rc ? -1 : 0;
}

int out_render_frame(const Scene *s, const double *b, double exposure, int ss, const char *bar, const char *path,
                     View *keep) {
  Camera cam;
  render_camera_default(&cam);
  cam.ss = ss;
  View view;
  Image img = {0};
  char err[512] = "";
  if (render_view(&cam, s->V, s->F, s->g, s->tri, &view, err, sizeof err) != 0 ||
      render_shade(&view, s->V, s->F, s->tri, s->g, b, exposure, &img) != 0 ||
      render_add_colorbar(&img, SCALE_SHADE, exposure, bar) != 0 ||
      render_write_png(path, &img, err, sizeof err) != 0) {
    if (!err[0]) snprintf(err, sizeof err, "%s: out of memory", path);
    fprintf(stderr, "npg-radiosity: %s\n", err);
    render_view_free(&view);
    image_free(&img);
    return -1;
  }
  image_free(&img);
  if (keep)
    *keep = view;
  else
    render_view_free(&view);
  return 0;
}
