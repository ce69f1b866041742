/* full.c — the full half of npg-radiosity (commands.h): full.
 *
 *   full   the visibility modes and the solvers timed on the nominal scene (each checked
 *          against the first, the fastest kept), both animations in full (per frame g, v,
 *          b_full and a picture), plots, the sampling of visibility shown, DIR/report.json
 *
 * cmd_full is the table of contents; each phase below is one step of it, its state in FullRun. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "animation.h"
#include "commands.h"
#include "frame.h"
#include "output.h"
#include "plot.h"
#include "radiosity.h"
#include "scene.h"
#include "visibility.h"

typedef struct FullRun {
  const Options *o;
  Scene s;
  FullRadiosity fr;
  double *vk, *bk; /* F x F visibility scratch; the reference b of a comparison */
  char err[1024];
  /* the visibility modes on the nominal scene */
  double t_mode[3], mode_diff;
  long mode_ndiff; /* entries where a mode disagrees with rtcOccluded1 (grazing rays) */
  long rays;
  VisMode best;
  /* the solvers on the nominal scene */
  double t_solver[SOLVER_COUNT], res_solver[SOLVER_COUNT], solver_diff;
  int iters[SOLVER_COUNT];
  double exposure;
  /* the animations: ANIM_COUNT x K values per series */
  int K;
  double *series, *t_vis, *t_ff, *t_sol, *living, *bedroom, *t_tot;
  double vis1_diff; /* relative L2 difference of b with centroid-only visibility */
} FullRun;

static int failed(const FullRun *r) {
  fprintf(stderr, "npg-radiosity: %s\n", r->err);
  return 1;
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

/* 1. The visibility modes on the nominal scene: time each (the faster of two calls, the
 *    first also builds), check they agree with the first, keep the fastest in r->best. */
static int time_visibility(FullRun *r) {
  const Options *o = r->o;
  long F = r->s.F;
  VisMode modes[3] = {VIS_SINGLE, VIS_STREAM, VIS_PACKET};
  const char *names[3] = {"single", "stream", "packet"};
  double *vref = malloc(sizeof(double) * F * F);
  if (!vref) {
    fprintf(stderr, "npg-radiosity: out of memory\n");
    return 1;
  }
  for (int m = 0; m < 3; m++) {
    if (strcmp(o->vis_mode, "auto") && strcmp(o->vis_mode, names[m])) continue;
    Visibility *vis = vis_new(r->s.V, F, r->s.tri, o->k, o->threads, modes[m], r->err, sizeof r->err);
    if (!vis) {
      free(vref);
      return failed(r);
    }
    double best_t = INFINITY;
    for (int rep = 0; rep < 2; rep++) {
      double t0 = frame_now();
      if (vis_compute(vis, r->s.g, m == 0 || isnan(r->t_mode[0]) ? vref : r->vk, r->err, sizeof r->err) != 0) {
        vis_free(vis);
        free(vref);
        return failed(r);
      }
      best_t = fmin(best_t, frame_now() - t0);
    }
    r->rays = vis_rays(vis);
    vis_free(vis);
    r->t_mode[m] = best_t;
    if (m > 0 && !isnan(r->t_mode[0]))
      for (size_t q = 0; q < (size_t)F * F; q++) {
        r->mode_diff = fmax(r->mode_diff, fabs(r->vk[q] - vref[q]));
        r->mode_ndiff += r->vk[q] != vref[q];
      }
    printf("visibility %-24s %.3f s (%ld rays, %.1f Mrays/s)\n", vis_mode_name(modes[m]), best_t, r->rays,
           r->rays / best_t * 1e-6);
  }
  free(vref);
  double tb = INFINITY;
  for (int m = 0; m < 3; m++)
    if (!isnan(r->t_mode[m]) && r->t_mode[m] < tb) tb = r->t_mode[m], r->best = modes[m];
  if (r->mode_diff > 0)
    printf("visibility modes differ by up to %g in %ld of %ld entries (rays grazing an edge)\n", r->mode_diff,
           r->mode_ndiff, F * F);
  return 0;
}

/* 2. The solvers on the nominal scene: time each, check they agree with the first (the
 *    largest relative difference of b), keep the fastest in r->fr.solver. */
static int time_solvers(FullRun *r) {
  const Options *o = r->o;
  long F = r->s.F;
  const char *solver_opt[SOLVER_COUNT] = {"lu", "gs", "gmres"};
  int want = -1;
  for (int q = 0; q < SOLVER_COUNT; q++)
    if (!strcmp(o->solver, solver_opt[q])) want = q;
  if (want < 0 && strcmp(o->solver, "auto")) {
    fprintf(stderr, "npg-radiosity: --solver auto|lu|gs|gmres, not '%s'\n", o->solver);
    return 1;
  }
  FullRadiosity *fr = &r->fr;
  if (frame_new(fr, &r->s, o->k, o->threads, r->best, want < 0 ? SOLVER_LU : (Solver)want, r->err, sizeof r->err) !=
          0 ||
      frame_compute(fr, NULL, r->err, sizeof r->err))
    return failed(r);
  double tbest = INFINITY;
  int have_ref = 0;
  for (int q = 0; q < SOLVER_COUNT; q++) {
    if (want >= 0 && want != q) continue;
    if (frame_solve(fr, (Solver)q, &r->t_solver[q], r->err, sizeof r->err)) return failed(r);
    r->iters[q] = q == SOLVER_LU ? 0 : fr->sweeps;
    r->res_solver[q] = radiosity_residual(F, r->s.rho, fr->p, r->s.e, fr->b);
    printf("solve %-13s %.3f s (residual %.2e", frame_solver_name((Solver)q), r->t_solver[q], r->res_solver[q]);
    if (q == SOLVER_GAUSS_SEIDEL) printf(", %d sweeps", r->iters[q]);
    if (q == SOLVER_GMRES) printf(", %d products", r->iters[q]);
    printf(")\n");
    if (!have_ref) {
      memcpy(r->bk, fr->b, sizeof(double) * F);
      have_ref = 1;
    } else {
      double big = 0, d = 0;
      for (long f = 0; f < F; f++) d = fmax(d, fabs(r->bk[f] - fr->b[f])), big = fmax(big, fabs(r->bk[f]));
      r->solver_diff = fmax(r->solver_diff, d / big);
    }
    if (r->t_solver[q] < tbest && r->iters[q] >= 0) tbest = r->t_solver[q], fr->solver = (Solver)q;
  }
  printf("using visibility %s, solver %s\n", vis_mode_name(r->best), frame_solver_name(fr->solver));
  return 0;
}

/* 3. The animations: per frame g, v, b_full and a picture, the phases' seconds and the
 *    rooms' mean radiosity into r->series; a progress line on a terminal. */
static int run_animations(FullRun *r) {
  const Options *o = r->o;
  const Scene *s = &r->s;
  FullRadiosity *fr = &r->fr;
  long F = s->F;
  int K = r->K, tty = isatty(fileno(stdout));
  char path[4096];
  for (int a = 0; a < ANIM_COUNT; a++) {
    for (int k = 0; k < K; k++) {
      SceneParams p;
      animation_params(a, (double)k / (K - 1), &p);
      if (frame_compute(fr, &p, r->err, sizeof r->err)) return failed(r);
      int at = a * K + k;
      r->t_vis[at] = fr->t_vis, r->t_ff[at] = fr->t_ff, r->t_sol[at] = fr->t_solve;
      r->t_tot[at] = fr->t_vis + fr->t_ff + fr->t_solve;
      r->living[at] = room_mean(s, fr->b, 0);
      r->bedroom[at] = room_mean(s, fr->b, 1);
      char dir[4096];
      snprintf(dir, sizeof dir, "%s/%s/frame_%04d", o->out, animation_name(a), k);
      long sg[2] = {s->V, 3}, sv[2] = {F, F}, sb[1] = {F};
      if (report_make_dir("npg-radiosity", dir) || out_npy(dir, "g", 2, sg, s->g) || out_npy(dir, "v", 2, sv, fr->v) ||
          out_npy(dir, "b_full", 1, sb, fr->b))
        return 1;
      snprintf(path, sizeof path, "%s/%s/frame_%04d.png", o->out, animation_name(a), k);
      if (out_render_frame(s, fr->b, r->exposure, o->ss, "radiosity b", path, NULL)) return 1;
      if (tty) {
        printf("\r%s frame %d/%d: visibility %.3f s, form factors %.3f s, solve %.3f s", animation_name(a), k + 1, K,
               fr->t_vis, fr->t_ff, fr->t_solve);
        fflush(stdout);
      }
    }
    if (tty) printf("\n");
    printf("%s: %d frames\n", animation_name(a), K);
  }
  return 0;
}

/* 4. Plots: per-frame seconds and room brightness of each animation. */
static int plot_animations(FullRun *r) {
  int K = r->K;
  char title[256], path[4096];
  for (int a = 0; a < ANIM_COUNT; a++) {
    PlotSeries ts[4] = {{"visibility", r->t_vis + a * K, K}, {"form factors", r->t_ff + a * K, K},
                        {"solve", r->t_sol + a * K, K}, {"total", r->t_tot + a * K, K}};
    snprintf(title, sizeof title, "full frame, %s animation (%ld faces)", animation_name(a), r->s.F);
    snprintf(path, sizeof path, "%s/%s_seconds.png", r->o->out, animation_name(a));
    if (plot_series(path, title, "seconds", ts, 4, 0, 0, r->err, sizeof r->err)) return failed(r);
    PlotSeries bs[2] = {{"living room", r->living + a * K, K}, {"bedroom", r->bedroom + a * K, K}};
    snprintf(title, sizeof title, "mean radiosity of the walls, %s animation", animation_name(a));
    snprintf(path, sizeof path, "%s/%s_brightness.png", r->o->out, animation_name(a));
    if (plot_series(path, title, "area-weighted mean b", bs, 2, 0, 0, r->err, sizeof r->err)) return failed(r);
  }
  return 0;
}

/* 5. The sampling of visibility shown: the last frame with centroid-only visibility against
 *    the k points, side by side with the error map (skipped when k is already 1). */
static int show_visibility_sampling(FullRun *r) {
  const Options *o = r->o;
  const Scene *s = &r->s;
  FullRadiosity *fr = &r->fr;
  long F = s->F;
  if (o->k == 1) return 0;
  memcpy(r->bk, fr->b, sizeof(double) * F);
  Visibility *v1 = vis_new(s->V, F, s->tri, 1, o->threads, r->best, r->err, sizeof r->err);
  if (!v1 || vis_compute(v1, s->g, r->vk, r->err, sizeof r->err)) {
    vis_free(v1);
    return failed(r);
  }
  vis_free(v1);
  radiosity_form_factors(s->V, F, s->g, s->tri, r->vk, fr->p, o->threads);
  if (frame_solve(fr, fr->solver, NULL, r->err, sizeof r->err)) return failed(r);
  double num = 0, den = 0;
  for (long f = 0; f < F; f++) num += (fr->b[f] - r->bk[f]) * (fr->b[f] - r->bk[f]), den += r->bk[f] * r->bk[f];
  r->vis1_diff = sqrt(num / den);
  char l0[64], l2[128], path[4096];
  snprintf(l0, sizeof l0, "visibility from %d points per face", o->k);
  snprintf(l2, sizeof l2, "|difference| (white: 10%% of bright walls), rel. L2 %.1f%%", 100 * r->vis1_diff);
  const char *const labels[3] = {l0, "centroid to centroid only", l2};
  snprintf(path, sizeof path, "%s/visibility_sampling.png", o->out);
  return out_render_compare(s, r->bk, fr->b, r->exposure, o->ss, labels, "|difference| of b", path) ? 1 : 0;
}

/* 6. DIR/report.json: sizes, the medians of the full frame's phases, the modes' and the
 *    solvers' figures, and the per-frame series. */
static int write_report(const FullRun *r) {
  const Options *o = r->o;
  int K = r->K, n = ANIM_COUNT * K;
  Report rep;
  if (report_open(&rep, "npg-radiosity", o->out) != 0) return 1;
  FILE *js = rep.f;
  fprintf(js, "{\n  \"faces\": %ld,\n  \"vertices\": %ld,\n  \"threads\": %d,\n  \"visibility_points_per_face\": %d,\n",
          r->s.F, r->s.V, o->threads, o->k);
  fprintf(js, "  \"frames_per_animation\": %d,\n  \"animations\": [\"%s\", \"%s\"],\n", K, animation_name(0),
          animation_name(1));
  fprintf(js, "  \"full_frame_seconds\": {\"visibility\": %.6g, \"form_factors\": %.6g, \"solve\": %.6g, \"total\": %.6g, "
              "\"statistic\": \"median over all frames\"},\n",
          out_median(r->t_vis, n), out_median(r->t_ff, n), out_median(r->t_sol, n), out_median(r->t_tot, n));
  fprintf(js, "  \"visibility_modes_seconds\": {\"single\": %.6g, \"stream\": %.6g, \"packet\": %.6g, \"rays\": %ld, "
              "\"used\": \"%s\", \"max_difference\": %.3g, \"entries_differing\": %ld},\n",
          r->t_mode[0], r->t_mode[1], r->t_mode[2], r->rays, vis_mode_name(r->best), r->mode_diff, r->mode_ndiff);
  fprintf(js, "  \"solvers\": {\"lu_seconds\": %.6g, \"gauss_seidel_seconds\": %.6g, \"gmres_seconds\": %.6g, "
              "\"gauss_seidel_sweeps\": %d, \"gmres_products\": %d, \"lu_residual\": %.3g, \"gauss_seidel_residual\": %.3g, "
              "\"gmres_residual\": %.3g, \"max_relative_difference\": %.3g, \"used\": \"%s\"},\n",
          r->t_solver[0], r->t_solver[1], r->t_solver[2], r->iters[1], r->iters[2], r->res_solver[0], r->res_solver[1],
          r->res_solver[2], r->solver_diff, frame_solver_name(r->fr.solver));
  fprintf(js, "  \"exposure\": %.6g,\n  \"centroid_visibility_relative_l2_difference\": %.6g,\n", r->exposure,
          r->vis1_diff);
  fprintf(js, "  \"per_frame\": {\n");
  for (int a = 0; a < ANIM_COUNT; a++) {
    fprintf(js, "    \"%s\": {", animation_name(a));
    report_json_array(js, "", "visibility_seconds", r->t_vis + a * K, K, 6, ", ");
    report_json_array(js, "", "form_factor_seconds", r->t_ff + a * K, K, 6, ", ");
    report_json_array(js, "", "solve_seconds", r->t_sol + a * K, K, 6, ", ");
    report_json_array(js, "", "mean_b_living", r->living + a * K, K, 6, ", ");
    report_json_array(js, "", "mean_b_bedroom", r->bedroom + a * K, K, 6, "");
    fprintf(js, "}%s\n", a + 1 < ANIM_COUNT ? "," : "");
  }
  fprintf(js, "  }\n}\n");
  return report_commit(&rep, "npg-radiosity") != 0;
}

/* The scratch of a run: the visibility matrix, a reference b and the per-frame series. */
static int alloc_run(FullRun *r) {
  long F = r->s.F;
  size_t K = (size_t)r->K;
  r->vk = malloc(sizeof(double) * F * F);
  r->bk = malloc(sizeof(double) * F);
  r->series = malloc(sizeof(double) * ANIM_COUNT * K * 6);
  if (!r->vk || !r->bk || !r->series) {
    fprintf(stderr, "npg-radiosity: out of memory\n");
    return 1;
  }
  double **col[6] = {&r->t_vis, &r->t_ff, &r->t_sol, &r->living, &r->bedroom, &r->t_tot};
  for (int q = 0; q < 6; q++) *col[q] = r->series + q * ANIM_COUNT * K;
  return 0;
}

int cmd_full(const Options *o) {
  if (!o->out) {
    fprintf(stderr, "npg-radiosity full: --out DIR is required\n");
    return 2;
  }
  FullRun r = {.o = o, .K = o->frames, .best = VIS_STREAM, .t_mode = {NAN, NAN, NAN},
               .t_solver = {NAN, NAN, NAN}, .res_solver = {NAN, NAN, NAN}, .vis1_diff = NAN};
  if (scene_new(o->faces, NULL, &r.s, r.err, sizeof r.err) != 0) return failed(&r);
  int rc = 1;
  if (alloc_run(&r) || report_make_dir("npg-radiosity", o->out) || out_scene_arrays(o->out, &r.s)) goto done;
  printf("scene: %ld faces, %ld vertices; visibility: %d points per face, %d threads\n", r.s.F, r.s.V, o->k,
         o->threads);
  if (time_visibility(&r) || time_solvers(&r)) goto done;
  r.exposure = render_exposure(r.s.F, r.fr.b, r.s.rho);
  char path[4096];
  snprintf(path, sizeof path, "%s/nominal.png", o->out);
  if (out_render_frame(&r.s, r.fr.b, r.exposure, o->ss, "radiosity b", path, NULL)) goto done;
  if (run_animations(&r) || plot_animations(&r) || show_visibility_sampling(&r) || write_report(&r)) goto done;
  int n = ANIM_COUNT * r.K;
  printf("full frame (median): visibility %.3f s, form factors %.3f s, solve %.3f s; wrote %s\n",
         out_median(r.t_vis, n), out_median(r.t_ff, n), out_median(r.t_sol, n), o->out);
  rc = 0;
done:
  free(r.vk);
  free(r.bk);
  free(r.series);
  frame_free(&r.fr);
  scene_free(&r.s);
  return rc;
}
