"""thermalblock_data.py — the thermal block problem of pyMOR's demo, assembled with numpy alone
(P1 finite elements on the unit square cut into grid x grid squares of two triangles each), as
the arrays examples/thermalblock/thermalblock.npg reads, or the same arrays from matrices given.

    python3 thermalblock_data.py OUT --blocks 2x2 --grid 6 --train 16 --test 8 [--seed 1]

writes OUT/data/ (the params and `mu` for --train uniform-random conductivities in [0.1, 1])
and OUT/test/ (the params and --test more). bench/pymor_thermalblock.py writes the same
layout from pyMOR's own matrices (write_params)."""
import argparse
import os
import sys

import numpy as np


def padded(mats, n):
    """The matrices (dense or scipy sparse, n x n) in one padded row pattern: cols (int64,
    -1 padding) and each matrix's values in it."""
    dense = [m.toarray() if hasattr(m, "toarray") else np.asarray(m, dtype=float) for m in mats]
    nz = np.zeros((n, n), dtype=bool)
    for d in dense:
        nz |= d != 0
    w = int(nz.sum(axis=1).max())
    cols = -np.ones((n, w), dtype=np.int64)
    vals = [np.zeros((n, w)) for _ in dense]
    for i in range(n):
        js = np.nonzero(nz[i])[0]
        cols[i, :len(js)] = js
        for v, d in zip(vals, dense):
            v[i, :len(js)] = d[i, js]
    return cols, vals


def assemble(xb, yb, grid):
    """K_b, [K_q], H, f of the thermal block (dense; small grids only)."""
    g = grid
    n = (g + 1) ** 2
    node = lambda ix, iy: iy * (g + 1) + ix
    q_count = xb * yb
    kq = [np.zeros((n, n)) for _ in range(q_count)]
    f = np.zeros(n)
    h = 1.0 / g
    for iy in range(g):
        for ix in range(g):
            a, b, c, d = node(ix, iy), node(ix + 1, iy), node(ix + 1, iy + 1), node(ix, iy + 1)
            for tri in ((a, b, c), (a, c, d)):
                p = np.array([[(t % (g + 1)) * h, (t // (g + 1)) * h] for t in tri])
                cx, cy = p.mean(axis=0)
                q = min(int(cx * xb), xb - 1) + xb * min(int(cy * yb), yb - 1)
                m = np.array([[1, *p[0]], [1, *p[1]], [1, *p[2]]])
                area = abs(np.linalg.det(m)) / 2
                grad = np.linalg.inv(m)[1:, :]          # gradients of the three hat functions
                local = area * grad.T @ grad
                for r in range(3):
                    f[tri[r]] += area / 3
                    for s in range(3):
                        kq[q][tri[r], tri[s]] += local[r, s]
    boundary = np.array([i for i in range(n) if i % (g + 1) in (0, g) or i // (g + 1) in (0, g)])
    kb = np.zeros((n, n))
    kb[boundary, boundary] = 1
    for k in kq:
        k[boundary, :] = 0
        k[:, boundary] = 0
    f[boundary] = 0
    hm = sum(kq) + kb
    return kb, kq, hm, f


def write_params(folder, kb, kq, hm, f, mus):
    os.makedirs(folder, exist_ok=True)
    n = f.shape[0]
    cols, vals = padded([kb, *kq, hm], n)
    np.save(os.path.join(folder, "cols.npy"), cols)
    np.save(os.path.join(folder, "a0.npy"), vals[0])
    np.save(os.path.join(folder, "a.npy"), np.stack(vals[1:-1]))
    np.save(os.path.join(folder, "h.npy"), vals[-1])
    np.save(os.path.join(folder, "f.npy"), np.asarray(f, dtype=float))
    np.save(os.path.join(folder, "mu.npy"), np.asarray(mus, dtype=float))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--blocks", default="2x2")
    ap.add_argument("--grid", type=int, default=6)
    ap.add_argument("--train", type=int, default=16)
    ap.add_argument("--test", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    try:
        xb, yb = (int(v) for v in a.blocks.split("x"))
    except ValueError:
        sys.exit(f"thermalblock_data.py: --blocks {a.blocks}: expected XxY, e.g. 2x2")
    if xb < 1 or yb < 1 or a.grid < 2 or a.grid > 60 or a.train < 1 or a.test < 1:
        sys.exit("thermalblock_data.py: --blocks, --train and --test take positive counts, --grid 2 to 60 "
                 "(dense assembly: pyMOR's grid 100 comes from bench/pymor_thermalblock.sh)")
    rng = np.random.default_rng(a.seed)
    kb, kq, hm, f = assemble(xb, yb, a.grid)
    q = xb * yb
    write_params(os.path.join(a.out, "data"), kb, kq, hm, f, rng.uniform(0.1, 1, (a.train, q)))
    write_params(os.path.join(a.out, "test"), kb, kq, hm, f, rng.uniform(0.1, 1, (a.test, q)))


if __name__ == "__main__":
    main()
