/* test_bind.c — binding data: every malformed case gets a message naming
 * the file (or the stage and sample) and the problem, exactly. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "npy.h"
#include "testutil.h"

static char dir[256];

static void put(const char *name, NpyType t, int nd, const long *shape, const void *data) {
  char path[512], err[512];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  if (npy_write(path, t, nd, shape, data, err, sizeof err)) fail_msg("%s", err);
}

static void rm(const char *name) {
  char path[512];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  unlink(path);
}

/* A well-formed radiosity binding: F = 4 faces of a tetrahedron, V = 4. */
static const long F = 4, V = 4;
static long long tri[4][3] = {{0, 1, 2}, {0, 3, 1}, {0, 2, 3}, {1, 3, 2}};
static double rho[4] = {0.2, 0.3, 0.4, 0.5};

static void good_data(void) {
  long s2[2] = {F, 3}, s1[1] = {F};
  put("tri", NPY_I64, 2, s2, tri);
  put("rho", NPY_F64, 1, s1, rho);
}

static NpgFull *radiosity(NpgProgram **pp) {
  *pp = compile_file("examples/radiosity/formfactors.npg");
  ir_ok(*pp);
  NpgFull *f = npg_full_new(*pp, NPG_TCC);
  assert_string_equal(npg_full_error(f), "");
  return f;
}

static char *msg(const char *fmt, const char *a) {
  static char buf[1024];
  snprintf(buf, sizeof buf, fmt, a, a, a);
  return buf;
}

static void expect_bind_error(const char *want) {
  NpgProgram *p;
  NpgFull *f = radiosity(&p);
  assert_int_equal(npg_full_bind_params(f, dir), -1);
  assert_string_equal(npg_full_error(f), want);
  npg_full_free(f);
  npg_free(p);
}

static void missing_file(void **state) {
  (void)state;
  good_data();
  rm("rho");
  char want[1024];
  snprintf(want, sizeof want, "%s/rho.npy: cannot open: No such file or directory", dir);
  NpgProgram *p;
  NpgFull *f = radiosity(&p);
  assert_int_equal(npg_full_bind_params(f, dir), -1);
  assert_non_null(strstr(npg_full_error(f), "/rho.npy"));
  assert_non_null(strstr(npg_full_error(f), "No such file or directory"));
  npg_full_free(f);
  npg_free(p);
  (void)want;
}

static void wrong_dtype(void **state) {
  (void)state;
  good_data();
  double t[12];
  for (int i = 0; i < 12; i++) t[i] = (double)tri[i / 3][i % 3];
  long s2[2] = {F, 3};
  put("tri", NPY_F64, 2, s2, t);
  expect_bind_error(msg("%s/tri.npy: param 'tri' is declared int but the array is float64", dir));
}

static void dim_mismatch_names_both_files(void **state) {
  (void)state;
  good_data();
  double r[7] = {0};
  long s1[1] = {7};
  put("rho", NPY_F64, 1, s1, r);
  char want[1024];
  snprintf(want, sizeof want, "dim F is 4 in %s/tri.npy but 7 in %s/rho.npy", dir, dir);
  expect_bind_error(want);
}

static void static_axis_mismatch(void **state) {
  (void)state;
  good_data();
  long long t[16] = {0};
  long s2[2] = {F, 4};
  put("tri", NPY_I64, 2, s2, t);
  expect_bind_error(msg("%s/tri.npy: axis 1 of 'tri' is static with size 3, but the array has 4", dir));
}

static void wrong_rank(void **state) {
  (void)state;
  good_data();
  long long t[12] = {0};
  long s1[1] = {12};
  put("tri", NPY_I64, 1, s1, t);
  expect_bind_error(msg("%s/tri.npy: 'tri' has 2 axes, but the array has 1", dir));
}

static void nan_in_param(void **state) {
  (void)state;
  good_data();
  double r[4] = {0.2, 0.3, 0.0 / 0.0, 0.5};
  long s1[1] = {F};
  put("rho", NPY_F64, 1, s1, r);
  expect_bind_error(msg("%s/rho.npy: param 'rho' holds NaN at [2]", dir));
}

/* The radiosity program on the tetrahedron with entry [face][corner] of
 * tri.npy set to `value`, evaluated once (it must fail): its evaluator,
 * whose error the caller reads and frees with `*pp`. */
static NpgFull *radiosity_failing(NpgProgram **pp, int face, int corner, long long value) {
  good_data();
  long long t[4][3];
  memcpy(t, tri, sizeof t);
  t[face][corner] = value;
  long s2[2] = {F, 3};
  put("tri", NPY_I64, 2, s2, t);
  NpgFull *f = radiosity(pp);
  assert_int_equal(npg_full_bind_params(f, dir), 0);
  double g[12], e[4] = {1, 0, 0, 0}, v[16];
  for (int i = 0; i < 12; i++) g[i] = (double)((i * 7) % 5) + 0.1 * i;
  for (int i = 0; i < 16; i++) v[i] = 1;
  long sg[2] = {V, 3}, se[1] = {F}, sv[2] = {F, F};
  assert_int_equal(npg_full_set(f, "g", 2, sg, g, "g"), 0);
  assert_int_equal(npg_full_set(f, "e", 1, se, e, "e"), 0);
  assert_int_equal(npg_full_set(f, "v", 2, sv, v, "v"), 0);
  assert_int_equal(npg_full_eval(f, 0), -1);
  return f;
}

/* An int param holds 32-bit entries (npg_iparam): a value outside that range
 * is refused when bound, naming the file, the entry and the range, never
 * truncated into another index. */
static void int_param_out_of_range(void **state) {
  (void)state;
  long long big[4][3];
  memcpy(big, tri, sizeof big);
  big[1][2] = 3000000000LL;
  long s2[2] = {F, 3};
  put("tri", NPY_I64, 2, s2, big);
  NpgProgram *p;
  NpgFull *f = radiosity(&p);
  assert_int_equal(npg_full_bind_params(f, dir), -1);
  const char *e = npg_full_error(f);
  if (!strstr(e, "tri.npy") || !strstr(e, "int param 'tri' holds 3000000000 at [1, 2], outside the range of an int "
                                         "param (-2147483648 to 2147483647)"))
    fail_msg("unexpected message: %s", e);
  npg_full_free(f);
  npg_free(p);
  good_data();
}

/* An index out of range in tri.npy: found once at bind time (the first
 * evaluation), naming the file, the entry and the dim. */
static void gather_out_of_range(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = radiosity_failing(&p, 2, 1, 9);
  /* at the use in the program: tri[f,1] is the first gather of stage n */
  char want[1024];
  snprintf(want, sizeof want,
           "examples/radiosity/formfactors.npg:12:29: error: %s/tri.npy: entry [2, 1] = 9 is out of range for dim V "
           "(size 4), used as an index in stage 'n'\n"
           "n[f:F]      = 0.5 * cross(g[tri[f,1]] - g[tri[f,0]], g[tri[f,2]] - g[tri[f,0]])   # area vector: |n|…\n"
           "                            ^",
           dir);
  assert_string_equal(npg_full_error(f), want);
  npg_full_free(f);
  npg_free(p);
}

/* A zero-area triangle: the NaN arises in p = d·a^(-1/2) (a = 0, d = 0), and the message names the zero
 * itself, a[0] (face 0, the degenerate triangle), not only the stage where the NaN appears and the solve for b
 * it then breaks (issue 38). */
static void zero_area_triangle(void **state) {
  (void)state;
  NpgProgram *p;
  NpgFull *f = radiosity_failing(&p, 0, 1, tri[0][0]);
  const char *want = "sample 0: stage 'p' is not finite: p[0, 0] is NaN (a division by zero: a[0] is 0, and p "
                     "raises it to the power -1/2); then stage 'b': operator M is not finite";
  if (strncmp(npg_full_error(f), want, strlen(want)) != 0) fail_msg("got: %s", npg_full_error(f));
  npg_full_free(f);
  npg_free(p);
  /* face 2 degenerate: a[2] named, at p's first entry of row 2 */
  f = radiosity_failing(&p, 2, 2, tri[2][1]);
  want = "sample 0: stage 'p' is not finite: p[2, 0] is NaN (a division by zero: a[2] is 0, and p raises it "
         "to the power -1/2); ";
  if (strncmp(npg_full_error(f), want, strlen(want)) != 0) fail_msg("got: %s", npg_full_error(f));
  npg_full_free(f);
  npg_free(p);
}

/* A compound index and a gather inlined from a fn: the error stands at
 * the use in the program (the param in the index, the call). */
static void gather_out_of_range_located(void **state) {
  (void)state;
  const struct {
    const char *stage, *want;
  } cases[] = {
      {"output y[k:E] = x[e[k] + 1]\n",
       "gather.npg:4:19: error: stage 'y' at [1]: index 4 is out of range for dim N (size 4)\n"
       "output y[k:E] = x[e[k] + 1]\n"
       "                  ^"},
      {"fn at(v, k) = v[e[k]]\noutput y[k:E] = 2 * at(x, k)\n",
       "gather.npg:5:21: error: IN/e.npy: entry [1] = 9 is out of range for dim N (size 4), used as an index in stage 'y'\n"
       "output y[k:E] = 2 * at(x, k)\n"
       "                    ^"},
  };
  for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
    char text[512];
    snprintf(text, sizeof text, "dim N, E\nparam e : int[E]\ninput x : real[N]\n%s", cases[c].stage);
    NpgProgram *p = compile_text("gather.npg", text);
    ir_ok(p);
    NpgFull *f = npg_full_new(p, NPG_TCC);
    double e[2] = {0, c == 0 ? 3 : 9}, x[4] = {1, 2, 3, 4};
    long se[1] = {2}, sx[1] = {4};
    assert_int_equal(npg_full_set(f, "e", 1, se, e, "IN/e.npy"), 0);
    assert_int_equal(npg_full_set(f, "x", 1, sx, x, "IN/x.npy"), 0);
    assert_int_equal(npg_full_eval(f, 0), -1);
    assert_string_equal(npg_full_error(f), cases[c].want);
    npg_full_free(f);
    npg_free(p);
  }
}

static void nan_in_input(void **state) {
  (void)state;
  good_data();
  NpgProgram *p;
  NpgFull *f = radiosity(&p);
  assert_int_equal(npg_full_bind_params(f, dir), 0);
  double g[12] = {0.0 / 0.0};
  long sg[2] = {V, 3};
  assert_int_equal(npg_full_set(f, "g", 2, sg, g, "IN/g.npy"), -1);
  assert_string_equal(npg_full_error(f), "IN/g.npy: 'g' holds NaN at [0, 0]");
  npg_full_free(f);
  npg_free(p);
}

/* Singular and indefinite operators: the stage, the operator and the sample. */
static void singular_and_indefinite(void **state) {
  (void)state;
  NpgProgram *p = compile_text("ops.npg",
                               "dim N\n"
                               "param a : real[N, N]\n"
                               "input x : real[N]\n"
                               "op M[i:N, j:N] = a[i, j]\n"
                               "output y = solve(M, x)\n"
                               "output z = root(M, 2) * x\n");
  ir_ok(p);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  double zero[4] = {0, 0, 0, 0}, neg[4] = {-1, 0, 0, -1}, x[2] = {1, 2};
  long s2[2] = {2, 2}, s1[1] = {2};
  assert_int_equal(npg_full_set(f, "a", 2, s2, zero, "a"), 0);
  assert_int_equal(npg_full_set(f, "x", 1, s1, x, "x"), 0);
  assert_int_equal(npg_full_eval(f, 12), -1);
  assert_string_equal(npg_full_error(f), "sample 12: stage 'y': operator M is singular (rcond 0.0e+00)");
  npg_full_clear_error(f);
  assert_int_equal(npg_full_set(f, "a", 2, s2, neg, "a"), 0);
  assert_int_equal(npg_full_eval(f, 3), -1);
  assert_string_equal(npg_full_error(f),
                      "sample 3: stage 'z': operator M is not positive semidefinite (eigenvalue -1), so its power 1/2 "
                      "is undefined");
  npg_full_free(f);
  npg_free(p);
}

/* An operator the data make non-finite (a division by zero in its
 * entries): named as such, not as a LAPACK argument error. */
static void operator_not_finite(void **state) {
  (void)state;
  NpgProgram *p = compile_text("inf.npg",
                               "dim N\n"
                               "param a : real[N, N]\n"
                               "input x : real[N]\n"
                               "input e : real[N]\n"
                               "op M[i:N, j:N] = delta(i, j) + a[i, j] / x[i]\n"
                               "output y = solve(M, e)\n");
  ir_ok(p);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  double a[4] = {1, 2, 3, 4}, x[2] = {0, 1}, e[2] = {1, 1};
  long s2[2] = {2, 2}, s1[1] = {2};
  assert_int_equal(npg_full_set(f, "a", 2, s2, a, "a"), 0);
  assert_int_equal(npg_full_set(f, "x", 1, s1, x, "x"), 0);
  assert_int_equal(npg_full_set(f, "e", 1, s1, e, "e"), 0);
  assert_int_equal(npg_full_eval(f, 5), -1);
  /* where the infinity arises: the stage the compiler introduced for the
   * division in the operator's entries (1 / x[i], elementwise), then the solve it breaks */
  assert_string_equal(npg_full_error(f),
                      "sample 5: stage 'M.t1' is not finite: M.t1[0] is an infinity (a division by zero: x[0] is 0, "
                      "and M.t1 divides by it); then stage 'y': operator M is not finite (row 0, column "
                      "0 is inf): the sample makes it undefined (a division by zero or a root of a negative number in "
                      "its entries?)");
  npg_full_free(f);
  npg_free(p);
}

static void unbound_dim(void **state) {
  (void)state;
  NpgProgram *p = compile_text("u.npg", "dim N\ninput x : real[N]\noutput y[i:N] = x[i] * x[i]\n");
  ir_ok(p);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  assert_int_equal(npg_full_eval(f, 0), -1);
  assert_string_equal(npg_full_error(f), "dim N is not bound: no param or input over it was given");
  npg_full_free(f);
  npg_free(p);
}

/* A dim bound by one source and then given another size by the same source (a caller naming every value of
 * an input alike): the message says which binding came first, not "9 in 'mu' but 8 in 'mu'" (issue 38). */
static void dim_rebound_by_same_source(void **state) {
  (void)state;
  NpgProgram *p = compile_text("u.npg", "dim B\ninput mu : real[B]\noutput y[i:B] = mu[i] * mu[i]\n");
  ir_ok(p);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  double mu[9] = {1, 2, 3, 4, 5, 6, 7, 8, 9};
  long s9[1] = {9}, s8[1] = {8};
  assert_int_equal(npg_full_set(f, "mu", 1, s9, mu, "argument 'mu'"), 0);
  assert_int_equal(npg_full_eval(f, 0), 0);
  assert_int_equal(npg_full_set(f, "mu", 1, s8, mu, "argument 'mu'"), -1);
  assert_string_equal(npg_full_error(f), "dim B is 8 in argument 'mu' but was bound to 9 by an earlier value of it: a "
                                         "dim keeps the size it was first bound to (give every value over it that size)");
  npg_full_free(f);
  npg_free(p);
}

static int setup(void **state) {
  (void)state;
  snprintf(dir, sizeof dir, "/tmp/npg-bind-XXXXXX");
  return mkdtemp(dir) ? 0 : -1;
}

static int teardown(void **state) {
  (void)state;
  rm("tri");
  rm("rho");
  rmdir(dir);
  return 0;
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(missing_file),         cmocka_unit_test(wrong_dtype),
      cmocka_unit_test(dim_mismatch_names_both_files), cmocka_unit_test(static_axis_mismatch),
      cmocka_unit_test(wrong_rank),           cmocka_unit_test(nan_in_param),
      cmocka_unit_test(gather_out_of_range),  cmocka_unit_test(gather_out_of_range_located),
      cmocka_unit_test(nan_in_input),         cmocka_unit_test(zero_area_triangle),
      cmocka_unit_test(singular_and_indefinite), cmocka_unit_test(operator_not_finite),
      cmocka_unit_test(unbound_dim),          cmocka_unit_test(dim_rebound_by_same_source),
      cmocka_unit_test(int_param_out_of_range),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
