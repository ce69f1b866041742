/* npgc.h — the commands of the npgc driver, a client of npg.h only. */
#ifndef NPGC_H
#define NPGC_H

#include <stdbool.h>
#include <stdio.h>

/* eval.c: `npgc eval --full` (the reduced form goes to npgc_reduce). */
int npgc_eval(int argc, char **argv);
/* reduce_cmds.c: train, reduced eval, verify, bench. */
int npgc_reduce(int argc, char **argv);

/* plot.c: npgc plot MODEL/ -o spectra.png (cairo, linked into npgc only). */
int npgc_plot(int argc, char **argv);
/* tune.c: npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/. */
int npgc_tune(int argc, char **argv);
/* npgc_util.c: the usage of `cmd` (to stdout and 0 for --help, else to
 * stderr and 2), and of every command. */
int npgc_usage(const char *cmd, bool help);
void npgc_usage_all(FILE *out);
/* Print `msg` to stderr as an error: "error: msg", or as it is when it is
 * already a diagnostic at a program location ("file:line:col: error: ..."
 * and its source line, as a bind-time index error is). */
void npgc_error(const char *msg);
/* Strict numbers: the whole string, in range (false otherwise). */
bool npgc_parse_long(const char *s, long lo, long hi, long *out);
bool npgc_parse_double(const char *s, double lo, double hi, bool lo_open, double *out);
/* BYTES with an optional suffix k, M, G, T (powers of 1000). */
bool npgc_parse_bytes(const char *s, size_t *out);
/* mkdir -p of the parent of `path` (and `path` itself with `self`);
 * -1 after printing which directory could not be made. */
int npgc_make_parents(const char *path, bool self);
/* Two paths naming one file (same device and inode). */
bool npgc_same_file(const char *a, const char *b);
/* `path` would be written inside directory `dir`. */
bool npgc_inside(const char *path, const char *dir);

#endif
