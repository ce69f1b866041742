"""bench/implicit_burgers.py with the step written in the language (`residual next u = ...`,
bench/implicit_burgers_step.npg): training by Trainer.add_trajectory and both rollouts by
simulate, each step a Newton solve inside the library (full: npg_full_newton, UMFPACK; reduced:
npg_reduced_newton, LAPACK), to ‖r‖ <= 1e-10 ‖r₀‖ (the default newton_tol).

    PYTHONPATH=build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 bench/implicit_burgers_step.py [NX [NY [STEPS [ENERGY]]]]

The same grid, step (4x the explicit limit), training amplitudes and test amplitudes as
implicit_burgers.py. Times: wall clock of a whole rollout of STEPS steps saving only its first and
last states, divided by STEPS (the full and reduced rollouts in the same process and thread); the
error: the worst over the steps of ‖R − F‖ / ‖F‖, from rollouts saving every step."""
import os
import time

import numpy as np

import npg
from implicit_burgers import initial, problem

HERE = os.path.dirname(os.path.abspath(__file__))


def per_step(run, steps):
    t = time.perf_counter()
    run(steps, every=steps)
    return (time.perf_counter() - t) / steps


def main():
    nx, ny, steps, energy, dt, params = problem()
    prog = npg.compile(os.path.join(HERE, "implicit_burgers_step.npg"))
    full = prog.full(params=params, backend="cc")
    t0 = time.perf_counter()
    tr = npg.Trainer(full, energy=energy, cap=60)
    for amp in np.linspace(0.3, 1.0, 6):
        tr.add_trajectory(steps, u=initial(nx, ny, amp))  # every solved step's pair (u, u.next)
    model = tr.finish()
    m = model.basis("u").shape[1]
    print("N=%d (%dx%d) dt=%.4g (4x explicit) steps=%d, trained on 6 trajectories in %.1f s: m=%d"
          % (nx * ny, nx, ny, dt, steps, time.perf_counter() - t0, m))
    red = model.reduced()
    for amp in (0.55, 0.85):
        u0 = initial(nx, ny, amp)
        F = full.simulate(steps, u=u0)["u"]
        R = red.simulate(steps, u=u0)["u"]
        err = max(np.linalg.norm(r - f) / np.linalg.norm(f) for r, f in zip(R, F))
        tf = per_step(lambda s, every: full.simulate(s, every=every, u=u0), steps)
        tr_ = per_step(lambda s, every: red.simulate(s, every=every, u=u0), steps)
        print("A=%.2f full step %.3f ms, reduced step %.1f us, ratio %.0fx | trajectory error %.2e"
              % (amp, 1e3 * tf, 1e6 * tr_, tf / tr_, err))


if __name__ == "__main__":
    main()
