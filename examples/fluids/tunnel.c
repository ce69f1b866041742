/* tunnel.c — npg-fluids tunnel: paper Fig. 5 (see tunnel.h). Everything npg does here
 * goes through npg.h: compiling fluids2d.npg, binding the mesh, streaming training, the
 * models' bases and reduced evaluation. tunnel_run is the table of contents: prepare the
 * folders, mesh and bind, train (two runs streamed, one model per basis size), set up the
 * reduced solvers, the test runs (full and reduced side by side, with every model's
 * one-step error per frame), the reduced step benchmarked alone, plots, VTK, report. */
#include "util.h"
#include "tunnel.h"

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

#ifndef FLUIDS_NPG
#define FLUIDS_NPG "examples/fluids/fluids2d.npg"
#endif
#define ERRLEN 1024
#define PROGRAM "npg-fluids"

void tunnel_options_default(TunnelOptions *o) {
  memset(o, 0, sizeof *o);
  o->frames = 300, o->particles = 3000, o->png_every = 25, o->vtk_every = 25, o->width = 640;
  o->spec = tunnel_spec_default();
  o->scale_large = 1.25, o->scale_small = 0.75, o->scale_test = 1.0;
  o->pulse = 0.05, o->period = 100, o->mu = 0.002, o->cfl = 0.25, o->u0 = 1;
  o->nsizes = 5;
  int sizes[] = {8, 16, 32, 64, 128};
  memcpy(o->mu_sizes, sizes, sizeof sizes);
  o->mg_cap = 5;
}

static double sigma_at(double scale, const TunnelOptions *o, int t) {
  return tunnel_obstacle_scale(scale, o->pulse, o->period, t);
}

/* Training samples of both runs: sample t of a run is the state of frame t
 * (g, f, u) with the mesh velocity of the step that leaves it. */
typedef struct Samples {
  long n, cap, ng, nf, nu;
  double *g, *gdot, *f, *u;
} Samples;

static int stage_sample(NpgTrainer *t, const Samples *S, long k) {
  long sg[2] = {S->ng / 2, 2}, sf[1] = {S->nf}, su[1] = {S->nu};
  if (npg_trainer_set(t, "g", 2, sg, S->g + k * S->ng) || npg_trainer_set(t, "gdot", 2, sg, S->gdot + k * S->ng) ||
      npg_trainer_set(t, "f", 1, sf, S->f + k * S->nf) || npg_trainer_set(t, "u", 1, su, S->u + k * S->nu) ||
      npg_trainer_add(t))
    return -1;
  return 0;
}

/* The options of model i: m_u = cap of u + one vector of each momentum
 * member (p, pv, pdot, lap), m_f = m_u / 2, m_g by its energy (the
 * deformation spans a few vectors). */
static void model_options(const TunnelOptions *o, int i, NpgTrainOptions *to, FluidBasisOptions *mo) {
  int mu = o->mu_sizes[i], mf = mu / 2 > 2 ? mu / 2 : 2;
  fluid_train_options(to, mo, mu > 5 ? mu - 4 : 1, mf, o->mg_cap, o->mg_cap);
}

/* ½ uᵀ V u with cell areas. */
static double energy_area(const double *area, const double *u, long C) {
  double e = 0;
  for (long c = 0; c < C; c++) e += area[c] * (u[2 * c] * u[2 * c] + u[2 * c + 1] * u[2 * c + 1]);
  return 0.5 * e;
}

/* One full training run at obstacle scale `scale`: samples appended to S,
 * and streamed into `t` (when not NULL) as they happen. */
static int training_run(const FluidMesh *m, const TunnelOptions *o, double scale, double dt, Samples *S, NpgTrainer *t,
                        double *seconds) {
  char err[ERRLEN];
  FullSolver s;
  double u0[2] = {o->u0, 0};
  if (solver_init(&s, m, PROJ_STREAM_CHOLMOD, o->mu, dt, sigma_at(scale, o, 0), u0, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return -1;
  }
  double t0 = util_now(), e0 = solver_energy(&s);
  for (int k = 0; k < o->frames; k++) {
    long i = S->n++;
    memcpy(S->g + i * S->ng, s.g, S->ng * sizeof(double));
    memcpy(S->f + i * S->nf, s.f, S->nf * sizeof(double));
    memcpy(S->u + i * S->nu, s.u, S->nu * sizeof(double));
    if (solver_step(&s, sigma_at(scale, o, k + 1), err, sizeof err) != 0 ||
        solver_check_energy(e0, solver_energy(&s), k + 1, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: training run at scale %g, frame %d: %s\n", scale, k, err);
      solver_free(&s);
      return -1;
    }
    memcpy(S->gdot + i * S->ng, s.gdot, S->ng * sizeof(double));
    if (t && stage_sample(t, S, i) != 0) {
      fprintf(stderr, "npg-fluids: trainer: %s\n", npg_trainer_error(t));
      solver_free(&s);
      return -1;
    }
  }
  *seconds += util_now() - t0;
  solver_free(&s);
  return 0;
}

/* Everything one experiment holds, so that each phase is a function of it. */
typedef struct TunnelRun {
  const TunnelOptions *o;
  char err[ERRLEN], dframes[1100], dvtk[1100], dplots[1100], dmodels[1100], dtmp[1100];
  FluidMesh m;
  int mesh_ok, T, K;             /* frames per run, models */
  double dt;
  long ng, nf, nu, C;            /* sizes of g, f, u; cells */
  NpgProgram *prog;
  NpgFull *fe;
  NpgModel **models;             /* [K], by increasing basis size */
  RedSolver *rs;                 /* [K] their reduced solvers */
  int *rs_ok;
  Samples S;                     /* both training runs' samples */
  FullSolver s, probe;           /* the full test run; the one-step errors' full step */
  int s_ok, probe_ok;
  Particles pfull, pred;         /* through the full and the reduced flow */
  RedState rstate;               /* the reduced run's state, while the probes step R from elsewhere */
  double *traj_g, *traj_gd;      /* the replayed trajectory ĝ_t, ĝdot_t of the reduced run */
  /* figures */
  double *err_onestep, *err_avg; /* [K][T] E(u_ground − u_test) / E(u_ground); its time average */
  double *proj_avg;              /* [K] the share of the state's energy each basis misses: E(u − B_u û) / E(u), averaged */
  double *div_basis, *train_seconds, *step_model; /* [K] */
  long (*msz)[4];                /* [K] m_u, m_f, m_g, m_b */
  double *e_full, *e_red, *div_red; /* [T + 1] */
  double *step_times;            /* the reduced run's steps */
  long red_steps;
  double seconds_train_runs, seconds_particles, seconds_output, seconds_onestep;
  double seconds_red, red_eval, red_adv, red_proj, full_adv, full_proj, full_def, max_div_full;
  double bench_step, bench_expm;
  int bench_krylov, bench_pade;
  /* scratch: full-size vectors and the one-step errors' reduced coordinates */
  double *ub, *ut, *pv, *fb, *gl, *gn, *gc1, *gdc;
  char **vtk_full, **vtk_red;
  double *vtk_times;
  int nvtk;
} TunnelRun;

/* ---------------------------------------------------------------- prepare */

/* DIR and its frames/, vtk/, plots/ (and models/ with --keep-models). */
static int prepare(TunnelRun *r) {
  const TunnelOptions *o = r->o;
  int rc = report_need_out(PROGRAM, "tunnel", o->out, 1000);
  if (rc) return rc;
  snprintf(r->dframes, sizeof r->dframes, "%s/frames", o->out);
  snprintf(r->dvtk, sizeof r->dvtk, "%s/vtk", o->out);
  snprintf(r->dplots, sizeof r->dplots, "%s/plots", o->out);
  snprintf(r->dmodels, sizeof r->dmodels, "%s/models", o->out);
  snprintf(r->dtmp, sizeof r->dtmp, "%s/frames/.parts", o->out);
  if (report_make_dir(PROGRAM, o->out) || report_make_dir(PROGRAM, r->dframes) || report_make_dir(PROGRAM, r->dvtk) ||
      report_make_dir(PROGRAM, r->dplots) || report_make_dir(PROGRAM, r->dtmp) ||
      (o->keep_models && report_make_dir(PROGRAM, r->dmodels)))
    return 1;
  return 0;
}

/* ---------------------------------------------------------------- mesh and bind */

/* The mesh, fluids2d.npg compiled with a full evaluator bound to it, and the buffers. */
static int mesh_and_bind(TunnelRun *r) {
  const TunnelOptions *o = r->o;
  if (mesh_tunnel(&r->m, &o->spec, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->mesh_ok = 1;
  const FluidMesh *m = &r->m;
  int T = r->T = o->frames, K = r->K = o->nsizes;
  r->dt = o->cfl * mesh_mean_edge(m) / o->u0;
  long ng = r->ng = 2L * m->nv, nf = r->nf = m->nf, nu = r->nu = 2L * m->nc;
  r->C = m->nc;
  fprintf(stderr, "npg-fluids: mesh %d cells, %d faces (%d boundary), %d vertices; dt %.4g; %d frames per run\n",
          m->nc, m->nf, m->nb, m->nv, r->dt, T);
  NpgOptions nopt = {0};
  r->prog = npg_compile(FLUIDS_NPG, &nopt);
  if (!npg_ok(r->prog)) {
    fprintf(stderr, "%s", npg_error(r->prog));
    return 1;
  }
  r->fe = npg_full_new(r->prog, NPG_TCC);
  r->models = calloc(K, sizeof *r->models);
  r->rs = calloc(K, sizeof *r->rs);
  r->rs_ok = calloc(K, sizeof *r->rs_ok);
  r->S = (Samples){0, 2L * T, ng, nf, nu, NULL, NULL, NULL, NULL};
  r->S.g = malloc(r->S.cap * ng * sizeof(double)), r->S.gdot = malloc(r->S.cap * ng * sizeof(double));
  r->S.f = malloc(r->S.cap * nf * sizeof(double)), r->S.u = malloc(r->S.cap * nu * sizeof(double));
  r->err_onestep = calloc((size_t)K * T, sizeof(double)), r->err_avg = calloc(K, sizeof(double));
  r->proj_avg = calloc(K, sizeof(double));
  r->div_basis = calloc(K, sizeof(double)), r->train_seconds = calloc(K, sizeof(double));
  r->step_model = calloc(K, sizeof(double));
  r->msz = calloc(K, sizeof *r->msz);
  r->e_full = malloc((T + 1) * sizeof(double)), r->e_red = malloc((T + 1) * sizeof(double));
  r->div_red = calloc(T + 1, sizeof(double));
  r->ub = malloc(nu * sizeof(double)), r->ut = malloc(nu * sizeof(double)), r->pv = malloc(nu * sizeof(double));
  r->fb = malloc(nf * sizeof(double)), r->gl = malloc(ng * sizeof(double)), r->gn = malloc(ng * sizeof(double));
  r->gc1 = malloc(64 * sizeof(double)), r->gdc = malloc(64 * sizeof(double));
  r->vtk_full = calloc(T + 1, sizeof(char *)), r->vtk_red = calloc(T + 1, sizeof(char *));
  r->vtk_times = malloc((T + 1) * sizeof(double));
  if (npg_full_error(r->fe)[0] || fluid_bind(r->fe, m, o->mu) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", npg_full_error(r->fe));
    return 1;
  }
  return 0;
}

/* ---------------------------------------------------------------- train */

/* The training runs streamed into the trainer of the largest basis, then one model per
 * basis size (the largest from the streamed trainer, the others replaying the same
 * samples into their own trainers). */
static int train(TunnelRun *r) {
  const TunnelOptions *o = r->o;
  int K = r->K;
  NpgTrainOptions to;
  FluidBasisOptions mo;
  model_options(o, K - 1, &to, &mo);
  NpgTrainer *tr = npg_trainer_new(r->fe, &to);
  double sc[2] = {o->scale_large, o->scale_small};
  for (int k = 0; k < 2; k++) {
    fprintf(stderr, "npg-fluids: training run %d: obstacle scale %g ± %g\n", k + 1, sc[k], o->pulse);
    if (training_run(&r->m, o, sc[k], r->dt, &r->S, tr, &r->seconds_train_runs) != 0) {
      npg_trainer_free(tr);
      return 1;
    }
  }
  for (int i = K - 1; i >= 0; i--) {
    double t0 = util_now();
    if (i != K - 1) {
      model_options(o, i, &to, &mo);
      tr = npg_trainer_new(r->fe, &to);
      for (long k = 0; k < r->S.n; k++)
        if (stage_sample(tr, &r->S, k) != 0) break;
    }
    char mdir[1200];
    snprintf(mdir, sizeof mdir, "%s/mu%d", r->dmodels, o->mu_sizes[i]);
    r->models[i] = npg_trainer_finish(tr, o->keep_models ? mdir : NULL);
    if (!r->models[i]) {
      fprintf(stderr, "npg-fluids: training (m_u %d): %s\n", o->mu_sizes[i], npg_trainer_error(tr));
      npg_trainer_free(tr);
      return 1;
    }
    npg_trainer_free(tr);
    r->train_seconds[i] = util_now() - t0;
  }
  return 0;
}

/* The reduced solver of every model; B_f divergence-free (§6.3). */
static int reduced_solvers(TunnelRun *r) {
  const TunnelOptions *o = r->o;
  Ops ops;
  ops_init(&ops, &r->m);
  int rc = 0;
  for (int i = 0; i < r->K && !rc; i++) {
    RedSolver *q = &r->rs[i];
    if (red_init(q, r->models[i], 2, o->mu, r->dt, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: reduced model m_u %d: %s\n", o->mu_sizes[i], r->err);
      rc = 1;
      break;
    }
    r->rs_ok[i] = 1;
    r->msz[i][0] = q->mu, r->msz[i][1] = q->mf, r->msz[i][2] = q->mg, r->msz[i][3] = q->mb;
    r->div_basis[i] = ops_max_column_divergence(&ops, q->Bf, r->nf, q->mf);
    fprintf(stderr,
            "npg-fluids: model %d: m_u %ld, m_f %ld, m_g %ld, m_gdot %ld, m_d %ld (rank of D̂ %ld), trained in %.1f s, set-up %.1f s (%ld reduced evaluations); "
            "max |div| over B_f's columns %.2e; rank of the symmetric part of Â ⊗ f̂ %ld\n",
            i, q->mu, q->mf, q->mg, q->mgd, q->mb, q->drank, r->train_seconds[i], q->seconds_setup, q->evals,
            r->div_basis[i], q->rs);
    if (q->mu > 256 || q->mf > 256 || q->mg > 64 || q->mgd > 64) { /* gc1, gdc hold 64 */
      fprintf(stderr, "npg-fluids: basis larger than this driver's buffers\n");
      rc = 1;
    }
  }
  ops_free(&ops);
  return rc;
}

/* ---------------------------------------------------------------- the test runs */

/* The full test run at the medium scale and its probe, the replayed trajectory of the
 * reduced run (the largest model), its projected start, the particles. */
static int set_up_test(TunnelRun *r) {
  const TunnelOptions *o = r->o;
  const FluidMesh *m = &r->m;
  FullSolver *s = &r->s;
  long ng = r->ng;
  double u0[2] = {o->u0, 0}, dt = r->dt;
  if (solver_init(s, m, PROJ_STREAM_CHOLMOD, o->mu, dt, sigma_at(o->scale_test, o, 0), u0, r->err, sizeof r->err) != 0 ||
      (r->s_ok = 1, solver_init(&r->probe, m, PROJ_STREAM_CHOLMOD, o->mu, dt, sigma_at(o->scale_test, o, 0), u0, r->err,
                                sizeof r->err)) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  r->probe_ok = 1;
  RedSolver *R = &r->rs[r->K - 1];
  int T = r->T;
  r->traj_g = malloc((size_t)(T + 1) * R->mg * sizeof(double));
  r->traj_gd = calloc((size_t)T * R->mgd + 1, sizeof(double));
  for (int t = 0; t <= T; t++) {
    if (mesh_deform(m, sigma_at(o->scale_test, o, t), s->sigma_ref, r->gl, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", r->err);
      return 1;
    }
    red_project_g(R, r->gl, r->traj_g + (size_t)t * R->mg);
    if (t > 0) {
      for (long i = 0; i < ng; i++) r->gn[i] = (r->gl[i] - r->gn[i]) / dt;
      red_coords(R->Bgd, ng, R->mgd, r->gn, r->traj_gd + (size_t)(t - 1) * R->mgd);
    }
    memcpy(r->gn, r->gl, ng * sizeof(double));
  }
  /* reduced start: the projected initial full state */
  for (long c = 0; c < r->C; c++)
    r->pv[2 * c] = s->ops.area[c] * s->u[2 * c], r->pv[2 * c + 1] = s->ops.area[c] * s->u[2 * c + 1];
  memcpy(R->g, r->traj_g, R->mg * sizeof(double));
  red_project_f(R, s->f, R->f);
  red_project_u(R, R->g, r->pv, R->u);
  int prc = red_state_save(R, &r->rstate);
  if (prc) fprintf(stderr, "npg-fluids: out of memory\n");
  particles_seed(&r->pfull, m, s->g, o->particles, 12345);
  particles_seed(&r->pred, m, s->g, o->particles, 12345);
  r->e_full[0] = solver_energy(s);
  r->e_red[0] = red_energy(R, R->g, R->u);
  r->step_times = calloc(T + 1, sizeof(double));
  return prc ? 1 : 0;
}

/* Frame t: the reduced state lifted, its divergence, and the PNG (full | reduced) and
 * VTK files when due. */
static int output_frame(TunnelRun *r, int t) {
  const TunnelOptions *o = r->o;
  const FluidMesh *m = &r->m;
  const FullSolver *s = &r->s;
  const RedSolver *R = &r->rs[r->K - 1];
  char path[4096], p2[4096], p3[4096];
  int T = r->T;
  double t0 = util_now();
  red_lift(R->Bg, r->ng, R->mg, r->rstate.g, r->gl);
  red_lift(R->Bf, r->nf, R->mf, r->rstate.f, r->fb);
  red_lift(R->Bu, r->nu, R->mu, r->rstate.u, r->ut);
  {
    /* divergence of the lifted reduced flux */
    double worst = 0, *d = malloc(r->C * sizeof *d);
    csr_mv(&s->ops.div, r->fb, d);
    for (long c = 0; c < r->C; c++) worst = fmax(worst, fabs(d[c]));
    r->div_red[t] = worst;
    free(d);
  }
  if (output_frame_due(t, T, o->png_every)) {
    snprintf(p2, sizeof p2, "%s/full.png", r->dtmp);
    snprintf(p3, sizeof p3, "%s/reduced.png", r->dtmp);
    snprintf(path, sizeof path, "%s/frame_%04d.png", r->dframes, t);
    char capl[128], capr[128];
    snprintf(capl, sizeof capl, "full, frame %d (%d cells)", t, m->nc);
    snprintf(capr, sizeof capr, "reduced, m_u %ld, m_f %ld, m_g %ld", R->mu, R->mf, R->mg);
    if (output_png(p2, m, s->g, s->u, &r->pfull, 1.6 * o->u0, o->width, r->err, sizeof r->err) != 0 ||
        output_png(p3, m, r->gl, r->ut, &r->pred, 1.6 * o->u0, o->width, r->err, sizeof r->err) != 0 ||
        plot_side_by_side(path, p2, p3, capl, capr, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", r->err);
      return -1;
    }
  }
  if (output_frame_due(t, T, o->vtk_every)) {
    int prc = 0;
    char name[64];
    snprintf(name, sizeof name, "full_%04d.vtu", t);
    r->vtk_full[r->nvtk] = strdup(name);
    snprintf(path, sizeof path, "%s/%s", r->dvtk, name);
    if (output_vtu_cells(path, m, s->g, s->u, r->err, sizeof r->err) != 0) prc = -1;
    snprintf(name, sizeof name, "reduced_%04d.vtu", t);
    r->vtk_red[r->nvtk] = strdup(name);
    snprintf(path, sizeof path, "%s/%s", r->dvtk, name);
    if (!prc && output_vtu_cells(path, m, r->gl, r->ut, r->err, sizeof r->err) != 0) prc = -1;
    /* face fluxes of both runs (the reduced one lifted; its induced flux is not lifted:
     * written as zero) */
    snprintf(path, sizeof path, "%s/full_faces_%04d.vtu", r->dvtk, t);
    if (!prc && output_vtu_faces(path, m, s->g, s->f, s->h, r->err, sizeof r->err) != 0) prc = -1;
    double *zero = calloc(r->nf, sizeof *zero);
    snprintf(path, sizeof path, "%s/reduced_faces_%04d.vtu", r->dvtk, t);
    if (!prc && output_vtu_faces(path, m, r->gl, r->fb, zero, r->err, sizeof r->err) != 0) prc = -1;
    free(zero);
    r->vtk_times[r->nvtk++] = t * r->dt;
    if (prc) {
      fprintf(stderr, "npg-fluids: %s\n", r->err);
      return -1;
    }
  }
  r->seconds_output += util_now() - t0;
  return 0;
}

/* Every model's one-step error from the projected full state of frame t: the full step
 * from the lifted state (the probe) against the reduced step, in energy (§7.1). */
static int onestep_errors(TunnelRun *r, int t, double sig1) {
  const FluidMesh *m = &r->m;
  FullSolver *s = &r->s, *probe = &r->probe;
  long ng = r->ng, nf = r->nf, nu = r->nu, C = r->C;
  int T = r->T;
  double t1 = util_now();
  for (long c = 0; c < C; c++)
    r->pv[2 * c] = s->ops.area[c] * s->u[2 * c], r->pv[2 * c + 1] = s->ops.area[c] * s->u[2 * c + 1];
  if (mesh_deform(m, sig1, s->sigma_ref, r->gn, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return -1;
  }
  for (long i = 0; i < ng; i++) r->gl[i] = (r->gn[i] - s->g[i]) / r->dt;
  for (int i = 0; i < r->K; i++) {
    RedSolver *q = &r->rs[i];
    red_project_g(q, s->g, q->g);
    red_project_g(q, r->gn, r->gc1);
    red_coords(q->Bgd, ng, q->mgd, r->gl, r->gdc);
    red_project_f(q, s->f, q->f);
    red_project_u(q, q->g, r->pv, q->u);
    /* full step from the lifted state */
    memcpy(probe->g, s->g, ng * sizeof(double));
    probe->sigma = s->sigma;
    red_lift(q->Bf, nf, q->mf, q->f, probe->f);
    red_lift(q->Bu, nu, q->mu, q->u, probe->u);
    for (long j = 0; j < nu; j++) r->ub[j] = s->u[j] - probe->u[j];
    r->proj_avg[i] += energy_area(s->ops.area, r->ub, C) / energy_area(s->ops.area, s->u, C) / T;
    ops_set_geometry(&probe->ops, probe->g);
    if (solver_step(probe, sig1, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: one-step error, frame %d: %s\n", t, r->err);
      return -1;
    }
    double tq = util_now();
    if (red_step(q, r->gc1, r->gdc, r->err, sizeof r->err) != 0) {
      fprintf(stderr, "npg-fluids: one-step error, frame %d: %s\n", t, r->err);
      return -1;
    }
    r->step_model[i] += util_now() - tq;
    red_lift(q->Bu, nu, q->mu, q->u, r->ub);
    for (long j = 0; j < nu; j++) r->ub[j] = probe->u[j] - r->ub[j];
    double eg = energy_area(probe->ops.area, probe->u, C);
    r->err_onestep[(size_t)i * T + t] = energy_area(probe->ops.area, r->ub, C) / eg;
  }
  r->seconds_onestep += util_now() - t1;
  return 0;
}

/* The full test run's step to frame t + 1. */
static int full_step(TunnelRun *r, int t, double sig1) {
  FullSolver *s = &r->s;
  double a0 = s->seconds_advection, p0 = s->seconds_projection, d0 = s->seconds_deformation;
  if (solver_step(s, sig1, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: test run, frame %d: %s\n", t, r->err);
    return -1;
  }
  r->full_adv += s->seconds_advection - a0, r->full_proj += s->seconds_projection - p0;
  r->full_def += s->seconds_deformation - d0;
  r->max_div_full = fmax(r->max_div_full, projection_max_divergence(&s->ops, s->f));
  r->e_full[t + 1] = solver_energy(s);
  if (solver_check_energy(r->e_full[0], r->e_full[t + 1], t + 1, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: test run: %s\n", r->err);
    return -1;
  }
  return 0;
}

/* The reduced test run's step to frame t + 1 (timed: the step alone), then both runs'
 * particles: full through the full flux, reduced through the lifted reduced flux (Eq. 13
 * evaluated per cell). */
static int reduced_step(TunnelRun *r, int t) {
  RedSolver *R = &r->rs[r->K - 1];
  red_state_restore(R, &r->rstate);
  double e0 = R->seconds_eval, a1 = R->seconds_advection, p1 = R->seconds_projection;
  double t2 = util_now();
  if (red_step(R, r->traj_g + (size_t)(t + 1) * R->mg, r->traj_gd + (size_t)t * R->mgd, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: reduced run, frame %d: %s\n", t, r->err);
    return -1;
  }
  r->step_times[r->red_steps] = util_now() - t2;
  r->seconds_red += r->step_times[r->red_steps];
  r->red_eval += R->seconds_eval - e0, r->red_adv += R->seconds_advection - a1;
  r->red_proj += R->seconds_projection - p1;
  r->red_steps++;
  red_state_save(R, &r->rstate);
  r->e_red[t + 1] = red_energy(R, R->g, R->u);
  double t3 = util_now();
  red_lift(R->Bg, r->ng, R->mg, r->rstate.g, r->gl);
  red_lift(R->Bf, r->nf, R->mf, r->rstate.f, r->fb);
  particles_advect(&r->pred, &r->m, r->gl, r->fb, r->dt, 10);
  r->seconds_particles += util_now() - t3;
  particles_advect(&r->pfull, &r->m, r->s.g, r->s.f, r->dt, 10);
  return 0;
}

/* The full test simulation at the medium scale; per frame the one-step error of every
 * model from the projected full state; beside it the reduced simulation of the largest
 * model, from the projected start, on the replayed trajectory ĝ_t, ĝdot_t. */
static int run_test(TunnelRun *r) {
  if (set_up_test(r) != 0) return 1;
  const TunnelOptions *o = r->o;
  int T = r->T;
  for (int t = 0; t <= T; t++) {
    if (output_frame(r, t) != 0) return 1;
    if (t == T) break;
    double sig1 = sigma_at(o->scale_test, o, t + 1);
    if (onestep_errors(r, t, sig1) != 0 || full_step(r, t, sig1) != 0 || reduced_step(r, t) != 0) return 1;
    if (t % 50 == 0) fprintf(stderr, "npg-fluids: test frame %d/%d\n", t, T);
  }
  return 0;
}

/* The reduced step alone, repeated from the last state (the minimum over repeats is the
 * figure least disturbed by other jobs on the machine): as run (the exponential applied to
 * û by Arnoldi), and with the whole matrix exponential (Padé, scaling and squaring) in its
 * place, repeats interleaved so that both see the same load. Then the time averages of
 * the one-step errors. */
static int bench_reduced_step(TunnelRun *r) {
  RedSolver *R = &r->rs[r->K - 1];
  int T = r->T, prc = 0;
  r->bench_step = INFINITY, r->bench_expm = INFINITY;
  for (int rep = 0; rep < 200 && !prc; rep++) {
    red_state_restore(R, &r->rstate);
    R->integ = rep % 2 ? RED_EXPM : RED_EXPMV;
    double t2 = util_now();
    if (red_step(R, r->traj_g + (size_t)(T - 1) * R->mg, r->traj_gd + (size_t)(T - 2) * R->mgd, r->err,
                 sizeof r->err) != 0)
      prc = -1;
    double dtm = util_now() - t2;
    if (rep % 2) r->bench_expm = fmin(r->bench_expm, dtm), r->bench_pade = R->last_pade;
    else r->bench_step = fmin(r->bench_step, dtm), r->bench_krylov = R->last_krylov;
  }
  R->integ = RED_EXPMV;
  if (prc) return 1;
  for (int i = 0; i < r->K; i++) {
    double a = 0;
    for (int t = 0; t < T; t++) a += r->err_onestep[(size_t)i * T + t];
    r->err_avg[i] = a / T;
  }
  return 0;
}

/* ---------------------------------------------------------------- plots, VTK */

/* plots/: the one-step error per frame and model, its time average against the basis
 * size, the test runs' energies. A chart that fails is reported; the run goes on. */
static int plots(TunnelRun *r) {
  int K = r->K, T = r->T;
  char path[4096];
  double *frame = malloc((T + 1) * sizeof *frame), *mx = malloc(K * sizeof *mx);
  ChartSeries *se = calloc(K, sizeof *se);
  char(*labels)[64] = malloc(K * sizeof *labels);
  for (int t = 0; t <= T; t++) frame[t] = t;
  for (int i = 0; i < K; i++) {
    snprintf(labels[i], sizeof *labels, "m_u %ld, m_f %ld", r->msz[i][0], r->msz[i][1]);
    se[i] = (ChartSeries){labels[i], T, frame, r->err_onestep + (size_t)i * T, -1, false, T <= 40};
    mx[i] = (double)r->msz[i][0];
  }
  Chart c = {.title = "one-step error E(u_ground - u_test) / E(u_ground), test (medium obstacle)", .xlabel = "frame",
             .ylabel = "relative one-step error", .logy = true, .nseries = K, .series = se};
  snprintf(path, sizeof path, "%s/onestep_error.png", r->dplots);
  int e1 = chart_png(&c, path, PLOT_WIDTH, PLOT_HEIGHT, r->err, sizeof r->err);
  ChartSeries avg = {"time average", K, mx, r->err_avg, -1, false, K <= 40};
  c = (Chart){.title = "time-averaged one-step error against basis size",
              .xlabel = "m_u, the velocity class's basis size", .ylabel = "time-averaged one-step error", .logy = true,
              .nseries = 1, .series = &avg};
  snprintf(path, sizeof path, "%s/onestep_error_average.png", r->dplots);
  int e2 = e1 ? -1 : chart_png(&c, path, PLOT_WIDTH, PLOT_HEIGHT, r->err, sizeof r->err);
  if (e1 || e2) fprintf(stderr, "npg-fluids: %s\n", r->err);
  ChartSeries en[2] = {{"full", T + 1, frame, r->e_full, -1, false, T + 1 <= 40},
                       {"reduced (largest basis)", T + 1, frame, r->e_red, -1, false, T + 1 <= 40}};
  c = (Chart){.title = "energy 1/2 u^T V(g) u of the test runs", .xlabel = "frame", .ylabel = "energy",
              .nseries = 2, .series = en};
  snprintf(path, sizeof path, "%s/energy.png", r->dplots);
  if (chart_png(&c, path, PLOT_WIDTH, PLOT_HEIGHT, r->err, sizeof r->err) != 0) fprintf(stderr, "npg-fluids: %s\n", r->err);
  free(frame), free(mx), free(se), free(labels);
  return 0;
}

/* vtk/full.pvd and reduced.pvd: the time series ParaView opens. */
static int vtk_collections(TunnelRun *r) {
  char path[4096], p2[4096];
  snprintf(path, sizeof path, "%s/full.pvd", r->dvtk);
  snprintf(p2, sizeof p2, "%s/reduced.pvd", r->dvtk);
  if (output_pvd(path, r->nvtk, (const char *const *)r->vtk_full, r->vtk_times, r->err, sizeof r->err) != 0 ||
      output_pvd(p2, r->nvtk, (const char *const *)r->vtk_red, r->vtk_times, r->err, sizeof r->err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", r->err);
    return 1;
  }
  return 0;
}

/* ---------------------------------------------------------------- report */

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* The reduced step's timing figures: the mean, median and minimum over the run, the
 * minimum of the repeats. */
static void report_reduced_timing(TunnelRun *r, FILE *fp) {
  const RedSolver *R = &r->rs[r->K - 1];
  long n = r->red_steps;
  fprintf(fp,
          "  \"reduced_step_seconds\": %.6e, \"reduced_assembly_seconds\": %.6e, \"reduced_advection_seconds\": %.6e, "
          "\"reduced_projection_seconds\": %.6e, \"reduced_pade_degree\": %d, \"reduced_squarings\": %d,\n",
          r->seconds_red / n, r->red_eval / n, r->red_adv / n, r->red_proj / n, R->last_pade, R->last_squarings);
  double *st = malloc(n * sizeof *st);
  memcpy(st, r->step_times, n * sizeof *st);
  qsort(st, n, sizeof *st, cmp_double);
  fprintf(fp, "  \"reduced_step_seconds_median\": %.6e, \"reduced_step_seconds_min\": %.6e,\n", st[n / 2], st[0]);
  fprintf(fp,
          "  \"reduced_step_seconds_min_of_100_repeats\": %.6e, \"reduced_arnoldi_steps\": %d,\n"
          "  \"reduced_step_whole_expm_seconds_min_of_100_repeats\": %.6e, \"reduced_step_whole_expm_pade_degree\": %d,\n",
          r->bench_step, r->bench_krylov, r->bench_expm, r->bench_pade);
  free(st);
}

/* The summary on stderr. */
static void report_summary(const TunnelRun *r) {
  int K = r->K, T = r->T;
  long n = r->red_steps;
  double full_step = (r->full_adv + r->full_proj + r->full_def) / T, red_step_s = r->seconds_red / n;
  fprintf(stderr,
          "npg-fluids: reduced step, minimum of 100 repeats from the last state: %.3f ms (exponential by Arnoldi, "
          "%d steps); with the whole matrix exponential (Padé %d): %.3f ms\n",
          1e3 * r->bench_step, r->bench_krylov, r->bench_pade, 1e3 * r->bench_expm);
  fprintf(stderr, "npg-fluids: one-step error (time average) per basis size:");
  for (int i = 0; i < K; i++)
    fprintf(stderr, " m_u %ld: %.3e (state's projection %.3e; reduced step from each projected state, mean %.3f ms, "
                    "speedup %.1f);",
            r->rs[i].mu, r->err_avg[i], r->proj_avg[i], 1e3 * r->step_model[i] / T,
            (r->full_adv + r->full_proj + r->full_def) / r->step_model[i]);
  fprintf(stderr, "\nnpg-fluids: full step %.3f ms (advection %.3f, projection %.3f, deformation %.3f), reduced step, "
                  "mean over the run's %ld steps %.3f ms (operators %.3f, exponential %.3f, projection %.3f): speedup of "
                  "the means %.1f\n",
          1e3 * full_step, 1e3 * r->full_adv / T, 1e3 * r->full_proj / T, 1e3 * r->full_def / T, n, 1e3 * red_step_s,
          1e3 * r->red_eval / n, 1e3 * r->red_adv / n, 1e3 * r->red_proj / n, full_step / red_step_s);
}

/* report.json (every model's figures, the test runs', the timings), then the summary. */
static int report(TunnelRun *r) {
  const TunnelOptions *o = r->o;
  const FluidMesh *m = &r->m;
  const RedSolver *R = &r->rs[r->K - 1];
  int K = r->K, T = r->T;
  Report rep;
  if (report_open(&rep, PROGRAM, o->out) != 0) return 1;
  FILE *fp = rep.f;
  double full_step = (r->full_adv + r->full_proj + r->full_def) / T, red_step_s = r->seconds_red / r->red_steps;
  size_t tbytes = 0, mbytes = npg_model_bytes(r->models[K - 1], &tbytes);
  fprintf(fp, "{\n  \"cells\": %d, \"faces\": %d, \"boundary_faces\": %d, \"vertices\": %d, \"dt\": %.6g, \"mu\": %g,\n",
          m->nc, m->nf, m->nb, m->nv, r->dt, o->mu);
  fprintf(fp, "  \"frames\": %d, \"scales\": {\"train\": [%g, %g], \"test\": %g, \"pulse\": %g, \"period\": %g},\n", T,
          o->scale_large, o->scale_small, o->scale_test, o->pulse, o->period);
  fprintf(fp, "  \"training_samples\": %ld, \"training_runs_seconds\": %.3f,\n", r->S.n, r->seconds_train_runs);
  fprintf(fp, "  \"models\": [\n");
  for (int i = 0; i < K; i++) {
    const RedSolver *q = &r->rs[i];
    size_t tb = 0, mb = npg_model_bytes(r->models[i], &tb);
    fprintf(fp,
            "    {\"m_u\": %ld, \"m_f\": %ld, \"m_g\": %ld, \"m_gdot\": %ld, \"m_d\": %ld, \"rank_D\": %ld, "
            "\"train_seconds\": %.3f, \"model_bytes\": %zu, \"tensor_bytes\": %zu, \"basis_f_max_divergence\": %.3e, "
            "\"onestep_error_mean\": %.6e, \"projection_error_mean\": %.6e, \"reduced_step_seconds\": %.6e, "
            "\"speedup\": %.2f}%s\n",
            q->mu, q->mf, q->mg, q->mgd, q->mb, q->drank, r->train_seconds[i], mb, tb, r->div_basis[i], r->err_avg[i],
            r->proj_avg[i], r->step_model[i] / T, (r->full_adv + r->full_proj + r->full_def) / r->step_model[i],
            i + 1 < K ? "," : "");
  }
  fprintf(fp, "  ],\n");
  fprintf(fp, "  \"onestep_error\": [\n");
  for (int i = 0; i < K; i++) {
    fprintf(fp, "    [");
    for (int t = 0; t < T; t++) fprintf(fp, "%s%.4e", t ? ", " : "", r->err_onestep[(size_t)i * T + t]);
    fprintf(fp, "]%s\n", i + 1 < K ? "," : "");
  }
  fprintf(fp, "  ],\n");
  report_json_array(fp, "  ", "onestep_error_mean", r->err_avg, K, 6, ",\n");
  int mono = 1;
  for (int i = 1; i < K; i++) mono &= r->err_avg[i] < r->err_avg[i - 1];
  fprintf(fp, "  \"onestep_error_mean_monotone\": %s,\n", mono ? "true" : "false");
  report_json_array(fp, "  ", "energy_full", r->e_full, T + 1, 6, ",\n");
  report_json_array(fp, "  ", "energy_reduced", r->e_red, T + 1, 6, ",\n");
  double drift_red = 0, mdr = 0;
  for (int t = 0; t < T; t++) drift_red = fmax(drift_red, (r->e_red[t + 1] - r->e_red[t]) / r->e_red[t]);
  fprintf(fp,
          "  \"energy_drift_full\": %.6e, \"energy_drift_reduced\": %.6e, \"energy_max_increase_per_step_reduced\": %.3e,\n",
          (r->e_full[T] - r->e_full[0]) / r->e_full[0], (r->e_red[T] - r->e_red[0]) / r->e_red[0], drift_red);
  for (int t = 0; t <= T; t++) mdr = fmax(mdr, r->div_red[t]);
  fprintf(fp, "  \"max_divergence_full\": %.3e, \"max_divergence_reduced\": %.3e,\n", r->max_div_full, mdr);
  fprintf(fp,
          "  \"full_step_seconds\": %.6e, \"full_advection_seconds\": %.6e, \"full_projection_seconds\": %.6e, "
          "\"full_deformation_seconds\": %.6e,\n",
          full_step, r->full_adv / T, r->full_proj / T, r->full_def / T);
  report_reduced_timing(r, fp);
  fprintf(fp, "  \"reduced_basis\": {\"m_u\": %ld, \"m_f\": %ld, \"m_g\": %ld},\n", R->mu, R->mf, R->mg);
  fprintf(fp, "  \"speedup\": %.2f,\n", full_step / red_step_s);
  fprintf(fp, "  \"particles\": %d, \"particle_seconds\": %.6e, \"onestep_seconds\": %.3f, \"output_seconds\": %.3f,\n",
          o->particles, r->seconds_particles / T, r->seconds_onestep, r->seconds_output);
  fprintf(fp, "  \"model_bytes\": %zu, \"tensor_bytes\": %zu\n}\n", mbytes, tbytes);
  if (report_commit(&rep, PROGRAM) != 0) return 1;
  report_summary(r);
  return 0;
}

static void release(TunnelRun *r) {
  char p[4200];
  snprintf(p, sizeof p, "%s/full.png", r->dtmp), remove(p);
  snprintf(p, sizeof p, "%s/reduced.png", r->dtmp), remove(p);
  if (r->dtmp[0]) rmdir(r->dtmp);
  for (int i = 0; i < r->K && r->models; i++) {
    if (r->rs_ok[i]) red_free(&r->rs[i]);
    if (r->models[i]) npg_model_free(r->models[i]);
  }
  for (int i = 0; i < r->nvtk; i++) free(r->vtk_full[i]), free(r->vtk_red[i]);
  free(r->vtk_full), free(r->vtk_red), free(r->vtk_times);
  if (r->s_ok) solver_free(&r->s);
  if (r->probe_ok) solver_free(&r->probe);
  particles_free(&r->pfull), particles_free(&r->pred);
  red_state_free(&r->rstate);
  free(r->traj_g), free(r->traj_gd);
  free(r->models), free(r->rs), free(r->rs_ok), free(r->S.g), free(r->S.gdot), free(r->S.f), free(r->S.u);
  free(r->err_onestep), free(r->err_avg), free(r->proj_avg), free(r->div_basis), free(r->train_seconds), free(r->msz);
  free(r->e_full), free(r->e_red), free(r->div_red), free(r->step_times), free(r->step_model);
  free(r->ub), free(r->ut), free(r->pv), free(r->fb), free(r->gl), free(r->gn), free(r->gc1), free(r->gdc);
  if (r->fe) npg_full_free(r->fe);
  if (r->prog) npg_free(r->prog);
  if (r->mesh_ok) mesh_free(&r->m);
  chart_cleanup();
}

int tunnel_run(const TunnelOptions *o) {
  TunnelRun *r = calloc(1, sizeof *r);
  if (!r) return 1;
  r->o = o;
  int rc = prepare(r);
  if (!rc) rc = mesh_and_bind(r);
  if (!rc) rc = train(r);
  if (!rc) rc = reduced_solvers(r);
  if (!rc) rc = run_test(r);
  if (!rc) rc = bench_reduced_step(r);
  if (!rc) rc = plots(r);
  if (!rc) rc = vtk_collections(r);
  if (!rc) rc = report(r);
  release(r);
  free(r);
  return rc;
}
