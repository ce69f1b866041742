#!/usr/bin/env python3
"""burgers_data.py — data folders for burgers.npg (README.md): pyMOR's burgers_ei.py setting,
[0, 2] x [0, 1] periodic, nx x ny cells, T = 0.3 in `steps` steps, initial data
0.5 (sin 2πx sin 2πy + 1); one trajectory per flux blend a.

    burgers_data.py OUT/ --nx 120 --ny 60 --steps 100 --blends 0,0.1,...,1
"""
import argparse
import os

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--nx", type=int, default=120)
    ap.add_argument("--ny", type=int, default=60)
    ap.add_argument("--steps", type=int, default=100, help="time steps over T = 0.3 (pyMOR's nt)")
    ap.add_argument("--blends", default="0,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1",
                    help="the flux blends a, one trajectory each (comma-separated, in [0, 1])")
    a = ap.parse_args()
    nx, ny = a.nx, a.ny
    if nx < 2 or ny < 2 or a.steps < 1:
        raise SystemExit("burgers_data.py: --nx and --ny at least 2, --steps at least 1")
    blends = np.array([float(b) for b in a.blends.split(",")])
    if not np.all((blends >= 0) & (blends <= 1)):
        raise SystemExit("burgers_data.py: every blend is in [0, 1]")
    hx, hy, dt = 2.0 / nx, 1.0 / ny, 0.3 / a.steps
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")  # cell (i, j) is i * ny + j
    west = (((i - 1) % nx) * ny + j).ravel()
    south = (i * ny + (j - 1) % ny).ravel()
    x, y = (i + 0.5) * hx, (j + 0.5) * hy
    u0 = (0.5 * (np.sin(2 * np.pi * x) * np.sin(2 * np.pi * y) + 1)).ravel()
    os.makedirs(a.out, exist_ok=True)
    np.save(os.path.join(a.out, "west.npy"), west.astype(np.int64))
    np.save(os.path.join(a.out, "south.npy"), south.astype(np.int64))
    np.save(os.path.join(a.out, "lx.npy"), np.array(dt / hx))
    np.save(os.path.join(a.out, "ly.npy"), np.array(dt / hy))
    np.save(os.path.join(a.out, "u.npy"), np.tile(u0, (len(blends), 1)))
    np.save(os.path.join(a.out, "a.npy"), blends)


if __name__ == "__main__":
    main()
