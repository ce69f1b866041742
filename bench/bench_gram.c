/* bench_gram.c — the two costs of the method of snapshots at large S,
 * each against the route it replaced, measured in the same run:
 *
 *   eigen      the eigenproblem of one S x S Gram matrix: pca_top_eigen
 *              (every eigenvalue, the eigenvectors of the k largest)
 *              against LAPACKE_dsyevd (every eigenvector), for each S and
 *              k; the Gram matrix is Z D² Zᵀ, Z a random S x (S/2)
 *              matrix, D from 1 down to 1e-4 geometrically, plus 1e-12 I
 *              (positive definite, decaying as snapshots' spectra do, which
 *              lets dsyevd's divide and conquer deflate). Checks: eigenvalues and the kept eigenvectors
 *              (up to sign, largest |1 − |vᵀw||, over those whose eigenvalue
 *              is 1e-5 λ_max from its neighbours: the others are not
 *              determined to more than ε λ_max / gap by either route)
 *              against dsyevd's.
 *   snapshots  the Gram matrix G = XᵀX of S synthetic snapshots of n
 *              entries that do not fit in the budget of `fit` samples:
 *              the route before (a held block of `fit` samples, a dgemv
 *              per later sample) against snapshots.c's (train_gram_blocks:
 *              a held block and a batch, a dgemm per batch). Snapshot k
 *              is Σ_j a_kj φ_j over 3 fixed random modes φ_j (3n flops
 *              to "recompute", the same in both routes; the trainer's
 *              recomputation, a full evaluation, is not measured here).
 *              Check: the largest |G_old − G_new| / max |G|.
 *
 *     build/bench_gram [eigen] [S=1000,3000,6300] [k=1,5,64,128]
 *                      [snapshots] [n=100000] [samples=600] [fit=120] [batch=Q]
 *
 * batch=Q: the snapshots part's batch Q (the held block fit − Q) instead
 * of train_gram_blocks' split.
 *
 * No part named: both, with those defaults. Prints figures, not pass/fail
 * (exit 1 only when a check exceeds 1e-8, a wrong result rather than a
 * slow one). */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "randdata.h"
#include "train.h"

/* Seconds on `clock`: CLOCK_MONOTONIC (wall), or CLOCK_PROCESS_CPUTIME_ID
 * (every thread of the process: on a loaded machine the steadier figure,
 * wall time also counting waits for a core). */
static double seconds(clockid_t clock) {
  struct timespec t;
  clock_gettime(clock, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
enum { WALL = CLOCK_MONOTONIC, CPU = CLOCK_PROCESS_CPUTIME_ID };

/* "1,5,64" into v[0..*n) (at most max). */
static void parse_list(const char *s, long *v, int *n, int max) {
  *n = 0;
  for (char *end; *s && *n < max; s = *end ? end + 1 : end) v[(*n)++] = strtol(s, &end, 10);
}

/* ---------------------------------------------------------------- eigen */

/* Column-major S x S: Z D² Zᵀ (Z S x c random, D_jj = 10^(-4 j/c)) + 1e-12 I. */
static double *gram_matrix(long S) {
  long c = S / 2 > 1 ? S / 2 : 1;
  unsigned seed = 7u;
  double *X = malloc(sizeof(double) * (size_t)(S * c)), *G = calloc((size_t)(S * S), sizeof(double));
  if (!X || !G) return free(X), free(G), NULL;
  for (long j = 0; j < c; j++)
    for (long i = 0; i < S; i++) X[j * S + i] = randdata_uniform(&seed, -1, 1) * pow(10.0, -4.0 * (double)j / (double)c);
  cblas_dsyrk(CblasColMajor, CblasUpper, CblasNoTrans, (int)S, (int)c, 1.0, X, (int)S, 0.0, G, (int)S);
  for (long i = 0; i < S; i++) G[i * S + i] += 1e-12;
  free(X);
  return G;
}

static int bench_eigen(const long *Ss, int nS, const long *ks, int nk) {
  int bad = 0;
  printf("eigen step: dsyevd (every eigenvector) vs pca_top_eigen (every eigenvalue, k eigenvectors)\n");
  printf("%6s %5s %9s %9s %9s %9s %7s %7s %9s %9s\n", "S", "k", "dsyevd", "(cpu)", "top_eig", "(cpu)", "ratio", "(cpu)",
         "d eigval", "d vector");
  for (int a = 0; a < nS; a++) {
    long S = Ss[a];
    double *G0 = gram_matrix(S), *G = malloc(sizeof(double) * (size_t)(S * S));
    double *ref = malloc(sizeof(double) * (size_t)S), *lam = malloc(sizeof(double) * (size_t)S);
    long kmax = 0;
    for (int b = 0; b < nk; b++) kmax = ks[b] > kmax ? ks[b] : kmax;
    double *V = malloc(sizeof(double) * (size_t)(S * (kmax < S ? kmax : S)));
    if (!G0 || !G || !ref || !lam || !V) return fprintf(stderr, "bench_gram: out of memory at S %ld\n", S), 1;
    memcpy(G, G0, sizeof(double) * (size_t)(S * S));
    double t0 = seconds(WALL), c0 = seconds(CPU);
    if (LAPACKE_dsyevd(LAPACK_COL_MAJOR, 'V', 'U', (lapack_int)S, G, (lapack_int)S, ref) != 0)
      return fprintf(stderr, "bench_gram: dsyevd failed at S %ld\n", S), 1;
    double tfull = seconds(WALL) - t0, cfull = seconds(CPU) - c0; /* G now holds every eigenvector, ascending */
    double *G2 = malloc(sizeof(double) * (size_t)(S * S));
    if (!G2) return fprintf(stderr, "bench_gram: out of memory at S %ld\n", S), 1;
    for (int b = 0; b < nk; b++) {
      long k = ks[b] < S ? ks[b] : S;
      memcpy(G2, G0, sizeof(double) * (size_t)(S * S));
      t0 = seconds(WALL), c0 = seconds(CPU);
      if (pca_top_eigen(S, G2, k, lam, V) != 0) return fprintf(stderr, "bench_gram: pca_top_eigen failed\n"), 1;
      double tpart = seconds(WALL) - t0, cpart = seconds(CPU) - c0, dl = 0, dv = 0;
      for (long i = 0; i < S; i++) dl = fmax(dl, fabs(lam[i] - ref[i]) / ref[S - 1]);
      for (long j = 0; j < k; j++) {
        long i = S - 1 - j; /* ascending index */
        double gap = fmin(i + 1 < S ? ref[i + 1] - ref[i] : INFINITY, i > 0 ? ref[i] - ref[i - 1] : INFINITY);
        if (gap >= 1e-5 * ref[S - 1]) dv = fmax(dv, fabs(1 - fabs(cblas_ddot((int)S, V + j * S, 1, G + i * S, 1))));
      }
      printf("%6ld %5ld %9.3f %9.3f %9.3f %9.3f %7.2f %7.2f %9.2g %9.2g\n", S, k, tfull, cfull, tpart, cpart, tfull / tpart,
             cfull / cpart, dl, dv);
      fflush(stdout);
      bad |= !(dl < 1e-8 && dv < 1e-8);
    }
    free(G0), free(G), free(G2), free(ref), free(lam), free(V);
  }
  return bad;
}

/* ---------------------------------------------------------------- snapshots */

typedef struct Modes {
  long n;
  double *phi;   /* 8 x n */
} Modes;

enum { NMODES = 3 };

/* Snapshot k: Σ_j a_kj φ_j, a_kj = cos(0.7 k j + j) / (1 + j). */
static void snapshot(const Modes *md, long k, double *x) {
  memset(x, 0, sizeof(double) * (size_t)md->n);
  for (int j = 0; j < NMODES; j++)
    cblas_daxpy((int)md->n, cos(0.7 * (double)k * (double)j + (double)j) / (1 + j), md->phi + j * md->n, 1, x, 1);
}

/* The route before: blocks of b held, G[I, k] by a dgemv per later sample. */
static void gram_by_dgemv(const Modes *md, long S, long b, double *G, double *H, double *x) {
  long n = md->n;
  for (long i0 = 0; i0 < S; i0 += b) {
    long i1 = i0 + b < S ? i0 + b : S, nb = i1 - i0;
    for (long k = i0; k < S; k++) {
      snapshot(md, k, k < i1 ? H + (k - i0) * n : x);
      if (k < i1) continue;
      double *g = x + n; /* nb entries after the sample */
      cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)nb, (int)n, 1.0, H, (int)n, x, 1, 0.0, g, 1);
      for (long a = 0; a < nb; a++) G[(i0 + a) * S + k] = G[k * S + i0 + a] = g[a];
    }
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nb, (int)n, 1.0, H, (int)n, H, (int)n, 0.0,
                G + i0 * S + i0, (int)S);
  }
}

/* snapshots.c's route: blocks of b held, later samples in batches of q, one
 * dgemm per batch (a dgemv for a batch of one). */
static void gram_by_dgemm(const Modes *md, long S, long b, long q, double *G, double *H, double *Y) {
  long n = md->n;
  for (long i0 = 0; i0 < S; i0 += b) {
    long i1 = i0 + b < S ? i0 + b : S, nb = i1 - i0;
    for (long k = i0, k0 = i1; k < S; k++) {
      snapshot(md, k, k < i1 ? H + (k - i0) * n : Y + (k - k0) * n);
      if (!(k >= i1 && (k + 1 - k0 == q || k + 1 == S))) continue;
      long nk = k + 1 - k0;
      if (nk == 1)
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)nb, (int)n, 1.0, H, (int)n, Y, 1, 0.0, G + i0 * S + k0, (int)S);
      else
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nk, (int)n, 1.0, H, (int)n, Y, (int)n, 0.0,
                    G + i0 * S + k0, (int)S);
      for (long a = i0; a < i1; a++)
        for (long e = k0; e <= k; e++) G[e * S + a] = G[a * S + e];
      k0 = k + 1;
    }
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nb, (int)n, 1.0, H, (int)n, H, (int)n, 0.0,
                G + i0 * S + i0, (int)S);
  }
}

static int bench_snapshots(long n, long S, long fit, long batch) {
  Modes md = {n, malloc(sizeof(double) * (size_t)(NMODES * n))};
  long b, q;
  train_gram_blocks(S, fit, &b, &q);
  if (batch > 0 && batch < fit) q = batch, b = fit - batch; /* another split, to compare */
  double *Ga = calloc((size_t)(S * S), sizeof(double)), *Gb = calloc((size_t)(S * S), sizeof(double));
  double *H = malloc(sizeof(double) * (size_t)(fit * n)), *x = malloc(sizeof(double) * (size_t)(n + fit));
  double *Y = malloc(sizeof(double) * (size_t)((q ? q : 1) * n));
  if (!md.phi || !Ga || !Gb || !H || !x || !Y) return fprintf(stderr, "bench_gram: out of memory\n"), 1;
  unsigned seed = 11u;
  for (long i = 0; i < NMODES * n; i++) md.phi[i] = randdata_uniform(&seed, -1, 1);
  printf("method of snapshots, Gram matrix of %ld synthetic snapshots of %ld entries (%.2f MB each), a budget of %ld "
         "(%.0f MB)\n", S, n, 8e-6 * (double)n, fit, 8e-6 * (double)(n * fit));
  double t0 = seconds(WALL), c0 = seconds(CPU);
  gram_by_dgemv(&md, S, fit, Ga, H, x);
  double told = seconds(WALL) - t0, cold = seconds(CPU) - c0;
  t0 = seconds(WALL), c0 = seconds(CPU);
  gram_by_dgemm(&md, S, b, q, Gb, H, Y);
  double tnew = seconds(WALL) - t0, cnew = seconds(CPU) - c0, big = 0, d = 0;
  for (long i = 0; i < S * S; i++) big = fmax(big, fabs(Ga[i])), d = fmax(d, fabs(Ga[i] - Gb[i]));
  long pold = (S + fit - 1) / fit, pnew = (S + b - 1) / b;
  printf("  before: blocks of %ld, a dgemv per later sample:  %ld passes, wall %8.3f s, cpu %8.3f s\n", fit, pold, told,
         cold);
  printf("  now:    blocks of %ld, batches of %ld (a dgemm each): %ld passes, wall %8.3f s, cpu %8.3f s\n", b, q, pnew,
         tnew, cnew);
  printf("  ratio (before / now) wall %.2f, cpu %.2f; G differs by %.2g of its largest entry\n", told / tnew, cold / cnew,
         d / big);
  free(md.phi), free(Ga), free(Gb), free(H), free(x), free(Y);
  return !(d <= 1e-8 * big);
}

int main(int argc, char **argv) {
  long Ss[16] = {1000, 3000, 6300}, ks[16] = {1, 5, 64, 128}, n = 100000, S = 600, fit = 120, batch = 0;
  int nS = 3, nk = 4, eigen = 0, snaps = 0;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "eigen")) eigen = 1;
    else if (!strcmp(argv[i], "snapshots")) snaps = 1;
    else if (!strncmp(argv[i], "S=", 2)) parse_list(argv[i] + 2, Ss, &nS, 16);
    else if (!strncmp(argv[i], "samples=", 8)) S = strtol(argv[i] + 8, NULL, 10);
    else if (!strncmp(argv[i], "k=", 2)) parse_list(argv[i] + 2, ks, &nk, 16);
    else if (!strncmp(argv[i], "n=", 2)) n = strtol(argv[i] + 2, NULL, 10);
    else if (!strncmp(argv[i], "fit=", 4)) fit = strtol(argv[i] + 4, NULL, 10);
    else if (!strncmp(argv[i], "batch=", 6)) batch = strtol(argv[i] + 6, NULL, 10);
    else {
      fprintf(stderr, "usage: %s [eigen] [snapshots] [S=..] [k=..] [n=N] [samples=S] [fit=F] [batch=Q]\n", argv[0]);
      return 2;
    }
  }
  if (!eigen && !snaps) eigen = snaps = 1;
  int bad = 0;
  if (eigen) bad |= bench_eigen(Ss, nS, ks, nk);
  if (snaps) bad |= bench_snapshots(n, S, fit, batch);
  return bad;
}
