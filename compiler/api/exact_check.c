/* exact_check.c — `npgc verify --exact` for a compiled program: the
 * exactness checks of backends/verify/exact.c run on its stage program. */
#include "compile.h"
#include "exact.h"
#include "npg.h"

int exact_check(NpgProgram *p, const ExactOptions *o, FILE *out, char *err, size_t errlen) {
  if (err && errlen) err[0] = '\0';
  if (!p || !npg_ok(p)) return error_set(err, errlen, "the program does not compile");
  return exact_check_program(program_ir(p), o, out, err, errlen);
}
