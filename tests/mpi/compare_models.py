#!/usr/bin/python3
"""compare_models.py A/ B/ [TOL] — two model folders hold the same .npy files, equal to TOL
(1e-10) relative to each array's largest entry; exit 1 naming the first array that differs.

The MPI tests train one model on one process and one over ranks: the ranks partition the
samples and the pre-multiplied rows, so sums are taken in another order and agree to rounding."""
import os
import sys

import numpy as np


def main():
    a, b = sys.argv[1], sys.argv[2]
    tol = float(sys.argv[3]) if len(sys.argv) > 3 else 1e-10
    names_a = sorted(f for f in os.listdir(a) if f.endswith(".npy"))
    names_b = sorted(f for f in os.listdir(b) if f.endswith(".npy"))
    if names_a != names_b or not names_a:
        print(f"compare_models: {a} holds {names_a}, {b} holds {names_b}")
        return 1
    worst = 0.0
    for name in names_a:
        x, y = np.load(os.path.join(a, name)), np.load(os.path.join(b, name))
        if x.shape != y.shape or x.dtype != y.dtype:
            print(f"compare_models: {name}: {x.shape} {x.dtype} against {y.shape} {y.dtype}")
            return 1
        if x.size == 0:
            continue
        scale = max(1.0, float(np.max(np.abs(x))))
        d = float(np.max(np.abs(x.astype(np.float64) - y.astype(np.float64)))) / scale
        worst = max(worst, d)
        if not d <= tol:
            print(f"compare_models: {name}: differs by {d:.3g} (relative to its largest entry), above {tol:g}")
            return 1
    print(f"compare_models: {len(names_a)} arrays equal, largest relative difference {worst:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
