/* test_emit_sparse.c — the loops over a sparse operator's entries (backends/emit/
 * emit_sparse.c, DESIGN §13): a variable an equality determines (`nbr[i, k] == j`,
 * `delta(i, tab[e, 0])`, `delta(j, i + 1)`) is computed, not looped over, and skipped
 * where it falls outside its dim or its summation's bounds (-1 padding, the band's ends).
 *
 * For small operators of every such shape, on random tables with padding, repeats and
 * self-loops, both users of those loops are checked against a dense evaluation written
 * here by hand from the definition: the tensor builder (npg_full_op's CSR: its pattern is
 * exactly the entries the definition reaches, its values the dense ones) and the full
 * evaluator's compressed assembly (y = K x, solved sparse from 16 rows up, equals the
 * dense product). Each operator is bound twice with different tables: a pattern kept from
 * the first binding would be wrong for the second. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "npg.h"

enum { N = 20, K = 3, E = 25 };

typedef struct Data {
  double nbr[N * K];   /* neighbour tables: -1 padding, repeats, self-loops */
  double tab[E * 2];   /* an edge list, repeated edges */
  double w[N * K], we[E], m[N], x[N];
} Data;

typedef struct Case {
  const char *name, *dims, *op;
  const char *params;  /* the params it declares, as bound below */
  /* the dense operator M (N x N, row-major) and its pattern P: every entry the
   * definition reaches for this data */
  void (*dense)(const Data *d, double *M, bool *P);
} Case;

static void reach(double *M, bool *P, long i, long j, double v) {
  M[i * N + j] += v;
  P[i * N + j] = true;
}

/* delta(i, j) * (2 + x[i]) - sum(k = 0..K-1, if(nbr[i, k] == j, x[i] * w[i, k], 0)) */
static void dense_neighbours(const Data *d, double *M, bool *P) {
  for (long i = 0; i < N; i++) {
    reach(M, P, i, i, 2 + d->x[i]);
    for (long k = 0; k < K; k++)
      if (d->nbr[i * K + k] >= 0) reach(M, P, i, (long)d->nbr[i * K + k], -d->x[i] * d->w[i * K + k]);
  }
}

/* sum(k = 0..K-1, delta(i, nbr[j, k]) * x[j]): the row determined by the column */
static void dense_transposed(const Data *d, double *M, bool *P) {
  for (long j = 0; j < N; j++)
    for (long k = 0; k < K; k++)
      if (d->nbr[j * K + k] >= 0) reach(M, P, (long)d->nbr[j * K + k], j, d->x[j]);
}

/* delta(i, j) + sum(e = 0..E-1, we[e] * x[i] * delta(i, tab[e, 0]) * delta(j, tab[e, 1])):
 * both determined by the summation variable */
static void dense_edges(const Data *d, double *M, bool *P) {
  for (long i = 0; i < N; i++) reach(M, P, i, i, 1);
  for (long e = 0; e < E; e++) {
    long i = (long)d->tab[2 * e], j = (long)d->tab[2 * e + 1];
    reach(M, P, i, j, d->we[e] * d->x[i]);
  }
}

/* 3 * delta(i, j) + x[i] * delta(j, i + 1) + x[j] * delta(j, i - 1): out of range at the ends */
static void dense_band(const Data *d, double *M, bool *P) {
  for (long i = 0; i < N; i++) {
    reach(M, P, i, i, 3);
    if (i + 1 < N) reach(M, P, i, i + 1, d->x[i]);
    if (i >= 1) reach(M, P, i, i - 1, d->x[i - 1]);
  }
}

/* delta(i, j) + sum(k = 2..N-3, delta(i, k) * delta(j, k) * x[k]): a determined summation
 * variable kept within its bounds */
static void dense_bounded(const Data *d, double *M, bool *P) {
  for (long i = 0; i < N; i++) reach(M, P, i, i, 1);
  for (long k = 2; k <= N - 3; k++) reach(M, P, k, k, d->x[k]);
}

/* delta(i, j) + sum(k = 0..K-1, if(nbr[i, k] == j && m[i] > 0.5, x[j], 0)): the rest of
 * the guard tested at each point */
static void dense_guarded(const Data *d, double *M, bool *P) {
  for (long i = 0; i < N; i++) {
    reach(M, P, i, i, 1);
    for (long k = 0; k < K; k++)
      if (d->nbr[i * K + k] >= 0 && d->m[i] > 0.5) {
        long j = (long)d->nbr[i * K + k];
        reach(M, P, i, j, d->x[j]);
      }
  }
}

static const Case cases[] = {
    {"neighbours", "N, K",
     "op A[i:N, j:N] = delta(i, j) * (2 + x[i]) - sum(k = 0..K-1, if(nbr[i, k] == j, x[i] * w[i, k], 0))",
     "param nbr : int[N, K]\nparam w : real[N, K]\n", dense_neighbours},
    {"transposed", "N, K", "op A[i:N, j:N] = sum(k = 0..K-1, delta(i, nbr[j, k]) * x[j])", "param nbr : int[N, K]\n",
     dense_transposed},
    {"edges", "N, E", "op A[i:N, j:N] = delta(i, j) + sum(e = 0..E-1, we[e] * x[i] * delta(i, tab[e, 0]) * delta(j, tab[e, 1]))",
     "param tab : int[E, 2]\nparam we : real[E]\n", dense_edges},
    {"band", "N", "op A[i:N, j:N] = 3 * delta(i, j) + x[i] * delta(j, i + 1) + x[j] * delta(j, i - 1)", "", dense_band},
    {"bounded", "N", "op A[i:N, j:N] = delta(i, j) + sum(k = 2..N-3, delta(i, k) * delta(j, k) * x[k])", "", dense_bounded},
    {"guarded", "N, K", "op A[i:N, j:N] = delta(i, j) + sum(k = 0..K-1, if(nbr[i, k] == j && m[i] > 0.5, x[j], 0))",
     "param nbr : int[N, K]\nparam m : real[N]\n", dense_guarded},
};

static unsigned rng;
static double uniform(void) {
  rng = rng * 1103515245u + 12345u;
  return ((rng >> 8) & 0xffffff) / (double)0x1000000;
}

static void random_data(Data *d) {
  for (long i = 0; i < N * K; i++) {
    double u = uniform();
    long row = i / K;
    /* a quarter padding, some self-loops, some repeats of the previous entry */
    d->nbr[i] = u < 0.25 ? -1 : u < 0.35 ? (double)row : (u < 0.45 && i % K) ? d->nbr[i - 1] : floor(uniform() * N);
    d->w[i] = 0.5 + uniform();
  }
  for (long e = 0; e < E; e++) {
    bool repeat = e > 0 && uniform() < 0.2;
    d->tab[2 * e] = repeat ? d->tab[2 * e - 2] : floor(uniform() * N);
    d->tab[2 * e + 1] = repeat ? d->tab[2 * e - 1] : floor(uniform() * N);
    d->we[e] = 0.5 + uniform();
  }
  for (long i = 0; i < N; i++) d->m[i] = uniform(), d->x[i] = 0.5 + uniform();
}

static void bind(NpgFull *f, const Case *c, const Data *d) {
  const struct {
    const char *name;
    int nd;
    long shape[2];
    const double *v;
  } given[] = {{"nbr", 2, {N, K}, d->nbr}, {"w", 2, {N, K}, d->w}, {"tab", 2, {E, 2}, d->tab},
               {"we", 1, {E}, d->we},      {"m", 1, {N}, d->m},    {"x", 1, {N}, d->x}};
  for (size_t g = 0; g < sizeof given / sizeof *given; g++) {
    char decl[32];
    snprintf(decl, sizeof decl, "param %s :", given[g].name);
    if (strcmp(given[g].name, "x") && !strstr(c->params, decl)) continue;
    if (npg_full_set(f, given[g].name, given[g].nd, given[g].shape, given[g].v, given[g].name) != 0)
      fail_msg("%s: %s", c->name, npg_full_error(f));
  }
}

/* The builder's CSR and the evaluator's y = A x against the dense evaluation. */
static void check_binding(const Case *c, NpgFull *f, const Data *d) {
  double M[N * N] = {0};
  bool P[N * N] = {false};
  c->dense(d, M, P);
  bind(f, c, d);
  if (npg_full_eval(f, 0) != 0) fail_msg("%s: %s", c->name, npg_full_error(f));
  NpgCsr a;
  if (npg_full_op(f, "A", &a) != 0) fail_msg("%s: %s", c->name, npg_full_error(f));
  assert_int_equal(a.rows, N);
  assert_int_equal(a.cols, N);
  long reached = 0;
  for (long k = 0; k < N * N; k++) reached += P[k];
  if (a.nnz != reached) fail_msg("%s: %ld entries in the CSR, the definition reaches %ld", c->name, a.nnz, reached);
  assert_int_equal(a.indptr[0], 0);
  for (long i = 0; i < N; i++)
    for (long p = a.indptr[i]; p < a.indptr[i + 1]; p++) {
      long j = a.indices[p];
      if (p > a.indptr[i] && j <= a.indices[p - 1]) fail_msg("%s: row %ld: columns not increasing", c->name, i);
      if (!P[i * N + j]) fail_msg("%s: the CSR holds (%ld, %ld), which the definition never reaches", c->name, i, j);
      double want = M[i * N + j];
      if (fabs(a.data[p] - want) > 1e-14 * fmax(1, fabs(want)))
        fail_msg("%s: entry (%ld, %ld) is %.17g, dense %.17g", c->name, i, j, a.data[p], want);
    }
  npg_csr_free(&a);
  size_t n;
  const double *y = npg_full_get(f, "y", &n);
  assert_int_equal(n, N);
  for (long i = 0; i < N; i++) {
    double want = 0;
    for (long j = 0; j < N; j++) want += M[i * N + j] * d->x[j];
    if (fabs(y[i] - want) > 1e-13 * fmax(1, fabs(want)))
      fail_msg("%s: y[%ld] = %.17g, the dense product %.17g", c->name, i, y[i], want);
  }
}

static void operators_equal_dense(void **state) {
  (void)state;
  for (size_t t = 0; t < sizeof cases / sizeof *cases; t++) {
    const Case *c = &cases[t];
    char text[1024];
    snprintf(text, sizeof text, "dim %s\n%sinput x : real[N]\noutput %s\noutput y = A * x\n", c->dims, c->params, c->op);
    NpgOptions o = {0};
    o.source = text;
    NpgProgram *p = npg_compile(c->name, &o);
    if (!npg_ok(p)) fail_msg("%s: %s", c->name, npg_error(p));
    for (int backend = 0; backend < 2; backend++) {
      NpgFull *f = npg_full_new(p, backend ? NPG_CC : NPG_TCC);
      if (npg_full_error(f)[0]) fail_msg("%s: %s", c->name, npg_full_error(f));
      rng = 17u + (unsigned)t;
      for (int binding = 0; binding < 2; binding++) {
        Data d;
        random_data(&d);
        if (binding) npg_full_unbind(f);
        check_binding(c, f, &d);
      }
      npg_full_free(f);
    }
    npg_free(p);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {cmocka_unit_test(operators_equal_dense)};
  return cmocka_run_group_tests(tests, NULL, NULL);
}
