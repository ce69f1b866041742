/* api_deriv.c — the derivatives of the full evaluator in npg.h (DESIGN §17):
 * npg_full_jvp, npg_full_vjp and npg_full_jacobian over full.h's full_jvp and full_vjp
 * (the generated C of backends/emit/emit_deriv.c). Each evaluates the program at the
 * inputs as bound, as npg_full_eval does, then differentiates it there; each checks
 * its arguments first and names the one it refuses. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"
#include "emit.h"

__attribute__((format(printf, 3, 4))) static int refuse(NpgFull *f, const char *func, const char *fmt, ...) {
  char why[400];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(why, sizeof why, fmt, ap);
  va_end(ap);
  api_refuse(NULL, 0, func, "%s", why);
  return full_refuse(f->full, api_refusal());
}

int api_full_slot(NpgFull *f, const char *func, const char *arg, const char *name, bool want_input) {
  const Program *prog = full_program(f->full);
  if (!name) return refuse(f, func, "argument '%s' is NULL", arg);
  for (int k = 0; prog && k < prog->slots.n; k++) {
    const Sym *s = prog->slots.v[k];
    if (strcmp(s->name, name) != 0) continue;
    if (want_input && s->kind != SYM_INPUT)
      return refuse(f, func, "argument '%s': '%s' is not an input of the program (derivatives are taken with "
                             "respect to inputs)", arg, name);
    if (s->kind == SYM_EXTERN || vec_position(&prog->temps, s) >= 0)
      return refuse(f, func, "argument '%s': '%s' is %s, not a quantity derivatives can be taken of", arg, name,
                    s->kind == SYM_EXTERN ? "an extern" : "inlined");
    return k;
  }
  return refuse(f, func, "argument '%s': the program has no quantity '%s'", arg, name);
}

/* Evaluate at the bound inputs, then the zeroed derivative arrays. */
static double *const *prepare(NpgFull *f, long sample) {
  if (full_eval(f->full, sample) != 0) return NULL;
  return full_deriv_arrays(f->full);
}

int npg_full_jvp(NpgFull *f, long sample, int nin, const char *const *inputs, const double *const *directions,
                 const char *output, double *out) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (nin < 0) return refuse(f, __func__, "argument 'nin' is %d (a count)", nin);
  if (nin > 0 && (!inputs || !directions)) return refuse(f, __func__, "argument '%s' is NULL", !inputs ? "inputs" : "directions");
  if (!out) return refuse(f, __func__, "argument 'out' is NULL");
  int ko = api_full_slot(f, __func__, "output", output, false);
  if (ko < 0) return -1;
  int *ki = calloc((size_t)nin + 1, sizeof *ki);
  if (!ki) return refuse(f, __func__, "out of memory");
  for (int i = 0; i < nin; i++)
    if ((ki[i] = api_full_slot(f, __func__, "inputs", inputs[i], true)) < 0 ||
        (!directions[i] && refuse(f, __func__, "argument 'directions': entry %d (for '%s') is NULL", i, inputs[i]))) {
      free(ki);
      return -1;
    }
  double *const *dq = prepare(f, sample);
  size_t n = 0;
  if (dq)
    for (int i = 0; i < nin; i++) {
      full_get(f->full, inputs[i], &n);
      for (size_t j = 0; j < n; j++) dq[ki[i]][j] += directions[i][j];
    }
  free(ki);
  if (!dq || full_jvp(f->full, sample) != 0) return -1;
  full_get(f->full, output, &n);
  memcpy(out, dq[ko], sizeof(double) * n);
  return 0;
}

int npg_full_vjp(NpgFull *f, long sample, int nout, const char *const *outputs, const double *const *cotangents,
                 const char *input, double *out) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (nout < 0) return refuse(f, __func__, "argument 'nout' is %d (a count)", nout);
  if (nout > 0 && (!outputs || !cotangents))
    return refuse(f, __func__, "argument '%s' is NULL", !outputs ? "outputs" : "cotangents");
  if (!out) return refuse(f, __func__, "argument 'out' is NULL");
  int ki = api_full_slot(f, __func__, "input", input, true);
  if (ki < 0) return -1;
  int *ko = calloc((size_t)nout + 1, sizeof *ko);
  if (!ko) return refuse(f, __func__, "out of memory");
  for (int i = 0; i < nout; i++)
    if ((ko[i] = api_full_slot(f, __func__, "outputs", outputs[i], false)) < 0 ||
        (!cotangents[i] && refuse(f, __func__, "argument 'cotangents': entry %d (for '%s') is NULL", i, outputs[i]))) {
      free(ko);
      return -1;
    }
  double *const *dq = prepare(f, sample);
  size_t n = 0;
  if (dq)
    for (int i = 0; i < nout; i++) {
      full_get(f->full, outputs[i], &n);
      for (size_t j = 0; j < n; j++) dq[ko[i]][j] += cotangents[i][j];
    }
  free(ko);
  if (!dq || full_vjp(f->full, sample) != 0) return -1;
  full_get(f->full, input, &n);
  memcpy(out, dq[ki], sizeof(double) * n);
  return 0;
}

/* The Jacobian by columns (one forward product per input entry) when the input has no
 * more entries than the output, else by rows (one reverse product per output entry). */
int npg_full_jacobian(NpgFull *f, long sample, const char *output, const char *input, double *out) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (!out) return refuse(f, __func__, "argument 'out' is NULL");
  int ko = api_full_slot(f, __func__, "output", output, false), ki = ko < 0 ? -1 : api_full_slot(f, __func__, "input", input, true);
  if (ko < 0 || ki < 0) return -1;
  if (!prepare(f, sample)) return -1;
  size_t nout = 0, nin = 0;
  full_get(f->full, output, &nout);
  full_get(f->full, input, &nin);
  bool columns = nin <= nout;
  for (size_t k = 0; k < (columns ? nin : nout); k++) {
    double *const *dq = full_deriv_arrays(f->full);
    if (!dq) return -1;
    dq[columns ? ki : ko][k] = 1.0;
    if ((columns ? full_jvp(f->full, sample) : full_vjp(f->full, sample)) != 0) return -1;
    if (columns)
      for (size_t r = 0; r < nout; r++) out[r * nin + k] = dq[ko][r];
    else memcpy(out + k * nin, dq[ki], sizeof(double) * nin);
  }
  return 0;
}

/* Greedy coloring of the columns of a pattern (rows × ncols, CSR): two columns that share
 * a row get different colors. color[ncols]; returns the number of colors, -1 out of memory. */
static long color_columns(long rows, long ncols, const long *ptr, const long *idx, long *color) {
  long *cptr = calloc((size_t)ncols + 2, sizeof(long)), *cidx = malloc(sizeof(long) * ((size_t)ptr[rows] + 1));
  long *mark = malloc(sizeof(long) * ((size_t)ncols + 1)), ncolors = 0;
  if (!cptr || !cidx || !mark) {
    free(cptr), free(cidx), free(mark);
    return -1;
  }
  for (long k = 0; k < ptr[rows]; k++) cptr[idx[k] + 2]++; /* the transpose: rows of each column */
  for (long j = 0; j < ncols; j++) cptr[j + 2] += cptr[j + 1];
  for (long r = 0; r < rows; r++)
    for (long k = ptr[r]; k < ptr[r + 1]; k++) cidx[cptr[idx[k] + 1]++] = r;
  for (long j = 0; j < ncols; j++) mark[j] = -1, color[j] = -1;
  for (long j = 0; j < ncols; j++) { /* colors of the columns sharing a row with j are taken */
    for (long a = cptr[j]; a < cptr[j + 1]; a++)
      for (long k = ptr[cidx[a]]; k < ptr[cidx[a] + 1]; k++)
        if (color[idx[k]] >= 0) mark[color[idx[k]]] = j;
    long c = 0;
    while (c < ncolors && mark[c] == j) c++;
    color[j] = c;
    if (c == ncolors) ncolors++;
  }
  free(cptr), free(cidx), free(mark);
  return ncolors;
}

void api_jac_plan_free(ApiJacPlan *p) {
  free(p->indptr), free(p->indices), free(p->color);
  memset(p, 0, sizeof *p);
}

int api_jac_plan(NpgFull *f, const char *output, const char *input, ApiJacPlan *p) {
  memset(p, 0, sizeof *p);
  size_t nout = 0, nin = 0;
  full_get(f->full, output, &nout);
  full_get(f->full, input, &nin);
  p->rows = (long)nout, p->cols = (long)nin;
  if (full_jacobian_pattern(f->full, output, input, &p->indptr, &p->indices) != 0) return -1;
  p->color = malloc(sizeof(long) * (nin + 1));
  p->ncolors = p->color ? color_columns(p->rows, p->cols, p->indptr, p->indices, p->color) : -1;
  if (p->ncolors < 0) {
    api_jac_plan_free(p);
    return full_fail(f->full, "out of memory");
  }
  return 0;
}

int api_jac_values(NpgFull *f, long sample, int ko, int ki, const ApiJacPlan *p, double *data) {
  const long *ptr = p->indptr, *idx = p->indices;
  for (long c = 0; c < p->ncolors; c++) {
    double *const *dq = full_deriv_arrays(f->full);
    if (!dq) return -1;
    for (long j = 0; j < p->cols; j++) dq[ki][j] = p->color[j] == c ? 1.0 : 0.0;
    if (full_jvp(f->full, sample) != 0) return -1;
    for (long r = 0; r < p->rows; r++) /* a row reads at most one column of each color */
      for (long k = ptr[r]; k < ptr[r + 1]; k++)
        if (p->color[idx[k]] == c) data[k] = ko == ki ? (idx[k] == r ? 1.0 : 0.0) : dq[ko][r];
  }
  return 0;
}

int npg_full_jacobian_csr(NpgFull *f, long sample, const char *output, const char *input, NpgCsr *out) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (!out) return refuse(f, __func__, "argument 'out' is NULL");
  memset(out, 0, sizeof *out);
  int ko = api_full_slot(f, __func__, "output", output, false);
  int ki = ko < 0 ? -1 : api_full_slot(f, __func__, "input", input, true);
  if (ko < 0 || ki < 0 || !prepare(f, sample)) return -1;
  ApiJacPlan p;
  if (api_jac_plan(f, output, input, &p) != 0) return -1;
  double *data = malloc(sizeof(double) * ((size_t)p.indptr[p.rows] + 1));
  int rc = data ? api_jac_values(f, sample, ko, ki, &p, data) : full_fail(f->full, "out of memory");
  if (rc != 0) {
    free(data);
    api_jac_plan_free(&p);
    return -1;
  }
  *out = (NpgCsr){p.rows, p.cols, p.indptr[p.rows], p.indptr, p.indices, data};
  free(p.color);
  return 0;
}
