"""estimate_stream.py BUILD_DIR [--mpi] — the online estimate's tables of the stages that read a basis the
model drops out of core (issue 41; backends/train/estimate_stream.c): radiosity's 24-face room (20 training
samples, 6 test samples of another seed), trained in memory and out of core at --mem 8k, where the pair classes
{s,h} {r} {c} {v} {d,p} are formed block by block and never whole (with --mpi, which ctest gives in a build with
MPI, also out of core over 2 ranks). The out-of-core model must hold a residual table for every term the
in-memory model has one for (manifest lines `estimate`), each the in-memory table to rounding (RᵀR, the form
‖R z‖ depends on, to 1e-10 of the largest column norm squared; the columns' norms to 1e-10 relative), the
inverse terms' σ_min ratios to 1e-10 relative, and on the test samples every stage's estimate the in-memory
model's to 1e-9 relative (the two routes' bases themselves differ by rounding, which moves even a stage whose
basis is whole in both: n's estimates differ by up to 2e-12). The effectivity (estimate / true error) of both
models is printed per stage, the true error from the full evaluator and the bases of a model trained with
--keep-bases all: every estimate at least half of its true error.

Then the same room without the extern (a convex room: d = c ρ_j, no visibility), with y = M e and
k = c / (μ0 + μ1 ρ_i ρ_j) added (μ an input of 2 entries), where out of core, beyond the tables, p = d a^(-1/2)
(a Galerkin stage of a diagonal root, in the dropped class {d,p}) gets its check table from the sweep
(manifest line `galerkincheck`: its entries, reads and monomials equal to in memory's, its basis rows within
1e-10), y's chained table (an operator application whose operator reads the dropped p: one R per column
block) is made, and k (an inverse of a diagonal operator affine in μ with semidefinite parts, in the dropped
class {c,k}) gets the min-θ anchors (manifest line `theta`, within 1e-10): p, b and y get estimates out of
core (none before), k its σ_min through the min-θ bound (the σ_min-ratio estimate before; its figure stays
an estimate: it carries c's error); every figure the in-memory model's to 1e-8 relative with the same flags
(bound, outside, roundoff), on one process and over 2 ranks (h c k within 2e-11; d p b y within 1.2e-9: the
routes' bases of {e,b,y} and {a}, whole on both, differ by up to 1.1e-11 relative, which those figures carry
through M̂⁻¹ and the propagated input errors)."""
import os
import subprocess
import sys
import tempfile

import numpy as np

B = sys.argv[1]
sys.path.insert(0, os.path.join(B, "python"))
import npg  # noqa: E402  (the build's module)

PROG = "examples/radiosity/formfactors.npg"
STAGES = "nsrhca"  # the stages with an estimate (d, p and b read the extern v, whose learned map has none)
CONVEX_STAGES = "hcdkpby"  # the convex room's compared stages (n s r a are reproduced to roundoff: their figures are noise)


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def child_env():
    """The programs this script runs: without the module's LD_PRELOAD of the sanitizers' runtime (npgc links it
    itself in a sanitized build), their leaks fatal again (the module's interpreter runs with leaks off)."""
    env = {k: v for k, v in os.environ.items() if k != "LD_PRELOAD"}
    if "ASAN_OPTIONS" in env:
        env["ASAN_OPTIONS"] = env["ASAN_OPTIONS"].replace("detect_leaks=0", "detect_leaks=1")
    return env


def run(*args):
    p = subprocess.run([os.path.join(B, "npgc")] + list(args), capture_output=True, text=True, env=child_env())
    if p.returncode != 0:
        fail("npgc %s: %s%s" % (" ".join(args), p.stdout, p.stderr))
    return p


def estimate_lines(model):
    """{stage: sigma} of the manifest's `estimate` lines."""
    out = {}
    for line in open(os.path.join(model, "manifest")):
        f = line.split()
        if f and f[0] == "estimate":
            out[f[1]] = float(f[f.index("sigma") + 1])
    return out


def train_over_ranks(data, model, prog=PROG):
    """npgc train out of core over 2 MPI ranks (loopback; OpenMPI's own leaks suppressed under the sanitizers, as
    tests/mpi/mpi.sh does): each rank factors the blocks of its passes, the ranks' R stacked and factored once more."""
    asan = child_env().get("ASAN_OPTIONS", "")
    env = dict(child_env(), OMPI_MCA_btl="self,vader", OMPI_MCA_btl_vader_single_copy_mechanism="none",
               OMPI_MCA_oob_tcp_if_include="lo", OPENBLAS_NUM_THREADS="1", OMPI_MCA_mca_base_component_disable_dlclose="1",
               ASAN_OPTIONS=(asan + ":" if asan else "") + "fast_unwind_on_malloc=0",
               LSAN_OPTIONS="suppressions=%s/tests/mpi/lsan.supp" % os.getcwd())
    cmd = ["timeout", "300", "mpirun", "--allow-run-as-root", "--oversubscribe", "-x", "ASAN_OPTIONS", "-x", "LSAN_OPTIONS",
           "-np", "2", os.path.join(B, "npgc"), "train", prog, data, "--cap", "8", "--mem", "8k", "-o", model, "--mpi"]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        fail("out of core over 2 ranks: %s%s" % (p.stdout, p.stderr))


def compare_tables(mem, ooc):
    want, got = estimate_lines(mem), estimate_lines(ooc)
    if set(want) != set(got):
        fail("out of core the model holds tables for %s, in memory for %s" % (sorted(got), sorted(want)))
    for q, sig in want.items():
        if not (np.isnan(sig) and np.isnan(got[q])) and not abs(got[q] - sig) <= 1e-10 * abs(sig):
            fail("stage %s: σ_min ratio %.17g out of core, %.17g in memory" % (q, got[q], sig))
        a, b = (np.load(os.path.join(d, "est_%s_t0.npy" % q)) for d in (mem, ooc))
        D = a.shape[1]
        if b.shape != a.shape:
            fail("stage %s: table %s out of core, %s in memory" % (q, b.shape, a.shape))
        gram = np.abs(a[:D].T @ a[:D] - b[:D].T @ b[:D]).max() / np.max(a[D]) ** 2
        norms = np.abs(a[D] - b[D]).max() / np.max(a[D])
        if not gram <= 1e-10 or not norms <= 1e-10:
            fail("stage %s: RᵀR differs by %.3g of the largest column norm squared, the norms by %.3g" % (q, gram, norms))
    print("tables: %d stages (%s), RᵀR and norms within 1e-10, σ_min ratios %s" %
          (len(want), " ".join(sorted(want)), ", ".join("%s %.6g" % (q, s) for q, s in want.items() if not np.isnan(s))))


def manifest_lines(model, word):
    return sorted(line for line in open(os.path.join(model, "manifest")) if line.startswith(word + " "))


def compare_theta(mem, ooc):
    """The min-θ anchors of the inverse terms: the same lines, the anchors within 1e-10 of their largest entry."""
    want, got = manifest_lines(mem, "theta"), manifest_lines(ooc, "theta")
    if want != got:
        fail("min-θ lines out of core %s, in memory %s" % (got, want))
    for line in want:
        f = line.split()
        a, b = (np.load(os.path.join(d, "theta_%s_t%s.npy" % (f[1], f[2]))) for d in (mem, ooc))
        if a.shape != b.shape or not np.abs(a - b).max() <= 1e-10 * np.abs(a).max():
            fail("stage %s: min-θ anchors %s out of core, %s in memory" % (f[1], b, a))
    print("min-θ anchors: %s equal (within 1e-10)" % ", ".join(l.split()[1] for l in want))


def compare_checks(mem, ooc):
    """The check tables of the Galerkin stages of diagonal operators: the same lines, entries, reads and
    monomials, the basis rows within 1e-10 of their largest entry."""
    want, got = manifest_lines(mem, "galerkincheck"), manifest_lines(ooc, "galerkincheck")
    if want != got:
        fail("check tables out of core %s, in memory %s" % (got, want))
    for line in want:
        q = line.split()[1]
        for part in ("rows", "reads", "monos", "brows", "readrows"):
            a, b = (np.load(os.path.join(d, "interp_%s_check_%s.npy" % (q, part))) for d in (mem, ooc))
            if a.shape != b.shape:
                fail("stage %s: check %s %s out of core, %s in memory" % (q, part, b.shape, a.shape))
            tol = 1e-10 * np.abs(a).max() if part in ("brows", "readrows") else 0
            if not np.abs(a - b).max() <= tol:
                fail("stage %s: check %s differ by %.3g" % (q, part, np.abs(a - b).max()))
    print("check tables: %s equal (basis rows within 1e-10)" % ", ".join(l.split()[1] for l in want))


def convex(rt, test, w):
    """The convex room (no extern) with y = M e and k = c / (μ0 + μ1 ρ_i ρ_j): p's check table, y's chained
    table and k's min-θ anchors out of core."""
    prog = os.path.join(w, "convex.npg")
    text = open(PROG).read()
    text = "".join(l for l in text.splitlines(True) if not l.startswith("extern v"))
    text = text.replace("d[i:F, j:F] = c[i,j] * v[i,j]", "d[i:F, j:F] = c[i,j] * rho[j]")
    text = text.replace("a[i:F]", "input mu : real[2]\nk[i:F, j:F] = c[i,j] / (mu[0] + mu[1] * rho[i] * rho[j])\na[i:F]")
    if "v[" in text or "k[i:F" not in text:
        fail("the convex room's program not made: still reads v, or no k")
    rng = np.random.default_rng(3)
    for d, S in ((rt, 20), (test, 6)):
        np.save(os.path.join(d, "mu.npy"), rng.uniform(0.5, 2, (S, 2)))
    open(prog, "w").write(text + "output y = M * e\n")
    for r, extra in (("CMEM", []), ("COOC", ["--mem", "8k"]), ("CKEEP", ["--keep-bases", "all"])):
        run("train", prog, rt, "--cap", "8", "-o", os.path.join(w, r), *extra)
    routes = ["COOC"]
    if "--mpi" in sys.argv[2:]:
        train_over_ranks(rt, os.path.join(w, "CMPI"), prog)
        routes.append("CMPI")
    for r in routes:
        compare_tables(os.path.join(w, "CMEM"), os.path.join(w, r))
        compare_checks(os.path.join(w, "CMEM"), os.path.join(w, r))
        compare_theta(os.path.join(w, "CMEM"), os.path.join(w, r))
    p = npg.compile(prog)
    full = p.full(params={n: np.load("%s/%s.npy" % (rt, n)) for n in ("tri", "rho")})
    g, e, mu = (np.load("%s/%s.npy" % (test, n)) for n in ("g", "e", "mu"))
    keep = npg.load(p, os.path.join(w, "CKEEP"))
    reds = {r: npg.load(p, os.path.join(w, r)).reduced() for r in ["CMEM"] + routes}
    eff = {q: [] for q in CONVEX_STAGES}
    worst = {q: 0.0 for q in CONVEX_STAGES}
    for k in range(len(g)):
        full(g=g[k], e=e[k], mu=mu[k])
        ests, flags = {}, {}
        for r, red in reds.items():
            red(g=g[k], e=e[k], mu=mu[k])
            for q in CONVEX_STAGES:
                info = red.estimate_info(q)
                ests[r, q] = info["estimate"]
                flags[r, q] = (info["bound"], info["outside"], info["roundoff"])
                err = np.linalg.norm(np.asarray(full.get(q)).ravel() - keep.basis(q) @ red.coords(q))
                if not ests[r, q] >= 0.5 * err:
                    fail("convex room, %s, sample %d, stage %s: estimate %.3g, true error %.3g" % (r, k, q, ests[r, q], err))
                if r == "CMEM":
                    eff[q].append(ests[r, q] / err)
        for r in routes:
            for q in CONVEX_STAGES:
                worst[q] = max(worst[q], abs(ests[r, q] - ests["CMEM", q]) / ests["CMEM", q])
                if flags[r, q] != flags["CMEM", q]:
                    fail("convex room, %s, sample %d, stage %s: flags (bound, outside, roundoff) %s, in memory %s" %
                         (r, k, q, flags[r, q], flags["CMEM", q]))
    print("convex room: bounds: %s" % (" ".join(q for q in CONVEX_STAGES if flags["CMEM", q][0]) or "none"))
    print("convex room: effectivity %s" % ", ".join("%s %.3g .. %.3g" % (q, min(eff[q]), max(eff[q])) for q in CONVEX_STAGES))
    print("convex room: estimates out of core (%s) within %s of the in-memory model's (relative)" %
          (" ".join(routes), ", ".join("%s %.2g" % (q, worst[q]) for q in CONVEX_STAGES)))
    if not max(worst.values()) <= 1e-8:
        fail("the convex room's out-of-core estimates differ from the in-memory ones by %.3g (relative)" % max(worst.values()))


def main():
    rdata = os.path.join(B, "radiosity_data")
    with tempfile.TemporaryDirectory() as w:
        subprocess.run([rdata, w + "/RT", "24", "20", "0", "1", "1"], check=True, capture_output=True, env=child_env())
        subprocess.run([rdata, w + "/TEST", "24", "6", "0", "1", "7"], check=True, capture_output=True, env=child_env())
        convex(w + "/RT", w + "/TEST", w)
        run("train", PROG, w + "/RT", "--cap", "8", "-o", w + "/MEM")
        run("train", PROG, w + "/RT", "--cap", "8", "--mem", "8k", "-o", w + "/OOC")
        run("train", PROG, w + "/RT", "--cap", "8", "--keep-bases", "all", "-o", w + "/KEEP")
        if "{s,h}" not in open(os.path.join(w, "OOC", "manifest")).read():
            fail("no class named {s,h} in the manifest")
        compare_tables(w + "/MEM", w + "/OOC")
        if "--mpi" in sys.argv[2:]:  # ctest passes it in a build with MPI
            train_over_ranks(w + "/RT", w + "/MPI")
            compare_tables(w + "/MEM", w + "/MPI")
        prog = npg.compile(PROG)
        full = prog.full(params={n: np.load("%s/RT/%s.npy" % (w, n)) for n in ("tri", "rho")})
        g, e, v = (np.load("%s/TEST/%s.npy" % (w, n)) for n in "gev")
        keep = npg.load(prog, w + "/KEEP")
        reds = {r: npg.load(prog, w + "/" + r).reduced() for r in ("MEM", "OOC")}
        eff = {(r, q): [] for r in reds for q in STAGES}
        worst = 0.0
        for k in range(len(g)):
            full(g=g[k], e=e[k], v=v[k])
            est = {}
            for r, red in reds.items():
                red(g=g[k], e=e[k])
                for q in STAGES:
                    est[r, q] = red.estimate(q)
                    err = np.linalg.norm(np.asarray(full.get(q)).ravel() - keep.basis(q) @ red.coords(q))
                    if not est[r, q] >= 0.5 * err:
                        fail("%s, sample %d, stage %s: estimate %.3g, true error %.3g" % (r, k, q, est[r, q], err))
                    eff[r, q].append(est[r, q] / err)
            for q in STAGES:
                worst = max(worst, abs(est["OOC", q] - est["MEM", q]) / est["MEM", q])
        for r in reds:
            print("%s: effectivity %s" % (r, ", ".join("%s %.3g .. %.3g" % (q, min(eff[r, q]), max(eff[r, q])) for q in STAGES)))
        print("estimates out of core within %.2g of the in-memory model's (relative)" % worst)
        if not worst <= 1e-9:
            fail("the out-of-core estimates differ from the in-memory ones by %.3g (relative)" % worst)
    print("ok")


main()
