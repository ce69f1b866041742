/* trained.h — a program trained on random samples in memory (tests of the
 * reduced model). Include after testutil.h. */
#ifndef NPG_TRAINED_H
#define NPG_TRAINED_H

#include "memsamples.h"
#include "reduced.h"
#include "train.h"

typedef struct Trained {
  NpgProgram *p;
  Program *prog;
  Full *f;
  MemSamples train;
  Model *m;
} Trained;

/* `path` (or `text` named `path`) trained on S random samples, every dim
 * of size n, caps of `cap` at energy 1: truncated, non-trivial bases. */
static inline void train(Trained *tr, const char *path, const char *text, long n, long S, int cap) {
  memset(tr, 0, sizeof *tr);
  tr->p = text ? compile_text(path, text) : compile_file(path);
  tr->prog = ir_ok(tr->p);
  tr->f = full_new(npg_program_ir(tr->p), JIT_TCC, NULL);
  if (memsamples_fill(&tr->train, tr->prog, tr->f, n, S, 5u)) fail_msg("binding random params failed");
  SampleSource src = {S, &tr->train, memsamples_set, NULL, NULL};
  TrainOptions opt = {0};
  opt.cap = cap;
  opt.energy = 1.0;
  char err[2048] = "";
  tr->m = train_model(tr->prog, tr->f, &src, &opt, err, sizeof err);
  if (!tr->m) fail_msg("%s: training: %s", path, err);
}

static inline void trained_free(Trained *tr) {
  model_free(tr->m);
  memsamples_free(&tr->train);
  full_free(tr->f);
  npg_free(tr->p);
}

#endif
