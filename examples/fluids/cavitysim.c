/* cavitysim.c — npg-fluids cavity: paper §7.2, Fig. 6 and Table 1 (see cavitysim.h).
 * cavity_run, the table of contents of the experiment (its options and deformation schedule
 * are cavityschedule.c's, its training runs cavitytrain.c's): prepare the folders, mesh and bind,
 * train, the reduced solver and the replayed trajectory, the test runs (full and reduced
 * side by side, with the one-step and trajectory errors per frame), timings, plots, the
 * report (Table 1). */
#include "util.h"
#include "cavitysim.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cblas.h>

#include "npg.h"
#include "npgbind.h"
#include "output.h"
#include "particles.h"
#include "chart.h"
#include "plot.h"
#include "reduced.h"
#include "report.h"
#include "solver.h"

#ifndef FLUIDS_NPG3
#define FLUIDS_NPG3 "examples/fluids/fluids3d.npg"
#endif
#define ERRLEN 1024
#define PROGRAM "npg-fluids"

static double max_abs(const double *v, long n) {
  double m = 0;
  for (long i = 0; i < n; i++) m = fmax(m, fabs(v[i]));
  return m;
}

/* The run's figures, filled as it goes. */
typedef struct FullStats {
  double t_d, t_a, t_p;         /* seconds per step: deformation, advection, projection */
  double min_quality, max_div_rel, max_boundary_residual;
  int min_quality_frame;
  double wall_energy;           /* the largest ½ |Ω| v_wall² so far (check_blowup) */
} FullStats;

/* The cavity's fluid starts at rest (energy 0) and only its walls drive it,
 * so a run is stopped as unstable when its energy is not finite or exceeds
 * CAVITY_BLOWUP times the largest energy the walls' motion has had so far,
 * ½ |Ω| v², v the fastest vertex. Squeezing raises the fluid's speed over the
 * walls': stable test runs stayed below 9.7 times that reference (1,000
 * cells at dt 0.01 and 0.05, 120 frames; 200 cells at dt 0.002 and 0.01),
 * while an unstable one grows without bound (1,000 cells at dt 0.3: 5.1,
 * 42, 418, then 4.1e6 times it at frames 3 to 6; the trial's run reached
 * 9e262 and reported success). */
#define CAVITY_BLOWUP 1e4
static int check_blowup(FullStats *st, const FullSolver *s, double energy, int t) {
  const FluidMesh *m = s->m;
  double v2 = 0, vol = 0;
  for (int i = 0; i < m->nv; i++) {
    const double *v = s->gdot + 3 * i;
    v2 = fmax(v2, v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  }
  for (int c = 0; c < m->nc; c++) vol += s->ops.area[c];
  st->wall_energy = fmax(st->wall_energy, 0.5 * vol * v2);
  if (isfinite(energy) && !(energy > CAVITY_BLOWUP * st->wall_energy)) return 0;
  if (isfinite(energy))
    fprintf(stderr, "npg-fluids: test frame %d: the flow's energy reached %.3g, %.3g times the most the walls' motion "
                    "has carried (%.3g): the run is unstable and was stopped (lower --dt, or --nu)\n",
            t, energy, energy / st->wall_energy, st->wall_energy);
  else
    fprintf(stderr, "npg-fluids: test frame %d: the flow's energy is not finite: the run is unstable and was stopped "
                    "(lower --dt, or --nu)\n", t);
  return -1;
}

/* One frame of particles through the reduced flow, timed into *seconds:
 * the geometry lifted into gl (n_v x m_g), then each face's flux lifted
 * from pf (whose g is gl) when a particle first reaches one of its cells
 * (paper §6.5). 0, or -1 with a message. */
static int particles_reduced_frame(Particles *p, const FluidMesh *m, const RedSolver *R, long ng, double *gl,
                                   const ParticleFlow *pf, double dt, double *seconds) {
  double t0 = util_now();
  red_lift(R->Bg, ng, R->mg, R->g, gl);
  int rc = particles_advect_flow(p, m, pf, dt, 10);
  *seconds += util_now() - t0;
  if (rc) fprintf(stderr, "npg-fluids: particles: out of memory\n");
  return rc;
}

/* ½ uᵀ V u for cell volumes `vol`, u [C][3]. */
static double energy3(const double *vol, const double *u, long C) {
  double e = 0;
  for (long c = 0; c < C; c++) e += vol[c] * (u[3 * c] * u[3 * c] + u[3 * c + 1] * u[3 * c + 1] + u[3 * c + 2] * u[3 * c + 2]);
  return 0.5 * e;
}

/* E(u − ub)/E(u) at the full run's geometry, for ub = B_u û the lift of
 * the projection of its velocity u: how much of the full flow the basis
 * can hold at all (a floor under the reduced run's trajectory error).
 * `work` [3C]. */
static double basis_error(const FullSolver *s, const double *ub, double *work) {
  long C = s->m->nc;
  for (long j = 0; j < 3 * C; j++) work[j] = s->u[j] - ub[j];
  double e = energy3(s->ops.area, s->u, C);
  return e > 0 ? energy3(s->ops.area, work, C) / e : 0;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

/* Everything one experiment holds, so that each phase is a function of it. */
typedef struct CavityRun {
  CavityOptions o;              /* as given, with --frames and --sample-every chosen from the mesh */
  char err[ERRLEN], dframes[1100], dvtk[1100], dplots[1100], dparts[1100];
  Cavity cv;
  const FluidMesh *m;
  int mesh_ok, T, reduced;      /* frames; a model is trained (--runs > 0) */
  double mu, t_mesh;
  long ng, nf, nu, C;
  FullSolver s, probe;          /* the full test run; the one-step errors' full step */
  int s_ok, probe_ok, red_ok;
  RedSolver R;
  RedState keep;                /* the run's reduced state while a probe or a repetition steps from it */
  NpgProgram *prog;
  NpgFull *fe;
  NpgModel *model;
  Particles part, pred, pred1;  /* full flow, reduced flow, reduced on one thread */
  double *g, *gn, *gl, *fl, *ul, *pv;
  double *energy, *energy_red, *quality, *divergence; /* [T + 1] */
  double *err_traj, *err_step;  /* [T + 1] reduced against full; one step from the projected full state */
  double *err_basis;            /* [T + 1] E(u − B_u û)/E(u) of the full state's own projection */
  double *step_times, *frame_axis;
  double *traj_g, *traj_gd;     /* the replayed trajectory of the test: ĝ_t and ĝdot_t */
  double seconds_particles, seconds_particles_red, seconds_particles_red1, seconds_lift, t_deform;
  int particles_same;           /* pred1 moved as pred, bit for bit */
  float *Bf32, *fh32;           /* B_f and f̂ in single precision for the particles' lift */
  double train_split[4];        /* npg_trainer_finish's snapshots, bases, pre-multiplication, externs */
  CavityTraining ct;
  int train_threads;            /* OpenBLAS's in npg_trainer_finish */
  double seconds_train, div_basis, max_div_red, split[3]; /* split: the reduced step's assembly, exponential, projection */
  FullStats st;
  size_t model_bytes, tensor_bytes;
  /* the test's timings (per step) */
  double steps, t_full, t_s, t_s_median, t_s_min, t_s_rep, t_s_rep_median, err_traj_mean, err_step_mean;
  /* the reduced step against its bytes: what it streams (red_step_bytes), the read bandwidth
   * measured over as many bytes (the cache they fit in) and over 256 MB (memory) */
  RedBytes bytes;
  double bw_step, bw_mem;
} CavityRun;

static void velocity_times_volume(CavityRun *r) {
  for (long c = 0; c < r->C; c++)
    for (int d = 0; d < 3; d++) r->pv[3 * c + d] = r->s.ops.area[c] * r->s.u[3 * c + d];
}

/* ---------------------------------------------------------------- prepare */

/* DIR and its frames/ (with frames/.parts for the halves of a frame), vtk/, plots/. */
static int prepare(CavityRun *r) {
  const CavityOptions *o = &r->o;
  int rc = report_need_out(PROGRAM, "cavity", o->out, 1000);
  if (rc) return rc;
  snprintf(r->dframes, sizeof r->dframes, "%s/frames", o->out);
  snprintf(r->dvtk, sizeof r->dvtk, "%s/vtk", o->out);
  snprintf(r->dplots, sizeof r->dplots, "%s/plots", o->out);
  snprintf(r->dparts, sizeof r->dparts, "%s/frames/.parts", o->out);
  if (report_make_dir(PROGRAM, o->out) || report_make_dir(PROGRAM, r->dframes) || report_make_dir(PROGRAM, r->dvtk) ||
      report_make_dir(PROGRAM, r->dplots) || report_make_dir(PROGRAM, r->dparts))
    return 1;
  return 0;
}

/* ---------------------------------------------------------------- mesh and bind */

/* The cavity's mesh, the viscosity and the frames it sets, and the buffers. */
static int mesh(CavityRun *r) {
  CavityOptions *o = &r->o;
  r->t_mesh = util_now();
  if (cavity_mesh(&r->cv, &o->spec, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->mesh_ok = 1;
  r->t_mesh = util_now() - r->t_mesh;
  const FluidMesh *m = r->m = &r->cv.m;
  /* the graph Laplacian's rate in cell c is up to 8 mu / V_c: scaled by the smallest
   * cell, diffusion stays stable at every --nu * dt < 0.3 */
  double vmin = INFINITY;
  for (int c = 0; c < m->nc; c++) vmin = fmin(vmin, mesh_volume(m, m->g0, c));
  r->mu = o->nu * vmin;
  if (o->frames <= 0) o->frames = cavity_frames_for(m->nc); /* --frames 0: from the mesh */
  if (o->sample_every <= 0) o->sample_every = cavity_sample_every_for(o->frames);
  int T = r->T = o->frames;
  r->reduced = o->runs > 0;
  long ng = r->ng = 3L * m->nv, nf = r->nf = m->nf, nu = r->nu = 3L * m->nc;
  r->C = m->nc;
  fprintf(stderr,
          "npg-fluids: cavity %d cells, %d faces (%d boundary), %d vertices, meshed in %.1f s; min quality %.3f; "
          "dt %g, mu %.3g, %d frames per run\n",
          m->nc, m->nf, m->nb, m->nv, r->t_mesh, mesh_min_quality(m, m->g0, NULL), o->dt, r->mu, o->frames);
  r->g = malloc(ng * sizeof(double)), r->gn = malloc(ng * sizeof(double)), r->gl = malloc(ng * sizeof(double));
  r->fl = malloc(nf * sizeof(double)), r->ul = malloc(nu * sizeof(double)), r->pv = malloc(nu * sizeof(double));
  r->energy = calloc(T + 1, sizeof(double)), r->energy_red = calloc(T + 1, sizeof(double));
  r->quality = calloc(T + 1, sizeof(double)), r->divergence = calloc(T + 1, sizeof(double));
  r->err_traj = calloc(T + 1, sizeof(double)), r->err_step = calloc(T + 1, sizeof(double));
  r->err_basis = calloc(T + 1, sizeof(double));
  r->step_times = calloc(T + 1, sizeof(double)), r->frame_axis = calloc(T + 1, sizeof(double));
  r->particles_same = 1;
  r->st.min_quality = INFINITY;
  return 0;
}

/* fluids3d.npg compiled, a full evaluator (--backend) bound to the mesh. */
static int bind(CavityRun *r) {
  NpgOptions nopt = {0};
  r->prog = npg_compile(FLUIDS_NPG3, &nopt);
  if (!npg_ok(r->prog)) {
    fprintf(stderr, "%s", npg_error(r->prog));
    return 1;
  }
  r->fe = npg_full_new(r->prog, r->o.backend);
  if (npg_full_error(r->fe)[0] || fluid_bind(r->fe, r->m, r->mu) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", npg_full_error(r->fe));
    return 1;
  }
  return 0;
}

/* ---------------------------------------------------------------- train */

/* The training runs streamed into npg's trainer (paper §6, §7.2), and the model. */
static int train(CavityRun *r) {
  const CavityOptions *o = &r->o;
  /* caps: m_u for the shared class (u's own plus p, pv, pdot, lap), m_f, m_g and m_gdot;
   * h complete, so that D̂_h ĥ is accurate */
  NpgTrainOptions to;
  FluidBasisOptions mo;
  fluid_train_options(&to, &mo, o->mu - 4, o->mf, o->mg, 60);
  to.progress = isatty(STDERR_FILENO); /* the trainer's passes take minutes at the paper's size */
  NpgTrainer *tr = npg_trainer_new(r->fe, &to);
  if (cavity_train(&r->cv, o, r->mu, tr, &r->ct) != 0) {
    npg_trainer_free(tr);
    return 1;
  }
  r->st.min_quality = r->ct.min_quality;
  fprintf(stderr, "npg-fluids: training runs done in %.1f s on %d worker%s; training on %ld samples\n", r->ct.seconds,
          r->ct.workers, r->ct.workers == 1 ? "" : "s", npg_trainer_samples(tr));
  /* training on every core: OpenBLAS's threads for the Gram matrices and their
   * eigendecompositions, then back to what the reduced step is timed with (on a machine
   * loaded by other jobs one thread was faster: README) */
  int blas_threads = openblas_get_num_threads();
  r->train_threads = o->train_threads > 0 ? o->train_threads : o->workers;
  openblas_set_num_threads(r->train_threads);
  double t0 = util_now();
  r->model = npg_trainer_finish(tr, NULL);
  r->seconds_train = util_now() - t0;
  openblas_set_num_threads(blas_threads);
  if (!r->model) {
    fprintf(stderr, "npg-fluids: training: %s\n", npg_trainer_error(tr));
    npg_trainer_free(tr);
    return 1;
  }
  npg_model_train_seconds(r->model, r->train_split, NULL);
  npg_trainer_free(tr);
  r->model_bytes = npg_model_bytes(r->model, &r->tensor_bytes);
  return 0;
}

/* The reduced solver, its reduced constraints (--dtol), the particles' single-precision
 * copy of B_f (their lift reads half the bytes), and B_f's divergence. */
static int reduced_solver(CavityRun *r) {
  const CavityOptions *o = &r->o;
  RedSolver *R = &r->R;
  if (red_init(R, r->model, 3, r->mu, o->dt, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: reduced model: %s\n", r->err);
    return 1;
  }
  r->red_ok = 1;
  if (red_constraints(R, o->dtol, r->err, sizeof r->err) != 0 ||
      (o->single_advection && red_single_advection(R, r->err, sizeof r->err) != 0)) {
    fprintf(stderr, "npg-fluids: reduced model: %s\n", r->err);
    return 1;
  }
  long nf = r->nf;
  r->Bf32 = malloc((size_t)nf * R->mf * sizeof *r->Bf32);
  r->fh32 = malloc(R->mf * sizeof *r->fh32);
  if (!r->Bf32 || !r->fh32) {
    fprintf(stderr, "npg-fluids: out of memory\n");
    return 1;
  }
  for (size_t i = 0; i < (size_t)nf * R->mf; i++) r->Bf32[i] = (float)R->Bf[i];
  Ops ops;
  ops_init(&ops, r->m);
  r->div_basis = ops_max_column_divergence(&ops, R->Bf, nf, R->mf);
  ops_free(&ops);
  char every[48] = "every frame";
  if (o->sample_every > 1) snprintf(every, sizeof every, "one frame in %d", o->sample_every);
  const CavityTraining *ct = &r->ct;
  fprintf(stderr,
          "npg-fluids: %d training runs on %d worker%s (%ld samples, %s) in %.1f s (their steps %.1f s "
          "summed); trained on %d BLAS thread%s in %.1f s (snapshots %.1f, bases %.1f, pre-multiplication %.1f); "
          "m_u %ld, m_f %ld, m_g %ld, m_gdot %ld, m_d %ld (rank of D̂ %ld); reduced set-up %.1f s (%ld reduced "
          "evaluations); model %.1f MB; max |div| over B_f's columns %.2e\n",
          o->runs, ct->workers, ct->workers == 1 ? "" : "s", npg_model_samples(r->model), every, ct->seconds,
          ct->seconds_runs, r->train_threads, r->train_threads == 1 ? "" : "s", r->seconds_train, r->train_split[0],
          r->train_split[1], r->train_split[2], R->mu, R->mf, R->mg, R->mgd, R->mb, R->drank, R->seconds_setup,
          R->evals, r->model_bytes / 1e6, r->div_basis);
  return 0;
}

/* The replayed trajectory of the test: ĝ_t and ĝdot_t. */
static int replay_trajectory(CavityRun *r) {
  const RedSolver *R = &r->R;
  long ng = r->ng;
  int T = r->T;
  r->traj_g = malloc((size_t)(T + 1) * R->mg * sizeof(double));
  r->traj_gd = calloc((size_t)T * R->mgd + 1, sizeof(double));
  for (int t = 0; t <= T; t++) {
    if (cavity_deform_at(&r->cv, -1, t, T, r->gl, &r->t_deform, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", r->err);
      return 1;
    }
    red_coords(R->Bg, ng, R->mg, r->gl, r->traj_g + (size_t)t * R->mg);
    if (t > 0) {
      for (long i = 0; i < ng; i++) r->gn[i] = (r->gl[i] - r->gn[i]) / r->o.dt;
      red_coords(R->Bgd, ng, R->mgd, r->gn, r->traj_gd + (size_t)(t - 1) * R->mgd);
    }
    memcpy(r->gn, r->gl, ng * sizeof(double));
  }
  return 0;
}

/* ---------------------------------------------------------------- the test runs */

/* The full test run at frame 0 (and its probe), the particles, the reduced start: the
 * projected full state. */
static int set_up_test(CavityRun *r) {
  const CavityOptions *o = &r->o;
  const FluidMesh *m = r->m;
  const double zero[3] = {0};
  r->t_deform = 0;
  if (cavity_deform_at(&r->cv, -1, 0, r->T, r->g, &r->t_deform, r->err, sizeof r->err) != 0 ||
      solver_init_at(&r->s, m, o->projection, r->mu, o->dt, r->g, zero, r->err, sizeof r->err) != 0 ||
      (r->s_ok = 1,
       r->reduced && solver_init_at(&r->probe, m, o->projection, r->mu, o->dt, r->g, zero, r->err, sizeof r->err) != 0)) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->probe_ok = r->reduced;
  r->t_deform = 0;
  if (particles_seed(&r->part, m, r->s.g, o->particles, 12345) != 0 ||
      (r->reduced && particles_seed(&r->pred, m, r->s.g, o->particles, 12345) != 0) ||
      (r->reduced && o->particle_threads > 1 && particles_seed(&r->pred1, m, r->s.g, o->particles, 12345) != 0)) {
    fprintf(stderr, "npg-fluids: out of memory for %d particles: fewer --particles\n", o->particles);
    return 1;
  }
  r->part.threads = o->particle_threads;
  if (r->reduced) {
    RedSolver *R = &r->R;
    r->pred.threads = o->particle_threads;
    memcpy(R->g, r->traj_g, R->mg * sizeof(double));
    velocity_times_volume(r);
    red_coords(R->Bf, r->nf, R->mf, r->s.f, R->f);
    red_project_u(R, R->g, r->pv, R->u);
    r->energy_red[0] = red_energy(R, R->g, R->u);
  }
  r->energy[0] = solver_energy(&r->s);
  r->quality[0] = r->s.min_quality;
  return 0;
}

/* The one-step error from the projected full state of frame t - 1 (to frame t at
 * positions r->g): the probe's full step from the lifted state against the reduced step. */
static int onestep_error(CavityRun *r, int t) {
  RedSolver *q = &r->R;
  FullSolver *probe = &r->probe;
  long nf = r->nf, nu = r->nu, C = r->C;
  double *gp = r->traj_g + (size_t)(t - 1) * q->mg, *gq = r->traj_g + (size_t)t * q->mg;
  if (red_state_save(q, &r->keep) != 0) {
    fprintf(stderr, "npg-fluids: out of memory\n");
    return -1;
  }
  velocity_times_volume(r);
  memcpy(q->g, gp, q->mg * sizeof(double));
  red_coords(q->Bf, nf, q->mf, r->s.f, q->f);
  red_project_u(q, q->g, r->pv, q->u);
  memcpy(probe->g, r->s.g, r->ng * sizeof(double));
  red_lift(q->Bf, nf, q->mf, q->f, probe->f);
  red_lift(q->Bu, nu, q->mu, q->u, probe->u);
  r->err_basis[t - 1] = basis_error(&r->s, probe->u, r->ul);
  ops_set_geometry(&probe->ops, probe->g);
  int prc = solver_step_to(probe, r->g, r->err, sizeof r->err);
  if (!prc) prc = red_step(q, gq, r->traj_gd + (size_t)(t - 1) * q->mgd, r->err, sizeof r->err);
  if (!prc) {
    red_lift(q->Bu, nu, q->mu, q->u, r->ul);
    for (long j = 0; j < nu; j++) r->ul[j] = probe->u[j] - r->ul[j];
    double ef = energy3(probe->ops.area, probe->u, C);
    r->err_step[t] = ef > 0 ? energy3(probe->ops.area, r->ul, C) / ef : 0;
  }
  red_state_restore(q, &r->keep);
  if (prc) {
    fprintf(stderr, "npg-fluids: one-step error, frame %d: %s\n", t, r->err);
    return -1;
  }
  return 0;
}

/* The full run's step to frame t (positions r->g), its particles and figures. */
static int full_step(CavityRun *r, int t) {
  FullSolver *s = &r->s;
  if (solver_step_to(s, r->g, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: test frame %d: %s\n", t, r->err);
    return -1;
  }
  r->energy[t] = solver_energy(s);
  if (check_blowup(&r->st, s, r->energy[t], t) != 0) return -1;
  double t0 = util_now();
  ParticleFlow pf = {.g = s->g, .f = s->f};
  if (particles_advect_flow(&r->part, r->m, &pf, r->o.dt, 10) != 0) {
    fprintf(stderr, "npg-fluids: particles: out of memory\n");
    return -1;
  }
  r->seconds_particles += util_now() - t0;
  r->quality[t] = s->min_quality;
  double sb = 0;
  for (int b = 0; b < r->m->nb; b++) sb += s->h[r->m->bface[b]];
  r->st.max_boundary_residual = fmax(r->st.max_boundary_residual, fabs(sb) / fmax(max_abs(s->h, r->nf), 1e-300));
  return 0;
}

/* The reduced step to frame t, timed alone (its split too: the probe's and the
 * repetitions' steps are not the run's); the particles through the reduced flow, never
 * lifted whole (and again on one thread, timed apart); the trajectory error and the
 * divergence of the lifted flux. */
static int reduced_step(CavityRun *r, int t) {
  const CavityOptions *o = &r->o;
  const FluidMesh *m = r->m;
  RedSolver *R = &r->R;
  long nf = r->nf, nu = r->nu, C = r->C;
  double e0 = R->seconds_eval, x0 = R->seconds_advection, p0 = R->seconds_projection;
  double a0 = util_now();
  if (red_step(R, r->traj_g + (size_t)t * R->mg, r->traj_gd + (size_t)(t - 1) * R->mgd, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: reduced step, frame %d: %s\n", t, r->err);
    return -1;
  }
  r->step_times[t - 1] = util_now() - a0;
  r->split[0] += R->seconds_eval - e0, r->split[1] += R->seconds_advection - x0;
  r->split[2] += R->seconds_projection - p0;
  r->energy_red[t] = red_energy(R, R->g, R->u);
  for (long k = 0; k < R->mf; k++) r->fh32[k] = (float)R->f[k];
  ParticleFlow pf = {.g = r->gl, .Bf = r->Bf32, .fh = r->fh32, .mf = (int)R->mf};
  if (particles_reduced_frame(&r->pred, m, R, r->ng, r->gl, &pf, o->dt, &r->seconds_particles_red) != 0) return -1;
  if (r->pred1.n) {
    if (particles_reduced_frame(&r->pred1, m, R, r->ng, r->gl, &pf, o->dt, &r->seconds_particles_red1) != 0)
      return -1;
    r->particles_same &= !memcmp(r->pred.x, r->pred1.x, 3 * (size_t)r->pred.n * sizeof *r->pred.x) &&
                         !memcmp(r->pred.cell, r->pred1.cell, (size_t)r->pred.n * sizeof *r->pred.cell);
  }
  /* the whole flux, for the divergence check (timed for comparison) */
  a0 = util_now();
  red_lift(R->Bf, nf, R->mf, R->f, r->fl);
  r->seconds_lift += util_now() - a0;
  const Ops *op = &r->s.ops; /* V(g_t) of the full run: the energy norm of the error */
  red_lift(R->Bu, nu, R->mu, R->u, r->ul);
  for (long j = 0; j < nu; j++) r->ul[j] = r->s.u[j] - r->ul[j];
  double ef = energy3(op->area, r->s.u, C);
  r->err_traj[t] = ef > 0 ? energy3(op->area, r->ul, C) / ef : 0;
  double dmax = 0;
  for (int c = 0; c < C; c++) {
    double dv = 0;
    for (int k = 0; k < 4; k++) dv += m->csign[4 * c + k] * r->fl[m->cface[4 * c + k]];
    dmax = fmax(dmax, fabs(dv));
  }
  r->max_div_red = fmax(r->max_div_red, dmax / fmax(max_abs(r->fl, nf), 1e-300));
  return 0;
}

/* Frame t's figures, and its PNG (full | reduced) and VTK files when due. */
static int output_frame(CavityRun *r, int t) {
  const CavityOptions *o = &r->o;
  const FluidMesh *m = r->m;
  const FullSolver *s = &r->s;
  RedSolver *R = &r->R;
  char path[4096], p2[4096], p3[4096];
  int T = r->T;
  r->divergence[t] = projection_max_divergence(&s->ops, s->f) / fmax(max_abs(s->f, r->nf), 1e-300);
  r->st.max_div_rel = fmax(r->st.max_div_rel, r->divergence[t]);
  if (r->quality[t] < r->st.min_quality) r->st.min_quality = r->quality[t], r->st.min_quality_frame = t;
  if (!isfinite(r->energy[t])) {
    fprintf(stderr, "npg-fluids: the energy is not finite at frame %d: unstable (lower --dt)\n", t);
    return -1;
  }
  if (output_frame_due(t, T, o->png_every)) {
    double extent = o->spec.D + o->spec.r;
    snprintf(path, sizeof path, "%s/full_%04d.png", r->dparts, t);
    if (output_png_points(path, m, s->g, &r->part, extent, o->width, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", r->err);
      return -1;
    }
    snprintf(p3, sizeof p3, "%s/frame_%04d.png", r->dframes, t);
    if (r->reduced) {
      red_lift(R->Bg, r->ng, R->mg, R->g, r->gl);
      snprintf(p2, sizeof p2, "%s/reduced_%04d.png", r->dparts, t);
      char cl[64], cr[96];
      snprintf(cl, sizeof cl, "full, frame %d", t);
      snprintf(cr, sizeof cr, "reduced (m_u %ld, m_f %ld, m_g %ld), frame %d", R->mu, R->mf, R->mg, t);
      if (output_png_points(p2, m, r->gl, &r->pred, extent, o->width, r->err, sizeof r->err) != 0 ||
          plot_side_by_side(p3, path, p2, cl, cr, r->err, sizeof r->err) != 0) {
        fprintf(stderr, "npg-fluids: %s\n", r->err);
        return -1;
      }
      remove(p2);
    } else if (rename(path, p3) != 0) {
      fprintf(stderr, "npg-fluids: %s: %s\n", p3, strerror(errno));
      return -1;
    }
    remove(path);
  }
  if (output_frame_due(t, T, o->vtk_every)) {
    snprintf(path, sizeof path, "%s/full_%04d.vtk", r->dvtk, t);
    if (output_vtk_tets(path, m, s->g, s->u, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", r->err);
      return -1;
    }
    if (r->reduced) {
      red_lift(R->Bg, r->ng, R->mg, R->g, r->gl);
      red_lift(R->Bu, r->nu, R->mu, R->u, r->ul);
      snprintf(path, sizeof path, "%s/reduced_%04d.vtk", r->dvtk, t);
      if (output_vtk_tets(path, m, r->gl, r->ul, r->err, sizeof r->err) != 0) {
        fprintf(stderr, "npg-fluids: %s\n", r->err);
        return -1;
      }
    }
  }
  return 0;
}

/* The last frame's basis error (the probe gave the others). */
static int last_basis_error(CavityRun *r) {
  RedSolver *R = &r->R;
  velocity_times_volume(r);
  double *uc = malloc(R->mu * sizeof(double));
  if (!uc || red_state_save(R, &r->keep) != 0) {
    free(uc);
    fprintf(stderr, "npg-fluids: out of memory\n");
    return 1;
  }
  red_project_u(R, r->traj_g + (size_t)r->T * R->mg, r->pv, uc);
  red_state_restore(R, &r->keep);
  red_lift(R->Bu, r->nu, R->mu, uc, r->pv);
  r->err_basis[r->T] = basis_error(&r->s, r->pv, r->ul);
  free(uc);
  return 0;
}

/* The test sequence: full, and reduced beside it from the projected start on the
 * replayed trajectory; per frame the one-step error from the projected full state (a
 * probe solver) and the trajectory error. */
static int run_test(CavityRun *r) {
  if (set_up_test(r) != 0) return 1;
  for (int t = 0; t <= r->T; t++) {
    if (t > 0) {
      if (cavity_deform_at(&r->cv, -1, t, r->T, r->g, &r->t_deform, r->err, sizeof r->err) != 0) {
        fprintf(stderr, "npg-fluids: test frame %d: %s\n", t, r->err);
        return 1;
      }
      if (r->reduced && onestep_error(r, t) != 0) return 1;
      if (full_step(r, t) != 0) return 1;
      if (r->reduced && reduced_step(r, t) != 0) return 1;
    }
    if (output_frame(r, t) != 0) return 1;
  }
  rmdir(r->dparts);
  if (r->reduced && last_basis_error(r) != 0) return 1;
  return 0;
}

/* The per-step timings; for the reduced run the step's mean, median, minimum and the
 * minimum of 50 repeats from one state (the least disturbed figure), the error means. */
static int timings(CavityRun *r) {
  const FullSolver *s = &r->s;
  int T = r->T;
  r->steps = T > 0 ? T : 1;
  r->st.t_d = (s->seconds_deformation + r->t_deform) / r->steps;
  r->st.t_a = s->seconds_advection / r->steps;
  r->st.t_p = s->seconds_projection / r->steps;
  r->t_full = r->st.t_d + r->st.t_a + r->st.t_p;
  if (!r->reduced) return 0;
  RedSolver *R = &r->R;
  for (int t = 0; t < T; t++) r->t_s += r->step_times[t] / T;
  qsort(r->step_times, T, sizeof *r->step_times, cmp_double);
  r->t_s_median = r->step_times[T / 2], r->t_s_min = r->step_times[0];
  double best = INFINITY, rep[50];
  int nrep = 0;
  if (red_state_save(R, &r->keep) != 0) {
    fprintf(stderr, "npg-fluids: out of memory\n");
    return 1;
  }
  for (int k = 0; k < 50; k++) {
    red_state_restore(R, &r->keep);
    double a0 = util_now();
    if (red_step(R, r->traj_g + (size_t)(T - 1) * R->mg, r->traj_gd + (size_t)(T - 2) * R->mgd, r->err,
                 sizeof r->err) != 0)
      break;
    best = fmin(best, rep[nrep++] = util_now() - a0);
  }
  r->t_s_rep = best;
  /* the median of the repeats: steps one after the other with nothing between them (a reduced
   * rollout alone), where the test's steps alternate with full steps that evict the tensors */
  qsort(rep, (size_t)nrep, sizeof *rep, cmp_double);
  r->t_s_rep_median = nrep ? rep[nrep / 2] : NAN;
  red_step_bytes(R, 1, &r->bytes);
  r->bw_step = util_read_bandwidth((size_t)r->bytes.total, 0.2);
  r->bw_mem = util_read_bandwidth((size_t)256 << 20, 0.5);
  for (int t = 1; t <= T; t++) r->err_traj_mean += r->err_traj[t] / T, r->err_step_mean += r->err_step[t] / T;
  return 0;
}

/* ---------------------------------------------------------------- plots */

/* plots/trajectory_error.png (with the basis error under it) and onestep_error.png. */
static int plots(CavityRun *r) {
  if (!r->reduced) return 0;
  int T = r->T;
  char path[4096], p2[4096];
  for (int t = 0; t <= T; t++) r->frame_axis[t] = t;
  bool dots = T <= 40;
  ChartSeries traj[2] = {{"reduced vs full", T, r->frame_axis + 1, r->err_traj + 1, -1, false, dots},
                         {"the full state projected onto B_u", T, r->frame_axis + 1, r->err_basis + 1, -1, false, dots}};
  ChartSeries step = {"one step from the projected full state", T, r->frame_axis + 1, r->err_step + 1, -1, false, dots};
  Chart c1 = {.title = "cavity test sequence: reduced trajectory error (energy, relative)", .xlabel = "frame",
              .ylabel = "E(u - B_u û) / E(u)", .logy = true, .nseries = 2, .series = traj};
  Chart c2 = {.title = "cavity test sequence: one-step error (energy, relative)", .xlabel = "frame",
              .ylabel = "E(u - B_u û) / E(u)", .logy = true, .nseries = 1, .series = &step};
  snprintf(path, sizeof path, "%s/trajectory_error.png", r->dplots);
  snprintf(p2, sizeof p2, "%s/onestep_error.png", r->dplots);
  if (chart_png(&c1, path, PLOT_WIDTH, PLOT_HEIGHT, r->err, sizeof r->err) != 0 ||
      chart_png(&c2, p2, PLOT_WIDTH, PLOT_HEIGHT, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  return 0;
}

/* ---------------------------------------------------------------- report */

/* The reduced step against its byte bound: bytes streamed / read bandwidth over as many bytes. */
static void step_bytes_summary(const CavityRun *r) {
  const RedBytes *b = &r->bytes;
  double bound = r->bw_step > 0 ? b->total / (r->bw_step * 1e9) : 0, mem = r->bw_mem > 0 ? b->total / (r->bw_mem * 1e9) : 0;
  fprintf(stderr, "npg-fluids: reduced step reads %.3g MB:", b->total / 1e6);
  for (int i = 0; i < b->n; i++) fprintf(stderr, "%s %s %.3g MB", i ? ";" : "", b->name[i], b->bytes[i] / 1e6);
  fprintf(stderr,
          "; read bandwidth %.3g GB/s over as many bytes, %.3g GB/s over 256 MB: bound %.3g ms (%.3g ms from "
          "memory); the test's median step %.3g ms, %.2fx the bound; repeated alone, median %.3g ms (%.2fx), "
          "best %.3g ms (%.2fx)\n",
          r->bw_step, r->bw_mem, 1e3 * bound, 1e3 * mem, 1e3 * r->t_s_median, bound > 0 ? r->t_s_median / bound : 0,
          1e3 * r->t_s_rep_median, bound > 0 ? r->t_s_rep_median / bound : 0, 1e3 * r->t_s_rep,
          bound > 0 ? r->t_s_rep / bound : 0);
}

/* The summary on stderr. */
static void report_summary(const CavityRun *r) {
  const CavityOptions *o = &r->o;
  const FullStats *st = &r->st;
  int T = r->T;
  double steps = r->steps;
  fprintf(stderr,
          "npg-fluids: test, %d frames: full t_d %.3g ms, t_a %.3g ms, t_p %.3g ms (step %.3g ms); particles %.3g "
          "ms/frame; max |div| / max |f| %.2e; min quality %.3f (frame %d); energy %.4g -> %.4g\n",
          T, 1e3 * st->t_d, 1e3 * st->t_a, 1e3 * st->t_p, 1e3 * r->t_full, 1e3 * r->seconds_particles / steps,
          st->max_div_rel, st->min_quality, st->min_quality_frame, r->energy[0], r->energy[T]);
  if (r->reduced)
    fprintf(stderr,
            "npg-fluids: reduced t_s %.3g ms (median %.3g, min %.3g, repeated %.3g; assembly %.3g, exponential "
            "%.3g, projection %.3g), speedup %.1f (repeated %.1f); "
            "t_pa %.3g ms on %d thread%s (%.3g ms on one; %.0f cells visited, %.0f faces lifted a frame; the whole B_f f̂ "
            "would take %.3g ms); trajectory error mean %.3g, final %.3g (the full state's own projection "
            "onto B_u: %.3g at frame %d, %.3g at the end); one-step error mean %.3g; reduced energy %.4g -> %.4g\n",
            1e3 * r->t_s, 1e3 * r->t_s_median, 1e3 * r->t_s_min, 1e3 * r->t_s_rep, 1e3 * r->split[0] / steps,
            1e3 * r->split[1] / steps, 1e3 * r->split[2] / steps, r->t_full / r->t_s, r->t_full / r->t_s_rep,
            1e3 * r->seconds_particles_red / steps, o->particle_threads, o->particle_threads == 1 ? "" : "s",
            1e3 * (r->pred1.n ? r->seconds_particles_red1 : r->seconds_particles_red) / steps,
            (double)r->pred.cells_visited / steps, (double)r->pred.faces_lifted / steps, 1e3 * r->seconds_lift / steps,
            r->err_traj_mean, r->err_traj[T], r->err_basis[T / 10], T / 10, r->err_basis[T], r->err_step_mean,
            r->energy_red[0], r->energy_red[T]);
  if (r->reduced) step_bytes_summary(r);
}

/* report.json's reduced half: training, the model, the reduced step (Table 1). */
static void report_reduced(const CavityRun *r, FILE *fp) {
  const CavityOptions *o = &r->o;
  const RedSolver *R = &r->R;
  int T = r->T;
  double steps = r->steps;
  fprintf(fp, "  \"training_runs\": %d,\n  \"workers\": %d,\n  \"train_threads\": %d,\n  \"sample_every\": %d,\n"
              "  \"train_backend\": \"%s\",\n  \"training_samples\": %ld,\n  \"training_runs_seconds\": %.4g,\n"
              "  \"training_runs_steps_seconds\": %.4g,\n  \"training_seconds\": %.4g,\n",
          o->runs, r->ct.workers, r->train_threads, o->sample_every, o->backend == NPG_CC ? "cc" : "tcc",
          npg_model_samples(r->model), r->ct.seconds, r->ct.seconds_runs, r->seconds_train);
  fprintf(fp, "  \"training_split\": {\"snapshots\": %.4g, \"bases\": %.4g, \"premultiplication\": %.4g, "
              "\"externs\": %.4g},\n",
          r->train_split[0], r->train_split[1], r->train_split[2], r->train_split[3]);
  fprintf(fp, "  \"reduced_setup_seconds\": %.4g,\n  \"reduced_setup_evaluations\": %ld,\n", R->seconds_setup, R->evals);
  fprintf(fp, "  \"precomputation_seconds\": %.4g,\n", r->ct.seconds + r->seconds_train + R->seconds_setup);
  fprintf(fp, "  \"m_f\": %ld,\n  \"m_u\": %ld,\n  \"m_g\": %ld,\n  \"m_gdot\": %ld,\n  \"m_d\": %ld,\n  \"rank_D\": %ld,\n",
          R->mf, R->mu, R->mg, R->mgd, R->mb, R->drank);
  fprintf(fp, "  \"model_bytes\": %zu,\n  \"model_tensor_bytes\": %zu,\n", r->model_bytes, r->tensor_bytes);
  fprintf(fp, "  \"t_s\": %.6g,\n  \"t_s_median\": %.6g,\n  \"t_s_min\": %.6g,\n  \"t_s_repeated_min\": %.6g,\n",
          r->t_s, r->t_s_median, r->t_s_min, r->t_s_rep);
  fprintf(fp, "  \"t_s_repeated_median\": %.6g,\n", r->t_s_rep_median);
  fprintf(fp, "  \"single_advection\": %s,\n", o->single_advection ? "true" : "false");
  fprintf(fp, "  \"step_bytes\": {");
  for (int i = 0; i < r->bytes.n; i++) fprintf(fp, "%s\"%s\": %.0f", i ? ", " : "", r->bytes.name[i], r->bytes.bytes[i]);
  fprintf(fp, "},\n  \"step_bytes_total\": %.0f,\n  \"read_bandwidth_step_bytes\": %.6g,\n"
              "  \"read_bandwidth_256mb\": %.6g,\n",
          r->bytes.total, r->bw_step * 1e9, r->bw_mem * 1e9);
  fprintf(fp, "  \"t_s_split\": {\"assembly\": %.6g, \"exponential\": %.6g, \"projection\": %.6g},\n",
          r->split[0] / steps, r->split[1] / steps, r->split[2] / steps);
  fprintf(fp, "  \"t_pa\": %.6g,\n  \"t_pa_one_thread\": %.6g,\n  \"particle_threads_same_motion\": %s,\n"
              "  \"t_lift_whole_flux\": %.6g,\n  \"particle_cells_visited_per_frame\": %.6g,\n"
              "  \"particle_faces_lifted_per_frame\": %.6g,\n  \"particle_basis_bytes\": %zu,\n",
          r->seconds_particles_red / steps, (r->pred1.n ? r->seconds_particles_red1 : r->seconds_particles_red) / steps,
          r->particles_same ? "true" : "false", r->seconds_lift / steps, (double)r->pred.cells_visited / steps,
          (double)r->pred.faces_lifted / steps, (size_t)r->nf * R->mf * sizeof *r->Bf32);
  fprintf(fp, "  \"speedup\": %.4g,\n  \"speedup_repeated\": %.4g,\n", r->t_full / r->t_s, r->t_full / r->t_s_rep);
  fprintf(fp, "  \"basis_f_max_divergence\": %.6g,\n  \"max_divergence_reduced_relative\": %.6g,\n", r->div_basis,
          r->max_div_red);
  fprintf(fp, "  \"trajectory_error_mean\": %.6g,\n  \"onestep_error_mean\": %.6g,\n", r->err_traj_mean,
          r->err_step_mean);
  report_json_array(fp, "  ", "trajectory_error", r->err_traj, T + 1, 6, ",\n");
  report_json_array(fp, "  ", "onestep_error", r->err_step, T + 1, 6, ",\n");
  report_json_array(fp, "  ", "basis_error", r->err_basis, T + 1, 6, ",\n");
  report_json_array(fp, "  ", "energy_reduced", r->energy_red, T + 1, 6, ",\n");
}

/* The summary, then report.json. */
static int report(CavityRun *r) {
  const CavityOptions *o = &r->o;
  const FluidMesh *m = r->m;
  const FullSolver *s = &r->s;
  const FullStats *st = &r->st;
  int T = r->T;
  report_summary(r);
  Report rep;
  if (report_open(&rep, PROGRAM, o->out) != 0) return 1;
  FILE *fp = rep.f;
  fprintf(fp, "{\n  \"command\": \"cavity\",\n  \"cells\": %d,\n  \"faces\": %d,\n  \"boundary_faces\": %d,\n"
              "  \"vertices\": %d,\n  \"mesh_seconds\": %.4g,\n  \"frames\": %d,\n  \"dt\": %g,\n  \"mu\": %.6g,\n",
          m->nc, m->nf, m->nb, m->nv, r->t_mesh, T, o->dt, r->mu);
  fprintf(fp, "  \"t_d\": %.6g,\n  \"t_a\": %.6g,\n  \"t_p\": %.6g,\n  \"full_step_seconds\": %.6g,\n", st->t_d, st->t_a,
          st->t_p, r->t_full);
  fprintf(fp, "  \"projection_method\": \"%s\",\n  \"projection_factorization_seconds\": %.6g,\n"
              "  \"projection_solve_seconds\": %.6g,\n",
          projection_method_name(o->projection), s->pr.seconds_numeric / r->steps, s->pr.seconds_solve / r->steps);
  projection_report_counts(fp, &s->pr);
  fprintf(fp, "  \"particles\": %d,\n  \"particle_threads\": %d,\n  \"t_pa_full_flow\": %.6g,\n", o->particles,
          o->particle_threads, r->seconds_particles / r->steps);
  if (r->reduced) report_reduced(r, fp);
  fprintf(fp, "  \"min_element_quality\": %.6g,\n  \"min_element_quality_frame\": %d,\n", st->min_quality,
          st->min_quality_frame);
  fprintf(fp, "  \"max_divergence_relative\": %.6g,\n  \"max_boundary_flux_sum_relative\": %.6g,\n", st->max_div_rel,
          st->max_boundary_residual);
  report_json_array(fp, "  ", "min_quality", r->quality, T + 1, 6, ",\n");
  report_json_array(fp, "  ", "max_divergence_per_frame", r->divergence, T + 1, 6, ",\n");
  report_json_array(fp, "  ", "energy_full", r->energy, T + 1, 6, "\n");
  fprintf(fp, "}\n");
  return report_commit(&rep, PROGRAM) ? 1 : 0;
}

static void release(CavityRun *r) {
  if (r->s_ok) solver_free(&r->s);
  if (r->probe_ok) solver_free(&r->probe);
  red_state_free(&r->keep);
  if (r->red_ok) red_free(&r->R);
  if (r->model) npg_model_free(r->model);
  if (r->fe) npg_full_free(r->fe);
  if (r->prog) npg_free(r->prog);
  particles_free(&r->part);
  particles_free(&r->pred);
  particles_free(&r->pred1);
  free(r->Bf32), free(r->fh32);
  free(r->g), free(r->gn), free(r->gl), free(r->fl), free(r->ul), free(r->pv), free(r->energy), free(r->energy_red);
  free(r->quality), free(r->divergence), free(r->err_traj), free(r->err_step), free(r->err_basis);
  free(r->step_times), free(r->frame_axis), free(r->traj_g), free(r->traj_gd);
  if (r->mesh_ok) cavity_free(&r->cv);
  chart_cleanup();
}

int cavity_run(const CavityOptions *o) {
  CavityRun *r = calloc(1, sizeof *r);
  if (!r) return 1;
  r->o = *o;
  int rc = prepare(r);
  if (!rc) rc = mesh(r);
  if (!rc && r->reduced) rc = bind(r);
  if (!rc && r->reduced) rc = train(r);
  if (!rc && r->reduced) rc = reduced_solver(r);
  if (!rc && r->reduced) rc = replay_trajectory(r);
  if (!rc) rc = run_test(r);
  if (!rc) rc = timings(r);
  if (!rc) rc = plots(r);
  if (!rc) rc = report(r);
  release(r);
  free(r);
  return rc;
}
