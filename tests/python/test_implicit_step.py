"""Implicit steps written in the language (issue 43): `residual next u[i:N] = ...` defines u.next as
the zero of a residual, and the rollouts (full.simulate, Trainer.add_trajectory, reduced.simulate)
solve every step by Newton — npg_full_newton in the full step, npg_reduced_newton in coordinates.
Backward Euler on the stiff nonlinear heat equation of test_implicit_newton.py, at 100x the explicit
step's limit: the full rollout equals a NumPy Newton, Newton converges quadratically, the reduced
rollout is stable and near the full one, and a failing Newton names the step, iteration and
residual."""
import re

import numpy as np
import pytest

import npg
from test_implicit_newton import DT, N, bump, full_backward_step, grid

STEPS = 12


@pytest.fixture(scope="module")
def setup(root):
    nbr, _ = grid()
    prog = npg.compile(str(root / "examples/heat/heat_backward.npg"))
    full = prog.full(params={"nbr": nbr, "dt": np.array(DT)})
    return root, nbr, full


def test_full_rollout_is_backward_euler(setup, capfd):
    _, nbr, full = setup
    u0 = bump(np.random.default_rng(5))
    frames = full.simulate(STEPS, u=u0, newton_verbose=True)["u"]
    ref = u0.copy()
    for t in range(STEPS):
        ref = full_backward_step(ref, nbr, DT)
        assert np.abs(frames[t + 1] - ref).max() <= 1e-9 * np.abs(ref).max(), t
    # the verbose lines: |r| per iteration; the first step's fall quadratically once in the basin
    err = capfd.readouterr().err
    hist = [float(x) for x in re.findall(r"newton sample \d+ iteration \d+: \|u\.residual\| = (\S+)", err)]
    first = []
    for h in hist:
        if first and h > first[-1] and first[-1] < 1e-3:
            break  # the next step's iteration 0
        first.append(h)
    assert len(first) >= 3 and first[-1] <= 1e-10 * first[0], first
    quadratic = [(a, b) for a, b in zip(first, first[1:]) if a < 0.1 and b > 1e-13]
    assert quadratic and all(b <= 10 * a * a for a, b in quadratic), first


def test_explicit_euler_blows_up_at_this_step(setup):
    root, nbr, _ = setup
    explicit = npg.compile(str(root / "examples/heat/heat.npg")).full(params={"nbr": nbr, "dt": np.array(DT)})
    with pytest.raises(npg.Error, match=r"step \d+: state 'u' blew up"):
        explicit.simulate(20, u=bump(np.random.default_rng(5)))


def test_reduced_rollout_stable_and_near_the_full(setup):
    _, nbr, full = setup
    rng = np.random.default_rng(11)
    tr = npg.Trainer(full, cap=3)  # {u, u.next, u.residual}: 3 + 3 + 1 at most, for 25 cells
    for _ in range(8):
        tr.add_trajectory(6, u=bump(rng))  # the pairs (u, u.next) of the full implicit steps
    model = tr.finish()
    m = model.basis_sizes["{u,u.next,u.residual}"]
    assert m <= N // 2
    u0 = bump(np.random.default_rng(99))
    F = full.simulate(30, u=u0)["u"]
    R = model.reduced().simulate(30, u=u0)["u"]
    assert np.all(np.isfinite(R))
    dev = [np.linalg.norm(r - r.mean()) for r in R]  # diffusion: the deviation from the mean decays
    assert all(b <= a * (1 + 1e-9) + 1e-12 for a, b in zip(dev, dev[1:])), dev
    err = np.linalg.norm(R - F) / np.linalg.norm(F)
    B = model.basis("u")
    floor = np.linalg.norm(F - F @ B @ B.T) / np.linalg.norm(F)
    final = np.linalg.norm(R[-1] - F[-1]) / np.linalg.norm(F[-1])
    assert err <= 1.05 * floor and final <= 0.01, (err, floor, final)


def test_failing_newton_names_step_iteration_residual(setup):
    _, _, full = setup
    u0 = bump(np.random.default_rng(5))
    with pytest.raises(npg.Error, match=r"step 1: npg_full_newton: Newton on residual 'u.residual' for 'u.next' did "
                                        r"not converge at sample \d+: iteration 1, residual [0-9.e+-]+ \(tolerance "):
        full.simulate(3, u=u0, newton_max_iter=1)
    with pytest.raises(ValueError, match=r"newton_tol is 2 \(a relative tolerance in \(0, 1\)\)"):
        full.simulate(3, u=u0, newton_tol=2.0)
    frames = full.simulate(3, u=u0, newton_tol=1e-6)["u"]  # a looser tolerance: fewer iterations, same states
    assert np.abs(frames[-1] - full.simulate(3, u=u0)["u"][-1]).max() <= 1e-4
