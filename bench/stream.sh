#!/bin/sh
# bench/stream.sh [FACES] [SAMPLES] [MEM] — streamed bases (issue 30) against the old layout,
# one after the other in one script: `npgc train` of the radiosity program out of core
# (--mem MEM), with every basis kept (--keep-bases all, the old layout: every basis written to its
# file) and with the default (the pair bases the model drops formed block by block and used at
# once, stream.c). BUILD=DIR runs another build's binaries (an older commit's, for before/after). Per run: the trainer's phase times, the wall
# time, peak RSS (/usr/bin/time), the peak scratch disk (the unnamed files training holds open or
# maps: the disk blocks of the deleted files under /proc/PID/fd and map_files, sampled every 0.1 s),
# the model's size.
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
  # the scratch: disk blocks of the deleted files the trainer holds open or mapped (each once)
  /usr/bin/python3 - $tpid >"$work/$name.scratch" <<'PY'
import os, subprocess, sys, time
tpid, peak = sys.argv[1], 0
while os.path.exists(f"/proc/{tpid}"):
    pids = subprocess.run(["pgrep", "-P", tpid], capture_output=True, text=True).stdout.split()
    for pid in pids:
        seen, total = set(), 0
        try:
            paths = [f"/proc/{pid}/fd/{fd}" for fd in os.listdir(f"/proc/{pid}/fd")]
            paths += [f"/proc/{pid}/map_files/{r}" for r in os.listdir(f"/proc/{pid}/map_files")]
            for path in paths:
                try:
                    if not os.readlink(path).endswith("(deleted)"):
                        continue
                    st = os.stat(path)
                except OSError:
                    continue
                if st.st_ino not in seen:
                    seen.add(st.st_ino)
                    total += st.st_blocks * 512
        except OSError:
            pass
        peak = max(peak, total)
    time.sleep(0.1)
print(peak)
PY
  wait $tpid
  du -sk "$work/$name" | cut -f1 >"$work/$name.size"
}
run stored --keep-bases all
run streamed
# every array of the streamed model against the stored model's (out of core the pair bases are
# formed block by block, so the tensors are summed in another order: equal to rounding)
/usr/bin/python3 - "$work/streamed" "$work/stored" <<'PY'
import os, sys, numpy as np
worst, name = 0.0, ""
for f in sorted(os.listdir(sys.argv[1])):
    if f.endswith(".npy"):
        x, y = np.load(os.path.join(sys.argv[1], f)), np.load(os.path.join(sys.argv[2], f))
        d = np.max(np.abs(x - y)) / max(1.0, np.max(np.abs(y))) if x.shape == y.shape and x.size else (0 if x.shape == y.shape else np.inf)
        if d >= worst:
            worst, name = d, f
print("streamed model against stored: largest relative difference %.2g (%s)" % (worst, name))
PY
echo "radiosity training out of core, $faces faces, $samples samples, --mem $mem ($(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg))"
grep -a -m1 '^out of core:' "$work/stored.err" || true
printf '%-9s %9s %12s %12s %10s  %s\n' layout "wall s" "peak RSS MB" "scratch MB" "model MB" "trainer phases (s)"
for name in stored streamed; do
  phases=$(grep -a '^phases:' "$work/$name.out" | sed 's/^phases: *//; s/ (cpu.*//')
  wall=$(grep -a '^trained' "$work/$name.out" | sed 's/.* in \([0-9.]*\) s.*/\1/')
  printf '%-9s %9s %12.0f %12.0f %10.1f  %s\n' "$name" "$wall" "$(($(cat "$work/$name.rss") / 1024))" \
    "$(echo "$(cat "$work/$name.scratch") / 1000000" | bc -l)" "$(echo "$(cat "$work/$name.size") / 1024" | bc -l)" "$phases"
done
grep -a -m1 '^out of core: bases formed block by block' "$work/streamed.err" || true
for name in stored streamed; do # the out-of-core passes, split (the streamed run's basis passes take the floors)
  echo "$name: $(grep -a -o 'out of core: [0-9.]* s samples.*' "$work/$name.err" | sed 's/out of core: //')"
done
