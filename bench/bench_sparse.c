/* bench_sparse.c — the full evaluator of a sparse operator (bench/heat_spd.npg:
 * steady heat conduction on an n × n grid of cells, five entries a row,
 * symmetric positive definite) against a hand-written CHOLMOD program that
 * assembles the same matrix straight into compressed columns and solves it,
 * in the same run (DESIGN §13; the peer a user would write).
 *
 *     build/bench_sparse [--reps R] [n ...]   (default: 3 rounds; 100 316 1000, i.e. 1e4, 1e5, 1e6 cells)
 *     build/bench_sparse --crossover     sparse against dense below 1,000 cells
 *     build/bench_sparse --premul [n] [S] [cap]   pre-multiplication of the operator's tensors
 *
 * For each size: the first evaluation (pattern, symbolic analysis,
 * factorization, solve) and a repeated one with a new conductivity (values
 * refilled, refactorization, solve: the analysis reused), both for npg and
 * the peer, R rounds of each (a new evaluator and a new peer a round), best
 * and median in wall and in CPU time (the less disturbed on a shared
 * machine); their ratios; the two solutions' difference; the process's peak
 * memory after npg's first round (npg runs first; run one size a process
 * for the size's own peak). --premul trains the program on S conductivity
 * fields of many modes (so the bases reach `cap`), then pre-multiplies each
 * tensor of the sparse operator again alone, timed, with premultiply()'s
 * own flop count, against OpenBLAS dgemm's rate at the final GEMM's shape
 * measured in the same run. Prints figures, not pass/fail. */
#define _POSIX_C_SOURCE 200809L
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include <cblas.h>
#include <suitesparse/cholmod.h>

#include "compile.h"
#include "full.h"
#include "npg.h"
#include "train.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static double peak_gb(void) {
  struct rusage u;
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1e6; /* kB -> GB */
}

typedef struct Grid {
  long n, N;
  double *nbr;     /* N x 4, -1 padding (as doubles, for full_set_param) */
  long *inbr;
  double *src;
  double *kappa[2]; /* two samples */
} Grid;

static Grid grid(long n) {
  Grid g = {n, n * n, 0, 0, 0, {0, 0}};
  long N = g.N;
  g.nbr = malloc(sizeof(double) * (size_t)N * 4);
  g.inbr = malloc(sizeof(long) * (size_t)N * 4);
  g.src = malloc(sizeof(double) * (size_t)N);
  for (int s = 0; s < 2; s++) g.kappa[s] = malloc(sizeof(double) * (size_t)N);
  unsigned seed = 1u;
  for (long y = 0; y < n; y++)
    for (long x = 0; x < n; x++) {
      long i = y * n + x, nb[4] = {x > 0 ? i - 1 : -1, x < n - 1 ? i + 1 : -1, y > 0 ? i - n : -1, y < n - 1 ? i + n : -1};
      for (int k = 0; k < 4; k++) g.nbr[i * 4 + k] = (double)nb[k], g.inbr[i * 4 + k] = nb[k];
      g.src[i] = sin(0.01 * (double)i);
      for (int s = 0; s < 2; s++) {
        seed = seed * 1103515245u + 12345u;
        g.kappa[s][i] = 0.5 + ((seed >> 8) & 0xFFFF) / 65536.0;
      }
    }
  return g;
}

/* The peer: the matrix straight into CSC (upper triangle, which CHOLMOD's
 * stype 1 reads), cholmod_l_analyze once, factorize and solve. */
typedef struct Peer {
  cholmod_common cc;
  cholmod_sparse *A;
  cholmod_factor *L;
  double *u;
} Peer;

static void peer_fill(Peer *p, const Grid *g, const double *kappa) {
  SuiteSparse_long *Ap = p->A->p, *Ai = p->A->i;
  double *Ax = p->A->x;
  long at = 0;
  for (long j = 0; j < g->N; j++) {
    Ap[j] = at;
    /* column j, rows i <= j in increasing order: the lower neighbours, then j */
    long lower[2] = {g->inbr[j * 4 + 2], g->inbr[j * 4 + 0]}; /* j - n, j - 1 */
    double diag = 1;
    for (int k = 0; k < 4; k++)
      if (g->inbr[j * 4 + k] >= 0) diag += 0.5 * (kappa[j] + kappa[g->inbr[j * 4 + k]]);
    for (int k = 0; k < 2; k++)
      if (lower[k] >= 0) Ai[at] = lower[k], Ax[at++] = -0.5 * (kappa[j] + kappa[lower[k]]);
    Ai[at] = j, Ax[at++] = diag;
  }
  Ap[g->N] = at;
}

static double peer_solve(Peer *p, const Grid *g, const double *kappa, bool analyze) {
  double t0 = now();
  peer_fill(p, g, kappa);
  if (analyze) p->L = cholmod_l_analyze(p->A, &p->cc);
  cholmod_l_factorize(p->A, p->L, &p->cc);
  cholmod_dense *b = cholmod_l_zeros((size_t)g->N, 1, CHOLMOD_REAL, &p->cc);
  memcpy(b->x, g->src, sizeof(double) * (size_t)g->N);
  cholmod_dense *x = cholmod_l_solve(CHOLMOD_A, p->L, b, &p->cc);
  memcpy(p->u, x->x, sizeof(double) * (size_t)g->N);
  cholmod_l_free_dense(&b, &p->cc);
  cholmod_l_free_dense(&x, &p->cc);
  return now() - t0;
}

static Full *evaluator(NpgProgram *prog, const Grid *g, JitBackend backend, long min_rows) {
  Full *f = full_new(program_ir(prog), backend, NULL);
  long s2[2] = {g->N, 4}, s1[1] = {g->N};
  if (!f || full_set_param(f, "nbr", 2, s2, g->nbr, "nbr") || full_set_param(f, "src", 1, s1, g->src, "src")) {
    fprintf(stderr, "bench_sparse: %s\n", f ? full_error(f) : "out of memory");
    exit(1);
  }
  full_set_sparse_min_rows(f, min_rows);
  return f;
}

/* A timed call: wall time and the process's CPU time (on a machine shared
 * with other work the CPU time is the less disturbed of the two). */
typedef struct Spent {
  double wall, cpu;
} Spent;

static double cpu_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static Spent npg_solve(Full *f, const Grid *g, const double *kappa, long sample) {
  long s1[1] = {g->N};
  double t0 = now(), c0 = cpu_now();
  if (full_set(f, "kappa", 1, s1, kappa, "kappa") || full_eval(f, sample)) {
    fprintf(stderr, "bench_sparse: %s\n", full_error(f));
    exit(1);
  }
  return (Spent){now() - t0, cpu_now() - c0};
}

static Spent peer_timed(Peer *p, const Grid *g, const double *kappa, bool analyze) {
  double c0 = cpu_now(), w = peer_solve(p, g, kappa, analyze);
  return (Spent){w, cpu_now() - c0};
}

static int by_value(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* best and median of v[0 .. n) (v sorted in place) */
static void best_median(double *v, int n, double *best, double *median) {
  qsort(v, (size_t)n, sizeof *v, by_value);
  *best = v[0];
  *median = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

enum { NPG_FIRST, NPG_AGAIN, PEER_FIRST, PEER_AGAIN, MEASURES };

/* One size, `reps` rounds: each a new npg evaluator (created untimed: its
 * compile comes from the cache) evaluated twice, then a new peer (its CSC
 * allocated untimed) solving twice. Prints best and median of each, wall
 * and CPU, and the ratios of the bests and of the medians. */
static void one_size(NpgProgram *prog, long n, int reps) {
  Grid g = grid(n);
  double *t[2][MEASURES]; /* [wall | cpu][measure][rep] */
  for (int c = 0; c < 2; c++)
    for (int k = 0; k < MEASURES; k++) t[c][k] = malloc(sizeof(double) * (size_t)reps);
  double d = 0, s = 0, npg_peak = 0;
  long patterns = 0, chol = 0, lu = 0;
  for (int r = 0; r < reps; r++) {
    /* npg first, so the process's peak memory up to here is npg's (with the grid's data) */
    Full *f = evaluator(prog, &g, JIT_CC, FULL_SPARSE_MIN_ROWS);
    Spent a = npg_solve(f, &g, g.kappa[0], 0), b = npg_solve(f, &g, g.kappa[1], 1);
    if (r == 0) npg_peak = peak_gb();
    Peer p;
    cholmod_l_start(&p.cc);
    p.cc.supernodal = CHOLMOD_SUPERNODAL;
    p.A = cholmod_l_allocate_sparse((size_t)g.N, (size_t)g.N, (size_t)g.N * 3, 1, 1, 1, CHOLMOD_REAL, &p.cc);
    p.u = malloc(sizeof(double) * (size_t)g.N);
    Spent c = peer_timed(&p, &g, g.kappa[0], true), e = peer_timed(&p, &g, g.kappa[1], false);
    Spent all[MEASURES] = {a, b, c, e};
    for (int k = 0; k < MEASURES; k++) t[0][k][r] = all[k].wall, t[1][k][r] = all[k].cpu;
    size_t cnt;
    const double *u = full_get(f, "u", &cnt);
    for (long i = 0; i < g.N; i++) d = fmax(d, fabs(u[i] - p.u[i])), s = fmax(s, fabs(p.u[i]));
    full_sparse_counts(f, &patterns, &chol, &lu);
    full_free(f);
    cholmod_l_free_factor(&p.L, &p.cc);
    cholmod_l_free_sparse(&p.A, &p.cc);
    cholmod_l_finish(&p.cc);
    free(p.u);
  }
  printf("%9ld cells, %d rounds (max |du|/|u| %.1e; patterns %ld, CHOLMOD %ld, UMFPACK %ld in the last round; peak "
         "RSS after npg %.2f GB)\n",
         g.N, reps, s > 0 ? d / s : d, patterns, chol, lu, npg_peak);
  const char *clock[2] = {"wall", "cpu"};
  for (int c = 0; c < 2; c++) {
    double best[MEASURES], med[MEASURES];
    for (int k = 0; k < MEASURES; k++) best_median(t[c][k], reps, &best[k], &med[k]);
    printf("  %-4s best (median), s: npg first %.3f (%.3f), again %.3f (%.3f) | CHOLMOD by hand first %.3f (%.3f), "
           "again %.3f (%.3f) | ratio first %.2f (%.2f), again %.2f (%.2f)\n",
           clock[c], best[NPG_FIRST], med[NPG_FIRST], best[NPG_AGAIN], med[NPG_AGAIN], best[PEER_FIRST], med[PEER_FIRST],
           best[PEER_AGAIN], med[PEER_AGAIN], best[NPG_FIRST] / best[PEER_FIRST], med[NPG_FIRST] / med[PEER_FIRST],
           best[NPG_AGAIN] / best[PEER_AGAIN], med[NPG_AGAIN] / med[PEER_AGAIN]);
  }
  fflush(stdout);
  for (int c = 0; c < 2; c++)
    for (int k = 0; k < MEASURES; k++) free(t[c][k]);
  free(g.nbr), free(g.inbr), free(g.src), free(g.kappa[0]), free(g.kappa[1]);
}

/* Below which size the dense path (assembled whole, LAPACK) is faster:
 * the best of `reps` repeated evaluations each way, libtcc code. */
static void crossover(NpgProgram *prog) {
  printf("%9s %12s %12s %8s\n", "cells", "sparse (s)", "dense (s)", "dense/sparse");
  for (long n = 4; n <= 32; n += 2) {
    Grid g = grid(n);
    Full *sp = evaluator(prog, &g, JIT_TCC, 0), *de = evaluator(prog, &g, JIT_TCC, LONG_MAX);
    double bs = 1e30, bd = 1e30;
    for (int r = 0; r < 7; r++) {
      bs = fmin(bs, npg_solve(sp, &g, g.kappa[r & 1], r).wall);
      bd = fmin(bd, npg_solve(de, &g, g.kappa[r & 1], r).wall);
    }
    printf("%9ld %12.2e %12.2e %8.2f\n", g.N, bs, bd, bd / bs);
    full_free(sp), full_free(de);
    free(g.nbr), free(g.inbr), free(g.src), free(g.kappa[0]), free(g.kappa[1]);
  }
}

/* ---------------------------------------------------------------- pre-multiplication */

typedef struct Fields {
  const Grid *g;
  long S;
  double *kappa; /* S x N */
} Fields;

static int fields_set(void *user, Full *f, long k) {
  const Fields *fs = user;
  long s1[1] = {fs->g->N};
  return full_set(f, "kappa", 1, s1, fs->kappa + k * fs->g->N, "kappa");
}

/* GFLOP/s of C(M x N) += Aᵀ B (A: K x M), premul.c's final GEMM, best of 3. */
static double dgemm_gflops(int M, int N, int K) {
  double *A = malloc(sizeof(double) * (size_t)M * K), *B = malloc(sizeof(double) * (size_t)K * N);
  double *C = calloc((size_t)M * N, sizeof(double));
  for (long i = 0; i < (long)M * K; i++) A[i] = sin((double)i);
  for (long i = 0; i < (long)K * N; i++) B[i] = cos((double)i);
  double best = 1e30;
  for (int r = 0; r < 3; r++) {
    double t0 = now();
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, M, N, K, 1.0, A, M, B, N, 1.0, C, N);
    best = fmin(best, now() - t0);
  }
  free(A), free(B), free(C);
  return 2.0 * M * (double)N * K / best / 1e9;
}

static void premul_bench(NpgProgram *prog, long n, long S, int cap) {
  Grid g = grid(n);
  Fields fs = {&g, S, malloc(sizeof(double) * (size_t)S * (size_t)g.N)};
  /* 100 smooth modes with random weights: rank min(S, 100) fields */
  unsigned seed = 5u;
  enum { MODES = 100 };
  double fx[MODES], fy[MODES], ph[MODES], w[MODES];
  for (int q = 0; q < MODES; q++) {
    seed = seed * 1103515245u + 12345u, fx[q] = 1 + (seed >> 8) % 7;
    seed = seed * 1103515245u + 12345u, fy[q] = 1 + (seed >> 8) % 7;
    seed = seed * 1103515245u + 12345u, ph[q] = 6.28 * ((seed >> 8) & 0xFFFF) / 65536.0;
  }
  for (long k = 0; k < S; k++) {
    for (int q = 0; q < MODES; q++) seed = seed * 1103515245u + 12345u, w[q] = (((seed >> 8) & 0xFFFF) / 32768.0 - 1) / 10;
    for (long i = 0; i < g.N; i++) {
      double x = (double)(i % n) / (double)(n - 1), y = (double)(i / n) / (double)(n - 1), v = 1;
      for (int q = 0; q < MODES; q++) v += 0.8 * w[q] * sin(3.141592653589793 * fx[q] * x + ph[q]) * cos(3.141592653589793 * fy[q] * y);
      fs.kappa[k * g.N + i] = v;
    }
  }
  Full *f = evaluator(prog, &g, JIT_CC, FULL_SPARSE_MIN_ROWS);
  SampleSource src = {S, &fs, fields_set, NULL, NULL};
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = cap;
  opt_user.energy = 1.0;
  char err[2048] = "";
  double t0 = now();
  Model *m = train_model(program_ir(prog), f, &src, &opt, ERR_OF(err, sizeof err));
  if (!m) {
    fprintf(stderr, "bench_sparse: %s\n", err);
    exit(1);
  }
  printf("%ld cells, %ld samples, cap %d: trained in %.2f s\n", g.N, S, cap, now() - t0);
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    for (int t = 0; t < rs->nterms; t++)
      for (int k = 0; k < rs->terms[t].nops; k++) {
        ROp *op = &rs->terms[t].ops[k];
        if (op->op->kind != OPK_DECL) continue;
        const RClass *cy = &m->classes[m->qclass[rs->q]];
        for (int j = 0; j < op->ntensors; j++) {
          RTensor *x = &op->t[j];
          double *kept = x->data, fl = 0;
          x->data = NULL;
          double s0 = now();
          if (premultiply(m, f, x, &(PremulOut){.By = cy->B, .ny = cy->n, .my = cy->m}, &fl, ERR_OF(err, sizeof err))) {
            fprintf(stderr, "bench_sparse: %s\n", err);
            exit(1);
          }
          double sec = now() - s0, d = 0, sc = 0;
          for (long e = 0; e < x->rows * x->cols; e++) d = fmax(d, fabs(x->data[e] - kept[e])), sc = fmax(sc, fabs(kept[e]));
          free(kept);
          double peak = dgemm_gflops((int)x->rows, (int)x->cols, 2048);
          printf("  operator tensor %s: %ld x %ld (m_u = %ld), %.3g GFLOP in %.3f s = %.2f GFLOP/s; dgemm at "
                 "(%ld x %ld x 2048) %.2f GFLOP/s: %.2fx the dgemm-rate time (same as in training to %.1e)\n",
                 x->name, x->rows, x->cols, cy->m, fl / 1e9, sec, fl / sec / 1e9, x->rows, x->cols, peak,
                 (fl / sec / 1e9) > 0 ? peak / (fl / sec / 1e9) : 0, sc > 0 ? d / sc : d);
        }
      }
  }
  model_free(m);
  full_free(f);
  free(fs.kappa);
  free(g.nbr), free(g.inbr), free(g.src), free(g.kappa[0]), free(g.kappa[1]);
}

int main(int argc, char **argv) {
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  NpgProgram *prog = npg_compile("bench/heat_spd.npg", &opt);
  if (!npg_ok(prog)) {
    fprintf(stderr, "%s", npg_error(prog));
    return 1;
  }
  if (argc > 1 && strcmp(argv[1], "--crossover") == 0) {
    crossover(prog);
  } else if (argc > 1 && strcmp(argv[1], "--premul") == 0) {
    premul_bench(prog, argc > 2 ? strtol(argv[2], NULL, 10) : 316, argc > 3 ? strtol(argv[3], NULL, 10) : 120,
                 argc > 4 ? (int)strtol(argv[4], NULL, 10) : 60);
  } else {
    int reps = 3, at = 1, sized = 0;
    if (argc > 2 && strcmp(argv[1], "--reps") == 0) {
      char *end;
      long r = strtol(argv[2], &end, 10);
      if (*end || r < 1 || r > 1000) {
        fprintf(stderr, "bench_sparse: --reps '%s' is not a whole number of rounds from 1 to 1000\n", argv[2]);
        return 1;
      }
      reps = (int)r, at = 3;
    }
    for (int i = at; i < argc; i++) {
      char *end;
      long n = strtol(argv[i], &end, 10);
      if (*end || n < 2 || n > 100000) {
        fprintf(stderr, "bench_sparse: '%s' is not a grid size (cells a side, 2 to 100000)\n", argv[i]);
        return 1;
      }
      one_size(prog, n, reps), sized++;
    }
    long sizes[] = {100, 316, 1000};
    for (int i = 0; !sized && i < 3; i++) one_size(prog, sizes[i], reps);
  }
  npg_free(prog);
  return 0;
}
