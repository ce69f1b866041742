"""Issue 38 through Python: no silent answer and no crash from threads, callables that misbehave,
options of the wrong type or externs left out; one default behind npgc, npg.h and Python."""
import gc
import os
import pathlib
import subprocess
import threading
import time

import numpy as np
import pytest

import npg

RATIONAL = "examples/rational/rational.npg"
EXTERN = "tests/programs/extern_stage.npg"
GRAVITY = "tests/programs/nbody_gravity.npg"


def extern_data(S, seed=3, F=6, V=8):
    rng = np.random.default_rng(seed)
    tri = rng.integers(0, V, (F, 3))
    g = rng.random((S, V, 3))
    v = np.array([np.sin(gk[tri[:, 1], 1]) + 2 for gk in g])
    return tri, g, v


def same_model(a, b):
    """Every file of MODEL a is byte-identical in b, and both hold the same files."""
    fa = sorted(p.name for p in pathlib.Path(a).iterdir())
    fb = sorted(p.name for p in pathlib.Path(b).iterdir())
    assert fa == fb and len(fa) >= 3
    for name in fa:
        assert (pathlib.Path(a) / name).read_bytes() == (pathlib.Path(b) / name).read_bytes(), name


# ---------------------------------------------------------------- memory safety

def test_dots_sized_under_the_lock():
    """tr.dots from a thread while tr.add evaluates on another: each result has one entry per sample
    the trainer held when it read them (the array was sized before the lock: a write past it).
    The externs are given, so no callable runs and dots waits for each add."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(12)
    full = prog.full(params={"tri": tri})
    tr = npg.Trainer(full)
    tr.add(g=g[0], v=v[0])
    got, stop = [], threading.Event()

    def dots():
        while not stop.is_set():
            got.append(tr.dots("g", g[0]))

    t = threading.Thread(target=dots)
    t.start()
    for k in range(1, 12):
        tr.add(g=g[k], v=v[k])
    stop.set()
    t.join()
    assert tr.samples == 12 and got
    want = [np.vdot(g[0], g[k]) for k in range(12)]
    for d in got:
        assert 1 <= d.shape[0] <= 12 and np.allclose(d, want[:d.shape[0]], rtol=1e-14)


def test_verify_survives_a_callable_clearing_its_test_dict():
    """An extern callable that clears model.verify's test= dict: the names and arrays verify
    sets each sample from stay alive (they were read from the freed dict's keys)."""
    prog = npg.compile("dim F\ninput gpos : real[F]\nextern vis[i:F] of gpos\n"
                       "output d[i:F] = vis[i] * gpos[i]\n", name="clear.npg")
    g = 1 + np.random.default_rng(6).random((20, 5))
    full = prog.full()
    full.extern("vis", lambda f, k: np.sin(f.get("gpos")) + 2)
    tr = npg.Trainer(full)
    for k in range(20):
        tr.add(gpos=g[k])
    model = tr.finish()
    expect = model.verify(test={"gpos": g[:3].copy()})["d"]["l2"]
    test = {"".join(["gp", "os"]): g[:3].copy()}  # a key and an array only the dict holds

    def clearing(f, k):
        test.clear()
        gc.collect()
        junk = ["".join(["ab", "cd"]) for _ in range(2000)]  # the freed key's memory reused
        junk.clear()
        return np.sin(f.get("gpos")) + 2

    full.extern("vis", clearing)
    assert model.verify(test=test)["d"]["l2"] == expect


def test_get_from_another_thread_inside_a_callable():
    """An extern callable whose helper thread reads the evaluator (full.get): the values, not a
    deadlock (the callable waits for a thread that waited for the evaluation)."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(2)
    full = prog.full(params={"tri": tri})
    seen = {}

    def visibility(f, sample):
        t = threading.Thread(target=lambda: seen.__setitem__("g", f.get("g")))
        t.start()
        t.join(timeout=20)
        assert not t.is_alive(), "full.get from a helper thread deadlocked"
        return np.sin(seen["g"][tri[:, 1], 1]) + 2

    full.extern("v", visibility)
    out = full(g=g[0])["d"]
    assert np.array_equal(seen["g"], g[0])
    assert np.allclose(out, v[0] * g[0][tri[:, 0], 0], rtol=1e-14)
    # the same in a trainer and in verify (the evaluator's lock held by them)
    tr = npg.Trainer(full)
    tr.add(g=g[1])
    assert np.array_equal(seen["g"], g[1])


@pytest.mark.parametrize("call", ["full", "bind", "op", "add", "add_full", "dots", "finish", "verify"])
def test_evaluating_from_another_thread_inside_a_callable(call):
    """An extern callable whose helper thread evaluates with the same evaluator (full(...), bind,
    a Trainer's methods, verify): npg.Error naming the call, not a deadlock (the evaluation waits
    for the callable, which waits for the helper). The outer evaluation then completes."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(3)
    full = prog.full(params={"tri": tri})
    tr = npg.Trainer(full)
    seen = {}
    calls = {
        "full": lambda f: f(g=g[1]),
        "bind": lambda f: f.bind({"tri": tri}),
        "op": lambda f: f.op("d"),
        "add": lambda f: tr.add(g=g[1]),
        "add_full": lambda f: tr.add_full(),
        "dots": lambda f: tr.dots("g", g[1]),
        "finish": lambda f: tr.finish(),
        "verify": lambda f: model.verify(test={"g": g[:2]}, full=f),
    }

    def helper(f):
        try:
            calls[call](f)
            seen["error"] = None
        except npg.Error as e:
            seen["error"] = str(e)

    model = None
    if call == "verify":  # a model of the same program to verify against
        other = prog.full(params={"tri": tri})
        other.extern("v", lambda f, k: np.sin(f.get("g")[tri[:, 1], 1]) + 2)
        t2 = npg.Trainer(other)
        for k in range(3):
            t2.add(g=g[k])
        model = t2.finish()

    def visibility(f, sample):
        if "error" not in seen:
            t = threading.Thread(target=helper, args=(f,))
            t.start()
            t.join(timeout=20)
            assert not t.is_alive(), f"{call} from a helper thread deadlocked"
        return np.sin(f.get("g")[tri[:, 1], 1]) + 2

    full.extern("v", visibility)
    out = full(g=g[0])["d"]
    assert np.allclose(out, v[0] * g[0][tri[:, 0], 0], rtol=1e-14)
    assert seen["error"] and "from a thread started while an extern callable of the same evaluator runs" in seen["error"]
    name = {"full": "Full.__call__", "bind": "Full.bind", "op": "Full.op", "add": "Trainer.add",
            "add_full": "Trainer.add_full", "dots": "Trainer.dots", "finish": "Trainer.finish",
            "verify": "Model.verify"}[call]
    assert seen["error"].startswith(name + ":"), seen["error"]
    # after the callable returned the same calls work
    tr.add(g=g[2])
    assert tr.samples == 1


def test_thread_from_before_a_callable_waits_its_turn():
    """A thread that existed before an extern callable started, calling the same evaluator while the
    callable runs (the callable does not wait for it), waits its turn and evaluates correctly."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(2)
    full = prog.full(params={"tri": tri})
    running, got = threading.Event(), {}

    def other():
        running.wait(20)
        got["d"] = full(g=g[1])["d"]

    def visibility(f, sample):
        if not running.is_set():
            running.set()
            time.sleep(0.2)  # the other thread calls full(...) meanwhile and waits for the lock
        return np.sin(f.get("g")[tri[:, 1], 1]) + 2

    t = threading.Thread(target=other)
    t.start()
    full.extern("v", visibility)
    out = full(g=g[0])["d"]
    t.join(20)
    assert not t.is_alive()
    assert np.allclose(out, v[0] * g[0][tri[:, 0], 0], rtol=1e-14)
    assert np.allclose(got["d"], v[1] * g[1][tri[:, 0], 0], rtol=1e-14)


# ---------------------------------------------------------------- externs left out

def test_extern_left_out_is_refused():
    """An extern without a callable left out of tr.add (or of verify's test=) is refused naming
    it; it was evaluated with the previous sample's value."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(40)
    tr = npg.Trainer(prog.full(params={"tri": tri}))
    tr.add(g=g[0], v=v[0])
    with pytest.raises(npg.Error, match=r"training sample 1: extern 'v' is not given and has no callback.*full.extern"):
        tr.add(g=g[1])
    tr.add(g=g[1], v=v[1])  # the trainer is still usable: the refused sample is not counted
    assert tr.samples == 2
    for k in range(2, 40):
        tr.add(g=g[k], v=v[k])
    model = tr.finish()
    full = prog.full(params={"tri": tri})
    with pytest.raises(npg.Error, match=r"extern 'v'.*not given"):
        model.verify(test={"g": g[:3]}, full=full)
    ok = model.verify(test={"g": g[:3], "v": v[:3]}, full=full)
    assert ok["d"]["l2"] < 1e-6
    with pytest.raises(npg.Error, match=r"input 'g'.*not given"):
        model.verify(test={"v": v[:3]}, full=full)


# ---------------------------------------------------------------- options

@pytest.mark.parametrize("opt", ["center", "joint", "progress"])
def test_flags_take_bools_only(opt):
    full = npg.compile(RATIONAL).full()
    for bad in ("off", "no", "", None, 2, 0.5, [1]):
        with pytest.raises(TypeError, match=f"Trainer: {opt} must be True or False"):
            npg.Trainer(full, **{opt: bad})
    for good in (True, False, 0, 1, np.bool_(True)):
        npg.Trainer(full, **{opt: good})


def test_other_flags_take_bools_only(tmp_path):
    prog = npg.compile(RATIONAL)
    tr = npg.Trainer(prog.full())
    for x in 0.5 + np.random.default_rng(1).random((12, 2)):
        tr.add(x=x)
    model = tr.finish()
    with pytest.raises(TypeError, match="verify: progress must be True or False"):
        model.verify(test={"x": 0.5 + np.ones((2, 2))}, progress="no")
    with pytest.raises(TypeError, match="reduced: exact_roots must be True or False"):
        model.reduced(exact_roots="off")


def test_mem_errors_name_mem():
    full = npg.compile(RATIONAL).full()
    with pytest.raises(ValueError, match="Trainer: mem -1"):
        npg.Trainer(full, mem=-1)
    with pytest.raises(ValueError, match="Trainer: mem 0"):
        npg.Trainer(full, mem=0)
    with pytest.raises(TypeError, match="Trainer: mem must be an int"):
        npg.Trainer(full, mem="1G")
    with pytest.raises(ValueError, match="Trainer: mem"):
        npg.Trainer(full, mem=2**80)


def test_options_checked_at_construction():
    """Trainer's options are refused when it is made, in Python's words (keyword names), not at
    finish() after every sample was streamed."""
    prog = npg.compile(GRAVITY)
    full = prog.full(params={"mass": np.full(8, 0.125), "eps": np.array(0.05)})
    with pytest.raises(npg.Error, match=r"Trainer: basis nosuch: no quantity"):
        npg.Trainer(full, basis="nosuch:cap=3")
    with pytest.raises(npg.Error, match=r"Trainer: interp r2: stage r2 cannot be interpolated"):
        npg.Trainer(full, interp=["r2"])
    with pytest.raises(npg.Error, match=r"Trainer: galerkin nosuch: the program has no stage 'nosuch'"):
        npg.Trainer(full, galerkin=["nosuch"])
    with pytest.raises(npg.Error, match=r"Trainer: keep_bases nosuch: no quantity or class"):
        npg.Trainer(full, keep_bases="nosuch")
    with pytest.raises(ValueError, match=r"Trainer: valid_holdout 0.7"):
        npg.Trainer(full, valid_holdout=0.7)


# ---------------------------------------------------------------- a refused call

def test_refused_add_leaves_the_trainer_usable():
    prog = npg.compile(RATIONAL)
    full = prog.full()
    tr = npg.Trainer(full)
    xs = 0.5 + np.random.default_rng(2).random((12, 2))
    for x in xs[:6]:
        tr.add(x=x)
    with pytest.raises(npg.Error, match="NaN"):
        tr.add(x=np.array([np.nan, 1.0]))
    with pytest.raises(npg.Error, match="no input or extern 'z'"):
        tr.add(z=np.ones(2))
    with pytest.raises(npg.Error):
        tr.add(x=np.ones(3))
    with pytest.raises(npg.Error, match="^Trainer.weight: the weight of training sample 6 is -1"):
        tr.weight(-1)
    with pytest.raises(npg.Error, match="no input or extern"):
        tr.dots("nothing", np.ones(2))
    for x in xs[6:]:
        tr.add(x=x)
    assert tr.samples == 12
    model = tr.finish()
    ref = npg.Trainer(full)
    for x in xs:
        ref.add(x=x)
    assert model.samples == ref.finish().samples == 12


# ---------------------------------------------------------------- reduced evaluation

def test_op_before_any_evaluation_is_refused(tmp_path, root):
    prog = npg.compile(str(root / "tests" / "programs" / "output_op.npg"))
    rng = np.random.default_rng(5)
    full = prog.full(params={"a": rng.random((3, 3))})
    tr = npg.Trainer(full)
    for w, x in 0.5 + rng.random((10, 2, 3)):
        tr.add(w=w, x=x)
    red = tr.finish().reduced()
    with pytest.raises(npg.Error, match="operator K reads 'w'.*nothing was evaluated"):
        red.op("K")
    red(w=np.full(3, 0.7), x=np.full(3, 0.6))
    assert red.op("K").shape[0] >= 1


def test_given_externs_recipe(tmp_path):
    """The README's coordinates recipe for an extern: red.given_externs(True), then the extern
    given in full (projected) or by coordinates, equals the full value's projection."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(20)
    tr = npg.Trainer(prog.full(params={"tri": tri}), keep_bases="v")
    for k in range(20):
        tr.add(g=g[k], v=v[k])
    model = tr.finish()
    red = model.reduced()
    with pytest.raises(npg.Error, match="extern"):
        red.set_coords("v", model.basis("v").T @ v[0])
    red.given_externs(True)
    with pytest.raises(npg.Error, match="'v' was never set"):
        red(g=g[0])
    red.set_coords("v", model.basis("v").T @ v[0])
    a = red(g=g[0])["d"]
    red(g=g[0], v=v[0])
    assert np.allclose(red.coords("d"), a, rtol=1e-12)
    with pytest.raises(TypeError, match="given_externs: on must be True or False"):
        red.given_externs("yes")
    red.given_externs(False)
    red(g=g[0])


# ---------------------------------------------------------------- one program, compiled twice

def test_same_program_compiled_twice_is_accepted(tmp_path, root):
    path = str(root / RATIONAL)
    p1, p2 = npg.compile(path), npg.compile(path)
    tr = npg.Trainer(p1.full())
    for x in 0.5 + np.random.default_rng(3).random((12, 2)):
        tr.add(x=x)
    tr.finish(tmp_path / "M")
    m1 = npg.load(p1, str(tmp_path / "M"), full=p2.full())
    test = {"x": 0.5 + np.random.default_rng(4).random((3, 2))}
    assert m1.verify(test=test, full=p2.full())["y"]["l2"] < 1
    other = npg.compile("input x : real[2]\noutput y = [x[0] * x[1], x[1]]\n")
    with pytest.raises(npg.Error, match="another program"):
        m1.verify(test=test, full=other.full())
    with pytest.raises(npg.Error, match="another program"):
        npg.load(p1, str(tmp_path / "M"), full=other.full())


# ---------------------------------------------------------------- one default behind every interface

def test_python_npgc_and_c_train_the_same_model(tmp_path, npgc, root):
    """The same samples through npgc train, npg.h (build/train_via_api) and npg.Trainer, every
    option at its default: the three MODEL/ folders are the same bytes (the automatic hold-out
    of DESIGN §12 chooses the reduction of the n-body program's eligible stage w)."""
    rng = np.random.default_rng(4)
    base = rng.normal(size=(8, 3)) * 2
    modes = rng.normal(size=(3, 8, 3))
    x = base + np.einsum("sk,kvc->svc", 0.2 * rng.normal(size=(40, 3)), modes)
    d = tmp_path / "DATA"
    d.mkdir()
    np.save(d / "x.npy", x)
    np.save(d / "mass.npy", np.full(8, 0.125))
    np.save(d / "eps.npy", np.array(0.05))
    prog_path = root / GRAVITY
    npgc("train", prog_path, d, "-o", tmp_path / "CLI")
    api = os.environ.get("NPG_TRAIN_VIA_API", root / "build" / "tests" / "train_via_api")
    subprocess.run([str(api), str(prog_path), str(d), str(tmp_path / "API")], check=True, capture_output=True)
    prog = npg.compile(str(prog_path))
    tr = npg.Trainer(prog.full(str(d)))
    for s in x:
        tr.add(x=s)
    model = tr.finish(tmp_path / "PY")
    assert "by interpolation" in model.reductions()  # the hold-out ran
    same_model(tmp_path / "CLI", tmp_path / "API")
    same_model(tmp_path / "CLI", tmp_path / "PY")


# ---------------------------------------------------------------- found by a hostile trial

def test_none_is_not_an_array():
    """None was made a 0-d NaN array by numpy: 'has 0 axes' or 'holds NaN' named the wrong problem."""
    prog = npg.compile(RATIONAL)
    full = prog.full()
    with pytest.raises(TypeError, match="argument 'x': None"):
        full(x=None)
    with pytest.raises(TypeError, match="'x': None"):
        npg.Trainer(full).add(x=None)
    tr = npg.Trainer(full)
    for x in 0.5 + np.random.default_rng(1).random((12, 2)):
        tr.add(x=x)
    model = tr.finish()
    with pytest.raises(TypeError, match="input 'x': None"):
        model.reduced()(x=None)
    with pytest.raises(TypeError, match=r"test\['x'\]: None"):
        model.verify(test={"x": None})


def test_number_options_are_named():
    """A str or None given for a number option said 'must be real number, not str' without naming it."""
    full = npg.compile(RATIONAL).full()
    for opt in ("energy", "interp_oversample", "valid_holdout"):
        for bad in ("0.9", True):
            with pytest.raises(TypeError, match=f"Trainer: {opt}"):
                npg.Trainer(full, **{opt: bad})
    with pytest.raises(TypeError, match="Trainer: energy must be a number, not NoneType"):
        npg.Trainer(full, energy=None)
    tr = npg.Trainer(full)
    for bad in (None, "2"):
        with pytest.raises(TypeError, match="Trainer.weight: the weight must be a number"):
            tr.weight(bad)
    tr.weight(np.float32(2))
    tr.add(x=np.array([1.0, 2.0]))
    for x in 0.5 + np.random.default_rng(1).random((11, 2)):
        tr.add(x=x)
    with pytest.raises(TypeError, match="verify: tol must be a number"):
        tr.finish().verify(test={"x": 0.5 + np.ones((2, 2))}, tol="1e-3")


def test_nonfinite_coordinates_and_validation_samples_refused():
    prog = npg.compile(GRAVITY)
    full = prog.full(params={"mass": np.full(8, 0.125), "eps": np.array(0.05)})
    bad = np.ones((3, 8, 3))
    bad[2, 1, 2] = np.nan
    with pytest.raises(npg.Error, match=r"Trainer: valid\['x'\] sample 2 holds NaN at flat entry 5"):
        npg.Trainer(full, valid={"x": bad})  # when made, not at finish() after every sample
    eq3 = npg.compile(RATIONAL)
    tr = npg.Trainer(eq3.full())
    for x in 0.5 + np.random.default_rng(1).random((12, 2)):
        tr.add(x=x)
    red = tr.finish().reduced()
    with pytest.raises(npg.Error, match="coordinates of 'x' hold NaN at entry 0"):
        red.set_coords("x", [np.nan, 1.0])
    with pytest.raises(npg.Error, match="coordinates of 'x' hold an infinity"):
        red.set_coords("x", [1.0, np.inf])
    with pytest.raises(npg.Error, match="'x' has no value to lift"):
        red.lift("x")  # the refused coordinates were not set


def test_empty_extern_from_a_callable():
    """A dim of 0: the callable's empty result is copied into the evaluator's empty buffer (a
    memcpy to NULL, undefined behaviour under UBSan) and the output is empty."""
    prog = npg.compile("dim F\ninput gpos : real[F]\nextern vis[i:F] of gpos\noutput d[i:F] = vis[i] * gpos[i]\n",
                       name="empty.npg")
    full = prog.full()
    full.extern("vis", lambda f, k: np.sin(f.get("gpos")) + 2)
    assert full(gpos=np.zeros(0))["d"].shape == (0,)


def test_callable_reads_inputs_only():
    """While extern callables run, the stages and the other externs still hold the previous
    sample's values: reading them is refused (it returned them silently)."""
    prog = npg.compile("dim F\ninput gpos : real[F]\nextern va[i:F] of gpos\nextern vb[i:F] of gpos\n"
                       "output d[i:F] = va[i] * vb[i] * gpos[i]\n", name="two.npg")
    g = 1 + np.random.default_rng(7).random((2, 5))
    full = prog.full()
    full.extern("va", lambda f, k: np.sin(f.get("gpos")) + 2)
    full.extern("vb", lambda f, k: np.cos(f.get("gpos")) + 2)
    full(gpos=g[0])
    full.extern("vb", lambda f, k: f.get("va") + 1)
    with pytest.raises(npg.Error) as e:
        full(gpos=g[1])
    assert "Full.get('va') while an extern callable runs" in str(e.value.__cause__)
    full.extern("vb", lambda f, k: f.get("d"))
    with pytest.raises(npg.Error) as e:
        full(gpos=g[1])
    assert "Full.get('d') while an extern callable runs" in str(e.value.__cause__)
    assert np.array_equal(full.get("d"), full.get("d"))  # outside a callable: the last evaluation's


def test_add_full_after_a_failed_evaluation_is_refused():
    """full() failed after its inputs were set: the evaluator holds this sample's inputs and the
    last one's externs, which tr.add_full recorded as one sample."""
    prog = npg.compile(EXTERN)
    tri, g, v = extern_data(3)
    full = prog.full(params={"tri": tri})
    calls = []

    def oracle(f, k):
        calls.append(k)
        if len(calls) == 2:
            raise RuntimeError("the oracle failed")
        return np.sin(f.get("g")[tri[:, 1], 1]) + 2

    full.extern("v", oracle)
    tr = npg.Trainer(full)
    full(g=g[0])
    tr.add_full()
    with pytest.raises(npg.Error):
        full(g=g[1])
    with pytest.raises(npg.Error, match="its last call failed"):
        tr.add_full()
    full(g=g[2])
    tr.add_full()
    assert tr.samples == 2


def test_unbound_params_and_empty_keep_bases():
    prog = npg.compile("tests/programs/output_op.npg")
    tr = npg.Trainer(prog.full())
    with pytest.raises(npg.Error, match="training sample 0: param 'a' is not bound"):
        tr.add(w=np.ones(3), x=np.ones(3))  # finish() alone said so, after every sample
    with pytest.raises(ValueError, match="Trainer: keep_bases is ''"):
        npg.Trainer(prog.full(), keep_bases="")
