"""A deforming mass-spring cloth simulated in NumPy: npg evaluates the spring
forces (examples/embed/cloth.npg), the simulation's states train a reduced
model, which then runs the same loop under a wind it was not trained on.

    python3 examples/python/springs.py [N] [STEPS]
"""
import pathlib
import sys

import numpy as np

import npg

n, steps = (int(a) for a in (sys.argv[1:] + ["10", "300"][len(sys.argv) - 1:])[:2])
V, h, dt, damping = n * n, 1.0 / (n - 1), 2e-3, 0.02
rest = np.array([(q * h, 0.0, -r * h) for r in range(n) for q in range(n)])
edge = np.array([(a, a + d) for a in range(V) for d in (1, n)
                 if (d == 1 and (a + 1) % n) or (d == n and a + n < V)], dtype=np.int64)
inc, sgn = -np.ones((V, 4), dtype=np.int64), np.zeros((V, 4))
for e, (a, b) in enumerate(edge):           # springs meeting at each vertex, -1 padded
    for v, s in ((a, 1.0), (b, -1.0)):
        j = np.argmax(inc[v] < 0)
        inc[v, j], sgn[v, j] = e, s
params = {"edge": edge, "L0": np.full(len(edge), h), "inc": inc, "sgn": sgn, "k": np.array(200.0)}
full = npg.compile(str(pathlib.Path(__file__).resolve().parents[1] / "embed" / "cloth.npg")).full(params=params)


def simulate(force, wind, on_state=None):
    """Semi-implicit Euler under `force(x)`, gravity and a gusty wind; two corners pinned."""
    x, v, free = rest.copy(), np.zeros_like(rest), np.ones((V, 1))
    free[[0, n - 1]] = 0
    for s in range(steps):
        f = force(x)
        if on_state:
            on_state(s)
        gust = wind * (1 + 0.5 * np.sin(3 * s * dt + 0.2 * np.arange(V)))
        v = (1 - damping) * v + dt * free * (f * V + np.c_[0 * gust, gust, np.full(V, -9.81)])
        x = x + dt * v
    return x


tr = npg.Trainer(full)                      # PCA energy 0.999, centered
for wind in (0.0, 4.0, 8.0):                # the full model, its states streamed into the trainer
    simulate(lambda x: full(x=x)["force"], wind, lambda s: s % 4 or tr.add_full())
model = tr.finish()
print(f"trained on {model.samples} states of a {n} x {n} cloth ({len(edge)} springs):", model.basis_sizes)

red = model.reduced()
x_full = simulate(lambda x: full(x=x)["force"], 6.0)
x_red = simulate(lambda x: (red(x=x), red.lift("force"))[1], 6.0)
drift = np.max(np.linalg.norm(x_red - x_full, axis=1)) / np.ptp(rest, axis=0).max()
print(f"wind 6 (not trained on), {steps} steps: the reduced cloth ends {drift:.2e} of the cloth's size from the full one")
if not drift < 0.2:  # examples/embed/README.md: 0.05-0.11 at 16 x 16, 400 steps
    sys.exit("springs.py: the reduced trajectory drifted further than expected")
