/* fuzz_frontend.c — libFuzzer target for the whole front end: lex, parse,
 * check, lower, basis classes, and the `npgc check` report of what compiles.
 *
 * DESIGN §3: "Never a crash, never a silent wrong answer." A crash, a
 * sanitizer report, a leak or a hang is a finding; so is a result that
 * breaks the npg.h contract (failure without a message, success with one).
 *
 * `use` modules are read from $NPG_STDLIB, else "stdlib" relative to the
 * working directory (scripts/test.sh runs this from the repository root).
 * The input becomes a NUL-terminated string, so an embedded NUL ends it.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static FILE *null_out(void) {
  static FILE *out;
  if (!out) out = fopen("/dev/null", "w");
  if (!out) abort();
  return out;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static const char *std_dir;
  if (!std_dir) {
    std_dir = getenv("NPG_STDLIB");
    if (!std_dir || !*std_dir) std_dir = "stdlib";
  }

  char *buf = malloc(size + 1);
  if (!buf) return 0;
  memcpy(buf, data, size);
  buf[size] = '\0';

  NpgOptions opt = {0};
  opt.source = buf;
  opt.std_dir = std_dir;
  NpgProgram *p = npg_compile("fuzz.npg", &opt);
  bool ok = npg_ok(p);
  const char *err = npg_error(p);
  if (ok != (err[0] == '\0')) {
    fprintf(stderr, "npg_ok() is %d but npg_error() is \"%s\"\n", ok, err);
    abort();
  }
  if (ok) {
    npg_report(p, null_out(), false);
    npg_report(p, null_out(), true);
  }
  npg_free(p);
  free(buf);
  return 0;
}
