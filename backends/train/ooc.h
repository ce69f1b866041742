/* ooc.h — the state of out-of-core training (ooc.c), shared with the
 * streamed pre-multiplication (stream.c) that runs on it before it is freed. */
#ifndef NPG_OOC_H
#define NPG_OOC_H

#include <stdio.h>

#include "scratch.h"
#include "train_steps.h"

/* Rows [r0, r1) of streamed class c, collected in one pass. */
typedef struct Segment {
  int c;
  long r0, r1;
  double **H;               /* per member: (r1 − r0) x S column-major, the rows of every sample */
} Segment;

typedef struct Stream {
  bool streamed;
  double **X;               /* small class: per member n x S column-major */
  double **G;               /* streamed: per member S x S column-major (upper), the R factor of its centered
                               snapshots (pca_fold_rows), then W = V Σ⁻¹ (S x k) */
  double **s;               /* per member: singular values, descending (S) */
  long *k;                  /* per member: directions kept from its R factor */
  double *big;              /* per member: its largest |snapshot entry| (squares underflowing to 0 leave G 0) */
  long *col;                /* per member: its first column of A (μ when centered, then k directions) */
  long K;                   /* columns of A */
  double *RA;               /* K x K column-major (upper): the R factor of A (pca_fold_rows of its row blocks) */
  FILE *A;                  /* A: n x K row-major, in an unnamed file */
  /* the training floors of a class whose basis the model drops (RClass.streamed, issue 30), from
   * the basis passes: per member AᵀX (K x S column-major) and every sample's ‖y_k‖² (S), so that
   * BᵀX = Tᵀ(AᵀX) and ‖y_k − BBᵀy_k‖² = ‖y_k‖² − ‖Bᵀy_k‖² need neither the basis nor another pass */
  double **AX, **yy;
  /* a class whose basis is formed block by block and used at once (stream.c, issue 30): A is not
   * kept either; the basis is B = A T, T here, its columns' signs fixed on the tensors at the end */
  bool blockwise;
  double *T;                /* K x m column-major */
  long m;
} Stream;

typedef struct Ooc {
  Train *t;                 /* the training: its model, evaluator, samples, options and error record */
  long S;
  Stream *st;
  Segment *seg;
  long nseg;
  long *first;              /* pass p collects segments [first[p], first[p + 1]) */
  long npass;
  size_t avail;             /* bytes for the blocks of one pass */
  double *tmp;              /* one member value */
  size_t fixed;             /* bytes of the Gram matrices, the small classes and the sample scratch */
  int rank, N;              /* over ranks (opt->dist): this rank takes the passes p ≡ rank (mod N) */
  /* the blocks of the pass being collected, and a basis pass's A and
   * mean, kept from pass to pass: allocated afresh, every pass paid page
   * faults on them (measured over MPI ranks, bench/mpi.md) */
  double *block, *abuf;
  size_t block_cap, abuf_cap;
} Ooc;

/* Whether pass p is this rank's. */
bool ooc_mine(const Ooc *o, long p);
/* The quantity whose rows member `mb` is: itself, or for an unnamed
 * numerator the stage it is the numerator of. */
const Sym *ooc_member_quantity(const Model *m, const RMember *mb);
/* Rows rows[0] <= r < rows[1] of member `mb` (of a class of n rows) after
 * evaluating sample k (restricted to a demand holding them), into out. 0,
 * or -1 with o->t->err. */
int ooc_member_rows(Ooc *o, const RMember *mb, long k, long n, const long rows[2], double *out);
/* pwrite / pread of `bytes` at offset `off` of fp, whole: 0, or -1. */
int ooc_write_at(FILE *fp, const void *p, size_t bytes, size_t off);
int ooc_read_at(FILE *fp, void *p, size_t bytes, size_t off);
/* The file of a class basis, `bytes` long, unnamed (over ranks: one file
 * every rank opens, a collective). NULL with o->t->err. */
FILE *ooc_basis_file(Ooc *o, const RClass *rc, size_t bytes);
/* Class rc's basis file (rc->n x rc->m, every rank's rows written unless
 * `bad` on some rank) mapped read-only as rc->B on every rank, fp closed (a
 * collective). 0, or -1 with o->t->err. */
int ooc_map_basis(Ooc *o, RClass *rc, FILE *fp, int bad);

/* ---------------------------------------------------------------- streamed pre-multiplication (stream.c) */

/* Whether class c's basis can be formed block by block and used at once
 * (Stream.blockwise): streamed by rows out of core, no stage may yet be
 * interpolated (which reads bases outside the tensors, and may make a
 * dropped class needed) and no projection B_yᵀB_w reads it. */
bool stream_blockwise(const Ooc *o, int c);
/* Every tensor that reads a blockwise class's basis, pre-multiplied by
 * passes over row blocks (t->data set; the others are left NULL for
 * train_premultiply_all); a blockwise class the model keeps (not
 * RClass.streamed) gets its basis file, mapped as rc->B. 0, or -1 with o->t->err. */
int stream_premultiply(Ooc *o);

/* Rows [r0, r1) of a class of n rows at the fraction [u/U, (u+1)/U) the sweep's block u of U
 * takes (of every class the same fraction: the blocks partition each class's rows). */
void stream_fraction(long n, long u, long U, long *r0, long *r1);
/* The signs of term rt's residual columns (estimate_term_columns's D, into cs) given each
 * class's column signs (sign[c] NULL: +1; cy the stage's class): a numerator tensor's columns
 * those of its inputs' packed products, an operator tensor's a of the output times them. 0, or
 * -1 when `sc` runs out of memory. */
int stream_column_signs(const Ooc *o, const RTerm *rt, int cy, const double *const *sign, double *cs, Scratch *sc);

/* ---------------------------------------------------------------- the estimate tables of the streamed (estimate_stream.c) */

/* The online estimate's tables of the terms that read a basis never whole (a class the model
 * drops, formed block by block: residual tables by a tall-skinny QR over the blocks, an inverse
 * term's σ_min ratio from B_yᵀM_kB_y summed over them), made along stream_premultiply's sweep. */
typedef struct EstStream EstStream;
/* *out NULL when no term needs it. 0, or -1 with o->t->err (*out then for estimate_stream_free). */
int estimate_stream_begin(Ooc *o, EstStream **out);
/* A block's demand: the whole of an operator's inputs whose rows are not held by the block. */
void estimate_stream_demand(const EstStream *e, Demand *d);
/* After sample k's evaluation restricted to block u of U: a picked sample's operator entries kept. */
int estimate_stream_sample(EstStream *e, long k, long u, long U);
/* Once block u of U's basis rows are formed (per class B[c] through map[c], NULL: whole): its
 * rows of each term's columns factored into its R, its operators' entries reduced. */
int estimate_stream_block(EstStream *e, const double *const *B, const RowMap *const *map, long u, long U);
/* After every block and the columns' signs (per class, NULL: +1): every term's table set in the
 * model (rt->est_G; an inverse term of a dropped class its est_sigma, from whole evaluations of
 * the picked samples). 0, or -1 with o->t->err. */
int estimate_stream_finish(EstStream *e, const double *const *sign);
void estimate_stream_free(EstStream *e);

/* A class formed block by block and used at once (Stream.blockwise) has
 * no sweep to take B's R factor (write_basis): B = A T is orthonormal only
 * to ε/ρ for a column kept at a remainder ρ, so its columns are kept at
 * remainders above this fraction, as before the in-memory rules applied. */
#define OOC_BLOCKWISE_TOL 1e-6

/* ooc_basis.c: T (K x *m column-major, malloc'd) with class c's basis
 * B = A T, its members orthonormalized, put in order and merged through
 * A's R factor (A = Q_A R_A: ⟨A x, A y⟩ = ⟨R_A x, R_A y⟩, norms of
 * remainders to rounding as from the vectors themselves), by the
 * in-memory rules (PCA_DEPENDENT_TOL, PCA_MERGE_TOL; a blockwise class
 * OOC_BLOCKWISE_TOL). 0, or -1 with o->t->err. */
int ooc_coefficients(Ooc *o, int c, double **Tout, long *mout);

#endif
