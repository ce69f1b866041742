/* gen_data.c — samples for the paper's Eq. 3 (examples/rational):
 *
 *     rational_data OUTDIR SAMPLES SEED
 *
 * writes OUTDIR/x.npy, float64 [SAMPLES, 2], x drawn uniformly from
 * [0.5, 2]^2 (away from the poles x0 = 0 and x1 = 0 of y). */
#include <stdio.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <errno.h>
#include <string.h>

#include "npy.h"

int main(int argc, char **argv) {
  if (argc != 4) {
    fprintf(stderr, "usage: %s OUTDIR SAMPLES SEED\n", argv[0]);
    return 2;
  }
  long n = strtol(argv[2], NULL, 10);
  unsigned seed = (unsigned)strtoul(argv[3], NULL, 10);
  if (n < 1 || n > 100000000) {
    fprintf(stderr, "%s: SAMPLES must be from 1 to 1e8\n", argv[0]);
    return 2;
  }
  if (mkdir(argv[1], 0777) != 0 && errno != EEXIST) {
    fprintf(stderr, "%s: cannot create %s: %s\n", argv[0], argv[1], strerror(errno));
    return 1;
  }
  double *x = malloc(sizeof(double) * (size_t)n * 2);
  if (!x) return 1;
  for (long i = 0; i < 2 * n; i++) {
    seed = seed * 1103515245u + 12345u;
    x[i] = 0.5 + 1.5 * ((seed >> 8) & 0xffffff) / (double)0x1000000;
  }
  char path[4096], err[1024];
  snprintf(path, sizeof path, "%s/x.npy", argv[1]);
  long shape[2] = {n, 2};
  int rc = npy_write(path, NPY_F64, 2, shape, x, err, sizeof err);
  if (rc) fprintf(stderr, "%s\n", err);
  free(x);
  return rc ? 1 : 0;
}
