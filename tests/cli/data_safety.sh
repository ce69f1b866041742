#!/bin/sh
# data_safety.sh BUILD_DIR — no lost or corrupted data and no silent wrong
# answer (issue 24), by root cause: (1) every path npgc writes (-o, --png,
# --spectra) is refused when it is an input, lies in a folder the command
# reads, or is a symbolic link, FIFO or device node, and a PNG is written
# whole or not at all; (2) only a model store's marked leftovers are removed
# or moved in; (3) a long dim name round-trips; (5) reduced eval and bench
# check input shapes, data at 1e-200 and 1e200 train and verify as at 1;
# (6) verify refuses training options, concurrent trainings and a model
# replaced while loading are handled; (4) a report lost on stdout fails.
# The MPI part of (5) is in tests/mpi/mpi.sh (e).
set -eu
B=$1
W=$(mktemp -d /tmp/npg_safe_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
N=$B/npgc

cat >"$W/p.npg" <<'NPG'
dim N
input x : real[N]
output y[i:N] = x[i] * x[i] + x[i]
NPG
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(4)
os.makedirs(w + "/TR"); os.makedirs(w + "/TE")
np.save(w + "/TR/x.npy", 1 + rng.random((30, 6)))
np.save(w + "/TE/x.npy", 1 + rng.random((5, 6)))
PY
"$N" train "$W/p.npg" "$W/TR" -o "$W/M" --cap 6 >/dev/null || fail "train"
"$N" train "$W/p.npg" "$W/TR" -o "$W/M1" --cap 6 >/dev/null || fail "train M1"
snapshot() { (cd "$1" && sha256sum -- * | sort) ; }
snapshot "$W/M" >"$W/M.sum"
snapshot "$W/M1" >"$W/M1.sum"
cp "$W/p.npg" "$W/p.keep"
intact() {
  snapshot "$W/M" | cmp -s - "$W/M.sum" || fail "$1: the model M changed"
  snapshot "$W/M1" | cmp -s - "$W/M1.sum" || fail "$1: the model M1 changed"
  cmp -s "$W/p.npg" "$W/p.keep" || fail "$1: the program changed"
  "$N" verify "$W/p.npg" "$W/M" "$W/TE" >/dev/null || fail "$1: M no longer verifies"
}
# refused: $1 what, $2 message, then the command
refused() {
  what=$1 msg=$2
  shift 2
  if "$N" "$@" >/dev/null 2>"$W/err.txt"; then fail "$what accepted"; fi
  grep -q -- "$msg" "$W/err.txt" || fail "$what: $(cat "$W/err.txt")"
  intact "$what"
}

# 1. outputs that are inputs, or lie in a folder the command reads
refused "eval -o MODEL/" "would overwrite an input of the command" eval "$W/p.npg" "$W/M" "$W/TE" -o "$W/M"
refused "eval -o MODEL/sub" "lies in a folder the command reads" eval "$W/p.npg" "$W/M" "$W/TE" -o "$W/M/out"
refused "eval -o another model" "holds a model" eval "$W/p.npg" "$W/M" "$W/TE" -o "$W/M1"
refused "eval --full -o IN/" "would overwrite an input" eval "$W/p.npg" --full "$W/TR" "$W/TE" -o "$W/TE"
refused "plot -o M/manifest" "would overwrite an input" plot "$W/M" -o "$W/M/manifest"
refused "plot -o M/new.png" "lies in a folder the command reads" plot "$W/M" -o "$W/M/new.png"
refused "tune --png DATA/x.npy" "would overwrite an input" tune "$W/p.npg" "$W/TR" "$W/TE" --tol 1e-2 -o "$W/T" --png "$W/TR/x.npy"
test -s "$W/TR/x.npy" && /usr/bin/python3 -c "import numpy,sys; numpy.load(sys.argv[1])" "$W/TR/x.npy" || fail "x.npy damaged"
refused "tune --png prog.npg" "would overwrite an input" tune "$W/p.npg" "$W/TR" "$W/TE" --tol 1e-2 -o "$W/T" --png "$W/p.npg"
test ! -e "$W/T" || fail "a refused tune wrote its model"
refused "train --spectra M1" "holds a model" train "$W/p.npg" "$W/TR" -o "$W/M2" --spectra "$W/M1"
test ! -e "$W/M2" || fail "a refused train wrote its model"
refused "train --spectra = -o" "would overwrite an input" train "$W/p.npg" "$W/TR" -o "$W/M" --spectra "$W/M"
refused "emit into a model" "would overwrite an input" emit "$W/p.npg" --reduced "$W/M" -o "$W/M/p.c"

# 1. symbolic links, FIFOs and device nodes are never replaced
echo keep >"$W/target"
ln -s "$W/target" "$W/link.png"
refused "plot -o a symlink" "is a symbolic link" plot "$W/M" -o "$W/link.png"
test -L "$W/link.png" && test "$(cat "$W/target")" = keep || fail "the link or its target changed"
mkfifo "$W/fifo.c"
refused "emit -o a FIFO" "not a regular file" emit "$W/p.npg" -o "$W/fifo.c"
test -p "$W/fifo.c" || fail "the FIFO was replaced"
# a device node of our own (a broken npgc must not replace the machine's /dev/null)
if mknod "$W/null" c 1 3 2>/dev/null; then
  refused "emit -o a device node" "not a regular file" emit "$W/p.npg" -o "$W/null"
  test -c "$W/null" || fail "the device node was replaced"
fi
refused "tune --png a symlink" "is a symbolic link" tune "$W/p.npg" "$W/TR" "$W/TE" --tol 1e-2 -o "$W/T" --png "$W/link.png"
ln -s "$W/OUTREAL" "$W/OUTLINK"
refused "eval -o a symlinked folder" "is a symbolic link" eval "$W/p.npg" "$W/M" "$W/TE" -o "$W/OUTLINK"
# a file in OUT/ that is a link is not replaced either (the library's npy writer)
mkdir "$W/O"
ln -s "$W/target" "$W/O/y.npy"
refused "eval over a link in OUT/" "is not a regular file (a symbolic link)" eval "$W/p.npg" "$W/M" "$W/TE" -o "$W/O"
test "$(cat "$W/target")" = keep || fail "the link's target changed"

# 1. plot and tune write to a temporary name and rename: a full disk leaves no file
"$N" plot "$W/M" -o "$W/ok.png" >/dev/null || fail "plot"
test -s "$W/ok.png" || fail "plot wrote nothing"
ls "$W" | grep -q '\.tmp\.' && fail "a temporary file was left: $(ls "$W")"
if [ "$(id -u)" = 0 ] && command -v mount >/dev/null && mkdir "$W/tiny" && mount -t tmpfs -o size=12k tmpfs "$W/tiny" 2>/dev/null; then
  dd if=/dev/zero of="$W/tiny/fill" bs=1k count=64 2>/dev/null || true
  if "$N" plot "$W/M" -o "$W/tiny/full.png" >/dev/null 2>"$W/err.txt"; then umount "$W/tiny"; fail "plot onto a full disk"; fi
  left=$(ls "$W/tiny" | grep -v '^fill$' || true)
  umount "$W/tiny"
  test -z "$left" || fail "plot onto a full disk left: $left"
fi

# 3. long names (a 4 KB buffer cut the manifest's dims line, and training exited 0 with a model that
# could not load): names are at most 128 characters, refused past that at compile time; names of 128
# characters save and load
LONG=$(/usr/bin/python3 -c "print('D' * 5000)")
printf 'dim %s\ninput x : real[%s]\noutput y[i:%s] = x[i] * x[i]\n' "$LONG" "$LONG" "$LONG" >"$W/long.npg"
if "$N" train "$W/long.npg" "$W/TR" -o "$W/LM" --cap 6 >/dev/null 2>"$W/err.txt"; then fail "a 5,000-character name was accepted"; fi
grep -q "is 5000 characters long (at most 128)" "$W/err.txt" || fail "long name: $(cut -c1-300 "$W/err.txt")"
D=$(/usr/bin/python3 -c "print('D' * 128)")
Y=$(/usr/bin/python3 -c "print('y' * 128)")
printf 'dim %s\ninput x : real[%s]\noutput %s[i:%s] = x[i] * x[i]\n' "$D" "$D" "$Y" "$D" >"$W/long.npg"
"$N" train "$W/long.npg" "$W/TR" -o "$W/LM" --cap 6 >/dev/null 2>"$W/err.txt" || fail "train with 128-character names: $(cut -c1-300 "$W/err.txt")"
"$N" verify "$W/long.npg" "$W/LM" "$W/TE" >/dev/null 2>"$W/err.txt" || fail "the long-named model does not load: $(cut -c1-300 "$W/err.txt")"

# 2. training and eval move or remove only folders a model store marked as its own leftovers: folders
# that merely look like them (a user's copies of a model, named like a dead training's) are left alone
DEAD=$(sh -c 'echo $$')
cp -r "$W/M1" "$W/M.old.$DEAD"
cp -r "$W/M1" "$W/M.tmp.$DEAD"
cp -r "$W/M1" "$W/M.old.2024"
"$N" train "$W/p.npg" "$W/TR" -o "$W/M" --cap 6 >/dev/null 2>"$W/err.txt" || fail "retrain M: $(cat "$W/err.txt")"
for d in "M.old.$DEAD" "M.tmp.$DEAD" "M.old.2024"; do
  test -d "$W/$d" && snapshot "$W/$d" | cmp -s - "$W/M1.sum" || fail "training removed or changed the user's $d"
done
cp -r "$W/M1" "$W/G.old.$DEAD"
if "$N" eval "$W/p.npg" "$W/G" "$W/TE" -o "$W/GO" >/dev/null 2>"$W/err.txt"; then fail "eval of a missing model"; fi
test ! -e "$W/G" && test -d "$W/G.old.$DEAD" || fail "eval of a missing G moved the user's G.old.$DEAD into it"
grep -q "G/manifest: cannot open" "$W/err.txt" || fail "missing model message: $(cat "$W/err.txt")"
# a real leftover (marked) of a killed training is still recovered and removed (tests/cli/interrupt.sh kills one)

# 5. reduced eval and bench refuse an input of another shape with the same entry count
printf 'dim A, B\ninput x : real[A, B]\noutput y[a:A, b:B] = x[a, b] * x[a, b]\n' >"$W/ab.npg"
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(5)
for d, shape in (("ABTR", (20, 5, 3)), ("AB35", (4, 3, 5)), ("AB151", (4, 15, 1))):
    os.makedirs(w + "/" + d); np.save(w + "/" + d + "/x.npy", 1 + rng.random(shape))
PY
"$N" train "$W/ab.npg" "$W/ABTR" -o "$W/ABM" >/dev/null || fail "train ab"
for d in AB35:3,\ 5 AB151:15,\ 1; do
  dir=${d%%:*} found=${d#*:}
  if "$N" eval "$W/ab.npg" "$W/ABM" "$W/$dir" -o "$W/ABO" >/dev/null 2>"$W/err.txt"; then fail "eval of x as (S, $found)"; fi
  grep -q "$dir/x.npy: input 'x' has shape (S, $found), the model was trained on (S, 5, 3)" "$W/err.txt" ||
    fail "eval shape message: $(cat "$W/err.txt")"
  if "$N" bench "$W/ab.npg" "$W/ABM" "$W/$dir" --reps 1 >/dev/null 2>"$W/err.txt"; then fail "bench of x as (S, $found)"; fi
  grep -q "input 'x' has shape (S, $found), the model was trained on (S, 5, 3)" "$W/err.txt" ||
    fail "bench shape message: $(cat "$W/err.txt")"
done
test ! -e "$W/ABO" || fail "a refused eval wrote outputs"

# 5. data at extreme scale: the PCA keeps what it keeps at scale 1 and verify reports the same relative
# errors (squares of 1e-200 underflow to 0, of 1e200 overflow: the truncation saw no energy, verify
# printed 0 or -nan); the Gram routes, which cannot scale, refuse such data with a message
printf 'dim N\ninput x : real[N]\noutput y[i:N] = 2 * x[i] + x[0]\n' >"$W/lin.npg"
/usr/bin/python3 - "$W" <<'PY'
import sys, os, numpy as np
w = sys.argv[1]; rng = np.random.default_rng(6)
P = rng.random((5, 100)); tr = rng.random((60, 5)) @ P + 1; te = rng.random((6, 5)) @ P + 1
te[:, :50] += 0.3 * rng.random((6, 50))  # off the training span: a cap-2 model is far off
for sc in ("1", "1e-200", "1e200"):
    for d, x in (("STR", tr), ("STE", te)):
        os.makedirs(f"{w}/{d}{sc}"); np.save(f"{w}/{d}{sc}/x.npy", float(sc) * x)
PY
for sc in 1 1e-200 1e200; do
  "$N" train "$W/lin.npg" "$W/STR$sc" -o "$W/SM$sc" >"$W/train$sc.txt" 2>&1 || fail "train at scale $sc: $(cat "$W/train$sc.txt")"
  grep "^{x}" "$W/train$sc.txt" | sed 's/lost .*//' >"$W/kept$sc.txt"
  "$N" train "$W/lin.npg" "$W/STR$sc" -o "$W/SC$sc" --cap 2 >/dev/null 2>&1 || fail "train --cap 2 at scale $sc"
  if "$N" verify "$W/lin.npg" "$W/SC$sc" "$W/STE$sc" >"$W/verify$sc.txt" 2>&1; then fail "verify passed a cap-2 model at scale $sc"; fi
  grep "^FAIL: output y" "$W/verify$sc.txt" >/dev/null || fail "verify at scale $sc: $(cat "$W/verify$sc.txt")"
  awk '$1 == "y" {print $4, $5, $8}' "$W/verify$sc.txt" >"$W/err$sc.txt"
done
for sc in 1e-200 1e200; do
  cmp -s "$W/kept1.txt" "$W/kept$sc.txt" || fail "scale $sc keeps $(cat "$W/kept$sc.txt"), scale 1 $(cat "$W/kept1.txt")"
  /usr/bin/python3 - "$W/err1.txt" "$W/err$sc.txt" <<'PY' || fail "verify's errors at scale $sc differ from scale 1: $(cat "$W/err$sc.txt") vs $(cat "$W/err1.txt")"
import sys, math
a, b = (list(map(float, open(f).read().split())) for f in sys.argv[1:])
sys.exit(0 if len(a) == len(b) == 3 and a[0] > 0.01 and all(math.isclose(x, y, rel_tol=1e-6) for x, y in zip(a, b)) else 1)
PY
done
for sc in 1e-200 1e200; do
  if "$N" train "$W/lin.npg" "$W/STR$sc" -o "$W/SG$sc" --mem 100k >/dev/null 2>"$W/err.txt"; then fail "the Gram route trained scale $sc"; fi
  grep -q "member x: snapshot values .* whose squares .*flow" "$W/err.txt" || fail "Gram route at scale $sc: $(cat "$W/err.txt")"
done

# 6. verify, eval and bench refuse the options of training, naming them, rather than ignoring them
for opt in "--cap 2" "--energy 0.5" "--center off" "--basis x:cap=1" "--merge joint" "--mem 1G" "--spectra $W/SP"; do
  if "$N" verify "$W/p.npg" "$W/M" "$W/TE" $opt >/dev/null 2>"$W/err.txt"; then fail "verify accepted $opt"; fi
  grep -q "npgc verify: ${opt%% *} is an option of npgc train" "$W/err.txt" || fail "verify $opt: $(cat "$W/err.txt")"
done
if "$N" eval "$W/p.npg" "$W/M" "$W/TE" -o "$W/EO" --cap 2 2>"$W/err.txt"; then fail "eval accepted --cap"; fi
if "$N" bench "$W/p.npg" "$W/M" "$W/TE" --energy 0.5 >/dev/null 2>"$W/err.txt"; then fail "bench accepted --energy"; fi
test ! -e "$W/SP" && test ! -e "$W/EO" || fail "a refused command wrote"

# 6. races: two trainings of one new model at once both succeed (the second said "Directory not
# empty"), and a model replaced while it is being loaded is read again (it said "checksum mismatch")
for round in 1 2 3; do
  rm -rf "$W/CM"
  "$N" train "$W/p.npg" "$W/TR" -o "$W/CM" >/dev/null 2>"$W/err1.txt" &
  pid=$!
  "$N" train "$W/p.npg" "$W/TR" -o "$W/CM" >/dev/null 2>"$W/err2.txt" || fail "concurrent training: $(cat "$W/err2.txt")"
  wait $pid || fail "concurrent training: $(cat "$W/err1.txt")"
  "$N" verify "$W/p.npg" "$W/CM" "$W/TE" >/dev/null || fail "the model of concurrent trainings does not verify"
  test -z "$(ls -d "$W"/CM.* 2>/dev/null)" || fail "concurrent trainings left $(ls -d "$W"/CM.*)"
done
"$N" train "$W/p.npg" "$W/TR" -o "$W/RA" --cap 3 >/dev/null || fail "train RA"
"$N" train "$W/p.npg" "$W/TR" -o "$W/RB" --cap 5 >/dev/null || fail "train RB"
NPG_TEST_REPLACE_DURING_LOAD="$W/RB" "$N" verify "$W/p.npg" "$W/RA" "$W/TE" --tol 1 >"$W/out.txt" 2>"$W/err.txt" ||
  fail "a model replaced while loading: $(cat "$W/err.txt")"
grep -q "^x  *input  *5 " "$W/out.txt" || fail "the replaced model was not the one read: $(cat "$W/out.txt")"

# 4. a report that cannot be written to stdout fails the command, saying so
if [ -w /dev/full ]; then
  for cmd in "check $W/p.npg --json" "check $W/p.npg" "verify $W/p.npg $W/M $W/TE" "bench $W/p.npg $W/M $W/TE --reps 1" \
             "train $W/p.npg $W/TR -o $W/MF" "plot $W/M -o $W/full.png" "--help" "train --help"; do
    if "$N" $cmd >/dev/full 2>"$W/err.txt"; then fail "npgc $cmd >/dev/full exited 0"; fi
    grep -q "cannot write to standard output: No space left on device" "$W/err.txt" || fail "npgc $cmd >/dev/full: $(cat "$W/err.txt")"
  done
fi
echo "ok"
