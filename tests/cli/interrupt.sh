#!/bin/sh
# interrupt.sh BUILD_DIR — a training killed at any point of writing its
# model leaves the old model or the new one, complete, and no litter after
# the next run (NPG_TEST_INTERRUPT, backends/model/model_store.c).
set -u
B=$1
W=$(mktemp -d /tmp/npg_kill_XXXXXX)
trap 'rm -rf "$W"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
P=examples/rational/rational.npg
"$B/rational_data" "$W/TRAIN" 100 1 >/dev/null || fail "data"
"$B/rational_data" "$W/TEST" 20 2 >/dev/null || fail "data"
# A: cap 1 (verify --tol 1e-10 fails); B: full rank (it passes)
old() { "$B/npgc" train $P "$W/TRAIN" -o "$W/M" --cap 1 >/dev/null || fail "train A"; }
is_old() { ! "$B/npgc" verify $P "$W/M" "$W/TEST" --tol 1e-10 >/dev/null 2>&1 && "$B/npgc" verify $P "$W/M" "$W/TEST" --tol 1 >/dev/null 2>&1; }
is_new() { "$B/npgc" verify $P "$W/M" "$W/TEST" --tol 1e-10 >/dev/null 2>"$W/recover.txt"; }
litter() { ls "$W" | grep -E '^M\.(tmp|old)\.' || true; }

for point in arrays manifest swap cleanup; do
  old
  if [ $point = swap ]; then export NPG_TEST_NO_EXCHANGE=1; fi
  NPG_TEST_INTERRUPT=$point "$B/npgc" train $P "$W/TRAIN" -o "$W/M" >/dev/null 2>&1
  status=$?
  unset NPG_TEST_NO_EXCHANGE
  [ $status -eq 137 ] || fail "$point: the training was not killed (status $status)"
  case $point in
    arrays|manifest) is_old || fail "$point: the previous model is not whole" ;;
    swap) test ! -e "$W/M" || fail "swap: the test did not stop between the renames"
          is_new || fail "swap: the complete new model was not recovered"
          grep -q "moved in the new (complete) model" "$W/recover.txt" || fail "swap: recovery not said: $(cat "$W/recover.txt")" ;;
    cleanup) is_new || fail "cleanup: the new model is not whole" ;;
  esac
  "$B/npgc" train $P "$W/TRAIN" -o "$W/M" >/dev/null || fail "$point: the next training failed"
  [ -z "$(litter)" ] || fail "$point: litter after the next run: $(litter)"
done

# SIGTERM and SIGINT while writing: the temporary folder is removed before the process dies
for sig in TERM INT; do
  old
  NPG_TEST_INTERRUPT=arrays:$sig "$B/npgc" train $P "$W/TRAIN" -o "$W/M" >/dev/null 2>&1
  [ -z "$(litter)" ] || fail "SIG$sig left $(litter)"
  is_old || fail "SIG$sig: the previous model is not whole"
done

# a .npy the user put in a model folder is not deleted by retraining
old
cp "$W/TEST/x.npy" "$W/M/mine.npy"
if "$B/npgc" train $P "$W/TRAIN" -o "$W/M" >/dev/null 2>"$W/err.txt"; then fail "retrain over a user's file"; fi
grep -q "holds 'mine.npy', which its manifest does not list" "$W/err.txt" || fail "unlisted message: $(cat "$W/err.txt")"
test -e "$W/M/mine.npy" || fail "the user's file was removed"
# out of core (--mem far below one basis: the bases live in unnamed files,
# memory-mapped, and are written from the mapping): killed while writing,
# it leaves no model; run again, it gives a model that loads, and no litter
R=examples/radiosity/formfactors.npg
"$B/radiosity_data" "$W/RDATA" 48 16 0 1 3 >/dev/null || fail "radiosity data"
NPG_TEST_INTERRUPT=arrays "$B/npgc" train $R "$W/RDATA" -o "$W/OOC" --cap 8 --mem 160k >/dev/null 2>&1
status=$?
[ $status -eq 137 ] || fail "out of core: the training was not killed (status $status)"
test ! -e "$W/OOC" || fail "out of core: a killed training left a model"
"$B/npgc" train $R "$W/RDATA" -o "$W/OOC" --cap 8 --mem 160k >/dev/null 2>"$W/err.txt" || fail "out of core: $(cat "$W/err.txt")"
[ -z "$(ls "$W" | grep -E '^OOC\.' || true)" ] || fail "out of core: litter after the next run: $(ls "$W")"
"$B/npgc" verify $R "$W/OOC" "$W/RDATA" --tol 0.05 >/dev/null 2>&1 || fail "out of core: the model does not verify"
echo "ok"
