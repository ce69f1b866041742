/* product.c — a class basis orthonormal in the inner product of an SPD
 * operator of the program (issue 41; `basis u: product K0`, --basis
 * u:product=K0; pyMOR's H¹ product). A transform around the PCA (pca.c,
 * unchanged):
 *
 *     K0 = Pᵀ L Lᵀ P            (CHOLMOD, simplicial LLᵀ, P its fill-reducing order)
 *     Y  = Lᵀ P X               (the snapshots weighted: ‖Y_k‖ = ‖X_k‖_K0)
 *     V  = PCA of Y             (train_member_bases: per member, merged; VᵀV = I)
 *     B  = Pᵀ L⁻ᵀ V             so that BᵀK0B = VᵀV = I
 *     D  = K0 B                 the dual: Dᵀx = BᵀK0x, the coordinates of x's
 *                               K0-orthogonal projection B Bᵀ K0 x onto span B
 *
 * Energies, spectra and truncation are those of the weighted snapshots (the
 * K0-norm). The snapshots need to be in memory (one process, --merge concat):
 * the other paths are refused by the caller (train.c, build_bases).
 *
 * Contract: K0 (its op's tensors) reads params only, is rc->n x rc->n,
 * symmetric to 1e-12 relative (‖K0 − K0ᵀ‖₁ ≤ 1e-12 ‖K0‖₁) and positive
 * definite; otherwise -1 with a message naming the class and the op. On
 * success rc->B (n x m row-major) holds the K0-orthonormal basis and rc->D
 * its dual; on failure rc->B and rc->D are freed and NULL. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/cholmod.h>

#include "emit.h"
#include "scratch.h"
#include "train.h"
#include "estimate_steps.h"
#include "train_steps.h"

typedef struct ProductEntries {
  SuiteSparse_long *i, *j;
  double *x;
  long n, nnz, cap;
  bool bad, oom;     /* an entry outside n x n; out of memory */
} ProductEntries;

static int product_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  ProductEntries *s = user;
  (void)in;
  if (nin != 0 || row < 0 || col < 0 || row >= s->n || col >= s->n) return s->bad = true, -1;
  if (s->nnz == s->cap) {
    long cap = s->cap ? 2 * s->cap : 4096;
    SuiteSparse_long *i = mem_realloc(s->i, sizeof *i * (size_t)cap);
    SuiteSparse_long *j = i ? mem_realloc(s->j, sizeof *j * (size_t)cap) : NULL;
    double *x = j ? mem_realloc(s->x, sizeof(double) * (size_t)cap) : NULL;
    if (i) s->i = i;
    if (j) s->j = j;
    if (x) s->x = x;
    if (!x) return s->oom = true, -1;
    s->cap = cap;
  }
  s->i[s->nnz] = row, s->j[s->nnz] = col, s->x[s->nnz] = coef;
  s->nnz++;
  return 0;
}

/* K0's entries (params only) as a CHOLMOD matrix, unsymmetric storage,
 * duplicates summed. */
cholmod_sparse *product_matrix(Model *m, Full *f, const RClass *rc, cholmod_common *cc, Err *err) {
  const Sym *op = rc->product;
  const OpDef *od = op->opdef;
  long rows = 1, cols = 1;
  for (int a = 0; a < op->nrow; a++) rows *= full_dim(f, op->ivars[a]->range->name);
  for (int a = op->nrow; a < op->nivars; a++) cols *= full_dim(f, op->ivars[a]->range->name);
  if (rows != rc->n || cols != rc->n)
    return err_set(err, "basis %s: product %s is %ld x %ld, but class %s has %ld entries: the product must "
                     "be a square operator of the class's size", rc->bc->size_name, op->name, rows, cols, rc->label,
                     rc->n), NULL;
  for (int g = 0; g < od->tensors.n; g++)
    if (od->tensors.g[g].ninputs > 0)
      return err_set(err, "basis %s: product %s reads '%s', which changes with the sample: an inner product "
                       "is a fixed operator (of params only)", rc->bc->size_name, op->name,
                       od->tensors.g[g].inputs[0]->name), NULL;
  ProductEntries s = {NULL, NULL, NULL, rc->n, 0, 0, false, false};
  int rc_ok = 0;
  for (int g = 0; g < od->tensors.n && rc_ok == 0; g++) {
    NpgSink sink = {&s, product_entry, 0, 1, 0, 0}; /* every row */
    if (full_build(f, emit_builder_name(m->prog->ctx, m->prog, NULL, 0, 0, g, op), &sink) != 0 || s.bad || s.oom)
      rc_ok = s.oom ? err_set(err, "out of memory for the entries of product %s", op->name)
              : s.bad ? err_set(err, "basis %s: product %s has an entry outside %ld x %ld", rc->bc->size_name,
                                  op->name, rc->n, rc->n)
                      : err_set(err, "basis %s: product %s: %s", rc->bc->size_name, op->name, full_error(f));
  }
  cholmod_sparse *A = NULL;
  cholmod_triplet *T = rc_ok ? NULL : cholmod_l_allocate_triplet((size_t)rc->n, (size_t)rc->n, (size_t)s.nnz + 1, 0,
                                                                CHOLMOD_REAL, cc);
  if (T) {
    memcpy(T->i, s.i, sizeof *s.i * (size_t)s.nnz);
    memcpy(T->j, s.j, sizeof *s.j * (size_t)s.nnz);
    memcpy(T->x, s.x, sizeof(double) * (size_t)s.nnz);
    T->nnz = (size_t)s.nnz;
    A = cholmod_l_triplet_to_sparse(T, (size_t)s.nnz, cc);
    cholmod_l_free_triplet(&T, cc);
  }
  if (rc_ok == 0 && !A) err_set(err, "out of memory for product %s", op->name);
  free(s.i), free(s.j), free(s.x);
  return A;
}

/* K0 = Pᵀ L Lᵀ P, after checking K0 symmetric; L simplicial LLᵀ. */
cholmod_factor *product_factor(const RClass *rc, cholmod_sparse *A, cholmod_common *cc, Err *err) {
  const char *name = rc->product->name;
  double one[2] = {1, 0}, minus[2] = {-1, 0};
  cholmod_sparse *At = cholmod_l_transpose(A, 1, cc);
  cholmod_sparse *Dif = At ? cholmod_l_add(A, At, one, minus, 1, 0, cc) : NULL;
  double nA = cholmod_l_norm_sparse(A, 1, cc), nD = Dif ? cholmod_l_norm_sparse(Dif, 1, cc) : NAN;
  cholmod_l_free_sparse(&At, cc);
  cholmod_l_free_sparse(&Dif, cc);
  if (isnan(nD)) return err_set(err, "out of memory for product %s", name), NULL;
  if (!(nA > 0) || !isfinite(nA))
    return err_set(err, "basis %s: product %s is %s: an inner product is symmetric positive definite",
                     rc->bc->size_name, name, nA == 0 ? "zero" : "not finite"), NULL;
  if (nD > 1e-12 * nA)
    return err_set(err, "basis %s: product %s is not symmetric (‖K − Kᵀ‖₁ = %.3g ‖K‖₁): an inner product is "
                     "symmetric positive definite", rc->bc->size_name, name, nD / nA), NULL;
  A->stype = 1; /* its upper triangle, now known to be the whole */
  cc->supernodal = CHOLMOD_SIMPLICIAL;
  cc->final_ll = 1;
  cholmod_factor *L = cholmod_l_analyze(A, cc);
  if (L && cholmod_l_factorize(A, L, cc) && cc->status == CHOLMOD_NOT_POSDEF) {
    long minor = (long)L->minor;
    cholmod_l_free_factor(&L, cc);
    return err_set(err, "basis %s: product %s is not positive definite (its Cholesky factorization breaks down "
                     "at column %ld of %ld): an inner product is symmetric positive definite", rc->bc->size_name,
                     name, minor, rc->n), NULL;
  }
  if (!L || cc->status < CHOLMOD_OK || !L->is_ll) {
    cholmod_l_free_factor(&L, cc);
    return err_set(err, "basis %s: product %s could not be factored (CHOLMOD status %d)", rc->bc->size_name,
                     name, cc->status), NULL;
  }
  return L;
}

/* Y = Lᵀ P X for the S columns of X (n x S, column-major). L simplicial,
 * column j: rows Li[Lp[j] .. Lp[j] + Lnz[j]), the diagonal first. */
static void weigh(const cholmod_factor *L, long n, long S, const double *X, double *Y) {
  const SuiteSparse_long *Lp = L->p, *Li = L->i, *Lnz = L->nz, *P = L->Perm;
  const double *Lx = L->x;
  for (long k = 0; k < S; k++) {
    const double *x = X + (size_t)k * (size_t)n;
    double *y = Y + (size_t)k * (size_t)n;
    for (long j = 0; j < n; j++) {
      double v = 0;
      for (SuiteSparse_long p = Lp[j]; p < Lp[j] + Lnz[j]; p++) v += Lx[p] * x[P[Li[p]]];
      y[j] = v;
    }
  }
}

/* B = Pᵀ L⁻ᵀ V in place on rc->B (n x m row-major): Lᵀ z = v by back
 * substitution over L's columns, then b[P[i]] = z[i]. */
static int unweigh(const cholmod_factor *L, RClass *rc) {
  const SuiteSparse_long *Lp = L->p, *Li = L->i, *Lnz = L->nz, *P = L->Perm;
  const double *Lx = L->x;
  long n = rc->n, m = rc->m;
  Scratch sc = SCRATCH_OF(NULL);
  double *z = scratch_array(&sc, (size_t)n, sizeof(double));
  for (long c = 0; z && c < m; c++) {
    for (long j = n - 1; j >= 0; j--) {
      double v = rc->B[j * m + c], d = 0;
      for (SuiteSparse_long p = Lp[j]; p < Lp[j] + Lnz[j]; p++)
        if (Li[p] == j) d = Lx[p];
        else v -= Lx[p] * z[Li[p]];
      z[j] = v / d;
    }
    for (long i = 0; i < n; i++) rc->B[P[i] * m + c] = z[i];
  }
  scratch_release(&sc);
  return z ? 0 : -1;
}

/* rc->D = K0 B (A unsymmetric storage, n x n; B and D n x m row-major). */
static int dual(const cholmod_sparse *A, RClass *rc) {
  long n = rc->n, m = rc->m;
  const SuiteSparse_long *Ap = A->p, *Ai = A->i;
  const double *Ax = A->x;
  if (!(rc->D = mem_calloc((size_t)n * (size_t)m, sizeof(double)))) return -1;
  for (long j = 0; j < n; j++)
    for (SuiteSparse_long p = Ap[j]; p < Ap[j + 1]; p++) {
      double a = Ax[p];
      double *d = rc->D + (size_t)Ai[p] * (size_t)m;
      const double *b = rc->B + (size_t)j * (size_t)m;
      for (long c = 0; c < m; c++) d[c] += a * b[c];
    }
  return 0;
}

int train_product_basis(Model *m, Full *f, RClass *rc, const ClassSnapshots *sn, bool full_rank, Err *err) {
  long S = sn->S;
  cholmod_common cc;
  cholmod_l_start(&cc);
  cc.print = 0;
  cholmod_sparse *A = product_matrix(m, f, rc, &cc, err);
  rc->k0_norm1 = A ? cholmod_l_norm_sparse(A, 1, &cc) : 0; /* whole A: product_factor leaves its upper triangle */
  cholmod_factor *L = A ? product_factor(rc, A, &cc, err) : NULL;
  Scratch sc = SCRATCH_OF(err);
  double **Y = L ? scratch_array(&sc, (size_t)rc->nmembers, sizeof(double *)) : NULL;
  int rc_ok = Y ? 0 : -1;
  if (L && !Y) err_set(err, "out of memory for the weighted snapshots of class %s", rc->label);
  for (int i = 0; rc_ok == 0 && i < rc->nmembers; i++) {
    if (!(Y[i] = scratch_array(&sc, (size_t)rc->n * (size_t)S, sizeof(double))))
      rc_ok = err_set(err, "out of memory for the weighted snapshots of class %s", rc->label);
    else weigh(L, rc->n, S, sn->X[i], Y[i]);
  }
  if (rc_ok == 0) rc_ok = train_member_bases(rc, S, Y, sn->w, NULL, err);
  if (rc_ok == 0) rc_ok = train_complete_basis(rc, full_rank, err);
  if (rc_ok == 0 && (unweigh(L, rc) || dual(A, rc)))
    rc_ok = err_set(err, "out of memory for the basis of class %s", rc->label);
  if (rc_ok != 0) /* the class is left without a basis, not half made: what was made goes with the scratch */
    scratch_adopt(&sc, rc->B), scratch_adopt(&sc, rc->D), rc->B = rc->D = NULL;
  scratch_release(&sc);
  cholmod_l_free_factor(&L, &cc);
  cholmod_l_free_sparse(&A, &cc);
  cholmod_l_finish(&cc);
  return rc_ok;
}

struct ProductNorm {
  cholmod_common cc;
  cholmod_sparse *A;
};

ProductNorm *product_norm_new(Model *m, Full *f, const RClass *rc, Err *err) {
  ProductNorm *p = mem_calloc(1, sizeof *p);
  if (!p) return err_set(err, "out of memory"), NULL;
  cholmod_l_start(&p->cc);
  p->cc.print = 0;
  if (!(p->A = product_matrix(m, f, rc, &p->cc, err))) {
    product_norm_free(p);
    return NULL;
  }
  return p;
}

double product_norm(const ProductNorm *p, const double *v) {
  const cholmod_sparse *A = p->A;
  const SuiteSparse_long *Ap = A->p, *Ai = A->i;
  const double *Ax = A->x;
  long n = (long)A->ncol;
  double s = 0;
  for (long j = 0; j < n; j++) {
    double a = 0; /* (K0 v)_j = Σ_i K0[i, j] v_i: K0 is symmetric */
    for (SuiteSparse_long k = Ap[j]; k < Ap[j + 1]; k++) a += Ax[k] * v[Ai[k]];
    s += a * v[j];
  }
  return sqrt(fmax(s, 0));
}

void product_norm_free(ProductNorm *p) {
  if (!p) return;
  cholmod_l_free_sparse(&p->A, &p->cc);
  cholmod_l_finish(&p->cc);
  free(p);
}
