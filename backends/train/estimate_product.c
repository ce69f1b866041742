/* estimate_product.c — the estimate tables of an inverse term whose class is orthonormal in a
 * product K0 (`basis u: product K0`, issue 41; docs/estimates.md "In a product"): the error is
 * measured in K0's norm, as pyMOR's coercive reduced-basis estimator does,
 *
 *     ‖u − B û‖_K0 ≤ ‖r‖_{K0⁻¹} / α_LB(x),    r = w − M(x) B û = C z,
 *
 * with ‖r‖_{K0⁻¹} = √(rᵀK0⁻¹r) the residual's dual norm and α_LB(x) ≤ inf_v vᵀM(x)v / vᵀK0v the
 * min-θ lower bound relative to K0.
 *
 * Dual norm. K0 = PᵀLLᵀP (CHOLMOD), so rᵀK0⁻¹r = ‖L⁻¹P C z‖²: the columns become Y = L⁻¹PC. Galerkin
 * makes Bᵀr = 0, i.e. Y z orthogonal to V = L⁻¹P K0B (VᵀY = BᵀC, VᵀV = BᵀK0B = I), so the caller
 * projects Y by I − VVᵀ and keeps R of its QR, as in the Euclidean case.
 *
 * Coercivity. M(x) = M_0 + Σ x_j M_j (estimate_affine_parts). Let S be the rows where the error is
 * zero whatever x: rows i where every M_j (j ≥ 1) is zero, M_0 has only its diagonal (≠ 0), the
 * numerator's columns are zero (Dirichlet rows: u_i = w_i / M_0[i,i] = 0, and (B û)_i = 0 when B's rows there are
 * zero: to 1e-6 of its largest entry, else the figure is flagged an estimate, est_sigma = 1). On the
 * other rows T, if every M_j restricted to T×T is symmetric positive semidefinite (by diagonal
 * dominance) and K0 restricted to T×T equals M(x̄) restricted for an x̄ > 0 (found by least squares
 * over the entries, then checked to 1e-12), then for e = u − B û (e_S = 0)
 *
 *     eᵀM(x)e = Σ θ_j(x) e_TᵀM_j e_T ≥ ρ e_TᵀM(x̄)e_T = ρ ‖e‖²_K0,   ρ = min(1, min_j x_j / x̄_j),
 *
 * and eᵀM(x)e = eᵀr ≤ ‖e‖_K0 ‖r‖_{K0⁻¹}: the bound above with α_LB = ρ, stored as one min-θ anchor
 * (x̄, 1). The rows S make pyMOR's matrices (Dirichlet rows of the parameter terms cleared, columns
 * not: nonsymmetric) qualify.
 *
 * The pencil. When K0 is M(x̄) at no positive x̄ on T, the same argument holds at any x̄ > 0 with
 * α(x̄) = λ_min of the pencil (M(x̄), K0) on T×T: eᵀM(x)e ≥ ρ e_TᵀM(x̄)e_T ≥ ρ α(x̄) ‖e‖²_K0. The
 * anchors are up to ESTIMATE_SIGMA_SAMPLES training samples with every x̄_j > 0 (spread over the
 * set), α(x̄) by LAPACK's dsygvd on the dense T×T matrices, to its roundoff, up to ESTIMATE_DENSE_MAX
 * rows of T; above, 1/λ_max(M(x̄)⁻¹K0) by Lanczos in K0's inner product (one Cholesky of M(x̄) per
 * anchor), erring low provided Lanczos found the top eigenvalue, as estimate_train.c's σ_min.
 *
 * A projection term ŷ = BᵀK0 w (the reduced evaluator projects by the dual D = K0B): its error
 * (I − BBᵀK0) w, in K0's norm ‖LᵀP(I − BBᵀK0)w‖ = ‖(I − VVᵀ) LᵀPw‖ with V = LᵀPB = L⁻¹P K0B
 * (VᵀV = BᵀK0B = I): the columns become LᵀPC = L⁻¹P K0C, projected and QR'd as the Euclidean
 * table, an exact figure. So is an application's (a term that only applies operators to positive powers, reduced as
 * ŷ = (DᵀMB)^p Dᵀw: estimate_term_applies): each block of its columns (the numerator's, M B ⊗ each operator's
 * monomials) is the error of a K0-projection, weighted the same way and QR'd block by block by the caller; and per
 * operator the ratio c = max ‖LᵀML⁻ᵀ‖₂ / ‖DᵀMB‖₂ over training samples (‖M‖_K0 ≈ c ‖DᵀMB‖₂ online; dense K0 = LLᵀ
 * up to ESTIMATE_DENSE_MAX rows, Lanczos in K0's inner product above: application_ratios). A term of several
 * operators with one solve (K⁻¹ M w, M K⁻¹ w: estimate_product_chains) keeps the solve's block (its operand's
 * producer's columns joined with its own) a residual, L⁻¹P-weighted for its dual norm, gets the solve's min-θ table
 * relative to K0 (chain_columns), and the ratio of an operator applied before it is into K0⁻¹'s norm,
 * ‖L⁻¹ML⁻ᵀ‖₂ / ‖BᵀMB‖₂.
 *
 * A named numerator w whose own error e_w is in its class's norm (the 2-norm, or its product K1's)
 * enters an inverse term's residual in K0⁻¹'s norm and a projection's error in K0's:
 * ‖v‖_{K0⁻¹} ≤ ‖v‖₂ / √λ_min(K0), ‖v‖_K0 ≤ √λ_max(K0) ‖v‖₂, ‖v‖₂ ≤ ‖v‖_K1 / √λ_min(K1) (none of
 * these when both norms are K0's, for a projection). The factor is est_carry (estimate_product_carry). With
 * a named numerator the rows S need its basis zero there, and the true w's values on S (not its
 * basis's) are not seen: the figure is flagged an estimate when S is not empty. */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "estimate_steps.h"
#include "scratch.h"

/* X (n x D row-major) <- L⁻¹ P X, L the LLᵀ factor of K0 = PᵀLLᵀP. */
static int solve_lower(cholmod_factor *L, double *X, long n, long D, cholmod_common *cc) {
  cholmod_dense *b = cholmod_l_allocate_dense((size_t)n, (size_t)D, (size_t)n, CHOLMOD_REAL, cc), *p = NULL, *y = NULL;
  if (!b) return -1;
  double *bx = b->x;
  for (long i = 0; i < n; i++)
    for (long c = 0; c < D; c++) bx[c * n + i] = X[i * D + c];
  if ((p = cholmod_l_solve(CHOLMOD_P, L, b, cc)) && (y = cholmod_l_solve(CHOLMOD_L, L, p, cc))) {
    const double *yx = y->x;
    for (long i = 0; i < n; i++)
      for (long c = 0; c < D; c++) X[i * D + c] = yx[c * n + i];
  }
  int ok = y ? 0 : -1;
  cholmod_l_free_dense(&b, cc), cholmod_l_free_dense(&p, cc), cholmod_l_free_dense(&y, cc);
  return ok;
}

/* Σ A_ij B_ij over the entries (w: n zeros on entry and exit). */
static double frobenius_dot(const cholmod_sparse *A, const cholmod_sparse *B, double *w) {
  const SuiteSparse_long *Ap = A->p, *Ai = A->i, *Bp = B->p, *Bi = B->i;
  const double *Ax = A->x, *Bx = B->x;
  double s = 0;
  for (long j = 0; j < (long)A->ncol; j++) {
    for (SuiteSparse_long k = Ap[j]; k < Ap[j + 1]; k++) w[Ai[k]] += Ax[k];
    for (SuiteSparse_long k = Bp[j]; k < Bp[j + 1]; k++) s += w[Bi[k]] * Bx[k];
    for (SuiteSparse_long k = Ap[j]; k < Ap[j + 1]; k++) w[Ai[k]] = 0;
  }
  return s;
}

/* error_rows's marks: the rows T found, scratch of n entries, and whether B is zero on the rows S. */
typedef struct RowMarks {
  SuiteSparse_long *T;      /* the rows T */
  bool *bad;                /* n: a row some M_j (j ≥ 1) or M_0 off its diagonal reaches */
  double *diag;             /* n: M_0's diagonal */
  bool b_zero;              /* in: true */
  bool named;               /* in: the numerator's columns are a named numerator's basis (zero to 1e-6 of its
                               largest entry counts as zero there: full solves leave roundoff, as in B) */
} RowMarks;

/* The rows T the error can live on (every row but S, above), into rm->T; their count. rm->b_zero: B's
 * rows S are zero to 1e-6 of its largest entry (else the figure is an estimate: the full solves leave
 * roundoff at Dirichlet rows, which the trailing directions magnify: of B's largest entry 2.7e-12 at
 * pyMOR's grid 19, m = 31, 4.2e-9 at m = 58, above 1e-6 at grid 100, m = 31). */

static long error_rows(cholmod_sparse *const *K, size_t nx, const RClass *rc, const ResidualCols *cols, RowMarks *rm) {
  long n = rc->n, nt = 0, D = cols->D;
  const double *C = cols->C;
  bool *bad = rm->bad;
  double *diag = rm->diag;
  double bmax = 0;
  for (long e = 0; e < n * rc->m; e++) bmax = fmax(bmax, fabs(rc->B[e]));
  for (long i = 0; i < n; i++) bad[i] = false, diag[i] = 0;
  for (size_t j = 0; j <= nx; j++) {
    const SuiteSparse_long *Ap = K[j]->p, *Ai = K[j]->i;
    const double *Ax = K[j]->x;
    for (long c = 0; c < n; c++)
      for (SuiteSparse_long k = Ap[c]; k < Ap[c + 1]; k++) {
        if (Ax[k] == 0) continue;
        if (j == 0 && Ai[k] == c) diag[c] = Ax[k];
        else bad[Ai[k]] = true;
      }
  }
  double ctol = 0; /* an unnamed numerator's columns: exactly zero */
  for (long i = 0; rm->named && i < n; i++)
    for (long c = 0; c < cols->nnum; c++) ctol = fmax(ctol, 1e-6 * fabs(C[i * D + c]));
  for (long i = 0; i < n; i++) {
    bool zero = !bad[i] && diag[i] != 0;
    for (long c = 0; zero && c < cols->nnum; c++) zero = fabs(C[i * D + c]) <= ctol;
    for (long c = 0; zero && rm->b_zero && c < rc->m; c++) rm->b_zero = fabs(rc->B[i * rc->m + c]) <= 1e-6 * bmax;
    if (!zero) rm->T[nt++] = i;
  }
  return nt;
}

/* M_0 + Σ x_j M_j of the parts Kt[0..nx] as one sparse matrix; NULL out of memory. */
static cholmod_sparse *affine_sum(cholmod_sparse *const *Kt, size_t nx, const double *x, cholmod_common *cc) {
  double one[2] = {1, 0};
  cholmod_sparse *sum = cholmod_l_copy_sparse(Kt[0], cc);
  for (size_t j = 0; sum && j < nx; j++) {
    double c[2] = {x[j], 0};
    cholmod_sparse *t = cholmod_l_add(sum, Kt[j + 1], one, c, 1, 1, cc);
    cholmod_l_free_sparse(&sum, cc);
    sum = t;
  }
  return sum;
}

/* x̄ with K0 = M_0 + Σ x̄_j M_j on T×T (Kt[0..nx] and K0t restricted), each x̄_j > 0; false if none. */
static bool anchor(cholmod_sparse *const *Kt, size_t nx, cholmod_sparse *K0t, double *xbar, double *w,
                   cholmod_common *cc) {
  double G[ESTIMATE_THETA_MAX * ESTIMATE_THETA_MAX];
  for (size_t a = 0; a < nx; a++) {
    xbar[a] = frobenius_dot(Kt[a + 1], K0t, w) - frobenius_dot(Kt[a + 1], Kt[0], w);
    for (size_t b = 0; b < nx; b++) G[a * nx + b] = frobenius_dot(Kt[a + 1], Kt[b + 1], w);
  }
  if (LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', (int)nx, 1, G, (int)nx, xbar, 1) != 0) return false;
  cholmod_sparse *sum = affine_sum(Kt, nx, xbar, cc);
  bool ok = sum && estimate_sparse_close(K0t, sum, cc);
  for (size_t j = 0; ok && j < nx; j++) ok = xbar[j] > 0;
  cholmod_l_free_sparse(&sum, cc);
  return ok;
}

/* What the pencil's anchors read (product_theta's): the operator's parts and K0 on T×T, the input x. */
typedef struct Pencil {
  cholmod_sparse *const *Kt; /* M_0, M_1, …, M_nx restricted to T×T */
  size_t nx;
  cholmod_sparse *K0t;       /* K0 restricted to T×T */
  const char *input;         /* x's name */
} Pencil;

/* The sparse pencil's operands: A = M(x̄) on T×T by its Cholesky factor, K0 on T×T; or, for an operator's norm in
 * K0's (norm_step: `step` set), LA K0's factor, K K0, M the operator, `dual` its norm into K0⁻¹'s, tmp n doubles. */
typedef struct PencilOp {
  cholmod_factor *LA;
  cholmod_sparse *K;
  cholmod_common *cc;
  long n;
  cholmod_sparse *M;
  bool dual;
  double *tmp;
  int (*step)(const struct PencilOp *o, double *v, double *w); /* w = the operator at v; NULL: A⁻¹K0 v */
} PencilOp;

/* A vector of n doubles as a CHOLMOD dense column (no copy). */
static cholmod_dense column(double *x, long n) {
  cholmod_dense d = {0};
  d.nrow = d.nzmax = d.d = (size_t)n, d.ncol = 1, d.x = x, d.xtype = CHOLMOD_REAL, d.dtype = CHOLMOD_DOUBLE;
  return d;
}

/* y = K0 x; 0, or -1 when CHOLMOD fails. */
static int pencil_mult(const PencilOp *o, double *x, double *y) {
  double one[2] = {1, 0}, zero[2] = {0, 0};
  cholmod_dense X = column(x, o->n), Y = column(y, o->n);
  return cholmod_l_sdmult(o->K, 0, one, zero, &X, &Y, o->cc) ? 0 : -1;
}

/* w = A⁻¹ y; 0, or -1 when CHOLMOD fails. */
static int pencil_solve(const PencilOp *o, double *y, double *w) {
  cholmod_dense Y = column(y, o->n);
  cholmod_dense *r = cholmod_l_solve(CHOLMOD_A, o->LA, &Y, o->cc);
  if (!r) return -1;
  memcpy(w, r->x, sizeof(double) * (size_t)o->n);
  cholmod_l_free_dense(&r, o->cc);
  return 0;
}

/* w = K0⁻¹ Mᵀ X M v, X = K0, or K0⁻¹ with o->dual: self-adjoint and positive in K0's inner product, its largest
 * eigenvalue ‖M‖²_K0 (the norm from K0's norm to itself), or ‖M‖² from K0's norm into K0⁻¹'s. 0, or -1 when CHOLMOD
 * fails. */
static int norm_step(const PencilOp *o, double *v, double *w) {
  double one[2] = {1, 0}, zero[2] = {0, 0};
  cholmod_dense V = column(v, o->n), T = column(o->tmp, o->n), W = column(w, o->n);
  if (!cholmod_l_sdmult(o->M, 0, one, zero, &V, &T, o->cc) || (o->dual ? pencil_solve(o, o->tmp, w) : pencil_mult(o, o->tmp, w)))
    return -1;
  return cholmod_l_sdmult(o->M, 1, one, zero, &W, &T, o->cc) ? pencil_solve(o, o->tmp, w) : -1;
}

/* The Lanczos steps of the sparse pencil, at most (estimate_train.c's SPARSE_LANCZOS_STEPS). */
#define PENCIL_LANCZOS_STEPS 60

/* λ_max of A⁻¹K0 — self-adjoint and positive in K0's inner product, its eigenvalues 1/λ(M(x̄), K0) — by
 * Lanczos in that inner product (K0-orthonormal vectors V, their images K0V kept) with full
 * reorthogonalization, from a fixed start, until the top Ritz value's residual bound |β s| is below 1e-10
 * of it: θ + |β s| (an eigenvalue lies within |β s| of θ: the figure errs high, 1/it low, as the σ_min
 * Lanczos in estimate_train.c). NaN on failure. */
static double pencil_lanczos(const PencilOp *o, Scratch *sc) {
  long n = o->n;
  int K = n < PENCIL_LANCZOS_STEPS ? (int)n : PENCIL_LANCZOS_STEPS;
  double *V = scratch_array(sc, (size_t)(n * (K + 1)), sizeof(double)), *w = scratch_array(sc, (size_t)n, sizeof(double));
  double *KV = scratch_array(sc, (size_t)(n * (K + 1)), sizeof(double)), al[PENCIL_LANCZOS_STEPS + 1],
         be[PENCIL_LANCZOS_STEPS + 1], out = NAN;
  if (!V || !w || !KV) return NAN;
  for (long i = 0; i < n; i++) V[i] = 1.0 + 0.5 * sin(0.7 * (double)i); /* fixed, not K0-orthogonal to smooth modes */
  if (pencil_mult(o, V, KV)) return NAN;
  double s0 = 1 / sqrt(cblas_ddot((int)n, V, 1, KV, 1));
  cblas_dscal((int)n, s0, V, 1), cblas_dscal((int)n, s0, KV, 1);
  for (int j = 0; j < K; j++) {
    double *kv = KV + (long)j * n, *vn = V + (long)(j + 1) * n, *kvn = kv + n;
    if (o->step ? o->step(o, V + (long)j * n, w) : pencil_solve(o, kv, w)) return NAN; /* w = A⁻¹K0 v */
    al[j] = cblas_ddot((int)n, kv, 1, w, 1);
    for (int pass = 0; pass < 2; pass++) /* w -= V (VᵀK0 w), twice */
      for (int k = 0; k <= j; k++) cblas_daxpy((int)n, -cblas_ddot((int)n, KV + (long)k * n, 1, w, 1), V + (long)k * n, 1, w, 1);
    memcpy(vn, w, sizeof(double) * (size_t)n);
    if (pencil_mult(o, vn, kvn)) return NAN;
    be[j] = sqrt(fmax(cblas_ddot((int)n, vn, 1, kvn, 1), 0));
    double res, theta = estimate_ritz_top(al, be, j, &res);
    if (isnan(theta)) return NAN;
    out = theta + res;
    if (res <= 1e-10 * theta || be[j] <= 1e-14 * theta || j + 1 == K) break;
    cblas_dscal((int)n, 1 / be[j], vn, 1), cblas_dscal((int)n, 1 / be[j], kvn, 1);
  }
  return out;
}

/* α(x̄) above ESTIMATE_DENSE_MAX rows: 1/λ_max(A⁻¹K0) by pencil_lanczos, A = M(x̄) on T×T (`Ms`) by CHOLMOD's
 * supernodal Cholesky (an A not positive definite fails: NaN, no anchor). */
static double pencil_sparse(const Pencil *p, cholmod_sparse *Ms, cholmod_common *cc) {
  long n = (long)Ms->nrow;
  int super = cc->supernodal;
  cc->supernodal = CHOLMOD_SUPERNODAL; /* LLᵀ: an indefinite matrix fails instead of factoring as LDLᵀ */
  cholmod_sparse *S = cholmod_l_copy(Ms, 1, 1, cc);
  cholmod_factor *L = S ? cholmod_l_analyze(S, cc) : NULL;
  double out = NAN;
  if (L && cholmod_l_factorize(S, L, cc) && cc->status == CHOLMOD_OK && L->minor >= (size_t)n) {
    Scratch sc = SCRATCH_OF(NULL);
    double top = pencil_lanczos(&(PencilOp){L, p->K0t, cc, n, NULL, false, NULL, NULL}, &sc);
    scratch_release(&sc);
    out = top > 0 ? 1 / top : NAN;
  }
  cc->supernodal = super;
  cholmod_l_free_factor(&L, cc), cholmod_l_free_sparse(&S, cc);
  return out;
}

/* α(x̄) = λ_min of the pencil (M(x̄), K0) on T×T, the largest α with vᵀM(x̄)v ≥ α vᵀK0v: LAPACK's dsygvd
 * on the dense matrices (their upper triangles; both symmetric to 1e-12, K0t positive definite as a
 * principal block of K0) up to ESTIMATE_DENSE_MAX rows, pencil_sparse above. NaN when LAPACK or CHOLMOD
 * fails or memory runs out. */
static double pencil_min(const Pencil *p, const double *xbar, cholmod_common *cc) {
  long nt = (long)p->K0t->nrow;
  cholmod_sparse *Ms = affine_sum(p->Kt, p->nx, xbar, cc);
  if (Ms && nt > ESTIMATE_DENSE_MAX) {
    double out = pencil_sparse(p, Ms, cc);
    cholmod_l_free_sparse(&Ms, cc);
    return out;
  }
  Scratch sc = SCRATCH_OF(NULL);
  double *w = scratch_array(&sc, (size_t)nt + 1, sizeof(double)), out = NAN;
  cholmod_dense *M = Ms ? cholmod_l_sparse_to_dense(Ms, cc) : NULL, *K = M ? cholmod_l_sparse_to_dense(p->K0t, cc) : NULL;
  if (w && K && LAPACKE_dsygvd(LAPACK_COL_MAJOR, 1, 'N', 'U', (int)nt, M->x, (int)M->d, K->x, (int)K->d, w) == 0)
    out = w[0];
  cholmod_l_free_sparse(&Ms, cc), cholmod_l_free_dense(&M, cc), cholmod_l_free_dense(&K, cc);
  scratch_release(&sc);
  return out;
}

/* rt's min-θ anchors relative to K0 by the pencil (the file's comment): at up to ESTIMATE_SIGMA_SAMPLES
 * training samples spread over the set (sample j (S − 1) / (nk − 1), as the σ_min ratios pick them), those
 * whose x̄ is positive, (x̄, α(x̄)) when α(x̄) > 0. None without samples or above ESTIMATE_SPARSE_MAX rows of T.
 * 0, or -1 with `err`. */
static int pencil_anchors(const EstWork *wk, const Pencil *p, RTerm *rt) {
  const SampleSource *src = wk->src;
  long S = src ? src->count : 0, nk = S < ESTIMATE_SIGMA_SAMPLES ? S : ESTIMATE_SIGMA_SAMPLES, nx = (long)p->nx;
  rt->est_theta_k = 0;
  if (nk < 1 || (long)p->K0t->nrow > ESTIMATE_SPARSE_MAX) return 0;
  if (!(rt->est_theta = malloc(sizeof(double) * (size_t)(nk * (nx + 1)) + 1)))
    return err_set(wk->err, "estimate tables: out of memory for the pencil's anchors");
  for (long j = 0; j < nk; j++) {
    long k = nk > 1 ? j * (S - 1) / (nk - 1) : 0;
    if (src->set(src->user, wk->f, k) != 0) return err_set(wk->err, "estimate tables: %s", full_error(wk->f));
    size_t cnt = 0;
    const double *x = full_get(wk->f, p->input, &cnt);
    bool positive = x && (long)cnt == nx;
    for (long a = 0; positive && a < nx; a++) positive = x[a] > 0;
    double alpha = positive ? pencil_min(p, x, wk->cc) : NAN;
    if (!(alpha > 0)) continue;
    double *row = rt->est_theta + (long)rt->est_theta_k++ * (nx + 1);
    memcpy(row, x, sizeof(double) * (size_t)nx);
    row[nx] = alpha;
  }
  return 0;
}

/* rt's min-θ table relative to K0 (unsymmetric storage) when it applies (the file's comment): one anchor
 * (x̄, 1) when K0 is M(x̄) on T×T, else the pencil's. */
static int product_theta(const EstWork *wk, RTerm *rt, const RClass *rc, cholmod_sparse *K0, const ResidualCols *cols) {
  cholmod_sparse *K[ESTIMATE_THETA_MAX + 1], *Kt[ESTIMATE_THETA_MAX + 1] = {0}, *K0t = NULL;
  cholmod_common *cc = wk->cc;
  const Model *m = wk->m;
  size_t nx = 0;
  int q = estimate_affine_parts(wk, rt, rc->n, K, &nx);
  if (q < 0) return 0;
  long n = rc->n;
  Scratch sc = SCRATCH_OF(NULL); /* out of memory: the caller's message */
  SuiteSparse_long *T = scratch_array(&sc, (size_t)n + 1, sizeof *T);
  bool *bad = scratch_array(&sc, (size_t)n + 1, sizeof *bad);
  double *w = scratch_array(&sc, (size_t)n + 1, sizeof(double)), xbar[ESTIMATE_THETA_MAX];
  int out = T && bad && w ? 0 : -1;
  RowMarks rm = {T, bad, w, true, rt->named_q >= 0};
  long nt = out ? 0 : error_rows(K, nx, rc, cols, &rm);
  if (!out) memset(w, 0, sizeof(double) * (size_t)n);
  bool ok = !out && nt > 0;
  for (size_t j = 0; ok && j <= nx; j++)
    ok = (Kt[j] = cholmod_l_submatrix(K[j], T, nt, T, nt, 1, 1, cc)) && estimate_symmetric_psd(Kt[j], cc);
  ok = ok && (K0t = cholmod_l_submatrix(K0, T, nt, T, nt, 1, 1, cc)) && m->classes[m->qclass[q]].n == (long)nx;
  rt->est_theta_q = q, rt->est_theta_n = (long)nx;
  if (ok && anchor(Kt, nx, K0t, xbar, w, cc)) {
    if ((rt->est_theta = malloc(sizeof(double) * (nx + 1)))) {
      memcpy(rt->est_theta, xbar, sizeof(double) * nx);
      rt->est_theta[nx] = 1; /* λ_min of the pencil (M(x̄), K0) on the error's rows: M(x̄) = K0 there */
      rt->est_theta_k = 1;
    } else {
      out = -1;
    }
  } else if (ok) {
    out = pencil_anchors(wk, &(Pencil){Kt, nx, K0t, ((const Sym *)m->prog->quantities.v[q])->name}, rt);
    if (rt->est_theta_k == 0) free(rt->est_theta), rt->est_theta = NULL;
  }
  /* 1: the figure is an estimate (estimate.c): B's rows S above roundoff, or a named numerator's true values there unseen */
  if (rt->est_theta_k > 0) rt->est_sigma = rm.b_zero && !(rt->named_q >= 0 && nt < n) ? NAN : 1;
  for (size_t j = 0; j <= nx; j++) cholmod_l_free_sparse(&K[j], cc), cholmod_l_free_sparse(&Kt[j], cc);
  cholmod_l_free_sparse(&K0t, cc);
  scratch_release(&sc);
  return out;
}

/* The len columns at X of an n-row row-major array of leading dimension ld <- K0 times them (K0 unsymmetric storage); 0,
 * or -1 out of memory. */
static int apply_product(cholmod_sparse *K0, double *X, long n, long ld, long D, cholmod_common *cc) {
  cholmod_dense *b = cholmod_l_allocate_dense((size_t)n, (size_t)D, (size_t)n, CHOLMOD_REAL, cc);
  cholmod_dense *y = b ? cholmod_l_zeros((size_t)n, (size_t)D, CHOLMOD_REAL, cc) : NULL;
  double one[2] = {1, 0}, zero[2] = {0, 0};
  int ok = y ? 0 : -1;
  if (!ok) {
    double *bx = b->x;
    for (long i = 0; i < n; i++)
      for (long c = 0; c < D; c++) bx[c * n + i] = X[i * ld + c];
    ok = cholmod_l_sdmult(K0, 0, one, zero, b, y, cc) ? 0 : -1;
  }
  if (!ok) {
    const double *yx = y->x;
    for (long i = 0; i < n; i++)
      for (long c = 0; c < D; c++) X[i * ld + c] = yx[c * n + i];
  }
  cholmod_l_free_dense(&b, cc), cholmod_l_free_dense(&y, cc);
  return ok;
}

/* What application_ratio reads and writes: K0's dense Cholesky factor L (lower, n x n row-major), the operator M
 * (n x n), M B (n x m), the reduced operator (m x m) and LAPACK's singular values (2n); `dual`: M's result is taken by
 * a solve next (model_term_projects false), so its norm is into K0⁻¹'s. */
typedef struct NormBufs {
  const double *L;
  double *M, *T, *R, *sv;
  bool dual;
  cholmod_factor *LK;       /* above ESTIMATE_DENSE_MAX rows (L and M NULL): K0's sparse factor, and K0 */
  cholmod_sparse *K0;
} NormBufs;

/* The reduced operator's ‖·‖₂ for application_ratio: (DᵀMB) or, b->dual, BᵀMB, from b->T = M B; NaN when LAPACK fails. */
static double reduced_norm(const RClass *rc, const NormBufs *b) {
  long n = rc->n, my = rc->m;
  cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)my, (int)my, (int)n, 1.0, b->dual ? rc->B : rc->D, (int)my,
              b->T, (int)my, 0.0, b->R, (int)my);
  if (LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'N', 'N', (int)my, (int)my, b->R, (int)my, b->sv, NULL, 1, NULL, 1, b->sv + n))
    return NAN;
  return my > 0 ? b->sv[0] : 0;
}

/* application_ratio above ESTIMATE_DENSE_MAX rows: M assembled sparse, M B by its columns, ‖M‖ by Lanczos in K0's inner
 * product on K0⁻¹MᵀXM (norm_step; θ + |β s| errs high, as a norm that multiplies an error should). */
static double sparse_ratio(const EstWork *wk, const RTerm *view, const RClass *rc, const NormBufs *b) {
  long n = rc->n, my = rc->m;
  cholmod_sparse *A = estimate_sparse_operator(wk->f, view, n, wk->cc, wk->err);
  if (!A) return -1;
  const SuiteSparse_long *Ap = A->p, *Ai = A->i;
  const double *Ax = A->x;
  memset(b->T, 0, sizeof(double) * (size_t)(n * my));
  for (long j = 0; j < n; j++) /* T = A B, column j of A times row j of B */
    for (SuiteSparse_long p = Ap[j]; p < Ap[j + 1]; p++) cblas_daxpy((int)my, Ax[p], rc->B + j * my, 1, b->T + Ai[p] * my, 1);
  double reduced = reduced_norm(rc, b), top = NAN;
  Scratch sc = SCRATCH_OF(NULL);
  double *tmp = scratch_array(&sc, (size_t)n + 1, sizeof(double));
  if (tmp) top = pencil_lanczos(&(PencilOp){b->LK, b->K0, wk->cc, n, A, b->dual, tmp, norm_step}, &sc);
  scratch_release(&sc);
  cholmod_l_free_sparse(&A, wk->cc);
  return top == 0 ? 0 : sqrt(top) / reduced;
}

/* ‖M‖_K0 / ‖DᵀMB‖₂ of operator view->ops[0] of class rc at the evaluator's current values: ‖M‖_K0 = ‖LᵀML⁻ᵀ‖₂ (K0
 * = LLᵀ; the norm of M from K0's norm to itself), and DᵀMB = VᵀLᵀML⁻ᵀV with V = LᵀB orthonormal, so the ratio is at
 * least 1 (the Euclidean chains' ‖M‖₂/‖BᵀMB‖₂ in K0's norm). With b->dual, M from K0's norm into K0⁻¹'s (the error
 * it carries into the solve after it, whose residual is in K0⁻¹'s norm): ‖L⁻¹ML⁻ᵀ‖₂ / ‖BᵀMB‖₂, BᵀMB = Vᵀ(L⁻¹ML⁻ᵀ)V
 * the reduced operator the solve's right-hand side takes. 0 when M is zero, NaN when LAPACK fails; -1 with `err` when
 * the operator is not built. */
static double application_ratio(const EstWork *wk, const RTerm *view, const RClass *rc, const NormBufs *b) {
  long n = rc->n, my = rc->m;
  if (!b->M) return sparse_ratio(wk, view, rc, b);
  if (estimate_dense_operator(wk->f, view, b->M, n, wk->err)) return -1;
  cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, (int)n, (int)my, (int)n, 1.0, b->M, (int)n, rc->B, (int)my, 0.0,
              b->T, (int)my);
  double reduced = reduced_norm(rc, b);
  cblas_dtrsm(CblasRowMajor, CblasRight, CblasLower, CblasTrans, CblasNonUnit, (int)n, (int)n, 1.0, b->L, (int)n, b->M,
              (int)n);
  if (b->dual)
    cblas_dtrsm(CblasRowMajor, CblasLeft, CblasLower, CblasNoTrans, CblasNonUnit, (int)n, (int)n, 1.0, b->L, (int)n, b->M,
                (int)n);
  else
    cblas_dtrmm(CblasRowMajor, CblasLeft, CblasLower, CblasTrans, CblasNonUnit, (int)n, (int)n, 1.0, b->L, (int)n, b->M,
                (int)n);
  if (LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'N', 'N', (int)n, (int)n, b->M, (int)n, b->sv, NULL, 1, NULL, 1, b->sv + n))
    return NAN;
  return b->sv[0] == 0 ? 0 : b->sv[0] / reduced;
}

/* Term rt's ratios c_k = the largest ‖M_k‖_K0 / ‖DᵀM_kB‖₂ (application_ratio; into K0⁻¹'s norm for an operator a solve
 * follows) over up to ESTIMATE_SIGMA_SAMPLES training samples spread over the set (as the σ_min ratios pick them), each
 * evaluated: est_sigma for a term of one operator, est_opc for several (NaN: none, a ratio not finite at a sample, and
 * an inverse's: it divides by its min-θ bound, chain_columns). Dense up to ESTIMATE_DENSE_MAX rows, by Lanczos on the
 * sparse operator through K0's factor LK above (sparse_ratio), none above ESTIMATE_SPARSE_MAX (a figure that needs
 * ‖M‖ reports so). 0, or -1 with `err`. */
static int application_ratios(const EstWork *wk, RTerm *rt, const RClass *rc, cholmod_sparse *K0, cholmod_factor *LK) {
  const SampleSource *src = wk->src;
  long n = rc->n, S = src ? src->count : 0, nk = S < ESTIMATE_SIGMA_SAMPLES ? S : ESTIMATE_SIGMA_SAMPLES;
  bool dense = n <= ESTIMATE_DENSE_MAX;
  free(rt->est_opc);
  rt->est_opc = NULL;
  if (nk < 1 || n > ESTIMATE_SPARSE_MAX) return 0;
  Scratch sc = SCRATCH_OF(wk->err);
  double *c = scratch_array(&sc, (size_t)rt->nops + 1, sizeof(double)),
         *L = dense ? scratch_array(&sc, (size_t)(n * n) + 1, sizeof(double)) : NULL;
  NormBufs b = {L, dense ? scratch_array(&sc, (size_t)(n * n) + 1, sizeof(double)) : NULL,
                scratch_array(&sc, (size_t)(n * rc->m) + 1, sizeof(double)),
                scratch_array(&sc, (size_t)(rc->m * rc->m) + 1, sizeof(double)),
                scratch_array(&sc, (size_t)(4 * n) + 1, sizeof(double)), false, LK, K0};
  bool room = c && (!dense || (L && b.M)) && b.T && b.R && b.sv;
  cholmod_dense *K = room && dense ? cholmod_l_sparse_to_dense(K0, wk->cc) : NULL;
  int out = room && (K || !dense) ? 0 : err_set(wk->err, "estimate tables: out of memory for the norms of class %s's "
                                                         "operators in %s", rc->label, rc->product->name);
  if (!out && K) memcpy(L, K->x, sizeof(double) * (size_t)(n * n)); /* symmetric: its column-major entries are its rows */
  cholmod_l_free_dense(&K, wk->cc);
  if (!out && dense && LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'L', (int)n, L, (int)n) != 0)
    out = err_set(wk->err, "estimate tables: product %s's dense Cholesky failed (LAPACK)", rc->product->name);
  for (int k = 0; k < rt->nops; k++) c[k] = NAN;
  for (long j = 0; !out && j < nk; j++) {
    if ((out = train_eval_sample(src, wk->f, nk > 1 ? j * (S - 1) / (nk - 1) : 0, wk->err))) break;
    for (int k = 0; !out && k < rt->nops; k++) {
      RTerm view = *rt;
      view.ops = &rt->ops[k], view.nops = 1;
      if (rt->ops[k].op->p < 0) continue;
      b.dual = !model_term_projects(rt, k);
      double r = application_ratio(wk, &view, rc, &b);
      if (r < 0) out = -1;
      else if (!(r >= 0 && isfinite(r))) c[k] = 0; /* a ratio not found: none */
      else if (r > 0 && (isnan(c[k]) || (c[k] > 0 && r > c[k]))) c[k] = r;
    }
  }
  for (int k = 0; k < rt->nops; k++)
    if (!(c[k] > 0)) c[k] = NAN;
  if (!out && rt->nops == 1) rt->est_sigma = c[0];
  else if (!out && (rt->est_opc = malloc(sizeof(double) * (size_t)rt->nops)))
    memcpy(rt->est_opc, c, sizeof(double) * (size_t)rt->nops);
  else if (!out)
    out = err_set(wk->err, "estimate tables: out of memory for the norms of class %s's operators", rc->label);
  scratch_release(&sc);
  return out;
}

/* The chained term rt's stage and term numbers in m (estimate_chain_layout takes them). */
static void term_position(const Model *m, const RTerm *rt, int *i, int *t) {
  for (int a = 0; a < m->nstages; a++)
    if (rt >= m->stages[a].terms && rt < m->stages[a].terms + m->stages[a].nterms) *i = a, *t = (int)(rt - m->stages[a].terms);
}

/* The columns of chained term rt (estimate_term_chains, in a product: estimate_product_chains) whose blocks are errors
 * of K0-projections (the numerator's and each applied operator's, unless joined with the solve after them) weighted
 * by K0 (apply_product); the solve's joined block stays a residual, whose dual norm the caller's L⁻¹P gives. And the
 * solve's min-θ table relative to K0 (product_theta on a view of its operator alone, the rows S checked on its
 * operand's producer's columns). 0, or -1 with `err`. */
static int chain_columns(const EstWork *wk, RTerm *rt, const RClass *rc, cholmod_sparse *K0, const ResidualCols *cols) {
  int i = 0, t = 0, out = 0;
  term_position(wk->m, rt, &i, &t);
  ChainLayout L;
  estimate_chain_layout(wk->m, i, t, &L);
  if (!L.joins[0] && L.nnum > 0) out = apply_product(K0, cols->C, rc->n, cols->D, L.nnum, wk->cc);
  for (int k = 0; !out && k < rt->nops; k++) {
    if (rt->ops[k].op->p > 0) {
      if (!L.joins[k + 1]) out = apply_product(K0, cols->C + L.off[k], rc->n, cols->D, L.len[k], wk->cc);
      continue;
    }
    RTerm view = *rt;
    view.ops = &rt->ops[k], view.nops = 1, view.est_theta = NULL;
    out = product_theta(wk, &view, rc, K0, &(ResidualCols){cols->C + L.start[k], cols->D, L.off[k] - L.start[k]});
    rt->est_theta = view.est_theta, rt->est_theta_k = view.est_theta_k, rt->est_theta_q = view.est_theta_q;
    rt->est_theta_n = view.est_theta_n, rt->est_sigma = view.est_sigma;
  }
  return out;
}

int estimate_product_columns(const EstWork *w, RTerm *rt, const RClass *rc, const ResidualCols *cols, double **V) {
  Model *m = w->m;
  Full *f = w->f;
  Err *err = w->err;
  cholmod_common cc;
  cholmod_l_start(&cc);
  cc.print = 0;
  EstWork wk = {m, f, &cc, err, w->src};
  free(rt->est_theta);
  rt->est_theta = NULL, rt->est_theta_k = 0, rt->est_sigma = NAN;
  cholmod_sparse *A = product_matrix(m, f, rc, &cc, err), *K0 = A ? cholmod_l_copy_sparse(A, &cc) : NULL;
  cholmod_factor *L = K0 ? product_factor(rc, A, &cc, err) : NULL; /* leaves A's upper triangle: K0 keeps both */
  int out = -1;
  *V = NULL;
  /* a projection's error in K0's norm: the columns K0C (the file's comment); a chained term's blocks each as theirs */
  bool chain = rt->nops > 0 && estimate_term_chains(rt), projection = rt->nops == 0;
  if (L && (chain ? chain_columns(&wk, rt, rc, K0, cols) : projection ? 0 : product_theta(&wk, rt, rc, K0, cols)) == 0 &&
      (!chain || application_ratios(&wk, rt, rc, K0, L) == 0) && (*V = malloc(sizeof(double) * (size_t)(rc->n * rc->m) + 1))) {
    memcpy(*V, rc->D, sizeof(double) * (size_t)(rc->n * rc->m));
    out = (projection && apply_product(K0, cols->C, rc->n, cols->D, cols->D, &cc)) ||
                  solve_lower(L, cols->C, rc->n, cols->D, &cc) || solve_lower(L, *V, rc->n, rc->m, &cc) ? -1 : 0;
  }
  if (out && L) err_set_first(err, "estimate tables: out of memory for the norm of class %s's residual in %s",
                              rc->label, rc->product->name);
  if (A && !K0) err_set(err, "estimate tables: out of memory for product %s", rc->product->name);
  cholmod_l_free_factor(&L, &cc);
  cholmod_l_free_sparse(&A, &cc), cholmod_l_free_sparse(&K0, &cc);
  cholmod_l_finish(&cc);
  return out;
}

/* range[0] ≤ λ_min(K) and range[1] = ‖K‖₁ ≥ λ_max(K) (Gershgorin; K symmetric) of class c's product K:
 * λ_min by dsyevr on the dense K up to ESTIMATE_DENSE_MAX rows (to its roundoff), by Lanczos above (erring low,
 * estimate_sparse_smallest_sv). 0, or -1 with `err`. */
static int product_range(const EstWork *w, const RClass *c, double range[2]) {
  cholmod_common *cc = w->cc;
  cholmod_sparse *A = product_matrix(w->m, w->f, c, cc, w->err);
  if (!A) return -1;
  range[1] = cholmod_l_norm_sparse(A, 1, cc), range[0] = NAN;
  if (c->n > ESTIMATE_DENSE_MAX) {
    range[0] = estimate_sparse_smallest_sv(A, c->n, cc);
  } else {
    cholmod_dense *K = cholmod_l_sparse_to_dense(A, cc);
    lapack_int found = 0, isuppz[2];
    double lo[1];
    if (K && LAPACKE_dsyevr(LAPACK_COL_MAJOR, 'N', 'I', 'U', (int)c->n, K->x, (int)K->d, 0, 0, 1, 1, 0, &found, lo,
                            NULL, 1, isuppz) == 0 && found == 1)
      range[0] = lo[0];
    cholmod_l_free_dense(&K, cc);
  }
  cholmod_l_free_sparse(&A, cc);
  if (!(range[0] > 0))
    return err_set(w->err, "estimate tables: the smallest eigenvalue of product %s was not found positive",
                   c->product->name);
  return 0;
}

int estimate_product_carry(const EstWork *w, RTerm *rt, const RClass *rc, const RClass *cw) {
  rt->est_carry = 0;
  if (!rc->product && !cw->product) return 0;
  cholmod_common cc;
  cholmod_l_start(&cc);
  cc.print = 0;
  EstWork wk = {w->m, w->f, &cc, w->err, w->src};
  double k0[2] = {1, 1}, k1[2] = {1, 1}; /* λ_min, λ_max bounds; 1: the 2-norm */
  int out = (rc->product && product_range(&wk, rc, k0)) || (cw->product && product_range(&wk, cw, k1)) ? -1 : 0;
  cholmod_l_finish(&cc);
  if (out) return -1;
  bool same = rc->product && rc->product == cw->product;
  /* into a solve's residual's norm (a solve takes the numerator first), K0⁻¹'s: ‖v‖_{K0⁻¹} ≤ ‖v‖₂ / √λ_min(K0),
   * ‖v‖₂ ≤ ‖v‖_K1 / √λ_min(K1) */
  if (rt->nops > 0 && !model_term_projects(rt, -1))
    rt->est_carry = 1 / sqrt(k0[0] * k1[0]);
  else /* into the error's norm, K0's: ‖v‖_K0 ≤ √λ_max(K0) ‖v‖₂ */
    rt->est_carry = same ? 1 : sqrt(k0[1] / k1[0]);
  return 0;
}
