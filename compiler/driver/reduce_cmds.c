/* reduce_cmds.c — the commands that make and use reduced models:
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
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "npg.h"
#include "npgc.h"

typedef struct Common {
  const char *prog_path, *a, *b, *out;
  NpgOptions opt;
  bool cc;
  bool exact;               /* verify: the exactness checks of DESIGN §4 */
  long exact_size;          /* their size of every dim (0: exact.c's defaults) */
  double tol;
  bool tol_set;
  long reps;                /* bench: passes over the samples */
  bool progress;            /* --progress: progress on stderr even when it is not a terminal */
  bool exact_roots;         /* eval, bench: roots by eigendecomposition, not Lanczos */
  NpgTrainOptions train;
  int nbasis;               /* --basis overrides */
  const char **basis_name;
  int *basis_cap;
  double *basis_energy;
  int *basis_center;
  const char *spectra;      /* train --spectra DIR */
  const char *params;       /* verify --params DIR: the params, when TEST/ holds only the samples */
  const char *valid;        /* train --valid DIR */
  const char *cmd;
} Common;

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* --basis NAME:cap=N,energy=E,center=on|off (NAME: a quantity, a class, a
 * numerator or '*', checked by training; `max=N` is accepted for `cap=N`,
 * and `cap N` for `cap=N`, as in the language's basis statement). 0, or -1
 * with the problem in `err`. */
static int parse_basis(Common *c, const char *s, char *err, size_t errlen) {
  const char *colon = strchr(s, ':');
  if (!colon || colon == s) {
    snprintf(err, errlen, "'%s': expected NAME:cap=N,energy=E,center=on|off (NAME a quantity, a class or '*')", s);
    return -1;
  }
  if (!colon[1 + strspn(colon + 1, " ")]) {
    snprintf(err, errlen, "'%s': nothing after the colon (expected NAME:cap=N,energy=E,center=on|off)", s);
    return -1;
  }
  int k = c->nbasis;
  const char **names = realloc(c->basis_name, sizeof(char *) * (size_t)(k + 1));
  if (names) c->basis_name = names;
  int *caps = realloc(c->basis_cap, sizeof(int) * (size_t)(k + 1));
  if (caps) c->basis_cap = caps;
  double *energies = realloc(c->basis_energy, sizeof(double) * (size_t)(k + 1));
  if (energies) c->basis_energy = energies;
  int *centers = realloc(c->basis_center, sizeof(int) * (size_t)(k + 1));
  if (centers) c->basis_center = centers;
  if (!names || !caps || !energies || !centers) {
    snprintf(err, errlen, "out of memory");
    return -1;
  }
  c->nbasis++;
  c->basis_center[k] = -1;
  c->basis_name[k] = strndup(s, (size_t)(colon - s));
  c->basis_cap[k] = -1;
  c->basis_energy[k] = -1;
  const char *p = colon + 1;
  while (*p == ' ') p++;
  while (*p) {
    size_t klen = strcspn(p, "= ,");
    const char *v = p + klen;
    while (*v == ' ') v++;
    if (*v == '=') v++;
    while (*v == ' ') v++;
    size_t vlen = strcspn(v, ", ");
    char key[64], val[64], why[256];
    snprintf(key, sizeof key, "%.*s", (int)(klen < 63 ? klen : 63), p);
    snprintf(val, sizeof val, "%.*s", (int)(vlen < 63 ? vlen : 63), v);
    if (!strcmp(key, "cap") || !strcmp(key, "max")) {
      long cap;
      if (npg_parse_long(val, 1, 1000000, &cap, why, sizeof why) != 0) {
        snprintf(err, errlen, "'%s': %s: %s", s, key, why);
        return -1;
      }
      c->basis_cap[k] = (int)cap;
    } else if (!strcmp(key, "energy")) {
      if (npg_parse_double(val, 0, 1, true, &c->basis_energy[k], why, sizeof why) != 0) {
        snprintf(err, errlen, "'%s': energy: %s", s, why);
        return -1;
      }
    } else if (!strcmp(key, "center")) {
      if (strcmp(val, "on") && strcmp(val, "off")) {
        snprintf(err, errlen, "'%s': center is on or off, not '%s'", s, val);
        return -1;
      }
      c->basis_center[k] = !strcmp(val, "on");
    } else {
      snprintf(err, errlen, "'%s': unknown key '%s' (the keys are cap, energy and center: NAME:cap=N,energy=E,center=on|off)",
               s, key);
      return -1;
    }
    p = v + vlen;
    while (*p == ' ') p++;
    if (*p == ',') p++;
    while (*p == ' ') p++;
  }
  return 0;
}

/* Each command's options: an option of another command is named as such. */
static const char *const options_of[][2] = {
    {"train", "-o --cc --progress --std --cap --energy --center --spectra --basis --merge --mem --mpi --reduce --valid "
              "--interp-oversample --keep-bases"},
    {"eval", "-o --progress --std --exact-roots --full --cc"},
    {"verify", "--tol --cc --exact --exact-size --progress --std --params"},
    {"bench", "--cc --reps --exact-roots --progress --std --params"},
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
  npg_train_options_default(&c->train);
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
    else if (npg_args_flag(&a, "--cc")) c->cc = true;
    else if (npg_args_flag(&a, "--full")) ; /* eval.c took it */
    else if (npg_args_flag(&a, "--progress")) c->progress = true;
    else if (npg_args_flag(&a, "--exact")) c->exact = true;
    else if (npg_args_long(&a, "--exact-size", 1, 64, &c->exact_size)) c->exact = true;
    else if ((v = npg_args_string(&a, "--std"))) c->opt.std_dir = v;
    else if (npg_args_double(&a, "--tol", 0, INFINITY, false, &c->tol)) c->tol_set = true;
    else if (npg_args_long(&a, "--cap", 1, 1000000, &cap)) c->train.cap = (int)cap;
    else if (npg_args_double(&a, "--energy", 0, 1, true, &c->train.energy)) ;
    else if (npg_args_flag(&a, "--exact-roots")) c->exact_roots = true;
    else if ((v = npg_args_string(&a, "--center"))) {
      c->train.uncentered = strcmp(v, "off") == 0;
      if (!c->train.uncentered && strcmp(v, "on") != 0)
        snprintf(a.error, sizeof a.error, "%s: --center is on or off, not '%s'", prog, v);
    } else if ((v = npg_args_string(&a, "--spectra"))) c->spectra = v;
    else if ((v = npg_args_string(&a, "--params"))) c->params = v;
    else if ((v = npg_args_string(&a, "--basis"))) {
      if (parse_basis(c, v, err, sizeof err) != 0) snprintf(a.error, sizeof a.error, "%s: --basis %s", prog, err);
    } else if ((v = npg_args_string(&a, "--reduce"))) {
      if (!npgc_parse_reduce(&c->train, v))
        snprintf(a.error, sizeof a.error, "%s: --reduce %s: expected STAGE:interp or STAGE:galerkin", prog, v);
    } else if ((v = npg_args_string(&a, "--valid"))) {
      /* a folder, or a fraction held out of DATA/ (every round(1/F)-th sample) */
      char *end, ferr[256];
      double F;
      c->valid = v;
      if (strcmp(v, "none") == 0) { /* no choice: every eligible stage not forced is reduced by Galerkin */
        c->train.valid_holdout = 0;
        c->valid = NULL;
      } else if (strtod(v, &end) && end != v && *end == 0) { /* a number: the fraction */
        if (npg_parse_double(v, 0, 0.5, true, &F, ferr, sizeof ferr) != 0)
          snprintf(a.error, sizeof a.error, "%s: --valid %s (a fraction of DATA/'s samples, or a folder)", prog, ferr);
        c->train.valid_holdout = F;
        c->valid = NULL;
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
    else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, c->cmd);
  c->train.progress = c->progress || isatty(2);
  c->train.nbasis = c->nbasis;
  c->train.basis_name = c->basis_name;
  c->train.basis_cap = c->basis_cap;
  c->train.basis_energy = c->basis_energy;
  c->train.basis_center = c->basis_center;
  return 0;
}

static void free_common(Common *c) {
  for (int i = 0; i < c->nbasis; i++) free((char *)c->basis_name[i]);
  free(c->basis_name);
  free(c->basis_cap);
  free(c->basis_energy);
  free(c->basis_center);
  npgc_free_reduce(&c->train);
}

static NpgProgram *compile(Common *c) {
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
  NpgProgram *p = compile(c);
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
  NpgFull *f = npg_full_new(p, c->cc ? NPG_CC : NPG_TCC);
  if (npg_full_error(f)[0] || npg_full_bind_params(f, c->a) != 0) {
    npgc_error(npg_full_error(f));
    goto done;
  }
  if (!(s = npg_samples_open(p, c->a, NULL, true, err, sizeof err))) {
    npgc_error(err);
    goto done;
  }
  if (npg_samples_count(s) < 1) {
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
  double t0 = now();
  t = npg_trainer_new(f, &c->train);
  for (long k = 0; k < npg_samples_count(s) && !npg_trainer_error(t)[0]; k++)
    if (npg_samples_set(s, f, k) != 0 || npg_trainer_add_full(t, f) != 0) break;
  if (npg_full_error(f)[0]) npgc_error(npg_full_error(f));
  else if (!(m = npg_trainer_finish(t, c->out))) npgc_error(npg_trainer_error(t));
  else if (c->spectra && npg_mpi_rank() == 0 && npgc_make_parents(c->spectra, false) != 0)
    ; /* said which folder could not be made */
  else if (c->spectra && npg_mpi_rank() == 0 && npg_model_write_spectra(m, c->spectra, err, sizeof err) != 0)
    npgc_error(err);
  else if (npg_mpi_rank() > 0) /* rank 0 reports */
    rc = 0;
  else {
    double sec[4], cpu[4];
    npg_model_train_seconds(m, sec, cpu);
    long held = npg_samples_count(s) - npg_model_samples(m); /* --valid F: held out to validate on */
    printf("trained %s on %ld samples", c->prog_path, npg_model_samples(m));
    if (held > 0) printf(" (%ld more of DATA/ held out to validate on)", held);
    printf(" in %.2f s -> %s\n", now() - t0, c->out);
    printf("phases: snapshots %.2f s, bases %.2f s, pre-multiplication %.2f s, externs %.2f s (cpu %.2f %.2f %.2f "
           "%.2f s)\n", sec[0], sec[1], sec[2], sec[3], cpu[0], cpu[1], cpu[2], cpu[3]);
    npg_model_report(m, stdout);
    rc = 0;
  }
done:
  npg_model_free(m);
  npg_trainer_free(t);
  npg_samples_free(s);
  npg_samples_free(v);
  npg_full_free(f);
  npg_free(p);
  return rc;
}

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
  if (!(x->p = compile(c))) return -1;
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
    x->f = npg_full_new(x->p, c->cc ? NPG_CC : NPG_TCC);
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
static int reduced_sample(Session *x, long k) {
  for (int i = 0; i < x->nsym; i++) {
    if (x->sym[i].kind != NPG_INPUT) continue;
    size_t n;
    const double *v = npg_samples_get(x->s, x->sym[i].name, k, &n);
    if (npg_reduced_set(x->r, x->sym[i].name, n, v) != 0) return -1;
  }
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
  return npg_reduced_lift(x->r, u->sym->name, u->lifted + k * u->n, (size_t)u->n);
}

static int cmd_eval_reduced(Common *c) {
  if (!c->prog_path || !c->a) return npgc_missing("eval", "MODEL/ (or --full DATA/)");
  if (!c->b) return npgc_missing("eval", "IN/ (the inputs to evaluate)");
  if (!c->out) return npgc_missing("eval", "-o OUT/ (where to write the outputs)");
  const char *inputs[] = {c->prog_path, c->a, c->b, NULL};
  if (npgc_check_output("eval", "-o", c->out, NPGC_OUT_DIR, inputs) != 0) return 1;
  Session x;
  int rc = 1, nout = 0;
  Out *outs = NULL;
  if (open_session(c, &x, false) != 0) goto done;
  long S = npg_samples_count(x.s);
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
    if (!u->lifted || !u->coords) goto oom;
  }
  for (long k = 0; k < S; k++) {
    if (reduced_sample(&x, k) != 0) goto failed;
    for (int o = 0; o < nout; o++)
      if (keep_output(&x, &outs[o], k) != 0) goto failed;
    npg_progress(c->train.progress && S > 1, "reduced evaluation", k + 1, S);
  }
  /* an operator's matrices were kept at the largest stride: pack them */
  for (int o = 0; o < nout; o++) {
    Out *u = &outs[o];
    if (u->sym->kind != NPG_OP) continue;
    for (long k = 1; k < S; k++)
      memmove(u->coords + k * u->rows * u->cols, u->coords + k * u->m, sizeof(double) * (size_t)(u->rows * u->cols));
  }
  rc = write_outputs(c, &x, outs, nout, S) == 0 ? 0 : 1;
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
  }
  free(outs);
  close_session(&x);
  return rc;
}

/* ---------------------------------------------------------------- verify */

/* The exactness checks of the design (npg_verify_exact): 0 pass, 1 fail or error. */
static int verify_exact(Common *c) {
  NpgProgram *p = compile(c);
  if (!p) return 1;
  char err[2048] = "";
  fflush(stdout);
  int rc = npg_verify_exact(p, c->exact_size, c->cc ? NPG_CC : NPG_TCC, c->train.progress, stdout, err, sizeof err);
  if (rc < 0)
    fprintf(stderr, "error: exactness checks of %s: %s%s\n", c->prog_path, err,
            strstr(err, "not finite") || strstr(err, "singular") || strstr(err, "indefinite")
                ? " (random data can be degenerate at small sizes, e.g. meshes with too few vertices: try a larger "
                  "--exact-size)"
                : "");
  npg_free(p);
  return rc == 0 ? 0 : 1;
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
}

static int cmd_verify(Common *c) {
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

/* The median and the quartiles of v[0..n) (sorted in place). */
static void quartiles(double *v, long n, double q[3]) {
  qsort(v, (size_t)n, sizeof *v, by_value);
  for (int k = 0; k < 3; k++) {
    double at = (double)(n - 1) * (k + 1) / 4; /* linear interpolation between order statistics */
    long i = (long)at;
    q[k] = i + 1 < n ? v[i] + (at - (double)i) * (v[i + 1] - v[i]) : v[n - 1];
  }
}

/* An error during the timed passes: the progress line is ended first. */
static void bench_error(const Common *c, const char *msg) {
  if (c->train.progress) fputc('\n', stderr);
  npgc_error(msg);
}

static int cmd_bench(Common *c) {
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
  /* per timed evaluation: full, reduced (projected and lifted), lifting alone, and their ratio */
  if (!(y = malloc(sizeof(double) * maxn)) || !(tf = malloc(sizeof(double) * (size_t)(4 * total + 4)))) {
    fputs("error: out of memory\n", stderr);
    goto done;
  }
  double *tr = tf + total + 1, *tl = tr + total + 1, *ratio = tl + total + 1;
  long timed = 0;
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
      double t0 = now();
      if (npg_full_eval(x.f, k) != 0) {
        bench_error(c, npg_full_error(x.f));
        goto done;
      }
      double t1 = now();
      if (reduced_sample(&x, k) != 0) {
        bench_error(c, npg_reduced_error(x.r));
        goto done;
      }
      double t2 = now();
      if (lift_outputs(&x, y, maxn) != 0) {
        bench_error(c, npg_reduced_error(x.r));
        goto done;
      }
      double t3 = now();
      if (rep == 0 && k == 0 && !(S == 1 && c->reps == 1)) continue; /* the first full evaluation also checks gathers */
      tf[timed] = t1 - t0;
      tr[timed] = t3 - t1;
      tl[timed] = t3 - t2;
      ratio[timed] = (t1 - t0) / fmax(t3 - t1, 1e-12);
      timed++;
    }
  npg_progress(c->train.progress, "bench (full and reduced)", total, total);
  size_t tb, bytes = npg_model_bytes(x.m, &tb);
  /* one statistic, the median (robust to the machine's other load, which the mean is not), with the quartiles
   * as its spread; the speedup is the median of the per-evaluation ratios, each full evaluation against the
   * reduced one that follows it */
  double qf[3], qr[3], ql[3], qs[3];
  quartiles(tf, timed, qf);
  quartiles(tr, timed, qr);
  quartiles(tl, timed, ql);
  quartiles(ratio, timed, qs);
  printf("bench %s: %ld samples x %ld passes, %ld evaluations timed; medians, quartiles in brackets\n", c->prog_path, S,
         c->reps, timed);
  printf("full evaluator: %s\n", c->cc ? "cc (the system compiler at -O3 -march=native)"
                                        : "libtcc (npg's default; --cc times the system compiler at -O3)");
  printf("full evaluation     %12.3e s per sample [%.3e, %.3e]\n", qf[1], qf[0], qf[2]);
  printf("reduced evaluation  %12.3e s per sample [%.3e, %.3e], inputs projected and outputs lifted\n", qr[1], qr[0],
         qr[2]);
  printf("  of which lifting  %12.3e s per sample [%.3e, %.3e]\n", ql[1], ql[0], ql[2]);
  printf("speedup             %12.3gx [%.3gx, %.3gx] (full time / reduced time per evaluation%s)\n", qs[1], qs[0],
         qs[2], qs[1] < 1 ? ": below 1, the reduced evaluation is slower" : "");
  printf("reduced model       %12.3f MB of reduced tensors, %.3f MB with bases and extern tables\n", (double)tb / 1e6,
         (double)bytes / 1e6);
  rc = 0;
done:
  free(tf);
  free(y);
  close_session(&x);
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
