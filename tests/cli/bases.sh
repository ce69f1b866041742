#!/bin/sh
# bases.sh BUILD_DIR — the bases as a user meets them (issue 11): --basis
# names checked (an unknown one refused with a message; a quantity, a class
# and a numerator accepted), the training table (kept / cap, energy lost),
# verify's warnings,
# --center, the spectra in MODEL/ (listed with checksums), --spectra DIR,
# npgc plot and npgc tune.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_bases_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

P=examples/rational/rational.npg
"$B/rational_data" "$W/TRAIN" 100 1 >/dev/null
# unknown names are refused, naming the name and what exists
if "$B/npgc" train $P "$W/TRAIN" -o "$W/M" --basis z:cap=3 >/dev/null 2>"$W/err.txt"; then fail "--basis z accepted"; fi
grep -q -- "--basis z: no quantity, class or numerator of that name" "$W/err.txt" || fail "message: $(cat "$W/err.txt")"
grep -q "m_y (y, y.num1)" "$W/err.txt" || fail "the message lists the classes: $(cat "$W/err.txt")"
test ! -e "$W/M" || fail "a refused training left a model"
if "$B/npgc" train $P "$W/TRAIN" -o "$W/M" --basis x:size=3 >/dev/null 2>&1; then fail "--basis x:size=3 accepted"; fi
if "$B/npgc" train $P "$W/TRAIN" -o "$W/M" --center maybe >/dev/null 2>&1; then fail "--center maybe accepted"; fi
# a quantity, a class and a numerator; cap and max are one option
"$B/npgc" train $P "$W/TRAIN" -o "$W/M" --basis x:cap=1 --basis m_y:max=1 --basis y.num1:energy=0.5,center=off \
  >"$W/train.txt" || fail "train with --basis"
grep -q "^{x} .* x 1/1 lost [0-9].[0-9]e[-+][0-9]*$" "$W/train.txt" || fail "x's line: $(cat "$W/train.txt")"
grep -q "y 1/1 lost .*, y.num1 1/1 lost .* (uncentered)" "$W/train.txt" || fail "y's line: $(cat "$W/train.txt")"
grep -q "^warning: x (class {x}) hit its cap 1 with .* of its centered energy lost" "$W/train.txt" ||
  fail "no warning at the cap: $(cat "$W/train.txt")"
# the program's basis statement says the same: cap, energy, center
{ cat $P; echo "basis y: cap 1, center off"; } >"$W/opts.npg"
"$B/npgc" train "$W/opts.npg" "$W/TRAIN" -o "$W/MO" >"$W/train.txt" || fail "train with a basis statement"
grep -q "y 1/1 lost .* (uncentered), y.num1 2/60 lost" "$W/train.txt" || fail "basis statement ignored: $(cat "$W/train.txt")"
# verify's warnings: x's one vector cannot hold the test samples, and y's
# error is then its inputs', not its basis's
"$B/rational_data" "$W/TEST" 30 2 >/dev/null
if "$B/npgc" verify $P "$W/M" "$W/TEST" --tol 1e-3 >"$W/verify.txt"; then fail "verify passed a cap-1 input"; fi
grep -q "^warning: input x: its projection floor .* exceeds --tol 0.001" "$W/verify.txt" || fail "input warning: $(cat "$W/verify.txt")"
grep -q "^warning: stage y: error .* its projection floor .*it reads x with error .*--basis x:cap=N" "$W/verify.txt" ||
  fail "stage warning: $(cat "$W/verify.txt")"
# spectra: in MODEL/ with checksums, and in --spectra DIR
"$B/npgc" train $P "$W/TRAIN" -o "$W/M" --center off --spectra "$W/SPEC" >"$W/train.txt" || fail "train --center off"
grep -q "x 2/60 lost 0.0e+00 (uncentered)" "$W/train.txt" || fail "uncentered table: $(cat "$W/train.txt")"
# x is under y's division: kept whole by default (energy 1, DESIGN §12)
grep -q "^member 0 x cap 60 energy 1 kept 2 captured 1 center 0 lost 0$" "$W/M/manifest" || fail "manifest member line"
grep -q "^array spectrum_y.num1.npy 2 fnv1a64 " "$W/M/manifest" || fail "manifest lacks the spectrum array"
grep -q "^file spectrum_x.csv fnv1a64 " "$W/M/manifest" || fail "manifest lacks the spectrum CSV"
cmp "$W/M/spectrum_x.csv" "$W/SPEC/spectrum_x.csv" || fail "--spectra differs from MODEL/"
/usr/bin/python3 - "$W" <<'PY' || fail "spectra differ from numpy's singular values"
import sys, numpy as np
w = sys.argv[1]
x = np.load(w + "/TRAIN/x.npy")
s = np.load(w + "/SPEC/spectrum_x.npy")
ref = np.linalg.svd(x.T, compute_uv=False)
assert np.allclose(s, ref, rtol=1e-12), (s, ref)
rows = [l.split(",") for l in open(w + "/M/spectrum_x.csv") if l[0].isdigit()]
assert [float(r[1]) for r in rows] == list(s)
PY
# npgc plot draws the spectra as a PNG (checked by its signature and size)
"$B/npgc" plot "$W/M" -o "$W/spectra.png" >/dev/null || fail "plot"
/usr/bin/python3 -c "import sys; b=open(sys.argv[1],'rb').read(); assert b[:8]==b'\x89PNG\r\n\x1a\n' and len(b)>2000" "$W/spectra.png" ||
  fail "plot wrote no PNG"
if "$B/npgc" plot "$W/NONE" -o "$W/x.png" 2>/dev/null; then fail "plot of a missing model"; fi
# npgc tune: meets its tolerance (npgc verify agrees), writes the model and the PNG, and says plainly
# when the tolerance cannot be met, naming the limiting class
"$B/npgc" tune $P "$W/TRAIN" "$W/TEST" --tol 1e-8 -o "$W/TUNED" >"$W/tune.txt" || fail "tune: $(cat "$W/tune.txt")"
grep -q "<- chosen" "$W/tune.txt" && grep -q "^chosen: cost .* m_x=2 m_y=2 -> " "$W/tune.txt" || fail "tune table: $(cat "$W/tune.txt")"
"$B/npgc" verify $P "$W/TUNED" "$W/TEST" --tol 1e-8 >/dev/null || fail "the tuned model misses --tol"
test -s "$W/TUNED-tune.png" || fail "tune wrote no PNG"
if "$B/npgc" tune $P "$W/TRAIN" "$W/TEST" --tol 1e-3 --max-cap 1 -o "$W/TUNED1" >"$W/tune.txt"; then fail "tune met 1e-3 with one vector"; fi
grep -q "^--tol 0.001 cannot be met: .*" "$W/tune.txt" && grep -q "^class m_x limits it: .*raise it" "$W/tune.txt" ||
  fail "unmet message: $(cat "$W/tune.txt")"
test ! -e "$W/TUNED1" || fail "an unmet tune wrote a model"
# --sizes (issue 41): eval, verify and bench at smaller sizes without retraining; m_x at 1 equals
# training with x's cap at 1, uncentered as M (one member: its first vector either way); names and sizes checked
"$B/npgc" train $P "$W/TRAIN" -o "$W/M1" --center off --basis x:cap=1 >/dev/null || fail "train x:cap=1"
"$B/npgc" eval $P "$W/M" "$W/TEST" -o "$W/OCUT" --sizes m_x=1 || fail "eval --sizes"
"$B/npgc" eval $P "$W/M1" "$W/TEST" -o "$W/ORET" || fail "eval the retrained model"
/usr/bin/python3 - "$W" <<'PY' || fail "--sizes m_x=1 differs from retraining at cap 1"
import sys, numpy as np
w = sys.argv[1]
a, b = np.load(w + "/OCUT/y.npy"), np.load(w + "/ORET/y.npy")
assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max(), np.abs(a - b).max()
PY
"$B/npgc" verify $P "$W/M" "$W/TEST" --sizes x=1 --tol 10 >"$W/verify.txt" || fail "verify --sizes"
grep -q "^x  *input  *1 " "$W/verify.txt" || fail "verify at size 1: $(cat "$W/verify.txt")"
"$B/npgc" bench $P "$W/M" "$W/TEST" --sizes m_x=1 --reps 1 >/dev/null || fail "bench --sizes"
if "$B/npgc" eval $P "$W/M" "$W/TEST" -o "$W/OBAD" --sizes m_q=1 2>"$W/err.txt"; then fail "--sizes m_q accepted"; fi
grep -q -- "--sizes m_q: no class of that name; the classes: m_x {x}, m_y {y}" "$W/err.txt" || fail "message: $(cat "$W/err.txt")"
if "$B/npgc" eval $P "$W/M" "$W/TEST" -o "$W/OBAD" --sizes m_x=9 2>"$W/err.txt"; then fail "--sizes m_x=9 accepted"; fi
grep -q -- "--sizes m_x=9: class m_x has 2 basis vectors" "$W/err.txt" || fail "message: $(cat "$W/err.txt")"
if "$B/npgc" eval $P "$W/M" "$W/TEST" -o "$W/OBAD" --sizes m_x=0 2>"$W/err.txt"; then fail "--sizes m_x=0 accepted"; fi
grep -q -- "--sizes m_x: '0' is not a whole number of at least 1" "$W/err.txt" || fail "message: $(cat "$W/err.txt")"
test ! -e "$W/OBAD" || fail "a refused eval wrote its output"
# member lines without center/lost and no spectra (as models before centering were written) load
# as uncentered once the manifest vouches for itself (its checksum line: a model written before
# the manifest had one is refused, "retrain"); plot says what it lacks
mkdir "$W/OLD"
grep -v "spectrum_" "$W/M/manifest" | grep -v "^manifest " | sed 's/ center [01] lost [^ ]*$//' >"$W/OLD/manifest"
for f in "$W"/M/*.npy; do case "$f" in *spectrum_*) ;; *) cp "$f" "$W/OLD/" ;; esac; done
if "$B/npgc" verify $P "$W/OLD" "$W/TEST" --tol 1e-8 >/dev/null 2>"$W/err.txt"; then fail "a manifest without its checksum loaded"; fi
grep -q "no 'manifest' checksum line: cut short, or written by an older npg (retrain)" "$W/err.txt" ||
  fail "unsealed manifest message: $(cat "$W/err.txt")"
/usr/bin/python3 - "$W/OLD/manifest" <<'PY'
import sys
path = sys.argv[1]
text = open(path, "rb").read()
h = 0xcbf29ce484222325
for b in text:
    h = ((h ^ b) * 0x100000001b3) & 0xffffffffffffffff
open(path, "ab").write(b"manifest fnv1a64 %016x\n" % h)
PY
"$B/npgc" verify $P "$W/OLD" "$W/TEST" --tol 1e-8 >/dev/null || fail "member lines without center no longer load"
if "$B/npgc" plot "$W/OLD" -o "$W/old.png" 2>"$W/err.txt"; then fail "plot of a model without spectra"; fi
grep -q "member x has no spectrum (a model trained before spectra were kept: retrain it)" "$W/err.txt" ||
  fail "old-model plot message: $(cat "$W/err.txt")"
# a deforming mesh whose rest shape dominates: centered (the default) at least 5x more accurate
D=tests/programs/deforming_springs.npg
/usr/bin/python3 tests/cli/deforming_springs_data.py "$W/MTRAIN" 60 7
/usr/bin/python3 tests/cli/deforming_springs_data.py "$W/MTEST" 20 8
for c in on off; do
  # every member at 0.999, x and l2 too (under a power they are kept whole by default: DESIGN §12)
  "$B/npgc" train $D "$W/MTRAIN" -o "$W/MESH$c" --center $c --valid none --basis "*:energy=0.999" >/dev/null || fail "train the mesh, --center $c"
  "$B/npgc" verify $D "$W/MESH$c" "$W/MTEST" --tol 10 >"$W/mesh$c.txt" || fail "verify the mesh, --center $c"
done
on=$(awk '$1 == "f" { print $4 }' "$W/meshon.txt"); off=$(awk '$1 == "f" { print $4 }' "$W/meshoff.txt")
/usr/bin/python3 -c "import sys; on, off = map(float, sys.argv[1:]); print('deforming springs: f error centered %.3e, uncentered %.3e' % (on, off)); assert on * 5 <= off" "$on" "$off" ||
  fail "centered is not 5x better on the deforming mesh"
# a corrupted CSV is named
printf 'X' >>"$W/M/spectrum_x.csv"
if "$B/npgc" verify $P "$W/M" "$W/TRAIN" 2>"$W/err.txt" >/dev/null; then fail "corrupted CSV accepted"; fi
grep -q "M/spectrum_x.csv: checksum mismatch" "$W/err.txt" || fail "CSV corruption message: $(cat "$W/err.txt")"
echo "ok"
