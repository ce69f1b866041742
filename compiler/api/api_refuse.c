/* api_refuse.c — the public API's refusals of bad arguments (api.h): the
 * message in the caller's buffer and kept as this thread's last refusal;
 * and npg_error_set, the library's error_set for its callers (npg.h). */
#include <stdarg.h>
#include <stdio.h>

#include "api.h"

static _Thread_local char refusal[512];

int api_refuse(char *err, size_t errlen, const char *func, const char *fmt, ...) {
  char why[400];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(why, sizeof why, fmt, ap);
  va_end(ap);
  snprintf(refusal, sizeof refusal, "%s: %s", func, why);
  return error_set(err, errlen, "%s", refusal);
}

const char *api_refusal(void) { return refusal; }

int npg_error_set(char *err, size_t errlen, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  error_vset(err, errlen, fmt, ap);
  va_end(ap);
  return -1;
}
