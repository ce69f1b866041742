/* plot.c — npgc plot MODEL/ -o spectra.png: every member's singular values
 * (relative to its largest, log scale), one curve per member, a dot where
 * its basis was truncated (issue 11). Reads the spectra MODEL/ lists (any
 * program's model: npg_spectra_read needs no program). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "chart.h"
#include "npg.h"
#include "npgc.h"

int npgc_plot(int argc, char **argv) {
  const char *dir = NULL, *out = NULL;
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npgc plot");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage("plot", true);
    if ((v = npg_args_string(&a, "-o"))) out = v;
    else if ((v = npg_args_positional(&a)) && !dir) dir = v;
    else if (v) npgc_args_extra(&a, "model", dir);
    else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, "plot");
  if (!dir) return npgc_missing("plot", "MODEL/ (a trained model)");
  if (!out) return npgc_missing("plot", "-o FILE.png (where to draw the spectra)");
  const char *inputs[] = {dir, NULL};
  if (npgc_check_output("plot", "-o", out, NPGC_OUT_FILE, inputs) != 0) return 1;
  NpgSpectrum *sp = NULL;
  int n = 0, rc = 1;
  char err[2048] = "";
  if (npg_spectra_read(dir, &sp, &n, err, sizeof err) != 0) {
    npgc_error(err);
    return 1;
  }
  ChartSeries *series = calloc((size_t)n + 1, sizeof *series);
  char **labels = calloc((size_t)n + 1, sizeof *labels);
  double **xs = calloc((size_t)n + 1, sizeof *xs), **ys = calloc((size_t)n + 1, sizeof *ys);
  if (!series || !labels || !xs || !ys) goto oom;
  for (int i = 0; i < n; i++) {
    long k = sp[i].n;
    xs[i] = malloc(sizeof(double) * (size_t)(k + 1));
    ys[i] = malloc(sizeof(double) * (size_t)(k + 1));
    labels[i] = malloc(600);
    if (!xs[i] || !ys[i] || !labels[i]) goto oom;
    for (long j = 0; j < k; j++) xs[i][j] = (double)(j + 1), ys[i][j] = sp[i].sigma[0] > 0 ? sp[i].sigma[j] / sp[i].sigma[0] : NAN;
    /* the dot: the last centered direction kept (the mean is not in the spectrum) */
    int last = sp[i].centered ? sp[i].kept - 2 : sp[i].kept - 1;
    snprintf(labels[i], 600, "%s (%d kept%s)", sp[i].member, sp[i].kept, sp[i].centered ? ", centered" : "");
    series[i] = (ChartSeries){labels[i], (int)k, xs[i], ys[i], last < k ? last : (int)k - 1, false, false};
  }
  char title[4200];
  snprintf(title, sizeof title, "singular values of each member's snapshots: %s", dir);
  Chart chart = {.title = title, .xlabel = "k", .ylabel = "singular value / largest", .logy = true, .nseries = n,
                 .series = series};
  if (npgc_make_parents(out, false) != 0) goto done; /* every writer of npgc creates the parents, as -o does */
  /* chart_png writes a temporary name, checks every write and the close, and renames it to `out` */
  int drawn = chart_png(&chart, out, 960, 540, err, sizeof err);
  chart_cleanup(); /* a command draws once: cairo's and fontconfig's caches released */
  if (drawn != 0) {
    npgc_error(err);
    goto done;
  }
  printf("%d spectra -> %s\n", n, out);
  rc = 0;
  goto done;
oom:
  fputs("error: out of memory\n", stderr);
done:
  for (int i = 0; i < n && xs && ys && labels; i++) free(xs[i]), free(ys[i]), free(labels[i]);
  free(series), free(labels), free(xs), free(ys);
  npg_spectra_free(sp, n);
  return rc;
}
