/* test_emit_direct.c — stages evaluated from their source expression and fused into one
 * loop nest (backends/emit/emit_direct.c; the plan, emit_full_plan).
 *
 * Small programs, each built to meet one rule of fusion: stages over one domain reading
 * each other at the same entry fuse; one read at another entry (h[j, i], radiosity's
 * pattern) fuses by recomputing it there when its definition needs nothing computed in
 * the group; a stage over another domain, or one that applies a declared operator, does
 * not; a stage that reads no member moves before the group. For each, the plan is the
 * one the rules give, and every stage's value, from libtcc (with its row kernels) and from
 * cc, equals the reference evaluator's evaluation of the stage's source expression
 * (tests/support/refeval.c) to 1e-12 on random data; the generated C reads a vector
 * quantity of the innermost loop from its per-component copy where the rule says so. */
#include <math.h>
#include <stdio.h>

#include "emit.h"
#include "support/refeval.h"
#include "testutil.h"

typedef struct Case {
  const char *name, *text;
  const char *together[4][2]; /* pairs of stages computed in one step */
  const char *apart[4][2];    /* pairs computed in different steps */
  const char *before;         /* a stage computed before the fused group it does not read, or NULL */
  const char *code;           /* text the generated C must hold, or NULL */
} Case;

static const Case cases[] = {
    {"identity",
     "dim N\ninput x : real[N]\ninput z : real[N]\na[i:N] = x[i] * x[i] + z[i]\noutput b[i:N] = a[i] * z[i] + x[i]\n",
     {{"a", "b"}},
     {{NULL}},
     NULL,
     NULL},
    {"transposed",
     "dim N\ninput x : real[N]\nh[i:N, j:N] = x[i] / (1 + x[j] * x[j])\noutput c[i:N, j:N] = h[i, j] * h[j, i]\n",
     {{"h", "c"}},
     {{NULL}},
     NULL,
     NULL},
    {"domains",
     "dim N\ninput x : real[N]\ns[i:N] = x[i] * x[i]\noutput t[i:N, j:N] = s[i] * x[j] + s[j]\n",
     {{NULL}},
     {{"s", "t"}},
     NULL,
     NULL},
    {"moved_before",
     "dim N\ninput x : real[N]\ninput z : real[N]\na[i:N, j:N] = x[i] * x[j]\nu[i:N] = z[i] * z[i]\n"
     "output b[i:N, j:N] = a[i, j] + x[i]\noutput v[i:N] = u[i] + 1\n",
     {{"a", "b"}},
     {{"u", "a"}},
     "u",
     NULL},
    {"declared_operator",
     "dim N\ninput x : real[N]\nop M[i:N, j:N] = delta(i, j) * (2 + x[i] * x[i]) + 0.1 * x[i] * x[j]\n"
     "y = solve(M, x)\noutput w[i:N] = y[i] * x[i]\n",
     {{NULL}},
     {{"y", "w"}},
     NULL,
     NULL},
    {"components",
     "dim N\ninput g : real[N, 3]\noutput c[i:N, j:N] = (g[i, 0] * g[j, 0] + g[i, 1] * g[j, 1] + g[i, 2] * g[j, 2]) "
     "/ (1 + g[j, 0] * g[j, 0])\n",
     {{NULL}},
     {{NULL}},
     NULL,
     "one array per component, read with unit stride by the innermost loop"},
    {"sums_and_choices",
     "dim N\nparam r : real[N]\ninput x : real[N]\n"
     "p[i:N, j:N] = if(i == j, r[i], x[i] * x[j] / r[j])\n"
     "output y[i:N] = sum(k = 0..N-1, p[i, k] * x[k]) + sum(k = 0..2, x[i] * k) + p[i, i]\n",
     {{NULL}},
     {{NULL}},
     NULL,
     NULL},
    {"powers_and_gathers", /* x^2 and x^(±3/2) without libm's pow; an int param's entries (32 bits) as indices */
     "dim N\ndim P\nparam a : int[P]\ninput x : real[N]\nr[p:P] = x[a[p]]^2 + 1\n"
     "output f[p:P] = x[a[p]] * r[p]^(-3/2) + r[p]^(3/2)\n",
     {{"r", "f"}},
     {{NULL}},
     NULL,
     "* sqrt("},
    {"guarded_gather", /* a stencil's guarded reads through an int param: the function is kept scalar */
     "dim N\nparam nbr : int[N, 2]\ninput u : real[N]\n"
     "output v[i:N] = u[i] + sum(j = 0..1, if(nbr[i, j] >= 0, u[nbr[i, j]] - u[i], 0))\n",
     {{NULL}},
     {{NULL}},
     NULL,
     "NPG_SCALAR static int"},
};

static int step_of(const FullPlan *plan, const char *name) {
  for (int s = 0; s < plan->n; s++)
    for (int m = 0; m < plan->steps[s].n; m++)
      if (!strcmp(plan->steps[s].members[m]->sym->name, name)) return s;
  fail_msg("no step computes %s", name);
  return -1;
}

static void set_both(void *user, const Sym *s, int ndim, const long *shape, const double *values) {
  NpgFull **fs = user;
  for (int f = 0; f < 2; f++)
    if (npg_full_set(fs[f], s->name, ndim, shape, values, s->name) != 0) fail_msg("%s", npg_full_error(fs[f]));
}

/* Every stage of both evaluators (libtcc, cc) against its source expression, for one dim size. */
static void values_equal_source(const Case *c, NpgProgram *p, NpgFull **fs, long n) {
  Program *prog = program_ir(p);
  for (int f = 0; f < 2; f++) npg_full_unbind(fs[f]);
  RefData *d = ref_new(prog, n);
  bind_random(d, prog, n, 31u + (unsigned)n, false, set_both, fs);
  for (int f = 0; f < 2; f++)
    if (npg_full_eval(fs[f], 0) != 0) fail_msg("%s: %s", c->name, npg_full_error(fs[f]));
  for (int i = 0; i < prog->stages.n; i++) {
    const Stage *st = prog->stages.v[i];
    if (st->kind == ST_EXTERN) continue;
    size_t count = ref_count(d, st->sym);
    double *want = ref_values(d, st->sym); /* later stages read it */
    ref_eval_direct(d, st->sym, want);
    if (ref_error(d)) fail_msg("%s: the reference: %s", c->name, ref_error(d));
    for (int f = 0; f < 2; f++) {
      size_t got_n;
      const double *got = npg_full_get(fs[f], st->sym->name, &got_n);
      assert_int_equal(got_n, count);
      double e = rel_diff(want, got, count);
      if (!(e <= 1e-12))
        fail_msg("%s (N = %ld, %s): stage %s differs from its source expression by %.3g", c->name, n, f ? "cc" : "tcc",
                 st->sym->name, e);
    }
  }
  ref_free(d);
}

static void plans_and_values(void **state) {
  (void)state;
  for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
    const Case *c = &cases[k];
    NpgProgram *p = compile_text(c->name, c->text);
    Program *prog = ir_ok(p);
    const FullPlan *plan = emit_full_plan(prog->ctx, prog);
    for (int t = 0; t < 4 && c->together[t][0]; t++)
      if (step_of(plan, c->together[t][0]) != step_of(plan, c->together[t][1]))
        fail_msg("%s: %s and %s are not fused", c->name, c->together[t][0], c->together[t][1]);
    for (int t = 0; t < 4 && c->apart[t][0]; t++)
      if (step_of(plan, c->apart[t][0]) == step_of(plan, c->apart[t][1]))
        fail_msg("%s: %s and %s are fused", c->name, c->apart[t][0], c->apart[t][1]);
    if (c->before) {
      const FullStep *s = &plan->steps[step_of(plan, c->before)];
      if (!s->before || s->kind != STEP_STAGE) fail_msg("%s: %s is not computed before the group", c->name, c->before);
    }
    if (c->code) {
      char *text = NULL;
      size_t len = 0;
      FILE *out = open_memstream(&text, &len);
      assert_int_equal(npg_emit_full(p, out), 0);
      fclose(out);
      if (!strstr(text, c->code)) fail_msg("%s: the generated C lacks '%s'", c->name, c->code);
      free(text);
    }
    NpgFull *fs[2] = {npg_full_new(p, NPG_TCC), npg_full_new(p, NPG_CC)};
    for (int f = 0; f < 2; f++)
      if (npg_full_error(fs[f])[0]) fail_msg("%s: %s", c->name, npg_full_error(fs[f]));
    values_equal_source(c, p, fs, 5);
    values_equal_source(c, p, fs, 17); /* a row longer than the row kernels' unrolling */
    npg_full_free(fs[0]);
    npg_full_free(fs[1]);
    npg_free(p);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {cmocka_unit_test(plans_and_values)};
  return cmocka_run_group_tests(tests, NULL, NULL);
}
