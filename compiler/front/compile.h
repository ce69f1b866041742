/* compile.h — the compiler's stages, called in order by npg_compile(). */
#ifndef NPG_COMPILE_H
#define NPG_COMPILE_H

#include "ir.h"

/* The tallest expression tree the compiler takes (a chain x+x+…+x of N
 * terms is N levels): the passes recurse over expressions, and beyond this
 * a sanitizer build's stack would not hold them. */
#define MAX_EXPR_HEIGHT 400

/* ---------------------------------------------------------------- sources (source.c) */

/* Read a whole file into the arena; NULL if it cannot be read (errno set).
 * The file stays in ctx->open_file while it is read, for npg_compile to
 * close if an allocation failure jumps out. */
SrcFile *source_read(Ctx *ctx, const char *path);
/* `text` (of `len` bytes) as a source named `name`, copied into the arena. */
SrcFile *source_from_string(Ctx *ctx, const char *name, const char *text, size_t len);

/* ---------------------------------------------------------------- tokens (lex.re) */

typedef enum TokKind {
  TK_EOF,    /* end of the file */
  TK_IDENT,  /* identifier or keyword */
  TK_NUM,    /* number */
  TK_PUNCT,  /* punctuation */
} TokKind;

typedef struct Token {
  TokKind kind;
  Loc loc;
  const char *text;  /* identifier or punctuation spelling (arena) */
  int len;
  double num;
  bool is_int;
  bool bol;          /* first token on its line */
} Token;

/* compiler/front/lex.re: tokenize a whole file; the array ends with TK_EOF. */
Token *lex_file(Ctx *ctx, const SrcFile *file, int *ntok);

/* ---------------------------------------------------------------- stages */

bool is_keyword(const char *s);
/* compiler/front/parse.c: tokens to declarations; reads `use`d modules. */
Decl *parse_program(Ctx *ctx, const SrcFile *file);
/* compiler/front/sema.c: names, fn inlining, types, every rule of DESIGN §3. */
Program *sema_program(Ctx *ctx, const SrcFile *file, Decl *decls);
/* compiler/front/dumpast.c: -dp, the parsed declarations. */
void dump_decls(FILE *out, const Decl *d);
void dump_checked(FILE *out, const Program *prog);
/* compiler/api/exact_check.c: exact_check_program() (backends/verify/exact.h) for a
 * compiled NpgProgram; -1 with "the program does not compile" otherwise. */
struct NpgProgram;
struct ExactOptions;
int exact_check(struct NpgProgram *p, const struct ExactOptions *o, FILE *out, char *err, size_t errlen);
/* compiler/api/npg.c: the stage program of a compiled NpgProgram (tests, backends). */
struct NpgProgram;
Program *program_ir(const struct NpgProgram *p);

#endif
