/* model_store_impl.h — what the two files of the model store share
 * (model_store.c: the store in memory and reading; model_store_dir.c:
 * directories, writing, and recovery from interrupted writes). Private to
 * backends/model/. */
#ifndef NPG_MODEL_STORE_IMPL_H
#define NPG_MODEL_STORE_IMPL_H

#include <stdint.h>

#include "model_store.h"

#define FORMAT_LINE "npg-model 1"
/* the newest format this build reads (model_store.h: ModelStore.format) */
#define FORMAT_LINE_MAX "npg-model 3"
#define FORMAT_MAX 3
#define FORMAT_WORD "npg-model"
#define CHECKSUM_KIND "fnv1a64"

/* A manifest is a few lines per array; anything much larger is not one, and
 * the cap bounds what a wrong path makes us allocate. */
#define MANIFEST_MAX ((size_t)16 << 20)

/* Room for a shape as text: NPY_MAX_DIMS numbers of at most 20 digits and
 * their separators. */
enum { SHAPE_TEXT = NPY_MAX_DIMS * 21 + 4 };

/* Where a message goes (`err` may be NULL, or hold no buffer: no message). */
typedef struct StoreReport {
  Err *err;
} StoreReport;

/* "<path>: <problem>", or "<path>:<line>: <problem>" when `line` > 0; -1. */
__attribute__((format(printf, 4, 5))) int model_store_fail(const StoreReport *r, const char *path, int line,
                                                           const char *fmt, ...);
/* `s` printable in a message (npy_excerpt). `buf` holds NPY_EXCERPT_SIZE. */
const char *model_store_excerpt(char *buf, const char *s);
/* A malloc'd printf, or NULL when out of memory. */
__attribute__((format(printf, 1, 2))) char *model_store_printf(const char *fmt, ...);
/* FNV-1a 64 of the whole file `path`. */
int model_store_hash_file(const StoreReport *r, const char *path, uint64_t *h);
/* A file stem of [A-Za-z0-9_.-] not starting with '.'. */
int model_store_valid_name(const char *s);
/* A metadata line the manifest can hold and give back verbatim. */
int model_store_valid_meta(const char *line);
/* `shape` as "3x4" ("5" for one dim, "()" for none) into `buf` (SHAPE_TEXT). */
const char *model_store_format_shape(char *buf, int ndim, const long *shape);
/* 16 hex digits: 0, or -1. */
int model_store_parse_hex64(const char *s, uint64_t *v);
/* The element count of a shape, checked against overflow: 0, or -1. */
int model_store_shape_count(int ndim, const long *shape, size_t *count);
/* The whole of `path` into a malloc'd, NUL-terminated `*text` of `*len` bytes. */
int model_store_slurp(const StoreReport *r, const char *path, char **text, size_t *len);
/* `dir` without trailing slashes (malloc'd; "/" stays "/"), or NULL. */
char *model_store_normalize_dir(const char *dir);
/* What dead trainings left beside `dir`: a complete new model (else the
 * previous one) moved into a missing `dir`, saying so on stderr; with
 * `clean`, the rest removed. Failures here are not errors of the caller. */
void model_store_recover(const char *dir, int clean);

#endif
