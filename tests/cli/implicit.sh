#!/bin/sh
# implicit.sh BUILD_DIR — implicit steps through npgc (issue 43): examples/heat/heat_backward.npg,
# backward Euler written `residual next u = ...`, on 8 x 8 cells at dt = 25 (a hundred times the
# explicit limit, where heat.npg's explicit step blows up). `simulate` solves each step by Newton
# (--newton-verbose: the residual falls quadratically); train/verify --steps train on the solved
# pairs and check the reduced implicit rollout against the full one; simulate --model runs it in
# coordinates; a Newton that fails names the step, iteration and residual; bad options refused.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_cli_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
H=examples/heat
P=$H/heat_backward.npg
PY=/usr/bin/python3

$PY $H/heat_data.py "$W/tr" --n 8 --trajectories 6 --seed 1 --dt 25 >/dev/null
$PY $H/heat_data.py "$W/te" --n 8 --trajectories 2 --seed 2 --dt 25 >/dev/null

# explicit Euler at this step blows up
if "$B/npgc" simulate $H/heat.npg "$W/te" --steps 20 -o "$W/explicit" 2>"$W/err.txt"; then fail "explicit step stable at dt 25"; fi
grep -q "blew up" "$W/err.txt" || fail "explicit: $(cat "$W/err.txt")"

# the full implicit rollout: Newton per step, quadratic, the states diffusing (max decreasing)
"$B/npgc" simulate $P "$W/te" --steps 20 --every 2 --newton-verbose -o "$W/full" 2>"$W/newton.txt" || fail "simulate full"
$PY - "$W/newton.txt" "$W/full/u.npy" <<'PY' || fail "full implicit rollout"
import re, sys, numpy as np
lines = open(sys.argv[1]).read().splitlines()
r = [float(re.fullmatch(r"newton sample \d+ iteration \d+: \|u\.residual\| = (\S+)", l).group(1)) for l in lines]
it = [int(re.search(r"iteration (\d+)", l).group(1)) for l in lines]
first = r[:it.index(0, 1)]  # trajectory 0, step 1
assert len(first) >= 3 and first[-1] <= 1e-10 * first[0], first
pairs = [(a, b) for a, b in zip(first, first[1:]) if a < 0.1 and b > 1e-13]
assert pairs and all(b <= 10 * a * a for a, b in pairs), first
u = np.load(sys.argv[2])
assert u.shape == (2, 11, 64) and np.all(np.isfinite(u)), u.shape
assert np.all(np.diff(u.max(axis=2), axis=1) <= 1e-12), u.max(axis=2)
PY

# trained on the solved steps, checked over the trajectory, run in coordinates
"$B/npgc" train $P "$W/tr" --steps 20 --every 1 --cap 10 --basis k:energy=0.99999 -o "$W/model" >/dev/null 2>&1 \
  || fail "train --steps"
"$B/npgc" verify $P "$W/model" "$W/te" --steps 20 --every 2 --tol 0.2 >"$W/verify.txt" 2>&1 \
  || fail "verify --steps: $(cat "$W/verify.txt")"
# the reduced rollout as close as its bases allow: error / projection floor (the initial bumps)
awk '$1 == "u" { if ($6 > 1.1) exit 1; found = 1 } END { exit !found }' "$W/verify.txt" \
  || fail "verify --steps: $(cat "$W/verify.txt")"
"$B/npgc" simulate $P "$W/te" --steps 20 --every 2 --model "$W/model" -o "$W/red" 2>/dev/null || fail "simulate --model"
$PY - "$W/full/u.npy" "$W/red/u.npy" <<'PY' || fail "reduced implicit rollout"
import sys, numpy as np
F, R = np.load(sys.argv[1]), np.load(sys.argv[2])
assert R.shape == F.shape and np.all(np.isfinite(R))
err = np.linalg.norm(R - F) / np.linalg.norm(F)
assert err <= 0.2, err
PY

# a Newton that fails: the step, the iteration and the residual named
if "$B/npgc" simulate $P "$W/te" --steps 5 --newton-max-iter 1 -o "$W/bad" 2>"$W/err.txt"; then fail "one iteration converged"; fi
grep -q "error: trajectory 0: step 1: npg_full_newton: Newton on residual 'u.residual' for 'u.next' did not converge at sample 0: iteration 1, residual " "$W/err.txt" \
  || fail "failed Newton: $(cat "$W/err.txt")"
test ! -e "$W/bad" || fail "a failed run wrote its output"
if "$B/npgc" simulate $P "$W/te" --steps 5 --model "$W/model" --newton-max-iter 1 --newton-tol 1e-14 -o "$W/bad" 2>"$W/err.txt"; then
  fail "one reduced iteration converged"; fi
grep -q "step 1: npg_reduced_newton: Newton on residual 'u.residual' for 'u.next' did not converge" "$W/err.txt" \
  || fail "failed reduced Newton: $(cat "$W/err.txt")"
for bad in "--newton-tol 0|--newton-tol" "--newton-tol 2|--newton-tol" "--newton-max-iter 0|--newton-max-iter"; do
  opt=${bad%%|*}; msg=${bad#*|}
  # shellcheck disable=SC2086
  if "$B/npgc" simulate $P "$W/te" --steps 5 $opt -o "$W/bad" 2>"$W/err.txt"; then fail "$opt accepted"; fi
  grep -q -- "$msg" "$W/err.txt" || fail "$opt: $(cat "$W/err.txt")"
done
echo ok
