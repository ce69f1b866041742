#!/bin/sh
# bench/stream.sh [FACES] [SAMPLES] [MEM] — streamed bases (issue 30) against the old layout,
# one after the other in one script: `npgc train` of the radiosity program out of core
# (--mem MEM), with every basis kept (--keep-bases all, the old layout) and with the default
# (the pair bases used in training, not stored). Per run: the trainer's phase times, the wall
# time, peak RSS (/usr/bin/time), the peak scratch disk (the unnamed files training holds open:
# the disk blocks of the deleted files under /proc/PID/fd, sampled every 0.1 s), the model's size.
set -eu
cd "$(dirname "$0")/.."
faces=${1:-1000}
samples=${2:-40}
mem=${3:-200M}
build=${BUILD:-build}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
prog=examples/radiosity/formfactors.npg
"$build/radiosity_data" "$work/data" "$faces" "$samples" 0 1 3 >/dev/null

run() {
  name=$1
  shift
  /usr/bin/time -f %M -o "$work/$name.rss" "$build/npgc" train $prog "$work/data" -o "$work/$name" --mem "$mem" \
    --progress "$@" >"$work/$name.out" 2>"$work/$name.err" &
  tpid=$!
  peak=0
  while kill -0 $tpid 2>/dev/null; do
    pid=$(pgrep -P $tpid npgc || true)
    if [ -n "$pid" ]; then
      s=$(for fd in /proc/$pid/fd/*; do
            case "$(readlink "$fd" 2>/dev/null)" in *'(deleted)') stat -L -c '%b %B' "$fd" 2>/dev/null ;; esac
          done | awk '{s += $1 * $2} END {print s + 0}')
      [ "$s" -gt "$peak" ] && peak=$s
    fi
    sleep 0.1
  done
  wait $tpid
  echo "$peak" >"$work/$name.scratch"
  du -sk "$work/$name" | cut -f1 >"$work/$name.size"
}
run stored --keep-bases all
run streamed
# every array of the streamed model is the stored model's, bit for bit
for f in "$work/streamed"/*.npy; do
  cmp -s "$f" "$work/stored/$(basename "$f")" || echo "note: $(basename "$f") differs from the stored model's"
done
echo "radiosity training out of core, $faces faces, $samples samples, --mem $mem ($(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg))"
grep -a -m1 '^out of core:' "$work/stored.err" || true
printf '%-9s %9s %12s %12s %10s  %s\n' layout "wall s" "peak RSS MB" "scratch MB" "model MB" "trainer phases (s)"
for name in stored streamed; do
  phases=$(grep -a '^phases:' "$work/$name.out" | sed 's/^phases: *//; s/ (cpu.*//')
  wall=$(grep -a '^trained' "$work/$name.out" | sed 's/.* in \([0-9.]*\) s.*/\1/')
  printf '%-9s %9s %12.0f %12.0f %10.1f  %s\n' "$name" "$wall" "$(($(cat "$work/$name.rss") / 1024))" \
    "$(echo "$(cat "$work/$name.scratch") / 1000000" | bc -l)" "$(echo "$(cat "$work/$name.size") / 1024" | bc -l)" "$phases"
done
