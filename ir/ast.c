/* ast.c — arena, diagnostics, expression nodes and their printer. */
#include "ast.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ---------------------------------------------------------------- tables */

const char *const node_kind_name[N__COUNT] = {
#define NODE(k, name, sym) name,
#include "ops.def"
#undef NODE
};

const char *const node_kind_sym[N__COUNT] = {
#define NODE(k, name, sym) sym,
#include "ops.def"
#undef NODE
};

const BuiltinInfo builtin_info[B__COUNT] = {
    {NULL, 0, false},
#define BUILTIN(id, name, arity, alg) {name, arity, alg},
#include "ops.def"
#undef BUILTIN
};

Builtin builtin_lookup(const char *name) {
  for (int b = 1; b < B__COUNT; b++)
    if (strcmp(builtin_info[b].name, name) == 0) return (Builtin)b;
  return B_NONE;
}

/* ---------------------------------------------------------------- arena */

struct ArenaBlock {
  ArenaBlock *next;
  size_t size, used;
  max_align_t data[];
};


void *arena_alloc(Ctx *ctx, size_t size) {
  size = (size + 15) & ~(size_t)15;
  ArenaBlock *b = ctx->arena.head;
  if (!b || b->used + size > b->size) {
    size_t cap = size > 65536 ? size : 65536;
    b = npg_alloc_hook(sizeof(ArenaBlock) + cap);
    if (!b) {
      /* The message itself must not need the arena. */
      ctx->msg = "error: out of memory";
      ctx->failed = true;
      longjmp(*ctx->on_error, 1);
    }
    b->size = cap;
    b->used = 0;
    b->next = ctx->arena.head;
    ctx->arena.head = b;
  }
  void *p = (char *)b->data + b->used;
  b->used += size;
  ctx->arena.used_total += size;
  memset(p, 0, size);
  return p;
}

void arena_release(Arena *arena) {
  for (ArenaBlock *b = arena->head; b;) {
    ArenaBlock *next = b->next;
    free(b);
    b = next;
  }
  arena->head = NULL;
  arena->used_total = 0;
}

void *arena_grow(Ctx *ctx, void *old, size_t old_size, size_t new_size) {
  void *p = arena_alloc(ctx, new_size);
  if (old && old_size) memcpy(p, old, old_size < new_size ? old_size : new_size);
  return p;
}

char *arena_strndup(Ctx *ctx, const char *s, size_t n) {
  char *p = arena_alloc(ctx, n + 1);
  if (n) memcpy(p, s, n);
  p[n] = 0;
  return p;
}

char *arena_strdup(Ctx *ctx, const char *s) { return arena_strndup(ctx, s, strlen(s)); }

static char *arena_vprintf(Ctx *ctx, const char *fmt, va_list ap) {
  va_list ap2;
  va_copy(ap2, ap);
  int n = vsnprintf(NULL, 0, fmt, ap2);
  va_end(ap2);
  char *p = arena_alloc(ctx, (size_t)n + 1);
  vsnprintf(p, (size_t)n + 1, fmt, ap);
  return p;
}

int npg_fail(char *err, size_t errlen, const char *fmt, ...) {
  if (err && errlen) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
  }
  return -1;
}

int npg_fail_first(char *err, size_t errlen, const char *fmt, ...) {
  if (err && errlen && !err[0]) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
  }
  return -1;
}

static _Thread_local char refusal[512];

int npg_refuse(char *err, size_t errlen, const char *func, const char *fmt, ...) {
  char why[400];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(why, sizeof why, fmt, ap);
  va_end(ap);
  snprintf(refusal, sizeof refusal, "%s: %s", func, why);
  return npg_fail(err, errlen, "%s", refusal);
}

const char *npg_refusal(void) { return refusal; }

const char *npg_bytes_text(double bytes, char *buf, size_t len) {
  static const char *const units[] = {"B", "kB", "MB", "GB", "TB", "PB", "EB"};
  int u = 0;
  while (bytes >= 1000 && u < 6) bytes /= 1000, u++;
  snprintf(buf, len, "%.3g %s", bytes, units[u]);
  return buf;
}

size_t npg_physical_memory(void) {
  long pages = sysconf(_SC_PHYS_PAGES), psize = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && psize > 0 ? (size_t)pages * (size_t)psize : 0;
}

char *arena_printf(Ctx *ctx, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *p = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  return p;
}

void vec_push(Ctx *ctx, PtrVec *vec, void *p) {
  if (vec->n == vec->cap) {
    int cap = vec->cap ? vec->cap * 2 : 8;
    vec->v = arena_grow(ctx, vec->v, sizeof(void *) * (size_t)vec->cap, sizeof(void *) * (size_t)cap);
    vec->cap = cap;
  }
  vec->v[vec->n++] = p;
}

/* ---------------------------------------------------------------- diagnostics */

/* A source line longer than this many bytes is shown as a window around
 * the column, its cut ends marked with "…" (a 125 KB one-line program must
 * not print 125 KB per diagnostic). */
enum { DIAG_WINDOW = 100 };

static bool utf8_continuation(char c) { return ((unsigned char)c & 0xC0) == 0x80; }

char *diag_excerpt(Ctx *ctx, Loc loc) {
  if (!loc.file) return arena_strndup(ctx, "", 0);
  const char *text = loc.file->text;
  size_t start = loc.off <= loc.file->len ? loc.off : loc.file->len;
  while (start > 0 && text[start - 1] != '\n' && text[start - 1] != '\r') start--; /* CR alone ends a line too */
  size_t end = start;
  while (end < loc.file->len && text[end] != '\n' && text[end] != '\r') end++;
  size_t at = start + (size_t)(loc.col > 0 ? loc.col - 1 : 0); /* may lie past the end of the line */
  size_t from = start, to = end;
  if (end - start > DIAG_WINDOW) {
    size_t mid = at < end ? at : end;
    from = mid - start > DIAG_WINDOW / 2 ? mid - DIAG_WINDOW / 2 : start;
    if (end - from < DIAG_WINDOW) from = end - DIAG_WINDOW;
    to = from + DIAG_WINDOW;
    while (from > start && utf8_continuation(text[from])) from--;
    while (to < end && utf8_continuation(text[to])) to++;
  }
  bool cut_before = from > start, cut_after = to < end;
  /* Caret line: one column for a leading "…", then one per character. */
  char *caret = arena_alloc(ctx, (at - from) + 3);
  size_t nc = 0;
  if (cut_before) caret[nc++] = ' ';
  for (size_t k = from; k < at; k++) {
    if (k < end && utf8_continuation(text[k])) continue;
    caret[nc++] = (k < end && text[k] == '\t') ? '\t' : ' ';
  }
  caret[nc++] = '^';
  caret[nc] = 0;
  /* Replace non-printable bytes of the echoed line so output stays text. */
  char *line = arena_strndup(ctx, text + from, to - from);
  for (char *c = line; *c; c++)
    if ((unsigned char)*c < 32 && *c != '\t') *c = '?';
  return arena_printf(ctx, "%s%s%s\n%s", cut_before ? "…" : "", line, cut_after ? "…" : "", caret);
}

/* Append "file:line:col: kind: msg\n<source line>\n<caret>\n" to buf. */
static char *format_at(Ctx *ctx, const char *prefix, Loc loc, const char *kind, const char *msg) {
  if (!loc.file) return arena_printf(ctx, "%s%s: %s\n", prefix, kind, msg);
  return arena_printf(ctx, "%s%s:%d:%d: %s: %s\n%s\n", prefix, loc.file->name, loc.line, loc.col, kind, msg,
                      diag_excerpt(ctx, loc));
}

static _Noreturn void fail(Ctx *ctx) {
  ctx->failed = true;
  longjmp(*ctx->on_error, 1);
}

_Noreturn void error_at(Ctx *ctx, Loc loc, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = loc;
  ctx->msg = format_at(ctx, "", loc, "error", msg);
  fail(ctx);
}

_Noreturn void error_note(Ctx *ctx, Loc loc, Loc note, const char *note_msg, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = loc;
  ctx->msg = format_at(ctx, "", loc, "error", msg);
  ctx->msg = format_at(ctx, ctx->msg, note, "note", note_msg);
  fail(ctx);
}

_Noreturn void error_node(Ctx *ctx, const Node *n, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = n->loc;
  ctx->msg = format_at(ctx, "", n->loc, "error", msg);
  for (const Node *c = n->inl; c; c = c->inl)
    ctx->msg = format_at(ctx, ctx->msg, c->loc, "note", arena_printf(ctx, "in the call of '%s' here", c->name));
  fail(ctx);
}

_Noreturn void error_plain(Ctx *ctx, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  char *msg = arena_vprintf(ctx, fmt, ap);
  va_end(ap);
  ctx->err_loc = (Loc){0};
  ctx->msg = arena_printf(ctx, "error: %s\n", msg);
  fail(ctx);
}

_Noreturn void internal_error(Ctx *ctx, const char *file, int line, const char *what) {
  ctx->err_loc = (Loc){0};
  ctx->msg = arena_printf(ctx, "internal error: %s:%d: %s (a bug in npgc; please report it with the program)\n",
                          file, line, what);
  fail(ctx);
}

/* ---------------------------------------------------------------- nodes */

Node *new_node(Ctx *ctx, NodeKind kind, Loc loc) {
  Node *n = arena_alloc(ctx, sizeof *n);
  n->kind = kind;
  n->loc = loc;
  return n;
}

bool node_uses(const Node *n, const Sym *s) {
  if (!n) return false;
  if (n->kind == N_NAME && n->sym == s) return true;
  if (node_uses(n->a, s) || node_uses(n->b, s) || node_uses(n->c, s)) return true;
  for (int i = 0; i < n->nargs; i++)
    if (node_uses(n->args[i], s)) return true;
  return false;
}

int node_height(const Node *n, int limit) {
  if (!n) return 0;
  typedef struct Frame {
    const Node *n;
    int depth;
  } Frame;
  size_t cap = 256, top = 0;
  Frame *st = malloc(sizeof(Frame) * cap);
  if (!st) return -1;
  st[top++] = (Frame){n, 1};
  int height = 0;
  while (top > 0) {
    Frame f = st[--top];
    if (f.depth > height) height = f.depth;
    if (height > limit) break;
    const Node *kids[3] = {f.n->a, f.n->b, f.n->c};
    size_t need = top + 3 + (size_t)(f.n->nargs > 0 ? f.n->nargs : 0);
    if (need > cap) {
      while (cap < need) cap *= 2;
      Frame *g = realloc(st, sizeof(Frame) * cap);
      if (!g) {
        free(st);
        return -1;
      }
      st = g;
    }
    for (int k = 0; k < 3; k++)
      if (kids[k]) st[top++] = (Frame){kids[k], f.depth + 1};
    for (int k = 0; k < f.n->nargs; k++)
      if (f.n->args[k]) st[top++] = (Frame){f.n->args[k], f.depth + 1};
  }
  free(st);
  return height > limit ? limit + 1 : height;
}

Node *new_num(Ctx *ctx, double v, bool is_int, Loc loc) {
  Node *n = new_node(ctx, N_NUM, loc);
  n->num = v;
  n->is_int = is_int;
  n->ty.is_int = is_int;
  return n;
}

Node *clone_node(Ctx *ctx, const Node *n) {
  if (!n) return NULL;
  Node *c = arena_alloc(ctx, sizeof *c);
  *c = *n;
  c->a = clone_node(ctx, n->a);
  c->b = clone_node(ctx, n->b);
  c->c = clone_node(ctx, n->c);
  if (n->nargs) {
    c->args = arena_alloc(ctx, sizeof(Node *) * (size_t)n->nargs);
    for (int i = 0; i < n->nargs; i++) c->args[i] = clone_node(ctx, n->args[i]);
  }
  return c;
}

static void print_num(FILE *out, double v) {
  if (v > -1e15 && v < 1e15 && v == (double)(long long)v) /* range first: no out-of-range cast */
    fprintf(out, "%lld", (long long)v);
  else
    fprintf(out, "%.17g", v);
}

static int prec(const Node *n) {
  switch (n->kind) {
  case N_OR: return 1;
  case N_AND: return 2;
  case N_EQ: case N_NE: case N_LT: case N_LE: case N_GT: case N_GE: return 3;
  case N_ADD: case N_SUB: return 4;
  case N_MUL: case N_DIV: return 5;
  case N_NEG: case N_NOT: return 6;
  case N_POW: return 7;
  case N_NUM: return n->num < 0 ? 6 : 9;
  case N_RAT: return 5;
  default: return 9;
  }
}

static void print_sub(FILE *out, const Node *n, int min_prec) {
  bool paren = prec(n) < min_prec;
  if (paren) fputc('(', out);
  print_node(out, n);
  if (paren) fputc(')', out);
}

static void print_args(FILE *out, const Node *n, char open, char close) {
  fputc(open, out);
  for (int i = 0; i < n->nargs; i++) {
    if (i) fputs(", ", out);
    print_node(out, n->args[i]);
  }
  fputc(close, out);
}

void print_node(FILE *out, const Node *n) {
  if (!n) {
    fputs("<null>", out);
    return;
  }
  switch (n->kind) {
  case N_NUM: print_num(out, n->num); break;
  case N_RAT: fprintf(out, "%ld/%ld", n->p, n->q); break;
  case N_NAME: fputs(n->sym ? n->sym->name : n->name, out); break;
  case N_INDEX:
    print_sub(out, n->a, 9);
    print_args(out, n, '[', ']');
    break;
  case N_CALL:
    fputs(n->name, out);
    print_args(out, n, '(', ')');
    break;
  case N_VEC: print_args(out, n, '[', ']'); break;
  case N_SUM:
    fprintf(out, "sum(%s = ", n->sym ? n->sym->name : n->name);
    print_node(out, n->a);
    fputs("..", out);
    print_node(out, n->b);
    fputs(", ", out);
    print_node(out, n->c);
    fputc(')', out);
    break;
  case N_IF:
    fputs("if(", out);
    print_node(out, n->a);
    fputs(", ", out);
    print_node(out, n->b);
    fputs(", ", out);
    print_node(out, n->c);
    fputc(')', out);
    break;
  case N_NEG:
  case N_NOT:
    fputs(node_kind_sym[n->kind], out);
    print_sub(out, n->a, 7);
    break;
  case N_POW:
    print_sub(out, n->a, 8);
    fputc('^', out);
    print_sub(out, n->b, 9);
    break;
  default: {
    int p = prec(n);
    print_sub(out, n->a, p);
    fprintf(out, " %s ", node_kind_sym[n->kind]);
    print_sub(out, n->b, p + 1);
    break;
  }
  }
}

char *print_to_arena(Ctx *ctx, void (*print)(FILE *, const void *), const void *x) {
  char *buf = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&buf, &len);
  if (!f) error_plain(ctx, "out of memory");
  print(f, x);
  fclose(f);
  /* arena_alloc may jump out on allocation failure: npg_compile frees
   * the pending buffer then. */
  ctx->pending_free = buf;
  char *s = arena_strndup(ctx, buf ? buf : "", buf ? len : 0);
  ctx->pending_free = NULL;
  free(buf);
  return s;
}

static void print_node_cb(FILE *out, const void *n) { print_node(out, n); }

char *node_str(Ctx *ctx, const Node *n) { return print_to_arena(ctx, print_node_cb, n); }
