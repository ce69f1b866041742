#!/bin/sh
# stream.sh BUILD_DIR — streamed bases (issue 30; model.h,
# model_class_streamable): by default a model keeps only the bases the
# reduced model reads (inputs', outputs', externs'); the pair classes of
# radiosity are used in training and not stored. The model equals the one
# that keeps every basis (--keep-bases all) array for array, bit for bit
# in memory, to 1e-10 out of core where the pair bases are formed block by
# block and used at once (no file of their size written); verify reports the floors training measured;
# a program without such classes gets the same files either way; a
# streamed training killed at any moment leaves the previous model whole,
# no litter and no scratch; npgc tune keeps the bases by the same rule.
set -u
B=$1
W=$(mktemp -d /tmp/npg_stream_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
N="$B/npgc"
R=examples/radiosity/formfactors.npg
# a room of 96 faces (RT, held-out RV) and one of 24 (RO, ROV) for the out-of-core trainings that
# keep one row of each streamed class a pass: as many passes as a pair class has rows (576, not
# 9,216), each evaluating every sample on the smaller room
"$B/radiosity_data" "$W/RT" 96 30 0 1 1 >/dev/null || fail "radiosity data"
"$B/radiosity_data" "$W/RV" 96 6 0.05 0.95 2 >/dev/null || fail "radiosity data"
cp "$W/RT/tri.npy" "$W/RT/rho.npy" "$W/RV/"
"$B/radiosity_data" "$W/RO" 24 30 0 1 1 >/dev/null || fail "radiosity data"
"$B/radiosity_data" "$W/ROV" 24 6 0.05 0.95 2 >/dev/null || fail "radiosity data"
cp "$W/RO/tri.npy" "$W/RO/rho.npy" "$W/ROV/"

# every file of model $1 but the manifest is in $2 with the same bytes; $2
# has a basis file for each class, $1 none for its streamed classes
same_arrays() {
  for f in "$1"/*; do
    b=$(basename "$f")
    [ "$b" = manifest ] && continue
    cmp -s "$f" "$2/$b" || fail "$1/$b differs from $2/$b"
  done
}
# every array of model $1 is in $2 with the same numbers to 1e-10 (relative to the largest
# entry, at least 1; a residual table R of the estimate by RᵀR); the bases $1 keeps bit for bit; a class $1 keeps as coefficients C of its
# training values X (v's out of core, issue 30: coef_C.npy; X from the samples $3, RT by default)
# has X C equal to $2's basis to 1e-10
same_numbers() {
  /usr/bin/python3 - "$1" "$2" "$W/${3:-RT}/v.npy" <<'PY' || fail "$1 and $2 differ"
import os, sys, numpy as np
a, b = sys.argv[1], sys.argv[2]
assert all(os.path.exists(os.path.join(b, f.replace("coef_", "basis_"))) for f in os.listdir(a)), \
    "a file of %s not in %s" % (a, b)
for f in os.listdir(a):
    if f.startswith("coef_"):
        C, B = np.load(os.path.join(a, f)), np.load(os.path.join(b, f.replace("coef_", "basis_")))
        X = np.load(sys.argv[3]).reshape(C.shape[0], -1)
        d = np.max(np.abs(X.T @ C - B)) / max(1.0, np.max(np.abs(B)))
        assert d <= 1e-10, "%s: X C against the basis: %g" % (f, d)
        continue
    if not f.endswith(".npy"):
        continue
    x, y = np.load(os.path.join(a, f)), np.load(os.path.join(b, f))
    assert x.shape == y.shape, f
    if f.startswith("basis_"):
        assert np.array_equal(x, y), f
    elif f.startswith("est_") and x.shape[0] == x.shape[1] + 1:
        # a residual table R (then its columns' norms): made block by block (estimate_stream.c) or whole, its rows
        # are R's up to an orthogonal factor; ‖R z‖, so RᵀR, is what the two share
        D, big = x.shape[1], max(1.0, np.max(y[-1]) ** 2)
        d = max(np.max(np.abs(x[:D].T @ x[:D] - y[:D].T @ y[:D])) / big, np.max(np.abs(x[D] - y[D])) / np.sqrt(big))
        assert d <= 1e-10, "%s: RᵀR and the norms: %g" % (f, d)
    elif x.size:
        d = np.max(np.abs(x - y)) / max(1.0, np.max(np.abs(y)))
        assert d <= 1e-10, "%s: %g" % (f, d)
PY
}
streamed_labels() { # the labels of the classes model $1 streamed, and a check that their basis files are absent
  for c in $(sed -n 's/^streamed \([0-9]*\)$/\1/p' "$1/manifest"); do
    test ! -e "$1/basis_$c.npy" || fail "$1: streamed class $c has a basis file"
    sed -n "s/^class $c \([^ ]*\) .*/\1/p" "$1/manifest"
  done | tr '\n' ' '
}

# in memory; by the method of snapshots (the floors from the samples evaluated again); out of core
# (the bases in unnamed mapped files while training, the floors from the basis passes): on the
# 24-face room at --mem 40k, which streams 8 of the 9 classes one row a pass and writes the kept
# ones ({g} {e,b} {n}) as formed, as 160k does on 96 faces (the progress lines say so)
for mem in "" "--cap 8 --mem 10M" "--mem 40k"; do
  T=RT V=RV
  case "$mem" in *40k) T=RO V=ROV ;; esac
  "$N" train $R "$W/$T" -o "$W/S" $mem --progress >/dev/null 2>"$W/s.err" || fail "train streamed $mem"
  "$N" train $R "$W/$T" -o "$W/K" $mem --keep-bases all >/dev/null || fail "train --keep-bases all $mem"
  # out of core v's class too, kept as coefficients of its training values (issue 30)
  want="{s,h} {r} {c} {d,p} " nstreamed=6 floors="s h r c d p"
  case "$mem" in *40k) want="{s,h} {r} {c} {v} {d,p} " nstreamed=7 floors="s h r c d p v" ;; esac
  case "$mem" in *40k)
    for line in 'out of core: 8 of 9 classes streamed by rows, 576 passes over the 30 samples' \
        'so each pass keeps one row of each streamed class' \
        'no basis file: {s,h} {r} {c} {v} {d,p}; {v} kept as coefficients of its training values; kept, written as formed (no scratch A): {g} {e,b} {n} ('; do
      tr '\r' '\n' <"$W/s.err" | grep -aqF "$line" || fail "--mem 40k: no '$line': $(tr '\r' '\n' <"$W/s.err" | grep -a 'out of core')"
    done ;;
  esac
  [ "$(streamed_labels "$W/S")" = "$want" ] || fail "streamed classes $mem: $(streamed_labels "$W/S")"
  grep -Eq '^(streamed|floor) ' "$W/K/manifest" && fail "--keep-bases all $mem: streamed lines in the manifest"
  for c in $(sed -n 's/^class \([0-9]*\) .*/\1/p' "$W/K/manifest"); do
    test -e "$W/K/basis_$c.npy" || fail "--keep-bases all $mem: no basis_$c.npy"
  done
  case "$mem" in
    *40k) same_numbers "$W/S" "$W/K" RO ;; # the pair bases formed block by block (stream.c): sums in another order
    *) same_arrays "$W/S" "$W/K" ;;
  esac
  # the reduced outputs on held-out samples: the same numbers
  "$N" eval $R "$W/S" "$W/$V" -o "$W/ES" >/dev/null || fail "eval streamed $mem"
  "$N" eval $R "$W/K" "$W/$V" -o "$W/EK" >/dev/null || fail "eval stored $mem"
  /usr/bin/python3 - "$W/ES" "$W/EK" <<'PY' || fail "reduced outputs differ $mem"
import sys, numpy as np
for name in ("b.npy", "b.reduced.npy"):
    a, b = np.load(sys.argv[1] + "/" + name), np.load(sys.argv[2] + "/" + name)
    assert a.shape == b.shape and np.max(np.abs(a - b)) <= 1e-10 * max(1.0, np.max(np.abs(b))), name
PY
  # the training floors recorded: verify of the stored model on the training samples measures the same
  "$N" verify $R "$W/S" "$W/$V" --tol 0.05 >"$W/vs.txt" || fail "verify streamed $mem: $(cat "$W/vs.txt")"
  grep -q '^h .* n/a  *[0-9.e+-]*\* ' "$W/vs.txt" || fail "verify: h not reported as streamed: $(cat "$W/vs.txt")"
  grep -q "^\* $nstreamed quantities of streamed bases" "$W/vs.txt" || fail "verify: no note on streamed bases: $(cat "$W/vs.txt")"
  grep -q '^b .*(output)$' "$W/vs.txt" || fail "verify: output b not lifted"
  "$N" verify $R "$W/K" "$W/$T" --tol 1 >"$W/vk.txt" || fail "verify stored on training samples"
  for q in $floors; do
    rec=$(sed -n "s/^floor $q l2 \([^ ]*\) linf .*/\1/p" "$W/S/manifest")
    got=$(awk -v q=$q '$1 == q { print $5 }' "$W/vk.txt")
    # out of core the floor is sqrt(‖y‖² − ‖Bᵀy‖²)/‖y‖ from the passes: resolved to about 1e-7
    abs=1e-15
    case "$mem" in *40k) abs=1e-6 ;; esac
    /usr/bin/python3 -c "import sys; r, g, a = map(float, sys.argv[1:]); sys.exit(abs(r - g) > 1e-3 * g + a)" \
      "$rec" "$got" "$abs" || fail "training floor of $q $mem: recorded $rec, verify on the training samples $got"
  done
  rm -rf "$W/S" "$W/K" "$W/ES" "$W/EK"
done

# out of core the pair bases are formed block by block and used at once (stream.c): no file of a
# pair basis's size (rows x basis size) is written, v's neither (kept as coefficients of its training
# values). Under a file-size limit of 200 kB, below the smallest of them ({r}: 9,216 x 3 doubles),
# streamed training succeeds where keeping every basis cannot; the model is the old layout's to
# 1e-10 and gives the same reduced outputs on held-out samples. The caps of {e,b} keep the residual
# table of b (D x D, D about 10 x its size: b's operator reads {d,p}'s 8 directions) below the limit
opts="--mem 4M --energy 0.9999999 --basis e:cap=6 --basis b:cap=6"
(ulimit -f 400 && exec "$N" train $R "$W/RT" -o "$W/F" $opts --progress >/dev/null 2>"$W/f.err") ||
  fail "streamed training under a 200 kB file-size limit: $(tr '\r' '\n' <"$W/f.err" | tail -3)"
grep -aq '^out of core: bases formed block by block for the pre-multiplication, no basis file: {s,h} {r} {c} {v} {d,p}; {v} kept as coefficients of its training values; kept, written as formed (no scratch A): (' \
  "$W/f.err" || fail "no block-by-block bases: $(tr '\r' '\n' <"$W/f.err" | grep -a 'out of core')"
if (ulimit -f 400 && exec "$N" train $R "$W/RT" -o "$W/G" $opts --keep-bases all >/dev/null 2>&1); then
  fail "the file-size limit does not bite: --keep-bases all trained under it"
fi
"$N" train $R "$W/RT" -o "$W/G" $opts --keep-bases all >/dev/null || fail "train --keep-bases all $opts"
same_numbers "$W/F" "$W/G"
"$N" eval $R "$W/F" "$W/RV" -o "$W/EF" >/dev/null && "$N" eval $R "$W/G" "$W/RV" -o "$W/EG" >/dev/null || fail "eval $opts"
/usr/bin/python3 - "$W/EF" "$W/EG" <<'PY' || fail "reduced outputs differ $opts"
import sys, numpy as np
for name in ("b.npy", "b.reduced.npy"):
    a, b = np.load(sys.argv[1] + "/" + name), np.load(sys.argv[2] + "/" + name)
    assert a.shape == b.shape and np.max(np.abs(a - b)) <= 1e-10 * max(1.0, np.max(np.abs(b))), name
PY
rm -rf "$W/F" "$W/G" "$W/EF" "$W/EG"
# a block whose rows (c[i,j] reads h[j,i]: the transposed stripe too) exceed a pass's share of
# --mem is split into sub-blocks (at cap 2 the passes' rows are small against them): the same model
"$N" train $R "$W/RT" -o "$W/F" --cap 2 --mem 1M --progress >/dev/null 2>"$W/f.err" || fail "train --cap 2 --mem 1M"
passes=$(tr '\r' '\n' <"$W/f.err" | sed -n 's/^out of core: .* \([0-9]*\) passes over .*/\1/p')
blocks=$(tr '\r' '\n' <"$W/f.err" | sed -n 's/^out of core: bases formed block by block.* (\([0-9]*\) blocks .*/\1/p')
[ -n "$passes" ] && [ -n "$blocks" ] && [ "$blocks" -gt "$passes" ] || fail "--cap 2 --mem 1M: $blocks blocks for $passes passes"
"$N" train $R "$W/RT" -o "$W/G" --cap 2 --mem 1M --keep-bases all >/dev/null || fail "train --cap 2 --mem 1M --keep-bases all"
same_numbers "$W/F" "$W/G"
rm -rf "$W/F" "$W/G"

# a size: the pair bases are most of the old layout
"$N" train $R "$W/RT" -o "$W/S" >"$W/ts.txt" && "$N" train $R "$W/RT" -o "$W/K" --keep-bases all >"$W/tk.txt" || fail "train"
grep -q '^streamed bases, used in training and not kept: {s,h} {r} {c} {d,p} (' "$W/ts.txt" || fail "table: $(cat "$W/ts.txt")"
grep -q '^streamed bases' "$W/tk.txt" && fail "--keep-bases all: the table names streamed bases"
s=$(du -sk "$W/S" | cut -f1) k=$(du -sk "$W/K" | cut -f1)
[ "$s" -lt "$k" ] || fail "the streamed model ($s kB) is not smaller than the old layout ($k kB)"

# --keep-bases NAME keeps that class; an unknown name is refused before training
"$N" train $R "$W/RT" -o "$W/H" --keep-bases h,m_r >/dev/null || fail "train --keep-bases h,m_r"
[ "$(streamed_labels "$W/H")" = "{c} {d,p} " ] || fail "--keep-bases h,m_r: $(streamed_labels "$W/H")"
if "$N" train $R "$W/RT" -o "$W/X" --keep-bases hh 2>"$W/err.txt"; then fail "unknown --keep-bases name accepted"; fi
grep -q "keep-bases hh: no quantity or class of that name" "$W/err.txt" || fail "message: $(cat "$W/err.txt")"
test ! -e "$W/X" || fail "a refused training left a model"

# npgc tune follows the same rule: its model keeps no pair basis unless --keep-bases names it, and
# equals the one that keeps every basis array for array; verify reads the floors it recorded
"$N" tune $R "$W/RT" "$W/RV" --tol 0.05 -o "$W/TS" >"$W/tune.txt" || fail "tune streamed: $(cat "$W/tune.txt")"
"$N" tune $R "$W/RT" "$W/RV" --tol 0.05 -o "$W/TK" --keep-bases all >"$W/tunek.txt" || fail "tune --keep-bases all"
[ "$(streamed_labels "$W/TS")" = "{s,h} {r} {c} {d,p} " ] || fail "tune: streamed classes: $(streamed_labels "$W/TS")"
grep -Eq '^(streamed|floor) ' "$W/TK/manifest" && fail "tune --keep-bases all: streamed lines in the manifest"
same_arrays "$W/TS" "$W/TK"
grep -q '^streamed bases, used in training and not kept: {s,h} {r} {c} {d,p} (' "$W/tune.txt" || fail "tune: $(cat "$W/tune.txt")"
grep -q '^streamed bases' "$W/tunek.txt" && fail "tune --keep-bases all: names streamed bases"
"$N" verify $R "$W/TS" "$W/RV" --tol 0.05 >"$W/vts.txt" || fail "verify of the tuned model: $(cat "$W/vts.txt")"
grep -q '^h .* n/a  *[0-9.e+-]*\* ' "$W/vts.txt" || fail "verify: h of the tuned model not reported as streamed"
"$N" tune $R "$W/RT" "$W/RV" --tol 0.05 -o "$W/TH" --keep-bases h,m_r >/dev/null || fail "tune --keep-bases h,m_r"
[ "$(streamed_labels "$W/TH")" = "{c} {d,p} " ] || fail "tune --keep-bases h,m_r: $(streamed_labels "$W/TH")"
if "$N" tune $R "$W/RT" "$W/RV" --tol 0.05 -o "$W/X" --keep-bases hh 2>"$W/err.txt" >/dev/null; then
  fail "tune: unknown --keep-bases name accepted"
fi
grep -q "keep-bases hh: no quantity or class of that name" "$W/err.txt" || fail "tune message: $(cat "$W/err.txt")"
test ! -e "$W/X" || fail "a refused tune left a model"

# a program without pair classes: the same files, the manifest included, either way
P=examples/rational/rational.npg
"$B/rational_data" "$W/QT" 40 1 >/dev/null || fail "rational data"
"$N" train $P "$W/QT" -o "$W/Q1" >/dev/null && "$N" train $P "$W/QT" -o "$W/Q2" --keep-bases all >/dev/null || fail "rational"
for f in "$W/Q1"/*; do cmp -s "$f" "$W/Q2/$(basename "$f")" || fail "rational: $(basename "$f") differs"; done
[ "$(ls "$W/Q1" | wc -l)" = "$(ls "$W/Q2" | wc -l)" ] || fail "rational: different files"

# kill -9 at random moments of a streamed out-of-core training: the previous
# model or the new one stays whole (it verifies), no scratch in TMPDIR. The 24-face room at
# --mem 40k (8 of 9 classes streamed one row a pass, as above), so that each training takes
# seconds, not tens of them, under the sanitizers too; the moments are random fractions of the
# time the same training took just before (the kills land inside it in any build, on any load)
mkdir -p "$W/tmp"
t0=$(date +%s.%N)
"$N" train $R "$W/RO" -o "$W/M" --mem 40k --cap 6 >/dev/null 2>&1 || fail "training before the kills"
t1=$(date +%s.%N)
for i in 1 2 3; do
  TMPDIR="$W/tmp" "$N" train $R "$W/RO" -o "$W/M" --mem 40k --cap 6 >/dev/null 2>&1 &
  pid=$!
  sleep "$(/usr/bin/python3 -c "import random, sys; random.seed($i)
print(round(random.uniform(0.02, 0.95) * (float(sys.argv[2]) - float(sys.argv[1])), 2))" "$t0" "$t1")"
  kill -9 $pid 2>/dev/null
  wait $pid 2>/dev/null
  "$N" verify $R "$W/M" "$W/ROV" --tol 0.05 >/dev/null 2>&1 || fail "kill $i: the model left does not verify"
  [ -z "$(ls "$W/tmp")" ] || fail "kill $i: scratch left in TMPDIR: $(ls "$W/tmp")"
done
# and killed during the block-by-block pre-multiplication (once its progress shows; on a loaded
# machine the training may take minutes to get there: the wait ends when it prints or exits)
for i in 1; do
  TMPDIR="$W/tmp" "$N" train $R "$W/RO" -o "$W/M" --mem 40k --cap 6 --progress >/dev/null 2>"$W/kill.err" &
  pid=$!
  n=0
  while ! grep -aq 'streamed bases' "$W/kill.err" && kill -0 $pid 2>/dev/null && [ $n -lt 12000 ]; do
    sleep 0.05
    n=$((n + 1))
  done
  grep -aq 'streamed bases' "$W/kill.err" || fail "kill in the streamed pre-multiplication $i: it never began"
  sleep "0.$i"
  kill -9 $pid 2>/dev/null
  wait $pid 2>/dev/null
  "$N" verify $R "$W/M" "$W/ROV" --tol 0.05 >/dev/null 2>&1 || fail "kill in the streamed pre-multiplication $i: the model left does not verify"
  [ -z "$(ls "$W/tmp")" ] || fail "kill in the streamed pre-multiplication $i: scratch left in TMPDIR: $(ls "$W/tmp")"
done
# a temporary folder a kill -9 left is removed by the next training
TMPDIR="$W/tmp" "$N" train $R "$W/RO" -o "$W/M" --mem 40k --cap 6 >/dev/null || fail "training after the kills"
[ -z "$(ls "$W" | grep -E '^M\.' || true)" ] || fail "litter after the next run: $(ls "$W")"
echo "ok"
