"""red.estimate(name), red.estimate_info(name), red.outside(name): the online error estimate and the
trust signal through Python (issue 41, docs/estimates.md), on the thermal block of
tests/cli/thermal_block.npg, checked against numpy's own solve of the same operator."""
import numpy as np
import pytest

import npg

G = 8  # cells per side: N = 64, four blocks


def grid():
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
    return nbr, blk, np.exp(-((xs - G / 3) ** 2 + (ys - G / 4) ** 2) / G)


def solve(mu, nbr, blk, src):
    K = np.eye(len(blk))
    for i in range(len(blk)):
        for j in nbr[i][nbr[i] >= 0]:
            c = 0.5 * (mu[blk[i]] + mu[blk[j]])
            K[i, i] += c
            K[i, j] -= c
    return np.linalg.solve(K, src)


@pytest.fixture(scope="module")
def block(root):
    nbr, blk, src = grid()
    prog = npg.compile((root / "tests/cli/thermal_block.npg").read_text())
    full = prog.full(params={"nbr": nbr, "blk": blk, "src": src})
    rng = np.random.default_rng(7)
    tr = npg.Trainer(full)
    for mu in rng.uniform(0.1, 1, (16, 4)):
        tr.add(mu=mu)
    return tr.finish().reduced(), (nbr, blk, src), rng


def test_estimate_bounds_the_true_error_within_20x(block):
    red, data, rng = block
    for mu in rng.uniform(0.1, 1, (10, 4)):
        red(mu=mu)
        err = np.linalg.norm(solve(mu, *data) - red.lift("u"))
        est = red.estimate("u")
        assert err <= est <= 20 * err, (mu, est, err)
        info = red.estimate_info("u")
        assert info["estimate"] == est and info["bound"] and info["why"] == ""
    assert red.estimate("mu") == 0 and red.estimate_info("mu")["bound"]


def test_outside_the_training_range_is_flagged(block):
    red, _, _ = block
    red(mu=np.full(4, 0.5))
    assert red.outside("mu") is None and not red.estimate_info("u")["outside"]
    red(mu=np.full(4, 5.0))
    assert red.outside("mu") is not None and red.estimate_info("u")["outside"]
    with pytest.raises(npg.Error, match="'u' is not an input of the program"):
        red.outside("u")
    with pytest.raises(npg.Error, match="the program has no quantity 'nope'"):
        red.estimate("nope")


def test_greedy_reaches_the_tolerance_on_its_pool(root):
    """Trainer.greedy from one sample: every candidate's true relative error ends below tol (the
    estimate bounds it), with fewer full evaluations than the pool holds, one per training sample."""
    nbr, blk, src = grid()
    prog = npg.compile((root / "tests/cli/thermal_block.npg").read_text())
    full = prog.full(params={"nbr": nbr, "blk": blk, "src": src})
    rng = np.random.default_rng(11)
    pool = rng.uniform(0.1, 1, (30, 4))
    tr = npg.Trainer(full, basis=["u:cap=60,energy=1"])
    model, info = tr.greedy({"mu": rng.uniform(0.1, 1, (1, 4))}, {"mu": pool}, 1e-3)
    assert info["converged"] and info["worst"] < 1e-3
    assert 0 < len(info["chosen"]) < 30 and len(set(info["chosen"])) == len(info["chosen"])
    assert info["evaluations"] == 1 + len(info["chosen"])  # each training sample evaluated in full once
    red = model.reduced()
    for mu in pool:
        red(mu=mu)
        u = solve(mu, nbr, blk, src)
        assert np.linalg.norm(u - red.lift("u")) <= 1e-3 * np.linalg.norm(u)
    _, budget = tr.greedy({"mu": pool[:1]}, {"mu": pool}, 1e-12, budget=3)
    assert not budget["converged"] and len(budget["chosen"]) == 2
    with pytest.raises(npg.Error, match="tolerance -1"):
        tr.greedy({"mu": pool[:1]}, {"mu": pool}, -1)


@pytest.fixture(scope="module")
def product_block(root):
    """examples/thermalblock (u's basis orthonormal in the H¹₀ product H) on a 6 x 6 grid."""
    import sys
    sys.path.insert(0, str(root / "examples/thermalblock"))
    import thermalblock_data
    kb, kq, hm, f = thermalblock_data.assemble(2, 2, 6)
    cols, (a0, *a, h) = thermalblock_data.padded([kb, *kq, hm], f.shape[0])
    prog = npg.compile((root / "examples/thermalblock/thermalblock.npg").read_text())
    full = prog.full(params={"cols": cols, "a0": a0, "a": np.stack(a), "h": h, "f": f})
    return full, (kb, kq, hm, f)


def h_error(mu, red, mats):
    kb, kq, hm, f = mats
    e = np.linalg.solve(kb + sum(m * k for m, k in zip(mu, kq)), f) - red.lift("u")
    return np.sqrt(e @ hm @ e)


def test_estimate_in_a_product_bounds_the_error_in_its_norm(product_block):
    """With `basis u: product H` the estimate is ‖r‖_{H⁻¹} / min(1, min μ): a bound of the true
    error in H's norm (pyMOR's coercive estimator), within 10× of it, also outside the range."""
    full, mats = product_block
    rng = np.random.default_rng(5)
    tr = npg.Trainer(full, basis=["u:cap=5"])
    for mu in rng.uniform(0.1, 1, (12, 4)):
        tr.add(mu=mu)
    red = tr.finish().reduced()
    for mu in [*rng.uniform(0.1, 1, (8, 4)), np.array([0.05, 0.3, 2.0, 0.5])]:
        red(mu=mu)
        err, est = h_error(mu, red, mats), red.estimate("u")
        assert err <= est <= 10 * err, (mu, est, err)
        assert red.estimate_info("u")["bound"]


def test_greedy_absolute_in_a_product(product_block):
    """Trainer.greedy(absolute=True): every candidate's true error in H's norm ends below tol."""
    full, mats = product_block
    rng = np.random.default_rng(9)
    pool = rng.uniform(0.1, 1, (25, 4))
    tr = npg.Trainer(full, basis=["u:cap=40,energy=1"], center=False)
    model, info = tr.greedy({"mu": pool[:1]}, {"mu": pool}, 1e-4, absolute=True)
    assert info["converged"] and info["worst"] < 1e-4 and 0 < len(info["chosen"]) < 24
    red = model.reduced()
    for mu in pool:
        red(mu=mu)
        assert h_error(mu, red, mats) <= 1e-4


def test_greedy_keeps_every_direction_of_the_inputs(root):
    """Under greedy training μ's basis keeps every direction its samples span: conductivities
    varying by ±1 % about 0.5 on 3 x 3 blocks (the uncentered default energy 0.999 kept one of
    them, every candidate stayed outside it and greedy took the pool in order) converge with
    fewer full solves than the pool, μ's class holding all nine, every candidate below tol."""
    import sys
    sys.path.insert(0, str(root / "examples/thermalblock"))
    import thermalblock_data
    kb, kq, hm, f = thermalblock_data.assemble(3, 3, 6)
    cols, (a0, *a, h) = thermalblock_data.padded([kb, *kq, hm], f.shape[0])
    prog = npg.compile((root / "examples/thermalblock/thermalblock.npg").read_text())
    full = prog.full(params={"cols": cols, "a0": a0, "a": np.stack(a), "h": h, "f": f})
    pool = 0.5 * (1 + 0.02 * (np.random.default_rng(4).uniform(size=(30, 9)) - 0.5))
    tr = npg.Trainer(full, basis=["u:cap=40,energy=1"], center=False)
    model, info = tr.greedy({"mu": pool[:1]}, {"mu": pool}, 1e-6, absolute=True)
    assert info["converged"] and len(info["chosen"]) < 25
    assert model.basis_sizes["{mu}"] == 9
    red = model.reduced()
    for mu in pool:
        red(mu=mu)
        assert h_error(mu, red, (kb, kq, hm, f)) <= 1e-6
