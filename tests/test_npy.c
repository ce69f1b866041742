/* test_npy.c — stdlib/runtime/npy.c: .npy arrays on disk (DESIGN §2, §10).
 *
 * The oracle is numpy itself: the files in tests/data/npy were written by numpy
 * (tests/data/npy/make_fixtures.py), npy_read must read them to the values
 * listed there, and npy_write must reproduce them byte for byte. Every way a
 * file can be wrong has its exact message here, and every prefix and
 * single-byte corruption of a valid file is read without a crash (these
 * tests run under ASan/UBSan in CI). Scratch files go to a fresh directory
 * under $TMPDIR, removed at the end. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp, mkfifo, fork */

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>

#include "npy.h"
#include "testutil.h"

#define FIXTURES "tests/data/npy/"
#define SUPPORTED "(supported: '<f8' float64, '<i4' int32, '<i8' int64)"

/* ---------------------------------------------------------------- scratch files */

static int make_scratch(void **state) {
  (void)state;
  return scratch_make("npg_test_npy");
}

static int remove_scratch(void **state) {
  (void)state;
  remove_tree(scratch);
  return 0;
}

/* A .npy file: magic, version `major`.0, `header` verbatim, then `datalen`
 * bytes of `data` (zeros when NULL). Returns its size. */
static size_t build_npy(unsigned char *out, int major, const char *header, const void *data, size_t datalen) {
  size_t hlen = strlen(header), n = 0;
  memcpy(out, "\x93NUMPY", 6);
  out[6] = (unsigned char)major;
  out[7] = 0;
  n = 8;
  out[n++] = (unsigned char)(hlen & 0xff);
  out[n++] = (unsigned char)(hlen >> 8);
  if (major > 1) {
    out[n++] = 0;
    out[n++] = 0;
  }
  memcpy(out + n, header, hlen);
  n += hlen;
  if (data) memcpy(out + n, data, datalen);
  else memset(out + n, 0, datalen);
  return n + datalen;
}

/* npy_read(`path`) fails with exactly "<path>: <problem>" and leaves the
 * array zeroed. `what` names the case in a failure. */
static void expect_read_error(const char *what, const char *path, const char *problem) {
  NpyArray a;
  char err[512], want[1024];
  memset(&a, 0x5a, sizeof a);
  int rc = npy_read(path, &a, err, sizeof err);
  snprintf(want, sizeof want, "%s: %s", path, problem);
  if (rc == 0) fail_msg("%s: read succeeded, expected \"%s\"", what, want);
  if (strcmp(err, want) != 0) fail_msg("%s:\n   got \"%s\"\n  want \"%s\"", what, err, want);
  if (a.data || a.count || a.ndim) fail_msg("%s: array not zeroed after an error", what);
  npy_free(&a);
}

static NpyArray read_ok(const char *path) {
  NpyArray a;
  char err[512];
  if (npy_read(path, &a, err, sizeof err) != 0) fail_msg("%s", err);
  assert_non_null(a.data);
  return a;
}

/* ---------------------------------------------------------------- numpy's files */

/* float64 compared bit for bit (signed zero included); NaN only as NaN —
 * its payload is the platform's, and NaN is not the reader's business. */
static void assert_f64_equal(const double *got, const double *want, size_t n) {
  for (size_t i = 0; i < n; i++) {
    if (isnan(want[i]) ? isnan(got[i]) : memcmp(&got[i], &want[i], sizeof(double)) == 0) continue;
    fail_msg("element %zu: %.17g, expected %.17g", i, got[i], want[i]);
  }
}

static void read_numpy_float64(void **state) {
  (void)state;
  NpyArray a = read_ok(FIXTURES "f64_3x4.npy");
  assert_int_equal(a.type, NPY_F64);
  assert_int_equal(a.ndim, 2);
  assert_int_equal(a.shape[0], 3);
  assert_int_equal(a.shape[1], 4);
  assert_int_equal(a.count, 12);
  const double want[12] = {-1.5, 0.0, -0.0, 2.25, 1e-300, 1e300, INFINITY, -INFINITY, NAN, 3.0, 0.1, -7.0};
  assert_f64_equal(a.data, want, 12);
  npy_free(&a);

  a = read_ok(FIXTURES "f64_0d.npy");
  assert_int_equal(a.ndim, 0);
  assert_int_equal(a.count, 1);
  assert_true(*(double *)a.data == 2.5);
  npy_free(&a);

  a = read_ok(FIXTURES "f64_0x3.npy");
  assert_int_equal(a.ndim, 2);
  assert_int_equal(a.shape[0], 0);
  assert_int_equal(a.shape[1], 3);
  assert_int_equal(a.count, 0);
  npy_free(&a);
  assert_null(a.data);
  npy_free(&a); /* twice is harmless */
}

static void read_numpy_integers(void **state) {
  (void)state;
  NpyArray a = read_ok(FIXTURES "i32_5.npy");
  assert_int_equal(a.type, NPY_I32);
  assert_int_equal(a.ndim, 1);
  assert_int_equal(a.shape[0], 5);
  const int32_t want32[5] = {INT32_MIN, -1, 0, 7, INT32_MAX};
  assert_memory_equal(a.data, want32, sizeof want32);
  npy_free(&a);

  a = read_ok(FIXTURES "i64_2x1x3.npy");
  assert_int_equal(a.type, NPY_I64);
  assert_int_equal(a.ndim, 3);
  assert_int_equal(a.shape[0], 2);
  assert_int_equal(a.shape[1], 1);
  assert_int_equal(a.shape[2], 3);
  const int64_t want64[6] = {INT64_MIN, -1, 0, 1, (int64_t)1 << 40, INT64_MAX};
  assert_memory_equal(a.data, want64, sizeof want64);
  npy_free(&a);
}

/* Format 2.0 and 3.0: a 4-byte header length. */
static void read_numpy_versions(void **state) {
  (void)state;
  NpyArray a = read_ok(FIXTURES "f64_v2.npy");
  assert_int_equal(a.ndim, 1);
  const double want[3] = {1.0, -2.0, 0.5};
  assert_f64_equal(a.data, want, 3);
  npy_free(&a);

  a = read_ok(FIXTURES "i64_v3.npy");
  assert_int_equal(a.type, NPY_I64);
  assert_int_equal(a.ndim, 2);
  assert_int_equal(a.shape[0], 1);
  assert_int_equal(a.shape[1], 2);
  const int64_t want64[2] = {5, -6};
  assert_memory_equal(a.data, want64, sizeof want64);
  npy_free(&a);
}

static void refuse_numpy_files(void **state) {
  (void)state;
  static const struct {
    const char *file, *problem;
  } cases[] = {
      {"f64_fortran_2x3.npy", "Fortran-order arrays are not supported; save with numpy.ascontiguousarray"},
      {"f64_big_endian.npy", "big-endian dtype '>f8' is not supported; convert with a.astype('<f8')"},
      {"f32.npy", "unsupported dtype '<f4' " SUPPORTED},
      {"c16.npy", "unsupported dtype '<c16' " SUPPORTED},
      {"object.npy", "unsupported dtype '|O' " SUPPORTED},
  };
  char path[512];
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    snprintf(path, sizeof path, FIXTURES "%s", cases[i].file);
    expect_read_error(cases[i].file, path, cases[i].problem);
  }
}

/* What npy_write makes of numpy's arrays is numpy's file, byte for byte —
 * so numpy loads everything npgc writes. */
static void write_matches_numpy(void **state) {
  (void)state;
  const char *files[] = {"f64_3x4.npy",   "f64_0d.npy",      "f64_0x3.npy",
                         "i32_5.npy",     "i64_2x1x3.npy",   "f64_pad1_header.npy",
                         "f64_pad64_header.npy"};
  char out[512], err[512];
  for (size_t i = 0; i < sizeof files / sizeof *files; i++) {
    char in[512];
    snprintf(in, sizeof in, FIXTURES "%s", files[i]);
    NpyArray a = read_ok(in);
    if (npy_write(scratch_path(out, files[i]), a.type, a.ndim, a.shape, a.data, err, sizeof err) != 0)
      fail_msg("%s", err);
    size_t n_numpy, n_ours;
    unsigned char *numpy = (unsigned char *)slurp(in, &n_numpy), *ours = (unsigned char *)slurp(out, &n_ours);
    if (n_numpy != n_ours || memcmp(numpy, ours, n_ours) != 0)
      fail_msg("%s: npy_write's bytes differ from numpy's (%zu vs %zu bytes)", files[i], n_ours, n_numpy);
    free(numpy);
    free(ours);
    npy_free(&a);
  }
}

/* ---------------------------------------------------------------- round trips */

static void round_trip(NpyType type, int ndim, const long *shape) {
  size_t count = 1, size = type == NPY_I32 ? 4 : 8;
  for (int i = 0; i < ndim; i++) count *= (size_t)shape[i];
  unsigned char *data = malloc(count * size + 1);
  for (size_t i = 0; i < count; i++) {
    /* distinct, sign-mixed values that use every byte */
    int64_t v = (int64_t)(i * 0x0123456789abcdefULL) ^ (i % 2 ? INT64_MIN : 0);
    if (type == NPY_F64) {
      double d = (double)v / 7.0;
      memcpy(data + i * size, &d, size);
    } else if (type == NPY_I32) {
      int32_t w = (int32_t)(uint32_t)v;
      memcpy(data + i * size, &w, size);
    } else {
      memcpy(data + i * size, &v, size);
    }
  }
  char path[512], err[512], name[64];
  snprintf(name, sizeof name, "rt_%s_%dd.npy", npy_type_name(type), ndim);
  if (npy_write(scratch_path(path, name), type, ndim, shape, data, err, sizeof err) != 0) fail_msg("%s", err);

  /* numpy's layout: version 1.0, the data on a 64-byte boundary after '\n' */
  size_t n;
  unsigned char *file = (unsigned char *)slurp(path, &n);
  size_t start = 10 + (size_t)(file[8] | file[9] << 8);
  assert_memory_equal(file, "\x93NUMPY\x01\x00", 8);
  assert_int_equal(start % 64, 0);
  assert_int_equal(file[start - 1], '\n');
  assert_int_equal(n, start + count * size);
  free(file);

  NpyArray a = read_ok(path);
  assert_int_equal(a.type, type);
  assert_int_equal(a.ndim, ndim);
  for (int i = 0; i < ndim; i++) assert_int_equal(a.shape[i], shape[i]);
  assert_int_equal(a.count, count);
  assert_memory_equal(a.data, data, count * size);
  npy_free(&a);
  free(data);
}

static void write_read_round_trip(void **state) {
  (void)state;
  const long one[1] = {5}, three[3] = {2, 3, 4}, empty[2] = {0, 7}, wide[1] = {123457};
  for (NpyType t = NPY_F64; t <= NPY_I64; t++) {
    round_trip(t, 0, NULL);
    round_trip(t, 1, one);
    round_trip(t, 3, three);
    round_trip(t, 2, empty);
  }
  round_trip(NPY_F64, 1, wide);
  const long eight[8] = {1, 2, 1, 2, 1, 2, 1, 3};
  round_trip(NPY_I32, 8, eight);
}

/* Leftover "<name>.tmp.<pid>" files in the scratch directory. */
static int leftover_temporaries(void) {
  DIR *d = opendir(scratch);
  int n = 0;
  struct dirent *e;
  while ((e = readdir(d))) n += strstr(e->d_name, ".tmp.") != NULL;
  closedir(d);
  return n;
}

static void write_replaces_whole_file(void **state) {
  (void)state;
  char path[512], err[512];
  const double big[6] = {1, 2, 3, 4, 5, 6};
  const int32_t small[1] = {42};
  const long six[1] = {6}, one[1] = {1};
  scratch_path(path, "replaced.npy");
  assert_int_equal(npy_write(path, NPY_F64, 1, six, big, err, sizeof err), 0);
  assert_int_equal(npy_write(path, NPY_I32, 1, one, small, err, sizeof err), 0);
  NpyArray a = read_ok(path);
  assert_int_equal(a.type, NPY_I32);
  assert_int_equal(a.count, 1);
  assert_int_equal(*(int32_t *)a.data, 42);
  npy_free(&a);
  assert_int_equal(leftover_temporaries(), 0);
}

static void write_errors(void **state) {
  (void)state;
  char path[512], err[512], want[1200];
  const double x[2] = {1, 2};
  const long two[1] = {2};

  /* the directory does not exist: the temporary cannot be created */
  scratch_path(path, "no_such_dir/a.npy");
  assert_int_not_equal(npy_write(path, NPY_F64, 1, two, x, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s: cannot create %s.tmp.%ld: %s", path, path, (long)getpid(), strerror(ENOENT));
  assert_string_equal(err, want);

  /* a directory is in the way: refused before anything is written */
  scratch_path(path, "a_directory");
  assert_int_equal(mkdir(path, 0700), 0);
  assert_int_not_equal(npy_write(path, NPY_F64, 1, two, x, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s: is not a regular file (a directory): refusing to replace it", path);
  assert_string_equal(err, want);
  assert_int_equal(leftover_temporaries(), 0);
  struct stat st;
  assert_int_equal(stat(path, &st), 0);
  assert_true(S_ISDIR(st.st_mode));

  /* lost data (issue 24): a symbolic link or a FIFO at the path is not
   * replaced (the rename would put a file in its place) */
  char target[600];
  scratch_path(target, "target.npy");
  assert_int_equal(npy_write(target, NPY_F64, 1, two, x, err, sizeof err), 0);
  scratch_path(path, "a_link.npy");
  assert_int_equal(symlink(target, path), 0);
  assert_int_not_equal(npy_write(path, NPY_F64, 1, two, x, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s: is not a regular file (a symbolic link): refusing to replace it", path);
  assert_string_equal(err, want);
  assert_int_equal(lstat(path, &st), 0);
  assert_true(S_ISLNK(st.st_mode));
  scratch_path(path, "a_fifo.npy");
  assert_int_equal(mkfifo(path, 0600), 0);
  assert_int_not_equal(npy_write(path, NPY_F64, 1, two, x, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s: is not a regular file (a FIFO, socket or device node): refusing to replace it", path);
  assert_string_equal(err, want);
  assert_int_equal(lstat(path, &st), 0);
  assert_true(S_ISFIFO(st.st_mode));
  assert_int_equal(leftover_temporaries(), 0);

  /* arguments that describe no array; nothing is created */
  scratch_path(path, "never.npy");
  static const long nine[9] = {1, 1, 1, 1, 1, 1, 1, 1, 1}, negative[2] = {3, -2}, one[1] = {1};
  static const struct {
    NpyType type;
    int ndim;
    const long *shape;
    const char *problem;
  } cases[] = {
      {NPY_F64, 9, nine, "cannot write 9 dimensions; at most 8 are supported"},
      {NPY_F64, -1, nine, "cannot write -1 dimensions; at most 8 are supported"},
      {NPY_F64, 2, negative, "cannot write: shape entry 1 is negative (-2)"},
      {(NpyType)7, 1, one, "cannot write: invalid element type 7"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    assert_int_not_equal(npy_write(path, cases[i].type, cases[i].ndim, cases[i].shape, x, err, sizeof err), 0);
    snprintf(want, sizeof want, "%s: %s", path, cases[i].problem);
    assert_string_equal(err, want);
  }
  assert_int_not_equal(npy_write(path, NPY_F64, 1, two, NULL, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s: cannot write: no data for 2 elements", path);
  assert_string_equal(err, want);
  assert_int_equal(access(path, F_OK), -1);
}

/* ---------------------------------------------------------------- bad files */

static void unreadable_files(void **state) {
  (void)state;
  char path[512], want[600];
  scratch_path(path, "does_not_exist.npy");
  snprintf(want, sizeof want, "cannot open: %s", strerror(ENOENT));
  expect_read_error("missing file", path, want);
  snprintf(want, sizeof want, "cannot read: %s", strerror(EISDIR));
  expect_read_error("directory", scratch, want);
}

/* Files that fail before or in the header length, byte for byte. */
static void bad_prefixes(void **state) {
  (void)state;
  static const struct {
    const char *bytes;
    size_t n;
    const char *problem;
  } cases[] = {
      {"", 0, "empty file"},
      {"hello, world\n", 13, "not a .npy file (bad magic)"},
      {"\x93NUMPz\x01\x00\x10\x00", 10, "not a .npy file (bad magic)"},
      {"PK\x03\x04", 4, "not a .npy file (bad magic)"},
      {"\x93NUM", 4, "truncated header: expected 8 bytes, found 4"},
      {"\x93NUMPY\x01", 7, "truncated header: expected 8 bytes, found 7"},
      {"\x93NUMPY\x04\x00\x10\x00", 10, "unsupported .npy format version 4.0 (supported: 1.0, 2.0, 3.0)"},
      {"\x93NUMPY\x01\x01\x10\x00", 10, "unsupported .npy format version 1.1 (supported: 1.0, 2.0, 3.0)"},
      {"\x93NUMPY\x00\x00\x10\x00", 10, "unsupported .npy format version 0.0 (supported: 1.0, 2.0, 3.0)"},
      {"\x93NUMPY\x01\x00\x10", 9, "truncated header: expected 10 bytes, found 9"},
      {"\x93NUMPY\x02\x00\x10\x00", 10, "truncated header: expected 12 bytes, found 10"},
      {"\x93NUMPY\x01\x00\x76\x00{'descr'", 18, "truncated header: expected 128 bytes, found 18"},
      {"\x93NUMPY\x03\x00\x76\x00\x00\x00", 12, "truncated header: expected 130 bytes, found 12"},
      {"\x93NUMPY\x02\x00\x11\x27\x00\x00{", 13, "header of 10001 bytes is too long (numpy.load's limit is 10000)"},
      {"\x93NUMPY\x03\x00\xff\xff\xff\xff", 12, "header of 4294967295 bytes is too long (numpy.load's limit is 10000)"},
  };
  char path[512], what[32];
  scratch_path(path, "prefix.npy");
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    write_file(path, cases[i].bytes, cases[i].n);
    snprintf(what, sizeof what, "prefix case %zu", i);
    expect_read_error(what, path, cases[i].problem);
  }
}

#define HDR(shape) "{'descr': '<f8', 'fortran_order': False, 'shape': " shape ", }"

/* Headers numpy would not have written, each with its message. */
static void bad_headers(void **state) {
  (void)state;
  static const struct {
    int major;
    const char *header;
    size_t datalen;
    const char *problem;
  } cases[] = {
      /* not a dict, or not the dict numpy.load wants */
      {1, "[1, 2]", 0, "header is not a dict: [1, 2]"},
      {1, "  \n", 0, "header is not a dict: it is blank"},
      {1, "", 0, "header is not a dict: it is blank"},
      {1, "\x01\xff{", 0, "header is not a dict: \\x01\\xff{"},
      {1, "{'descr': '<f8', 'fortran_order': False, }", 8, "header has no 'shape' key"},
      {1, "{'shape': (), 'fortran_order': False}", 8, "header has no 'descr' key"},
      {1, "{}", 8, "header has no 'descr' key"},
      {1, "{'descr': '<f8', 'fortran_order': False, 'shape': (), 'extra': 1}", 8, "header has unexpected key 'extra'"},
      {1, "{'shape': (), 'descr': '<f8', 'shape': (), 'fortran_order': False}", 8, "header has key 'shape' twice"},
      /* Python syntax */
      {1, "{'descr' '<f8'}", 8, "malformed header dict at byte 9: expected ':'"},
      {1, "{'descr': '<f8' 'shape': ()}", 8, "malformed header dict at byte 16: expected ',' or '}'"},
      {1, "{'descr': '<f8', 'fortran_order': False, 'shape': (), } x", 8,
       "malformed header dict at byte 56: unexpected text after '}'"},
      {1, "{'descr': '<f8', 'fortran_order': False, 'shape': (3, 4]}", 96,
       "malformed header dict at byte 50: cannot parse the value of 'shape'"},
      {1, "{'descr': '<f8", 8, "malformed header dict at byte 10: cannot parse the value of 'descr'"},
      {1, "{'descr", 8, "malformed header dict at byte 1: unterminated string"},
      {1, "{descr: '<f8'}", 8, "malformed header dict at byte 1: expected a quoted key or '}'"},
      {1, "{'descr': '<f8',, }", 8, "malformed header dict at byte 16: expected a quoted key or '}'"},
      {1, "{'descr': '<f8'", 8, "malformed header dict at byte 15: expected ',' or '}'"},
      {1, "{,}", 8, "malformed header dict at byte 1: expected a quoted key or '}'"},
      /* fortran_order */
      {1, "{'descr': '<f8', 'fortran_order': 'yes', 'shape': ()}", 8, "'fortran_order' is not True or False: 'yes'"},
      {1, "{'descr': '<f8', 'fortran_order': 0, 'shape': ()}", 8, "'fortran_order' is not True or False: 0"},
      {1, "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 1, 3)}", 48,
       "Fortran-order arrays are not supported; save with numpy.ascontiguousarray"},
      /* descr */
      {1, "{'descr': '>i4', 'fortran_order': False, 'shape': ()}", 4,
       "big-endian dtype '>i4' is not supported; convert with a.astype('<i4')"},
      {1, "{'descr': '>i8', 'fortran_order': False, 'shape': ()}", 8,
       "big-endian dtype '>i8' is not supported; convert with a.astype('<i8')"},
      {1, "{'descr': '|f8', 'fortran_order': False, 'shape': ()}", 8, "unsupported dtype '|f8' " SUPPORTED},
      {1, "{'descr': '<u8', 'fortran_order': False, 'shape': ()}", 8, "unsupported dtype '<u8' " SUPPORTED},
      {1, "{'descr': '|b1', 'fortran_order': False, 'shape': ()}", 1, "unsupported dtype '|b1' " SUPPORTED},
      {1, "{'descr': '<f8 ', 'fortran_order': False, 'shape': ()}", 8, "unsupported dtype '<f8 ' " SUPPORTED},
      {1, "{'descr': '<f\\'8', 'fortran_order': False, 'shape': ()}", 8, "unsupported dtype '<f\\'8' " SUPPORTED},
      {1, "{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': ()}", 8,
       "unsupported dtype [('a', '<f8')] " SUPPORTED},
      {1, "{'descr': 8, 'fortran_order': False, 'shape': ()}", 8, "unsupported dtype 8 " SUPPORTED},
      /* shape */
      {1, HDR("[3]"), 24, "'shape' is not a tuple of integers: [3]"},
      {1, HDR("3"), 24, "'shape' is not a tuple of integers: 3"},
      {1, HDR("(3)"), 24, "'shape' is not a tuple of integers: (3)"},
      {1, HDR("(3 4)"), 96, "'shape' is not a tuple of integers: (3 4)"},
      {1, HDR("(3,,)"), 24, "'shape' is not a tuple of integers: (3,,)"},
      {1, HDR("(,)"), 8, "'shape' is not a tuple of integers: (,)"},
      {1, HDR("(2, -3)"), 48, "shape entry -3 is negative"},
      {1, HDR("(3.5,)"), 24, "shape entry 3.5 is not an integer"},
      {1, HDR("(None,)"), 24, "shape entry None is not an integer"},
      {1, HDR("('3',)"), 24, "shape entry '3' is not an integer"},
      {1, HDR("((3,),)"), 24, "shape entry (3,) is not an integer"},
      {1, HDR("(0x10,)"), 128, "shape entry 0x10 is not an integer"},
      {1, HDR("(1__0,)"), 80, "shape entry 1__0 is not an integer"},
      {1, HDR("(-,)"), 80, "shape entry - is not an integer"},
      {3, HDR("(3L,)"), 24, "shape entry 3L is not an integer"}, /* Python 2 longs predate format 3.0 */
      {1, HDR("(9223372036854775808,)"), 8, "shape entry 9223372036854775808 is too large"},
      {1, HDR("(99999999999999999999999999,)"), 8, "shape entry 99999999999999999999999999 is too large"},
      {1, HDR("(9223372036854775807,)"), 8, "shape (9223372036854775807,) has too many elements"},
      {1, HDR("(4294967296, 4294967296)"), 8, "shape (4294967296, 4294967296) has too many elements"},
      {1, HDR("(1, 1, 1, 1, 1, 1, 1, 1, 1)"), 8,
       "shape (1, 1, 1, 1, 1, 1, 1, 1, 1) has 9 dimensions; at most 8 are supported"},
      /* data */
      {1, HDR("(3,)"), 16, "truncated: expected 24 bytes of data, found 16"},
      {1, HDR("(3,)"), 0, "truncated: expected 24 bytes of data, found 0"},
      {1, HDR("(1000000000000,)"), 8, "truncated: expected 8000000000000 bytes of data, found 8"},
      {1, HDR("(3,)"), 25, "trailing garbage: expected 24 bytes of data, found 25"},
      {1, HDR("()"), 16, "trailing garbage: expected 8 bytes of data, found 16"},
      {1, HDR("(0, 5)"), 1, "trailing garbage: expected 0 bytes of data, found 1"},
  };
  static unsigned char file[4096];
  char path[512], what[300];
  scratch_path(path, "header.npy");
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    write_file(path, file, build_npy(file, cases[i].major, cases[i].header, NULL, cases[i].datalen));
    snprintf(what, sizeof what, "header case %zu: %s", i, cases[i].header);
    expect_read_error(what, path, cases[i].problem);
  }
}

/* Headers numpy never writes but a Python literal allows, and what
 * numpy.load also accepts. */
static void good_headers(void **state) {
  (void)state;
  static const struct {
    int major;
    const char *header;
    NpyType type;
    int ndim;
    long shape[3];
  } cases[] = {
      {1, "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", NPY_F64, 2, {2, 3}},
      {1, "{'shape':(2,3),'fortran_order':False,'descr':'<i8'}", NPY_I64, 2, {2, 3}},
      {1, " \t{ \"descr\" : \"<i4\" ,\n 'shape' : ( 6 , ) , 'fortran_order' : False , } \n \n", NPY_I32, 1, {6}},
      {1, "{'descr': '=f8', 'fortran_order': False, 'shape': ()}", NPY_F64, 0, {0}},
      {1, "{'descr': '=i4', 'fortran_order': False, 'shape': (1, 2, 3,)}", NPY_I32, 3, {1, 2, 3}},
      {1, "{'descr': '<i4', 'fortran_order': False, 'shape': (+2, 3)}", NPY_I32, 2, {2, 3}},
      {1, "{'descr': '<i4', 'fortran_order': False, 'shape': (1_2,)}", NPY_I32, 1, {12}},
      {1, "{'descr': '<i4', 'fortran_order': False, 'shape': (2L, 3l)}", NPY_I32, 2, {2, 3}},
      {2, "{'descr': '<i4', 'fortran_order': False, 'shape': (6L,)}", NPY_I32, 1, {6}},
      {3, "{'descr': '<i4', 'fortran_order': False, 'shape': (6,)}", NPY_I32, 1, {6}},
      /* Fortran order with one long axis is C order */
      {1, "{'descr': '<f8', 'fortran_order': True, 'shape': (6,)}", NPY_F64, 1, {6}},
      {1, "{'descr': '<f8', 'fortran_order': True, 'shape': (1, 6, 1)}", NPY_F64, 3, {1, 6, 1}},
      {1, "{'descr': '<f8', 'fortran_order': True, 'shape': ()}", NPY_F64, 0, {0}},
      {1, "{'descr': '<f8', 'fortran_order': True, 'shape': (0, 5)}", NPY_F64, 2, {0, 5}},
  };
  static unsigned char file[4096];
  unsigned char data[64];
  for (size_t i = 0; i < sizeof data; i++) data[i] = (unsigned char)(i * 37 + 1);
  char path[512];
  scratch_path(path, "good.npy");
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    size_t count = 1, size = cases[i].type == NPY_I32 ? 4 : 8;
    for (int d = 0; d < cases[i].ndim; d++) count *= (size_t)cases[i].shape[d];
    write_file(path, file, build_npy(file, cases[i].major, cases[i].header, data, count * size));
    NpyArray a;
    char err[512];
    if (npy_read(path, &a, err, sizeof err) != 0) fail_msg("good header %zu: %s", i, err);
    assert_int_equal(a.type, cases[i].type);
    assert_int_equal(a.ndim, cases[i].ndim);
    for (int d = 0; d < a.ndim; d++) assert_int_equal(a.shape[d], cases[i].shape[d]);
    assert_int_equal(a.count, count);
    assert_memory_equal(a.data, data, count * size);
    npy_free(&a);
  }
}

/* A message that does not fit is cut, still terminated; no buffer at all is
 * allowed. */
static void small_error_buffers(void **state) {
  (void)state;
  char path[512], err[8];
  NpyArray a;
  scratch_path(path, "does_not_exist.npy");
  memset(err, 'x', sizeof err);
  assert_int_not_equal(npy_read(path, &a, err, sizeof err), 0);
  assert_int_equal(strlen(err), sizeof err - 1);
  assert_memory_equal(err, path, sizeof err - 1);
  assert_int_not_equal(npy_read(path, &a, NULL, 0), 0);
  assert_int_not_equal(npy_read(path, &a, err, 0), 0);
  assert_string_equal(npy_type_name(NPY_F64), "float64");
  assert_string_equal(npy_type_name(NPY_I32), "int32");
  assert_string_equal(npy_type_name(NPY_I64), "int64");
}

/* ---------------------------------------------------------------- streams */

/* npy_read from a FIFO fed `n` `bytes` by a child process: the path taken
 * for files whose size cannot be known in advance. */
static int read_from_fifo(const void *bytes, size_t n, NpyArray *a, char *err, size_t errlen) {
  char path[512];
  scratch_path(path, "fifo.npy");
  unlink(path);
  if (mkfifo(path, 0600) != 0) fail_msg("mkfifo: %s", strerror(errno));
  pid_t child = fork();
  if (child == 0) {
    FILE *f = fopen(path, "wb");
    size_t ok = f ? fwrite(bytes, 1, n, f) : 0;
    if (f) fclose(f);
    _exit(ok == n ? 0 : 1);
  }
  int rc = npy_read(path, a, err, errlen);
  waitpid(child, NULL, 0);
  return rc;
}

static void read_from_stream(void **state) {
  (void)state;
  static unsigned char file[4096];
  double data[300];
  for (int i = 0; i < 300; i++) data[i] = i * 0.25;
  char err[512];
  NpyArray a;
  size_t n = build_npy(file, 1, HDR("(300,)"), data, sizeof data);
  if (read_from_fifo(file, n, &a, err, sizeof err) != 0) fail_msg("%s", err);
  assert_int_equal(a.count, 300);
  assert_memory_equal(a.data, data, sizeof data);
  npy_free(&a);

  char want[600];
  n = build_npy(file, 1, HDR("(300,)"), data, sizeof data - 3);
  assert_int_not_equal(read_from_fifo(file, n, &a, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s/fifo.npy: truncated: expected 2400 bytes of data, found 2397", scratch);
  assert_string_equal(err, want);

  n = build_npy(file, 1, HDR("(299,)"), data, sizeof data);
  assert_int_not_equal(read_from_fifo(file, n, &a, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s/fifo.npy: trailing garbage: expected 2392 bytes of data, found 2400", scratch);
  assert_string_equal(err, want);

  /* a shape far beyond what arrives costs no more than what arrives */
  n = build_npy(file, 1, HDR("(1000000000000,)"), data, sizeof data);
  assert_int_not_equal(read_from_fifo(file, n, &a, err, sizeof err), 0);
  snprintf(want, sizeof want, "%s/fifo.npy: truncated: expected 8000000000000 bytes of data, found 2400", scratch);
  assert_string_equal(err, want);
  assert_null(a.data);
}

/* ---------------------------------------------------------------- robustness */

/* Either an error with a message, or an array consistent with itself. */
static void check_outcome(const char *what, const char *path, int rc, NpyArray *a, const char *err) {
  if (rc != 0) {
    size_t plen = strlen(path);
    if (strncmp(err, path, plen) != 0 || strncmp(err + plen, ": ", 2) != 0 || !err[plen + 2])
      fail_msg("%s: bad message \"%s\"", what, err);
    if (a->data) fail_msg("%s: data left after an error", what);
    return;
  }
  size_t count = 1;
  if (a->ndim < 0 || a->ndim > NPY_MAX_DIMS) fail_msg("%s: ndim %d", what, a->ndim);
  for (int i = 0; i < a->ndim; i++) count *= (size_t)a->shape[i];
  if (!a->data || count != a->count) fail_msg("%s: count %zu for shape product %zu", what, a->count, count);
  size_t size = a->type == NPY_I32 ? 4 : 8;
  volatile unsigned char sink = 0;
  for (size_t i = 0; i < a->count * size; i++) sink ^= ((unsigned char *)a->data)[i]; /* ASan checks the size */
  (void)sink;
  npy_free(a);
}

static void every_prefix_and_corruption(void **state) {
  (void)state;
  const char *sources[] = {FIXTURES "f64_3x4.npy", FIXTURES "i64_v3.npy"};
  static const unsigned char replacements[] = {0x00, 0x01, 0x7f, 0x80, 0xff, '(', ')', ',', '\'', '"', '{', '}', ':',
                                               ' ',  '\n', '-',  '9',  '0',  'L', '[', ']', '.', '<', '>', '=', 'T'};
  char path[512], err[512], what[128];
  scratch_path(path, "mutant.npy");
  for (size_t s = 0; s < sizeof sources / sizeof *sources; s++) {
    size_t n;
    unsigned char *good = (unsigned char *)slurp(sources[s], &n);
    size_t header_end = 10 + (size_t)(good[8] | good[9] << 8) + (good[6] > 1 ? 2 : 0);
    NpyArray a;
    for (size_t len = 0; len < n; len++) {
      write_file(path, good, len);
      int rc = npy_read(path, &a, err, sizeof err);
      snprintf(what, sizeof what, "%s cut to %zu bytes", sources[s], len);
      if (rc == 0) fail_msg("%s: read succeeded", what);
      check_outcome(what, path, rc, &a, err);
    }
    unsigned char *bad = malloc(n);
    for (size_t at = 0; at < header_end; at++) {
      for (size_t r = 0; r < sizeof replacements + 2; r++) {
        memcpy(bad, good, n);
        bad[at] = r < sizeof replacements ? replacements[r] : (unsigned char)(good[at] ^ (r == sizeof replacements ? 1 : 0x20));
        if (bad[at] == good[at]) continue;
        write_file(path, bad, n);
        int rc = npy_read(path, &a, err, sizeof err);
        snprintf(what, sizeof what, "%s with byte %zu = 0x%02x", sources[s], at, bad[at]);
        check_outcome(what, path, rc, &a, err);
      }
    }
    free(bad);
    free(good);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(read_numpy_float64),
      cmocka_unit_test(read_numpy_integers),
      cmocka_unit_test(read_numpy_versions),
      cmocka_unit_test(refuse_numpy_files),
      cmocka_unit_test(write_matches_numpy),
      cmocka_unit_test(write_read_round_trip),
      cmocka_unit_test(write_replaces_whole_file),
      cmocka_unit_test(write_errors),
      cmocka_unit_test(unreadable_files),
      cmocka_unit_test(bad_prefixes),
      cmocka_unit_test(bad_headers),
      cmocka_unit_test(good_headers),
      cmocka_unit_test(small_error_buffers),
      cmocka_unit_test(read_from_stream),
      cmocka_unit_test(every_prefix_and_corruption),
  };
  return cmocka_run_group_tests(tests, make_scratch, remove_scratch);
}
