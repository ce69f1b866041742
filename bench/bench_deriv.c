/* bench_deriv.c — what a derivative of the full evaluator costs (DESIGN §17, issue 43's
 * goals: a forward product within 3x of one full evaluation, a reverse product within 5x):
 * per program and size, random data (randdata.h, every dim of size N), the best of R
 * full evaluations, forward sweeps (all inputs' tangents set) and reverse sweeps (every
 * output's cotangent set), each sweep after an evaluation and timed alone, through the
 * backend given (cc by default), in the same run.
 *
 *     build/bench_deriv [--jit cc|tcc] [--reps R] [--jacobian] PROG.npg:N ...
 *
 * Prints figures, not pass/fail: t_eval, t_jvp, t_vjp and the ratios jvp/eval, vjp/eval;
 * with --jacobian (before the programs), the first output's Jacobian by the first input,
 * dense (npg_full_jacobian) against CSR on its pattern (npg_full_jacobian_csr), timed once. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "compile.h"
#include "full.h"
#include "npg.h"
#include "randdata.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Random data for every param and input, every dim of size n. */
static int bind(Full *f, const Program *prog, long n) {
  unsigned seed = 17u;
  for (int pass = 0; pass < 2; pass++) {
    const PtrVec *v = pass ? &prog->inputs : &prog->params;
    for (int i = 0; i < v->n; i++) {
      const Sym *s = v->v[i];
      long shape[MAX_AXES + MAX_STATIC];
      size_t count = 1;
      for (int a = 0; a < s->ndims; a++) shape[a] = n, count *= (size_t)n;
      for (int a = 0; a < s->nstatic; a++) shape[s->ndims + a] = s->shape[a], count *= (size_t)s->shape[a];
      double *x = malloc(sizeof(double) * (count ? count : 1));
      randdata_fill(&(RandData){.prog = prog, .n = n, .seed = &seed}, s, x, count);
      int rc = pass ? full_set(f, s->name, s->ndims + s->nstatic, shape, x, s->name)
                    : full_set_param(f, s->name, s->ndims + s->nstatic, shape, x, s->name);
      free(x);
      if (rc) return -1;
    }
  }
  return 0;
}

/* The same data into a public evaluator (npg_full_jacobian and npg_full_jacobian_csr). */
static int bind_public(NpgFull *f, const Program *prog, long n) {
  unsigned seed = 17u;
  for (int pass = 0; pass < 2; pass++) {
    const PtrVec *v = pass ? &prog->inputs : &prog->params;
    for (int i = 0; i < v->n; i++) {
      const Sym *s = v->v[i];
      long shape[MAX_AXES + MAX_STATIC];
      size_t count = 1;
      for (int a = 0; a < s->ndims; a++) shape[a] = n, count *= (size_t)n;
      for (int a = 0; a < s->nstatic; a++) shape[s->ndims + a] = s->shape[a], count *= (size_t)s->shape[a];
      double *x = malloc(sizeof(double) * (count ? count : 1));
      randdata_fill(&(RandData){.prog = prog, .n = n, .seed = &seed}, s, x, count);
      int rc = pass ? npg_full_set(f, s->name, s->ndims + s->nstatic, shape, x, s->name)
                    : npg_full_set_param(f, s->name, s->ndims + s->nstatic, shape, x, s->name);
      free(x);
      if (rc) return -1;
    }
  }
  return 0;
}

/* The Jacobian of the first output by the first input, dense (a product per column or
 * row) and on its pattern (a product per color). */
static int bench_jacobian(NpgProgram *p, const Program *prog, long n, JitBackend backend) {
  NpgFull *f = npg_full_new(p, backend == JIT_CC ? NPG_CC : NPG_TCC);
  const char *out = ((Sym *)prog->outputs.v[0])->name, *in = ((Sym *)prog->inputs.v[0])->name;
  size_t nout = 0, nin = 0;
  int rc = npg_full_error(f)[0] || bind_public(f, prog, n) || npg_full_eval(f, 0) ? -1 : 0;
  npg_full_get(f, out, &nout);
  npg_full_get(f, in, &nin);
  double *J = rc ? NULL : malloc(sizeof(double) * (nout * nin + 1));
  NpgCsr csr = {0};
  if (rc == 0) rc = npg_full_jacobian_csr(f, 0, out, in, &csr); /* warm: the derivative code compiled */
  npg_csr_free(&csr);
  double t0 = now();
  if (rc == 0) rc = npg_full_jacobian(f, 0, out, in, J);
  double t1 = now();
  if (rc == 0) rc = npg_full_jacobian_csr(f, 0, out, in, &csr);
  double t2 = now();
  if (rc == 0)
    printf("  jacobian %s by %s (%zu x %zu): dense %.3e s, CSR %.3e s (%ld entries, %.1fx faster)\n", out, in, nout,
           nin, t1 - t0, t2 - t1, csr.nnz, (t1 - t0) / (t2 - t1));
  else fprintf(stderr, "bench_deriv: %s\n", npg_full_error(f));
  npg_csr_free(&csr);
  free(J);
  npg_full_free(f);
  return rc;
}

/* Seeds the derivative arrays: every input's tangent (forward) or every output's cotangent. */
static int seed_arrays(Full *f, const Program *prog, bool forward) {
  double *const *d = full_deriv_arrays(f);
  if (!d) return -1;
  const PtrVec *v = forward ? &prog->inputs : &prog->outputs;
  for (int i = 0; i < v->n; i++) {
    int k = -1;
    for (int j = 0; j < prog->slots.n && k < 0; j++)
      if (prog->slots.v[j] == v->v[i]) k = j;
    size_t n = 0;
    full_get(f, ((Sym *)v->v[i])->name, &n);
    for (size_t e = 0; e < n; e++) d[k][e] = 1.0 / (double)(1 + e % 7);
  }
  return 0;
}

static int bench(const char *spec, JitBackend backend, int reps, bool jacobians) {
  char path[1024];
  snprintf(path, sizeof path, "%s", spec);
  char *colon = strrchr(path, ':');
  long n = colon ? atol(colon + 1) : 0;
  if (!colon || n <= 0) {
    fprintf(stderr, "bench_deriv: '%s': expected PROG.npg:N\n", spec);
    return 1;
  }
  *colon = 0;
  NpgProgram *p = npg_compile(path, NULL);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  const Program *prog = program_ir(p);
  Full *f = full_new(program_ir(p), backend, NULL);
  int rc = 1;
  if (full_error(f)[0] || bind(f, prog, n) || full_eval(f, 0)) goto done;
  double best[3] = {1e300, 1e300, 1e300};
  for (int r = 0; r < reps; r++) {
    double t0 = now();
    if (full_eval(f, 0)) goto done;
    double t1 = now();
    if (seed_arrays(f, prog, true)) goto done;
    double t2 = now();
    if (full_jvp(f, 0)) goto done;
    double t3 = now();
    if (seed_arrays(f, prog, false)) goto done;
    double t4 = now();
    if (full_vjp(f, 0)) goto done;
    double t5 = now();
    double t[3] = {t1 - t0, t3 - t2, t5 - t4};
    for (int k = 0; k < 3; k++) best[k] = t[k] < best[k] ? t[k] : best[k];
  }
  printf("%-40s N=%-5ld %-3s eval %.3e s  jvp %.3e s (%.2fx)  vjp %.3e s (%.2fx)\n", path, n,
         backend == JIT_CC ? "cc" : "tcc", best[0], best[1], best[1] / best[0], best[2], best[2] / best[0]);
  rc = jacobians && prog->outputs.n && prog->inputs.n ? bench_jacobian(p, prog, n, backend) : 0;
done:
  if (rc) fprintf(stderr, "bench_deriv: %s: %s\n", path, full_error(f));
  full_free(f);
  npg_free(p);
  return rc;
}

int main(int argc, char **argv) {
  JitBackend backend = JIT_CC;
  int reps = 5, rc = 0;
  bool jacobians = false;
  for (int i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--jit") == 0 && i + 1 < argc) {
      i++;
      backend = strcmp(argv[i], "tcc") == 0 ? JIT_TCC : JIT_CC;
    } else if (strcmp(argv[i], "--reps") == 0 && i + 1 < argc) reps = atoi(argv[++i]) > 0 ? atoi(argv[i]) : 1;
    else if (strcmp(argv[i], "--jacobian") == 0) jacobians = true;
    else rc |= bench(argv[i], backend, reps, jacobians);
  }
  return rc;
}
