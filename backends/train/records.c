/* records.c — the training samples a trainer keeps (records.h): a sample's inputs and externs
 * encoded compactly, kept in memory up to a quarter of --mem and in an unnamed scratch file
 * beyond, read back bit for bit, their inner products with a value (npg_trainer_dots), and
 * replayed into the full evaluator as training's sample source. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "records.h"
#include "scratch.h"

/* An entry a bit cannot hold: neither +0 nor 1. */
static bool exceptional(double v) { return !(v == 1.0 || (v == 0.0 && !signbit(v))); }

/* The record of t->buf into t->enc: per slot, an input's doubles; an
 * extern's tag byte and its entries — tag 1: one bit per entry (set: 1),
 * then the count of exceptional entries and (index, value) for each,
 * whenever that is smaller than the doubles (tag 0). Its bytes. */
size_t records_encode(SampleRecords *t) {
  size_t off = 0, pos = 0;
  for (int i = 0; i < t->nslots; i++) {
    const double *v = t->buf + off;
    size_t n = t->count[i];
    off += n;
    if (t->slot[i]->kind == SYM_EXTERN) {
      uint64_t x = 0;
      for (size_t e = 0; e < n; e++) x += exceptional(v[e]);
      bool bits = (n + 7) / 8 + 8 + 16 * x < 8 * n;
      t->enc[pos++] = bits;
      if (bits) {
        memset(t->enc + pos, 0, (n + 7) / 8);
        for (size_t e = 0; e < n; e++) t->enc[pos + e / 8] |= (unsigned char)((v[e] == 1.0) << (e % 8));
        pos += (n + 7) / 8;
        memcpy(t->enc + pos, &x, 8);
        pos += 8;
        for (uint64_t e = 0; e < n && x > 0; e++)
          if (exceptional(v[e])) memcpy(t->enc + pos, &e, 8), memcpy(t->enc + pos + 8, v + e, 8), pos += 16;
        continue;
      }
    }
    memcpy(t->enc + pos, v, sizeof(double) * n);
    pos += sizeof(double) * n;
  }
  return pos;
}

/* Slot i of the record at t->enc + pos into v[0..n): every entry (nr < 0),
 * or the entries in the nr ranges r[2j] <= e < r[2j+1]. The position after
 * the slot. */
size_t records_decode_slot(const SampleRecords *t, int i, size_t pos, double *v, const size_t *r, long nr) {
  size_t n = t->count[i], all[2] = {0, n};
  if (nr < 0) r = all, nr = 1;
  if (t->slot[i]->kind == SYM_EXTERN && t->enc[pos++]) {
    const unsigned char *bits = t->enc + pos;
    for (long j = 0; j < nr; j++)
      for (size_t e = r[2 * j]; e < r[2 * j + 1]; e++) v[e] = (bits[e / 8] >> (e % 8)) & 1 ? 1.0 : 0.0;
    pos += (n + 7) / 8;
    uint64_t x, e;
    memcpy(&x, t->enc + pos, 8);
    pos += 8;
    const unsigned char *ex = t->enc + pos; /* (index, value), indices ascending */
    for (long j = 0; j < nr; j++) {
      uint64_t lo = 0, hi = x; /* the first exceptional entry at r[2j] or after */
      while (lo < hi) {
        uint64_t mid = lo + (hi - lo) / 2;
        memcpy(&e, ex + 16 * mid, 8);
        if (e < r[2 * j]) lo = mid + 1;
        else hi = mid;
      }
      for (; lo < x && (memcpy(&e, ex + 16 * lo, 8), e < r[2 * j + 1]); lo++) memcpy(v + e, ex + 16 * lo + 8, 8);
    }
    return pos + 16 * x;
  }
  for (long j = 0; j < nr; j++)
    memcpy(v + r[2 * j], t->enc + pos + sizeof(double) * r[2 * j], sizeof(double) * (r[2 * j + 1] - r[2 * j]));
  return pos + sizeof(double) * n;
}

/* The inner product of values[0..n) with slot i of the record at t->enc + *pos, *pos moved past
 * the slot: a bit-coded extern summed over its set bits and its exceptional entries, undecoded
 * (radiosity's v at the paper's size: 25 M entries, a few MB of bits a sample). */
double records_dot_slot(const SampleRecords *t, int i, size_t *pos, const double *values) {
  size_t n = t->count[i], p = *pos;
  double sum = 0;
  if (t->slot[i]->kind == SYM_EXTERN && t->enc[p++]) {
    const unsigned char *bits = t->enc + p;
    size_t e = 0;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    for (; e + 64 <= n; e += 64) { /* a word's bit j is entry e + j */
      uint64_t w;
      memcpy(&w, bits + e / 8, 8);
      for (; w; w &= w - 1) sum += values[e + (size_t)__builtin_ctzll(w)];
    }
#endif
    for (; e < n; e++)
      if ((bits[e / 8] >> (e % 8)) & 1) sum += values[e];
    p += (n + 7) / 8;
    uint64_t x, k;
    double v;
    memcpy(&x, t->enc + p, 8);
    p += 8;
    for (uint64_t j = 0; j < x; j++) { /* an exceptional entry's bit is 0 (encode) */
      memcpy(&k, t->enc + p + 16 * j, 8), memcpy(&v, t->enc + p + 16 * j + 8, 8);
      sum += v * values[k];
    }
    *pos = p + 16 * x;
    return sum;
  }
  for (size_t e = 0; e < n; e++) {
    double v;
    memcpy(&v, t->enc + p + sizeof(double) * e, sizeof(double));
    sum += v * values[e];
  }
  *pos = p + sizeof(double) * n;
  return sum;
}

/* The position after slot i of the record at t->enc + pos. */
size_t records_slot_end(const SampleRecords *t, int i, size_t pos) {
  size_t n = t->count[i];
  if (t->slot[i]->kind == SYM_EXTERN && t->enc[pos++]) {
    uint64_t x;
    memcpy(&x, t->enc + pos + (n + 7) / 8, 8);
    return pos + (n + 7) / 8 + 8 + 16 * x;
  }
  return pos + sizeof(double) * n;
}

/* t->enc back into t->buf (the inverse of encode, bit for bit). */
void records_decode(SampleRecords *t) {
  size_t off = 0, pos = 0;
  for (int i = 0; i < t->nslots; i++) {
    pos = records_decode_slot(t, i, pos, t->buf + off, NULL, -1);
    off += t->count[i];
  }
}

/* The encoded record in t->enc (`bytes`) as record kk of `r`: in memory
 * while the records there stay within mem_cap, then in the scratch file. */
int records_store(SampleRecords *t, Records *r, long kk, size_t bytes) {
  if (kk % 64 == 0) {
    size_t *at = mem_realloc(r->at, sizeof(size_t) * (size_t)(kk + 64));
    if (at) r->at = at;
    size_t *len = at ? mem_realloc(r->len, sizeof(size_t) * (size_t)(kk + 64)) : NULL;
    if (!len) return err_set_first(t->err, "out of memory keeping training sample %ld", t->samples);
    r->len = len;
  }
  r->len[kk] = bytes;
  if (r->in_mem == kk && r->used + bytes <= t->mem_cap) {
    if (r->used + bytes > r->alloc) {
      size_t want = r->alloc * 2 > r->used + bytes ? r->alloc * 2 : r->used + bytes;
      unsigned char *m = mem_realloc(r->mem, want < t->mem_cap ? want : t->mem_cap);
      if (!m) return err_set_first(t->err, "out of memory keeping training sample %ld", t->samples);
      r->mem = m;
      r->alloc = want < t->mem_cap ? want : t->mem_cap;
    }
    if (bytes) memcpy(r->mem + r->used, t->enc, bytes); /* a record of zero-size arrays has no bytes */
    r->at[kk] = r->used;
    r->used += bytes;
    r->in_mem++;
  } else {
    if (!r->scratch && !(r->scratch = tmpfile()))
      return err_set_first(t->err, "cannot create a scratch file for the training samples beyond --mem");
    if (fseeko(r->scratch, 0, SEEK_END) != 0) return err_set_first(t->err, "cannot seek in the scratch file");
    r->at[kk] = (size_t)ftello(r->scratch);
    if (fwrite(t->enc, 1, bytes, r->scratch) != bytes)
      return err_set_first(t->err, "cannot write training sample %ld to the scratch file (disk full?)", t->samples);
  }
  return 0;
}

/* Record kk of `r` into t->enc. */
int records_fetch(SampleRecords *t, const Records *r, long kk) {
  if (kk < r->in_mem) {
    if (r->len[kk]) memcpy(t->enc, r->mem + r->at[kk], r->len[kk]);
    return 0;
  }
  return fseeko(r->scratch, (off_t)r->at[kk], SEEK_SET) != 0 || fread(t->enc, 1, r->len[kk], r->scratch) != r->len[kk]
             ? -1 : 0;
}

void records_free(SampleRecords *t) {
  records_free_store(&t->rec);
  free(t->slot);
  free(t->count);
  free(t->buf);
  free(t->ranges);
  free(t->enc);
}

void records_free_store(Records *r) {
  if (r->scratch) fclose(r->scratch);
  free(r->mem);
  free(r->at);
  free(r->len);
  memset(r, 0, sizeof *r);
}


/* The shape of input or extern `s` in `f` (its dims' sizes, then its static axes). */
static int slot_shape(const Full *f, const Sym *s, long *shape) {
  int nd = 0;
  for (int i = 0; i < s->ndims; i++) shape[nd++] = full_dim(f, s->dims[i]->name);
  for (int i = 0; i < s->nstatic; i++) shape[nd++] = s->shape[i];
  return nd;
}

/* Sample k's encoded record into t->enc. */
static int load_record(SampleRecords *t, Full *f, long k) {
  if (!records_own(t, k)) return full_fail(f, "a training sample of another rank was asked for (a bug in npg)");
  if (records_fetch(t, &t->rec, records_kept_index(t, k))) return full_fail(f, "cannot read a training sample back from the scratch file");
  return 0;
}

/* Over ranks: the bytes the records of all the samples take in memory on
 * one process (and on every rank after share_samples), the same on every
 * rank. */
size_t records_shared_use(SampleRecords *t) {
  int N = dist_size(), rank = dist_rank();
  Scratch sc = SCRATCH_OF(NULL);
  double *len = scratch_array(&sc, (size_t)t->samples + 1, sizeof(double));
  if (!len) return err_set_first(t->err, "out of memory"), 0;
  for (long k = 0; k < t->samples; k++)
    if ((k == 0 ? 0 : (int)(k % N)) == rank) len[k] = (double)t->rec.len[records_kept_index(t, k)];
  dist_allreduce_sum(len, t->samples);
  size_t used = 0;
  for (long k = 0; k < t->samples && used + (size_t)len[k] <= t->mem_cap; k++) used += (size_t)len[k];
  scratch_release(&sc);
  return used;
}

/* SampleSource.share: out of core over ranks every rank's passes evaluate
 * every sample, so each sample's record (inputs and extern values, encoded)
 * is sent from the rank that keeps it to all: every extern callback still
 * ran once, on one rank, and afterwards every rank keeps every sample (in
 * memory up to mem_cap, the rest in its scratch file). */
static int share_samples(void *user, Err *err) {
  SampleRecords *t = user;
  int N = dist_size(), rank = dist_rank();
  if (!t->mpi || N == 1 || t->all) return 0;
  Records old = t->rec;
  memset(&t->rec, 0, sizeof t->rec);
  int rc = 0;
  for (long k = 0; k < t->samples; k++) {
    int from = k == 0 ? 0 : (int)(k % N); /* sample 0: every rank has it */
    double bytes = 0;
    if (rank == from) {
      if (records_fetch(t, &old, records_kept_index(t, k)))
        rc = err_set(err, "cannot read training sample %ld back from the scratch file", k);
      bytes = rc ? -1 : (double)old.len[records_kept_index(t, k)];
    }
    dist_broadcast(&bytes, 1, from);
    if (bytes < 0) {
      if (!rc) rc = err_set(err, "rank %d could not read training sample %ld back from its scratch file", from, k);
      break;
    }
    dist_broadcast_bytes(t->enc, (long)bytes, from);
    if (records_store(t, &t->rec, k, (size_t)bytes)) {
      rc = err_set(err, "%s", err_held(t->err) ? t->err->msg : "out of memory");
      break;
    }
  }
  records_free_store(&old);
  t->all = true;
  return rc;
}

/* SampleSource: sample k back into the evaluator. */
static int replay(void *user, Full *f, long k) {
  SampleRecords *t = user;
  if (load_record(t, f, k)) return -1;
  records_decode(t);
  const double *v = t->buf;
  char from[64];
  snprintf(from, sizeof from, "training sample %ld", records_kept_index(t, k));
  for (int i = 0; i < t->nslots; i++) {
    long shape[MAX_AXES + MAX_STATIC];
    int nd = slot_shape(f, t->slot[i], shape);
    if (full_set(f, t->slot[i]->name, nd, shape, v, from) != 0) return -1;
    v += t->count[i];
  }
  return 0;
}

/* SampleSource: sample k back into the evaluator, of each extern only the
 * entries the restricted evaluation `d` reads (at the paper's size the
 * visibility is 25 M entries, a pass reads a few of its rows), decoded
 * straight into the evaluator. */
static int replay_part(void *user, Full *f, long k, const Demand *d) {
  SampleRecords *t = user;
  if (load_record(t, f, k)) return -1;
  char from[64];
  snprintf(from, sizeof from, "training sample %ld", records_kept_index(t, k));
  size_t pos = 0, off = 0;
  for (int i = 0; i < t->nslots; i++) {
    /* as many ranges as the demand has rows of boxes: a block of radiosity's stream sweep reads v at
     * a stripe and its transpose, one range a face (decoding all 25 M entries instead cost as much
     * as the evaluation) */
    long nr = t->slot[i]->kind == SYM_EXTERN ? demand_range_bound(d, t->slot[i]) : -1;
    if (nr > t->range_cap) {
      size_t *r = mem_realloc(t->ranges, sizeof(size_t) * 2 * (size_t)nr);
      if (!r) return full_fail(f, "out of memory reading a training sample back");
      t->ranges = r, t->range_cap = nr;
    }
    if (nr > 0) nr = demand_ranges(d, t->slot[i], t->ranges, nr);
    if (nr < 0) { /* whole, through the checks of npg_full_set */
      pos = records_decode_slot(t, i, pos, t->buf + off, NULL, -1);
      long shape[MAX_AXES + MAX_STATIC];
      int nd = slot_shape(f, t->slot[i], shape);
      if (full_set(f, t->slot[i]->name, nd, shape, t->buf + off, from) != 0) return -1;
    } else { /* recorded from values that passed those checks */
      double *v = full_extern_values(f, t->slot[i]->name, t->count[i]);
      if (!v) return -1;
      pos = records_decode_slot(t, i, pos, v, t->ranges, nr);
    }
    off += t->count[i];
  }
  return 0;
}

SampleSource records_source(SampleRecords *t) { return (SampleSource){t->samples, t, replay, replay_part, share_samples}; }
