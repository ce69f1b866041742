/* parse.c — recursive-descent parser: tokens to Decls and Nodes.
 * The full grammar is compiler/front/grammar.txt; each function carries its rule.
 * `use NAME` reads <std_dir>/npg/NAME.npg and splices its fn definitions.
 */
#include <errno.h>
#include <string.h>

#include "compile.h"

#define MAX_NESTING 200  /* deeper expressions are refused, not a stack overflow */

typedef struct Parser {
  Ctx *ctx;
  Token *tok;
  int pos, n;
  int depth;            /* expression nesting */
  bool is_module;       /* a `use`d file: only fn and use allowed */
  PtrVec *used;         /* module names already imported */
} Parser;

static const char *const keywords[] = {"dim", "param", "input", "output", "fn", "op",
                                       "extern", "share", "basis", "inline", "use", "state", "next", NULL};

bool is_keyword(const char *s) {
  for (int i = 0; keywords[i]; i++)
    if (strcmp(keywords[i], s) == 0) return true;
  return false;
}

static Token *peek(Parser *p) { return &p->tok[p->pos]; }
static Token *peek2(Parser *p) { return &p->tok[p->pos + 1 < p->n ? p->pos + 1 : p->pos]; }
static Token *next(Parser *p) {
  Token *t = &p->tok[p->pos];
  if (t->kind != TK_EOF) p->pos++;
  return t;
}

static bool is_punct(Token *t, const char *s) { return t->kind == TK_PUNCT && strcmp(t->text, s) == 0; }
static bool is_ident(Token *t, const char *s) { return t->kind == TK_IDENT && strcmp(t->text, s) == 0; }

static const char *describe(Parser *p, Token *t) {
  switch (t->kind) {
  case TK_EOF: return "end of file";
  case TK_NUM: return arena_printf(p->ctx, "number '%s'", t->text);
  case TK_IDENT: return arena_printf(p->ctx, "'%s'", t->text);
  default: return arena_printf(p->ctx, "'%s'", t->text);
  }
}

/* Where to report that something is missing before token t: if t starts
 * a new line (or is the end of the file), right after the previous token,
 * since that is where the user stopped writing. */
static Loc missing_at(Parser *p, Token *t, const char **found) {
  if ((t->bol || t->kind == TK_EOF) && p->pos > 0) {
    Token *prev = &p->tok[p->pos - 1];
    Loc l = prev->loc;
    l.col += prev->len;
    l.off += (size_t)prev->len;
    *found = t->kind == TK_EOF ? "end of file" : "end of line";
    return l;
  }
  *found = describe(p, t);
  return t->loc;
}

static bool accept(Parser *p, const char *s) {
  if (is_punct(peek(p), s)) {
    next(p);
    return true;
  }
  return false;
}

static Token *expect(Parser *p, const char *s, const char *what) {
  Token *t = peek(p);
  if (!is_punct(t, s)) {
    const char *found;
    Loc at = missing_at(p, t, &found);
    error_at(p->ctx, at, "expected '%s' %s, found %s", s, what, found);
  }
  return next(p);
}

/* Closing bracket with a note at the opening one. */
static void expect_close(Parser *p, const char *s, Token *open) {
  Token *t = peek(p);
  if (!is_punct(t, s))
    error_note(p->ctx, t->loc, open->loc, arena_printf(p->ctx, "to match this '%s'", open->text),
               "expected '%s', found %s", s, describe(p, t));
  next(p);
}

static Token *expect_ident(Parser *p, const char *what) {
  Token *t = peek(p);
  if (t->kind != TK_IDENT || (t->bol && p->pos > 0)) {
    const char *found;
    Loc at = missing_at(p, t, &found);
    error_at(p->ctx, at, "expected %s, found %s", what, found);
  }
  return next(p);
}

static Token *expect_name(Parser *p, const char *what) {
  Token *t = expect_ident(p, what);
  if (is_keyword(t->text)) error_at(p->ctx, t->loc, "'%s' is a keyword and cannot be used as a name", t->text);
  return t;
}

static Node *parse_expr(Parser *p);

/* args = expr { "," expr }, until `close`. */
static Node **parse_list(Parser *p, const char *close, Token *open, int *n) {
  PtrVec v = {0};
  if (!is_punct(peek(p), close)) {
    do {
      vec_push(p->ctx, &v, parse_expr(p));
    } while (accept(p, ","));
  }
  expect_close(p, close, open);
  *n = v.n;
  return (Node **)v.v;
}

/* primary = number | ident | call | "(" expr ")" | "[" expr { "," expr } "]"
 *         | "sum" "(" ident "=" expr ".." expr "," expr ")" */
static Node *parse_primary(Parser *p) {
  Ctx *ctx = p->ctx;
  Token *t = peek(p);
  if (t->kind == TK_NUM) {
    next(p);
    return new_num(ctx, t->num, t->is_int, t->loc);
  }
  if (is_punct(t, "(")) {
    next(p);
    Node *e = parse_expr(p);
    expect_close(p, ")", t);
    return e;
  }
  if (is_punct(t, "[")) {
    next(p);
    Node *n = new_node(ctx, N_VEC, t->loc);
    n->args = parse_list(p, "]", t, &n->nargs);
    if (n->nargs == 0) error_at(ctx, t->loc, "empty vector literal");
    return n;
  }
  if (t->kind == TK_IDENT) {
    if (is_keyword(t->text)) error_at(ctx, t->loc, "'%s' is a keyword and cannot be used as a name", t->text);
    next(p);
    if (strcmp(t->text, "sum") == 0 && is_punct(peek(p), "(")) {
      Token *open = next(p);
      Node *n = new_node(ctx, N_SUM, t->loc);
      Token *v = expect_name(p, "the summation variable after 'sum('");
      n->name = v->text;
      expect(p, "=", "after the summation variable (sum(k = a..b, expr))");
      n->a = parse_expr(p);
      expect(p, "..", "between the bounds of the sum (sum(k = a..b, expr))");
      n->b = parse_expr(p);
      expect(p, ",", "after the bounds of the sum (sum(k = a..b, expr))");
      n->c = parse_expr(p);
      expect_close(p, ")", open);
      return n;
    }
    if (is_punct(peek(p), "(")) {
      Token *open = next(p);
      Node *n = new_node(ctx, N_CALL, t->loc);
      n->name = t->text;
      n->args = parse_list(p, ")", open, &n->nargs);
      return n;
    }
    Node *n = new_node(ctx, N_NAME, t->loc);
    n->name = t->text;
    return n;
  }
  const char *found;
  Loc at = missing_at(p, t, &found);
  error_at(ctx, at, "expected an expression, found %s", found);
}

/* postfix = primary { "[" expr { "," expr } "]" } */
static Node *parse_postfix(Parser *p) {
  Node *e = parse_primary(p);
  while (is_punct(peek(p), "[") && !peek(p)->bol) {
    Token *open = next(p);
    Node *n = new_node(p->ctx, N_INDEX, e->loc);  /* diagnostics point at the name */
    n->a = e;
    n->args = parse_list(p, "]", open, &n->nargs);
    if (n->nargs == 0) error_at(p->ctx, open->loc, "empty index list");
    e = n;
  }
  return e;
}

static Node *parse_unary(Parser *p);
static Node *parse_unary1(Parser *p, Token *t);
static void operand_follows(Parser *p, Token *op);

/* power = postfix [ "^" unary ] */
static Node *parse_power(Parser *p) {
  Node *base = parse_postfix(p);
  Token *t = peek(p);
  if (is_punct(t, "^")) {
    next(p);
    operand_follows(p, t);
    Node *n = new_node(p->ctx, N_POW, t->loc);
    n->a = base;
    n->b = parse_unary(p);
    return n;
  }
  return base;
}

/* unary = ( "-" | "+" | "!" ) unary | power */
static Node *parse_unary(Parser *p) {
  Token *t = peek(p);
  if (++p->depth > MAX_NESTING) error_at(p->ctx, t->loc, "expression nested too deeply (more than %d levels)", MAX_NESTING);
  Node *n = parse_unary1(p, t);
  p->depth--;
  return n;
}

static Node *parse_unary1(Parser *p, Token *t) {
  if (is_punct(t, "-") || is_punct(t, "!")) {
    next(p);
    Node *n = new_node(p->ctx, is_punct(t, "-") ? N_NEG : N_NOT, t->loc);
    n->a = parse_unary(p);
    return n;
  }
  if (is_punct(t, "+")) {
    next(p);
    return parse_unary(p);
  }
  return parse_power(p);
}

/* A binary operator at the end of a line whose right operand would be the
 * start of the next statement ("x +" then "s = ..."): report the operator. */
static void operand_follows(Parser *p, Token *op) {
  Token *t = peek(p);
  if (t->kind == TK_EOF || (t->bol && t->kind == TK_IDENT && (is_keyword(t->text) || is_punct(peek2(p), "="))))
    error_at(p->ctx, op->loc, "expected an expression after '%s' at the end of the line", op->text);
}

static Node *binary(Parser *p, NodeKind k, Token *t, Node *a, Node *b) {
  Node *n = new_node(p->ctx, k, t->loc);
  n->a = a;
  n->b = b;
  return n;
}

/* mul = unary { ( "*" | "/" ) unary } */
static Node *parse_mul(Parser *p) {
  Node *e = parse_unary(p);
  for (;;) {
    Token *t = peek(p);
    NodeKind k = is_punct(t, "*") ? N_MUL : is_punct(t, "/") ? N_DIV : N_NUM;
    if (k == N_NUM) return e;
    next(p);
    /* `x**2` (Python, Fortran): the power is `^` here */
    if (k == N_MUL && is_punct(peek(p), "*") && peek(p)->loc.off == t->loc.off + 1)
      error_at(p->ctx, t->loc, "'**' is not an operator: write a power as x^2 (or x^(1/2))");
    operand_follows(p, t);
    e = binary(p, k, t, e, parse_unary(p));
  }
}

/* add = mul { ( "+" | "-" ) mul } */
static Node *parse_add(Parser *p) {
  Node *e = parse_mul(p);
  for (;;) {
    Token *t = peek(p);
    NodeKind k = is_punct(t, "+") ? N_ADD : is_punct(t, "-") ? N_SUB : N_NUM;
    if (k == N_NUM) return e;
    next(p);
    operand_follows(p, t);
    e = binary(p, k, t, e, parse_mul(p));
  }
}

/* cmp = add [ ( "==" | "!=" | "<" | "<=" | ">" | ">=" ) add ] */
static Node *parse_cmp(Parser *p) {
  static const struct { const char *s; NodeKind k; } cmps[] = {
      {"==", N_EQ}, {"!=", N_NE}, {"<", N_LT}, {"<=", N_LE}, {">", N_GT}, {">=", N_GE}};
  Node *e = parse_add(p);
  Token *t = peek(p);
  for (size_t i = 0; i < sizeof cmps / sizeof cmps[0]; i++)
    if (is_punct(t, cmps[i].s)) {
      next(p);
      e = binary(p, cmps[i].k, t, e, parse_add(p));
      Token *u = peek(p);
      for (size_t j = 0; j < sizeof cmps / sizeof cmps[0]; j++)
        if (is_punct(u, cmps[j].s))
          error_at(p->ctx, u->loc, "comparisons do not chain: write (a %s b) && (b %s c)", t->text, u->text);
      return e;
    }
  return e;
}

/* and = cmp { "&&" cmp } */
static Node *parse_and(Parser *p) {
  Node *e = parse_cmp(p);
  for (Token *t = peek(p); is_punct(t, "&&"); t = peek(p)) e = (next(p), binary(p, N_AND, t, e, parse_cmp(p)));
  return e;
}

/* or = and { "||" and } */
static Node *parse_or(Parser *p) {
  Node *e = parse_and(p);
  for (Token *t = peek(p); is_punct(t, "||"); t = peek(p)) e = (next(p), binary(p, N_OR, t, e, parse_and(p)));
  return e;
}

static Node *parse_expr(Parser *p) { return parse_or(p); }

/* A definition's body: an expression no taller than the passes take. */
static Node *parse_body(Parser *p) {
  Token *at = peek(p);
  Node *body = parse_expr(p);
  int h = node_height(body, MAX_EXPR_HEIGHT);
  if (h < 0) error_plain(p->ctx, "out of memory");
  if (h > MAX_EXPR_HEIGHT)
    error_at(p->ctx, at->loc, "expression too deep (more than %d levels: a chain of that many terms, or nested "
                              "calls); split it into named definitions or write it with sum()", MAX_EXPR_HEIGHT);
  return body;
}

/* ---------------------------------------------------------------- statements */

static Decl *new_decl(Parser *p, DeclKind kind, Loc loc) {
  Decl *d = arena_alloc(p->ctx, sizeof *d);
  d->kind = kind;
  d->loc = loc;
  d->basis_max = -1;
  d->basis_energy = -1;
  d->basis_center = -1;
  return d;
}

/* names = ident { "," ident } */
static void parse_names(Parser *p, Decl *d, const char *what) {
  PtrVec names = {0}, locs = {0};
  do {
    Token *t = expect_name(p, what);
    vec_push(p->ctx, &names, (void *)t->text);
    Loc *l = arena_alloc(p->ctx, sizeof *l);
    *l = t->loc;
    vec_push(p->ctx, &locs, l);
  } while (accept(p, ","));
  d->nnames = names.n;
  d->names = (const char **)names.v;
  d->name_locs = arena_alloc(p->ctx, sizeof(Loc) * (size_t)names.n);
  for (int i = 0; i < names.n; i++) d->name_locs[i] = *(Loc *)locs.v[i];
}

/* ivars = "[" ident ":" ident { "," ident ":" ident } "]" */
static void parse_ivars(Parser *p, Decl *d) {
  Token *open = expect(p, "[", "before the index variables");
  do {
    if (d->nivars == MAX_AXES) error_at(p->ctx, peek(p)->loc, "too many index variables (at most %d)", MAX_AXES);
    Token *v = peek(p);
    if (v->kind == TK_NUM)
      error_at(p->ctx, v->loc, "expected an index variable 'name:DIM' in a definition, found %s", describe(p, v));
    v = expect_name(p, "an index variable (i:F)");
    if (!is_punct(peek(p), ":"))
      error_at(p->ctx, peek(p)->loc, "index variable '%s' needs a dim: write %s:DIM", v->text, v->text);
    next(p);
    Token *dim = peek(p);
    if (dim->kind != TK_IDENT)
      error_at(p->ctx, dim->loc, "index variable '%s' must range over a declared dim, found %s", v->text,
               describe(p, dim));
    next(p);
    IndexVarDecl *iv = &d->ivars[d->nivars++];
    iv->name = v->text;
    iv->loc = v->loc;
    iv->dim = dim->text;
    iv->dim_loc = dim->loc;
  } while (accept(p, ","));
  expect_close(p, "]", open);
}

/* type = ( "real" | "int" ) [ "[" axis { "," axis } "]" ] */
static void parse_type(Parser *p, Decl *d) {
  Token *t = expect_ident(p, "a type ('real' or 'int')");
  if (strcmp(t->text, "real") == 0) d->is_int = false;
  else if (strcmp(t->text, "int") == 0) d->is_int = true;
  else error_at(p->ctx, t->loc, "unknown type '%s': expected 'real' or 'int'", t->text);
  if (!is_punct(peek(p), "[") || peek(p)->bol) return;
  Token *open = next(p);
  bool seen_static = false;
  do {
    Token *a = peek(p);
    if (d->naxes == MAX_AXES) error_at(p->ctx, a->loc, "too many axes (at most %d)", MAX_AXES);
    Axis *ax = &d->axes[d->naxes++];
    ax->loc = a->loc;
    if (a->kind == TK_NUM) {
      if (!a->is_int || a->num < 1 || a->num > 64)
        error_at(p->ctx, a->loc, "a static axis size must be an integer from 1 to 64, found %s", a->text);
      ax->size = (int)a->num;
      seen_static = true;
    } else if (a->kind == TK_IDENT) {
      if (seen_static)
        error_at(p->ctx, a->loc, "dim axis '%s' after a static axis: static axes must come last", a->text);
      ax->dim = a->text;
    } else {
      error_at(p->ctx, a->loc, "expected a dim name or a static size, found %s", describe(p, a));
    }
    next(p);
  } while (accept(p, ","));
  expect_close(p, "]", open);
}

/* def = ident [ ivars ] "=" expr */
static Decl *parse_def(Parser *p, DeclKind kind, Token *name) {
  Decl *d = new_decl(p, kind, name->loc);
  d->name = name->text;
  d->name_loc = name->loc;
  if (is_punct(peek(p), "[")) parse_ivars(p, d);
  Token *eq = peek(p);
  if (!is_punct(eq, "=")) {
    if (is_punct(eq, ":"))
      error_at(p->ctx, eq->loc, "'%s : type' declares nothing: write 'param %s : ...' or 'input %s : ...'",
               name->text, name->text, name->text);
    error_at(p->ctx, eq->loc, "expected '=' in the definition of '%s', found %s", name->text, describe(p, eq));
  }
  next(p);
  d->body = parse_body(p);
  return d;
}

/* next u [ivars] = expr: the state u after one step, the output stage u.next; residual next u
 * [ivars] = expr: u.next the zero of expr (an implicit step, lowered by sema), the output stage
 * u.residual. */
static Decl *parse_next_def(Parser *p, bool residual) {
  if (residual) next(p); /* past `next` */
  Token *n = expect_name(p, residual ? "the state's name after 'residual next'" : "the state's name after 'next'");
  Decl *d = parse_def(p, D_STAGE, n);
  d->name = arena_printf(p->ctx, "%s.%s", n->text, residual ? "residual" : "next");
  if (residual) d->residual_of = n->text;
  else d->next_of = n->text;
  d->next_of_loc = n->loc;
  d->is_output = true;
  return d;
}

/* opdef = ident ivars "=" expr [ "on" ident "->" ident ] */
static Decl *parse_opdef(Parser *p) {
  Token *name = expect_name(p, "the operator's name after 'op'");
  if (!is_punct(peek(p), "["))
    error_at(p->ctx, peek(p)->loc, "operator '%s' needs index variables: op %s[i:N, j:N] = ...", name->text,
             name->text);
  Decl *d = parse_def(p, D_OP, name);
  if (is_ident(peek(p), "on") && !peek(p)->bol) {
    Token *on = next(p);
    d->on_loc = on->loc;
    Token *from = expect_name(p, "the column quantity after 'on'");
    d->on_from = from->text;
    d->on_loc = from->loc;
    expect(p, "->", "between the quantities of 'on u -> p'");
    Token *to = expect_name(p, "the row quantity after '->'");
    d->on_to = to->text;
    d->on_to_loc = to->loc;
  }
  return d;
}

static void parse_file(Parser *p, Decl ***tail);

static void parse_use(Parser *p, Token *kw, Decl ***tail) {
  Ctx *ctx = p->ctx;
  Token *m = expect_name(p, "a module name after 'use'");
  for (const char *c = m->text; *c; c++)
    if (!((*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') || *c == '_'))
      error_at(ctx, m->loc, "module names are lowercase letters, digits and '_'");
  for (int i = 0; i < p->used->n; i++)
    if (strcmp(p->used->v[i], m->text) == 0) return; /* imported once */
  vec_push(ctx, p->used, (void *)m->text);
  const char *dir = ctx->std_dir ? ctx->std_dir : ".";
  char *path = arena_printf(ctx, "%s/npg/%s.npg", dir, m->text);
  SrcFile *f = source_read(ctx, path);
  if (!f) error_at(ctx, m->loc, "cannot read module '%s' (%s): %s", m->text, path, strerror(errno));
  (void)kw;
  Parser sub = {0};
  sub.ctx = ctx;
  sub.tok = lex_file(ctx, f, &sub.n);
  sub.is_module = true;
  sub.used = p->used;
  parse_file(&sub, tail);
}

static void parse_stmt(Parser *p, Decl ***tail) {
  Ctx *ctx = p->ctx;
  Token *t = peek(p);
  Decl *d = NULL;
  if (t->kind != TK_IDENT) error_at(ctx, t->loc, "expected a declaration or a definition, found %s", describe(p, t));
  next(p);
  const char *kw = t->text;
  if (is_keyword(kw) && (is_punct(peek(p), "=") || (is_punct(peek(p), "[") && strcmp(kw, "output") != 0)))
    error_at(ctx, t->loc, "'%s' is a keyword and cannot be used as a name", kw);
  if (p->is_module && strcmp(kw, "fn") != 0 && strcmp(kw, "use") != 0)
    error_at(ctx, t->loc, "a module may contain only 'fn' and 'use' statements");
  if (strcmp(kw, "dim") == 0) {
    d = new_decl(p, D_DIM, t->loc);
    parse_names(p, d, "a dim name");
  } else if (strcmp(kw, "param") == 0 || strcmp(kw, "input") == 0 || strcmp(kw, "state") == 0) {
    d = new_decl(p, kw[0] == 'p' ? D_PARAM : D_INPUT, t->loc);
    d->is_state = kw[0] == 's';
    Token *n = expect_name(p, arena_printf(ctx, "a name after '%s'", kw));
    d->name = n->text;
    d->name_loc = n->loc;
    if (is_punct(peek(p), "="))
      error_at(ctx, peek(p)->loc, "%s '%s' is bound from data and cannot have a definition; declare its type: %s %s : real[...]",
               kw, n->text, kw, n->text);
    expect(p, ":", arena_printf(ctx, "after '%s %s' (%s %s : real[N])", kw, n->text, kw, n->text));
    parse_type(p, d);
  } else if (strcmp(kw, "next") == 0 || (strcmp(kw, "residual") == 0 && is_ident(peek(p), "next"))) {
    d = parse_next_def(p, kw[0] == 'r');
  } else if (strcmp(kw, "fn") == 0) {
    Token *n = expect_name(p, "a function name after 'fn'");
    d = new_decl(p, D_FN, n->loc);
    d->name = n->text;
    d->name_loc = n->loc;
    Token *open = expect(p, "(", arena_printf(ctx, "after 'fn %s'", n->text));
    if (!is_punct(peek(p), ")")) parse_names(p, d, "a parameter name");
    expect_close(p, ")", open);
    expect(p, "=", arena_printf(ctx, "after the parameters of fn '%s'", n->text));
    d->body = parse_body(p);
  } else if (strcmp(kw, "op") == 0) {
    d = parse_opdef(p);
  } else if (strcmp(kw, "extern") == 0) {
    Token *n = expect_name(p, "a name after 'extern'");
    d = new_decl(p, D_EXTERN, n->loc);
    d->name = n->text;
    d->name_loc = n->loc;
    if (is_punct(peek(p), "[")) parse_ivars(p, d);
    Token *of = peek(p);
    if (!is_ident(of, "of"))
      error_at(ctx, of->loc, "expected 'of' and the quantities extern '%s' depends on, found %s", n->text,
               describe(p, of));
    next(p);
    parse_names(p, d, "a quantity after 'of'");
  } else if (strcmp(kw, "share") == 0) {
    d = new_decl(p, D_SHARE, t->loc);
    parse_names(p, d, "a quantity after 'share'");
    if (d->nnames < 2) error_at(ctx, t->loc, "'share' needs at least two quantities");
  } else if (strcmp(kw, "basis") == 0) {
    d = new_decl(p, D_BASIS, t->loc);
    parse_names(p, d, "a quantity after 'basis'");
    expect(p, ":", "after the quantities of 'basis' (basis x: cap 60, energy 0.999, center on; or cap=60)");
    do {
      /* `cap` as on the command line (--cap, --basis x:cap=N); `max` is its older name */
      Token *o = expect_ident(p, "'cap', 'energy', 'center', 'reduce' or 'product'");
      accept(p, "="); /* `cap=12` as --basis writes it, or `cap 12` */
      Token *v = peek(p);
      if (strcmp(o->text, "product") == 0) { /* an SPD op of the program: BᵀK0B = I (pyMOR's H¹ product) */
        v = expect_name(p, "the name of an op after 'product' (basis u: product K0)");
        d->basis_product = v->text;
        d->basis_product_loc = v->loc;
        continue;
      }
      if (strcmp(o->text, "reduce") == 0) { /* as --reduce STAGE:interp|galerkin (DESIGN §12) */
        if (!is_ident(v, "interp") && !is_ident(v, "galerkin"))
          error_at(ctx, v->loc, "expected 'interp' or 'galerkin' after 'reduce', found %s", describe(p, v));
        next(p);
        d->basis_reduce = strcmp(v->text, "interp") == 0 ? STAGE_REDUCE_INTERP : STAGE_REDUCE_GALERKIN;
        continue;
      }
      if (strcmp(o->text, "center") == 0) {
        if (!is_ident(v, "on") && !is_ident(v, "off"))
          error_at(ctx, v->loc, "expected 'on' or 'off' after 'center', found %s", describe(p, v));
        next(p);
        d->basis_center = strcmp(v->text, "on") == 0;
        continue;
      }
      if (v->kind != TK_NUM) error_at(ctx, v->loc, "expected a number after '%s', found %s", o->text, describe(p, v));
      next(p);
      if (strcmp(o->text, "cap") == 0 || strcmp(o->text, "max") == 0) {
        if (!v->is_int || v->num < 1 || v->num > 100000)
          error_at(ctx, v->loc, "'%s' takes a whole number of basis vectors from 1 to 100000", o->text);
        d->basis_max = (int)v->num;
      } else if (strcmp(o->text, "energy") == 0) {
        if (!(v->num > 0 && v->num <= 1))
          error_at(ctx, v->loc, "'energy' is a fraction in (0, 1], found %s", v->text);
        d->basis_energy = v->num;
      } else {
        error_at(ctx, o->loc, "unknown basis option '%s': expected 'cap', 'energy', 'center', 'reduce' or 'product'",
                 o->text);
      }
    } while (accept(p, ","));
  } else if (strcmp(kw, "inline") == 0) {
    d = new_decl(p, D_INLINE, t->loc);
    parse_names(p, d, "a quantity after 'inline'");
  } else if (strcmp(kw, "use") == 0) {
    parse_use(p, t, tail);
  } else if (strcmp(kw, "output") == 0) {
    Token *n = peek(p);
    if (is_ident(n, "op")) {
      next(p);
      d = parse_opdef(p);
      d->is_output = true;
    } else {
      n = expect_name(p, "a name after 'output'");
      Token *after = peek(p);
      if (after->kind != TK_EOF && !after->bol && !is_punct(after, ",") && !is_punct(after, "[") &&
          !is_punct(after, "=") && !is_punct(after, ";"))
        error_at(ctx, after->loc, "expected '=' in the definition of output '%s', found %s", n->text, describe(p, after));
      if (is_punct(peek(p), "[") || is_punct(peek(p), "=")) {
        d = parse_def(p, D_STAGE, n);
        d->is_output = true;
      } else {
        d = new_decl(p, D_OUTPUT, n->loc);
        p->pos--;
        parse_names(p, d, "a quantity after 'output'");
      }
    }
  } else if (is_keyword(kw)) {
    internal_error(ctx, __FILE__, __LINE__, "keyword without a statement");
  } else {
    Token *after = peek(p);
    if (!is_punct(after, "=") && !is_punct(after, "[")) {
      if (is_punct(after, ":"))
        error_at(ctx, after->loc, "'%s : type' declares nothing: write 'param %s : ...' or 'input %s : ...'", kw,
                 kw, kw);
      if (after->kind != TK_EOF && !after->bol)
        error_at(ctx, after->loc, "expected '=' or '[' after '%s' to define it, found %s", kw, describe(p, after));
      error_at(ctx, after->loc, "expected '=' or '[' after '%s' to define it, found %s", kw, describe(p, after));
    }
    d = parse_def(p, D_STAGE, t);
  }
  if (d) {
    **tail = d;
    *tail = &d->next;
  }
  /* One statement per line. */
  Token *e = peek(p);
  if (accept(p, ";")) return;
  if (e->kind != TK_EOF && !e->bol)
    error_at(ctx, e->loc, "unexpected %s after the end of the statement (one statement per line)", describe(p, e));
}

static void parse_file(Parser *p, Decl ***tail) {
  while (peek(p)->kind != TK_EOF) {
    while (accept(p, ";")) {}
    if (peek(p)->kind == TK_EOF) break;
    parse_stmt(p, tail);
  }
}

Decl *parse_program(Ctx *ctx, const SrcFile *file) {
  Parser p = {0};
  PtrVec used = {0};
  p.ctx = ctx;
  p.tok = lex_file(ctx, file, &p.n);
  p.used = &used;
  Decl *head = NULL, **tail = &head;
  parse_file(&p, &tail);
  (void)peek2;
  return head;
}
