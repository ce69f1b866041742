/* tunnelfull.c — npg-fluids tunnel-full (see tunnelfull.h). tunnel_full_run is the table
 * of contents: prepare the folders, mesh and set up the solver, run every frame (outputs
 * of the frame, then its step and samples), the VTK collections, the arrays of data/, the
 * report. */
#include "tunnelfull.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"
#include "npgbind.h"
#include "output.h"
#include "particles.h"
#include "chart.h"
#include "plot.h"
#include "report.h"
#include "solver.h"
#include "tunnelstep.h"
#include "util.h"

#define ERRLEN 512
#define PROGRAM "npg-fluids"

void tunnel_full_options_default(TunnelFullOptions *o) {
  *o = (TunnelFullOptions){.frames = 200, .particles = 3000, .png_every = 1, .vtk_every = 10, .png_width = 800,
                           .scale = 1, .pulse = 0.2, .period = 100, .mu = 0.002, .cfl = 0.25, .u0 = 1,
                           .projection = PROJ_STREAM_CHOLMOD, .spec = tunnel_spec_default()};
}

/* Everything one run holds, so that each phase is a function of it. */
typedef struct FullRun {
  const TunnelFullOptions *o;
  char err[ERRLEN], dir_frames[1100], dir_vtk[1100], dir_data[1100];
  FluidMesh m;
  FullSolver s;
  Particles part;
  int mesh_ok, solver_ok, T, nvtk, worst_quality_frame;
  double dt, t_mesh, t_run, seconds_particles, seconds_output, worst_quality;
  size_t gv, uv, fv;          /* sizes of one sample of g, u and f */
  double *Sg, *Sgdot, *Su, *Sf, *Sh, *Sgmid;               /* the samples, one per frame */
  double *energy, *divergence, *quality, *sigmas, *flux_scale; /* per frame 0 .. T */
  char **vtk_cells, **vtk_faces;
  double *vtk_times;
} FullRun;

/* Obstacle scale of frame t: the mesh is always gmsh's mesh at --size, deformed (so runs
 * with different --scale share one topology, as paper Fig. 5's training and test runs must). */
static double sigma_at(const TunnelFullOptions *o, int frame) {
  return tunnel_obstacle_scale(o->scale, o->pulse, o->period, frame);
}

/* FNV-1a of the topology and rest positions: equal hashes, same mesh. */
static unsigned long long mesh_hash(const FluidMesh *m) {
  unsigned long long h = 1469598103934665603ull;
  const unsigned char *p[2] = {(const unsigned char *)m->cell, (const unsigned char *)m->g0};
  size_t n[2] = {3 * (size_t)m->nc * sizeof *m->cell, 2 * (size_t)m->nv * sizeof *m->g0};
  for (int k = 0; k < 2; k++)
    for (size_t i = 0; i < n[k]; i++) h = (h ^ p[k][i]) * 1099511628211ull;
  return h;
}

/* ---------------------------------------------------------------- data/ */

/* What an array holds: doubles, or ints (written as int64, as npg reads int params). */
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
static int save_params(const char *dir, const FluidMesh *m, double mu) {
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

/* ---------------------------------------------------------------- phases */

/* DIR and its frames/, vtk/ and data/. */
static int prepare(FullRun *r) {
  const TunnelFullOptions *o = r->o;
  int rc = report_need_out(PROGRAM, "tunnel-full", o->out, 1000);
  if (rc) return rc;
  snprintf(r->dir_frames, sizeof r->dir_frames, "%s/frames", o->out);
  snprintf(r->dir_vtk, sizeof r->dir_vtk, "%s/vtk", o->out);
  snprintf(r->dir_data, sizeof r->dir_data, "%s/data", o->out);
  if (report_make_dir(PROGRAM, o->out) || report_make_dir(PROGRAM, r->dir_frames) ||
      report_make_dir(PROGRAM, r->dir_vtk) || report_make_dir(PROGRAM, r->dir_data))
    return 1;
  return 0;
}

/* The mesh, the solver at frame 0, the particles, and the per-frame arrays. */
static int mesh_and_set_up(FullRun *r) {
  const TunnelFullOptions *o = r->o;
  r->t_mesh = util_now();
  if (mesh_tunnel(&r->m, &o->spec, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->mesh_ok = 1;
  r->t_mesh = util_now() - r->t_mesh;
  FluidMesh *m = &r->m;
  r->dt = o->cfl * mesh_mean_edge(m) / o->u0;
  fprintf(stderr, "npg-fluids: mesh %d cells, %d faces (%d boundary), %d vertices; dt %.4g, mu %g\n", m->nc, m->nf,
          m->nb, m->nv, r->dt, o->mu);
  double u0[2] = {o->u0, 0};
  if (solver_init(&r->s, m, o->projection, o->mu, r->dt, sigma_at(o, 0), u0, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->solver_ok = 1;
  if (particles_seed(&r->part, m, r->s.g, o->particles, 12345) != 0) {
    fprintf(stderr, "npg-fluids: out of memory for %d particles: fewer --particles\n", o->particles);
    return 1;
  }
  int T = r->T = o->frames;
  size_t gv = r->gv = 2 * (size_t)m->nv, uv = r->uv = 2 * (size_t)m->nc, fv = r->fv = m->nf;
  r->Sg = malloc(T * gv * sizeof(double)), r->Sgdot = malloc(T * gv * sizeof(double));
  r->Su = malloc(T * uv * sizeof(double)), r->Sf = malloc(T * fv * sizeof(double));
  r->Sh = malloc(T * fv * sizeof(double)), r->Sgmid = malloc(T * gv * sizeof(double));
  r->energy = malloc((T + 1) * sizeof(double)), r->divergence = malloc((T + 1) * sizeof(double));
  r->quality = malloc((T + 1) * sizeof(double)), r->sigmas = malloc((T + 1) * sizeof(double));
  r->flux_scale = malloc((T + 1) * sizeof(double));
  r->vtk_cells = calloc(T + 1, sizeof(char *)), r->vtk_faces = calloc(T + 1, sizeof(char *));
  r->vtk_times = malloc((T + 1) * sizeof(double));
  if (!r->Sg || !r->Sgdot || !r->Su || !r->Sf || !r->Sh || !r->Sgmid || !r->energy || !r->divergence ||
      !r->quality || !r->sigmas || !r->flux_scale || !r->vtk_cells || !r->vtk_faces || !r->vtk_times) {
    snprintf(r->err, sizeof r->err,
             "out of memory for %d frames of %d cells (%.3g GB of samples): fewer --frames or --cells", T, m->nc,
             (double)T * (3 * gv + uv + 2 * fv) * sizeof(double) / 1e9);
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->worst_quality = r->s.min_quality;
  return 0;
}

/* The figures of frame t's state. */
static void record(FullRun *r, int t) {
  FullSolver *s = &r->s;
  double maxf = 0;
  r->energy[t] = solver_energy(s);
  r->divergence[t] = projection_max_divergence(&s->ops, s->f);
  r->quality[t] = s->min_quality;
  r->sigmas[t] = s->sigma;
  for (int j = 0; j < r->m.nf; j++) maxf = fmax(maxf, fabs(s->f[j]));
  r->flux_scale[t] = maxf;
}

/* Frame t's PNG and VTK files, when due (frames 0 .. T: the last one too, output_frame_due). */
static int output_frame(FullRun *r, int t) {
  const TunnelFullOptions *o = r->o;
  char path[4096], name[64];
  double t0 = util_now();
  int rc = 0;
  if (output_frame_due(t, r->T, o->png_every)) {
    snprintf(path, sizeof path, "%s/frame_%04d.png", r->dir_frames, t);
    if (output_png(path, &r->m, r->s.g, r->s.u, &r->part, 1.6 * o->u0, o->png_width, r->err, sizeof r->err) != 0)
      rc = -1;
  }
  if (rc == 0 && output_frame_due(t, r->T, o->vtk_every)) {
    snprintf(name, sizeof name, "cells_%04d.vtu", t);
    r->vtk_cells[r->nvtk] = strdup(name);
    snprintf(path, sizeof path, "%s/%s", r->dir_vtk, name);
    if (output_vtu_cells(path, &r->m, r->s.g, r->s.u, r->err, sizeof r->err) != 0) rc = -1;
    snprintf(name, sizeof name, "faces_%04d.vtu", t);
    r->vtk_faces[r->nvtk] = strdup(name);
    snprintf(path, sizeof path, "%s/%s", r->dir_vtk, name);
    if (rc == 0 && output_vtu_faces(path, &r->m, r->s.g, r->s.f, r->s.h, r->err, sizeof r->err) != 0) rc = -1;
    r->vtk_times[r->nvtk++] = t * r->dt;
  }
  r->seconds_output += util_now() - t0;
  return rc;
}

/* Sample t (the state of frame t and the motion of the step that leaves it), the step to
 * frame t + 1, the particles, and frame t + 1's figures. */
static int step(FullRun *r, int t) {
  FullSolver *s = &r->s;
  size_t gv = r->gv, uv = r->uv, fv = r->fv;
  memcpy(r->Sg + t * gv, s->g, gv * sizeof(double));
  memcpy(r->Su + t * uv, s->u, uv * sizeof(double));
  memcpy(r->Sf + t * fv, s->f, fv * sizeof(double));
  if (solver_step(s, sigma_at(r->o, t + 1), r->err, sizeof r->err) != 0) return -1;
  memcpy(r->Sgdot + t * gv, s->gdot, gv * sizeof(double));
  memcpy(r->Sh + t * fv, s->h, fv * sizeof(double));
  memcpy(r->Sgmid + t * gv, s->gmid, gv * sizeof(double));
  double t1 = util_now();
  particles_advect(&r->part, &r->m, s->g, s->f, r->dt, 10);
  r->seconds_particles += util_now() - t1;
  record(r, t + 1);
  if (s->min_quality < r->worst_quality) r->worst_quality = s->min_quality, r->worst_quality_frame = t + 1;
  return solver_check_energy(r->energy[0], r->energy[t + 1], t + 1, r->err, sizeof r->err);
}

/* Frames 0 .. T: each one's outputs, then the step that leaves it. */
static int run_full(FullRun *r) {
  int rc = 0;
  record(r, 0);
  r->t_run = util_now();
  for (int t = 0; t <= r->T && rc == 0; t++) {
    rc = output_frame(r, t);
    if (rc || t == r->T) break;
    rc = step(r, t);
  }
  r->t_run = util_now() - r->t_run;
  if (rc) fprintf(stderr, "npg-fluids: %s\n", r->err);
  return rc ? 1 : 0;
}

/* vtk/cells.pvd and faces.pvd: the time series ParaView opens. */
static int vtk_collections(FullRun *r) {
  char path[4096], e2[ERRLEN];
  int rc = 0;
  snprintf(path, sizeof path, "%s/cells.pvd", r->dir_vtk);
  if (output_pvd(path, r->nvtk, (const char *const *)r->vtk_cells, r->vtk_times, e2, sizeof e2) != 0) rc = -1;
  snprintf(path, sizeof path, "%s/faces.pvd", r->dir_vtk);
  if (rc == 0 && output_pvd(path, r->nvtk, (const char *const *)r->vtk_faces, r->vtk_times, e2, sizeof e2) != 0)
    rc = -1;
  if (rc) fprintf(stderr, "npg-fluids: %s\n", e2);
  return rc ? 1 : 0;
}

/* data/: the params and the samples, the layout `npgc train` reads. */
static int data_arrays(FullRun *r) {
  const char *d = r->dir_data;
  int T = r->T, rc = 0;
  long sg[3] = {T, r->m.nv, 2}, su[2] = {T, 2 * (long)r->m.nc}, sf[2] = {T, r->m.nf};
  rc |= save_params(d, &r->m, r->o->mu);
  rc |= save(d, "g", SAVE_F64, 3, sg, r->Sg);
  rc |= save(d, "gdot", SAVE_F64, 3, sg, r->Sgdot);
  rc |= save(d, "u", SAVE_F64, 2, su, r->Su);
  rc |= save(d, "f", SAVE_F64, 2, sf, r->Sf);
  rc |= save(d, "h", SAVE_F64, 2, sf, r->Sh);
  rc |= save(d, "gmid", SAVE_F64, 3, sg, r->Sgmid);
  rc |= save(d, "energy", SAVE_F64, 1, (long[]){T + 1}, r->energy);
  return rc ? 1 : 0;
}

/* --dump-step DIR: the step's operators, frame 0 and the driver's frames (tunnelstep.h). */
static int dump_step(FullRun *r) {
  if (!r->o->dump_step) return 0;
  if (tunnel_step_dump(r->o->dump_step, &r->s, r->Su, r->Sf, r->Sg, r->T, r->o->pulse != 0, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  return 0;
}

/* report.json, and the summary on stderr. */
static int report(FullRun *r) {
  const TunnelFullOptions *o = r->o;
  const FluidMesh *m = &r->m;
  const FullSolver *s = &r->s;
  int T = r->T;
  double maxdiv = 0, maxdiv_rel = 0, steps = T > 0 ? T : 1;
  for (int t = 0; t <= T; t++) {
    maxdiv = fmax(maxdiv, r->divergence[t]);
    maxdiv_rel = fmax(maxdiv_rel, r->divergence[t] / r->flux_scale[t]);
  }
  Report rep;
  if (report_open(&rep, PROGRAM, o->out) != 0) return 1;
  FILE *fp = rep.f;
  fprintf(fp, "{\n  \"command\": \"tunnel-full\",\n");
  fprintf(fp, "  \"cells\": %d,\n  \"faces\": %d,\n  \"boundary_faces\": %d,\n  \"vertices\": %d,\n", m->nc, m->nf,
          m->nb, m->nv);
  fprintf(fp, "  \"tunnel\": {\"L\": %g, \"H\": %g, \"obstacle_center\": [%g, %g], \"obstacle_size\": %g},\n",
          m->spec.L, m->spec.H, m->spec.cx, m->spec.cy, m->spec.size);
  fprintf(fp, "  \"mesh_hash\": \"%016llx\",\n  \"scale\": %g,\n", mesh_hash(m), o->scale);
  fprintf(fp, "  \"frames\": %d,\n  \"dt\": %.10g,\n  \"mu\": %g,\n  \"u0\": %g,\n  \"pulse\": %g,\n", T, r->dt,
          o->mu, o->u0, o->pulse);
  fprintf(fp, "  \"period_frames\": %g,\n  \"particles\": %d,\n", o->period, o->particles);
  fprintf(fp, "  \"mesh_seconds\": %.6g,\n  \"run_seconds\": %.6g,\n", r->t_mesh, r->t_run);
  fprintf(fp, "  \"projection_method\": \"%s\",\n", projection_method_name(o->projection));
  fprintf(fp, "  \"full_step_seconds\": {\"total\": %.6g, \"advection\": %.6g, \"projection\": %.6g, "
              "\"projection_factorization\": %.6g, \"projection_solve\": %.6g, \"deformation\": %.6g},\n",
          (s->seconds_advection + s->seconds_projection + s->seconds_deformation) / steps,
          s->seconds_advection / steps, s->seconds_projection / steps, s->pr.seconds_numeric / steps,
          s->pr.seconds_solve / steps, s->seconds_deformation / steps);
  fprintf(fp, "  \"particle_seconds_per_frame\": %.6g,\n  \"output_seconds_per_frame\": %.6g,\n",
          r->seconds_particles / steps, r->seconds_output / steps);
  fprintf(fp, "  \"particle_walk_steps_per_frame\": %.6g,\n", r->part.walk_steps / steps);
  fprintf(fp, "  \"max_divergence\": %.6g,\n  \"max_divergence_relative_to_max_flux\": %.6g,\n", maxdiv, maxdiv_rel);
  fprintf(fp, "  \"min_element_quality\": %.6g,\n  \"min_element_quality_frame\": %d,\n", r->worst_quality,
          r->worst_quality_frame);
  fprintf(fp, "  \"energy_drift\": %.6g,\n", T > 0 ? r->energy[T] / r->energy[0] - 1 : 0.0);
  report_json_array(fp, "  ", "obstacle_scale", r->sigmas, T + 1, 10, ",\n");
  report_json_array(fp, "  ", "min_quality", r->quality, T + 1, 10, ",\n");
  report_json_array(fp, "  ", "max_divergence_per_frame", r->divergence, T + 1, 10, ",\n");
  report_json_array(fp, "  ", "energy", r->energy, T + 1, 10, "\n");
  fprintf(fp, "}\n");
  if (report_commit(&rep, PROGRAM) != 0) return 1;
  fprintf(stderr,
          "npg-fluids: %d frames in %.2f s: step %.3g ms (advection %.3g, projection %.3g, deformation %.3g), "
          "particles %.3g ms/frame; energy %.6g -> %.6g; max divergence %.3g; min quality %.3f\n",
          T, r->t_run, 1e3 * (s->seconds_advection + s->seconds_projection + s->seconds_deformation) / steps,
          1e3 * s->seconds_advection / steps, 1e3 * s->seconds_projection / steps,
          1e3 * s->seconds_deformation / steps, 1e3 * r->seconds_particles / steps, r->energy[0], r->energy[T], maxdiv,
          r->worst_quality);
  return 0;
}

static void release(FullRun *r) {
  for (int i = 0; i < r->nvtk; i++) free(r->vtk_cells[i]), free(r->vtk_faces[i]);
  free(r->vtk_cells), free(r->vtk_faces), free(r->vtk_times);
  free(r->Sg), free(r->Sgdot), free(r->Su), free(r->Sf), free(r->Sh), free(r->Sgmid);
  free(r->energy), free(r->divergence), free(r->quality), free(r->sigmas), free(r->flux_scale);
  particles_free(&r->part);
  if (r->solver_ok) solver_free(&r->s);
  if (r->mesh_ok) mesh_free(&r->m);
  chart_cleanup(); /* the frames' colour bars (cairo, fontconfig) */
}

int tunnel_full_run(const TunnelFullOptions *o) {
  FullRun *r = calloc(1, sizeof *r);
  if (!r) return 1;
  r->o = o;
  int rc = prepare(r);
  if (!rc) rc = mesh_and_set_up(r);
  if (!rc) rc = run_full(r);
  if (!rc) rc = vtk_collections(r);
  if (!rc) rc = data_arrays(r);
  if (!rc) rc = dump_step(r);
  if (!rc) rc = report(r);
  release(r);
  free(r);
  return rc;
}
