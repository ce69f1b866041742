/* reduce_use.c — the commands that use a reduced model (reduce_cmds.h):
 *
 *   npgc eval   PROG.npg MODEL/ IN/ -o OUT/  (reduced: coordinates and lifted outputs)
 *   npgc verify PROG.npg MODEL/ TEST/        (DESIGN §7: the auto-check)
 *   npgc bench  PROG.npg MODEL/ TEST/        (full vs reduced time, memory)
 *
 * over one Session: the program, the model, its reduced evaluator, the
 * samples and (verify, bench) the full evaluator. A client of npg.h only. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "npg.h"
#include "npgc.h"
#include "reduce_cmds.h"

/* ---------------------------------------------------------------- shared by eval, verify, bench */

typedef struct Session {
  NpgProgram *p;
  NpgModel *m;
  NpgReduced *r;
  NpgSamples *s;
  NpgFull *f;               /* only verify and bench */
  int nsym;
  NpgSymbol *sym;           /* every symbol of the program */
} Session;


static void close_session(Session *x) {
  npg_reduced_free(x->r);
  npg_model_free(x->m);
  npg_samples_free(x->s);
  npg_full_free(x->f);
  free(x->sym);
  npg_free(x->p);
}

/* Compile, load MODEL/ (c->a), open the samples of c->b; with `full`, a
 * full evaluator bound to c->b's params, which must be the model's. */
static int open_session(Common *c, Session *x, bool full) {
  memset(x, 0, sizeof *x);
  char err[2048] = "";
  if (!(x->p = reduce_compile(c))) return -1;
  x->nsym = npg_nsymbols(x->p);
  if (!(x->sym = calloc((size_t)x->nsym + 1, sizeof *x->sym))) {
    fputs("error: out of memory\n", stderr);
    return -1;
  }
  for (int i = 0; i < x->nsym; i++) npg_symbol(x->p, i, &x->sym[i]);
  if (npgc_check_model_and_data(c->cmd, c->a, c->b, strcmp(c->cmd, "eval") ? "TEST/" : "IN/") != 0) return -1;
  x->m = npg_model_load(x->p, c->a);
  if (npg_model_error(x->m)[0]) {
    npgc_error(npg_model_error(x->m));
    return -1;
  }
  if (c->sizes) { /* the model at smaller sizes: the leading blocks of its bases and tensors */
    NpgModel *cut = npg_model_at_sizes(x->m, c->sizes);
    npg_model_free(x->m);
    x->m = cut;
    if (!cut || npg_model_error(cut)[0]) {
      npgc_error(cut ? npg_model_error(cut) : "out of memory");
      return -1;
    }
  }
  x->r = npg_reduced_new(x->m);
  npg_reduced_exact_roots(x->r, c->exact_roots);
  if (npg_reduced_error(x->r)[0]) {
    npgc_error(npg_reduced_error(x->r));
    return -1;
  }
  /* a full evaluation needs the extern values of the data; a reduced one learns them */
  if (!(x->s = npg_samples_open(x->p, c->b, NULL, full, err, sizeof err))) {
    npgc_error(err);
    return -1;
  }
  if (!full && npg_model_check_params_dir(x->m, c->b, err, sizeof err) != 0) {
    npgc_error(err);
    return -1;
  }
  if (full) {
    x->f = npg_full_new(x->p, c->backend);
    const char *params = c->params ? c->params : c->b;
    if (npg_full_error(x->f)[0] || npg_full_bind_params(x->f, params) != 0) {
      npgc_error(npg_full_error(x->f));
      if (!c->params)
        fprintf(stderr, "(npgc %s reads the params from %s, the TEST/ folder, beside its samples; --params DIR reads "
                        "them from another folder, such as the training data's)\n", c->cmd, c->b);
      return -1;
    }
    if (npg_model_check_params(x->m, x->f, err, sizeof err) != 0) {
      npgc_error(err);
      return -1;
    }
  }
  if (npg_samples_count(x->s) < 1) {
    fprintf(stderr, "error: %s: no samples (the first axis of its inputs is 0)\n", c->b);
    return -1;
  }
  /* the inputs' shapes, and so their sizes, must be the model's */
  if (npg_samples_check_model(x->s, x->m, err, sizeof err) != 0) {
    npgc_error(err);
    return -1;
  }
  for (int i = 0; i < x->nsym; i++) {
    if (x->sym[i].kind != NPG_INPUT) continue;
    size_t n = 0;
    NpgClassInfo ci;
    npg_samples_get(x->s, x->sym[i].name, 0, &n);
    npg_model_class(x->m, npg_model_class_of(x->m, x->sym[i].name), &ci);
    if ((long)n != ci.n) {
      fprintf(stderr, "error: %s/%s.npy: '%s' has %zu entries per sample, the model was trained with %ld\n", c->b,
              x->sym[i].name, x->sym[i].name, n, ci.n);
      return -1;
    }
  }
  return 0;
}

/* Project the inputs of sample k and evaluate the reduced model. */
/* Sample k's inputs projected onto their bases (npg_reduced_set). */
static int project_inputs(Session *x, long k) {
  for (int i = 0; i < x->nsym; i++) {
    if (x->sym[i].kind != NPG_INPUT) continue;
    size_t n;
    const double *v = npg_samples_get(x->s, x->sym[i].name, k, &n);
    if (npg_reduced_set(x->r, x->sym[i].name, n, v) != 0) return -1;
  }
  return 0;
}

static int reduced_sample(Session *x, long k) {
  if (project_inputs(x, k) != 0) return -1;
  return npg_reduced_eval(x->r, k);
}

/* ---------------------------------------------------------------- eval (reduced) */

/* One output over every sample: lifted values and reduced coordinates, or
 * an operator's reduced matrices. */
typedef struct Out {
  const NpgSymbol *sym;
  long n, m;                /* full size and coordinates (an op: rows x cols in m) */
  long rows, cols;
  double *lifted, *coords;
  double *est;              /* per sample: the online estimate (absolute 2-norm or product norm; NaN: none) */
  unsigned *flags;          /* and its NPG_EST_ bits */
} Out;

static int write_outputs(const Common *c, const Session *x, const Out *outs, int nout, long S) {
  if (npgc_make_parents(c->out, true) != 0) return -1;
  for (int o = 0; o < nout; o++) {
    const Out *u = &outs[o];
    char path[4096], err[2048];
    long shape[16];
    int nd = 0;
    shape[nd++] = S;
    if (u->sym->kind != NPG_OP) {
      for (int i = 0; i < u->sym->ndims; i++) shape[nd++] = npg_model_dim(x->m, u->sym->dims[i]);
      for (int i = 0; i < u->sym->nstatic; i++) shape[nd++] = u->sym->shape[i];
      snprintf(path, sizeof path, "%s/%s.npy", c->out, u->sym->name);
      if (npg_npy_write(path, nd, shape, u->lifted, err, sizeof err) != 0) goto fail;
      long cs[2] = {S, u->m};
      snprintf(path, sizeof path, "%s/%s.reduced.npy", c->out, u->sym->name);
      if (npg_npy_write(path, 2, cs, u->coords, err, sizeof err) != 0) goto fail;
      snprintf(path, sizeof path, "%s/%s.estimate.npy", c->out, u->sym->name);
      if (npg_npy_write(path, 1, cs, u->est, err, sizeof err) != 0) goto fail;
    } else {
      long os[3] = {S, u->rows, u->cols};
      snprintf(path, sizeof path, "%s/%s.reduced.npy", c->out, u->sym->name);
      if (npg_npy_write(path, 3, os, u->coords, err, sizeof err) != 0) goto fail;
    }
    continue;
  fail:
    npgc_error(err);
    return -1;
  }
  return 0;
}

/* Output o of sample k into its arrays. */
static int keep_output(Session *x, Out *u, long k) {
  if (u->sym->kind == NPG_OP) {
    size_t cap = (size_t)u->m;
    return npg_reduced_op(x->r, u->sym->name, u->coords + k * u->m, cap, &u->rows, &u->cols, NULL, NULL);
  }
  size_t m;
  const double *v = npg_reduced_coords(x->r, u->sym->name, &m);
  memcpy(u->coords + k * u->m, v, sizeof(double) * m);
  if (npg_reduced_estimate(x->r, u->sym->name, &u->est[k], &u->flags[k]) != 0) return -1;
  /* one lift per sample, as npg_reduced_lift and Python's red.lift give it: the same bits (a
   * dgemm over all the samples, npg_reduced_lift_many, differs from it in the last bits) */
  return npg_reduced_lift(x->r, u->sym->name, u->lifted + k * u->n, (size_t)u->n);
}

/* The trust signal of sample k: a warning naming each input outside the training range. */
static int warn_outside(Session *x, long k) {
  for (int i = 0; i < x->nsym; i++) {
    long coord = 0;
    if (x->sym[i].kind != NPG_INPUT) continue;
    int out = npg_reduced_outside(x->r, x->sym[i].name, &coord);
    if (out < 0) return -1;
    if (out)
      fprintf(stderr, "warning: sample %ld: input '%s' lies outside the training range (its reduced coordinate %ld, "
              "beyond the training samples' by more than a tenth of their range): the reduced answer and its error "
              "estimate are extrapolations there\n", k, x->sym[i].name, coord);
  }
  return 0;
}

/* The estimates of every output, a row per sample (docs/estimates.md); why one has none, once. */
static void print_estimates(Session *x, const Out *outs, int nout, long S) {
  printf("%8s", "sample");
  for (int o = 0; o < nout; o++)
    if (outs[o].sym->kind != NPG_OP) printf(" %14s", outs[o].sym->name);
  printf("   (online error estimate, absolute, 2-norm or a class's product norm; b: a bound, e: an estimate, !: "
         "inputs outside the training range, r: at the roundoff level)\n");
  for (long k = 0; k < S; k++) {
    printf("%8ld", k);
    for (int o = 0; o < nout; o++) {
      const Out *u = &outs[o];
      if (u->sym->kind == NPG_OP) continue;
      unsigned f = u->flags[k];
      char cell[32];
      if (f & NPG_EST_NONE) snprintf(cell, sizeof cell, "n/a%s", f & NPG_EST_OUTSIDE ? " !" : "");
      else snprintf(cell, sizeof cell, "%.3e %s%s%s", u->est[k], f & NPG_EST_BOUND ? "b" : "e",
                    f & NPG_EST_OUTSIDE ? "!" : "", f & NPG_EST_ROUNDOFF ? "r" : "");
      printf(" %14s", cell);
    }
    printf("\n");
  }
  for (int o = 0; o < nout; o++)
    if (outs[o].sym->kind != NPG_OP && S > 0 && (outs[o].flags[S - 1] & NPG_EST_NONE))
      printf("%s has no estimate: %s\n", outs[o].sym->name, npg_reduced_estimate_why(x->r, outs[o].sym->name));
}

/* One eval --jacobian OUT:IN of the reduced evaluation: ∂OUT̂/∂IN̂ in coordinates at every sample. */
typedef struct RedJac {
  char out[256], in[256];
  long mo, mi;
  double *v;                /* S x mo x mi */
} RedJac;

/* "OUT:IN" checked against the model: OUT any quantity with coordinates, IN an input. 0, or -1
 * after a message naming the option. */
static int red_jac_parse(const Session *x, const char *spec, RedJac *j) {
  const char *colon = strchr(spec, ':');
  size_t lo = colon ? (size_t)(colon - spec) : 0;
  if (!colon || lo == 0 || !colon[1] || lo >= sizeof j->out || strlen(colon + 1) >= sizeof j->in) {
    fprintf(stderr, "npgc eval: --jacobian '%s': expected OUT:IN (a stage or output, then an input)\n", spec);
    return -1;
  }
  memcpy(j->out, spec, lo);
  j->out[lo] = 0;
  strcpy(j->in, colon + 1);
  bool in_ok = false;
  for (int i = 0; i < x->nsym; i++) in_ok = in_ok || (strcmp(x->sym[i].name, j->in) == 0 && x->sym[i].kind == NPG_INPUT);
  int co = npg_model_class_of(x->m, j->out), ci = npg_model_class_of(x->m, j->in);
  if (co < 0 || !in_ok || ci < 0) {
    if (co < 0) fprintf(stderr, "npgc eval: --jacobian '%s': '%s' is not a stage or input of the program\n", spec, j->out);
    else
      fprintf(stderr, "npgc eval: --jacobian '%s': '%s' is not an input of the program (derivatives are taken with "
              "respect to inputs)\n", spec, j->in);
    return -1;
  }
  NpgClassInfo a, b;
  npg_model_class(x->m, co, &a);
  npg_model_class(x->m, ci, &b);
  j->mo = a.m, j->mi = b.m;
  return 0;
}

static int red_jac_write(const Common *c, const RedJac *j, long S) {
  char path[4096], err[2048];
  long shape[3] = {S, j->mo, j->mi};
  if (snprintf(path, sizeof path, "%s/jacobian_%s_%s.reduced.npy", c->out, j->out, j->in) >= (int)sizeof path)
    snprintf(err, sizeof err, "%s: the path of jacobian_%s_%s.reduced.npy is too long", c->out, j->out, j->in);
  else if (npg_npy_write(path, 3, shape, j->v, err, sizeof err) == 0) return 0;
  npgc_error(err);
  return -1;
}

int cmd_eval_reduced(Common *c) {
  if (!c->prog_path || !c->a) return npgc_missing("eval", "MODEL/ (or --full DATA/)");
  if (!c->b) return npgc_missing("eval", "IN/ (the inputs to evaluate)");
  if (!c->out) return npgc_missing("eval", "-o OUT/ (where to write the outputs)");
  const char *inputs[] = {c->prog_path, c->a, c->b, NULL};
  if (npgc_check_output("eval", "-o", c->out, NPGC_OUT_DIR, inputs) != 0) return 1;
  Session x;
  int rc = 1, nout = 0;
  Out *outs = NULL;
  RedJac jacs[16];
  memset(jacs, 0, sizeof jacs);
  if (open_session(c, &x, false) != 0) goto done;
  long S = npg_samples_count(x.s);
  for (int j = 0; j < c->njacobian; j++) {
    if (red_jac_parse(&x, c->jacobian[j], &jacs[j]) != 0) {
      rc = 2;
      goto done;
    }
    if (!(jacs[j].v = malloc(sizeof(double) * (size_t)(S * jacs[j].mo * jacs[j].mi + 1)))) goto oom;
  }
  if (!(outs = calloc((size_t)x.nsym + 1, sizeof *outs))) goto oom;
  for (int i = 0; i < x.nsym; i++) {
    if (!x.sym[i].output) continue;
    Out *u = &outs[nout++];
    u->sym = &x.sym[i];
    NpgClassInfo ci;
    if (u->sym->kind == NPG_OP) { /* rows x cols of the reduced operator: at most the largest class squared */
      for (int k = 0; k < npg_model_nclasses(x.m); k++)
        if (npg_model_class(x.m, k, &ci) == 0 && ci.m * ci.m > u->m) u->m = ci.m * ci.m;
    } else {
      npg_model_class(x.m, npg_model_class_of(x.m, u->sym->name), &ci);
      u->n = ci.n;
      u->m = ci.m;
    }
    u->lifted = malloc(sizeof(double) * (size_t)(u->n * S + 1));
    u->coords = malloc(sizeof(double) * (size_t)(u->m * S + 1));
    u->est = malloc(sizeof(double) * (size_t)(S + 1));
    u->flags = calloc((size_t)S + 1, sizeof(unsigned));
    if (!u->lifted || !u->coords || !u->est || !u->flags) goto oom;
  }
  for (long k = 0; k < S; k++) {
    if (reduced_sample(&x, k) != 0 || warn_outside(&x, k) != 0) goto failed;
    for (int o = 0; o < nout; o++)
      if (keep_output(&x, &outs[o], k) != 0) goto failed;
    for (int j = 0; j < c->njacobian; j++) /* after the outputs are kept: it evaluates again */
      if (npg_reduced_jacobian(x.r, k, jacs[j].out, jacs[j].in, jacs[j].v + k * jacs[j].mo * jacs[j].mi) != 0)
        goto failed;
    npg_progress(c->train.progress && S > 1, "reduced evaluation", k + 1, S);
  }
  print_estimates(&x, outs, nout, S);
  /* an operator's matrices were kept at the largest stride: pack them */
  for (int o = 0; o < nout; o++) {
    Out *u = &outs[o];
    if (u->sym->kind != NPG_OP) continue;
    for (long k = 1; k < S; k++)
      memmove(u->coords + k * u->rows * u->cols, u->coords + k * u->m, sizeof(double) * (size_t)(u->rows * u->cols));
  }
  rc = write_outputs(c, &x, outs, nout, S) == 0 ? 0 : 1;
  for (int j = 0; j < c->njacobian && rc == 0 && S > 0; j++) rc = red_jac_write(c, &jacs[j], S) == 0 ? 0 : 1;
  goto done;
failed:
  npgc_error(npg_reduced_error(x.r));
  goto done;
oom:
  fputs("error: out of memory\n", stderr);
done:
  for (int o = 0; outs && o < nout; o++) {
    free(outs[o].lifted);
    free(outs[o].coords);
    free(outs[o].est);
    free(outs[o].flags);
  }
  free(outs);
  for (int j = 0; j < c->njacobian; j++) free(jacs[j].v);
  close_session(&x);
  return rc;
}

/* ---------------------------------------------------------------- verify */

/* The exactness checks of the design (npg_verify_exact): 0 pass, 1 fail or error. */
static int verify_exact(Common *c) {
  NpgProgram *p = reduce_compile(c);
  if (!p) return 1;
  char err[2048] = "";
  fflush(stdout);
  int rc = npg_verify_exact(p, c->exact_size, c->backend, c->train.progress, stdout, err, sizeof err);
  if (rc < 0)
    fprintf(stderr, "error: exactness checks of %s: %s%s\n", c->prog_path, err,
            strstr(err, "not finite") || strstr(err, "singular") || strstr(err, "indefinite")
                ? " (random data can be degenerate at small sizes, e.g. meshes with too few vertices: try a larger "
                  "--exact-size)"
                : "");
  npg_free(p);
  return rc == 0 ? 0 : 1;
}

/* The online estimate against the true error (absolute, 2-norm or a class's product norm; docs/estimates.md). */
static void print_verify_estimates(const NpgVerifyReport *rep, int wn) {
  /* each row starts "estimate", so that a row of the table above stays the only one naming a quantity first */
  printf("online estimate (absolute, 2-norm or a class's product norm, mean over samples; effectivity = estimate / "
         "true error, min..max)\n");
  printf("estimate %-*s %10s %10s %21s %s\n", wn, "quantity", "estimate", "true", "effectivity", "kind");
  for (int q = 0; q < rep->nrows; q++) {
    const NpgVerifyRow *e = &rep->rows[q];
    if (e->est_samples == 0) {
      printf("estimate %-*s %10s %10s %21s %s\n", wn, e->name, "n/a", "n/a", "n/a", "none (npgc eval says why)");
      continue;
    }
    char eff[48];
    if (isnan(e->eff_min)) snprintf(eff, sizeof eff, "n/a (no error)");
    else snprintf(eff, sizeof eff, "%.3g..%.3g", e->eff_min, e->eff_max);
    printf("estimate %-*s %10.3e %10.3e %21s %s%s\n", wn, e->name, e->est, e->err, eff,
           e->est_bound ? "bound" : "estimate", e->est_samples < rep->samples ? " (some samples had none)" : "");
  }
}

static void print_report(const Common *c, const NpgVerifyReport *rep) {
  printf("verify %s against %s on %ld held-out samples (relative errors, mean over samples)\n", c->prog_path, c->a,
         rep->samples);
  int wn = 8, wk = 4; /* columns as wide as their widest entry */
  for (int q = 0; q < rep->nrows; q++) {
    wn = (int)strlen(rep->rows[q].name) > wn ? (int)strlen(rep->rows[q].name) : wn;
    wk = (int)strlen(rep->rows[q].kind) > wk ? (int)strlen(rep->rows[q].kind) : wk;
  }
  printf("%-*s %-*s %5s %10s %10s %10s %10s %10s %10s\n", wn, "quantity", wk, "kind", "m", "L2 error", "floor", "own",
         "max L2", "Linf error", "Linf floor");
  int streamed = 0;
  for (int q = 0; q < rep->nrows; q++) {
    const NpgVerifyRow *e = &rep->rows[q];
    if (e->streamed) { /* no basis in the model: the floors training measured, no lifted error */
      char linf[32] = "n/a"; /* not measured out of core */
      if (!isnan(e->linf_floor)) snprintf(linf, sizeof linf, "%9.3e*", e->linf_floor);
      printf("%-*s %-*s %5ld %10s %9.3e* %10s %10s %10s %10s\n", wn, e->name, wk, e->kind, e->m, "n/a", e->floor,
             "n/a", "n/a", "n/a", linf);
      streamed++;
      continue;
    }
    printf("%-*s %-*s %5ld %10.3e %10.3e %10.3e %10.3e %10.3e %10.3e%s\n", wn, e->name, wk, e->kind, e->m, e->l2,
           e->floor, e->own, e->l2_max, e->linf, e->linf_floor, e->output ? "  (output)" : "");
  }
  if (streamed)
    printf("* %d quantit%s of streamed bases (not kept in the model, issue 30): floor from the training run (mean over "
           "the training samples), no lifted error; retrain with --keep-bases NAME (or all) to verify them here\n",
           streamed, streamed == 1 ? "y" : "ies");
  if (rep->grows_at)
    printf("error grows most at stage %s (+%.3e over the worst quantity it reads)\n", rep->grows_at, rep->growth);
  print_verify_estimates(rep, wn);
}

int cmd_verify(Common *c) {
  if (c->steps >= 0) return cmd_verify_steps(c);
  if (c->exact && c->prog_path && !c->a && !c->b && !c->out) return verify_exact(c);
  if (!c->prog_path) return npgc_missing("verify", "the program (PROG.npg)");
  if (!c->a) return npgc_missing("verify", "MODEL/ (a model trained by npgc train), or --exact");
  if (!c->b) return npgc_missing("verify", "TEST/ (held-out samples)");
  Session x;
  NpgVerifyReport rep;
  memset(&rep, 0, sizeof rep);
  int rc = 1;
  if (open_session(c, &x, true) != 0) goto done;
  if (npg_verify(x.m, x.f, npg_samples_count(x.s), npg_samples_set, x.s, c->train.progress, &rep) != 0) {
    npgc_error(rep.error);
    goto done;
  }
  print_report(c, &rep);
  npg_verify_warnings(x.m, &rep, c->tol, stdout);
  rc = 0;
  for (int q = 0; q < rep.nrows; q++)
    if (rep.rows[q].output && !(rep.rows[q].l2 <= c->tol && isfinite(rep.rows[q].linf))) { /* NaN never passes */
      printf("FAIL: output %s: mean relative L2 error %.3e above --tol %.3g\n", rep.rows[q].name, rep.rows[q].l2,
             c->tol);
      rc = 1;
    }
  if (rc == 0) printf("ok: every output within --tol %.3g\n", c->tol);
  if (c->exact) {
    printf("\n");
    rc |= verify_exact(c);
  }
done:
  npg_verify_free(&rep);
  close_session(&x);
  return rc;
}

/* ---------------------------------------------------------------- bench */

/* Lift every output that is not an operator (the caller's buffer `y`). */
static int lift_outputs(Session *x, double *y, size_t n) {
  for (int i = 0; i < x->nsym; i++)
    if (x->sym[i].output && x->sym[i].kind != NPG_OP) {
      NpgClassInfo ci;
      npg_model_class(x->m, npg_model_class_of(x->m, x->sym[i].name), &ci);
      if ((size_t)ci.n > n || npg_reduced_lift(x->r, x->sym[i].name, y, (size_t)ci.n) != 0) return -1;
    }
  return 0;
}

static int by_value(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

void npgc_quartiles(double *v, long n, double q[3]) {
  qsort(v, (size_t)n, sizeof *v, by_value);
  for (int k = 0; k < 3; k++) {
    double at = (double)(n - 1) * (k + 1) / 4; /* linear interpolation between order statistics */
    long i = (long)at;
    q[k] = i + 1 < n ? v[i] + (at - (double)i) * (v[i + 1] - v[i]) : v[n - 1];
  }
}

void npgc_print_jit(const NpgFull *f) {
  NpgJitInfo ji;
  if (npg_full_jit_info(f, &ji) != 0) return;
  const char *cache = ji.cache == 1 ? "loaded from the cache" : ji.cache == 0 ? "compiled, then cached"
                      : ji.cache == 2 ? "compiled again, the cached entry was damaged" : "not cached";
  printf("full evaluator: %s, %s in %.1f ms (%s)\n",
         ji.backend == NPG_CC ? "cc (the system compiler at -O3 -march=native)" : "libtcc",
         ji.cache == 1 ? "loaded" : "compiled", 1e3 * ji.compile_seconds, cache);
}

/* Every output's online estimate after an evaluation (npg_reduced_estimate: the first call computes
 * them all, the others read them), timed; *with the outputs that got a figure (not NaN). -1 on an
 * error (npg_reduced_error). */
static double time_estimates(Session *x, int *with) {
  double t0 = reduce_now(), e;
  unsigned flags;
  *with = 0;
  for (int i = 0; i < x->nsym; i++)
    if (x->sym[i].output && x->sym[i].kind != NPG_OP) {
      if (npg_reduced_estimate(x->r, x->sym[i].name, &e, &flags) != 0) return -1;
      *with += !(flags & NPG_EST_NONE);
    }
  return reduce_now() - t0;
}

/* The reduced evaluation with every output's estimate against the evaluation alone (docs/estimates.md):
 * `tes` the estimates' times, `ratio` per evaluation (alone + estimate) / alone; without any output's
 * figure, why the first has none. */
static void print_estimate_cost(Session *x, int with, double *tes, double *ratio, long timed) {
  if (!with) {
    for (int i = 0; i < x->nsym; i++)
      if (x->sym[i].output && x->sym[i].kind != NPG_OP) {
        printf("  + estimate        none: %s has no estimate (%s)\n", x->sym[i].name,
               npg_reduced_estimate_why(x->r, x->sym[i].name));
        return;
      }
    return;
  }
  double q[3], qs[3];
  npgc_quartiles(tes, timed, q);
  npgc_quartiles(ratio, timed, qs);
  printf("  reduced + estimate%12.3e s per sample [%.3e, %.3e], then every output's estimate (npg_reduced_estimate, "
         "%d of them with a figure): %.3gx [%.3gx, %.3gx] the reduced alone\n", q[1], q[0], q[2], with, qs[1], qs[0],
         qs[2]);
}

/* An error during the timed passes: the progress line is ended first. */
static void bench_error(const Common *c, const char *msg) {
  if (c->train.progress) fputc('\n', stderr);
  npgc_error(msg);
}

/* The reduced evaluation against its byte bound: its tensors read once at the read bandwidth
 * measured over as many bytes (one thread; a size that fits a cache measures that cache). */
static void print_byte_bound(size_t tensor_bytes, double reduced_alone) {
  double bw = npg_read_bandwidth(tensor_bytes, 0.2), bound = bw > 0 ? (double)tensor_bytes / (bw * 1e9) : 0;
  printf("byte bound          %12.3e s: the reduced tensors read once at %.3g GB/s (read bandwidth measured over as "
         "many bytes, one thread); reduced alone %.3gx the bound\n",
         bound, bw, bound > 0 ? reduced_alone / bound : 0);
}

int cmd_bench(Common *c) {
  npg_blas_threads(c->threads); /* one unless asked: a loaded machine's threads slow small GEMMs down */
  if (c->steps >= 0) return cmd_bench_steps(c);
  if (!c->prog_path) return npgc_missing("bench", "the program (PROG.npg)");
  if (!c->a) return npgc_missing("bench", "MODEL/ (a model trained by npgc train)");
  if (!c->b) return npgc_missing("bench", "TEST/ (the samples to time)");
  Session x;
  int rc = 1;
  double *y = NULL, *tf = NULL;
  if (open_session(c, &x, true) != 0) goto done;
  long S = npg_samples_count(x.s);
  size_t maxn = 1;
  for (int k = 0; k < npg_model_nclasses(x.m); k++) {
    NpgClassInfo ci;
    npg_model_class(x.m, k, &ci);
    maxn = (size_t)ci.n > maxn ? (size_t)ci.n : maxn;
  }
  long total = c->reps * S, shown = -1;
  /* per timed evaluation: full; reduced (projected and lifted); projection, the reduced evaluation alone
   * (coordinates in, coordinates out) and lifting; the ratios of full to the reduced with and without; the
   * reduced alone followed by every output's estimate, and its ratio to the reduced alone */
  if (!(y = malloc(sizeof(double) * maxn)) || !(tf = malloc(sizeof(double) * (size_t)(9 * total + 9)))) {
    fputs("error: out of memory\n", stderr);
    goto done;
  }
  double *tr = tf + total + 1, *tl = tr + total + 1, *ratio = tl + total + 1, *tp = ratio + total + 1,
         *te = tp + total + 1, *ratio_core = te + total + 1, *tes = ratio_core + total + 1, *ratio_est = tes + total + 1;
  long timed = 0;
  int with = 0; /* outputs with an estimate */
  for (long rep = 0; rep < c->reps; rep++)
    for (long k = 0; k < S; k++) {
      /* progress between timed evaluations, redrawn once per percent */
      long done = rep * S + k;
      if (done * 100 / total != shown) {
        shown = done * 100 / total;
        npg_progress(c->train.progress, "bench (full and reduced)", done, total);
      }
      if (npg_samples_set(x.s, x.f, k) != 0) {
        bench_error(c, npg_full_error(x.f));
        goto done;
      }
      double t0 = reduce_now();
      if (npg_full_eval(x.f, k) != 0) {
        bench_error(c, npg_full_error(x.f));
        goto done;
      }
      double t1 = reduce_now();
      if (project_inputs(&x, k) != 0) {
        bench_error(c, npg_reduced_error(x.r));
        goto done;
      }
      double t1p = reduce_now();
      if (npg_reduced_eval(x.r, k) != 0) {
        bench_error(c, npg_reduced_error(x.r));
        goto done;
      }
      double t2 = reduce_now();
      if (lift_outputs(&x, y, maxn) != 0) {
        bench_error(c, npg_reduced_error(x.r));
        goto done;
      }
      double t3 = reduce_now(), ts = time_estimates(&x, &with);
      if (ts < 0) {
        bench_error(c, npg_reduced_error(x.r));
        goto done;
      }
      if (rep == 0 && k == 0 && !(S == 1 && c->reps == 1)) continue; /* the first full evaluation also checks gathers */
      tf[timed] = t1 - t0;
      tr[timed] = t3 - t1;
      tl[timed] = t3 - t2;
      tp[timed] = t1p - t1;
      te[timed] = t2 - t1p;
      ratio[timed] = (t1 - t0) / fmax(t3 - t1, 1e-12);
      ratio_core[timed] = (t1 - t0) / fmax(t2 - t1p, 1e-12);
      tes[timed] = t2 - t1p + ts;
      ratio_est[timed] = tes[timed] / fmax(t2 - t1p, 1e-12);
      timed++;
    }
  npg_progress(c->train.progress, "bench (full and reduced)", total, total);
  size_t tb, bytes = npg_model_bytes(x.m, &tb);
  /* one statistic, the median (robust to the machine's other load, which the mean is not), with the quartiles
   * as its spread; the speedup is the median of the per-evaluation ratios, each full evaluation against the
   * reduced one that follows it */
  double qf[3], qr[3], ql[3], qs[3], qp[3], qe[3], qc[3];
  npgc_quartiles(tf, timed, qf);
  npgc_quartiles(tr, timed, qr);
  npgc_quartiles(tl, timed, ql);
  npgc_quartiles(ratio, timed, qs);
  npgc_quartiles(tp, timed, qp);
  npgc_quartiles(te, timed, qe);
  npgc_quartiles(ratio_core, timed, qc);
  printf("bench %s: %ld samples x %ld passes, %ld evaluations timed, %d BLAS thread%s; medians, quartiles in "
         "brackets\n", c->prog_path, S, c->reps, timed, c->threads, c->threads == 1 ? " (--threads N for more)" : "s");
  npgc_print_jit(x.f);
  printf("full evaluation     %12.3e s per sample [%.3e, %.3e]\n", qf[1], qf[0], qf[2]);
  printf("reduced evaluation  %12.3e s per sample [%.3e, %.3e], inputs projected and outputs lifted\n", qr[1], qr[0],
         qr[2]);
  printf("  projecting inputs %12.3e s per sample [%.3e, %.3e]\n", qp[1], qp[0], qp[2]);
  printf("  reduced alone     %12.3e s per sample [%.3e, %.3e], coordinates in, coordinates out\n", qe[1], qe[0],
         qe[2]);
  print_estimate_cost(&x, with, tes, ratio_est, timed);
  printf("  lifting outputs   %12.3e s per sample [%.3e, %.3e]\n", ql[1], ql[0], ql[2]);
  printf("speedup             %12.3gx [%.3gx, %.3gx] (full time / reduced time per evaluation%s)\n", qs[1], qs[0],
         qs[2], qs[1] < 1 ? ": below 1, the reduced evaluation is slower" : "");
  printf("  without projection and lift %.3gx [%.3gx, %.3gx]\n", qc[1], qc[0], qc[2]);
  printf("reduced model       %12.3f MB of reduced tensors, %.3f MB with bases and extern tables\n", (double)tb / 1e6,
         (double)bytes / 1e6);
  print_byte_bound(tb, qe[1]);
  rc = 0;
done:
  free(tf);
  free(y);
  close_session(&x);
  return rc;
}
