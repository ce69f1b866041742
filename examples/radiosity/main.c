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
 *   npg-radiosity full: the full half (full.c); train / run / demo: the reduced half (demo.c),
 *   through npg.h only. */
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
        "                           [--basis NAME:cap=N,energy=E,center=on|off]... [--structured-weight W|balanced]\n"
        "       npg-radiosity run --model OUT/MODEL [--faces N] [--frames K] [--reps R] [--out DIR]\n"
        "       npg-radiosity demo --out DIR [--faces N] [--samples S] [--frames K] [--cap C] [--energy E] [--mem MB]\n"
        "                          [--basis NAME:cap=N,energy=E,center=on|off]... [--structured-weight W|balanced] [--ss S] [--reps R]\n",
        out);
}


/* --basis NAME:cap=N,energy=E,center=on|off (npg_parse_basis; NAME a quantity or a class
 * of formfactors.npg, checked by training): one more override in `o`. 0, or -1 with the
 * problem in `err`. */
static int add_basis(Options *o, const char *s, char *err, size_t errlen) {
  if (o->nbasis == RADIOSITY_MAX_BASIS) {
    snprintf(err, errlen, "'%s': at most %d --basis options", s, RADIOSITY_MAX_BASIS);
    return -1;
  }
  int k = o->nbasis;
  if (npg_parse_basis(s, &o->basis_name[k], &o->basis_cap[k], &o->basis_energy[k], &o->basis_center[k], err, errlen))
    return -1;
  o->nbasis++;
  return 0;
}

static int parse(int argc, char **argv, Options *o) {
  *o = (Options){.faces = 800, .frames = 24, .k = 4, .threads = 2, .checks = 1000, .ss = 3, .vis_mode = "auto",
                 .solver = "auto", .samples = 120, .cap = 60, .energy = 0.999, .mem_mb = 4096, .reps = 9,
                 .structured_weight = 0, .program = RADIOSITY_PROGRAM};
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
    else if ((v = npg_args_string(&a, "--basis"))) {
      char why[384];
      if (add_basis(o, v, why, sizeof why)) snprintf(a.error, sizeof a.error, "%s: --basis %s", prog, why);
    }
    else if ((v = npg_args_string(&a, "--structured-weight"))) {
      char why[256];
      if (strcmp(v, "balanced") == 0) o->structured_weight = 0;
      else if (npg_parse_double(v, 0, 1e6, true, &o->structured_weight, why, sizeof why))
        snprintf(a.error, sizeof a.error, "%s: --structured-weight: %s (a weight in (0, 1e6], or 'balanced')", prog, why);
    }
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
  int rc = 2;
  if (parse(argc, argv, &o)) {
    for (int i = 0; i < o.nbasis; i++) free(o.basis_name[i]);
    return rc;
  }
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
  for (int i = 0; i < o.nbasis; i++) free(o.basis_name[i]);
  return rc;
}

int main(int argc, char **argv) { return util_exit_status("npg-radiosity", run(argc, argv)); }
