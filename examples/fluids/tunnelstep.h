/* tunnelstep.h — npg-fluids tunnel-full --dump-step DIR: the wind tunnel's full step
 * (paper Fig. 2, left column, with a fixed obstacle) as the data of the npg program
 * examples/fluids/tunnel_step.npg, and the driver's own trajectory beside it.
 *
 * With the obstacle fixed (--pulse 0) the mesh never moves, h = 0, and every operator of the
 * step is a constant matrix of the mesh: V (cell areas), P (flux to momentum), the graph
 * Laplacian and the advection tensor A(f) (read through the topology tables of
 * fluids2d.npg), and the projection's stream function system: R = C^T P^T (velocity to the
 * right-hand side), S = C^T P^T V^-1 P C (SPD) and C (stream function to flux). DIR/ gets:
 *
 *   params   ucell [U], unbr [U, 3], cface [C, 3], csign [C, 3], area [C], mu, dt,
 *            rcol, rval [Nd, Wr] (R, one row per unknown, padded with -1 and 0),
 *            scol, sval [Nd, Ws] (S the same way), fhead, ftail [F] (the unknowns whose
 *            difference is an interior edge's flux, -1 for none), pval [U, 3] (P's entries
 *            for the three edges cface of the entry's cell);
 *   states   u [1, U] and f [1, F]: frame 0 (the projected uniform flow), one trajectory;
 *   driver/  u [1, T+1, U] and f [1, T+1, F]: the driver's frames 0..T, the layout of
 *            `npgc simulate -o OUT/`.
 *
 * U = 2C velocity entries (entry 2c + d: component d of cell c), Nd the stream function's
 * unknowns (stream.h). */
#ifndef FLUIDS_TUNNELSTEP_H
#define FLUIDS_TUNNELSTEP_H

#include <stddef.h>

#include "solver.h"

/* `s` is the solver after the run (its geometry the fixed one), Su [T][U] and Sf [T][F]
 * the frames 0..T-1 and s->u, s->f frame T. 0, or -1 with the reason in `err`. */
int tunnel_step_dump(const char *dir, const FullSolver *s, const double *Su, const double *Sf, int T, char *err,
                     size_t errlen);

#endif
