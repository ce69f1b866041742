/* dist_train.c — the reductions of training over ranks (train.c with
 * TrainOptions.dist; DESIGN §5 map and reduce):
 *
 *   snapshots   rank r evaluates the samples k ≡ r (mod N); round j's
 *               columns k = jN … jN+N−1, contiguous in every member's
 *               n x S column-major matrix, are gathered on every rank,
 *               so every rank builds the same bases from the same matrix;
 *   SPD marks   a diagonal operator stays SPD when it was on every rank;
 *   pre-multiplication  each rank its rows (premultiply_part), the
 *               reduced tensors summed (train.c). */
#include <stdlib.h>

#include "dist.h"
#include "train.h"

int dist_gather_round(Model *m, double ***X, long S, long j, char *err, size_t errlen) {
  int N = dist_size();
  long *counts = malloc(sizeof(long) * (size_t)N);
  if (!counts) return npg_fail(err, errlen, "out of memory gathering the snapshots");
  int rc = 0;
  for (int c = 0; rc == 0 && c < m->nclasses; c++) {
    const RClass *cl = &m->classes[c];
    for (int r = 0; r < N; r++) counts[r] = j * N + r < S ? cl->n : 0;
    for (int i = 0; rc == 0 && i < cl->nmembers; i++)
      rc = dist_allgather(X[c][i] + (size_t)(j * N) * (size_t)cl->n, counts, err, errlen);
  }
  free(counts);
  return rc;
}

void dist_and_spd(Model *m) {
  long n = 0, at = 0;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) n += m->stages[i].terms[t].nops;
  double *not_spd = calloc((size_t)n + 1, sizeof(double));
  if (!not_spd) dist_abort("out of memory combining the SPD marks");
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) not_spd[at++] = !m->stages[i].terms[t].ops[k].spd;
  dist_allreduce_sum(not_spd, n);
  at = 0;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) m->stages[i].terms[t].ops[k].spd = not_spd[at++] == 0;
  free(not_spd);
}
