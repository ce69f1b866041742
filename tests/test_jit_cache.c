/* test_jit_cache.c — the cache of cc-compiled evaluators (backends/jit/jit_cache.h):
 * the key's SHA-256 against FIPS 180-4's vectors; an evaluator compiled, stored,
 * loaded from the cache and compiled with the cache off gives the same stage values
 * bit for bit; an entry truncated, with a byte flipped, emptied, replaced by another
 * program's (foreign) or owned by another user is detected, rebuilt and then loaded; the folder is bounded by
 * NPG_CACHE_MAX, oldest out first; badly set NPG_CACHE_DIR, NPG_CACHE_MAX and NPG_JIT
 * are refused naming the variable; with no cc on PATH, auto is libtcc. Every test
 * works in its own scratch folder (NPG_CACHE_DIR), never the user's cache. */
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "support/refeval.h"
#include "testutil.h"

#include "jit_cache.h"

static const char *const RADIOSITY = "examples/radiosity/formfactors.npg";
static const char *const RATIONAL = "examples/rational/rational.npg";

static int setup(void **state) {
  (void)state;
  if (scratch_make("npg_jit_cache") != 0) return -1;
  char dir[512];
  setenv("NPG_CACHE_DIR", scratch_path(dir, "cache"), 1);
  unsetenv("NPG_CACHE_MAX");
  unsetenv("NPG_JIT");
  return 0;
}

static int teardown(void **state) {
  (void)state;
  remove_tree(scratch);
  return 0;
}

/* The cache's entries (KEY.so) and temporary files, counted; the first entry's path. */
static int entries(int *tmp, char *first) {
  char dir[512];
  DIR *d = opendir(scratch_path(dir, "cache"));
  int n = 0;
  *tmp = 0;
  for (struct dirent *e; d && (e = readdir(d));) {
    size_t len = strlen(e->d_name);
    if (strstr(e->d_name, ".tmp.")) (*tmp)++;
    else if (len == 67 && strcmp(e->d_name + 64, ".so") == 0) {
      if (first && n == 0) snprintf(first, 600, "%s/%s", dir, e->d_name);
      n++;
    }
  }
  if (d) closedir(d);
  return n;
}

static NpgJitInfo info(NpgFull *f) {
  NpgJitInfo ji;
  if (npg_full_jit_info(f, &ji) != 0) fail_msg("no jit info: %s", npg_full_error(f));
  return ji;
}

static void sha256_vectors(void **state) {
  (void)state;
  char hex[65];
  jit_cache_sha256_hex("", 0, hex);
  assert_string_equal(hex, "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  jit_cache_sha256_hex("abc", 3, hex);
  assert_string_equal(hex, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  const char *two = "abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"; /* 56 bytes: two blocks of padding */
  jit_cache_sha256_hex(two, strlen(two), hex);
  assert_string_equal(hex, "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  /* one million 'a' fed at once: the long-message vector */
  char *a = malloc(1000000);
  memset(a, 'a', 1000000);
  jit_cache_sha256_hex(a, 1000000, hex);
  free(a);
  assert_string_equal(hex, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
  /* the key covers each part: moving text between the source and the flags changes it */
  char k1[65], k2[65], k3[65];
  jit_cache_key("ab", "gcc", "-O3", k1);
  jit_cache_key("a", "bgcc", "-O3", k2);
  jit_cache_key("ab", "gcc", "-O2", k3);
  assert_true(strcmp(k1, k2) != 0 && strcmp(k1, k3) != 0);
}

/* Random data into every evaluator of `fs` (bind_random's callback). */
typedef struct Fulls {
  NpgFull **f;
  int n;
} Fulls;

static void set_all(void *user, const Sym *s, int ndim, const long *shape, const double *values) {
  Fulls *fs = user;
  for (int i = 0; i < fs->n; i++)
    if (npg_full_set(fs->f[i], s->name, ndim, shape, values, s->name) != 0) fail_msg("%s", npg_full_error(fs->f[i]));
}

/* Every stage of every evaluator equal to the first's, bit for bit, on random data of size 6. */
static void same_bits(NpgProgram *p, NpgFull **f, int n) {
  Program *prog = program_ir(p);
  RefData *d = ref_new(prog, 6);
  Fulls fs = {f, n};
  bind_random(d, prog, 6, 7u, false, set_all, &fs);
  for (int i = 0; i < n; i++)
    if (npg_full_eval(f[i], 0) != 0) fail_msg("evaluator %d: %s", i, npg_full_error(f[i]));
  int compared = 0;
  for (int s = 0; s < prog->stages.n; s++) {
    const char *name = ((const Stage *)prog->stages.v[s])->sym->name;
    size_t n0, ni;
    const double *a = npg_full_get(f[0], name, &n0);
    for (int i = 1; i < n; i++) {
      const double *b = npg_full_get(f[i], name, &ni);
      assert_true(a && b);
      assert_int_equal(n0, ni);
      if (memcmp(a, b, sizeof(double) * n0) != 0) fail_msg("stage %s differs between evaluators 0 and %d", name, i);
      compared++;
    }
  }
  assert_true(compared >= prog->stages.n - 1);
  ref_free(d);
}

static void cached_equals_uncached(void **state) {
  (void)state;
  NpgProgram *p = compile_file(RADIOSITY);
  NpgFull *f[4];
  f[0] = npg_full_new(p, NPG_CC); /* an empty cache: compiled, stored */
  f[1] = npg_full_new(p, NPG_CC); /* loaded */
  f[2] = npg_full_new(p, NPG_AUTO); /* cc is installed: auto is cc, loaded */
  setenv("NPG_CACHE_MAX", "0", 1); /* the cache off */
  f[3] = npg_full_new(p, NPG_CC);
  unsetenv("NPG_CACHE_MAX");
  for (int i = 0; i < 4; i++)
    if (npg_full_error(f[i])[0]) fail_msg("evaluator %d: %s", i, npg_full_error(f[i]));
  int want[4] = {0, 1, 1, -1};
  for (int i = 0; i < 4; i++) {
    NpgJitInfo ji = info(f[i]);
    assert_int_equal(ji.backend, NPG_CC);
    assert_int_equal(ji.cache, want[i]);
    assert_true(ji.compile_seconds > 0);
  }
  int tmp;
  assert_int_equal(entries(&tmp, NULL), 1);
  assert_int_equal(tmp, 0);
  same_bits(p, f, 4);
  for (int i = 0; i < 4; i++) npg_full_free(f[i]);
  npg_free(p);
}

/* Damage the entry with `how`, create the evaluator: the damage is detected (cache 2),
 * the evaluator is right, and the rebuilt entry then loads (cache 1). */
static void damaged(NpgProgram *p, NpgFull *ref, const char *how) {
  char path[600];
  int tmp;
  assert_int_equal(entries(&tmp, path), 1);
  size_t n;
  char *bytes = slurp(path, &n);
  if (strcmp(how, "flip") == 0) {
    bytes[n / 2] ^= 0x20;
    write_file(path, bytes, n);
  } else if (strcmp(how, "truncate") == 0) {
    write_file(path, bytes, n / 3);
  } else if (strcmp(how, "empty") == 0) {
    write_file(path, bytes, 0);
  } else if (strcmp(how, "owner") == 0) { /* a valid entry another user owns */
    assert_int_equal(chown(path, 65534, 65534), 0);
  } else if (strcmp(how, "foreign") == 0) { /* another program's valid entry under this key */
    char other[600];
    NpgProgram *q = compile_text("foreign", "input x : real[3]\noutput y = [x[0]*x[2], x[1]^2]\n");
    NpgFull *g = npg_full_new(q, NPG_CC);
    if (npg_full_error(g)[0]) fail_msg("%s", npg_full_error(g));
    npg_full_free(g);
    npg_free(q);
    char dir[512];
    DIR *d = opendir(scratch_path(dir, "cache"));
    other[0] = 0;
    for (struct dirent *e; d && (e = readdir(d));)
      if (strlen(e->d_name) == 67 && strcmp(strrchr(path, '/') + 1, e->d_name) != 0)
        snprintf(other, sizeof other, "%s/%s", dir, e->d_name);
    if (d) closedir(d);
    assert_true(other[0]);
    assert_int_equal(rename(other, path), 0);
  }
  free(bytes);
  NpgFull *f = npg_full_new(p, NPG_CC);
  if (npg_full_error(f)[0]) fail_msg("%s: %s", how, npg_full_error(f));
  if (info(f).cache != 2) fail_msg("%s entry not detected (cache %d)", how, info(f).cache);
  NpgFull *g = npg_full_new(p, NPG_CC);
  assert_int_equal(info(g).cache, 1);
  NpgFull *fs[3] = {ref, f, g};
  same_bits(p, fs, 3);
  npg_full_free(f);
  npg_full_free(g);
}

static void damaged_entries_rebuilt(void **state) {
  (void)state;
  char dir[512];
  remove_tree(scratch_path(dir, "cache"));
  NpgProgram *p = compile_file(RATIONAL);
  setenv("NPG_CACHE_MAX", "0", 1);
  NpgFull *ref = npg_full_new(p, NPG_CC); /* uncached: the reference */
  unsetenv("NPG_CACHE_MAX");
  NpgFull *first = npg_full_new(p, NPG_CC);
  assert_int_equal(info(first).cache, 0);
  npg_full_free(first);
  damaged(p, ref, "flip");
  damaged(p, ref, "truncate");
  damaged(p, ref, "empty");
  damaged(p, ref, "foreign");
  if (geteuid() == 0) damaged(p, ref, "owner"); /* only root may give a file away */
  npg_full_free(ref);
  npg_free(p);
}

/* NPG_CACHE_MAX bounds the folder: with room for about two entries, five programs leave
 * at most two, the newest among them. */
static void cache_bounded(void **state) {
  (void)state;
  char dir[512];
  remove_tree(scratch_path(dir, "cache"));
  NpgProgram *p = compile_file(RATIONAL);
  NpgFull *f = npg_full_new(p, NPG_CC);
  char path[600];
  int tmp;
  assert_int_equal(entries(&tmp, path), 1);
  size_t size;
  free(slurp(path, &size));
  npg_full_free(f);
  npg_free(p);
  char max[64];
  snprintf(max, sizeof max, "%zu", 2 * size + size / 2);
  setenv("NPG_CACHE_MAX", max, 1);
  for (int k = 1; k <= 5; k++) {
    char text[256];
    snprintf(text, sizeof text, "input x : real[2]\noutput y = [x[0]*x[1] + %d, x[1]^2 * %d]\n", k, k + 1);
    NpgProgram *q = compile_text("bounded", text);
    NpgFull *g = npg_full_new(q, NPG_CC);
    if (npg_full_error(g)[0]) fail_msg("%s", npg_full_error(g));
    assert_int_equal(info(g).cache, 0);
    npg_full_free(g);
    npg_free(q);
    int n = entries(&tmp, NULL);
    assert_true(n >= 1 && n <= 2);
  }
  /* the newest is kept: creating it again is a hit */
  NpgProgram *q = compile_text("bounded", "input x : real[2]\noutput y = [x[0]*x[1] + 5, x[1]^2 * 6]\n");
  NpgFull *g = npg_full_new(q, NPG_CC);
  assert_int_equal(info(g).cache, 1);
  npg_full_free(g);
  npg_free(q);
  unsetenv("NPG_CACHE_MAX");
}

/* The evaluator's construction error holds `want`. */
static void refused(NpgProgram *p, NpgBackend b, const char *want) {
  NpgFull *f = npg_full_new(p, b);
  if (!strstr(npg_full_error(f), want)) fail_msg("expected '%s', got '%s'", want, npg_full_error(f));
  NpgJitInfo ji;
  assert_int_equal(npg_full_jit_info(f, &ji), -1);
  npg_full_free(f);
}

static void bad_settings_named(void **state) {
  (void)state;
  NpgProgram *p = compile_file(RATIONAL);
  char saved[512], file[512];
  snprintf(saved, sizeof saved, "%s", getenv("NPG_CACHE_DIR"));
  write_file(scratch_path(file, "a_file"), "x", 1);
  setenv("NPG_CACHE_DIR", file, 1);
  refused(p, NPG_CC, "NPG_CACHE_DIR='");
  refused(p, NPG_CC, "is not a folder npg can write");
  setenv("NPG_CACHE_DIR", saved, 1);
  setenv("NPG_CACHE_MAX", "12 MB", 1);
  refused(p, NPG_CC, "NPG_CACHE_MAX='12 MB' is not a size in bytes");
  unsetenv("NPG_CACHE_MAX");
  setenv("NPG_JIT", "gcc", 1);
  refused(p, NPG_AUTO, "NPG_JIT='gcc' is not a backend (expected auto, cc or tcc)");
  /* NPG_JIT chooses for auto only: an explicit backend stays */
  setenv("NPG_JIT", "tcc", 1);
  NpgFull *f = npg_full_new(p, NPG_AUTO), *g = npg_full_new(p, NPG_CC);
  assert_int_equal(info(f).backend, NPG_TCC);
  assert_int_equal(info(f).cache, -1);
  assert_int_equal(info(g).backend, NPG_CC);
  npg_full_free(f);
  npg_full_free(g);
  unsetenv("NPG_JIT");
  /* no compiler: auto is libtcc, cc says what to do */
  setenv("CC", "npg-no-such-compiler", 1);
  f = npg_full_new(p, NPG_AUTO);
  assert_string_equal(npg_full_error(f), "");
  assert_int_equal(info(f).backend, NPG_TCC);
  npg_full_free(f);
  refused(p, NPG_CC, "cannot run the C compiler 'npg-no-such-compiler': not found on PATH (set CC, or choose libtcc: --jit tcc)");
  unsetenv("CC");
  npg_free(p);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(sha256_vectors),
      cmocka_unit_test(cached_equals_uncached),
      cmocka_unit_test(damaged_entries_rebuilt),
      cmocka_unit_test(cache_bounded),
      cmocka_unit_test(bad_settings_named),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
