/* dist.h — the ranks training runs on (DESIGN §5, §11: training as map and
 * reduce, the same code over MPI ranks when one machine is outgrown).
 *
 * One process, rank 0 of 1, until dist_start(); after it, the ranks of
 * MPI_COMM_WORLD. In a build without MPI (NPG_HAVE_MPI undefined)
 * dist_start() fails with a message saying so and everything else is the
 * one-process no-op. Collective calls must be made by every rank in the
 * same order; a rank that cannot go on calls dist_abort(), never returns
 * into a collective the others are waiting in. */
#ifndef NPG_DIST_H
#define NPG_DIST_H

#include <stdbool.h>
#include <stddef.h>

#include "context.h"

/* Whether this build has MPI. */
bool dist_available(void);
/* Join the MPI job (MPI_Init unless the program has already initialized
 * MPI; then MPI_Finalize at exit). Idempotent. 0, or -1 with `err` (no MPI
 * in this build, or MPI_Init failed). */
int dist_start(Err *err);
/* This process's rank and the number of ranks: 0 and 1 before dist_start. */
int dist_rank(void);
int dist_size(void);
/* x[0..n) = its sum over the ranks, on every rank (in chunks: n may exceed
 * an int). */
void dist_allreduce_sum(double *x, long n);
/* x[0..n) = its largest value over the ranks, on every rank. */
void dist_allreduce_max(double *x, long n);
/* Blocks of counts[r] doubles, rank r's at all + Σ_{q<r} counts[q] (already
 * in place there on rank r), gathered on every rank. -1 with `err` when a
 * block exceeds what one MPI call takes (2^31 - 1 entries). */
int dist_allgather(double *all, const long *counts, Err *err);
/* x[0..n) of rank `root` on every rank (in chunks: n may exceed an int). */
void dist_broadcast(double *x, long n, int root);
/* bytes p[0..n) of rank `root` on every rank (in chunks). */
void dist_broadcast_bytes(void *p, long n, int root);
void dist_barrier(void);
/* "npg: rank K of N failed: <message>" on stderr, then the whole job is
 * ended (MPI_Abort: the other ranks get SIGTERM, so a model store cleans
 * its staging folder). With one process: the message and exit(1). */
_Noreturn void dist_abort(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* Test hook: true when the environment's NPG_MPI_FAIL_RANK is this rank
 * (after dist_start), so training fails there after its first sample;
 * "K:kill" kills rank K there instead (SIGKILL, as a crashed node). */
bool dist_fail_here(void);

#endif
