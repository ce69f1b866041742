/* estimate_stream.c — the online estimate's tables (estimate_train.c, docs/estimates.md) of the
 * terms that read a basis the model drops out of core (RClass.streamed, formed block by block in
 * stream.c's sweep and never whole: radiosity's pair classes at --mem below their bases).
 *
 * The residual table of a term is R of the QR of C' = (I − B_yB_yᵀ)C, C (n x D) its residual's
 * full-space columns. Row block by row block, as the sweep forms the basis rows a block reads,
 * the block's rows of [B_y C] are stacked under the R so far and factored again (LAPACK dgeqrf:
 * a tall-skinny QR, one block at a time). At the end R = [R11 R12; 0 R22] with Q1 = B_y R11⁻¹ a
 * basis of B_y's span, and R22 is R of C − Q1Q1ᵀC = (I − B_yB_yᵀ)C: ‖R22 z‖ = ‖C' z‖, the
 * in-memory table's figure to rounding, without the columns ever held whole (the block's rows
 * only, in chunks of TSQR_CHUNK_BYTES). The columns are made with the bases' columns as the
 * sweep forms them (B = A T, signs not yet fixed: stream.c's fix_signs), so C's columns are
 * those of the model times ±1: R22's columns are multiplied by those signs at the end
 * (stream_column_signs), which makes R22ᵀR22 the model's.
 *
 * An inverse term's σ_min ratio c = min over picked training samples of σ_min(M)/σ_min(B_yᵀMB_y)
 * (estimate_train.c's sigma_ratios: the same samples) needs B_yᵀM_kB_y: while the sweep evaluates
 * a picked sample restricted to a block's rows, M_k's entries of the block's output rows are kept
 * (their input values read from that evaluation), and once the block's basis rows are formed,
 * B_y[row]ᵀ M_k(row, col) B_y[col] is added up (σ_min is unchanged by the columns' signs). σ_min(M_k)
 * itself is measured as in memory, on the operator assembled from a whole evaluation of the sample
 * (the one full evaluation --mem leaves room for).
 *
 * A Galerkin stage of diagonal operators of a dropped class whose terms have no table (a diagonal
 * root: radiosity's p = d a^(-1/2) in a room without the extern) is estimated by its check table
 * (interp_check: the formula's residual at k_c sampled entries). Its entries and monomials need
 * no basis (interp_train_check_rows, before the sweep); the basis rows it keeps — the stage's class
 * at the entries (brows), each read quantity's at the entry read (read_rows) — are copied from the
 * blocks as the sweep forms them, each from the one block whose home rows hold it, and multiplied
 * by the columns' signs at the end: the in-memory check table to rounding.
 *
 * Over MPI ranks each rank factors its own blocks; the ranks' R are stacked in rank order on every
 * rank and factored once more (the same bytes everywhere), the norms, B_yᵀM_kB_y and the check
 * tables' rows summed (every row from one rank, zero on the others). */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <suitesparse/cholmod.h>

#include "dist.h"
#include "estimate_steps.h"
#include "interp.h"
#include "ooc.h"
#include "scratch.h"

/* A block's rows of [B_y C] are factored in chunks of about this many bytes (at least 64 rows). */
#define TSQR_CHUNK_BYTES ((size_t)1 << 20)

/* One picked sample's entries of M on the current block's output rows: (row, col, value). */
typedef struct Trip {
  long *rc;                 /* row, col pairs */
  double *v;
  long count, cap;
} Trip;

/* A term whose table is made in the sweep. A chained term's (estimate_term_chains) column blocks are
 * factored apart, as estimate_train.c's qr_blocks does: one R per block b, of [B_y C_b]. */
typedef struct EstTerm {
  int i, t, cy;             /* stage, term, the stage's class */
  long my, D;
  int nb;                   /* blocks: C's columns [cols[2b], cols[2b + 1]), all D of them for a term not chained */
  long cols[2 * ESTIMATE_OPS_MAX + 2];
  double *R[ESTIMATE_OPS_MAX + 1]; /* per block, W x W row-major (W = my + its columns), upper: R of [B_y C_b] over
                                      this rank's rows so far */
  double *norms;            /* D: Σ of the squares of C's columns */
  bool sigma;               /* an inverse term of a class never whole: its σ_min ratio made here */
  double *G;                /* nk x my x my: B_yᵀ M_k B_y of the picked samples */
  Trip *trip;               /* nk: this block's entries of M_k */
} EstTerm;

/* A Galerkin stage of diagonal operators of a dropped class: its estimate's check table. */
typedef struct EstCheck {
  int i;                    /* stage */
  RInterp *ck;              /* interp_train_check_rows's: brows and read_rows filled by the blocks */
  long *at;                 /* per read: its row's offset in ck->read_rows */
} EstCheck;

struct EstStream {
  Ooc *o;
  EstWork w;
  EstTerm *term;
  int nt;
  EstCheck *check;
  int nc;
  long nk;                  /* picked samples, as sigma_ratios picks them */
  Scratch sc;               /* everything above, released by estimate_stream_free */
};

static bool dropped(const Ooc *o, int c) { return o->st[c].blockwise && o->t->m->classes[c].streamed; }

/* Picked sample j of nk: j (S − 1) / (nk − 1), as estimate_train.c's run_pick. */
static long pick(const EstStream *e, long j) { return e->nk > 1 ? j * (e->o->t->src->count - 1) / (e->nk - 1) : 0; }

/* Whether term t of stage i reads a basis never whole (its class's, or an input's) and every
 * other basis it reads is whole now; its table then is the sweep's. */
static bool streamed_term(const Ooc *o, int i, int t) {
  Model *m = o->t->m;
  const RStage *rs = &m->stages[i];
  const RTerm *rt = &rs->terms[t];
  char why[256];
  int cy = m->qclass[rs->q];
  /* a kept class formed block by block is mapped only after the sweep: eligible as if streamed
   * (estimate_term_eligible asks for a basis, whole or streamed) */
  bool was = m->classes[cy].streamed, eligible;
  m->classes[cy].streamed |= o->st[cy].blockwise;
  eligible = estimate_term_eligible(m, i, t, why, sizeof why) && estimate_term_make(m, i, t) != EST_MAKE_NONE;
  m->classes[cy].streamed = was;
  /* a chained term (operator applications, roots of a declared op, several operators) of a class whose
   * basis is never whole would need its per-operator ratios from B_yᵀMB_y too: no table out of core;
   * of a class kept, whose operator reads a dropped basis, its blocks' R here, its ratios in memory */
  bool never = dropped(o, cy), whole = o->st[cy].blockwise || m->classes[cy].B;
  if (!eligible || (never && (estimate_term_chains(rt) || (rt->nops == 1 && rt->ops[0].op->p > 0)))) return false;
  RTERM_FOR_TENSORS(rt, x)
    for (int j = 0; j < x->nin; j++) {
      int c = m->qclass[x->in_q[j]];
      never |= dropped(o, c), whole &= o->st[c].blockwise || m->classes[c].B != NULL;
    }
  if (rt->named_q >= 0) { /* a named numerator's rows: the stage's own class's, or a whole basis of as many rows */
    int c = m->qclass[rt->named_q];
    whole &= c == cy || (!o->st[c].blockwise && m->classes[c].B && m->classes[c].n == m->classes[cy].n);
  }
  return never && whole;
}

/* Columns of x's block b, and W, the columns of [B_y C_b]. */
static long block_len(const EstTerm *x, int b) { return x->cols[2 * b + 1] - x->cols[2 * b]; }
static long block_w(const EstTerm *x, int b) { return x->my + block_len(x, b); }

static int term_init(EstStream *e, EstTerm *x, int i, int t) {
  const Model *m = e->o->t->m;
  const RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
  *x = (EstTerm){.i = i, .t = t, .cy = m->qclass[m->stages[i].q], .my = rc->m, .D = estimate_term_dim(m, i, t)};
  x->nb = estimate_table_blocks(m, i, t, x->cols) / 2;
  x->sigma = dropped(e->o, x->cy) && m->stages[i].terms[t].nops == 1 && rc->n <= ESTIMATE_SPARSE_MAX;
  bool room = true;
  for (int b = 0; b < x->nb; b++)
    room &= (x->R[b] = scratch_array(&e->sc, (size_t)(block_w(x, b) * block_w(x, b)) + 1, sizeof(double))) != NULL;
  x->norms = scratch_array(&e->sc, (size_t)x->D + 1, sizeof(double));
  if (x->sigma) {
    x->G = scratch_array(&e->sc, (size_t)(e->nk * x->my * x->my) + 1, sizeof(double));
    x->trip = scratch_array(&e->sc, (size_t)e->nk, sizeof(Trip));
  }
  return room && x->norms && (!x->sigma || (x->G && x->trip)) ? 0 : -1;
}

/* Whether stage i is a Galerkin stage of diagonal operators of a dropped class with a term of no table: its
 * estimate is a check table (train_estimates's rule, which skips the class: it has no basis there). */
static bool checked_stage(const Ooc *o, int i) {
  Model *m = o->t->m;
  const RStage *rs = &m->stages[i];
  char why[256];
  bool tables = true;
  for (int t = 0; t < rs->nterms; t++) tables = tables && estimate_term_eligible(m, i, t, why, sizeof why);
  return !rs->interp && !tables && lower_interp_eligible(rs->st) && dropped(o, m->qclass[rs->q]);
}

/* Stage i's check table without its rows (the blocks copy them), kept when every class it reads is
 * blockwise or whole (as in memory, where a read class without its basis leaves the check out). */
static int check_init(EstStream *e, int i) {
  Model *m = e->w.m;
  RInterp *ck = NULL;
  if (interp_train_check_rows(m, e->w.f, i, &ck, e->w.err)) return -1;
  EstCheck *x = &e->check[e->nc];
  *x = (EstCheck){i, ck, scratch_array(&e->sc, (size_t)ck->nreads + 1, sizeof(long))};
  long len = 0;
  bool rows = true;
  for (long r = 0; r < ck->nreads; r++) {
    int c = m->qclass[ck->read_q[r]];
    rows &= e->o->st[c].blockwise || m->classes[c].B || m->classes[c].m == 0;
    if (x->at) x->at[r] = len;
    len += m->classes[c].m;
  }
  if (!rows) { /* no check, as in memory */
    interp_free(ck);
    return 0;
  }
  e->nc++;
  if (!x->at || !(ck->read_rows = mem_calloc((size_t)len + 1, sizeof(double))))
    return err_set(e->w.err, "out of memory for the check table of stage %s", m->stages[i].st->sym->name);
  return 0;
}

int estimate_stream_begin(Ooc *o, EstStream **out) {
  Model *m = o->t->m;
  *out = NULL;
  long S = o->t->src->count;
  int n = 0, nc = 0;
  for (int i = 0; i < m->nstages; i++) {
    nc += checked_stage(o, i);
    for (int t = 0; t < m->stages[i].nterms; t++) n += streamed_term(o, i, t);
  }
  if (n + nc == 0 || S < 1) return 0;
  EstStream *e = calloc(1, sizeof *e);
  if (!e) return err_set(o->t->err, "out of memory for the estimate tables of the streamed bases");
  *e = (EstStream){o, {m, o->t->f, NULL, o->t->err, o->t->src}, NULL, 0, NULL, 0,
                   S < ESTIMATE_SIGMA_SAMPLES ? S : ESTIMATE_SIGMA_SAMPLES, SCRATCH_OF(o->t->err)};
  *out = e;
  if (!(e->term = scratch_array(&e->sc, (size_t)n + 1, sizeof(EstTerm))) ||
      !(e->check = scratch_array(&e->sc, (size_t)nc + 1, sizeof(EstCheck))))
    return -1;
  for (int i = 0; i < m->nstages; i++) {
    if (checked_stage(o, i) && check_init(e, i)) return -1;
    for (int t = 0; t < m->stages[i].nterms; t++)
      if (streamed_term(o, i, t) && term_init(e, &e->term[e->nt++], i, t)) return -1;
  }
  return 0;
}

void estimate_stream_free(EstStream *e) {
  if (!e) return;
  for (int k = 0; k < e->nt; k++)
    for (long j = 0; e->term[k].trip && j < e->nk; j++) free(e->term[k].trip[j].rc), free(e->term[k].trip[j].v);
  for (int k = 0; k < e->nc; k++) interp_free(e->check[k].ck); /* NULL once the stage holds it */
  scratch_release(&e->sc);
  free(e);
}

void estimate_stream_demand(const EstStream *e, Demand *d) {
  if (!e) return;
  const Model *m = e->o->t->m;
  for (int k = 0; k < e->nt; k++) { /* an operator's inputs of a class not held by rows: whole */
    const RTerm *rt = &m->stages[e->term[k].i].terms[e->term[k].t];
    for (int g = 0; e->term[k].sigma && g < rt->ops[0].ntensors; g++)
      for (int j = 0; j < rt->ops[0].t[g].nin; j++)
        if (!e->o->st[m->qclass[rt->ops[0].t[g].in_q[j]]].blockwise)
          demand_all(d, m->prog->quantities.v[rt->ops[0].t[g].in_q[j]]);
  }
}

/* ---------------------------------------------------------------- M_k's entries of a block */

/* The sink of M_k's entries: coef · Π input values at (row, col), or (row, row) for a diagonal one. */
typedef struct TripSink {
  const double *in[64];
  long lo, hi, n;
  bool diag;
  Trip *trip;
} TripSink;

static int trip_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  TripSink *s = user;
  long c = s->diag ? (long)row : (long)col;
  if (row < s->lo || row >= s->hi) return row >= 0 && row < s->n ? 0 : -1;
  if (c < 0 || c >= s->n || nin > 64) return -1;
  Trip *tp = s->trip;
  if (tp->count == tp->cap) {
    long cap = tp->cap ? 2 * tp->cap : 1024;
    long *rc = mem_realloc(tp->rc, sizeof(long) * (size_t)(2 * cap));
    if (rc) tp->rc = rc;
    double *v = mem_realloc(tp->v, sizeof(double) * (size_t)cap);
    if (v) tp->v = v;
    if (!rc || !v) return -1;
    tp->cap = cap;
  }
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  tp->rc[2 * tp->count] = row, tp->rc[2 * tp->count + 1] = c, tp->v[tp->count++] = v;
  return 0;
}

int estimate_stream_sample(EstStream *e, long k, long u, long U) {
  if (!e) return 0;
  long j = 0;
  while (j < e->nk && pick(e, j) != k) j++;
  if (j == e->nk) return 0;
  const Model *m = e->o->t->m;
  Full *f = e->o->t->f;
  for (int q = 0; q < e->nt; q++) {
    EstTerm *x = &e->term[q];
    if (!x->sigma) continue;
    const RTerm *rt = &m->stages[x->i].terms[x->t];
    TripSink s = {{0}, 0, 0, m->classes[x->cy].n, false, &x->trip[j]};
    stream_fraction(s.n, u, U, &s.lo, &s.hi);
    for (int g = 0; s.lo < s.hi && g < rt->ops[0].ntensors; g++) {
      const RTensor *t = &rt->ops[0].t[g];
      s.diag = t->kind == RT_DIAG;
      for (int i = 0; i < t->group->ninputs && i < 64; i++) s.in[i] = full_get(f, t->group->inputs[i]->name, NULL);
      NpgSink sink = {&s, trip_entry, 0, 1, s.lo, s.hi};
      if (full_build(f, t->builder, &sink) != 0)
        return err_set(e->w.err, "estimate tables: the operator of stage %s at training sample %ld: %s",
                       m->stages[x->i].st->sym->name, k, full_error(f)[0] ? full_error(f) : "out of memory");
    }
  }
  return 0;
}

/* ---------------------------------------------------------------- a block's rows */

/* Rows [lo, hi) of [B_y C_b] stacked under block b's R (C's rows in C, nr x D) and factored again: R of every
 * row so far. */
static int tsqr_block(EstStream *e, EstTerm *x, int b, const ColRows *rows, const double *C) {
  long nr = rows->hi - rows->lo, W = block_w(x, b), D = x->D, my = x->my, c0 = x->cols[2 * b];
  Scratch sc = SCRATCH_OF(e->w.err);
  double *Z = scratch_array(&sc, (size_t)((W + nr) * W) + 1, sizeof(double)), *tau = scratch_array(&sc, (size_t)W + 1, sizeof(double));
  int out = Z && tau ? 0 : -1;
  if (out == 0) memcpy(Z, x->R[b], sizeof(double) * (size_t)(W * W));
  for (long r = 0; out == 0 && r < nr; r++) {
    const double *br = estimate_basis_row(e->w.m, rows, x->cy, rows->lo + r);
    if (!br) out = err_set(e->w.err, "estimate tables: row %ld of class %s's basis not held (a bug in npg)", rows->lo + r,
                           e->w.m->classes[x->cy].label);
    else memcpy(Z + (W + r) * W, br, sizeof(double) * (size_t)my);
    if (out == 0) memcpy(Z + (W + r) * W + my, C + r * D + c0, sizeof(double) * (size_t)(W - my));
  }
  if (out == 0 && LAPACKE_dgeqrf(LAPACK_ROW_MAJOR, (int)(W + nr), (int)W, Z, (int)W, tau) != 0)
    out = err_set(e->w.err, "estimate tables: the QR of stage %s's residual rows failed (LAPACK)",
                  e->w.m->stages[x->i].st->sym->name);
  for (long a = 0; out == 0 && a < W; a++)
    for (long c = 0; c < W; c++) x->R[b][a * W + c] = c >= a ? Z[a * W + c] : 0;
  scratch_release(&sc);
  return out;
}

/* Rows [lo, hi) of x's columns made, their squares added to the norms, each block's R updated. */
static int tsqr_rows(EstStream *e, EstTerm *x, const ColRows *rows, Scratch *sc) {
  long nr = rows->hi - rows->lo, D = x->D;
  double *C = scratch_array(sc, (size_t)(nr * D) + 1, sizeof(double));
  if (!C || estimate_term_columns(&e->w, x->i, x->t, rows, C)) return -1;
  for (long r = 0; r < nr; r++)
    for (long c = 0; c < D; c++) x->norms[c] += C[r * D + c] * C[r * D + c];
  for (int b = 0; b < x->nb; b++)
    if (block_len(x, b) > 0 && tsqr_block(e, x, b, rows, C)) return -1;
  return 0;
}

/* The block's entries of every picked M_k into B_yᵀ M_k B_y; the entries forgotten. */
static int reduce_operator(EstStream *e, EstTerm *x, const ColRows *rows) {
  long my = x->my;
  for (long j = 0; j < e->nk; j++) {
    Trip *tp = &x->trip[j];
    double *G = x->G + j * my * my;
    for (long p = 0; p < tp->count; p++) {
      const double *br = estimate_basis_row(e->w.m, rows, x->cy, tp->rc[2 * p]),
                   *bc = estimate_basis_row(e->w.m, rows, x->cy, tp->rc[2 * p + 1]);
      if (!br || !bc) return err_set(e->w.err, "estimate tables: a basis row of class %s not held (a bug in npg)",
                                     e->w.m->classes[x->cy].label);
      for (long a = 0; a < my; a++)
        for (long b = 0; b < my; b++) G[a * my + b] += br[a] * tp->v[p] * bc[b];
    }
    tp->count = 0;
  }
  return 0;
}

/* The basis rows of block u of U as the sweep formed them (signs not fixed), each class's by its map. */
typedef struct BlockRows {
  const double *const *B;
  const RowMap *const *map;
  long u, U;
} BlockRows;

/* Row r of class c into `out` when c is blockwise and r one of the block's home rows (every row is one
 * block's home: each row copied once over the blocks and the ranks). */
static int home_row(const EstStream *e, const BlockRows *b, int c, long r, double *out) {
  const Model *m = e->w.m;
  long n = m->classes[c].n, lo, hi;
  if (!e->o->st[c].blockwise) return 0;
  stream_fraction(n, b->u, b->U, &lo, &hi);
  if (r < lo || r >= hi) return 0;
  const double *row = estimate_basis_row(m, &(ColRows){lo, hi, n, b->B, b->map}, c, r);
  if (!row) return err_set(e->w.err, "estimate tables: row %ld of class %s's basis not held (a bug in npg)", r, m->classes[c].label);
  memcpy(out, row, sizeof(double) * (size_t)m->classes[c].m);
  return 0;
}

/* The check table's rows held by the block: the stage's class at its entries, each read's class at the entry read. */
static int check_rows_of_block(const EstStream *e, const EstCheck *x, const BlockRows *b) {
  const Model *m = e->w.m;
  const RInterp *ck = x->ck;
  int cy = m->qclass[m->stages[x->i].q], out = 0;
  for (long s = 0; out == 0 && s < ck->k; s++) out = home_row(e, b, cy, ck->rows[s], ck->brows + s * m->classes[cy].m);
  for (long r = 0; out == 0 && r < ck->nreads; r++)
    out = home_row(e, b, m->qclass[ck->read_q[r]], ck->read_e[r], ck->read_rows + x->at[r]);
  return out;
}

int estimate_stream_block(EstStream *e, const double *const *B, const RowMap *const *map, long u, long U) {
  if (!e) return 0;
  int out = 0;
  for (int k = 0; out == 0 && k < e->nc; k++) out = check_rows_of_block(e, &e->check[k], &(BlockRows){B, map, u, U});
  for (int q = 0; out == 0 && q < e->nt; q++) {
    EstTerm *x = &e->term[q];
    long n = e->w.m->classes[x->cy].n, lo, hi, chunk = (long)(TSQR_CHUNK_BYTES / sizeof(double) / (size_t)(x->my + x->D));
    chunk = chunk > 64 ? chunk : 64;
    stream_fraction(n, u, U, &lo, &hi);
    for (long r = lo; out == 0 && r < hi; r += chunk) {
      Scratch sc = SCRATCH_OF(e->w.err);
      out = tsqr_rows(e, x, &(ColRows){r, r + chunk < hi ? r + chunk : hi, n, B, map}, &sc);
      scratch_release(&sc);
    }
    if (out == 0 && x->sigma) out = reduce_operator(e, x, &(ColRows){lo, hi, n, B, map});
  }
  return out;
}

/* ---------------------------------------------------------------- the tables */

/* Over ranks: every rank's R of block b stacked in rank order and factored (the same on every rank). */
static int combine_block(EstStream *e, EstTerm *x, int b) {
  int N = e->o->N, rank = e->o->rank;
  long W = block_w(x, b);
  Scratch sc = SCRATCH_OF(e->w.err);
  double *Z = scratch_array(&sc, (size_t)(N * W * W) + 1, sizeof(double)), *tau = scratch_array(&sc, (size_t)W + 1, sizeof(double));
  int out = Z && tau ? 0 : -1;
  if (out == 0) {
    memcpy(Z + (long)rank * W * W, x->R[b], sizeof(double) * (size_t)(W * W));
    dist_allreduce_sum(Z, N * W * W); /* every other rank's block zero: exact */
    if (LAPACKE_dgeqrf(LAPACK_ROW_MAJOR, (int)(N * W), (int)W, Z, (int)W, tau) != 0)
      out = err_set(e->w.err, "estimate tables: the QR of the ranks' residual factors failed (LAPACK)");
    for (long a = 0; out == 0 && a < W; a++)
      for (long c = 0; c < W; c++) x->R[b][a * W + c] = c >= a ? Z[a * W + c] : 0;
  }
  scratch_release(&sc);
  return out;
}

/* Over ranks: the norms and B_yᵀM_kB_y summed, each block's R combined. */
static int combine_ranks(EstStream *e, EstTerm *x) {
  dist_allreduce_sum(x->norms, x->D);
  if (x->sigma) dist_allreduce_sum(x->G, e->nk * x->my * x->my);
  for (int b = 0; b < x->nb; b++)
    if (block_len(x, b) > 0 && combine_block(e, x, b)) return -1;
  return 0;
}

/* Term x's table into the model: each block's R22 with its columns' signs on the diagonal (zero off it:
 * qr_blocks's layout), then the columns' norms. */
static int store_table(EstStream *e, EstTerm *x, const double *const *sign) {
  RTerm *rt = &e->w.m->stages[x->i].terms[x->t];
  long D = x->D, my = x->my;
  Scratch sc = SCRATCH_OF(e->w.err);
  double *cs = scratch_array(&sc, (size_t)D + 1, sizeof(double));
  double *G = scratch_adopt(&sc, mem_calloc((size_t)((D + 1) * D) + 1, sizeof(double))); /* the term's once whole */
  int out = cs && G && stream_column_signs(e->o, rt, x->cy, sign, cs, &sc) == 0 ? 0 : -1;
  if (out == 0) {
    for (int b = 0; b < x->nb; b++)
      for (long W = block_w(x, b), c0 = x->cols[2 * b], a = 0; a < block_len(x, b); a++)
        for (long c = 0; c < block_len(x, b); c++) G[(c0 + a) * D + c0 + c] = x->R[b][(my + a) * W + my + c] * cs[c0 + c];
    for (long c = 0; c < D; c++) G[D * D + c] = sqrt(x->norms[c]);
    free(rt->est_G); /* the table it replaces */
    rt->est_G = scratch_keep(&sc, G), rt->est_D = D, rt->est_sigma = NAN;
  } else if (!err_held(e->w.err)) {
    err_set(e->w.err, "out of memory for the estimate tables of the streamed bases");
  }
  scratch_release(&sc);
  return out;
}

/* A picked sample's record: σ_min(M_k), 1 when the min-θ input x̄ follows, then x̄. */
#define STREAM_REC (2 + ESTIMATE_THETA_MAX)

/* Which σ terms' operators are affine in one input with semidefinite parts (estimate_affine_input: the
 * operator assembled whole at unit inputs, as σ_min(M_k) is), found at sample 0's inputs by rank 0 and sent
 * to the others, as estimate_train.c's theta_detect; room for nk anchors each. */
static int theta_detect(EstStream *e) {
  Model *m = e->w.m;
  const SampleSource *src = e->o->t->src;
  Scratch sc = SCRATCH_OF(e->w.err);
  double *q = scratch_array(&sc, (size_t)e->nt + 1, sizeof(double));
  int out = q ? 0 : -1;
  if (out == 0 && e->o->rank == 0 && src->set(src->user, e->w.f, 0) != 0) out = err_set(e->w.err, "%s", full_error(e->w.f));
  for (int k = 0; out == 0 && e->o->rank == 0 && k < e->nt; k++) {
    const EstTerm *x = &e->term[k];
    q[k] = x->sigma ? estimate_affine_input(&e->w, &m->stages[x->i].terms[x->t], m->classes[x->cy].n) : -1;
  }
  if (out == 0 && e->o->N > 1) dist_broadcast(q, e->nt, 0);
  for (int k = 0; out == 0 && k < e->nt; k++) {
    RTerm *rt = &m->stages[e->term[k].i].terms[e->term[k].t];
    if (!e->term[k].sigma) continue;
    free(rt->est_theta);
    rt->est_theta = NULL, rt->est_theta_k = 0;
    if (q[k] < 0) continue;
    rt->est_theta_q = (int)q[k], rt->est_theta_n = m->classes[m->qclass[rt->est_theta_q]].n;
    if (!(rt->est_theta = malloc(sizeof(double) * (size_t)(e->nk * (rt->est_theta_n + 1)) + 1)))
      out = err_set(e->w.err, "estimate tables: out of memory");
  }
  scratch_release(&sc);
  return out;
}

/* Sample j's record r folded into rt: an anchor of the min-θ bound when its x̄ is positive (λ_min = σ_min of
 * the SPD M(x̄)), and the σ_min ratio against B_yᵀM_kB_y's (G, destroyed; sv 2 my doubles). */
static void fold_record(RTerm *rt, long j, const double *r, double *G, long my, double *sv) {
  estimate_theta_anchor(rt, r[1] == 1 ? r + 2 : NULL, r[0]);
  double ratio = r[0] / (my > 0 ? estimate_smallest_sv(G, my, sv) : INFINITY);
  if (!(ratio > 0)) ratio = 0;
  if (j == 0 || ratio < rt->est_sigma) rt->est_sigma = ratio;
}

/* x's σ_min ratio: min over the picked samples of σ_min(M_k)/σ_min(B_yᵀM_kB_y), M_k measured on
 * the rank that holds sample k (k mod N, as sigma_ratios) with the sample's min-θ input, and the records
 * summed (nk x STREAM_REC, zero on entry); a ratio not positive (a singular operator, LAPACK failing) is 0,
 * which estimate_train.c makes NaN. */
static int sigma_ratio(EstStream *e, EstTerm *x, double *rec) {
  const Model *m = e->w.m;
  RTerm *rt = &m->stages[x->i].terms[x->t];
  long my = x->my;
  Scratch sc = SCRATCH_OF(e->w.err);
  double *A = scratch_array(&sc, (size_t)(my * my) + 1, sizeof(double)), *sv = scratch_array(&sc, (size_t)(2 * my) + 1, sizeof(double));
  int out = A && sv ? 0 : -1;
  for (long j = 0; out == 0 && j < e->nk; j++) {
    long k = pick(e, j);
    double *r = rec + j * STREAM_REC;
    if (k % e->o->N != e->o->rank) continue;
    out = train_eval_sample(e->o->t->src, e->w.f, k, e->w.err) ||
          estimate_operator_sigma(&e->w, rt, m->classes[x->cy].n, &r[0]);
    size_t nx = 0;
    const double *xb =
        out == 0 && rt->est_theta ? full_get(e->w.f, ((const Sym *)m->prog->quantities.v[rt->est_theta_q])->name, &nx) : NULL;
    if (xb && (long)nx == rt->est_theta_n) r[1] = 1, memcpy(r + 2, xb, sizeof(double) * nx);
  }
  if (e->o->N > 1) dist_allreduce_sum(rec, e->nk * STREAM_REC); /* each sample's figures on one rank, 0 elsewhere */
  for (long j = 0; out == 0 && j < e->nk; j++) {
    memcpy(A, x->G + j * my * my, sizeof(double) * (size_t)(my * my));
    fold_record(rt, j, rec + j * STREAM_REC, A, my, sv);
  }
  scratch_release(&sc);
  return out;
}

/* Check x's rows summed over the ranks, the blockwise classes' columns multiplied by their signs, a whole
 * class's rows read from its basis; packed, the stage's check table. */
static int check_finish(EstStream *e, EstCheck *x, const double *const *sign) {
  Model *m = e->w.m;
  RInterp *ck = x->ck;
  RStage *rs = &m->stages[x->i];
  int cy = m->qclass[rs->q];
  long my = m->classes[cy].m, len = 0;
  for (long r = 0; r < ck->nreads; r++) len += m->classes[m->qclass[ck->read_q[r]]].m;
  if (e->o->N > 1) dist_allreduce_sum(ck->brows, ck->k * my), dist_allreduce_sum(ck->read_rows, len);
  for (long s = 0; s < ck->k; s++)
    for (long a = 0; a < my; a++) ck->brows[s * my + a] *= sign[cy][a];
  for (long r = 0; r < ck->nreads; r++) {
    const RClass *rc = &m->classes[m->qclass[ck->read_q[r]]];
    double *row = ck->read_rows + x->at[r];
    if (!e->o->st[m->qclass[ck->read_q[r]]].blockwise) {
      if (rc->m > 0) memcpy(row, rc->B + ck->read_e[r] * rc->m, sizeof(double) * (size_t)rc->m);
      continue;
    }
    for (long a = 0; a < rc->m; a++) row[a] *= sign[m->qclass[ck->read_q[r]]][a];
  }
  if (interp_pack(m, rs, ck)) return err_set(e->w.err, "out of memory for the check table of stage %s", rs->st->sym->name);
  interp_free(rs->check);
  rs->check = ck, x->ck = NULL;
  return 0;
}

int estimate_stream_finish(EstStream *e, const double *const *sign) {
  if (!e) return 0;
  int out = 0;
  for (int k = 0; out == 0 && k < e->nc; k++) out = check_finish(e, &e->check[k], sign);
  for (int q = 0; out == 0 && q < e->nt; q++)
    out = (e->o->N > 1 && combine_ranks(e, &e->term[q])) || store_table(e, &e->term[q], sign);
  cholmod_common cc;
  cholmod_l_start(&cc);
  e->w.cc = &cc;
  Scratch sc = SCRATCH_OF(e->w.err);
  double *rec = scratch_array(&sc, (size_t)(e->nk * STREAM_REC) + 1, sizeof(double));
  bool sigma = false;
  for (int q = 0; q < e->nt; q++) sigma |= e->term[q].sigma;
  if (!rec) out = -1;
  if (out == 0 && sigma) out = theta_detect(e);
  for (int q = 0; out == 0 && q < e->nt; q++) {
    if (!e->term[q].sigma) continue;
    memset(rec, 0, sizeof(double) * (size_t)(e->nk * STREAM_REC));
    out = sigma_ratio(e, &e->term[q], rec);
  }
  scratch_release(&sc);
  cholmod_l_finish(&cc);
  e->w.cc = NULL;
  return out;
}
