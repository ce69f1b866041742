/* test_emit_checks.c — the bind-time gather checks (backends/emit/emit_checks.c): every
 * index into a dim, where its guard holds, checked once per binding, so the evaluators'
 * gathers need no bounds checks.
 *
 * For programs with a gather of every kind the checker knows — direct, guarded by the
 * index itself or by another param's gather, nested, compound, in a summation, inlined
 * from a fn, in an inlined stage, in an operator's entries — random tables, most entries
 * in range and some not (-1 and past the end), are bound many times: the evaluation must
 * fail exactly when an index the program evaluates is out of range (an oracle written
 * here from each definition), the message must name a table entry or an index that is
 * out of range, and an evaluation that passes must give the definition's values. */
#include <limits.h>
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

enum { F = 5, V = 6 };

typedef struct Data {
  long t[F][2], u[V]; /* index tables into V, entries in -2 .. V+1 */
  double r[V], x[V];
} Data;

static bool in(long k) { return k >= 0 && k < V; }

typedef struct Case {
  const char *name, *text;
  long ny;                                 /* entries of y */
  /* every index the program evaluates in range; then y's values in `y` */
  bool (*ok)(const Data *d);
  void (*value)(const Data *d, double *y);
} Case;

static bool ok_direct(const Data *d) {
  for (int f = 0; f < F; f++)
    if (!in(d->t[f][0]) || !in(d->t[f][1])) return false;
  return true;
}
static void value_direct(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->x[d->t[f][0]] * d->x[d->t[f][1]];
}

static bool ok_guarded(const Data *d) {
  for (int f = 0; f < F; f++)
    if (d->t[f][0] >= V) return false; /* a negative one is never read */
  return true;
}
static void value_guarded(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->t[f][0] >= 0 ? d->x[d->t[f][0]] : 2;
}

static bool ok_nested(const Data *d) {
  for (int f = 0; f < F; f++)
    if (!in(d->t[f][1]) || !in(d->u[d->t[f][1]])) return false;
  return true;
}
static void value_nested(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->x[d->u[d->t[f][1]]];
}

static bool ok_compound(const Data *d) {
  for (int f = 0; f < F; f++)
    if (!in(d->t[f][0] + 1)) return false; /* t[f, 0] itself indexes nothing: -1 reads x[0] */
  return true;
}
static void value_compound(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->x[d->t[f][0] + 1];
}

static void value_sum(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->x[d->t[f][0]] + d->x[d->t[f][1]];
}

static bool ok_fn(const Data *d) {
  for (int f = 0; f < F; f++)
    if (!in(d->t[f][1])) return false;
  return true;
}
static void value_fn(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = 2 * d->x[d->t[f][1]];
}

static bool ok_guard_gather(const Data *d) {
  for (int f = 0; f < F; f++)
    if (!in(d->t[f][0]) || (d->r[d->t[f][0]] > 0.5 && !in(d->t[f][1]))) return false;
  return true;
}
static void value_guard_gather(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->r[d->t[f][0]] > 0.5 ? d->x[d->t[f][1]] : 1;
}

static bool ok_inline(const Data *d) {
  for (int f = 0; f < F; f++)
    if (!in(d->t[f][0])) return false;
  return true;
}
static void value_inline(const Data *d, double *y) {
  for (int f = 0; f < F; f++) y[f] = d->x[d->t[f][0]] + 1;
}

static bool ok_op(const Data *d) {
  for (int i = 0; i < V; i++)
    if (!in(d->u[i])) return false;
  return true;
}
static void value_op(const Data *d, double *y) {
  for (int i = 0; i < V; i++) y[i] = (1 + d->x[d->u[i]]) * d->x[i];
}

#define PARAMS "dim F, V\nparam t : int[F, 2]\nparam u : int[V]\nparam r : real[V]\ninput x : real[V]\n"
static const Case cases[] = {
    {"direct", PARAMS "output y[f:F] = x[t[f, 0]] * x[t[f, 1]]\n", F, ok_direct, value_direct},
    {"guarded", PARAMS "output y[f:F] = if(t[f, 0] >= 0, x[t[f, 0]], 2)\n", F, ok_guarded,
     value_guarded},
    {"nested", PARAMS "output y[f:F] = x[u[t[f, 1]]]\n", F, ok_nested, value_nested},
    {"compound", PARAMS "output y[f:F] = x[t[f, 0] + 1]\n", F, ok_compound, value_compound},
    {"sum", PARAMS "output y[f:F] = sum(k = 0..1, x[t[f, k]])\n", F, ok_direct, value_sum},
    {"fn", PARAMS "fn at(v, k) = v[k]\noutput y[f:F] = 2 * at(x, t[f, 1])\n", F, ok_fn,
     value_fn},
    {"guard_gather", PARAMS "output y[f:F] = if(r[t[f, 0]] > 0.5, x[t[f, 1]], 1)\n", F, ok_guard_gather,
     value_guard_gather},
    {"inline", PARAMS "c[f:F] = x[t[f, 0]]\ninline c\noutput y[f:F] = c[f] + 1\n", F,
     ok_inline, value_inline},
    {"op", PARAMS "op A[i:V, j:V] = delta(i, j) * (1 + x[u[i]])\noutput y = A * x\n", V,
     ok_op, value_op},
};

static unsigned rng;
static long index_draw(void) {
  rng = rng * 1103515245u + 12345u;
  unsigned u = (rng >> 8) % 100;
  return u < 4 ? -1 : u < 6 ? -2 : u < 9 ? V : u < 10 ? V + 1 : (long)(u % V); /* one in ten out of range */
}

static void random_data(Data *d) {
  for (int f = 0; f < F; f++) d->t[f][0] = index_draw(), d->t[f][1] = index_draw();
  for (int i = 0; i < V; i++) {
    d->u[i] = index_draw();
    rng = rng * 1103515245u + 12345u;
    d->r[i] = (double)((rng >> 8) % 1000) / 1000;
    d->x[i] = 0.5 + (double)i / 7;
  }
}

/* The table entry or index a refusal names, checked to be out of range: "t: entry [2, 1]
 * = 9 is out of range for dim V (size 6)" names t[2, 1], which must hold 9; "stage 'y' at
 * [1]: index 6 is out of range for dim V (size 6)" a compound index. */
static void check_message(const Case *c, const Data *d, const char *msg) {
  const char *p = strstr(msg, "error: ");
  if (!p) fail_msg("%s: not a gather error: %s", c->name, msg);
  p += 7;
  long a, b, v, size;
  char param[8];
  int n = sscanf(p, "%7[a-z]: entry [%ld, %ld] = %ld is out of range for dim V (size %ld)", param, &a, &b, &v, &size);
  if (n != 5) n = sscanf(p, "%7[a-z]: entry [%ld] = %ld is out of range for dim V (size %ld)", param, &a, &v, &size) + 1, b = -1;
  if (n == 5) {
    long held = !strcmp(param, "t") && a >= 0 && a < F && b >= 0 && b < 2 ? d->t[a][b]
              : !strcmp(param, "u") && a >= 0 && a < V && b < 0          ? d->u[a]
                                                                          : LONG_MIN;
    if (held != v) fail_msg("%s: the message names %s[%ld, %ld] = %ld, which holds %ld: %s", c->name, param, a, b, v, held, msg);
  } else if (sscanf(p, "stage '%*[a-z]' at [%*[0-9, ]]: index %ld is out of range for dim V (size %ld)", &v, &size) != 2) {
    fail_msg("%s: not a gather error: %s", c->name, msg);
  }
  if (size != V || in(v)) fail_msg("%s: %ld is not out of range: %s", c->name, v, msg);
}

static void refused_exactly_when_out_of_range(void **state) {
  (void)state;
  for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
    const Case *c = &cases[k];
    NpgOptions o = {0};
    o.source = c->text;
    NpgProgram *p = npg_compile(c->name, &o);
    if (!npg_ok(p)) fail_msg("%s: %s", c->name, npg_error(p));
    NpgFull *f = npg_full_new(p, NPG_TCC);
    if (npg_full_error(f)[0]) fail_msg("%s: %s", c->name, npg_full_error(f));
    int accepted = 0, refused = 0;
    rng = 101u * (unsigned)k + 7;
    for (int trial = 0; trial < 80; trial++) {
      Data d;
      random_data(&d);
      double t[F * 2], u[V];
      for (int i = 0; i < F * 2; i++) t[i] = (double)d.t[i / 2][i % 2];
      for (int i = 0; i < V; i++) u[i] = (double)d.u[i];
      long st[2] = {F, 2}, sv[1] = {V};
      npg_full_unbind(f);
      if (npg_full_set(f, "t", 2, st, t, "t") || npg_full_set(f, "u", 1, sv, u, "u") ||
          npg_full_set(f, "r", 1, sv, d.r, "r") || npg_full_set(f, "x", 1, sv, d.x, "x"))
        fail_msg("%s: %s", c->name, npg_full_error(f));
      bool want = c->ok(&d);
      int rc = npg_full_eval(f, trial);
      if (rc != 0 && want) fail_msg("%s: refused a binding whose gathers are in range: %s", c->name, npg_full_error(f));
      if (rc == 0 && !want) fail_msg("%s (trial %d): accepted an index out of range", c->name, trial);
      if (rc != 0) {
        check_message(c, &d, npg_full_error(f));
        refused++;
        continue;
      }
      accepted++;
      double y[V];
      size_t ny;
      const double *got = npg_full_get(f, "y", &ny);
      assert_int_equal(ny, c->ny);
      c->value(&d, y);
      for (long i = 0; i < c->ny; i++)
        if (fabs(got[i] - y[i]) > 1e-15 * fabs(y[i])) fail_msg("%s: y[%ld] = %.17g, expected %.17g", c->name, i, got[i], y[i]);
    }
    print_message("%-13s %2d bindings accepted, %2d refused\n", c->name, accepted, refused);
    assert_true(accepted >= 5 && refused >= 5); /* both sides of each program's rule were seen */
    npg_full_free(f);
    npg_free(p);
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {cmocka_unit_test(refused_exactly_when_out_of_range)};
  return cmocka_run_group_tests(tests, NULL, NULL);
}
