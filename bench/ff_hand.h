/* ff_hand.h — hand-written C peer for the full evaluator of examples/radiosity/formfactors.npg.
 *
 * Computes every stage of the program with the formulas of DESIGN §3 (docs/design.md) / paper Table 2:
 *
 *   n[f]   = 0.5 * cross(g[t1] - g[t0], g[t2] - g[t0])        area vector, |n| = A     [F,3]
 *   s[i,j] = dot(n[i], c_j - c_i)    (c = triangle centroid)   scaled cosines           [F,F]
 *   r[i,j] = i == j ? 1 : |c_i - c_j|^2                         squared distances        [F,F]
 *   h[i,j] = s[i,j] / r[i,j]                                    half form factors        [F,F]
 *   c[i,j] = h[i,j] * h[j,i] / pi                               visibility-free FF       [F,F]
 *   d[i,j] = c[i,j] * v[i,j]                                    area-free FF             [F,F]
 *   a[i]   = dot(n[i], n[i])                                    squared areas            [F]
 *   p[i,j] = d[i,j] / sqrt(a[i])                                form factors F_ij        [F,F]
 *
 * Pair quantities are row-major [F,F] (index i*F + j). Every stage is computed and stored.
 */
#ifndef NPG_BENCH_FF_HAND_H
#define NPG_BENCH_FF_HAND_H

/* g: V*3 vertex positions, tri: F*3 vertex indices (each in [0, V)), v: F*F visibility.
 * Outputs n (F*3), s, r, h, c, d, p (F*F each) and a (F). Single-threaded. Aborts with a
 * message on stderr only if its O(F) scratch cannot be allocated. */
void ff_hand(long F, long V, const double *g, const int *tri, const double *v, double *n, double *s,
             double *r, double *h, double *c, double *d, double *a, double *p);

/* Radiosity b = (I - diag(rho) p)^-1 e by LU (LAPACKE_dgesv). p is the F*F form-factor matrix
 * from ff_hand, rho and e have F entries, b receives F entries. Returns 0 on success, the
 * LAPACK info (> 0: the matrix is singular) or -1 when memory runs out. */
int ff_radiosity_solve(long F, const double *rho, const double *p, const double *e, double *b);

#endif
