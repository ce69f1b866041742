/* pca.c — bases from snapshots (DESIGN §5; paper §8.2).
 *
 * One PCA per member (uncentered, as the paper's: the mean is a direction
 * like any other), truncated at an energy fraction and a cap; a class's
 * member bases concatenated and re-orthonormalized, dropping dependent
 * directions (paper §6.1: two 60-vector bases gave a 120-vector one). All
 * factorizations through LAPACKE. */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "reduce.h"

/* Singular values below this fraction of the largest are dependent
 * directions, not data. */
#define PCA_RANK_TOL 1e-10

int pca_member(long n, long S, const double *X, int cap, double energy, double **U, int *k, double *captured,
               char *err, size_t errlen) {
  *U = NULL;
  *k = 0;
  *captured = 1;
  long r = n < S ? n : S;
  double *A = malloc(sizeof(double) * (size_t)(n * S + 1));
  double *s = malloc(sizeof(double) * (size_t)(r + 1));
  double *u = malloc(sizeof(double) * (size_t)(n * r + 1));
  double *vt = malloc(sizeof(double) * (size_t)(r * S + 1));
  if (!A || !s || !u || !vt) {
    free(A), free(s), free(u), free(vt);
    snprintf(err, errlen, "out of memory for a PCA of %ld x %ld snapshots", n, S);
    return -1;
  }
  memcpy(A, X, sizeof(double) * (size_t)(n * S));
  /* X is n x S column-major: its left singular vectors are the basis */
  lapack_int info = LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)n, (lapack_int)S, A, (lapack_int)n, s, u,
                                   (lapack_int)n, vt, (lapack_int)(r ? r : 1));
  free(A);
  free(vt);
  if (info != 0) {
    free(s), free(u);
    snprintf(err, errlen, "the SVD of %ld x %ld snapshots did not converge (LAPACK info %d)", n, S, (int)info);
    return -1;
  }
  double total = 0;
  for (long i = 0; i < r; i++) total += s[i] * s[i];
  int kept = 0;
  double run = 0;
  if (total > 0) {
    while (kept < r && kept < cap && s[kept] > PCA_RANK_TOL * s[0]) {
      run += s[kept] * s[kept];
      kept++;
      if (run >= energy * total) break;
    }
    *captured = run / total;
  }
  double *out = malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  if (!out) {
    free(s), free(u);
    snprintf(err, errlen, "out of memory for a basis of %ld x %d", n, kept);
    return -1;
  }
  for (long i = 0; i < n; i++)
    for (int j = 0; j < kept; j++) out[i * kept + j] = u[(size_t)j * (size_t)n + (size_t)i];
  free(s);
  free(u);
  *U = out;
  *k = kept;
  return 0;
}

int pca_merge(long n, int r, double *const *U, const int *k, double **B, long *m, char *err, size_t errlen) {
  *B = NULL;
  *m = 0;
  long K = 0;
  for (int i = 0; i < r; i++) K += k[i];
  if (K == 0) {
    *B = malloc(sizeof(double));
    return *B ? 0 : -1;
  }
  if (r == 1) { /* already orthonormal */
    *B = malloc(sizeof(double) * (size_t)(n * K));
    if (!*B) goto oom;
    memcpy(*B, U[0], sizeof(double) * (size_t)(n * K));
    *m = K;
    return 0;
  }
  long rk = n < K ? n : K;
  double *A = malloc(sizeof(double) * (size_t)(n * K)), *s = malloc(sizeof(double) * (size_t)rk);
  double *u = malloc(sizeof(double) * (size_t)(n * rk)), *vt = malloc(sizeof(double) * (size_t)(rk * K));
  if (!A || !s || !u || !vt) {
    free(A), free(s), free(u), free(vt);
    goto oom;
  }
  long col = 0;
  for (int i = 0; i < r; i++) {
    for (long row = 0; row < n; row++)
      for (int j = 0; j < k[i]; j++) A[row * K + col + j] = U[i][row * k[i] + j];
    col += k[i];
  }
  lapack_int info = LAPACKE_dgesdd(LAPACK_ROW_MAJOR, 'S', (lapack_int)n, (lapack_int)K, A, (lapack_int)K, s, u,
                                   (lapack_int)rk, vt, (lapack_int)K);
  free(A);
  free(vt);
  if (info != 0) {
    free(s), free(u);
    snprintf(err, errlen, "re-orthonormalizing a merged basis: SVD did not converge (LAPACK info %d)", (int)info);
    return -1;
  }
  long kept = 0;
  while (kept < rk && s[kept] > PCA_RANK_TOL * s[0]) kept++;
  double *out = malloc(sizeof(double) * (size_t)(n * (kept ? kept : 1)));
  if (!out) {
    free(s), free(u);
    goto oom;
  }
  for (long row = 0; row < n; row++)
    for (long j = 0; j < kept; j++) out[row * kept + j] = u[row * rk + j];
  free(s);
  free(u);
  *B = out;
  *m = kept;
  return 0;
oom:
  snprintf(err, errlen, "out of memory merging bases of %ld entries", n);
  return -1;
}
