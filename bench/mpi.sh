#!/bin/sh
# mpi.sh [FACES] [SAMPLES] [REPS] — training over MPI ranks against one process, on the
# deforming radiosity room (radiosity_data; the visibility is given as data): wall time per
# phase of `npgc train` for
#   1 rank  x 1 thread   (OPENBLAS_NUM_THREADS=1: one BLAS thread, one pre-multiplication worker)
#   2 ranks x 1 thread   (mpirun -np 2 ... --mpi)
#   1 rank  x 2 threads  (OPENBLAS_NUM_THREADS=2)
# each the best of REPS runs, and the ratios against the first, measured in this run. The
# models are compared (tests/mpi/compare_models.py). Figures, not a test: bench/mpi.md.
# MEM=BYTES trains with --mem BYTES (out of core when the bases exceed it: the ranks share the
# row passes); the passes' split is printed from rank 0's progress line, and over ranks the
# pre-multiplication's: rank 0's own rows against the sums over ranks (the wait for the
# slower rank included). The peak resident memory of the largest process of each best run is
# printed last (GNU time's maximum RSS: over ranks, the larger rank's, not their sum).
set -eu
cd "$(dirname "$0")/.."
faces=${1:-600}
samples=${2:-100}
reps=${3:-2}
build=${BUILD:-build}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# shared memory between the ranks (single copies by CMA), loopback for the launcher
export OMPI_MCA_btl=self,vader OMPI_MCA_oob_tcp_if_include=lo
# a rank that waits yields its core (the machine is shared): no busy polling
export OMPI_MCA_mpi_yield_when_idle=1
prog=examples/radiosity/formfactors.npg
"$build/radiosity_data" "$work/data" "$faces" "$samples" 0 1 3 >/dev/null

# run NAME THREADS CMD...: the best total of REPS runs; its phases in $work/NAME.best
run() {
  name=$1 threads=$2
  shift 2
  best=
  for r in $(seq "$reps"); do
    rm -rf "$work/$name"
    OPENBLAS_NUM_THREADS=$threads /usr/bin/time -f %M -o "$work/$name.rss" "$@" "$build/npgc" train $prog "$work/data" -o "$work/$name" ${MPI_FLAG:-} \
      --progress ${MEM:+--mem $MEM} >"$work/$name.out" 2>"$work/$name.err"
    line=$(grep '^phases:' "$work/$name.out")
    total=$(grep '^trained' "$work/$name.out" | sed 's/.* in \([0-9.]*\) s.*/\1/')
    if [ -z "$best" ] || [ "$(echo "$total < $best" | bc)" = 1 ]; then
      best=$total
      echo "$total $line" >"$work/$name.best"
      cp "$work/$name.rss" "$work/$name.peak"
      grep -a -o 'out of core: [0-9.]* s.*' "$work/$name.err" >"$work/$name.ooc" || true
      grep -a -o 'pre-multiplication over ranks: .*' "$work/$name.err" >"$work/$name.pre" || true
    fi
  done
}
run one 1
MPI_FLAG=--mpi run ranks 1 mpirun --allow-run-as-root --oversubscribe -np 2
run threads 2
/usr/bin/python3 tests/mpi/compare_models.py "$work/one" "$work/ranks" 1e-10 ${MEM:+1e-7} >/dev/null
[ -z "${MEM:-}" ] || grep -a -m1 '^out of core' "$work/one.err" || echo "--mem $MEM: in memory"

echo "radiosity training, $faces faces, $samples samples (best of $reps; $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg))"
/usr/bin/python3 - "$work" <<'PY'
import re, sys
w = sys.argv[1]
def read(name):
    t, line = open(f"{w}/{name}.best").read().split(" ", 1)
    x = [float(v) for v in re.findall(r"[0-9]+\.[0-9]+", line)]
    return [float(t)] + x[:4], [sum(x[4:8])] + x[4:8]
rows = {"1 rank  x 1 thread ": read("one"), "2 ranks x 1 thread ": read("ranks"), "1 rank  x 2 threads": read("threads")}
base = rows["1 rank  x 1 thread "][0]
print("wall seconds (speedup against 1 rank x 1 thread)")
print(f"{'':20s} {'total':>14s} {'snapshots':>14s} {'bases':>14s} {'premultiply':>14s} {'externs':>14s}")
for k, (wall, cpu) in rows.items():
    print(f"{k:20s} " + " ".join(f"{x:7.2f} ({b / x:4.2f}x)" if x > 0 else f"{x:14.2f}" for b, x in zip(base, wall)))
print("CPU seconds of rank 0's process (all its threads; sum of the four phases as total)")
for k, (wall, cpu) in rows.items():
    print(f"{k:20s} " + " ".join(f"{x:14.2f}" for x in cpu))
PY
for name in one ranks threads; do
  [ ! -s "$work/$name.ooc" ] || echo "$name: $(cat "$work/$name.ooc")"
done
[ ! -s "$work/ranks.pre" ] || echo "ranks: $(cat "$work/ranks.pre")"
for name in one ranks threads; do
  echo "$name: peak RSS $(($(tail -1 "$work/$name.peak") / 1024)) MB (the largest process: rank 0 or 1 over ranks)"
done
