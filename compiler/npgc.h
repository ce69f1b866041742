/* npgc.h — the commands of the npgc driver, a client of npg.h only. */
#ifndef NPGC_H
#define NPGC_H

#include <stdbool.h>
#include <stdio.h>

#include "npg.h"

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
/* Numbers and options are parsed by npg.h's npg_args_* / npg_parse_*, the
 * parser the applications use too. The problem the parser kept, with a
 * pointer to `npgc CMD --help`; 2. */
int npgc_args_error(const NpgArgs *a, const char *cmd);
/* One positional argument too many: "more than one WHAT given ('FIRST' and 'this')". */
void npgc_args_extra(NpgArgs *a, const char *what, const char *first);
/* "npgc CMD: missing WHAT" and a pointer to the usage; 2. */
int npgc_missing(const char *cmd, const char *what);
/* BYTES with an optional suffix k, M, G, T (powers of 1000). */
bool npgc_parse_bytes(const char *s, size_t *out);
/* mkdir -p of the parent of `path` (and `path` itself with `self`);
 * -1 after printing which directory could not be made. */
int npgc_make_parents(const char *path, bool self);
/* Two paths naming one file (same device and inode). */
bool npgc_same_file(const char *a, const char *b);
/* `path` would be written inside directory `dir`. */
bool npgc_inside(const char *path, const char *dir);
/* Before loading MODEL/: the arguments swapped (a model given where the
 * data is, the data where the model is) or a data folder given as a model
 * are said as such, not as "MODEL/manifest: cannot open". `data` may be
 * NULL; `data_role` names it in the usage ("TEST/", "IN/"). -1 after the
 * message. */
int npgc_check_model_and_data(const char *cmd, const char *model, const char *data, const char *data_role);

#endif
