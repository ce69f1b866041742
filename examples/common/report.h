/* report.h — what every application run writes besides its arrays: its folders, and
 * report.json (the figures) written to a temporary name and renamed, so a reader never
 * sees half a report. Functions returning int give 0, or -1 after printing
 * "PROGRAM: reason" on stderr. */
#ifndef EXAMPLES_REPORT_H
#define EXAMPLES_REPORT_H

#include <stdio.h>

/* The --out folder of `command` given, and short enough for the paths built under it
 * (`maxlen` bytes): 0, or 2 (a usage error) after saying what is wrong. */
int report_need_out(const char *program, const char *command, const char *out, size_t maxlen);
/* mkdir -p `path` (every missing parent too); `program` prefixes the message. */
int report_make_dir(const char *program, const char *path);
/* `lead` "name": [x0, x1, ...] `tail`, each number with `digits` significant digits;
 * NaN and infinities as null (JSON has no NaN). */
void report_json_array(FILE *f, const char *lead, const char *name, const double *x, long n, int digits,
                       const char *tail);

/* A report being written: `path`.tmp until report_commit renames it to `path`. */
typedef struct Report {
  FILE *f;
  char path[4096], tmp[4200];
} Report;
/* Open DIR/report.json's temporary file. */
int report_open(Report *r, const char *program, const char *dir);
/* Close it and rename it into place; on any write error the temporary file is removed. */
int report_commit(Report *r, const char *program);

#endif
