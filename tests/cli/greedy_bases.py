"""greedy_bases.py BUILD_DIR — greedy training's bases through npgc (issue 41, docs/estimates.md,
"Greedy training") on examples/thermalblock at 4 x 4 blocks, grid 10 (121 unknowns), as
bench/thermalblock.md's 3 x 3 run invoked it (`--center off --basis u:cap=N,energy=1 --basis
u.num1:cap=1 --absolute`):

1. `--basis mu:energy=1` given (the run that was refused once u's class passed 51 vectors: its
   residual table, D = 1 + 17 m columns here, exceeded the former limit of 512 columns): greedy
   runs to its budget of 36 samples with 36 full evaluations (one per sample: each retraining takes
   the earlier samples' snapshots from the last), the final model's table has more than 512 columns, and
   `npgc eval`'s estimate of u bounds the true error in H's norm (numpy's dense solve) on
   held-out parameters, within 20x;
2. without it, μ's basis keeps all 16 directions (greedy training's default energy 1 for inputs;
   the uncentered default 0.999 kept fewer) and the manifest's chosen candidates are the pool
   indices farthest outside μ's basis first, not the pool's order."""
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, "examples/thermalblock")
import thermalblock_data  # noqa: E402

B = sys.argv[1]
PROG = "examples/thermalblock/thermalblock.npg"
COMMON = ["--center", "off", "--basis", "u:cap=60,energy=1", "--basis", "u.num1:cap=1", "--absolute"]


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def run(*args):
    p = subprocess.run([os.path.join(B, "npgc"), *args], capture_output=True, text=True)
    if p.returncode != 0:
        fail("npgc %s: exit %d\n%s%s" % (" ".join(args), p.returncode, p.stdout, p.stderr))
    return p


def manifest(model):
    return open(os.path.join(model, "manifest")).read().splitlines()


def main():
    kb, kq, hm, f = thermalblock_data.assemble(4, 4, 10)
    rng = np.random.default_rng(6)
    pool_mu, test_mu = rng.uniform(0.1, 1, (50, 16)), rng.uniform(0.1, 1, (5, 16))
    with tempfile.TemporaryDirectory() as w:
        start, pool, test = (os.path.join(w, n) for n in ("START", "POOL", "TEST"))
        for d, mus in ((start, pool_mu[:1]), (test, test_mu)):
            thermalblock_data.write_params(d, kb, kq, hm, f, mus)
        os.makedirs(pool)
        np.save(os.path.join(pool, "mu.npy"), pool_mu)  # POOL/ holds the inputs only
        m1, m2 = os.path.join(w, "M1"), os.path.join(w, "M2")
        p = run("train", PROG, start, "--greedy", pool, "--tol", "1e-14", "--budget", "36", "-o", m1, *COMMON,
                "--basis", "mu:energy=1")
        evals = re.search(r"greedily on (\d+) samples .*; (\d+) full evaluations\)", p.stdout)
        if not evals or evals.group(1) != "36" or evals.group(2) != "36":
            fail("greedy training on 36 samples did not evaluate each once in full:\n" + p.stdout)
        dims = [int(l.split()[4]) for l in manifest(m1) if l.startswith("estimate u 0 dim ")]
        if not dims or dims[0] <= 512:
            fail("the greedy model's residual table has %s columns (the test needs more than 512)" % dims)
        out = os.path.join(w, "OUT")
        run("eval", PROG, m1, test, "-o", out)
        V, est = np.load(os.path.join(out, "u.npy")), np.load(os.path.join(out, "u.estimate.npy")).ravel()
        true = []
        for k, mu in enumerate(test_mu):
            e = np.linalg.solve(kb + sum(m * q for m, q in zip(mu, kq)), f) - V[k]
            true.append(np.sqrt(e @ hm @ e))
            if not true[k] <= est[k] <= 20 * true[k]:
                fail("test parameter %d (table of %d columns): estimate %.3e against the true error %.3e"
                     % (k, dims[0], est[k], true[k]))
        eff = est / np.array(true)
        print("greedy past 512 columns: table of %d columns, effectivity %.2f .. %.2f" % (dims[0], eff.min(), eff.max()))
        p = run("train", PROG, start, "--greedy", pool, "--tol", "1e-14", "--budget", "17", "-o", m2, *COMMON)
        rows = [l.split() for l in (p.stdout + p.stderr).splitlines() if l.startswith("{mu}")]
        if not rows or rows[0][2] != "16":
            fail("μ's basis under greedy training does not keep all 16 directions:\n" + p.stdout + p.stderr)
        line = next(l for l in manifest(m2) if l.startswith("greedy ")).split()
        chosen = [int(c) for c in line[line.index("chosen") + 1].split(",")]
        if chosen == sorted(chosen):
            fail("greedy took the candidates outside μ's basis in the pool's order: %s" % chosen)


main()
