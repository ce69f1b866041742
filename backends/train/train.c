/* train.c — training a reduced model (DESIGN §5; paper §8.2–§8.3):
 *
 *   0. the layout, and every member's cap, energy fraction and centering
 *      (defaults, the program's `basis` statements, --basis);
 *   1. snapshots: the full evaluator on every training sample; every
 *      quantity's value and, for every operator term with an unnamed
 *      numerator, the numerator's value (it joins the result's class:
 *      DESIGN §4, "a numerator lives in the result's basis");
 *   2. one orthonormal basis per class: a PCA per member (centered by
 *      default: pca.c), concatenated and re-orthonormalized, or with
 *      --merge joint one PCA of the unit-scaled member blocks;
 *   3. pre-multiplication of every tensor (premul.c);
 *   4. the learned map of every extern (paper §8.3): the training samples'
 *      reduced inputs and reduced values.
 *
 * A TrainSet (npgc tune) runs 0–1 and every member's PCA once, then builds
 * models of any caps from truncations of those bases, steps 2–4 only.
 */
#include <cblas.h>
#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "dist.h"
#include "emit.h"
#include "interp.h"
#include "reduced.h"
#include "train.h"

/* Redrawn at most ten times a second (a pass of many tiny steps would
 * otherwise spend its time drawing), and always at the first and last step. */
void progress_show(bool on, const char *what, long done, long total) {
  if (!on) return;
  static _Thread_local double last = -1;
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  double now = (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
  if (done > 1 && done < total && now - last < 0.1) return;
  last = now;
  int width = 30, fill = total > 0 ? (int)((double)done / (double)total * width) : width;
  fprintf(stderr, "\r%-28s [", what);
  for (int i = 0; i < width; i++) fputc(i < fill ? '#' : ' ', stderr);
  fprintf(stderr, "] %ld/%ld", done, total);
  if (done >= total) fputc('\n', stderr);
  fflush(stderr);
}


/* ---------------------------------------------------------------- fields through the builders */

typedef struct FieldSum {
  const double *in[16];  /* the values of the tensor's inputs, in its input order */
  double *out;
  long n;
} FieldSum;

static int sum_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  FieldSum *s = user;
  (void)col;
  if (row < 0 || row >= s->n) return -1;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  s->out[row] += v;
  return 0;
}

/* out[0..n) = the field whose tensors are `ts` (builders named in `ts`),
 * evaluated on the current values of the evaluator. */
static int field_value(NpgFull *f, const RTensor *ts, int nt, double *out, long n, char *err, size_t errlen) {
  memset(out, 0, sizeof(double) * (size_t)n);
  for (int g = 0; g < nt; g++) {
    FieldSum s = {{0}, out, n};
    for (int i = 0; i < ts[g].group->ninputs; i++) s.in[i] = npg_full_get(f, ts[g].group->inputs[i]->name, NULL);
    NpgSink sink = {&s, sum_entry, 0, 1, 0, 0}; /* every row */
    if (full_build(f, ts[g].builder, &sink) != 0) return npg_fail(err, errlen, "%s", npg_full_error(f));
  }
  return 0;
}

/* ---------------------------------------------------------------- options */

/* Whether override `name` (--basis NAME:...) names member `mb` of class
 * `c`, and how specifically: 0 not at all, 1 '*', 2 its class (m_f as
 * `npgc check` prints it, or its label {f,g}), 3 the member itself (a
 * quantity, or a numerator f.num1). */
static int override_level(const RClass *c, const RMember *mb, const char *name) {
  if (strcmp(name, mb->name) == 0) return 3;
  if (strcmp(name, c->label) == 0 || (c->bc->size_name && strcmp(name, c->bc->size_name) == 0)) return 2;
  /* m_<any member>, as the language's `basis m_q:` takes it (the class of q) */
  for (int k = 0; strncmp(name, "m_", 2) == 0 && k < c->nmembers; k++)
    if (strcmp(name + 2, c->members[k].name) == 0) return 2;
  return strcmp(name, "*") == 0 ? 1 : 0;
}

/* Every --basis name must name something: a misspelt one would silently
 * train with the defaults. */
static int check_overrides(const Model *m, const TrainOptions *opt, char *err, size_t errlen) {
  for (int i = 0; i < opt->noverride; i++) {
    bool found = false;
    for (int c = 0; c < m->nclasses && !found; c++)
      for (int k = 0; k < m->classes[c].nmembers && !found; k++)
        found = override_level(&m->classes[c], &m->classes[c].members[k], opt->override_name[i]) > 0;
    if (found) continue;
    char list[1024] = "";
    size_t len = 0;
    for (int c = 0; c < m->nclasses && len < sizeof list; c++) {
      const RClass *rc = &m->classes[c];
      len += (size_t)snprintf(list + len, sizeof list - len, "%s%s (", c ? "; " : "", rc->bc->size_name);
      for (int k = 0; k < rc->nmembers && len < sizeof list; k++)
        len += (size_t)snprintf(list + len, sizeof list - len, "%s%s", k ? ", " : "", rc->members[k].name);
      if (len < sizeof list) len += (size_t)snprintf(list + len, sizeof list - len, ")");
    }
    return npg_fail(err, errlen,
                    "--basis %s: no quantity, class or numerator of that name; classes (members): %s, or '*' for all",
                    opt->override_name[i], list);
  }
  return 0;
}

/* A member's cap, energy and centering: the defaults, then the program's
 * `basis` statements, then --basis from the least specific to the most. */
static void member_options(const Model *m, const RClass *c, RMember *mb, const TrainOptions *opt) {
  mb->cap = opt->cap > 0 ? opt->cap : 60;
  mb->energy = opt->energy > 0 ? opt->energy : 0.999;
  mb->center = !opt->uncentered;
  const BasisClass *bc = c->bc;
  if (bc->basis_max > 0) mb->cap = bc->basis_max;
  if (bc->basis_energy > 0) mb->energy = bc->basis_energy;
  if (bc->basis_center >= 0) mb->center = bc->basis_center;
  if (mb->q >= 0) {
    const Sym *s = m->prog->quantities.v[mb->q];
    if (s->basis_max > 0) mb->cap = s->basis_max;
    if (s->basis_energy > 0) mb->energy = s->basis_energy;
    if (s->basis_center >= 0) mb->center = s->basis_center;
  }
  for (int level = 1; level <= 3; level++)
    for (int i = 0; i < opt->noverride; i++) {
      if (override_level(c, mb, opt->override_name[i]) != level) continue;
      if (opt->override_cap[i] > 0) mb->cap = opt->override_cap[i];
      if (opt->override_energy[i] > 0) mb->energy = opt->override_energy[i];
      if (opt->override_center && opt->override_center[i] >= 0) mb->center = opt->override_center[i];
    }
}

/* ---------------------------------------------------------------- training */

typedef struct Snapshots {
  long S;
  double ***X;      /* [class][member] n x S column-major (NULL: method of snapshots) */
  double ***U;      /* [class][member] its PCA basis, n x k row-major (method of snapshots) */
  int **k;
} Snapshots;

static void free_snapshots(Model *m, Snapshots *sn) {
  for (int c = 0; c < m->nclasses; c++) {
    for (int i = 0; i < m->classes[c].nmembers; i++) {
      if (sn->X && sn->X[c]) free(sn->X[c][i]);
      if (sn->U && sn->U[c]) free(sn->U[c][i]);
    }
    if (sn->X) free(sn->X[c]);
    if (sn->U) free(sn->U[c]);
    if (sn->k) free(sn->k[c]);
  }
  free(sn->X);
  free(sn->U);
  free(sn->k);
}

/* Visit every diagonal operator (stage, term, op). */
#define FOR_DIAG_OPS(m, rs, rt, ro)                                                   \
  for (int i_ = 0; i_ < (m)->nstages; i_++)                                           \
    for (RStage *rs = &(m)->stages[i_]; rs; rs = NULL)                                \
      for (int t_ = 0; t_ < rs->nterms; t_++)                                         \
        for (RTerm *rt = &rs->terms[t_]; rt; rt = NULL)                               \
          for (int k_ = 0; k_ < rt->nops; k_++)                                       \
            for (ROp *ro = &rt->ops[k_]; ro && ro->op->kind == OPK_DIAG; ro = NULL)

void train_mark_spd(Model *m) {
  FOR_DIAG_OPS(m, rs, rt, ro) ro->spd = true;
}

static RTerm *joiner_term(Model *m, const Joiner *j) {
  for (int i = 0; i < m->nstages; i++)
    if (m->stages[i].st == j->stage) return &m->stages[i].terms[j->term];
  return NULL;
}


/* Set and evaluate training sample k. */
int train_eval_sample(const SampleSource *src, NpgFull *f, long k, char *err, size_t errlen) {
  if (src->set(src->user, f, k) != 0 || npg_full_eval(f, k) != 0) return npg_fail(err, errlen, "%s", npg_full_error(f));
  return 0;
}

/* The current value of a class member (a quantity, or an unnamed numerator
 * through its builders) at sample k into out[0..n); refused when not
 * finite, since a basis of it would be meaningless (and the SVD would fail
 * without saying why). */
int train_member_value(Model *m, NpgFull *f, const RMember *mb, long k, long n, double *out, char *err,
                        size_t errlen) {
  if (mb->q >= 0) {
    memcpy(out, npg_full_get(f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL), sizeof(double) * (size_t)n);
  } else {
    RTerm *rt = joiner_term(m, mb->joiner);
    if (!rt) return npg_fail(err, errlen, "a numerator without its term (a bug in npg)");
    if (field_value(f, rt->num, rt->nnum, out, n, err, errlen)) return -1;
  }
  for (long e = 0; e < n; e++)
    if (!isfinite(out[e])) {
      /* name where the NaN arises (the first quantity in evaluation order
       * holding one), not the member that happened to be looked at */
      const Sym *s;
      char at[256];
      double v;
      if (full_first_nonfinite(f, &s, at, sizeof at, &v))
        return npg_fail(err, errlen,
                        "training sample %ld: %s is not finite (%s%s is %s): the sample makes it undefined (a "
                        "division by zero or a root of a negative number in the program?)",
                        k, s->name, s->name, at, isnan(v) ? "NaN" : v > 0 ? "inf" : "-inf");
      return npg_fail(err, errlen,
                      "training sample %ld: %s is not finite (entry %ld is %g): the sample makes it undefined (a "
                      "division by zero or a root of a negative number in the program?)",
                      k, mb->name, e, out[e]);
    }
  return 0;
}

/* A diagonal operator stays marked SPD while every training diagonal seen is
 * positive (then BᵀDB is SPD for every basis: Cholesky). */
int train_check_spd(Model *m, NpgFull *f, double *tmp, char *err, size_t errlen) {
  FOR_DIAG_OPS(m, rs, rt, ro) {
    if (!ro->spd) continue;
    long n = m->classes[m->qclass[rs->q]].n;
    if (field_value(f, ro->t, ro->ntensors, tmp, n, err, errlen)) return -1;
    for (long e = 0; e < n && ro->spd; e++)
      if (!(tmp[e] > 0)) ro->spd = false;
  }
  return 0;
}

/* How the method of snapshots shares a budget of `fit` samples (half of
 * --mem over the bytes of one sample's members): a held block of *b and a
 * batch of *q later samples. All S held when they fit (one pass, no
 * batch). Otherwise the held block is as large as the budget allows: every
 * pass recomputes the samples after its block, about S²/2b evaluations in
 * all. The cross block G[I, K] = H_Iᵀ X_K is one dgemm per batch, reading
 * the held block once per batch where a dgemv per sample read it once per
 * sample; but OpenBLAS's dgemm with 1, 2 or 4 columns is 4, 2 and 1.2 times
 * slower than as many dgemv (bench/gram.md), so the batch takes an eighth of
 * the budget, at most TRAIN_GRAM_BATCH samples, when that is 8 or more
 * (evaluations grow by at most 1/7), and otherwise is one sample outside
 * the budget (a small block stays in cache: the dgemv route as before). */
#define TRAIN_GRAM_BATCH 32
void train_gram_blocks(long S, long fit, long *b, long *q) {
  if (fit >= S) {
    *b = S > 0 ? S : 1, *q = 0;
    return;
  }
  *q = fit / 8 < TRAIN_GRAM_BATCH ? fit / 8 : TRAIN_GRAM_BATCH;
  if (*q < 8) *q = 1, *b = fit > 1 ? fit : 1;
  else *b = fit - *q;
}

/* The method of snapshots (DESIGN §5), for snapshots that do not fit in
 * `mem`: no snapshot matrix is held whole. Pass 1 builds every member's
 * S x S Gram matrix G = XᵀX holding a block of b samples at a time and
 * recomputing the later samples against it in batches of q (one dgemm per
 * member and batch: train_gram_blocks; one pass when the budget holds every
 * sample, ⌈S/b⌉ in general); the eigenvectors of G give the basis
 * U = X V Λ^(-1/2), formed in pass 2 by recomputing every sample once and
 * adding its rank-one contribution. U[c][i], kk[c][i] per member.
 *
 * A centered member's snapshots are shifted by its first sample x₀ (on a
 * deforming mesh that removes the dominant rest shape before any product,
 * so nothing cancels), their mean d accumulated in pass 1; the centered
 * Gram matrix is then J G J (J = I − 11ᵀ/S: the mean of a shift is
 * removed exactly), its eigenvectors give U_c = (X − x₀1ᵀ − d1ᵀ) W, and
 * the member's basis is the orthonormalization of [μ = x₀ + d, U_c]. */
static int snapshot_bases(Model *m, NpgFull *f, const SampleSource *src, const TrainOptions *opt, double ***U,
                          int **kk, double *tmp, char *err, size_t errlen) {
  long S = src->count, per = 0;
  for (int c = 0; c < m->nclasses; c++) per += m->classes[c].n * m->classes[c].nmembers;
  long b, q;
  train_gram_blocks(S, (long)(opt->mem / 2 / sizeof(double) / (size_t)(per ? per : 1)), &b, &q);
  int rc = -1;
  double ***G = npg_calloc((size_t)m->nclasses + 1, sizeof(double **)), ***H = npg_calloc((size_t)m->nclasses + 1, sizeof(double **));
  double ***Y = npg_calloc((size_t)m->nclasses + 1, sizeof(double **)); /* the batch of later samples */
  double *lam = npg_malloc(sizeof(double) * (size_t)S), *V = NULL;
  /* centered members: the shift x₀ and the sum of the shifted snapshots, then their mean */
  double ***X0 = npg_calloc((size_t)m->nclasses + 1, sizeof(double **)), ***D = npg_calloc((size_t)m->nclasses + 1, sizeof(double **));
  double **big = npg_calloc((size_t)m->nclasses + 1, sizeof(double *)); /* every member's largest |entry| */
  if (!G || !H || !Y || !lam || !X0 || !D || !big) goto oom;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(G[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) || !(H[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) ||
        !(X0[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) || !(D[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) ||
        !(Y[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) || !(big[c] = npg_calloc((size_t)rc->nmembers, sizeof(double))))
      goto oom;
    for (int i = 0; i < rc->nmembers; i++) {
      if (!(G[c][i] = npg_calloc((size_t)(S * S), sizeof(double))) ||
          !(H[c][i] = npg_malloc(sizeof(double) * (size_t)(rc->n * b))) ||
          (q > 0 && !(Y[c][i] = npg_malloc(sizeof(double) * (size_t)(rc->n * q)))))
        goto oom;
      if (rc->members[i].center &&
          (!(X0[c][i] = npg_malloc(sizeof(double) * (size_t)rc->n)) || !(D[c][i] = npg_calloc((size_t)rc->n, sizeof(double)))))
        goto oom;
    }
  }
  long passes = (S + b - 1) / b, done = 0, work = 0;
  for (long i0 = 0; i0 < S; i0 += b) work += S - i0;
  for (long i0 = 0; i0 < S; i0 += b) {
    long i1 = i0 + b < S ? i0 + b : S, nb = i1 - i0;
    for (long k = i0, k0 = i1; k < S; k++) { /* k0: the first sample of the batch */
      if (train_eval_sample(src, f, k, err, errlen)) goto done;
      if (k < i1 && train_check_spd(m, f, tmp, err, errlen)) goto done;
      bool full = k >= i1 && (k + 1 - k0 == q || k + 1 == S);
      for (int c = 0; c < m->nclasses; c++) {
        RClass *rc = &m->classes[c];
        for (int i = 0; i < rc->nmembers; i++) {
          double *x = k < i1 ? H[c][i] + (k - i0) * rc->n : Y[c][i] + (k - k0) * rc->n;
          if (train_member_value(m, f, &rc->members[i], k, rc->n, x, err, errlen)) goto done;
          if (X0[c][i]) {
            if (k == 0) memcpy(X0[c][i], x, sizeof(double) * (size_t)rc->n);
            cblas_daxpy((int)rc->n, -1.0, X0[c][i], 1, x, 1);
            if (k < i1) cblas_daxpy((int)rc->n, 1.0, x, 1, D[c][i], 1);
          }
          for (long e = 0; k < i1 && e < rc->n; e++) big[c][i] = fmax(big[c][i], fabs(x[e])); /* what enters G */
          if (!full) continue;
          /* G[I, K] = X_Iᵀ X_K for the batch K = [k0, k] (one sample: a
           * dgemv, faster than a dgemm of one column), and its mirror */
          long nk = k + 1 - k0;
          double *g = G[c][i];
          if (nk == 1)
            cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)nb, (int)rc->n, 1.0, H[c][i], (int)rc->n, Y[c][i], 1, 0.0,
                        g + i0 * S + k0, (int)S);
          else
            cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nk, (int)rc->n, 1.0, H[c][i], (int)rc->n,
                        Y[c][i], (int)rc->n, 0.0, g + i0 * S + k0, (int)S);
          for (long a = i0; a < i1; a++)
            for (long e = k0; e <= k; e++) g[e * S + a] = g[a * S + e];
        }
      }
      if (full) k0 = k + 1;
      progress_show(opt->progress, passes > 1 ? "snapshots (Gram, recomputing)" : "snapshots (Gram)", ++done, work);
    }
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) { /* G[I, I] = X_Iᵀ X_I */
        double *gi = G[c][i] + i0 * S + i0;
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nb, (int)rc->n, 1.0, H[c][i], (int)rc->n,
                    H[c][i], (int)rc->n, 0.0, gi, (int)S);
      }
    }
  }
  /* eigenvectors of every Gram matrix: the coefficients of the basis */
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    for (int i = 0; i < rc->nmembers; i++) {
      RMember *mb = &rc->members[i];
      const char *range = pca_gram_out_of_range(S, G[c][i], big[c][i]);
      if (range) {
        npg_fail(err, errlen, "class %s, member %s: snapshot %s; rescale the data, or give --mem enough to keep the snapshots in memory (their PCA is scale-invariant)", rc->label, mb->name, range);
        goto done;
      }
      if (mb->center) { /* J G J, and d the mean of the shifted snapshots */
        double *g = G[c][i], all = 0;
        for (long a = 0; a < S; a++) {
          double row = 0;
          for (long e = 0; e < S; e++) row += g[a * S + e];
          lam[a] = row / (double)S;
          all += row;
        }
        all /= (double)S * (double)S;
        for (long a = 0; a < S; a++)
          for (long e = 0; e < S; e++) g[a * S + e] += all - lam[a] - lam[e];
        cblas_dscal((int)rc->n, 1.0 / (double)S, D[c][i], 1);
      }
      int k = 0, cap = mb->center ? mb->cap - 1 : mb->cap;
      long kmax = cap < S ? cap : S;
      free(V);
      if (!(V = npg_malloc(sizeof(double) * (size_t)(S * (kmax ? kmax : 1))))) goto oom;
      int info = pca_top_eigen(S, G[c][i], kmax, lam, V); /* G whole: either layout */
      if (info != 0) {
        npg_fail(err, errlen, "class %s, member %s: eigendecomposition of the Gram matrix failed (LAPACK info %d)",
              rc->label, mb->name, info);
        goto done;
      }
      double total = 0, run = 0;
      for (long a = 0; a < S; a++) total += fmax(lam[a], 0);
      mb->captured = 1;
      if (total > 0) {
        while (k < S && k < cap && lam[S - 1 - k] > 1e-20 * lam[S - 1]) {
          /* what is left is rounding (a centered Gram matrix has a null vector, 1) */
          if (k > 0 && total - run <= (double)S * DBL_EPSILON * total) break;
          run += lam[S - 1 - k];
          k++;
          if (run >= mb->energy * total) break;
        }
        mb->captured = run / total;
      }
      mb->lost = fmax(0, 1 - mb->captured);
      free(mb->sv);
      if (!(mb->sv = npg_malloc(sizeof(double) * (size_t)S))) goto oom;
      mb->nsv = S;
      for (long a = 0; a < S; a++) mb->sv[a] = sqrt(fmax(lam[S - 1 - a], 0));
      mb->kept = kk[c][i] = k;
      /* column a of W = V[:, a] / sqrt(λ), kept in G's place (S x k, row-major with leading dimension S) */
      for (long s2 = 0; s2 < S; s2++)
        for (int a = 0; a < k; a++) G[c][i][s2 * S + a] = V[a * S + s2] / sqrt(lam[S - 1 - a]);
      if (!(U[c][i] = npg_calloc((size_t)(rc->n * (k ? k : 1)), sizeof(double)))) goto oom;
    }
  }
  /* pass 2: U += x_s ⊗ W[s, :] */
  for (long k = 0; k < S; k++) {
    if (train_eval_sample(src, f, k, err, errlen)) goto done;
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        if (!kk[c][i]) continue;
        if (train_member_value(m, f, &rc->members[i], k, rc->n, tmp, err, errlen)) goto done;
        if (X0[c][i]) cblas_daxpy((int)rc->n, -1.0, X0[c][i], 1, tmp, 1);
        cblas_dger(CblasRowMajor, (int)rc->n, kk[c][i], 1.0, tmp, 1, G[c][i] + k * S, 1, U[c][i], kk[c][i]);
      }
    }
    progress_show(opt->progress, "snapshots (basis)", k + 1, S);
  }
  /* centered members: U_c -= d (1ᵀW), then [μ, U_c] orthonormalized */
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    for (int i = 0; i < rc->nmembers; i++) {
      if (!X0[c][i]) continue;
      int k = kk[c][i];
      for (int a = 0; a < k; a++) {
        double w = 0;
        for (long s2 = 0; s2 < S; s2++) w += G[c][i][s2 * S + a];
        tmp[a] = w;
      }
      if (k > 0) cblas_dger(CblasRowMajor, (int)rc->n, k, -1.0, D[c][i], 1, tmp, 1, U[c][i], k);
      cblas_daxpy((int)rc->n, 1.0, X0[c][i], 1, D[c][i], 1); /* μ = x₀ + d */
      double *parts[2] = {D[c][i], U[c][i]}, *Q = NULL;
      int ks[2] = {1, k}, mm = 0;
      if (pca_in_order(rc->n, 2, parts, ks, &Q, &mm, err, errlen)) goto done;
      free(U[c][i]);
      U[c][i] = Q;
      rc->members[i].kept = kk[c][i] = mm;
    }
  }
  rc = 0;
  goto done;
oom:
  npg_fail(err, errlen, "out of memory for the Gram matrices of %ld samples", S);
done:
  for (int c = 0; c < m->nclasses; c++) {
    for (int i = 0; G && G[c] && i < m->classes[c].nmembers; i++) free(G[c][i]);
    for (int i = 0; H && H[c] && i < m->classes[c].nmembers; i++) free(H[c][i]);
    for (int i = 0; Y && Y[c] && i < m->classes[c].nmembers; i++) free(Y[c][i]);
    for (int i = 0; X0 && X0[c] && i < m->classes[c].nmembers; i++) free(X0[c][i]);
    for (int i = 0; D && D[c] && i < m->classes[c].nmembers; i++) free(D[c][i]);
    if (G) free(G[c]);
    if (H) free(H[c]);
    if (Y) free(Y[c]);
    if (X0) free(X0[c]);
    if (D) free(D[c]);
    if (big) free(big[c]);
  }
  free(big);
  free(G);
  free(H);
  free(Y);
  free(X0);
  free(D);
  free(lam);
  free(V);
  return rc;
}

/* Record a member's PCA (its size, lost energy and spectrum). */
static void take_pca(RMember *mb, PcaMember *p) {
  mb->kept = p->k;
  mb->lost = p->lost;
  mb->captured = 1 - p->lost;
  free(mb->sv);
  mb->sv = p->sv;
  mb->nsv = p->nsv;
  p->sv = NULL;
}

/* The class basis by the paper's way (§6.1, §9): one PCA per member, the
 * member bases concatenated and re-orthonormalized. X[i]: member i's
 * snapshots, n x S column-major; `pre` (over ranks): the members' PCAs
 * already made (dist_member_pcas), taken over. */
int train_member_bases(RClass *rc, long S, double *const *X, PcaMember *pre, char *err, size_t errlen) {
  double **U = npg_calloc((size_t)rc->nmembers + 1, sizeof(double *));
  int *kk = npg_calloc((size_t)rc->nmembers + 1, sizeof(int)), rc_ok = U && kk ? 0 : -1;
  for (int i = 0; i < rc->nmembers && rc_ok == 0; i++) {
    RMember *mb = &rc->members[i];
    PcaMember p;
    if (pre) p = pre[i], memset(&pre[i], 0, sizeof pre[i]);
    else rc_ok = pca_basis(rc->n, S, X[i], mb->cap, mb->energy, mb->center, &p, err, errlen);
    if (rc_ok) break;
    U[i] = p.U;
    kk[i] = p.k;
    take_pca(mb, &p);
  }
  if (rc_ok == 0) rc_ok = pca_merge(rc->n, rc->nmembers, U, kk, &rc->B, &rc->m, err, errlen);
  for (int i = 0; U && i < rc->nmembers; i++) free(U[i]);
  free(U);
  free(kk);
  return rc_ok;
}

/* --merge joint (DESIGN §5): one PCA of the members' snapshot blocks, each
 * scaled to unit norm first; centered (when the first member is), each
 * block minus its own mean, and the class basis the orthonormalization of
 * [μ_1 … μ_r, U_c], at most Σ cap vectors. Every member reports the joint
 * PCA. */
static int joint_basis(RClass *rc, long S, double *const *X, char *err, size_t errlen) {
  size_t n = (size_t)rc->n * (size_t)S;
  int r = rc->nmembers, cap = 0, rc_ok = -1;
  bool center = rc->members[0].center;
  double energy = 1;
  double *J = npg_malloc(sizeof(double) * n * (size_t)r), *mu = npg_malloc(sizeof(double) * (size_t)(rc->n * r + 1));
  double **parts = npg_calloc((size_t)r + 1, sizeof(double *));
  int *ks = npg_calloc((size_t)r + 1, sizeof(int));
  PcaMember p = {0};
  if (!J || !mu || !parts || !ks) goto done;
  for (int i = 0; i < r; i++) {
    double *Ji = J + (size_t)i * n, *mi = mu + (size_t)i * (size_t)rc->n;
    memcpy(Ji, X[i], sizeof(double) * n);
    if (center) {
      pca_mean(rc->n, S, X[i], mi);
      for (long s = 0; s < S; s++) cblas_daxpy((int)rc->n, -1.0, mi, 1, Ji + s * rc->n, 1);
    }
    double nrm = cblas_dnrm2((int)n, Ji, 1);
    if (nrm > 0) cblas_dscal((int)n, 1 / nrm, Ji, 1);
    cap += rc->members[i].cap;
    energy = fmin(energy, rc->members[i].energy);
    parts[i] = mi;
    ks[i] = 1;
  }
  if (center) cap = cap > r ? cap - r : 0;
  if (pca_basis(rc->n, S * r, J, cap, energy, false, &p, err, errlen)) goto done;
  if (center) {
    parts[r] = p.U;
    ks[r] = p.k;
    int mm = 0;
    rc_ok = pca_in_order(rc->n, r + 1, parts, ks, &rc->B, &mm, err, errlen);
    rc->m = mm;
  } else {
    rc_ok = pca_merge(rc->n, 1, &p.U, &p.k, &rc->B, &rc->m, err, errlen);
  }
  for (int i = 0; rc_ok == 0 && i < r; i++) {
    RMember *mb = &rc->members[i];
    mb->kept = (int)rc->m;
    mb->lost = p.lost;
    mb->captured = 1 - p.lost;
    free(mb->sv);
    mb->nsv = p.nsv;
    if ((mb->sv = npg_malloc(sizeof(double) * (size_t)(p.nsv + 1)))) memcpy(mb->sv, p.sv, sizeof(double) * (size_t)p.nsv);
    else rc_ok = -1;
  }
done:
  free(J);
  free(mu);
  free(parts);
  free(ks);
  free(p.U);
  free(p.sv);
  return rc_ok;
}

/* Whether --keep-bases `list` (comma-separated) names class `c` (a member
 * or the class, as --basis names them); *unknown set to the first name
 * that names nothing (NULL: none). "all" names every class. */
static bool keep_named(const Model *m, const char *list, int c, char *unknown, size_t ulen) {
  bool kept = false;
  for (const char *p = list; p && *p;) {
    size_t len = strcspn(p, ",");
    char name[256];
    snprintf(name, sizeof name, "%.*s", (int)(len < sizeof name ? len : sizeof name - 1), p);
    bool any = strcmp(name, "all") == 0;
    kept |= any;
    for (int k = 0; k < m->nclasses; k++)
      for (int i = 0; i < m->classes[k].nmembers; i++) {
        int level = override_level(&m->classes[k], &m->classes[k].members[i], name);
        any |= level >= 2;
        kept |= level >= 2 && k == c;
      }
    if (!any && unknown && !unknown[0]) snprintf(unknown, ulen, "%s", name);
    p += len + (p[len] == ',');
  }
  return kept;
}

/* The model's layout for the dims sample 0 binds, with every member's
 * options set and the --basis names checked. NULL with `err`. */
static Model *begin_training(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                             size_t errlen) {
  if (src->count < 1) {
    npg_fail(err, errlen, "no training samples");
    return NULL;
  }
  if (src->set(src->user, f, 0) != 0 || npg_full_eval(f, 0) != 0) { /* sample 0 binds every dim */
    npg_fail(err, errlen, "%s", npg_full_error(f));
    return NULL;
  }
  long *dims = npg_calloc((size_t)prog->dims.n + 1, sizeof(long));
  if (!dims) return npg_fail(err, errlen, "out of memory"), NULL;
  for (int i = 0; i < prog->dims.n; i++) dims[i] = full_dim_size(f, i);
  Model *m = model_layout(prog, dims, err, errlen);
  free(dims);
  if (!m) return NULL;
  m->samples = src->count;
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++) member_options(m, &m->classes[c], &m->classes[c].members[i], opt);
  char unknown[256] = ""; /* a misspelt --keep-bases name is refused before training, not after */
  if (m->nclasses > 0) keep_named(m, opt->keep_bases, 0, unknown, sizeof unknown);
  if (unknown[0])
    npg_fail(err, errlen, "--keep-bases %s: no quantity or class of that name (a quantity, a class m_x, or all)",
             unknown);
  if (unknown[0] || check_overrides(m, opt, err, errlen)) {
    model_free(m);
    return NULL;
  }
  return m;
}

int train_fail_hook(const TrainOptions *opt, long k, char *err, size_t errlen) {
  if (!opt->dist || k != dist_rank() || !dist_fail_here()) return 0;
  return npg_fail(err, errlen, "training sample %ld: NPG_MPI_FAIL_RANK=%d: this rank stops after its first sample (a test hook)",
                  k, dist_rank());
}

/* Step 1: every member's snapshots in memory (sn->X), or, when they need
 * more than opt->mem, their bases by the method of snapshots (sn->U, sn->k;
 * *gram set). Marks which diagonal operators stay SPD. */
static int take_snapshots(Model *m, NpgFull *f, const SampleSource *src, const TrainOptions *opt, Snapshots *sn,
                          bool *gram, char *err, size_t errlen) {
  long S = src->count, maxn = 1;
  size_t need = 0;
  for (int c = 0; c < m->nclasses; c++) {
    need += sizeof(double) * (size_t)m->classes[c].n * (size_t)S * (size_t)m->classes[c].nmembers;
    maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
  }
  *gram = opt->mem && need > opt->mem;
  if (*gram && opt->dist && dist_size() > 1)
    return npg_fail(err, errlen,
                    "the snapshots need %.3g GB, more than --mem %.3g GB: training over MPI ranks keeps them in "
                    "memory (the method of snapshots runs on one process): raise --mem",
                    (double)need / 1e9, (double)opt->mem / 1e9);
  if (*gram && opt->joint)
    return npg_fail(err, errlen,
                    "the snapshots need %.3g GB, more than --mem %.3g GB, and --merge joint needs them in memory: raise "
                    "--mem or use --merge concat (the method of snapshots)",
                    (double)need / 1e9, (double)opt->mem / 1e9);
  sn->S = S;
  double *tmp = npg_malloc(sizeof(double) * (size_t)(maxn > S ? maxn : S));
  if (!tmp || !(sn->X = npg_calloc((size_t)m->nclasses + 1, sizeof(double **))) ||
      !(sn->U = npg_calloc((size_t)m->nclasses + 1, sizeof(double **))) ||
      !(sn->k = npg_calloc((size_t)m->nclasses + 1, sizeof(int *))))
    goto oom;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(sn->X[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) ||
        !(sn->U[c] = npg_calloc((size_t)rc->nmembers, sizeof(double *))) || !(sn->k[c] = npg_calloc((size_t)rc->nmembers, sizeof(int))))
      goto oom;
    for (int i = 0; !*gram && i < rc->nmembers; i++)
      if (!(sn->X[c][i] = npg_malloc(sizeof(double) * (size_t)rc->n * (size_t)S))) goto oom;
  }
  train_mark_spd(m);
  int rc = 0;
  if (*gram) rc = snapshot_bases(m, f, src, opt, sn->U, sn->k, tmp, err, errlen);
  /* over ranks (opt->dist): rank r takes the samples k ≡ r (mod N), then
   * the columns are gathered on every rank (a rank that fails returns
   * here, before the gather: its caller ends the job) */
  int rank = opt->dist ? dist_rank() : 0, N = opt->dist ? dist_size() : 1;
  for (long k = rank; !*gram && rc == 0 && k < S; k += N) {
    if (k > 0 && train_eval_sample(src, f, k, err, errlen)) rc = -1;
    for (int c = 0; rc == 0 && c < m->nclasses; c++) {
      RClass *cl = &m->classes[c];
      for (int i = 0; rc == 0 && i < cl->nmembers; i++)
        rc = train_member_value(m, f, &cl->members[i], k, cl->n, sn->X[c][i] + (size_t)k * (size_t)cl->n, err, errlen);
    }
    if (rc == 0) rc = train_check_spd(m, f, tmp, err, errlen);
    if (rc == 0) rc = train_fail_hook(opt, k, err, errlen);
    progress_show(opt->progress, "snapshots", k + 1, S);
  }
  if (rc == 0 && !*gram && N > 1 && (rc = dist_gather_snapshots(m, sn->X, S, err, errlen)) == 0) {
    dist_and_spd(m);
    progress_show(opt->progress, "snapshots", S, S); /* every rank's are in */
  }
  free(tmp);
  return rc;
oom:
  free(tmp);
  return npg_fail(err, errlen, "out of memory for the snapshots of %ld samples", S);
}

/* A class basis completed to full rank (convergence tests: the PCA
 * directions first, then the rest of the space), and one direction for a
 * class whose every snapshot is zero (lifting gives 0). */
int train_complete_basis(RClass *rc, bool full_rank, char *err, size_t errlen) {
  if (full_rank && rc->m < rc->n) {
    double *eye = npg_calloc((size_t)(rc->n * rc->n), sizeof(double)), *B = NULL;
    double *parts[2] = {rc->B, eye};
    int ks[2] = {(int)rc->m, (int)rc->n};
    if (!eye) return npg_fail(err, errlen, "out of memory completing the basis of class %s", rc->label);
    for (long e = 0; e < rc->n; e++) eye[e * rc->n + e] = 1;
    int rc_ok = pca_merge(rc->n, 2, parts, ks, &B, &rc->m, err, errlen);
    free(eye);
    if (rc_ok != 0) return -1;
    free(rc->B);
    rc->B = B;
  }
  if (rc->m == 0) {
    free(rc->B);
    if (!(rc->B = npg_calloc((size_t)rc->n, sizeof(double)))) return npg_fail(err, errlen, "out of memory");
    rc->B[0] = 1;
    rc->m = 1;
  }
  if (!rc->B_mapped && pca_fix_signs(rc->n, rc->m, rc->B)) return npg_fail(err, errlen, "out of memory");
  return 0;
}

/* Step 2: one basis per class (DESIGN §5), sized into the tensors. */
static int build_bases(Model *m, const Snapshots *sn, bool gram, const TrainOptions *opt, char *err, size_t errlen) {
  /* over ranks: the members' PCAs shared out, each made on one rank */
  PcaMember **pre = NULL;
  if (opt->dist && dist_size() > 1 && !gram && !opt->joint && dist_member_pcas(m, sn->S, sn->X, &pre, err, errlen))
    return -1;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    int rc_ok = 0;
    if (opt->joint && rc->nmembers > 1) rc_ok = joint_basis(rc, sn->S, sn->X[c], err, errlen);
    else if (gram) rc_ok = pca_merge(rc->n, rc->nmembers, sn->U[c], sn->k[c], &rc->B, &rc->m, err, errlen);
    else rc_ok = train_member_bases(rc, sn->S, sn->X[c], pre ? pre[c] : NULL, err, errlen);
    if (rc_ok != 0) {
      dist_free_pcas(m, pre);
      if (!err[0]) npg_fail(err, errlen, "out of memory building the basis of class %s", rc->label);
      return -1;
    }
    if (train_complete_basis(rc, opt->full_rank, err, errlen)) return dist_free_pcas(m, pre), -1;
  }
  dist_free_pcas(m, pre);
  model_size_tensors(m);
  return 0;
}

/* The wall and CPU (this process's threads) seconds since t0[0], t0[1]
 * into sec[0], cpu[0]; t0 moved to now. */
static void phase_time(struct timespec t0[2], double *sec, double *cpu) {
  struct timespec t[2];
  clock_gettime(CLOCK_MONOTONIC, &t[0]);
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t[1]);
  *sec = (double)(t[0].tv_sec - t0[0].tv_sec) + 1e-9 * (double)(t[0].tv_nsec - t0[0].tv_nsec);
  *cpu = (double)(t[1].tv_sec - t0[1].tv_sec) + 1e-9 * (double)(t[1].tv_nsec - t0[1].tv_nsec);
  t0[0] = t[0], t0[1] = t[1];
}

/* Step 3: the projections between classes and every tensor pre-multiplied.
 * Over ranks, with progress on, rank 0 says how long its own rows took and
 * how long the sums over ranks (the wait for the slowest rank included). */
static int premultiply_all(Model *m, NpgFull *f, bool progress, bool dist, char *err, size_t errlen) {
  long ntensors = 0, done = 0;
  int rank = dist ? dist_rank() : 0, N = dist ? dist_size() : 1;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      ntensors += rt->nnum;
      for (int k = 0; k < rt->nops; k++) ntensors += rt->ops[k].ntensors;
    }
  double flops = 0, own[2] = {0, 0}, sum[2] = {0, 0}, d[2];
  struct timespec t0[2] = {{0}};
  phase_time(t0, &d[0], &d[1]);
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    RClass *cy = &m->classes[m->qclass[rs->q]];
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      if (rt->proj_name) {
        RClass *cw = &m->classes[m->qclass[rt->named_q]];
        if (!(rt->proj = npg_malloc(sizeof(double) * (size_t)(cy->m * cw->m))))
          return npg_fail(err, errlen, "out of memory while training");
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)cy->m, (int)cw->m, (int)cy->n, 1.0, cy->B,
                    (int)cy->m, cw->B, (int)cw->m, 0.0, rt->proj, (int)cw->m);
      }
      RTERM_FOR_TENSORS(rt, x) {
        if (x->data) { /* pre-multiplied out of core by the streamed bases (stream.c) */
          progress_show(progress, "pre-multiplication", ++done, ntensors);
          continue;
        }
        /* over ranks: every rank its share of the rows, summed on all */
        if (premultiply_part(m, f, x, cy->B, cy->n, cy->m, rank, N, &flops, err, errlen)) return -1;
        phase_time(t0, &d[0], &d[1]);
        own[0] += d[0], own[1] += d[1];
        if (N > 1) dist_allreduce_sum(x->data, x->rows * x->cols);
        phase_time(t0, &d[0], &d[1]);
        sum[0] += d[0], sum[1] += d[1];
        progress_show(progress, "pre-multiplication", ++done, ntensors);
      }
    }
  }
  if (progress && N > 1)
    fprintf(stderr, "pre-multiplication over ranks: %.2f s (%.2f s CPU) this rank's rows, %.2f s (%.2f s CPU) summing "
            "the tensors\n", own[0], own[1], sum[0], sum[1]);
  return 0;
}

/* Issue 30: the classes whose bases are streamed — used in training, then
 * dropped (drop_bases) — marked once the reduction of every stage is
 * chosen (an interpolated stage's class is needed): the streamable ones
 * (model_class_streamable) --keep-bases does not name. */
static bool mark_streamed(Model *m, const TrainOptions *opt) {
  bool any = false; /* whose floors are still to be taken */
  for (int c = 0; c < m->nclasses; c++) { /* the names were checked by begin_training */
    m->classes[c].streamed = opt->stream && !keep_named(m, opt->keep_bases, c, NULL, 0) && model_class_streamable(m, c);
    any |= m->classes[c].streamed && !m->classes[c].floors_known;
  }
  return any;
}

/* Sample k's projection floors (model_projection_floor) of every quantity
 * of a streamed class, added to their means over the S samples: verify
 * reports them in place of the held-out floors it cannot measure without
 * the basis. `gram`: the values are the evaluator's (the sample just
 * evaluated), else the snapshots'. */
static void take_floors(Model *m, NpgFull *f, const Snapshots *sn, bool gram, long k, long S, double *proj, double *y) {
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; m->classes[c].streamed && !m->classes[c].floors_known && i < m->classes[c].nmembers; i++) {
      RMember *mb = &m->classes[c].members[i];
      if (mb->q < 0) continue; /* a numerator is no quantity verify reports */
      const double *val = gram ? npg_full_get(f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL)
                               : sn->X[c][i] + (size_t)k * (size_t)m->classes[c].n;
      double fl[2];
      model_projection_floor(&m->classes[c], val, proj, y, fl);
      mb->floor_l2 += fl[0] / (double)S, mb->floor_linf += fl[1] / (double)S;
    }
}

/* Step 5: the streamed classes' bases dropped (their floors taken). */
static void drop_bases(Model *m) {
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!rc->streamed) continue;
    if (rc->B_mapped) munmap(rc->B, rc->B_mapped);
    else free(rc->B);
    rc->B = NULL, rc->B_mapped = 0;
  }
}

static int fit_externs_floors(Model *m, NpgFull *f, const SampleSource *src, const Snapshots *sn, bool gram,
                              bool floors, double *proj, double *y, bool progress, bool dist, char *err, size_t errlen);

/* Step 4: every extern's learned map (paper §8.3): the training samples'
 * reduced inputs and values, from the snapshots or, after the method of
 * snapshots, recomputed; with `floors`, in the same pass the streamed
 * classes' training floors (take_floors). */
static int fit_externs(Model *m, NpgFull *f, const SampleSource *src, const Snapshots *sn, bool gram, bool floors,
                       bool progress, bool dist, char *err, size_t errlen) {
  long maxn = 1, maxm = 1;
  for (int c = 0; floors && c < m->nclasses; c++)
    if (m->classes[c].streamed && !m->classes[c].floors_known)
      maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn, maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  double *y = floors ? malloc(sizeof(double) * (size_t)maxn) : NULL, *proj = floors ? malloc(sizeof(double) * (size_t)maxm) : NULL;
  if (floors && (!y || !proj)) return free(y), free(proj), npg_fail(err, errlen, "out of memory measuring the training floors");
  int rc = fit_externs_floors(m, f, src, sn, gram, floors, proj, y, progress, dist, err, errlen);
  free(y), free(proj);
  return rc;
}

static int fit_externs_floors(Model *m, NpgFull *f, const SampleSource *src, const Snapshots *sn, bool gram, bool floors,
                              double *proj, double *y, bool progress, bool dist, char *err, size_t errlen) {
  long S = src->count;
  /* recomputed over ranks (out of core): rank r its samples k ≡ r (mod N),
   * the others' rows zero, then summed */
  int N = gram && dist ? dist_size() : 1, rank = N > 1 ? dist_rank() : 0;
  for (int i = 0; i < m->nexterns; i++) {
    RExtern *x = &m->externs[i];
    long mz = m->classes[m->qclass[x->q]].m;
    x->S = S;
    if (!(x->X = npg_calloc((size_t)(S * x->d + 1), sizeof(double))) || !(x->Z = npg_calloc((size_t)(S * mz) + 1, sizeof(double))))
      return npg_fail(err, errlen, "out of memory while training");
  }
  for (long k = rank; k < S && (m->nexterns > 0 || floors); k += N) {
    if (gram && train_eval_sample(src, f, k, err, errlen)) return -1; /* recompute: no snapshot was kept */
    for (int i = 0; i < m->nexterns; i++) {
      RExtern *x = &m->externs[i];
      long mz = m->classes[m->qclass[x->q]].m, off = 0;
      for (int j = 0; j <= x->nin; j++) {
        int q = j < x->nin ? x->in_q[j] : x->q;
        RClass *rc = &m->classes[m->qclass[q]];
        const double *val = npg_full_get(f, ((Sym *)m->prog->quantities.v[q])->name, NULL);
        if (!gram) {
          int mi = 0;
          while (rc->members[mi].q != q) mi++;
          val = sn->X[m->qclass[q]][mi] + (size_t)k * (size_t)rc->n;
        }
        double *dst = j < x->nin ? x->X + k * x->d + off : x->Z + k * mz;
        cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)rc->m, 1.0, rc->B, (int)rc->m, val, 1, 0.0, dst, 1);
        if (j < x->nin) off += rc->m;
      }
    }
    if (floors) take_floors(m, f, sn, gram, k, S, proj, y);
    if (gram) progress_show(progress, floors ? "extern samples, floors" : "extern samples", k + 1, S);
  }
  for (int i = 0; N > 1 && i < m->nexterns; i++) {
    RExtern *x = &m->externs[i];
    dist_allreduce_sum(x->X, S * x->d);
    dist_allreduce_sum(x->Z, S * m->classes[m->qclass[x->q]].m);
  }
  for (int c = 0; N > 1 && floors && c < m->nclasses; c++) /* every rank's samples' floors summed */
    for (int i = 0; m->classes[c].streamed && !m->classes[c].floors_known && i < m->classes[c].nmembers; i++) {
      dist_allreduce_sum(&m->classes[c].members[i].floor_l2, 1);
      dist_allreduce_sum(&m->classes[c].members[i].floor_linf, 1);
    }
  return 0;
}

/* Step 3b: the stages opt->interp_stage names made interpolated, and with
 * validation samples every other eligible stage reduced the way that
 * measures better there (DESIGN §12). */
static bool named_in(const char *const *names, int n, const char *name) {
  for (int j = 0; j < n; j++)
    if (strcmp(names[j], name) == 0) return true;
  return false;
}

static int interpolate_stages(Model *m, NpgFull *f, const TrainOptions *opt, char *err, size_t errlen) {
  double over = opt->interp_oversample > 0 ? opt->interp_oversample : TRAIN_INTERP_OVERSAMPLE;
  /* the program's `basis w: reduce interp`, unless the command line says galerkin */
  for (int i = 0; i < m->nstages; i++) {
    const Sym *s = m->stages[i].st->sym;
    if (s->reduce != STAGE_REDUCE_INTERP || named_in(opt->galerkin_stage, opt->ngalerkin, s->name) ||
        named_in(opt->interp_stage, opt->ninterp, s->name))
      continue;
    if (interp_train_stage(m, f, i, over, err, errlen)) return -1;
    m->stages[i].choice_reason = interp_reasons[INTERP_FORCED];
  }
  for (int j = 0; j < opt->ninterp; j++) {
    int i = 0;
    while (i < m->nstages && strcmp(m->stages[i].st->sym->name, opt->interp_stage[j]) != 0) i++;
    if (i == m->nstages)
      return npg_fail(err, errlen, "--reduce %s:interp: the program has no stage '%s'", opt->interp_stage[j],
                      opt->interp_stage[j]);
    if (interp_train_stage(m, f, i, over, err, errlen)) return -1;
    m->stages[i].choice_reason = interp_reasons[INTERP_FORCED];
    if (opt->progress)
      fprintf(stderr, "stage %s interpolated: %ld of %ld entries (m %ld), ‖(PB)⁺‖ %.3g\n", opt->interp_stage[j],
              m->stages[i].interp->k, m->classes[m->qclass[m->stages[i].q]].n, m->stages[i].interp->m,
              m->stages[i].interp->pinv_norm);
  }
  for (int j = 0; j < opt->ngalerkin; j++) {
    int i = 0;
    while (i < m->nstages && strcmp(m->stages[i].st->sym->name, opt->galerkin_stage[j]) != 0) i++;
    if (i == m->nstages)
      return npg_fail(err, errlen, "--reduce %s:galerkin: the program has no stage '%s'", opt->galerkin_stage[j],
                      opt->galerkin_stage[j]);
    if (named_in(opt->interp_stage, opt->ninterp, opt->galerkin_stage[j]))
      return npg_fail(err, errlen, "stage %s is forced both to interpolation and to Galerkin", opt->galerkin_stage[j]);
  }
  return opt->valid ? tune_choose_reductions(m, f, opt->valid, opt, err, errlen) : 0;
}

/* Steps 1–2: the bases, from snapshots in memory, by the method of
 * snapshots, or out of core when the bases exceed opt->mem (ooc.c; then,
 * as after the method of snapshots, *gram: no snapshot is kept). */
static int bases(Model *m, NpgFull *f, const SampleSource *src, const TrainOptions *opt, Snapshots *sn, bool *gram,
                 struct timespec t[2], double *sec, double *cpu, char *err, size_t errlen) {
  if (ooc_needed(m, opt)) {
    *gram = true;
    mark_streamed(m, opt); /* their floors taken in the passes (the choice is made again after interpolation) */
    return ooc_bases(m, f, src, opt, err, errlen) || (phase_time(t, &sec[0], &cpu[0]), 0);
  }
  return take_snapshots(m, f, src, opt, sn, gram, err, errlen) || (phase_time(t, &sec[0], &cpu[0]), 0) ||
         build_bases(m, sn, *gram, opt, err, errlen);
}

/* Training as named steps (DESIGN §5), each step's wall and CPU time kept (out of core: the
 * snapshots and the bases are one step, timed as snapshots). */
Model *train_model(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen) {
  Snapshots sn = {0};
  bool gram = false;
  err[0] = 0;
  struct timespec t[2];
  clock_gettime(CLOCK_MONOTONIC, &t[0]);
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t[1]);
  Model *m = begin_training(prog, f, src, opt, err, errlen);
  double *sec = m ? m->phase_seconds : NULL, *cpu = m ? m->phase_cpu : NULL;
  if (!m || bases(m, f, src, opt, &sn, &gram, t, sec, cpu, err, errlen) || (phase_time(t, &sec[1], &cpu[1]), 0) ||
      premultiply_all(m, f, opt->progress, opt->dist, err, errlen) || interpolate_stages(m, f, opt, err, errlen) ||
      (phase_time(t, &sec[2], &cpu[2]), 0) ||
      fit_externs(m, f, src, &sn, gram, mark_streamed(m, opt), opt->progress, opt->dist, err, errlen) ||
      (drop_bases(m), phase_time(t, &sec[3], &cpu[3]), 0)) {
    if (m) free_snapshots(m, &sn);
    model_free(m);
    /* the steps name what failed; a helper that only returned NULL ran out of memory */
    if (!err[0]) npg_fail(err, errlen, "out of memory during training");
    return NULL;
  }
  if (opt->progress)
    fprintf(stderr, "training phases: snapshots %.2f s, bases %.2f s (%s), pre-multiplication %.2f s, externs %.2f s\n",
            m->phase_seconds[0], m->phase_seconds[1],
            ooc_needed(m, opt) ? "out of core, with the snapshots" : gram ? "method of snapshots" : "in memory",
            m->phase_seconds[2], m->phase_seconds[3]);
  free_snapshots(m, &sn);
  return m;
}

/* ---------------------------------------------------------------- truncations (npgc tune) */

struct TrainSet {
  Model *base;              /* layout, member options, SPD marks */
  NpgFull *f;
  const SampleSource *src;
  bool progress;
  Snapshots sn;             /* in memory */
  PcaMember **pm;           /* [class][member]: its ordered basis at its cap */
};

void train_set_free(TrainSet *ts) {
  if (!ts) return;
  for (int c = 0; ts->pm && c < ts->base->nclasses; c++) {
    for (int i = 0; ts->pm[c] && i < ts->base->classes[c].nmembers; i++) free(ts->pm[c][i].U), free(ts->pm[c][i].sv);
    free(ts->pm[c]);
  }
  free(ts->pm);
  if (ts->base) free_snapshots(ts->base, &ts->sn);
  model_free(ts->base);
  free(ts);
}

TrainSet *train_set_new(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                        size_t errlen) {
  TrainSet *ts = npg_calloc(1, sizeof *ts);
  TrainOptions o = *opt;
  bool gram = false;
  err[0] = 0;
  o.mem = 0; /* truncations re-use the snapshots: they stay in memory */
  o.joint = false;
  if (!ts) return NULL;
  ts->f = f, ts->src = src, ts->progress = opt->progress;
  if (!(ts->base = begin_training(prog, f, src, &o, err, errlen)) ||
      take_snapshots(ts->base, f, src, &o, &ts->sn, &gram, err, errlen))
    goto fail;
  Model *m = ts->base;
  if (!(ts->pm = npg_calloc((size_t)m->nclasses + 1, sizeof(PcaMember *)))) goto fail;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(ts->pm[c] = npg_calloc((size_t)rc->nmembers + 1, sizeof(PcaMember)))) goto fail;
    for (int i = 0; i < rc->nmembers; i++) {
      RMember *mb = &rc->members[i];
      if (pca_basis(rc->n, ts->sn.S, ts->sn.X[c][i], mb->cap, mb->energy, mb->center, &ts->pm[c][i], err, errlen))
        goto fail;
    }
    progress_show(ts->progress, "member bases", c + 1, m->nclasses);
  }
  return ts;
fail:
  if (!err[0]) npg_fail(err, errlen, "out of memory while training");
  train_set_free(ts);
  return NULL;
}

int train_set_classes(const TrainSet *ts) { return ts->base->nclasses; }

int train_set_max_cap(const TrainSet *ts, int c) {
  int k = 1;
  for (int i = 0; i < ts->base->classes[c].nmembers; i++) k = ts->pm[c][i].k > k ? ts->pm[c][i].k : k;
  return k;
}

/* Member `mb` keeping the first `k` of its ordered basis `p`: its report. */
static int truncated_member(RMember *mb, const PcaMember *p, int cap, int k) {
  double total = 0, run = 0;
  int r = mb->center ? k - 1 : k; /* a centered basis starts with the mean */
  for (long j = 0; j < p->nsv; j++) total += p->sv[j] * p->sv[j], run += j < r ? p->sv[j] * p->sv[j] : 0;
  mb->cap = cap;
  mb->kept = k;
  mb->lost = total > 0 ? fmax(0, 1 - run / total) : 0;
  mb->captured = 1 - mb->lost;
  mb->nsv = p->nsv;
  if (!(mb->sv = npg_malloc(sizeof(double) * (size_t)(p->nsv + 1)))) return -1;
  memcpy(mb->sv, p->sv, sizeof(double) * (size_t)p->nsv);
  return 0;
}

Model *train_set_model(TrainSet *ts, const int *cap, char *err, size_t errlen) {
  const Model *b = ts->base;
  err[0] = 0;
  Model *m = model_layout(b->prog, b->dims, err, errlen);
  if (!m) return NULL;
  m->samples = b->samples;
  for (int i = 0; i < m->nstages; i++) /* the SPD marks the snapshots set */
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) m->stages[i].terms[t].ops[k].spd = b->stages[i].terms[t].ops[k].spd;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    double **U = npg_calloc((size_t)rc->nmembers + 1, sizeof(double *));
    int *kk = npg_calloc((size_t)rc->nmembers + 1, sizeof(int)), ok = U && kk;
    for (int i = 0; ok && i < rc->nmembers; i++) {
      const PcaMember *p = &ts->pm[c][i];
      RMember *mb = &rc->members[i];
      mb->energy = b->classes[c].members[i].energy;
      mb->center = b->classes[c].members[i].center;
      kk[i] = cap[c] < p->k ? cap[c] : p->k;
      if (!(U[i] = npg_malloc(sizeof(double) * (size_t)(rc->n * (kk[i] ? kk[i] : 1)))) || truncated_member(mb, p, cap[c], kk[i]))
        ok = 0;
      for (long e = 0; ok && e < rc->n; e++) memcpy(U[i] + e * kk[i], p->U + e * p->k, sizeof(double) * (size_t)kk[i]);
    }
    int rc_ok = ok ? pca_merge(rc->n, rc->nmembers, U, kk, &rc->B, &rc->m, err, errlen) : -1;
    for (int i = 0; U && i < rc->nmembers; i++) free(U[i]);
    free(U);
    free(kk);
    if (rc_ok || train_complete_basis(rc, false, err, errlen)) {
      if (!err[0]) npg_fail(err, errlen, "out of memory building the basis of class %s", rc->label);
      model_free(m);
      return NULL;
    }
  }
  model_size_tensors(m);
  if (premultiply_all(m, ts->f, false, false, err, errlen) || fit_externs(m, ts->f, ts->src, &ts->sn, false, false, false, false, err, errlen)) {
    model_free(m);
    return NULL;
  }
  return m;
}
