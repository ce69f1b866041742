/* sym.c — packed symmetric powers: an input repeated k times in a tensor
 * (x ⊗ x) is one axis of C(m + k - 1, k) coordinates over sorted
 * multi-indices, so the tensor is stored once, not k! times. */
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "model.h"

long sym_len(long m, int k) {
  /* C(m + k - 1, k), exact in integers for the sizes that fit in memory */
  long r = 1;
  for (int i = 1; i <= k; i++) r = r * (m + i - 1) / i;
  return r;
}

/* Advance the sorted multi-index a[0..k) (a[0] <= … <= a[k-1] < m) to the
 * next in lexicographic order; false after the last. */
static bool next_sorted(long m, int k, long *a) {
  int i = k - 1;
  while (i >= 0 && a[i] == m - 1) i--;
  if (i < 0) return false;
  a[i]++;
  for (int j = i + 1; j < k; j++) a[j] = a[i];
  return true;
}

void sym_power(long m, int k, const double *x, double *z) {
  if (k == 1) {
    memcpy(z, x, sizeof(double) * (size_t)m);
    return;
  }
  if (k == 2) {
    long p = 0;
    for (long a = 0; a < m; a++)
      for (long b = a; b < m; b++) z[p++] = x[a] * x[b];
    return;
  }
  long a[RT_MAX_IN] = {0}, p = 0;
  do {
    double v = 1;
    for (int l = 0; l < k; l++) v *= x[a[l]];
    z[p++] = v;
  } while (next_sorted(m, k, a));
}

/* Σ over the distinct arrangements of the multiset a[0..k) assigned to
 * positions 0..k-1 of Π rows[pos][value]. */
static double arrangements(int k, const long *a, const double *const *rows, int pos, bool *used) {
  if (pos == k) return 1;
  double s = 0;
  for (int i = 0; i < k; i++) {
    if (used[i] || (i > 0 && a[i] == a[i - 1] && !used[i - 1])) continue; /* each distinct value once */
    used[i] = true;
    s += rows[pos][a[i]] * arrangements(k, a, rows, pos + 1, used);
    used[i] = false;
  }
  return s;
}

void sym_outer(long m, int k, const double *const *rows, double *v) {
  if (k == 1) {
    memcpy(v, rows[0], sizeof(double) * (size_t)m);
    return;
  }
  if (k == 2) {
    const double *r0 = rows[0], *r1 = rows[1];
    long p = 0;
    for (long a = 0; a < m; a++) {
      v[p++] = r0[a] * r1[a];
      for (long b = a + 1; b < m; b++) v[p++] = r0[a] * r1[b] + r0[b] * r1[a];
    }
    return;
  }
  long a[RT_MAX_IN] = {0}, p = 0;
  bool used[RT_MAX_IN] = {0};
  do v[p++] = arrangements(k, a, rows, 0, used);
  while (next_sorted(m, k, a));
}

void sym_leading(long m, int k, long m2, long *map) {
  if (m <= 0 || m2 <= 0) return;
  long a[RT_MAX_IN] = {0}, p = 0, j = 0;
  do {
    if (a[k - 1] < m2) map[j++] = p; /* sorted: the last index is the largest */
    p++;
  } while (next_sorted(m, k, a));
}
