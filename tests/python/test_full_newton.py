"""Implicit steps solved by Newton's method in the full model (issue 43, DESIGN §17): backward
Euler on a stiff nonlinear heat equation as a residual r(u, v) of the next state v, solved by
full.newton (npg_full_newton: the Jacobian on its sparse pattern by UMFPACK, dense ones by LAPACK).
Newton converges quadratically; the full implicit rollout equals a NumPy reference Newton; the
dense path agrees with it; failures name the sample, the iteration and the residual."""
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
"""
SIDE = 16  # 256 cells, 4.7 entries a row: 1.9% of the Jacobian's entries, solved by UMFPACK
N = SIDE * SIDE
DT = 25.0  # the explicit limit of this Laplacian with k <= 1 is 1/4: 100x it


def grid():
    nbr = -np.ones((N, 4), dtype=np.int64)
    for i in range(SIDE):
        for j in range(SIDE):
            c = i * SIDE + j
            nbr[c] = [c - SIDE if i > 0 else -1, c + SIDE if i < SIDE - 1 else -1,
                      c - 1 if j > 0 else -1, c + 1 if j < SIDE - 1 else -1]
    return nbr


def reference_step(u, nbr, dt):
    """The step by Newton with the exact Jacobian written by hand (numpy)."""
    v = u.copy()
    for _ in range(50):
        k = 1 / (1 + v ** 2)
        dk = -2 * v * k ** 2
        res, J = v - u, np.eye(N)
        for j in range(4):
            i = np.nonzero(nbr[:, j] >= 0)[0]
            n = nbr[i, j]
            kf, d = 0.5 * (k[i] + k[n]), v[n] - v[i]
            res[i] -= dt * kf * d
            J[i, n] -= dt * (kf + 0.5 * dk[n] * d)
            J[i, i] -= dt * (-kf + 0.5 * dk[i] * d)
        if np.linalg.norm(res) < 1e-12:
            return v
        v = v - np.linalg.solve(J, res)
    raise AssertionError("the reference Newton did not converge")


def bump():
    x, y = np.meshgrid(np.arange(SIDE), np.arange(SIDE), indexing="ij")
    return (3.0 * np.exp(-((x - 2.2) ** 2 + (y - 3.1) ** 2) / 1.5 ** 2)).ravel()


@pytest.fixture(scope="module")
def full():
    nbr = grid()
    prog = npg.compile(BACKWARD, name="backward.npg")
    return prog.full(params={"nbr": nbr, "dt": np.array(DT)}), nbr


def test_newton_converges_quadratically(full, capfd):
    f, nbr = full
    u0 = bump()
    v, hist = f.newton("r", "v", tol=1e-12, verbose=True, sample=3, u=u0, v=u0)
    assert hist[-1] <= 1e-12 and 3 <= len(hist) <= 12, hist
    # quadratic: once in the basin, each residual at most about the square of the one before
    for a, b in zip(hist, hist[1:]):
        if a < 0.1 and b > 1e-13:
            assert b <= 10 * a * a, hist
    assert any(a < 0.1 and 1e-13 < b for a, b in zip(hist, hist[1:])), hist  # a quadratic step seen
    err = capfd.readouterr().err.splitlines()
    assert len(err) == len(hist), err
    for i, (line, h) in enumerate(zip(err, hist)):
        assert line == "newton sample 3 iteration %d: |r| = %.3e" % (i, h), (line, h)
    print("full Newton residuals:", " ".join("%.1e" % h for h in hist))
    # the solution: the residual vanishes there, every quantity holds its value there
    assert v.shape == (N,) and np.array_equal(v, f.get("v"))
    assert np.linalg.norm(f.get("r")) <= 1e-12
    assert np.abs(v - reference_step(u0, nbr, DT)).max() <= 1e-11


def test_full_implicit_rollout_equals_numpy(full):
    f, nbr = full
    u = ref = bump()
    for step in range(12):
        u, hist = f.newton("r", "v", tol=1e-12, sample=step, u=u, v=u)
        ref = reference_step(ref, nbr, DT)
        assert len(hist) <= 12, (step, hist)
    assert np.abs(u - ref).max() <= 1e-10 * np.abs(ref).max(), np.abs(u - ref).max()
    assert abs(u.sum() - bump().sum()) <= 1e-9  # conservative fluxes: the total is kept
    assert u.max() < 0.5 * bump().max()  # and it diffused, at 100x the explicit step


def test_dense_jacobian_by_lapack():
    # every entry reads every other through the mean: the Jacobian is dense, solved by LAPACK
    prog = npg.compile("""dim N
input u : real[N]
input v : real[N]
m = sum(j = 0..N-1, v[j]) / N
output r[i:N] = v[i] + 0.5 * v[i]^3 + 2 * m * v[i] - u[i]
""", name="dense.npg")
    f = prog.full()
    rng = np.random.default_rng(5)
    u = rng.uniform(0.5, 1.5, 8)
    v, hist = f.newton("r", "v", tol=1e-13, u=u, v=np.zeros(8))
    assert hist[-1] <= 1e-13 and len(hist) <= 12, hist
    assert np.abs(v + 0.5 * v ** 3 + 2 * v.mean() * v - u).max() <= 1e-13


def test_newton_failures_are_named(full):
    f, _ = full
    u0 = bump()
    with pytest.raises(npg.Error, match=r"npg_full_newton: Newton on residual 'r' for 'v' did not converge at "
                                        r"sample 7: iteration 1, residual [0-9.e+-]+ \(tolerance 1.000e-30\)"):
        f.newton("r", "v", tol=1e-30, max_iter=1, sample=7, u=u0, v=u0)
    with pytest.raises(npg.Error, match=r"npg_full_newton: argument 'unknown': 'k' is not an input"):
        f.newton("r", "k")
    with pytest.raises(npg.Error, match=r"npg_full_newton: argument 'residual': the program has no quantity 'q'"):
        f.newton("q", "v")
    with pytest.raises(npg.Error, match=r"npg_full_newton: tolerance -1: it must be positive and finite"):
        f.newton("r", "v", tol=-1)
    with pytest.raises(npg.Error, match=r"npg_full_newton: max_iter 0: at least one iteration"):
        f.newton("r", "v", max_iter=0)
    # a residual that is not finite at the start: named, not iterated on
    big = np.full(N, 1e308)  # v - u overflows
    with pytest.raises(npg.Error, match=r"npg_full_newton: sample 2, iteration 0: residual 'r' is not finite"):
        f.newton("r", "v", sample=2, u=big, v=-big)
    # as many equations as unknowns
    prog = npg.compile("dim N\ninput v : real[N]\noutput r = sum(i = 0..N-1, v[i]^2) - 1\n", name="scalar.npg")
    with pytest.raises(npg.Error, match=r"npg_full_newton: residual 'r' has 1 entries and unknown 'v' 3: a Newton "
                                        r"step needs as many equations as unknowns"):
        prog.full().newton("r", "v", v=np.ones(3))
    # a singular Jacobian: r = v² + 1 at v = 0 (diagonal, 1% filled: UMFPACK), and dense (LAPACK)
    prog = npg.compile("dim N\ninput v : real[N]\noutput r[i:N] = v[i]^2 + 1\n", name="singular.npg")
    with pytest.raises(npg.Error, match=r"npg_full_newton: sample 4, iteration 0: the Jacobian of 'r' by 'v' is "
                                        r"singular \(UMFPACK"):
        prog.full().newton("r", "v", sample=4, v=np.zeros(100))
    with pytest.raises(npg.Error, match=r"npg_full_newton: sample 4, iteration 0: the Jacobian of 'r' by 'v' is "
                                        r"singular \(LAPACK dgesv"):
        prog.full().newton("r", "v", sample=4, v=np.zeros(1))
