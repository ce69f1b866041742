"""The per-call overhead of a reduced evaluation from Python (npg module)
over the same evaluation from C (npg.h), measured in one run, rounds
alternating between the two; and the memory the Python call allocates
(no input or output larger than a coordinate vector may be copied).

    PYTHONPATH=build/python python3 bench/python_overhead.py [BUILD_DIR] [ROUNDS]

Two models: Eq. 3 (a call of about a microsecond: the overhead dominates)
and the radiosity form factors at 800 faces (examples/radiosity/formfactors.npg
on bench/meshgen's deforming room, 30 samples; inputs g 1206 and e 800
values, projected in place). Results: bench/python_overhead.md."""
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc

import numpy as np

import npg

ROOT = pathlib.Path(__file__).resolve().parents[1]
build = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ROOT / "build").resolve()
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5


def python_us(red, kws, calls, batch):
    """Median and minimum µs a call over batches, as the C side measures."""
    per = []
    for b in range(-1, calls // batch):
        t0 = time.perf_counter()
        for c in range(batch):
            red(**kws[(b * batch + c + batch) % len(kws)])
        if b >= 0:
            per.append((time.perf_counter() - t0) / batch * 1e6)
    return statistics.median(per), min(per)


def c_us(prog, model, test, calls, batch):
    out = subprocess.run([str(build / "bench_python_overhead"), prog, model, test, str(calls), str(batch)],
                         check=True, capture_output=True, text=True, cwd=ROOT).stdout.split()
    return float(out[1].split("=")[1]), float(out[2].split("=")[1])


def measure(name, prog, model_dir, test_dir, inputs, calls, batch):
    model = npg.load(npg.compile(prog), model_dir)
    red = model.reduced()
    S = len(next(iter(inputs.values())))
    kws = [{k: v[s] for k, v in inputs.items()} for s in range(S)]
    py, c = [], []
    for _ in range(rounds):
        c.append(c_us(prog, model_dir, test_dir, calls, batch))
        py.append(python_us(red, kws, calls, batch))
    cm, pm = statistics.median(x[0] for x in c), statistics.median(x[0] for x in py)
    cmin, pmin = min(x[1] for x in c), min(x[1] for x in py)
    # what one call allocates through Python (NumPy registers its buffers with tracemalloc)
    red(**kws[0])
    tracemalloc.start()
    red(**kws[1 % S])
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    biggest_in = max(v[0].nbytes for v in inputs.values())
    coords = sum(8 * n for n in model.basis_sizes.values())
    print(f"{name}: C {cm:.3f} µs/call (min {cmin:.3f}), Python {pm:.3f} µs/call (min {pmin:.3f}): "
          f"overhead {pm - cm:.3f} µs (min to min {pmin - cmin:.3f}), ratio {pm / cm:.3f}; "
          f"peak Python allocation during a call {peak} B (largest input {biggest_in} B, "
          f"all coordinate vectors together {coords} B); {rounds} rounds of {calls} calls")


with tempfile.TemporaryDirectory() as tmp:
    tmp = pathlib.Path(tmp)
    # Eq. 3
    rng = np.random.default_rng(1)
    prog = npg.compile(str(ROOT / "examples/rational/rational.npg"))
    tr = npg.Trainer(prog.full())
    for x in 0.5 + rng.random((100, 2)):
        tr.add(x=x)
    tr.finish(str(tmp / "EQ3"))
    (tmp / "EQ3IN").mkdir()
    xt = 0.5 + rng.random((64, 2))
    np.save(tmp / "EQ3IN" / "x.npy", xt)
    measure("Eq. 3", "examples/rational/rational.npg", str(tmp / "EQ3"), str(tmp / "EQ3IN"), {"x": xt},
            200000, 2000)
    # radiosity, 800 faces
    data, test = tmp / "R800", tmp / "R800T"
    subprocess.run([str(build / "radiosity_data"), str(data), "800", "30", "0", "1", "1"], check=True,
                   capture_output=True)
    subprocess.run([str(build / "radiosity_data"), str(test), "800", "16", "0.03", "0.97", "2"], check=True,
                   capture_output=True)
    prog = npg.compile(str(ROOT / "examples/radiosity/formfactors.npg"))
    t0 = time.perf_counter()
    tr = npg.Trainer(prog.full(params=str(data)))
    g, e, v = (np.load(data / f"{n}.npy") for n in ("g", "e", "v"))
    for k in range(len(g)):
        tr.add(g=g[k], e=e[k], v=v[k])
    model = tr.finish(str(tmp / "M800"))
    print(f"radiosity model trained from Python in {time.perf_counter() - t0:.1f} s: {model.basis_sizes}")
    del v
    gt, et = np.load(test / "g.npy"), np.load(test / "e.npy")
    measure("radiosity 800 faces", "examples/radiosity/formfactors.npg", str(tmp / "M800"), str(test),
            {"g": gt, "e": et}, 20000, 500)
