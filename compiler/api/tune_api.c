/* tune_api.c — basis sizes chosen by error through npg.h (npg_tune): the
 * search is tune_search (backends/train/tune.c) over one TrainSet. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"
#include "compile.h"

NpgModel *npg_tune(NpgFull *f, long ntrain, NpgSampleFn train, void *tuser, long nvalid, NpgSampleFn valid,
                   void *vuser, double tol, int max_cap, const NpgTrainOptions *o, NpgTuneReport *rep) {
  API_REFUSE_NULL(rep, NULL, 0, NULL);
  memset(rep, 0, sizeof *rep);
  rep->chosen = -1;
#define REFUSE(...) return api_refuse(rep->error, sizeof rep->error, __func__, __VA_ARGS__), NULL
  if (!f) REFUSE("argument 'f' is NULL");
  if (!train) REFUSE("argument 'train' is NULL");
  if (!valid) REFUSE("argument 'valid' is NULL");
  if (ntrain < 1) REFUSE("argument 'ntrain' is %ld (at least one training sample)", ntrain);
  if (nvalid < 1) REFUSE("argument 'nvalid' is %ld (at least one validation sample)", nvalid);
  if (!(tol > 0) || !isfinite(tol)) REFUSE("argument 'tol' is %g (a relative error, positive and finite)", tol);
  if (max_cap < 1) REFUSE("argument 'max_cap' is %d (at least 1)", max_cap);
  if (o && o->mem == 0) REFUSE("NpgTrainOptions.mem is 0 (bytes of memory for training)");
  if (o && o->rollout_steps < 0) REFUSE("NpgTrainOptions.rollout_steps is %ld (0: one step, or the steps of a rollout)",
                                        o->rollout_steps);
  if (o && o->rollout_every < 0) REFUSE("NpgTrainOptions.rollout_every is %ld (0 or more)", o->rollout_every);
  if (o && o->rollout_steps > 0 && !full_program(f->full)->states.n)
    REFUSE("NpgTrainOptions.rollout_steps is %ld but the program has no state (DESIGN §15)", o->rollout_steps);
  for (int i = 0; o && o->rollout_steps > 0 && i < full_program(f->full)->states.n; i++)
    if (((const Sym *)full_program(f->full)->states.v[i])->residual)
      REFUSE("NpgTrainOptions.rollout_steps: state '%s' is stepped implicitly ('residual next'), and the search's "
             "rollouts are explicit steps: tune on its samples, or train and verify with --steps",
             ((const Sym *)full_program(f->full)->states.v[i])->name);
  if (o && api_refuse_reduce_options(o, __func__, rep->error, sizeof rep->error) != 0) return NULL;
#undef REFUSE
  if (npg_full_error(f)[0]) {
    snprintf(rep->error, sizeof rep->error, "%s", npg_full_error(f));
    return NULL;
  }
  Program *prog = (Program *)full_program(f->full);
  SampleClosure tset = {train, tuser, f}, vset = {valid, vuser, f};
  SampleSource tsrc = {ntrain, &tset, api_sample_set, NULL, NULL}, vsrc = {nvalid, &vset, api_sample_set, NULL, NULL};
  /* the options as the trainer takes them (api_train_options): the reductions as NpgTrainOptions force
   * them (the choice of the others is part of the search), the bases kept as npg_trainer keeps them
   * (issue 30: the streamable ones dropped unless named); the search's own bases at max_cap vectors
   * of every energy, and in one process */
  NpgTrainOptions given;
  if (o) given = *o;
  else npg_train_options_default(&given);
  given.cap = max_cap, given.energy = 1.0;
  TrainOptions topt;
  api_train_options(&given, &topt);
  topt.dist = false;
  TuneResult *r = calloc(1, sizeof *r);
  const char **names = calloc((size_t)prog->classes.n + 1, sizeof *names);
  TrainSet *ts = NULL;
  NpgModel *nm = NULL;
  if (!r || !names) {
    snprintf(rep->error, sizeof rep->error, "out of memory");
    free(r);
    free(names);
    return NULL;
  }
  rep->priv = r;
  rep->class_name = names;
  for (int c = 0; c < prog->classes.n; c++) names[c] = ((BasisClass *)prog->classes.v[c])->size_name;
  /* the params before any sample is set: a `valid` that sets one is refused after the search (trial3) */
  char *params = train_param_hashes(f->full);
  bool oom = !params;
  const char *changed = NULL;
  if (oom || !(ts = train_set_new(prog, f->full, &tsrc, &topt, ERR_OF(rep->error, sizeof rep->error))) ||
      tune_search(ts, &(TuneGoal){&vsrc, tol, max_cap}, &topt, r, ERR_OF(rep->error, sizeof rep->error)) != 0 ||
      (changed = train_param_changed(f->full, params, &oom)) || oom) {
    if (oom) snprintf(rep->error, sizeof rep->error, "out of memory");
    else if (changed)
      snprintf(rep->error, sizeof rep->error, "npg_tune: a training or validation sample function changed param "
                                              "'%s' (samples hold inputs and externs only)", changed);
    free(params);
    goto done;
  }
  free(params);
  rep->nclasses = r->nclasses;
  rep->ntrials = r->ntrials;
  if (!(rep->trials = calloc((size_t)r->ntrials + 1, sizeof *rep->trials))) {
    snprintf(rep->error, sizeof rep->error, "out of memory");
    goto done;
  }
  for (int t = 0; t < r->ntrials; t++)
    rep->trials[t] =
        (NpgTuneTrial){r->trials[t].m, r->trials[t].cost, r->trials[t].err, r->trials[t].uniform, r->trials[t].interp};
  rep->chosen = r->chosen;
  if (r->chosen < 0) {
    rep->limiting = names[r->limiting];
    rep->limiting_floor = r->limiting_floor;
    rep->limiting_saturated = r->limiting_saturated;
    goto done;
  }
  Model *m = r->model; /* its reductions chosen in the search */
  r->model = NULL;
  if (train_set_stream(ts, m, &topt, ERR_OF(rep->error, sizeof rep->error)) != 0) {
    model_free(m);
    m = NULL;
  }
  if (m && !(m->param_hashes = train_param_hashes(f->full))) snprintf(rep->error, sizeof rep->error, "out of memory");
  if (m && !m->param_hashes) model_free(m);
  else if (m && !(nm = api_model_wrap(m))) snprintf(rep->error, sizeof rep->error, "out of memory");
done:
  train_set_free(ts);
  if (rep->error[0] && o && o->words != NPG_WORDS_NPGC) { /* training's messages in the caller's words */
    char worded[sizeof rep->error];
    api_words(rep->error, o->words, worded, sizeof worded);
    memcpy(rep->error, worded, sizeof worded);
  }
  return nm;
}

void npg_tune_free(NpgTuneReport *rep) {
  if (!rep) return;
  if (rep->priv) {
    tune_result_free(rep->priv);
    free(rep->priv);
  }
  free(rep->trials);
  free((void *)rep->class_name);
  memset(rep, 0, sizeof *rep);
}
