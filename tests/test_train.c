/* test_train.c — training (backends/train/train.c; DESIGN §5, §11):
 *
 *   - the reduced error falls as the basis caps grow (the radiosity room and
 *     Eq. 3);
 *   - on a deforming mesh at energy 0.999, centered truncation (the default)
 *     is at least 5x more accurate than the paper's uncentered one.
 *   - snapshots kept between trainings (TrainOptions.cache, greedy training):
 *     a training on more samples takes those of the samples held and
 *     evaluates the others alone, and its model is the one replaying every
 *     sample gives, bit for bit; a cache of other samples is not used.
 * The method of snapshots: test_snapshots.c.
 */
#include "emit.h"
#include "memsamples.h"
#include "meshgen.h"
#include "train.h"
#include "testutil.h"
#include "trained.h"

/* ---------------------------------------------------------------- error falls with basis size */

static void error_falls_with_caps(void **state) {
  (void)state;
  const int caps[] = {2, 4, 8, 16, 32};
  double err_rad[5], err_rat[2];
  const int rat_caps[] = {1, 2}; /* y has 2 entries */
  /* radiosity: train on 48 deformations of the room and lights, test between them */
  NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  RoomSamples train, test;
  room_samples(&train, f, 48, 48, 0.0, 1.0 / 47);
  room_samples(&test, NULL, 48, 12, 0.5 / 47, 4.0 / 47);
  for (int c = 0; c < 5; c++) {
    SampleSource src = {train.S, &train, room_set, NULL, NULL};
    NpgTrainOptions opt_user = {0};
    TrainOptions opt = {.user = &opt_user};
    opt_user.cap = caps[c];
    opt_user.energy = 1.0;
    char err[2048] = "";
    Model *m = train_model(prog, f, &src, &opt, ERR_OF(err, sizeof err));
    if (!m) fail_msg("radiosity: %s", err);
    err_rad[c] = mean_error(prog, f, m, &test, room_set, test.S, "b");
    model_free(m);
  }
  room_free(&train);
  room_free(&test);
  full_free(f);
  npg_free(p);
  /* rational (paper Eq. 3): random x in [0.5, 1.5]^2 */
  p = compile_file("examples/rational/rational.npg");
  prog = ir_ok(p);
  f = full_new(program_ir(p), JIT_TCC, NULL);
  MemSamples rtrain, rtest;
  if (memsamples_fill(&rtrain, prog, f, 2, 40, 3u)) fail_msg("binding random params failed");
  if (memsamples_fill(&rtest, prog, f, 2, 20, 4u)) fail_msg("binding random params failed");
  for (int c = 0; c < 2; c++) {
    SampleSource src = {rtrain.S, &rtrain, memsamples_set, NULL, NULL};
    NpgTrainOptions opt_user = {0};
    TrainOptions opt = {.user = &opt_user};
    opt_user.cap = rat_caps[c];
    opt_user.energy = 1.0;
    char err[2048] = "";
    Model *m = train_model(prog, f, &src, &opt, ERR_OF(err, sizeof err));
    if (!m) fail_msg("rational: %s", err);
    err_rat[c] = mean_error(prog, f, m, &rtest, memsamples_set, rtest.S, "y");
    model_free(m);
  }
  memsamples_free(&rtrain);
  memsamples_free(&rtest);
  full_free(f);
  npg_free(p);
  print_message("mean relative L2 error of the output over held-out samples, by cap per member:\n");
  print_message("  cap          ");
  for (int c = 0; c < 5; c++) print_message(" %10d", caps[c]);
  print_message("\n  radiosity b  ");
  for (int c = 0; c < 5; c++) print_message(" %10.3e", err_rad[c]);
  print_message("\n  rational y: cap 1 %.3e, cap 2 %.3e\n", err_rat[0], err_rat[1]);
  /* falls: never rises by more than 5 %, and the largest cap is far better than the smallest */
  for (int c = 1; c < 5; c++) assert_true(err_rad[c] <= err_rad[c - 1] * 1.05);
  assert_true(err_rad[4] < err_rad[0] / 10);
  assert_true(err_rat[1] < err_rat[0] / 10);
}

/* ---------------------------------------------------------------- centered truncation */

/* A deforming mesh whose rest shape dominates (issue 11): an nx x nx grid
 * with horizontal, vertical and diagonal springs, its rest shape far from
 * the origin, deformed by seven smooth modes of random amplitude. */
typedef struct MeshSamples {
  long V, E, S;
  double *x;                /* S x V x 3 */
} MeshSamples;

static int mesh_set(void *user, Full *f, long k) {
  MeshSamples *ms = user;
  long shape[2] = {ms->V, 3};
  return full_set(f, "x", 2, shape, ms->x + k * ms->V * 3, "x");
}

/* Bind the grid's params in `f` (when non-NULL) and draw S deformations. */
static void mesh_samples(MeshSamples *ms, Full *f, long nx, long S, unsigned seed) {
  long V = nx * nx, E = 0;
  double *edge = malloc(sizeof(double) * (size_t)(V * 6)), *L0 = malloc(sizeof(double) * (size_t)(V * 3));
  double *rest = malloc(sizeof(double) * (size_t)(V * 3));
  double h = 1.0 / (double)(nx - 1);
  for (long v = 0; v < V; v++) {
    rest[v * 3] = 4 + (double)(v % nx) * h, rest[v * 3 + 1] = 4 + (double)(v / nx) * h, rest[v * 3 + 2] = 3;
  }
  for (long j = 0; j < nx; j++)
    for (long i = 0; i < nx; i++) {
      long a = j * nx + i, to[3] = {i + 1 < nx ? a + 1 : -1, j + 1 < nx ? a + nx : -1,
                                    i + 1 < nx && j + 1 < nx ? a + nx + 1 : -1};
      for (int t = 0; t < 3; t++) {
        long b = to[t];
        if (b < 0) continue;
        edge[E * 2] = (double)a, edge[E * 2 + 1] = (double)b;
        double l = 0;
        for (int c = 0; c < 3; c++) l += (rest[b * 3 + c] - rest[a * 3 + c]) * (rest[b * 3 + c] - rest[a * 3 + c]);
        L0[E] = sqrt(l);
        E++;
      }
    }
  if (f) {
    long se[2] = {E, 2}, sl[1] = {E};
    if (full_set_param(f, "edge", 2, se, edge, "edge") || full_set_param(f, "L0", 1, sl, L0, "L0"))
      fail_msg("%s", full_error(f));
  }
  *ms = (MeshSamples){V, E, S, malloc(sizeof(double) * (size_t)(S * V * 3))};
  for (long s = 0; s < S; s++) {
    double a[7];
    for (int i = 0; i < 7; i++) a[i] = 0.3 * (rand_r(&seed) / (double)RAND_MAX - 0.5);
    for (long v = 0; v < V; v++) {
      double u = (double)(v % nx) * h, w = (double)(v / nx) * h, *x = ms->x + (s * V + v) * 3;
      x[0] = rest[v * 3] + a[3] * (u - 0.5) + a[4] * (w - 0.5);
      x[1] = rest[v * 3 + 1] + a[5] * (w - 0.5) * u;
      x[2] = rest[v * 3 + 2] + a[0] * sin(M_PI * u) * sin(M_PI * w) + a[1] * sin(2 * M_PI * u) * sin(M_PI * w) +
             a[2] * sin(M_PI * u) * sin(2 * M_PI * w) + a[6] * (u - 0.5) * (w - 0.5);
    }
  }
  free(edge), free(L0), free(rest);
}

/* Issue 11's acceptance: on a deforming mesh, with the defaults (energy
 * 0.999, cap 60), the centered truncation's output error is at least 5x
 * smaller than the paper's uncentered one at the same threshold. */
static void centered_beats_uncentered_on_deforming_mesh(void **state) {
  (void)state;
  NpgProgram *p = compile_file("tests/programs/deforming_springs.npg");
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  MeshSamples train, test;
  mesh_samples(&train, f, 8, 60, 7u);
  mesh_samples(&test, NULL, 8, 20, 8u);
  double err[2];
  long mx[2], mf[2];
  for (int uncentered = 0; uncentered < 2; uncentered++) {
    SampleSource src = {train.S, &train, mesh_set, NULL, NULL};
    Model *m = train_with(prog, f, &src, 60, 0.999, uncentered, 0);
    err[uncentered] = mean_error(prog, f, m, &test, mesh_set, test.S, "f");
    mx[uncentered] = m->classes[m->qclass[vec_position(&prog->quantities, find_quantity(prog, "x"))]].m;
    mf[uncentered] = m->classes[m->qclass[vec_position(&prog->quantities, find_quantity(prog, "f"))]].m;
    model_free(m);
  }
  print_message("deforming springs (%ld vertices, %ld springs), energy 0.999: mean relative error of the forces f: centered "
                "%.3e (m_x %ld, m_f %ld), uncentered %.3e (m_x %ld, m_f %ld): %.1fx\n",
                train.V, train.E, err[0], mx[0], mf[0], err[1], mx[1], mf[1], err[1] / err[0]);
  assert_true(err[0] * 5 <= err[1]);
  free(train.x);
  free(test.x);
  full_free(f);
  npg_free(p);
}

/* ---------------------------------------------------------------- snapshots kept between trainings */

/* Every basis, SPD mark, reduced tensor and estimate table of `a` and `b` equal, bit for bit. */
static void assert_same_model(const Model *a, const Model *b) {
  assert_int_equal(a->nclasses, b->nclasses);
  for (int c = 0; c < a->nclasses; c++) {
    const RClass *x = &a->classes[c], *y = &b->classes[c];
    assert_int_equal(x->m, y->m);
    assert_int_equal(x->n, y->n);
    assert_memory_equal(x->B, y->B, sizeof(double) * (size_t)(x->n * x->m));
  }
  assert_int_equal(a->nstages, b->nstages);
  for (int i = 0; i < a->nstages; i++)
    for (int t = 0; t < a->stages[i].nterms; t++) {
      const RTerm *x = &a->stages[i].terms[t], *y = &b->stages[i].terms[t];
      for (int k = 0; k < x->nops; k++) assert_int_equal(x->ops[k].spd, y->ops[k].spd);
      assert_int_equal(x->est_D, y->est_D);
      if (x->est_G) assert_memory_equal(x->est_G, y->est_G, sizeof(double) * (size_t)((x->est_D + 1) * x->est_D));
    }
  long n = 0;
  const RTensor *ys[256];
  FOR_TENSORS(b, y) ys[n < 256 ? n++ : n] = y;
  long j = 0;
  FOR_TENSORS(a, x) {
    assert_true(j < n);
    assert_int_equal(x->rows * x->cols, ys[j]->rows * ys[j]->cols);
    assert_memory_equal(x->data, ys[j]->data, sizeof(double) * (size_t)(x->rows * x->cols));
    j++;
  }
  assert_int_equal(j, n);
}

/* The whole evaluations of `f` training `count` of the samples of `ms` with `cache` made: *m the model. */
static long evaluations_training(Program *prog, Full *f, MemSamples *ms, long count, SnapshotCache *cache, Model **m) {
  SampleSource src = {count, ms, memsamples_set, NULL, NULL};
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = 8, opt_user.energy = 1, opt.cache = cache;
  char err[2048] = "";
  long before, after;
  full_evaluations(f, &before, NULL);
  *m = train_model(prog, f, &src, &opt, ERR_OF(err, sizeof err));
  if (!*m) fail_msg("rational, %ld samples: %s", count, err);
  full_evaluations(f, &after, NULL);
  return after - before;
}

static void kept_snapshots_give_the_replayed_model(void **state) {
  (void)state;
  /* the paper's Eq. 3: a diagonal operator (its SPD mark) inverted on a numerator (a member of y's class) */
  NpgProgram *p = compile_file("examples/rational/rational.npg");
  Program *prog = ir_ok(p);
  Full *f = full_new(program_ir(p), JIT_TCC, NULL);
  MemSamples ms, other;
  if (memsamples_fill(&ms, prog, f, 2, 40, 5u) || memsamples_fill(&other, prog, NULL, 2, 20, 6u))
    fail_msg("binding random params failed");
  Model *replayed, *m;
  assert_int_equal(evaluations_training(prog, f, &ms, 40, NULL, &replayed), 40);
  SnapshotCache *cache = snapshot_cache_new();
  assert_non_null(cache);
  /* 20, then 21, then 40 samples: each training evaluates the samples the last did not hold (and its last) */
  assert_int_equal(evaluations_training(prog, f, &ms, 20, cache, &m), 20);
  model_free(m);
  assert_int_equal(snapshot_cache_samples(cache), 20);
  assert_int_equal(evaluations_training(prog, f, &ms, 21, cache, &m), 1);
  model_free(m);
  assert_int_equal(evaluations_training(prog, f, &ms, 40, cache, &m), 19);
  assert_same_model(m, replayed);
  model_free(m);
  /* the same samples again: only the last is evaluated (the evaluator ends on its values, as replayed) */
  assert_int_equal(evaluations_training(prog, f, &ms, 40, cache, &m), 1);
  assert_same_model(m, replayed);
  model_free(m);
  /* other samples: every one evaluated, and the columns not taken kept for one more training (the
   * hold-out's samples, between its training and the retraining on all) */
  assert_int_equal(evaluations_training(prog, f, &other, 20, cache, &m), 20);
  model_free(m);
  assert_int_equal(evaluations_training(prog, f, &ms, 40, cache, &m), 1);
  assert_same_model(m, replayed);
  model_free(m);
  /* left unused by two trainings: dropped, every sample evaluated, the model the replayed one */
  assert_int_equal(evaluations_training(prog, f, &other, 20, cache, &m), 1);
  model_free(m);
  assert_int_equal(evaluations_training(prog, f, &other, 20, cache, &m), 1);
  model_free(m);
  assert_int_equal(evaluations_training(prog, f, &ms, 40, cache, &m), 40);
  assert_same_model(m, replayed);
  model_free(m);
  /* samples numbered otherwise (the last 20 of the 40, first): found by their hashes */
  MemSamples last = ms;
  for (int q = 0; q < ms.n; q++) last.val[q] = ms.val[q] + (size_t)20 * ms.count[q];
  last.S = 20;
  assert_int_equal(evaluations_training(prog, f, &last, 20, cache, &m), 1);
  model_free(m);
  /* a new first sample before held ones: evaluated by the pass, after the samples set to be found */
  MemSamples mixed = ms;
  for (int q = 0; q < ms.n; q++) {
    mixed.val[q] = malloc(sizeof(double) * 20 * ms.count[q]);
    assert_non_null(mixed.val[q]);
    memcpy(mixed.val[q], other.val[q], sizeof(double) * ms.count[q]);
    memcpy(mixed.val[q] + ms.count[q], last.val[q] + ms.count[q], sizeof(double) * 19 * ms.count[q]);
  }
  mixed.S = 20;
  Model *fresh;
  assert_int_equal(evaluations_training(prog, f, &mixed, 20, NULL, &fresh), 20);
  assert_int_equal(evaluations_training(prog, f, &mixed, 20, cache, &m), 2);
  assert_same_model(m, fresh);
  model_free(m);
  model_free(fresh);
  for (int q = 0; q < ms.n; q++) free(mixed.val[q]);
  model_free(replayed);
  snapshot_cache_free(cache);
  memsamples_free(&ms);
  memsamples_free(&other);
  full_free(f);
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(error_falls_with_caps),
      cmocka_unit_test(centered_beats_uncentered_on_deforming_mesh),
      cmocka_unit_test(kept_snapshots_give_the_replayed_model),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
