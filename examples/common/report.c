/* report.c — report.h. */
#define _POSIX_C_SOURCE 200809L
#include "report.h"

#include <errno.h>
#include <math.h>
#include <string.h>

#include "util.h"

int report_need_out(const char *program, const char *command, const char *out, size_t maxlen) {
  if (!out) {
    fprintf(stderr, "%s: %s needs --out DIR\n", program, command);
    return 2;
  }
  if (strlen(out) > maxlen) {
    fprintf(stderr, "%s: --out: path longer than %zu bytes\n", program, maxlen);
    return 2;
  }
  return 0;
}

int report_make_dir(const char *program, const char *path) {
  char err[512];
  if (util_make_dirs(path, err, sizeof err) != 0) {
    fprintf(stderr, "%s: %s\n", program, err);
    return -1;
  }
  return 0;
}

void report_json_array(FILE *f, const char *lead, const char *name, const double *x, long n, int digits,
                       const char *tail) {
  fprintf(f, "%s\"%s\": [", lead, name);
  for (long i = 0; i < n; i++) {
    if (isfinite(x[i]))
      fprintf(f, "%s%.*g", i ? ", " : "", digits, x[i]);
    else
      fprintf(f, "%snull", i ? ", " : "");
  }
  fprintf(f, "]%s", tail);
}

int report_open(Report *r, const char *program, const char *dir) {
  snprintf(r->path, sizeof r->path, "%s/report.json", dir);
  snprintf(r->tmp, sizeof r->tmp, "%s.tmp", r->path);
  r->f = fopen(r->tmp, "w");
  if (!r->f) {
    fprintf(stderr, "%s: %s: %s\n", program, r->tmp, strerror(errno));
    return -1;
  }
  return 0;
}

int report_commit(Report *r, const char *program) {
  int bad = ferror(r->f);
  if (fclose(r->f) != 0) bad = 1;
  r->f = NULL;
  if (bad || rename(r->tmp, r->path) != 0) {
    fprintf(stderr, "%s: %s: %s\n", program, r->path, bad ? "write failed" : strerror(errno));
    remove(r->tmp);
    return -1;
  }
  return 0;
}
