/* train_via_api PROG DATA MODEL — train MODEL/ from DATA/ through npg.h alone, every option at
 * npg_train_options_default's value: the C side of the three-interface check (npgc train, npg.h,
 * npg.Trainer give the same model byte for byte; tests/python/test_trust.py). Exit 1 with the
 * library's message on any failure. */
#include <stdio.h>

#include "npg.h"

int main(int argc, char **argv) {
  if (argc != 4) {
    fprintf(stderr, "usage: train_via_api PROG DATA MODEL\n");
    return 2;
  }
  char err[2048] = "";
  NpgProgram *p = npg_compile(argv[1], NULL);
  if (!p || !npg_ok(p)) {
    fprintf(stderr, "%s", p ? npg_error(p) : "out of memory\n");
    npg_free(p);
    return 1;
  }
  int rc = 1;
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgSamples *s = NULL;
  NpgTrainer *t = NULL;
  NpgModel *m = NULL;
  if (npg_full_error(f)[0] || npg_full_bind_params(f, argv[2]) != 0) {
    fprintf(stderr, "%s\n", npg_full_error(f));
    goto done;
  }
  if (!(s = npg_samples_open(p, argv[2], NULL, true, err, sizeof err))) {
    fprintf(stderr, "%s\n", err);
    goto done;
  }
  NpgTrainOptions o;
  npg_train_options_default(&o);
  t = npg_trainer_new(f, &o);
  for (long k = 0; k < npg_samples_count(s) && !npg_trainer_error(t)[0]; k++)
    if (npg_samples_set(s, f, k) != 0 || npg_trainer_add_full(t, f) != 0) break;
  if (npg_full_error(f)[0]) fprintf(stderr, "%s\n", npg_full_error(f));
  else if (!(m = npg_trainer_finish(t, argv[3]))) fprintf(stderr, "%s\n", npg_trainer_error(t));
  else rc = 0;
done:
  npg_model_free(m);
  npg_trainer_free(t);
  npg_samples_free(s);
  npg_full_free(f);
  npg_free(p);
  return rc;
}
