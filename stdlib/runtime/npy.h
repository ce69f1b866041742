/* npy.h — NumPy .npy arrays on disk: float64, int32, int64, C order,
 * little-endian, format 1.0/2.0/3.0 headers.
 *
 * DESIGN §2: every array a user gives to or gets from npgc (params, inputs,
 * bases, reduced tensors) is a .npy file, so users inspect everything with
 * numpy. DESIGN §10: a missing or malformed file is a user error that names
 * the file and the problem, and a file being written is never seen half
 * written.
 *
 * The format (numpy/lib/format.py, "NEP 1"): the magic "\x93NUMPY", a
 * major and minor version byte, the header length (2 bytes little-endian for
 * 1.0, 4 bytes for 2.0 and 3.0), then the header: a Python dict literal
 * {'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), } padded with
 * spaces and ended by '\n'; the raw array data follows, nothing after it.
 */
#ifndef NPG_NPY_H
#define NPG_NPY_H

#include <stdarg.h>
#include <stddef.h>

typedef enum NpyType {
  NPY_F64, /* '<f8', double */
  NPY_I32, /* '<i4', int32_t */
  NPY_I64, /* '<i8', int64_t */
} NpyType;

#define NPY_MAX_DIMS 8

/* The longest header npy_read accepts, in bytes (numpy.load's default
 * limit): a file holds at most this, the 12 bytes before it and its data. */
#define NPY_HEADER_MAX 10000

typedef struct NpyArray {
  NpyType type;
  int ndim;
  long shape[NPY_MAX_DIMS];
  size_t count; /* product of shape (1 for a 0-d array) */
  void *data;   /* count elements of `type`, malloc'd; native byte order */
} NpyArray;

/* Read `path` into `out`. 0 on success: `out->data` is then non-NULL, even
 * when `out->count` is 0, and belongs to the caller (npy_free). Otherwise
 * non-zero, `out` is zeroed (npy_free on it is harmless), and `err` holds
 * "<path>: <problem>" with no trailing newline (cut to `errlen`; `err` may
 * be NULL). Accepts exactly the files numpy writes for the three types —
 * descr '<f8' '<i4' '<i8' (or '=' order), C order — and rejects anything
 * else, including bytes after the data, since a longer file than its header
 * says is most likely a corrupted or concatenated one. */
int npy_read(const char *path, NpyArray *out, char *err, size_t errlen);

/* Write `ndim` (0..NPY_MAX_DIMS) dims `shape` of `data` (native byte order,
 * C order) as a version 1.0 .npy file byte-identical to numpy.save's. The
 * bytes go to "<path>.tmp.<pid>" first and are renamed over `path` only once
 * complete and synced, so `path` always holds either its old contents or the
 * whole new array. 0 on success; otherwise non-zero, `path` is untouched, the
 * temporary file is removed, and `err` holds "<path>: <problem>". */
int npy_write(const char *path, NpyType type, int ndim, const long *shape, const void *data, char *err,
              size_t errlen);

/* Release `a->data` and zero `a`; harmless on a zeroed or freed array. */
void npy_free(NpyArray *a);

/* "float64", "int32", "int64" ("unknown" for a value outside NpyType). */
const char *npy_type_name(NpyType t);

/* `n` bytes of text at `s`, printable in a message: at most 40 bytes,
 * bytes outside printable ASCII as \xNN, "..." when cut. `buf` holds
 * NPY_EXCERPT_SIZE. Returns buf. */
enum { NPY_EXCERPT_SIZE = 200 };
const char *npy_excerpt(char *buf, const char *s, size_t n);

/* A message naming a file: "<path>: <problem>", or "<path>:<line>: <problem>"
 * when `line` > 0, into `err` (when `err` and `errlen` are given). Returns -1. */
int npy_vfail(char *err, size_t errlen, const char *path, int line, const char *fmt, va_list ap);

#endif
