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
  const char *std_dir;  /* directory holding npg/<module>.npg; NULL: the installed one
                           (<prefix>/share/npg/stdlib), else the source tree's */
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

/* ---------------------------------------------------------------- full evaluation
 *
 *     NpgFull *f = npg_full_new(p, NPG_TCC);       // generate + compile (libtcc)
 *     npg_full_bind_params(f, "DATA");             // DATA/<param>.npy; dims from shapes
 *     npg_full_set(f, "g", 2, shape, values, "g"); // an input (or extern) of one sample
 *     if (npg_full_eval(f, 0)) fputs(npg_full_error(f), stderr);
 *     const double *b = npg_full_get(f, "b", &n); // every stage value is kept
 *     npg_full_free(f);
 *
 * The evaluator keeps pointers into `p`: free it before npg_free(p). Values
 * handed back belong to the evaluator and change with the next evaluation.
 * Every function returns 0, or -1 with a message in npg_full_error() naming
 * the file or the stage and sample; after an error the evaluator refuses
 * further work until npg_full_clear_error(). */
typedef struct NpgFull NpgFull;
typedef enum NpgBackend {
  NPG_TCC,  /* libtcc, in memory (default) */
  NPG_CC,   /* the system compiler (CC, default cc) at -O3 -march=native, dlopen */
} NpgBackend;

NPG_API NpgFull *npg_full_new(NpgProgram *p, NpgBackend backend);
NPG_API const char *npg_full_error(const NpgFull *f);
NPG_API void npg_full_clear_error(NpgFull *f);
/* Forget every dim, param and value (to bind data of other sizes). */
NPG_API void npg_full_unbind(NpgFull *f);
/* Every param from DIR/<name>.npy (float64 for real, int32/int64 for int). */
NPG_API int npg_full_bind_params(NpgFull *f, const char *data_dir);
/* A param from memory (ints as whole doubles); `from` names it in messages. */
NPG_API int npg_full_set_param(NpgFull *f, const char *name, int ndim, const long *shape, const double *values,
                               const char *from);
/* An input or extern (or a param) for the next evaluation: dims then static axes. */
NPG_API int npg_full_set(NpgFull *f, const char *name, int ndim, const long *shape, const double *values,
                         const char *from);
/* Evaluate every stage; gathers are checked once per binding first. */
NPG_API int npg_full_eval(NpgFull *f, long sample);
/* The value of a quantity (input, extern or stage), C order; NULL if unknown. */
NPG_API const double *npg_full_get(const NpgFull *f, const char *name, size_t *count);
/* The bound size of a dim, -1 if unbound or unknown. */
NPG_API long npg_full_dim(const NpgFull *f, const char *name);
NPG_API void npg_full_free(NpgFull *f);

#ifdef __cplusplus
}
#endif
#endif
