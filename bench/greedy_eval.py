"""greedy_eval.py NPGC OUT MODEL — a thermal-block model's max H¹₀ error and estimate effectivity on the test
parameters bench/pymor_thermalblock.py exported to OUT/test (run from the repository root): the true solutions by
scipy's sparse LU of the same matrices (pyMOR's to rounding), the reduced ones and their estimates by `npgc eval`.
For a model trained apart from the bench (a greedy run resumed, a size of its own): bench/thermalblock.md."""
import os, subprocess, sys, tempfile
import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spl
npgc, d, model = sys.argv[1:4]
t = os.path.join(d, "test")
cols, a0, a, h, f, mu = (np.load(os.path.join(t, n + ".npy")) for n in ("cols", "a0", "a", "h", "f", "mu"))
N, W = cols.shape
rows = np.repeat(np.arange(N), W)
ok = cols.ravel() >= 0
def mat(v):
    return sps.csr_matrix((v.ravel()[ok], (rows[ok], cols.ravel()[ok])), shape=(N, N))
H, A0, A = mat(h), mat(a0), [mat(a[q]) for q in range(a.shape[0])]
U = np.array([spl.spsolve((A0 + sum(m[q] * A[q] for q in range(len(A)))).tocsc(), f) for m in mu])
with tempfile.TemporaryDirectory() as o:
    subprocess.run([npgc, "eval", "examples/thermalblock/thermalblock.npg", model, t, "-o", o], check=True, capture_output=True)
    V, est = np.load(os.path.join(o, "u.npy")), np.load(os.path.join(o, "u.estimate.npy")).ravel()
E = U - V
err = np.sqrt(np.einsum("ij,ij->i", E, (H @ E.T).T))
nrm = np.sqrt(np.einsum("ij,ij->i", U, (H @ U.T).T))
eff = est / err
print("test samples %d: max H1-0 error %.3e (relative %.2e), estimate max %.3e, effectivity %.2f .. %.2f" %
      (len(mu), err.max(), (err / nrm).max(), est.max(), eff.min(), eff.max()))
