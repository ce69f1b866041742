/* test_premul.c — pre-multiplication (backends/train/premul.c; paper §4):
 *
 *   - pre-multiplication equals a brute-force dense product (the explicit
 *     tensor from the builder, explicit random orthonormal bases) to 1e-12,
 *     for every tensor kind of the example and test programs (orders 2–5,
 *     repeated inputs stored packed — a last x ⊗ x axis by both of its
 *     paths — diagonal and declared operators), and so do its parts over 2,
 *     3 and more ranks than rows, each rank's builder enumerating only its
 *     rows.
 */
#include <cblas.h>
#include <limits.h>

#include "train.h"
#include "testutil.h"
#include "trained.h"

/* ---------------------------------------------------------------- explicit tensors */

/* Dense explicit tensor of one group: [out (row, or row*n+col)][input offsets...]. */
typedef struct Dense {
  long nout;
  int nin;
  long nfull[RT_MAX_IN];   /* full size of each input position */
  double *q;
  long size;
} Dense;

static int dense_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  Dense *d = user;
  long pos = d->nout == 0 ? 0 : row;
  if (col >= 0 && d->nout > 0 && d->nfull[RT_MAX_IN - 1] > 0) pos = row * d->nfull[RT_MAX_IN - 1] + col;
  for (int l = 0; l < nin; l++) pos = pos * d->nfull[l] + in[l];
  if (pos < 0 || pos >= d->size) return -1;
  d->q[pos] += coef;
  return 0;
}

/* Lexicographic rank of the sorted multi-index a[0..k) over [0, m). */
static long sorted_rank(long m, int k, const long *a) {
  long idx[RT_MAX_IN] = {0}, r = 0;
  for (;;) {
    bool eq = true;
    for (int l = 0; l < k; l++) eq = eq && idx[l] == a[l];
    if (eq) return r;
    int i = k - 1;
    while (i >= 0 && idx[i] == m - 1) i--;
    if (i < 0) return -1;
    idx[i]++;
    for (int j = i + 1; j < k; j++) idx[j] = idx[i];
    r++;
  }
}

static int cmp_long(const void *a, const void *b) {
  long x = *(const long *)a, y = *(const long *)b;
  return (x > y) - (x < y);
}

/* The pre-multiplied tensor `t` of a stage of class cy recomputed by brute
 * force from the explicit tensor: every nonzero of Q times the explicit
 * basis rows, accumulated into the packed layout. Returns the relative
 * difference, or -1 when the tensor is too large to do this way. */
static double brute_premul(const Model *m, Full *f, const RTensor *t, const RClass *cy) {
  const TensorGroup *g = t->group;
  Dense d = {0};
  d.nin = g->ninputs;
  long ny = cy->n, my = cy->m;
  d.nout = ny;
  d.nfull[RT_MAX_IN - 1] = t->kind == RT_DECL ? ny : 0;
  d.size = t->kind == RT_DECL ? ny * ny : ny;
  const double *B[RT_MAX_IN];
  long mm[RT_MAX_IN];
  int owner[RT_MAX_IN];  /* distinct input of each position */
  int pos = 0;
  for (int j = 0; j < t->nin; j++)
    for (int l = 0; l < t->in_mult[j]; l++, pos++) {
      const RClass *c = &m->classes[m->qclass[t->in_q[j]]];
      d.nfull[pos] = c->n;
      B[pos] = c->B;
      mm[pos] = c->m;
      owner[pos] = j;
      d.size *= c->n;
    }
  long red = t->rows;
  for (int l = 0; l < d.nin; l++) red *= mm[l];
  if (d.size > 4000000 || (double)d.size * (double)red > 4e8) return -1;
  d.q = calloc((size_t)d.size, sizeof(double));
  NpgSink sink = {&d, dense_entry, 0, 1, 0, 0}; /* every row */
  if (full_build(f, t->builder, &sink)) fail_msg("%s", full_error(f));
  double *packed = calloc((size_t)(t->rows * t->cols), sizeof(double));
  long fidx[RT_MAX_IN + 2];
  for (long p = 0; p < d.size; p++) {
    if (d.q[p] == 0) continue;
    long rest = p;
    for (int l = d.nin - 1; l >= 0; l--) fidx[l] = rest % d.nfull[l], rest /= d.nfull[l];
    long row = t->kind == RT_DECL ? rest / ny : rest, col = t->kind == RT_DECL ? rest % ny : row;
    /* every reduced output coordinate and every unpacked reduced input tuple */
    long ridx[RT_MAX_IN] = {0};
    for (;;) {
      double in = d.q[p];
      for (int l = 0; l < d.nin; l++) in *= B[l][fidx[l] * mm[l] + ridx[l]];
      /* packed column */
      long cidx = 0, l0 = 0;
      for (int j = 0; j < t->nin; j++) {
        long a[RT_MAX_IN];
        for (int l = 0; l < t->in_mult[j]; l++) a[l] = ridx[l0 + l];
        qsort(a, (size_t)t->in_mult[j], sizeof(long), cmp_long);
        cidx = cidx * t->in_len[j] + sorted_rank(m->classes[m->qclass[t->in_q[j]]].m, t->in_mult[j], a);
        l0 += t->in_mult[j];
      }
      const double *by = cy->B + row * my, *bc = cy->B + col * my;
      long o = 0;
      for (long a = 0; a < my; a++)
        for (long b = t->kind == RT_NUM ? my - 1 : t->kind == RT_DIAG ? a : 0; b < my; b++, o++) {
          double k = t->kind == RT_NUM ? by[a] : by[a] * bc[b];
          packed[o * t->cols + cidx] += k * in;
        }
      int l = d.nin - 1;
      while (l >= 0 && ridx[l] == mm[l] - 1) ridx[l--] = 0;
      if (l < 0) break;
      ridx[l]++;
    }
  }
  (void)owner;
  double diff = rel_diff(packed, t->data, (size_t)(t->rows * t->cols));
  free(packed);
  free(d.q);
  return diff;
}

typedef struct PremulStats {
  double worst;
  int tensors, skipped, other_path, splits;
  int kinds[3], orders[8], packed;
} PremulStats;

/* Over ranks: the parts of premultiply (PremulOut.part; each rank's builder enumerating
 * only its rows; premul refuses an entry of another's) sum to the whole, for
 * 2 and 3 parts and for more parts than the tensor has rows (ranks with
 * nothing to do). Non-zero after printing a failure. */
static int premul_split_check(Model *m, Full *f, RTensor *x, const RClass *cy, const char *path, PremulStats *ps) {
  long nparts[] = {2, 3, cy->n + 1}, len = x->rows * x->cols;
  double *kept = x->data, *sum = calloc((size_t)len + 1, sizeof(double));
  int failures = 0;
  for (size_t k = 0; k < sizeof nparts / sizeof *nparts; k++) {
    memset(sum, 0, sizeof(double) * (size_t)len);
    for (long part = 0; part < nparts[k]; part++) {
      char err[512];
      x->data = NULL;
      if (premultiply(m, f, x, &(PremulOut){.By = cy->B, .ny = cy->n, .my = cy->m, .part = (int)part, .nparts = (int)nparts[k]}, NULL,
                      ERR_OF(err, sizeof err)))
        fail_msg("%s", err);
      cblas_daxpy((int)len, 1.0, x->data, 1, sum, 1);
      free(x->data);
    }
    x->data = sum;
    double d = brute_premul(m, f, x, cy);
    ps->splits++;
    ps->worst = fmax(ps->worst, d);
    if (!(d <= 1e-12)) {
      print_message("%s: tensor %s over %ld ranks: differs from brute force by %.3g\n", path, x->name, nparts[k], d);
      failures++;
    }
  }
  x->data = kept;
  free(sum);
  return failures;
}

static int premul_program(const char *path, void *arg) {
  PremulStats *ps = arg;
  Trained tr;
  train_small(&tr, path, 3, 4);
  Model *m = tr.m;
  int failures = 0;
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    const RClass *cy = &m->classes[m->qclass[rs->q]];
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      RTERM_FOR_TENSORS(rt, x) {
        double d = brute_premul(m, tr.f, x, cy);
        if (d < 0) {
          ps->skipped++;
          continue;
        }
        ps->tensors++;
        ps->kinds[x->kind]++;
        ps->orders[x->group->order < 8 ? x->group->order : 7]++;
        for (int j = 0; j < x->nin; j++) ps->packed += x->in_mult[j] > 1;
        ps->worst = fmax(ps->worst, d);
        if (!(d <= 1e-12)) {
          print_message("%s: tensor %s: pre-multiplied differs from brute force by %.3g\n", path, x->name, d);
          failures++;
        }
        if (premul_split_check(m, tr.f, x, cy, path, ps)) failures++;
        if (x->nin > 0 && x->in_mult[x->nin - 1] == 2) {
          /* the other path for a last x ⊗ x axis (unpacked GEMM or packed rows) */
          char err[512];
          double *kept = x->data;
          x->data = NULL;
          int other = x->group->nmono >= 8 ? INT_MAX : 1;
          if (premultiply(m, tr.f, x, &(PremulOut){.By = cy->B, .ny = cy->n, .my = cy->m, .unpack_min_monos = other}, NULL,
                          ERR_OF(err, sizeof err)))
            fail_msg("%s", err);
          double d2 = brute_premul(m, tr.f, x, cy);
          free(x->data);
          x->data = kept;
          ps->other_path++;
          ps->worst = fmax(ps->worst, d2);
          if (!(d2 <= 1e-12)) {
            print_message("%s: tensor %s (other x ⊗ x path): differs from brute force by %.3g\n", path, x->name, d2);
            failures++;
          }
        }
      }
    }
  }
  trained_free(&tr);
  return failures;
}

static void premultiply_equals_brute_force(void **state) {
  (void)state;
  const char *dirs[] = {"examples/rational", "examples/radiosity", "examples/fluids", "tests/programs"};
  int n = 0, failures = 0;
  PremulStats ps = {0};
  for (size_t i = 0; i < sizeof dirs / sizeof *dirs; i++) failures += for_each_program(dirs[i], premul_program, &ps, &n);
  print_message("%d programs, %d tensors (%d numerator, %d diagonal, %d declared; orders 2..5: %d %d %d %d; %d packed "
                "symmetric axes; %d last x ⊗ x axes also by the other path; %d splits over ranks; %d too large, "
                "skipped): worst relative difference %.2g\n",
                n, ps.tensors, ps.kinds[0], ps.kinds[1], ps.kinds[2], ps.orders[2], ps.orders[3], ps.orders[4],
                ps.orders[5], ps.packed, ps.other_path, ps.splits, ps.skipped, ps.worst);
  assert_int_equal(failures, 0);
  assert_true(ps.other_path > 0 && ps.splits == 3 * ps.tensors);
  for (int o = 2; o <= 5; o++) assert_true(ps.orders[o] > 0);
  assert_true(ps.kinds[RT_DIAG] > 0 && ps.kinds[RT_DECL] > 0 && ps.packed > 0);
}

/* Every tensor's pre-multiplication timed by training itself, each within
 * the phase and together no more than it (bench_reduce read the progress
 * bar's stamps, which skip updates, and printed -3645.694 s and 3649.949 s
 * at F = 500, issue 38). */
static void premultiply_timed_per_tensor(void **state) {
  (void)state;
  Trained tr;
  train_small(&tr, "examples/radiosity/formfactors.npg", 4, 10);
  double sum = 0, phase = tr.m->phase_seconds[2];
  int n = 0;
  for (int i = 0; i < tr.m->nstages; i++)
    for (int t = 0; t < tr.m->stages[i].nterms; t++) {
      RTerm *rt = &tr.m->stages[i].terms[t];
      RTERM_FOR_TENSORS(rt, x) {
        if (!(x->premul_seconds >= 0 && x->premul_seconds <= phase))
          fail_msg("tensor %s: pre-multiplied in %g s, the phase took %g s", x->name, x->premul_seconds, phase);
        sum += x->premul_seconds, n++;
      }
    }
  assert_true(n > 3);
  if (!(sum <= phase * (1 + 1e-9) + 1e-9)) fail_msg("the tensors' times sum to %g s, the phase took %g s", sum, phase);
  trained_free(&tr);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(premultiply_equals_brute_force),
      cmocka_unit_test(premultiply_timed_per_tensor),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
