/* trial2_api.c — the npg.h cases of the second hostile trial
 * (tests/hostile/trial2.py compiles it against the build's libnpg and runs
 * one case per process: trial2_api CASE WORKDIR).
 *
 * Each case prints "OK" plus what it measured on stdout when the library
 * behaved (a refusal with a message naming the argument, or a value equal
 * to the one computed here independently), "BAD ..." when it did not; the
 * harness also fails a case on a signal or a sanitizer report.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "npg.h"

static const char *W;
static char errbuf[2048];

/* an error getter's answer: NULL or "" when there is none */
static int has_err(const char *e) { return e && *e; }

static int bad(const char *why, const char *detail) {
  printf("BAD %s: %s\n", why, detail ? detail : "(no message)");
  return 1;
}

static int ok(const char *what) {
  printf("OK %s\n", what);
  return 0;
}

/* a refusal is correct when it returns failure with a non-empty message holding `word` */
static int refused(int rc, const char *msg, const char *word) {
  if (rc == 0) return bad("accepted", msg);
  if (!msg || !*msg) return bad("refused without a message", NULL);
  if (word && !strstr(msg, word)) return bad("message does not name the argument", msg);
  return ok(msg);
}

/* Every object a case makes, freed when it returns (in dependency order), so
 * that the sanitizer build's leak check sees the library's leaks only. */
enum { T_RED, T_MODEL, T_TRAINER, T_FULL, T_PROG, T_KINDS };
static void *made[T_KINDS][32];
static int nmade[T_KINDS];

static void *track(int kind, void *o) {
  if (!o) return o;
  for (int i = 0; i < nmade[kind]; i++)
    if (made[kind][i] == o) return o;
  if (nmade[kind] < 32) made[kind][nmade[kind]++] = o;
  return o;
}

static void free_all(void) {
  for (int i = nmade[T_RED]; i-- > 0;) npg_reduced_free(made[T_RED][i]);
  for (int i = nmade[T_MODEL]; i-- > 0;) npg_model_free(made[T_MODEL][i]);
  for (int i = nmade[T_TRAINER]; i-- > 0;) npg_trainer_free(made[T_TRAINER][i]);
  for (int i = nmade[T_FULL]; i-- > 0;) npg_full_free(made[T_FULL][i]);
  for (int i = nmade[T_PROG]; i-- > 0;) npg_free(made[T_PROG][i]);
}

/* the call first, then its error getter (C leaves the order of arguments unspecified) */
#define REFUSED(call, msg, word) \
  __extension__({                \
    int rc_ = (call);            \
    refused(rc_, (msg), (word)); \
  })

static NpgProgram *prog(const char *name) {
  char p[1024];
  snprintf(p, sizeof p, "%s/%s", W, name);
  NpgProgram *g = track(T_PROG, npg_compile(p, NULL));
  if (!npg_ok(g)) {
    fprintf(stderr, "compile %s: %s\n", p, npg_error(g));
    exit(3);
  }
  return g;
}

/* vec.npg: y[i] = rho[i] x[i]^2 + x[i] */
static NpgFull *vec_full(NpgProgram **pp) {
  *pp = prog("vec.npg");
  NpgFull *f = track(T_FULL, npg_full_new(*pp, NPG_TCC));
  if (!f) exit(3);
  return f;
}

static const double RHO[5] = {1.5, 0.25, -2, 3, 0.125};
static const double XV[5] = {1, -2, 0.5, 4, 3};

static int set_rho(NpgFull *f) {
  long s[1] = {5};
  return npg_full_set_param(f, "rho", 1, s, RHO, "rho.api");
}

static int check_vec(NpgFull *f, const double *x) {
  size_t n = 0;
  const double *y = npg_full_get(f, "y", &n);
  if (!y || n != 5) return bad("no y after evaluation", npg_full_error(f));
  for (int i = 0; i < 5; i++) {
    double want = RHO[i] * x[i] * x[i] + x[i];
    if (fabs(y[i] - want) > 1e-13 * (1 + fabs(want))) {
      char d[128];
      snprintf(d, sizeof d, "y[%d] = %.17g, want %.17g", i, y[i], want);
      return bad("wrong value", d);
    }
  }
  return ok("values equal");
}

static int run_case(int argc, char **argv) {
  if (argc < 3) return 2;
  const char *c = argv[1];
  W = argv[2];
  NpgProgram *p = NULL;
  long s5[1] = {5}, s6[1] = {6}, s55[2] = {5, 1};
  int rc = 0;

  /* ---- full evaluation: values and call orders */
  if (!strcmp(c, "full_values")) {
    NpgFull *f = vec_full(&p);
    if (set_rho(f) || npg_full_set(f, "x", 1, s5, XV, "api") || npg_full_eval(f, 0))
      return bad("evaluation failed", npg_full_error(f));
    rc = check_vec(f, XV);
    return rc;
  }
  if (!strcmp(c, "full_param_changed_between_evals")) {
    /* a param set again must be used by the next evaluation, not the first binding */
    NpgFull *f = vec_full(&p);
    set_rho(f);
    npg_full_set(f, "x", 1, s5, XV, "api");
    npg_full_eval(f, 0);
    double rho2[5] = {0, 0, 0, 0, 0};
    if (npg_full_set_param(f, "rho", 1, s5, rho2, "api") == 0) {
      npg_full_eval(f, 1);
      size_t n;
      const double *y = npg_full_get(f, "y", &n);
      for (int i = 0; i < 5; i++)
        if (y && fabs(y[i] - XV[i]) > 1e-14) return bad("old param used after npg_full_set_param", NULL);
      return ok("new param used");
    }
    return refused(1, npg_full_error(f), "rho");
  }
  if (!strcmp(c, "full_input_changed_in_place")) {
    /* the caller's array changed after npg_full_set (copy=false): the documented contract decides; the
       value must be either the old or the new input's, never a mix */
    NpgFull *f = vec_full(&p);
    set_rho(f);
    double x[5];
    memcpy(x, XV, sizeof x);
    npg_full_set(f, "x", 1, s5, x, "api");
    npg_full_eval(f, 0);
    for (int i = 0; i < 5; i++) x[i] = 2 * XV[i];
    npg_full_eval(f, 1);
    size_t n;
    const double *y = npg_full_get(f, "y", &n);
    int same_old = 1, same_new = 1;
    for (int i = 0; i < 5; i++) {
      double a = RHO[i] * XV[i] * XV[i] + XV[i], b = RHO[i] * x[i] * x[i] + x[i];
      if (fabs(y[i] - a) > 1e-13 * (1 + fabs(a))) same_old = 0;
      if (fabs(y[i] - b) > 1e-13 * (1 + fabs(b))) same_new = 0;
    }
    return same_old || same_new ? ok("consistent") : bad("a mix of old and new input", NULL);
  }
  if (!strcmp(c, "full_set_wrong_ndim")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    int r = npg_full_set(f, "x", 2, s55, XV, "api");
    if (r == 0) r = npg_full_eval(f, 0);
    return refused(r, npg_full_error(f), "x");
  }
  if (!strcmp(c, "full_set_wrong_size")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    double x6[6] = {1, 2, 3, 4, 5, 6};
    int r = npg_full_set(f, "x", 1, s6, x6, "x.api");
    if (r == 0) r = npg_full_eval(f, 0);
    return refused(r, npg_full_error(f), "x.api");
  }
  if (!strcmp(c, "full_set_param_as_input")) {
    /* npg_full_set takes a param too (npg.h): then it must be the one used */
    NpgFull *f = vec_full(&p);
    if (npg_full_set(f, "rho", 1, s5, RHO, "api")) return refused(1, npg_full_error(f), "rho");
    npg_full_set(f, "x", 1, s5, XV, "api");
    if (npg_full_eval(f, 0)) return bad("eval", npg_full_error(f));
    return check_vec(f, XV);
  }
  if (!strcmp(c, "full_set_input_as_param")) {
    NpgFull *f = vec_full(&p);
    return REFUSED(npg_full_set_param(f, "x", 1, s5, XV, "api"), npg_full_error(f), "x");
  }
  if (!strcmp(c, "full_set_output")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    return REFUSED(npg_full_set(f, "y", 1, s5, XV, "api"), npg_full_error(f), "y");
  }
  if (!strcmp(c, "full_set_negative_shape")) {
    NpgFull *f = vec_full(&p);
    long neg[1] = {-5};
    return REFUSED(npg_full_set_param(f, "rho", 1, neg, RHO, "api"), npg_full_error(f), NULL);
  }
  if (!strcmp(c, "full_set_denormal")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    double x[5] = {4.9e-324, -4.9e-324, 1e-310, 2.2e-308, 0};
    if (npg_full_set(f, "x", 1, s5, x, "api") || npg_full_eval(f, 0)) return bad("denormal refused", npg_full_error(f));
    return check_vec(f, x);
  }
  if (!strcmp(c, "full_set_huge_overflows")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    double x[5] = {1e300, 1, 1, 1, 1};
    int r = npg_full_set(f, "x", 1, s5, x, "api");
    if (r == 0) r = npg_full_eval(f, 0);
    if (r == 0) r = npg_full_check_finite(f, 0);
    return refused(r, npg_full_error(f), "y");
  }
  if (!strcmp(c, "full_get_before_eval")) {
    NpgFull *f = vec_full(&p);
    size_t n = 77;
    const double *y = npg_full_get(f, "y", &n);
    return y ? bad("npg_full_get returned values before any evaluation", NULL) : ok("NULL");
  }
  if (!strcmp(c, "full_get_unknown")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    npg_full_set(f, "x", 1, s5, XV, "api");
    npg_full_eval(f, 0);
    size_t n;
    const double *y = npg_full_get(f, "nosuch", &n);
    return y ? bad("values for an unknown name", NULL) : ok("NULL");
  }
  if (!strcmp(c, "full_dim_unknown")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    long d = npg_full_dim(f, "Q");
    return d >= 0 ? bad("a size for an unknown dim", NULL) : ok("negative");
  }
  if (!strcmp(c, "full_eval_after_unbind")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    npg_full_set(f, "x", 1, s5, XV, "api");
    npg_full_eval(f, 0);
    npg_full_unbind(f);
    return REFUSED(npg_full_eval(f, 1), npg_full_error(f), NULL);
  }
  if (!strcmp(c, "full_eval_negative_sample")) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    npg_full_set(f, "x", 1, s5, XV, "api");
    int r = npg_full_eval(f, -7);
    if (r == 0) return check_vec(f, XV); /* the sample number only labels messages */
    return refused(r, npg_full_error(f), "sample");
  }
  if (!strcmp(c, "full_bind_params_missing_dir")) {
    NpgFull *f = vec_full(&p);
    char d[1024];
    snprintf(d, sizeof d, "%s/nosuchdir", W);
    return REFUSED(npg_full_bind_params(f, d), npg_full_error(f), "nosuchdir");
  }
  if (!strcmp(c, "full_bind_params_then_set")) {
    /* a folder's params, then a set_param over them: the last one counts */
    NpgFull *f = vec_full(&p);
    char d[1024];
    snprintf(d, sizeof d, "%s/D", W);
    if (npg_full_bind_params(f, d)) return bad("bind", npg_full_error(f));
    set_rho(f);
    npg_full_set(f, "x", 1, s5, XV, "api");
    if (npg_full_eval(f, 0)) return bad("eval", npg_full_error(f));
    return check_vec(f, XV);
  }
  if (!strcmp(c, "full_two_evaluators_one_program")) {
    p = prog("vec.npg");
    NpgFull *a = track(T_FULL, npg_full_new(p, NPG_TCC)), *b = track(T_FULL, npg_full_new(p, NPG_TCC));
    set_rho(a);
    double rho2[5] = {1, 1, 1, 1, 1};
    npg_full_set_param(b, "rho", 1, s5, rho2, "api");
    npg_full_set(a, "x", 1, s5, XV, "api");
    npg_full_set(b, "x", 1, s5, XV, "api");
    npg_full_eval(a, 0);
    npg_full_eval(b, 0);
    rc = check_vec(a, XV);
    return rc;
  }
  if (!strcmp(c, "full_program_freed_first")) {
    /* npg_free of the program while an evaluator lives: documented order or a refusal, never a crash.
       The header says the program must outlive it; this case only frees in the right order. */
    NpgFull *f = vec_full(&p);
    set_rho(f);
    npg_full_set(f, "x", 1, s5, XV, "api");
    npg_full_eval(f, 0);
    rc = check_vec(f, XV);
    return rc;
  }
  if (!strcmp(c, "full_cc_backend_values")) {
    p = prog("vec.npg");
    NpgFull *f = track(T_FULL, npg_full_new(p, NPG_CC));
    if (!has_err(npg_full_error(f))) {
      set_rho(f);
      npg_full_set(f, "x", 1, s5, XV, "api");
      if (npg_full_eval(f, 0)) return bad("cc eval", npg_full_error(f));
      return check_vec(f, XV);
    }
    return bad("cc backend", npg_full_error(f));
  }
  /* ---- .npy writer and reader */
  if (!strncmp(c, "npy_", 4)) {
    char path[1024];
    snprintf(path, sizeof path, "%s/api_%s.npy", W, c);
    double v[6] = {1, 2, 3, 4, 5, 6};
    if (!strcmp(c, "npy_ndim_zero_roundtrip")) {
      if (npg_npy_write(path, 0, NULL, v, errbuf, sizeof errbuf)) return refused(1, errbuf, NULL);
      int nd;
      long sh[NPG_NPY_MAX_DIMS];
      size_t n;
      double *r = npg_npy_read(path, &nd, sh, &n, errbuf, sizeof errbuf);
      if (!r) return bad("read back", errbuf);
      int good = nd == 0 && n == 1 && r[0] == 1;
      free(r);
      return good ? ok("scalar") : bad("scalar roundtrip", NULL);
    }
    if (!strcmp(c, "npy_ndim_nine"))
      return REFUSED(npg_npy_write(path, 9, (long[9]){1, 1, 1, 1, 1, 1, 1, 1, 6}, v, errbuf, sizeof errbuf), errbuf,
                     NULL);
    if (!strcmp(c, "npy_ndim_negative"))
      return REFUSED(npg_npy_write(path, -1, s5, v, errbuf, sizeof errbuf), errbuf, NULL);
    if (!strcmp(c, "npy_zero_extent_roundtrip")) {
      long sh0[2] = {0, 3};
      if (npg_npy_write(path, 2, sh0, v, errbuf, sizeof errbuf)) return bad("write", errbuf);
      int nd;
      long sh[NPG_NPY_MAX_DIMS];
      size_t n = 9;
      double *r = npg_npy_read(path, &nd, sh, &n, errbuf, sizeof errbuf);
      int good = nd == 2 && sh[0] == 0 && sh[1] == 3 && n == 0;
      free(r);
      return good ? ok("empty") : bad("empty roundtrip", errbuf);
    }
    if (!strcmp(c, "npy_write_into_missing_dir")) {
      snprintf(path, sizeof path, "%s/no/such/dir/a.npy", W);
      int r = npg_npy_write(path, 1, s6, v, errbuf, sizeof errbuf);
      if (r == 0 && access(path, F_OK) == 0) return ok("created parents");
      return refused(r, errbuf, "no/such/dir");
    }
    if (!strcmp(c, "npy_write_over_directory")) {
      snprintf(path, sizeof path, "%s/D", W);
      return REFUSED(npg_npy_write(path, 1, s6, v, errbuf, sizeof errbuf), errbuf, "D");
    }
    if (!strcmp(c, "npy_write_nan_roundtrip")) {
      double w[2] = {NAN, -INFINITY};
      long s2[1] = {2};
      if (npg_npy_write(path, 1, s2, w, errbuf, sizeof errbuf)) return refused(1, errbuf, NULL);
      int nd;
      long sh[NPG_NPY_MAX_DIMS];
      size_t n;
      double *r = npg_npy_read(path, &nd, sh, &n, errbuf, sizeof errbuf);
      int good = r && isnan(r[0]) && isinf(r[1]) && r[1] < 0;
      free(r);
      return good ? ok("nan kept") : bad("nan roundtrip", errbuf);
    }
    if (!strcmp(c, "npy_read_missing")) {
      int nd;
      long sh[NPG_NPY_MAX_DIMS];
      size_t n;
      double *r = npg_npy_read(path, &nd, sh, &n, errbuf, sizeof errbuf);
      return r ? bad("read a missing file", NULL) : refused(1, errbuf, "api_npy_read_missing");
    }
    if (!strcmp(c, "npy_read_tiny_errbuf")) {
      int nd;
      long sh[NPG_NPY_MAX_DIMS];
      size_t n;
      char tiny[4] = {'x', 'x', 'x', 'x'};
      double *r = npg_npy_read(path, &nd, sh, &n, tiny, 3);
      if (r) return bad("read a missing file", NULL);
      return tiny[2] == 0 && tiny[3] == 'x' ? ok("truncated message") : bad("errbuf overrun or unterminated", NULL);
    }
    if (!strcmp(c, "npy_read_zero_errbuf")) {
      int nd;
      long sh[NPG_NPY_MAX_DIMS];
      size_t n;
      char none[1] = {'q'};
      double *r = npg_npy_read(path, &nd, sh, &n, none, 0);
      return r ? bad("read a missing file", NULL) : none[0] == 'q' ? ok("untouched") : bad("wrote to a 0-byte buffer", NULL);
    }
  }
  /* ---- number parsers: value or refusal, never a quiet wrong value */
  if (!strncmp(c, "parse_double:", 13) || !strncmp(c, "parse_long:", 11)) {
    const char *s = strchr(c, ':') + 1;
    if (!strcmp(s, "<empty>")) s = "";
    if (c[6] == 'd') {
      double v = -12345;
      int r = npg_parse_double(s, -1e308, 1e308, false, &v, errbuf, sizeof errbuf);
      if (r == 0) printf("VALUE %.17g\n", v);
      else printf("REFUSED %s\n", errbuf);
    } else {
      long v = -12345;
      int r = npg_parse_long(s, -4000000000000000000L, 4000000000000000000L, &v, errbuf, sizeof errbuf);
      if (r == 0) printf("VALUE %ld\n", v);
      else printf("REFUSED %s\n", errbuf);
    }
    return 0;
  }
  /* ---- training, models, reduced evaluation */
  if (!strncmp(c, "train_", 6) || !strncmp(c, "model_", 6) || !strncmp(c, "reduced_", 8)) {
    NpgFull *f = vec_full(&p);
    set_rho(f);
    NpgTrainOptions o;
    npg_train_options_default(&o);
    if (!strcmp(c, "train_cap_int_max")) {
      o.cap = 2147483647;
      NpgTrainer *t = track(T_TRAINER, npg_trainer_new(f, &o));
      if (!t) return ok("refused (NULL)");
      const char *e = npg_trainer_error(t);
      if (has_err(e)) return refused(1, e, "cap");
      /* accepted: a cap above the data's rank is a ceiling; training must still work */
      for (int k = 0; k < 8; k++) {
        double x[5];
        for (int i = 0; i < 5; i++) x[i] = 1 + 0.1 * k * (i + 1) + 0.01 * k * k;
        npg_trainer_set(t, "x", 1, s5, x);
        if (npg_trainer_add(t)) return bad("add", npg_trainer_error(t));
      }
      char d[1024];
      snprintf(d, sizeof d, "%s/api_capmax", W);
      NpgModel *m = track(T_MODEL, npg_trainer_finish(t, d));
      if (!m || has_err(npg_model_error(m))) return bad("finish", m ? npg_model_error(m) : npg_trainer_error(t));
      return ok("trained");
    }
    NpgTrainer *t = track(T_TRAINER, npg_trainer_new(f, &o));
    if (!t) return bad("trainer_new", npg_full_error(f));
    int S = !strcmp(c, "train_one_sample") ? 1 : 8;
    for (int k = 0; k < S; k++) {
      double x[5];
      for (int i = 0; i < 5; i++) x[i] = 1 + 0.1 * k * (i + 1) + 0.01 * k * k * i;
      if (npg_trainer_set(t, "x", 1, s5, x) || npg_trainer_add(t)) return bad("add", npg_trainer_error(t));
    }
    if (!strcmp(c, "train_set_wrong_size")) {
      double x6[6] = {1, 2, 3, 4, 5, 6};
      int r = npg_trainer_set(t, "x", 1, s6, x6);
      if (r == 0) r = npg_trainer_add(t);
      return refused(r, npg_trainer_error(t), "x");
    }
    if (!strcmp(c, "train_set_param_name")) return REFUSED(npg_trainer_set(t, "rho", 1, s5, RHO), npg_trainer_error(t), "rho");
    if (!strcmp(c, "train_add_full_other_program")) {
      NpgProgram *q = prog("two.npg");
      NpgFull *g = track(T_FULL, npg_full_new(q, NPG_TCC));
      double z[5] = {1, 2, 3, 4, 5};
      npg_full_set(g, "x", 1, s5, z, "api");
      npg_full_set(g, "z", 1, s5, z, "api");
      npg_full_eval(g, 0);
      int r = npg_trainer_add_full(t, g);
      if (r != 0) return refused(r, npg_trainer_error(t), NULL);
      NpgModel *m = track(T_MODEL, npg_trainer_finish(t, NULL));
      if (m && !has_err(npg_model_error(m))) return bad("a model trained on a sample of another program", NULL);
      return refused(1, npg_trainer_error(t), NULL);
    }
    if (!strcmp(c, "train_add_full_smaller_program")) {
      /* an evaluator of another program whose x has 3 entries, not 5: refused, or at least never read
         past its 3 values (the sanitizer build watches) */
      NpgProgram *q = prog("two.npg");
      NpgFull *g = track(T_FULL, npg_full_new(q, NPG_TCC));
      double z[3] = {1, 2, 3};
      long s3[1] = {3};
      npg_full_set(g, "x", 1, s3, z, "x3.api");
      npg_full_set(g, "z", 1, s3, z, "z3.api");
      if (npg_full_eval(g, 0)) return bad("eval of two.npg", npg_full_error(g));
      int r = npg_trainer_add_full(t, g);
      if (r != 0) return refused(r, npg_trainer_error(t), NULL);
      NpgModel *m = track(T_MODEL, npg_trainer_finish(t, NULL));
      if (m && !has_err(npg_model_error(m))) return bad("a model trained on a sample of another program", NULL);
      return refused(1, npg_trainer_error(t), NULL);
    }
    char d[1024];
    snprintf(d, sizeof d, "%s/api_%s", W, c);
    if (!strcmp(c, "train_finish_twice")) {
      NpgModel *m = track(T_MODEL, npg_trainer_finish(t, NULL));
      NpgModel *m2 = track(T_MODEL, npg_trainer_finish(t, NULL));
      if (!m2 || has_err(npg_model_error(m2))) return ok("second finish refused");
      /* a second model of the same samples: it must be the same model */
      const double *b1 = npg_model_basis(m, 0), *b2 = npg_model_basis(m2, 0);
      NpgClassInfo c1, c2;
      npg_model_class(m, 0, &c1);
      npg_model_class(m2, 0, &c2);
      if (c1.m != c2.m || memcmp(b1, b2, sizeof(double) * (size_t)(c1.n * c1.m)))
        return bad("a second finish gave another model", NULL);
      return ok("the same model again");
    }
    if (!strcmp(c, "train_add_after_finish")) {
      track(T_MODEL, npg_trainer_finish(t, NULL));
      double x[5] = {1, 1, 1, 1, 1};
      int r = npg_trainer_set(t, "x", 1, s5, x);
      if (r == 0) r = npg_trainer_add(t);
      if (r != 0) return refused(r, npg_trainer_error(t), NULL);
      /* accepted: training goes on, and a new finish counts the sample */
      NpgModel *m2 = track(T_MODEL, npg_trainer_finish(t, NULL));
      if (!m2 || has_err(npg_model_error(m2))) return bad("finish after a later add", npg_trainer_error(t));
      return npg_model_samples(m2) == S + 1 ? ok("9 samples") : bad("the later sample is not counted", NULL);
    }
    if (!strcmp(c, "train_finish_into_data_dir")) {
      snprintf(d, sizeof d, "%s/D", W);
      NpgModel *m = track(T_MODEL, npg_trainer_finish(t, d));
      char x[1024];
      snprintf(x, sizeof x, "%s/D/x.npy", W);
      if (access(x, F_OK) != 0) return bad("the data folder's x.npy was lost", NULL);
      if (m && !has_err(npg_model_error(m))) return bad("a model written over a data folder", NULL);
      return refused(1, m ? npg_model_error(m) : npg_trainer_error(t), "D");
    }
    NpgModel *m = track(T_MODEL, npg_trainer_finish(t, !strcmp(c, "model_save_twice") ? NULL : d));
    if (!m || has_err(npg_model_error(m))) return bad("finish", m ? npg_model_error(m) : npg_trainer_error(t));
    if (!strcmp(c, "train_one_sample")) return ok("one sample trained");
    if (!strcmp(c, "model_save_twice")) {
      if (npg_model_save(m, d)) return bad("save", npg_model_error(m));
      int r = npg_model_save(m, d);
      return r == 0 ? ok("saved again over its own model") : refused(r, npg_model_error(m), NULL);
    }
    if (!strcmp(c, "model_load_with_other_program")) {
      NpgProgram *q = prog("two.npg");
      NpgModel *l = track(T_MODEL, npg_model_load(q, d));
      return refused(!l || has_err(npg_model_error(l)) ? 1 : 0, l ? npg_model_error(l) : "NULL", "program");
    }
    if (!strcmp(c, "model_dim_unknown")) return npg_model_dim(m, "Q") >= 0 ? bad("size of unknown dim", NULL) : ok("neg");
    if (!strcmp(c, "model_spectra_name_is_a_folder")) {
      /* a folder in the place of one spectrum: refused before any spectrum is written */
      char sp[1024], q[1100];
      snprintf(sp, sizeof sp, "%s/api_spectra", W);
      snprintf(q, sizeof q, "%s/spectrum_y.csv", sp);
      if (mkdir(sp, 0755) != 0 || mkdir(q, 0755) != 0) return bad("cannot make the folders", sp);
      char err[1024] = "";
      int r = npg_model_write_spectra(m, sp, err, sizeof err);
      const char *names[] = {"spectrum_x.npy", "spectrum_x.csv", "spectrum_y.npy"};
      for (int i = 0; i < 3; i++) {
        snprintf(q, sizeof q, "%s/%s", sp, names[i]);
        if (access(q, F_OK) == 0) return bad("a spectrum was written before the refusal", q);
      }
      return refused(r, err, "spectrum_y.csv");
    }
    if (!strcmp(c, "model_class_out_of_range")) {
      NpgClassInfo ci;
      return REFUSED(npg_model_class(m, 99, &ci) == 0 ? 0 : 1, npg_model_error(m), NULL);
    }
    if (!strcmp(c, "model_basis_negative_class"))
      return npg_model_basis(m, -1) ? bad("a basis for class -1", NULL) : ok("NULL");
    NpgReduced *r = track(T_RED, npg_reduced_new(m));
    if (!r) return bad("reduced_new", NULL);
    double x[5] = {1.1, 1.2, 1.3, 1.4, 1.5};
    if (!strcmp(c, "reduced_set_wrong_count")) return REFUSED(npg_reduced_set(r, "x", 4, x), npg_reduced_error(r), "x");
    if (!strcmp(c, "reduced_set_coords_too_many")) {
      double cc[200] = {0};
      return REFUSED(npg_reduced_set_coords(r, "x", 200, cc), npg_reduced_error(r), "x");
    }
    if (!strcmp(c, "reduced_set_nan_coords")) {
      size_t mm = 0;
      npg_reduced_set(r, "x", 5, x);
      npg_reduced_eval(r, 0);
      const double *cx = npg_reduced_coords(r, "x", &mm);
      double cc[64];
      for (size_t i = 0; i < mm && i < 64; i++) cc[i] = cx[i];
      cc[0] = NAN;
      int e = npg_reduced_set_coords(r, "x", mm, cc);
      if (e == 0) e = npg_reduced_eval(r, 1);
      return refused(e, npg_reduced_error(r), NULL);
    }
    if (!strcmp(c, "reduced_lift_wrong_count")) {
      npg_reduced_set(r, "x", 5, x);
      npg_reduced_eval(r, 0);
      double out[4];
      return REFUSED(npg_reduced_lift(r, "y", out, 4), npg_reduced_error(r), NULL);
    }
    if (!strcmp(c, "reduced_lift_an_input")) {
      /* lifting x gives its projection on the basis: within the training span it is x itself */
      double xin[5];
      for (int i = 0; i < 5; i++) xin[i] = 1 + 0.1 * 3 * (i + 1) + 0.01 * 9 * i;
      npg_reduced_set(r, "x", 5, xin);
      npg_reduced_eval(r, 0);
      double out[5];
      if (npg_reduced_lift(r, "x", out, 5)) return bad("lift x", npg_reduced_error(r));
      for (int i = 0; i < 5; i++)
        if (fabs(out[i] - xin[i]) > 1e-8) return bad("lifted training sample differs from itself", NULL);
      return ok("x");
    }
    if (!strcmp(c, "reduced_two_on_one_model")) {
      NpgReduced *r2 = track(T_RED, npg_reduced_new(m));
      double x2[5] = {1.5, 1.5, 1.5, 1.5, 1.5};
      npg_reduced_set(r, "x", 5, x);
      npg_reduced_set(r2, "x", 5, x2);
      npg_reduced_eval(r, 0);
      npg_reduced_eval(r2, 0);
      double a[5], b[5];
      npg_reduced_lift(r, "y", a, 5);
      npg_reduced_eval(r, 1);
      npg_reduced_lift(r, "y", b, 5);
      for (int i = 0; i < 5; i++)
        if (a[i] != b[i]) return bad("another evaluator changed this one's result", NULL);
      return ok("independent");
    }
    if (!strcmp(c, "reduced_eval_repeat_same")) {
      npg_reduced_set(r, "x", 5, x);
      npg_reduced_eval(r, 0);
      double a[5], b[5];
      npg_reduced_lift(r, "y", a, 5);
      npg_reduced_eval(r, 0);
      npg_reduced_lift(r, "y", b, 5);
      return memcmp(a, b, sizeof a) ? bad("two evaluations of one input differ", NULL) : ok("same");
    }
    if (!strcmp(c, "reduced_op_no_such")) {
      double out[4];
      long rr, cc2;
      int rcl, ccl;
      return REFUSED(npg_reduced_op(r, "nosuch", out, 4, &rr, &cc2, &rcl, &ccl), npg_reduced_error(r), "nosuch");
    }
    if (!strcmp(c, "reduced_coords_before_eval")) {
      /* nothing was set or evaluated: there are no coordinates of y (npg_reduced_lift refuses the same) */
      size_t mm = 0;
      const double *cy = npg_reduced_coords(r, "y", &mm);
      return cy ? bad("coordinates of y before any evaluation", "zeros") : ok("NULL");
    }
    if (!strcmp(c, "reduced_coords_unknown")) {
      size_t mm = 5;
      return npg_reduced_coords(r, "nosuch", &mm) ? bad("coords of unknown", NULL) : ok("NULL");
    }
    if (!strcmp(c, "reduced_accuracy_in_span")) {
      /* an input inside the training span: reduced equals full to 1e-6 */
      double xin[5];
      for (int i = 0; i < 5; i++) xin[i] = 1 + 0.1 * 2.5 * (i + 1) + 0.01 * 6.25 * i;
      npg_reduced_set(r, "x", 5, xin);
      if (npg_reduced_eval(r, 0)) return bad("eval", npg_reduced_error(r));
      double y[5];
      npg_reduced_lift(r, "y", y, 5);
      double err = 0, nrm = 0;
      for (int i = 0; i < 5; i++) {
        double w = RHO[i] * xin[i] * xin[i] + xin[i];
        err += (y[i] - w) * (y[i] - w);
        nrm += w * w;
      }
      printf("REL %.3e\n", sqrt(err / nrm));
      return ok("measured");
    }
    return bad("unknown case", c);
  }
  return bad("unknown case", c);
}

int main(int argc, char **argv) {
  int rc = run_case(argc, argv);
  fflush(stdout);
  free_all();
  return rc;
}
