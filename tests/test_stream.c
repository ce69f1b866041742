/* test_stream.c — pre-multiplication by bases formed block by block
 * (backends/train/stream.c, issue 30):
 *
 *   - the radiosity room trained out of core with the streamable bases
 *     dropped (TrainOptions.stream; --mem 8, then 4, times the largest
 *     basis) forms its pair classes block by block, never whole (no
 *     basis in the model), and gives in-memory training's model: every
 *     pre-multiplied tensor (its signs fixed on the sums at the end), every
 *     basis both keep, and the reduced output b, to 1e-10;
 *   - the smaller budget takes more blocks (more passes, and a block whose
 *     rows exceed a pass's share split), to the same tensors.
 */
#include <unistd.h>

#include "emit.h"
#include "memsamples.h"
#include "reduced.h"
#include "train.h"
#include "testutil.h"
#include "trained.h"

/* The largest difference of a pre-multiplied tensor of `a` and `b` relative
 * to its largest entry (a column of opposite sign gives about 2). */
static double tensor_distance(const Model *a, const Model *b) {
  double worst = 0;
  for (int i = 0; i < a->nstages; i++)
    for (int t = 0; t < a->stages[i].nterms; t++) {
      RTerm *ta = &a->stages[i].terms[t], *tb = &b->stages[i].terms[t];
      RTERM_FOR_TENSORS(ta, x) {
        const RTensor *y = k_ < 0 ? &tb->num[g_] : &tb->ops[k_].t[g_];
        assert_int_equal(x->rows * x->cols, y->rows * y->cols);
        double big = 0, d = 0;
        for (long e = 0; e < x->rows * x->cols; e++)
          big = fmax(big, fabs(x->data[e])), d = fmax(d, fabs(x->data[e] - y->data[e]));
        worst = fmax(worst, big > 0 ? d / big : d);
      }
    }
  return worst;
}

/* The largest difference of a basis entry over the classes both keep whole;
 * how many classes `b` keeps no basis of into *streamed. A class
 * `b` keeps as coefficients is compared by the tensors and outputs it gives. */
static double basis_distance(const Model *a, const Model *b, int *streamed) {
  double worst = 0;
  *streamed = 0;
  assert_int_equal(a->nclasses, b->nclasses);
  for (int c = 0; c < a->nclasses; c++) {
    const RClass *x = &a->classes[c], *y = &b->classes[c];
    assert_int_equal(x->m, y->m);
    /* an extern's class formed block by block is kept as coefficients of its training values (issue 30) */
    assert_true(x->streamed == y->streamed || (y->coef && y->coef_S > 0));
    if (y->streamed && !y->B) ++*streamed;
    if (!x->B || !y->B) continue;
    for (long e = 0; e < x->n * x->m; e++) worst = fmax(worst, fabs(x->B[e] - y->B[e]));
  }
  return worst;
}

/* train_model with its progress lines (stderr) captured into `log`. */
static Model *train_logged(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, char *log,
                           size_t len) {
  char path[] = "/tmp/npg_test_stream_XXXXXX";
  int fd = mkstemp(path);
  assert_true(fd >= 0);
  fflush(stderr);
  int saved = dup(2);
  assert_true(saved >= 0 && dup2(fd, 2) == 2);
  char err[2048] = "";
  Model *m = train_model(prog, f, src, opt, ERR_OF(err, sizeof err));
  fflush(stderr);
  dup2(saved, 2);
  close(saved);
  ssize_t n = pread(fd, log, len - 1, 0);
  log[n > 0 ? n : 0] = 0;
  close(fd);
  unlink(path);
  if (!m) fail_msg("training: %s", err);
  return m;
}

/* The count after "(" of stream_premultiply's progress line: its blocks; -1 when no class was
 * formed block by block. */
static long blocks_of(const char *log) {
  const char *line = strstr(log, "bases formed block by block");
  const char *at = line ? strstr(line, " blocks on this rank") : NULL;
  if (!at) return -1;
  while (at > line && at[-1] != '(') at--;
  return strtol(at, NULL, 10);
}

static void streamed_equals_memory(void **state) {
  (void)state;
  Room room;
  room_open(&room, 24, 20, 6);
  Program *prog = room.prog;
  Full *f = room.f;
  NpgTrainOptions opt_user = {.cap = 8, .energy = 0.9999};
  TrainOptions opt = {.user = &opt_user, .stream = true};
  char *log = malloc(1 << 16);
  Model *a = train_logged(prog, f, &room.src, &opt, log, 1 << 16);
  assert_int_equal(blocks_of(log), -1); /* in memory: no block */
  double ea = mean_error(prog, f, a, &room.test, room_set, room.test.S, "b");
  size_t largest = 0;
  for (int c = 0; c < a->nclasses; c++) {
    size_t bytes = (size_t)a->classes[c].n * (size_t)a->classes[c].m * sizeof(double);
    largest = bytes > largest ? bytes : largest;
  }
  long blocks[2];
  for (int run = 0; run < 2; run++) {
    opt_user.mem = largest * (run ? 4 : 8); /* above 16x: the method of snapshots, no block */
    opt_user.progress = true;
    Model *b = train_logged(prog, f, &room.src, &opt, log, 1 << 16);
    opt_user.progress = false;
    blocks[run] = blocks_of(log);
    int streamed;
    double db = basis_distance(a, b, &streamed), dt = tensor_distance(a, b);
    double eb = mean_error(prog, f, b, &room.test, room_set, room.test.S, "b");
    print_message("streamed (--mem %zu bytes, %ld blocks, %d classes without a basis) vs in memory: kept bases %.2g, "
                  "tensors %.2g, mean error of b %.6g vs %.6g\n",
                  opt_user.mem, blocks[run], streamed, db, dt, eb, ea);
    assert_true(blocks[run] > 0);
    assert_true(streamed > 0);
    assert_true(db < 1e-10 && dt < 1e-10 && fabs(eb - ea) <= 1e-10 * ea);
    model_free(b);
  }
  assert_true(blocks[1] > blocks[0]); /* measured: 8 and 78 */
  model_free(a);
  free(log);
  room_close(&room);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(streamed_equals_memory),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
