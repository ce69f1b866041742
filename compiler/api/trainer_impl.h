/* trainer_impl.h — the trainer's state and its sample records, shared by trainer.c (npg.h
 * NpgTrainer) and trainer_records.c (the records' encoding, storage and inner products). */
#ifndef NPG_TRAINER_IMPL_H
#define NPG_TRAINER_IMPL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#include "api.h"
#include "dist.h"

/* Encoded sample records: the first in memory, the others in a scratch
 * file, indexed by their place among those kept. */
typedef struct Records {
  unsigned char *mem;       /* the first records, back to back */
  size_t used, alloc;       /* bytes held in `mem`, allocated */
  long in_mem;              /* records held in `mem` */
  FILE *scratch;            /* the others, in order */
  size_t *at, *len;         /* per record: where it starts (in `mem` or the scratch file) and its bytes */
} Records;

struct NpgTrainer {
  NpgFull *f;
  const Program *prog;
  NpgTrainOptions opt;
  int nslots;
  const Sym **slot;         /* inputs and externs, program order */
  size_t *count;            /* entries of each, fixed by the first sample */
  bool *staged;             /* npg_trainer_set since the last add */
  size_t record;            /* doubles per sample: Σ count */
  Records rec;              /* the samples this process keeps */
  size_t mem_cap;           /* bytes allowed in rec.mem */
  bool all;                 /* over ranks: every rank keeps every sample (share_samples) */
  long samples;
  double *buf;              /* one record, decoded */
  unsigned char *enc;       /* one record, encoded */
  size_t *ranges;           /* an extern's entries a restricted evaluation reads (replay_part) */
  long range_cap;           /* ranges' room, in ranges */
  double weight;            /* the next sample's (npg_trainer_weight; 1 after every add) */
  double *weights;          /* every sample's, in order (every rank's too); NULL while all are 1 */
  long weights_cap;
  bool broken;              /* a failure that may have left the records incomplete (or the construction's):
                               npg_trainer_clear_error keeps the error */
  uint64_t inputs_hash;     /* over ranks: of every sample's inputs, in order (every rank's too: ranks_agree) */
  char error[2048];
  char worded[2048];        /* error in the caller's words (NpgTrainOptions.words), made by npg_trainer_error */
};

#define tfail(t, ...) error_set_first((t)->error, sizeof (t)->error, __VA_ARGS__)

/* Over MPI ranks (NpgTrainOptions.mpi) a rank keeps sample 0 (every rank
 * binds the dims with it) and its own samples k ≡ rank (mod ranks), in
 * order: sample k's place among those kept. */
static inline bool own_sample(const NpgTrainer *t, long k) {
  return !t->opt.mpi || t->all || k == 0 || k % dist_size() == dist_rank();
}
static inline long kept_index(const NpgTrainer *t, long k) {
  int N = t->opt.mpi && !t->all ? dist_size() : 1, r = t->opt.mpi ? dist_rank() : 0;
  return k == 0 || N == 1 ? k : r == 0 ? k / N : 1 + (k - r) / N;
}

/* The record of t->buf into t->enc: its bytes (trainer_records.c, where the encoding is described). */
size_t trainer_encode(NpgTrainer *t);
/* Slot i of the record at t->enc + pos into v: every entry (nr < 0), or the nr ranges
 * r[2j] <= e < r[2j+1]. The position after the slot. */
size_t trainer_decode_slot(const NpgTrainer *t, int i, size_t pos, double *v, const size_t *r, long nr);
/* <values, slot i of the record at t->enc + *pos>, *pos moved past the slot. */
double trainer_dot_slot(const NpgTrainer *t, int i, size_t *pos, const double *values);
/* The position after slot i of the record at t->enc + pos. */
size_t trainer_slot_end(const NpgTrainer *t, int i, size_t pos);
/* t->enc back into t->buf, bit for bit. */
void trainer_decode(NpgTrainer *t);
/* The encoded record in t->enc (`bytes`) as record kk of r: 0, or -1 with t->error. */
int trainer_store(NpgTrainer *t, Records *r, long kk, size_t bytes);
/* Record kk of r into t->enc: 0, or -1. */
int trainer_fetch(NpgTrainer *t, const Records *r, long kk);
void trainer_records_free(Records *r);

#endif
