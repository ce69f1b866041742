/* test_sym.c — packed symmetric powers (backends/model/sym.c): an input
 * repeated k times in a tensor stored over sorted multi-indices. Checked
 * against the unpacked sums they stand for: the packed length is the count of
 * sorted multi-indices, a packed outer product contracted with a packed
 * power is the product of the rows' contractions (the full m^k sum), and the
 * coordinates of a smaller basis are the leading ones' entries. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "model.h"

static unsigned seed = 7u;
static double uniform(void) {
  seed = seed * 1103515245u + 12345u;
  return (double)(seed >> 8) / (double)(1u << 24) * 2 - 1;
}

/* The sorted multi-indices of k entries below m, counted by brute force. */
static long sorted_count(long m, int k, long below, int left) {
  if (left == 0) return 1;
  long n = 0;
  for (long a = below; a < m; a++) n += sorted_count(m, k, a, left - 1);
  return n;
}

static void lengths_count_sorted_indices(void **state) {
  (void)state;
  for (long m = 1; m <= 9; m++)
    for (int k = 1; k <= 5; k++) assert_int_equal(sym_len(m, k), sorted_count(m, k, 0, k));
  assert_int_equal(sym_len(60, 2), 60 * 61 / 2);
  assert_int_equal(sym_len(30, 3), 30L * 31 * 32 / 6);
}

/* ⟨sym_outer(rows), sym_power(x)⟩ = Π_pos ⟨rows[pos], x⟩: the packed pair
 * holds the whole m^k contraction, for k = 1 … 4 (the k = 1, 2 fast paths and
 * the general one). */
static void outer_against_power_is_the_full_sum(void **state) {
  (void)state;
  for (int k = 1; k <= 4; k++)
    for (long m = 1; m <= 7; m++) {
      long n = sym_len(m, k);
      double *x = malloc(sizeof(double) * (size_t)m), *z = malloc(sizeof(double) * (size_t)n);
      double *v = malloc(sizeof(double) * (size_t)n), *rowbuf = malloc(sizeof(double) * (size_t)(m * k));
      const double *rows[RT_MAX_IN];
      for (long i = 0; i < m; i++) x[i] = uniform();
      double want = 1;
      for (int p = 0; p < k; p++) {
        double dot = 0;
        for (long i = 0; i < m; i++) rowbuf[p * m + i] = uniform(), dot += rowbuf[p * m + i] * x[i];
        rows[p] = rowbuf + p * m;
        want *= dot;
      }
      sym_power(m, k, x, z);
      sym_outer(m, k, rows, v);
      double got = 0, scale = 0;
      for (long j = 0; j < n; j++) got += v[j] * z[j], scale += fabs(v[j] * z[j]);
      if (!(fabs(got - want) <= 1e-13 * (scale + 1)))
        fail_msg("m %ld, k %d: packed %.17g, full sum %.17g", m, k, got, want);
      free(x), free(z), free(v), free(rowbuf);
    }
}

/* The power's entries are the monomials in lexicographic order of the sorted indices. */
static void power_lists_sorted_monomials(void **state) {
  (void)state;
  double x[3] = {2, 3, 5}, z[10];
  sym_power(3, 3, x, z);
  const double want[10] = {8, 12, 20, 18, 30, 50, 27, 45, 75, 125}; /* 000 001 002 011 012 022 111 112 122 222 */
  assert_memory_equal(z, want, sizeof want);
}

/* sym_leading: the coordinates of x's first m2 entries are the entries map[] of the whole power. */
static void leading_coordinates_are_a_smaller_basis(void **state) {
  (void)state;
  for (int k = 1; k <= 4; k++)
    for (long m = 1; m <= 6; m++)
      for (long m2 = 1; m2 <= m; m2++) {
        long n = sym_len(m, k), n2 = sym_len(m2, k);
        double x[6], *z = malloc(sizeof(double) * (size_t)n), *z2 = malloc(sizeof(double) * (size_t)n2);
        long *map = malloc(sizeof(long) * (size_t)n2);
        for (long i = 0; i < m; i++) x[i] = uniform();
        sym_power(m, k, x, z);
        sym_power(m2, k, x, z2);
        sym_leading(m, k, m2, map);
        for (long j = 0; j < n2; j++)
          if (z[map[j]] != z2[j]) fail_msg("m %ld, k %d, m2 %ld: coordinate %ld", m, k, m2, j);
        free(z), free(z2), free(map);
      }
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(lengths_count_sorted_indices),
      cmocka_unit_test(outer_against_power_is_the_full_sum),
      cmocka_unit_test(power_lists_sorted_monomials),
      cmocka_unit_test(leading_coordinates_are_a_smaller_basis),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
