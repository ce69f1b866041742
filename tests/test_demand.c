/* test_demand.c — restricted evaluation (backends/jit/demand.h): the
 * entries a demand asks for equal a whole evaluation's, bit for bit, and
 * what nothing demands is not computed. */
#include "testutil.h"

#include "demand.h"
#include "full.h"
#include "meshgen.h"
#include "randdata.h"

/* Gathers, transposed reads (of t, computed alone, and of u, fused with w
 * and z, rematerialized: z's u[j, i] reads e2 by columns), diagonal reads,
 * a summation, a division, a stage over another domain between them. */
static const char *const transposes =
    "dim N, M, V\n"
    "param idx : int[N]\n"
    "input x : real[V]\n"
    "input y : real[N, N]\n"
    "input m : real[M]\n"
    "t[i:N, j:N] = x[idx[i]] * y[j, i] + y[i, j]^2\n"
    "q[i:N, l:M] = t[i, i] * m[l] + 2\n"
    "extern e2[i:N, j:N] of x\n"
    "u[i:N, j:N] = t[j, i] * t[i, j] + x[idx[j]] * e2[i, j]\n"
    "w[i:N, j:N] = u[i, j] * q[i, 1] / (1 + t[i, i]^2)\n"
    "z[i:N, j:N] = sum(k = 0..N-1, t[i, k]) * w[i, j] + u[j, i]\n"
    "output o = sum(k = 0..N-1, z[k, k])\n";

/* Bind `f` to sample `k` of `prog` (the radiosity room, or the program above). */
static void bind_sample(Full *f, bool radiosity, long n, long k) {
  unsigned seed = 7u + 31u * (unsigned)k;
  if (radiosity) {
    Mesh mesh;
    char err[256];
    if (mesh_room(n, 0.05 * (double)k, &mesh, err, sizeof err)) fail_msg("%s", err);
    double *tri = malloc(sizeof(double) * (size_t)(3 * n)), *rho = malloc(sizeof(double) * (size_t)n);
    double *e = malloc(sizeof(double) * (size_t)n), *v = malloc(sizeof(double) * (size_t)(n * n));
    for (long i = 0; i < 3 * n; i++) tri[i] = mesh.tri[i];
    for (long i = 0; i < n; i++) rho[i] = randdata_uniform(&seed, 0.1, 0.8), e[i] = randdata_uniform(&seed, 0, 1);
    for (long i = 0; i < n * n; i++) v[i] = randdata_uniform(&seed, 0, 1);
    long ts[2] = {n, 3}, fs[1] = {n}, gs[2] = {mesh.V, 3}, vs[2] = {n, n};
    if (full_set_param(f, "tri", 2, ts, tri, "tri") || full_set_param(f, "rho", 1, fs, rho, "rho") ||
        full_set(f, "g", 2, gs, mesh.g, "g") || full_set(f, "e", 1, fs, e, "e") ||
        full_set(f, "v", 2, vs, v, "v"))
      fail_msg("%s", full_error(f));
    free(tri), free(rho), free(e), free(v);
    mesh_free(&mesh);
    return;
  }
  long V = n + 3;
  double *idx = malloc(sizeof(double) * (size_t)n), *x = malloc(sizeof(double) * (size_t)V);
  double *y = malloc(sizeof(double) * (size_t)(n * n)), *e2 = malloc(sizeof(double) * (size_t)(n * n));
  for (long i = 0; i < n; i++) idx[i] = (double)((i * 5 + 2) % V);
  for (long i = 0; i < V; i++) x[i] = randdata_uniform(&seed, -1, 1);
  for (long i = 0; i < n * n; i++) y[i] = randdata_uniform(&seed, -1, 1), e2[i] = randdata_uniform(&seed, 0, 1);
  double m[3] = {randdata_uniform(&seed, 1, 2), randdata_uniform(&seed, 1, 2), randdata_uniform(&seed, 1, 2)};
  long is[1] = {n}, xs[1] = {V}, ys[2] = {n, n}, ms[1] = {3};
  if (full_set_param(f, "idx", 1, is, idx, "idx") || full_set(f, "x", 1, xs, x, "x") ||
      full_set(f, "y", 2, ys, y, "y") || full_set(f, "m", 1, ms, m, "m") ||
      full_set(f, "e2", 2, ys, e2, "e2"))
    fail_msg("%s", full_error(f));
  free(idx), free(x), free(y), free(e2);
}

typedef struct Want {
  const char *name;
  size_t e0, e1;  /* flat entries */
} Want;

/* For samples 0 and 1: evaluate whole with one evaluator, restricted to
 * `want` with another (fresh before sample 0, so what it did not compute
 * is 0), and compare the wanted entries bit for bit; `skipped` must stay
 * 0 on sample 0, and so must some entry of the first wanted quantity that
 * a whole evaluation makes nonzero. */
static void check_restricted(NpgProgram *p, bool radiosity, long n, JitBackend backend, const Want *want, int nwant,
                             const char *skipped) {
  Program *prog = ir_ok(p);
  Full *whole = full_new(program_ir(p), backend, NULL), *part = full_new(program_ir(p), backend, NULL);
  for (long k = 0; k < 2; k++) {
    bind_sample(whole, radiosity, n, k);
    bind_sample(part, radiosity, n, k);
    if (full_eval(whole, k)) fail_msg("%s", full_error(whole));
    Demand *d = full_demand(part);
    assert_non_null(d);
    for (int i = 0; i < nwant; i++) demand_entries(d, find_quantity(prog, want[i].name), want[i].e0, want[i].e1);
    if (full_eval_demand(part, k, d)) fail_msg("%s", full_error(part));
    for (int i = 0; i < nwant; i++) {
      size_t na, nb;
      const double *a = full_get(whole, want[i].name, &na), *b = full_get(part, want[i].name, &nb);
      assert_int_equal(na, nb);
      for (size_t e = want[i].e0; e < want[i].e1; e++)
        if (memcmp(&a[e], &b[e], sizeof(double)) != 0)
          fail_msg("%s, sample %ld: %s entry %zu is %.17g restricted, %.17g whole", radiosity ? "radiosity" : "transposes",
                   k, want[i].name, e, b[e], a[e]);
    }
    if (k == 0) {
      size_t ns;
      const double *s = full_get(part, skipped, &ns), *w = full_get(whole, skipped, NULL);
      bool zero = true, nonzero = false;
      for (size_t e = 0; e < ns; e++) zero &= s[e] == 0, nonzero |= w[e] != 0;
      assert_true(nonzero && zero); /* computed whole, never restricted */
      size_t no;
      const double *o = full_get(part, want[0].name, &no), *ow = full_get(whole, want[0].name, NULL);
      bool restricted = false; /* some entry of it not computed */
      for (size_t e = 0; e < no; e++) restricted |= ow[e] != 0 && o[e] == 0;
      assert_true(restricted);
    }
  }
  full_free(whole);
  full_free(part);
}

/* Radiosity's pair rows as out-of-core passes ask for them: partial first
 * and last rows, overlapping ranges of different members (h is read
 * transposed by c, rematerialized in the fused loop). */
static void radiosity_rows_equal_whole(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
  const long F = 24;
  Want want[] = {{"p", 30, 100}, {"c", 90, 150}, {"h", 201, 202}, {"r", 575, 576}, {"s", 48, 72}, {"d", 0, 5}};
  check_restricted(p, true, F, JIT_TCC, want, 6, "b");
  npg_free(p);
}

static void transposes_and_gathers_equal_whole(void **state) {
  (void)state;
  NpgProgram *p = compile_text("transposes.npg", transposes);
  const long N = 13;
  Want want[] = {{"z", 20, 61}, {"t", 100, 110}, {"u", 140, 169}};
  for (int cc = 0; cc < 2; cc++) check_restricted(p, false, N, cc ? JIT_CC : JIT_TCC, want, 3, "o");
  npg_free(p);
}

/* Flat entries become boxes: a partial first row, whole rows, a partial
 * last row; the demand on a fused step joins overlapping rows. */
static void entries_become_boxes(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  bind_sample(f, true, 24, 0);
  Demand *d = full_demand(f);
  demand_entries(d, find_quantity(prog, "p"), 30, 100); /* row 1 from 6, rows 2-3, row 4 to 4 */
  demand_entries(d, find_quantity(prog, "d"), 48, 96);  /* rows 2-3: inside the above */
  assert_int_equal(demand_propagate(d), 0);
  const FullPlan *plan = emit_full_plan(prog->ctx, prog);
  int fused = -1, solve = -1;
  for (int k = 0; k < plan->n; k++) {
    if (plan->steps[k].kind == STEP_FUSED) fused = k;
    if (strcmp(plan->steps[k].members[0]->sym->name, "b") == 0) solve = k;
  }
  assert_true(fused >= 0 && solve >= 0);
  const npg_idx *box;
  assert_int_equal(demand_step(d, solve, &box), -1);
  int n = demand_step(d, fused, &box);
  assert_int_equal(n, 3);
  npg_idx want[3][4] = {{1, 6, 2, 24}, {2, 0, 4, 24}, {4, 0, 5, 4}};
  for (int b = 0; b < 3; b++) {
    bool found = false;
    for (int i = 0; i < n; i++) found |= memcmp(box + 4 * i, want[b], sizeof want[b]) == 0;
    assert_true(found);
  }
  full_free(f);
  npg_free(p);
}

/* t is read by rows (t[i, j], t[i, k]) and by columns (t[j, i]): rows 2-3
 * of z demand of t rows 2-3 and columns 2-3, as three disjoint boxes, not
 * their bounding box (the whole); of the extern e2 the same entries, the
 * columns through z's read of u[j, i] (rematerialized), as flat ranges. */
static void transposed_read_demands_rows_and_columns(void **state) {
  (void)state;
  NpgProgram *p = compile_text("transposes.npg", transposes);
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  const long N = 13;
  bind_sample(f, false, N, 0);
  Demand *d = full_demand(f);
  demand_entries(d, find_quantity(prog, "z"), 2 * N, 4 * N);
  assert_int_equal(demand_propagate(d), 0);
  const FullPlan *plan = emit_full_plan(prog->ctx, prog);
  int t = -1;
  for (int k = 0; k < plan->n; k++)
    if (plan->steps[k].n == 1 && strcmp(plan->steps[k].members[0]->sym->name, "t") == 0) t = k;
  assert_true(t >= 0 && plan->steps[t].boxed);
  const npg_idx *box;
  int n = demand_step(d, t, &box);
  assert_int_equal(n, 3);
  npg_idx want[3][4] = {{0, 2, 2, 4}, {2, 0, 4, N}, {4, 2, N, 4}};
  for (int b = 0; b < 3; b++) {
    bool found = false;
    for (int i = 0; i < n; i++) found |= memcmp(box + 4 * i, want[b], sizeof want[b]) == 0;
    assert_true(found);
  }
  size_t r[2 * 32];
  long nr = demand_ranges(d, find_quantity(prog, "e2"), r, 32);
  assert_int_equal(nr, 12); /* rows 2-3 as one range, columns 2-3 of the 11 other rows */
  /* the bound training's replay sizes its ranges by: one a row of a box, so never too few */
  long bound = demand_range_bound(d, find_quantity(prog, "e2"));
  assert_int_equal(bound, 2 + 2 + (N - 4));
  assert_int_equal(demand_ranges(d, find_quantity(prog, "e2"), r, nr - 1), -1);
  bool col = false, other = false;
  const size_t in = 7 * N + 2, out = 7 * N + 5; /* row 7: column 2 is read, column 5 not */
  for (long i = 0; i < nr; i++) col |= r[2 * i] <= in && in < r[2 * i + 1], other |= r[2 * i] <= out && out < r[2 * i + 1];
  assert_true(col && !other);
  full_free(f);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(radiosity_rows_equal_whole),
      cmocka_unit_test(transposes_and_gathers_equal_whole),
      cmocka_unit_test(entries_become_boxes),
      cmocka_unit_test(transposed_read_demands_rows_and_columns),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
