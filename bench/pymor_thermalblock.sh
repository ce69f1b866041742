#!/bin/sh
# pymor_thermalblock.sh PYMOR_DIR [BUILD_DIR] — npg against pyMOR 2025.2 on pyMOR's thermal
# block (issue 41's goals), both tools in the same run on the same matrices and parameters:
# 2 x 2 blocks (5 training parameters per block: pyMOR's POD's 625) and 3 x 3 (2 per block:
# 512), pyMOR's --grid 100 (10,201 unknowns), 100 random test parameters, bases of 20 and 30
# vectors. PYMOR_DIR is pyMOR's source folder (the one holding src/pymor), run from Debian's
# packages as its README says (python3-scipy python3-diskcache python3-typer python3-qtpy
# python3-matplotlib python3-threadpoolctl python3-pil); nothing else in the project needs it.
# Writes build/bench_thermalblock/ (the matrices as .npy, the models, results.json per case).
# Usage from the repository root after a build: sh bench/pymor_thermalblock.sh PYMOR_DIR
set -eu
if [ $# -lt 1 ] || [ ! -f "$1/src/pymor/__init__.py" ]; then
  echo "usage: pymor_thermalblock.sh PYMOR_DIR [BUILD_DIR]: PYMOR_DIR must hold pyMOR's sources (src/pymor)" >&2
  exit 2
fi
P=$(cd "$1" && pwd)
B=${2:-build}
[ -x "$B/npgc" ] || { echo "pymor_thermalblock.sh: $B/npgc not found: build first (cmake --build $B --target npgc)" >&2; exit 2; }
W=$B/bench_thermalblock
mkdir -p "$W"
export PYTHONPATH="$P/src" MPLBACKEND=Agg OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
GRID=${TB_GRID:-100}
TEST=${TB_TEST:-100}
/usr/bin/python3 bench/pymor_thermalblock.py "$B/npgc" "$W/2x2" --blocks 2x2 --grid "$GRID" --snapshots 5 \
  --test "$TEST" --sizes 20,30
echo
/usr/bin/python3 bench/pymor_thermalblock.py "$B/npgc" "$W/3x3" --blocks 3x3 --grid "$GRID" --snapshots 2 \
  --test "$TEST" --sizes 20,30
