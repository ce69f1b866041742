/* simulate.c — `npgc simulate PROG.npg DATA/ --steps T [--every K] [--model MODEL/] -o OUT/`:
 * run the program's time step T times from each trajectory's initial states in DATA/ (params
 * there too; inputs held or given per step, trajectories.c), the full step or, with MODEL/, the
 * reduced step with every state kept in coordinates and lifted only at the saved steps. Writes
 * OUT/<state>.npy, [trajectories, T/K + 1, ...]: steps 0, K, 2K, … (DESIGN §15). A blow-up stops
 * the run with the step and the state; OUT/ is written only when every trajectory finished. */
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "npg.h"
#include "npgc.h"

typedef struct Sim {
  const Trajectories *t;
  NpgFull *f;
  NpgReduced *r;
  long k, saves;
  int nstates;
  TrajInput **states;       /* the trajectory inputs that are states */
  double **out;             /* per state: trajectories x saves x each */
  long every;
} Sim;

static int before_step(void *user, long step) {
  Sim *s = user;
  if (step == 0) return 0; /* set with the initial states */
  return s->f ? npgc_trajectories_set_full(s->t, s->f, s->k, step, false)
              : npgc_trajectories_set_reduced(s->t, s->r, s->k, step, false);
}

static int at_save(void *user, long step) {
  Sim *s = user;
  for (int i = 0; i < s->nstates; i++) {
    const TrajInput *in = s->states[i];
    double *dst = s->out[i] + ((size_t)s->k * (size_t)s->saves + (size_t)(step / s->every)) * in->each;
    if (s->f) {
      size_t n = 0;
      const double *v = npg_full_get(s->f, in->sym.name, &n);
      if (!v || n != in->each) return -1;
      memcpy(dst, v, sizeof(double) * n);
    } else if (npg_reduced_lift(s->r, in->sym.name, dst, in->each) != 0) {
      return -1;
    }
  }
  return 0;
}

static int write_states(const Sim *s, const char *outdir) {
  for (int i = 0; i < s->nstates; i++) {
    const TrajInput *in = s->states[i];
    long shape[10];
    int nd = 0;
    shape[nd++] = s->t->samples;
    shape[nd++] = s->saves;
    for (int k = in->ndim - in->axes; k < in->ndim; k++) shape[nd++] = in->shape[k];
    char path[4200], err[1024];
    snprintf(path, sizeof path, "%s/%s.npy", outdir, in->sym.name);
    if (npg_npy_write(path, nd, shape, s->out[i], err, sizeof err) != 0) {
      npgc_error(err);
      return -1;
    }
  }
  return 0;
}

static int simulate(NpgProgram *p, const char *data, const char *model_dir, long steps, long every, double blowup,
                    const NpgcNewton *nw, NpgBackend backend, bool progress, const char *outdir) {
  int rc = 1;
  char err[4400] = "";
  Trajectories t = {0};
  Sim s = {0};
  NpgModel *m = NULL;
  s.every = every;
  s.saves = steps / every + 1;
  if (npgc_trajectories_open(p, data, steps, &t, err, sizeof err) != 0) {
    npgc_error(err);
    return 1;
  }
  s.t = &t;
  s.states = calloc((size_t)t.n + 1, sizeof *s.states);
  s.out = calloc((size_t)t.n + 1, sizeof *s.out);
  if (!s.states || !s.out) goto oom;
  for (int i = 0; i < t.n; i++)
    if (t.in[i].sym.next) {
      s.states[s.nstates] = &t.in[i];
      size_t n = (size_t)t.samples * (size_t)s.saves * t.in[i].each;
      if (!(s.out[s.nstates++] = malloc(sizeof(double) * (n ? n : 1)))) goto oom;
    }
  if (s.nstates == 0) {
    fputs("error: the program has no state: declare one with 'state u : ...' and its next value with 'next u = "
          "...'\n", stderr);
    goto done;
  }
  if (model_dir) {
    m = npg_model_load(p, model_dir);
    if (npg_model_error(m)[0]) {
      npgc_error(npg_model_error(m));
      goto done;
    }
    if (npg_model_check_params_dir(m, data, err, sizeof err) != 0) {
      npgc_error(err);
      goto done;
    }
    s.r = npg_reduced_new(m);
    if (blowup >= 0) npg_reduced_set_blowup(s.r, blowup);
    npgc_newton_reduced(nw, s.r);
  } else {
    s.f = npg_full_new(p, backend);
    if (!npg_full_error(s.f)[0]) npg_full_bind_params(s.f, data);
    if (blowup >= 0) npg_full_set_blowup(s.f, blowup);
    npgc_newton_full(nw, s.f);
  }
  bool tty = progress || isatty(2);
  NpgRollout ro = {.steps = steps, .every = every, .before_step = before_step, .at_save = at_save, .user = &s};
  for (s.k = 0; s.k < t.samples; s.k++) {
    int bad = s.f ? (npg_full_error(s.f)[0] || npgc_trajectories_set_full(&t, s.f, s.k, 0, true) ||
                     npg_full_simulate(s.f, s.k, &ro))
                  : (npg_reduced_error(s.r)[0] || npgc_trajectories_set_reduced(&t, s.r, s.k, 0, true) ||
                     npg_reduced_simulate(s.r, s.k, &ro));
    if (bad) {
      if (tty) fputc('\n', stderr);
      snprintf(err, sizeof err, "trajectory %ld: %s", s.k, s.f ? npg_full_error(s.f) : npg_reduced_error(s.r));
      npgc_error(err);
      goto done;
    }
    npg_progress(tty, model_dir ? "reduced rollouts" : "full rollouts", s.k + 1, t.samples);
  }
  if (npgc_make_parents(outdir, true) != 0 || write_states(&s, outdir) != 0) goto done;
  rc = 0;
  goto done;
oom:
  fputs("npgc simulate: out of memory\n", stderr);
done:
  for (int i = 0; s.out && i < s.nstates; i++) free(s.out[i]);
  free(s.out);
  free(s.states);
  npg_full_free(s.f);
  npg_reduced_free(s.r);
  npg_model_free(m);
  npgc_trajectories_free(&t);
  return rc;
}

int npgc_simulate(int argc, char **argv) {
  const char *prog_path = NULL, *data = NULL, *outdir = NULL, *model = NULL;
  long steps = -1, every = 1;
  double blowup = -1;
  NpgcNewton nw = NPGC_NEWTON_DEFAULT;
  bool progress = false;
  NpgBackend backend = NPG_AUTO;
  NpgOptions opt = {0};
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npgc simulate");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage("simulate", true);
    if (npg_args_backend(&a, &backend)) {}
    else if (npg_args_flag(&a, "--progress")) progress = true;
    else if (npg_args_long(&a, "--steps", 0, 1000000000L, &steps)) {}
    else if (npg_args_long(&a, "--every", 1, 1000000000L, &every)) {}
    else if (npg_args_double(&a, "--blowup", 0, 1e300, false, &blowup)) {}
    else if (npgc_newton_arg(&a, &nw)) {}
    else if ((v = npg_args_string(&a, "--model"))) model = v;
    else if ((v = npg_args_string(&a, "-o"))) outdir = v;
    else if ((v = npg_args_string(&a, "--std"))) opt.std_dir = v;
    else if ((v = npg_args_positional(&a))) {
      if (!prog_path) prog_path = v;
      else if (!data) data = v;
      else npgc_args_extra(&a, "data folder", data);
    } else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, "simulate");
  if (!prog_path) return npgc_missing("simulate", "the program (PROG.npg)");
  if (!data) return npgc_missing("simulate", "DATA/ (params and each trajectory's initial states)");
  if (steps < 0) return npgc_missing("simulate", "--steps T (the steps to run)");
  if (!outdir) return npgc_missing("simulate", "-o OUT/ (where to write the states)");
  if (blowup > 0 && blowup <= 1) {
    fprintf(stderr, "npgc simulate: --blowup %g: a blow-up factor must exceed 1 (0 checks finiteness only)\n", blowup);
    return 2;
  }
  if (model && npgc_check_model_and_data("simulate", model, data, "DATA/") != 0) return 1;
  const char *inputs[] = {prog_path, data, model, NULL};
  if (npgc_check_output("simulate", "-o", outdir, NPGC_OUT_DIR, inputs) != 0) return 1;
  NpgProgram *p = npg_compile(prog_path, &opt);
  int rc = 1;
  if (!npg_ok(p)) fputs(npg_error(p), stderr);
  else rc = simulate(p, data, model, steps, every, blowup, &nw, backend, progress, outdir);
  npg_free(p);
  return rc;
}
