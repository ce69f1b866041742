/* tunnel.c — npg-fluids tunnel: paper Fig. 5 (see tunnel.h). Everything npg
 * does here goes through npg.h: compiling fluids2d.npg, binding the mesh,
 * streaming training, the models' bases and reduced evaluation. */
#include "util.h"
#include "tunnel.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <cblas.h>

#include "npg.h"
#include "npgbind.h"
#include "output.h"
#include "particles.h"
#include "plot.h"
#include "reduced.h"
#include "solver.h"

#ifndef FLUIDS_NPG
#define FLUIDS_NPG "examples/fluids/fluids2d.npg"
#endif
#define ERRLEN 1024

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
  return scale + o->pulse * sin(2 * M_PI * t / o->period);
}

static int make_dir(const char *path) {
  if (mkdir(path, 0777) != 0 && errno != EEXIST) {
    fprintf(stderr, "npg-fluids: %s: %s\n", path, strerror(errno));
    return -1;
  }
  return 0;
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

static void lift(const double *B, long n, long m, const double *x, double *out) {
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)m, 1.0, B, (int)m, x, 1, 0.0, out, 1);
}

static void json_array(FILE *fp, const char *name, const double *v, long n, const char *tail) {
  fprintf(fp, "  \"%s\": [", name);
  for (long i = 0; i < n; i++) fprintf(fp, "%s%.6g", i ? ", " : "", v[i]);
  fprintf(fp, "]%s\n", tail);
}

/* One full training run at obstacle scale `scale`: samples appended to S,
 * and streamed into `t` (when not NULL) as they happen. */
static int training_run(const Mesh *m, const TunnelOptions *o, double scale, double dt, Samples *S, NpgTrainer *t,
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

int tunnel_run(const TunnelOptions *o) {
  char err[ERRLEN], path[4096], p2[4096], p3[4096];
  if (!o->out) {
    fprintf(stderr, "npg-fluids: tunnel needs --out DIR\n");
    return 2;
  }
  if (strlen(o->out) > 1000) {
    fprintf(stderr, "npg-fluids: --out: path longer than 1000 bytes\n");
    return 2;
  }
  char dframes[1100], dvtk[1100], dplots[1100], dmodels[1100], dtmp[1100];
  snprintf(dframes, sizeof dframes, "%s/frames", o->out);
  snprintf(dvtk, sizeof dvtk, "%s/vtk", o->out);
  snprintf(dplots, sizeof dplots, "%s/plots", o->out);
  snprintf(dmodels, sizeof dmodels, "%s/models", o->out);
  snprintf(dtmp, sizeof dtmp, "%s/frames/.parts", o->out);
  if (make_dir(o->out) || make_dir(dframes) || make_dir(dvtk) || make_dir(dplots) || make_dir(dtmp) ||
      (o->keep_models && make_dir(dmodels)))
    return 1;
  Mesh m;
  if (mesh_tunnel(&m, &o->spec, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    return 1;
  }
  int T = o->frames, K = o->nsizes, rc = 1;
  double dt = o->cfl * mesh_mean_edge(&m) / o->u0;
  long ng = 2L * m.nv, nf = m.nf, nu = 2L * m.nc, C = m.nc;
  fprintf(stderr, "npg-fluids: mesh %d cells, %d faces (%d boundary), %d vertices; dt %.4g; %d frames per run\n", m.nc,
          m.nf, m.nb, m.nv, dt, T);

  /* npg: the program and a full evaluator with the mesh bound */
  NpgOptions nopt = {0};
  NpgProgram *prog = npg_compile(FLUIDS_NPG, &nopt);
  if (!npg_ok(prog)) {
    fprintf(stderr, "%s", npg_error(prog));
    npg_free(prog);
    mesh_free(&m);
    return 1;
  }
  NpgFull *fe = npg_full_new(prog, NPG_TCC);
  NpgModel **models = calloc(K, sizeof *models);
  RedSolver *rs = calloc(K, sizeof *rs);
  int *rs_ok = calloc(K, sizeof *rs_ok);
  Samples S = {0, 2L * T, ng, nf, nu, NULL, NULL, NULL, NULL};
  S.g = malloc(S.cap * ng * sizeof(double)), S.gdot = malloc(S.cap * ng * sizeof(double));
  S.f = malloc(S.cap * nf * sizeof(double)), S.u = malloc(S.cap * nu * sizeof(double));
  FullSolver s, probe;
  int s_ok = 0, probe_ok = 0;
  Particles pfull = {0}, pred = {0};
  double *err_onestep = calloc((size_t)K * T, sizeof(double)), *err_avg = calloc(K, sizeof(double));
  /* the share of the state's energy each basis misses (the start of every one-step error):
   * E(u − B_u û) / E(u), time-averaged */
  double *proj_avg = calloc(K, sizeof(double));
  double *div_basis = calloc(K, sizeof(double)), *train_seconds = calloc(K, sizeof(double));
  long(*msz)[4] = calloc(K, sizeof *msz);
  double *e_full = malloc((T + 1) * sizeof(double)), *e_red = malloc((T + 1) * sizeof(double));
  double *div_red = calloc(T + 1, sizeof(double));
  double *ub = malloc(nu * sizeof(double)), *ut = malloc(nu * sizeof(double)), *pv = malloc(nu * sizeof(double));
  double *fb = malloc(nf * sizeof(double)), *gl = malloc(ng * sizeof(double)), *gn = malloc(ng * sizeof(double));
  double *uc = malloc(256 * sizeof(double)), *fc = malloc(256 * sizeof(double)), *gc = malloc(64 * sizeof(double));
  double *gc1 = malloc(64 * sizeof(double)), *gdc = malloc(64 * sizeof(double));
  double seconds_train_runs = 0, seconds_particles = 0, seconds_output = 0, seconds_onestep = 0;
  char **vtk_full = calloc(T + 1, sizeof(char *)), **vtk_red = calloc(T + 1, sizeof(char *));
  double *vtk_times = malloc((T + 1) * sizeof(double));
  int nvtk = 0;
  double *step_times = NULL, *step_model = calloc(K, sizeof(double));
  if (!npg_ok(prog) || npg_full_error(fe)[0] || fluid_bind(fe, &m, o->mu) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", npg_full_error(fe));
    goto done;
  }

  /* 1. training runs, streamed into the trainer of the largest basis */
  NpgTrainOptions to;
  FluidBasisOptions mo;
  model_options(o, K - 1, &to, &mo);
  NpgTrainer *tr = npg_trainer_new(fe, &to);
  double sc[2] = {o->scale_large, o->scale_small};
  for (int r = 0; r < 2; r++) {
    fprintf(stderr, "npg-fluids: training run %d: obstacle scale %g ± %g\n", r + 1, sc[r], o->pulse);
    if (training_run(&m, o, sc[r], dt, &S, tr, &seconds_train_runs) != 0) {
      npg_trainer_free(tr);
      goto done;
    }
  }
  /* 2. one model per basis size (the largest from the streamed trainer, the
   * others replaying the same samples into their own trainers) */
  for (int i = K - 1; i >= 0; i--) {
    double t0 = util_now();
    if (i != K - 1) {
      model_options(o, i, &to, &mo);
      tr = npg_trainer_new(fe, &to);
      for (long k = 0; k < S.n; k++)
        if (stage_sample(tr, &S, k) != 0) break;
    }
    char mdir[1200];
    snprintf(mdir, sizeof mdir, "%s/mu%d", dmodels, o->mu_sizes[i]);
    models[i] = npg_trainer_finish(tr, o->keep_models ? mdir : NULL);
    if (!models[i]) {
      fprintf(stderr, "npg-fluids: training (m_u %d): %s\n", o->mu_sizes[i], npg_trainer_error(tr));
      npg_trainer_free(tr);
      goto done;
    }
    npg_trainer_free(tr);
    train_seconds[i] = util_now() - t0;
  }
  /* reduced solvers; B_f divergence-free (§6.3) */
  Ops ops;
  ops_init(&ops, &m);
  for (int i = 0; i < K; i++) {
    if (red_init(&rs[i], models[i], 2, o->mu, dt, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: reduced model m_u %d: %s\n", o->mu_sizes[i], err);
      ops_free(&ops);
      goto done;
    }
    rs_ok[i] = 1;
    msz[i][0] = rs[i].mu, msz[i][1] = rs[i].mf, msz[i][2] = rs[i].mg, msz[i][3] = rs[i].mb;
    div_basis[i] = ops_max_column_divergence(&ops, rs[i].Bf, nf, rs[i].mf);
    fprintf(stderr,
            "npg-fluids: model %d: m_u %ld, m_f %ld, m_g %ld, m_gdot %ld, m_d %ld (rank of D̂ %ld), trained in %.1f s, set-up %.1f s (%ld reduced evaluations); "
            "max |div| over B_f's columns %.2e; rank of the symmetric part of Â ⊗ f̂ %ld\n",
            i, rs[i].mu, rs[i].mf, rs[i].mg, rs[i].mgd, rs[i].mb, rs[i].drank, train_seconds[i], rs[i].seconds_setup, rs[i].evals, div_basis[i], rs[i].rs);
    if (rs[i].mu > 256 || rs[i].mf > 256 || rs[i].mg > 64 || rs[i].mgd > 64) {
      fprintf(stderr, "npg-fluids: basis larger than this driver's buffers\n");
      ops_free(&ops);
      goto done;
    }
  }
  ops_free(&ops);

  /* 3. the test: full simulation at the medium scale; per frame the one-step
   * error of every model from the projected full state; beside it the
   * reduced simulation of the largest model, from the projected start, on
   * the replayed trajectory ĝ_t, ĝdot_t */
  double u0[2] = {o->u0, 0};
  if (solver_init(&s, &m, PROJ_STREAM_CHOLMOD, o->mu, dt, sigma_at(o->scale_test, o, 0), u0, err, sizeof err) != 0 ||
      (s_ok = 1, solver_init(&probe, &m, PROJ_STREAM_CHOLMOD, o->mu, dt, sigma_at(o->scale_test, o, 0), u0, err,
                             sizeof err)) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    goto done;
  }
  probe_ok = 1;
  RedSolver *R = &rs[K - 1];
  /* the replayed trajectory of the reduced run */
  double *traj_g = malloc((size_t)(T + 1) * R->mg * sizeof(double)), *traj_gd = calloc((size_t)T * R->mgd + 1, sizeof(double));
  for (int t = 0; t <= T; t++) {
    if (mesh_deform(&m, sigma_at(o->scale_test, o, t), s.sigma_ref, gl, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", err);
      free(traj_g), free(traj_gd);
      goto done;
    }
    red_project_g(R, gl, traj_g + (size_t)t * R->mg);
    if (t > 0) {
      for (long i = 0; i < ng; i++) gn[i] = (gl[i] - gn[i]) / dt;
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)ng, (int)R->mgd, 1.0, R->Bgd, (int)R->mgd, gn, 1, 0.0,
                  traj_gd + (size_t)(t - 1) * R->mgd, 1);
    }
    memcpy(gn, gl, ng * sizeof(double));
  }
  /* reduced start: the projected initial full state */
  for (long c = 0; c < C; c++) pv[2 * c] = s.ops.area[c] * s.u[2 * c], pv[2 * c + 1] = s.ops.area[c] * s.u[2 * c + 1];
  memcpy(R->g, traj_g, R->mg * sizeof(double));
  red_project_f(R, s.f, R->f);
  red_project_u(R, R->g, pv, R->u);
  /* the reduced run's state, while the one-step probes step R from elsewhere */
  RedState rstate = {0};
  int prc = red_state_save(R, &rstate);
  if (prc) fprintf(stderr, "npg-fluids: out of memory\n");
  particles_seed(&pfull, &m, s.g, o->particles, 12345);
  particles_seed(&pred, &m, s.g, o->particles, 12345);
  e_full[0] = solver_energy(&s);
  e_red[0] = red_energy(R, R->g, R->u);
  double seconds_red = 0, red_eval = 0, red_adv = 0, red_proj = 0;
  double full_adv = 0, full_proj = 0, full_def = 0, max_div_full = 0;
  long red_steps = 0;
  step_times = calloc(T + 1, sizeof(double));
  for (int t = 0; t <= T && !prc; t++) {
    /* frame t: outputs */
    double t0 = util_now();
    lift(R->Bg, ng, R->mg, rstate.g, gl);
    lift(R->Bf, nf, R->mf, rstate.f, fb);
    lift(R->Bu, nu, R->mu, rstate.u, ut);
    {
      /* divergence of the lifted reduced flux */
      double worst = 0, *d = malloc(C * sizeof *d);
      csr_mv(&s.ops.div, fb, d);
      for (long c = 0; c < C; c++) worst = fmax(worst, fabs(d[c]));
      div_red[t] = worst;
      free(d);
    }
    if (output_frame_due(t, T, o->png_every)) {
      snprintf(p2, sizeof p2, "%s/full.png", dtmp);
      snprintf(p3, sizeof p3, "%s/reduced.png", dtmp);
      snprintf(path, sizeof path, "%s/frame_%04d.png", dframes, t);
      char capl[128], capr[128];
      snprintf(capl, sizeof capl, "full, frame %d (%d cells)", t, m.nc);
      snprintf(capr, sizeof capr, "reduced, m_u %ld, m_f %ld, m_g %ld", R->mu, R->mf, R->mg);
      if (output_png(p2, &m, s.g, s.u, &pfull, 1.6 * o->u0, o->width, err, sizeof err) != 0 ||
          output_png(p3, &m, gl, ut, &pred, 1.6 * o->u0, o->width, err, sizeof err) != 0 ||
          plot_side_by_side(path, p2, p3, capl, capr, err, sizeof err) != 0) {
        fprintf(stderr, "npg-fluids: %s\n", err);
        prc = -1;
        break;
      }
    }
    if (output_frame_due(t, T, o->vtk_every)) {
      char name[64];
      snprintf(name, sizeof name, "full_%04d.vtu", t);
      vtk_full[nvtk] = strdup(name);
      snprintf(path, sizeof path, "%s/%s", dvtk, name);
      if (output_vtu_cells(path, &m, s.g, s.u, err, sizeof err) != 0) prc = -1;
      snprintf(name, sizeof name, "reduced_%04d.vtu", t);
      vtk_red[nvtk] = strdup(name);
      snprintf(path, sizeof path, "%s/%s", dvtk, name);
      if (!prc && output_vtu_cells(path, &m, gl, ut, err, sizeof err) != 0) prc = -1;
      /* face fluxes of both runs (the reduced one lifted; its induced flux is
       * not lifted: written as zero) */
      snprintf(path, sizeof path, "%s/full_faces_%04d.vtu", dvtk, t);
      if (!prc && output_vtu_faces(path, &m, s.g, s.f, s.h, err, sizeof err) != 0) prc = -1;
      double *zero = calloc(nf, sizeof *zero);
      snprintf(path, sizeof path, "%s/reduced_faces_%04d.vtu", dvtk, t);
      if (!prc && output_vtu_faces(path, &m, gl, fb, zero, err, sizeof err) != 0) prc = -1;
      free(zero);
      vtk_times[nvtk++] = t * dt;
      if (prc) {
        fprintf(stderr, "npg-fluids: %s\n", err);
        break;
      }
    }
    seconds_output += util_now() - t0;
    if (t == T) break;
    double sig1 = sigma_at(o->scale_test, o, t + 1);
    /* one-step errors from the projected full state of frame t */
    double t1 = util_now();
    for (long c = 0; c < C; c++) pv[2 * c] = s.ops.area[c] * s.u[2 * c], pv[2 * c + 1] = s.ops.area[c] * s.u[2 * c + 1];
    if (mesh_deform(&m, sig1, s.sigma_ref, gn, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: %s\n", err);
      prc = -1;
      break;
    }
    for (long i = 0; i < ng; i++) gl[i] = (gn[i] - s.g[i]) / dt;
    for (int i = 0; i < K && !prc; i++) {
      RedSolver *q = &rs[i];
      red_project_g(q, s.g, q->g);
      red_project_g(q, gn, gc1);
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)ng, (int)q->mgd, 1.0, q->Bgd, (int)q->mgd, gl, 1, 0.0, gdc, 1);
      red_project_f(q, s.f, q->f);
      red_project_u(q, q->g, pv, q->u);
      /* full step from the lifted state */
      memcpy(probe.g, s.g, ng * sizeof(double));
      probe.sigma = s.sigma;
      lift(q->Bf, nf, q->mf, q->f, probe.f);
      lift(q->Bu, nu, q->mu, q->u, probe.u);
      for (long j = 0; j < nu; j++) ub[j] = s.u[j] - probe.u[j];
      proj_avg[i] += energy_area(s.ops.area, ub, C) / energy_area(s.ops.area, s.u, C) / T;
      ops_set_geometry(&probe.ops, probe.g);
      if (solver_step(&probe, sig1, err, sizeof err) != 0) {
        fprintf(stderr, "npg-fluids: one-step error, frame %d: %s\n", t, err);
        prc = -1;
        break;
      }
      double tq = util_now();
      if (red_step(q, gc1, gdc, err, sizeof err) != 0) {
        fprintf(stderr, "npg-fluids: one-step error, frame %d: %s\n", t, err);
        prc = -1;
        break;
      }
      step_model[i] += util_now() - tq;
      lift(q->Bu, nu, q->mu, q->u, ub);
      for (long j = 0; j < nu; j++) ub[j] = probe.u[j] - ub[j];
      double eg = energy_area(probe.ops.area, probe.u, C);
      err_onestep[(size_t)i * T + t] = energy_area(probe.ops.area, ub, C) / eg;
    }
    seconds_onestep += util_now() - t1;
    if (prc) break;
    /* the full test simulation */
    double a0 = s.seconds_advection, p0 = s.seconds_projection, d0 = s.seconds_deformation;
    if (solver_step(&s, sig1, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: test run, frame %d: %s\n", t, err);
      prc = -1;
      break;
    }
    full_adv += s.seconds_advection - a0, full_proj += s.seconds_projection - p0, full_def += s.seconds_deformation - d0;
    max_div_full = fmax(max_div_full, projection_max_divergence(&s.ops, s.f));
    e_full[t + 1] = solver_energy(&s);
    if (solver_check_energy(e_full[0], e_full[t + 1], t + 1, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: test run: %s\n", err);
      prc = -1;
      break;
    }
    /* the reduced test simulation (timed: the step alone) */
    red_state_restore(R, &rstate);
    double e0 = R->seconds_eval, a1 = R->seconds_advection, p1 = R->seconds_projection;
    double t2 = util_now();
    if (red_step(R, traj_g + (size_t)(t + 1) * R->mg, traj_gd + (size_t)t * R->mgd, err, sizeof err) != 0) {
      fprintf(stderr, "npg-fluids: reduced run, frame %d: %s\n", t, err);
      prc = -1;
      break;
    }
    step_times[red_steps] = util_now() - t2;
    seconds_red += step_times[red_steps];
    red_eval += R->seconds_eval - e0, red_adv += R->seconds_advection - a1, red_proj += R->seconds_projection - p1;
    red_steps++;
    red_state_save(R, &rstate);
    e_red[t + 1] = red_energy(R, R->g, R->u);
    /* particles: full through the full flux, reduced through the lifted
     * reduced flux (Eq. 13 evaluated per cell) */
    double t3 = util_now();
    lift(R->Bg, ng, R->mg, rstate.g, gl);
    lift(R->Bf, nf, R->mf, rstate.f, fb);
    particles_advect(&pred, &m, gl, fb, dt, 10);
    seconds_particles += util_now() - t3;
    particles_advect(&pfull, &m, s.g, s.f, dt, 10);
    if (t % 50 == 0) fprintf(stderr, "npg-fluids: test frame %d/%d\n", t, T);
  }
  /* the reduced step alone, repeated from the last state (the minimum over
   * repeats is the figure least disturbed by other jobs on the machine):
   * as run (the exponential applied to û by Arnoldi), and with the whole
   * matrix exponential (Padé, scaling and squaring) in its place, repeats
   * interleaved so that both see the same load */
  double bench_step = INFINITY, bench_expm = INFINITY;
  int bench_krylov = 0, bench_pade = 0;
  if (!prc) {
    for (int rep = 0; rep < 200 && !prc; rep++) {
      red_state_restore(R, &rstate);
      R->integ = rep % 2 ? RED_EXPM : RED_EXPMV;
      double t2 = util_now();
      if (red_step(R, traj_g + (size_t)(T - 1) * R->mg, traj_gd + (size_t)(T - 2) * R->mgd, err, sizeof err) != 0) prc = -1;
      double dtm = util_now() - t2;
      if (rep % 2) bench_expm = fmin(bench_expm, dtm), bench_pade = R->last_pade;
      else bench_step = fmin(bench_step, dtm), bench_krylov = R->last_krylov;
    }
    R->integ = RED_EXPMV;
  }
  free(traj_g), free(traj_gd);
  red_state_free(&rstate);
  if (prc) goto done;
  for (int i = 0; i < K; i++) {
    double a = 0;
    for (int t = 0; t < T; t++) a += err_onestep[(size_t)i * T + t];
    err_avg[i] = a / T;
  }
  /* plots */
  {
    double **xs = malloc(K * sizeof *xs), **ys = malloc(K * sizeof *ys);
    char **labels = malloc(K * sizeof *labels);
    int *ns = malloc(K * sizeof *ns);
    for (int i = 0; i < K; i++) {
      xs[i] = malloc(T * sizeof(double));
      ys[i] = err_onestep + (size_t)i * T;
      for (int t = 0; t < T; t++) xs[i][t] = t;
      ns[i] = T;
      labels[i] = malloc(64);
      snprintf(labels[i], 64, "m_u %ld, m_f %ld", msz[i][0], msz[i][1]);
    }
    snprintf(path, sizeof path, "%s/onestep_error.png", dplots);
    int e1 = plot_lines(path, "one-step error E(u_ground - u_test) / E(u_ground), test (medium obstacle)", "frame",
                        "relative one-step error", K, ns, (const double *const *)xs, (const double *const *)ys,
                        (const char *const *)labels, 1, err, sizeof err);
    double *mx = malloc(K * sizeof *mx);
    for (int i = 0; i < K; i++) mx[i] = (double)msz[i][0];
    int one = K;
    const char *lab = "time average";
    snprintf(path, sizeof path, "%s/onestep_error_average.png", dplots);
    int e2 = e1 ? -1 : plot_lines(path, "time-averaged one-step error against basis size", "m_u, the velocity class's basis size",
                                  "time-averaged one-step error", 1, &one, (const double *const *)&mx,
                                  (const double *const *)&err_avg, &lab, 1, err, sizeof err);
    if (e1 || e2) fprintf(stderr, "npg-fluids: %s\n", err);
    for (int i = 0; i < K; i++) free(xs[i]), free(labels[i]);
    free(xs), free(ys), free(labels), free(ns), free(mx);
    /* energies */
    double *tx = malloc((T + 1) * sizeof *tx);
    for (int t = 0; t <= T; t++) tx[t] = t;
    int n2[2] = {T + 1, T + 1};
    const double *x2[2] = {tx, tx}, *y2[2] = {e_full, e_red};
    const char *l2[2] = {"full", "reduced (largest basis)"};
    snprintf(path, sizeof path, "%s/energy.png", dplots);
    if (plot_lines(path, "energy 1/2 u^T V(g) u of the test runs", "frame", "energy", 2, n2, x2, y2, l2, 0, err,
                   sizeof err) != 0)
      fprintf(stderr, "npg-fluids: %s\n", err);
    free(tx);
  }
  /* VTK collections */
  snprintf(path, sizeof path, "%s/full.pvd", dvtk);
  snprintf(p2, sizeof p2, "%s/reduced.pvd", dvtk);
  if (output_pvd(path, nvtk, (const char *const *)vtk_full, vtk_times, err, sizeof err) != 0 ||
      output_pvd(p2, nvtk, (const char *const *)vtk_red, vtk_times, err, sizeof err) != 0) {
    fprintf(stderr, "npg-fluids: %s\n", err);
    goto done;
  }
  /* report.json */
  {
    snprintf(path, sizeof path, "%s/report.json", o->out);
    FILE *fp = fopen(path, "w");
    if (!fp) {
      fprintf(stderr, "npg-fluids: %s: %s\n", path, strerror(errno));
      goto done;
    }
    double full_step = (full_adv + full_proj + full_def) / T, red_step_s = seconds_red / red_steps;
    size_t tbytes = 0, mbytes = npg_model_bytes(models[K - 1], &tbytes);
    fprintf(fp, "{\n  \"cells\": %d, \"faces\": %d, \"boundary_faces\": %d, \"vertices\": %d, \"dt\": %.6g, \"mu\": %g,\n",
            m.nc, m.nf, m.nb, m.nv, dt, o->mu);
    fprintf(fp, "  \"frames\": %d, \"scales\": {\"train\": [%g, %g], \"test\": %g, \"pulse\": %g, \"period\": %g},\n", T,
            o->scale_large, o->scale_small, o->scale_test, o->pulse, o->period);
    fprintf(fp, "  \"training_samples\": %ld, \"training_runs_seconds\": %.3f,\n", S.n, seconds_train_runs);
    fprintf(fp, "  \"models\": [\n");
    for (int i = 0; i < K; i++) {
      size_t tb = 0, mb = npg_model_bytes(models[i], &tb);
      fprintf(fp,
              "    {\"m_u\": %ld, \"m_f\": %ld, \"m_g\": %ld, \"m_gdot\": %ld, \"m_d\": %ld, \"rank_D\": %ld, "
              "\"train_seconds\": %.3f, \"model_bytes\": %zu, \"tensor_bytes\": %zu, \"basis_f_max_divergence\": %.3e, "
              "\"onestep_error_mean\": %.6e, \"projection_error_mean\": %.6e, \"reduced_step_seconds\": %.6e, "
              "\"speedup\": %.2f}%s\n",
              rs[i].mu, rs[i].mf, rs[i].mg, rs[i].mgd, rs[i].mb, rs[i].drank, train_seconds[i], mb, tb, div_basis[i],
              err_avg[i], proj_avg[i], step_model[i] / T, (full_adv + full_proj + full_def) / step_model[i], i + 1 < K ? "," : "");
    }
    fprintf(fp, "  ],\n");
    fprintf(fp, "  \"onestep_error\": [\n");
    for (int i = 0; i < K; i++) {
      fprintf(fp, "    [");
      for (int t = 0; t < T; t++) fprintf(fp, "%s%.4e", t ? ", " : "", err_onestep[(size_t)i * T + t]);
      fprintf(fp, "]%s\n", i + 1 < K ? "," : "");
    }
    fprintf(fp, "  ],\n");
    json_array(fp, "onestep_error_mean", err_avg, K, ",");
    int mono = 1;
    for (int i = 1; i < K; i++) mono &= err_avg[i] < err_avg[i - 1];
    fprintf(fp, "  \"onestep_error_mean_monotone\": %s,\n", mono ? "true" : "false");
    json_array(fp, "energy_full", e_full, T + 1, ",");
    json_array(fp, "energy_reduced", e_red, T + 1, ",");
    double drift_red = 0;
    for (int t = 0; t < T; t++) drift_red = fmax(drift_red, (e_red[t + 1] - e_red[t]) / e_red[t]);
    fprintf(fp, "  \"energy_drift_full\": %.6e, \"energy_drift_reduced\": %.6e, \"energy_max_increase_per_step_reduced\": %.3e,\n",
            (e_full[T] - e_full[0]) / e_full[0], (e_red[T] - e_red[0]) / e_red[0], drift_red);
    double mdr = 0;
    for (int t = 0; t <= T; t++) mdr = fmax(mdr, div_red[t]);
    fprintf(fp, "  \"max_divergence_full\": %.3e, \"max_divergence_reduced\": %.3e,\n", max_div_full, mdr);
    fprintf(fp,
            "  \"full_step_seconds\": %.6e, \"full_advection_seconds\": %.6e, \"full_projection_seconds\": %.6e, "
            "\"full_deformation_seconds\": %.6e,\n",
            full_step, full_adv / T, full_proj / T, full_def / T);
    fprintf(fp,
            "  \"reduced_step_seconds\": %.6e, \"reduced_assembly_seconds\": %.6e, \"reduced_advection_seconds\": %.6e, "
            "\"reduced_projection_seconds\": %.6e, \"reduced_pade_degree\": %d, \"reduced_squarings\": %d,\n",
            red_step_s, red_eval / red_steps, red_adv / red_steps, red_proj / red_steps, R->last_pade,
            R->last_squarings);
    {
      double *st = malloc(red_steps * sizeof *st);
      memcpy(st, step_times, red_steps * sizeof *st);
      for (long i = 1; i < red_steps; i++)
        for (long j = i; j > 0 && st[j] < st[j - 1]; j--) {
          double x = st[j];
          st[j] = st[j - 1], st[j - 1] = x;
        }
      fprintf(fp, "  \"reduced_step_seconds_median\": %.6e, \"reduced_step_seconds_min\": %.6e,\n", st[red_steps / 2], st[0]);
      fprintf(fp,
              "  \"reduced_step_seconds_min_of_100_repeats\": %.6e, \"reduced_arnoldi_steps\": %d,\n"
              "  \"reduced_step_whole_expm_seconds_min_of_100_repeats\": %.6e, \"reduced_step_whole_expm_pade_degree\": %d,\n",
              bench_step, bench_krylov, bench_expm, bench_pade);
      free(st);
    }
    fprintf(fp, "  \"reduced_basis\": {\"m_u\": %ld, \"m_f\": %ld, \"m_g\": %ld},\n", R->mu, R->mf, R->mg);
    fprintf(fp, "  \"speedup\": %.2f,\n", full_step / red_step_s);
    fprintf(fp, "  \"particles\": %d, \"particle_seconds\": %.6e, \"onestep_seconds\": %.3f, \"output_seconds\": %.3f,\n",
            o->particles, seconds_particles / T, seconds_onestep, seconds_output);
    fprintf(fp, "  \"model_bytes\": %zu, \"tensor_bytes\": %zu\n}\n", mbytes, tbytes);
    if (fclose(fp) != 0) {
      fprintf(stderr, "npg-fluids: %s: write failed\n", path);
      goto done;
    }
    fprintf(stderr,
            "npg-fluids: reduced step, minimum of 100 repeats from the last state: %.3f ms (exponential by Arnoldi, "
            "%d steps); with the whole matrix exponential (Padé %d): %.3f ms\n",
            1e3 * bench_step, bench_krylov, bench_pade, 1e3 * bench_expm);
  fprintf(stderr,
            "npg-fluids: one-step error (time average) per basis size:");
    for (int i = 0; i < K; i++)
      fprintf(stderr, " m_u %ld: %.3e (state's projection %.3e; reduced step from each projected state, mean %.3f ms, "
                      "speedup %.1f);",
              rs[i].mu, err_avg[i],
              proj_avg[i], 1e3 * step_model[i] / T, (full_adv + full_proj + full_def) / step_model[i]);
    fprintf(stderr, "\nnpg-fluids: full step %.3f ms (advection %.3f, projection %.3f, deformation %.3f), reduced step, "
                    "mean over the run's %ld steps %.3f ms (operators %.3f, exponential %.3f, projection %.3f): speedup of "
                    "the means %.1f\n",
            1e3 * full_step, 1e3 * full_adv / T, 1e3 * full_proj / T, 1e3 * full_def / T, red_steps, 1e3 * red_step_s,
            1e3 * red_eval / red_steps, 1e3 * red_adv / red_steps, 1e3 * red_proj / red_steps, full_step / red_step_s);
  }
  rc = 0;
done:
  snprintf(p2, sizeof p2, "%s/full.png", dtmp), remove(p2);
  snprintf(p3, sizeof p3, "%s/reduced.png", dtmp), remove(p3);
  rmdir(dtmp);
  for (int i = 0; i < K; i++) {
    if (rs_ok[i]) red_free(&rs[i]);
    if (models[i]) npg_model_free(models[i]);
  }
  for (int i = 0; i < nvtk; i++) free(vtk_full[i]), free(vtk_red[i]);
  free(vtk_full), free(vtk_red), free(vtk_times);
  if (s_ok) solver_free(&s);
  if (probe_ok) solver_free(&probe);
  particles_free(&pfull), particles_free(&pred);
  free(models), free(rs), free(rs_ok), free(S.g), free(S.gdot), free(S.f), free(S.u);
  free(err_onestep), free(err_avg), free(proj_avg), free(div_basis), free(train_seconds), free(msz), free(e_full), free(e_red), free(div_red);
  free(step_times), free(step_model);
  free(ub), free(ut), free(pv), free(fb), free(gl), free(gn), free(uc), free(fc), free(gc), free(gc1), free(gdc);
  npg_full_free(fe);
  npg_free(prog);
  mesh_free(&m);
  plot_cleanup();
  return rc;
}
