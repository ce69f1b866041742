#!/bin/sh
# simulate_burgers.sh BUILD_DIR — examples/burgers at 40 x 20 cells: trained from trajectories of
# 11 flux blends, the reduced rollout of 3 held-out blends within 1e-3 of the full one over the
# 100 steps (verify --steps), above its projection floor.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_cli_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
E=examples/burgers
/usr/bin/python3 $E/burgers_data.py "$W/train" --nx 40 --ny 20
/usr/bin/python3 $E/burgers_data.py "$W/test" --nx 40 --ny 20 --blends 0.15,0.55,0.85
"$B/npgc" train $E/burgers.npg "$W/train" --steps 100 --energy 0.999999 -o "$W/m" >"$W/train.txt" || fail "train: $(cat "$W/train.txt")"
"$B/npgc" verify $E/burgers.npg "$W/m" "$W/test" --steps 100 --every 5 --tol 1e-3 >"$W/verify.txt" || fail "verify: $(cat "$W/verify.txt")"
grep -q "^ok: every state's trajectory error within --tol 0.001" "$W/verify.txt" || fail "$(cat "$W/verify.txt")"
echo "simulate_burgers: ok"
