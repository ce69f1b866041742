/* reduced.c — the reduced radiosity through npg.h (reduced.h). */
#include "reduced.h"

#include <cblas.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "design.h"
#include "frame.h"

/* The visibility extern's callback: v of the g the evaluator holds, ray-cast. */
static int visibility_extern(void *user, const NpgFull *f, long sample, double *out, size_t count) {
  ReducedRadiosity *r = user;
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

int reduced_open(ReducedRadiosity *r, const Scene *s, const char *program, int k, int threads, char *err, size_t errlen) {
  memset(r, 0, sizeof *r);
  r->V = s->V, r->F = s->F;
  r->prog = npg_compile(program, NULL);
  if (!npg_ok(r->prog)) return failed(err, errlen, program, npg_error(r->prog));
  /* training evaluates every sample restricted to each pass's rows many times over (out of core at
   * 5,000 faces): the system compiler's code evaluates 1.7x faster than libtcc's and gives the same
   * model (-ffp-contract=off); libtcc where no compiler is found: npg's default, NPG_AUTO */
  r->full = npg_full_new(r->prog, NPG_AUTO);
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

int reduced_train(ReducedRadiosity *r, Scene *s, const Options *opt, const char *model_dir, TrainTimes *t, char *err,
                  size_t errlen) {
  memset(t, 0, sizeof *t);
  int samples = opt->samples;
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = opt->cap, o.energy = opt->energy, o.progress = isatty(2); /* bars on a terminal, not in a log */
  o.words = NPG_WORDS_NPGC; /* its --cap, --basis and --mem are npgc train's: training's messages name them */
  /* g moves linearly with eight of the nine parameters (patch corners slide) and with the
   * sine and cosine of the tilt: dropping one of its few directions at 0.999 loses a
   * parameter outright, and the thin faces its areas then miss (a strip over a large
   * window) turn the root's operator diag(a) indefinite. The small classes of the geometry
   * (g, the area vectors n, the squared areas a) keep 1 - 1e-6 of their energy; the
   * user's --basis options come after, so they win. */
  enum { FIXED = 3 };
  const char *names[FIXED + RADIOSITY_MAX_BASIS] = {"g", "n", "a"};
  int caps[FIXED + RADIOSITY_MAX_BASIS] = {-1, -1, -1}, centers[FIXED + RADIOSITY_MAX_BASIS];
  double energies[FIXED + RADIOSITY_MAX_BASIS] = {1 - 1e-6, 1 - 1e-6, 1 - 1e-6};
  for (int i = 0; i < FIXED; i++) centers[i] = -1;
  for (int i = 0; i < opt->nbasis; i++)
    names[FIXED + i] = opt->basis_name[i], caps[FIXED + i] = opt->basis_cap[i], energies[FIXED + i] = opt->basis_energy[i],
    centers[FIXED + i] = opt->basis_center[i];
  o.nbasis = FIXED + opt->nbasis, o.basis_name = names, o.basis_cap = caps, o.basis_energy = energies,
  o.basis_center = centers;
  size_t mem = (size_t)opt->mem_mb << 20;
  if (mem) o.mem = mem;
  NpgTrainer *tr = npg_trainer_new(r->full, &o);
  if (!tr) return failed(err, errlen, "trainer", "out of memory");
  if (npg_trainer_error(tr)[0]) { /* the options (a --basis name) refused before any ray is cast */
    snprintf(err, errlen, "training: %s", npg_trainer_error(tr));
    npg_trainer_free(tr);
    return -1;
  }
  long sg[2] = {s->V, 3}, sf[1] = {s->F};
  double t0 = frame_now();
  r->ray_seconds = 0, r->ray_calls = 0;
  double ws = design_structured_weight(samples, opt->structured_weight);
  for (int k = 0; k < samples; k++) {
    SceneParams p;
    design_point(k, &p);
    scene_place(s, &p, NULL);
    if ((k < DESIGN_STRUCTURED && ws != 1 && npg_trainer_weight(tr, ws)) || npg_trainer_set(tr, "g", 2, sg, s->g) ||
        npg_trainer_set(tr, "e", 1, sf, s->e) || npg_trainer_add(tr)) {
      snprintf(err, errlen, "training sample %d: %s%s%s", k, npg_trainer_error(tr), r->err[0] ? ": " : "", r->err);
      npg_trainer_free(tr);
      return -1;
    }
    npg_progress(isatty(2), "samples (ray casting)", k + 1, samples);
  }
  t->samples = frame_now() - t0;
  t->rays = r->ray_seconds;
  double f0 = frame_now();
  r->model = npg_trainer_finish(tr, model_dir);
  t->finish = frame_now() - f0;
  t->total = frame_now() - t0;
  if (!r->model) {
    snprintf(err, errlen, "training: %s", npg_trainer_error(tr));
    npg_trainer_free(tr);
    return -1;
  }
  int cv = npg_model_class_of(r->model, "v");
  NpgClassInfo vi;
  r->vcoef = cv >= 0 && npg_model_class(r->model, cv, &vi) == 0 ? npg_model_coefficients(r->model, cv, &r->vS) : NULL;
  if (r->vcoef) { /* out of core: v's coordinates from the trainer's records of the training values */
    r->trainer = tr, r->vm = vi.m;
    r->dots = malloc(sizeof(double) * (size_t)r->vS);
    r->vcoords = malloc(sizeof(double) * (size_t)r->vm);
    if (!r->dots || !r->vcoords) return failed(err, errlen, "reduced evaluator", "out of memory");
  } else {
    npg_trainer_free(tr);
  }
  /* the split of npg_trainer_finish is the library's own (the trainer's "training
   * phases" line gives the same figures): snapshots, bases, pre-multiplication, and the
   * learned visibility's fit (its samples' extern values are cached: no ray is cast) */
  double phase[4];
  npg_model_train_seconds(r->model, phase, NULL);
  t->snapshots = phase[0], t->pca = phase[1], t->premultiply = phase[2], t->externs = phase[3];
  r->learned = npg_reduced_new(r->model);
  r->given = npg_reduced_new(r->model);
  if (!r->learned || !r->given) return failed(err, errlen, "reduced evaluator", "out of memory");
  npg_reduced_given_externs(r->given, true);
  return 0;
}

int reduced_load(ReducedRadiosity *r, const char *model_dir, char *err, size_t errlen) {
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

int reduced_frame(ReducedRadiosity *r, const Scene *s, const SceneParams *p, long sample, double *b, char *err,
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

/* v's coordinates into the visibility-given evaluator: projected onto its basis, or, when the model
 * keeps v as coefficients C of its training values X, Cᵀ(Xᵀv) from the trainer's records. */
static int set_given_v(ReducedRadiosity *r, const double *v, char *err, size_t errlen) {
  NpgReduced *q = r->given;
  if (!r->vcoef) {
    if (npg_reduced_set(q, "v", (size_t)(r->F * r->F), v)) return failed(err, errlen, "visibility given", npg_reduced_error(q));
    return 0;
  }
  if (!r->trainer)
    return failed(err, errlen, "visibility given",
                  "the model keeps v as coefficients of its training values: their records are the trainer's (train in "
                  "this run, or with --keep-bases v)");
  if (npg_trainer_dots(r->trainer, "v", (size_t)(r->F * r->F), v, r->dots))
    return failed(err, errlen, "visibility given", npg_trainer_error(r->trainer));
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)r->vS, (int)r->vm, 1.0, r->vcoef, (int)r->vm, r->dots, 1, 0.0, r->vcoords, 1);
  if (npg_reduced_set_coords(q, "v", (size_t)r->vm, r->vcoords))
    return failed(err, errlen, "visibility given", npg_reduced_error(q));
  return 0;
}

int reduced_frame_given(ReducedRadiosity *r, const double *g, const double *e, const double *v, long sample, double *b,
                        char *err, size_t errlen) {
  NpgReduced *q = r->given;
  if (set_given_v(r, v, err, errlen)) return -1;
  if (npg_reduced_set(q, "g", (size_t)(3 * r->V), g) || npg_reduced_set(q, "e", (size_t)r->F, e) ||
      npg_reduced_eval(q, sample) || npg_reduced_lift(q, "b", b, (size_t)r->F))
    return failed(err, errlen, "reduced frame (visibility given)", npg_reduced_error(q));
  return 0;
}

int reduced_project_b(const ReducedRadiosity *r, const double *b, double *out) {
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

void reduced_close(ReducedRadiosity *r) {
  npg_trainer_free(r->trainer);
  free(r->dots);
  free(r->vcoords);
  npg_reduced_free(r->learned);
  npg_reduced_free(r->given);
  npg_model_free(r->model);
  npg_full_free(r->full);
  vis_free(r->vis);
  npg_free(r->prog);
  free(r->g);
  memset(r, 0, sizeof *r);
}
