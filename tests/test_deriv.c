/* test_deriv.c — derivatives of the full evaluator (DESIGN §17, npg_full_jvp /
 * npg_full_vjp / npg_full_jacobian): for every example and test program, random data,
 * every stage against every input:
 *   - the forward product J w equals central finite differences of the evaluator, and
 *     their error shrinks like h² (a quarter, within [2.5, 6.5], when halving h), or is
 *     at rounding for both steps (a stage linear or quadratic in that input);
 *   - forward and reverse agree: <v, J w> = <J^T v, w> to 1e-12 relative;
 *   - the Jacobian's columns are forward products and its rows reverse products.
 * Inverse and root stages are among the stages: each is checked against the finite
 * difference of the exact stage the evaluator computes. A program with an extern is
 * refused with a message naming it (a black box has no derivative). The libtcc and cc
 * backends agree on an inverse and a root stage. */
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "emit.h"
#include "full.h"
#include "randdata.h"
#include "support/failing_alloc.h"
#include "support/refeval.h"
#include "testutil.h"

static void set_one(void *user, const Sym *s, int ndim, const long *shape, const double *values) {
  NpgFull *f = user;
  if (npg_full_set(f, s->name, ndim, shape, values, s->name) != 0) fail_msg("%s", npg_full_error(f));
}

static double dot(const double *a, const double *b, size_t n) {
  double s = 0;
  for (size_t i = 0; i < n; i++) s += a[i] * b[i];
  return s;
}

static double max_abs(const double *a, size_t n) {
  double m = 0;
  for (size_t i = 0; i < n; i++) m = fmax(m, fabs(a[i]));
  return m;
}

typedef struct Pair {
  NpgFull *f;
  RefData *d;
  const Sym *in, *out;
  size_t nin, nout;
  double *x, *w;   /* the input's value, a direction */
} Pair;

/* (out(x + h w) - out(x - h w)) / 2h into fd. */
static int central(Pair *p, double h, double *fd) {
  long shape[MAX_AXES + MAX_STATIC];
  int nd = 0;
  for (int i = 0; i < p->in->ndims; i++) shape[nd++] = ref_dim(p->d, p->in->dims[i]);
  for (int i = 0; i < p->in->nstatic; i++) shape[nd++] = p->in->shape[i];
  double *xs = malloc(sizeof(double) * p->nin);
  for (int side = 0; side < 2; side++) {
    for (size_t i = 0; i < p->nin; i++) xs[i] = p->x[i] + (side ? -h : h) * p->w[i];
    if (npg_full_set(p->f, p->in->name, nd, shape, xs, "fd") != 0 || npg_full_eval(p->f, 0) != 0) {
      free(xs);
      return -1;
    }
    const double *y = npg_full_get(p->f, p->out->name, NULL);
    for (size_t i = 0; i < p->nout; i++) fd[i] = side ? (fd[i] - y[i]) / (2 * h) : y[i];
  }
  int rc = npg_full_set(p->f, p->in->name, nd, shape, p->x, "x");
  free(xs);
  return rc;
}

/* Data and directions are O(1) (inputs in [0.5, 1.5], directions in [-1, 1]): a
 * difference below this is the rounding of terms that cancel (a derivative that is zero
 * in exact arithmetic, as d(c_i - c_i) in the canonical form of a dot product), not a
 * disagreement. */
#define ROUNDING 1e-14

typedef struct Tally {
  int pairs, quadratic_order, exact, sparse;
  double worst_adjoint;
} Tally;

/* One stage against one input: 0 when every check holds. */
static int check_pair(Pair *p, const char *path, unsigned *seed, Tally *t) {
  double *jw = calloc(p->nout + 1, sizeof(double)), *v = calloc(p->nout + 1, sizeof(double));
  double *jtv = calloc(p->nin + 1, sizeof(double));
  double *fd2 = calloc(p->nout + 1, sizeof(double)), *jac = calloc(p->nout * p->nin + 1, sizeof(double));
  int failures = 0;
  for (size_t i = 0; i < p->nout; i++) v[i] = randdata_uniform(seed, -1, 1);
  const double *w = p->w;
  if (npg_full_jvp(p->f, 0, 1, &p->in->name, &w, p->out->name, jw) != 0 ||
      npg_full_vjp(p->f, 0, 1, &p->out->name, (const double *const *)&v, p->in->name, jtv) != 0 ||
      npg_full_jacobian(p->f, 0, p->out->name, p->in->name, jac) != 0) {
    print_message("%s: %s by %s: %s\n", path, p->out->name, p->in->name, npg_full_error(p->f));
    failures++;
    goto done;
  }
  /* forward against reverse, relative to the sums' magnitude (they may cancel) */
  double a = dot(v, jw, p->nout), b = dot(jtv, p->w, p->nin), mag = 0;
  for (size_t i = 0; i < p->nout; i++) mag += fabs(v[i] * jw[i]);
  for (size_t i = 0; i < p->nin; i++) mag += fabs(jtv[i] * p->w[i]);
  double adj = fabs(a - b) / fmax(mag, 1e-300);
  if (fabs(a - b) > ROUNDING) t->worst_adjoint = fmax(t->worst_adjoint, adj);
  if (adj > 1e-12 && fabs(a - b) > ROUNDING) {
    print_message("%s: %s by %s: <v, J w> = %.17g but <J^T v, w> = %.17g\n", path, p->out->name, p->in->name, a, b);
    failures++;
  }
  /* the Jacobian: J w and J^T v again */
  double ej = 0, jmax = max_abs(jac, p->nout * p->nin);
  for (size_t r = 0; r < p->nout; r++) ej = fmax(ej, fabs(dot(jac + r * p->nin, p->w, p->nin) - jw[r]));
  for (size_t c = 0; c < p->nin; c++) {
    double s = 0;
    for (size_t r = 0; r < p->nout; r++) s += jac[r * p->nin + c] * v[r];
    ej = fmax(ej, fabs(s - jtv[c]));
  }
  if (ej > fmax(1e-12 * jmax * (double)(p->nin + p->nout), ROUNDING)) {
    print_message("%s: %s by %s: the Jacobian disagrees with the products by %.3g\n", path, p->out->name,
                  p->in->name, ej);
    failures++;
  }
  /* the Jacobian on its structural pattern, by colored forward products: the dense one */
  NpgCsr csr;
  if (npg_full_jacobian_csr(p->f, 0, p->out->name, p->in->name, &csr) != 0) {
    print_message("%s: %s by %s: %s\n", path, p->out->name, p->in->name, npg_full_error(p->f));
    failures++;
    goto done;
  }
  double *dense = calloc(p->nout * p->nin + 1, sizeof(double)), ec = 0;
  for (long r = 0; r < csr.rows; r++)
    for (long k = csr.indptr[r]; k < csr.indptr[r + 1]; k++) dense[r * csr.cols + csr.indices[k]] = csr.data[k];
  for (size_t k = 0; k < p->nout * p->nin; k++) ec = fmax(ec, fabs(dense[k] - jac[k]));
  if ((size_t)csr.rows != p->nout || (size_t)csr.cols != p->nin || ec > fmax(1e-12 * jmax, ROUNDING)) {
    print_message("%s: %s by %s: the CSR Jacobian (%ld x %ld, %ld entries) differs from the dense one by %.3g\n", path,
                  p->out->name, p->in->name, csr.rows, csr.cols, csr.nnz, ec);
    failures++;
  }
  if ((size_t)csr.nnz < p->nout * p->nin / 4) t->sparse++;
  free(dense);
  npg_csr_free(&csr);
  /* central differences at halving steps until two consecutive errors show the
   * h² term (a ratio near 4), or both are at rounding (linear or quadratic) */
  double h = 1e-2, e1 = -1, e2 = -1, ref = max_abs(jw, p->nout), ratio = 0;
  double tiny = fmax(1e-9 * fmax(ref, jmax), ROUNDING);
  bool ok = false, exact = false;
  for (int k = 0; k < 6 && !ok; k++, h /= 2) {
    if (central(p, h, fd2) != 0) {
      print_message("%s: %s by %s: finite differences: %s\n", path, p->out->name, p->in->name, npg_full_error(p->f));
      failures++;
      goto done;
    }
    e1 = e2;
    e2 = 0;
    for (size_t i = 0; i < p->nout; i++) e2 = fmax(e2, fabs(fd2[i] - jw[i]));
    if (e1 < 0) continue;
    ratio = e2 > 0 ? e1 / e2 : INFINITY;
    exact = e1 <= tiny && e2 <= tiny;
    ok = exact || (ratio >= 3.0 && ratio <= 5.3 && e2 <= 1e-2 * ref);
  }
  if (exact) t->exact++;
  else if (ok) t->quadratic_order++;
  else {
    print_message("%s: %s by %s: J w differs from central differences by %.3g (h = %g) and %.3g (h = %g), "
                  "a ratio of %.3g, not the h^2 term's 4 (|J w| = %.3g)\n",
                  path, p->out->name, p->in->name, e1, 4 * h, e2, 2 * h, ratio, ref);
    failures++;
  }
  t->pairs++;
done:
  free(jw), free(v), free(jtv), free(fd2), free(jac);
  return failures;
}

static int check_program(NpgProgram *p, const char *path, void *arg) {
  Tally *total = arg, t = {0};
  Program *prog = program_ir(p);
  NpgFull *f = npg_full_new(p, NPG_AUTO);
  long n = 5;
  RefData *d = ref_new(prog, n);
  bind_random(d, prog, n, 4321u, false, set_one, f);
  int failures = 0;
  if (prog->externs.n) { /* refused, naming the extern */
    double out[1];
    const char *in = ((Sym *)prog->inputs.v[0])->name, *o = ((Stage *)prog->stages.v[prog->stages.n - 1])->sym->name;
    int rc = npg_full_jacobian(f, 0, o, in, out);
    const char *msg = npg_full_error(f);
    if (rc == 0 || !strstr(msg, ((Sym *)prog->externs.v[0])->name) || !strstr(msg, "no derivative")) {
      print_message("%s: a program with an extern is not refused clearly: %s\n", path, msg);
      failures++;
    } else print_message("%-44s skipped: %s", path, msg);
    ref_free(d);
    npg_full_free(f);
    return failures;
  }
  if (npg_full_eval(f, 0) != 0) {
    print_message("%s: %s\n", path, npg_full_error(f));
    failures++;
  }
  unsigned seed = 77u;
  for (int i = 0; i < prog->inputs.n && !failures; i++) {
    const Sym *in = prog->inputs.v[i];
    size_t nin = 0;
    const double *x0 = npg_full_get(f, in->name, &nin);
    Pair pr = {f, d, in, NULL, nin, 0, malloc(sizeof(double) * (nin + 1)), malloc(sizeof(double) * (nin + 1))};
    memcpy(pr.x, x0, sizeof(double) * nin);
    for (size_t k = 0; k < nin; k++) pr.w[k] = randdata_uniform(&seed, -1, 1);
    for (int s = 0; s < prog->stages.n; s++) {
      const Stage *st = prog->stages.v[s];
      if (st->kind == ST_INPUT) continue;
      pr.out = st->sym;
      npg_full_get(f, st->sym->name, &pr.nout);
      failures += check_pair(&pr, path, &seed, &t);
    }
    free(pr.x);
    free(pr.w);
  }
  print_message("%-44s %3d stage-input pairs: %d second order, %d exact to rounding; <v,Jw> vs <J^T v,w> %.1e\n",
                path, t.pairs, t.quadratic_order, t.exact, t.worst_adjoint);
  total->pairs += t.pairs;
  total->quadratic_order += t.quadratic_order;
  total->exact += t.exact;
  total->sparse += t.sparse;
  ref_free(d);
  npg_full_free(f);
  return failures;
}

/* Programs whose operators read inputs, so the derivative of an inverse and of a root
 * go through dM (the corpus's operators read params): M symmetric positive definite
 * (diagonally dominant for data in [0.5, 1.5] and params in [0.1, 0.3]), K not symmetric. */
static const char *const operator_programs[][2] = {
    {"root_of_input_op.npg",
     "dim N\nparam a : real[N, N]\ninput x : real[N]\ninput u : real[N]\n"
     "op M[i:N, j:N] = a[i, j] + a[j, i] + delta(i, j) * (2 + x[i] * x[i])\n"
     "output y = root(M, 2) * u\noutput z = root(M, 3) * (root(M, 3) * u)\n"},
    {"solve_input_op.npg",
     "dim N\nparam a : real[N, N]\ninput x : real[N]\ninput u : real[N]\n"
     "op K[i:N, j:N] = delta(i, j) * (3 + x[i]) + a[i, j] * x[j]\n"
     "s[i:N] = u[i] * x[i]\noutput b = solve(K, s)\noutput c = solve(K, solve(K, u))\n"},
    {"two_ops_in_a_term.npg", /* K^-1 M^(1/2) u and K^-1 M u: one term, two operators */
     "dim N\nparam a : real[N, N]\ninput x : real[N]\ninput u : real[N]\n"
     "op M[i:N, j:N] = a[i, j] + a[j, i] + delta(i, j) * (2 + x[i] * x[i])\n"
     "op K[i:N, j:N] = delta(i, j) * (3 + x[i]) + a[i, j] * x[j]\n"
     "output z = solve(K, root(M, 2) * u)\noutput w = solve(K, M * u)\n"},
};

static void corpus_derivatives(void **state) {
  (void)state;
  Tally t = {0};
  const char *const dirs[] = {"examples/rational", "examples/radiosity", "examples/fluids", "examples/heat",
                              "examples/burgers", "examples/embed", "tests/programs", NULL};
  int n = 0, failures = check_programs(dirs, check_program, &t, &n);
  for (size_t k = 0; k < sizeof operator_programs / sizeof operator_programs[0]; k++) {
    NpgProgram *p = compile_text(operator_programs[k][0], operator_programs[k][1]);
    ir_ok(p);
    failures += check_program(p, operator_programs[k][0], &t);
    npg_free(p);
  }
  assert_true(n >= 20);
  assert_int_equal(failures, 0);
  assert_true(t.quadratic_order >= 20); /* the order check ran, not only the rounding one */
  assert_true(t.sparse >= 10);          /* and the CSR one on Jacobians under a quarter full */
  print_message("%d stage-input pairs, %d of them with a Jacobian under a quarter full\n", t.pairs, t.sparse);
}

/* The checks can fail: a direction scaled after the fact is caught by both. */
static void detects_a_wrong_derivative(void **state) {
  (void)state;
  NpgProgram *p = compile_file("tests/programs/solve_stage.npg");
  Program *prog = ir_ok(p);
  NpgFull *f = npg_full_new(p, NPG_AUTO);
  RefData *d = ref_new(prog, 4);
  bind_random(d, prog, 4, 5u, false, set_one, f);
  const Sym *x = find_quantity(prog, "x"), *b = find_quantity(prog, "b");
  size_t nx = 0, nb = 0;
  assert_int_equal(npg_full_eval(f, 0), 0);
  const double *x0 = npg_full_get(f, "x", &nx);
  npg_full_get(f, "b", &nb);
  Pair pr = {f, d, x, b, nx, nb, malloc(sizeof(double) * nx), malloc(sizeof(double) * nx)};
  memcpy(pr.x, x0, sizeof(double) * nx);
  unsigned seed = 3u;
  for (size_t k = 0; k < nx; k++) pr.w[k] = randdata_uniform(&seed, -1, 1);
  double *jw = malloc(sizeof(double) * nb), *fd = malloc(sizeof(double) * nb);
  const double *w = pr.w;
  assert_int_equal(npg_full_jvp(f, 0, 1, &x->name, &w, "b", jw), 0);
  assert_int_equal(central(&pr, 1e-3, fd), 0);
  double e = 0, ref = max_abs(jw, nb);
  for (size_t i = 0; i < nb; i++) e = fmax(e, fabs(fd[i] - jw[i]));
  assert_true(ref > 1e-3);
  assert_true(e < 1e-4 * ref);
  for (size_t i = 0; i < nb; i++) jw[i] *= 1.001;
  e = 0;
  for (size_t i = 0; i < nb; i++) e = fmax(e, fabs(fd[i] - jw[i]));
  assert_true(e > 1e-4 * ref);
  free(jw), free(fd), free(pr.x), free(pr.w);
  ref_free(d);
  npg_full_free(f);
  npg_free(p);
}

/* libtcc and cc: the same products on an inverse and a root stage. */
static void backends_agree(void **state) {
  (void)state;
  const char *progs[] = {"tests/programs/solve_stage.npg", "tests/programs/root_of_op.npg"};
  for (int k = 0; k < 2; k++) {
    NpgProgram *p = compile_file(progs[k]);
    Program *prog = ir_ok(p);
    NpgFull *fs[2] = {npg_full_new(p, NPG_TCC), npg_full_new(p, NPG_CC)};
    const Sym *in = prog->inputs.v[0], *out = prog->outputs.v[0];
    double *jac[2] = {NULL, NULL};
    size_t nin = 0, nout = 0;
    for (int b = 0; b < 2; b++) {
      RefData *d = ref_new(prog, 5);
      bind_random(d, prog, 5, 11u, false, set_one, fs[b]);
      ref_free(d);
      assert_int_equal(npg_full_eval(fs[b], 0), 0);
      npg_full_get(fs[b], in->name, &nin);
      npg_full_get(fs[b], out->name, &nout);
      jac[b] = malloc(sizeof(double) * nin * nout);
      if (npg_full_jacobian(fs[b], 0, out->name, in->name, jac[b]) != 0) fail_msg("%s: %s", progs[k], npg_full_error(fs[b]));
    }
    assert_true(max_abs(jac[0], nin * nout) > 0);
    assert_true(rel_diff(jac[0], jac[1], nin * nout) < 1e-12);
    free(jac[0]), free(jac[1]);
    npg_full_free(fs[0]);
    npg_full_free(fs[1]);
    npg_free(p);
  }
}

/* The Jacobian of `out` by `in` through the internal evaluator, by columns of forward
 * products, and one reverse product of cotangent v (into vjp, in's count). */
static double *internal_jacobian(Full *f, const Program *prog, const Sym *out, const Sym *in, const double *v,
                                 double *vjp, size_t *nout, size_t *nin) {
  int ko = vec_position(&prog->slots, out), ki = vec_position(&prog->slots, in);
  full_get(f, out->name, nout);
  full_get(f, in->name, nin);
  double *J = malloc(sizeof(double) * (*nout * *nin + 1));
  for (size_t k = 0; k < *nin; k++) {
    double *const *d = full_deriv_arrays(f);
    assert_non_null(d);
    d[ki][k] = 1;
    if (full_jvp(f, 0) != 0) fail_msg("%s", full_error(f));
    for (size_t r = 0; r < *nout; r++) J[r * *nin + k] = d[ko][r];
  }
  double *const *d = full_deriv_arrays(f);
  memcpy(d[ko], v, sizeof(double) * *nout);
  if (full_vjp(f, 0) != 0) fail_msg("%s", full_error(f));
  memcpy(vjp, d[ki], sizeof(double) * *nin);
  return J;
}

static void set_internal(void *user, const Sym *s, int ndim, const long *shape, const double *values) {
  Full **fs = user;
  for (int k = 0; k < 2; k++)
    if ((s->kind == SYM_PARAM ? full_set_param(fs[k], s->name, ndim, shape, values, s->name)
                              : full_set(fs[k], s->name, ndim, shape, values, s->name)) != 0)
      fail_msg("%s", full_error(fs[k]));
}

/* Sparse operators at 20 rows: the derivatives on the pattern (CHOLMOD or UMFPACK, one
 * factorization per operator for the tangent's or the transposed solves) equal the
 * densified ones (checked against finite differences above) to 1e-12, and the reverse
 * product is the Jacobian's transpose. */
static int sparse_program(NpgProgram *p, const char *path, void *arg) {
  int *checked = arg;
  Program *prog = program_ir(p);
  bool sparse = false;
  for (int i = 0; i < prog->opdefs.n; i++) sparse |= ((OpDef *)prog->opdefs.v[i])->sparse;
  if (!sparse || prog->externs.n) return 0;
  Full *fs[2] = {full_new(prog, JIT_TCC, NULL), full_new(prog, JIT_TCC, NULL)};
  full_set_sparse_min_rows(fs[0], 0);
  full_set_sparse_min_rows(fs[1], LONG_MAX);
  RefData *rd = ref_new(prog, 20);
  bind_random(rd, prog, 20, 9u, false, set_internal, fs);
  ref_free(rd);
  int failures = 0;
  for (int k = 0; k < 2; k++)
    if (full_eval(fs[k], 0) != 0) fail_msg("%s: %s", path, full_error(fs[k]));
  unsigned seed = 5u;
  for (int i = 0; i < prog->inputs.n; i++)
    for (int st = 0; st < prog->stages.n; st++) {
      const Sym *in = prog->inputs.v[i], *out = ((Stage *)prog->stages.v[st])->sym;
      if (((Stage *)prog->stages.v[st])->kind == ST_INPUT) continue;
      size_t nout = 0, nin = 0;
      full_get(fs[0], out->name, &nout);
      full_get(fs[0], in->name, &nin);
      double *v = malloc(sizeof(double) * (nout + 1)), *vj[2];
      for (size_t r = 0; r < nout; r++) v[r] = randdata_uniform(&seed, -1, 1);
      double *J[2];
      for (int k = 0; k < 2; k++) {
        vj[k] = malloc(sizeof(double) * (nin + 1));
        J[k] = internal_jacobian(fs[k], prog, out, in, v, vj[k], &nout, &nin);
      }
      double scale = fmax(max_abs(J[1], nout * nin), 1e-300), e = 0, t = 0;
      for (size_t r = 0; r < nout * nin; r++) e = fmax(e, fabs(J[0][r] - J[1][r]));
      for (size_t c = 0; c < nin; c++) {
        double s = 0;
        for (size_t r = 0; r < nout; r++) s += J[0][r * nin + c] * v[r];
        t = fmax(t, fabs(s - vj[0][c]));
      }
      if (e > 1e-12 * scale + ROUNDING || t > 1e-12 * scale * (double)nout + ROUNDING) {
        print_message("%s: %s by %s: sparse Jacobian differs from the dense one by %.3g, its transpose from the "
                      "reverse product by %.3g (scale %.3g)\n", path, out->name, in->name, e, t, scale);
        failures++;
      }
      (*checked)++;
      for (int k = 0; k < 2; k++) free(J[k]), free(vj[k]);
      free(v);
    }
  long patterns, chol, lu;
  full_sparse_counts(fs[0], &patterns, &chol, &lu);
  print_message("%-44s sparse path: %ld patterns, %ld Cholesky and %ld LU factorizations\n", path, patterns, chol, lu);
  if (patterns == 0) failures++;
  full_free(fs[0]);
  full_free(fs[1]);
  return failures;
}

static void sparse_operators(void **state) {
  (void)state;
  int checked = 0, n = 0;
  const char *const dirs[] = {"examples/heat", "examples/burgers", "tests/programs", NULL};
  int failures = check_programs(dirs, sparse_program, &checked, &n);
  assert_int_equal(failures, 0);
  assert_true(checked >= 4);
}

/* Every allocation that fails during a Jacobian (the derivative arrays, the runtime's and
 * the generated code's scratch, a dense LU and a sparse factorization) is reported as "out
 * of memory", never a crash or a leak; then the Jacobian is the one computed without
 * failures. */
static void allocation_failure(void **state) {
  (void)state;
  NpgProgram *ps[2] = {compile_file("tests/programs/heat_neighbours.npg"), compile_text(operator_programs[1][0], operator_programs[1][1])};
  for (int k = 0; k < 2; k++) {
    Program *prog = ir_ok(ps[k]);
    NpgFull *f = npg_full_new(ps[k], NPG_AUTO);
    RefData *d = ref_new(prog, 20);
    bind_random(d, prog, 20, 8u, false, set_one, f);
    ref_free(d);
    const char *in = ((Sym *)prog->inputs.v[0])->name, *out = ((Sym *)prog->outputs.v[0])->name;
    assert_int_equal(npg_full_eval(f, 0), 0);
    size_t nin = 0, nout = 0;
    npg_full_get(f, in, &nin);
    npg_full_get(f, out, &nout);
    double *want = malloc(sizeof(double) * nin * nout), *got = malloc(sizeof(double) * nin * nout);
    if (npg_full_jacobian(f, 0, out, in, want) != 0) fail_msg("%s", npg_full_error(f));
    int failed = 0;
    for (long after = 0; after < 100000; after++) {
      failing_alloc_after(after);
      int rc = npg_full_jacobian(f, 0, out, in, got);
      failing_alloc_off();
      if (rc == 0) break;
      if (!strstr(npg_full_error(f), "out of memory")) fail_msg("allocation %ld failing: %s", after, npg_full_error(f));
      npg_full_clear_error(f);
      failed++;
    }
    assert_true(failed > 3);
    assert_memory_equal(want, got, sizeof(double) * nin * nout);
    free(want), free(got);
    npg_full_free(f);
    npg_free(ps[k]);
  }
}

/* Stages whose derivatives are built on the evaluator's value graph (emit_ddirect.c), one
 * rule each: a gather guarded by a choice (its cotangent added only where the guard holds),
 * a division infinite in the branch not taken (nothing sent from it there), a rational
 * power, a square root, a sum of vectors over a whole dim (reversed as a loop more), entries
 * gathered by several rows (their cotangents added up). Each is checked as the corpus is,
 * and its derivative code must come from the graph (no canonical term, no entry-by-entry
 * cotangent). */
static const char *const graph_programs[][2] = {
    {"graph_guarded_gather.npg",
     "dim N, E\nparam ends : int[E, 2]\nparam k : real[E]\ninput s : real[N]\n"
     "output g[j:E] = if(ends[j, 1] >= 1, k[j] * (s[ends[j, 0]] - s[ends[j, 1]])^2, (s[ends[j, 0]]^2 + 1)^(2/3))\n"},
    {"graph_division_branch.npg",
     "use geometry\ndim N\ninput x : real[N, 3]\ninput s : real[N]\n"
     "f[i:N, j:N] = if(i == j, 1, s[j] / dist2(x[i], x[j]))\n"
     "r[i:N, j:N] = sqrt(f[i, j] * f[i, j] + 1)\n"
     "output a[i:N] = sum(j = 0..N-1, (x[j] - x[i]) * r[i, j] * s[j])\n"},
    {"graph_shared_entries.npg",
     "dim N, C\nparam tri : int[C, 3]\ninput g : real[N, 2]\n"
     "output area[c:C] = (g[tri[c, 1], 0] - g[tri[c, 0], 0]) * (g[tri[c, 2], 1] - g[tri[c, 0], 1]) / "
     "(1 + g[tri[c, 2], 0] * g[tri[c, 2], 0])\n"},
};

static void graph_derivatives(void **state) {
  (void)state;
  Tally t = {0};
  int failures = 0;
  for (size_t k = 0; k < sizeof graph_programs / sizeof graph_programs[0]; k++) {
    NpgProgram *p = compile_text(graph_programs[k][0], graph_programs[k][1]);
    ir_ok(p);
    Program *prog = program_ir(p);
    char *text = NULL;
    size_t len = 0;
    FILE *out = open_memstream(&text, &len);
    emit_deriv(prog->ctx, prog, out);
    fclose(out);
    if (strstr(text, "/* term ") || strstr(text, "yb0_")) fail_msg("%s: a derivative from the canonical form", graph_programs[k][0]);
    free(text);
    failures += check_program(p, graph_programs[k][0], &t);
    npg_free(p);
  }
  assert_int_equal(failures, 0);
  assert_true(t.quadratic_order >= 4);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(corpus_derivatives),
      cmocka_unit_test(graph_derivatives),
      cmocka_unit_test(sparse_operators),
      cmocka_unit_test(allocation_failure),
      cmocka_unit_test(detects_a_wrong_derivative),
      cmocka_unit_test(backends_agree),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
