"""sizes_sweep.py — an error-against-size curve without retraining (issue 41): steady heat
conduction (bench/heat_spd.npg, the thermal problem of pyMOR's demos) on an n x n grid, trained
once at a cap of 21 vectors for u (energy 1), then evaluated at the 20 sizes m_u = 1 … 20 by
truncation (model.reduced(sizes=...)), each on every held-out sample with its error against the
full solution. Prints the training time (snapshots included), the sweep's time (every reduced
evaluation and error of the 20 sizes; the full solutions of the held-out samples, computed once,
timed apart) and the error at every size.

    PYTHONPATH=build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 bench/sizes_sweep.py [n] [S] [T]

n cells per side (64), S training samples (60), T held-out samples (20). After a build."""
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import npg

n = int(sys.argv[1]) if len(sys.argv) > 1 else 64
S = int(sys.argv[2]) if len(sys.argv) > 2 else 60
T = int(sys.argv[3]) if len(sys.argv) > 3 else 20
here = os.path.dirname(os.path.abspath(__file__))
with tempfile.TemporaryDirectory() as w:
    for name, count, seed in (("TRAIN", S, 1), ("TEST", T, 2)):
        subprocess.run([sys.executable, os.path.join(here, "heat_data.py"), str(n), str(count), os.path.join(w, name),
                        str(seed)], check=True)
    prog = npg.compile(os.path.join(here, "heat_spd.npg"))
    full = prog.full(params=os.path.join(w, "TRAIN"))
    train = np.load(os.path.join(w, "TRAIN", "kappa.npy"))
    test = np.load(os.path.join(w, "TEST", "kappa.npy"))

    t0 = time.perf_counter()
    tr = npg.Trainer(full, basis=["u:cap=21,energy=1", "kappa:energy=1"])
    for k in train:
        tr.add(kappa=k)
    model = tr.finish()
    t_train = time.perf_counter() - t0

    t0 = time.perf_counter()
    ref = [full(kappa=k)["u"].copy() for k in test]
    t_full = time.perf_counter() - t0

    t0 = time.perf_counter()
    curve = []
    for m in range(1, 21):
        red = model.reduced(sizes={"m_u": m})
        worst = 0.0
        for k, y in zip(test, ref):
            red(kappa=k)
            worst = max(worst, np.linalg.norm(red.lift("u") - y) / np.linalg.norm(y))
        curve.append((m, worst))
    t_sweep = time.perf_counter() - t0

print(f"heat_spd, {n} x {n} cells, {S} training and {T} held-out samples; sizes {model.basis_sizes}")
print(f"one training (cap 21): {t_train:.3f} s")
print(f"sweep of 20 sizes (m_u = 1..20, {T} reduced evaluations and errors each): {t_sweep:.3f} s "
      f"({t_sweep / t_train:.3f} of the training; the {T} full solutions, once: {t_full:.3f} s)")
print("m_u  max relative error")
for m, e in curve:
    print(f"{m:3d}  {e:.3e}")
