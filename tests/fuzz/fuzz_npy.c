/* fuzz_npy.c — libFuzzer target for the .npy reader (stdlib/runtime/npy.c).
 *
 * npy_read takes a path, so each input goes to a memfd, read through
 * /proc/self/fd/N: a regular file of the input's size, like a file on disk,
 * with no file system traffic. The npy.h contract is checked on every
 * input: a failure leaves the array zeroed and a message that starts with
 * the path; a success has data (even when empty), a count equal to the
 * product of the shape, and writes back (npy_write, into a per-process
 * folder under /dev/shm) as a file that reads back to the same array.
 *
 * Seeds: tests/data/npy (scripts/test.sh) and tests/fuzz/seeds_npy (what
 * this target found, kept as regression inputs).
 */
#define _GNU_SOURCE /* memfd_create */

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "npy.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int input_fd = -1;
static char input_path[64], out_dir[128], out_path[160];

static void remove_out_dir(void) {
  unlink(out_path);
  rmdir(out_dir);
}

static void setup(void) {
  input_fd = memfd_create("fuzz_npy_input", 0);
  if (input_fd < 0) abort();
  snprintf(input_path, sizeof input_path, "/proc/self/fd/%d", input_fd);
  snprintf(out_dir, sizeof out_dir, "/dev/shm/npg_fuzz_npy.%ld", (long)getpid());
  snprintf(out_path, sizeof out_path, "%s/round_trip.npy", out_dir);
  if (mkdir(out_dir, 0700) != 0) abort();
  atexit(remove_out_dir);
}

static size_t element_size(NpyType t) { return t == NPY_I32 ? 4 : 8; }

static void check(int ok, const char *what) {
  if (!ok) {
    fprintf(stderr, "npy.h contract broken: %s\n", what);
    abort();
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (input_fd < 0) setup();
  if (ftruncate(input_fd, 0) != 0 || pwrite(input_fd, data, size, 0) != (ssize_t)size) abort();

  NpyArray a;
  char err[512];
  if (npy_read(input_path, &a, err, sizeof err) != 0) {
    static const NpyArray zero;
    check(memcmp(&a, &zero, sizeof a) == 0, "a failed read leaves the array zeroed");
    check(strncmp(err, input_path, strlen(input_path)) == 0 && err[strlen(input_path)] == ':',
          "a failure message starts with the path");
    return 0;
  }
  check(a.data != NULL, "a successful read has data");
  check(a.ndim >= 0 && a.ndim <= NPY_MAX_DIMS, "ndim in range");
  size_t count = 1;
  for (int i = 0; i < a.ndim; i++) {
    check(a.shape[i] >= 0, "no negative extent");
    count *= (size_t)a.shape[i];
  }
  check(count == a.count, "count is the product of the shape");

  /* what was read writes back and reads back the same */
  check(npy_write(out_path, a.type, a.ndim, a.shape, a.data, err, sizeof err) == 0, "the array writes back");
  NpyArray b;
  check(npy_read(out_path, &b, err, sizeof err) == 0, "what npy_write wrote reads back");
  check(b.type == a.type && b.ndim == a.ndim && b.count == a.count &&
            memcmp(b.shape, a.shape, sizeof a.shape[0] * (size_t)a.ndim) == 0 &&
            memcmp(b.data, a.data, a.count * element_size(a.type)) == 0,
        "the array read back equals the one written");
  npy_free(&b);
  npy_free(&a);
  return 0;
}
