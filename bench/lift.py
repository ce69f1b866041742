"""Lift and projection of a reduced model against NumPy, one BLAS thread, same run.

    PYTHONPATH=build/python /usr/bin/python3 bench/lift.py [N [M [S [REPS]]]]

Trains bench/lift.npg (y = 2 x on N entries) on 2 M samples of M random
modes, so y's basis B is N x M (default 20,000 x 20), then times, median
(and best) of REPS calls each:
  lift 1     red.lift("y")                  against NumPy's B @ y
  lift S     red.lift("y", coords=Y)        (S x M, one pass over B) against NumPy's Y @ B.T
  project 1  red(x=x) (projection + the one contraction) against NumPy's B.T @ x
and checks that npg's lifted values equal NumPy's to 1e-12.
"""
import os
import sys
import time

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before NumPy and npg load OpenBLAS
import numpy as np  # noqa: E402

import npg  # noqa: E402

here = os.path.dirname(os.path.abspath(__file__))


def timed(f, reps):
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return np.median(ts) * 1e6, min(ts) * 1e6


def main():
    a = [int(v) for v in sys.argv[1:]]
    N, M, S, reps = (a + [20000, 20, 16, 1000][len(a):])[:4]
    rng = np.random.default_rng(1)
    modes = rng.standard_normal((M, N))
    tr = npg.Trainer(npg.compile(os.path.join(here, "lift.npg")).full(), energy=1 - 1e-12)
    for _ in range(2 * M):
        tr.add(x=rng.standard_normal(M) @ modes)
    model = tr.finish(None)
    B = np.asarray(model.basis("y"))
    red = model.reduced()
    x = rng.standard_normal(M) @ modes
    red(x=x)
    yh = red.coords("y")
    Y = rng.standard_normal((S, B.shape[1]))
    if not (np.allclose(red.lift("y"), B @ yh, rtol=0, atol=1e-12 * np.abs(B @ yh).max())
            and np.allclose(red.lift("y", coords=Y), Y @ B.T, rtol=0, atol=1e-12 * np.abs(Y @ B.T).max())):
        sys.exit("lift.py: npg's lift differs from NumPy's product")
    print(f"basis {B.shape[0]} x {B.shape[1]}, one BLAS thread, median (best) of {reps} calls, microseconds")
    rows = [
        ("lift 1", timed(lambda: red.lift("y"), reps), timed(lambda: B @ yh, reps), 1),
        (f"lift {S}", timed(lambda: red.lift("y", coords=Y), reps), timed(lambda: Y @ B.T, reps), S),
        ("project 1 (+ eval)", timed(lambda: red(x=x), reps), timed(lambda: B.T @ x, reps), 1),
    ]
    print(f"{'':20s} {'npg':>16s} {'NumPy':>16s} {'npg/NumPy':>10s} {'npg per sample':>15s}")
    for name, n, p, s in rows:
        print(f"{name:20s} {n[0]:9.1f} ({n[1]:5.1f}) {p[0]:9.1f} ({p[1]:5.1f}) {n[0] / p[0]:10.2f} {n[0] / s:15.1f}")


if __name__ == "__main__":
    main()
