#!/usr/bin/env bash
# check_layers.sh — fail when a file includes a header of a layer it does not sit on.
#
#   bash scripts/check_layers.sh [BUILD_DIR]
#
# Each layer is one folder (its files as CMake globs them) and sits on the
# layers named after it in the table below; a file may include the headers of
# its own layer and of every layer under it, the relation followed through.
# The library, libnpg (DESIGN §9): stdlib/runtime <- ir <- backends (emit <-
# jit <- model <- train <- verify) <- compiler/api, the npg.h facade, which
# also sits on the front end (compiler/front, itself on ir alone) and on
# include/, the public header npg.h. train sits on include/ too: its options
# are a view of npg.h's NpgTrainOptions (train.h), the one options type. Its clients see npg.h and nothing under
# it: compiler/chart (the charts, cairo) <- compiler/driver (npgc),
# compiler/python (the module npg) and examples/common <- every other folder
# of examples/, an application each (found, not listed).
#
#   1. every `#include "..."` of every source in a layer names a header it
#      may include (the grep, which names the file and the line);
#   2. with BUILD_DIR (holding compile_commands.json): with the include flags
#      CMake gives a source of each layer, one header of its own compiles and
#      one of every layer it does not sit on does not (the build's structure,
#      checked; a layer without a compile command, such as compiler/python in
#      a build without Python, is checked by the grep alone).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# layer    folder            sits on
table="
runtime    stdlib/runtime    -
ir         ir                runtime
emit       backends/emit     ir
jit        backends/jit      emit
model      backends/model    jit
train      backends/train    model public
verify     backends/verify   train
front      compiler/front    ir
public     include           -
api        compiler/api      front verify public
chart      compiler/chart    public
driver     compiler/driver   chart
python     compiler/python   chart
common     examples/common   chart
"
layers=()
declare -A dir under
while read -r name folder on; do
  [[ -n $name ]] || continue
  layers+=("$name")
  dir[$name]=$folder
  under[$name]=${on//-/}
done <<<"$table"
for d in examples/*/; do
  d=${d%/}
  app=${d#examples/}
  [[ $app == common ]] && continue
  ls "$d"/*.c "$d"/*.h >/dev/null 2>&1 || continue # no C (examples/python)
  layers+=("app:$app")
  dir["app:$app"]=$d
  under["app:$app"]=common
done

# The files of a layer (sources and headers), and its headers' names.
files_of() {
  local f
  for f in "${dir[$1]}"/*.c "${dir[$1]}"/*.h "${dir[$1]}"/*.re "${dir[$1]}"/*.def; do
    [[ -e $f ]] && echo "$f"
  done
  return 0
}
declare -A headers
for layer in "${layers[@]}"; do
  headers[$layer]=" "
  for f in $(files_of "$layer"); do
    case $f in *.h | *.def) headers[$layer]+="${f##*/} " ;; esac
  done
done
headers_of() { printf '%s\n' ${headers[$1]}; }

# Every layer a layer sits on, directly or through others.
declare -A below
closure() {
  local seen=" " todo=(${under[$1]}) l
  while ((${#todo[@]})); do
    l=${todo[0]}
    todo=("${todo[@]:1}")
    [[ $seen == *" $l "* ]] && continue
    seen+="$l "
    todo+=(${under[$l]})
  done
  echo "$seen"
}
for layer in "${layers[@]}"; do below[$layer]=$(closure "$layer"); done

# 1. The includes, grepped.
status=0
for layer in "${layers[@]}"; do
  allowed=${headers[$layer]}
  for l in ${below[$layer]}; do allowed+=${headers[$l]}; done
  while IFS= read -r line; do
    file=${line%%:*}
    rest=${line#*:}
    lineno=${rest%%:*}
    header=${rest#*\"}
    header=${header%%\"*}
    [[ $allowed == *" ${header##*/} "* ]] && continue
    echo "$file:$lineno: layer ${layer#app:} includes \"$header\", which is neither its own nor of a layer it sits on ($(echo ${below[$layer]}))" >&2
    status=1
  done < <(files_of "$layer" | xargs -r grep -nH -E '^[[:space:]]*#[[:space:]]*include[[:space:]]+"' || true)
done

# 2. The build itself refuses a header of a layer not under the file's.
build=${1:-}
if [[ -n $build ]]; then
  if [[ ! -f $build/compile_commands.json ]]; then
    echo "check_layers: $build/compile_commands.json missing (configure with CMake first)" >&2
    exit 1
  fi
  # the include flags of the first source of each layer that has a compile command
  declare -A flags
  while IFS=$'\t' read -r layer f; do flags[$layer]=$f; done < <(
    for layer in "${layers[@]}"; do echo "$layer ${dir[$layer]}"; done | python3 -c '
import json, os, shlex, sys
commands = {}
for c in json.load(open(sys.argv[1])):
    commands.setdefault(os.path.normpath(os.path.join(c["directory"], c["file"])), c)
for line in sys.stdin:
    layer, folder = line.split()
    folder = os.path.join(os.getcwd(), folder)
    for path in sorted(p for p in commands if os.path.dirname(p) == folder):
        c = commands[path]
        args = c.get("arguments") or shlex.split(c["command"])
        out, it = [], iter(args)
        for a in it:
            if a in ("-I", "-isystem"): out += [a, next(it)]
            elif a.startswith("-I") or a.startswith("-isystem"): out.append(a)
        print(layer + "\t" + " ".join(shlex.quote(a) for a in out))
        break
' "$build/compile_commands.json")
  # one header a layer, named by no other layer's header
  all=$(for l in "${layers[@]}"; do headers_of "$l"; done | sort | uniq -d)
  declare -A sample
  for layer in "${layers[@]}"; do
    for h in $(headers_of "$layer"); do
      case $h in *.def) continue ;; esac
      grep -qxF "$h" <<<"$all" || { sample[$layer]=$h; break; }
    done
  done
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  cc=${CC:-cc}
  for layer in "${layers[@]}"; do
    [[ -n ${flags[$layer]:-} ]] || continue
    if [[ -n ${sample[$layer]:-} ]]; then
      echo "#include \"${sample[$layer]}\"" >"$tmp/own.c"
      if ! eval "$cc -fsyntax-only ${flags[$layer]} $tmp/own.c" 2>"$tmp/err"; then
        echo "check_layers: layer ${layer#app:} cannot include its own ${sample[$layer]}:" >&2
        cat "$tmp/err" >&2
        status=1
      fi
    fi
    # a header of every other layer, reached or not through this layer's include
    # path: one preprocessor run, each include behind __has_include (which
    # searches the path as #include does), the files it opened read from its
    # line markers (a system header of the same name, Python's compile.h, is
    # not the layer's)
    : >"$tmp/up.c"
    for other in "${layers[@]}"; do
      [[ $other == "$layer" || ${below[$layer]} == *" $other "* || -z ${sample[$other]:-} ]] && continue
      printf '#if __has_include("%s")\n#include "%s"\n#endif\n' "${sample[$other]}" "${sample[$other]}" >>"$tmp/up.c"
    done
    opened=$(eval "$cc -E ${flags[$layer]} $tmp/up.c" 2>/dev/null | sed -nE 's/^# [0-9]+ "([^"]+)".*/\1/p' | sort -u)
    for other in "${layers[@]}"; do
      [[ $other == "$layer" || ${below[$layer]} == *" $other "* || -z ${sample[$other]:-} ]] && continue
      if grep -qxF "$PWD/${dir[$other]}/${sample[$other]}" <<<"$opened"; then
        echo "check_layers: layer ${layer#app:} (${dir[$layer]}) can include \"${sample[$other]}\" of layer ${other#app:}, which it does not sit on" >&2
        status=1
      fi
    done
  done
fi

if [[ $status == 0 ]]; then echo "check_layers: every include points down"; fi
exit $status
