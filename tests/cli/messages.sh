#!/bin/sh
# messages.sh BUILD_DIR — issue 38's messages and file safety: each value, file or
# failure named as it is (--valid read strictly, write errors of plot and --spectra
# reported with the file, the files that disagree named, ...).
set -eu
B=$1
W=$(mktemp -d /tmp/npg_msg_XXXXXX)
trap 'umount "$W/full" "$W/full2" 2>/dev/null || true; rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
N=$B/npgc

cat >"$W/sqrt.npg" <<'NPG'
dim N
input x : real[N]
output y[i:N] = x[i]^(1/2)
NPG
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(1)
os.makedirs(w + "/TR")
np.save(w + "/TR/x.npy", 1 + rng.random((20, 5)))
PY

# 1. --valid is a fraction in (0, 0.5], none, or a folder that exists: anything else is refused naming
#    --valid and the value (0, 0.25x and NONE were read as folder names)
touch "$W/afile"
for bad in "0|--valid 0 is out of range (expected (0, 0.5])" \
           "0.25x|--valid '0.25x' is not a number (expected (0, 0.5])" \
           "0.7|--valid 0.7 is out of range" \
           "NONE|--valid 'NONE' is not a folder that exists (expected a fraction in (0, 0.5] of DATA/'s samples, none, or a folder of validation samples); did you mean 'none'?" \
           "$W/nosuch|--valid '$W/nosuch' is not a folder that exists" \
           "$W/afile|--valid '$W/afile' is not a folder (expected"; do
  v=${bad%%|*}; msg=${bad#*|}
  if "$N" train "$W/sqrt.npg" "$W/TR" -o "$W/M" --valid "$v" >/dev/null 2>"$W/err.txt"; then fail "--valid $v accepted"; fi
  grep -qF "npgc train: $msg" "$W/err.txt" || fail "--valid $v: $(cat "$W/err.txt")"
  test ! -e "$W/M" || fail "--valid $v left a model"
done
"$N" train "$W/sqrt.npg" "$W/TR" -o "$W/M" --valid 0.25 >/dev/null || fail "--valid 0.25"
"$N" train "$W/sqrt.npg" "$W/TR" -o "$W/M2" --valid none >/dev/null || fail "--valid none"
"$N" train "$W/sqrt.npg" "$W/TR" -o "$W/M3" --valid "$W/TR" >/dev/null || fail "--valid DIR"

# 2. npgc plot checks every write and the close: a full disk (a 16 kB tmpfs, when this runs as root and may
#    mount one) or a file size limit (ulimit -f, anywhere) is reported with the file and its cause, and the
#    chart already there is left as it was, with no temporary file beside it
"$N" plot "$W/M" -o "$W/p.png" >/dev/null || fail "plot"
cp "$W/p.png" "$W/p0.png"
if (trap '' XFSZ; ulimit -f 8; "$N" plot "$W/M" -o "$W/p.png") >/dev/null 2>"$W/err.txt"; then fail "plot past ulimit -f"; fi
grep -qF "error: $W/p.png: cannot write the PNG: File too large" "$W/err.txt" || fail "plot EFBIG: $(cat "$W/err.txt")"
cmp -s "$W/p.png" "$W/p0.png" || fail "a failed plot changed the chart there"
test -z "$(ls "$W" | grep 'p.png.tmp')" || fail "a failed plot left $(ls "$W" | grep 'p.png.tmp')"
mkdir "$W/full"
if [ "$(id -u)" = 0 ] && mount -t tmpfs -o size=16k tmpfs "$W/full" 2>/dev/null; then
  if "$N" plot "$W/M" -o "$W/full/p.png" >/dev/null 2>"$W/err.txt"; then umount "$W/full"; fail "plot on a full disk"; fi
  left=$(ls -A "$W/full")
  umount "$W/full"
  grep -qF "error: $W/full/p.png: cannot write the PNG: No space left on device" "$W/err.txt" ||
    fail "plot ENOSPC: $(cat "$W/err.txt")"
  test -z "$left" || fail "a plot on a full disk left $left"
fi

# 3. npgc check prints a stage's shape as the user wrote it: an explicit index variable with its dim
#    (real[i:N]), an implicit one (z = y + x) as the dim alone, never the compiler's name (real[_i:N])
cat >"$W/implicit.npg" <<'NPG'
dim N, M
input x : real[N]
input u : real[N, M]
y[i:N] = x[i] * x[i]
output z = y + x
output w = 2 * u
NPG
"$N" check "$W/implicit.npg" >"$W/out.txt" || fail "check implicit.npg"
grep -q "^  y : real\[i:N\]   contraction" "$W/out.txt" || fail "check, explicit: $(grep ' y :' "$W/out.txt")"
grep -q "^  z : real\[N\]   contraction, output" "$W/out.txt" || fail "check, implicit: $(grep ' z :' "$W/out.txt")"
grep -q "^  w : real\[N, M\]   contraction, output" "$W/out.txt" || fail "check, implicit 2: $(grep ' w :' "$W/out.txt")"
! grep -q "_[ij]:" "$W/out.txt" || fail "check prints a compiler's index name: $(grep '_[ij]:' "$W/out.txt")"

# 4. a learned extern map whose inputs file was shortened (and resealed in the manifest, so no checksum
#    catches it) is reported as that file, not as extern_v_values.npy
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(3)
os.makedirs(w + "/ED")
F, V, S = 4, 6, 30
np.save(w + "/ED/tri.npy", rng.integers(0, V, (F, 3)).astype(np.int64))
np.save(w + "/ED/g.npy", rng.random((S, V, 3)))
np.save(w + "/ED/v.npy", rng.random((S, F)))
PY
"$N" train tests/programs/extern_stage.npg "$W/ED" -o "$W/EM" >/dev/null || fail "train extern_stage"
reseal() { # reseal MODEL NAME ROWS: keep the first ROWS rows of MODEL/NAME.npy and reseal the manifest
  /usr/bin/python3 - "$@" <<'PY'
import io, sys, numpy as np
d, name, rows = sys.argv[1], sys.argv[2], int(sys.argv[3])
def fnv1a64(b):
    h = 0xcbf29ce484222325
    for x in b:
        h = ((h ^ x) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h
a = np.load("%s/%s.npy" % (d, name))[:rows]
buf = io.BytesIO(); np.save(buf, a); blob = buf.getvalue()
open("%s/%s.npy" % (d, name), "wb").write(blob)
lines = open(d + "/manifest", "rb").read().split(b"\n")[:-2]
lines = [b"array %s.npy %s fnv1a64 %016x" % (name.encode(), b"x".join(b"%d" % n for n in a.shape), fnv1a64(blob))
         if l.startswith(b"array %s.npy " % name.encode()) else l for l in lines]
body = b"\n".join(lines) + b"\n"
open(d + "/manifest", "wb").write(body + b"manifest fnv1a64 %016x\n" % fnv1a64(body))
PY
}
for f in inputs values; do
  rm -rf "$W/EM2"; cp -r "$W/EM" "$W/EM2"
  reseal "$W/EM2" extern_v_$f 20
  other=values; test $f = inputs || other=inputs
  if "$N" eval tests/programs/extern_stage.npg "$W/EM2" "$W/ED" -o "$W/EO" 2>"$W/err.txt"; then fail "eval with a short extern_v_$f"; fi
  grep -qF "error: $W/EM2/extern_v_$f.npy: 20 rows, but extern_v_$other.npy has 30 and the model 30 training samples: the learned map of extern 'v' needs one row per training sample in both files" "$W/err.txt" ||
    fail "short extern_v_$f: $(cat "$W/err.txt")"
done

# 5. a degenerate triangle (two equal corners at sample 5) is named where the zero is, a[1] = 0, not only as
#    the NaN in the stage that divides by it
cat >"$W/un.npg" <<'NPG'
use geometry
dim F, V
param tri : int[F, 3]
input g : real[V, 3]
n[f:F] = tri_normal(g, tri, f)
a[f:F] = norm2(n[f])
output u[f:F] = n[f] * a[f]^(-1/2)
NPG
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(5)
os.makedirs(w + "/UD")
np.save(w + "/UD/tri.npy", np.array([[0, 1, 2], [1, 2, 3], [0, 2, 3]], dtype=np.int64))
g = rng.random((12, 4, 3)); g[5, 3] = g[5, 1]
np.save(w + "/UD/g.npy", g)
PY
if "$N" eval "$W/un.npg" --full "$W/UD" "$W/UD" -o "$W/UO" 2>"$W/err.txt"; then fail "eval of a degenerate triangle"; fi
grep -qF "error: sample 5: stage 'u' is not finite: u[1, 0] is NaN (a division by zero: a[1] is 0, and u raises it to the power -1/2)" "$W/err.txt" ||
  fail "degenerate triangle, eval: $(cat "$W/err.txt")"
if "$N" train "$W/un.npg" "$W/UD" -o "$W/UM" 2>"$W/err.txt" >/dev/null; then fail "training on a degenerate triangle"; fi
grep -qF "error: training sample 5: u is not finite (u[1, 0] is NaN): the sample makes it undefined (a division by zero: a[1] is 0, and u raises it to the power -1/2)" "$W/err.txt" ||
  fail "degenerate triangle, train: $(cat "$W/err.txt")"

#    the same zero through a gather (a[pick[f]]), an odd root (^(-1/3)), a root stage divided by
#    (r = a^(1/3), then n / r) and a base of several factors: each names a[1], where the message was
#    the generic one
np_pick() { /usr/bin/python3 -c "import numpy as np, sys; np.save(sys.argv[1], np.array([1, 2, 0], dtype=np.int64))" "$1"; }
cp -r "$W/UD" "$W/UP"; np_pick "$W/UP/pick.npy"
while IFS='|' read -r body want; do
  { sed '$d' "$W/un.npg"; echo "param pick : int[F]"; printf '%b\n' "$body"; } > "$W/ug.npg"
  if "$N" eval "$W/ug.npg" --full "$W/UP" "$W/UP" -o "$W/UGO" 2>"$W/err.txt"; then fail "eval of a degenerate triangle: $body"; fi
  rm -rf "$W/UGO"
  grep -qF "$want" "$W/err.txt" || fail "degenerate triangle through $body: $(cat "$W/err.txt")"
done <<'CASES'
output u[f:F] = n[f] * a[pick[f]]^(-1/2)|u[0, 0] is an infinity (a division by zero: a[1] is 0, and u raises it to the power -1/2)
output u[f:F] = n[f] * a[f]^(-1/3)|u[1, 0] is NaN (a division by zero: a[1] is 0, and u raises it to the power -1/3)
r[f:F] = a[pick[f]]^(1/3)\noutput u[f:F] = n[f] / r[f]|u[0, 0] is an infinity (a division by zero: r[0] is 0, and u divides by it; a[1] is 0, and r raises it to the power 1/3)
output u[f:F] = n[f] * (2 * a[f] * a[f])^(-1/3)|u[1, 0] is NaN (a division by zero: the base of its power -1/3 is 0 there, where a[1] is 0)
CASES

# 6. --spectra DIR is all or none: on a disk that fills after two of the new spectra's files, the spectra of
#    the last training stay there byte for byte and no temporary file is left (root, a 64 kB tmpfs)
mkdir "$W/full2"
if [ "$(id -u)" = 0 ] && mount -t tmpfs -o size=64k tmpfs "$W/full2" 2>/dev/null; then
  /usr/bin/python3 -c "import numpy as np, sys; np.save(sys.argv[1], 1 + np.random.default_rng(2).random((200, 300)))" \
    "$W/big.npy"
  mkdir "$W/TRB"; mv "$W/big.npy" "$W/TRB/x.npy"
  ok=1
  "$N" train "$W/sqrt.npg" "$W/TR" -o "$W/S1" --spectra "$W/full2/SP" >/dev/null || ok=0
  cp -r "$W/full2/SP" "$W/SP0"
  avail=$(df -k "$W/full2" | awk 'NR==2 {print $4}')
  head -c $(( (avail - 12) * 1024 )) /dev/zero >"$W/full2/fill" || true
  if "$N" train "$W/sqrt.npg" "$W/TRB" -o "$W/S2" --spectra "$W/full2/SP" >/dev/null 2>"$W/err.txt"; then ok=2; fi
  left=$(ls "$W/full2/SP" | grep -v '^spectrum_[a-z0-9.]*\.\(npy\|csv\)$' || true)
  diff -r "$W/SP0" "$W/full2/SP" >/dev/null || ok=3
  umount "$W/full2"
  test $ok = 1 || fail "spectra on a filling disk: case $ok: $(cat "$W/err.txt")"
  grep -qF "error: $W/full2/SP/spectrum_y.npy: cannot write: No space left on device" "$W/err.txt" ||
    fail "spectra ENOSPC message: $(cat "$W/err.txt")"
  grep -qF "npgc train: the model in $W/S2 is whole; no spectrum was written to $W/full2/SP (its files are as they were)" \
    "$W/err.txt" || fail "spectra ENOSPC, the model: $(cat "$W/err.txt")"
  test -z "$left" || fail "spectra on a full disk left $left"
  "$N" verify "$W/sqrt.npg" "$W/S2" "$W/TRB" --tol 10 >/dev/null || fail "the model beside failed spectra"
fi

# 7. inputs of no samples, of a small and of a huge dim (10^12: the file holds its header only): the full
#    evaluation writes empty outputs of the shapes the files give (it said "shape entry 1 is negative (-1)"),
#    a dim they disagree on is named as with samples, and the commands that need samples say so
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]
for d in ("Z0", "ZH", "ZD", "ZP"):
    os.makedirs(w + "/" + d)
for d in ("Z0", "ZD", "ZP"):
    np.save(w + "/%s/x.npy" % d, np.zeros((0, 5)))
with open(w + "/ZH/x.npy", "wb") as f:
    np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (0, 10**12)})
np.save(w + "/ZD/w.npy", np.ones(6))
np.save(w + "/ZP/w.npy", np.ones(5))
PY
for z in "Z0 5" "ZH 1000000000000"; do
  set -- $z
  "$N" eval "$W/sqrt.npg" --full "$W/$1" "$W/$1" -o "$W/ZO$1" >/dev/null || fail "eval --full of no samples ($1)"
  /usr/bin/python3 -c "import numpy as np, sys; a = np.load(sys.argv[1]); assert a.shape == (0, $2) and a.dtype == np.float64, a.shape" \
    "$W/ZO$1/y.npy" || fail "eval --full of no samples ($1): the output's shape"
  for cmd in "eval $W/sqrt.npg $W/M $W/$1 -o $W/ZO" "verify $W/sqrt.npg $W/M $W/$1" "train $W/sqrt.npg $W/$1 -o $W/ZM"; do
    if "$N" $cmd >/dev/null 2>"$W/err.txt"; then fail "npgc $cmd accepted no samples"; fi
    grep -qF "error: $W/$1: no samples (the first axis of its inputs is 0)" "$W/err.txt" || fail "npgc $cmd: $(cat "$W/err.txt")"
    test ! -e "$W/ZO" && test ! -e "$W/ZM" || fail "npgc $cmd wrote an output"
  done
done
cat >"$W/wx.npg" <<'NPG'
dim N
param w : real[N]
input x : real[N]
output y[i:N] = w[i] * x[i]
NPG
"$N" eval "$W/wx.npg" --full "$W/ZP" "$W/ZP" -o "$W/ZOP" >/dev/null || fail "eval --full of no samples with a param"
if "$N" eval "$W/wx.npg" --full "$W/ZD" "$W/ZD" -o "$W/ZOD" 2>"$W/err.txt"; then fail "no samples of another dim"; fi
grep -qF "error: dim N is 6 in $W/ZD/w.npy but 5 in $W/ZD/x.npy" "$W/err.txt" || fail "no samples, dims: $(cat "$W/err.txt")"
cat >"$W/opout.npg" <<'NPG'
dim N
input x : real[N]
output op M[i:N, j:N] = delta(i, j) * x[i]
output y = M * x
NPG
if "$N" eval "$W/opout.npg" --full "$W/Z0" "$W/Z0" -o "$W/ZOO" 2>"$W/err.txt"; then fail "an op output of no samples"; fi
grep -qF "error: $W/Z0: no samples, and output op 'M' takes its sparsity structure from one" "$W/err.txt" ||
  fail "no samples, op: $(cat "$W/err.txt")"
test ! -e "$W/ZOO" || fail "an op output of no samples wrote files"

echo "messages: ok"
