/* reduced_derivatives.c — derivatives of the reduced evaluator through
 * npg.h (DESIGN §17): npg_reduced_jvp, npg_reduced_vjp and
 * npg_reduced_jacobian in reduced coordinates, the signatures of the full
 * evaluator's npg_full_jvp, npg_full_vjp and npg_full_jacobian. Each
 * evaluates (npg_reduced_eval) and differentiates there (reduced_deriv.c). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

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
  return npg_reduced_eval(r, sample);
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
  if (reduced_jvp(r->r, nin, qs, directions, 1, qo, out, sample, err, sizeof err)) return rfail(r, "%s", err);
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
  if (reduced_vjp(r->r, nout, qs, cotangents, 1, qi, out, sample, err, sizeof err)) return rfail(r, "%s", err);
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
  if (reduced_jacobian(r->r, qo, qi, out, sample, err, sizeof err)) return rfail(r, "%s", err);
  return 0;
}
