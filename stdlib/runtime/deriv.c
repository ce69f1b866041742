/* deriv.c — derivatives of a dense operator power y = M^r x, r = p/q (DESIGN §17),
 * for the derivative code of the full evaluator (backends/emit/emit_deriv.c).
 *
 *   r = k > 0:   y = M^k x by k products; dy = Σ_j M^(k-1-j) dM M^j x + M^k dx.
 *   r = -k < 0:  one LU; each step w' = M^-1 w, dw' = M^-1 (dw - dM w'), the
 *                tangent's solves reusing the factorization: d(M^-1 f) = M^-1 (df - dM M^-1 f).
 *   r = p/q:     M = V diag(λ) V^T (symmetric), f(λ) = λ^r. Daleckii-Krein:
 *                D f(M)[E] = V (F ∘ (V^T E V)) V^T, F_ij = (f(λ_i) - f(λ_j)) / (λ_i - λ_j),
 *                f'(λ_i) where λ_i and λ_j coincide (to 1e-10 relative).
 * The reverse products are the transposes: for r = -k, λ = M^-T ybar and Mbar -= λ w'^T
 * per step; for r = p/q, with a = V^T x and b = V^T ybar, Mbar += V (F ∘ b a^T) V^T. */
#include <cblas.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "runtime.h"

static double *vec(const NpgCtx *c, const char *stage, size_t n) {
  double *v = mem_calloc(n ? n : 1, sizeof(double));
  if (!v) runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
  return v;
}

/* y <- M y (row-major n x n). */
static void matvec(npg_idx n, const double *M, bool transpose, const double *x, double *y) {
  cblas_dgemv(CblasRowMajor, transpose ? CblasTrans : CblasNoTrans, (int)n, (int)n, 1.0, M, (int)n, x, 1, 0.0, y, 1);
}

/* The divided differences of f(λ) = λ^r over the eigenvalues w (n x n, row-major). */
static void divided_differences(npg_idx n, const double *w, double r, double *F) {
  double wmax = 0;
  for (npg_idx i = 0; i < n; i++) wmax = fmax(wmax, fabs(w[i]));
  for (npg_idx i = 0; i < n; i++)
    for (npg_idx j = 0; j < n; j++) {
      double wi = w[i] < 0 ? 0 : w[i], wj = w[j] < 0 ? 0 : w[j];
      if (fabs(wi - wj) > 1e-10 * wmax) F[i * n + j] = (pow(wi, r) - pow(wj, r)) / (wi - wj);
      else F[i * n + j] = r * pow(0.5 * (wi + wj), r - 1);
    }
}

/* Fractional powers: the eigendecomposition, then Daleckii-Krein. */
static int root_jvp(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, const double *dM, long p,
                    long q, double *x, double *dx) {
  size_t nn = (size_t)n * (size_t)n;
  double *w = vec(c, stage, (size_t)n), *F = vec(c, stage, nn), *E = vec(c, stage, nn), *T = vec(c, stage, nn);
  double *a = vec(c, stage, (size_t)n), *b = vec(c, stage, (size_t)n);
  int rc = !w || !F || !E || !T || !a || !b ? -1 : runtime_sym_eigen(c, stage, op, n, M, p, q, w);
  if (rc == 0) {
    double r = (double)p / (double)q;
    divided_differences(n, w, r, F);
    /* E = V^T dM V */
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)n, (int)n, 1.0, dM, (int)n, M, (int)n, 0.0, T,
                (int)n);
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)n, (int)n, (int)n, 1.0, M, (int)n, T, (int)n, 0.0, E,
                (int)n);
    matvec(n, M, true, x, a);  /* a = V^T x */
    matvec(n, M, true, dx, b); /* b = V^T dx */
    for (npg_idx i = 0; i < n; i++) {
      double s = 0;
      for (npg_idx j = 0; j < n; j++) s += F[i * n + j] * E[i * n + j] * a[j];
      b[i] = pow(w[i] < 0 ? 0 : w[i], r) * b[i] + s;
    }
    for (npg_idx i = 0; i < n; i++) a[i] *= pow(w[i] < 0 ? 0 : w[i], r);
    matvec(n, M, false, a, x);
    matvec(n, M, false, b, dx);
  }
  free(w), free(F), free(E), free(T), free(a), free(b);
  return rc;
}

static int root_vjp(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, double *Mbar, long p,
                    long q, const double *x, double *ybar) {
  size_t nn = (size_t)n * (size_t)n;
  double *w = vec(c, stage, (size_t)n), *F = vec(c, stage, nn), *T = vec(c, stage, nn), *U = vec(c, stage, nn);
  double *a = vec(c, stage, (size_t)n), *b = vec(c, stage, (size_t)n);
  int rc = !w || !F || !T || !U || !a || !b ? -1 : runtime_sym_eigen(c, stage, op, n, M, p, q, w);
  if (rc == 0) {
    double r = (double)p / (double)q;
    divided_differences(n, w, r, F);
    matvec(n, M, true, x, a);    /* a = V^T x */
    matvec(n, M, true, ybar, b); /* b = V^T ybar */
    for (npg_idx i = 0; i < n; i++)
      for (npg_idx j = 0; j < n; j++) T[i * n + j] = F[i * n + j] * b[i] * a[j];
    /* Mbar += V T V^T */
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)n, (int)n, 1.0, M, (int)n, T, (int)n, 0.0, U,
                (int)n);
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)n, (int)n, (int)n, 1.0, U, (int)n, M, (int)n, 1.0, Mbar,
                (int)n);
    for (npg_idx i = 0; i < n; i++) b[i] *= pow(w[i] < 0 ? 0 : w[i], r);
    matvec(n, M, false, b, ybar);
  }
  free(w), free(F), free(T), free(U), free(a), free(b);
  return rc;
}

int runtime_power_jvp(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, const double *dM,
                      long p, long q, double *x, double *dx) {
  if (runtime_check_finite(c, stage, op, n, M, x)) return -1;
  if (q != 1) return root_jvp(c, stage, op, n, M, dM, p, q, x, dx);
  double *t = vec(c, stage, (size_t)n), *u = vec(c, stage, (size_t)n);
  lapack_int *piv = p < 0 ? mem_malloc(sizeof(lapack_int) * (size_t)(n ? n : 1)) : NULL;
  int rc = !t || !u || (p < 0 && !piv) ? -1 : 0;
  if (rc == 0 && p < 0) rc = runtime_lu(c, stage, op, n, M, piv);
  for (long k = 0; k < labs(p) && rc == 0; k++) {
    if (p > 0) { /* x' = M x, dx' = M dx + dM x */
      matvec(n, M, false, x, t);
      matvec(n, M, false, dx, u);
      cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)n, 1.0, dM, (int)n, x, 1, 1.0, u, 1);
      memcpy(x, t, sizeof(double) * (size_t)n);
      memcpy(dx, u, sizeof(double) * (size_t)n);
    } else { /* x' = M^-1 x, dx' = M^-1 (dx - dM x') */
      rc = runtime_lu_solve(c, stage, n, M, piv, false, x);
      if (rc == 0) cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)n, -1.0, dM, (int)n, x, 1, 1.0, dx, 1);
      if (rc == 0) rc = runtime_lu_solve(c, stage, n, M, piv, false, dx);
    }
  }
  if (!t || !u || (p < 0 && !piv)) runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
  free(t), free(u), free(piv);
  return rc;
}

int runtime_power_vjp(const NpgCtx *c, const char *stage, const char *op, npg_idx n, double *M, double *Mbar,
                      long p, long q, const double *x, double *ybar) {
  if (runtime_check_finite(c, stage, op, n, M, x)) return -1;
  if (q != 1) return root_vjp(c, stage, op, n, M, Mbar, p, q, x, ybar);
  long k = labs(p);
  /* the vectors of the forward products: ws[j] = M^(±j) x */
  double *ws = vec(c, stage, (size_t)n * (size_t)(k + 1)), *t = vec(c, stage, (size_t)n);
  lapack_int *piv = p < 0 ? mem_malloc(sizeof(lapack_int) * (size_t)(n ? n : 1)) : NULL;
  int rc = !ws || !t || (p < 0 && !piv) ? -1 : 0;
  if (rc == 0 && p < 0) rc = runtime_lu(c, stage, op, n, M, piv);
  if (rc == 0) memcpy(ws, x, sizeof(double) * (size_t)n);
  for (long j = 0; j < k && rc == 0; j++) {
    double *from = ws + (size_t)j * (size_t)n, *to = from + n;
    if (p > 0) matvec(n, M, false, from, to);
    else {
      memcpy(to, from, sizeof(double) * (size_t)n);
      rc = runtime_lu_solve(c, stage, n, M, piv, false, to);
    }
  }
  for (long j = k - 1; j >= 0 && rc == 0; j--) {
    const double *from = ws + (size_t)j * (size_t)n, *to = from + n;
    if (p > 0) { /* y = M w: Mbar += ybar w^T, ybar <- M^T ybar */
      cblas_dger(CblasRowMajor, (int)n, (int)n, 1.0, ybar, 1, from, 1, Mbar, (int)n);
      matvec(n, M, true, ybar, t);
      memcpy(ybar, t, sizeof(double) * (size_t)n);
    } else { /* y = M^-1 w: ybar <- M^-T ybar, Mbar -= ybar y^T */
      rc = runtime_lu_solve(c, stage, n, M, piv, true, ybar);
      if (rc == 0) cblas_dger(CblasRowMajor, (int)n, (int)n, -1.0, ybar, 1, to, 1, Mbar, (int)n);
    }
  }
  if (!ws || !t || (p < 0 && !piv)) runtime_record(c, "sample %ld: out of memory in stage '%s'", c->sample, stage);
  free(ws), free(t), free(piv);
  return rc;
}
