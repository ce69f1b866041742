"""The paper's Eq. 3 end to end from NumPy: compile, evaluate, train, verify,
then run the reduced model (examples/python/README.md).

    python3 examples/python/eq3.py [MODEL_DIR]
"""
import pathlib
import sys

import numpy as np

import npg

here = pathlib.Path(__file__).resolve().parent
prog = npg.compile(str(here.parent / "rational" / "rational.npg"))
print("stages:", [(s["name"], s["kind"]) for s in prog.stages])

rng = np.random.default_rng(1)
train = 0.5 + rng.random((200, 2))          # x in [0.5, 1.5]^2
test = 0.5 + rng.random((20, 2))

full = prog.full()                          # libtcc, in memory
tr = npg.Trainer(full, energy=0.999999)
for x in train:
    tr.add(x=x)                             # one sample streamed at a time
model = tr.finish(sys.argv[1] if len(sys.argv) > 1 else None)
print(model.report(), end="")

rows = model.verify(test={"x": test}, tol=1e-3)
y = rows["y"]
print(f"verify y: L2 error {y['l2']:.2e} (projection floor {y['floor']:.2e}), passes 1e-3: {y['pass']}")

red = model.reduced()
worst = 0.0
for x in test:                              # the reduced model in a loop
    yhat = red(x=x)["y"]                    # reduced coordinates
    y_red = red.lift("y")                   # B yhat, in full space
    y_full = full(x=x)["y"]
    worst = max(worst, np.linalg.norm(y_red - y_full) / np.linalg.norm(y_full))
print(f"{len(test)} held-out samples: coordinates {yhat.shape[0]}, worst relative error {worst:.2e}")
if not worst < 1e-3:
    sys.exit("eq3.py: the reduced model is less accurate than expected")
