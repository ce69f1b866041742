/* lex.re — the tokenizer, generated into lex.c by re2c at build time.
 *
 * Tokens: identifiers, numbers (123, 0.5, 1e-3; "0..3" is 0 .. 3),
 * punctuation. `#` starts a comment to the end of the line. Newlines are
 * white space; each token records whether it is the first on its line so
 * the parser can require one statement per line.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "compile.h"

typedef struct Lexer {
  Ctx *ctx;
  const SrcFile *file;
  const unsigned char *base;
  const unsigned char *line_start;
  int line;
  bool bol;
  Token *toks;
  int n, cap;
} Lexer;

static Loc loc_at(Lexer *lx, const unsigned char *p) {
  Loc l;
  l.file = lx->file;
  l.line = lx->line;
  l.col = (int)(p - lx->line_start) + 1;
  l.off = (size_t)(p - lx->base);
  return l;
}

static void push(Lexer *lx, TokKind kind, const unsigned char *s, const unsigned char *e) {
  if (lx->n == lx->cap) {
    int cap = lx->cap ? lx->cap * 2 : 256;
    lx->toks = arena_grow(lx->ctx, lx->toks, sizeof(Token) * (size_t)lx->cap, sizeof(Token) * (size_t)cap);
    lx->cap = cap;
  }
  Token *t = &lx->toks[lx->n++];
  t->kind = kind;
  t->loc = loc_at(lx, s);
  t->len = (int)(e - s);
  t->text = arena_strndup(lx->ctx, (const char *)s, (size_t)(e - s));
  t->bol = lx->bol;
  lx->bol = false;
  if (kind == TK_NUM) {
    t->is_int = strpbrk(t->text, ".eE") == NULL;
    t->num = strtod(t->text, NULL);
    /* the digits, not the rounded double: 9007199254740993 rounds to 2^53
     * and would pass a test on t->num */
    const char *d = t->text;
    while (*d == '0' && d[1]) d++;
    if (t->is_int && (strlen(d) > 16 || (strlen(d) == 16 && strcmp(d, "9007199254740992") > 0)))
      error_at(lx->ctx, t->loc, "integer literal '%s' is too large (at most 2^53)", t->text);
    if (!isfinite(t->num)) error_at(lx->ctx, t->loc, "number '%s' is out of the range of double precision", t->text);
  }
}

/*!re2c
  re2c:define:YYCTYPE = "unsigned char";
  re2c:yyfill:enable = 0;
  re2c:define:YYCURSOR = cur;
  re2c:define:YYMARKER = mar;

  digits = [0-9]+;
  ident  = [a-zA-Z_][a-zA-Z_0-9]*;
  expo   = [eE] [+-]? digits;
*/

/* The longest name (an identifier), in characters. */
#define MAX_IDENT 128

Token *lex_file(Ctx *ctx, const SrcFile *file, int *ntok) {
  Lexer lx = {0};
  lx.ctx = ctx;
  lx.file = file;
  lx.base = (const unsigned char *)file->text;
  lx.line_start = lx.base;
  lx.line = 1;
  lx.bol = true;
  const unsigned char *end = lx.base + file->len;
  const unsigned char *cur = lx.base, *mar = lx.base, *tok;

  for (;;) {
    tok = cur;
    /*!re2c
      "\x00" {
        if (tok >= end) {
          push(&lx, TK_EOF, tok, tok);
          *ntok = lx.n;
          return lx.toks;
        }
        error_at(ctx, loc_at(&lx, tok), "invalid character NUL in source");
      }
      "\r\n" | "\n" | "\r" { lx.line++; lx.line_start = cur; lx.bol = true; continue; }
      [ \t\f\v]+ { continue; }
      "#" [^\n\r\x00]* { continue; }

      ident {
        /* A name becomes file names (MODEL/spectrum_<name>.csv, tensor files
         * named after stages) and manifest lines, which have limits: a
         * 4,000-character dim name cut the manifest's line, and training
         * wrote a model that could not load. */
        if (cur - tok > MAX_IDENT)
          error_at(ctx, loc_at(&lx, tok), "the name '%.20s...' is %d characters long (at most %d)", (const char *)tok,
                   (int)(cur - tok), MAX_IDENT);
        push(&lx, TK_IDENT, tok, cur);
        continue;
      }
      ident "." ident {
        /* u.next: a state's next value, the unknown of an implicit step (one name) */
        if (cur - tok < 6 || memcmp(cur - 5, ".next", 5) != 0)
          error_at(ctx, loc_at(&lx, tok), "unexpected '.' in '%.*s': the only dotted name is a state's next value, "
                   "NAME.next", (int)(cur - tok), (const char *)tok);
        if (cur - tok > MAX_IDENT)
          error_at(ctx, loc_at(&lx, tok), "the name '%.20s...' is %d characters long (at most %d)", (const char *)tok,
                   (int)(cur - tok), MAX_IDENT);
        push(&lx, TK_IDENT, tok, cur);
        continue;
      }
      digits ("." digits)? expo? { push(&lx, TK_NUM, tok, cur); continue; }
      digits "." [^0-9.] {
        error_at(ctx, loc_at(&lx, tok), "malformed number '%.*s': a decimal point must be followed by digits",
                 (int)(cur - tok - 1), (const char *)tok);
      }
      digits ("." digits)? [eE] [+-]? [^0-9] {
        error_at(ctx, loc_at(&lx, tok), "malformed number: the exponent of '%.*s' has no digits",
                 (int)(cur - tok - 1), (const char *)tok);
      }
      digits [a-zA-Z_] {
        error_at(ctx, loc_at(&lx, tok), "malformed number: a letter follows the digits of '%.*s'",
                 (int)(cur - tok), (const char *)tok);
      }
      "." digits {
        error_at(ctx, loc_at(&lx, tok), "malformed number '%.*s': write a leading zero (0%.*s)",
                 (int)(cur - tok), (const char *)tok, (int)(cur - tok), (const char *)tok);
      }

      ".." | "==" | "!=" | "<=" | ">=" | "&&" | "||" | "->"
      | "[" | "]" | "(" | ")" | "," | ":" | "=" | "+" | "-" | "*" | "/" | "^"
      | "<" | ">" | "!" | ";" { push(&lx, TK_PUNCT, tok, cur); continue; }

      "&" { error_at(ctx, loc_at(&lx, tok), "unexpected character '&' (did you mean '&&'?)"); }
      "|" { error_at(ctx, loc_at(&lx, tok), "unexpected character '|' (did you mean '||'?)"); }
      "\"" | "'" { error_at(ctx, loc_at(&lx, tok), "the language has no strings: unexpected quote"); }
      [\x80-\xff] { error_at(ctx, loc_at(&lx, tok), "non-ASCII byte 0x%02x in source (identifiers are ASCII)", tok[0]); }
      * {
        if (tok[0] >= 32 && tok[0] < 127)
          error_at(ctx, loc_at(&lx, tok), "unexpected character '%c'", tok[0]);
        error_at(ctx, loc_at(&lx, tok), "unexpected control character 0x%02x", tok[0]);
      }
    */
  }
}
