/* test_joint.c — a class basis by one joint PCA (backends/train/joint.c,
 * --merge joint): orthonormal, at most the members' caps, spanning every
 * member's snapshots when the caps allow it (centered: their means too),
 * the same span whatever a member's units (each block scaled to unit norm),
 * and every member reporting the joint PCA. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "train.h"
#include "train_steps.h"

enum { N = 10, S = 6, R = 2 };

static unsigned seed = 11u;
static double uniform(void) {
  seed = seed * 1103515245u + 12345u;
  return (double)(seed >> 8) / (double)(1u << 24) * 2 - 1;
}

/* Member i's snapshots (sample-major, S x N): combinations of `rank` fixed directions plus an offset. */
static void snapshots(double *X, int rank, double offset) {
  double dir[4][N];
  for (int d = 0; d < rank; d++)
    for (int e = 0; e < N; e++) dir[d][e] = uniform();
  for (int s = 0; s < S; s++)
    for (int e = 0; e < N; e++) {
      X[s * N + e] = offset;
      for (int d = 0; d < rank; d++) X[s * N + e] += uniform() * dir[d][e];
    }
}

/* ‖x − BBᵀx‖ / ‖x‖ for a basis of m columns (row-major N x m). */
static double residual(const double *B, long m, const double *x) {
  double c[N] = {0}, r2 = 0, x2 = 0;
  for (long j = 0; j < m; j++)
    for (int e = 0; e < N; e++) c[j] += B[e * m + j] * x[e];
  for (int e = 0; e < N; e++) {
    double p = 0;
    for (long j = 0; j < m; j++) p += B[e * m + j] * c[j];
    r2 += (x[e] - p) * (x[e] - p), x2 += x[e] * x[e];
  }
  return sqrt(r2 / x2);
}

static long joint(bool center, int cap, double scale1, double *X0, double *X1, double **B, double *lost) {
  RMember mb[R] = {{0}};
  for (int i = 0; i < R; i++) mb[i].cap = cap, mb[i].energy = 1, mb[i].center = center;
  RClass rc = {0};
  rc.n = N;
  rc.nmembers = R;
  rc.members = mb;
  double *X1s = malloc(sizeof(double) * N * S);
  for (int i = 0; i < N * S; i++) X1s[i] = X1[i] * scale1;
  double *const X[R] = {X0, X1s};
  char err[512] = "";
  if (train_joint_basis(&rc, S, X, ERR_OF(err, sizeof err))) fail_msg("train_joint_basis: %s", err);
  for (int i = 0; i < R; i++) {
    assert_int_equal(mb[i].kept, rc.m); /* every member reports the joint PCA */
    assert_true(mb[i].lost >= 0 && mb[i].lost <= 1 && mb[i].lost == mb[0].lost);
    free(mb[i].sv);
  }
  free(X1s);
  *lost = mb[0].lost;
  *B = rc.B;
  return rc.m;
}

static void spans_every_member(void **state) {
  (void)state;
  double X0[N * S], X1[N * S];
  snapshots(X0, 2, 0);
  snapshots(X1, 3, 0);
  for (int centered = 0; centered < 2; centered++) {
    double *B;
    double lost;
    long m = joint(centered, 6, 1, X0, X1, &B, &lost);
    assert_true(m >= 5 && m <= 2 * 6 && lost <= 1e-12);
    for (long a = 0; a < m; a++) /* orthonormal */
      for (long b = 0; b < m; b++) {
        double d = 0;
        for (int e = 0; e < N; e++) d += B[e * m + a] * B[e * m + b];
        if (!(fabs(d - (a == b)) <= 1e-12)) fail_msg("centered %d: BᵀB[%ld][%ld] = %.3g", centered, a, b, d);
      }
    for (int s = 0; s < S; s++) {
      double r0 = residual(B, m, X0 + s * N), r1 = residual(B, m, X1 + s * N);
      if (!(r0 <= 1e-10 && r1 <= 1e-10))
        fail_msg("centered %d: sample %d outside the basis (%.3g, %.3g)", centered, s, r0, r1);
    }
    free(B);
  }
}

/* A member in other units (1e6 times larger) leaves the span where it was: with a cap that
 * keeps only part of it, the basis is the same subspace. */
static void span_independent_of_units(void **state) {
  (void)state;
  double X0[N * S], X1[N * S];
  snapshots(X0, 3, 0);
  snapshots(X1, 3, 0);
  double *B, *Bs, lost, lost_s;
  long m = joint(false, 2, 1, X0, X1, &B, &lost), ms = joint(false, 2, 1e6, X0, X1, &Bs, &lost_s);
  assert_true(lost > 0 && fabs(lost - lost_s) <= 1e-9); /* part of it left out, the same part */
  assert_int_equal(m, ms);
  for (long j = 0; j < m; j++) { /* each column of one basis lies in the other's span */
    double col[N];
    for (int e = 0; e < N; e++) col[e] = Bs[e * ms + j];
    if (!(residual(B, m, col) <= 1e-8))
      fail_msg("column %ld of the scaled basis is %.3g outside", j, residual(B, m, col));
  }
  free(B);
  free(Bs);
}

/* The caps bound the basis: at most Σ cap vectors (centered: the means counted in them). */
static void caps_bound_the_size(void **state) {
  (void)state;
  double X0[N * S], X1[N * S];
  snapshots(X0, 4, 1);
  snapshots(X1, 4, -2);
  double *B, lost;
  assert_true(joint(false, 1, 1, X0, X1, &B, &lost) <= 2);
  free(B);
  assert_true(joint(true, 2, 1, X0, X1, &B, &lost) <= 4);
  free(B);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(spans_every_member),
      cmocka_unit_test(span_independent_of_units),
      cmocka_unit_test(caps_bound_the_size),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
