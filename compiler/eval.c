/* eval.c — `npgc eval PROG.npg --full DATA/ IN/ -o OUT/`: evaluate the full
 * program on every sample of IN/ and write each output as OUT/<name>.npy
 * with a leading sample axis. Params come from DATA/<name>.npy; inputs and
 * externs from IN/<name>.npy (else DATA/), their first axis the samples.
 * Every output is written to a temporary name and renamed when complete,
 * after all samples succeeded: a failure leaves OUT/ as it was. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "compile.h"
#include "npg.h"
#include "npy.h"

typedef struct Given {
  const Sym *sym;
  NpyArray a;
  char path[4096];
} Given;

static int usage(void) {
  fputs("usage: npgc eval PROG.npg --full DATA/ IN/ -o OUT/ [--cc]\n", stderr);
  return 2;
}

static bool exists(const char *path) {
  struct stat st;
  return stat(path, &st) == 0;
}

int npgc_eval(int argc, char **argv) {
  const char *prog_path = NULL, *data = NULL, *in = NULL, *outdir = NULL;
  bool full = false, cc = false;
  NpgOptions opt = {0};
  for (int i = 2; i < argc; i++) {
    if (strcmp(argv[i], "--full") == 0) full = true;
    else if (strcmp(argv[i], "--cc") == 0) cc = true;
    else if (strcmp(argv[i], "-o") == 0 && i + 1 < argc) outdir = argv[++i];
    else if (strncmp(argv[i], "--std=", 6) == 0) opt.std_dir = argv[i] + 6;
    else if (argv[i][0] == '-') {
      fprintf(stderr, "npgc eval: unknown option '%s'\n", argv[i]);
      return usage();
    } else if (!prog_path) prog_path = argv[i];
    else if (!data) data = argv[i];
    else if (!in) in = argv[i];
    else return usage();
  }
  if (!prog_path || !data || !in || !outdir) return usage();
  if (!full) return npgc_reduce(argc, argv);
  NpgProgram *p = npg_compile(prog_path, &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  Program *prog = npg_program_ir(p);
  int rc = 1;
  NpgFull *f = npg_full_new(p, cc ? NPG_CC : NPG_TCC);
  Given *given = calloc((size_t)prog->slots.n + 1, sizeof *given);
  int ngiven = 0;
  double **outs = calloc((size_t)prog->outputs.n + 1, sizeof *outs);
  size_t *outcount = calloc((size_t)prog->outputs.n + 1, sizeof *outcount);
  char err[1024];
  long samples = -1;
  const char *samples_from = NULL;
  if (!given || !outs || !outcount) {
    fputs("npgc eval: out of memory\n", stderr);
    goto done;
  }
  if (npg_full_error(f)[0] || npg_full_bind_params(f, data) != 0) {
    fprintf(stderr, "error: %s\n", npg_full_error(f));
    goto done;
  }
  /* Inputs and externs, every sample at once. */
  for (int i = 0; i < prog->slots.n; i++) {
    const Sym *s = prog->slots.v[i];
    if (s->kind != SYM_INPUT && s->kind != SYM_EXTERN) continue;
    Given *gv = &given[ngiven];
    gv->sym = s;
    snprintf(gv->path, sizeof gv->path, "%s/%s.npy", in, s->name);
    if (!exists(gv->path)) snprintf(gv->path, sizeof gv->path, "%s/%s.npy", data, s->name);
    if (npy_read(gv->path, &gv->a, err, sizeof err) != 0) {
      fprintf(stderr, "error: %s\n", err);
      goto done;
    }
    ngiven++;
    if (gv->a.type != NPY_F64) {
      fprintf(stderr, "error: %s: %s '%s' must be float64, the array is %s\n", gv->path,
              s->kind == SYM_INPUT ? "input" : "extern", s->name, npy_type_name(gv->a.type));
      goto done;
    }
    if (gv->a.ndim < 1) {
      fprintf(stderr, "error: %s: expected a leading sample axis, the array is 0-d\n", gv->path);
      goto done;
    }
    if (samples < 0) {
      samples = gv->a.shape[0];
      samples_from = gv->path;
    } else if (gv->a.shape[0] != samples) {
      fprintf(stderr, "error: %s has %ld samples but %s has %ld\n", samples_from, samples, gv->path, gv->a.shape[0]);
      goto done;
    }
  }
  if (samples < 0) samples = 1; /* a program without inputs: one evaluation */
  bool tty = isatty(2);
  for (long k = 0; k < samples; k++) {
    for (int i = 0; i < ngiven; i++) {
      Given *gv = &given[i];
      size_t per = gv->a.count / (size_t)(samples ? samples : 1);
      if (npg_full_set(f, gv->sym->name, gv->a.ndim - 1, gv->a.shape + 1, (double *)gv->a.data + (size_t)k * per,
                       gv->path) != 0)
        break;
    }
    if (npg_full_eval(f, k) != 0) {
      if (tty) fputc('\n', stderr);
      fprintf(stderr, "error: %s\n", npg_full_error(f));
      goto done;
    }
    for (int o = 0; o < prog->outputs.n; o++) {
      const Sym *s = prog->outputs.v[o];
      if (s->kind == SYM_OP) continue;
      size_t n;
      const double *v = npg_full_get(f, s->name, &n);
      if (!outs[o]) {
        outcount[o] = n;
        outs[o] = malloc(sizeof(double) * (n ? n : 1) * (size_t)samples);
        if (!outs[o]) {
          fputs("npgc eval: out of memory\n", stderr);
          goto done;
        }
      }
      memcpy(outs[o] + (size_t)k * n, v, sizeof(double) * n);
    }
    if (tty && (k + 1 == samples || k % 16 == 0)) fprintf(stderr, "\rfull evaluation: sample %ld/%ld", k + 1, samples);
  }
  if (tty) fputc('\n', stderr);
  if (mkdir(outdir, 0777) != 0 && errno != EEXIST) {
    fprintf(stderr, "error: cannot create %s: %s\n", outdir, strerror(errno));
    goto done;
  }
  for (int o = 0; o < prog->outputs.n; o++) {
    const Sym *s = prog->outputs.v[o];
    if (s->kind == SYM_OP) {
      fprintf(stderr, "note: output op '%s' is not written by eval --full\n", s->name);
      continue;
    }
    long shape[NPY_MAX_DIMS];
    int nd = 0;
    shape[nd++] = samples;
    for (int i = 0; i < s->ndims && nd < NPY_MAX_DIMS; i++) shape[nd++] = npg_full_dim(f, s->dims[i]->name);
    for (int i = 0; i < s->nstatic && nd < NPY_MAX_DIMS; i++) shape[nd++] = s->shape[i];
    char path[4096];
    snprintf(path, sizeof path, "%s/%s.npy", outdir, s->name);
    if (npy_write(path, NPY_F64, nd, shape, outs[o], err, sizeof err) != 0) {
      fprintf(stderr, "error: %s\n", err);
      goto done;
    }
  }
  rc = 0;
done:
  for (int i = 0; i < ngiven; i++) npy_free(&given[i].a);
  for (int o = 0; outs && o < prog->outputs.n; o++) free(outs[o]);
  free(outs);
  free(outcount);
  free(given);
  npg_full_free(f);
  npg_free(p);
  return rc;
}
