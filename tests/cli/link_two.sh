#!/bin/sh
# link_two.sh BUILD_DIR — the generated C of two programs links into one
# binary: every external symbol of a generated translation unit carries the
# program's prefix (its file stem). Two programs' `npgc emit` output and a
# small main that calls both entry points compile and link with cc.
set -eu
npgc="$1/npgc"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$npgc" emit examples/rational/rational.npg -o "$tmp/rational.c"
"$npgc" emit examples/radiosity/formfactors.npg -o "$tmp/formfactors.c"
cat >"$tmp/main.c" <<'C'
#include <stdio.h>
typedef struct NpgCtx NpgCtx;
int rational_npg_full(const NpgCtx *c);
int rational_npg_check(const NpgCtx *c);
int formfactors_npg_full(const NpgCtx *c);
int formfactors_npg_check(const NpgCtx *c);
int main(void) {
  int (*const entry[])(const NpgCtx *) = {rational_npg_full, rational_npg_check, formfactors_npg_full,
                                          formfactors_npg_check};
  printf("link_two: %zu entry points of two programs in one binary\n", sizeof entry / sizeof *entry);
  return 0;
}
C
cc -Wall -Werror -c "$tmp/rational.c" -o "$tmp/rational.o"
cc -Wall -Werror -c "$tmp/formfactors.c" -o "$tmp/formfactors.o"
cc -Wall -Werror "$tmp/main.c" "$tmp/rational.o" "$tmp/formfactors.o" -lm -o "$tmp/both"
"$tmp/both"
