/* context.h — what every layer of the compiler shares beneath the syntax
 * tree: source files and locations, the compilation's arena and pointer
 * vectors, the context (Ctx) with its diagnostics, and library code's
 * failures (error_set). The public API's argument refusals are the
 * facade's (compiler/api/api.h).
 *
 * Two ways to fail, by who calls: while compiling (the front end, the
 * lowering, the emitters), everything lives in the compilation's arena
 * (Ctx.arena), released at once by ctx_free(), and a user error or running
 * out of memory longjmps to ctx->on_error, which npg_compile arms
 * (compiler/api/npg.c; the full evaluator and the reduced emitter arm it
 * around code generation). Library code that runs on a finished program
 * (evaluation, training, models) does not jump: it frees what it allocated
 * and returns -1 with the message error_set wrote.
 */
#ifndef NPG_CONTEXT_H
#define NPG_CONTEXT_H

#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#define NPG_HIDDEN __attribute__((visibility("hidden")))

/* ---------------------------------------------------------------- sources */

typedef struct SrcFile {
  const char *name;  /* path as given by the user, used in diagnostics */
  const char *text;  /* NUL-terminated contents */
  size_t len;        /* bytes, excluding the terminating NUL */
} SrcFile;

typedef struct Loc {
  const SrcFile *file;
  int line, col;     /* 1-based */
  size_t off;        /* byte offset of the token */
} Loc;

/* ---------------------------------------------------------------- arena */

typedef struct ArenaBlock ArenaBlock;
typedef struct Arena {
  ArenaBlock *head;
  size_t used_total;
} Arena;

#include "alloc.h" /* mem_alloc_hook, mem_malloc, ... */

/* Library code's failures: the message formatted into `err` (when `err` and
 * `errlen` are given), and -1 to return. */
int error_set(char *err, size_t errlen, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* The same with the arguments as a va_list (npg_error_set, npg.h, is this). */
int error_vset(char *err, size_t errlen, const char *fmt, va_list ap);
/* The same, unless `err` already holds a message: the first error of an
 * object stays (the evaluators and the trainer refuse work after one). */
int error_set_first(char *err, size_t errlen, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* The error record of the backends (DESIGN §9): where a failure's message
 * goes. A function that can fail takes `Err *err` (NULL, or a NULL `msg`:
 * the message is dropped) and returns err_set's -1; its caller passes the
 * same record on. The API's `char *err, size_t errlen` becomes one with
 * ERR_OF(err, errlen), a record that lives until the end of the enclosing
 * block. */
typedef struct Err {
  char *msg;
  size_t len;
} Err;
#define ERR_OF(buf, buflen) (&(Err){(buf), (buflen)})
/* The buffer and size behind a record (NULL and 0 for none), for a function
 * that still takes `char *err, size_t errlen` (npy.h, jit.h). */
#define ERR_MSG(e) ((e) ? (e)->msg : NULL)
#define ERR_LEN(e) ((e) ? (e)->len : 0)
int err_set(Err *e, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
int err_vset(Err *e, const char *fmt, va_list ap);
/* The same, unless the record already holds a message (the first stays). */
int err_set_first(Err *e, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Whether the record holds a message. */
bool err_held(const Err *e);
/* `bytes` for a message, in the units --mem takes (powers of 1000):
 * "800 B", "1.12 GB", "8 TB"; into `buf`, which is returned. */
const char *bytes_text(double bytes, char *buf, size_t len);
/* This machine's physical memory in bytes (0 if unknown). */
size_t physical_memory(void);

typedef struct Ctx Ctx;
void *arena_alloc(Ctx *ctx, size_t size);            /* zeroed; never NULL */
char *arena_strdup(Ctx *ctx, const char *s);
char *arena_strndup(Ctx *ctx, const char *s, size_t n);
char *arena_printf(Ctx *ctx, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
char *arena_vprintf(Ctx *ctx, const char *fmt, va_list ap);
void *arena_grow(Ctx *ctx, void *old, size_t old_size, size_t new_size);
void arena_release(Arena *arena);   /* frees every block */

/* Growable array of pointers, in the arena. */
typedef struct PtrVec {
  void **v;
  int n, cap;
} PtrVec;
void vec_push(Ctx *ctx, PtrVec *vec, void *p);
/* The position of `p` in `vec` (the first, by a linear search), or -1 when
 * it is not there: a symbol's number in a program's list of dims, params,
 * quantities or slots, which the generated code and the models index by. */
int vec_position(const PtrVec *vec, const void *p);

/* ---------------------------------------------------------------- context */

struct Ctx {
  Arena arena;
  jmp_buf *on_error;     /* where user errors and OOM jump to */
  char *msg;             /* the diagnostic text of the error (arena) */
  Loc err_loc;           /* location of the error */
  bool failed;
  const char *std_dir;   /* directory with npg/<module>.npg */
  PtrVec files;          /* SrcFile*, every file read */
  int uniq;              /* counter for fresh names */
  FILE *open_file;       /* a file being read, closed if an error jumps out */
  char *pending_free;    /* a malloc'd buffer being copied, freed if an error jumps out */
};

/* User error: "file:line:col: error: message", the source line, a caret.
 * Never returns: jumps to ctx->on_error. */
_Noreturn void error_at(Ctx *ctx, Loc loc, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* The same, with an extra "note:" line pointing at a second location. */
_Noreturn void error_note(Ctx *ctx, Loc loc, Loc note, const char *note_msg,
                          const char *fmt, ...) __attribute__((format(printf, 5, 6)));
/* The source line of `loc` (a window of it around the column when long,
 * its cuts marked "…") and below it a caret under the column: the lines
 * that follow "file:line:col: error: message" in a diagnostic, for errors
 * found later than compilation (bind time). "" without a file. */
char *diag_excerpt(Ctx *ctx, Loc loc);
/* Error without a source location (files, data). */
_Noreturn void error_plain(Ctx *ctx, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Internal error: a broken invariant of the compiler itself. */
/* The diagnostic "PREFIXfile:line:col: KIND: MSG", the excerpt below it
 * (diag_excerpt), in the arena; what error_at and error_note format. */
char *diag_format(Ctx *ctx, const char *prefix, Loc loc, const char *kind, const char *msg);
/* Mark the compilation failed and jump to ctx->on_error (after ctx->msg is set). */
_Noreturn void ctx_fail(Ctx *ctx);
_Noreturn void internal_error(Ctx *ctx, const char *file, int line, const char *what);
#define iassert(ctx, cond) \
  do { if (!(cond)) internal_error((ctx), __FILE__, __LINE__, #cond); } while (0)

#endif
