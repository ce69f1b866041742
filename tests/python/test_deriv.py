"""Derivatives of the full evaluator from Python (DESIGN §17): Full.jacobian, Full.jvp and
Full.vjp with the shapes of their quantities, against central differences and each other,
and their refusals named."""
import numpy as np
import pytest

import npg

# A stage with two dim axes, an input with a static axis, an inverse whose operator reads an input.
PROGRAM = """
dim N
param a : real[N, N]
input x : real[N]
input g : real[N, 2]
op K[i:N, j:N] = delta(i, j) * (3 + x[i] * g[i, 1]) + a[i, j] * x[j]
s[i:N] = g[i, 0] * x[i]
output b = solve(K, s)
output p[i:N, j:N] = x[i] * g[j, 0] * g[j, 1] * g[j, 1]
"""

EXTERN = "dim V\ninput g : real[V]\nextern v[i:V] of g\noutput y[i:V] = v[i] * g[i]\n"


@pytest.fixture()
def full():
    rng = np.random.default_rng(5)
    return npg.compile(PROGRAM, name="deriv.npg").full(params={"a": 0.2 * rng.random((4, 4))}), rng


def point(rng):
    return {"x": 0.5 + rng.random(4), "g": 0.5 + rng.random((4, 2))}


def central(full, out, name, w, at, h):
    plus = dict(at, **{name: at[name] + h * w})
    minus = dict(at, **{name: at[name] - h * w})
    return (full(**plus)[out] - full(**minus)[out]) / (2 * h)


def test_jacobian_shapes_and_finite_differences(full):
    full, rng = full
    at = point(rng)
    J = full.jacobian("p", "g", **at)
    assert J.shape == (4, 4, 4, 2)
    Jb = full.jacobian("b", "x", **at)
    assert Jb.shape == (4, 4)
    w = rng.uniform(-1, 1, 4)
    e1 = np.abs(central(full, "b", "x", w, at, 1e-2) - Jb @ w).max()
    e2 = np.abs(central(full, "b", "x", w, at, 5e-3) - Jb @ w).max()
    assert 3 < e1 / e2 < 5.3  # second order: the h^2 term


def test_products_agree_with_the_jacobian(full):
    full, rng = full
    at = point(rng)
    wx, wg = rng.uniform(-1, 1, 4), rng.uniform(-1, 1, (4, 2))
    Jx, Jg = full.jacobian("b", "x", **at), full.jacobian("b", "g", **at)
    jv = full.jvp("b", {"x": wx, "g": wg}, **at)
    assert jv.shape == (4,)
    assert np.allclose(jv, Jx @ wx + np.tensordot(Jg, wg, 2), rtol=1e-12, atol=1e-14)
    v, vp = rng.uniform(-1, 1, 4), rng.uniform(-1, 1, (4, 4))
    vj = full.vjp({"b": v, "p": vp}, "g", **at)
    assert vj.shape == (4, 2)
    Jp = full.jacobian("p", "g", **at)
    assert np.allclose(vj, np.tensordot(v, Jg, 1) + np.tensordot(vp, Jp, 2), rtol=1e-12, atol=1e-14)
    # <v, J w> both ways
    assert np.isclose(v @ full.jvp("b", {"g": wg}, **at), np.sum(full.vjp({"b": v}, "g", **at) * wg), rtol=1e-12)


def test_refusals_name_the_argument(full):
    full, rng = full
    at = point(rng)
    with pytest.raises(npg.Error, match="'q'"):
        full.jacobian("q", "x", **at)
    with pytest.raises(npg.Error, match="'b' is not an input"):
        full.jacobian("p", "b", **at)
    with pytest.raises(ValueError, match=r"directions\['x'\]: 3 values, but 'x' has 4"):
        full.jvp("b", {"x": np.ones(3)}, **at)
    with pytest.raises(TypeError, match="cotangents: a dict"):
        full.vjp(np.ones(4), "x", **at)
    ext = npg.compile(EXTERN, name="ext.npg").full()
    with pytest.raises(npg.Error, match="extern 'v' is a black box"):
        ext.jacobian("y", "g", g=np.ones(3), v=np.ones(3))


def test_jacobian_csr_equals_the_dense_one(full):
    full, rng = full
    at = point(rng)
    for out, inp, shape in (("p", "g", (16, 8)), ("b", "x", (4, 4))):
        c = full.jacobian_csr(out, inp, **at)
        J = full.jacobian(out, inp, **at)
        rows, cols = c["shape"]
        assert (rows, cols) == shape
        dense = np.zeros((rows, cols))
        for r in range(rows):
            for k in range(c["indptr"][r], c["indptr"][r + 1]):
                dense[r, c["indices"][k]] = c["data"][k]
        assert np.allclose(dense, J.reshape(rows, cols), rtol=1e-12, atol=1e-14)
    # p[i, j] reads x[i] and g[j]: 4 x 8 by g, 2 entries a row
    assert full.jacobian_csr("p", "g", **at)["indptr"][-1] == 16 * 2
