#!/bin/sh
# simulate_tunnel.sh BUILD_DIR — the wind tunnel's step as a program (examples/fluids/tunnel_step.npg,
# paper Fig. 2 left): `npg-fluids tunnel-full --pulse 0 --dump-step` writes its operators and the
# driver's frames on a 300-cell mesh; `npgc simulate` of the program equals the driver's trajectory
# to 1e-8 (relative, every frame, velocity and flux); the step trained from trajectories
# (train --steps), checked over a held-out one (verify --steps) and run reduced (simulate --model);
# the same for the deforming mesh (tunnel_step_moving.npg, positions given per step); bad starts refused
# with the reason.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_tunnel_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
PY=/usr/bin/python3
PROG=examples/fluids/tunnel_step.npg
QUIET="--particles 0 --png-every 1000 --vtk-every 1000"

"$B/npg-fluids" tunnel-full --out "$W/run" --frames 40 --cells 300 --pulse 0 $QUIET --dump-step "$W/step" 2>"$W/log.txt" ||
  fail "tunnel-full --dump-step: $(cat "$W/log.txt")"
grep -q "stream function unknowns" "$W/log.txt" || fail "no summary of the dump: $(cat "$W/log.txt")"
"$B/npgc" simulate $PROG "$W/step" --steps 40 -o "$W/sim" >/dev/null || fail "simulate $PROG"
$PY - "$W/sim" "$W/step/driver" <<'PY' || fail "the program's trajectory differs from the driver's"
import sys, numpy as np
for n in ("u", "f"):
    a, b = np.load(f"{sys.argv[1]}/{n}.npy"), np.load(f"{sys.argv[2]}/{n}.npy")
    assert a.shape == b.shape == (1, 41, b.shape[2]), (n, a.shape, b.shape)
    err = np.linalg.norm(a - b, axis=2)[0] / np.linalg.norm(b, axis=2)[0]
    assert err.max() <= 1e-8, (n, err.max(), int(err.argmax()))
    assert np.linalg.norm(b[0, 40] - b[0, 0]) > 1e-3 * np.linalg.norm(b[0, 0]), "the flow did not change"
    print(f"{n}: largest relative difference from the driver over 40 steps {err.max():.2e}")
PY

# the deforming mesh (the obstacle pulsing): tunnel_step_moving.npg rebuilds the operators from the
# positions given per step; equal to the driver in the same way. The fixed step's operators are
# not written for a moving mesh, and the fixed program says which param is missing.
"$B/npg-fluids" tunnel-full --out "$W/run_moving" --frames 40 --cells 300 --pulse 0.2 --period 20 $QUIET \
  --dump-step "$W/moving" 2>"$W/log.txt" || fail "tunnel-full --dump-step (moving): $(cat "$W/log.txt")"
"$B/npgc" simulate examples/fluids/tunnel_step_moving.npg "$W/moving" --steps 40 -o "$W/sim_moving" >/dev/null ||
  fail "simulate tunnel_step_moving.npg"
$PY - "$W/sim_moving" "$W/moving/driver" "$W/moving/g.npy" <<'PY' || fail "the moving step's trajectory differs from the driver's"
import sys, numpy as np
g = np.load(sys.argv[3])
assert g.shape[:2] == (1, 40) and np.abs(g[0, 5] - g[0, 0]).max() > 1e-3, "the mesh does not move"
for n in ("u", "f"):
    a, b = np.load(f"{sys.argv[1]}/{n}.npy"), np.load(f"{sys.argv[2]}/{n}.npy")
    assert a.shape == b.shape == (1, 41, b.shape[2]), (n, a.shape, b.shape)
    err = np.linalg.norm(a - b, axis=2)[0] / np.linalg.norm(b, axis=2)[0]
    assert err.max() <= 1e-8, (n, err.max(), int(err.argmax()))
    print(f"{n} (moving mesh): largest relative difference from the driver over 40 steps {err.max():.2e}")
PY
# the moving step reduced: positions per step cut to each trajectory's steps
$PY examples/fluids/tunnel_step_data.py "$W/moving" "$W/nosteps" --starts 0
if "$B/npgc" simulate examples/fluids/tunnel_step_moving.npg "$W/nosteps" --steps 4 -o "$W/bad" 2>"$W/err.txt"; then
  fail "the moving step without its positions"
fi
grep -q "g.npy" "$W/err.txt" || fail "no positions message: $(cat "$W/err.txt")"
if $PY examples/fluids/tunnel_step_data.py "$W/moving" "$W/bad" --starts 35 --steps 10 2>"$W/err.txt"; then fail "past the positions"; fi
grep -q -- "--steps 10 from frame 35 needs the positions of 45 steps" "$W/err.txt" || fail "positions message: $(cat "$W/err.txt")"
$PY examples/fluids/tunnel_step_data.py "$W/moving" "$W/mtrain" --starts 0,10 --steps 12
$PY examples/fluids/tunnel_step_data.py "$W/moving" "$W/mtest" --starts 25 --steps 12
$PY -c "import numpy as np, sys; g = np.load(sys.argv[1]); assert g.shape[:2] == (2, 12), g.shape" "$W/mtrain/g.npy" ||
  fail "positions per step not cut"
"$B/npgc" train examples/fluids/tunnel_step_moving.npg "$W/mtrain" --steps 12 --energy 0.99999 -o "$W/mmodel" >"$W/train.txt" ||
  fail "train --steps (moving): $(cat "$W/train.txt")"
"$B/npgc" verify examples/fluids/tunnel_step_moving.npg "$W/mmodel" "$W/mtest" --steps 12 --every 4 --tol 0.2 >"$W/mverify.txt" ||
  fail "verify --steps (moving): $(cat "$W/mverify.txt")"
grep -E "^(u|f) " "$W/mverify.txt"
if "$B/npgc" simulate $PROG "$W/moving" --steps 4 -o "$W/bad" 2>"$W/err.txt"; then fail "the fixed step on moving data"; fi
grep -q "area" "$W/err.txt" || fail "missing param message: $(cat "$W/err.txt")"
if $PY examples/fluids/tunnel_step_data.py "$W/step" "$W/bad" --starts 0,41 2>"$W/err.txt"; then fail "start past the run"; fi
grep -q "frame 41 is not in the driver's run (frames 0..40)" "$W/err.txt" || fail "starts message: $(cat "$W/err.txt")"

# reduced: trained from two trajectories, verified on a held-out start
$PY examples/fluids/tunnel_step_data.py "$W/step" "$W/train" --starts 0,10
$PY examples/fluids/tunnel_step_data.py "$W/step" "$W/test" --starts 25
"$B/npgc" train $PROG "$W/train" --steps 15 --every 1 --energy 0.99999 -o "$W/model" >"$W/train.txt" || fail "train --steps: $(cat "$W/train.txt")"
grep -q "^trained .* on 32 visited states" "$W/train.txt" || fail "visited states: $(head -1 "$W/train.txt")"
"$B/npgc" verify $PROG "$W/model" "$W/test" --steps 15 --every 5 --tol 0.05 >"$W/verify.txt" ||
  fail "verify --steps: $(cat "$W/verify.txt")"
$PY - "$W/verify.txt" <<'PY' || fail "trajectory error against its floor: $(cat "$W/verify.txt")"
import sys
rows = {l.split()[0]: l.split() for l in open(sys.argv[1]) if l.split() and l.split()[0] in ("u", "f")}
assert set(rows) == {"u", "f"}, rows
for n, r in rows.items():
    err, floor = float(r[1]), float(r[2])
    assert 0 < floor <= err * (1 + 1e-9) and err < 0.05, (n, err, floor)
PY
"$B/npgc" simulate $PROG "$W/test" --steps 15 --every 15 --model "$W/model" -o "$W/red" >/dev/null || fail "simulate --model"
test -s "$W/red/u.npy" && test -s "$W/red/f.npy" || fail "simulate --model wrote no states"
cat "$W/verify.txt" | grep -E "^(u|f) "
echo "ok: the tunnel's step as a program equals the driver's"
