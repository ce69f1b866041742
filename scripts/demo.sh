#!/usr/bin/env bash
# demo.sh — the main demo: install what is missing, build, and show what the
# compiler makes of the paper's Eq. 3 (examples/rational): its stages,
# tensors, basis classes and costs; then generate samples and evaluate the
# full program on them with the generated, JIT-compiled evaluator.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/setup.sh

cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j2

run() {
  echo
  echo "+ $*"
  "$@"
}

work=build/demo/rational
mkdir -p "$work"
run build/npgc check examples/rational/rational.npg
run build/rational_data "$work/DATA" 1000 1
run build/npgc eval examples/rational/rational.npg --full "$work/DATA" "$work/DATA" -o "$work/OUT"
echo
echo "wrote $work/OUT/y.npy (1000 samples of y = f(x), paper Eq. 3)"
echo "training, reduced evaluation and verification are not implemented yet (issue 4)"
