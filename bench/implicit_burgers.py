"""Burgers' equation implicit in time: the full implicit step (npg_full_newton: the Jacobian on
its sparse pattern, UMFPACK) against the reduced one (npg_reduced_newton: m x m, LAPACK), per-step
time and trajectory error (issue 43's goal: >= 100x faster per step at <= 1e-3 error).

    PYTHONPATH=build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 bench/implicit_burgers.py [NX [NY [STEPS [ENERGY]]]]

bench/implicit_burgers.npg is the backward-Euler residual on an NX x NY periodic grid (upwind,
u > 0) at a step 4x the explicit (CFL) limit. Training: full implicit trajectories (Full.newton)
from initial states 1 + A g(x, y), a Gaussian g of amplitude A in [0.3, 1.0] (6 of them); test:
A = 0.55 and 0.85, not trained. Each trajectory is rolled out by both models from the same start
(the reduced one in coordinates, Newton from the previous state); the error is the worst over the
steps of ‖B ĉ − u‖ / ‖u‖ against the full trajectory. Times: wall clock per step (Newton to
‖r‖ <= 1e-10 ‖u‖ in full, the same relative tolerance in reduced coordinates), the median of the
test steps, the same process and thread (OPENBLAS_NUM_THREADS=1)."""
import os
import sys
import time

import numpy as np

import npg

HERE = os.path.dirname(os.path.abspath(__file__))


def grid(nx, ny):
    c = np.arange(nx * ny).reshape(nx, ny)
    west = np.roll(c, 1, axis=0).ravel()
    south = np.roll(c, 1, axis=1).ravel()
    return west.astype(np.int64), south.astype(np.int64)


def initial(nx, ny, amp):
    x, y = np.meshgrid(np.linspace(0, 2, nx, endpoint=False), np.linspace(0, 1, ny, endpoint=False), indexing="ij")
    return (1 + amp * np.exp(-((x - 0.6) ** 2 + (y - 0.5) ** 2) / 0.15 ** 2)).ravel()


def full_rollout(full, u, steps, times=None):
    out = [u]
    for k in range(steps):
        t = time.perf_counter()
        u, _ = full.newton("r", "v", tol=1e-10 * np.linalg.norm(u), max_iter=30, sample=k, u=u, v=u)
        if times is not None:
            times.append(time.perf_counter() - t)
        out.append(u)
    return np.array(out)


def reduced_rollout(red, B, u0, steps, times):
    c = B.T @ u0
    out = [c]
    for k in range(steps):
        t = time.perf_counter()
        red.set_coords("u", c)
        red.set_coords("v", c)
        c, _ = red.newton("r", "v", tol=1e-10 * np.linalg.norm(c), max_iter=30, sample=k)
        times.append(time.perf_counter() - t)
        out.append(c)
    return np.array(out)


def problem():
    """NX, NY, STEPS, ENERGY from the command line, the time step and the params."""
    nx = int(sys.argv[1]) if len(sys.argv) > 1 else 128
    ny = int(sys.argv[2]) if len(sys.argv) > 2 else 64
    steps = int(sys.argv[3]) if len(sys.argv) > 3 else 40
    energy = float(sys.argv[4]) if len(sys.argv) > 4 else 0.999
    hx, hy = 2 / nx, 1 / ny
    umax = 2.0
    dt = 4 * min(hx, hy) / umax / 2  # explicit upwind: dt (1/hx + 1/hy) umax <= 1; 4x that
    west, south = grid(nx, ny)
    params = {"west": west, "south": south, "lx": np.array(dt / hx), "ly": np.array(dt / hy)}
    return nx, ny, steps, energy, dt, params


def main():
    nx, ny, steps, energy, dt, params = problem()
    prog = npg.compile(open(os.path.join(HERE, "implicit_burgers.npg")).read(), name="implicit_burgers.npg")
    full = prog.full(params=params, backend="cc")
    t0 = time.perf_counter()
    tr = npg.Trainer(full, energy=energy, cap=60)
    for amp in np.linspace(0.3, 1.0, 6):
        traj = full_rollout(full, initial(nx, ny, amp), steps)
        for k in range(steps):
            tr.add(u=traj[k], v=traj[k + 1])
    model = tr.finish()
    B = model.basis("u")
    print("N=%d (%dx%d) dt=%.4g (4x explicit) steps=%d, trained on 6 trajectories in %.1f s: m=%d"
          % (nx * ny, nx, ny, dt, steps, time.perf_counter() - t0, B.shape[1]))
    red = model.reduced()
    for amp in (0.55, 0.85):
        u0 = initial(nx, ny, amp)
        tf, tr_ = [], []
        traj = full_rollout(full, u0, steps, tf)
        coords = reduced_rollout(red, B, u0, steps, tr_)
        err = max(np.linalg.norm(B @ c - u) / np.linalg.norm(u) for c, u in zip(coords, traj))
        floor = max(np.linalg.norm(B @ (B.T @ u) - u) / np.linalg.norm(u) for u in traj)
        f, r = np.median(tf), np.median(tr_)
        print("A=%.2f full step %.3f ms, reduced step %.1f us, ratio %.0fx | trajectory error %.2e (projection floor "
              "%.2e)" % (amp, 1e3 * f, 1e6 * r, f / r, err, floor))


if __name__ == "__main__":
    main()
