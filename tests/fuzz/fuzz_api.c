/* fuzz_api.c — libFuzzer target for sequences of npg.h calls.
 *
 * Once per process: a small program (a param, an input over a dim N, a
 * stage, a diagonal inverse, an `output op` and a solve) is compiled and
 * JIT-compiled, and a model is trained on 12 samples with N = 3. Each input
 * is then a program of calls: every byte pair picks a call and its
 * arguments — names known and unknown or NULL, shapes of any rank and
 * size (negative, zero, mismatched), values finite or not, buffers too
 * small or NULL, samples out of range, training options out of range,
 * objects NULL — on the shared evaluator (unbound between inputs) and on a
 * reduced evaluator, a trainer and models of the input's own.
 *
 * Checked on every call, as npg.h promises: nothing crashes, leaks or
 * reads out of bounds (ASan, UBSan, LeakSanitizer), and a call that fails
 * leaves a message in its object's error (a failure without one aborts).
 * Only npg.h is used, as any caller would.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static const char *program_text = "dim N\n"
                                  "param w : real[N]\n"
                                  "input x : real[N]\n"
                                  "a[i:N] = x[i]^2 + w[i]\n"
                                  "output op M[i:N, j:N] = delta(i, j) * a[i]\n"
                                  "output y[i:N] = x[i] / a[i]\n"
                                  "output z = solve(M, x)\n";

static NpgProgram *program;
static NpgFull *full;
static NpgModel *model;

static void check(int ok, const char *what, const char *msg) {
  if (!ok) {
    fprintf(stderr, "npg.h contract broken: %s (message \"%s\")\n", what, msg ? msg : "(null)");
    abort();
  }
}

static const long shape3[1] = {3};
static const double w3[3] = {1, 2, 3};

/* x of sample k: positive, varied. */
static void sample_x(long k, double *x) {
  for (int i = 0; i < 3; i++) x[i] = 0.5 + 0.37 * (double)((k * 7 + i * 3) % 11);
}

static void cleanup(void) {
  npg_model_free(model);
  npg_full_free(full);
  npg_free(program);
}

static void bind(NpgFull *f) {
  npg_full_unbind(f);
  if (npg_full_set_param(f, "w", 1, shape3, w3, "w") != 0) {
    fprintf(stderr, "fuzz_api: %s\n", npg_full_error(f));
    abort();
  }
}

static void setup(void) {
  NpgOptions opt = {0};
  opt.source = program_text;
  program = npg_compile("fuzz_api.npg", &opt);
  check(npg_ok(program), "the fuzz program compiles", npg_error(program));
  full = npg_full_new(program, NPG_TCC);
  check(!npg_full_error(full)[0], "the fuzz program JIT-compiles", npg_full_error(full));
  bind(full);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  NpgTrainer *t = npg_trainer_new(full, &o);
  for (long k = 0; k < 12; k++) {
    double x[3];
    sample_x(k, x);
    if (npg_full_set(full, "x", 1, shape3, x, "x") || npg_full_eval(full, k) || npg_trainer_add_full(t, full))
      check(0, "training the fuzz model", npg_full_error(full)[0] ? npg_full_error(full) : npg_trainer_error(t));
  }
  model = npg_trainer_finish(t, NULL);
  check(model != NULL, "training the fuzz model", npg_trainer_error(t));
  npg_trainer_free(t);
  atexit(cleanup);
}

/* The input, consumed byte by byte (zeros once it is used up). */
typedef struct Bytes {
  const uint8_t *p;
  size_t n, at;
} Bytes;

static unsigned take(Bytes *b) { return b->at < b->n ? b->p[b->at++] : 0; }

static const char *const names[] = {"x", "y", "z", "a", "w", "M", "N", "nosuch", "", NULL};

static const char *take_name(Bytes *b) { return names[take(b) % (sizeof names / sizeof *names)]; }

/* A double from one byte: ordinary values mostly, and the awkward ones. */
static double take_value(Bytes *b) {
  unsigned v = take(b);
  switch (v % 16) {
  case 0: return NAN;
  case 1: return INFINITY;
  case 2: return -INFINITY;
  case 3: return 0;
  case 4: return -0.0;
  case 5: return 1e300;
  case 6: return -1e-300;
  case 7: return -(double)(v >> 4);
  default: return 0.25 + (double)v / 16;
  }
}

typedef struct State {
  NpgReduced *r;
  NpgTrainer *t;
  NpgModel *m;      /* a model trained by this input */
  double vals[64], out[128];
  long shape[8];
} State;

/* A shape argument: ndim in [-1, 4], entries mostly 3, sometimes 0, 1, 2,
 * negative or large; NULL sometimes. */
static const long *take_shape(Bytes *b, State *s, int *ndim) {
  unsigned v = take(b);
  *ndim = (int)(v % 6) - 1;
  for (int i = 0; i < 8; i++) {
    unsigned e = take(b);
    s->shape[i] = e % 8 < 5 ? 3 : e % 8 == 5 ? (long)(e >> 3) - 2 : e % 8 == 6 ? 0 : 1L << 40;
  }
  return v >= 240 ? NULL : s->shape;
}

static const double *take_values(Bytes *b, State *s) {
  unsigned v = take(b);
  if (v >= 250) return NULL;
  for (int i = 0; i < 64; i++) s->vals[i] = v % 4 == 0 ? take_value(b) : 0.5 + 0.1 * i;
  return s->vals;
}

/* A failed call leaves a message. */
static void failed_says(int rc, const char *msg, const char *call) {
  if (rc != 0) check(msg && msg[0], call, msg);
}

static int set_sample(void *user, NpgFull *f, long k) {
  (void)user;
  double x[3];
  sample_x(k, x);
  return npg_full_set(f, "x", 1, shape3, x, "set_sample");
}

static void one_call(Bytes *b, State *s) {
  unsigned op = take(b);
  int ndim, rc;
  size_t count;
  const char *name;
  const long *shape;
  switch (op % 24) {
  case 0:
    name = take_name(b);
    shape = take_shape(b, s, &ndim);
    rc = npg_full_set(full, name, ndim, shape, take_values(b, s), take(b) % 8 ? "fuzz" : NULL);
    failed_says(rc, npg_full_error(full), "npg_full_set");
    break;
  case 1:
    rc = npg_full_eval(full, (long)take(b) - 8);
    failed_says(rc, npg_full_error(full), "npg_full_eval");
    break;
  case 2:
    npg_full_get(full, take_name(b), take(b) % 2 ? &count : NULL);
    npg_full_dim(full, take_name(b));
    break;
  case 3:
    rc = npg_full_check_finite(full, 0);
    failed_says(rc, npg_full_error(full), "npg_full_check_finite");
    break;
  case 4:
    npg_full_clear_error(full);
    break;
  case 5: /* unbind, and bind w again (or not) */
    if (take(b) % 2) bind(full);
    else npg_full_unbind(full);
    break;
  case 6:
    name = take_name(b);
    shape = take_shape(b, s, &ndim);
    rc = npg_full_set_param(full, name, ndim, shape, take_values(b, s), "fuzz");
    failed_says(rc, npg_full_error(full), "npg_full_set_param");
    break;
  case 7: {
    NpgCsr K = {0};
    rc = npg_full_op(full, take_name(b), take(b) % 8 ? &K : NULL);
    failed_says(rc, npg_full_error(full), "npg_full_op");
    npg_csr_free(&K);
    break;
  }
  case 8:
    if (!s->r) s->r = npg_reduced_new(take(b) % 16 ? (s->m && take(b) % 2 ? s->m : model) : NULL);
    name = take_name(b);
    count = take(b) % 8;
    rc = npg_reduced_set(s->r, name, count, take_values(b, s));
    failed_says(rc, npg_reduced_error(s->r), "npg_reduced_set");
    break;
  case 9:
    if (!s->r) break;
    name = take_name(b);
    rc = npg_reduced_set_coords(s->r, name, take(b) % 8, take_values(b, s));
    failed_says(rc, npg_reduced_error(s->r), "npg_reduced_set_coords");
    break;
  case 10:
    if (!s->r) break;
    rc = npg_reduced_eval(s->r, (long)take(b));
    failed_says(rc, npg_reduced_error(s->r), "npg_reduced_eval");
    break;
  case 11:
    if (!s->r) break;
    name = take_name(b);
    count = take(b) % 8;
    rc = npg_reduced_lift(s->r, name, take(b) % 8 ? s->out : NULL, count);
    failed_says(rc, npg_reduced_error(s->r), "npg_reduced_lift");
    break;
  case 12:
    if (!s->r) break;
    npg_reduced_coords(s->r, take_name(b), take(b) % 2 ? &count : NULL);
    npg_reduced_clear_error(s->r);
    break;
  case 13:
    if (!s->r) break;
    npg_reduced_given_externs(s->r, take(b) % 2);
    npg_reduced_exact_roots(s->r, take(b) % 2);
    break;
  case 14: {
    if (!s->r) break;
    long rows = 0, cols = 0;
    int rcl, ccl;
    rc = npg_reduced_op(s->r, take_name(b), take(b) % 8 ? s->out : NULL, take(b) % 80, &rows, &cols, &rcl, &ccl);
    failed_says(rc, npg_reduced_error(s->r), "npg_reduced_op");
    break;
  }
  case 15: /* a trainer with options in or out of range */
    if (s->t) break;
    {
      NpgTrainOptions o;
      npg_train_options_default(&o);
      unsigned v = take(b);
      if (v % 5 == 1) o.cap = (int)take(b) - 4;
      if (v % 5 == 2) o.energy = take_value(b);
      if (v % 5 == 3) o.mem = take(b) % 3;
      o.joint = v & 32;
      o.uncentered = v & 64;
      s->t = npg_trainer_new(take(b) % 16 ? full : NULL, v % 5 == 4 ? NULL : &o);
    }
    break;
  case 16:
    if (!s->t) break;
    name = take_name(b);
    shape = take_shape(b, s, &ndim);
    rc = npg_trainer_set(s->t, name, ndim, shape, take_values(b, s));
    failed_says(rc, npg_trainer_error(s->t), "npg_trainer_set");
    break;
  case 17:
    if (!s->t) break;
    rc = take(b) % 2 ? npg_trainer_add(s->t) : npg_trainer_add_full(s->t, take(b) % 8 ? full : NULL);
    failed_says(rc, npg_trainer_error(s->t), "npg_trainer_add");
    break;
  case 18: /* finish (a few samples at most: training is the slow call) */
    if (!s->t || s->m || npg_trainer_samples(s->t) > 6) break;
    s->m = npg_trainer_finish(s->t, NULL);
    if (!s->m) check(npg_trainer_error(s->t)[0], "npg_trainer_finish", npg_trainer_error(s->t));
    npg_trainer_free(s->t);
    s->t = NULL;
    break;
  case 19: { /* model queries with any index */
    const NpgModel *m = take(b) % 4 ? model : s->m;
    NpgClassInfo ci;
    NpgMemberInfo mi;
    int c = (int)take(b) - 2, i = (int)take(b) - 2;
    npg_model_nclasses(m);
    npg_model_class(m, c, take(b) % 8 ? &ci : NULL);
    npg_model_member(m, c, i, take(b) % 8 ? &mi : NULL);
    npg_model_class_of(m, take_name(b));
    npg_model_basis(m, c);
    npg_model_bytes(m, NULL);
    npg_model_samples(m);
    npg_model_dim(m, take_name(b));
    break;
  }
  case 20: { /* parameters against the model */
    char err[256] = "";
    rc = npg_model_check_params(take(b) % 8 ? model : NULL, take(b) % 8 ? full : NULL, err, sizeof err);
    failed_says(rc, err, "npg_model_check_params");
    break;
  }
  case 21: { /* a short verification */
    NpgVerifyReport rep;
    rc = npg_verify(model, full, (long)(take(b) % 4), take(b) % 8 ? set_sample : NULL, NULL, false, &rep);
    failed_says(rc, rep.error, "npg_verify");
    npg_verify_free(&rep);
    npg_full_clear_error(full);
    break;
  }
  case 22: { /* the program's symbols */
    NpgSymbol sym;
    npg_symbol(program, (int)take(b) - 2, take(b) % 8 ? &sym : NULL);
    npg_nsymbols(take(b) % 8 ? program : NULL);
    break;
  }
  case 23: /* a fresh reduced evaluator */
    npg_reduced_free(s->r);
    s->r = NULL;
    break;
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static int ready;
  if (!ready) {
    setup();
    ready = 1;
  }
  bind(full);
  Bytes b = {data, size, 0};
  State s;
  memset(&s, 0, sizeof s);
  for (int calls = 0; b.at < b.n && calls < 64; calls++) one_call(&b, &s);
  npg_reduced_free(s.r);
  npg_trainer_free(s.t);
  npg_model_free(s.m);
  return 0;
}
