#!/bin/sh
# jacobian.sh BUILD_DIR — npgc eval --full ... --jacobian OUT:IN and npgc emit --derivatives
# (DESIGN §17): the Jacobian of rational.npg's y by x at every sample, written as
# OUT/jacobian_y_x.npy (samples x 2 x 2), equals the analytic derivative; a bad spec, an
# unknown or non-input name are refused with a message naming the option; with a model, the
# reduced Jacobian in coordinates (at whole bases B_yᵀ J B_x); the derivatives' C has its two entry points, and is refused with --reduced.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_jacobian_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

P=examples/rational/rational.npg
"$B/rational_data" "$W/IN" 5 3 >/dev/null
"$B/npgc" eval $P --full "$W/IN" "$W/IN" -o "$W/OUT" --jacobian y:x || fail "eval --jacobian y:x"
/usr/bin/python3 - "$W" <<'PY' || fail "the Jacobian differs from the analytic one"
import sys, numpy as np
w = sys.argv[1]
x = np.load(w + "/IN/x.npy")
J = np.load(w + "/OUT/jacobian_y_x.npy")
assert J.shape == (5, 2, 2), J.shape
a, b = x[:, 0], x[:, 1]
# y0 = (a b + b^2) / a^2, y1 = a^2 / b^2
ref = np.stack([np.stack([-b / a**2 - 2 * b**2 / a**3, (a + 2 * b) / a**2], 1),
                np.stack([2 * a / b**2, -2 * a**2 / b**3], 1)], 1)
err = np.abs(J - ref).max() / np.abs(ref).max()
assert err < 1e-13, err
PY
for spec in y y:q z:x "y:"; do
  if "$B/npgc" eval $P --full "$W/IN" "$W/IN" -o "$W/BAD" --jacobian "$spec" 2>"$W/err.txt"; then
    fail "--jacobian $spec accepted"
  fi
  grep -q -- "--jacobian '$spec'" "$W/err.txt" || fail "--jacobian $spec: $(cat "$W/err.txt")"
done
grep -q "'y:': expected OUT:IN" "$W/err.txt" || fail "$(cat "$W/err.txt")"
"$B/npgc" eval $P --full "$W/IN" "$W/IN" -o "$W/BAD" --jacobian x:y 2>"$W/err.txt" && fail "x:y accepted"
grep -q "input 'y' is not an input of the program" "$W/err.txt" || fail "$(cat "$W/err.txt")"
test ! -e "$W/BAD" || fail "a refused evaluation wrote OUT/"
# with a model: the reduced Jacobian in coordinates; at whole bases (2 of 2) B_yᵀ J B_x
"$B/npgc" train $P "$W/IN" -o "$W/M" >/dev/null || fail "train"
"$B/npgc" eval $P "$W/M" "$W/IN" -o "$W/ROUT" --jacobian y:x >/dev/null || fail "eval MODEL/ --jacobian y:x"
/usr/bin/python3 - "$W" <<'PY' || fail "the reduced Jacobian differs from the full one at whole bases"
import sys, numpy as np
w = sys.argv[1]
J = np.load(w + "/OUT/jacobian_y_x.npy")
R = np.load(w + "/ROUT/jacobian_y_x.reduced.npy")
By, Bx = np.load(w + "/M/basis_1.npy"), np.load(w + "/M/basis_0.npy")
assert R.shape == (5, 2, 2) and By.shape == Bx.shape == (2, 2), (R.shape, By.shape, Bx.shape)
err = np.abs(R - np.einsum("ai,sab,bj->sij", By, J, Bx)).max() / np.abs(J).max()
assert err < 1e-10, err
PY
if "$B/npgc" eval $P "$W/M" "$W/IN" -o "$W/BAD" --jacobian y:y 2>"$W/err.txt"; then fail "y:y with a model"; fi
grep -q -- "--jacobian 'y:y': 'y' is not an input of the program" "$W/err.txt" || fail "$(cat "$W/err.txt")"
test ! -e "$W/BAD" || fail "a refused evaluation wrote OUT/"
# npgc emit --derivatives: the C of the forward and reverse products; not with --reduced
"$B/npgc" emit $P --derivatives -o "$W/d.c" || fail "emit --derivatives"
grep -q "^int rational_npg_full_jvp(const NpgCtx \*c, const NpgCtx \*d)" "$W/d.c" || fail "no jvp entry point"
grep -q "^int rational_npg_full_vjp(const NpgCtx \*c, const NpgCtx \*d)" "$W/d.c" || fail "no vjp entry point"
if "$B/npgc" emit $P --derivatives --reduced "$W" -o "$W/e.c" 2>"$W/err.txt"; then fail "--derivatives with --reduced"; fi
grep -q "does not go with --reduced" "$W/err.txt" || fail "$(cat "$W/err.txt")"
echo "ok: --jacobian y:x equals the analytic Jacobian at 5 samples, the reduced one B_yᵀ J B_x at whole bases; bad specs refused"
