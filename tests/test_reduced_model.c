/* test_reduced_model.c — the reduced model and its evaluator
 * (backends/model/reduced.c; DESIGN §4, §5; paper §4, §7.1):
 *
 *   - full-rank bases, centered and uncentered, reproduce the full evaluator
 *     (1e-10) on every example and test program, on held-out random samples;
 *   - every reduced stage equals the formulas of paper §4 computed densely
 *     ((BᵀM(x̃)B)^r Bᵀq(x̃) with LAPACK) to 1e-12, with truncated bases;
 *   - a root of a given operator U diag(λ) Uᵀ equals U diag(λ^(p/q)) Uᵀ to
 *     1e-12 for spectra that are spread, clustered or scalar, diagonal or
 *     not, scaled near overflow or underflow; it fails naming an indefinite
 *     operator, a singular one under a negative power, and one not finite;
 *   - a corrupted, truncated or mismatched model is refused naming the file;
 *   - the reduced Jacobian from the operators, factors and local Jacobians an evaluation kept
 *     equals the one recomputing them (1e-12), and a coordinate changed since voids them;
 *   - a stage's local partial by reverse directions (reduced_stage_vjp) is the forward one
 *     (reduced_stage_jvp) transposed (1e-12), an interpolated stage's too.
 */
#include <cblas.h>
#include <lapacke.h>
#include <unistd.h>

#include "emit.h"
#include "memsamples.h"
#include "randdata.h"
#include "reduced.h"
#include "train.h"
#include "support/refeval.h"
#include "testutil.h"
#include "trained.h"

/* ---------------------------------------------------------------- random samples in memory */

static long largest_class(const Program *prog, long n) {
  long best = 1, shape[MAX_AXES + MAX_STATIC];
  for (int i = 0; i < prog->quantities.n; i++) {
    size_t c = memsamples_count(prog->quantities.v[i], n, shape);
    best = (long)c > best ? (long)c : best;
  }
  return best;
}

/* ---------------------------------------------------------------- full rank */

/* Full-rank bases, centered or not, reproduce the full evaluator (1e-10). */
static int full_rank_check(const char *path, double *worst, bool uncentered) {
  NpgProgram *p = compile_file(path);
  Program *prog = ir_ok(p);
  const long n = 4; /* 3 vertices cannot make 3 distinct triangles */
  long S = largest_class(prog, n) + 4;
  if (S > 400) print_message("%s: largest class %ld entries\n", path, S - 4);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  MemSamples train;
  if (memsamples_fill(&train, prog, f, n, S, 11u)) fail_msg("binding random params failed");
  SampleSource src = {S, &train, memsamples_set, NULL, NULL};
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = 1 << 20;
  opt_user.energy = 1.0;
  opt.full_rank = true;
  opt_user.uncentered = uncentered;
  char err[2048] = "";
  Model *m = train_model(prog, f, &src, &opt, ERR_OF(err, sizeof err));
  if (!m) fail_msg("%s: training: %s", path, err);
  for (int c = 0; c < m->nclasses; c++) assert_int_equal(m->classes[c].m, m->classes[c].n);
  Reduced *r = reduced_new(m, ERR_OF(err, sizeof err));
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
      randdata_fill(&(RandData){.prog = prog, .n = n, .seed = &seed}, held.sym[i], held.val[i] + (size_t)j * held.count[i], held.count[i]);
  }
  held.S = 3;
  int failures = 0;
  for (long k = 0; k < 3; k++) {
    if (memsamples_set(&held, f, k) || full_eval(f, k)) fail_msg("%s: %s", path, full_error(f));
    for (int i = 0; i < held.n; i++) reduced_project(r, vec_position(&prog->quantities, held.sym[i]), held.val[i] + (size_t)k * held.count[i]);
    if (reduced_eval(r, k)) fail_msg("%s: %s", path, reduced_error(r));
    for (int q = 0; q < m->nq; q++) {
      const Sym *s = prog->quantities.v[q];
      size_t cnt;
      const double *full = full_get(f, s->name, &cnt);
      double *y = malloc(sizeof(double) * cnt);
      reduced_lift(r, q, y);
      double d = rel_diff(full, y, cnt);
      *worst = fmax(*worst, d);
      if (!(d <= 1e-10)) {
        print_message("%s: %s: full-rank reduced (%s) differs from full by %.3g\n", path, s->name,
                      uncentered ? "uncentered" : "centered", d);
        failures++;
      }
      free(y);
    }
  }
  memsamples_free(&held);
  memsamples_free(&train);
  reduced_free(r);
  model_free(m);
  full_free(f);
  npg_free(p);
  return failures;
}

static int full_rank_program(const char *path, void *worstp) {
  return full_rank_check(path, worstp, false) + full_rank_check(path, worstp, true);
}

static void full_rank_reproduces_full(void **state) {
  (void)state;
  const char *dirs[] = {"examples/rational", "examples/radiosity", "examples/fluids", "tests/programs"};
  int n = 0, failures = 0;
  double worst = 0;
  for (size_t i = 0; i < sizeof dirs / sizeof *dirs; i++) failures += for_each_program(dirs[i], full_rank_program, &worst, &n);
  print_message("%d programs: full-rank reduced (centered and uncentered bases) vs full evaluator, worst relative "
                "difference %.2g\n", n, worst);
  assert_int_equal(failures, 0);
}

/* ---------------------------------------------------------------- reduced stages vs paper §4 densely */

typedef struct FieldAt {
  double *out;
  long ncols;
  const double *x[RT_MAX_IN];
} FieldAt;

static int field_at_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  FieldAt *fa = user;
  double v = coef;
  for (int l = 0; l < nin; l++) v *= fa->x[l][in[l]];
  fa->out[fa->ncols ? row * fa->ncols + col : row] += v;
  return 0;
}

/* Σ over tensors ts of their field at the lifted values xt[q]. */
static void field_at(const Model *m, Full *f, const RTensor *ts, int nt, double *const *xt, double *out, long ncols) {
  FieldAt fa = {out, ncols, {0}};
  for (int g = 0; g < nt; g++) {
    int pos = 0;
    for (int j = 0; j < ts[g].nin; j++)
      for (int l = 0; l < ts[g].in_mult[j]; l++) fa.x[pos++] = xt[ts[g].in_q[j]];
    NpgSink sink = {&fa, field_at_entry, 0, 1, 0, 0}; /* every row */
    if (full_build(f, ts[g].builder, &sink)) fail_msg("%s", full_error(f));
  }
  (void)m;
}

static int stages_program(const char *path, void *arg) {
  double *worst = arg;
  Trained tr;
  train_small(&tr, path, 3, 4);
  Model *m = tr.m;
  Program *prog = tr.prog;
  char err[1024];
  Reduced *r = reduced_new(m, ERR_OF(err, sizeof err));
  RefData *rd = ref_new(prog, 4);
  int failures = 0;
  /* coordinates: the projections of a training sample's values */
  if (memsamples_set(&tr.train, tr.f, 3) || full_eval(tr.f, 3)) fail_msg("%s", full_error(tr.f));
  double **xt = calloc((size_t)m->nq, sizeof(double *));
  for (int q = 0; q < m->nq; q++) {
    const RClass *c = &m->classes[m->qclass[q]];
    reduced_project(r, q, full_get(tr.f, ((Sym *)prog->quantities.v[q])->name, NULL));
    xt[q] = malloc(sizeof(double) * (size_t)c->n);
    reduced_lift(r, q, xt[q]);
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (rs->st->kind == ST_EXTERN) continue;
    const RClass *cy = &m->classes[m->qclass[rs->q]];
    long n = cy->n, my = cy->m;
    double *yhat = calloc((size_t)my, sizeof(double)), *v = malloc(sizeof(double) * (size_t)my);
    double *full = malloc(sizeof(double) * (size_t)(n * n)), *Mh = malloc(sizeof(double) * (size_t)(my * my));
    double *tmp = malloc(sizeof(double) * (size_t)(n * my));
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      /* Bᵀ q(x̃) */
      memset(full, 0, sizeof(double) * (size_t)n);
      if (rt->named_q >= 0) memcpy(full, xt[rt->named_q], sizeof(double) * (size_t)n);
      else field_at(m, tr.f, rt->num, rt->nnum, xt, full, 0);
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, (int)my, 1.0, cy->B, (int)my, full, 1, 0.0, v, 1);
      for (int k = 0; k < rt->nops; k++) {
        const ROp *ro = &rt->ops[k];
        memset(full, 0, sizeof(double) * (size_t)(n * n));
        if (ro->op->kind == OPK_DIAG) {
          double *dg = calloc((size_t)n, sizeof(double));
          field_at(m, tr.f, ro->t, ro->ntensors, xt, dg, 0);
          for (long e = 0; e < n; e++) full[e * n + e] = dg[e];
          free(dg);
        } else {
          field_at(m, tr.f, ro->t, ro->ntensors, xt, full, n);
        }
        /* M̂ = Bᵀ M B, then v <- M̂^(p/q) v by the reference's dense LAPACK */
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)my, (int)n, 1.0, full, (int)n, cy->B,
                    (int)my, 0.0, tmp, (int)my);
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)my, (int)my, (int)n, 1.0, cy->B, (int)my, tmp,
                    (int)my, 0.0, Mh, (int)my);
        if (!ref_apply_power(rd, Mh, (int)my, ro->op->p, ro->op->q, v)) fail_msg("%s: dense formula failed", path);
      }
      for (long a = 0; a < my; a++) yhat[a] += v[a];
    }
    if (reduced_eval_stage(r, i, 0)) fail_msg("%s: %s", path, reduced_error(r));
    double d = rel_diff(yhat, reduced_coords(r, rs->q), (size_t)my);
    *worst = fmax(*worst, d);
    if (!(d <= 1e-12)) {
      print_message("%s: stage %s: reduced differs from the dense formula by %.3g\n", path, rs->st->sym->name, d);
      failures++;
    }
    /* the next stages read this stage's reduced value: keep the projection */
    reduced_project(r, rs->q, full_get(tr.f, rs->st->sym->name, NULL));
    free(yhat), free(v), free(full), free(Mh), free(tmp);
  }
  for (int q = 0; q < m->nq; q++) free(xt[q]);
  free(xt);
  ref_free(rd);
  reduced_free(r);
  trained_free(&tr);
  return failures;
}

static void reduced_stages_equal_dense_formulas(void **state) {
  (void)state;
  const char *dirs[] = {"examples/rational", "examples/radiosity", "examples/fluids", "tests/programs"};
  int n = 0, failures = 0;
  double worst = 0;
  for (size_t i = 0; i < sizeof dirs / sizeof *dirs; i++) failures += for_each_program(dirs[i], stages_program, &worst, &n);
  print_message("%d programs: every reduced stage (contractions, inverses, roots) vs paper §4 densely, worst %.2g\n",
                n, worst);
  assert_int_equal(failures, 0);
}

/* ---------------------------------------------------------------- corrupted models */

static void corrupted_model_named(void **state) {
  (void)state;
  Trained tr;
  train_small(&tr, "examples/rational/rational.npg", 2, 4);
  char dir[] = "/tmp/npg_model_XXXXXX", path[1024], err[2048];
  assert_non_null(mkdtemp(dir));
  char model[600];
  snprintf(model, sizeof model, "%s/MODEL", dir);
  assert_int_equal(model_save(tr.m, model, ERR_OF(err, sizeof err)), 0);
  Model *ok = model_load(tr.prog, model, ERR_OF(err, sizeof err));
  if (!ok) fail_msg("%s", err);
  model_free(ok);
  /* a flipped byte */
  snprintf(path, sizeof path, "%s/t_y_t0_op1_g0.npy", model);
  FILE *f = fopen(path, "r+b");
  assert_non_null(f);
  fseek(f, 100, SEEK_SET);
  int c = fgetc(f);
  fseek(f, 100, SEEK_SET);
  fputc(c ^ 0x10, f);
  fclose(f);
  assert_null(model_load(tr.prog, model, ERR_OF(err, sizeof err)));
  assert_non_null(strstr(err, "t_y_t0_op1_g0.npy: checksum mismatch"));
  /* truncated */
  assert_int_equal(model_save(tr.m, model, ERR_OF(err, sizeof err)), 0);
  snprintf(path, sizeof path, "%s/basis_1.npy", model);
  assert_int_equal(truncate(path, 90), 0);
  assert_null(model_load(tr.prog, model, ERR_OF(err, sizeof err)));
  assert_non_null(strstr(err, "basis_1.npy"));
  /* missing */
  assert_int_equal(model_save(tr.m, model, ERR_OF(err, sizeof err)), 0);
  snprintf(path, sizeof path, "%s/t_y_t0_f0_g0.npy", model);
  assert_int_equal(remove(path), 0);
  assert_null(model_load(tr.prog, model, ERR_OF(err, sizeof err)));
  assert_non_null(strstr(err, "t_y_t0_f0_g0.npy"));
  /* another program */
  assert_int_equal(model_save(tr.m, model, ERR_OF(err, sizeof err)), 0);
  NpgProgram *other = compile_text("other.npg", "input x : real[2]\noutput y = [x[0] / x[1], x[1]]\n");
  assert_null(model_load(ir_ok(other), model, ERR_OF(err, sizeof err)));
  assert_non_null(strstr(err, "manifest: model was trained for another program"));
  npg_free(other);
  /* clean up */
  char cmd[700];
  snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
  assert_int_equal(system(cmd), 0);
  trained_free(&tr);
}

/* ---------------------------------------------------------------- roots of given operators */

/* Row-major n × n M = U diag(lam) Uᵀ, U orthogonal from the QR of a random
 * matrix, or the identity with `diagonal`. */
static void spectral_matrix(int n, const double *lam, bool diagonal, unsigned *seed, double *U, double *M) {
  double *tau = malloc(sizeof(double) * (size_t)n);
  for (int i = 0; i < n * n; i++) U[i] = diagonal ? i % (n + 1) == 0 : randdata_uniform(seed, -1, 1);
  if (!diagonal) {
    LAPACKE_dgeqrf(LAPACK_ROW_MAJOR, n, n, U, n, tau);
    LAPACKE_dorgqr(LAPACK_ROW_MAJOR, n, n, n, U, n, tau);
  }
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++) {
      double s = 0;
      for (int k = 0; k < n; k++) s += U[i * n + k] * lam[k] * U[j * n + k];
      M[i * n + j] = s;
    }
  free(tau);
}

/* Spectra of the operators below, eigenvalue i of n. */
typedef enum Spectrum {
  SP_SPREAD,    /* 1 down to 1e-3, geometrically */
  SP_CLUSTERED, /* 1, 2, 3, each n/3 times */
  SP_SCALAR,    /* every eigenvalue 3 */
  SP_HALF_ZERO, /* half of them 0 (semidefinite) */
  SP_NEGATIVE,  /* one eigenvalue -0.5 */
} Spectrum;

static double eigenvalue(Spectrum sp, int i, int n) {
  switch (sp) {
  case SP_SPREAD: return pow(1e-3, (double)i / (n - 1));
  case SP_CLUSTERED: return 1 + i % 3;
  case SP_SCALAR: return 3;
  case SP_HALF_ZERO: return i < n / 2 ? 0 : 1 + (double)i / n;
  case SP_NEGATIVE: return i == n / 2 ? -0.5 : 1 + (double)i / n;
  }
  return 0;
}

typedef struct RootCase {
  Spectrum sp;
  bool diagonal;   /* M diagonal: T's off-diagonal zero from the start */
  int exponent;    /* M scaled by 2^exponent: the result by 2^(exponent·p/q) */
  double tol;      /* relative to U diag(lam^(p/q)) Uᵀ v */
  const char *err; /* or the failure's message holds this */
} RootCase;

/* M̂^(p/q) v of the root stage of `path` through reduced_apply_power, for
 * operators of the spectra above, against U diag(lam^(p/q)) Uᵀ v; m[0] or
 * (when set) m[1] gets the operators' size. */
static int roots_of_program(const char *path, long n, double *worst, int *cases, int *m) {
  Trained tr;
  train(&tr, path, NULL, n, 40, 40);
  int stage = -1;
  for (int i = 0; i < tr.m->nstages; i++)
    if (tr.m->stages[i].st->kind == ST_ROOT) stage = i;
  assert_true(stage >= 0);
  const RStage *rs = &tr.m->stages[stage];
  const OpPow *op = rs->terms[0].ops[0].op;
  int my = (int)tr.m->classes[tr.m->qclass[rs->q]].m;
  m[m[0] ? 1 : 0] = my;
  double power = (double)op->p / (double)op->q;
  /* a semidefinite operator's positive root is only Hölder continuous at
   * its zero eigenvalues: rounding ε in them becomes √ε in the result */
  const RootCase table[] = {
      {SP_SPREAD, false, 0, 1e-12, NULL},
      {SP_SPREAD, true, 0, 1e-12, NULL},
      {SP_SPREAD, false, 600, 1e-12, NULL},
      {SP_SPREAD, false, -600, 1e-12, NULL},
      {SP_CLUSTERED, false, 0, 1e-12, NULL},
      {SP_CLUSTERED, true, -900, 1e-12, NULL},
      {SP_SCALAR, false, 0, 1e-12, NULL},
      {SP_HALF_ZERO, false, 0, 1e-6, op->p < 0 ? "singular at sample 3" : NULL},
      {SP_NEGATIVE, false, 0, 0, "indefinite at sample 3 (eigenvalue -0.5, largest"},
  };
  size_t mm = (size_t)my * (size_t)my;
  double *lam = malloc(sizeof(double) * (size_t)my), *U = malloc(sizeof(double) * mm), *M = malloc(sizeof(double) * mm);
  double *v = malloc(sizeof(double) * (size_t)my), *y = malloc(sizeof(double) * (size_t)my);
  double *want = malloc(sizeof(double) * (size_t)my);
  unsigned seed = 11u;
  char err[1024] = "";
  int failures = 0;
  for (size_t c = 0; c < sizeof table / sizeof *table; c++) {
    const RootCase *rc = &table[c];
    for (int i = 0; i < my; i++) lam[i] = eigenvalue(rc->sp, i, my), v[i] = randdata_uniform(&seed, -1, 1);
    spectral_matrix(my, lam, rc->diagonal, &seed, U, M);
    cblas_dgemv(CblasRowMajor, CblasTrans, my, my, 1.0, U, my, v, 1, 0.0, y, 1);
    for (int i = 0; i < my; i++) y[i] *= lam[i] > 0 ? pow(lam[i], power) : 0;
    cblas_dgemv(CblasRowMajor, CblasNoTrans, my, my, 1.0, U, my, y, 1, 0.0, want, 1);
    for (size_t i = 0; i < mm; i++) M[i] = ldexp(M[i], rc->exponent);
    Reduced *r = reduced_new(tr.m, ERR_OF(err, sizeof err));
    assert_non_null(r);
    int got = reduced_apply_power(r, &(ReducedPower){stage, 0, 0, op->p, op->q, 3}, M, v);
    (*cases)++;
    if (rc->err) {
      if (got != -1 || !strstr(reduced_error(r), rc->err)) {
        print_message("%s: case %zu: expected a failure with '%s', got %d '%s'\n", path, c, rc->err, got,
                      reduced_error(r));
        failures++;
      }
    } else if (got != 0) {
      print_message("%s: case %zu: %s\n", path, c, reduced_error(r));
      failures++;
    } else {
      for (int i = 0; i < my; i++) v[i] = ldexp(v[i], -(int)lround(rc->exponent * power));
      double d = rel_diff(want, v, (size_t)my);
      if (rc->tol <= 1e-12) *worst = fmax(*worst, d);
      if (!(d <= rc->tol)) {
        print_message("%s: case %zu (m = %d): differs from U diag(lam^(p/q)) Uᵀ v by %.3g\n", path, c, my, d);
        failures++;
      }
    }
    reduced_free(r);
  }
  /* not finite */
  Reduced *r = reduced_new(tr.m, ERR_OF(err, sizeof err));
  for (size_t i = 0; i < mm; i++) M[i] = i == (size_t)my + 1 ? NAN : 0;
  if (reduced_apply_power(r, &(ReducedPower){stage, 0, 0, op->p, op->q, 3}, M, v) != -1 ||
      !strstr(reduced_error(r), "eigendecomposition of reduced operator")) {
    print_message("%s: NaN operator: '%s'\n", path, reduced_error(r));
    failures++;
  }
  (*cases)++;
  reduced_free(r);
  free(lam), free(U), free(M), free(v), free(y), free(want);
  trained_free(&tr);
  return failures;
}

static void roots_of_given_operators(void **state) {
  (void)state;
  double worst = 0;
  int cases = 0, failures = 0, m[2] = {0, 0};
  failures += roots_of_program("tests/programs/negative_power_named.npg", 12, &worst, &cases, m); /* d a^(-1/2) */
  failures += roots_of_program("tests/programs/root_of_op.npg", 16, &worst, &cases, m);          /* M^(1/2) x */
  print_message("%d roots of given operators (m = %d, %d) vs U diag(lam^(p/q)) Uᵀ v, worst relative difference "
                "%.2g\n", cases, m[0], m[1], worst);
  assert_int_equal(failures, 0);
}

/* ---------------------------------------------------------------- sizes without retraining */

/* The largest over the test samples and the outputs of ‖y_a − y_b‖/‖y_a‖, y lifted from the
 * reduced evaluations of models a and b. */
static double lifted_distance(Program *prog, Full *f, Model *a, Model *b, MemSamples *test) {
  char err[1024];
  Reduced *ra = reduced_new(a, ERR_OF(err, sizeof err)), *rb = reduced_new(b, ERR_OF(err, sizeof err));
  assert_non_null(ra), assert_non_null(rb);
  double worst = 0;
  for (long k = 0; k < test->S; k++) {
    if (memsamples_set(test, f, k) || full_eval(f, k)) fail_msg("%s", full_error(f));
    for (int q = 0; q < a->nq; q++) {
      const Sym *s = prog->quantities.v[q];
      if (s->kind == SYM_INPUT) reduced_project(ra, q, full_get(f, s->name, NULL)), reduced_project(rb, q, full_get(f, s->name, NULL));
    }
    if (reduced_eval(ra, k)) fail_msg("%s", reduced_error(ra));
    if (reduced_eval(rb, k)) fail_msg("%s", reduced_error(rb));
    for (int q = 0; q < a->nq; q++) {
      const Sym *s = prog->quantities.v[q];
      if (!s->is_output) continue;
      size_t n;
      full_get(f, s->name, &n);
      double *ya = malloc(sizeof(double) * n), *yb = malloc(sizeof(double) * n), num = 0, den = 0;
      reduced_lift(ra, q, ya), reduced_lift(rb, q, yb);
      for (size_t i = 0; i < n; i++) num += (ya[i] - yb[i]) * (ya[i] - yb[i]), den += ya[i] * ya[i];
      worst = fmax(worst, sqrt(num / den));
      free(ya), free(yb);
    }
  }
  reduced_free(ra), reduced_free(rb);
  return worst;
}

/* Issue 41, sizes without retraining: a model trained at caps of 8 (energy 1), cut by
 * model_truncate to the sizes training at caps 2, 3 and 5 gives, evaluates as that training
 * does: every output lifted on held-out samples equal to 1e-12, centered and uncentered. The
 * programs: contractions with packed repeated inputs (x ⊗ x, a ⊗ a) over three classes of one
 * member; an inverse stage (a diagonal operator, packed BᵀMB rows) whose class {z, z.num1}
 * merges two members (interleaved, pca_merge) or is one joint PCA (--merge joint); an
 * explicit size above the class's is refused, naming the class. */
static void smaller_sizes_equal_retraining(void **state) {
  (void)state;
  const char *programs[2] = {"dim N\ninput x : real[N]\na[i:N] = x[i] * x[i] + x[i]\n"
                             "output y[i:N] = a[i] * a[i] * x[i] + a[i]\n",
                             "dim N\ninput x : real[N]\nw[i:N] = x[i] * x[i]\n"
                             "output z[i:N] = (w[i] + x[i]) / (w[i] + 2)\n"};
  for (int run = 0; run < 6; run++) {
      int pr = run / 2 > 0, uncentered = run % 2;
      bool joint = run / 2 == 2;
      NpgProgram *p = compile_text("sizes.npg", programs[pr]);
      Program *prog = ir_ok(p);
      Full *f = full_new(program_ir(p), JIT_TCC, NULL);
      MemSamples train, test;
      if (memsamples_fill(&train, prog, f, 30, 14, 3u) || memsamples_fill(&test, prog, f, 30, 5, 4u))
        fail_msg("binding random params failed");
      SampleSource src = {train.S, &train, memsamples_set, NULL, NULL};
      NpgTrainOptions opt_user = {.cap = 8, .energy = 1.0, .uncentered = uncentered, .joint = joint};
      TrainOptions opt = {.user = &opt_user};
      char err[2048] = "";
      Model *big = train_model(prog, f, &src, &opt, ERR_OF(err, sizeof err));
      if (!big) fail_msg("%s", err);
      const int caps[3] = {2, 3, 5};
      double worst = 0;
      for (int i = 0; i < 3; i++) {
        opt_user.cap = caps[i];
        Model *small = train_model(prog, f, &src, &opt, ERR_OF(err, sizeof err));
        if (!small) fail_msg("%s", err);
        long sizes[16];
        for (int c = 0; c < small->nclasses; c++) sizes[c] = small->classes[c].m;
        Model *cut = model_truncate(big, sizes, ERR_OF(err, sizeof err));
        if (!cut) fail_msg("%s", err);
        for (int c = 0; c < small->nclasses; c++) assert_int_equal(cut->classes[c].m, small->classes[c].m);
        worst = fmax(worst, lifted_distance(prog, f, small, cut, &test));
        model_free(small), model_free(cut);
      }
      print_message("program %d, %s, %s: caps 8 cut to the sizes of caps 2, 3, 5 against retraining there: lifted "
                    "outputs equal to %.2g\n", pr + 1, uncentered ? "uncentered" : "centered",
                    joint ? "merge joint" : "members merged", worst);
      assert_true(worst < 1e-12);
      long too[16];
      for (int c = 0; c < big->nclasses; c++) too[c] = -1;
      too[0] = big->classes[0].m + 1;
      assert_null(model_truncate(big, too, ERR_OF(err, sizeof err)));
      assert_non_null(strstr(err, big->classes[0].bc->size_name));
      model_free(big);
      memsamples_free(&train), memsamples_free(&test);
      full_free(f);
      npg_free(p);
    }
}

/* ---------------------------------------------------------------- derivatives from the evaluation's operators */

/* The largest over every (output, input) of the relative difference between the Jacobian taken
 * from what reduced_eval kept (its operators, factors and chains; the local Jacobians of the
 * tensors of one input taken twice) and the one recomputing them (an evaluator that evaluated
 * stage by stage keeps nothing). Counts the operators and local Jacobians kept; checks that a
 * changed coordinate voids them. */
static double kept_against_recomputed(const char *path, const char *text, int *nops, int *nlocal) {
  Trained tr;
  train(&tr, path, text, 6, 16, 3);
  char err[1024];
  Reduced *a = reduced_new(tr.m, ERR_OF(err, sizeof err)), *b = reduced_new(tr.m, ERR_OF(err, sizeof err));
  assert_non_null(a), assert_non_null(b);
  if (memsamples_set(&tr.train, tr.f, 3) || full_eval(tr.f, 3)) fail_msg("%s", full_error(tr.f));
  for (int q = 0; q < tr.m->nq; q++) {
    const Sym *s = tr.prog->quantities.v[q];
    if (s->kind == SYM_INPUT) reduced_project(a, q, full_get(tr.f, s->name, NULL)), reduced_project(b, q, full_get(tr.f, s->name, NULL));
  }
  reduced_keep_local_jacobians(a, true);
  if (reduced_eval(a, 3)) fail_msg("%s", reduced_error(a));
  reduced_keep_local_jacobians(a, false);
  for (int i = 0; i < tr.m->nstages; i++)
    if (reduced_eval_stage(b, i, 3)) fail_msg("%s", reduced_error(b));
  for (int i = 0; i < tr.m->nstages; i++)
    for (int t = 0; !tr.m->stages[i].interp && t < tr.m->stages[i].nterms; t++)
      for (int k = 0; k < tr.m->stages[i].terms[t].nops; k++) {
        *nops += reduced_kept(a, i, t, k) != NULL;
        assert_null(reduced_kept(b, i, t, k));
      }
  FOR_TENSORS(tr.m, x) *nlocal += reduced_kept_local_jacobian(a, x) != NULL;
  double worst = 0;
  for (int qi = 0; qi < tr.m->nq; qi++) {
    const Sym *si = tr.prog->quantities.v[qi];
    long mi = tr.m->classes[tr.m->qclass[qi]].m;
    for (int qo = 0; si->kind == SYM_INPUT && mi > 0 && qo < tr.m->nq; qo++) {
      if (!((const Sym *)tr.prog->quantities.v[qo])->is_output) continue;
      long mo = tr.m->classes[tr.m->qclass[qo]].m;
      double *Ja = malloc(sizeof(double) * (size_t)(mo * mi + 1)), *Jb = malloc(sizeof(double) * (size_t)(mo * mi + 1));
      if (reduced_jacobian(a, qo, qi, Ja, 3, ERR_OF(err, sizeof err)) ||
          reduced_jacobian(b, qo, qi, Jb, 3, ERR_OF(err, sizeof err)))
        fail_msg("%s: %s", path, err);
      double big = 1, diff = 0;
      for (long e = 0; e < mo * mi; e++) big = fmax(big, fabs(Jb[e])), diff = fmax(diff, fabs(Ja[e] - Jb[e]));
      worst = fmax(worst, diff / big);
      free(Ja), free(Jb);
    }
  }
  for (int q = 0; q < tr.m->nq; q++) /* a coordinate changed after the evaluation voids what it kept */
    if (((const Sym *)tr.prog->quantities.v[q])->kind == SYM_INPUT && tr.m->classes[tr.m->qclass[q]].m > 0) {
      reduced_coords(a, q)[0] += 1;
      for (int i = 0; i < tr.m->nstages; i++)
        if (!tr.m->stages[i].interp && tr.m->stages[i].nterms > 0 && tr.m->stages[i].terms[0].nops > 0)
          assert_null(reduced_kept(a, i, 0, 0));
      FOR_TENSORS(tr.m, x) assert_null(reduced_kept_local_jacobian(a, x));
      reduced_coords(a, q)[0] -= 1;
      break;
    }
  reduced_free(a), reduced_free(b);
  trained_free(&tr);
  return worst;
}

/* Issue 43: the reduced Jacobian taken from the evaluation's operators equals the one that
 * recomputes them, to 1e-12: an inverse of an operator quadratic in its input (its local
 * Jacobian kept by the evaluation), a root, a declared operator solved. */
static void derivatives_reuse_the_evaluation(void **state) {
  (void)state;
  static const char *quadratic = "dim N\ninput x : real[N]\ninput u : real[N]\nk[i:N] = u[i] / (1 + x[i]^2)\n"
                                 "output y[i:N] = k[i] * x[i] + u[i]\n";
  static const char *root = "dim N\ninput x : real[N]\ninput u : real[N]\nd[i:N] = x[i]^2 + 1\n"
                            "output y[i:N] = u[i] * d[i]^(-1/2)\n";
  int nops = 0, nlocal = 0;
  double worst = kept_against_recomputed("quadratic.npg", quadratic, &nops, &nlocal);
  assert_true(nops > 0 && nlocal > 0);
  worst = fmax(worst, kept_against_recomputed("root.npg", root, &nops, &nlocal));
  worst = fmax(worst, kept_against_recomputed("tests/programs/solve_stage.npg", NULL, &nops, &nlocal));
  print_message("%d operators and %d local Jacobians kept, kept against recomputed: worst relative %.2g\n", nops,
                nlocal, worst);
  assert_true(worst <= 1e-12);
}

/* ---------------------------------------------------------------- one stage's partials */

/* The largest over every stage and every quantity it reads of the relative difference between the stage's
 * local partial by reverse directions (reduced_stage_vjp, the identity seeded on the stage) and the forward
 * one (reduced_stage_jvp, the identity seeded on the input) transposed. Counts the pairs compared and the
 * interpolated stages among them. */
static double stage_vjp_against_jvp(const char *path, const char *text, int *pairs, int *interpolated) {
  Trained tr;
  train(&tr, path, text, 6, 16, 3);
  char err[1024];
  Reduced *r = reduced_new(tr.m, ERR_OF(err, sizeof err));
  assert_non_null(r);
  if (memsamples_set(&tr.train, tr.f, 3) || full_eval(tr.f, 3)) fail_msg("%s", full_error(tr.f));
  for (int q = 0; q < tr.m->nq; q++) {
    const Sym *s = tr.prog->quantities.v[q];
    if (s->kind == SYM_INPUT) reduced_project(r, q, full_get(tr.f, s->name, NULL));
  }
  if (reduced_eval(r, 3)) fail_msg("%s", reduced_error(r));
  double worst = 0;
  for (int i = 0; i < tr.m->nstages; i++)
    for (int q = 0; q < tr.m->nq; q++) {
      int qy = tr.m->stages[i].q;
      long my = tr.m->classes[tr.m->qclass[qy]].m, mq = tr.m->classes[tr.m->qclass[q]].m;
      if (q == qy || my == 0 || mq == 0) continue;
      double *ey = calloc((size_t)(my * my), sizeof(double)), *eq = calloc((size_t)(mq * mq), sizeof(double));
      double *J = malloc(sizeof(double) * (size_t)(my * mq)), *Jt = malloc(sizeof(double) * (size_t)(my * mq));
      for (long a = 0; a < my; a++) ey[a * my + a] = 1;
      for (long a = 0; a < mq; a++) eq[a * mq + a] = 1;
      const double *sy = ey, *sq = eq;
      if (reduced_stage_jvp(r, i, &(ReducedSeeds){1, &q, &sq, mq, false}, J, -1, ERR_OF(err, sizeof err)) ||
          reduced_stage_vjp(r, i, &(ReducedSeeds){1, &q, &sy, my, false}, Jt, -1, ERR_OF(err, sizeof err)))
        fail_msg("%s: stage %d: %s", path, i, err);
      double big = 0, diff = 0;
      for (long a = 0; a < my; a++)
        for (long b = 0; b < mq; b++)
          big = fmax(big, fabs(J[a * mq + b])), diff = fmax(diff, fabs(J[a * mq + b] - Jt[b * my + a]));
      if (big > 0) worst = fmax(worst, diff / big), ++*pairs, *interpolated += tr.m->stages[i].interp != NULL;
      else assert_true(diff == 0);
      free(ey), free(eq), free(J), free(Jt);
    }
  reduced_free(r);
  trained_free(&tr);
  return worst;
}

/* reduced_stage_vjp (which the propagation of an input's error takes when the stage's basis is smaller
 * than its input's, estimate.c) is reduced_stage_jvp transposed, to 1e-12: contractions, an inverse of an
 * operator quadratic in its input, a root, a declared operator solved, an interpolated stage. */
static void stage_partials_transpose(void **state) {
  (void)state;
  static const char *quadratic = "dim N\ninput x : real[N]\ninput u : real[N]\nk[i:N] = u[i] / (1 + x[i]^2)\n"
                                 "output y[i:N] = k[i] * x[i] + u[i]\n";
  static const char *interp = "dim N\ninput x : real[N]\ninput u : real[N]\nk[i:N] = u[i] / (1 + x[i]^2)\n"
                              "basis k: reduce interp\noutput y[i:N] = k[i] * x[i] + u[i]\n";
  static const char *root = "dim N\ninput x : real[N]\ninput u : real[N]\nd[i:N] = x[i]^2 + 1\n"
                            "output y[i:N] = u[i] * d[i]^(-1/2)\n";
  int pairs = 0, interpolated = 0;
  double worst = stage_vjp_against_jvp("quadratic.npg", quadratic, &pairs, &interpolated);
  worst = fmax(worst, stage_vjp_against_jvp("interp.npg", interp, &pairs, &interpolated));
  worst = fmax(worst, stage_vjp_against_jvp("root.npg", root, &pairs, &interpolated));
  worst = fmax(worst, stage_vjp_against_jvp("tests/programs/solve_stage.npg", NULL, &pairs, &interpolated));
  print_message("%d (stage, input) pairs, %d of an interpolated stage: the stage's reverse partial against its "
                "forward one transposed, worst relative %.2g\n", pairs, interpolated, worst);
  assert_true(pairs >= 8 && interpolated >= 2);
  assert_true(worst <= 1e-12);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(full_rank_reproduces_full),
      cmocka_unit_test(reduced_stages_equal_dense_formulas),
      cmocka_unit_test(corrupted_model_named),
      cmocka_unit_test(roots_of_given_operators),
      cmocka_unit_test(smaller_sizes_equal_retraining),
      cmocka_unit_test(derivatives_reuse_the_evaluation),
      cmocka_unit_test(stage_partials_transpose),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
