#!/bin/sh
# app_options.sh APP BINARY — an application's command line (issues 24, 28):
# every number read whole and in range (the parser npgc uses, npg.h's
# npg_args_*), `--opt=value` as `--opt value`, unknown options named, and for
# npg-fluids unphysical parameters refused, a blown-up run stopped with a
# non-zero exit, sizes bounded before any allocation. APP is fluids, points
# or radiosity.
set -eu
APP=$1
X=$2
W=$(mktemp -d /tmp/npg_app_options_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

# expect STATUS MESSAGE ARGS...: the application exits with STATUS and its stderr holds MESSAGE
expect() {
  want=$1 msg=$2
  shift 2
  set +e
  "$X" "$@" >"$W/out.txt" 2>"$W/err.txt"
  got=$?
  set -e
  [ "$got" = "$want" ] || fail "$APP $* exited $got, expected $want: $(cat "$W/err.txt")"
  grep -qF -- "$msg" "$W/err.txt" || fail "$APP $*: stderr lacks '$msg': $(cat "$W/err.txt")"
}

case $APP in
fluids)
  # numbers: wrapped, trailing text, exponent for a count, out of range
  expect 2 "npg-fluids tunnel-full: --frames: 4294967298 is out of range (expected 1..100000)" \
    tunnel-full --out "$W/o" --frames 4294967298
  expect 2 "npg-fluids tunnel-full: --frames: '1e8' is not a whole number (expected 1..100000)" \
    tunnel-full --out "$W/o" --frames 1e8
  expect 2 "npg-fluids tunnel-full: --width: '1e8' is not a whole number (expected 16..8192)" \
    tunnel-full --out "$W/o" --width 1e8
  expect 2 "npg-fluids tunnel-full: --width: 100000000 is out of range (expected 16..8192)" \
    tunnel-full --out "$W/o" --width=100000000
  expect 2 "npg-fluids tunnel-full: --cells: '300abc' is not a whole number" tunnel-full --out "$W/o" --cells 300abc
  expect 2 "npg-fluids tunnel: --sizes: entry 2: '16x' is not a whole number (expected 2..256)" \
    tunnel --out "$W/o" --sizes 8,16x
  expect 2 "npg-fluids cavity: --runs: 15 is out of range (expected 0..14)" cavity --out "$W/o" --runs 15
  expect 2 "npg-fluids cavity-projection: --steps: 'abc' is not a whole number" cavity-projection --steps abc
  expect 2 "npg-fluids tunnel-full: unknown option '--frame'" tunnel-full --out "$W/o" --frame 3
  expect 2 "npg-fluids tunnel-full: --out needs a value" tunnel-full --out
  # unphysical parameters: the range and why
  expect 2 "npg-fluids tunnel-full: --mu -1: the viscosity is in [0, 10] (a negative one amplifies every mode" \
    tunnel-full --out "$W/o" --mu -1
  expect 2 "npg-fluids tunnel-full: --cfl 16: the CFL number is in (0, 1] (above 1 the flow crosses more than an edge" \
    tunnel-full --out "$W/o" --cfl 16
  expect 2 "npg-fluids tunnel: --mu -0.5: the viscosity is in [0, 10]" tunnel --out "$W/o" --mu=-0.5
  # a run that blows up inside the allowed range stops with a message and exit 1, not 0
  expect 1 "the run is unstable and was stopped" tunnel-full --out "$W/blown" --cfl 1 --frames 20 --cells 300 \
    --particles 10 --png-every 100 --vtk-every 100
  test ! -e "$W/blown/report.json" || fail "a blown-up run wrote its report as if it had succeeded"
  # --opt=value: the same mesh as --opt value; outputs under missing parents
  "$X" mesh --cells=400 | sed 's/, "mesh_seconds".*//' >"$W/a.json"
  "$X" mesh --cells 400 | sed 's/, "mesh_seconds".*//' >"$W/b.json"
  cmp "$W/a.json" "$W/b.json" || fail "mesh --cells=400 differs from --cells 400"
  "$X" tunnel-full --out="$W/p/q/r" --frames=2 --cells=300 --particles=10 >/dev/null 2>&1 ||
    fail "tunnel-full with --opt=value into missing parents"
  test -s "$W/p/q/r/report.json" || fail "tunnel-full wrote no report under missing parents"
  ;;
points)
  expect 2 "npg-points demo: --points: '300abc' is not a whole number (expected 100..10000000)" \
    demo --out "$W/o" --points 300abc
  expect 2 "npg-points demo: --tol: 'abc' is not a number (expected (0, 1])" demo --out "$W/o" --tol abc
  expect 2 "npg-points demo: --p: '2.9' is not a whole number (expected 2..8)" demo --out "$W/o" --p 2.9
  expect 2 "npg-points demo: --leaf: 4294967300 is out of range" demo --out "$W/o" --leaf=4294967300
  expect 2 "npg-points: --orders: entry 2: '3.5' is not a whole number (expected 2..8)" \
    sweep --out "$W/o" --orders 2,3.5
  expect 2 "npg-points demo: unknown option '--point'" demo --out "$W/o" --point 300
  expect 2 "npg-points demo: --visibility is on or off, not 'no'" demo --out "$W/o" --visibility no
  "$X" demo --points=200 --out="$W/d/e" --check-points=0 >/dev/null 2>&1 || fail "demo with --opt=value"
  grep -q '^  "N": 200,$' "$W/d/e/report.json" || fail "demo --points=200: $(head -c 300 "$W/d/e/report.json")"
  ;;
radiosity)
  expect 2 "npg-radiosity full: --frames: 4294967298 is out of range (expected 2..10000)" \
    full --out "$W/o" --frames 4294967298
  expect 2 "npg-radiosity train: --energy: 99 is out of range (expected (0, 1])" train --out "$W/o" --energy 99
  expect 2 "npg-radiosity full: --faces: '300abc' is not a whole number" full --out "$W/o" --faces=300abc
  expect 2 "npg-radiosity full: --vis-samples is 1, 4 or 16 (points per face), not 3" full --out "$W/o" --vis-samples 3
  expect 2 "npg-radiosity scene: unknown option '--face'" scene --face 100
  expect 2 "npg-radiosity full: --vis-mode is auto, single, stream or packet, not 'fast'" full --out "$W/o" --vis-mode fast
  expect 2 "npg-radiosity full: --solver is auto, lu, gs or gmres, not 'cg'" full --out "$W/o" --solver=cg
  # --basis NAME:cap=N,energy=E,center=on|off (npg_parse_basis): malformed lists refused with the option named; a name the
  # program lacks refused by training; a cap given reaches the member it names, the others not
  expect 2 "npg-radiosity train: --basis 'v': expected NAME:cap=N,energy=E" train --out "$W/o" --basis v
  expect 2 "npg-radiosity demo: --basis 'v:cap=0': cap: 0 is out of range (expected 1..1000000)" \
    demo --out "$W/o" --basis v:cap=0
  expect 2 "npg-radiosity train: --basis 'v:size=3': unknown key 'size' (the keys are cap, energy and center" \
    train --out "$W/o" --basis v:size=3
  expect 2 "npg-radiosity train: --basis 'v:center=maybe': center is on or off, not 'maybe'" \
    train --out "$W/o" --basis v:center=maybe
  expect 2 "npg-radiosity train: --basis 'c:energy=1.5': energy: 1.5 is out of range (expected (0, 1])" \
    train --out "$W/o" --basis c:energy=1.5
  expect 1 "training: --basis zz: no quantity, class or numerator of that name" \
    train --out "$W/z" --faces 100 --samples 6 --basis zz:cap=5
  "$X" train --out "$W/t" --faces 100 --samples 8 --basis c:cap=2 --basis d:energy=0.5 >"$W/t.txt" 2>&1 ||
    fail "train --basis c:cap=2: $(cat "$W/t.txt")"
  grep -q " c 2/2 lost" "$W/t.txt" || fail "train --basis c:cap=2: c is not 2/2: $(grep -F '{c}' "$W/t.txt")"
  grep -q " v [0-9]*/60 lost" "$W/t.txt" || fail "train --basis c:cap=2: v's cap moved: $(grep -F '{v}' "$W/t.txt")"
  # --structured-weight W|balanced: the design's structured points weighed in the PCA
  # (npg_trainer_weight; the library's test_api checks weights against duplicated samples)
  expect 2 "npg-radiosity train: --structured-weight: 0 is out of range (expected (0, 1e+06])" \
    train --out "$W/o" --structured-weight 0
  expect 2 "npg-radiosity demo: --structured-weight: 'x' is not a number" demo --out "$W/o" --structured-weight x
  # (balanced, the default: 1 until the interior points outnumber the structured ones, then
  # their ratio)
  "$X" train --out "$W/sw" --faces 100 --samples 150 >"$W/sw.txt" 2>&1 || fail "train --samples 150: $(cat "$W/sw.txt")"
  grep -q "150 samples (51 structured of weight 1.941, 99 interior)" "$W/sw.txt" ||
    fail "train --samples 150 (balanced): $(grep training: "$W/sw.txt")"
  grep -q '"structured_weight": 1.9411764705882' "$W/sw/train.json" || fail "train.json lacks structured_weight"
  "$X" train --out "$W/sw1" --faces 100 --samples 150 --structured-weight 1 >"$W/sw1.txt" 2>&1 ||
    fail "train --structured-weight 1: $(cat "$W/sw1.txt")"
  grep -q "150 samples (51 structured of weight 1, 99 interior)" "$W/sw1.txt" || fail "--structured-weight 1: $(grep training: "$W/sw1.txt")"
  [ "$(grep -F '{s,h}' "$W/sw.txt")" != "$(grep -F '{s,h}' "$W/sw1.txt")" ] ||
    fail "balanced weights trained the same {s,h} as weight 1: $(grep -F '{s,h}' "$W/sw.txt")"
  "$X" train --out "$W/sw2" --faces 100 --samples 60 >"$W/sw2.txt" 2>&1 || fail "train --samples 60: $(cat "$W/sw2.txt")"
  grep -q "60 samples (51 structured of weight 1, 9 interior)" "$W/sw2.txt" || fail "--samples 60: $(grep training: "$W/sw2.txt")"
  "$X" scene --faces=200 --checks=5 >"$W/a.txt" || fail "scene --faces=200"
  "$X" scene --faces 200 --checks 5 >"$W/b.txt" || fail "scene --faces 200"
  head -1 "$W/a.txt" >"$W/a1.txt"
  head -1 "$W/b.txt" >"$W/b1.txt"
  cmp "$W/a1.txt" "$W/b1.txt" || fail "scene --faces=200 differs from --faces 200"
  ;;
*) fail "unknown application '$APP'" ;;
esac

# a report that cannot reach standard output fails the program (issue 24: the
# applications exited 0 with their output lost on a full disk)
if [ -w /dev/full ]; then
  case $APP in
  points) args="demo --points 150 --out $W/full --p 2 --visibility off --check-points 0" ;;
  *) args="--help" ;;
  esac
  set +e
  # shellcheck disable=SC2086
  "$X" $args >/dev/full 2>"$W/err.txt"
  got=$?
  set -e
  [ "$got" != 0 ] || fail "$APP $args >/dev/full exited 0"
  grep -q "cannot write to standard output" "$W/err.txt" || fail "$APP $args >/dev/full: $(cat "$W/err.txt")"
fi
echo "$APP options: ok"
