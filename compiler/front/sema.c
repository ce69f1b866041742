/* sema.c — semantic checks: every rule of DESIGN §3.
 *
 * Declarations become Syms; stage, op and extern bodies are checked in
 * source order (a quantity must be defined before it is used). fn calls are
 * inlined here, by substitution: argument expressions replace the
 * parameters, the body's own free names see only the program's globals, and
 * the body's summation variables are renamed so they cannot capture names of
 * the caller. After this pass every NAME/INDEX node carries its Sym, every
 * node its Type, sqrt/root/if calls are rewritten to POW/IF nodes and every
 * exponent of a varying quantity is an N_RAT literal.
 */
#include <ctype.h>
#include <dirent.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sema.h"

Sym *sema_new_sym(Checker *ck, SymKind kind, const char *name, Loc loc) {
  Sym *s = arena_alloc(ck->ctx, sizeof *s);
  s->kind = kind;
  s->name = name;
  s->loc = loc;
  s->basis_max = -1;
  s->basis_energy = -1;
  s->basis_center = -1;
  s->class_basis_max = -1;
  s->class_basis_energy = -1;
  s->class_basis_center = -1;
  s->klass = -1;
  return s;
}

/* What a name is, with its article: "an input", "a stage". */
const char *sema_kind_word(const Sym *s) {
  switch (s->kind) {
  case SYM_DIM: return "a dim";
  case SYM_PARAM: return "a param";
  case SYM_INPUT: return "an input";
  case SYM_STAGE: return "a stage";
  case SYM_OP: return "an op";
  case SYM_EXTERN: return "an extern";
  case SYM_FN: return "a fn";
  case SYM_IVAR: return "an index variable";
  case SYM_SUMVAR: return "a summation variable";
  case SYM_FNARG: return "a fn argument";
  }
  return "a name";
}

Sym *sema_find_global(Checker *ck, const char *name) {
  for (int i = 0; i < ck->globals.n; i++) {
    Sym *s = ck->globals.v[i];
    if (strcmp(s->name, name) == 0) return s;
  }
  return NULL;
}

/* The edit distance of `a` and `b` (insertions, deletions, substitutions and swaps of neighbours, each 1:
 * "sovle" is 1 from "solve"), or `cap` + 1 when it is more than `cap` or a name is over 63 characters. */
static int edit_distance(const char *a, const char *b, int cap) {
  int n = (int)strlen(a), m = (int)strlen(b);
  if (n > 63 || m > 63 || abs(n - m) > cap) return cap + 1;
  int d[64][64];
  for (int i = 0; i <= n; i++) d[i][0] = i;
  for (int j = 0; j <= m; j++) d[0][j] = j;
  for (int i = 1; i <= n; i++)
    for (int j = 1; j <= m; j++) {
      int best = d[i - 1][j - 1] + (a[i - 1] != b[j - 1]);
      if (d[i - 1][j] + 1 < best) best = d[i - 1][j] + 1;
      if (d[i][j - 1] + 1 < best) best = d[i][j - 1] + 1;
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] && d[i - 2][j - 2] + 1 < best)
        best = d[i - 2][j - 2] + 1;
      d[i][j] = best;
    }
  return d[n][m] > cap ? cap + 1 : d[n][m];
}

/* Keep `cand` in *best when it is nearer `name` than *best (at most a third of the name's length away, at
 * least 1: "q" suggests nothing, "nromal" suggests "normal"). */
static void nearer(const char *name, const char *cand, const char **best, int *dist) {
  int cap = (int)strlen(name) / 3 > 0 ? (int)strlen(name) / 3 : 1;
  if (cap > 3) cap = 3;
  int d = edit_distance(name, cand, cap);
  if (d <= cap && d < (int)strlen(name) && d < *dist && strcmp(name, cand) != 0) *best = cand, *dist = d;
}

const char *sema_suggest(Checker *ck, const char *name, SemaSuggest what) {
  const char *best = NULL;
  int dist = 1 << 20;
  if (what == SUGGEST_FUNCTION) {
    for (int b = 1; b < B__COUNT; b++) /* the algebraic builtins: the others are refused anyway */
      if (builtin_info[b].algebraic) nearer(name, builtin_info[b].name, &best, &dist);
    for (int i = 0; i < ck->globals.n; i++)
      if (((Sym *)ck->globals.v[i])->kind == SYM_FN) nearer(name, ((Sym *)ck->globals.v[i])->name, &best, &dist);
    return best;
  }
  for (int i = ck->sums.n - 1; what == SUGGEST_VALUE && i >= 0; i--)
    if (!strchr(((Sym *)ck->sums.v[i])->name, '#')) nearer(name, ((Sym *)ck->sums.v[i])->name, &best, &dist);
  for (int i = 0; what == SUGGEST_VALUE && ck->cur && i < ck->cur->nivars; i++)
    if (ck->cur->ivars[i] && !ck->cur->ivars[i]->introduced) nearer(name, ck->cur->ivars[i]->name, &best, &dist);
  for (int i = 0; i < ck->globals.n; i++) {
    const Sym *g = ck->globals.v[i];
    bool quantity = g->kind == SYM_INPUT || g->kind == SYM_STAGE || g->kind == SYM_EXTERN;
    if (what == SUGGEST_VALUE ? g->kind != SYM_FN : quantity || (what == SUGGEST_OUTPUT && g->kind == SYM_OP))
      nearer(name, g->name, &best, &dist);
  }
  if (what == SUGGEST_VALUE) nearer(name, "pi", &best, &dist);
  return best;
}

static int compare_names(const void *a, const void *b) { return strcmp((const char *)a, (const char *)b); }

const char *sema_module_of_fn(Checker *ck, const char *name) {
  Ctx *ctx = ck->ctx;
  char dir[4096], names[64][128];
  int n = 0;
  snprintf(dir, sizeof dir, "%s/npg", ctx->std_dir ? ctx->std_dir : ".");
  DIR *d = opendir(dir);
  if (!d) return NULL;
  for (struct dirent *e; n < 64 && (e = readdir(d));) { /* no arena allocation while the folder is open */
    size_t len = strlen(e->d_name);
    if (len > 4 && len < sizeof names[0] && strcmp(e->d_name + len - 4, ".npg") == 0)
      snprintf(names[n++], sizeof names[0], "%.*s", (int)(len - 4), e->d_name);
  }
  closedir(d);
  qsort(names, (size_t)n, sizeof names[0], compare_names); /* the first module in name order, on every system */
  for (int i = 0; i < n; i++) {
    SrcFile *f = source_read(ctx, arena_printf(ctx, "%s/%s.npg", dir, names[i]));
    for (const char *line = f ? f->text : NULL; line && *line;) { /* "fn NAME(" at the start of a line */
      const char *id = line + strspn(line, " \t"), *eol = strchr(line, '\n');
      line = eol ? eol + 1 : NULL;
      if (strncmp(id, "fn", 2) != 0 || !isspace((unsigned char)id[2])) continue;
      id += 2 + strspn(id + 2, " \t");
      size_t len = strlen(name);
      if (strncmp(id, name, len) == 0 && !(isalnum((unsigned char)id[len]) || id[len] == '_'))
        return arena_strdup(ctx, names[i]);
    }
  }
  return NULL;
}

const char *sema_did_you_mean(Checker *ck, const char *name, SemaSuggest what) {
  const char *best = sema_suggest(ck, name, what);
  return best ? arena_printf(ck->ctx, "; did you mean '%s'?", best) : "";
}

char *sema_shape_str(Ctx *ctx, const Type *t) {
  if (t->nwhole) {
    char *s = "whole [";
    for (int i = 0; i < t->nwhole; i++) s = arena_printf(ctx, "%s%s%s", s, i ? ", " : "", t->whole[i]->name);
    for (int i = 0; i < t->nstatic; i++) s = arena_printf(ctx, "%s, %d", s, t->shape[i]);
    return arena_printf(ctx, "%s]", s);
  }
  if (t->nstatic == 0) return "scalar";
  char *s = "[";
  for (int i = 0; i < t->nstatic; i++) s = arena_printf(ctx, "%s%s%d", s, i ? ", " : "", t->shape[i]);
  return arena_printf(ctx, "%s]", s);
}

char *sema_sym_type_str(Ctx *ctx, const Sym *s) {
  char *t = arena_printf(ctx, "%s", s->is_int ? "int" : "real");
  if (s->ndims + s->nstatic == 0) return t;
  t = arena_printf(ctx, "%s[", t);
  for (int i = 0; i < s->ndims; i++) t = arena_printf(ctx, "%s%s%s", t, i ? ", " : "", s->dims[i]->name);
  for (int i = 0; i < s->nstatic; i++) t = arena_printf(ctx, "%s%s%d", t, s->ndims + i ? ", " : "", s->shape[i]);
  return arena_printf(ctx, "%s]", t);
}

/* ---------------------------------------------------------------- declarations */

static void declare(Checker *ck, Sym *s) {
  Sym *old = sema_find_global(ck, s->name);
  if (old && s->decl && s->decl->next_of)
    error_note(ck->ctx, s->decl->next_of_loc, old->loc, "the first is here", "state '%s' has two next values",
               s->decl->next_of);
  if (old)
    error_note(ck->ctx, s->loc, old->loc, "previous definition is here", "redefinition of '%s' (already %s)", s->name,
               sema_kind_word(old));
  if (strchr(s->name, '.') && !(s->decl && (s->decl->next_of || s->decl->residual_of)))
    error_at(ck->ctx, s->loc, "'%s' cannot be declared: a dotted name is a state's next value, defined by 'next %.*s = "
             "...' or 'residual next %.*s = ...'", s->name, (int)(strchr(s->name, '.') - s->name), s->name,
             (int)(strchr(s->name, '.') - s->name), s->name);
  if (builtin_lookup(s->name) || strcmp(s->name, "pi") == 0)
    error_at(ck->ctx, s->loc, "'%s' is a builtin and cannot be redefined", s->name);
  if (is_keyword(s->name)) error_at(ck->ctx, s->loc, "'%s' is a keyword", s->name);
  vec_push(ck->ctx, &ck->globals, s);
}

static Sym *lookup_dim(Checker *ck, const char *name, Loc loc) {
  Sym *d = sema_find_global(ck, name);
  if (!d) error_at(ck->ctx, loc, "unknown dim '%s' (declare it with 'dim %s')", name, name);
  if (d->kind != SYM_DIM) error_at(ck->ctx, loc, "'%s' is %s, not a dim", name, sema_kind_word(d));
  return d;
}

static void declare_ivars(Checker *ck, Sym *s, Decl *d) {
  for (int i = 0; i < d->nivars; i++) {
    IndexVarDecl *iv = &d->ivars[i];
    for (int j = 0; j < i; j++)
      if (strcmp(d->ivars[j].name, iv->name) == 0)
        error_at(ck->ctx, iv->loc, "index variable '%s' is declared twice", iv->name);
    Sym *v = sema_new_sym(ck, SYM_IVAR, iv->name, iv->loc);
    v->range = lookup_dim(ck, iv->dim, iv->dim_loc);
    s->ivars[i] = v;
    s->dims[i] = v->range;
  }
  s->nivars = s->ndims = d->nivars;
}

static Sym *need_quantity(Checker *ck, const char *name, Loc loc, const char *what) {
  Sym *s = sema_find_global(ck, name);
  if (!s) error_at(ck->ctx, loc, "unknown name '%s'%s", name, sema_did_you_mean(ck, name, SUGGEST_QUANTITY));
  if (s->kind != SYM_INPUT && s->kind != SYM_STAGE && s->kind != SYM_EXTERN)
    error_at(ck->ctx, loc, "%s: '%s' is %s, not a quantity with a basis (input, stage or extern)", what, name,
             sema_kind_word(s));
  return s;
}

/* `basis q: product K0` (issue 41): K0 must be an op of the program; that it
 * is square over the dims of q's class is checked with the classes
 * (basis_classes), that it is SPD and of the class's size in training. */
static void basis_product(Checker *ck, const Decl *d, Sym *q) {
  if (!d->basis_product) return;
  Sym *op = sema_find_global(ck, d->basis_product);
  if (!op)
    error_at(ck->ctx, d->basis_product_loc, "basis %s: product '%s' is not a name of the program: it takes an op "
             "(op K0[i:N, j:N] = ...)%s", q->name, d->basis_product, sema_did_you_mean(ck, d->basis_product, SUGGEST_VALUE));
  if (op->kind != SYM_OP)
    error_at(ck->ctx, d->basis_product_loc, "basis %s: product '%s' is %s, not an op: the inner product is an SPD "
             "operator of the program (op K0[i:N, j:N] = ...)", q->name, d->basis_product, sema_kind_word(op));
  q->product = op;
  q->product_loc = d->basis_product_loc;
}

/* A definition without index variables whose value is a whole quantity
 * (b = solve(M, e)) gets implicit index variables over its dims. */
static void implicit_ivars(Checker *ck, Sym *s, const Type *t) {
  for (int i = 0; i < t->nwhole; i++) {
    Sym *v = sema_new_sym(ck, SYM_IVAR, arena_printf(ck->ctx, "_%c", "ijklmnop"[i]), s->loc);
    v->range = t->whole[i];
    v->introduced = true; /* npgc check prints real[N], not the name it was given here */
    s->ivars[i] = v;
    s->dims[i] = t->whole[i];
  }
  s->nivars = s->ndims = t->nwhole;
}

static void check_stage(Checker *ck, Sym *s, Decl *d) {
  Ctx *ctx = ck->ctx;
  ck->cur = s;
  ck->cur_order = s->id;
  Node *body = sema_expr_check(ck, d->body);
  ck->cur = NULL;
  if (body->ty.is_bool) error_node(ctx, body, "'%s' is defined as a condition; conditions go inside if()", s->name);
  if (body->ty.op)
    error_node(ctx, body, "'%s' is defined as an operator; declare it with 'op %s[...] = ...' or apply it to a quantity",
               s->name, s->name);
  if (body->ty.nwhole) {
    if (d->nivars)
      error_node(ctx, body, "the value of '%s[...]' is a whole quantity over %s; index it, or define '%s = ...' without index variables",
                 s->name, sema_shape_str(ctx, &body->ty), s->name);
    implicit_ivars(ck, s, &body->ty);
  }
  if (body->ty.nstatic > MAX_STATIC) error_node(ctx, body, "too many static axes");
  s->nstatic = body->ty.nstatic;
  memcpy(s->shape, body->ty.shape, sizeof s->shape);
  s->is_int = false;
  s->body = body;
  if (body->ty.var != V_VARYING) {
    /* A constant definition: folded into its users as a coefficient. */
    s->inlined = true;
    if (d->next_of)
      error_node(ctx, body, "the next value of state '%s' does not depend on any state or input", d->next_of);
    if (s->is_output)
      error_node(ctx, body, "output '%s' does not depend on any input; make it a param", s->name);
  }
}

static void check_op(Checker *ck, Sym *s, Decl *d) {
  Ctx *ctx = ck->ctx;
  if (d->nivars % 2)
    error_at(ctx, d->name_loc, "operator '%s' needs as many column index variables as row index variables "
             "(op %s[i:N, j:N] = ...)", s->name, s->name);
  s->nrow = d->nivars / 2;
  ck->cur = s;
  ck->cur_order = s->id;
  Node *body = sema_expr_check(ck, d->body);
  ck->cur = NULL;
  sema_expr_no_op_value(ck, body, "as the entries of an operator");
  sema_expr_no_whole(ck, body, "as an operator entry");
  sema_expr_no_bool(ck, body, "as an operator entry");
  if (body->ty.nstatic)
    error_node(ctx, body, "the entries of operator '%s' must be scalars, found a %s value", s->name,
               sema_shape_str(ctx, &body->ty));
  s->body = body;
  if (d->on_from) {
    s->on_from = need_quantity(ck, d->on_from, d->on_loc, "'on'");
    s->on_to = need_quantity(ck, d->on_to, d->on_to_loc, "'on'");
  }
}

static void set_axes(Checker *ck, Sym *s, Decl *d) {
  for (int i = 0; i < d->naxes; i++) {
    Axis *ax = &d->axes[i];
    if (ax->dim) {
      s->dims[s->ndims++] = lookup_dim(ck, ax->dim, ax->loc);
    } else {
      if (s->nstatic == MAX_STATIC) error_at(ck->ctx, ax->loc, "too many static axes (at most %d)", MAX_STATIC);
      s->shape[s->nstatic++] = ax->size;
    }
  }
  s->is_int = d->is_int;
}

/* `residual next u[i:N] = e` (an implicit step) lowered: an input `u.next` of the state's type (the
 * unknown, declared just before the residual) and the output stage `u.residual` = e; link_states
 * makes u.next the state's next value, and basis_classes puts u, u.next and the residual in one
 * class, so the reduced residual is the Galerkin projection in the state's basis. */
static void lower_implicit(Checker *ck) {
  Ctx *ctx = ck->ctx;
  for (Decl **pp = &ck->prog->decls; *pp; pp = &(*pp)->next) {
    Decl *r = *pp;
    if (r->kind != D_STAGE || !r->residual_of) continue;
    Decl *st = NULL;
    for (Decl *d = ck->prog->decls; d && !st; d = d->next)
      if (d->name && strcmp(d->name, r->residual_of) == 0 && d->kind != D_DIM) st = d;
    if (!st)
      error_at(ctx, r->next_of_loc, "'residual next %s' names no state: declare it first with 'state %s : real[...]'",
               r->residual_of, r->residual_of);
    if (st->kind != D_INPUT || !st->is_state)
      error_note(ctx, r->next_of_loc, st->name_loc, "declared here",
                 "'%s' is not a state: only a quantity declared 'state %s : ...' has a next value to solve for",
                 r->residual_of, r->residual_of);
    Decl *u = arena_alloc(ctx, sizeof *u);
    *u = *st;
    u->is_state = false;
    u->loc = r->loc;
    u->name = arena_printf(ctx, "%s.next", st->name);
    u->name_loc = r->next_of_loc;
    u->next_of = st->name;
    u->next_of_loc = r->next_of_loc;
    u->next = r;
    *pp = u;
    pp = &u->next; /* on to r, then past it */
  }
}

/* Pass 1: every name, so duplicates are found and fns can be used anywhere.
 * Dims first, since types refer to them. */
static void declare_all(Checker *ck) {
  Ctx *ctx = ck->ctx;
  Program *prog = ck->prog;
  int order = 0;
  for (Decl *d = prog->decls; d; d = d->next)
    if (d->kind == D_DIM)
      for (int i = 0; i < d->nnames; i++) {
        Sym *s = sema_new_sym(ck, SYM_DIM, d->names[i], d->name_locs[i]);
        s->id = order++;
        declare(ck, s);
        vec_push(ctx, &prog->dims, s);
      }
  for (Decl *d = prog->decls; d; d = d->next) {
    Sym *s = NULL;
    switch (d->kind) {
    case D_PARAM:
    case D_INPUT:
      s = sema_new_sym(ck, d->kind == D_PARAM ? SYM_PARAM : SYM_INPUT, d->name, d->name_loc);
      s->decl = d;
      set_axes(ck, s, d);
      if (d->kind == D_INPUT) {
        if (d->is_int)
          error_at(ctx, d->loc, "%s '%s' must be real: %ss get a basis", d->is_state ? "state" : "input", d->name,
                   d->is_state ? "state" : "input");
        vec_push(ctx, &prog->inputs, s);
        if (d->is_state) vec_push(ctx, &prog->states, s);
      } else {
        vec_push(ctx, &prog->params, s);
      }
      break;
    case D_STAGE:
      s = sema_new_sym(ck, SYM_STAGE, d->name, d->name_loc);
      s->is_output = d->is_output;
      break;
    case D_OP:
      s = sema_new_sym(ck, SYM_OP, d->name, d->name_loc);
      s->is_output = d->is_output;
      vec_push(ctx, &prog->ops, s);
      break;
    case D_EXTERN:
      s = sema_new_sym(ck, SYM_EXTERN, d->name, d->name_loc);
      vec_push(ctx, &prog->externs, s);
      break;
    case D_FN:
      s = sema_new_sym(ck, SYM_FN, d->name, d->name_loc);
      s->nargs = d->nnames;
      s->argnames = d->names;
      s->body = d->body;
      for (int i = 0; i < d->nnames; i++)
        for (int j = 0; j < i; j++)
          if (strcmp(d->names[i], d->names[j]) == 0)
            error_at(ctx, d->name_locs[i], "fn '%s' has two parameters named '%s'", d->name, d->names[i]);
      vec_push(ctx, &prog->fns, s);
      break;
    default: break;
    }
    if (s) {
      s->decl = d;
      s->id = order++;
      declare(ck, s);
    }
  }
}

/* Each `next u = ...` to its state: u declared `state`, given one next value. */
static void link_states(Checker *ck) {
  Ctx *ctx = ck->ctx;
  for (Decl *d = ck->prog->decls; d; d = d->next) {
    if ((d->kind != D_STAGE && d->kind != D_INPUT) || !d->next_of) continue; /* D_INPUT: lowered u.next */
    Sym *u = sema_find_global(ck, d->next_of);
    if (!u) error_at(ctx, d->next_of_loc, "'next %s' names no state: declare it first with 'state %s : real[...]'",
                     d->next_of, d->next_of);
    if (u->kind != SYM_INPUT || !u->decl->is_state)
      error_note(ctx, d->next_of_loc, u->loc, "declared here",
                 "'%s' is %s, not a state: only a quantity declared 'state %s : ...' has a next value", u->name,
                 sema_kind_word(u), u->name);
    if (u->next)
      error_note(ctx, d->next_of_loc, u->next->loc, "the first is here", "state '%s' has two next values", u->name);
    u->next = sema_find_global(ck, d->name);
    u->next->state_of = u;
  }
  Sym *implicit = NULL;
  for (Decl *d = ck->prog->decls; d; d = d->next) {
    if (d->kind != D_STAGE || !d->residual_of) continue;
    Sym *u = sema_find_global(ck, d->residual_of), *next = sema_find_global(ck, d->name);
    if (u->next && u->next->kind != SYM_INPUT) /* an explicit next value after the residual */
      error_note(ctx, u->next->decl->next_of_loc, d->next_of_loc, "the residual is here",
                 "state '%s' has two next values: 'next %s = ...' and 'residual next %s = ...'", u->name, u->name,
                 u->name);
    if (implicit)
      error_note(ctx, d->next_of_loc, implicit->residual->decl->next_of_loc, "the first is here",
                 "a second implicit state '%s': one state per program may be stepped by a residual (stack coupled "
                 "unknowns into one state)", u->name);
    u->residual = next;
    next->state_of = u;
    implicit = u;
  }
  for (int i = 0; i < ck->prog->states.n; i++) {
    Sym *u = ck->prog->states.v[i];
    if (!u->next)
      error_at(ctx, u->loc, "state '%s' has no next value: define it with 'next %s = ...' (or declare it 'input')",
               u->name, u->name);
  }
}

/* A state and its next value have one shape: the step's output is its next input. */
static void check_state_shapes(Checker *ck) {
  Ctx *ctx = ck->ctx;
  for (int i = 0; i < ck->prog->states.n; i++) {
    Sym *u = ck->prog->states.v[i], *n = u->next;
    bool same = u->ndims == n->ndims && u->nstatic == n->nstatic;
    for (int k = 0; same && k < u->ndims; k++) same = u->dims[k] == n->dims[k];
    for (int k = 0; same && k < u->nstatic; k++) same = u->shape[k] == n->shape[k];
    if (!same)
      error_note(ctx, n->decl->next_of_loc, u->loc, "the state is declared here",
                 "the next value of state '%s' is %s but the state is %s", u->name, sema_sym_type_str(ctx, n),
                 sema_sym_type_str(ctx, u));
  }
}

/* Whether quantity `s` reads `target`, directly or through the stages, ops and externs it reads;
 * seen[] (per symbol id) visits each once. */
static bool reads(const Node *n, const Sym *target, bool *seen, int nseen);

static bool sym_reads(const Sym *s, const Sym *target, bool *seen, int nseen) {
  if (s == target) return true;
  if (!s || s->id < 0 || s->id >= nseen || seen[s->id]) return false;
  if (s->kind != SYM_STAGE && s->kind != SYM_OP && s->kind != SYM_EXTERN) return false;
  seen[s->id] = true;
  for (int i = 0; i < s->nof; i++)
    if (sym_reads(s->of[i], target, seen, nseen)) return true;
  return reads(s->body, target, seen, nseen);
}

static bool reads(const Node *n, const Sym *target, bool *seen, int nseen) {
  if (!n) return false;
  if (n->sym && sym_reads(n->sym, target, seen, nseen)) return true;
  if (reads(n->a, target, seen, nseen) || reads(n->b, target, seen, nseen) || reads(n->c, target, seen, nseen))
    return true;
  for (int i = 0; i < n->nargs; i++)
    if (reads(n->args[i], target, seen, nseen)) return true;
  return false;
}

/* An implicit step's residual has the state's shape and reads its unknown u.next. */
static void check_residuals(Checker *ck) {
  Ctx *ctx = ck->ctx;
  for (int i = 0; i < ck->prog->states.n; i++) {
    Sym *u = ck->prog->states.v[i], *r = u->residual;
    if (!r) continue;
    bool same = u->ndims == r->ndims && u->nstatic == r->nstatic;
    for (int k = 0; same && k < u->ndims; k++) same = u->dims[k] == r->dims[k];
    for (int k = 0; same && k < u->nstatic; k++) same = u->shape[k] == r->shape[k];
    if (!same)
      error_note(ctx, r->decl->next_of_loc, u->loc, "the state is declared here",
                 "the residual of state '%s' is %s but the state is %s: Newton needs one equation per unknown entry",
                 u->name, sema_sym_type_str(ctx, r), sema_sym_type_str(ctx, u));
    int nseen = ck->globals.n + 1;
    bool *seen = arena_alloc(ctx, sizeof(bool) * (size_t)nseen);
    memset(seen, 0, sizeof(bool) * (size_t)nseen);
    if (!reads(r->body, u->next, seen, nseen))
      error_node(ctx, r->body, "the residual of state '%s' does not read '%s': nothing defines the next value (write "
                 "the residual in terms of %s.next)", u->name, u->next->name, u->name);
  }
}

/* Pass 2: definitions in source order. */
static void check_definitions(Checker *ck) {
  Ctx *ctx = ck->ctx;
  Program *prog = ck->prog;
  for (Decl *d = prog->decls; d; d = d->next) {
    if (d->kind != D_STAGE && d->kind != D_OP && d->kind != D_EXTERN) continue;
    Sym *s = sema_find_global(ck, d->name);
    if (d->kind == D_STAGE) {
      declare_ivars(ck, s, d);
      check_stage(ck, s, d);
    } else if (d->kind == D_OP) {
      declare_ivars(ck, s, d);
      check_op(ck, s, d);
    } else {
      declare_ivars(ck, s, d);
      s->of = arena_alloc(ctx, sizeof(Sym *) * (size_t)d->nnames);
      for (int i = 0; i < d->nnames; i++) {
        Sym *q = need_quantity(ck, d->names[i], d->name_locs[i], "extern ... of");
        if (q->id >= s->id)
          error_note(ctx, d->name_locs[i], q->loc, "defined here", "'%s' is used before its definition", q->name);
        s->of[s->nof++] = q;
      }
    }
  }
}

/* Pass 3: share, basis, inline, output. */
static void apply_directives(Checker *ck) {
  Ctx *ctx = ck->ctx;
  Program *prog = ck->prog;
  for (Decl *d = prog->decls; d; d = d->next) {
    switch (d->kind) {
    case D_SHARE:
      for (int i = 0; i < d->nnames; i++) {
        Sym *q = need_quantity(ck, d->names[i], d->name_locs[i], "share");
        for (int j = 0; j < i; j++)
          if (strcmp(d->names[j], d->names[i]) == 0)
            error_at(ctx, d->name_locs[i], "'%s' appears twice in 'share'", d->names[i]);
        (void)q;
      }
      vec_push(ctx, &prog->shares, d);
      break;
    case D_BASIS:
      for (int i = 0; i < d->nnames; i++) {
        /* a class by the name `npgc check` and --basis give it, m_<a member>: the options hold for the
         * whole class (basis_classes applies them); a quantity of that very name is the quantity */
        const char *name = d->names[i];
        Sym *member = !sema_find_global(ck, name) && strncmp(name, "m_", 2) == 0 ? sema_find_global(ck, name + 2) : NULL;
        if (member) {
          Sym *q = need_quantity(ck, name + 2, d->name_locs[i], "basis (the class m_<quantity>)");
          if (d->basis_max > 0) q->class_basis_max = d->basis_max;
          if (d->basis_energy > 0) q->class_basis_energy = d->basis_energy;
          if (d->basis_center >= 0) q->class_basis_center = d->basis_center;
          basis_product(ck, d, q);
          continue;
        }
        if (!sema_find_global(ck, name))
          error_at(ctx, d->name_locs[i], "unknown name '%s': 'basis' takes quantities and classes (m_x, the class of "
                   "quantity x, as npgc check names it)%s", name, sema_did_you_mean(ck, name, SUGGEST_QUANTITY));
        Sym *q = need_quantity(ck, name, d->name_locs[i], "basis");
        if (d->basis_max > 0) q->basis_max = d->basis_max;
        if (d->basis_energy > 0) q->basis_energy = d->basis_energy;
        if (d->basis_center >= 0) q->basis_center = d->basis_center;
        basis_product(ck, d, q);
        if (d->basis_reduce != STAGE_REDUCE_DEFAULT) q->reduce = d->basis_reduce, q->reduce_loc = d->name_locs[i];
      }
      break;
    case D_INLINE:
      for (int i = 0; i < d->nnames; i++) {
        Sym *q = sema_find_global(ck, d->names[i]);
        if (!q)
          error_at(ctx, d->name_locs[i], "unknown name '%s'%s", d->names[i],
                   sema_did_you_mean(ck, d->names[i], SUGGEST_QUANTITY));
        if (q->kind != SYM_STAGE)
          error_at(ctx, d->name_locs[i], "only a stage can be inlined; '%s' is %s", q->name, sema_kind_word(q));
        if (q->is_output) error_at(ctx, d->name_locs[i], "'%s' is an output and cannot be inlined", q->name);
        q->inlined = true;
        q->inline_loc = d->name_locs[i];
        vec_push(ctx, &prog->inlined, q);
      }
      break;
    case D_OUTPUT:
      for (int i = 0; i < d->nnames; i++) {
        Sym *q = sema_find_global(ck, d->names[i]);
        if (!q)
          error_at(ctx, d->name_locs[i], "unknown name '%s'%s", d->names[i],
                   sema_did_you_mean(ck, d->names[i], SUGGEST_OUTPUT));
        if (q->kind != SYM_INPUT && q->kind != SYM_STAGE && q->kind != SYM_EXTERN && q->kind != SYM_OP)
          error_at(ctx, d->name_locs[i], "'%s' is %s and cannot be an output", q->name, sema_kind_word(q));
        q->is_output = true;
      }
      break;
    default: break;
    }
  }
}

/* A shared, basis'd or output quantity that was inlined has no basis; the
 * outputs and the quantities with a basis, in program order. */
static void list_quantities(Checker *ck) {
  Ctx *ctx = ck->ctx;
  Program *prog = ck->prog;
  for (Decl *d = prog->decls; d; d = d->next) {
    if (d->kind != D_SHARE && d->kind != D_BASIS) continue;
    for (int i = 0; i < d->nnames; i++) {
      Sym *q = sema_find_global(ck, d->names[i]);
      if (!q) q = sema_find_global(ck, d->names[i] + 2); /* `basis m_x:` (apply_directives checked x) */
      if (q->inlined)
        error_at(ctx, d->name_locs[i], "'%s' is inlined (or constant) and has no basis to %s", q->name,
                 d->kind == D_SHARE ? "share" : "configure");
    }
  }
  for (int i = 0; i < ck->globals.n; i++) {
    Sym *s = ck->globals.v[i];
    if (s->is_output && s->inlined) error_at(ctx, s->loc, "'%s' is an output and cannot be inlined", s->name);
    if (s->is_output) vec_push(ctx, &prog->outputs, s);
  }
  for (int i = 0; i < ck->globals.n; i++) {
    Sym *s = ck->globals.v[i];
    if (s->kind == SYM_INPUT) vec_push(ctx, &prog->quantities, s);
  }
  for (int i = 0; i < ck->globals.n; i++) {
    Sym *s = ck->globals.v[i];
    if ((s->kind == SYM_STAGE && !s->inlined) || s->kind == SYM_EXTERN) vec_push(ctx, &prog->quantities, s);
  }
  if (prog->outputs.n == 0) {
    Loc end = {prog->main, 1, 1, 0};
    error_at(ctx, end, "the program has no output: mark the result with 'output'");
  }
}

Program *sema_program(Ctx *ctx, const SrcFile *file, Decl *decls) {
  Checker ck = {0};
  ck.ctx = ctx;
  Program *prog = arena_alloc(ctx, sizeof *prog);
  prog->ctx = ctx;
  prog->main = file;
  prog->decls = decls;
  ck.prog = prog;
  lower_implicit(&ck);
  declare_all(&ck);
  link_states(&ck);
  check_definitions(&ck);
  check_state_shapes(&ck);
  check_residuals(&ck);
  apply_directives(&ck);
  list_quantities(&ck);
  return prog;
}
