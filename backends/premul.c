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
 * contributes its packed symmetrized power (reduce.h), so x ⊗ x is stored
 * once. All dense work is OpenBLAS dgemm. */
#include <cblas.h>
#include <stdlib.h>
#include <string.h>

#include "reduce.h"

#define PREMUL_PENDING 64          /* entries batched per GEMM of a key */
#define PREMUL_BLOCK_BYTES (64L << 20)  /* bound on a block's W */

typedef struct Premul {
  const Model *m;
  RTensor *t;
  const double *By;
  long ny, my;
  const double *Bin[RT_MAX_IN];
  long min[RT_MAX_IN], nin_full[RT_MAX_IN];
  long pre, last;             /* cols = pre * last: the last input axis apart */
  long KB, nkeys, row_start;  /* keys per block, keys in block, first key of the current row */
  long *key_row, *key_col;
  double *W;                  /* KB x cols */
  double *K;                  /* KB x rows */
  long npend, pend_key;
  double *U, *V;              /* PREMUL_PENDING x pre, x last */
  double *vec;                /* packed input vectors of one entry */
  double *kron;               /* running Kronecker product */
  double flops;
  char *err;
  size_t errlen;
} Premul;

static void flush_pending(Premul *p) {
  if (p->npend == 0) return;
  double *Wk = p->W + p->pend_key * p->pre * p->last;
  cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)p->pre, (int)p->last, (int)p->npend, 1.0, p->U,
              (int)p->pre, p->V, (int)p->last, 1.0, Wk, (int)p->last);
  p->flops += 2.0 * (double)p->pre * (double)p->last * (double)p->npend;
  p->npend = 0;
}

static void flush_block(Premul *p) {
  flush_pending(p);
  if (p->nkeys == 0) return;
  RTensor *t = p->t;
  long my = p->my;
  for (long k = 0; k < p->nkeys; k++) {
    double *Kk = p->K + k * t->rows;
    const double *b = p->By + p->key_row[k] * my;
    if (t->kind == RT_NUM) {
      memcpy(Kk, b, sizeof(double) * (size_t)my);
    } else if (t->kind == RT_DIAG) {
      long q = 0;
      for (long a = 0; a < my; a++)
        for (long c = a; c < my; c++) Kk[q++] = b[a] * b[c];
    } else {
      const double *bc = p->By + p->key_col[k] * my;
      for (long a = 0; a < my; a++)
        for (long c = 0; c < my; c++) Kk[a * my + c] = b[a] * bc[c];
    }
  }
  long cols = t->cols;
  cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)t->rows, (int)cols, (int)p->nkeys, 1.0, p->K,
              (int)t->rows, p->W, (int)cols, 1.0, t->data, (int)cols);
  p->flops += 2.0 * (double)t->rows * (double)cols * (double)p->nkeys;
  p->nkeys = 0;
  p->row_start = 0;
}

static int on_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Premul *p = user;
  RTensor *t = p->t;
  if (row < 0 || row >= p->ny || (t->kind == RT_DECL && (col < 0 || col >= p->ny))) {
    snprintf(p->err, p->errlen, "tensor %s: entry (%ld, %ld) outside %ld rows (a bug in npg)", t->name, (long)row,
             (long)col, p->ny);
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
    memset(p->W + key * t->cols, 0, sizeof(double) * (size_t)t->cols);
  }
  if (key != p->pend_key) {
    flush_pending(p);
    p->pend_key = key;
  }
  /* packed vectors of the inputs, then U row = coef · v_1 ⊗ … ⊗ v_{J-1}, V row = v_J */
  double *Ur = p->U + p->npend * p->pre, *Vr = p->V + p->npend * p->last;
  if (t->nin == 0) {
    Ur[0] = coef;
    Vr[0] = 1;
  } else {
    int pos = 0;
    double *v[RT_MAX_IN];
    double *vp = p->vec;
    for (int j = 0; j < t->nin; j++) {
      const double *rows[RT_MAX_IN];
      for (int l = 0; l < t->in_mult[j]; l++, pos++) {
        if (pos >= nin || in[pos] < 0 || in[pos] >= p->nin_full[j]) {
          snprintf(p->err, p->errlen, "tensor %s: input offset out of range (a bug in npg)", t->name);
          return -1;
        }
        rows[l] = p->Bin[j] + in[pos] * p->min[j];
      }
      v[j] = j == t->nin - 1 ? Vr : vp;
      sym_outer(p->min[j], t->in_mult[j], rows, v[j]);
      if (j < t->nin - 1) vp += t->in_len[j];
    }
    /* Kronecker product of v_0 … v_{J-2}, scaled by coef */
    Ur[0] = coef;
    long len = 1;
    for (int j = 0; j + 1 < t->nin; j++) {
      long lj = t->in_len[j];
      /* expand in place from the back: Ur[a*lj + b] = Ur[a] * v_j[b] */
      for (long a = len - 1; a >= 0; a--) {
        double ua = Ur[a];
        for (long b = lj - 1; b >= 0; b--) Ur[a * lj + b] = ua * v[j][b];
      }
      len *= lj;
    }
  }
  if (++p->npend == PREMUL_PENDING) flush_pending(p);
  return 0;
}

int premultiply(Model *m, NpgFull *f, RTensor *t, const double *By, long ny, long my, double *flops, char *err,
                size_t errlen) {
  Premul p = {0};
  p.m = m;
  p.t = t;
  p.By = By;
  p.ny = ny;
  p.my = my;
  p.err = err;
  p.errlen = errlen;
  p.pend_key = -1;
  long veclen = 1;
  for (int j = 0; j < t->nin; j++) {
    const RClass *c = &m->classes[m->qclass[t->in_q[j]]];
    p.Bin[j] = c->B;
    p.min[j] = c->m;
    p.nin_full[j] = c->n;
    veclen += t->in_len[j];
  }
  p.last = t->nin ? t->in_len[t->nin - 1] : 1;
  p.pre = t->cols / p.last;
  long bytes_per_key = (long)sizeof(double) * (t->cols + t->rows);
  p.KB = PREMUL_BLOCK_BYTES / (bytes_per_key ? bytes_per_key : 1);
  if (p.KB > 1024) p.KB = 1024;
  if (p.KB < 1) p.KB = 1;
  t->data = calloc((size_t)(t->rows * t->cols) + 1, sizeof(double));
  p.key_row = malloc(sizeof(long) * (size_t)p.KB);
  p.key_col = malloc(sizeof(long) * (size_t)p.KB);
  p.W = malloc(sizeof(double) * (size_t)(p.KB * t->cols));
  p.K = malloc(sizeof(double) * (size_t)(p.KB * t->rows));
  p.U = malloc(sizeof(double) * (size_t)(PREMUL_PENDING * p.pre));
  p.V = malloc(sizeof(double) * (size_t)(PREMUL_PENDING * p.last));
  p.vec = malloc(sizeof(double) * (size_t)veclen);
  int rc = -1;
  if (!t->data || !p.key_row || !p.key_col || !p.W || !p.K || !p.U || !p.V || !p.vec) {
    snprintf(err, errlen, "out of memory pre-multiplying %s (%ld x %ld reduced entries)", t->name, t->rows, t->cols);
    goto done;
  }
  err[0] = 0;
  NpgSink sink = {&p, on_entry};
  if (full_build(f, t->builder, &sink) != 0) {
    if (!err[0]) snprintf(err, errlen, "%s", npg_full_error(f));
    goto done;
  }
  flush_block(&p);
  if (flops) *flops += p.flops;
  rc = 0;
done:
  free(p.key_row);
  free(p.key_col);
  free(p.W);
  free(p.K);
  free(p.U);
  free(p.V);
  free(p.vec);
  if (rc != 0) {
    free(t->data);
    t->data = NULL;
  }
  return rc;
}
