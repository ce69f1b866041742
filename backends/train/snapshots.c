/* snapshots.c — the method of snapshots (DESIGN §5; Sirovich 1987): the
 * member bases of training when the snapshots do not fit in --mem. Only
 * S x S Gram matrices are held, built by passes that recompute the samples
 * (train_gram_blocks shares the budget between a held block and a batch).
 * A Gram matrix squares the snapshots' condition number: its eigenvectors
 * resolve directions down to about √ε of the largest only (issue 41). So a
 * first round's basis (U = X V Λ^(-1/2)) is completed by a second round on
 * the snapshots' residual after it, and the basis is the SVD of every
 * snapshot's coefficients in their joint span — the in-memory PCA's
 * (pca_basis) to rounding (test_train's snapshots_match_memory compares
 * the projectors; test_ooc's method_of_snapshots_reaches_svd_accuracy,
 * LAPACK's SVD at every leading size). */
#include <cblas.h>
#include <float.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scratch.h"
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
  double *d;   /* centered: the sum of the shifted snapshots, then their mean d */
  double big;  /* the largest |entry| that entered G */
  double *Q;   /* rounds 2 and 3: an orthonormal basis (n x p) the snapshots' residual is taken against
                  (round 1's in Gram.round1, round 2's in Gram.mem) */
  double *c;   /* room for p coefficients */
  int p;       /* Q's columns */
  double *D;   /* round 3: Qᵀ X, S x p (row s: sample s's coefficients) */
  double smax; /* the largest singular value round 1 saw */
} GramMember;

/* The method of snapshots under way: every member's state, [class][member]. */
typedef struct Gram {
  Train *t;            /* the training: its model, evaluator, samples, options and error record */
  long S, b, q;        /* samples; the held block; the batch (train_gram_blocks) */
  int round;           /* 1: G = XᵀX; 2: the Gram matrix of X's residual after Q; 3: Qᵀ X */
  GramMember **gm;
  double *lam;         /* S eigenvalues */
  double *tmp;         /* room for max(largest class, S) doubles */
  Scratch mem;         /* the method's memory: every array above, released at its end */
  Scratch round1;      /* round 1's Q of every member, released once round 2's replaced them */
} Gram;

/* Every member's Gram matrix (zero), held block and batch, and for a
 * centered one its shift and sum (zero), from g->mem. 0, or -1 when out of memory. */
static int gram_alloc(Gram *g) {
  Model *m = g->t->m;
  size_t S = (size_t)g->S;
  if (!(g->gm = scratch_array(&g->mem, (size_t)m->nclasses + 1, sizeof(GramMember *))) ||
      !(g->lam = scratch_array(&g->mem, S, sizeof(double))))
    return -1;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    size_t n = (size_t)rc->n;
    if (!(g->gm[c] = scratch_array(&g->mem, (size_t)rc->nmembers + 1, sizeof(GramMember)))) return -1;
    for (int i = 0; i < rc->nmembers; i++) {
      GramMember *x = &g->gm[c][i];
      x->mb = &rc->members[i];
      if (!(x->G = scratch_array(&g->mem, S * S, sizeof(double))) ||
          !(x->H = scratch_array(&g->mem, n * (size_t)g->b, sizeof(double))) ||
          (g->q > 0 && !(x->Y = scratch_array(&g->mem, n * (size_t)g->q, sizeof(double)))))
        return -1;
      if (x->mb->center &&
          (!(x->x0 = scratch_array(&g->mem, n, sizeof(double))) || !(x->d = scratch_array(&g->mem, n, sizeof(double)))))
        return -1;
    }
  }
  return 0;
}

/* Sample k's values of member x in v (n entries), as the round takes
 * them: shifted by x₀ (round 1 sets x₀ at sample 0), from round 2 on
 * centered by d as well, and in round 2 their residual after Q (removed
 * twice: Kahan–Parlett). */
static int member_sample(Gram *g, GramMember *x, long n, long k, double *v) {
  if (train_member_value(g->t, x->mb, k, n, v)) return -1;
  if (x->x0) {
    if (g->round == 1 && k == 0) memcpy(x->x0, v, sizeof(double) * (size_t)n);
    cblas_daxpy((int)n, -1.0, x->x0, 1, v, 1);
    if (g->round > 1) cblas_daxpy((int)n, -1.0, x->d, 1, v, 1);
  }
  for (int pass = 0; g->round == 2 && x->p > 0 && pass < 2; pass++) {
    cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, x->p, 1.0, x->Q, x->p, v, 1, 0.0, x->c, 1);
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, x->p, -1.0, x->Q, x->p, x->c, 1, 1.0, v, 1);
  }
  return 0;
}

/* Whether member x takes part in the round: in rounds 2 and 3 only a
 * member with directions from round 1. */
static bool member_in_round(const Gram *g, const GramMember *x) { return g->round == 1 || x->p > 0; }

/* G[I, K] = X_Iᵀ X_K for the held block I = [held[0], held[1]) and the
 * batch K = [k0, k] (one sample: a dgemv, faster than a dgemm of one
 * column), and its mirror. */
static void gram_cross(const Gram *g, GramMember *x, long n, const long held[2], long k0, long k) {
  long S = g->S, i0 = held[0], i1 = held[1], nb = i1 - i0, nk = k + 1 - k0;
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
  Model *m = g->t->m;
  long S = g->S, nb = i1 - i0;
  for (long k = i0, k0 = i1; k < S; k++) { /* k0: the first sample of the batch */
    if (train_eval_sample(g->t->src, g->t->f, k, g->t->err)) return -1;
    if (g->round == 1 && k < i1 && train_check_spd(g->t, g->tmp)) return -1;
    bool full = k >= i1 && (k + 1 - k0 == g->q || k + 1 == S);
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        GramMember *x = &g->gm[c][i];
        double *v = k < i1 ? x->H + (k - i0) * rc->n : x->Y + (k - k0) * rc->n;
        if (!member_in_round(g, x)) continue;
        if (member_sample(g, x, rc->n, k, v)) return -1;
        if (x->d && g->round == 1 && k < i1) cblas_daxpy((int)rc->n, 1.0, v, 1, x->d, 1);
        for (long e = 0; k < i1 && e < rc->n; e++) x->big = fmax(x->big, fabs(v[e])); /* what enters G */
        if (full) gram_cross(g, x, rc->n, (long[2]){i0, i1}, k0, k);
      }
    }
    if (full) k0 = k + 1;
    progress_show(g->t->opt->user->progress,
                  g->round == 2 ? "snapshots (residual Gram)" : g->b < S ? "snapshots (Gram, recomputing)" : "snapshots (Gram)",
                  ++*done, work);
  }
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    for (int i = 0; i < rc->nmembers; i++) { /* G[I, I] = X_Iᵀ X_I */
      GramMember *x = &g->gm[c][i];
      if (!member_in_round(g, x)) continue;
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

/* The member's eigenvectors V (S x kmax, of the eigenvalues in g->lam,
 * ascending): how many it keeps (its cap and energy; its report set), and
 * W = V Λ^(-1/2) for them in G's place (S x k, row-major with leading
 * dimension S); *U allocated (zero) for pass 2. */
static int keep_eigen(Gram *g, GramMember *x, const RClass *rc, const double *V, double **U, int *kk) {
  RMember *mb = x->mb;
  long S = g->S;
  const double *lam = g->lam;
  int cap = mb->center ? mb->cap - 1 : mb->cap;
  double *sv = mem_malloc(sizeof(double) * (size_t)S); /* the member's report's */
  if (!sv) return err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S);
  free(mb->sv); /* replaced by these */
  mb->sv = sv;
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
  if (!(*U = mem_calloc((size_t)(rc->n * (k ? k : 1)), sizeof(double))))
    return err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S);
  return 0;
}

/* Round 1 for one member: its Gram matrix checked (and centered), its
 * leading eigenvectors (up to its cap) kept as keep_eigen keeps them. */
static int gram_eigen(Gram *g, GramMember *x, const RClass *rc, double **U, int *kk) {
  RMember *mb = x->mb;
  long S = g->S;
  const char *range = pca_gram_out_of_range(S, x->G, x->big);
  if (range)
    return err_set(g->t->err,
                   "class %s, member %s: snapshot %s; rescale the data, or give --mem enough to keep the snapshots in "
                   "memory (their PCA is scale-invariant)",
                   rc->label, mb->name, range);
  if (mb->center) gram_center(x, rc->n, S, g->lam);
  int cap = mb->center ? mb->cap - 1 : mb->cap;
  long kmax = cap < S ? cap : S;
  Scratch sc = SCRATCH_OF(g->t->err);
  double *V = scratch_array(&sc, (size_t)(S * (kmax ? kmax : 1)), sizeof(double));
  int info = V ? pca_top_eigen(S, x->G, kmax, g->lam, V) : 0; /* G whole: either layout */
  int status = !V || info == -1 /* pca_top_eigen's "out of memory" */
                   ? err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S)
               : info ? err_set(g->t->err,
                                "class %s, member %s: eigendecomposition of the Gram matrix failed (LAPACK info %d)",
                                rc->label, mb->name, info)
                      : keep_eigen(g, x, rc, V, U, kk);
  scratch_release(&sc);
  return status;
}

/* Pass 2: every sample recomputed once, U += x_s ⊗ W[s, :] (shifted). */
static int basis_pass(Gram *g, double ***U, int **kk) {
  Model *m = g->t->m;
  for (long k = 0; k < g->S; k++) {
    if (train_eval_sample(g->t->src, g->t->f, k, g->t->err)) return -1;
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        GramMember *x = &g->gm[c][i];
        if (!kk[c][i]) continue;
        if (member_sample(g, x, rc->n, k, g->tmp)) return -1;
        cblas_dger(CblasRowMajor, (int)rc->n, kk[c][i], 1.0, g->tmp, 1, x->G + k * g->S, 1, U[c][i], kk[c][i]);
      }
    }
    progress_show(g->t->opt->user->progress, g->round == 2 ? "snapshots (residual basis)" : "snapshots (basis)", k + 1,
                  g->S);
  }
  return 0;
}

/* After round 1: a member's directions U = X W (n x k) centered
 * (U −= d (1ᵀW): the shifted snapshots' mean removed) and orthonormalized
 * into x->Q (pca_in_order), the start of rounds 2 and 3; *U freed. */
static int round1_basis(Gram *g, GramMember *x, long n, double **U, int k) {
  long S = g->S;
  if (x->x0 && k > 0) {
    for (int a = 0; a < k; a++) {
      double w = 0;
      for (long s2 = 0; s2 < S; s2++) w += x->G[s2 * S + a];
      g->tmp[a] = w;
    }
    cblas_dger(CblasRowMajor, (int)n, k, -1.0, x->d, 1, g->tmp, 1, *U, k);
  }
  x->smax = x->mb->nsv > 0 ? x->mb->sv[0] : 0;
  int p = 0;
  double *Q = NULL;
  if (k > 0 && (pca_in_order(n, (PcaBlocks){1, U, &k}, &Q, &p, g->t->err) || !(x->Q = scratch_adopt(&g->round1, Q))))
    return -1;
  free(*U); /* the Snapshots' slot: its directions are in Q now */
  *U = NULL;
  x->p = p;
  if (p > 0 && !(x->c = scratch_array(&g->mem, (size_t)(2 * S + 1), sizeof(double))))
    return err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S);
  return 0;
}

/* Round 2's directions from the residual Gram matrix's eigenvectors V
 * (S x kmax, their eigenvalues in g->lam, ascending): those above the
 * rounding floors, as W = V Λ^(-1/2) in G's place; *U allocated (zero). */
static int resid_directions(Gram *g, GramMember *x, long n, const double *V, double **U, int *kk) {
  long S = g->S;
  const double *lam = g->lam;
  int cap = x->mb->center ? x->mb->cap - 1 : x->mb->cap;
  long kmax = cap < S ? cap : S;
  double top = fmax(lam[S - 1], 0), eps = DBL_EPSILON * x->smax;
  double floor = fmax((double)S * DBL_EPSILON * top, eps * eps);
  int k = 0;
  while (k < kmax && lam[S - 1 - k] > floor) k++;
  for (long s2 = 0; s2 < S; s2++)
    for (int a = 0; a < k; a++) x->G[s2 * S + a] = V[a * S + s2] / sqrt(lam[S - 1 - a]);
  if (!(*U = mem_calloc((size_t)(n * (k ? k : 1)), sizeof(double))))
    return err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S);
  *kk = k;
  return 0;
}

/* Round 2: x->G holds the Gram matrix of the snapshots' residual after Q
 * (what round 1's Gram matrix could not resolve, below about √ε of the
 * largest). Its leading eigenvectors (up to the member's cap) whose
 * eigenvalues stand above its rounding (S ε of the largest) and above
 * (ε σ_max)² give W = V Λ^(-1/2) in G's place, as gram_eigen does; *U
 * allocated (zero) for the residual basis pass (resid_directions). */
static int resid_eigen(Gram *g, GramMember *x, const RClass *rc, double **U, int *kk) {
  long S = g->S;
  int cap = x->mb->center ? x->mb->cap - 1 : x->mb->cap;
  long kmax = cap < S ? cap : S;
  *kk = 0;
  if (!x->p || kmax <= 0) return 0;
  Scratch sc = SCRATCH_OF(g->t->err);
  double *V = scratch_array(&sc, (size_t)(S * kmax), sizeof(double));
  int info = V ? pca_top_eigen(S, x->G, kmax, g->lam, V) : 0;
  int status = !V || info == -1 /* pca_top_eigen's "out of memory" */
                   ? err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S)
               : info ? err_set(g->t->err,
                                "class %s, member %s: eigendecomposition of the residual Gram matrix failed (LAPACK info %d)",
                                rc->label, x->mb->name, info)
                      : resid_directions(g, x, rc->n, V, U, kk);
  scratch_release(&sc);
  return status;
}

/* After round 2: Q := the orthonormalization of [Q, U] in that order
 * (U, the residual's directions, is orthogonal to Q to rounding); *U freed. */
static int round2_merge(Gram *g, GramMember *x, long n, double **U, int k) {
  double *parts[2] = {x->Q, *U}, *Q = NULL;
  int ks[2] = {x->p, k}, p = 0;
  if (x->p > 0 && (pca_in_order(n, (PcaBlocks){2, parts, ks}, &Q, &p, g->t->err) || !scratch_adopt(&g->mem, Q)))
    return -1;
  free(*U); /* the Snapshots' slot: its directions are in Q now */
  *U = NULL;
  x->Q = Q, x->p = p; /* round 1's stays in g->round1 until every member's is replaced */
  return 0;
}

/* Round 3: every sample recomputed once (shifted and centered), its
 * coefficients Qᵀ x in row s of x->D. */
static int coefficient_pass(Gram *g) {
  Model *m = g->t->m;
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++) {
      GramMember *x = &g->gm[c][i];
      if (x->p > 0 && !(x->D = scratch_array(&g->mem, (size_t)(g->S * x->p), sizeof(double))))
        return err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", g->S);
    }
  for (long k = 0; k < g->S; k++) {
    if (train_eval_sample(g->t->src, g->t->f, k, g->t->err)) return -1;
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        GramMember *x = &g->gm[c][i];
        if (!x->p) continue;
        if (member_sample(g, x, rc->n, k, g->tmp)) return -1;
        cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, x->p, 1.0, x->Q, x->p, g->tmp, 1, 0.0, x->D + k * x->p, 1);
      }
    }
    progress_show(g->t->opt->user->progress, "snapshots (coefficients)", k + 1, g->S);
  }
  return 0;
}

/* A member's basis from round 3: the SVD of its coefficients Dᵀ = U_D Σ
 * V_Dᵀ (p x S, dgesdd) is the snapshots' SVD in Q's span, which holds them
 * to rounding; the truncation rule of every route (pca_choose) on Σ, the
 * report set, and the basis Q U_D (its kept columns) in *U. */
static int svd_basis(Gram *g, GramMember *x, const RClass *rc, double **U, int *kk) {
  RMember *mb = x->mb;
  long S = g->S, p = x->p, r = p < S ? p : S, n = rc->n;
  int cap = mb->center ? mb->cap - 1 : mb->cap, k = 0;
  Scratch sc = SCRATCH_OF(g->t->err);
  double *s = scratch_array(&sc, (size_t)(r + 1), sizeof(double));
  double *ud = scratch_array(&sc, (size_t)(p * r + 1), sizeof(double));
  double *vt = scratch_array(&sc, (size_t)(r * S + 1), sizeof(double));
  bool room = s && ud && vt;
  lapack_int info = room && p > 0 ? LAPACKE_dgesdd(LAPACK_COL_MAJOR, 'S', (lapack_int)p, (lapack_int)S, x->D,
                                                   (lapack_int)p, s, ud, (lapack_int)p, vt, (lapack_int)r)
                                  : 0;
  double *sv = room && info == 0 && p > 0 ? mem_malloc(sizeof(double) * (size_t)(r + 1)) : NULL; /* the member's report's */
  int status = info ? err_set(g->t->err, "class %s, member %s: SVD of the snapshots' coefficients failed (LAPACK info %d)",
                              rc->label, mb->name, (int)info)
               : !room || (p > 0 && !sv) ? err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S)
                                        : 0;
  *U = NULL;
  if (status == 0 && p > 0) {
    k = (int)pca_choose(s, r, cap, mb->energy, false);
    double total = 0, run = 0;
    for (long a = 0; a < r; a++) total += (s[a] / s[0]) * (s[a] / s[0]);
    for (int a = 0; a < k; a++) run += (s[a] / s[0]) * (s[a] / s[0]);
    memcpy(sv, s, sizeof(double) * (size_t)r);
    free(mb->sv); /* round 1's values: these replace them */
    mb->sv = sv, mb->nsv = r;
    mb->captured = total > 0 ? run / total : 1;
    mb->lost = fmax(0, 1 - mb->captured);
  }
  if (status == 0 && !(*U = mem_calloc((size_t)(n * (k ? k : 1)), sizeof(double))))
    status = err_set(g->t->err, "out of memory for the Gram matrices of %ld samples", S);
  if (status == 0 && k > 0)
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)n, k, (int)p, 1.0, x->Q, (int)p, ud, (int)p, 0.0, *U, k);
  if (status == 0) mb->kept = *kk = k;
  scratch_release(&sc);
  return status;
}

/* A centered member's basis: [μ = x₀ + d, U_c] orthonormalized in that
 * order (*U replaced, *kk and the report's kept set to its size). */
static int centered_basis(Gram *g, GramMember *x, long n, double **U, int *kk) {
  cblas_daxpy((int)n, 1.0, x->x0, 1, x->d, 1); /* μ = x₀ + d */
  double *parts[2] = {x->d, *U}, *Q = NULL;
  int ks[2] = {1, *kk}, mm = 0;
  if (pca_in_order(n, (PcaBlocks){2, parts, ks}, &Q, &mm, g->t->err)) return -1;
  free(*U); /* the Snapshots' slot: replaced by the basis with its mean */
  *U = Q;
  x->mb->kept = *kk = mm;
  return 0;
}

/* Rounds 1 and 2's Gram passes: ⌈S/b⌉ held blocks. */
static int gram_passes(Gram *g) {
  long done = 0, work = 0, S = g->S;
  for (long i0 = 0; i0 < S; i0 += g->b) work += S - i0;
  for (long i0 = 0; i0 < S; i0 += g->b)
    if (gram_pass(g, i0, i0 + g->b < S ? i0 + g->b : S, &done, work)) return -1;
  return 0;
}

/* Every member of the model, class by class (i of class c). */
#define EACH_MEMBER(m) for (int c = 0; c < (m)->nclasses; c++) for (int i = 0; i < (m)->classes[c].nmembers; i++)

/* Rounds 1 and 2: the Gram passes (of the snapshots, then of their
 * residuals after Q), every member's eigenvectors (gram_eigen, then
 * resid_eigen), their directions U = X W formed by a basis pass, then
 * orthonormalized into Q (round1_basis) or extending it (round2_merge). */
static int gram_round(Gram *g, int round) {
  Model *m = g->t->m;
  double ***U = g->t->sn.U;
  int **kk = g->t->sn.k;
  g->round = round;
  if (gram_passes(g)) return -1;
  EACH_MEMBER(m) if ((round == 1 ? gram_eigen : resid_eigen)(g, &g->gm[c][i], &m->classes[c], &U[c][i], &kk[c][i])) return -1;
  if (basis_pass(g, U, kk)) return -1;
  EACH_MEMBER(m) if ((round == 1 ? round1_basis : round2_merge)(g, &g->gm[c][i], m->classes[c].n, &U[c][i], kk[c][i])) return -1;
  return 0;
}

/* Round 3: the coefficient pass, every member's basis from their SVD (a
 * centered one's mean put first). */
static int gram_round3(Gram *g) {
  Model *m = g->t->m;
  double ***U = g->t->sn.U;
  int **kk = g->t->sn.k;
  g->round = 3;
  if (coefficient_pass(g)) return -1;
  EACH_MEMBER(m) if (svd_basis(g, &g->gm[c][i], &m->classes[c], &U[c][i], &kk[c][i])) return -1;
  EACH_MEMBER(m) if (g->gm[c][i].x0 && centered_basis(g, &g->gm[c][i], m->classes[c].n, &U[c][i], &kk[c][i])) return -1;
  return 0;
}
#undef EACH_MEMBER

/* The method of snapshots (DESIGN §5), for snapshots that do not fit in
 * `mem`: no snapshot matrix is held whole; every sample is recomputed in
 * each pass. U[c][i], kk[c][i] per member.
 *  1. Gram passes build every member's S x S Gram matrix G = XᵀX holding a
 *     block of b samples at a time and recomputing the later samples
 *     against it in batches of q (one dgemm per member and batch:
 *     train_gram_blocks; one pass when the budget holds every sample,
 *     ⌈S/b⌉ in general); its eigenvectors give U₁ = X V Λ^(-1/2), formed
 *     by a basis pass (each sample's rank-one contribution), orthonormalized
 *     into Q.
 *  2. The same passes on the residuals X − Q Qᵀ X: their Gram matrix's
 *     leading eigenvectors resolve what round 1 could not (below √ε of the
 *     largest, to about ε), and their directions U₂, formed by a basis
 *     pass, extend Q = orth[Q, U₂].
 *  3. A coefficient pass: D = Qᵀ X (p x S); the SVD D = U_D Σ V_Dᵀ is the
 *     snapshots' SVD to rounding, the truncation rule (pca_choose) runs on
 *     Σ, and the basis is Q U_D's kept columns.
 * About twice the evaluations of the Gram route alone, plus one pass.
 *
 * A centered member's snapshots are shifted by its first sample x₀ (on a
 * deforming mesh that removes the dominant rest shape before any product,
 * so nothing cancels), their mean d accumulated in round 1, whose Gram
 * matrix is then J G J (J = I − 11ᵀ/S: the mean of a shift is removed
 * exactly); rounds 2 and 3 take x − x₀ − d, and the member's basis is the
 * orthonormalization of [μ = x₀ + d, Q U_D]. */
int train_snapshot_bases(Train *t, double *tmp) {
  Gram g = {.t = t, .S = t->src->count, .round = 1, .tmp = tmp, .mem = SCRATCH_OF(t->err), .round1 = SCRATCH_OF(t->err)};
  Model *m = t->m;
  long S = g.S, per = 0;
  for (int c = 0; c < m->nclasses; c++) per += m->classes[c].n * m->classes[c].nmembers;
  train_gram_blocks(S, (long)(t->opt->user->mem / 2 / sizeof(double) / (size_t)(per ? per : 1)), &g.b, &g.q);
  int rc = gram_alloc(&g) ? err_set(t->err, "out of memory for the Gram matrices of %ld samples", S) : 0;
  if (rc == 0) rc = gram_round(&g, 1);
  if (rc == 0) rc = gram_round(&g, 2);
  scratch_release(&g.round1); /* every member's Q is round 2's now */
  if (rc == 0) rc = gram_round3(&g);
  scratch_release(&g.mem);
  return rc;
}
