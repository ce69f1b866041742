"""pymor_thermalblock.py — npg against pyMOR on pyMOR's own thermal block, in one run (issue 41).

Run by bench/pymor_thermalblock.sh, which sets PYTHONPATH to pyMOR's sources:

    python3 bench/pymor_thermalblock.py NPGC OUT --blocks 2x2 --grid 100 --snapshots 5 \
        --test 100 --sizes 20,30 [--greedy-tol 1e-6] [--greedy-budget 200] [--no-greedy] [--seed 0]

1. pyMOR discretizes the problem (discretize_stationary_cg, diameter 1/grid) and the matrices
   are exported as the params of examples/thermalblock/thermalblock.npg (K_b, K_q, the H¹₀
   product H in one padded row pattern, f) in OUT/data/ and OUT/test/ (.npy);
2. the training parameters are pyMOR's POD's (parameter_space.sample_uniformly(snapshots)),
   the test ones --test random parameters (sample_randomly, seeded): the same for both tools;
3. pyMOR: the full solves of the training and test parameters (timed), POD in the H¹₀ product
   at each size (CoerciveRBReductor, as its demo), the reduced solves (timed), the reduced solves
   with their estimate (rom.solve(mu, return_error_estimate=True), timed) and the errors, and its
   weak greedy (rb_greedy with its estimator, atol --greedy-tol): the full solves it needed;
4. npg: `npgc train` on the same training parameters at the same sizes (n POD vectors of u,
   uncentered and untruncated as pyMOR's POD, and f's direction, which u's class holds too:
   class m = n + 1), `npgc eval` of the test parameters and its online estimate (in the H¹₀
   product, as pyMOR's), `npgc bench` for the full and reduced times, and the reduced evaluation
   followed by u's estimate ("reduced + estimate": npg_reduced_estimate after each evaluation);
5. both tools' errors measured here alike against pyMOR's full solutions: the H¹₀ seminorm
   of u − u_rb, absolute and relative to the solution's.

6. npg's greedy training (npg_estimate_greedy): from one of the training parameters over all
   of them, `--tol --greedy-tol --absolute` (the estimate in the H¹₀ norm, as pyMOR's atol),
   u's cap and the budget --greedy-budget (pyMOR's greedy has none: 138 on 3 x 3 at grid 19),
   its full evaluations, its model's estimate effectivity and error on the test parameters; a
   refusal is printed as such. --no-greedy leaves both tools' greedy out (pyMOR's weak greedy
   over 512 candidates at --grid 100 takes over 50 minutes): the rest of the table is unchanged.

Prints the table and writes OUT/results.json. Columns of features npgc does not have print
"n/a (not built)".
"""
import argparse
import json
import os
import re
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PROG = os.path.join(ROOT, "examples", "thermalblock", "thermalblock.npg")


def padded_sparse(mats):
    """The scipy sparse matrices (n x n) in one padded row pattern: cols (int64, -1 padding)
    and each matrix's values in it."""
    import scipy.sparse as sp
    pattern = sum(abs(sp.csr_matrix(m)) for m in mats).tocsr()
    pattern.sort_indices()
    n = pattern.shape[0]
    counts = np.diff(pattern.indptr)
    w = int(counts.max())
    rows = np.repeat(np.arange(n), counts)
    slot = np.arange(pattern.nnz) - np.repeat(pattern.indptr[:-1], counts)
    cols = -np.ones((n, w), dtype=np.int64)
    cols[rows, slot] = pattern.indices
    vals = []
    for m in mats:
        v = np.zeros((n, w))
        v[rows, slot] = np.asarray(sp.csr_matrix(m)[rows, pattern.indices]).ravel()
        vals.append(v)
    return cols, vals


def export(fom, folder, mus):
    """The program's params from pyMOR's matrices, and `mu` for `mus`."""
    op = fom.operator
    kb, kq = None, {}
    for o, c in zip(op.operators, op.coefficients):
        if isinstance(c, (int, float)):
            kb = o.matrix * c if kb is None else kb + o.matrix * c
        else:
            kq[c.index] = o.matrix
    q = len(kq)
    h = fom.h1_0_semi_product.matrix
    f = fom.rhs.as_range_array().to_numpy().ravel()
    cols, vals = padded_sparse([kb, *[kq[i] for i in range(q)], h])
    os.makedirs(folder, exist_ok=True)
    np.save(os.path.join(folder, "cols.npy"), cols)
    np.save(os.path.join(folder, "a0.npy"), vals[0])
    np.save(os.path.join(folder, "a.npy"), np.stack(vals[1:-1]))
    np.save(os.path.join(folder, "h.npy"), vals[-1])
    np.save(os.path.join(folder, "f.npy"), f)
    np.save(os.path.join(folder, "mu.npy"), np.array([m["diffusion"] for m in mus], dtype=float))
    return h


def run(cmd):
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)}: exit {r.returncode}\n{r.stdout}{r.stderr}")
    return r.stdout + r.stderr, time.perf_counter() - t


def h1_errors(H, U, V):
    """Per sample (rows): ‖U − V‖_H and ‖U‖_H."""
    E = U - V
    return np.sqrt(np.einsum("ij,ij->i", E, (H @ E.T).T)), np.sqrt(np.einsum("ij,ij->i", U, (H @ U.T).T))


def pymor_side(fom, ps, train, test, sizes, greedy_tol, greedy=True):
    from pymor.algorithms.greedy import rb_greedy
    from pymor.algorithms.pod import pod
    from pymor.parameters.functionals import ExpressionParameterFunctional
    from pymor.reductors.coercive import CoerciveRBReductor
    product = fom.h1_0_semi_product
    coercivity = ExpressionParameterFunctional("min(diffusion)", fom.parameters)
    t = time.perf_counter()
    snaps = fom.solution_space.empty()
    for mu in train:
        snaps.append(fom.solve(mu))
    train_solve = (time.perf_counter() - t) / len(train)
    U, full_times = [], []
    for mu in test:
        t = time.perf_counter()
        U.append(fom.solve(mu).to_numpy().ravel())
        full_times.append(time.perf_counter() - t)
    U = np.array(U)
    out = {"full_solve_s": float(np.median(full_times)), "train_full_solve_s": train_solve, "sizes": {}}
    for n in sizes:
        modes, svals = pod(snaps, modes=n, product=product)
        red = CoerciveRBReductor(fom, RB=modes, product=product, coercivity_estimator=coercivity,
                                 check_orthonormality=False)
        rom = red.reduce()
        V, times, times_est, eff = [], [], [], []
        for mu in test:
            t = time.perf_counter()
            u = rom.solve(mu)
            times.append(time.perf_counter() - t)
            V.append(red.reconstruct(u).to_numpy().ravel())
            # the solve with its estimate in one call (pyMOR's compute: one solve, then the estimator)
            t = time.perf_counter()
            _, e = rom.solve(mu, return_error_estimate=True)
            times_est.append(time.perf_counter() - t)
            eff.append(float(e[0]))
        V = np.array(V)
        out["sizes"][n] = {"m": len(modes), "V": V, "online_s": float(np.median(times)),
                           "online_est_s": float(np.median(times_est)), "estimates": np.array(eff)}
    if not greedy:
        out["greedy_full_solves"], out["greedy_max_estimate"] = None, float("nan")
        return U, out
    red = CoerciveRBReductor(fom, product=product, coercivity_estimator=coercivity, check_orthonormality=False)
    # its weak greedy over the same training parameters, as its demo (pyMOR's estimator, H¹₀ norm)
    g = rb_greedy(fom, red, train, use_error_estimator=True, error_norm=fom.h1_0_semi_norm, atol=greedy_tol,
                  max_extensions=200)
    out["greedy_full_solves"] = int(g["extensions"])
    out["greedy_max_estimate"] = float(g["max_errs"][-1]) if len(g["max_errs"]) else float("nan")
    return U, out


def npg_side(npgc, out, sizes):
    res = {}
    data, test = os.path.join(out, "data"), os.path.join(out, "test")
    for n in sizes:
        model, pred = os.path.join(out, f"npg_model_{n}"), os.path.join(out, f"npg_out_{n}")
        # as pyMOR's POD: uncentered, no energy threshold, n POD vectors of u; u's class also
        # holds its numerator f's direction (DESIGN §4), so that m = n + 1
        text, train_s = run([npgc, "train", PROG, data, "-o", model, "--center", "off", "--basis",
                             f"u:cap={n},energy=1", "--basis", "u.num1:cap=1"])
        m = int(re.search(r"^\{u\}\s+\d+\s+(\d+)", text, re.M).group(1))
        run([npgc, "eval", PROG, model, test, "-o", pred])
        est = np.load(os.path.join(pred, "u.estimate.npy")).ravel()
        bench, _ = run([npgc, "bench", PROG, model, test, "--reps", "3"])
        full = float(re.search(r"full evaluation\s+([0-9.e+-]+) s", bench).group(1))
        alone = float(re.search(r"reduced alone\s+([0-9.e+-]+) s", bench).group(1))
        # the reduced evaluation then u's estimate (npg_reduced_estimate), timed together per sample
        with_est = re.search(r"reduced \+ estimate\s*([0-9.e+-]+) s", bench)
        res[n] = {"m": m, "V": np.load(os.path.join(pred, "u.npy")), "train_s": train_s, "online_s": alone,
                  "online_est_s": float(with_est.group(1)) if with_est else float("nan"),
                  "full_solve_s": full, "estimates": est}
    return res


def has_feature(npgc, command, option):
    r = subprocess.run([npgc, command, "--help"], capture_output=True, text=True)
    return option in r.stdout + r.stderr


def npg_estimate_greedy(npgc, out, n, tol, U, H):
    """npg's greedy training (issue 41, docs/estimates.md) as pyMOR's weak greedy: u's basis in
    the H¹₀ product (the program's `basis u: product H`), uncentered, from pyMOR's first training
    parameter over its training parameters as the pool, `--tol` absolute (`--absolute`: the
    estimate itself, in H's norm, as pyMOR's atol), u's cap n (each chosen sample may add a
    direction), budget n; then its model's estimate effectivity (estimate / true H¹₀ error) and
    max error on the test parameters. A refusal is returned in place of the figures."""
    data, test = os.path.join(out, "data"), os.path.join(out, "test")
    start, pool = os.path.join(out, "greedy_start"), os.path.join(out, "greedy_pool")
    os.makedirs(start, exist_ok=True)
    os.makedirs(pool, exist_ok=True)
    for name in os.listdir(data):
        if name != "mu.npy":
            np.save(os.path.join(start, name), np.load(os.path.join(data, name)))
    mu = np.load(os.path.join(data, "mu.npy"))
    np.save(os.path.join(start, "mu.npy"), mu[:1])
    np.save(os.path.join(pool, "mu.npy"), mu)
    model = os.path.join(out, "npg_greedy")
    cmd = [npgc, "train", PROG, start, "--greedy", pool, "--tol", f"{tol:g}", "--absolute", "--budget", str(n),
           "-o", model, "--center", "off", "--basis", f"u:cap={n},energy=1", "--basis", "u.num1:cap=1"]
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    if r.returncode != 0:
        why = (r.stdout + r.stderr).strip().splitlines()[-1]
        return {"refused": why}
    manifest = open(os.path.join(model, "manifest")).read()
    line = next((ln for ln in manifest.splitlines() if ln.startswith("greedy")), "")
    samples = int(re.search(r"^samples (\d+)", manifest, re.M).group(1))  # one full evaluation each
    pred = os.path.join(out, "npg_greedy_out")
    run([npgc, "eval", PROG, model, test, "-o", pred])
    V, est = np.load(os.path.join(pred, "u.npy")), np.load(os.path.join(pred, "u.estimate.npy")).ravel()
    true, norm = h1_errors(H, U, V)
    eff = est / np.maximum(true, 1e-300)
    return {"full_solves": samples, "greedy_line": line.strip(), "seconds": seconds,
            "converged": " converged 1 " in line,
            "effectivity": [float(np.nanmin(eff)), float(np.nanmax(eff))],
            "max_err_h1": float(true.max()), "max_rel_h1": float((true / norm).max())}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("npgc")
    ap.add_argument("out")
    ap.add_argument("--blocks", default="2x2")
    ap.add_argument("--grid", type=int, default=100)
    ap.add_argument("--snapshots", type=int, default=5)
    ap.add_argument("--test", type=int, default=100)
    ap.add_argument("--sizes", default="20,30")
    ap.add_argument("--greedy-tol", type=float, default=1e-6)
    ap.add_argument("--greedy-budget", type=int, default=200)
    ap.add_argument("--no-greedy", action="store_true", help="leave both tools' greedy training out")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    xb, yb = (int(v) for v in a.blocks.split("x"))
    sizes = [int(v) for v in a.sizes.split(",")]
    from pymor.analyticalproblems.thermalblock import thermal_block_problem
    from pymor.core.logger import set_log_levels
    from pymor.discretizers.builtin import discretize_stationary_cg
    from pymor.tools.random import new_rng
    set_log_levels({"pymor": "WARN"})
    fom, _ = discretize_stationary_cg(thermal_block_problem(num_blocks=(xb, yb)), diameter=1.0 / a.grid)
    ps = fom.parameters.space(0.1, 1.0)
    train = ps.sample_uniformly(a.snapshots)
    with new_rng(a.seed):
        test = ps.sample_randomly(a.test)
    H = export(fom, os.path.join(a.out, "data"), train)
    export(fom, os.path.join(a.out, "test"), test)
    U, py = pymor_side(fom, ps, train, test, sizes, a.greedy_tol, greedy=not a.no_greedy)
    npg = npg_side(a.npgc, a.out, sizes)
    greedy = has_feature(a.npgc, "train", "--greedy")
    if a.no_greedy:
        est = {"refused": "not run (--no-greedy)"}
    else:
        est = npg_estimate_greedy(a.npgc, a.out, a.greedy_budget, a.greedy_tol, U, H) if greedy else {"refused": "not built"}
    na = "n/a (not built)" if not greedy else "not run" if a.no_greedy else "n/a (see below)" if "refused" in est else None
    rows, report = [], {"blocks": a.blocks, "grid": a.grid, "unknowns": int(U.shape[1]), "train": len(train),
                        "test": len(test), "sizes": {}}
    for n in sizes:
        e_py, norm = h1_errors(H, U, py["sizes"][n]["V"])
        e_npg, _ = h1_errors(H, U, npg[n]["V"])
        eff = py["sizes"][n]["estimates"] / np.maximum(e_py, 1e-300)
        eff_npg = npg[n]["estimates"] / np.maximum(e_npg, 1e-300)
        report["sizes"][n] = {
            "m_pymor": py["sizes"][n]["m"], "m_npg": npg[n]["m"],
            "max_err_pymor": float(e_py.max()), "max_err_npg": float(e_npg.max()),
            "max_rel_pymor": float((e_py / norm).max()), "max_rel_npg": float((e_npg / norm).max()),
            "pymor_effectivity": [float(eff.min()), float(eff.max())],
            "npg_effectivity": [float(np.nanmin(eff_npg)), float(np.nanmax(eff_npg))],
            "online_s_pymor": py["sizes"][n]["online_s"], "online_s_npg": npg[n]["online_s"],
            "online_est_s_pymor": py["sizes"][n]["online_est_s"], "online_est_s_npg": npg[n]["online_est_s"],
            "train_s_npg": npg[n]["train_s"]}
    report.update({"full_solve_s_pymor": py["full_solve_s"], "full_solve_s_npg": npg[sizes[0]]["full_solve_s"],
                   "greedy_full_solves_pymor": py["greedy_full_solves"], "greedy_tol": a.greedy_tol,
                   "npg_estimate_greedy": est})
    print(f"thermal block {a.blocks}, grid {a.grid} ({U.shape[1]} unknowns): {len(train)} training parameters "
          f"(pyMOR's POD's, {a.snapshots} per block), {len(test)} random test parameters; errors in the H¹₀ "
          f"seminorm against pyMOR's full solutions, max over the test parameters (absolute, relative)")
    print(f"{'':34s}{'npg':>28s}{'pyMOR':>28s}")
    for n in sizes:
        r = report["sizes"][n]
        print(f"{'max error at ' + str(n) + ' vectors':34s}{r['max_err_npg']:>14.3e} ({r['max_rel_npg']:.2e})"
              f"{r['max_err_pymor']:>14.3e} ({r['max_rel_pymor']:.2e})")
        print(f"{'  basis size (class m)':34s}{r['m_npg']:>28d}{r['m_pymor']:>28d}")
        print(f"{'  online solve (median)':34s}{r['online_s_npg']:>26.3e} s{r['online_s_pymor']:>26.3e} s")
        print(f"{'  online solve + estimate (median)':34s}{r['online_est_s_npg']:>26.3e} s"
              f"{r['online_est_s_pymor']:>26.3e} s")
        print(f"{'    npg solve + estimate against':34s}{r['online_s_pymor'] / r['online_est_s_npg']:>7.2f}x faster than "
              f"pyMOR's solve alone, {r['online_est_s_pymor'] / r['online_est_s_npg']:.2f}x than its solve + estimate")
        print(f"{'  estimate effectivity':34s}{'%.2f .. %.2f' % tuple(r['npg_effectivity']):>28s}"
              f"{'%.2f .. %.2f' % tuple(r['pymor_effectivity']):>28s}")
    print(f"{'full solve (median)':34s}{report['full_solve_s_npg']:>26.3e} s{report['full_solve_s_pymor']:>26.3e} s")
    npg_greedy = na if na else f"{est['full_solves']}{'' if est['converged'] else ' (budget)'} (abs. H¹₀)"
    py_greedy = "not run" if report["greedy_full_solves_pymor"] is None else \
        f"{report['greedy_full_solves_pymor']} (abs. H¹₀)"
    print(f"{'greedy full solves (tol %g)' % a.greedy_tol:34s}{npg_greedy:>28s}{py_greedy:>28s}")
    if na is None:
        print(f"{'  npg greedy model: effectivity':34s}{'%.2f .. %.2f' % tuple(est['effectivity']):>28s}"
              f"   (test parameters; max error {est['max_err_h1']:.3e} ({est['max_rel_h1']:.2e}); "
              f"greedy {est['seconds']:.0f} s)")
    elif greedy and not a.no_greedy:
        print(f"npg's estimate and greedy training: {est['refused']}")
    with open(os.path.join(a.out, "results.json"), "w") as fh:
        json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
