/* bench_newton.c — a reduced Newton step against a reduced evaluation (issue 43's goal: the
 * Jacobian and its LAPACK solve in less than 2x one evaluation at m <= 60), same process.
 *
 *     bench_newton PROG.npg MODEL/ IN/ OUTPUT INPUT REPS
 *
 * Every input is set from sample 0 of IN/ (full values, projected). Timed, best and median over
 * REPS: one npg_reduced_eval; one npg_reduced_jacobian(OUTPUT, INPUT) (which evaluates first, as
 * a Newton iteration must); and a Newton step: that Jacobian, I − J formed and solved for one
 * right-hand side by LAPACKE_dgesv (OUTPUT and INPUT of one size, a state and its next value).
 * Prints `newton m=<m> eval_us=<median> jacobian_us=<median> solve_us=<median> step_us=<median>
 * ratio=<step/eval>`, solve_us the step's I − J and dgesv alone. */
#include <lapacke.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "npg.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

static double median(double *t, long n) {
  qsort(t, (size_t)n, sizeof *t, cmp);
  return t[n / 2];
}

int main(int argc, char **argv) {
  if (argc != 7) {
    fprintf(stderr, "usage: %s PROG.npg MODEL/ IN/ OUTPUT INPUT REPS\n", argv[0]);
    return 2;
  }
  const char *out = argv[4], *in = argv[5];
  long reps = atol(argv[6]);
  if (reps < 1) return fputs("bench_newton: REPS must be positive\n", stderr), 2;
  NpgProgram *p = npg_compile(argv[1], NULL);
  if (!npg_ok(p)) return fputs(npg_error(p), stderr), 1;
  NpgModel *m = npg_model_load(p, argv[2]);
  if (npg_model_error(m)[0]) return fprintf(stderr, "%s\n", npg_model_error(m)), 1;
  char err[2048];
  NpgSamples *s = npg_samples_open(p, argv[3], NULL, false, err, sizeof err);
  if (!s) return fprintf(stderr, "%s\n", err), 1;
  NpgReduced *r = npg_reduced_new(m);
  int n = npg_nsymbols(p);
  for (int i = 0; i < n; i++) {
    NpgSymbol sym;
    npg_symbol(p, i, &sym);
    if (sym.kind != NPG_INPUT) continue;
    size_t cnt;
    const double *v = npg_samples_get(s, sym.name, 0, &cnt);
    if (!v || npg_reduced_set(r, sym.name, cnt, v) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
  }
  if (npg_reduced_eval(r, 0) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
  size_t mo = 0, mi = 0;
  npg_reduced_coords(r, out, &mo);
  npg_reduced_coords(r, in, &mi);
  if (mo != mi || mo == 0)
    return fprintf(stderr, "bench_newton: OUTPUT '%s' (%zu coordinates) and INPUT '%s' (%zu) must be of one size\n",
                   out, mo, in, mi), 2;
  long mm = (long)mo;
  double *J = malloc(sizeof(double) * (size_t)(mm * mm)), *rhs = malloc(sizeof(double) * (size_t)mm);
  double *te = malloc(sizeof(double) * (size_t)reps), *tj = malloc(sizeof(double) * (size_t)reps);
  double *ts = malloc(sizeof(double) * (size_t)reps), *tv = malloc(sizeof(double) * (size_t)reps);
  lapack_int *piv = malloc(sizeof(lapack_int) * (size_t)mm);
  for (long k = -1; k < reps; k++) { /* -1 warms up */
    double t0 = now();
    if (npg_reduced_eval(r, 0) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
    double t1 = now();
    if (npg_reduced_jacobian(r, 0, out, in, J) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
    double t2 = now();
    if (npg_reduced_jacobian(r, 0, out, in, J) != 0) return fprintf(stderr, "%s\n", npg_reduced_error(r)), 1;
    double t2s = now();
    for (long a = 0; a < mm; a++) {
      for (long b = 0; b < mm; b++) J[a * mm + b] = (a == b) - J[a * mm + b];
      rhs[a] = 1;
    }
    if (LAPACKE_dgesv(LAPACK_ROW_MAJOR, (lapack_int)mm, 1, J, (lapack_int)mm, piv, rhs, 1) != 0)
      return fputs("bench_newton: I - J is singular\n", stderr), 1;
    double t3 = now();
    if (k >= 0) te[k] = (t1 - t0) * 1e6, tj[k] = (t2 - t1) * 1e6, ts[k] = (t3 - t2) * 1e6, tv[k] = (t3 - t2s) * 1e6;
  }
  double me = median(te, reps), mj = median(tj, reps), ms = median(ts, reps), mv = median(tv, reps);
  printf("newton m=%ld eval_us=%.2f jacobian_us=%.2f solve_us=%.2f step_us=%.2f ratio=%.2f\n", mm, me, mj, mv, ms,
         ms / me);
  npg_reduced_free(r);
  npg_samples_free(s);
  npg_model_free(m);
  npg_free(p);
  free(J), free(rhs), free(te), free(tj), free(ts), free(tv), free(piv);
  return 0;
}
