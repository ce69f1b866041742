/* test_cse.c — the values of a loop nest (backends/emit/cse.c): common subexpressions
 * shared, invariants hoisted, guarded reads left in place, and libtcc's row kernels.
 *
 * Random expression trees over a two-loop nest (i, j < N; arrays A[i], B[j], M[i, j];
 * guarded reads B[j + 1], A[i + 1]; sqrt, choices, sums) are written twice into one C
 * file: as the plain expression, every subtree printed where it stands, and through
 * cse.c, each distinct value once. Sharing claims the same operations in the same order,
 * only fewer times, so under libtcc (which never contracts a * b + c) the two must agree
 * bit for bit on random data. The arrays read past their end by a guarded read sit
 * against an unmapped page: a read taken out of its guard is a crash, not a quiet pass. */
#define _DEFAULT_SOURCE /* MAP_ANONYMOUS */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cmocka.h>

#include "emit.h"
#include "jit.h"
#include "runtime.h"

enum { N = 9 };

/* ---------------------------------------------------------------- expressions */

typedef enum ExprKind {
  E_NUM,     /* a literal */
  E_I,       /* (double)i */
  E_A,       /* A[i] */
  E_B,       /* B[j] */
  E_M,       /* M[i * N + j] */
  E_ANEXT,   /* i + 1 < N ? A[i + 1] * num : 0.0 (the read guarded; num 1 or 2) */
  E_BNEXT,   /* j + 1 < N ? B[j + 1] * num : 0.0 */
  E_ADD,     /* a + b */
  E_SUB,     /* a - b */
  E_MUL,     /* a * b */
  E_DIV,     /* a / b */
  E_NEG,     /* -a */
  E_SQRT,    /* sqrt(fabs(a)) */
  E_DIAG,    /* i == j ? a : b */
  E_LESS,    /* a < b ? c : a */
  E_SUM,     /* the sum over k = 0..2 of a * (double)k */
} ExprKind;

typedef struct Expr {
  ExprKind kind;
  double num;
  const struct Expr *a, *b, *c;
} Expr;

typedef struct Gen {
  Expr nodes[4096];
  int n;
  const Expr *pool[4096]; /* subtrees made so far: picked again, they are shared */
  int npool;
  unsigned seed;
} Gen;

static unsigned next(Gen *g) {
  g->seed = g->seed * 1103515245u + 12345u;
  return (g->seed >> 8) & 0xffffff;
}

static const Expr *node(Gen *g, ExprKind k, const Expr *a, const Expr *b, const Expr *c) {
  if (g->n == (int)(sizeof g->nodes / sizeof *g->nodes)) fail_msg("expression too large");
  Expr *e = &g->nodes[g->n++];
  *e = (Expr){k, 0, a, b, c};
  if (k == E_NUM) e->num = (double)(next(g) % 7 + 1) / 4; /* 0.25 .. 1.75, exact */
  if (k == E_ANEXT || k == E_BNEXT) e->num = 1 + next(g) % 2;   /* one guarded read, two values */
  g->pool[g->npool++] = e;
  return e;
}

static bool contains_sum(const Expr *e) {
  return e && (e->kind == E_SUM || contains_sum(e->a) || contains_sum(e->b) || contains_sum(e->c));
}

/* A random expression of `depth` at most; `sums`: a sum may appear (never nested: one
 * summation variable). Subtrees made before come back a third of the time, and a
 * commuted copy of + and * now and then (the same value to cse.c). */
static const Expr *gen(Gen *g, int depth, bool sums) {
  if (g->npool > 4 && next(g) % 3 == 0) {
    const Expr *e = g->pool[next(g) % (unsigned)g->npool];
    if (sums || !contains_sum(e)) return e;
  }
  static const ExprKind leaves[] = {E_NUM, E_I, E_A, E_B, E_M, E_ANEXT, E_BNEXT};
  if (depth == 0) return node(g, leaves[next(g) % 7], NULL, NULL, NULL);
  ExprKind k = (ExprKind)(E_NUM + next(g) % (E_SUM + 1));
  if (k == E_SUM && !sums) k = E_MUL;
  if (k < E_ADD) return node(g, k, NULL, NULL, NULL);
  bool inner_sums = sums && k != E_SUM;
  const Expr *a = gen(g, depth - 1, inner_sums);
  const Expr *b = k == E_NEG || k == E_SQRT || k == E_SUM ? NULL : gen(g, depth - 1, inner_sums);
  const Expr *c = k == E_LESS ? gen(g, depth - 1, inner_sums) : NULL;
  const Expr *e = node(g, k, a, b, c);
  if ((k == E_ADD || k == E_MUL) && next(g) % 4 == 0) node(g, k, b, a, NULL);
  return e;
}

/* Row-wise computable (cse_rows_plan): + - * / and negation of rows (B[j], M[i, j]) and
 * per-row scalars (A[i], (double)i, literals), and the diagonal choice i == j ? scalar : row. */
static const Expr *gen_scalar(Gen *g, int depth) {
  static const ExprKind leaves[] = {E_NUM, E_I, E_A};
  if (depth == 0 || next(g) % 2) return node(g, leaves[next(g) % 3], NULL, NULL, NULL);
  return node(g, (ExprKind)(E_ADD + next(g) % 4), gen_scalar(g, depth - 1), gen_scalar(g, depth - 1), NULL);
}

static const Expr *gen_row(Gen *g, int depth) {
  if (depth == 0) return node(g, next(g) % 2 ? E_B : E_M, NULL, NULL, NULL);
  switch (next(g) % 7) {
  case 0: return node(g, E_NEG, gen_row(g, depth - 1), NULL, NULL);
  case 1: return node(g, E_DIAG, gen_scalar(g, 1), gen_row(g, depth - 1), NULL);
  case 2: return node(g, (ExprKind)(E_ADD + next(g) % 4), gen_scalar(g, 1), gen_row(g, depth - 1), NULL);
  case 3: return node(g, (ExprKind)(E_ADD + next(g) % 4), gen_row(g, depth - 1), gen_scalar(g, 1), NULL);
  default: return node(g, (ExprKind)(E_ADD + next(g) % 4), gen_row(g, depth - 1), gen_row(g, depth - 1), NULL);
  }
}

/* ---------------------------------------------------------------- the plain C */

static void print_plain(FILE *out, const Expr *e) {
  static const char *const ops[] = {[E_ADD] = "+", [E_SUB] = "-", [E_MUL] = "*", [E_DIV] = "/"};
  switch (e->kind) {
  case E_NUM: fprintf(out, "%.17g", e->num); return;
  case E_I: fputs("((double)i)", out); return;
  case E_A: fputs("A[i]", out); return;
  case E_B: fputs("B[j]", out); return;
  case E_M: fputs("M[i * N + j]", out); return;
  case E_ANEXT: fprintf(out, "((i + 1 < N) ? A[i + 1] * %g : 0.0)", e->num); return;
  case E_BNEXT: fprintf(out, "((j + 1 < N) ? B[j + 1] * %g : 0.0)", e->num); return;
  case E_ADD:
  case E_SUB:
  case E_MUL:
  case E_DIV:
    fputc('(', out);
    print_plain(out, e->a);
    fprintf(out, " %s ", ops[e->kind]);
    print_plain(out, e->b);
    fputc(')', out);
    return;
  case E_NEG: fputs("(-", out); print_plain(out, e->a); fputc(')', out); return;
  case E_SQRT: fputs("sqrt(fabs(", out); print_plain(out, e->a); fputs("))", out); return;
  case E_DIAG:
    fputs("((i == j) ? ", out);
    print_plain(out, e->a);
    fputs(" : ", out);
    print_plain(out, e->b);
    fputc(')', out);
    return;
  case E_LESS:
    fputs("((", out);
    print_plain(out, e->a);
    fputs(" < ", out);
    print_plain(out, e->b);
    fputs(") ? ", out);
    print_plain(out, e->c);
    fputs(" : ", out);
    print_plain(out, e->a);
    fputc(')', out);
    return;
  case E_SUM:
    fputs("__extension__({ double s = 0.0; for (npg_idx k = 0; k <= 2; k++) s += ", out);
    print_plain(out, e->a);
    fputs(" * (double)k; s; })", out);
    return;
  }
}

/* ---------------------------------------------------------------- through cse.c */

typedef struct Nest {
  Cse *c;
  int i, j, n, k;   /* the loop variables, N, the summation variable */
} Nest;

static Sym dim_n; /* the dim i and j range over: a read at i or j is in range */

static Nest nest_new(Ctx *ctx) {
  Nest s;
  s.c = cse_new(ctx, 2);
  s.i = cse_leaf(s.c, "i", true, 1, &dim_n);
  s.j = cse_leaf(s.c, "j", true, 2, &dim_n);
  s.n = cse_leaf(s.c, "N", true, 0, NULL);
  s.k = -1;
  return s;
}

/* cond ? array[var + 1] * scale : 0.0, the read evaluated only where the guard holds. */
static int guarded_next(Nest *s, const char *array, int var, double scale) {
  Cse *c = s->c;
  int at = cse_op(c, VAL_ADD, var, cse_num(c, 1, true), -1);
  int cond = cse_op(c, VAL_LT, at, s->n, -1);
  cse_guard(c, 1);
  int load = cse_op(c, VAL_MUL, cse_load(c, array, false, at, false), cse_num(c, scale, false), -1);
  int zero = cse_num(c, 0.0, false);
  cse_guard(c, -1);
  return cse_op(c, VAL_SELECT, cond, load, zero);
}

static int build(Nest *s, const Expr *e) {
  Cse *c = s->c;
  switch (e->kind) {
  case E_NUM: return cse_num(c, e->num, false);
  case E_I: return cse_op(c, VAL_DOUBLE, s->i, -1, -1);
  case E_A: return cse_load(c, "A", false, s->i, true);
  case E_B: return cse_load(c, "B", false, s->j, true);
  case E_M: return cse_load(c, "M", false, cse_op(c, VAL_ADD, cse_op(c, VAL_MUL, s->i, s->n, -1), s->j, -1), true);
  case E_ANEXT: return guarded_next(s, "A", s->i, e->num);
  case E_BNEXT: return guarded_next(s, "B", s->j, e->num);
  case E_ADD: return cse_op(c, VAL_ADD, build(s, e->a), build(s, e->b), -1);
  case E_SUB: return cse_op(c, VAL_SUB, build(s, e->a), build(s, e->b), -1);
  case E_MUL: return cse_op(c, VAL_MUL, build(s, e->a), build(s, e->b), -1);
  case E_DIV: return cse_op(c, VAL_DIV, build(s, e->a), build(s, e->b), -1);
  case E_NEG: return cse_op(c, VAL_NEG, build(s, e->a), -1, -1);
  case E_SQRT: return cse_call(c, "sqrt", cse_call(c, "fabs", build(s, e->a), -1), -1);
  case E_DIAG: {
    int cond = cse_op(c, VAL_EQ, s->i, s->j, -1);
    cse_guard(c, 1);
    int a = build(s, e->a), b = build(s, e->b);
    cse_guard(c, -1);
    return cse_op(c, VAL_SELECT, cond, a, b);
  }
  case E_LESS: {
    int a = build(s, e->a), cond = cse_op(c, VAL_LT, a, build(s, e->b), -1);
    cse_guard(c, 1);
    int x = build(s, e->c), y = build(s, e->a);
    cse_guard(c, -1);
    return cse_op(c, VAL_SELECT, cond, x, y);
  }
  case E_SUM: {
    int k = cse_sumvar(c, "k");
    int lo = cse_num(c, 0, true), hi = cse_num(c, 2, true);
    cse_guard(c, 1);
    int body = cse_op(c, VAL_MUL, build(s, e->a), cse_op(c, VAL_DOUBLE, k, -1, -1), -1);
    cse_guard(c, -1);
    return cse_sum(c, k, lo, hi, body);
  }
  }
  fail_msg("expression kind %d", e->kind);
  return -1;
}

static const char *const signature =
    "(const NpgCtx *c, npg_idx N, const double *A, const double *B, const double *M, double *O1, double *O2, "
    "double *rows_)";

/* The nest of O1[i, j] = e1 and O2[i, j] = e2 through cse.c, as the function `name`: the
 * innermost loop a row at a time by the kernels when `rows` (then *nrows the scratch rows
 * it needs, -1 when it cannot). */
static void write_cse(FILE *out, Ctx *ctx, const char *name, const Expr *e1, const Expr *e2, bool rows, int *nrows) {
  Nest s = nest_new(ctx);
  int v1 = build(&s, e1), v2 = build(&s, e2);
  int off = cse_op(s.c, VAL_ADD, cse_op(s.c, VAL_MUL, s.i, s.n, -1), s.j, -1);
  cse_root(s.c, v1);
  cse_root(s.c, v2);
  cse_root(s.c, off);
  cse_plan(s.c);
  CseStore st[2] = {{"O1", off, v1, CSE_SET, -1}, {"O2", off, v2, CSE_SET, -1}};
  int nr = rows ? cse_rows_plan(s.c, st, 2) : -1;
  if (nrows) *nrows = nr;
  fprintf(out, "int %s%s {\n  (void)c;\n  (void)rows_;\n", name, signature);
  for (int r = 0; r < nr; r++) fprintf(out, "  double *const row%d_ = rows_ + %d * N;\n", r, r);
  cse_emit_level(s.c, out, 0, 1);
  fputs("  for (npg_idx i = 0; i < N; i++) {\n", out);
  cse_emit_level(s.c, out, 1, 2);
  if (nr >= 0) {
    cse_emit_rows(s.c, out, st, 2, "N", 2);
  } else {
    fputs("    for (npg_idx j = 0; j < N; j++) {\n", out);
    cse_emit_store(s.c, out, "O1", off, v1, 3);
    cse_emit_store(s.c, out, "O2", off, v2, 3);
    fputs("    }\n", out);
  }
  fputs("  }\n  return 0;\n}\n", out);
}

static void write_plain(FILE *out, const char *name, const Expr *e1, const Expr *e2) {
  fprintf(out, "int %s%s {\n  (void)c;\n  (void)rows_;\n", name, signature);
  fputs("  for (npg_idx i = 0; i < N; i++)\n    for (npg_idx j = 0; j < N; j++) {\n      O1[i * N + j] = ", out);
  print_plain(out, e1);
  fputs(";\n      O2[i * N + j] = ", out);
  print_plain(out, e2);
  fputs(";\n    }\n  return 0;\n}\n", out);
}

/* ---------------------------------------------------------------- running both */

typedef int (*NestFn)(const NpgCtx *c, npg_idx n, const double *A, const double *B, const double *M, double *O1,
                      double *O2, double *rows_);

/* n doubles that end where an unmapped page begins: reading one past them faults. */
static double *fenced(size_t n, void **map, size_t *maplen) {
  size_t page = (size_t)sysconf(_SC_PAGESIZE), bytes = n * sizeof(double);
  size_t len = (bytes + page - 1) / page * page + page;
  char *m = mmap(NULL, len, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (m == MAP_FAILED || mprotect(m + len - page, page, PROT_NONE) != 0) fail_msg("mmap");
  *map = m, *maplen = len;
  return (double *)(m + len - page - bytes);
}

/* How many times `what` occurs in `text`. */
static int occurrences(const char *text, const char *what) {
  int k = 0;
  for (const char *p = text; (p = strstr(p, what)); p += strlen(what)) k++;
  return k;
}

typedef struct Outcome {
  char *plain, *cse;        /* each function's text (malloc'd) */
} Outcome;

/* Compile the plain and the cse.c nest of (e1, e2) with libtcc, run both on random data
 * and require the same bits; with `rows`, the cse.c nest by the row kernels, which must
 * be possible. */
static Outcome run_pair(const Expr *e1, const Expr *e2, bool rows, unsigned seed) {
  Ctx ctx = {0};
  char *text = NULL;
  size_t len = 0;
  FILE *out = open_memstream(&text, &len);
  fputs(npg_abi_header, out);
  long plain_at = ftell(out);
  write_plain(out, "plain_nest", e1, e2);
  long cse_at = ftell(out);
  int nrows = -1;
  write_cse(out, &ctx, "cse_nest", e1, e2, rows, &nrows);
  fclose(out);
  arena_release(&ctx.arena);
  if (rows && nrows < 0) fail_msg("the row kernels cannot compute this nest:\n%s", text + cse_at);
  char err[4096];
  JitModule *m = jit_compile(text, JIT_TCC, err, sizeof err);
  if (!m) fail_msg("%s\n%s", err, text + plain_at);
  NestFn plain = (NestFn)jit_symbol(m, "plain_nest"), shared = (NestFn)jit_symbol(m, "cse_nest");
  assert_non_null(plain);
  assert_non_null(shared);
  void *ma, *mb;
  size_t la, lb;
  double *A = fenced(N, &ma, &la), *B = fenced(N, &mb, &lb);
  double M[N * N], P1[N * N], P2[N * N], S1[N * N], S2[N * N], scratch[16 * N];
  for (int k = 0; k < N; k++) {
    seed = seed * 1103515245u + 12345u, A[k] = 0.5 + (double)((seed >> 8) & 0xffff) / 65536;
    seed = seed * 1103515245u + 12345u, B[k] = 0.5 + (double)((seed >> 8) & 0xffff) / 65536;
  }
  for (int k = 0; k < N * N; k++) seed = seed * 1103515245u + 12345u, M[k] = (double)((seed >> 8) & 0xffff) / 65536 - 0.5;
  NpgCtx c = {0};
  c.rt = &npg_runtime;
  assert_int_equal(plain(&c, N, A, B, M, P1, P2, scratch), 0);
  assert_int_equal(shared(&c, N, A, B, M, S1, S2, scratch), 0);
  if (memcmp(P1, S1, sizeof P1) || memcmp(P2, S2, sizeof P2)) {
    for (int k = 0; k < N * N; k++)
      if (memcmp(&P1[k], &S1[k], sizeof(double)) || memcmp(&P2[k], &S2[k], sizeof(double)))
        fail_msg("entry %d: plain %.17g %.17g, cse %.17g %.17g\n%s", k, P1[k], P2[k], S1[k], S2[k], text + plain_at);
  }
  munmap(ma, la);
  munmap(mb, lb);
  jit_free(m);
  Outcome o = {strndup(text + plain_at, (size_t)(cse_at - plain_at)), strdup(text + cse_at)};
  free(text);
  return o;
}

static void outcome_free(Outcome o) {
  free(o.plain);
  free(o.cse);
}

/* ---------------------------------------------------------------- tests */

/* Random nests: shared equals unshared, bit for bit; and sharing happens (fewer square
 * roots printed than the trees hold). */
static void shared_equals_unshared(void **state) {
  (void)state;
  int plain = 0, shared = 0;
  for (unsigned t = 0; t < 60; t++) {
    static Gen g;
    memset(&g, 0, sizeof g);
    g.seed = 7919u * t + 1;
    const Expr *e1 = gen(&g, 4, true), *e2 = gen(&g, 4, true);
    Outcome o = run_pair(e1, e2, false, t);
    plain += occurrences(o.plain, "sqrt("), shared += occurrences(o.cse, "sqrt(");
    outcome_free(o);
  }
  print_message("60 random nests: %d square roots written, %d after sharing\n", plain, shared);
  assert_true(shared < plain);
}

/* Random nests the row kernels compute (libtcc's path): equal to the scalar loop. */
static void rows_equal_scalar(void **state) {
  (void)state;
  for (unsigned t = 0; t < 40; t++) {
    static Gen g;
    memset(&g, 0, sizeof g);
    g.seed = 104729u * t + 3;
    const Expr *e1 = gen_row(&g, 3), *e2 = gen_row(&g, 3);
    outcome_free(run_pair(e1, e2, true, t));
  }
}

/* The exact identities cse_op relies on: a + b is b + a, (q - p)^2 is (p - q)^2 — one
 * value each, one subtraction printed; and a guarded read used twice is still read only
 * under its guard (B and A end at an unmapped page: hoisting B[j + 1] or A[i + 1] out of
 * its choice reads past the end at the last entry). */
static void identities_and_guards(void **state) {
  (void)state;
  static Gen g;
  memset(&g, 0, sizeof g);
  const Expr *a = node(&g, E_A, NULL, NULL, NULL), *b = node(&g, E_B, NULL, NULL, NULL);
  const Expr *ab = node(&g, E_SUB, a, b, NULL), *ba = node(&g, E_SUB, b, a, NULL);
  const Expr *sq1 = node(&g, E_MUL, ab, ab, NULL), *sq2 = node(&g, E_MUL, ba, ba, NULL);
  Outcome o = run_pair(node(&g, E_ADD, sq1, a, NULL), node(&g, E_ADD, a, sq2, NULL), false, 1);
  assert_int_equal(occurrences(o.plain, " - "), 4);
  assert_int_equal(occurrences(o.cse, " - "), 1);
  outcome_free(o);

  /* two choices reading the same B[j + 1] (and A[i + 1]): the read is one value used
   * twice, yet never a local of its own before them */
  Expr *bn = (Expr *)node(&g, E_BNEXT, NULL, NULL, NULL), *bn2 = (Expr *)node(&g, E_BNEXT, NULL, NULL, NULL);
  Expr *an = (Expr *)node(&g, E_ANEXT, NULL, NULL, NULL), *an2 = (Expr *)node(&g, E_ANEXT, NULL, NULL, NULL);
  bn->num = an->num = 1, bn2->num = an2->num = 2;
  const Expr *twice = node(&g, E_ADD, bn, node(&g, E_MUL, bn2, bn, NULL), NULL);
  const Expr *outer = node(&g, E_MUL, an, node(&g, E_ADD, an2, a, NULL), NULL);
  o = run_pair(twice, node(&g, E_SUB, outer, node(&g, E_SUM, bn, NULL, NULL), NULL), false, 2);
  outcome_free(o);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(shared_equals_unshared),
      cmocka_unit_test(rows_equal_scalar),
      cmocka_unit_test(identities_and_guards),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
