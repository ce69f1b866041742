/* plot.c — npgc plot MODEL/ -o spectra.png: every member's singular values
 * (relative to its largest, log scale), one curve per member, a dot where
 * its basis was truncated (issue 11). Reads the spectra MODEL/ lists (any
 * program's model: the store is read without the program). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "chart.h"
#include "compile.h"
#include "model_store.h"

/* One curve per member line of the manifest: "member C NAME cap N energy E
 * kept K captured X [center 0|1 lost L]". */
int npgc_plot(int argc, char **argv) {
  const char *dir = NULL, *out = NULL;
  for (int i = 2; i < argc; i++) {
    if (strcmp(argv[i], "-o") == 0 && i + 1 < argc) out = argv[++i];
    else if (argv[i][0] == '-') {
      fprintf(stderr, "npgc plot: unknown option '%s'\n", argv[i]);
      dir = NULL;
      break;
    } else if (!dir) dir = argv[i];
    else dir = NULL, i = argc;
  }
  if (!dir || !out) {
    fputs("usage: npgc plot MODEL/ -o spectra.png\n", stderr);
    return 2;
  }
  ModelStore s;
  char err[2048] = "";
  if (model_store_read_any(dir, &s, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    return 1;
  }
  int n = 0, rc = 1;
  ChartSeries *series = calloc((size_t)s.nmeta + 1, sizeof *series);
  char **labels = calloc((size_t)s.nmeta + 1, sizeof *labels);
  double **xs = calloc((size_t)s.nmeta + 1, sizeof *xs), **ys = calloc((size_t)s.nmeta + 1, sizeof *ys);
  if (!series || !labels || !xs || !ys) goto oom;
  for (int i = 0; i < s.nmeta; i++) {
    int c, cap, kept, center = 0;
    double energy, captured, lost = -1;
    char name[512], aname[600];
    int got = sscanf(s.meta[i], "member %d %511s cap %d energy %lf kept %d captured %lf center %d lost %lf", &c, name,
                     &cap, &energy, &kept, &captured, &center, &lost);
    if (got < 6) continue;
    snprintf(aname, sizeof aname, "spectrum_%s", name);
    const NpyArray *a = model_store_array(&s, aname);
    if (!a || a->ndim != 1) {
      fprintf(stderr, "error: %s/manifest: member %s has no spectrum (a model trained before spectra were kept: "
              "retrain it)\n", dir, name);
      goto done;
    }
    const double *sv = a->data;
    int k = (int)a->count;
    xs[n] = malloc(sizeof(double) * (size_t)(k + 1));
    ys[n] = malloc(sizeof(double) * (size_t)(k + 1));
    labels[n] = malloc(600);
    if (!xs[n] || !ys[n] || !labels[n]) goto oom;
    for (int j = 0; j < k; j++) xs[n][j] = j + 1, ys[n][j] = sv[0] > 0 ? sv[j] / sv[0] : NAN;
    /* the dot: the last centered direction kept (the mean is not in the spectrum) */
    int last = (got == 8 && center) ? kept - 2 : kept - 1;
    snprintf(labels[n], 600, "%s (%d kept%s)", name, kept, got == 8 && center ? ", centered" : "");
    series[n] = (ChartSeries){labels[n], k, xs[n], ys[n], last < k ? last : k - 1, false};
    n++;
  }
  char title[4200];
  snprintf(title, sizeof title, "singular values of each member's snapshots: %s", dir);
  Chart chart = {title, "k", "singular value / largest", false, true, n, series};
  if (chart_png(&chart, out, 960, 540, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  printf("%d spectra -> %s\n", n, out);
  rc = 0;
  goto done;
oom:
  fputs("error: out of memory\n", stderr);
done:
  for (int i = 0; i < n + 1 && xs && ys && labels; i++) free(xs[i]), free(ys[i]), free(labels[i]);
  free(series), free(labels), free(xs), free(ys);
  model_store_free(&s);
  return rc;
}
