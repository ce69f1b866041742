/* bench_shapes.c — npg's default full evaluator against hand-written C (bench/shapes_hand.c,
 * -O3 -march=native) on two shapes of program, one thread, in the same run:
 *   - a stencil with `if` guards: one explicit step of the nonlinear heat equation
 *     (examples/heat/heat.npg) on an n x n grid (default 128);
 *   - a gather over a pair list: softened inverse-square forces of n-body pairs
 *     (bench/nbody_pairs.npg), N points each paired with K random others (default 4096, 16).
 * The third shape, a sparse operator against CHOLMOD by hand, is bench_sparse.
 *
 *     build/bench_shapes [n [N [K [reps]]]]
 *
 * Per shape: the backend NPG_AUTO chose, median (best) seconds of `reps` evaluations
 * (npg_full_eval; for heat also npg_full_step, whose per-step checks a rollout pays) and of the
 * hand-written peer, their ratio, and the largest difference of the results (relative to the
 * largest value). Figures, not pass/fail. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "npg.h"
#include "shapes_hand.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* Median and best of `reps` calls of fn(ctx). */
typedef struct Timing {
  double median, best;
} Timing;

static Timing timed(void (*fn)(void *), void *ctx, int reps) {
  double *t = malloc(sizeof(double) * (size_t)reps);
  fn(ctx); /* warm: buffers touched, caches filled */
  for (int r = 0; r < reps; r++) {
    double t0 = now();
    fn(ctx);
    t[r] = now() - t0;
  }
  qsort(t, (size_t)reps, sizeof *t, cmp);
  Timing out = {t[reps / 2], t[0]};
  free(t);
  return out;
}

static void die(const char *what, const char *msg) {
  fprintf(stderr, "bench_shapes: %s: %s\n", what, msg);
  exit(1);
}

static double max_rel_diff(const double *a, const double *b, long n) {
  double d = 0, big = 0;
  for (long i = 0; i < n; i++) d = fmax(d, fabs(a[i] - b[i])), big = fmax(big, fabs(b[i]));
  return big > 0 ? d / big : d;
}

static void row(const char *name, Timing npg, Timing hand, double diff) {
  printf("%-34s %10.1f (%8.1f) %10.1f (%8.1f) %7.2fx (%5.2fx) %9.2g\n", name, 1e6 * npg.median, 1e6 * npg.best,
         1e6 * hand.median, 1e6 * hand.best, npg.median / hand.median, npg.best / hand.best, diff);
}

static NpgFull *evaluator(const char *path) {
  NpgOptions o = {0};
  NpgProgram *p = npg_compile(path, &o);
  if (!npg_ok(p)) die(path, npg_error(p));
  NpgFull *f = npg_full_new(p, NPG_AUTO);
  NpgJitInfo ji;
  if (npg_full_jit_info(f, &ji) != 0) die(path, npg_full_error(f));
  printf("%s: backend %s (compile and load %.3f s%s)\n", path, npg_backend_name(ji.backend), ji.compile_seconds,
         ji.cache == 1 ? ", from the cache" : "");
  return f;
}

/* ---------------------------------------------------------------- heat: a stencil with if guards */

typedef struct Heat {
  NpgFull *f;
  long n, steps;
  int *nbr;
  double dt, *u0, *u, *v;
} Heat;

static void heat_npg_eval(void *c) {
  Heat *h = c;
  if (npg_full_eval(h->f, 0) != 0) die("heat", npg_full_error(h->f));
}

static void heat_hand_eval(void *c) {
  Heat *h = c;
  hand_heat_step(h->n, h->nbr, h->dt, h->u0, h->v);
}

static void heat_npg_steps(void *c) {
  Heat *h = c;
  if (npg_full_step(h->f, h->steps, 0) != 0) die("heat", npg_full_error(h->f));
}

static void heat_hand_steps(void *c) {
  Heat *h = c;
  for (long t = 0; t < h->steps; t++) {
    hand_heat_step(h->n, h->nbr, h->dt, h->u, h->v);
    double *w = h->u;
    h->u = h->v, h->v = w;
  }
}

static void bench_heat(long side, int reps) {
  Heat h = {.f = evaluator("examples/heat/heat.npg"), .n = side * side, .steps = 20, .dt = 0.2};
  h.nbr = malloc(sizeof(int) * 4 * (size_t)h.n);
  double *nb = malloc(sizeof(double) * 4 * (size_t)h.n);
  h.u0 = malloc(sizeof(double) * (size_t)h.n), h.u = malloc(sizeof(double) * (size_t)h.n);
  h.v = malloc(sizeof(double) * (size_t)h.n);
  for (long i = 0; i < side; i++)
    for (long j = 0; j < side; j++) {
      long c = i * side + j;
      long nbrs[4] = {i > 0 ? c - side : -1, i + 1 < side ? c + side : -1, j > 0 ? c - 1 : -1,
                      j + 1 < side ? c + 1 : -1};
      for (int k = 0; k < 4; k++) h.nbr[4 * c + k] = (int)nbrs[k], nb[4 * c + k] = (double)nbrs[k];
      double x = (i + 0.5) / side - 0.5, y = (j + 0.5) / side - 0.5;
      h.u0[c] = exp(-20 * (x * x + y * y));
    }
  long sn[2] = {h.n, 4}, su[1] = {h.n};
  if (npg_full_set_param(h.f, "nbr", 2, sn, nb, "nbr") || npg_full_set_param(h.f, "dt", 0, NULL, &h.dt, "dt") ||
      npg_full_set(h.f, "u", 1, su, h.u0, "u"))
    die("heat", npg_full_error(h.f));
  /* one step each: the results compared */
  if (npg_full_step(h.f, 1, 0) != 0) die("heat", npg_full_error(h.f));
  hand_heat_step(h.n, h.nbr, h.dt, h.u0, h.v);
  double diff = max_rel_diff(npg_full_get(h.f, "u", NULL), h.v, h.n);
  npg_full_set(h.f, "u", 1, su, h.u0, "u");
  Timing ne = timed(heat_npg_eval, &h, reps), he = timed(heat_hand_eval, &h, reps);
  char name[96];
  snprintf(name, sizeof name, "heat %ldx%ld, one evaluation", side, side);
  row(name, ne, he, diff);
  memcpy(h.u, h.u0, sizeof(double) * (size_t)h.n);
  npg_full_set(h.f, "u", 1, su, h.u0, "u");
  Timing ns = timed(heat_npg_steps, &h, reps), hs = timed(heat_hand_steps, &h, reps);
  ns.median /= h.steps, ns.best /= h.steps, hs.median /= h.steps, hs.best /= h.steps;
  snprintf(name, sizeof name, "heat %ldx%ld, a step of npg_full_step", side, side);
  row(name, ns, hs, NAN);
  npg_full_free(h.f);
  free(h.nbr), free(nb), free(h.u0), free(h.u), free(h.v);
}

/* ---------------------------------------------------------------- n-body pairs: a gather */

typedef struct Pairs {
  NpgFull *f;
  long P;
  int *a, *b;
  double eps, *x, *out;
} Pairs;

static void pairs_npg(void *c) {
  Pairs *p = c;
  if (npg_full_eval(p->f, 0) != 0) die("pairs", npg_full_error(p->f));
}

static void pairs_hand(void *c) {
  Pairs *p = c;
  hand_pair_forces(p->P, p->a, p->b, p->eps, p->x, p->out);
}

static void bench_pairs(long N, long K, int reps) {
  Pairs p = {.f = evaluator("bench/nbody_pairs.npg"), .P = N * K, .eps = 1e-3};
  p.a = malloc(sizeof(int) * (size_t)p.P), p.b = malloc(sizeof(int) * (size_t)p.P);
  double *da = malloc(sizeof(double) * (size_t)p.P), *db = malloc(sizeof(double) * (size_t)p.P);
  p.x = malloc(sizeof(double) * 3 * (size_t)N), p.out = malloc(sizeof(double) * 3 * (size_t)p.P);
  unsigned long s = 12345;
  for (long i = 0; i < 3 * N; i++) {
    s = s * 6364136223846793005UL + 1442695040888963407UL;
    p.x[i] = (double)(s >> 11) / 9007199254740992.0;
  }
  for (long i = 0; i < N; i++)
    for (long k = 0; k < K; k++) {
      s = s * 6364136223846793005UL + 1442695040888963407UL;
      long j = (long)((s >> 33) % (unsigned long)(N - 1));
      if (j >= i) j++;
      p.a[i * K + k] = (int)i, p.b[i * K + k] = (int)j, da[i * K + k] = (double)i, db[i * K + k] = (double)j;
    }
  long sp[1] = {p.P}, sx[2] = {N, 3};
  if (npg_full_set_param(p.f, "a", 1, sp, da, "a") || npg_full_set_param(p.f, "b", 1, sp, db, "b") ||
      npg_full_set_param(p.f, "eps", 0, NULL, &p.eps, "eps") || npg_full_set(p.f, "x", 2, sx, p.x, "x") ||
      npg_full_eval(p.f, 0) != 0)
    die("pairs", npg_full_error(p.f));
  pairs_hand(&p);
  double diff = max_rel_diff(npg_full_get(p.f, "f", NULL), p.out, 3 * p.P);
  Timing n = timed(pairs_npg, &p, reps), h = timed(pairs_hand, &p, reps);
  char name[96];
  snprintf(name, sizeof name, "n-body pairs N=%ld, P=%ld", N, p.P);
  row(name, n, h, diff);
  npg_full_free(p.f);
  free(p.a), free(p.b), free(da), free(db), free(p.x), free(p.out);
}

int main(int argc, char **argv) {
  long side = argc > 1 ? atol(argv[1]) : 128, N = argc > 2 ? atol(argv[2]) : 4096, K = argc > 3 ? atol(argv[3]) : 16;
  int reps = argc > 4 ? atoi(argv[4]) : 200;
  if (side < 2 || N < 2 || K < 1 || reps < 1) {
    fputs("usage: bench_shapes [n >= 2 [N >= 2 [K >= 1 [reps >= 1]]]]\n", stderr);
    return 2;
  }
  printf("%-34s %21s %21s %16s %9s\n", "", "npg, µs: median (best)", "hand-written C", "npg / hand", "max diff");
  bench_heat(side, reps);
  bench_pairs(N, K, reps);
  puts("sparse operator (heat at 1e5 cells) against CHOLMOD by hand: build/bench_sparse 316");
  return 0;
}
