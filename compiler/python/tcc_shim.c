/* tcc_shim.c — the variables Debian's non-PIC libtcc.a reads, for the
 * module's copy of it (CMakeLists.txt renames its references to stdout,
 * stderr and environ, which a shared object cannot reach PC-relative in
 * libc). Hidden, so the module's PC-relative reads resolve inside it; set
 * from libc's when the module is loaded, before any compilation. */
#include <stdio.h>

extern char **environ;

__attribute__((visibility("hidden"))) FILE *npg_tcc_stdout, *npg_tcc_stderr;
__attribute__((visibility("hidden"))) char **npg_tcc_environ;

__attribute__((constructor)) static void tcc_shim_init(void) {
  npg_tcc_stdout = stdout;
  npg_tcc_stderr = stderr;
  npg_tcc_environ = environ;
}
