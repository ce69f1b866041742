/* ff_hand.c — hand-written C peer for the radiosity form-factor program (see ff_hand.h).
 *
 * Written the way one would for gcc -O3 -march=native: per-face quantities (area vectors,
 * centroids, 1/sqrt(a)) first, into structure-of-arrays scratch so the inner loop loads
 * contiguous vectors; then one pass over rows i and columns j that computes all pair stages of
 * entry (i, j) at once and streams them to the seven [F,F] outputs. c[i,j] needs h[j,i]: instead
 * of reading the transposed entry (a strided, cache-hostile access) it is recomputed from the
 * per-face arrays; the operations are the same ones that produce h[j,i], so the value is
 * bit-identical to the stored h[j,i]. The diagonal (r = 1, s = 0 exactly) is written apart so the
 * inner loop has no branch and vectorizes.
 */
#include "ff_hand.h"

#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FF_INV_PI 0.318309886183790671537767526745028724 /* 1/pi */

/* Pair stages of row i for columns j in [j0, j1), j != i. */
static inline void ff_row_span(long F, long i, long j0, long j1, const double *restrict cx,
                               const double *restrict cy, const double *restrict cz,
                               const double *restrict nx, const double *restrict ny,
                               const double *restrict nz, const double sc,
                               const double *restrict v, double *restrict s, double *restrict r, double *restrict h,
                               double *restrict c, double *restrict d, double *restrict p) {
    const double cix = cx[i], ciy = cy[i], ciz = cz[i];
    const double nix = nx[i], niy = ny[i], niz = nz[i];
    const double *restrict vi = v + i * F;
    double *restrict si = s + i * F, *restrict ri = r + i * F, *restrict hi = h + i * F;
    double *restrict ci = c + i * F, *restrict di = d + i * F, *restrict pi_ = p + i * F;
    for (long j = j0; j < j1; j++) {
        const double dx = cx[j] - cix, dy = cy[j] - ciy, dz = cz[j] - ciz; /* c_j - c_i */
        const double sij = nix * dx + niy * dy + niz * dz;                /* s[i,j] */
        const double sji = -(nx[j] * dx + ny[j] * dy + nz[j] * dz);       /* s[j,i] = n_j.(c_i - c_j) */
        const double rij = dx * dx + dy * dy + dz * dz;                   /* r[i,j] = r[j,i] */
        const double hij = sij / rij, hji = sji / rij;
        const double cij = hij * hji * FF_INV_PI;
        const double dij = cij * vi[j];
        si[j] = sij;
        ri[j] = rij;
        hi[j] = hij;
        ci[j] = cij;
        di[j] = dij;
        pi_[j] = dij * sc; /* p[i,j] = d[i,j] / sqrt(a[i]), sc = 1/sqrt(a[i]) */
    }
}

void ff_hand(long F, long V, const double *restrict g, const int *restrict tri,
             const double *restrict v, double *restrict n, double *restrict s, double *restrict r,
             double *restrict h, double *restrict c, double *restrict d, double *restrict a,
             double *restrict p) {
    (void)V;
    /* scratch: centroids cx, cy, cz, area vectors nx, ny, nz, 1/sqrt(a) */
    double *w = malloc((size_t)F * 7 * sizeof *w);
    if (!w) {
        fprintf(stderr, "ff_hand: out of memory for %ld faces\n", F);
        abort();
    }
    double *cx = w, *cy = w + F, *cz = w + 2 * F, *nx = w + 3 * F, *ny = w + 4 * F,
           *nz = w + 5 * F, *ia = w + 6 * F;

    for (long f = 0; f < F; f++) {
        const double *g0 = g + 3 * (long)tri[3 * f], *g1 = g + 3 * (long)tri[3 * f + 1],
                     *g2 = g + 3 * (long)tri[3 * f + 2];
        const double e1x = g1[0] - g0[0], e1y = g1[1] - g0[1], e1z = g1[2] - g0[2];
        const double e2x = g2[0] - g0[0], e2y = g2[1] - g0[1], e2z = g2[2] - g0[2];
        const double fx = 0.5 * (e1y * e2z - e1z * e2y);
        const double fy = 0.5 * (e1z * e2x - e1x * e2z);
        const double fz = 0.5 * (e1x * e2y - e1y * e2x);
        n[3 * f] = nx[f] = fx;
        n[3 * f + 1] = ny[f] = fy;
        n[3 * f + 2] = nz[f] = fz;
        cx[f] = (g0[0] + g1[0] + g2[0]) / 3.0;
        cy[f] = (g0[1] + g1[1] + g2[1]) / 3.0;
        cz[f] = (g0[2] + g1[2] + g2[2]) / 3.0;
        a[f] = fx * fx + fy * fy + fz * fz;
        ia[f] = 1.0 / sqrt(a[f]);
    }

    for (long i = 0; i < F; i++) {
        ff_row_span(F, i, 0, i, cx, cy, cz, nx, ny, nz, ia[i], v, s, r, h, c, d, p);
        ff_row_span(F, i, i + 1, F, cx, cy, cz, nx, ny, nz, ia[i], v, s, r, h, c, d, p);
        /* diagonal: s = n_i . (c_i - c_i) = 0, r = 1, so h = c = d = p = 0 */
        const long ii = i * F + i;
        s[ii] = 0.0;
        r[ii] = 1.0;
        h[ii] = 0.0;
        c[ii] = 0.0;
        d[ii] = 0.0 * v[ii];
        p[ii] = d[ii] * ia[i];
    }
    free(w);
}

int ff_radiosity_solve(long F, const double *rho, const double *p, const double *e, double *b) {
    double *M = malloc((size_t)F * (size_t)F * sizeof *M);
    lapack_int *ipiv = malloc((size_t)F * sizeof *ipiv);
    if (!M || !ipiv) {
        free(M), free(ipiv);
        return -1;
    }
    for (long i = 0; i < F; i++) {
        const double ri = rho[i];
        const double *pi_ = p + i * F;
        double *Mi = M + i * F;
        for (long j = 0; j < F; j++) Mi[j] = -ri * pi_[j];
        Mi[i] += 1.0;
    }
    memcpy(b, e, (size_t)F * sizeof *b);
    lapack_int info = LAPACKE_dgesv(LAPACK_ROW_MAJOR, (lapack_int)F, 1, M, (lapack_int)F, ipiv, b, 1);
    free(M), free(ipiv);
    return (int)info;
}
