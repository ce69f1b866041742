/* bench_restricted.c — what an out-of-core training pass costs: the whole
 * evaluation of the radiosity program (examples/radiosity/formfactors.npg,
 * the solve included) against a sweep of P restricted evaluations, each
 * computing one P-th of the rows of the pair quantities (full_eval_demand),
 * through libtcc and through cc -O3 -march=native, in the same run.
 *
 *     build/bench_restricted [F ...] [--passes P] [--reps R]
 *
 * Prints figures, not pass/fail: per F and backend the best whole
 * evaluation, the best sweep, and their ratio (a sweep of restricted passes
 * replaces P whole evaluations). */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "compile.h"
#include "full.h"
#include "meshgen.h"
#include "npg.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static const char *const PAIRS[] = {"s", "r", "h", "c", "d", "p"};

static Full *evaluator(NpgProgram *p, JitBackend b, const Mesh *m, const double *v) {
  Full *f = full_new(program_ir(p), b, NULL);
  long F = m->F;
  double *t = malloc(sizeof(double) * (size_t)F * 3), *rho = malloc(sizeof(double) * (size_t)F);
  double *e = malloc(sizeof(double) * (size_t)F);
  for (long i = 0; i < F * 3; i++) t[i] = m->tri[i];
  for (long i = 0; i < F; i++) rho[i] = 0.5, e[i] = (double)(i % 7) / 7.0;
  long st[2] = {F, 3}, sf[1] = {F}, sg[2] = {m->V, 3}, sv[2] = {F, F};
  if (full_set_param(f, "tri", 2, st, t, "tri") || full_set_param(f, "rho", 1, sf, rho, "rho") ||
      full_set(f, "g", 2, sg, m->g, "g") || full_set(f, "e", 1, sf, e, "e") ||
      full_set(f, "v", 2, sv, v, "v") || full_eval(f, 0)) {
    fprintf(stderr, "bench_restricted: %s\n", full_error(f));
    exit(1);
  }
  free(t), free(rho), free(e);
  return f;
}

/* One sweep: P restricted evaluations, pass k the rows [n k / P, n (k+1) / P)
 * of every pair quantity (as ooc.c cuts them). */
static double sweep(Full *f, const Program *prog, long P) {
  double t0 = now();
  size_t n = (size_t)full_dim(f, "F") * (size_t)full_dim(f, "F");
  for (long k = 0; k < P; k++) {
    Demand *d = full_demand(f);
    for (int q = 0; q < prog->quantities.n; q++) {
      const Sym *s = prog->quantities.v[q];
      for (size_t i = 0; i < sizeof PAIRS / sizeof *PAIRS; i++)
        if (strcmp(s->name, PAIRS[i]) == 0) demand_entries(d, s, n * (size_t)k / (size_t)P, n * (size_t)(k + 1) / (size_t)P);
    }
    if (full_eval_demand(f, k, d)) {
      fprintf(stderr, "bench_restricted: %s\n", full_error(f));
      exit(1);
    }
  }
  return now() - t0;
}

int main(int argc, char **argv) {
  long sizes[16], nsizes = 0, P = 8;
  int reps = 3;
  for (int i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--passes") == 0 && i + 1 < argc) P = atol(argv[++i]);
    else if (strcmp(argv[i], "--reps") == 0 && i + 1 < argc) reps = atoi(argv[++i]);
    else if (nsizes < 16) sizes[nsizes++] = atol(argv[i]);
  }
  if (!nsizes) sizes[nsizes++] = 524, sizes[nsizes++] = 1004;
  if (P < 1) P = 1;
  if (reps < 1) reps = 1;
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  NpgProgram *p = npg_compile("examples/radiosity/formfactors.npg", &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    return 1;
  }
  const Program *prog = program_ir(p);
  printf("radiosity (solve included), best of %d; a sweep is %ld restricted evaluations, each one %ld-th of the pair rows\n",
         reps, P, P);
  printf("%6s %8s %12s %12s %12s %14s\n", "F", "backend", "whole s", "sweep s", "sweep/whole", "P whole/sweep");
  for (long k = 0; k < nsizes; k++) {
    long F = sizes[k];
    Mesh m;
    char err[256];
    if (mesh_room(F, 0.5, &m, err, sizeof err)) {
      fprintf(stderr, "bench_restricted: %s\n", err);
      return 1;
    }
    double *v = malloc(sizeof(double) * (size_t)F * (size_t)F);
    for (long i = 0; i < F * F; i++) v[i] = 1;
    for (int b = 0; b < 2; b++) {
      Full *f = evaluator(p, b ? JIT_CC : JIT_TCC, &m, v);
      double whole = 1e30, sw = 1e30;
      for (int r = 0; r < reps; r++) {
        double t0 = now();
        full_eval(f, r);
        whole = fmin(whole, now() - t0);
        sw = fmin(sw, sweep(f, prog, P));
      }
      printf("%6ld %8s %12.4f %12.4f %12.2f %14.2f\n", F, b ? "cc -O3" : "libtcc", whole, sw, sw / whole,
             (double)P * whole / sw);
      full_free(f);
    }
    free(v);
    mesh_free(&m);
  }
  npg_free(p);
  return 0;
}
