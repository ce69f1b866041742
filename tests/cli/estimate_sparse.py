"""estimate_sparse.py BUILD_DIR — the online error estimate of an inverse stage whose operator is too
large for a dense SVD in training (issue 41): σ_min measured on the sparse operator (Lanczos on K⁻¹
through one CHOLMOD Cholesky for the SPD thermal block, on (KᵀK)⁻¹ through one UMFPACK LU for a
nonsymmetric one). The thermal block of tests/cli/thermal_block.npg on a 60 x 60 grid (3600
unknowns): on every test sample the estimate is at least the true error and at most 20 times it,
the true errors from numpy (conjugate gradients on the same operator, an independent oracle). The
same with a convection term (nonsymmetric, 30 x 30 = 900 unknowns, beyond the dense limit of 800
rows) against numpy's dense solve. The SPD block's operator is affine in mu with semidefinite terms:
its estimate is the min-θ bound (flagged b, the manifest's theta line); the convective one, and one
whose conductivities enter squared, stay estimates (e, no theta line). With u's basis orthonormal in a
product 2I (40 x 40 = 1600 unknowns), the operator at no parameter: the pencil's bound by Lanczos, in
that product's norm."""
import os
import subprocess
import sys
import tempfile

import numpy as np

B = sys.argv[1]
PROG = "tests/cli/thermal_block.npg"
# a one-sided flux to the +x neighbour: K no longer symmetric, still nonsingular
CONV = " + sum(k = 0..3, if(nbr[i, k] == j, 0.4 * if(k == 0, 1, 0), 0)) - delta(i, j) * 0.4 * if(nbr[i, 0] >= 0, 1, 0)"


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def grid(G):
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
    for name, a in (("nbr", nbr), ("blk", blk), ("src", src), ("mu", mu)):
        np.save(os.path.join(d, name + ".npy"), a)


def block_inputs(d, G, rng):
    """TRAIN/ (12 samples) and TEST/ (6) under d for the G x G block (mu uniform in [0.1, 1]) with an input x of three
    smooth modes (tests/cli/estimate_apply.py, estimate_product_apply.py); returns (train, test, the test mu and x)."""
    nbr, blk, src = grid(G)
    cx, cy = np.arange(G * G) % G / G, np.arange(G * G) // G / G
    phi = np.array([np.sin(np.pi * (i + 1) * cx) * np.sin(np.pi * (j + 1) * cy) for i, j in ((0, 0), (1, 0), (0, 1))])
    train, test = os.path.join(d, "TRAIN"), os.path.join(d, "TEST")
    write(train, rng.uniform(0.1, 1, (12, 4)), nbr, blk, src)
    np.save(os.path.join(train, "x.npy"), rng.uniform(-1, 1, (12, 3)) @ phi)
    mu, x = rng.uniform(0.1, 1, (6, 4)), rng.uniform(-1, 1, (6, 3)) @ phi
    write(test, mu, nbr, blk, src)
    np.save(os.path.join(test, "x.npy"), x)
    return train, test, mu, x


def faces(mu, nbr, blk):
    """Each (cell, neighbour slot)'s conductance, 0 where there is no neighbour."""
    c = 0.5 * (mu[blk][:, None] + mu[blk[np.maximum(nbr, 0)]])
    return np.where(nbr >= 0, c, 0.0)


def apply_spd(x, c, nbr):
    return x + c.sum(1) * x - (c * x[np.maximum(nbr, 0)]).sum(1)


def solve_cg(mu, nbr, blk, src):
    """K(mu) u = src by conjugate gradients (K SPD), to a relative residual of 1e-14."""
    c = faces(mu, nbr, blk)
    u, r = np.zeros_like(src), src.copy()
    p, rr = r.copy(), r @ r
    for _ in range(5000):
        q = apply_spd(p, c, nbr)
        a = rr / (p @ q)
        u += a * p
        r -= a * q
        rn = r @ r
        if np.sqrt(rn) <= 1e-14 * np.linalg.norm(src):
            return u
        p, rr = r + rn / rr * p, rn
    fail("numpy's conjugate gradients did not converge")


def solve_conv(mu, nbr, blk, src):
    """The convective variant assembled dense by numpy and solved."""
    N = len(blk)
    c = faces(mu, nbr, blk)
    K = np.eye(N) + np.diag(c.sum(1))
    for k in range(4):
        rows = np.nonzero(nbr[:, k] >= 0)[0]
        K[rows, nbr[rows, k]] -= c[rows, k]
    rows = np.nonzero(nbr[:, 0] >= 0)[0]
    K[rows, nbr[rows, 0]] += 0.4
    K[rows, rows] -= 0.4
    return np.linalg.solve(K, src)


def run(*args):
    p = subprocess.run([os.path.join(B, "npgc")] + list(args), capture_output=True, text=True)
    if p.returncode != 0:
        fail("npgc %s: %s%s" % (" ".join(args), p.stdout, p.stderr))
    return p


def case(w, label, prog, G, ntrain, ntest, solve, seed, bound, scale=1.0):
    data = grid(G)
    rng = np.random.default_rng(seed)
    train, test, model, out = (os.path.join(w, label + n) for n in ("TRAIN", "TEST", "MODEL", "OUT"))
    write(train, rng.uniform(0.1, 1, (ntrain, 4)), *data)
    mu_test = rng.uniform(0.1, 1, (ntest, 4))
    write(test, mu_test, *data)
    run("train", prog, train, "-o", model, *(("--basis", "u:product=H") if "op H" in open(prog).read() else ()))
    manifest = open(os.path.join(model, "manifest")).read()
    if "estimate u 0 dim" not in manifest:
        fail("%s: the model holds no estimate table" % label)
    if ("theta u 0 input mu anchors" in manifest) != bound:
        fail("%s: the min-theta table is %s:\n%s" % (label, "missing" if bound else "present", manifest))
    p = run("eval", prog, model, test, "-o", out)
    flag = " b" if bound else " e"
    if sum(1 for l in p.stdout.splitlines() if l.split()[:1] and l.split()[0].isdigit() and flag in l) != ntest:
        fail("%s: not every estimate flagged%s:\n%s" % (label, flag, p.stdout))
    est = np.load(os.path.join(out, "u.estimate.npy"))
    if np.isnan(est).any():
        fail("%s (%d unknowns): no estimate:\n%s" % (label, G * G, p.stdout))
    red = np.load(os.path.join(out, "u.npy"))
    err = scale * np.array([np.linalg.norm(solve(mu_test[k], *data) - red[k]) for k in range(ntest)])
    eff = est / err
    print("%s, %d unknowns: effectivity over %d test samples %.3g .. %.3g (true errors %.2e .. %.2e)"
          % (label, G * G, ntest, eff.min(), eff.max(), err.min(), err.max()))
    if not (eff >= 1).all():
        fail("%s: the estimate is below the true error at samples %s" % (label, np.nonzero(eff < 1)[0]))
    if not (eff <= 20).all():
        fail("%s: the estimate exceeds 20x the true error at samples %s" % (label, np.nonzero(eff > 20)[0]))


def main():
    with tempfile.TemporaryDirectory() as w:
        case(w, "spd", PROG, 60, 12, 10, solve_cg, 43, True)
        conv = os.path.join(w, "conv.npg")
        with open(PROG) as f, open(conv, "w") as g:
            g.write(f.read().replace("\nbasis mu", CONV + "\nbasis mu"))
        case(w, "conv", conv, 30, 12, 10, solve_conv, 44, False)
        # conductivities squared: SPD still, not affine in mu, so no min-theta bound
        sq = os.path.join(w, "square.npg")
        with open(PROG) as f, open(sq, "w") as g:
            g.write(f.read().replace("0.5 * (mu[blk[i]] + mu[blk[nbr[i, k]]])", "0.5 * (mu[blk[i]] * mu[blk[i]] + "
                                     "mu[blk[nbr[i, k]]] * mu[blk[nbr[i, k]]])")
                    .replace("0.5 * (mu[blk[i]] + mu[blk[j]])", "0.5 * (mu[blk[i]] * mu[blk[i]] + mu[blk[j]] * mu[blk[j]])"))
        case(w, "square", sq, 8, 12, 4, lambda mu, *d: solve_cg(mu * mu, *d), 45, False)
        # u's basis orthonormal in H = 2I, the operator at no parameter, beyond the dense limit: the pencil
        # (K(mu), H) by Lanczos in H's inner product, a bound of the error in H's norm √2 ‖e‖
        hprog = os.path.join(w, "product.npg")
        with open(PROG) as f, open(hprog, "w") as g:
            g.write(f.read().replace("output u =", "op H[i:N, j:N] = delta(i, j) * 2\noutput u ="))
        case(w, "product", hprog, 40, 12, 6, solve_cg, 46, True, np.sqrt(2))
    print("ok")


if __name__ == "__main__":
    main()
