/* bench_reduce.c — the reduction of the radiosity form factors
 * (bench/formfactors.npg) against peers measured in the same run:
 *
 *   1. pre-multiplication throughput (GFLOP/s, flops as premultiply()
 *      counts them) against OpenBLAS dgemm, square and at the
 *      pre-multiplication's own final-GEMM shapes; training split into
 *      snapshots, PCA and pre-multiplication;
 *   2. reduced evaluation (reduced_eval) against numpy running the same
 *      stage sequence on the same reduced tensors (bench/reduced_peer.py,
 *      reading the model_save() files), and against the bandwidth bound
 *      (bytes of reduced tensors / streaming bandwidth measured here);
 *   3. full evaluation (full_eval, cc and libtcc) against reduced
 *      evaluation, for F = 500, 1000, 2000.
 *
 *     build/bench_reduce [1] [2] [3] [F=500,1000] [S=64] [caps=10,20,40,60]
 *                        [F3=500,1000,2000] [S3=24] [C3=60] [keep] [rerun]
 *
 * Parts named run, none named: all three. F: part 1's face counts (the
 * first one is also part 2's); S: training samples of parts 1 and 2, cap
 * 60 per member there; caps: part 2's; F3, S3, C3: part 3's own models,
 * one per face count and cap per member (it also reuses the cap-60 models
 * of part 1); keep: leave part 2's model
 * directories in /tmp; rerun: pre-multiply every tensor a second time alone
 * (slow), not only the cheap ones. Run from the source root (it reads
 * bench/formfactors.npg, stdlib/ and bench/reduced_peer.py). Prints
 * figures, not pass/fail. */
#define _XOPEN_SOURCE 700
#include <cblas.h>
#include <ftw.h>
#include <lapacke.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "compile.h"
#include "meshgen.h"
#include "npg.h"
#include "reduced.h"
#include "train.h"

static const char *PROG = "bench/formfactors.npg";
static const char *PEER = "bench/reduced_peer.py";

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static void die(const char *what, const char *msg) {
  fprintf(stderr, "bench_reduce: %s: %s\n", what, msg);
  exit(1);
}

static void *xmalloc(size_t n) {
  void *p = malloc(n ? n : 1);
  if (!p) die("out of memory", "malloc");
  return p;
}

/* splitmix64: deterministic samples on every machine */
static double urand(uint64_t *s) {
  uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  z ^= z >> 31;
  return (double)(z >> 11) * 0x1.0p-53;
}

/* ---------------------------------------------------------------- samples: the deforming room
 *
 * mesh_room(F, t) deforms the room by one parameter t, and g is affine in
 * t: its snapshots have rank 2, and every stage a handful of significant
 * directions, so no class would come near a cap of 60. Every sample adds a
 * random combination of ROOM_MODES smooth displacement fields (products of
 * sines over the room, each along one axis) to the room at its t, so g has
 * ROOM_MODES + 2 independent directions and every class reaches its cap
 * once there are at least cap samples. Visibility stays 1 (as in
 * bench_full: a benchmark of the arithmetic, not of the lighting). */

#define ROOM_MODES 64
#define ROOM_AMP 0.1 /* metres, times a mean-zero sum of modes scaled by 1/sqrt(ROOM_MODES) */

typedef struct Room {
  long F, V, S;
  double *tri; /* F x 3, the param (ints as doubles) */
  double *g;   /* S x V x 3 */
  double *v;   /* F x F ones: the extern */
} Room;

static void room_make(Room *r, long F, long S, double t0, double dt, uint64_t seed) {
  char err[256];
  Mesh ref;
  if (mesh_room(F, 0.0, &ref, err, sizeof err)) die("mesh_room", err);
  r->F = F, r->V = ref.V, r->S = S;
  r->tri = xmalloc(sizeof(double) * (size_t)(3 * F));
  for (long i = 0; i < 3 * F; i++) r->tri[i] = ref.tri[i];
  r->g = xmalloc(sizeof(double) * (size_t)(S * r->V * 3));
  r->v = xmalloc(sizeof(double) * (size_t)(F * F));
  for (long i = 0; i < F * F; i++) r->v[i] = 1;
  /* the modes: the same fields for every sample set */
  uint64_t ms = 12345;
  int dir[ROOM_MODES];
  double k[ROOM_MODES][3], ph[ROOM_MODES][3];
  const double L[3] = {5.0, 4.0, 3.0};
  for (int j = 0; j < ROOM_MODES; j++) {
    dir[j] = j % 3;
    for (int d = 0; d < 3; d++) k[j][d] = M_PI * (1.0 + floor(3.0 * urand(&ms))) / L[d], ph[j][d] = 2 * M_PI * urand(&ms);
  }
  for (long s = 0; s < S; s++) {
    Mesh mk;
    if (mesh_room(F, t0 + dt * (double)s, &mk, err, sizeof err)) die("mesh_room", err);
    double a[ROOM_MODES];
    for (int j = 0; j < ROOM_MODES; j++) a[j] = (2 * urand(&seed) - 1) * ROOM_AMP / sqrt((double)ROOM_MODES);
    double *gs = r->g + s * r->V * 3;
    for (long v = 0; v < r->V; v++) {
      const double *x = ref.g + 3 * v;
      for (int d = 0; d < 3; d++) gs[3 * v + d] = mk.g[3 * v + d];
      for (int j = 0; j < ROOM_MODES; j++)
        gs[3 * v + dir[j]] += a[j] * sin(k[j][0] * x[0] + ph[j][0]) * sin(k[j][1] * x[1] + ph[j][1]) *
                              sin(k[j][2] * x[2] + ph[j][2]);
    }
    mesh_free(&mk);
  }
  mesh_free(&ref);
}

static void room_free(Room *r) {
  free(r->tri), free(r->g), free(r->v);
  memset(r, 0, sizeof *r);
}

static void room_bind(const Room *r, Full *f) {
  long st[2] = {r->F, 3};
  if (full_set_param(f, "tri", 2, st, r->tri, "tri")) die("bind tri", full_error(f));
}

static int room_set(void *user, Full *f, long k) {
  const Room *r = user;
  long sg[2] = {r->V, 3}, sv[2] = {r->F, r->F};
  return full_set(f, "g", 2, sg, r->g + k * r->V * 3, "g") || full_set(f, "v", 2, sv, r->v, "v");
}

/* ---------------------------------------------------------------- training, its phases timed
 *
 * By training itself: its phases (Model.phase_seconds: snapshots, bases,
 * pre-multiplication, externs) and each tensor's pre-multiplication
 * (RTensor.premul_seconds). Stamping the progress bar's updates instead
 * missed the updates it skips (at most ten a second): at F = 500 tensors
 * read an unset stamp, -3645.694 s and 3649.949 s (the monotonic clock). */

/* Visit every reduced tensor of a model in training order, with its stage. */
#define FOR_STAGE_TENSORS(m, rs, x)                                                    \
  for (int i_ = 0; i_ < (m)->nstages; i_++)                                         \
    for (RStage *rs = &(m)->stages[i_]; rs; rs = NULL)                              \
      for (int t_ = 0; t_ < rs->nterms; t_++)                                       \
        for (RTerm *rt_ = &rs->terms[t_]; rt_; rt_ = NULL)                          \
          for (int k_ = -1; k_ < rt_->nops; k_++)                                   \
            for (int g_ = 0; g_ < (k_ < 0 ? rt_->nnum : rt_->ops[k_].ntensors); g_++) \
              for (RTensor *x = k_ < 0 ? &rt_->num[g_] : &rt_->ops[k_].t[g_]; x; x = NULL)

typedef struct TensorRun {
  RTensor *t;
  const char *stage;
  long entries, keys;   /* streamed by the builder; distinct output keys */
  double flops;         /* premul.c's count, from entries and keys */
  double seconds;       /* in training (RTensor.premul_seconds) */
  double rerun_seconds; /* the re-run alone, NAN if not re-run */
  double rerun_flops;   /* premultiply()'s own count on the re-run */
  long keys_per_block;
} TensorRun;

typedef struct Trained {
  long F, S;
  int cap;
  Room room;
  Full *f; /* the training evaluator (cc), bound to the room */
  Model *m;
  double t_train, t_snap, t_pca, t_premul;
  int nt;
  TensorRun runs[64];
  double premul_flops;
  double count_diff;  /* max relative difference, counted flops vs premultiply()'s on the re-runs */
  double rerun_diff;  /* max |re-run − trained| / max |trained| */
  int nrerun;
} Trained;


/* The builder's stream of one tensor, counted: entries, and keys as
 * premul.c makes them for a numerator or diagonal operator (a new key
 * whenever the row changes). */
typedef struct Count {
  long entries, keys, row;
} Count;

static int count_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  (void)col, (void)nin, (void)in, (void)coef;
  Count *c = user;
  if (c->entries++ == 0 || row != c->row) c->keys++;
  c->row = row;
  return 0;
}

/* premul.c's flops: one pending GEMM row per entry (2 · pre · last, pre ·
 * last = cols) and one final-GEMM column per key (2 · rows · cols). */
static double premul_flops(const RTensor *t, long entries, long keys) {
  return 2.0 * (double)t->cols * ((double)entries + (double)t->rows * (double)keys);
}

/* Re-run the pre-multiplication of one tensor alone: time, premultiply()'s
 * own flop count, and the largest difference from the trained tensor. */
static void rerun(Trained *tr, const RStage *rs, TensorRun *run) {
  Model *m = tr->m;
  RTensor *x = run->t;
  const RClass *cy = &m->classes[m->qclass[rs->q]];
  char err[1024];
  double *trained = x->data, fl = 0;
  x->data = NULL;
  double s0 = now();
  if (premultiply(m, tr->f, x, &(PremulOut){.By = cy->B, .ny = cy->n, .my = cy->m}, &fl, ERR_OF(err, sizeof err)))
    die("premultiply", err);
  run->rerun_seconds = now() - s0;
  run->rerun_flops = fl;
  double dn = 0, dd = 0;
  for (long e = 0; e < x->rows * x->cols; e++) {
    dn = fmax(dn, fabs(x->data[e] - trained[e]));
    dd = fmax(dd, fabs(trained[e]));
  }
  tr->rerun_diff = fmax(tr->rerun_diff, dd > 0 ? dn / dd : dn);
  tr->count_diff = fmax(tr->count_diff, fabs(fl - run->flops) / fmax(fl, 1));
  tr->nrerun++;
  free(trained);
}

/* Train on S samples of the room with F faces, every member capped at
 * `cap`. Every tensor's flops are counted; tensors of less than a GFLOP
 * (the first one always), or every
 * one with `rerun_all`, are pre-multiplied again alone, which checks the
 * count against premultiply()'s own. */
static Trained *train(NpgProgram *p, long F, long S, int cap, bool rerun_all) {
  Trained *tr = calloc(1, sizeof *tr);
  if (!tr) die("out of memory", "train");
  tr->F = F, tr->S = S, tr->cap = cap;
  room_make(&tr->room, F, S, 0.5 / (double)S, 1.0 / (double)S, 1000u + (uint64_t)F);
  tr->f = full_new(program_ir(p), JIT_CC, NULL);
  if (full_error(tr->f)[0]) die("npg_full_new", full_error(tr->f));
  room_bind(&tr->room, tr->f);
  SampleSource src = {S, &tr->room, room_set, NULL, NULL};
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = cap;
  opt_user.energy = 1.0; /* keep every direction up to the cap (and above 1e-10 σ_max) */
  char err[2048] = "";
  double t0 = now();
  tr->m = train_model(program_ir(p), tr->f, &src, &opt, ERR_OF(err, sizeof err));
  double t1 = now();
  if (!tr->m) die("train_model", err);
  tr->t_train = t1 - t0;
  tr->t_snap = tr->m->phase_seconds[0];  /* snapshots */
  tr->t_pca = tr->m->phase_seconds[1];   /* bases */
  tr->t_premul = tr->m->phase_seconds[2]; /* pre-multiplication */
  Model *m = tr->m;
  FOR_STAGE_TENSORS(m, rs, x) {
    TensorRun *run = &tr->runs[tr->nt];
    run->t = x;
    run->stage = rs->st->sym->name;
    run->keys_per_block = premul_keys_per_block(x);
    run->seconds = x->premul_seconds;
    if (!(run->seconds >= 0) || run->seconds > t1 - t0) die(x->name, "training timed its pre-multiplication wrongly");
    run->rerun_seconds = NAN;
    Count c = {0, 0, 0};
    NpgSink sink = {&c, count_entry, 0, 1, 0, 0}; /* every row */
    if (full_build(tr->f, x->builder, &sink)) die("full_build", full_error(tr->f));
    run->entries = c.entries, run->keys = c.keys;
    run->flops = premul_flops(x, c.entries, c.keys);
    tr->premul_flops += run->flops;
    if (x->kind == RT_DECL) die(x->name, "declared operators are not counted here");
    if (tr->nt == 0 || rerun_all || run->flops < 1e9) rerun(tr, rs, run);
    tr->nt++;
  }
  return tr;
}

static void trained_free(Trained *tr) {
  if (!tr) return;
  model_free(tr->m);
  full_free(tr->f);
  room_free(&tr->room);
  free(tr);
}

static void print_classes(const Model *m) {
  printf("    classes:");
  for (int c = 0; c < m->nclasses; c++) printf(" %s %ld", m->classes[c].label, m->classes[c].m);
  printf("\n");
}

/* ---------------------------------------------------------------- peers: dgemm, bandwidth */

static double *random_array(size_t n, uint64_t seed) {
  double *a = xmalloc(sizeof(double) * n);
  for (size_t i = 0; i < n; i++) a[i] = urand(&seed) - 0.5;
  return a;
}

/* GFLOP/s of C(MxN) += op(A) B(KxN), best of reps, row-major; op(A) = Aᵀ
 * (A is K x M) when `trans`, as premul.c's final GEMM. */
static double dgemm_gflops(bool trans, int M, int N, int K, double min_seconds) {
  double *A = random_array((size_t)M * (size_t)K, 1), *B = random_array((size_t)K * (size_t)N, 2);
  double *C = calloc((size_t)M * (size_t)N, sizeof(double));
  double best = 1e30, spent = 0;
  for (int r = 0; r < 3 || spent < min_seconds; r++) {
    double t0 = now();
    cblas_dgemm(CblasRowMajor, trans ? CblasTrans : CblasNoTrans, CblasNoTrans, M, N, K, 1.0, A, trans ? M : K, B, N,
                1.0, C, N);
    double t = now() - t0;
    best = fmin(best, t), spent += t;
  }
  free(A), free(B), free(C);
  return 2.0 * M * (double)N * K / best / 1e9;
}

/* Streaming read bandwidth (GB/s) over `bytes`, best of reps: OpenBLAS
 * dgemv (rows of 64 entries, the routine and threading of reduced_eval's
 * contractions) and a plain 8-accumulator sum (one thread). */
typedef struct Bandwidth {
  double gemv, sum;
} Bandwidth;

static Bandwidth bandwidth(size_t bytes, double min_seconds) {
  size_t n = bytes / sizeof(double) / 64 * 64;
  if (n < 64) n = 64;
  double *a = random_array(n, 3), x[64], y0 = 0;
  double *y = xmalloc(sizeof(double) * (n / 64));
  for (int i = 0; i < 64; i++) x[i] = 1.0 / (i + 1);
  Bandwidth bw;
  double best = 1e30, spent = 0;
  for (int r = 0; r < 3 || spent < min_seconds; r++) {
    double t0 = now();
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)(n / 64), 64, 1.0, a, 64, x, 1, 0.0, y, 1);
    double t = now() - t0;
    best = fmin(best, t), spent += t;
  }
  bw.gemv = (double)(n * sizeof(double)) / best / 1e9;
  best = 1e30, spent = 0;
  for (int r = 0; r < 3 || spent < min_seconds; r++) {
    double t0 = now(), s[8] = {0};
    for (size_t i = 0; i < n; i += 8)
      for (int k = 0; k < 8; k++) s[k] += a[i + k];
    double t = now() - t0;
    y0 += s[0] + s[1] + s[2] + s[3] + s[4] + s[5] + s[6] + s[7];
    best = fmin(best, t), spent += t;
  }
  bw.sum = (double)(n * sizeof(double)) / best / 1e9;
  if (y0 == 12345.678) printf("%g\n", y0 + y[0]); /* keep the sums */
  free(a), free(y);
  return bw;
}

static double bw_best(Bandwidth b) { return fmax(b.gemv, b.sum); }

/* The factorizations alone: best seconds of the LAPACK calls reduced_eval
 * makes for a root (dsytrd + dstedc, as apply_root) and for an inverse
 * (dpotrf + dpocon, as apply_inverse) on a random n × n SPD matrix with
 * a spread 0.9^k of eigenvalues, on one OpenBLAS thread: what those stages cost
 * before a single tensor byte is read. */
typedef struct Factor {
  double root, inverse;
} Factor;

static Factor factor_seconds(int n, double min_seconds) {
  Factor f = {0, 0};
  if (n < 1) return f;
  size_t nn = (size_t)n * (size_t)n;
  double *X = random_array(nn, 5), *A = calloc(nn, sizeof(double)), *M = xmalloc(sizeof(double) * nn);
  double *Z = xmalloc(sizeof(double) * nn), *d = xmalloc(sizeof(double) * (size_t)n);
  double *e = xmalloc(sizeof(double) * (size_t)n), *tau = xmalloc(sizeof(double) * (size_t)n);
  for (int k = 0; k < n; k++) /* A = Σ_k 0.9^k x_k x_kᵀ */
    cblas_dsyr(CblasRowMajor, CblasUpper, n, pow(0.9, k), &X[(size_t)k * n], 1, A, n);
  lapack_int lwork = 1 + 4 * n + n * n + 64 * n, liwork = 3 + 5 * n;
  double *work = xmalloc(sizeof(double) * (size_t)lwork);
  lapack_int *iwork = xmalloc(sizeof(lapack_int) * (size_t)liwork);
  int threads = openblas_get_num_threads();
  openblas_set_num_threads(1);
  for (int which = 0; which < 2; which++) {
    double best = 1e30, spent = 0;
    for (int r = 0; r < 3 || spent < min_seconds; r++) {
      memcpy(M, A, sizeof(double) * nn);
      double t0 = now(), rcond = 0;
      lapack_int info;
      if (which == 0) {
        info = LAPACKE_dsytrd_work(LAPACK_COL_MAJOR, 'L', n, M, n, d, e, tau, work, lwork);
        if (info == 0) info = LAPACKE_dstedc_work(LAPACK_COL_MAJOR, 'I', n, d, e, Z, n, work, lwork, iwork, liwork);
      } else {
        info = LAPACKE_dpotrf_work(LAPACK_COL_MAJOR, 'L', n, M, n);
        if (info == 0) info = LAPACKE_dpocon_work(LAPACK_COL_MAJOR, 'L', n, M, n, 1.0, &rcond, work, iwork);
      }
      double t = now() - t0;
      if (info != 0) die("factor_seconds", "LAPACK failed on the SPD test matrix");
      best = fmin(best, t), spent += t;
    }
    if (which == 0) f.root = best;
    else f.inverse = best;
  }
  openblas_set_num_threads(threads);
  free(X), free(A), free(M), free(Z), free(d), free(e), free(tau), free(work), free(iwork);
  return f;
}

/* ---------------------------------------------------------------- part 1 */

static void part1(Trained *tr, double square) {
  printf("\n  F = %ld, %ld samples, cap %d per member: trained in %.2f s\n", tr->F, tr->S, tr->cap, tr->t_train);
  print_classes(tr->m);
  printf("    snapshots %.2f s, PCA %.2f s, pre-multiplication %.2f s (extern fit and the rest: %.2f s)\n", tr->t_snap,
         tr->t_pca, tr->t_premul, tr->t_train - tr->t_snap - tr->t_pca - tr->t_premul);
  printf("    %-4s %-16s %4s %5s %5s %9s %8s %4s %8s %8s %7s %7s %6s\n", "stage", "tensor", "kind", "rows", "cols",
         "entries", "keys", "KB", "GFLOP", "seconds", "GFLOP/s", "dgemm", "ratio");
  double wt = 0; /* the flops at the dgemm rate of each tensor's final GEMM shape */
  for (int i = 0; i < tr->nt; i++) {
    const TensorRun *run = &tr->runs[i];
    const RTensor *x = run->t;
    double rate = run->flops / run->seconds / 1e9;
    double peer = dgemm_gflops(true, (int)x->rows, (int)x->cols, (int)run->keys_per_block, 0.2);
    wt += run->flops / (peer * 1e9);
    printf("    %-4s %-16s %4s %5ld %5ld %9.3g %8.3g %4ld %8.2f %8.3f %7.2f %7.2f %6.2f\n", run->stage, x->name,
           x->kind == RT_NUM ? "num" : x->kind == RT_DIAG ? "diag" : "decl", x->rows, x->cols, (double)run->entries,
           (double)run->keys, run->keys_per_block, run->flops / 1e9, run->seconds, rate, peer, rate / peer);
  }
  double secs = 0;
  for (int i = 0; i < tr->nt; i++) secs += tr->runs[i].seconds;
  double rate = tr->premul_flops / secs / 1e9, shaped = tr->premul_flops / wt / 1e9;
  printf("    total %.1f GFLOP in %.2f s: %.2f GFLOP/s\n", tr->premul_flops / 1e9, secs, rate);
  printf("    dgemm at each tensor's final-GEMM shape (rows x cols x KB): %.2f GFLOP/s, ratio %.2f; square dgemm "
         "%.2f GFLOP/s, ratio %.2f (goal >= 0.5)\n",
         shaped, rate / shaped, square, rate / square);
  printf("    flops counted from the builder's entries and keys; %d tensor(s) re-run alone: premultiply()'s count "
         "agrees to %.1e, the tensors to %.1e\n",
         tr->nrerun, tr->count_diff, tr->rerun_diff);
  for (int i = 0; i < tr->nt; i++)
    if (!isnan(tr->runs[i].rerun_seconds) && tr->runs[i].flops >= 1e9)
      printf("    re-run %-16s %.3f s (%.2f GFLOP/s) vs %.3f s in training\n", tr->runs[i].t->name,
             tr->runs[i].rerun_seconds, tr->runs[i].flops / tr->runs[i].rerun_seconds / 1e9, tr->runs[i].seconds);
}

/* ---------------------------------------------------------------- part 2: files for the numpy peer */

static void write_npy(const char *path, long rows, long cols, const double *x) {
  FILE *f = fopen(path, "wb");
  if (!f) die("cannot write", path);
  char hdr[128];
  int n = snprintf(hdr, sizeof hdr, "{'descr': '<f8', 'fortran_order': False, 'shape': (%ld, %ld), }", rows, cols);
  int total = 10 + n + 1;
  int pad = (64 - total % 64) % 64;
  unsigned short hl = (unsigned short)(n + pad + 1);
  fwrite("\x93NUMPY\x01\x00", 1, 8, f);
  fputc(hl & 0xff, f), fputc(hl >> 8, f);
  fwrite(hdr, 1, (size_t)n, f);
  for (int i = 0; i < pad; i++) fputc(' ', f);
  fputc('\n', f);
  fwrite(x, sizeof(double), (size_t)(rows * cols), f);
  fclose(f);
}

static const char *qname(const Model *m, int q) { return ((Sym *)m->prog->quantities.v[q])->name; }

/* DIR/layout: the stage sequence the reduced evaluator runs (reduced.c),
 * for the peer; DIR/in_<q>.npy the given coordinates, DIR/out_<q>.npy
 * every stage's result. */
static void write_peer_files(const Model *m, Reduced *r, const char *dir, double reps_seconds) {
  char path[4096];
  if (snprintf(path, sizeof path, "%s/layout", dir) >= (int)sizeof path) die("path too long", dir);
  FILE *f = fopen(path, "w");
  if (!f) die("cannot write", path);
  fprintf(f, "seconds %g\n", reps_seconds);
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = m->prog->quantities.v[q];
    bool given = s->kind == SYM_INPUT || s->kind == SYM_EXTERN;
    fprintf(f, "quantity %s %ld %s\n", s->name, m->classes[m->qclass[q]].m, given ? "given" : "stage");
    if (snprintf(path, sizeof path, "%s/%s_%s.npy", dir, given ? "in" : "out", s->name) >= (int)sizeof path)
      die("path too long", dir);
    write_npy(path, 1, m->classes[m->qclass[q]].m, reduced_coords(r, q));
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (rs->st->kind == ST_EXTERN) continue;
    fprintf(f, "stage %s\n", qname(m, rs->q));
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      fprintf(f, "term %s %s\n", rt->named_q >= 0 ? qname(m, rt->named_q) : "-", rt->proj_name ? rt->proj_name : "-");
      for (int k = -1; k < rt->nops; k++) {
        if (k >= 0) {
          const OpPow *op = rt->ops[k].op;
          fprintf(f, "op %s %ld %ld %d\n", op->kind == OPK_DIAG ? "diag" : "decl", op->p, op->q, rt->ops[k].spd);
        }
        int n = k < 0 ? rt->nnum : rt->ops[k].ntensors;
        for (int g = 0; g < n; g++) {
          const RTensor *x = k < 0 ? &rt->num[g] : &rt->ops[k].t[g];
          fprintf(f, "tensor %s %ld %ld", x->name, x->rows, x->cols);
          for (int j = 0; j < x->nin; j++) fprintf(f, " %s:%d:%ld", qname(m, x->in_q[j]), x->in_mult[j], x->in_len[j]);
          fprintf(f, "\n");
        }
      }
    }
  }
  fclose(f);
}

static int rm_entry(const char *path, const struct stat *sb, int flag, struct FTW *ftw) {
  (void)sb, (void)flag, (void)ftw;
  return remove(path);
}

/* best seconds per call of fn over at least `min_seconds` and 20 calls */
typedef int (*EvalFn)(void *);
static double best_of(EvalFn fn, void *arg, double min_seconds) {
  double best = 1e30, spent = 0;
  for (int r = 0; r < 20 || spent < min_seconds; r++) {
    double t0 = now();
    if (fn(arg)) return NAN;
    double t = now() - t0;
    best = fmin(best, t), spent += t;
  }
  return best;
}

static int eval_given(void *arg) { return reduced_eval(arg, 0); }

typedef struct StageCtx {
  Reduced *r;
  int i;
} StageCtx;

static int eval_stage(void *arg) {
  StageCtx *c = arg;
  return reduced_eval_stage(c->r, c->i, 0);
}

typedef struct PeerResult {
  double packed, full, diff_packed, diff_full;
  double bytes_packed, bytes_full;
} PeerResult;

static void copy_line(char *dst, size_t dstlen, const char *src) {
  size_t n = strlen(src) < dstlen ? strlen(src) : dstlen - 1;
  memcpy(dst, src, n);
  dst[n] = 0;
}

static bool run_peer(const char *dir, int threads, PeerResult *pr, char *stages, char *stages_full, size_t stageslen) {
  char cmd[2048], line[1024];
  snprintf(cmd, sizeof cmd, "OPENBLAS_NUM_THREADS=%d /usr/bin/python3 %s %s", threads, PEER, dir);
  FILE *p = popen(cmd, "r");
  if (!p) return false;
  bool ok = false;
  while (fgets(line, sizeof line, p))
    if (sscanf(line, "RESULT packed %lf %lf %lf full %lf %lf %lf", &pr->packed, &pr->diff_packed, &pr->bytes_packed,
               &pr->full, &pr->diff_full, &pr->bytes_full) == 6)
      ok = true;
    else if (strncmp(line, "STAGESFULL", 10) == 0) copy_line(stages_full, stageslen, line + 10);
    else if (strncmp(line, "STAGES", 6) == 0) copy_line(stages, stageslen, line + 6);
    else fputs(line, stdout);
  return pclose(p) == 0 && ok;
}

/* One side-by-side measurement at a number of OpenBLAS threads. */
typedef struct Part2Run {
  int threads;
  double c_seconds;
  PeerResult peer;
  bool peer_ok;
  char stages[512], peer_stages[512], peer_stages_full[512]; /* µs per stage, "n 1.2 s 3.4 ..." */
  double contract_seconds; /* npg, the contraction stages alone (sum of their best times) */
} Part2Run;

typedef struct Part2Row {
  int cap;
  long F, S;
  char classes[256];
  double bytes;
  Part2Run run[2]; /* OpenBLAS's default threads, and 1 */
  Bandwidth bw;    /* at the tensors' bytes */
  long m_root, m_inv; /* class sizes of the root stage p and the inverse stage h */
  Factor factor;      /* their LAPACK factorizations alone */
  double contract_bytes; /* bytes of the contraction stages' tensors */
  Bandwidth contract_bw;  /* streaming as many bytes */
  char contract_names[128];
  double root_exact, root_krylov; /* stage p alone, 1 thread: eigendecomposition, Lanczos */
  double root_steps, root_diff;   /* Lanczos steps per root, |p_krylov − p_exact| / |p_exact| */
  long root_fallbacks;
} Part2Row;

static void part2_row(Trained *tr, const char *base, bool keep, Part2Row *row) {
  Model *m = tr->m;
  char dir[1024], err[1024];
  row->cap = tr->cap, row->F = tr->F, row->S = tr->S;
  size_t len = 0;
  row->classes[0] = 0;
  for (int c = 0; c < m->nclasses; c++)
    len += (size_t)snprintf(row->classes + len, sizeof row->classes - len, "%s%ld", c ? "," : "", m->classes[c].m);
  snprintf(dir, sizeof dir, "%s/cap%d", base, tr->cap);
  if (model_save(m, dir, ERR_OF(err, sizeof err))) die("model_save", err);
  /* the given coordinates: a held-out deformation, and the visibility 1 */
  Room test;
  room_make(&test, tr->F, 1, 0.37, 0, 7u);
  Reduced *r = reduced_new(m, ERR_OF(err, sizeof err));
  if (!r) die("reduced_new", err);
  reduced_use_given_externs(r, true);
  int qg = -1, qv = -1, qp = -1, qh = -1;
  for (int q = 0; q < m->nq; q++) {
    if (strcmp(qname(m, q), "g") == 0) qg = q;
    if (strcmp(qname(m, q), "v") == 0) qv = q;
    if (strcmp(qname(m, q), "p") == 0) qp = q;
    if (strcmp(qname(m, q), "h") == 0) qh = q;
  }
  reduced_project(r, qg, test.g);
  reduced_project(r, qv, test.v);
  if (reduced_eval(r, 0)) die("reduced_eval", reduced_error(r));
  write_peer_files(m, r, dir, 1.0);
  size_t tb = 0;
  model_bytes(m, &tb);
  row->bytes = (double)tb;
  row->bw = bandwidth(tb, 0.5);
  row->m_root = m->classes[m->qclass[qp]].m, row->m_inv = m->classes[m->qclass[qh]].m;
  /* the contraction stages (no factorization): their tensors' bytes */
  row->contract_bytes = 0;
  len = 0;
  row->contract_names[0] = 0;
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (rs->st->kind != ST_CONTRACT) continue;
    len += (size_t)snprintf(row->contract_names + len, sizeof row->contract_names - len, "%s%s", len ? " " : "",
                            qname(m, rs->q));
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      RTERM_FOR_TENSORS(rt, x) { row->contract_bytes += sizeof(double) * (double)(x->rows * x->cols); }
    }
  }
  row->contract_bw = bandwidth((size_t)row->contract_bytes, 0.3);
  Factor fr = factor_seconds((int)row->m_root, 0.3), fi = factor_seconds((int)row->m_inv, 0.3);
  row->factor.root = fr.root, row->factor.inverse = fi.inverse;
  int threads = openblas_get_num_threads();
  for (int k = 0; k < 2; k++) {
    Part2Run *run = &row->run[k];
    run->threads = k == 0 ? threads : 1;
    openblas_set_num_threads(run->threads);
    run->c_seconds = best_of(eval_given, r, 1.0);
    len = 0;
    run->contract_seconds = 0;
    for (int i = 0; i < m->nstages; i++) {
      StageCtx sc = {r, i};
      if (m->stages[i].st->kind == ST_EXTERN) continue;
      double t = best_of(eval_stage, &sc, 0.1);
      if (m->stages[i].st->kind == ST_CONTRACT) run->contract_seconds += t;
      len += (size_t)snprintf(run->stages + len, sizeof run->stages - len, " %s %.1f", qname(m, m->stages[i].q),
                              1e6 * t);
    }
    run->peer_ok = run_peer(dir, run->threads, &run->peer, run->peer_stages, run->peer_stages_full,
                            sizeof run->peer_stages);
  }
  /* the root stage p alone on one thread: eigendecomposition against Lanczos, and their difference */
  openblas_set_num_threads(1);
  for (int i = 0; i < m->nstages; i++) {
    if (m->stages[i].q != qp) continue;
    long mp = m->classes[m->qclass[qp]].m, roots0, steps0, fb0, roots1, steps1, fb1;
    double *pe = xmalloc(sizeof(double) * (size_t)(mp + 1));
    StageCtx sc = {r, i};
    reduced_krylov_roots(r, false);
    row->root_exact = best_of(eval_stage, &sc, 0.2);
    memcpy(pe, reduced_coords(r, qp), sizeof(double) * (size_t)mp);
    reduced_krylov_roots(r, true);
    reduced_root_stats(r, &roots0, &steps0, &fb0);
    row->root_krylov = best_of(eval_stage, &sc, 0.2);
    reduced_root_stats(r, &roots1, &steps1, &fb1);
    row->root_steps = roots1 > roots0 ? (double)(steps1 - steps0) / (double)(roots1 - roots0 - (fb1 - fb0) + 1e-300) : 0;
    row->root_fallbacks = fb1 - fb0;
    double dn = 0, nn = 0;
    for (long k = 0; k < mp; k++) {
      double dk = reduced_coords(r, qp)[k] - pe[k];
      dn += dk * dk, nn += pe[k] * pe[k];
    }
    row->root_diff = sqrt(dn / (nn > 0 ? nn : 1));
    reduced_krylov_roots(r, false);
    free(pe);
  }
  openblas_set_num_threads(threads);
  reduced_free(r);
  room_free(&test);
  if (!keep) nftw(dir, rm_entry, 16, FTW_DEPTH | FTW_PHYS);
}

/* ---------------------------------------------------------------- part 3 */

typedef struct Part3Ctx {
  Reduced *r;
  int qg;
  const double *g;
} Part3Ctx;

static int eval_projected(void *arg) {
  Part3Ctx *c = arg;
  reduced_project(c->r, c->qg, c->g);
  return reduced_eval(c->r, 0);
}

static int eval_full(void *arg) { return full_eval(arg, 0); }

typedef struct Part3Row {
  long F, S;
  char classes[256];
  double cc, tcc, reduced, reduced_1, reduced_given, err_p, floor_p, bytes;
} Part3Row;

static void part3_row(NpgProgram *p, Trained *tr, Part3Row *row) {
  Model *m = tr->m;
  char err[1024];
  row->F = tr->F, row->S = tr->S;
  size_t len = 0;
  for (int c = 0; c < m->nclasses; c++)
    len += (size_t)snprintf(row->classes + len, sizeof row->classes - len, "%s%ld", c ? "," : "", m->classes[c].m);
  size_t tb = 0;
  model_bytes(m, &tb);
  row->bytes = (double)tb;
  Room test;
  room_make(&test, tr->F, 1, 0.37, 0, 7u);
  /* full: the training evaluator (cc) and a libtcc one, on the held-out sample */
  Full *ft = full_new(program_ir(p), JIT_TCC, NULL);
  if (full_error(ft)[0]) die("npg_full_new", full_error(ft));
  room_bind(&test, ft);
  if (room_set(&test, tr->f, 0) || full_eval(tr->f, 0)) die("full", full_error(tr->f));
  if (room_set(&test, ft, 0) || full_eval(ft, 0)) die("full", full_error(ft));
  row->cc = best_of(eval_full, tr->f, 0.5);
  row->tcc = best_of(eval_full, ft, 0.5);
  full_free(ft);
  /* reduced: project g, every stage (v by its learned map), no lifting */
  Reduced *r = reduced_new(m, ERR_OF(err, sizeof err));
  if (!r) die("reduced_new", err);
  Part3Ctx c = {r, -1, test.g};
  int qp = -1;
  for (int q = 0; q < m->nq; q++) {
    if (strcmp(qname(m, q), "g") == 0) c.qg = q;
    if (strcmp(qname(m, q), "p") == 0) qp = q;
  }
  if (eval_projected(&c)) die("reduced_eval", reduced_error(r));
  row->reduced = best_of(eval_projected, &c, 1.0);
  int threads = openblas_get_num_threads();
  openblas_set_num_threads(1);
  row->reduced_1 = best_of(eval_projected, &c, 1.0);
  openblas_set_num_threads(threads);
  /* the accuracy of what was timed: ‖p − B p̂‖ / ‖p‖, and the floor ‖p − B Bᵀp‖ / ‖p‖ */
  size_t n;
  const double *pf = full_get(tr->f, "p", &n);
  double *pl = xmalloc(sizeof(double) * n), *pc = xmalloc(sizeof(double) * (size_t)m->classes[m->qclass[qp]].m);
  reduced_lift(r, qp, pl);
  double num = 0, den = 0;
  for (size_t i = 0; i < n; i++) num += (pf[i] - pl[i]) * (pf[i] - pl[i]), den += pf[i] * pf[i];
  row->err_p = sqrt(num / den);
  memcpy(pc, reduced_coords(r, qp), sizeof(double) * (size_t)m->classes[m->qclass[qp]].m);
  reduced_project(r, qp, pf);
  reduced_lift(r, qp, pl);
  num = 0;
  for (size_t i = 0; i < n; i++) num += (pf[i] - pl[i]) * (pf[i] - pl[i]);
  row->floor_p = sqrt(num / den);
  /* given externs: the same stages without the learned map of v */
  reduced_use_given_externs(r, true);
  row->reduced_given = best_of(eval_projected, &c, 0.5);
  free(pl), free(pc);
  reduced_free(r);
  room_free(&test);
}

/* ---------------------------------------------------------------- main */

static int parse_list(const char *s, long *out, int max) {
  int n = 0;
  while (*s && n < max) {
    out[n++] = strtol(s, (char **)&s, 10);
    if (*s == ',') s++;
    else break;
  }
  return n;
}

static Trained *cache[16];
static int ncache;

static Trained *trained(NpgProgram *p, long F, long S, int cap, bool rerun_all) {
  for (int i = 0; i < ncache; i++)
    if (cache[i] && cache[i]->F == F && cache[i]->S == S && cache[i]->cap == cap) return cache[i];
  Trained *tr = train(p, F, S, cap, rerun_all);
  if (ncache < 16) cache[ncache++] = tr;
  return tr;
}

static void forget(Trained *tr) {
  for (int i = 0; i < ncache; i++)
    if (cache[i] == tr) cache[i] = NULL;
  trained_free(tr);
}

int main(int argc, char **argv) {
  bool part[4] = {false, false, false, false}, keep = false, rerun_all = false;
  long F1[8] = {500, 1000}, F3[8] = {500, 1000, 2000}, caps[8] = {10, 20, 40, 60}, C3[8] = {60}, S = 64, S3 = 24;
  int nF1 = 2, nF3 = 3, ncaps = 4, nC3 = 1;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    if (strlen(a) == 1 && a[0] >= '1' && a[0] <= '3') part[a[0] - '0'] = true;
    else if (strncmp(a, "F=", 2) == 0) nF1 = parse_list(a + 2, F1, 8);
    else if (strncmp(a, "F3=", 3) == 0) nF3 = parse_list(a + 3, F3, 8);
    else if (strncmp(a, "caps=", 5) == 0) ncaps = parse_list(a + 5, caps, 8);
    else if (strncmp(a, "S=", 2) == 0) S = strtol(a + 2, NULL, 10);
    else if (strncmp(a, "S3=", 3) == 0) S3 = strtol(a + 3, NULL, 10);
    else if (strncmp(a, "C3=", 3) == 0) nC3 = parse_list(a + 3, C3, 8);
    else if (strcmp(a, "keep") == 0) keep = true;
    else if (strcmp(a, "rerun") == 0) rerun_all = true;
    else {
      fprintf(stderr, "usage: bench_reduce [1] [2] [3] [F=500,1000] [S=64] [caps=10,20,40,60] [F3=500,1000,2000] "
                      "[S3=24] [C3=60] [keep] [rerun]\n");
      return 2;
    }
  }
  if (!part[1] && !part[2] && !part[3]) part[1] = part[2] = part[3] = true;
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  NpgProgram *p = npg_compile(PROG, &opt);
  if (!npg_ok(p)) die(PROG, npg_error(p));
  printf("bench_reduce: %s (stages n s r h c v d a p), the room of meshgen.c plus %d random smooth displacement "
         "modes per sample, visibility 1\n",
         PROG, ROOM_MODES);
  double t_start = now();

  if (part[1]) {
    printf("\n== 1. pre-multiplication throughput (flops counted by premultiply; best dgemm peers in the same run)\n");
    double sq = dgemm_gflops(false, 2000, 2000, 2000, 1.0);
    printf("  OpenBLAS dgemm 2000 x 2000 x 2000: %.2f GFLOP/s\n", sq);
    for (int i = 0; i < nF1; i++) {
      Trained *tr = trained(p, F1[i], S, 60, rerun_all);
      part1(tr, sq);
      fflush(stdout);
    }
  }

  if (part[2]) {
    printf("\n== 2. reduced evaluation vs numpy (bench/reduced_peer.py) on the same reduced tensors\n");
    Bandwidth dram = bandwidth(1L << 30, 1.0), l3 = bandwidth(8L << 20, 0.5);
    printf("  streaming read bandwidth: 1 GB %.1f GB/s (dgemv) %.1f GB/s (sum, 1 thread); 8 MB %.1f GB/s (dgemv) "
           "%.1f GB/s (sum)\n",
           dram.gemv, dram.sum, l3.gemv, l3.sum);
    char base[] = "/tmp/bench_reduce.XXXXXX";
    if (!mkdtemp(base)) die("mkdtemp", base);
    Part2Row rows[8];
    for (int i = 0; i < ncaps; i++) {
      Trained *tr = trained(p, F1[0], S, (int)caps[i], rerun_all);
      part2_row(tr, base, keep, &rows[i]);
      if (caps[i] != 60) forget(tr); /* part 3 reuses the cap-60 models */
    }
    if (!keep) rmdir(base);
    else printf("  models kept in %s\n", base);
    printf("  trained at F = %ld on %ld samples; externs given (v̂ = Bᵀ1) to both sides; inputs ĝ of a held-out "
           "sample\n",
           F1[0], S);
    printf("  numpy packed: the same packed tensors and the same dgemv order; numpy full: every symmetric axis "
           "unpacked (x⊗x inputs and the BᵀDB rows), plain dense tensors\n");
    printf("  %4s %-22s %7s %3s %10s %10s %10s %6s %6s %8s %9s %9s %6s %6s\n", "cap", "m per class", "MB", "thr",
           "npg s", "numpy pack", "numpy full", "x pack", "x full", "rel diff", "bound L", "bound D", "/L", "/D");
    for (int i = 0; i < ncaps; i++) {
      Part2Row *r = &rows[i];
      double bl = r->bytes / (bw_best(r->bw) * 1e9), bd = r->bytes / (bw_best(dram) * 1e9);
      for (int k = 0; k < 2; k++) {
        Part2Run *u = &r->run[k];
        printf("  %4d %-22s %7.2f %3d %10.2e", r->cap, r->classes, r->bytes / 1e6, u->threads, u->c_seconds);
        if (u->peer_ok)
          printf(" %10.2e %10.2e %6.2f %6.2f %8.1e", u->peer.packed, u->peer.full, u->peer.packed / u->c_seconds,
                 u->peer.full / u->c_seconds, fmax(u->peer.diff_packed, u->peer.diff_full));
        else printf(" %10s %10s %6s %6s %8s", "(failed)", "", "", "", "");
        printf(" %9.2e %9.2e %6.1f %6.1f\n", bl, bd, u->c_seconds / bl, u->c_seconds / bd);
      }
    }
    printf("  (x = numpy / npg; thr = OpenBLAS threads on both sides; bound L = tensor bytes / the bandwidth streaming "
           "as many bytes, measured here; bound D = tensor bytes / the 1 GB bandwidth; /L, /D = npg / bound)\n");
    for (int i = 0; i < ncaps; i++) {
      printf("  cap %d: bandwidth over %.2f MB: %.1f GB/s (dgemv), %.1f GB/s (sum); numpy full reads %.2f MB\n",
             rows[i].cap, rows[i].bytes / 1e6, rows[i].bw.gemv, rows[i].bw.sum, rows[i].run[0].peer.bytes_full / 1e6);
      printf("    LAPACK alone on a random SPD matrix of the stage's size, 1 thread: root p (dsytrd + dstedc, m = %ld) "
             "%.1f µs, inverse h (dpotrf + dpocon, m = %ld) %.1f µs; together %.1fx bound L (%.1f µs)\n",
             rows[i].m_root, 1e6 * rows[i].factor.root, rows[i].m_inv, 1e6 * rows[i].factor.inverse,
             (rows[i].factor.root + rows[i].factor.inverse) / (rows[i].bytes / (bw_best(rows[i].bw) * 1e9)),
             1e6 * rows[i].bytes / (bw_best(rows[i].bw) * 1e9));
      printf("    root stage p (m = %ld) alone, 1 thread: eigendecomposition %.1f µs, Lanczos %.1f µs (%.2fx; %.1f steps "
             "per root, %ld fell back to the eigendecomposition), difference %.1e relative\n",
             rows[i].m_root, 1e6 * rows[i].root_exact, 1e6 * rows[i].root_krylov,
             rows[i].root_exact / rows[i].root_krylov, rows[i].root_steps, rows[i].root_fallbacks, rows[i].root_diff);
      {
        Bandwidth cb = rows[i].contract_bw;
        double bound = rows[i].contract_bytes / (bw_best(cb) * 1e9);
        printf("    contraction stages alone (%s): %.2f MB, bound %.2f µs (%.1f GB/s over as many bytes); npg %.2f µs "
               "(%.2fx) on %d thread(s), %.2f µs (%.2fx) on 1\n",
               rows[i].contract_names, rows[i].contract_bytes / 1e6, 1e6 * bound, bw_best(cb),
               1e6 * rows[i].run[0].contract_seconds, rows[i].run[0].contract_seconds / bound, rows[i].run[0].threads,
               1e6 * rows[i].run[1].contract_seconds, rows[i].run[1].contract_seconds / bound);
      }
      for (int k = 0; k < 2; k++) {
        const Part2Run *u = &rows[i].run[k];
        printf("    µs per stage, %d thread(s), npg:         %s\n", u->threads, u->stages);
        printf("    µs per stage, %d thread(s), numpy packed:%s", u->threads, u->peer_stages);
        printf("    µs per stage, %d thread(s), numpy full:  %s", u->threads, u->peer_stages_full);
      }
    }
    fflush(stdout);
  }

  if (part[3]) {
    printf("\n== 3. full vs reduced evaluation (reduced: project g, every stage with v by its learned map, no "
           "lifting)\n");
    Part3Row rows[16];
    int nrows = 0;
    /* the cap-60 models of part 1 first, while they exist, then one sample count at every F */
    for (int i = 0; i < ncache; i++)
      if (cache[i] && cache[i]->cap == 60) part3_row(p, cache[i], &rows[nrows++]);
    for (int i = 0; i < ncache; i++) forget(cache[i]);
    for (int i = 0; i < nF3; i++)
      for (int c = 0; c < nC3 && nrows < 16; c++) {
        Trained *tr = trained(p, F3[i], S3, C3[c], rerun_all);
        printf("  trained F = %ld on %ld samples, cap %ld, in %.1f s (snapshots %.1f s, PCA %.1f s, "
               "pre-multiplication %.1f s, %.0f GFLOP/s)\n",
               tr->F, tr->S, C3[c], tr->t_train, tr->t_snap, tr->t_pca, tr->t_premul,
               tr->premul_flops / tr->t_premul / 1e9);
        fflush(stdout);
        part3_row(p, tr, &rows[nrows++]);
        forget(tr);
      }
    printf("  %5s %3s %-24s %6s %9s %9s %9s %9s %9s %6s %6s %6s %8s %8s\n", "F", "S", "m per class", "MB", "full cc",
           "full tcc", "reduced", "red. 1thr", "red. givn", "x cc", "x tcc", "x cc1", "err p", "floor p");
    for (int i = 0; i < nrows; i++) {
      Part3Row *r = &rows[i];
      printf("  %5ld %3ld %-24s %6.2f %9.2e %9.2e %9.2e %9.2e %9.2e %6.1f %6.1f %6.1f %8.2e %8.2e\n", r->F, r->S,
             r->classes, r->bytes / 1e6, r->cc, r->tcc, r->reduced, r->reduced_1, r->reduced_given, r->cc / r->reduced,
             r->tcc / r->reduced, r->cc / r->reduced_1, r->err_p, r->floor_p);
    }
    printf("  (seconds per evaluation, best of repeats; reduced = project g + every stage, v̂ by its learned map, no "
           "lifting, OpenBLAS default threads; red. 1thr: the same on 1 thread; red. givn: v̂ given, default threads; "
           "x = full / reduced; x cc1 = full cc / red. 1thr; err p = ‖p − B p̂‖/‖p‖ on the held-out sample, floor p "
           "= ‖p − B Bᵀp‖/‖p‖)\n");
  }
  printf("\nbench_reduce: %.0f s\n", now() - t_start);
  npg_free(p);
  return 0;
}
