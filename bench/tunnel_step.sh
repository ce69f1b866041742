#!/bin/sh
# tunnel_step.sh [CELLS [FRAMES]] — the wind tunnel's step as a program (examples/fluids/tunnel_step.npg,
# paper Fig. 2 left, fixed obstacle) against the hand-written driver (npg-fluids tunnel-full), same run:
#   1. the driver's run with --dump-step, and `npgc simulate` of the program over every frame: the
#      largest relative difference of the velocity and the flux from the driver's frames;
#   2. the reduced step trained from trajectories (train --steps 100 from frames 0, 50, ..., 200)
#      and checked over a trajectory from frame 250 (verify --steps: error against its floor);
#   3. bench --steps --cc: the reduced step in coordinates against the program's full step compiled
#      by cc -O3; the driver's own step time is its report.json's full_step_seconds.
# Usage from the repository root after a build; writes build/bench_tunnel_step/.
set -eu
cells=${1:-2000}
frames=${2:-400}
B=build
W=$B/bench_tunnel_step
PY=/usr/bin/python3
PROG=examples/fluids/tunnel_step.npg
rm -rf "$W"
mkdir -p "$W"
echo "== npg-fluids tunnel-full --cells $cells --frames $frames --pulse 0 --dump-step"
$B/npg-fluids tunnel-full --out "$W/run" --frames "$frames" --cells "$cells" --pulse 0 --particles 0 \
  --png-every 100000 --vtk-every 100000 --dump-step "$W/step" 2>&1 | grep -v "^npg-fluids: mesh"
$PY -c "import json; r = json.load(open('$W/run/report.json')); print('driver full step %.3g ms' % (1e3 * r['full_step_seconds']['total']))"
echo "== npgc simulate $PROG --steps $frames against the driver's frames"
$B/npgc simulate $PROG "$W/step" --steps "$frames" -o "$W/sim" >/dev/null
$PY - "$W/sim" "$W/step/driver" <<'PY'
import sys, numpy as np
for n in ("u", "f"):
    a, b = np.load(f"{sys.argv[1]}/{n}.npy"), np.load(f"{sys.argv[2]}/{n}.npy")
    e = np.linalg.norm(a - b, axis=2)[0] / np.linalg.norm(b, axis=2)[0]
    print(f"{n}: largest relative difference from the driver {e.max():.3g} (frame {e.argmax()} of {len(e) - 1})")
PY
$PY examples/fluids/tunnel_step_data.py "$W/step" "$W/train" --starts 0,50,100,150,200
$PY examples/fluids/tunnel_step_data.py "$W/step" "$W/test" --starts 250
echo "== train --steps 100 (starts 0, 50, ..., 200) --energy 0.999999"
$B/npgc train $PROG "$W/train" --steps 100 --energy 0.999999 -o "$W/model" | grep -v '^phases'
echo "== verify --steps 100 (start 250)"
$B/npgc verify $PROG "$W/model" "$W/test" --steps 100 --every 5 --png "$W/error.png" || true
echo "== bench --steps 100 (full step: cc -O3)"
$B/npgc bench $PROG "$W/model" "$W/test" --steps 100 --cc
