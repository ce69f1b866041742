#!/bin/sh
# options.sh BUILD_DIR — npgc's command lines as a new user types them
# (issue 28, issue 24): `--opt=value` beside `--opt value`, strict numbers
# with their range, what is missing said by name, swapped folders recognised,
# params for verify from --params, and the data generators' strict numbers
# and missing parents.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_options_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
N=$B/npgc
P=examples/rational/rational.npg

# expect STATUS MESSAGE CMD...: CMD exits with STATUS and its stderr holds MESSAGE
expect() {
  want=$1 msg=$2
  shift 2
  set +e
  "$@" >"$W/out.txt" 2>"$W/err.txt"
  got=$?
  set -e
  [ "$got" = "$want" ] || fail "$* exited $got, expected $want: $(cat "$W/err.txt")"
  grep -qF -- "$msg" "$W/err.txt" || fail "$*: stderr lacks '$msg': $(cat "$W/err.txt")"
}

# 1. the data generators: parents created, numbers strict
"$B/rational_data" "$W/deep/er/TRAIN" 60 1 >/dev/null || fail "rational_data into a missing parent"
test -s "$W/deep/er/TRAIN/x.npy" || fail "rational_data wrote no x.npy"
"$B/rational_data" "$W/TEST" 20 2 >/dev/null
expect 2 "SAMPLES: '60abc' is not a whole number (expected 1..100000000)" "$B/rational_data" "$W/X" 60abc 1
expect 2 "SEED: '1.5' is not a whole number" "$B/rational_data" "$W/X" 60 1.5
"$B/radiosity_data" "$W/r/s/RT" 24 2 0 1 1 >/dev/null || fail "radiosity_data into a missing parent"
test -s "$W/r/s/RT/v.npy" || fail "radiosity_data wrote no v.npy"
expect 2 "F: 4294967320 is out of range (expected 12..100000)" "$B/radiosity_data" "$W/X" 4294967320 2 0 1 1
expect 2 "F: 25 is odd" "$B/radiosity_data" "$W/X" 25 2 0 1 1
expect 2 "T1: 'one' is not a number (expected [0, 1])" "$B/radiosity_data" "$W/X" 24 2 0 one 1

# 2. --opt=value is --opt value: the two models are the same bytes
"$N" train "$P" "$W/deep/er/TRAIN" -o "$W/M1" --cap 2 --energy 0.9 --center off >/dev/null || fail "train --opt value"
"$N" train "$P" "$W/deep/er/TRAIN" -o="$W/M2" --cap=2 --energy=0.9 --center=off >/dev/null || fail "train --opt=value"
cmp "$W/M1/basis_0.npy" "$W/M2/basis_0.npy" || fail "--cap=2 trained another basis than --cap 2"
"$N" verify "$P" "$W/M1" "$W/TEST" --tol=0.5 >/dev/null || fail "verify --tol=0.5"
"$N" eval "$P" "$W/M1" "$W/TEST" -o="$W/OUT" || fail "eval -o=OUT"
test -s "$W/OUT/y.npy" || fail "eval -o=OUT wrote no y.npy"
"$N" check "$P" --std=stdlib >/dev/null || fail "check --std=DIR"
"$N" bench "$P" "$W/M1" "$W/TEST" --reps=3 >"$W/bench.txt" || fail "bench --reps=3"
# bench: one statistic, stated (medians), with its spread (quartiles), one speedup (not a mean beside a best)
grep -q "59 evaluations timed, 1 BLAS thread (--threads N for more); medians, quartiles in brackets" "$W/bench.txt" ||
  fail "bench statistic: $(cat "$W/bench.txt")"
# honest bench (issue 42): the full evaluator's backend named with its compile time and cache state, the
# reduced time with and without projection and lift, the BLAS threads asked for
grep -q "^full evaluator: \(cc (the system compiler at -O3 -march=native)\|libtcc\), \(compiled\|loaded\) in [0-9.]* ms (" "$W/bench.txt" ||
  fail "bench names no backend: $(cat "$W/bench.txt")"
grep -q "^  reduced alone  *[0-9.e+-]* s per sample .*coordinates in, coordinates out" "$W/bench.txt" &&
  grep -q "^  without projection and lift [0-9.e+-]*x" "$W/bench.txt" || fail "bench lacks the reduced time alone: $(cat "$W/bench.txt")"
# the reduced evaluation against its byte bound (issue 42): tensor bytes / read bandwidth measured over as many
grep -q "^byte bound  *[0-9.e+-]* s: the reduced tensors read once at [0-9.e+-]* GB/s (read bandwidth measured over as many bytes, one thread); reduced alone [0-9.e+-]*x the bound$" "$W/bench.txt" ||
  fail "bench lacks the byte bound: $(cat "$W/bench.txt")"
NPG_JIT=tcc "$N" bench "$P" "$W/M1" "$W/TEST" --reps 1 --threads 2 >"$W/bench2.txt" || fail "bench --threads 2"
grep -q "evaluations timed, 2 BLAS threads;" "$W/bench2.txt" && grep -q "^full evaluator: libtcc, compiled in" "$W/bench2.txt" ||
  fail "bench --threads 2 under NPG_JIT=tcc: $(cat "$W/bench2.txt")"
"$N" bench "$P" "$W/M1" "$W/TEST" --reps 1 --jit cc >"$W/bench3.txt" || fail "bench --jit cc"
grep -q "^full evaluator: cc (the system compiler" "$W/bench3.txt" || fail "bench --jit cc: $(cat "$W/bench3.txt")"
expect 2 "npgc bench: --jit: 'gcc' is not a backend (expected auto, cc or tcc)" "$N" bench "$P" "$W/M1" "$W/TEST" --jit gcc
expect 2 "npgc bench: --threads: 0 is out of range (expected 1..1024)" "$N" bench "$P" "$W/M1" "$W/TEST" --threads 0
[ "$(grep -c "speedup" "$W/bench.txt")" = 1 ] || fail "bench prints more than one speedup: $(cat "$W/bench.txt")"
grep -q "^speedup  *[0-9.e+-]*x \[[0-9.e+-]*x, [0-9.e+-]*x\] (full time / reduced time per evaluation" "$W/bench.txt" ||
  fail "bench speedup line: $(cat "$W/bench.txt")"
grep -q "^full evaluation  *[0-9.e+-]* s per sample \[[0-9.e+-]*, [0-9.e+-]*\]$" "$W/bench.txt" ||
  fail "bench full line: $(cat "$W/bench.txt")"
expect 2 "npgc check: --json takes no value ('--json=yes')" "$N" check "$P" --json=yes
# every writer creates the parents of what it writes (as -o does)
"$N" plot "$W/M1" -o "$W/pl/ot/s.png" >/dev/null || fail "plot -o into missing parents"
test -s "$W/pl/ot/s.png" || fail "plot wrote no PNG"
"$N" train "$P" "$W/deep/er/TRAIN" -o "$W/M6" --spectra "$W/sp/ec/tra" >/dev/null || fail "train --spectra into missing parents"
ls "$W/sp/ec/tra/"spectrum_*.npy >/dev/null || fail "--spectra wrote no spectrum"
"$N" tune "$P" "$W/deep/er/TRAIN" "$W/TEST" --tol 1e-3 -o "$W/tu/ne/M" --png "$W/tu/pn/g.png" >/dev/null ||
  fail "tune into missing parents"
test -s "$W/tu/pn/g.png" && test -s "$W/tu/ne/M/manifest" || fail "tune wrote no PNG or model"

# 3. numbers: the whole value, its range in the message
expect 2 "npgc train: --energy: 99 is out of range (expected (0, 1])" "$N" train "$P" "$W/TEST" -o "$W/X" --energy 99
expect 2 "npgc train: --cap: '300abc' is not a whole number (expected 1..1000000)" \
  "$N" train "$P" "$W/TEST" -o "$W/X" --cap=300abc
expect 2 "npgc bench: --reps: '2.9' is not a whole number (expected 1..1000000)" "$N" bench "$P" "$W/M1" "$W/TEST" --reps 2.9

# 4. --basis names the bad key and the allowed ones; `cap 12` is cap=12 (the program's syntax)
expect 2 "unknown key 'size' (the keys are cap, energy, center and product" "$N" train "$P" "$W/TEST" -o "$W/X" --basis u:size=5
"$N" train "$P" "$W/deep/er/TRAIN" -o "$W/M3" --basis "y:cap 2" >/dev/null || fail "--basis 'y:cap 2'"
"$N" train "$P" "$W/deep/er/TRAIN" -o "$W/M4" --basis "y:cap=2" >/dev/null || fail "--basis y:cap=2"
cmp "$W/M3/manifest" "$W/M4/manifest" || fail "--basis 'y:cap 2' and y:cap=2 trained different models"

# the program's `basis m_b: cap=2, energy 0.99` and the CLI's --basis m_b:cap=2,energy=0.99 configure the same
# class {a, b} (m_<a member>, in both places)
C=tests/programs/basis_class_name.npg
/usr/bin/python3 -c "import numpy as np, os, sys; os.makedirs(sys.argv[1]); np.save(sys.argv[1] + '/x.npy', np.random.default_rng(1).random((30, 6)))" "$W/CD"
grep -v '^basis m_b' "$C" >"$W/noclass.npg"
"$N" train "$C" "$W/CD" -o "$W/CM1" >"$W/t1.txt" || fail "train basis m_b: $(cat "$W/t1.txt")"
"$N" train "$W/noclass.npg" "$W/CD" -o "$W/CM2" --basis m_b:cap=2,energy=0.99 >"$W/t2.txt" || fail "train --basis m_b"
grep -q "^{a,b} .* a 2/2 .* b 2/2 " "$W/t1.txt" || fail "basis m_b: cap=2 in the program: $(cat "$W/t1.txt")"
[ "$(grep '^{a,b}' "$W/t1.txt")" = "$(grep '^{a,b}' "$W/t2.txt")" ] ||
  fail "the program's basis m_b and --basis m_b differ: $(grep '^{a,b}' "$W/t1.txt" "$W/t2.txt")"

# 5. unknown options are unknown; another command's option is named as such
expect 2 "npgc verify: unknown option '--progres'" "$N" verify "$P" "$W/M1" "$W/TEST" --progres
expect 2 "npgc verify: --cap is an option of npgc train, not of npgc verify" "$N" verify "$P" "$W/M1" "$W/TEST" --cap 3
expect 2 "npgc train: --progress takes no value" "$N" train "$P" "$W/TEST" -o "$W/X" --progress=yes

# 6. what is missing, by name
expect 2 "npgc train: missing -o MODEL/" "$N" train "$P" "$W/TEST"
expect 2 "npgc emit: missing -o FILE.c" "$N" emit "$P"
expect 2 "npgc eval: missing a folder: after the program come MODEL/ IN/ (the reduced evaluation) or --full DATA/ IN/" \
  "$N" eval "$P" "$W/TEST" -o "$W/X"
expect 2 "npgc eval: missing DATA/ (the params of the full evaluation, after --full)" "$N" eval "$P" --full -o "$W/X"
expect 2 "npgc tune: missing --tol T" "$N" tune "$P" "$W/deep/er/TRAIN" "$W/TEST" -o "$W/X"

# 7. swapped folders: a data folder given as the model, the model given as the data
expect 1 "npgc verify: $W/M1 is a model and $W/TEST is not (it has no manifest): the order is npgc verify PROG.npg MODEL/ TEST/" \
  "$N" verify "$P" "$W/TEST" "$W/M1"
expect 1 "npgc eval: $W/TEST is a data folder (it holds .npy files and no manifest), not a model" \
  "$N" eval "$P" "$W/TEST" "$W/TEST" -o "$W/X"

# 8. verify's params: from TEST/ by default (the folder lacking one is named), or --params DIR
R=examples/radiosity/formfactors.npg
"$B/radiosity_data" "$W/RT" 24 12 0 1 1 >/dev/null
"$B/radiosity_data" "$W/RV" 24 3 0.1 0.9 2 >/dev/null
"$N" train "$R" "$W/RT" -o "$W/RM" --cap 4 >/dev/null || fail "train radiosity"
mkdir "$W/RS"
for f in g e v; do cp "$W/RV/$f.npy" "$W/RS/"; done
expect 1 "npgc verify reads the params from $W/RS, the TEST/ folder, beside its samples; --params DIR" \
  "$N" verify "$R" "$W/RM" "$W/RS"
grep -q "RS/tri.npy" "$W/err.txt" || fail "verify without params does not name the missing file: $(cat "$W/err.txt")"
"$N" verify "$R" "$W/RM" "$W/RS" --params "$W/RT" --tol 1 >"$W/out.txt" || fail "verify --params DIR: $(cat "$W/err.txt")"
grep -q "^ok: every output within --tol 1" "$W/out.txt" || fail "verify --params: $(cat "$W/out.txt")"
expect 1 "tri.npy" "$N" verify "$R" "$W/RM" "$W/RS" --params "$W/TEST"
"$N" bench "$R" "$W/RM" "$W/RS" --params="$W/RT" --reps 1 >/dev/null || fail "bench --params=DIR"
expect 2 "npgc train: --params is an option of npgc verify and bench, not of npgc train" \
  "$N" train "$R" "$W/RT" -o "$W/X" --params "$W/RT"

# verify's "own" error (L2 error minus the floor) is at least 0 in exact arithmetic: a full-rank model's
# rounding (-1.7e-17, -1.0e-16 before) is printed as 0
"$N" train "$R" "$W/RT" -o "$W/RF" --energy 1 --cap 200 >/dev/null || fail "train full rank"
"$N" verify "$R" "$W/RF" "$W/RS" --params "$W/RT" --tol 1 >"$W/out.txt" || fail "verify full rank"
awk 'NR > 2 && $3 ~ /^[0-9]+$/ && $6 ~ /^-/ { bad = 1; print } END { exit bad }' "$W/out.txt" >"$W/neg.txt" ||
  fail "negative own errors: $(cat "$W/neg.txt")"
grep -q "^v .* 0.000e+00 " "$W/out.txt" || fail "no own error of 0 in: $(cat "$W/out.txt")"

# 9. a report that cannot be written is a failure, not exit 0 (issue 24: check --json >/dev/full)
if [ -w /dev/full ]; then
  if "$N" check "$P" --json >/dev/full 2>"$W/err.txt"; then fail "check --json >/dev/full exited 0"; fi
  grep -q "^npgc: cannot write to standard output: No space left on device" "$W/err.txt" ||
    fail "stdout error message: $(cat "$W/err.txt")"
  if "$N" verify "$P" "$W/M1" "$W/TEST" --tol 1 >/dev/full 2>/dev/null; then fail "verify >/dev/full exited 0"; fi
fi

# 10. the embedding example's positional numbers, read by the same parser
expect 2 "embed: N: '16x' is not a whole number (expected 3..200)" "$B/embed" 16x
expect 2 "embed: ENERGY: 2 is out of range (expected (0, 1])" "$B/embed" 16 40 2
echo "options: ok"
