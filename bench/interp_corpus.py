"""interp_corpus.py BUILD_DIR — issue 26's first goal measured on every program of the corpus with
a stage eligible for interpolation (`npgc check P` prints "interpolation: eligible"): at the
default settings, is the output error within 2x its projection floor, and no worse than Galerkin
alone? SEEDS="1 3 5 7" (the default) the data's seeds: training seed s, held-out s + 1; the
detailed tables are the first seed's, the summary has one column per seed.

For each program: training samples (100) and held-out ones (20, another seed) with inputs
varying smoothly over a few random modes around a positive base (so roots and divisions are
defined) and valid params (dims, index tables); bodies and springs from bench/interp/data.py.
Then `npgc train P TR -o M` (the default: the automatic choice, which holds every 10th sample
out since there is no extern and >= 30 samples), `npgc train P TR -o G --valid none` (Galerkin
alone), `npgc verify P M TE --tol 1e9` and the same for G. One row per program (several outputs:
the one furthest above its floor). Then both again with every member at energy 0.999 (`--basis
'*:energy=0.999'`, the default before the quantities under a power were kept whole, DESIGN §12).
Run with /usr/bin/python3; about a minute on 2 cores."""
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
S_TRAIN, S_TEST = 100, 20
# training data's seeds (held out: seed + 1); the detailed table is the first one's
SEEDS = [int(t) for t in os.environ.get("SEEDS", "1 3 5 7").split()]
TIE = 0.02  # training's tie rule: output errors within 2 % go to the cheaper reduction
ROUNDING = 1e-12  # a relative error below this is rounding (a full-rank basis)


def modes_1d(n, k=4):
    """k smooth modes over n entries (sines of increasing frequency)."""
    t = (np.arange(n) + 0.5) / n
    return np.array([np.sin((j + 1) * np.pi * t + 0.3 * j) for j in range(k)])


def smooth(rng, S, n, base, amp, k=4):
    """S samples of base + amp * (combination of k smooth modes over n entries, coefficients uniform
    in [-1, 1]): within base ± k·amp, so a positive base above k·amp keeps every entry positive."""
    return base + amp * rng.uniform(-1, 1, size=(S, k)) @ modes_1d(n, k)


def tiny(rng, S, n):
    """S samples of n scalars uniform in [0.5, 2] (examples/rational/gen_data.c's range)."""
    return 0.5 + 1.5 * rng.random((S, n))


def data_py(kind, out, S, seed):
    subprocess.run([sys.executable, os.path.join(ROOT, "bench/interp/data.py"), kind, out, str(S), str(seed)], check=True)


def grid_mesh(n):
    """An n x n vertex grid in the unit square split into triangles; nbr[f, k] is the face across
    the edge (tri[f, k], tri[f, k+1]), -1 on the boundary."""
    tri = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            tri.append((a, a + 1, a + n + 1))
            tri.append((a, a + n + 1, a + n))
    tri = np.array(tri, dtype=np.int64)
    owner = {}
    for f, t in enumerate(tri):
        for k in range(3):
            owner.setdefault(frozenset((t[k], t[(k + 1) % 3])), []).append(f)
    nbr = np.full_like(tri, -1)
    for f, t in enumerate(tri):
        for k in range(3):
            others = [g for g in owner[frozenset((t[k], t[(k + 1) % 3]))] if g != f]
            if others:
                nbr[f, k] = others[0]
    g0 = np.array([[i / (n - 1), j / (n - 1), 0.0] for i in range(n) for j in range(n)])
    return tri, nbr, g0


# Each generator writes the program's params and inputs (name.npy) into d: S samples, seed.
def gen_deforming_springs(d, S, seed):
    data_py("springs:8", d, S, seed)


def gen_spring_two_terms(d, S, seed):
    data_py("springs:8", d, S, seed)
    os.rename(f"{d}/x.npy", f"{d}/g.npy")
    E = np.load(f"{d}/edge.npy").shape[0]
    np.save(f"{d}/k.npy", 1.0 + 0.5 * np.random.default_rng(5).random(E))


def gen_cloth(d, S, seed):
    # data.py's springs without the diagonals, so that every vertex has at most 4 springs (inc: V x 4)
    data_py("springs:8", d, S, seed)
    X, E, L0 = np.load(f"{d}/x.npy"), np.load(f"{d}/edge.npy"), np.load(f"{d}/L0.npy")
    n = 8
    keep = (E[:, 1] - E[:, 0] == 1) | (E[:, 1] - E[:, 0] == n)
    E, L0 = E[keep], L0[keep]
    V = X.shape[1]
    inc, sgn = np.full((V, 4), -1, dtype=np.int64), np.zeros((V, 4))
    cnt = np.zeros(V, dtype=int)
    for e, (a, b) in enumerate(E):
        for v, s in ((a, 1.0), (b, -1.0)):
            inc[v, cnt[v]], sgn[v, cnt[v]] = e, s
            cnt[v] += 1
    for name, a in (("edge", E), ("L0", L0), ("inc", inc), ("sgn", sgn), ("k", np.array(40.0))):
        np.save(f"{d}/{name}.npy", a)


def gen_nbody_small(d, S, seed):  # the regime: small motions (bench/interp.md)
    data_py("nbody:64:0.01:0.02:0.3", d, S, seed)


def gen_nbody_large(d, S, seed):  # large motions, any rotation
    data_py("nbody:64:0.1", d, S, seed)


def gen_lj(d, S, seed):
    data_py("lj:64", d, S, seed)


def gen_guarded(d, S, seed):
    tri, nbr, g0 = grid_mesh(4)  # F 18, V 16
    rng = np.random.default_rng(seed)
    V, F, K = g0.shape[0], tri.shape[0], 3
    mv = np.random.default_rng(11).normal(size=(4, V, 3)) * 0.05
    g = g0 + np.einsum("sk,kvc->svc", rng.normal(size=(S, 4)), mv)
    g[:, :, 2] += 1.0
    np.save(f"{d}/g.npy", g)
    np.save(f"{d}/u.npy", smooth(rng, S, F, 1.5, 0.2))
    np.save(f"{d}/tri.npy", tri)
    np.save(f"{d}/nbr.npy", nbr)
    np.save(f"{d}/w.npy", np.array([0.5, 0.3, 0.2]))
    assert K == 3


def gen_if_division(d, S, seed):
    rng, N = np.random.default_rng(seed), 40
    np.save(f"{d}/mask.npy", (np.arange(N) % 3 != 0).astype(np.int64))
    np.save(f"{d}/x.npy", smooth(rng, S, N, 1.0, 0.3))
    np.save(f"{d}/z.npy", smooth(rng, S, N, 2.0, 0.3))


def gen_negative_power_named(d, S, seed):
    rng, F = np.random.default_rng(seed), 20
    np.save(f"{d}/x.npy", smooth(rng, S, F, 1.0, 0.4))
    m = modes_1d(F, 3)
    c = rng.normal(size=(S, 3, 3))
    np.save(f"{d}/d.npy", 1.0 + 0.3 * np.einsum("sab,ai,bj->sij", c, m, m))


def gen_nested_division(d, S, seed):
    np.save(f"{d}/x.npy", tiny(np.random.default_rng(seed), S, 2))


def gen_vector_literal(d, S, seed):
    np.save(f"{d}/x.npy", tiny(np.random.default_rng(seed), S, 2))


def gen_rational(d, S, seed):
    np.save(f"{d}/x.npy", tiny(np.random.default_rng(seed), S, 2))


def gen_rational_power(d, S, seed):
    np.save(f"{d}/x.npy", smooth(np.random.default_rng(seed), S, 50, 2.0, 0.4))


def gen_row_kernels(d, S, seed):
    rng, N = np.random.default_rng(seed), 30
    np.save(f"{d}/x.npy", smooth(rng, S, N, 1.0, 0.4))
    np.save(f"{d}/y.npy", smooth(rng, S, N, 1.5, 0.4))


def gen_scalar_param(d, S, seed):
    np.save(f"{d}/eps.npy", np.array(0.1))
    np.save(f"{d}/x.npy", smooth(np.random.default_rng(seed), S, 50, 1.0, 0.4))


def gen_sqrt_stage(d, S, seed):
    rng, N = np.random.default_rng(seed), 50
    np.save(f"{d}/x.npy", np.stack([smooth(rng, S, N, 1.5, 0.3), smooth(rng, S, N, 1.0, 0.3)], axis=-1))


# (row name, program, generator, what the data are); the second table retrains every row with every
# member at 0.999, the default before the quantities under a power were kept whole (npgc check lists
# them), to tell how much of the error their truncation causes
PROGRAMS = [
    ("deforming_springs", "tests/programs/deforming_springs.npg", gen_deforming_springs, "data.py springs:8"),
    ("guarded_reads_in_loop_nests", "tests/programs/guarded_reads_in_loop_nests.npg", gen_guarded,
     "4x4 triangulated grid (F 18), g moved by 4 modes, u 1.5 + 4 modes, K 3"),
    ("if_division_branch", "tests/programs/if_division_branch.npg", gen_if_division, "N 40, z 2 + modes"),
    ("nbody_gravity (small motions)", "tests/programs/nbody_gravity.npg", gen_nbody_small,
     "data.py nbody:64:0.01:0.02:0.3"),
    ("nbody_gravity (large motions)", "tests/programs/nbody_gravity.npg", gen_nbody_large, "data.py nbody:64:0.1"),
    ("negative_power_named", "tests/programs/negative_power_named.npg", gen_negative_power_named, "F 20"),
    ("nested_division", "tests/programs/nested_division.npg", gen_nested_division, "x in [0.5, 2]^2"),
    ("rational_power", "tests/programs/rational_power.npg", gen_rational_power, "N 50, x 2 + modes"),
    ("row_kernels", "tests/programs/row_kernels.npg", gen_row_kernels, "N 30"),
    ("scalar_param", "tests/programs/scalar_param.npg", gen_scalar_param, "N 50, eps 0.1"),
    ("spring_two_terms", "tests/programs/spring_two_terms.npg", gen_spring_two_terms,
     "data.py springs:8, k in [1, 1.5]"),
    ("sqrt_stage", "tests/programs/sqrt_stage.npg", gen_sqrt_stage, "N 50"),
    ("vector_literal_mixed_operators", "tests/programs/vector_literal_mixed_operators.npg", gen_vector_literal,
     "x in [0.5, 2]^2"),
    ("cloth (examples/embed)", "examples/embed/cloth.npg", gen_cloth, "data.py springs:8 without diagonals, k 40"),
    ("rational (examples/rational)", "examples/rational/rational.npg", gen_rational, "x in [0.5, 2]^2"),
    ("lennard_jones (bench/interp)", "bench/interp/lennard_jones.npg", gen_lj, "data.py lj:64"),
]

FLOAT = r"[-+0-9.eE]+|nan|inf|-inf"


def npgc(build, *args):
    r = subprocess.run([os.path.join(build, "npgc"), *args], capture_output=True, text=True)
    return r.returncode, r.stdout + r.stderr


def eligible(build, prog):
    _, out = npgc(build, "check", prog)
    return re.findall(r"--reduce (\S+):interp", out)


def outputs(verify_text):
    """{output name: (L2 error, floor)} from verify's table rows marked (output)."""
    res = {}
    for line in verify_text.splitlines():
        if line.rstrip().endswith("(output)"):
            f = line.split()
            nums = [t for t in f if re.fullmatch(FLOAT, t)]
            # m, L2 error, floor, own, max L2, Linf error, Linf floor
            res[f[0]] = (float(nums[-6]), float(nums[-5]))
    return res


def choices(train_text):
    """'w: interp' / 'w: galerkin' per stage from train's `stage X:` lines."""
    res = []
    for line in train_text.splitlines():
        m = re.match(r"stage (\S+): (.*)", line)
        if m:
            how = "interp" if m.group(2).startswith("interpolated") else "galerkin"
            why = re.search(r": ([^:]*)$", m.group(2))
            res.append(f"{m.group(1)}: {how}" + (f" ({why.group(1).strip()})" if why else ""))
    return res


def last_line(text):
    lines = text.strip().splitlines()
    return lines[-1] if lines else "(no output)"


def measure(build, prog, tr, te, w, extra):
    """Train the default and the Galerkin-alone model (with `extra` options) and verify each on te.
    {"choice": [...], "default"/"galerkin": {output: (error, floor)} or the failure's message}."""
    res = {"choice": []}
    for key, opts in (("default", []), ("galerkin", ["--valid", "none"])):
        model = os.path.join(w, key)
        rc, t = npgc(build, "train", prog, tr, "-o", model, *opts, *extra)
        if key == "default":
            res["choice"] = choices(t)
        if rc:
            res[key] = "train failed: " + last_line(t)
            continue
        rc, v = npgc(build, "verify", prog, model, te, "--tol", "1e9")
        o = outputs(v)
        res[key] = o if (rc == 0 and o) else "verify failed: " + last_line(v)
    return res


def bench_seconds(build, prog, model, te):
    """npgc bench's median seconds per sample: (full, reduced), or None when it fails."""
    rc, b = npgc(build, "bench", prog, model, te)
    full = re.search(r"^full evaluation\s+(" + FLOAT + r") s per sample", b, re.M)
    red = re.search(r"^reduced evaluation\s+(" + FLOAT + r") s per sample", b, re.M)
    return (float(full.group(1)), float(red.group(1))) if rc == 0 and full and red else None


def each_way(build, prog, tr, te, w, stages):
    """The output error, floor and reduced time per sample of the program with every eligible stage
    reduced by Galerkin (--valid none) and by interpolation (--reduce S:interp each), and the full
    evaluation's time: {"galerkin"/"interp": (output, error, floor, seconds) or a message, "full": s}."""
    res = {"full": None}
    for key, opts in (("galerkin", ["--valid", "none"]),
                      ("interp", [a for st in stages for a in ("--reduce", f"{st}:interp")])):
        model = os.path.join(w, "each." + key)
        rc, t = npgc(build, "train", prog, tr, "-o", model, *opts)
        if rc:
            res[key] = "train failed: " + last_line(t)
            continue
        rc, v = npgc(build, "verify", prog, model, te, "--tol", "1e9")
        o = outputs(v)
        if rc or not o:
            res[key] = "verify failed: " + last_line(v)
            continue
        secs = bench_seconds(build, prog, model, te)
        if secs is None:
            res[key] = "bench failed"
            continue
        res["full"] = secs[0]
        res[key] = (*worst(o), secs[1])
    return res


def each_way_row(name, r):
    g, i, full = r["galerkin"], r["interp"], r["full"]
    if isinstance(g, str) or isinstance(i, str):
        return f"| {name} | {g if isinstance(g, str) else ''} {i if isinstance(i, str) else ''} | | | | | |"
    return (f"| {name} | {g[0]}: {g[2]:.3e} | {g[1]:.3e} ({ratio(g[1], g[2])}) | {i[1]:.3e} ({ratio(i[1], i[2])}) | "
            f"{full:.2e} | {g[3]:.2e} ({full / g[3]:.1f}×) | {i[3]:.2e} ({full / i[3]:.1f}×) |")


def worst(o):
    """The output furthest above its floor: (name, error, floor)."""
    k = max(o, key=lambda k: (o[k][0] / o[k][1]) if o[k][1] >= ROUNDING else 0.0)
    return k, o[k][0], o[k][1]


def ratio(err, floor):
    return "—" if floor < ROUNDING else f"{err / floor:.2f}×"


def verdict(r):
    """(≤ 2x floor, ≤ Galerkin) as cells, and the row's outcome (True: goal met)."""
    d, g = r["default"], r["galerkin"]
    if isinstance(d, str):
        return "**no** (fails)", "—", False
    _, ed, fd = worst(d)
    meets = ed <= 2 * fd or (fd < ROUNDING and ed < ROUNDING)
    if isinstance(g, str):
        return ("yes" if meets else "**no**"), "yes (Galerkin fails)", meets
    rel = [d[k][0] / g[k][0] if g[k][0] > 0 else 1.0 for k in d]
    rounding = all(d[k][0] < ROUNDING and g[k][0] < ROUNDING for k in d)
    if all(x <= 1 for x in rel) or rounding:
        cmp, ok = "yes", True
    elif all(x <= 1 + TIE for x in rel):
        cmp, ok = "**no**, within the 2 % tie", False
    else:
        cmp, ok = "**no**", False
    cmp += " (" + "; ".join(f"{x:.3f}" for x in rel) + ")" + (" rounding" if rounding else "")
    return ("yes" if meets else "**no**"), cmp, meets and ok


def cell(o):
    if isinstance(o, str):
        return o
    k, e, f = worst(o)
    return f"{k}: {e:.3e} / {f:.3e} ({ratio(e, f)})"


def short(r):
    """A summary cell: default's ratio to its floor, to Galerkin's error, or the failure."""
    d, g = r["default"], r["galerkin"]
    how = "/".join(c.split(" (")[0].split(": ")[1] for c in r["choice"]) or "?"
    if isinstance(d, str):
        gs = "Galerkin fails too" if isinstance(g, str) else f"Galerkin {ratio(*worst(g)[1:])}"
        return f"**fails** ({how}: {d.split(':')[0]}; {gs})"
    k, e, f = worst(d)
    _, _, ok = verdict(r)
    if isinstance(g, str):
        rel = "Galerkin fails"
    elif e < ROUNDING and g[k][0] < ROUNDING:
        rel = "rounding"
    else:
        rel = f"{e / g[k][0]:.3f}" if g[k][0] > 0 else "—"
    return f"{ratio(e, f)}, {rel} ({how})" + ("" if ok else " **✗**")


HEAD = ("| program | eligible | choice (train) | default: output error / floor (×) | "
        "Galerkin alone: output error / floor (×) | default ≤ 2× floor | default ≤ Galerkin (ratio) |\n"
        "|---|---|---|---|---|---|---|")


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: interp_corpus.py BUILD_DIR")
    build = os.path.abspath(sys.argv[1])
    if not os.access(os.path.join(build, "npgc"), os.X_OK):
        sys.exit(f"interp_corpus.py: {build}/npgc: not found or not executable")
    os.chdir(ROOT)
    work = tempfile.mkdtemp(prefix="npg_corpus26_")
    t0 = time.time()
    try:
        results = {}  # (row, seed, energy1) -> measure()
        for seed in SEEDS:
            for i, (name, prog, gen, what) in enumerate(PROGRAMS):
                w = os.path.join(work, f"{seed}.{i}")
                tr, te = os.path.join(w, "TR"), os.path.join(w, "TE")
                os.makedirs(tr)
                os.makedirs(te)
                gen(tr, S_TRAIN, seed)
                gen(te, S_TEST, seed + 1)
                results[i, seed, False] = measure(build, prog, tr, te, w, [])
                results[i, seed, True] = measure(build, prog, tr, te, w, ["--basis", "*:energy=0.999"])
                if seed == SEEDS[0]:
                    results[i, seed, "each"] = each_way(build, prog, tr, te, w, eligible(build, prog))
                shutil.rmtree(w)
        s0 = SEEDS[0]
        for e1 in (False, True):
            if not e1:
                print(f"At the default settings ({S_TRAIN} training samples, {S_TEST} held out; seeds {s0} and {s0 + 1}):\n")
                print(HEAD)
            else:
                print(f"\nThe same data, every member at energy 0.999 (--basis '*:energy=0.999': the default before "
                      f"the quantities under a power were kept whole):\n")
                print(HEAD.replace("| program |", "| program (all at 0.999) |"))
            for i, (name, prog, gen, what) in enumerate(PROGRAMS):
                if (i, s0, e1) not in results:
                    continue
                r = results[i, s0, e1]
                a, b, _ = verdict(r)
                label = name
                print(f"| {label} | {', '.join(eligible(build, prog))} | {'; '.join(r['choice'])} | {cell(r['default'])} | "
                      f"{cell(r['galerkin'])} | {a} | {b} |")
        print(f"\nEach program, every eligible stage by Galerkin (--valid none) and by interpolation (--reduce S:interp "
              f"each), seeds {s0} and {s0 + 1}: the output's floor, each way's output error (× the floor), and the "
              f"reduced evaluation's median time per sample (npgc bench; × faster than the full evaluation):\n")
        print("| program | output: floor | Galerkin error | interpolation error | full s/sample | Galerkin s/sample | "
              "interpolation s/sample |\n|---|---|---|---|---|---|---|")
        for i, (name, prog, gen, what) in enumerate(PROGRAMS):
            print(each_way_row(name, results[i, s0, "each"]))
        print(f"\nEvery seed: the default's output error over its floor, over Galerkin alone's (worst output), "
              f"the choice; ✗ where the goal is missed.\n")
        print("| program | setting | " + " | ".join(f"seed {s}" for s in SEEDS) + " | goal met |")
        print("|---|---|" + "---|" * len(SEEDS) + "---|")
        met = {False: 0, True: 0}
        for e1 in (False, True):
            for i, (name, prog, gen, what) in enumerate(PROGRAMS):
                if (i, s0, e1) not in results:
                    continue
                rs = [results[i, s, e1] for s in SEEDS]
                ok = sum(verdict(r)[2] for r in rs)
                met[e1] += ok == len(SEEDS)
                print(f"| {name} | {'all at 0.999' if e1 else 'default'} | " +
                      " | ".join(short(r) for r in rs) + f" | {ok}/{len(SEEDS)} |")
        print(f"\ngoal met on every seed: {met[False]} of {len(PROGRAMS)} rows at the default settings; "
              f"{met[True]} of {len(PROGRAMS)} with every member at 0.999")
        print(f"\n{time.time() - t0:.0f} s; data: " + "; ".join(f"{n}: {w}" for n, _, _, w in PROGRAMS))
        fails = [(PROGRAMS[i][0], s, e1, k, r[k]) for (i, s, e1), r in results.items() if e1 != "each"
                 for k in ("default", "galerkin") if isinstance(r[k], str)]
        for name, s, e1, k, msg in fails:
            print(f"\nfailure: {name}, seed {s}{', all at 0.999' if e1 else ''}, {k} model: {msg}")
    finally:
        shutil.rmtree(work)


main()
