/* stream.c — pre-multiplication by bases formed block by block (issue 30).
 *
 * A class whose basis the model drops (RClass.streamed: radiosity's pair
 * classes, F² rows) needs its basis only to pre-multiply the tensors
 * (paper §4: Q̂ = B_yᵀ Q (B_a ⊗ … ⊗ B_b)); one it keeps (radiosity's v, the
 * extern) needs no scratch beyond its basis file. Out of core (ooc.c) a basis is
 * B = A T, A = [μ, (X − μ1ᵀ) W] per member, row by row: a row of B needs only
 * the same row of every sample's snapshot, the Gram eigenvectors W and the
 * small K x m matrix T. So instead of writing A and B to disk (n x K and
 * n x m: 85 GB and 60 GB at the paper's 5,012 faces), a third sweep of
 * passes forms the rows a block needs and uses them at once:
 *
 *   a block      the output rows [n_y·u/U, n_y·(u+1)/U) of every tensor that
 *                reads a blockwise basis (the same fraction of every
 *                output, as the passes of ooc.c take of every class);
 *   its rows     a dry run of each tensor's builder over those output rows
 *                marks every basis row its entries read (RowMap): for
 *                radiosity's c[i,j] = h[i,j]·h[j,i]/π a stripe of rows
 *                (i, *) and the transposed stripe (*, i) of {s,h}; plus the
 *                class's own share of rows ("home": the same fraction of
 *                its rows), so every row's B is seen exactly once;
 *   formed       every sample evaluated restricted to those rows
 *                (full_eval_demand), A's rows as the basis passes make
 *                them, B's rows = A_b T;
 *   used         each tensor's entries of the block's output rows
 *                pre-multiplied (premultiply_block) and added to its sum:
 *                a reduced entry is a sum over output keys, so the blocks'
 *                sums add up to the whole; the rows are then dropped.
 *
 * A block whose rows would exceed --mem's share of a pass is split into
 * sub-blocks of the same fractions (the transposed stripe makes a block
 * about twice a basis pass's rows for radiosity).
 *
 * The sign convention (pca_fix_signs: each column's first row of magnitude
 * at least PCA_SIGN_FRACTION of the column's largest is positive) needs every row of B, so
 * the tensors are summed with B's columns as A T gives them, and the signs
 * are fixed on the sums at the end: flipping column j of a basis multiplies
 * the reduced entries by ±1 (exactly). The row that decides a column's sign
 * is a strict running maximum of |B(·, j)| in row order (the rows before it
 * are below that fraction of the largest, so below it), and one below it of the running
 * maximum can no longer decide: each column keeps the running maxima above
 * that fraction of the current largest (Peaks), as home rows come in ascending order.
 *
 * A class the model keeps has its home rows written to its basis file as
 * they are formed, the signs fixed in the file at the end (one read and
 * write of this rank's rows, only when a column flips), then mapped.
 *
 * Over MPI ranks every rank takes the passes p ≡ rank (mod N) as in ooc.c;
 * the tensors' sums are summed over the ranks, the largest magnitudes and
 * the deciding rows reduced as write_basis does. */
#include <cblas.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "dist.h"
#include "ooc.h"
#include "scratch.h"

/* One column's running maxima of |B(r, j)| (ascending rows), those below
 * PCA_SIGN_FRACTION of the largest dropped. */
typedef struct Peaks {
  double big;               /* the largest |B(r, j)| so far */
  long *row;
  double *v;
  long head, len, cap;
} Peaks;

/* The rows of a blockwise class held for the current block. */
typedef struct Held {
  RowMap map;
  long *run;                /* the held rows as ranges run[2i] <= r < run[2i + 1], ascending */
  long nrun, runcap;
  double **H;               /* per member: count x S column-major, every sample's rows */
  double *A, *B, *mu;       /* count x K, count x m row-major; count */
  size_t Hcap, Acap;
  Peaks *peaks;             /* per column of B */
  double *sign;             /* per column, once every row is seen: ±1 */
  /* a class the model keeps (v's, the extern's): its home rows of B written to its basis file as
   * they are formed, their signs fixed in the file at the end, then mapped (rc->B) */
  FILE *file;
  long *own;                /* the home ranges this rank wrote: own[2i] <= r < own[2i + 1] */
  long nown, owncap;
} Held;

/* A tensor reading a blockwise basis. */
typedef struct STensor {
  RTensor *x;
  int cy;                   /* its output's class */
} STensor;

typedef struct Streamer {
  Ooc *o;
  Held *held;               /* per class (blockwise ones only used) */
  STensor *t;
  long nt;
  long done, total;         /* progress: samples evaluated, of all blocks' (estimated by passes) */
  long nblocks;             /* this rank's blocks */
  double sec[4];            /* wall seconds: dry runs, evaluations, A and B, pre-multiplying */
  double flops;             /* the pre-multiplication's (premultiply_block's count: the packed products) */
  size_t peak;              /* the largest block's bytes of held rows */
  long u, U;                /* the current block: the fraction [u/U, (u+1)/U) of every class's rows */
  /* per class: a blockwise one's held rows of B, its row map and (after decide_signs) its columns'
   * signs; NULL for one whose basis is whole */
  const double **B;
  const RowMap **map;
  const double **sign;
  EstStream *est;           /* the estimate tables of the terms reading a basis never whole (estimate_stream.c) */
} Streamer;

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* An extern's class kept as coefficients (RClass.coef, issue 30): its basis is B = A T diag(sign)
 * with A = X G0 (the mean is X 1/S, the Gram directions (X − μ1ᵀ)W = X (W − 1 1ᵀW/S), or X W
 * uncentered; weighted, X wt/Σwt and X (DW − wt 1ᵀDW/Σwt), D = diag(√wt)), so C = G0 T diag(sign);
 * and its training values' coordinates are BᵀX = diag(sign) Tᵀ(AᵀX), AᵀX from the basis passes (Stream.AX). */
static int coefficients(Ooc *o, int c, const double *sign) {
  Stream *st = &o->st[c];
  RClass *rc = &o->t->m->classes[c];
  const RMember *mb = &rc->members[0];
  long S = o->S, K = st->K, m = st->m, u = st->col[0];
  Scratch sc = SCRATCH_OF(NULL);
  double *G0 = scratch_array(&sc, (size_t)(S * K) + 1, sizeof(double)),
         *P = scratch_array_unzeroed(&sc, (size_t)(S * m + 1), sizeof(double));
  rc->coef = mem_malloc(sizeof(double) * (size_t)(S * m + 1));
  rc->train_coords = mem_malloc(sizeof(double) * (size_t)(S * m + 1));
  if (!G0 || !P || !rc->coef || !rc->train_coords || !st->AX || !st->AX[0]) {
    scratch_release(&sc);
    return err_set(o->t->err, "out of memory keeping class %s as coefficients", rc->label);
  }
  /* weighted (pca_weigh): μ = X wt/Σwt, the directions (X − μ1ᵀ) diag(√wt) W */
  const double *wt = o->t->opt->weights;
  double total = 0;
  for (long e = 0; e < S; e++) total += wt ? wt[e] : 1;
  if (mb->center) {
    for (long e = 0; e < S; e++) G0[u * S + e] = wt ? wt[e] / total : 1.0 / (double)S;
    u++;
  }
  for (long j = 0; j < st->k[0]; j++) {
    const double *w = st->G[0] + j * S;
    double mean = 0;
    for (long e = 0; mb->center && e < S; e++) mean += wt ? sqrt(wt[e]) * w[e] : w[e] / (double)S;
    for (long e = 0; e < S; e++) G0[(u + j) * S + e] = wt ? sqrt(wt[e]) * w[e] - wt[e] / total * mean : w[e] - mean;
  }
  /* P = G0 T (S x m column-major), then C row-major with the signs */
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)S, (int)m, (int)K, 1.0, G0, (int)S, st->T, (int)K, 0.0, P,
              (int)S);
  for (long e = 0; e < S; e++)
    for (long j = 0; j < m; j++) rc->coef[e * m + j] = P[j * S + e] * sign[j];
  /* Tᵀ(AᵀX): m x S column-major, that is S x m row-major */
  cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, (int)m, (int)S, (int)K, 1.0, st->T, (int)K, st->AX[0], (int)K, 0.0,
              rc->train_coords, (int)m);
  for (long e = 0; e < S; e++)
    for (long j = 0; j < m; j++) rc->train_coords[e * m + j] *= sign[j];
  scratch_release(&sc);
  return 0;
}

bool stream_blockwise(const Ooc *o, int c) {
  const Model *m = o->t->m;
  if (!o->st[c].streamed || o->t->opt->user->ninterp > 0 || o->t->opt->valid) return false;
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (rs->st->sym->reduce == STAGE_REDUCE_INTERP) return false; /* its class and reads become needed */
    for (int t = 0; t < rs->nterms; t++)
      if (rs->terms[t].proj_name && (m->qclass[rs->q] == c || m->qclass[rs->terms[t].named_q] == c)) return false;
  }
  return true;
}

static bool blockwise(const Streamer *s, int c) { return s->o->st[c].blockwise; }

/* ---------------------------------------------------------------- row maps */

static int map_alloc(RowMap *map, long n) {
  long words = (n + 63) / 64;
  map->n = n;
  map->bits = mem_calloc((size_t)words + 1, sizeof(uint64_t));
  map->before = mem_calloc((size_t)words + 1, sizeof(long));
  return map->bits && map->before ? 0 : -1;
}

static void map_mark(RowMap *map, long r) { map->bits[r >> 6] |= UINT64_C(1) << (r & 63); }

/* The counts before each word, and the held rows as ranges. */
static int map_finish(Held *h) {
  RowMap *map = &h->map;
  long words = (map->n + 63) / 64, count = 0;
  h->nrun = 0;
  for (long w = 0; w < words; w++) {
    map->before[w] = count;
    uint64_t b = map->bits[w];
    count += __builtin_popcountll(b);
    while (b) { /* the runs of set bits of this word, joined to the previous run when adjacent */
      int lo = __builtin_ctzll(b);
      uint64_t from = b >> lo;
      int len = ~from ? __builtin_ctzll(~from) : 64 - lo;
      long r0 = w * 64 + lo, r1 = r0 + len;
      if (h->nrun > 0 && h->run[2 * h->nrun - 1] == r0) {
        h->run[2 * h->nrun - 1] = r1;
      } else {
        if (h->nrun == h->runcap) {
          long cap = h->runcap ? 2 * h->runcap : 64;
          long *run = mem_realloc(h->run, sizeof(long) * (size_t)(2 * cap));
          if (!run) return -1;
          h->run = run, h->runcap = cap;
        }
        h->run[2 * h->nrun] = r0, h->run[2 * h->nrun + 1] = r1;
        h->nrun++;
      }
      b = lo + len < 64 ? b & ~(((UINT64_C(1) << len) - 1) << lo) : 0;
    }
  }
  map->count = count;
  return 0;
}

/* ---------------------------------------------------------------- the dry run: the rows a block reads */

typedef struct Mark {
  const RTensor *x;
  long lo, hi;
  RowMap *ymap;             /* the output class's rows (NULL: not blockwise) */
  RowMap *inmap[RT_MAX_IN];
} Mark;

static int mark_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  (void)coef;
  Mark *k = user;
  if (row < k->lo || row >= k->hi) return 0;
  /* out-of-range offsets are left to premultiply_block, which names them */
  if (k->ymap && row >= 0 && row < k->ymap->n) map_mark(k->ymap, row);
  if (k->ymap && k->x->kind == RT_DECL && col >= 0 && col < k->ymap->n) map_mark(k->ymap, col);
  for (int pos = 0, j = 0; j < k->x->nin; j++)
    for (int l = 0; l < k->x->in_mult[j]; l++, pos++)
      if (k->inmap[j] && pos < nin && in[pos] >= 0 && in[pos] < k->inmap[j]->n) map_mark(k->inmap[j], in[pos]);
  return 0;
}

void stream_fraction(long n, long u, long U, long *r0, long *r1) {
  *r0 = (long)((double)n * (double)u / (double)U), *r1 = u + 1 == U ? n : (long)((double)n * (double)(u + 1) / (double)U);
}

/* Output rows [lo, hi) of tensor x at the fraction [u/U, (u+1)/U). */
static void block_rows(const Model *m, const STensor *t, long u, long U, long *lo, long *hi) {
  stream_fraction(m->classes[t->cy].n, u, U, lo, hi);
}

/* A class's home rows at the fraction [u/U, (u+1)/U): the same formula, so the homes partition its rows. */
static void home_rows(long n, long u, long U, long *r0, long *r1) { stream_fraction(n, u, U, r0, r1); }

static int mark_block(Streamer *s, long u, long U, size_t *need) {
  Ooc *o = s->o;
  Model *m = o->t->m;
  for (int c = 0; c < m->nclasses; c++) {
    if (!blockwise(s, c)) continue;
    RowMap *map = &s->held[c].map;
    memset(map->bits, 0, sizeof(uint64_t) * (size_t)((map->n + 63) / 64));
    long r0, r1;
    home_rows(map->n, u, U, &r0, &r1);
    for (long r = r0; r < r1; r++) map_mark(map, r);
  }
  for (long i = 0; i < s->nt; i++) {
    const STensor *t = &s->t[i];
    Mark k = {t->x, 0, 0, blockwise(s, t->cy) ? &s->held[t->cy].map : NULL, {NULL}};
    block_rows(m, t, u, U, &k.lo, &k.hi);
    if (k.lo >= k.hi) continue;
    for (int j = 0; j < t->x->nin; j++) {
      int c = m->qclass[t->x->in_q[j]];
      k.inmap[j] = blockwise(s, c) ? &s->held[c].map : NULL;
    }
    NpgSink sink = {&k, mark_entry, 0, 1, k.lo, k.hi}; /* the builder skips the other rows */
    if (full_build(o->t->f, t->x->builder, &sink)) return err_set(o->t->err, "%s", full_error(o->t->f));
  }
  *need = 0;
  for (int c = 0; c < m->nclasses; c++) {
    if (!blockwise(s, c)) continue;
    if (map_finish(&s->held[c])) return err_set(o->t->err, "out of memory");
    const RClass *rc = &m->classes[c];
    *need += sizeof(double) * (size_t)s->held[c].map.count *
             ((size_t)o->S * (size_t)rc->nmembers + (size_t)o->st[c].K + (size_t)o->st[c].m + 1);
  }
  return 0;
}

/* ---------------------------------------------------------------- the block's basis rows */

static int grow(double **p, size_t *cap, size_t need) {
  if (need <= *cap) return 0;
  free(*p);
  *p = mem_malloc(sizeof(double) * need);
  *cap = *p ? need : 0;
  return *p ? 0 : -1;
}

/* Member mb's held rows of sample k (evaluated restricted to them) into out
 * (count values, ascending rows). */
static int held_member_rows(Ooc *o, const Held *h, const RMember *mb, long k, long n, double *out) {
  if (mb->q < 0) { /* an unnamed numerator: through its tensors, whole, once */
    if (train_member_value(o->t, mb, k, n, o->tmp)) return -1;
    for (long q = 0, e = 0; q < h->nrun; e += h->run[2 * q + 1] - h->run[2 * q], q++)
      memcpy(out + e, o->tmp + h->run[2 * q], sizeof(double) * (size_t)(h->run[2 * q + 1] - h->run[2 * q]));
    return 0;
  }
  for (long q = 0, e = 0; q < h->nrun; e += h->run[2 * q + 1] - h->run[2 * q], q++)
    if (ooc_member_rows(o, mb, k, n, h->run + 2 * q, out + e)) return -1;
  return 0;
}

/* Demand the held rows of member quantity q. Its flat rows run over its
 * dims; for one of two dims (a pair quantity, no static axes) the rows
 * are cut at the rows of its last dim and the pieces of consecutive first
 * indices over the same columns joined into one box: a transposed stripe
 * (*, [i0, i1)) is then one box, not one per row (the demand takes a
 * quantity of more than 64 boxes whole, DEMAND_MAX_BOXES). */
static void demand_held(Ooc *o, Demand *d, const Sym *q, const Held *h) {
  long L = 0;
  for (int k = 0; q->ndims == 2 && q->nstatic == 0 && k < o->t->m->prog->dims.n; k++)
    if (o->t->m->prog->dims.v[k] == q->dims[1]) L = full_dim_size(o->t->f, k);
  if (L <= 0) {
    for (long r = 0; r < h->nrun; r++) demand_entries(d, q, (size_t)h->run[2 * r], (size_t)h->run[2 * r + 1]);
    return;
  }
  enum { OPEN = 16 };
  npg_idx box[OPEN][4]; /* lo0, lo1, hi0, hi1: the boxes still growing, oldest first */
  int nbox = 0;
  for (long r = 0; r < h->nrun; r++)
    for (long a = h->run[2 * r], b = h->run[2 * r + 1]; a < b;) {
      long i = a / L, j = a % L, rows = j == 0 ? (b - a) / L : 0;
      npg_idx x[4] = {i, j, i + (rows ? rows : 1), rows ? L : (b < (i + 1) * L ? b - i * L : L)};
      a = rows ? a + rows * L : (b < (i + 1) * L ? b : (i + 1) * L);
      int k = 0;
      while (k < nbox && !(box[k][2] == x[0] && box[k][1] == x[1] && box[k][3] == x[3])) k++;
      if (k < nbox) {
        box[k][2] = x[2]; /* the same columns on the next first indices */
        continue;
      }
      if (nbox == OPEN) { /* the oldest can no longer grow much: out */
        demand_box(d, q, box[0], box[0] + 2);
        memmove(box[0], box[1], sizeof(box[0]) * (OPEN - 1));
        nbox--;
      }
      memcpy(box[nbox++], x, sizeof x);
    }
  for (int k = 0; k < nbox; k++) demand_box(d, q, box[k], box[k] + 2);
}

/* Every sample evaluated restricted to the held rows; each blockwise
 * class's rows of A (as basis_passes forms them) and of B = A T. */
static int form_rows(Streamer *s) {
  Ooc *o = s->o;
  Model *m = o->t->m;
  long S = o->S;
  Demand *d = full_demand(o->t->f);
  if (!d) return err_set(o->t->err, "%s", full_error(o->t->f));
  for (int c = 0; c < m->nclasses; c++) {
    if (!blockwise(s, c)) continue;
    Held *h = &s->held[c];
    const RClass *rc = &m->classes[c];
    if (grow(&h->H[0], &h->Hcap, (size_t)h->map.count * (size_t)S * (size_t)rc->nmembers + 1))
      return err_set(o->t->err, "out of memory forming the basis rows of class %s", rc->label);
    for (int i = 1; i < rc->nmembers; i++) h->H[i] = h->H[i - 1] + (size_t)h->map.count * (size_t)S;
    for (int i = 0; i < rc->nmembers; i++) demand_held(o, d, ooc_member_quantity(m, &rc->members[i]), h);
  }
  estimate_stream_demand(s->est, d);
  if (demand_propagate(d)) return err_set(o->t->err, "out of memory");
  double t0 = now();
  for (long k = 0; k < S; k++) {
    if ((o->t->src->set_part ? o->t->src->set_part(o->t->src->user, o->t->f, k, d) : o->t->src->set(o->t->src->user, o->t->f, k)) ||
        full_eval_demand(o->t->f, k, d))
      return err_set(o->t->err, "%s", full_error(o->t->f));
    if (estimate_stream_sample(s->est, k, s->u, s->U)) return -1;
    for (int c = 0; c < m->nclasses; c++) {
      if (!blockwise(s, c)) continue;
      Held *h = &s->held[c];
      const RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++)
        if (held_member_rows(o, h, &rc->members[i], k, rc->n, h->H[i] + (size_t)k * (size_t)h->map.count)) return -1;
    }
    progress_show(o->t->opt->user->progress, "pre-multiplication (streamed bases)", ++s->done, s->total);
  }
  s->sec[3] += now() - t0;
  for (int c = 0; c < m->nclasses; c++) {
    if (!blockwise(s, c)) continue;
    Held *h = &s->held[c];
    const Stream *st = &o->st[c];
    const RClass *rc = &m->classes[c];
    long R = h->map.count, K = st->K, mm = st->m;
    if (grow(&h->A, &h->Acap, (size_t)R * (size_t)(K + mm + 1) + 1))
      return err_set(o->t->err, "out of memory forming the basis rows of class %s", rc->label);
    h->B = h->A + (size_t)R * (size_t)K, h->mu = h->B + (size_t)R * (size_t)mm;
    memset(h->A, 0, sizeof(double) * (size_t)(R * K));
    for (int i = 0; i < rc->nmembers; i++) { /* basis_passes's arithmetic, row for row */
      long col = st->col[i];
      pca_weigh(R, S, h->H[i], o->t->opt->weights, rc->members[i].center ? h->mu : NULL);
      if (rc->members[i].center) {
        for (long e = 0; e < R; e++) h->A[e * K + col] = h->mu[e];
        col++;
      }
      if (st->k[i] > 0 && R > 0)
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasTrans, (int)R, (int)st->k[i], (int)S, 1.0, h->H[i], (int)R,
                    st->G[i], (int)S, 0.0, h->A + col, (int)K);
    }
    /* B = A T (write_basis's product) */
    if (R > 0)
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)R, (int)mm, (int)K, 1.0, h->A, (int)K, st->T, (int)K, 0.0,
                h->B, (int)mm);
  }
  return 0;
}

/* The home rows' entries of B into each column's running maxima. */
static int take_peaks(Streamer *s, int c, long r0, long r1) {
  Held *h = &s->held[c];
  long mm = s->o->st[c].m;
  for (long r = r0; r < r1; r++) {
    const double *b = h->B + row_map_at(&h->map, r) * mm;
    for (long j = 0; j < mm; j++) {
      Peaks *pk = &h->peaks[j];
      double a = fabs(b[j]);
      if (!(a > pk->big)) continue;
      pk->big = a;
      while (pk->head < pk->len && fabs(pk->v[pk->head]) < PCA_SIGN_FRACTION * a) pk->head++;
      if (pk->head > 0 && pk->head == pk->len) pk->head = pk->len = 0;
      if (pk->len == pk->cap) {
        if (pk->head > 0) { /* reclaim the dropped front */
          memmove(pk->row, pk->row + pk->head, sizeof(long) * (size_t)(pk->len - pk->head));
          memmove(pk->v, pk->v + pk->head, sizeof(double) * (size_t)(pk->len - pk->head));
          pk->len -= pk->head, pk->head = 0;
        }
        if (pk->len == pk->cap) {
          long cap = pk->cap ? 2 * pk->cap : 16;
          long *row = mem_realloc(pk->row, sizeof(long) * (size_t)cap);
          if (row) pk->row = row;
          double *v = mem_realloc(pk->v, sizeof(double) * (size_t)cap);
          if (v) pk->v = v;
          if (!row || !v) return err_set(s->o->t->err, "out of memory");
          pk->cap = cap;
        }
      }
      pk->row[pk->len] = r, pk->v[pk->len] = b[j], pk->len++;
    }
  }
  return 0;
}

/* A kept class's home rows [r0, r1) of B (signs still to fix) into its
 * basis file: they are consecutive among the held rows. */
static int write_home(Streamer *s, int c, long r0, long r1) {
  Held *h = &s->held[c];
  long mm = s->o->st[c].m;
  if (r1 <= r0) return 0;
  if (h->nown == h->owncap) {
    long cap = h->owncap ? 2 * h->owncap : 64;
    long *own = mem_realloc(h->own, sizeof(long) * (size_t)(2 * cap));
    if (!own) return err_set(s->o->t->err, "out of memory");
    h->own = own, h->owncap = cap;
  }
  h->own[2 * h->nown] = r0, h->own[2 * h->nown + 1] = r1, h->nown++;
  if (ooc_write_at(h->file, h->B + row_map_at(&h->map, r0) * mm, sizeof(double) * (size_t)((r1 - r0) * mm),
                   sizeof(double) * (size_t)(r0 * mm)))
    return err_set(s->o->t->err, "cannot write the basis of class %s (disk full?)", s->o->t->m->classes[c].label);
  return 0;
}

/* A kept class's basis once its signs are known: this rank's rows' columns
 * of negative sign flipped in the file, then the whole file mapped
 * read-only on every rank as rc->B (write_basis's ending). */
static int map_kept(Streamer *s, int c) {
  Ooc *o = s->o;
  Held *h = &s->held[c];
  RClass *rc = &o->t->m->classes[c];
  long mm = o->st[c].m, chunk = 4096;
  bool flip = false;
  for (long j = 0; j < mm; j++) flip |= h->sign[j] < 0;
  Scratch sc = SCRATCH_OF(o->t->err);
  double *buf = flip ? scratch_array_unzeroed(&sc, (size_t)(chunk * mm), sizeof(double)) : NULL;
  int bad = flip && !buf; /* the scratch said so */
  for (long q = 0; flip && !bad && q < h->nown; q++)
    for (long r0 = h->own[2 * q]; !bad && r0 < h->own[2 * q + 1]; r0 += chunk) {
      long R = r0 + chunk < h->own[2 * q + 1] ? chunk : h->own[2 * q + 1] - r0;
      size_t len = sizeof(double) * (size_t)(R * mm), off = sizeof(double) * (size_t)(r0 * mm);
      bad = ooc_read_at(h->file, buf, len, off);
      for (long e = 0; !bad && e < R; e++)
        for (long j = 0; j < mm; j++) buf[e * mm + j] *= h->sign[j];
      bad = bad || ooc_write_at(h->file, buf, len, off);
    }
  scratch_release(&sc);
  FILE *fp = h->file;
  h->file = NULL;
  return ooc_map_basis(o, rc, fp, bad);
}

/* ---------------------------------------------------------------- a block */

static int block(Streamer *s, long u, long U, bool split) {
  Ooc *o = s->o;
  Model *m = o->t->m;
  size_t need = 0;
  double t0 = now();
  if (mark_block(s, u, U, &need)) return -1;
  double t1 = now();
  s->sec[0] += t1 - t0;
  long parts = o->avail > 0 ? (long)((need + o->avail - 1) / o->avail) : 1;
  if (split && parts > 1) { /* the rows it reads exceed a pass's share of --mem */
    s->total += (parts - 1) * o->S;
    for (long q = 0; q < parts; q++)
      if (block(s, u * parts + q, U * parts, false)) return -1;
    return 0;
  }
  s->nblocks++;
  s->peak = need > s->peak ? need : s->peak;
  s->u = u, s->U = U;
  if (form_rows(s)) return -1;
  for (int c = 0; c < m->nclasses; c++)
    s->B[c] = blockwise(s, c) ? s->held[c].B : NULL, s->map[c] = blockwise(s, c) ? &s->held[c].map : NULL;
  if (estimate_stream_block(s->est, s->B, s->map, u, U)) return -1;
  double t2 = now();
  s->sec[1] += t2 - t1;
  for (int c = 0; c < m->nclasses; c++) {
    long r0, r1;
    home_rows(m->classes[c].n, u, U, &r0, &r1);
    if (blockwise(s, c) && (take_peaks(s, c, r0, r1) || (s->held[c].file && write_home(s, c, r0, r1)))) return -1;
  }
  double flops = 0;
  for (long i = 0; i < s->nt; i++) {
    const STensor *t = &s->t[i];
    const RClass *cy = &m->classes[t->cy];
    PremulBlock b = {0, 0, blockwise(s, t->cy) ? s->held[t->cy].B : cy->B, cy->n, cy->m,
                     blockwise(s, t->cy) ? &s->held[t->cy].map : NULL, {NULL}, {NULL}};
    block_rows(m, t, u, U, &b.lo, &b.hi);
    if (b.lo >= b.hi) continue;
    for (int j = 0; j < t->x->nin; j++) {
      int c = m->qclass[t->x->in_q[j]];
      b.Bin[j] = blockwise(s, c) ? s->held[c].B : m->classes[c].B;
      b.inmap[j] = blockwise(s, c) ? &s->held[c].map : NULL;
    }
    if (premultiply_block(m, o->t->f, t->x, &b, &flops, o->t->err)) return -1;
  }
  s->sec[2] += now() - t2;
  s->flops += flops;
  return 0;
}

/* ---------------------------------------------------------------- signs */

/* Each blockwise class's column signs, over every rank's rows (write_basis's rule). */
static int decide_signs(Streamer *s) {
  Ooc *o = s->o;
  for (int c = 0; c < o->t->m->nclasses; c++) {
    if (!blockwise(s, c)) continue;
    Held *h = &s->held[c];
    long mm = o->st[c].m;
    Scratch sc = SCRATCH_OF(NULL);
    double *big = scratch_array_unzeroed(&sc, (size_t)(mm + 1), sizeof(double)),
           *first = scratch_array_unzeroed(&sc, (size_t)(mm + 1), sizeof(double));
    if (!big || !first || !(h->sign = mem_malloc(sizeof(double) * (size_t)(mm + 1))))
      return scratch_release(&sc), err_set(o->t->err, "out of memory");
    for (long j = 0; j < mm; j++) big[j] = h->peaks[j].big;
    dist_allreduce_max(big, mm);
    for (long j = 0; j < mm; j++) {
      const Peaks *pk = &h->peaks[j];
      first[j] = -HUGE_VAL;
      for (long q = pk->head; big[j] > 0 && q < pk->len; q++)
        if (fabs(pk->v[q]) >= PCA_SIGN_FRACTION * big[j]) {
          first[j] = -(2.0 * (double)pk->row[q] + (pk->v[q] > 0 ? 0 : 1));
          break;
        }
    }
    dist_allreduce_max(first, mm);
    for (long j = 0; j < mm; j++) h->sign[j] = first[j] > -HUGE_VAL && fmod(-first[j], 2) == 1 ? -1.0 : 1.0;
    scratch_release(&sc);
  }
  return 0;
}

/* The signs of a packed symmetric power's coordinates: those of the
 * product of its indices' signs (sym_outer of the signs, whose
 * coefficients are positive). */
static void packed_signs(long mm, int mult, const double *d, double *out) {
  const double *rows[RT_MAX_IN];
  for (int l = 0; l < mult; l++) rows[l] = d;
  sym_outer(mm, mult, rows, out);
  long len = sym_len(mm, mult);
  for (long a = 0; a < len; a++) out[a] = out[a] < 0 ? -1.0 : 1.0;
}

/* The signs of tensor x's columns given each class's column signs (`sign` NULL, or sign[c] NULL
 * for a class: +1): the Kronecker product of its inputs' packed signs, the first input slowest,
 * as pend_entry lays them out. `pk` holds the largest input's packed length. */
static void tensor_col_signs(const Model *m, const RTensor *x, const double *const *sign, double *cs, double *pk) {
  cs[0] = 1;
  long len = 1;
  for (int j = 0; j < x->nin; j++) {
    int c = m->qclass[x->in_q[j]];
    long lj = x->in_len[j];
    if (sign && sign[c]) packed_signs(m->classes[c].m, x->in_mult[j], sign[c], pk);
    else
      for (long b = 0; b < lj; b++) pk[b] = 1;
    for (long a = len - 1; a >= 0; a--) /* in place from the back, as pend_entry expands */
      for (long b = lj - 1; b >= 0; b--) cs[a * lj + b] = cs[a] * pk[b];
    len *= lj;
  }
}

static long max_in_len(const RTensor *x) {
  long len = 1;
  for (int j = 0; j < x->nin; j++) len = x->in_len[j] > len ? x->in_len[j] : len;
  return len;
}

/* Tensor x's sums as if B's columns had had their signs: entry (a, b) times
 * the sign of output coordinate a and of input coordinate b. */
static int fix_signs(Streamer *s, const STensor *t) {
  Model *m = s->o->t->m;
  RTensor *x = t->x;
  const double *dy = s->sign[t->cy];
  long my = m->classes[t->cy].m;
  Scratch sc = SCRATCH_OF(s->o->t->err);
  double *rs = scratch_array(&sc, (size_t)x->rows + 1, sizeof(double)), *cs = scratch_array(&sc, (size_t)x->cols + 1, sizeof(double));
  double *pk = scratch_array(&sc, (size_t)max_in_len(x) + 1, sizeof(double));
  int out = rs && cs && pk ? 0 : -1;
  long q = 0;
  if (out == 0 && x->kind == RT_NUM)
    for (long a = 0; a < my; a++) rs[q++] = dy ? dy[a] : 1;
  else if (out == 0 && x->kind == RT_DIAG)
    for (long a = 0; a < my; a++)
      for (long c = a; c < my; c++) rs[q++] = dy ? dy[a] * dy[c] : 1;
  else if (out == 0)
    for (long a = 0; a < my; a++)
      for (long c = 0; c < my; c++) rs[q++] = dy ? dy[a] * dy[c] : 1;
  if (out == 0) tensor_col_signs(m, x, s->sign, cs, pk);
  for (long a = 0; out == 0 && a < x->rows; a++)
    for (long b = 0; b < x->cols; b++) x->data[a * x->cols + b] *= rs[a] * cs[b];
  scratch_release(&sc);
  return out;
}

int stream_column_signs(const Ooc *o, const RTerm *rt, int cy, const double *const *sign, double *cs, Scratch *sc) {
  const Model *m = o->t->m;
  long maxlen = 1, maxcols = 1, off = 0, my = m->classes[cy].m;
  for (int k = -1; k < rt->nops; k++)
    for (int g = 0; g < (k < 0 ? rt->nnum : rt->ops[k].ntensors); g++) {
      const RTensor *x = k < 0 ? &rt->num[g] : &rt->ops[k].t[g];
      maxcols = x->cols > maxcols ? x->cols : maxcols, maxlen = max_in_len(x) > maxlen ? max_in_len(x) : maxlen;
    }
  double *pk = scratch_array(sc, (size_t)maxlen + 1, sizeof(double)), *ct = scratch_array(sc, (size_t)maxcols + 1, sizeof(double));
  if (!pk || !ct) return -1;
  if (rt->named_q >= 0) {
    int cw = m->qclass[rt->named_q];
    for (long a = 0; a < m->classes[cw].m; a++) cs[off++] = sign && sign[cw] ? sign[cw][a] : 1;
  }
  for (int g = 0; g < rt->nnum; g++) {
    tensor_col_signs(m, &rt->num[g], sign, ct, pk);
    for (long c = 0; c < rt->num[g].cols; c++) cs[off++] = ct[c];
  }
  const double *dy = sign ? sign[cy] : NULL;
  for (int k = 0; k < rt->nops; k++)
    for (int g = 0; g < rt->ops[k].ntensors; g++) {
      tensor_col_signs(m, &rt->ops[k].t[g], sign, ct, pk);
      for (long a = 0; a < my; a++)
        for (long c = 0; c < rt->ops[k].t[g].cols; c++) cs[off++] = (dy ? dy[a] : 1) * ct[c];
    }
  return 0;
}

/* ---------------------------------------------------------------- the sweep */

static void held_free(Streamer *s) {
  for (int c = 0; s->held && c < s->o->t->m->nclasses; c++) {
    Held *h = &s->held[c];
    free(h->map.bits), free(h->map.before), free(h->run), free(h->A), free(h->sign), free(h->own);
    if (h->file) fclose(h->file);
    if (h->H) free(h->H[0]);
    free(h->H);
    for (long j = 0; h->peaks && j < s->o->st[c].m; j++) free(h->peaks[j].row), free(h->peaks[j].v);
    free(h->peaks);
  }
  free(s->held), free(s->t), free(s->B), free(s->map), free(s->sign);
  estimate_stream_free(s->est);
}

/* The sweep's state: the tensors that read a blockwise class (their sums zeroed), every blockwise
 * class's row map, peaks and (kept by the model) basis file, the estimate tables' terms. 0, or -1
 * with o->t->err. */
static int streamer_setup(Streamer *s) {
  Ooc *o = s->o;
  Model *m = o->t->m;
  long ntensors = 0;
  FOR_TENSORS(m, x) ntensors++;
  int bad = !(s->held = mem_calloc((size_t)m->nclasses, sizeof(Held))) || !(s->t = mem_calloc((size_t)ntensors + 1, sizeof(STensor))) ||
            !(s->B = mem_calloc((size_t)m->nclasses, sizeof(double *))) || !(s->map = mem_calloc((size_t)m->nclasses, sizeof(RowMap *))) ||
            !(s->sign = mem_calloc((size_t)m->nclasses, sizeof(double *)));
  for (int i = 0; !bad && i < m->nstages; i++) {
    int cy = m->qclass[m->stages[i].q];
    for (int t = 0; !bad && t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      RTERM_FOR_TENSORS(rt, x) {
        bool reads = blockwise(s, cy);
        for (int j = 0; j < x->nin; j++) reads |= blockwise(s, m->qclass[x->in_q[j]]);
        if (!reads || bad) continue; /* train_premultiply_all's */
        bad = !(x->data = mem_calloc((size_t)(x->rows * x->cols) + 1, sizeof(double)));
        s->t[s->nt++] = (STensor){x, cy};
      }
    }
  }
  for (int c = 0; !bad && c < m->nclasses; c++) {
    if (!blockwise(s, c)) continue;
    Held *h = &s->held[c];
    bad = map_alloc(&h->map, m->classes[c].n) || !(h->H = mem_calloc((size_t)m->classes[c].nmembers, sizeof(double *))) ||
          !(h->peaks = mem_calloc((size_t)o->st[c].m + 1, sizeof(Peaks)));
  }
  if (bad) return err_set(o->t->err, "out of memory pre-multiplying by the streamed bases");
  for (int c = 0; c < m->nclasses; c++) /* every rank in the same order: over ranks a collective */
    if (blockwise(s, c) && !m->classes[c].streamed &&
        !(s->held[c].file = ooc_basis_file(o, &m->classes[c], sizeof(double) * (size_t)m->classes[c].n * (size_t)o->st[c].m)))
      return -1;
  return estimate_stream_begin(o, &s->est);
}

/* What the sweep did, on stderr (--progress). */
static void report_sweep(const Streamer *s) {
  const Model *m = s->o->t->m;
  if (!s->o->t->opt->user->progress) return;
  fprintf(stderr, "out of core: bases formed block by block for the pre-multiplication, no basis file:");
  for (int c = 0; c < m->nclasses; c++)
    if (blockwise(s, c) && m->classes[c].streamed) fprintf(stderr, " %s", m->classes[c].label);
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].coef) fprintf(stderr, "; %s kept as coefficients of its training values", m->classes[c].label);
  fprintf(stderr, "; kept, written as formed (no scratch A):");
  for (int c = 0; c < m->nclasses; c++)
    if (blockwise(s, c) && !m->classes[c].streamed) fprintf(stderr, " %s", m->classes[c].label);
  fprintf(stderr, " (%ld blocks on this rank, at most %.3g MB of rows held, %ld tensors; %.2f s finding the rows, "
          "%.2f s forming them (%.2f s of it evaluating), %.2f s pre-multiplying: %.3g flops, %.3g GFLOP/s)\n", s->nblocks,
          (double)s->peak / 1e6, s->nt, s->sec[0], s->sec[1], s->sec[3], s->sec[2], s->flops,
          s->sec[2] > 0 ? s->flops / s->sec[2] / 1e9 : 0.0);
}

/* The blocks of this rank's passes, then the signs: the coefficients and kept files fixed, the
 * tensors' sums added over the ranks and fixed, the estimate tables made. */
static int sweep(Streamer *s) {
  Ooc *o = s->o;
  Model *m = o->t->m;
  /* the passes' buffers are done with: their bytes are this sweep's */
  free(o->block), free(o->abuf);
  o->block = o->abuf = NULL, o->block_cap = o->abuf_cap = 0;
  s->total = (o->npass - o->rank + o->N - 1) / o->N * o->S; /* this rank's passes, before any split */
  for (long p = 0; p < o->npass; p++)
    if (ooc_mine(o, p) && block(s, p, o->npass, true)) return -1;
  if (decide_signs(s)) return -1;
  for (int c = 0; c < m->nclasses; c++) s->sign[c] = blockwise(s, c) ? s->held[c].sign : NULL;
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].coef_S > 0 && blockwise(s, c) && coefficients(o, c, s->held[c].sign)) return -1;
  for (int c = 0; c < m->nclasses; c++)
    if (s->held[c].file && map_kept(s, c)) return -1;
  report_sweep(s);
  for (long i = 0; i < s->nt; i++) {
    RTensor *x = s->t[i].x;
    if (o->N > 1) dist_allreduce_sum(x->data, x->rows * x->cols); /* every rank's blocks summed */
    if (fix_signs(s, &s->t[i])) return -1;
  }
  return estimate_stream_finish(s->est, s->sign);
}

int stream_premultiply(Ooc *o) {
  Model *m = o->t->m;
  bool any = false;
  for (int c = 0; c < m->nclasses; c++) any |= o->st[c].blockwise;
  if (!any) return 0;
  Streamer s = {.o = o};
  int rc = streamer_setup(&s) || sweep(&s) ? -1 : 0;
  held_free(&s);
  return rc;
}
