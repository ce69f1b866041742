#!/usr/bin/python3
"""compare_models.py A/ B/ [TOL [SPECTRA_TOL]] — two model folders hold the same .npy files, equal to
TOL (1e-10) relative to each array's largest entry, the singular values (spectrum_*.npy) to
SPECTRA_TOL (TOL unless given); exit 1 naming the first array that differs.

Out of core the singular values come from Gram matrices, which resolve the small ones only to
about sqrt(machine epsilon) of the largest (the bases and tensors are unaffected): a model trained
out of core is compared to one trained in memory, or over another number of ranks, with
SPECTRA_TOL 1e-7.

The MPI tests train one model on one process and one over ranks: the ranks partition the
samples and the pre-multiplied rows, so sums are taken in another order and agree to rounding."""
import os
import sys

import numpy as np


def main():
    a, b = sys.argv[1], sys.argv[2]
    tol = float(sys.argv[3]) if len(sys.argv) > 3 else 1e-10
    spectra_tol = float(sys.argv[4]) if len(sys.argv) > 4 else tol
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
        if not name.startswith("spectrum_"):
            worst = max(worst, d)
        limit = spectra_tol if name.startswith("spectrum_") else tol
        if not d <= limit:
            print(f"compare_models: {name}: differs by {d:.3g} (relative to its largest entry), above {limit:g}")
            return 1
    print(f"compare_models: {len(names_a)} arrays equal, largest relative difference {worst:.3g} "
          f"(singular values: within {spectra_tol:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
