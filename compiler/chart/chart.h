/* chart.h — line charts as PNG with cairo: the one chart module of npgc (plot, tune) and
 * the applications (fluids, radiosity, points), built once as the library npg_chart, a
 * layer of its own above the npg.h facade (compiler/README.md). libnpg stays free of cairo. */
#ifndef NPG_CHART_H
#define NPG_CHART_H

#include <stdbool.h>
#include <stddef.h>

typedef struct ChartSeries {
  const char *label;        /* legend text (NULL: no legend entry) */
  int n;
  const double *x, *y;      /* n points; a point not finite (or ≤ 0 on a log axis) is skipped */
  int mark;                 /* index of a point to mark with a big dot, or -1 */
  bool points;              /* small dots instead of a line */
  bool dots;                /* a line with a dot on every point */
} ChartSeries;

typedef struct Chart {
  const char *title, *xlabel, *ylabel;
  bool logx, logy;
  int nseries;
  const ChartSeries *series;
  double ymin, ymax;        /* a linear y axis's range when ymin < ymax; else the data's */
  bool legend_inside;       /* the legend in the plot's upper right corner, on a light box (else right of it) */
  const double (*palette)[3]; /* npalette colours for the series in turn (NULL: Tableau 10) */
  int npalette;
} Chart;

/* Draw `c` into the PNG file `path` (width x height pixels). An axis whose values are all
 * whole numbers (frames, basis sizes) gets whole-number ticks. 0, or -1 with `err`
 * ("path: problem": a failed write or close names its cause, e.g. "No space left on device"); the
 * file is written to a temporary name and renamed, so a failure leaves `path` as it was. */
int chart_png(const Chart *c, const char *path, int width, int height, char *err, size_t errlen);
/* Release cairo's and fontconfig's caches (once, at exit: a leak checker then sees only
 * the program's own allocations); no drawing with cairo text after it. */
void chart_cleanup(void);

#endif
