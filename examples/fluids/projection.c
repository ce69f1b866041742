/* projection.c — the constrained pressure projection by UMFPACK on the KKT
 * system, or by CHOLMOD and augmented Lagrangian iterations (see
 * projection.h). */
#include "util.h"
#include "projection.h"

#include "stream.h"
#include "npg.h"

#include <math.h>
#include <stdbool.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/cholmod.h>
#include <suitesparse/umfpack.h>
#include <time.h>

/* w = AL_WEIGHT times K's largest diagonal entry: large enough that a few
 * iterations converge, small enough that K + w D^T D keeps K's digits */
#define AL_WEIGHT 1e8
#define AL_MAXIT 50
/* How many times faster CHOLMOD's supernodal factorization runs per flop
 * than its solves, measured here on one core (cavity, Hilbert numbering):
 * 8.1 at 17,300 cells (8.8e8 flops to factor in 110 ms, 2.3M entries in L,
 * a solve 9.5 ms), 10.8 at 88,599 (1.0e10 flops in 1.12 s, 15.1M entries,
 * a solve 73 ms). The policy's counts depend on it only mildly. */
#define AL_FACTOR_EFFICIENCY 10.0
/* a stale factor is dropped when a correction is not below this fraction
 * of the previous one */
#define AL_STALE_RATE 0.5

struct AugLagrangian {
  cholmod_common cc;
  cholmod_triplet *T;  /* upper triangle of K + w D^T D, fixed order */
  cholmod_factor *L;   /* analysed once, factored for some earlier geometry (or this one) */
  cholmod_dense *b;
  double *lambda, *res; /* [C - 1] multipliers, constraint residual */
  double w;            /* the weight L was factored with: the iterations use it */
  bool factored;       /* L holds a factor */
  bool fresh;          /* L is the factor of the current geometry */
  bool warm;           /* pr->x and lambda hold the last projection's solution */
  /* the reuse policy's cycle since the last factorization: its steps and
   * the solves they took (the first step's apart) */
  int cycle_steps, cycle_solves, cycle_first_solves;
  double factor_cost; /* a factorization's cost in solves, from the analysis's flop counts */
};

/* Triplets in a fixed order: for every cell, its nk x nk block of K
 * (interior faces only), then (but the last cell) its divergence row and
 * column. */
static void triplets(Projection *pr, bool values) {
  const Ops *o = pr->o;
  const FluidMesh *m = o->m;
  int dim = m->dim, nk = m->nk, t = 0;
  for (int c = 0; c < m->nc; c++) {
    const double *P = o->P.val + dim * nk * c; /* rows dim c + d; columns the faces k */
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk < 0) continue;
      for (int l = 0; l < nk; l++) {
        int fl = pr->fidx[m->cface[nk * c + l]];
        if (fl < 0) continue;
        if (values) {
          double s = 0;
          for (int d = 0; d < dim; d++) s += P[nk * d + k] * P[nk * d + l];
          pr->tx[t] = s / o->area[c];
        } else {
          pr->ti[t] = fk, pr->tj[t] = fl;
        }
        t++;
      }
    }
    if (c == m->nc - 1) continue;
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk < 0) continue;
      if (values) pr->tx[t] = pr->tx[t + 1] = m->csign[nk * c + k];
      else pr->ti[t] = pr->ni + c, pr->tj[t] = fk, pr->ti[t + 1] = fk, pr->tj[t + 1] = pr->ni + c;
      t += 2;
    }
  }
  pr->nt = t;
}

const char *projection_method_name(ProjectionMethod method) {
  return method == PROJ_STREAM_CHOLMOD ? "stream-cholmod" : method == PROJ_AL_CHOLMOD ? "al-cholmod" : "kkt-umfpack";
}

/* K + w D^T D's upper triangle into al->T, cell by cell (the last cell has
 * no constraint row); w = AL_WEIGHT times K's largest diagonal entry, or
 * the pattern alone when `values` is false. Returns w. */
static double al_assemble(Projection *pr, bool values) {
  const Ops *o = pr->o;
  const FluidMesh *m = o->m;
  int dim = m->dim, nk = m->nk;
  double w = 0;
  for (int c = 0; values && c < m->nc; c++)
    for (int k = 0; k < nk; k++) {
      const double *P = o->P.val + dim * nk * c;
      double s = 0;
      for (int d = 0; d < dim; d++) s += P[nk * d + k] * P[nk * d + k];
      w = fmax(w, s / o->area[c]);
    }
  w *= AL_WEIGHT;
  cholmod_triplet *T = pr->al->T;
  int *ti = T->i, *tj = T->j;
  double *tx = T->x;
  size_t n = 0;
  for (int c = 0; c < m->nc; c++) {
    const double *P = o->P.val + dim * nk * c;
    double wc = c < m->nc - 1 ? w : 0;
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk < 0) continue;
      for (int l = 0; l < nk; l++) {
        int fl = pr->fidx[m->cface[nk * c + l]];
        if (fl < fk) continue;
        ti[n] = fk, tj[n] = fl;
        double s = 0;
        for (int d = 0; d < dim; d++) s += P[nk * d + k] * P[nk * d + l];
        tx[n++] = values ? s / o->area[c] + wc * m->csign[nk * c + k] * m->csign[nk * c + l] : 1;
      }
    }
  }
  T->nnz = n;
  return w;
}

static int al_init(Projection *pr, char *err, size_t errlen) {
  const FluidMesh *m = pr->o->m;
  AugLagrangian *al = pr->al = calloc(1, sizeof *al);
  cholmod_start(&al->cc);
  al->cc.print = 0;
  al->T = cholmod_allocate_triplet(pr->ni, pr->ni, (size_t)m->nk * (m->nk + 1) / 2 * m->nc, 1, CHOLMOD_REAL, &al->cc);
  al->b = cholmod_zeros(pr->ni, 1, CHOLMOD_REAL, &al->cc);
  al->lambda = malloc(m->nc * sizeof *al->lambda);
  al->res = malloc(m->nc * sizeof *al->res);
  if (!al->T || !al->b) return npg_error_set(err, errlen,
                                             "projection: CHOLMOD allocation failed (status %d)", al->cc.status);
  al_assemble(pr, false);
  cholmod_sparse *A = cholmod_triplet_to_sparse(al->T, al->T->nnz, &al->cc);
  al->L = A ? cholmod_analyze(A, &al->cc) : NULL;
  cholmod_free_sparse(&A, &al->cc);
  if (!al->L) return npg_error_set(err, errlen, "projection: CHOLMOD analysis failed (status %d)", al->cc.status);
  /* a solve is 4 flops per entry of L (forward and back); the factorization's
   * flops run AL_FACTOR_EFFICIENCY times faster (BLAS 3 against BLAS 2) */
  al->factor_cost = al->cc.fl / (4 * fmax(al->cc.lnz, 1)) / AL_FACTOR_EFFICIENCY;
  return 0;
}

static void al_free(AugLagrangian *al) {
  if (!al) return;
  cholmod_free_factor(&al->L, &al->cc);
  cholmod_free_triplet(&al->T, &al->cc);
  cholmod_free_dense(&al->b, &al->cc);
  cholmod_finish(&al->cc);
  free(al->lambda);
  free(al->res);
  free(al);
}

int projection_init(Projection *pr, const Ops *o, ProjectionMethod method, char *err, size_t errlen) {
  memset(pr, 0, sizeof *pr);
  const FluidMesh *m = o->m;
  pr->o = o;
  pr->method = method;
  if (method == PROJ_STREAM_CHOLMOD) return stream_init(&pr->stream, o, err, errlen);
  pr->fidx = malloc(m->nf * sizeof *pr->fidx);
  for (int j = 0; j < m->nf; j++) pr->fidx[j] = m->fkind[j] == BF_INTERIOR ? pr->ni++ : -1;
  pr->n = pr->ni + m->nc - 1;
  pr->rhs = malloc(pr->n * sizeof *pr->rhs);
  pr->x = malloc(pr->n * sizeof *pr->x);
  pr->work_f = malloc(m->nf * sizeof *pr->work_f);
  pr->work_f2 = malloc(m->nf * sizeof *pr->work_f2);
  pr->work_u = malloc(m->dim * m->nc * sizeof *pr->work_u);
  if (method == PROJ_AL_CHOLMOD) return al_init(pr, err, errlen);
  int cap = (m->nk * m->nk + 2 * m->nk) * m->nc;
  pr->ti = malloc(cap * sizeof *pr->ti);
  pr->tj = malloc(cap * sizeof *pr->tj);
  pr->tx = calloc(cap, sizeof *pr->tx);
  pr->map = malloc(cap * sizeof *pr->map);
  triplets(pr, false);
  for (int t = 0; t < pr->nt; t++) pr->tx[t] = 1; /* the pattern only */
  pr->Ap = malloc((pr->n + 1) * sizeof *pr->Ap);
  pr->Ai = malloc(pr->nt * sizeof *pr->Ai);
  pr->Ax = malloc(pr->nt * sizeof *pr->Ax);
  int st = umfpack_di_triplet_to_col(pr->n, pr->n, pr->nt, pr->ti, pr->tj, pr->tx, pr->Ap, pr->Ai, pr->Ax, pr->map);
  if (st != UMFPACK_OK) return npg_error_set(err, errlen, "projection: UMFPACK triplet_to_col failed (status %d)", st);
  /* UMFPACK's default (automatic) strategy: measured faster here than the
   * symmetric one on this KKT matrix (README) */
  umfpack_di_defaults(pr->control);
  st = umfpack_di_symbolic(pr->n, pr->n, pr->Ap, pr->Ai, pr->Ax, &pr->symbolic, pr->control, NULL);
  if (st != UMFPACK_OK) return npg_error_set(err, errlen,
                                             "projection: UMFPACK symbolic analysis failed (status %d)", st);
  return 0;
}

void projection_free(Projection *pr) {
  stream_free(pr->stream);
  al_free(pr->al);
  if (pr->numeric) umfpack_di_free_numeric(&pr->numeric);
  if (pr->symbolic) umfpack_di_free_symbolic(&pr->symbolic);
  free(pr->fidx);
  free(pr->ti);
  free(pr->tj);
  free(pr->tx);
  free(pr->map);
  free(pr->Ap);
  free(pr->Ai);
  free(pr->Ax);
  free(pr->rhs);
  free(pr->x);
  free(pr->work_f);
  free(pr->work_f2);
  free(pr->work_u);
  memset(pr, 0, sizeof *pr);
}

/* The KKT right-hand side into pr->rhs: P^T u - K_ib h_b on the interior
 * faces, then -G_b h_b per cell but the last; the boundary fluxes into
 * pr->work_f (zero on the interior faces). */
static void kkt_rhs(Projection *pr, const double *u_in, const double *h) {
  const Ops *o = pr->o;
  const FluidMesh *m = o->m;
  double *fb = pr->work_f, *r = pr->work_f2, *w = pr->work_u;
  for (int j = 0; j < m->nf; j++) fb[j] = (pr->fidx[j] < 0 && h) ? h[j] : 0;
  /* r = P^T u - P^T V^-1 P fb */
  int dim = m->dim, nk = m->nk;
  csr_mv(&o->P, fb, w);
  for (int c = 0; c < m->nc; c++)
    for (int d = 0; d < dim; d++) w[dim * c + d] = u_in[dim * c + d] - w[dim * c + d] / o->area[c];
  csr_mtv(&o->P, w, r);
  for (int j = 0; j < m->nf; j++)
    if (pr->fidx[j] >= 0) pr->rhs[pr->fidx[j]] = r[j];
  for (int c = 0; c < m->nc - 1; c++) {
    double s = 0;
    for (int k = 0; k < nk; k++) s += m->csign[nk * c + k] * fb[m->cface[nk * c + k]];
    pr->rhs[pr->ni + c] = -s;
  }
}

/* A factorization's cost in solves: pr->al_factor_cost when set (tests),
 * else the estimate from CHOLMOD's analysis — not a timing, so that the
 * schedule of factorizations, and the fluxes to the last bit, are the same
 * on every run and every machine. */
static double al_factor_cost(const Projection *pr) {
  return pr->al_factor_cost > 0 ? pr->al_factor_cost : pr->al->factor_cost;
}

/* The solves a projection may spend on a stale factor: past them,
 * refactoring and the solves of a fresh factor would have been cheaper. */
static double al_refactor_budget(const Projection *pr) {
  return al_factor_cost(pr) + pr->al->cycle_first_solves;
}

/* Whether the next projection should refactor: the cycle since the last
 * factorization has cost F + S (F the factorization's, in solves, S the
 * sum of its solves) over n steps; a step's solves only grow as the factor
 * ages, so refactoring pays once one costs more than the cycle's mean,
 * (F + S)/n. */
static bool al_refactor_next(const Projection *pr, int solves) {
  const AugLagrangian *al = pr->al;
  if (pr->al_refactor_every_step) return true;
  return (double)solves * al->cycle_steps > al_factor_cost(pr) + al->cycle_solves;
}

/* res = bc - D x on the constraint rows (bc the KKT right-hand side's);
 * returns max |res|. */
static double al_constraint_residual(const Projection *pr, const double *x, double *res) {
  const FluidMesh *m = pr->o->m;
  const double *bc = pr->rhs + pr->ni;
  int nk = m->nk;
  double rmax = 0;
  for (int c = 0; c < m->nc - 1; c++) {
    double s = bc[c];
    for (int k = 0; k < nk; k++) {
      int fk = pr->fidx[m->cface[nk * c + k]];
      if (fk >= 0) s -= m->csign[nk * c + k] * x[fk];
    }
    res[c] = s;
    rmax = fmax(rmax, fabs(s));
  }
  return rmax;
}

/* The augmented Lagrangian iterations (projection.h) in residual form: the
 * right-hand side of every solve is the exact KKT system's residual at the
 * current geometry, r - K x - D^T lam + w D^T (bc - D x), so the factor L
 * (of this geometry, or of an earlier one) decides only how fast the
 * iterate converges, not what it converges to: with a stale factor the
 * iterations are a stationary iteration preconditioned by it. Starts from
 * the last projection's solution when al->warm. Stops when the correction
 * and the constraint residual fall below 1e-15 of the largest flux, or
 * when they stagnate at rounding (below 1e-10 of it with a fresh factor,
 * as before the factor was kept; below 1e-13 with a stale one).
 * 0 when converged (the interior fluxes in pr->x); 1 when a stale factor
 * stops paying: its corrections fall by less than AL_STALE_RATE, or the
 * solves their rate predicts exceed al_refactor_budget (the caller
 * refactors and goes on from the iterate); -1 on failure; the reason in
 * `err`. Counts the solves into *solves. */
static int al_iterate(Projection *pr, int *solves, char *err, size_t errlen) {
  const Ops *o = pr->o;
  const FluidMesh *m = o->m;
  AugLagrangian *al = pr->al;
  int dim = m->dim, nk = m->nk, ni = pr->ni, nc1 = m->nc - 1;
  const double *r = pr->rhs;
  double *x = pr->x, *lam = al->lambda, *b = al->b->x, *ff = pr->work_f2, *uu = pr->work_u, *res = al->res;
  double w = al->w, hmax = 0, prev = INFINITY;
  if (!al->warm) {
    memset(lam, 0, nc1 * sizeof *lam);
    memset(x, 0, ni * sizeof *x);
    al->warm = true;
  }
  al_constraint_residual(pr, x, res);
  for (int j = 0; j < m->nf; j++) hmax = fmax(hmax, fabs(pr->work_f[j]));
  for (int it = 1;; it++) {
    /* b = r - K x - D^T lam + w D^T (bc - D x), with res = bc - D x */
    for (int j = 0; j < m->nf; j++) ff[j] = pr->fidx[j] >= 0 ? x[pr->fidx[j]] : 0;
    csr_mv(&o->P, ff, uu);
    for (int c = 0; c < m->nc; c++)
      for (int d = 0; d < dim; d++) uu[dim * c + d] /= o->area[c];
    csr_mtv(&o->P, uu, ff);
    for (int j = 0; j < m->nf; j++)
      if (pr->fidx[j] >= 0) b[pr->fidx[j]] = r[pr->fidx[j]] - ff[j];
    for (int c = 0; c < nc1; c++)
      for (int k = 0; k < nk; k++) {
        int fk = pr->fidx[m->cface[nk * c + k]];
        if (fk >= 0) b[fk] += m->csign[nk * c + k] * (w * res[c] - lam[c]);
      }
    cholmod_dense *sol = cholmod_solve(CHOLMOD_A, al->L, al->b, &al->cc);
    if (!sol) return npg_error_set(err, errlen, "projection: CHOLMOD solve failed (status %d)", al->cc.status);
    ++*solves;
    const double *dx = sol->x;
    double dmax = 0, fmx = hmax;
    for (int i = 0; i < ni; i++) x[i] += dx[i], dmax = fmax(dmax, fabs(dx[i])), fmx = fmax(fmx, fabs(x[i]));
    cholmod_free_dense(&sol, &al->cc);
    /* res = bc - D x; lam -= w res */
    double rmax = al_constraint_residual(pr, x, res);
    for (int c = 0; c < nc1; c++) lam[c] -= w * res[c];
    /* to rounding, or until the corrections stop falling */
    double size = fmax(dmax, rmax);
    if (!isfinite(size)) {
      al->warm = false;
      if (!al->fresh) return 1;
    }
    if (size <= 1e-15 * fmx) break;
    /* at rounding, stagnating: any factor's corrections stall there, a
     * stale one's are held to a hundredth of the target */
    if (size >= 0.5 * prev && size <= (al->fresh ? 1e-10 : 1e-13) * fmx) break;
    if (!al->fresh && (size >= AL_STALE_RATE * prev || it == AL_MAXIT ||
                       it + log(1e-15 * fmx / size) / log(size / prev) > al_refactor_budget(pr)))
      return 1;
    if (it == AL_MAXIT || size >= 0.5 * prev || !isfinite(size))
      return npg_error_set(err, errlen, "projection: augmented Lagrangian iterations did not converge "
                           "(correction %.3g of the largest flux after %d)", size / fmx, it);
    prev = size;
  }
  return 0;
}

/* K + w D^T D assembled at the current geometry and factored into L; its
 * seconds added to pr->seconds_numeric. 0, or -1 with the reason in `err`. */
static int al_factor(Projection *pr, char *err, size_t errlen) {
  AugLagrangian *al = pr->al;
  double t0 = util_now();
  al->w = al_assemble(pr, true);
  cholmod_sparse *A = cholmod_triplet_to_sparse(al->T, al->T->nnz, &al->cc);
  int ok = A && cholmod_factorize(A, al->L, &al->cc) && al->cc.status == CHOLMOD_OK;
  cholmod_free_sparse(&A, &al->cc);
  al->factored = al->fresh = ok;
  al->cycle_steps = al->cycle_solves = 0;
  pr->seconds_numeric += util_now() - t0;
  pr->factorizations++;
  if (!ok)
    return npg_error_set(err, errlen, "projection: K + w D^T D is not positive definite (CHOLMOD status %d)",
                         al->cc.status);
  return 0;
}

/* The projection by augmented Lagrangian iterations: with the factor kept
 * from an earlier geometry while it pays (al_refactor_next), refactored
 * when its iterations stop contracting; the interior fluxes into pr->x. */
static int al_solve(Projection *pr, char *err, size_t errlen) {
  AugLagrangian *al = pr->al;
  int solves = 0, rc = 1;
  if (pr->al_refactor_every_step) al->factored = false;
  if (al->factored) pr->reuses++;
  while (rc == 1) {
    if (!al->factored && al_factor(pr, err, errlen) != 0) return -1;
    rc = al_iterate(pr, &solves, err, errlen);
    if (rc == 1) {
      al->factored = false;
      pr->stale_refactorizations++;
    }
  }
  if (rc != 0) {
    al->warm = false;
    return -1;
  }
  pr->iterations = solves;
  pr->solves += solves;
  pr->projections++;
  if (al->cycle_steps++ == 0) al->cycle_first_solves = solves;
  al->cycle_solves += solves;
  al->fresh = false;
  if (al_refactor_next(pr, solves)) al->factored = false;
  return 0;
}

int projection_solve(Projection *pr, const double *u_in, const double *h, double *f, double *u_out, char *err,
                     size_t errlen) {
  if (pr->stream)
    return stream_solve(pr->stream, u_in, h, f, u_out, &pr->seconds_numeric, &pr->seconds_solve, err, errlen);
  const Ops *o = pr->o;
  const FluidMesh *m = o->m;
  double t0 = util_now();
  if (!pr->al) {
    triplets(pr, true);
    memset(pr->Ax, 0, pr->nt * sizeof *pr->Ax);
    for (int t = 0; t < pr->nt; t++) pr->Ax[pr->map[t]] += pr->tx[t];
    if (pr->numeric) umfpack_di_free_numeric(&pr->numeric);
    int st = umfpack_di_numeric(pr->Ap, pr->Ai, pr->Ax, pr->symbolic, &pr->numeric, pr->control, NULL);
    if (st != UMFPACK_OK)
      return npg_error_set(err, errlen, "projection: UMFPACK numeric factorization failed (status %d%s)", st,
                           st == UMFPACK_WARNING_singular_matrix ? ": singular KKT matrix" : "");
  }
  double t1 = util_now();
  kkt_rhs(pr, u_in, h);
  if (pr->al) {
    double factor0 = pr->seconds_numeric;
    if (al_solve(pr, err, errlen) != 0) return -1;
    t1 += pr->seconds_numeric - factor0; /* al_solve's factorizations: counted as numeric */
  } else {
    int st = umfpack_di_solve(UMFPACK_A, pr->Ap, pr->Ai, pr->Ax, pr->x, pr->rhs, pr->numeric, pr->control, NULL);
    if (st != UMFPACK_OK) return npg_error_set(err, errlen, "projection: UMFPACK solve failed (status %d)", st);
  }
  const double *fb = pr->work_f;
  for (int j = 0; j < m->nf; j++) f[j] = pr->fidx[j] >= 0 ? pr->x[pr->fidx[j]] : fb[j];
  ops_velocity_from_flux(o, f, u_out);
  double t2 = util_now();
  if (!pr->al) pr->seconds_numeric += t1 - t0;
  pr->seconds_solve += t2 - t1;
  return 0;
}

void projection_report_counts(FILE *fp, const Projection *pr) {
  if (!pr->al) return;
  fprintf(fp, "  \"projection_projections\": %ld,\n  \"projection_solves_per_projection\": %.4g,\n"
              "  \"projection_factorizations\": %ld,\n  \"projection_stale_refactorizations\": %ld,\n"
              "  \"projection_factor_reuses\": %ld,\n",
          pr->projections, (double)pr->solves / (pr->projections ? pr->projections : 1), pr->factorizations,
          pr->stale_refactorizations, pr->reuses);
}

double projection_max_divergence(const Ops *o, const double *f) {
  const FluidMesh *m = o->m;
  int nk = m->nk;
  double worst = 0;
  for (int c = 0; c < m->nc; c++) {
    double s = 0;
    for (int k = 0; k < nk; k++) s += m->csign[nk * c + k] * f[m->cface[nk * c + k]];
    if (fabs(s) > worst) worst = fabs(s);
  }
  return worst;
}
