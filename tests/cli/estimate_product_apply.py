"""estimate_product_apply.py BUILD_DIR — operator applications in a class orthonormal in a product H (`basis x:
product H`, the 1-D H¹ product on 40 points; issue 41, docs/estimates.md "In a product"), as a user runs them:
npgc train, npgc eval (OUT/NAME.estimate.npy), the true errors in H's norm √(eᵀHe) from numpy's own products.

An application reduces by H-projections, ŷ = (DᵀMB)^p Dᵀw with D = HB (model_term_projects): y = M x equals numpy's
B BᵀH M B BᵀH x; with x in its basis its figure is the projection residual ‖(I − BBᵀH) M B x̂‖_H itself,
effectivity 1 to rounding, flagged a bound. Where ‖M‖_H enters (a second power, two operators applied, a numerator's
own projection error: v's 8 decaying modes truncated) the figure is an estimate, at least the true error and at most
20 times it on every test sample. A solve after an application or before one, u = G⁻¹ (M x) and r = M (G⁻¹ x) with
G = H + diag(w) (affine in w, semidefinite terms), is Galerkin's on the projected x (x̂ = BᵀHx; M's result the solve's
right-hand side BᵀMB x̂), and its figure divides by the pencil's α of (G(w̄), H): u's a bound (x exact, no ratio
enters), r's an estimate, each in [1, 20]. A solve after a power above 1 has no estimate, saying why. Two solves and a
solve after a power reduce as Galerkin's at each step (two(): values against numpy, an old model refused), and so do
powers of an inverse G⁻² x, G⁻³ x (powers()); a root in the product is refused at training. With x set in
full off its basis (noise), its error enters y's figure in H's norm (npg_reduced_set's bound √‖H‖₁ ‖x − B x̂‖₂):
y's effectivity in [1, 50]."""
import os
import subprocess
import sys
import tempfile

import numpy as np

N = 40
HEAD = """dim N, W
param cols : int[N, W]
param h : real[N, W]
param a : real[N, N]
input w : real[N]
input x : real[N]
input v : real[N]
op H[i:N, j:N] = sum(k = 0..W-1, h[i, k] * delta(j, cols[i, k]))
op M[i:N, j:N] = a[i, j] * w[i] * w[j]
op K[i:N, j:N] = a[i, j] + delta(i, j) * w[i]
op G[i:N, j:N] = sum(k = 0..W-1, h[i, k] * delta(j, cols[i, k])) + delta(i, j) * w[i]
"""
APPLY = HEAD + "output y = M * x\nbasis x: product H\n"
CHAIN = HEAD + """output s = M^2 * x
output z = M * (x + v)
output q = K * (M * x)
output p = G^-1 * (M^2 * x)
basis x: product H
basis z: product H
"""
TWO = HEAD + """output t = K^-1 * (G^-1 * x)
output p = G^-1 * (M^2 * x)
basis x: product H
"""
POWERS = HEAD + """output e = G^-2 * x
output c = G^-3 * x
output f = K^-1 * (G^-2 * (M * x))
basis x: product H
"""
ROOT = HEAD + "output r = G^(1/2) * x\nbasis x: product H\n"
DIAG = HEAD + "output r[i:N] = w[i]^(-2) * x[i]\nbasis x: product H\n"
SOLVE = HEAD + """output u = G^-1 * (M * x)
output r = M * (G^-1 * x)
basis x: product H
"""


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def run(*args):
    p = subprocess.run([os.path.join(sys.argv[1], "npgc")] + list(args), capture_output=True, text=True)
    if p.returncode != 0:
        fail("npgc %s: %s%s" % (" ".join(args), p.stdout, p.stderr))
    return p


def h1(n):
    """The 1-D H¹ product on n points of [0, 1] as padded rows (cols, h) and as a dense matrix."""
    cols, h, H = -np.ones((n, 3), dtype=np.int64), np.zeros((n, 3)), np.zeros((n, n))
    dx2 = 1.0 / (n - 1) ** 2
    for i in range(n):
        for k, j in enumerate((i - 1, i, i + 1)):
            if 0 <= j < n:
                cols[i, k], h[i, k] = j, 1 + 2 / dx2 if i == j else -1 / dx2
                H[i, j] = h[i, k]
    return cols, h, H


def write(d, arrays):
    os.makedirs(d)
    [np.save(os.path.join(d, name + ".npy"), arr) for name, arr in arrays.items()]


def class_basis(model, name):
    for line in open(os.path.join(model, "manifest")):
        w = line.split()
        if len(w) > 2 and w[0] == "class" and name in w[2].strip("{}").split(","):
            return np.load(os.path.join(model, "basis_%s.npy" % w[1]))
    fail("%s/manifest: no class holds %s" % (model, name))


def check(label, est, truth, red, H, lo, hi):
    e = truth - red
    err = np.sqrt(np.einsum("si,ij,sj->s", e, H, e))
    eff = est.ravel() / err
    print("%s: effectivity %.6g .. %.6g (true errors in H's norm %.2e .. %.2e)" % (label, eff.min(), eff.max(),
                                                                                   err.min(), err.max()))
    if not (eff >= lo).all() or not (eff <= hi).all():
        fail("%s: effectivity outside [%g, %g] at samples %s" % (label, lo, hi, np.nonzero((eff < lo) | (eff > hi))[0]))


def flags(said, column):
    """The flag of every sample's figure in `npgc eval`'s table, column `column` (0: the first output)."""
    rows = [ln.split() for ln in said.splitlines() if ln.split() and ln.split()[0].isdigit()]
    return [r[2 + 2 * column] if len(r) > 2 + 2 * column else "" for r in rows]


def main():
    rng = np.random.default_rng(41)
    cols, h, H = h1(N)
    t = np.linspace(0, 1, N)
    g = rng.standard_normal((N, N)) / np.sqrt(N)
    a = g @ g.T + 0.5 * np.eye(N)
    phi = np.array([np.sin(np.pi * (k + 1) * t) for k in range(3)])
    psi = np.array([np.cos(np.pi * k * t) * 0.5 ** k for k in range(8)])
    M = lambda w: a * np.outer(w, w)
    K = lambda w: a + np.diag(w)

    def samples(S):
        return {"w": 1 + 0.3 * rng.uniform(-1, 1, (S, 3)) @ phi, "x": rng.uniform(-1, 1, (S, 3)) @ phi,
                "v": rng.uniform(-1, 1, (S, 8)) @ psi}
    params = {"cols": cols, "h": h, "a": a}
    with tempfile.TemporaryDirectory() as d:
        train, test = os.path.join(d, "TRAIN"), os.path.join(d, "TEST")
        st = samples(10)
        write(train, dict(samples(20), **params))
        write(test, dict(st, **params))
        w, x, v = st["w"], st["x"], st["v"]
        prog, model, out = (os.path.join(d, n) for n in ("apply.npg", "APPLY", "OUT"))
        open(prog, "w").write(APPLY)
        run("train", prog, train, "--basis", "x:cap=8", "-o", model)
        if "estimate y 0 dim" not in open(os.path.join(model, "manifest")).read():
            fail("the model holds no estimate table for y = M x in the product H")
        said = run("eval", prog, model, test, "-o", out).stdout
        B = class_basis(model, "y")
        y = np.load(os.path.join(out, "y.npy"))
        P = B @ B.T @ H
        want = np.array([P @ M(w[k]) @ P @ x[k] for k in range(len(w))])
        dev = abs(y - want).max() / abs(want).max()
        print("y = M x: the reduced value is the H-projections' B BᵀH M B BᵀH x to %.1e" % dev)
        if dev > 1e-10:
            fail("y = M x in the product H is not reduced by H-projections (%.1e)" % dev)
        truth = np.array([M(w[k]) @ x[k] for k in range(len(w))])
        check("y = M x, inputs in their bases", np.load(os.path.join(out, "y.estimate.npy")), truth, y, H,
              1 - 1e-6, 1 + 1e-6)
        if not all(f.startswith("b") for f in flags(said, 0)) or len(flags(said, 0)) != len(w):
            fail("the figures of y = M x with exact inputs are not flagged bounds:\n" + said)
        noisy(d, prog, model, dict(st, x=x + 0.1 * rng.standard_normal(x.shape), **params), B, H, M)
        chain(d, train, test, st, H, M, K)


def noisy(d, prog, model, st, B, H, M):
    """x set in full off its basis (noise): its own error enters in H's norm, ‖x − B BᵀHx‖_H ≤ √‖H‖₁ ‖x − B BᵀHx‖₂
    (npg_reduced_set's bound, ‖H‖₁ stored at training): y's figure at least its true error in H's norm."""
    test, out = os.path.join(d, "NOISY"), os.path.join(d, "OUTN")
    write(test, st)
    run("eval", prog, model, test, "-o", out)
    w, x = st["w"], st["x"]
    est = lambda n: np.load(os.path.join(out, n + ".estimate.npy"))
    check("y = M x, x set off its basis", est("y"), np.array([M(w[k]) @ x[k] for k in range(len(w))]),
          np.load(os.path.join(out, "y.npy")), H, 1, 50)


def chain(d, train, test, st, H, M, K):
    """Powers, a numerator's own projection error, two operators applied, and an inverse after an application."""
    prog, model, out = (os.path.join(d, n) for n in ("chain.npg", "CHAIN", "OUTC"))
    open(prog, "w").write(CHAIN)
    run("train", prog, train, "--basis", "x:cap=8", "--basis", "v:energy=1", "-o", model)
    manifest = open(os.path.join(model, "manifest")).read()
    if "\nestops q 0 " not in manifest:
        fail("the model holds no ratios per operator (an estops line) for q = K M x:\n" + manifest)
    said = run("eval", prog, model, test, "-o", out)
    said = said.stdout + said.stderr
    w, x, v = st["w"], st["x"], st["v"]
    est = lambda n: np.load(os.path.join(out, n + ".estimate.npy"))
    red = lambda n: np.load(os.path.join(out, n + ".npy"))
    truth = np.array([M(w[k]) @ M(w[k]) @ x[k] for k in range(len(w))])
    check("s = M² x", est("s"), truth, red("s"), H, 1, 20)
    truth = np.array([M(w[k]) @ (x[k] + v[k]) for k in range(len(w))])
    check("z = M (x + v)", est("z"), truth, red("z"), H, 1, 20)
    truth = np.array([K(w[k]) @ M(w[k]) @ x[k] for k in range(len(w))])
    check("q = K M x", est("q"), truth, red("q"), H, 1, 20)
    if any(f.startswith("b") for f in flags(said, 0)):
        fail("a figure with ‖M‖_H estimated is flagged a bound:\n" + said)
    if not np.isnan(est("p")).all() or "chains solves, roots or diagonal operators otherwise" not in said:
        fail("p = G⁻¹ (M² x) in a product has an estimate, or no reason for none:\n" + said)
    solves(d, train, test, st, H, M, K)


def solves(d, train, test, st, H, M, K):
    """A solve after an application and before one: Galerkin's on the projected x, G(w) = H + diag(w) affine in w with
    semidefinite terms, its α the pencil's (G(w̄), H) at training anchors."""
    prog, model, out = (os.path.join(d, n) for n in ("solve.npg", "SOLVE", "OUTS"))
    open(prog, "w").write(SOLVE)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    said = run("eval", prog, model, test, "-o", out)
    said = said.stdout + said.stderr
    w, x = st["w"], st["x"]
    est = lambda n: np.load(os.path.join(out, n + ".estimate.npy"))
    red = lambda n: np.load(os.path.join(out, n + ".npy"))
    G = lambda w: H + np.diag(w)
    B = class_basis(model, "u")
    xh = [B.T @ H @ x[k] for k in range(len(w))]
    want = np.array([B @ np.linalg.solve(B.T @ G(w[k]) @ B, B.T @ M(w[k]) @ B @ xh[k]) for k in range(len(w))])
    dev = abs(red("u") - want).max() / abs(want).max()
    want = np.array([B @ B.T @ H @ M(w[k]) @ B @ np.linalg.solve(B.T @ G(w[k]) @ B, B.T @ B @ xh[k])
                     for k in range(len(w))])
    dev = max(dev, abs(red("r") - want).max() / abs(want).max())
    print("u = G⁻¹ M x, r = M G⁻¹ x: Galerkin's on the projected x, (BᵀGB)⁻¹ BᵀMB BᵀHx and DᵀMB (BᵀGB)⁻¹ BᵀB BᵀHx, to "
          "%.1e" % dev)
    if dev > 1e-10:
        fail("u = G⁻¹ (M x) or r = M (G⁻¹ x) in the product H is not Galerkin's on the projected x (%.1e)" % dev)
    truth = np.array([np.linalg.solve(G(w[k]), M(w[k]) @ x[k]) for k in range(len(w))])
    check("u = G⁻¹ M x (the pencil's bound of G(w) against H)", est("u"), truth, red("u"), H, 1, 20)
    truth = np.array([M(w[k]) @ np.linalg.solve(G(w[k]), x[k]) for k in range(len(w))])
    check("r = M G⁻¹ x", est("r"), truth, red("r"), H, 1, 20)
    if not all(f.startswith("b") for f in flags(said, 0)):
        fail("u = G⁻¹ M x with x exact: its figure is not flagged a bound:\n" + said)
    two(d, train, test, st, H, M, K)


def fnv1a64(data):
    """The manifest's checksum (backends/model/model_store.c)."""
    h = 0xcbf29ce484222325
    for byte in data:
        h = ((h ^ byte) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h


def two(d, train, test, st, H, M, K):
    """Two solves, t = K⁻¹ G⁻¹ x, and a solve after a power, p = G⁻¹ M² x: coordinates pass into the second solve and
    through the power (model_term_coords: rows B (BᵀB)⁻¹), so t is Galerkin's at each step, (BᵀKB)⁻¹ BᵀB (BᵀGB)⁻¹ BᵀB
    x̂, and p is (BᵀGB)⁻¹ BᵀMB (BᵀB)⁻¹ BᵀMB x̂ (each power's step least-squares coordinates). Both were reduced with B
    rows, (BᵀKB)⁻¹ (BᵀGB)⁻¹ BᵀB x̂ and (BᵀGB)⁻¹ (BᵀMB)² x̂, no approximation (their errors in H's norm, printed, far
    above these); a model without the productnorm line (trained before) is refused: retrain."""
    prog, model, out = (os.path.join(d, n) for n in ("two.npg", "TWO", "OUTT"))
    open(prog, "w").write(TWO)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    run("eval", prog, model, test, "-o", out)
    w, x = st["w"], st["x"]
    red = lambda n: np.load(os.path.join(out, n + ".npy"))
    B = class_basis(model, "t")
    BB, S = B.T @ B, len(w)
    Kr = lambda k: B.T @ K(w[k]) @ B
    Gr = lambda k: B.T @ (H + np.diag(w[k])) @ B
    Mr = lambda k: B.T @ M(w[k]) @ B
    xh = [B.T @ H @ x[k] for k in range(S)]
    want_t = np.array([B @ np.linalg.solve(Kr(k), BB @ np.linalg.solve(Gr(k), BB @ xh[k])) for k in range(S)])
    want_p = np.array([B @ np.linalg.solve(Gr(k), Mr(k) @ np.linalg.solve(BB, Mr(k) @ xh[k])) for k in range(S)])
    dev = max(abs(red("t") - want_t).max() / abs(want_t).max(), abs(red("p") - want_p).max() / abs(want_p).max())
    print("t = K⁻¹ G⁻¹ x, p = G⁻¹ M² x: Galerkin's at each step (coordinates passed by B (BᵀB)⁻¹) to %.1e" % dev)
    if dev > 1e-10:
        fail("t = K⁻¹ G⁻¹ x or p = G⁻¹ M² x in the product H is not reduced as Galerkin's at each step (%.1e)" % dev)
    norm = lambda e: np.sqrt(np.einsum("si,ij,sj->s", e, H, e))
    true_t = np.array([np.linalg.solve(K(w[k]), np.linalg.solve(H + np.diag(w[k]), x[k])) for k in range(S)])
    true_p = np.array([np.linalg.solve(H + np.diag(w[k]), M(w[k]) @ M(w[k]) @ x[k]) for k in range(S)])
    old_t = np.array([B @ np.linalg.solve(Kr(k), np.linalg.solve(Gr(k), BB @ xh[k])) for k in range(S)])
    old_p = np.array([B @ np.linalg.solve(Gr(k), Mr(k) @ Mr(k) @ xh[k]) for k in range(S)])
    for lab, tr, now, old in (("t", true_t, red("t"), old_t), ("p", true_p, red("p"), old_p)):
        print("%s: errors in H's norm %.2e .. %.2e (with B rows, before: %.2e .. %.2e)" % (
            lab, norm(tr - now).min(), norm(tr - now).max(), norm(tr - old).min(), norm(tr - old).max()))
    strip_line(model, b"productnorm ")
    p = subprocess.run([os.path.join(sys.argv[1], "npgc"), "eval", prog, model, test, "-o", out + "2"], capture_output=True,
                       text=True)
    if p.returncode == 0 or "retrain" not in p.stderr:
        fail("a model of t = K⁻¹ G⁻¹ x trained before the rows of model_term_coords is not refused:\n" + p.stdout + p.stderr)
    print("an old model of t = K⁻¹ G⁻¹ x is refused: " + p.stderr.strip().splitlines()[-1][:160])
    powers(d, train, test, st, H, M, K)


def strip_line(model, prefix):
    """Model `model` resealed without its manifest lines starting with `prefix` (as a model trained before them)."""
    mf = os.path.join(model, "manifest")
    body = b"".join(ln + b"\n" for ln in open(mf, "rb").read().split(b"\n")[:-1]
                    if not ln.startswith((b"manifest ", prefix)))
    open(mf, "wb").write(body + b"manifest fnv1a64 %016x\n" % fnv1a64(body))


def powers(d, train, test, st, H, M, K):
    """Powers of an inverse, e = G⁻² x, c = G⁻³ x and f = K⁻¹ G⁻² M x: each solve after a solve takes coordinates
    (model_term_coords: the power's rows and those of what it takes, B (BᵀB)⁻¹), so e is Galerkin's step by step,
    BᵀGB ẑ = BᵀB x̂, BᵀGB ê = BᵀB ẑ; with B rows it was (BᵀGB)⁻² BᵀB x̂, no approximation (its error in H's norm,
    printed). A model of such a term without its productpowers line (trained before) is refused: retrain. A root in the
    product is refused at training, naming the stage and why, and so is a diagonal operator's inverse power w⁻² x
    (its reduced matrix packed symmetric: no R rows; with B rows 100× Galerkin's error)."""
    prog, model, out = (os.path.join(d, n) for n in ("powers.npg", "POWERS", "OUTP"))
    open(prog, "w").write(POWERS)
    run("train", prog, train, "--basis", "x:cap=8", "-o", model)
    run("eval", prog, model, test, "-o", out)
    w, x = st["w"], st["x"]
    S = len(w)
    red = lambda n: np.load(os.path.join(out, n + ".npy"))
    B = class_basis(model, "e")
    BB = B.T @ B
    G = lambda k: H + np.diag(w[k])
    Gr = lambda k: B.T @ G(k) @ B
    xh = [B.T @ H @ x[k] for k in range(S)]

    def steps(k, z, p):
        for i in range(p):
            z = np.linalg.solve(Gr(k), BB @ z if i else z)
        return z
    want = {"e": np.array([B @ steps(k, BB @ xh[k], 2) for k in range(S)]),
            "c": np.array([B @ steps(k, BB @ xh[k], 3) for k in range(S)]),
            "f": np.array([B @ np.linalg.solve(B.T @ K(w[k]) @ B, BB @ steps(k, B.T @ M(w[k]) @ B @ xh[k], 2))
                           for k in range(S)])}
    dev = max(abs(red(n) - v).max() / abs(v).max() for n, v in want.items())
    print("e = G⁻² x, c = G⁻³ x, f = K⁻¹ G⁻² M x: Galerkin's at each step to %.1e" % dev)
    if dev > 1e-10:
        fail("G⁻² x, G⁻³ x or K⁻¹ G⁻² M x in the product H is not reduced as Galerkin's at each step (%.1e)" % dev)
    norm = lambda e: np.sqrt(np.einsum("si,ij,sj->s", e, H, e))
    for n, p in (("e", 2), ("c", 3)):
        true = np.array([np.linalg.matrix_power(np.linalg.inv(G(k)), p) @ x[k] for k in range(S)])
        old = np.array([B @ np.linalg.matrix_power(np.linalg.inv(Gr(k)), p) @ BB @ xh[k] for k in range(S)])
        print("%s = G^-%d x: errors in H's norm %.2e .. %.2e (with B rows, before: %.2e .. %.2e)" % (
            n, p, norm(true - red(n)).min(), norm(true - red(n)).max(), norm(true - old).min(), norm(true - old).max()))
    strip_line(model, b"productpowers ")
    p = subprocess.run([os.path.join(sys.argv[1], "npgc"), "eval", prog, model, test, "-o", out + "2"],
                       capture_output=True, text=True)
    if p.returncode == 0 or "retrain" not in p.stderr:
        fail("a model of e = G⁻² x trained before its rows is not refused:\n" + p.stdout + p.stderr)
    print("an old model of e = G⁻² x is refused: " + p.stderr.strip().splitlines()[-1][:160])
    open(prog, "w").write(ROOT)
    p = subprocess.run([os.path.join(sys.argv[1], "npgc"), "train", prog, train, "-o", model + "R"], capture_output=True,
                       text=True)
    if p.returncode == 0 or "stage r: a root (power 1/2)" not in p.stderr or "product H" not in p.stderr:
        fail("a root in the product H is not refused at training with its reason:\n" + p.stdout + p.stderr)
    print("a root in the product is refused: " + p.stderr.strip().splitlines()[-1][:200])
    open(prog, "w").write(DIAG)
    p = subprocess.run([os.path.join(sys.argv[1], "npgc"), "train", prog, train, "-o", model + "D"], capture_output=True,
                       text=True)
    if p.returncode == 0 or "stage r: a diagonal operator's inverse power (power -2/1)" not in p.stderr:
        fail("w⁻² x (a diagonal operator) in the product H is not refused at training with its reason:\n" + p.stdout +
             p.stderr)


def sparse():
    """Beyond the dense limit of 800 rows: the thermal block's K(mu) (tests/cli/thermal_block.npg, 30 x 30 cells) applied
    to x of three smooth modes, and its square, x's class orthonormal in H = K(1, 1, 1, 1); ‖K‖_H's ratio measured by
    Lanczos in H's inner product on the sparse operator."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import estimate_sparse as sp
    G = 30
    nbr, blk, src = sp.grid(G)
    prog = open(sp.PROG).read().replace("basis u: max 8\n", "").replace(
        "output u = solve(K, src)\n", "op H[i:N, j:N] = delta(i, j) * (1 + sum(k = 0..3, if(nbr[i, k] >= 0, 1, 0))) - "
        "sum(k = 0..3, if(nbr[i, k] == j, 1, 0))\ninput x : real[N]\noutput v = K * x\noutput s = K^2 * x\n"
        "basis x: product H\n")
    stiff = lambda mu: np.column_stack([sp.apply_spd(e, sp.faces(mu, nbr, blk), nbr) for e in np.eye(G * G)])
    H = stiff(np.ones(4))
    with tempfile.TemporaryDirectory() as d:
        open(os.path.join(d, "block.npg"), "w").write(prog)
        model, out = os.path.join(d, "MODEL"), os.path.join(d, "OUT")
        train, test, mu, x = sp.block_inputs(d, G, np.random.default_rng(5))
        run("train", os.path.join(d, "block.npg"), train, "-o", model)
        if "estimate s 0 dim" not in open(os.path.join(model, "manifest")).read() or "sigma nan" in open(
                os.path.join(model, "manifest")).read():
            fail("K² x beyond the dense limit in a product has no table or no ratio")
        run("eval", os.path.join(d, "block.npg"), model, test, "-o", out)
        Ks = [stiff(mu[k]) for k in range(len(mu))]
        est = lambda n: np.load(os.path.join(out, n + ".estimate.npy"))
        red = lambda n: np.load(os.path.join(out, n + ".npy"))
        check("sparse K x", est("v"), np.array([Ks[k] @ x[k] for k in range(len(mu))]), red("v"), H, 1 - 1e-6, 1 + 1e-6)
        check("sparse K² x", est("s"), np.array([Ks[k] @ Ks[k] @ x[k] for k in range(len(mu))]), red("s"), H, 1, 20)


if __name__ == "__main__":
    main()
    sparse()
    print("ok")
