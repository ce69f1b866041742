"""width_bound.py OUT [N ...] — a lower bound on the error of ANY N-vector reduced space on the thermal block's
test parameters that bench/pymor_thermalblock.py exported to OUT/test (run from the repository root; N 20 30 by
default). With U the test solutions (scipy's sparse LU of the same matrices) and λ_j the eigenvalues of their Gram
matrix in the H¹₀ product, every N-dimensional space V has Σ_k dist(u_k, V)² ≥ Σ_{j>N} λ_j (Eckart–Young: the best
N-dimensional space for these S samples in that sum is their own leading singular space), so its max error over the
S samples is at least √(Σ_{j>N} λ_j / S) — whatever the method or its training. It measures how far a goal such as
"error ≤ 1e-11 at 30 vectors" is from what the problem allows."""
import os
import sys

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spl

t = os.path.join(sys.argv[1], "test")
sizes = [int(v) for v in sys.argv[2:]] or [20, 30]
cols, a0, a, h, f, mu = (np.load(os.path.join(t, n + ".npy")) for n in ("cols", "a0", "a", "h", "f", "mu"))
N, W = cols.shape
rows, ok = np.repeat(np.arange(N), W), cols.ravel() >= 0


def mat(v):
    return sps.csr_matrix((v.ravel()[ok], (rows[ok], cols.ravel()[ok])), shape=(N, N))


H, A0, A = mat(h), mat(a0), [mat(a[q]) for q in range(a.shape[0])]
U = np.array([spl.spsolve((A0 + sum(m[q] * A[q] for q in range(len(A)))).tocsc(), f) for m in mu])
G = U @ (H @ U.T)
lam = np.sort(np.linalg.eigvalsh((G + G.T) / 2))[::-1]
norm = np.sqrt(np.max(np.diag(G)))
for n in sizes:
    lb = np.sqrt(max(lam[n:].sum(), 0.0) / len(mu))
    print("%d unknowns, %d test parameters: any %d-vector space errs at least %.3e in H¹₀ on one of them "
          "(%.2e of the largest solution's norm)" % (N, len(mu), n, lb, lb / norm))
