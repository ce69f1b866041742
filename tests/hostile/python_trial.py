#!/usr/bin/python3
"""python_trial.py — a hostile trial of the Python module (issue 38): threads, extern callables
that misbehave, wrong types, None, huge and negative sizes, NaN data, non-contiguous and
wrong-dtype arrays, externs given, left out and read. Each case expects an exception of a type
whose message (or its __cause__'s) names the culprit, or a result checked against NumPy. Prints
a line per case and the counts; exits 1 when any case is wrong. Run from the source root with
PYTHONPATH=BUILD/python (ctest: hostile_python, under the sanitizers too).

    PYTHONPATH=build/python /usr/bin/python3 tests/hostile/python_trial.py
"""
import copy
import gc
import pickle
import re
import sys
import tempfile
import threading
import time

import numpy as np

import npg

ROOT = sys.argv[1] if len(sys.argv) > 1 else "."
_TMP = tempfile.TemporaryDirectory(prefix="npg_python_trial_")  # removed at exit
results = []


def case(name, fn, exc=None, match=None, check=None):
    try:
        r = fn()
    except BaseException as e:  # noqa
        if exc is None:
            results.append((name, False, f"raised {type(e).__name__}: {e}"))
            return
        text = str(e) + (" | cause: " + str(e.__cause__) if e.__cause__ else "")
        ok = isinstance(e, exc) and (match is None or re.search(match, text))
        results.append((name, bool(ok), f"{type(e).__name__}: {text[:300]}"))
        return
    if exc is not None:
        results.append((name, False, f"no exception (returned {str(r)[:100]})"))
        return
    ok = True if check is None else bool(check(r))
    results.append((name, ok, "result checked" if ok else f"wrong result {str(r)[:200]}"))


EQ3 = npg.compile(f"{ROOT}/examples/rational/rational.npg")
EXT = npg.compile("dim F\ninput gpos : real[F]\nextern vis[i:F] of gpos\noutput d[i:F] = vis[i] * gpos[i]\n",
                  name="ext.npg")
OP = npg.compile(f"{ROOT}/tests/programs/output_op.npg")
rng = np.random.default_rng(11)
X = 0.5 + rng.random((40, 2))
G = 1 + rng.random((40, 5))


def y_of(x):
    return np.array([(x[0] * x[1] + x[1] ** 2) / x[0] ** 2, x[0] ** 2 / x[1] ** 2])


def eq3_model():
    tr = npg.Trainer(EQ3.full())
    for x in X:
        tr.add(x=x)
    return tr.finish()


MODEL = eq3_model()


def vis(f, k):
    return np.sin(f.get("gpos")) + 2


def ext_trainer(**kw):
    full = EXT.full()
    full.extern("vis", vis)
    return full, npg.Trainer(full, **kw)


def _try(fn):
    try:
        return fn()
    except Exception as e:  # noqa
        return e


def eq3_tr():
    tr = npg.Trainer(EQ3.full())
    for x in X[:3]:
        tr.add(x=x)
    return tr


def _add_nc():
    a, b = npg.Trainer(EQ3.full()), npg.Trainer(EQ3.full())
    for k in range(12):
        m = np.zeros((2, 3))
        m[:, 1] = X[k]
        a.add(x=m[:, 1])
        b.add(x=X[k].copy())
    return np.array_equal(a.finish().basis("x"), b.finish().basis("x"))


# ---------------------------------------------------------------- threads
def threads_add_together():
    full, tr = ext_trainer()
    def work(lo):
        for k in range(lo, lo + 10):
            tr.add(gpos=G[k])
    ts = [threading.Thread(target=work, args=(10 * i,)) for i in range(4)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    return tr.samples, tr.finish().samples
case("threads: four threads add to one trainer", threads_add_together, check=lambda r: r == (40, 40))


def threads_full_while_add():
    full, tr = ext_trainer()
    out = []
    def ev():
        for k in range(20):
            out.append((k, full(gpos=G[k])["d"]))
    t = threading.Thread(target=ev)
    t.start()
    for k in range(20):
        tr.add(gpos=G[k])
    t.join()
    return all(np.allclose(d, (np.sin(G[k]) + 2) * G[k], rtol=1e-14) for k, d in out)
case("threads: full() on one thread while another adds with its evaluator", threads_full_while_add, check=bool)


def threads_one_reduced():
    red = MODEL.reduced()
    errs = []
    def work(i):
        for k in range(30):
            x = X[(i * 7 + k) % 40]
            c = red(x=x)["y"]
            # the same thread's own evaluation: lift of coords returned
            if not np.all(np.isfinite(c)):
                errs.append(k)
    ts = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    red2 = MODEL.reduced()
    return not errs and np.allclose(red2(x=X[3])["y"], red(x=X[3])["y"], rtol=1e-14)
case("threads: four threads share one Reduced", threads_one_reduced, check=bool)


def threads_finish_while_add():
    full, tr = ext_trainer()
    for k in range(10):
        tr.add(gpos=G[k])
    res = {}
    def fin():
        res["m"] = tr.finish()
    t = threading.Thread(target=fin)
    t.start()
    for k in range(10, 20):
        tr.add(gpos=G[k])
    t.join()
    return 10 <= res["m"].samples <= 20 and tr.samples == 20
case("threads: finish on one thread while another adds", threads_finish_while_add, check=bool)


def threads_verify_and_train():
    full, tr = ext_trainer()
    for k in range(20):
        tr.add(gpos=G[k])
    m = tr.finish()
    res = {}
    def v():
        res["v"] = m.verify(test={"gpos": G[20:25]})
    t = threading.Thread(target=v)
    t.start()
    for k in range(20, 30):
        tr.add(gpos=G[k])
    t.join()
    return res["v"]["d"]["l2"] == m.verify(test={"gpos": G[20:25]})["d"]["l2"]
case("threads: verify on one thread while the trainer adds on another (one evaluator)", threads_verify_and_train,
     check=bool)


def threads_dots_many():
    full, tr = ext_trainer()
    out = []
    stop = threading.Event()
    def d():
        while not stop.is_set():
            if tr.samples:
                r = tr.dots("gpos", G[0])
                out.append(len(r) >= 1 and np.isclose(r[0], G[0] @ G[0]))
    t = threading.Thread(target=d)
    t.start()
    for k in range(30):
        tr.add(gpos=G[k])
    stop.set()
    t.join()
    return all(out)
case("threads: dots in a loop while adding", threads_dots_many, check=bool)


def helper_thread_evaluates():
    full = EXT.full()
    res = {}
    def cb(f, k):
        t = threading.Thread(target=lambda: res.setdefault("dim", f.dim("F")))
        t.start()
        t.join(5)
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    full(gpos=G[0])
    return res.get("dim") == 5
case("threads: a callable's helper thread reads full.dim", helper_thread_evaluates, check=bool)


# ---------------------------------------------------------------- callables that misbehave
def ext_full(fn):
    full = EXT.full()
    full.extern("vis", fn)
    return full


case("callable returns int64 array", lambda: ext_full(lambda f, k: np.ones(5, dtype=np.int64))(gpos=G[0]),
     npg.Error, "'vis'")
case("callable returns None", lambda: ext_full(lambda f, k: None)(gpos=G[0]), npg.Error, "'vis'")
case("callable returns NaN", lambda: ext_full(lambda f, k: np.full(5, np.nan))(gpos=G[0]), npg.Error,
     "vis.*NaN")
case("callable returns a list", lambda: ext_full(lambda f, k: [1.0] * 5)(gpos=G[0])["d"],
     check=lambda d: np.array_equal(d, G[0]))
case("callable returns 5x1 array", lambda: ext_full(lambda f, k: np.ones((5, 1)))(gpos=G[0])["d"],
     check=lambda d: np.array_equal(d, G[0]))
case("callable returns too many values", lambda: ext_full(lambda f, k: np.ones(6))(gpos=G[0]), npg.Error,
     "vis")
case("callable returns a str", lambda: ext_full(lambda f, k: "abc")(gpos=G[0]), npg.Error, "vis")


def cb_unregisters():
    full = EXT.full()
    def cb(f, k):
        f.extern("vis", None)
        return np.ones(5)
    full.extern("vis", cb)
    full(gpos=G[0])
case("callable unregisters itself", cb_unregisters, npg.Error, "vis")


def cb_rebinds():
    full = EXT.full()
    def cb(f, k):
        f.bind({})
        return np.ones(5)
    full.extern("vis", cb)
    full(gpos=G[0])
case("callable rebinds its evaluator", cb_rebinds, npg.Error, "vis")


def cb_trainer_add():
    full = EXT.full()
    tr = npg.Trainer(full)
    def cb(f, k):
        tr.add(gpos=G[1])
        return np.ones(5)
    full.extern("vis", cb)
    tr.add(gpos=G[0])
case("callable adds to its own trainer", cb_trainer_add, npg.Error, "vis")


def cb_verify():
    full, tr = ext_trainer()
    for k in range(10):
        tr.add(gpos=G[k])
    m = tr.finish()
    def cb(f, k):
        m.verify(test={"gpos": G[:2]})
        return np.ones(5)
    full.extern("vis", cb)
    full(gpos=G[0])
case("callable verifies with its evaluator", cb_verify, npg.Error, "vis")


def cb_raises_systemexit():
    full = ext_full(lambda f, k: sys.exit(3))
    full(gpos=G[0])
case("callable raises SystemExit", cb_raises_systemexit, BaseException, "vis|3")


class BadArray:
    def __array__(self, *a, **k):
        raise RuntimeError("no array for you")


case("callable returns an object whose __array__ raises", lambda: ext_full(lambda f, k: BadArray())(gpos=G[0]),
     npg.Error, "vis")


def cb_collects_full():
    holder = {}
    def cb(f, k):
        holder.clear()
        gc.collect()
        return np.ones(5)
    full = EXT.full()
    full.extern("vis", cb)
    holder["f"] = full
    tr = npg.Trainer(full)
    del full
    tr.add(gpos=G[0])
    return tr.samples
case("callable drops the last outside reference to its evaluator", cb_collects_full, check=lambda r: r == 1)


def cb_replaced_midcall():
    full = EXT.full()
    res = {}
    def cb2(f, k):
        return np.full(5, 2.0)
    def cb(f, k):
        t = threading.Thread(target=lambda: res.setdefault("e", _try(lambda: f.extern("vis", cb2))))
        t.start()
        t.join(1.0)
        return np.ones(5)
    full.extern("vis", cb)
    out = full(gpos=G[0])["d"]
    time.sleep(0.2)
    return np.array_equal(out, G[0])
case("callable whose helper thread replaces it (waits its turn, no crash)", cb_replaced_midcall, check=bool)



def cb_mutates_input_array():
    full = EXT.full()
    g = G[0].copy()
    def cb(f, k):
        g[:] = 100.0
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    out = full(gpos=g)["d"]
    return np.allclose(out, (np.sin(G[0]) + 2) * G[0], rtol=1e-14)
case("callable mutates the caller's input array mid-evaluation", cb_mutates_input_array, check=bool)


# ---------------------------------------------------------------- wrong types, None
full0 = EQ3.full()
case("compile(None)", lambda: npg.compile(None), TypeError)
case("compile(42)", lambda: npg.compile(42), TypeError)
case("full(params={1: arr})", lambda: OP.full(params={1: np.ones((3, 3))}), TypeError, "param")
case("full(params={'a': None})", lambda: OP.full(params={"a": None}), TypeError, "'a'")
case("full(params=[1])", lambda: OP.full(params=[1]), TypeError, "params")
case("Trainer(full, cap=None)", lambda: npg.Trainer(full0, cap=None), TypeError, "cap")
case("Trainer(full, energy='0.9')", lambda: npg.Trainer(full0, energy="0.9"), TypeError, "energy")
case("Trainer(full, energy=nan)", lambda: npg.Trainer(full0, energy=float("nan")), ValueError, "energy")
case("Trainer(full, energy=None)", lambda: npg.Trainer(full0, energy=None), TypeError, "energy")
case("Trainer(full, interp_oversample='x')", lambda: npg.Trainer(full0, interp_oversample="x"), TypeError,
     "interp_oversample")
case("Trainer(full, valid_holdout='0.1')", lambda: npg.Trainer(full0, valid_holdout="0.1"), TypeError,
     "valid_holdout")
case("Trainer(full, valid_holdout=nan)", lambda: npg.Trainer(full0, valid_holdout=float("nan")), ValueError,
     "valid_holdout")
case("Trainer(full, keep_bases=3)", lambda: npg.Trainer(full0, keep_bases=3), TypeError, "keep_bases")
case("Trainer(None)", lambda: npg.Trainer(None), TypeError)
case("Trainer(full, basis=None) fine", lambda: npg.Trainer(full0, basis=None), check=lambda t: t.samples == 0)
case("tr.add(x=None)", lambda: npg.Trainer(full0).add(x=None), TypeError, "'x'")
case("tr.add(x='ab')", lambda: npg.Trainer(full0).add(x="ab"), TypeError, "'x'")
case("tr.add(1.0)", lambda: npg.Trainer(full0).add(1.0), TypeError)
case("tr.add() nothing", lambda: npg.Trainer(full0).add(), npg.Error, "input 'x'")
case("tr.weight(None)", lambda: npg.Trainer(full0).weight(None), TypeError, "weight")
case("tr.weight('2')", lambda: npg.Trainer(full0).weight("2"), TypeError, "weight")
case("tr.weight(nan)", lambda: npg.Trainer(full0).weight(float("nan")), npg.Error, "weight")
case("tr.dots(None, v)", lambda: npg.Trainer(full0).dots(None, X[0]), TypeError)
case("tr.dots before samples", lambda: npg.Trainer(full0).dots("x", X[0]), npg.Error, "no training samples")
case("tr.finish() no samples", lambda: npg.Trainer(full0).finish(), npg.Error, "no training samples")
case("tr.finish(model_dir=3)", lambda: npg.Trainer(full0).finish(3), TypeError)
red0 = MODEL.reduced()
case("red(x=None)", lambda: red0(x=None), TypeError, "'x'")
case("red(1)", lambda: red0(1), TypeError)
case("red(y=...) an output", lambda: red0(y=X[0]), npg.Error, "'y'")
case("red.lift(None)", lambda: red0.lift(None), TypeError)
case("red.lift('nosuch')", lambda: red0.lift("nosuch"), npg.Error, "nosuch")
case("red.coords(3)", lambda: red0.coords(3), TypeError)
case("red.set_coords('x', None)", lambda: red0.set_coords("x", None), TypeError, "x")
case("red.op(None)", lambda: red0.op(None), TypeError)
case("red.op('y') not an op", lambda: red0.op("y"), npg.Error, "'y'")
case("red.given_externs(None)", lambda: red0.given_externs(None), TypeError, "given_externs")
case("verify(test=None)", lambda: MODEL.verify(test=None), TypeError)
case("verify(test={})", lambda: MODEL.verify(test={}), npg.Error, "no test samples")
case("verify(test={1: x})", lambda: MODEL.verify(test={1: X[:2]}), TypeError, "test")
case("verify(test={'x': None})", lambda: MODEL.verify(test={"x": None}), TypeError, "'x'")
case("verify(tol='1')", lambda: MODEL.verify(test={"x": X[:2]}, tol="1"), TypeError, "tol")
case("verify(full=3)", lambda: MODEL.verify(test={"x": X[:2]}, full=3), TypeError, "full")
case("load(prog, None)", lambda: npg.load(EQ3, None), TypeError)
case("load(prog, missing dir)", lambda: npg.load(EQ3, "/nonexistent/MODEL"), npg.Error, "/nonexistent/MODEL")
case("load(None, dir)", lambda: npg.load(None, "/tmp"), TypeError)
case("model.basis(None)", lambda: MODEL.basis(None), TypeError)
case("model.basis('nosuch')", lambda: MODEL.basis("nosuch"), npg.Error, "nosuch")
case("model.save(None)", lambda: MODEL.save(None), TypeError)
case("model.save into a file path", lambda: MODEL.save("/dev/null/M"), npg.Error, "/dev/null")
case("full.get(None)", lambda: full0.get(None), TypeError)
case("full.get('nosuch')", lambda: full0.get("nosuch"), npg.Error, "nosuch")
case("full.dim(None)", lambda: full0.dim(None), TypeError)
case("full.op('nosuch')", lambda: full0.op("nosuch"), npg.Error, "nosuch")
case("full.extern(None, f)", lambda: full0.extern(None, vis), TypeError)
case("Trainer.__new__ then add", lambda: npg.Trainer.__new__(npg.Trainer).add(x=X[0]), RuntimeError,
     "not initialized")
case("Trainer.__new__ then dots", lambda: npg.Trainer.__new__(npg.Trainer).dots("x", X[0]), RuntimeError,
     "not initialized")
case("Trainer.__new__ then samples", lambda: npg.Trainer.__new__(npg.Trainer).samples, check=lambda s: s == 0)
case("Trainer.__init__ twice", lambda: npg.Trainer(full0).__init__(full0), RuntimeError, "already")
case("npg.Full() direct", lambda: npg.Full(), TypeError)
case("npg.Reduced() direct", lambda: npg.Reduced(), TypeError)
case("npg.Model() direct", lambda: npg.Model(), TypeError)
case("prog.full(backend=None)", lambda: EQ3.full(backend=None), TypeError)
case("prog.full(backend='gcc')", lambda: EQ3.full(backend="gcc"), ValueError, "gcc")

# ---------------------------------------------------------------- huge / negative sizes
case("Trainer(cap=-1)", lambda: npg.Trainer(full0, cap=-1), ValueError, "cap")
case("Trainer(cap=10**30)", lambda: npg.Trainer(full0, cap=10 ** 30), ValueError, "cap")
case("Trainer(mem=-5)", lambda: npg.Trainer(full0, mem=-5), ValueError, "mem")
case("Trainer(interp_oversample=-1)", lambda: npg.Trainer(full0, interp_oversample=-1), ValueError,
     "interp_oversample")
case("Trainer(interp_oversample=1e300)", lambda: npg.Trainer(full0, interp_oversample=1e300), ValueError,
     "interp_oversample")


def tiny_mem():
    tr = npg.Trainer(EXT.full(), mem=1)
    tr.add(gpos=G[0], vis=G[1])
    tr.finish()
case("Trainer(mem=1) then finish", tiny_mem, npg.Error, r"\bmem\b")
case("tr.add(x of 10**6 entries)", lambda: npg.Trainer(full0).add(x=np.zeros(10 ** 6) + 1), npg.Error, "'x'")
case("tr.add(x of 0 entries)", lambda: npg.Trainer(full0).add(x=np.zeros(0)), npg.Error, "'x'")
case("red(x of 0 entries)", lambda: red0(x=np.zeros(0)), npg.Error, "'x'")
case("red.lift(out too small)", lambda: red0.lift("x", out=np.zeros(1)), npg.Error, "'x'")
case("red.set_coords wrong length", lambda: red0.set_coords("x", np.zeros(99)), npg.Error, "'x'")
case("tr.dots wrong length", lambda: eq3_tr().dots("x", np.zeros(5)), npg.Error, "'x'")



case("verify(test) 0 samples", lambda: MODEL.verify(test={"x": np.zeros((0, 2))}), npg.Error, "no test samples")
case("verify(test) wrong per-sample shape", lambda: MODEL.verify(test={"x": np.ones((3, 5))}), npg.Error, "'x'")
case("full(gpos of 0 entries): an empty output", lambda: ext_full(vis)(gpos=np.zeros(0))["d"], check=lambda d: d.shape == (0,))

# ---------------------------------------------------------------- NaN data
case("tr.add(x with NaN)", lambda: npg.Trainer(full0).add(x=np.array([np.nan, 1])), npg.Error, "NaN")
case("full(x with inf)", lambda: EQ3.full()(x=np.array([np.inf, 1])), npg.Error, "infinity")
case("red(x with NaN)", lambda: MODEL.reduced()(x=np.array([np.nan, 1])), npg.Error, "NaN")
case("red.set_coords with NaN", lambda: MODEL.reduced().set_coords("x", np.full(MODEL.basis("x").shape[1], np.nan)),
     npg.Error, "NaN")
case("verify(test with NaN)", lambda: MODEL.verify(test={"x": np.array([[1, 1], [np.nan, 1.0]])}), npg.Error,
     "NaN")
case("Trainer(valid with NaN) refused when made", lambda: npg.Trainer(npg.compile(f"{ROOT}/tests/programs/nbody_gravity.npg").full(
    params={"mass": np.full(8, 0.125), "eps": np.array(0.05)}), valid={"x": np.full((2, 8, 3), np.nan)}),
     npg.Error, "NaN")
case("tr.dots with NaN", lambda: eq3_tr().dots("x", np.array([np.nan, 1])), npg.Error, "NaN")
case("params with NaN", lambda: OP.full(params={"a": np.full((3, 3), np.nan)}), npg.Error, "NaN")
case("tr.weight(inf)", lambda: npg.Trainer(full0).weight(np.inf), npg.Error, "weight")
case("red(x = huge values)", lambda: MODEL.reduced()(x=np.array([1e308, 1e308])), npg.Error, None)

# ---------------------------------------------------------------- layouts and dtypes
xnc = np.zeros((2, 2))
xnc[:, 0] = X[5]
case("tr.add(x non-contiguous)", lambda: _add_nc(), check=bool)



case("red(x non-contiguous) equals contiguous", lambda: np.array_equal(MODEL.reduced()(x=xnc[:, 0])["y"],
                                                                        MODEL.reduced()(x=X[5].copy())["y"]), check=bool)
case("full(x float32)", lambda: EQ3.full()(x=X[0].astype(np.float32)), TypeError, "'x'")
case("red(x int64)", lambda: MODEL.reduced()(x=np.array([1, 2])), TypeError, "'x'")
case("tr.add(x big-endian)", lambda: np.allclose(EQ3.full()(x=X[0].astype(">f8"))["y"], y_of(X[0]), rtol=1e-14),
     check=bool)
case("red(x big-endian)", lambda: np.array_equal(MODEL.reduced()(x=X[0].astype(">f8"))["y"],
                                                 MODEL.reduced()(x=X[0].copy())["y"]), check=bool)
case("full(x Fortran 2-d for a 1-d input)", lambda: EQ3.full()(x=np.asfortranarray(X[:1].T)), npg.Error, "'x'")
case("verify(test x non-contiguous)", lambda: MODEL.verify(test={"x": X[::2][:4]})["y"]["l2"]
     == MODEL.verify(test={"x": X[::2][:4].copy()})["y"]["l2"], check=bool)
case("verify(test x float32)", lambda: MODEL.verify(test={"x": X[:3].astype(np.float32)}), TypeError, "'x'")
case("int param as floats with fractions", lambda: npg.compile(f"{ROOT}/tests/programs/extern_stage.npg").full(
    params={"tri": np.full((2, 3), 0.5)}), npg.Error, "tri")
case("params a as float32", lambda: OP.full(params={"a": np.ones((3, 3), dtype=np.float32)}), TypeError, "'a'")
case("tr.add(x=np.float64 scalar)", lambda: npg.Trainer(full0).add(x=np.float64(1.0)), npg.Error, "'x'")
case("red.lift(out= read-only)", lambda: MODEL.reduced().lift("x", out=np.zeros(2)[::1].view().setflags(write=False)
                                                             or np.zeros(2)), npg.Error, None)


def lift_out_readonly():
    red = MODEL.reduced()
    red(x=X[0])
    out = np.zeros(2)
    out.setflags(write=False)
    red.lift("y", out=out)
case("red.lift(out read-only)", lift_out_readonly, TypeError, "out")


def lift_out_float32():
    red = MODEL.reduced()
    red(x=X[0])
    red.lift("y", out=np.zeros(2, dtype=np.float32))
case("red.lift(out float32)", lift_out_float32, TypeError, "out")

# ---------------------------------------------------------------- externs through Python
def ext_left_out_verify_with_callable():
    full, tr = ext_trainer()
    for k in range(15):
        tr.add(gpos=G[k])
    return tr.finish().verify(test={"gpos": G[20:23]})["d"]["l2"]
case("extern with a callable may be left out of verify's test", ext_left_out_verify_with_callable,
     check=lambda l2: 0 < l2 < 0.1)


def ext_given_twice():
    full, tr = ext_trainer()
    tr.add(gpos=G[0], vis=np.sin(G[0]) + 2)
    tr.add(gpos=G[1])
    m = tr.finish()
    return m.samples
case("extern given for one sample, callable for the next", ext_given_twice, check=lambda s: s == 2)


def ext_values_wrong_shape():
    tr = npg.Trainer(EXT.full())
    tr.add(gpos=G[0], vis=np.ones(4))
case("extern values of the wrong size", ext_values_wrong_shape, npg.Error, "vis")


def ext_red_given_before():
    full, tr = ext_trainer()
    for k in range(15):
        tr.add(gpos=G[k])
    red = tr.finish().reduced()
    red(gpos=G[0], vis=G[0])
case("red(vis=...) without given_externs", ext_red_given_before, npg.Error, "given_externs")


def ext_red_given_after():
    full, tr = ext_trainer(keep_bases="vis")
    for k in range(15):
        tr.add(gpos=G[k])
    red = tr.finish().reduced()
    red.given_externs(True)
    a = red(gpos=G[3], vis=np.sin(G[3]) + 2)["d"]
    red.given_externs(False)
    b = red(gpos=G[3])["d"]
    return np.allclose(a, b, rtol=1e-6, atol=1e-9)
case("red(vis=...) after given_externs equals the learned map on a training sample", ext_red_given_after,
     check=bool)


def ext_verify_param_name():
    m = MODEL
    return m.verify(test={"x": X[:2], "nosuch": X[:2]})
case("verify(test with an unknown name)", ext_verify_param_name, npg.Error, "nosuch")


def ext_nonstr_kw():
    return npg.Trainer(full0).add(**{"x": X[0]}) is None
case("add with a kw dict", ext_nonstr_kw, check=bool)


# ---------------------------------------------------------------- second batch
EQ3 = npg.compile(f"{ROOT}/examples/rational/rational.npg")
EXT = npg.compile("dim F\ninput gpos : real[F]\nextern vis[i:F] of gpos\noutput d[i:F] = vis[i] * gpos[i]\n",
                  name="ext.npg")
TWO = npg.compile("dim F\ninput gpos : real[F]\nextern va[i:F] of gpos\nextern vb[i:F] of gpos\n"
                  "output d[i:F] = va[i] * vb[i] * gpos[i]\n", name="two.npg")
GRAV = npg.compile(f"{ROOT}/tests/programs/nbody_gravity.npg")
GPAR = {"mass": np.full(8, 0.125), "eps": np.array(0.05)}
OP = npg.compile(f"{ROOT}/tests/programs/output_op.npg")
rng = np.random.default_rng(12)
X = 0.5 + rng.random((40, 2))
G = 1 + rng.random((40, 5))


def vis(f, k):
    return np.sin(f.get("gpos")) + 2


def eq3_model(n=20):
    tr = npg.Trainer(EQ3.full())
    for x in X[:n]:
        tr.add(x=x)
    return tr, tr.finish()


TR, MODEL = eq3_model()

# ---------------------------------------------------------------- trainer lifecycle
case("finish twice gives the same basis", lambda: np.array_equal(TR.finish().basis("x"), MODEL.basis("x")), check=bool)


def add_after_finish():
    tr, m = eq3_model(12)
    tr.add(x=X[30])
    return tr.finish().samples
case("add after finish, finish again", add_after_finish, check=lambda s: s == 13)
case("keep_bases=''", lambda: npg.Trainer(EQ3.full(), keep_bases=""), ValueError, "Trainer: keep_bases")
case("cap=True", lambda: npg.Trainer(EQ3.full(), cap=True), TypeError, "cap")
case("basis x:cap=0", lambda: npg.Trainer(EQ3.full(), basis=["x:cap=0"]), ValueError, "basis")
case("basis x:energy=2", lambda: npg.Trainer(EQ3.full(), basis=["x:energy=2"]), ValueError, "basis")
case("basis with a bad key", lambda: npg.Trainer(EQ3.full(), basis=["x:size=3"]), ValueError, "basis")
case("interp and galerkin the same stage", lambda: npg.Trainer(GRAV.full(params=GPAR), interp="w", galerkin="w"),
     npg.Error, "Trainer: stage w is forced both")
case("interp a name that is an input", lambda: npg.Trainer(GRAV.full(params=GPAR), interp="x"), npg.Error,
     "Trainer: interp x")
case("galerkin=[None]", lambda: npg.Trainer(GRAV.full(params=GPAR), galerkin=[None]), TypeError, "galerkin")
case("valid={} (no samples)", lambda: npg.Trainer(GRAV.full(params=GPAR), valid={}), npg.Error, "valid")
case("valid with a param name", lambda: npg.Trainer(GRAV.full(params=GPAR), valid={"mass": np.ones((2, 8))}),
     npg.Error, "param")



def _valid_unknown():
    tr = npg.Trainer(GRAV.full(params=GPAR), valid={"x": np.ones((2, 8, 3)) + np.arange(24).reshape(8, 3) / 10,
                                                     "nosuch": np.ones((2, 3))})
    for k in range(3):
        tr.add(x=np.arange(24.0).reshape(8, 3) / (k + 3) + rng.random((8, 3)))
    tr.finish()


case("valid with an unknown name", lambda: _valid_unknown(), npg.Error, "nosuch")


def unbound_params():
    tr = npg.Trainer(OP.full())
    tr.add(w=np.ones(3), x=np.ones(3))
case("params never bound: add names the param", unbound_params, npg.Error, "'a'")


def unknown_then_good():
    tr = npg.Trainer(EQ3.full())
    try:
        tr.add(x=X[0], x2=X[1])
    except npg.Error:
        pass
    tr.add(x=X[0])
    return tr.samples
case("an unknown name refused, the trainer goes on", unknown_then_good, check=lambda s: s == 1)


def ext_nan_then_good():
    full = EXT.full()
    tr = npg.Trainer(full)
    try:
        tr.add(gpos=G[0], vis=np.full(5, np.nan))
    except npg.Error as e:
        assert "NaN" in str(e)
    tr.add(gpos=G[0], vis=np.sin(G[0]) + 2)
    return tr.samples, tr.dots("vis", np.ones(5))
case("an extern with NaN refused, the trainer goes on", ext_nan_then_good,
     check=lambda r: r[0] == 1 and np.isclose(r[1][0], (np.sin(G[0]) + 2).sum()))


def given_wins_over_callable():
    full = EXT.full()
    full.extern("vis", vis)
    tr = npg.Trainer(full)
    tr.add(gpos=G[0], vis=np.full(5, 7.0))
    tr.add(gpos=G[1])
    return tr.dots("vis", np.ones(5))
case("a given extern wins over its callable, the next sample calls it", given_wins_over_callable,
     check=lambda d: np.isclose(d[0], 35) and np.isclose(d[1], (np.sin(G[1]) + 2).sum()))


def add_full_after_failed_call():
    full = EXT.full()
    calls = []
    def cb(f, k):
        calls.append(k)
        if len(calls) == 2:
            raise RuntimeError("the oracle failed")
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    tr = npg.Trainer(full)
    full(gpos=G[0])
    try:
        full(gpos=G[1])
    except npg.Error:
        pass
    tr.add_full()  # the last evaluation failed: there is no sample to add
case("add_full after a failed evaluation", add_full_after_failed_call, npg.Error, "evaluat")


def two_trainers_one_full():
    full = EXT.full()
    full.extern("vis", vis)
    a, b = npg.Trainer(full), npg.Trainer(full)
    for k in range(12):
        a.add(gpos=G[k])
        b.add(gpos=G[k])
    return np.array_equal(a.finish().basis("gpos"), b.finish().basis("gpos"))
case("two trainers on one evaluator, interleaved", two_trainers_one_full, check=bool)


# ---------------------------------------------------------------- callables
def get_stage_in_callable():
    full = EXT.full()
    full.extern("vis", vis)
    full(gpos=G[0])
    seen = {}
    def cb(f, k):
        seen["d"] = f.get("d")  # a stage: not evaluated yet for this sample
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    full(gpos=G[1])
    return seen
case("callable reads a stage (not yet evaluated for this sample)", get_stage_in_callable, npg.Error, "'d'")


def get_other_extern_in_callable():
    full = TWO.full()
    full.extern("va", lambda f, k: np.sin(f.get("gpos")) + 2)
    full.extern("vb", lambda f, k: f.get("va") + 1)
    full(gpos=G[0])
    return full(gpos=G[1])
case("callable reads another extern", get_other_extern_in_callable, npg.Error, "'va'")


def callable_returns_matrix():
    full = EXT.full()
    full.extern("vis", lambda f, k: np.asmatrix(np.sin(f.get("gpos")) + 2))
    return full(gpos=G[0])["d"]
case("callable returns np.matrix", callable_returns_matrix, check=lambda d: np.allclose(d, (np.sin(G[0]) + 2) * G[0]))


def callable_returns_bytes():
    full = EXT.full()
    full.extern("vis", lambda f, k: b"\x00" * 40)
    return full(gpos=G[0])
case("callable returns bytes", callable_returns_bytes, npg.Error, "vis")


def callable_keeps_f_later():
    full = EXT.full()
    kept = []
    def cb(f, k):
        kept.append(f)
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    full(gpos=G[0])
    full(gpos=G[1])
    return kept[0].get("gpos")
case("a kept evaluator read after its callable returned", callable_keeps_f_later, check=lambda g: np.array_equal(g, G[1]))


def callable_threads_many_gets():
    full = EXT.full()
    def cb(f, k):
        out = []
        ts = [threading.Thread(target=lambda: out.append(f.get("gpos"))) for _ in range(8)]
        [t.start() for t in ts]
        [t.join(5) for t in ts]
        assert len(out) == 8
        return np.sin(out[0]) + 2
    full.extern("vis", cb)
    tr = npg.Trainer(full)
    for k in range(12):
        tr.add(gpos=G[k])
    return tr.finish().verify(test={"gpos": G[20:22]})["d"]["l2"]
case("callable with 8 helper threads reading", callable_threads_many_gets, check=lambda l2: l2 < 0.1)


def helper_evaluates_other_full():
    full, other = EXT.full(), EXT.full()
    other.extern("vis", vis)
    res = {}
    def cb(f, k):
        t = threading.Thread(target=lambda: res.setdefault("d", other(gpos=G[5])["d"]))
        t.start()
        t.join(10)
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    full(gpos=G[0])
    return res["d"]
case("callable's helper evaluates another evaluator", helper_evaluates_other_full,
     check=lambda d: np.allclose(d, (np.sin(G[5]) + 2) * G[5]))

# ---------------------------------------------------------------- models, verify, reduced
def verify_other_params():
    full = GRAV.full(params=GPAR)
    tr = npg.Trainer(full, valid_holdout=0)
    x = np.arange(24.0).reshape(8, 3) / 5
    for k in range(6):
        tr.add(x=x + rng.random((8, 3)) * 0.1)
    m = tr.finish()
    other = GRAV.full(params={"mass": np.full(8, 0.5), "eps": np.array(0.05)})
    return m.verify(test={"x": (x + rng.random((2, 8, 3)) * 0.1)}, full=other)
case("verify with an evaluator of other params", verify_other_params, npg.Error, "mass")


def load_other_params():
    full = GRAV.full(params=GPAR)
    tr = npg.Trainer(full, valid_holdout=0)
    x = np.arange(24.0).reshape(8, 3) / 5
    for k in range(6):
        tr.add(x=x + rng.random((8, 3)) * 0.1)
    d = tempfile.mkdtemp(dir=_TMP.name)
    tr.finish(d + "/M")
    other = GRAV.full(params={"mass": np.full(8, 0.5), "eps": np.array(0.05)})
    return npg.load(GRAV, d + "/M", full=other).verify(test={"x": x[None] + 0.01})
case("load with an evaluator of other params, then verify", load_other_params, npg.Error, "mass")
case("pickle a model", lambda: pickle.dumps(MODEL), TypeError)
case("copy a reduced", lambda: copy.copy(MODEL.reduced()), TypeError)
case("model.save over an existing file", lambda: MODEL.save(__file__), npg.Error, None)


def lift_2d_out():
    red = MODEL.reduced()
    red(x=X[0])
    out = np.zeros((1, 2))
    red.lift("y", out=out)
    return out
case("lift into a 1x2 out", lift_2d_out, check=lambda o: o.shape == (1, 2) and np.all(np.isfinite(o)))


def op_after_set_coords_only():
    rng2 = np.random.default_rng(5)
    full = OP.full(params={"a": rng2.random((3, 3))})
    tr = npg.Trainer(full)
    for w, x in 0.5 + rng2.random((10, 2, 3)):
        tr.add(w=w, x=x)
    m = tr.finish()
    red = m.reduced()
    red(w=np.full(3, 0.7), x=np.full(3, 0.6))
    a = red.op("K")
    red2 = m.reduced()
    red2.set_coords("w", red.coords("w"))
    return np.allclose(red2.op("K"), a, rtol=1e-14)
case("op before evaluation, its input set by coordinates", op_after_set_coords_only, check=bool)


def coords_refused_input():
    red = MODEL.reduced()
    return red.coords("x")
case("coords before anything", coords_refused_input, npg.Error, "'x'")


def reduced_threads_lift():
    reds = [MODEL.reduced() for _ in range(4)]
    out = [None] * 4
    def work(i):
        for k in range(50):
            reds[i](x=X[(k + i) % 40])
            out[i] = reds[i].lift("y")
    ts = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    ref = MODEL.reduced()
    good = True
    for i in range(4):
        ref(x=X[(49 + i) % 40])
        good &= np.array_equal(ref.lift("y"), out[i])
    return good
case("four reduced evaluators lifting on four threads", reduced_threads_lift, check=bool)


def dealloc_in_thread():
    full = EXT.full()
    full.extern("vis", vis)
    tr = npg.Trainer(full)
    for k in range(12):
        tr.add(gpos=G[k])
    m = tr.finish()
    del full, tr
    box = [m]
    def drop():
        box.clear()
        gc.collect()
    t = threading.Thread(target=drop)
    t.start()
    t.join()
    return True
case("the last references dropped on another thread", dealloc_in_thread, check=bool)


def verify_progress_numpy_bool():
    return MODEL.verify(test={"x": X[30:32]}, progress=np.bool_(False))["y"]["l2"]
case("verify(progress=np.bool_(False))", verify_progress_numpy_bool, check=lambda l: l < 1)
case("reduced(exact_roots=2)", lambda: MODEL.reduced(exact_roots=2), TypeError, "exact_roots")
case("Trainer(center=np.int64(1))", lambda: npg.Trainer(EQ3.full(), center=np.int64(1)), TypeError, "center")


def dots_noncontiguous():
    tr, _ = eq3_model(5)
    v = np.zeros((2, 2))
    v[:, 1] = [1.0, 2.0]
    return tr.dots("x", v[:, 1])
case("dots with a non-contiguous value", dots_noncontiguous,
     check=lambda d: np.allclose(d, X[:5] @ np.array([1.0, 2.0]), rtol=1e-14))
case("dots with float32", lambda: eq3_model(3)[0].dots("x", np.ones(2, dtype=np.float32)), TypeError, "'x'")
case("dots of a stage", lambda: eq3_model(3)[0].dots("y", np.ones(2)), npg.Error, "'y'")


# ---------------------------------------------------------------- third batch
EXT = npg.compile("dim F\ninput gpos : real[F]\nextern vis[i:F] of gpos\noutput d[i:F] = vis[i] * gpos[i]\n",
                  name="ext.npg")
EQ3 = npg.compile(f"{ROOT}/examples/rational/rational.npg")
rng = np.random.default_rng(13)
G = 1 + rng.random((40, 5))
X = 0.5 + rng.random((40, 2))


def want(g):
    return (np.sin(g) + 2) * g


def _given(v):
    tr = npg.Trainer(EXT.full())
    tr.add(gpos=G[0], vis=v)
    return tr.dots("vis", np.ones(5))


def _ro(a):
    a.setflags(write=False)
    return a


def run(fn):
    full = EXT.full()
    full.extern("vis", fn)
    return full(gpos=G[0])["d"]


case("extern given as a list of lists (5x1): its shape is checked, as an input's",
     lambda: _given([[v] for v in np.sin(G[0]) + 2]), npg.Error, "'vis' has 1 axis, but the array has 2")
case("extern given as a list", lambda: _given(list(np.sin(G[0]) + 2)), check=lambda d: np.isclose(d[0], (np.sin(G[0]) + 2).sum()))



case("callable returns a read-only array", lambda: run(lambda f, k: _ro(np.sin(f.get("gpos")) + 2)),
     check=lambda d: np.allclose(d, want(G[0]), rtol=1e-14))



case("callable returns a strided view", lambda: run(lambda f, k: np.repeat(np.sin(f.get("gpos")) + 2, 2)[::2]),
     check=lambda d: np.allclose(d, want(G[0]), rtol=1e-14))
case("callable returns big-endian", lambda: run(lambda f, k: (np.sin(f.get("gpos")) + 2).astype(">f8")),
     check=lambda d: np.allclose(d, want(G[0]), rtol=1e-14))
case("callable returns float32", lambda: run(lambda f, k: (np.sin(f.get("gpos")) + 2).astype(np.float32)),
     npg.Error, "vis.*float32|float32")
case("callable returns complex", lambda: run(lambda f, k: np.sin(f.get("gpos")) + 2j), npg.Error, "vis|complex")
case("callable returns an object array", lambda: run(lambda f, k: np.array([object()] * 5)), npg.Error, "vis")
case("callable raises KeyboardInterrupt", lambda: run(lambda f, k: (_ for _ in ()).throw(KeyboardInterrupt())),
     BaseException, "vis")


def sample_numbers_two_threads():
    full = EXT.full()
    seen = []
    lock = threading.Lock()
    def cb(f, k):
        with lock:
            seen.append(k)
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    outs = {}
    def work(i):
        for j in range(10):
            g = G[i * 10 + j]
            outs[(i, j)] = (g, full(gpos=g)["d"])
    ts = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    return sorted(seen) == list(range(20)) and all(np.allclose(d, want(g), rtol=1e-14) for g, d in outs.values())
case("two threads evaluate one evaluator with a callable", sample_numbers_two_threads, check=bool)


def rebind_other_size():
    full = EXT.full()
    full.extern("vis", lambda f, k: np.sin(f.get("gpos")) + 2)
    tr = npg.Trainer(full)
    tr.add(gpos=G[0])
    tr.add(gpos=np.ones(7))
case("a sample of another size", rebind_other_size, npg.Error, "gpos|7|5")


def load_other_program():
    tr = npg.Trainer(EQ3.full())
    for x in X[:12]:
        tr.add(x=x)
    d = tempfile.mkdtemp(dir=_TMP.name)
    tr.finish(d + "/M")
    return npg.load(EXT, d + "/M")
case("load a model of another program", load_other_program, npg.Error, "program|hash|manifest")


def verify_loaded_without_full():
    tr = npg.Trainer(EQ3.full())
    for x in X[:12]:
        tr.add(x=x)
    d = tempfile.mkdtemp(dir=_TMP.name)
    tr.finish(d + "/M")
    return npg.load(EQ3, d + "/M").verify(test={"x": X[20:22]})
case("verify a loaded model without full=", verify_loaded_without_full, npg.Error, "full=")


def coefficients_of_input():
    tr = npg.Trainer(EQ3.full())
    for x in X[:12]:
        tr.add(x=x)
    return tr.finish().coefficients("x")
case("coefficients of a class that keeps its basis", coefficients_of_input, npg.Error, "model.basis")


def dots_of_callable_extern():
    full = EXT.full()
    full.extern("vis", lambda f, k: np.sin(f.get("gpos")) + 2)
    tr = npg.Trainer(full)
    for k in range(4):
        tr.add(gpos=G[k])
    v = np.arange(5.0)
    return np.allclose(tr.dots("vis", v), [(np.sin(G[k]) + 2) @ v for k in range(4)], rtol=1e-14)
case("dots of an extern computed by its callable", dots_of_callable_extern, check=bool)


def independent_reader_during_callback():
    full = EXT.full()
    ev = threading.Event()
    done = threading.Event()
    def cb(f, k):
        if k == 1:
            ev.set()
            done.wait(5)
        return np.sin(f.get("gpos")) + 2
    full.extern("vis", cb)
    full(gpos=G[0])
    res = {}
    def reader():
        ev.wait(5)
        try:
            res["g"] = full.get("gpos")
        finally:
            done.set()
    t = threading.Thread(target=reader)
    t.start()
    full(gpos=G[1])
    t.join()
    return np.array_equal(res["g"], G[1])
case("an independent thread reads an input while a callable runs", independent_reader_during_callback, check=bool)


def valid_with_callable_extern_missing():
    full = EXT.full()
    full.extern("vis", lambda f, k: np.sin(f.get("gpos")) + 2)
    tr = npg.Trainer(full, valid={"gpos": G[30:33]})
    for k in range(12):
        tr.add(gpos=G[k])
    return tr.finish().samples
case("valid= without the extern that has a callable", valid_with_callable_extern_missing, check=lambda s: s == 12)


def huge_cap_small_data():
    tr = npg.Trainer(EQ3.full(), cap=1000000)
    for x in X[:5]:
        tr.add(x=x)
    return tr.finish().basis_sizes
case("cap 10^6 on 5 samples", huge_cap_small_data, check=lambda b: all(v <= 5 for v in b.values()))


ok = sum(r[1] for r in results)
for name, good, why in results:
    print(("ok   " if good else "FAIL ") + name + ": " + why)
print(f"{len(results)} cases, {ok} correct, {len(results) - ok} wrong")
sys.exit(0 if ok == len(results) else 1)
