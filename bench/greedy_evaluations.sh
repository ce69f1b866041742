#!/bin/sh
# greedy_evaluations.sh BEFORE_NPGC AFTER_NPGC [RUNS] — greedy training (issue 41) by two builds of
# npgc in the same run, alternating, RUNS times each (3), on the thermal block of
# examples/thermalblock (numpy's assembly): 3 x 3 blocks at --grid 19 (400 unknowns) over the
# 512 corners of [0.1, 1]^9 (pyMOR's sample_uniformly(2)), and 2 x 2 at --grid 60 (3,721) over
# the 625 points of a 5-per-block grid, from the first point, as bench/pymor_thermalblock.py
# runs greedy (`--tol 1e-6 --absolute --center off --basis u:cap=N,energy=1 --basis
# u.num1:cap=1`). Prints each run's wall, user and system seconds and the full evaluations it
# reports (a build without the count prints none), then whether the two builds' models are the
# same files byte for byte (the manifest's timing lines left out). bench/thermalblock.md,
# "Greedy training's full evaluations".
# Usage from the repository root: sh bench/greedy_evaluations.sh OLD/npgc build/npgc
set -eu
if [ $# -lt 2 ] || [ ! -x "$1" ] || [ ! -x "$2" ]; then
  echo "usage: greedy_evaluations.sh BEFORE_NPGC AFTER_NPGC [RUNS]: two npgc executables" >&2
  exit 2
fi
BEFORE=$1 AFTER=$2 RUNS=${3:-3}
W=$(mktemp -d "${TMPDIR:-/tmp}/npg_greedy_XXXXXX")
trap 'rm -rf "$W"' EXIT
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
PY=/usr/bin/python3
TB=examples/thermalblock
# START/ (the params and the pool's first point) and POOL/ (the points) per case
$PY $TB/thermalblock_data.py "$W/d3" --blocks 3x3 --grid 19 --train 1 --test 1 >/dev/null
$PY $TB/thermalblock_data.py "$W/d2" --blocks 2x2 --grid 60 --train 1 --test 1 >/dev/null
$PY - "$W" <<'PY'
import itertools, os, sys
import numpy as np
w = sys.argv[1]
for case, pts in (("d3", itertools.product([0.1, 1.0], repeat=9)),
                  ("d2", itertools.product(np.linspace(0.1, 1, 5), repeat=4))):
    mu = np.array(list(pts))
    for sub, rows in (("start", mu[:1]), ("pool", mu)):
        os.makedirs(os.path.join(w, case, sub))
        np.save(os.path.join(w, case, sub, "mu.npy"), rows)
    for name in os.listdir(os.path.join(w, case, "data")):
        if name != "mu.npy":
            np.save(os.path.join(w, case, "start", name), np.load(os.path.join(w, case, "data", name)))
PY
run() { # label npgc case budget
  /usr/bin/time -f "%e %U %S" -o "$W/time" "$2" train $TB/thermalblock.npg "$W/$3/start" --greedy "$W/$3/pool" \
    --tol 1e-6 --absolute --budget "$4" --center off --basis "u:cap=$4,energy=1" --basis u.num1:cap=1 \
    -o "$W/model_$3_$1" >"$W/out" 2>"$W/err"
  line=$(grep greedily "$W/out")
  echo "$3 $1: wall $(cut -d' ' -f1 "$W/time") s, user $(cut -d' ' -f2 "$W/time") s, system $(cut -d' ' -f3 "$W/time") s;" \
    "$(echo "$line" | sed -n 's/.*greedily on \([0-9]*\) samples.*/\1 samples/p')" \
    "$(echo "$line" | sed -n 's/.*; \([0-9]*\) full evaluations.*/(\1 full evaluations)/p')"
}
i=0
while [ $i -lt "$RUNS" ]; do
  for case in d3:200 d2:60; do
    run before "$BEFORE" "${case%:*}" "${case#*:}"
    run after "$AFTER" "${case%:*}" "${case#*:}"
  done
  i=$((i + 1))
done
for case in d3 d2; do
  echo "$case: the two builds' models the same byte for byte: $(sh bench/same_models.sh "$W/model_${case}_before" "$W/model_${case}_after")"
done
