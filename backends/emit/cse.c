/* cse.c — the values computed in one loop nest, as a graph: every distinct
 * subexpression is built once (common subexpression elimination by hashing)
 * and printed as a local in the outermost loop whose variables it reads
 * (loop-invariant hoisting), so generated C does little work per entry even
 * under libtcc, which does neither; and gcc sees plain loops it vectorizes.
 *
 * Sharing and hoisting never change a result: a value is computed by the
 * same operations in the same order, only fewer times (two spellings are
 * one value only by an identity exact in IEEE arithmetic, cse_op). Two
 * things are never
 * moved out of the place they were written: a read that may fall outside its
 * array where a guard does not hold (`if` branches, DESIGN §3: the branch
 * not taken is never evaluated), and anything that reads the variable of a
 * summation loop (printed inside that loop). */
#include <string.h>

#include "emit.h"

typedef struct Val {
  ValOp op;
  bool is_int;
  double num;          /* VAL_NUM */
  const char *text;    /* VAL_LEAF: C text; VAL_LOAD: array; VAL_CALL: function; VAL_SUM: variable */
  int a, b, c;         /* operands, -1 when absent */
  int level;           /* innermost loop of the nest whose variable it reads, 0 for none */
  uint64_t pin;        /* summation variables it reads, one bit each */
  bool unsafe;         /* reads what may be out of range outside its guard */
  const Sym *range;    /* VAL_LEAF of an index variable: the dim it ranges over */
  const char *hint;    /* name for its local */
  /* planning */
  bool reached, named, emitted;
  bool pending;        /* declared; defined where its statement reads it */
  int uses, eval;      /* users; the deepest loop it is evaluated in */
  const char *local;
  unsigned stamp;
  /* rows (cse_rows_plan) */
  unsigned char row;   /* RowKind */
  int outer;           /* ROW_COND: the outer loop variable; ROW_VALUE: the store it is computed in, or -1 */
  int last;            /* ROW_VALUE: the last value reading it */
  int buf;             /* ROW_VALUE: its scratch row, or -1 */
} Val;

/* What a value of the innermost loop is, row-wise (cse_rows_plan). */
typedef enum RowKind {
  ROW_NONE,   /* not of the innermost loop: a scalar per row */
  ROW_INDEX,  /* the innermost loop variable */
  ROW_OFFSET, /* it plus a scalar: a unit-stride offset */
  ROW_COND,   /* the outer loop variable `outer` ==, != the innermost one */
  ROW_LOAD,   /* a read at a unit-stride offset: a pointer into its array */
  ROW_VALUE,  /* computed by a row kernel */
} RowKind;

struct Cse {
  Ctx *ctx;
  Val *v;
  int n, cap;
  int *table;          /* open addressing: value ids, -1 empty */
  int tcap;
  int nloops;
  int nbits;           /* summation variables given a bit */
  int nlocals;
  int *roots;
  int nroots, rcap;
  unsigned stamp;
  int guard;           /* building inside this many guards (if branches, summations) */
  const char **names;  /* locals named after hints, to keep them distinct */
  int nnames;
};

Cse *cse_new(Ctx *ctx, int nloops) {
  Cse *c = arena_alloc(ctx, sizeof *c);
  c->ctx = ctx;
  c->nloops = nloops;
  c->tcap = 256;
  c->table = arena_alloc(ctx, sizeof(int) * (size_t)c->tcap);
  memset(c->table, -1, sizeof(int) * (size_t)c->tcap);
  return c;
}

static unsigned long hash_val(const Val *x) {
  unsigned long h = (unsigned long)x->op * 1000003u ^ (unsigned long)x->is_int;
  unsigned long long bits;
  memcpy(&bits, &x->num, sizeof bits);
  h = (h ^ bits) * 1099511628211u;
  h = (h ^ (unsigned long)(x->a + 1)) * 1099511628211u;
  h = (h ^ (unsigned long)(x->b + 1)) * 1099511628211u;
  h = (h ^ (unsigned long)(x->c + 1)) * 1099511628211u;
  if (x->text)
    for (const char *s = x->text; *s; s++) h = (h ^ (unsigned char)*s) * 1099511628211u;
  return h;
}

static bool same_val(const Val *x, const Val *y) {
  return x->op == y->op && x->is_int == y->is_int && memcmp(&x->num, &y->num, sizeof x->num) == 0 && x->a == y->a &&
         x->b == y->b && x->c == y->c && (x->text == y->text || (x->text && y->text && strcmp(x->text, y->text) == 0));
}

static void rehash(Cse *c) {
  int cap = c->tcap * 2;
  int *t = arena_alloc(c->ctx, sizeof(int) * (size_t)cap);
  memset(t, -1, sizeof(int) * (size_t)cap);
  for (int i = 0; i < c->n; i++) {
    unsigned long h = hash_val(&c->v[i]) & (unsigned long)(cap - 1);
    while (t[h] >= 0) h = (h + 1) & (unsigned long)(cap - 1);
    t[h] = i;
  }
  c->table = t;
  c->tcap = cap;
}

/* The id of the value `x` describes: an existing one, or a new one. A value
 * found again where it may be evaluated anywhere is safe from then on. */
static int intern(Cse *c, Val x) {
  unsigned long h = hash_val(&x) & (unsigned long)(c->tcap - 1);
  for (; c->table[h] >= 0; h = (h + 1) & (unsigned long)(c->tcap - 1)) {
    Val *y = &c->v[c->table[h]];
    if (same_val(y, &x)) {
      if (!x.unsafe) y->unsafe = false;
      return c->table[h];
    }
  }
  if (c->n == c->cap) {
    int cap = c->cap ? 2 * c->cap : 64;
    c->v = arena_grow(c->ctx, c->v, sizeof(Val) * (size_t)c->cap, sizeof(Val) * (size_t)cap);
    c->cap = cap;
  }
  int id = c->n++;
  c->v[id] = x;
  c->table[h] = id;
  if (2 * c->n > c->tcap) rehash(c);
  return id;
}

static Val blank(ValOp op) {
  Val x;
  memset(&x, 0, sizeof x);
  x.op = op;
  x.a = x.b = x.c = -1;
  return x;
}

int cse_num(Cse *c, double v, bool is_int) {
  Val x = blank(VAL_NUM);
  x.num = v;
  x.is_int = is_int;
  return intern(c, x);
}

int cse_leaf(Cse *c, const char *text, bool is_int, int level, const Sym *range) {
  Val x = blank(VAL_LEAF);
  x.text = text;
  x.is_int = is_int;
  int id = intern(c, x);
  c->v[id].level = level;
  c->v[id].range = range;
  return id;
}

int cse_sumvar(Cse *c, const char *text) {
  Val x = blank(VAL_LEAF);
  x.text = text;
  x.is_int = true;
  int id = intern(c, x);
  if (!c->v[id].pin) {
    /* past 63 variables, they share the last bit and are never cleared
     * (printed in place: correct, only slower) */
    int bit = c->nbits < 63 ? c->nbits++ : 63;
    c->v[id].pin = 1ull << bit;
  }
  return id;
}

bool cse_in_range(const Cse *c, int v, const Sym *dim) { return c->v[v].op == VAL_LEAF && c->v[v].range == dim; }

void cse_guard(Cse *c, int delta) { c->guard += delta; }

int cse_load(Cse *c, const char *array, bool is_int, int offset, bool in_range) {
  Val x = blank(VAL_LOAD);
  x.text = array;
  x.is_int = is_int;
  x.a = offset;
  x.unsafe = (c->guard && !in_range) || c->v[offset].unsafe;
  x.level = c->v[offset].level;
  x.pin = c->v[offset].pin;
  return intern(c, x);
}

static bool is_num(const Cse *c, int v, double k) {
  return c->v[v].op == VAL_NUM && c->v[v].num == k;
}

/* A value of `op` over operands a, b, k (-1 when absent), not yet interned. */
static Val combine(Cse *c, ValOp op, int a, int b, int k) {
  Val x = blank(op);
  x.a = a, x.b = b, x.c = k;
  int ops[3] = {a, b, k};
  for (int i = 0; i < 3; i++)
    if (ops[i] >= 0) {
      const Val *o = &c->v[ops[i]];
      x.level = o->level > x.level ? o->level : x.level;
      x.pin |= o->pin;
      x.unsafe |= o->unsafe;
    }
  /* a choice or a summation evaluates its branches or body only where
   * they are valid: evaluating it is as safe as the place it is built */
  if (op == VAL_SELECT) x.unsafe = c->v[a].unsafe || (c->guard && x.unsafe);
  if (op == VAL_SUM) x.unsafe = c->v[a].unsafe || c->v[b].unsafe || (c->guard && x.unsafe);
  switch (op) {
  case VAL_NEG: x.is_int = c->v[a].is_int; break;
  case VAL_ADD:
  case VAL_SUB:
  case VAL_MUL: x.is_int = c->v[a].is_int && c->v[b].is_int; break;
  case VAL_NOT:
  case VAL_EQ:
  case VAL_NE:
  case VAL_LT:
  case VAL_LE:
  case VAL_GT:
  case VAL_GE:
  case VAL_AND:
  case VAL_OR: x.is_int = true; break;
  case VAL_SELECT: x.is_int = c->v[b].is_int && c->v[k].is_int; break;
  default: x.is_int = false; break;
  }
  return x;
}

int cse_op(Cse *c, ValOp op, int a, int b, int k) {
  /* Exact identities only, in IEEE arithmetic with signed zeros: operands
   * of + * == != commute; (q - p)^2 is (p - q)^2 (p - q is -(q - p), or
   * +0 for both when p == q). Sharing then sees through the order in which
   * the source wrote them: dist2(c_i, c_j) read transposed is dist2(c_i, c_j). */
  if ((op == VAL_ADD || op == VAL_MUL || op == VAL_EQ || op == VAL_NE) && a > b) {
    int t = a;
    a = b, b = t;
  }
  if (op == VAL_MUL && a == b && c->v[a].op == VAL_SUB && c->v[a].a > c->v[a].b) {
    const Val *d = &c->v[a];
    a = b = cse_op(c, VAL_SUB, d->b, d->a, -1);
  }
  /* a ? (a ? x : y) : z is a ? x : z, and a ? x : (a ? y : z) is a ? x : z */
  if (op == VAL_SELECT && c->v[b].op == VAL_SELECT && c->v[b].a == a) b = c->v[b].b;
  if (op == VAL_SELECT && c->v[k].op == VAL_SELECT && c->v[k].a == a) k = c->v[k].c;
  /* integer index arithmetic: fold constants and units */
  if (op == VAL_ADD || op == VAL_MUL) {
    bool ints = c->v[a].is_int && c->v[b].is_int;
    if (ints && c->v[a].op == VAL_NUM && c->v[b].op == VAL_NUM)
      return cse_num(c, op == VAL_ADD ? c->v[a].num + c->v[b].num : c->v[a].num * c->v[b].num, true);
    if (ints && op == VAL_ADD && is_num(c, b, 0)) return a;
    if (ints && op == VAL_ADD && is_num(c, a, 0)) return b;
    if (ints && op == VAL_MUL && is_num(c, b, 1)) return a;
    if (ints && op == VAL_MUL && is_num(c, a, 1)) return b;
  }
  return intern(c, combine(c, op, a, b, k));
}

int cse_call(Cse *c, const char *fn, int a, int b) {
  Val x = combine(c, VAL_CALL, a, b, -1);
  x.text = fn;
  return intern(c, x);
}

int cse_sum(Cse *c, int var, int lo, int hi, int body) {
  Val x = combine(c, VAL_SUM, lo, hi, body);
  x.text = c->v[var].text;
  uint64_t bit = c->v[var].pin;
  if (bit != 1ull << 63) x.pin &= ~bit;
  return intern(c, x);
}

void cse_hint(Cse *c, int v, const char *name) {
  if (!c->v[v].hint) c->v[v].hint = name;
}

bool cse_is_int(const Cse *c, int v) { return c->v[v].is_int; }

int cse_nloops(const Cse *c) { return c->nloops; }

bool cse_reads(const Cse *c, const char *array) {
  for (int i = 0; i < c->n; i++)
    if (c->v[i].reached && c->v[i].op == VAL_LOAD && strcmp(c->v[i].text, array) == 0) return true;
  return false;
}

bool cse_guarded_gathers(const Cse *c) {
  bool ints = false, guarded = false;
  for (int i = 0; i < c->n; i++) {
    const Val *x = &c->v[i];
    if (!x->reached || x->op != VAL_LOAD || c->nloops == 0 || x->level != c->nloops) continue;
    ints |= x->is_int;
    guarded |= x->unsafe;
  }
  return ints && guarded;
}

void cse_root(Cse *c, int v) {
  if (c->nroots == c->rcap) {
    int cap = c->rcap ? 2 * c->rcap : 16;
    c->roots = arena_grow(c->ctx, c->roots, sizeof(int) * (size_t)c->rcap, sizeof(int) * (size_t)cap);
    c->rcap = cap;
  }
  c->roots[c->nroots++] = v;
}

static void reach(Cse *c, int v) {
  if (v < 0 || c->v[v].reached) return;
  c->v[v].reached = true;
  reach(c, c->v[v].a);
  reach(c, c->v[v].b);
  reach(c, c->v[v].c);
}

/* Which values get a local: those used twice, and those computed in a
 * deeper loop than the one whose variables they read. Users have larger
 * ids than what they use, so one sweep from the top sees every user of a
 * value before the value. */
void cse_plan(Cse *c) {
  for (int i = 0; i < c->n; i++) c->v[i].eval = -1;
  for (int r = 0; r < c->nroots; r++) {
    reach(c, c->roots[r]);
    c->v[c->roots[r]].uses++;
    c->v[c->roots[r]].eval = c->nloops;
  }
  for (int i = c->n - 1; i >= 0; i--) {
    Val *x = &c->v[i];
    if (!x->reached) continue;
    bool eligible = x->op != VAL_NUM && x->op != VAL_LEAF && !x->pin && !x->unsafe;
    x->named = eligible && (x->uses >= 2 || x->level < x->eval);
    /* where its operands are evaluated: in its loop when it has a local,
     * where it is evaluated when printed in place, and in the summation
     * loop (deeper than any loop of the nest) when it reads its variable */
    int at = x->pin ? c->nloops + 1 : x->named ? x->level : x->eval;
    int ops[3] = {x->a, x->b, x->c};
    for (int k = 0; k < 3; k++)
      if (ops[k] >= 0) {
        Val *o = &c->v[ops[k]];
        o->uses++;
        if (at > o->eval) o->eval = at;
      }
  }
}

static void print_val(Cse *c, FILE *out, int v, bool top);

static const char *binop_text(ValOp op) {
  switch (op) {
  case VAL_ADD: return "+";
  case VAL_SUB: return "-";
  case VAL_MUL: return "*";
  case VAL_EQ: return "==";
  case VAL_NE: return "!=";
  case VAL_LT: return "<";
  case VAL_LE: return "<=";
  case VAL_GT: return ">";
  case VAL_GE: return ">=";
  case VAL_AND: return "&&";
  case VAL_OR: return "||";
  default: return NULL;
  }
}

static void print_double_arg(Cse *c, FILE *out, int v) {
  if (c->v[v].is_int) fputs("(double)", out);
  print_val(c, out, v, false);
}

/* `top`: the outermost expression of a statement or an index, printed
 * without its parentheses. */
static void print_val(Cse *c, FILE *out, int v, bool top) {
  Val *x = &c->v[v];
  if (x->emitted) {
    fputs(x->local, out);
    return;
  }
  if (x->pending) { /* its one read in this statement defines it */
    x->pending = false;
    fprintf(out, "(%s = ", x->local);
    print_val(c, out, v, true);
    fputc(')', out);
    x->emitted = true;
    return;
  }
  const char *op = binop_text(x->op);
  if (op) {
    if (!top) fputc('(', out);
    print_val(c, out, x->a, false);
    fprintf(out, " %s ", op);
    print_val(c, out, x->b, false);
    if (!top) fputc(')', out);
    return;
  }
  switch (x->op) {
  case VAL_NUM:
    if (x->is_int) fprintf(out, "%lld", (long long)x->num);
    else emit_double(out, x->num);
    return;
  case VAL_LEAF: fputs(x->text, out); return;
  case VAL_LOAD: /* an int param's entry (npg_iparam, 32 bits) widened: index arithmetic in npg_idx */
    fprintf(out, x->is_int ? "((npg_idx)%s[" : "%s[", x->text);
    print_val(c, out, x->a, true);
    fputs(x->is_int ? "])" : "]", out);
    return;
  case VAL_NEG: fputs("(-", out); print_val(c, out, x->a, false); fputc(')', out); return;
  case VAL_NOT: fputs("(!", out); print_val(c, out, x->a, false); fputc(')', out); return;
  case VAL_DOUBLE: fputs("((double)", out); print_val(c, out, x->a, false); fputc(')', out); return;
  case VAL_DIV:
    if (!top) fputc('(', out);
    print_double_arg(c, out, x->a);
    fputs(" / ", out);
    print_val(c, out, x->b, false);
    if (!top) fputc(')', out);
    return;
  case VAL_SELECT:
    if (!top) fputc('(', out);
    print_val(c, out, x->a, false);
    fputs(" ? ", out);
    print_val(c, out, x->b, false);
    fputs(" : ", out);
    print_val(c, out, x->c, false);
    if (!top) fputc(')', out);
    return;
  case VAL_CALL:
    fprintf(out, "%s(", x->text);
    print_double_arg(c, out, x->a);
    if (x->b >= 0) {
      fputs(", ", out);
      print_double_arg(c, out, x->b);
    }
    fputc(')', out);
    return;
  case VAL_SUM:
    fprintf(out, "__extension__({ double s%d_ = 0.0; for (npg_idx %s = ", v, x->text);
    print_val(c, out, x->a, true);
    fprintf(out, "; %s <= ", x->text);
    print_val(c, out, x->b, false);
    fprintf(out, "; %s++) s%d_ += ", x->text, v);
    print_val(c, out, x->c, true);
    fprintf(out, "; s%d_; })", v);
    return;
  default: break;
  }
  internal_error(c->ctx, __FILE__, __LINE__, "value not printed");
}

static const char *local_name(Cse *c, const Val *x) {
  if (x->hint) {
    bool taken = false;
    for (int i = 0; i < c->nnames && !taken; i++) taken = strcmp(c->names[i], x->hint) == 0;
    if (!taken) {
      c->names = arena_grow(c->ctx, c->names, sizeof(char *) * (size_t)c->nnames, sizeof(char *) * (size_t)(c->nnames + 1));
      c->names[c->nnames++] = x->hint;
      return x->hint;
    }
  }
  return arena_printf(c->ctx, "t%d", c->nlocals++);
}

static void emit_deps(Cse *c, FILE *out, int v, int depth);

/* Does `op` evaluate each of its operands exactly once? */
static bool evaluates_operands_once(ValOp op) {
  return op != VAL_SELECT && op != VAL_AND && op != VAL_OR && op != VAL_SUM;
}

/* How many times printing v (when not a local yet) reads o. */
static int printed_reads(const Cse *c, int v, int o) {
  if (v < 0) return 0;
  if (v == o) return 1;
  const Val *x = &c->v[v];
  if (x->emitted) return 0;
  return printed_reads(c, x->a, o) + printed_reads(c, x->b, o) + printed_reads(c, x->c, o);
}

/* The locals a statement computing v (and printing `extra` too, when
 * >= 0) reads, v excluded. An operand of v that the statement reads once,
 * and no local before it reads at all, is only declared here and defined
 * where the statement reads it, `(t = ...)`: libtcc keeps every local on
 * the stack, and this saves it a reload per such value (gcc sees the same
 * dataflow). The operands of v are evaluated once, so the assignment
 * always runs, and it is the statement's only read of the local, so it is
 * not unsequenced with another. */
static void emit_operands(Cse *c, FILE *out, int v, int extra, int depth) {
  Val *x = &c->v[v];
  int ops[3] = {x->a, x->b, x->c};
  bool inline_def[3];
  for (int k = 0; k < 3; k++) {
    const Val *o = ops[k] >= 0 ? &c->v[ops[k]] : NULL;
    inline_def[k] = o && evaluates_operands_once(x->op) && o->named && !o->emitted && o->stamp != c->stamp;
    if (!inline_def[k]) emit_deps(c, out, ops[k], depth);
  }
  if (extra >= 0) emit_deps(c, out, extra, depth);
  for (int k = 0; k < 3; k++) {
    if (!inline_def[k]) continue;
    Val *o = &c->v[ops[k]];
    if (o->emitted || o->stamp == c->stamp || printed_reads(c, v, ops[k]) + printed_reads(c, extra, ops[k]) != 1) {
      emit_deps(c, out, ops[k], depth); /* a local before the statement after all */
      continue;
    }
    o->stamp = c->stamp;
    emit_deps(c, out, o->a, depth);
    emit_deps(c, out, o->b, depth);
    emit_deps(c, out, o->c, depth);
    o->local = local_name(c, o);
    o->pending = true;
    emit_indent(out, depth);
    fprintf(out, "%s %s;\n", o->is_int ? "npg_idx" : "double", o->local);
  }
}

static void emit_local(Cse *c, FILE *out, int v, int depth) {
  Val *x = &c->v[v];
  emit_indent(out, depth);
  fprintf(out, "const %s ", x->is_int ? "npg_idx" : "double");
  const char *name = local_name(c, x);
  fprintf(out, "%s = ", name);
  print_val(c, out, v, true);
  fputs(";\n", out);
  x->local = name;
  x->emitted = true;
}

void cse_emit_level(Cse *c, FILE *out, int level, int depth) {
  for (int i = 0; i < c->n; i++)
    if (c->v[i].named && !c->v[i].emitted && c->v[i].level == level) {
      c->stamp++;
      emit_operands(c, out, i, -1, depth);
      emit_local(c, out, i, depth);
    }
}

static void emit_deps(Cse *c, FILE *out, int v, int depth) {
  if (v < 0) return;
  Val *x = &c->v[v];
  if (x->emitted || x->stamp == c->stamp) return;
  x->stamp = c->stamp;
  if (!x->named) {
    emit_deps(c, out, x->a, depth);
    emit_deps(c, out, x->b, depth);
    emit_deps(c, out, x->c, depth);
    return;
  }
  emit_operands(c, out, v, -1, depth);
  emit_local(c, out, v, depth);
}

void cse_emit_store(Cse *c, FILE *out, const char *array, int offset, int v, int depth) {
  c->stamp++;
  Val *x = &c->v[v];
  bool define = !x->emitted && x->stamp != c->stamp;
  if (define) {
    x->stamp = c->stamp;
    emit_operands(c, out, v, offset, depth);
  } else {
    emit_deps(c, out, offset, depth);
  }
  emit_indent(out, depth);
  if (define && x->named) { /* read again later: a local too, without a reload (see emit_operands) */
    x->local = local_name(c, x);
    fprintf(out, "const %s %s = ", x->is_int ? "npg_idx" : "double", x->local);
  }
  fprintf(out, "%s[", array);
  print_val(c, out, offset, true);
  fputs("] = ", out);
  print_val(c, out, v, true);
  fputs(";\n", out);
  if (define && x->named) x->emitted = true;
}

/* ---------------------------------------------------------------- rows
 *
 * libtcc neither vectorizes nor keeps values in registers, so its innermost
 * loop costs several times gcc's. When every value of that loop is an
 * elementwise + - * / of unit-stride reads and per-row scalars (or a choice
 * on the diagonal, `if(i == j, ...)`), libtcc code computes a row at a
 * time instead: one call of a gcc-compiled kernel (NpgRt.row_*) per value,
 * over scratch rows or the row of the quantity it is stored in. Each value
 * is the same IEEE operation on the same operands as in the scalar loop, so
 * results are bit-identical. Where a choice's off-diagonal branch is
 * computed on the diagonal too, its result is overwritten; the check below
 * makes sure that computation reads nothing out of range (no unsafe value). */

static bool row_scalar(const Cse *c, int v) {
  const Val *x = &c->v[v];
  return x->level < c->nloops && (x->op == VAL_NUM || x->op == VAL_LEAF || x->named);
}

static bool row_array(const Cse *c, int v) { return c->v[v].row == ROW_LOAD || c->v[v].row == ROW_VALUE; }

static bool row_operand(const Cse *c, int v) { return row_scalar(c, v) || row_array(c, v); }

/* The kind of value x (of the innermost loop), ROW_NONE when no kernel computes it. */
static RowKind row_kind(Cse *c, Val *x) {
  const Val *a = x->a >= 0 ? &c->v[x->a] : NULL, *b = x->b >= 0 ? &c->v[x->b] : NULL;
  if (x->pin || x->unsafe) return ROW_NONE;
  switch (x->op) {
  case VAL_LEAF: return ROW_INDEX; /* the only leaf of the innermost loop is its variable */
  case VAL_ADD:
    if (x->is_int && ((a->row == ROW_INDEX && row_scalar(c, x->b)) || (b->row == ROW_INDEX && row_scalar(c, x->a))))
      return ROW_OFFSET;
    break;
  case VAL_EQ:
  case VAL_NE: {
    const Val *o = a->row == ROW_INDEX ? b : a, *in = a->row == ROW_INDEX ? a : b;
    if (in->row == ROW_INDEX && o->op == VAL_LEAF && o->level >= 1 && o->range && o->range == in->range) {
      x->outer = a->row == ROW_INDEX ? x->b : x->a;
      return ROW_COND;
    }
    return ROW_NONE;
  }
  case VAL_LOAD: return !x->is_int && (a->row == ROW_INDEX || a->row == ROW_OFFSET) ? ROW_LOAD : ROW_NONE;
  default: break;
  }
  if (x->is_int) return ROW_NONE;
  switch (x->op) {
  case VAL_ADD:
  case VAL_SUB:
  case VAL_MUL:
  case VAL_DIV: return row_operand(c, x->a) && row_operand(c, x->b) ? ROW_VALUE : ROW_NONE;
  case VAL_NEG: return row_array(c, x->a) ? ROW_VALUE : ROW_NONE;
  case VAL_SELECT: {
    if (a->row != ROW_COND) return ROW_NONE;
    int diagonal = a->op == VAL_EQ ? x->b : x->c, off = a->op == VAL_EQ ? x->c : x->b;
    return row_scalar(c, diagonal) && row_operand(c, off) ? ROW_VALUE : ROW_NONE;
  }
  default: return ROW_NONE;
  }
}

int cse_rows_plan(Cse *c, const CseStore *st, int nst) {
  if (c->nloops < 1) return -1;
  for (int i = 0; i < c->n; i++) {
    Val *x = &c->v[i];
    x->row = ROW_NONE;
    x->outer = x->last = x->buf = -1;
    if (!x->reached || x->level < c->nloops) continue;
    if ((x->row = (unsigned char)row_kind(c, x)) == ROW_NONE) return -1;
  }
  for (int k = 0; k < nst; k++) {
    const Val *o = &c->v[st[k].offset];
    if ((o->row != ROW_INDEX && o->row != ROW_OFFSET) || !row_operand(c, st[k].val) || c->v[st[k].val].is_int) return -1;
    Val *x = &c->v[st[k].val];
    if (x->row == ROW_VALUE && x->outer < 0) x->outer = k; /* computed in its (first) store's row */
  }
  /* an off-diagonal branch read by its choice alone is computed in the
   * choice's store row (then overwritten on the diagonal) */
  for (int i = c->n - 1; i >= 0; i--) {
    Val *x = &c->v[i];
    if (x->row != ROW_VALUE || x->op != VAL_SELECT || x->outer < 0) continue;
    Val *off = &c->v[c->v[x->a].op == VAL_EQ ? x->c : x->b];
    if (off->row == ROW_VALUE && off->outer < 0 && off->uses == 1) off->outer = x->outer;
  }
  for (int i = 0; i < c->n; i++) {
    Val *x = &c->v[i];
    if (x->row != ROW_VALUE) continue;
    int ops[3] = {x->a, x->b, x->c};
    for (int k = 0; k < 3; k++)
      if (ops[k] >= 0 && c->v[ops[k]].row == ROW_VALUE) c->v[ops[k]].last = i;
  }
  /* scratch rows: a value's row is taken before its operands' are given
   * back, so a kernel never writes a row it reads */
  int nbuf = 0, *busy = arena_alloc(c->ctx, sizeof(int) * (size_t)(c->n + 1));
  for (int i = 0; i < c->n; i++) {
    Val *x = &c->v[i];
    if (x->row != ROW_VALUE) continue;
    if (x->outer < 0) {
      int b = 0;
      while (b < nbuf && busy[b]) b++;
      if (b == nbuf) nbuf++;
      busy[b] = 1;
      x->buf = b;
    }
    int ops[3] = {x->a, x->b, x->c};
    for (int k = 0; k < 3; k++)
      if (ops[k] >= 0 && c->v[ops[k]].row == ROW_VALUE && c->v[ops[k]].last == i && c->v[ops[k]].buf >= 0)
        busy[c->v[ops[k]].buf] = 0;
  }
  return nbuf;
}

/* A kernel's row operand, or its scalar one (in double). */
static void print_row_arg(Cse *c, FILE *out, int v) {
  const Val *x = &c->v[v];
  if (x->row == ROW_LOAD) fprintf(out, "l%d_", v);
  else if (x->row == ROW_VALUE && x->buf >= 0) fprintf(out, "row%d_", x->buf);
  else if (x->row == ROW_VALUE) fprintf(out, "w%d_", x->outer);
  else print_double_arg(c, out, v);
}

/* The start of the row of a unit-stride offset: `array` or `array + base`. */
static void print_row_start(Cse *c, FILE *out, const char *array, int offset) {
  const Val *o = &c->v[offset];
  fputs(array, out);
  if (o->row == ROW_INDEX) return;
  fputs(" + ", out);
  print_val(c, out, c->v[o->a].row == ROW_INDEX ? o->b : o->a, false);
}

static const char *row_op_name(ValOp op) {
  switch (op) {
  case VAL_ADD: return "NPG_ROW_ADD";
  case VAL_SUB: return "NPG_ROW_SUB";
  case VAL_MUL: return "NPG_ROW_MUL";
  default: return "NPG_ROW_DIV";
  }
}

void cse_emit_rows(Cse *c, FILE *out, const CseStore *st, int nst, const char *len, int depth) {
  for (int k = 0; k < nst; k++) {
    emit_indent(out, depth);
    fprintf(out, "double *const w%d_ = ", k);
    print_row_start(c, out, st[k].array, st[k].offset);
    fputs(";\n", out);
  }
  for (int i = 0; i < c->n; i++) {
    Val *x = &c->v[i];
    if (x->row == ROW_LOAD) {
      emit_indent(out, depth);
      fprintf(out, "const double *const l%d_ = ", i);
      print_row_start(c, out, x->text, x->a);
      fputs(";\n", out);
    }
    if (x->row != ROW_VALUE) continue;
    emit_indent(out, depth);
    if (x->op == VAL_NEG) {
      fprintf(out, "c->rt->row_unary(%s, NPG_ROW_NEG, ", len);
    } else if (x->op == VAL_SELECT) {
      bool eq = c->v[x->a].op == VAL_EQ;
      int diagonal = eq ? x->b : x->c, off = eq ? x->c : x->b;
      bool in_row = c->v[off].row == ROW_VALUE && c->v[off].buf < 0 && c->v[off].outer == x->outer; /* cse_rows_plan */
      if (!in_row) {
        fprintf(out, row_array(c, off) ? "c->rt->row_unary(%s, NPG_ROW_COPY, " : "c->rt->row_fill(%s, ", len);
        print_row_arg(c, out, off);
        fputs(", ", out);
        print_row_arg(c, out, i);
        fputs(");\n", out);
        emit_indent(out, depth);
      }
      print_row_arg(c, out, i);
      fputc('[', out);
      print_val(c, out, c->v[x->a].outer, true);
      fputs("] = ", out);
      print_double_arg(c, out, diagonal);
      fputs(";\n", out);
      continue;
    } else {
      const char *kind = row_array(c, x->a) ? row_array(c, x->b) ? "vv" : "vs" : "sv";
      fprintf(out, "c->rt->row_%s(%s, %s, ", kind, len, row_op_name(x->op));
      print_row_arg(c, out, x->a);
      fputs(", ", out);
      print_row_arg(c, out, x->b);
    }
    if (x->op == VAL_NEG) print_row_arg(c, out, x->a);
    fputs(", ", out);
    print_row_arg(c, out, i);
    fputs(");\n", out);
  }
  /* stores not computed in their row: copies, and scalars filled in */
  for (int k = 0; k < nst; k++) {
    const Val *x = &c->v[st[k].val];
    if (x->row == ROW_VALUE && x->outer == k) continue;
    emit_indent(out, depth);
    fprintf(out, row_array(c, st[k].val) ? "c->rt->row_unary(%s, NPG_ROW_COPY, " : "c->rt->row_fill(%s, ", len);
    print_row_arg(c, out, st[k].val);
    fprintf(out, ", w%d_);\n", k);
  }
}

void cse_emit_update_if(Cse *c, FILE *out, const char *lhs, int offset, int v, int cond, int depth) {
  c->stamp++;
  emit_deps(c, out, cond, depth);
  emit_deps(c, out, offset, depth);
  emit_deps(c, out, v, depth);
  emit_indent(out, depth);
  fputs("if (", out);
  print_val(c, out, cond, true);
  fprintf(out, ") %s[", lhs);
  print_val(c, out, offset, true);
  fputs("] += ", out);
  print_val(c, out, v, true);
  fputs(";\n", out);
}

void cse_emit_update(Cse *c, FILE *out, const char *lhs, int offset, int v, const char *rhs, int depth) {
  c->stamp++;
  if (v >= 0) emit_operands(c, out, v, offset, depth);
  else emit_deps(c, out, offset, depth);
  emit_indent(out, depth);
  fputs(lhs, out);
  if (offset >= 0) {
    fputc('[', out);
    print_val(c, out, offset, true);
    fputc(']', out);
  }
  fputs(" += ", out);
  if (v >= 0) print_val(c, out, v, true);
  else fputs(rhs, out);
  fputs(";\n", out);
}

/* ---------------------------------------------------------------- derivatives
 *
 * Forward and reverse mode on the values of the nest (emit_ddirect.c): each rule is the
 * derivative of one IEEE operation, built as values of the same graph, so derivatives
 * share and hoist as the values do. -1 stands for a zero derivative. */

int cse_count(const Cse *c) { return c->n; }

static int d_add(Cse *c, int x, int y) { return x < 0 ? y : y < 0 ? x : cse_op(c, VAL_ADD, x, y, -1); }

static int d_sub(Cse *c, int x, int y) {
  if (y < 0) return x;
  return x < 0 ? cse_op(c, VAL_NEG, y, -1, -1) : cse_op(c, VAL_SUB, x, y, -1);
}

static int d_mul(Cse *c, int s, int x) { return x < 0 ? -1 : cse_op(c, VAL_MUL, s, x, -1); }

static int d_zero(Cse *c, int x) { return x < 0 ? cse_num(c, 0.0, false) : x; }

/* The derivative of libm function `x` at its operand: sqrt'(a) = 0.5 / sqrt(a),
 * pow'(a, b) = b pow(a, b - 1) for a constant b; -1 (and *ok cleared) otherwise. */
static int d_call(Cse *c, int v, bool *ok) {
  const Val x = c->v[v];
  if (strcmp(x.text, "sqrt") == 0) return cse_op(c, VAL_DIV, cse_num(c, 0.5, false), v, -1);
  if (strcmp(x.text, "pow") == 0 && c->v[x.b].op == VAL_NUM) {
    double b = c->v[x.b].num;
    return cse_op(c, VAL_MUL, cse_num(c, b, false), cse_call(c, "pow", x.a, cse_num(c, b - 1.0, false)), -1);
  }
  *ok = false;
  return -1;
}

/* A read of the same offset from another array (a tangent's), as safe as the read it mirrors. */
static int mirror_load(Cse *c, int v, const char *array) {
  Val x = c->v[v];
  Val y = blank(VAL_LOAD);
  y.text = array;
  y.a = x.a;
  y.unsafe = x.unsafe;
  y.level = x.level;
  y.pin = x.pin;
  return intern(c, y);
}

static int tangent_rule(Cse *c, int v, int *memo, CseArrayFn fn, void *arg, bool *ok) {
  const Val x = c->v[v];
  if (x.is_int) return -1;
  switch (x.op) {
  case VAL_NUM:
  case VAL_LEAF: return -1;
  case VAL_LOAD: {
    const char *t = fn(arg, x.text);
    return t ? mirror_load(c, v, t) : -1;
  }
  case VAL_NEG: {
    int da = cse_tangent(c, x.a, memo, fn, arg, ok);
    return da < 0 ? -1 : cse_op(c, VAL_NEG, da, -1, -1);
  }
  case VAL_ADD: return d_add(c, cse_tangent(c, x.a, memo, fn, arg, ok), cse_tangent(c, x.b, memo, fn, arg, ok));
  case VAL_SUB:
    if (x.a == x.b) return -1; /* v - v: a finite value's 0 (emit_direct.c's cured denominators) */
    return d_sub(c, cse_tangent(c, x.a, memo, fn, arg, ok), cse_tangent(c, x.b, memo, fn, arg, ok));
  case VAL_MUL: {
    int da = cse_tangent(c, x.a, memo, fn, arg, ok), db = cse_tangent(c, x.b, memo, fn, arg, ok);
    return d_add(c, d_mul(c, x.b, da), d_mul(c, x.a, db));
  }
  case VAL_DIV: { /* (da - q db) / b */
    int da = cse_tangent(c, x.a, memo, fn, arg, ok), db = cse_tangent(c, x.b, memo, fn, arg, ok);
    int num = d_sub(c, da, d_mul(c, v, db));
    return num < 0 ? -1 : cse_op(c, VAL_DIV, num, x.b, -1);
  }
  case VAL_SELECT: {
    int db = cse_tangent(c, x.b, memo, fn, arg, ok), dc = cse_tangent(c, x.c, memo, fn, arg, ok);
    if (db < 0 && dc < 0) return -1;
    return cse_op(c, VAL_SELECT, x.a, d_zero(c, db), d_zero(c, dc));
  }
  case VAL_CALL: {
    if (x.b >= 0 && cse_tangent(c, x.b, memo, fn, arg, ok) >= 0) *ok = false; /* a varying exponent */
    int da = cse_tangent(c, x.a, memo, fn, arg, ok);
    return da < 0 ? -1 : d_mul(c, d_call(c, v, ok), da);
  }
  case VAL_SUM: {
    int db = cse_tangent(c, x.c, memo, fn, arg, ok);
    return db < 0 ? -1 : cse_sum(c, cse_sumvar(c, x.text), x.a, x.b, db);
  }
  default: return -1;
  }
}

int cse_tangent(Cse *c, int v, int *memo, CseArrayFn fn, void *arg, bool *ok) {
  if (memo[v] != -2) return memo[v];
  int t = tangent_rule(c, v, memo, fn, arg, ok);
  /* built where v was: under v's guards when v may read out of range */
  if (t >= 0 && c->v[v].unsafe) c->v[t].unsafe = true;
  return memo[v] = t;
}

/* g added into v's cotangent; `when` (>= 0) the condition under which the value sending
 * it is evaluated, so the contribution is computed only there (?: evaluates one branch): a
 * partial derivative of a branch not taken may read out of range or be infinite. */
static void adj_add(Cse *c, int *adj, int v, int g, int when) {
  if (g < 0 || c->v[v].is_int) return;
  if (when >= 0) g = cse_op(c, VAL_SELECT, when, g, cse_num(c, 0.0, false));
  adj[v] = d_add(c, adj[v], g);
}

/* guard[o] widened by `g` (-1: always, -2: not yet known). */
static void guard_or(Cse *c, int *guard, int o, int g) {
  if (o < 0) return;
  if (guard[o] == -2 || guard[o] == g) guard[o] = g;
  else if (guard[o] == -1 || g == -1) guard[o] = -1;
  else guard[o] = cse_op(c, VAL_OR, guard[o], g, -1);
}

/* The condition under which each value of the nest is evaluated (-1: always), from the
 * choices above it, users first. */
static int *guards(Cse *c, const int *adj, int n) {
  int *guard = arena_alloc(c->ctx, sizeof(int) * (size_t)n);
  for (int i = 0; i < n; i++) guard[i] = adj[i] >= 0 ? -1 : -2;
  for (int v = n - 1; v >= 0; v--) {
    const Val x = c->v[v];
    if (!x.reached || guard[v] == -2) continue;
    int g = guard[v];
    if (x.op != VAL_SELECT) {
      guard_or(c, guard, x.a, g);
      guard_or(c, guard, x.b, g);
      guard_or(c, guard, x.c, g);
      continue;
    }
    int yes = x.a, no = cse_op(c, VAL_NOT, x.a, -1, -1);
    guard_or(c, guard, x.a, g);
    guard_or(c, guard, x.b, g < 0 ? yes : cse_op(c, VAL_AND, g, yes, -1));
    guard_or(c, guard, x.c, g < 0 ? no : cse_op(c, VAL_AND, g, no, -1));
  }
  return guard;
}

void cse_adjoint(Cse *c, int *adj, CseArrayFn fn, void *arg, CseStore *upd, int *nupd, bool *ok) {
  int n = c->n;
  for (int i = 0; i < n; i++) c->v[i].reached = false;
  for (int i = 0; i < n; i++)
    if (adj[i] >= 0) reach(c, i);
  int *guard = guards(c, adj, n);
  *nupd = 0;
  for (int v = n - 1; v >= 0 && *ok; v--) {
    const Val x = c->v[v];
    int g = adj[v], w = guard[v];
    if (g < 0 || x.is_int) continue;
    switch (x.op) {
    case VAL_NUM:
    case VAL_LEAF:
    case VAL_DOUBLE: break;
    case VAL_LOAD: {
      const char *t = fn(arg, x.text);
      if (!t) break;
      if (x.pin || (x.unsafe && w < 0)) *ok = false;
      upd[(*nupd)++] = (CseStore){t, x.a, g, x.unsafe ? CSE_ADD_IF : CSE_ADD, w};
      break;
    }
    case VAL_NEG: adj_add(c, adj, x.a, cse_op(c, VAL_NEG, g, -1, -1), w); break;
    case VAL_ADD:
      adj_add(c, adj, x.a, g, w);
      adj_add(c, adj, x.b, g, w);
      break;
    case VAL_SUB:
      if (x.a == x.b) break;
      adj_add(c, adj, x.a, g, w);
      adj_add(c, adj, x.b, cse_op(c, VAL_NEG, g, -1, -1), w);
      break;
    case VAL_MUL:
      adj_add(c, adj, x.a, cse_op(c, VAL_MUL, g, x.b, -1), w);
      adj_add(c, adj, x.b, cse_op(c, VAL_MUL, g, x.a, -1), w);
      break;
    case VAL_DIV: { /* a / b: g / b into a, -(g / b) q into b */
      int gb = cse_op(c, VAL_DIV, g, x.b, -1);
      adj_add(c, adj, x.a, gb, w);
      adj_add(c, adj, x.b, cse_op(c, VAL_NEG, cse_op(c, VAL_MUL, gb, v, -1), -1, -1), w);
      break;
    }
    case VAL_SELECT: { /* into the branch taken (each branch masks what it sends on by its guard) */
      int zero = cse_num(c, 0.0, false);
      adj_add(c, adj, x.b, cse_op(c, VAL_SELECT, x.a, g, zero), w);
      adj_add(c, adj, x.c, cse_op(c, VAL_SELECT, x.a, zero, g), w);
      break;
    }
    case VAL_CALL: {
      int dd = d_call(c, v, ok);
      if (dd >= 0) adj_add(c, adj, x.a, cse_op(c, VAL_MUL, g, dd, -1), w);
      break;
    }
    default: *ok = false; break; /* a summation inside the nest */
    }
  }
  for (int i = 0; i < n; i++) c->v[i].reached = false;
}

int cse_level(const Cse *c, int v) { return c->v[v].level; }

bool cse_gathers(const Cse *c, int v) {
  if (v < 0) return false;
  const Val *x = &c->v[v];
  return x->op == VAL_LOAD || cse_gathers(c, x->a) || cse_gathers(c, x->b) || cse_gathers(c, x->c);
}

bool cse_mentions(const Cse *c, const char *text) {
  for (int i = 0; i < c->n; i++)
    if (c->v[i].reached && c->v[i].text && (c->v[i].op == VAL_LOAD || c->v[i].op == VAL_LEAF) &&
        strcmp(c->v[i].text, text) == 0)
      return true;
  return false;
}
