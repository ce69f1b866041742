#!/bin/sh
# same_models.sh A/ B/ — "yes" when model folder B/ holds A/'s files byte for byte (the manifest's
# timing lines left out, as tests/train_identical.py does), else "no: FILE"; the greedy benches'
# comparison of two builds' models (greedy_evaluations.sh, greedy_routes.sh).
set -eu
T=$(mktemp -d "${TMPDIR:-/tmp}/npg_same_XXXXXX")
trap 'rm -rf "$T"' EXIT
same=yes
for f in "$1"/*; do
  g="$2/$(basename "$f")"
  if [ "$(basename "$f")" = manifest ]; then
    grep -v -E '^(seconds|timing|cpu)' "$f" >"$T/m1" || true
    grep -v -E '^(seconds|timing|cpu)' "$g" >"$T/m2" || true
    f="$T/m1" g="$T/m2"
  fi
  cmp -s "$f" "$g" || same="no: $(basename "$g")"
done
echo "$same"
