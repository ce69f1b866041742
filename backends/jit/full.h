/* full.h — the full evaluator: the program's C generated, compiled (jit.h)
 * and run on bound params and inputs, every stage value kept. The internal
 * type every layer from here up evaluates with (training, the exact checks,
 * the tests); npg.h's Full is the facade's wrapper over it
 * (compiler/api/api_full.c), as NpgModel wraps Model.
 *
 * Nothing here is shared with npg.h: the one public type the evaluator
 * needs, NpgBackend, is translated by the facade into JitBackend (jit.h),
 * so this layer compiles without include/ on its path.
 *
 * The evaluator refuses further work after an error (the first one stays)
 * until full_clear_error(). Arguments are trusted: the facade checks them
 * (NULL pointers, shapes) before calling in. */
#ifndef NPG_FULL_H
#define NPG_FULL_H

#include <stdint.h>
#include <stdio.h>

#include "demand.h"
#include "ir.h"
#include "jit.h"
#include "npg_abi.h"

typedef struct Full Full;

/* An extern's values from a function: called at every full_eval for an
 * extern not given by full_set since the last evaluation, to write its
 * `count` values (C order) to `out`; 0, or non-zero for a failure. */
typedef int (*FullExternFn)(void *user, const Full *f, long sample, double *out, size_t count);
/* Bind the dims of input or extern `name` from `shape` (its dims, then its
 * static axes) without a value, as full_set would bind them: the shapes of
 * the outputs of no samples. 0, or -1 naming `from` and the disagreement. */
int full_bind_shape(Full *f, const char *name, int ndim, const long *shape, const char *from);

/* The generated C of `prog`'s full evaluator (every stage, the bind-time
 * gather checker) and its tensor builders, written to `out` with the
 * compilation's error handler armed: 0, or -1 with the diagnostic in
 * prog->ctx->msg. What the facade's npg_emit_full() writes. */
int full_emit(Program *prog, FILE *out);
/* The full evaluator of `prog`: its C generated and compiled (jit.h's
 * `backend`: libtcc, cc, or JIT_AUTO's choice). With `refusal` non-NULL, an evaluator that refuses all work
 * with that message (the program did not compile), and has no program
 * (full_program() is NULL). NULL only when out of memory; otherwise errors
 * are in full_error(). */
Full *full_new(Program *prog, JitBackend backend, const char *refusal);
/* The compiled module (how it was built: jit_info), NULL when compiling failed. */
const JitModule *full_jit(const Full *f);
/* The evaluator's error, "" when none. */
const char *full_error(const Full *f);
/* Forget the error, unless the construction failed (that one stays). */
void full_clear_error(Full *f);
/* Forget every binding: dims, params, inputs and stage values; the error too. */
void full_unbind(Full *f);
/* Bind every param from DATA/<param>.npy; dims from the shapes. */
int full_bind_params(Full *f, const char *data_dir);
/* A param from memory, `ndim` axes of `shape`: doubles (an int param's
 * must be whole numbers); `from` names the source in messages. */
int full_set_param(Full *f, const char *name, int ndim, const long *shape, const double *values, const char *from);
/* An input or extern of one sample (a param too, by name), as full_set_param. */
int full_set(Full *f, const char *name, int ndim, const long *shape, const double *values, const char *from);
/* The extern `name` given by `fn` (NULL removes it); its `of` quantities
 * must be inputs (the callback runs before the stages). */
int full_set_extern_fn(Full *f, const char *name, FullExternFn fn, void *user);
/* Evaluate sample `sample` (externs' callbacks run first). */
int full_eval(Full *f, long sample);
/* One step of a simulation (DESIGN §15), after a full_eval: every state takes its next value
 * (buffers exchanged, nothing copied; the next stage then holds the state before the step until
 * the next evaluation). 0, or -1 with full_error() when a next value was not evaluated. */
int full_advance(Full *f);
/* The values full_set gave since the last evaluation no longer count as given: the next
 * evaluation calls the externs' callbacks again (after values were set only to be read back). */
void full_forget_given(Full *f);
/* After one sample's values were set (a test or validation sample, a training sample staged):
 * every input, and every extern without a callback, must have been given since the last
 * evaluation; one left out would silently be evaluated with the previous sample's value (issue
 * 38). 0, or -1 with "<what>: input 'x' is not given ..." naming the first left out. */
int full_check_given(Full *f, const char *what);
/* The first param not bound, or NULL when every one is. */
const char *full_unbound_param(const Full *f);
/* Whether extern `name` has a callback (full_set_extern_fn). */
bool full_has_extern_fn(const Full *f, const char *name);
/* The values of quantity `name` and their count (optional), NULL when the
 * program has none by that name or it holds no value yet. */
const double *full_get(const Full *f, const char *name, size_t *count);
/* The bound size of dim `name`: -1 unbound or unknown. */
long full_dim(const Full *f, const char *name);
void full_free(Full *f);
/* The evaluator's demand (demand.h), emptied, for its dims as bound (bind
 * them first: an evaluation, or every input and param set). NULL after
 * full_error() (out of memory). */
Demand *full_demand(Full *f);
/* Evaluate sample `sample` as full_eval() does, but compute only the
 * entries `d` (from full_demand) asks for and what they read: the demanded
 * entries equal a whole evaluation's bit for bit; every other entry of a
 * stage holds whatever it held (an earlier sample's value, or 0). Inputs
 * and externs are given as for full_eval(). 0, or -1 with
 * full_error(). */
int full_eval_demand(Full *f, long sample, Demand *d);
/* The values of extern `name` (n entries, its count as bound), to be
 * written in place for the next evaluation — for a restricted evaluation
 * that reads only some of them; entries not written keep what they held.
 * The extern counts as given (no callback runs). NULL with
 * full_error(). */
double *full_extern_values(Full *f, const char *name, size_t n);
/* Run the tensor builder `name` on the current binding (after an
 * evaluation bound everything). 0, or -1 with full_error(). */
int full_build(Full *f, const char *name, NpgSink *sink);
/* Sparse declared operators with fewer rows than this are solved by the
 * dense path (their compressed matrix expanded, LAPACK): FULL_SPARSE_MIN_ROWS
 * by default, 0 for the sparse path always, LONG_MAX for dense always
 * (tests compare the two). The sparse path measured as fast or faster than
 * the dense one from 16 cells up (heat conduction, `bench_sparse
 * --crossover`: 1.3x at 16, 3.4x at 256, 46x at 1,024). */
#define FULL_SPARSE_MIN_ROWS 16
void full_set_sparse_min_rows(Full *f, long rows);
/* How many evaluations ran since the evaluator was made (those that reached the stages): whole
 * (full_eval) and restricted (full_eval_demand; `restricted` may be NULL). What a caller that
 * avoids evaluating again counts (greedy training, its test). */
void full_evaluations(const Full *f, long *whole, long *restricted);
/* How many sparse patterns were built, and factorizations made by CHOLMOD
 * and by UMFPACK, since the evaluator was made. */
void full_sparse_counts(const Full *f, long *patterns, long *cholesky, long *lu);
/* The bound size of dim number k (program order). */
long full_dim_size(const Full *f, int k);
/* A hash of the values of param number k as bound (0 when unbound), and in
 * *from (optional) the file or call that bound it. */
uint64_t full_param_hash(const Full *f, int k, const char **from);
/* The hash full_param_hash records: FNV-1a 64 of n doubles. */
uint64_t full_hash_values(const double *v, size_t n);
/* The stage program the evaluator runs. */
const Program *full_program(const Full *f);
/* After an evaluation: the first quantity in evaluation order holding a
 * NaN or an infinity (where it arises, not where it spreads to), its entry
 * as "[2, 5]" and the value; false when every value is finite. `cause`
 * (may be NULL) gets why, when a division or a power of that stage has a
 * base of 0 (or a root a negative base) at that entry: "a division by
 * zero: a[0] is 0, and p raises it to the power -1/2" (the zero area
 * itself); else "". */
bool full_first_nonfinite(Full *f, const Sym **sym, char *index, size_t len, double *value, char *cause,
                          size_t causelen);
/* Record `msg` as the evaluator's error (the first one stays); -1. */
int full_fail(Full *f, const char *msg);
/* Record `msg` as the evaluator's error, replacing one already there (an
 * argument refused by the facade: the latest thing the caller should hear
 * about: api_refuse in compiler/api/api.h); -1. */
int full_refuse(Full *f, const char *msg);

/* Derivatives (DESIGN §17; the C: backends/emit/emit_deriv.c), compiled on first use with
 * the evaluator's backend. full_deriv_emit writes that C as full_emit does (-1 for a
 * program with an extern: a black box has no derivative). After an evaluation,
 * full_deriv_arrays gives one zeroed array per quantity (Program.slots, counts as
 * bound), owned by the evaluator; set the inputs' tangents and call full_jvp: every
 * stage's array then holds its tangent (J times the inputs' tangents); or set the
 * outputs' cotangents and call full_vjp: every input's array then holds the reverse
 * product (the stages' are consumed). Each NULL or -1 with full_error(). */
int full_deriv_emit(Program *prog, FILE *out);
/* backends/jit/full_pattern.c: after an evaluation, the structural pattern of
 * d output / d input at the params as bound (the tensor builders' entries propagated
 * through the stages; a declared operator's power makes its term dense): per entry of
 * `output`, the sorted entries of input `input` it reads, as CSR (*indptr: count(output)
 * + 1, *indices), malloc'd. 0, or -1 with full_error(). */
int full_jacobian_pattern(Full *f, const char *output, const char *input, long **indptr, long **indices);
double *const *full_deriv_arrays(Full *f);
int full_jvp(Full *f, long sample);
int full_vjp(Full *f, long sample);

#endif
