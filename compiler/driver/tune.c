/* tune.c — npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/: every class's
 * basis size chosen so that every output's mean relative error on VALID/ is
 * under T at the least reduced cost (issue 11; the search is tune_search in
 * backends/train/tune.c). Prints the candidates tried, writes the chosen model
 * and a PNG of error against cost. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "chart.h"
#include "npg.h"
#include "npgc.h"

/* "m_x=3 m_y=8" */
static void print_sizes(const NpgTuneReport *r, const NpgTuneTrial *t) {
  for (int c = 0; c < r->nclasses; c++) printf("%s%s=%ld", c ? " " : "", r->class_name[c], t->m[c]);
}

static int draw(const NpgTuneReport *r, double tol, const char *path, char *err, size_t errlen) {
  double *x = malloc(sizeof(double) * (size_t)(r->ntrials + 1) * 4), *y = x ? x + r->ntrials + 1 : NULL;
  double *ux = y ? y + r->ntrials + 1 : NULL, *uy = ux ? ux + r->ntrials + 1 : NULL;
  if (!x) {
    snprintf(err, errlen, "out of memory");
    return -1;
  }
  int nu = 0, nt = 0, mark = -1;
  for (int t = 0; t < r->ntrials; t++) {
    if (r->trials[t].uniform) ux[nu] = r->trials[t].cost, uy[nu++] = r->trials[t].err;
    if (t == r->chosen) mark = nt;
    x[nt] = r->trials[t].cost, y[nt++] = r->trials[t].err;
  }
  double tx[2] = {INFINITY, -INFINITY}, ty[2] = {tol, tol};
  for (int t = 0; t < nt; t++) tx[0] = fmin(tx[0], x[t]), tx[1] = fmax(tx[1], x[t]);
  ChartSeries s[3] = {{"uniform caps", nu, ux, uy, -1, false, false},
                      {"candidates (big dot: chosen)", nt, x, y, mark, true, false},
                      {"tolerance", 2, tx, ty, -1, false, false}};
  Chart c = {.title = "npgc tune: worst output's mean relative error against reduced cost",
             .xlabel = "reduced multiply-adds", .ylabel = "mean relative L2 error", .logx = true, .logy = true,
             .nseries = 3, .series = s};
  int rc = -1;
  if (npgc_make_parents(path, false) != 0) /* every writer of npgc creates the parents, as -o does */
    snprintf(err, errlen, "%.1000s: no folder to write it in", path);
  else {
    rc = chart_png(&c, path, 960, 540, err, errlen);
    chart_cleanup(); /* a command draws once: cairo's and fontconfig's caches released */
  }
  free(x);
  return rc;
}

static int tune(int argc, char **argv, NpgTrainOptions *topt);

/* --steps T --every K (DESIGN §15): the training samples are the states DATA/'s full rollouts
 * visit, every K-th step, each with its trajectory's held inputs; the validation samples are
 * VALID/'s initial states, each judged by its rollout (NpgTrainOptions.rollout_steps). */
typedef struct Visited {
  Trajectories tr;
  long saves, every;
  double **state;           /* per input of tr that is a state: trajectories x saves x its entries */
  NpgFull *f;               /* the rollouts' evaluator, while they run */
  long k;                   /* the trajectory running */
} Visited;

static void visited_free(Visited *v) {
  for (int i = 0; v->state && i < v->tr.n; i++) free(v->state[i]);
  free(v->state);
  npgc_trajectories_free(&v->tr);
}

static int visit_save(void *user, long step) {
  Visited *v = user;
  for (int i = 0; i < v->tr.n; i++) {
    const TrajInput *in = &v->tr.in[i];
    size_t n = 0;
    const double *u = in->sym.next ? npg_full_get(v->f, in->sym.name, &n) : NULL;
    if (in->sym.next && (!u || n != in->each)) return -1;
    if (u) memcpy(v->state[i] + ((size_t)v->k * (size_t)v->saves + (size_t)(step / v->every)) * n, u, sizeof(double) * n);
  }
  return 0;
}

/* DIR's trajectories run by the full step (inputs held: per-step inputs are refused), their
 * visited states kept. 0, or -1 after the message. */
static int visit(NpgProgram *p, NpgFull *f, const char *dir, long steps, long every, Visited *v) {
  char err[4400];
  memset(v, 0, sizeof *v);
  if (npgc_trajectories_open(p, dir, steps, &v->tr, err, sizeof err) != 0) return npgc_error(err), -1;
  v->every = every, v->saves = steps / every + 1, v->f = f;
  if (!(v->state = calloc((size_t)v->tr.n + 1, sizeof *v->state))) return fputs("npgc tune: out of memory\n", stderr), -1;
  for (int i = 0; i < v->tr.n; i++) {
    const TrajInput *in = &v->tr.in[i];
    if (in->per_step) {
      fprintf(stderr, "error: %s: npgc tune --steps holds every input for a trajectory; '%s' is given per step\n",
              in->path, in->sym.name);
      return -1;
    }
    if (in->sym.next && !(v->state[i] = malloc(sizeof(double) * ((size_t)v->tr.samples * (size_t)v->saves * in->each + 1))))
      return fputs("npgc tune: out of memory\n", stderr), -1;
  }
  NpgRollout ro = {.steps = steps, .every = every, .at_save = visit_save, .user = v};
  for (v->k = 0; v->k < v->tr.samples; v->k++)
    if (npgc_trajectories_set_full(&v->tr, f, v->k, 0, true) != 0 || npg_full_simulate(f, v->k, &ro) != 0) {
      snprintf(err, sizeof err, "%s, trajectory %ld: %s", dir, v->k, npg_full_error(f));
      return npgc_error(err), -1;
    }
  return 0;
}

/* Training sample k: trajectory k / saves at its (k % saves)-th saved step (an NpgSampleFn). */
static int visited_set(void *user, NpgFull *f, long k) {
  Visited *v = user;
  long j = k / v->saves, s = k % v->saves;
  if (npgc_trajectories_set_full(&v->tr, f, j, 0, true) != 0) return -1;
  for (int i = 0; i < v->tr.n; i++) {
    const TrajInput *in = &v->tr.in[i];
    if (!in->sym.next) continue;
    char from[64];
    snprintf(from, sizeof from, "trajectory %ld, step %ld", j, s * v->every);
    if (npg_full_set(f, in->sym.name, in->axes, in->shape + (in->ndim - in->axes),
                     v->state[i] + ((size_t)j * (size_t)v->saves + (size_t)s) * in->each, from) != 0)
      return -1;
  }
  return 0;
}

/* Validation sample k: trajectory k's initial states and inputs. */
static int initial_set(void *user, NpgFull *f, long k) {
  return npgc_trajectories_set_full(&((Visited *)user)->tr, f, k, 0, true);
}

/* Issue 30: the bases the model does not keep, as npgc train says it. */
static void print_streamed(const NpgModel *m) {
  double bytes = 0;
  bool any = false;
  for (int c = 0; c < npg_model_nclasses(m); c++) {
    NpgClassInfo ci;
    if (npg_model_class(m, c, &ci) != 0 || npg_model_basis(m, c)) continue;
    printf("%s%s", any ? " " : "streamed bases, used in training and not kept: ", ci.label);
    bytes += 8.0 * (double)ci.n * (double)ci.m, any = true;
  }
  if (any) printf(" (%.3f MB; --keep-bases all keeps them)\n", bytes / 1e6);
}

int npgc_tune(int argc, char **argv) {
  NpgTrainOptions topt;
  npg_train_options_default(&topt);
  topt.words = NPG_WORDS_NPGC; /* training's messages name npgc's flags */
  int rc = tune(argc, argv, &topt);
  npgc_free_reduce(&topt); /* the --reduce names */
  return rc;
}

/* MODEL-tune.png beside MODEL/, which holds only what a model store writes. */
static const char *beside(const char *out, char *buf, size_t len) {
  size_t n = strlen(out);
  while (n > 1 && out[n - 1] == '/') n--;
  snprintf(buf, len, "%.*s-tune.png", (int)n, out);
  return buf;
}

/* The candidates tried, one line each. */
static void print_trials(const NpgTuneReport *r, double tol) {
  printf("%5s %-8s %14s %12s  %s\n", "trial", "kind", "cost", "error", "sizes");
  for (int t = 0; t < r->ntrials; t++) {
    const NpgTuneTrial *tr = &r->trials[t];
    printf("%5d %-8s %14.6g %12.3e  ", t + 1, tr->uniform ? "uniform" : "class", tr->cost, tr->err);
    print_sizes(r, tr);
    if (tr->interpolated[0]) printf("  interpolated: %s", tr->interpolated); /* DESIGN §12: chosen at these sizes */
    printf("%s%s\n", tr->err <= tol ? "  meets" : "", t == r->chosen ? "  <- chosen" : "");
  }
}

/* Why `tol` cannot be met: the class whose floor limits, or the reduction of a stage. */
static void print_unmet(const NpgTuneReport *r, double tol, long max_cap, const char *valid, const char *png) {
  const NpgTuneTrial *last = &r->trials[r->ntrials - 1];
  printf("--tol %.3g cannot be met: the smallest error reached is %.3e with every cap at its largest (%ld).\n"
         "class %s limits it: its projection floor on %s is %.3e, and %s\n",
         tol, last->err, max_cap, r->limiting, valid, r->limiting_floor,
         r->limiting_saturated ? "its members have no more directions in the training samples: train with more, "
                                 "or more varied, samples"
                               : "its members are at --max-cap: raise it");
  if (last->err > 2 * r->limiting_floor && last->interpolated[0]) /* DESIGN §12 */
    printf("the error reached is %.1fx that floor: the reduction of a stage, not a basis, limits it; %s %s "
           "interpolated there: more entries may help (a larger --interp-oversample)\n",
           last->err / r->limiting_floor, strchr(last->interpolated, ',') ? "stages" : "stage", last->interpolated);
  else if (last->err > 2 * r->limiting_floor)
    printf("the error reached is %.1fx that floor: the reduction of a stage, not a basis, limits it (every stage "
           "npgc check marks eligible for interpolation was measured interpolated too, unless --reduce named it)\n",
           last->err / r->limiting_floor);
  printf("error against cost -> %s; no model written\n", png);
}

static int tune(int argc, char **argv, NpgTrainOptions *to) {
  const char *prog_path = NULL, *data = NULL, *valid = NULL, *out = NULL, *png = NULL;
  double tol = -1;
  long max_cap = 60, steps = -1, every = 1;
  NpgBackend backend = NPG_AUTO;
  NpgOptions opt = {0};
  NpgTrainOptions topt = *to;
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npgc tune");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage("tune", true);
    if ((v = npg_args_string(&a, "-o"))) out = v;
    else if ((v = npg_args_string(&a, "--png"))) png = v;
    else if (npg_args_double(&a, "--tol", 0, INFINITY, true, &tol)) ;
    else if (npg_args_long(&a, "--max-cap", 1, 100000, &max_cap)) ;
    else if (npg_args_long(&a, "--steps", 1, 1000000000L, &steps)) ;
    else if (npg_args_long(&a, "--every", 1, 1000000000L, &every)) ;
    else if ((v = npg_args_string(&a, "--center"))) {
      topt.uncentered = strcmp(v, "off") == 0;
      if (!topt.uncentered && strcmp(v, "on") != 0)
        snprintf(a.error, sizeof a.error, "npgc tune: --center is on or off, not '%s'", v);
    } else if ((v = npg_args_string(&a, "--reduce"))) {
      if (!npgc_parse_reduce(&topt, v))
        snprintf(a.error, sizeof a.error, "npgc tune: --reduce %s: expected STAGE:interp or STAGE:galerkin", v);
    } else if (npg_args_double(&a, "--interp-oversample", 1, 1000, false, &topt.interp_oversample)) ;
    else if ((v = npg_args_string(&a, "--keep-bases"))) {
      if (!*v) snprintf(a.error, sizeof a.error, "npgc tune: --keep-bases: give quantities or classes (m_x), or all");
      topt.keep_bases = v;
    } else if (npg_args_backend(&a, &backend)) ;
    else if ((v = npg_args_string(&a, "--std"))) opt.std_dir = v;
    else if ((v = npg_args_positional(&a))) {
      if (!prog_path) prog_path = v;
      else if (!data) data = v;
      else if (!valid) valid = v;
      else npgc_args_extra(&a, "folder", valid);
    } else if (strncmp(a.argv[a.i], "--valid", 7) == 0 && strcspn(a.argv[a.i], "=") == 7) /* as npgc train has it */
      snprintf(a.error, sizeof a.error, "npgc tune: --valid is npgc train's; tune validates on the samples of its "
                                        "third argument, VALID/ (npgc tune PROG.npg DATA/ VALID/ ...)");
    else npg_args_unknown(&a);
  }
  *to = topt; /* the --reduce lists, to be freed */
  if (a.error[0]) return npgc_args_error(&a, "tune");
  if (!prog_path) return npgc_missing("tune", "the program (PROG.npg)");
  if (!data) return npgc_missing("tune", "DATA/ (the training samples)");
  if (!valid) return npgc_missing("tune", "VALID/ (held-out samples the error is measured on)");
  if (tol < 0) return npgc_missing("tune", "--tol T (the error to meet)");
  if (every != 1 && steps < 0) {
    fprintf(stderr, "npgc tune: --every %ld saves every K-th step of a rollout: give --steps T too\n", every);
    return 2;
  }
  if (!out) return npgc_missing("tune", "-o MODEL/ (where to write the chosen model)");
  topt.progress = isatty(2);
  char pngbuf[4096], err[2048] = "";
  if (!png) png = beside(out, pngbuf, sizeof pngbuf);
  const char *inputs[] = {prog_path, data, valid, NULL}, *png_inputs[] = {prog_path, data, valid, out, NULL};
  if (npgc_check_output("tune", "-o", out, NPGC_OUT_MODEL, inputs) != 0 ||
      npgc_check_output("tune", "--png", png, NPGC_OUT_FILE, png_inputs) != 0)
    return 1;
  /* Both outputs are checked before either is written: the chart drawn first
   * into the model folder would leave a file there when the model is refused. */
  if (npgc_under(png, out)) {
    fprintf(stderr, "npgc tune: --png %s lies in the model folder -o %s: refusing to write there (a model folder "
                    "holds only the model's files)\n", png, out);
    return 1;
  }
  NpgProgram *p = npg_compile(prog_path, &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  int rc = 1;
  NpgSamples *ds = NULL, *vs = NULL;
  Visited dv = {0}, vv = {0};
  NpgTuneReport r = {0};
  NpgModel *m = NULL;
  NpgFull *f = npg_full_new(p, backend);
  if (npg_full_error(f)[0] || npg_full_bind_params(f, data) != 0) {
    npgc_error(npg_full_error(f));
    goto done;
  }
  long nvalid;
  if (steps > 0) { /* DESIGN §15: trained on visited states, judged by rollouts */
    if (npg_full_check_params_dir(f, valid, err, sizeof err) != 0) {
      npgc_error(err);
      goto done;
    }
    if (visit(p, f, data, steps, every, &dv) != 0 || visit(p, f, valid, 0, 1, &vv) != 0) goto done;
    topt.rollout_steps = steps, topt.rollout_every = every;
    nvalid = vv.tr.samples;
    m = npg_tune(f, dv.tr.samples * dv.saves, visited_set, &dv, nvalid, initial_set, &vv, tol, (int)max_cap, &topt, &r);
  } else {
    if (!(ds = npg_samples_open(p, data, NULL, true, err, sizeof err)) ||
        !(vs = npg_samples_open(p, valid, NULL, true, err, sizeof err)) ||
        npg_full_check_params_dir(f, valid, err, sizeof err) != 0) {
      npgc_error(err[0] ? err : "out of memory");
      goto done;
    }
    nvalid = npg_samples_count(vs);
    m = npg_tune(f, npg_samples_count(ds), npg_samples_set, ds, nvalid, npg_samples_set, vs, tol, (int)max_cap, &topt,
                 &r);
  }
  if (!m && r.error[0]) {
    npgc_error(r.error);
    goto done;
  }
  if (steps > 0)
    printf("tune %s: %d candidates (every class's cap; the basis sizes they give), worst state's trajectory error "
           "over %ld-step rollouts from %ld initial states of %s\n", prog_path, r.ntrials, steps, nvalid, valid);
  else
    printf("tune %s: %d candidates (every class's cap; the basis sizes they give), worst output's mean relative L2 "
           "error on %ld samples of %s\n", prog_path, r.ntrials, nvalid, valid);
  print_trials(&r, tol);
  char tmp[4096];
  npgc_tmp_path(tmp, sizeof tmp, png);
  if (npgc_commit("tune", tmp, png, draw(&r, tol, tmp, err, sizeof err)) != 0) {
    if (err[0]) npgc_error(err);
    goto done;
  }
  if (!m) {
    print_unmet(&r, tol, max_cap, valid, png);
    goto done;
  }
  if (npgc_make_parents(out, false) != 0 || npg_model_save(m, out) != 0) {
    if (npg_model_error(m)[0]) npgc_error(npg_model_error(m));
    goto done;
  }
  const NpgTuneTrial *ch = &r.trials[r.chosen];
  printf("chosen: cost %.6g, error %.3e (--tol %.3g): ", ch->cost, ch->err, tol);
  print_sizes(&r, ch);
  if (ch->interpolated[0]) printf(", interpolated: %s", ch->interpolated);
  printf(" -> %s; error against cost -> %s\n", out, png);
  npg_model_report_reductions(m, stdout); /* DESIGN §12: how each eligible stage is reduced at these sizes, and why */
  print_streamed(m);
  rc = 0;
done:
  npg_model_free(m);
  npg_tune_free(&r);
  npg_samples_free(ds);
  npg_samples_free(vs);
  visited_free(&dv);
  visited_free(&vv);
  npg_full_free(f);
  npg_free(p);
  return rc;
}
