#!/bin/sh
# simulate.sh BUILD_DIR — simulations end to end through npgc (DESIGN §15), on the heat examples
# (examples/heat/, 8 x 8 cells): `npgc simulate` of the linear step, with a source held and given
# per step, equals a NumPy loop; the nonlinear (inverse stage) and semi-implicit (a solve with a
# state-dependent operator) steps trained from trajectories (train --steps), checked over the
# trajectory (verify --steps, --png) and run reduced (simulate --model, states in coordinates);
# bench --steps; a blow-up named by step and state; bad options and data refused with the reason.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_cli_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
H=examples/heat
PY=/usr/bin/python3

$PY $H/heat_data.py "$W/held" --n 8 --trajectories 3 --seed 3 --source held
$PY $H/heat_data.py "$W/steps" --n 8 --trajectories 2 --seed 4 --source steps:60
for d in held steps; do
  "$B/npgc" simulate $H/heat_linear.npg "$W/$d" --steps 50 --every 5 -o "$W/out_$d" >/dev/null || fail "simulate ($d source)"
  $PY - "$W/$d" "$W/out_$d/u.npy" <<'PY' || fail "simulate ($d source) differs from NumPy"
import sys, numpy as np
d, out = sys.argv[1], np.load(sys.argv[2])
u, f, nbr, dt = (np.load(f"{d}/{n}.npy") for n in ("u", "f", "nbr", "dt"))
assert out.shape == (u.shape[0], 11, u.shape[1]), out.shape
for k in range(u.shape[0]):
    x = u[k].copy()
    for t in range(51):
        if t % 5 == 0:
            err = np.abs(out[k, t // 5] - x).max()
            assert err <= 1e-12, (k, t, err)
        fk = f[k] if f.ndim == 2 else f[k, t]
        x = x + dt * (np.where(nbr >= 0, x[np.maximum(nbr, 0)] - x[:, None], 0).sum(1) + fk)
PY
done
# a source given for fewer steps than asked
if "$B/npgc" simulate $H/heat_linear.npg "$W/steps" --steps 80 -o "$W/bad" 2>"$W/err.txt"; then fail "80 steps of a 60-step source"; fi
grep -q "f.npy: input 'f' is given per step for 60 steps, fewer than the 80 to run" "$W/err.txt" || fail "short source: $(cat "$W/err.txt")"
test ! -e "$W/bad" || fail "a failed simulate wrote its output"

# the nonlinear steps: trained from trajectories, checked over the trajectory, run reduced
$PY $H/heat_data.py "$W/train" --n 8 --trajectories 6 --seed 1
$PY $H/heat_data.py "$W/test" --n 8 --trajectories 2 --seed 2
for prog in heat heat_implicit; do
  "$B/npgc" train $H/$prog.npg "$W/train" --steps 100 --every 2 --basis k:energy=0.99999 -o "$W/m_$prog" >"$W/train.txt" ||
    fail "train --steps $prog: $(cat "$W/train.txt")"
  grep -q "^trained .* on 306 visited states" "$W/train.txt" || fail "$prog: visited states: $(head -1 "$W/train.txt")"
  "$B/npgc" verify $H/$prog.npg "$W/m_$prog" "$W/test" --steps 100 --every 10 --tol 0.05 --png "$W/$prog.png" >"$W/verify.txt" ||
    fail "verify --steps $prog: $(cat "$W/verify.txt")"
  grep -q '^u  *[0-9.e+-]* *[0-9.e+-]* *[0-9.e+-]* *[0-9.e+-]* *[0-9.e+-]*  trajectory [0-9]*, step [0-9]*$' "$W/verify.txt" ||
    fail "verify --steps row: $(cat "$W/verify.txt")"
  $PY -c "import sys; sys.exit(open('$W/$prog.png','rb').read(8) != b'\x89PNG\r\n\x1a\n')" || fail "--png is not a PNG"
  # the trajectory error is at least its floor, and a bad --tol fails
  $PY - "$W/verify.txt" <<'PY' || fail "$prog: trajectory error below its floor: $(cat "$W/verify.txt")"
import sys
row = [l.split() for l in open(sys.argv[1]) if l.startswith("u ")][0]
err, floor = float(row[1]), float(row[2])
assert floor <= err * (1 + 1e-9) and err > 0, (err, floor)
PY
  if "$B/npgc" verify $H/$prog.npg "$W/m_$prog" "$W/test" --steps 100 --tol 1e-12 >"$W/v2.txt"; then fail "--tol 1e-12 passed"; fi
  grep -q "^FAIL: state u: trajectory error" "$W/v2.txt" || fail "no FAIL line: $(cat "$W/v2.txt")"
  # the reduced rollout through simulate --model is the one verify compared
  "$B/npgc" simulate $H/$prog.npg "$W/test" --steps 100 --every 50 --model "$W/m_$prog" -o "$W/red_$prog" >/dev/null ||
    fail "simulate --model $prog"
  "$B/npgc" simulate $H/$prog.npg "$W/test" --steps 100 --every 50 -o "$W/full_$prog" >/dev/null || fail "simulate $prog"
  $PY - "$W/red_$prog/u.npy" "$W/full_$prog/u.npy" <<'PY' || fail "$prog: reduced rollout far from the full one"
import sys, numpy as np
r, f = np.load(sys.argv[1]), np.load(sys.argv[2])
assert r.shape == f.shape == (2, 3, 64), (r.shape, f.shape)
e = np.linalg.norm(r - f) / np.linalg.norm(f)
assert 0 < e < 0.05, e
PY
done
"$B/npgc" bench $H/heat.npg "$W/m_heat" "$W/test" --steps 50 --reps 1 >"$W/bench.txt" || fail "bench --steps: $(cat "$W/bench.txt")"
grep -q "^reduced step .* in reduced coordinates" "$W/bench.txt" || fail "bench --steps: $(cat "$W/bench.txt")"
grep -q "^full evaluator: \(cc (the system compiler at -O3 -march=native)\|libtcc\), \(compiled\|loaded\) in" "$W/bench.txt" &&
  grep -q "steps, 1 BLAS thread (--threads N for more);" "$W/bench.txt" || fail "bench --steps names no backend or threads: $(cat "$W/bench.txt")"
grep -q "^speedup  *[0-9.e+-]*x" "$W/bench.txt" || fail "bench --steps speedup: $(cat "$W/bench.txt")"
# the reduced evaluation with its estimates per step: a time against the evaluation alone, or why none
grep -q "^reduced + estimate  *\([0-9.e+-]* s \[.*\] per step: .* the evaluation alone\|none: .* has no estimate\)" "$W/bench.txt" ||
  fail "bench --steps: no line of the reduced evaluation with its estimates: $(cat "$W/bench.txt")"

# tune --steps: sizes chosen by the rollout error, which verify --steps then confirms
"$B/npgc" tune $H/heat.npg "$W/train" "$W/test" --steps 60 --every 3 --tol 0.02 -o "$W/tuned" >"$W/tune.txt" ||
  fail "tune --steps: $(cat "$W/tune.txt")"
grep -q "worst state's trajectory error over 60-step rollouts from 2 initial states" "$W/tune.txt" || fail "tune --steps header: $(head -1 "$W/tune.txt")"
grep -q "^chosen: cost .*, error .* (--tol 0.02)" "$W/tune.txt" || fail "tune --steps chose nothing: $(cat "$W/tune.txt")"
"$B/npgc" verify $H/heat.npg "$W/tuned" "$W/test" --steps 60 --every 3 --tol 0.03 >"$W/vt.txt" || fail "tuned model: $(cat "$W/vt.txt")"

# a blow-up: explicit Euler past its stability limit
$PY $H/heat_data.py "$W/unstable" --n 8 --trajectories 1 --dt 1.5 --source held
if "$B/npgc" simulate $H/heat_linear.npg "$W/unstable" --steps 500 -o "$W/bad" 2>"$W/err.txt"; then fail "blow-up not caught"; fi
grep -q "^error: trajectory 0: step [0-9]*: state 'u' blew up: its energy" "$W/err.txt" || fail "blow-up message: $(cat "$W/err.txt")"
test ! -e "$W/bad" || fail "a blown-up simulate wrote its output"

# refusals
"$B/npgc" simulate $H/heat.npg "$W/test" -o "$W/bad" 2>"$W/err.txt" && fail "simulate without --steps"
grep -q "missing --steps T" "$W/err.txt" || fail "no --steps: $(cat "$W/err.txt")"
"$B/npgc" train $H/heat.npg "$W/train" --every 3 -o "$W/bad" 2>"$W/err.txt" && fail "--every without --steps"
grep -q "give --steps T too" "$W/err.txt" || fail "--every alone: $(cat "$W/err.txt")"
"$B/npgc" simulate tests/programs/heat_neighbours.npg "$W/test" --steps 3 -o "$W/bad" 2>"$W/err.txt" && fail "a program without state"
grep -q "has no state\|no input\|kappa" "$W/err.txt" || fail "no state: $(cat "$W/err.txt")"
$PY -c "import numpy as np; np.save('$W/test/u.npy', np.zeros((2, 5, 64)))"
"$B/npgc" simulate $H/heat.npg "$W/test" --steps 3 -o "$W/bad" 2>"$W/err.txt" && fail "a state given per step"
grep -q "state 'u' is 1-dimensional, so its file holds \[samples, ...\] (2 axes) with the initial value of each trajectory; it has 3" "$W/err.txt" ||
  fail "per-step state: $(cat "$W/err.txt")"
echo "simulate: ok"
