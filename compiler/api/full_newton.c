/* full_newton.c — npg_full_newton (DESIGN §17, implicit steps): Newton's method on a residual
 * of the full evaluator, the contract of npg_reduced_newton (reduced_derivatives.c) with the
 * full Jacobian: on its structural pattern (api_jac_plan, planned once per call), solved by
 * UMFPACK (the pattern analysed once, factorized at every iteration), or expanded and solved by
 * LAPACK dgesv when it is dense (more than 2% of its entries on the pattern). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

#include "api.h"
#include <lapacke.h>

/* A Jacobian with more than this fraction of its entries on the pattern is solved dense. Measured
 * (one factorization and solve, OPENBLAS_NUM_THREADS=1; UMFPACK's analysis apart): a periodic
 * 5-point grid at 100 cells (5% filled) dense 0.065 ms, UMFPACK 0.17; at 400 (1.25%) dense 1.7 ms,
 * UMFPACK 0.35; random patterns at 400 × 400, 5% filled: dense 1.7 ms, UMFPACK 11.6 (fill-in). */
#define NEWTON_DENSE_FILL 0.02

__attribute__((format(printf, 2, 3))) static int nfail(NpgFull *f, const char *fmt, ...) {
  char why[1024];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(why, sizeof why, fmt, ap);
  va_end(ap);
  return full_refuse(f->full, why);
}

/* One Newton solve's state: the Jacobian's plan and values, UMFPACK's analysis of its pattern
 * (sparse) or the expanded matrix and pivots (dense). */
typedef struct NewtonSolver {
  ApiJacPlan plan;
  double *data, *dense, *x;
  lapack_int *piv;
  bool sparse;
  void *symbolic;
  double control[UMFPACK_CONTROL];
} NewtonSolver;

static void solver_free(NewtonSolver *s) {
  if (s->symbolic) umfpack_dl_free_symbolic(&s->symbolic);
  api_jac_plan_free(&s->plan);
  free(s->data), free(s->dense), free(s->x), free(s->piv);
}

static int solver_init(NpgFull *f, const char *residual, const char *unknown, NewtonSolver *s) {
  memset(s, 0, sizeof *s);
  if (api_jac_plan(f, residual, unknown, &s->plan) != 0) return -1;
  long n = s->plan.rows, nnz = s->plan.indptr[n];
  s->sparse = (double)nnz <= NEWTON_DENSE_FILL * (double)n * (double)n;
  s->data = malloc(sizeof(double) * (size_t)(nnz + 1));
  s->x = malloc(sizeof(double) * (size_t)(n + 1));
  if (!s->sparse) {
    s->dense = malloc(sizeof(double) * (size_t)(n * n + 1));
    s->piv = malloc(sizeof(lapack_int) * (size_t)(n + 1));
  }
  if (!s->data || !s->x || (!s->sparse && (!s->dense || !s->piv))) return nfail(f, "npg_full_newton: out of memory");
  umfpack_dl_defaults(s->control);
  return 0;
}

/* The correction δ of J δ = b into s->x: UMFPACK on the CSR pattern read as the CSC of Jᵀ
 * (solved transposed), or LAPACK dgesv on the expanded matrix. */
static int solver_solve(NpgFull *f, NewtonSolver *s, const char *residual, const char *unknown, long sample, int it,
                        const double *b) {
  long n = s->plan.rows;
  const long *ptr = s->plan.indptr, *idx = s->plan.indices;
  if (!s->sparse) {
    memset(s->dense, 0, sizeof(double) * (size_t)(n * n));
    for (long r = 0; r < n; r++)
      for (long k = ptr[r]; k < ptr[r + 1]; k++) s->dense[r * n + idx[k]] = s->data[k];
    memcpy(s->x, b, sizeof(double) * (size_t)n);
    lapack_int info = LAPACKE_dgesv(LAPACK_ROW_MAJOR, (lapack_int)n, 1, s->dense, (lapack_int)n, s->piv, s->x, 1);
    if (info != 0)
      return nfail(f, "npg_full_newton: sample %ld, iteration %d: the Jacobian of '%s' by '%s' is singular (LAPACK "
                      "dgesv info %d)", sample, it, residual, unknown, (int)info);
    return 0;
  }
  const SuiteSparse_long *Ap = (const SuiteSparse_long *)ptr, *Ai = (const SuiteSparse_long *)idx;
  double info[UMFPACK_INFO] = {0};
  int st = UMFPACK_OK;
  if (!s->symbolic)
    st = (int)umfpack_dl_symbolic((SuiteSparse_long)n, (SuiteSparse_long)n, Ap, Ai, s->data, &s->symbolic, s->control,
                                  info);
  void *numeric = NULL;
  if (st == UMFPACK_OK) st = (int)umfpack_dl_numeric(Ap, Ai, s->data, s->symbolic, &numeric, s->control, info);
  if (st == UMFPACK_OK) st = (int)umfpack_dl_solve(UMFPACK_At, Ap, Ai, s->data, s->x, b, numeric, s->control, info);
  if (numeric) umfpack_dl_free_numeric(&numeric);
  if (st == UMFPACK_WARNING_singular_matrix || (st == UMFPACK_OK && !(info[UMFPACK_RCOND] > 0)))
    return nfail(f, "npg_full_newton: sample %ld, iteration %d: the Jacobian of '%s' by '%s' is singular (UMFPACK "
                    "reciprocal condition %.1e)", sample, it, residual, unknown, info[UMFPACK_RCOND]);
  if (st != UMFPACK_OK)
    return nfail(f, "npg_full_newton: sample %ld, iteration %d: UMFPACK failed on the Jacobian of '%s' by '%s' "
                    "(status %d)", sample, it, residual, unknown, st);
  return 0;
}

/* One correction: the Jacobian at the point just evaluated, J δ = r, unknown -= δ. */
static int newton_update(NpgFull *f, NewtonSolver *s, long sample, int it, const char *residual, const char *unknown,
                         int kr, int ku) {
  if (!s->plan.indptr && solver_init(f, residual, unknown, s) != 0) return -1;
  if (api_jac_values(f, sample, kr, ku, &s->plan, s->data) != 0) return -1;
  if (solver_solve(f, s, residual, unknown, sample, it, full_get(f->full, residual, NULL)) != 0) return -1;
  long n = s->plan.rows, shape[MAX_AXES + MAX_STATIC];
  const double *v = full_get(f->full, unknown, NULL);
  for (long i = 0; i < n; i++) s->x[i] = v[i] - s->x[i];
  const Program *prog = full_program(f->full);
  int nd = api_shape(f->full, prog->slots.v[ku], shape);
  return full_set(f->full, unknown, nd, shape, s->x, "npg_full_newton");
}

int npg_full_newton(NpgFull *f, long sample, const char *residual, const char *unknown, NpgNewton *o) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (!o) return nfail(f, "npg_full_newton: argument 'o' is NULL");
  const char *fn = __func__;
  int kr = api_full_slot(f, fn, "residual", residual, false);
  int ku = kr < 0 ? -1 : api_full_slot(f, fn, "unknown", unknown, true);
  if (kr < 0 || ku < 0) return -1;
  if (!(o->tol > 0) || !isfinite(o->tol)) return nfail(f, "%s: tolerance %g: it must be positive and finite", fn, o->tol);
  if (o->max_iter < 1) return nfail(f, "%s: max_iter %d: at least one iteration", fn, o->max_iter);
  if (!(o->rtol >= 0) || !isfinite(o->rtol))
    return nfail(f, "%s: relative tolerance %g: it must be 0 or positive and finite", fn, o->rtol);
  if (!full_get(f->full, unknown, NULL))
    return nfail(f, "%s: unknown '%s' has no value: set it first (the previous state is the usual start)", fn, unknown);
  NewtonSolver s = {0};
  o->iterations = 0, o->residual = NAN;
  double tol = o->tol;
  int rc = -1;
  for (int it = 0;; it++) {
    if (npg_full_eval(f, sample) != 0) break;
    size_t nr = 0, nu = 0;
    const double *res = full_get(f->full, residual, &nr);
    full_get(f->full, unknown, &nu);
    if (nr != nu) {
      nfail(f, "%s: residual '%s' has %zu entries and unknown '%s' %zu: a Newton step needs as many equations as "
               "unknowns", fn, residual, nr, unknown, nu);
      break;
    }
    double norm = 0;
    for (size_t i = 0; i < nr; i++) norm += res[i] * res[i];
    norm = sqrt(norm);
    o->iterations = it, o->residual = norm;
    if (o->history && it < o->history_cap) o->history[it] = norm;
    if (o->verbose) fprintf(o->verbose, "newton sample %ld iteration %d: |%s| = %.3e\n", sample, it, residual, norm);
    if (!isfinite(norm)) {
      nfail(f, "%s: sample %ld, iteration %d: residual '%s' is not finite", fn, sample, it, residual);
      break;
    }
    if (it == 0) tol = fmax(o->tol, o->rtol * norm);
    if (norm <= tol) {
      rc = 0;
      break;
    }
    if (it == o->max_iter) {
      nfail(f, "%s: Newton on residual '%s' for '%s' did not converge at sample %ld: iteration %d, residual %.3e "
               "(tolerance %.3e)", fn, residual, unknown, sample, it, norm, tol);
      break;
    }
    if (newton_update(f, &s, sample, it, residual, unknown, kr, ku) != 0) break;
  }
  solver_free(&s);
  return rc;
}
