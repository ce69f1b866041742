#!/bin/sh
# reduce.sh BUILD_DIR — the reduction commands end to end, as a user runs
# them: train, verify (pass and fail by --tol; --exact, the exactness checks),
# reduced eval checked against numpy's evaluation of the paper's Eq. 3 (an
# independent oracle), a corrupted model and foreign params refused naming
# the file, radiosity trained and verified on the deforming room.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_cli_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

P=examples/rational/rational.npg
"$B/rational_data" "$W/TRAIN" 200 1 >/dev/null
"$B/rational_data" "$W/TEST" 50 2 >/dev/null
"$B/npgc" train $P "$W/TRAIN" -o "$W/MODEL" >/dev/null || fail "train"
"$B/npgc" verify $P "$W/MODEL" "$W/TEST" --tol 1e-10 >"$W/verify.txt" || fail "verify at full rank"
grep -q '^y  *inverse' "$W/verify.txt" || fail "verify report lacks stage y"
# the exactness checks of DESIGN §4, alone and after the report
"$B/npgc" verify $P --exact >"$W/exact.txt" || fail "verify --exact"
grep -q '^  1. lowering' "$W/exact.txt" && grep -q '^  2. full rank' "$W/exact.txt" || fail "verify --exact report: $(cat "$W/exact.txt")"
grep -q '^ok: the lowering is exact' "$W/exact.txt" || fail "verify --exact verdict"
"$B/npgc" verify $P "$W/MODEL" "$W/TEST" --tol 1e-10 --exact-size 5 >"$W/both.txt" || fail "verify with --exact-size"
grep -q '^y  *inverse' "$W/both.txt" && grep -q 'every dim 5' "$W/both.txt" || fail "verify report and checks: $(cat "$W/both.txt")"
if "$B/npgc" verify $P --exact-size 0 2>/dev/null; then fail "--exact-size 0 accepted"; fi
if "$B/npgc" verify $P 2>/dev/null; then fail "verify without a model or --exact accepted"; fi
# a training sample that makes y undefined (x0 = 0) is named, no model is left
cp -r "$W/TRAIN" "$W/ZERO"
/usr/bin/python3 -c "import numpy as np,sys; x=np.load(sys.argv[1]); x[3,0]=0; np.save(sys.argv[1], x)" "$W/ZERO/x.npy"
if "$B/npgc" train $P "$W/ZERO" -o "$W/ZMODEL" 2>"$W/err.txt" >/dev/null; then fail "a division by zero trained"; fi
grep -q "training sample 3: y is not finite (y\[0\] is inf)" "$W/err.txt" || fail "non-finite message: $(cat "$W/err.txt")"
test ! -e "$W/ZMODEL" || fail "a failed training left a model"
# cap 1: y is not representable; verify must exit 1 above --tol
"$B/npgc" train $P "$W/TRAIN" -o "$W/SMALL" --cap 1 >/dev/null || fail "train --cap 1"
if "$B/npgc" verify $P "$W/SMALL" "$W/TEST" --tol 1e-3 >/dev/null; then fail "verify passed a cap-1 model"; fi
# --weights FILE.npy: sample k counted w_k times — the model of DATA/ with weights is the model of
# DATA/ with those samples repeated (cap 1: the weighted mean alone, which the weights move)
/usr/bin/python3 - "$W" <<'PY' || fail "writing the weighted data"
import sys, os, numpy as np
w = sys.argv[1]
x = np.load(w + "/TRAIN/x.npy")
wt = np.where(np.arange(len(x)) % 5 == 0, 3.0, 1.0)
np.save(w + "/weights.npy", wt)
os.mkdir(w + "/DUP")
np.save(w + "/DUP/x.npy", np.repeat(x, wt.astype(int), axis=0))
np.save(w + "/short.npy", wt[:-1])
np.save(w + "/neg.npy", np.where(np.arange(len(x)) == 7, -1.0, wt))
PY
"$B/npgc" train $P "$W/TRAIN" -o "$W/WMODEL" --cap 1 --weights "$W/weights.npy" >/dev/null || fail "train --weights"
"$B/npgc" train $P "$W/DUP" -o "$W/DMODEL" --cap 1 >/dev/null || fail "train the repeated samples"
for M in WMODEL DMODEL SMALL; do "$B/npgc" eval $P "$W/$M" "$W/TEST" -o "$W/OUT_$M" >/dev/null || fail "eval $M"; done
/usr/bin/python3 - "$W" <<'PY' || fail "--weights is not the repeated samples"
import sys, numpy as np
w = sys.argv[1]
a, b, c = (np.load(w + "/OUT_%s/y.npy" % m) for m in ("WMODEL", "DMODEL", "SMALL"))
same, moved = np.max(np.abs(a - b)) / np.max(np.abs(b)), np.max(np.abs(a - c)) / np.max(np.abs(c))
print("--weights against repeated samples %.2e, against no weights %.2e" % (same, moved))
assert same < 1e-10 and moved > 1e-6
PY
if "$B/npgc" train $P "$W/TRAIN" -o "$W/X1" --weights "$W/short.npy" 2>"$W/err.txt" >/dev/null; then fail "short --weights accepted"; fi
grep -q "error: --weights $W/short.npy: a vector of 199 entries, DATA/ has 200 samples" "$W/err.txt" || fail "short weights: $(cat "$W/err.txt")"
if "$B/npgc" train $P "$W/TRAIN" -o "$W/X1" --weights "$W/neg.npy" 2>"$W/err.txt" >/dev/null; then fail "negative --weights accepted"; fi
grep -q "error: --weights $W/neg.npy: npg_trainer_weight: the weight of training sample 7 is -1: weights must be positive and finite" "$W/err.txt" || fail "negative weight: $(cat "$W/err.txt")"
if "$B/npgc" train $P "$W/TRAIN" -o "$W/X1" --weights "$W/none.npy" 2>"$W/err.txt" >/dev/null; then fail "missing --weights accepted"; fi
grep -q "error: --weights $W/none.npy" "$W/err.txt" || fail "missing weights file: $(cat "$W/err.txt")"
if "$B/npgc" train $P "$W/TRAIN" -o "$W/X1" --weights "$W/weights.npy" --merge joint 2>"$W/err.txt" >/dev/null; then
  fail "--weights with --merge joint accepted"
fi
grep -q "sample weights are not implemented with --merge joint" "$W/err.txt" || fail "joint weights: $(cat "$W/err.txt")"
if "$B/npgc" eval $P "$W/MODEL" "$W/TEST" -o "$W/X2" --weights "$W/weights.npy" 2>"$W/err.txt"; then fail "eval --weights accepted"; fi
test ! -e "$W/X1" || fail "a refused training left a model"
# reduced eval = Eq. 3 computed by numpy
"$B/npgc" eval $P "$W/MODEL" "$W/TEST" -o "$W/OUT" || fail "reduced eval"
/usr/bin/python3 - "$W" <<'PY' || fail "reduced eval differs from numpy"
import sys, numpy as np
w = sys.argv[1]
x = np.load(w + "/TEST/x.npy"); y = np.load(w + "/OUT/y.npy")
ref = np.stack([(x[:,0]*x[:,1] + x[:,1]**2) / x[:,0]**2, x[:,0]**2 / x[:,1]**2], axis=1)
assert y.shape == ref.shape, (y.shape, ref.shape)
err = np.max(np.abs(y - ref)) / np.max(np.abs(ref))
print("reduced eval vs numpy: %.2e" % err)
assert err < 1e-12
assert np.load(w + "/OUT/y.reduced.npy").shape == (50, 2)
PY
# a corrupted model is named
printf 'X' | dd of="$W/MODEL/basis_1.npy" bs=1 seek=100 conv=notrunc 2>/dev/null
if "$B/npgc" verify $P "$W/MODEL" "$W/TEST" 2>"$W/err.txt"; then fail "corrupted model accepted"; fi
grep -q "MODEL/basis_1.npy: checksum mismatch" "$W/err.txt" || fail "corruption message: $(cat "$W/err.txt")"

# radiosity: train on 30 deformations, verify on 6 held out
R=examples/radiosity/formfactors.npg
"$B/radiosity_data" "$W/RTRAIN" 96 30 0 1 1 || fail "radiosity data"
"$B/radiosity_data" "$W/RTEST" 96 6 0.05 0.95 2 || fail "radiosity data"
cp "$W/RTRAIN/tri.npy" "$W/RTRAIN/rho.npy" "$W/RTEST/"
"$B/npgc" train $R "$W/RTRAIN" -o "$W/RMODEL" >/dev/null || fail "radiosity train"
"$B/npgc" verify $R "$W/RMODEL" "$W/RTEST" --tol 0.05 || fail "radiosity verify"
# params that differ from training are refused naming the file
"$B/radiosity_data" "$W/RHO" 96 2 0 1 3 >/dev/null
/usr/bin/python3 -c "import numpy as np,sys; r=np.load(sys.argv[1]); np.save(sys.argv[1], r*0.9)" "$W/RHO/rho.npy"
if "$B/npgc" verify $R "$W/RMODEL" "$W/RHO" 2>"$W/err.txt"; then fail "changed params accepted"; fi
grep -q "RHO/rho.npy: param 'rho' differs from the one the model was trained with" "$W/err.txt" || fail "param message: $(cat "$W/err.txt")"
# params equal in value but stored as int32 instead of int64 are the same params
/usr/bin/python3 -c "import numpy as np,sys; t=np.load(sys.argv[1]); np.save(sys.argv[1], t.astype(np.int32))" "$W/RTEST/tri.npy"
"$B/npgc" verify $R "$W/RMODEL" "$W/RTEST" --tol 0.05 >/dev/null || fail "int32 copy of the params refused"

# output operators: eval --full writes CSR triplets, reduced eval the reduced matrices
O=tests/programs/output_op.npg
mkdir -p "$W/ODATA"
/usr/bin/python3 - "$W/ODATA" <<'PY'
import sys, numpy as np
d = sys.argv[1]; rng = np.random.default_rng(5)
np.save(d + "/a.npy", rng.standard_normal((6, 6)))
np.save(d + "/w.npy", 1 + 0.3 * rng.standard_normal((12, 6)))
np.save(d + "/x.npy", rng.standard_normal((12, 6)))
PY
"$B/npgc" eval $O --full "$W/ODATA" "$W/ODATA" -o "$W/OFULL" 2>"$W/err.txt" || fail "eval --full of an output op: $(cat "$W/err.txt")"
"$B/npgc" train $O "$W/ODATA" -o "$W/OMODEL" --cap 3 >/dev/null || fail "train output_op"
"$B/npgc" eval $O "$W/OMODEL" "$W/ODATA" -o "$W/ORED" 2>"$W/err.txt" || fail "reduced eval of an output op: $(cat "$W/err.txt")"
/usr/bin/python3 - "$W" <<'PY' || fail "output op files"
import sys, numpy as np
w = sys.argv[1]
a = np.load(w + "/ODATA/a.npy"); ws = np.load(w + "/ODATA/w.npy")
ip = np.load(w + "/OFULL/K.indptr.npy"); ix = np.load(w + "/OFULL/K.indices.npy"); data = np.load(w + "/OFULL/K.data.npy")
assert ip.dtype == np.int64 and ix.dtype == np.int64 and data.shape == (12, ix.size), (ip.dtype, data.shape)
for k in range(12):
    K = np.zeros((6, 6))
    for r in range(6):
        K[r, ix[ip[r]:ip[r+1]]] = data[k, ip[r]:ip[r+1]]
    assert np.allclose(K, a * ws[k][None, :], rtol=0, atol=1e-15), k
red = np.load(w + "/ORED/K.reduced.npy")
assert red.ndim == 3 and red.shape[0] == 12 and red.shape[1] == red.shape[2] and red.shape[1] <= 6, red.shape
assert np.all(np.isfinite(red))
PY
echo "ok"
