/* shapes_hand.h — hand-written C peers of bench_shapes' programs (bench/shapes_hand.c, compiled
 * at -O3 -march=native): what a user would write for the same step, single-threaded. */
#ifndef SHAPES_HAND_H
#define SHAPES_HAND_H

/* One explicit step of examples/heat/heat.npg: out[i] = u[i] + dt k(u[i]) Σ_j (u[nbr[i,j]] − u[i])
 * over the neighbours that exist (nbr[i, j] ≥ 0), k(u) = 1 / (1 + u²). */
void hand_heat_step(long n, const int *nbr, double dt, const double *u, double *out);
/* bench/nbody_pairs.npg: f[p] = (x[b[p]] − x[a[p]]) (|x[b[p]] − x[a[p]]|² + eps)^(−3/2), f [P][3]. */
void hand_pair_forces(long P, const int *a, const int *b, double eps, const double *x, double *f);

#endif
