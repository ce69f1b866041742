/* npg-radiosity — the radiosity application of paper §8–§9 on a parametric two-room scene.
 *
 *   npg-radiosity scene [--faces N] [--checks S] [--out DIR]
 *       build the scene, check every triangle over the parameter box (its corners and S
 *       random interior points), print sizes and the minimum area; with --out, write the
 *       scene's arrays (tri, rho, e, g) and a picture of its albedo (scene.png)
 *   npg-radiosity full --out DIR [--faces N] [--frames K] [--vis-samples k] [--threads T]
 *                      [--vis-mode auto|single|stream|packet] [--solver auto|lu|gs|gmres] [--ss S]
 *       full-space radiosity of both animations: per frame g, v, b_full (.npy) and a PNG,
 *       the scene's tri, rho, e once, plots, and report.json with the timings; --ss S:
 *       S x S samples per pixel (3)
 *   npg-radiosity train / run / demo: the reduced half (demo.c), through npg.h only. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "animation.h"
#include "commands.h"
#include "frame.h"
#include "chart.h"
#include "npg.h"
#include "output.h"
#include "plot.h"
#include "radiosity.h"
#include "render.h"
#include "scene.h"
#include "visibility.h"
#include "util.h"

static void usage(FILE *out) {
  fputs("usage: npg-radiosity scene [--faces N] [--checks S] [--out DIR]\n"
        "       npg-radiosity full --out DIR [--faces N] [--frames K] [--vis-samples 1|4|16] [--threads T]\n"
        "                          [--vis-mode auto|single|stream|packet] [--solver auto|lu|gs|gmres] [--ss S]\n"
        "       npg-radiosity train --out DIR [--faces N] [--samples S] [--cap C] [--energy E] [--mem MB]\n"
        "       npg-radiosity run --model OUT/MODEL [--faces N] [--frames K] [--reps R] [--out DIR]\n"
        "       npg-radiosity demo --out DIR [--faces N] [--samples S] [--frames K] [--cap C] [--ss S] [--reps R]\n",
        out);
}


static int parse(int argc, char **argv, Options *o) {
  *o = (Options){.faces = 800, .frames = 24, .k = 4, .threads = 2, .checks = 1000, .ss = 3, .vis_mode = "auto",
                 .solver = "auto", .samples = 120, .cap = 60, .energy = 0.999, .mem_mb = 4096, .reps = 9,
                 .program = RADIOSITY_PROGRAM};
  char prog[48];
  snprintf(prog, sizeof prog, "npg-radiosity %s", argv[1]);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, prog);
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_flag(&a, "-h") || npg_args_flag(&a, "--help")) {
      usage(stdout);
      exit(0);
    }
    if (npg_args_long(&a, "--faces", 1, 20000, &o->faces)) ;
    else if (npg_args_int(&a, "--frames", 2, 10000, &o->frames)) ;
    else if (npg_args_int(&a, "--vis-samples", 1, 16, &o->k)) {
      if (!a.error[0] && o->k != 1 && o->k != 4 && o->k != 16)
        snprintf(a.error, sizeof a.error, "%s: --vis-samples is 1, 4 or 16 (points per face), not %d", prog, o->k);
    } else if (npg_args_int(&a, "--threads", 1, 64, &o->threads)) ;
    else if (npg_args_int(&a, "--ss", 1, 8, &o->ss)) ;
    else if (npg_args_int(&a, "--checks", 0, 100000000, &o->checks)) ;
    else if ((v = npg_args_string(&a, "--out"))) {
      o->out = v;
      if (!v[0]) snprintf(a.error, sizeof a.error, "%s: --out: the folder name is empty", prog);
    }
    else if ((v = npg_args_string(&a, "--vis-mode"))) {
      o->vis_mode = v;
      if (strcmp(v, "auto") && strcmp(v, "single") && strcmp(v, "stream") && strcmp(v, "packet"))
        snprintf(a.error, sizeof a.error, "%s: --vis-mode is auto, single, stream or packet, not '%s'", prog, v);
    } else if ((v = npg_args_string(&a, "--solver"))) {
      o->solver = v;
      if (strcmp(v, "auto") && strcmp(v, "lu") && strcmp(v, "gs") && strcmp(v, "gmres"))
        snprintf(a.error, sizeof a.error, "%s: --solver is auto, lu, gs or gmres, not '%s'", prog, v);
    }
    else if (npg_args_int(&a, "--samples", 2, 100000, &o->samples)) ;
    else if (npg_args_int(&a, "--cap", 1, 1000000, &o->cap)) ;
    else if (npg_args_double(&a, "--energy", 0, 1, true, &o->energy)) ;
    else if (npg_args_long(&a, "--mem", 1, 1L << 30, &o->mem_mb)) ;
    else if (npg_args_int(&a, "--reps", 1, 10000, &o->reps)) ;
    else if ((v = npg_args_string(&a, "--model"))) o->model = v;
    else if ((v = npg_args_string(&a, "--program"))) o->program = v;
    else npg_args_unknown(&a);
  }
  if (a.error[0]) {
    fprintf(stderr, "%s\n", a.error);
    return -1;
  }
  return 0;
}


/* ---------------------------------------------------------------- scene */

/* Walk the box: its corners, then random interior points; the worst area and cosine. */
static int check_box(Scene *s, int checks, double *amin_out, double *cmin_out) {
  double *g = malloc(sizeof(double) * 3 * s->V), *ref = malloc(sizeof(double) * 3 * s->V);
  SceneParams nominal, p;
  scene_param_nominal(&nominal);
  scene_place(s, &nominal, ref);
  double amin = INFINITY, cmin = 1;
  unsigned long long rng = 0x9E3779B97F4A7C15ull;
  long total = (1L << SCENE_NGEOM) + checks;
  for (long c = 0; c < total; c++) {
    double t[SCENE_NGEOM];
    for (int k = 0; k < SCENE_NGEOM; k++) {
      if (c < (1L << SCENE_NGEOM)) {
        t[k] = (c >> k) & 1;
      } else {
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        t[k] = (double)(rng >> 11) / 9007199254740992.0;
      }
    }
    scene_param_at(t, &p);
    scene_place(s, &p, g);
    double cos_;
    double a = scene_min_area(s, g, ref, NULL, &cos_);
    if (a < amin) amin = a;
    if (cos_ < cmin) cmin = cos_;
  }
  free(g);
  free(ref);
  *amin_out = amin;
  *cmin_out = cmin;
  return 0;
}

static int cmd_scene(const Options *o) {
  Scene s;
  char err[512];
  if (scene_new(o->faces, NULL, &s, err, sizeof err) != 0) {
    fprintf(stderr, "npg-radiosity: %s\n", err);
    return 1;
  }
  long worst;
  double a0 = scene_min_area(&s, s.g, NULL, &worst, NULL), amin, cmin;
  check_box(&s, o->checks, &amin, &cmin);
  long count[MAT_COUNT] = {0};
  for (long f = 0; f < s.F; f++) count[s.mat[f]]++;
  printf("scene: %ld faces, %ld vertices, %d patches\n", s.F, s.V, s.npatch);
  for (int m = 0; m < MAT_COUNT; m++) printf("  %-15s %6ld faces\n", scene_material_name(m), count[m]);
  printf("nominal: minimum triangle area %.4g m^2 (face %ld)\n", a0, worst);
  printf("parameter box (%d corners + %d random points): minimum area %.4g m^2, minimum cosine to the nominal "
         "normal %.4f\n",
         1 << SCENE_NGEOM, o->checks, amin, cmin);
  int rc = !(amin > 0 && cmin > 0);
  if (rc) fprintf(stderr, "npg-radiosity: degenerate or inverted triangles in the parameter box\n");
  if (o->out && !rc) {
    long sg[2] = {s.V, 3};
    if (report_make_dir("npg-radiosity", o->out) || out_scene_arrays(o->out, &s) || out_npy(o->out, "g", 2, sg, s.g)) rc = 1;
    /* the picture: albedo, openings bright (no light transport) */
    double *shade = malloc(sizeof(double) * s.F);
    for (long f = 0; f < s.F; f++) shade[f] = s.rho[f] + s.e[f];
    char path[4096];
    snprintf(path, sizeof path, "%s/scene.png", o->out);
    if (!rc && out_render_frame(&s, shade, 1.5, o->ss, "albedo (openings: emission)", path, NULL)) rc = 1;
    free(shade);
  }
  scene_free(&s);
  return rc;
}

/* Area-weighted mean radiosity of the non-emitting faces of one room (bedroom: x > 6.15). */
static double room_mean(const Scene *s, const double *b, int bedroom) {
  double num = 0, den = 0;
  for (long f = 0; f < s->F; f++) {
    if (s->rho[f] <= 0) continue;
    const int *t = s->tri + 3 * f;
    double cx = (s->g[3 * t[0]] + s->g[3 * t[1]] + s->g[3 * t[2]]) / 3;
    if ((cx > 6.1) != bedroom) continue;
    const double *a = s->g + 3 * t[0], *p = s->g + 3 * t[1], *c = s->g + 3 * t[2];
    double u[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double n0 = u[1] * w[2] - u[2] * w[1], n1 = u[2] * w[0] - u[0] * w[2], n2 = u[0] * w[1] - u[1] * w[0];
    double area = 0.5 * sqrt(n0 * n0 + n1 * n1 + n2 * n2);
    num += area * b[f];
    den += area;
  }
  return den > 0 ? num / den : 0;
}

static int cmd_full(const Options *o) {
  if (!o->out) {
    fprintf(stderr, "npg-radiosity full: --out DIR is required\n");
    return 2;
  }
  char err[1024], path[4096];
  Scene s;
  if (scene_new(o->faces, NULL, &s, err, sizeof err) != 0) {
    fprintf(stderr, "npg-radiosity: %s\n", err);
    return 1;
  }
  long F = s.F;
  int rc = 1;
  FullRadiosity fr = {0};
  double *vk = NULL, *bk = NULL, *series = NULL;
  if (report_make_dir("npg-radiosity", o->out) || out_scene_arrays(o->out, &s)) goto done;
  printf("scene: %ld faces, %ld vertices; visibility: %d points per face, %d threads\n", F, s.V, o->k, o->threads);

  /* 1. the visibility modes on the nominal scene: time each, check they agree, keep the fastest */
  VisMode modes[3] = {VIS_SINGLE, VIS_STREAM, VIS_PACKET};
  double t_mode[3] = {NAN, NAN, NAN}, mode_diff = 0;
  long mode_ndiff = 0; /* entries where a mode disagrees with rtcOccluded1 (grazing rays) */
  long rays = 0;
  VisMode best = VIS_STREAM;
  vk = malloc(sizeof(double) * F * F);
  double *vref = malloc(sizeof(double) * F * F);
  if (!vk || !vref) {
    free(vref);
    fprintf(stderr, "npg-radiosity: out of memory\n");
    goto done;
  }
  for (int m = 0; m < 3; m++) {
    const char *names[3] = {"single", "stream", "packet"};
    if (strcmp(o->vis_mode, "auto") && strcmp(o->vis_mode, names[m])) continue;
    Visibility *vis = vis_new(s.V, F, s.tri, o->k, o->threads, modes[m], err, sizeof err);
    if (!vis) {
      fprintf(stderr, "npg-radiosity: %s\n", err);
      free(vref);
      goto done;
    }
    double best_t = INFINITY;
    for (int rep = 0; rep < 2; rep++) { /* the first call also builds; take the faster */
      double t0 = frame_now();
      if (vis_compute(vis, s.g, m == 0 || isnan(t_mode[0]) ? vref : vk, err, sizeof err) != 0) {
        fprintf(stderr, "npg-radiosity: %s\n", err);
        vis_free(vis);
        free(vref);
        goto done;
      }
      best_t = fmin(best_t, frame_now() - t0);
    }
    rays = vis_rays(vis);
    vis_free(vis);
    t_mode[m] = best_t;
    if (m > 0 && !isnan(t_mode[0]))
      for (size_t q = 0; q < (size_t)F * F; q++) {
        mode_diff = fmax(mode_diff, fabs(vk[q] - vref[q]));
        mode_ndiff += vk[q] != vref[q];
      }
    printf("visibility %-24s %.3f s (%ld rays, %.1f Mrays/s)\n", vis_mode_name(modes[m]), best_t, rays,
           rays / best_t * 1e-6);
  }
  free(vref);
  double tb = INFINITY;
  for (int m = 0; m < 3; m++)
    if (!isnan(t_mode[m]) && t_mode[m] < tb) tb = t_mode[m], best = modes[m];
  if (mode_diff > 0)
    printf("visibility modes differ by up to %g in %ld of %ld entries (rays grazing an edge)\n", mode_diff, mode_ndiff,
           F * F);

  /* 2. the solvers on the nominal scene: time each, check they agree, keep the fastest */
  const char *solver_opt[SOLVER_COUNT] = {"lu", "gs", "gmres"};
  int want = -1;
  for (int q = 0; q < SOLVER_COUNT; q++)
    if (!strcmp(o->solver, solver_opt[q])) want = q;
  if (want < 0 && strcmp(o->solver, "auto")) {
    fprintf(stderr, "npg-radiosity: --solver auto|lu|gs|gmres, not '%s'\n", o->solver);
    goto done;
  }
  if (frame_new(&fr, &s, o->k, o->threads, best, want < 0 ? SOLVER_LU : (Solver)want, err, sizeof err) != 0 ||
      frame_compute(&fr, NULL, err, sizeof err)) {
    fprintf(stderr, "npg-radiosity: %s\n", err);
    goto done;
  }
  double t_solver[SOLVER_COUNT] = {NAN, NAN, NAN}, res_solver[SOLVER_COUNT] = {NAN, NAN, NAN}, solver_diff = 0;
  int iters[SOLVER_COUNT] = {0};
  bk = malloc(sizeof(double) * F);
  double tbest = INFINITY;
  int have_ref = 0;
  for (int q = 0; q < SOLVER_COUNT; q++) {
    if (want >= 0 && want != q) continue;
    if (frame_solve(&fr, (Solver)q, &t_solver[q], err, sizeof err)) goto solve_failed;
    iters[q] = q == SOLVER_LU ? 0 : fr.sweeps;
    res_solver[q] = radiosity_residual(F, s.rho, fr.p, s.e, fr.b);
    printf("solve %-13s %.3f s (residual %.2e", frame_solver_name((Solver)q), t_solver[q], res_solver[q]);
    if (q == SOLVER_GAUSS_SEIDEL) printf(", %d sweeps", iters[q]);
    if (q == SOLVER_GMRES) printf(", %d products", iters[q]);
    printf(")\n");
    if (!have_ref) {
      memcpy(bk, fr.b, sizeof(double) * F);
      have_ref = 1;
    } else {
      double big = 0, d = 0;
      for (long f = 0; f < F; f++) d = fmax(d, fabs(bk[f] - fr.b[f])), big = fmax(big, fabs(bk[f]));
      solver_diff = fmax(solver_diff, d / big);
    }
    if (t_solver[q] < tbest && iters[q] >= 0) tbest = t_solver[q], fr.solver = (Solver)q;
  }
  printf("using visibility %s, solver %s\n", vis_mode_name(best), frame_solver_name(fr.solver));
  double exposure = render_exposure(F, fr.b, s.rho);
  snprintf(path, sizeof path, "%s/nominal.png", o->out);
  if (out_render_frame(&s, fr.b, exposure, o->ss, "radiosity b", path, NULL)) goto done;

  /* 3. the animations */
  int K = o->frames, tty = isatty(fileno(stdout));
  series = malloc(sizeof(double) * ANIM_COUNT * K * 6);
  double *t_vis = series, *t_ff = series + ANIM_COUNT * K, *t_sol = series + 2 * ANIM_COUNT * K;
  double *living = series + 3 * ANIM_COUNT * K, *bedroom = series + 4 * ANIM_COUNT * K, *t_tot = series + 5 * ANIM_COUNT * K;
  for (int a = 0; a < ANIM_COUNT; a++) {
    for (int k = 0; k < K; k++) {
      SceneParams p;
      animation_params(a, (double)k / (K - 1), &p);
      if (frame_compute(&fr, &p, err, sizeof err)) goto solve_failed;
      int at = a * K + k;
      t_vis[at] = fr.t_vis, t_ff[at] = fr.t_ff, t_sol[at] = fr.t_solve;
      t_tot[at] = fr.t_vis + fr.t_ff + fr.t_solve;
      living[at] = room_mean(&s, fr.b, 0);
      bedroom[at] = room_mean(&s, fr.b, 1);
      char dir[4096];
      snprintf(dir, sizeof dir, "%s/%s/frame_%04d", o->out, animation_name(a), k);
      long sg[2] = {s.V, 3}, sv[2] = {F, F}, sb[1] = {F};
      if (report_make_dir("npg-radiosity", dir) || out_npy(dir, "g", 2, sg, s.g) || out_npy(dir, "v", 2, sv, fr.v) ||
          out_npy(dir, "b_full", 1, sb, fr.b))
        goto done;
      snprintf(path, sizeof path, "%s/%s/frame_%04d.png", o->out, animation_name(a), k);
      if (out_render_frame(&s, fr.b, exposure, o->ss, "radiosity b", path, NULL)) goto done;
      if (tty) {
        printf("\r%s frame %d/%d: visibility %.3f s, form factors %.3f s, solve %.3f s", animation_name(a), k + 1, K,
               fr.t_vis, fr.t_ff, fr.t_solve);
        fflush(stdout);
      }
    }
    if (tty) printf("\n");
    printf("%s: %d frames\n", animation_name(a), K);
  }

  /* 4. plots: per-frame seconds and room brightness */
  for (int a = 0; a < ANIM_COUNT; a++) {
    char title[256];
    PlotSeries ts[4] = {{"visibility", t_vis + a * K, K}, {"form factors", t_ff + a * K, K},
                        {"solve", t_sol + a * K, K}, {"total", t_tot + a * K, K}};
    snprintf(title, sizeof title, "full frame, %s animation (%ld faces)", animation_name(a), F);
    snprintf(path, sizeof path, "%s/%s_seconds.png", o->out, animation_name(a));
    if (plot_series(path, title, "seconds", ts, 4, 0, 0, err, sizeof err)) {
      fprintf(stderr, "npg-radiosity: %s\n", err);
      goto done;
    }
    PlotSeries bs[2] = {{"living room", living + a * K, K}, {"bedroom", bedroom + a * K, K}};
    snprintf(title, sizeof title, "mean radiosity of the walls, %s animation", animation_name(a));
    snprintf(path, sizeof path, "%s/%s_brightness.png", o->out, animation_name(a));
    if (plot_series(path, title, "area-weighted mean b", bs, 2, 0, 0, err, sizeof err)) {
      fprintf(stderr, "npg-radiosity: %s\n", err);
      goto done;
    }
  }

  /* 5. the sampling of visibility shown: the last frame with centroid-only visibility
   *    against the k points, side by side with the error map */
  double vis1_diff = NAN;
  if (o->k != 1) {
    Scene *sc = &s;
    memcpy(bk, fr.b, sizeof(double) * F);
    Visibility *v1 = vis_new(s.V, F, s.tri, 1, o->threads, best, err, sizeof err);
    if (!v1 || vis_compute(v1, s.g, vk, err, sizeof err)) {
      fprintf(stderr, "npg-radiosity: %s\n", err);
      vis_free(v1);
      goto done;
    }
    vis_free(v1);
    radiosity_form_factors(s.V, F, s.g, s.tri, vk, fr.p, o->threads);
    if (frame_solve(&fr, fr.solver, NULL, err, sizeof err)) goto solve_failed;
    double num = 0, den = 0;
    for (long f = 0; f < F; f++) num += (fr.b[f] - bk[f]) * (fr.b[f] - bk[f]), den += bk[f] * bk[f];
    vis1_diff = sqrt(num / den);
    Camera cam;
    render_camera_default(&cam);
    cam.ss = o->ss;
    View view;
    Image im[3] = {{0}};
    if (render_view(&cam, sc->V, F, sc->g, sc->tri, &view, err, sizeof err)) goto solve_failed;
    render_shade(&view, s.V, F, s.tri, s.g, bk, exposure, &im[0]);
    render_shade(&view, s.V, F, s.tri, s.g, fr.b, exposure, &im[1]);
    render_error(&view, F, bk, fr.b, 0.1 * -log(0.4) / exposure, &im[2]); /* 10% of the bright walls */
    render_view_free(&view);
    for (int q = 0; q < 2; q++) render_add_colorbar(&im[q], SCALE_SHADE, exposure, "radiosity b");
    render_add_colorbar(&im[2], SCALE_ERROR, 0.1 * -log(0.4) / exposure, "|difference| of b");
    char l0[64], l2[128];
    snprintf(l0, sizeof l0, "visibility from %d points per face", o->k);
    snprintf(l2, sizeof l2, "|difference| (white: 10%% of bright walls), rel. L2 %.1f%%", 100 * vis1_diff);
    const Image *ims[3] = {&im[0], &im[1], &im[2]};
    const char *labels[3] = {l0, "centroid to centroid only", l2};
    snprintf(path, sizeof path, "%s/visibility_sampling.png", o->out);
    int w = render_side_by_side(path, ims, labels, 3, err, sizeof err);
    for (int q = 0; q < 3; q++) image_free(&im[q]);
    if (w) {
      fprintf(stderr, "npg-radiosity: %s\n", err);
      goto done;
    }
  }

  /* 6. report.json */
  Report rep;
  if (report_open(&rep, "npg-radiosity", o->out) != 0) goto done;
  FILE *js = rep.f;
  int n = ANIM_COUNT * K;
  fprintf(js, "{\n  \"faces\": %ld,\n  \"vertices\": %ld,\n  \"threads\": %d,\n  \"visibility_points_per_face\": %d,\n",
          F, s.V, o->threads, o->k);
  fprintf(js, "  \"frames_per_animation\": %d,\n  \"animations\": [\"%s\", \"%s\"],\n", K, animation_name(0),
          animation_name(1));
  fprintf(js, "  \"full_frame_seconds\": {\"visibility\": %.6g, \"form_factors\": %.6g, \"solve\": %.6g, \"total\": %.6g, "
              "\"statistic\": \"median over all frames\"},\n",
          out_median(t_vis, n), out_median(t_ff, n), out_median(t_sol, n), out_median(t_tot, n));
  fprintf(js, "  \"visibility_modes_seconds\": {\"single\": %.6g, \"stream\": %.6g, \"packet\": %.6g, \"rays\": %ld, "
              "\"used\": \"%s\", \"max_difference\": %.3g, \"entries_differing\": %ld},\n",
          t_mode[0], t_mode[1], t_mode[2], rays, vis_mode_name(best), mode_diff, mode_ndiff);
  fprintf(js, "  \"solvers\": {\"lu_seconds\": %.6g, \"gauss_seidel_seconds\": %.6g, \"gmres_seconds\": %.6g, "
              "\"gauss_seidel_sweeps\": %d, \"gmres_products\": %d, \"lu_residual\": %.3g, \"gauss_seidel_residual\": %.3g, "
              "\"gmres_residual\": %.3g, \"max_relative_difference\": %.3g, \"used\": \"%s\"},\n",
          t_solver[0], t_solver[1], t_solver[2], iters[1], iters[2], res_solver[0], res_solver[1], res_solver[2],
          solver_diff, frame_solver_name(fr.solver));
  fprintf(js, "  \"exposure\": %.6g,\n  \"centroid_visibility_relative_l2_difference\": %.6g,\n", exposure, vis1_diff);
  fprintf(js, "  \"per_frame\": {\n");
  for (int a = 0; a < ANIM_COUNT; a++) {
    fprintf(js, "    \"%s\": {", animation_name(a));
    report_json_array(js, "", "visibility_seconds", t_vis + a * K, K, 6, ", ");
    report_json_array(js, "", "form_factor_seconds", t_ff + a * K, K, 6, ", ");
    report_json_array(js, "", "solve_seconds", t_sol + a * K, K, 6, ", ");
    report_json_array(js, "", "mean_b_living", living + a * K, K, 6, ", ");
    report_json_array(js, "", "mean_b_bedroom", bedroom + a * K, K, 6, "");
    fprintf(js, "}%s\n", a + 1 < ANIM_COUNT ? "," : "");
  }
  fprintf(js, "  }\n}\n");
  if (report_commit(&rep, "npg-radiosity") != 0) goto done;
  printf("full frame (median): visibility %.3f s, form factors %.3f s, solve %.3f s; wrote %s\n", out_median(t_vis, n),
         out_median(t_ff, n), out_median(t_sol, n), o->out);
  rc = 0;
  goto done;
solve_failed:
  fprintf(stderr, "npg-radiosity: %s\n", err);
done:
  free(vk);
  free(bk);
  free(series);
  frame_free(&fr);
  scene_free(&s);
  return rc;
}

static int run(int argc, char **argv) {
  if (argc < 2) {
    usage(stderr);
    return 2;
  }
  Options o;
  if (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help") || !strcmp(argv[1], "help")) {
    usage(stdout);
    return 0;
  }
  if (parse(argc, argv, &o)) return 2;
  int rc = 2;
  if (!strcmp(argv[1], "scene"))
    rc = cmd_scene(&o);
  else if (!strcmp(argv[1], "full"))
    rc = cmd_full(&o);
  else if (!strcmp(argv[1], "train"))
    rc = cmd_train(&o);
  else if (!strcmp(argv[1], "run"))
    rc = cmd_run(&o);
  else if (!strcmp(argv[1], "demo"))
    rc = cmd_demo(&o);
  else {
    fprintf(stderr, "npg-radiosity: unknown command '%s'\n", argv[1]);
    usage(stderr);
  }
  chart_cleanup(); /* cairo's and fontconfig's caches */
  return rc;
}

int main(int argc, char **argv) { return util_exit_status("npg-radiosity", run(argc, argv)); }
