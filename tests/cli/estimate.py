"""estimate.py BUILD_DIR — the online error estimate and the trust signal (issue 41) on a small
thermal block (tests/cli/thermal_block.npg: K(mu) = K0 + sum_q mu_q K_q, SPD, source fixed), as a
user runs them: npgc train, npgc eval (OUT/u.estimate.npy), npgc verify's effectivity column.
The true errors come from numpy's own solve of the same operator (an independent oracle): on
every test sample the estimate must be at least the true error and at most 20 times it. Inputs
outside the training range are named by a warning and flagged on their estimates. A basis
orthonormal in a product 2I, the operator at no parameter, gets the pencil's bound in its norm. Greedy training
(npgc train --greedy) from one sample reaches the accuracy of the POD model of the whole pool
with fewer full evaluations; the choice is in the manifest; a budget stops it with a message."""
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

B = sys.argv[1]
PROG = "tests/cli/thermal_block.npg"
G = 12  # cells per side: N = 144, four blocks (8 for the greedy part)


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def grid(G=G):
    N = G * G
    nbr = -np.ones((N, 4), np.int32)
    blk = np.zeros(N, np.int32)
    for y in range(G):
        for x in range(G):
            i = y * G + x
            for k, (dx, dy) in enumerate([(1, 0), (-1, 0), (0, 1), (0, -1)]):
                if 0 <= x + dx < G and 0 <= y + dy < G:
                    nbr[i, k] = (y + dy) * G + x + dx
            blk[i] = (2 * y // G) * 2 + (2 * x // G)
    xs, ys = np.arange(N) % G, np.arange(N) // G
    src = np.exp(-((xs - G / 3) ** 2 + (ys - G / 4) ** 2) / G)
    return nbr, blk, src


def write(d, mu, nbr, blk, src):
    os.makedirs(d)
    np.save(os.path.join(d, "nbr.npy"), nbr)
    np.save(os.path.join(d, "blk.npy"), blk)
    np.save(os.path.join(d, "src.npy"), src)
    np.save(os.path.join(d, "mu.npy"), mu)


def solve(mu, nbr, blk, src):
    """The program's operator assembled by numpy, solved densely."""
    N = len(blk)
    K = np.eye(N)
    for i in range(N):
        for k in range(4):
            j = nbr[i, k]
            if j >= 0:
                c = 0.5 * (mu[blk[i]] + mu[blk[j]])
                K[i, i] += c
                K[i, j] -= c
    return np.linalg.solve(K, src)


def run(*args, ok=True):
    p = subprocess.run([os.path.join(B, "npgc")] + list(args), capture_output=True, text=True)
    if ok and p.returncode != 0:
        fail("npgc %s: %s%s" % (" ".join(args), p.stdout, p.stderr))
    return p


def main():
    nbr, blk, src = grid()
    rng = np.random.default_rng(41)
    with tempfile.TemporaryDirectory() as w:
        train, test, out = (os.path.join(w, n) for n in ("TRAIN", "TEST", "OUT"))
        write(train, rng.uniform(0.1, 1, (20, 4)), nbr, blk, src)
        mu_test = rng.uniform(0.1, 1, (25, 4))
        write(test, mu_test, nbr, blk, src)
        run("train", PROG, train, "-o", os.path.join(w, "MODEL"))
        manifest = open(os.path.join(w, "MODEL", "manifest")).read()
        if "estimate u 0 dim" not in manifest or "range mu" not in manifest:
            fail("the model holds no estimate table or no input range:\n" + manifest)
        run("eval", PROG, os.path.join(w, "MODEL"), test, "-o", out)
        est = np.load(os.path.join(out, "u.estimate.npy"))
        red = np.load(os.path.join(out, "u.npy"))
        err = np.array([np.linalg.norm(solve(mu_test[k], nbr, blk, src) - red[k]) for k in range(len(mu_test))])
        eff = est / err
        print("effectivity over %d test samples: %.3g .. %.3g (true errors %.2e .. %.2e)"
              % (len(eff), eff.min(), eff.max(), err.min(), err.max()))
        if not (eff >= 1).all():
            fail("the estimate is below the true error at samples %s" % np.nonzero(eff < 1)[0])
        if not (eff <= 20).all():
            fail("the estimate exceeds 20x the true error at samples %s" % np.nonzero(eff > 20)[0])
        v = run("verify", PROG, os.path.join(w, "MODEL"), test).stdout
        if not any(l.split()[:2] == ["estimate", "u"] and ".." in l and l.split()[-1] == "bound"
                   for l in v.splitlines()):
            fail("npgc verify prints no estimate with its effectivity for u, a bound (min-θ):\n" + v)
        # npgc bench times the evaluation followed by every output's estimate: one line, the median (with its
        # quartiles) of alone + estimate, at least the evaluation alone's (each sample's sum is), and their ratio
        b = run("bench", PROG, os.path.join(w, "MODEL"), test, "--reps", "1").stdout
        num = r"([0-9.]+e[+-][0-9]+)"
        rows = [re.fullmatch(r"  reduced \+ estimate\s+%s s per sample \[%s, %s\], then every output's estimate "
                             r"\(npg_reduced_estimate, 1 of them with a figure\): ([0-9.]+)x \[([0-9.]+)x, ([0-9.]+)x\] "
                             r"the reduced alone" % (num, num, num), l) for l in b.splitlines()]
        rows = [r for r in rows if r]
        alone = re.search(r"^  reduced alone\s+%s s per sample" % num, b, re.M)
        if len(rows) != 1 or not alone:
            fail("npgc bench prints no line of the evaluation with its estimate (or a malformed one):\n" + b)
        med, q1, q3, ratio, r1, r3 = (float(v) for v in rows[0].groups())
        if not (q1 <= med <= q3 and med >= float(alone.group(1)) and 1 <= r1 <= ratio <= r3):
            fail("npgc bench's estimate line is inconsistent (median within its quartiles, at least the evaluation "
                 "alone's, a ratio of at least 1):\n" + b)
        # conductivities beyond the training range: the warning names the input, the estimate says so
        far = os.path.join(w, "FAR")
        write(far, rng.uniform(1.5, 2, (3, 4)), nbr, blk, src)
        p = run("eval", PROG, os.path.join(w, "MODEL"), far, "-o", os.path.join(w, "OUT2"))
        if p.stderr.count("input 'mu' lies outside the training range") != 3:
            fail("no warning naming input mu outside the training range:\n" + p.stderr)
        if p.stdout.count("b!") != 3:  # flagged outside, and still a bound: min-θ holds for any mu > 0
            fail("the estimates of the samples outside the range are not flagged:\n" + p.stdout)
        # a complete basis (4 x 4 cells, 16 vectors): the residual is roundoff, reported as its level, flagged
        small = grid(4)
        t4, e4 = os.path.join(w, "T4"), os.path.join(w, "E4")
        write(t4, rng.uniform(0.1, 1, (30, 4)), *small)
        write(e4, rng.uniform(0.1, 1, (4, 4)), *small)
        run("train", PROG, t4, "--basis", "u:cap=200,energy=1", "-o", os.path.join(w, "M4"))
        p = run("eval", PROG, os.path.join(w, "M4"), e4, "-o", os.path.join(w, "O4"))
        est4 = np.load(os.path.join(w, "O4", "u.estimate.npy"))
        if p.stdout.count(" br\n") != 4 or not (est4 < 1e-12).all() or not (est4 > 0).all():
            fail("a complete basis: estimates %s not flagged at the roundoff level:\n%s" % (est4, p.stdout))
        # a basis orthonormal in a product H that is the operator at no parameter (2I against I + Σ μ_q K_q): the
        # coercivity bound relative to H from the pencil (M(μ̄), H) at training anchors, a bound of the error in
        # H's norm √(eᵀHe) = √2 ‖e‖ (docs/estimates.md, "In a product")
        hprog = os.path.join(w, "product.npg")
        with open(PROG) as f, open(hprog, "w") as g:
            g.write(f.read().replace("output u =", "op H[i:N, j:N] = delta(i, j) * 2\noutput u ="))
        run("train", hprog, train, "--basis", "u:product=H", "-o", os.path.join(w, "HMODEL"))
        if "theta u 0 input mu anchors 8" not in open(os.path.join(w, "HMODEL", "manifest")).read():
            fail("the pencil's 8 anchors are not in the manifest of a product that is no parameter's operator")
        p = run("eval", hprog, os.path.join(w, "HMODEL"), test, "-o", os.path.join(w, "HOUT"))
        hest = np.load(os.path.join(w, "HOUT", "u.estimate.npy")).ravel()
        hred = np.load(os.path.join(w, "HOUT", "u.npy"))
        herr = np.array([np.sqrt(2) * np.linalg.norm(solve(mu_test[k], nbr, blk, src) - hred[k])
                         for k in range(len(mu_test))])
        heff = hest / herr
        print("product 2I, the pencil's bound: effectivity %.3g .. %.3g" % (heff.min(), heff.max()))
        if not ((heff >= 1).all() and (heff <= 20).all()) or len(re.findall(r"^ +\d+ +\S+ b!?$", p.stdout, re.M)) != len(mu_test):
            fail("the pencil's bound in the product 2I: effectivity %s, flags:\n%s" % (heff, p.stdout))
        p = run("eval", PROG, os.path.join(w, "MODEL"), test, "-o", os.path.join(w, "OUT3"))
        inside = p.stderr.count("lies outside the training range")
        if inside > 3:
            fail("%d of 25 test samples drawn from the training box flagged outside:\n%s" % (inside, p.stderr))

def max_error(w, model, test, mu, data):
    out = os.path.join(w, "OUT_" + os.path.basename(model))
    run("eval", PROG, model, test, "-o", out)
    red = np.load(os.path.join(out, "u.npy"))
    return max(np.linalg.norm(solve(mu[k], *data) - red[k]) / np.linalg.norm(solve(mu[k], *data))
               for k in range(len(mu)))


def greedy_line(model):
    for l in open(os.path.join(model, "manifest")):
        if l.startswith("greedy "):
            return l.split()
    fail("no greedy line in %s/manifest" % model)


def greedy():
    data = grid(8)
    rng = np.random.default_rng(42)
    with tempfile.TemporaryDirectory() as w:
        start, pool, test = (os.path.join(w, n) for n in ("START", "POOL", "TEST"))
        write(start, rng.uniform(0.1, 1, (1, 4)), *data)
        write(pool, rng.uniform(0.1, 1, (40, 4)), *data)
        mu_test = rng.uniform(0.1, 1, (20, 4))
        write(test, mu_test, *data)
        pod, gm, bm = (os.path.join(w, n) for n in ("POD", "GREEDY", "BUDGET"))
        run("train", PROG, pool, "--basis", "u:cap=60", "-o", pod)
        p = run("train", PROG, start, "--greedy", pool, "--tol", "1e-3", "--basis", "u:cap=60,energy=1", "-o", gm)
        if p.stderr.count("greedy: ") < 2:
            fail("no progress of greedy training on stderr:\n" + p.stderr)
        line = greedy_line(gm)
        chosen = line[line.index("chosen") + 1].split(",")
        if line[line.index("converged") + 1] != "1" or len(chosen) >= 40 or len(set(chosen)) != len(chosen):
            fail("greedy did not converge with fewer full evaluations than the pool: " + " ".join(line))
        e_pod, e_greedy = max_error(w, pod, test, mu_test, data), max_error(w, gm, test, mu_test, data)
        print("greedy: %d full evaluations, max relative error %.3e; POD of the 40 candidates: %.3e"
              % (len(chosen) + 1, e_greedy, e_pod))
        if not e_greedy <= e_pod:
            fail("the greedy model (%d samples) is less accurate than POD of the pool: %.3e > %.3e"
                 % (len(chosen) + 1, e_greedy, e_pod))
        p = run("train", PROG, start, "--greedy", pool, "--tol", "1e-9", "--budget", "4", "-o", bm)
        line = greedy_line(bm)
        if "stopped at the budget of 4 training samples" not in p.stderr or line[line.index("converged") + 1] != "0" \
                or len(line[line.index("chosen") + 1].split(",")) != 3:
            fail("a budget of 4 did not stop greedy training with a message:\n%s\n%s" % (p.stderr, " ".join(line)))
        p = run("train", PROG, start, "--tol", "1e-3", "-o", os.path.join(w, "X"), ok=False)
        if p.returncode == 0 or "--tol, --budget and --absolute are options of greedy training" not in p.stderr:
            fail("--tol without --greedy was accepted:\n" + p.stderr)


if __name__ == "__main__":
    main()
    greedy()
    print("ok")
