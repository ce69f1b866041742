"""heat_data.py — data for bench/heat_spd.npg: an n x n grid of cells (its
neighbour table, a source) and S conductivity fields, each a random
combination of four smooth modes (so a reduced model has something to learn).

    /usr/bin/python3 bench/heat_data.py n S OUT [seed]

writes OUT/nbr.npy (int64, N x 4, -1 padding), OUT/src.npy and OUT/kappa.npy
(S x N)."""
import os
import sys

import numpy as np

n, S, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
seed = int(sys.argv[4]) if len(sys.argv) > 4 else 1
N = n * n
idx = np.arange(N).reshape(n, n)
nbr = -np.ones((n, n, 4), dtype=np.int64)
nbr[:, 1:, 0] = idx[:, :-1]
nbr[:, :-1, 1] = idx[:, 1:]
nbr[1:, :, 2] = idx[:-1, :]
nbr[:-1, :, 3] = idx[1:, :]
y, x = np.mgrid[0:n, 0:n] / max(n - 1, 1)
modes = np.stack([np.sin(np.pi * x), np.cos(np.pi * y), np.sin(2 * np.pi * x) * np.sin(np.pi * y),
                  np.cos(2 * np.pi * y)]).reshape(4, N)
rng = np.random.default_rng(seed)
kappa = 1.0 + 0.4 * rng.uniform(-1, 1, (S, 4)) @ modes
src = (np.exp(-((x - 0.3) ** 2 + (y - 0.6) ** 2) / 0.02)).reshape(N)
os.makedirs(out, exist_ok=True)
np.save(os.path.join(out, "nbr.npy"), nbr.reshape(N, 4))
np.save(os.path.join(out, "src.npy"), src)
np.save(os.path.join(out, "kappa.npy"), kappa)
