/* test_builder.c — the tensor builders: for every example and test program,
 * every stage rebuilt from its tensors' streamed entries by a simple
 * reference contraction loop equals the generated full evaluator's value
 * (1e-12 relative, the exactness of lowering of DESIGN §4 seen through the
 * tensors); entries arrive output-major; their count equals the symbolic
 * nonzero count npgc check reports (at most, where guards make it a bound). */
#include <math.h>
#include <stdio.h>

#include "emit.h"
#include "full.h"
#include "support/refeval.h"
#include "testutil.h"

typedef struct Collect {
  const Program *prog;
  Full *f;
  const TensorGroup *g;
  double *out;          /* numerator or diagonal: [rows]; declared operator: [rows * ncols] */
  long ncols;
  long last_row;
  long count;
  bool ordered, diag_ok;
  bool diag;            /* entries must have row == col */
} Collect;

static int on_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Collect *k = user;
  if (row < k->last_row) k->ordered = false;
  k->last_row = row;
  if (k->diag && row != col) k->diag_ok = false;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= full_get(k->f, k->g->inputs[i]->name, NULL)[in[i]];
  if (k->ncols) k->out[row * k->ncols + col] += v;
  else k->out[row] += v;
  k->count++;
  return 0;
}

/* The entries of output rows [lo, hi): their number and a checksum of
 * everything they carry (the same entries in the same order give the same). */
typedef struct RangeCount {
  long lo, hi, count;
  double sum;
} RangeCount;

static int count_in_range(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  RangeCount *r = user;
  if (row < r->lo || row >= r->hi) return 0;
  r->count++;
  r->sum += coef * (double)(row + 1) + 0.5 * (double)col;
  for (int i = 0; i < nin; i++) r->sum += 1e-3 * (double)(i + 1) * (double)in[i];
  return 0;
}

/* Value of a symbolic count like "18·F^2 + 3·F" with every dim = n. */
static long eval_count(const char *s, long n) {
  long total = 0;
  while (*s) {
    long term = 1;
    if (*s >= '0' && *s <= '9') term = strtol(s, (char **)&s, 10);
    while (*s && *s != ' ') {
      if (strncmp(s, "·", strlen("·")) == 0) {
        s += strlen("·");
        continue;
      }
      if ((*s >= 'A' && *s <= 'Z') || (*s >= 'a' && *s <= 'z')) {
        while ((*s >= 'A' && *s <= 'Z') || (*s >= 'a' && *s <= 'z') || (*s >= '0' && *s <= '9') || *s == '_') s++;
        long p = 1;
        if (*s == '^') p = strtol(s + 1, (char **)&s, 10);
        for (long i = 0; i < p; i++) term *= n;
        continue;
      }
      s++;
    }
    total += term;
    while (*s == ' ' || *s == '+') s++;
  }
  return total;
}

static int run_group(Collect *k, const char *name, const TensorGroup *g, long n, const char *path, const char *what) {
  k->g = g;
  k->last_row = -1;
  k->count = 0;
  k->ordered = k->diag_ok = true;
  NpgSink sink = {k, on_entry, 0, 1, 0, 0}; /* every row */
  if (full_build(k->f, name, &sink) != 0) {
    print_message("%s: %s: %s\n", path, what, full_error(k->f));
    return 1;
  }
  int bad = 0;
  long expect = eval_count(g->nnz, n);
  if (!k->ordered) print_message("%s: %s: entries not in output-major order\n", path, what), bad++;
  if (!k->diag_ok) print_message("%s: %s: a diagonal operator entry off the diagonal\n", path, what), bad++;
  if (g->nnz_bound ? k->count > expect : k->count != expect)
    print_message("%s: %s: %ld entries, nnz formula '%s' gives %ld\n", path, what, k->count, g->nnz, expect), bad++;
  /* a block of rows (NpgSink.lo, .hi, out-of-core pre-multiplication): the
   * builder may skip the rows outside, and gives every entry of those inside */
  long rows = k->last_row + 1;
  RangeCount whole = {rows / 3, 2 * rows / 3 + 1, 0, 0}, part = whole;
  NpgSink all = {&whole, count_in_range, 0, 1, 0, 0}, block = {&part, count_in_range, 0, 1, part.lo, part.hi};
  if (rows > 1 && (full_build(k->f, name, &all) || full_build(k->f, name, &block)))
    print_message("%s: %s: %s\n", path, what, full_error(k->f)), bad++;
  else if (part.count != whole.count || part.sum != whole.sum)
    print_message("%s: %s: rows [%ld, %ld): %ld entries built as a block, %ld of the whole\n", path, what, part.lo,
                  part.hi, part.count, whole.count), bad++;
  return bad;
}

static double rpow(double b, long p, long q) {
  if (q == 1) return pow(b, (double)p);
  return pow(b, (double)p / (double)q);
}

/* Each given symbol's random values into the evaluator too (bind_random). */
static void set_full(void *user, const Sym *s, int ndim, const long *shape, const double *values) {
  if (full_set(user, s->name, ndim, shape, values, s->name)) fail_msg("%s", full_error(user));
}

static int check_program(NpgProgram *p, const char *path, void *arg) {
  double *worst = arg;
  Program *prog = program_ir(p);
  Full *f = full_new(prog, JIT_TCC, NULL);
  int failures = 0;
  const long n = 6;
  RefData *d = ref_new(prog, n);
  bind_random(d, prog, n, 4321u, false, set_full, f);
  if (full_eval(f, 0)) fail_msg("%s: %s", path, full_error(f));
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (st->kind == ST_EXTERN) continue;
    size_t count = ref_count(d, st->sym);
    size_t ne = count / (size_t)st->ncomp;
    double *y = calloc(count, sizeof(double)), *num = calloc(count, sizeof(double)), *dg = calloc(count, sizeof(double));
    Collect k = {prog, f, NULL, NULL, 0, 0, 0, true, true, false};
    for (int t = 0; t < st->nterms; t++) {
      const Term *tm = st->terms[t];
      memset(num, 0, sizeof(double) * count);
      if (tm->named_num) {
        memcpy(num, full_get(f, tm->named_num->name, NULL), sizeof(double) * count);
      } else {
        k.out = num;
        k.ncols = 0;
        k.diag = false;
        for (int g = 0; g < tm->num_tensors.n; g++)
          failures += run_group(&k, emit_builder_name(prog->ctx, prog, st, t, 0, g, NULL), &tm->num_tensors.g[g], n, path,
                                st->sym->name);
      }
      for (int o = 0; o < tm->nops; o++) {
        const OpPow *op = &tm->ops[o];
        if (op->kind == OPK_DIAG) {
          memset(dg, 0, sizeof(double) * count);
          k.out = dg;
          k.ncols = 0;
          k.diag = true;
          for (int g = 0; g < tm->op_tensors[o].n; g++)
            failures += run_group(&k, emit_builder_name(prog->ctx, prog, st, t, o + 1, g, NULL), &tm->op_tensors[o].g[g], n,
                                  path, st->sym->name);
          for (size_t e = 0; e < count; e++) num[e] *= rpow(dg[e], op->p, op->q);
        } else {
          double *M = calloc(ne * ne, sizeof(double));
          k.out = M;
          k.ncols = (long)ne;
          k.diag = false;
          const OpDef *od = op->op->opdef;
          for (int g = 0; g < od->tensors.n; g++)
            failures += run_group(&k, emit_builder_name(prog->ctx, prog, NULL, 0, 0, g, op->op), &od->tensors.g[g], n, path,
                                  op->op->name);
          if (!ref_apply_power(d, M, (int)ne, op->p, op->q, num)) fail_msg("%s: singular operator in the reference", path);
          free(M);
        }
      }
      for (size_t e = 0; e < count; e++) y[e] += num[e];
    }
    const double *full = full_get(f, st->sym->name, NULL);
    double dn = 0, dd = 0;
    for (size_t e = 0; e < count; e++) {
      dn = fmax(dn, fabs(y[e] - full[e]));
      dd = fmax(dd, fabs(full[e]));
    }
    double rel = dd > 0 ? dn / dd : dn;
    if (!(rel <= 1e-12)) {
      print_message("%s: stage %s: tensor form differs from the full evaluator by %.3g\n", path, st->sym->name, rel);
      failures++;
    }
    *worst = fmax(*worst, rel);
    free(y);
    free(num);
    free(dg);
  }
  ref_free(d);
  full_free(f);
  return failures;
}

static void tensor_form_equals_full(void **state) {
  (void)state;
  int n = 0;
  double worst = 0;
  int failures = check_programs(corpus_all, check_program, &worst, &n);
  print_message("%d programs: tensor form vs full evaluator, worst relative difference %.2g\n", n, worst);
  assert_true(n >= 20);
  assert_int_equal(failures, 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {cmocka_unit_test(tensor_form_equals_full)};
  return cmocka_run_group_tests(tests, NULL, NULL);
}
