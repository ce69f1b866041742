"""A mass-spring cloth as a reduced simulation from NumPy: the cloth's whole time step is the
program examples/embed/cloth.npg (states x and v, the wind's mode weights an input per step).
Three full rollouts train a model (Trainer.add_trajectory: every fourth visited state); then
the reduced step runs in reduced coordinates (Reduced.simulate) under a wind it was not trained
on, and its frames are compared with the full rollout's.

    python3 examples/python/springs.py [N] [STEPS]
"""
import pathlib
import sys
import time

import numpy as np

import npg

n, steps = (int(a) for a in (sys.argv[1:] + ["10", "300"][len(sys.argv) - 1:])[:2])
V, h = n * n, 1.0 / (n - 1)
rest = np.array([(q * h, 0.0, -r * h) for r in range(n) for q in range(n)])
edge = np.array([(a, a + d) for a in range(V) for d in (1, n)
                 if (d == 1 and (a + 1) % n) or (d == n and a + n < V)], dtype=np.int64)
inc, sgn = -np.ones((V, 4), dtype=np.int64), np.zeros((V, 4))
for e, (a, b) in enumerate(edge):           # springs meeting at each vertex, -1 padded
    for v, s in ((a, 1.0), (b, -1.0)):
        j = np.argmax(inc[v] < 0)
        inc[v, j], sgn[v, j] = e, s
pin = np.ones(V)
pin[[0, n - 1]] = 0                         # two corners pinned
a = np.arange(V)
dt = 2e-3 * 16 / n                          # the springs stiffen as 1/h: the step shrinks with it
params = {"edge": edge, "L0": np.full(len(edge), h), "inc": inc, "sgn": sgn, "k": np.array(200.0), "pin": pin,
          "modes": np.c_[np.ones(V), np.cos(0.2 * a), np.sin(0.2 * a)], "dt": np.array(dt),
          "mass": np.array(1.0 / V), "damping": np.array(0.02)}
full = npg.compile(str(pathlib.Path(__file__).resolve().parents[1] / "embed" / "cloth.npg")).full(params=params)


def wind(w):
    """The gust w (1 + 0.5 sin(3t + 0.2a)) along y as its three mode weights at every step."""
    t = dt * np.arange(steps)
    return np.c_[np.full(steps, w), 0.5 * w * np.sin(3 * t), 0.5 * w * np.cos(3 * t)]


start = {"x": rest, "v": np.zeros_like(rest)}
tr = npg.Trainer(full)                      # PCA energy 0.999, centered
for w in (0.0, 4.0, 8.0):                   # full rollouts, every 4th state streamed into the trainer
    tr.add_trajectory(steps, every=4, wind=wind(w), **start)
model = tr.finish()
print(f"trained on {model.samples} states of a {n} x {n} cloth ({len(edge)} springs):", model.basis_sizes)

every = steps // 5
t0 = time.perf_counter()
x_full = full.simulate(steps, every=every, wind=wind(6.0), **start)["x"]
t1 = time.perf_counter()
x_red = model.reduced().simulate(steps, every=every, wind=wind(6.0), **start)["x"]
t2 = time.perf_counter()
drift = np.max(np.linalg.norm(x_red - x_full, axis=2)) / np.ptp(rest, axis=0).max()
print(f"wind 6 (not trained on), {steps} steps: the reduced cloth is at most {drift:.2e} of the cloth's size from "
      f"the full one at its {len(x_full)} frames; {1e6 * (t1 - t0) / steps:.0f} us per full step, "
      f"{1e6 * (t2 - t1) / steps:.0f} us per reduced step in coordinates")
if not drift < 0.2:  # examples/embed/README.md: 2.6e-2 to 2.8e-2 at 16 x 16, 400 steps
    sys.exit("springs.py: the reduced trajectory drifted further than expected")
