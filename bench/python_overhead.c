/* python_overhead.c — the C side of bench/python_overhead.py: one reduced
 * evaluation through npg.h exactly as the Python module makes it (every
 * input projected from its full values, the evaluation, each output's
 * reduced coordinates copied out), timed per call.
 *
 *     bench_python_overhead PROG.npg MODEL/ IN/ CALLS BATCH
 *
 * IN/<input>.npy hold samples (leading axis); call k uses sample k mod S.
 * Prints one line: `c_us median=<µs a call, median over batches> min=<µs>`. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "npg.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

int main(int argc, char **argv) {
  if (argc != 6) {
    fprintf(stderr, "usage: %s PROG.npg MODEL/ IN/ CALLS BATCH\n", argv[0]);
    return 2;
  }
  long calls = atol(argv[4]), batch = atol(argv[5]);
  if (calls < 1 || batch < 1 || calls % batch) {
    fprintf(stderr, "bench_python_overhead: CALLS must be a positive multiple of BATCH\n");
    return 2;
  }
  NpgProgram *p = npg_compile(argv[1], NULL);
  if (!npg_ok(p)) return fputs(npg_error(p), stderr), 1;
  NpgModel *m = npg_model_load(p, argv[2]);
  if (npg_model_error(m)[0]) return fprintf(stderr, "%s\n", npg_model_error(m)), 1;
  char err[2048];
  NpgSamples *s = npg_samples_open(p, argv[3], NULL, false, err, sizeof err);
  if (!s) return fprintf(stderr, "%s\n", err), 1;
  int n = npg_nsymbols(p), nin = 0, nout = 0;
  NpgSymbol *sym = calloc((size_t)n, sizeof *sym);
  const char **in = calloc((size_t)n, sizeof *in), **out = calloc((size_t)n, sizeof *out);
  double *coords = malloc(sizeof(double) * 100000);
  for (int i = 0; i < n; i++) {
    npg_symbol(p, i, &sym[i]);
    if (sym[i].kind == NPG_INPUT) in[nin++] = sym[i].name;
    else if (sym[i].output && sym[i].kind != NPG_OP) out[nout++] = sym[i].name;
  }
  NpgReduced *r = npg_reduced_new(m);
  long S = npg_samples_count(s), nb = calls / batch;
  double *per = malloc(sizeof(double) * (size_t)nb);
  for (long b = -1; b < nb; b++) { /* batch -1 warms up */
    double t0 = now();
    for (long c = 0; c < batch; c++) {
      long k = (b * batch + c + batch) % S;
      for (int i = 0; i < nin; i++) {
        size_t cnt;
        const double *v = npg_samples_get(s, in[i], k, &cnt);
        if (npg_reduced_set(r, in[i], cnt, v) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
      }
      if (npg_reduced_eval(r, k) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
      for (int o = 0; o < nout; o++) { /* the module hands out a copy of each output's coordinates */
        size_t mm;
        const double *x = npg_reduced_coords(r, out[o], &mm);
        memcpy(coords, x, sizeof(double) * mm);
      }
    }
    if (b >= 0) per[b] = (now() - t0) / (double)batch * 1e6;
  }
  qsort(per, (size_t)nb, sizeof *per, cmp);
  printf("c_us median=%.4f min=%.4f\n", per[nb / 2], per[0]);
  npg_reduced_free(r);
  npg_samples_free(s);
  npg_model_free(m);
  npg_free(p);
  free(sym), free(in), free(out), free(coords), free(per);
  return 0;
}
