/* stream.h — the same projection as projection.h (paper Eq. 10 with
 * div f = 0 and D f = D h), solved in 2D on the constraint's null space with
 * CHOLMOD instead of UMFPACK on the KKT system.
 *
 * Every flux field that is divergence-free in every cell and zero on the
 * boundary is the discrete curl of a stream function psi on the vertices,
 * f_j = psi(b) - psi(a) for edge j = (a, b), where psi is periodic (the two
 * copies of a periodic vertex share one value) and constant on each
 * boundary component (bottom wall, pinned to 0; top wall, whose value is the
 * flux through the tunnel; obstacle). A particular field f_p with
 * div f_p = 0 and f_p = h on the boundary is f_b + G_i^T phi, where
 * G_i G_i^T phi = -G f_b: a graph Laplacian on the cells (one cell pinned),
 * constant, so factored once. The projection is then the SPD system
 *
 *     (C^T K C) psi = C^T (P^T u - K f_p),    K = P^T V^-1 P,
 *
 * assembled from 3x3 element matrices, analysed once and factored by CHOLMOD
 * once per geometry: about as many unknowns as vertices, against faces plus
 * cells for the KKT system. This is a 2D construction (3D needs vector
 * potentials); projection.c's KKT route is the dimension-generic one.
 */
#ifndef FLUIDS_STREAM_H
#define FLUIDS_STREAM_H

#include <stddef.h>

#include "operators.h"

typedef struct StreamProjection StreamProjection;

/* 0, or -1 with the reason in `err` (*out NULL). */
int stream_init(StreamProjection **out, const Ops *o, char *err, size_t errlen);
void stream_free(StreamProjection *s);
/* As projection_solve; seconds of factorization and solve are added to
 * *t_factor and *t_solve. */
int stream_solve(StreamProjection *s, const double *u_in, const double *h, double *f, double *u_out,
                 double *t_factor, double *t_solve, char *err, size_t errlen);

/* The stream function's unknowns on mesh `m` (2D tunnel): dof[v] for every
 * vertex, one per periodic vertex class off the boundary, one for the top
 * wall, one for the obstacle, -1 on the bottom wall (pinned to 0). Returns
 * their count. */
int stream_number_dofs(const FluidMesh *m, int *dof);
/* The local map from cell c's three vertex values of psi to its momentum at
 * positions g (paper §5.3's P applied to the curl): the outward flux through
 * face k is psi_{k+2} - psi_{k+1}, p = sum_k (outward flux) a_k with
 * a_k = (centroid - g_k)/2, so p[d] = sum_q Q[d][q] psi_q. */
void stream_cell_curl(const FluidMesh *m, const double *g, int c, double Q[2][3], double a[3][2]);

#endif
