/* rollout_cmds.c — verify and bench of a program with state judged over the trajectory
 * (DESIGN §15), not one step:
 *
 *   npgc verify PROG.npg MODEL/ TEST/ --steps T [--every K] [--png FILE]
 *   npgc bench  PROG.npg MODEL/ TEST/ --steps T
 *
 * TEST/ holds each trajectory's initial states and its inputs (held or per step, trajectories.c).
 * verify runs the full and the reduced rollouts and compares the states at every saved step with
 * the trajectory's projection floor: the full states projected onto the model's bases, the best
 * any reduced rollout in those bases can do. bench times the full step against the reduced step
 * in coordinates (states never lifted), and the lift of the states apart. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "chart.h"
#include "npg.h"
#include "npgc.h"
#include "reduce_cmds.h"

typedef struct Roll {
  Common *c;
  NpgProgram *p;
  NpgModel *m;
  NpgFull *f;
  NpgReduced *r;            /* the reduced rollout */
  Trajectories tr;
  int ns;
  TrajInput **st;           /* the states */
  long saves, k;
  double **red;             /* per state: one lifted value (bench) */
  const char **est;         /* the outputs and the states' next values, whose estimates bench times */
  int nest;
} Roll;

static void close_roll(Roll *x) {
  free(x->est);
  for (int i = 0; x->red && i < x->ns; i++) free(x->red[i]);
  free(x->red);
  free(x->st);
  npgc_trajectories_free(&x->tr);
  npg_reduced_free(x->r);
  npg_full_free(x->f);
  npg_model_free(x->m);
  npg_free(x->p);
}

static int open_roll(Common *c, Roll *x, const char *cmd) {
  memset(x, 0, sizeof *x);
  x->c = c;
  if (!c->prog_path) return npgc_missing(cmd, "the program (PROG.npg)");
  if (!c->a) return npgc_missing(cmd, "MODEL/ (a model trained by npgc train)");
  if (!c->b) return npgc_missing(cmd, "TEST/ (held-out initial states)");
  if (npgc_check_model_and_data(cmd, c->a, c->b, "TEST/") != 0) return 1;
  char err[4400];
  const char *params = c->params ? c->params : c->b;
  if (!(x->p = reduce_compile(c))) return 1;
  x->m = npg_model_load(x->p, c->a);
  if (npg_model_error(x->m)[0]) return npgc_error(npg_model_error(x->m)), 1;
  if (npg_model_check_params_dir(x->m, params, err, sizeof err) != 0) return npgc_error(err), 1;
  if (npgc_trajectories_open(x->p, c->b, c->steps, &x->tr, err, sizeof err) != 0) return npgc_error(err), 1;
  x->f = npg_full_new(x->p, c->backend);
  if (npg_full_error(x->f)[0] || npg_full_bind_params(x->f, params) != 0) return npgc_error(npg_full_error(x->f)), 1;
  x->r = npg_reduced_new(x->m);
  if (npg_reduced_error(x->r)[0]) return npgc_error(npg_reduced_error(x->r)), 1;
  npgc_newton_full(&c->newton, x->f);
  npgc_newton_reduced(&c->newton, x->r);
  x->saves = c->steps / c->every + 1;
  x->st = calloc((size_t)x->tr.n + 1, sizeof *x->st);
  x->red = calloc((size_t)x->tr.n + 1, sizeof *x->red);
  if (!x->st || !x->red) return fputs("error: out of memory\n", stderr), 1;
  for (int i = 0; i < x->tr.n; i++)
    if (x->tr.in[i].sym.next) {
      x->st[x->ns] = &x->tr.in[i];
      if (!(x->red[x->ns++] = malloc(sizeof(double) * (x->tr.in[i].each + 1))))
        return fputs("error: out of memory\n", stderr), 1;
    }
  if (!(x->est = calloc((size_t)npg_nsymbols(x->p) + 1, sizeof *x->est))) return fputs("error: out of memory\n", stderr), 1;
  for (int i = 0; i < npg_nsymbols(x->p); i++) {
    NpgSymbol s;
    if (npg_symbol(x->p, i, &s) == 0 && s.kind != NPG_OP && (s.output || s.state_of)) x->est[x->nest++] = s.name;
  }
  if (x->ns == 0) {
    fprintf(stderr, "error: %s has no state: --steps judges a rollout of a program with 'state u' and 'next u = "
                    "...'; without --steps, %s judges one evaluation\n", c->prog_path, cmd);
    return 1;
  }
  return 0;
}

static int full_before(void *user, long step) {
  Roll *x = user;
  return step ? npgc_trajectories_set_full(&x->tr, x->f, x->k, step, false) : 0;
}

static int reduced_before(void *user, long step) {
  Roll *x = user;
  return step ? npgc_trajectories_set_reduced(&x->tr, x->r, x->k, step, false) : 0;
}

/* ---------------------------------------------------------------- verify --steps */

/* Trajectory k's values at step t from TEST/ (an NpgStepFn). */
static int set_step(void *user, NpgFull *f, long k, long t) {
  return npgc_trajectories_set_full(&((Roll *)user)->tr, f, k, t, t == 0);
}

static int plot_png(const Common *c, const NpgRolloutReport *rep, char *err, size_t errlen) {
  int nser = 2 * rep->nstates;
  ChartSeries *ser = calloc((size_t)nser, sizeof *ser);
  double *t = malloc(sizeof(double) * (size_t)rep->saves);
  char (*labels)[160] = calloc((size_t)nser, sizeof *labels);
  int rc = -1;
  if (!ser || !t || !labels) {
    snprintf(err, errlen, "out of memory");
    goto done;
  }
  for (long s = 0; s < rep->saves; s++) t[s] = (double)(s * rep->every);
  for (int i = 0; i < rep->nstates; i++) {
    const NpgRolloutRow *row = &rep->rows[i];
    snprintf(labels[2 * i], sizeof labels[0], "%s: reduced rollout", row->state);
    snprintf(labels[2 * i + 1], sizeof labels[0], "%s: projection floor", row->state);
    ser[2 * i] = (ChartSeries){.label = labels[2 * i], .n = (int)rep->saves, .x = t, .y = row->err, .mark = -1};
    ser[2 * i + 1] = (ChartSeries){.label = labels[2 * i + 1], .n = (int)rep->saves, .x = t, .y = row->floor, .mark = -1};
  }
  char title[400];
  snprintf(title, sizeof title, "%s: rollout error against time (largest over %ld trajectories)", c->prog_path,
           rep->trajectories);
  Chart ch = {.title = title, .xlabel = "step", .ylabel = "relative L2 error of the state", .logy = true,
              .nseries = nser, .series = ser};
  char tmp[4200];
  npgc_tmp_path(tmp, sizeof tmp, c->png);
  rc = chart_png(&ch, tmp, 900, 520, err, errlen);
  chart_cleanup(); /* a command draws once: cairo's and fontconfig's caches released */
  rc = npgc_commit("verify", tmp, c->png, rc);
done:
  free(ser);
  free(t);
  free(labels);
  return rc;
}

int cmd_verify_steps(Common *c) {
  Roll x;
  NpgRolloutReport rep = {0};
  int rc = 1;
  if (c->png) {
    const char *inputs[] = {c->prog_path, c->a, c->b, c->params, NULL};
    if (npgc_check_output("verify", "--png", c->png, NPGC_OUT_FILE, inputs) != 0) return 1;
  }
  if (open_roll(c, &x, "verify") != 0) goto done;
  if (npg_verify_rollout(x.m, x.f, x.tr.samples, c->steps, c->every, set_step, &x, c->train.progress, &rep) != 0) {
    if (c->train.progress) fputc('\n', stderr);
    npgc_error(rep.error);
    goto done;
  }
  printf("verify %s: %ld trajector%s of %s, %ld steps, states compared every %ld (%ld saves); relative L2 errors\n",
         c->prog_path, rep.trajectories, rep.trajectories == 1 ? "y" : "ies", c->b, rep.steps, rep.every, rep.saves);
  printf("%-10s %12s %12s %12s %12s %8s  %s\n", "state", "trajectory", "floor", "final", "max", "err/flr", "max at");
  rc = 0;
  for (int i = 0; i < rep.nstates; i++) {
    const NpgRolloutRow *row = &rep.rows[i];
    double te = row->traj_err, tf = row->traj_floor;
    char ratio[32];
    if (tf > 1e-12) snprintf(ratio, sizeof ratio, "%.3g", te / tf); /* a whole basis: no floor to compare with */
    else snprintf(ratio, sizeof ratio, "-");
    printf("%-10s %12.3e %12.3e %12.3e %12.3e %8s  trajectory %ld, step %ld\n", row->state, te, tf, row->err_final,
           row->err_max, ratio, row->max_trajectory, row->max_step);
    if (!(te <= c->tol)) {
      printf("FAIL: state %s: trajectory error %.3e above --tol %.3g (its projection floor is %.3e%s)\n", row->state, te,
             c->tol, tf,
             tf > c->tol ? ": the bases cannot hold the trajectory; train on more of it or raise their cap/energy"
             : te > 3 * tf ? ": the state's bases hold the trajectory, the step drifts from them; raise the bases of "
                             "the step's other quantities (npgc verify without --steps reports each one's error) or "
                             "train on more of the trajectories" : "");
      rc = 1;
    }
  }
  printf("(trajectory: ‖R − F‖ / ‖F‖ over every trajectory and saved step; floor: the same for the full states\n"
         " projected onto the model's bases; final and max: per trajectory and step, the largest)\n");
  if (rc == 0) printf("ok: every state's trajectory error within --tol %.3g\n", c->tol);
  if (c->png) {
    char err[4400];
    if (plot_png(c, &rep, err, sizeof err) != 0) {
      npgc_error(err);
      rc = 1;
    } else {
      printf("error against time -> %s\n", c->png);
    }
  }
done:
  npg_verify_rollout_free(&rep);
  close_roll(&x);
  return rc;
}

/* ---------------------------------------------------------------- bench --steps */

/* Every output's and every state's next value's estimate after an evaluation (npg_reduced_estimate: the first
 * call computes them all, the others read them), timed; *with those that got a figure. -1 on an error. */
static double step_estimates(Roll *x, int *with) {
  double t0 = reduce_now(), e;
  unsigned flags;
  *with = 0;
  for (int i = 0; i < x->nest; i++) {
    if (npg_reduced_estimate(x->r, x->est[i], &e, &flags) != 0) return -1;
    *with += !(flags & NPG_EST_NONE);
  }
  return reduce_now() - t0;
}

/* Trajectory x->k's reduced rollout with each step's estimates: at every step the reduced evaluation at its
 * inputs, then the estimates, timed (the step then advances the states, untimed); their means per step in
 * alone_est[0] (the evaluation) and alone_est[1] (the evaluation and the estimates). -1 on an error. */
static int time_step_estimates(Roll *x, double alone_est[2], int *with) {
  long steps = x->c->steps;
  double sum[2] = {0, 0};
  if (npgc_trajectories_set_reduced(&x->tr, x->r, x->k, 0, true) != 0) return -1;
  for (long t = 0; t < steps; t++) {
    if (t && npgc_trajectories_set_reduced(&x->tr, x->r, x->k, t, false) != 0) return -1;
    double t0 = reduce_now();
    if (npg_reduced_eval(x->r, x->k) != 0) return -1;
    double t1 = reduce_now(), ts = step_estimates(x, with);
    if (ts < 0 || npg_reduced_step(x->r, 1, x->k) != 0) return -1;
    sum[0] += t1 - t0, sum[1] += t1 - t0 + ts;
  }
  alone_est[0] = sum[0] / (double)(steps ? steps : 1), alone_est[1] = sum[1] / (double)(steps ? steps : 1);
  return 0;
}

/* The line of the reduced evaluation with its estimates (npgc bench's "reduced + estimate", per step);
 * without any figure, why the first quantity has none. */
static void print_step_estimates(Roll *x, int with, double *te, double *ratio, long timed) {
  if (!with) {
    if (x->nest) printf("reduced + estimate  none: %s has no estimate (%s)\n", x->est[0],
                        npg_reduced_estimate_why(x->r, x->est[0]));
    return;
  }
  double q[3], qs[3];
  npgc_quartiles(te, timed, q);
  npgc_quartiles(ratio, timed, qs);
  printf("reduced + estimate  %12.3e s [%.3e, %.3e] per step: the reduced evaluation at the step's inputs, then every "
         "output's and next state's estimate (npg_reduced_estimate, %d of them with a figure): %.3gx [%.3gx, %.3gx] "
         "the evaluation alone\n", q[1], q[0], q[2], with, qs[1], qs[0], qs[2]);
}

int cmd_bench_steps(Common *c) {
  Roll x;
  int rc = 1;
  double *tf = NULL;
  if (open_roll(c, &x, "bench") != 0) goto done;
  long S = x.tr.samples, n = S * c->reps;
  if (!(tf = malloc(sizeof(double) * (size_t)(6 * n + 6)))) {
    fputs("error: out of memory\n", stderr);
    goto done;
  }
  double *tr = tf + n + 1, *tl = tr + n + 1, *ratio = tl + n + 1, *te = ratio + n + 1, *ratio_est = te + n + 1;
  int with = 0; /* quantities with an estimate */
  NpgRollout fro = {.steps = c->steps, .every = c->steps, .before_step = full_before, .user = &x};
  NpgRollout rro = {.steps = c->steps, .every = c->steps, .before_step = reduced_before, .user = &x};
  long timed = 0;
  for (long rep = 0; rep < c->reps; rep++)
    for (x.k = 0; x.k < S; x.k++) {
      char err[2400];
      if (npgc_trajectories_set_full(&x.tr, x.f, x.k, 0, true) != 0) goto full_failed;
      double t0 = reduce_now();
      if (npg_full_simulate(x.f, x.k, &fro) != 0) goto full_failed;
      double t1 = reduce_now();
      if (npgc_trajectories_set_reduced(&x.tr, x.r, x.k, 0, true) != 0) goto reduced_failed;
      double t2 = reduce_now();
      if (npg_reduced_simulate(x.r, x.k, &rro) != 0) goto reduced_failed;
      double t3 = reduce_now();
      for (int i = 0; i < x.ns; i++)
        if (npg_reduced_lift(x.r, x.st[i]->sym.name, x.red[i], x.st[i]->each) != 0) goto reduced_failed;
      double t4 = reduce_now(), alone_est[2];
      if (time_step_estimates(&x, alone_est, &with) != 0) goto reduced_failed;
      te[timed] = alone_est[1];
      ratio_est[timed] = alone_est[1] / fmax(alone_est[0], 1e-15);
      tf[timed] = (t1 - t0) / (double)c->steps;
      tr[timed] = (t3 - t2) / (double)c->steps;
      tl[timed] = t4 - t3;
      ratio[timed] = tf[timed] / fmax(tr[timed], 1e-15);
      timed++;
      npg_progress(c->train.progress, "bench rollouts (full and reduced)", timed, n);
      continue;
    full_failed:
      snprintf(err, sizeof err, "trajectory %ld, full rollout: %s", x.k, npg_full_error(x.f));
      npgc_error(err);
      goto done;
    reduced_failed:
      snprintf(err, sizeof err, "trajectory %ld, reduced rollout: %s", x.k, npg_reduced_error(x.r));
      npgc_error(err);
      goto done;
    }
  double qf[3], qr[3], ql[3], qs[3];
  npgc_quartiles(tf, timed, qf);
  npgc_quartiles(tr, timed, qr);
  npgc_quartiles(tl, timed, ql);
  npgc_quartiles(ratio, timed, qs);
  printf("bench %s: %ld trajector%s x %ld passes of %ld steps, %d BLAS thread%s; per step, medians over the rollouts, "
         "quartiles in brackets\n", c->prog_path, S, S == 1 ? "y" : "ies", c->reps, c->steps, c->threads,
         c->threads == 1 ? " (--threads N for more)" : "s");
  npgc_print_jit(x.f);
  printf("full step           %12.3e s [%.3e, %.3e]\n", qf[1], qf[0], qf[2]);
  printf("reduced step        %12.3e s [%.3e, %.3e], in reduced coordinates (states never lifted)\n", qr[1], qr[0],
         qr[2]);
  printf("lift of the states  %12.3e s [%.3e, %.3e], once per saved frame\n", ql[1], ql[0], ql[2]);
  printf("speedup             %12.3gx [%.3gx, %.3gx] (full step / reduced step%s)\n", qs[1], qs[0], qs[2],
         qs[1] < 1 ? ": below 1, the reduced step is slower" : "");
  print_step_estimates(&x, with, te, ratio_est, timed);
  rc = 0;
done:
  free(tf);
  close_roll(&x);
  return rc;
}
