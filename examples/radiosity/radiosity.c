/* radiosity.c — form factors and the radiosity solve (radiosity.h). */
#include "util.h"
#include "radiosity.h"
#include "npg.h"

#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct FormFactorJob {
  long F;
  const double *n, *cen, *v;
  double *p;
  int t, nt;
} FormFactorJob;

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* Rows t, t + nt, ...: interleaved, so both threads get long and short rows alike. */
static void *form_factor_rows(void *arg) {
  const FormFactorJob *job = arg;
  long F = job->F;
  for (long i = job->t; i < F; i += job->nt) {
    const double *ni = job->n + 3 * i, *ci = job->cen + 3 * i;
    double a = dot3(ni, ni), root = pow(a, -0.5);
    double *prow = job->p + (size_t)i * F;
    const double *vrow = job->v + (size_t)i * F;
    for (long j = 0; j < F; j++) {
      if (vrow[j] == 0) {
        prow[j] = 0; /* d = c v = 0 (c is finite: distinct centroids) */
        continue;
      }
      const double *nj = job->n + 3 * j, *cj = job->cen + 3 * j;
      double dij[3] = {cj[0] - ci[0], cj[1] - ci[1], cj[2] - ci[2]};
      double dji[3] = {ci[0] - cj[0], ci[1] - cj[1], ci[2] - cj[2]};
      double s_ij = dot3(ni, dij), s_ji = dot3(nj, dji);
      double r = i == j ? 1 : dot3(dji, dji);
      double h_ij = s_ij / r, h_ji = s_ji / r;
      double c = h_ij * h_ji / M_PI;
      double d = c * vrow[j];
      prow[j] = d * root;
    }
  }
  return NULL;
}

void radiosity_form_factors(long V, long F, const double *g, const int *tri, const double *v, double *p, int threads) {
  (void)V;
  double *n = malloc(sizeof(double) * 3 * F), *cen = malloc(sizeof(double) * 3 * F);
  for (long f = 0; f < F; f++) {
    const double *a = g + 3 * tri[3 * f], *b = g + 3 * tri[3 * f + 1], *c = g + 3 * tri[3 * f + 2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    n[3 * f + 0] = 0.5 * (u[1] * w[2] - u[2] * w[1]);
    n[3 * f + 1] = 0.5 * (u[2] * w[0] - u[0] * w[2]);
    n[3 * f + 2] = 0.5 * (u[0] * w[1] - u[1] * w[0]);
    for (int d = 0; d < 3; d++) cen[3 * f + d] = (a[d] + b[d] + c[d]) / 3;
  }
  int nt = threads < 1 ? 1 : threads > 64 ? 64 : threads;
  FormFactorJob job[64];
  pthread_t th[64];
  int started[64] = {0};
  for (int t = 0; t < nt; t++) job[t] = (FormFactorJob){F, n, cen, v, p, t, nt};
  for (int t = 1; t < nt; t++) started[t] = pthread_create(&th[t], NULL, form_factor_rows, &job[t]) == 0;
  form_factor_rows(&job[0]);
  for (int t = 1; t < nt; t++) {
    if (started[t])
      pthread_join(th[t], NULL);
    else
      form_factor_rows(&job[t]);
  }
  free(n);
  free(cen);
}

int radiosity_solve_lu(long F, const double *rho, const double *p, const double *e, double *b, char *err,
                       size_t errlen) {
  double *M = malloc(sizeof(double) * (size_t)F * F);
  lapack_int *piv = malloc(sizeof(lapack_int) * F);
  if (!M || !piv) {
    free(M), free(piv);
    return npg_error_set(err, errlen, "LU solve: out of memory for a %ld x %ld matrix", F, F);
  }
  for (long i = 0; i < F; i++) {
    for (long j = 0; j < F; j++) M[(size_t)i * F + j] = -rho[i] * p[(size_t)i * F + j];
    M[(size_t)i * F + i] += 1;
  }
  memcpy(b, e, sizeof(double) * F);
  lapack_int info = LAPACKE_dgesv(LAPACK_ROW_MAJOR, (lapack_int)F, 1, M, (lapack_int)F, piv, b, 1);
  free(M);
  free(piv);
  if (info > 0) return npg_error_set(err, errlen, "LU solve: I - rho F is singular (zero pivot %d)", (int)info);
  if (info < 0) return npg_error_set(err, errlen, "LU solve: dgesv argument %d is invalid", (int)-info);
  return 0;
}

int radiosity_solve_gauss_seidel(long F, const double *rho, const double *p, const double *e, double *b, double tol,
                                 int max_sweeps, char *err, size_t errlen) {
  memcpy(b, e, sizeof(double) * F);
  for (int sweep = 1; sweep <= max_sweeps; sweep++) {
    double change = 0, big = 0;
    for (long i = 0; i < F; i++) {
      const double *row = p + (size_t)i * F;
      double acc = 0;
      for (long j = 0; j < F; j++) acc += row[j] * b[j];
      acc -= row[i] * b[i];
      double bi = (e[i] + rho[i] * acc) / (1 - rho[i] * row[i]);
      change = fmax(change, fabs(bi - b[i]));
      b[i] = bi;
      big = fmax(big, fabs(bi));
    }
    if (!isfinite(change)) return npg_error_set(err, errlen, "Gauss-Seidel: not finite at sweep %d", sweep);
    if (change <= tol * big) return sweep;
  }
  return npg_error_set(err, errlen,
                       "Gauss-Seidel: no convergence to %g in %d sweeps (is every albedo < 1?)", tol, max_sweeps);
}

/* y = (I − diag(rho) p) x: one pass over p through BLAS (threaded). */
static void apply(long F, const double *rho, const double *p, const double *x, double *y) {
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)F, (int)F, 1.0, p, (int)F, x, 1, 0.0, y, 1);
  for (long i = 0; i < F; i++) y[i] = x[i] - rho[i] * y[i];
}

/* Restarted GMRES(m) (Saad & Schultz 1986): Arnoldi with modified Gram–Schmidt, Givens
 * rotations on the Hessenberg matrix, the residual norm read off the rotated right-hand
 * side; the solution is updated at each restart and at convergence. */
int radiosity_solve_gmres(long F, const double *rho, const double *p, const double *e, double *b, double tol,
                          int max_matvecs, char *err, size_t errlen) {
  enum { M = 30 };
  double *V = malloc(sizeof(double) * (size_t)(M + 1) * F), *w = malloc(sizeof(double) * F);
  double H[M + 1][M], cs[M], sn[M], g[M + 1], y[M];
  if (!V || !w) {
    free(V), free(w);
    return npg_error_set(err, errlen, "GMRES: out of memory");
  }
  double enorm = cblas_dnrm2((int)F, e, 1);
  if (enorm == 0) enorm = 1;
  memcpy(b, e, sizeof(double) * F);
  int matvecs = 0;
  for (;;) {
    apply(F, rho, p, b, w);
    matvecs++;
    for (long i = 0; i < F; i++) V[i] = e[i] - w[i];
    double beta = cblas_dnrm2((int)F, V, 1);
    if (!isfinite(beta)) {
      free(V), free(w);
      return npg_error_set(err, errlen, "GMRES: residual not finite after %d products", matvecs);
    }
    if (beta <= tol * enorm) break;
    if (matvecs >= max_matvecs) {
      free(V), free(w);
      return npg_error_set(err, errlen,
                           "GMRES: residual %.3g above %.3g after %d products", beta / enorm, tol, matvecs);
    }
    cblas_dscal((int)F, 1 / beta, V, 1);
    memset(g, 0, sizeof g);
    g[0] = beta;
    int k = 0;
    for (; k < M && matvecs < max_matvecs; k++) {
      double *vk1 = V + (size_t)(k + 1) * F;
      apply(F, rho, p, V + (size_t)k * F, vk1);
      matvecs++;
      for (int q = 0; q <= k; q++) {
        H[q][k] = cblas_ddot((int)F, vk1, 1, V + (size_t)q * F, 1);
        cblas_daxpy((int)F, -H[q][k], V + (size_t)q * F, 1, vk1, 1);
      }
      H[k + 1][k] = cblas_dnrm2((int)F, vk1, 1);
      if (H[k + 1][k] > 0) cblas_dscal((int)F, 1 / H[k + 1][k], vk1, 1);
      for (int q = 0; q < k; q++) {
        double t = cs[q] * H[q][k] + sn[q] * H[q + 1][k];
        H[q + 1][k] = -sn[q] * H[q][k] + cs[q] * H[q + 1][k];
        H[q][k] = t;
      }
      double r = hypot(H[k][k], H[k + 1][k]);
      cs[k] = H[k][k] / r;
      sn[k] = H[k + 1][k] / r;
      H[k][k] = r;
      H[k + 1][k] = 0;
      g[k + 1] = -sn[k] * g[k];
      g[k] = cs[k] * g[k];
      if (fabs(g[k + 1]) <= 0.1 * tol * enorm) {
        k++;
        break;
      }
    }
    for (int q = k - 1; q >= 0; q--) {
      double t = g[q];
      for (int c = q + 1; c < k; c++) t -= H[q][c] * y[c];
      y[q] = t / H[q][q];
    }
    for (int q = 0; q < k; q++) cblas_daxpy((int)F, y[q], V + (size_t)q * F, 1, b, 1);
  }
  free(V);
  free(w);
  return matvecs;
}

double radiosity_residual(long F, const double *rho, const double *p, const double *e, const double *b) {
  double rr = 0, ee = 0;
  for (long i = 0; i < F; i++) {
    const double *row = p + (size_t)i * F;
    double acc = 0;
    for (long j = 0; j < F; j++) acc += row[j] * b[j];
    double r = e[i] - (b[i] - rho[i] * acc);
    rr += r * r;
    ee += e[i] * e[i];
  }
  return sqrt(rr) / (ee > 0 ? sqrt(ee) : 1);
}
