#!/bin/sh
# greedy_routes.sh BEFORE_NPGC AFTER_NPGC [RUNS] — greedy training's full evaluations (issue 41) by
# two builds of npgc, alternating, RUNS times each (1), on the routes beyond one process without a
# hold-out: the thermal block of examples/thermalblock at 3 x 3 blocks, --grid 19 (400 unknowns),
# 300 random points of [0.1, 1]^9, from the first, `--tol 1e-14 --absolute --center off --basis
# u:cap=N,energy=1 --basis u.num1:cap=1 --basis mu:energy=1` to a budget of samples,
#   holdout  the program with a stage w = (u² + 1)^(-1/2) whose reduction is open (the automatic
#            hold-out from 30 samples: every 10th validates the choice, then all retrain), 60 samples;
#   mpi2     the program without its product (not implemented over ranks), over 2 MPI ranks, 40.
# Prints each run's wall, user and system seconds (of mpirun: its ranks' included) and the full
# evaluations it reports, then whether the two builds' models are the same files byte for byte
# (the manifest's timing lines left out). bench/thermalblock.md, "Greedy training's full
# evaluations". Usage from the repository root: sh bench/greedy_routes.sh OLD/npgc build/npgc
set -eu
[ $# -ge 2 ] && [ -x "$1" ] && [ -x "$2" ] || { echo "usage: greedy_routes.sh BEFORE_NPGC AFTER_NPGC [RUNS]" >&2; exit 2; }
BEFORE=$1 AFTER=$2 RUNS=${3:-1} PY=/usr/bin/python3
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
W=$(mktemp -d "${TMPDIR:-/tmp}/npg_greedy_routes_XXXXXX")
trap 'rm -rf "$W"' EXIT
$PY examples/thermalblock/thermalblock_data.py "$W/d" --blocks 3x3 --grid 19 --train 1 --test 1 >/dev/null
$PY - "$W" <<'PY'
import os, sys
import numpy as np
w = sys.argv[1]
mu = np.random.default_rng(2).uniform(0.1, 1, (300, 9))
for sub, rows in (("start", mu[:1]), ("pool", mu)):
    os.makedirs(os.path.join(w, sub))
    np.save(os.path.join(w, sub, "mu.npy"), rows)
for name in os.listdir(os.path.join(w, "d", "data")):
    if name != "mu.npy":
        np.save(os.path.join(w, "start", name), np.load(os.path.join(w, "d", "data", name)))
text = open("examples/thermalblock/thermalblock.npg").read()
open(os.path.join(w, "holdout.npg"), "w").write(text + "output w[i:N] = (u[i] * u[i] + 1)^(-1/2)\n")
open(os.path.join(w, "mpi2.npg"), "w").write(text.replace("basis u: product H\n", ""))
PY
run() { # label npgc case budget [launcher...]
  label=$1 npgc=$2 case=$3 budget=$4
  shift 4
  /usr/bin/time -f "%e %U %S" -o "$W/time" "$@" "$npgc" train "$W/$case.npg" "$W/start" --greedy "$W/pool" \
    --tol 1e-14 --absolute --budget "$budget" --center off --basis "u:cap=$budget,energy=1" --basis u.num1:cap=1 \
    --basis mu:energy=1 $([ "$case" = mpi2 ] && echo --mpi) -o "$W/model_${case}_$label" >"$W/out" 2>"$W/err"
  line=$(grep greedily "$W/out" | head -n 1) # before greedy over ranks, every rank printed its own
  echo "$case $label: wall $(cut -d' ' -f1 "$W/time") s, user $(cut -d' ' -f2 "$W/time") s, system $(cut -d' ' -f3 "$W/time") s;" \
    "$(echo "$line" | sed -n 's/.*greedily on \([0-9]*\) samples.*/\1 samples/p')" \
    "$(echo "$line" | sed -n 's/.*; \([0-9]*\) full evaluations.*/(\1 full evaluations)/p')"
}
MPIRUN="timeout 3000 mpirun --allow-run-as-root --oversubscribe -np 2"
i=0
while [ $i -lt "$RUNS" ]; do
  run before "$BEFORE" holdout 60
  run after "$AFTER" holdout 60
  run before "$BEFORE" mpi2 40 $MPIRUN
  run after "$AFTER" mpi2 40 $MPIRUN
  i=$((i + 1))
done
for case in holdout mpi2; do
  echo "$case: the two builds' models the same byte for byte: $(sh bench/same_models.sh "$W/model_${case}_before" "$W/model_${case}_after")"
done
