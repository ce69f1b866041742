/* snapshots.c — the method of snapshots (DESIGN §5; Sirovich 1987): the
 * member bases of training when the snapshots do not fit in --mem. Only
 * S x S Gram matrices G = XᵀX are held, built by passes that recompute the
 * samples (train_gram_blocks shares the budget between a held block and a
 * batch); their eigenvectors V give U = X V Λ^(-1/2), formed in a last
 * pass. train.c's train_take_snapshots calls it instead of keeping the snapshot
 * matrices; the bases are the in-memory PCA's (pca_basis) to rounding
 * (test_reduce's snapshots_match_memory compares the projectors). */
#include <cblas.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "train.h"
#include "train_steps.h"

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

/* One member's state in the method of snapshots. */
typedef struct GramMember {
  RMember *mb;
  double *G;   /* S x S: XᵀX (of the shifted snapshots), then W = V Λ^(-1/2) in its first k columns */
  double *H;   /* the held block: b samples of n entries */
  double *Y;   /* the batch of later samples: q of n (NULL when q is 0) */
  double *x0;  /* centered: the shift, the member's first sample (NULL: uncentered) */
  double *d;   /* centered: the sum of the shifted snapshots, then their mean d, then μ = x₀ + d */
  double big;  /* the largest |entry| that entered G */
} GramMember;

/* The method of snapshots under way: every member's state, [class][member]. */
typedef struct Gram {
  Model *m;
  Full *f;
  const SampleSource *src;
  const TrainOptions *opt;
  long S, b, q;        /* samples; the held block; the batch (train_gram_blocks) */
  GramMember **gm;
  double *lam;         /* S eigenvalues */
  double *tmp;         /* room for max(largest class, S) doubles */
  char *err;
  size_t errlen;
} Gram;

static void gram_free(Gram *g) {
  for (int c = 0; g->gm && c < g->m->nclasses; c++) {
    for (int i = 0; g->gm[c] && i < g->m->classes[c].nmembers; i++) {
      GramMember *x = &g->gm[c][i];
      free(x->G), free(x->H), free(x->Y), free(x->x0), free(x->d);
    }
    free(g->gm[c]);
  }
  free(g->gm);
  free(g->lam);
}

/* Every member's Gram matrix (zero), held block and batch, and for a
 * centered one its shift and sum. 0, or -1 when out of memory. */
static int gram_alloc(Gram *g) {
  Model *m = g->m;
  long S = g->S;
  if (!(g->gm = mem_calloc((size_t)m->nclasses + 1, sizeof(GramMember *))) || !(g->lam = mem_malloc(sizeof(double) * (size_t)S)))
    return -1;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(g->gm[c] = mem_calloc((size_t)rc->nmembers + 1, sizeof(GramMember)))) return -1;
    for (int i = 0; i < rc->nmembers; i++) {
      GramMember *x = &g->gm[c][i];
      x->mb = &rc->members[i];
      if (!(x->G = mem_calloc((size_t)(S * S), sizeof(double))) || !(x->H = mem_malloc(sizeof(double) * (size_t)(rc->n * g->b))) ||
          (g->q > 0 && !(x->Y = mem_malloc(sizeof(double) * (size_t)(rc->n * g->q)))))
        return -1;
      if (x->mb->center &&
          (!(x->x0 = mem_malloc(sizeof(double) * (size_t)rc->n)) || !(x->d = mem_calloc((size_t)rc->n, sizeof(double)))))
        return -1;
    }
  }
  return 0;
}

/* G[I, K] = X_Iᵀ X_K for the held block I = [i0, i1) and the batch
 * K = [k0, k] (one sample: a dgemv, faster than a dgemm of one column),
 * and its mirror. */
static void gram_cross(const Gram *g, GramMember *x, long n, long i0, long i1, long k0, long k) {
  long S = g->S, nb = i1 - i0, nk = k + 1 - k0;
  double *G = x->G;
  if (nk == 1)
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)nb, (int)n, 1.0, x->H, (int)n, x->Y, 1, 0.0, G + i0 * S + k0, (int)S);
  else
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nk, (int)n, 1.0, x->H, (int)n, x->Y, (int)n, 0.0,
                G + i0 * S + k0, (int)S);
  for (long a = i0; a < i1; a++)
    for (long e = k0; e <= k; e++) G[e * S + a] = G[a * S + e];
}

/* Pass 1 for the held block [i0, i1): its samples evaluated and held (their
 * SPD marks checked), the samples after it recomputed in batches against
 * it, then the block against itself. `done` counts the evaluations of all
 * passes (of `work`). */
static int gram_pass(Gram *g, long i0, long i1, long *done, long work) {
  Model *m = g->m;
  long S = g->S, nb = i1 - i0;
  for (long k = i0, k0 = i1; k < S; k++) { /* k0: the first sample of the batch */
    if (train_eval_sample(g->src, g->f, k, g->err, g->errlen)) return -1;
    if (k < i1 && train_check_spd(m, g->f, g->tmp, g->err, g->errlen)) return -1;
    bool full = k >= i1 && (k + 1 - k0 == g->q || k + 1 == S);
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        GramMember *x = &g->gm[c][i];
        double *v = k < i1 ? x->H + (k - i0) * rc->n : x->Y + (k - k0) * rc->n;
        if (train_member_value(m, g->f, x->mb, k, rc->n, v, g->err, g->errlen)) return -1;
        if (x->x0) {
          if (k == 0) memcpy(x->x0, v, sizeof(double) * (size_t)rc->n);
          cblas_daxpy((int)rc->n, -1.0, x->x0, 1, v, 1);
          if (k < i1) cblas_daxpy((int)rc->n, 1.0, v, 1, x->d, 1);
        }
        for (long e = 0; k < i1 && e < rc->n; e++) x->big = fmax(x->big, fabs(v[e])); /* what enters G */
        if (full) gram_cross(g, x, rc->n, i0, i1, k0, k);
      }
    }
    if (full) k0 = k + 1;
    progress_show(g->opt->progress, g->b < S ? "snapshots (Gram, recomputing)" : "snapshots (Gram)", ++*done, work);
  }
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    for (int i = 0; i < rc->nmembers; i++) { /* G[I, I] = X_Iᵀ X_I */
      GramMember *x = &g->gm[c][i];
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nb, (int)rc->n, 1.0, x->H, (int)rc->n, x->H,
                  (int)rc->n, 0.0, x->G + i0 * S + i0, (int)S);
    }
  }
  return 0;
}

/* A centered member's Gram matrix made J G J (J = I − 11ᵀ/S), and its d
 * the mean of the shifted snapshots. `rows`: room for S doubles. */
static void gram_center(GramMember *x, long n, long S, double *rows) {
  double *G = x->G, all = 0;
  for (long a = 0; a < S; a++) {
    double row = 0;
    for (long e = 0; e < S; e++) row += G[a * S + e];
    rows[a] = row / (double)S;
    all += row;
  }
  all /= (double)S * (double)S;
  for (long a = 0; a < S; a++)
    for (long e = 0; e < S; e++) G[a * S + e] += all - rows[a] - rows[e];
  cblas_dscal((int)n, 1.0 / (double)S, x->d, 1);
}

/* The member's eigenvectors: how many it keeps (its cap and energy; its
 * report set), and W = V Λ^(-1/2) for them in G's place (S x k, row-major
 * with leading dimension S); *U allocated (zero) for pass 2. */
static int gram_eigen(Gram *g, GramMember *x, const RClass *rc, double **U, int *kk) {
  RMember *mb = x->mb;
  long S = g->S;
  double *lam = g->lam;
  const char *range = pca_gram_out_of_range(S, x->G, x->big);
  if (range)
    return error_set(g->err, g->errlen, "class %s, member %s: snapshot %s; rescale the data, or give --mem enough to keep the snapshots in memory (their PCA is scale-invariant)", rc->label, mb->name, range);
  if (mb->center) gram_center(x, rc->n, S, lam);
  int cap = mb->center ? mb->cap - 1 : mb->cap;
  long kmax = cap < S ? cap : S;
  double *V = mem_malloc(sizeof(double) * (size_t)(S * (kmax ? kmax : 1)));
  if (!V) return error_set(g->err, g->errlen, "out of memory for the Gram matrices of %ld samples", S);
  int info = pca_top_eigen(S, x->G, kmax, lam, V); /* G whole: either layout */
  if (info != 0) {
    free(V);
    return error_set(g->err, g->errlen, "class %s, member %s: eigendecomposition of the Gram matrix failed (LAPACK info %d)",
                     rc->label, mb->name, info);
  }
  free(mb->sv);
  if (!(mb->sv = mem_malloc(sizeof(double) * (size_t)S))) {
    free(V);
    return error_set(g->err, g->errlen, "out of memory for the Gram matrices of %ld samples", S);
  }
  mb->nsv = S;
  for (long a = 0; a < S; a++) mb->sv[a] = sqrt(fmax(lam[S - 1 - a], 0));
  /* the truncation rule of every route (a centered Gram matrix's null
   * vector, 1, is one its rounding stop drops) */
  int k = (int)pca_choose(mb->sv, S, cap, mb->energy, true);
  double total = 0, run = 0;
  for (long a = 0; a < S; a++) total += fmax(lam[a], 0);
  for (int a = 0; a < k; a++) run += lam[S - 1 - a];
  mb->captured = total > 0 ? run / total : 1;
  mb->lost = fmax(0, 1 - mb->captured);
  mb->kept = *kk = k;
  /* column a of W = V[:, a] / sqrt(λ), kept in G's place (S x k, row-major with leading dimension S) */
  for (long s2 = 0; s2 < S; s2++)
    for (int a = 0; a < k; a++) x->G[s2 * S + a] = V[a * S + s2] / sqrt(lam[S - 1 - a]);
  free(V);
  if (!(*U = mem_calloc((size_t)(rc->n * (k ? k : 1)), sizeof(double))))
    return error_set(g->err, g->errlen, "out of memory for the Gram matrices of %ld samples", S);
  return 0;
}

/* Pass 2: every sample recomputed once, U += x_s ⊗ W[s, :] (shifted). */
static int basis_pass(Gram *g, double ***U, int **kk) {
  Model *m = g->m;
  for (long k = 0; k < g->S; k++) {
    if (train_eval_sample(g->src, g->f, k, g->err, g->errlen)) return -1;
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        GramMember *x = &g->gm[c][i];
        if (!kk[c][i]) continue;
        if (train_member_value(m, g->f, x->mb, k, rc->n, g->tmp, g->err, g->errlen)) return -1;
        if (x->x0) cblas_daxpy((int)rc->n, -1.0, x->x0, 1, g->tmp, 1);
        cblas_dger(CblasRowMajor, (int)rc->n, kk[c][i], 1.0, g->tmp, 1, x->G + k * g->S, 1, U[c][i], kk[c][i]);
      }
    }
    progress_show(g->opt->progress, "snapshots (basis)", k + 1, g->S);
  }
  return 0;
}

/* A centered member's basis: U_c −= d (1ᵀW), then [μ = x₀ + d, U_c]
 * orthonormalized in that order (*U replaced, *kk and the report's kept
 * set to its size). */
static int centered_basis(Gram *g, GramMember *x, long n, double **U, int *kk) {
  long S = g->S;
  int k = *kk;
  for (int a = 0; a < k; a++) {
    double w = 0;
    for (long s2 = 0; s2 < S; s2++) w += x->G[s2 * S + a];
    g->tmp[a] = w;
  }
  if (k > 0) cblas_dger(CblasRowMajor, (int)n, k, -1.0, x->d, 1, g->tmp, 1, *U, k);
  cblas_daxpy((int)n, 1.0, x->x0, 1, x->d, 1); /* μ = x₀ + d */
  double *parts[2] = {x->d, *U}, *Q = NULL;
  int ks[2] = {1, k}, mm = 0;
  if (pca_in_order(n, 2, parts, ks, &Q, &mm, g->err, g->errlen)) return -1;
  free(*U);
  *U = Q;
  x->mb->kept = *kk = mm;
  return 0;
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
int train_snapshot_bases(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, double ***U,
                         int **kk, double *tmp, char *err, size_t errlen) {
  Gram g = {m, f, src, opt, src->count, 0, 0, NULL, NULL, tmp, err, errlen};
  long S = g.S, per = 0;
  for (int c = 0; c < m->nclasses; c++) per += m->classes[c].n * m->classes[c].nmembers;
  train_gram_blocks(S, (long)(opt->mem / 2 / sizeof(double) / (size_t)(per ? per : 1)), &g.b, &g.q);
  int rc = -1;
  if (gram_alloc(&g)) {
    error_set(err, errlen, "out of memory for the Gram matrices of %ld samples", S);
    goto done;
  }
  long done = 0, work = 0;
  for (long i0 = 0; i0 < S; i0 += g.b) work += S - i0;
  for (long i0 = 0; i0 < S; i0 += g.b)
    if (gram_pass(&g, i0, i0 + g.b < S ? i0 + g.b : S, &done, work)) goto done;
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++)
      if (gram_eigen(&g, &g.gm[c][i], &m->classes[c], &U[c][i], &kk[c][i])) goto done;
  if (basis_pass(&g, U, kk)) goto done;
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++)
      if (g.gm[c][i].x0 && centered_basis(&g, &g.gm[c][i], m->classes[c].n, &U[c][i], &kk[c][i])) goto done;
  rc = 0;
done:
  gram_free(&g);
  return rc;
}
