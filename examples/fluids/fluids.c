/* fluids.c — build/npg-fluids: the fluid solver of paper §5 on the deforming
 * periodic wind tunnel (§7.1), with marker particles (§6.5), PNG frames, VTK
 * files and full-space snapshots for training.
 *
 *   npg-fluids tunnel-full --out DIR [--frames N] [--cells N] [--size S] ...
 *   npg-fluids mesh [--cells N] [--size S]      mesh statistics as JSON
 *
 * Every run writes DIR/report.json (the figures), DIR/frames/frame_NNNN.png,
 * DIR/vtk/cells_NNNN.vtu and faces_NNNN.vtu with cells.pvd and faces.pvd (ParaView), and DIR/data/: the
 * params of fluids2d.npg (tri, edge, cface, csign, nbr, bface, mu) and the
 * per-frame inputs g, gdot, f, u with the induced fluxes h and the midpoint
 * geometry gmid they were evaluated at, one sample per frame (leading axis),
 * as .npy — the layout `npgc train` reads.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include <cblas.h>

#include "util.h"
#include "npgbind.h"
#include "output.h"
#include "plot.h"
#include "particles.h"
#include "solver.h"
#include "tunnel.h"
#include "cavitysim.h"

#define ERRLEN 512

/* Bounds of the sizes a command line can ask for, so that a typo (--frames
 * 1e8) is refused before it asks for terabytes: 100,000 frames of the
 * default tunnel keep 5.3 GB of samples; a million cells is 500x the
 * default mesh; a PNG 8192 pixels wide holds 200 MB. */
#define FLUIDS_MAX_FRAMES 100000
#define FLUIDS_MAX_CELLS 1000000
#define FLUIDS_MAX_PARTICLES 10000000
#define FLUIDS_MAX_WIDTH 8192

typedef struct RunOptions {
  const char *out;
  int frames, particles, png_every, vtk_every, png_width;
  double scale, pulse, period, mu, cfl, u0;
  ProjectionMethod projection;
  TunnelSpec spec;
} RunOptions;

static void usage(FILE *fp) {
  fputs("usage: npg-fluids tunnel-full --out DIR [--frames N] [--cells N] [--size S]\n"
        "                  [--scale X] [--pulse A] [--period P] [--mu MU] [--cfl C] [--u0 U]\n"
        "                  [--particles N] [--png-every K] [--vtk-every K] [--width PX]\n"
        "                  [--projection stream|kkt]\n"
        "       npg-fluids tunnel --out DIR [--frames N] [--cells N] [--sizes 8,16,32,64,128]\n"
        "                  [--pulse A] [--period P] [--mu MU] [--cfl C] [--mg N] [--particles N]\n"
        "                  [--png-every K] [--vtk-every K] [--width PX] [--keep-models 0|1]\n"
        "       npg-fluids mesh [--cells N] [--size S]\n"
        "       npg-fluids cavity --out DIR [--cells N] [--frames N] [--runs N] [--dt DT] [--nu NU]\n"
        "                  [--mf N] [--mu N] [--mg N] [--dtol X] [--particles N] [--png-every K] [--vtk-every K]\n"
        "                  [--width PX] [--projection al|kkt] [--workers W] [--train-threads N]\n"
        "                  [--sample-every K] [--buffer-mb N] [--backend cc|tcc] [--particle-threads N]\n"
        "       npg-fluids cavity-mesh [--cells N]         the cavity's mesh statistics as JSON\n"
        "       npg-fluids cavity-projection [--cells N] [--steps N] [--method kkt|al|both]\n"
        "                  the full projection timed on the cavity (JSON)\n"
        "\n"
        "tunnel-full: full-space simulation of the periodic wind tunnel (paper §5, §7.1).\n"
        "  --frames N     steps, one per frame (200)\n"
        "  --cells N      target triangle count of the gmsh mesh (2000)\n"
        "  --size S       obstacle side length at rest, tunnel height 1 (0.3)\n"
        "  --scale X      mean obstacle scale, by deforming the --size mesh (1)\n"
        "  --pulse A      obstacle scale X + A sin(2 pi t / P): 0 keeps it fixed (0.2)\n"
        "  --period P     frames per pulse (100)\n"
        "  --mu MU        viscosity of the graph Laplacian (0.002)\n"
        "  --cfl C        dt = C * mean edge length / u0 (0.25)\n"
        "  --u0 U         initial uniform velocity along the tunnel, projected (1)\n"
        "  --particles N  marker particles, ten Euler substeps per frame (3000)\n"
        "  --png-every K, --vtk-every K   output every K frames (1, 10)\n"
        "  --projection M stream: CHOLMOD on the stream function (default); kkt: UMFPACK on\n"
        "                 the KKT system (the same minimizer)\n"
        "\n"
        "tunnel: paper Fig. 5. Full training runs with a large and a small obstacle (scales\n"
        "  1.25 and 0.75, each pulsing by A, default 0.05) streamed into npg trainers, one\n"
        "  model per basis size (--sizes: m_u; m_f = m_u / 2; --mg: cap of m_g, 5), a full\n"
        "  test run with a medium obstacle (1.0) and per frame the one-step error of every\n"
        "  model, the reduced test run of the largest model with particles; DIR/report.json,\n"
        "  DIR/plots/*.png, DIR/frames/frame_NNNN.png (full | reduced), DIR/vtk/*.vtu, *.pvd.\n"
        "  --frames N per run (300), --png-every and --vtk-every (25), --width (640)\n"
        "\n"
        "cavity: paper §7.2, Fig. 6, Table 1. The 3D cavity (a central chamber and three side\n"
        "  chambers joined by thin tunnels) tetrahedralized by gmsh (--cells, 20000); --runs full\n"
        "  training runs (14) of --frames frames each (by default 100 (cells/1000)^(1/3), at least\n"
        "  100: 260 at the default 17,300 cells) compressing and re-inflating one or\n"
        "  two side chambers, streamed into npg's trainer (caps --mf 64, --mu 128, --mg 5); the\n"
        "  test sequence (chamber 1 expanding while chamber 0 stays compressed) full and reduced,\n"
        "  --particles (10000) marker particles through the reduced flow; --dt (0.01), viscosity\n"
        "  mu = --nu (5) times the smallest cell's volume; --dtol (1e-2) the rank tolerance of the\n"
        "  reduced boundary constraints; DIR/report.json (Table 1), DIR/frames/*.png,\n"
        "  DIR/vtk/*.vtk (legacy VTK), DIR/plots/trajectory_error.png. --projection: al (default),\n"
        "  CHOLMOD on K + w D^T D with augmented Lagrangian iterations; kkt: UMFPACK on the KKT\n"
        "  system (the same minimizer). --workers W: threads running the training runs (the\n"
        "  online CPUs; 1: one run after the other); the trainer gets the same samples in the\n"
        "  same order for every W. --train-threads N: OpenBLAS's threads while training (W).\n"
        "  --sample-every K: every K-th frame of a training run is a sample (by default at most\n"
        "  120 samples per run: 1 up to 120 frames, 3 at 260, 4 at 450; the runs still take\n"
        "  every step). --buffer-mb N: bound on the samples of later runs waiting while the\n"
        "  trainer takes an earlier run's (2048). --backend: the trainer's full evaluator, compiled\n"
        "  by the system compiler (cc, default: its replays ran 2-3x faster here) or by libtcc (tcc).\n"
        "  --particle-threads N: threads advecting the particles (the online CPUs); the reduced\n"
        "  flow's particles also run on one thread, timed apart (t_pa_one_thread), and must move\n"
        "  the same bit for bit; they lift only the faces of the cells they reach (paper 6.5).\n",
        fp);
}

/* The physical parameters every command shares, refused with the reason when
 * a run with them could only blow up or mean nothing: a negative viscosity
 * amplifies every mode (anti-diffusion); a CFL number above 1 moves the flow
 * more than an edge per step, beyond what the explicit RK4 advection step
 * can follow (measured on the default tunnel: 0.45 ran 200 frames, 0.5 was
 * not finite by frame 7). Smaller values can still be unstable (explicit
 * diffusion limits the step too): the runs stop when the energy blows up
 * (solver_check_energy). */
static bool physical(NpgArgs *a, double *mu, double *cfl) {
  if (npg_args_double(a, "--mu", -INFINITY, INFINITY, false, mu)) {
    if (!a->error[0] && !(*mu >= 0 && *mu <= 10))
      snprintf(a->error, sizeof a->error, "%s: --mu %g: the viscosity is in [0, 10]%s", a->prog, *mu,
               *mu < 0 ? " (a negative one amplifies every mode of the flow: anti-diffusion, the run blows up)" : "");
    return true;
  }
  if (npg_args_double(a, "--cfl", -INFINITY, INFINITY, false, cfl)) {
    if (!a->error[0] && !(*cfl > 0 && *cfl <= 1))
      snprintf(a->error, sizeof a->error, "%s: --cfl %g: the CFL number is in (0, 1]%s", a->prog, *cfl,
               *cfl > 1 ? " (above 1 the flow crosses more than an edge per step, which the explicit RK4 advection "
                          "cannot follow: the run blows up)" : "");
    return true;
  }
  return false;
}

/* The message of a parser's first problem, and 2; 0 when there was none. */
static int args_status(const NpgArgs *a) {
  if (!a->error[0]) return 0;
  fprintf(stderr, "%s\n", a->error);
  return 2;
}

static int parse_options(int argc, char **argv, RunOptions *o) {
  *o = (RunOptions){.frames = 200, .particles = 3000, .png_every = 1, .vtk_every = 10, .png_width = 800,
                    .scale = 1, .pulse = 0.2, .period = 100, .mu = 0.002, .cfl = 0.25, .u0 = 1, .projection = PROJ_STREAM_CHOLMOD,
                    .spec = tunnel_spec_default()};
  char prog[48];
  snprintf(prog, sizeof prog, "npg-fluids %s", argv[1]);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, prog);
  while (npg_args_next(&a)) {
    const char *v;
    if ((v = npg_args_string(&a, "--out"))) o->out = v;
    else if (npg_args_int(&a, "--frames", 1, FLUIDS_MAX_FRAMES, &o->frames)) ;
    else if (npg_args_int(&a, "--cells", 50, FLUIDS_MAX_CELLS, &o->spec.cells)) ;
    else if (npg_args_int(&a, "--particles", 0, FLUIDS_MAX_PARTICLES, &o->particles)) ;
    else if (npg_args_int(&a, "--png-every", 1, 1000000, &o->png_every)) ;
    else if (npg_args_int(&a, "--vtk-every", 1, 1000000, &o->vtk_every)) ;
    else if (npg_args_int(&a, "--width", 16, FLUIDS_MAX_WIDTH, &o->png_width)) ;
    else if (npg_args_double(&a, "--size", 0, 0.9, true, &o->spec.size)) ;
    else if (npg_args_double(&a, "--scale", 0, 10, true, &o->scale)) ;
    else if (npg_args_double(&a, "--pulse", 0, 10, false, &o->pulse)) ;
    else if (npg_args_double(&a, "--period", 0, 1e9, true, &o->period)) ;
    else if (physical(&a, &o->mu, &o->cfl)) ;
    else if (npg_args_double(&a, "--u0", 0, 100, true, &o->u0)) ;
    else if ((v = npg_args_string(&a, "--projection"))) {
      if (!strcmp(v, "stream")) o->projection = PROJ_STREAM_CHOLMOD;
      else if (!strcmp(v, "kkt")) o->projection = PROJ_KKT_UMFPACK;
      else snprintf(a.error, sizeof a.error, "%s: --projection is stream or kkt, not '%s'", prog, v);
    } else npg_args_unknown(&a);
  }
  if (!a.error[0] && o->pulse >= o->scale)
    snprintf(a.error, sizeof a.error, "%s: --pulse %g must stay below --scale %g (the obstacle's scale X + A sin(...) "
             "would reach 0)", prog, o->pulse, o->scale);
  return args_status(&a) ? -1 : 0;
}

static int make_dir(const char *path) {
  char err[ERRLEN];
  if (util_make_dirs(path, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return -1;
  }
  return 0;
}

/* Obstacle scale of frame t: the mesh is always gmsh's mesh at --size, deformed
 * (so runs with different --scale share one topology, as paper Fig. 5's
 * training and test runs must). */
static double sigma_at(const RunOptions *o, int frame) {
  return o->scale + o->pulse * sin(2 * M_PI * frame / o->period);
}

/* FNV-1a of the topology and rest positions: equal hashes, same mesh. */
static unsigned long long mesh_hash(const Mesh *m) {
  unsigned long long h = 1469598103934665603ull;
  const unsigned char *p[2] = {(const unsigned char *)m->cell, (const unsigned char *)m->g0};
  size_t n[2] = {3 * (size_t)m->nc * sizeof *m->cell, 2 * (size_t)m->nv * sizeof *m->g0};
  for (int k = 0; k < 2; k++)
    for (size_t i = 0; i < n[k]; i++) h = (h ^ p[k][i]) * 1099511628211ull;
  return h;
}

/* ---------------------------------------------------------------- data/ */

/* What an array holds: doubles, or ints (written as int64, as npg reads
 * int params). */
typedef enum SaveType { SAVE_F64, SAVE_INT } SaveType;

static int save(const char *dir, const char *name, SaveType type, int ndim, const long *shape, const void *data) {
  char path[4096], err[ERRLEN];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  int rc;
  if (type == SAVE_F64) {
    rc = npg_npy_write(path, ndim, shape, data, err, sizeof err);
  } else {
    size_t n = 1;
    for (int i = 0; i < ndim; i++) n *= (size_t)shape[i];
    long *v = malloc(sizeof(long) * (n ? n : 1));
    if (!v) {
      fprintf(stderr, "npg-fluids: out of memory writing %s\n", path);
      return -1;
    }
    for (size_t i = 0; i < n; i++) v[i] = ((const int *)data)[i];
    rc = npg_npy_write_i64(path, ndim, shape, v, err, sizeof err);
    free(v);
  }
  if (rc != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return -1;
  }
  return 0;
}

/* The params of fluids2d.npg, named as its `param`s. */
static int save_params(const char *dir, const Mesh *m, double mu) {
  long c3[2] = {m->nc, 3}, f2[2] = {m->nf, 2}, b1[1] = {m->nb};
  int rc = 0;
  rc |= save(dir, "tri", SAVE_INT, 2, c3, m->cell);
  rc |= save(dir, "edge", SAVE_INT, 2, f2, m->face);
  rc |= save(dir, "cface", SAVE_INT, 2, c3, m->cface);
  rc |= save(dir, "csign", SAVE_F64, 2, c3, m->csign);
  rc |= save(dir, "nbr", SAVE_INT, 2, c3, m->nbr);
  rc |= save(dir, "bface", SAVE_INT, 1, b1, m->bface);
  rc |= save(dir, "mu", SAVE_F64, 0, NULL, &mu);
  /* the flat velocity layout's params: ucell, ucomp, unbr */
  FluidParam p[FLUID_NPARAMS];
  fluid_params(m, mu, p);
  for (int i = 0; i < FLUID_NPARAMS; i++) {
    if (strncmp(p[i].name, "u", 1) != 0) continue;
    long n = p[i].shape[0] * (p[i].ndim == 2 ? p[i].shape[1] : 1);
    int *iv = malloc(n * sizeof *iv);
    for (long j = 0; j < n; j++) iv[j] = (int)p[i].v[j];
    rc |= save(dir, p[i].name, SAVE_INT, p[i].ndim, p[i].shape, iv);
    free(iv);
  }
  fluid_params_free(p);
  rc |= save(dir, "g0", SAVE_F64, 2, (long[]){m->nv, 2}, m->g0);
  rc |= save(dir, "fkind", SAVE_INT, 1, (long[]){m->nf}, m->fkind);
  return rc ? -1 : 0;
}

/* ---------------------------------------------------------------- report */

static void json_array(FILE *fp, const char *name, const double *v, int n, const char *tail) {
  fprintf(fp, "  \"%s\": [", name);
  for (int i = 0; i < n; i++) fprintf(fp, "%s%.10g", i ? ", " : "", v[i]);
  fprintf(fp, "]%s\n", tail);
}

/* ---------------------------------------------------------------- tunnel-full */

static int tunnel_full(const RunOptions *o) {
  char err[ERRLEN], path[4096], dir_frames[1100], dir_vtk[1100], dir_data[1100];
  if (!o->out) {
    fprintf(stderr, "npg-fluids: tunnel-full needs --out DIR\n");
    return 2;
  }
  if (strlen(o->out) > 1000) {
    fprintf(stderr, "npg-fluids: --out: path longer than 1000 bytes\n");
    return 2;
  }
  snprintf(dir_frames, sizeof dir_frames, "%s/frames", o->out);
  snprintf(dir_vtk, sizeof dir_vtk, "%s/vtk", o->out);
  snprintf(dir_data, sizeof dir_data, "%s/data", o->out);
  if (make_dir(o->out) || make_dir(dir_frames) || make_dir(dir_vtk) || make_dir(dir_data)) return 1;

  double t_mesh = util_now();
  Mesh m;
  if (mesh_tunnel(&m, &o->spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  t_mesh = util_now() - t_mesh;
  double dt = o->cfl * mesh_mean_edge(&m) / o->u0;
  fprintf(stderr, "npg-fluids: mesh %d cells, %d faces (%d boundary), %d vertices; dt %.4g, mu %g\n", m.nc, m.nf, m.nb,
          m.nv, dt, o->mu);

  FullSolver s;
  double u0[2] = {o->u0, 0};
  if (solver_init(&s, &m, o->projection, o->mu, dt, sigma_at(o, 0), u0, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    mesh_free(&m);
    return 1;
  }
  Particles part;
  if (particles_seed(&part, &m, s.g, o->particles, 12345) != 0) {
    fprintf(stderr, "npg-fluids: out of memory for %d particles: fewer --particles\n", o->particles);
    solver_free(&s);
    mesh_free(&m);
    return 1;
  }

  int T = o->frames;
  size_t gv = 2 * (size_t)m.nv, uv = 2 * (size_t)m.nc, fv = m.nf;
  double *Sg = malloc(T * gv * sizeof(double)), *Sgdot = malloc(T * gv * sizeof(double));
  double *Su = malloc(T * uv * sizeof(double)), *Sf = malloc(T * fv * sizeof(double));
  double *Sh = malloc(T * fv * sizeof(double)), *Sgmid = malloc(T * gv * sizeof(double));
  double *energy = malloc((T + 1) * sizeof(double)), *divergence = malloc((T + 1) * sizeof(double));
  double *quality = malloc((T + 1) * sizeof(double)), *sigmas = malloc((T + 1) * sizeof(double));
  double *flux_scale = malloc((T + 1) * sizeof(double));
  char **vtk_cells = calloc(T + 1, sizeof(char *)), **vtk_faces = calloc(T + 1, sizeof(char *));
  double *vtk_times = malloc((T + 1) * sizeof(double));
  int nvtk = 0, rc = 0;
  if (!Sg || !Sgdot || !Su || !Sf || !Sh || !Sgmid || !energy || !divergence || !quality || !sigmas || !flux_scale ||
      !vtk_cells || !vtk_faces || !vtk_times) {
    snprintf(err, sizeof err, "out of memory for %d frames of %d cells (%.3g GB of samples): fewer --frames or --cells",
             T, m.nc, (double)T * (3 * gv + uv + 2 * fv) * sizeof(double) / 1e9);
    rc = -1;
  }
  double seconds_particles = 0, seconds_output = 0, worst_quality = s.min_quality;
  int worst_quality_frame = 0;

  double maxf = 0;
  if (rc == 0) {
    energy[0] = solver_energy(&s);
    divergence[0] = projection_max_divergence(&s.ops, s.f);
    quality[0] = s.min_quality;
    sigmas[0] = s.sigma;
    for (int j = 0; j < m.nf; j++) maxf = fmax(maxf, fabs(s.f[j]));
    flux_scale[0] = maxf;
  }
  double t_run = util_now();
  for (int t = 0; t <= T && rc == 0; t++) {
    /* output of frame t (frames 0 .. T: the last one too, output_frame_due) */
    double t0 = util_now();
    if (output_frame_due(t, T, o->png_every)) {
      snprintf(path, sizeof path, "%s/frame_%04d.png", dir_frames, t);
      if (output_png(path, &m, s.g, s.u, &part, 1.6 * o->u0, o->png_width, err, sizeof err) != 0) rc = -1;
    }
    if (rc == 0 && output_frame_due(t, T, o->vtk_every)) {
      char name[64];
      snprintf(name, sizeof name, "cells_%04d.vtu", t);
      vtk_cells[nvtk] = strdup(name);
      snprintf(path, sizeof path, "%s/%s", dir_vtk, name);
      if (output_vtu_cells(path, &m, s.g, s.u, err, sizeof err) != 0) rc = -1;
      snprintf(name, sizeof name, "faces_%04d.vtu", t);
      vtk_faces[nvtk] = strdup(name);
      snprintf(path, sizeof path, "%s/%s", dir_vtk, name);
      if (rc == 0 && output_vtu_faces(path, &m, s.g, s.f, s.h, err, sizeof err) != 0) rc = -1;
      vtk_times[nvtk++] = t * dt;
    }
    seconds_output += util_now() - t0;
    if (rc || t == T) break;
    /* sample t: the state of frame t and the motion of the step that leaves it */
    memcpy(Sg + t * gv, s.g, gv * sizeof(double));
    memcpy(Su + t * uv, s.u, uv * sizeof(double));
    memcpy(Sf + t * fv, s.f, fv * sizeof(double));
    /* the step */
    if (solver_step(&s, sigma_at(o, t + 1), err, sizeof err) != 0) {
      rc = -1;
      break;
    }
    memcpy(Sgdot + t * gv, s.gdot, gv * sizeof(double));
    memcpy(Sh + t * fv, s.h, fv * sizeof(double));
    memcpy(Sgmid + t * gv, s.gmid, gv * sizeof(double));
    double t1 = util_now();
    particles_advect(&part, &m, s.g, s.f, dt, 10);
    seconds_particles += util_now() - t1;
    energy[t + 1] = solver_energy(&s);
    divergence[t + 1] = projection_max_divergence(&s.ops, s.f);
    quality[t + 1] = s.min_quality;
    sigmas[t + 1] = s.sigma;
    maxf = 0;
    for (int j = 0; j < m.nf; j++) maxf = fmax(maxf, fabs(s.f[j]));
    flux_scale[t + 1] = maxf;
    if (s.min_quality < worst_quality) worst_quality = s.min_quality, worst_quality_frame = t + 1;
    if (solver_check_energy(energy[0], energy[t + 1], t + 1, err, sizeof err) != 0) rc = -1;
  }
  t_run = util_now() - t_run;
  if (rc) fprintf(stderr, "npg-fluids: %s\n", err);

  if (rc == 0) {
    char e2[ERRLEN];
    snprintf(path, sizeof path, "%s/cells.pvd", dir_vtk);
    if (output_pvd(path, nvtk, (const char *const *)vtk_cells, vtk_times, e2, sizeof e2) != 0) rc = -1;
    snprintf(path, sizeof path, "%s/faces.pvd", dir_vtk);
    if (rc == 0 && output_pvd(path, nvtk, (const char *const *)vtk_faces, vtk_times, e2, sizeof e2) != 0) rc = -1;
    if (rc) fprintf(stderr, "npg-fluids: %s\n", e2);
  }
  if (rc == 0) {
    long sg[3] = {T, m.nv, 2}, su[2] = {T, 2 * (long)m.nc}, sf[2] = {T, m.nf};
    rc |= save_params(dir_data, &m, o->mu);
    rc |= save(dir_data, "g", SAVE_F64, 3, sg, Sg);
    rc |= save(dir_data, "gdot", SAVE_F64, 3, sg, Sgdot);
    rc |= save(dir_data, "u", SAVE_F64, 2, su, Su);
    rc |= save(dir_data, "f", SAVE_F64, 2, sf, Sf);
    rc |= save(dir_data, "h", SAVE_F64, 2, sf, Sh);
    rc |= save(dir_data, "gmid", SAVE_F64, 3, sg, Sgmid);
    rc |= save(dir_data, "energy", SAVE_F64, 1, (long[]){T + 1}, energy);
  }
  if (rc == 0) {
    double maxdiv = 0, maxdiv_rel = 0;
    for (int t = 0; t <= T; t++) {
      maxdiv = fmax(maxdiv, divergence[t]);
      maxdiv_rel = fmax(maxdiv_rel, divergence[t] / flux_scale[t]);
    }
    snprintf(path, sizeof path, "%s/report.json", o->out);
    FILE *fp = fopen(path, "w");
    if (!fp) {
      fprintf(stderr, "npg-fluids: %s: %s\n", path, strerror(errno));
      rc = -1;
    } else {
      double steps = T > 0 ? T : 1;
      fprintf(fp, "{\n  \"command\": \"tunnel-full\",\n");
      fprintf(fp, "  \"cells\": %d,\n  \"faces\": %d,\n  \"boundary_faces\": %d,\n  \"vertices\": %d,\n", m.nc, m.nf,
              m.nb, m.nv);
      fprintf(fp, "  \"tunnel\": {\"L\": %g, \"H\": %g, \"obstacle_center\": [%g, %g], \"obstacle_size\": %g},\n",
              m.spec.L, m.spec.H, m.spec.cx, m.spec.cy, m.spec.size);
      fprintf(fp, "  \"mesh_hash\": \"%016llx\",\n  \"scale\": %g,\n", mesh_hash(&m), o->scale);
      fprintf(fp, "  \"frames\": %d,\n  \"dt\": %.10g,\n  \"mu\": %g,\n  \"u0\": %g,\n  \"pulse\": %g,\n", T, dt,
              o->mu, o->u0, o->pulse);
      fprintf(fp, "  \"period_frames\": %g,\n  \"particles\": %d,\n", o->period, o->particles);
      fprintf(fp, "  \"mesh_seconds\": %.6g,\n  \"run_seconds\": %.6g,\n", t_mesh, t_run);
      fprintf(fp, "  \"projection_method\": \"%s\",\n", projection_method_name(o->projection));
      fprintf(fp, "  \"full_step_seconds\": {\"total\": %.6g, \"advection\": %.6g, \"projection\": %.6g, "
                  "\"projection_factorization\": %.6g, \"projection_solve\": %.6g, \"deformation\": %.6g},\n",
              (s.seconds_advection + s.seconds_projection + s.seconds_deformation) / steps,
              s.seconds_advection / steps, s.seconds_projection / steps, s.pr.seconds_numeric / steps,
              s.pr.seconds_solve / steps, s.seconds_deformation / steps);
      fprintf(fp, "  \"particle_seconds_per_frame\": %.6g,\n  \"output_seconds_per_frame\": %.6g,\n",
              seconds_particles / steps, seconds_output / steps);
      fprintf(fp, "  \"particle_walk_steps_per_frame\": %.6g,\n", part.walk_steps / steps);
      fprintf(fp, "  \"max_divergence\": %.6g,\n  \"max_divergence_relative_to_max_flux\": %.6g,\n", maxdiv,
              maxdiv_rel);
      fprintf(fp, "  \"min_element_quality\": %.6g,\n  \"min_element_quality_frame\": %d,\n", worst_quality,
              worst_quality_frame);
      fprintf(fp, "  \"energy_drift\": %.6g,\n", T > 0 ? energy[T] / energy[0] - 1 : 0.0);
      json_array(fp, "obstacle_scale", sigmas, T + 1, ",");
      json_array(fp, "min_quality", quality, T + 1, ",");
      json_array(fp, "max_divergence_per_frame", divergence, T + 1, ",");
      json_array(fp, "energy", energy, T + 1, "");
      fprintf(fp, "}\n");
      if (fclose(fp) != 0) rc = -1;
      fprintf(stderr,
              "npg-fluids: %d frames in %.2f s: step %.3g ms (advection %.3g, projection %.3g, deformation %.3g), "
              "particles %.3g ms/frame; energy %.6g -> %.6g; max divergence %.3g; min quality %.3f\n",
              T, t_run, 1e3 * (s.seconds_advection + s.seconds_projection + s.seconds_deformation) / steps,
              1e3 * s.seconds_advection / steps, 1e3 * s.seconds_projection / steps,
              1e3 * s.seconds_deformation / steps, 1e3 * seconds_particles / steps, energy[0], energy[T], maxdiv,
              worst_quality);
    }
  }
  for (int i = 0; i < nvtk; i++) free(vtk_cells[i]), free(vtk_faces[i]);
  free(vtk_cells);
  free(vtk_faces);
  free(vtk_times);
  free(Sg);
  free(Sgdot);
  free(Su);
  free(Sf);
  free(Sh);
  free(Sgmid);
  free(energy);
  free(divergence);
  free(quality);
  free(sigmas);
  free(flux_scale);
  particles_free(&part);
  solver_free(&s);
  mesh_free(&m);
  plot_cleanup(); /* the frames' colour bars (cairo, fontconfig) */
  return rc ? 1 : 0;
}

static int mesh_info(const RunOptions *o) {
  char err[ERRLEN];
  Mesh m;
  double t0 = util_now();
  if (mesh_tunnel(&m, &o->spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  double t1 = util_now();
  int walls = 0, obstacle = 0, periodic = 0;
  for (int j = 0; j < m.nf; j++) walls += m.fkind[j] == BF_WALL, obstacle += m.fkind[j] == BF_OBSTACLE;
  for (int i = 0; i < 3 * m.nc; i++) periodic += m.nshift[i] > 0;
  printf("{\"cells\": %d, \"faces\": %d, \"vertices\": %d, \"wall_faces\": %d, \"obstacle_faces\": %d, "
         "\"periodic_faces\": %d, \"min_quality\": %.4f, \"fluid_area\": %.12g, \"mesh_seconds\": %.4f}\n",
         m.nc, m.nf, m.nv, walls, obstacle, periodic, mesh_min_quality(&m, m.g0, NULL), mesh_fluid_volume(&m, m.g0),
         t1 - t0);
  mesh_free(&m);
  return 0;
}

/* ---------------------------------------------------------------- cavity */

static int cavity_cmd(int argc, char **argv) {
  CavityOptions o;
  cavity_options_default(&o);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npg-fluids cavity");
  while (npg_args_next(&a)) {
    const char *v;
    int mb;
    if ((v = npg_args_string(&a, "--out"))) o.out = v;
    else if (npg_args_double(&a, "--dtol", 0, 1, false, &o.dtol)) {
      if (!a.error[0] && o.dtol >= 1) snprintf(a.error, sizeof a.error, "npg-fluids cavity: --dtol is in [0, 1)");
    } else if (npg_args_int(&a, "--cells", 50, FLUIDS_MAX_CELLS, &o.spec.cells)) ;
    else if (npg_args_int(&a, "--frames", 2, FLUIDS_MAX_FRAMES, &o.frames)) ;
    else if (npg_args_int(&a, "--runs", 0, 14, &o.runs)) ;
    else if (npg_args_double(&a, "--dt", 0, 10, true, &o.dt)) ;
    else if (npg_args_double(&a, "--nu", 0, 1e6, false, &o.nu)) ;
    else if (npg_args_int(&a, "--mf", 2, 512, &o.mf)) ;
    else if (npg_args_int(&a, "--mu", 6, 512, &o.mu)) ;
    else if (npg_args_int(&a, "--mg", 1, 16, &o.mg)) ;
    else if (npg_args_int(&a, "--particles", 0, FLUIDS_MAX_PARTICLES, &o.particles)) ;
    else if (npg_args_int(&a, "--png-every", 1, 1000000, &o.png_every)) ;
    else if (npg_args_int(&a, "--vtk-every", 1, 1000000, &o.vtk_every)) ;
    else if (npg_args_int(&a, "--width", 16, FLUIDS_MAX_WIDTH, &o.width)) ;
    else if (npg_args_int(&a, "--workers", 1, CAVITY_MAX_WORKERS, &o.workers)) ;
    else if (npg_args_int(&a, "--particle-threads", 1, PARTICLES_MAX_THREADS, &o.particle_threads)) ;
    else if (npg_args_int(&a, "--train-threads", 1, CAVITY_MAX_WORKERS, &o.train_threads)) ;
    else if (npg_args_int(&a, "--sample-every", 0, FLUIDS_MAX_FRAMES, &o.sample_every)) ;
    else if (npg_args_int(&a, "--buffer-mb", 0, 1 << 20, &mb)) o.buffer_bytes = (size_t)mb << 20;
    else if ((v = npg_args_string(&a, "--backend"))) {
      if (!strcmp(v, "cc")) o.backend = NPG_CC;
      else if (!strcmp(v, "tcc")) o.backend = NPG_TCC;
      else snprintf(a.error, sizeof a.error, "npg-fluids cavity: --backend is cc or tcc, not '%s'", v);
    } else if ((v = npg_args_string(&a, "--projection"))) {
      if (!strcmp(v, "al")) o.projection = PROJ_AL_CHOLMOD;
      else if (!strcmp(v, "kkt")) o.projection = PROJ_KKT_UMFPACK;
      else snprintf(a.error, sizeof a.error, "npg-fluids cavity: --projection is al or kkt, not '%s'", v);
    } else npg_args_unknown(&a);
  }
  if (args_status(&a)) return 2;
  return cavity_run(&o);
}

/* npg-fluids cavity-mesh --cells N: the cavity's mesh statistics as JSON,
 * and one deformation (the deepest of the training and test scales). */
static int cavity_mesh_cmd(int argc, char **argv) {
  CavitySpec spec = cavity_spec_default();
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npg-fluids cavity-mesh");
  while (npg_args_next(&a))
    if (!npg_args_int(&a, "--cells", 50, FLUIDS_MAX_CELLS, &spec.cells)) npg_args_unknown(&a);
  if (args_status(&a)) return 2;
  char err[ERRLEN];
  Cavity cv;
  double t0 = util_now();
  if (cavity_mesh(&cv, &spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  double t1 = util_now();
  double *g = malloc(3 * (size_t)cv.m.nv * sizeof *g), sigma[CAVITY_SIDES] = {0.75, 0.8, 1.0}, kappa = 1;
  int rc = cavity_deform(&cv, sigma, g, &kappa, err, sizeof err);
  double t2 = util_now();
  if (rc == 0)
    printf("{\"cells\": %d, \"faces\": %d, \"boundary_faces\": %d, \"vertices\": %d, \"mesh_seconds\": %.3f, "
           "\"min_quality\": %.4f, \"deformed_min_quality\": %.4f, \"deformation_seconds\": %.4f, \"kappa\": %.6f, "
           "\"volume_change_relative\": %.3g}\n",
           cv.m.nc, cv.m.nf, cv.m.nb, cv.m.nv, t1 - t0, mesh_min_quality(&cv.m, cv.m.g0, NULL),
           mesh_min_quality(&cv.m, g, NULL), t2 - t1, kappa, mesh_fluid_volume(&cv.m, g) / cv.volume0 - 1);
  else
    fprintf(stderr, "npg-fluids: %s\n", err);
  free(g);
  cavity_free(&cv);
  return rc ? 1 : 0;
}

/* npg-fluids cavity-projection: the full step's projection timed per
 * method on the cavity at --cells N, over --steps steps of training run 6
 * (two chambers compressed together) from u = 0; with both methods, the
 * largest difference of their fluxes relative to the largest flux. */
static int cavity_projection_cmd(int argc, char **argv) {
  CavitySpec spec = cavity_spec_default();
  int steps = 3, which = 3; /* 1 kkt, 2 al */
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npg-fluids cavity-projection");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_int(&a, "--cells", 50, FLUIDS_MAX_CELLS, &spec.cells)) ;
    else if (npg_args_int(&a, "--steps", 1, 100000, &steps)) ;
    else if ((v = npg_args_string(&a, "--method"))) {
      which = !strcmp(v, "kkt") ? 1 : !strcmp(v, "al") ? 2 : !strcmp(v, "both") ? 3 : 0;
      if (!which) snprintf(a.error, sizeof a.error, "npg-fluids cavity-projection: --method is kkt, al or both, not '%s'", v);
    } else npg_args_unknown(&a);
  }
  if (args_status(&a)) return 2;
  char err[ERRLEN];
  Cavity cv;
  if (cavity_mesh(&cv, &spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  const Mesh *m = &cv.m;
  double vmin = INFINITY, sigma[CAVITY_SIDES];
  for (int c = 0; c < m->nc; c++) vmin = fmin(vmin, mesh_volume(m, m->g0, c));
  const double zero[3] = {0, 0, 0}, dt = 0.01;
  const ProjectionMethod methods[2] = {PROJ_KKT_UMFPACK, PROJ_AL_CHOLMOD};
  FullSolver s[2];
  int want[2] = {which & 1, (which & 2) >> 1}, on[2] = {0, 0}, rc = 0, iterations = 0; /* on: initialized */
  double *g = malloc(3 * (size_t)m->nv * sizeof *g), diff = 0, div[2] = {0}, init[2] = {0}, fmx = 0;
  for (int k = 0; k < 2 && !rc; k++) {
    if (!want[k]) continue;
    double t0 = util_now();
    rc = solver_init_at(&s[k], m, methods[k], 5 * vmin, dt, m->g0, zero, err, sizeof err);
    init[k] = util_now() - t0;
    on[k] = !rc;
  }
  for (int t = 1; t <= steps && !rc; t++) {
    cavity_schedule(6, t, 100, sigma);
    rc = cavity_deform(&cv, sigma, g, NULL, err, sizeof err);
    for (int k = 0; k < 2 && !rc; k++) {
      if (!on[k]) continue;
      rc = solver_step_to(&s[k], g, err, sizeof err);
      if (rc) break;
      for (int j = 0; j < m->nf; j++) fmx = fmax(fmx, fabs(s[k].f[j]));
      div[k] = fmax(div[k], projection_max_divergence(&s[k].ops, s[k].f) / fmx);
      iterations = k == 1 ? s[k].pr.iterations : iterations;
    }
    if (!rc && on[0] && on[1])
      for (int j = 0; j < m->nf; j++) diff = fmax(diff, fabs(s[0].f[j] - s[1].f[j]) / fmx);
  }
  if (rc) fprintf(stderr, "npg-fluids: %s\n", err);
  else {
    printf("{\"cells\": %d, \"faces\": %d, \"interior_faces\": %d, \"projections\": %d", m->nc, m->nf,
           m->nf - m->nb, steps + 1);
    for (int k = 0; k < 2; k++)
      if (on[k])
        printf(", \"%s\": {\"init_seconds\": %.4g, \"factorization_seconds\": %.4g, \"solve_seconds\": %.4g, "
               "\"max_divergence_relative\": %.3g}",
               projection_method_name(methods[k]), init[k], s[k].pr.seconds_numeric / (steps + 1),
               s[k].pr.seconds_solve / (steps + 1), div[k]);
    if (on[1]) printf(", \"al_iterations_last\": %d", iterations);
    if (on[0] && on[1]) printf(", \"max_flux_difference_relative\": %.3g", diff);
    printf("}\n");
  }
  for (int k = 0; k < 2; k++)
    if (on[k]) solver_free(&s[k]);
  free(g);
  cavity_free(&cv);
  return rc ? 1 : 0;
}

/* ---------------------------------------------------------------- tunnel */

static int tunnel_cmd(int argc, char **argv) {
  TunnelOptions o;
  tunnel_options_default(&o);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npg-fluids tunnel");
  while (npg_args_next(&a)) {
    const char *v;
    if ((v = npg_args_string(&a, "--out"))) o.out = v;
    else if (npg_args_int(&a, "--frames", 2, FLUIDS_MAX_FRAMES, &o.frames)) ;
    else if (npg_args_int(&a, "--cells", 50, FLUIDS_MAX_CELLS, &o.spec.cells)) ;
    else if (npg_args_int(&a, "--particles", 0, FLUIDS_MAX_PARTICLES, &o.particles)) ;
    else if (npg_args_int(&a, "--png-every", 1, 1000000, &o.png_every)) ;
    else if (npg_args_int(&a, "--vtk-every", 1, 1000000, &o.vtk_every)) ;
    else if (npg_args_int(&a, "--width", 16, FLUIDS_MAX_WIDTH, &o.width)) ;
    else if (npg_args_int(&a, "--mg", 1, 512, &o.mg_cap)) ;
    else if (npg_args_int(&a, "--keep-models", 0, 1, &o.keep_models)) ;
    else if (npg_args_double(&a, "--pulse", 0, 0.7, false, &o.pulse)) ;
    else if (npg_args_double(&a, "--period", 0, 1e9, true, &o.period)) ;
    else if (physical(&a, &o.mu, &o.cfl)) ;
    else if ((v = npg_args_string(&a, "--sizes"))) {
      o.nsizes = 0;
      char buf[256], err[256];
      snprintf(buf, sizeof buf, "%s", v);
      for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok && !a.error[0]; tok = strtok_r(NULL, ",", &save)) {
        long n;
        if (o.nsizes >= 16)
          snprintf(a.error, sizeof a.error, "npg-fluids tunnel: --sizes: at most 16 sizes");
        else if (npg_parse_long(tok, 2, 256, &n, err, sizeof err) != 0)
          snprintf(a.error, sizeof a.error, "npg-fluids tunnel: --sizes: entry %d: %s", o.nsizes + 1, err);
        else if (o.nsizes && n <= o.mu_sizes[o.nsizes - 1])
          snprintf(a.error, sizeof a.error, "npg-fluids tunnel: --sizes: %ld after %d: the sizes increase", n,
                   o.mu_sizes[o.nsizes - 1]);
        else
          o.mu_sizes[o.nsizes++] = (int)n;
      }
      if (!o.nsizes && !a.error[0]) snprintf(a.error, sizeof a.error, "npg-fluids tunnel: --sizes: an empty list");
    } else npg_args_unknown(&a);
  }
  if (args_status(&a)) return 2;
  return tunnel_run(&o);
}

int main(int argc, char **argv) {
  if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  /* UMFPACK's fronts are small: BLAS threads only contend (measured: the
   * projection took 29 ms a step with OpenBLAS's threads, 17 ms without) */
  openblas_set_num_threads(1);
  if (!strcmp(argv[1], "tunnel")) return tunnel_cmd(argc, argv);
  if (!strcmp(argv[1], "cavity")) return cavity_cmd(argc, argv);
  if (!strcmp(argv[1], "cavity-mesh")) return cavity_mesh_cmd(argc, argv);
  if (!strcmp(argv[1], "cavity-projection")) return cavity_projection_cmd(argc, argv);
  RunOptions o;
  if (parse_options(argc, argv, &o) != 0) return 2;
  if (!strcmp(argv[1], "tunnel-full")) return tunnel_full(&o);
  if (!strcmp(argv[1], "mesh")) return mesh_info(&o);
  fprintf(stderr, "npg-fluids: unknown command '%s'\n", argv[1]);
  usage(stderr);
  return 2;
}
