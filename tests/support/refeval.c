/* refeval.c — a slow, independent reference evaluator (test oracle).
 *
 * Evaluates a compiled program two ways on bound data:
 *   - directly from the checked source expressions (the AST), and
 *   - from the canonical form (terms of operator powers over polynomial
 *     fields, DESIGN §4),
 * so tests can check that lowering is exact. Dense operator work goes
 * through LAPACKE (dgesv, dsyev); nothing here is fast or meant to be.
 */
#include "refeval.h"

#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct Env {
  const Sym *var;
  long val;
  const struct Env *next;
} Env;

struct RefData {
  const Program *prog;
  int nslots;
  const Sym **syms;
  double **vals;
  size_t *sizes;
  const Sym **dims;
  long *dimval;
  int ndims;
  const char *error;   /* first evaluation problem, or NULL */
  const Sym *cur;      /* definition whose whole references are being evaluated */
  const Env *cur_env;
};

static long env_get(RefData *d, const Env *e, const Sym *s) {
  for (; e; e = e->next)
    if (e->var == s) return e->val;
  if (!d->error) d->error = "unbound index variable";
  return 0;
}

static const Env *bind(Env *cell, const Sym *v, long val, const Env *next) {
  cell->var = v;
  cell->val = val;
  cell->next = next;
  return cell;
}

long ref_dim(RefData *d, const Sym *dim) {
  for (int i = 0; i < d->ndims; i++)
    if (d->dims[i] == dim) return d->dimval[i];
  return 0;
}

size_t ref_count(RefData *d, const Sym *q) {
  size_t n = 1;
  for (int i = 0; i < q->ndims; i++) n *= (size_t)ref_dim(d, q->dims[i]);
  for (int i = 0; i < q->nstatic; i++) n *= (size_t)q->shape[i];
  return n;
}

double *ref_values(RefData *d, const Sym *q) {
  for (int i = 0; i < d->nslots; i++)
    if (d->syms[i] == q) return d->vals[i];
  for (int i = 0; i < d->nslots; i++)
    if (!d->syms[i]) {
      d->syms[i] = q;
      d->sizes[i] = ref_count(d, q);
      d->vals[i] = calloc(d->sizes[i] ? d->sizes[i] : 1, sizeof(double));
      return d->vals[i];
    }
  return NULL;
}

RefData *ref_new(const Program *prog, long dimsize) {
  RefData *d = calloc(1, sizeof *d);
  d->prog = prog;
  d->nslots = prog->params.n + prog->quantities.n + 64;
  d->syms = calloc((size_t)d->nslots, sizeof *d->syms);
  d->vals = calloc((size_t)d->nslots, sizeof *d->vals);
  d->sizes = calloc((size_t)d->nslots, sizeof *d->sizes);
  d->ndims = prog->dims.n;
  d->dims = calloc((size_t)d->ndims + 1, sizeof *d->dims);
  d->dimval = calloc((size_t)d->ndims + 1, sizeof *d->dimval);
  for (int i = 0; i < d->ndims; i++) {
    d->dims[i] = prog->dims.v[i];
    d->dimval[i] = dimsize;
  }
  return d;
}

void ref_free(RefData *d) {
  if (!d) return;
  for (int i = 0; i < d->nslots; i++) free(d->vals[i]);
  free(d->syms);
  free(d->vals);
  free(d->sizes);
  free(d->dims);
  free(d->dimval);
  free(d);
}

const char *ref_error(RefData *d) { return d->error; }

/* ---------------------------------------------------------------- storage access */

static double load(RefData *d, const Sym *q, const long *idx) {
  size_t off = 0;
  for (int i = 0; i < q->ndims + q->nstatic; i++) {
    long n = i < q->ndims ? ref_dim(d, q->dims[i]) : q->shape[i - q->ndims];
    if (idx[i] < 0 || idx[i] >= n) {
      if (!d->error) d->error = "index out of range";
      return NAN;
    }
    off = off * (size_t)n + (size_t)idx[i];
  }
  double *v = ref_values(d, q);
  return v ? v[off] : NAN;
}

/* ---------------------------------------------------------------- direct evaluation */

static double eval(RefData *d, const Node *n, const Env *env, int comp);

static int ncomp_of(const Type *t) {
  int c = 1;
  for (int i = 0; i < t->nstatic; i++) c *= t->shape[i];
  return c;
}

/* Entry of a param/quantity (or an inlined definition) given dim and some
 * static indices; `comp` enumerates the static axes left. */
static double entry(RefData *d, const Sym *q, Node *const *args, int nargs, const Env *env, int comp) {
  long idx[MAX_AXES + MAX_STATIC];
  int given_static = nargs > q->ndims ? nargs - q->ndims : 0;
  for (int i = 0; i < q->ndims; i++) {
    if (nargs) idx[i] = lround(eval(d, args[i], env, 0));
    else {  /* whole reference: the definition's index variables */
      if (!d->cur || i >= d->cur->nivars) {
        if (!d->error) d->error = "whole reference outside a definition";
        return NAN;
      }
      idx[i] = env_get(d, env ? env : d->cur_env, d->cur->ivars[i]);
    }
  }
  for (int i = 0; i < given_static; i++) idx[q->ndims + i] = lround(eval(d, args[q->ndims + i], env, 0));
  for (int i = q->nstatic - 1, c = comp; i >= given_static; i--) {
    idx[q->ndims + i] = c % q->shape[i];
    c /= q->shape[i];
  }
  if (q->kind == SYM_STAGE && q->inlined) {
    Env cells[MAX_AXES];
    const Env *e2 = NULL;
    for (int i = 0; i < q->ndims; i++) e2 = bind(&cells[i], q->ivars[i], idx[i], e2);
    int flat = 0;
    for (int i = 0; i < q->nstatic; i++) flat = flat * q->shape[i] + (int)idx[q->ndims + i];
    const Sym *saved = d->cur;
    const Env *saved_env = d->cur_env;
    d->cur = q;
    d->cur_env = e2;
    double v = eval(d, q->body, e2, flat);
    d->cur = saved;
    d->cur_env = saved_env;
    return v;
  }
  if (q->ndims + q->nstatic == 0) {
    double *v = ref_values(d, q);
    return v ? v[0] : NAN;
  }
  return load(d, q, idx);
}

static double rpow(double b, long p, long q) {
  if (q == 1) return pow(b, (double)p);
  return pow(b, (double)p / (double)q);
}

static int select_flat(RefData *d, const Node *n, const Env *env, int comp) {
  const Type *bt = &n->a->ty;
  int flat = 0;
  for (int i = 0; i < bt->nstatic; i++) {
    int v;
    if (i < n->nargs) v = (int)lround(eval(d, n->args[i], env, 0));
    else {
      int inner = 1;
      for (int k = i + 1; k < bt->nstatic; k++) inner *= bt->shape[k];
      v = (comp / inner) % bt->shape[i];
    }
    flat = flat * bt->shape[i] + v;
  }
  return flat;
}

static double eval(RefData *d, const Node *n, const Env *env, int comp) {
  switch (n->kind) {
  case N_NUM: return n->num;
  case N_RAT: return (double)n->p / (double)n->q;
  case N_NAME: {
    const Sym *s = n->sym;
    if (!s) return NAN;
    if (s->kind == SYM_IVAR || s->kind == SYM_SUMVAR) return (double)env_get(d, env, s);
    if (s->kind == SYM_DIM) return (double)ref_dim(d, s);
    return entry(d, s, NULL, 0, env, comp);
  }
  case N_INDEX:
    if (n->a->kind == N_NAME && n->sym && n->sym->kind != SYM_OP)
      return entry(d, n->sym, n->args, n->nargs, env, comp);
    return eval(d, n->a, env, select_flat(d, n, env, comp));
  case N_VEC: {
    int per = ncomp_of(&n->args[0]->ty);
    return eval(d, n->args[comp / per], env, comp % per);
  }
  case N_NEG: return -eval(d, n->a, env, comp);
  case N_NOT: return !eval(d, n->a, env, 0);
  case N_IF:
    return eval(d, n->a, env, 0) != 0 ? eval(d, n->b, env, n->b->ty.nstatic ? comp : 0)
                                      : eval(d, n->c, env, n->c->ty.nstatic ? comp : 0);
  case N_SUM: {
    long lo = lround(eval(d, n->a, env, 0)), hi = lround(eval(d, n->b, env, 0));
    double s = 0;
    Env cell;
    for (long k = lo; k <= hi; k++) s += eval(d, n->c, bind(&cell, n->sym, k, env), comp);
    return s;
  }
  case N_CALL: {
    double a[2] = {0, 0};
    for (int i = 0; i < n->nargs && i < 2; i++) a[i] = eval(d, n->args[i], env, n->args[i]->ty.nstatic ? comp : 0);
    switch (n->builtin) {
    case B_DELTA: return lround(a[0]) == lround(a[1]);
    case B_EXP: return exp(a[0]);
    case B_LOG: return log(a[0]);
    case B_SIN: return sin(a[0]);
    case B_COS: return cos(a[0]);
    case B_TAN: return tan(a[0]);
    case B_ATAN: return atan(a[0]);
    case B_ATAN2: return atan2(a[0], a[1]);
    case B_ABS: return fabs(a[0]);
    case B_FLOOR: return floor(a[0]);
    case B_MIN: return fmin(a[0], a[1]);
    case B_MAX: return fmax(a[0], a[1]);
    case B_TANH: return tanh(a[0]);
    default:
      if (!d->error) d->error = "operator call in an entrywise context";
      return NAN;
    }
  }
  case N_POW: {
    double b = eval(d, n->a, env, n->a->ty.nstatic ? comp : 0);
    if (n->b->kind == N_RAT) return rpow(b, n->b->p, n->b->q);
    return pow(b, eval(d, n->b, env, 0));
  }
  default: {
    double a = eval(d, n->a, env, n->a->ty.nstatic ? comp : 0);
    double b = eval(d, n->b, env, n->b->ty.nstatic ? comp : 0);
    switch (n->kind) {
    case N_ADD: return a + b;
    case N_SUB: return a - b;
    case N_MUL: return a * b;
    case N_DIV: return a / b;
    case N_EQ: return a == b;
    case N_NE: return a != b;
    case N_LT: return a < b;
    case N_LE: return a <= b;
    case N_GT: return a > b;
    case N_GE: return a >= b;
    case N_AND: return a != 0 && b != 0;
    case N_OR: return a != 0 || b != 0;
    default:
      if (!d->error) d->error = "unexpected node";
      return NAN;
    }
  }
  }
}

/* ---------------------------------------------------------------- entries of a definition */

/* Enumerate the entries (index tuples) of a definition's dims. */
static size_t n_entries(RefData *d, const Sym *s) {
  size_t n = 1;
  for (int i = 0; i < s->nivars; i++) n *= (size_t)ref_dim(d, s->ivars[i]->range);
  return n;
}

static const Env *entry_env(RefData *d, const Sym *s, size_t e, Env *cells) {
  const Env *env = NULL;
  for (int i = s->nivars - 1; i >= 0; i--) {
    long n = ref_dim(d, s->ivars[i]->range);
    env = bind(&cells[i], s->ivars[i], (long)(e % (size_t)n), env);
    e /= (size_t)n;
  }
  return env;
}

/* ---------------------------------------------------------------- dense operators */

/* M^(p/q) applied to x (n entries), M dense row-major n x n. */
bool ref_apply_power(RefData *d, double *M, int n, long p, long q, double *x) {
  double *A = malloc(sizeof(double) * (size_t)n * (size_t)n);
  double *y = malloc(sizeof(double) * (size_t)n);
  bool ok = true;
  if (q == 1) {
    for (long r = 0; r < (p < 0 ? -p : p) && ok; r++) {
      memcpy(A, M, sizeof(double) * (size_t)n * (size_t)n);
      if (p < 0) {
        lapack_int *piv = malloc(sizeof(lapack_int) * (size_t)n);
        lapack_int info = LAPACKE_dgesv(LAPACK_ROW_MAJOR, n, 1, A, n, piv, x, 1);
        free(piv);
        if (info != 0) ok = false;
      } else {
        for (int i = 0; i < n; i++) {
          double s = 0;
          for (int j = 0; j < n; j++) s += M[(size_t)i * (size_t)n + (size_t)j] * x[j];
          y[i] = s;
        }
        memcpy(x, y, sizeof(double) * (size_t)n);
      }
    }
  } else {  /* symmetric: V diag(w^(p/q)) V^T x */
    memcpy(A, M, sizeof(double) * (size_t)n * (size_t)n);
    double *w = malloc(sizeof(double) * (size_t)n);
    lapack_int info = LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', n, A, n, w);
    if (info != 0) ok = false;
    for (int k = 0; k < n && ok; k++) {
      double c = 0;
      for (int i = 0; i < n; i++) c += A[(size_t)i * (size_t)n + (size_t)k] * x[i];
      y[k] = c * rpow(w[k], p, q);
    }
    for (int i = 0; i < n && ok; i++) {
      double s = 0;
      for (int k = 0; k < n; k++) s += A[(size_t)i * (size_t)n + (size_t)k] * y[k];
      x[i] = s;
    }
    free(w);
  }
  if (!ok && !d->error) d->error = "singular or indefinite operator";
  free(A);
  free(y);
  return ok;
}

static double *op_matrix_ast(RefData *d, const Sym *op) {
  size_t n = n_entries(d, op);
  double *M = malloc(sizeof(double) * n);
  Env cells[MAX_AXES];
  for (size_t e = 0; e < n; e++) M[e] = eval(d, op->body, entry_env(d, op, e, cells), 0);
  return M;
}

static const Sym *op_power(const Node *n, long *p, long *q) {
  if (n->kind == N_NAME) {
    *p = *q = 1;
    return n->sym;
  }
  const Sym *op = op_power(n->a, p, q);
  *p *= n->b->p;
  *q *= n->b->q;
  return op;
}

static bool has_op(const Node *n) {
  if (!n) return false;
  if (n->kind == N_CALL && n->builtin == B_SOLVE) return true;
  if (n->kind == N_MUL && n->a->ty.op) return true;
  if (has_op(n->a) || has_op(n->b) || has_op(n->c)) return true;
  for (int i = 0; i < n->nargs; i++)
    if (has_op(n->args[i])) return true;
  return false;
}

/* A whole-valued expression of the definition `s`, into out[entries]. */
static void eval_whole(RefData *d, const Sym *s, const Node *n, double *out) {
  size_t ne = n_entries(d, s);
  Env cells[MAX_AXES];
  if (!has_op(n)) {
    for (size_t e = 0; e < ne; e++) {
      const Env *env = entry_env(d, s, e, cells);
      d->cur_env = env;
      out[e] = eval(d, n, env, 0);
    }
    return;
  }
  double *a = calloc(ne, sizeof(double)), *b = calloc(ne, sizeof(double));
  switch (n->kind) {
  case N_ADD:
  case N_SUB:
    eval_whole(d, s, n->a, a);
    eval_whole(d, s, n->b, b);
    for (size_t e = 0; e < ne; e++) out[e] = n->kind == N_ADD ? a[e] + b[e] : a[e] - b[e];
    break;
  case N_NEG:
    eval_whole(d, s, n->a, a);
    for (size_t e = 0; e < ne; e++) out[e] = -a[e];
    break;
  case N_MUL:
  case N_CALL: {
    long p, q;
    const Node *opn = n->kind == N_MUL ? n->a : n->args[0];
    const Node *x = n->kind == N_MUL ? n->b : n->args[1];
    if (n->kind == N_MUL && !n->a->ty.op) {  /* coefficient * whole */
      eval_whole(d, s, n->a, a);
      eval_whole(d, s, n->b, b);
      for (size_t e = 0; e < ne; e++) out[e] = a[e] * b[e];
      break;
    }
    const Sym *op = op_power(opn, &p, &q);
    if (n->kind == N_CALL) p = -p;
    eval_whole(d, s, x, out);
    double *M = op_matrix_ast(d, op);
    ref_apply_power(d, M, (int)ne, p, q, out);
    free(M);
    break;
  }
  default:
    if (!d->error) d->error = "unsupported whole expression";
  }
  free(a);
  free(b);
}

void ref_eval_direct(RefData *d, const Sym *s, double *out) {
  size_t ne = n_entries(d, s);
  int nc = 1;
  for (int i = 0; i < s->nstatic; i++) nc *= s->shape[i];
  d->cur = s;
  const Node *body = s->body;
  if (s->introduced && s->introduced_for) d->cur = s->introduced_for;
  if (body->ty.nwhole && !s->introduced) {
    eval_whole(d, s, body, out);
  } else {
    Env cells[MAX_AXES];
    for (size_t e = 0; e < ne; e++) {
      const Env *env = entry_env(d, s, e, cells);
      d->cur_env = env;
      for (int c = 0; c < nc; c++) out[e * (size_t)nc + (size_t)c] = eval(d, body, env, c);
    }
  }
  d->cur = NULL;
  d->cur_env = NULL;
}

/* ---------------------------------------------------------------- canonical evaluation */

static double eval_mono_sums(RefData *d, const Mono *m, int k, const Env *env) {
  if (k == m->nsums) {
    /* the guard may read the sums' variables (`if(col[i, q] >= 0, …)` in a sum over q): it is
       evaluated where they are bound, and nothing else is where it fails */
    if (m->guard && eval(d, m->guard, env, 0) == 0) return 0;
    double v = eval(d, m->coef, env, 0);
    for (int a = 0; a < m->natoms; a++) {
      const Atom *at = &m->atoms[a];
      long idx[MAX_AXES + MAX_STATIC];
      for (int i = 0; i < at->nidx; i++) idx[i] = lround(eval(d, at->idx[i], env, 0));
      v *= load(d, at->q, idx);
    }
    return v;
  }
  long lo = lround(eval(d, m->sums[k].lo, env, 0)), hi = lround(eval(d, m->sums[k].hi, env, 0));
  double s = 0;
  Env cell;
  for (long i = lo; i <= hi; i++) s += eval_mono_sums(d, m, k + 1, bind(&cell, m->sums[k].var, i, env));
  return s;
}

static double eval_poly(RefData *d, const Poly *p, const Env *env) {
  double s = 0;
  for (int i = 0; i < p->n; i++) {
    const Mono *m = p->m[i];
    s += eval_mono_sums(d, m, 0, env);  /* the guard inside: never evaluated where it fails */
  }
  return s;
}

void ref_eval_canonical(RefData *d, const Stage *st, double *out) {
  const Sym *s = st->sym;
  size_t ne = n_entries(d, s);
  int nc = st->ncomp;
  size_t n = ne * (size_t)nc;
  for (size_t i = 0; i < n; i++) out[i] = 0;
  double *v = malloc(sizeof(double) * (n ? n : 1));
  Env cells[MAX_AXES];
  for (int t = 0; t < st->nterms; t++) {
    const Term *tm = st->terms[t];
    for (size_t e = 0; e < ne; e++) {
      const Env *env = entry_env(d, s, e, cells);
      for (int c = 0; c < nc; c++) v[e * (size_t)nc + (size_t)c] = eval_poly(d, &tm->num->comp[c], env);
    }
    for (int k = 0; k < tm->nops; k++) {
      const OpPow *o = &tm->ops[k];
      if (o->kind == OPK_DIAG) {
        for (size_t e = 0; e < ne; e++) {
          const Env *env = entry_env(d, s, e, cells);
          for (int c = 0; c < nc; c++)
            v[e * (size_t)nc + (size_t)c] *= rpow(eval_poly(d, &o->diag->comp[c], env), o->p, o->q);
        }
      } else {
        const OpDef *od = o->op->opdef;
        size_t nm = n_entries(d, o->op);
        double *M = malloc(sizeof(double) * nm);
        for (size_t e = 0; e < nm; e++) M[e] = eval_poly(d, &od->entries->comp[0], entry_env(d, o->op, e, cells));
        ref_apply_power(d, M, (int)ne, o->p, o->q, v);
        free(M);
      }
    }
    for (size_t i = 0; i < n; i++) out[i] += v[i];
  }
  free(v);
}
