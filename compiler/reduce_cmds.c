/* reduce_cmds.c — the commands that make and use reduced models:
 *
 *   npgc train  PROG.npg DATA/ -o MODEL/     (DESIGN §5)
 *   npgc eval   PROG.npg MODEL/ IN/ -o OUT/  (reduced: coordinates and lifted outputs)
 *   npgc verify PROG.npg MODEL/ TEST/        (DESIGN §7: the auto-check)
 *   npgc bench  PROG.npg MODEL/ TEST/        (full vs reduced time, memory)
 */
#include <cblas.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "compile.h"
#include "emit.h"
#include "exact.h"
#include "npy.h"
#include "reduced.h"
#include "samples.h"
#include "train.h"

typedef struct Common {
  const char *prog_path, *a, *b, *out;
  NpgOptions opt;
  bool cc;
  bool exact;               /* verify: the exactness checks of DESIGN §4 */
  long exact_size;          /* their size of every dim (0: exact.c's defaults) */
  double tol;
  bool tol_set;
  TrainOptions train;
  const char *cmd;
} Common;

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static size_t parse_bytes(const char *s, bool *ok) {
  char *end;
  double v = strtod(s, &end);
  double mul = 1;
  if (*end == 'k' || *end == 'K') mul = 1e3, end++;
  else if (*end == 'M') mul = 1e6, end++;
  else if (*end == 'G') mul = 1e9, end++;
  *ok = end != s && *end == 0 && v > 0;
  return (size_t)(v * mul);
}

/* --basis NAME:cap=N,energy=E (NAME may be '*') */
static bool parse_basis(Common *c, const char *s) {
  TrainOptions *t = &c->train;
  const char *colon = strchr(s, ':');
  if (!colon || colon == s) return false;
  int k = t->noverride++;
  t->override_name = realloc(t->override_name, sizeof(char *) * (size_t)t->noverride);
  t->override_cap = realloc(t->override_cap, sizeof(int) * (size_t)t->noverride);
  t->override_energy = realloc(t->override_energy, sizeof(double) * (size_t)t->noverride);
  if (!t->override_name || !t->override_cap || !t->override_energy) return false;
  t->override_name[k] = strndup(s, (size_t)(colon - s));
  t->override_cap[k] = -1;
  t->override_energy[k] = -1;
  const char *p = colon + 1;
  while (*p) {
    char *end;
    if (strncmp(p, "cap=", 4) == 0) {
      long v = strtol(p + 4, &end, 10);
      if (end == p + 4 || v < 1) return false;
      t->override_cap[k] = (int)v;
    } else if (strncmp(p, "energy=", 7) == 0) {
      double v = strtod(p + 7, &end);
      if (end == p + 7 || !(v > 0 && v <= 1)) return false;
      t->override_energy[k] = v;
    } else {
      return false;
    }
    p = end;
    if (*p == ',') p++;
    else if (*p) return false;
  }
  return true;
}

static int usage(const char *cmd) {
  if (strcmp(cmd, "train") == 0)
    fputs("usage: npgc train PROG.npg DATA/ -o MODEL/ [--cap N] [--energy E] [--basis NAME:cap=N,energy=E]\n"
          "                  [--merge concat|joint] [--mem BYTES] [--cc]\n",
          stderr);
  else if (strcmp(cmd, "eval") == 0)
    fputs("usage: npgc eval PROG.npg MODEL/ IN/ -o OUT/ [--cc]   (reduced)\n"
          "       npgc eval PROG.npg --full DATA/ IN/ -o OUT/ [--cc]\n",
          stderr);
  else if (strcmp(cmd, "verify") == 0)
    fputs("usage: npgc verify PROG.npg MODEL/ TEST/ [--tol T] [--cc] [--exact] [--exact-size N]\n"
          "       npgc verify PROG.npg --exact [--exact-size N] [--cc]\n",
          stderr);
  else fprintf(stderr, "usage: npgc %s PROG.npg MODEL/ TEST/ [--cc]\n", cmd);
  return 2;
}

static int parse(Common *c, int argc, char **argv) {
  memset(c, 0, sizeof *c);
  c->cmd = argv[1];
  c->tol = 1e-2;
  c->train.cap = 60;
  c->train.energy = 0.999;
  long pages = sysconf(_SC_PHYS_PAGES), psize = sysconf(_SC_PAGE_SIZE);
  c->train.mem = pages > 0 && psize > 0 ? (size_t)pages * (size_t)psize / 2 : (size_t)8 << 30;
  for (int i = 2; i < argc; i++) {
    const char *a = argv[i];
    bool has = i + 1 < argc, ok = true;
    if (strcmp(a, "-o") == 0 && has) c->out = argv[++i];
    else if (strcmp(a, "--cc") == 0) c->cc = true;
    else if (strcmp(a, "--exact") == 0 && strcmp(c->cmd, "verify") == 0) c->exact = true;
    else if (strcmp(a, "--exact-size") == 0 && has && strcmp(c->cmd, "verify") == 0) {
      char *end;
      c->exact = true;
      c->exact_size = strtol(argv[++i], &end, 10);
      ok = *end == 0 && c->exact_size >= 1 && c->exact_size <= 64;
    }
    else if (strncmp(a, "--std=", 6) == 0) c->opt.std_dir = a + 6;
    else if (strcmp(a, "--tol") == 0 && has) {
      char *end;
      c->tol = strtod(argv[++i], &end);
      c->tol_set = true;
      ok = *end == 0 && c->tol >= 0;
    } else if (strcmp(a, "--cap") == 0 && has) {
      char *end;
      c->train.cap = (int)strtol(argv[++i], &end, 10);
      ok = *end == 0 && c->train.cap >= 1;
    } else if (strcmp(a, "--energy") == 0 && has) {
      char *end;
      c->train.energy = strtod(argv[++i], &end);
      ok = *end == 0 && c->train.energy > 0 && c->train.energy <= 1;
    } else if (strcmp(a, "--basis") == 0 && has) {
      ok = parse_basis(c, argv[++i]);
    } else if (strcmp(a, "--merge") == 0 && has) {
      const char *v = argv[++i];
      c->train.joint = strcmp(v, "joint") == 0;
      ok = c->train.joint || strcmp(v, "concat") == 0;
    } else if (strcmp(a, "--mem") == 0 && has) {
      c->train.mem = parse_bytes(argv[++i], &ok);
    } else if (a[0] == '-') {
      fprintf(stderr, "npgc %s: unknown option '%s'\n", c->cmd, a);
      return usage(c->cmd);
    } else if (!c->prog_path) c->prog_path = a;
    else if (!c->a) c->a = a;
    else if (!c->b) c->b = a;
    else return usage(c->cmd);
    if (!ok) {
      fprintf(stderr, "npgc %s: bad value for %s: '%s'\n", c->cmd, a, argv[i]);
      return 2;
    }
  }
  c->train.progress = isatty(2);
  return 0;
}

static void free_common(Common *c) {
  for (int i = 0; i < c->train.noverride; i++) free((char *)c->train.override_name[i]);
  free(c->train.override_name);
  free(c->train.override_cap);
  free(c->train.override_energy);
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

static void print_model(const Model *m, FILE *out) {
  fprintf(out, "%-24s %8s %6s  %s\n", "class", "n", "m", "members (kept / cap, energy captured)");
  for (int c = 0; c < m->nclasses; c++) {
    const RClass *rc = &m->classes[c];
    fprintf(out, "%-24s %8ld %6ld ", rc->label, rc->n, rc->m);
    for (int i = 0; i < rc->nmembers; i++)
      fprintf(out, " %s %d/%d %.6f", rc->members[i].name, rc->members[i].kept, rc->members[i].cap,
              rc->members[i].captured);
    fputc('\n', out);
  }
  size_t tb, total = model_bytes(m, &tb);
  fprintf(out, "reduced tensors: %.3f MB; model with bases: %.3f MB\n", (double)tb / 1e6, (double)total / 1e6);
}

static int cmd_train(Common *c) {
  if (!c->prog_path || !c->a || !c->out || c->b) return usage("train");
  NpgProgram *p = compile(c);
  if (!p) return 1;
  Program *prog = npg_program_ir(p);
  char err[2048] = "";
  int rc = 1;
  SampleSet s = {0};
  Model *m = NULL;
  NpgFull *f = npg_full_new(p, c->cc ? NPG_CC : NPG_TCC);
  if (npg_full_error(f)[0] || npg_full_bind_params(f, c->a) != 0) {
    fprintf(stderr, "error: %s\n", npg_full_error(f));
    goto done;
  }
  if (samples_open(&s, prog, c->a, NULL, true, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  SampleSource src = {s.count, &s, samples_set};
  double t0 = now();
  m = train_model(prog, f, &src, &c->train, err, sizeof err);
  if (!m) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  if (!(m->param_hashes = samples_param_hashes(prog, c->a, err, sizeof err))) {
    fprintf(stderr, "error: %s\n", err[0] ? err : "out of memory");
    goto done;
  }
  if (model_save(m, c->out, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    goto done;
  }
  printf("trained %s on %ld samples in %.2f s -> %s\n", c->prog_path, s.count, now() - t0, c->out);
  print_model(m, stdout);
  rc = 0;
done:
  model_free(m);
  samples_close(&s);
  npg_full_free(f);
  npg_free(p);
  return rc;
}

/* ---------------------------------------------------------------- shared by eval, verify, bench */

typedef struct Session {
  NpgProgram *p;
  Program *prog;
  Model *m;
  Reduced *r;
  SampleSet s;
  NpgFull *f;               /* only verify and bench */
} Session;

static void close_session(Session *x) {
  reduced_free(x->r);
  model_free(x->m);
  samples_close(&x->s);
  npg_full_free(x->f);
  npg_free(x->p);
}

/* Compile, load MODEL/ (c->a), open the samples of c->b; with `full`, a
 * full evaluator bound to c->b's params. */
static int open_session(Common *c, Session *x, bool full) {
  memset(x, 0, sizeof *x);
  char err[2048] = "";
  if (!(x->p = compile(c))) return -1;
  x->prog = npg_program_ir(x->p);
  if (!(x->m = model_load(x->prog, c->a, err, sizeof err)) || !(x->r = reduced_new(x->m, err, sizeof err))) {
    fprintf(stderr, "error: %s\n", err);
    return -1;
  }
  /* a full evaluation needs the extern values of the data; a reduced one learns them */
  if (samples_open(&x->s, x->prog, c->b, NULL, full, err, sizeof err) != 0) {
    fprintf(stderr, "error: %s\n", err);
    return -1;
  }
  if (full) {
    if (samples_check_params(x->prog, c->b, x->m->param_hashes, err, sizeof err) != 0) {
      fprintf(stderr, "error: %s\n", err);
      return -1;
    }
    x->f = npg_full_new(x->p, c->cc ? NPG_CC : NPG_TCC);
    if (npg_full_error(x->f)[0] || npg_full_bind_params(x->f, c->b) != 0) {
      fprintf(stderr, "error: %s\n", npg_full_error(x->f));
      return -1;
    }
  }
  /* the inputs' sizes must be the model's */
  for (int i = 0; i < x->s.n; i++) {
    const SampleFile *g = &x->s.files[i];
    size_t n;
    samples_value(&x->s, i, 0, &n);
    const RClass *rc = &x->m->classes[x->m->qclass[g->q]];
    if ((long)n != rc->n) {
      fprintf(stderr, "error: %s: '%s' has %zu entries per sample, the model was trained with %ld\n", g->path,
              g->sym->name, n, rc->n);
      return -1;
    }
  }
  return 0;
}

/* Project the inputs of sample k and evaluate the reduced model. */
static int reduced_sample(Session *x, long k) {
  for (int i = 0; i < x->s.n; i++)
    if (x->s.files[i].sym->kind == SYM_INPUT) reduced_project(x->r, x->s.files[i].q, samples_value(&x->s, i, k, NULL));
  return reduced_eval(x->r, k);
}

/* ---------------------------------------------------------------- eval (reduced) */

static int cmd_eval_reduced(Common *c) {
  if (!c->prog_path || !c->a || !c->b || !c->out) return usage("eval");
  Session x;
  int rc = 1;
  double **lifted = NULL, **coords = NULL;
  if (open_session(c, &x, false) != 0) goto done;
  const Model *m = x.m;
  int no = x.prog->outputs.n;
  lifted = calloc((size_t)no + 1, sizeof(double *));
  coords = calloc((size_t)no + 1, sizeof(double *));
  if (!lifted || !coords) goto oom;
  for (int o = 0; o < no; o++) {
    const Sym *s = x.prog->outputs.v[o];
    int q = emit_index_of(&x.prog->quantities, s);
    if (q < 0) continue;
    const RClass *rc = &m->classes[m->qclass[q]];
    lifted[o] = malloc(sizeof(double) * (size_t)(rc->n * x.s.count + 1));
    coords[o] = malloc(sizeof(double) * (size_t)(rc->m * x.s.count + 1));
    if (!lifted[o] || !coords[o]) goto oom;
  }
  for (long k = 0; k < x.s.count; k++) {
    if (reduced_sample(&x, k) != 0) {
      fprintf(stderr, "error: %s\n", reduced_error(x.r));
      goto done;
    }
    for (int o = 0; o < no; o++) {
      int q = emit_index_of(&x.prog->quantities, x.prog->outputs.v[o]);
      if (q < 0) continue;
      const RClass *rc = &m->classes[m->qclass[q]];
      reduced_lift(x.r, q, lifted[o] + k * rc->n);
      memcpy(coords[o] + k * rc->m, reduced_coords(x.r, q), sizeof(double) * (size_t)rc->m);
    }
    progress_show(c->train.progress && x.s.count > 1, "reduced evaluation", k + 1, x.s.count);
  }
  if (mkdir(c->out, 0777) != 0 && errno != EEXIST) {
    fprintf(stderr, "error: cannot create %s: %s\n", c->out, strerror(errno));
    goto done;
  }
  for (int o = 0; o < no; o++) {
    const Sym *s = x.prog->outputs.v[o];
    int q = emit_index_of(&x.prog->quantities, s);
    if (q < 0) {
      fprintf(stderr, "note: output op '%s' is not written by eval\n", s->name);
      continue;
    }
    const RClass *rc = &m->classes[m->qclass[q]];
    long shape[NPY_MAX_DIMS];
    int nd = 0;
    shape[nd++] = x.s.count;
    for (int i = 0; i < s->ndims && nd < NPY_MAX_DIMS; i++)
      shape[nd++] = m->dims[emit_index_of(&x.prog->dims, s->dims[i])];
    for (int i = 0; i < s->nstatic && nd < NPY_MAX_DIMS; i++) shape[nd++] = s->shape[i];
    char path[4096], err[2048];
    snprintf(path, sizeof path, "%s/%s.npy", c->out, s->name);
    if (npy_write(path, NPY_F64, nd, shape, lifted[o], err, sizeof err) != 0) {
      fprintf(stderr, "error: %s\n", err);
      goto done;
    }
    long cs[2] = {x.s.count, rc->m};
    snprintf(path, sizeof path, "%s/%s.reduced.npy", c->out, s->name);
    if (npy_write(path, NPY_F64, 2, cs, coords[o], err, sizeof err) != 0) {
      fprintf(stderr, "error: %s\n", err);
      goto done;
    }
  }
  rc = 0;
  goto done;
oom:
  fputs("error: out of memory\n", stderr);
done:
  for (int o = 0; lifted && o < x.prog->outputs.n; o++) free(lifted[o]);
  for (int o = 0; coords && o < x.prog->outputs.n; o++) free(coords[o]);
  free(lifted);
  free(coords);
  close_session(&x);
  return rc;
}

/* ---------------------------------------------------------------- verify */

typedef struct ErrStat {
  double l2, linf, floor2, floorinf;    /* sums over samples (means at the end) */
  double l2max, linfmax;
} ErrStat;

/* Quantities a stage reads (tensor inputs, named numerators), for "where
 * error grows". */
static double worst_input(const Model *m, const RStage *rs, const ErrStat *st, long S) {
  double w = 0;
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    if (rt->named_q >= 0) w = fmax(w, st[rt->named_q].l2 / (double)S);
    for (int k = -1; k < rt->nops; k++) {
      int n = k < 0 ? rt->nnum : rt->ops[k].ntensors;
      for (int g = 0; g < n; g++) {
        const RTensor *x = k < 0 ? &rt->num[g] : &rt->ops[k].t[g];
        for (int j = 0; j < x->nin; j++) w = fmax(w, st[x->in_q[j]].l2 / (double)S);
      }
    }
  }
  if (rs->st->kind == ST_EXTERN)
    for (int i = 0; i < m->nexterns; i++)
      if (m->externs[i].q == rs->q)
        for (int j = 0; j < m->externs[i].nin; j++) w = fmax(w, st[m->externs[i].in_q[j]].l2 / (double)S);
  return w;
}

/* The exactness checks of DESIGN §4 (exact.h): 0 pass, 1 fail or error. */
static int verify_exact(Common *c) {
  NpgProgram *p = compile(c);
  if (!p) return 1;
  ExactOptions o = {c->exact_size, c->exact_size, 1u, c->cc ? NPG_CC : NPG_TCC, c->train.progress};
  char err[2048] = "";
  fflush(stdout);
  int rc = exact_check(p, &o, stdout, err, sizeof err);
  if (rc < 0)
    fprintf(stderr, "error: exactness checks of %s: %s%s\n", c->prog_path, err,
            strstr(err, "not finite") || strstr(err, "singular") || strstr(err, "indefinite")
                ? " (random data can be degenerate at small sizes, e.g. meshes with too few vertices: try a larger "
                  "--exact-size)"
                : "");
  npg_free(p);
  return rc == 0 ? 0 : 1;
}

static int cmd_verify(Common *c) {
  if (c->exact && c->prog_path && !c->a && !c->b && !c->out) return verify_exact(c);
  if (!c->prog_path || !c->a || !c->b || c->out) return usage("verify");
  Session x;
  int rc = 1;
  ErrStat *st = NULL;
  double *y = NULL, *proj = NULL;
  if (open_session(c, &x, true) != 0) goto done;
  Model *m = x.m;
  long maxn = 1, maxm = 1;
  for (int k = 0; k < m->nclasses; k++) {
    maxn = m->classes[k].n > maxn ? m->classes[k].n : maxn;
    maxm = m->classes[k].m > maxm ? m->classes[k].m : maxm;
  }
  st = calloc((size_t)m->nq + 1, sizeof *st);
  y = malloc(sizeof(double) * (size_t)maxn);
  proj = malloc(sizeof(double) * (size_t)maxm);
  if (!st || !y || !proj) {
    fputs("error: out of memory\n", stderr);
    goto done;
  }
  long S = x.s.count;
  for (long k = 0; k < S; k++) {
    if (samples_set(&x.s, x.f, k) != 0 || npg_full_eval(x.f, k) != 0) {
      fprintf(stderr, "error: %s\n", npg_full_error(x.f));
      goto done;
    }
    if (reduced_sample(&x, k) != 0) {
      fprintf(stderr, "error: %s\n", reduced_error(x.r));
      goto done;
    }
    for (int q = 0; q < m->nq; q++) {
      const RClass *rc = &m->classes[m->qclass[q]];
      const double *full = npg_full_get(x.f, ((Sym *)x.prog->quantities.v[q])->name, NULL);
      /* ‖y − B ŷ‖ and the projection floor ‖y − B Bᵀ y‖ (Arvo's discretization error) */
      double ny = 0, nyinf = 0, e2 = 0, einf = 0, f2 = 0, finf = 0;
      reduced_lift(x.r, q, y);
      for (long e = 0; e < rc->n; e++) {
        double d = full[e] - y[e];
        ny += full[e] * full[e];
        nyinf = fmax(nyinf, fabs(full[e]));
        e2 += d * d;
        einf = fmax(einf, fabs(d));
      }
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)rc->m, 1.0, rc->B, (int)rc->m, full, 1, 0.0, proj, 1);
      cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)rc->n, (int)rc->m, 1.0, rc->B, (int)rc->m, proj, 1, 0.0, y, 1);
      for (long e = 0; e < rc->n; e++) {
        double d = full[e] - y[e];
        f2 += d * d;
        finf = fmax(finf, fabs(d));
      }
      double l2 = ny > 0 ? sqrt(e2 / ny) : sqrt(e2), linf = nyinf > 0 ? einf / nyinf : einf;
      st[q].l2 += l2;
      st[q].linf += linf;
      st[q].floor2 += ny > 0 ? sqrt(f2 / ny) : sqrt(f2);
      st[q].floorinf += nyinf > 0 ? finf / nyinf : finf;
      st[q].l2max = fmax(st[q].l2max, l2);
      st[q].linfmax = fmax(st[q].linfmax, linf);
    }
    progress_show(c->train.progress, "verification", k + 1, S);
  }
  printf("verify %s against %s on %ld held-out samples (relative errors, mean over samples)\n", c->prog_path, c->a, S);
  printf("%-14s %-7s %5s %10s %10s %10s %10s %10s %10s\n", "quantity", "kind", "m", "L2 error", "floor", "own",
         "max L2", "Linf error", "Linf floor");
  double worst_growth = 0;
  const char *grows_at = NULL;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = x.prog->quantities.v[q];
    const ErrStat *e = &st[q];
    const char *kind = s->kind == SYM_INPUT ? "input" : s->kind == SYM_EXTERN ? "extern" : "stage";
    for (int i = 0; i < m->nstages; i++)
      if (m->stages[i].q == q && m->stages[i].st->kind != ST_EXTERN) kind = stage_kind_name[m->stages[i].st->kind];
    printf("%-14s %-7s %5ld %10.3e %10.3e %10.3e %10.3e %10.3e %10.3e%s\n", s->name, kind,
           m->classes[m->qclass[q]].m, e->l2 / (double)S, e->floor2 / (double)S, (e->l2 - e->floor2) / (double)S,
           e->l2max, e->linf / (double)S, e->floorinf / (double)S, s->is_output ? "  (output)" : "");
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    double g = st[rs->q].l2 / (double)S - worst_input(m, rs, st, S);
    if (g > worst_growth) {
      worst_growth = g;
      grows_at = rs->st->sym->name;
    }
  }
  if (grows_at)
    printf("error grows most at stage %s (+%.3e over the worst quantity it reads)\n", grows_at, worst_growth);
  rc = 0;
  for (int o = 0; o < x.prog->outputs.n; o++) {
    int q = emit_index_of(&x.prog->quantities, x.prog->outputs.v[o]);
    if (q < 0) continue;
    double e = st[q].l2 / (double)S;
    if (e > c->tol) {
      printf("FAIL: output %s: mean relative L2 error %.3e above --tol %.3g\n",
             ((Sym *)x.prog->outputs.v[o])->name, e, c->tol);
      rc = 1;
    }
  }
  if (rc == 0) printf("ok: every output within --tol %.3g\n", c->tol);
  if (c->exact) {
    printf("\n");
    rc |= verify_exact(c);
  }
done:
  free(st);
  free(y);
  free(proj);
  close_session(&x);
  return rc;
}

/* ---------------------------------------------------------------- bench */

static int cmd_bench(Common *c) {
  if (!c->prog_path || !c->a || !c->b || c->out) return usage("bench");
  Session x;
  int rc = 1;
  if (open_session(c, &x, true) != 0) goto done;
  long S = x.s.count;
  double tf = 0, tr = 0, tfbest = INFINITY, trbest = INFINITY;
  for (long k = 0; k < S; k++) {
    if (samples_set(&x.s, x.f, k) != 0) {
      fprintf(stderr, "error: %s\n", npg_full_error(x.f));
      goto done;
    }
    double t0 = now();
    if (npg_full_eval(x.f, k) != 0) {
      fprintf(stderr, "error: %s\n", npg_full_error(x.f));
      goto done;
    }
    double t1 = now();
    if (reduced_sample(&x, k) != 0) {
      fprintf(stderr, "error: %s\n", reduced_error(x.r));
      goto done;
    }
    double t2 = now();
    if (k > 0 || S == 1) { /* the first full evaluation also checks gathers */
      tf += t1 - t0;
      tr += t2 - t1;
      tfbest = fmin(tfbest, t1 - t0);
      trbest = fmin(trbest, t2 - t1);
    }
  }
  long n = S > 1 ? S - 1 : 1;
  size_t tb, total = model_bytes(x.m, &tb);
  printf("bench %s: %ld samples (%s backend for the full evaluator)\n", c->prog_path, S, c->cc ? "cc" : "libtcc");
  printf("full evaluation     %12.3e s per sample (best %.3e)\n", tf / (double)n, tfbest);
  printf("reduced evaluation  %12.3e s per sample (best %.3e), inputs projected, outputs not lifted\n",
         tr / (double)n, trbest);
  printf("speedup             %12.1fx (mean), %.1fx (best)\n", tf / tr, tfbest / trbest);
  printf("reduced model       %12.3f MB of reduced tensors, %.3f MB with bases and extern tables\n", (double)tb / 1e6,
         (double)total / 1e6);
  rc = 0;
done:
  close_session(&x);
  return rc;
}

int npgc_reduce(int argc, char **argv) {
  Common c;
  int rc = parse(&c, argc, argv);
  if (rc == 0) {
    if (strcmp(c.cmd, "train") == 0) rc = cmd_train(&c);
    else if (strcmp(c.cmd, "eval") == 0) rc = cmd_eval_reduced(&c);
    else if (strcmp(c.cmd, "verify") == 0) rc = cmd_verify(&c);
    else rc = cmd_bench(&c);
  }
  free_common(&c);
  return rc;
}
