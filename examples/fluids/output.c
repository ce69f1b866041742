/* output.c — PNG frames and VTK files (see output.h). */
#include "util.h"
#include "output.h"
#include "plot.h"
#include "npg.h"

#include <errno.h>
#include <math.h>
#include <png.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------- PNG */

/* Piecewise-linear colour map from dark blue through teal to yellow. */
static void colormap(double t, unsigned char rgb[3]) {
  static const double stop[5][3] = {
      {0.05, 0.03, 0.25}, {0.23, 0.20, 0.62}, {0.13, 0.55, 0.56}, {0.52, 0.80, 0.28}, {0.99, 0.91, 0.15}};
  t = t < 0 ? 0 : t > 1 ? 1 : t;
  double s = t * 4;
  int i = s >= 4 ? 3 : (int)s;
  double w = s - i;
  for (int d = 0; d < 3; d++) rgb[d] = (unsigned char)lround(255 * ((1 - w) * stop[i][d] + w * stop[i + 1][d]));
}

static int write_png(const char *path, int w, int h, unsigned char *rgb, char *err, size_t errlen) {
  char tmp[4096];
  snprintf(tmp, sizeof tmp, "%s.tmp", path);
  FILE *fp = fopen(tmp, "wb");
  if (!fp) return npg_error_set(err, errlen, "%s: %s", tmp, strerror(errno));
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
  png_infop info = png ? png_create_info_struct(png) : NULL;
  png_bytep *rows = malloc(h * sizeof *rows);
  if (!png || !info || !rows || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    fclose(fp);
    free(rows);
    remove(tmp);
    return npg_error_set(err, errlen, "%s: libpng could not write the image", path);
  }
  png_init_io(png, fp);
  png_set_IHDR(png, info, w, h, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  for (int y = 0; y < h; y++) rows[y] = rgb + 3 * (size_t)w * y;
  png_set_rows(png, info, rows);
  png_write_png(png, info, PNG_TRANSFORM_IDENTITY, NULL);
  png_destroy_write_struct(&png, &info);
  free(rows);
  if (fclose(fp) != 0 || rename(tmp, path) != 0) {
    remove(tmp);
    return npg_error_set(err, errlen, "%s: %s", path, strerror(errno));
  }
  return 0;
}

int output_png(const char *path, const FluidMesh *m, const double *g, const double *u, const Particles *p, double vmax,
               int width, char *err, size_t errlen) {
  double ymin = INFINITY, ymax = -INFINITY;
  for (int v = 0; v < m->nv; v++) ymin = fmin(ymin, g[2 * v + 1]), ymax = fmax(ymax, g[2 * v + 1]);
  double scale = width / m->spec.L;
  int height = (int)ceil((ymax - ymin) * scale);
  if (height < 1) height = 1;
  /* the flow, then a colour bar of |u| under it */
  unsigned char *img = malloc(3 * (size_t)width * (height + PLOT_COLORBAR_HEIGHT));
  if (!img) return npg_error_set(err, errlen, "%s: out of memory for a %d x %d picture", path, width, height);
  memset(img, 96, 3 * (size_t)width * height);
  for (int c = 0; c < m->nc; c++) {
    const int *t = m->cell + 3 * c;
    double px[3], py[3]; /* pixel coordinates, y down */
    for (int k = 0; k < 3; k++) px[k] = g[2 * t[k]] * scale, py[k] = (ymax - g[2 * t[k] + 1]) * scale;
    unsigned char rgb[3];
    colormap(hypot(u[2 * c], u[2 * c + 1]) / vmax, rgb);
    int x0 = (int)floor(fmin(px[0], fmin(px[1], px[2]))), x1 = (int)ceil(fmax(px[0], fmax(px[1], px[2])));
    int y0 = (int)floor(fmin(py[0], fmin(py[1], py[2]))), y1 = (int)ceil(fmax(py[0], fmax(py[1], py[2])));
    double area2 = (px[1] - px[0]) * (py[2] - py[0]) - (py[1] - py[0]) * (px[2] - px[0]);
    for (int y = y0 < 0 ? 0 : y0; y <= y1 && y < height; y++)
      for (int x = x0 < 0 ? 0 : x0; x <= x1 && x < width; x++) {
        double cx = x + 0.5, cy = y + 0.5, inside = 1;
        for (int k = 0; k < 3 && inside; k++) {
          int a = (k + 1) % 3, b = (k + 2) % 3;
          double e = ((px[a] - cx) * (py[b] - cy) - (py[a] - cy) * (px[b] - cx)) / area2;
          if (e < -1e-9) inside = 0;
        }
        if (inside) memcpy(img + 3 * ((size_t)y * width + x), rgb, 3);
      }
  }
  if (p)
    for (int i = 0; i < p->n; i++) {
      int x = (int)(p->x[2 * i] * scale), y = (int)((ymax - p->x[2 * i + 1]) * scale);
      static const unsigned char col[2][3] = {{255, 255, 255}, {255, 120, 40}};
      for (int dy = 0; dy < 2; dy++)
        for (int dx = 0; dx < 2; dx++) {
          int xx = x + dx, yy = y + dy;
          if (xx >= 0 && xx < width && yy >= 0 && yy < height)
            memcpy(img + 3 * ((size_t)yy * width + xx), col[p->tag[i] & 1], 3);
        }
    }
  if (plot_colorbar(img, width, height, colormap, vmax, "|u|, cell velocity (obstacle grey)") != 0) {
    free(img);
    return npg_error_set(err, errlen, "%s: out of memory", path);
  }
  int rc = write_png(path, width, height + PLOT_COLORBAR_HEIGHT, img, err, errlen);
  free(img);
  return rc;
}

/* ---------------------------------------------------------------- VTK */

static FILE *open_tmp(const char *path, char *tmp, size_t n, char *err, size_t errlen) {
  snprintf(tmp, n, "%s.tmp", path);
  FILE *fp = fopen(tmp, "w");
  if (!fp) npg_error_set(err, errlen, "%s: %s", tmp, strerror(errno));
  return fp;
}

static int close_rename(FILE *fp, const char *tmp, const char *path, char *err, size_t errlen) {
  if (ferror(fp) | (fclose(fp) != 0) || rename(tmp, path) != 0) {
    remove(tmp);
    return npg_error_set(err, errlen, "%s: %s", path, strerror(errno));
  }
  return 0;
}

static void vtu_points(FILE *fp, const FluidMesh *m, const double *g) {
  fprintf(fp, "<Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
  for (int v = 0; v < m->nv; v++) fprintf(fp, "%.17g %.17g 0\n", g[2 * v], g[2 * v + 1]);
  fprintf(fp, "</DataArray></Points>\n");
}

static void vtu_cells(FILE *fp, int n, int nper, const int *conn, int type) {
  fprintf(fp, "<Cells><DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n");
  for (int i = 0; i < n; i++) {
    for (int k = 0; k < nper; k++) fprintf(fp, "%d ", conn[nper * i + k]);
    fputc('\n', fp);
  }
  fprintf(fp, "</DataArray><DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n");
  for (int i = 0; i < n; i++) fprintf(fp, "%d\n", nper * (i + 1));
  fprintf(fp, "</DataArray><DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
  for (int i = 0; i < n; i++) fprintf(fp, "%d\n", type);
  fprintf(fp, "</DataArray></Cells>\n");
}

static const char *vtu_head = "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" "
                              "byte_order=\"LittleEndian\">\n<UnstructuredGrid>\n";

int output_vtu_cells(const char *path, const FluidMesh *m, const double *g, const double *u, char *err, size_t errlen) {
  char tmp[4096];
  FILE *fp = open_tmp(path, tmp, sizeof tmp, err, errlen);
  if (!fp) return -1;
  fprintf(fp, "%s<Piece NumberOfPoints=\"%d\" NumberOfCells=\"%d\">\n", vtu_head, m->nv, m->nc);
  vtu_points(fp, m, g);
  vtu_cells(fp, m->nc, 3, m->cell, 5);
  fprintf(fp, "<CellData Vectors=\"velocity\" Scalars=\"speed\">\n");
  fprintf(fp, "<DataArray type=\"Float64\" Name=\"velocity\" NumberOfComponents=\"3\" format=\"ascii\">\n");
  for (int c = 0; c < m->nc; c++) fprintf(fp, "%.17g %.17g 0\n", u[2 * c], u[2 * c + 1]);
  fprintf(fp, "</DataArray>\n<DataArray type=\"Float64\" Name=\"speed\" format=\"ascii\">\n");
  for (int c = 0; c < m->nc; c++) fprintf(fp, "%.17g\n", hypot(u[2 * c], u[2 * c + 1]));
  fprintf(fp, "</DataArray>\n<DataArray type=\"Float64\" Name=\"area\" format=\"ascii\">\n");
  for (int c = 0; c < m->nc; c++) fprintf(fp, "%.17g\n", mesh_volume(m, g, c));
  fprintf(fp, "</DataArray>\n</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
  return close_rename(fp, tmp, path, err, errlen);
}

int output_vtu_faces(const char *path, const FluidMesh *m, const double *g, const double *f, const double *h, char *err,
                     size_t errlen) {
  char tmp[4096];
  FILE *fp = open_tmp(path, tmp, sizeof tmp, err, errlen);
  if (!fp) return -1;
  fprintf(fp, "%s<Piece NumberOfPoints=\"%d\" NumberOfCells=\"%d\">\n", vtu_head, m->nv, m->nf);
  vtu_points(fp, m, g);
  vtu_cells(fp, m->nf, 2, m->face, 3);
  fprintf(fp, "<CellData Scalars=\"flux\">\n<DataArray type=\"Float64\" Name=\"flux\" format=\"ascii\">\n");
  for (int j = 0; j < m->nf; j++) fprintf(fp, "%.17g\n", f[j]);
  fprintf(fp, "</DataArray>\n<DataArray type=\"Float64\" Name=\"induced_flux\" format=\"ascii\">\n");
  for (int j = 0; j < m->nf; j++) fprintf(fp, "%.17g\n", h[j]);
  fprintf(fp, "</DataArray>\n<DataArray type=\"Int32\" Name=\"kind\" format=\"ascii\">\n");
  for (int j = 0; j < m->nf; j++) fprintf(fp, "%d\n", m->fkind[j]);
  fprintf(fp, "</DataArray>\n</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
  return close_rename(fp, tmp, path, err, errlen);
}

int output_pvd(const char *path, int n, const char *const *files, const double *times, char *err, size_t errlen) {
  char tmp[4096];
  FILE *fp = open_tmp(path, tmp, sizeof tmp, err, errlen);
  if (!fp) return -1;
  fprintf(fp, "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n<Collection>\n");
  for (int i = 0; i < n; i++)
    fprintf(fp, "<DataSet timestep=\"%.17g\" part=\"0\" file=\"%s\"/>\n", times[i], files[i]);
  fprintf(fp, "</Collection>\n</VTKFile>\n");
  return close_rename(fp, tmp, path, err, errlen);
}

/* ---------------------------------------------------------------- 3D */

int output_vtk_tets(const char *path, const FluidMesh *m, const double *g, const double *u, char *err, size_t errlen) {
  char tmp[4096];
  FILE *fp = open_tmp(path, tmp, sizeof tmp, err, errlen);
  if (!fp) return -1;
  fprintf(fp, "# vtk DataFile Version 3.0\nnpg-fluids cavity\nASCII\nDATASET UNSTRUCTURED_GRID\n");
  fprintf(fp, "POINTS %d double\n", m->nv);
  for (int v = 0; v < m->nv; v++) fprintf(fp, "%.9g %.9g %.9g\n", g[3 * v], g[3 * v + 1], g[3 * v + 2]);
  fprintf(fp, "CELLS %d %d\n", m->nc, 5 * m->nc);
  for (int c = 0; c < m->nc; c++) {
    const int *t = m->cell + 4 * c;
    fprintf(fp, "4 %d %d %d %d\n", t[0], t[1], t[2], t[3]);
  }
  fprintf(fp, "CELL_TYPES %d\n", m->nc);
  for (int c = 0; c < m->nc; c++) fputs("10\n", fp);
  fprintf(fp, "CELL_DATA %d\nVECTORS velocity double\n", m->nc);
  for (int c = 0; c < m->nc; c++) fprintf(fp, "%.9g %.9g %.9g\n", u[3 * c], u[3 * c + 1], u[3 * c + 2]);
  fprintf(fp, "SCALARS speed double 1\nLOOKUP_TABLE default\n");
  for (int c = 0; c < m->nc; c++)
    fprintf(fp, "%.9g\n", sqrt(u[3 * c] * u[3 * c] + u[3 * c + 1] * u[3 * c + 1] + u[3 * c + 2] * u[3 * c + 2]));
  return close_rename(fp, tmp, path, err, errlen);
}

/* The camera of output_png_points: looking at the origin from direction
 * (0, -cos e, sin e) (elevation e = 55 degrees), perspective from distance
 * `dist`, `fov` the half-width of the view at the origin. */
static void camera(const double x[3], double dist, double *sx, double *sy, double *depth) {
  const double ce = cos(55 * M_PI / 180), se = sin(55 * M_PI / 180);
  /* right = (1, 0, 0); up = (0, se, ce); forward (into the scene) = (0, ce, -se) */
  double xr = x[0], xu = se * x[1] + ce * x[2], xf = ce * x[1] - se * x[2];
  double z = dist + xf;
  *sx = xr * dist / z, *sy = xu * dist / z, *depth = z;
}

int output_png_points(const char *path, const FluidMesh *m, const double *g, const Particles *p, double extent, int width,
                      char *err, size_t errlen) {
  int w = width, h = width * 3 / 4;
  unsigned char *rgb = malloc(3 * (size_t)w * h);
  float *zbuf = malloc((size_t)w * h * sizeof *zbuf);
  for (size_t i = 0; i < (size_t)w * h; i++) {
    rgb[3 * i] = 12, rgb[3 * i + 1] = 14, rgb[3 * i + 2] = 24;
    zbuf[i] = INFINITY;
  }
  double dist = 4 * extent, scale = 0.5 * w / (1.05 * extent);
  /* the walls: the boundary faces' vertices as faint grey dots */
  for (int b = 0; b < m->nb; b++) {
    const int *t = m->face + 3 * m->bface[b];
    for (int k = 0; k < 3; k++) {
      double sx, sy, z;
      camera(g + 3 * t[k], dist, &sx, &sy, &z);
      int px = (int)lround(w / 2 + sx * scale), py = (int)lround(h / 2 - sy * scale);
      if (px < 0 || py < 0 || px >= w || py >= h) continue;
      unsigned char *c = rgb + 3 * ((size_t)py * w + px);
      c[0] = c[1] = c[2] = 70;
    }
  }
  /* particles: 2x2 splats, nearer ones in front, shaded by depth */
  for (int i = 0; p && i < p->n; i++) {
    double sx, sy, z;
    camera(p->x + 3 * i, dist, &sx, &sy, &z);
    double shade = 1.15 - 0.35 * (z - (dist - extent)) / (2 * extent);
    shade = shade < 0.4 ? 0.4 : shade > 1 ? 1 : shade;
    unsigned char col[3] = {255, 255, 255};
    if (p->tag[i]) col[0] = 255, col[1] = 150, col[2] = 40;
    int px = (int)lround(w / 2 + sx * scale), py = (int)lround(h / 2 - sy * scale);
    for (int dy = 0; dy < 2; dy++)
      for (int dx = 0; dx < 2; dx++) {
        int qx = px + dx, qy = py + dy;
        if (qx < 0 || qy < 0 || qx >= w || qy >= h) continue;
        size_t k = (size_t)qy * w + qx;
        if (z >= zbuf[k]) continue;
        zbuf[k] = (float)z;
        for (int d = 0; d < 3; d++) rgb[3 * k + d] = (unsigned char)lround(shade * col[d]);
      }
  }
  int rc = write_png(path, w, h, rgb, err, errlen);
  free(rgb);
  free(zbuf);
  return rc;
}

int output_frame_due(int t, int last, int every) { return t % every == 0 || t == last; }
