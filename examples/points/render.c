#include "render.h"
int render_radiosity(const Surfels *s, const double *b, double exposure, int width, const char *path) { return 0; }
int render_comparison(const Surfels *s, const double *b_fmm, const double *b_dense, double exposure, int width,
                      const char *path) { return 0; }
int render_plot(const char *path, const char *title, const char *xlabel, const char *ylabel, int logx,
                const PlotSeries *series, int nseries) { return 0; }
