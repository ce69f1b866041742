"""Samples for bench/interp.sh (issue 26): bodies on a jittered lattice moved
by a rotation (any angle, or within ±rot), a scale and smooth random modes of
amplitude amp (n-body, Lennard-Jones), or a
cloth-like grid deformed by smooth modes (springs). Deterministic per seed."""
import os
import sys

import numpy as np


def bodies(N, S, seed, amp, spacing, rot=np.pi):
    rng = np.random.default_rng(7)
    k = int(round(N ** (1 / 3)))
    while k ** 3 < N:
        k += 1
    grid = np.array([[i, j, l] for i in range(k) for j in range(k) for l in range(k)], float)[:N]
    base = spacing * (grid + 0.1 * rng.normal(size=(N, 3)))
    modes = rng.normal(size=(4, N, 3)) * spacing
    r = np.random.default_rng(seed)
    out = []
    for _ in range(S):
        t = r.uniform(-rot, rot)
        R = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
        x = base @ R.T * r.uniform(0.95, 1.05)
        out.append(x + np.einsum("k,kvc->vc", amp * r.normal(size=4), modes))
    return np.array(out)


def springs(n, S, seed, amp):
    g = np.array([[i, j, 0.0] for i in range(n) for j in range(n)])
    E = []
    for i in range(n):
        for j in range(n):
            v = i * n + j
            if i + 1 < n:
                E.append((v, v + n))
            if j + 1 < n:
                E.append((v, v + 1))
            if i + 1 < n and j + 1 < n:
                E.append((v, v + n + 1))
    E = np.array(E, dtype=np.int64)
    r = np.random.default_rng(seed)
    u, v = g[:, 0] / n, g[:, 1] / n
    X = []
    for _ in range(S):
        a = r.normal(size=6) * amp
        x = g.copy()
        x[:, 2] += n * (a[0] * np.sin(np.pi * u) * np.sin(np.pi * v) + a[1] * np.sin(2 * np.pi * u) * np.sin(np.pi * v))
        x[:, 0] += n * (a[2] * u * u + 0.5 * a[3] * np.sin(np.pi * v))
        x[:, 1] += n * (a[4] * u * v + 0.3 * a[5] * np.cos(np.pi * u))
        X.append(x)
    return np.array(X), E, np.linalg.norm(g[E[:, 1]] - g[E[:, 0]], axis=1)


def main():
    kind, out, S, seed = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    os.makedirs(out, exist_ok=True)
    if kind.startswith("nbody"):  # nbody:N:eps, or nbody:N:eps:amp:rot (smaller motions, the regime)
        f = kind.split(":")
        N, eps = int(f[1]), f[2]
        amp, rot = (float(f[3]), float(f[4])) if len(f) > 3 else (0.1, np.pi)
        np.save(f"{out}/x.npy", bodies(N, S, seed, amp, 1.0, rot))
        np.save(f"{out}/mass.npy", np.full(N, 1.0 / N))
        np.save(f"{out}/eps.npy", np.array(float(eps)))
    elif kind.startswith("lj"):  # lj:N
        N = int(kind.split(":")[1])
        np.save(f"{out}/x.npy", bodies(N, S, seed, 0.02, 1.12))
    else:  # springs:n
        X, E, L0 = springs(int(kind.split(":")[1]), S, seed, 0.3)
        np.save(f"{out}/x.npy", X)
        np.save(f"{out}/edge.npy", E)
        np.save(f"{out}/L0.npy", L0)


main()
