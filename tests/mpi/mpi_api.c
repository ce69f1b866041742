/* mpi_api.c — training over MPI ranks through npg.h (NpgTrainOptions.mpi),
 * with the extern given by a C callback, as a simulation with a ray caster
 * would train:
 *
 *     mpirun -np N mpi_api PROG.npg DATA/ MODEL/ [--mpi]
 *
 * stages every input of every sample of DATA/ and adds it; the extern `v`
 * comes from a callback reading DATA/v.npy (the ray caster's stand-in).
 * With --mpi the callback must run on this rank for its own samples
 * k ≡ rank (mod N) alone (and sample 0, which binds the dims), and each rank must get the same model (rank 0
 * writes MODEL/); exit 1 otherwise. tests/mpi/mpi.sh compares MODEL/ with
 * the one-process model. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"

typedef struct Calls {
  const NpgSamples *s;
  long n, wrong;            /* calls, and calls for a sample of another rank */
  int rank, size;
} Calls;

static int visibility(void *user, const NpgFull *f, long sample, double *out, size_t count) {
  Calls *c = user;
  size_t n;
  const double *v = npg_samples_get(c->s, "v", sample, &n);
  if (!v || n != count) return -1;
  memcpy(out, v, sizeof(double) * n);
  c->n++;
  if (c->size > 1 && sample > 0 && sample % c->size != c->rank) c->wrong++;
  return 0;
}

int main(int argc, char **argv) {
  if (argc < 4) {
    fprintf(stderr, "usage: mpi_api PROG.npg DATA/ MODEL/ [--mpi] [--mem BYTES]\n");
    return 2;
  }
  bool mpi = false;
  size_t mem = 0; /* --mem: out of core when the bases exceed it */
  for (int i = 4; i < argc; i++)
    if (strcmp(argv[i], "--mpi") == 0) mpi = true;
    else if (strcmp(argv[i], "--mem") == 0 && i + 1 < argc) mem = (size_t)atol(argv[++i]);
  char err[2048];
  NpgProgram *p = npg_compile(argv[1], NULL);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    return 1;
  }
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgSamples *s = npg_samples_open(p, argv[2], NULL, true, err, sizeof err);
  if (!s || npg_full_bind_params(f, argv[2]) != 0) {
    fprintf(stderr, "mpi_api: %s\n", s ? npg_full_error(f) : err);
    return 1;
  }
  Calls calls = {s, 0, 0, 0, 1};
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.mpi = mpi;
  if (mem) o.mem = mem;
  NpgTrainer *t = npg_trainer_new(f, &o);
  if (npg_trainer_error(t)[0]) {
    fprintf(stderr, "mpi_api: %s\n", npg_trainer_error(t));
    return 1;
  }
  npg_full_set_extern_fn(f, "v", visibility, &calls);
  calls.rank = npg_mpi_rank();
  calls.size = npg_mpi_size();
  /* every input of every sample, staged by name */
  for (long k = 0; k < npg_samples_count(s); k++) {
    for (int i = 0; i < npg_nsymbols(p); i++) {
      NpgSymbol sym;
      npg_symbol(p, i, &sym);
      if (sym.kind != NPG_INPUT) continue;
      long shape[12];
      int nd = 0;
      for (int d = 0; d < sym.ndims; d++) shape[nd++] = npg_full_dim(f, sym.dims[d]);
      for (int d = 0; d < sym.nstatic; d++) shape[nd++] = sym.shape[d];
      size_t n;
      const double *v = npg_samples_get(s, sym.name, k, &n);
      if (shape[0] < 0) shape[0] = (long)n / (nd > 1 ? shape[1] : 1); /* a dim only this input binds */
      if (npg_trainer_set(t, sym.name, nd, shape, v) != 0) break;
    }
    if (npg_trainer_add(t) != 0) break;
  }
  NpgModel *m = npg_trainer_error(t)[0] ? NULL : npg_trainer_finish(t, argv[3]);
  if (!m) {
    fprintf(stderr, "mpi_api: %s\n", npg_trainer_error(t));
    return 1;
  }
  int rc = 0;
  /* its own samples, and sample 0 (every rank binds the dims with it) */
  long S = npg_samples_count(s), own = (S - calls.rank + calls.size - 1) / calls.size + (calls.rank > 0);
  if (calls.wrong || calls.n != own) {
    fprintf(stderr, "mpi_api: rank %d of %d: the extern callback ran %ld times (%ld for other ranks' samples), "
                    "expected %ld\n", calls.rank, calls.size, calls.n, calls.wrong, own);
    rc = 1;
  } else if (calls.rank == 0) {
    printf("mpi_api: %ld samples over %d rank(s), the extern called %ld times on rank 0\n", S, calls.size, calls.n);
  }
  npg_model_free(m);
  npg_trainer_free(t);
  npg_samples_free(s);
  npg_full_free(f);
  npg_free(p);
  return rc;
}
