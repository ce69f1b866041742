#!/usr/bin/python3
"""python_trial2.py — the second hostile trial of the Python module (issue 38), fresh cases not in
python_trial.py: names holding NUL characters, extern callables that change their answer's size or
dtype between samples, nest evaluators, start threads or switch callables mid-training; options of
every wrong type; arrays of odd kinds (subclasses, memoryviews, 0-d, object, complex, bool); the
sample numbers callables see; reduced evaluation and lifting against the full one. Each case expects
an exception of a type whose message (or its __cause__'s) names the culprit, or a result checked
against NumPy. Prints a line per case and the counts; exits 1 when any case is wrong. Run from the
source root with PYTHONPATH=BUILD/python (ctest: hostile_python2, under the sanitizers too).

    PYTHONPATH=build/python /usr/bin/python3 tests/hostile/python_trial2.py
"""
import array
import re
import sys
import tempfile
import threading

import numpy as np

import npg

ROOT = sys.argv[1] if len(sys.argv) > 1 else "."
_TMP = tempfile.TemporaryDirectory(prefix="npg_python_trial2_")  # removed at exit
results = []


def case(name, fn, exc=None, match=None, check=None):
    try:
        r = fn()
    except BaseException as e:  # noqa
        if exc is None:
            results.append((name, False, f"raised {type(e).__name__}: {e}"))
            return
        text, c = str(e), e.__cause__
        while c is not None:  # the whole chain, as a traceback shows it
            text, c = text + " | cause: " + str(c), c.__cause__
        ok = isinstance(e, exc) and (match is None or re.search(match, text))
        results.append((name, bool(ok), f"{type(e).__name__}: {text[:300]}"))
        return
    if exc is not None:
        results.append((name, False, f"no exception (returned {str(r)[:100]})"))
        return
    ok = True if check is None else bool(check(r))
    results.append((name, ok, "result checked" if ok else f"wrong result {str(r)[:200]}"))


EQ3 = npg.compile(f"{ROOT}/examples/rational/rational.npg")
EXT_SRC = "dim F\ninput gpos : real[F]\nextern vis[i:F] of gpos\noutput d[i:F] = vis[i] * gpos[i]\n"
EXT = npg.compile(EXT_SRC, name="ext.npg")
OP = npg.compile(f"{ROOT}/tests/programs/output_op.npg")
rng = np.random.default_rng(23)
X = 0.5 + rng.random((40, 2))
G = 1 + rng.random((40, 5))


def y_of(x):
    return np.array([(x[0] * x[1] + x[1] ** 2) / x[0] ** 2, x[0] ** 2 / x[1] ** 2])


def vis(f, k):
    return np.sin(f.get("gpos")) + 2


def d_of(g):
    return (np.sin(g) + 2) * g


def eq3_model(n=20):
    tr = npg.Trainer(EQ3.full())
    for x in X[:n]:
        tr.add(x=x)
    return tr.finish()


MODEL = eq3_model()


def ext_full(fn=vis):
    full = EXT.full()
    full.extern("vis", fn)
    return full


def ext_model(n=12):
    full = ext_full()
    tr = npg.Trainer(full)
    for k in range(n):
        tr.add(gpos=G[k])
    return full, tr.finish()


EXT_FULL, EXT_MODEL = ext_model()

# ---------------------------------------------------------------- helpers of the cases
def _get_nul():
    f = EQ3.full()
    f(x=X[0])
    return f.get("x\0junk")


def _full_then(fn):
    f = EQ3.full()
    f(x=X[0])
    return fn(f)


def _tr3():
    tr = npg.Trainer(EQ3.full())
    for x in X[:3]:
        tr.add(x=x)
    return tr


def _red_then(fn):
    r = MODEL.reduced()
    r(x=X[0])
    return fn(r)


def _growing(f, k):
    return np.ones(5 + (k % 2))


def _add_all(full, n, **kw):
    tr = npg.Trainer(full, **kw)
    for k in range(n):
        tr.add(gpos=G[k])
    return tr


def _dtype_switch(f, k):
    v = np.sin(f.get("gpos")) + 2
    return v if k == 0 else v.astype(np.float32)


def _raise_on(k_bad):
    def fn(f, k):
        if k == k_bad and not fn.raised:  # once: the refused sample's number is the next sample's
            fn.raised = True
            raise KeyError("sample %d" % k)
        return vis(f, k)
    fn.raised = False
    return fn


def _raise_then_go_on():
    full = ext_full(_raise_on(2))
    tr = npg.Trainer(full)
    errs = 0
    for k in range(6):
        try:
            tr.add(gpos=G[k])
        except npg.Error as e:
            errs += isinstance(e.__cause__, KeyError)
    return errs, tr.samples, tr.finish().samples


class _Vis:
    def method(self, f, k):
        return vis(f, k)


class _CallObj:
    def __call__(self, f, k):
        return vis(f, k)


def _sample_numbers():
    seen = []
    full = ext_full(lambda f, k: (seen.append(k), vis(f, k))[1])
    full(gpos=G[0])
    full(gpos=G[1])
    tr = npg.Trainer(full)
    for k in range(3):
        tr.add(gpos=G[k])
    return seen


def _switch_callable_midway():
    calls = {"a": 0, "b": 0}
    def a(f, k):
        calls["a"] += 1
        return vis(f, k)
    def b(f, k):
        calls["b"] += 1
        return vis(f, k)
    full = ext_full(a)
    tr = npg.Trainer(full)
    for k in range(6):
        if k == 3:
            full.extern("vis", b)
        tr.add(gpos=G[k])
    m = tr.finish()
    return calls, m.samples


def _callable_removed_midway():
    full = ext_full()
    tr = npg.Trainer(full)
    tr.add(gpos=G[0])
    full.extern("vis", None)
    tr.add(gpos=G[1])


def _nested_evaluators():
    other = ext_full()
    def fn(f, k):
        return other(gpos=f.get("gpos"))["d"] / f.get("gpos")
    return ext_full(fn)(gpos=G[4])["d"]


def _mutual_recursion():
    a = EXT.full()
    b = EXT.full()
    a.extern("vis", lambda f, k: b(gpos=f.get("gpos"))["d"])
    b.extern("vis", lambda f, k: a(gpos=f.get("gpos"))["d"])
    return a(gpos=G[0])


def _thread_reads_dim_in_callable():
    full = ext_full()
    out = {}
    def fn(f, k):
        t = threading.Thread(target=lambda: out.__setitem__("F", f.dim("F")))
        t.start()
        t.join(20)
        return vis(f, k)
    full.extern("vis", fn)
    full(gpos=G[0])
    return out.get("F")


def _threads_share_with_callables():
    full = ext_full()
    outs, errs = [], []
    def work(i):
        for k in range(i, 40, 4):
            try:
                outs.append((k, full(gpos=G[k])["d"]))
            except Exception as e:  # noqa
                errs.append(e)
    ts = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    return errs, all(np.allclose(d, d_of(G[k]), rtol=1e-14) for k, d in outs), len(outs)


def _positional():
    tr = npg.Trainer(EQ3.full(), 0.9, 3, True)
    for x in X[:5]:
        tr.add(x=x)
    return tr.finish().samples


def _cap_np():
    tr = npg.Trainer(EQ3.full(), cap=np.int32(3))
    for x in X[:10]:
        tr.add(x=x)
    return tr.finish().basis_sizes


class Sub(np.ndarray):
    pass


def _readonly(x):
    a = x.copy()
    a.flags.writeable = False
    return a


def _reduced_vs_full():
    red = MODEL.reduced()
    errs = []
    for x in X[25:35]:
        red(x=x)
        errs.append(np.linalg.norm(red.lift("y") - y_of(x)) / np.linalg.norm(y_of(x)))
    return max(errs)


def _ext_reduced_vs_full():
    red = EXT_MODEL.reduced()
    errs = []
    for g in G[20:30]:
        red(gpos=g)
        errs.append(np.linalg.norm(red.lift("d") - d_of(g)) / np.linalg.norm(d_of(g)))
    return max(errs)


def _given_externs_exact():
    red = EXT_MODEL.reduced()
    red.given_externs(True)
    g = G[3]  # a training sample: in the basis span
    red(gpos=g, vis=np.sin(g) + 2)
    return np.linalg.norm(red.lift("d") - d_of(g)) / np.linalg.norm(d_of(g))


def _lift_out_shape(shape, dtype=np.float64):
    red = MODEL.reduced()
    red(x=X[0])
    return red.lift("y", out=np.zeros(shape, dtype))


def _lift_strided():
    red = MODEL.reduced()
    red(x=X[0])
    buf = np.zeros(4)
    try:
        red.lift("y", out=buf[::2])
        return buf, True
    except (ValueError, TypeError) as e:  # refused naming out is also right
        return np.r_[y_of(X[0]), 0, 0][[0, 2, 1, 3]] if "out" in str(e) else buf, "out" in str(e)


def _write(a):
    a[0, 0] = 1.0


def _round_trip():
    d = _TMP.name + "/rt"
    MODEL.save(d)
    m = npg.load(EQ3, d)
    a, b = MODEL.reduced(), m.reduced()
    return np.array_equal(a(x=X[33])["y"], b(x=X[33])["y"])


def _load_other():
    d = _TMP.name + "/rt2"
    MODEL.save(d)
    return npg.load(EXT, d)


def _save_into_file():
    p = _TMP.name + "/afile"
    open(p, "w").close()
    MODEL.save(p + "/sub")


# ---------------------------------------------------------------- names holding a NUL character
NUL = r"NUL character"
case("full.get('x\\0junk')", lambda: (EQ3.full()(x=X[0]), None)[1] or _get_nul(), ValueError, NUL)


case("full.get('y\\0')", lambda: _full_then(lambda f: f.get("y\0")), ValueError, NUL)


case("full(**{'x\\0y': x})", lambda: EQ3.full()(**{"x\0y": X[0]}), ValueError, NUL)
case("full.dim('F\\0')", lambda: ext_full().dim("F\0"), ValueError, NUL)
case("full.op('K\\0')", lambda: OP.full().op("K\0"), ValueError, NUL)
case("full.extern('vis\\0', fn)", lambda: EXT.full().extern("vis\0", vis), ValueError, "null|NUL")
case("full(params={'a\\0': ...})", lambda: OP.full(params={"a\0": np.eye(3)}), ValueError, NUL)
case("tr.add(**{'x\\0': x})", lambda: npg.Trainer(EQ3.full()).add(**{"x\0": X[0]}), ValueError, NUL)
case("tr.dots('x\\0', v)", lambda: _tr3().dots("x\0", X[0]), ValueError, "null|NUL")


case("Trainer(basis=['x\\0:cap=1'])", lambda: npg.Trainer(EQ3.full(), basis=["x\0:cap=1"]), ValueError, NUL)
case("Trainer(keep_bases='all\\0x')", lambda: npg.Trainer(EQ3.full(), keep_bases="all\0x"), ValueError, NUL)
case("Trainer(interp=['w\\0'])", lambda: npg.Trainer(EQ3.full(), interp=["w\0"]), ValueError, NUL)
case("Trainer(galerkin=['w\\0'])", lambda: npg.Trainer(EQ3.full(), galerkin=["w\0"]), ValueError, NUL)
case("Trainer(valid={'x\\0': ...})", lambda: npg.Trainer(EQ3.full(), valid={"x\0": X[:3]}), ValueError, NUL)
case("model.basis('x\\0')", lambda: MODEL.basis("x\0"), ValueError, NUL)
case("model.interpolated('y\\0')", lambda: MODEL.interpolated("y\0"), ValueError, NUL)
case("model.coefficients('x\\0')", lambda: MODEL.coefficients("x\0"), ValueError, NUL)
case("model.dim('N\\0')", lambda: MODEL.dim("N\0"), ValueError, "null|NUL")
case("model.verify(test={'x\\0': ...})", lambda: MODEL.verify(test={"x\0": X[:3]}), ValueError, NUL)
case("red(**{'x\\0': x})", lambda: MODEL.reduced()(**{"x\0": X[0]}), (ValueError, npg.Error), r"NUL|no input 'x")
case("red.lift('y\\0')", lambda: _red_then(lambda r: r.lift("y\0")), ValueError, "null|NUL")
case("red.coords('y\\0')", lambda: _red_then(lambda r: r.coords("y\0")), ValueError, NUL)
case("red.set_coords('x\\0', c)", lambda: _red_then(lambda r: r.set_coords("x\0", np.zeros(2))), ValueError,
     "null|NUL")
case("red.op('K\\0')", lambda: _red_then(lambda r: r.op("K\0")), ValueError, NUL)
case("compile(source with NUL)", lambda: npg.compile("input x : real[2]\n\0output y = x\n"), ValueError, "NUL")
case("compile(path with NUL)", lambda: npg.compile(f"{ROOT}/examples/rational/rational.npg\0x"), ValueError, "NUL")
case("model.save('dir\\0x')", lambda: MODEL.save(_TMP.name + "/m\0x"), ValueError, "null")
case("npg.load(prog, 'dir\\0x')", lambda: npg.load(EQ3, _TMP.name + "/m\0x"), ValueError, "null")


# ---------------------------------------------------------------- extern callables that change between samples
case("callable's answer grows at the next sample (trainer)",
     lambda: _add_all(ext_full(_growing), 3), npg.Error, r"extern 'vis'.*returned 6 values.*5")


case("callable switches to float32 at sample 1", lambda: _add_all(ext_full(_dtype_switch), 3), npg.Error,
     r"extern 'vis'.*float64|float32")
case("callable returns complex", lambda: ext_full(lambda f, k: np.ones(5, complex))(gpos=G[0]), npg.Error,
     r"extern 'vis'.*(complex|float64)")
case("callable returns a bool array", lambda: ext_full(lambda f, k: np.ones(5, bool))(gpos=G[0]), npg.Error,
     r"extern 'vis'.*(bool|float64)")
case("callable returns an object array", lambda: ext_full(lambda f, k: np.array([1.0] * 5, object))(gpos=G[0]),
     npg.Error, r"extern 'vis'.*(object|float64)")
case("callable returns a 0-d array for 5 values", lambda: ext_full(lambda f, k: np.array(2.0))(gpos=G[0]),
     npg.Error, r"extern 'vis'.*returned 1 values")
case("callable returns a tuple of 5 floats",
     lambda: ext_full(lambda f, k: tuple(np.sin(f.get("gpos")) + 2))(gpos=G[0])["d"],
     check=lambda d: np.allclose(d, d_of(G[0]), rtol=1e-14))
case("callable returns a Fortran 5x1 view",
     lambda: ext_full(lambda f, k: np.asfortranarray((np.sin(f.get("gpos")) + 2)[:, None]))(gpos=G[0])["d"],
     check=lambda d: np.allclose(d, d_of(G[0]), rtol=1e-14))
case("callable returns a reversed (negative-stride) view",
     lambda: ext_full(lambda f, k: (np.sin(f.get("gpos")) + 2)[::-1][::-1])(gpos=G[1])["d"],
     check=lambda d: np.allclose(d, d_of(G[1]), rtol=1e-14))
case("callable returns inf", lambda: _add_all(ext_full(lambda f, k: np.full(5, np.inf)), 1), npg.Error,
     r"vis.*(inf|not finite)")
case("callable returns -0.0 everywhere (zeros are fine)",
     lambda: ext_full(lambda f, k: np.full(5, -0.0))(gpos=G[0])["d"], check=lambda d: np.all(d == 0))


case("callable raises KeyError at sample 2: the cause kept, the trainer goes on", _raise_then_go_on,
     check=lambda r: r == (1, 5, 5))
case("callable raises StopIteration", lambda: ext_full(lambda f, k: next(iter([])))(gpos=G[0]), npg.Error,
     r"extern 'vis'|StopIteration")
case("callable raises KeyboardInterrupt",
     lambda: ext_full(lambda f, k: (_ for _ in ()).throw(KeyboardInterrupt))(gpos=G[0]), BaseException)
case("callable is a bound method", lambda: ext_full(_Vis().method)(gpos=G[2])["d"],
     check=lambda d: np.allclose(d, d_of(G[2]), rtol=1e-14))


case("callable is a callable object", lambda: ext_full(_CallObj())(gpos=G[3])["d"],
     check=lambda d: np.allclose(d, d_of(G[3]), rtol=1e-14))


case("callable takes one argument only", lambda: ext_full(lambda f: vis(f, 0))(gpos=G[0]), npg.Error,
     r"extern 'vis'|positional")
case("full.extern(name, 3)", lambda: EXT.full().extern("vis", 3), TypeError, r"vis.*callable")
case("full.extern('nosuch', fn)", lambda: EXT.full().extern("nosuch", vis), npg.Error, r"nosuch")
case("full.extern('d', fn) (an output)", lambda: EXT.full().extern("d", vis), npg.Error, r"'d'")
case("full.extern('gpos', fn) (an input)", lambda: EXT.full().extern("gpos", vis), npg.Error, r"gpos")


case("the sample numbers a callable sees: the evaluator's calls, then the trainer's samples", _sample_numbers,
     check=lambda s: s == [0, 1, 0, 1, 2])


case("the callable replaced between two adds: the new one is called", _switch_callable_midway,
     check=lambda r: r[0]["a"] == 3 and r[0]["b"] == 3 and r[1] == 6)


case("the callable removed between two adds: the extern is left out", _callable_removed_midway, npg.Error,
     r"extern 'vis' is not given")


case("callable evaluates another evaluator of the same program", _nested_evaluators,
     check=lambda d: np.allclose(d, d_of(G[4]), rtol=1e-13))


case("two evaluators whose callables call each other: the re-entry named in the chain", _mutual_recursion,
     npg.Error, r"cause: .*called from an extern callable of the same evaluator")


def _thread_started_in_callable(call):
    full = ext_full()
    tr = npg.Trainer(full)
    out = {}
    def fn(f, k):
        if "e" not in out:
            def helper():
                try:
                    call(f, tr)
                    out["e"] = None
                except npg.Error as e:
                    out["e"] = str(e)
            t = threading.Thread(target=helper)
            t.start()
            t.join(20)
            if t.is_alive():
                out["e"] = "deadlock"
        return vis(f, k)
    full.extern("vis", fn)
    d = full(gpos=G[5])["d"]
    return out["e"], np.allclose(d, d_of(G[5]), rtol=1e-14)


for what, call in [("full(...)", lambda f, tr: f(gpos=G[6])), ("full.extern", lambda f, tr: f.extern("vis", vis)),
                   ("tr.add", lambda f, tr: tr.add(gpos=G[6])), ("tr.finish", lambda f, tr: tr.finish()),
                   ("full.bind", lambda f, tr: f.bind({})),
                   ("tr.add_full", lambda f, tr: tr.add_full())]:
    case(f"a thread the callable starts and waits for calls {what}",
         lambda call=call: _thread_started_in_callable(call),
         check=lambda r: r[1] and r[0] and "started while an extern callable" in r[0])


case("a thread the callable starts reads full.dim", _thread_reads_dim_in_callable, check=lambda F: F == 5)


case("four threads share one evaluator with a callable: each waits its turn", _threads_share_with_callables,
     check=lambda r: r == ([], True, 40))

# ---------------------------------------------------------------- options of wrong types
for kw, val, exc, msg in [
        ("cap", 2.5, TypeError, r"cap"), ("cap", "3", TypeError, r"cap"), ("cap", [3], TypeError, r"cap"),
        ("cap", 0, ValueError, r"cap"), ("cap", np.float64(3.0), TypeError, r"cap"),
        ("energy", 0, ValueError, r"energy"), ("energy", 1.5, ValueError, r"energy"),
        ("energy", -0.1, ValueError, r"energy"), ("energy", np.inf, ValueError, r"energy"),
        ("energy", True, TypeError, r"energy"), ("energy", [0.9], TypeError, r"energy"),
        ("center", "yes", TypeError, r"center"), ("center", 2, TypeError, r"center"),
        ("center", None, TypeError, r"center"), ("center", 1.0, TypeError, r"center"),
        ("joint", "True", TypeError, r"joint"), ("joint", [], TypeError, r"joint"),
        ("progress", "no", TypeError, r"progress"), ("progress", -1, TypeError, r"progress"),
        ("mem", "1G", TypeError, r"mem"), ("mem", -1, ValueError, r"mem"), ("mem", 0, ValueError, r"mem"),
        ("mem", 1.5, TypeError, r"mem"), ("mem", 10 ** 40, (ValueError, OverflowError), r"mem"),
        ("basis", "x:cap=0", ValueError, r"basis 'x:cap=0'"), ("basis", [3], TypeError, r"basis"),
        ("basis", ["x:cap=2.5"], ValueError, r"basis 'x:cap=2.5': cap"), ("basis", ["x:cap=-3"], ValueError, r"cap"),
        ("basis", ["x:center=maybe"], ValueError, r"center"), ("basis", ["nosuch:cap=2"], npg.Error,
                                                                     r"basis nosuch: no quantity"),
        ("basis", [":cap=2"], ValueError, r"basis ':cap=2'"), ("basis", ["x"], ValueError, r"basis 'x'"),
        ("keep_bases", ["x"], TypeError, r"keep_bases"), ("keep_bases", "nosuch", npg.Error,
                                                         r"keep_bases nosuch: no quantity"),
        ("interp", "nosuch", npg.Error, r"interp nosuch"), ("interp", ["nosuch"], npg.Error, r"interp nosuch"),
        ("interp", [3], TypeError, r"interp"), ("galerkin", ["nosuch"], npg.Error, r"galerkin nosuch"),
        ("interp_oversample", 0.5, ValueError, r"interp_oversample"),
        ("interp_oversample", np.nan, ValueError, r"interp_oversample"),
        ("valid_holdout", 0.6, ValueError, r"valid_holdout"), ("valid_holdout", -0.1, ValueError,
                                                               r"valid_holdout"),
        ("valid_holdout", True, TypeError, r"valid_holdout"),
        ("valid", [1, 2], TypeError, r"valid"), ("valid", {"x": "ab"}, (TypeError, ValueError, npg.Error), r"x"),
]:
    case(f"Trainer({kw}={val!r})", lambda kw=kw, val=val: npg.Trainer(EQ3.full(), **{kw: val}), exc, msg)

case("Trainer(nosuch=1)", lambda: npg.Trainer(EQ3.full(), nosuch=1), TypeError, r"nosuch")
case("Trainer(full, 0.9, 3, True) positional", lambda: _positional(), check=lambda s: s == 5)


case("Trainer(cap=np.int32(3)) keeps at most 3", lambda: _cap_np(), check=lambda b: max(b.values()) <= 3)


for tol in [np.nan, -1.0, "0.1", np.inf, -0.5]:
    case(f"verify(tol={tol!r})", lambda tol=tol: MODEL.verify(test={"x": X[30:33]}, tol=tol),
         (TypeError, ValueError), r"tol")
case("verify(progress='yes')", lambda: MODEL.verify(test={"x": X[30:33]}, progress="yes"), TypeError, r"progress")
case("verify(test={'x': 3 samples}) the errors", lambda: MODEL.verify(test={"x": X[30:33]})["y"]["l2"],
     check=lambda e: 0 <= e < 1e-6)
case("model.reduced(exact_roots='no')", lambda: MODEL.reduced(exact_roots="no"), TypeError, r"exact_roots")
case("prog.full(backend=3)", lambda: EQ3.full(backend=3), TypeError)
case("prog.full(params=3)", lambda: EQ3.full(params=3), TypeError, r"params")

# ---------------------------------------------------------------- arrays of odd kinds
for label, make in [
        ("ndarray subclass", lambda x: x.view(Sub)), ("memoryview", lambda x: memoryview(x.copy())),
        ("array.array('d')", lambda x: array.array("d", x)), ("a list of numpy float64", lambda x: list(x)),
        ("a masked array (no mask)", lambda x: np.ma.masked_array(x)), ("a read-only array", _readonly),
        ("a Fortran-ordered copy", lambda x: np.asfortranarray(x)),
]:
    case(f"full(x = {label})", lambda make=make: EQ3.full()(x=make(X[7]))["y"],
         check=lambda y: np.allclose(y, y_of(X[7]), rtol=1e-14))


for label, val, exc in [
        ("complex", X[0].astype(complex), TypeError), ("bool", np.array([True, True]), TypeError),
        ("object", np.array([1.0, 2.0], object), TypeError), ("str array", np.array(["1", "2"]), TypeError),
        ("bytes", b"ab", TypeError), ("a dict", {"a": 1}, TypeError), ("a set", {1.0, 2.0}, TypeError),
        ("ragged list", [[1.0], [1.0, 2.0]], (TypeError, ValueError)), ("3 values", np.ones(3), npg.Error),
        ("a 2x1 array", np.ones((2, 1)), npg.Error), ("0-d", np.array(1.0), npg.Error),
        ("float16", X[0].astype(np.float16), TypeError), ("a 1x2 matrix", np.asmatrix(X[0]), npg.Error), ("uint8", np.array([1, 2], np.uint8), TypeError),
]:
    case(f"full(x = {label})", lambda val=val: EQ3.full()(x=val), exc, r"'x'|x")

for label, val, exc in [
        ("complex", X[0].astype(complex), TypeError), ("3 values", np.ones(3), npg.Error),
        ("NaN", np.array([np.nan, 1.0]), npg.Error), ("-inf", np.array([1.0, -np.inf]), npg.Error),
]:
    case(f"red(x = {label})", lambda val=val: MODEL.reduced()(x=val), exc, r"'?x'?")
    case(f"tr.add(x = {label})", lambda val=val: npg.Trainer(EQ3.full()).add(x=val), exc, r"'?x'?")

# ---------------------------------------------------------------- reduced against full
case("reduced eq3 against NumPy on 10 held-out samples", _reduced_vs_full, check=lambda e: e < 1e-8)


case("reduced extern program against NumPy on 10 held-out samples (learned map)", _ext_reduced_vs_full,
     check=lambda e: np.isfinite(e) and e < 0.5)


case("reduced with the extern given, a training sample", _given_externs_exact, check=lambda e: e < 1e-8)


case("red.lift(out of 3 entries)", lambda: _lift_out_shape(3), (ValueError, npg.Error), r"'y' has 2 entries.* 3")
case("red.lift(out int64)", lambda: _lift_out_shape(2, np.int64), TypeError, r"out")
case("red.lift(out strided view)", lambda: _lift_strided(), check=lambda r: np.allclose(r[0][::2], y_of(X[0]),
                                                                                        rtol=1e-8) and r[1])


case("red.coords('x') after red(x)", lambda: _red_then(lambda r: r.coords("x")), check=lambda c: c.ndim == 1 and
     np.all(np.isfinite(c)))
case("red.set_coords('x', list)", lambda: _red_then(lambda r: r.set_coords("x", list(r.coords("x")))),
     check=lambda r: r is None)
case("red.set_coords('y', c) (an output)", lambda: _red_then(lambda r: r.set_coords("y", r.coords("y"))),
     npg.Error, r"'y'")
case("red(y=...) an output", lambda: MODEL.reduced()(y=X[0]), npg.Error, r"'y'")
case("red() no input ever given", lambda: MODEL.reduced()(), npg.Error, r"'x'")
case("red.given_externs(True) on a model without externs", lambda: MODEL.reduced().given_externs(True),
     check=lambda r: r is None)
case("EXT red(vis=...) without given_externs", lambda: EXT_MODEL.reduced()(gpos=G[0], vis=G[0]), npg.Error,
     r"vis.*extern")
case("model.basis('x') is read-only", lambda: _write(MODEL.basis("x")), ValueError, r"read-only")


case("model.basis('nosuch')", lambda: MODEL.basis("nosuch"), npg.Error, r"nosuch")
case("model.dim('nosuch')", lambda: MODEL.dim("nosuch"), check=lambda d: d == -1)
case("model.save then npg.load round trip", lambda: _round_trip(), check=bool)


case("npg.load(other program, dir)", lambda: _load_other(), npg.Error, r"program|hash|another")


case("model.save(into a file)", lambda: _save_into_file(), (npg.Error, OSError), r"")


# ---------------------------------------------------------------- divisions and roots inside op entries
# Each op against the dense matrix NumPy builds and solves; the op stays sparse unless a base reads both
# the row and the column (h[i] + h[j]), and no stage of N x N entries is introduced for it.
NB = 5
NN = NB * NB
NBR = -np.ones((NN, 4), dtype=np.int64)
for _y in range(NB):
    for _x in range(NB):
        _i = _y * NB + _x
        NBR[_i] = [_i - 1 if _x > 0 else -1, _i + 1 if _x < NB - 1 else -1, _i - NB if _y > 0 else -1,
                   _i + NB if _y < NB - 1 else -1]
SRC, KAP, HH, GG = rng.random(NN), 0.5 + rng.random(NN), 0.5 + rng.random(NN), 0.5 + rng.random(NN)
OP_HEAD = "dim N\nparam nbr : int[N, 4]\nparam src : real[N]\ninput kappa : real[N]\ninput h : real[N]\ninput g : real[N]\n"


def op_program(entry):
    return (OP_HEAD + "op K[i:N, j:N] = delta(i, j) * (8 + sum(k = 0..3, if(nbr[i, k] >= 0, kappa[i] / h[i], 0))) - "
            f"sum(k = 0..3, if(nbr[i, k] == j, {entry}, 0))\noutput u = solve(K, src)\n")


def op_dense(f):
    K = np.zeros((NN, NN))
    for i in range(NN):
        K[i, i] = 8 + sum(KAP[i] / HH[i] for k in range(4) if NBR[i, k] >= 0)
        for k in range(4):
            if NBR[i, k] >= 0:
                K[i, NBR[i, k]] -= f(i, NBR[i, k], k)
    return np.linalg.solve(K, SRC)


def op_case(entry, f, sparse):
    p = npg.compile(op_program(entry), name="opform.npg")
    u = p.full(params={"nbr": NBR, "src": SRC})(kappa=KAP, h=HH, g=GG)["u"]
    want = op_dense(f)
    text = p.check()
    squares = [s for s in p.report["stages"] if s.get("introduced") and s["shape"] == ["N", "N"]]
    return (np.abs(u - want).max() / np.abs(want).max() < 1e-12, ("K[i:N, j:N]  (1 row axis; sparse" in text) == sparse,
            (not squares) == sparse)


for entry, f, sparse in [
        ("kappa[i] / h[i]", lambda i, j, k: KAP[i] / HH[i], True),
        ("kappa[i] / h[j]", lambda i, j, k: KAP[i] / HH[j], True),
        ("kappa[i] * h[i]^(-1/2)", lambda i, j, k: KAP[i] * HH[i] ** -0.5, True),
        ("kappa[i] / (h[i] * g[i])", lambda i, j, k: KAP[i] / (HH[i] * GG[i]), True),
        ("kappa[i] / h[i] / g[i]^(1/3)", lambda i, j, k: KAP[i] / HH[i] / GG[i] ** (1 / 3), True),
        ("kappa[i] / (h[i] + g[i])", lambda i, j, k: KAP[i] / (HH[i] + GG[i]), True),
        ("(kappa[i] + kappa[j]) / (2 * h[i])", lambda i, j, k: (KAP[i] + KAP[j]) / (2 * HH[i]), True),
        ("if(k < 2, kappa[i] / h[i], kappa[i] / g[i])", lambda i, j, k: KAP[i] / (HH[i] if k < 2 else GG[i]), True),
        ("kappa[i] / h[i] + kappa[j] / g[j]", lambda i, j, k: KAP[i] / HH[i] + KAP[j] / GG[j], True),
        ("kappa[i] * (h[i] * g[i])^(-1/2)", lambda i, j, k: KAP[i] * (HH[i] * GG[i]) ** -0.5, True),
        ("kappa[i] / (h[i] + h[j])", lambda i, j, k: KAP[i] / (HH[i] + HH[j]), False),
        ("kappa[i] / (h[i] * h[j])", lambda i, j, k: KAP[i] / (HH[i] * HH[j]), False),
]:
    case(f"op entry {entry}: the solution, the pattern, no N x N stage", lambda e=entry, f=f, s=sparse: op_case(e, f, s),
         check=lambda r: r == (True, True, True))


def op_reduced(text):
    p = npg.compile(text, name="opform.npg")
    full = p.full(params={"nbr": NBR, "src": SRC})
    tr = npg.Trainer(full)
    r = np.random.default_rng(4)
    ks, hs = 0.5 + r.random((12, NN)), 0.5 + r.random((12, NN))
    for k in range(12):
        tr.add(kappa=ks[k], h=hs[k], g=GG)
    m = tr.finish()
    red = m.reduced()
    red(kappa=ks[3], h=hs[3], g=GG)
    want = full(kappa=ks[3], h=hs[3], g=GG)["u"]
    return np.linalg.norm(red.lift("u") - want) / np.linalg.norm(want), sorted(m.basis_sizes.values())


def op_reduced_as_by_hand():
    auto = op_reduced(op_program("kappa[i] / h[i]"))
    hand = op_reduced(op_program("kappa[i] * r[i]").replace("op K", "r[i:N] = 1 / h[i]\nop K")
                      .replace("kappa[i] / h[i], 0)))", "kappa[i] * r[i], 0)))"))
    return auto, hand


case("op entry kappa[i] / h[i]: the reduced model as with the reciprocal named by hand", op_reduced_as_by_hand,
     check=lambda r: r[0][1] == r[1][1] and abs(r[0][0] - r[1][0]) <= 1e-9 * max(r[1][0], 1e-300) + 1e-14
     and r[0][0] < 0.05)


ok = sum(r[1] for r in results)
for name, good, why in results:
    print(("ok   " if good else "FAIL ") + name + ": " + why)
print(f"{len(results)} cases, {ok} correct, {len(results) - ok} wrong")
sys.exit(0 if ok == len(results) else 1)
