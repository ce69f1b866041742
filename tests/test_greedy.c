/* test_greedy.c — greedy training through npg.h (npg_train_greedy; docs/estimates.md, "Greedy
 * training"; issue 41) on a thermal block of G x G cells in B x B blocks (a cell-centred K(μ) =
 * K0 + Σ μ_q K_q, SPD, the source fixed):
 *
 *   - a pool whose conductivities vary by ±1 % about one value: under greedy training μ's basis
 *     keeps every direction its samples span (the uncentered default energy 0.999 kept one, and
 *     every candidate then stayed outside it), so greedy converges before the pool is used up,
 *     μ's class holds all B² directions and every candidate's true error is below the tolerance;
 *   - with `--basis mu:energy=1` given (the case bench/thermalblock.md's 3 x 3 run was refused
 *     at) greedy runs past the residual table's former limit of 512 columns (D = 1 + 17 m on 4 x 4
 *     blocks): every model along the way keeps its estimate, which bounds the true error on
 *     held-out parameters.
 *
 * In both, every training sample is evaluated in full once over the whole run (a retraining takes
 * the earlier samples' snapshots from the last, and the σ_min ratios' operators, which read μ
 * only, are built without an evaluation).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testutil.h"

static const char *PROG =
    "dim N, Q\n"
    "param nbr : int[N, 4]\n"
    "param blk : int[N]\n"
    "param src : real[N]\n"
    "input mu : real[Q]\n"
    "op K[i:N, j:N] = delta(i, j) * (1 + sum(k = 0..3, if(nbr[i, k] >= 0, 0.5 * (mu[blk[i]] + mu[blk[nbr[i, k]]]), "
    "0))) - sum(k = 0..3, if(nbr[i, k] == j, 0.5 * (mu[blk[i]] + mu[blk[j]]), 0))\n"
    "output u = solve(K, src)\n";

/* The block with a stage whose reduction is open to the automatic choice (interpolation or
 * Galerkin): at 30 samples and more training holds every 10th out to choose on. */
static const char *PROG_CHOICE_TAIL = "output w[i:N] = (u[i] * u[i] + 1)^(-1/2)\n";

typedef struct Block {
  NpgProgram *p;
  NpgFull *f;
  long N, Q;
} Block;

static void block_new(Block *b, long G, long B, const char *tail) {
  char text[2048];
  snprintf(text, sizeof text, "%s%s", PROG, tail);
  b->p = compile_text("greedy_block.npg", text);
  ir_ok(b->p);
  b->f = npg_full_new(b->p, NPG_TCC);
  b->N = G * G, b->Q = B * B;
  double *nbr = malloc(sizeof(double) * (size_t)(b->N * 4)), *blk = malloc(sizeof(double) * (size_t)b->N),
         *src = malloc(sizeof(double) * (size_t)b->N);
  for (long y = 0; y < G; y++)
    for (long x = 0; x < G; x++) {
      long i = y * G + x, d[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
      for (int k = 0; k < 4; k++) {
        long xx = x + d[k][0], yy = y + d[k][1];
        nbr[i * 4 + k] = xx >= 0 && xx < G && yy >= 0 && yy < G ? (double)(yy * G + xx) : -1;
      }
      blk[i] = (double)((B * y / G) * B + B * x / G);
      src[i] = exp(-((x - G / 3.0) * (x - G / 3.0) + (y - G / 4.0) * (y - G / 4.0)) / (double)G);
    }
  long s2[2] = {b->N, 4}, s1[1] = {b->N};
  if (npg_full_set_param(b->f, "nbr", 2, s2, nbr, "nbr") || npg_full_set_param(b->f, "blk", 1, s1, blk, "blk") ||
      npg_full_set_param(b->f, "src", 1, s1, src, "src"))
    fail_msg("%s", npg_full_error(b->f));
  free(nbr), free(blk), free(src);
}

static void block_free(Block *b) {
  npg_full_free(b->f);
  npg_free(b->p);
}

typedef struct Mus {
  const double *mu;
  long Q;
} Mus;

static int set_mu(void *user, NpgFull *f, long k) {
  const Mus *s = user;
  long shape[1] = {s->Q};
  return npg_full_set(f, "mu", 1, shape, s->mu + k * s->Q, "pool");
}

static double lcg(unsigned *seed) { return (double)(*seed = *seed * 1103515245u + 12345u) / 4294967296.0; }

/* ‖u − lift‖ and ‖u‖ at μ, the estimate of u into *est. */
static double true_error(const Block *b, NpgReduced *r, const double *mu, double *unorm, double *est) {
  long shape[1] = {b->Q};
  if (npg_full_set(b->f, "mu", 1, shape, mu, "mu") || npg_full_eval(b->f, 0)) fail_msg("%s", npg_full_error(b->f));
  size_t n = 0;
  const double *u = npg_full_get(b->f, "u", &n);
  double *lift = malloc(sizeof(double) * n);
  if (npg_reduced_set(r, "mu", (size_t)b->Q, mu) || npg_reduced_eval(r, 0) || npg_reduced_lift(r, "u", lift, n) ||
      npg_reduced_estimate(r, "u", est, NULL))
    fail_msg("%s", npg_reduced_error(r));
  double e = 0, nu = 0;
  for (size_t i = 0; i < n; i++) e += (u[i] - lift[i]) * (u[i] - lift[i]), nu += u[i] * u[i];
  free(lift);
  *unorm = sqrt(nu);
  return sqrt(e);
}

static void options(NpgTrainOptions *o, int nbasis, const char *const *names, const int *caps, const double *energies) {
  npg_train_options_default(o);
  o->uncentered = true;
  o->nbasis = nbasis, o->basis_name = names, o->basis_cap = caps, o->basis_energy = energies;
}

static void inputs_keep_every_direction(void **state) {
  (void)state;
  Block b;
  block_new(&b, 6, 3, "");
  enum { POOL = 30 };
  double mu[POOL * 9];
  unsigned seed = 7;
  for (long i = 0; i < POOL * b.Q; i++) mu[i] = 0.5 * (1 + 0.02 * (lcg(&seed) - 0.5));
  Mus pool = {mu, b.Q}, start = {mu, b.Q};
  const char *names[1] = {"u"};
  int caps[1] = {60};
  double energies[1] = {1};
  NpgTrainOptions o;
  options(&o, 1, names, caps, energies);
  NpgGreedyOptions g = {.tol = 1e-6};
  NpgGreedyResult res;
  NpgModel *m = npg_train_greedy(b.f, &o, 1, set_mu, &start, POOL, set_mu, &pool, &g, NULL, &res);
  if (!m) fail_msg("%s", res.error);
  NpgClassInfo ci;
  assert_int_equal(npg_model_class(m, npg_model_class_of(m, "mu"), &ci), 0);
  assert_int_equal(ci.m, b.Q); /* every direction of the 1 % variations */
  assert_true(res.converged);
  assert_true(res.nchosen < POOL - 5);
  /* each sample evaluated in full once: a retraining takes the earlier ones' snapshots from the last */
  assert_int_equal(res.evaluations, 1 + res.nchosen);
  NpgReduced *r = npg_reduced_new(m);
  for (long k = 0; k < POOL; k++) {
    double nu, est, e = true_error(&b, r, mu + k * b.Q, &nu, &est);
    if (!(e <= 1e-6 * nu)) fail_msg("candidate %ld: true relative error %.3e above the tolerance 1e-6", k, e / nu);
  }
  npg_reduced_free(r);
  npg_model_free(m);
  free(res.chosen);
  block_free(&b);
}

/* The `estimate STAGE T dim D ...` line of the model's manifest: D. */
static long manifest_dim(const char *dir) {
  char path[600], line[512];
  snprintf(path, sizeof path, "%s/manifest", dir);
  FILE *fp = fopen(path, "r");
  assert_non_null(fp);
  long D = -1;
  while (fgets(line, sizeof line, fp))
    if (sscanf(line, "estimate u 0 dim %ld", &D) == 1) break;
  fclose(fp);
  return D;
}

static void past_512_columns_keeps_the_estimate(void **state) {
  (void)state;
  Block b;
  block_new(&b, 10, 4, "");
  enum { POOL = 50, TEST = 5 };
  double mu[(POOL + TEST) * 16];
  unsigned seed = 3;
  for (long i = 0; i < (POOL + TEST) * b.Q; i++) mu[i] = 0.1 + 0.9 * lcg(&seed);
  Mus pool = {mu, b.Q}, start = {mu, b.Q};
  const char *names[2] = {"u", "mu"};
  int caps[2] = {60, -1};
  double energies[2] = {1, 1};
  NpgTrainOptions o;
  options(&o, 2, names, caps, energies);
  NpgGreedyOptions g = {.tol = 1e-14, .budget = 36};
  NpgGreedyResult res;
  char dir[512];
  scratch_path(dir, "past512");
  NpgModel *m = npg_train_greedy(b.f, &o, 1, set_mu, &start, POOL, set_mu, &pool, &g, dir, &res);
  if (!m) fail_msg("%s", res.error);
  assert_int_equal(res.nchosen, 35);
  assert_int_equal(res.evaluations, 1 + res.nchosen);
  long D = manifest_dim(dir);
  if (D <= 512) fail_msg("the final model's residual table has %ld columns (the test needs more than 512)", D);
  NpgReduced *r = npg_reduced_new(m);
  for (long k = POOL; k < POOL + TEST; k++) {
    double nu, est, e = true_error(&b, r, mu + k * b.Q, &nu, &est);
    if (!(est >= e && est <= 20 * e)) fail_msg("test parameter %ld: estimate %.3e against the true error %.3e", k, est, e);
  }
  npg_reduced_free(r);
  npg_model_free(m);
  free(res.chosen);
  block_free(&b);
}

/* The manifest's greedy, timing and checksum lines taken out of text (in place); its new length. */
static size_t drop_lines(char *text) {
  char *to = text;
  for (char *l = text; *l;) {
    size_t len = strcspn(l, "\n") + (l[strcspn(l, "\n")] != 0);
    if (strncmp(l, "greedy", 6) && strncmp(l, "manifest ", 9) && strncmp(l, "seconds", 7) && strncmp(l, "timing", 6) && strncmp(l, "cpu", 3))
      memmove(to, l, len), to += len;
    l += len;
  }
  *to = 0;
  return (size_t)(to - text);
}

/* Every file of model a the same as b's, the manifest's greedy and timing lines left out. */
static void models_same(const char *a, const char *b) {
  DIR *d = opendir(a);
  assert_non_null(d);
  struct dirent *e;
  int files = 0;
  while ((e = readdir(d))) {
    if (e->d_name[0] == '.') continue;
    char pa[1024], pb[1024];
    snprintf(pa, sizeof pa, "%s/%s", a, e->d_name), snprintf(pb, sizeof pb, "%s/%s", b, e->d_name);
    size_t na, nb;
    char *x = slurp(pa, &na), *y = slurp(pb, &nb);
    if (strcmp(e->d_name, "manifest") == 0) na = drop_lines(x), nb = drop_lines(y);
    size_t at = 0;
    while (at < na && at < nb && x[at] == y[at]) at++;
    if (na != nb || at < na)
      fail_msg("model file %s differs from the fresh training's at byte %zu: %.60s | %.60s", e->d_name, at,
               x + (at > 20 ? at - 20 : 0), y + (at > 20 ? at - 20 : 0));
    free(x), free(y);
    files++;
  }
  closedir(d);
  assert_true(files > 3);
}

/* The automatic hold-out (w's reduction open, 30 samples and more) with the snapshot cache, which
 * finds the samples by their hashes: the hold-out's training takes its samples from the last
 * retraining on all, the retraining on all takes them back, with the held-out ones left from the
 * training before, and so does the validation on them. Each training evaluates its new sample and
 * its last one, the validation its last (the evaluator ends as it did): three per iteration, where
 * replaying took every sample twice; the final model is, file for file, the one training on the
 * chosen samples afresh. */
static void hold_out_keeps_the_snapshots(void **state) {
  (void)state;
  Block b;
  block_new(&b, 6, 2, PROG_CHOICE_TAIL);
  enum { POOL = 60, BUDGET = 36 };
  double mu[POOL * 4];
  unsigned seed = 11;
  for (long i = 0; i < POOL * b.Q; i++) mu[i] = 0.1 + 0.9 * lcg(&seed);
  Mus pool = {mu, b.Q}, start = {mu, b.Q};
  const char *names[3] = {"u", "mu", "w"};
  int caps[3] = {60, -1, 60};
  double energies[3] = {1, 1, 1};
  NpgTrainOptions o;
  options(&o, 3, names, caps, energies);
  NpgGreedyOptions g = {.tol = 1e-14, .budget = BUDGET, .absolute = true};
  NpgGreedyResult res;
  char dir[512], again[512];
  scratch_path(dir, "holdout"), scratch_path(again, "holdout_again");
  NpgModel *m = npg_train_greedy(b.f, &o, 1, set_mu, &start, POOL, set_mu, &pool, &g, dir, &res);
  if (!m) fail_msg("%s", res.error);
  assert_int_equal(res.nchosen, BUDGET - 1);
  /* replayed (the hold-out's training, its validation and the retraining evaluating every sample):
   * 2 S per iteration from 30 samples, 491 in all; with the cache one per iteration below 30, then
   * the new sample, the last held-out one and the retraining's last (the evaluator ends as it did): 50 */
  long replayed = 0, bound = 0;
  for (long S = 1; S <= BUDGET; S++) replayed += S < 30 ? 1 : 2 * S, bound += S < 30 ? 1 : 3;
  print_message("hold-out: %ld full evaluations (%ld replayed, at most %ld)\n", res.evaluations, replayed, bound);
  assert_true(res.evaluations <= bound);
  assert_true(res.evaluations >= BUDGET);
  NpgTrainer *t = npg_trainer_new(b.f, &o); /* the chosen samples trained afresh */
  for (long k = 0; k <= res.nchosen; k++) {
    if (set_mu(&pool, b.f, k ? res.chosen[k - 1] : 0) != 0) fail_msg("%s", npg_full_error(b.f));
    npg_trainer_add_full(t, b.f);
  }
  NpgModel *m2 = npg_trainer_finish(t, again);
  if (!m2) fail_msg("%s", npg_trainer_error(t));
  models_same(dir, again);
  npg_model_free(m2);
  npg_trainer_free(t);
  npg_model_free(m);
  free(res.chosen);
  block_free(&b);
}

static int setup(void **state) {
  (void)state;
  return scratch_make("npg_test_greedy");
}

static int teardown(void **state) {
  (void)state;
  remove_tree(scratch);
  return 0;
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(inputs_keep_every_direction),
      cmocka_unit_test(past_512_columns_keeps_the_estimate),
      cmocka_unit_test(hold_out_keeps_the_snapshots),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
