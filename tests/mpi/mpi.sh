#!/bin/sh
# mpi.sh BUILD — training over MPI ranks (npgc train --mpi, NpgTrainOptions.mpi) on
# loopback: 2 ranks (and 3, uneven) give the one-process model to 1e-10, for the radiosity
# program (through npgc, and through npg.h with the visibility extern by callback), for a
# program with an extern on data, and out of core (--mem below the bases); a rank that fails, or is killed, mid-training ends the job
# with a message naming it and leaves no model. Registered only in a build with MPI.
set -eu
build=$1
npgc=$build/npgc
scratch=$build/tests/mpi_scratch
rm -rf "$scratch"
mkdir -p "$scratch"
compare="/usr/bin/python3 tests/mpi/compare_models.py"

# one machine, no network: shared memory between ranks, loopback for the launcher; root
# (containers) needs --allow-run-as-root; 2 cores, so ranks may oversubscribe them
export OMPI_MCA_btl=self,vader OMPI_MCA_btl_vader_single_copy_mechanism=none
export OMPI_MCA_oob_tcp_if_include=lo OMPI_MCA_rmaps_base_oversubscribe=1 OMPI_MCA_mpi_yield_when_idle=1
export OPENBLAS_NUM_THREADS=1
# the sanitizer build: OpenMPI's own allocations outlive MPI_Finalize (tests/mpi/lsan.supp);
# suppressing them by library needs full stacks and its components kept loaded
export ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}fast_unwind_on_malloc=0"
export LSAN_OPTIONS="suppressions=$PWD/tests/mpi/lsan.supp" OMPI_MCA_mca_base_component_disable_dlclose=1
mpirun="timeout 300 mpirun --allow-run-as-root --oversubscribe -x ASAN_OPTIONS -x LSAN_OPTIONS"

fail() {
  echo "mpi.sh: $*" >&2
  exit 1
}

# (a) the radiosity program (its extern v, the visibility, given as data) at 60 faces
"$build/radiosity_data" "$scratch/rdata" 60 13 0 1 7 >/dev/null
prog=examples/radiosity/formfactors.npg
"$npgc" train $prog "$scratch/rdata" -o "$scratch/r1" --cap 8 >/dev/null
$mpirun -np 2 "$npgc" train $prog "$scratch/rdata" -o "$scratch/r2" --cap 8 --mpi >/dev/null
$compare "$scratch/r1" "$scratch/r2"
$mpirun -np 3 "$npgc" train $prog "$scratch/rdata" -o "$scratch/r3" --cap 8 --mpi >/dev/null
$compare "$scratch/r1" "$scratch/r3"

# the same through npg.h, the visibility from a callback that must run on each rank for its
# own samples only
"$build/tests/mpi_api" $prog "$scratch/rdata" "$scratch/a1" >/dev/null
$mpirun -np 2 "$build/tests/mpi_api" $prog "$scratch/rdata" "$scratch/a2" --mpi
$compare "$scratch/a1" "$scratch/a2"

# (b) a program with an extern, on data numpy writes
/usr/bin/python3 - "$scratch/xdata" <<'PY'
import os, sys
import numpy as np
d = sys.argv[1]
os.makedirs(d, exist_ok=True)
rng = np.random.default_rng(5)
F, V, S = 30, 20, 11
tri = rng.integers(0, V, size=(F, 3)).astype(np.int64)
np.save(f"{d}/tri.npy", tri)
t = np.linspace(0, 1, S)[:, None, None]
g = rng.standard_normal((V, 3))[None] * (1 + t) + rng.standard_normal((V, 3))[None] * t**2
np.save(f"{d}/g.npy", np.ascontiguousarray(g))
np.save(f"{d}/v.npy", np.ascontiguousarray(np.cos(g[:, tri[:, 1], 2])))  # the black box: any function of g
PY
xprog=tests/programs/extern_stage.npg
"$npgc" train $xprog "$scratch/xdata" -o "$scratch/x1" >/dev/null
$mpirun -np 2 "$npgc" train $xprog "$scratch/xdata" -o "$scratch/x2" --mpi >/dev/null
$compare "$scratch/x1" "$scratch/x2"

# (c) out of core over ranks: --mem far below the bases, so the pair classes stream by rows (23
# passes); the ranks share the passes, fold their R factors and write their rows of the basis
# files all ranks map, or for the bases the model drops form their blocks' rows and sum the
# tensors' blocks. Equal to one process out of core and to in memory (the streamed members'
# singular values to 1e-7: compare_models.py says why); through npg.h the extern's records are
# shared, its callback still runs once per sample (mpi_api counts)
mem=300000
"$npgc" train $prog "$scratch/rdata" -o "$scratch/o1" --cap 8 --mem $mem >/dev/null
# out of core v's class is kept as coefficients of its training values (issue 30), in memory as a
# basis: with --keep-bases v the layouts are the same
"$npgc" train $prog "$scratch/rdata" -o "$scratch/o1k" --cap 8 --mem $mem --keep-bases v >/dev/null
$compare "$scratch/r1" "$scratch/o1k" 1e-10 1e-7 --estimates-subset
test -f "$scratch/o1/coef_6.npy" && ! test -f "$scratch/o1/basis_6.npy" || fail "out of core v is not kept as coefficients"
for np in 2 3; do
  $mpirun -np $np "$npgc" train $prog "$scratch/rdata" -o "$scratch/o$np" --cap 8 --mem $mem --mpi --progress \
    >/dev/null 2>"$scratch/o$np.log"
  grep -q "out of core: 5 of 9 classes streamed by rows, 23 passes" "$scratch/o$np.log" ||
    fail "--mem $mem over $np ranks did not go out of core: $(cat "$scratch/o$np.log")"
  # the pair bases the model drops formed block by block over the ranks (stream.c), no basis file
  grep -aq "bases formed block by block for the pre-multiplication, no basis file: {s,h} {r} {c} {v} {d,p}; {v} kept as coefficients of its training values" \
    "$scratch/o$np.log" || fail "over $np ranks the pair bases were not formed block by block"
  $compare "$scratch/o1" "$scratch/o$np" 1e-10 1e-7
  # the streamed classes' training floors (issue 30), summed over the ranks' passes: one process's
  # to the 1e-7 the out-of-core floors resolve
  /usr/bin/python3 - "$scratch/o1/manifest" "$scratch/o$np/manifest" <<'PY' || fail "training floors over $np ranks"
import sys
def floors(path):
    return {f[1]: float(f[3]) for f in (l.split() for l in open(path)) if f and f[0] == "floor"}
a, b = floors(sys.argv[1]), floors(sys.argv[2])
assert a and a.keys() == b.keys(), (a, b)
for q in a:
    assert abs(a[q] - b[q]) <= 1e-6 * a[q] + 1e-7, (q, a[q], b[q])
PY
done
$mpirun -np 2 "$build/tests/mpi_api" $prog "$scratch/rdata" "$scratch/ao2" --mpi --mem $mem
$compare "$scratch/o2" "$scratch/ao2" 1e-10 1e-7
# sample weights (--weights) out of core over 2 ranks: the one-process weighted model
/usr/bin/python3 -c "import numpy as np, sys; w = np.ones(13); w[::4] = 3; np.save(sys.argv[1], w)" "$scratch/w.npy"
"$npgc" train $prog "$scratch/rdata" -o "$scratch/w1" --cap 8 --mem $mem --weights "$scratch/w.npy" >/dev/null
$mpirun -np 2 "$npgc" train $prog "$scratch/rdata" -o "$scratch/w2" --cap 8 --mem $mem --mpi --weights "$scratch/w.npy" >/dev/null
$compare "$scratch/w1" "$scratch/w2" 1e-10 1e-7

# (c2) bases to roundoff over 2 ranks out of core (issue 41): snapshots of x whose singular
# values span 1 … 1e-14 give, from the ranks' R factors folded on every rank, a basis that
# reproduces them at every leading size as numpy's SVD does, to 1e-12 of their norm (through
# Gram matrices it stopped near 1e-8)
printf 'dim N\ninput x : real[N]\noutput y[i:N] = x[i] * x[i]\n' >"$scratch/designed.npg"
/usr/bin/python3 - "$scratch/ddata" <<'PY'
import os, sys
import numpy as np
d = sys.argv[1]
os.makedirs(d, exist_ok=True)
rng = np.random.default_rng(3)
n, S = 400, 29
Q, _ = np.linalg.qr(rng.standard_normal((n, S)))
P, _ = np.linalg.qr(rng.standard_normal((S, S)))
s = 10.0 ** (-14.0 * np.arange(S) / (S - 1))
np.save(f"{d}/x.npy", np.ascontiguousarray(((Q * s) @ P.T).T))
PY
$mpirun -np 2 "$npgc" train "$scratch/designed.npg" "$scratch/ddata" -o "$scratch/d2" --center off --cap 29 --energy 1 \
  --mem 20000 --mpi --progress >/dev/null 2>"$scratch/d2.log"
grep -q "out of core: 2 of 2 classes streamed by rows" "$scratch/d2.log" || fail "the designed snapshots did not go out of core"
/usr/bin/python3 - "$scratch/ddata/x.npy" "$scratch/d2/basis_0.npy" <<'PY' || fail "x's basis over 2 ranks is not an SVD's"
import sys
import numpy as np
X = np.load(sys.argv[1]).T
B = np.load(sys.argv[2])
s = np.linalg.svd(X, compute_uv=False)
need = int(np.sum(s >= 1e-12 * s[0]))
assert B.shape[1] >= need, (B.shape, need)
worst = max(abs(np.linalg.norm(X - B[:, :j] @ (B[:, :j].T @ X)) - np.sqrt(np.sum(s[j:] ** 2)))
            for j in range(B.shape[1] + 1)) / np.linalg.norm(s)
print(f"mpi.sh: x's basis over 2 ranks out of core, sigma 1 ... 1e-14: {B.shape[1]} directions ({need} at >= 1e-12), "
      f"residual at every size against numpy's SVD {worst:.2g} of |X|")
assert worst < 1e-12, worst
PY

# (d) rank 1 fails after its first sample, then rank 1 is killed there: the job ends (no
# rank waits forever: timeout 300 would say so), the message names the rank, no model and no
# staging folder is left
# (in memory, and out of core: its whole evaluations)
for how in 1 1:kill 1:ooc; do
  rm -rf "$scratch/dead"*
  ooc=
  [ "$how" != 1:ooc ] || how=1 ooc="--cap 8 --mem $mem"
  # shellcheck disable=SC2086
  if NPG_MPI_FAIL_RANK=$how $mpirun -np 2 -x NPG_MPI_FAIL_RANK "$npgc" train $prog "$scratch/rdata" \
      -o "$scratch/dead" --mpi $ooc >"$scratch/dead.log" 2>&1; then
    fail "NPG_MPI_FAIL_RANK=$how: the job succeeded"
  fi
  status=$?
  [ $status -ne 124 ] || fail "NPG_MPI_FAIL_RANK=$how: the job hung (timeout)"
  if [ "$how" = 1 ]; then
    grep -q "rank 1 of 2 failed: training sample 1: NPG_MPI_FAIL_RANK" "$scratch/dead.log" ||
      fail "NPG_MPI_FAIL_RANK=$how: no message naming rank 1: $(cat "$scratch/dead.log")"
  else
    grep -q "rank 1 .*exited on signal 9" "$scratch/dead.log" ||
      fail "NPG_MPI_FAIL_RANK=$how: no message naming rank 1: $(cat "$scratch/dead.log")"
  fi
  leftover=$(ls -d "$scratch/dead" "$scratch"/dead.tmp.* "$scratch"/dead.old.* "$scratch"/dead.ooc.* 2>/dev/null || true)
  [ -z "$leftover" ] || fail "NPG_MPI_FAIL_RANK=$how left $leftover"
done
# (e) ranks given different problems (issue 24: a model 80 % wrong with exit 0, or an MPI abort
# with no message): every rank refuses before training, naming what differs; no model is left
"$build/radiosity_data" "$scratch/rsame" 60 13 0 1 7 >/dev/null
"$build/radiosity_data" "$scratch/rfew" 60 9 0 1 7 >/dev/null
"$build/radiosity_data" "$scratch/rdims" 48 13 0 1 7 >/dev/null
/usr/bin/python3 -c "import numpy as np,sys; r=np.load(sys.argv[1]); np.save(sys.argv[1], r*0.5)" "$scratch/rsame/rho.npy"
# another folder of the same shapes and params, its inputs other (issue 38: trained on a mixture)
cp -r "$scratch/rdata" "$scratch/rinputs"
/usr/bin/python3 -c "import numpy as np,sys; r=np.load(sys.argv[1]); np.save(sys.argv[1], r*1.5)" "$scratch/rinputs/e.npy"
for case in "rsame|param 'rho' (the hash of its values) differs between ranks" \
            "rfew|the number of training samples is 9 on some ranks and 13 on others" \
            "rinputs|the training samples' inputs (the hash of their values) differs between ranks" \
            "rdims|dim F is 48 on some ranks and 60 on others" \
            "rdata --cap 4|--cap is 4 on some ranks and 8 on others" \
            "rdata --weights $scratch/w.npy|the sum of the sample weights is 13 on some ranks and 21 on others"; do
  other=${case%%|*} want=${case#*|}
  rm -rf "$scratch/differ"*
  # shellcheck disable=SC2086
  if $mpirun -np 1 "$npgc" train $prog "$scratch/rdata" -o "$scratch/differ" --cap 8 --mpi : \
      -np 1 "$npgc" train $prog --cap 8 "$scratch"/$other -o "$scratch/differ" --mpi >"$scratch/differ.log" 2>&1; then
    fail "ranks given $other trained"
  fi
  grep -qF "the 2 MPI ranks were not given the same training: $want" "$scratch/differ.log" ||
    fail "ranks given $other: $(cat "$scratch/differ.log")"
  [ -z "$(ls -d "$scratch"/differ* 2>/dev/null | grep -v differ.log || true)" ] || fail "ranks given $other left a model"
done
sed 's|/ pi |/ (2 * pi) |' $prog >"$scratch/other.npg"
if $mpirun -np 1 "$npgc" train $prog "$scratch/rdata" -o "$scratch/differ" --mpi : \
    -np 1 "$npgc" train "$scratch/other.npg" "$scratch/rdata" -o "$scratch/differ" --mpi >"$scratch/differ.log" 2>&1; then
  fail "ranks given two programs trained"
fi
grep -qF "not given the same training: the program (its hash) differs between ranks" "$scratch/differ.log" ||
  fail "ranks given two programs: $(cat "$scratch/differ.log")"
echo "mpi.sh: 2 and 3 ranks equal one process, in memory and out of core; a failed and a killed rank end the job, named, no model"
