#!/usr/bin/env bash
# check_layers.sh — fail when a file includes a header of a higher layer.
#
#   bash scripts/check_layers.sh [BUILD_DIR]
#
# Layers, lowest first (DESIGN §9): stdlib/runtime <- ir <- backends <-
# compiler, backends/ layered by concern (emit <- jit <- model <- train <-
# verify) and compiler/ by folder: front (the front end) <- api (the npg.h
# facade) <- driver (npgc, a client of npg.h only). A file may include
# headers of its own layer and of the layers below; include/npg.h, the
# public API, is the facade's own header (layer api). Each layer is one
# folder, as CMake globs it, so this list and the build's are the same list.
#
#   1. every `#include "..."` of every source in a layer names a header it
#      may include (the grep, which names the file and the line);
#   2. with BUILD_DIR (holding compile_commands.json): with the include flags
#      CMake gives each layer, a header of every higher layer does not even
#      compile, and one of its own does (the build's structure, checked).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

layers=(runtime ir emit jit model train verify front api driver)
declare -A dirs=(
  [runtime]="stdlib/runtime"
  [ir]="ir"
  [emit]="backends/emit"
  [jit]="backends/jit"
  [model]="backends/model"
  [train]="backends/train"
  [verify]="backends/verify"
  [front]="compiler/front"
  [api]="compiler/api"
  [driver]="compiler/driver"
)
# The driver, a client of npg.h alone, with its own headers and the charts it
# shares with the applications (examples/common/chart.h, library npg_chart).
driver_may_include="npg.h npgc.h reduce_cmds.h chart.h"

# The files of a layer (sources and headers).
files_of() {
  local layer=$1 f
  for f in "${dirs[$layer]}"/*.c "${dirs[$layer]}"/*.h "${dirs[$layer]}"/*.re "${dirs[$layer]}"/*.def; do
    [[ -e $f ]] && echo "$f"
  done
  [[ $layer == api ]] && echo include/npg.h
  return 0
}

# The header names a layer's files may include: its own and every lower
# layer's.
allowed=" "
status=0
for layer in "${layers[@]}"; do
  for f in $(files_of "$layer"); do
    case $f in *.h | *.def) allowed+="$(basename "$f") " ;; esac
  done
  while IFS= read -r line; do
    file=${line%%:*}
    rest=${line#*:}
    lineno=${rest%%:*}
    header=$(sed -E 's/^[^"]*"([^"]+)".*/\1/' <<<"${rest#*:}")
    if [[ $layer == driver ]]; then
      [[ " $driver_may_include " == *" $header "* ]] && continue
    elif [[ $allowed == *" $(basename "$header") "* ]]; then
      continue
    fi
    echo "$file:$lineno: layer $layer includes \"$header\", which is not its own or a lower layer's" >&2
    status=1
  done < <(files_of "$layer" | xargs grep -nH -E '^[[:space:]]*#[[:space:]]*include[[:space:]]+"' || true)
done

# 2. The build itself refuses an upward include.
build=${1:-}
if [[ -n $build ]]; then
  if [[ ! -f $build/compile_commands.json ]]; then
    echo "check_layers: $build/compile_commands.json missing (configure with CMake first)" >&2
    exit 1
  fi
  # a source of the layer, its own header, and one header of every higher layer
  declare -A source=([runtime]=stdlib/runtime/npy.c [ir]=ir/basis.c [emit]=backends/emit/emit_full.c
                     [jit]=backends/jit/full.c [model]=backends/model/reduced.c [train]=backends/train/train.c
                     [verify]=backends/verify/exact.c [front]=compiler/front/parse.c [api]=compiler/api/npg.c
                     [driver]=compiler/driver/main.c)
  declare -A own=([runtime]=npy.h [ir]=ir.h [emit]=emit.h [jit]=full.h [model]=reduced.h [train]=train.h
                  [verify]=exact.h [front]=compile.h [api]=api.h [driver]=npgc.h)
  higher=(ir.h emit.h full.h model.h reduced.h train.h exact.h compile.h api.h npg.h npgc.h)
  declare -A rank=([ir.h]=1 [emit.h]=2 [full.h]=3 [model.h]=4 [reduced.h]=4 [train.h]=5 [exact.h]=6
                   [compile.h]=7 [api.h]=8 [npg.h]=8 [npgc.h]=9)
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  cc=${CC:-cc}
  i=0
  for layer in "${layers[@]}"; do
    flags=$(python3 - "$build/compile_commands.json" "$PWD/${source[$layer]}" <<'EOF'
import json, shlex, sys
for c in json.load(open(sys.argv[1])):
    if c["file"] == sys.argv[2]:
        args = c.get("arguments") or shlex.split(c["command"])
        out, it = [], iter(args)
        for a in it:
            if a in ("-I", "-isystem"): out += [a, next(it)]
            elif a.startswith("-I") or a.startswith("-isystem"): out.append(a)
        print(" ".join(shlex.quote(a) for a in out))
        break
else:
    sys.exit("no compile command for " + sys.argv[2])
EOF
)
    echo "#include \"${own[$layer]}\"" >"$tmp/own.c"
    if ! eval "$cc -fsyntax-only $flags $tmp/own.c" 2>"$tmp/err"; then
      echo "check_layers: layer $layer cannot include its own ${own[$layer]}:" >&2
      cat "$tmp/err" >&2
      status=1
    fi
    for h in "${higher[@]}"; do
      [[ ${rank[$h]} -gt $i ]] || continue
      echo "#include \"$h\"" >"$tmp/up.c"
      if eval "$cc -fsyntax-only $flags $tmp/up.c" 2>/dev/null; then
        echo "check_layers: layer $layer (${source[$layer]}'s flags) can include \"$h\" of a higher layer" >&2
        status=1
      fi
    done
    i=$((i + 1))
  done
fi

if [[ $status == 0 ]]; then echo "check_layers: every include points down"; fi
exit $status
