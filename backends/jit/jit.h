/* jit.h — compile generated C and load it: in memory with libtcc (the
 * default; no compiler needed at run time), or with the system compiler at
 * -O3 -march=native into a shared object loaded with dlopen (--cc). */
#ifndef NPG_JIT_H
#define NPG_JIT_H

#include <stdbool.h>
#include <stddef.h>

typedef struct JitModule JitModule;

/* Which compiler builds the generated C (npg.h's NpgBackend, translated by
 * the facade). */
typedef enum JitBackend {
  JIT_TCC,  /* libtcc, in memory */
  JIT_CC,   /* the system compiler, loaded with dlopen */
} JitBackend;

/* NULL on failure, with the reason in err. */
JitModule *jit_compile(const char *source, bool use_cc, char *err, size_t errlen);
void *jit_symbol(JitModule *m, const char *name);
void jit_free(JitModule *m);

#endif
