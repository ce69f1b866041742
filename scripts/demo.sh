#!/usr/bin/env bash
# demo.sh — the main demo: install what is missing, build, and show what the
# compiler makes of the paper's Eq. 3 (examples/rational): its stages,
# tensors, basis classes and costs.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/setup.sh

cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j2

echo
echo "+ build/npgc check examples/rational/rational.npg"
build/npgc check examples/rational/rational.npg
