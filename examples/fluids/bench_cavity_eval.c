/* bench_cavity_eval.c — one sample of fluids3d.npg's full evaluation (what
 * the trainer replays for every snapshot: npg_full_set of g, gdot, f, u,
 * then npg_full_eval) on the cavity meshed once per numbering (gmsh's,
 * reverse Cuthill-McKee, Hilbert; mesh_renumber), under libtcc and the
 * system compiler, the numberings' evaluations interleaved so that they
 * share the machine's load alike.
 *
 *     build/bench-cavity-eval [--cells N] [--reps R] [--steps S]   (defaults 110000, 20, 0)
 *
 * Prints the median and the minimum per sample and their ratios to gmsh's
 * numbering; as a check that the three meshes and evaluations are the
 * same, the sums of squares of p, pdot and lap (the same in every numbering,
 * to rounding); CHOLMOD's fill and flops for the projection's matrix in
 * each numbering; with --steps, S full steps of training run 6 on each
 * numbering (the cavity's projection, the numberings taking turns step by
 * step) split as Table 1's t_d, t_a, t_p; and the time mesh_renumber
 * takes.
 * Figures, not pass/fail. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <suitesparse/cholmod.h>

#include "cavity.h"
#include "cavitysim.h"
#include "npg.h"
#include "npgbind.h"
#include "solver.h"
#include "util.h"

#ifndef FLUIDS_NPG3
#define FLUIDS_NPG3 "examples/fluids/fluids3d.npg"
#endif

enum { NORDERS = 3, NBACKENDS = 2 };
static const MeshOrder ORDERS[NORDERS] = {MO_MESHER, MO_RCM, MO_HILBERT};
static const char *ORDER_NAMES[NORDERS] = {"gmsh", "rcm", "hilbert"};
static const NpgBackend BACKENDS[NBACKENDS] = {NPG_TCC, NPG_CC};
static const char *BACKEND_NAMES[NBACKENDS] = {"tcc", "cc"};

/* One sample's inputs, smooth fields of position (so every numbering gets
 * the same sample): g at rest, gdot and u a swirl, f the swirl's flux
 * through each face's area vector. */
typedef struct Sample {
  double *g, *gdot, *f, *u;
} Sample;

static void swirl(const double *x, double *w) {
  w[0] = -x[1] + 0.1 * x[2], w[1] = x[0], w[2] = 0.3 * sin(x[0]);
}

static Sample sample_of(const FluidMesh *m) {
  Sample s = {malloc(3 * (size_t)m->nv * sizeof(double)), malloc(3 * (size_t)m->nv * sizeof(double)),
              malloc((size_t)m->nf * sizeof(double)), malloc(3 * (size_t)m->nc * sizeof(double))};
  memcpy(s.g, m->g0, 3 * (size_t)m->nv * sizeof(double));
  for (int v = 0; v < m->nv; v++) swirl(m->g0 + 3 * v, s.gdot + 3 * v);
  for (int c = 0; c < m->nc; c++) {
    double x[3] = {0, 0, 0};
    for (int k = 0; k < 4; k++)
      for (int d = 0; d < 3; d++) x[d] += 0.25 * m->g0[3 * m->cell[4 * c + k] + d];
    swirl(x, s.u + 3 * c);
  }
  for (int j = 0; j < m->nf; j++) {
    const int *v = m->face + 3 * j;
    const double *a = m->g0 + 3 * v[0], *b = m->g0 + 3 * v[1], *d = m->g0 + 3 * v[2];
    double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, q[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]}, x[3], w[3];
    double n[3] = {e[1] * q[2] - e[2] * q[1], e[2] * q[0] - e[0] * q[2], e[0] * q[1] - e[1] * q[0]};
    for (int k = 0; k < 3; k++) x[k] = (a[k] + b[k] + d[k]) / 3;
    swirl(x, w);
    s.f[j] = 0.5 * (n[0] * w[0] + n[1] * w[1] + n[2] * w[2]);
  }
  return s;
}

static void sample_free(Sample *s) {
  free(s->g), free(s->gdot), free(s->f), free(s->u);
}

/* One timed sample: the four inputs set, every stage evaluated. */
static double timed_sample(NpgFull *fe, const FluidMesh *m, const Sample *s) {
  long sg[2] = {m->nv, 3}, sf[1] = {m->nf}, su[2] = {m->nc, 3};
  double t0 = util_now();
  if (npg_full_set(fe, "g", 2, sg, s->g, "g") || npg_full_set(fe, "gdot", 2, sg, s->gdot, "gdot") ||
      npg_full_set(fe, "f", 1, sf, s->f, "f") || npg_full_set(fe, "u", 2, su, s->u, "u") || npg_full_eval(fe, 0)) {
    fprintf(stderr, "bench-cavity-eval: %s\n", npg_full_error(fe));
    exit(1);
  }
  return util_now() - t0;
}

/* The sum of the squares of a stage's entries: the same in every numbering. */
static double stage_squares(const NpgFull *fe, const char *name) {
  size_t n = 0;
  const double *v = npg_full_get(fe, name, &n);
  double s = 0;
  for (size_t i = 0; i < n; i++) s += v[i] * v[i];
  return s;
}

/* CHOLMOD's analysis, with its defaults as projection.c's augmented
 * Lagrangian uses them, of the pattern of K + w DᵀD on the interior faces
 * (every pair of a cell's interior faces): the factor's entries and flops,
 * which the numbering could change only through the orderings' tie-breaks
 * (CHOLMOD orders the matrix itself); -1 on failure. */
static int cholmod_fill(const FluidMesh *m, double *lnz, double *flops) {
  int *fidx = malloc((size_t)m->nf * sizeof *fidx), ni = 0, rc = -1;
  for (int j = 0; j < m->nf; j++) fidx[j] = m->fkind[j] == BF_INTERIOR ? ni++ : -1;
  cholmod_common cc;
  cholmod_start(&cc);
  cc.print = 0;
  cholmod_triplet *T = cholmod_allocate_triplet(ni, ni, 10 * (size_t)m->nc, 1, CHOLMOD_PATTERN, &cc);
  if (T) {
    int *ti = T->i, *tj = T->j;
    for (int c = 0; c < m->nc; c++)
      for (int k = 0; k < 4; k++)
        for (int l = k; l < 4; l++) {
          int a = fidx[m->cface[4 * c + k]], b = fidx[m->cface[4 * c + l]];
          if (a < 0 || b < 0) continue;
          ti[T->nnz] = a < b ? a : b, tj[T->nnz] = a < b ? b : a, T->nnz++;
        }
    cholmod_sparse *A = cholmod_triplet_to_sparse(T, T->nnz, &cc);
    cholmod_factor *L = A ? cholmod_analyze(A, &cc) : NULL;
    if (L) *lnz = cc.lnz, *flops = cc.fl, rc = 0;
    cholmod_free_factor(&L, &cc);
    cholmod_free_sparse(&A, &cc);
  }
  cholmod_free_triplet(&T, &cc);
  cholmod_finish(&cc);
  free(fidx);
  return rc;
}

/* The full step's parts, summed over steps: the deformation (cavity_deform
 * and the solver's h), advection, the projection's factorization and
 * solve. */
typedef struct StepTimes {
  double deform, advect, factor, solve;
} StepTimes;

/* `steps` full steps of training run 6 on each numbering's mesh, the
 * numberings taking turns step by step; 0, or -1 with the reason in err. */
static int time_steps(const Cavity *cv, int n, int steps, StepTimes *out, char *err, size_t errlen) {
  FullSolver s[NORDERS];
  double *g[NORDERS], sigma[CAVITY_SIDES];
  const double zero[3] = {0, 0, 0};
  int on = 0, rc = 0;
  for (; on < n && !rc; on++) {
    g[on] = malloc(3 * (size_t)cv[on].m.nv * sizeof *g[on]);
    rc = solver_init_at(&s[on], &cv[on].m, PROJ_AL_CHOLMOD, 1e-4, 0.01, cv[on].m.g0, zero, err, errlen);
    if (rc) free(g[on]);
  }
  if (rc) on--;
  for (int o = 0; o < on; o++) s[o].pr.seconds_numeric = s[o].pr.seconds_solve = 0; /* not the initial projection */
  for (int t = 1; t <= steps && !rc; t++)
    for (int o = 0; o < n && !rc; o++) {
      cavity_schedule(6, t, 100, sigma);
      double t0 = util_now();
      rc = cavity_deform(&cv[o], sigma, g[o], NULL, err, errlen);
      out[o].deform += util_now() - t0;
      if (!rc) rc = solver_step_to(&s[o], g[o], err, errlen);
    }
  for (int o = 0; o < on; o++) {
    out[o].deform += s[o].seconds_deformation, out[o].advect = s[o].seconds_advection;
    out[o].factor = s[o].pr.seconds_numeric, out[o].solve = s[o].pr.seconds_solve;
    solver_free(&s[o]), free(g[o]);
  }
  return rc;
}

static int cmp_double(const void *x, const void *y) {
  double a = *(const double *)x, b = *(const double *)y;
  return a < b ? -1 : a > b;
}

int main(int argc, char **argv) {
  CavitySpec spec = cavity_spec_default();
  int reps = 20, steps = 0;
  spec.cells = 110000;
  for (int i = 1; i < argc; i += 2) {
    if (i + 1 < argc && !strcmp(argv[i], "--cells")) spec.cells = atoi(argv[i + 1]);
    else if (i + 1 < argc && !strcmp(argv[i], "--reps")) reps = atoi(argv[i + 1]);
    else if (i + 1 < argc && !strcmp(argv[i], "--steps")) steps = atoi(argv[i + 1]);
    else {
      fprintf(stderr, "usage: bench-cavity-eval [--cells N] [--reps R] [--steps S]\n");
      return 2;
    }
  }
  if (spec.cells < 50 || reps < 1 || steps < 0) {
    fprintf(stderr, "bench-cavity-eval: --cells must be at least 50, --reps at least 1, --steps at least 0\n");
    return 2;
  }
  NpgOptions no = {0};
  NpgProgram *prog = npg_compile(FLUIDS_NPG3, &no);
  if (!npg_ok(prog)) {
    fprintf(stderr, "%s", npg_error(prog));
    return 1;
  }
  Cavity cv[NORDERS];
  Sample smp[NORDERS];
  NpgFull *fe[NORDERS][NBACKENDS];
  double mesh_seconds[NORDERS], *t[NORDERS][NBACKENDS];
  char err[512];
  for (int o = 0; o < NORDERS; o++) {
    spec.order = ORDERS[o];
    double t0 = util_now();
    if (cavity_mesh(&cv[o], &spec, err, sizeof err) != 0) {
      fprintf(stderr, "bench-cavity-eval: %s\n", err);
      return 1;
    }
    mesh_seconds[o] = util_now() - t0;
    smp[o] = sample_of(&cv[o].m);
    for (int b = 0; b < NBACKENDS; b++) {
      fe[o][b] = npg_full_new(prog, BACKENDS[b]);
      if (fluid_bind(fe[o][b], &cv[o].m, 1e-4) != 0) {
        fprintf(stderr, "bench-cavity-eval: %s\n", npg_full_error(fe[o][b]));
        return 1;
      }
      timed_sample(fe[o][b], &cv[o].m, &smp[o]); /* the gathers' check and first touch, untimed */
      t[o][b] = malloc(reps * sizeof(double));
    }
  }
  printf("cavity: %d cells, %d faces, %d vertices; meshing %.1f s (gmsh), renumbering + meshing %.1f s (rcm), %.1f s "
         "(hilbert)\n",
         cv[0].m.nc, cv[0].m.nf, cv[0].m.nv, mesh_seconds[0], mesh_seconds[1], mesh_seconds[2]);
  for (int r = 0; r < reps; r++)
    for (int b = 0; b < NBACKENDS; b++)
      for (int o = 0; o < NORDERS; o++) t[o][b][r] = timed_sample(fe[o][b], &cv[o].m, &smp[o]);
  for (int b = 0; b < NBACKENDS; b++) {
    double med0 = 0, min0 = 0;
    for (int o = 0; o < NORDERS; o++) {
      qsort(t[o][b], reps, sizeof(double), cmp_double);
      double med = t[o][b][reps / 2], mn = t[o][b][0];
      if (o == 0) med0 = med, min0 = mn;
      printf("%-3s %-7s per sample: median %7.2f ms, min %7.2f ms; gmsh / this: %.2f (median), %.2f (min); "
             "|p|² %.12e |pdot|² %.12e |lap|² %.12e\n",
             BACKEND_NAMES[b], ORDER_NAMES[o], 1e3 * med, 1e3 * mn, med0 / med, min0 / mn,
             stage_squares(fe[o][b], "p"), stage_squares(fe[o][b], "pdot"), stage_squares(fe[o][b], "lap"));
    }
  }
  for (int o = 0; o < NORDERS; o++) {
    double lnz = 0, fl = 0;
    if (cholmod_fill(&cv[o].m, &lnz, &fl) == 0)
      printf("CHOLMOD's analysis of K + w DᵀD, %-7s numbering: %.0f entries in L, %.4g flops to factor\n",
             ORDER_NAMES[o], lnz, fl);
  }
  if (steps > 0) {
    StepTimes st[NORDERS] = {{0}};
    if (time_steps(cv, NORDERS, steps, st, err, sizeof err) != 0) {
      fprintf(stderr, "bench-cavity-eval: %s\n", err);
      return 1;
    }
    for (int o = 0; o < NORDERS; o++)
      printf("full step, %-7s numbering, mean of %d: t_d %.2f ms, t_a %.2f ms, t_p %.1f ms (factorization %.1f + "
             "solve %.1f); gmsh / this: t_d %.2f, t_a %.2f, t_p %.2f\n",
             ORDER_NAMES[o], steps, 1e3 * st[o].deform / steps, 1e3 * st[o].advect / steps,
             1e3 * (st[o].factor + st[o].solve) / steps, 1e3 * st[o].factor / steps, 1e3 * st[o].solve / steps,
             st[0].deform / st[o].deform, st[0].advect / st[o].advect,
             (st[0].factor + st[0].solve) / (st[o].factor + st[o].solve));
  }
  /* the renumbering alone, of gmsh's mesh (then of reverse Cuthill-McKee's) */
  for (int o = 1; o < NORDERS; o++) {
    double t0 = util_now();
    mesh_renumber(&cv[0].m, ORDERS[o]);
    printf("mesh_renumber %s: %.3f s\n", ORDER_NAMES[o], util_now() - t0);
  }
  for (int o = 0; o < NORDERS; o++) {
    for (int b = 0; b < NBACKENDS; b++) npg_full_free(fe[o][b]), free(t[o][b]);
    sample_free(&smp[o]);
    cavity_free(&cv[o]);
  }
  npg_free(prog);
  return 0;
}
