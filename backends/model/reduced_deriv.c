/* reduced_deriv.c — derivatives of the reduced evaluator in reduced
 * coordinates (DESIGN §17): forward products (tangents), reverse products
 * (cotangents) and whole Jacobians, at reduced cost (nothing of order N).
 *
 * Every stage is linearized from its local Jacobians, the partial
 * derivatives of its reduced tensors' contractions with respect to each
 * input's coordinates:
 *
 *     ŷ = T ·(z_1 ⊗ … ⊗ z_n),  z_j = x̂_j^⊗k_j (packed)   →
 *     ∂ŷ/∂x̂_j = (T contracted with every z but z_j) · ∂z_j/∂x̂_j,
 *
 * read once per input, like an evaluation. A term's operators chain
 * innermost first, v_{k+1} = M̂_k^{r_k} v_k, and differentiate in closed form:
 *
 *     integer power  v' = M v:     dv' = M dv + dM v
 *     inverse        v' = M⁻¹ v:   dv' = M⁻¹ (dv − dM v')
 *     root           v' = f(M) v:  dv' = f(M) dv + U (F ∘ Uᵀ dM U) Uᵀ v,
 *                    M = U Λ Uᵀ, F_ij = (f(λ_i) − f(λ_j)) / (λ_i − λ_j) (f'(λ_i) where equal:
 *                    Daleckii–Krein), f(λ) = λ^(p/q);
 *
 * reverse products apply the adjoints of the same rules (M̄ = v̄' vᵀ, −M⁻ᵀv̄' v'ᵀ,
 * U (F ∘ Uᵀv̄' (Uᵀv)ᵀ) Uᵀ), and an operator's cotangent M̄ reaches its inputs through
 * the transposed local Jacobians of its tensors. An interpolated stage (DESIGN §12)
 * differentiates its formula at the selected entries, whose reads are rows of their
 * bases: ∂ŷ/∂x̂ = (W P B)⁺ W · ∂(P y)/∂x̂. An extern's learned map (a convex
 * combination chosen by NNLS) has no derivative: reading one is refused; externs given by
 * the caller (reduced_use_given_externs) are constants.
 *
 * The primal of each term is the evaluation's (reduced_kept: every operator as assembled, an
 * inverse's Cholesky or LU factor, the vectors of its power's steps), never contracted or
 * factored again while the coordinates are those it evaluated at; a tensor of one input taken
 * twice has its local Jacobian from the evaluation's read too (reduced_keep_local_jacobians).
 * A Jacobian's identity seed is added where a product by it would be formed.
 *
 * The tangents (and cotangents) of `nd` directions travel together as
 * m × nd row-major blocks, so a whole Jacobian is one forward sweep with the
 * identity as seed (or one reverse sweep, whichever has fewer columns). */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "interp.h"
#include "reduced.h"
#include "scratch.h"

typedef struct Deriv {
  const Model *m;
  const Reduced *r;     /* the evaluator: its kept operators (reduced_kept) */
  double *const *x;     /* the primal coordinates of every quantity (reduced_eval's) */
  long nd;              /* directions carried */
  double **d;           /* per quantity: its tangent (forward) or cotangent (reverse), m_q x nd, or NULL */
  bool *active;         /* quantities that depend on the differentiated inputs */
  int ident_q;          /* forward: the quantity whose tangent block is the identity (nd = its m), or -1 */
  struct DerivCache **cache_slot; /* the evaluator's (reduced_deriv_cache) */
  bool given_externs;   /* externs hold the caller's values (reduced_use_given_externs): constants */
  long sample;
  Err *err;             /* the caller's record, or `own` when it holds no buffer */
  Err own;
  char own_msg[256];
  Scratch sc;           /* x, d and active: released at the operation's end */
} Deriv;

static long qm(const Model *m, int q) { return m->classes[m->qclass[q]].m; }

static int dfail_oom(Deriv *dv) { return err_set(dv->err, "out of memory for the reduced derivative"); }

/* Forward: out (rows x nd) += alpha · J d[q], J rows x m_q. A Jacobian's seed is the identity:
 * then J itself is added (a product by I cost as much as the rest of the sweep at m = 50). */
static void forward_product(const Deriv *dv, int q, long rows, double alpha, const double *J, double *out) {
  long mq = qm(dv->m, q), nd = dv->nd;
  if (q == dv->ident_q)
    for (long e = 0; e < rows * mq; e++) out[e] += alpha * J[e];
  else
    cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)rows, (int)nd, (int)mq, alpha, J, (int)mq, dv->d[q],
                (int)nd, 1.0, out, (int)nd);
}

/* ---------------------------------------------------------------- the evaluator's cache */

/* A tensor of one input repeated twice (x ⊗ x, packed) is its own partial
 * contraction, so its local Jacobian is Ŝ x for Ŝ (rows·m x m) its rows
 * unpacked to whole symmetric matrices with doubled diagonals: one dgemv.
 * Ŝ is made on the first derivative through the tensor and kept in the
 * evaluator (twice the tensor's memory, for the tensors differentiated). */
typedef struct DerivCache {
  int n, cap;
  const RTensor **t;
  double **S;
} DerivCache;

void reduced_deriv_cache_free(DerivCache *c) {
  if (!c) return;
  for (int i = 0; i < c->n; i++) free(c->S[i]);
  free(c->t);
  free(c->S);
  free(c);
}

/* Ŝ of tensor t (its only input packed twice, m coordinates) in the cache *slot, or NULL out
 * of memory. */
static const double *square_unpacked(DerivCache **slot, const RTensor *t, long m) {
  DerivCache *c = *slot;
  for (int i = 0; c && i < c->n; i++)
    if (c->t[i] == t) return c->S[i];
  if (!c || c->n == c->cap) {
    int cap = c ? 2 * c->cap : 8;
    DerivCache *nc = c ? c : mem_calloc(1, sizeof *nc);
    if (!nc) return NULL;
    const RTensor **nt = realloc(nc->t, sizeof *nt * (size_t)cap);
    if (nt) nc->t = nt;
    double **ns = nt ? realloc(nc->S, sizeof *ns * (size_t)cap) : NULL;
    if (ns) nc->S = ns;
    if (!c) *slot = c = nc;
    if (!nt || !ns) return NULL;
    c->cap = cap;
  }
  double *S = mem_malloc(sizeof(double) * (size_t)(t->rows * m * m + 1));
  if (!S) return NULL;
  for (long r = 0; r < t->rows; r++) {
    const double *pr = t->data + r * t->cols;
    double *sr = S + r * m * m;
    for (long a = 0, p = 0; a < m; a++)
      for (long b = a; b < m; b++, p++) {
        sr[a * m + b] = pr[p] * (a == b ? 2 : 1);
        sr[b * m + a] = pr[p] * (a == b ? 2 : 1);
      }
  }
  c->t[c->n] = t, c->S[c->n] = S, c->n++;
  return S;
}

const double *reduced_deriv_square(Reduced *r, const RTensor *t) {
  const Model *m = reduced_model(r);
  return square_unpacked(reduced_deriv_cache(r), t, qm(m, t->in_q[0]));
}

/* ---------------------------------------------------------------- tensors */

/* The packed powers z_j of tensor t's inputs, one after another in `zbuf`. */
static void tensor_z(const Deriv *dv, const RTensor *t, const double **z, double *zbuf) {
  for (int j = 0; j < t->nin; j++) {
    const double *x = dv->x[t->in_q[j]];
    if (t->in_mult[j] == 1) {
      z[j] = x;
      continue;
    }
    sym_power(qm(dv->m, t->in_q[j]), t->in_mult[j], x, zbuf);
    z[j] = zbuf;
    zbuf += t->in_len[j];
  }
}

static long tensor_zlen(const RTensor *t) {
  long n = 1;
  for (int j = 0; j < t->nin; j++) n += t->in_len[j];
  return n;
}

/* out (rows) += T ·(z_1 ⊗ … ⊗ z_n), the last axis first; its two buffers from the caller's
 * scratch `sc`. */
static int contract_into(const RTensor *t, const double *const *z, double *out, Scratch *sc) {
  if (t->nin == 0) {
    cblas_daxpy((int)t->rows, 1.0, t->data, 1, out, 1);
    return 0;
  }
  long lead = t->rows;
  for (int j = 0; j + 1 < t->nin; j++) lead *= t->in_len[j];
  double *buf[2] = {scratch_array_unzeroed(sc, (size_t)(lead + 1), sizeof(double)), NULL};
  if (!buf[0] || !(buf[1] = scratch_array_unzeroed(sc, (size_t)(lead + 1), sizeof(double)))) return -1;
  const double *src = t->data;
  int b = 0;
  for (int j = t->nin - 1; j >= 0; j--) {
    long cols = t->in_len[j];
    double *dst = j == 0 ? out : buf[b];
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)lead, (int)cols, 1.0, src, (int)cols, z[j], 1, j == 0 ? 1.0 : 0.0,
                dst, 1);
    src = dst;
    b ^= 1;
    if (j > 0) lead /= t->in_len[j - 1];
  }
  return 0;
}

/* P (rows x L_j): T contracted with every packed input but z_j, into *P:
 * the tensor itself when j is its only axis (nothing copied), else an
 * array of the caller's scratch `sc`. The axes after j by dgemv from the
 * last; those before j row by row against z_1 ⊗ … ⊗ z_{j-1}. */
static int contract_but(const RTensor *t, int j, const double *const *z, const double **P, Scratch *sc) {
  long before = 1, upto = t->rows, Lj = t->in_len[j];
  for (int i = 0; i < j; i++) before *= t->in_len[i];
  for (int i = 0; i <= j; i++) upto *= t->in_len[i];
  if (j == t->nin - 1 && before == 1) {
    *P = t->data;
    return 0;
  }
  long lead = upto; /* the first trailing step's rows */
  for (int i = j + 1; i + 1 < t->nin; i++) lead *= t->in_len[i];
  double *buf[2] = {NULL, NULL};
  if (j < t->nin - 1 && (!(buf[0] = scratch_array(sc, (size_t)(lead + 1), sizeof(double))) ||
                         !(buf[1] = scratch_array(sc, (size_t)(lead + 1), sizeof(double)))))
    return -1;
  double *kron = scratch_array(sc, (size_t)(before + 1), sizeof(double));
  double *out = kron ? scratch_array(sc, (size_t)(t->rows * Lj + 1), sizeof(double)) : NULL;
  if (!out) return -1;
  const double *src = t->data;
  int b = 0;
  for (int i = t->nin - 1; i > j; i--) {
    long cols = t->in_len[i];
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)lead, (int)cols, 1.0, src, (int)cols, z[i], 1, 0.0, buf[b], 1);
    src = buf[b];
    b ^= 1;
    lead /= t->in_len[i - 1];
  }
  kron[0] = 1;
  long len = 1;
  for (int i = 0; i < j; i++) { /* kron <- kron ⊗ z_i */
    long li = t->in_len[i];
    for (long a = len - 1; a >= 0; a--)
      for (long c = li - 1; c >= 0; c--) kron[a * li + c] = kron[a] * z[i][c];
    len *= li;
  }
  if (before == 1) memcpy(out, src, sizeof(double) * (size_t)(t->rows * Lj));
  else
    for (long r = 0; r < t->rows; r++)
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)before, (int)Lj, 1.0, src + r * before * Lj, (int)Lj, kron, 1, 0.0,
                  out + r * Lj, 1);
  *P = out;
  return 0;
}

/* An input of a tensor repeated k times: its coordinates x (m_q), its packed length L_j, and
 * when k > 2 the scratch of jacobian_of (col, coef: L_j k entries each). */
typedef struct RepeatedInput {
  const double *x;
  long mq, Lj;
  int k;
  long *col;
  double *coef;
} RepeatedInput;

/* J (rows x m_q) from P (rows x L_j, contract_but) for the repeated input `in`. */
static void jacobian_of(const double *P, long rows, const RepeatedInput *in, double *J) {
  const double *x = in->x;
  long mq = in->mq, Lj = in->Lj, *col = in->col;
  int k = in->k;
  double *coef = in->coef;
  if (k == 1) memcpy(J, P, sizeof(double) * (size_t)(rows * mq));
  else if (k == 2) { /* z[(a,b)] = x_a x_b, a <= b: row r gains P[r,(a,b)] x_b at a and P[r,(a,b)] x_a at b
                        * (loops: BLAS per row and index made thousands of level-1 calls) */
    memset(J, 0, sizeof(double) * (size_t)(rows * mq));
    for (long r = 0; r < rows; r++) {
      const double *pr = P + r * Lj;
      double *jr = J + r * mq;
      for (long a = 0, off = 0; a < mq; off += mq - a, a++) {
        const double *seg = pr + off - a; /* seg[b] = P[r,(a,b)] for b >= a */
        double s0 = 0, s1 = 0, xa = x[a];
        long b = a;
        for (; b + 1 < mq; b += 2) s0 += seg[b] * x[b], s1 += seg[b + 1] * x[b + 1];
        if (b < mq) s0 += seg[b] * x[b];
        for (b = a; b < mq; b++) jr[b] += seg[b] * xa;
        jr[a] += s0 + s1;
      }
    }
  } else if (k > 2) {
    long a[RT_MAX_IN] = {0};
    for (long p = 0; p < Lj; p++) {
      for (int l = 0; l < k; l++) {
        double c = 1;
        for (int l2 = 0; l2 < k; l2++)
          if (l2 != l) c *= x[a[l2]];
        col[p * k + l] = a[l], coef[p * k + l] = c;
      }
      int i = k - 1; /* the next sorted multi-index (sym.c's order) */
      while (i >= 0 && a[i] == mq - 1) i--;
      if (i < 0) break;
      a[i]++;
      for (int l = i + 1; l < k; l++) a[l] = a[i];
    }
    memset(J, 0, sizeof(double) * (size_t)(rows * mq));
    for (long r = 0; r < rows; r++) {
      const double *pr = P + r * Lj;
      double *jr = J + r * mq;
      for (long p = 0; p < Lj; p++)
        for (int l = 0; l < k; l++) jr[col[p * k + l]] += pr[p] * coef[p * k + l];
    }
  }
}

/* J (rows x m_q, overwritten) = ∂(T · z)/∂x̂ of input j of tensor t:
 * P · ∂z_j/∂x̂, each packed coordinate z[α] = Π_l x[α_l] contributing
 * Π_{l'≠l} x[α_l'] to column α_l for every position l. */
static int tensor_jacobian(Deriv *dv, const RTensor *t, int j, double *J) {
  long mq = qm(dv->m, t->in_q[j]), Lj = t->in_len[j], rows = t->rows;
  int k = t->in_mult[j];
  if (k == 2 && t->nin == 1) {
    const double *S = square_unpacked(dv->cache_slot, t, mq);
    if (!S) return -1;
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)(rows * mq), (int)mq, 1.0, S, (int)mq, dv->x[t->in_q[j]], 1, 0.0,
                J, 1);
    return 0;
  }
  const double *z[RT_MAX_IN];
  Scratch sc = SCRATCH_OF(NULL);
  double *zbuf = scratch_array(&sc, (size_t)tensor_zlen(t), sizeof(double));
  const double *P = NULL;
  long *col = k <= 2 ? NULL : scratch_array(&sc, (size_t)(Lj * k + 1), sizeof(long));
  double *coef = k <= 2 ? NULL : scratch_array(&sc, (size_t)(Lj * k + 1), sizeof(double));
  int rc = zbuf && (k <= 2 || (col && coef)) ? 0 : -1;
  if (rc == 0) tensor_z(dv, t, z, zbuf);
  if (rc == 0) rc = contract_but(t, j, z, &P, &sc);
  if (rc == 0) jacobian_of(P, rows, &(RepeatedInput){dv->x[t->in_q[j]], mq, Lj, k, col, coef}, J);
  scratch_release(&sc);
  return rc;
}

/* The local Jacobian ∂(T·z)/∂x̂ of input j of t (rows x m_q): the tensor itself when j is its
 * only input, of degree 1 (nothing copied), the evaluation's when it kept it, else
 * tensor_jacobian's into `J`. NULL out of memory. */
static const double *local_jacobian(Deriv *dv, const RTensor *t, int j, double *J) {
  if (t->nin == 1 && t->in_mult[0] == 1) return t->data;
  const double *kept = j == 0 && reduced_keeps_local_jacobian(t) ? reduced_kept_local_jacobian(dv->r, t) : NULL;
  if (kept) return kept;
  return tensor_jacobian(dv, t, j, J) ? NULL : J;
}

/* Forward: out (rows x nd) += Σ_j ∂(T·z)/∂x̂_j · d[x_j]; reverse: d[x_j] += (∂(T·z)/∂x̂_j)ᵀ · bar
 * (rows x nd), for the active inputs of t. */
static int tensor_tangent(Deriv *dv, const RTensor *t, bool reverse, const double *bar, double *out) {
  long most = 0; /* the largest local Jacobian: one buffer for every input */
  for (int j = 0; j < t->nin; j++) {
    long size = t->rows * qm(dv->m, t->in_q[j]);
    if (dv->active[t->in_q[j]] && size > most) most = size;
  }
  Scratch sc = SCRATCH_OF(NULL);
  double *buf = most > 0 ? scratch_array_unzeroed(&sc, (size_t)most, sizeof(double)) : NULL;
  int rc = most > 0 && !buf ? dfail_oom(dv) : 0;
  for (int j = 0; j < t->nin && rc == 0; j++) {
    int q = t->in_q[j];
    if (!dv->active[q]) continue;
    long mq = qm(dv->m, q);
    if (mq == 0 || t->rows == 0) continue;
    const double *J = local_jacobian(dv, t, j, buf);
    if (!J) rc = dfail_oom(dv);
    else if (reverse)
      cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)mq, (int)dv->nd, (int)t->rows, 1.0, J, (int)mq, bar,
                  (int)dv->nd, 1.0, dv->d[q], (int)dv->nd);
    else forward_product(dv, q, t->rows, 1.0, J, out);
  }
  scratch_release(&sc);
  return rc;
}

static bool tensor_active(const Deriv *dv, const RTensor *t) {
  for (int j = 0; j < t->nin; j++)
    if (dv->active[t->in_q[j]]) return true;
  return false;
}

/* ---------------------------------------------------------------- operators */

/* One operator of a term at the current coordinates: M̂ (n x n, row-major)
 * and what its power needs — LU factors, or the eigendecomposition. */
typedef struct OpState {
  const ROp *ro;
  long n;
  double *M, *LU, *U, *lam, *F; /* LU: an inverse's factor (as ReducedKept's); F: f's divided differences (roots) */
  lapack_int *piv;
  bool chol;                    /* LU holds Cholesky's L of M̂, else the LU factors of M̂ᵀ (column-major) */
  bool kept;                    /* M, LU and piv are the evaluator's (reduced_kept), not its own */
  Scratch *mem;                 /* where its own arrays live: its term's (TermState) */
} OpState;

/* B (n x nrhs, row-major) <- M̂⁻¹ B, or M̂⁻ᵀ B with `trans`, by the inverse's factor; `work`
 * holds n·nrhs (B transposed to the column-major layout LAPACK solves in) when nrhs > 1. */
static void op_solve(const OpState *o, bool trans, double *B, long nrhs, double *work) {
  lapack_int n = (lapack_int)o->n;
  if (nrhs < 1 || n < 1) return;
  double *X = nrhs == 1 ? B : work;
  for (long i = 0; nrhs > 1 && i < n; i++)
    for (long d = 0; d < nrhs; d++) X[d * n + i] = B[i * nrhs + d];
  if (o->chol) LAPACKE_dpotrs_work(LAPACK_COL_MAJOR, 'L', n, (lapack_int)nrhs, o->LU, n, X, n);
  else LAPACKE_dgetrs_work(LAPACK_COL_MAJOR, trans ? 'N' : 'T', n, (lapack_int)nrhs, o->LU, n, o->piv, X, n);
  for (long i = 0; nrhs > 1 && i < n; i++)
    for (long d = 0; d < nrhs; d++) B[i * nrhs + d] = X[d * n + i];
}

static double root_f(double l, double e) { return l > 0 ? pow(l, e) : 0.0; }

/* Factor o->M as its power needs: an inverse's LU (unless kept), a root's eigendecomposition
 * and divided differences. */
static int op_factor(Deriv *dv, const RStage *rs, OpState *o) {
  const ROp *ro = o->ro;
  long n = o->n;
  const char *sn = rs->st->sym->name;
  long p = ro->op->p, q = ro->op->q;
  if ((q == 1 && p > 0) || (q == 1 && o->kept)) return 0;
  if (q == 1) {
    o->LU = scratch_array_unzeroed(o->mem, (size_t)(n * n + 1), sizeof(double));
    o->piv = scratch_array_unzeroed(o->mem, (size_t)(n + 1), sizeof(lapack_int));
    if (!o->LU || !o->piv) return dfail_oom(dv);
    memcpy(o->LU, o->M, sizeof(double) * (size_t)(n * n)); /* column-major: M̂ᵀ, as the evaluator factors it */
    lapack_int info = LAPACKE_dgetrf_work(LAPACK_COL_MAJOR, (lapack_int)n, (lapack_int)n, o->LU, (lapack_int)n, o->piv);
    if (info != 0)
      return err_set(dv->err, "stage %s: its reduced operator is singular (LAPACK dgetrf info %d): no "
                     "derivative there", sn, (int)info);
    return 0;
  }
  o->U = scratch_array_unzeroed(o->mem, (size_t)(n * n + 1), sizeof(double));
  o->lam = scratch_array_unzeroed(o->mem, (size_t)(n + 1), sizeof(double));
  o->F = scratch_array_unzeroed(o->mem, (size_t)(n * n + 1), sizeof(double));
  if (!o->U || !o->lam || !o->F) return dfail_oom(dv);
  memcpy(o->U, o->M, sizeof(double) * (size_t)(n * n));
  lapack_int info = LAPACKE_dsyevd(LAPACK_ROW_MAJOR, 'V', 'U', (lapack_int)n, o->U, (lapack_int)n, o->lam);
  if (info != 0)
    return err_set(dv->err, "stage %s: eigendecomposition of its reduced operator failed (LAPACK dsyevd "
                   "info %d)", sn, (int)info);
  double e = (double)p / (double)q, big = 0;
  for (long i = 0; i < n; i++) big = fmax(big, fabs(o->lam[i]));
  double tol = 1e-12 * (big > 0 ? big : 1);
  for (long i = 0; i < n; i++)
    if (o->lam[i] <= tol)
      return err_set(dv->err, "stage %s: its reduced operator has eigenvalue %.3g (largest %.3g): the "
                     "power %ld/%ld is not differentiable there", sn, o->lam[i], big, p, q);
  /* Daleckii–Krein: divided differences of f, its derivative where two eigenvalues are close */
  for (long i = 0; i < n; i++)
    for (long j = 0; j < n; j++) {
      double li = o->lam[i], lj = o->lam[j];
      o->F[i * n + j] = fabs(li - lj) > 1e-8 * fmax(li, lj) ? (root_f(li, e) - root_f(lj, e)) / (li - lj)
                                                            : e * pow(0.5 * (li + lj), e - 1);
    }
  return 0;
}

/* Assemble M̂ of `ro` (its packed rows and each tensor's buffers from a scratch) and factor it
 * as its power needs, into `o` (whose `mem` is set). */
static int op_state(Deriv *dv, const RStage *rs, const ROp *ro, long n, OpState *o) {
  *o = (OpState){.ro = ro, .n = n, .mem = o->mem};
  long rows = ro->op->kind == OPK_DIAG ? n * (n + 1) / 2 : n * n;
  Scratch sc = SCRATCH_OF(NULL);
  double *acc = scratch_array(&sc, (size_t)rows + 1, sizeof(double));
  int rc = acc && (o->M = scratch_array(o->mem, (size_t)(n * n) + 1, sizeof(double))) ? 0 : -1;
  for (int g = 0; g < ro->ntensors && rc == 0; g++) {
    const double *z[RT_MAX_IN];
    double *zbuf = scratch_array_unzeroed(&sc, (size_t)tensor_zlen(&ro->t[g]), sizeof(double));
    rc = zbuf ? contract_into(&ro->t[g], (tensor_z(dv, &ro->t[g], z, zbuf), z), acc, &sc) : -1;
  }
  if (rc == 0 && ro->op->kind == OPK_DIAG) {
    long p = 0;
    for (long a = 0; a < n; a++)
      for (long b = a; b < n; b++, p++) o->M[a * n + b] = o->M[b * n + a] = acc[p];
  } else if (rc == 0) memcpy(o->M, acc, sizeof(double) * (size_t)(n * n));
  scratch_release(&sc);
  return rc ? dfail_oom(dv) : op_factor(dv, rs, o);
}

/* The operator `ro` as the evaluation kept it (`kp`): M̂ and an inverse's factor borrowed, a
 * root's eigendecomposition computed from the kept M̂ (the evaluation never forms it), into `o`
 * (whose `mem` is set). */
static int op_state_kept(Deriv *dv, const RStage *rs, const ROp *ro, long n, const ReducedKept *kp, OpState *o) {
  *o = (OpState){.ro = ro, .n = n, .kept = true, .mem = o->mem};
  o->M = kp->M, o->LU = kp->factor, o->piv = kp->piv, o->chol = kp->chol;
  return op_factor(dv, rs, o);
}

/* out (n) = f(M) v for a root: U f(Λ) Uᵀ v. */
static void root_apply(const OpState *o, const double *v, double *out, double *w) {
  long n = o->n;
  double e = (double)o->ro->op->p / (double)o->ro->op->q;
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, (int)n, 1.0, o->U, (int)n, v, 1, 0.0, w, 1);
  for (long i = 0; i < n; i++) w[i] *= root_f(o->lam[i], e);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)n, 1.0, o->U, (int)n, w, 1, 0.0, out, 1);
}

/* The primal chain of one power: vs[0] = v, vs[s+1] the s-th step's result
 * (|p| steps of M or M⁻¹, one of f(M)). Returns the step count. */
static long op_steps(const OpState *o) {
  if (o->ro->op->q != 1) return 1;
  return labs(o->ro->op->p);
}

static void op_forward_primal(const OpState *o, double *vs, double *w) {
  long n = o->n, steps = op_steps(o);
  for (long s = 0; s < steps; s++) {
    const double *v = vs + s * n;
    double *v2 = vs + (s + 1) * n;
    if (o->ro->op->q != 1) root_apply(o, v, v2, w);
    else if (o->ro->op->p > 0) cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)n, 1.0, o->M, (int)n, v, 1, 0.0,
                                           v2, 1);
    else {
      memcpy(v2, v, sizeof(double) * (size_t)n);
      op_solve(o, false, v2, 1, NULL);
    }
  }
}

/* The tangent of M̂ in each direction, unpacked: dM (nd x n x n) from
 * Σ_g Σ_j J_g,j d[x_j] (packed rows x nd). */
static int op_tangent(Deriv *dv, const OpState *o, double *dM) {
  long n = o->n, nd = dv->nd, rows = o->ro->op->kind == OPK_DIAG ? n * (n + 1) / 2 : n * n;
  Scratch sc = SCRATCH_OF(NULL);
  double *pk = scratch_array(&sc, (size_t)(rows * nd) + 1, sizeof(double));
  int rc = pk ? 0 : dfail_oom(dv);
  for (int g = 0; g < o->ro->ntensors && rc == 0; g++) rc = tensor_tangent(dv, &o->ro->t[g], false, NULL, pk);
  for (long d = 0; d < nd && rc == 0; d++) {
    double *Md = dM + d * n * n;
    if (o->ro->op->kind == OPK_DIAG) {
      long p = 0;
      for (long a = 0; a < n; a++)
        for (long b = a; b < n; b++, p++) Md[a * n + b] = Md[b * n + a] = pk[p * nd + d];
    } else
      for (long e = 0; e < n * n; e++) Md[e] = pk[e * nd + d];
  }
  scratch_release(&sc);
  return rc;
}

/* The reverse of op_tangent: M̄ (nd x n x n) to the operator's inputs. */
static int op_cotangent(Deriv *dv, const OpState *o, const double *Mbar) {
  long n = o->n, nd = dv->nd, rows = o->ro->op->kind == OPK_DIAG ? n * (n + 1) / 2 : n * n;
  Scratch sc = SCRATCH_OF(NULL);
  double *pk = scratch_array(&sc, (size_t)(rows * nd) + 1, sizeof(double));
  int rc = pk ? 0 : dfail_oom(dv);
  for (long d = 0; d < nd && rc == 0; d++) {
    const double *Md = Mbar + d * n * n;
    if (o->ro->op->kind == OPK_DIAG) {
      long p = 0;
      for (long a = 0; a < n; a++)
        for (long b = a; b < n; b++, p++) pk[p * nd + d] = a == b ? Md[a * n + a] : Md[a * n + b] + Md[b * n + a];
    } else
      for (long e = 0; e < n * n; e++) pk[e * nd + d] = Md[e];
  }
  for (int g = 0; g < o->ro->ntensors && rc == 0; g++) rc = tensor_tangent(dv, &o->ro->t[g], true, pk, NULL);
  scratch_release(&sc);
  return rc;
}

/* U (F ∘ (Uᵀ E U)) Uᵀ-free part: out (n) = U [F ∘ (Uᵀ E U)] w, the Daleckii–Krein
 * derivative of f(M) v in direction E, w = Uᵀ v. `work` holds 2 n² + n. */
static void dk_forward(const OpState *o, const double *E, const double *w, double *out, double *work) {
  int n = (int)o->n;
  double *A = work, *B = A + (long)n * n, *t = B + (long)n * n;
  cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, n, n, n, 1.0, o->U, n, E, n, 0.0, A, n);
  cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, n, n, n, 1.0, A, n, o->U, n, 0.0, B, n);
  for (long e = 0; e < (long)n * n; e++) B[e] *= o->F[e];
  cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, B, n, w, 1, 0.0, t, 1);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, n, n, 1.0, o->U, n, t, 1, 0.0, out, 1);
}

/* The operator's tangent applied to one vector, without forming dM: for
 * each active input q of its tensors, G = ∂(M̂ u)/∂x̂_q (n x m_q, folded
 * from the tensor's local Jacobian: packed row (a,b) adds its row times
 * u_b to G's row a, and times u_a to row b when a < b), then forward
 * V (n x nd) += sign · G d[q], reverse d[q] += sign · Gᵀ V. */
static int op_dM_times(Deriv *dv, const OpState *o, const double *u, double sign, bool reverse, double *V) {
  long n = o->n, nd = dv->nd, most = 0; /* the largest m_q: buffers for every input */
  bool diag = o->ro->op->kind == OPK_DIAG;
  long rows = diag ? n * (n + 1) / 2 : n * n;
  for (int g = 0; g < o->ro->ntensors; g++)
    for (int j = 0; j < o->ro->t[g].nin; j++)
      if (dv->active[o->ro->t[g].in_q[j]] && qm(dv->m, o->ro->t[g].in_q[j]) > most) most = qm(dv->m, o->ro->t[g].in_q[j]);
  Scratch sc = SCRATCH_OF(NULL);
  double *buf = NULL, *G = NULL;
  int rc = most > 0 && n > 0 && (!(buf = scratch_array_unzeroed(&sc, (size_t)(rows * most), sizeof(double))) ||
                                 !(G = scratch_array_unzeroed(&sc, (size_t)(n * most), sizeof(double))))
               ? dfail_oom(dv)
               : 0;
  for (int g = 0; g < o->ro->ntensors && rc == 0; g++) {
    const RTensor *t = &o->ro->t[g];
    for (int j = 0; j < t->nin && rc == 0; j++) {
      int q = t->in_q[j];
      long mq = qm(dv->m, q);
      if (!dv->active[q] || mq == 0 || n == 0) continue;
      const double *J = local_jacobian(dv, t, j, buf);
      if (!J) {
        rc = dfail_oom(dv);
        continue;
      }
      memset(G, 0, sizeof(double) * (size_t)(n * mq));
      if (!diag) /* G's row a = (J's rows (a, ·))ᵀ u */
        for (long a = 0; a < n; a++)
          cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, (int)mq, 1.0, J + a * n * mq, (int)mq, u, 1, 0.0, G + a * mq,
                      1);
      else
        for (long a = 0, p = 0; a < n; a++)
          for (long b = a; b < n; b++, p++) {
            const double *jr = J + p * mq;
            double *ga = G + a * mq, *gb = G + b * mq, ub = u[b], ua = u[a];
            for (long c = 0; c < mq; c++) ga[c] += jr[c] * ub;
            if (b != a)
              for (long c = 0; c < mq; c++) gb[c] += jr[c] * ua;
          }
      if (reverse)
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)mq, (int)nd, (int)n, sign, G, (int)mq, V, (int)nd,
                    1.0, dv->d[q], (int)nd);
      else forward_product(dv, q, n, sign, G, V);
    }
  }
  scratch_release(&sc);
  return rc;
}

/* Forward through one power: dV (n x nd) <- the tangent of the result, vs its primal chain. */
static int op_forward(Deriv *dv, const OpState *o, const double *vs, double *dV) {
  long n = o->n, nd = dv->nd, steps = op_steps(o);
  bool dm = false, root = o->ro->op->q != 1; /* dM formed for roots only (Daleckii–Krein) */
  for (int g = 0; g < o->ro->ntensors; g++) dm = dm || (root && tensor_active(dv, &o->ro->t[g]));
  Scratch sc = SCRATCH_OF(NULL);
  double *dM = dm ? scratch_array(&sc, (size_t)(nd * n * n) + 1, sizeof(double)) : NULL;
  double *tmp = scratch_array_unzeroed(&sc, (size_t)(n * nd + 2 * n * n + 5 * n + 1), sizeof(double));
  int rc = (dm && !dM) || !tmp ? dfail_oom(dv) : dm ? op_tangent(dv, o, dM) : 0;
  double *A = NULL, *w = NULL, *t = NULL, *col = NULL; /* A: dk_forward's 2 n² + n */
  if (tmp) A = tmp + n * nd, w = A + 2 * n * n + n, t = w + n, col = t + n;
  for (long s = 0; s < steps && rc == 0; s++) {
    const double *v = vs + s * n, *v2 = vs + (s + 1) * n;
    if (o->ro->op->q == 1 && o->ro->op->p > 0) { /* dv' = M dv + dM v */
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)nd, (int)n, 1.0, o->M, (int)n, dV, (int)nd,
                  0.0, tmp, (int)nd);
      memcpy(dV, tmp, sizeof(double) * (size_t)(n * nd));
      if (op_dM_times(dv, o, v, 1.0, false, dV)) break;
    } else if (o->ro->op->q == 1) { /* dv' = M⁻¹ (dv − dM v') */
      if (op_dM_times(dv, o, v2, -1.0, false, dV)) break;
      op_solve(o, false, dV, nd, tmp);
    } else { /* dv' = f(M) dv + U (F ∘ Uᵀ dM U) Uᵀ v */
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, (int)n, 1.0, o->U, (int)n, v, 1, 0.0, w, 1);
      for (long d = 0; d < nd; d++) {
        for (long i = 0; i < n; i++) t[i] = dV[i * nd + d];
        root_apply(o, t, col, A);
        if (dm) {
          dk_forward(o, dM + d * n * n, w, t, A);
          for (long i = 0; i < n; i++) col[i] += t[i];
        }
        for (long i = 0; i < n; i++) dV[i * nd + d] = col[i];
      }
    }
  }
  scratch_release(&sc);
  return rc || err_held(dv->err) ? -1 : 0;
}

/* Reverse through one power: Vb (n x nd), the cotangent of the result, becomes that of its
 * operand; the operator's cotangent goes to its inputs. */
static int op_reverse(Deriv *dv, const OpState *o, const double *vs, double *Vb) {
  long n = o->n, nd = dv->nd, steps = op_steps(o);
  bool dm = false, root = o->ro->op->q != 1; /* M̄ formed for roots only */
  for (int g = 0; g < o->ro->ntensors; g++) dm = dm || (root && tensor_active(dv, &o->ro->t[g]));
  Scratch sc = SCRATCH_OF(NULL);
  double *Mb = dm ? scratch_array(&sc, (size_t)(nd * n * n) + 1, sizeof(double)) : NULL;
  double *tmp = scratch_array_unzeroed(&sc, (size_t)(n * nd + 2 * n * n + 2 * n + 1), sizeof(double));
  int rc = (dm && !Mb) || !tmp ? dfail_oom(dv) : 0;
  double *A = NULL, *B = NULL, *w = NULL;
  if (tmp) A = tmp + n * nd, B = A + n * n, w = B + n * n;
  double e = (double)o->ro->op->p / (double)o->ro->op->q;
  for (long s = steps - 1; s >= 0 && rc == 0; s--) {
    const double *v = vs + s * n, *v2 = vs + (s + 1) * n;
    if (o->ro->op->q == 1 && o->ro->op->p > 0) { /* M̄ = v̄' vᵀ to the inputs, v̄ = Mᵀ v̄' */
      if (op_dM_times(dv, o, v, 1.0, true, Vb)) break;
      cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)n, (int)nd, (int)n, 1.0, o->M, (int)n, Vb, (int)nd,
                  0.0, tmp, (int)nd);
      memcpy(Vb, tmp, sizeof(double) * (size_t)(n * nd));
    } else if (o->ro->op->q == 1) { /* λ = M⁻ᵀ v̄', M̄ −= λ v'ᵀ, v̄ = λ */
      op_solve(o, true, Vb, nd, tmp);
      if (op_dM_times(dv, o, v2, -1.0, true, Vb)) break;
    } else { /* ū = Uᵀ v̄': M̄ += U (F ∘ ū wᵀ) Uᵀ, w = Uᵀ v; v̄ = U f(Λ) ū */
      cblas_dgemv(CblasRowMajor, CblasTrans, (int)n, (int)n, 1.0, o->U, (int)n, v, 1, 0.0, w, 1);
      cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)n, (int)nd, (int)n, 1.0, o->U, (int)n, Vb, (int)nd,
                  0.0, tmp, (int)nd);
      for (long d = 0; dm && d < nd; d++) {
        for (long i = 0; i < n; i++)
          for (long j = 0; j < n; j++) A[i * n + j] = o->F[i * n + j] * tmp[i * nd + d] * w[j];
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)n, (int)n, 1.0, o->U, (int)n, A, (int)n,
                    0.0, B, (int)n);
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)n, (int)n, (int)n, 1.0, B, (int)n, o->U, (int)n, 1.0,
                    Mb + d * n * n, (int)n);
      }
      for (long i = 0; i < n; i++)
        for (long d = 0; d < nd; d++) tmp[i * nd + d] *= root_f(o->lam[i], e);
      cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)nd, (int)n, 1.0, o->U, (int)n, tmp, (int)nd,
                  0.0, Vb, (int)nd);
    }
  }
  if (rc == 0) rc = err_held(dv->err) ? -1 : dm ? op_cotangent(dv, o, Mb) : 0;
  scratch_release(&sc);
  return rc;
}

/* ---------------------------------------------------------------- Galerkin stages */

/* One term's primal: its numerator v0 and, per operator, its state and the
 * chain of its steps (vs[k]: op_steps + 1 vectors of n, vs[k][0] its operand). */
typedef struct TermState {
  int nops;
  OpState *ops;
  double **vs;
  bool kept;  /* the chains are the evaluator's (reduced_kept) */
  Scratch mem; /* its arrays and its operators' own (zero: empty), released with the term */
} TermState;

/* ts->ops and ts->vs for `nops` operators, each operator's arrays in ts->mem. */
static int term_alloc(TermState *ts, int nops) {
  ts->nops = nops;
  ts->ops = scratch_array(&ts->mem, (size_t)nops + 1, sizeof(OpState));
  ts->vs = scratch_array(&ts->mem, (size_t)nops + 1, sizeof(double *));
  for (int k = 0; ts->ops && k < nops; k++) ts->ops[k].mem = &ts->mem;
  return ts->ops && ts->vs ? 0 : -1;
}

/* Term `t` of stage rs as the evaluation kept it, or 1 when it kept none (reduced_kept). */
static int term_kept(Deriv *dv, const RStage *rs, int t, long n, TermState *ts) {
  const RTerm *rt = &rs->terms[t];
  int stage = (int)(rs - dv->m->stages);
  for (int k = 0; k < rt->nops; k++)
    if (!reduced_kept(dv->r, stage, t, k)) return 1;
  ts->kept = true;
  if (term_alloc(ts, rt->nops)) return dfail_oom(dv);
  for (int k = 0; k < rt->nops; k++) {
    const ReducedKept *kp = reduced_kept(dv->r, stage, t, k);
    ts->vs[k] = kp->chain;
    if (op_state_kept(dv, rs, &rt->ops[k], n, kp, &ts->ops[k])) return -1;
  }
  return 0;
}

/* Term rt's primal recomputed from the coordinates: its numerator, each operator assembled,
 * factored and applied; the numerator and work vectors from `sc`. */
static int term_primal_in(Deriv *dv, const RStage *rs, const RTerm *rt, long n, TermState *ts, Scratch *sc) {
  const Model *m = dv->m;
  double *v0 = scratch_array(sc, (size_t)n + 1, sizeof(double)), *w = scratch_array(sc, (size_t)n + 1, sizeof(double));
  if (!v0 || !w) return dfail_oom(dv);
  if (rt->named_q >= 0) {
    if (rt->proj)
      cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)qm(m, rt->named_q), 1.0, rt->proj, (int)qm(m, rt->named_q),
                  dv->x[rt->named_q], 1, 0.0, v0, 1);
    else memcpy(v0, dv->x[rt->named_q], sizeof(double) * (size_t)n);
  } else
    for (int g = 0; g < rt->nnum; g++) {
      const double *z[RT_MAX_IN];
      double *zbuf = scratch_array(sc, (size_t)tensor_zlen(&rt->num[g]), sizeof(double));
      if (!zbuf || contract_into(&rt->num[g], (tensor_z(dv, &rt->num[g], z, zbuf), z), v0, sc)) return dfail_oom(dv);
    }
  const double *in = v0;
  for (int k = 0; k < rt->nops; k++) {
    if (op_state(dv, rs, &rt->ops[k], n, &ts->ops[k])) return -1;
    long steps = op_steps(&ts->ops[k]);
    if (!(ts->vs[k] = scratch_array_unzeroed(&ts->mem, (size_t)((steps + 1) * n + 1), sizeof(double))))
      return dfail_oom(dv);
    memcpy(ts->vs[k], in, sizeof(double) * (size_t)n);
    op_forward_primal(&ts->ops[k], ts->vs[k], w);
    in = ts->vs[k] + steps * n;
  }
  return 0;
}

/* term_primal_in with a scratch released at its end; `ts` (its own scratch) holds the primal. */
static int term_primal(Deriv *dv, const RStage *rs, const RTerm *rt, long n, TermState *ts) {
  Scratch sc = SCRATCH_OF(NULL);
  int rc = term_alloc(ts, rt->nops) == 0 ? term_primal_in(dv, rs, rt, n, ts, &sc) : dfail_oom(dv);
  scratch_release(&sc);
  return rc;
}

/* The numerator's tangent (forward, into dV) or cotangent (reverse, from Vb). */
static int term_numerator(Deriv *dv, const RTerm *rt, long n, bool reverse, double *V) {
  long nd = dv->nd;
  if (rt->named_q < 0) {
    for (int g = 0; g < rt->nnum; g++)
      if (tensor_tangent(dv, &rt->num[g], reverse, V, V)) return -1;
    return 0;
  }
  int w = rt->named_q;
  if (!dv->active[w]) return 0;
  long mw = qm(dv->m, w);
  if (!rt->proj) cblas_daxpy((int)(n * nd), 1.0, reverse ? V : dv->d[w], 1, reverse ? dv->d[w] : V, 1);
  else if (reverse)
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)mw, (int)nd, (int)n, 1.0, rt->proj, (int)mw, V, (int)nd,
                1.0, dv->d[w], (int)nd);
  else forward_product(dv, w, n, 1.0, rt->proj, V);
  return 0;
}

static int galerkin_stage(Deriv *dv, const RStage *rs, bool reverse) {
  long n = qm(dv->m, rs->q), nd = dv->nd;
  Scratch sc = SCRATCH_OF(NULL);
  double *V = scratch_array_unzeroed(&sc, (size_t)(n * nd + 1), sizeof(double));
  int rc = V ? 0 : dfail_oom(dv);
  for (int t = 0; t < rs->nterms && rc == 0; t++) {
    const RTerm *rt = &rs->terms[t];
    TermState ts = {0};
    if (rt->nops > 0 && (rc = term_kept(dv, rs, t, n, &ts)) == 1) { /* not kept: recomputed */
      scratch_release(&ts.mem);
      memset(&ts, 0, sizeof ts);
      rc = term_primal(dv, rs, rt, n, &ts);
    }
    if (rc == 0 && !reverse) {
      memset(V, 0, sizeof(double) * (size_t)(n * nd));
      rc = term_numerator(dv, rt, n, false, V);
      for (int k = 0; k < rt->nops && rc == 0; k++) rc = op_forward(dv, &ts.ops[k], ts.vs[k], V);
      if (rc == 0) cblas_daxpy((int)(n * nd), 1.0, V, 1, dv->d[rs->q], 1);
    } else if (rc == 0) {
      memcpy(V, dv->d[rs->q], sizeof(double) * (size_t)(n * nd));
      for (int k = rt->nops - 1; k >= 0 && rc == 0; k--) rc = op_reverse(dv, &ts.ops[k], ts.vs[k], V);
      if (rc == 0) rc = term_numerator(dv, rt, n, true, V);
    }
    scratch_release(&ts.mem);
  }
  scratch_release(&sc);
  return rc;
}

/* ---------------------------------------------------------------- interpolated stages */

/* b^(p/q): small integer and half-integer powers by multiplication and one sqrt (one per
 * selected entry and operator, as interp.c's evaluation), others by pow(). */
static double interp_pow(double b, long p, long q) {
  if ((q == 1 || q == 2) && p >= -16 && p <= 16) {
    double base = q == 2 ? sqrt(b) : b, v = 1;
    for (long i = 0; i < labs(p); i++) v *= base;
    return p < 0 ? 1 / v : v;
  }
  return pow(b, (double)p / (double)q);
}

/* What interp_stage computes once for all the quantities its formula reads. */
typedef struct InterpPartials {
  const RStage *rs;
  const long *base;  /* per term: the row of its numerator in g, its operators' rows after it */
  const double *val; /* the read entries */
  const double *g;   /* ∂(P y)[s]/∂acc: rows x k */
  const double *pT;  /* the fit transposed, k x m_y */
  bool reverse;
} InterpPartials;

/* Forward: d[y] += J_q d[q]; reverse: d[q] += J_qᵀ d[y], J_q = (W P B)⁺ W · ∂(P y)/∂x̂_q for one
 * quantity q the formula reads, g = ∂(P y)/∂acc and val the read entries (interp_stage's), pT the
 * fit transposed (k x m_y). Each monomial's read of q adds its coefficient times the fit's
 * column of its slot to C's row of the read (C: reads x m_y), then J_q = Cᵀ B_read, B_read the
 * rows of q's basis read: m_y FLOPs a monomial and one dgemm, where forming ∂(P y)/∂x̂_q
 * (k x m_q) first took m_q a monomial and a product of k·m_y·m_q (heat.npg's k: 948 monomials,
 * k = 316, the stage's largest cost). */
static int interp_jacobian(Deriv *dv, const InterpPartials *pa, int q) {
  const Model *m = dv->m;
  const RStage *rs = pa->rs;
  const long *base = pa->base;
  const double *g = pa->g, *val = pa->val, *pT = pa->pT;
  bool reverse = pa->reverse;
  const RInterp *ip = rs->interp;
  const RClass *c = &m->classes[m->qclass[q]];
  long mq = c->m, my = qm(m, rs->q), nd = dv->nd, k = ip->k, nr = 0;
  Scratch sc = SCRATCH_OF(NULL);
  long *row = scratch_array_unzeroed(&sc, (size_t)(ip->nreads + 1), sizeof(long));
  double *C = scratch_array(&sc, (size_t)(ip->nreads * my) + 1, sizeof(double));
  double *Br = scratch_array_unzeroed(&sc, (size_t)(ip->nreads * mq + 1), sizeof(double));
  double *J = scratch_array_unzeroed(&sc, (size_t)(my * mq + 1), sizeof(double));
  int rc = row && C && Br && J ? 0 : dfail_oom(dv);
  for (long r = 0; r < ip->nreads && rc == 0; r++) {
    row[r] = ip->read_q[r] == q ? nr : -1;
    if (row[r] >= 0) memcpy(Br + nr++ * mq, c->B + ip->read_e[r] * mq, sizeof(double) * (size_t)mq);
  }
  for (long i = 0; i < ip->nmono && rc == 0; i++) {
    const RInterpMono *mo = &ip->mono[i];
    double gi = g[(base[mo->term] + mo->factor) * k + mo->slot] * mo->coef;
    for (int j = 0; j < mo->nin; j++) {
      long r = mo->read[j];
      if (row[r] < 0) continue;
      double cj = gi;
      for (int l = 0; l < mo->nin; l++)
        if (l != j) cj *= val[mo->read[l]];
      const double *col = pT + mo->slot * my; /* a loop: cblas_daxpy's call cost more at these m */
      double *dst = C + row[r] * my;
      for (long a = 0; a < my; a++) dst[a] += cj * col[a];
    }
  }
  if (rc == 0 && nr > 0)
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)my, (int)mq, (int)nr, 1.0, C, (int)my, Br, (int)mq, 0.0,
                J, (int)mq);
  else if (rc == 0) memset(J, 0, sizeof(double) * (size_t)(my * mq));
  if (rc == 0 && reverse)
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)mq, (int)nd, (int)my, 1.0, J, (int)mq, dv->d[rs->q],
                (int)nd, 1.0, dv->d[q], (int)nd);
  else if (rc == 0) forward_product(dv, q, my, 1.0, J, dv->d[rs->q]);
  scratch_release(&sc);
  return rc;
}

/* interp_stage's buffers: per term the row of its numerator (then its operators') in acc and g,
 * the read entries, the formula's sums (acc, k per row), their partials (g) and the fit
 * transposed (pT, k x m_y). */
typedef struct InterpWork {
  long *base;
  double *val, *acc, *g, *pT;
} InterpWork;

/* Forward: d[y] += J_q d[q]; reverse: d[q] += J_qᵀ d[y], for every active quantity q the
 * formula reads, J_q = (W P B)⁺ W · ∂(P y)/∂x̂_q from its monomials (RInterp.mono). */
static int interp_stage_in(Deriv *dv, const RStage *rs, bool reverse, const InterpWork *wk) {
  const Model *m = dv->m;
  const long *base = wk->base;
  double *val = wk->val, *acc = wk->acc, *g = wk->g, *pT = wk->pT;
  const RInterp *ip = rs->interp;
  long k = ip->k, my = qm(m, rs->q);
  int rc;
  for (long r = 0; r < ip->nreads; r++) {
    const RClass *c = &m->classes[m->qclass[ip->read_q[r]]];
    val[r] = cblas_ddot((int)c->m, c->B + ip->read_e[r] * c->m, 1, dv->x[ip->read_q[r]], 1);
  }
  for (long i = 0; i < ip->nmono; i++) {
    const RInterpMono *mo = &ip->mono[i];
    double v = mo->coef;
    for (int j = 0; j < mo->nin; j++) v *= val[mo->read[j]];
    acc[(base[mo->term] + mo->factor) * k + mo->slot] += v;
  }
  for (int t = 0; t < rs->nterms; t++) { /* g = ∂(P y)[s]/∂acc */
    const RTerm *rt = &rs->terms[t];
    for (long s = 0; s < k; s++) {
      double num = acc[base[t] * k + s], all = 1, pw[RT_MAX_IN];
      for (int o = 0; o < rt->nops && o < RT_MAX_IN; o++)
        all *= pw[o] = interp_pow(acc[(base[t] + o + 1) * k + s], rt->ops[o].op->p, rt->ops[o].op->q);
      g[base[t] * k + s] = all;
      for (int o = 0; o < rt->nops && o < RT_MAX_IN; o++) { /* ∂(d^e)/∂d = e d^e / d, the rest's product kept */
        double rest = num, e = (double)rt->ops[o].op->p / (double)rt->ops[o].op->q, d = acc[(base[t] + o + 1) * k + s];
        for (int o2 = 0; o2 < rt->nops && o2 < RT_MAX_IN; o2++)
          if (o2 != o) rest *= pw[o2];
        g[(base[t] + o + 1) * k + s] = rest * e * (d != 0 ? pw[o] / d : pow(d, e - 1));
      }
    }
  }
  rc = 0;
  for (long s = 0; s < k; s++) /* the fit transposed, k x my: a slot's column contiguous */
    for (long i = 0; i < my; i++) pT[s * my + i] = ip->pinv[i * k + s];
  InterpPartials pa = {rs, base, val, g, pT, reverse};
  for (int q = 0; q < m->nq && rc == 0; q++) {
    if (!dv->active[q]) continue;
    bool reads = false;
    for (long r = 0; r < ip->nreads && !reads; r++) reads = ip->read_q[r] == q;
    if (!reads) continue;
    rc = interp_jacobian(dv, &pa, q);
  }
  return rc;
}

/* interp_stage_in with its accumulators from a scratch. */
static int interp_stage(Deriv *dv, const RStage *rs, bool reverse) {
  const RInterp *ip = rs->interp;
  long k = ip->k, nf = 0, my = qm(dv->m, rs->q);
  Scratch sc = SCRATCH_OF(NULL);
  long *base = scratch_array(&sc, (size_t)rs->nterms + 1, sizeof(long));
  for (int t = 0; base && t < rs->nterms; t++) base[t] = nf, nf += 1 + rs->terms[t].nops;
  double *val = scratch_array(&sc, (size_t)ip->nreads + 1, sizeof(double));
  double *acc = scratch_array(&sc, (size_t)(k * nf) + 1, sizeof(double));
  double *g = scratch_array(&sc, (size_t)(k * nf) + 1, sizeof(double));
  double *pT = scratch_array(&sc, (size_t)(k * my) + 1, sizeof(double));
  int rc = base && val && acc && g && pT ? interp_stage_in(dv, rs, reverse, &(InterpWork){base, val, acc, g, pT})
                                         : dfail_oom(dv);
  scratch_release(&sc);
  return rc;
}

/* ---------------------------------------------------------------- sweeps */

/* Whether stage rs reads an active quantity. */
static bool stage_reads_active(const Deriv *dv, const RStage *rs) {
  const Model *m = dv->m;
  if (rs->st->kind == ST_EXTERN) {
    if (dv->given_externs) return false; /* the caller's values: constants here */
    for (int k = 0; k < m->nexterns; k++)
      if (m->externs[k].q == rs->q)
        for (int j = 0; j < m->externs[k].nin; j++)
          if (dv->active[m->externs[k].in_q[j]]) return true;
    return false;
  }
  if (rs->interp) {
    for (long r = 0; r < rs->interp->nreads; r++)
      if (dv->active[rs->interp->read_q[r]]) return true;
    return false;
  }
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    if (rt->named_q >= 0 && dv->active[rt->named_q]) return true;
    RTERM_FOR_TENSORS(rt, x) {
      if (tensor_active(dv, x)) return true;
    }
  }
  return false;
}

static int stage_derivative(Deriv *dv, const RStage *rs, bool reverse) {
  if (rs->st->kind == ST_EXTERN)
    return err_set(dv->err, "extern '%s' depends on the differentiated input, and its learned map (a "
                   "convex combination of training samples) has no derivative", rs->st->sym->name);
  if (rs->interp) return interp_stage(dv, rs, reverse);
  return galerkin_stage(dv, rs, reverse);
}

/* Every quantity's block allocated (zero), none active yet (deriv_activate). */
static int deriv_init(Deriv *dv, Reduced *r, long nd, long sample, Err *err) {
  memset(dv, 0, sizeof *dv);
  dv->r = r, dv->ident_q = -1;
  dv->m = reduced_model(r), dv->nd = nd, dv->sample = sample, dv->err = err;
  /* a failure is known by its message: a record without a buffer gets one */
  if (!err || !err->msg || !err->len) dv->own = (Err){dv->own_msg, sizeof dv->own_msg}, dv->err = &dv->own;
  dv->cache_slot = reduced_deriv_cache(r);
  dv->given_externs = reduced_given_externs(r);
  dv->err->msg[0] = 0;
  dv->sc = SCRATCH_OF(NULL);
  const Model *m = dv->m;
  double **x = scratch_array(&dv->sc, (size_t)m->nq + 1, sizeof(double *));
  dv->d = scratch_array(&dv->sc, (size_t)m->nq + 1, sizeof(double *));
  dv->active = scratch_array(&dv->sc, (size_t)m->nq + 1, sizeof(bool));
  if (!x || !dv->d || !dv->active) return dfail_oom(dv);
  for (int q = 0; q < m->nq; q++) {
    x[q] = reduced_coords(r, q);
    if (!(dv->d[q] = scratch_array(&dv->sc, (size_t)(qm(m, q) * nd) + 1, sizeof(double)))) return dfail_oom(dv);
  }
  dv->x = x;
  return 0;
}

/* The quantities depending on `from` (one input, or the seeds' quantities). */
static void deriv_activate(Deriv *dv, const int *from, int nfrom) {
  const Model *m = dv->m;
  for (int i = 0; i < nfrom; i++) dv->active[from[i]] = true;
  for (int i = 0; i < m->nstages; i++)
    if (!dv->active[m->stages[i].q] && stage_reads_active(dv, &m->stages[i])) dv->active[m->stages[i].q] = true;
}

int reduced_jvp(Reduced *r, const ReducedSeeds *seeds, int out_q, double *out, long sample, Err *err) {
  Deriv dv;
  long nd = seeds->nd;
  int rc = deriv_init(&dv, r, nd, sample, err);
  const Model *m = dv.m;
  if (rc == 0) deriv_activate(&dv, seeds->q, seeds->n);
  if (seeds->identity) dv.ident_q = seeds->q[0];
  for (int i = 0; i < seeds->n && rc == 0; i++)
    cblas_daxpy((int)(qm(m, seeds->q[i]) * nd), 1.0, seeds->block[i], 1, dv.d[seeds->q[i]], 1);
  for (int i = 0; i < m->nstages && rc == 0; i++) {
    const RStage *rs = &m->stages[i];
    bool seeded = false;
    for (int s = 0; s < seeds->n; s++) seeded = seeded || seeds->q[s] == rs->q;
    if (dv.active[rs->q] && !seeded) rc = stage_derivative(&dv, rs, false);
  }
  if (rc == 0) memcpy(out, dv.d[out_q], sizeof(double) * (size_t)(qm(m, out_q) * nd));
  scratch_release(&dv.sc);
  return rc ? -1 : 0;
}

int reduced_vjp(Reduced *r, const ReducedSeeds *seeds, int in_q, double *out, long sample, Err *err) {
  Deriv dv;
  long nd = seeds->nd;
  int rc = deriv_init(&dv, r, nd, sample, err);
  const Model *m = dv.m;
  if (rc == 0) deriv_activate(&dv, &in_q, 1);
  for (int i = 0; i < seeds->n && rc == 0; i++)
    if (dv.active[seeds->q[i]])
      cblas_daxpy((int)(qm(m, seeds->q[i]) * nd), 1.0, seeds->block[i], 1, dv.d[seeds->q[i]], 1);
  for (int i = m->nstages - 1; i >= 0 && rc == 0; i--) {
    const RStage *rs = &m->stages[i];
    if (dv.active[rs->q] && rs->q != in_q) rc = stage_derivative(&dv, rs, true);
  }
  if (rc == 0) memcpy(out, dv.d[in_q], sizeof(double) * (size_t)(qm(m, in_q) * nd));
  scratch_release(&dv.sc);
  return rc ? -1 : 0;
}

int reduced_jacobian(Reduced *r, int out_q, int in_q, double *J, long sample, Err *err) {
  const Model *m = reduced_model(r);
  long mo = qm(m, out_q), mi = qm(m, in_q);
  bool forward = mi <= mo;
  long nd = forward ? mi : mo;
  Scratch sc = SCRATCH_OF(NULL);
  double *eye = scratch_array(&sc, (size_t)(nd * nd) + 1, sizeof(double));
  double *T = forward ? NULL : scratch_array_unzeroed(&sc, (size_t)(mi * mo + 1), sizeof(double));
  const double *seed = eye;
  int rc = !eye || (!forward && !T) ? err_set(err, "out of memory for the reduced Jacobian") : 0;
  for (long i = 0; i < nd && rc == 0; i++) eye[i * nd + i] = 1;
  if (rc == 0)
    rc = forward ? reduced_jvp(r, &(ReducedSeeds){1, &in_q, &seed, nd, true}, out_q, J, sample, err)
                 : reduced_vjp(r, &(ReducedSeeds){1, &out_q, &seed, nd, false}, in_q, T, sample, err);
  if (rc == 0 && !forward)
    for (long a = 0; a < mo; a++)
      for (long b = 0; b < mi; b++) J[a * mi + b] = T[b * mo + a];
  scratch_release(&sc);
  return rc;
}

/* One stage's local partial (reduced_stage_jvp, reduced_stage_vjp): the stage, the sample, the direction. */
typedef struct StageSweep {
  int stage;
  long sample;
  bool reverse;
} StageSweep;

/* Forward: the seed on input in->q[0], the stage's tangent out; reverse: the seed on the stage's quantity, the
 * input's adjoint out. Every other quantity keeps a zero block: stage `stage` alone is differentiated (in
 * reverse the adjoints it adds to its other inputs are not read). */
static int stage_sweep(Reduced *r, const StageSweep *sw, const ReducedSeeds *in, double *out, Err *err) {
  Deriv dv;
  int in_q = in->q[0];
  long nd = in->nd;
  int rc = deriv_init(&dv, r, nd, sw->sample, err);
  const Model *m = dv.m;
  const RStage *rs = &m->stages[sw->stage];
  int seeded = sw->reverse ? rs->q : in_q, read = sw->reverse ? in_q : rs->q;
  if (rc == 0) deriv_activate(&dv, &in_q, 1);
  if (rc == 0) cblas_dcopy((int)(qm(m, seeded) * nd), in->block[0], 1, dv.d[seeded], 1);
  if (rc == 0 && dv.active[rs->q] && rs->q != in_q) rc = stage_derivative(&dv, rs, sw->reverse);
  if (rc == 0) memcpy(out, dv.d[read], sizeof(double) * (size_t)(qm(m, read) * nd));
  scratch_release(&dv.sc);
  return rc ? -1 : 0;
}

int reduced_stage_jvp(Reduced *r, int stage, const ReducedSeeds *in, double *out, long sample, Err *err) {
  return stage_sweep(r, &(StageSweep){stage, sample, false}, in, out, err);
}

int reduced_stage_vjp(Reduced *r, int stage, const ReducedSeeds *in, double *out, long sample, Err *err) {
  return stage_sweep(r, &(StageSweep){stage, sample, true}, in, out, err);
}
