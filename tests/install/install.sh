#!/bin/sh
# install.sh BUILD_DIR — `cmake --install` into a temporary prefix, then use
# it as a stranger would, from outside the source tree:
#   1. a consumer built with `cc consumer.c $(pkg-config --cflags --libs npg)`
#      (libnpg.so) compiles a program that uses the stdlib and evaluates it;
#   2. the same consumer through find_package(npg) (npg::npg, libnpg.a, and
#      npg::npg_shared, libnpg.so), every consumer run without LD_LIBRARY_PATH;
#   3. the installed npgc checks a program that uses `geometry` and a module
#      that exists only in the installed stdlib, so the stdlib it found is
#      the installed one (found relative to the executable), not the source
#      tree's.
#
# NPG_CONSUMER_CFLAGS: extra flags for the consumers (the sanitizer build's).
set -eu
cflags=${NPG_CONSUMER_CFLAGS:-}
build=$(cd "$1" && pwd)
src=$(cd "$(dirname "$0")" && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
prefix=$tmp/prefix
cmake --install "$build" --prefix "$prefix" >"$tmp/install.log"
for f in bin/npgc lib/libnpg.a lib/libnpg.so include/npg.h share/npg/stdlib/npg/geometry.npg \
         lib/pkgconfig/npg.pc lib/cmake/npg/npgConfig.cmake; do
  [ -e "$prefix/$f" ] || { echo "install.sh: $f was not installed" >&2; exit 1; }
done
cd "$tmp"

# The consumers run as a user's would: no LD_LIBRARY_PATH (npg.pc and CMake give them an rpath),
# and the prefix is not one the loader knows, so a missing rpath fails here
unset LD_LIBRARY_PATH

# 1. pkg-config only (libnpg.so)
export PKG_CONFIG_PATH="$prefix/lib/pkgconfig"
cc -Wall -Werror $cflags "$src/consumer.c" $(pkg-config --cflags --libs npg) -lm -o consumer_pc
# loads_installed BINARY: its libnpg.so is the installed one (the path resolved: npg.pc's is pkgconfig/../..)
loads_installed() {
  lib=$(ldd "$1" | awk '/libnpg\.so/ { print $3 }')
  [ -n "$lib" ] && [ "$(realpath "$lib")" = "$(realpath "$prefix/lib/libnpg.so")" ] ||
    { echo "install.sh: $1 does not load the installed libnpg.so: $(ldd "$1" | grep npg)" >&2; exit 1; }
}
loads_installed ./consumer_pc
./consumer_pc

# 2. find_package(npg): npg::npg (libnpg.a) and npg::npg_shared (libnpg.so)
cmake -S "$src" -B consumer_cmake -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_C_FLAGS="$cflags" >consumer_cmake.log
cmake --build consumer_cmake >>consumer_cmake.log
consumer_cmake/consumer
loads_installed consumer_cmake/consumer_shared
consumer_cmake/consumer_shared

# 2b. the installed npgc carries an rpath to the installed libraries, relative to itself
readelf -d "$prefix/bin/npgc" | grep -q 'R.*PATH.*\$ORIGIN/../lib' ||
  { echo "install.sh: npgc has no \$ORIGIN rpath: $(readelf -d "$prefix/bin/npgc" | grep PATH)" >&2; exit 1; }

# 3. the installed npgc and its stdlib
printf 'fn twice(a) = 2 * a\n' >"$prefix/share/npg/stdlib/npg/installed_only.npg"
cat >prog.npg <<'NPG'
use geometry
use installed_only
input a : real[3]
input b : real[3]
output d = twice(dot(a, b))
NPG
"$prefix/bin/npgc" check prog.npg >check.txt
grep -q '^' check.txt
echo "install.sh: ok (prefix $prefix)"
