/* cavitysim.c — npg-fluids cavity: paper §7.2, Fig. 6 and Table 1 (see
 * cavitysim.h). */
#include "util.h"
#include "cavitysim.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "output.h"
#include "particles.h"
#include "solver.h"

#define ERRLEN 1024

void cavity_options_default(CavityOptions *o) {
  memset(o, 0, sizeof *o);
  o->spec = cavity_spec_default();
  o->frames = 100, o->runs = 14, o->particles = 10000, o->png_every = 10, o->vtk_every = 25, o->width = 800;
  o->dt = 0.01, o->nu = 5.0;
  o->mf = 64, o->mu = 128, o->mg = 5;
}

/* Compress and re-inflate: 1 - a sin^2(pi t / T), smooth at both ends. */
static double pulse(double a, int t, int T) {
  double s = sin(M_PI * t / T);
  return 1 - a * s * s;
}

/* Smoothstep from 0 (t = 0) to 1 (t = T). */
static double ramp(int t, int T) {
  double x = (double)t / T;
  return x * x * (3 - 2 * x);
}

void cavity_schedule(int r, int t, int T, double sigma[CAVITY_SIDES]) {
  for (int i = 0; i < CAVITY_SIDES; i++) sigma[i] = 1;
  if (r < 0) {
    /* the test, in no training run: chamber 0 compressed throughout while
     * chamber 1 expands from compressed to beyond its rest size */
    sigma[0] = 0.8;
    sigma[1] = 0.8 + 0.25 * ramp(t, T);
    return;
  }
  static const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
  if (r < 3) sigma[r] = pulse(0.25, t, T);                            /* one chamber, deep */
  else if (r < 6) sigma[r - 3] = pulse(0.12, t, T);                   /* one chamber, shallow */
  else if (r < 9) {                                                   /* two together */
    sigma[pairs[r - 6][0]] = pulse(0.2, t, T);
    sigma[pairs[r - 6][1]] = pulse(0.2, t, T);
  } else if (r < 12) {                                                /* two, deep and shallow */
    sigma[pairs[r - 9][0]] = pulse(0.25, t, T);
    sigma[pairs[r - 9][1]] = pulse(0.1, t, T);
  } else {                                                            /* two, one after the other */
    int a = r == 12 ? 0 : 2, b = 1;
    sigma[a] = t < T / 2 ? pulse(0.22, t, T / 2) : 1;
    sigma[b] = t >= T / 2 ? pulse(0.22, t - T / 2, T - T / 2) : 1;
  }
}

static int make_dir(const char *path) {
  if (mkdir(path, 0777) != 0 && errno != EEXIST) {
    fprintf(stderr, "npg-fluids: %s: %s\n", path, strerror(errno));
    return -1;
  }
  return 0;
}

static double max_abs(const double *v, long n) {
  double m = 0;
  for (long i = 0; i < n; i++) m = fmax(m, fabs(v[i]));
  return m;
}

static void json_array(FILE *fp, const char *name, const double *v, long n, const char *tail) {
  fprintf(fp, "  \"%s\": [", name);
  for (long i = 0; i < n; i++) fprintf(fp, "%s%.6g", i ? ", " : "", v[i]);
  fprintf(fp, "]%s\n", tail);
}

/* The run's figures, filled as it goes. */
typedef struct FullStats {
  double t_d, t_a, t_p;         /* seconds per step: deformation, advection, projection */
  double min_quality, max_div_rel, max_boundary_residual;
  int min_quality_frame;
} FullStats;

/* Positions of run r at frame t; the time cavity_deform takes is added to *seconds. */
static int deform_at(const Cavity *cv, int r, int t, int T, double *g, double *seconds, char *err, size_t errlen) {
  double sigma[CAVITY_SIDES];
  cavity_schedule(r, t, T, sigma);
  double t0 = util_now();
  int rc = cavity_deform(cv, sigma, g, NULL, err, errlen);
  *seconds += util_now() - t0;
  return rc;
}

int cavity_run(const CavityOptions *o) {
  char err[ERRLEN], path[4096];
  if (!o->out) {
    fprintf(stderr, "npg-fluids: cavity needs --out DIR\n");
    return 2;
  }
  if (strlen(o->out) > 1000) {
    fprintf(stderr, "npg-fluids: --out: path longer than 1000 bytes\n");
    return 2;
  }
  char dframes[1100], dvtk[1100];
  snprintf(dframes, sizeof dframes, "%s/frames", o->out);
  snprintf(dvtk, sizeof dvtk, "%s/vtk", o->out);
  if (make_dir(o->out) || make_dir(dframes) || make_dir(dvtk)) return 1;

  double t_mesh = util_now();
  Cavity cv;
  if (cavity_mesh(&cv, &o->spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  t_mesh = util_now() - t_mesh;
  const Mesh *m = &cv.m;
  /* the graph Laplacian's rate in cell c is up to 8 mu / V_c: scaled by
   * the smallest cell, diffusion stays stable at every --nu * dt < 0.3 */
  double vmin = INFINITY;
  for (int c = 0; c < m->nc; c++) vmin = fmin(vmin, mesh_volume(m, m->g0, c));
  double mu = o->nu * vmin;
  int T = o->frames, rc = 1;
  long ng = 3L * m->nv, nf = m->nf;
  fprintf(stderr,
          "npg-fluids: cavity %d cells, %d faces (%d boundary), %d vertices, meshed in %.1f s; min quality %.3f; "
          "dt %g, mu %.3g\n",
          m->nc, m->nf, m->nb, m->nv, t_mesh, mesh_min_quality(m, m->g0, NULL), o->dt, mu);

  FullSolver s = {0};
  int s_ok = 0;
  Particles part = {0};
  double *g = malloc(ng * sizeof(double));
  double *energy = calloc(T + 1, sizeof(double)), *quality = calloc(T + 1, sizeof(double));
  double *divergence = calloc(T + 1, sizeof(double));
  double seconds_particles = 0, t_deform = 0;
  FullStats st = {0};
  st.min_quality = INFINITY;
  const double zero[3] = {0, 0, 0};

  /* the test sequence, full */
  if (deform_at(&cv, -1, 0, T, g, &t_deform, err, sizeof err) != 0 ||
      solver_init_at(&s, m, PROJ_KKT_UMFPACK, mu, o->dt, g, zero, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    goto done;
  }
  s_ok = 1;
  t_deform = 0;
  particles_seed(&part, m, s.g, o->particles, 12345);
  energy[0] = solver_energy(&s);
  quality[0] = s.min_quality;
  for (int t = 0; t <= T; t++) {
    if (t > 0) {
      if (deform_at(&cv, -1, t, T, g, &t_deform, err, sizeof err) != 0 ||
          solver_step_to(&s, g, err, sizeof err) != 0) {
        fprintf(stderr, "npg-fluids: test frame %d: %s\n", t, err);
        goto done;
      }
      double t0 = util_now();
      particles_advect(&part, m, s.g, s.f, o->dt, 10);
      seconds_particles += util_now() - t0;
      energy[t] = solver_energy(&s);
      quality[t] = s.min_quality;
      double sb = 0;
      for (int b = 0; b < m->nb; b++) sb += s.h[m->bface[b]];
      st.max_boundary_residual = fmax(st.max_boundary_residual, fabs(sb) / fmax(max_abs(s.h, nf), 1e-300));
    }
    divergence[t] = projection_max_divergence(&s.ops, s.f) / fmax(max_abs(s.f, nf), 1e-300);
    st.max_div_rel = fmax(st.max_div_rel, divergence[t]);
    if (quality[t] < st.min_quality) st.min_quality = quality[t], st.min_quality_frame = t;
    if (!isfinite(energy[t])) {
      fprintf(stderr, "npg-fluids: the energy is not finite at frame %d: unstable (lower --dt)\n", t);
      goto done;
    }
    if (t % o->png_every == 0) {
      snprintf(path, sizeof path, "%s/full_%04d.png", dframes, t);
      if (output_png_points(path, m, s.g, &part, o->spec.D + o->spec.r, o->width, err, sizeof err) != 0) {
        fprintf(stderr, "npg-fluids: %s\n", err);
        goto done;
      }
    }
    if (t % o->vtk_every == 0) {
      snprintf(path, sizeof path, "%s/full_%04d.vtk", dvtk, t);
      if (output_vtk_tets(path, m, s.g, s.u, err, sizeof err) != 0) {
        fprintf(stderr, "npg-fluids: %s\n", err);
        goto done;
      }
    }
  }
  double steps = T > 0 ? T : 1;
  st.t_d = (s.seconds_deformation + t_deform) / steps;
  st.t_a = s.seconds_advection / steps;
  st.t_p = s.seconds_projection / steps;
  fprintf(stderr,
          "npg-fluids: full test run, %d frames: t_d %.3g ms, t_a %.3g ms, t_p %.3g ms; particles %.3g ms/frame; "
          "max |div| / max |f| %.2e; min quality %.3f (frame %d); energy %.4g -> %.4g\n",
          T, 1e3 * st.t_d, 1e3 * st.t_a, 1e3 * st.t_p, 1e3 * seconds_particles / steps, st.max_div_rel,
          st.min_quality, st.min_quality_frame, energy[0], energy[T]);

  snprintf(path, sizeof path, "%s/report.json", o->out);
  char tmp[4200];
  snprintf(tmp, sizeof tmp, "%s.tmp", path);
  FILE *fp = fopen(tmp, "w");
  if (!fp) {
    fprintf(stderr, "npg-fluids: %s: %s\n", tmp, strerror(errno));
    goto done;
  }
  fprintf(fp, "{\n  \"command\": \"cavity\",\n  \"cells\": %d,\n  \"faces\": %d,\n  \"boundary_faces\": %d,\n"
              "  \"vertices\": %d,\n  \"mesh_seconds\": %.4g,\n  \"frames\": %d,\n  \"dt\": %g,\n  \"mu\": %.6g,\n",
          m->nc, m->nf, m->nb, m->nv, t_mesh, T, o->dt, mu);
  fprintf(fp, "  \"t_d\": %.6g,\n  \"t_a\": %.6g,\n  \"t_p\": %.6g,\n  \"full_step_seconds\": %.6g,\n", st.t_d, st.t_a,
          st.t_p, st.t_d + st.t_a + st.t_p);
  fprintf(fp, "  \"projection_factorization_seconds\": %.6g,\n  \"projection_solve_seconds\": %.6g,\n",
          s.pr.seconds_numeric / steps, s.pr.seconds_solve / steps);
  fprintf(fp, "  \"particles\": %d,\n  \"t_pa_full\": %.6g,\n", o->particles, seconds_particles / steps);
  fprintf(fp, "  \"min_element_quality\": %.6g,\n  \"min_element_quality_frame\": %d,\n", st.min_quality,
          st.min_quality_frame);
  fprintf(fp, "  \"max_divergence_relative\": %.6g,\n  \"max_boundary_flux_sum_relative\": %.6g,\n", st.max_div_rel,
          st.max_boundary_residual);
  json_array(fp, "min_quality", quality, T + 1, ",");
  json_array(fp, "max_divergence_per_frame", divergence, T + 1, ",");
  json_array(fp, "energy_full", energy, T + 1, "");
  fprintf(fp, "}\n");
  if (fclose(fp) != 0 || rename(tmp, path) != 0) {
    fprintf(stderr, "npg-fluids: %s: %s\n", path, strerror(errno));
    goto done;
  }
  rc = 0;
done:
  if (s_ok) solver_free(&s);
  particles_free(&part);
  free(g), free(energy), free(quality), free(divergence);
  cavity_free(&cv);
  return rc;
}
