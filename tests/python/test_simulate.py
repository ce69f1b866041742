"""Simulations from Python (DESIGN §15) on examples/heat: Full.simulate against NumPy with a
source given per step, Trainer.add_trajectory giving the model `npgc train --steps` gives (byte for
byte), Reduced.simulate equal to `npgc simulate --model`, blow-ups and bad arguments refused."""
import subprocess

import numpy as np
import pytest

import npg

from test_npg import same_model


def heat_data(root, tmp, name, *args):
    subprocess.run(["/usr/bin/python3", str(root / "examples/heat/heat_data.py"), str(tmp / name), *args], check=True)
    return {f: np.load(tmp / name / f"{f}.npy") for f in ("u", "nbr", "dt")}, tmp / name


def params(d):
    return {"nbr": d["nbr"], "dt": d["dt"]}


def test_full_simulate_equals_numpy(root, tmp_path):
    d, _ = heat_data(root, tmp_path, "h", "--n", "6", "--trajectories", "1", "--seed", "3")
    full = npg.compile(str(root / "examples/heat/heat_linear.npg")).full(params=params(d))
    u0 = d["u"][0]
    f = np.random.default_rng(0).uniform(-0.05, 0.05, (40, u0.size))
    out = full.simulate(40, every=4, u=u0, f=f)
    assert list(out) == ["u"] and out["u"].shape == (11, u0.size)
    nbr, x = d["nbr"], u0.copy()
    for t in range(41):
        if t % 4 == 0:
            assert np.abs(out["u"][t // 4] - x).max() <= 1e-12
        if t < 40:
            x = x + d["dt"] * (np.where(nbr >= 0, x[np.maximum(nbr, 0)] - x[:, None], 0).sum(1) + f[t])
    # held source, keywords for steps and every
    held = full.simulate(steps=5, u=u0, f=f[0])
    assert held["u"].shape == (6, u0.size)


@pytest.mark.parametrize("program", ["heat", "heat_implicit"])
def test_trajectory_training_equals_npgc(root, tmp_path, npgc, program):
    """Explicit (an inverse stage) and semi-implicit (a solve with a state-dependent operator)."""
    d, folder = heat_data(root, tmp_path, "train", "--n", "8", "--trajectories", "4", "--seed", "1")
    prog = npg.compile(str(root / f"examples/heat/{program}.npg"))
    full = prog.full(params=params(d))
    tr = npg.Trainer(full)
    for u0 in d["u"]:
        tr.add_trajectory(60, every=3, u=u0)
    assert tr.samples == 4 * 21
    model = tr.finish(str(tmp_path / "PY"))
    npgc("train", f"examples/heat/{program}.npg", folder, "--steps", 60, "--every", 3, "-o", tmp_path / "CLI")
    same_model(tmp_path / "CLI", tmp_path / "PY")
    # the reduced rollout in coordinates equals npgc simulate --model's
    t, tfolder = heat_data(root, tmp_path, "test", "--n", "8", "--trajectories", "1", "--seed", "2")
    red = model.reduced().simulate(60, every=20, u=t["u"][0])["u"]
    npgc("simulate", f"examples/heat/{program}.npg", tfolder, "--steps", 60, "--every", 20, "--model", tmp_path / "CLI",
         "-o", tmp_path / "OUT")
    assert np.array_equal(red, np.load(tmp_path / "OUT" / "u.npy")[0])
    ref = full.simulate(60, every=20, u=t["u"][0])["u"]
    assert 0 < np.linalg.norm(red - ref) / np.linalg.norm(ref) < 0.05
    # verify over the trajectory: the figures npgc verify --steps prints
    rep = model.verify({"u": t["u"]}, steps=60, every=20, tol=0.05)["u"]
    assert rep["ok"] and rep["floor"] <= rep["trajectory"] and rep["error_per_save"].shape == (4,)
    out = npgc("verify", f"examples/heat/{program}.npg", tmp_path / "CLI", tfolder, "--steps", 60, "--every", 20,
               "--tol", 0.05).stdout
    row = [line.split() for line in out.splitlines() if line.startswith("u ")][0]
    assert np.allclose([rep["trajectory"], rep["floor"], rep["final"], rep["max"]], [float(x) for x in row[1:5]],
                       rtol=1e-3)
    with pytest.raises(TypeError, match="give steps too"):
        model.verify({"u": t["u"]}, every=3)
    with pytest.raises(ValueError, match="has 3 axes"):
        model.verify({"u": t["u"][:, None, :]}, steps=3)


def test_blowup_and_bad_arguments(root, tmp_path):
    d, _ = heat_data(root, tmp_path, "h", "--n", "6", "--trajectories", "1", "--dt", "1.5")
    full = npg.compile(str(root / "examples/heat/heat_linear.npg")).full(params=params(d))
    u0 = np.where(np.arange(36) % 2, 1.0, -1.0)
    with pytest.raises(npg.Error, match=r"step \d+: state 'u' blew up"):
        full.simulate(500, u=u0, f=np.zeros(36))
    # blowup=F: this call's factor (npgc simulate --blowup); 0 checks finiteness only
    with pytest.raises(npg.Error, match=r"step \d+: state 'u' blew up"):
        full.simulate(12, u=u0, f=np.zeros(36))
    grown = full.simulate(12, u=u0, f=np.zeros(36), blowup=0)["u"]
    assert np.all(np.isfinite(grown)) and np.linalg.norm(grown[-1]) > 10 * np.linalg.norm(u0)
    with pytest.raises(npg.Error, match="blew up"):  # the factor does not outlive its call
        full.simulate(12, u=u0, f=np.zeros(36))
    with pytest.raises(ValueError, match="blowup is 0.5"):
        full.simulate(3, u=u0, f=np.zeros(36), blowup=0.5)
    with pytest.raises(TypeError, match="'blowup' must be a number"):
        full.simulate(3, u=u0, f=np.zeros(36), blowup="10")
    with pytest.raises(TypeError, match="state 'u' has no initial value"):
        full.simulate(3, f=np.zeros(36))
    with pytest.raises(ValueError, match="fewer than the 5 to run"):
        full.simulate(5, u=u0, f=np.zeros((3, 36)))
    with pytest.raises(ValueError, match="every is 0"):
        full.simulate(5, every=0, u=u0, f=np.zeros(36))
    with pytest.raises(TypeError, match="'nbr' is a param"):
        full.simulate(5, u=u0, f=np.zeros(36), nbr=d["nbr"])
    with pytest.raises(TypeError, match="give steps"):
        full.simulate(u=u0, f=np.zeros(36))
    with pytest.raises(TypeError, match="'steps' must be an int"):
        full.simulate("3", u=u0, f=np.zeros(36))
    plain = npg.compile(str(root / "tests/programs/heat_neighbours.npg")).full()
    with pytest.raises(npg.Error, match="has no state"):
        plain.simulate(3)
