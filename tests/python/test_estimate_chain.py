"""The propagation of input errors through the stages (issue 41, docs/estimates.md): a stage whose
tensor inputs carry an error reports an estimate, its residual plus the propagation of each input's
error by the stage's local reduced Jacobian (and the secant along its worst direction). Checked
against the full evaluation on held-out samples: effectivity (estimate / true error) within
[1/3, 30] on programs of two and three stages, a polynomial chain and a contraction feeding a
solve; the estimate is flagged an estimate (not a bound). Interpolated stages: the residual of the
formula at the fit's entries and at check entries drawn from the others (n-body gravity's w)."""
import numpy as np
import pytest

import npg

N = 40

CHAIN = """
dim N
param a : real[N]
input x : real[N]
s[i:N] = x[i] * x[i] + a[i] * x[i]
t[i:N] = s[i] * x[i] + s[i]
output y[i:N] = t[i] * s[i] + x[i]
basis s: cap 3
basis t: cap 6
basis y: energy 1
"""

# 1-D heat with a conductivity that is itself a stage (kappa = 1 + x²): its projection error
# reaches the solve through the operator's tensors.
SOLVE = """
dim N
param nbr : int[N, 2]
param src : real[N]
input x : real[N]
kappa[i:N] = 1 + x[i] * x[i]
op K[i:N, j:N] = delta(i, j) * (1 + sum(k = 0..1, if(nbr[i, k] >= 0, kappa[i], 0))) - sum(k = 0..1, if(nbr[i, k] == j, kappa[i], 0))
basis kappa: cap 2
basis u: energy 1
output u = solve(K, src)
"""


def inputs(rng, count):
    """x in a three-dimensional family of smooth profiles, so x's own basis holds it exactly."""
    s = np.linspace(0, 1, N)
    modes = np.stack([np.sin(np.pi * s), np.sin(2 * np.pi * s), np.cos(np.pi * s)])
    return rng.uniform(-1, 1, (count, 3)) @ modes


def effectivities(prog, params, out, rng, train=24, test=12):
    full = prog.full(params=params)
    tr = npg.Trainer(full)
    for x in inputs(rng, train):
        tr.add(x=x)
    red = tr.finish().reduced()
    eff = []
    for x in inputs(rng, test):
        red(x=x)
        err = np.linalg.norm(full(x=x)[out] - red.lift(out))
        info = red.estimate_info(out)
        assert info["why"] == "" and not info["bound"], info
        eff.append(info["estimate"] / err)
    return np.array(eff)


def test_polynomial_chain_propagates_errors():
    rng = np.random.default_rng(3)
    prog = npg.compile(CHAIN)
    eff = effectivities(prog, {"a": np.linspace(-1, 1, N)}, "y", rng)
    print("chain effectivity %.3g .. %.3g" % (eff.min(), eff.max()))
    assert 1 / 3 <= eff.min() and eff.max() <= 30, eff


def test_contraction_into_a_solve_propagates_errors():
    rng = np.random.default_rng(5)
    nbr = -np.ones((N, 2), np.int32)
    nbr[1:, 0] = np.arange(N - 1)
    nbr[:-1, 1] = np.arange(1, N)
    prog = npg.compile(SOLVE)
    eff = effectivities(prog, {"nbr": nbr, "src": np.ones(N)}, "u", rng)
    print("solve effectivity %.3g .. %.3g" % (eff.min(), eff.max()))
    assert 1 / 3 <= eff.min() and eff.max() <= 30, eff


def test_input_without_estimate_still_blocks():
    """An exact input chain keeps its bound: x set by its values lies in its basis (error 0)."""
    rng = np.random.default_rng(9)
    prog = npg.compile(CHAIN.replace("basis s: cap 3", "basis s: energy 1").replace("basis t: cap 6", "basis t: energy 1"))
    full = prog.full(params={"a": np.linspace(-1, 1, N)})
    tr = npg.Trainer(full)
    for x in inputs(rng, 24):
        tr.add(x=x)
    red = tr.finish().reduced()
    red(x=inputs(rng, 1)[0])
    assert red.estimate_info("s")["bound"]
    assert np.isfinite(red.estimate("y"))


def nbody(root, rng, n_bodies, tmp_path=None, how="interp"):
    """tests/programs/nbody_gravity.npg with w = r2^(-3/2) interpolated (or, how="galerkin",
    reduced by Galerkin: a root) and an output: the effectivity of its own estimate and of the
    acceleration's, against the full evaluation (with tmp_path, through a model saved and loaded)."""
    src = (root / "tests/programs/nbody_gravity.npg").read_text().replace("\nw[i:N", "\noutput w[i:N")
    prog = npg.compile(src)
    full = prog.full(params={"mass": rng.uniform(1, 2, n_bodies), "eps": 0.1})
    base, modes = rng.normal(size=(n_bodies, 3)), rng.normal(size=(4, n_bodies, 3))
    tr = npg.Trainer(full, **{how: ["w"]})
    for c in rng.uniform(-1, 1, (30, 4)):
        tr.add(x=base + 0.2 * np.tensordot(c, modes, 1))
    model = tr.finish(model_dir=str(tmp_path / "m")) if tmp_path else tr.finish()
    if tmp_path:
        model = npg.load(prog, str(tmp_path / "m"), full=full)
    red = model.reduced()
    rows = []
    for c in rng.uniform(-1, 1, (6, 4)):
        x = base + 0.2 * np.tensordot(c, modes, 1)
        red(x=x)
        f = full(x=x)
        rows.append([red.estimate(q) / np.linalg.norm(f[q] - red.lift(q)) for q in ("w", "a")])
        assert red.estimate_info("w")["why"] == "" and red.estimate_info("a")["why"] == ""
    return np.array(rows)


def test_interpolated_stage_exhaustive_check_is_its_error(root, tmp_path):
    """12 bodies: w has 144 entries, and its check entries are all those the fit leaves out, so
    the estimate is the error of the formula at the reduced inputs (r2's roundoff aside)."""
    eff = nbody(root, np.random.default_rng(1), 12, tmp_path)
    print("n-body 12: w effectivity %.6f .. %.6f, a %.3g .. %.3g" % (eff[:, 0].min(), eff[:, 0].max(),
                                                                      eff[:, 1].min(), eff[:, 1].max()))
    assert np.allclose(eff[:, 0], 1, rtol=1e-6), eff
    assert 1 / 3 <= eff[:, 1].min() and eff[:, 1].max() <= 30, eff


def test_interpolated_stage_sampled_check(root):
    """40 bodies: w's 1600 entries, the residual sampled at 64 of those the fit leaves out."""
    eff = nbody(root, np.random.default_rng(1), 40)
    print("n-body 40: w effectivity %.3g .. %.3g, a %.3g .. %.3g" % (eff[:, 0].min(), eff[:, 0].max(),
                                                                  eff[:, 1].min(), eff[:, 1].max()))
    assert 0.5 <= eff[:, 0].min() and eff[:, 0].max() <= 2, eff
    assert 1 / 3 <= eff[:, 1].min() and eff[:, 1].max() <= 30, eff


def test_galerkin_root_stage_sampled_check(root, tmp_path):
    """w = r2^(-3/2) by Galerkin (a root of a diagonal operator, no residual table): its estimate
    from the formula's residual at 64 of its 144 entries, through a saved and loaded model."""
    eff = nbody(root, np.random.default_rng(1), 12, tmp_path, how="galerkin")
    print("n-body 12 Galerkin: w effectivity %.3g .. %.3g, a %.3g .. %.3g" % (eff[:, 0].min(), eff[:, 0].max(),
                                                                           eff[:, 1].min(), eff[:, 1].max()))
    assert 0.3 <= eff[:, 0].min() and eff[:, 0].max() <= 3, eff
    assert 1 / 3 <= eff[:, 1].min() and eff[:, 1].max() <= 30, eff
