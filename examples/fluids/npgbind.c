/* npgbind.c — the mesh as the params of fluids2d.npg (see npgbind.h). */
#include "npgbind.h"

#include <stdlib.h>
#include <string.h>

static double *ints(const int *v, size_t n) {
  double *d = malloc((n ? n : 1) * sizeof *d);
  for (size_t i = 0; i < n; i++) d[i] = v[i];
  return d;
}

/* fluids3d.npg's params: tet, tri, cface, csign, nbr, bface, mu. */
static int params3d(const FluidMesh *m, double mu, FluidParam out[FLUID_NPARAMS]) {
  long C = m->nc, F = m->nf, B = m->nb;
  int k = 0;
  memset(out, 0, FLUID_NPARAMS * sizeof *out);
  out[k++] = (FluidParam){"tet", 2, {C, 4}, ints(m->cell, 4 * C), 1};
  out[k++] = (FluidParam){"tri", 2, {F, 3}, ints(m->face, 3 * F), 1};
  out[k++] = (FluidParam){"cface", 2, {C, 4}, ints(m->cface, 4 * C), 1};
  double *cs = malloc(4 * C * sizeof *cs);
  memcpy(cs, m->csign, 4 * C * sizeof *cs);
  out[k++] = (FluidParam){"csign", 2, {C, 4}, cs, 0};
  out[k++] = (FluidParam){"nbr", 2, {C, 4}, ints(m->nbr, 4 * C), 1};
  out[k++] = (FluidParam){"bface", 1, {B}, ints(m->bface, B), 1};
  double *mv = malloc(sizeof *mv);
  *mv = mu;
  out[k++] = (FluidParam){"mu", 0, {0, 0}, mv, 0};
  return k;
}

int fluid_params(const FluidMesh *m, double mu, FluidParam out[FLUID_NPARAMS]) {
  if (m->dim == 3) return params3d(m, mu, out);
  long C = m->nc, F = m->nf, B = m->nb, U = 2 * C;
  int k = 0;
  out[k++] = (FluidParam){"tri", 2, {C, 3}, ints(m->cell, 3 * C), 1};
  out[k++] = (FluidParam){"edge", 2, {F, 2}, ints(m->face, 2 * F), 1};
  out[k++] = (FluidParam){"cface", 2, {C, 3}, ints(m->cface, 3 * C), 1};
  double *cs = malloc(3 * C * sizeof *cs);
  memcpy(cs, m->csign, 3 * C * sizeof *cs);
  out[k++] = (FluidParam){"csign", 2, {C, 3}, cs, 0};
  out[k++] = (FluidParam){"nbr", 2, {C, 3}, ints(m->nbr, 3 * C), 1};
  out[k++] = (FluidParam){"bface", 1, {B}, ints(m->bface, B), 1};
  double *uc = malloc(U * sizeof *uc), *ud = malloc(U * sizeof *ud), *un = malloc(3 * U * sizeof *un);
  for (long i = 0; i < U; i++) {
    long c = i / 2, d = i % 2;
    uc[i] = (double)c, ud[i] = (double)d;
    for (int j = 0; j < 3; j++) un[3 * i + j] = m->nbr[3 * c + j] >= 0 ? (double)(2 * m->nbr[3 * c + j] + d) : -1.0;
  }
  out[k++] = (FluidParam){"ucell", 1, {U}, uc, 1};
  out[k++] = (FluidParam){"ucomp", 1, {U}, ud, 1};
  out[k++] = (FluidParam){"unbr", 2, {U, 3}, un, 1};
  double *mv = malloc(sizeof *mv);
  *mv = mu;
  out[k++] = (FluidParam){"mu", 0, {0, 0}, mv, 0};
  return k;
}

void fluid_params_free(FluidParam p[FLUID_NPARAMS]) {
  for (int i = 0; i < FLUID_NPARAMS; i++) free(p[i].v), p[i].v = NULL;
}

int fluid_bind(NpgFull *f, const FluidMesh *m, double mu) {
  FluidParam p[FLUID_NPARAMS];
  int n = fluid_params(m, mu, p), rc = 0;
  for (int i = 0; i < n && !rc; i++)
    rc = npg_full_set_param(f, p[i].name, p[i].ndim, p[i].shape, p[i].v, p[i].name);
  fluid_params_free(p);
  return rc ? -1 : 0;
}

void fluid_train_options(NpgTrainOptions *to, FluidBasisOptions *b, int cap_u, int cap_f, int cap_g, int cap_h) {
  npg_train_options_default(to);
  const char *names[11] = {"u", "p", "pv", "pdot", "lap", "f", "g", "gdot", "h", "bf", "bh"};
  int caps[11] = {cap_u, 1, 1, 1, 1, cap_f, cap_g, cap_g, cap_h, 60, 60};
  double en[11] = {1 - 1e-14, 1 - 1e-14, 1 - 1e-14, 1 - 1e-14, 1 - 1e-14, 1 - 1e-9,
                   1 - 1e-13, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13, 1 - 1e-13};
  memcpy(b->names, names, sizeof names);
  memcpy(b->caps, caps, sizeof caps);
  memcpy(b->energies, en, sizeof en);
  to->nbasis = 11;
  to->basis_name = b->names;
  to->basis_cap = b->caps;
  to->basis_energy = b->energies;
  to->progress = false;
}
