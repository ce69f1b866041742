"""estimate_slack.py BUILD_DIR — where radiosity's estimates at h and c lose against their true errors
(docs/estimates.md, "Where radiosity's h and c are loose"): the room of tests/cli/estimate_stream.py (24 faces,
20 training samples, 6 test samples of another seed, --cap 8, every basis kept), each test sample's figure of

- h = s / r (a Galerkin inverse of the diagonal operator r) split into its residual part ‖ρ‖ / (c σ_min(BᵀR̃B)),
  ρ = s̃ − r̃ ∘ (B ĥ) at the reduced inputs s̃ = B_s ŝ, r̃ = B_r r̂, against the error it stands for, ‖ρ / r̃‖ (the
  solve at those inputs; exact, r being diagonal), and its propagation part (the rest of the figure: s's and r's
  errors through the stage's Jacobian) against the error the inputs' errors cause, ‖s / r − s̃ / r̃‖;
- c = h ∘ hᵀ / π (a contraction) split into its exact residual ‖c(h̃) − B_c ĉ‖ and the propagation of h's figure,
  against the error h's error causes, ‖c(h) − c(h̃)‖.

Each ratio is a part's figure over the error it estimates; the effectivity (figure / true error) is printed first.
Run from the repository root; it trains into a temporary folder."""
import os
import subprocess
import sys
import tempfile

import numpy as np

B = sys.argv[1]
sys.path.insert(0, os.path.join(B, "python"))
import npg  # noqa: E402  (the build's module)

PROG = "examples/radiosity/formfactors.npg"


def train(w):
    rdata = os.path.join(B, "radiosity_data")
    subprocess.run([rdata, w + "/RT", "24", "20", "0", "1", "1"], check=True, capture_output=True)
    subprocess.run([rdata, w + "/TEST", "24", "6", "0", "1", "7"], check=True, capture_output=True)
    subprocess.run([os.path.join(B, "npgc"), "train", PROG, w + "/RT", "--cap", "8", "--keep-bases", "all", "-o",
                    w + "/KEEP"], check=True, capture_output=True)
    for line in open(w + "/KEEP/manifest"):
        f = line.split()
        if f[:2] == ["estimate", "h"]:
            return float(f[f.index("sigma") + 1])
    sys.exit("no estimate table for h in the manifest")


def h_split(full, red, basis, ratio):
    """h's figure, its true error, and its residual and propagation parts with the errors they stand for."""
    s, r, h = (np.asarray(full.get(q)).ravel() for q in "srh")
    st, rt, hh = (basis[q] @ red.coords(q) for q in "srh")
    rho = st - rt * hh
    smin = np.linalg.svd(basis["h"].T @ (rt[:, None] * basis["h"]), compute_uv=False)[-1]
    res = np.linalg.norm(rho) / (ratio * smin)
    est = red.estimate("h")
    return dict(est=est, err=np.linalg.norm(h - hh), res=res, solve=np.linalg.norm(rho / rt), prop=est - res,
                inputs=np.linalg.norm(s / r - st / rt), lam=ratio * smin, rmin=rt.min(), rmed=np.median(rt))


def c_split(full, red, basis):
    """c's figure, its true error, its residual and propagation parts with the errors they stand for."""
    F = int(round(np.sqrt(basis["h"].shape[0])))
    c_of = lambda h: (h.reshape(F, F) * h.reshape(F, F).T / np.pi).ravel()  # noqa: E731
    h, hh = np.asarray(full.get("h")).ravel(), basis["h"] @ red.coords("h")
    cc = basis["c"] @ red.coords("c")
    res = np.linalg.norm(c_of(hh) - cc)
    est = red.estimate("c")
    return dict(est=est, err=np.linalg.norm(np.asarray(full.get("c")).ravel() - cc), res=res, prop=est - res,
                inputs=np.linalg.norm(c_of(h) - c_of(hh)))


def main():
    with tempfile.TemporaryDirectory() as w:
        ratio = train(w)
        prog = npg.compile(PROG)
        full = prog.full(params={n: np.load("%s/RT/%s.npy" % (w, n)) for n in ("tri", "rho")})
        g, e, v = (np.load("%s/TEST/%s.npy" % (w, n)) for n in "gev")
        model = npg.load(prog, w + "/KEEP")
        red = model.reduced()
        basis = {q: model.basis(q) for q in "srhc"}
        print("h's σ_min ratio c = %.4g (min over the training samples of λ_min(R) / σ_min(BᵀRB))" % ratio)
        for k in range(len(g)):
            full(g=g[k], e=e[k], v=v[k])
            red(g=g[k], e=e[k])
            h, c = h_split(full, red, basis, ratio), c_split(full, red, basis)
            print("sample %d: h effectivity %.1f: residual part %.3g / solve error %.3g = %.1f (c σ_min %.3g; r̃ min "
                  "%.3g, median %.3g), propagation part %.3g / error from s, r %.3g = %.1f | c effectivity %.1f: "
                  "residual %.3g, propagation part %.3g / error from h %.3g = %.1f"
                  % (k, h["est"] / h["err"], h["res"], h["solve"], h["res"] / h["solve"], h["lam"], h["rmin"],
                     h["rmed"], h["prop"], h["inputs"], h["prop"] / h["inputs"], c["est"] / c["err"], c["res"],
                     c["prop"], c["inputs"], c["prop"] / c["inputs"]))


main()
