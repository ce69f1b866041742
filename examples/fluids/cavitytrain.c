/* cavitytrain.c — the cavity's training runs (cavity_train, cavitysim.h): full
 * simulations on several workers, their samples fed to one trainer in run order. */
#include "cavitysim.h"

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cblas.h>

#include "npg.h"
#include "solver.h"
#include "util.h"

#define ERRLEN 1024

/* ---------------------------------------------------------------- training runs
 *
 * The runs are independent full simulations; the trainer must see their
 * samples in run order (run 1's frames, then run 2's, ...) whatever the
 * number of workers, so that the model does not depend on it. One worker:
 * each run streams into the trainer as it goes (no buffer). W workers: each
 * takes the next run not started, with its own FullSolver (its own CHOLMOD
 * common); this thread adds the samples to the trainer in run order,
 * streaming the oldest unfinished run (the head) while later runs queue
 * their samples. A worker whose run is not the head waits once the queued
 * samples reach `buffer_bytes`, so the queue stays under that bound plus
 * one sample per worker; the head's worker never waits, so the runs always
 * progress. */

/* One frame's sample, queued: g, gdot, f, u in one block. */
typedef struct Sample {
  struct Sample *next;
  double x[];
} Sample;

/* The samples of one run waiting for the trainer. */
typedef struct RunQueue {
  Sample *first, *last;
  int state; /* 0 running or not started, 1 finished, -1 failed or stopped */
} RunQueue;

/* The runs shared by the workers and the thread feeding the trainer. */
typedef struct Training {
  const Cavity *cv;
  const CavityOptions *o;
  double mu;
  NpgTrainer *tr;
  int threaded;            /* 0: one worker, on the caller's thread, adding to `tr` itself */
  long ng, nf, nu;         /* a sample's parts: g and gdot (ng each), f, u */
  pthread_mutex_t lock;    /* guards everything below */
  pthread_cond_t changed;  /* a sample queued or taken, a run finished, the head moved, a stop */
  RunQueue *queue;         /* per run */
  int next;                /* the next run a worker starts */
  int head;                /* the run the trainer takes samples from */
  size_t queued;           /* bytes of samples in `queue` */
  int stop;                /* a run failed or the trainer refused a sample: every worker stops */
  double min_quality;      /* over the runs' frames */
  double seconds_runs;     /* the runs' own seconds (their steps), summed over the runs */
} Training;

static int stopped(Training *tg) {
  pthread_mutex_lock(&tg->lock);
  int stop = tg->stop;
  pthread_mutex_unlock(&tg->lock);
  return stop;
}

/* Stage one sample (x: g, gdot, f, u) in the trainer and add it. */
static int trainer_add_sample(Training *tg, const double *g, const double *gdot, const double *f, const double *u) {
  const FluidMesh *m = &tg->cv->m;
  long sg[2] = {m->nv, 3}, sf[1] = {m->nf}, su[2] = {m->nc, 3};
  NpgTrainer *tr = tg->tr;
  if (npg_trainer_set(tr, "g", 2, sg, g) || npg_trainer_set(tr, "gdot", 2, sg, gdot) ||
      npg_trainer_set(tr, "f", 1, sf, f) || npg_trainer_set(tr, "u", 2, su, u) || npg_trainer_add(tr)) {
    fprintf(stderr, "npg-fluids: trainer: %s\n", npg_trainer_error(tr));
    return -1;
  }
  return 0;
}

/* Hand run r's sample to the trainer (one worker) or to its queue (several):
 * 0, -1 on an error (said), 1 when the training has stopped. */
static int deliver(Training *tg, int r, const double *g, const double *gdot, const double *f, const double *u) {
  if (!tg->threaded) return trainer_add_sample(tg, g, gdot, f, u) ? -1 : 0;
  size_t bytes = sizeof(Sample) + (size_t)(2 * tg->ng + tg->nf + tg->nu) * sizeof(double);
  Sample *s = malloc(bytes);
  if (!s) {
    fprintf(stderr, "npg-fluids: training run %d: out of memory queueing a sample\n", r + 1);
    return -1;
  }
  s->next = NULL;
  memcpy(s->x, g, tg->ng * sizeof(double));
  memcpy(s->x + tg->ng, gdot, tg->ng * sizeof(double));
  memcpy(s->x + 2 * tg->ng, f, tg->nf * sizeof(double));
  memcpy(s->x + 2 * tg->ng + tg->nf, u, tg->nu * sizeof(double));
  pthread_mutex_lock(&tg->lock);
  while (!tg->stop && r != tg->head && tg->queued >= tg->o->buffer_bytes) pthread_cond_wait(&tg->changed, &tg->lock);
  int stop = tg->stop;
  if (!stop) {
    RunQueue *q = &tg->queue[r];
    if (q->last) q->last->next = s;
    else q->first = s;
    q->last = s;
    tg->queued += bytes;
    pthread_cond_broadcast(&tg->changed);
  }
  pthread_mutex_unlock(&tg->lock);
  if (stop) free(s);
  return stop;
}

/* One full training run r, every o->sample_every-th frame delivered: sample
 * t is the state of frame t (g, f, u) with the mesh velocity of the step
 * that leaves it (as the 2D tunnel's). 0, -1 on an error (said, with the
 * run's number), 1 when stopped by another run's failure. */
static int training_run(Training *tg, int r, double *min_quality, double *seconds) {
  char err[ERRLEN];
  const Cavity *cv = tg->cv;
  const CavityOptions *o = tg->o;
  const FluidMesh *m = &cv->m;
  int T = o->frames, rc = -1;
  long ng = 3L * m->nv, nf = m->nf, nu = 3L * m->nc;
  double *g = malloc(ng * sizeof *g), *g0 = malloc(ng * sizeof *g0), *f0 = malloc(nf * sizeof *f0);
  double *u0 = malloc(nu * sizeof *u0), t_def = 0;
  const double zero[3] = {0};
  FullSolver s;
  if (!g || !g0 || !f0 || !u0) {
    fprintf(stderr, "npg-fluids: training run %d: out of memory\n", r + 1);
    free(g), free(g0), free(f0), free(u0);
    return -1;
  }
  if (cavity_deform_at(cv, r, 0, T, g, &t_def, err, sizeof err) != 0 ||
      solver_init_at(&s, m, o->projection, tg->mu, o->dt, g, zero, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: training run %d: %s\n", r + 1, err);
    free(g), free(g0), free(f0), free(u0);
    return -1;
  }
  double t0 = util_now();
  for (int t = 0; t < T; t++) {
    memcpy(g0, s.g, ng * sizeof *g0);
    memcpy(f0, s.f, nf * sizeof *f0);
    memcpy(u0, s.u, nu * sizeof *u0);
    if (tg->threaded && stopped(tg)) {
      rc = 1;
      goto done;
    }
    if (cavity_deform_at(cv, r, t + 1, T, g, &t_def, err, sizeof err) != 0 || solver_step_to(&s, g, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: training run %d, frame %d: %s\n", r + 1, t + 1, err);
      goto done;
    }
    if (s.min_quality < *min_quality) *min_quality = s.min_quality;
    if (!isfinite(solver_energy(&s))) {
      fprintf(stderr, "npg-fluids: training run %d diverged at frame %d of %d (the energy is not finite): the step "
              "--dt %g is too large for a deformation over %d frames; raise --frames (the default grows as the cells shrink) "
              "or lower --dt\n", r + 1, t + 1, T, o->dt, T);
      goto done;
    }
    if (t % o->sample_every == 0) {
      int d = deliver(tg, r, g0, s.gdot, f0, u0);
      if (d != 0) {
        rc = d;
        goto done;
      }
    }
  }
  rc = 0;
done:
  *seconds += util_now() - t0;
  solver_free(&s);
  free(g), free(g0), free(f0), free(u0);
  return rc;
}

/* A worker: runs in turn until none is left or the training stops. */
static void *training_worker(void *arg) {
  Training *tg = arg;
  int runs = tg->o->runs, T = tg->o->frames;
  pthread_mutex_lock(&tg->lock);
  while (!tg->stop && tg->next < runs) {
    int r = tg->next++;
    pthread_mutex_unlock(&tg->lock);
    double sg[CAVITY_SIDES], q = INFINITY, seconds = 0;
    cavity_schedule(r, T / 2, T, sg);
    fprintf(stderr, "npg-fluids: training run %d of %d: side scales (%.2f, %.2f, %.2f) at mid-run\n", r + 1, runs,
            sg[0], sg[1], sg[2]);
    int rc = training_run(tg, r, &q, &seconds);
    pthread_mutex_lock(&tg->lock);
    tg->queue[r].state = rc == 0 ? 1 : -1;
    if (rc != 0) tg->stop = 1;
    if (q < tg->min_quality) tg->min_quality = q;
    tg->seconds_runs += seconds;
    pthread_cond_broadcast(&tg->changed);
  }
  pthread_mutex_unlock(&tg->lock);
  return NULL;
}

/* The workers' samples into the trainer in run order; -1 when the training
 * stopped (a failed run said why; a refused sample is said here). */
static int feed_trainer(Training *tg) {
  size_t bytes = sizeof(Sample) + (size_t)(2 * tg->ng + tg->nf + tg->nu) * sizeof(double);
  pthread_mutex_lock(&tg->lock);
  while (!tg->stop && tg->head < tg->o->runs) {
    RunQueue *q = &tg->queue[tg->head];
    Sample *s = q->first;
    if (s) {
      q->first = s->next;
      if (!q->first) q->last = NULL;
      tg->queued -= bytes;
      pthread_cond_broadcast(&tg->changed);
      pthread_mutex_unlock(&tg->lock);
      const double *x = s->x;
      int rc = trainer_add_sample(tg, x, x + tg->ng, x + 2 * tg->ng, x + 2 * tg->ng + tg->nf);
      free(s);
      pthread_mutex_lock(&tg->lock);
      if (rc != 0) tg->stop = 1, pthread_cond_broadcast(&tg->changed);
    } else if (q->state != 0) {
      tg->head++;
      pthread_cond_broadcast(&tg->changed);
    } else {
      pthread_cond_wait(&tg->changed, &tg->lock);
    }
  }
  int stop = tg->stop;
  pthread_mutex_unlock(&tg->lock);
  return stop ? -1 : 0;
}

int cavity_train(const Cavity *cv, const CavityOptions *given, double mu, NpgTrainer *tr, CavityTraining *out) {
  CavityOptions chosen = *given; /* --sample-every 0: from the frames */
  if (chosen.sample_every <= 0) chosen.sample_every = cavity_sample_every_for(chosen.frames);
  const CavityOptions *o = &chosen;
  const FluidMesh *m = &cv->m;
  int workers = o->workers < 1 ? 1 : o->workers < o->runs ? o->workers : o->runs > 0 ? o->runs : 1;
  Training tg = {.cv = cv, .o = o, .mu = mu, .tr = tr, .threaded = workers > 1, .ng = 3L * m->nv, .nf = m->nf,
                 .nu = 3L * m->nc, .min_quality = INFINITY};
  memset(out, 0, sizeof *out);
  out->workers = workers;
  tg.queue = calloc(o->runs > 0 ? o->runs : 1, sizeof *tg.queue);
  if (!tg.queue) {
    fprintf(stderr, "npg-fluids: out of memory\n");
    return -1;
  }
  pthread_mutex_init(&tg.lock, NULL);
  pthread_cond_init(&tg.changed, NULL);
  double t0 = util_now();
  int rc = 0;
  if (!tg.threaded) {
    training_worker(&tg);
    rc = tg.stop ? -1 : 0;
  } else {
    /* the workers fill the cores: OpenBLAS's own threads would only contend */
    int blas_threads = openblas_get_num_threads();
    openblas_set_num_threads(1);
    pthread_t tid[CAVITY_MAX_WORKERS];
    int started = 0;
    for (; started < workers; started++) {
      int e = pthread_create(&tid[started], NULL, training_worker, &tg);
      if (e != 0) {
        fprintf(stderr, "npg-fluids: cannot start training worker %d: %s\n", started + 1, strerror(e));
        pthread_mutex_lock(&tg.lock);
        tg.stop = 1;
        pthread_cond_broadcast(&tg.changed);
        pthread_mutex_unlock(&tg.lock);
        break;
      }
    }
    rc = feed_trainer(&tg);
    for (int i = 0; i < started; i++) pthread_join(tid[i], NULL);
    if (started < workers) rc = -1;
    openblas_set_num_threads(blas_threads);
  }
  out->seconds = util_now() - t0;
  out->seconds_runs = tg.seconds_runs;
  out->min_quality = tg.min_quality;
  for (int r = 0; r < o->runs; r++)
    for (Sample *s = tg.queue[r].first, *n; s; s = n) n = s->next, free(s);
  free(tg.queue);
  pthread_mutex_destroy(&tg.lock);
  pthread_cond_destroy(&tg.changed);
  return rc;
}
