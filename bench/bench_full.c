/* bench_full.c — the generated full evaluator of the radiosity form factors
 * (bench/formfactors.npg) against hand-written C (bench/ff_hand.c, -O3
 * -march=native) in the same run, for F = 500, 1000, 2000; and the time from
 * .npg source to a callable evaluator through libtcc and through cc, compiled
 * (the cache off: NPG_CACHE_MAX=0) and loaded from the cache of compiled
 * evaluators (a folder of its own under TMPDIR); which of the two the
 * default (NPG_AUTO) is.
 *
 *     build/bench_full [reps]
 *
 * Prints figures, not pass/fail. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "ff_hand.h"
#include "meshgen.h"
#include "npg.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static const char *PROG = "bench/formfactors.npg";

static NpgFull *evaluator(NpgProgram *p, NpgBackend b, const Mesh *m, const double *v) {
  NpgFull *f = npg_full_new(p, b);
  double *t = malloc(sizeof(double) * (size_t)m->F * 3);
  for (long i = 0; i < m->F * 3; i++) t[i] = m->tri[i];
  long st[2] = {m->F, 3}, sg[2] = {m->V, 3}, sv[2] = {m->F, m->F};
  npg_full_set_param(f, "tri", 2, st, t, "tri");
  npg_full_set(f, "g", 2, sg, m->g, "g");
  npg_full_set(f, "v", 2, sv, v, "v");
  free(t);
  if (npg_full_eval(f, 0) != 0) {
    fprintf(stderr, "bench_full: %s\n", npg_full_error(f));
    exit(1);
  }
  return f;
}

static double timed_eval(NpgFull *f, int r) {
  double t0 = now();
  npg_full_eval(f, r);
  return now() - t0;
}

int main(int argc, char **argv) {
  int reps = argc > 1 ? atoi(argv[1]) : 5;
  if (reps < 1) reps = 1;
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";

  /* Source to callable: parse, check, lower, emit, compile, relocate. */
  double best_tcc = 1e30, best_cc = 1e30;
  for (int r = 0; r < 20; r++) {
    double t0 = now();
    NpgProgram *p = npg_compile(PROG, &opt);
    NpgFull *f = npg_full_new(p, NPG_TCC);
    double t1 = now();
    if (!npg_ok(p) || npg_full_error(f)[0]) {
      fprintf(stderr, "bench_full: %s%s\n", npg_error(p), npg_full_error(f));
      return 1;
    }
    best_tcc = fmin(best_tcc, t1 - t0);
    npg_full_free(f);
    npg_free(p);
  }
  /* cc: a cache of its own, so the first compile is a miss and the rest are hits */
  char cache[256];
  const char *tmp = getenv("TMPDIR");
  snprintf(cache, sizeof cache, "%s/npg-bench-full-XXXXXX", tmp && *tmp ? tmp : "/tmp");
  if (!mkdtemp(cache)) {
    perror("bench_full: mkdtemp");
    return 1;
  }
  setenv("NPG_CACHE_DIR", cache, 1);
  double best_hit = 1e30;
  for (int r = 0; r < 23; r++) {
    if (r < 3) setenv("NPG_CACHE_MAX", "0", 1); /* compiled every time */
    else unsetenv("NPG_CACHE_MAX");
    double t0 = now();
    NpgProgram *p = npg_compile(PROG, &opt);
    NpgFull *f = npg_full_new(p, NPG_CC);
    double t = now() - t0;
    NpgJitInfo ji;
    if (npg_full_jit_info(f, &ji) != 0) {
      fprintf(stderr, "bench_full: %s\n", npg_full_error(f));
      return 1;
    }
    if (ji.cache == 1) best_hit = fmin(best_hit, t);
    else if (ji.cache == -1) best_cc = fmin(best_cc, t);
    npg_full_free(f);
    npg_free(p);
  }
  NpgProgram *pd = npg_compile(PROG, &opt);
  NpgFull *fd = npg_full_new(pd, NPG_AUTO);
  NpgJitInfo def;
  if (npg_full_jit_info(fd, &def) != 0) {
    fprintf(stderr, "bench_full: %s\n", npg_full_error(fd));
    return 1;
  }
  npg_full_free(fd);
  npg_free(pd);
  char rm[300];
  snprintf(rm, sizeof rm, "rm -rf '%s'", cache);
  if (system(rm) != 0) fprintf(stderr, "bench_full: could not remove %s\n", cache);
  printf("source to callable (%s, best): libtcc %.2f ms (goal < 20 ms); cc -O3 compiled %.0f ms, loaded from the "
         "cache %.2f ms (goal <= 5 ms)\n", PROG, 1e3 * best_tcc, 1e3 * best_cc, 1e3 * best_hit);
  printf("the default evaluator (NPG_AUTO, here): %s\n\n", def.backend == NPG_CC ? "cc" : "libtcc");

  printf("full evaluation of the form factors, best of %d (seconds; ratio = npg / hand-written)\n", reps);
  printf("  warm: each evaluator called %d times in a row (at F = 500 its 14 MB of outputs stay in L3)\n", reps);
  printf("  cold: the three called in turn, %d rounds (each evicts the others' outputs)\n", reps);
  printf("%6s %5s %12s %12s %8s %12s %8s %10s\n", "F", "cache", "hand -O3", "npg cc", "ratio", "npg libtcc", "ratio",
         "max rel diff");
  NpgProgram *p = npg_compile(PROG, &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    return 1;
  }
  long sizes[] = {500, 1000, 2000};
  for (int k = 0; k < 3; k++) {
    long F = sizes[k];
    Mesh m;
    char err[256];
    if (mesh_room(F, 0.5, &m, err, sizeof err)) {
      fprintf(stderr, "bench_full: %s\n", err);
      return 1;
    }
    size_t FF = (size_t)F * (size_t)F;
    double *v = malloc(sizeof(double) * FF);
    for (size_t i = 0; i < FF; i++) v[i] = 1;
    double *n = malloc(sizeof(double) * (size_t)F * 3), *s = malloc(sizeof(double) * FF), *r = malloc(sizeof(double) * FF),
           *h = malloc(sizeof(double) * FF), *c = malloc(sizeof(double) * FF), *d = malloc(sizeof(double) * FF),
           *a = malloc(sizeof(double) * (size_t)F), *pp = malloc(sizeof(double) * FF);
    ff_hand(F, m.V, m.g, m.tri, v, n, s, r, h, c, d, a, pp); /* warm up, fault the pages */
    NpgFull *fc = evaluator(p, NPG_CC, &m, v);
    NpgFull *ft = evaluator(p, NPG_TCC, &m, v);
    timed_eval(fc, 0); /* warm up */
    timed_eval(ft, 0);
    /* warm: back to back, outputs in cache when they fit; cold: in turn */
    double hand[2] = {1e30, 1e30}, tcc_cc[2] = {1e30, 1e30}, tcc_t[2] = {1e30, 1e30};
    for (int rep = 0; rep < reps; rep++) {
      double t0 = now();
      ff_hand(F, m.V, m.g, m.tri, v, n, s, r, h, c, d, a, pp);
      hand[0] = fmin(hand[0], now() - t0);
    }
    for (int rep = 0; rep < reps; rep++) tcc_cc[0] = fmin(tcc_cc[0], timed_eval(fc, rep));
    for (int rep = 0; rep < reps; rep++) tcc_t[0] = fmin(tcc_t[0], timed_eval(ft, rep));
    for (int rep = 0; rep < reps; rep++) {
      double t0 = now();
      ff_hand(F, m.V, m.g, m.tri, v, n, s, r, h, c, d, a, pp);
      hand[1] = fmin(hand[1], now() - t0);
      tcc_cc[1] = fmin(tcc_cc[1], timed_eval(fc, rep));
      tcc_t[1] = fmin(tcc_t[1], timed_eval(ft, rep));
    }
    const double *q = npg_full_get(fc, "p", NULL);
    double dn = 0, dd = 0;
    for (size_t i = 0; i < FF; i++) {
      dn = fmax(dn, fabs(q[i] - pp[i]));
      dd = fmax(dd, fabs(pp[i]));
    }
    for (int w = 0; w < 2; w++)
      printf("%6ld %5s %12.5f %12.5f %8.2f %12.5f %8.2f %10.1e\n", F, w ? "cold" : "warm", hand[w], tcc_cc[w],
             tcc_cc[w] / hand[w], tcc_t[w], tcc_t[w] / hand[w], dn / dd);
    npg_full_free(fc);
    npg_full_free(ft);
    free(v), free(n), free(s), free(r), free(h), free(c), free(d), free(a), free(pp);
    mesh_free(&m);
  }
  npg_free(p);
  return 0;
}
