/* trajectories.c — the inputs of rollouts read from a folder (npgc simulate, and train, verify
 * and bench with --steps): every input's file holds one value per trajectory, [S, ...], held for
 * every step, or one per step, [S, T', ...] with T' at least the steps run; a state holds its
 * initial value, [S, ...]. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npgc.h"

void npgc_trajectories_free(Trajectories *t) {
  for (int i = 0; i < t->n; i++) free(t->in[i].v);
  free(t->in);
  memset(t, 0, sizeof *t);
}

int npgc_trajectories_open(NpgProgram *p, const char *dir, long steps, Trajectories *t, char *err, size_t errlen) {
  memset(t, 0, sizeof *t);
  t->samples = -1;
  int n = npg_nsymbols(p);
  if (!(t->in = calloc((size_t)n + 1, sizeof *t->in))) return snprintf(err, errlen, "out of memory"), -1;
  for (int i = 0; i < n; i++) {
    NpgSymbol sym;
    if (npg_symbol(p, i, &sym) != 0) continue;
    if (sym.kind == NPG_EXTERN) {
      snprintf(err, errlen, "extern '%s': rollouts of programs with externs are not supported (a learned map "
               "would be stepped outside its training states); evaluate it in the program or step with npg.h", sym.name);
      goto fail;
    }
    if (sym.kind != NPG_INPUT || sym.state_of) continue; /* u.next of an implicit step: the step solves it */
    TrajInput *in = &t->in[t->n++];
    in->sym = sym;
    snprintf(in->path, sizeof in->path, "%s/%s.npy", dir, sym.name);
    size_t count;
    if (!(in->v = npg_npy_read(in->path, &in->ndim, in->shape, &count, err, errlen))) goto fail;
    int rank = sym.ndims + sym.nstatic, lead = in->ndim - rank;
    if (lead != 1 && (lead != 2 || sym.next)) {
      snprintf(err, errlen, "%s: %s '%s' is %d-dimensional, so its file holds [samples, ...] (%d axes)%s; it has %d",
               in->path, sym.next ? "state" : "input", sym.name, rank, rank + 1,
               sym.next ? " with the initial value of each trajectory" : " or [samples, steps, ...] (one value per step)",
               in->ndim);
      goto fail;
    }
    in->per_step = lead == 2;
    in->axes = in->ndim - lead;
    in->each = 1;
    for (int k = lead; k < in->ndim; k++) in->each *= (size_t)in->shape[k];
    if (t->samples >= 0 && in->shape[0] != t->samples) {
      snprintf(err, errlen, "%s: %ld trajectories, but %s holds %ld", in->path, in->shape[0], t->in[0].path,
               t->samples);
      goto fail;
    }
    t->samples = in->shape[0];
    if (in->per_step && in->shape[1] < steps) {
      snprintf(err, errlen, "%s: input '%s' is given per step for %ld steps, fewer than the %ld to run", in->path,
               sym.name, in->shape[1], steps);
      goto fail;
    }
  }
  if (t->n == 0 || t->samples < 0) {
    snprintf(err, errlen, "%s: the program has no input to read", dir);
    goto fail;
  }
  return 0;
fail:
  npgc_trajectories_free(t);
  return -1;
}

const double *npgc_trajectory_value(const TrajInput *in, long k, long step) {
  size_t at = in->per_step ? (size_t)k * (size_t)in->shape[1] + (size_t)step : (size_t)k;
  return in->v + at * in->each;
}

int npgc_trajectories_set_full(const Trajectories *t, NpgFull *f, long k, long step, bool all) {
  for (int i = 0; i < t->n; i++) {
    const TrajInput *in = &t->in[i];
    if (!all && !in->per_step) continue;
    char from[4200];
    if (in->per_step) snprintf(from, sizeof from, "%s, trajectory %ld, step %ld", in->path, k, step);
    else snprintf(from, sizeof from, "%s, trajectory %ld", in->path, k);
    if (npg_full_set(f, in->sym.name, in->axes, in->shape + (in->ndim - in->axes), npgc_trajectory_value(in, k, step),
                     from) != 0)
      return -1;
  }
  return 0;
}

int npgc_trajectories_set_reduced(const Trajectories *t, NpgReduced *r, long k, long step, bool all) {
  for (int i = 0; i < t->n; i++) {
    const TrajInput *in = &t->in[i];
    if ((all || in->per_step) && npg_reduced_set(r, in->sym.name, in->each, npgc_trajectory_value(in, k, step)) != 0)
      return -1;
  }
  return 0;
}
