/* test_emit_reduced.c — the reduced evaluator as generated C (DESIGN §6):
 *
 *   - on every example (rational, radiosity) and test program, a model
 *     trained on random data with truncated bases evaluates, through the
 *     generated code compiled by libtcc and by cc, to the coordinates of
 *     the runtime reduced evaluator (backends/model/reduced.c) within 1e-12
 *     relative on every stage, on held-out samples (externs learned);
 *   - the emitted file compiles standalone with cc -Wall -Wextra, without
 *     a warning, and so does the output of `npgc emit --reduced MODEL/`;
 *   - a singular reduced operator fails in the generated code with the
 *     runtime evaluator's message; coordinates of another model are refused.
 */
#include <unistd.h>

#include "emit.h"
#include "memsamples.h"
#include "randdata.h"
#include "reduced.h"
#include "train.h"
#include "testutil.h"
#include "trained.h"

/* ---------------------------------------------------------------- a trained model */

/* Project the inputs of sample k of `ms` into every Reduced of r[0..n). */
static void project_inputs(const Program *prog, const MemSamples *ms, long k, Reduced *const *r, int n) {
  for (int i = 0; i < ms->n; i++) {
    if (ms->sym[i]->kind != SYM_INPUT) continue;
    int q = vec_position(&prog->quantities, ms->sym[i]);
    for (int j = 0; j < n; j++) reduced_project(r[j], q, ms->val[i] + (size_t)k * ms->count[i]);
  }
}

/* ---------------------------------------------------------------- cc -Wall -Wextra */

static const char *tmp_dir(void) {
  const char *t = getenv("TMPDIR");
  return t && *t ? t : "/tmp";
}

/* `cc -Wall -Wextra -Werror -c` on `path`: 0 when it compiles without a
 * warning; the compiler's output is printed otherwise. */
static int cc_clean(const char *path) {
  char cmd[4096], log[1024];
  snprintf(log, sizeof log, "%s.log", path);
  const char *cc = getenv("CC");
  snprintf(cmd, sizeof cmd, "%s -std=c11 -Wall -Wextra -Werror -c '%s' -o '%s.o' > '%s' 2>&1", cc && *cc ? cc : "cc",
           path, path, log);
  int rc = system(cmd);
  if (rc != 0) {
    FILE *f = fopen(log, "r");
    char buf[2048] = "";
    if (f) {
      size_t n = fread(buf, 1, sizeof buf - 1, f);
      buf[n] = 0;
      fclose(f);
    }
    print_message("%s: cc -Wall -Wextra:\n%s\n", path, buf);
  }
  snprintf(cmd, sizeof cmd, "%s.o", path);
  unlink(cmd);
  unlink(log);
  return rc;
}

/* ---------------------------------------------------------------- generated equals runtime */

typedef struct Stats {
  long n, S;                /* dims, training samples */
  int cap;
  double chain_tol;         /* end to end */
  double worst, worst_chain;
  int stages, programs;
} Stats;

static int generated_text(const char *path, const char *text, Stats *st) {
  Trained tr;
  train(&tr, path, text, st->n, st->S, st->cap);
  Model *m = tr.m;
  Program *prog = tr.prog;
  char err[2048] = "";
  int failures = 0;

  /* the emitted file compiles standalone without a warning */
  char cpath[1024];
  snprintf(cpath, sizeof cpath, "%s/npg-emit-reduced-%d.c", tmp_dir(), (int)getpid());
  FILE *out = fopen(cpath, "w");
  assert_non_null(out);
  if (emit_reduced(m, out, ERR_OF(err, sizeof err))) fail_msg("%s: %s", path, err);
  fclose(out);
  if (cc_clean(cpath) != 0) failures++;
  unlink(cpath);

  /* runtime, libtcc, cc: three evaluators on three Reduced */
  Reduced *r[3];
  for (int j = 0; j < 3; j++)
    if (!(r[j] = reduced_new(m, ERR_OF(err, sizeof err)))) fail_msg("%s: %s", path, err);
  RedJit *jit[2];
  for (int j = 0; j < 2; j++)
    if (!(jit[j] = reduced_jit_new(m, j == 1, ERR_OF(err, sizeof err)))) fail_msg("%s: %s", path, err);
  MemSamples held;
  if (memsamples_fill(&held, prog, NULL, st->n, 3, 977u)) fail_msg("binding random params failed");
  for (long k = 0; k < 3; k++) {
    project_inputs(prog, &held, k, r, 3);
    int rc0 = reduced_eval(r[0], k);
    for (int j = 0; j < 2; j++) {
      const char *be = j ? "cc" : "libtcc";
      int rc = reduced_jit_eval(jit[j], r[j + 1], k);
      if (rc0 != 0 || rc != 0) { /* both fail, with one message */
        if (rc0 == 0 || rc == 0 || strcmp(reduced_error(r[0]), reduced_jit_error(jit[j])) != 0) {
          print_message("%s (%s), sample %ld: runtime says '%s', generated code '%s'\n", path, be, k,
                        rc0 ? reduced_error(r[0]) : "ok", rc ? reduced_jit_error(jit[j]) : "ok");
          failures++;
        }
        continue;
      }
      /* end to end: differences of earlier stages propagate */
      for (int i = 0; i < m->nstages; i++) {
        int q = m->stages[i].q;
        long mq = m->classes[m->qclass[q]].m;
        double d = rel_diff(reduced_coords(r[0], q), reduced_coords(r[j + 1], q), (size_t)mq);
        st->worst_chain = fmax(st->worst_chain, d);
        if (!(d <= st->chain_tol)) {
          print_message("%s (%s), sample %ld: stage %s differs end to end from the runtime by %.3g\n", path, be, k,
                        m->stages[i].st->sym->name, d);
          failures++;
        }
      }
      /* stage by stage, from the runtime's coordinates: only the stage's own rounding */
      for (int i = 0; i < m->nstages; i++) {
        for (int q = 0; q < m->nq; q++)
          memcpy(reduced_coords(r[j + 1], q), reduced_coords(r[0], q),
                 sizeof(double) * (size_t)m->classes[m->qclass[q]].m);
        int q = m->stages[i].q;
        long mq = m->classes[m->qclass[q]].m;
        memset(reduced_coords(r[j + 1], q), 0, sizeof(double) * (size_t)mq);
        if (reduced_jit_eval_stage(jit[j], r[j + 1], i, k)) fail_msg("%s: %s", path, reduced_jit_error(jit[j]));
        double d = rel_diff(reduced_coords(r[0], q), reduced_coords(r[j + 1], q), (size_t)mq);
        st->worst = fmax(st->worst, d);
        st->stages++;
        if (!(d <= 1e-12)) {
          print_message("%s (%s), sample %ld: stage %s differs from the runtime by %.3g\n", path, be, k,
                        m->stages[i].st->sym->name, d);
          failures++;
        }
      }
    }
    if (rc0 != 0) print_message("%s, sample %ld: the runtime fails: %s\n", path, k, reduced_error(r[0]));
  }
  st->programs++;
  memsamples_free(&held);
  for (int j = 0; j < 2; j++) reduced_jit_free(jit[j]);
  for (int j = 0; j < 3; j++) reduced_free(r[j]);
  trained_free(&tr);
  return failures;
}

static int generated_program(const char *path, void *arg) { return generated_text(path, NULL, arg); }

/* Shapes the corpus lacks: a tensor of three distinct inputs, one of them
 * squared (two intermediate buffers); a two-term inverse stage. */
static const char three_inputs[] = "dim N\n"
                                   "input x : real[N]\n"
                                   "input y : real[N]\n"
                                   "input z : real[N]\n"
                                   "input d : real[N]\n"
                                   "a[i:N] = x[i] * x[i] + 1\n"
                                   "output w[i:N] = x[i] * y[i] * z[i] * z[i] + x[i]\n"
                                   "output p[i:N] = d[i] / a[i] + w[i] / a[i]\n";

static void generated_equals_runtime(void **state) {
  (void)state;
  Stats st = {.n = 4, .S = 12, .cap = 3, .chain_tol = 1e-12};
  int n = 0, failures = 0;
  failures += generated_program("examples/rational/rational.npg", &st);
  failures += generated_program("examples/radiosity/formfactors.npg", &st);
  failures += generated_text("three_inputs.npg", three_inputs, &st);
  n += 3;
  failures += for_each_program("tests/programs", generated_program, &st, &n);
  print_message("%d programs, %d stage evaluations: generated reduced code (libtcc, cc) vs runtime, worst relative "
                "difference %.2g stage by stage, %.2g end to end\n",
                n, st.stages, st.worst, st.worst_chain);
  assert_int_equal(failures, 0);
  assert_int_equal(st.programs, n);
}

/* Larger bases: rows longer than 8 (the four partial sums, every
 * remainder), packed squares of 10-dimensional coordinates. Stage by stage
 * the generated code agrees to 1e-12; end to end, the reduced radiosity
 * solve on random triangles amplifies the 1e-14 differences of its inputs
 * (as it amplifies the runtime's own rounding): 1e-10. */
static void generated_equals_runtime_larger(void **state) {
  (void)state;
  Stats st = {.n = 6, .S = 40, .cap = 10, .chain_tol = 1e-10};
  int failures = 0;
  failures += generated_program("examples/radiosity/formfactors.npg", &st);
  failures += generated_text("three_inputs.npg", three_inputs, &st);
  failures += generated_program("tests/programs/spring_two_terms.npg", &st);
  failures += generated_program("tests/programs/root_of_op.npg", &st);
  print_message("larger bases: %d stage evaluations, worst relative difference %.2g stage by stage, %.2g end to end\n",
                st.stages, st.worst, st.worst_chain);
  assert_int_equal(failures, 0);
}

/* ---------------------------------------------------------------- failures */

static void singular_operator_named(void **state) {
  (void)state;
  Trained tr;
  train_small(&tr, "examples/rational/rational.npg", 3, 4);
  char err[2048] = "";
  Reduced *r[2];
  for (int j = 0; j < 2; j++) assert_non_null(r[j] = reduced_new(tr.m, ERR_OF(err, sizeof err)));
  RedJit *jit = reduced_jit_new(tr.m, false, ERR_OF(err, sizeof err));
  assert_non_null(jit);
  /* x = 0: the diagonal x^2 of y's denominator vanishes, and with it the reduced operator */
  int q = vec_position(&tr.prog->quantities, find_quantity(tr.prog, "x"));
  double zero[2] = {0, 0};
  for (int j = 0; j < 2; j++) reduced_project(r[j], q, zero);
  assert_int_equal(reduced_eval(r[0], 7), -1);
  assert_int_equal(reduced_jit_eval(jit, r[1], 7), -1);
  assert_string_equal(reduced_jit_error(jit), reduced_error(r[0]));
  /* the operator itself is zero there: said so, not "basis too small?" (issue 38) */
  assert_non_null(strstr(reduced_jit_error(jit), "is zero at sample 7: the operator itself vanishes"));

  /* coordinates of another model are refused */
  Trained other;
  train_small(&other, "tests/programs/root_of_op.npg", 3, 4);
  Reduced *ro = reduced_new(other.m, ERR_OF(err, sizeof err));
  assert_int_equal(reduced_jit_eval(jit, ro, 0), -1);
  assert_non_null(strstr(reduced_jit_error(jit), "another model"));
  reduced_free(ro);
  trained_free(&other);
  reduced_jit_free(jit);
  for (int j = 0; j < 2; j++) reduced_free(r[j]);
  trained_free(&tr);
}

/* ---------------------------------------------------------------- npgc emit --reduced */

/* The npgc next to this test's directory (build/tests/test_x -> build/npgc). */
static bool npgc_path(char *buf, size_t n) {
  char self[1024];
  ssize_t len = readlink("/proc/self/exe", self, sizeof self - 1);
  if (len <= 0) return false;
  self[len] = 0;
  char *slash = strrchr(self, '/');
  if (!slash) return false;
  *slash = 0;
  snprintf(buf, n, "%s/../npgc", self);
  return access(buf, X_OK) == 0;
}

static void npgc_emit_reduced(void **state) {
  (void)state;
  char npgc[1200];
  if (!npgc_path(npgc, sizeof npgc)) {
    print_message("npgc not found next to the test: skipped\n");
    skip();
  }
  const char *progs[] = {"examples/radiosity/formfactors.npg", "tests/programs/extern_stage.npg"};
  for (size_t i = 0; i < sizeof progs / sizeof *progs; i++) {
    Trained tr;
    train_small(&tr, progs[i], 3, 4);
    char dir[1024], model[1100], cpath[1100], cmd[4096], err[2048] = "";
    snprintf(dir, sizeof dir, "%s/npg-emit-reduced-XXXXXX", tmp_dir());
    assert_non_null(mkdtemp(dir));
    snprintf(model, sizeof model, "%s/model", dir);
    snprintf(cpath, sizeof cpath, "%s/reduced.c", dir);
    if (model_save(tr.m, model, ERR_OF(err, sizeof err))) fail_msg("%s", err);
    snprintf(cmd, sizeof cmd, "'%s' emit %s --reduced '%s' -o '%s'", npgc, progs[i], model, cpath);
    assert_int_equal(system(cmd), 0);
    /* what the command wrote is what emit_reduced writes for the loaded model */
    Model *loaded = model_load(tr.prog, model, ERR_OF(err, sizeof err));
    assert_non_null(loaded);
    char *mine = NULL;
    size_t len = 0;
    FILE *mem = open_memstream(&mine, &len);
    assert_int_equal(emit_reduced(loaded, mem, ERR_OF(err, sizeof err)), 0);
    fclose(mem);
    FILE *f = fopen(cpath, "r");
    assert_non_null(f);
    char *written = malloc(len + 2);
    size_t got = fread(written, 1, len + 1, f);
    fclose(f);
    assert_int_equal(got, len);
    assert_memory_equal(written, mine, len);
    /* the entry point carries the program's prefix (emit_symbol) */
    char entry[512], sig[600];
    emit_symbol(tr.prog, "reduced", entry, sizeof entry);
    snprintf(sig, sizeof sig, "int %s(const NpgReducedCtx *c)", entry);
    assert_non_null(strstr(written, sig));
    free(written);
    free(mine);
    model_free(loaded);
    assert_int_equal(cc_clean(cpath), 0);
    /* a missing model is an error, and no file is left behind */
    snprintf(cmd, sizeof cmd, "'%s' emit %s --reduced '%s/none' -o '%s/x.c' 2>/dev/null", npgc, progs[i], dir, dir);
    assert_int_not_equal(system(cmd), 0);
    snprintf(cmd, sizeof cmd, "%s/x.c", dir);
    assert_int_not_equal(access(cmd, F_OK), 0);
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    assert_int_equal(system(cmd), 0);
    trained_free(&tr);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(generated_equals_runtime),
      cmocka_unit_test(generated_equals_runtime_larger),
      cmocka_unit_test(singular_operator_named),
      cmocka_unit_test(npgc_emit_reduced),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
