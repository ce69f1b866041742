/* reduced.c — the reduced radiosity through npg.h (reduced.h). */
#include "reduced.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "design.h"
#include "frame.h"

/* The visibility extern's callback: v of the g the evaluator holds, ray-cast. */
static int visibility_extern(void *user, const NpgFull *f, long sample, double *out, size_t count) {
  Reduced *r = user;
  size_t ng = 0;
  const double *g = npg_full_get(f, "g", &ng);
  if (!g || ng != (size_t)(3 * r->V) || count != (size_t)(r->F * r->F)) {
    snprintf(r->err, sizeof r->err, "sample %ld: visibility callback got %zu positions and %zu entries", sample, ng,
             count);
    return -1;
  }
  double t0 = frame_now();
  int rc = vis_compute(r->vis, g, out, r->err, sizeof r->err);
  r->ray_seconds += frame_now() - t0;
  r->ray_calls++;
  return rc;
}

static int failed(char *err, size_t errlen, const char *what, const char *msg) {
  snprintf(err, errlen, "%s: %s", what, msg);
  return -1;
}

int reduced_open(Reduced *r, const Scene *s, const char *program, int k, int threads, char *err, size_t errlen) {
  memset(r, 0, sizeof *r);
  r->V = s->V, r->F = s->F;
  r->prog = npg_compile(program, NULL);
  if (!npg_ok(r->prog)) return failed(err, errlen, program, npg_error(r->prog));
  r->full = npg_full_new(r->prog, NPG_TCC);
  if (npg_full_error(r->full)[0]) return failed(err, errlen, "full evaluator", npg_full_error(r->full));
  double *tri = malloc(sizeof(double) * 3 * (size_t)s->F);
  r->g = malloc(sizeof(double) * 3 * (size_t)s->V);
  if (!tri || !r->g) {
    free(tri);
    return failed(err, errlen, "reduced", "out of memory");
  }
  for (long i = 0; i < 3 * s->F; i++) tri[i] = s->tri[i];
  long st[2] = {s->F, 3}, sf[1] = {s->F};
  int rc = npg_full_set_param(r->full, "tri", 2, st, tri, "scene tri") ||
           npg_full_set_param(r->full, "rho", 1, sf, s->rho, "scene rho");
  free(tri);
  if (rc) return failed(err, errlen, "binding the scene", npg_full_error(r->full));
  r->vis = vis_new(s->V, s->F, s->tri, k, threads, VIS_STREAM, err, errlen);
  if (!r->vis) return -1;
  if (npg_full_set_extern_fn(r->full, "v", visibility_extern, r))
    return failed(err, errlen, "visibility extern", npg_full_error(r->full));
  return 0;
}

/* ---------------------------------------------------------------- the phases of finishing
 *
 * npg_trainer_finish reports progress on stderr ("\r<what> [###   ] done/total") but no
 * timings: while it runs, stderr goes through a pipe whose reader passes everything on and
 * notes when each phase's bar first appears. */
typedef struct PhaseWatch {
  int saved, pipe[2];
  pthread_t thread;
  double start, first[4], last[4]; /* bars of: snapshots, member bases, pre-multiplication, extern samples */
} PhaseWatch;

/* A bar segment: "<what> [###   ] done/total". */
static int is_bar(const char *seg) {
  const char *open = strstr(seg, " ["), *close = open ? strstr(open, "] ") : NULL;
  return close && strchr(close, '/');
}

static void *phase_reader(void *arg) {
  PhaseWatch *w = arg;
  char seg[512];
  size_t n = 0;
  char c;
  int tty = isatty(w->saved);
  for (;;) {
    int got = read(w->pipe[0], &c, 1) == 1;
    if (got && c != '\r' && c != '\n' && n + 1 < sizeof seg) {
      seg[n++] = c, seg[n] = 0;
      if (n == 20) {
        const char *names[4] = {"snapshots", "member bases", "pre-multiplication", "extern samples"};
        for (int i = 0; i < 4; i++)
          if (!strncmp(seg, names[i], strlen(names[i]))) {
            w->last[i] = frame_now();
            if (w->first[i] == 0) w->first[i] = w->last[i];
          }
      }
      continue;
    }
    /* a segment ends: pass it on, bars only to a terminal (a log keeps the last one) */
    seg[n] = 0;
    int bar = is_bar(seg);
    if (tty || !bar || (got && c == '\n')) {
      if (write(w->saved, seg, n) < 0 || (got && write(w->saved, &c, 1) < 0)) { /* stderr gone: keep draining */
      }
    }
    n = 0;
    if (!got) break;
  }
  return NULL;
}

static int phase_watch_start(PhaseWatch *w) {
  memset(w, 0, sizeof *w);
  fflush(stderr);
  w->start = frame_now();
  if (pipe(w->pipe) != 0) return -1;
  w->saved = dup(2);
  if (w->saved < 0 || dup2(w->pipe[1], 2) < 0) return -1;
  close(w->pipe[1]);
  return pthread_create(&w->thread, NULL, phase_reader, w) ? -1 : 0;
}

static void phase_watch_stop(PhaseWatch *w, TrainTimes *t) {
  fflush(stderr);
  double end = frame_now();
  dup2(w->saved, 2); /* closes the pipe's last write end: the reader sees EOF */
  pthread_join(w->thread, NULL);
  close(w->saved);
  close(w->pipe[0]);
  /* snapshots: until their last bar; PCA (member bases): from there to the first bar of
   * pre-multiplication; pre-multiplication: to the first bar of the learned visibility's
   * samples; those: to the end */
  double snap_end = w->last[0] ? w->last[0] : w->start;
  double pre = w->first[2] ? w->first[2] : end, ext = w->first[3] ? w->first[3] : end;
  t->snapshots = snap_end - w->start;
  t->pca = pre - snap_end;
  t->premultiply = ext - pre;
  t->externs = end - ext;
  t->finish = end - w->start;
}

int reduced_train(Reduced *r, Scene *s, int samples, int cap, double energy, size_t mem, const char *model_dir,
                  TrainTimes *t, char *err, size_t errlen) {
  memset(t, 0, sizeof *t);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = cap, o.energy = energy, o.progress = true;
  /* g moves linearly with eight of the nine parameters (patch corners slide) and with the
   * sine and cosine of the tilt: dropping one of its few directions at 0.999 loses a
   * parameter outright, and the thin faces its areas then miss (a strip over a large
   * window) turn the root's operator diag(a) indefinite. The small classes of the geometry
   * (g, the area vectors n, the squared areas a) keep 1 - 1e-6 of their energy. */
  static const char *const names[3] = {"g", "n", "a"};
  static const int caps[3] = {-1, -1, -1}, centers[3] = {-1, -1, -1};
  static const double energies[3] = {1 - 1e-6, 1 - 1e-6, 1 - 1e-6};
  o.nbasis = 3, o.basis_name = names, o.basis_cap = caps, o.basis_energy = energies, o.basis_center = centers;
  if (mem) o.mem = mem;
  NpgTrainer *tr = npg_trainer_new(r->full, &o);
  if (!tr) return failed(err, errlen, "trainer", "out of memory");
  long sg[2] = {s->V, 3}, sf[1] = {s->F};
  double t0 = frame_now();
  r->ray_seconds = 0, r->ray_calls = 0;
  for (int k = 0; k < samples; k++) {
    SceneParams p;
    design_point(k, &p);
    scene_place(s, &p, NULL);
    if (npg_trainer_set(tr, "g", 2, sg, s->g) || npg_trainer_set(tr, "e", 1, sf, s->e) || npg_trainer_add(tr)) {
      snprintf(err, errlen, "training sample %d: %s%s%s", k, npg_trainer_error(tr), r->err[0] ? ": " : "", r->err);
      npg_trainer_free(tr);
      return -1;
    }
    npg_progress(isatty(2), "samples (ray casting)", k + 1, samples);
  }
  t->samples = frame_now() - t0;
  t->rays = r->ray_seconds;
  PhaseWatch w;
  int watching = phase_watch_start(&w) == 0;
  r->model = npg_trainer_finish(tr, model_dir);
  if (watching) phase_watch_stop(&w, t);
  t->total = frame_now() - t0;
  if (!r->model) {
    snprintf(err, errlen, "training: %s", npg_trainer_error(tr));
    npg_trainer_free(tr);
    return -1;
  }
  npg_trainer_free(tr);
  r->learned = npg_reduced_new(r->model);
  r->given = npg_reduced_new(r->model);
  if (!r->learned || !r->given) return failed(err, errlen, "reduced evaluator", "out of memory");
  npg_reduced_given_externs(r->given, true);
  return 0;
}

int reduced_load(Reduced *r, const char *model_dir, char *err, size_t errlen) {
  r->model = npg_model_load(r->prog, model_dir);
  if (!r->model || npg_model_error(r->model)[0])
    return failed(err, errlen, model_dir, r->model ? npg_model_error(r->model) : "out of memory");
  if (npg_model_dim(r->model, "F") != r->F || npg_model_dim(r->model, "V") != r->V) {
    snprintf(err, errlen, "%s: trained for %ld faces and %ld vertices, the scene has %ld and %ld (--faces?)",
             model_dir, npg_model_dim(r->model, "F"), npg_model_dim(r->model, "V"), r->F, r->V);
    return -1;
  }
  char why[1024];
  if (npg_model_check_params(r->model, r->full, why, sizeof why)) return failed(err, errlen, model_dir, why);
  r->learned = npg_reduced_new(r->model);
  r->given = npg_reduced_new(r->model);
  if (!r->learned || !r->given) return failed(err, errlen, "reduced evaluator", "out of memory");
  npg_reduced_given_externs(r->given, true);
  return 0;
}

int reduced_frame(Reduced *r, const Scene *s, const SceneParams *p, long sample, double *b, char *err,
                  size_t errlen) {
  scene_place((Scene *)s, p, r->g);
  double e[s->F];
  scene_emission(s, p, e);
  NpgReduced *q = r->learned;
  if (npg_reduced_set(q, "g", (size_t)(3 * r->V), r->g) || npg_reduced_set(q, "e", (size_t)r->F, e) ||
      npg_reduced_eval(q, sample) || npg_reduced_lift(q, "b", b, (size_t)r->F))
    return failed(err, errlen, "reduced frame", npg_reduced_error(q));
  return 0;
}

int reduced_frame_given(Reduced *r, const double *g, const double *e, const double *v, long sample, double *b,
                        char *err, size_t errlen) {
  NpgReduced *q = r->given;
  if (npg_reduced_set(q, "g", (size_t)(3 * r->V), g) || npg_reduced_set(q, "e", (size_t)r->F, e) ||
      npg_reduced_set(q, "v", (size_t)(r->F * r->F), v) || npg_reduced_eval(q, sample) ||
      npg_reduced_lift(q, "b", b, (size_t)r->F))
    return failed(err, errlen, "reduced frame (visibility given)", npg_reduced_error(q));
  return 0;
}

int reduced_project_b(const Reduced *r, const double *b, double *out) {
  int c = npg_model_class_of(r->model, "b");
  NpgClassInfo ci;
  if (c < 0 || npg_model_class(r->model, c, &ci)) return -1;
  const double *B = npg_model_basis(r->model, c);
  long n = ci.n, m = ci.m;
  double *x = calloc((size_t)m, sizeof(double));
  if (!x) return -1;
  for (long i = 0; i < n; i++)
    for (long j = 0; j < m; j++) x[j] += B[i * m + j] * b[i];
  for (long i = 0; i < n; i++) {
    double sum = 0;
    for (long j = 0; j < m; j++) sum += B[i * m + j] * x[j];
    out[i] = sum;
  }
  free(x);
  return 0;
}

void reduced_close(Reduced *r) {
  npg_reduced_free(r->learned);
  npg_reduced_free(r->given);
  npg_model_free(r->model);
  npg_full_free(r->full);
  vis_free(r->vis);
  npg_free(r->prog);
  free(r->g);
  memset(r, 0, sizeof *r);
}
