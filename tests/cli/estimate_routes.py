"""estimate_routes.py BUILD_DIR [--mpi] — the online estimate's tables on every route of training (issue 41),
on the thermal block of estimate.py (tests/cli/thermal_block.npg, 8 x 8 cells, SPD, the min-θ
bound): trained in memory (the reference), out of core (--mem below the bases: they are built by
row blocks and mapped from their files), over two MPI ranks (npgc train --mpi; with --mpi, which ctest
gives in a build with MPI), with an extern (a second output w = v u, v an extern of mu given as data), and by npgc
tune (the model of the size search). On each route the model must hold the tables (manifest lines
`estimate`, `theta`, `range`), its estimate of u must bound numpy's true error on every test sample
(effectivity in [1, 20], as estimate.py: the min-θ bound is rigorous), and its tables must be the
in-memory route's: over ranks (the same arithmetic, the sums in another order) and with the extern
(u's class and its snapshots unchanged) the arrays to 1e-10 of their largest entry; out of core and
from tune (bases from row blocks, or truncated from larger ones: equal to rounding, not bit for
bit) the estimates on the test samples to 1e-8 relative. With the extern, w reads v, whose learned
map has no estimate: w reports none, with that reason."""
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from estimate import fail, grid, run, solve, write  # noqa: E402  (estimate.py runs only as a script)

B = sys.argv[1]
PROG = "tests/cli/thermal_block.npg"


def manifest(model):
    return open(os.path.join(model, "manifest")).read()


def tables(model):
    """The estimate's arrays of a model folder: est_*, theta_*, range_*."""
    return {f: np.load(os.path.join(model, f)) for f in sorted(os.listdir(model))
            if f.startswith(("est_", "theta_", "range_")) and f.endswith(".npy")}


def check_route(name, prog, model, test, mu_test, data, ref=None, same=None):
    """The route's model: tables present, u's estimate bounding the true error (effectivity in [1, 20]); its
    estimates the in-memory model's `ref` to 1e-10 relative, and with `same` (arrays by file name) its tables of
    those names those arrays to 1e-10 of their largest entry."""
    man = manifest(model)
    for line in ("estimate u 0 dim", "theta u 0 input mu", "range mu"):
        if line not in man:
            fail("%s: no `%s` line in the manifest:\n%s" % (name, line, man))
    out = model + "_OUT"
    run("eval", prog, model, test, "-o", out)
    est = np.load(os.path.join(out, "u.estimate.npy"))
    red = np.load(os.path.join(out, "u.npy"))
    err = np.array([np.linalg.norm(solve(mu_test[k], *data) - red[k]) for k in range(len(mu_test))])
    eff = est / err
    print("%s: effectivity %.3g .. %.3g over %d test samples" % (name, eff.min(), eff.max(), len(eff)))
    if not (eff >= 1).all() or not (eff <= 20).all():
        fail("%s: effectivity outside [1, 20]: %s" % (name, eff))
    if ref is not None:
        d = np.max(np.abs(est - ref) / ref)
        print("%s: estimates within %.2g of the in-memory model's (relative)" % (name, d))
        if not d <= 1e-10:
            fail("%s: the estimates differ from the in-memory model's by %.3g (relative)" % (name, d))
    if same is not None:
        mine = tables(model)
        if not set(same) <= set(mine):
            fail("%s: tables %s, the in-memory model's %s" % (name, sorted(mine), sorted(same)))
        for f, a in same.items():
            d = np.max(np.abs(mine[f] - a)) / max(1.0, np.max(np.abs(a))) if mine[f].shape == a.shape else np.inf
            if not d <= 1e-10:
                fail("%s: %s differs from the in-memory model's by %.3g" % (name, f, d))
        print("%s: its %d tables are the in-memory model's to 1e-10" % (name, len(same)))
    return out, est


def mpi_train(train, model):
    """npgc train over 2 MPI ranks (loopback, and under the sanitizers OpenMPI's own leaks suppressed, as
    tests/mpi/mpi.sh); False unless the build has MPI (ctest passes --mpi then)."""
    if "--mpi" not in sys.argv[2:]:
        return False
    asan = os.environ.get("ASAN_OPTIONS", "")
    env = dict(os.environ, OMPI_MCA_btl="self,vader", OMPI_MCA_btl_vader_single_copy_mechanism="none",
               OMPI_MCA_oob_tcp_if_include="lo", OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1",
               ASAN_OPTIONS=(asan + ":" if asan else "") + "fast_unwind_on_malloc=0",
               LSAN_OPTIONS="suppressions=%s/tests/mpi/lsan.supp" % os.getcwd(),
               OMPI_MCA_mca_base_component_disable_dlclose="1")
    p = subprocess.run(["timeout", "300", "mpirun", "--allow-run-as-root", "--oversubscribe", "-x", "ASAN_OPTIONS",
                        "-x", "LSAN_OPTIONS", "-np", "2", os.path.join(B, "npgc"), "train", PROG, train, "-o", model,
                        "--mpi"], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        fail("npgc train --mpi over 2 ranks: %s%s" % (p.stdout, p.stderr))
    return True


def extern_route(w, train, test, mu_test, data, ref, ref_tables):
    """A program with an extern v of mu (given as data) and a second output w = v u reading it."""
    xprog = os.path.join(w, "extern.npg")
    with open(PROG) as f, open(xprog, "w") as g:
        g.write(f.read() + "extern v[i:N] of mu\noutput w[i:N] = v[i] * u[i]\n")
    for d in (train, test):
        mu = np.load(os.path.join(d, "mu.npy"))
        np.save(os.path.join(d, "v.npy"), np.ascontiguousarray(1 + 0.3 * mu[:, data[1]] ** 2))
    xm = os.path.join(w, "EXTERN")
    run("train", xprog, train, "-o", xm)
    out, _ = check_route("with an extern", xprog, xm, test, mu_test, data, ref,
                         {f: a for f, a in ref_tables.items() if f.startswith(("est_u", "theta_u", "range_mu"))})
    p = run("eval", xprog, xm, test, "-o", out + "2")
    if "w has no estimate: its input v has no estimate" not in p.stdout or \
            not np.isnan(np.load(os.path.join(out + "2", "w.estimate.npy"))).all():
        fail("with an extern: w (which reads the extern v) reported an estimate or no reason:\n" + p.stdout)
    for d in (train, test):
        os.remove(os.path.join(d, "v.npy"))


def tune_route(w, train, valid, test, mu_test, data):
    """npgc tune's model, and the model trained at the sizes it chose (its basis of u the same to 1e-12)."""
    tm = os.path.join(w, "TUNE")
    run("tune", PROG, train, valid, "--tol", "1e-2", "-o", tm, "--png", os.path.join(w, "tune.png"))
    cap = [l.split()[4] for l in manifest(tm).splitlines() if l.startswith("member ") and l.split()[2] == "u"]
    if len(cap) != 1:
        fail("npgc tune: no member line of u in its manifest:\n" + manifest(tm))
    tt = os.path.join(w, "TUNE_SIZES")
    run("train", PROG, train, "-o", tt, "--basis", "u:cap=%s,energy=1" % cap[0])
    ba, bb = (np.load(os.path.join(d, tables_u_basis(d))) for d in (tt, tm))
    if ba.shape != bb.shape or not np.max(np.abs(ba - bb)) <= 1e-12:
        fail("npgc tune's basis of u is not the one trained at its sizes (u cap %s)" % cap[0])
    _, ref = check_route("trained at tune's sizes (u cap %s)" % cap[0], PROG, tt, test, mu_test, data)
    check_route("npgc tune", PROG, tm, test, mu_test, data, ref)


def tables_u_basis(model):
    """The file of u's class basis (the manifest's `class C {u}` line)."""
    for line in manifest(model).splitlines():
        f = line.split()
        if f[:1] == ["class"] and f[2] == "{u}":
            return "basis_%s.npy" % f[1]
    fail("no class {u} in %s/manifest" % model)


def main():
    data = grid(8)  # 8 x 8 cells: out of core a pass holds one row (the R factors take --mem), 64 passes
    rng = np.random.default_rng(43)
    w = tempfile.mkdtemp(prefix="npg_estroutes_")
    try:
        train, test, valid = (os.path.join(w, n) for n in ("TRAIN", "TEST", "VALID"))
        write(train, rng.uniform(0.1, 1, (20, 4)), *data)
        mu_test = rng.uniform(0.1, 1, (12, 4))
        write(test, mu_test, *data)
        write(valid, rng.uniform(0.1, 1, (6, 4)), *data)
        mem = os.path.join(w, "MEM")
        run("train", PROG, train, "-o", mem)
        _, ref = check_route("in memory", PROG, mem, test, mu_test, data)
        ref_tables = tables(mem)
        ooc = os.path.join(w, "OOC")
        p = run("train", PROG, train, "-o", ooc, "--mem", "3k", "--progress")
        if "of 2 classes streamed by rows" not in p.stderr:
            fail("--mem 3k did not train out of core:\n" + p.stderr)
        check_route("out of core", PROG, ooc, test, mu_test, data, ref)
        if mpi_train(train, os.path.join(w, "MPI")):
            check_route("over 2 MPI ranks", PROG, os.path.join(w, "MPI"), test, mu_test, data, ref, ref_tables)
        else:
            print("over MPI ranks: skipped (a build without MPI)")
        extern_route(w, train, test, mu_test, data, ref, ref_tables)
        tune_route(w, train, valid, test, mu_test, data)
    finally:
        shutil.rmtree(w, ignore_errors=True)


main()
print("ok")
