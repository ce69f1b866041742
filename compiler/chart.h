/* chart.h — line charts as PNG with cairo, for the commands that draw
 * (npgc plot). Linked into npgc only: the library stays free of cairo. */
#ifndef NPG_CHART_H
#define NPG_CHART_H

#include <stdbool.h>
#include <stddef.h>

typedef struct ChartSeries {
  const char *label;        /* legend text */
  int n;
  const double *x, *y;      /* n points; a point not finite (or ≤ 0 on a log axis) is skipped */
  int mark;                 /* index of a point to mark with a dot, or -1 */
  bool points;              /* small dots instead of a line */
} ChartSeries;

typedef struct Chart {
  const char *title, *xlabel, *ylabel;
  bool logx, logy;
  int nseries;
  const ChartSeries *series;
} Chart;

/* Draw `c` into the PNG file `path` (width x height pixels). 0, or -1 with
 * `err` ("path: problem"). */
int chart_png(const Chart *c, const char *path, int width, int height, char *err, size_t errlen);

#endif
