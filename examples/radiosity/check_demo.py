"""check_demo.py DIR [MAX_MEDIAN MAX_WORST MAX_MEDIAN_INDIRECT] — checks what `npg-radiosity demo` wrote.

The report parses and holds every figure; no test frame was a training sample; the
a-posteriori bound held on every frame (and is checked again here from the per-frame
figures); the median and worst relative L2 errors of b, and the median against the indirect
part b - e, are below the tolerances (the emitters' b = e dominates ||b||, so the indirect
error is the one a reduction that loses the interreflection cannot hide); every frame folder holds g, v, b_full, b_reduced; the
reduced b of the last frame is re-derived as what the report says: its relative L2 error
against b_full. The precomputation has one split: samples + training = total, and
training = snapshots + PCA + pre-multiplication + learned visibility + model files
(the library's phase times). With LOG (the demo's stdout), the log says the same once,
and a frame without Arvo's bound says why (||rhoF|| >= 1) instead of printing nan.
"""
import json
import os
import sys

import numpy as np

root = sys.argv[1]
max_median = float(sys.argv[2]) if len(sys.argv) > 2 else 0.1
max_worst = float(sys.argv[3]) if len(sys.argv) > 3 else 0.25
max_indirect = float(sys.argv[4]) if len(sys.argv) > 4 else 1.0
log = sys.argv[5] if len(sys.argv) > 5 else None
r = json.load(open(os.path.join(root, "report.json")))
for key in ("faces", "training_samples", "basis_sizes", "precomputation_seconds", "full_frame_seconds",
            "reduced_frame_seconds", "speedup", "model_bytes", "error", "per_frame"):
    assert key in r, f"report.json lacks {key}"
assert r["test_frames_in_training"] == 0, "a test frame is a training sample"
assert r["bound_holds_every_frame"], "the a-posteriori bound fails on a frame"
assert r["error"]["median"] <= max_median, f"median error {r['error']['median']} above {max_median}"
assert r["error"]["max"] <= max_worst, f"worst error {r['error']['max']} above {max_worst}"
assert r["error"]["median_indirect"] <= max_indirect, \
    f"median error against b - e {r['error']['median_indirect']} above {max_indirect}"
assert r["reduced_frames_failed"] == 0, "a frame failed in reduced space"
assert r["reduced_frame_seconds"] > 0 and r["full_frame_seconds"]["total"] > 0
pre = r["precomputation_seconds"]
parts = ("snapshots", "pca", "premultiplication", "learned_visibility", "model_files")
assert all(pre[k] >= 0 for k in parts), f"a negative phase: {pre}"
# %.4g in the report: sums agree to 1e-3 relative
assert abs(pre["samples_incl_ray_casting"] + pre["finish"] - pre["total"]) <= 1e-3 * pre["total"] + 1e-3, pre
assert abs(sum(pre[k] for k in parts) - pre["finish"]) <= 1e-3 * pre["finish"] + 1e-3, pre
if log:
    text = open(log).read()
    assert text.count("precomputation") == 1, "the log gives the precomputation more than once"
    assert "nan" not in text, "the log prints nan"
    for anim, pf in r["per_frame"].items():
        assert all((a is None) == (rf >= 1) for a, rf in zip(pf["bound_arvo"], pf["rho_f_linf"])), "Arvo's bound where ||rhoF|| >= 1"
    nobound = sum(x is None for pf in r["per_frame"].values() for x in pf["bound_arvo"])
    assert text.count("no Arvo bound: ||rhoF||") == nobound, "a frame without Arvo's bound does not say why"
for anim, pf in r["per_frame"].items():
    for k, (err, bound) in enumerate(zip(pf["linf_error"], pf["bound_neumann"])):
        assert bound is None or err <= bound * (1 + 1e-9) + 1e-12, f"{anim} frame {k}: {err} > bound {bound}"
    k = len(pf["relative_l2"]) - 1
    d = os.path.join(root, anim, f"frame_{k:04d}")
    arrays = {n: np.load(os.path.join(d, n + ".npy")) for n in ("g", "v", "b_full", "b_reduced")}
    F = r["faces"]
    assert arrays["v"].shape == (F, F) and arrays["b_full"].shape == (F,)
    b, bt = arrays["b_full"], arrays["b_reduced"]
    err = np.linalg.norm(b - bt) / np.linalg.norm(b)
    assert abs(err - pf["relative_l2"][k]) <= 1e-4 * max(err, 1e-3), f"{anim}: {err} against {pf['relative_l2'][k]}"
for f in ("error.png", "window_arvo.png", "window_bound.png", "tri.npy", "rho.npy", "e.npy"):
    assert os.path.exists(os.path.join(root, f)), f"{f} missing"
print(f"demo report: {r['faces']} faces, median error {r['error']['median']:.3%}, worst {r['error']['max']:.3%}, "
      f"bound holds, speedup {r['speedup']:.0f}x")
