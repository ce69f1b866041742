/* records.h — the training samples a trainer keeps (npg.h NpgTrainer): each sample's inputs and
 * extern values encoded compactly as a record, in memory up to a budget and in an unnamed scratch
 * file beyond, read back bit for bit and replayed into the full evaluator as training's sample
 * source (records.c). Stage values are never kept: training recomputes them. */
#ifndef NPG_RECORDS_H
#define NPG_RECORDS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#include "dist.h"
#include "train.h"

/* Encoded sample records: the first in memory, the others in a scratch
 * file, indexed by their place among those kept. */
typedef struct Records {
  unsigned char *mem;       /* the first records, back to back */
  size_t used, alloc;       /* bytes held in `mem`, allocated */
  long in_mem;              /* records held in `mem` */
  FILE *scratch;            /* the others, in order */
  size_t *at, *len;         /* per record: where it starts (in `mem` or the scratch file) and its bytes */
} Records;

/* The samples kept, and what reading them back needs. */
typedef struct SampleRecords {
  int nslots;
  const Sym **slot;         /* inputs and externs, program order */
  size_t *count;            /* entries of each, fixed by the first sample */
  size_t record;            /* doubles per sample: Σ count */
  Records rec;              /* the samples this process keeps */
  size_t mem_cap;           /* bytes allowed in rec.mem */
  long samples;             /* samples added (over ranks, every rank's) */
  bool mpi;                 /* over ranks: rank r keeps sample 0 and the samples k ≡ r (mod ranks) */
  bool all;                 /* over ranks: every rank keeps every sample (records_source's share) */
  double *buf;              /* one record, decoded */
  unsigned char *enc;       /* one record, encoded */
  size_t *ranges;           /* an extern's entries a restricted evaluation reads (replay_part) */
  long range_cap;           /* ranges' room, in ranges */
  Err *err;                 /* the error record (the trainer's) */
} SampleRecords;

/* Over MPI ranks a rank keeps sample 0 (every rank binds the dims with it)
 * and its own samples k ≡ rank (mod ranks), in order: whether it keeps
 * sample k, and sample k's place among those kept. */
static inline bool records_own(const SampleRecords *t, long k) {
  return !t->mpi || t->all || k == 0 || k % dist_size() == dist_rank();
}
static inline long records_kept_index(const SampleRecords *t, long k) {
  int N = t->mpi && !t->all ? dist_size() : 1, r = t->mpi ? dist_rank() : 0;
  return k == 0 || N == 1 ? k : r == 0 ? k / N : 1 + (k - r) / N;
}

/* The record of t->buf into t->enc: its bytes. */
size_t records_encode(SampleRecords *t);
/* Slot i of the record at t->enc + pos into v: every entry (nr < 0), or the nr ranges
 * r[2j] <= e < r[2j+1]. The position after the slot. */
size_t records_decode_slot(const SampleRecords *t, int i, size_t pos, double *v, const size_t *r, long nr);
/* <values, slot i of the record at t->enc + *pos>, *pos moved past the slot. */
double records_dot_slot(const SampleRecords *t, int i, size_t *pos, const double *values);
/* The position after slot i of the record at t->enc + pos. */
size_t records_slot_end(const SampleRecords *t, int i, size_t pos);
/* t->enc back into t->buf, bit for bit. */
void records_decode(SampleRecords *t);
/* The encoded record in t->enc (`bytes`) as record kk of r: 0, or -1 with t->err. */
int records_store(SampleRecords *t, Records *r, long kk, size_t bytes);
/* Record kk of r into t->enc: 0, or -1. */
int records_fetch(SampleRecords *t, const Records *r, long kk);
void records_free_store(Records *r);
/* Everything `t` holds (the struct itself is the caller's). */
void records_free(SampleRecords *t);
/* Over ranks: the bytes the records of all the samples take in memory on
 * one process (and on every rank after they are shared), the same on every
 * rank; 0 with t->err when out of memory. */
size_t records_shared_use(SampleRecords *t);
/* Training's sample source: every sample kept, replayed into the evaluator
 * (whole, or of each extern the entries a restricted evaluation reads),
 * and over ranks shared with every rank when out of core asks for it. */
SampleSource records_source(SampleRecords *t);

#endif
