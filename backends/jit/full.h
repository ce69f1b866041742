/* full.h — internals of the full evaluator shared with the trainer and
 * tests (the public API is in npg.h). */
#ifndef NPG_FULL_H
#define NPG_FULL_H

#include <stdint.h>

#include "demand.h"
#include "ir.h"
#include "npg.h"
#include "npg_abi.h"

/* The generated C of `prog`'s full evaluator (every stage, the bind-time
 * gather checker) and its tensor builders, written to `out` with the
 * compilation's error handler armed: 0, or -1 with the diagnostic in
 * prog->ctx->msg. What npg_emit_full() writes. */
int full_emit(Program *prog, FILE *out);
/* The full evaluator of `prog`: its C generated and compiled (libtcc, or cc
 * with NPG_CC). With `refusal` non-NULL, an evaluator that refuses all work
 * with that message (the program did not compile). NULL only when out of
 * memory; otherwise errors are in npg_full_error(). npg_full_new() is this
 * for an NpgProgram. */
NpgFull *full_new(Program *prog, NpgBackend backend, const char *refusal);
/* The evaluator's demand (demand.h), emptied, for its dims as bound (bind
 * them first: an evaluation, or every input and param set). NULL after
 * npg_full_error() (out of memory). */
Demand *full_demand(NpgFull *f);
/* Evaluate sample `sample` as npg_full_eval() does, but compute only the
 * entries `d` (from full_demand) asks for and what they read: the demanded
 * entries equal a whole evaluation's bit for bit; every other entry of a
 * stage holds whatever it held (an earlier sample's value, or 0). Inputs
 * and externs are given as for npg_full_eval(). 0, or -1 with
 * npg_full_error(). */
int full_eval_demand(NpgFull *f, long sample, Demand *d);
/* The values of extern `name` (n entries, its count as bound), to be
 * written in place for the next evaluation — for a restricted evaluation
 * that reads only some of them; entries not written keep what they held.
 * The extern counts as given (no callback runs). NULL with
 * npg_full_error(). */
double *full_extern_values(NpgFull *f, const char *name, size_t n);
/* Run the tensor builder `name` on the current binding (after an
 * evaluation bound everything). 0, or -1 with npg_full_error(). */
int full_build(NpgFull *f, const char *name, NpgSink *sink);
/* Sparse declared operators with fewer rows than this are solved by the
 * dense path (their compressed matrix expanded, LAPACK): FULL_SPARSE_MIN_ROWS
 * by default, 0 for the sparse path always, LONG_MAX for dense always
 * (tests compare the two). The sparse path measured as fast or faster than
 * the dense one from 16 cells up (heat conduction, `bench_sparse
 * --crossover`: 1.3x at 16, 3.4x at 256, 46x at 1,024). */
#define FULL_SPARSE_MIN_ROWS 16
void full_set_sparse_min_rows(NpgFull *f, long rows);
/* How many sparse patterns were built, and factorizations made by CHOLMOD
 * and by UMFPACK, since the evaluator was made. */
void full_sparse_counts(const NpgFull *f, long *patterns, long *cholesky, long *lu);
/* The bound size of dim number k (program order). */
long full_dim_size(const NpgFull *f, int k);
/* A hash of the values of param number k as bound (0 when unbound), and in
 * *from (optional) the file or call that bound it. */
uint64_t full_param_hash(const NpgFull *f, int k, const char **from);
/* The hash full_param_hash records: FNV-1a 64 of n doubles. */
uint64_t full_hash_values(const double *v, size_t n);
/* The stage program the evaluator runs. */
const Program *full_program(const NpgFull *f);
/* After an evaluation: the first quantity in evaluation order holding a
 * NaN or an infinity (where it arises, not where it spreads to), its entry
 * as "[2, 5]" and the value; false when every value is finite. */
bool full_first_nonfinite(NpgFull *f, const Sym **sym, char *index, size_t len, double *value);
/* Record `msg` as the evaluator's error (the first one stays); -1. */
int full_fail(NpgFull *f, const char *msg);

#endif
