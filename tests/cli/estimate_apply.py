"""estimate_apply.py BUILD_DIR — the online error estimate of operator applications (issue 41):
y = M(w) x (tests/programs/op_application.npg, M_ij = a_ij w_i w_j, a symmetric positive definite),
its square M² x, M applied to an unnamed numerator x + v, terms of two operators, K⁻¹ M x and
M K⁻¹ x (K = a + diag(w)), roots K^(1/2) x, K^(-1/2) x, K^(2/3) (x + v), roots of power above 1 K^(3/2) x,
K^(-3/2) x, K^(5/3) x, roots among several operators K⁻¹ M^(1/2) x and M^(1/2) K⁻¹ x, a diagonal operator
among them K⁻¹ diag(w)⁻¹ x and K diag(w)⁻¹ x (x / w), powers below −1 K^-2 x, M K^-2 x and K^-2 M x, and beyond
the dense limit the thermal block's K x, K² x, K^(1/2) x, K^(3/2) x, K^(-3/2) x, K^-2 x (900 unknowns; the last a
bound by the min-θ bound), as a user runs them: npgc train, npgc eval
(OUT/NAME.estimate.npy). The true errors come from numpy's own products (an independent oracle).
With inputs in their bases (x and w in three-dimensional families) the figure of y = M x is the
projection residual ‖(I − BBᵀ) M B x̂‖ itself: effectivity 1 to rounding, flagged a bound. Where
‖M‖ or σ_min enters (an input x off its basis, a second power, a numerator's own projection error:
v's family of 8 decaying modes is truncated in the numerator's basis; an inverse; a root's
quadrature) the figure is an estimate: at least the true error and at most 20 times it on every
test sample (30 for M K⁻¹ x, whose chain multiplies ‖M‖ by 1/σ_min(K), five times ‖M K⁻¹‖ here)."""
import os
import subprocess
import sys
import tempfile

import numpy as np

B = sys.argv[1]
N = 40
PROG = "tests/programs/op_application.npg"
CHAIN = """dim N
param  a : real[N, N]
input  w : real[N]
input  x : real[N]
input  v : real[N]
op M[i:N, j:N] = a[i, j] * w[i] * w[j]
op K[i:N, j:N] = a[i, j] + delta(i, j) * w[i]
output s = M^2 * x
output z = M * (x + v)
output u = K^-1 * (M * x)
output q = M * (K^-1 * x)
"""
ROOTS = """dim N
param  a : real[N, N]
input  w : real[N]
input  x : real[N]
input  v : real[N]
op K[i:N, j:N] = a[i, j] + delta(i, j) * w[i]
output r = root(K, 2) * x
output h = K^(-1/2) * x
output g = K^(2/3) * (x + v)
"""
# roots of power above 1 (the fractional part's quadrature carried through the integer part) and roots among
# several operators, then a diagonal operator (diag(w)⁻¹, from x / w) among them: programs of their own, so that
# each class stays below the full space (x's class takes up to 8 vectors a member)
ROOTSX = """dim N
param  a : real[N, N]
input  w : real[N]
input  x : real[N]
op K[i:N, j:N] = a[i, j] + delta(i, j) * w[i]
op M[i:N, j:N] = a[i, j] * w[i] * w[j]
output p = K^(3/2) * x
output n = K^(-3/2) * x
output f = K^(5/3) * x
output c = K^-1 * (M^(1/2) * x)
output l = M^(1/2) * (K^-1 * x)
"""
DIAGX = """dim N
param  a : real[N, N]
input  w : real[N]
input  x : real[N]
op K[i:N, j:N] = a[i, j] + delta(i, j) * w[i]
output dv = K^-1 * (x / w)
output da = K * (x / w)
"""
# powers below −1 (two Galerkin solves by one factorization, each chained as an inverse), alone and among several
# operators (the applied M joined with the first solve's residual in K⁻² M x): ROOTSX's declarations
NEGPOW = ROOTSX[:ROOTSX.index("output")] + """output n2 = K^-2 * x
output mk = M * (K^-2 * x)
output km = K^-2 * (M * x)
"""


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def run(*args):
    p = subprocess.run([os.path.join(B, "npgc")] + list(args), capture_output=True, text=True)
    if p.returncode != 0:
        fail("npgc %s: %s%s" % (" ".join(args), p.stdout, p.stderr))
    return p


def data(rng):
    t = np.linspace(0, 1, N)
    g = rng.standard_normal((N, N)) / np.sqrt(N)
    a = g @ g.T + 0.5 * np.eye(N)  # symmetric positive definite, so is every M(w) with w > 0
    phi = np.array([np.sin(np.pi * (k + 1) * t) for k in range(3)])
    psi = np.array([np.cos(np.pi * k * t) * 0.5 ** k for k in range(8)])
    return a, phi, psi


def samples(rng, phi, psi, S, noise=0.0):
    w = 1 + 0.3 * rng.uniform(-1, 1, (S, 3)) @ phi
    x = rng.uniform(-1, 1, (S, 3)) @ phi + noise * rng.standard_normal((S, N))
    v = rng.uniform(-1, 1, (S, 8)) @ psi
    return {"w": w, "x": x, "v": v}


def write(d, arrays):
    """A data folder: each array as NAME.npy."""
    os.makedirs(d)
    [np.save(os.path.join(d, name + ".npy"), arr) for name, arr in arrays.items()]


def effectivity(out, name, truth):
    est = np.load(os.path.join(out, name + ".estimate.npy"))
    red = np.load(os.path.join(out, name + ".npy"))
    err = np.linalg.norm(truth - red, axis=1)
    return est / err, err


def check(label, eff, err, lo, hi):
    print("%s: effectivity %.6g .. %.6g (true errors %.2e .. %.2e)" % (label, eff.min(), eff.max(), err.min(),
                                                                      err.max()))
    if not (eff >= lo).all() or not (eff <= hi).all():
        fail("%s: effectivity outside [%g, %g] at samples %s" % (label, lo, hi,
                                                                 np.nonzero((eff < lo) | (eff > hi))[0]))


def main():
    rng = np.random.default_rng(41)
    a, phi, psi = data(rng)
    M = lambda w: a * np.outer(w, w)
    K = lambda w: a + np.diag(w)
    with tempfile.TemporaryDirectory() as d:
        train, test, noisy = (os.path.join(d, n) for n in ("TRAIN", "TEST", "NOISY"))
        write(train, dict(samples(rng, phi, psi, 20), a=a))
        st, sn = samples(rng, phi, psi, 10), samples(rng, phi, psi, 10, noise=1e-3)
        write(test, dict(st, a=a))
        write(noisy, dict(sn, a=a))
        (wt, xt, vt), (wn, xn) = (st[k] for k in "wxv"), (sn[k] for k in "wx")
        model = os.path.join(d, "MODEL")
        run("train", PROG, train, "--basis", "x:cap=8", "-o", model)
        manifest = open(os.path.join(model, "manifest")).read()
        if "estimate y 0 dim" not in manifest:
            fail("the model holds no estimate table for y = M x:\n" + manifest)
        out = os.path.join(d, "OUT")
        p = run("eval", PROG, model, test, "-o", out)
        truth = np.array([M(wt[k]) @ xt[k] for k in range(len(wt))])
        eff, err = effectivity(out, "y", truth)
        check("y = M x, inputs in their bases", eff, err, 1 - 1e-6, 1 + 1e-6)
        if p.stdout.count(" b\n") + p.stdout.count(" b!\n") != len(wt):
            fail("the figures of y = M x with exact inputs are not flagged bounds:\n" + p.stdout)
        out = os.path.join(d, "OUTN")
        p = run("eval", PROG, model, noisy, "-o", out)
        truth = np.array([M(wn[k]) @ xn[k] for k in range(len(wn))])
        eff, err = effectivity(out, "y", truth)
        check("y = M x, x off its basis (noise 1e-3)", eff, err, 1, 20)
        if " b\n" in p.stdout:
            fail("a figure with ‖M‖ estimated is flagged a bound:\n" + p.stdout)
        prog = os.path.join(d, "chain.npg")
        open(prog, "w").write(CHAIN)
        model = os.path.join(d, "CHAIN")
        run("train", prog, train, "--basis", "x:cap=8", "--basis", "v:energy=1", "-o", model)
        out = os.path.join(d, "OUTC")
        run("eval", prog, model, test, "-o", out)
        truth = np.array([M(wt[k]) @ M(wt[k]) @ xt[k] for k in range(len(wt))])
        check("s = M² x", *effectivity(out, "s", truth), 1, 20)
        truth = np.array([M(wt[k]) @ (xt[k] + vt[k]) for k in range(len(wt))])
        check("z = M (x + v)", *effectivity(out, "z", truth), 1, 20)
        truth = np.array([np.linalg.solve(K(wt[k]), M(wt[k]) @ xt[k]) for k in range(len(wt))])
        check("u = K⁻¹ M x", *effectivity(out, "u", truth), 1, 20)
        truth = np.array([M(wt[k]) @ np.linalg.solve(K(wt[k]), xt[k]) for k in range(len(wt))])
        # the inverse's error then M: ‖M‖ / σ_min(K) ≈ 5 times ‖M K⁻¹‖ here (a ≈ M, K ≈ a + I), a factor the
        # chain of one figure per operator cannot see: up to 30
        check("q = M K⁻¹ x", *effectivity(out, "q", truth), 1, 30)
        if "\nestops u 0 " not in open(os.path.join(model, "manifest")).read():
            fail("the model holds no ratios per operator (an estops line) for u = K⁻¹ M x")
        roots(d, a, train, test, st)
        negative_powers(d, a, train, test, st)


def roots(d, a, train, test, st):
    """Roots of K, each figure a quadrature of the shifted systems' residuals (docs/estimates.md, Roots)."""
    K = lambda w: a + np.diag(w)

    def power(A, alpha):
        lam, Q = np.linalg.eigh(A)
        return Q @ np.diag(lam ** alpha) @ Q.T

    prog, model, out = (os.path.join(d, n) for n in ("roots.npg", "ROOTS", "OUTR"))
    open(prog, "w").write(ROOTS)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    run("eval", prog, model, test, "-o", out)
    w, x, v = st["w"], st["x"], st["v"]
    for name, alpha, label, rhs in (("r", 0.5, "K^(1/2) x", x), ("h", -0.5, "K^(-1/2) x", x),
                                    ("g", 2 / 3, "K^(2/3) (x + v)", x + v)):
        truth = np.array([power(K(w[k]), alpha) @ rhs[k] for k in range(len(w))])
        check(label, *effectivity(out, name, truth), 1, 20)
    prog, model, out = (os.path.join(d, n) for n in ("rootsx.npg", "ROOTSX", "OUTX"))
    open(prog, "w").write(ROOTSX)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    manifest = open(os.path.join(model, "manifest")).read()
    for line in ("\nestops p 0 ", "\nestops f 0 ", "\nestops c 0 ", "\nestops l 0 ", "\nestimate n 0 dim "):
        if line not in manifest:
            fail("the model holds no '%s' line (a root's table or its ‖M‖ ratio):\n%s" % (line.strip(), manifest))
    run("eval", prog, model, test, "-o", out)
    M = lambda w: a * np.outer(w, w)
    for name, label, truth in (
            ("p", "K^(3/2) x", lambda k: power(K(w[k]), 1.5) @ x[k]),
            ("n", "K^(-3/2) x", lambda k: power(K(w[k]), -1.5) @ x[k]),
            ("f", "K^(5/3) x", lambda k: power(K(w[k]), 5 / 3) @ x[k]),
            ("c", "K⁻¹ M^(1/2) x", lambda k: np.linalg.solve(K(w[k]), power(M(w[k]), 0.5) @ x[k])),
            ("l", "M^(1/2) K⁻¹ x", lambda k: power(M(w[k]), 0.5) @ np.linalg.solve(K(w[k]), x[k]))):
        check(label, *effectivity(out, name, np.array([truth(k) for k in range(len(w))])), 1, 20)
    prog, model, out = (os.path.join(d, n) for n in ("diagx.npg", "DIAGX", "OUTD"))
    open(prog, "w").write(DIAGX)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    if "\nestops dv 0 " not in open(os.path.join(model, "manifest")).read():
        fail("the model holds no ratios per operator for K⁻¹ diag(w)⁻¹ x")
    run("eval", prog, model, test, "-o", out)
    for name, label, truth in (("dv", "K⁻¹ diag(w)⁻¹ x", lambda k: np.linalg.solve(K(w[k]), x[k] / w[k])),
                               ("da", "K diag(w)⁻¹ x", lambda k: K(w[k]) @ (x[k] / w[k]))):
        check(label, *effectivity(out, name, np.array([truth(k) for k in range(len(w))])), 1, 20)


def negative_powers(d, a, train, test, st):
    """Powers below −1 of K, alone and beside M (docs/estimates.md, Powers below −1): each solve's error divided by
    σ_min(K) ≈ c σ_min(K̂) (K is not diagonally dominant here: no min-θ bound), an estimate."""
    K = lambda w: a + np.diag(w)
    M = lambda w: a * np.outer(w, w)
    solve2 = lambda A, b: np.linalg.solve(A, np.linalg.solve(A, b))
    prog, model, out = (os.path.join(d, n) for n in ("negpow.npg", "NEGPOW", "OUTP"))
    open(prog, "w").write(NEGPOW)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    manifest = open(os.path.join(model, "manifest")).read()
    for line in ("\nestimate n2 0 dim ", "\nestops mk 0 ", "\nestops km 0 "):
        if line not in manifest:
            fail("the model holds no '%s' line (a power below -1's table or its ratios):\n%s" % (line.strip(), manifest))
    p = run("eval", prog, model, test, "-o", out)
    if " b\n" in p.stdout or " b!\n" in p.stdout:
        fail("a figure with σ_min's ratio is flagged a bound:\n" + p.stdout)
    w, x = st["w"], st["x"]
    for name, label, truth in (("n2", "K^-2 x", lambda k: solve2(K(w[k]), x[k])),
                               ("mk", "M K^-2 x", lambda k: M(w[k]) @ solve2(K(w[k]), x[k])),
                               ("km", "K^-2 M x", lambda k: solve2(K(w[k]), M(w[k]) @ x[k]))):
        check(label, *effectivity(out, name, np.array([truth(k) for k in range(len(w))])), 1, 20)


def sparse():
    """Beyond the dense limit of 800 rows: the thermal block's K(mu) (tests/cli/thermal_block.npg, 30 x 30 cells)
    applied to an input x of three smooth modes, its square and its root; ‖K‖ and σ_min(K) measured in training
    by Lanczos on the sparse operator (K's on KᵀK, the root's on K⁻¹), the root's λ_min by the min-θ bound. Then
    K^(3/2) x and K^(-3/2) x in a model of their own (‖K‖'s ratio by Lanczos for the first)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import estimate_sparse as sp
    G = 30
    nbr, blk, src = sp.grid(G)
    prog = open(sp.PROG).read().replace("basis u: max 8\n", "").replace(
        "output u = solve(K, src)\n", "input x : real[N]\noutput v = K * x\noutput s = K^2 * x\noutput r = root(K, 2) * x\n")
    with tempfile.TemporaryDirectory() as d:
        open(os.path.join(d, "block.npg"), "w").write(prog)
        model, out = os.path.join(d, "MODEL"), os.path.join(d, "OUT")
        train, test, mu, x = sp.block_inputs(d, G, np.random.default_rng(5))
        run("train", os.path.join(d, "block.npg"), train, "-o", model)
        manifest = open(os.path.join(model, "manifest")).read()
        if "sigma nan" in manifest or "\ntheta r 0 input mu" not in manifest:
            fail("a ratio of the sparse operator was not measured, or the root's operator, affine in mu with "
                 "semidefinite terms, has no min-θ anchors:\n" + manifest)
        run("eval", os.path.join(d, "block.npg"), model, test, "-o", out)
        truth = {"v": [], "s": [], "r": [], "p": [], "n": [], "m": []}
        for k in range(len(mu)):
            c = sp.faces(mu[k], nbr, blk)
            K = np.column_stack([sp.apply_spd(e, c, nbr) for e in np.eye(G * G)])
            lam, Q = np.linalg.eigh(K)
            truth["v"].append(K @ x[k]), truth["s"].append(K @ K @ x[k])
            truth["r"].append(Q @ (np.sqrt(lam) * (Q.T @ x[k])))
            truth["p"].append(Q @ (lam ** 1.5 * (Q.T @ x[k]))), truth["n"].append(Q @ (lam ** -1.5 * (Q.T @ x[k])))
            truth["m"].append(Q @ (lam ** -2.0 * (Q.T @ x[k])))
        check("sparse K x", *effectivity(out, "v", np.array(truth["v"])), 1 - 1e-6, 1 + 1e-6)
        check("sparse K² x", *effectivity(out, "s", np.array(truth["s"])), 1, 20)
        check("sparse K^(1/2) x", *effectivity(out, "r", np.array(truth["r"])), 1, 20)
        prog = open(sp.PROG).read().replace("basis u: max 8\n", "").replace(
            "output u = solve(K, src)\n", "input x : real[N]\noutput p = K^(3/2) * x\noutput n = K^(-3/2) * x\n")
        open(os.path.join(d, "blockx.npg"), "w").write(prog)
        model, out = os.path.join(d, "MODELX"), os.path.join(d, "OUTX")
        run("train", os.path.join(d, "blockx.npg"), train, "-o", model)
        manifest = open(os.path.join(model, "manifest")).read()
        if "\nestops p 0 " not in manifest or "\ntheta n 0 input mu" not in manifest:
            fail("K^(3/2) has no ‖K‖ ratio, or K^(-3/2) no min-θ anchors:\n" + manifest)
        run("eval", os.path.join(d, "blockx.npg"), model, test, "-o", out)
        check("sparse K^(3/2) x", *effectivity(out, "p", np.array(truth["p"])), 1, 20)
        check("sparse K^(-3/2) x", *effectivity(out, "n", np.array(truth["n"])), 1, 20)
        sparse_negative_power(d, train, test, mu, x, np.array(truth["m"]))


def sparse_negative_power(d, train, test, mu, x, truth):
    """K^-2 x on the thermal block (a model of its own): K(mu) is affine in mu with semidefinite terms, so each
    solve's σ_min is the min-θ bound and, x being exact, the figure a bound (flagged b) on every test sample."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import estimate_sparse as sp
    prog = open(sp.PROG).read().replace("basis u: max 8\n", "").replace(
        "output u = solve(K, src)\n", "input x : real[N]\noutput m = K^-2 * x\n")
    open(os.path.join(d, "blockm.npg"), "w").write(prog)
    model, out = os.path.join(d, "MODELM"), os.path.join(d, "OUTM")
    run("train", os.path.join(d, "blockm.npg"), train, "-o", model)
    if "\ntheta m 0 input mu" not in open(os.path.join(model, "manifest")).read():
        fail("K^-2 has no min-θ anchors:\n" + open(os.path.join(model, "manifest")).read())
    p = run("eval", os.path.join(d, "blockm.npg"), model, test, "-o", out)
    if p.stdout.count(" b\n") + p.stdout.count(" b!\n") != len(mu):
        fail("the figures of K^-2 x by the min-θ bound with exact inputs are not flagged bounds:\n" + p.stdout)
    check("sparse K^-2 x", *effectivity(out, "m", truth), 1, 20)


if __name__ == "__main__":
    main()
    sparse()
    print("ok")
