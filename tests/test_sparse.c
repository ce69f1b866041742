/* test_sparse.c — sparse declared operators in the full evaluator (DESIGN
 * §13): an operator that gathers its K neighbours through an index table is
 * assembled in compressed form, its pattern once per param binding, and
 * solved by CHOLMOD when symmetric positive definite, by UMFPACK otherwise;
 * every result equals the dense path (assembled whole, LAPACK) to 1e-12. */
#include <limits.h>
#include <math.h>

#include "full.h"
#include "testutil.h"

/* Finite-volume heat conduction on an nx × ny grid: a conductivity per cell
 * scales its row, so the operator is not symmetric (UMFPACK). */
static const char *heat =
    "dim N\n"
    "param nbr : int[N, 4]\n"
    "param src : real[N]\n"
    "input kappa : real[N]\n"
    "op K[i:N, j:N] = delta(i, j) * (1 + sum(k = 0..3, if(nbr[i, k] >= 0, kappa[i], 0)))"
    " - sum(k = 0..3, if(nbr[i, k] == j, kappa[i], 0))\n"
    "output u = solve(K, src)\n"
    "output y = K * src\n";

/* A weighted graph Laplacian from an edge list, plus `shift` times the
 * identity: symmetric, positive definite for positive weights and shift
 * (CHOLMOD), indefinite for a negative shift (UMFPACK after CHOLMOD
 * refuses), and singular with no shift. */
static const char *laplacian =
    "dim N, E\n"
    "param tab : int[E, 2]\n"
    "param f : real[N]\n"
    "param shift : real\n"
    "input w : real[E]\n"
    "op L[i:N, j:N] = shift * delta(i, j) + sum(e = 0..E-1, w[e] * (delta(i, tab[e, 0]) - delta(i, tab[e, 1]))"
    " * (delta(j, tab[e, 0]) - delta(j, tab[e, 1])))\n"
    "output y = solve(L, f)\n";

/* The same operator's roots: by Lanczos on sparse products, against the
 * dense eigendecomposition. */
static const char *laplacian_roots =
    "dim N, E\n"
    "param tab : int[E, 2]\n"
    "param f : real[N]\n"
    "param shift : real\n"
    "input w : real[E]\n"
    "op L[i:N, j:N] = shift * delta(i, j) + sum(e = 0..E-1, w[e] * (delta(i, tab[e, 0]) - delta(i, tab[e, 1]))"
    " * (delta(j, tab[e, 0]) - delta(j, tab[e, 1])))\n"
    "output r = root(L, 2) * f\n"
    "output s = L^(-1/2) * f\n"
    "output t = L^(3/2) * f\n";

enum { NX = 12, NY = 10, N = NX * NY };

static unsigned rng = 12345u;
static double uniform(void) {
  rng = rng * 1103515245u + 12345u;
  return ((rng >> 8) & 0xFFFFFF) / (double)0x1000000;
}

/* The same data every call (the sparse and the dense evaluator compare). */
static Full *heat_full(NpgProgram *p) {
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  assert_non_null(f);
  double nbr[N * 4], src[N];
  unsigned seed = 7u;
  for (int y = 0; y < NY; y++)
    for (int x = 0; x < NX; x++) {
      int i = y * NX + x;
      nbr[i * 4 + 0] = x > 0 ? i - 1 : -1;
      nbr[i * 4 + 1] = x < NX - 1 ? i + 1 : -1;
      nbr[i * 4 + 2] = y > 0 ? i - NX : -1;
      nbr[i * 4 + 3] = y < NY - 1 ? i + NX : -1;
      seed = seed * 1103515245u + 12345u;
      src[i] = ((seed >> 8) & 0xFFFF) / 65536.0;
    }
  long s2[2] = {N, 4}, s1[1] = {N};
  assert_int_equal(full_set_param(f, "nbr", 2, s2, nbr, "nbr"), 0);
  assert_int_equal(full_set_param(f, "src", 1, s1, src, "src"), 0);
  return f;
}

/* Evaluate `sparse` (sparse path forced) and `dense` (dense path forced)
 * on the same input; every output equal to 1e-12. */
static void same_outputs(Full *sparse, Full *dense, const char *input, long n, const double *values,
                         const char *const *outputs, int nout, long sample) {
  long shape[1] = {n};
  assert_int_equal(full_set(sparse, input, 1, shape, values, input), 0);
  assert_int_equal(full_set(dense, input, 1, shape, values, input), 0);
  if (full_eval(sparse, sample)) fail_msg("%s", full_error(sparse));
  if (full_eval(dense, sample)) fail_msg("%s", full_error(dense));
  for (int k = 0; k < nout; k++) {
    size_t cs, cd;
    const double *a = full_get(sparse, outputs[k], &cs), *b = full_get(dense, outputs[k], &cd);
    assert_int_equal(cs, cd);
    double d = rel_diff(a, b, cs);
    if (!(d <= 1e-12)) fail_msg("output %s: sparse and dense differ by %.3g", outputs[k], d);
  }
}

/* Non-symmetric heat operator: UMFPACK, the pattern built once over three
 * samples and again after the params are bound anew. */
static void heat_umfpack_equals_dense(void **state) {
  (void)state;
  NpgProgram *p = compile_text("heat.npg", heat);
  ir_ok(p);
  Full *sparse = heat_full(p), *dense = heat_full(p);
  full_set_sparse_min_rows(sparse, 0);
  full_set_sparse_min_rows(dense, LONG_MAX);
  const char *outs[] = {"u", "y"};
  double kappa[N];
  for (int s = 0; s < 3; s++) {
    for (int i = 0; i < N; i++) kappa[i] = 0.2 + uniform();
    same_outputs(sparse, dense, "kappa", N, kappa, outs, 2, s);
  }
  long patterns, chol, lu;
  full_sparse_counts(sparse, &patterns, &chol, &lu);
  assert_int_equal(patterns, 1);
  assert_int_equal(chol, 0);
  assert_int_equal(lu, 3);
  full_sparse_counts(dense, &patterns, &chol, &lu);
  assert_int_equal(chol + lu, 0); /* assembled in compressed form, then solved dense */
  /* a new binding: a new pattern */
  double src[N];
  for (int i = 0; i < N; i++) src[i] = uniform();
  long s1[1] = {N};
  assert_int_equal(full_set_param(sparse, "src", 1, s1, src, "src"), 0);
  assert_int_equal(full_set_param(dense, "src", 1, s1, src, "src"), 0);
  same_outputs(sparse, dense, "kappa", N, kappa, outs, 2, 3);
  full_sparse_counts(sparse, &patterns, &chol, &lu);
  assert_int_equal(patterns, 2);
  full_free(sparse);
  full_free(dense);
  npg_free(p);
}

/* A ring with chords: E edges over N nodes. */
enum { LN = 150, LE = 300 };
static Full *laplacian_full(NpgProgram *p, double shift) {
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  assert_non_null(f);
  static double tab[LE * 2], rhs[LN];
  for (int e = 0; e < LE; e++) {
    tab[e * 2] = e % LN;
    tab[e * 2 + 1] = e < LN ? (e + 1) % LN : (e * 7 + 3) % LN;
    if (tab[e * 2 + 1] == tab[e * 2]) tab[e * 2 + 1] = (e + 2) % LN;
  }
  unsigned seed = 11u;
  for (int i = 0; i < LN; i++) {
    seed = seed * 1103515245u + 12345u;
    rhs[i] = ((seed >> 8) & 0xFFFF) / 65536.0 - 0.5;
  }
  long st[2] = {LE, 2}, sf[1] = {LN};
  assert_int_equal(full_set_param(f, "tab", 2, st, tab, "tab"), 0);
  assert_int_equal(full_set_param(f, "f", 1, sf, rhs, "f"), 0);
  assert_int_equal(full_set_param(f, "shift", 0, NULL, &shift, "shift"), 0);
  return f;
}

/* Positive weights: symmetric positive definite, CHOLMOD. A negative
 * shift: symmetric indefinite, CHOLMOD refuses and UMFPACK solves. */
static void laplacian_cholmod_and_indefinite(void **state) {
  (void)state;
  NpgProgram *p = compile_text("laplacian.npg", laplacian);
  Program *prog = ir_ok(p);
  assert_true(((OpDef *)prog->opdefs.v[0])->sparse);
  Full *sparse = laplacian_full(p, 0.5), *dense = laplacian_full(p, 0.5);
  full_set_sparse_min_rows(sparse, 0);
  full_set_sparse_min_rows(dense, LONG_MAX);
  const char *outs[] = {"y"};
  double w[LE];
  for (int s = 0; s < 2; s++) {
    for (int e = 0; e < LE; e++) w[e] = 0.1 + uniform();
    same_outputs(sparse, dense, "w", LE, w, outs, 1, s);
  }
  long patterns, chol, lu;
  full_sparse_counts(sparse, &patterns, &chol, &lu);
  assert_int_equal(patterns, 1);
  assert_int_equal(chol, 2);
  assert_int_equal(lu, 0);
  /* the Laplacian's eigenvalue 0 shifted below zero: symmetric indefinite */
  double shift = -0.37;
  assert_int_equal(full_set_param(sparse, "shift", 0, NULL, &shift, "shift"), 0);
  assert_int_equal(full_set_param(dense, "shift", 0, NULL, &shift, "shift"), 0);
  same_outputs(sparse, dense, "w", LE, w, outs, 1, 2);
  full_sparse_counts(sparse, &patterns, &chol, &lu);
  assert_int_equal(patterns, 2);
  assert_int_equal(chol, 2);
  assert_int_equal(lu, 1);
  full_free(sparse);
  full_free(dense);
  npg_free(p);
}

/* The pattern's placement of unordered contributions: a star (a hub in the
 * middle joined to every other node, the edges in shuffled order, so the
 * hub's column gathers LN rows out of order, more than the insertion sort's
 * 16) and chords (short columns out of order, repeated entries merged).
 * Equal to the dense path, and symmetric (CHOLMOD: every transposed slot
 * found). */
static void unordered_pattern_placed(void **state) {
  (void)state;
  NpgProgram *p = compile_text("laplacian.npg", laplacian);
  ir_ok(p);
  static double tab[LE * 2], rhs[LN];
  int order[LN - 1], hub = LN / 2;
  for (int k = 0; k < LN - 1; k++) order[k] = k < hub ? k : k + 1;
  for (int k = LN - 2; k > 0; k--) { /* Fisher-Yates */
    int r = (int)(uniform() * (k + 1)), t = order[k];
    order[k] = order[r], order[r] = t;
  }
  for (int e = 0; e < LE; e++) {
    bool star = e < LN - 1;
    tab[e * 2] = star ? (e % 2 ? hub : order[e]) : (e * 13 + 5) % LN;
    tab[e * 2 + 1] = star ? (e % 2 ? order[e] : hub) : (e * 29 + 1) % LN;
    if (tab[e * 2] == tab[e * 2 + 1]) tab[e * 2 + 1] = ((int)tab[e * 2] + 3) % LN;
  }
  for (int i = 0; i < LN; i++) rhs[i] = uniform() - 0.5;
  double shift = 0.25;
  long st[2] = {LE, 2}, sf[1] = {LN};
  Full *f[2];
  for (int k = 0; k < 2; k++) {
    f[k] = full_new(program_ir(p), JIT_TCC, NULL);
    assert_non_null(f[k]);
    assert_int_equal(full_set_param(f[k], "tab", 2, st, tab, "tab"), 0);
    assert_int_equal(full_set_param(f[k], "f", 1, sf, rhs, "f"), 0);
    assert_int_equal(full_set_param(f[k], "shift", 0, NULL, &shift, "shift"), 0);
  }
  full_set_sparse_min_rows(f[0], 0);
  full_set_sparse_min_rows(f[1], LONG_MAX);
  const char *outs[] = {"y"};
  double w[LE];
  for (int e = 0; e < LE; e++) w[e] = 0.1 + uniform();
  same_outputs(f[0], f[1], "w", LE, w, outs, 1, 0);
  long patterns, chol, lu;
  full_sparse_counts(f[0], &patterns, &chol, &lu);
  assert_int_equal(patterns, 1);
  assert_int_equal(chol, 1);
  assert_int_equal(lu, 0);
  full_free(f[0]);
  full_free(f[1]);
  npg_free(p);
}

/* Square root, inverse square root and 3/2 power of a sparse SPD
 * operator by Lanczos equal the dense eigendecomposition to 1e-10; an
 * indefinite one is refused, naming the operator. */
static void roots_by_lanczos(void **state) {
  (void)state;
  NpgProgram *p = compile_text("roots.npg", laplacian_roots);
  ir_ok(p);
  Full *sparse = laplacian_full(p, 0.5), *dense = laplacian_full(p, 0.5);
  full_set_sparse_min_rows(sparse, 0);
  full_set_sparse_min_rows(dense, LONG_MAX);
  const char *outs[] = {"r", "s", "t"};
  double w[LE];
  for (int e = 0; e < LE; e++) w[e] = 0.1 + uniform();
  long shape[1] = {LE};
  assert_int_equal(full_set(sparse, "w", 1, shape, w, "w"), 0);
  assert_int_equal(full_set(dense, "w", 1, shape, w, "w"), 0);
  if (full_eval(sparse, 0)) fail_msg("%s", full_error(sparse));
  if (full_eval(dense, 0)) fail_msg("%s", full_error(dense));
  for (int k = 0; k < 3; k++) {
    size_t cs, cd;
    const double *a = full_get(sparse, outs[k], &cs), *b = full_get(dense, outs[k], &cd);
    double d = rel_diff(a, b, cs);
    if (!(d <= 1e-10)) fail_msg("output %s: Lanczos and the eigendecomposition differ by %.3g", outs[k], d);
  }
  double shift = -0.37;
  assert_int_equal(full_set_param(sparse, "shift", 0, NULL, &shift, "shift"), 0);
  assert_int_not_equal(full_eval(sparse, 4), 0);
  if (!strstr(full_error(sparse), "operator L") || !strstr(full_error(sparse), "sample 4"))
    fail_msg("unexpected message: %s", full_error(sparse));
  full_free(sparse);
  full_free(dense);
  npg_free(p);
}

/* No shift: the Laplacian of a connected graph is singular; refused with
 * the operator, the stage and the sample named. */
static void singular_refused(void **state) {
  (void)state;
  NpgProgram *p = compile_text("laplacian.npg", laplacian);
  ir_ok(p);
  Full *f = laplacian_full(p, 0.0);
  full_set_sparse_min_rows(f, 0);
  double w[LE];
  for (int e = 0; e < LE; e++) w[e] = 0.1 + uniform();
  long shape[1] = {LE};
  assert_int_equal(full_set(f, "w", 1, shape, w, "w"), 0);
  assert_int_not_equal(full_eval(f, 7), 0);
  const char *msg = full_error(f);
  if (!strstr(msg, "sample 7") || !strstr(msg, "operator L is singular") || !strstr(msg, "stage 'y'"))
    fail_msg("unexpected message: %s", msg);
  full_free(f);
  npg_free(p);
}

/* Negative roots of the singular Laplacian (no shift): refused as solve
 * refuses it, on the Lanczos path and on the dense eigendecomposition,
 * rather than rounding noise (~1e7) raised to the power (issue 38). */
static const char *laplacian_negative_roots =
    "dim N, E\n"
    "param tab : int[E, 2]\n"
    "param f : real[N]\n"
    "param shift : real\n"
    "input w : real[E]\n"
    "op L[i:N, j:N] = shift * delta(i, j) + sum(e = 0..E-1, w[e] * (delta(i, tab[e, 0]) - delta(i, tab[e, 1]))"
    " * (delta(j, tab[e, 0]) - delta(j, tab[e, 1])))\n"
    "output s = L^(NUM) * f\n";

static void singular_negative_roots_refused(void **state) {
  (void)state;
  const char *powers[] = {"-1/2", "-1/3", "-3/2"};
  for (int k = 0; k < 3; k++) {
    char text[1024];
    const char *at = strstr(laplacian_negative_roots, "NUM");
    snprintf(text, sizeof text, "%.*s%s%s", (int)(at - laplacian_negative_roots), laplacian_negative_roots, powers[k],
             at + 3);
    NpgProgram *p = compile_text("roots.npg", text);
    ir_ok(p);
    for (int path = 1; path >= 0; path--) {
      Full *f = laplacian_full(p, 0.0);
      full_set_sparse_min_rows(f, path ? LONG_MAX : 0);
      double w[LE];
      for (int e = 0; e < LE; e++) w[e] = 0.1 + uniform();
      long shape[1] = {LE};
      assert_int_equal(full_set(f, "w", 1, shape, w, "w"), 0);
      if (full_eval(f, 5) == 0) {
        size_t n;
        const double *s = full_get(f, "s", &n);
        fail_msg("L^(%s) of a singular L (%s path) accepted: s[0] = %g", powers[k], path ? "dense" : "Lanczos", s[0]);
      }
      const char *msg = full_error(f);
      if (!strstr(msg, "sample 5") || !strstr(msg, "operator L is singular") || !strstr(msg, "stage 's'"))
        fail_msg("L^(%s), %s path: unexpected message: %s", powers[k], path ? "dense" : "Lanczos", msg);
      full_free(f);
    }
    npg_free(p);
  }
}

/* A sparse matrix given as data in padded rows (ELLPACK: a column table with -1 padding and
 * a value table, W entries per row, W a dim): an operator over params alone, sparse because
 * the delta fixes the column and the sum runs over the row width, not over a dim of the
 * operator's axes (examples/fluids/tunnel_step.npg's projection). The same sum over the
 * whole column dim stays dense. */
static const char *padded =
    "dim N, W\n"
    "param col : int[N, W]\n"
    "param val : real[N, W]\n"
    "input a : real[N]\n"
    "op S[i:N, j:N] = sum(q = 0..W-1, delta(j, col[i, q]) * val[i, q])\n"
    "output y = solve(S, a)\n"
    "output z = S * a\n";

static void padded_rows_cholmod(void **state) {
  (void)state;
  NpgProgram *p = compile_text("padded.npg", padded);
  Program *prog = ir_ok(p);
  assert_true(((OpDef *)prog->opdefs.v[0])->sparse);
  /* a 1D Laplacian plus 2.5 I, rows in shuffled slot order, padded to W = 5 */
  enum { PN = 120, PW = 5 };
  static double col[PN * PW], val[PN * PW];
  Full *fs[2];
  for (int k = 0; k < 2; k++) {
    fs[k] = full_new(prog, JIT_TCC, NULL);
    assert_non_null(fs[k]);
  }
  for (int i = 0; i < PN; i++) {
    int n = 0, slot0 = i % PW;
    for (int q = 0; q < PW; q++) col[i * PW + q] = -1, val[i * PW + q] = 0;
    const int cols[3] = {i, i - 1, i + 1};
    const double vals[3] = {4.5, -1, -1};
    for (int t = 0; t < 3; t++) {
      if (cols[t] < 0 || cols[t] >= PN) continue;
      int q = (slot0 + 2 * n++) % PW;
      col[i * PW + q] = cols[t], val[i * PW + q] = vals[t];
    }
  }
  long sh[2] = {PN, PW};
  for (int k = 0; k < 2; k++) {
    assert_int_equal(full_set_param(fs[k], "col", 2, sh, col, "col"), 0);
    assert_int_equal(full_set_param(fs[k], "val", 2, sh, val, "val"), 0);
  }
  full_set_sparse_min_rows(fs[0], 0);
  full_set_sparse_min_rows(fs[1], LONG_MAX);
  double a[PN];
  for (int i = 0; i < PN; i++) a[i] = uniform() - 0.5;
  const char *outs[] = {"y", "z"};
  same_outputs(fs[0], fs[1], "a", PN, a, outs, 2, 0);
  /* z = S a by hand */
  size_t n;
  const double *z = full_get(fs[0], "z", &n);
  assert_int_equal(n, PN);
  for (int i = 0; i < PN; i++) {
    double want = 4.5 * a[i] - (i > 0 ? a[i - 1] : 0) - (i + 1 < PN ? a[i + 1] : 0);
    assert_true(fabs(z[i] - want) <= 1e-13);
  }
  long patterns, chol, lu;
  full_sparse_counts(fs[0], &patterns, &chol, &lu);
  assert_int_equal(chol, 1);
  assert_int_equal(lu, 0);
  for (int k = 0; k < 2; k++) full_free(fs[k]);
  npg_free(p);
  /* a sum over the column dim itself is not a row table: dense */
  p = compile_text("wide.npg", "dim N\nparam col : int[N, N]\nparam val : real[N, N]\ninput a : real[N]\n"
                               "op S[i:N, j:N] = sum(q = 0..N-1, delta(j, col[i, q]) * val[i, q])\n"
                               "output y = solve(S, a)\n");
  prog = ir_ok(p);
  assert_false(((OpDef *)prog->opdefs.v[0])->sparse);
  npg_free(p);
}

/* `npgc check` treats a neighbour gather as sparse and radiosity's form
 * factors as dense. */
static void density_decided_by_pattern(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
  Program *prog = ir_ok(p);
  for (int i = 0; i < prog->opdefs.n; i++) assert_false(((OpDef *)prog->opdefs.v[i])->sparse);
  npg_free(p);
  p = compile_text("heat.npg", heat);
  prog = ir_ok(p);
  assert_true(((OpDef *)prog->opdefs.v[0])->sparse);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(heat_umfpack_equals_dense),
      cmocka_unit_test(laplacian_cholmod_and_indefinite),
      cmocka_unit_test(unordered_pattern_placed),
      cmocka_unit_test(roots_by_lanczos),
      cmocka_unit_test(singular_refused),
      cmocka_unit_test(singular_negative_roots_refused),
      cmocka_unit_test(density_decided_by_pattern),
      cmocka_unit_test(padded_rows_cholmod),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
