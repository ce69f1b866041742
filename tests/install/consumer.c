/* consumer.c — a program built against an installed npg with pkg-config
 * (or find_package(npg)) only: compiles a small program that uses the
 * stdlib, evaluates it with the full evaluator, checks the values. */
#include <math.h>
#include <stdio.h>

#include <npg.h>

static const char *const program =
    "use geometry\n"
    "input x : real[2]\n"
    "input a : real[3]\n"
    "input b : real[3]\n"
    "output y = [ (x[0]*x[1] + x[1]^2) / x[0]^2,  x[0]^2 / x[1]^2 ]\n"
    "output d = dot(a, b)\n";

static int check(NpgFull *f, const char *name, const double *want, size_t n) {
  size_t count = 0;
  const double *got = npg_full_get(f, name, &count);
  if (!got || count != n) {
    fprintf(stderr, "consumer: %s: %zu values, want %zu\n", name, got ? count : 0, n);
    return 1;
  }
  for (size_t i = 0; i < n; i++)
    if (!(fabs(got[i] - want[i]) <= 1e-12 * fabs(want[i]))) {
      fprintf(stderr, "consumer: %s[%zu] = %.17g, want %.17g\n", name, i, got[i], want[i]);
      return 1;
    }
  return 0;
}

int main(void) {
  NpgOptions opt = {0};
  opt.source = program;  /* std_dir NULL: the installed stdlib */
  NpgProgram *p = npg_compile("consumer.npg", &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  NpgFull *f = npg_full_new(p, NPG_TCC);
  const long s2[] = {2}, s3[] = {3};
  const double x[] = {1.5, 2.0}, a[] = {1, 2, 3}, b[] = {4, 5, 6};
  int rc = 1;
  if (!f || npg_full_error(f)[0] || npg_full_set(f, "x", 1, s2, x, "x") || npg_full_set(f, "a", 1, s3, a, "a") ||
      npg_full_set(f, "b", 1, s3, b, "b") || npg_full_eval(f, 0)) {
    fprintf(stderr, "consumer: %s\n", f ? npg_full_error(f) : "out of memory");
  } else {
    const double y[] = {(x[0] * x[1] + x[1] * x[1]) / (x[0] * x[0]), x[0] * x[0] / (x[1] * x[1])}, d[] = {32};
    rc = check(f, "y", y, 2) | check(f, "d", d, 1);
  }
  if (rc == 0) printf("consumer: ok\n");
  npg_full_free(f);
  npg_free(p);
  return rc;
}
