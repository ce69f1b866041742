/* greedy.c — greedy training through npg.h (npg_train_greedy; DESIGN §16, issue 41): the weak
 * greedy of reduced-basis methods (pyMOR's), driven by the online estimate (estimate.h). Each
 * iteration is one training (npg_trainer) on the start samples and the candidates chosen so far,
 * then one reduced evaluation and estimate per remaining candidate; the worst joins. The trainings
 * share one SnapshotCache (train.h): each takes the earlier samples' snapshots from the last and
 * evaluates its new sample alone, so every training sample is evaluated in full once (with the
 * automatic hold-out, also found by their hashes; over MPI ranks each rank holds its share's and
 * estimates its share of the candidates). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "api.h"
#include "dist.h"
#include "estimate.h"

#define gfail(res, ...) error_set_first((res)->error, sizeof (res)->error, __VA_ARGS__)

/* What every iteration of greedy training reads: the evaluator, the options, the start samples and
 * the pool, the snapshots kept between trainings. */
typedef struct Greedy {
  NpgFull *f;
  const NpgTrainOptions *o;
  long nstart, npool;
  NpgSampleFn start, pool;
  void *suser, *puser;
  const NpgGreedyOptions *g;
  SnapshotCache *cache;     /* the last training's snapshots: a retraining evaluates its new sample alone */
} Greedy;

/* One training on the start samples and the chosen ones; NULL with res->error. */
static NpgModel *train_once(const Greedy *gr, NpgGreedyResult *res) {
  NpgFull *f = gr->f;
  NpgTrainer *t = npg_trainer_new(f, gr->o);
  api_trainer_inputs_whole(t); /* each input's basis holds every direction of the samples chosen */
  api_trainer_cache(t, gr->cache);
  NpgModel *m = NULL;
  long nstart = gr->nstart;
  for (long k = 0; k < nstart + res->nchosen && !npg_trainer_error(t)[0]; k++) {
    int rc = k < nstart ? gr->start(gr->suser, f, k) : gr->pool(gr->puser, f, res->chosen[k - nstart]);
    if (rc != 0) {
      gfail(res, "%s sample %ld: %s", k < nstart ? "start" : "pool", k < nstart ? k : res->chosen[k - nstart],
            npg_full_error(f));
      npg_trainer_free(t);
      return NULL;
    }
    npg_trainer_add_full(t, f);
  }
  if (!npg_trainer_error(t)[0]) m = npg_trainer_finish(t, NULL);
  if (!m) gfail(res, "%s", npg_trainer_error(t));
  npg_trainer_free(t);
  return m;
}

/* Candidate c's worst estimated error over the outputs, relative (estimate / ‖output‖) or with
 * `absolute` the estimate itself; NAN with res->error. When an input lies outside its basis,
 * *outside and the largest such input's share outside it, ‖x − B x̂‖ / ‖x‖, in place of the outputs'. */
static double candidate_error(NpgFull *f, NpgReduced *r, NpgSampleFn pool, void *puser, long c, bool absolute,
                              bool *outside, NpgGreedyResult *res) {
  const Model *m = r->nm->m;
  if (pool(puser, f, c) != 0) return gfail(res, "pool sample %ld: %s", c, npg_full_error(f)), NAN;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = m->prog->quantities.v[q];
    size_t n = 0;
    const double *v = s->kind == SYM_INPUT ? npg_full_get(f, s->name, &n) : NULL;
    if (v && npg_reduced_set(r, s->name, n, v) != 0) return gfail(res, "pool sample %ld: %s", c, npg_reduced_error(r)), NAN;
  }
  if (npg_reduced_eval(r, c) != 0) return gfail(res, "pool sample %ld: %s", c, npg_reduced_error(r)), NAN;
  double worst = 0;
  *outside = false;
  for (int q = 0; q < m->nq; q++) { /* an input its basis does not hold: a full evaluation there adds the direction */
    const Sym *s = m->prog->quantities.v[q];
    double e = 0, nx = 0;
    size_t n = 0;
    if (s->kind != SYM_INPUT || npg_reduced_estimate(r, s->name, &e, NULL) != 0 || !(e > 0)) continue;
    const double *x = npg_full_get(f, s->name, &n);
    for (size_t k = 0; x && k < n; k++) nx += x[k] * x[k];
    *outside = true;
    worst = fmax(worst, nx > 0 ? e / sqrt(nx) : e);
  }
  if (*outside) return worst;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = m->prog->quantities.v[q];
    if (!s->is_output) continue;
    double e;
    if (npg_reduced_estimate(r, s->name, &e, NULL) != 0) return gfail(res, "%s", npg_reduced_error(r)), NAN;
    if (isnan(e))
      return gfail(res, "greedy training needs an estimate of every output: %s has none (%s)", s->name,
                   npg_reduced_estimate_why(r, s->name)), NAN;
    if (absolute) {
      worst = fmax(worst, e);
      continue;
    }
    size_t mq = 0;
    const double *y = npg_reduced_coords(r, s->name, &mq);
    double ny = 0; /* ‖B ŷ‖ = ‖ŷ‖: B is orthonormal (in the product's norm, the estimate's, for a class with one) */
    for (size_t a = 0; a < mq; a++) ny += y[a] * y[a];
    ny = sqrt(ny);
    worst = fmax(worst, ny > 0 ? e / ny : e > 0 ? INFINITY : 0);
  }
  return worst;
}

/* Whether the candidates are shared among MPI ranks: training over them (the first training
 * joined the job). */
static bool split(const Greedy *gr) { return gr->o->mpi && dist_size() > 1; }

/* The ranks' worst candidates (res->worst, worst_at, *outside: each rank's of its share) reduced to
 * the job's on every rank: outside a basis first, then the largest estimate, then the first in the
 * pool's order, as one process finds it. `rc`: this rank's; -1 on every rank when one failed. */
static int reduce_worst(NpgGreedyResult *res, bool *outside, int rc) {
  double any[2] = {*outside ? 1 : 0, rc != 0 ? 1 : 0};
  dist_allreduce_max(any, 2);
  if (any[1] > 0) return rc ? rc : gfail(res, "greedy training: another MPI rank failed estimating its candidates");
  bool mine = res->worst_at >= 0 && *outside == (any[0] > 0); /* this rank's worst among the job's kind */
  double e = mine ? res->worst : -INFINITY;
  dist_allreduce_max(&e, 1);
  double c = mine && res->worst == e ? -(double)res->worst_at : -INFINITY; /* the first: the largest -c */
  dist_allreduce_max(&c, 1);
  *outside = any[0] > 0;
  res->worst = isinf(c) ? -1 : e, res->worst_at = isinf(c) ? -1 : (long)-c;
  return 0;
}

/* The worst candidate not chosen into res (worst, worst_at): one whose input lies outside its
 * basis before any other (res->worst INFINITY; among them the farthest outside, so that the first
 * choices span the inputs' space), else the largest estimate; -1 on an error. Over MPI ranks each
 * rank estimates the candidates c ≡ rank (mod ranks), the worst reduced over them. */
static int worst_candidate(const Greedy *gr, NpgModel *nm, NpgGreedyResult *res) {
  NpgReduced *r = npg_reduced_new(nm);
  if (npg_reduced_error(r)[0]) {
    gfail(res, "%s", npg_reduced_error(r));
    npg_reduced_free(r);
    return -1;
  }
  res->worst = -1, res->worst_at = -1;
  int rc = 0, step = split(gr) ? dist_size() : 1;
  bool worst_outside = false;
  for (long c = split(gr) ? dist_rank() : 0; c < gr->npool && rc == 0; c += step) {
    bool taken = false, outside;
    for (long j = 0; j < res->nchosen; j++) taken |= res->chosen[j] == c;
    if (taken) continue;
    double e = candidate_error(gr->f, r, gr->pool, gr->puser, c, gr->g->absolute, &outside, res);
    if (isnan(e)) rc = -1;
    else if (outside > worst_outside || (outside == worst_outside && e > res->worst))
      res->worst = e, res->worst_at = c, worst_outside = outside;
  }
  if (split(gr)) rc = reduce_worst(res, &worst_outside, rc);
  if (res->worst_at < 0) res->worst = 0; /* every candidate chosen */
  if (worst_outside) res->worst = INFINITY;
  npg_reduced_free(r);
  return rc;
}

/* The manifest's greedy line: the record of the choice. */
static int record(NpgModel *nm, const NpgGreedyOptions *g, long budget, const NpgGreedyResult *res) {
  size_t cap = 128 + 24 * (size_t)res->nchosen;
  char *line = malloc(cap);
  if (!line) return -1;
  int n = snprintf(line, cap, "tol %.17g %s budget %ld converged %d worst %.17g chosen ", g->tol,
                   g->absolute ? "absolute" : "relative", budget, res->converged ? 1 : 0, res->worst);
  for (long j = 0; j < res->nchosen; j++) n += snprintf(line + n, cap - (size_t)n, "%s%ld", j ? "," : "", res->chosen[j]);
  if (res->nchosen == 0) snprintf(line + n, cap - (size_t)n, "none");
  free(nm->m->greedy);
  nm->m->greedy = line;
  return 0;
}

/* The loop: train, find the worst candidate, add it, until it is below the tolerance or the
 * budget is spent; the last model, NULL with res->error. */
static NpgModel *greedy_loop(const Greedy *gr, long budget, NpgGreedyResult *res) {
  const NpgGreedyOptions *g = gr->g;
  long before, after;
  full_evaluations(gr->f->full, &before, NULL);
  NpgModel *nm = NULL;
  for (;;) {
    npg_model_free(nm);
    if (!(nm = train_once(gr, res))) return NULL;
    if (worst_candidate(gr, nm, res) != 0) {
      npg_model_free(nm);
      return NULL;
    }
    full_evaluations(gr->f->full, &after, NULL);
    double done = (double)(after - before); /* over MPI ranks, the job's */
    if (split(gr)) dist_allreduce_sum(&done, 1);
    res->evaluations = (long)done;
    res->converged = res->worst < g->tol;
    long samples = gr->nstart + res->nchosen;
    bool progress = g->progress && dist_rank() == 0; /* one rank reports */
    if (progress && isinf(res->worst))
      fprintf(stderr, "greedy: %ld training samples (%ld full evaluations), candidate %ld: an input outside its basis\n",
              samples, res->evaluations, res->worst_at);
    else if (progress)
      fprintf(stderr, "greedy: %ld training samples (%ld full evaluations), worst candidate %ld: estimated %s error "
              "%.3e (tol %.3g)\n", samples, res->evaluations, res->worst_at, g->absolute ? "absolute" : "relative",
              res->worst, g->tol);
    if (res->converged || res->worst_at < 0 || samples >= budget) return nm;
    res->chosen[res->nchosen++] = res->worst_at;
  }
}

NpgModel *npg_train_greedy(NpgFull *f, const NpgTrainOptions *o, long nstart, NpgSampleFn start, void *suser,
                           long npool, NpgSampleFn pool, void *puser, const NpgGreedyOptions *g,
                           const char *model_dir, NpgGreedyResult *res) {
  API_REFUSE_NULL(res, NULL, 0, NULL);
  memset(res, 0, sizeof *res);
  API_REFUSE_NULL(f, res->error, sizeof res->error, NULL);
  API_REFUSE_NULL(o, res->error, sizeof res->error, NULL);
  API_REFUSE_NULL(start, res->error, sizeof res->error, NULL);
  API_REFUSE_NULL(pool, res->error, sizeof res->error, NULL);
  API_REFUSE_NULL(g, res->error, sizeof res->error, NULL);
  if (nstart < 1) return gfail(res, "greedy training: no start samples (at least one)"), NULL;
  if (npool < 1) return gfail(res, "greedy training: an empty pool of candidates"), NULL;
  if (!(g->tol > 0) || !isfinite(g->tol)) return gfail(res, "greedy training: tolerance %g (a positive number)", g->tol), NULL;
  if (g->budget < 0 || (g->budget > 0 && g->budget < nstart))
    return gfail(res, "greedy training: budget %ld below the %ld start samples", g->budget, nstart), NULL;
  long budget = g->budget ? g->budget : nstart + npool;
  if (!(res->chosen = calloc((size_t)npool + 1, sizeof(long)))) return gfail(res, "out of memory"), NULL;
  Greedy gr = {f, o, nstart, npool, start, pool, suser, puser, g, snapshot_cache_new()};
  if (!gr.cache) return gfail(res, "out of memory"), NULL;
  NpgModel *nm = greedy_loop(&gr, budget, res);
  snapshot_cache_free(gr.cache);
  if (nm && !res->converged && g->progress && dist_rank() == 0)
    fprintf(stderr, "greedy: stopped at the budget of %ld training samples with the worst candidate's estimate %.3e "
            "above --tol %.3g\n", budget, res->worst, g->tol);
  if (nm && record(nm, g, budget, res) != 0) {
    gfail(res, "out of memory");
    npg_model_free(nm);
    return NULL;
  }
  if (nm && model_dir && npg_model_save(nm, model_dir) != 0) {
    gfail(res, "%s", npg_model_error(nm));
    npg_model_free(nm);
    return NULL;
  }
  return nm;
}
