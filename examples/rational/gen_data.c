/* gen_data.c — samples for the paper's Eq. 3 (examples/rational):
 *
 *     rational_data OUTDIR SAMPLES SEED
 *
 * writes OUTDIR/x.npy, float64 [SAMPLES, 2], x drawn uniformly from
 * [0.5, 2]^2 (away from the poles x0 = 0 and x1 = 0 of y). */
#include <stdio.h>
#include <stdlib.h>

#include "npg.h"
#include "util.h"

int main(int argc, char **argv) {
  if (argc != 4) {
    fprintf(stderr, "usage: %s OUTDIR SAMPLES SEED\n", argv[0]);
    return 2;
  }
  long n, seed_l;
  char err[1024];
  if (npg_parse_long(argv[2], 1, 100000000, &n, err, sizeof err) != 0) {
    fprintf(stderr, "%s: SAMPLES: %s\n", argv[0], err);
    return 2;
  }
  if (npg_parse_long(argv[3], 0, 4294967295L, &seed_l, err, sizeof err) != 0) {
    fprintf(stderr, "%s: SEED: %s\n", argv[0], err);
    return 2;
  }
  unsigned seed = (unsigned)seed_l;
  if (util_make_dirs(argv[1], err, sizeof err) != 0) {
    fprintf(stderr, "%s: %s\n", argv[0], err);
    return 1;
  }
  double *x = malloc(sizeof(double) * (size_t)n * 2);
  if (!x) {
    fprintf(stderr, "%s: out of memory for %ld samples\n", argv[0], n);
    return 1;
  }
  for (long i = 0; i < 2 * n; i++) {
    seed = seed * 1103515245u + 12345u;
    x[i] = 0.5 + 1.5 * ((seed >> 8) & 0xffffff) / (double)0x1000000;
  }
  char path[4096];
  snprintf(path, sizeof path, "%s/x.npy", argv[1]);
  long shape[2] = {n, 2};
  int rc = npg_npy_write(path, 2, shape, x, err, sizeof err);
  if (rc) fprintf(stderr, "%s\n", err);
  free(x);
  return rc ? 1 : 0;
}
