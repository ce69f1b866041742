#!/usr/bin/env bash
# test.sh — the one test command (README, .ci/run). Exits non-zero on any failure.
#
#   1. plain build (build/):          no layer includes a higher one; every ctest test (the Python
#                                     module's pytest suite among them: python_npg)
#   2. sanitizer build (build-asan/): every ctest test under ASan + UBSan, leaks fatal (python_npg:
#                                     ASan preloaded into the interpreter, leaks not checked there,
#                                     tests/CMakeLists.txt says why)
#   3. ThreadSanitizer (build-tsan/): the tests labelled `threads` (one model, many evaluators)
#   4. fuzz build (build-fuzz/):      libFuzzer on the front end for NPG_FUZZ_SECONDS (60), then on
#                                     the .npy reader, the model manifest and npg.h call sequences
#                                     for a third of that each
#
# ctest starts the longest tests first (cmake/test_costs.cmake). Phases 3 and 4 run side by side
# once both are built: the ThreadSanitizer test takes about one core and each fuzzer one, so the
# fuzzers get the time they would alone; phase 3's output follows the fuzzers'.
#
# Builds are incremental; delete a build directory to start it afresh.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

fuzz_seconds=${NPG_FUZZ_SECONDS:-60}

# The full evaluators of the suite compiled by libtcc (milliseconds each) rather than the system
# compiler, npg's default (0.1-1 s each; the suite creates thousands): NPG_JIT is what --jit auto,
# NPG_AUTO and backend="auto" mean. test_jit_cache, cli_jit_cache, test_full, test_emit_direct,
# test_demand and the Python tests ask for cc explicitly. NPG_JIT=auto bash scripts/test.sh runs
# everything the default way. The tests' cc cache is build*/jit-cache (CMake sets NPG_CACHE_DIR).
export NPG_JIT=${NPG_JIT:-tcc}

header() {
  printf '\n==================== %s ====================\n' "$*"
}

bash scripts/setup.sh

header "1/4 plain build (build/)"
cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j2
bash scripts/check_layers.sh build
ctest --test-dir build --output-on-failure -j2  # two at a time on two cores (points_*, mpi_train run alone)

# The sanitizer and fuzz builds are Debug so that assertions and the
# between-stage IR verifiers run too.
header "2/4 AddressSanitizer + UndefinedBehaviorSanitizer (build-asan/)"
cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=Debug -DNPG_SANITIZE=ON
cmake --build build-asan -j2
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 \
UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build-asan --output-on-failure -j2

header "3/4 ThreadSanitizer: the tests labelled threads (build-tsan/), beside phase 4"
cmake -S . -B build-tsan -DCMAKE_BUILD_TYPE=Debug -DNPG_TSAN=ON
cmake --build build-tsan -j2 --target test_api npgc radiosity_data

header "4/4 fuzz the front end, the .npy reader, the manifest and npg.h call sequences (build-fuzz/)"
CC=clang cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=Debug -DNPG_FUZZ=ON
cmake --build build-fuzz -j2

# phase 3 in the background, its output in build-tsan/tsan.log (shown when the fuzzers are done)
tsan_log=build-tsan/tsan.log
TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/tests/tsan.supp" \
  ctest --test-dir build-tsan -L threads --output-on-failure >"$tsan_log" 2>&1 &
tsan_pid=$!
# phase 3's result: its log and status. Waited for before test.sh exits whichever way (a fuzzer
# that fails, or any command under set -e: the trap), so no ctest outlives it.
tsan_done() {
  local rc=0
  wait "$tsan_pid" || rc=$?
  tsan_pid=
  header "3/4 ThreadSanitizer: the tests labelled threads (build-tsan/)"
  cat "$tsan_log"
  if [ "$rc" != 0 ]; then
    echo "test.sh: the ThreadSanitizer phase failed (its log: $tsan_log)" >&2
  fi
  return "$rc"
}
trap '[ -z "$tsan_pid" ] || tsan_done || true' EXIT

# Seed corpus: every .npg in the tree, tracked or not. libFuzzer adds the
# inputs it finds to the first corpus directory, so it is a scratch copy;
# the flattened path keeps same-named files in different folders apart.
corpus=build-fuzz/corpus
artifacts=build-fuzz/artifacts
rm -rf "$corpus"
mkdir -p "$corpus" "$artifacts"
nseeds=0
while IFS= read -r -d '' f; do
  name=${f#./}
  cp "$f" "$corpus/${name//\//_}"
  nseeds=$((nseeds + 1))
done < <(find . -name '*.npg' -not -path './build*' -not -path './.git/*' -print0)

# Run from the repository root so the target's default std_dir "stdlib" resolves.
log=build-fuzz/fuzz.log
echo "fuzz_frontend: $nseeds seed files, ${fuzz_seconds} s, log in $log"
if ! build-fuzz/fuzz_frontend -max_total_time="$fuzz_seconds" -rss_limit_mb=4096 -timeout=10 \
    -print_final_stats=1 -artifact_prefix="$artifacts/" "$corpus" >"$log" 2>&1; then
  tail -n 80 "$log"
  echo "test.sh: fuzz_frontend failed; the crashing input is in $artifacts/" >&2
  exit 1
fi
grep -E '^(Done|stat::number_of_executed_units|stat::new_units_added)' "$log" || true

# The .npy reader and the model manifest, a third of the front end's time
# each (at least 5 s). fuzz_npy: seeded with the .npy fixtures of the tests
# and its regression inputs. fuzz_manifest: a model of Eq. 3 trained here
# gives the arrays beside each input and, with the regression inputs, the
# seed manifest.
side_seconds=$((fuzz_seconds / 3 > 5 ? fuzz_seconds / 3 : 5))
model=build-fuzz/manifest-model
rm -rf build-fuzz/manifest-data "$model"
build-fuzz/rational_data build-fuzz/manifest-data 20 1 >/dev/null
ASAN_OPTIONS=detect_leaks=0 build-fuzz/npgc train examples/rational/rational.npg build-fuzz/manifest-data -o "$model" >/dev/null
# fuzz_api (npg.h call sequences, bad arguments among them): seeded with
# tests/fuzz/seeds_api, its own small program and model built in-process.
for target in fuzz_npy fuzz_manifest fuzz_api; do
  corpus=build-fuzz/corpus_$target
  rm -rf "$corpus"
  mkdir -p "$corpus"
  if [ "$target" = fuzz_npy ]; then
    cp tests/data/npy/*.npy tests/fuzz/seeds_npy/* "$corpus"/
  elif [ "$target" = fuzz_api ]; then
    cp tests/fuzz/seeds_api/* "$corpus"/
  else
    cp "$model/manifest" "$corpus/rational_manifest"
    cp tests/fuzz/seeds_manifest/* "$corpus"/
  fi
  log=build-fuzz/$target.log
  echo "$target: $(ls "$corpus" | wc -l) seed files, ${side_seconds} s, log in $log"
  if ! NPG_FUZZ_MODEL=$model build-fuzz/$target -max_total_time="$side_seconds" -rss_limit_mb=4096 -timeout=10 \
      -print_final_stats=1 -artifact_prefix="$artifacts/" "$corpus" >"$log" 2>&1; then
    tail -n 80 "$log"
    echo "test.sh: $target failed; the crashing input is in $artifacts/" >&2
    exit 1
  fi
  grep -E '^(Done|stat::number_of_executed_units|stat::new_units_added)' "$log" || true
done

tsan_done || exit 1

header "all phases passed"
