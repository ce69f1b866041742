/* estimate_train.c — the tables of the online estimate (estimate.h, DESIGN
 * §16, issue 41), built in training while the bases exist:
 *
 *   - per eligible term, the residual's columns C_t (n x D: the numerator's
 *     full-space monomials, then −M B_y ⊗ each operator tensor's monomials),
 *     streamed from the same tensor builders pre-multiplication reads,
 *     projected twice by I − BBᵀ and reduced to R_t of C' = QR (dgeqrf);
 *   - per inverse term, c = min over up to ESTIMATE_SIGMA_SAMPLES training
 *     samples of σ_min(M)/σ_min(BᵀMB), the full operator assembled dense
 *     from its builders (dsyevr/dgesvd) up to ESTIMATE_DENSE_MAX rows, sparse
 *     above (Lanczos on K⁻¹ by CHOLMOD, on (KᵀK)⁻¹ by UMFPACK);
 *   - per input, each reduced coordinate's min and max over the training
 *     samples (the trust signal).
 * Every route of training builds them: in memory, out of core (the bases
 * mapped from their files are read as in memory; the terms of a class formed
 * block by block, whose basis is never whole, get theirs in that sweep:
 * estimate_stream.c, through estimate_term_columns), over MPI
 * ranks (the residual tables need only the bases and the params, which
 * every rank holds: each term's is built by one rank and sent to the
 * others, term_tables; the σ_min ratios and the ranges need training
 * samples: each rank measures those it holds and the figures are combined
 * exactly, see sigma_ratios and input_ranges), with externs (a sample set again gives the extern values
 * training was given, from the data or the trainer's cache: no callback
 * runs; the learned map itself has no estimate), and for the model npgc
 * tune writes (train_set_stream). */
#include <cblas.h>
#include <lapacke.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <suitesparse/cholmod.h>
#include <suitesparse/umfpack.h>

#include "dist.h"
#include "estimate_steps.h"
#include "scratch.h"

/* The sink filling one tensor's block of the columns: entries arrive as
 * (row, col, input offsets, coefficient); rows outside [rows->lo, rows->hi) are skipped. */
typedef struct ColSink {
  const Model *m;
  const RTensor *t;
  const ColRows *rows;
  double *C;                /* (hi − lo) x D row-major */
  long D, off;              /* the block starts at column off */
  int cy;                   /* an operator's: the stage's class; -1 for a numerator */
  double *v, *pack;         /* the entry's monomials (cols), a packed power's scratch */
} ColSink;

const double *estimate_basis_row(const Model *m, const ColRows *rows, int c, long r) {
  const RClass *rc = &m->classes[c];
  const RowMap *map = rows->map ? rows->map[c] : NULL;
  const double *B = rows->B && rows->B[c] ? rows->B[c] : rc->B;
  if (r < 0 || r >= rc->n || !B || !row_map_has(map, r)) return NULL;
  return B + row_map_at(map, r) * rc->m;
}

static int col_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  ColSink *s = user;
  const RTensor *t = s->t;
  const Model *m = s->m;
  if (row < s->rows->lo || row >= s->rows->hi) return row >= 0 && row < s->rows->n ? 0 : -1;
  s->v[0] = coef;
  long len = 1;
  for (int pos = 0, j = 0; j < t->nin; j++) {
    int c = m->qclass[t->in_q[j]];
    const double *rows[RT_MAX_IN];
    for (int l = 0; l < t->in_mult[j]; l++, pos++)
      if (pos >= nin || !(rows[l] = estimate_basis_row(m, s->rows, c, in[pos]))) return -1;
    sym_outer(m->classes[c].m, t->in_mult[j], rows, s->pack);
    long lj = t->in_len[j];
    for (long a = len - 1; a >= 0; a--) {
      double va = s->v[a];
      for (long b = lj - 1; b >= 0; b--) s->v[a * lj + b] = va * s->pack[b];
    }
    len *= lj;
  }
  double *Cr = s->C + (long)(row - s->rows->lo) * s->D + s->off;
  if (s->cy < 0) {
    for (long c = 0; c < t->cols; c++) Cr[c] += s->v[c];
    return 0;
  }
  const double *b = estimate_basis_row(m, s->rows, s->cy, t->kind == RT_DIAG ? (long)row : (long)col);
  if (!b) return -1;
  for (long a = 0, my = m->classes[s->cy].m; a < my; a++)
    for (long c = 0; c < t->cols; c++) Cr[a * t->cols + c] -= b[a] * s->v[c];
  return 0;
}

static int fill_block(Full *f, const RTensor *t, ColSink *s, Err *err) {
  s->t = t;
  NpgSink sink = {s, col_entry, 0, 1, s->rows->lo, s->rows->hi};
  if (full_build(f, t->builder, &sink) != 0)
    return err_set(err, "estimate tables: tensor %s: %s", t->name, full_error(f)[0] ? full_error(f) :
                     "an entry outside its rows, or reading a basis row not held (a bug in npg)");
  return 0;
}

int estimate_term_columns(const EstWork *w, int i, int t, const ColRows *rows, double *C) {
  Model *m = w->m;
  RStage *rs = &m->stages[i];
  RTerm *rt = &rs->terms[t];
  long D = estimate_term_dim(m, i, t), maxcols = 1, maxpack = 1;
  RTERM_FOR_TENSORS(rt, x) {
    maxcols = x->cols > maxcols ? x->cols : maxcols;
    for (int j = 0; j < x->nin; j++) maxpack = x->in_len[j] > maxpack ? x->in_len[j] : maxpack;
  }
  Scratch sc = SCRATCH_OF(w->err);
  ColSink s = {m, NULL, rows, C, D, 0, -1, scratch_array(&sc, (size_t)maxcols, sizeof(double)),
               scratch_array(&sc, (size_t)maxpack, sizeof(double))};
  int out = s.v && s.pack ? 0 : -1;
  if (out == 0 && rt->named_q >= 0) {
    int cw = m->qclass[rt->named_q];
    for (long row = rows->lo; out == 0 && row < rows->hi; row++) {
      const double *b = estimate_basis_row(m, rows, cw, row);
      if (b) memcpy(C + (row - rows->lo) * D, b, sizeof(double) * (size_t)m->classes[cw].m);
      else out = err_set(w->err, "estimate tables: stage %s: row %ld of its numerator's basis not held (a bug in npg)",
                         rs->st->sym->name, row);
    }
    s.off = m->classes[cw].m;
  }
  for (int g = 0; out == 0 && g < rt->nnum; s.off += rt->num[g++].cols) out = fill_block(w->f, &rt->num[g], &s, w->err);
  s.cy = m->qclass[rs->q];
  for (int k = 0; out == 0 && k < rt->nops; k++)
    for (int g = 0; out == 0 && g < rt->ops[k].ntensors; s.off += m->classes[s.cy].m * rt->ops[k].t[g++].cols)
      out = fill_block(w->f, &rt->ops[k].t[g], &s, w->err);
  scratch_release(&sc);
  return out;
}

/* C (n x D) <- (I − BBᵀ) C, twice (one projection leaves ε‖C‖ of B's span); B n x m orthonormal. */
static int project_out(const double *B, long n, long m, double *C, long D) {
  Scratch sc = SCRATCH_OF(NULL);
  double *T = scratch_array_unzeroed(&sc, (size_t)(m * D) + 1, sizeof(double));
  if (!T) return -1;
  for (int pass = 0; pass < 2 && m > 0; pass++) {
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)m, (int)D, (int)n, 1.0, B, (int)m, C, (int)D, 0.0, T,
                (int)D);
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)D, (int)m, -1.0, B, (int)m, T, (int)D, 1.0, C,
                (int)D);
  }
  scratch_release(&sc);
  return 0;
}

/* R (D x D, upper, row-major, zero below) of the QR of the n x D row-major C (destroyed): ‖C z‖ =
 * ‖R z‖ without the Gram matrix's squaring, so a residual is resolved down to ε, not √ε, of its
 * columns (on pyMOR's thermal block the Gram form floored the estimate at 1e-4 of the solution
 * while the true error was 1e-13). 0, -1 when LAPACK fails, -2 when memory runs out. */
static int qr_factor(double *C, long n, long D, double *R) {
  Scratch sc = SCRATCH_OF(NULL);
  double *tau = scratch_array_unzeroed(&sc, (size_t)D + 1, sizeof(double));
  lapack_int info = tau ? LAPACKE_dgeqrf(LAPACK_ROW_MAJOR, (int)n, (int)D, C, (int)D, tau) : -1;
  scratch_release(&sc);
  if (info != 0) return tau ? -1 : -2;
  for (long a = 0; a < D; a++)
    for (long b = 0; b < D; b++) R[a * D + b] = a < n && b >= a ? C[a * D + b] : 0;
  return 0;
}

/* The column blocks [b[2k], b[2k+1]) whose residuals are factored apart: one, [0, D), for a term
 * that is not chained; a chained term's (estimate_term_chains) ChainLayout blocks — the numerator's,
 * each applied operator's, each inverse's joined with its operand's producer —, so that each part's
 * norm ‖R_b z_b‖ is found alone: online they are chained with ‖M‖ or σ_min(M) between them, not
 * summed in one residual. Returns the count of entries of b (twice the blocks'). */
int estimate_table_blocks(const Model *m, int i, int t, long b[2 * ESTIMATE_OPS_MAX + 2]) {
  const RTerm *rt = &m->stages[i].terms[t];
  int nb = 0;
  if (!estimate_term_chains(rt)) {
    b[nb++] = 0, b[nb++] = estimate_term_dim(m, i, t);
    return nb;
  }
  ChainLayout L;
  estimate_chain_layout(m, i, t, &L);
  if (!L.joins[0]) b[nb++] = 0, b[nb++] = L.nnum;
  for (int k = 0; k < rt->nops; k++)
    if (rt->ops[k].op->p < 0 || !L.joins[k + 1]) b[nb++] = L.start[k], b[nb++] = L.off[k] + L.len[k];
  return nb;
}

/* A chained term's table: R (D x D, row-major, zero off its diagonal blocks) of the QRs of C's
 * column blocks apart (estimate_table_blocks). C (n x D row-major) is left as is. 0, -1 when LAPACK fails,
 * -2 when memory runs out. */
static int qr_blocks(const Model *m, int i, int t, const double *C, long n, double *R) {
  long D = estimate_term_dim(m, i, t), b[2 * ESTIMATE_OPS_MAX + 2];
  int nb = estimate_table_blocks(m, i, t, b);
  Scratch sc = SCRATCH_OF(NULL);
  double *T = scratch_array(&sc, (size_t)(n * D) + 1, sizeof(double)), *Rb = scratch_array(&sc, (size_t)(D * D) + 1,
                                                                                           sizeof(double));
  int out = T && Rb ? 0 : -2;
  for (int k = 0; out == 0 && k < nb; k += 2) {
    long off = b[k], len = b[k + 1] - b[k];
    if (len == 0) continue;
    for (long row = 0; row < n; row++) memcpy(T + row * len, C + row * D + off, sizeof(double) * (size_t)len);
    out = qr_factor(T, n, len, Rb);
    for (long a = 0; out == 0 && a < len; a++) memcpy(R + (off + a) * D + off, Rb + a * len, sizeof(double) * (size_t)len);
  }
  scratch_release(&sc);
  return out;
}

/* ---------------------------------------------------------------- a table by row chunks */

/* A block's factor while its rows arrive: R (W x W, column-major, upper) of [B C_b] over the rows so far. */
typedef struct ChunkQR {
  long off, len, W;         /* the block's columns [off, off + len) of C; W = m + len */
  double *R;
} ChunkQR;

/* Rows [lo, hi) of [B C_b] (C's chunk: (hi − lo) x D row-major) stacked under the block's R and
 * factored again (LAPACK dtpqrt: the triangle on the rows, 2 (hi − lo) W² flops, no more). */
static int chunk_rows(const Model *m, int cy, ChunkQR *q, const double *C, long D, const ColRows *rows, Scratch *sc) {
  long nr = rows->hi - rows->lo, W = q->W, my = m->classes[cy].m, nb = W < 32 ? W : 32;
  double *Z = scratch_array_unzeroed(sc, (size_t)(nr * W) + 1, sizeof(double));
  double *T = scratch_array_unzeroed(sc, (size_t)(nb * W) + 1, sizeof(double));
  if (!Z || !T) return -2;
  for (long r = 0; r < nr; r++) {
    const double *b = estimate_basis_row(m, rows, cy, rows->lo + r);
    for (long c = 0; c < my; c++) Z[c * nr + r] = b[c];
    for (long c = 0; c < q->len; c++) Z[(my + c) * nr + r] = C[r * D + q->off + c];
  }
  return LAPACKE_dtpqrt(LAPACK_COL_MAJOR, (int)nr, (int)W, 0, (int)nb, q->R, (int)W, Z, (int)nr, T, (int)nb) ? -1 : 0;
}

/* Term t of stage i's table when its columns do not fit whole (estimate_term_whole): R of each
 * block's (I − BBᵀ)C_b as the R22 of [B C_b] = [Q1 Q2][R11 R12; 0 R22] — Q1 spans B, so R22 is R of
 * C_b − Q1Q1ᵀC_b —, made row chunk by row chunk (about ESTIMATE_CHUNK_BYTES of C), each chunk
 * stacked under the R so far; C's column norms summed over the chunks. The columns are never
 * whole: the memory is the blocks' R and one chunk. G: (D + 1) x D as term_table's. 0, -1 when
 * LAPACK fails, -2 when memory runs out, -3 with w->err when a column is not made. */
static int chunked_table(const EstWork *w, int i, int t, double *G) {
  const Model *m = w->m;
  int cy = m->qclass[m->stages[i].q], nb;
  long n = m->classes[cy].n, my = m->classes[cy].m, D = estimate_term_dim(m, i, t), b[2 * ESTIMATE_OPS_MAX + 2];
  long rows = (long)(ESTIMATE_CHUNK_BYTES / sizeof(double) / (size_t)(my + D));
  rows = estimate_test_chunk_rows() ? estimate_test_chunk_rows() : rows < 64 ? 64 : rows;
  nb = estimate_table_blocks(m, i, t, b);
  Scratch sc = SCRATCH_OF(NULL);
  ChunkQR *q = scratch_array(&sc, (size_t)nb / 2 + 1, sizeof(ChunkQR));
  double *C = scratch_array_unzeroed(&sc, (size_t)(rows * D) + 1, sizeof(double));
  int out = q && C ? 0 : -2;
  for (int k = 0; out == 0 && k < nb / 2; k++) {
    q[k] = (ChunkQR){b[2 * k], b[2 * k + 1] - b[2 * k], my + b[2 * k + 1] - b[2 * k], NULL};
    if (!(q[k].R = scratch_array(&sc, (size_t)(q[k].W * q[k].W) + 1, sizeof(double)))) out = -2;
  }
  for (long lo = 0; out == 0 && lo < n; lo += rows) {
    ColRows cr = {lo, lo + rows < n ? lo + rows : n, n, NULL, NULL};
    memset(C, 0, sizeof(double) * (size_t)((cr.hi - lo) * D));
    if (estimate_term_columns(w, i, t, &cr, C)) out = -3;
    for (long r = 0; out == 0 && r < cr.hi - lo; r++)
      for (long c = 0; c < D; c++) G[D * D + c] += C[r * D + c] * C[r * D + c];
    for (int k = 0; out == 0 && k < nb / 2; k++) {
      Scratch cs = SCRATCH_OF(NULL);
      if (q[k].len > 0) out = chunk_rows(m, cy, &q[k], C, D, &cr, &cs);
      scratch_release(&cs);
    }
  }
  for (long c = 0; out == 0 && c < D; c++) G[D * D + c] = sqrt(G[D * D + c]);
  for (int k = 0; out == 0 && k < nb / 2; k++) /* R22: rows and columns my.. of the column-major R */
    for (long a = 0; a < q[k].len; a++)
      for (long c = a; c < q[k].len; c++) G[(q[k].off + a) * D + q[k].off + c] = q[k].R[(my + c) * q[k].W + my + a];
  scratch_release(&sc);
  return out;
}

/* Term t of stage i: its columns, their norms and R of the projected columns into rt->est_G. In a
 * class with a product K0 the columns are first replaced by L⁻¹PC and B by L⁻¹P K0B
 * (estimate_product_columns): R then gives the residual's dual norm ‖r‖_{K0⁻¹}. */
static int term_table(Model *m, Full *f, const SampleSource *src, int i, int t, Err *err) {
  RStage *rs = &m->stages[i];
  RTerm *rt = &rs->terms[t];
  const RClass *rc = &m->classes[m->qclass[rs->q]];
  long n = rc->n, D = estimate_term_dim(m, i, t);
  RTERM_FOR_TENSORS(rt, x) {
    for (int j = 0; j < x->nin; j++)
      if (!m->classes[m->qclass[x->in_q[j]]].B) return 0; /* an input's basis is not whole here */
  }
  if (rt->named_q >= 0 && (!m->classes[m->qclass[rt->named_q]].B || m->classes[m->qclass[rt->named_q]].n != n)) return 0;
  EstMake make = estimate_term_make(m, i, t);
  if (make == EST_MAKE_NONE) return 0; /* estimate.c's message says so */
  Scratch sc = SCRATCH_OF(err);
  double *C = make == EST_MAKE_WHOLE ? scratch_array(&sc, (size_t)(n * D) + 1, sizeof(double)) : NULL, *V = NULL;
  double *G = scratch_array(&sc, (size_t)((D + 1) * D) + 1, sizeof(double));
  EstWork w = {m, f, NULL, err, src};
  long nnum = rt->named_q >= 0 ? m->classes[m->qclass[rt->named_q]].m : 0;
  for (int g = 0; g < rt->nnum; g++) nnum += rt->num[g].cols;
  int bad = !G || (make == EST_MAKE_WHOLE && (!C || estimate_term_columns(&w, i, t, &(ColRows){0, n, n, NULL, NULL}, C)));
  if (!bad && rc->product)
    bad = estimate_product_columns(&w, rt, rc, &(ResidualCols){C, D, nnum}, &V) || !scratch_adopt(&sc, V);
  if (!bad && rt->named_q >= 0) bad = estimate_product_carry(&w, rt, rc, &m->classes[m->qclass[rt->named_q]]);
  if (!bad && make == EST_MAKE_WHOLE) {
    estimate_column_norms(C, n, D, G + D * D);
    if (project_out(V ? V : rc->B, n, rc->m, C, D))
      bad = err_set(err, "estimate tables: out of memory projecting stage %s", rs->st->sym->name);
  }
  int qr = bad ? 0 : make == EST_MAKE_CHUNKS ? chunked_table(&w, i, t, G)
                   : estimate_term_chains(rt) ? qr_blocks(m, i, t, C, n, G) : qr_factor(C, n, D, G);
  if (qr && qr != -3)
    bad = err_set(err, "estimate tables: %s the QR of stage %s's residual columns", qr == -2 ? "out of memory for" : "LAPACK failed in",
                  rs->st->sym->name);
  bad = bad || qr;
  if (!bad && !(rt->est_G = malloc(sizeof(double) * (size_t)((D + 1) * D) + 1)))
    bad = err_set(err, "estimate tables: out of memory for stage %s", rs->st->sym->name);
  if (!bad) {
    memcpy(rt->est_G, G, sizeof(double) * (size_t)((D + 1) * D));
    rt->est_D = D;
    if (!rc->product) rt->est_sigma = NAN; /* a product's: estimate_product_columns's */
  }
  scratch_release(&sc);
  return bad ? -1 : 0;
}

void estimate_column_norms(const double *C, long n, long D, double *norms) {
  for (long c = 0; c < D; c++) norms[c] = cblas_dnrm2((int)n, C + c, (int)D);
}

/* The dense full operator's sink: value coef · Π input entries at (row, col), or (row, row) for a diagonal one. */
typedef struct DenseSink {
  const double *in[64];
  double *M;
  long n;
  bool diag;
} DenseSink;

static int dense_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  DenseSink *s = user;
  long c = s->diag ? (long)row : (long)col;
  if (row < 0 || row >= s->n || c < 0 || c >= s->n || nin > 64) return -1;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  s->M[row * s->n + c] += v;
  return 0;
}

/* The full operator of term rt (one op) at the evaluator's current values, dense n x n into M. */
static int full_operator(Full *f, const RTerm *rt, double *M, long n, Err *err) {
  memset(M, 0, sizeof(double) * (size_t)(n * n));
  for (int g = 0; g < rt->ops[0].ntensors; g++) {
    const RTensor *t = &rt->ops[0].t[g];
    DenseSink s = {{0}, M, n, t->kind == RT_DIAG};
    for (int i = 0; i < t->group->ninputs && i < 64; i++) s.in[i] = full_get(f, t->group->inputs[i]->name, NULL);
    NpgSink sink = {&s, dense_entry, 0, 1, 0, 0};
    if (full_build(f, t->builder, &sink) != 0) return err_set(err, "estimate tables: %s", full_error(f));
  }
  return 0;
}


/* Smallest singular value of the n x n row-major A (destroyed); NaN if LAPACK fails. A symmetric
 * positive definite A (the usual inverse: Cholesky's) by its smallest eigenvalue alone (dsyevr,
 * about a quarter of the SVD's time), anything else by dgesvd. `sv` holds 2n doubles. */
double estimate_smallest_sv(double *A, long n, double *sv) {
  double big = 0, asym = 0;
  for (long i = 0; i < n; i++)
    for (long j = 0; j < n; j++) big = fmax(big, fabs(A[i * n + j])), asym = fmax(asym, fabs(A[i * n + j] - A[j * n + i]));
  if (asym <= 1e-14 * big) {
    lapack_int found = 0, isuppz[2];
    Scratch sc = SCRATCH_OF(NULL);
    double *copy = scratch_array_unzeroed(&sc, (size_t)(n * n) + 1, sizeof(double));
    lapack_int info = -1;
    if (copy) {
      memcpy(copy, A, sizeof(double) * (size_t)(n * n));
      info = LAPACKE_dsyevr(LAPACK_ROW_MAJOR, 'N', 'I', 'U', (int)n, copy, (int)n, 0, 0, 1, 1, 0, &found, sv, NULL, 1,
                            isuppz);
    }
    scratch_release(&sc);
    if (info == 0 && found == 1 && sv[0] > 0) return sv[0];
  }
  lapack_int info = LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'N', 'N', (int)n, (int)n, A, (int)n, sv, NULL, 1, NULL, 1,
                                   sv + n);
  return info == 0 ? sv[n - 1] : NAN;
}

/* ‖A‖₂ of the n x n row-major A (destroyed): a symmetric A's largest eigenvalue magnitude (dsyevr, values
 * alone), anything else dgesvd's largest singular value; NaN if LAPACK fails. `sv` holds 2n doubles. */
static double largest_sv(double *A, long n, double *sv) {
  double big = 0, asym = 0;
  for (long i = 0; i < n; i++)
    for (long j = 0; j < n; j++) big = fmax(big, fabs(A[i * n + j])), asym = fmax(asym, fabs(A[i * n + j] - A[j * n + i]));
  lapack_int found = 0, isuppz[2];
  if (asym <= 1e-14 * big && LAPACKE_dsyevr(LAPACK_ROW_MAJOR, 'N', 'A', 'U', (int)n, A, (int)n, 0, 0, 0, 0, 0, &found,
                                            sv, NULL, 1, isuppz) == 0 && found == n)
    return n > 0 ? fmax(fabs(sv[0]), fabs(sv[n - 1])) : 0;
  lapack_int info = LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'N', 'N', (int)n, (int)n, A, (int)n, sv, NULL, 1, NULL, 1,
                                   sv + n);
  return info == 0 ? (n > 0 ? sv[0] : 0) : NAN;
}

/* The full operator's entries as triplets (row, col, value), duplicates summed later. */
typedef struct TripSink {
  const double *in[64];
  long n, count, cap;
  bool diag;
  SuiteSparse_long *ri, *ci;
  double *x;
} TripSink;

static int trip_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  TripSink *s = user;
  long c = s->diag ? (long)row : (long)col;
  if (row < 0 || row >= s->n || c < 0 || c >= s->n || nin > 64) return -1;
  if (s->count == s->cap) {
    long cap = s->cap ? 2 * s->cap : 4096;
    SuiteSparse_long *ri = realloc(s->ri, sizeof(*ri) * (size_t)cap), *ci = ri ? realloc(s->ci, sizeof(*ci) * (size_t)cap) : NULL;
    double *x = ci ? realloc(s->x, sizeof(double) * (size_t)cap) : NULL;
    if (ri) s->ri = ri;
    if (ci) s->ci = ci;
    if (!x) return -1;
    s->x = x, s->cap = cap;
  }
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  s->ri[s->count] = row, s->ci[s->count] = c, s->x[s->count++] = v;
  return 0;
}

/* The full operator of term rt (one op) at the evaluator's current values as a CHOLMOD sparse
 * matrix (unsymmetric storage, sorted, duplicates summed); NULL with err set on failure. */
static cholmod_sparse *sparse_operator(Full *f, const RTerm *rt, long n, cholmod_common *cc, Err *err) {
  TripSink s = {{0}, n, 0, 0, false, NULL, NULL, NULL};
  cholmod_sparse *A = NULL;
  bool built = true;
  for (int g = 0; g < rt->ops[0].ntensors && built; g++) {
    const RTensor *t = &rt->ops[0].t[g];
    s.diag = t->kind == RT_DIAG;
    for (int i = 0; i < t->group->ninputs && i < 64; i++) s.in[i] = full_get(f, t->group->inputs[i]->name, NULL);
    NpgSink sink = {&s, trip_entry, 0, 1, 0, 0};
    if (full_build(f, t->builder, &sink) != 0)
      built = false, err_set(err, "estimate tables: %s", full_error(f)[0] ? full_error(f) : "out of memory for the operator");
  }
  cholmod_triplet T = {0};
  T.nrow = T.ncol = (size_t)n, T.nzmax = T.nnz = (size_t)s.count;
  T.i = s.ri, T.j = s.ci, T.x = s.x, T.stype = 0;
  T.itype = CHOLMOD_LONG, T.xtype = CHOLMOD_REAL, T.dtype = CHOLMOD_DOUBLE;
  if (built && !(A = cholmod_l_triplet_to_sparse(&T, (size_t)s.count, cc)))
    err_set(err, "estimate tables: CHOLMOD could not assemble the %ld x %ld operator (status %d)", n, n, cc->status);
  free(s.ri), free(s.ci), free(s.x); /* grown by trip_entry (realloc), freed at the one exit */
  return A;
}

int estimate_dense_operator(Full *f, const RTerm *rt, double *M, long n, Err *err) { return full_operator(f, rt, M, n, err); }
cholmod_sparse *estimate_sparse_operator(Full *f, const RTerm *rt, long n, cholmod_common *cc, Err *err) {
  return sparse_operator(f, rt, n, cc, err);
}

/* y = AᵀA x for the sparse n x n A (CHOLMOD's compressed columns); tmp: n doubles. */
static void forward_apply(const cholmod_sparse *A, const double *x, double *y, double *tmp, long n) {
  const SuiteSparse_long *Ap = A->p, *Ai = A->i;
  const double *Ax = A->x;
  memset(tmp, 0, sizeof(double) * (size_t)n);
  for (long j = 0; j < n; j++)
    for (SuiteSparse_long p = Ap[j]; p < Ap[j + 1]; p++) tmp[Ai[p]] += Ax[p] * x[j];
  for (long j = 0; j < n; j++) {
    double v = 0;
    for (SuiteSparse_long p = Ap[j]; p < Ap[j + 1]; p++) v += Ax[p] * tmp[Ai[p]];
    y[j] = v;
  }
}

/* The operator Lanczos runs on: K⁻¹ (CHOLMOD's Cholesky of an SPD K) or K⁻¹K⁻ᵀ = (KᵀK)⁻¹ (UMFPACK's LU). */
typedef struct InvOp {
  cholmod_common *cc;
  cholmod_factor *L;        /* SPD: the Cholesky factor */
  const cholmod_sparse *A;  /* otherwise: the LU's matrix (without an LU, numeric NULL: AᵀA itself, forward_apply) */
  void *numeric;
  double *tmp;
} InvOp;

static int inv_apply(InvOp *o, double *x, double *y, long n) {
  if (!o->L && !o->numeric) return forward_apply(o->A, x, y, o->tmp, n), 0;
  if (o->L) {
    cholmod_dense d = {0};
    d.nrow = (size_t)n, d.ncol = 1, d.nzmax = (size_t)n, d.d = (size_t)n, d.x = x;
    d.xtype = CHOLMOD_REAL, d.dtype = CHOLMOD_DOUBLE;
    cholmod_dense *r = cholmod_l_solve(CHOLMOD_A, o->L, &d, o->cc);
    if (!r) return -1;
    memcpy(y, r->x, sizeof(double) * (size_t)n);
    cholmod_l_free_dense(&r, o->cc);
    return 0;
  }
  const SuiteSparse_long *Ap = o->A->p, *Ai = o->A->i;
  const double *Ax = o->A->x;
  if (umfpack_dl_solve(UMFPACK_At, Ap, Ai, Ax, o->tmp, x, o->numeric, NULL, NULL) != UMFPACK_OK) return -1;
  return umfpack_dl_solve(UMFPACK_A, Ap, Ai, Ax, y, o->tmp, o->numeric, NULL, NULL) == UMFPACK_OK ? 0 : -1;
}

/* The largest eigenvalue of the SPD operator o by Lanczos with full reorthogonalization, from a
 * fixed start, until the Ritz value's residual bound |β s| is below 1e-10 of it (at most
 * SPARSE_LANCZOS_STEPS steps); returns θ + |β s| (an eigenvalue lies within |β s| of θ, so the
 * figure errs on the large side: σ_min = 1/it errs low, the estimate high), NaN on failure. For
 * an elliptic K the top of K⁻¹'s spectrum (1/λ_1 against 1/λ_2) is well separated, so the Ritz
 * value settles in tens of steps; 60 bounds the work of a clustered spectrum, whose figure then
 * still carries its |β s|. */
#define SPARSE_LANCZOS_STEPS 60

double estimate_ritz_top(const double *al, const double *be, int j, double *res) {
  double d[SPARSE_LANCZOS_STEPS + 1], e[SPARSE_LANCZOS_STEPS + 1], Z[SPARSE_LANCZOS_STEPS * SPARSE_LANCZOS_STEPS + 1];
  if (j >= SPARSE_LANCZOS_STEPS) return NAN;
  memcpy(d, al, sizeof(double) * (size_t)(j + 1));
  memcpy(e, be, sizeof(double) * (size_t)j);
  if (LAPACKE_dstev(LAPACK_COL_MAJOR, 'V', j + 1, d, e, Z, j + 1) != 0) return NAN;
  *res = fabs(be[j] * Z[(long)j * (j + 1) + j]); /* last component of the top Ritz vector */
  return d[j];
}

static double lanczos_max(InvOp *o, long n) {
  int K = n < SPARSE_LANCZOS_STEPS ? (int)n : SPARSE_LANCZOS_STEPS;
  Scratch sc = SCRATCH_OF(NULL);
  double *V = scratch_array_unzeroed(&sc, (size_t)(n * (K + 1)) + 1, sizeof(double)),
         *w = scratch_array_unzeroed(&sc, (size_t)n + 1, sizeof(double));
  double al[SPARSE_LANCZOS_STEPS + 1], be[SPARSE_LANCZOS_STEPS + 1], out = NAN;
  if (V && w) {
    for (long i = 0; i < n; i++) V[i] = 1.0 + 0.5 * sin(0.7 * (double)i); /* fixed, not orthogonal to smooth modes */
    cblas_dscal((int)n, 1.0 / cblas_dnrm2((int)n, V, 1), V, 1);
  }
  for (int j = 0; V && w && j < K; j++) {
    double *v = V + (long)j * n;
    if (inv_apply(o, v, w, n)) break; /* the last figure stands */
    al[j] = cblas_ddot((int)n, v, 1, w, 1);
    for (int pass = 0; pass < 2; pass++) /* w -= V (Vᵀ w), twice */
      for (int k = 0; k <= j; k++) cblas_daxpy((int)n, -cblas_ddot((int)n, V + (long)k * n, 1, w, 1), V + (long)k * n, 1, w, 1);
    be[j] = cblas_dnrm2((int)n, w, 1);
    double res, theta = estimate_ritz_top(al, be, j, &res);
    if (isnan(theta)) break;
    out = theta + res;
    if (res <= 1e-10 * theta || be[j] <= 1e-14 * theta || j + 1 == K) break;
    double *vn = V + (long)(j + 1) * n;
    for (long i = 0; i < n; i++) vn[i] = w[i] / be[j];
  }
  scratch_release(&sc);
  return out;
}

/* σ_min of the sparse n x n operator A: an SPD A (symmetric to 1e-14 and CHOLMOD's Cholesky
 * succeeds) by 1/λ_max(A⁻¹), anything else by 1/√λ_max((AᵀA)⁻¹) through one UMFPACK LU; each
 * by Lanczos (lanczos_max). NaN when the factorization fails (a singular operator: no bound). */
double estimate_sparse_smallest_sv(cholmod_sparse *A, long n, cholmod_common *cc) {
  double one[2] = {1, 0}, minus[2] = {-1, 0}, out = NAN;
  cholmod_sparse *At = cholmod_l_transpose(A, 2, cc), *Dif = At ? cholmod_l_add(A, At, one, minus, 1, 0, cc) : NULL, *S = NULL;
  Scratch sc = SCRATCH_OF(NULL);
  InvOp o = {cc, NULL, A, NULL, scratch_array(&sc, (size_t)n + 1, sizeof(double))};
  bool sym = Dif && cholmod_l_norm_sparse(Dif, 0, cc) <= 1e-14 * cholmod_l_norm_sparse(A, 0, cc);
  if (sym && (S = cholmod_l_copy(A, 1, 1, cc))) {
    int super = cc->supernodal;
    cc->supernodal = CHOLMOD_SUPERNODAL; /* LLᵀ: an indefinite matrix fails instead of factoring as LDLᵀ */
    cholmod_factor *L = cholmod_l_analyze(S, cc);
    if (L && cholmod_l_factorize(S, L, cc) && cc->status == CHOLMOD_OK && L->minor >= (size_t)n) {
      o.L = L;
      double lmax = lanczos_max(&o, n);
      out = lmax > 0 ? 1.0 / lmax : NAN;
    }
    cc->supernodal = super;
    if (L) cholmod_l_free_factor(&L, cc);
  }
  if (!o.L && o.tmp) { /* nonsymmetric or indefinite: (AᵀA)⁻¹ through A's LU */
    void *sym_ = NULL;
    const SuiteSparse_long *Ap = A->p, *Ai = A->i;
    if (umfpack_dl_symbolic(n, n, Ap, Ai, A->x, &sym_, NULL, NULL) == UMFPACK_OK &&
        umfpack_dl_numeric(Ap, Ai, A->x, sym_, &o.numeric, NULL, NULL) == UMFPACK_OK) {
      double lmax = lanczos_max(&o, n);
      out = lmax > 0 ? 1.0 / sqrt(lmax) : NAN;
    }
    if (sym_) umfpack_dl_free_symbolic(&sym_);
    if (o.numeric) umfpack_dl_free_numeric(&o.numeric);
  }
  scratch_release(&sc);
  cholmod_l_free_sparse(&At, cc), cholmod_l_free_sparse(&Dif, cc), cholmod_l_free_sparse(&S, cc);
  return out;
}

/* ‖A‖₂ of the sparse n x n A: √λ_max(AᵀA) by Lanczos on AᵀA (lanczos_max: it errs high, as a norm that
 * multiplies an error should). NaN on failure. */
static double sparse_largest_sv(const cholmod_sparse *A, long n, cholmod_common *cc) {
  Scratch sc = SCRATCH_OF(NULL);
  InvOp o = {cc, NULL, A, NULL, scratch_array(&sc, (size_t)n + 1, sizeof(double))};
  double lmax = o.tmp ? lanczos_max(&o, n) : NAN;
  scratch_release(&sc);
  return lmax >= 0 ? sqrt(lmax) : NAN;
}

/* Is the symmetric A positive semidefinite by diagonal dominance (a nonnegative diagonal at
 * least the sum of its row's other magnitudes, to 1e-12 of its largest entry)? */
static bool dominant_psd(const cholmod_sparse *A, cholmod_common *cc) {
  const SuiteSparse_long *Ap = A->p, *Ai = A->i;
  const double *Ax = A->x;
  double big = cholmod_l_norm_sparse((cholmod_sparse *)A, 0, cc), tol = 1e-12 * big;
  for (long j = 0; j < (long)A->ncol; j++) { /* symmetric: column j is row j */
    double dg = 0, off = 0;
    for (SuiteSparse_long p = Ap[j]; p < Ap[j + 1]; p++) {
      if (Ai[p] == j) dg += Ax[p];
      else off += fabs(Ax[p]);
    }
    if (dg < -tol || dg + tol < off) return false;
  }
  return true;
}

bool estimate_sparse_close(cholmod_sparse *A, cholmod_sparse *B, cholmod_common *cc) {
  double one[2] = {1, 0}, minus[2] = {-1, 0};
  cholmod_sparse *D = cholmod_l_add(A, B, one, minus, 1, 0, cc);
  bool ok = D && cholmod_l_norm_sparse(D, 1, cc) <= 1e-12 * cholmod_l_norm_sparse(A, 1, cc);
  cholmod_l_free_sparse(&D, cc);
  return ok;
}

bool estimate_symmetric_psd(cholmod_sparse *A, cholmod_common *cc) {
  cholmod_sparse *T = cholmod_l_transpose(A, 2, cc);
  bool ok = T && estimate_sparse_close(A, T, cc) && dominant_psd(A, cc);
  cholmod_l_free_sparse(&T, cc);
  return ok;
}

/* The operator of term rt with its input `name` set to x (n entries); NULL on failure. */
static cholmod_sparse *operator_at(const EstWork *w, const RTerm *rt, long n, const char *name, const double *x, long nx) {
  char buf[256];
  long shape[1] = {nx};
  return full_set(w->f, name, 1, shape, x, "the min-θ bound") ? NULL
                                                              : sparse_operator(w->f, rt, n, w->cc, ERR_OF(buf, sizeof buf));
}

int estimate_affine_parts(const EstWork *w, const RTerm *rt, long n, cholmod_sparse **K, size_t *pnx) {
  const Model *m = w->m;
  cholmod_common *cc = w->cc;
  int q = -1;
  if (rt->nops != 1) return -1;
  for (int g = 0; g < rt->ops[0].ntensors; g++) {
    const RTensor *x = &rt->ops[0].t[g];
    if (x->nin > 1 || (x->nin == 1 && q >= 0 && x->in_q[0] != q)) return -1;
    if (x->nin == 1) q = x->in_q[0];
  }
  const Sym *sy = q >= 0 ? m->prog->quantities.v[q] : NULL;
  if (sy && sy->ndims + sy->nstatic != 1) return -1; /* set below as a vector: one axis only */
  size_t nx = 0;
  const double *cur = sy && sy->kind == SYM_INPUT ? full_get(w->f, sy->name, &nx) : NULL;
  if (!cur || nx < 1 || nx > ESTIMATE_THETA_MAX) return -1;
  double x[ESTIMATE_THETA_MAX], xs[ESTIMATE_THETA_MAX], one[2] = {1, 0}, minus[2] = {-1, 0};
  memcpy(xs, cur, sizeof(double) * nx);
  cholmod_sparse *sum = NULL, *Kx = NULL;
  bool ok = true;
  for (size_t j = 0; j <= nx; j++) K[j] = NULL;
  for (long j = -1; ok && j < (long)nx; j++) { /* K[0] = M(0), K[j + 1] = M(e_j) − M(0) */
    for (size_t a = 0; a < nx; a++) x[a] = (long)a == j ? 1 : 0;
    cholmod_sparse *A = operator_at(w, rt, n, sy->name, x, (long)nx);
    if (j >= 0 && A) K[j + 1] = cholmod_l_add(A, K[0], one, minus, 1, 1, cc), cholmod_l_free_sparse(&A, cc);
    else K[0] = A;
    ok = K[j + 1] && cholmod_l_drop(0, K[j + 1], cc) && cholmod_l_sort(K[j + 1], cc);
  }
  for (int pass = 0; ok && pass < 2; pass++) { /* affine: M(x) = M_0 + Σ x_j M_j at the sample and at 2·1 */
    for (size_t a = 0; a < nx; a++) x[a] = pass ? 2 : xs[a];
    sum = cholmod_l_copy_sparse(K[0], cc);
    for (size_t j = 0; sum && j < nx; j++) {
      double c[2] = {x[j], 0};
      cholmod_sparse *t = cholmod_l_add(sum, K[j + 1], one, c, 1, 1, cc);
      cholmod_l_free_sparse(&sum, cc);
      sum = t;
    }
    Kx = sum ? operator_at(w, rt, n, sy->name, x, (long)nx) : NULL;
    ok = Kx && estimate_sparse_close(Kx, sum, cc);
    cholmod_l_free_sparse(&sum, cc), cholmod_l_free_sparse(&Kx, cc);
  }
  if (!ok)
    for (size_t j = 0; j <= nx; j++) cholmod_l_free_sparse(&K[j], cc);
  *pnx = nx;
  return ok ? q : -1;
}

int estimate_affine_input(const EstWork *w, const RTerm *rt, long n) {
  cholmod_sparse *K[ESTIMATE_THETA_MAX + 1];
  size_t nx = 0;
  int q = estimate_affine_parts(w, rt, n, K, &nx);
  for (size_t j = 0; q >= 0 && j <= nx; j++)
    if (!estimate_symmetric_psd(K[j], w->cc)) q = -1;
  for (size_t j = 0; j <= nx && nx > 0; j++) cholmod_l_free_sparse(&K[j], w->cc);
  return q;
}

int estimate_operator_sigma(const EstWork *w, const RTerm *rt, long n, double *sigma) {
  Scratch sc = SCRATCH_OF(w->err);
  int out = -1;
  *sigma = NAN;
  if (n <= ESTIMATE_DENSE_MAX) {
    double *M = scratch_array(&sc, (size_t)(n * n) + 1, sizeof(double)), *sv = scratch_array(&sc, (size_t)(2 * n) + 1, sizeof(double));
    if (M && sv && (out = full_operator(w->f, rt, M, n, w->err)) == 0) *sigma = estimate_smallest_sv(M, n, sv);
  } else {
    cholmod_sparse *A = sparse_operator(w->f, rt, n, w->cc, w->err);
    if (A) *sigma = estimate_sparse_smallest_sv(A, n, w->cc), out = 0;
    cholmod_l_free_sparse(&A, w->cc);
  }
  scratch_release(&sc);
  return out;
}

/* sig[0] = σ_min(M), sig[1] = σ_min(BᵀMB) of inverse term rt of `stage` at the evaluator's current values: M
 * assembled dense and decomposed by LAPACK up to ESTIMATE_DENSE_MAX rows, sparse above (estimate_sparse_smallest_sv).
 * With `norm` (an applied operator's, or a root's of power above 1): ‖M‖₂ and ‖BᵀMB‖₂ instead (largest_sv,
 * sparse_largest_sv). rt's first operator is measured (a term of several operators is measured through a view of
 * each, run_view). */
static int term_sigmas(const EstWork *w, const RTerm *rt, const RClass *rc, const char *stage, bool norm, double sig[2]) {
  cholmod_common *cc = w->cc;
  long n = rc->n, my = rc->m;
  Scratch sc = SCRATCH_OF(NULL);
  bool dense = n <= ESTIMATE_DENSE_MAX;
  double *T = scratch_array(&sc, (size_t)(n * my) + 1, sizeof(double)),
         *R = scratch_array_unzeroed(&sc, (size_t)(my * my) + 1, sizeof(double)),
         *sv = scratch_array_unzeroed(&sc, (size_t)(2 * (n > my ? n : my) + 1), sizeof(double)),
         *M = dense ? scratch_array_unzeroed(&sc, (size_t)(n * n) + 1, sizeof(double)) : NULL;
  cholmod_sparse *A = NULL;
  if (!T || !R || !sv || (dense && !M)) {
    scratch_release(&sc);
    return err_set(w->err, "estimate tables: out of memory for the %ld x %ld operator of stage %s", n, n, stage);
  }
  int rc_ = dense ? full_operator(w->f, rt, M, n, w->err) : (A = sparse_operator(w->f, rt, n, cc, w->err)) ? 0 : -1;
  if (rc_ == 0 && dense)
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)my, (int)n, 1.0, M, (int)n, rc->B, (int)my, 0.0,
                T, (int)my);
  else if (rc_ == 0) {
    const SuiteSparse_long *Ap = A->p, *Ai = A->i;
    const double *Ax = A->x;
    for (long j = 0; j < n; j++) /* T = A B, column j of A times row j of B */
      for (SuiteSparse_long p = Ap[j]; p < Ap[j + 1]; p++) cblas_daxpy((int)my, Ax[p], rc->B + j * my, 1, T + Ai[p] * my, 1);
  }
  if (rc_ == 0) {
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)my, (int)my, (int)n, 1.0, rc->B, (int)my, T, (int)my, 0.0,
                R, (int)my);
    if (norm) {
      sig[0] = dense ? largest_sv(M, n, sv) : sparse_largest_sv(A, n, cc);
      sig[1] = largest_sv(R, my, sv);
    } else {
      sig[0] = dense ? estimate_smallest_sv(M, n, sv) : estimate_sparse_smallest_sv(A, n, cc);
      sig[1] = my > 0 ? estimate_smallest_sv(R, my, sv) : INFINITY;
    }
  }
  scratch_release(&sc);
  if (A) cholmod_l_free_sparse(&A, cc);
  return rc_;
}

/* The measurement of the σ_min ratios: its terms (terms of one operator with a table, of a class within the sparse
 * limit and without a product: a product's is its own table; and each operator of a term of several, chained:
 * estimate_term_chains), the samples picked, and their records. */
typedef struct SigmaRun {
  EstWork w;
  const SampleSource *src;
  int (*terms)[4];          /* (stage, term, operator, ‖M‖ of a root) of each: operator -1 for a term of one (its
                             * est_sigma); the fourth 1 for the ‖M‖ ratio of a root of power above 1 (est_opc) */
  int nt;
  long nk;                  /* picked samples: k_j = j (S − 1) / (nk − 1) */
  int rank, N;              /* sample k is rank k mod N's (over MPI ranks, as the snapshots are taken) */
  double *rec;              /* per term and picked sample: SIGMA_REC doubles */
} SigmaRun;

/* A record: σ_min(M), σ_min(BᵀMB), 1 when the sample's min-θ input x follows, then x. */
#define SIGMA_REC (3 + ESTIMATE_THETA_MAX)

static RTerm *run_term(const SigmaRun *s, int e) { return &s->w.m->stages[s->terms[e][0]].terms[s->terms[e][1]]; }
/* The term measured by record e: the term itself, or a view of its one operator (into `view`; a root's ‖M‖ record's
 * without the min-θ table, whose anchors are λ_min's). */
static const RTerm *run_view(const SigmaRun *s, int e, RTerm *view) {
  const RTerm *rt = run_term(s, e);
  if (s->terms[e][2] < 0) return rt;
  *view = *rt;
  view->ops = &rt->ops[s->terms[e][2]], view->nops = 1;
  if (s->terms[e][3]) view->est_theta = NULL, view->est_theta_k = 0;
  return view;
}
/* Where record e's ratio goes: the term's est_sigma, or its operator's est_opc entry (a root's ‖M‖ ratio: its
 * estimate_norm_slot). */
static double *run_ratio(const SigmaRun *s, int e) {
  RTerm *rt = run_term(s, e);
  if (s->terms[e][3]) return &rt->est_opc[estimate_norm_slot(rt, s->terms[e][2])];
  return s->terms[e][2] < 0 ? &rt->est_sigma : &rt->est_opc[s->terms[e][2]];
}
/* Whether record e measures ‖M‖ (the largest ratio kept) rather than σ_min (the smallest). */
static bool run_norm(const SigmaRun *s, int e) {
  RTerm view;
  const OpPow *op = run_view(s, e, &view)->ops[0].op;
  return s->terms[e][3] || (op->p > 0 && op->q == 1);
}
static const RClass *run_class(const SigmaRun *s, int e) {
  return &s->w.m->classes[s->w.m->qclass[s->w.m->stages[s->terms[e][0]].q]];
}
static long run_pick(const SigmaRun *s, long j) { return s->nk > 1 ? j * (s->src->count - 1) / (s->nk - 1) : 0; }

/* Sample k set for the terms' operators, and evaluated unless every tensor of each reads given values only
 * (inputs and externs: a thermal block's K(μ)), which the tensor builders read as set: the same operators, no
 * full evaluation (a solve at every picked sample of every greedy retraining). */
static int sigma_sample(const SigmaRun *s, long k) {
  bool given_only = true;
  for (int e = 0; e < s->nt && given_only; e++)
    for (int o = 0; o < run_term(s, e)->nops && given_only; o++) { /* every operator of a chained term */
      const ROp *ro = &run_term(s, e)->ops[o];
      for (int g = 0; g < ro->ntensors && given_only; g++)
        for (int i = 0; i < ro->t[g].group->ninputs; i++)
          given_only &= ro->t[g].group->inputs[i]->kind == SYM_INPUT || ro->t[g].group->inputs[i]->kind == SYM_EXTERN;
    }
  if (!given_only) return train_eval_sample(s->src, s->w.f, k, s->w.err);
  return s->src->set(s->src->user, s->w.f, k) != 0 ? err_set(s->w.err, "%s", full_error(s->w.f)) : 0;
}

/* Whether the min-θ bound enters term rt of one operator: an inverse's σ_min (of a power −1, or below: M^-2's chain
 * of solves, estimate.c's inverse_steps) or a root's λ_min; an application's ‖M‖ has no lower bound to take. */
static bool theta_applies(const RTerm *rt) {
  const OpPow *op = rt->ops[0].op;
  return !estimate_term_chains(rt) || op->q != 1 || op->p < 0;
}

/* Which terms' operators are affine with semidefinite terms (estimate_affine_input), found at sample 0 by the rank that
 * holds it and sent to the others; room for nk anchors each. */
static int theta_detect(SigmaRun *s) {
  Scratch sc = SCRATCH_OF(s->w.err);
  double *q = scratch_array(&sc, (size_t)s->nt + 1, sizeof(double));
  if (!q) return -1;
  int out = 0;
  if (s->rank == 0 && s->nt > 0 && (out = sigma_sample(s, 0)) == 0)
    for (int e = 0; e < s->nt; e++)
      q[e] = s->terms[e][2] >= 0 || !theta_applies(run_term(s, e)) ? -1
                                                                : estimate_affine_input(&s->w, run_term(s, e), run_class(s, e)->n);
  if (out == 0 && s->N > 1) dist_broadcast(q, s->nt, 0);
  for (int e = 0; out == 0 && e < s->nt; e++) {
    RTerm *rt = run_term(s, e);
    if (s->terms[e][3]) continue; /* a root's ‖M‖ record: its term's λ_min record decides */
    free(rt->est_theta);
    rt->est_theta = NULL, rt->est_theta_k = 0;
    if (q[e] < 0) continue;
    rt->est_theta_q = (int)q[e], rt->est_theta_n = s->w.m->classes[s->w.m->qclass[rt->est_theta_q]].n;
    if (!(rt->est_theta = malloc(sizeof(double) * (size_t)(s->nk * (rt->est_theta_n + 1)) + 1)))
      out = err_set(s->w.err, "estimate tables: out of memory");
  }
  scratch_release(&sc);
  return out;
}

/* This rank's picked samples evaluated, each term's record made (the others' records stay zero). */
static int sigma_records(SigmaRun *s) {
  for (long j = 0; j < s->nk; j++) {
    long k = run_pick(s, j);
    if (k % s->N != s->rank) continue;
    if (sigma_sample(s, k)) return -1;
    for (int e = 0; e < s->nt; e++) {
      RTerm view;
      const RTerm *rt = run_view(s, e, &view);
      double *r = s->rec + ((long)e * s->nk + j) * SIGMA_REC;
      if (term_sigmas(&s->w, rt, run_class(s, e), s->w.m->stages[s->terms[e][0]].st->sym->name, run_norm(s, e), r))
        return -1;
      size_t nx = 0;
      const double *x =
          rt->est_theta ? full_get(s->w.f, ((const Sym *)s->w.m->prog->quantities.v[rt->est_theta_q])->name, &nx) : NULL;
      if (x && (long)nx == rt->est_theta_n) r[2] = 1, memcpy(r + 3, x, sizeof(double) * nx);
    }
  }
  return 0;
}

void estimate_theta_anchor(RTerm *rt, const double *x, double lmin) {
  bool anchor = rt->est_theta && x && lmin > 0;
  for (long a = 0; anchor && a < rt->est_theta_n; a++) anchor = x[a] > 0;
  if (!anchor) return;
  double *row = rt->est_theta + (long)rt->est_theta_k++ * (rt->est_theta_n + 1);
  memcpy(row, x, sizeof(double) * (size_t)rt->est_theta_n);
  row[rt->est_theta_n] = lmin;
}

/* The records folded in the order of the samples, as on one process: c = min of σ_min(M)/σ_min(BᵀMB) (an
 * applied operator's: the max of ‖M‖/‖BᵀMB‖), and an anchor of the min-θ bound at each sample whose x̄ is
 * positive (λ_min = σ_min of the SPD M(x̄)). */
static void sigma_fold(SigmaRun *s) {
  for (long j = 0; j < s->nk; j++)
    for (int e = 0; e < s->nt; e++) {
      RTerm *rt = run_term(s, e);
      double *c = run_ratio(s, e);
      const double *r = s->rec + ((long)e * s->nk + j) * SIGMA_REC;
      estimate_theta_anchor(rt, !s->terms[e][3] && r[2] == 1 ? r + 3 : NULL, r[0]);
      double ratio = r[0] / r[1];
      if (run_norm(s, e)) { /* the largest ‖M‖/‖BᵀMB‖ (M = 0: no ratio); a failed one: none */
        if (r[0] == 0 && r[1] == 0) continue;
        if (!(ratio > 0 && isfinite(ratio))) *c = 0;
        else if (isnan(*c) || (*c > 0 && ratio > *c)) *c = ratio;
        continue;
      }
      if (!(ratio > 0)) ratio = 0; /* a singular operator or a decomposition that failed: no bound */
      if (j == 0 || isnan(*c) || ratio < *c) *c = ratio;
    }
}

/* The records of run s: every term of one operator with a table (its class within the sparse limit, without a
 * product), each operator of a chained term of several, and the ‖M‖ of each root of power above 1 (its est_opc
 * made, estimate_term_ratios entries, NaN until measured). */
static int sigma_terms(SigmaRun *s) {
  Model *m = s->w.m;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      const RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
      /* a class whose basis is never whole (out of core, RClass.streamed): estimate_stream.c's */
      if (!rt->est_G || rc->n > ESTIMATE_SPARSE_MAX || rc->product || !rc->B) continue;
      bool several = rt->nops > 1 && estimate_term_chains(rt) && rt->nops <= ESTIMATE_OPS_MAX;
      if (rt->nops != 1 && !several) continue;
      int K = estimate_term_ratios(rt);
      free(rt->est_opc);
      rt->est_opc = K > 0 ? malloc(sizeof(double) * (size_t)K) : NULL;
      if (K > 0 && !rt->est_opc) return -1;
      for (int k = 0; k < K; k++) rt->est_opc[k] = NAN;
      for (int k = several ? 0 : -1; k < (several ? rt->nops : 0); k++) {
        int *rec = s->terms[s->nt++];
        rec[0] = i, rec[1] = t, rec[2] = k, rec[3] = 0;
      }
      for (int k = 0; k < rt->nops; k++) {
        if (estimate_norm_slot(rt, k) < 0) continue;
        int *rec = s->terms[s->nt++];
        rec[0] = i, rec[1] = t, rec[2] = k, rec[3] = 1;
      }
    }
  return 0;
}

/* c = min over spread training samples of σ_min(M)/σ_min(BᵀMB) for every inverse term with a table. Over ranks
 * each rank evaluates the picked samples it holds, and the records are summed (one rank's nonzero each): every
 * rank folds the same records, so the tables are one process's. */
static int sigma_ratios(Model *m, Full *f, const SampleSource *src, bool dist, Err *err) {
  cholmod_common cc;
  cholmod_l_start(&cc);
  long S = src->count;
  SigmaRun s = {{m, f, &cc, err, src}, src, NULL, 0, S < ESTIMATE_SIGMA_SAMPLES ? S : ESTIMATE_SIGMA_SAMPLES,
                dist ? dist_rank() : 0, dist ? dist_size() : 1, NULL};
  int n = 0;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) n += 1 + m->stages[i].terms[t].nops + estimate_term_ratios(&m->stages[i].terms[t]);
  Scratch sc = SCRATCH_OF(NULL);
  int out = (s.terms = scratch_array_unzeroed(&sc, (size_t)n + 1, sizeof *s.terms)) && !sigma_terms(&s) &&
                    (s.rec = scratch_array(&sc, (size_t)(s.nt * s.nk * SIGMA_REC) + 1, sizeof(double))) &&
                    (s.nt == 0 || (!theta_detect(&s) && !sigma_records(&s)))
                ? 0
                : -1;
  if (out == 0 && s.nt > 0 && s.N > 1) dist_allreduce_sum(s.rec, s.nt * s.nk * SIGMA_REC);
  if (out == 0) sigma_fold(&s);
  if (out && !err_held(err)) err_set(err, "estimate tables: out of memory");
  cholmod_l_finish(&cc);
  scratch_release(&sc);
  if (out) return -1;
  for (int i = 0; i < m->nstages; i++) /* a ratio of 0 is no lower bound: the term has no estimate */
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      if (rt->est_sigma == 0) rt->est_sigma = NAN;
      for (int k = 0; rt->est_opc && k < estimate_term_ratios(rt); k++)
        if (rt->est_opc[k] == 0) rt->est_opc[k] = NAN;
    }
  return 0;
}

/* Each input's reduced coordinates' min and max over the training samples; over ranks each rank's samples
 * (k ≡ rank mod N), then the largest of the maxima and of the negated minima (exact: the same figures). */
static int input_ranges(Model *m, Full *f, const SampleSource *src, bool dist, Err *err) {
  int rank = dist ? dist_rank() : 0, N = dist ? dist_size() : 1;
  if (!(m->in_range = calloc((size_t)m->nq + 1, sizeof(double *)))) return err_set(err, "estimate tables: out of memory");
  for (int q = 0; q < m->nq; q++) { /* -min, max: −∞ until a sample is seen */
    const RClass *rc = &m->classes[m->qclass[q]];
    if (((const Sym *)m->prog->quantities.v[q])->kind != SYM_INPUT || !rc->B) continue;
    if (!(m->in_range[q] = malloc(sizeof(double) * (size_t)(2 * rc->m) + 1))) return err_set(err, "estimate tables: out of memory");
    for (long a = 0; a < 2 * rc->m; a++) m->in_range[q][a] = -INFINITY;
  }
  for (long k = rank; k < src->count; k += N) {
    if (src->set(src->user, f, k) != 0) return err_set(err, "%s", full_error(f));
    for (int q = 0; q < m->nq; q++) {
      const RClass *rc = &m->classes[m->qclass[q]];
      size_t cnt = 0;
      const double *x = m->in_range[q] ? full_get(f, ((const Sym *)m->prog->quantities.v[q])->name, &cnt) : NULL;
      if (!x || (long)cnt != rc->n) continue;
      long mq = rc->m;
      double *rg = m->in_range[q], xh[mq + 1];
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)mq, 1.0, model_projector(rc), (int)mq, x, 1, 0.0, xh, 1);
      for (long a = 0; a < mq; a++) rg[a] = fmax(rg[a], -xh[a]), rg[mq + a] = fmax(rg[mq + a], xh[a]);
    }
  }
  for (int q = 0; q < m->nq; q++) {
    if (!m->in_range[q]) continue;
    long mq = m->classes[m->qclass[q]].m;
    if (N > 1) dist_allreduce_max(m->in_range[q], 2 * mq);
    if (mq > 0 && m->in_range[q][mq] == -INFINITY) { /* no sample gave it: no range */
      free(m->in_range[q]);
      m->in_range[q] = NULL;
      continue;
    }
    for (long a = 0; a < mq; a++) m->in_range[q][a] = -m->in_range[q][a];
  }
  return 0;
}

/* Term rt's table as rank `owner` built it (none, or R with its norms row), on every rank. */
static int share_table(RTerm *rt, int owner, Err *err) {
  double D = rt->est_G ? (double)rt->est_D : -1;
  dist_broadcast(&D, 1, owner);
  if (D < 0) return 0;
  if (dist_rank() != owner) {
    free(rt->est_G);
    rt->est_D = (long)D, rt->est_sigma = NAN;
    if (!(rt->est_G = malloc(sizeof(double) * (size_t)((rt->est_D + 1) * rt->est_D) + 1)))
      return err_set(err, "estimate tables: out of memory");
  }
  dist_broadcast(rt->est_G, (rt->est_D + 1) * rt->est_D, owner);
  return 0;
}

/* Every eligible term's residual table. Over ranks the e-th (in stage and term order) is built by rank e mod N
 * and sent to the others: the same arithmetic as on one process, the work divided (a class with a product, which
 * training over ranks refuses, would be built on every rank). */
static int term_tables(Model *m, Full *f, const SampleSource *src, bool dist, Err *err) {
  int rank = dist ? dist_rank() : 0, N = dist ? dist_size() : 1, e = 0;
  char why[256];
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      const RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
      if (!estimate_term_eligible(m, i, t, why, sizeof why) || !rc->B) continue;
      bool shared = N > 1 && !rc->product;
      int owner = e++ % N;
      if ((!shared || owner == rank) && term_table(m, f, src, i, t, err)) return -1;
      if (shared && share_table(&m->stages[i].terms[t], owner, err)) return -1;
    }
  return 0;
}

int train_estimates(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err) {
  if (src->count < 1) return 0;
  char why[256];
  for (int i = 0; i < m->nstages; i++) { /* a Galerkin stage of diagonal operators with a term of no table: a check */
    const RStage *rs = &m->stages[i];
    bool tables = true;
    for (int t = 0; t < rs->nterms; t++) tables = tables && estimate_term_eligible(m, i, t, why, sizeof why);
    if (!rs->interp && !tables && lower_interp_eligible(rs->st) && m->classes[m->qclass[rs->q]].B &&
        interp_train_check(m, f, i, err))
      return -1;
  }
  if (term_tables(m, f, src, opt->dist, err) || sigma_ratios(m, f, src, opt->dist, err) ||
      input_ranges(m, f, src, opt->dist, err))
    return -1;
  if (m->nexterns > 0) full_forget_given(f); /* the ranges' samples set, never evaluated: callbacks as before */
  return 0;
}
