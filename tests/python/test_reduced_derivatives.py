"""Derivatives of the reduced evaluator in reduced coordinates (issue 43, DESIGN §17):
red.jacobian, red.jvp and red.vjp against central finite differences of the reduced evaluator
(the error shrinking as h²), forward against reverse, and at full-size bases against the full
evaluator's finite differences. Galerkin contractions, inverse stages, roots (Daleckii–Krein)
and interpolated stages."""
import numpy as np
import pytest

import npg

RATIONAL = "examples/rational/rational.npg"
SOLVE = "tests/programs/solve_stage.npg"
NBODY = "tests/programs/nbody_gravity.npg"
EXTERN = "tests/programs/extern_stage.npg"
# a root of an input-dependent diagonal operator: y = diag(x² + 1)^(-1/2) u, its class {u, y}
ROOT_STAGE = """dim N
input x : real[N]
input u : real[N]
d[i:N] = x[i]^2 + 1
output y[i:N] = u[i] * d[i]^(-1/2)
"""


def trained(prog, inputs, params=None, **kw):
    full = prog.full(params=params) if params else prog.full()
    tr = npg.Trainer(full, **kw)
    for k in range(len(next(iter(inputs.values())))):
        tr.add(**{n: v[k] for n, v in inputs.items()})
    return full, tr.finish()


def gravity(S):
    rng = np.random.default_rng(4)
    base = rng.normal(size=(8, 3)) * 2
    modes = rng.normal(size=(3, 8, 3))
    return base + np.einsum("sk,kvc->svc", 0.2 * rng.normal(size=(S, 3)), modes)


def cases():
    """(name, model, test inputs, [(output, input)]) over the corpus' stage kinds."""
    rng = np.random.default_rng(0)
    x = 0.5 + rng.random((40, 2))
    _, rational = trained(npg.compile(RATIONAL), {"x": x})
    yield "rational", rational, {"x": x[3] + 0.01}, [("y", "x")]
    F = 5
    pa = {"rho": 0.3 * rng.random(F), "a": 0.2 * rng.random((F, F))}
    _, solve = trained(npg.compile(SOLVE), {"x": rng.random((30, F)), "e": rng.random((30, F))}, pa, cap=3)
    yield "solve", solve, {"x": rng.random(F), "e": rng.random(F)}, [("b", "x"), ("b", "e"), ("p", "x"), ("p", "e")]
    data, test = {"x": rng.random((30, 6)), "u": rng.random((30, 6))}, {"x": rng.random(6), "u": rng.random(6)}
    for how in ("interp", "galerkin"):  # y's diagonal root: Daleckii–Krein, or the formula at entries
        _, root = trained(npg.compile(ROOT_STAGE), data, cap=4, **{how: ["y"]})
        assert (root.interpolated("y") is not None) == (how == "interp")
        yield "root-" + how, root, test, [("y", "x"), ("y", "u")]
    xs = gravity(41)
    pa = {"mass": np.full(8, 0.125), "eps": np.array(0.05)}
    nbody = npg.compile(NBODY)
    for how in ("interp", "galerkin"):
        _, model = trained(nbody, {"x": xs[:40]}, pa, **{how: ["w"]})
        assert (model.interpolated("w") is not None) == (how == "interp")
        yield "nbody-" + how, model, {"x": xs[40]}, [("a", "x"), ("w", "x"), ("r2", "x")]


@pytest.fixture(scope="module")
def corpus():
    return list(cases())


def reduced_fd(red, out, inp, h):
    """Central differences of out's coordinates in inp's, the other inputs as set."""
    c0 = red.coords(inp).copy()
    cols = []
    for e in np.eye(len(c0)):
        red.set_coords(inp, c0 + h * e)
        red()
        plus = red.coords(out).copy()
        red.set_coords(inp, c0 - h * e)
        red()
        cols.append((plus - red.coords(out)) / (2 * h))
    red.set_coords(inp, c0)
    red()
    return np.column_stack(cols)


def test_jacobian_agrees_with_finite_differences(corpus):
    for name, model, test, pairs in corpus:
        red = model.reduced(exact_roots=True)
        red(**test)
        for out, inp in pairs:
            J = red.jacobian(out, inp, **test)
            assert J.shape == (len(red.coords(out)), len(red.coords(inp)))
            scale = max(1.0, np.abs(J).max())
            e1 = np.abs(reduced_fd(red, out, inp, 1e-3) - J).max() / scale
            e2 = np.abs(reduced_fd(red, out, inp, 1e-4) - J).max() / scale
            assert e2 < 1e-7, (name, out, inp, e1, e2)
            # truncation O(h²): 10x smaller h, about 100x smaller error, unless already at rounding
            assert e1 < 1e-11 or e2 < e1 / 30, (name, out, inp, e1, e2)


def test_forward_and_reverse_agree(corpus):
    for name, model, test, pairs in corpus:
        red = model.reduced(exact_roots=True)
        red(**test)
        for out, inp in pairs:
            J = red.jacobian(out, inp)
            mo, mi = J.shape
            by_jvp = np.column_stack([red.jvp(out, {inp: e}) for e in np.eye(mi)])
            by_vjp = np.vstack([red.vjp({out: e}, inp) for e in np.eye(mo)])
            scale = max(1.0, np.abs(J).max())
            assert np.abs(by_jvp - by_vjp).max() <= 1e-12 * scale, name
            assert np.abs(J - by_jvp).max() <= 1e-12 * scale, name
            rng = np.random.default_rng(2)
            v, w = rng.standard_normal(mi), rng.standard_normal(mo)
            assert abs(w @ red.jvp(out, {inp: v}) - red.vjp({out: w}, inp) @ v) <= 1e-12 * scale * np.abs(w).sum() * np.abs(v).sum()


def test_several_directions_sum():
    """jvp over two inputs is the sum of the two Jacobians' products; vjp of two outputs likewise."""
    rng = np.random.default_rng(5)
    F = 4
    pa = {"rho": 0.3 * rng.random(F), "a": 0.2 * rng.random((F, F))}
    _, model = trained(npg.compile(SOLVE), {"x": rng.random((20, F)), "e": rng.random((20, F))}, pa)
    red = model.reduced()
    red(x=rng.random(F), e=rng.random(F))
    mx, me, mb, mp = (len(red.coords(q)) for q in "xebp")
    dx, de = rng.standard_normal(mx), rng.standard_normal(me)
    both = red.jvp("b", {"x": dx, "e": de})
    assert np.allclose(both, red.jacobian("b", "x") @ dx + red.jacobian("b", "e") @ de, rtol=0, atol=1e-12)
    cb, cp = rng.standard_normal(mb), rng.standard_normal(mp)
    both = red.vjp({"b": cb, "p": cp}, "x")
    assert np.allclose(both, red.jacobian("b", "x").T @ cb + red.jacobian("p", "x").T @ cp, rtol=0, atol=1e-12)
    # an input's own Jacobian is the identity
    assert np.array_equal(red.jacobian("x", "x"), np.eye(mx))


def full_fd(full, out, inp, at, h=1e-3):
    """Richardson-extrapolated central differences of the full evaluator: O(h⁴)."""
    x0 = at[inp].ravel()

    def d(step):
        cols = []
        for e in np.eye(len(x0)):
            args = dict(at)
            args[inp] = (x0 + step * e).reshape(at[inp].shape)
            plus = full(**args)[out].ravel().copy()
            args[inp] = (x0 - step * e).reshape(at[inp].shape)
            cols.append((plus - full(**args)[out].ravel()) / (2 * step))
        return np.column_stack(cols)

    return (4 * d(h / 2) - d(h)) / 3


def test_identity_bases_equal_the_full_jacobian():
    """Bases holding every snapshot direction (full size): Bᵀ J B of the full evaluator's exact
    Jacobian (itself checked against its Richardson differences)."""
    rng = np.random.default_rng(6)
    F = 4
    pa = {"rho": 0.3 * rng.random(F), "a": 0.2 * rng.random((F, F))}
    for src, inputs, params, test, pairs, how in (
        (RATIONAL, {"x": 0.5 + rng.random((20, 2))}, None, {"x": np.array([0.9, 1.3])}, [("y", "x")], {}),
        (SOLVE, {"x": rng.random((30, F)), "e": rng.random((30, F))}, pa, {"x": rng.random(F), "e": rng.random(F)},
         [("b", "x"), ("b", "e")], {}),
        *((ROOT_STAGE, {"x": rng.random((20, 3)), "u": rng.random((20, 3))}, None,
           {"x": 0.2 + rng.random(3), "u": rng.random(3)}, [("y", "x"), ("y", "u")], {how: ["y"]})
          for how in ("galerkin", "interp")),
    ):
        prog = npg.compile(src)
        full, model = trained(prog, inputs, params, energy=1.0, cap=64, **how)
        red = model.reduced(exact_roots=True)
        for out, inp in pairs:
            Bo, Bi = model.basis(out), model.basis(inp)
            assert Bi.shape[0] == Bi.shape[1] and Bo.shape[0] == Bo.shape[1], (src, Bi.shape, Bo.shape)
            J = red.jacobian(out, inp, **test)
            Jfull = full.jacobian(out, inp, **test).reshape(Bo.shape[0], Bi.shape[0])  # exact (npg_full_jacobian)
            assert np.abs(full_fd(full, out, inp, test) - Jfull).max() <= 1e-9 * max(1.0, np.abs(Jfull).max())
            Jf = Bo.T @ Jfull @ Bi
            assert np.abs(J - Jf).max() <= 1e-10 * max(1.0, np.abs(Jf).max()), (src, out, inp, np.abs(J - Jf).max())


def test_bad_arguments_are_named():
    rng = np.random.default_rng(7)
    x = 0.5 + rng.random((20, 2))
    _, model = trained(npg.compile(RATIONAL), {"x": x})
    red = model.reduced()
    with pytest.raises(npg.Error, match="the program has no quantity 'nosuch'"):
        red.jacobian("nosuch", "x", x=x[0])
    with pytest.raises(npg.Error, match=r"npg_reduced_jacobian: argument 'input': 'y' is not an input"):
        red.jacobian("x", "y", x=x[0])
    with pytest.raises(npg.Error, match=r"jvp: directions\['x'\] has 3 values; 'x' has 2 reduced coordinates"):
        red.jvp("y", {"x": np.ones(3)})
    with pytest.raises(npg.Error, match=r"npg_reduced_jvp: argument 'directions\[0\]' \(of 'x'\) is not finite"):
        red.jvp("y", {"x": np.array([1.0, np.nan])}, x=x[0])
    with pytest.raises(TypeError, match="jvp: directions must be a non-empty dict"):
        red.jvp("y", {})
    assert red.jvp("y", {"x": np.ones(2)}).shape == (2,)  # usable again after each error


def test_extern_has_no_derivative_unless_given():
    prog = npg.compile(EXTERN)
    F, V, S = 4, 6, 12
    rng = np.random.default_rng(3)
    tri = rng.integers(0, V, (F, 3))
    g = rng.random((S, V, 3))
    v = np.array([np.sin(gk[tri[:, 1], 1]) + 2 for gk in g])
    _, model = trained(prog, {"g": g, "v": v}, {"tri": tri})
    red = model.reduced()
    with pytest.raises(npg.Error, match="extern 'v' depends on the differentiated input"):
        red.jacobian("d", "g", g=g[0])
    # externs given by the caller are constants: d = v ∘ g[tri[:, 0], 0] differentiates in g alone
    red.given_externs(True)
    J = red.jacobian("d", "g", g=g[0], v=v[0])
    fd = reduced_fd(red, "d", "g", 1e-4)
    assert np.abs(J).max() > 0.1 and np.abs(fd - J).max() <= 1e-8 * np.abs(J).max()


def test_npgc_eval_jacobian_equals_python(tmp_path, npgc, root):
    """npgc eval MODEL/ IN/ --jacobian OUT:IN writes the reduced Jacobian of every sample
    (samples x m_out x m_in) as red.jacobian gives it; bad specs refused by name."""
    rng = np.random.default_rng(9)
    F = 4
    for d in ("DATA", "IN"):
        (tmp_path / d).mkdir()
    np.save(tmp_path / "DATA" / "rho.npy", 0.3 * rng.random(F))
    np.save(tmp_path / "DATA" / "a.npy", 0.2 * rng.random((F, F)))
    np.save(tmp_path / "DATA" / "x.npy", rng.random((20, F)))
    np.save(tmp_path / "DATA" / "e.npy", rng.random((20, F)))
    for name in ("rho", "a"):
        np.save(tmp_path / "IN" / f"{name}.npy", np.load(tmp_path / "DATA" / f"{name}.npy"))
    xs, es = rng.random((3, F)), rng.random((3, F))
    np.save(tmp_path / "IN" / "x.npy", xs)
    np.save(tmp_path / "IN" / "e.npy", es)
    npgc("train", SOLVE, tmp_path / "DATA", "-o", tmp_path / "M", "--cap", "3")
    npgc("eval", SOLVE, tmp_path / "M", tmp_path / "IN", "-o", tmp_path / "OUT", "--jacobian", "b:x",
         "--jacobian", "p:e")
    red = npg.load(npg.compile(str(root / SOLVE)), str(tmp_path / "M")).reduced()
    got_bx = np.load(tmp_path / "OUT" / "jacobian_b_x.reduced.npy")
    got_pe = np.load(tmp_path / "OUT" / "jacobian_p_e.reduced.npy")
    red(x=xs[0], e=es[0])
    assert got_bx.shape == (3, len(red.coords("b")), len(red.coords("x")))
    for k in range(3):
        assert np.allclose(got_bx[k], red.jacobian("b", "x", x=xs[k], e=es[k]), rtol=0, atol=1e-12)
        assert np.array_equal(got_pe[k], np.zeros_like(got_pe[k]))  # p reads x only
    for spec, msg in (("b:p", "'p' is not an input of the program"), ("q:x", "'q' is not a stage or input"),
                      ("bx", "expected OUT:IN")):
        r = npgc("eval", SOLVE, tmp_path / "M", tmp_path / "IN", "-o", tmp_path / "BAD", "--jacobian", spec,
                 check=False)
        assert r.returncode == 2 and f"npgc eval: --jacobian '{spec}': " in r.stderr and msg in r.stderr, r.stderr
        assert not (tmp_path / "BAD").exists()
