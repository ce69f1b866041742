/* main.c — npg-points: radiosity of point models by the fast multipole
 * method with point-based visibility (examples/points/README.md).
 *
 *   npg-points demo  --points N --out DIR [--p P] [--leaf S] [--tol T] [--scene box|rooms] [--faces F]
 *   npg-points sweep --out DIR [--points N1,N2,...] [--orders P1,P2,...]
 *
 * demo writes DIR/report.json, DIR/b.npy (and the other arrays), and the
 * pictures; sweep measures error against p and time against N and plots
 * them. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "dense.h"
#include "fmm.h"
#include "kernel.h"
#include "chart.h"
#include "npg.h"
#include "rooms.h"
#include "octree.h"
#include "render.h"
#include "report.h"
#include "surfels.h"
#include "util.h"
#include "visibility.h"

static double now_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* CPU seconds of the whole process (every thread): what a run cost when
 * other work shares the cores and wall time says little. */
static double cpu_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double rel_error(const double *a, const double *ref, long n) {
  double d = 0, r = 0;
  for (long k = 0; k < n; k++) d += (a[k] - ref[k]) * (a[k] - ref[k]), r += ref[k] * ref[k];
  return r > 0 ? sqrt(d / r) : sqrt(d);
}

typedef struct DenseCtx {
  const Surfels *s;
  const Octree *t;
  const float *vis;
  const unsigned char *bits;
} DenseCtx;

static void gather_fmm(void *ctx, const double *b, double *g) { fmm_gather(ctx, b, g); }
static void gather_dense(void *ctx, const double *b, double *g) {
  DenseCtx *d = ctx;
  if (d->bits)
    dense_gather_bits(d->s, d->bits, b, g);
  else
    dense_gather(d->s, d->t, d->vis, b, g);
}

/* The point model of the Cornell box, or of examples/radiosity's two rooms
 * (about `room_faces` triangles) when room_faces > 0: sampled, ordered by
 * its octree. */
typedef struct Model {
  TriScene scene;
  Surfels s;
  Octree t;
  Visibility vis;
} Model;

static int model_new(Model *m, long n, int leaf, long room_faces) {
  memset(m, 0, sizeof *m);
  char err[512];
  if (room_faces > 0 && scene_rooms(&m->scene, room_faces, err, sizeof err) != 0) {
    fprintf(stderr, "npg-points: the two-room scene: %s\n", err);
    return -1;
  }
  if ((room_faces <= 0 && scene_cornell_box(&m->scene)) || scene_sample(&m->scene, n, 1, &m->s) ||
      octree_build(&m->s, leaf > 0 ? leaf : fmm_leaf_for(n), &m->t)) {
    fprintf(stderr, "npg-points: out of memory for %ld points\n", n);
    return -1;
  }
  visibility_init(&m->vis, &m->s, &m->t);
  return 0;
}

static void model_free(Model *m) {
  octree_free(&m->t), surfels_free(&m->s), triscene_free(&m->scene);
}

/* ------------------------------------------------------------ visibility against ray casting */

typedef struct VisAgreement {
  double hier, point;  /* agreement with ray casting by form-factor weight */
  long targets, pairs; /* targets sampled, pairs weighed */
  double seconds_rays;
} VisAgreement;

/* For `ntargets` targets spread over the points and every source: weigh
 * each pair by K(x_i, y_j) w_j and compare the hierarchical visibility
 * (the leaf table of the plan) and the point–point test with Embree. */
static int vis_agreement(const Model *m, const RayCaster *rc, const float *leaf_vis, int ntargets, int point_targets,
                         VisAgreement *out) {
  const Surfels *s = &m->s;
  long n = s->n, nl = m->t.nleaf;
  long *leaf_of = malloc(sizeof(long) * (size_t)n);
  if (!leaf_of) return -1;
  for (long a = 0; a < nl; a++) {
    const OctNode *nd = &m->t.node[m->t.leaf[a]];
    for (long i = nd->start; i < nd->start + nd->count; i++) leaf_of[i] = a;
  }
  double w_all = 0, w_hier = 0, w_pt_all = 0, w_pt = 0, t_rays = 0;
  for (int k = 0; k < ntargets; k++) {
    long i = (long)(((double)k + 0.5) / ntargets * (double)n);
    int stride = ntargets / (point_targets > 1 ? point_targets : 1), with_point = k % (stride > 1 ? stride : 1) == 0;
    double t0 = now_seconds(), wa = 0, wh = 0, wpa = 0, wp = 0;
#pragma omp parallel for schedule(dynamic, 256) reduction(+ : wa, wh, wpa, wp)
    for (long j = 0; j < n; j++) {
      double kw = s->w[j] * kernel_ff(s->x[i], s->y[i], s->z[i], s->nx[i], s->ny[i], s->nz[i], s->x[j], s->y[j],
                                      s->z[j], s->nx[j], s->ny[j], s->nz[j], s->w[j]);
      if (kw <= 0) continue;
      int ray = raycast_points(rc, s, i, j);
      double hv = leaf_vis ? leaf_vis[leaf_of[i] * nl + leaf_of[j]] : 1;
      wa += kw, wh += kw * (1 - fabs(hv - ray));
      if (with_point) wpa += kw, wp += kw * (visibility_points(&m->vis, i, j) == ray);
    }
    t_rays += now_seconds() - t0;
    w_all += wa, w_hier += wh, w_pt_all += wpa, w_pt += wp;
  }
  free(leaf_of);
  out->hier = w_all > 0 ? w_hier / w_all : 1;
  out->point = w_pt_all > 0 ? w_pt / w_pt_all : 1;
  out->targets = ntargets, out->pairs = (long)ntargets * n;
  out->seconds_rays = t_rays;
  return 0;
}

/* ------------------------------------------------------------ arguments */

typedef struct Options {
  long points;
  const char *out;
  int p, leaf, max_iter, vis_targets, point_targets, no_visibility;
  long check_points, dense_limit;
  double tol;
  const char *points_list, *orders_list, *error_points_list;
  long room_faces;        /* --scene rooms: examples/radiosity's two rooms at about this many faces; 0: the Cornell box */
} Options;

/* The numbers of a comma-separated list (--points, --orders, --error-points),
 * each a whole number in [lo, hi], at most `cap`: their count, or -1 with the
 * message (naming the option and the entry). */
static int parse_list(const char *opt, const char *text, long lo, long hi, double *out, int cap) {
  int n = 0;
  char buf[1024], err[256];
  snprintf(buf, sizeof buf, "%s", text);
  /* Split by hand: strtok would drop an empty entry ("200,,300") without a word. */
  for (char *tok = buf, *next = NULL; buf[0] && tok; tok = next) {
    long v;
    if ((next = strchr(tok, ','))) *next++ = '\0';
    if (!tok[0]) {
      fprintf(stderr, "npg-points: %s: entry %d is empty in '%s'\n", opt, n + 1, text);
      return -1;
    }
    if (n == cap) {
      fprintf(stderr, "npg-points: %s: at most %d entries\n", opt, cap);
      return -1;
    }
    if (npg_parse_long(tok, lo, hi, &v, err, sizeof err) != 0) {
      fprintf(stderr, "npg-points: %s: entry %d: %s\n", opt, n + 1, err);
      return -1;
    }
    out[n++] = (double)v;
  }
  if (n == 0) fprintf(stderr, "npg-points: %s: an empty list\n", opt);
  return n ? n : -1;
}

static int parse_options(int argc, char **argv, Options *o) {
  *o = (Options){.points = 20000, .out = NULL, .p = 4, .leaf = 0 /* by N: fmm_leaf_for */, .max_iter = 60, .vis_targets = 48,
                 .point_targets = 8, .check_points = 3000, .dense_limit = 60000, .tol = 1e-4,
                 .points_list = "2000,5000,10000,20000,50000,110528,300000,1000000", .orders_list = "2,3,4,5,6", .error_points_list = "5000,20000"};
  int rooms = 0, faces_given = 0;
  long faces = 2000;
  bool sweep = !strcmp(argv[1], "sweep");
  char prog[32];
  snprintf(prog, sizeof prog, "npg-points %s", argv[1]);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, prog);
  while (npg_args_next(&a)) {
    const char *v;
    if ((v = npg_args_string(&a, "--points"))) {
      char err[256];
      if (strchr(v, ',') || sweep) o->points_list = v;
      else if (npg_parse_long(v, 100, 10000000, &o->points, err, sizeof err) != 0)
        snprintf(a.error, sizeof a.error, "%s: --points: %s", prog, err);
    } else if ((v = npg_args_string(&a, "--out"))) o->out = v;
    else if (npg_args_int(&a, "--p", 2, 8, &o->p)) ;
    else if ((v = npg_args_string(&a, "--orders"))) o->orders_list = v;
    else if ((v = npg_args_string(&a, "--error-points"))) o->error_points_list = v;
    else if (npg_args_int(&a, "--leaf", 4, 1000000, &o->leaf)) ;
    else if ((v = npg_args_string(&a, "--visibility"))) {
      if (strcmp(v, "on") && strcmp(v, "off"))
        snprintf(a.error, sizeof a.error, "%s: --visibility is on or off, not '%s'", prog, v);
      o->no_visibility = !strcmp(v, "off");
    } else if (npg_args_double(&a, "--tol", 0, 1, true, &o->tol)) ;
    else if (npg_args_int(&a, "--max-iter", 1, 1000000, &o->max_iter)) ;
    else if (npg_args_int(&a, "--vis-targets", 1, 1000000, &o->vis_targets)) ;
    else if (npg_args_long(&a, "--check-points", 0, 10000000, &o->check_points)) ;
    else if (npg_args_long(&a, "--dense-limit", 0, 100000000, &o->dense_limit)) ;
    else if ((v = npg_args_string(&a, "--scene"))) {
      if (strcmp(v, "box") && strcmp(v, "rooms"))
        snprintf(a.error, sizeof a.error, "%s: --scene '%s': the scenes are box (the Cornell box) and rooms "
                 "(examples/radiosity)", prog, v);
      rooms = !strcmp(v, "rooms");
    } else if (npg_args_long(&a, "--faces", 1, 100000, &faces)) faces_given = 1;
    else npg_args_unknown(&a);
  }
  if (a.error[0]) {
    fprintf(stderr, "%s\n", a.error);
    return -1;
  }
  double list[32];
  if (parse_list("--points", o->points_list, 100, 10000000, list, 32) < 0 ||
      parse_list("--orders", o->orders_list, 2, 8, list, 16) < 0 ||
      parse_list("--error-points", o->error_points_list, 100, 10000000, list, 8) < 0)
    return -1;
  if (!o->out) {
    fprintf(stderr, "npg-points: --out DIR is required\n");
    return -1;
  }
  if (faces_given && !rooms) {
    fprintf(stderr, "npg-points: --faces sets the size of --scene rooms; the Cornell box has a fixed mesh\n");
    return -1;
  }
  o->room_faces = rooms ? faces : 0;
  char err[512];
  if (util_make_dirs(o->out, err, sizeof err) != 0) {
    fprintf(stderr, "npg-points: --out: %s\n", err);
    return -1;
  }
  return 0;
}

static int write_npy(const char *dir, const char *name, int ndim, const long *shape, const double *data) {
  char path[4096], err[512];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  if (npg_npy_write(path, ndim, shape, data, err, sizeof err)) {
    fprintf(stderr, "npg-points: %s\n", err);
    return -1;
  }
  return 0;
}

static void out_path(char *buf, size_t len, const char *dir, const char *name) { snprintf(buf, len, "%s/%s", dir, name); }

/* ------------------------------------------------------------ the cost of point visibility in b */

typedef struct VisCost {
  long n;
  double b_difference; /* ‖b_point − b_ray‖ / ‖b_ray‖, both by dense gathers */
  int iterations;
} VisCost;

/* A smaller model of the same box solved twice by dense gathers: with the
 * hierarchical point visibility of its FMM plan and with Embree's exact
 * visibility for every pair. */
static int vis_cost(long n, const Options *o, VisCost *out, double **b_point_out, double **b_ray_out, Model *mout) {
  Model *m = mout;
  if (model_new(m, n, o->leaf, o->room_faces)) return -1;
  Fmm f;
  if (fmm_plan(&f, &m->s, &m->t, o->p, &m->vis)) return -1;
  float *table = fmm_leaf_visibility(&f);
  size_t nbits = (size_t)n * (size_t)n;
  unsigned char *bits = calloc((nbits + 7) / 8, 1);
  double *b_point = malloc(sizeof(double) * 3 * (size_t)n), *b_ray = malloc(sizeof(double) * 3 * (size_t)n);
  RayCaster rc;
  if (!table || !bits || !b_point || !b_ray || raycast_open(&rc, &m->scene)) {
    fmm_free(&f), free(table), free(bits), free(b_point), free(b_ray);
    return -1;
  }
#pragma omp parallel for schedule(dynamic, 16)
  for (long i = 0; i < n; i++)
    for (long j = 0; j < n; j++) {
      size_t bit = (size_t)i * (size_t)n + (size_t)j;
      if (raycast_points(&rc, &m->s, i, j)) {
#pragma omp atomic
        bits[bit >> 3] |= (unsigned char)(1u << (bit & 7));
      }
    }
  raycast_close(&rc);
  DenseCtx dp = {&m->s, &m->t, table, NULL}, dr = {&m->s, &m->t, NULL, bits};
  radiosity_jacobi(&m->s, gather_dense, &dp, o->tol * 0.1, o->max_iter, b_point);
  out->iterations = radiosity_jacobi(&m->s, gather_dense, &dr, o->tol * 0.1, o->max_iter, b_ray);
  out->n = n;
  out->b_difference = rel_error(b_point, b_ray, 3 * n);
  fmm_free(&f), free(table), free(bits);
  *b_point_out = b_point, *b_ray_out = b_ray;
  return 0;
}

/* ------------------------------------------------------------ demo */

static int demo(const Options *o) {
  Model m;
  double t0 = now_seconds();
  if (model_new(&m, o->points, o->leaf, o->room_faces)) return 1;
  const Surfels *s = &m.s;
  long n = s->n;
  double t_model = now_seconds() - t0;
  printf("npg-points: %ld surfels, octree of %d nodes, %d leaves of up to %d points%s, depth %d (%.2f s)\n", n,
         m.t.nnode, m.t.nleaf, m.t.leaf_size, o->leaf ? "" : " (chosen by N)", m.t.depth, t_model);

  Fmm f;
  if (fmm_plan(&f, s, &m.t, o->p, o->no_visibility ? NULL : &m.vis)) {
    fprintf(stderr, "npg-points: out of memory planning the FMM\n");
    return 1;
  }
  printf("plan with visibility: %.2f s (%ld point-point tests); M2L %ld (%ld matrices), M2P %ld, P2L %ld, P2P %ld "
         "(%ld point pairs), dropped %ld facing %ld hidden\n",
         f.stats.plan_seconds, f.stats.visibility_tests, f.stats.m2l, f.stats.m2l_offsets, f.stats.m2p, f.stats.p2l,
         f.stats.p2p, f.stats.p2p_points, f.stats.dropped_facing, f.stats.dropped_hidden);
  char fallback[512];
  int direct = fmm_falls_back(&f, fallback, sizeof fallback);
  if (direct) printf("npg-points: %s\n", fallback);

  double *b = malloc(sizeof(double) * 3 * (size_t)n), *g = malloc(sizeof(double) * 3 * (size_t)n);
  double *g_dense = malloc(sizeof(double) * 3 * (size_t)n), *b_dense = malloc(sizeof(double) * 3 * (size_t)n);
  if (!b || !g || !g_dense || !b_dense) return 1;

  t0 = now_seconds();
  int iters = radiosity_jacobi(s, gather_fmm, &f, o->tol, o->max_iter, b);
  double t_fmm_solve = now_seconds() - t0;
  /* one gather, timed on the converged b */
  int reps = n > 300000 ? 1 : 3;
  t0 = now_seconds();
  for (int r = 0; r < reps; r++) fmm_gather(&f, b, g);
  double t_fmm = (now_seconds() - t0) / reps;
  printf("FMM: %d Jacobi iterations in %.2f s; one gather %.3f s\n", iters, t_fmm_solve, t_fmm);

  int dense = n <= o->dense_limit;
  float *table = dense || n <= 250000 ? fmm_leaf_visibility(&f) : NULL;
  double t_dense = -1, err_gather = -1, err_b = -1;
  int iters_dense = 0;
  if (dense && table) {
    DenseCtx dc = {s, &m.t, table, NULL};
    t0 = now_seconds();
    dense_gather(s, &m.t, table, b, g_dense);
    t_dense = now_seconds() - t0;
    err_gather = rel_error(g, g_dense, 3 * n);
    iters_dense = radiosity_jacobi(s, gather_dense, &dc, o->tol, o->max_iter, b_dense);
    err_b = rel_error(b, b_dense, 3 * n);
    printf("dense: one gather %.3f s; FMM gather error %.2e, converged b error %.2e (%d iterations)\n", t_dense,
           err_gather, err_b, iters_dense);
  }

  /* visibility against ray casting */
  VisAgreement agree = {0};
  RayCaster rc;
  if (raycast_open(&rc, &m.scene) == 0) {
    vis_agreement(&m, &rc, table, o->vis_targets, o->point_targets, &agree);
    raycast_close(&rc);
    printf("visibility agreement with ray casting by form-factor weight: hierarchical %.4f, point-point %.4f "
           "(%d targets x %ld sources)\n",
           agree.hier, agree.point, o->vis_targets, n);
  }
  VisCost cost = {0};
  double *bp = NULL, *br = NULL;
  Model mc;
  memset(&mc, 0, sizeof mc);
  if (o->check_points > 0 && vis_cost(o->check_points, o, &cost, &bp, &br, &mc) == 0)
    printf("cost of point visibility in b at N = %ld: ‖b_point − b_ray‖/‖b_ray‖ = %.4f\n", cost.n, cost.b_difference);

  /* arrays, pictures, report */
  char path[4096];
  long shape[2] = {n, 3};
  int rc_out = write_npy(o->out, "b.npy", 2, shape, b);
  if (dense) rc_out |= write_npy(o->out, "b_dense.npy", 2, shape, b_dense);
  double *pts = malloc(sizeof(double) * 7 * (size_t)n);
  if (pts) {
    for (long i = 0; i < n; i++) {
      double row[7] = {s->x[i], s->y[i], s->z[i], s->nx[i], s->ny[i], s->nz[i], s->w[i]};
      memcpy(pts + 7 * i, row, sizeof row);
    }
    long sh7[2] = {n, 7};
    rc_out |= write_npy(o->out, "points.npy", 2, sh7, pts);
    free(pts);
  }
  double exposure = 1.6;
  out_path(path, sizeof path, o->out, "radiosity.png");
  rc_out |= render_radiosity(s, b, exposure, 640, path);
  if (dense) {
    out_path(path, sizeof path, o->out, "fmm_vs_dense.png");
    rc_out |= render_comparison(s, b, b_dense, exposure, 480, path, "FMM", "dense O(N^2), same visibility");
  }
  if (bp && br) {
    out_path(path, sizeof path, o->out, "point_vs_ray_visibility.png");
    rc_out |= render_comparison(&mc.s, bp, br, exposure, 480, path, "point-based visibility", "ray casting (Embree)");
  }

  Report rep;
  if (report_open(&rep, "npg-points", o->out) != 0) return 1;
  FILE *js = rep.f;
  fprintf(js, "{\n  \"scene\": \"%s\",\n  \"faces\": %d,\n  \"N\": %ld,\n  \"p\": %d,\n  \"s\": %d,\n",
          o->room_faces ? "two_rooms" : "cornell_box", m.scene.nt, n, o->p, m.t.leaf_size);
  fprintf(js, "  \"octree\": {\"nodes\": %d, \"leaves\": %d, \"depth\": %d},\n", m.t.nnode, m.t.nleaf, m.t.depth);
  fprintf(js, "  \"tol\": %g,\n  \"iterations\": %d,\n  \"iterations_dense\": %d,\n", o->tol, iters, iters_dense);
  fprintf(js, "  \"error_vs_dense\": {\"gather\": %.6e, \"b\": %.6e},\n", err_gather, err_b);
  fprintf(js, "  \"gather_seconds\": {\"fmm\": %.6f, \"brute_force\": %.6f},\n", t_fmm, t_dense);
  fprintf(js, "  \"solve_seconds_fmm\": %.4f,\n", t_fmm_solve);
  fprintf(js, "  \"visibility_seconds\": %.4f,\n", f.stats.plan_seconds);
  fprintf(js, "  \"visibility_tests\": %ld,\n", f.stats.visibility_tests);
  fprintf(js,
          "  \"visibility_agreement\": {\"hierarchical\": %.6f, \"point_point\": %.6f, \"targets\": %ld, "
          "\"pairs\": %ld, \"ray_seconds\": %.3f},\n",
          agree.hier, agree.point, agree.targets, agree.pairs, agree.seconds_rays);
  fprintf(js, "  \"visibility_cost_in_b\": {\"N\": %ld, \"relative_difference\": %.6e},\n", cost.n, cost.b_difference);
  fprintf(js,
          "  \"lists\": {\"m2l\": %ld, \"m2l_matrices\": %ld, \"m2p\": %ld, \"p2l\": %ld, \"p2p\": %ld, "
          "\"p2p_point_pairs\": %ld, \"dropped_facing\": %ld, \"dropped_hidden\": %ld},\n"
          "  \"falls_back_to_direct_sums\": %s\n}\n",
          f.stats.m2l, f.stats.m2l_offsets, f.stats.m2p, f.stats.p2l, f.stats.p2p, f.stats.p2p_points,
          f.stats.dropped_facing, f.stats.dropped_hidden, direct ? "true" : "false");
  if (report_commit(&rep, "npg-points") != 0) rc_out = -1;
  printf("wrote %s/report.json, b.npy, PNGs\n", o->out);

  free(b), free(g), free(g_dense), free(b_dense), free(table), free(bp), free(br);
  fmm_free(&f);
  model_free(&m);
  if (mc.s.n) model_free(&mc);
  return rc_out ? 1 : 0;
}


/* ------------------------------------------------------------ sweep */

/* Seconds of one gather (the best of a few when short), wall and CPU. */
static double time_gather(GatherFn fn, void *ctx, const double *b, double *g, int max_reps, double *cpu) {
  double best = INFINITY, best_cpu = INFINITY, total = 0;
  for (int r = 0; r < max_reps && total < 2.0; r++) {
    double t0 = now_seconds(), c0 = cpu_seconds();
    fn(ctx, b, g);
    double dt = now_seconds() - t0, dc = cpu_seconds() - c0;
    best = fmin(best, dt), best_cpu = fmin(best_cpu, dc), total += dt;
  }
  *cpu = best_cpu;
  return best;
}

static int sweep(const Options *o) {
  double ns[32], ps[16], ens[8];
  /* checked by parse_options */
  int nn = parse_list("--points", o->points_list, 100, 10000000, ns, 32);
  int np = parse_list("--orders", o->orders_list, 2, 8, ps, 16);
  int ne = parse_list("--error-points", o->error_points_list, 100, 10000000, ens, 8);
  char path[4096];
  out_path(path, sizeof path, o->out, "sweep.json");
  FILE *js = fopen(path, "w");
  if (!js) return 1;
  fprintf(js, "{\n  \"scene\": \"%s\", \"s\": %d, \"tol\": %g,\n  \"error_vs_p\": [", o->room_faces ? "two_rooms" : "cornell_box",
          o->leaf /* 0: by N (fmm_leaf_for; each entry gives its leaf size) */, o->tol);

  /* error against p, with point-based visibility, the dense reference using
   * the plan's leaf-pair visibility (the same for every p) */
  double err_g[8][16], err_b[8][16];
  for (int e = 0; e < ne; e++) {
    long n = (long)ens[e];
    Model m;
    if (model_new(&m, n, o->leaf, o->room_faces)) return 1;
    double *b = malloc(sizeof(double) * 3 * (size_t)n), *g = malloc(sizeof(double) * 3 * (size_t)n);
    double *gd = malloc(sizeof(double) * 3 * (size_t)n), *bd = malloc(sizeof(double) * 3 * (size_t)n);
    double *b1 = malloc(sizeof(double) * 3 * (size_t)n);
    float *table = NULL;
    for (int k = 0; k < np; k++) {
      Fmm f;
      if (fmm_plan(&f, &m.s, &m.t, (int)ps[k], &m.vis)) return 1;
      if (!table) { /* the reference: one gather of b1 = e + ρ g(e), and the converged b */
        table = fmm_leaf_visibility(&f);
        DenseCtx dc = {&m.s, &m.t, table, NULL};
        radiosity_jacobi(&m.s, gather_dense, &dc, 0, 1, b1);
        dense_gather(&m.s, &m.t, table, b1, gd);
        radiosity_jacobi(&m.s, gather_dense, &dc, o->tol * 0.01, o->max_iter, bd);
      }
      fmm_gather(&f, b1, g);
      err_g[e][k] = rel_error(g, gd, 3 * n);
      int it = radiosity_jacobi(&m.s, gather_fmm, &f, o->tol * 0.01, o->max_iter, b);
      err_b[e][k] = rel_error(b, bd, 3 * n);
      printf("error: N = %ld, p = %d: gather %.3e, converged b %.3e (%d iterations), %ld M2L\n", n, (int)ps[k],
             err_g[e][k], err_b[e][k], it, f.stats.m2l);
      fprintf(js, "%s\n    {\"N\": %ld, \"p\": %d, \"gather\": %.6e, \"b\": %.6e, \"iterations\": %d}",
              e + k ? "," : "", n, (int)ps[k], err_g[e][k], err_b[e][k], it);
      fflush(js);
      fmm_free(&f);
    }
    free(b), free(g), free(gd), free(bd), free(b1), free(table);
    model_free(&m);
  }
  fprintf(js, "\n  ],\n  \"time_vs_n\": [");

  /* time of one gather against N: FMM (p = --p) and the brute force */
  double t_fmm[32], t_brute[32], vis_s[32], c_fmm[32], c_brute[32];
  for (int k = 0; k < nn; k++) {
    long n = (long)ns[k];
    Model m;
    if (model_new(&m, n, o->leaf, o->room_faces)) return 1;
    int with_vis = n <= 120000;
    Fmm f;
    if (fmm_plan(&f, &m.s, &m.t, o->p, with_vis ? &m.vis : NULL)) return 1;
    vis_s[k] = f.stats.plan_seconds;
    double *b = malloc(sizeof(double) * 3 * (size_t)n), *g = malloc(sizeof(double) * 3 * (size_t)n);
    radiosity_jacobi(&m.s, gather_fmm, &f, 0, 1, b);
    t_fmm[k] = time_gather(gather_fmm, &f, b, g, 5, &c_fmm[k]);
    t_brute[k] = c_brute[k] = -1;
    float *table = NULL;
    if (n <= o->dense_limit && (table = fmm_leaf_visibility(&f))) {
      DenseCtx dc = {&m.s, &m.t, table, NULL};
      t_brute[k] = time_gather(gather_dense, &dc, b, g, 3, &c_brute[k]);
    }
    printf("time: N = %ld: FMM gather %.4f s (CPU %.4f s), brute force %.4f s (CPU %.4f s); plan%s %.2f s%s\n", n,
           t_fmm[k], c_fmm[k], t_brute[k], c_brute[k], with_vis ? " with visibility" : "", vis_s[k],
           fmm_falls_back(&f, NULL, 0) ? " (no expansions: direct sums)" : "");
    fprintf(js,
            "%s\n    {\"N\": %ld, \"fmm_seconds\": %.6f, \"fmm_cpu_seconds\": %.6f, \"brute_force_seconds\": %.6f, "
            "\"brute_force_cpu_seconds\": %.6f, \"visibility\": %s, \"plan_seconds\": %.4f, \"m2l\": %ld, "
            "\"p2p_point_pairs\": %ld, \"leaf\": %d}",
            k ? "," : "", n, t_fmm[k], c_fmm[k], t_brute[k], c_brute[k], with_vis ? "true" : "false", vis_s[k],
            f.stats.m2l, f.stats.p2p_points, m.t.leaf_size);
    fflush(js);
    free(b), free(g), free(table);
    fmm_free(&f);
    model_free(&m);
  }
  /* break-even: where the brute force's CPU time crosses the FMM's
   * (log–log; CPU time, because the cores are shared with other work) */
  double breakeven = -1;
  for (int k = 0; k < nn; k++) {
    if (c_brute[k] <= 0) break;
    if (c_brute[k] >= c_fmm[k]) {
      if (k == 0) breakeven = 0; /* the FMM already wins at the smallest N */
      else {
        double a0 = log(c_brute[k - 1] / c_fmm[k - 1]), a1 = log(c_brute[k] / c_fmm[k]);
        breakeven = exp(log(ns[k - 1]) + (log(ns[k]) - log(ns[k - 1])) * (-a0) / (a1 - a0));
      }
      break;
    }
  }
  fprintf(js, "\n  ],\n  \"p_for_timing\": %d,\n  \"break_even_N_cpu\": %.0f\n}\n", o->p, breakeven);
  fclose(js);
  if (breakeven == 0) printf("break-even: the FMM is faster at every N measured (from N = %.0f)\n", ns[0]);
  else printf("break-even N ≈ %.0f (CPU seconds)\n", breakeven);

  /* plots */
  double px[16];
  for (int k = 0; k < np; k++) px[k] = ps[k];
  PlotSeries se[16];
  char labels[16][64];
  int nse = 0;
  for (int e = 0; e < ne; e++) {
    snprintf(labels[nse], 64, "one gather, N = %.0f", ens[e]);
    se[nse] = (PlotSeries){labels[nse], np, px, err_g[e]}, nse++;
    snprintf(labels[nse], 64, "converged b, N = %.0f", ens[e]);
    se[nse] = (PlotSeries){labels[nse], np, px, err_b[e]}, nse++;
  }
  int rc = 0;
  out_path(path, sizeof path, o->out, "error_vs_p.png");
  if (ne > 0)
    rc |= render_plot(path, "FMM against dense (same point-based visibility)", "order p", "relative error", 0, se, nse);
  PlotSeries st[4] = {{"FMM, wall", nn, ns, t_fmm},
                      {"brute force (2 threads, AVX2), wall", nn, ns, t_brute},
                      {"FMM, CPU (both threads)", nn, ns, c_fmm},
                      {"brute force, CPU (both threads)", nn, ns, c_brute}};
  out_path(path, sizeof path, o->out, "time_vs_n.png");
  if (nn > 0)
    rc |= render_plot(path, "one gather (one Jacobi iteration), Cornell box, p = 4", "N (surfels)", "seconds", 1, st, 4);
  printf("wrote %s/sweep.json, error_vs_p.png, time_vs_n.png\n", o->out);
  return rc ? 1 : 0;
}

static int run(int argc, char **argv) {
  Options o;
  setvbuf(stdout, NULL, _IOLBF, 0); /* progress lines reach a log as they happen */
  if (argc < 2 || (strcmp(argv[1], "demo") && strcmp(argv[1], "sweep"))) {
    fprintf(stderr, "usage: npg-points demo --points N --out DIR [--p P] [--leaf S] [--tol T] [--scene box|rooms] [--faces F]\n"
                    "       npg-points sweep --out DIR [--points N1,N2,...] [--orders P1,P2,...]\n");
    return 2;
  }
  if (parse_options(argc, argv, &o)) return 2;
  int rc = !strcmp(argv[1], "demo") ? demo(&o) : sweep(&o);
  chart_cleanup(); /* cairo's and fontconfig's caches */
  return rc;
}

int main(int argc, char **argv) { return util_exit_status("npg-points", run(argc, argv)); }
