/* tune.c — npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/: every class's
 * basis size chosen so that every output's mean relative error on VALID/ is
 * under T at the least reduced cost (issue 11; the search is tune_search in
 * backends/tune.c). Prints the candidates tried, writes the chosen model
 * and a PNG of error against cost. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "chart.h"
#include "compile.h"
#include "reduce.h"
#include "samples.h"

static int usage(void) {
  fputs("usage: npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/ [--max-cap N] [--center on|off] [--png FILE]\n"
        "                 [--cc]\n"
        "  chooses every class's basis size so that every output's mean relative L2 error on VALID/\n"
        "  (held-out samples, the same params) is under T at the least reduced cost; writes the chosen\n"
        "  model to MODEL/ and the error against cost of every candidate to FILE (MODEL-tune.png).\n",
        stderr);
  return 2;
}

/* "m_x=3 m_y=8" */
static void print_sizes(const Program *prog, const TuneTrial *t, int nc) {
  for (int c = 0; c < nc; c++) printf("%s%s=%ld", c ? " " : "", ((BasisClass *)prog->classes.v[c])->size_name, t->m[c]);
}

static int draw(const TuneResult *r, double tol, const char *path, char *err, size_t errlen) {
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
  ChartSeries s[3] = {{"uniform caps", nu, ux, uy, -1, false},
                      {"candidates (big dot: chosen)", nt, x, y, mark, true},
                      {"tolerance", 2, tx, ty, -1, false}};
  Chart c = {"npgc tune: worst output's mean relative error against reduced cost", "reduced multiply-adds",
             "mean relative L2 error", true, true, 3, s};
  int rc = chart_png(&c, path, 960, 540, err, errlen);
  free(x);
  return rc;
}

int npgc_tune(int argc, char **argv) {
  const char *prog_path = NULL, *data = NULL, *valid = NULL, *out = NULL, *png = NULL;
  double tol = -1;
  int max_cap = 60;
  bool cc = false, uncentered = false;
  NpgOptions opt = {0};
  for (int i = 2; i < argc; i++) {
    const char *a = argv[i];
    bool has = i + 1 < argc, ok = true;
    char *end = NULL;
    if (strcmp(a, "-o") == 0 && has) out = argv[++i];
    else if (strcmp(a, "--png") == 0 && has) png = argv[++i];
    else if (strcmp(a, "--tol") == 0 && has) tol = strtod(argv[++i], &end), ok = *end == 0 && tol > 0;
    else if (strcmp(a, "--max-cap") == 0 && has) max_cap = (int)strtol(argv[++i], &end, 10), ok = *end == 0 && max_cap >= 1;
    else if (strcmp(a, "--center") == 0 && has) {
      uncentered = strcmp(argv[++i], "off") == 0;
      ok = uncentered || strcmp(argv[i], "on") == 0;
    } else if (strcmp(a, "--cc") == 0) cc = true;
    else if (strncmp(a, "--std=", 6) == 0) opt.std_dir = a + 6;
    else if (a[0] == '-') {
      fprintf(stderr, "npgc tune: unknown option '%s'\n", a);
      return usage();
    } else if (!prog_path) prog_path = a;
    else if (!data) data = a;
    else if (!valid) valid = a;
    else return usage();
    if (!ok) {
      fprintf(stderr, "npgc tune: bad value for %s: '%s'\n", a, argv[i]);
      return 2;
    }
  }
  if (!prog_path || !data || !valid || !out || tol < 0) return usage();
  char pngbuf[4096], err[2048] = "";
  if (!png) { /* beside MODEL/, which holds only what a model store writes */
    size_t n = strlen(out);
    while (n > 1 && out[n - 1] == '/') n--;
    snprintf(pngbuf, sizeof pngbuf, "%.*s-tune.png", (int)n, out);
    png = pngbuf;
  }
  NpgProgram *p = npg_compile(prog_path, &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  Program *prog = npg_program_ir(p);
  int rc = 1;
  SampleSet ds = {0}, vs = {0};
  TrainSet *ts = NULL;
  TuneResult r = {0};
  Model *m = NULL;
  char *hashes = NULL;
  NpgFull *f = npg_full_new(p, cc ? NPG_CC : NPG_TCC);
  if (npg_full_error(f)[0] || npg_full_bind_params(f, data) != 0) {
    fprintf(stderr, "error: %s\n", npg_full_error(f));
    goto done;
  }
  if (samples_open(&ds, prog, data, NULL, true, err, sizeof err) != 0 ||
      samples_open(&vs, prog, valid, NULL, true, err, sizeof err) != 0 ||
      !(hashes = samples_param_hashes(prog, data, err, sizeof err)) ||
      samples_check_params(prog, valid, hashes, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err[0] ? err : "out of memory");
    goto done;
  }
  SampleSource dsrc = {ds.count, &ds, samples_set}, vsrc = {vs.count, &vs, samples_set};
  TrainOptions topt = {.cap = max_cap, .energy = 1.0, .uncentered = uncentered, .progress = isatty(2)};
  if (!(ts = train_set_new(prog, f, &dsrc, &topt, err, sizeof err)) ||
      tune_search(ts, prog, f, &vsrc, tol, max_cap, isatty(2), &r, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  printf("tune %s: %d candidates (every class's cap; the basis sizes they give), worst output's mean relative L2 "
         "error on %ld samples of %s\n",
         prog_path, r.ntrials, vs.count, valid);
  printf("%5s %-8s %14s %12s  %s\n", "trial", "kind", "cost", "error", "sizes");
  for (int t = 0; t < r.ntrials; t++) {
    const TuneTrial *tr = &r.trials[t];
    printf("%5d %-8s %14.6g %12.3e  ", t + 1, tr->uniform ? "uniform" : "class", tr->cost, tr->err);
    print_sizes(prog, tr, r.nclasses);
    printf("%s%s\n", tr->err <= tol ? "  meets" : "", t == r.chosen ? "  <- chosen" : "");
  }
  if (draw(&r, tol, png, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  if (r.chosen < 0) {
    const BasisClass *bc = prog->classes.v[r.limiting];
    printf("--tol %.3g cannot be met: the smallest error reached is %.3e with every cap at its largest (%d).\n"
           "class %s limits it: its projection floor on %s is %.3e, and %s\n",
           tol, r.trials[r.ntrials - 1].err, max_cap, bc->size_name, valid, r.limiting_floor,
           r.limiting_saturated ? "its members have no more directions in the training samples: train with more, "
                                  "or more varied, samples"
                                : "its members are at --max-cap: raise it");
    printf("error against cost -> %s; no model written\n", png);
    goto done;
  }
  if (!(m = train_set_model(ts, r.best_cap, err, sizeof err))) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  m->param_hashes = hashes;
  hashes = NULL;
  if (model_save(m, out, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  const TuneTrial *ch = &r.trials[r.chosen];
  printf("chosen: cost %.6g, error %.3e (--tol %.3g): ", ch->cost, ch->err, tol);
  print_sizes(prog, ch, r.nclasses);
  printf(" -> %s; error against cost -> %s\n", out, png);
  rc = 0;
done:
  model_free(m);
  free(hashes);
  tune_result_free(&r);
  train_set_free(ts);
  samples_close(&ds);
  samples_close(&vs);
  npg_full_free(f);
  npg_free(p);
  return rc;
}
