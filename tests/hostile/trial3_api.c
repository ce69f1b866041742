/* trial3_api.c — the npg.h cases of the third hostile trial
 * (tests/hostile/trial3.py compiles it against the build's libnpg and runs
 * one case per process: trial3_api CASE WORKDIR, on the n-body program and
 * data the script wrote under WORKDIR/ip).
 *
 * A sample function (NpgSampleFn) may call npg_full_set on a param: the
 * validation samples of a trainer and the test samples of npg_verify must
 * then be refused naming the param, never compared with a full evaluation
 * of other params (nor recorded in the model). Prints "OK <message>" when
 * the library refused as it should, "BAD ..." otherwise.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"

static char path_buf[4096];

static const char *at(const char *w, const char *rel) {
  snprintf(path_buf, sizeof path_buf, "%s/%s", w, rel);
  return path_buf;
}

/* sample k of `user` (NpgSamples) and a param 'mass' of 5 for every body: what a careless
 * validation callback does */
static int set_with_param(void *user, NpgFull *f, long k) {
  if (npg_samples_set(user, f, k) != 0) return -1;
  double mass[8];
  long shape[1] = {8};
  for (int i = 0; i < 8; i++) mass[i] = 5.0;
  return npg_full_set(f, "mass", 1, shape, mass, "set_with_param");
}

static int report(int failed, const char *msg, const char *word) {
  if (!failed) return printf("BAD accepted\n"), 1;
  if (!msg || !strstr(msg, word)) return printf("BAD message lacks '%s': %s\n", word, msg ? msg : "(none)"), 1;
  return printf("OK %s\n", msg), 0;
}

int main(int argc, char **argv) {
  if (argc < 3) return fprintf(stderr, "usage: trial3_api CASE WORKDIR [tune]\n"), 2;
  const char *w = argv[2];
  char err[1024] = "";
  NpgProgram *p = npg_compile(at(w, "ip/nb.npg"), NULL);
  NpgFull *f = p && !npg_error(p)[0] ? npg_full_new(p, NPG_TCC) : NULL;
  if (!f || npg_full_bind_params(f, at(w, "ip/D")) != 0) return printf("BAD setup\n"), 1;
  NpgSamples *train = npg_samples_open(p, at(w, "ip/D"), NULL, false, err, sizeof err);
  NpgSamples *valid = npg_samples_open(p, at(w, "ip/V"), NULL, false, err, sizeof err);
  if (!train || !valid) return printf("BAD samples: %s\n", err), 1;
  int rc = 1;
  if (strcmp(argv[1], "valid_set_param") == 0) {
    NpgTrainOptions o;
    npg_train_options_default(&o);
    o.valid_count = npg_samples_count(valid);
    o.valid_set = set_with_param;
    o.valid_user = valid;
    NpgTrainer *t = npg_trainer_new(f, &o);
    for (long k = 0; t && k < npg_samples_count(train); k++)
      if (npg_samples_set(train, f, k) != 0 || npg_trainer_add_full(t, f) != 0) break;
    NpgModel *m = t ? npg_trainer_finish(t, NULL) : NULL;
    rc = report(m == NULL, t ? npg_trainer_error(t) : NULL, "mass");
    npg_model_free(m);
    npg_trainer_free(t);
  } else if (strcmp(argv[1], "verify_set_param") == 0) {
    NpgModel *m = npg_model_load(p, at(w, "ip/MG"));
    NpgVerifyReport rep;
    int v = m ? npg_verify(m, f, npg_samples_count(valid), set_with_param, valid, false, &rep) : 0;
    rc = report(m && v != 0, m ? rep.error : npg_model_error(m), "mass");
    if (m) npg_verify_free(&rep);
    npg_model_free(m);
  } else if (strcmp(argv[1], "tune_valid_set_param") == 0) {
    NpgTuneReport rep;
    NpgModel *m = npg_tune(f, npg_samples_count(train), npg_samples_set, train, npg_samples_count(valid),
                           set_with_param, valid, 0.5, 8, NULL, &rep);
    rc = report(!m, rep.error, "mass");
    npg_model_free(m);
    npg_tune_free(&rep);
  } else if (strncmp(argv[1], "options_", 8) == 0) {
    /* NpgTrainOptions of the interpolated stages out of their range: refused naming the field, at
     * npg_trainer_new or at the latest npg_trainer_finish, never trained with silently */
    NpgTrainOptions o;
    npg_train_options_default(&o);
    const char *w_only[] = {"w"}, *null_name[] = {NULL};
    const char *field = argv[1] + 8;
    if (strcmp(field, "oversample_half") == 0) o.interp_oversample = 0.5, o.ninterp = 1, o.interp_stage = w_only;
    else if (strcmp(field, "oversample_nan") == 0) o.interp_oversample = 0.0 / 0.0, o.ninterp = 1, o.interp_stage = w_only;
    else if (strcmp(field, "oversample_negative") == 0) o.interp_oversample = -3, o.ninterp = 1, o.interp_stage = w_only;
    else if (strcmp(field, "ninterp_negative") == 0) o.ninterp = -1, o.interp_stage = w_only;
    else if (strcmp(field, "interp_stage_null") == 0) o.ninterp = 1, o.interp_stage = NULL;
    else if (strcmp(field, "interp_name_null") == 0) o.ninterp = 1, o.interp_stage = null_name;
    else if (strcmp(field, "ngalerkin_negative") == 0) o.ngalerkin = -2, o.galerkin_stage = w_only;
    else if (strcmp(field, "galerkin_stage_null") == 0) o.ngalerkin = 1, o.galerkin_stage = NULL;
    else if (strcmp(field, "valid_count_negative") == 0) o.valid_count = -4, o.valid_set = npg_samples_set, o.valid_user = valid;
    else if (strcmp(field, "holdout_nan") == 0) o.valid_holdout = 0.0 / 0.0;
    else if (strcmp(field, "keep_bases_empty") == 0) o.keep_bases = "";
    const char *word = strstr(field, "oversample") ? "interp_oversample" : strstr(field, "ninterp") ? "ninterp"
                     : strstr(field, "interp_") ? "interp_stage" : strstr(field, "ngalerkin") ? "ngalerkin"
                     : strstr(field, "galerkin_") ? "galerkin_stage" : strstr(field, "valid_count") ? "valid_count"
                     : strstr(field, "holdout") ? "valid_holdout" : "keep_bases";
    if (argc > 3 && strcmp(argv[3], "tune") == 0) { /* the same options through npg_tune */
      NpgTuneReport rep;
      NpgModel *m = npg_tune(f, npg_samples_count(train), npg_samples_set, train, npg_samples_count(valid),
                             npg_samples_set, valid, 0.5, 8, &o, &rep);
      rc = report(!m, rep.error, word);
      npg_model_free(m);
      npg_tune_free(&rep);
      goto done;
    }
    NpgTrainer *t = npg_trainer_new(f, &o);
    const char *e = t ? npg_trainer_error(t) : "npg_trainer_new returned NULL";
    NpgModel *m = NULL;
    if (t && !e[0]) {
      for (long k = 0; k < npg_samples_count(train); k++)
        if (npg_samples_set(train, f, k) != 0 || npg_trainer_add_full(t, f) != 0) break;
      m = npg_trainer_finish(t, NULL);
      e = npg_trainer_error(t);
    }
    rc = report(!m, e, word);
    npg_model_free(m);
    npg_trainer_free(t);
  } else {
    printf("BAD unknown case %s\n", argv[1]);
  }
done:
  npg_samples_free(train);
  npg_samples_free(valid);
  npg_full_free(f);
  npg_free(p);
  return rc;
}
