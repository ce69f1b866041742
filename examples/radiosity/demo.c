/* demo.c — the reduced half of npg-radiosity (commands.h): train, run, demo.
 *
 *   train  the design's samples (design.h) streamed into an NpgTrainer with the visibility
 *          extern ray-cast by callback; DIR/MODEL and DIR/train.json
 *   run    both animations through a model: parameters -> g -> ĝ -> reduced chain -> b̂ -> b,
 *          timed per frame on one core, lifting included, beside the full frame
 *   demo   all of it in one run, the full frames beside the reduced ones (frames not in
 *          training), Arvo's error split and the a-posteriori bounds (arvo.h), pictures,
 *          plots, arrays and DIR/report.json
 *
 * Only npg.h of libnpg is used (through reduced.c). */
#include <cblas.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "animation.h"
#include "arvo.h"
#include "commands.h"
#include "design.h"
#include "frame.h"
#include "output.h"
#include "plot.h"
#include "radiosity.h"
#include "reduced.h"
#include "render.h"
#include "scene.h"

static int fail(const char *err) {
  fprintf(stderr, "npg-radiosity: %s\n", err);
  return 1;
}

/* ---------------------------------------------------------------- the model's figures */

/* What npg_trainer_finish spent besides its four timed phases: writing MODEL/. */
static double model_files(const TrainTimes *t) {
  return fmax(0, t->finish - t->snapshots - t->pca - t->premultiply - t->externs);
}

static void json_model(FILE *js, const ReducedRadiosity *r, int samples, double structured_weight, const TrainTimes *t) {
  size_t tensor_bytes = 0, bytes = npg_model_bytes(r->model, &tensor_bytes);
  fprintf(js, "  \"training_samples\": %d,\n  \"structured_weight\": %.17g,\n", samples,
          design_structured_weight(samples, structured_weight));
  fprintf(js, "  \"model_bytes\": %zu,\n  \"model_tensor_bytes\": %zu,\n", bytes, tensor_bytes);
  fprintf(js, "  \"basis_sizes\": {");
  for (int c = 0; c < npg_model_nclasses(r->model); c++) {
    NpgClassInfo ci;
    npg_model_class(r->model, c, &ci);
    fprintf(js, "%s\"%s\": {\"m\": %ld, \"n\": %ld}", c ? ", " : "", ci.label, ci.m, ci.n);
  }
  fprintf(js, "},\n");
  if (t)
    fprintf(js,
            "  \"precomputation_seconds\": {\"samples_incl_ray_casting\": %.4g, \"ray_casting\": %.4g, "
            "\"snapshots\": %.4g, \"pca\": %.4g, \"premultiplication\": %.4g, \"learned_visibility\": %.4g, "
            "\"finish\": %.4g, \"model_files\": %.4g, \"total\": %.4g, \"note\": \"total = samples_incl_ray_casting + "
            "finish; finish = npg_trainer_finish = snapshots + pca + premultiplication + learned_visibility (the "
            "library's phase times, npg_model_train_seconds) + model_files\"},\n",
            t->samples, t->rays, t->snapshots, t->pca, t->premultiply, t->externs, t->finish, model_files(t), t->total);
}

static void print_train(const TrainTimes *t, int samples) {
  printf("precomputation %.2f s: %d samples %.2f s (ray casting %.2f s); training %.2f s: snapshots %.2f s, PCA %.2f s, "
         "pre-multiplication %.2f s, learned visibility %.2f s, model files %.2f s\n",
         t->total, samples, t->samples, t->rays, t->finish, t->snapshots, t->pca, t->premultiply, t->externs,
         model_files(t));
}

static int train(const Options *o, Scene *s, ReducedRadiosity *r, TrainTimes *t, char *model_dir) {
  char err[2048];
  if (reduced_open(r, s, o->program, o->k, o->threads, err, sizeof err)) return fail(err);
  if (o->samples < DESIGN_STRUCTURED)
    fprintf(stderr, "npg-radiosity: warning: %d samples keep only part of the design's %d structured points\n",
            o->samples, DESIGN_STRUCTURED);
  printf("training: %ld faces, %ld vertices, %d samples (%d structured of weight %.4g, %d interior), cap %d, energy %g\n",
         s->F, s->V, o->samples, o->samples < DESIGN_STRUCTURED ? o->samples : DESIGN_STRUCTURED,
         design_structured_weight(o->samples, o->structured_weight),
         o->samples > DESIGN_STRUCTURED ? o->samples - DESIGN_STRUCTURED : 0, o->cap, o->energy);
  for (int i = 0; i < o->nbasis; i++) {
    const char *sep = "";
    printf("  --basis %s:", o->basis_name[i]);
    if (o->basis_cap[i] > 0) printf("cap=%d", o->basis_cap[i]), sep = ",";
    if (o->basis_energy[i] > 0) printf("%senergy=%g", sep, o->basis_energy[i]), sep = ",";
    if (o->basis_center[i] >= 0) printf("%scenter=%s", sep, o->basis_center[i] ? "on" : "off");
    printf("\n");
  }
  fflush(stdout);
  if (reduced_train(r, s, o, model_dir, t, err, sizeof err))
    return fail(err);
  npg_model_report(r->model, stdout);
  print_train(t, o->samples);
  SceneParams nominal;
  scene_param_nominal(&nominal);
  scene_place(s, &nominal, NULL);
  return 0;
}

int cmd_train(const Options *o) {
  if (!o->out) return fail("train: --out DIR is required");
  char err[1024], path[4096];
  Scene s;
  if (scene_new(o->faces, NULL, &s, err, sizeof err)) return fail(err);
  ReducedRadiosity r;
  memset(&r, 0, sizeof r);
  TrainTimes t;
  int rc = 1;
  snprintf(path, sizeof path, "%s/MODEL", o->out);
  if (report_make_dir("npg-radiosity", o->out) || train(o, &s, &r, &t, path)) goto done;
  snprintf(path, sizeof path, "%s/train.json", o->out);
  FILE *js = fopen(path, "w");
  if (!js) goto done;
  fprintf(js, "{\n  \"faces\": %ld,\n  \"vertices\": %ld,\n", s.F, s.V);
  json_model(js, &r, o->samples, o->structured_weight, &t);
  fprintf(js, "  \"model\": \"MODEL\"\n}\n");
  rc = fclose(js) != 0;
  printf("wrote %s/MODEL and %s\n", o->out, path);
done:
  reduced_close(&r);
  scene_free(&s);
  return rc;
}

/* ---------------------------------------------------------------- the reduced frame, timed */

/* The reduced frame of p, `reps` times on one OpenBLAS thread; the median seconds. */
static int timed_frame(ReducedRadiosity *r, const Scene *s, const SceneParams *p, long sample, int reps, double *b,
                       double *seconds, char *err, size_t errlen) {
  double t[reps];
  int threads = openblas_get_num_threads();
  openblas_set_num_threads(1);
  int rc = 0;
  for (int i = 0; i < reps && !rc; i++) {
    double t0 = frame_now();
    rc = reduced_frame(r, s, p, sample, b, err, errlen);
    t[i] = frame_now() - t0;
  }
  openblas_set_num_threads(threads);
  *seconds = rc ? NAN : out_median(t, reps);
  return rc;
}

/* Where the reduced frame's time goes, on the nominal parameters (one thread): projecting
 * g and e, the chain, lifting b. Seconds per call, medians of `reps`. */
static void frame_split(ReducedRadiosity *r, const Scene *s, int reps, double split[3]) {
  SceneParams p;
  scene_param_nominal(&p);
  double *g = malloc(sizeof(double) * 3 * (size_t)s->V), *e = malloc(sizeof(double) * (size_t)s->F),
         *b = malloc(sizeof(double) * (size_t)s->F);
  double *t = malloc(sizeof(double) * 3 * (size_t)reps);
  scene_place((Scene *)s, &p, g);
  scene_emission(s, &p, e);
  int threads = openblas_get_num_threads();
  openblas_set_num_threads(1);
  for (int i = 0; i < reps; i++) {
    double t0 = frame_now();
    npg_reduced_set(r->learned, "g", (size_t)(3 * s->V), g);
    npg_reduced_set(r->learned, "e", (size_t)s->F, e);
    double t1 = frame_now();
    npg_reduced_eval(r->learned, i);
    double t2 = frame_now();
    npg_reduced_lift(r->learned, "b", b, (size_t)s->F);
    double t3 = frame_now();
    t[i] = t1 - t0, t[reps + i] = t2 - t1, t[2 * reps + i] = t3 - t2;
  }
  openblas_set_num_threads(threads);
  for (int q = 0; q < 3; q++) split[q] = out_median(t + q * reps, reps);
  free(g), free(e), free(b), free(t);
}

int cmd_run(const Options *o) {
  if (!o->model) return fail("run: --model MODEL (the folder train or demo wrote: OUT/MODEL) is required");
  char err[2048], path[4096];
  Scene s;
  if (scene_new(o->faces, NULL, &s, err, sizeof err)) return fail(err);
  ReducedRadiosity r;
  memset(&r, 0, sizeof r);
  FullRadiosity fr;
  memset(&fr, 0, sizeof fr);
  int rc = 1, K = o->frames, n = ANIM_COUNT * K;
  double *b = malloc(sizeof(double) * (size_t)s.F), *sec = malloc(sizeof(double) * 5 * (size_t)n);
  double *full = sec + n, *vis = sec + 2 * n, *ff = sec + 3 * n, *sol = sec + 4 * n;
  if (reduced_open(&r, &s, o->program, o->k, 1, err, sizeof err) || reduced_load(&r, o->model, err, sizeof err) ||
      frame_new(&fr, &s, o->k, o->threads, VIS_STREAM, SOLVER_GMRES, err, sizeof err)) {
    fail(err);
    goto done;
  }
  /* every frame full (what a user runs without npg) and reduced, in this one process */
  for (int a = 0; a < ANIM_COUNT; a++)
    for (int k = 0; k < K; k++) {
      int i = a * K + k;
      SceneParams p;
      animation_params(a, (double)k / (K - 1), &p);
      if (timed_frame(&r, &s, &p, k, o->reps, b, &sec[i], err, sizeof err) || frame_compute(&fr, &p, err, sizeof err)) {
        fail(err);
        goto done;
      }
      vis[i] = fr.t_vis, ff[i] = fr.t_ff, sol[i] = fr.t_solve, full[i] = fr.t_vis + fr.t_ff + fr.t_solve;
      if (o->out) {
        snprintf(path, sizeof path, "%s/%s/frame_%04d", o->out, animation_name(a), k);
        long sb[1] = {s.F};
        if (report_make_dir("npg-radiosity", path) || out_npy(path, "b_reduced", 1, sb, b)) goto done;
      }
    }
  double split[3];
  frame_split(&r, &s, o->reps * 10, split);
  double med = out_median(sec, n), medf = out_median(full, n);
  printf("reduced frame (%ld faces, one core, lifting included): median %.1f us over %d frames = %.0f frames per "
         "second; nominal: projection %.1f us, chain %.1f us, lift %.1f us\n",
         s.F, 1e6 * med, n, 1 / med, 1e6 * split[0], 1e6 * split[1], 1e6 * split[2]);
  printf("full frame (%d threads): median %.4f s (visibility %.4f, form factors %.4f, solve %.4f); speedup %.0fx\n",
         o->threads, medf, out_median(vis, n), out_median(ff, n), out_median(sol, n), medf / med);
  rc = 0;
done:
  free(b), free(sec);
  frame_free(&fr);
  reduced_close(&r);
  scene_free(&s);
  return rc;
}

/* ---------------------------------------------------------------- demo */

enum { NSERIES = 15 }; /* per-frame series of the demo, below */
typedef enum Series {
  S_TOTAL, S_INDIRECT, S_BOUNDARY, S_DISCRETIZATION, S_COMPUTATION, S_ERR_INF, S_RES_INF, S_RHOF, S_BOUND_ARVO,
  S_BOUND_NEUMANN, S_FULL_VIS, S_FULL_FF, S_FULL_SOLVE, S_FULL_TOTAL, S_REDUCED,
} Series;
static const char *series_name[NSERIES] = {
    "relative_l2", "relative_l2_indirect", "boundary", "discretization", "computation", "linf_error",
    "residual_linf", "rho_f_linf", "bound_arvo", "bound_neumann", "full_visibility_seconds",
    "full_form_factor_seconds", "full_solve_seconds", "full_seconds", "reduced_seconds"};

/* Full | reduced | error map for one frame, to `path`. */
static int compare_png(const Scene *s, const double *b, const double *bt, double exposure, int ss, double err_l2,
                       const char *path) {
  char l2[128];
  snprintf(l2, sizeof l2, "|full - reduced| (white: 10%% of bright walls), rel. L2 %.2f%%", 100 * err_l2);
  const char *const labels[3] = {"full (ray-cast visibility)", "reduced (learned visibility)", l2};
  return out_render_compare(s, b, bt, exposure, ss, labels, "|b full - b reduced|", path) ? 1 : 0;
}

static int plot(const char *dir, const char *file, const char *title, const char *ylabel, const PlotSeries *ps,
                int n) {
  char path[4096], err[512];
  snprintf(path, sizeof path, "%s/%s", dir, file);
  return plot_series(path, title, ylabel, ps, n, 0, 0, err, sizeof err) ? fail(err) : 0;
}

/* The median of the finite values of x. */
static double finite_median(const double *x, int n) {
  double y[n > 0 ? n : 1];
  int m = 0;
  for (int i = 0; i < n; i++)
    if (isfinite(x[i])) y[m++] = x[i];
  return out_median(y, m);
}

static int chosen(int k, int K) { return k == 0 || k == K / 2 || k == K - 1; }

/* The state of a demo run; its per-frame series are NSERIES rows of ANIM_COUNT x K values. */
typedef struct DemoRun {
  const Options *o;
  Scene s;
  ReducedRadiosity r;
  FullRadiosity fr;
  TrainTimes tt;
  int K, n;                   /* frames per animation; frames in all */
  double *ser, *bt, *bv, *pb; /* the series; b reduced, reduced given v, projected (F each) */
  int in_training, bound_fail, failures;
  double exposure, split[3];
  char err[2048];
} DemoRun;

/* Series q at frame i (i = animation * K + frame). */
static double *ser(const DemoRun *d, int q, int i) { return d->ser + (size_t)q * (size_t)d->n + (size_t)i; }

/* One frame of animation a, full and reduced: the error split and the bounds into the series,
 * the arrays, the picture, a line. A frame the reduced model cannot evaluate (an error from
 * npg) is reported and counted, not fatal: its errors are NaN (null in report.json).
 * 1 on a failure that stops the demo. */
static int demo_frame(DemoRun *d, int a, int k) {
  const Options *o = d->o;
  const Scene *s = &d->s;
  FullRadiosity *fr = &d->fr;
  long F = s->F;
  int i = a * d->K + k;
  SceneParams p;
  animation_params(a, (double)k / (d->K - 1), &p);
  d->in_training += design_contains(o->samples, &p);
  if (frame_compute(fr, &p, d->err, sizeof d->err)) return fail(d->err);
  ArvoSplit as;
  if (timed_frame(&d->r, s, &p, i, o->reps, d->bt, ser(d, S_REDUCED, i), d->err, sizeof d->err) ||
      reduced_frame_given(&d->r, s->g, s->e, fr->v, i, d->bv, d->err, sizeof d->err) ||
      reduced_project_b(&d->r, fr->b, d->pb) < 0 ||
      arvo_split(F, s->rho, fr->p, s->e, fr->b, d->bt, d->bv, d->pb, &as, d->err, sizeof d->err)) {
    fprintf(stderr, "npg-radiosity: %s frame %d: %s\n", animation_name(a), k, d->err);
    npg_reduced_clear_error(d->r.learned), npg_reduced_clear_error(d->r.given);
    for (int q = 0; q < NSERIES; q++) *ser(d, q, i) = NAN;
    *ser(d, S_FULL_VIS, i) = fr->t_vis, *ser(d, S_FULL_FF, i) = fr->t_ff, *ser(d, S_FULL_SOLVE, i) = fr->t_solve;
    *ser(d, S_FULL_TOTAL, i) = fr->t_vis + fr->t_ff + fr->t_solve;
    d->failures++;
    return 0;
  }
  double vals[NSERIES] = {as.total, as.total_indirect, as.boundary, as.discretization, as.computation,
                          as.err_inf, as.residual_inf, as.rho_f_inf, as.bound_arvo, as.bound_neumann,
                          fr->t_vis, fr->t_ff, fr->t_solve, fr->t_vis + fr->t_ff + fr->t_solve, *ser(d, S_REDUCED, i)};
  for (int q = 0; q < NSERIES; q++) *ser(d, q, i) = vals[q];
  /* a bound that fails is a bug: b is GMRES's to 1e-13, so allow that much slack */
  double slack = 1e-9 * fabs(as.err_inf) + 1e-12;
  if ((!isnan(as.bound_arvo) && as.err_inf > as.bound_arvo + slack) ||
      (!isnan(as.bound_neumann) && as.err_inf > as.bound_neumann + slack)) {
    fprintf(stderr, "npg-radiosity: %s frame %d: the bound fails: error %.3e, Arvo %.3e, Neumann %.3e\n",
            animation_name(a), k, as.err_inf, as.bound_arvo, as.bound_neumann);
    d->bound_fail++;
  }
  char dir[4096], path[4096];
  snprintf(dir, sizeof dir, "%s/%s/frame_%04d", o->out, animation_name(a), k);
  long sg[2] = {s->V, 3}, sv[2] = {F, F}, sb[1] = {F};
  if (report_make_dir("npg-radiosity", dir) || out_npy(dir, "g", 2, sg, s->g) || out_npy(dir, "v", 2, sv, fr->v) ||
      out_npy(dir, "b_full", 1, sb, fr->b) || out_npy(dir, "b_reduced", 1, sb, d->bt) ||
      out_npy(dir, "b_reduced_given_v", 1, sb, d->bv) || out_npy(dir, "e", 1, sb, s->e))
    return 1;
  snprintf(path, sizeof path, "%s/%s/frame_%04d.png", o->out, animation_name(a), k);
  if (out_render_frame(s, d->bt, d->exposure, o->ss, "radiosity b (reduced)", path, NULL)) return 1;
  if (chosen(k, d->K)) {
    snprintf(path, sizeof path, "%s/%s_compare_%04d.png", o->out, animation_name(a), k);
    if (compare_png(s, fr->b, d->bt, d->exposure, o->ss, as.total, path)) return 1;
  }
  /* Arvo's bound ||r|| / (1 - ||rhoF||) exists only where ||rhoF|| < 1 */
  char arvo[64];
  if (isnan(as.bound_arvo))
    snprintf(arvo, sizeof arvo, "no Arvo bound: ||rhoF|| %.3f >= 1", as.rho_f_inf);
  else
    snprintf(arvo, sizeof arvo, "Arvo %.3g, ||rhoF|| %.3f", as.bound_arvo, as.rho_f_inf);
  printf("%s frame %2d: error %.2f%% (indirect %.2f%%; boundary %.2f%%, discretization %.2f%%, computation "
         "%.2f%%), Linf %.3g <= bound %.3g (%s); full %.3f s, reduced %.1f us\n",
         animation_name(a), k, 100 * as.total, 100 * as.total_indirect, 100 * as.boundary, 100 * as.discretization,
         100 * as.computation, as.err_inf, as.bound_neumann, arvo, *ser(d, S_FULL_TOTAL, i),
         1e6 * *ser(d, S_REDUCED, i));
  fflush(stdout);
  return 0;
}

/* 2. Both animations, full and reduced, frame by frame; the reduced frame's split. */
static int run_frames(DemoRun *d) {
  if (frame_new(&d->fr, &d->s, d->o->k, d->o->threads, VIS_STREAM, SOLVER_GMRES, d->err, sizeof d->err) ||
      frame_compute(&d->fr, NULL, d->err, sizeof d->err))
    return fail(d->err);
  d->exposure = render_exposure(d->s.F, d->fr.b, d->s.rho);
  for (int a = 0; a < ANIM_COUNT; a++)
    for (int k = 0; k < d->K; k++)
      if (demo_frame(d, a, k)) return 1;
  frame_split(&d->r, &d->s, d->o->reps * 10, d->split);
  if (d->in_training) fprintf(stderr, "npg-radiosity: warning: %d frames are training samples\n", d->in_training);
  return 0;
}

/* 3. Plots: paper Fig. 8 (the error of both animations), Arvo's split and the bounds. */
static int plot_demo(const DemoRun *d) {
  const Options *o = d->o;
  int K = d->K;
  char title[256], file[64];
  PlotSeries fig8[2] = {{"window", ser(d, S_TOTAL, 0), K}, {"ceiling", ser(d, S_TOTAL, K), K}};
  snprintf(title, sizeof title, "reduced vs full radiosity, %ld faces, %d training samples", d->s.F, o->samples);
  if (plot(o->out, "error.png", title, "relative L2 error of b", fig8, 2)) return 1;
  for (int a = 0; a < ANIM_COUNT; a++) {
    const char *an = animation_name(a);
    PlotSeries sp[4] = {{"total", ser(d, S_TOTAL, a * K), K},
                        {"boundary data (learned visibility)", ser(d, S_BOUNDARY, a * K), K},
                        {"discretization (projection floor)", ser(d, S_DISCRETIZATION, a * K), K},
                        {"computation (reduction)", ser(d, S_COMPUTATION, a * K), K}};
    snprintf(title, sizeof title, "error split (Arvo), %s animation", an);
    snprintf(file, sizeof file, "%s_arvo.png", an);
    if (plot(o->out, file, title, "relative L2 of b", sp, 4)) return 1;
    PlotSeries bp[3] = {{"true max error", ser(d, S_ERR_INF, a * K), K},
                        {"bound ||r|| ||(I-rhoF)^-1 1||", ser(d, S_BOUND_NEUMANN, a * K), K},
                        {"Arvo's bound ||r|| / (1 - ||rhoF||): none where ||rhoF|| >= 1", ser(d, S_BOUND_ARVO, a * K), K}};
    snprintf(title, sizeof title, "a-posteriori bounds, %s animation", an);
    snprintf(file, sizeof file, "%s_bound.png", an);
    if (plot(o->out, file, title, "max-norm error of b", bp, 3)) return 1;
  }
  return 0;
}

/* The medians and the worst error of a run, for report.json and the summary. */
typedef struct DemoFigures {
  double full, full_vis, full_ff, full_solve, reduced, err_median, err_max;
} DemoFigures;

static DemoFigures demo_figures(const DemoRun *d) {
  int n = d->n;
  DemoFigures f = {out_median(ser(d, S_FULL_TOTAL, 0), n), out_median(ser(d, S_FULL_VIS, 0), n),
                   out_median(ser(d, S_FULL_FF, 0), n),    out_median(ser(d, S_FULL_SOLVE, 0), n),
                   finite_median(ser(d, S_REDUCED, 0), n), finite_median(ser(d, S_TOTAL, 0), n), 0};
  for (int i = 0; i < n; i++) f.err_max = fmax(f.err_max, *ser(d, S_TOTAL, i)); /* fmax skips NaN */
  return f;
}

/* 4. DIR/report.json. */
static int write_demo_report(const DemoRun *d, const DemoFigures *f) {
  const Options *o = d->o;
  int K = d->K;
  Report rep;
  if (report_open(&rep, "npg-radiosity", o->out) != 0) return 1;
  FILE *js = rep.f;
  fprintf(js, "{\n  \"faces\": %ld,\n  \"vertices\": %ld,\n  \"threads_full\": %d,\n  \"threads_reduced\": 1,\n",
          d->s.F, d->s.V, o->threads);
  fprintf(js, "  \"visibility_points_per_face\": %d,\n  \"frames_per_animation\": %d,\n", o->k, K);
  fprintf(js, "  \"animations\": [\"%s\", \"%s\"],\n  \"test_frames_in_training\": %d,\n", animation_name(0),
          animation_name(1), d->in_training);
  json_model(js, &d->r, o->samples, o->structured_weight, &d->tt);
  fprintf(js, "  \"full_frame_seconds\": {\"visibility\": %.6g, \"form_factors\": %.6g, \"solve\": %.6g, "
              "\"total\": %.6g, \"statistic\": \"median over the frames\"},\n",
          f->full_vis, f->full_ff, f->full_solve, f->full);
  fprintf(js, "  \"reduced_frame_seconds\": %.6g,\n  \"reduced_frames_per_second\": %.1f,\n", f->reduced,
          1 / f->reduced);
  fprintf(js, "  \"reduced_frame_split_seconds\": {\"project_g_e\": %.4g, \"chain\": %.4g, \"lift_b\": %.4g},\n",
          d->split[0], d->split[1], d->split[2]);
  fprintf(js, "  \"speedup\": %.1f,\n", f->full / f->reduced);
  fprintf(js, "  \"error\": {\"median\": %.6g, \"max\": %.6g, \"median_indirect\": %.6g, \"measure\": \"relative L2 "
              "of b over both animations\"},\n",
          f->err_median, f->err_max, finite_median(ser(d, S_INDIRECT, 0), d->n));
  fprintf(js, "  \"bound_holds_every_frame\": %s,\n  \"reduced_frames_failed\": %d,\n",
          d->bound_fail ? "false" : "true", d->failures);
  fprintf(js, "  \"per_frame\": {\n");
  for (int a = 0; a < ANIM_COUNT; a++) {
    fprintf(js, "    \"%s\": {", animation_name(a));
    for (int q = 0; q < NSERIES; q++)
      report_json_array(js, "", series_name[q], ser(d, q, a * K), K, 6, q + 1 < NSERIES ? ", " : "");
    fprintf(js, "}%s\n", a + 1 < ANIM_COUNT ? "," : "");
  }
  fprintf(js, "  }\n}\n");
  return report_commit(&rep, "npg-radiosity") != 0;
}

static void print_summary(const DemoRun *d, const DemoFigures *f) {
  printf("error over %d frames: median %.2f%%, max %.2f%% (relative L2 of b); bound %s on every frame\n",
         d->n - d->failures, 100 * f->err_median, 100 * f->err_max, d->bound_fail ? "FAILS" : "holds");
  if (d->failures) printf("%d frames failed in reduced space (above)\n", d->failures);
  printf("full frame %.4f s (median; visibility %.4f, form factors %.4f, solve %.4f); reduced frame %.1f us (%.0f "
         "frames/s, one core; nominal: projection %.1f us, chain %.1f us, lift %.1f us); speedup %.0fx\n",
         f->full, f->full_vis, f->full_ff, f->full_solve, 1e6 * f->reduced, 1 / f->reduced, 1e6 * d->split[0],
         1e6 * d->split[1], 1e6 * d->split[2], f->full / f->reduced);
  printf("wrote %s\n", d->o->out);
}

int cmd_demo(const Options *o) {
  if (!o->out) return fail("demo: --out DIR is required");
  DemoRun d = {.o = o, .K = o->frames, .n = ANIM_COUNT * o->frames, .exposure = 1, .split = {NAN, NAN, NAN}};
  if (scene_new(o->faces, NULL, &d.s, d.err, sizeof d.err)) return fail(d.err);
  long F = d.s.F;
  int rc = 1;
  d.ser = calloc((size_t)NSERIES * (size_t)d.n, sizeof(double));
  d.bt = malloc(sizeof(double) * (size_t)F), d.bv = malloc(sizeof(double) * (size_t)F);
  d.pb = malloc(sizeof(double) * (size_t)F);
  if (!d.ser || !d.bt || !d.bv || !d.pb) {
    fail("out of memory");
    goto done;
  }
  /* 1. the scene and the model */
  char model_dir[4096];
  snprintf(model_dir, sizeof model_dir, "%s/MODEL", o->out);
  if (report_make_dir("npg-radiosity", o->out) || out_scene_arrays(o->out, &d.s) ||
      train(o, &d.s, &d.r, &d.tt, model_dir))
    goto done;
  if (run_frames(&d) || plot_demo(&d)) goto done;
  DemoFigures f = demo_figures(&d);
  if (write_demo_report(&d, &f)) goto done;
  print_summary(&d, &f);
  rc = d.bound_fail || d.failures ? 1 : 0;
done:
  free(d.ser), free(d.bt), free(d.bv), free(d.pb);
  frame_free(&d.fr);
  reduced_close(&d.r);
  scene_free(&d.s);
  return rc;
}
