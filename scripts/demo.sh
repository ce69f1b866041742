#!/usr/bin/env bash
# demo.sh — the main demo: install what is missing, build, and show what the
# compiler makes of the paper's Eq. 3 (examples/rational): its stages,
# tensors, basis classes and costs; then generate training and held-out
# samples, train the reduced model, verify it against the full evaluator,
# evaluate it, and time full against reduced.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/setup.sh

# No build type given: a fresh build/ gets CMakeLists.txt's default (RelWithDebInfo), an existing
# one keeps the type it was configured with (passing one would reconfigure a Release build/ and
# rebuild all of it)
cmake -S . -B build
cmake --build build -j2

run() {
  echo
  echo "+ $*"
  "$@"
}

work=build/demo/rational
rm -rf "$work"
mkdir -p "$work"
run build/npgc check examples/rational/rational.npg
run build/rational_data "$work/TRAIN" 200 1
run build/rational_data "$work/TEST" 100 2
run build/npgc train examples/rational/rational.npg "$work/TRAIN" -o "$work/MODEL"
run build/npgc verify examples/rational/rational.npg "$work/MODEL" "$work/TEST" --tol 1e-10
run build/npgc eval examples/rational/rational.npg "$work/MODEL" "$work/TEST" -o "$work/OUT"
run build/npgc bench examples/rational/rational.npg "$work/MODEL" "$work/TEST"
echo
echo "wrote $work/MODEL (the reduced model: manifest + .npy) and $work/OUT/y.npy (reduced, lifted)"

# The radiosity form factors of paper §8 on a deforming room (200 faces):
# train on 40 deformations and lights, verify and time on 10 held out.
work=build/demo/radiosity
rm -rf "$work"
mkdir -p "$work"
run build/radiosity_data "$work/TRAIN" 200 40 0 1 1
run build/radiosity_data "$work/TEST" 200 10 0.05 0.95 2
cp "$work/TRAIN/tri.npy" "$work/TRAIN/rho.npy" "$work/TEST/"
run build/npgc train examples/radiosity/formfactors.npg "$work/TRAIN" -o "$work/MODEL"
run build/npgc verify examples/radiosity/formfactors.npg "$work/MODEL" "$work/TEST" --tol 0.02
run build/npgc bench examples/radiosity/formfactors.npg "$work/MODEL" "$work/TEST" --cc

# The reduced fluid of paper §6–§7.1 (Fig. 5), short: full training runs with a
# large and a small obstacle on an 800-cell periodic tunnel, streamed into npg
# trainers (one model per basis size), the one-step error of a medium obstacle,
# full and reduced frames side by side (build/npg-fluids tunnel --out DIR for the
# 2,000-cell, 300-frame version).
work=build/demo/fluids
rm -rf "$work"
run build/npg-fluids tunnel --out "$work" --cells 800 --frames 120 --sizes 8,16,32,64 --particles 1000 --png-every 40 --vtk-every 40
echo
echo "wrote $work/report.json, $work/plots/*.png, $work/frames/frame_NNNN.png (full | reduced), $work/vtk/*.pvd"

# The radiosity application (examples/radiosity/README.md): the two-room scene at 266
# faces, trained on 60 samples of the parameter box (visibility ray-cast by callback),
# both animations full and reduced on frames not in training, the error split and the
# bound per frame, pictures and arrays in build/demo/radiosity_app.
work=build/demo/radiosity_app
rm -rf "$work"
run build/npg-radiosity demo --faces 250 --samples 60 --frames 8 --ss 2 --out "$work"
