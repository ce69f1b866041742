"""estimate_chunks.py BUILD_DIR — residual tables made by row chunks (issue 41; backends/train/estimate_train.c
chunked_table): a term whose columns (n x D) do not fit ESTIMATE_MAX_BYTES whole has its table made as the R22 of a
tall-skinny QR of [B C], C's rows a chunk at a time under the R so far (LAPACK dtpqrt), so that only R is ever
whole. NPG_TEST_ESTIMATE_CHUNKS=ROWS makes every table that route, ROWS rows a chunk: each program below is trained
both ways and the two models must hold the same tables to rounding (RᵀR, what ‖R z‖ depends on, to 1e-10 of the
largest column norm squared; the columns' norms to 1e-12 relative) and give the same estimates on test samples (to
1e-9 relative, the same flags). The programs cover every table kind: a contraction and an inverse (the thermal
block's u = K⁻¹ src, 900 unknowns, with its sparse σ_min), applications, powers, chains and roots (of powers above 1, among
several operators, a diagonal operator among them, powers below −1: block tables apart per column block: tests/cli/estimate_apply.py's
programs)."""
import os
import subprocess
import sys
import tempfile

import numpy as np

B = sys.argv[1]
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import estimate_apply as ap  # noqa: E402
import estimate_sparse as sp  # noqa: E402


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def run(args, chunks=None):
    env = dict(os.environ)
    env.pop("NPG_TEST_ESTIMATE_CHUNKS", None)
    if chunks:
        env["NPG_TEST_ESTIMATE_CHUNKS"] = str(chunks)
    p = subprocess.run([os.path.join(B, "npgc")] + args, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        fail("npgc %s: %s%s" % (" ".join(args), p.stdout, p.stderr))
    return p


def tables(model):
    return sorted(f for f in os.listdir(model) if f.startswith("est_") and f.endswith(".npy"))


def compare(label, prog, train, test, d, basis=()):
    whole, chunked = os.path.join(d, label + "_WHOLE"), os.path.join(d, label + "_CHUNKS")
    run(["train", prog, train, *basis, "-o", whole])
    run(["train", prog, train, *basis, "-o", chunked], chunks=7)
    names = tables(whole)
    if not names or names != tables(chunked):
        fail("%s: tables %s whole, %s by chunks" % (label, names, tables(chunked)))
    worst = [0.0, 0.0]
    for name in names:
        a, b = np.load(os.path.join(whole, name)), np.load(os.path.join(chunked, name))
        D = a.shape[1]
        if b.shape != a.shape:
            fail("%s: %s is %s whole, %s by chunks" % (label, name, a.shape, b.shape))
        top = np.max(a[D]) ** 2
        worst[0] = max(worst[0], np.abs(a[:D].T @ a[:D] - b[:D].T @ b[:D]).max() / top)
        worst[1] = max(worst[1], np.abs(a[D] - b[D]).max() / np.max(a[D]))
    if not worst[0] <= 1e-10 or not worst[1] <= 1e-12:
        fail("%s: RᵀR differs by %.3g of the largest column norm squared, the norms by %.3g" % (label, *worst))
    outs = [os.path.join(d, label + "_OUT" + r) for r in ("W", "C")]
    flags = [run(["eval", prog, m, test, "-o", o]).stdout for m, o in zip((whole, chunked), outs)]
    rel = 0.0
    for f in sorted(os.listdir(outs[0])):
        if f.endswith(".estimate.npy"):
            e, c = (np.load(os.path.join(o, f)) for o in outs)
            if not np.array_equal(np.isnan(e), np.isnan(c)):
                fail("%s: %s has a figure on one route only" % (label, f))
            ok = ~np.isnan(e)
            if ok.any():
                rel = max(rel, float(np.max(np.abs(e[ok] - c[ok]) / np.maximum(np.abs(e[ok]), 1e-300))))
    strip = lambda s: [ln.split()[-1] for ln in s.splitlines() if ln.strip()]
    if strip(flags[0]) != strip(flags[1]):
        fail("%s: the flags differ:\n%s\n%s" % (label, flags[0], flags[1]))
    print("%s: %d tables (%s): RᵀR within %.1e, norms within %.1e; estimates within %.1e (relative)" %
          (label, len(names), " ".join(n[4:-4] for n in names), worst[0], worst[1], rel))
    if not rel <= 1e-9:
        fail("%s: the estimates made by chunks differ from the whole route's by %.3g (relative)" % (label, rel))


def main():
    rng = np.random.default_rng(7)
    a, phi, psi = ap.data(rng)
    with tempfile.TemporaryDirectory() as d:
        train, test = os.path.join(d, "TRAIN"), os.path.join(d, "TEST")
        ap.write(train, dict(ap.samples(rng, phi, psi, 20), a=a))
        ap.write(test, dict(ap.samples(rng, phi, psi, 6, noise=1e-3), a=a))
        compare("apply", ap.PROG, train, test, d, ("--basis", "x:cap=8"))
        for label, text in (("chain", ap.CHAIN), ("roots", ap.ROOTS), ("rootsx", ap.ROOTSX), ("diagx", ap.DIAGX),
                            ("negpow", ap.NEGPOW)):
            prog = os.path.join(d, label + ".npg")
            open(prog, "w").write(text)
            v = ("--basis", "v:energy=1") if "input  v" in text else ()
            compare(label, prog, train, test, d, ("--basis", "x:cap=8") + v)
        G = 30
        nbr, blk, src = sp.grid(G)
        tb_train, tb_test = os.path.join(d, "TB"), os.path.join(d, "TBTEST")
        sp.write(tb_train, rng.uniform(0.1, 1, (12, 4)), nbr, blk, src)
        sp.write(tb_test, rng.uniform(0.1, 1, (5, 4)), nbr, blk, src)
        compare("thermal block", sp.PROG, tb_train, tb_test, d)
    print("ok")


main()
