/* test_dist.c — the ranks training runs on (backends/train/dist.c) in one
 * process, before any MPI: rank 0 of 1, every collective leaves its data as
 * it is, the failure test hook stays off, a build without MPI refuses to
 * start naming what to install, and dist_abort ends the process with status
 * 1 after one line naming the rank. (Over ranks: tests/mpi.) */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>

#include "dist.h"

static void one_process_collectives_keep_data(void **state) {
  (void)state;
  assert_int_equal(dist_rank(), 0);
  assert_int_equal(dist_size(), 1);
  double x[4] = {1.5, -2, 0, 1e300}, want[4];
  memcpy(want, x, sizeof x);
  dist_allreduce_sum(x, 4);
  dist_allreduce_max(x, 4);
  dist_broadcast(x, 4, 0);
  dist_broadcast_bytes(x, sizeof x, 0);
  assert_memory_equal(x, want, sizeof x);
  long counts[1] = {4};
  char err[256] = "";
  assert_int_equal(dist_allgather(x, counts, ERR_OF(err, sizeof err)), 0);
  assert_memory_equal(x, want, sizeof x);
  assert_string_equal(err, "");
  dist_barrier();
}

static void fail_hook_off_before_start(void **state) {
  (void)state;
  setenv("NPG_MPI_FAIL_RANK", "0", 1);
  assert_false(dist_fail_here()); /* only after dist_start */
  unsetenv("NPG_MPI_FAIL_RANK");
  assert_false(dist_fail_here());
}

static void start_without_mpi_says_what_to_install(void **state) {
  (void)state;
  if (dist_available()) skip(); /* MPI_Init in a unit test: tests/mpi runs it */
  char err[512] = "";
  assert_int_equal(dist_start(ERR_OF(err, sizeof err)), -1);
  assert_non_null(strstr(err, "no MPI"));
  assert_non_null(strstr(err, "libopenmpi-dev"));
  assert_int_equal(dist_size(), 1);
}

static void abort_in_one_process(void **state) {
  (void)state;
  int fd[2];
  assert_int_equal(pipe(fd), 0);
  fflush(NULL);
  pid_t pid = fork();
  assert_true(pid >= 0);
  if (pid == 0) {
    dup2(fd[1], 2);
    close(fd[0]);
    dist_abort("sample %d: %s", 7, "no value");
  }
  close(fd[1]);
  char buf[512] = "";
  size_t n = 0;
  ssize_t got;
  while (n + 1 < sizeof buf && (got = read(fd[0], buf + n, sizeof buf - 1 - n)) > 0) n += (size_t)got;
  buf[n] = 0;
  close(fd[0]);
  int status = 0;
  assert_int_equal(waitpid(pid, &status, 0), pid);
  assert_true(WIFEXITED(status));
  assert_int_equal(WEXITSTATUS(status), 1);
  assert_string_equal(buf, "npg: rank 0 of 1 failed: sample 7: no value\n");
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(one_process_collectives_keep_data),
      cmocka_unit_test(fail_hook_off_before_start),
      cmocka_unit_test(start_without_mpi_says_what_to_install),
      cmocka_unit_test(abort_in_one_process),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
