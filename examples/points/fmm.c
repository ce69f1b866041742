/* fmm.c — black-box (Chebyshev) FMM of the radiosity kernel with
 * visibility-aware interaction lists (fmm.h). */
#include "fmm.h"

#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "kernel.h"

#ifdef _OPENMP
#include <omp.h>
#endif

static double now_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ------------------------------------------------------------ Chebyshev interpolation */

/* S_k(x) = 1/p + 2/p Σ_{j=1}^{p-1} T_j(t_k) T_j(x) for k < p, at one x. */
static void cheb_weights(const Fmm *f, double x, double *s) {
  int p = f->p;
  double tx[16];
  tx[0] = 1, tx[1] = x;
  for (int j = 2; j < p; j++) tx[j] = 2 * x * tx[j - 1] - tx[j - 2];
  for (int k = 0; k < p; k++) {
    double tk0 = 1, tk1 = f->cheb[k], acc = 0;
    for (int j = 1; j < p; j++) {
      acc += tk1 * tx[j];
      double next = 2 * f->cheb[k] * tk1 - tk0;
      tk0 = tk1, tk1 = next;
    }
    s[k] = (1.0 + 2.0 * acc) / p;
  }
}

/* The p³ interpolation weights S_l(ξ) of the point `pt` in the cube (c, h). */
static void cheb_weights3(const Fmm *f, const double c[3], double h, const double pt[3], double *s3) {
  double s1[3][16];
  for (int d = 0; d < 3; d++) cheb_weights(f, (pt[d] - c[d]) / h, s1[d]);
  int p = f->p, l = 0;
  for (int i2 = 0; i2 < p; i2++)
    for (int i1 = 0; i1 < p; i1++) {
      double a = s1[2][i2] * s1[1][i1];
      for (int i0 = 0; i0 < p; i0++) s3[l++] = a * s1[0][i0];
    }
}

/* Chebyshev node l of the cube (c, h). */
static void cheb_node(const Fmm *f, const double c[3], double h, int l, double out[3]) {
  int p = f->p;
  out[0] = c[0] + h * f->cheb[l % p];
  out[1] = c[1] + h * f->cheb[(l / p) % p];
  out[2] = c[2] + h * f->cheb[l / (p * p)];
}

/* M2L matrix for two cubes of half width 1 whose centres differ by 2·o:
 * rows (a, l) = a p³ + l of the target, columns (b, m) of the source. */
static double *m2l_operator(const Fmm *f, const int o[3]) {
  int p3 = f->p3, n = 3 * p3;
  double *op = malloc(sizeof(double) * (size_t)n * (size_t)n);
  if (!op) return NULL;
  const double zero[3] = {0, 0, 0}, off[3] = {2.0 * o[0], 2.0 * o[1], 2.0 * o[2]};
  for (int m = 0; m < p3; m++) {
    double ym[3], xl[3], d[3], hv[6];
    cheb_node(f, off, 1.0, m, ym);
    for (int l = 0; l < p3; l++) {
      cheb_node(f, zero, 1.0, l, xl);
      for (int k = 0; k < 3; k++) d[k] = xl[k] - ym[k];
      kernel_tensor(d, hv);
      const double hm[3][3] = {{hv[0], hv[3], hv[4]}, {hv[3], hv[1], hv[5]}, {hv[4], hv[5], hv[2]}};
      for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) op[(size_t)(b * p3 + m) * (size_t)n + (size_t)(a * p3 + l)] = hm[a][b];
    }
  }
  return op;
}

/* The M2L basis U (fmm.h): the eigenvectors of G = Σ_o K_o K_oᵀ over the
 * plain interaction list (2 ≤ max_k |o_k| ≤ 3: 316 positions) are the left
 * singular vectors of [K_o ...], and its eigenvalues their squared singular
 * values σ²; U keeps those with σ > eps σ_max. (One symmetric eigenproblem
 * of 3p³ instead of the SVD of a 3p³ x 316·3p³ matrix; squaring costs
 * digits below 1e-8 of σ_max only, far under any eps used.) */
static int m2l_basis(Fmm *f, double eps) {
  int n = 3 * f->p3, o[3];
  double *G = calloc((size_t)n * (size_t)n, sizeof(double)), *sigma2 = malloc(sizeof(double) * (size_t)n);
  if (!G || !sigma2) goto fail;
  for (o[0] = -3; o[0] <= 3; o[0]++)
    for (o[1] = -3; o[1] <= 3; o[1]++)
      for (o[2] = -3; o[2] <= 3; o[2]++) {
        if (abs(o[0]) < 2 && abs(o[1]) < 2 && abs(o[2]) < 2) continue;
        double *K = m2l_operator(f, o);
        if (!K) goto fail;
        cblas_dsyrk(CblasColMajor, CblasUpper, CblasNoTrans, n, n, 1.0, K, n, 1.0, G, n);
        free(K);
      }
  if (LAPACKE_dsyevd(LAPACK_COL_MAJOR, 'V', 'U', n, G, n, sigma2)) goto fail; /* ascending */
  int r = 0;
  while (r < n && sigma2[n - 1 - r] > eps * eps * sigma2[n - 1]) r++;
  f->rank = r;
  f->U = malloc(sizeof(double) * (size_t)n * (size_t)r);
  if (!f->U) goto fail;
  for (int k = 0; k < r; k++) memcpy(f->U + (size_t)k * (size_t)n, G + (size_t)(n - 1 - k) * (size_t)n, sizeof(double) * (size_t)n);
  free(G), free(sigma2);
  return 0;
fail:
  free(G), free(sigma2);
  return -1;
}

/* The compressed M2L matrix of position o: Uᵀ K_o U, r x r. */
static double *m2l_compressed(const Fmm *f, const int o[3]) {
  int n = 3 * f->p3, r = f->rank;
  double *K = m2l_operator(f, o), *KU = malloc(sizeof(double) * (size_t)n * (size_t)r),
         *C = malloc(sizeof(double) * (size_t)r * (size_t)r);
  if (K && KU && C) {
    cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, n, r, n, 1.0, K, n, f->U, n, 0.0, KU, n);
    cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, r, r, n, 1.0, f->U, n, KU, n, 0.0, C, r);
  } else {
    free(C);
    C = NULL;
  }
  free(K), free(KU);
  return C;
}

/* ------------------------------------------------------------ the plan: dual traversal */

enum { FACE_NONE, FACE_ALL, FACE_MIXED };

enum { P2P_LANES = 8 }; /* floats in an AVX2 register */
enum { P2P_BLOCK = 128 }; /* targets whose sums P2P keeps at once (a multiple of P2P_LANES) */
enum { M2L_COMPRESSED_MAX_P = 5 };
enum { M2L_CHUNK = 256 }; /* pairs per M2L GEMM */

/* Do the points of target `a` and source `b` face each other? From the
 * tight boxes and the normal cones: n·d ≥ axis·d − spread·|d|. */
static int facing(const OctNode *a, const OctNode *b) {
  double lo_ax = 0, hi_ax = 0, lo_bx = 0, hi_bx = 0, dmax2 = 0;
  for (int k = 0; k < 3; k++) {
    double dlo = b->lo[k] - a->hi[k], dhi = b->hi[k] - a->lo[k]; /* d = y − x */
    lo_ax += a->axis[k] * (a->axis[k] > 0 ? dlo : dhi);
    hi_ax += a->axis[k] * (a->axis[k] > 0 ? dhi : dlo);
    lo_bx += b->axis[k] * (b->axis[k] > 0 ? dlo : dhi);
    hi_bx += b->axis[k] * (b->axis[k] > 0 ? dhi : dlo);
    double m = fmax(fabs(dlo), fabs(dhi));
    dmax2 += m * m;
  }
  double dmax = sqrt(dmax2), tol = 1e-9 * dmax;
  /* target cosine n_x·(y − x) ∈ [LA, UA]; source cosine n_y·(x − y) = −n_y·d ∈ [LB, UB] */
  double LA = lo_ax - a->spread * dmax, UA = hi_ax + a->spread * dmax;
  double LB = -hi_bx - b->spread * dmax, UB = -lo_bx + b->spread * dmax;
  if (UA <= tol || UB <= tol) return FACE_NONE;
  if (LA >= -tol && LB >= -tol) return FACE_ALL;
  return FACE_MIXED;
}

static int separated(const OctNode *a, const OctNode *b) {
  double gap = 0, hmax = fmax(a->h, b->h);
  for (int k = 0; k < 3; k++) gap = fmax(gap, fabs(a->c[k] - b->c[k]) - a->h - b->h);
  return gap >= 2 * hmax * (1 - 1e-9);
}

static int list_push(FmmList *l, int tgt, int src, int key, float v) {
  if (l->n == l->cap) {
    long cap = l->cap ? 2 * l->cap : 1024;
    FmmPair *g = realloc(l->pair, sizeof(FmmPair) * (size_t)cap);
    if (!g) return -1;
    l->pair = g, l->cap = cap;
  }
  l->pair[l->n++] = (FmmPair){tgt, src, key, v};
  return 0;
}

typedef struct Lists {
  FmmList m2l, m2p, p2l, p2p, pending;
  long dropped_facing, dropped_hidden, tests;
  int oom;
} Lists;

typedef struct Planner {
  const Fmm *f;
  const Octree *t;
  const Visibility *vis;
} Planner;

/* Cubes of one level at most three widths apart in every axis: the
 * interaction lists of the plain FMM, whose 316 M2L matrices are shared by
 * many pairs. Farther pairs come from splitting partly visible ones. */
static int standard_offset(const OctNode *a, const OctNode *b) {
  for (int k = 0; k < 3; k++)
    if (fabs(b->c[k] - a->c[k]) > 3.5 * 2 * a->h) return 0;
  return 1;
}

static int m2l_key(const OctNode *a, const OctNode *b) {
  int key = 0;
  for (int k = 0; k < 3; k++) key = key * 128 + (int)lround((b->c[k] - a->c[k]) / (2 * a->h)) + 64;
  return key;
}

/* What the interactions cost in units of one float P2P point pair (AVX2):
 * an M2L multiply-add 0.11 (measured: GEMM samples against the samples of
 * the P2P before its loops were swapped, at N = 110 528; r x r per colour
 * and pair; scaling all three by 1.8 for the faster P2P changed nothing
 * measurable at N = 50 000), and, estimated from the flops
 * and the vectorization of their loops, an M2P at one target point and one
 * node of the source 4, a P2L of one source point at one node of the
 * target 8. */
#define COST_M2L 0.11
#define COST_M2P 4.0
#define COST_P2L 8.0

/* Visit the pair (target a, source b). With `defer`, pairs to split are put
 * on the pending list instead of being visited (the parallel frontier). */
static void visit(const Planner *pl, Lists *ls, int ia, int ib, int defer) {
  const OctNode *a = &pl->t->node[ia], *b = &pl->t->node[ib];
  int face = facing(a, b);
  if (face == FACE_NONE) {
    ls->dropped_facing++;
    return;
  }
  int leaf_a = octree_is_leaf(a), leaf_b = octree_is_leaf(b);
  int sep = separated(a, b);
  double frac = 1;
  if (pl->vis && (sep || (leaf_a && leaf_b))) {
    /* two leaves: a first look at 2 x 2 pairs, and a closer one only when
     * those disagree (§2.2.4.4 asks for a fraction, most pairs are plain) */
    int m = leaf_a && leaf_b ? 2 : pl->vis->samples_far, nfacing = 0;
    frac = visibility_nodes(pl->vis, ia, ib, m, &nfacing);
    ls->tests += nfacing;
    if (leaf_a && leaf_b && frac > 0 && frac < 1) {
      frac = visibility_nodes(pl->vis, ia, ib, pl->vis->samples_leaf, &nfacing);
      ls->tests += nfacing;
    }
    if (nfacing > 0 && frac == 0) { /* §2.2.4.2: invalid, dropped */
      ls->dropped_hidden++;
      return;
    }
  }
  long p3 = pl->f->p3;
  /* valid; or two leaves seen in part, whose visible fraction then scales
   * the interaction as a whole (§2.2.4.4: leaves are the finest visibility) */
  if (sep && face == FACE_ALL && (frac == 1 || (leaf_a && leaf_b))) {
    /* the expansion this pair can use, or a direct sum when that is cheaper
     * (leaf targets only); costs in P2P's unit, one float point pair (cost_*) */
    double ca = (double)a->count, cb = (double)b->count, cost;
    int kind;
    if (a->level == b->level && (standard_offset(a, b) || (!leaf_a && !leaf_b)))
      kind = 0, cost = COST_M2L * 3.0 * pl->f->rank * pl->f->rank;
    else if (leaf_a && a->level <= b->level) /* far apart (an operator for a few pairs), or a is the larger cube */
      kind = 1, cost = COST_M2P * ca * (double)p3;
    else /* b is a leaf */
      kind = 2, cost = COST_P2L * cb * (double)p3;
    float v = (float)frac;
    int rc;
    if (leaf_a && ca * cb <= cost)
      rc = list_push(&ls->p2p, ia, ib, 0, v);
    else if (kind == 0)
      rc = list_push(&ls->m2l, ia, ib, m2l_key(a, b), v);
    else if (kind == 1)
      rc = list_push(&ls->m2p, ia, ib, 0, v);
    else
      rc = list_push(&ls->p2l, ia, ib, 0, v);
    if (rc) ls->oom = 1;
    return;
  }
  if (leaf_a && leaf_b) {
    if (list_push(&ls->p2p, ia, ib, 0, (float)frac)) ls->oom = 1;
    return;
  }
  /* split: the side that is not a leaf; both when they are cubes of one level */
  int split_a = !leaf_a && (leaf_b || a->level <= b->level);
  int split_b = !leaf_b && (leaf_a || b->level <= a->level);
  for (int oa = 0; oa < (split_a ? 8 : 1); oa++) {
    int ca = split_a ? a->child[oa] : ia;
    if (ca < 0) continue;
    for (int ob = 0; ob < (split_b ? 8 : 1); ob++) {
      int cb = split_b ? b->child[ob] : ib;
      if (cb < 0) continue;
      if (defer) {
        if (list_push(&ls->pending, ca, cb, 0, 1.0f)) ls->oom = 1;
      } else {
        visit(pl, ls, ca, cb, 0);
      }
    }
  }
}

static int cmp_tgt(const void *x, const void *y) {
  const FmmPair *a = x, *b = y;
  if (a->tgt != b->tgt) return (a->tgt > b->tgt) - (a->tgt < b->tgt);
  return (a->src > b->src) - (a->src < b->src);
}

static int cmp_key(const void *x, const void *y) {
  const FmmPair *a = x, *b = y;
  if (a->key != b->key) return (a->key > b->key) - (a->key < b->key);
  return cmp_tgt(x, y);
}

static int list_append(FmmList *dst, const FmmList *src) {
  for (long k = 0; k < src->n; k++)
    if (list_push(dst, src->pair[k].tgt, src->pair[k].src, src->pair[k].key, src->pair[k].v)) return -1;
  return 0;
}

/* Sort by target and index it: first[t] .. first[t+1] are target t's pairs. */
static int list_index(FmmList *l, int ntargets) {
  if (l->n > 1) qsort(l->pair, (size_t)l->n, sizeof(FmmPair), cmp_tgt); /* pair is NULL when empty */
  l->first = calloc((size_t)ntargets + 1, sizeof(long));
  if (!l->first) return -1;
  for (long k = 0; k < l->n; k++) l->first[l->pair[k].tgt + 1]++;
  for (int t = 0; t < ntargets; t++) l->first[t + 1] += l->first[t];
  return 0;
}

static void list_free(FmmList *l) {
  free(l->pair), free(l->first);
  memset(l, 0, sizeof *l);
}

int fmm_plan(Fmm *f, const Surfels *s, const Octree *t, int p, const Visibility *vis) {
  memset(f, 0, sizeof *f);
  if (p < 2 || p > 12) return -1;
  double t0 = now_seconds();
  f->s = s, f->t = t, f->p = p, f->p3 = p * p * p;
  for (int k = 0; k < p; k++) f->cheb[k] = cos((2 * k + 1) * M_PI / (2 * p));
  int p3 = f->p3;
  for (int o = 0; o < 8; o++) {
    f->m2m[o] = malloc(sizeof(double) * (size_t)p3 * (size_t)p3);
    if (!f->m2m[o]) goto oom;
    /* column m' (a child node) holds the parent's weights S_l at that node */
    const double parent_c[3] = {0, 0, 0};
    double child_c[3] = {(o & 1) ? 0.5 : -0.5, (o & 2) ? 0.5 : -0.5, (o & 4) ? 0.5 : -0.5}, pt[3];
    for (int m = 0; m < p3; m++) {
      cheb_node(f, child_c, 0.5, m, pt);
      cheb_weights3(f, parent_c, 1.0, pt, f->m2m[o] + (size_t)m * (size_t)p3);
    }
  }
  /* T[l + p3·m'] = S_l(child node m'): M_parent += T · M_child, L_child += Tᵀ · L_parent */
  /* σ > 10^(1−p) σ_max (fmm.h; the gather error grows 1.2–1.9x at p = 2…5, README); the
   * basis costs 158 (3p³)³ multiply-adds, 8·10⁹ at p = 5 and 4·10¹⁰ at
   * p = 6, so higher orders keep the dense matrices (U NULL, r = 3p³) */
  if (p <= M2L_COMPRESSED_MAX_P) {
    if (m2l_basis(f, pow(10.0, 1.0 - p))) goto oom;
  } else {
    f->rank = 3 * p3;
  }

  Planner pl = {f, t, vis};
  Lists top;
  memset(&top, 0, sizeof top);
  visit(&pl, &top, 0, 0, 1);
  /* widen the frontier to a few hundred pairs, then visit in parallel */
  for (int round = 0; round < 3 && !top.oom && top.pending.n > 0 && top.pending.n < 256; round++) {
    FmmList frontier = top.pending;
    memset(&top.pending, 0, sizeof top.pending);
    for (long k = 0; k < frontier.n; k++) visit(&pl, &top, frontier.pair[k].tgt, frontier.pair[k].src, 1);
    list_free(&frontier);
  }
  int nthreads = 1;
#ifdef _OPENMP
  nthreads = omp_get_max_threads();
#endif
  Lists *part = calloc((size_t)nthreads, sizeof(Lists));
  if (!part) goto oom;
  long npending = top.pending.n;
#pragma omp parallel for schedule(dynamic, 1)
  for (long k = 0; k < npending; k++) {
    int id = 0;
#ifdef _OPENMP
    id = omp_get_thread_num();
#endif
    visit(&pl, &part[id], top.pending.pair[k].tgt, top.pending.pair[k].src, 0);
  }
  int oom = top.oom;
  f->stats.dropped_facing = top.dropped_facing, f->stats.dropped_hidden = top.dropped_hidden;
  f->stats.visibility_tests = top.tests;
  for (int id = 0; id < nthreads; id++) {
    Lists *ls = &part[id];
    oom |= ls->oom || list_append(&top.m2l, &ls->m2l) || list_append(&top.m2p, &ls->m2p) ||
           list_append(&top.p2l, &ls->p2l) || list_append(&top.p2p, &ls->p2p);
    f->stats.dropped_facing += ls->dropped_facing, f->stats.dropped_hidden += ls->dropped_hidden;
    f->stats.visibility_tests += ls->tests;
    list_free(&ls->m2l), list_free(&ls->m2p), list_free(&ls->p2l), list_free(&ls->p2p), list_free(&ls->pending);
  }
  free(part);
  list_free(&top.pending);
  f->m2l = top.m2l, f->m2p = top.m2p, f->p2l = top.p2l, f->p2p = top.p2p;
  if (oom) goto oom;

  /* P2P and M2P by target leaf (node ids), P2L by target node, M2L by key */
  if (list_index(&f->p2p, t->nnode) || list_index(&f->m2p, t->nnode) || list_index(&f->p2l, t->nnode)) goto oom;
  if (f->m2l.n > 1) qsort(f->m2l.pair, (size_t)f->m2l.n, sizeof(FmmPair), cmp_key);
  f->key = malloc(sizeof(int) * (size_t)(f->m2l.n + 1));
  f->key_first = malloc(sizeof(long) * (size_t)(f->m2l.n + 2));
  if (!f->key || !f->key_first) goto oom;
  for (long k = 0; k < f->m2l.n; k++)
    if (k == 0 || f->m2l.pair[k].key != f->m2l.pair[k - 1].key) {
      f->key_first[f->nkeys] = k;
      f->key[f->nkeys++] = f->m2l.pair[k].key;
    }
  f->key_first[f->nkeys] = f->m2l.n;
  f->op = calloc((size_t)f->nkeys + 1, sizeof(double *));
  if (!f->op) goto oom;
  int op_failed = 0, blas_threads = openblas_get_num_threads();
  openblas_set_num_threads(1); /* the OpenMP threads share the keys, each GEMM on its own thread */
#pragma omp parallel for schedule(dynamic, 1)
  for (int k = 0; k < f->nkeys; k++) {
    int o[3] = {f->key[k] / (128 * 128) - 64, (f->key[k] / 128) % 128 - 64, f->key[k] % 128 - 64};
    f->op[k] = f->U ? m2l_compressed(f, o) : m2l_operator(f, o);
    if (!f->op[k]) op_failed = 1;
  }
  openblas_set_num_threads(blas_threads);
  if (op_failed) goto oom;
  f->M = calloc((size_t)t->nnode * 9 * (size_t)p3, sizeof(double));
  f->L = calloc((size_t)t->nnode * 9 * (size_t)p3, sizeof(double));
  if (f->U) {
    f->Mc = calloc((size_t)t->nnode * 3 * (size_t)f->rank, sizeof(double));
    f->Lc = calloc((size_t)t->nnode * 3 * (size_t)f->rank, sizeof(double));
  } else { /* uncompressed: the M2L reads M and adds into L */
    f->Mc = f->M, f->Lc = f->L;
  }
  f->q = malloc(sizeof(double) * 3 * (size_t)(s->n > 0 ? s->n : 1));
  size_t np = (size_t)s->n + P2P_LANES; /* each array padded with zeros */
  f->pf = calloc(7 * np, sizeof(float));
  f->qf = calloc(3 * np, sizeof(float));
  if (!f->M || !f->L || !f->Mc || !f->Lc || !f->q || !f->pf || !f->qf) goto oom;
  f->nthreads = nthreads;
  f->work = calloc((size_t)nthreads, sizeof(double *));
  if (!f->work) goto oom;
  for (int id = 0; id < nthreads; id++) {
    size_t sums = id ? (size_t)t->nnode * 3 * (size_t)f->rank : 0;
    f->work[id] = malloc(sizeof(double) * (2 * 3 * (size_t)f->rank * M2L_CHUNK + sums));
    if (!f->work[id]) goto oom;
  }
  const double *origin = t->node[0].c;
  for (long j = 0; j < s->n; j++) {
    float *pj = f->pf + j;
    pj[0] = (float)(s->x[j] - origin[0]), pj[np] = (float)(s->y[j] - origin[1]), pj[2 * np] = (float)(s->z[j] - origin[2]);
    pj[3 * np] = (float)s->nx[j], pj[4 * np] = (float)s->ny[j], pj[5 * np] = (float)s->nz[j], pj[6 * np] = (float)s->w[j];
  }
  f->stats.m2l = f->m2l.n, f->stats.m2p = f->m2p.n, f->stats.p2l = f->p2l.n, f->stats.p2p = f->p2p.n;
  f->stats.m2l_offsets = f->nkeys;
  for (long k = 0; k < f->p2p.n; k++)
    f->stats.p2p_points += t->node[f->p2p.pair[k].tgt].count * t->node[f->p2p.pair[k].src].count;
  f->stats.plan_seconds = now_seconds() - t0;
  return 0;
oom:
  fmm_free(f);
  return -1;
}

int fmm_leaf_for(long n) { return n < 30000 ? 256 : 128; }

int fmm_falls_back(const Fmm *f, char *msg, size_t len) {
  if (f->stats.m2l + f->stats.m2p + f->stats.p2l > 0) return 0;
  if (msg && len)
    snprintf(msg, len,
             "the FMM falls back to direct sums: %ld points in leaves of up to %d, an octree of depth %d, and no "
             "two cubes far enough apart for an expansion (M2L, M2P, P2L 0; P2P %ld): a gather costs the dense "
             "gather's work over the kept pairs, plus the plan (expansions start near 10,000 points; a smaller --leaf "
             "gives them sooner at a higher plan cost)",
             f->s->n, f->t->leaf_size, f->t->depth, f->stats.p2p);
  return 1;
}

void fmm_free(Fmm *f) {
  for (int o = 0; o < 8; o++) free(f->m2m[o]);
  if (f->op)
    for (int k = 0; k < f->nkeys; k++) free(f->op[k]);
  if (f->U) free(f->Mc), free(f->Lc);
  if (f->work)
    for (int id = 0; id < f->nthreads; id++) free(f->work[id]);
  free(f->work);
  free(f->op), free(f->key), free(f->key_first), free(f->U);
  list_free(&f->m2l), list_free(&f->m2p), list_free(&f->p2l), list_free(&f->p2p);
  free(f->M), free(f->L), free(f->q), free(f->pf), free(f->qf);
  memset(f, 0, sizeof *f);
}

/* ------------------------------------------------------------ the gather */

static void p2m(Fmm *f, int node, double *s3) {
  const Surfels *s = f->s;
  const OctNode *nd = &f->t->node[node];
  long p3 = f->p3;
  double *M = f->M + (size_t)node * 9 * (size_t)p3;
  for (long j = nd->start; j < nd->start + nd->count; j++) {
    double pt[3] = {s->x[j], s->y[j], s->z[j]}, nrm[3] = {s->nx[j], s->ny[j], s->nz[j]};
    cheb_weights3(f, nd->c, nd->h, pt, s3);
    for (int ch = 0; ch < 3; ch++)
      for (int b = 0; b < 3; b++) {
        double c = nrm[b] * f->q[(size_t)ch * (size_t)s->n + (size_t)j], *col = M + (size_t)(b + 3 * ch) * (size_t)p3;
        for (long m = 0; m < p3; m++) col[m] += c * s3[m];
      }
  }
}

static void l2p(const Fmm *f, int node, double *s3, double *g) {
  const Surfels *s = f->s;
  const OctNode *nd = &f->t->node[node];
  long p3 = f->p3;
  const double *L = f->L + (size_t)node * 9 * (size_t)p3;
  for (long i = nd->start; i < nd->start + nd->count; i++) {
    double pt[3] = {s->x[i], s->y[i], s->z[i]}, nrm[3] = {s->nx[i], s->ny[i], s->nz[i]};
    cheb_weights3(f, nd->c, nd->h, pt, s3);
    for (int ch = 0; ch < 3; ch++) {
      double acc = 0;
      for (int a = 0; a < 3; a++) {
        const double *col = L + (size_t)(a + 3 * ch) * (size_t)p3;
        double dot = 0;
        for (long l = 0; l < p3; l++) dot += col[l] * s3[l];
        acc += nrm[a] * dot;
      }
      g[3 * i + ch] += acc;
    }
  }
}

/* Target leaf a gets source b's multipole, evaluated exactly at its points:
 * Σ_m n_xᵀ H(x − ȳ_m) M_m (the source's nodes laid out once per pair, the
 * loop over them vectorized). */
static void m2p(const Fmm *f, int ia, int ib, double v, double *g) {
  const Surfels *s = f->s;
  const OctNode *a = &f->t->node[ia], *b = &f->t->node[ib];
  int p3 = f->p3;
  const double *M = f->M + (size_t)ib * 9 * (size_t)p3;
  double yx[1728], yy[1728], yz[1728]; /* p ≤ 12 */
  for (int m = 0; m < p3; m++) {
    double ym[3];
    cheb_node(f, b->c, b->h, m, ym);
    yx[m] = ym[0], yy[m] = ym[1], yz[m] = ym[2];
  }
  for (long i = a->start; i < a->start + a->count; i++) {
    double xi = s->x[i], yi = s->y[i], zi = s->z[i], n0 = s->nx[i], n1 = s->ny[i], n2 = s->nz[i];
    double acc0 = 0, acc1 = 0, acc2 = 0;
#pragma omp simd reduction(+ : acc0, acc1, acc2)
    for (int m = 0; m < p3; m++) {
      double d0 = xi - yx[m], d1 = yi - yy[m], d2 = zi - yz[m];
      double r2 = d0 * d0 + d1 * d1 + d2 * d2;
      /* n_xᵀ H = −(n_x·d) dᵀ / (π r⁴) */
      double c = -(n0 * d0 + n1 * d1 + n2 * d2) * KERNEL_INV_PI / (r2 * r2);
      double u0 = c * d0, u1 = c * d1, u2 = c * d2;
      acc0 += u0 * M[m] + u1 * M[m + p3] + u2 * M[m + 2 * p3];
      acc1 += u0 * M[m + 3 * p3] + u1 * M[m + 4 * p3] + u2 * M[m + 5 * p3];
      acc2 += u0 * M[m + 6 * p3] + u1 * M[m + 7 * p3] + u2 * M[m + 8 * p3];
    }
    g[3 * i] += v * acc0, g[3 * i + 1] += v * acc1, g[3 * i + 2] += v * acc2;
  }
}

/* Target cube a's local expansion gets the points of source leaf b. */
static void p2l(Fmm *f, int ia, int ib, double v) {
  const Surfels *s = f->s;
  const OctNode *a = &f->t->node[ia], *b = &f->t->node[ib];
  long p3 = f->p3;
  double *L = f->L + (size_t)ia * 9 * (size_t)p3;
  for (int l = 0; l < p3; l++) {
    double xl[3], acc[9] = {0};
    cheb_node(f, a->c, a->h, l, xl);
    for (long j = b->start; j < b->start + b->count; j++) {
      double d[3] = {xl[0] - s->x[j], xl[1] - s->y[j], xl[2] - s->z[j]}, hv[6], u[3];
      double nrm[3] = {s->nx[j], s->ny[j], s->nz[j]};
      kernel_tensor(d, hv);
      kernel_tensor_apply(hv, nrm, u);
      for (int ch = 0; ch < 3; ch++)
        for (int c = 0; c < 3; c++) acc[c + 3 * ch] += u[c] * f->q[(size_t)ch * (size_t)s->n + (size_t)j];
    }
    for (int k = 0; k < 9; k++) L[l + p3 * k] += v * acc[k];
  }
}

/* Direct interaction of target leaf a with the points of source node b,
 * in single precision (Fmm.pf): eight targets per AVX2 instruction. The
 * loop over targets is the inner one (each source point broadcast), run to
 * a multiple of P2P_LANES past the leaf's last point into the next one's
 * (or the zero padding), whose sums are dropped; targets go in blocks of
 * P2P_BLOCK, their sums kept in float and added into the double g. */
static void p2p(const Fmm *f, int ia, int ib, double v, double *g) {
  const OctNode *a = &f->t->node[ia], *b = &f->t->node[ib];
  size_t np = (size_t)f->s->n + P2P_LANES;
  const float *X = f->pf, *Y = X + np, *Z = X + 2 * np, *NX = X + 3 * np, *NY = X + 4 * np, *NZ = X + 5 * np,
              *W = X + 6 * np;
  const float *q0 = f->qf, *q1 = q0 + np, *q2 = q0 + 2 * np;
  long j0 = b->start, j1 = b->start + b->count;
  for (long ib0 = a->start; ib0 < a->start + a->count; ib0 += P2P_BLOCK) {
    long nt = a->start + a->count - ib0 < P2P_BLOCK ? a->start + a->count - ib0 : P2P_BLOCK;
    long nv = (nt + P2P_LANES - 1) / P2P_LANES * P2P_LANES;
    float g0[P2P_BLOCK] = {0}, g1[P2P_BLOCK] = {0}, g2[P2P_BLOCK] = {0};
    const float *x = X + ib0, *y = Y + ib0, *z = Z + ib0, *nx = NX + ib0, *ny = NY + ib0, *nz = NZ + ib0;
    for (long j = j0; j < j1; j++) {
      float yx = X[j], yy = Y[j], yz = Z[j], nyx = NX[j], nyy = NY[j], nyz = NZ[j], wy = W[j];
      float c0 = q0[j], c1 = q1[j], c2 = q2[j];
#pragma omp simd
      for (long i = 0; i < nv; i++) {
        float k = kernel_ff_float(x[i], y[i], z[i], nx[i], ny[i], nz[i], yx, yy, yz, nyx, nyy, nyz, wy);
        g0[i] += k * c0, g1[i] += k * c1, g2[i] += k * c2;
      }
    }
    for (long i = 0; i < nt; i++) {
      g[3 * (ib0 + i)] += v * g0[i], g[3 * (ib0 + i) + 1] += v * g1[i], g[3 * (ib0 + i) + 2] += v * g2[i];
    }
  }
}

/* M2L for the pairs [k0, k1) of one key: gather the scaled projected
 * multipoles side by side, one r x r GEMM, scatter-add into `sums`. */
static void m2l_batch(Fmm *f, const double *op, long k0, long k1, double *X, double *Y, double *sums) {
  long r = f->rank, nb = 3 * r;
  for (long k = k0; k < k1; k++) {
    const FmmPair *pr = &f->m2l.pair[k];
    double h = f->t->node[pr->tgt].h, scale = pr->v / (h * h);
    const double *M = f->Mc + (size_t)pr->src * (size_t)nb;
    double *x = X + (size_t)(k - k0) * (size_t)nb;
    for (long i = 0; i < nb; i++) x[i] = scale * M[i];
  }
  int cols = (int)(3 * (k1 - k0));
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)r, cols, (int)r, 1.0, op, (int)r, X, (int)r, 0.0, Y,
              (int)r);
  for (long k = k0; k < k1; k++) {
    double *L = sums + (size_t)f->m2l.pair[k].tgt * (size_t)nb;
    const double *y = Y + (size_t)(k - k0) * (size_t)nb;
    for (long i = 0; i < nb; i++) L[i] += y[i];
  }
}

void fmm_gather(Fmm *f, const double *b, double *g) {
  const Surfels *s = f->s;
  const Octree *t = f->t;
  long n = s->n, p3 = f->p3, nb = 9 * p3;
  for (long j = 0; j < n; j++)
    for (int ch = 0; ch < 3; ch++) {
      f->q[(size_t)ch * (size_t)n + (size_t)j] = s->w[j] * b[3 * j + ch];
      f->qf[(size_t)ch * (size_t)(n + P2P_LANES) + (size_t)j] = (float)f->q[(size_t)ch * (size_t)n + (size_t)j];
    }
  memset(f->M, 0, sizeof(double) * (size_t)t->nnode * (size_t)nb);
  memset(f->L, 0, sizeof(double) * (size_t)t->nnode * (size_t)nb);
  memset(g, 0, sizeof(double) * 3 * (size_t)n);

  /* upward pass: P2M at the leaves, M2M level by level */
#pragma omp parallel
  {
    double *s3 = malloc(sizeof(double) * (size_t)p3);
#pragma omp for schedule(dynamic, 8)
    for (int a = 0; a < t->nleaf; a++) p2m(f, t->leaf[a], s3);
    free(s3);
  }
  for (int q = t->nnode - 1; q > 0; q--) {
    const OctNode *nd = &t->node[q];
    if (t->grouped && nd->parent == 0) continue; /* a group's root: node 0 has no expansion */
    int o = (nd->c[0] > t->node[nd->parent].c[0]) | ((nd->c[1] > t->node[nd->parent].c[1]) << 1) |
            ((nd->c[2] > t->node[nd->parent].c[2]) << 2);
    cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)p3, 9, (int)p3, 1.0, f->m2m[o], (int)p3,
                f->M + (size_t)q * (size_t)nb, (int)p3, 1.0, f->M + (size_t)nd->parent * (size_t)nb, (int)p3);
  }

  /* M2L by key, in chunks, on the projected expansions Mc = Uᵀ M (every
   * node's three colours are columns of one 3p³ x 3·nnode matrix); then
   * L += U Lc; P2L by target */
  int r = f->rank, n3 = 3 * (int)p3, cols = 3 * t->nnode;
  if (f->U) {
    cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, r, cols, n3, 1.0, f->U, n3, f->M, n3, 0.0, f->Mc, r);
    memset(f->Lc, 0, sizeof(double) * (size_t)cols * (size_t)r);
  }
  /* the OpenMP threads take whole positions, each GEMM on one OpenBLAS
   * thread, each thread adding into its own sums (one barrier, then the
   * sums are added up: positions share targets) */
  int blas_threads = openblas_get_num_threads();
  openblas_set_num_threads(1);
  size_t nsums = (size_t)cols * (size_t)r;
#pragma omp parallel num_threads(f->nthreads)
  {
    int id = 0;
#ifdef _OPENMP
    id = omp_get_thread_num();
#endif
    double *X = f->work[id], *Y = X + 3 * (size_t)r * M2L_CHUNK, *sums = id ? Y + 3 * (size_t)r * M2L_CHUNK : f->Lc;
    if (id) memset(sums, 0, sizeof(double) * nsums);
#pragma omp for schedule(dynamic, 1)
    for (int k = 0; k < f->nkeys; k++)
      for (long k0 = f->key_first[k]; k0 < f->key_first[k + 1]; k0 += M2L_CHUNK) {
        long k1 = k0 + M2L_CHUNK < f->key_first[k + 1] ? k0 + M2L_CHUNK : f->key_first[k + 1];
        m2l_batch(f, f->op[k], k0, k1, X, Y, sums);
      }
    if (id) {
#pragma omp critical
      for (size_t i = 0; i < nsums; i++) f->Lc[i] += sums[i];
    }
  }
  openblas_set_num_threads(blas_threads);
  if (f->U) cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, n3, cols, r, 1.0, f->U, n3, f->Lc, r, 1.0, f->L, n3);
#pragma omp parallel for schedule(dynamic, 4)
  for (int a = 0; a < t->nnode; a++)
    for (long k = f->p2l.first[a]; k < f->p2l.first[a + 1]; k++) p2l(f, a, f->p2l.pair[k].src, f->p2l.pair[k].v);

  /* downward pass: L2L level by level (parents first: breadth-first order) */
  for (int q = 1; q < t->nnode; q++) {
    const OctNode *nd = &t->node[q];
    if (t->grouped && nd->parent == 0) continue;
    int o = (nd->c[0] > t->node[nd->parent].c[0]) | ((nd->c[1] > t->node[nd->parent].c[1]) << 1) |
            ((nd->c[2] > t->node[nd->parent].c[2]) << 2);
    cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, (int)p3, 9, (int)p3, 1.0, f->m2m[o], (int)p3,
                f->L + (size_t)nd->parent * (size_t)nb, (int)p3, 1.0, f->L + (size_t)q * (size_t)nb, (int)p3);
  }

  /* evaluation at the leaves: L2P, M2P, P2P */
#pragma omp parallel
  {
    double *s3 = malloc(sizeof(double) * (size_t)p3);
#pragma omp for schedule(dynamic, 4)
    for (int a = 0; a < t->nleaf; a++) {
      int leaf = t->leaf[a];
      l2p(f, leaf, s3, g);
      for (long k = f->m2p.first[leaf]; k < f->m2p.first[leaf + 1]; k++)
        m2p(f, leaf, f->m2p.pair[k].src, f->m2p.pair[k].v, g);
      for (long k = f->p2p.first[leaf]; k < f->p2p.first[leaf + 1]; k++)
        p2p(f, leaf, f->p2p.pair[k].src, f->p2p.pair[k].v, g);
    }
    free(s3);
  }
}

float *fmm_leaf_visibility(const Fmm *f) {
  const Octree *t = f->t;
  long nl = t->nleaf;
  float *vis = calloc((size_t)nl * (size_t)nl, sizeof(float));
  if (!vis) return NULL;
  const FmmList *lists[] = {&f->m2l, &f->m2p, &f->p2l, &f->p2p};
  for (int k = 0; k < 4; k++)
    for (long e = 0; e < lists[k]->n; e++) {
      const FmmPair *pr = &lists[k]->pair[e];
      const OctNode *a = &t->node[pr->tgt], *b = &t->node[pr->src];
      for (long la = a->leaf_first; la < a->leaf_first + a->nleaf; la++)
        for (long lb = b->leaf_first; lb < b->leaf_first + b->nleaf; lb++) vis[la * nl + lb] = pr->v;
    }
  return vis;
}
