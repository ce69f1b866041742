#!/usr/bin/python3
"""compare_models.py A/ B/ [TOL [SPECTRA_TOL]] [--estimates-subset] — two model folders hold the same
.npy files, equal to TOL (1e-10) relative to each array's largest entry, the singular values
(spectrum_*.npy) to SPECTRA_TOL (TOL unless given); exit 1 naming the first array that differs. With
--estimates-subset B may lack some of A's estimate tables (est_*, theta_*, range_*, interpolation
checks): out of core a class formed block by block gives its stages none (docs/estimates.md).

Out of core the singular values come from Gram matrices, which resolve the small ones only to
about sqrt(machine epsilon) of the largest (the bases and tensors are unaffected): a model trained
out of core is compared to one trained in memory, or over another number of ranks, with
SPECTRA_TOL 1e-7.

The MPI tests train one model on one process and one over ranks: the ranks partition the
samples and the pre-multiplied rows, so sums are taken in another order and agree to rounding."""
import os
import sys

import numpy as np


def estimate_table(name):
    """An array of the online estimate's tables (docs/estimates.md): residual, min-θ, range, check."""
    return name.startswith(("est_", "theta_", "range_")) or (name.startswith("interp_") and "_check_" in name)


def main():
    subset = "--estimates-subset" in sys.argv
    args = [x for x in sys.argv if x != "--estimates-subset"]
    a, b = args[1], args[2]
    tol = float(args[3]) if len(args) > 3 else 1e-10
    spectra_tol = float(args[4]) if len(args) > 4 else tol
    names_a = sorted(f for f in os.listdir(a) if f.endswith(".npy"))
    names_b = sorted(f for f in os.listdir(b) if f.endswith(".npy"))
    if subset:  # B's estimate tables a subset of A's: the others compared as usual
        names_a = [f for f in names_a if not estimate_table(f) or f in names_b]
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
        if name.startswith("est_") and x.ndim == 2 and x.shape[0] == x.shape[1] + 1:
            # R of a residual's QR is unique up to an orthogonal factor where a column is roundoff (a numerator
            # in the basis's span): RᵀR, what the estimate reads (‖R z‖), and the columns' norms are compared
            x, y = (np.vstack([r[:-1].T @ r[:-1], r[-1:]]) for r in (x, y))
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
