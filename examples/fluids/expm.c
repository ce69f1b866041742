/* expm.c — the matrix exponential of the reduced step (reduced.h): exp(X) by scaling and
 * squaring with Padé approximants (Higham 2005; degrees chosen as Al-Mohy and Higham 2009),
 * and exp(ΔtM) û by Arnoldi with the small exponential done by the former (Saad 1992). */
#include "reduced.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <cblas.h>
#include <lapacke.h>

/* ---------------------------------------------------------------- expm */

/* Padé coefficients b_0..b_m of degree m (Higham 2005, Table 2.3 / Eq. 10.33). */
static const double pade3[] = {120, 60, 12, 1};
static const double pade5[] = {30240, 15120, 3360, 420, 30, 1};
static const double pade7[] = {17297280, 8648640, 1995840, 277200, 25200, 1512, 56, 1};
static const double pade9[] = {17643225600., 8821612800., 2075673600., 302702400., 30270240.,
                               2162160.,     110880.,     3960.,       90.,        1.};
static const double pade13[] = {64764752532480000., 32382376266240000., 7771770303897600., 1187353796428800.,
                                 129060195264000.,   10559470521600.,    670442572800.,     33522128640.,
                                 1323241920.,        40840800.,          960960.,           16380.,
                                 182.,               1.};
/* theta_m: the largest 1-norm for which degree m without scaling meets unit roundoff. */
static const double theta[] = {1.495585217958292e-2, 2.539398330063230e-1, 9.504178996162932e-1,
                               2.097847961257068e0, 5.371920351148152e0};

static void mm(int n, const double *a, const double *b, double *c) {
  cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, n, n, n, 1.0, a, n, b, n, 0.0, c, n);
}

/* out = Σ_k coef[k] * mats[k] (+ c0 I). */
static void lincomb(int n, double *out, int nm, const double *const *mats, const double *coef, double c0) {
  size_t nn = (size_t)n * n;
  for (size_t i = 0; i < nn; i++) {
    double v = 0;
    for (int k = 0; k < nm; k++) v += coef[k] * mats[k][i];
    out[i] = v;
  }
  for (int i = 0; i < n; i++) out[(size_t)i * n + i] += c0;
}

static double norm1(int n, const double *A) {
  double norm = 0;
  for (int j = 0; j < n; j++) {
    double s = 0;
    for (int i = 0; i < n; i++) s += fabs(A[(size_t)i * n + j]);
    if (s > norm) norm = s;
  }
  return norm;
}

int red_expm(int n, const double *X, double *out, double *work, int *pade, int *squarings) {
  size_t nn = (size_t)n * n;
  double *Xs = work, *A2 = work + nn, *A4 = work + 2 * nn, *A6 = work + 3 * nn, *A8 = work + 4 * nn;
  double *T = work + 5 * nn, *U = work + 6 * nn, *Vm = work + 7 * nn;
  double norm = norm1(n, X);
  /* Degree and scaling (Al-Mohy and Higham 2009): from ‖X^k‖^(1/k) of the
   * powers computed anyway, which for a nearly normal X (reduced advection
   * is V̂-skew) is far below ‖X‖ and allows a lower degree. */
  size_t bytes = nn * sizeof *Xs;
  memcpy(Xs, X, bytes);
  mm(n, Xs, Xs, A2);
  mm(n, A2, A2, A4);
  mm(n, A2, A4, A6);
  double d4 = pow(norm1(n, A4), 0.25), d6 = pow(norm1(n, A6), 1.0 / 6);
  double eta1 = fmax(d4, d6);
  int deg = 13, s = 0;
  if (norm <= theta[0] || eta1 <= theta[0]) deg = 3;
  else if (eta1 <= theta[1]) deg = 5;
  else {
    /* ‖X^8‖ ≤ ‖X^4‖², ‖X^10‖ ≤ ‖X^4‖ ‖X^6‖ (cheap bounds instead of estimates) */
    double d8 = pow(norm1(n, A4) * norm1(n, A4), 1.0 / 8), d10 = pow(norm1(n, A4) * norm1(n, A6), 1.0 / 10);
    double eta3 = fmax(d6, d8);
    if (eta3 <= theta[2]) deg = 7;
    else if (eta3 <= theta[3]) deg = 9;
    else {
      double eta5 = fmin(eta3, fmax(d8, d10));
      if (eta5 > theta[4]) s = (int)ceil(log2(eta5 / theta[4]));
    }
  }
  if (s > 0) {
    double sc = ldexp(1.0, -s);
    for (size_t i = 0; i < nn; i++) Xs[i] *= sc;
    mm(n, Xs, Xs, A2);
    mm(n, A2, A2, A4);
    mm(n, A2, A4, A6);
  }
  if (deg == 9) mm(n, A4, A4, A8);
  if (deg == 13) {
    const double *b = pade13;
    lincomb(n, T, 3, (const double *[]){A6, A4, A2}, (double[]){b[13], b[11], b[9]}, 0);
    mm(n, A6, T, U);
    for (size_t i = 0; i < nn; i++) U[i] += b[7] * A6[i] + b[5] * A4[i] + b[3] * A2[i];
    for (int i = 0; i < n; i++) U[(size_t)i * n + i] += b[1];
    mm(n, Xs, U, T);
    memcpy(U, T, nn * sizeof *U);
    lincomb(n, T, 3, (const double *[]){A6, A4, A2}, (double[]){b[12], b[10], b[8]}, 0);
    mm(n, A6, T, Vm);
    for (size_t i = 0; i < nn; i++) Vm[i] += b[6] * A6[i] + b[4] * A4[i] + b[2] * A2[i];
    for (int i = 0; i < n; i++) Vm[(size_t)i * n + i] += b[0];
  } else {
    const double *b = deg == 3 ? pade3 : deg == 5 ? pade5 : deg == 7 ? pade7 : pade9;
    const double *pw[4] = {A2, A4, A6, A8};
    int np = (deg - 1) / 2; /* even powers A^2 .. A^(deg-1) */
    double cu[4], cv[4];
    for (int k = 0; k < np; k++) cu[k] = b[2 * k + 3], cv[k] = b[2 * k + 2];
    lincomb(n, T, np, pw, cu, b[1]);
    mm(n, Xs, T, U);
    lincomb(n, Vm, np, pw, cv, b[0]);
  }
  /* (V - U) R = (V + U). V and U are polynomials in X, so they commute and
   * R = (V + U)(V - U)⁻¹ too: read column-major, the arrays hold the
   * transposes, and Rᵀ = (V - U)⁻ᵀ(V + U)ᵀ is LAPACK's column-major solve
   * (without LAPACKE's row-major transposes) */
  for (size_t i = 0; i < nn; i++) {
    double v = Vm[i], u = U[i];
    T[i] = v - u;
    out[i] = v + u;
  }
  lapack_int *ipiv = malloc(sizeof *ipiv * (size_t)n);
  if (!ipiv) return -1;
  lapack_int info = LAPACKE_dgesv_work(LAPACK_COL_MAJOR, n, n, T, n, ipiv, out, n);
  free(ipiv);
  if (info != 0) return -1;
  for (int k = 0; k < s; k++) {
    mm(n, out, out, T);
    memcpy(out, T, nn * sizeof *out);
  }
  if (pade) *pade = deg;
  if (squarings) *squarings = s;
  return 0;
}

/* ---------------------------------------------------------------- exp(ΔtM) û by Arnoldi */

int red_expmv(RedSolver *s, const double *S, const double *Vf, double dt, const double *u, double *y, double tol) {
  int n = (int)s->mu, kmax = s->kmax;
  double *Q = s->Q, *H = s->H, *c = s->hwork + 9 * (size_t)kmax * kmax, *Hm = s->hwork + 8 * (size_t)kmax * kmax;
  /* w = Lᵀu: advection is V̂-skew, so L⁻¹ S L⁻ᵀ is skew and exp of the
   * (then skew tridiagonal) Hessenberg matrix orthogonal: the energy
   * ½‖w‖² is kept to rounding whatever the truncation */
  memcpy(Q, u, (size_t)n * sizeof *Q);
  cblas_dtrmv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, n, Vf, n, Q, 1);
  double beta = cblas_dnrm2(n, Q, 1);
  if (beta == 0) {
    memset(y, 0, (size_t)n * sizeof *y);
    return 0;
  }
  cblas_dscal(n, 1.0 / beta, Q, 1);
  memset(H, 0, (size_t)(kmax + 1) * (size_t)kmax * sizeof *H);
  for (int j = 0; j < kmax; j++) {
    double *qj = Q + (size_t)j * n, *w = Q + (size_t)(j + 1) * n;
    /* w = Δt L⁻¹ S L⁻ᵀ q_j */
    memcpy(c, qj, (size_t)n * sizeof *c);
    cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, n, Vf, n, c, 1);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, dt, S, n, c, 1, 0.0, w, 1);
    cblas_dtrsv(CblasRowMajor, CblasLower, CblasNoTrans, CblasNonUnit, n, Vf, n, w, 1);
    /* orthogonalize against q_0 … q_j, twice */
    for (int pass = 0; pass < 2; pass++) {
      cblas_dgemv(CblasRowMajor, CblasNoTrans, j + 1, n, 1.0, Q, n, w, 1, 0.0, c, 1);
      cblas_dgemv(CblasRowMajor, CblasTrans, j + 1, n, -1.0, Q, n, c, 1, 1.0, w, 1);
      for (int i = 0; i <= j; i++) H[(size_t)i * kmax + j] += c[i];
    }
    double h = cblas_dnrm2(n, w, 1);
    H[(size_t)(j + 1) * kmax + j] = h;
    int m = j + 1;
    double scale = 0;
    for (int i = 0; i <= j; i++) scale = fmax(scale, fabs(H[(size_t)i * kmax + j]));
    int invariant = h <= 1e-14 * (scale + 1e-300) || m == n;
    if (invariant || (m >= 4 && m % 2 == 0)) {
      for (int i = 0; i < m; i++) memcpy(Hm + (size_t)i * m, H + (size_t)i * kmax, (size_t)m * sizeof *Hm);
      if (red_expm(m, Hm, s->Hx, s->hwork, NULL, NULL) != 0) return -1;
      /* the error of β Q_m exp(H_m) e₁: about β h_{m+1,m} |e_mᵀ exp(H_m) e₁| (Saad 1992) */
      if (invariant || h * fabs(s->Hx[(size_t)(m - 1) * m]) <= tol) {
        for (int i = 0; i < m; i++) c[i] = beta * s->Hx[(size_t)i * m];
        cblas_dgemv(CblasRowMajor, CblasTrans, m, n, 1.0, Q, n, c, 1, 0.0, y, 1);
        cblas_dtrsv(CblasRowMajor, CblasLower, CblasTrans, CblasNonUnit, n, Vf, n, y, 1); /* u = L⁻ᵀ w */
        return m;
      }
    }
    cblas_dscal(n, 1.0 / h, w, 1);
  }
  return -1;
}
