"""products.py — bases orthonormal in an inner product of the program (issue 41: `basis u:
product K0`), end to end through npgc, checked against numpy:

1. the thermal block (examples/thermalblock, grid 8): BᵀHB = I and the dual D = HB to 1e-12,
   verify passes, and the reduced u equals numpy's Galerkin solution B (BᵀKB)⁻¹ Bᵀf;
2. a problem where the product matters: snapshots of large smooth and small rough modes; the
   uncentered POD in the H¹ product keeps the rough ones (Eckart–Young in each norm): its
   H-norm projection error is far below the Euclidean basis's, which wins in the 2-norm; a
   reduced evaluation projects an input by the product (Dᵀx) where the model says so;
3. --basis x:product=H (npg_parse_basis_product) equal to the statement, bit for bit; smaller
   sizes without retraining (--sizes) project by the leading columns of HB;
4. the error estimate in the product (docs/estimates.md): a bound of the true error in H's norm
   within 10× on the thermal block, also with pyMOR's nonsymmetric Dirichlet columns; verify's
   true error in H's norm; a product that is no parameter's operator (H + I) gets the pencil's bound;
   a projection term's figure is its error in H's norm, a named numerator's error is carried into
   the inverse's (and the inverse of a named numerator in a product is Galerkin's);
5. products refused with a message naming them: not SPD, not symmetric, reading an input, in
   npgc tune (not implemented there); tests/bad/basis_product_*.npg: not a name, not an op, not
   square, of another size.

    python3 tests/cli/products.py BUILD_DIR
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "examples", "thermalblock"))
import thermalblock_data  # noqa: E402

FAILS = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what)
    if not ok:
        FAILS.append(what)


def npgc(*args, fail=False):
    r = subprocess.run([NPGC, *args], capture_output=True, text=True)
    if (r.returncode != 0) != fail:
        sys.exit(f"npgc {' '.join(args)}: exit {r.returncode}\n{r.stdout}{r.stderr}")
    return r.stdout + r.stderr


def padded_matrix(cols, vals):
    n = cols.shape[0]
    m = np.zeros((n, n))
    for i in range(n):
        for k in range(cols.shape[1]):
            if cols[i, k] >= 0:
                m[i, cols[i, k]] += vals[i, k]
    return m


def class_of(model, name):
    """The index C of basis_C.npy whose class holds quantity `name` (the manifest's class lines)."""
    for line in open(os.path.join(model, "manifest")):
        w = line.split()
        if len(w) > 2 and w[0] == "class" and name in w[2].strip("{}").split(","):
            return int(w[1])
    sys.exit(f"{model}/manifest: no class holds {name}")


def thermal_block(tmp):
    prog = os.path.join(ROOT, "examples", "thermalblock", "thermalblock.npg")
    rng = np.random.default_rng(3)
    kb, kq, hm, f = thermalblock_data.assemble(2, 2, 8)
    data, test, model, out = (os.path.join(tmp, d) for d in ("data", "test", "model", "out"))
    thermalblock_data.write_params(data, kb, kq, hm, f, rng.uniform(0.1, 1, (30, 4)))
    thermalblock_data.write_params(test, kb, kq, hm, f, rng.uniform(0.1, 1, (6, 4)))
    npgc("train", prog, data, "-o", model)
    c = class_of(model, "u")
    B = np.load(os.path.join(model, f"basis_{c}.npy"))
    D = np.load(os.path.join(model, f"dual_{c}.npy"))
    check(abs(B.T @ hm @ B - np.eye(B.shape[1])).max() < 1e-12, f"thermal block: BᵀHB = I to 1e-12 ({B.shape[1]} vectors)")
    check(abs(D - hm @ B).max() < 1e-12 * abs(hm).max(), "thermal block: the dual is HB")
    check(abs(B.T @ B - np.eye(B.shape[1])).max() > 1e-3, "thermal block: B is not Euclidean-orthonormal (the product is used)")
    report = npgc("verify", prog, model, test, "--tol", "1e-2")
    check("ok: every output within" in report, "thermal block: npgc verify passes at --tol 1e-2")
    npgc("eval", prog, model, test, "-o", out)
    u = np.load(os.path.join(out, "u.npy"))
    worst = 0
    for s, mu in enumerate(np.load(os.path.join(test, "mu.npy"))):
        K = kb + sum(m * k for m, k in zip(mu, kq))
        galerkin = B @ np.linalg.solve(B.T @ K @ B, B.T @ f)
        worst = max(worst, abs(u[s] - galerkin).max() / abs(galerkin).max())
    check(worst < 1e-10, f"thermal block: reduced u equals numpy's Galerkin B(BᵀKB)⁻¹Bᵀf ({worst:.1e})")
    kq_cols = product_estimate(tmp, prog, kb, kq, hm, f, rng)
    for label, kqs in (("symmetric", kq), ("Dirichlet columns kept", kq_cols)):
        product_terms(os.path.join(tmp, f"terms_{len(label)}"), label, kb, kqs, hm, f, rng)


def product_estimate(tmp, prog, kb, kq, hm, f, rng):
    """The estimate in the product H: ‖u − Bû‖_H ≤ ‖r‖_{H⁻¹} / min(1, min μ), a bound (b) at every
    test parameter and within 10× of numpy's true error in H's norm, and verify's true error in
    H's norm; the same with pyMOR's layout (Dirichlet rows of K_q cleared, columns not: K
    nonsymmetric), where the Dirichlet rows are left out of the coercivity check. Returns pyMOR's K_q."""
    n = f.shape[0]
    boundary = np.nonzero(np.diag(kb))[0]
    interior = np.setdiff1d(np.arange(n), boundary)
    kq_cols = []
    for k in kq:  # an interior row's entries in boundary columns, as pyMOR leaves them
        k = k.copy()
        k[np.ix_(interior, boundary)] = -0.05 * rng.uniform(0.5, 1, (len(interior), len(boundary)))
        kq_cols.append(k)
    mus = np.concatenate([rng.uniform(0.1, 1, (6, 4)), [[0.05, 1.5, 0.2, 2.0]]])  # the last outside the range
    for label, kqs in (("symmetric", kq), ("Dirichlet columns kept", kq_cols)):
        data, test, model, out = (os.path.join(tmp, f"{d}_{len(label)}") for d in ("data", "test", "model", "out"))
        thermalblock_data.write_params(data, kb, kqs, hm, f, rng.uniform(0.1, 1, (20, 4)))
        thermalblock_data.write_params(test, kb, kqs, hm, f, mus)
        npgc("train", prog, data, "-o", model, "--basis", "u:cap=6")
        npgc("eval", prog, model, test, "-o", out)
        u, est = np.load(os.path.join(out, "u.npy")), np.load(os.path.join(out, "u.estimate.npy")).ravel()
        eff = []
        for s, mu in enumerate(mus):
            e = np.linalg.solve(kb + sum(m * k for m, k in zip(mu, kqs)), f) - u[s]
            eff.append(est[s] / np.sqrt(e @ hm @ e))
        check(min(eff) >= 1 and max(eff) <= 10,
              f"thermal block, {label}: the estimate in H's norm bounds the true error, effectivity "
              f"{min(eff):.2f}..{max(eff):.2f} (in [1, 10])")
        report = npgc("verify", prog, model, test, "--tol", "1")
        row = next(ln.split() for ln in report.splitlines() if ln.startswith("estimate u "))
        lo, hi = (float(v) for v in row[4].split(".."))
        check(row[-1] == "bound" and abs(lo - min(eff)) < 6e-3 * lo and abs(hi - max(eff)) < 6e-3 * hi,
              f"thermal block, {label}: verify's effectivity {row[4]} is against the true error in H's norm, a bound")
    os.makedirs(os.path.join(tmp, "noH"))
    H2 = os.path.join(tmp, "noH", "h2.npg")  # a product H + I, the operator at no parameter: the pencil's bound
    open(H2, "w").write(open(prog).read().replace("h[i, k] * delta", "(h[i, k] + delta(i, cols[i, k])) * delta"))
    npgc("train", H2, data, "-o", model + "2", "--basis", "u:cap=6")
    said = npgc("eval", H2, model + "2", test, "-o", out + "2")
    u, est = np.load(os.path.join(out + "2", "u.npy")), np.load(os.path.join(out + "2", "u.estimate.npy")).ravel()
    h2 = hm + np.eye(n)
    eff = []
    for s, mu in enumerate(mus):
        e = np.linalg.solve(kb + sum(m * k for m, k in zip(mu, kqs)), f) - u[s]
        eff.append(est[s] / np.sqrt(e @ h2 @ e))
    flags = [ln.split()[-1] for ln in said.splitlines() if ln.split() and ln.split()[0].isdigit()]
    check(min(eff) >= 1 and max(eff) <= 20 and len(flags) == len(mus) and all(f_.startswith("b") for f_ in flags),
          f"thermal block: a product H + I, the operator at no parameter, gets the pencil's bound in its norm, "
          f"effectivity {min(eff):.2f}..{max(eff):.2f} (in [1, 20])")
    return kq_cols


PRODUCT_TERMS = """
output g[i:N] = f[i] * (1 + mu[0]) + 40 * mu[1] * mu[1] * f[i] * f[i] + 200 * mu[2] * f[i] * f[i] * f[i] + mu[3] * f[i] * h[i, 0]
output u = solve(K, g)
basis g: product H
"""


def product_terms(tmp, label, kb, kq, hm, f, rng):
    """Every term kind in a product (docs/estimates.md, "In a product"): g, a polynomial in μ projected by H
    (ŷ = BᵀH w), gets its error in H's norm exactly; u = K⁻¹g, whose numerator g is named (it joins u's class),
    gets a bound with g's error carried into H⁻¹'s norm (1/λ_min(H)), flagged an estimate (g's true values on
    the Dirichlet rows are not seen), and u's reduced value is Galerkin's, B (BᵀKB)⁻¹ BᵀB ĝ. A figure at the
    roundoff level (g's, when u's vectors span it: flagged r) is at least the true error."""
    os.makedirs(tmp)
    prog = os.path.join(tmp, "terms.npg")
    base = open(os.path.join(ROOT, "examples", "thermalblock", "thermalblock.npg")).read()
    open(prog, "w").write(base.replace("output u = solve(K, f)\n", "").replace("\nbasis u: product H", "") +
                          PRODUCT_TERMS)
    data, test, model, out = (os.path.join(tmp, d) for d in ("data", "test", "model", "out"))
    mus = rng.uniform(0.1, 1, (8, 4))
    thermalblock_data.write_params(data, kb, kq, hm, f, rng.uniform(0.1, 1, (20, 4)))
    thermalblock_data.write_params(test, kb, kq, hm, f, mus)
    npgc("train", prog, data, "-o", model, "--basis", "g:cap=1", "--basis", "u:cap=3")
    said = npgc("eval", prog, model, test, "-o", out)
    B = np.load(os.path.join(model, f"basis_{class_of(model, 'u')}.npy"))
    h0 = np.load(os.path.join(test, "h.npy"))[:, 0]
    g, u = np.load(os.path.join(out, "g.npy")), np.load(os.path.join(out, "u.npy"))
    eg, eu = (np.load(os.path.join(out, q + ".estimate.npy")).ravel() for q in ("g", "u"))
    effg, effu, galerkin = [], [], 0
    for s, mu in enumerate(mus):
        gt = f * (1 + mu[0]) + 40 * mu[1] ** 2 * f ** 2 + 200 * mu[2] * f ** 3 + mu[3] * f * h0
        K = kb + sum(m * k for m, k in zip(mu, kq))
        dg, du = gt - g[s], np.linalg.solve(K, gt) - u[s]
        effg.append(eg[s] / np.sqrt(dg @ hm @ dg))
        effu.append(eu[s] / np.sqrt(du @ hm @ du))
        want = B @ np.linalg.solve(B.T @ K @ B, B.T @ g[s])
        galerkin = max(galerkin, abs(u[s] - want).max() / abs(want).max())
    check(galerkin < 1e-10, f"product terms, {label}: u from its named numerator g is Galerkin's B(BᵀKB)⁻¹Bᵀg̃ ({galerkin:.1e})")
    flags = [ln.split()[2::2] for ln in said.splitlines() if ln.split() and ln.split()[0].isdigit()]
    exact = [abs(e - 1) < 1e-6 if "r" not in fl[0] else e >= 1 for e, fl in zip(effg, flags)]
    check(len(flags) == len(mus) and all(exact),
          f"product terms, {label}: a projection's figure is its error in H's norm (or the roundoff level, r, above it), effectivity "
          f"{min(effg):.8f}..{max(effg):.8f}")
    check(all(fl[0].startswith("b") and fl[1].startswith("e") for fl in flags),
          f"product terms, {label}: g's figure a bound, u's (its named numerator's values on the Dirichlet rows unseen) an estimate")
    check(min(effu) >= 1 and max(effu) <= 20,
          f"product terms, {label}: u's figure with g's error carried into H⁻¹'s norm bounds its error in H's norm, "
          f"effectivity {min(effu):.2f}..{max(effu):.2f} (in [1, 20])")


ROUGH = """dim N, W
param cols : int[N, W]
param h : real[N, W]
input x : real[N]
op H[i:N, j:N] = sum(k = 0..W-1, h[i, k] * delta(j, cols[i, k]))
output y[i:N] = 2 * x[i]
"""


def laplacian(n):
    """The 1D H¹ product on n points of [0, 1]: the unit diagonal plus the second difference over
    dx², as padded rows."""
    cols = -np.ones((n, 3), dtype=np.int64)
    h = np.zeros((n, 3))
    dx2 = 1.0 / (n - 1) ** 2
    for i in range(n):
        for k, j in enumerate((i - 1, i, i + 1)):
            if 0 <= j < n:
                cols[i, k] = j
                h[i, k] = 1 + 2 / dx2 if i == j else -1 / dx2
    return cols, h


def rough(tmp):
    n, s = 60, 24
    cols, h = laplacian(n)
    H = padded_matrix(cols, h)
    t = np.arange(n) / (n - 1)
    smooth = np.stack([np.sin((k + 1) * np.pi * t) for k in range(3)])
    wiggly = np.stack([np.sin((k + 30) * np.pi * t) for k in range(3)])
    rng = np.random.default_rng(5)
    X = rng.normal(size=(s, 3)) @ smooth + 0.25 * rng.normal(size=(s, 3)) @ wiggly
    Xt = rng.normal(size=(4, 3)) @ smooth + 0.25 * rng.normal(size=(4, 3)) @ wiggly
    models = {}
    os.makedirs(tmp)
    for name, basis in (("euclid", ""), ("h1", "basis x: product H\n")):
        prog = os.path.join(tmp, f"{name}.npg")
        open(prog, "w").write(ROUGH + basis)
        for d, xs in (("data", X), ("test", Xt)):
            os.makedirs(os.path.join(tmp, d), exist_ok=True)
            np.save(os.path.join(tmp, d, "cols.npy"), cols)
            np.save(os.path.join(tmp, d, "h.npy"), h)
            np.save(os.path.join(tmp, d, "x.npy"), xs)
        model = os.path.join(tmp, f"model_{name}")
        npgc("train", prog, os.path.join(tmp, "data"), "-o", model, "--center", "off", "--basis", "x:cap=3,energy=1",
             "--basis", "y:cap=6,energy=1")
        models[name] = (prog, model, np.load(os.path.join(model, f"basis_{class_of(model, 'x')}.npy")))
    Xc = X.T

    def errors(B):
        ph = B @ np.linalg.solve(B.T @ H @ B, B.T @ H @ Xc)
        pe = B @ np.linalg.lstsq(B, Xc, rcond=None)[0]
        return np.sqrt(np.einsum("ik,ij,jk->", Xc - ph, H, Xc - ph)), np.linalg.norm(Xc - pe)
    (eh_e, e2_e), (eh_h, e2_h) = errors(models["euclid"][2]), errors(models["h1"][2])
    Bh = models["h1"][2]
    check(abs(Bh.T @ H @ Bh - np.eye(3)).max() < 1e-12, "rough: BᵀHB = I to 1e-12")
    check(eh_h < eh_e / 2, f"rough: the H¹ basis's H-norm error {eh_h:.3g} is below half the Euclidean's {eh_e:.3g}")
    check(e2_e < e2_h / 2, f"rough: the Euclidean basis's 2-norm error {e2_e:.3g} is below half the H¹ one's {e2_h:.3g}")
    # the reduced evaluation projects x by the product: y = 2 B_y B_yᵀ B_x (B_xᵀ H x)
    prog, model, Bx = models["h1"]
    out = os.path.join(tmp, "out")
    npgc("eval", prog, model, os.path.join(tmp, "test"), "-o", out)
    By = np.load(os.path.join(model, f"basis_{class_of(model, 'y')}.npy"))
    want = (2 * By @ (By.T @ (Bx @ (Bx.T @ H @ Xt.T)))).T
    got = np.load(os.path.join(out, "y.npy"))
    check(abs(got - want).max() < 1e-12 * abs(want).max(), "rough: the reduced y projects x by its product (BᵀH x)")
    # at a smaller size without retraining (--sizes, model_truncate): the leading columns of B and HB
    npgc("eval", prog, model, os.path.join(tmp, "test"), "-o", os.path.join(tmp, "out2"), "--sizes", "m_x=2")
    B2 = Bx[:, :2]
    want2 = (2 * By @ (By.T @ (B2 @ (B2.T @ H @ Xt.T)))).T
    got2 = np.load(os.path.join(tmp, "out2", "y.npy"))
    check(abs(got2 - want2).max() < 1e-12 * abs(want2).max(), "rough: --sizes m_x=2 projects by the leading columns of HB")
    # --basis x:product=H: the same basis as the statement, from the program without it, and the
    # model evaluated by that program (the manifest names the product)
    eprog = models["euclid"][0]
    opt_model = os.path.join(tmp, "model_option")
    npgc("train", eprog, os.path.join(tmp, "data"), "-o", opt_model, "--center", "off", "--basis",
         "x:cap=3,energy=1,product=H", "--basis", "y:cap=6,energy=1")
    Bo = np.load(os.path.join(opt_model, f"basis_{class_of(opt_model, 'x')}.npy"))
    check(np.array_equal(Bo, Bx), "--basis x:product=H gives the basis of 'basis x: product H', bit for bit")
    npgc("eval", eprog, opt_model, os.path.join(tmp, "test"), "-o", os.path.join(tmp, "out_option"))
    check(np.array_equal(np.load(os.path.join(tmp, "out_option", "y.npy")), got),
          "a model trained with --basis x:product=H evaluates the same from the program without the statement")
    msg = npgc("eval", prog, os.path.join(tmp, "model_euclid"), os.path.join(tmp, "test"), "-o",
               os.path.join(tmp, "out_refused"), fail=True)
    check("model was trained for another program" in msg,
          "refused: a model trained without the product the program declares (another program)")
    msg = npgc("train", eprog, os.path.join(tmp, "data"), "-o", os.path.join(tmp, "m_bad"), "--basis", "x:product=Hx",
               fail=True)
    check("--basis x:product=Hx: the program has no op of that name" in msg, "refused: --basis x:product= of no op")
    msg = npgc("train", eprog, os.path.join(tmp, "data"), "-o", os.path.join(tmp, "m_bad"), "--basis", "x:product=",
               fail=True)
    check("product: no op named" in msg, "refused: --basis x:product= without a name")
    msg = npgc("tune", prog, os.path.join(tmp, "data"), os.path.join(tmp, "test"), "--tol", "0.1", "-o",
               os.path.join(tmp, "m_tune"), fail=True)
    check("product H is not implemented in tune" in msg, "refused: npgc tune of a class with a product")


def refused(tmp):
    cols, h = laplacian(10)
    d = os.path.join(tmp, "data")
    os.makedirs(d)
    np.save(os.path.join(d, "cols.npy"), cols)
    np.save(os.path.join(d, "x.npy"), np.random.default_rng(1).normal(size=(5, 10)))
    cases = [
        ("indefinite", -h, "basis x: product H\n", "product H is not positive definite"),
        ("unsymmetric", h + np.where(np.arange(3) == 2, 0.5, 0), "basis x: product H\n", "product H is not symmetric"),
    ]
    for name, hv, basis, want in cases:
        np.save(os.path.join(d, "h.npy"), hv)
        prog = os.path.join(tmp, f"{name}.npg")
        open(prog, "w").write(ROUGH + basis)
        msg = npgc("train", prog, d, "-o", os.path.join(tmp, "m_" + name), fail=True)
        check(want in msg and "basis m_x" in msg, f"refused: {want} ({msg.strip().splitlines()[-1]})")
    np.save(os.path.join(d, "h.npy"), h)
    prog = os.path.join(tmp, "reads_input.npg")
    open(prog, "w").write(ROUGH.replace("h[i, k] * delta", "x[i] * h[i, k] * delta") + "basis x: product H\n")
    msg = npgc("train", prog, d, "-o", os.path.join(tmp, "m_reads"), fail=True)
    check("product H reads 'x', which changes with the sample" in msg, "refused: a product that reads an input")
    check(not os.path.exists(os.path.join(tmp, "m_reads")), "refused: no model written")


def main():
    global NPGC
    if len(sys.argv) != 2:
        sys.exit("usage: products.py BUILD_DIR")
    NPGC = os.path.join(sys.argv[1], "npgc")
    with tempfile.TemporaryDirectory() as tmp:
        thermal_block(os.path.join(tmp, "tb"))
        rough(os.path.join(tmp, "rough"))
        refused(os.path.join(tmp, "bad"))
    if FAILS:
        sys.exit(f"{len(FAILS)} check(s) failed")


if __name__ == "__main__":
    main()
