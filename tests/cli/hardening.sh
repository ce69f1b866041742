#!/bin/sh
# hardening.sh BUILD_DIR — regression tests of the defects a hostile-input
# trial found in npgc (non-finite values, foreign params, outputs that are
# inputs, numbers misread, --help, missing parents, bench's report).
set -eu
B=$1
W=$(mktemp -d /tmp/npg_hard_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
N=$B/npgc

# 1. a root of a negative test entry: verify and eval --full fail naming stage, sample and entry
cat >"$W/sqrt.npg" <<'NPG'
dim N
input x : real[N]
output y[i:N] = x[i]^(1/2)
NPG
/usr/bin/python3 - "$W" <<'PY'
import sys, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(1)
import os
os.makedirs(w + "/TR"); os.makedirs(w + "/TE")
np.save(w + "/TR/x.npy", 1 + rng.random((20, 5)))
x = 1 + rng.random((4, 5)); x[2, 3] = -0.5
np.save(w + "/TE/x.npy", x)
PY
"$N" train "$W/sqrt.npg" "$W/TR" -o "$W/SM" >/dev/null || fail "train sqrt"
if "$N" verify "$W/sqrt.npg" "$W/SM" "$W/TE" >"$W/out.txt" 2>"$W/err.txt"; then fail "verify passed a NaN"; fi
grep -q "sample 2: stage 'y' is not finite: y\[3\] is NaN" "$W/err.txt" || fail "verify NaN message: $(cat "$W/err.txt")"
if "$N" eval "$W/sqrt.npg" --full "$W/TE" "$W/TE" -o "$W/FO" 2>"$W/err.txt"; then fail "eval --full wrote a NaN"; fi
grep -q "sample 2: stage 'y' is not finite: y\[3\] is NaN" "$W/err.txt" || fail "eval NaN message: $(cat "$W/err.txt")"
test ! -e "$W/FO/y.npy" || fail "eval --full left an output with a NaN"
# a NaN input to the reduced evaluation is named, not reported as a singular operator
/usr/bin/python3 -c "import numpy as np,sys; x=np.load(sys.argv[1]); x[1,0]=np.nan; np.save(sys.argv[2], x)" "$W/TR/x.npy" "$W/nan.npy"
mkdir "$W/NI"; mv "$W/nan.npy" "$W/NI/x.npy"
if "$N" eval "$W/sqrt.npg" "$W/SM" "$W/NI" -o "$W/NO" 2>"$W/err.txt"; then fail "reduced eval of a NaN input"; fi
grep -q "NI/x.npy: input 'x' holds NaN at sample 1, \[0\]" "$W/err.txt" || fail "NaN input message: $(cat "$W/err.txt")"

# 2. reduced eval refuses params in IN/ that differ from the model's, as verify does
R=examples/radiosity/formfactors.npg
"$B/radiosity_data" "$W/RT" 24 8 0 1 1 >/dev/null
"$N" train $R "$W/RT" -o "$W/RM" --cap 4 >/dev/null || fail "radiosity train"
/usr/bin/python3 -c "import numpy as np,sys; r=np.load(sys.argv[1]); np.save(sys.argv[1], r*0.5)" "$W/RT/rho.npy"
if "$N" eval $R "$W/RM" "$W/RT" -o "$W/RO" 2>"$W/err.txt"; then fail "reduced eval accepted other params"; fi
grep -q "rho.npy: param 'rho' differs from the one the model was trained with" "$W/err.txt" || fail "eval params: $(cat "$W/err.txt")"
if "$N" bench $R "$W/RM" "$W/RT" 2>"$W/err.txt" >/dev/null; then fail "bench accepted other params"; fi
grep -q "param 'rho' differs" "$W/err.txt" || fail "bench params: $(cat "$W/err.txt")"

# 3. an output path that is an input is refused, and the input survives
cp "$W/sqrt.npg" "$W/keep.npg"
if "$N" emit "$W/keep.npg" -o "$W/keep.npg" 2>"$W/err.txt"; then fail "emit over its program"; fi
cmp -s "$W/sqrt.npg" "$W/keep.npg" || fail "emit replaced the program"
if "$N" emit "$W/sqrt.npg" --reduced "$W/SM" -o "$W/SM/manifest" 2>"$W/err.txt"; then fail "emit into the model"; fi
"$N" verify "$W/sqrt.npg" "$W/SM" "$W/TR" >/dev/null || fail "the model was damaged by emit"
if "$N" train "$W/sqrt.npg" "$W/TR" -o "$W/TR" 2>"$W/err.txt"; then fail "train -o DATA accepted"; fi
test -e "$W/TR/x.npy" || fail "train -o DATA removed the data"

# 5. numbers are parsed strictly
for bad in "--cap 4294967297" "--cap 0" "--cap 3x" "--energy 0" "--energy 1.5" "--mem 1Q" "--mem -1"; do
  if "$N" train "$W/sqrt.npg" "$W/TR" -o "$W/X" $bad 2>"$W/err.txt"; then fail "train accepted $bad"; fi
  opt=${bad%% *}
  grep -q "^npgc train: $opt[: ].*\(out of range (expected\|not a whole number (expected\|is not a size in bytes\)" "$W/err.txt" ||
    fail "train $bad: $(cat "$W/err.txt")"
done
if "$N" verify "$W/sqrt.npg" "$W/SM" "$W/TR" --tol '' 2>"$W/err.txt"; then fail "--tol '' accepted"; fi
if "$N" verify "$W/sqrt.npg" "$W/SM" "$W/TR" --tol nan 2>"$W/err.txt"; then fail "--tol nan accepted"; fi
if "$N" verify "$W/sqrt.npg" --exact-size 99999999999999999999 2>"$W/err.txt"; then fail "huge --exact-size accepted"; fi
if "$N" train "$W/sqrt.npg" "$W/TR" -o 2>"$W/err.txt"; then fail "-o without a value"; fi
grep -q "^npgc train: -o needs a value" "$W/err.txt" || fail "-o message: $(cat "$W/err.txt")"

# 13. every command has a whole --help, on stdout, exit 0
for cmd in check emit eval train verify bench; do
  "$N" $cmd --help >"$W/help.txt" 2>&1 || fail "$cmd --help exit status"
  grep -q "^usage: npgc $cmd" "$W/help.txt" || fail "$cmd --help: $(head -2 "$W/help.txt")"
done
"$N" eval --help | grep -q -- "--full" && "$N" eval --help | grep -q "MODEL/ IN/" || fail "eval usage incomplete"

# 15. -o creates missing parents
"$N" train "$W/sqrt.npg" "$W/TR" -o "$W/a/b/MODEL" >/dev/null || fail "train into a missing parent"
"$N" eval "$W/sqrt.npg" "$W/a/b/MODEL" "$W/TR" -o "$W/c/d/OUT" || fail "eval into a missing parent"
test -e "$W/c/d/OUT/y.npy" || fail "eval output"
"$N" emit "$W/sqrt.npg" -o "$W/e/f/prog.c" || fail "emit into a missing parent"

# 16. bench says which backend it timed, how often, includes lifting, never "0.0x"
"$N" bench "$W/sqrt.npg" "$W/SM" "$W/TR" --reps 2 --jit tcc >"$W/bench.txt" || fail "bench"
grep -q "20 samples x 2 passes, 39 evaluations timed" "$W/bench.txt" || fail "bench reps: $(cat "$W/bench.txt")"
grep -q "^full evaluator: libtcc" "$W/bench.txt" && grep -q "^  lifting outputs" "$W/bench.txt" || fail "bench report"
if grep -q " 0\.0x" "$W/bench.txt"; then fail "bench printed 0.0x"; fi
# and the evaluation followed by every output's estimate, against the evaluation alone (y's: its check entries)
grep -q "^  reduced + estimate  *[0-9.]*e[-+][0-9]* s per sample \[[0-9.e+-]*, [0-9.e+-]*\], then every output's estimate (npg_reduced_estimate, 1 of them with a figure): [0-9.]*x \[[0-9.]*x, [0-9.]*x\] the reduced alone$" "$W/bench.txt" ||
  fail "bench estimate line: $(cat "$W/bench.txt")"
# an output without an estimate (a power -2 of a declared op applied to an extern's output, whose learned map has
# none): bench says which and why, in place of the timing
printf 'dim N\nparam a : real[N, N]\ninput x : real[N]\nextern v[i:N] of x\nop M[i:N, j:N] = a[i, j] + a[j, i] + delta(i, j)\noutput y = M^-2 * v\n' \
  >"$W/root.npg"
/usr/bin/python3 -c "import numpy as np, os, sys; r = np.random.default_rng(1); os.makedirs(sys.argv[1]);
np.save(sys.argv[1] + '/a.npy', 0.1 * r.random((5, 5))); x = r.random((12, 5)); np.save(sys.argv[1] + '/x.npy', x)
np.save(sys.argv[1] + '/v.npy', 1 + x ** 2)" "$W/RR"
"$N" train "$W/root.npg" "$W/RR" -o "$W/RRM" >/dev/null || fail "train root"
"$N" bench "$W/root.npg" "$W/RRM" "$W/RR" --reps 1 >"$W/bench.txt" || fail "bench root"
grep -q "^  + estimate        none: y has no estimate (its numerator v has no estimate)$" \
  "$W/bench.txt" && ! grep -q "reduced + estimate" "$W/bench.txt" || fail "bench without an estimate: $(cat "$W/bench.txt")"
# 14. bench shows progress on stderr with --progress (as on a terminal), nothing when not a terminal
"$N" bench "$W/sqrt.npg" "$W/SM" "$W/TR" --reps 2 --progress >/dev/null 2>"$W/err.txt" || fail "bench --progress"
grep -q "bench (full and reduced) *\[#*\] 40/40$" "$W/err.txt" || fail "bench progress: $(cat "$W/err.txt")"
"$N" bench "$W/sqrt.npg" "$W/SM" "$W/TR" --reps 2 >/dev/null 2>"$W/err.txt" || fail "bench"
test ! -s "$W/err.txt" || fail "bench not on a terminal wrote: $(cat "$W/err.txt")"
"$N" verify "$W/sqrt.npg" "$W/SM" "$W/TR" --progress >/dev/null 2>"$W/err.txt" || fail "verify --progress"
grep -q "verification" "$W/err.txt" || fail "verify progress: $(cat "$W/err.txt")"
# the reduced eval takes the --exact-roots its usage shows; eval --full refuses it by name
"$N" eval "$W/sqrt.npg" "$W/SM" "$W/TR" -o "$W/XR" --exact-roots --progress 2>"$W/err.txt" || fail "eval --exact-roots: $(cat "$W/err.txt")"
if "$N" eval "$W/sqrt.npg" --full "$W/TR" "$W/TR" -o "$W/XF" --exact-roots 2>"$W/err.txt"; then fail "eval --full --exact-roots"; fi
grep -q "exact-roots is an option of the reduced evaluation" "$W/err.txt" || fail "--full --exact-roots: $(cat "$W/err.txt")"
# 8. a zero-size dim: evaluated, and refused by training with a message (no LAPACK error)
mkdir "$W/Z"
printf 'dim N\ninput x : real[N]\noutput y[i:N] = 2 * x[i]\n' >"$W/z.npg"
/usr/bin/python3 -c "import numpy as np,sys; np.save(sys.argv[1], np.zeros((4, 0)))" "$W/Z/x.npy"
"$N" eval "$W/z.npg" --full "$W/Z" "$W/Z" -o "$W/ZO" || fail "eval of a zero-size dim"
if "$N" train "$W/z.npg" "$W/Z" -o "$W/ZM" >"$W/out.txt" 2>"$W/err.txt"; then fail "trained a zero-size dim"; fi
grep -q "^error: dim N is 0 in the training data" "$W/err.txt" || fail "zero dim message: $(cat "$W/err.txt")"
if grep -q DGESDD "$W/err.txt" "$W/out.txt"; then fail "LAPACK spoke"; fi

# 12. an int64 file for a real param names its type
/usr/bin/python3 -c "import numpy as np,sys; np.save(sys.argv[1], np.arange(24))" "$W/RT/rho.npy"
if "$N" eval $R --full "$W/RT" "$W/RT" -o "$W/RO" 2>"$W/err.txt"; then fail "int64 rho accepted"; fi
grep -q "param 'rho' is declared real but the array is int64" "$W/err.txt" || fail "int64 message: $(cat "$W/err.txt")"
# 12. a stage of 1e12 entries: eval --full and train fail naming the stage and the memory it needs
mkdir "$W/BIG"
printf 'dim N\ninput x : real[N]\noutput y[i:N, j:N] = x[i] * x[j]\n' >"$W/big.npg"
/usr/bin/python3 -c "import numpy as np,sys; np.save(sys.argv[1], np.ones((2, 1000000)))" "$W/BIG/x.npy"
if "$N" eval "$W/big.npg" --full "$W/BIG" "$W/BIG" -o "$W/BO" 2>"$W/err.txt"; then fail "eval of a 1e12-entry stage"; fi
grep -q "^error: out of memory: stage 'y', real\[N, N\] with N = 1000000, has 1e+12 entries and needs 8 TB, more than this machine's memory" "$W/err.txt" ||
  fail "1e12 eval message: $(cat "$W/err.txt")"
if "$N" train "$W/big.npg" "$W/BIG" -o "$W/BM" 2>"$W/err.txt"; then fail "train of a 1e12-entry stage"; fi
grep -q "^error: stage 'y' alone needs 8 TB per sample (1e+12 entries), more than --mem" "$W/err.txt" ||
  fail "1e12 train message: $(cat "$W/err.txt")"
# 1e20 entries: a count that overflows 64 bits is refused too, not wrapped
printf 'dim N\ninput x : real[N]\noutput y[i:N, j:N, k:N, l:N] = x[i] * x[j] * x[k] * x[l]\n' >"$W/big4.npg"
/usr/bin/python3 -c "import numpy as np,sys; np.save(sys.argv[1], np.ones((2, 100000)))" "$W/BIG/x.npy"
if "$N" eval "$W/big4.npg" --full "$W/BIG" "$W/BIG" -o "$W/BO" 2>"$W/err.txt"; then fail "eval of a 1e20-entry stage"; fi
grep -q "^error: out of memory: stage 'y', real\[N, N, N, N\] with N = 100000, has 1e+20 entries and needs 800 EB" "$W/err.txt" ||
  fail "1e20 eval message: $(cat "$W/err.txt")"
# a stage larger than --mem is refused, naming it, its size and the budget; one within it trains
/usr/bin/python3 -c "import numpy as np,sys; np.save(sys.argv[1], np.random.default_rng(3).random((4, 300)))" "$W/BIG/x.npy"
if "$N" train "$W/big.npg" "$W/BIG" -o "$W/BM" --mem 500k 2>"$W/err.txt"; then fail "train exceeded --mem"; fi
grep -q "^error: stage 'y' alone needs 720 kB per sample (9e+04 entries), more than --mem 500 kB: " "$W/err.txt" ||
  fail "--mem message: $(cat "$W/err.txt")"
"$N" train "$W/big.npg" "$W/BIG" -o "$W/BM" --mem 10M >/dev/null || fail "train within --mem"
# one of several ranks of an MPI job without --mpi is refused (each would write the same MODEL/)
if OMPI_COMM_WORLD_SIZE=2 "$N" train "$W/big.npg" "$W/BIG" -o "$W/RK" 2>"$W/err.txt"; then fail "a rank trained alone"; fi
grep -q "started as one of 2 ranks of an MPI job without --mpi" "$W/err.txt" || fail "rank message: $(cat "$W/err.txt")"
test ! -e "$W/RK" || fail "a refused rank left a model"
# 7. a 125 KB one-line program: a diagnostic shows a window of the line, generated C cites its start
/usr/bin/python3 -c "import sys; open(sys.argv[1], 'w').write('input x : real[2]\\noutput y = x[0] +' + ' ' * 125000 + 'x[1] * nosuch\\n')" "$W/long.npg"
if "$N" check "$W/long.npg" 2>"$W/err.txt"; then fail "check of an unknown name"; fi
test "$(wc -c <"$W/err.txt")" -lt 400 || fail "a diagnostic of $(wc -c <"$W/err.txt") bytes"
grep -q "^…  *x\[1\] \* nosuch$" "$W/err.txt" || fail "long line window: $(cat "$W/err.txt")"
sed -i 's/ \* nosuch//' "$W/long.npg"
"$N" emit "$W/long.npg" -o "$W/long.c" || fail "emit of a long line"
test -z "$(awk 'length > 400' "$W/long.c")" || fail "generated C holds the whole 125 KB line"
echo "ok"
