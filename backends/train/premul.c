/* premul.c — pre-multiplication of one tensor by its bases (DESIGN §5;
 * paper §4: Q̂ = B_yᵀ Q (B_a ⊗ … ⊗ B_b)), the expensive step of training.
 *
 * The tensor is never formed. Its builder streams the sparse entries
 * (row, col, input offsets, coefficient) in output-major order; entries of
 * one output key (a row; a (row, col) pair for a declared operator) are
 * summed into a row of a block matrix W over the packed input coordinates,
 * as outer products of basis rows — batched into one small GEMM per key.
 * When the block is full, one GEMM against the output basis finishes it:
 *
 *     Q̂ += K_blockᵀ W_block,
 *
 * K's row for a key being B_y[row] (numerator), the packed upper triangle
 * of B_y[row] ⊗ B_y[row] (diagonal operator: BᵀDB is symmetric), or
 * B_y[row] ⊗ B_y[col] (declared operator). An input repeated k times
 * contributes its packed symmetrized power (model.h), so x ⊗ x is stored
 * once. All dense work is OpenBLAS dgemm.
 *
 * Map and reduce across output blocks: the builder's callback only records
 * a block's entries; the block's keys are then split at row boundaries
 * over worker threads (one per core), each accumulating its keys' rows of W
 * and K with its own scratch and finishing them with its own GEMM into its
 * own sum of Q̂ (summed once at the end), BLAS on one thread throughout:
 * one worker's per-key work overlaps another's GEMM, and no idle BLAS
 * thread spins meanwhile. (Where the sums would not fit, the block's final
 * GEMM is shared and runs on OpenBLAS's threads.)
 *
 * A last x ⊗ x axis with many monomials per key is accumulated unpacked —
 * one real GEMM of full basis rows per batch, folded into packed form —
 * instead of one packed row per entry.
 *
 * A block of output rows (premultiply_block, issue 30): the entries of the
 * output rows [lo, hi) only, added to the tensor's sum, the bases' rows read
 * through row maps from buffers holding only the rows the block reads
 * (stream.c forms them block by block and never stores a whole basis). A
 * reduced entry is a sum over output keys, so the blocks' sums add up to
 * the whole. */
#include <cblas.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "scratch.h"
#include "train.h"

#define PREMUL_PENDING 64               /* entries batched per GEMM of a key */
#define PREMUL_BLOCK_BYTES (128L << 20) /* bound on a block's W */
#define PREMUL_MAX_KEYS 2048            /* keys per block */
#define PREMUL_UNPACK_MONOS 8           /* monomials per key from which x ⊗ x goes unpacked */
#define PREMUL_MAX_WORKERS 8
#define PREMUL_LOCAL_BYTES (256L << 20) /* bound on the workers' own sums */

struct Premul;

/* One worker's share of a block: keys [k0, k1), their entries [e0, e1). */
typedef struct Worker {
  struct Premul *p;
  long k0, k1, e0, e1;
  double *U, *V, *G;          /* pending U rows, V rows; unpacked flush scratch */
  double *vec;                /* packed input vectors of one entry */
  long npend, pend_key;
  double *acc;                /* local: this worker's sum of its blocks' final GEMMs (rows x cols) */
  double flops;
} Worker;

typedef struct Premul {
  const Model *m;
  RTensor *t;
  const double *By;
  const double *Bcol;         /* a declared operator's column basis (PremulOut.Bcol; NULL: By) */
  long ny, my;
  const double *Bin[RT_MAX_IN];
  long min[RT_MAX_IN], nin_full[RT_MAX_IN];
  long pre, last;             /* cols = pre * last: the last input axis apart */
  bool unpack;                /* last axis x ⊗ x accumulated unpacked, folded per flush */
  long mu;                    /* the last input's basis size m */
  long ulen, vlen;            /* lengths of a U row and a V row */
  long KB, nkeys, row_start;  /* keys per block, keys in block, first key of the current row */
  long *key_row, *key_col;
  double *W;                  /* KB x cols */
  double *K;                  /* KB x rows */
  /* the block's entries, in stream order */
  long nent, capent;
  int nidx;                   /* input offsets per entry */
  long *ent_key;
  double *ent_coef;
  npg_idx *ent_in;
  int part, nparts;           /* the output rows ≡ part (mod nparts) only (PremulOut.part):
                                 the builder enumerates no other row (NpgSink) */
  long lo, hi;                /* the output rows [lo, hi) only (premultiply_block): others skipped */
  const RowMap *ymap;         /* By's row r at ymap's index of r (NULL: at r) */
  const RowMap *inmap[RT_MAX_IN];
  int nworkers;
  bool local;                 /* each worker finishes its own keys (see flush_block) */
  Worker wk[PREMUL_MAX_WORKERS];
  double flops;
  Err *err;
} Premul;

/* Unpacked x ⊗ x: G = Σ_e U_eᵀ V_e over the pending entries, U_e =
 * coef · prefix ⊗ B[i], V_e = B[j]; then fold into the packed row,
 * w(a,a) += G[a,a], w(a,b) += G[a,b] + G[b,a] (sym_outer's coordinates). */
static void flush_unpacked(Worker *w, double *Wk) {
  const Premul *p = w->p;
  long m = p->mu, pm = p->pre * m;
  cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)pm, (int)m, (int)w->npend, 1.0, w->U, (int)pm, w->V,
              (int)m, 0.0, w->G, (int)m);
  for (long q = 0; q < p->pre; q++) {
    const double *g = w->G + q * m * m;
    double *wr = Wk + q * p->last;
    for (long a = 0; a < m; a++) {
      const double *ga = g + a * m;
      *wr++ += ga[a];
      for (long b = a + 1; b < m; b++) *wr++ += ga[b] + g[b * m + a];
    }
  }
}

static void flush_pending(Worker *w) {
  if (w->npend == 0) return;
  const Premul *p = w->p;
  double *Wk = p->W + w->pend_key * p->t->cols;
  /* flops are counted as the packed product's, the useful work */
  w->flops += 2.0 * (double)p->pre * (double)p->last * (double)w->npend;
  if (p->unpack) flush_unpacked(w, Wk);
  else if (w->npend == 1 && p->pre == 1) cblas_daxpy((int)p->last, w->U[0], w->V, 1, Wk, 1);
  else
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)p->pre, (int)p->last, (int)w->npend, 1.0, w->U,
                (int)p->pre, w->V, (int)p->last, 1.0, Wk, (int)p->last);
  w->npend = 0;
}

/* K's row of key k: what the output basis contributes. */
static void key_row(const Premul *p, long k) {
  const RTensor *t = p->t;
  long my = p->my;
  double *Kk = p->K + k * t->rows;
  const double *b = p->By + row_map_at(p->ymap, p->key_row[k]) * my;
  if (t->kind == RT_NUM) {
    memcpy(Kk, b, sizeof(double) * (size_t)my);
  } else if (t->kind == RT_DIAG) {
    long q = 0;
    for (long a = 0; a < my; a++)
      for (long c = a; c < my; c++) Kk[q++] = b[a] * b[c];
  } else {
    const double *bc = (p->Bcol ? p->Bcol : p->By) + row_map_at(p->ymap, p->key_col[k]) * my;
    for (long a = 0; a < my; a++)
      for (long c = 0; c < my; c++) Kk[a * my + c] = b[a] * bc[c];
  }
}

/* Append entry e to the worker's pending batch: U row = coef · v_1 ⊗ … ⊗
 * v_{J-1}, V row = v_J (packed vectors of the inputs); unpacked x ⊗ x last:
 * U row = coef · v_1 ⊗ … ⊗ v_{J-1} ⊗ B[i], V row = B[j]. */
static void pend_entry(Worker *w, long e) {
  const Premul *p = w->p;
  const RTensor *t = p->t;
  double coef = p->ent_coef[e];
  const npg_idx *in = p->ent_in + e * p->nidx;
  double *Ur = w->U + w->npend * p->ulen, *Vr = w->V + w->npend * p->vlen;
  if (t->nin == 0) {
    Ur[0] = coef;
    Vr[0] = 1;
    return;
  }
  int pos = 0, nk = 0; /* nk: factors of U's Kronecker product */
  const double *v[RT_MAX_IN + 1];
  long vl[RT_MAX_IN + 1];
  double *vp = w->vec;
  for (int j = 0; j < t->nin; j++) {
    const double *rows[RT_MAX_IN];
    for (int l = 0; l < t->in_mult[j]; l++, pos++) rows[l] = p->Bin[j] + row_map_at(p->inmap[j], in[pos]) * p->min[j];
    if (j == t->nin - 1 && p->unpack) {
      v[nk] = rows[0];
      vl[nk++] = p->mu;
      memcpy(Vr, rows[1], sizeof(double) * (size_t)p->mu);
    } else if (j == t->nin - 1) {
      sym_outer(p->min[j], t->in_mult[j], rows, Vr);
    } else {
      sym_outer(p->min[j], t->in_mult[j], rows, vp);
      v[nk] = vp;
      vl[nk++] = t->in_len[j];
      vp += t->in_len[j];
    }
  }
  Ur[0] = coef;
  long len = 1;
  for (int j = 0; j < nk; j++) {
    long lj = vl[j];
    /* expand in place from the back: Ur[a*lj + b] = Ur[a] * v_j[b] */
    for (long a = len - 1; a >= 0; a--) {
      double ua = Ur[a];
      for (long b = lj - 1; b >= 0; b--) Ur[a * lj + b] = ua * v[j][b];
    }
    len *= lj;
  }
}

/* A worker's share: zero its W rows, fill its K rows, accumulate its entries. */
static void *work(void *arg) {
  Worker *w = arg;
  const Premul *p = w->p;
  long cols = p->t->cols;
  memset(p->W + w->k0 * cols, 0, sizeof(double) * (size_t)((w->k1 - w->k0) * cols));
  for (long k = w->k0; k < w->k1; k++) key_row(p, k);
  w->npend = 0;
  w->pend_key = -1;
  for (long e = w->e0; e < w->e1; e++) {
    long key = p->ent_key[e];
    if (key != w->pend_key) {
      flush_pending(w);
      w->pend_key = key;
    }
    pend_entry(w, e);
    if (++w->npend == PREMUL_PENDING) flush_pending(w);
  }
  flush_pending(w);
  if (p->local && w->k1 > w->k0) {
    const RTensor *t = p->t;
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)t->rows, (int)cols, (int)(w->k1 - w->k0), 1.0,
                p->K + w->k0 * t->rows, (int)t->rows, p->W + w->k0 * cols, (int)cols, 1.0, w->acc, (int)cols);
    w->flops += 2.0 * (double)t->rows * (double)cols * (double)(w->k1 - w->k0);
  }
  return NULL;
}

/* Split the block's keys over the workers at row boundaries, balancing
 * entries (a row's keys, and so its entries, stay with one worker: entries
 * of one row are contiguous in the stream and their keys are numbered
 * together). */
static void split_block(Premul *p) {
  int nw = p->nworkers;
  long kprev = 0, eprev = 0;
  for (int i = 0; i < nw; i++) {
    Worker *w = &p->wk[i];
    long ks = p->nkeys, es = p->nent;
    if (i + 1 < nw) {
      long e = p->nent * (i + 1) / nw;
      ks = e < p->nent ? p->ent_key[e] : p->nkeys;
      while (ks > 0 && ks < p->nkeys && p->key_row[ks - 1] == p->key_row[ks]) ks--;
      if (ks < kprev) ks = kprev;
      es = eprev;
      while (es < p->nent && p->ent_key[es] < ks) es++;
    }
    w->k0 = kprev;
    w->k1 = ks;
    w->e0 = eprev;
    w->e1 = es;
    kprev = ks;
    eprev = es;
  }
}

static void flush_block(Premul *p) {
  if (p->nkeys == 0) return;
  RTensor *t = p->t;
  split_block(p);
  pthread_t tid[PREMUL_MAX_WORKERS];
  bool started[PREMUL_MAX_WORKERS] = {false};
  /* shared final GEMM: the workers' small GEMMs on one BLAS thread each,
   * OpenBLAS's threads for the block's GEMM (local: one thread throughout) */
  int blas_threads = openblas_get_num_threads();
  if (!p->local && p->nworkers > 1) openblas_set_num_threads(1);
  for (int i = 1; i < p->nworkers; i++)
    started[i] = p->wk[i].k1 > p->wk[i].k0 && pthread_create(&tid[i], NULL, work, &p->wk[i]) == 0;
  work(&p->wk[0]);
  for (int i = 1; i < p->nworkers; i++) {
    if (started[i]) pthread_join(tid[i], NULL);
    else if (p->wk[i].k1 > p->wk[i].k0) work(&p->wk[i]); /* no thread: do it here */
  }
  if (!p->local && p->nworkers > 1) openblas_set_num_threads(blas_threads);
  if (!p->local) {
    long cols = t->cols;
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)t->rows, (int)cols, (int)p->nkeys, 1.0, p->K,
                (int)t->rows, p->W, (int)cols, 1.0, t->data, (int)cols);
    p->flops += 2.0 * (double)t->rows * (double)cols * (double)p->nkeys;
  }
  p->nkeys = 0;
  p->row_start = 0;
  p->nent = 0;
}

static int grow_entries(Premul *p) {
  long cap = p->capent ? 2 * p->capent : 4096;
  long *k = mem_realloc(p->ent_key, sizeof(long) * (size_t)cap);
  if (k) p->ent_key = k;
  double *c = mem_realloc(p->ent_coef, sizeof(double) * (size_t)cap);
  if (c) p->ent_coef = c;
  npg_idx *in = mem_realloc(p->ent_in, sizeof(npg_idx) * (size_t)(cap * (p->nidx ? p->nidx : 1)));
  if (in) p->ent_in = in;
  if (!k || !c || !in) {
    err_set(p->err, "out of memory pre-multiplying %s (%ld entries in a block)", p->t->name, cap);
    return -1;
  }
  p->capent = cap;
  return 0;
}

static int on_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Premul *p = user;
  RTensor *t = p->t;
  if (row < 0 || row >= p->ny || (t->kind == RT_DECL && (col < 0 || col >= p->ny))) {
    err_set(p->err, "tensor %s: entry (%ld, %ld) outside %ld rows (a bug in npg)", t->name, (long)row, (long)col,
            p->ny);
    return -1;
  }
  for (int pos = 0, j = 0; j < t->nin; j++)
    for (int l = 0; l < t->in_mult[j]; l++, pos++)
      if (pos >= nin || in[pos] < 0 || in[pos] >= p->nin_full[j]) {
        err_set(p->err, "tensor %s: input offset out of range (a bug in npg)", t->name);
        return -1;
      }
  if (row < p->lo || row >= p->hi) return 0; /* another block's */
  bool held = row_map_has(p->ymap, row) && (t->kind != RT_DECL || row_map_has(p->ymap, col));
  for (int pos = 0, j = 0; j < t->nin; j++)
    for (int l = 0; l < t->in_mult[j]; l++, pos++) held = held && row_map_has(p->inmap[j], in[pos]);
  if (!held) {
    err_set(p->err, "tensor %s: a basis row of output row %ld is not among the block's (a bug in npg)", t->name,
            (long)row);
    return -1;
  }
  if (row % p->nparts != p->part) {
    err_set(p->err, "tensor %s: row %ld is not this rank's (%d of %d; a bug in npg)", t->name, (long)row, p->part,
            p->nparts);
    return -1;
  }
  /* the key of this entry */
  long key = -1;
  bool same_row = p->nkeys > 0 && p->key_row[p->nkeys - 1] == row;
  if (!same_row) p->row_start = p->nkeys;
  if (t->kind == RT_DECL) {
    for (long k = p->row_start; k < p->nkeys && key < 0; k++)
      if (p->key_col[k] == col) key = k;
  } else if (same_row) {
    key = p->nkeys - 1;
  }
  if (key < 0) {
    if (p->nkeys == p->KB) {
      /* a row's keys never straddle a block for declared operators: that
       * only costs a repeated key, the sum is the same */
      flush_block(p);
      p->row_start = 0;
    }
    key = p->nkeys++;
    p->key_row[key] = row;
    p->key_col[key] = col;
  }
  if (p->nent == p->capent && grow_entries(p)) return -1;
  p->ent_key[p->nent] = key;
  p->ent_coef[p->nent] = coef;
  if (p->nidx) memcpy(p->ent_in + p->nent * p->nidx, in, sizeof(npg_idx) * (size_t)p->nidx);
  p->nent++;
  return 0;
}

long premul_keys_per_block(const RTensor *t) {
  long bytes_per_key = (long)sizeof(double) * (t->cols + t->rows);
  long kb = PREMUL_BLOCK_BYTES / (bytes_per_key ? bytes_per_key : 1);
  return kb > PREMUL_MAX_KEYS ? PREMUL_MAX_KEYS : kb < 1 ? 1 : kb;
}

/* One worker per core, at most OPENBLAS_NUM_THREADS when the environment
 * sets it (1: one thread, as for MPI ranks sharing a machine). */
static int workers_online(void) {
  long n = sysconf(_SC_NPROCESSORS_ONLN);
  const char *env = getenv("OPENBLAS_NUM_THREADS");
  long blas = env ? strtol(env, NULL, 10) : 0;
  if (blas >= 1 && blas < n) n = blas;
  return n < 1 ? 1 : n > PREMUL_MAX_WORKERS ? PREMUL_MAX_WORKERS : (int)n;
}

static int premultiply_rows(Premul *p, Full *f, const PremulBlock *b, int unpack_min_monos, double *flops);

int premultiply(Model *m, Full *f, RTensor *t, const PremulOut *out, double *flops, Err *err) {
  Premul p = {.m = m,
              .t = t,
              .By = out->By,
              .Bcol = out->Bcol,
              .ny = out->ny,
              .my = out->my,
              .part = out->part,
              .nparts = out->nparts,
              .err = err};
  return premultiply_rows(&p, f, NULL, out->unpack_min_monos > 0 ? out->unpack_min_monos : PREMUL_UNPACK_MONOS, flops);
}

int premultiply_block(Model *m, Full *f, RTensor *t, const PremulBlock *b, double *flops, Err *err) {
  Premul p = {.m = m, .t = t, .By = b->By, .ny = b->ny, .my = b->my, .err = err};
  return premultiply_rows(&p, f, b, PREMUL_UNPACK_MONOS, flops);
}

/* The builder's entries of p's tensor streamed through the workers (of block `b`'s output rows
 * only when b is not NULL), then the workers' own sums added up. 0, or -1 with the builder's
 * message in p's error record. */
static int build_entries(Premul *p, Full *f, const PremulBlock *b) {
  RTensor *t = p->t;
  if (err_held(p->err)) p->err->msg[0] = 0;
  /* the builder enumerates this rank's rows only, of the block's (premultiply_block) */
  NpgSink sink = {p, on_entry, p->part, p->nparts, b ? b->lo : 0, b ? b->hi : 0};
  int blas_threads = openblas_get_num_threads();
  if (p->local) openblas_set_num_threads(1);
  int built = full_build(f, t->builder, &sink);
  if (built == 0) flush_block(p);
  if (p->local) openblas_set_num_threads(blas_threads);
  if (built != 0) return err_set_first(p->err, "%s", full_error(f));
  for (int i = 1; i < p->nworkers && p->local; i++)
    cblas_daxpy((int)(t->rows * t->cols), 1.0, p->wk[i].acc, 1, t->data, 1);
  for (int i = 0; i < p->nworkers; i++) p->flops += p->wk[i].flops;
  return 0;
}

/* The pre-multiplication of p->t by p->By (p's tensor, output basis, rows and
 * error record set), of block `b`'s rows only when b is not NULL. */
static int premultiply_rows(Premul *pp, Full *f, const PremulBlock *b, int unpack_min_monos, double *flops) {
  Premul p = *pp;
  const Model *m = p.m;
  RTensor *t = p.t;
  Err *err = p.err;
  p.lo = b ? b->lo : 0;
  p.hi = b ? b->hi : p.ny;
  p.ymap = b ? b->ymap : NULL;
  p.nparts = p.nparts > 0 ? p.nparts : 1;
  long veclen = 1;
  for (int j = 0; j < t->nin; j++) {
    const RClass *c = &m->classes[m->qclass[t->in_q[j]]];
    p.Bin[j] = b ? b->Bin[j] : c->B;
    p.inmap[j] = b ? b->inmap[j] : NULL;
    p.min[j] = c->m;
    p.nin_full[j] = c->n;
    p.nidx += t->in_mult[j];
    veclen += t->in_len[j];
  }
  p.last = t->nin ? t->in_len[t->nin - 1] : 1;
  p.pre = t->cols / p.last;
  /* many monomials per key on a last x ⊗ x axis: one real GEMM per batch
   * instead of a packed row per entry (a GEMV) */
  p.unpack = t->nin > 0 && t->in_mult[t->nin - 1] == 2 && t->group && t->group->nmono >= unpack_min_monos;
  p.mu = t->nin ? p.min[t->nin - 1] : 1;
  p.ulen = p.unpack ? p.pre * p.mu : p.pre;
  p.vlen = p.unpack ? p.mu : p.last;
  p.KB = premul_keys_per_block(t);
  p.nworkers = workers_online();
  /* each worker finishes its own keys into its own sum when the sums fit:
   * no BLAS threads (which would spin while the workers run), the per-key
   * work of one worker overlapping the other's GEMM */
  p.local = p.nworkers > 1 && (double)t->rows * (double)t->cols * (double)(p.nworkers - 1) * sizeof(double) <=
                                  (double)PREMUL_LOCAL_BYTES;
  Scratch sc = SCRATCH_OF(err);
  if (!b) /* the tensor's data, the scratch's until it is whole (a block adds to the caller's) */
    t->data = scratch_adopt(&sc, mem_calloc((size_t)(t->rows * t->cols) + 1, sizeof(double)));
  p.key_row = scratch_array(&sc, (size_t)p.KB, sizeof(long));
  p.key_col = scratch_array(&sc, (size_t)p.KB, sizeof(long));
  p.W = scratch_array(&sc, (size_t)(p.KB * t->cols), sizeof(double));
  p.K = scratch_array(&sc, (size_t)(p.KB * t->rows), sizeof(double));
  bool ok = t->data && p.key_row && p.key_col && p.W && p.K;
  for (int i = 0; i < p.nworkers; i++) {
    Worker *w = &p.wk[i];
    w->p = &p;
    w->U = scratch_array(&sc, (size_t)(PREMUL_PENDING * p.ulen), sizeof(double));
    w->V = scratch_array(&sc, (size_t)(PREMUL_PENDING * p.vlen), sizeof(double));
    w->G = p.unpack ? scratch_array(&sc, (size_t)(p.ulen * p.mu), sizeof(double)) : NULL;
    w->vec = scratch_array(&sc, (size_t)veclen, sizeof(double));
    w->acc = !p.local ? NULL : i == 0 ? t->data : scratch_array(&sc, (size_t)(t->rows * t->cols) + 1, sizeof(double));
    ok = ok && w->U && w->V && w->vec && (!p.unpack || w->G) && (!p.local || w->acc);
  }
  int rc = ok ? build_entries(&p, f, b)
              : err_set(err, "out of memory pre-multiplying %s (%ld x %ld reduced entries)", t->name, t->rows, t->cols);
  if (rc == 0 && flops) *flops += p.flops;
  free(p.ent_key), free(p.ent_coef), free(p.ent_in); /* grown by grow_entries */
  if (!b) t->data = rc == 0 ? scratch_keep(&sc, t->data) : NULL; /* the tensor's on success; else left without data, not half made */
  scratch_release(&sc);
  return rc;
}
