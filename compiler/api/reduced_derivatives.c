/* reduced_derivatives.c — derivatives of the reduced evaluator through
 * npg.h (DESIGN §17): npg_reduced_jvp, npg_reduced_vjp and
 * npg_reduced_jacobian in reduced coordinates, the signatures of the full
 * evaluator's npg_full_jvp, npg_full_vjp and npg_full_jacobian. Each
 * evaluates (npg_reduced_eval) and differentiates there (reduced_deriv.c). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <lapacke.h>
#include <stdio.h>

#include "api.h"

#define rfail(r, ...) error_set_first((r)->error, sizeof (r)->error, __VA_ARGS__)
#define REFUSE_NULL(arg) API_REFUSE_NULL(arg, r->error, sizeof r->error, -1)

/* Quantity `name` of the model, for the argument `what` of `fn`: -1 with the error set when
 * unknown, or not an input where `input` is asked. */
static int derivative_quantity(NpgReduced *r, const char *fn, const char *what, const char *name, bool input) {
  const Model *m = r->nm->m;
  if (!name) return rfail(r, "%s: argument '%s' is NULL", fn, what), -1;
  int q = api_quantity(m->prog, name);
  if (q < 0) return rfail(r, "%s: argument '%s': the program has no quantity '%s'", fn, what, name), -1;
  const Sym *s = m->prog->quantities.v[q];
  if (input && s->kind != SYM_INPUT)
    return rfail(r, "%s: argument '%s': '%s' is not an input (derivatives are taken with respect to inputs)", fn, what,
                 name), -1;
  return q;
}

static long coords_of(const NpgReduced *r, int q) { return r->nm->m->classes[r->nm->m->qclass[q]].m; }

/* The arrays `n` vectors given by the caller: every one non-NULL and finite. */
static int finite_vectors(NpgReduced *r, const char *fn, const char *what, int n, const int *q,
                          const double *const *v) {
  for (int i = 0; i < n; i++) {
    if (!v[i]) return rfail(r, "%s: argument '%s[%d]' is NULL", fn, what, i);
    for (long k = 0; k < coords_of(r, q[i]); k++)
      if (!isfinite(v[i][k]))
        return rfail(r, "%s: argument '%s[%d]' (of '%s') is not finite at coordinate %ld", fn, what, i,
                     ((Sym *)r->nm->m->prog->quantities.v[q[i]])->name, k);
  }
  return 0;
}

/* npg_reduced_eval, keeping the local Jacobians of the tensors of one input taken twice from the
 * evaluation's read of them (reduced_keep_local_jacobians): a derivative follows. */
static int eval_for_derivative(NpgReduced *r, long sample) {
  if (r->r) reduced_keep_local_jacobians(r->r, true);
  int rc = npg_reduced_eval(r, sample);
  if (r->r) reduced_keep_local_jacobians(r->r, false);
  return rc;
}

/* What the three share: the arguments named, the evaluation at `sample`. `qs` holds n + 1. */
static int derivative_begin(NpgReduced *r, const char *fn, long sample, int n, const char *const *names,
                            bool names_inputs, const char *what, int *qs) {
  if (npg_reduced_error(r)[0]) return -1;
  if (n < 1 || n > 1024) return rfail(r, "%s: %d %s given (1 to 1024)", fn, n, what);
  for (int i = 0; i < n; i++) {
    char arg[64];
    if (strcmp(what, "output") == 0) snprintf(arg, sizeof arg, "%s", what); /* npg_reduced_jacobian's one */
    else snprintf(arg, sizeof arg, "%s[%d]", what, i);
    if ((qs[i] = derivative_quantity(r, fn, arg, names[i], names_inputs)) < 0) return -1;
  }
  return eval_for_derivative(r, sample);
}

int npg_reduced_jvp(NpgReduced *r, long sample, int nin, const char *const *inputs, const double *const *directions,
                    const char *output, double *out) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  REFUSE_NULL(inputs);
  REFUSE_NULL(directions);
  REFUSE_NULL(out);
  if (!r->r) return -1;
  int qs[1025], qo;
  if ((qo = derivative_quantity(r, __func__, "output", output, false)) < 0) return -1;
  if (derivative_begin(r, __func__, sample, nin, inputs, true, "inputs", qs)) return -1;
  if (finite_vectors(r, __func__, "directions", nin, qs, directions)) return -1;
  char err[1024];
  ReducedSeeds seeds = {nin, qs, directions, 1, false};
  if (reduced_jvp(r->r, &seeds, qo, out, sample, ERR_OF(err, sizeof err))) return rfail(r, "%s", err);
  return 0;
}

int npg_reduced_vjp(NpgReduced *r, long sample, int nout, const char *const *outputs, const double *const *cotangents,
                    const char *input, double *out) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  REFUSE_NULL(outputs);
  REFUSE_NULL(cotangents);
  REFUSE_NULL(out);
  if (!r->r) return -1;
  int qs[1025], qi;
  if ((qi = derivative_quantity(r, __func__, "input", input, true)) < 0) return -1;
  if (derivative_begin(r, __func__, sample, nout, outputs, false, "outputs", qs)) return -1;
  if (finite_vectors(r, __func__, "cotangents", nout, qs, cotangents)) return -1;
  char err[1024];
  ReducedSeeds seeds = {nout, qs, cotangents, 1, false};
  if (reduced_vjp(r->r, &seeds, qi, out, sample, ERR_OF(err, sizeof err))) return rfail(r, "%s", err);
  return 0;
}

int npg_reduced_jacobian(NpgReduced *r, long sample, const char *output, const char *input, double *out) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  REFUSE_NULL(out);
  if (!r->r) return -1;
  int qo, qi;
  if ((qi = derivative_quantity(r, __func__, "input", input, true)) < 0) return -1;
  if (derivative_begin(r, __func__, sample, 1, &output, false, "output", &qo)) return -1;
  char err[1024];
  if (reduced_jacobian(r->r, qo, qi, out, sample, ERR_OF(err, sizeof err))) return rfail(r, "%s", err);
  return 0;
}

/* ---------------------------------------------------------------- Newton on a reduced residual */

static double norm2(const double *v, long n) {
  double s = 0;
  for (long i = 0; i < n; i++) s += v[i] * v[i];
  return sqrt(s);
}

/* One Newton iteration's correction: J δ = r̂ by LAPACK dgesv, then x̂ -= δ. `J` holds m·m. */
static int newton_update(NpgReduced *r, const char *fn, long sample, const char *residual, const char *unknown, int it,
                         double *J, double *rhs, long m) {
  const Program *prog = r->nm->m->prog;
  char err[1024]; /* at the coordinates just evaluated: not npg_reduced_jacobian, which evaluates again */
  if (reduced_jacobian(r->r, api_quantity(prog, residual), api_quantity(prog, unknown), J, sample,
                       ERR_OF(err, sizeof err)))
    return rfail(r, "%s: sample %ld, iteration %d: %s", fn, sample, it, err);
  lapack_int *piv = malloc(sizeof(lapack_int) * (size_t)(m + 1));
  if (!piv) return rfail(r, "%s: out of memory", fn);
  lapack_int info = LAPACKE_dgesv(LAPACK_ROW_MAJOR, (lapack_int)m, 1, J, (lapack_int)m, piv, rhs, 1);
  free(piv);
  if (info != 0)
    return rfail(r, "%s: sample %ld, iteration %d: the Jacobian of '%s' by '%s' is singular (LAPACK dgesv info %d)",
                 fn, sample, it, residual, unknown, (int)info);
  size_t mu = 0;
  const double *x = npg_reduced_coords(r, unknown, &mu);
  double *next = malloc(sizeof(double) * (size_t)(m + 1));
  if (!next) return rfail(r, "%s: out of memory", fn);
  for (long i = 0; i < m; i++) next[i] = x[i] - rhs[i];
  int rc = npg_reduced_set_coords(r, unknown, (size_t)m, next);
  free(next);
  return rc;
}

int npg_reduced_newton(NpgReduced *r, long sample, const char *residual, const char *unknown, NpgNewton *o) {
  API_REFUSE_NULL(r, NULL, 0, -1);
  REFUSE_NULL(o);
  if (!r->r || npg_reduced_error(r)[0]) return -1;
  const char *fn = __func__;
  int qr = derivative_quantity(r, fn, "residual", residual, false), qu;
  if (qr < 0 || (qu = derivative_quantity(r, fn, "unknown", unknown, true)) < 0) return -1;
  long m = coords_of(r, qu);
  if (coords_of(r, qr) != m)
    return rfail(r, "%s: residual '%s' has %ld reduced coordinates and unknown '%s' %ld: a Newton step needs them in "
                    "one basis (share %s, %s)", fn, residual, coords_of(r, qr), unknown, m, residual, unknown);
  if (!(o->tol > 0) || !isfinite(o->tol)) return rfail(r, "%s: tolerance %g: it must be positive and finite", fn, o->tol);
  if (o->max_iter < 1) return rfail(r, "%s: max_iter %d: at least one iteration", fn, o->max_iter);
  if (!(o->rtol >= 0) || !isfinite(o->rtol))
    return rfail(r, "%s: relative tolerance %g: it must be 0 or positive and finite", fn, o->rtol);
  double tol = o->tol;
  double *J = malloc(sizeof(double) * (size_t)(m * m + 1)), *rhs = malloc(sizeof(double) * (size_t)(m + 1));
  int rc = -1;
  o->iterations = 0, o->residual = NAN;
  if (!J || !rhs) {
    rfail(r, "%s: out of memory", fn);
    goto done;
  }
  for (int it = 0;; it++) {
    if (eval_for_derivative(r, sample)) goto done;
    const double *res = npg_reduced_coords(r, residual, NULL);
    double nr = norm2(res, m);
    o->iterations = it, o->residual = nr;
    if (o->history && it < o->history_cap) o->history[it] = nr;
    if (o->verbose) fprintf(o->verbose, "newton sample %ld iteration %d: |%s| = %.3e\n", sample, it, residual, nr);
    if (!isfinite(nr)) {
      rfail(r, "%s: sample %ld, iteration %d: residual '%s' is not finite", fn, sample, it, residual);
      goto done;
    }
    if (it == 0) tol = fmax(o->tol, o->rtol * nr);
    if (nr <= tol) break;
    if (it == o->max_iter) {
      rfail(r, "%s: Newton on residual '%s' for '%s' did not converge at sample %ld: iteration %d, residual %.3e "
               "(tolerance %.3e)", fn, residual, unknown, sample, it, nr, tol);
      goto done;
    }
    memcpy(rhs, res, sizeof(double) * (size_t)m);
    if (newton_update(r, fn, sample, residual, unknown, it, J, rhs, m)) goto done;
  }
  rc = 0;
done:
  free(J);
  free(rhs);
  return rc;
}
