/* tunnelstep.h — npg-fluids tunnel-full --dump-step DIR: the wind tunnel's full step
 * (paper Fig. 2, left column) as the data of the npg programs examples/fluids/tunnel_step.npg
 * (fixed obstacle) and tunnel_step_moving.npg (the obstacle pulsing, the mesh deforming), and
 * the driver's own trajectory beside it.
 *
 * With the obstacle fixed (--pulse 0) the mesh never moves, h = 0, and every operator of the
 * step is a constant matrix of the mesh: V (cell areas), P (flux to momentum), the graph
 * Laplacian and the advection tensor A(f) (read through the topology tables of
 * fluids2d.npg), and the projection's stream function system: R = C^T P^T (velocity to the
 * right-hand side), S = C^T P^T V^-1 P C (SPD) and C (stream function to flux). When the mesh
 * moves, the operators are rebuilt from the positions each step, and the tables say which
 * positions each entry reads. DIR/ gets:
 *
 *   both     ucell [U], unbr [U, 3], cface [C, 3], csign [C, 3], mu, dt, fhead, ftail [F]
 *            (the unknowns whose difference is an interior edge's flux, -1 for none);
 *   fixed    (--pulse 0 only) area [C], rcol, rval [Nd, Wr] (R, one row per unknown, padded
 *            with -1 and 0), scol, sval [Nd, Ws] (S the same way), pval [U, 3] (P's entries for
 *            the three edges cface of the entry's cell);
 *   moving   tri [C, 3], edge [F, 2], ucomp [U], fint [F] (1: interior edge), fbnd [F] (1 - fint), fc0, fc1 [F] (its
 *            cells, -1 for the pinned one), lcol, lval [C, Wl] (the cells' graph Laplacian, the
 *            last cell pinned), cfree [C], the contributions to R's rows rx, ry (the cell's two velocity
 *            entries), rv1, rv2 [Nd, Wr'] and to S's rows: its diagonal squares dcell, d1, d2 [Nd, Wd] and the
 *            other products mcol, mcell, mp1, mp2, mq1, mq2 [Nd, Ws'] (cell c's curl
 *            column of vertex q is (g[v2] - g[v1]) / 2 with v1, v2 its other two vertices), and
 *            the positions per step g, gn [1, T, V, 2] (g_t and g_{t+1});
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

/* `s` is the solver after the run, Su [T][U], Sf [T][F] and Sg [T][V][2] the frames 0..T-1
 * and s->u, s->f, s->g frame T; `moving` (the obstacle pulsed) leaves out the fixed step's
 * operators. 0, or -1 with the reason in `err`. */
int tunnel_step_dump(const char *dir, const FullSolver *s, const double *Su, const double *Sf, const double *Sg, int T,
                     int moving, char *err, size_t errlen);

#endif
