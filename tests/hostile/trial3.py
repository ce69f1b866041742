#!/usr/bin/python3
"""trial3.py BUILD_DIR [NAME...] — the third hostile trial: the features landed last.

Cases not in corpus.py or trial2.py, typed as a new user and as a hostile
one, against the features of issues 26, 29 and 30 and the Python module:

  sparse   operators written as index-table gathers (DESIGN §13) at sizes
           where the full evaluator takes the SuiteSparse path (>= 16 rows:
           trial2's six-cell tables went dense), against numpy: CHOLMOD,
           the UMFPACK fallback for indefinite and non-symmetric matrices,
           Lanczos roots, products, output ops, params rebound;
  interp   interpolated stages: --reduce, --interp-oversample, --valid DIR|F,
           npgc tune with the choice in its search, verify's advice, the
           format-2 model through eval, emit and verify;
  stream   models without their pair-class bases, --keep-bases, verify's
           recorded floors and its advice when a stage reads one of them;
  py       npg.Trainer(interp=, galerkin=, interp_oversample=, valid=,
           valid_holdout=), model.interpolated(), model.reductions(), the
           README's "From Python" example.

Each case is a command with its expectation, as in trial2.py: the exit
status, a substring of stderr (stdout for the Python driver), and where a
result is produced a check of it against numpy or the full evaluation (a
quiet wrong answer fails), or of files that must not change. A case also
fails when killed by a signal, when a sanitizer reports, when it runs past
its timeout or exits 0 on bad input. "either": a clear refusal or a correct
value, nothing else. With NAME arguments only the cases whose name contains
one of them run; NPG_TRIAL_VERBOSE=1 prints every case's outcome.
"""
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import trialkit
from trialkit import SANITIZER_MARKS, fnv1a64, sanitized

BUILD = os.path.abspath(sys.argv[1])
SRC = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
NPGC = os.path.join(BUILD, "npgc")
ONLY = sys.argv[2:]
VERBOSE = os.environ.get("NPG_TRIAL_VERBOSE") == "1"
TIMEOUT = 120


SANITIZED = sanitized(BUILD)
W = tempfile.mkdtemp(prefix="npg_trial3_")
os.chmod(W, 0o755)
CASES = []
# name -> reason; reported, not failed. Each fixed case leaves this list in the commit that fixes it.
KNOWN_FAILURES = {
}


def case(name, argv, status=1, msg="", check=None, stream="err", env=None, timeout=None, after=None):
    """argv[0] 'npgc' (this build's) or a path. `status`
    None: any refusal (exit 1 or 2 with a message); 'either': 0 with check() passing, or a refusal whose
    message holds `msg`. `check(proc)` returns a problem or None; `after` names cases that must run first."""
    CASES.append(dict(name=name, argv=argv, status=status, msg=msg, check=check, stream=stream, env=env,
                      timeout=timeout or TIMEOUT, after=after))


def path(*parts):
    return os.path.join(W, *parts)


def write(rel, text):
    p = path(rel)
    os.makedirs(os.path.dirname(p), exist_ok=True)
    with open(p, "w") as f:
        f.write(text)
    return rel


def data_dir(rel, arrays):
    os.makedirs(path(rel), exist_ok=True)
    for name, a in arrays.items():
        np.save(path(rel, name + ".npy"), a)
    return rel


def npgc_ok(*argv):
    p = subprocess.run([NPGC] + list(argv), cwd=W, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if p.returncode != 0:
        raise SystemExit("fixture failed: npgc %s\n%s" % (" ".join(argv), p.stderr.decode()))
    return p.stdout.decode()


def digest(p):
    h = hashlib.sha256()
    for root, dirs, files in sorted(os.walk(p)):
        dirs.sort()
        for f in sorted(files):
            with open(os.path.join(root, f), "rb") as fh:
                h.update(f.encode() + fh.read())
    return h.hexdigest()


def close(got, want, rtol, what):
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if got.shape != want.shape:
        return "%s has shape %s, expected %s" % (what, got.shape, want.shape)
    if not np.all(np.isfinite(got)):
        return "%s holds non-finite values" % what
    scale = max(1e-300, float(np.max(np.abs(want))))
    err = float(np.max(np.abs(got - want)))
    return None if err <= rtol * scale else "%s differs by %.3e relative (allowed %.0e)" % (what, err / scale, rtol)


def out_equals(rel, want, rtol=1e-10):
    def check(proc):
        if not os.path.exists(path(rel)):
            return "%s was not written" % rel
        return close(np.load(path(rel)), want, rtol, rel)
    return check


def text_lacks(*words, stream="out"):
    """A check: the command's stdout (or stderr) holds none of `words`."""
    def check(proc):
        t = (proc.stdout if stream == "out" else proc.stderr).decode("utf-8", "replace")
        for w in words:
            if w in t:
                return "%s says %r" % ("stdout" if stream == "out" else "stderr", w)
        return None
    return check


def both(*checks):
    def check(proc):
        for c in checks:
            prob = c(proc)
            if prob:
                return prob
        return None
    return check


# ------------------------------------------------------------------ sparse operators (DESIGN §13)

RNG = np.random.default_rng(2026)


def grid(nx, ny):
    """Four neighbours per cell of an nx x ny grid, -1 where there is none."""
    nbr = -np.ones((nx * ny, 4), dtype=np.int64)
    for y in range(ny):
        for x in range(nx):
            i = y * nx + x
            nbr[i] = [i - 1 if x > 0 else -1, i + 1 if x < nx - 1 else -1, i - nx if y > 0 else -1,
                      i + nx if y < ny - 1 else -1]
    return nbr


def heat_K(nbr, kap, spd):
    """bench/heat_spd.npg's operator (spd: face conductivity the mean of its two cells) or
    tests/programs/heat_neighbours.npg's (kappa of the row's cell: not symmetric)."""
    K = np.eye(len(kap))
    for i in range(len(kap)):
        for j in nbr[i]:
            if j >= 0:
                c = 0.5 * (kap[i] + kap[j]) if spd else kap[i]
                K[i, i] += c
                K[i, j] -= c
    return K


def mpow(K, r):
    w, V = np.linalg.eigh(K)
    return (V * w ** r) @ V.T


def sparse_cases():
    spd = open(os.path.join(SRC, "bench/heat_spd.npg")).read()
    ns = open(os.path.join(SRC, "tests/programs/heat_neighbours.npg")).read()
    write("sp/spd.npg", spd)
    write("sp/ns.npg", ns)
    head = spd[:spd.rindex("output")]
    nbr = grid(6, 5)                        # 30 cells: above FULL_SPARSE_MIN_ROWS, so CHOLMOD / UMFPACK
    N = len(nbr)
    src = 1 + RNG.random(N)
    kap = 0.2 + RNG.random((4, N))
    lopsided = nbr.copy()
    lopsided[0, 1] = -1                     # cell 0 no longer sees cell 1; cell 1 still sees 0: pattern not symmetric
    indef = kap.copy()
    indef[1:3] *= -3                        # symmetric but indefinite at samples 1 and 2: CHOLMOD fails, LU follows
    mixed = kap.copy()
    mixed[1] *= -3                          # PD, indefinite, PD, PD: the fallback must not leak into later samples
    sets = {"grid": (nbr, kap), "lopsided": (lopsided, kap), "indefinite": (nbr, indef),
            "mixed": (nbr, mixed)}
    for name, (tab, k) in sets.items():
        d = data_dir("sp/D_" + name, {"nbr": tab, "src": src, "kappa": k})
        for prog, sym in (("spd", True), ("ns", False)):
            want = np.array([np.linalg.solve(heat_K(tab, kk, sym), src) for kk in k])
            case("sparse_%s_%s_solve" % (prog, name), ["npgc", "eval", "sp/%s.npg" % prog, "--full", d, d, "-o",
                                                       "out/sp_%s_%s" % (prog, name)], 0, "",
                 check=out_equals("out/sp_%s_%s/u.npy" % (prog, name), want, 1e-11))
    # at the dense/sparse boundary (FULL_SPARSE_MIN_ROWS 16), a table of padding only, and every cell
    # reading one hub cell (a dense column: a pattern far from symmetric)
    hub = -np.ones((20, 4), dtype=np.int64)
    hub[1:, 0] = 0
    for name, tab in (("boundary_15", grid(5, 3)), ("boundary_16", grid(4, 4)),
                      ("padding_only", -np.ones((20, 4), dtype=np.int64)), ("hub", hub)):
        n_ = len(tab)
        s_, k_ = 1 + RNG.random(n_), 0.2 + RNG.random((2, n_))
        d = data_dir("sp/D_" + name, {"nbr": tab, "src": s_, "kappa": k_})
        for prog, sym in (("spd", True), ("ns", False)):
            case("sparse_%s_%s" % (prog, name), ["npgc", "eval", "sp/%s.npg" % prog, "--full", d, d, "-o",
                                                 "out/sp_%s_%s" % (prog, name)], 0, "",
                 check=out_equals("out/sp_%s_%s/u.npy" % (prog, name),
                                  np.array([np.linalg.solve(heat_K(tab, kk, sym), s_) for kk in k_]), 1e-11))
    # powers, roots and products of the SPD operator, against numpy's eigendecomposition
    exprs = {"inv_sqrt": ("K^(-1/2) * src", lambda K: mpow(K, -0.5) @ src),
             "cube_root": ("root(K, 3) * src", lambda K: mpow(K, 1 / 3) @ src),
             "two_thirds": ("K^(2/3) * src", lambda K: mpow(K, 2 / 3) @ src),
             "inv_three_halves": ("K^(-3/2) * src", lambda K: mpow(K, -1.5) @ src),
             "square": ("K^2 * src", lambda K: K @ K @ src),
             "product": ("K * src", lambda K: K @ src),
             "inv_square": ("K^(-2) * src", lambda K: np.linalg.solve(K @ K, src)),
             "solve_twice": ("solve(K, solve(K, src))", lambda K: np.linalg.solve(K, np.linalg.solve(K, src)))}
    d = "sp/D_grid"
    for name, (e, fn) in exprs.items():
        write("sp/pow_%s.npg" % name, head + "output u = %s\n" % e)
        want = np.array([fn(heat_K(nbr, kk, True)) for kk in kap])
        case("sparse_power_%s" % name, ["npgc", "eval", "sp/pow_%s.npg" % name, "--full", d, d, "-o",
                                        "out/sp_pow_" + name], 0, "",
             check=out_equals("out/sp_pow_%s/u.npy" % name, want, 1e-10))
        # indefinite: a product is defined (numpy), a root is refused naming the operator and the sample
        if name in ("square", "product", "inv_square", "solve_twice"):
            want = np.array([fn(heat_K(nbr, kk, True)) for kk in indef])
            case("sparse_power_%s_indefinite" % name, ["npgc", "eval", "sp/pow_%s.npg" % name, "--full",
                                                        "sp/D_indefinite", "sp/D_indefinite", "-o",
                                                        "out/sp_powi_" + name], 0, "",
                 check=out_equals("out/sp_powi_%s/u.npy" % name, want, 1e-9))
        else:
            case("sparse_power_%s_indefinite" % name, ["npgc", "eval", "sp/pow_%s.npg" % name, "--full",
                                                        "sp/D_indefinite", "sp/D_indefinite", "-o",
                                                        "out/sp_powi_" + name], 1, "not positive definite",
                 check=text_lacks("after 0 steps", "estimate inf", stream="err"))
            # the message says where: the operator and the sample
            case("sparse_power_%s_indefinite_names" % name,
                 ["npgc", "eval", "sp/pow_%s.npg" % name, "--full", "sp/D_indefinite", "sp/D_indefinite", "-o",
                  "out/sp_powj_" + name], 1, "sample 1: stage 'u'")
    # verify --exact draws a random (non-symmetric) table: it cannot check a root of heat_spd's K, and must
    # not present that as a defect of the program or of npg without saying why
    case("sparse_exact_random_table", ["npgc", "verify", "sp/pow_inv_sqrt.npg", "--exact"], 1, "cannot be checked")
    # the non-symmetric operator has no root
    nsh = ns[:ns.rindex("output")]
    write("sp/ns_root.npg", nsh + "output u = K^(-1/2) * src\n")
    case("sparse_root_not_symmetric", ["npgc", "eval", "sp/ns_root.npg", "--full", d, d, "-o", "out/sp_nsr"], 1,
         "not symmetric")
    # a singular graph Laplacian: I + w (e_a - e_b)(e_a - e_b)^T with w = -1/2 on one edge only
    lap = open(os.path.join(SRC, "tests/programs/graph_laplacian_delta.npg")).read()
    write("sp/lap.npg", lap)
    NL = 20
    ring = np.array([[e, (e + 1) % NL] for e in range(NL)], dtype=np.int64)
    w = np.zeros((2, NL))
    w[0] = 0.3 + RNG.random(NL)
    w[1, 4] = -0.5
    d = data_dir("sp/D_lap_singular", {"tab": ring, "f": 1 + RNG.random(NL), "w": w})
    case("sparse_laplacian_singular", ["npgc", "eval", "sp/lap.npg", "--full", d, d, "-o", "out/sp_lsing"], 1,
         "sample 1")
    # an output op at 30 rows: CSR written by eval --full equals numpy's matrix
    write("sp/out_op.npg", head.replace("op K[", "output op K[") + "output u = solve(K, src)\n")
    want_k = [heat_K(nbr, kk, True) for kk in kap]

    def csr_equals(proc):
        ip, ix, dat = (np.load(path("out/sp_op/K.%s.npy" % s)) for s in ("indptr", "indices", "data"))
        for k, K in enumerate(want_k):
            M = np.zeros((N, N))
            for r in range(N):
                M[r, ix[ip[r]:ip[r + 1]]] = dat[k, ip[r]:ip[r + 1]]
            prob = close(M, K, 1e-13, "K sample %d" % k)
            if prob:
                return prob
        return None
    case("sparse_output_op_csr", ["npgc", "eval", "sp/out_op.npg", "--full", "sp/D_grid", "sp/D_grid", "-o",
                                  "out/sp_op"], 0, "", check=csr_equals)
    # index-table and stencil conditions the enumerator solves for the column, as products A x against numpy
    K3 = 3
    tab = RNG.integers(-1, 20, size=(20, K3))
    cc = 1 + RNG.random(20)
    xs = RNG.normal(size=(3, 20))
    data_dir("sp/D_st", {"nbr": tab, "c": cc, "x": xs})
    forms = {
        "eq_reversed": ("sum(k = 0..2, if(j == nbr[i, k], c[j], 0))", lambda i, j: sum(cc[j] for k in range(K3) if j == tab[i, k])),
        "transposed": ("sum(k = 0..2, if(nbr[j, k] == i, c[i], 0))", lambda i, j: sum(cc[i] for k in range(K3) if tab[j, k] == i)),
        "shift": ("if(j == i + 1, c[i], 0)", lambda i, j: cc[i] * (j == i + 1)),
        "half": ("if(2 * j == i, c[i], 0)", lambda i, j: cc[i] * (2 * j == i)),
        "square": ("if(j * j == i, c[i], 0)", lambda i, j: cc[i] * (j * j == i)),
        "antidiagonal": ("if(i + j == N - 1, c[i], 0)", lambda i, j: cc[i] * (i + j == 19)),
        "delta_shift": ("delta(j, i - 1) * c[i]", lambda i, j: cc[i] * (j == i - 1)),
        "out_of_range_shift": ("if(j == i - 25, c[i], 0)", lambda i, j: 0.0),
        "both_ways": ("sum(k = 0..2, if(nbr[i, k] == j, c[j], 0) + if(nbr[j, k] == i, c[i], 0))",
                      lambda i, j: sum(cc[j] * (tab[i, k] == j) + cc[i] * (tab[j, k] == i) for k in range(K3))),
    }
    for name, (e, fn) in forms.items():
        write("sp/st_%s.npg" % name, "dim N\nparam nbr : int[N, 3]\nparam c : real[N]\ninput x : real[N]\n"
                                     "op A[i:N, j:N] = delta(i, j) + %s\noutput u = A * x\n" % e)
        A = np.eye(20) + np.array([[fn(i, j) for j in range(20)] for i in range(20)], dtype=float)
        case("sparse_stencil_" + name, ["npgc", "eval", "sp/st_%s.npg" % name, "--full", "sp/D_st", "sp/D_st", "-o",
                                        "out/sp_st_" + name], 0, "",
             check=out_equals("out/sp_st_%s/u.npy" % name, xs @ A.T, 1e-13))
    # 900 cells, each sample's solve against numpy
    big = grid(30, 30)
    kb = 0.2 + RNG.random((2, 900))
    sb = 1 + RNG.random(900)
    d = data_dir("sp/D_big", {"nbr": big, "src": sb, "kappa": kb})
    case("sparse_spd_900_cells", ["npgc", "eval", "sp/spd.npg", "--full", d, d, "-o", "out/sp_big"], 0, "",
         check=out_equals("out/sp_big/u.npy", np.array([np.linalg.solve(heat_K(big, k, True), sb) for k in kb]),
                          1e-10))
    case("sparse_reduce_interp_ineligible", ["npgc", "train", "sp/spd.npg", "sp/D_grid", "-o", "sp/MX", "--reduce",
                                             "u:interp"], None, "u")
    # trained: the reduced model of the sparse program against the full evaluation, and verify's figure
    # against the mean relative error numpy computes from the two evaluations
    ktr = 0.5 + 0.3 * RNG.random((40, N))
    kte = 0.5 + 0.3 * RNG.random((6, N))
    data_dir("sp/TR", {"nbr": nbr, "src": src, "kappa": ktr})
    data_dir("sp/TE", {"nbr": nbr, "src": src, "kappa": kte})
    npgc_ok("train", "sp/spd.npg", "sp/TR", "-o", "sp/M", "--energy", "0.999999")
    # the reduced output op equals B^T K B with the kept basis of u, for every sample
    npgc_ok("train", "sp/out_op.npg", "sp/TR", "-o", "sp/MOP")

    def reduced_op_equals(proc):
        B = np.load(path("sp/MOP/basis_1.npy"))
        R = np.load(path("out/sp_opr/K.reduced.npy"))
        for k, kk in enumerate(np.load(path("sp/TE/kappa.npy"))):
            prob = close(R[k], B.T @ heat_K(nbr, kk, True) @ B, 1e-12, "K.reduced sample %d" % k)
            if prob:
                return prob
        return None
    case("sparse_output_op_reduced", ["npgc", "eval", "sp/out_op.npg", "sp/MOP", "sp/TE", "-o", "out/sp_opr"], 0, "",
         check=reduced_op_equals)
    # full-rank models of the sparse roots and powers reproduce numpy (DESIGN §4: to 1e-10)
    for name in ("inv_sqrt", "cube_root", "square"):
        npgc_ok("train", "sp/pow_%s.npg" % name, "sp/TR", "-o", "sp/MP_" + name, "--energy", "1")
        fn = exprs[name][1]
        case("sparse_full_rank_" + name, ["npgc", "eval", "sp/pow_%s.npg" % name, "sp/MP_" + name, "sp/TE", "-o",
                                          "out/sp_fr_" + name], 0, "",
             check=out_equals("out/sp_fr_%s/u.npy" % name, np.array([fn(heat_K(nbr, k, True)) for k in kte]), 1e-10))
    want = np.array([np.linalg.solve(heat_K(nbr, k, True), src) for k in kte])
    case("sparse_trained_reduced_eval", ["npgc", "eval", "sp/spd.npg", "sp/M", "sp/TE", "-o", "out/sp_red"], 0, "",
         check=out_equals("out/sp_red/u.npy", want, 1e-3))

    def verify_honest(proc):
        got = np.load(path("out/sp_red/u.npy"))
        err = np.mean([np.linalg.norm(g - w_) / np.linalg.norm(w_) for g, w_ in zip(got, want)])
        for line in proc.stdout.decode().splitlines():
            if line.startswith("u "):
                rep = float(line.split()[3])
                return None if abs(rep - err) <= 1e-3 * err + 1e-14 else "verify says %g, numpy %g" % (rep, err)
        return "no row for u"
    case("sparse_tune", ["npgc", "tune", "sp/spd.npg", "sp/TR", "sp/TE", "--tol", "1e-3", "-o", "sp/MT", "--png",
                         "out/sp_tune.png"], 0, "", timeout=300)
    case("sparse_tune_meets_tol", ["npgc", "verify", "sp/spd.npg", "sp/MT", "sp/TE", "--tol", "1e-3"], 0, "",
         after="sparse_tune")
    case("sparse_trained_verify_honest", ["npgc", "verify", "sp/spd.npg", "sp/M", "sp/TE", "--tol", "1"], 0, "",
         check=verify_honest, stream="out", after="sparse_trained_reduced_eval")


# ------------------------------------------------------------------ interpolated stages (DESIGN §12)

def nbody_data(rel, S, seed):
    r = np.random.default_rng(seed)
    base = np.random.default_rng(7).normal(size=(8, 3)) * 2
    modes = np.random.default_rng(8).normal(size=(3, 8, 3))
    x = base + np.einsum("sk,kvc->svc", 0.2 * r.normal(size=(S, 3)), modes)
    return data_dir(rel, {"x": x, "mass": np.full(8, 1 / 8), "eps": np.array(0.05)})


def nbody_a(x, mass=1 / 8, eps=0.05):
    d = x[None, :, :] - x[:, None, :]                  # d[i, j] = x_j - x_i
    r2 = np.sum(d * d, axis=2) + eps
    w = r2 ** -1.5
    np.fill_diagonal(w, 1.0)                             # r2[i, i] = 1 in the program; d[i, i] = 0 anyway
    return np.einsum("ij,ijc->ic", mass * w, d)


def better_than_nothing(rel, want):
    """A check: the reduced output's mean relative L2 error is below 1 (zero would score 1)."""
    def check(proc):
        got = np.load(path(rel))
        if got.shape != want.shape or not np.all(np.isfinite(got)):
            return "%s: shape %s or non-finite values" % (rel, got.shape)
        err = np.mean([np.linalg.norm(g - w) / np.linalg.norm(w) for g, w in zip(got, want)])
        return None if err < 1 else "%s: mean relative error %.3g" % (rel, err)
    return check


def entries_are(X):
    """A check: MO's interpolated stage w has k entries, m <= k <= ceil(X m) (its manifest line 'interp w k K m M
    ...': the m pivoted entries and ceil(X m) - m drawn by leverage, the distinct ones counted)."""
    def check(proc):
        line = [l.split() for l in open(path("ip/MO/manifest")) if l.startswith("interp w ")][0]
        k, m = int(line[3]), int(line[5])
        return None if m <= k <= int(np.ceil(X * m)) else "k %d for m %d at --interp-oversample %g" % (k, m, X)
    return check


def eligible_is_w(proc):
    import json
    rep = json.loads(proc.stdout.decode())
    el = sorted(st["name"] for st in rep["stages"] if st.get("interp_eligible"))
    return None if el == ["w"] else "interp_eligible stages: %s" % el


def interp_cases():
    write("ip/nb.npg", open(os.path.join(SRC, "tests/programs/nbody_gravity.npg")).read())
    nbody_data("ip/D", 40, 1)
    nbody_data("ip/V", 10, 2)
    nbody_data("ip/T", 8, 3)
    xt = np.load(path("ip/T/x.npy"))
    want = np.array([nbody_a(x) for x in xt])
    # the Galerkin model: --valid none, since on these samples the default choice interpolates w
    npgc_ok("train", "ip/nb.npg", "ip/D", "-o", "ip/MG", "--valid", "none")
    npgc_ok("train", "ip/nb.npg", "ip/D", "-o", "ip/MI", "--reduce", "w:interp")
    # the full evaluation itself against numpy (the reference for what follows)
    case("interp_full_equals_numpy", ["npgc", "eval", "ip/nb.npg", "--full", "ip/D", "ip/T", "-o", "out/ip_full"], 0,
         "", check=out_equals("out/ip_full/a.npy", want, 1e-12))
    # every basis at full size and every entry interpolated: the reduced model is the full evaluation
    case("interp_full_rank_exact", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MX", "--reduce", "w:interp",
                                    "--energy", "1", "--cap", "1000", "--interp-oversample", "1000"], 0, "")
    case("interp_full_rank_eval", ["npgc", "eval", "ip/nb.npg", "ip/MX", "ip/T", "-o", "out/ip_mx"], 0, "",
         check=out_equals("out/ip_mx/a.npy", want, 1e-8), after="interp_full_rank_exact")
    # verify's figure for the interpolated model equals numpy's mean relative error of eval's output

    def verify_matches(model, out):
        def check(proc):
            got = np.load(path(out, "a.npy"))
            err = np.mean([np.linalg.norm(g - w_) / np.linalg.norm(w_) for g, w_ in zip(got, want)])
            for line in proc.stdout.decode().splitlines():
                if line.startswith("a "):
                    rep = float(line.split()[3])      # quantity, kind, m, L2 error
                    return None if abs(rep - err) <= 1e-3 * err else "verify says %g, numpy %g" % (rep, err)
            return "no row for a"
        return check
    for m in ("MG", "MI"):
        case("interp_eval_%s" % m, ["npgc", "eval", "ip/nb.npg", "ip/" + m, "ip/T", "-o", "out/ip_" + m], 0, "",
             check=better_than_nothing("out/ip_%s/a.npy" % m, want))
        case("interp_verify_%s_honest" % m, ["npgc", "verify", "ip/nb.npg", "ip/" + m, "ip/T", "--tol", "1"], 0, "",
             stream="out", check=verify_matches(m, "out/ip_" + m), after="interp_eval_" + m)
    # --valid F: every round(1/F)-th sample held out; one that holds none out is refused naming --valid
    case("interp_valid_fraction_none_held", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M1", "--valid", "0.01"],
         1, "--valid 0.01")
    case("interp_valid_fraction_dot", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M2", "--valid", ".5"], 0,
         "on 20 samples (20 more", stream="out",
         check=lambda p: None if "samples 20" in open(path("ip/M2/manifest")).read() else "not 20 samples trained")
    case("interp_valid_fraction_exponent", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M3", "--valid",
                                            "2.5e-1"], 0, "",
         check=lambda p: None if "samples 30" in open(path("ip/M3/manifest")).read() else "not 30 samples trained")
    case("interp_valid_fraction_mpi", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M4", "--mpi", "--valid", "0.25"],
         None, "", check=lambda p: None if "--valid 0.25" in p.stderr.decode() or "has no MPI" in p.stderr.decode()
         else "stderr does not name --valid 0.25",
         # OpenMPI keeps allocations of MPI_Init past MPI_Finalize: its suppressions, as tests/mpi/mpi.sh sets them
         env=dict(os.environ, ASAN_OPTIONS=os.environ.get("ASAN_OPTIONS", "") + ":fast_unwind_on_malloc=0",
                  LSAN_OPTIONS="suppressions=" + os.path.join(SRC, "tests/mpi/lsan.supp"),
                  OMPI_MCA_mca_base_component_disable_dlclose="1"))
    case("interp_valid_fraction_text", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M4", "--valid", "0.2x"], None,
         "0.2x")
    case("interp_valid_fraction_inf", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M4", "--valid", "inf"], None,
         "inf")
    case("interp_valid_is_file", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M4", "--valid", "ip/V/x.npy"],
         None, "ip/V/x.npy")
    # validation data that disagree with the training data: refused naming the file
    v = {k: np.load(path("ip/V", k + ".npy")) for k in ("x", "mass", "eps")}
    data_dir("ip/V_mass", dict(v, mass=np.full(8, 5.0)))
    data_dir("ip/V_dims", dict(v, x=v["x"][:, :5]))
    data_dir("ip/V_nan", dict(v, x=np.where(np.arange(v["x"].size).reshape(v["x"].shape) == 7, np.nan, v["x"])))
    data_dir("ip/V_extra", dict(v, q=v["x"]))
    os.makedirs(path("ip/V_empty"), exist_ok=True)
    case("interp_valid_other_params", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M5", "--valid", "ip/V_mass"],
         1, "mass")
    case("interp_valid_other_dims", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M5", "--valid", "ip/V_dims"],
         1, "N")
    case("interp_valid_nan", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M5", "--valid", "ip/V_nan"], 1, "NaN")
    case("interp_valid_empty_dir", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M5", "--valid", "ip/V_empty"], 1,
         "x.npy")
    case("interp_valid_extra_file", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/M6", "--valid", "ip/V_extra"],
         "either", "q")
    for name in ("M5",):
        case("interp_valid_refused_leaves_no_model_" + name, ["sh", "-c", "test ! -e %s" % path("ip", name)], 0, "",
             after="interp_valid_other_params")
    # the choice recorded and printed, and the model it made evaluates like the one forced to it
    case("interp_valid_dir_choice", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MV", "--valid", "ip/V"], 0,
         "", stream="out", check=lambda p: None if "choice w " in open(path("ip/MV/manifest")).read()
         else "no choice line")
    case("interp_docs_options", ["sh", "-c", "true"], 0, "",
         check=docs_name("--reduce STAGE:interp", "--interp-oversample", "--valid DIR", "--valid F", "npg-model 2"))
    # --valid DIR is an input of the command: --spectra may not write into it, as into DATA/
    shutil.copytree(path("ip/V"), path("ip/VS"))
    keep_vs = {f: open(path("ip/VS", f), "rb").read() for f in os.listdir(path("ip/VS"))}
    case("interp_spectra_into_valid", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MSP", "--valid", "ip/VS",
                                       "--spectra", "ip/VS"], None, "ip/VS",
         check=lambda p: None if {f: open(path("ip/VS", f), "rb").read() for f in os.listdir(path("ip/VS"))} == keep_vs
         else "ip/VS changed: %s" % sorted(os.listdir(path("ip/VS"))))
    # --valid 0.25 holds out samples 3, 7, 11, ...: the model equals training on the others with those as --valid DIR
    xd = np.load(path("ip/D/x.npy"))
    held = [k for k in range(len(xd)) if k % 4 == 3]
    kept_ = [k for k in range(len(xd)) if k % 4 != 3]
    for d, idx in (("ip/DK", kept_), ("ip/DH", held)):
        data_dir(d, {"x": xd[idx], "mass": np.load(path("ip/D/mass.npy")), "eps": np.load(path("ip/D/eps.npy"))})
    npgc_ok("train", "ip/nb.npg", "ip/DK", "-o", "ip/MHD", "--valid", "ip/DH")
    case("interp_valid_fraction_equals_dir", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MHF", "--valid", "0.25"],
         0, "", check=lambda p: None if digest(path("ip/MHF")) == digest(path("ip/MHD"))
         else "--valid 0.25 and --valid DIR of the same held-out samples give different models")
    case("interp_valid_small_mem", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MVM", "--valid", "ip/V", "--mem",
                                    "10k"], 0, "", stream="out", check=text_lacks("both fail"))
    case("interp_reduce_galerkin_wins_over_valid", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MVG", "--valid",
                                                    "ip/V", "--reduce", "w:galerkin"], 0, "",
         check=lambda p: None if open(path("ip/MVG/manifest")).readline().strip() == "npg-model 1"
         else "w was not kept Galerkin")
    case("interp_oversample_fraction", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MO", "--reduce", "w:interp",
                                        "--interp-oversample", "1.5"], 0, "", check=entries_are(1.5))
    case("interp_oversample_negative", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MO2", "--reduce", "w:interp",
                                        "--interp-oversample", "-2"], 2, "--interp-oversample")
    case("interp_oversample_below_one", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "ip/MO2", "--reduce", "w:interp",
                                         "--interp-oversample", "0.5"], 2, "--interp-oversample")
    # emit --reduced of the format-2 model compiles
    case("interp_emit_reduced", ["npgc", "emit", "ip/nb.npg", "--reduced", "ip/MI", "-o", "out/ip_red.c"], 0, "")
    case("interp_emit_reduced_compiles", ["cc", "-c", "-std=c11", "-I", os.path.join(SRC, "include"),
                                          "-I", os.path.join(SRC, "stdlib/runtime"), path("out/ip_red.c"),
                                          "-o", path("out/ip_red.o")], 0, "", after="interp_emit_reduced")
    # tune with the choice in its search: the model it writes meets --tol on VALID/ when verified
    case("interp_tune", ["npgc", "tune", "ip/nb.npg", "ip/D", "ip/V", "--tol", "0.08", "-o", "ip/MT", "--png",
                         "out/tune.png"], 0, "", timeout=300)
    case("interp_tune_model_meets_tol", ["npgc", "verify", "ip/nb.npg", "ip/MT", "ip/V", "--tol", "0.08"], 0, "",
         after="interp_tune")
    case("interp_tune_reduce_unknown", ["npgc", "tune", "ip/nb.npg", "ip/D", "ip/V", "--tol", "0.08", "-o", "ip/MT2",
                                        "--reduce", "nosuch:interp"], None, "nosuch")
    case("interp_tune_reduce_ineligible", ["npgc", "tune", "ip/nb.npg", "ip/D", "ip/V", "--tol", "0.08", "-o",
                                           "ip/MT2", "--reduce", "a:interp"], None, "a")
    case("interp_tune_keep_bases_all", ["npgc", "tune", "ip/nb.npg", "ip/D", "ip/V", "--tol", "0.08", "-o", "ip/MTK",
                                        "--png", "out/tunek.png", "--keep-bases", "all"], 0, "", timeout=300,
         check=lambda p: None if {"basis_%d.npy" % i for i in range(4)} <= set(os.listdir(path("ip/MTK")))
         else "tune --keep-bases all dropped a basis: %s" % sorted(os.listdir(path("ip/MTK"))))
    # npgc check --json marks the one eligible stage
    case("interp_check_json", ["npgc", "check", "ip/nb.npg", "--json"], 0, "", stream="out", check=eligible_is_w)
    case("interp_plot", ["npgc", "plot", "ip/MI", "-o", "out/ip_plot.png"], 0, "")
    case("interp_bench", ["npgc", "bench", "ip/nb.npg", "ip/MI", "ip/T"], 0, "")
    case("interp_eval_exact_roots", ["npgc", "eval", "ip/nb.npg", "ip/MI", "ip/T", "-o", "out/ip_mier", "--exact-roots"],
         0, "", check=lambda p: close(np.load(path("out/ip_mier/a.npy")), np.load(path("out/ip_MI/a.npy")), 1e-10,
                                      "a with --exact-roots"), after="interp_eval_MI")
    # an interpolated root whose input's reduced value goes negative at a selected entry: named, never NaN
    write("ip/neg.npg", "dim N\ninput x : real[N]\ns[i:N] = x[i] * x[i] + 0.001\noutput w[i:N] = s[i]^(-1/2)\n")
    r = np.random.default_rng(11)
    data_dir("ip/ND", {"x": r.normal(size=(30, 40))})
    data_dir("ip/NT", {"x": r.normal(size=(5, 40))})
    npgc_ok("train", "ip/neg.npg", "ip/ND", "-o", "ip/MN", "--reduce", "w:interp", "--cap", "3")
    case("interp_negative_root_named", ["npgc", "eval", "ip/neg.npg", "ip/MN", "ip/NT", "-o", "out/ip_neg"], "either",
         "stage w (interpolated)", check=lambda p: close(np.load(path("out/ip_neg/w.npy")),
                                                         (np.load(path("ip/NT/x.npy")) ** 2 + 0.001) ** -0.5, 1,
                                                         "w"))
    case("interp_negative_root_verify", ["npgc", "verify", "ip/neg.npg", "ip/MN", "ip/NT"], None, "entry")
    # a program with an extern: the choice measured on validation samples must see the extern's learned
    # map (it is fitted after the choice in train_model: both ways "fail", Galerkin kept by default)
    write("ip/ext.npg", "dim N\ninput x : real[N]\nextern v[i:N] of x\ns[i:N] = v[i] * v[i] + 1\n"
                        "output w[i:N] = x[i] * s[i]^(-1/2)\n")
    r = np.random.default_rng(12)
    for d, S in (("ip/ED", 30), ("ip/EV", 6)):
        xe = r.normal(size=(S, 20))
        data_dir(d, {"x": xe, "v": np.sin(xe)})
    case("interp_valid_with_extern", ["npgc", "train", "ip/ext.npg", "ip/ED", "-o", "ip/ME", "--valid", "ip/EV"], 0,
         "", stream="out", check=text_lacks("both fail"))
    case("interp_valid_holdout_with_extern", ["npgc", "train", "ip/ext.npg", "ip/ED", "-o", "ip/ME2", "--valid", "0.2"],
         0, "", stream="out", check=text_lacks("both fail"))
    npgc_ok("train", "ip/ext.npg", "ip/ED", "-o", "ip/MEG")
    case("interp_verify_extern_advice", ["npgc", "verify", "ip/ext.npg", "ip/MEG", "ip/EV", "--tol", "1"], 0,
         "learned map", stream="out", check=text_lacks("--basis v:cap"))
    case("interp_tune_with_extern", ["npgc", "tune", "ip/ext.npg", "ip/ED", "ip/EV", "--tol", "0.5", "-o", "ip/MTE",
                                     "--png", "out/tune_ext.png"], 0, "", stream="out", check=text_lacks("both fail"),
         timeout=300)
    case("interp_tune_valid_option", ["npgc", "tune", "ip/nb.npg", "ip/D", "ip/V", "--tol", "0.08", "-o", "ip/MT3",
                                      "--valid", "ip/V"], 2, "VALID/")
    case("interp_tune_valid_other_params", ["npgc", "tune", "ip/nb.npg", "ip/D", "ip/V_mass", "--tol", "0.08", "-o",
                                            "ip/MT2"], 1, "mass")


# ------------------------------------------------------------------ streamed bases (issue 30)

def stream_cases():
    npgc_ok("train", "ip/nb.npg", "ip/D", "-o", "st/MK", "--keep-bases", "all", "--valid", "none")
    files = set(os.listdir(path("ip/MG")))
    case("stream_pair_bases_not_kept", ["sh", "-c", "true"], 0, "",
         check=lambda p: None if {"basis_1.npy", "basis_2.npy"}.isdisjoint(files) and "basis_0.npy" in files
         else "model files: %s" % sorted(files))
    npgc_ok("eval", "ip/nb.npg", "st/MK", "ip/T", "-o", "st/OK")
    case("stream_eval_equals_kept", ["npgc", "eval", "ip/nb.npg", "ip/MG", "ip/T", "-o", "out/st_eval"], 0, "",
         check=out_equals("out/st_eval/a.npy", np.load(path("st/OK/a.npy")), 1e-13))
    # verify must not send the user to a basis that is already exact when the stage reads a streamed one
    case("stream_verify_advice_not_misleading", ["npgc", "verify", "ip/nb.npg", "ip/MG", "ip/T", "--tol", "1"], 0, "",
         stream="out", check=text_lacks("--basis x:cap"))
    # with every member at 0.999 (x and r2, under w's power, are whole by default: DESIGN §12) w's error
    # dominates the output's, and w's basis is streamed
    npgc_ok("train", "ip/nb.npg", "ip/D", "-o", "st/M999", "--valid", "none", "--basis", "*:energy=0.999")
    case("stream_verify_advice_names_streamed", ["npgc", "verify", "ip/nb.npg", "st/M999", "ip/T", "--tol", "1"], 0,
         "keep-bases w", stream="out")
    case("stream_verify_floor_marked", ["npgc", "verify", "ip/nb.npg", "ip/MG", "ip/T", "--tol", "1"], 0, "*",
         stream="out")
    case("stream_docs_options", ["sh", "-c", "true"], 0, "", check=docs_name("--keep-bases", "marked `*`"))
    case("stream_keep_bases_empty", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "st/M1", "--keep-bases", ""], 2,
         "--keep-bases")
    case("stream_keep_bases_unknown", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "st/M1", "--keep-bases", "zz"], None,
         "zz")
    case("stream_keep_bases_class", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "st/M2", "--keep-bases", "m_w"], 0, "",
         check=lambda p: None if "basis_2.npy" in os.listdir(path("st/M2")) else "m_w not kept")
    case("stream_keep_bases_input", ["npgc", "train", "ip/nb.npg", "ip/D", "-o", "st/M3", "--keep-bases", "x"], 0, "")
    case("stream_emit_reduced", ["npgc", "emit", "ip/nb.npg", "--reduced", "ip/MG", "-o", "out/st_red.c"], 0, "")
    case("stream_bench", ["npgc", "bench", "ip/nb.npg", "ip/MG", "ip/T"], 0, "")
    # the floors verify prints for a streamed class are those of the training samples: recompute them
    case("stream_floor_recorded_is_training_floor", ["sh", "-c", "true"], 0, "", check=training_floor_check)
    # under a small --mem (the method of snapshots, out of core) a merged class whose members' vectors
    # outnumber its rows must still get at most n orthonormal vectors, and the model the in-memory one
    case("stream_mem_merged_class_rank", ["npgc", "train", "sp/spd.npg", "sp/TR", "-o", "st/Mmem", "--energy",
                                          "0.999999", "--mem", "20k"], 0, "", check=ranks_at_most_rows("st/Mmem"))
    case("stream_mem_merged_class_eval", ["npgc", "eval", "sp/spd.npg", "st/Mmem", "sp/TE", "-o", "out/st_mem"], 0,
         "", check=out_equals("out/st_mem/u.npy", np.array([np.linalg.solve(heat_K(grid(6, 5), k, True),
                                                                            np.load(path("sp/TR/src.npy")))
                                                            for k in np.load(path("sp/TE/kappa.npy"))]), 1e-8),
         after="stream_mem_merged_class_rank")
    write("st/share.npg", "dim N\ninput a : real[N]\ninput b : real[N]\nshare a, b\noutput y[i:N] = a[i] * b[i]\n")
    a, b = 1 + RNG.random((40, 6)), 1 + RNG.random((40, 6))
    data_dir("st/SD", {"a": a, "b": b})
    case("stream_mem_shared_full_rank", ["npgc", "train", "st/share.npg", "st/SD", "-o", "st/MS", "--energy", "1",
                                         "--mem", "5k"], 0, "", check=ranks_at_most_rows("st/MS"))
    case("stream_mem_shared_full_rank_eval", ["npgc", "eval", "st/share.npg", "st/MS", "st/SD", "-o", "out/st_ms"], 0,
         "", check=out_equals("out/st_ms/y.npy", a * b, 1e-10), after="stream_mem_shared_full_rank")


def reseal(d, edit):
    """d/manifest's lines through `edit`, with the checksum a forger who knows the format computes."""
    with open(path(d, "manifest"), "rb") as f:
        ls = f.read().split(b"\n")[:-1]
    body = b"".join(l + b"\n" for l in edit(ls) if not l.startswith(b"manifest "))
    with open(path(d, "manifest"), "wb") as f:
        f.write(body + b"manifest fnv1a64 %016x\n" % fnv1a64(body))


def forge_stream_cases():
    """The streamed-basis lines of a model (issue 30: 'streamed C', 'floor Q l2 .. linf ..') changed and
    resealed: refused naming the model, or (a repeated line) the genuine model's output."""
    def sub(prefix, new):
        return lambda ls: [new if l.startswith(prefix) else l for l in ls]
    forgeries = {
        "floor_nan": sub(b"floor r2", b"floor r2 l2 nan linf nan"),
        "floor_negative": sub(b"floor r2", b"floor r2 l2 -0.5 linf -1"),
        "floor_above_one": sub(b"floor r2", b"floor r2 l2 1e300 linf 1e308"),
        "floor_removed": lambda ls: [l for l in ls if not l.startswith(b"floor r2")],
        "floor_unknown": sub(b"floor r2", b"floor zz l2 0.1 linf 0.1"),
        "floor_of_kept_class": lambda ls: ls + [b"floor a l2 0.5 linf 0.5"],
        "floor_garbage": sub(b"floor r2", b"floor r2 l2 abc linf"),
        "streamed_removed": lambda ls: [l for l in ls if l != b"streamed 1"],
        "streamed_input_class": lambda ls: ls + [b"streamed 0"],
        "streamed_output_class": lambda ls: ls + [b"streamed 3"],
        "streamed_out_of_range": lambda ls: ls + [b"streamed 99"],
        "streamed_negative": lambda ls: ls + [b"streamed -1"],
        "floor_twice": lambda ls: ls + [l for l in ls if l.startswith(b"floor r2")],
        "streamed_twice": lambda ls: ls + [b"streamed 1"],
    }
    for name, edit in forgeries.items():
        d = "st/F_" + name
        shutil.copytree(path("ip/MG"), path(d))
        reseal(d, edit)
        if name.endswith("_twice"):
            case("stream_forge_%s_eval" % name, ["npgc", "eval", "ip/nb.npg", d, "ip/T", "-o", "out/stf_" + name],
                 "either", d, check=lambda p, name=name: close(np.load(path("out/stf_%s/a.npy" % name)),
                                                               np.load(path("st/OK/a.npy")), 1e-13, "a"))
        else:
            case("stream_forge_%s_eval" % name, ["npgc", "eval", "ip/nb.npg", d, "ip/T", "-o", "out/stf_" + name], 1, d)
            case("stream_forge_%s_verify" % name, ["npgc", "verify", "ip/nb.npg", d, "ip/T", "--tol", "1"], 1, d)


def ranks_at_most_rows(model):
    """A check: every class line of the model's manifest has m <= n."""
    def check(proc):
        for line in open(path(model, "manifest")):
            f = line.split()
            if f[0] == "class" and int(f[f.index("m") + 1]) > int(f[f.index("n") + 1]):
                return "%s: %s" % (model, line.strip())
        return None
    return check


def training_floor_check(proc):
    """MK keeps r2's basis; MG records r2's floor on the training samples: they agree with numpy."""
    x = np.load(path("ip/D/x.npy"))
    B = np.load(path("st/MK/basis_1.npy"))
    fl = []
    for xs in x:
        d = xs[None, :, :] - xs[:, None, :]
        r2 = np.sum(d * d, axis=2) + 0.05
        np.fill_diagonal(r2, 1.0)
        y = r2.ravel()
        fl.append(np.linalg.norm(y - B @ (B.T @ y)) / np.linalg.norm(y))
    for line in open(path("ip/MG/manifest")):
        if line.startswith("floor r2 "):
            rec = float(line.split()[3])
            return None if abs(rec - np.mean(fl)) <= 1e-6 * np.mean(fl) + 1e-12 else \
                "recorded floor %g, numpy %g" % (rec, np.mean(fl))
    return "no floor line for r2"


# ------------------------------------------------------------------ the Python module

PY_HEAD = r'''
import os, sys, filecmp, numpy as np, npg
W = sys.argv[1]
os.chdir(W)
prog = npg.compile("ip/nb.npg")
X = np.load("ip/D/x.npy"); XV = np.load("ip/V/x.npy"); XT = np.load("ip/T/x.npy")
full = prog.full(params="ip/D")
def train(d=None, **kw):
    kw.setdefault("valid_holdout", 0)  # as ip/MG: no automatic choice unless a case asks for one
    tr = npg.Trainer(full, **kw)
    for x in X: tr.add(x=x)
    return tr.finish(d)
def refused(fn, *words, kinds=(npg.Error, TypeError, ValueError)):
    try:
        r = fn()
    except kinds as e:
        m = str(e)
        for w in words:
            assert w in m, "message %r lacks %r" % (m, w)
        return m
    raise AssertionError("accepted, returned %r" % (r,))
def same_dir(a, b):
    fa, fb = sorted(os.listdir(a)), sorted(os.listdir(b))
    assert fa == fb, (fa, fb)
    for f in fa:
        assert filecmp.cmp(os.path.join(a, f), os.path.join(b, f), shallow=False), f
A0 = full(x=XT[0])["a"].copy()
'''

PY_CASES = {
    "interp_same_as_npgc": "m = train('py_MI', interp=['w'])\nsame_dir('py_MI', 'ip/MI')\nassert m.interpolated('w') > 0",
    "interp_str_is_one_name": "m = train(interp='w')\nassert m.interpolated('w') > 0",
    "valid_same_as_npgc": "m = train('py_MV', valid={'x': XV})\nsame_dir('py_MV', 'ip/MV')",
    "valid_holdout_same_as_npgc": "m = train('py_M2', valid_holdout=0.5)\nsame_dir('py_M2', 'ip/M2')",
    "galerkin_model_interpolated_none": "m = train(galerkin=['w'])\nassert m.interpolated('w') is None\n"
                                        "assert m.reductions().strip() == '', m.reductions()",
    "interpolated_unknown_stage": "m = npg.load(prog, 'ip/MI')\nrefused(lambda: m.interpolated('nosuch'), 'nosuch')",
    "interpolated_none_argument": "m = npg.load(prog, 'ip/MI')\nrefused(lambda: m.interpolated(None), 'interpolated', 'str')",
    "interpolated_int_argument": "m = npg.load(prog, 'ip/MI')\nrefused(lambda: m.interpolated(3), 'interpolated', 'str')",
    "interpolated_loaded": "m = npg.load(prog, 'ip/MI')\nassert m.interpolated('w') == int(open('ip/MI/manifest').read()"
                           ".split('interp w k ')[1].split()[0])",
    "reductions_loaded": "m = npg.load(prog, 'ip/MV')\nassert 'stage w' in m.reductions(), m.reductions()",
    "interp_ineligible": "refused(lambda: train(interp=['a']), 'a')",
    "interp_unknown": "refused(lambda: train(interp=['nosuch']), 'nosuch')",
    "interp_and_galerkin": "refused(lambda: train(interp=['w'], galerkin=['w']), 'w')",
    "interp_not_names": "refused(lambda: train(interp=[3]), 'interp')",
    "interp_bytes": "refused(lambda: train(interp=b'w'), 'interp')",
    "oversample_low": "refused(lambda: train(interp=['w'], interp_oversample=0.5), 'interp_oversample')",
    "oversample_nan": "refused(lambda: train(interp=['w'], interp_oversample=float('nan')), 'interp_oversample')",
    "oversample_str": "refused(lambda: train(interp=['w'], interp_oversample='3'))",
    "holdout_big": "refused(lambda: train(valid_holdout=0.9), 'valid_holdout')",
    "holdout_nan": "refused(lambda: train(valid_holdout=float('nan')), 'valid_holdout')",
    "holdout_none_held": "refused(lambda: train(valid_holdout=1e-9), 'valid')",
    "valid_and_holdout": "refused(lambda: train(valid={'x': XV}, valid_holdout=0.2), 'valid')",
    "valid_empty": "refused(lambda: train(valid={}), 'valid')",
    "valid_not_dict": "refused(lambda: train(valid=XV), 'valid')",
    "valid_zero_samples": "refused(lambda: train(valid={'x': XV[:0]}), 'valid')",
    "valid_wrong_dims": "refused(lambda: train(valid={'x': XV[:, :3]}), 'N')",
    "valid_unknown_name": "refused(lambda: train(valid={'q': XV}), 'q')",
    "valid_nan": "refused(lambda: train(valid={'x': np.where(XV > 1, np.nan, XV)}), 'NaN')",
    "valid_int_dtype": "refused(lambda: train(valid={'x': XV.astype(np.int64)}))",
    # a param among the validation samples would rebind the trainer's evaluator: refused, and nothing changed
    "valid_with_param_refused": "refused(lambda: train(valid={'x': XV, 'mass': np.full((10, 8), 5.0)}), 'mass')\n"
                                "assert np.array_equal(full(x=XT[0])['a'], A0), 'the evaluator was changed'",
    "verify_test_with_param_refused": "m = npg.load(prog, 'ip/MG')\n"
                                      "refused(lambda: m.verify(test={'x': XT, 'mass': np.full((8, 8), 5.0)}, full=full),"
                                      " 'mass')\nassert np.array_equal(full(x=XT[0])['a'], A0), 'the evaluator was changed'",
    "keep_bases_list": "refused(lambda: train(keep_bases=['r2']), 'keep_bases')",
    "keep_bases_all_same_as_npgc": "m = train('py_MK', keep_bases='all')\nsame_dir('py_MK', 'st/MK')\n"
                                   "red = m.reduced(); red(x=XT[0]); assert red.lift('r2').shape == (8, 8)",
    "keep_bases_default_same_as_npgc": "m = train('py_MG')\nsame_dir('py_MG', 'ip/MG')",
    "keep_bases_empty": "refused(lambda: train(keep_bases=''), 'keep_bases')",
    "keep_bases_unknown": "refused(lambda: train(keep_bases='zz'), 'zz')",
    "streamed_lift_refused": "m = npg.load(prog, 'ip/MG'); red = m.reduced(); red(x=XT[0])\n"
                             "refused(lambda: red.lift('r2'), 'r2', 'keep')",
    "streamed_basis_refused": "m = npg.load(prog, 'ip/MG')\nrefused(lambda: m.basis('r2'), 'r2', 'keep_bases')",
    "streamed_coords_kept": "m = npg.load(prog, 'ip/MG'); red = m.reduced(); red(x=XT[0])\n"
                            "assert red.coords('r2').shape == (m.basis_sizes['{r2}'],)",
    "streamed_verify_floor": "m = npg.load(prog, 'ip/MG')\nr = m.verify(test={'x': XT}, full=full)\n"
                             "assert np.isnan(r['w']['l2']) and r['w']['floor'] > 0, r['w']",
    "interp_reduced_equals_npgc_eval": "m = npg.load(prog, 'ip/MI'); red = m.reduced()\n"
                                       "got = np.array([(red(x=x), red.lift('a'))[1] for x in XT])\n"
                                       "want = np.load('out/ip_MI/a.npy')\nassert np.max(abs(got - want)) <= 1e-13 * "
                                       "np.max(abs(want)), np.max(abs(got - want))",
    "valid_fortran_order": "m = train('py_MVF', valid={'x': np.asfortranarray(XV)})\nsame_dir('py_MVF', 'ip/MV')",
    "valid_strided_view": "big = np.concatenate([XV, XV], axis=2)\nm = train('py_MVS', valid={'x': big[:, :, :3]})\n"
                          "same_dir('py_MVS', 'ip/MV')",
    "save_reload_interp": "m = npg.load(prog, 'ip/MI')\nm.save('py_SAVED')\nm2 = npg.load(prog, 'py_SAVED')\n"
                          "assert m2.interpolated('w') == m.interpolated('w')\nsame_dir('py_SAVED', 'ip/MI')",
    "bind_other_table_sparse": "p2 = npg.compile('sp/spd.npg')\nD = {k: np.load('sp/D_grid/%s.npy' % k) for k in "
                               "('nbr', 'src', 'kappa')}\nf = p2.full(params={'nbr': D['nbr'], 'src': D['src']})\n"
                               "u1 = f(kappa=D['kappa'][0])['u']\nnb2 = np.load('sp/D_lopsided/nbr.npy')\n"
                               "f.bind({'nbr': nb2, 'src': D['src']})\nu2 = f(kappa=D['kappa'][0])['u']\n"
                               "want = np.load('out/sp_spd_lopsided/u.npy')[0]\n"
                               "assert np.max(abs(u2 - want)) <= 1e-12 * np.max(abs(want)), np.max(abs(u2 - want))\n"
                               "assert np.max(abs(u1 - u2)) > 1e-3, 'the table change had no effect'",
    "forced_by_statement_reason": "open('nbs.npg', 'w').write(open('ip/nb.npg').read() + 'basis w: reduce interp\\n')\n"
                                  "p2 = npg.compile('nbs.npg')\ntr = npg.Trainer(p2.full(params='ip/D'))\n"
                                  "for x in X: tr.add(x=x)\nm = tr.finish()\nassert m.interpolated('w')\n"
                                  "assert 'basis STAGE: reduce interp' in m.reductions(), m.reductions()",
    "valid_small_mem_same_as_npgc": "m = train('py_MVM', valid={'x': XV}, mem=10000)\nsame_dir('py_MVM', 'ip/MVM')",
    "threads_interp_model": "import threading\nm = npg.load(prog, 'ip/MI')\nr0 = m.reduced()\n"
                            "ref = [(r0(x=x), r0.lift('a').copy())[1] for x in XT]\nerrs = []\n"
                            "def work(t):\n    red = m.reduced()\n    for it in range(200):\n"
                            "        k = (t + it) % len(XT)\n        red(x=XT[k])\n"
                            "        if not np.array_equal(red.lift('a'), ref[k]): errs.append((t, it)); return\n"
                            "ts = [threading.Thread(target=work, args=(t,)) for t in range(4)]\n"
                            "[t.start() for t in ts]; [t.join() for t in ts]\nassert not errs, errs",
    "readme_from_python": "os.chdir(os.environ['NPG_SRC'])\nimport runpy, tempfile\n"
                          "d = tempfile.mkdtemp(); os.chdir(d)\n"
                          "os.symlink(os.path.join(os.environ['NPG_SRC'], 'examples'), 'examples')\n"
                          "runpy.run_path(os.path.join(W, 'readme.py'))\nassert os.path.exists('MODEL/manifest')",
}


def docs_name(*words):
    """A check: docs/reducing.md (the commands' documentation in docs/) mentions every word."""
    def check(proc):
        text = open(os.path.join(SRC, "docs/reducing.md")).read()
        missing = [w for w in words if w not in text]
        return "docs/reducing.md does not mention %s" % missing if missing else None
    return check


def readme_python():
    """The README's "From Python" example, as the reader copies it."""
    text = open(os.path.join(SRC, "README.md")).read()
    block = text.split("## From Python", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    write("readme.py", block)


def python_cases():
    if not os.path.isdir(os.path.join(BUILD, "python")):
        return
    readme_python()
    env = dict(os.environ, PYTHONPATH=os.path.join(BUILD, "python"), PYTHONDONTWRITEBYTECODE="1", NPG_SRC=SRC)
    if SANITIZED:
        lib = subprocess.run(["cc", "-print-file-name=libasan.so"], stdout=subprocess.PIPE).stdout.decode().strip()
        env.update(LD_PRELOAD=lib, ASAN_OPTIONS="detect_leaks=0:abort_on_error=1",
                   UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    case("py_docs_keywords", ["sh", "-c", "true"], 0, "",
         check=docs_name("interp=", "galerkin=", "interp_oversample=", "valid=", "valid_holdout=", "keep_bases=",
                         "model.interpolated", "model.reductions"))
    for name, body in PY_CASES.items():
        write("py/%s.py" % name, PY_HEAD + body + "\nprint('OK')\n")
        after = "interp_eval_MI" if "npgc_eval" in name else "interp_valid_fraction_dot" if "holdout_same" in name \
            else "sparse_spd_lopsided_solve" if "sparse" in name else "interp_valid_small_mem" if "small_mem" in name \
            else "interp_valid_dir_choice"
        case("py_" + name, ["/usr/bin/python3", path("py/%s.py" % name), W], 0, "OK", stream="out", env=env,
             after=after)


# ------------------------------------------------------------------ the C API (tests/hostile/trial3_api.c)

API_BIN = os.path.join(W, "trial3_api")


def build_api():
    trialkit.build_api(SRC, BUILD, "tests/hostile/trial3_api.c", API_BIN)


def api_cases():
    build_api()
    for name in ("valid_set_param", "verify_set_param", "tune_valid_set_param"):
        case("api_" + name, [API_BIN, name, W], 0, "OK", stream="out")
    # NpgTrainOptions' interpolation and streaming fields out of range, through the trainer and npg_tune
    for field in ("oversample_half", "oversample_nan", "oversample_negative", "ninterp_negative", "interp_stage_null",
                  "interp_name_null", "ngalerkin_negative", "galerkin_stage_null", "valid_count_negative",
                  "holdout_nan", "keep_bases_empty"):
        case("api_options_" + field, [API_BIN, "options_" + field, W], 0, "OK", stream="out")
        if field not in ("valid_count_negative", "holdout_nan"):
            case("api_tune_options_" + field, [API_BIN, "options_" + field, W, "tune"], 0, "OK", stream="out",
                 timeout=300)


# ------------------------------------------------------------------ running

def run(c):
    argv = list(c["argv"])
    if argv[0] == "npgc":
        argv[0] = NPGC
    t0 = time.time()
    try:
        p = subprocess.run(argv, cwd=W, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           timeout=c["timeout"], env=c["env"])
    except subprocess.TimeoutExpired:
        return c["name"], "hangs: no exit within %d s" % c["timeout"], "", time.time() - t0
    err, out = p.stderr.decode("utf-8", "replace"), p.stdout.decode("utf-8", "replace")
    text = out if c["stream"] == "out" else err
    first = (err.strip() or out.strip()).split("\n", 1)[0]
    status, msg, problem = c["status"], c["msg"], None
    if p.returncode < 0:
        problem = "killed by signal %d" % -p.returncode
    elif any(m in err for m in SANITIZER_MARKS):
        problem = "sanitizer report: " + next(l for l in err.splitlines() if any(m in l for m in SANITIZER_MARKS))[:160]
    elif status == "either":
        if p.returncode == 0:
            problem = c["check"](p) if c["check"] else None
        elif p.returncode in (1, 2):
            problem = "refused with no message" if not err.strip() else \
                "message lacks %r" % msg if msg and msg not in err else None
        else:
            problem = "exit %d" % p.returncode
    else:
        if status is None:
            problem = "exit 0 on bad input" if p.returncode == 0 else \
                "exit %d" % p.returncode if p.returncode > 2 else None
        elif p.returncode != status:
            problem = "exit 0 on bad input" if p.returncode == 0 else "exit %d, expected %d" % (p.returncode, status)
        if not problem:
            if msg and msg not in text:
                problem = "%s lacks %r" % ("stdout" if c["stream"] == "out" else "stderr", msg)
            elif p.returncode != 0 and not err.strip() and not out.strip():
                problem = "no message"
            elif c["check"]:
                problem = c["check"](p)
    if problem and c["stream"] == "out" and argv[0].endswith("python3") and "Error" in err:
        problem += ": " + err.strip().splitlines()[-1][:300]
    return c["name"], problem, first[:200] + ("" if first else " [no output]"), time.time() - t0


def run_all(todo):
    """Cases in two workers; a case waits for the one it names in `after` (its output is this one's input)."""
    done, results = {}, []
    by_name = {c["name"]: c for c in todo}
    left = list(todo)
    while left:
        wave = [c for c in left if not c["after"] or c["after"] not in by_name or c["after"] in done]
        if not wave:
            raise SystemExit("cases wait for each other: %s" % [c["name"] for c in left])
        with ThreadPoolExecutor(max_workers=2) as pool:
            for r in pool.map(run, wave):
                results.append(r)
                done[r[0]] = r
        left = [c for c in left if c["name"] not in done]
    return results


def main():
    t0 = time.time()
    sparse_cases()
    interp_cases()
    stream_cases()
    forge_stream_cases()
    python_cases()
    api_cases()
    names = [c["name"] for c in CASES]
    dup = {n for n in names if names.count(n) > 1}
    assert not dup, "case names used twice: %s" % sorted(dup)
    stale = [k for k in KNOWN_FAILURES if k not in names]
    assert not stale, "known failures that are not cases: %s" % stale
    todo = [c for c in CASES if not ONLY or any(o in c["name"] for o in ONLY)]
    by_name = {c["name"]: c for c in CASES}
    while any(c["after"] and by_name[c["after"]] not in todo for c in todo):   # what the chosen ones read
        todo += [by_name[c["after"]] for c in todo if c["after"] and by_name[c["after"]] not in todo]
    results = run_all(todo)
    failed, still_known, fixed = [], [], []
    for name, problem, first, secs in results:
        if VERBOSE:
            print("%-55s %5.1fs %s\n    %s" % (name, secs, problem or "ok", first))
        if name in KNOWN_FAILURES:
            (still_known if problem else fixed).append((name, problem))
        elif problem:
            failed.append((name, problem, first))
    kinds = {}
    for c in todo:
        kinds[c["name"].split("_")[0]] = kinds.get(c["name"].split("_")[0], 0) + 1
    print("hostile trial 3: %d cases in %.0f s (%s)" % (len(todo), time.time() - t0,
                                                       ", ".join("%s %d" % kv for kv in sorted(kinds.items()))))
    for name, problem in still_known:
        print("known failure %s: %s (%s)" % (name, problem, KNOWN_FAILURES[name]))
    for name, _ in fixed:
        print("known failure %s now passes: move it out of KNOWN_FAILURES" % name)
    by_name = {c["name"]: c for c in CASES}
    for name, problem, first in failed:
        print("FAIL %s: %s\n    %s\n    first line: %s" % (name, problem, " ".join(
            repr(a) if (" " in a or not a) else a for a in by_name[name]["argv"]), first))
    print("%d of %d cases ended correctly (%d known failures)" % (len(todo) - len(failed) - len(still_known),
                                                                len(todo), len(still_known)))
    if failed:
        print("work folder kept: %s" % W)
        return 1
    shutil.rmtree(W, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
