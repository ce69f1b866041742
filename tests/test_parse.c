/* test_parse.c — lexer and parser, table driven: source expressions and the
 * text the parser's tree prints back (precedence and associativity made
 * explicit), and programs that must tokenize or parse a certain way. */
#include "testutil.h"

static char *parse_expr_text(Ctx *ctx, const char *expr) {
  char *src = arena_printf(ctx, "y = %s\n", expr);
  const SrcFile *f = source_from_string(ctx, "t.npg", src, strlen(src));
  Decl *d = parse_program(ctx, f);
  return node_str(ctx, d->body);
}

static void expressions(void **state) {
  (void)state;
  static const struct { const char *src, *printed; } cases[] = {
      {"a + b * c", "a + b * c"},
      {"(a + b) * c", "(a + b) * c"},
      {"a - b - c", "a - b - c"},
      {"a - (b - c)", "a - (b - c)"},
      {"a / b / c", "a / b / c"},
      {"-x^2", "-x^2"},
      {"(-x)^2", "(-x)^2"},
      {"x^-1", "x^(-1)"},
      {"x^(1/2)", "x^(1 / 2)"},
      {"x^y^z", "x^(y^z)"},
      {"g[tri[f, 1]] - g[tri[f, 0]]", "g[tri[f, 1]] - g[tri[f, 0]]"},
      {"[a, b][1]", "[a, b][1]"},
      {"sum(k = 0..D-1, x[k])", "sum(k = 0..D - 1, x[k])"},
      {"if(i == j && k < 3, 1, 0)", "if(i == j && k < 3, 1, 0)"},
      {"1e-3 * 2.5", "0.001 * 2.5"},
      {"+a", "a"},
      {"!(i == j) || i < j", "!(i == j) || i < j"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    Ctx ctx = {0};
    jmp_buf env;
    ctx.on_error = &env;
    if (setjmp(env)) fail_msg("'%s' does not parse:\n%s", cases[i].src, ctx.msg);
    char *got = parse_expr_text(&ctx, cases[i].src);
    if (strcmp(got, cases[i].printed) != 0) fail_msg("'%s' parsed as '%s', expected '%s'", cases[i].src, got, cases[i].printed);
    arena_release(&ctx.arena);
  }
}

static void tokens(void **state) {
  (void)state;
  Ctx ctx = {0};
  jmp_buf env;
  ctx.on_error = &env;
  if (setjmp(env)) fail_msg("lexing failed: %s", ctx.msg);
  const char *src = "x[0..3] # comment\n  1.5e+2 ->\tfoo_1";
  const SrcFile *f = source_from_string(&ctx, "t.npg", src, strlen(src));
  int n;
  Token *t = lex_file(&ctx, f, &n);
  static const char *const want[] = {"x", "[", "0", "..", "3", "]", "1.5e+2", "->", "foo_1"};
  assert_int_equal(n, 10); /* + EOF */
  for (int i = 0; i < 9; i++) assert_string_equal(t[i].text, want[i]);
  assert_true(t[2].is_int);
  assert_false(t[6].is_int);
  assert_true(t[6].num == 150.0);
  assert_true(t[0].bol);
  assert_false(t[5].bol);
  assert_true(t[6].bol);            /* first token on line 2 */
  assert_int_equal(t[6].loc.line, 2);
  assert_int_equal(t[6].loc.col, 3);
  assert_int_equal(t[8].loc.col, 13); /* after a tab, columns count bytes */
  assert_int_equal(t[9].kind, TK_EOF);
  arena_release(&ctx.arena);
}

/* Statements: one per line; continuation inside brackets. */
static void statements(void **state) {
  (void)state;
  NpgProgram *p = compile_text("s.npg",
                               "input x : real[3]\n"
                               "a = [x[0],\n"
                               "     x[1]]; b = x[2]\n"
                               "output c = a[0] * b\n");
  ir_ok(p);
  npg_free(p);
  p = compile_text("s.npg", "input x : real[3]\noutput c = x[0] x[1]\n");
  assert_false(npg_ok(p));
  assert_non_null(strstr(npg_error(p), "s.npg:2:17: error: unexpected 'x' after the end of the statement"));
  npg_free(p);
}

/* Diagnostics have the file:line:col, the source line and a caret under the
 * column. */
static void diagnostic_format(void **state) {
  (void)state;
  NpgProgram *p = compile_text("d.npg", "input x : real[2]\noutput y = x[0] + z\n");
  assert_false(npg_ok(p));
  assert_string_equal(npg_error(p), "d.npg:2:19: error: unknown name 'z'\noutput y = x[0] + z\n                  ^\n");
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(expressions),
      cmocka_unit_test(tokens),
      cmocka_unit_test(statements),
      cmocka_unit_test(diagnostic_format),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
