/* eval.c — `npgc eval PROG.npg --full DATA/ IN/ -o OUT/`: evaluate the full
 * program on every sample of IN/ and write each output as OUT/<name>.npy
 * with a leading sample axis. Params come from DATA/<name>.npy; inputs and
 * externs from IN/<name>.npy (else DATA/), their first axis the samples.
 * An `output op` is written as CSR: OUT/<name>.indptr.npy and
 * OUT/<name>.indices.npy (its structure, the same for every sample) and
 * OUT/<name>.data.npy (samples x nonzeros). Every file is written to a
 * temporary name and renamed when complete, after all samples succeeded: a
 * failure leaves OUT/ as it was. With --jacobian OUT:IN (repeatable), the
 * Jacobian of quantity OUT with respect to input IN at every sample is written
 * as OUT/jacobian_<OUT>_<IN>.npy: samples x OUT's axes x IN's axes (DESIGN §17). */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "npg.h"
#include "npgc.h"

/* One output's values over every sample. */
typedef struct Out {
  NpgSymbol sym;
  double *v;                /* samples x count */
  size_t count;
  NpgCsr csr;               /* an op: the structure of sample 0 */
} Out;

static int keep(Out *o, NpgFull *f, long k, long samples) {
  size_t n = 0;
  const double *v;
  NpgCsr c = {0};
  if (o->sym.kind == NPG_OP) {
    if (npg_full_op(f, o->sym.name, &c) != 0) return -1;
    n = (size_t)c.nnz;
    v = c.data;
    if (k > 0 && (c.nnz != o->csr.nnz || memcmp(c.indptr, o->csr.indptr, sizeof(long) * (size_t)(c.rows + 1)) ||
                  memcmp(c.indices, o->csr.indices, sizeof(long) * (size_t)c.nnz))) {
      fprintf(stderr, "error: output op '%s': its sparsity differs between samples 0 and %ld\n", o->sym.name, k);
      npg_csr_free(&c);
      return -1;
    }
  } else {
    v = npg_full_get(f, o->sym.name, &n);
  }
  if (k == 0) {
    o->count = n;
    o->v = malloc(sizeof(double) * (n ? n : 1) * (size_t)samples);
  }
  int rc = 0;
  if (!o->v) {
    fputs("npgc eval: out of memory\n", stderr);
    rc = -1;
  } else if (n > 0) { /* an empty output's values may be NULL */
    memcpy(o->v + (size_t)k * n, v, sizeof(double) * n);
  }
  if (k == 0) o->csr = c;
  else npg_csr_free(&c);
  return rc;
}

static int write_out(const Out *o, NpgFull *f, const char *outdir, long samples) {
  char path[4096], err[1024];
  long shape[16];
  int nd = 0, rc = 0;
  shape[nd++] = samples;
  if (o->sym.kind == NPG_OP) {
    long ip[1] = {o->csr.rows + 1}, ix[1] = {o->csr.nnz};
    snprintf(path, sizeof path, "%s/%s.indptr.npy", outdir, o->sym.name);
    rc = npg_npy_write_i64(path, 1, ip, o->csr.indptr, err, sizeof err);
    snprintf(path, sizeof path, "%s/%s.indices.npy", outdir, o->sym.name);
    if (rc == 0) rc = npg_npy_write_i64(path, 1, ix, o->csr.indices, err, sizeof err);
    shape[nd++] = o->csr.nnz;
    snprintf(path, sizeof path, "%s/%s.data.npy", outdir, o->sym.name);
  } else {
    for (int i = 0; i < o->sym.ndims; i++) shape[nd++] = npg_full_dim(f, o->sym.dims[i]);
    for (int i = 0; i < o->sym.nstatic; i++) shape[nd++] = o->sym.shape[i];
    snprintf(path, sizeof path, "%s/%s.npy", outdir, o->sym.name);
  }
  if (rc == 0) rc = npg_npy_write(path, nd, shape, o->v, err, sizeof err);
  if (rc != 0) npgc_error(err);
  return rc;
}

/* One --jacobian OUT:IN: the derivative of `out` by input `in` at every sample. */
#define MAX_JACOBIANS 16
typedef struct Jac {
  char out[256], in[256];
  NpgSymbol so, si;
  double *v;                /* samples x count(out) x count(in) */
  size_t nout, nin;
} Jac;

/* "OUT:IN" into j, checked against the program: OUT a quantity (an input or a stage), IN an
 * input. 0, or -1 after a message naming the option. */
static int jac_parse(NpgProgram *p, const char *spec, Jac *j) {
  const char *colon = strchr(spec, ':');
  size_t lo = colon ? (size_t)(colon - spec) : 0;
  if (!colon || lo == 0 || !colon[1] || lo >= sizeof j->out || strlen(colon + 1) >= sizeof j->in) {
    fprintf(stderr, "npgc eval: --jacobian '%s': expected OUT:IN (a stage or output, then an input)\n", spec);
    return -1;
  }
  memcpy(j->out, spec, lo);
  j->out[lo] = 0;
  strcpy(j->in, colon + 1);
  bool found_out = false, found_in = false;
  for (int i = 0; i < npg_nsymbols(p); i++) {
    NpgSymbol s;
    if (npg_symbol(p, i, &s) != 0) continue;
    if (strcmp(s.name, j->out) == 0 && (s.kind == NPG_INPUT || s.kind == NPG_STAGE)) j->so = s, found_out = true;
    if (strcmp(s.name, j->in) == 0 && s.kind == NPG_INPUT) j->si = s, found_in = true;
  }
  if (!found_out || !found_in) {
    fprintf(stderr, "npgc eval: --jacobian '%s': %s '%s' %s\n", spec, found_out ? "input" : "quantity",
            found_out ? j->in : j->out,
            found_out ? "is not an input of the program (derivatives are taken with respect to inputs)"
                      : "is not a stage or input of the program");
    return -1;
  }
  return 0;
}

/* Jacobian `j` at sample k of `samples` (allocated at sample 0). */
static int jac_keep(Jac *j, NpgFull *f, long k, long samples) {
  if (k == 0) {
    npg_full_get(f, j->out, &j->nout);
    npg_full_get(f, j->in, &j->nin);
    size_t n = j->nout * j->nin;
    if (!(j->v = malloc(sizeof(double) * (n ? n : 1) * (size_t)samples))) {
      fputs("npgc eval: out of memory\n", stderr);
      return -1;
    }
  }
  if (npg_full_jacobian(f, k, j->out, j->in, j->v + (size_t)k * j->nout * j->nin) != 0) {
    npgc_error(npg_full_error(f));
    return -1;
  }
  return 0;
}

static int jac_write(const Jac *j, NpgFull *f, const char *outdir, long samples) {
  char path[4096], err[1024];
  long shape[40];
  int nd = 0;
  shape[nd++] = samples;
  const NpgSymbol *sy[2] = {&j->so, &j->si};
  for (int k = 0; k < 2; k++) {
    for (int i = 0; i < sy[k]->ndims; i++) shape[nd++] = npg_full_dim(f, sy[k]->dims[i]);
    for (int i = 0; i < sy[k]->nstatic; i++) shape[nd++] = sy[k]->shape[i];
  }
  snprintf(path, sizeof path, "%s/jacobian_%s_%s.npy", outdir, j->out, j->in);
  int rc = npg_npy_write(path, nd, shape, j->v, err, sizeof err);
  if (rc != 0) npgc_error(err);
  return rc;
}

static int eval_full(NpgProgram *p, const char *data, const char *in, const char *outdir, NpgBackend backend, bool progress,
                     Jac *jacs, int njac) {
  int rc = 1, nout = 0;
  char err[2048] = "";
  NpgFull *f = npg_full_new(p, backend);
  NpgSamples *s = NULL;
  Out *outs = calloc((size_t)npg_nsymbols(p) + 1, sizeof *outs);
  if (!outs) {
    fputs("npgc eval: out of memory\n", stderr);
    goto done;
  }
  for (int i = 0; i < npg_nsymbols(p); i++)
    if (npg_symbol(p, i, &outs[nout].sym) == 0 && outs[nout].sym.output) nout++;
  /* IN/ falls back to DATA/ file by file, so a mistyped IN/ would silently
   * evaluate the training data: both must be directories */
  struct stat st;
  for (int i = 0; i < 2; i++)
    if (stat(i ? in : data, &st) != 0 || !S_ISDIR(st.st_mode)) {
      bool found = stat(i ? in : data, &st) == 0;
      fprintf(stderr, "error: %s (%s): %s\n", i ? in : data, i ? "IN/" : "DATA/",
              found ? "not a directory" : strerror(errno));
      goto done;
    }
  if (npg_full_error(f)[0] || npg_full_bind_params(f, data) != 0) {
    npgc_error(npg_full_error(f));
    goto done;
  }
  if (!(s = npg_samples_open(p, in, data, true, err, sizeof err))) {
    npgc_error(err);
    goto done;
  }
  long samples = npg_samples_count(s);
  /* no samples: every output is empty, of the shape the files' dims give it (without this, a dim that only
   * inputs bind stayed unbound and a zero-sample output was refused as "shape entry 1 is negative (-1)") */
  if (samples == 0 && npg_samples_bind_dims(s, f) != 0) {
    npgc_error(npg_full_error(f));
    goto done;
  }
  for (int o = 0; samples == 0 && o < nout; o++)
    if (outs[o].sym.kind == NPG_OP) {
      fprintf(stderr, "error: %s: no samples, and output op '%s' takes its sparsity structure from one: give a sample "
                      "(or leave it out of the outputs)\n", in, outs[o].sym.name);
      goto done;
    }
  bool tty = progress || isatty(2);
  for (long k = 0; k < samples; k++) {
    if (npg_samples_set(s, f, k) != 0 || npg_full_eval(f, k) != 0 || npg_full_check_finite(f, k) != 0) {
      if (tty) fputc('\n', stderr);
      npgc_error(npg_full_error(f));
      goto done;
    }
    for (int o = 0; o < nout; o++)
      if (keep(&outs[o], f, k, samples) != 0) {
        if (npg_full_error(f)[0]) npgc_error(npg_full_error(f));
        goto done;
      }
    for (int j = 0; j < njac; j++)
      if (jac_keep(&jacs[j], f, k, samples) != 0) goto done;
    npg_progress(tty, "full evaluation", k + 1, samples);
  }
  if (npgc_make_parents(outdir, true) != 0) goto done;
  for (int o = 0; o < nout; o++)
    if (write_out(&outs[o], f, outdir, samples) != 0) goto done;
  for (int j = 0; j < njac && samples > 0; j++)
    if (jac_write(&jacs[j], f, outdir, samples) != 0) goto done;
  rc = 0;
done:
  for (int o = 0; outs && o < nout; o++) {
    free(outs[o].v);
    npg_csr_free(&outs[o].csr);
  }
  free(outs);
  npg_samples_free(s);
  npg_full_free(f);
  return rc;
}

int npgc_eval(int argc, char **argv) {
  const char *prog_path = NULL, *data = NULL, *in = NULL, *outdir = NULL;
  bool full = false, progress = false, exact_roots = false, sizes = false;
  const char *jac_specs[MAX_JACOBIANS];
  int njac = 0;
  NpgBackend backend = NPG_AUTO;
  NpgOptions opt = {0};
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npgc eval");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage("eval", true);
    if (npg_args_flag(&a, "--full")) full = true;
    else if (npg_args_backend(&a, &backend)) ;
    else if (npg_args_flag(&a, "--progress")) progress = true;
    else if (npg_args_flag(&a, "--exact-roots")) exact_roots = true; /* the reduced evaluation's */
    else if (npg_args_string(&a, "--sizes")) sizes = true;           /* the reduced evaluation's too */
    else if ((v = npg_args_string(&a, "-o"))) outdir = v;
    else if ((v = npg_args_string(&a, "--jacobian"))) {
      if (njac == MAX_JACOBIANS) {
        fprintf(stderr, "npgc eval: --jacobian given more than %d times\n", MAX_JACOBIANS);
        return 2;
      }
      jac_specs[njac++] = v;
    }
    else if ((v = npg_args_string(&a, "--std"))) opt.std_dir = v;
    else if ((v = npg_args_positional(&a))) {
      if (!prog_path) prog_path = v;
      else if (!data) data = v;
      else if (!in) in = v;
      else npgc_args_extra(&a, "input folder", in);
    } else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, "eval");
  if (!prog_path) return npgc_missing("eval", "the program (PROG.npg)");
  if (!data && full) return npgc_missing("eval", "DATA/ (the params of the full evaluation, after --full)");
  if (!data) return npgc_missing("eval", "MODEL/ (a model trained by npgc train), or --full DATA/ for the full evaluation");
  if (!in && !full)
    return npgc_missing("eval", "a folder: after the program come MODEL/ IN/ (the reduced evaluation) or --full DATA/ "
                                "IN/ (the full one); one folder was given");
  if (!in) return npgc_missing("eval", "IN/ (the inputs to evaluate, a leading sample axis)");
  if (!outdir) return npgc_missing("eval", "-o OUT/ (where to write the outputs)");
  if (!full) return npgc_reduce(argc, argv);
  if (exact_roots || sizes) {
    fprintf(stderr, "npgc eval: %s is an option of the reduced evaluation (with MODEL/), not of --full\n",
            exact_roots ? "--exact-roots" : "--sizes");
    return 2;
  }
  const char *inputs[] = {prog_path, data, in, NULL};
  if (npgc_check_output("eval", "-o", outdir, NPGC_OUT_DIR, inputs) != 0) return 1;
  NpgProgram *p = npg_compile(prog_path, &opt);
  int rc = 1;
  if (!npg_ok(p)) fputs(npg_error(p), stderr);
  else {
    Jac *jacs = calloc((size_t)njac + 1, sizeof *jacs);
    if (!jacs) fputs("npgc eval: out of memory\n", stderr);
    bool ok = jacs != NULL;
    for (int j = 0; j < njac && ok; j++) ok = jac_parse(p, jac_specs[j], &jacs[j]) == 0;
    rc = ok ? eval_full(p, data, in, outdir, backend, progress, jacs, njac) : 2;
    for (int j = 0; jacs && j < njac; j++) free(jacs[j].v);
    free(jacs);
  }
  npg_free(p);
  return rc;
}
