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

static void json_model(FILE *js, const ReducedRadiosity *r, int samples, const TrainTimes *t) {
  size_t tensor_bytes = 0, bytes = npg_model_bytes(r->model, &tensor_bytes);
  fprintf(js, "  \"training_samples\": %d,\n  \"model_bytes\": %zu,\n  \"model_tensor_bytes\": %zu,\n", samples, bytes,
          tensor_bytes);
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
  printf("training: %ld faces, %ld vertices, %d samples (%d structured, %d interior), cap %d, energy %g\n", s->F,
         s->V, o->samples, o->samples < DESIGN_STRUCTURED ? o->samples : DESIGN_STRUCTURED,
         o->samples > DESIGN_STRUCTURED ? o->samples - DESIGN_STRUCTURED : 0, o->cap, o->energy);
  fflush(stdout);
  if (reduced_train(r, s, o->samples, o->cap, o->energy, (size_t)o->mem_mb << 20, model_dir, t, err, sizeof err))
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
  json_model(js, &r, o->samples, &t);
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
  Camera cam;
  render_camera_default(&cam);
  cam.ss = ss;
  View view;
  Image im[3] = {{0}};
  char err[512];
  if (render_view(&cam, s->V, s->F, s->g, s->tri, &view, err, sizeof err)) return fail(err);
  double scale = 0.1 * -log(0.4) / exposure; /* 10 % of the bright walls' radiosity */
  render_shade(&view, s->V, s->F, s->tri, s->g, b, exposure, &im[0]);
  render_shade(&view, s->V, s->F, s->tri, s->g, bt, exposure, &im[1]);
  render_error(&view, s->F, b, bt, scale, &im[2]);
  render_view_free(&view);
  for (int q = 0; q < 2; q++) render_add_colorbar(&im[q], SCALE_SHADE, exposure, "radiosity b");
  render_add_colorbar(&im[2], SCALE_ERROR, scale, "|b full - b reduced|");
  char l2[128];
  snprintf(l2, sizeof l2, "|full - reduced| (white: 10%% of bright walls), rel. L2 %.2f%%", 100 * err_l2);
  const Image *ims[3] = {&im[0], &im[1], &im[2]};
  const char *labels[3] = {"full (ray-cast visibility)", "reduced (learned visibility)", l2};
  int rc = render_side_by_side(path, ims, labels, 3, err, sizeof err);
  for (int q = 0; q < 3; q++) image_free(&im[q]);
  return rc ? fail(err) : 0;
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

int cmd_demo(const Options *o) {
  if (!o->out) return fail("demo: --out DIR is required");
  char err[2048], path[4096], model_dir[4096];
  Scene s;
  if (scene_new(o->faces, NULL, &s, err, sizeof err)) return fail(err);
  long F = s.F;
  int K = o->frames, n = ANIM_COUNT * K, rc = 1;
  ReducedRadiosity r;
  memset(&r, 0, sizeof r);
  FullRadiosity fr;
  memset(&fr, 0, sizeof fr);
  TrainTimes tt;
  double *ser = calloc((size_t)NSERIES * (size_t)n, sizeof(double));
  double *bt = malloc(sizeof(double) * (size_t)F), *bv = malloc(sizeof(double) * (size_t)F),
         *pb = malloc(sizeof(double) * (size_t)F);
  int in_training = 0, bound_fail = 0, failures = 0;
  double exposure = 1, split[3] = {NAN, NAN, NAN};
  if (!ser || !bt || !bv || !pb) {
    fail("out of memory");
    goto done;
  }
#define SER(q, i) ser[(size_t)(q) * (size_t)n + (size_t)(i)]

  /* 1. the scene and the model */
  snprintf(model_dir, sizeof model_dir, "%s/MODEL", o->out);
  if (report_make_dir("npg-radiosity", o->out) || out_scene_arrays(o->out, &s) || train(o, &s, &r, &tt, model_dir)) goto done;

  /* 2. both animations, full and reduced */
  if (frame_new(&fr, &s, o->k, o->threads, VIS_STREAM, SOLVER_GMRES, err, sizeof err) ||
      frame_compute(&fr, NULL, err, sizeof err)) {
    fail(err);
    goto done;
  }
  exposure = render_exposure(F, fr.b, s.rho);
  for (int a = 0; a < ANIM_COUNT; a++) {
    for (int k = 0; k < K; k++) {
      int i = a * K + k;
      SceneParams p;
      animation_params(a, (double)k / (K - 1), &p);
      in_training += design_contains(o->samples, &p);
      if (frame_compute(&fr, &p, err, sizeof err)) {
        fail(err);
        goto done;
      }
      /* a frame the reduced model cannot evaluate (an error from npg) is reported and
       * counted, not fatal: its errors are NaN (null in report.json) */
      ArvoSplit as;
      if (timed_frame(&r, &s, &p, i, o->reps, bt, &SER(S_REDUCED, i), err, sizeof err) ||
          reduced_frame_given(&r, s.g, s.e, fr.v, i, bv, err, sizeof err) || reduced_project_b(&r, fr.b, pb) < 0 ||
          arvo_split(F, s.rho, fr.p, s.e, fr.b, bt, bv, pb, &as, err, sizeof err)) {
        fprintf(stderr, "npg-radiosity: %s frame %d: %s\n", animation_name(a), k, err);
        npg_reduced_clear_error(r.learned), npg_reduced_clear_error(r.given);
        for (int q = 0; q < NSERIES; q++) SER(q, i) = NAN;
        SER(S_FULL_VIS, i) = fr.t_vis, SER(S_FULL_FF, i) = fr.t_ff, SER(S_FULL_SOLVE, i) = fr.t_solve;
        SER(S_FULL_TOTAL, i) = fr.t_vis + fr.t_ff + fr.t_solve;
        failures++;
        continue;
      }
      double vals[NSERIES] = {as.total, as.total_indirect, as.boundary, as.discretization, as.computation,
                              as.err_inf, as.residual_inf, as.rho_f_inf, as.bound_arvo, as.bound_neumann,
                              fr.t_vis, fr.t_ff, fr.t_solve, fr.t_vis + fr.t_ff + fr.t_solve, SER(S_REDUCED, i)};
      for (int q = 0; q < NSERIES; q++) SER(q, i) = vals[q];
      /* a bound that fails is a bug: b is GMRES's to 1e-13, so allow that much slack */
      double slack = 1e-9 * fabs(as.err_inf) + 1e-12;
      if ((!isnan(as.bound_arvo) && as.err_inf > as.bound_arvo + slack) ||
          (!isnan(as.bound_neumann) && as.err_inf > as.bound_neumann + slack)) {
        fprintf(stderr, "npg-radiosity: %s frame %d: the bound fails: error %.3e, Arvo %.3e, Neumann %.3e\n",
                animation_name(a), k, as.err_inf, as.bound_arvo, as.bound_neumann);
        bound_fail++;
      }
      char dir[4096];
      snprintf(dir, sizeof dir, "%s/%s/frame_%04d", o->out, animation_name(a), k);
      long sg[2] = {s.V, 3}, sv[2] = {F, F}, sb[1] = {F};
      if (report_make_dir("npg-radiosity", dir) || out_npy(dir, "g", 2, sg, s.g) || out_npy(dir, "v", 2, sv, fr.v) ||
          out_npy(dir, "b_full", 1, sb, fr.b) || out_npy(dir, "b_reduced", 1, sb, bt) ||
          out_npy(dir, "b_reduced_given_v", 1, sb, bv) || out_npy(dir, "e", 1, sb, s.e))
        goto done;
      snprintf(path, sizeof path, "%s/%s/frame_%04d.png", o->out, animation_name(a), k);
      if (out_render_frame(&s, bt, exposure, o->ss, "radiosity b (reduced)", path, NULL)) goto done;
      if (chosen(k, K)) {
        snprintf(path, sizeof path, "%s/%s_compare_%04d.png", o->out, animation_name(a), k);
        if (compare_png(&s, fr.b, bt, exposure, o->ss, as.total, path)) goto done;
      }
      /* Arvo's bound ||r|| / (1 - ||rhoF||) exists only where ||rhoF|| < 1 */
      char arvo[64];
      if (isnan(as.bound_arvo))
        snprintf(arvo, sizeof arvo, "no Arvo bound: ||rhoF|| %.3f >= 1", as.rho_f_inf);
      else
        snprintf(arvo, sizeof arvo, "Arvo %.3g, ||rhoF|| %.3f", as.bound_arvo, as.rho_f_inf);
      printf("%s frame %2d: error %.2f%% (indirect %.2f%%; boundary %.2f%%, discretization %.2f%%, computation "
             "%.2f%%), Linf %.3g <= bound %.3g (%s); full %.3f s, reduced %.1f us\n",
             animation_name(a), k, 100 * as.total, 100 * as.total_indirect, 100 * as.boundary,
             100 * as.discretization, 100 * as.computation, as.err_inf, as.bound_neumann, arvo,
             SER(S_FULL_TOTAL, i), 1e6 * SER(S_REDUCED, i));
      fflush(stdout);
    }
  }
  frame_split(&r, &s, o->reps * 10, split);
  if (in_training) fprintf(stderr, "npg-radiosity: warning: %d frames are training samples\n", in_training);

  /* 3. plots (paper Fig. 8 and the split) */
  PlotSeries fig8[2] = {{"window", &SER(S_TOTAL, 0), K}, {"ceiling", &SER(S_TOTAL, K), K}};
  char title[256];
  snprintf(title, sizeof title, "reduced vs full radiosity, %ld faces, %d training samples", F, o->samples);
  if (plot(o->out, "error.png", title, "relative L2 error of b", fig8, 2)) goto done;
  for (int a = 0; a < ANIM_COUNT; a++) {
    const char *an = animation_name(a);
    PlotSeries sp[4] = {{"total", &SER(S_TOTAL, a * K), K},
                        {"boundary data (learned visibility)", &SER(S_BOUNDARY, a * K), K},
                        {"discretization (projection floor)", &SER(S_DISCRETIZATION, a * K), K},
                        {"computation (reduction)", &SER(S_COMPUTATION, a * K), K}};
    snprintf(title, sizeof title, "error split (Arvo), %s animation", an);
    snprintf(path, sizeof path, "%s_arvo.png", an);
    if (plot(o->out, path, title, "relative L2 of b", sp, 4)) goto done;
    PlotSeries bp[3] = {{"true max error", &SER(S_ERR_INF, a * K), K},
                        {"bound ||r|| ||(I-rhoF)^-1 1||", &SER(S_BOUND_NEUMANN, a * K), K},
                        {"Arvo's bound ||r|| / (1 - ||rhoF||): none where ||rhoF|| >= 1", &SER(S_BOUND_ARVO, a * K), K}};
    snprintf(title, sizeof title, "a-posteriori bounds, %s animation", an);
    snprintf(path, sizeof path, "%s_bound.png", an);
    if (plot(o->out, path, title, "max-norm error of b", bp, 3)) goto done;
  }

  /* 4. report.json */
  double med_full = out_median(&SER(S_FULL_TOTAL, 0), n), med_red = finite_median(&SER(S_REDUCED, 0), n);
  double med_err = finite_median(&SER(S_TOTAL, 0), n), max_err = 0;
  for (int i = 0; i < n; i++) max_err = fmax(max_err, SER(S_TOTAL, i)); /* fmax skips NaN */
  Report rep;
  if (report_open(&rep, "npg-radiosity", o->out) != 0) goto done;
  FILE *js = rep.f;
  fprintf(js, "{\n  \"faces\": %ld,\n  \"vertices\": %ld,\n  \"threads_full\": %d,\n  \"threads_reduced\": 1,\n", F,
          s.V, o->threads);
  fprintf(js, "  \"visibility_points_per_face\": %d,\n  \"frames_per_animation\": %d,\n", o->k, K);
  fprintf(js, "  \"animations\": [\"%s\", \"%s\"],\n  \"test_frames_in_training\": %d,\n", animation_name(0),
          animation_name(1), in_training);
  json_model(js, &r, o->samples, &tt);
  fprintf(js, "  \"full_frame_seconds\": {\"visibility\": %.6g, \"form_factors\": %.6g, \"solve\": %.6g, "
              "\"total\": %.6g, \"statistic\": \"median over the frames\"},\n",
          out_median(&SER(S_FULL_VIS, 0), n), out_median(&SER(S_FULL_FF, 0), n),
          out_median(&SER(S_FULL_SOLVE, 0), n), med_full);
  fprintf(js, "  \"reduced_frame_seconds\": %.6g,\n  \"reduced_frames_per_second\": %.1f,\n", med_red, 1 / med_red);
  fprintf(js, "  \"reduced_frame_split_seconds\": {\"project_g_e\": %.4g, \"chain\": %.4g, \"lift_b\": %.4g},\n",
          split[0], split[1], split[2]);
  fprintf(js, "  \"speedup\": %.1f,\n", med_full / med_red);
  fprintf(js, "  \"error\": {\"median\": %.6g, \"max\": %.6g, \"median_indirect\": %.6g, \"measure\": \"relative L2 "
              "of b over both animations\"},\n",
          med_err, max_err, finite_median(&SER(S_INDIRECT, 0), n));
  fprintf(js, "  \"bound_holds_every_frame\": %s,\n  \"reduced_frames_failed\": %d,\n", bound_fail ? "false" : "true",
          failures);
  fprintf(js, "  \"per_frame\": {\n");
  for (int a = 0; a < ANIM_COUNT; a++) {
    fprintf(js, "    \"%s\": {", animation_name(a));
    for (int q = 0; q < NSERIES; q++) report_json_array(js, "", series_name[q], &SER(q, a * K), K, 6, q + 1 < NSERIES ? ", " : "");
    fprintf(js, "}%s\n", a + 1 < ANIM_COUNT ? "," : "");
  }
  fprintf(js, "  }\n}\n");
  if (report_commit(&rep, "npg-radiosity") != 0) goto done;
  printf("error over %d frames: median %.2f%%, max %.2f%% (relative L2 of b); bound %s on every frame\n", n - failures,
         100 * med_err, 100 * max_err, bound_fail ? "FAILS" : "holds");
  if (failures) printf("%d frames failed in reduced space (above)\n", failures);
  printf("full frame %.4f s (median; visibility %.4f, form factors %.4f, solve %.4f); reduced frame %.1f us (%.0f "
         "frames/s, one core; nominal: projection %.1f us, chain %.1f us, lift %.1f us); speedup %.0fx\n",
         med_full, out_median(&SER(S_FULL_VIS, 0), n), out_median(&SER(S_FULL_FF, 0), n),
         out_median(&SER(S_FULL_SOLVE, 0), n), 1e6 * med_red, 1 / med_red, 1e6 * split[0], 1e6 * split[1],
         1e6 * split[2], med_full / med_red);
  printf("wrote %s\n", o->out);
  rc = bound_fail || failures ? 1 : 0;
#undef SER
done:
  free(ser), free(bt), free(bv), free(pb);
  frame_free(&fr);
  reduced_close(&r);
  scene_free(&s);
  return rc;
}
