/* corpus.h — the programs the tests check over (the examples' and tests/programs) and
 * random data for a program: what the checks of every program share (test_full,
 * test_exact, test_builder, test_emit_direct, ...). */
#ifndef NPG_CORPUS_H
#define NPG_CORPUS_H

#include <stdbool.h>

#include "ir.h"
#include "npg.h"
#include "refeval.h"

/* The example programs' folders, and with them tests/programs: NULL-terminated lists. */
extern const char *const corpus_examples[];
extern const char *const corpus_all[];

/* Run check(path, arg) on every .npg file in `dir` (a missing dir has none); returns the
 * sum of what check returned, and adds the programs to *n. */
int for_each_program(const char *dir, int (*check)(const char *path, void *arg), void *arg, int *n);

/* check(p, path, arg) on every program of the folders dirs[0..] (NULL-terminated), each
 * compiled first (the repository's stdlib) and freed after: a program that does not
 * compile is one failure, its message printed. Returns the failures (what check returned,
 * summed), the programs counted in *n. */
typedef int (*ProgramCheck)(NpgProgram *p, const char *path, void *arg);
int check_programs(const char *const *dirs, ProgramCheck check, void *arg, int *n);

/* Random data (backends/train/randdata.h) for every param, then every input and extern of
 * `prog` (program order, one stream from `seed`), every dim of size n: written into `d`
 * and, when `set` is non-NULL, handed to set(user, s, ndim, shape, values) too (to bind an
 * evaluator). With `padded`, int params that some guard tests get -1 entries. Returns how
 * many params were padded. */
typedef void (*GivenFn)(void *user, const Sym *s, int ndim, const long *shape, const double *values);
int bind_random(RefData *d, const Program *prog, long n, unsigned seed, bool padded, GivenFn set, void *user);

#endif
