/* args.c — the command-line parser npgc and the applications share
 * (npg.h, "command lines"): `--opt value` and `--opt=value`, strict numbers
 * with their range in the message, unknown options named as such; and the
 * one reader of a per-name basis option (`--basis NAME:cap=N,...`,
 * npg_parse_basis), which npgc, the Python module and the applications call.
 *
 * Why a public function and not a helper of examples/common: the
 * applications may use npg.h only, and npgc is a client of npg.h too; one
 * parser behind the public API is the one place both can reach without a
 * dependency pointing from the compiler up into the examples. */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "ast.h" /* error_set */
#include "npg.h"

/* The range as the messages print it: "1..10000", "at least 1", "(0, 1]". */
static void long_range(char *buf, size_t n, long lo, long hi) {
  if (hi == LONG_MAX) snprintf(buf, n, "at least %ld", lo);
  else snprintf(buf, n, "%ld..%ld", lo, hi);
}

static void double_range(char *buf, size_t n, double lo, double hi, bool lo_open) {
  if (isinf(hi) && isinf(lo)) snprintf(buf, n, "a finite number");
  else if (isinf(hi)) snprintf(buf, n, "%s %g", lo_open ? "above" : "at least", lo);
  else snprintf(buf, n, "%s%g, %g]", lo_open ? "(" : "[", lo, hi);
}

int npg_parse_long(const char *s, long lo, long hi, long *out, char *err, size_t errlen) {
  if (!out) return error_set(err, errlen, "npg_parse_long: out is NULL");
  char range[96];
  long_range(range, sizeof range, lo, hi);
  if (!s) return error_set(err, errlen, "no value (expected %s)", range);
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  /* strtol skips leading blanks: " 5" is not what a user typed as a number either */
  if (!*s || end == s || *end || s[0] == ' ' || s[0] == '\t')
    return error_set(err, errlen, "'%s' is not a whole number (expected %s)", s, range);
  if (errno == ERANGE || v < lo || v > hi) return error_set(err, errlen, "%s is out of range (expected %s)", s, range);
  *out = v;
  return 0;
}

int npg_parse_double(const char *s, double lo, double hi, bool lo_open, double *out, char *err, size_t errlen) {
  if (!out) return error_set(err, errlen, "npg_parse_double: out is NULL");
  char range[96];
  double_range(range, sizeof range, lo, hi, lo_open);
  if (!s) return error_set(err, errlen, "no value (expected %s)", range);
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  if (!*s || end == s || *end || s[0] == ' ' || s[0] == '\t' || isnan(v))
    return error_set(err, errlen, "'%s' is not a number (expected %s)", s, range);
  /* ERANGE on underflow still gives a usable tiny value; overflow gives inf, refused below */
  if (!isfinite(v) || v < lo || v > hi || (lo_open && v == lo))
    return error_set(err, errlen, "%s is out of range (expected %s)", s, range);
  *out = v;
  return 0;
}

void npg_args_init(NpgArgs *a, int argc, char **argv, int first, const char *prog) {
  if (!a) return;
  memset(a, 0, sizeof *a);
  if (!argv || argc < 0) argc = 0; /* nothing to read */
  a->argc = argc;
  a->argv = argv;
  a->i = first - 1;
  a->prog = prog ? prog : "";
}

bool npg_args_next(NpgArgs *a) {
  if (!a || a->error[0]) return false;
  a->i++;
  return a->i < a->argc;
}

/* The argument being read, NULL after an error or past the end (or for a NULL `a`). */
static const char *current(const NpgArgs *a) {
  return a && !a->error[0] && a->i >= 0 && a->i < a->argc ? a->argv[a->i] : NULL;
}

static void args_fail(NpgArgs *a, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void args_fail(NpgArgs *a, const char *fmt, ...) {
  if (a->error[0]) return; /* the first problem is the one to fix */
  int n = snprintf(a->error, sizeof a->error, "%s%s", a->prog, a->prog[0] ? ": " : "");
  if (n < 0 || (size_t)n >= sizeof a->error) return;
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(a->error + n, sizeof a->error - (size_t)n, fmt, ap);
  va_end(ap);
}

bool npg_args_flag(NpgArgs *a, const char *name) {
  const char *s = name ? current(a) : NULL;
  size_t n = s ? strlen(name) : 0;
  if (!s || strncmp(s, name, n) != 0) return false;
  if (s[n] == '=') {
    args_fail(a, "%s takes no value ('%s')", name, s);
    return true;
  }
  return s[n] == 0;
}

const char *npg_args_string(NpgArgs *a, const char *name) {
  const char *s = name ? current(a) : NULL;
  size_t n = s ? strlen(name) : 0;
  if (!s || strncmp(s, name, n) != 0) return NULL;
  if (s[n] == '=') return s + n + 1;
  if (s[n] != 0) return NULL;
  if (a->i + 1 >= a->argc) {
    args_fail(a, "%s needs a value", name);
    return NULL;
  }
  return a->argv[++a->i];
}

/* The option `name` was given (its value read, or the error set). */
static bool matched(NpgArgs *a, const char *name, const char **value) {
  const char *s = name ? current(a) : NULL;
  size_t n = s ? strlen(name) : 0;
  if (!s || strncmp(s, name, n) != 0 || (s[n] != 0 && s[n] != '=')) return false;
  *value = npg_args_string(a, name);
  return true;
}

bool npg_args_long(NpgArgs *a, const char *name, long lo, long hi, long *out) {
  const char *v;
  if (!matched(a, name, &v)) return false;
  char err[256];
  if (v && npg_parse_long(v, lo, hi, out, err, sizeof err) != 0) args_fail(a, "%s: %s", name, err);
  return true;
}

bool npg_args_int(NpgArgs *a, const char *name, int lo, int hi, int *out) {
  long v = 0;
  bool took = npg_args_long(a, name, lo, hi, &v);
  if (took && !a->error[0] && !out) args_fail(a, "npg_args_int: out is NULL");
  else if (took && !a->error[0]) *out = (int)v;
  return took;
}

bool npg_args_double(NpgArgs *a, const char *name, double lo, double hi, bool lo_open, double *out) {
  const char *v;
  if (!matched(a, name, &v)) return false;
  char err[256];
  if (v && npg_parse_double(v, lo, hi, lo_open, out, err, sizeof err) != 0) args_fail(a, "%s: %s", name, err);
  return true;
}

int npg_backend_parse(const char *name, NpgBackend *out) {
  static const char *const names[] = {"tcc", "cc", "auto"}; /* indexed by NpgBackend */
  for (int i = 0; name && out && i < 3; i++)
    if (strcmp(name, names[i]) == 0) {
      *out = (NpgBackend)i;
      return 0;
    }
  return -1;
}

const char *npg_backend_name(NpgBackend b) {
  return b == NPG_TCC ? "tcc" : b == NPG_CC ? "cc" : b == NPG_AUTO ? "auto" : NULL;
}

bool npg_args_backend(NpgArgs *a, NpgBackend *out) {
  const char *v;
  if (npg_args_flag(a, "--cc")) {
    if (!a->error[0]) *out = NPG_CC;
    return true;
  }
  if (!matched(a, "--jit", &v)) return false;
  if (v && npg_backend_parse(v, out) != 0) args_fail(a, "--jit: '%s' is not a backend (expected auto, cc or tcc)", v);
  return true;
}

const char *npg_args_positional(NpgArgs *a) {
  const char *s = current(a);
  return s && (s[0] != '-' || s[1] == 0) ? s : NULL;
}

void npg_args_unknown(NpgArgs *a) {
  const char *s = current(a);
  if (!s) return;
  if (s[0] == '-' && s[1]) {
    const char *eq = strchr(s, '=');
    args_fail(a, "unknown option '%.*s'", eq ? (int)(eq - s) : (int)strlen(s), s);
  } else {
    args_fail(a, "unexpected argument '%s'", s);
  }
}

/* ---------------------------------------------------------------- --basis */

#define BASIS_SYNTAX "NAME:cap=N,energy=E,center=on|off"

/* The one reader of --basis: npg_parse_basis (`product`, NULL, not a key)
 * and npg_parse_basis_product (`product=OP` too, issue 41). */
static int parse_basis(const char *fn, const char *spec, char **name, int *cap, double *energy, int *center,
                       char **product, char *err, size_t errlen) {
  if (!spec || !name || !cap || !energy || !center)
    return error_set(err, errlen, "%s: argument '%s' is NULL", fn,
                     !spec ? "spec" : !name ? "name" : !cap ? "cap" : !energy ? "energy" : "center");
  const char *keys = product ? "cap, energy, center and product" : "cap, energy and center";
  char prod[256] = "";
  const char *colon = strchr(spec, ':');
  if (!colon || colon == spec)
    return error_set(err, errlen, "'%s': expected " BASIS_SYNTAX " (NAME a quantity, a class or '*')", spec);
  int c = -1, k_center = -1;
  double e = -1;
  bool given[4] = {false, false, false, false}; /* cap, energy, center, product */
  const char *p = colon + 1;
  p += strspn(p, " \t");
  if (!*p) return error_set(err, errlen, "'%s': nothing after the colon (expected " BASIS_SYNTAX ")", spec);
  for (;;) {
    /* one item: KEY=VALUE or KEY VALUE, blanks around */
    size_t klen = strcspn(p, "= \t,");
    const char *v = p + klen;
    v += strspn(v, " \t");
    if (*v == '=') v += 1 + strspn(v + 1, " \t");
    size_t vlen = strcspn(v, " \t,");
    const char *next = v + vlen;
    next += strspn(next, " \t");
    if (*next && *next != ',')
      return error_set(err, errlen, "'%s': '%.*s' after %.*s's value (items are separated by commas: " BASIS_SYNTAX ")",
                       spec, (int)strcspn(next, ","), next, (int)klen, p);
    if (klen == 0 && vlen == 0) return error_set(err, errlen, "'%s': an empty item (expected " BASIS_SYNTAX ")", spec);
    if (klen == 0)
      return error_set(err, errlen, "'%s': '%.*s' has no key (expected " BASIS_SYNTAX ")", spec, (int)(next - p), p);
    char key[16] = "", value[256], why[384];
    if (klen < sizeof key) memcpy(key, p, klen), key[klen] = 0; /* a longer one is no key */
    int which = !strcmp(key, "cap") || !strcmp(key, "max") ? 0 : !strcmp(key, "energy") ? 1 : !strcmp(key, "center") ? 2
                : product && !strcmp(key, "product") ? 3 : -1;
    if (which < 0)
      return error_set(err, errlen, "'%s': unknown key '%.*s' (the keys are %s: " BASIS_SYNTAX "%s)", spec, (int)klen,
                       p, keys, product ? ",product=OP" : "");
    if (vlen >= sizeof value) return error_set(err, errlen, "'%s': the value of %s is too long", spec, key);
    memcpy(value, v, vlen), value[vlen] = 0;
    if (given[which]) return error_set(err, errlen, "'%s': %s is given twice", spec, which ? key : "cap");
    given[which] = true;
    if (which == 0) {
      long n;
      if (npg_parse_long(value, 1, 1000000, &n, why, sizeof why) != 0)
        return error_set(err, errlen, "'%s': %s: %s", spec, key, why);
      c = (int)n;
    } else if (which == 1) {
      if (npg_parse_double(value, 0, 1, true, &e, why, sizeof why) != 0)
        return error_set(err, errlen, "'%s': energy: %s", spec, why);
    } else if (which == 3) { /* an op's name; training checks it names an SPD op of the program */
      if (!value[0]) return error_set(err, errlen, "'%s': product: no op named (expected product=OP)", spec);
      snprintf(prod, sizeof prod, "%s", value);
    } else if (!strcmp(value, "on") || !strcmp(value, "off")) {
      k_center = !strcmp(value, "on");
    } else {
      return error_set(err, errlen, "'%s': center is on or off, not '%s'", spec, value);
    }
    if (!*next) break;
    p = next + 1;
    p += strspn(p, " \t");
    if (!*p) return error_set(err, errlen, "'%s': an empty item after the last comma (expected " BASIS_SYNTAX ")", spec);
  }
  char *n = mem_malloc((size_t)(colon - spec) + 1);
  if (!n) return error_set(err, errlen, "out of memory");
  memcpy(n, spec, (size_t)(colon - spec));
  n[colon - spec] = 0;
  char *pr = NULL;
  if (prod[0] && !(pr = mem_malloc(strlen(prod) + 1))) return free(n), error_set(err, errlen, "out of memory");
  if (pr) memcpy(pr, prod, strlen(prod) + 1);
  *name = n, *cap = c, *energy = e, *center = k_center;
  if (product) *product = pr;
  return 0;
}

int npg_parse_basis(const char *spec, char **name, int *cap, double *energy, int *center, char *err, size_t errlen) {
  return parse_basis("npg_parse_basis", spec, name, cap, energy, center, NULL, err, errlen);
}

int npg_parse_basis_product(const char *spec, char **name, int *cap, double *energy, int *center, char **product,
                            char *err, size_t errlen) {
  if (!product) return error_set(err, errlen, "npg_parse_basis_product: argument 'product' is NULL");
  return parse_basis("npg_parse_basis_product", spec, name, cap, energy, center, product, err, errlen);
}
