#!/bin/sh
# jit_cache.sh BUILD_DIR — the cache of cc-compiled evaluators under concurrent processes
# (issue 42): two npgc started at once on an empty cache folder, compiling the same program,
# both succeed with the same results as libtcc's evaluator; the folder then holds one complete
# entry and no temporary file, and a third process loads it. The cache folder is this test's.
set -eu
B=$1
W=$(mktemp -d /tmp/npg_jit_cache_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
unset NPG_JIT NPG_CACHE_MAX
P=examples/radiosity/formfactors.npg
"$B/radiosity_data" "$W/DATA" 96 4 0 1 1 >/dev/null || fail "radiosity_data"
NPG_CACHE_DIR="$W/unused" "$B/npgc" eval $P --full "$W/DATA" "$W/DATA" -o "$W/TCC" --jit tcc >/dev/null || fail "eval --jit tcc"
test ! -e "$W/unused" || fail "libtcc touched the cache folder"

export NPG_CACHE_DIR="$W/cache"
for k in 1 2; do
  "$B/npgc" eval $P --full "$W/DATA" "$W/DATA" -o "$W/CC$k" --jit cc >"$W/out$k.txt" 2>&1 &
  eval "pid$k=\$!"
done
wait "$pid1" || fail "the first of two concurrent processes: $(cat "$W/out1.txt")"
wait "$pid2" || fail "the second of two concurrent processes: $(cat "$W/out2.txt")"
n=$(ls "$W/cache" | grep -c '^[0-9a-f]\{64\}\.so$' || true)
[ "$n" = 1 ] || fail "the cache holds $n entries, not 1: $(ls "$W/cache")"
[ "$(ls "$W/cache" | grep -c tmp || true)" = 0 ] || fail "temporary files left: $(ls "$W/cache")"
/usr/bin/python3 - "$W" <<'PY' || fail "cc evaluators differ from libtcc's"
import sys, glob, os, numpy as np
w = sys.argv[1]
names = sorted(os.path.basename(f) for f in glob.glob(w + "/TCC/*.npy"))
assert names, "no outputs"
for n in names:
    t, a, b = (np.load(os.path.join(w, d, n)) for d in ("TCC", "CC1", "CC2"))
    assert np.array_equal(a, b), n + ": the two concurrent cc evaluators differ"
    assert np.allclose(a, t, rtol=1e-13, atol=0), n + ": cc and libtcc differ by %g" % np.max(np.abs(a - t))
print("two concurrent processes: one entry, %d outputs equal" % len(names))
PY
# a third process loads the entry (npgc bench says so)
"$B/npgc" train $P "$W/DATA" -o "$W/MODEL" --jit tcc --cap 2 >/dev/null || fail "train"
"$B/npgc" bench $P "$W/MODEL" "$W/DATA" --reps 1 >"$W/bench.txt" || fail "bench: $(cat "$W/bench.txt")"
grep -q "^full evaluator: cc (the system compiler at -O3 -march=native), loaded in [0-9.]* ms (loaded from the cache)" \
  "$W/bench.txt" || fail "bench did not load the cached evaluator: $(cat "$W/bench.txt")"
# the compiler's identity kept beside the entries (cc-*.id, saving a `cc --version` a process):
# damaged, it changes the key at worst, never the results
ls "$W/cache"/cc-*.id >/dev/null 2>&1 || fail "no compiler identity kept: $(ls "$W/cache")"
for f in "$W/cache"/cc-*.id; do printf 'garbage' >"$f"; done
"$B/npgc" eval $P --full "$W/DATA" "$W/DATA" -o "$W/CC3" --jit cc >/dev/null || fail "eval after a damaged identity"
for f in "$W"/CC1/*.npy; do cmp -s "$f" "$W/CC3/$(basename "$f")" || fail "$(basename "$f") differs after a damaged identity"; done
