#!/bin/sh
# burgers.sh [NX NY] — pyMOR's burgers_ei.py setting as a reduced simulation (examples/burgers):
# 120 x 60 cells, 100 steps to T = 0.3; trained on 11 flux blends, verified over the whole
# trajectory on 3 held-out blends (goal: relative error <= 1e-3), and the reduced step in
# coordinates timed against the full step (UMFPACK, the evaluator compiled by cc -O3) in the
# same run (goal: >= 100x). From the repository root after a build; writes build/bench_burgers/.
set -eu
nx=${1:-120}
ny=${2:-60}
B=build
W=$B/bench_burgers
PY=/usr/bin/python3
mkdir -p "$W"
$PY examples/burgers/burgers_data.py "$W/train" --nx "$nx" --ny "$ny"
$PY examples/burgers/burgers_data.py "$W/test" --nx "$nx" --ny "$ny" --blends 0.15,0.55,0.85
echo "== train --steps 100 (11 blends, energy 0.999999)"
$B/npgc train examples/burgers/burgers.npg "$W/train" --steps 100 --energy 0.999999 --cc -o "$W/model" | grep -v '^phases'
echo "== verify --steps 100 (held-out blends 0.15, 0.55, 0.85)"
$B/npgc verify examples/burgers/burgers.npg "$W/model" "$W/test" --steps 100 --every 5 --tol 1e-3 --cc --png "$W/error.png" || true
echo "== bench --steps 100 (full step: cc -O3 and UMFPACK)"
OPENBLAS_NUM_THREADS=1 $B/npgc bench examples/burgers/burgers.npg "$W/model" "$W/test" --steps 100 --cc --reps 3
