/* ooc.c — class bases out of core, by row blocks (DESIGN §11).
 *
 * When the bases themselves do not fit in --mem (radiosity's pair classes
 * at the paper's size: 25 M rows x 60 columns, 12 GB each), no snapshot
 * matrix and no basis is held whole. The large ("streamed") classes are cut
 * into blocks of rows; a pass over the samples evaluates on every sample
 * the rows of its blocks and what they read (the full program restricted
 * to them, demand.h; externs come from the trainer's cache) and keeps
 * those rows, all S samples of them, so every row-local
 * step of the in-memory PCA (pca_basis) runs on a block exactly as it
 * would on the whole:
 *
 *   factor passes μ_b = the block's sample mean, X_b − μ_b1ᵀ (centered
 *                 members), R ← the R of the QR of [R; X_b] (dtpqrt: a
 *                 tall-skinny QR, never the Gram matrix, whose squared
 *                 condition number stopped bases near 1e-8, issue 41);
 *                 the SVD of R gives W = V Σ⁻¹ with the same choice of k
 *                 (pca_choose), and X W the left singular vectors to
 *                 ε σ_max;
 *   basis passes  A_b = [μ_b, X_b W] per member (dgemm), written to an
 *                 unnamed file at its rows' offset, and folded into A's R
 *                 factor R_A (dtpqrt, as the factor passes);
 *   coefficients  each member's R from a QR of its columns of R_A, its
 *                 [μ, U] orthonormalized in order, and the class's members
 *                 merged (interleaved, in order, as pca_merge) all act on
 *                 A's columns through R_A (ooc_basis.c): B = A T with T
 *                 small, by the in-memory tolerances (a blockwise class:
 *                 OOC_BLOCKWISE_TOL);
 *   the basis     B = (A T) R_B⁻¹ block by block into another unnamed file
 *                 (R_B the TSQR of A T's rows, one sweep; then two that
 *                 decide the sign convention, pca_fix_signs), then mapped
 *                 read-only: pre-multiplication
 *                 and the extern fit read basis rows through rc->B as from
 *                 memory. Unless a stage may yet become interpolated (issue
 *                 30, Stream.blockwise): then A is never written, and a
 *                 third sweep forms each block's rows of B = A T and
 *                 pre-multiplies the tensors that read them at once
 *                 (stream.c); a class the model drops is never stored
 *                 (rc->B stays NULL), one it keeps (v's) has its rows
 *                 written to its basis file as they are formed, then mapped.
 *
 * Small classes keep their snapshots in memory (collected on the first
 * pass) and go through train_member_bases as in memory. A pass holds the
 * same fraction of every streamed class's rows: the number of passes is
 * about the streamed classes' snapshot bytes over the budget, plus one
 * factor and one basis pass at least.
 *
 * Over MPI ranks (opt->dist, N ranks) the rows are shared, not the
 * samples: every rank plans the same passes and takes those p ≡ rank
 * (mod N), evaluating every sample restricted to their rows (so every rank
 * needs every sample: src->share gives it them, the trainer's records sent
 * from the rank that keeps each; npgc train's data is read on every rank).
 * The whole evaluations (the small classes' snapshots, the SPD marks) are
 * divided by samples and the small snapshots gathered (whole_sweep); the
 * ranks' R factors (the members' and R_A) are gathered and folded in rank
 * order on every rank, so the SVDs and T are the same on
 * every rank; each rank's A file holds only its rows;
 * each rank writes its rows of B into one file all ranks open (basis_file),
 * the sign convention taken over all rows by two reductions; then every
 * rank maps the whole basis, and pre-multiplication and the extern fit run
 * as in memory over ranks.
 */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fcntl.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "dist.h"
#include "ooc.h"

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Whether pass p is this rank's. */
bool ooc_mine(const Ooc *o, long p) { return p % o->N == o->rank; }

/* Bytes of member bases at their caps. */
static size_t basis_bytes(const RClass *rc) {
  size_t cols = 0;
  for (int i = 0; i < rc->nmembers; i++) cols += (size_t)rc->members[i].cap;
  return sizeof(double) * (size_t)rc->n * cols;
}

bool ooc_needed(const Model *m, const TrainOptions *opt, long S) {
  if (!opt->user->mem || opt->user->joint || opt->full_rank) return false;
  size_t need = 0;
  for (int c = 0; c < m->nclasses; c++) need += basis_bytes(&m->classes[c]);
  /* weighted samples: out of core rather than by the method of snapshots, which does not take them */
  return need > opt->user->mem || (opt->weights && train_snapshot_bytes(m, S) > opt->user->mem);
}

/* Bytes a row of streamed class `rc` needs in a pass: every member's S
 * values, and its row of A. */
static size_t row_bytes(const RClass *rc, long S) {
  size_t b = 0;
  for (int i = 0; i < rc->nmembers; i++) b += sizeof(double) * ((size_t)S + (size_t)rc->members[i].cap + 1);
  return b;
}

/* Which classes stream (the largest, until the others' snapshots take at
 * most a quarter of the budget), and the passes' segments. */
static int plan(Ooc *o) {
  Model *m = o->t->m;
  long S = o->S;
  size_t small = 0, fixed = 0;
  for (int c = 0; c < m->nclasses; c++) small += sizeof(double) * (size_t)(m->classes[c].n * m->classes[c].nmembers) * (size_t)S;
  while (small > o->t->opt->user->mem / 4) {
    int big = -1;
    for (int c = 0; c < m->nclasses; c++)
      if (!o->st[c].streamed && (big < 0 || m->classes[c].n * m->classes[c].nmembers > m->classes[big].n * m->classes[big].nmembers))
        big = c;
    if (big < 0) break;
    o->st[big].streamed = true;
    small -= sizeof(double) * (size_t)(m->classes[big].n * m->classes[big].nmembers) * (size_t)S;
  }
  for (int c = 0; c < m->nclasses; c++)
    if (o->st[c].streamed) {
      long K = 0;
      for (int i = 0; i < m->classes[c].nmembers; i++) K += m->classes[c].members[i].cap + 1;
      fixed += sizeof(double) * (size_t)(2 * S * S * m->classes[c].nmembers + 2 * K * K);
    }
  fixed += small + sizeof(double) * (size_t)o->S * 4;
  o->fixed = fixed;
  o->avail = o->t->opt->user->mem > fixed ? o->t->opt->user->mem - fixed : 0;
  /* Pass p keeps the same fraction [p/P, (p+1)/P) of every streamed
   * class's rows: the pair classes number their rows alike, so a pass
   * demands the same entries of all of them, and each entry is computed
   * in one pass only. Rounding adds at most a row per class to a pass. */
  size_t total = 0, w = 0;
  long maxn = 0, nstreamed = 0;
  for (int c = 0; c < m->nclasses; c++)
    if (o->st[c].streamed && m->classes[c].n > 0) {
      total += row_bytes(&m->classes[c], S) * (size_t)m->classes[c].n;
      w += row_bytes(&m->classes[c], S);
      maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
      nstreamed++;
    }
  long P = o->avail > w ? (long)((total + (o->avail - w) - 1) / (o->avail - w)) : maxn; /* else a row at a time */
  if (P > maxn) P = maxn;
  if (P < 1) P = 1;
  o->seg = mem_calloc((size_t)(P * nstreamed) + 1, sizeof(Segment));
  o->first = mem_calloc((size_t)P + 2, sizeof(long));
  if (!o->seg || !o->first) return -1;
  o->npass = 0;
  for (long p = 0; p < P && nstreamed > 0; p++) {
    for (int c = 0; c < m->nclasses; c++) {
      long n = m->classes[c].n, r0 = n * p / P, r1 = n * (p + 1) / P;
      if (o->st[c].streamed && r1 > r0) o->seg[o->nseg++] = (Segment){c, r0, r1, NULL};
    }
    o->first[++o->npass] = o->nseg;
  }
  if (o->nseg == 0) o->npass = 1; /* no streamed class: one pass for the small ones */
  return 0;
}

/* The quantity whose rows member `mb` is: itself, or for an unnamed
 * numerator the stage it is the numerator of (its expression reads what
 * the numerator reads, at the same entries). */
const Sym *ooc_member_quantity(const Model *m, const RMember *mb) {
  return mb->q >= 0 ? m->prog->quantities.v[mb->q] : mb->joiner->stage->sym;
}

int ooc_member_rows(Ooc *o, const RMember *mb, long k, long n, const long rows[2], double *out) {
  long r0 = rows[0], r1 = rows[1];
  if (mb->q < 0) { /* an unnamed numerator: through its tensors, whole */
    if (train_member_value(o->t, mb, k, n, o->tmp)) return -1;
    memcpy(out, o->tmp + r0, sizeof(double) * (size_t)(r1 - r0));
    return 0;
  }
  const double *v = full_get(o->t->f, ((Sym *)o->t->m->prog->quantities.v[mb->q])->name, NULL);
  for (long e = r0; e < r1; e++)
    if (!isfinite(v[e])) /* the message naming where it arises */
      return train_member_value(o->t, mb, k, n, o->tmp)
                 ? -1
                 : err_set(o->t->err, "training sample %ld: %s is not finite", k, mb->name);
  memcpy(out, v + r0, sizeof(double) * (size_t)(r1 - r0));
  return 0;
}

/* Sample k evaluated whole: its SPD marks checked and the small classes'
 * snapshots taken. */
static int whole_sample(Ooc *o, long k) {
  Model *m = o->t->m;
  if (train_eval_sample(o->t->src, o->t->f, k, o->t->err) || train_check_spd(o->t, o->tmp)) return -1;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    for (int i = 0; !o->st[c].streamed && i < rc->nmembers; i++)
      if (train_member_value(o->t, &rc->members[i], k, rc->n, o->st[c].X[i] + (size_t)k * (size_t)rc->n))
        return -1;
  }
  return 0;
}

/* One pass: every sample evaluated, the rows of pass p's segments kept.
 * The first factor pass evaluates everything (it also takes the small
 * classes' snapshots and the SPD marks); every other pass evaluates only
 * the rows of its segments and what they read (full_eval_demand), so the
 * passes of a sweep together cost about one evaluation per sample. */
static int collect(Ooc *o, long p, bool gram) {
  Model *m = o->t->m;
  long S = o->S;
  bool whole = p == 0 && gram && o->N == 1; /* over ranks: whole_sweep */
  Demand *d = whole ? NULL : full_demand(o->t->f);
  if (!whole && !d) return err_set(o->t->err, "%s", full_error(o->t->f));
  size_t need = 0;
  for (long g = o->first[p]; g < o->first[p + 1]; g++)
    need += (size_t)(o->seg[g].r1 - o->seg[g].r0) * (size_t)S * (size_t)m->classes[o->seg[g].c].nmembers;
  if (need > o->block_cap) {
    free(o->block);
    if (!(o->block = mem_malloc(sizeof(double) * need))) return o->block_cap = 0, -1;
    o->block_cap = need;
  }
  double *next = o->block;
  for (long g = o->first[p]; g < o->first[p + 1]; g++) {
    Segment *sg = &o->seg[g];
    RClass *rc = &m->classes[sg->c];
    if (!(sg->H = mem_calloc((size_t)rc->nmembers, sizeof(double *)))) return -1;
    for (int i = 0; i < rc->nmembers; i++) {
      sg->H[i] = next;
      next += (size_t)(sg->r1 - sg->r0) * (size_t)S;
      if (d) demand_entries(d, ooc_member_quantity(m, &rc->members[i]), (size_t)sg->r0, (size_t)sg->r1);
    }
  }
  if (d && demand_propagate(d)) return err_set(o->t->err, "out of memory");
  const char *what = gram ? "snapshots (R factors, out of core)" : "snapshots (basis, out of core)";
  for (long k = 0; k < S; k++) {
    if (whole) {
      if (whole_sample(o, k)) return -1;
    } else if ((o->t->src->set_part ? o->t->src->set_part(o->t->src->user, o->t->f, k, d) : o->t->src->set(o->t->src->user, o->t->f, k)) ||
               full_eval_demand(o->t->f, k, d)) {
      return err_set(o->t->err, "%s", full_error(o->t->f));
    }
    for (long g = o->first[p]; g < o->first[p + 1]; g++) {
      Segment *sg = &o->seg[g];
      RClass *rc = &m->classes[sg->c];
      long R = sg->r1 - sg->r0;
      for (int i = 0; i < rc->nmembers; i++)
        if (ooc_member_rows(o, &rc->members[i], k, rc->n, (long[2]){sg->r0, sg->r1}, sg->H[i] + (size_t)k * (size_t)R))
          return -1;
    }
    /* this rank's passes: p / N of (npass − rank) / N, rounded up */
    progress_show(o->t->opt->user->progress, what, p / o->N * S + k + 1, (o->npass - o->rank + o->N - 1) / o->N * S);
  }
  return 0;
}

/* Over ranks, what the first factor pass does on one process, divided by
 * samples: rank r evaluates the samples k ≡ r (mod N) whole (the small
 * classes' snapshots, the SPD marks), then the small classes' columns are
 * gathered on every rank and the SPD marks combined. */
static int whole_sweep(Ooc *o) {
  Model *m = o->t->m;
  long S = o->S;
  for (long k = o->rank; k < S; k += o->N) {
    if (whole_sample(o, k)) return -1;
    if (train_fail_hook(o->t, k)) return -1;
    progress_show(o->t->opt->user->progress, "snapshots (whole, out of core)", k + 1, S);
  }
  double ***X = mem_calloc((size_t)m->nclasses + 1, sizeof(double **));
  if (!X) return err_set(o->t->err, "out of memory gathering the snapshots");
  for (int c = 0; c < m->nclasses; c++) X[c] = o->st[c].X;
  int rc = dist_gather_snapshots(m, X, S, o->t->err);
  free(X);
  if (rc == 0) dist_and_spd(m);
  return rc;
}

static void release(Ooc *o, long p) {
  for (long g = o->first[p]; g < o->first[p + 1]; g++) { /* the blocks stay in o->block for the next pass */
    free(o->seg[g].H);
    o->seg[g].H = NULL;
  }
}

/* Segment sg's rows of every member of its class folded into the member's R (TSQR), after
 * pca_basis's arithmetic row by row; H_b overwritten: it is not read again. */
static int fold_segment(Ooc *o, Segment *sg) {
  long S = o->S, R = sg->r1 - sg->r0;
  RClass *rc = &o->t->m->classes[sg->c];
  Scratch sc = SCRATCH_OF(o->t->err);
  double *mu = scratch_array_unzeroed(&sc, (size_t)R + 1, sizeof(double));
  int out = mu ? 0 : -1;
  for (int i = 0; out == 0 && i < rc->nmembers; i++) {
    pca_weigh(R, S, sg->H[i], o->t->opt->weights, rc->members[i].center ? mu : NULL);
    double big = o->st[sg->c].big[i]; /* the largest |entry| of what enters G (fmax's NaN rule, inlined) */
    for (size_t e = 0; e < (size_t)R * (size_t)S; e++) {
      double a = fabs(sg->H[i][e]);
      big = a > big ? a : big;
    }
    o->st[sg->c].big[i] = big;
    int info = pca_fold_rows(S, o->st[sg->c].G[i], R, sg->H[i], R); /* -1: its workspace (LAPACKE's -1 is the layout) */
    if (info != 0)
      out = err_set(o->t->err, "class %s, member %s: %s", rc->label, rc->members[i].name,
                    info == -1 ? "out of memory for the QR of a block of snapshots" : "the QR of a block of snapshots failed");
  }
  scratch_release(&sc);
  return out;
}

/* Factor passes: every streamed member's R (in G's place) the R of the QR
 * of [R; X_b], block by block (TSQR: never the Gram matrix, issue 41). */
static int gram_passes(Ooc *o) {
  long S = o->S;
  for (long p = 0; p < o->npass; p++) {
    if (!ooc_mine(o, p)) continue;
    if (collect(o, p, true)) return -1;
    for (long g = o->first[p]; g < o->first[p + 1]; g++)
      if (fold_segment(o, &o->seg[g])) return -1;
    release(o, p);
  }
  for (int c = 0; o->N > 1 && c < o->t->m->nclasses; c++) /* every rank's R gathered, folded alike on every rank */
    for (int i = 0; o->st[c].streamed && i < o->t->m->classes[c].nmembers; i++) {
      double *all = mem_calloc((size_t)(o->N * S * S) + 1, sizeof(double));
      if (!all) return err_set(o->t->err, "out of memory");
      memcpy(all + (size_t)o->rank * (size_t)(S * S), o->st[c].G[i], sizeof(double) * (size_t)(S * S));
      dist_allreduce_sum(all, o->N * S * S); /* each rank's slot from it alone: exact */
      int bad = pca_fold_r(S, o->N, all, o->st[c].G[i]);
      free(all);
      if (bad) return err_set(o->t->err, "the QR of the ranks' snapshot factors failed");
      dist_allreduce_max(&o->st[c].big[i], 1);
    }
  return 0;
}

/* Over ranks: every rank's K x K R factor R gathered and folded in rank
 * order alike on every rank (R replaced). 0, or -1 with o->t->err. */
static int fold_ranks(Ooc *o, long K, double *R) {
  double *all = mem_calloc((size_t)(o->N * K * K) + 1, sizeof(double));
  if (!all) return err_set(o->t->err, "out of memory");
  memcpy(all + (size_t)o->rank * (size_t)(K * K), R, sizeof(double) * (size_t)(K * K));
  dist_allreduce_sum(all, o->N * K * K); /* each rank's slot from it alone: exact */
  int bad = pca_fold_r(K, o->N, all, R);
  free(all);
  return bad ? err_set(o->t->err, "the QR of the ranks' basis factors failed") : 0;
}

/* Member i of class rc (streamed, st): its directions from its R factor (pca_r_basis), W = V Σ⁻¹ in G's
 * place (S x k column-major), k chosen and the member's report made as pca_core makes them. */
static int member_directions(Ooc *o, Stream *st, RClass *rc, int i) {
  long S = o->S;
  RMember *mb = &rc->members[i];
  int cap = mb->center ? (mb->cap > 1 ? mb->cap - 1 : 0) : mb->cap;
  long kmax = cap < S ? cap : S;
  Scratch sc = SCRATCH_OF(o->t->err);
  double *G = st->G[i], *W = scratch_array_unzeroed(&sc, (size_t)S * (size_t)(kmax ? kmax : 1), sizeof(double));
  /* snapshots whose squares leave the range of doubles: AᵀA below would lose them */
  double *Gd = scratch_array(&sc, (size_t)(S * S) + 1, sizeof(double)), *sv = scratch_adopt(&sc, mem_malloc(sizeof(double) * (size_t)S + 1));
  int out = W && Gd && sv ? 0 : err_set(o->t->err, "out of memory for the basis of class %s", rc->label);
  for (long j = 0; out == 0 && j < S; j++) Gd[j * S + j] = cblas_ddot((int)(j + 1), G + j * S, 1, G + j * S, 1);
  const char *range = out == 0 ? pca_gram_out_of_range(S, Gd, st->big[i]) : NULL;
  if (range)
    out = err_set(o->t->err,
                  "class %s, member %s: snapshot %s; rescale the data, or give --mem enough to keep the snapshots "
                  "in memory (their PCA is scale-invariant)",
                  rc->label, mb->name, range);
  double *s = st->s[i];
  long k = 0;
  int info = out == 0 ? pca_r_basis(S, G, &(PcaRule){.cap = cap, .energy = mb->energy}, s, W, &k) : 0;
  if (info != 0) /* -1: its workspace (LAPACKE's -1 is the layout) */
    out = info == -1 ? err_set(o->t->err, "class %s, member %s: out of memory for the SVD of the snapshots' R factor",
                               rc->label, mb->name)
                     : err_set(o->t->err, "class %s, member %s: the SVD of the snapshots' R factor failed (LAPACK info %d)",
                               rc->label, mb->name, (int)info);
  if (out == 0) {
    double total = 0, run = 0;
    for (long j = 0; j < S; j++) total += s[j] * s[j];
    for (long j = 0; j < k; j++) run += s[j] * s[j];
    mb->captured = total > 0 ? run / total : 1;
    mb->lost = fmax(0, 1 - mb->captured);
    free(mb->sv); /* replaced */
    memcpy(sv, s, sizeof(double) * (size_t)S);
    mb->sv = scratch_keep(&sc, sv), mb->nsv = S; /* the member's now */
    memcpy(G, W, sizeof(double) * (size_t)(k * S));
    st->k[i] = k;
    st->col[i] = st->K;
    st->K += k + (mb->center ? 1 : 0);
  }
  scratch_release(&sc);
  return out;
}

/* Every streamed member's directions from its R factor (pca_r_basis):
 * W = V Σ⁻¹ in G's place (S x k column-major), the choice of k and the
 * member's report as pca_core makes them. */
static int eigen(Ooc *o) {
  long S = o->S;
  for (int c = 0; c < o->t->m->nclasses; c++) {
    Stream *st = &o->st[c];
    RClass *rc = &o->t->m->classes[c];
    if (!st->streamed) continue;
    st->K = 0;
    for (int i = 0; i < rc->nmembers; i++)
      if (member_directions(o, st, rc, i)) return -1;
    if (!(st->RA = mem_calloc((size_t)(st->K * st->K) + 1, sizeof(double))))
      return err_set(o->t->err, "out of memory for the basis of class %s", rc->label);
    if (!st->blockwise && !(st->A = tmpfile()))
      return err_set(o->t->err, "cannot create a scratch file for the basis of class %s", rc->label);
    if (!rc->streamed) continue; /* the model keeps its basis: no floors to take */
    if (!(st->AX = calloc((size_t)rc->nmembers, sizeof(double *))) || !(st->yy = calloc((size_t)rc->nmembers, sizeof(double *))))
      return err_set(o->t->err, "out of memory");
    for (int i = 0; i < rc->nmembers; i++)
      if (rc->members[i].q >= 0 && (!(st->AX[i] = calloc((size_t)(st->K * S) + 1, sizeof(double))) ||
                                    !(st->yy[i] = calloc((size_t)S, sizeof(double)))))
        return err_set(o->t->err, "out of memory");
  }
  return 0;
}

int ooc_write_at(FILE *fp, const void *p, size_t bytes, size_t off) {
  const char *c = p;
  while (bytes > 0) {
    ssize_t w = pwrite(fileno(fp), c, bytes, (off_t)off);
    if (w <= 0) return -1;
    c += w, bytes -= (size_t)w, off += (size_t)w;
  }
  return 0;
}

int ooc_read_at(FILE *fp, void *p, size_t bytes, size_t off) {
  char *c = p;
  while (bytes > 0) {
    ssize_t r = pread(fileno(fp), c, bytes, (off_t)off);
    if (r <= 0) return -1;
    c += r, bytes -= (size_t)r, off += (size_t)r;
  }
  return 0;
}

/* A segment's share of the training floors (Stream.AX, yy): for every
 * quantity member, AX += A_bᵀX_b and yy_k += ‖X_b(:, k)‖², X_b the block's
 * snapshots as they were (a centered member's block is held centered, its
 * mean μ_b in A's column col[i]: X_b = H_b + μ_b1ᵀ; weighted, its columns
 * are first divided by √w_k back). */
static int floor_products(Ooc *o, const Segment *sg, const double *A, long K) {
  Stream *st = &o->st[sg->c];
  RClass *rc = &o->t->m->classes[sg->c];
  long R = sg->r1 - sg->r0, S = o->S;
  double *Amu = malloc(sizeof(double) * (size_t)(K + 1));
  if (!Amu) return err_set(o->t->err, "out of memory");
  for (int i = 0; i < rc->nmembers; i++) {
    if (rc->members[i].q < 0 || K == 0) continue;
    bool centered = rc->members[i].center;
    const double *mu = A + st->col[i], *w = o->t->opt->weights;
    for (long k = 0; w && k < S; k++) cblas_dscal((int)R, 1 / sqrt(w[k]), sg->H[i] + k * R, 1);
    cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, (int)K, (int)S, (int)R, 1.0, A, (int)K, sg->H[i], (int)R,
                1.0, st->AX[i], (int)K);
    if (centered) { /* + (A_bᵀμ_b)1ᵀ */
      cblas_dgemv(CblasColMajor, CblasNoTrans, (int)K, (int)R, 1.0, A, (int)K, mu, (int)K, 0.0, Amu, 1);
      for (long k = 0; k < S; k++) cblas_daxpy((int)K, 1.0, Amu, 1, st->AX[i] + k * K, 1);
    }
    for (long k = 0; k < S; k++) {
      double t = 0;
      for (long e = 0; e < R; e++) {
        double v = sg->H[i][k * R + e] + (centered ? mu[e * K] : 0);
        t += v * v;
      }
      st->yy[i][k] += t;
    }
  }
  free(Amu);
  return 0;
}

/* The training floors of streamed class `c` once its T is final (signs
 * included): per quantity member the mean over the samples of
 * sqrt(max(0, ‖y_k‖² − ‖Tᵀ(AᵀX)_k‖²)/‖y_k‖²). The difference of two
 * squares resolves a floor only down to about 1e-7 (√ε times the
 * rounding of the sums; below it, the figure is rounding: 7.7e-8 measured for
 * a floor of 5e-14); the L∞ floor would need the residual itself and is
 * left NaN (not measured). */
static int take_floors(Ooc *o, int c, const double *T, long m) {
  Stream *st = &o->st[c];
  RClass *rc = &o->t->m->classes[c];
  long K = st->K, S = o->S;
  double *P = malloc(sizeof(double) * (size_t)(m * S + 1));
  if (!P) return err_set(o->t->err, "out of memory");
  for (int i = 0; i < rc->nmembers; i++) {
    RMember *mb = &rc->members[i];
    if (mb->q < 0) continue;
    if (m > 0 && K > 0)
      cblas_dgemm(CblasColMajor, CblasTrans, CblasNoTrans, (int)m, (int)S, (int)K, 1.0, T, (int)K, st->AX[i], (int)K, 0.0,
                  P, (int)m);
    double sum = 0;
    for (long k = 0; k < S; k++) {
      double p2 = m > 0 && K > 0 ? cblas_ddot((int)m, P + k * m, 1, P + k * m, 1) : 0, y2 = st->yy[i][k];
      sum += y2 > 0 ? sqrt(fmax(0, y2 - p2) / y2) : 0;
    }
    mb->floor_l2 = sum / (double)S;
    mb->floor_linf = NAN;
  }
  rc->floors_known = true;
  free(P);
  return 0;
}

/* Basis passes: A_b = [μ_b, X_b W] per member, written at its rows, and
 * folded into A's R factor R_A. */
static int basis_passes(Ooc *o) {
  long S = o->S;
  for (long p = 0; p < o->npass && o->nseg > 0; p++) {
    if (!ooc_mine(o, p)) continue;
    if (collect(o, p, false)) return -1;
    for (long g = o->first[p]; g < o->first[p + 1]; g++) {
      Segment *sg = &o->seg[g];
      Stream *st = &o->st[sg->c];
      RClass *rc = &o->t->m->classes[sg->c];
      long R = sg->r1 - sg->r0, K = st->K;
      size_t need = 2 * (size_t)(R * K) + (size_t)R + 1; /* A, mu, Aᵀ: kept from pass to pass as the blocks are */
      if (need > o->abuf_cap) {
        free(o->abuf);
        if (!(o->abuf = mem_malloc(sizeof(double) * need))) return o->abuf_cap = 0, -1;
        o->abuf_cap = need;
      }
      double *A = o->abuf, *mu = o->abuf + R * K, *At = mu + R;
      memset(A, 0, sizeof(double) * (size_t)(R * K));
      for (int i = 0; i < rc->nmembers; i++) {
        long col = st->col[i];
        pca_weigh(R, S, sg->H[i], o->t->opt->weights, rc->members[i].center ? mu : NULL);
        if (rc->members[i].center) {
          for (long e = 0; e < R; e++) A[e * K + col] = mu[e];
          col++;
        }
        if (st->k[i] > 0)
          cblas_dgemm(CblasRowMajor, CblasTrans, CblasTrans, (int)R, (int)st->k[i], (int)S, 1.0, sg->H[i], (int)R,
                      st->G[i], (int)S, 0.0, A + col, (int)K);
      }
      for (long e = 0; e < R; e++) /* the block's rows folded into A's R factor (TSQR), from a column-major copy */
        for (long j = 0; j < K; j++) At[j * R + e] = A[e * K + j];
      int info = K > 0 ? pca_fold_rows(K, st->RA, R, At, R) : 0; /* -1: its workspace */
      if (info != 0)
        return err_set(o->t->err, "class %s: %s a block of its basis rows", rc->label,
                       info == -1 ? "out of memory for the QR of" : "the QR failed on");
      if (st->AX && floor_products(o, sg, A, K)) return -1;
      int bad = !st->blockwise && ooc_write_at(st->A, A, sizeof(double) * (size_t)(R * K), sizeof(double) * (size_t)(sg->r0 * K));
      if (bad) return err_set(o->t->err, "cannot write the scratch file of class %s (disk full?)", rc->label);
    }
    release(o, p);
  }
  for (int c = 0; o->N > 1 && c < o->t->m->nclasses; c++) /* every rank's rows summed */
    if (o->st[c].streamed) {
      if (fold_ranks(o, o->st[c].K, o->st[c].RA)) return -1;
      for (int i = 0; o->st[c].AX && i < o->t->m->classes[c].nmembers; i++)
        if (o->st[c].AX[i]) dist_allreduce_sum(o->st[c].AX[i], o->st[c].K * S), dist_allreduce_sum(o->st[c].yy[i], S);
    }
  return 0;
}

/* The file of a class basis, `bytes` long: one process, an unnamed file;
 * over ranks a file every rank opens (rank 0 creates it as
 * PREFIX.ooc.XXXXXX, opt->shared_prefix, sizes it and unlinks it once every
 * rank has it open, so no name outlives the step). NULL with o->t->err. */
FILE *ooc_basis_file(Ooc *o, const RClass *rc, size_t bytes) {
  if (o->N == 1) {
    FILE *fp = tmpfile();
    if (fp && ftruncate(fileno(fp), (off_t)bytes) == 0) return fp;
    if (fp) fclose(fp);
    err_set(o->t->err, "cannot create the file of the basis of class %s (%.3g GB)", rc->label, (double)bytes / 1e9);
    return NULL;
  }
  char path[4096] = "";
  int fd = -1;
  if (o->rank == 0) {
    const char *tmp = getenv("TMPDIR");
    if (o->t->opt->shared_prefix) snprintf(path, sizeof path, "%s.ooc.XXXXXX", o->t->opt->shared_prefix);
    else snprintf(path, sizeof path, "%s/npg.ooc.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if ((fd = mkstemp(path)) < 0 || ftruncate(fd, (off_t)bytes) != 0) path[0] = 0;
  }
  dist_broadcast_bytes(path, sizeof path, 0); /* "" when rank 0 could not: every rank fails alike */
  if (o->rank != 0 && path[0]) fd = open(path, O_RDWR);
  double opened = fd >= 0;
  dist_allreduce_sum(&opened, 1);
  if (o->rank == 0 && path[0]) unlink(path); /* every rank that could has it open */
  FILE *fp = fd >= 0 ? fdopen(fd, "r+") : NULL;
  if (opened == o->N && fp) return fp;
  if (fp) fclose(fp);
  else if (fd >= 0) close(fd);
  err_set(o->t->err, "cannot create or open the shared file of the basis of class %s (%.3g GB) next to %s", rc->label,
          (double)bytes / 1e9, o->t->opt->shared_prefix ? o->t->opt->shared_prefix : "$TMPDIR/npg");
  return NULL;
}

/* The rows of class `c` this rank forms: its passes' segments (one
 * process: all rows, in one range). Ranges into r[2·j], r[2·j + 1]; their
 * number. */
static long own_rows(const Ooc *o, int c, long *r) {
  long nr = 0;
  if (o->N == 1) {
    r[0] = 0, r[1] = o->t->m->classes[c].n;
    return 1;
  }
  for (long p = 0; p < o->npass; p++)
    for (long g = o->first[p]; ooc_mine(o, p) && g < o->first[p + 1]; g++)
      if (o->seg[g].c == c) r[2 * nr] = o->seg[g].r0, r[2 * nr + 1] = o->seg[g].r1, nr++;
  return nr;
}

/* B = A T, this rank's rows block by block, into the class's basis file,
 * then the whole file mapped read-only on every rank. A T is orthonormal
 * in exact arithmetic, but a column kept for a small remainder ρ (down to
 * PCA_MERGE_TOL) is a difference of nearly equal columns of A, formed to
 * ε/ρ only: the rows of A T are folded into its R factor R_B first (over
 * the ranks too), and B = (A T) R_B⁻¹, orthonormal to rounding as the
 * in-memory Gram–Schmidt's vectors are. */
static int write_basis(Ooc *o, int c, double *T, long m) {
  Stream *st = &o->st[c];
  RClass *rc = &o->t->m->classes[c];
  long n = rc->n, K = st->K;
  rc->m = m;
  if (m == 0) return 0; /* train_complete_basis gives it one direction */
  size_t bytes = sizeof(double) * (size_t)n * (size_t)m;
  FILE *fp = ooc_basis_file(o, rc, bytes);
  if (!fp) return -1;
  long rows = (long)(o->avail / (sizeof(double) * (size_t)(K + m)));
  if (rows < 1) rows = 1;
  if (rows > n) rows = n;
  Scratch sc = SCRATCH_OF(o->t->err);
  double *A = scratch_array_unzeroed(&sc, (size_t)(rows * K) + 1, sizeof(double)),
         *B = scratch_array_unzeroed(&sc, (size_t)(rows * m), sizeof(double));
  double *big = scratch_array(&sc, (size_t)m, sizeof(double)), *first = scratch_array_unzeroed(&sc, (size_t)m, sizeof(double));
  double *RB = scratch_array(&sc, (size_t)(m * m), sizeof(double)),
         *Bt = scratch_array_unzeroed(&sc, (size_t)(rows * m), sizeof(double));
  int *flip = scratch_array(&sc, (size_t)m, sizeof(int));
  long *range = scratch_array_unzeroed(&sc, (size_t)(2 * o->npass + 2), sizeof(long)), nr = range ? own_rows(o, c, range) : 0;
  int bad = !A || !B || !big || !first || !range || !RB || !Bt || !flip ? -1 : 0; /* the scratch said so */
  for (long j = 0; !bad && j < m; j++) first[j] = -HUGE_VAL;
  /* four sweeps over this rank's rows of A: R_B (the TSQR of A T's rows), the largest
   * magnitude of every column of B = (A T) R_B⁻¹ (the largest over the ranks), the sign
   * convention (pca_fix_signs: the sign of the first row, over all ranks, whose entry is at
   * least PCA_SIGN_FRACTION of that; as −(2·row + negative), the largest over the ranks is the first row), then
   * B written */
  for (int sweep = 0; sweep < 4 && !bad; sweep++) {
    if (sweep == 1) {
      if (o->N > 1 && fold_ranks(o, m, RB)) {
        bad = -1;
        break;
      }
      for (long j = 0; j < m; j++) /* positive diagonal: B's columns keep A T's orientation */
        if (RB[j * m + j] < 0)
          for (long i = j; i < m; i++) RB[i * m + j] = -RB[i * m + j];
    }
    if (sweep == 2) dist_allreduce_max(big, m);
    if (sweep == 3) {
      dist_allreduce_max(first, m);
      for (long j = 0; j < m; j++)
        flip[j] = first[j] > -HUGE_VAL && fmod(-first[j], 2) == 1;
    }
    for (long q = 0; !bad && q < nr; q++)
      for (long r0 = range[2 * q]; !bad && r0 < range[2 * q + 1]; r0 += rows) {
        long R = r0 + rows < range[2 * q + 1] ? rows : range[2 * q + 1] - r0;
        bad = ooc_read_at(st->A, A, sizeof(double) * (size_t)(R * K), sizeof(double) * (size_t)(r0 * K));
        if (bad) break;
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)R, (int)m, (int)K, 1.0, A, (int)K, T, (int)K, 0.0, B,
                    (int)m);
        if (sweep == 0) {
          for (long e = 0; e < R; e++)
            for (long j = 0; j < m; j++) Bt[j * R + e] = B[e * m + j];
          if (pca_fold_rows(m, RB, R, Bt, R) != 0) /* -1: its workspace */
            bad = err_set(o->t->err, "class %s: out of memory (or LAPACK failed) in the QR of its basis rows", rc->label);
          continue;
        }
        cblas_dtrsm(CblasColMajor, CblasLeft, CblasUpper, CblasTrans, CblasNonUnit, (int)m, (int)R, 1.0, RB, (int)m, B,
                    (int)m);
        for (long e = 0; sweep == 3 && e < R; e++)
          for (long j = 0; j < m; j++)
            if (flip[j]) B[e * m + j] = -B[e * m + j];
        for (long e = 0; sweep < 3 && e < R; e++)
          for (long j = 0; j < m; j++) {
            double v = B[e * m + j];
            if (sweep == 1) big[j] = fmax(big[j], fabs(v));
            else if (first[j] == -HUGE_VAL && big[j] > 0 && fabs(v) >= PCA_SIGN_FRACTION * big[j])
              first[j] = -(2.0 * (double)(r0 + e) + (v > 0 ? 0 : 1));
          }
        if (sweep == 3) bad = ooc_write_at(fp, B, sizeof(double) * (size_t)(R * m), sizeof(double) * (size_t)(r0 * m));
      }
  }
  for (long j = 0; !bad && j < m; j++) /* T's columns signed as B's (the floors read B as A T) */
    if (flip[j]) cblas_dscal((int)K, -1.0, (double *)T + j * K, 1);
  scratch_release(&sc);
  return ooc_map_basis(o, rc, fp, bad);
}

int ooc_map_basis(Ooc *o, RClass *rc, FILE *fp, int bad) {
  size_t bytes = sizeof(double) * (size_t)rc->n * (size_t)rc->m;
  /* every rank's rows written (a rank that failed ends the job before it) */
  double ok = !bad;
  dist_allreduce_sum(&ok, 1);
  void *map = ok == o->N ? mmap(NULL, bytes, PROT_READ, MAP_SHARED, fileno(fp), 0) : MAP_FAILED;
  fclose(fp); /* the mapping keeps the file */
  if (map == MAP_FAILED) /* the failure's own message when its maker gave one */
    return err_held(o->t->err) ? -1
                               : err_set(o->t->err, "cannot write or map the basis of class %s (%.3g GB; disk full?)",
                                         rc->label, (double)bytes / 1e9);
  free(rc->B);
  rc->B = map;
  rc->B_mapped = bytes;
  return 0;
}

static void ooc_free(Ooc *o) {
  for (int c = 0; o->st && c < o->t->m->nclasses; c++) {
    Stream *st = &o->st[c];
    for (int i = 0; i < o->t->m->classes[c].nmembers; i++) {
      if (st->X) free(st->X[i]);
      if (st->G) free(st->G[i]);
      if (st->s) free(st->s[i]);
    }
    for (int i = 0; i < o->t->m->classes[c].nmembers; i++) {
      if (st->AX) free(st->AX[i]);
      if (st->yy) free(st->yy[i]);
    }
    free(st->AX), free(st->yy);
    free(st->X), free(st->G), free(st->s), free(st->k), free(st->big), free(st->col), free(st->RA), free(st->T);
    if (st->A) fclose(st->A);
  }
  for (long p = 0; o->seg && p < o->npass; p++) release(o, p);
  free(o->st), free(o->seg), free(o->first), free(o->tmp), free(o->block), free(o->abuf);
}

/* Every class's state for the passes: the plan, the small classes' snapshots, the streamed ones' R
 * factors and singular values. 0, or -1 with "out of memory planning". */
static int ooc_setup(Ooc *o) {
  Model *m = o->t->m;
  long maxn = 1;
  for (int c = 0; c < m->nclasses; c++) maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
  int bad = !(o->st = mem_calloc((size_t)m->nclasses, sizeof(Stream))) || !(o->tmp = mem_malloc(sizeof(double) * (size_t)maxn)) ||
            plan(o);
  for (int c = 0; !bad && c < m->nclasses; c++) {
    Stream *st = &o->st[c];
    int r = m->classes[c].nmembers;
    if (!st->streamed) {
      bad = !(st->X = mem_calloc((size_t)r, sizeof(double *)));
      for (int i = 0; !bad && i < r; i++) bad = !(st->X[i] = mem_malloc(sizeof(double) * (size_t)m->classes[c].n * (size_t)o->S));
      continue;
    }
    bad = !(st->G = mem_calloc((size_t)r, sizeof(double *))) || !(st->s = mem_calloc((size_t)r, sizeof(double *))) ||
          !(st->k = mem_calloc((size_t)r, sizeof(long))) || !(st->big = mem_calloc((size_t)r, sizeof(double))) ||
          !(st->col = mem_calloc((size_t)r, sizeof(long)));
    for (int i = 0; !bad && i < r; i++)
      bad = !(st->G[i] = mem_calloc((size_t)(o->S * o->S), sizeof(double))) || !(st->s[i] = mem_malloc(sizeof(double) * (size_t)o->S));
  }
  return bad ? err_set(o->t->err, "out of memory planning out-of-core training (--mem %.3g GB)", (double)o->t->opt->user->mem / 1e9)
             : 0;
}

/* The plan on stderr (--progress): the classes streamed, the passes, and when --mem leaves no rows for a pass. */
static void report_plan(const Ooc *o) {
  const Model *m = o->t->m;
  const TrainOptions *opt = o->t->opt;
  if (!opt->user->progress) return;
  int streamed = 0;
  for (int c = 0; c < m->nclasses; c++) streamed += o->st[c].streamed;
  fprintf(stderr, "out of core: %d of %d classes streamed by rows, %ld passes over the %ld samples for the R "
          "factors (a QR by row blocks) and as many for the bases (--mem %.3g GB, %.3g GB for the rows of a pass)\n",
          streamed, m->nclasses, o->npass, o->S, (double)opt->user->mem / 1e9, (double)o->avail / 1e9);
  if (o->avail == 0) /* the passes run a row at a time: say why, and what would help */
    fprintf(stderr, "out of core: --mem leaves nothing for the rows of a pass (the R factors of the %ld samples "
            "and the small classes' snapshots need %.3g MB of it), so each pass keeps one row of each streamed class; raise "
            "--mem for fewer passes\n", o->S, (double)o->fixed / 1e6);
}

/* Every class's basis from the passes' results: a small class's from its snapshots, a streamed one's
 * written to its file, or (blockwise) its T kept for stream_premultiply. */
static int class_bases(Ooc *o) {
  Model *m = o->t->m;
  Err *err = o->t->err;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rcl = &m->classes[c];
    if (!o->st[c].streamed) {
      if (train_member_bases(rcl, o->S, o->st[c].X, o->t->opt->weights, NULL, err)) return -1;
    } else {
      double *T = NULL;
      long mm = 0;
      Stream *st = &o->st[c];
      if (ooc_coefficients(o, c, &T, &mm)) return -1;
      if (st->blockwise && mm == 0) st->blockwise = false; /* train_complete_basis gives it one direction */
      if (!st->blockwise && rcl->coef_S > 0) rcl->streamed = false, rcl->coef_S = 0; /* kept as a basis after all */
      /* the floors need only ‖Tᵀ(AᵀX)‖, whatever the columns' signs */
      int bad = (!st->blockwise && write_basis(o, c, T, mm)) || (st->AX && take_floors(o, c, T, mm));
      if (st->blockwise) st->T = T, st->m = rcl->m = mm; /* its basis formed block by block: stream_premultiply */
      else free(T);
      if (bad) return -1;
      if (st->blockwise) continue;
    }
    if (train_complete_basis(rcl, false, err)) return -1;
  }
  return 0;
}

/* The passes, the bases and the streamed pre-multiplication, timed. */
static int ooc_run(Ooc *o) {
  Model *m = o->t->m;
  const TrainOptions *opt = o->t->opt;
  const SampleSource *src = o->t->src;
  report_plan(o);
  for (int c = 0; c < m->nclasses; c++) o->st[c].blockwise = stream_blockwise(o, c);
  /* an extern's pair class formed block by block: kept as coefficients of its training values, its
   * basis never whole (issue 30: radiosity's v, 12 GB at the paper's size) */
  for (int c = 0; c < m->nclasses; c++)
    if (o->st[c].blockwise && !m->classes[c].streamed && !train_keeps_basis(m, opt, c) && model_class_by_coefficients(m, c))
      m->classes[c].streamed = true, m->classes[c].coef_S = o->S;
  train_mark_spd(m);
  double t[6] = {now()};
  /* over ranks every rank's passes evaluate every sample */
  if (o->N > 1 && ((src->share && src->share(src->user, o->t->err)) || whole_sweep(o))) return -1;
  t[1] = now();
  if (gram_passes(o)) return -1;
  t[2] = now();
  if (eigen(o) || basis_passes(o)) return -1;
  t[3] = now();
  if (class_bases(o)) return -1;
  model_size_tensors(m);
  t[4] = now();
  if (stream_premultiply(o)) return -1;
  t[5] = now();
  if (opt->user->progress)
    fprintf(stderr, "out of core: %.2f s samples shared and whole evaluations (over ranks), %.2f s R-factor passes, %.2f s "
            "basis passes, %.2f s bases, %.2f s streamed pre-multiplication\n", t[1] - t[0], t[2] - t[1], t[3] - t[2],
            t[4] - t[3], t[5] - t[4]);
  return 0;
}

int ooc_bases(Train *tr) {
  Ooc o = {.t = tr, .S = tr->src->count, .N = 1};
  if (tr->opt->dist) o.rank = dist_rank(), o.N = dist_size();
  int rc = ooc_setup(&o) || ooc_run(&o) ? -1 : 0;
  if (rc) err_set_first(tr->err, "out of memory in out-of-core training (--mem %.3g GB)", (double)tr->opt->user->mem / 1e9);
  ooc_free(&o);
  return rc;
}
