#!/bin/sh
# interp.sh BUILD_DIR — Galerkin against interpolated reduction of the
# eligible stage of each program (issue 26, DESIGN §12): its output's
# projection floor, the output error of each reduction and of the eligible
# stage, and the reduced evaluation time of each against the full one
# (npgc bench, best of its passes), on held-out samples. The inputs' bases
# are kept at energy 1 (x, and r2 or l2, are polynomial in a few modes; the
# training default since the quantities under a power are kept whole, DESIGN
# §12), so the errors are the eligible stage's reduction and the output's basis.
# OVERSAMPLE="1 2 4 8 16" sets the oversamplings tried (default "16 32"),
# ROWS="springs gravity_eps0.1" the programs (default all).
set -eu
B=$1
W=$(mktemp -d /tmp/npg_interp_XXXXXX)
trap 'rm -rf "$W"' EXIT
cd "$(dirname "$0")/.."
row() { # name program data-kind stage input-basis samples
  name=$1 P=$2 kind=$3 st=$4 inb=$5 S=$6
  case " ${ROWS:-$name} " in *" $name "*) ;; *) return 0;; esac
  /usr/bin/python3 bench/interp/data.py "$kind" "$W/$name.tr" "$S" 1
  /usr/bin/python3 bench/interp/data.py "$kind" "$W/$name.te" 20 2
  for how in galerkin $(for x in ${OVERSAMPLE:-16 32}; do echo interp:$x; done); do
    case $how in galerkin) opt="";; interp:*) opt="--reduce $st:interp --interp-oversample ${how#interp:}";; esac
    "$B/npgc" train "$P" "$W/$name.tr" -o "$W/$name.m" --basis x:energy=1 --basis "$inb:energy=1" $opt >/dev/null
    "$B/npgc" verify "$P" "$W/$name.m" "$W/$name.te" --tol 1e9 >"$W/v.txt"
    "$B/npgc" bench "$P" "$W/$name.m" "$W/$name.te" >"$W/b.txt"
    out=$(grep '(output)' "$W/v.txt" | sed 's/, interp//' | awk '{print $4, $5}')
    stg=$(grep "^$st " "$W/v.txt" | sed 's/, interp//' | awk '{print $4, $5}')
    m=$(grep "^$st " "$W/v.txt" | sed 's/, interp//' | awk '{print $3}')
    # npgc bench: "full evaluation   T s per sample [Q1, Q3]": the median
    full=$(grep '^full evaluation' "$W/b.txt" | awk '{print $3}')
    red=$(grep '^reduced evaluation' "$W/b.txt" | awk '{print $3}')
    echo "$name $st $m $how $out $stg $full $red"
  done
}
echo "program stage m reduction output_error output_floor stage_error stage_floor full_s reduced_s"
row gravity_eps0.01 tests/programs/nbody_gravity.npg nbody:64:0.01 w r2 300
row gravity_eps0.1 tests/programs/nbody_gravity.npg nbody:64:0.1 w r2 300
# smaller motions (rotations within ±0.3, modes of amplitude 0.02 or 0.05): the regime of the
# issue's trial, where Galerkin leaves the output 5-9x above its floor
row gravity_small_eps0.01 tests/programs/nbody_gravity.npg nbody:64:0.01:0.02:0.3 w r2 300
row gravity_small_eps0.1 tests/programs/nbody_gravity.npg nbody:64:0.1:0.02:0.3 w r2 300
row gravity_mid_eps0.1 tests/programs/nbody_gravity.npg nbody:64:0.1:0.05:0.3 w r2 300
row lennard_jones bench/interp/lennard_jones.npg lj:64 g r2 300
row springs tests/programs/deforming_springs.npg springs:12 f l2 200
