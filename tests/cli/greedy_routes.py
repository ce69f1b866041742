"""greedy_routes.py BUILD_DIR [--mpi] — greedy training's snapshot cache on the routes beyond one
process without a hold-out (issue 41, docs/estimates.md "Greedy training"), through npgc on
examples/thermalblock at 3 x 3 blocks, grid 8 (81 unknowns):

1. with the automatic hold-out (a stage w = (u² + 1)^(-1/2) whose reduction is open: from 30
   samples every 10th validates the choice, then all retrain): the samples found in the cache by
   their hashes, the validation's too, so each iteration evaluates its new sample, the last held-out
   one and the retraining's last one (at most 3) where replaying took 2 S; the model the same files,
   byte for byte, as `npgc train` on the chosen samples afresh;
2. with --mpi, over 2 ranks (the program without its product, which training over ranks does not
   implement): each rank keeps its share's snapshots and estimates its share of the candidates, so
   a retraining evaluates its new sample on its rank and the other rank's last one (2 per training,
   summed over the ranks; replaying took S); the model the same as `npgc train --mpi` on the
   chosen samples over 2 ranks."""
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, "examples/thermalblock")
import thermalblock_data  # noqa: E402

B = sys.argv[1]
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mpi_env import mpi_launch  # noqa: E402
MPI = "--mpi" in sys.argv[2:]
BASES = ["--center", "off", "--basis", "u:cap=60,energy=1", "--basis", "u.num1:cap=1", "--basis", "mu:energy=1"]


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def run(args, ranks=0):
    launch, env = mpi_launch(ranks) if ranks else ([], None)
    p = subprocess.run([*launch, os.path.join(B, "npgc"), *args], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        fail("npgc %s: exit %d\n%s%s" % (" ".join(args), p.returncode, p.stdout, p.stderr))
    return p


def greedy(w, prog, budget, name, extra, ranks=0):
    """Greedy training to its budget: the full evaluations and the samples chosen (the start first)."""
    model = os.path.join(w, name)
    p = run(["train", prog, os.path.join(w, "START"), "--greedy", os.path.join(w, "POOL"), "--tol", "1e-14",
             "--budget", str(budget), "--absolute", "-o", model, *BASES, *extra], ranks)
    m = re.search(r"greedily on (\d+) samples .*; (\d+) full evaluations\)", p.stdout)
    if not m or int(m.group(1)) != budget:
        fail("greedy training did not run to its budget of %d samples:\n%s" % (budget, p.stdout))
    line = next(l for l in open(os.path.join(model, "manifest")).read().splitlines() if l.startswith("greedy "))
    chosen = line.split()[line.split().index("chosen") + 1]
    return int(m.group(2)), [0] + [int(c) for c in chosen.split(",")]


def manifest_kept(path):
    return [l for l in open(path).read().splitlines()
            if not l.startswith(("greedy", "manifest ", "seconds", "timing", "cpu"))]


def afresh(w, prog, name, chosen, pool_mu, greedy_model, extra, ranks=0):
    """`npgc train` on the chosen samples; fails unless its files are greedy_model's."""
    data, model = os.path.join(w, name + "_DATA"), os.path.join(w, name)
    os.makedirs(data)
    for f in os.listdir(os.path.join(w, "START")):
        if f != "mu.npy":
            os.link(os.path.join(w, "START", f), os.path.join(data, f))
    np.save(os.path.join(data, "mu.npy"), pool_mu[chosen])
    run(["train", prog, data, "-o", model, *BASES, *extra], ranks)
    names = sorted(os.listdir(model))
    if names != sorted(os.listdir(greedy_model)):
        fail("%s: files %s against the greedy model's %s" % (name, names, sorted(os.listdir(greedy_model))))
    for f in names:
        a, b = os.path.join(greedy_model, f), os.path.join(model, f)
        same = manifest_kept(a) == manifest_kept(b) if f == "manifest" else open(a, "rb").read() == open(b, "rb").read()
        if not same:
            fail("%s: %s differs from the greedy model's (the cache changed the model)" % (name, f))


def main():
    kb, kq, hm, f = thermalblock_data.assemble(3, 3, 8)
    pool_mu = np.random.default_rng(5).uniform(0.1, 1, (50, 9))
    with tempfile.TemporaryDirectory() as w:
        thermalblock_data.write_params(os.path.join(w, "START"), kb, kq, hm, f, pool_mu[:1])
        os.makedirs(os.path.join(w, "POOL"))
        np.save(os.path.join(w, "POOL", "mu.npy"), pool_mu)
        text = open("examples/thermalblock/thermalblock.npg").read()
        choice, plain = os.path.join(w, "choice.npg"), os.path.join(w, "plain.npg")
        with open(choice, "w") as fp:
            fp.write(text + "output w[i:N] = (u[i] * u[i] + 1)^(-1/2)\n")
        with open(plain, "w") as fp:
            fp.write(text.replace("basis u: product H\n", ""))
        budget, extra = 34, ["--basis", "w:energy=1"]
        evals, chosen = greedy(w, choice, budget, "HOLD", extra)
        bound = sum(1 if S < 30 else 3 for S in range(1, budget + 1))
        replayed = sum(1 if S < 30 else 2 * S for S in range(1, budget + 1))
        if not budget <= evals <= bound:
            fail("the hold-out route: %d full evaluations for %d samples, not within [%d, %d] (replayed: %d)"
                 % (evals, budget, budget, bound, replayed))
        afresh(w, choice, "HOLD_AFRESH", chosen, pool_mu, os.path.join(w, "HOLD"), extra)
        print("greedy with the hold-out: %d full evaluations for %d samples (replaying: %d), the model the same"
              % (evals, budget, replayed))
        if not MPI:
            return
        budget = 16
        evals, chosen = greedy(w, plain, budget, "MPI", ["--mpi"], ranks=2)
        if evals != 2 * budget:
            fail("over 2 ranks: %d full evaluations for %d samples, not 2 per training (replayed: %d)"
                 % (evals, budget, budget * (budget + 1) // 2))
        afresh(w, plain, "MPI_AFRESH", chosen, pool_mu, os.path.join(w, "MPI"), ["--mpi"], ranks=2)
        print("greedy over 2 ranks: %d full evaluations for %d samples (replaying: about %d), the model the same"
              % (evals, budget, budget * (budget + 1) // 2))


main()
