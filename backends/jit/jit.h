/* jit.h — compile generated C and load it: in memory with libtcc (no
 * compiler needed at run time, milliseconds), or with the system compiler at
 * -O3 -march=native into a shared object loaded with dlopen (--jit cc),
 * kept in the cache of jit_cache.h. JIT_AUTO, the default, is cc wherever it
 * is installed. */
#ifndef NPG_JIT_H
#define NPG_JIT_H

#include <stdbool.h>
#include <stddef.h>

typedef struct JitModule JitModule;

/* Which compiler builds the generated C (npg.h's NpgBackend, translated by
 * the facade). */
typedef enum JitBackend {
  JIT_TCC,  /* libtcc, in memory */
  JIT_CC,   /* the system compiler ($CC, else cc), loaded with dlopen */
  JIT_AUTO, /* $NPG_JIT (auto, cc or tcc) when set, else cc when found on PATH, else libtcc */
} JitBackend;

/* How a module was built. */
typedef struct JitInfo {
  JitBackend backend; /* JIT_TCC or JIT_CC, never JIT_AUTO */
  double seconds;     /* jit_compile's time: compiling and loading, or for a cache
                         hit identifying the compiler, hashing and loading */
  int cache;          /* 1 loaded from the cache, 0 compiled and stored, 2 a damaged
                         entry found, compiled and stored again, -1 not cached (libtcc, cache off) */
} JitInfo;

/* The backend `b` stands for (JIT_AUTO resolved): 0, or -1 when NPG_JIT
 * holds something else than auto, cc or tcc (the message in err). */
int jit_resolve(JitBackend b, JitBackend *out, char *err, size_t errlen);
/* NULL on failure, with the reason in err. */
JitModule *jit_compile(const char *source, JitBackend backend, char *err, size_t errlen);
JitInfo jit_info(const JitModule *m);
void *jit_symbol(JitModule *m, const char *name);
void jit_free(JitModule *m);

#endif
