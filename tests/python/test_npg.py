"""The npg module against npgc (issue 27): the same diagnostics, the same
full evaluation, byte-identical models from the same samples, the same
reduced outputs; bad arrays raise; any order of freeing is safe."""
import gc
import json
import pathlib
import threading

import numpy as np
import pytest

import npg

RATIONAL = "examples/rational/rational.npg"
SPRINGS = "tests/programs/deforming_springs.npg"
EXTERN = "tests/programs/extern_stage.npg"


def rational_samples(S, seed):
    return 0.5 + np.random.default_rng(seed).random((S, 2))


def springs_data(S, seed, n=4):
    """An n x n grid of springs, deformed by random smooth displacements."""
    V = n * n
    edge = [(r * n + q, r * n + q + 1) for r in range(n) for q in range(n - 1)]
    edge += [(r * n + q, (r + 1) * n + q) for r in range(n - 1) for q in range(n)]
    edge = np.array(edge, dtype=np.int64)
    rest = np.array([(q, r, 0.0) for r in range(n) for q in range(n)]) / (n - 1)
    L0 = np.linalg.norm(rest[edge[:, 1]] - rest[edge[:, 0]], axis=1)
    rng = np.random.default_rng(seed)
    modes = rng.standard_normal((3, V, 3)) * 0.05
    x = np.array([rest + np.tensordot(rng.standard_normal(3), modes, 1) for _ in range(S)])
    assert x.shape == (S, V, 3)
    return edge, L0, x


def same_model(a, b):
    """Every .npy of MODEL a is byte-identical in b, and both hold the same files."""
    fa = sorted(p.name for p in pathlib.Path(a).glob("*.npy"))
    fb = sorted(p.name for p in pathlib.Path(b).glob("*.npy"))
    assert fa == fb and len(fa) >= 2
    for name in fa:
        assert (pathlib.Path(a) / name).read_bytes() == (pathlib.Path(b) / name).read_bytes(), name


@pytest.fixture(scope="module")
def eq3(tmp_path_factory, npgc, root):
    """Eq. 3: 60 training samples, a CLI model, 12 held-out samples."""
    d = tmp_path_factory.mktemp("eq3")
    x = rational_samples(60, 7)
    (d / "DATA").mkdir()
    np.save(d / "DATA" / "x.npy", x)
    npgc("train", RATIONAL, d / "DATA", "-o", d / "CLI")
    xt = rational_samples(12, 8)
    (d / "TEST").mkdir()
    np.save(d / "TEST" / "x.npy", xt)
    return {"dir": d, "x": x, "xt": xt, "prog": npg.compile(str(root / RATIONAL))}


# ---------------------------------------------------------------- compile

def test_compile_error_has_the_caret(root):
    with pytest.raises(npg.CompileError) as e:
        npg.compile("input x : real[2]\noutput y = exp(x[0])\n", name="eq.npg")
    lines = str(e.value).splitlines()
    assert lines[0].startswith("eq.npg:2:12: error: 'exp' is not an elementary algebraic operation")
    assert lines[1] == "output y = exp(x[0])"
    assert lines[2] == " " * 11 + "^"
    assert isinstance(e.value, npg.Error)


def test_compile_error_equals_npgc(npgc):
    bad = "tests/bad/abs_of_input.npg"
    r = npgc("check", bad, check=False)
    assert r.returncode != 0
    with pytest.raises(npg.CompileError) as e:
        npg.compile(bad)
    assert str(e.value) == r.stderr.rstrip("\n")
    assert "^" in str(e.value)


def test_compile_missing_file():
    with pytest.raises(npg.CompileError, match="cannot read 'no/such.npg'"):
        npg.compile("no/such.npg")
    assert npg.compile(pathlib.Path(RATIONAL)).path == RATIONAL


def test_report_is_npgc_check_json(npgc):
    prog = npg.compile(SPRINGS)
    want = json.loads(npgc("check", "--json", SPRINGS).stdout)
    assert prog.report == want
    assert [s["name"] for s in prog.stages] == [s["name"] for s in want["stages"]] == ["d", "l2", "f"]
    assert prog.classes == want["classes"]
    assert {s["name"]: s["kind"] for s in prog.symbols}["edge"] == "param"
    assert "stage" in prog.check()


# ---------------------------------------------------------------- full evaluation

@pytest.mark.parametrize("backend", ["tcc", "cc"])
def test_full_equals_npgc_eval_full(tmp_path, npgc, backend):
    edge, L0, x = springs_data(5, 1)
    data = tmp_path / "DATA"
    data.mkdir()
    np.save(data / "edge.npy", edge)
    np.save(data / "L0.npy", L0)
    np.save(data / "x.npy", x)
    npgc("eval", SPRINGS, "--full", data, data, "-o", tmp_path / "OUT")
    want = np.load(tmp_path / "OUT" / "f.npy")
    full = npg.compile(SPRINGS).full(params={"edge": edge, "L0": L0}, backend=backend)
    for k in range(len(x)):
        out = full(x=x[k])
        assert set(out) == {"f"}
        assert out["f"].shape == want[k].shape
        assert np.max(np.abs(out["f"] - want[k])) <= 1e-15 * max(1.0, np.max(np.abs(want[k])))
    # params from the folder: the same values
    by_dir = npg.compile(SPRINGS).full(params=str(data))
    assert np.array_equal(by_dir(x=x[0])["f"], full(x=x[0])["f"])
    assert full.dim("E") == len(edge) and full.get("l2").shape == (len(edge),)
    assert full.jit["backend"] == backend


def test_backends_tcc_cc_auto_identical(tmp_path, monkeypatch):
    """issue 42: backend='tcc', 'cc' and the default 'auto' give the same values, bit for bit (the
    generated C is compiled with -ffp-contract=off, so no fused multiply-add differs), and 'auto' is
    NPG_JIT's choice, else cc"""
    monkeypatch.setenv("NPG_CACHE_DIR", str(tmp_path / "cache"))
    edge, L0, x = springs_data(6, 3)
    prog = npg.compile(SPRINGS)
    params = {"edge": edge, "L0": L0}
    monkeypatch.delenv("NPG_JIT", raising=False)
    fulls = {b: prog.full(params=params, backend=b) for b in ("tcc", "cc", "auto")}
    assert fulls["tcc"].jit["backend"] == "tcc" and fulls["tcc"].jit["cache"] == "none"
    assert fulls["cc"].jit["backend"] == "cc" and fulls["cc"].jit["cache"] in ("miss", "hit")
    assert fulls["auto"].jit == dict(fulls["auto"].jit, backend="cc", cache="hit")  # cc installed: auto is cc, cached
    for k in range(len(x)):
        outs = {b: f(x=x[k])["f"] for b, f in fulls.items()}
        assert np.array_equal(outs["tcc"], outs["cc"]) and np.array_equal(outs["cc"], outs["auto"])
    monkeypatch.setenv("NPG_JIT", "tcc")
    assert prog.full(params=params).jit["backend"] == "tcc"
    monkeypatch.setenv("NPG_JIT", "gcc")
    with pytest.raises(Exception, match="NPG_JIT='gcc' is not a backend"):
        prog.full(params=params)


def test_full_outputs_are_fresh_arrays(eq3):
    full = eq3["prog"].full()
    a = full(x=eq3["x"][0])["y"]
    b = full(x=eq3["x"][1])["y"]
    assert not np.shares_memory(a, b) and not np.array_equal(a, b)



def test_dim_disagreement_names_the_calls():
    """A dim bound by one call's argument and given another size by the next: the message names both calls
    (issue 38: it said "dim B is 9 in argument 'mu' but 8 in argument 'mu'")."""
    full = npg.compile("dim B\ninput mu : real[B]\noutput y[i:B] = mu[i]^2\n").full()
    full(mu=np.ones(9))
    with pytest.raises(npg.Error) as e:
        full(mu=np.ones(8))
    assert str(e.value) == "dim B is 9 in argument 'mu' (sample 0) but 8 in argument 'mu' (sample 1)"
    full = npg.compile("dim B\nparam w : real[B]\ninput mu : real[B]\noutput y[i:B] = w[i] * mu[i]\n").full(
        params={"w": np.ones(9)})
    with pytest.raises(npg.Error) as e:
        full(mu=np.ones(8))
    assert str(e.value) == "dim B is 9 in param 'w' but 8 in argument 'mu' (sample 0)"

# ---------------------------------------------------------------- training

def test_trained_model_equals_npgc_train(eq3, tmp_path):
    full = eq3["prog"].full()
    tr = npg.Trainer(full)
    for xk in eq3["x"]:
        tr.add(x=xk)
    assert tr.samples == 60
    model = tr.finish(str(tmp_path / "PY"))
    same_model(eq3["dir"] / "CLI", tmp_path / "PY")
    assert model.samples == 60
    assert set(model.basis_sizes) == {"{x}", "{y}"}
    assert "{y}" in model.report()
    # streamed from evaluations (add_full): the same model again
    tr2 = npg.Trainer(full)
    for xk in eq3["x"]:
        full(x=xk)
        tr2.add_full()
    tr2.finish(str(tmp_path / "PY2"))
    same_model(eq3["dir"] / "CLI", tmp_path / "PY2")


def test_weight_counts_a_sample_that_many_times(eq3):
    full = eq3["prog"].full()
    weighted, twice, flat = (npg.Trainer(full, cap=1) for _ in range(3))  # cap 1: the mean alone
    for k, xk in enumerate(eq3["x"]):
        w = 2 if k % 4 == 0 else 1
        weighted.weight(w) if w != 1 else None
        weighted.add(x=xk)
        flat.add(x=xk)
        for _ in range(w):
            twice.add(x=xk)
    ys = []
    for tr in (weighted, twice, flat):
        red = tr.finish().reduced()
        ys.append(np.array([(red(x=xk), red.lift("y").copy())[1] for xk in eq3["x"][:8]]))
    assert np.allclose(ys[0], ys[1], rtol=0, atol=1e-10 * np.abs(ys[1]).max())
    assert not np.allclose(ys[0], ys[2], rtol=0, atol=1e-8 * np.abs(ys[2]).max())
    tr = npg.Trainer(full)
    with pytest.raises(npg.Error, match="weight of training sample 0 is -1: weights must be positive"):
        tr.weight(-1)


def test_trained_springs_equal_npgc_train(tmp_path, npgc):
    edge, L0, x = springs_data(40, 2)
    data = tmp_path / "DATA"
    data.mkdir()
    np.save(data / "edge.npy", edge)
    np.save(data / "L0.npy", L0)
    np.save(data / "x.npy", x)
    npgc("train", SPRINGS, data, "-o", tmp_path / "CLI", "--energy", "0.9999", "--cap", "8")
    full = npg.compile(SPRINGS).full(params={"edge": edge, "L0": L0})
    tr = npg.Trainer(full, energy=0.9999, cap=8, mem=1 << 20)
    for xk in x:
        tr.add(x=xk)
    tr.finish(tmp_path / "PY")
    same_model(tmp_path / "CLI", tmp_path / "PY")
    # per-name options, as npgc train --basis
    npgc("train", SPRINGS, data, "-o", tmp_path / "CLI2", "--basis", "l2:cap=3,center=off", "--basis", "f:energy=0.99")
    tr = npg.Trainer(full, basis=["l2:cap=3,center=off", "f:energy=0.99"])
    for xk in x:
        tr.add(x=xk)
    model = tr.finish(tmp_path / "PY2")
    same_model(tmp_path / "CLI2", tmp_path / "PY2")
    assert model.basis_sizes["{l2}"] == 3
    # npg_parse_basis_product's syntax and messages (tests/api/test_cli_args.c)
    with pytest.raises(ValueError, match=r"^Trainer: basis 'l2:size=3': unknown key 'size' \(the keys are cap, energy, "
                                         r"center and product"):
        npg.Trainer(full, basis=["l2:size=3"])
    with pytest.raises(ValueError, match=r"'l2:cap=0': cap: 0 is out of range \(expected 1\.\.1000000\)"):
        npg.Trainer(full, basis="l2:cap=0")
    with pytest.raises(TypeError, match="list of 'NAME:cap=N"):
        npg.Trainer(full, basis={"l2": {"cap": 3}})
    with pytest.raises(TypeError, match=r"basis\[1\]"):
        npg.Trainer(full, basis=["l2:cap=3", 3])
    with pytest.raises(npg.Error, match="Trainer: basis nosuch: no quantity"):  # when made, not at finish()
        npg.Trainer(full, basis="nosuch:cap=3")


PRODUCT = """dim N, W
param cols : int[N, W]
param h : real[N, W]
input x : real[N]
op H[i:N, j:N] = sum(k = 0..W-1, h[i, k] * delta(j, cols[i, k]))
output y[i:N] = 2 * x[i]
"""


def test_trainer_basis_product_equals_npgc(tmp_path, npgc):
    """basis=["x:product=H"] (npg_parse_basis_product, issue 41) trains what npgc train --basis does."""
    n = 12
    cols = -np.ones((n, 3), dtype=np.int64)
    h = np.zeros((n, 3))
    for i in range(n):
        for k, j in enumerate((i - 1, i, i + 1)):
            if 0 <= j < n:
                cols[i, k], h[i, k] = j, (3.0 if i == j else -1.0)
    x = np.random.default_rng(4).standard_normal((9, n))
    prog = tmp_path / "product.npg"
    prog.write_text(PRODUCT)
    data = tmp_path / "DATA"
    data.mkdir()
    for name, v in (("cols", cols), ("h", h), ("x", x)):
        np.save(data / f"{name}.npy", v)
    npgc("train", prog, data, "-o", tmp_path / "CLI", "--basis", "x:cap=4,product=H")
    full = npg.compile(str(prog)).full(params={"cols": cols, "h": h})
    tr = npg.Trainer(full, basis=["x:cap=4,product=H"])
    for xk in x:
        tr.add(x=xk)
    tr.finish(tmp_path / "PY")
    same_model(tmp_path / "CLI", tmp_path / "PY")
    assert (tmp_path / "PY" / "dual_0.npy").exists()
    with pytest.raises(npg.Error, match=r"^Trainer: basis x:product=K: the program has no op of that name"):
        npg.Trainer(full, basis=["x:product=K"])


def test_trainer_options_checked(eq3):
    with pytest.raises(ValueError, match="energy"):
        npg.Trainer(eq3["prog"].full(), energy=1.5)
    with pytest.raises(TypeError):
        npg.Trainer("not a full evaluator")


# ---------------------------------------------------------------- reduced evaluation

ZERO_OP = """dim N, P
param K : real[N, N]
input mu : real[P]
input x : real[N]
op M[i:N, j:N] = mu[0] * (K[i, j] + K[j, i]) + mu[0] * delta(i, j)
output y = solve(M, x)
"""


def test_reduced_zero_operator_said(tmp_path):
    # at mu = 0 the operator is zero: said so, at these inputs (no "sample 2", the count of calls,
    # and no "basis too small?"), issue 38
    rng = np.random.default_rng(2)
    K = rng.random((20, 20))
    full = npg.compile(ZERO_OP, name="zero_op.npg").full(params={"K": K})
    tr = npg.Trainer(full, cap=3)
    for _ in range(20):
        tr.add(mu=1 + rng.random(1), x=rng.random(20))
    red = tr.finish(str(tmp_path / "Z")).reduced()
    x = rng.random(20)
    red(mu=np.array([1.5]), x=x)
    red(mu=np.array([1.2]), x=x)
    with pytest.raises(npg.Error) as e:
        red(mu=np.array([0.0]), x=x)
    msg = str(e.value)
    assert "reduced operator M is zero at these inputs" in msg, msg
    assert "sample" not in msg and "too small" not in msg, msg


def test_reduced_equals_npgc_eval(eq3, npgc):
    d = eq3["dir"]
    npgc("eval", RATIONAL, d / "CLI", d / "TEST", "-o", d / "OUT")
    coords = np.load(d / "OUT" / "y.reduced.npy")
    lifted = np.load(d / "OUT" / "y.npy")
    model = npg.load(eq3["prog"], str(d / "CLI"))
    red = model.reduced()
    for k, xk in enumerate(eq3["xt"]):
        out = red(x=xk)
        assert list(out) == ["y"]
        assert np.array_equal(out["y"], coords[k])
        assert np.array_equal(red.lift("y"), lifted[k])
        buf = np.empty(2)
        assert red.lift("y", out=buf) is buf and np.array_equal(buf, lifted[k])
    assert np.array_equal(red.coords("y"), coords[-1])
    # an input from its coordinates
    red2 = model.reduced()
    red2.set_coords("x", red.coords("x"))
    assert np.array_equal(red2()["y"], coords[-1])


def test_lift_many_equals_lift_per_sample(eq3):
    model = npg.load(eq3["prog"], str(eq3["dir"] / "CLI"))
    red = model.reduced()
    rows, one = [], []
    for xk in eq3["xt"]:
        red(x=xk)
        rows.append(red.coords("y"))
        one.append(red.lift("y").copy())
    many = red.lift("y", coords=np.array(rows))
    assert many.shape == (len(rows), 2)
    assert np.allclose(many, np.array(one), rtol=1e-14, atol=1e-14)
    with pytest.raises(npg.Error, match="reduced coordinates"):
        red.lift("y", coords=np.ones((3, len(rows[0]) + 1)))
    with pytest.raises(npg.Error, match="NaN at sample 1"):
        red.lift("y", coords=np.array([rows[0], np.full(len(rows[0]), np.nan)]))
    with pytest.raises(TypeError, match="not both"):
        red.lift("y", out=np.empty(2), coords=np.array(rows))
    with pytest.raises(TypeError, match="2-D array"):
        red.lift("y", coords=rows[0])


def test_verify(eq3):
    full = eq3["prog"].full()
    tr = npg.Trainer(full)
    for xk in eq3["x"]:
        tr.add(x=xk)
    model = tr.finish()
    rows = model.verify(test={"x": eq3["xt"]}, tol=0.5)
    assert set(rows) == {"x", "y"}
    y = rows["y"]
    assert y["output"] and y["kind"] == "inverse" and y["pass"] is True
    assert 0 <= y["floor"] <= y["l2"] + 1e-15 and y["l2"] < 0.5 and y["m"] == model.basis_sizes["{y}"]
    # a loaded model has no evaluator of its own
    loaded = npg.load(eq3["prog"], str(eq3["dir"] / "CLI"))
    with pytest.raises(npg.Error, match="full="):
        loaded.verify(test={"x": eq3["xt"]})
    assert loaded.verify(test={"x": eq3["xt"]}, full=full)["y"]["l2"] < 0.5
    with pytest.raises(npg.Error, match="samples"):
        model.verify(test={"x": eq3["xt"], "y": eq3["xt"][:3]})


def test_reduced_at_smaller_sizes(eq3, npgc):
    """Issue 41: model.reduced(sizes=...) evaluates at smaller sizes without retraining, as
    npgc eval --sizes does, and as training with x's cap at 1 (one member: its first vector)."""
    d = eq3["dir"]
    model = npg.load(eq3["prog"], str(d / "CLI"))
    full = eq3["prog"].full()
    tr = npg.Trainer(full, basis="x:cap=1")
    for xk in eq3["x"]:
        tr.add(x=xk)
    small = tr.finish()
    assert small.basis_sizes["{x}"] == 1 < model.basis_sizes["{x}"]
    npgc("eval", RATIONAL, d / "CLI", d / "TEST", "-o", d / "OUTSIZES", "--sizes", "m_x=1")
    lifted = np.load(d / "OUTSIZES" / "y.npy")
    red, ret = model.reduced(sizes={"m_x": 1}), small.reduced()
    for k, xk in enumerate(eq3["xt"]):
        red(x=xk), ret(x=xk)
        y, yr = red.lift("y"), ret.lift("y")
        assert np.array_equal(y, lifted[k])
        assert np.abs(y - yr).max() <= 1e-12 * np.abs(yr).max()
    assert red.coords("x").shape == (1,)
    with pytest.raises(npg.Error, match="--sizes m_q: no class of that name"):
        model.reduced(sizes={"m_q": 1})
    with pytest.raises(npg.Error, match="class m_x has 2 basis vectors"):
        model.reduced(sizes={"m_x": 3})
    with pytest.raises(TypeError, match="must be an int"):
        model.reduced(sizes={"m_x": 1.5})
    with pytest.raises(TypeError, match="must be a dict"):
        model.reduced(sizes=["m_x", 1])


# ---------------------------------------------------------------- bad input

def test_bad_arrays_raise(eq3):
    full = eq3["prog"].full()
    red = npg.load(eq3["prog"], str(eq3["dir"] / "CLI")).reduced()
    tr = npg.Trainer(full)
    # unset inputs
    with pytest.raises(npg.Error, match="'x' is not set"):
        full()
    with pytest.raises(npg.Error, match="'x' is not set"):
        red()
    # wrong shapes
    with pytest.raises(npg.Error, match="x"):
        full(x=np.ones(3))
    with pytest.raises(npg.Error, match=r"shape \(3,\); the model was trained with \(2,\)"):
        red(x=np.ones(3))
    with pytest.raises(npg.Error):
        tr.add(x=np.ones((2, 2)))
    # wrong dtypes
    for call in (lambda a: full(x=a), lambda a: red(x=a), lambda a: npg.Trainer(full).add(x=a)):
        with pytest.raises(TypeError, match="float64"):
            call(np.ones(2, dtype=np.float32))
        with pytest.raises(TypeError, match="float64"):
            call(np.array([1, 2]))
    # NaN and infinities
    with pytest.raises(npg.Error, match="NaN"):
        full(x=np.array([np.nan, 1.0]))
    with pytest.raises(npg.Error, match="NaN"):
        red(x=np.array([1.0, np.nan]))
    with pytest.raises(npg.Error, match="infinity"):
        npg.Trainer(full).add(x=np.array([np.inf, 1.0]))
    # unknown names
    with pytest.raises(npg.Error, match="no input 'z'"):
        red(z=np.ones(2))
    with pytest.raises(npg.Error, match="'z'"):
        full(z=np.ones(2))
    with pytest.raises(TypeError):
        full(np.ones(2))
    # every object is usable after its errors
    assert np.isfinite(full(x=np.array([1.0, 2.0]))["y"]).all()
    assert np.isfinite(red(x=np.array([1.0, 2.0]))["y"]).all()
    # a non-contiguous float64 view is accepted (copied)
    assert np.array_equal(red(x=np.array([[1.0, 9], [2.0, 9]])[:, 0])["y"], red(x=np.array([1.0, 2.0]))["y"])
    with pytest.raises(npg.Error, match="no quantity"):
        red.lift("nosuch")
    with pytest.raises(TypeError, match="out"):
        red.lift("y", out=np.empty(2, dtype=np.float32))
    with pytest.raises(npg.Error):
        red.lift("y", out=np.empty(3))
    with pytest.raises(ValueError, match="backend"):
        eq3["prog"].full(backend="gcc")


def test_load_errors_name_the_file(eq3, tmp_path):
    with pytest.raises(npg.Error, match="nosuch"):
        npg.load(eq3["prog"], str(tmp_path / "nosuch"))


# ---------------------------------------------------------------- externs as callables

def test_extern_callable_equals_extern_data(tmp_path):
    prog = npg.compile(EXTERN)
    F, V, S = 6, 8, 20
    rng = np.random.default_rng(3)
    tri = rng.integers(0, V, (F, 3))
    g = rng.random((S, V, 3))
    v = np.array([np.sin(gk[tri[:, 1], 1]) + 2 for gk in g])
    by_data = npg.Trainer(prog.full(params={"tri": tri}))
    for k in range(S):
        by_data.add(g=g[k], v=v[k])
    by_data.finish(tmp_path / "DATA_MODEL")
    full = prog.full(params={"tri": tri})
    calls = []

    def visibility(f, sample):
        calls.append(sample)
        return np.sin(f.get("g")[tri[:, 1], 1]) + 2

    full.extern("v", visibility)
    by_call = npg.Trainer(full)
    for k in range(S):
        by_call.add(g=g[k])
    model = by_call.finish(tmp_path / "CALL_MODEL")
    assert calls == list(range(S))  # once per sample, not again when training replays them
    same_model(tmp_path / "DATA_MODEL", tmp_path / "CALL_MODEL")
    assert np.allclose(full(g=g[0])["d"], v[0] * g[0][tri[:, 0], 0], rtol=1e-14)
    full(g=g[1])
    assert calls[-2:] == [0, 1]  # a full evaluator's k-th call is sample k
    assert model.verify(test={"g": g[:4]})["d"]["l2"] < 1e-6


def test_extern_callable_errors_raise(tmp_path):
    prog = npg.compile(EXTERN)
    tri = np.zeros((2, 3), dtype=np.int64)
    full = prog.full(params={"tri": tri})

    def broken(f, sample):
        raise KeyError("the visibility oracle failed")

    full.extern("v", broken)
    with pytest.raises(npg.Error, match="'v'") as e:
        full(g=np.ones((1, 3)))
    assert isinstance(e.value.__cause__, KeyError)
    full.extern("v", lambda f, k: np.ones(5))
    with pytest.raises(npg.Error) as e:
        full(g=np.ones((1, 3)))
    assert "5 values" in str(e.value.__cause__)

    def reentrant(f, k):
        return f(g=np.ones((1, 3)))["d"]

    full.extern("v", reentrant)
    with pytest.raises(npg.Error) as e:
        full(g=np.ones((1, 3)))
    assert "same evaluator" in str(e.value.__cause__)
    full.extern("v", lambda f, k: np.full(2, 3.0))
    assert np.array_equal(full(g=np.ones((1, 3)))["d"], np.full(2, 3.0))
    with pytest.raises(TypeError):
        full.extern("v", 42)
    with pytest.raises(npg.Error, match="extern"):
        full.extern("g", lambda f, k: 0)


# ---------------------------------------------------------------- lifetimes

def test_owners_outlive_their_users(eq3, tmp_path):
    """Programs, evaluators and models freed in every order their users allow."""
    xs = eq3["x"]
    prog = npg.compile(RATIONAL)
    full = prog.full()
    tr = npg.Trainer(full)
    del prog, full
    gc.collect()
    for xk in xs:
        tr.add(x=xk)
    model = tr.finish()
    del tr
    gc.collect()
    red = model.reduced()
    basis = model.basis("y")
    assert not basis.flags.writeable and basis.shape == (2, model.basis_sizes["{y}"])
    del model
    gc.collect()
    want = red(x=xs[0])["y"]
    assert np.allclose(basis @ want, red.lift("y"))
    loaded = npg.load(npg.compile(RATIONAL), str(eq3["dir"] / "CLI"))
    red2 = loaded.reduced()
    del loaded
    gc.collect()
    assert red2(x=xs[0])["y"].shape == (red2.model.basis_sizes["{y}"],)
    del red, red2
    gc.collect()
    assert np.isfinite(basis).all()  # the view kept its model


def test_reference_cycles_are_collected():
    prog = npg.compile(EXTERN)
    tri = np.zeros((1, 3), dtype=np.int64)
    for _ in range(3):
        full = prog.full(params={"tri": tri})
        holder = {"full": full}
        full.extern("v", lambda f, k, holder=holder: np.ones(1) * len(holder))  # full -> lambda -> full
        tr = npg.Trainer(full)
        holder["tr"] = tr
        tr.add(g=np.ones((1, 3)))
        holder["model"] = tr.finish()
        del full, tr, holder
        assert gc.collect() > 0
    gc.collect()


def test_threads_share_a_model(eq3):
    model = npg.load(eq3["prog"], str(eq3["dir"] / "CLI"))
    serial = [model.reduced()(x=xk)["y"] for xk in eq3["xt"]]
    results = {}

    def work(t):
        red = model.reduced()
        for _ in range(50):
            results[t] = [red(x=xk)["y"] for xk in eq3["xt"]]

    threads = [threading.Thread(target=work, args=(t,)) for t in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for t in range(4):
        assert all(np.array_equal(a, b) for a, b in zip(results[t], serial))
    # one evaluator called from two threads takes turns
    red = model.reduced()
    out = {}
    threads = [threading.Thread(target=lambda t=t: out.setdefault(t, red(x=eq3["xt"][t])["y"])) for t in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert np.array_equal(out[0], serial[0]) and np.array_equal(out[1], serial[1])


def test_evaluation_path_copies_no_array(tmp_path):
    """red(...) projects a float64 C-contiguous input in place and returns
    coordinates: what it allocates through Python (NumPy's buffers are
    traced) is far below one input; a non-contiguous input is copied."""
    import tracemalloc

    edge, L0, x = springs_data(30, 4, n=16)
    full = npg.compile(SPRINGS).full(params={"edge": edge, "L0": L0})
    tr = npg.Trainer(full)
    for xk in x:
        tr.add(x=xk)
    red = tr.finish().reduced()
    xin = x[0]
    assert xin.flags.c_contiguous and xin.nbytes == 16 * 16 * 3 * 8
    strided = np.asfortranarray(x[1])
    red(x=xin)

    def peak(arr):
        tracemalloc.start()
        red(x=arr)
        p = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return p

    assert peak(xin) < xin.nbytes / 2
    assert peak(strided) >= strided.nbytes  # the copy this test exists to catch


def test_no_reference_leaks_per_call(eq3):
    """Calls that succeed and calls that raise leave nothing behind: over
    5,000 rounds a loss of one small object a call would be ~100 KB."""
    import tracemalloc

    full = eq3["prog"].full()
    red = npg.load(eq3["prog"], str(eq3["dir"] / "CLI")).reduced()
    x, strided = np.array([1.0, 2.0]), np.array([[1.0, 9], [2.0, 9]])[:, 0]

    def rounds(n):
        for _ in range(n):
            red(x=x), red(x=strided), red.lift("y"), red.coords("y"), full(x=x), full.get("y")
            for bad in (lambda: red(x=np.array([np.nan, 1.0])), lambda: full(x=np.ones(3)),
                        lambda: red(x=np.ones(3))):
                with pytest.raises(npg.Error):
                    bad()

    rounds(200)
    gc.collect()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    rounds(5000)
    gc.collect()
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert grown < 16384, grown


def test_output_op_equals_npgc_eval(tmp_path, npgc):
    """An `output op`: full.op() (CSR arrays owning the library's buffers)
    equals npgc eval --full's CSR files; red.op() equals npgc eval's reduced
    matrices."""
    prog_path = "tests/programs/output_op.npg"
    N, S = 6, 12
    rng = np.random.default_rng(5)
    a = rng.random((N, N)) * (rng.random((N, N)) < 0.5) + np.eye(N)
    w, x = 1 + rng.random((S, N)), rng.random((S, N))
    data = tmp_path / "DATA"
    data.mkdir()
    for name, v in (("a", a), ("w", w), ("x", x)):
        np.save(data / f"{name}.npy", v)
    npgc("eval", prog_path, "--full", data, data, "-o", tmp_path / "FULL")
    npgc("train", prog_path, data, "-o", tmp_path / "MODEL", "--cap", "3")
    npgc("eval", prog_path, tmp_path / "MODEL", data, "-o", tmp_path / "RED")
    prog = npg.compile(prog_path)
    full = prog.full(params={"a": a})
    red = npg.load(prog, str(tmp_path / "MODEL")).reduced()
    want_data = np.load(tmp_path / "FULL" / "K.data.npy")
    want_red = np.load(tmp_path / "RED" / "K.reduced.npy")
    for k in range(S):
        full(w=w[k], x=x[k])
        K = full.op("K")
        assert K["shape"] == (N, N)
        assert np.array_equal(K["indptr"], np.load(tmp_path / "FULL" / "K.indptr.npy"))
        assert np.array_equal(K["indices"], np.load(tmp_path / "FULL" / "K.indices.npy"))
        assert np.max(np.abs(K["data"] - want_data[k])) <= 1e-15 * np.max(np.abs(want_data[k]))
        dense = np.zeros((N, N))
        for r in range(N):
            dense[r, K["indices"][K["indptr"][r]:K["indptr"][r + 1]]] = K["data"][K["indptr"][r]:K["indptr"][r + 1]]
        assert np.allclose(dense, a * w[k][None, :], rtol=1e-15, atol=0)
        red(w=w[k], x=x[k])
        assert np.array_equal(red.op("K"), want_red[k])
    with pytest.raises(npg.Error):
        full.op("y")
    with pytest.raises(npg.Error):
        red.op("y")


def test_streamed_basis_raises(tmp_path, npgc, root):
    """A basis the model does not keep (issue 30: radiosity's pair class {s,h}) raises naming
    --keep-bases instead of giving an array of uninitialized memory; a kept one is a view."""
    import os
    data = pathlib.Path(os.environ.get("NPG_NPGC", root / "build" / "npgc")).parent / "radiosity_data"
    import subprocess
    subprocess.run([str(data), str(tmp_path / "D"), "48", "8", "0", "1", "3"], check=True, capture_output=True)
    prog_path = root / "examples" / "radiosity" / "formfactors.npg"
    npgc("train", prog_path, tmp_path / "D", "-o", tmp_path / "M", "--cap", "4")
    model = npg.load(npg.compile(str(prog_path)), str(tmp_path / "M"))
    with pytest.raises(npg.Error, match="--keep-bases h"):
        model.basis("h")
    b = model.basis("b")
    assert np.allclose(b.T @ b, np.eye(b.shape[1]), atol=1e-12)
    # Trainer(keep_bases=) as npgc train --keep-bases: the same model, h's basis kept
    full = npg.compile(str(prog_path)).full(params={n: np.load(tmp_path / "D" / f"{n}.npy") for n in ("tri", "rho")})
    g, e, v = (np.load(tmp_path / "D" / f"{n}.npy") for n in ("g", "e", "v"))
    tr = npg.Trainer(full, cap=4, keep_bases="h")
    for k in range(len(g)):
        tr.add(g=g[k], e=e[k], v=v[k])
    kept = tr.finish(tmp_path / "K")
    npgc("train", prog_path, tmp_path / "D", "-o", tmp_path / "KCLI", "--cap", "4", "--keep-bases", "h")
    same_model(tmp_path / "K", tmp_path / "KCLI")
    h = kept.basis("h")
    assert np.allclose(h.T @ h, np.eye(h.shape[1]), atol=1e-12)


def test_coefficients_and_dots(tmp_path, root):
    """Out of core, radiosity's v is kept as coefficients C of its training values (issue 30):
    model.coefficients("v") and tr.dots("v", v) give the training coordinates Cᵀ(Xᵀv_k) the
    model learned, and a visibility no sample had the same coordinates as keep_bases="v"'s
    basis gives; the refusals name the class."""
    import os
    import subprocess
    data = pathlib.Path(os.environ.get("NPG_NPGC", root / "build" / "npgc")).parent / "radiosity_data"
    subprocess.run([str(data), str(tmp_path / "D"), "48", "16", "0", "1", "3"], check=True, capture_output=True)
    prog = npg.compile(str(root / "examples" / "radiosity" / "formfactors.npg"))
    params = {n: np.load(tmp_path / "D" / f"{n}.npy") for n in ("tri", "rho")}
    g, e, v = (np.load(tmp_path / "D" / f"{n}.npy") for n in ("g", "e", "v"))

    def train(**opt):
        tr = npg.Trainer(prog.full(params=params), cap=16, energy=1, mem=160000, **opt)
        for k in range(len(g)):
            tr.add(g=g[k], e=e[k], v=v[k])
        return tr, tr.finish(tmp_path / ("K" if opt else "M"))

    tr, model = train()
    C = model.coefficients("v")
    assert C.shape[0] == len(g) and not C.flags.writeable
    with pytest.raises(npg.Error, match="model.coefficients.*--keep-bases v"):
        model.basis("v")
    z = np.load(tmp_path / "M" / "extern_v_values.npy")
    for k in range(len(g)):
        d = tr.dots("v", v[k])
        assert d.shape == (len(g),)
        assert np.allclose(d, [np.vdot(v[k], v[l]) for l in range(len(g))], rtol=1e-12, atol=0)
        assert np.abs(C.T @ d - z[k]).max() <= 1e-10 * np.abs(z).max()
    # a visibility of no training sample: the same coordinates as the kept basis's Bᵀv
    trk, kept = train(keep_bases="v")
    B = kept.basis("v")
    with pytest.raises(npg.Error, match="keeps its basis"):
        kept.coefficients("v")
    w = np.where(np.random.default_rng(2).random(v[0].shape) < 0.5, v[3], v[7])
    zb, zc = B.T @ w.ravel(), C.T @ tr.dots("v", w)
    assert np.abs(zb - zc).max() <= 1e-10 * max(1.0, np.abs(zb).max())
    # the README's recipe: the extern given by those coordinates (red.given_externs) evaluates as
    # the kept basis's model given w in full
    red, redk = model.reduced(), kept.reduced()
    with pytest.raises(npg.Error, match="extern"):
        red.set_coords("v", zc)
    red.given_externs(True), redk.given_externs(True)
    red.set_coords("v", zc)
    b = red(g=g[2], e=e[2])["b"]
    bk = redk(g=g[2], e=e[2], v=w)["b"]
    assert np.abs(b - bk).max() <= 1e-8 * np.abs(bk).max()
    with pytest.raises(npg.Error, match="entries"):
        tr.dots("v", v[0][:5])
    with pytest.raises(npg.Error, match="no input or extern"):  # a failed trainer refuses further work
        trk.dots("nothing", v[0])
    with pytest.raises(npg.Error, match="not kept as coefficients"):
        model.coefficients("b")


def gravity_data(d):
    """The n-body program's samples of tests/cli/interp.sh: 8 bodies moved by 3 modes."""
    rng = np.random.default_rng(4)
    base = rng.normal(size=(8, 3)) * 2
    modes = rng.normal(size=(3, 8, 3))
    out = {}
    for name, S in (("TRAIN", 40), ("VALID", 8)):
        (d / name).mkdir()
        x = base + np.einsum("sk,kvc->svc", 0.2 * rng.normal(size=(S, 3)), modes)
        np.save(d / name / "x.npy", x)
        np.save(d / name / "mass.npy", np.full(8, 0.125))
        np.save(d / name / "eps.npy", np.array(0.05))
        out[name] = x
    return out


def test_interpolated_stages(tmp_path, npgc, root):
    """Issue 26 through Python: the trainer's interp=, galerkin=, interp_oversample=, valid= and
    valid_holdout= give the models npgc train's --reduce, --interp-oversample and --valid give (byte
    for byte), and model.interpolated() / model.reductions() read the choice the model records."""
    x = gravity_data(tmp_path)
    prog_path = root / "tests" / "programs" / "nbody_gravity.npg"
    prog = npg.compile(str(prog_path))
    full = prog.full(str(tmp_path / "TRAIN"))

    def train(name, **kw):
        tr = npg.Trainer(full, **kw)
        for s in x["TRAIN"]:
            tr.add(x=s)
        return tr.finish(tmp_path / name)

    forced = train("PI", interp=["w"], interp_oversample=2)
    npgc("train", prog_path, tmp_path / "TRAIN", "-o", tmp_path / "CI", "--reduce", "w:interp", "--interp-oversample", "2")
    same_model(tmp_path / "PI", tmp_path / "CI")
    # 2 x m 9 draws: the 9 pivoted entries and 9 by leverage, the distinct ones counted (as
    # tests/cli/interp.sh reads in npgc train's report)
    k = forced.interpolated("w")
    assert 9 < k <= 18
    assert forced.interpolated("r2") is None  # not eligible: Galerkin
    assert npg.load(prog, str(tmp_path / "CI")).interpolated("w") == k
    assert f"stage w: interpolated at {k} of 64 entries" in forced.reductions()
    with pytest.raises(npg.Error, match="no stage 'x'"):
        forced.interpolated("x")

    chosen = train("PV", valid={"x": x["VALID"]})
    npgc("train", prog_path, tmp_path / "TRAIN", "-o", tmp_path / "CV", "--valid", tmp_path / "VALID")
    same_model(tmp_path / "PV", tmp_path / "CV")
    assert "output error on the validation samples by Galerkin" in chosen.reductions()
    assert chosen.interpolated("w") == npg.load(prog, str(tmp_path / "CV")).interpolated("w")

    held = train("PH", valid_holdout=0.25)
    npgc("train", prog_path, tmp_path / "TRAIN", "-o", tmp_path / "CH", "--valid", "0.25")
    same_model(tmp_path / "PH", tmp_path / "CH")
    assert held.samples == 30 and "stage w" in held.reductions()

    galerkin = train("PG", valid={"x": x["VALID"]}, galerkin="w")
    assert galerkin.interpolated("w") is None and "stage w" not in galerkin.reductions()

    with pytest.raises(npg.Error, match="stage r2 cannot be interpolated"):
        train("BAD", interp=["r2"])
    with pytest.raises(ValueError, match="interp_oversample 0.5"):
        npg.Trainer(full, interp_oversample=0.5)
    with pytest.raises(ValueError, match="valid= and valid_holdout= both"):
        npg.Trainer(full, valid={"x": x["VALID"]}, valid_holdout=0.25)
    with pytest.raises(ValueError, match="valid_holdout 0.7"):
        npg.Trainer(full, valid_holdout=0.7)
    with pytest.raises(npg.Error, match=r"Trainer: valid\['x'\] has no sample axis"):
        npg.Trainer(full, valid={"x": np.array(1.0)})
    with pytest.raises(TypeError, match=r"interp\[0\] must be a stage name"):
        npg.Trainer(full, interp=[3])
