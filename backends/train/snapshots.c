/* snapshots.c — the method of snapshots (DESIGN §5; Sirovich 1987): the
 * member bases of training when the snapshots do not fit in --mem. Only
 * S x S Gram matrices G = XᵀX are held, built by passes that recompute the
 * samples (train_gram_blocks shares the budget between a held block and a
 * batch); their eigenvectors V give U = X V Λ^(-1/2), formed in a last
 * pass. train.c's take_snapshots calls it instead of keeping the snapshot
 * matrices; the result is the in-memory PCA's (pca_basis) to rounding. */
#include <cblas.h>
#include <float.h>
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
int snapshot_bases(Model *m, NpgFull *f, const SampleSource *src, const TrainOptions *opt, double ***U,
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
