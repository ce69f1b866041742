/* model_store.h — the on-disk store of a trained reduced model: a MODEL/
 * directory of named float64 arrays and metadata lines.
 *
 * DESIGN §2: "A MODEL/ directory holds `manifest` (text: program hash, basis
 * classes and sizes, tensor list with shapes, energy captured, checksums)
 * plus one .npy per basis and reduced tensor." This file knows nothing of
 * bases or tensors: the trainer says what they are in metadata lines and
 * names the arrays; the store keeps them, checks them and says which file is
 * wrong.
 *
 * The manifest, one entry a line, each line ended by '\n':
 *
 *   npg-model 1                                   format and version, always first
 *   program 0123456789abcdef                      the program's hash, 16 hex digits
 *   <key> <value...>                              metadata lines, verbatim, in order
 *   array basis_0.npy 3x4 fnv1a64 89abcdef01234567  one line per array
 *
 *   file spectrum_x.csv fnv1a64 0123456789abcdef   one line per text file
 *   manifest fnv1a64 0123456789abcdef             always last: the hash of the lines before it
 *
 * An array line gives the file, its shape ("3x4"; "5" for a vector, "()"
 * for a 0-d array) and the FNV-1a 64 hash of the whole .npy file's bytes;
 * the last line vouches for the manifest itself, so no line of it can be
 * added, changed or removed unnoticed.
 *
 * A model is replaced whole or not at all: model_store_write builds the new
 * one in "<dir>.tmp.<pid>" and swaps it in only once every byte is synced
 * (one atomic renameat2 exchange where the file system has it), so an
 * interrupted training never leaves a half model. SIGINT and SIGTERM remove
 * the temporary folder; what a killed process left is recovered or removed
 * by the next write, and a missing `dir` is recovered by the next read.
 */
#ifndef NPG_MODEL_STORE_H
#define NPG_MODEL_STORE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "context.h" /* Err */
#include "npy.h"

typedef struct ModelArray {
  char *name;        /* file stem: "basis_0" is stored as basis_0.npy */
  NpyArray a;        /* always NPY_F64 */
  uint64_t checksum; /* FNV-1a 64 of the .npy file, as model_store_read verified it; 0 after model_store_add */
  bool borrowed;     /* a.data belongs to the caller (model_store_add_borrowed) */
} ModelArray;

/* A text file beside the arrays (a CSV for people and spreadsheets). */
typedef struct ModelText {
  char *name;        /* file name, ending in .csv */
  char *text;
  uint64_t checksum; /* FNV-1a 64 of the file, as model_store_read verified it; 0 after model_store_add_text */
} ModelText;

typedef struct ModelStore {
  uint64_t program_hash; /* the program the model was trained for */
  int format;            /* the first line's version: 0 or 1 writes "npg-model 1"; 2 a model with
                            interpolated stages (interp.h), which builds that predate them refuse
                            ("model format 'npg-model 2' is not supported") instead of evaluating
                            it by Galerkin; 3 a model with a class kept as coefficients of its
                            training values (RClass.coef), which older builds refuse the same way
                            instead of finding no basis; read: what the file said */
  int nmeta;
  char **meta; /* ordered manifest lines "key value...", without '\n', written verbatim */
  int narrays;
  ModelArray *arrays;
  int ntexts;
  ModelText *texts;
} ModelStore;

/* An empty store: no metadata, no arrays, program hash 0. */
void model_store_init(ModelStore *m);

/* Append the metadata line printf(`fmt`, ...). 0, or -1 when out of memory
 * or when the line is not "key value...": empty, starting with a space or a
 * tab, holding a '\n', or with a first word the manifest reserves
 * ("npg-model", "program", "array"). Nothing is appended on -1. */
__attribute__((format(printf, 2, 3))) int model_store_meta(ModelStore *m, const char *fmt, ...);

/* Append a float64 array `name` of `ndim` (0..NPY_MAX_DIMS) dims `shape`,
 * copying the elements of `data` (C order; may be NULL when the array is
 * empty). `name` holds only [A-Za-z0-9_.-], does not start with '.' and is
 * not already in `m`. 0, or -1 (invalid argument or out of memory) with
 * `m` unchanged. */
int model_store_add(ModelStore *m, const char *name, int ndim, const long *shape, const double *data);

/* model_store_add without the copy: `data` (count > 0 elements) is read
 * when `m` is written and must outlive `m` — a basis memory-mapped from
 * its file (out-of-core training) is written from the mapping, never held
 * twice in memory. */
int model_store_add_borrowed(ModelStore *m, const char *name, int ndim, const long *shape, const double *data);

/* Append the text file `name` (a valid array name ending in ".csv", not
 * already in `m`) holding `text`. 0, or -1 with `m` unchanged. */
int model_store_add_text(ModelStore *m, const char *name, const char *text);

/* The array `name`, or NULL if `m` has none of that name. */
const NpyArray *model_store_array(const ModelStore *m, const char *name);

/* The rest of the first metadata line whose first word is `key` (spaces
 * after the key skipped; "" when the line is the key alone), or NULL. The
 * pointer lives as long as `m`. */
const char *model_store_find(const ModelStore *m, const char *key);

/* Write `m` as the model directory `dir` (trailing slashes ignored),
 * replacing whatever model `dir` held. The model is built in
 * "<dir>.tmp.<pid>" (a stale one of that name is removed first), files and
 * directory are synced, then an existing `dir` is renamed to
 * "<dir>.old.<pid>", the new one renamed to `dir`, and the old one removed.
 *
 * Only what a model store writes is ever removed — `manifest`, the .npy
 * files its manifest lists and leftovers of npy_write ("*.npy.tmp.<pid>") —
 * so a `dir` that holds anything else (an unlisted .npy too), or holds files
 * but no model manifest, is refused before anything is written. `dir` may
 * not be a symbolic link.
 *
 * 0 on success. Otherwise -1, `err` holds "<path>: <problem>", and `dir` is
 * as it was — with one exception, said in the message: when only the
 * removal of the replaced model failed, the new model is complete in `dir`
 * and "<dir>.old.<pid>" is left for the user to remove. */
int model_store_write(const char *dir, const ModelStore *m, Err *err);

/* Read the model directory `dir` into `m` (which need not be initialized),
 * checking everything: the manifest's format, that the model was trained for
 * the program of hash `expect_program_hash`, and for every array that its
 * file exists, hashes to the manifest's checksum, is a valid float64 .npy
 * and has the manifest's shape. 0, or -1 with `m` empty and `err` holding
 * "<file>[:<line>]: <problem>", naming the file that is wrong. */
int model_store_read(const char *dir, uint64_t expect_program_hash, ModelStore *m, Err *err);

/* model_store_read without the program check: for tools that look at any
 * model (npgc plot). */
int model_store_read_any(const char *dir, ModelStore *m, Err *err);

/* Release everything `m` holds and leave it empty (model_store_init). */
void model_store_free(ModelStore *m);

/* FNV-1a 64: the hash of `n` bytes at `p` continuing from `h`, which is
 * model_hash_init() for the first bytes. Used for the program hash and the
 * checksum of every file. */
uint64_t model_hash_bytes(uint64_t h, const void *p, size_t n);
uint64_t model_hash_init(void);

#endif
