/* dist_train.c — the reductions of training over ranks (train.c with
 * TrainOptions.dist; DESIGN §5 map and reduce):
 *
 *   snapshots   rank r evaluates the samples k ≡ r (mod N); then round
 *               j's columns k = jN … jN+N−1, contiguous in every member's
 *               n x S column-major matrix, are gathered on every rank,
 *               so every rank builds the same bases from the same matrix;
 *   bases       every member's PCA made on one rank (the largest first,
 *               each to the least loaded rank) and broadcast;
 *   SPD marks   a diagonal operator stays SPD when it was on every rank;
 *   pre-multiplication  each rank its rows (PremulOut.part: its
 *               builders enumerate no other rank's entries), the
 *               reduced tensors summed (train.c). */
#include <stdlib.h>
#include <string.h>

#include "dist.h"
#include "scratch.h"
#include "train.h"

/* Rounds of columns gathered per collective call: as many as keep a
 * rank's block under 2^27 doubles (1 GB, and an int count). */
static long rounds_per_call(long n) { return n > 0 && (1L << 27) / n > 1 ? (1L << 27) / n : 1; }

int dist_gather_snapshots(Model *m, double ***X, long S, Err *err) {
  int N = dist_size(), rank = dist_rank();
  long maxn = 1;
  for (int c = 0; c < m->nclasses; c++) maxn = X[c] && m->classes[c].n > maxn ? m->classes[c].n : maxn;
  long R = rounds_per_call(maxn), rounds = (S + N - 1) / N;
  if (R > rounds) R = rounds;
  Scratch s = SCRATCH_OF(err);
  long *counts = scratch_array(&s, (size_t)N, sizeof(long));
  double *all = scratch_array(&s, (size_t)maxn * (size_t)(R * N), sizeof(double));
  int rc = counts && all ? 0 : err_set(err, "out of memory gathering the snapshots");
  /* rounds j0 … j1−1 at a time: rank r's columns jN + r packed in order
   * as its block (one collective call per member), then put in place */
  for (long j0 = 0; rc == 0 && j0 < rounds; j0 += R) {
    long j1 = j0 + R < rounds ? j0 + R : rounds, at = 0, mine = 0;
    for (int c = 0; rc == 0 && c < m->nclasses; c++) {
      const RClass *cl = &m->classes[c];
      size_t n = (size_t)cl->n;
      if (!X[c]) continue; /* not gathered (out of core: a streamed class) */
      at = 0;
      for (int r = 0; r < N; r++) {
        long cols = 0;
        for (long j = j0; j < j1; j++) cols += j * N + r < S;
        counts[r] = cols * cl->n;
        if (r < rank) at += counts[r];
        if (r == rank) mine = cols;
      }
      for (int i = 0; rc == 0 && i < cl->nmembers; i++) {
        for (long q = 0; q < mine; q++) memcpy(all + at + q * cl->n, X[c][i] + ((j0 + q) * N + rank) * n, sizeof(double) * n);
        if ((rc = dist_allgather(all, counts, err))) break;
        for (int r = 0, off = 0; r < N; off += (int)(counts[r] / (cl->n ? cl->n : 1)), r++)
          for (long q = 0; q < counts[r] / (cl->n ? cl->n : 1); q++)
            if (r != rank) memcpy(X[c][i] + ((j0 + q) * N + r) * n, all + (off + q) * cl->n, sizeof(double) * n);
      }
    }
  }
  scratch_release(&s);
  return rc;
}

void dist_and_spd(Model *m) {
  long n = 0, at = 0;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) n += m->stages[i].terms[t].nops;
  Scratch s = SCRATCH_OF(NULL);
  double *not_spd = scratch_array(&s, (size_t)n + 1, sizeof(double));
  if (!not_spd) dist_abort("out of memory combining the SPD marks");
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) not_spd[at++] = !m->stages[i].terms[t].ops[k].spd;
  dist_allreduce_sum(not_spd, n);
  at = 0;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) m->stages[i].terms[t].ops[k].spd = not_spd[at++] == 0;
  scratch_release(&s);
}

void dist_free_pcas(Model *m, PcaMember **pcas) {
  for (int c = 0; pcas && c < m->nclasses; c++) {
    for (int i = 0; pcas[c] && i < m->classes[c].nmembers; i++) pca_member_free(&pcas[c][i]);
    free(pcas[c]);
  }
  free(pcas);
}

/* The rank that makes every member's PCA, the members numbered class by
 * class: the largest first, each to the least loaded rank (a PCA costs
 * about n S² either way); the same on every rank. NULL when out of memory. */
static int *pca_owners(const Model *m, Scratch *s) {
  int N = dist_size();
  long nm = 0;
  for (int c = 0; c < m->nclasses; c++) nm += m->classes[c].nmembers;
  int *owner = scratch_array(s, (size_t)(nm + 1), sizeof(int));
  long *size = scratch_array(s, (size_t)(nm + 1), sizeof(long));
  double *load = scratch_array(s, (size_t)N, sizeof(double));
  if (!owner || !size || !load) return NULL;
  for (int c = 0, g = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++, g++) owner[g] = -1, size[g] = m->classes[c].n;
  for (long done = 0; done < nm; done++) {
    long best = -1;
    for (long g = 0; g < nm; g++)
      if (owner[g] < 0 && (best < 0 || size[g] > size[best])) best = g;
    int r = 0;
    for (int q = 1; q < N; q++) r = load[q] < load[r] ? q : r;
    owner[best] = r;
    load[r] += (double)size[best];
  }
  return owner;
}

/* The members' PCAs under way: their snapshots, and where each is made. */
typedef struct PcaShare {
  long S;
  double ***X;      /* [class][member]: n x S column-major */
  const double *w;  /* the samples' weights, or NULL */
  const int *owner; /* the rank of each member, numbered class by class (pca_owners) */
  PcaMember **p;    /* [class][member], allocated: the PCAs */
} PcaShare;

/* Every member's PCA made by its owner (map) and broadcast from it, in the
 * same order on every rank (share). */
static int make_and_share(Model *m, const PcaShare *sh, Err *err) {
  int rank = dist_rank();
  const int *owner = sh->owner;
  PcaMember **p = sh->p;
  for (int c = 0, g = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++, g++) {
      const RClass *rc = &m->classes[c];
      const RMember *mb = &rc->members[i];
      if (owner[g] == rank &&
          pca_basis(rc->n, sh->S, sh->X[c][i], &(PcaRule){mb->cap, mb->energy, mb->center, sh->w}, &p[c][i], err))
        return -1;
    }
  for (int c = 0, g = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++, g++) {
      PcaMember *q = &p[c][i];
      long n = m->classes[c].n;
      double head[3] = {q->k, (double)q->nsv, q->lost};
      dist_broadcast(head, 3, owner[g]);
      if (owner[g] != rank) {
        q->k = (int)head[0], q->nsv = (long)head[1], q->lost = head[2];
        if (!(q->U = mem_malloc(sizeof(double) * (size_t)(n * (q->k ? q->k : 1)))) ||
            !(q->sv = mem_malloc(sizeof(double) * (size_t)(q->nsv + 1))))
          return err_set(err, "out of memory for the member bases");
      }
      dist_broadcast(q->U, n * q->k, owner[g]);
      dist_broadcast(q->sv, q->nsv, owner[g]);
    }
  return 0;
}

int dist_member_pcas(Model *m, long S, double ***X, const double *w, PcaMember ***out, Err *err) {
  Scratch s = SCRATCH_OF(err);
  PcaMember **p = mem_calloc((size_t)m->nclasses + 1, sizeof(PcaMember *));
  int rc = p ? 0 : -1;
  for (int c = 0; rc == 0 && c < m->nclasses; c++)
    if (!(p[c] = mem_calloc((size_t)m->classes[c].nmembers + 1, sizeof(PcaMember)))) rc = -1;
  const int *owner = rc == 0 ? pca_owners(m, &s) : NULL;
  if (!owner) rc = err_set(err, "out of memory for the member bases");
  else rc = make_and_share(m, &(PcaShare){S, X, w, owner, p}, err);
  scratch_release(&s);
  if (rc) dist_free_pcas(m, p); /* what was made of it: its own free */
  else *out = p;
  return rc;
}
