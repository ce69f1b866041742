/* snapshot_cache.c — the snapshots of one training kept for the next (train.h SnapshotCache;
 * greedy training, issue 41). Greedy training retrains after each sample it chooses, on the
 * samples of the last training and that one: replayed, every earlier sample was evaluated in full
 * again, N chosen samples cost N²/2 full evaluations. The first pass of training takes from each
 * evaluation only every member's values and whether each diagonal operator's diagonal is positive
 * (train_take_snapshots in memory); kept here, a retraining evaluates its new samples alone (and
 * its last sample, so that the evaluator ends on the values it ended on before: the same
 * arithmetic, only not repeated).
 *
 * The cache is keyed by the samples' hashes (their inputs and externs as set), not by position:
 * the automatic hold-out numbers a training's samples otherwise than the retraining on all of them
 * that follows, and both take what the other left. A column holds one sample's values, and its own
 * SPD marks (each sample checked alone, so that any subset's marks are the and of its samples').
 * The columns a training did not take stay for one more training (the held-out samples, between
 * the training that validated on them and the retraining on all; the validation reads their values
 * from them, snapshot_cache_values). Over MPI ranks each rank notes
 * only the samples it evaluated (k ≡ rank mod N, its share): the gathered columns of the others
 * are kept unmarked, never taken, so a retraining evaluates a new sample on the rank that owns it.
 *
 * Training's arrays move into the cache when it ends; a retraining copies the columns it holds
 * into its own. A sample counts as held when its inputs and externs hash as a column's did, under
 * the same program, params and layout. */
#include <stdlib.h>
#include <string.h>

#include "dist.h"
#include "train_steps.h"

/* Per sample of the training in progress: its hash, whether this process knows it (set and
 * checked, or taken), the column taken from (-1: evaluated), its own SPD marks. */
typedef struct Pass {
  long S;
  uint64_t *hash;
  bool *known;
  long *from;
  bool *spd;                /* S x nspd */
} Pass;

struct SnapshotCache {
  const Program *prog;
  char *params;             /* train_param_hashes of the evaluator the snapshots were taken with */
  long S;                   /* columns held */
  int nclasses;
  int *nmembers;            /* per class: its members, and */
  long *n;                  /*   their rows */
  double ***X;              /* [class][member] n x S column-major, as Snapshots.X */
  uint64_t *given;          /* per column: the hash of its sample's inputs and externs as set */
  bool *known;              /* per column: noted by this process (else another rank's, never taken) */
  bool *fresh;              /* per column: the last training's (else left over once: dropped next) */
  bool *spd;                /* per column: its sample's own marks, nspd each (FOR_DIAG_OPS order) */
  int nspd;
  Pass pass;
  bool lost;                /* the pass's records not made (out of memory): this training's columns not kept */
};

SnapshotCache *snapshot_cache_new(void) { return mem_calloc(1, sizeof(SnapshotCache)); }

long snapshot_cache_samples(const SnapshotCache *c) {
  long n = 0;
  for (long j = 0; c && j < c->S; j++) n += c->known[j];
  return n;
}

static void pass_free(Pass *p) {
  free(p->hash), free(p->known), free(p->from), free(p->spd);
  *p = (Pass){0};
}

/* The columns dropped (the cache stays usable, empty). */
static void forget(SnapshotCache *c) {
  for (int k = 0; c->X && k < c->nclasses; k++) {
    for (int i = 0; c->X[k] && i < c->nmembers[k]; i++) free(c->X[k][i]);
    free(c->X[k]);
  }
  free(c->X), free(c->nmembers), free(c->n), free(c->spd), free(c->params), free(c->given), free(c->known);
  free(c->fresh);
  c->X = NULL, c->nmembers = NULL, c->n = NULL, c->spd = NULL, c->params = NULL, c->given = NULL, c->known = NULL;
  c->fresh = NULL, c->S = 0, c->nclasses = 0;
}

void snapshot_cache_free(SnapshotCache *c) {
  if (!c) return;
  forget(c);
  pass_free(&c->pass);
  free(c);
}

/* The hash of the values set in `f` for the program's inputs and externs. */
static uint64_t given_hash(const Full *f) {
  const Program *prog = full_program(f);
  uint64_t h = 0xcbf29ce484222325ull;
  for (int i = 0; i < prog->slots.n; i++) {
    const Sym *s = prog->slots.v[i];
    size_t n = 0;
    const double *v = s->kind == SYM_INPUT || s->kind == SYM_EXTERN ? full_get(f, s->name, &n) : NULL;
    if (v) h = (h ^ full_hash_values(v, n)) * 0x100000001b3ull + (uint64_t)i;
  }
  return h;
}

bool snapshot_cache_usable(const Train *t) { return t->opt->cache != NULL; }

/* Whether sample k is this process's (over ranks: k ≡ rank mod N, as the pass shares them). */
static bool owned(const Train *t, long k) { return !t->opt->dist || k % dist_size() == dist_rank(); }

/* The column holding the sample of hash h, or -1. */
static long column_of(const SnapshotCache *c, uint64_t h) {
  for (long j = 0; j < c->S; j++)
    if (c->known[j] && c->given[j] == h) return j;
  return -1;
}

bool snapshot_cache_begin(Train *t) {
  SnapshotCache *c = t->opt->cache;
  if (c) pass_free(&c->pass); /* a training that failed after its take left its own */
  if (!c || c->prog != t->prog || c->S == 0) return false;
  return owned(t, 0) || dist_rank() < t->src->count; /* another rank's: this one evaluates its share first */
}

/* Whether the cache's columns are of t's program, params and layout. */
static bool matches(Train *t, int nspd) {
  SnapshotCache *c = t->opt->cache;
  const Model *m = t->m;
  if (c->S == 0 || c->prog != t->prog || c->nclasses != m->nclasses || c->nspd != nspd) return false;
  for (int k = 0; k < m->nclasses; k++)
    if (c->nmembers[k] != m->classes[k].nmembers || c->n[k] != m->classes[k].n) return false;
  char *params = train_param_hashes(t->f);
  bool same = params && strcmp(params, c->params) == 0;
  free(params);
  return same;
}

/* The pass's per-sample records for S samples; false when out of memory. */
static bool pass_new(Pass *p, long S, int nspd) {
  pass_free(p);
  p->S = S;
  if (!(p->hash = mem_calloc((size_t)S + 1, sizeof(uint64_t))) || !(p->known = mem_calloc((size_t)S + 1, sizeof(bool))) ||
      !(p->from = mem_calloc((size_t)S + 1, sizeof(long))) ||
      !(p->spd = mem_calloc((size_t)S * (size_t)nspd + 1, sizeof(bool)))) {
    pass_free(p);
    return false;
  }
  for (long k = 0; k < S; k++) p->from[k] = -1;
  return true;
}

/* The columns no training sample took and not left over before, moved to the front (the others
 * freed); left over now. */
static void keep_leftovers(SnapshotCache *c, const bool *taken) {
  long L = 0;
  for (long j = 0; j < c->S; j++) {
    if (taken[j] || !c->fresh[j] || !c->known[j]) continue;
    for (int k = 0; k < c->nclasses; k++)
      for (int i = 0; i < c->nmembers[k]; i++)
        memmove(c->X[k][i] + (size_t)L * (size_t)c->n[k], c->X[k][i] + (size_t)j * (size_t)c->n[k],
                sizeof(double) * (size_t)c->n[k]);
    memmove(c->spd + (size_t)L * (size_t)c->nspd, c->spd + (size_t)j * (size_t)c->nspd, sizeof(bool) * (size_t)c->nspd);
    c->given[L] = c->given[j], c->known[L] = true, c->fresh[L] = false;
    L++;
  }
  c->S = L;
}

/* Sample k of t taken from column j: its columns copied into t->sn.X, its marks and-ed into spd. */
static void take_column(Train *t, long k, long j, bool *spd) {
  SnapshotCache *c = t->opt->cache;
  for (int q = 0; q < c->nclasses; q++)
    for (int i = 0; i < c->nmembers[q]; i++)
      memcpy(t->sn.X[q][i] + (size_t)k * (size_t)c->n[q], c->X[q][i] + (size_t)j * (size_t)c->n[q],
             sizeof(double) * (size_t)c->n[q]);
  const bool *own = c->spd + (size_t)j * (size_t)c->nspd;
  memcpy(c->pass.spd + (size_t)k * (size_t)c->nspd, own, sizeof(bool) * (size_t)c->nspd);
  for (int q = 0; q < c->nspd; q++) spd[q] = spd[q] && own[q];
  c->pass.hash[k] = c->given[j], c->pass.known[k] = true, c->pass.from[k] = j;
}

long snapshot_cache_take(Train *t, bool *spd, int nspd) {
  SnapshotCache *c = t->opt->cache;
  if (!snapshot_cache_usable(t)) return 0;
  long S = t->sn.S, held = 0;
  if (!pass_new(&c->pass, S, nspd)) {
    c->lost = true; /* nothing noted: this training's snapshots are not kept */
    return 0;
  }
  if (!matches(t, nspd)) {
    forget(c);
    c->nspd = nspd;
    return 0;
  }
  bool *taken = mem_calloc((size_t)c->S + 1, sizeof(bool));
  if (!taken) {
    forget(c);
    return 0;
  }
  for (long k = 0; k < S; k++) {
    if (!owned(t, k)) continue;
    if (t->src->set(t->src->user, t->f, k) != 0) break; /* the pass sets it again and says why */
    long j = column_of(c, given_hash(t->f));
    if (j < 0) continue;
    take_column(t, k, j, spd);
    taken[j] = true, held++;
  }
  keep_leftovers(c, taken);
  free(taken);
  return held;
}

bool snapshot_cache_kept(const Train *t, long k) {
  const SnapshotCache *c = t->opt->cache;
  return c && k < c->pass.S && c->pass.from[k] >= 0;
}

void snapshot_cache_note(Train *t, long k, const bool *spd, int nspd) {
  SnapshotCache *c = t->opt->cache;
  if (!snapshot_cache_usable(t)) return;
  if (k >= c->pass.S || nspd != c->nspd) return (void)(c->lost = true);
  c->pass.hash[k] = given_hash(t->f), c->pass.known[k] = true;
  memcpy(c->pass.spd + (size_t)k * (size_t)nspd, spd, sizeof(bool) * (size_t)nspd);
}

/* Room for the layout of t's model and L + S columns; false when out of memory (the cache
 * emptied). */
static bool layout_room(SnapshotCache *c, const Train *t, long total) {
  const Model *m = t->m;
  c->prog = t->prog;
  c->nclasses = m->nclasses;
  free(c->params);
  c->params = NULL;
  uint64_t *given = mem_realloc(c->given, sizeof(uint64_t) * (size_t)(total + 1));
  if (given) c->given = given;
  bool *known = given ? mem_realloc(c->known, (size_t)total + 1) : NULL;
  if (known) c->known = known;
  bool *fresh = known ? mem_realloc(c->fresh, (size_t)total + 1) : NULL;
  if (fresh) c->fresh = fresh;
  bool *spd = fresh ? mem_realloc(c->spd, (size_t)total * (size_t)c->nspd + 1) : NULL;
  if (spd) c->spd = spd;
  if (!spd || !(c->params = train_param_hashes(t->f))) return false;
  return true;
}

/* Training's snapshots of class k, member i, with the L columns left over after them. */
static double *join_member(SnapshotCache *c, Train *t, int k, int i, long L) {
  long S = t->sn.S, n = t->m->classes[k].n;
  double *X = L ? mem_realloc(t->sn.X[k][i], sizeof(double) * (size_t)n * (size_t)(S + L)) : t->sn.X[k][i];
  if (!X) return NULL;
  t->sn.X[k][i] = NULL;
  if (L) memcpy(X + (size_t)S * (size_t)n, c->X[k][i], sizeof(double) * (size_t)n * (size_t)L);
  return X;
}

/* t's columns as the cache's first, the leftovers after them; false when out of memory. */
static bool join(SnapshotCache *c, Train *t) {
  const Model *m = t->m;
  long S = t->sn.S, L = c->S;
  if (L && (c->nclasses != m->nclasses || c->prog != t->prog)) return false;
  double ***X = mem_calloc((size_t)m->nclasses + 1, sizeof(double **));
  int *nmembers = X ? mem_calloc((size_t)m->nclasses + 1, sizeof(int)) : NULL;
  long *n = nmembers ? mem_calloc((size_t)m->nclasses + 1, sizeof(long)) : NULL;
  bool room = n && layout_room(c, t, S + L), ok = room;
  for (int k = 0; ok && k < m->nclasses; k++) {
    nmembers[k] = m->classes[k].nmembers, n[k] = m->classes[k].n;
    ok = (X[k] = mem_calloc((size_t)nmembers[k] + 1, sizeof(double *))) != NULL;
    for (int i = 0; ok && i < nmembers[k]; i++) ok = (X[k][i] = join_member(c, t, k, i, L)) != NULL;
  }
  if (room) { /* the leftovers' marks after t's */
    memmove(c->given + S, c->given, sizeof(uint64_t) * (size_t)L);
    memmove(c->known + S, c->known, (size_t)L);
    memmove(c->fresh + S, c->fresh, (size_t)L);
    memmove(c->spd + (size_t)S * (size_t)c->nspd, c->spd, (size_t)L * (size_t)c->nspd);
  }
  for (int k = 0; c->X && k < c->nclasses; k++) { /* the leftovers' own arrays, copied */
    for (int i = 0; c->X[k] && i < c->nmembers[k]; i++) free(c->X[k][i]);
    free(c->X[k]);
  }
  free(c->X), free(c->nmembers), free(c->n);
  c->X = X, c->nmembers = nmembers, c->n = n, c->S = S + L;
  return ok;
}

void snapshot_cache_keep(Train *t) {
  SnapshotCache *c = t->opt->cache;
  if (!snapshot_cache_usable(t)) return;
  Pass p = c->pass;
  c->pass = (Pass){0};
  bool whole = t->sn.X && !t->gram && !c->lost && p.S == t->sn.S && p.S > 0;
  if (!whole || !join(c, t)) {
    forget(c); /* out of core, by the method of snapshots or out of memory: the next training replays */
    c->lost = false;
    pass_free(&p);
    return;
  }
  for (long k = 0; k < p.S; k++) {
    c->given[k] = p.hash[k], c->known[k] = p.known[k], c->fresh[k] = true;
    memcpy(c->spd + (size_t)k * (size_t)c->nspd, p.spd + (size_t)k * (size_t)c->nspd, (size_t)c->nspd);
  }
  pass_free(&p);
}

bool snapshot_cache_values(SnapshotCache *c, Full *f, const Model *m, double *out) {
  if (!c || c->S == 0 || c->prog != m->prog || c->nclasses != m->nclasses) return false;
  for (int k = 0; k < m->nclasses; k++)
    if (c->nmembers[k] != m->classes[k].nmembers || c->n[k] != m->classes[k].n) return false;
  long j = column_of(c, given_hash(f)), off = 0;
  char *params = j >= 0 ? train_param_hashes(f) : NULL;
  bool same = params && strcmp(params, c->params) == 0;
  free(params);
  for (int q = 0; same && q < m->nq; q++) { /* each quantity a member of its class (else evaluated) */
    const RClass *rc = &m->classes[m->qclass[q]];
    int i = 0;
    while (i < rc->nmembers && rc->members[i].q != q) i++;
    if (i == rc->nmembers) return false;
    memcpy(out + off, c->X[m->qclass[q]][i] + (size_t)j * (size_t)rc->n, sizeof(double) * (size_t)rc->n);
    off += rc->n;
  }
  return same;
}
