"""train_identical.py — the sha256 of models `npgc train` writes for corpus programs along every
route of training: in memory, by the method of snapshots, out of core (radiosity's extern and
streamed bases too), joint merge, weights, interpolation (forced, chosen on validation samples,
held out, the automatic hold-out and retrain), an inner product (`basis u: product`), greedy, over
two MPI ranks. Two builds of npgc
trained the same way give byte-identical models when training's arithmetic is unchanged, so a
refactoring of training is checked by running this with the npgc before and after it:

    python3 tests/train_identical.py NPGC > before.txt      # e.g. an npgc built from main
    python3 tests/train_identical.py NPGC --check before.txt

prints one line per model, `CASE SHA256` (the hash of every file of MODEL/ but its timings, in
name order); --check compares with a file of such lines and exits 1 naming each case that
differs. The data are generated here with fixed seeds."""
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def npgc(npgc_path, *args, mpi=0):
    cmd = [npgc_path, *args]
    if mpi:
        cmd = ["timeout", "300", "mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(mpi), *cmd, "--mpi"]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)}: exit {r.returncode}\n{r.stdout}{r.stderr}")


def model_hash(d):
    """sha256 over MODEL/'s files in name order; the manifest's timing lines left out."""
    h = hashlib.sha256()
    for root, dirs, files in os.walk(d):
        dirs.sort()
        for name in sorted(files):
            p = os.path.join(root, name)
            h.update(os.path.relpath(p, d).encode() + b"\0")
            with open(p, "rb") as f:
                data = f.read()
            if name == "manifest":
                data = b"\n".join(l for l in data.split(b"\n") if not l.startswith((b"seconds", b"timing", b"cpu")))
            h.update(data)
    return h.hexdigest()


def nbody_data(w):
    rng = np.random.default_rng(4)
    base = rng.normal(size=(8, 3)) * 2
    modes = rng.normal(size=(3, 8, 3))
    for name, S in (("TRAIN", 40), ("VALID", 8)):
        os.makedirs(f"{w}/{name}")
        x = base + np.einsum("sk,kvc->svc", 0.2 * rng.normal(size=(S, 3)), modes)
        np.save(f"{w}/{name}/x.npy", x)
        np.save(f"{w}/{name}/mass.npy", np.full(8, 0.125))
        np.save(f"{w}/{name}/eps.npy", np.array(0.05))
    np.save(f"{w}/weights.npy", rng.uniform(0.5, 2, 40))


def greedy_start(w):
    """START/: the first sample of the thermal block's TB/data (its params and one mu)."""
    src, start = os.path.join(w, "TB", "data"), os.path.join(w, "START")
    os.makedirs(start)
    for name in os.listdir(src):
        a = np.load(os.path.join(src, name))
        np.save(os.path.join(start, name), a[:1] if name == "mu.npy" else a)


def main():
    if len(sys.argv) not in (2, 4) or (len(sys.argv) == 4 and sys.argv[2] != "--check"):
        sys.exit(__doc__)
    exe = os.path.abspath(sys.argv[1])
    w = tempfile.mkdtemp(prefix="npg_identical_")
    try:
        nbody_data(w)
        subprocess.run([sys.executable, os.path.join(ROOT, "tests", "cli", "deforming_springs_data.py"),
                        os.path.join(w, "SPRINGS"), "24", "3"], check=True)
        subprocess.run([sys.executable, os.path.join(ROOT, "examples", "thermalblock", "thermalblock_data.py"),
                        os.path.join(w, "TB"), "--blocks", "2x2", "--grid", "6", "--train", "16", "--test", "2"],
                       check=True, capture_output=True)
        greedy_start(w)
        rdata = os.path.join(os.path.dirname(exe), "radiosity_data")  # the build's, beside its npgc
        subprocess.run([rdata, f"{w}/RT", "24", "20", "0", "1", "1"], check=True, capture_output=True)
        nb, sp = "tests/programs/nbody_gravity.npg", "tests/programs/deforming_springs.npg"
        tb = "examples/thermalblock/thermalblock.npg"
        T, S = f"{w}/TRAIN", f"{w}/SPRINGS"
        cases = [
            ("nbody_memory", [nb, T, "--valid", "none"]),
            ("nbody_auto_holdout", [nb, T]),
            ("nbody_interp", [nb, T, "--reduce", "w:interp", "--interp-oversample", "2"]),
            ("nbody_valid_dir", [nb, T, "--valid", f"{w}/VALID"]),
            ("nbody_valid_fraction", [nb, T, "--valid", "0.25"]),
            ("nbody_weights", [nb, T, "--valid", "none", "--weights", f"{w}/weights.npy"]),
            ("nbody_joint", [nb, T, "--valid", "none", "--merge", "joint"]),
            ("nbody_uncentered_caps", [nb, T, "--valid", "none", "--center", "off", "--basis", "x:cap=3"]),
            ("springs_memory", [sp, S, "--cap", "8"]),
            ("springs_snapshots", [sp, S, "--cap", "8", "--mem", "300k"]),
            ("springs_out_of_core", [sp, S, "--cap", "8", "--mem", "60k"]),
            ("springs_keep_bases", [sp, S, "--cap", "8", "--keep-bases", "all"]),
            ("radiosity_memory", ["examples/radiosity/formfactors.npg", f"{w}/RT", "--cap", "8"]),
            ("radiosity_out_of_core", ["examples/radiosity/formfactors.npg", f"{w}/RT", "--cap", "8", "--mem", "8k"]),
            ("radiosity_out_of_core_kept", ["examples/radiosity/formfactors.npg", f"{w}/RT", "--cap", "8", "--mem", "8k",
                                            "--keep-bases", "all", "--center", "off"]),
            ("thermalblock_product", [tb, f"{w}/TB/data"]),
            ("thermalblock_greedy", [tb, f"{w}/START", "--greedy", f"{w}/TB/data", "--tol", "1e-3", "--basis",
                                     "u:cap=60,energy=1"]),
        ]
        mpi_cases = [("springs_mpi2", [sp, S, "--cap", "8"]), ("springs_mpi2_out_of_core", [sp, S, "--cap", "8", "--mem", "60k"])]
        lines = []
        for name, args in cases + (mpi_cases if shutil.which("mpirun") else []):
            out = os.path.join(w, "M_" + name)
            npgc(exe, "train", *args, "-o", out, mpi=2 if "mpi" in name else 0)
            lines.append(f"{name} {model_hash(out)}")
        if len(sys.argv) == 2:
            print("\n".join(lines))
            return 0
        want = dict(l.split() for l in open(sys.argv[3]) if l.strip())
        bad = [l.split()[0] for l in lines if want.get(l.split()[0]) != l.split()[1]]
        for l in lines:
            print(("ok   " if l.split()[0] not in bad else "DIFF ") + l)
        return 1 if bad else 0
    finally:
        shutil.rmtree(w, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
