#!/bin/sh
# heat.sh [N_SIDE [STEPS]] — the nonlinear heat equation as a reduced simulation (DESIGN §15,
# examples/heat/heat.npg), at the size of issue 40's goal: 128 x 128 cells, 1,000 steps.
# Trains from 8 trajectories (bump heights 0.5 to 1.5), then checks 3 held-out trajectories
# whose bumps are higher (1.6 to 1.8: an initial amplitude outside training) over the whole
# rollout against its projection floor, and times the reduced step in coordinates against the
# full step compiled by the system compiler at -O3 (bench --steps --cc), same run, one machine.
# Usage from the repository root after a build; writes build/bench_heat/.
set -eu
n=${1:-128}
T=${2:-1000}
B=build
W=$B/bench_heat
PY=/usr/bin/python3
mkdir -p "$W"
$PY examples/heat/heat_data.py "$W/train" --n "$n" --trajectories 8 --seed 1 --amplitude 0.5:1.5
$PY examples/heat/heat_data.py "$W/test" --n "$n" --trajectories 3 --seed 2 --amplitude 1.6:1.8
# small bases, and the conductivity interpolated at 4 entries per basis vector (DESIGN §12): the
# reduced step's cost is then a few thousand multiply-adds
BASIS=${HEAT_BASIS:---basis u:cap=12 --basis u.next:cap=12 --basis k:cap=8,energy=1 --reduce k:interp --interp-oversample 4}
echo "== train --steps $T --every 10 $BASIS"
# shellcheck disable=SC2086
$B/npgc train examples/heat/heat.npg "$W/train" --steps "$T" --every 10 --cc $BASIS -o "$W/model" | grep -v '^phases'
echo "== verify --steps $T (held-out amplitudes)"
$B/npgc verify examples/heat/heat.npg "$W/model" "$W/test" --steps "$T" --every 10 --cc --png "$W/error.png" || true
echo "== bench --steps $T (full step: cc -O3)"
OPENBLAS_NUM_THREADS=1 $B/npgc bench examples/heat/heat.npg "$W/model" "$W/test" --steps "$T" --cc --reps 3
