/* npg.h — the public C API of libnpg.
 *
 * Compiling a program:
 *
 *     NpgOptions opt = {0};                 // defaults
 *     NpgProgram *p = npg_compile("prog.npg", &opt);
 *     if (!npg_ok(p)) fputs(npg_error(p), stderr);   // "file:line:col: error: ..."
 *     ...
 *     npg_free(p);                          // frees everything the program owns
 *
 * Ownership: an NpgProgram owns all memory it hands out (strings, reports);
 * pointers stay valid until npg_free(). npg_compile never returns NULL and
 * never exits the process: errors are reported through npg_error().
 */
#ifndef NPG_H
#define NPG_H

#include <stdbool.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NPG_API __attribute__((visibility("default")))

typedef struct NpgProgram NpgProgram;

typedef struct NpgOptions {
  const char *std_dir;  /* directory holding npg/<module>.npg; NULL: the built-in one */
  const char *dump;     /* letters of IR dumps to print to dump_out: p (parse),
                           s (checked), l (lowered), b (basis classes) */
  FILE *dump_out;       /* NULL: stderr */
  const char *source;   /* if non-NULL, compile this text instead of reading the file;
                           the path is still used as the name in diagnostics */
} NpgOptions;

/* Compile a .npg program: parse, check, lower, basis classes. */
NPG_API NpgProgram *npg_compile(const char *path, const NpgOptions *opt);
/* True when compilation succeeded. */
NPG_API bool npg_ok(const NpgProgram *p);
/* The diagnostic of a failed compilation ("file:line:col: error: msg\n<line>\n<caret>\n"),
 * or "" on success. */
NPG_API const char *npg_error(const NpgProgram *p);
/* The `npgc check` report, human readable (json=false) or JSON. */
NPG_API void npg_report(const NpgProgram *p, FILE *out, bool json);
NPG_API void npg_free(NpgProgram *p);

/* Write the generated C of the full evaluator (every stage, the bind-time
 * gather checker) and the tensor builders to `out`. Returns 0, or -1 with
 * the reason in npg_error(). The C compiles standalone (cc -c). */
NPG_API int npg_emit_full(NpgProgram *p, FILE *out);

#ifdef __cplusplus
}
#endif
#endif
