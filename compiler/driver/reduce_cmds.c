/* reduce_cmds.c — the commands that make and use reduced models, their
 * options and train (eval, verify and bench: reduce_use.c):
 *
 *   npgc train  PROG.npg DATA/ -o MODEL/     (DESIGN §5)
 *   npgc eval   PROG.npg MODEL/ IN/ -o OUT/  (reduced: coordinates and lifted outputs)
 *   npgc verify PROG.npg MODEL/ TEST/        (DESIGN §7: the auto-check)
 *   npgc bench  PROG.npg MODEL/ TEST/        (full vs reduced time, memory)
 *
 * A client of npg.h only: what these commands do, a C program can do. */
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "npg.h"
#include "npgc.h"
#include "reduce_cmds.h"


double reduce_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* --basis NAME:cap=N,energy=E,center=on|off,product=OP (npg_parse_basis_product; NAME checked
 * by training): one more override in `c`. 0, or -1 with the problem in `err`. */
static int add_basis(Common *c, const char *s, char *err, size_t errlen) {
  int k = c->nbasis;
  const char **names = realloc(c->basis_name, sizeof(char *) * (size_t)(k + 1));
  if (names) c->basis_name = names;
  int *caps = realloc(c->basis_cap, sizeof(int) * (size_t)(k + 1));
  if (caps) c->basis_cap = caps;
  double *energies = realloc(c->basis_energy, sizeof(double) * (size_t)(k + 1));
  if (energies) c->basis_energy = energies;
  int *centers = realloc(c->basis_center, sizeof(int) * (size_t)(k + 1));
  if (centers) c->basis_center = centers;
  const char **products = realloc(c->basis_product, sizeof(char *) * (size_t)(k + 1));
  if (products) c->basis_product = products;
  if (!names || !caps || !energies || !centers || !products) {
    snprintf(err, errlen, "out of memory");
    return -1;
  }
  char *name, *product;
  if (npg_parse_basis_product(s, &name, &c->basis_cap[k], &c->basis_energy[k], &c->basis_center[k], &product, err,
                              errlen) != 0)
    return -1;
  c->basis_name[k] = name;
  c->basis_product[k] = product;
  c->nbasis++;
  return 0;
}

/* Each command's options: an option of another command is named as such. */
static const char *const options_of[][2] = {
    {"train", "-o --cc --jit --progress --std --cap --energy --center --spectra --basis --merge --mem --mpi --reduce --valid "
              "--interp-oversample --keep-bases --weights --steps --every --greedy --tol --budget --absolute "
              "--newton-tol --newton-max-iter --newton-verbose"},
    {"eval", "-o --progress --std --exact-roots --full --cc --jit --sizes --jacobian"},
    {"verify", "--tol --cc --jit --exact --exact-size --progress --std --params --steps --every --png --sizes "
               "--newton-tol --newton-max-iter --newton-verbose"},
    {"bench", "--cc --jit --threads --reps --exact-roots --progress --std --params --steps --every --sizes "
              "--newton-tol --newton-max-iter --newton-verbose"},
};

/* Whether `opt` (up to '=') is in the space-separated `list`. */
static bool listed(const char *list, const char *opt) {
  size_t n = strcspn(opt, "=");
  for (const char *p = list; *p;) {
    size_t w = strcspn(p, " ");
    if (w == n && strncmp(p, opt, n) == 0) return true;
    p += w;
    while (*p == ' ') p++;
  }
  return false;
}

static void unknown_option(NpgArgs *a, const char *cmd) {
  const char *s = a->argv[a->i];
  char others[64] = "";
  for (size_t k = 0; k < sizeof options_of / sizeof options_of[0]; k++)
    if (strcmp(options_of[k][0], cmd) && listed(options_of[k][1], s))
      snprintf(others + strlen(others), sizeof others - strlen(others), "%s%s", others[0] ? " and " : "",
               options_of[k][0]);
  if (others[0])
    snprintf(a->error, sizeof a->error, "%s: %.*s is an option of npgc %s, not of npgc %s", a->prog,
             (int)strcspn(s, "="), s, others, cmd);
  else
    npg_args_unknown(a);
}

/* Whether argv[a->i] is `name` and an option of c->cmd. */
static bool mine(const Common *c, const NpgArgs *a, const char *name) {
  const char *s = a->argv[a->i];
  size_t n = strlen(name);
  if (strncmp(s, name, n) != 0 || (s[n] && s[n] != '=')) return false;
  for (size_t k = 0; k < sizeof options_of / sizeof options_of[0]; k++)
    if (!strcmp(options_of[k][0], c->cmd)) return listed(options_of[k][1], name);
  return false;
}

static int parse(Common *c, int argc, char **argv) {
  memset(c, 0, sizeof *c);
  c->cmd = argv[1];
  c->tol = 1e-2;
  c->reps = 3;
  c->steps = -1;
  c->newton = (NpgcNewton)NPGC_NEWTON_DEFAULT;
  c->every = 1;
  c->backend = NPG_AUTO;
  c->threads = 1;
  npg_train_options_default(&c->train);
  c->train.words = NPG_WORDS_NPGC; /* training's messages name npgc's flags */
  char prog[64], err[400];
  snprintf(prog, sizeof prog, "npgc %s", c->cmd);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, prog);
  while (npg_args_next(&a)) {
    const char *v;
    long cap;
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage(c->cmd, true) - 1; /* -1: done */
    if ((v = npg_args_positional(&a))) {
      if (!c->prog_path) c->prog_path = v;
      else if (!c->a) c->a = v;
      else if (!c->b) c->b = v;
      else npgc_args_extra(&a, "folder", c->b);
    } else if (!mine(c, &a, argv[a.i])) {
      unknown_option(&a, c->cmd);
    } else if ((v = npg_args_string(&a, "-o"))) c->out = v;
    else if (npg_args_backend(&a, &c->backend)) ;
    else if (npg_args_int(&a, "--threads", 1, 1024, &c->threads)) ;
    else if (npg_args_flag(&a, "--full")) ; /* eval.c took it */
    else if (npg_args_flag(&a, "--progress")) c->progress = true;
    else if (npg_args_flag(&a, "--exact")) c->exact = true;
    else if (npg_args_long(&a, "--exact-size", 1, 64, &c->exact_size)) c->exact = true;
    else if ((v = npg_args_string(&a, "--std"))) c->opt.std_dir = v;
    else if (npg_args_double(&a, "--tol", 0, INFINITY, false, &c->tol)) c->tol_set = true;
    else if (npg_args_long(&a, "--cap", 1, 1000000, &cap)) c->train.cap = (int)cap;
    else if (npg_args_double(&a, "--energy", 0, 1, true, &c->train.energy)) ;
    else if (npg_args_flag(&a, "--exact-roots")) c->exact_roots = true;
    else if ((v = npg_args_string(&a, "--jacobian"))) {
      if (c->njacobian == 16) snprintf(a.error, sizeof a.error, "%s: --jacobian given more than 16 times", prog);
      else c->jacobian[c->njacobian++] = v;
    }    else if ((v = npg_args_string(&a, "--center"))) {
      c->train.uncentered = strcmp(v, "off") == 0;
      if (!c->train.uncentered && strcmp(v, "on") != 0)
        snprintf(a.error, sizeof a.error, "%s: --center is on or off, not '%s'", prog, v);
    } else if ((v = npg_args_string(&a, "--spectra"))) c->spectra = v;
    else if ((v = npg_args_string(&a, "--weights"))) c->weights = v;
    else if ((v = npg_args_string(&a, "--greedy"))) c->greedy = v;
    else if (npg_args_long(&a, "--budget", 1, 1000000000, &c->budget)) ;
    else if (npg_args_flag(&a, "--absolute")) c->absolute = true;
    else if ((v = npg_args_string(&a, "--params"))) c->params = v;
    else if ((v = npg_args_string(&a, "--sizes"))) {
      if (!*v) snprintf(a.error, sizeof a.error, "%s: --sizes: give NAME=N,... (classes as npgc check names them)", prog);
      c->sizes = v;
    }
    else if ((v = npg_args_string(&a, "--basis"))) {
      if (add_basis(c, v, err, sizeof err) != 0) snprintf(a.error, sizeof a.error, "%s: --basis %s", prog, err);
    } else if ((v = npg_args_string(&a, "--reduce"))) {
      if (!npgc_parse_reduce(&c->train, v))
        snprintf(a.error, sizeof a.error, "%s: --reduce %s: expected STAGE:interp or STAGE:galerkin", prog, v);
    } else if ((v = npg_args_string(&a, "--valid"))) {
      /* a fraction held out of DATA/ (every round(1/F)-th sample), none, or a folder that exists: a value
       * that is none of them (0, 0.25x, NONE, a missing folder) is refused here, naming --valid, not read
       * later as a folder of samples */
      char *end, ferr[256];
      double F = 0;
      struct stat st;
      c->valid = v;
      strtod(v, &end);
      bool number = end != v && *end == 0, numeric_start = end != v;
      if (strcmp(v, "none") == 0) { /* no choice: every eligible stage not forced is reduced by Galerkin */
        c->train.valid_holdout = 0;
        c->valid = NULL;
      } else if (number || (numeric_start && stat(v, &st) != 0)) { /* a number (or what starts as one): the fraction */
        if (npg_parse_double(v, 0, 0.5, true, &F, ferr, sizeof ferr) != 0)
          snprintf(a.error, sizeof a.error, "%s: --valid %s (a fraction of DATA/'s samples, none, or a folder)", prog,
                   ferr);
        c->train.valid_holdout = F;
        c->valid = NULL;
      } else if (stat(v, &st) != 0 || !S_ISDIR(st.st_mode)) {
        snprintf(a.error, sizeof a.error, "%s: --valid '%s' is %s (expected a fraction in (0, 0.5] of DATA/'s "
                 "samples, none, or a folder of validation samples)%s", prog, v,
                 stat(v, &st) != 0 ? "not a folder that exists" : "not a folder",
                 strcasecmp(v, "none") == 0 ? "; did you mean 'none'?" : "");
      }
    } else if (npg_args_double(&a, "--interp-oversample", 1, 1000, false, &c->train.interp_oversample)) ;
    else if ((v = npg_args_string(&a, "--keep-bases"))) {
      if (!*v) snprintf(a.error, sizeof a.error, "%s: --keep-bases: give quantities or classes (m_x), or all", prog);
      c->train.keep_bases = v;
    } else if ((v = npg_args_string(&a, "--merge"))) {
      c->train.joint = strcmp(v, "joint") == 0;
      if (!c->train.joint && strcmp(v, "concat") != 0)
        snprintf(a.error, sizeof a.error, "%s: --merge is concat or joint, not '%s'", prog, v);
    } else if ((v = npg_args_string(&a, "--mem"))) {
      if (!npgc_parse_bytes(v, &c->train.mem))
        snprintf(a.error, sizeof a.error, "%s: --mem: '%s' is not a size in bytes (a positive number, optionally "
                 "followed by k, M, G or T)", prog, v);
    } else if (npg_args_flag(&a, "--mpi")) {
      if (!npg_mpi_available()) {
        fprintf(stderr, "npgc train: --mpi: this build of npg has no MPI (install OpenMPI with scripts/setup.sh "
                        "and configure the build again)\n");
        return 2;
      }
      c->train.mpi = true;
    } else if (npg_args_long(&a, "--reps", 1, 1000000, &c->reps)) ;
    else if (npg_args_long(&a, "--steps", 1, 1000000000L, &c->steps)) ;
    else if (npg_args_long(&a, "--every", 1, 1000000000L, &c->every)) ;
    else if (npgc_newton_arg(&a, &c->newton)) ;
    else if ((v = npg_args_string(&a, "--png"))) c->png = v;
    else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, c->cmd);
  if (c->every != 1 && c->steps < 0) {
    fprintf(stderr, "%s: --every %ld saves every K-th step of a rollout: give --steps T too\n", prog, c->every);
    return 2;
  }
  if (c->png && c->steps < 0) {
    fprintf(stderr, "%s: --png plots the error along a rollout: give --steps T too\n", prog);
    return 2;
  }
  c->train.progress = c->progress || isatty(2);
  c->train.nbasis = c->nbasis;
  c->train.basis_name = c->basis_name;
  c->train.basis_cap = c->basis_cap;
  c->train.basis_energy = c->basis_energy;
  c->train.basis_center = c->basis_center;
  c->train.basis_product = c->basis_product;
  return 0;
}

static void free_common(Common *c) {
  for (int i = 0; i < c->nbasis; i++) free((char *)c->basis_name[i]), free((char *)c->basis_product[i]);
  free(c->basis_product);
  free(c->basis_name);
  free(c->basis_cap);
  free(c->basis_energy);
  free(c->basis_center);
  npgc_free_reduce(&c->train);
}

NpgProgram *reduce_compile(Common *c) {
  NpgProgram *p = npg_compile(c->prog_path, &c->opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return NULL;
  }
  return p;
}

/* ---------------------------------------------------------------- train */

/* Before training: an entry of --spectra DIR that a spectrum of `p` would
 * replace (spectrum_Q.npy or .csv, Q a quantity or its numerator Q.numK) and
 * that is not a regular file (a folder, a link) refuses the command, rather
 * than after the model is written. 0, or -1 after saying which. */
static int check_spectra_names(const char *dir, const NpgProgram *p) {
  DIR *d = opendir(dir);
  if (!d) return 0; /* absent: made when writing */
  int rc = 0;
  for (struct dirent *e; rc == 0 && (e = readdir(d));) {
    const char *n = e->d_name;
    size_t len = strlen(n);
    if (strncmp(n, "spectrum_", 9) != 0 || len < 14 || (strcmp(n + len - 4, ".npy") && strcmp(n + len - 4, ".csv")))
      continue;
    char q[256];
    snprintf(q, sizeof q, "%.*s", (int)(len - 13 < 255 ? len - 13 : 255), n + 9);
    char *num = strstr(q, ".num");
    if (num && num[4] && strspn(num + 4, "0123456789") == strlen(num + 4)) *num = 0;
    bool member = false;
    NpgSymbol sym;
    for (int i = 0; i < npg_nsymbols(p) && !member; i++)
      member = npg_symbol(p, i, &sym) == 0 && sym.kind != NPG_PARAM && !strcmp(sym.name, q);
    char path[4096];
    struct stat st;
    snprintf(path, sizeof path, "%s/%s", dir, n);
    if (member && lstat(path, &st) == 0 && !S_ISREG(st.st_mode)) {
      fprintf(stderr, "npgc train: --spectra %s: %s is not a regular file (a spectrum of the model would replace it): "
                      "refusing to train\n", dir, path);
      rc = -1;
    }
  }
  closedir(d);
  return rc;
}

typedef struct TrainRoll {
  const Trajectories *tr;
  NpgFull *f;
  long k;
} TrainRoll;

static int train_before_step(void *user, long step) {
  TrainRoll *x = user;
  return step ? npgc_trajectories_set_full(x->tr, x->f, x->k, step, false) : 0;
}

/* --steps T: DATA/'s trajectories run by the full step, every K-th visited state streamed into the
 * trainer (DESIGN §15); nothing written but the trainer's records. 0, or -1 after the message. */
static int add_trajectories(Common *c, NpgProgram *p, NpgFull *f, NpgTrainer *t) {
  Trajectories tr;
  char err[4400];
  if (npgc_trajectories_open(p, c->a, c->steps, &tr, err, sizeof err) != 0) return npgc_error(err), -1;
  TrainRoll x = {&tr, f, 0};
  NpgRollout ro = {.steps = c->steps, .every = c->every, .before_step = train_before_step, .user = &x};
  int rc = 0;
  for (x.k = 0; x.k < tr.samples && rc == 0; x.k++) {
    if (npgc_trajectories_set_full(&tr, f, x.k, 0, true) != 0 || npg_trainer_add_trajectory(t, f, x.k, &ro) != 0) {
      snprintf(err, sizeof err, "trajectory %ld of %s: %s", x.k, c->a,
               npg_trainer_error(t)[0] ? npg_trainer_error(t) : npg_full_error(f));
      npgc_error(err);
      rc = -1;
    }
    npg_progress(c->train.progress, "trajectories", x.k + 1, tr.samples);
  }
  npgc_trajectories_free(&tr);
  return rc;
}

/* --greedy POOL/: npg_train_greedy from DATA/'s samples over POOL/'s candidates; 0, or 1 after
 * the message. The budget reached without --tol met is said on stderr and is no failure. */
static int train_greedy(Common *c, NpgProgram *p, NpgFull *f, NpgSamples *s) {
  char err[2048];
  NpgSamples *pool = npg_samples_open(p, c->greedy, NULL, true, err, sizeof err);
  if (!pool) return npgc_error(err), 1;
  int rc = 1;
  if (npg_samples_count(pool) < 1) {
    fprintf(stderr, "error: --greedy %s: no candidates (the first axis of its inputs is 0)\n", c->greedy);
    goto done;
  }
  if (!c->tol_set) {
    fprintf(stderr, "npgc train: --greedy needs --tol E, the estimated relative error (with --absolute: the absolute "
            "one) every candidate must reach\n");
    goto done;
  }
  NpgGreedyOptions g = {c->tol, c->budget, true, c->absolute};
  NpgGreedyResult res;
  double t0 = reduce_now();
  NpgModel *m = npg_train_greedy(f, &c->train, npg_samples_count(s), npg_samples_set, s, npg_samples_count(pool),
                                 npg_samples_set, pool, &g, c->out, &res);
  if (!m) npgc_error(res.error);
  else if (npg_mpi_rank() > 0) /* rank 0 reports */
    rc = 0;
  else {
    printf("trained %s greedily on %ld samples (%ld of DATA/, %ld chosen of %ld candidates in %s; %ld full "
           "evaluations) in %.2f s -> %s\n", c->prog_path, npg_model_samples(m), npg_samples_count(s), res.nchosen,
           npg_samples_count(pool), c->greedy, res.evaluations, reduce_now() - t0, c->out);
    printf("worst candidate's estimated %s error %.3e: %s --tol %.3g\n", c->absolute ? "absolute" : "relative", res.worst,
           res.converged ? "below" : "above (the budget stopped it)", c->tol);
    npg_model_report(m, stdout);
    rc = 0;
  }
  free(res.chosen);
  npg_model_free(m);
done:
  npg_samples_free(pool);
  return rc;
}

/* The samples of DATA/ streamed into a trainer, as any C program would. */
static int cmd_train(Common *c) {
  if (!c->prog_path) return npgc_missing("train", "the program (PROG.npg)");
  if (!c->a) return npgc_missing("train", "DATA/ (the params and the training samples)");
  if (c->b) {
    fprintf(stderr, "npgc train: more than one DATA/ folder given ('%s' and '%s'): training reads one (the model's "
                    "folder follows -o)\n", c->a, c->b);
    return 2;
  }
  if (!c->out) return npgc_missing("train", "-o MODEL/ (where to write the model)");
  /* --valid DIR is read as DATA/ is: --spectra may not write into it (trial3); NULL ends the lists early */
  const char *inputs[] = {c->prog_path, c->a, c->valid, NULL};
  const char *spectra_inputs[] = {c->prog_path, c->a, c->out, c->valid, NULL};
  if (npgc_check_output("train", "-o", c->out, NPGC_OUT_MODEL, inputs) != 0 ||
      (c->spectra && npgc_check_output("train", "--spectra", c->spectra, NPGC_OUT_DIR, spectra_inputs) != 0))
    return 1;
  /* one of several ranks of an MPI job (OpenMPI's or a PMI launcher's variable) without --mpi: every rank
   * would train alone and race to write MODEL/ */
  const char *ranks = getenv("OMPI_COMM_WORLD_SIZE") ? getenv("OMPI_COMM_WORLD_SIZE") : getenv("PMI_SIZE");
  if (!c->train.mpi && ranks && atol(ranks) > 1) {
    fprintf(stderr, "npgc train: started as one of %ld ranks of an MPI job without --mpi: each would train alone and "
                    "write %s; add --mpi to train over the ranks, or run one process\n", atol(ranks), c->out);
    return 2;
  }
  NpgProgram *p = reduce_compile(c);
  if (!p) return 1;
  if ((c->spectra && check_spectra_names(c->spectra, p) != 0) || npgc_make_parents(c->out, false) != 0) {
    npg_free(p);
    return 1;
  }
  char err[2048] = "";
  int rc = 1;
  NpgSamples *s = NULL, *v = NULL;
  NpgTrainer *t = NULL;
  NpgModel *m = NULL;
  NpgFull *f = npg_full_new(p, c->backend);
  if (npg_full_error(f)[0] || npg_full_bind_params(f, c->a) != 0) {
    npgc_error(npg_full_error(f));
    goto done;
  }
  npgc_newton_full(&c->newton, f);
  if (c->steps >= 0 && c->weights) {
    fprintf(stderr, "npgc train: --weights weighs samples, not trajectories: not with --steps\n");
    goto done;
  }
  if (c->steps < 0 && !(s = npg_samples_open(p, c->a, NULL, true, err, sizeof err))) {
    npgc_error(err);
    goto done;
  }
  if (s && npg_samples_count(s) < 1) {
    fprintf(stderr, "error: %s: no samples (the first axis of its inputs is 0)\n", c->a);
    goto done;
  }
  if (c->valid) { /* DESIGN §12: Galerkin or interpolation per eligible stage, by the error on these */
    if (!(v = npg_samples_open(p, c->valid, NULL, true, err, sizeof err)) ||
        npg_full_check_params_dir(f, c->valid, err, sizeof err) != 0) {
      npgc_error(err);
      goto done;
    }
    c->train.valid_count = npg_samples_count(v);
    c->train.valid_set = npg_samples_set;
    c->train.valid_user = v;
    if (c->train.valid_count < 1) {
      fprintf(stderr, "error: --valid %s: no samples (the first axis of its inputs is 0)\n", c->valid);
      goto done;
    }
  }
  /* --weights: a float64 vector, one weight per sample; npg_trainer_weight refuses one not positive and finite */
  double *w = NULL;
  int wnd = 0;
  long wshape[NPG_NPY_MAX_DIMS];
  size_t wn = 0;
  if (c->weights && !(w = npg_npy_read(c->weights, &wnd, wshape, &wn, err, sizeof err))) {
    fprintf(stderr, "error: --weights %s\n", err);
    goto done;
  }
  if (w && s && (wnd != 1 || (long)wn != npg_samples_count(s))) {
    fprintf(stderr, "error: --weights %s: %s %zu entries, DATA/ has %ld samples (a vector of one weight per sample)\n",
            c->weights, wnd == 1 ? "a vector of" : "not a vector but", wn, npg_samples_count(s));
    free(w);
    goto done;
  }
  if (c->greedy) {
    if (c->steps >= 0 || c->weights || c->valid || c->spectra) {
      fprintf(stderr, "npgc train: --greedy is not with --steps, --weights, --valid or --spectra\n");
      goto done_w;
    }
    rc = train_greedy(c, p, f, s);
    goto done_w;
  }
  if (c->tol_set || c->budget || c->absolute) {
    fprintf(stderr, "npgc train: --tol, --budget and --absolute are options of greedy training (--greedy POOL/)\n");
    goto done_w;
  }
  double t0 = reduce_now();
  t = npg_trainer_new(f, &c->train);
  if (c->steps >= 0) {
    if (add_trajectories(c, p, f, t) != 0) goto done_w;
  } else {
    for (long k = 0; k < npg_samples_count(s) && !npg_trainer_error(t)[0]; k++) {
      if (w && npg_trainer_weight(t, w[k]) != 0) {
        fprintf(stderr, "error: --weights %s: %s\n", c->weights, npg_trainer_error(t));
        goto done_w;
      }
      if (npg_samples_set(s, f, k) != 0 || npg_trainer_add_full(t, f) != 0) break;
    }
  }
  free(w);
  w = NULL;
  if (npg_trainer_error(t)[0]) npgc_error(npg_trainer_error(t));
  else if (npg_full_error(f)[0]) npgc_error(npg_full_error(f));
  else if (!(m = npg_trainer_finish(t, c->out))) npgc_error(npg_trainer_error(t));
  else if (c->spectra && npg_mpi_rank() == 0 && npgc_make_parents(c->spectra, false) != 0)
    ; /* said which folder could not be made */
  else if (c->spectra && npg_mpi_rank() == 0 && npg_model_write_spectra(m, c->spectra, err, sizeof err) != 0) {
    npgc_error(err);
    fprintf(stderr, "npgc train: the model in %s is whole; no spectrum was written to %s (its files are as they "
                    "were)\n", c->out, c->spectra);
  }
  else if (npg_mpi_rank() > 0) /* rank 0 reports */
    rc = 0;
  else {
    double sec[4], cpu[4];
    npg_model_train_seconds(m, sec, cpu);
    long held = s ? npg_samples_count(s) - npg_model_samples(m) : 0; /* --valid F: held out to validate on */
    printf("trained %s on %ld %s", c->prog_path, npg_model_samples(m), s ? "samples" : "visited states");
    if (held > 0) printf(" (%ld more of DATA/ held out to validate on)", held);
    printf(" in %.2f s -> %s\n", reduce_now() - t0, c->out);
    printf("phases: snapshots %.2f s, bases %.2f s, pre-multiplication %.2f s, externs %.2f s (cpu %.2f %.2f %.2f "
           "%.2f s)\n", sec[0], sec[1], sec[2], sec[3], cpu[0], cpu[1], cpu[2], cpu[3]);
    npg_model_report(m, stdout);
    rc = 0;
  }
  goto done;
done_w:
  free(w);
done:
  npg_model_free(m);
  npg_trainer_free(t);
  npg_samples_free(s);
  npg_samples_free(v);
  npg_full_free(f);
  npg_free(p);
  return rc;
}

int npgc_reduce(int argc, char **argv) {
  Common c;
  int rc = parse(&c, argc, argv); /* refuses training's options to verify and bench, naming them (issue 24) */
  if (rc == -1) rc = 0;            /* --help */
  else if (rc == 0) {
    if (strcmp(c.cmd, "train") == 0) rc = cmd_train(&c);
    else if (strcmp(c.cmd, "eval") == 0) rc = cmd_eval_reduced(&c);
    else if (strcmp(c.cmd, "verify") == 0) rc = cmd_verify(&c);
    else rc = cmd_bench(&c);
  }
  free_common(&c);
  return rc;
}
