#!/usr/bin/python3
"""tunnel_step_data.py DUMP OUT --starts 0,20,40 [--steps N] — a data folder for tunnel_step.npg
or tunnel_step_moving.npg whose trajectories start from frames of the driver's run.

DUMP is the folder `npg-fluids tunnel-full --pulse 0 --dump-step DUMP` wrote: the step's
operators (params), frame 0 (u.npy, f.npy) and the driver's frames 0..T (DUMP/driver/). OUT
gets the same params and, as its initial states, the driver's frames listed by --starts (one
trajectory each): training and held-out trajectories from one run, with the params that
`npgc verify` requires to be the model's. The moving mesh's positions per step (g, gn: one
trajectory × T steps) are cut to the N steps from each start with --steps N (without it they are
left out: the fixed step reads none)."""
import argparse
import os
import shutil
import sys

import numpy as np

STATES = ("u", "f")
PER_STEP = ("g", "gn")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dump", help="the folder of npg-fluids tunnel-full --dump-step")
    ap.add_argument("out", help="the data folder to write")
    ap.add_argument("--starts", required=True, help="driver frames to start from, comma-separated (0,20,40)")
    ap.add_argument("--steps", type=int, help="steps per trajectory (cuts the positions given per step)")
    a = ap.parse_args()
    try:
        starts = [int(s) for s in a.starts.split(",")]
    except ValueError:
        sys.exit("tunnel_step_data.py: --starts %r: expected frames as integers separated by commas" % a.starts)
    traj = {}
    for n in STATES:
        path = os.path.join(a.dump, "driver", n + ".npy")
        if not os.path.exists(path):
            sys.exit("tunnel_step_data.py: %s is missing: is %s a folder of npg-fluids tunnel-full --dump-step?"
                     % (path, a.dump))
        traj[n] = np.load(path)
    frames = traj["u"].shape[1]
    bad = [s for s in starts if not 0 <= s < frames]
    if bad:
        sys.exit("tunnel_step_data.py: --starts: frame %d is not in the driver's run (frames 0..%d)" % (bad[0], frames - 1))
    tmp = a.out.rstrip("/") + ".tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    for name in sorted(os.listdir(a.dump)):
        stem, ext = os.path.splitext(name)
        if ext == ".npy" and stem not in STATES + PER_STEP:
            shutil.copyfile(os.path.join(a.dump, name), os.path.join(tmp, name))
    for n in PER_STEP:
        path = os.path.join(a.dump, n + ".npy")
        if not os.path.exists(path):
            continue
        if a.steps is None:
            continue  # the fixed step reads no positions; tunnel_step_moving.npg then stops naming g.npy
        x = np.load(path)
        if a.steps < 1:
            shutil.rmtree(tmp)
            sys.exit("tunnel_step_data.py: --steps %d: a trajectory needs at least one step" % a.steps)
        end = max(starts) + a.steps
        if end > x.shape[1]:
            shutil.rmtree(tmp)
            sys.exit("tunnel_step_data.py: --steps %d from frame %d needs the positions of %d steps, and %s holds %d"
                     % (a.steps, max(starts), end, path, x.shape[1]))
        np.save(os.path.join(tmp, n + ".npy"), np.ascontiguousarray(np.stack([x[0, s:s + a.steps] for s in starts])))
    for n in STATES:
        np.save(os.path.join(tmp, n + ".npy"), np.ascontiguousarray(traj[n][0, starts]))
    shutil.rmtree(a.out, ignore_errors=True)
    os.rename(tmp, a.out)


if __name__ == "__main__":
    main()
