/* test_cli_args.c — npg.h's command-line parser (npg_args_*, npg_parse_*, npg_parse_basis),
 * the one npgc and the applications share, and its public .npy reader
 * (npg_npy_read): table-driven, through the public API alone. */
#include <limits.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <cmocka.h>

#include "npg.h"

typedef struct LongCase {
  const char *text;
  long lo, hi;
  int rc;
  long value;
  const char *message; /* a substring of the message when refused */
} LongCase;

static void parse_long_table(void **state) {
  (void)state;
  static const LongCase cases[] = {
      {"300", 1, 1000, 0, 300, NULL},
      {"-4", -10, 10, 0, -4, NULL},
      {"300abc", 1, 1000, -1, 0, "'300abc' is not a whole number (expected 1..1000)"},
      {"2.9", 2, 8, -1, 0, "'2.9' is not a whole number (expected 2..8)"},
      {"1e8", 1, 100000, -1, 0, "'1e8' is not a whole number"},
      {"4294967298", 2, 10000, -1, 0, "4294967298 is out of range (expected 2..10000)"},
      {"99999999999999999999", 1, LONG_MAX, -1, 0, "is out of range (expected at least 1)"},
      {"", 1, 10, -1, 0, "'' is not a whole number"},
      {" 5", 1, 10, -1, 0, "' 5' is not a whole number"},
      {"0", 1, 10, -1, 0, "0 is out of range (expected 1..10)"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    const LongCase *c = &cases[i];
    long v = -12345;
    char err[256] = "";
    int rc = npg_parse_long(c->text, c->lo, c->hi, &v, err, sizeof err);
    if (rc != c->rc) fail_msg("'%s': rc %d, expected %d (%s)", c->text, rc, c->rc, err);
    if (rc == 0) assert_int_equal(v, c->value);
    else {
      assert_int_equal(v, -12345); /* untouched when refused */
      if (!strstr(err, c->message)) fail_msg("'%s': message '%s' lacks '%s'", c->text, err, c->message);
    }
  }
}

typedef struct DoubleCase {
  const char *text;
  double lo, hi;
  bool lo_open;
  int rc;
  double value;
  const char *message;
} DoubleCase;

static void parse_double_table(void **state) {
  (void)state;
  static const DoubleCase cases[] = {
      {"0.999", 0, 1, true, 0, 0.999, NULL},
      {"1e-3", 0, INFINITY, false, 0, 1e-3, NULL},
      {"1", 0, 1, true, 0, 1, NULL},
      {"0", 0, 1, true, -1, 0, "0 is out of range (expected (0, 1])"},
      {"99", 0, 1, true, -1, 0, "99 is out of range (expected (0, 1])"},
      {"abc", 0, 1, true, -1, 0, "'abc' is not a number (expected (0, 1])"},
      {"nan", 0, 1, true, -1, 0, "'nan' is not a number"},
      {"inf", 0, INFINITY, false, -1, 0, "inf is out of range (expected at least 0)"},
      {"1e999", 0, INFINITY, false, -1, 0, "1e999 is out of range"},
      {"0.5x", 0, 1, false, -1, 0, "'0.5x' is not a number (expected [0, 1])"},
      {"-1", 0, INFINITY, true, -1, 0, "-1 is out of range (expected above 0)"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    const DoubleCase *c = &cases[i];
    double v = -12345;
    char err[256] = "";
    int rc = npg_parse_double(c->text, c->lo, c->hi, c->lo_open, &v, err, sizeof err);
    if (rc != c->rc) fail_msg("'%s': rc %d, expected %d (%s)", c->text, rc, c->rc, err);
    if (rc == 0) assert_true(v == c->value);
    else if (!strstr(err, c->message)) fail_msg("'%s': message '%s' lacks '%s'", c->text, err, c->message);
  }
}

/* Parse `argv` with the options of a small program; the error, or "" and the values. */
typedef struct Parsed {
  long frames;
  double mu;
  const char *out, *pos;
  bool cc;
  char error[512];
} Parsed;

static Parsed parse(int argc, char **argv) {
  Parsed p = {.frames = 24, .mu = 0.002};
  NpgArgs a;
  npg_args_init(&a, argc, argv, 1, "prog");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_long(&a, "--frames", 2, 10000, &p.frames)) continue;
    if (npg_args_double(&a, "--mu", 0, 10, false, &p.mu)) continue;
    if ((v = npg_args_string(&a, "--out"))) {
      p.out = v;
      continue;
    }
    if (npg_args_flag(&a, "--cc")) {
      p.cc = true;
      continue;
    }
    if ((v = npg_args_positional(&a))) {
      p.pos = v;
      continue;
    }
    npg_args_unknown(&a);
  }
  snprintf(p.error, sizeof p.error, "%s", a.error);
  return p;
}

static void args_both_forms(void **state) {
  (void)state;
  char *a1[] = {"prog", "--frames", "30", "--mu", "0.5", "--out", "D", "--cc", "file"};
  Parsed p = parse(9, a1);
  assert_string_equal(p.error, "");
  assert_int_equal(p.frames, 30);
  assert_true(p.mu == 0.5);
  assert_string_equal(p.out, "D");
  assert_true(p.cc);
  assert_string_equal(p.pos, "file");
  char *a2[] = {"prog", "--frames=30", "--mu=0.5", "--out=D", "--cc", "file"};
  Parsed q = parse(6, a2);
  assert_string_equal(q.error, "");
  assert_int_equal(q.frames, 30);
  assert_true(q.mu == 0.5);
  assert_string_equal(q.out, "D");
  /* a value that looks like an option is still the value (a negative number) */
  char *a3[] = {"prog", "--mu", "-1"};
  assert_string_equal(parse(3, a3).error, "prog: --mu: -1 is out of range (expected [0, 10])");
  /* an empty value after '=' is a value, refused as a number */
  char *a4[] = {"prog", "--frames="};
  assert_string_equal(parse(2, a4).error, "prog: --frames: '' is not a whole number (expected 2..10000)");
}

static void args_errors(void **state) {
  (void)state;
  struct {
    int argc;
    char *argv[4];
    const char *error;
  } cases[] = {
      {3, {"prog", "--frames", "4294967298"}, "prog: --frames: 4294967298 is out of range (expected 2..10000)"},
      {2, {"prog", "--frames"}, "prog: --frames needs a value"},
      {2, {"prog", "--progress"}, "prog: unknown option '--progress'"},
      {2, {"prog", "--progress=1"}, "prog: unknown option '--progress'"},
      {2, {"prog", "--cc=yes"}, "prog: --cc takes no value ('--cc=yes')"},
      {2, {"prog", "--framesx=3"}, "prog: unknown option '--framesx'"},
      /* the first problem is kept: later arguments are not read */
      {4, {"prog", "--mu", "abc", "--bogus"}, "prog: --mu: 'abc' is not a number (expected [0, 10])"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    Parsed p = parse(cases[i].argc, cases[i].argv);
    if (strcmp(p.error, cases[i].error) != 0) fail_msg("case %zu: '%s', expected '%s'", i, p.error, cases[i].error);
  }
}

static void npy_read_roundtrip(void **state) {
  (void)state;
  char dir[] = "/tmp/npg_test_npy_XXXXXX", path[256], err[512];
  assert_non_null(mkdtemp(dir));
  snprintf(path, sizeof path, "%s/a.npy", dir);
  double v[6] = {1, -2.5, 3e-300, 4, 5, 6};
  long shape[2] = {2, 3};
  assert_int_equal(npg_npy_write(path, 2, shape, v, err, sizeof err), 0);
  int nd = -1;
  long got[NPG_NPY_MAX_DIMS];
  size_t n = 0;
  double *r = npg_npy_read(path, &nd, got, &n, err, sizeof err);
  assert_non_null(r);
  assert_int_equal(nd, 2);
  assert_int_equal(got[0], 2);
  assert_int_equal(got[1], 3);
  assert_int_equal(n, 6);
  assert_memory_equal(r, v, sizeof v);
  free(r);
  /* int64 read exactly as doubles */
  long iv[3] = {7, -8, 1L << 53};
  long is[1] = {3};
  snprintf(path, sizeof path, "%s/i.npy", dir);
  assert_int_equal(npg_npy_write_i64(path, 1, is, iv, err, sizeof err), 0);
  r = npg_npy_read(path, &nd, got, &n, err, sizeof err);
  assert_non_null(r);
  assert_true(r[0] == 7 && r[1] == -8 && r[2] == 9007199254740992.0);
  free(r);
  /* beyond 2^53: refused, not rounded */
  iv[2] = (1L << 53) + 1;
  assert_int_equal(npg_npy_write_i64(path, 1, is, iv, err, sizeof err), 0);
  nd = -1;
  assert_null(npg_npy_read(path, &nd, got, &n, err, sizeof err));
  assert_non_null(strstr(err, "i.npy: entry 2 (9007199254740993) is beyond 2^53"));
  assert_int_equal(nd, -1); /* outputs untouched on failure */
  /* a missing file, a truncated one: named */
  snprintf(path, sizeof path, "%s/none.npy", dir);
  assert_null(npg_npy_read(path, &nd, got, &n, err, sizeof err));
  assert_non_null(strstr(err, "none.npy: "));
  snprintf(path, sizeof path, "%s/a.npy", dir);
  assert_int_equal(truncate(path, 100), 0);
  assert_null(npg_npy_read(path, &nd, got, &n, err, sizeof err));
  assert_non_null(strstr(err, "a.npy: "));
  /* a NULL output is refused with its name */
  assert_null(npg_npy_read(path, NULL, got, &n, err, sizeof err));
  assert_string_equal(err, "npg_npy_read: ndim is NULL");
  remove(path);
  snprintf(path, sizeof path, "%s/i.npy", dir);
  remove(path);
  rmdir(dir);
}

/* npg_parse_basis: the one reader of --basis (npgc, Python, the applications). Accepted
 * specs give the name and exactly the keys given (-1 elsewhere); refused ones leave the
 * outputs as they were and say what is wrong, naming the key. */
typedef struct BasisCase {
  const char *spec;
  const char *name;    /* NULL: refused, with `message` */
  int cap;
  double energy;
  int center;
  const char *message; /* the whole message when refused */
} BasisCase;

static void parse_basis_table(void **state) {
  (void)state;
  static const BasisCase cases[] = {
      {"x:cap=3", "x", 3, -1, -1, NULL},
      {"m_y:energy=0.99", "m_y", -1, 0.99, -1, NULL},
      {"h.num1:center=off", "h.num1", -1, -1, 0, NULL},
      {"*:cap=5,energy=1,center=on", "*", 5, 1, 1, NULL},
      {"x:max=7", "x", 7, -1, -1, NULL},                   /* `max` is cap, as in the basis statement */
      {"x:cap 4, energy 0.5", "x", 4, 0.5, -1, NULL},     /* KEY VALUE, blanks around items */
      {"x: cap = 2 ,center=off", "x", 2, -1, 0, NULL},
      {"x", NULL, 0, 0, 0, "'x': expected NAME:cap=N,energy=E,center=on|off (NAME a quantity, a class or '*')"},
      {":cap=3", NULL, 0, 0, 0, "':cap=3': expected NAME:cap=N,energy=E,center=on|off (NAME a quantity, a class or '*')"},
      {"", NULL, 0, 0, 0, "'': expected NAME:cap=N,energy=E,center=on|off (NAME a quantity, a class or '*')"},
      {"x:", NULL, 0, 0, 0, "'x:': nothing after the colon (expected NAME:cap=N,energy=E,center=on|off)"},
      {"x:  ", NULL, 0, 0, 0, "'x:  ': nothing after the colon (expected NAME:cap=N,energy=E,center=on|off)"},
      {"x:cap=0", NULL, 0, 0, 0, "'x:cap=0': cap: 0 is out of range (expected 1..1000000)"},
      {"x:max=1000001", NULL, 0, 0, 0, "'x:max=1000001': max: 1000001 is out of range (expected 1..1000000)"},
      {"x:cap=3;", NULL, 0, 0, 0, "'x:cap=3;': cap: '3;' is not a whole number (expected 1..1000000)"},
      {"x:cap=2.5", NULL, 0, 0, 0, "'x:cap=2.5': cap: '2.5' is not a whole number (expected 1..1000000)"},
      {"x:cap=", NULL, 0, 0, 0, "'x:cap=': cap: '' is not a whole number (expected 1..1000000)"},
      {"x:energy=0", NULL, 0, 0, 0, "'x:energy=0': energy: 0 is out of range (expected (0, 1])"},
      {"x:energy=nan", NULL, 0, 0, 0, "'x:energy=nan': energy: 'nan' is not a number (expected (0, 1])"},
      {"x:energy=1.5", NULL, 0, 0, 0, "'x:energy=1.5': energy: 1.5 is out of range (expected (0, 1])"},
      {"x:center=maybe", NULL, 0, 0, 0, "'x:center=maybe': center is on or off, not 'maybe'"},
      {"x:size=3", NULL, 0, 0, 0,
       "'x:size=3': unknown key 'size' (the keys are cap, energy and center: NAME:cap=N,energy=E,center=on|off)"},
      {"x:capacity=3", NULL, 0, 0, 0,
       "'x:capacity=3': unknown key 'capacity' (the keys are cap, energy and center: NAME:cap=N,energy=E,center=on|off)"},
      {"x:cap=2,cap=3", NULL, 0, 0, 0, "'x:cap=2,cap=3': cap is given twice"},
      {"x:max=2,cap=3", NULL, 0, 0, 0, "'x:max=2,cap=3': cap is given twice"},
      {"x:cap=2 energy=0.5", NULL, 0, 0, 0,
       "'x:cap=2 energy=0.5': 'energy=0.5' after cap's value (items are separated by commas: "
       "NAME:cap=N,energy=E,center=on|off)"},
      {"x:cap=2,,energy=0.5", NULL, 0, 0, 0, "'x:cap=2,,energy=0.5': an empty item (expected NAME:cap=N,energy=E,center=on|off)"},
      {"x:cap=2,", NULL, 0, 0, 0,
       "'x:cap=2,': an empty item after the last comma (expected NAME:cap=N,energy=E,center=on|off)"},
      {"x:=3", NULL, 0, 0, 0, "'x:=3': '=3' has no key (expected NAME:cap=N,energy=E,center=on|off)"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    const BasisCase *c = &cases[i];
    char *name = (char *)"untouched", err[512] = "";
    int cap = -7, center = -7;
    double energy = -7;
    int rc = npg_parse_basis(c->spec, &name, &cap, &energy, &center, err, sizeof err);
    if (c->name) {
      if (rc != 0) fail_msg("'%s': refused: %s", c->spec, err);
      if (strcmp(name, c->name) || cap != c->cap || energy != c->energy || center != c->center)
        fail_msg("'%s': got %s cap %d energy %g center %d", c->spec, name, cap, energy, center);
      free(name);
    } else {
      if (rc != -1) fail_msg("'%s': accepted", c->spec);
      if (strcmp(err, c->message)) fail_msg("'%s': '%s', expected '%s'", c->spec, err, c->message);
      if (strcmp(name, "untouched") || cap != -7 || energy != -7 || center != -7) fail_msg("'%s': outputs written", c->spec);
    }
  }
  /* NULL arguments refused with their name */
  char err[128];
  char *name;
  int cap, center;
  double energy;
  assert_int_equal(npg_parse_basis(NULL, &name, &cap, &energy, &center, err, sizeof err), -1);
  assert_string_equal(err, "npg_parse_basis: argument 'spec' is NULL");
  assert_int_equal(npg_parse_basis("x:cap=1", &name, &cap, NULL, &center, err, sizeof err), -1);
  assert_string_equal(err, "npg_parse_basis: argument 'energy' is NULL");
}

/* npg_parse_basis_product: the same reader with product=OP (issue 41); npg_parse_basis
 * refuses the key as unknown. */
static void parse_basis_product(void **state) {
  (void)state;
  char err[512] = "", *name = NULL, *product = (char *)"untouched";
  int cap = -7, center = -7;
  double energy = -7;
  assert_int_equal(npg_parse_basis_product("u:product=H,cap=4", &name, &cap, &energy, &center, &product, err, sizeof err), 0);
  assert_string_equal(name, "u");
  assert_string_equal(product, "H");
  assert_int_equal(cap, 4);
  assert_true(energy == -1 && center == -1);
  free(name), free(product);
  assert_int_equal(npg_parse_basis_product("u:cap=4", &name, &cap, &energy, &center, &product, err, sizeof err), 0);
  assert_null(product);
  free(name);
  assert_int_equal(npg_parse_basis_product("u:product=H,product=K", &name, &cap, &energy, &center, &product, err,
                                           sizeof err), -1);
  assert_string_equal(err, "'u:product=H,product=K': product is given twice");
  assert_int_equal(npg_parse_basis_product("u:product=", &name, &cap, &energy, &center, &product, err, sizeof err), -1);
  assert_string_equal(err, "'u:product=': product: no op named (expected product=OP)");
  assert_int_equal(npg_parse_basis_product("u:size=3", &name, &cap, &energy, &center, &product, err, sizeof err), -1);
  assert_string_equal(err, "'u:size=3': unknown key 'size' (the keys are cap, energy, center and product: "
                           "NAME:cap=N,energy=E,center=on|off,product=OP)");
  assert_int_equal(npg_parse_basis_product("u:cap=1", &name, &cap, &energy, &center, NULL, err, sizeof err), -1);
  assert_string_equal(err, "npg_parse_basis_product: argument 'product' is NULL");
  assert_int_equal(npg_parse_basis("u:product=H", &name, &cap, &energy, &center, err, sizeof err), -1);
  assert_string_equal(err, "'u:product=H': unknown key 'product' (the keys are cap, energy and center: "
                           "NAME:cap=N,energy=E,center=on|off)");
}

/* NULL arguments are refused with their name, never dereferenced */
static void null_arguments(void **state) {
  (void)state;
  char err[128];
  assert_int_equal(npg_parse_long("3", 1, 5, NULL, err, sizeof err), -1);
  assert_string_equal(err, "npg_parse_long: out is NULL");
  assert_int_equal(npg_parse_double("3", 1, 5, false, NULL, err, sizeof err), -1);
  assert_string_equal(err, "npg_parse_double: out is NULL");
  long v;
  assert_int_equal(npg_parse_long(NULL, 1, 5, &v, err, sizeof err), -1);
  assert_string_equal(err, "no value (expected 1..5)");
  npg_args_init(NULL, 1, NULL, 1, "prog");
  assert_false(npg_args_next(NULL));
  assert_false(npg_args_flag(NULL, "--x"));
  assert_null(npg_args_string(NULL, "--x"));
  assert_null(npg_args_positional(NULL));
  npg_args_unknown(NULL);
  char *argv[] = {"prog", "--n", "3"};
  NpgArgs a;
  npg_args_init(&a, 3, argv, 1, "prog");
  assert_true(npg_args_next(&a));
  assert_false(npg_args_flag(&a, NULL));
  assert_true(npg_args_int(&a, "--n", 1, 5, NULL));
  assert_string_equal(a.error, "prog: npg_args_int: out is NULL");
  npg_args_init(&a, 3, NULL, 1, "prog"); /* no argv: nothing to read */
  assert_false(npg_args_next(&a));
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(parse_long_table), cmocka_unit_test(parse_double_table), cmocka_unit_test(args_both_forms),
      cmocka_unit_test(args_errors),      cmocka_unit_test(npy_read_roundtrip), cmocka_unit_test(null_arguments),
      cmocka_unit_test(parse_basis_table),
      cmocka_unit_test(parse_basis_product),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
