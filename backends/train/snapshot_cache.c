/* snapshot_cache.c — the snapshots of one training kept for the next (train.h SnapshotCache;
 * greedy training, issue 41). Greedy training retrains after each sample it chooses, on the
 * samples of the last training and that one: replayed, every earlier sample was evaluated in full
 * again, N chosen samples cost N²/2 full evaluations. The first pass of training takes from each
 * evaluation only every member's values and whether each diagonal operator's diagonal is positive
 * (train_take_snapshots in memory); kept here, a retraining evaluates its new samples alone (and
 * its last sample, so that the evaluator ends on the values it ended on before: the same
 * arithmetic, only not repeated).
 *
 * The arrays move, not copied: training takes the cache's snapshots as its own (grown to its S
 * samples), and the cache takes them back when training ends; a training that fails frees them
 * and leaves the cache empty. A sample counts as held when its inputs and externs hash as the
 * cache's sample of that number did, under the same program, params and layout. */
#include <stdlib.h>
#include <string.h>

#include "train_steps.h"

struct SnapshotCache {
  const Program *prog;
  char *params;             /* train_param_hashes of the evaluator the snapshots were taken with */
  long S;                   /* samples held: their snapshots and marks */
  int nclasses;
  int *nmembers;            /* per class: its members, and */
  long *n;                  /*   their rows */
  double ***X;              /* [class][member] n x S column-major, as Snapshots.X */
  uint64_t *given;          /* per sample: the hash of its inputs and externs as set (room for `room`) */
  long room;
  bool lost;                /* a hash not noted (out of memory): the next training keeps nothing */
  bool *spd;                /* per diagonal operator (FOR_DIAG_OPS order): positive at every sample held */
  int nspd;
};

SnapshotCache *snapshot_cache_new(void) { return mem_calloc(1, sizeof(SnapshotCache)); }

long snapshot_cache_samples(const SnapshotCache *c) { return c ? c->S : 0; }

/* Everything held dropped (the cache stays usable, empty). */
static void forget(SnapshotCache *c) {
  for (int k = 0; c->X && k < c->nclasses; k++) {
    for (int i = 0; c->X[k] && i < c->nmembers[k]; i++) free(c->X[k][i]);
    free(c->X[k]);
  }
  free(c->X), free(c->nmembers), free(c->n), free(c->spd), free(c->params);
  c->X = NULL, c->nmembers = NULL, c->n = NULL, c->spd = NULL, c->params = NULL;
  c->S = 0, c->nclasses = 0, c->nspd = 0;
}

void snapshot_cache_free(SnapshotCache *c) {
  if (!c) return;
  forget(c);
  free(c->given);
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

/* Room for sample k's hash; false when out of memory. */
static bool note_room(SnapshotCache *c, long k) {
  if (k < c->room) return true;
  long room = 2 * k + 16;
  uint64_t *g = mem_realloc(c->given, sizeof(uint64_t) * (size_t)room);
  if (!g) return false;
  c->given = g, c->room = room;
  return true;
}

bool snapshot_cache_usable(const Train *t) { return t->opt->cache && !t->opt->dist; }

bool snapshot_cache_holds(Train *t, long k) {
  SnapshotCache *c = t->opt->cache;
  if (!snapshot_cache_usable(t) || k >= c->S || c->prog != t->prog) return false;
  return given_hash(t->f) == c->given[k];
}

void snapshot_cache_note(Train *t, long k) {
  SnapshotCache *c = t->opt->cache;
  if (!snapshot_cache_usable(t)) return;
  if (note_room(c, k)) c->given[k] = given_hash(t->f);
  else c->lost = true;
}

/* Whether the cache's snapshots are of t's program, params and layout, and its samples the first of
 * t's, each set to be compared (the last left set: the pass sets it again). */
static bool matches(Train *t) {
  SnapshotCache *c = t->opt->cache;
  const Model *m = t->m;
  if (c->S == 0 || c->S > t->sn.S || c->prog != t->prog || c->nclasses != m->nclasses) return false;
  for (int k = 0; k < m->nclasses; k++)
    if (c->nmembers[k] != m->classes[k].nmembers || c->n[k] != m->classes[k].n) return false;
  char *params = train_param_hashes(t->f);
  bool same = params && strcmp(params, c->params) == 0;
  free(params);
  for (long k = 0; same && k < c->S; k++) {
    if (t->src->set(t->src->user, t->f, k) != 0) return false;
    same = given_hash(t->f) == c->given[k];
  }
  return same;
}

long snapshot_cache_take(Train *t, bool *spd, int nspd) {
  SnapshotCache *c = t->opt->cache;
  if (!snapshot_cache_usable(t)) return 0;
  if (!matches(t) || c->nspd != nspd) {
    forget(c);
    return 0;
  }
  long S = t->sn.S, held = c->S;
  for (int k = 0; k < c->nclasses; k++)
    for (int i = 0; i < c->nmembers[k]; i++) { /* the columns of the samples held, then room for the others */
      double *X = mem_realloc(c->X[k][i], sizeof(double) * (size_t)c->n[k] * (size_t)S);
      if (!X) {
        forget(c);
        return 0;
      }
      free(t->sn.X[k][i]);
      t->sn.X[k][i] = X, c->X[k][i] = NULL;
    }
  for (int j = 0; j < nspd; j++) spd[j] = spd[j] && c->spd[j];
  forget(c); /* the arrays are training's now; the hashes stay, noted again as the pass goes */
  return held;
}

void snapshot_cache_keep(Train *t, const bool *spd, int nspd) {
  SnapshotCache *c = t->opt->cache;
  const Model *m = t->m;
  if (!snapshot_cache_usable(t)) return;
  forget(c);
  if (!t->sn.X || t->gram || c->lost) return (void)(c->lost = false);
  c->prog = t->prog;
  c->nclasses = m->nclasses;
  if (!(c->params = train_param_hashes(t->f)) || !(c->nmembers = mem_calloc((size_t)m->nclasses + 1, sizeof(int))) ||
      !(c->n = mem_calloc((size_t)m->nclasses + 1, sizeof(long))) ||
      !(c->X = mem_calloc((size_t)m->nclasses + 1, sizeof(double **))) ||
      !(c->spd = mem_calloc((size_t)nspd + 1, sizeof(bool))) || !note_room(c, t->sn.S)) {
    forget(c); /* out of memory: the next training replays its samples */
    return;
  }
  for (int k = 0; k < m->nclasses; k++) {
    c->nmembers[k] = m->classes[k].nmembers, c->n[k] = m->classes[k].n;
    if (!(c->X[k] = mem_calloc((size_t)c->nmembers[k] + 1, sizeof(double *)))) {
      forget(c);
      return;
    }
    for (int i = 0; i < c->nmembers[k]; i++) c->X[k][i] = t->sn.X[k][i], t->sn.X[k][i] = NULL;
  }
  memcpy(c->spd, spd, sizeof(bool) * (size_t)nspd);
  c->nspd = nspd;
  c->S = t->sn.S;
}
