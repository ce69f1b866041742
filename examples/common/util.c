/* util.c — util.h. */
#define _POSIX_C_SOURCE 200809L
#include "util.h"

#include "npg.h"

#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

int util_exit_status(const char *prog, int rc) {
  errno = 0;
  bool flushed = fflush(stdout) == 0;
  int saved = errno;
  if (!flushed || ferror(stdout)) {
    fprintf(stderr, "%s: cannot write to standard output%s%s\n", prog, saved ? ": " : "", saved ? strerror(saved) : "");
    return rc ? rc : 1;
  }
  return rc;
}

double util_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

double util_read_bandwidth(size_t bytes, double min_seconds) { return npg_read_bandwidth(bytes, min_seconds); }

double util_tick_step(double range, int want) {
  double raw = range / want, mag = pow(10, floor(log10(raw))), r = raw / mag;
  return mag * (r < 1.5 ? 1 : r < 3.5 ? 2 : r < 7.5 ? 5 : 10);
}

int util_make_dirs(const char *path, char *err, size_t errlen) {
  char buf[4096];
  if (!path || !*path) return npg_error_set(err, errlen, "no folder given");
  if (snprintf(buf, sizeof buf, "%s", path) >= (int)sizeof buf)
    return npg_error_set(err, errlen, "%.64s...: path too long", path);
  for (char *q = buf + 1;; q++) {
    bool last = *q == 0;
    if (*q != '/' && !last) continue;
    *q = 0;
    struct stat st;
    if (mkdir(buf, 0777) != 0 && errno != EEXIST)
      return npg_error_set(err, errlen, "cannot create %s: %s", buf, strerror(errno));
    if (stat(buf, &st) != 0 || !S_ISDIR(st.st_mode))
      return npg_error_set(err, errlen, "%s exists and is not a folder", buf);
    if (last) break;
    *q = '/';
  }
  return 0;
}
