/* util.h — what the example's files share: folders made with their parents,
 * a monotonic clock, and the step of a chart's ticks. (A message into a
 * caller's buffer is npg.h's npg_error_set.) */
#ifndef EXAMPLES_UTIL_H
#define EXAMPLES_UTIL_H

#include <stddef.h>

/* mkdir -p `path`: every missing parent too (a writer creates the folders
 * it writes into, as npgc -o does). 0, or -1 with "PATH: problem" in `err`. */
int util_make_dirs(const char *path, char *err, size_t errlen);
/* A program's exit status once its standard output is flushed: `rc`, or 1
 * (rc when already non-zero) after "PROG: cannot write to standard output"
 * when the output did not reach it (a full disk, /dev/full, a closed pipe):
 * a report that was not written is a failure (issue 24). */
int util_exit_status(const char *prog, int rc);
/* Seconds on a monotonic clock. */
double util_now(void);
/* Streaming read bandwidth in GB/s over a buffer of `bytes`: npg_read_bandwidth (npg.h). */
double util_read_bandwidth(size_t bytes, double min_seconds);
/* A round tick step (1, 2 or 5 times a power of ten) giving about `want` ticks over
 * `range` (> 0); a chart whose axis is a count rounds it up to 1. */
double util_tick_step(double range, int want);

#endif
