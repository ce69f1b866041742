"""Implicit steps solved by Newton's method in the reduced model (issue 43, DESIGN §17):
backward Euler on a stiff nonlinear heat equation written as a residual r(u, v) whose unknown v
(the next state) shares the state's basis, solved by red.newton (npg_reduced_newton: the reduced
Jacobian, m x m, LAPACK dgesv). Newton converges quadratically; the reduced implicit step stays
stable at 100x the explicit step's limit, where explicit Euler blows up; a failure names the
sample, the iteration and the residual."""
import numpy as np
import pytest

import npg

# backward Euler, k(v) = 1/(1 + v²), fluxes through the faces of a grid of cells (conservative):
#   v_i − u_i − dt Σ_j ½ (k(v_i) + k(v_j)) (v_j − v_i) = 0
BACKWARD = """dim N
param nbr : int[N, 4]
param dt : real
input u : real[N]
input v : real[N]
k[i:N] = 1 / (1 + v[i]^2)
output r[i:N] = v[i] - u[i] - dt * sum(j = 0..3, if(nbr[i, j] >= 0, 0.5 * (k[i] + k[nbr[i, j]]) * (v[nbr[i, j]] - v[i]), 0))
share u, v, r
"""
SIDE = 5
N = SIDE * SIDE
DT = 25.0  # the explicit limit of this Laplacian with k <= 1 is 1/4: 100x it


def grid():
    nbr = -np.ones((N, 4), dtype=np.int64)
    for i in range(SIDE):
        for j in range(SIDE):
            c = i * SIDE + j
            nbr[c] = [c - SIDE if i > 0 else -1, c + SIDE if i < SIDE - 1 else -1,
                      c - 1 if j > 0 else -1, c + 1 if j < SIDE - 1 else -1]
    L = np.zeros((N, N))
    for c in range(N):
        for n in nbr[c]:
            if n >= 0:
                L[c, n] += 1
                L[c, c] -= 1
    return nbr, L


def full_backward_step(u, nbr, dt):
    """The full step by Newton with the exact Jacobian (the reference, numpy)."""
    v = u.copy()
    for _ in range(50):
        k = 1 / (1 + v ** 2)
        dk = -2 * v * k ** 2
        res, J = v - u, np.eye(N)
        for j in range(4):  # the faces of each cell toward its j-th neighbour
            i = np.nonzero(nbr[:, j] >= 0)[0]
            n = nbr[i, j]
            kf, d = 0.5 * (k[i] + k[n]), v[n] - v[i]
            res[i] -= dt * kf * d
            J[i, n] -= dt * (kf + 0.5 * dk[n] * d)
            J[i, i] -= dt * (-kf + 0.5 * dk[i] * d)
        if np.linalg.norm(res) < 1e-11:
            return v
        v = v - np.linalg.solve(J, res)
    raise AssertionError("the reference Newton did not converge")


def bump(rng):
    x, y = np.meshgrid(np.arange(SIDE), np.arange(SIDE), indexing="ij")
    cx, cy, w, h = rng.uniform(1, SIDE - 2), rng.uniform(1, SIDE - 2), rng.uniform(0.8, 2), rng.uniform(0.5, 2)
    return (h * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / w ** 2)).ravel()


@pytest.fixture(scope="module")
def setup():
    nbr, L = grid()
    rng = np.random.default_rng(11)
    prog = npg.compile(BACKWARD, name="backward.npg")
    full = prog.full(params={"nbr": nbr, "dt": np.array(DT)})
    tr = npg.Trainer(full, cap=3)  # {u, v, r}: 9 coordinates for 25 cells
    for _ in range(8):  # trajectories of the full implicit step
        u = bump(rng)
        for _ in range(6):
            v = full_backward_step(u, nbr, DT)
            tr.add(u=u, v=v)
            u = v
    model = tr.finish()
    assert model.basis_sizes["{u,v,r}"] <= N // 2
    return model, L, nbr, rng


def test_newton_converges_quadratically(setup, capfd):
    model, L, nbr, rng = setup
    red = model.reduced()
    u0 = bump(rng)
    red.set_coords("u", model.basis("u").T @ u0)
    red.set_coords("v", model.basis("v").T @ u0)  # the previous state as the first guess
    coords, hist = red.newton("r", "v", tol=1e-12, verbose=True, sample=3)
    assert hist[-1] <= 1e-12 and 2 <= len(hist) <= 10, hist
    # quadratic: once in the basin, each residual about the square of the one before
    for a, b in zip(hist, hist[1:]):
        if a < 0.1 and b > 1e-13:
            assert b <= 10 * a * a, hist
    assert any(a < 0.1 and 1e-13 < b for a, b in zip(hist, hist[1:])), hist  # a quadratic step seen
    err = capfd.readouterr().err.splitlines()
    assert err[0].startswith("newton sample 3 iteration 0: |r| = ") and len(err) == len(hist)
    # the solution: the residual's coordinates vanish there, the Jacobian is that of the step
    assert np.abs(red.coords("r")).max() <= 1e-12
    assert np.array_equal(coords, red.coords("v"))


def test_reduced_implicit_step_stable_at_100x_explicit_limit(setup):
    model, L, nbr, rng = setup
    red = model.reduced()
    B = model.basis("u")
    u = bump(np.random.default_rng(99))
    # explicit Euler at this step blows up (the full step, numpy): diffusion never raises the
    # largest value, this does tenfold
    e = u.copy()
    with np.errstate(all="ignore"):
        for _ in range(20):
            k = 1 / (1 + e ** 2)
            e = e + DT * np.array([sum(0.5 * (k[i] + k[n]) * (e[n] - e[i]) for n in nbr[i] if n >= 0)
                                   for i in range(N)])
    assert not np.all(np.isfinite(e)) or np.abs(e).max() > 10 * np.abs(u).max()
    # the reduced implicit rollout: coordinates to coordinates, Newton at every step
    c = B.T @ u
    full = u.copy()
    energies = []
    for step in range(30):
        red.set_coords("u", c)
        red.set_coords("v", c)
        c, hist = red.newton("r", "v", tol=1e-11, sample=step)
        assert np.all(np.isfinite(c)) and len(hist) <= 12
        full = full_backward_step(full, nbr, DT)
        energies.append(np.linalg.norm(B @ c - (B @ c).mean()))
    # diffusion: the deviation from the mean decays, and the rollout stays near the full one
    assert all(b <= a * (1 + 1e-9) + 1e-12 for a, b in zip(energies, energies[1:])), energies
    assert np.linalg.norm(B @ c - full) <= 0.02 * np.linalg.norm(full)  # measured 7.5e-4


def test_newton_failures_are_named(setup):
    model, _, _, rng = setup
    red = model.reduced()
    u0 = bump(rng)
    red.set_coords("u", model.basis("u").T @ u0)
    red.set_coords("v", model.basis("v").T @ u0)
    with pytest.raises(npg.Error, match=r"npg_reduced_newton: Newton on residual 'r' for 'v' did not converge at "
                                        r"sample 7: iteration 1, residual [0-9.e+-]+ \(tolerance 1.000e-30\)"):
        red.newton("r", "v", tol=1e-30, max_iter=1, sample=7)
    with pytest.raises(npg.Error, match=r"npg_reduced_newton: argument 'unknown': 'k' is not an input"):
        red.newton("r", "k")
    with pytest.raises(npg.Error, match=r"npg_reduced_newton: residual 'k' has \d+ reduced coordinates and unknown "
                                        r"'v' \d+: a Newton step needs them in one basis \(share k, v\)"):
        red.newton("k", "v")
    with pytest.raises(npg.Error, match=r"npg_reduced_newton: tolerance -1: it must be positive and finite"):
        red.newton("r", "v", tol=-1)
