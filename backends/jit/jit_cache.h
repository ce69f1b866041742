/* jit_cache.h — the content-addressed cache of evaluators compiled by cc.
 *
 * Building generated C with the system compiler costs 0.1–1 s; the same
 * program compiled again by the same compiler with the same flags gives the
 * same shared object, so it is kept on disk and loaded next time.
 *
 * Key: SHA-256 of (the generated C, the compiler's identity — its resolved
 * path and the output of `CC --version`, and the processor -march=native
 * targets —, the flags), 64 hex digits.
 * Folder: $NPG_CACHE_DIR, else $XDG_CACHE_HOME/npg, else $HOME/.cache/npg
 * (created on first use). An entry is KEY.so: the shared object followed by
 * a trailer (magic, the key, the SHA-256 of the object's bytes), so a
 * truncated, corrupted or renamed ("foreign") entry is detected before it is
 * loaded, removed and rebuilt; an entry another user owns is never loaded.
 * Concurrency: a new entry is written under a temporary name in the folder,
 * loaded from there, then renamed onto KEY.so (atomic): two processes
 * compiling the same program both succeed, one rename winning.
 * Size: at most $NPG_CACHE_MAX bytes (suffix K, M or G allowed; default
 * 256M; 0 turns the cache off): after a store the oldest entries (by mtime,
 * refreshed on every hit) are removed until the folder fits.
 *
 * Failures: a badly set variable (NPG_CACHE_DIR not a folder nor a path
 * one can be made at, NPG_CACHE_MAX not a size) is an error naming it; a
 * folder this process may not write (another user's, read-only), like an
 * unusable default folder (no HOME), only turns the cache off: nothing is
 * loaded from a folder others could write into unseen. */
#ifndef NPG_JIT_CACHE_H
#define NPG_JIT_CACHE_H

#include <stdbool.h>
#include <stddef.h>

/* SHA-256 of `n` bytes, as 64 hex digits and a NUL in `hex`. */
void jit_cache_sha256_hex(const void *data, size_t n, char hex[65]);

typedef struct JitCache {
  char dir[1024];  /* the folder, "" when the cache is off */
  long long max;   /* bytes */
} JitCache;

/* The folder and limit from the environment: 0, or -1 with the message in
 * `err` (the variable named). With the cache off, dir is "". */
int jit_cache_open(JitCache *c, char *err, size_t errlen);

/* The key of `source` compiled by `cc_identity` with `flags`. */
void jit_cache_key(const char *source, const char *cc_identity, const char *flags, char key[65]);

/* Load entry `key`: the dlopen handle after its trailer checked, or NULL
 * when absent, or damaged or foreign (then removed, and `*damaged` set). */
void *jit_cache_load(const JitCache *c, const char *key, bool *damaged);

/* Append the trailer of `key` to the shared object at `tmp_so` (a file in
 * the cache folder) so it becomes a valid entry: 0, or -1 with `err`. */
int jit_cache_seal(const char *tmp_so, const char *key, char *err, size_t errlen);

/* Rename the sealed `tmp_so` onto entry `key`, then evict the oldest
 * entries beyond the limit (never `key`). 0, or -1 with `err` (`tmp_so`
 * removed; the caller's loaded copy stays valid, merely not cached). */
int jit_cache_store(const JitCache *c, const char *tmp_so, const char *key, char *err, size_t errlen);

#endif
