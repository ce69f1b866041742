#!/usr/bin/env python3
"""heat_data.py — data folders for the heat examples (README.md): the grid's neighbour table,
the time step and each trajectory's initial state, a Gaussian bump of random height, width and
centre (seeded: the same folder every time).

    heat_data.py OUT/ --n 128 --trajectories 8 [--seed 1] [--dt 0.2] [--amplitude 0.5:1.5]
                      [--source held|steps:T] [--random]

--source adds the input f of heat_linear.npg: held (one per trajectory) or given per step for T
steps. --random: initial states of independent random entries instead of bumps (they span every
direction: the bases of a model trained on N of them are whole).
"""
import argparse
import os
import sys

import numpy as np


def neighbours(n):
    """nbr[c, k]: the k-th of the four neighbours of cell c of an n x n grid, -1 off the grid."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = i * n + j
    nbr = np.stack([np.where(i > 0, c - n, -1), np.where(i < n - 1, c + n, -1),
                    np.where(j > 0, c - 1, -1), np.where(j < n - 1, c + 1, -1)], axis=-1)
    return nbr.reshape(n * n, 4).astype(np.int64)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--n", type=int, default=128, help="grid side (N = n * n cells)")
    ap.add_argument("--trajectories", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--dt", type=float, default=0.2, help="time step (explicit Euler is stable up to 0.25)")
    ap.add_argument("--amplitude", default="0.5:1.5", help="range of the bumps' heights, LO:HI")
    ap.add_argument("--source", default=None, help="held, or steps:T (heat_linear.npg's input f)")
    ap.add_argument("--random", action="store_true", help="random initial states instead of bumps")
    a = ap.parse_args()
    if a.n < 2 or a.trajectories < 1:
        sys.exit("heat_data.py: --n must be at least 2 and --trajectories at least 1")
    lo, hi = (float(v) for v in a.amplitude.split(":"))
    rng = np.random.default_rng(a.seed)
    n, S = a.n, a.trajectories
    x = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(x, x, indexing="ij")
    if a.random:
        u = rng.uniform(-1, 1, (S, n * n))
    else:
        u = np.empty((S, n * n))
        for s in range(S):
            h, w = rng.uniform(lo, hi), rng.uniform(8, 30)
            cx, cy = rng.uniform(0.3, 0.7, 2)
            u[s] = (h * np.exp(-w * ((X - cx) ** 2 + (Y - cy) ** 2))).ravel()
    os.makedirs(a.out, exist_ok=True)
    np.save(os.path.join(a.out, "nbr.npy"), neighbours(n))
    np.save(os.path.join(a.out, "dt.npy"), np.array(a.dt))
    np.save(os.path.join(a.out, "u.npy"), u)
    if a.source:
        shape = (S, n * n) if a.source == "held" else (S, int(a.source.split(":")[1]), n * n)
        np.save(os.path.join(a.out, "f.npy"), rng.uniform(-0.05, 0.05, shape))


if __name__ == "__main__":
    main()
