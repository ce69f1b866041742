#!/usr/bin/env python3
"""recheck.py DIR — re-check `npg-radiosity full` output independently with numpy.

For every frame in DIR/<animation>/frame_NNNN/: Eq. 15 form factors from g.npy, the
scene's tri.npy and the ray-cast v.npy (area vectors n = (g1 - g0) x (g2 - g0) / 2,
F_ij = (n_i . (c_j - c_i)) (n_j . (c_i - c_j)) v_ij / (pi |c_i - c_j|^4 |n_i|)), then
b = (I - diag(rho) F)^-1 e by numpy's LU, compared with b_full.npy. Also checks that v is
symmetric, in [0, 1], zero on the diagonal and wherever a face lies behind the other.
Exits 1 when a frame differs by more than 1e-10 relative.
"""
import glob
import os
import sys

import numpy as np


def main(root):
    tri = np.load(os.path.join(root, "tri.npy"))
    rho = np.load(os.path.join(root, "rho.npy"))
    e = np.load(os.path.join(root, "e.npy"))
    frames = sorted(glob.glob(os.path.join(root, "*", "frame_*", "b_full.npy")))
    if not frames:
        print(f"recheck: no frames under {root}")
        return 1
    worst = 0.0
    for path in frames:
        d = os.path.dirname(path)
        g = np.load(os.path.join(d, "g.npy"))
        v = np.load(os.path.join(d, "v.npy"))
        b_full = np.load(path)
        p0, p1, p2 = g[tri[:, 0]], g[tri[:, 1]], g[tri[:, 2]]
        n = 0.5 * np.cross(p1 - p0, p2 - p0)
        c = (p0 + p1 + p2) / 3
        diff = c[None, :, :] - c[:, None, :]            # c_j - c_i at [i, j]
        s = np.einsum("ik,ijk->ij", n, diff)            # n_i . (c_j - c_i)
        r = np.einsum("ijk,ijk->ij", diff, diff)
        np.fill_diagonal(r, 1.0)
        behind = (s <= 0) | (s.T <= 0)
        assert np.array_equal(v, v.T), f"{d}: v is not symmetric"
        assert v.min() >= 0 and v.max() <= 1, f"{d}: v outside [0, 1]"
        assert not np.any(v[behind]), f"{d}: v > 0 where a face lies behind the other"
        area = np.linalg.norm(n, axis=1)
        F = s * s.T * v / (np.pi * r * r * area[:, None])
        b = np.linalg.solve(np.eye(len(e)) - rho[:, None] * F, e)
        err = np.abs(b - b_full).max() / np.abs(b).max()
        worst = max(worst, err)
        if err > 1e-10:
            print(f"recheck: {d}: b differs from numpy's by {err:.3g} relative")
            return 1
    print(f"recheck: {len(frames)} frames of {len(e)} faces agree with numpy to {worst:.2g}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__)
        sys.exit(2)
    sys.exit(main(sys.argv[1]))
