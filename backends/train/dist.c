/* dist.c — the ranks training runs on (dist.h): MPI_COMM_WORLD when this
 * build has MPI and training asked for it, one process otherwise. The only
 * file that includes mpi.h. */
#include <limits.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ast.h"
#include "dist.h"
#include "scratch.h"

#ifdef NPG_HAVE_MPI
#include <mpi.h>
#endif

static bool started;      /* dist_start succeeded: MPI_COMM_WORLD */
static int rank_, size_ = 1;

bool dist_available(void) {
#ifdef NPG_HAVE_MPI
  return true;
#else
  return false;
#endif
}

#ifdef NPG_HAVE_MPI
static void finalize(void) {
  int done = 0;
  MPI_Finalized(&done);
  if (!done) MPI_Finalize();
}
#endif

int dist_start(Err *err) {
  if (started) return 0;
#ifdef NPG_HAVE_MPI
  int up = 0;
  MPI_Initialized(&up);
  if (!up) {
    if (MPI_Init(NULL, NULL) != MPI_SUCCESS) return err_set(err, "MPI_Init failed");
    atexit(finalize);
  }
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
  started = true;
  return 0;
#else
  return err_set(err, "this build of npg has no MPI: install OpenMPI (scripts/setup.sh installs libopenmpi-dev "
                      "openmpi-bin) and configure the build again");
#endif
}

int dist_rank(void) { return rank_; }
int dist_size(void) { return size_; }

#ifdef NPG_HAVE_MPI
static void allreduce(double *x, long n, MPI_Op op) {
  if (!started || size_ == 1) return;
  for (long i = 0; i < n; i += 1L << 28) {
    long c = n - i < 1L << 28 ? n - i : 1L << 28;
    MPI_Allreduce(MPI_IN_PLACE, x + i, (int)c, MPI_DOUBLE, op, MPI_COMM_WORLD);
  }
}
void dist_allreduce_sum(double *x, long n) { allreduce(x, n, MPI_SUM); }
void dist_allreduce_max(double *x, long n) { allreduce(x, n, MPI_MAX); }
#else
void dist_allreduce_sum(double *x, long n) { (void)x, (void)n; }
void dist_allreduce_max(double *x, long n) { (void)x, (void)n; }
#endif

int dist_allgather(double *all, const long *counts, Err *err) {
#ifdef NPG_HAVE_MPI
  if (!started || size_ == 1) return 0;
  Scratch s = SCRATCH_OF(err);
  int *cnt = scratch_array(&s, (size_t)size_, sizeof(int)), *displ = scratch_array(&s, (size_t)size_, sizeof(int));
  long at = 0;
  int rc = 0;
  if (!cnt || !displ) rc = err_set(err, "out of memory gathering the ranks' blocks");
  for (int r = 0; rc == 0 && r < size_; r++) {
    if (counts[r] > INT_MAX || at > INT_MAX)
      rc = err_set(err, "a block of %ld entries is more than one MPI call gathers", counts[r]);
    else cnt[r] = (int)counts[r], displ[r] = (int)at;
    at += counts[r];
  }
  /* every rank reaches the collective, even one whose counts were refused,
   * so that no other rank waits for it: all refuse alike */
  if (rc == 0) MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_DATATYPE_NULL, all, cnt, displ, MPI_DOUBLE, MPI_COMM_WORLD);
  scratch_release(&s);
  return rc;
#else
  (void)all, (void)counts, (void)err;
  return 0;
#endif
}

void dist_broadcast(double *x, long n, int root) {
#ifdef NPG_HAVE_MPI
  if (!started || size_ == 1) return;
  for (long i = 0; i < n; i += 1L << 28) {
    long c = n - i < 1L << 28 ? n - i : 1L << 28;
    MPI_Bcast(x + i, (int)c, MPI_DOUBLE, root, MPI_COMM_WORLD);
  }
#else
  (void)x, (void)n, (void)root;
#endif
}

void dist_broadcast_bytes(void *p, long n, int root) {
#ifdef NPG_HAVE_MPI
  if (!started || size_ == 1) return;
  for (long i = 0; i < n; i += 1L << 30) {
    long c = n - i < 1L << 30 ? n - i : 1L << 30;
    MPI_Bcast((char *)p + i, (int)c, MPI_BYTE, root, MPI_COMM_WORLD);
  }
#else
  (void)p, (void)n, (void)root;
#endif
}

void dist_barrier(void) {
#ifdef NPG_HAVE_MPI
  if (started && size_ > 1) MPI_Barrier(MPI_COMM_WORLD);
#endif
}

_Noreturn void dist_abort(const char *fmt, ...) {
  char msg[4096];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  fprintf(stderr, "npg: rank %d of %d failed: %s\n", rank_, size_, msg);
  fflush(stderr);
#ifdef NPG_HAVE_MPI
  if (started) MPI_Abort(MPI_COMM_WORLD, 1);
#endif
  exit(1);
}

bool dist_fail_here(void) {
  const char *v = getenv("NPG_MPI_FAIL_RANK");
  if (!started || !v || !*v) return false;
  char *end;
  long k = strtol(v, &end, 10);
  if (end == v || k != rank_) return false;
  if (strcmp(end, ":kill") == 0) raise(SIGKILL); /* dies without a word, as a crashed node */
  return !*end;
}
