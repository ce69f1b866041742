"""estimate_cost.py — what the online error estimate costs against the reduced evaluation it
estimates, per program of the corpus that has estimate tables (issue 41, docs/estimates.md).

    /usr/bin/python3 bench/estimate_cost.py build/npgc [--work DIR] [--reps 5] [--bodies 8]

Per case: the data are made here (seeded), `npgc train` trains a model, and `npgc bench` (one BLAS
thread) times on held-out samples the reduced evaluation alone (coordinates in, coordinates out)
and the same evaluation followed by every output's estimate (npg_reduced_estimate), per sample,
in the same run; the ratio is the median of the per-evaluation ratios (alone + estimate) / alone.
Cases:

  nbody      tests/programs/nbody_gravity.npg, --bodies bodies: r2 contraction, w = r2^(-3/2)
             a root reduced by Galerkin (its estimate: the check entries, galerkincheck),
             a contraction; the input errors propagated through each stage
  nbody-interp  the same with w interpolated (--reduce w:interp): the interpolated stage's check
  thermalblock  examples/thermalblock/thermalblock.npg, 2 x 2 blocks, grid 19, u's basis in
             the H¹₀ product (min-θ bound; the residual's R is D x D, D = 1 + m·(1 + m_mu))
  heat       bench/heat_spd.npg: a sparse SPD solve whose operator reads a 16 x 16 field
             kappa (an input of 256 entries: σ_min(BᵀKB) estimated, an m x m eigenproblem)

Prints one row per case and writes WORK/estimate_cost.json. Figures, not pass/fail."""
import argparse
import json
import os
import re
import subprocess
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)}: exit {r.returncode}\n{r.stdout}{r.stderr}")
    return r.stdout


def nbody_data(folder, bodies, samples, seed):
    """Positions as a base configuration plus three random modes (the shape of tests/train_identical.py's)."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(bodies, 3)) * 2
    modes = rng.normal(size=(3, bodies, 3))
    for name, S in (("train", samples), ("test", 16)):
        d = os.path.join(folder, name)
        os.makedirs(d, exist_ok=True)
        np.save(os.path.join(d, "x.npy"), base + np.einsum("sk,kvc->svc", 0.2 * rng.normal(size=(S, 3)), modes))
        np.save(os.path.join(d, "mass.npy"), np.full(bodies, 1.0 / bodies))
        np.save(os.path.join(d, "eps.npy"), np.array(0.05))


def cases(work, bodies):
    """(name, program, train dir, test dir, training options), the data written first."""
    nb = os.path.join(work, "nbody")
    nbody_data(nb, bodies, 40, 4)
    tb = os.path.join(work, "thermalblock")
    run([sys.executable, "examples/thermalblock/thermalblock_data.py", tb, "--blocks", "2x2", "--grid", "19",
         "--train", "40", "--test", "16"])
    heat = os.path.join(work, "heat")
    run([sys.executable, "bench/heat_data.py", "16", "40", os.path.join(heat, "train"), "1"])
    run([sys.executable, "bench/heat_data.py", "16", "16", os.path.join(heat, "test"), "2"])
    nbp = "tests/programs/nbody_gravity.npg"
    return [
        (f"nbody ({bodies} bodies)", nbp, f"{nb}/train", f"{nb}/test", ["--reduce", "w:galerkin"]),
        (f"nbody-interp ({bodies} bodies)", nbp, f"{nb}/train", f"{nb}/test", ["--reduce", "w:interp"]),
        ("thermalblock (2x2, grid 19)", "examples/thermalblock/thermalblock.npg", f"{tb}/data", f"{tb}/test",
         ["--center", "off", "--basis", "u:cap=20,energy=1", "--basis", "u.num1:cap=1"]),
        ("heat (16 x 16 cells)", "bench/heat_spd.npg", f"{heat}/train", f"{heat}/test", []),
    ]


def field(text, label):
    m = re.search(r"^\s*" + re.escape(label) + r"\s*([0-9.e+-]+) s per sample", text, re.M)
    return float(m.group(1)) if m else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("npgc")
    ap.add_argument("--work", default=os.path.join("build", "bench_estimate"))
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--bodies", type=int, default=8)
    a = ap.parse_args()
    npgc = os.path.abspath(a.npgc)
    work = os.path.abspath(a.work)
    os.makedirs(work, exist_ok=True)
    rows = []
    print(f"{'program':32s} {'classes m':>24s} {'reduced alone':>14s} {'+ estimate':>14s} {'ratio':>8s}  estimates")
    for name, prog, train, test, opts in cases(work, a.bodies):
        model = os.path.join(work, "model_" + re.sub(r"\W+", "_", name))
        text = run([npgc, "train", prog, train, "-o", model, *opts])
        sizes = " ".join(f"{c}={m}" for c, m in re.findall(r"^(\{[^}]*\})\s+\d+\s+(\d+)", text, re.M))
        b = run([npgc, "bench", prog, model, test, "--reps", str(a.reps), "--threads", "1"])
        alone, both = field(b, "reduced alone"), field(b, "reduced + estimate")
        ratio = re.search(r"reduced \+ estimate.*?: ([0-9.e+-]+)x \[", b)
        kinds = re.search(r"npg_reduced_estimate, (\d+) of them with a figure", b)
        none = re.search(r"\+ estimate\s+none: (.*)$", b, re.M)
        row = {"case": name, "program": prog, "classes": sizes, "reduced_alone_s": alone, "with_estimate_s": both,
               "ratio": float(ratio.group(1)) if ratio else float("nan"),
               "outputs_with_estimate": int(kinds.group(1)) if kinds else 0, "none": none.group(1) if none else ""}
        rows.append(row)
        print(f"{name:32s} {sizes:>24s} {alone:>12.3e} s {both:>12.3e} s {row['ratio']:>7.3g}x  "
              f"{row['outputs_with_estimate'] or row['none']}")
    with open(os.path.join(work, "estimate_cost.json"), "w") as fh:
        json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
