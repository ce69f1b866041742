#!/usr/bin/env bash
# setup.sh — install the Debian packages npg needs, and only the missing ones.
#
# Idempotent and quiet when everything is there; otherwise it says what it
# installs. demo.sh and test.sh call it first, so a fresh Debian 12 machine
# needs nothing but this repository.
set -euo pipefail

packages=(
  cmake gcc make pkg-config
  re2c                        # lexer generator (compiler/front/lex.re)
  libopenblas-dev liblapacke-dev  # dense linear algebra: PCA, reduced solves
  libtcc-dev tcc              # in-memory JIT; tcc ships libtcc1.a and the headers
  libcmocka-dev               # unit tests
  libcairo2-dev               # npgc plot and the examples: charts as PNG (linked into npgc and the examples only)
  clang libclang-rt-14-dev    # libFuzzer for the fuzz targets
  libomp-dev                  # OpenMP for clang (the fuzz build compiles examples/points too)
  python3-numpy               # the Python module npg (compiler/python/) and the benchmark peer
  python3-dev                 # the Python module npg: CPython's headers
  python3-pytest              # the Python module's tests (tests/python/)
  python3-setuptools          # pip install --no-build-isolation . (setup.py)
  libgmsh-dev                 # examples/fluids: the wind tunnel's mesher (C API)
  libsuitesparse-dev          # examples/fluids: UMFPACK for the pressure projection
  libembree-dev               # examples/radiosity, examples/points: ray-cast visibility
  libpng-dev                  # examples/fluids, examples/radiosity: PNG frames and renders
  libopenmpi-dev openmpi-bin  # optional build feature: training over MPI ranks (npgc train --mpi) and its tests
)

missing=()
for pkg in "${packages[@]}"; do
  # `dpkg -s` also succeeds for removed packages that left config files,
  # so look at the status line rather than the exit code alone.
  if ! dpkg -s "$pkg" 2>/dev/null | grep -q '^Status: install ok installed'; then
    missing+=("$pkg")
  fi
done

[ ${#missing[@]} -eq 0 ] && exit 0

echo "setup.sh: installing ${missing[*]}"
sudo=()
if [ "$(id -u)" -ne 0 ]; then
  sudo=(sudo)
fi
"${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update
"${sudo[@]}" env DEBIAN_FRONTEND=noninteractive \
  apt-get install -y --no-install-recommends "${missing[@]}"
