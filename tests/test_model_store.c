/* test_model_store.c — backends/model/model_store.c: MODEL/ directories on disk
 * (DESIGN §2).
 *
 * A model written and read back is the same model, bit for bit; writing over
 * a model replaces it whole, and a write that fails leaves the previous model
 * as it was, with no temporary directory behind. Every way a model directory
 * can be wrong on reading has its exact message here, naming the file (and
 * manifest line) that is wrong. Scratch models go to a fresh directory under
 * $TMPDIR (or /tmp), removed at the end; these tests run under ASan/UBSan
 * too, so every error path is also checked for leaks. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp, lstat */

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>

#include "model_store.h"
#include "npy.h"
#include "testutil.h"

#define PROGRAM UINT64_C(0x0123456789abcdef)
#define ENOENT_TEXT "No such file or directory"

/* ---------------------------------------------------------------- scratch files */

static int make_scratch(void **state) {
  (void)state;
  return scratch_make("npg_test_model_store");
}

static int remove_scratch(void **state) {
  (void)state;
  remove_tree(scratch);
  return 0;
}

/* Replace the first `from` in the text file `path` by `to`. */
static void edit_file(const char *path, const char *from, const char *to) {
  size_t n;
  char *text = slurp(path, &n);
  char *at = strstr(text, from);
  if (!at) fail_msg("%s: no '%s' to replace", path, from);
  size_t before = (size_t)(at - text), flen = strlen(from), tlen = strlen(to);
  char *edited = malloc(n - flen + tlen + 1);
  memcpy(edited, text, before);
  memcpy(edited + before, to, tlen);
  memcpy(edited + before + tlen, at + flen, n - before - flen);
  write_file(path, edited, n - flen + tlen);
  free(edited);
  free(text);
}

/* Recompute the manifest's own checksum (its last line) after an edit, as a
 * deliberate rewrite of the manifest would. */
static void reseal(const char *path) {
  size_t n;
  char *text = slurp(path, &n);
  char *last = strstr(text, "\nmanifest fnv1a64 ");
  if (!last) fail_msg("%s: no checksum line", path);
  size_t body = (size_t)(last - text) + 1;
  char line[64];
  int k = snprintf(line, sizeof line, "manifest fnv1a64 %016llx\n",
                   (unsigned long long)model_hash_bytes(model_hash_init(), text, body));
  char *out = malloc(body + (size_t)k);
  memcpy(out, text, body);
  memcpy(out + body, line, (size_t)k);
  write_file(path, out, body + (size_t)k);
  free(out);
  free(text);
}

/* FNV-1a 64 of the file `path`'s bytes. */
static uint64_t file_hash(const char *path) {
  size_t n;
  char *bytes = slurp(path, &n);
  uint64_t h = model_hash_bytes(model_hash_init(), bytes, n);
  free(bytes);
  return h;
}

static int exists(const char *path) {
  struct stat st;
  return lstat(path, &st) == 0;
}

/* No "<name>.tmp.*" or "<name>.old.*" left in scratch by a write of
 * "<scratch>/<name>". */
static void assert_no_leftovers(const char *name) {
  DIR *d = opendir(scratch);
  assert_non_null(d);
  struct dirent *e;
  char tmp[256], old[256];
  snprintf(tmp, sizeof tmp, "%s.tmp.", name);
  snprintf(old, sizeof old, "%s.old.", name);
  while ((e = readdir(d)))
    if (strncmp(e->d_name, tmp, strlen(tmp)) == 0 || strncmp(e->d_name, old, strlen(old)) == 0)
      fail_msg("%s/%s left behind", scratch, e->d_name);
  closedir(d);
}

/* ---------------------------------------------------------------- models */

/* The model most tests start from: two metadata lines, a 3x4 basis and a
 * vector of 5, program PROGRAM. */
static void example_model(ModelStore *m) {
  static const long shape_a[] = {3, 4}, shape_b[] = {5};
  double a[12], b[5];
  for (int i = 0; i < 12; i++) a[i] = 1.0 / (i + 1);
  for (int i = 0; i < 5; i++) b[i] = -1e-300 * i;
  model_store_init(m);
  m->program_hash = PROGRAM;
  assert_int_equal(model_store_meta(m, "basis_classes %d", 2), 0);
  assert_int_equal(model_store_meta(m, "energy %.17g", 0.999), 0);
  assert_int_equal(model_store_add(m, "a", 2, shape_a, a), 0);
  assert_int_equal(model_store_add(m, "b", 1, shape_b, b), 0);
}

/* `got` holds the same metadata lines and arrays as `want`, in order, with
 * the same shapes and the same bits. */
static void assert_same_model(const ModelStore *got, const ModelStore *want) {
  assert_int_equal(got->program_hash, want->program_hash);
  assert_int_equal(got->nmeta, want->nmeta);
  for (int i = 0; i < want->nmeta; i++) assert_string_equal(got->meta[i], want->meta[i]);
  assert_int_equal(got->narrays, want->narrays);
  for (int i = 0; i < want->narrays; i++) {
    const ModelArray *g = &got->arrays[i], *w = &want->arrays[i];
    assert_string_equal(g->name, w->name);
    assert_int_equal(g->a.type, NPY_F64);
    assert_int_equal(g->a.ndim, w->a.ndim);
    for (int k = 0; k < w->a.ndim; k++) assert_int_equal(g->a.shape[k], w->a.shape[k]);
    assert_int_equal(g->a.count, w->a.count);
    assert_non_null(g->a.data);
    if (memcmp(g->a.data, w->a.data, w->a.count * sizeof(double)) != 0) fail_msg("array %s: values differ", w->name);
  }
}

static void write_ok(const char *dir, const ModelStore *m) {
  char err[1024];
  if (model_store_write(dir, m, ERR_OF(err, sizeof err)) != 0) fail_msg("%s", err);
}

/* `dir` reads back as `want`. */
static void expect_model(const char *dir, const ModelStore *want) {
  ModelStore got;
  char err[1024];
  if (model_store_read(dir, want->program_hash, &got, ERR_OF(err, sizeof err)) != 0) fail_msg("%s", err);
  assert_same_model(&got, want);
  model_store_free(&got);
}

/* model_store_read(`dir`) fails with exactly `want` and leaves the store
 * empty. */
static void expect_read_error(const char *dir, uint64_t program, const char *want) {
  ModelStore m;
  char err[1024];
  memset(&m, 0x5a, sizeof m);
  if (model_store_read(dir, program, &m, ERR_OF(err, sizeof err)) == 0)
    fail_msg("read succeeded, expected \"%s\"", want);
  if (strcmp(err, want) != 0) fail_msg("\n   got \"%s\"\n  want \"%s\"", err, want);
  assert_int_equal(m.nmeta, 0);
  assert_int_equal(m.narrays, 0);
  assert_null(m.meta);
  assert_null(m.arrays);
  model_store_free(&m);
}

/* model_store_write(`dir`, `m`) fails with exactly `want`. */
static void expect_write_error(const char *dir, const ModelStore *m, const char *want) {
  char err[1024];
  if (model_store_write(dir, m, ERR_OF(err, sizeof err)) == 0) fail_msg("write succeeded, expected \"%s\"", want);
  if (strcmp(err, want) != 0) fail_msg("\n   got \"%s\"\n  want \"%s\"", err, want);
}

/* ---------------------------------------------------------------- hashing */

/* FNV-1a 64 test vectors (Fowler, Noll, Vo: the reference fnv_test.c). */
static void fnv1a64_vectors(void **state) {
  (void)state;
  assert_int_equal(model_hash_bytes(model_hash_init(), "", 0), UINT64_C(0xcbf29ce484222325));
  assert_int_equal(model_hash_bytes(model_hash_init(), "a", 1), UINT64_C(0xaf63dc4c8601ec8c));
  assert_int_equal(model_hash_bytes(model_hash_init(), "foobar", 6), UINT64_C(0x85944171f73967e8));
  /* in pieces as in one go */
  assert_int_equal(model_hash_bytes(model_hash_bytes(model_hash_init(), "foo", 3), "bar", 3),
                   UINT64_C(0x85944171f73967e8));
}

/* ---------------------------------------------------------------- the store in memory */

static void add_and_find(void **state) {
  (void)state;
  ModelStore m;
  model_store_init(&m);
  static const long shape[] = {2, 2}, neg[] = {2, -1}, nine[9] = {1, 1, 1, 1, 1, 1, 1, 1, 1};
  const double data[4] = {1, 2, 3, 4};
  assert_int_equal(model_store_add(&m, "basis_0", 2, shape, data), 0);
  assert_int_equal(model_store_add(&m, "Tensor-1.v2", 2, shape, data), 0);
  /* names that are not one plain file, duplicates, bad shapes, no data */
  const char *bad_names[] = {"", ".hidden", ".", "..", "a/b", "a b", "a\nb", "caf\xc3\xa9", "basis_0"};
  for (size_t i = 0; i < sizeof bad_names / sizeof *bad_names; i++)
    if (model_store_add(&m, bad_names[i], 2, shape, data) != -1) fail_msg("name '%s' accepted", bad_names[i]);
  assert_int_equal(model_store_add(&m, "neg", 2, neg, data), -1);
  assert_int_equal(model_store_add(&m, "nine", 9, nine, data), -1);
  assert_int_equal(model_store_add(&m, "nodata", 2, shape, NULL), -1);
  assert_int_equal(m.narrays, 2);
  /* an empty array needs no data; a 0-d one has one element */
  static const long empty[] = {0, 3};
  const double one = 42;
  assert_int_equal(model_store_add(&m, "empty", 2, empty, NULL), 0);
  assert_int_equal(model_store_add(&m, "scalar", 0, NULL, &one), 0);

  /* the data is copied */
  double mutable[4] = {1, 2, 3, 4};
  assert_int_equal(model_store_add(&m, "copied", 2, shape, mutable), 0);
  mutable[0] = 99;
  assert_true(((const double *)model_store_array(&m, "copied")->data)[0] == 1);
  assert_int_equal(model_store_array(&m, "empty")->count, 0);
  assert_int_equal(model_store_array(&m, "scalar")->count, 1);
  assert_null(model_store_array(&m, "nope"));

  assert_int_equal(model_store_meta(&m, "classes %d", 3), 0);
  assert_int_equal(model_store_meta(&m, "class b,e size 4 energy 0.9999"), 0);
  assert_int_equal(model_store_meta(&m, "class c size 2"), 0);
  assert_int_equal(model_store_meta(&m, "flag"), 0);
  const char *bad_meta[] = {"", " lead", "\tlead", "two\nlines", "program 0123456789abcdef", "array x.npy 3 fnv1a64 0",
                            "npg-model 1"};
  for (size_t i = 0; i < sizeof bad_meta / sizeof *bad_meta; i++)
    if (model_store_meta(&m, "%s", bad_meta[i]) != -1) fail_msg("metadata line '%s' accepted", bad_meta[i]);
  assert_int_equal(m.nmeta, 4);
  assert_string_equal(model_store_find(&m, "classes"), "3");
  assert_string_equal(model_store_find(&m, "class"), "b,e size 4 energy 0.9999"); /* the first one */
  assert_string_equal(model_store_find(&m, "flag"), "");
  assert_null(model_store_find(&m, "clas"));
  assert_null(model_store_find(&m, "size"));
  model_store_free(&m);
  assert_int_equal(m.narrays, 0);
  model_store_free(&m); /* harmless twice */
}

/* ---------------------------------------------------------------- writing and reading */

static void round_trip(void **state) {
  (void)state;
  ModelStore m;
  example_model(&m);
  /* values whose bits a text format would lose */
  static const long shape_c[] = {2, 3}, empty[] = {0, 3};
  const double c[6] = {-0.0, INFINITY, -INFINITY, 4.9406564584124654e-324, 0.1, 1.7976931348623157e308};
  const double scalar = 3.141592653589793;
  assert_int_equal(model_store_add(&m, "c.values", 2, shape_c, c), 0);
  assert_int_equal(model_store_add(&m, "empty", 2, empty, NULL), 0);
  assert_int_equal(model_store_add(&m, "scalar", 0, NULL, &scalar), 0);
  char dir[512], path[1024];
  scratch_path(dir, "round");
  write_ok(dir, &m);
  assert_no_leftovers("round");

  /* the manifest, line for line */
  ModelStore got;
  char err[1024];
  if (model_store_read(dir, PROGRAM, &got, ERR_OF(err, sizeof err)) != 0) fail_msg("%s", err);
  assert_same_model(&got, &m);
  assert_string_equal(model_store_find(&got, "energy"), "0.999");
  size_t n;
  char *manifest = slurp(scratch_path(path, "round/manifest"), &n), expected[2048];
  int o = snprintf(expected, sizeof expected, "npg-model 1\nprogram 0123456789abcdef\nbasis_classes 2\nenergy 0.999\n");
  const char *lines[] = {"a.npy 3x4", "b.npy 5", "c.values.npy 2x3", "empty.npy 0x3", "scalar.npy ()"};
  for (int i = 0; i < got.narrays; i++) {
    /* each checksum is that of the file's bytes */
    char file[1024];
    size_t len;
    snprintf(file, sizeof file, "%s/%s.npy", dir, got.arrays[i].name);
    char *bytes = slurp(file, &len);
    assert_int_equal(got.arrays[i].checksum, model_hash_bytes(model_hash_init(), bytes, len));
    free(bytes);
    o += snprintf(expected + o, sizeof expected - (size_t)o, "array %s fnv1a64 %016llx\n", lines[i],
                  (unsigned long long)got.arrays[i].checksum);
  }
  snprintf(expected + o, sizeof expected - (size_t)o, "manifest fnv1a64 %016llx\n",
           (unsigned long long)model_hash_bytes(model_hash_init(), expected, strlen(expected)));
  assert_string_equal(manifest, expected);
  free(manifest);
  model_store_free(&got);

  /* each array is a plain .npy numpy reads */
  NpyArray a;
  if (npy_read(scratch_path(path, "round/c.values.npy"), &a, err, sizeof err) != 0) fail_msg("%s", err);
  assert_memory_equal(a.data, c, sizeof c);
  npy_free(&a);

  /* trailing slashes name the same directory */
  scratch_path(dir, "round//");
  expect_model(dir, &m);
  write_ok(dir, &m);
  assert_no_leftovers("round");
  expect_model(scratch_path(dir, "round"), &m);
  model_store_free(&m);
}

static void write_replaces_model(void **state) {
  (void)state;
  ModelStore first, second;
  example_model(&first);
  model_store_init(&second);
  second.program_hash = PROGRAM;
  static const long shape[] = {2};
  const double c[2] = {7, 8};
  assert_int_equal(model_store_meta(&second, "energy 0.5"), 0);
  assert_int_equal(model_store_add(&second, "c", 1, shape, c), 0);
  char dir[512], path[1024];
  scratch_path(dir, "replace");
  write_ok(dir, &first);
  write_ok(dir, &second);
  expect_model(dir, &second);
  /* nothing of the first model is left */
  assert_false(exists(scratch_path(path, "replace/a.npy")));
  assert_false(exists(scratch_path(path, "replace/b.npy")));
  assert_true(exists(scratch_path(path, "replace/c.npy")));
  assert_no_leftovers("replace");
  /* and back: a model replaces an empty directory too */
  write_ok(dir, &first);
  expect_model(dir, &first);
  mkdir(scratch_path(path, "empty_dir"), 0777);
  write_ok(path, &first);
  expect_model(path, &first);
  assert_no_leftovers("empty_dir");
  model_store_free(&first);
  model_store_free(&second);
}

/* What a training killed at any moment leaves beside a model is removed by the next write: a
 * temporary folder with the marker and some files (killed while it removed them: the marker goes
 * last), an empty one (killed between its mkdir and its marker); a folder of a dead process's name
 * without the marker holding a file is someone's, and stays. */
static void dead_leftovers(void **state) {
  (void)state;
  ModelStore m;
  example_model(&m);
  char dir[512], tmp[1024], old[1100], path[1200];
  scratch_path(dir, "dead");
  write_ok(dir, &m);
  pid_t child = fork();
  if (child == 0) _exit(0);
  assert_true(child > 0 && waitpid(child, NULL, 0) == child); /* its pid is no process now */
  snprintf(tmp, sizeof tmp, "%s.tmp.%ld", dir, (long)child);
  snprintf(old, sizeof old, "%s.old.%ld", dir, (long)child);
  assert_int_equal(mkdir(tmp, 0777), 0);
  write_ok(dir, &m);
  assert_false(exists(tmp));
  assert_int_equal(mkdir(tmp, 0777), 0);
  snprintf(path, sizeof path, "%s/npg-model-store-leftover", tmp);
  FILE *f = fopen(path, "w");
  assert_non_null(f);
  fclose(f);
  snprintf(path, sizeof path, "%s/a.npy", tmp);
  assert_non_null(f = fopen(path, "w"));
  fclose(f);
  write_ok(dir, &m);
  assert_false(exists(tmp));
  assert_int_equal(mkdir(old, 0777), 0);
  snprintf(path, sizeof path, "%s/notes.txt", old);
  assert_non_null(f = fopen(path, "w"));
  fclose(f);
  write_ok(dir, &m);
  assert_true(exists(path));
  expect_model(dir, &m);
  model_store_free(&m);
}

/* Every failed write leaves the previous model in "<scratch>/keep" whole and
 * no temporary directory behind. */
static void failed_write_keeps_model(void **state) {
  (void)state;
  ModelStore m, bad;
  example_model(&m);
  char dir[512], path[1024], want[2048];
  scratch_path(dir, "keep");
  write_ok(dir, &m);
  long pid = (long)getpid();

  /* refused before anything is written: a name add would not take */
  example_model(&bad);
  free(bad.arrays[1].name);
  bad.arrays[1].name = strdup("sub/b");
  snprintf(want, sizeof want, "%s: array name 'sub/b' is not a file stem of [A-Za-z0-9_.-] not starting with '.'", dir);
  expect_write_error(dir, &bad, want);
  expect_model(dir, &m);
  assert_no_leftovers("keep");
  model_store_free(&bad);

  /* failing half way: the second array's file name is too long for the
   * file system, once the first array is already written */
  example_model(&bad);
  char long_name[301];
  memset(long_name, 'x', 300);
  long_name[300] = '\0';
  static const long shape[] = {1};
  const double one = 1;
  assert_int_equal(model_store_add(&bad, long_name, 1, shape, &one), 0);
  snprintf(want, sizeof want, "%s.tmp.%ld/%s.npy: cannot create %s.tmp.%ld/%s.npy.tmp.%ld: File name too long", dir,
           pid, long_name, dir, pid, long_name, pid);
  expect_write_error(dir, &bad, want);
  expect_model(dir, &m);
  assert_no_leftovers("keep");
  model_store_free(&bad);

  /* a stale temporary directory of our pid that holds something of the
   * user's is not removed, and nothing is written */
  char stale[600];
  snprintf(stale, sizeof stale, "%s.tmp.%ld", dir, pid);
  assert_int_equal(mkdir(stale, 0777), 0);
  snprintf(path, sizeof path, "%s/notes.txt", stale);
  write_file(path, "mine\n", 5);
  snprintf(want, sizeof want,
           "%s: is in the way and was not made by npg (it has no npg-model-store-leftover marker): refusing to remove "
           "it; move it elsewhere", stale);
  expect_write_error(dir, &m, want);
  expect_model(dir, &m);
  assert_true(exists(path));
  /* nor with the marker of a model store's leftover beside the user's file */
  char marker[700];
  snprintf(marker, sizeof marker, "%s/npg-model-store-leftover", stale);
  write_file(marker, "made by npg\n", 12);
  snprintf(want, sizeof want, "%s: holds 'notes.txt', which a model store never writes: refusing to remove it", stale);
  expect_write_error(dir, &m, want);
  expect_model(dir, &m);
  assert_true(exists(path));
  unlink(path);
  /* one holding only model files and the marker is removed */
  snprintf(path, sizeof path, "%s/a.npy.tmp.12345", stale);
  write_file(path, "partial", 7);
  write_ok(dir, &m);
  assert_no_leftovers("keep");

  /* the parent cannot take the temporary directory (root writes anywhere,
   * so only an ordinary user can see this one) */
  if (geteuid() != 0) {
    char ro[512], inner[600];
    scratch_path(ro, "readonly");
    assert_int_equal(mkdir(ro, 0777), 0);
    snprintf(inner, sizeof inner, "%s/model", ro);
    write_ok(inner, &m);
    chmod(ro, 0555);
    snprintf(want, sizeof want, "%s: cannot create the model's temporary directory %s.tmp.%ld: Permission denied",
             inner, inner, pid);
    expect_write_error(inner, &m, want);
    chmod(ro, 0755);
    expect_model(inner, &m);
  }
  /* the parent is not a directory */
  snprintf(path, sizeof path, "%s/keep/manifest/model", scratch);
  snprintf(want, sizeof want, "%s: cannot examine: Not a directory", path);
  expect_write_error(path, &m, want);
  expect_model(dir, &m);
  model_store_free(&m);
}

/* A directory that is not a model is never replaced, whatever it holds. */
static void refuse_to_replace(void **state) {
  (void)state;
  ModelStore m;
  example_model(&m);
  char dir[512], path[1024], want[2048];

  scratch_path(dir, "user_files");
  assert_int_equal(mkdir(dir, 0777), 0);
  write_ok(dir, &m);
  snprintf(path, sizeof path, "%s/README", dir);
  write_file(path, "notes\n", 6);
  snprintf(want, sizeof want, "%s: holds 'README', which a model store never writes: refusing to replace it", dir);
  expect_write_error(dir, &m, want);
  assert_true(exists(path));
  expect_model(dir, &m);
  unlink(path);

  /* a subdirectory, even with a model file's name */
  snprintf(path, sizeof path, "%s/sub.npy", dir);
  assert_int_equal(mkdir(path, 0777), 0);
  snprintf(want, sizeof want, "%s: holds 'sub.npy', which a model store never writes: refusing to replace it", dir);
  expect_write_error(dir, &m, want);
  rmdir(path);

  /* .npy files without a model manifest: someone's DATA/, not a model */
  scratch_path(dir, "data");
  assert_int_equal(mkdir(dir, 0777), 0);
  snprintf(path, sizeof path, "%s/x.npy", dir);
  static const long shape[] = {1};
  const double one = 1;
  assert_int_equal(npy_write(path, NPY_F64, 1, shape, &one, NULL, 0), 0);
  snprintf(want, sizeof want, "%s: exists and is not a model (it has no model manifest): refusing to replace it", dir);
  expect_write_error(dir, &m, want);
  assert_true(exists(path));

  /* a file, and a symbolic link to a model */
  scratch_path(path, "plain_file");
  write_file(path, "x", 1);
  snprintf(want, sizeof want, "%s: exists and is not a directory: refusing to replace it", path);
  expect_write_error(path, &m, want);
  scratch_path(path, "link");
  assert_int_equal(symlink(scratch_path(dir, "user_files"), path), 0);
  snprintf(want, sizeof want, "%s: is a symbolic link: refusing to replace it (give the directory it points to)",
           path);
  expect_write_error(path, &m, want);
  expect_model(dir, &m);
  assert_no_leftovers("user_files");
  assert_no_leftovers("data");
  assert_no_leftovers("link");
  model_store_free(&m);
}

/* ---------------------------------------------------------------- reading errors */

/* A fresh example model in "<scratch>/<name>", its path in `dir`. */
/* model_store_read(`dir`) succeeds. */
static void expect_model_ok(const char *dir) {
  ModelStore m;
  char err[1024];
  if (model_store_read(dir, PROGRAM, &m, ERR_OF(err, sizeof err)) != 0) fail_msg("%s", err);
  model_store_free(&m);
}

static void fresh_model(char *dir, const char *name) {
  ModelStore m;
  example_model(&m);
  scratch_path(dir, name);
  write_ok(dir, &m);
  model_store_free(&m);
}

static void read_errors(void **state) {
  (void)state;
  char dir[512], path[1024], want[2048];

  /* no manifest, or no directory at all */
  scratch_path(dir, "no_manifest");
  assert_int_equal(mkdir(dir, 0777), 0);
  snprintf(want, sizeof want, "%s/manifest: cannot open: " ENOENT_TEXT, dir);
  expect_read_error(dir, PROGRAM, want);
  scratch_path(dir, "no_such_dir");
  snprintf(want, sizeof want, "%s/manifest: cannot open: " ENOENT_TEXT, dir);
  expect_read_error(dir, PROGRAM, want);

  /* not a manifest, or one of another format version */
  fresh_model(dir, "bad_first");
  snprintf(path, sizeof path, "%s/manifest", dir);
  edit_file(path, "npg-model 1", "hello");
  snprintf(want, sizeof want, "%s:1: not a model manifest: first line is 'hello', expected 'npg-model 1'", path);
  expect_read_error(dir, PROGRAM, want);
  edit_file(path, "hello", "npg-model 4");
  snprintf(want, sizeof want,
           "%s:1: model format 'npg-model 4' is not supported (this npgc reads 'npg-model 1' to 'npg-model 3': a "
           "newer npgc wrote it?)",
           path);
  expect_read_error(dir, PROGRAM, want);
  write_file(path, "", 0);
  snprintf(want, sizeof want, "%s:1: empty file: not a model manifest (expected 'npg-model 1')", path);
  expect_read_error(dir, PROGRAM, want);

  /* trained for another program */
  fresh_model(dir, "other_program");
  snprintf(want, sizeof want,
           "%s/manifest: model was trained for another program (program hash 0123456789abcdef, this program "
           "00000000000000ff): retrain",
           dir);
  expect_read_error(dir, 0xff, want);

  /* one byte of an array flipped */
  fresh_model(dir, "flipped");
  snprintf(path, sizeof path, "%s/a.npy", dir);
  size_t n;
  char *bytes = slurp(path, &n);
  bytes[n - 3] ^= 0x01;
  write_file(path, bytes, n);
  snprintf(want, sizeof want, "%s: checksum mismatch: the file is corrupted or was changed after training", path);
  expect_read_error(dir, PROGRAM, want);

  /* cut short */
  fresh_model(dir, "truncated");
  snprintf(path, sizeof path, "%s/b.npy", dir);
  write_file(path, bytes, n - 8); /* a.npy's bytes, minus its last element */
  free(bytes);
  snprintf(want, sizeof want, "%s: checksum mismatch: the file is corrupted or was changed after training", path);
  expect_read_error(dir, PROGRAM, want);

  /* missing */
  fresh_model(dir, "missing");
  snprintf(path, sizeof path, "%s/b.npy", dir);
  unlink(path);
  snprintf(want, sizeof want, "%s: cannot open: " ENOENT_TEXT, path);
  expect_read_error(dir, PROGRAM, want);

  /* the manifest's shape is not the file's (its checksum still matches) */
  fresh_model(dir, "shape");
  snprintf(path, sizeof path, "%s/manifest", dir);
  edit_file(path, " 3x4 ", " 4x3 ");
  snprintf(want, sizeof want, "%s/a.npy: shape 3x4, manifest says 4x3", dir);
  expect_read_error(dir, PROGRAM, want);
  edit_file(path, " 4x3 ", " 12 ");
  snprintf(want, sizeof want, "%s/a.npy: shape 3x4, manifest says 12", dir);
  expect_read_error(dir, PROGRAM, want);

  /* a well-hashed file that is not float64, and one npy_read refuses: its
   * message, which names the file, is passed through */
  fresh_model(dir, "int64");
  snprintf(path, sizeof path, "%s/b.npy", dir);
  char manifest[1024];
  snprintf(manifest, sizeof manifest, "%s/manifest", dir);
  static const long shape[] = {5};
  const int64_t ints[5] = {1, 2, 3, 4, 5};
  char good_hex[32], new_hex[32];
  snprintf(good_hex, sizeof good_hex, "%016llx", (unsigned long long)file_hash(path));
  assert_int_equal(npy_write(path, NPY_I64, 1, shape, ints, NULL, 0), 0);
  snprintf(new_hex, sizeof new_hex, "%016llx", (unsigned long long)file_hash(path));
  edit_file(manifest, good_hex, new_hex);
  snprintf(want, sizeof want, "%s: holds int64 elements; a model holds float64", path);
  expect_read_error(dir, PROGRAM, want);
  write_file(path, "not npy", 7);
  snprintf(good_hex, sizeof good_hex, "%016llx", (unsigned long long)file_hash(path));
  edit_file(manifest, new_hex, good_hex);
  snprintf(want, sizeof want, "%s: not a .npy file (bad magic)", path);
  expect_read_error(dir, PROGRAM, want);
}

/* Each manifest line that is wrong is named with its line number. The
 * example model's manifest is:
 *   1 npg-model 1
 *   2 program 0123456789abcdef
 *   3 basis_classes 2
 *   4 energy 0.999
 *   5 array a.npy 3x4 fnv1a64 <hex>
 *   6 array b.npy 5 fnv1a64 <hex> */
static void malformed_manifest_lines(void **state) {
  (void)state;
  static const struct {
    const char *from, *to; /* the edit */
    const char *problem;   /* after "<dir>/manifest" */
  } cases[] = {
      {"program 0123456789abcdef", "program 0123456789abcdeg", ":2: expected 'program <16 hex digits>'"},
      {"program 0123456789abcdef", "program 123456789abcdef", ":2: expected 'program <16 hex digits>'"},
      {"program 0123456789abcdef", "program  0123456789abcdef", ":2: expected 'program <16 hex digits>'"},
      {"program 0123456789abcdef", "program 0123456789abcdef x", ":2: expected 'program <16 hex digits>'"},
      {"program 0123456789abcdef\n", "", ": no 'program' line"},
      {"basis_classes 2", "program 0123456789abcdef", ":3: second 'program' line (the first is line 2)"},
      {"basis_classes 2", "npg-model 1", ":3: 'npg-model' may only be the first line"},
      {"basis_classes 2", "", ":3: empty line"},
      {"basis_classes 2", " basis_classes 2", ":3: line starts with a space (expected 'key value...')"},
      {"basis_classes 2", "basis_classes 2\0", ":3: line holds a NUL byte"},
      {"array a.npy 3x4 fnv1a64", "array a.npy 3x4  fnv1a64",
       ":5: expected 'array <name>.npy <shape> fnv1a64 <16 hex digits>'"},
      {"array a.npy 3x4 fnv1a64", "array a.npy 3x4",
       ":5: expected 'array <name>.npy <shape> fnv1a64 <16 hex digits>'"},
      {"array a.npy", "array a.txt", ":5: array file 'a.txt' does not end in .npy"},
      {"array a.npy", "array .a.npy", ":5: bad array name '.a'"},
      {"array a.npy", "array ../a.npy", ":5: bad array name '../a'"},
      {"array a.npy 3x4", "array a.npy 3x", ":5: bad shape '3x' (expected sizes joined by 'x', like 3x4)"},
      {"array a.npy 3x4", "array a.npy -3x4", ":5: bad shape '-3x4' (expected sizes joined by 'x', like 3x4)"},
      {"array a.npy 3x4", "array a.npy 1x1x1x1x1x1x1x1x1",
       ":5: bad shape '1x1x1x1x1x1x1x1x1' (expected sizes joined by 'x', like 3x4)"},
      {"array a.npy 3x4", "array a.npy 99999999999999999999x4",
       ":5: bad shape '99999999999999999999x4' (expected sizes joined by 'x', like 3x4)"},
      {"3x4 fnv1a64", "3x4 md5", ":5: unknown checksum kind 'md5' (expected fnv1a64)"},
      {"array b.npy", "array a.npy", ":6: array a.npy listed twice (first on line 5)"},
  };
  char dir[512], path[1024], want[2048];
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    char name[64];
    snprintf(name, sizeof name, "malformed_%zu", i);
    fresh_model(dir, name);
    snprintf(path, sizeof path, "%s/manifest", dir);
    /* "\0" in `to` stands for a NUL byte written into the file */
    size_t n;
    char *text = slurp(path, &n);
    char *at = strstr(text, cases[i].from);
    assert_non_null(at);
    size_t before = (size_t)(at - text), flen = strlen(cases[i].from), tlen = strlen(cases[i].to);
    int nul = strcmp(cases[i].problem, ":3: line holds a NUL byte") == 0;
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    fwrite(text, 1, before, f);
    fwrite(cases[i].to, 1, tlen, f);
    if (nul) fputc('\0', f);
    fwrite(at + flen, 1, n - before - flen, f);
    fclose(f);
    free(text);
    snprintf(want, sizeof want, "%s%s", path, cases[i].problem);
    expect_read_error(dir, PROGRAM, want);
  }

  /* a bad checksum field, and a manifest cut in its last line */
  fresh_model(dir, "malformed_hex");
  snprintf(path, sizeof path, "%s/manifest", dir);
  size_t n;
  char *text = slurp(path, &n);
  size_t end6 = (size_t)(strstr(text, "\nmanifest ") - text); /* line 6 ends here */
  char digit = text[end6 - 1];
  text[end6 - 1] = 'z';
  write_file(path, text, n);
  snprintf(want, sizeof want, "%s:6: bad checksum '%.15sz' (expected 16 hex digits)", path, text + end6 - 16);
  expect_read_error(dir, PROGRAM, want);
  text[end6 - 1] = digit;
  write_file(path, text, n - 1);
  snprintf(want, sizeof want, "%s:7: last line has no newline: the file was cut short?", path);
  expect_read_error(dir, PROGRAM, want);
  free(text);

  /* the manifest's own checksum: a line added, changed or removed is caught
   * (a forged 'spd' line would make the reduced solve use Cholesky on a
   * non-symmetric operator), and so is a missing or misplaced checksum line */
  fresh_model(dir, "manifest_sum");
  snprintf(path, sizeof path, "%s/manifest", dir);
  edit_file(path, "energy 0.999\n", "energy 0.999\nspd b 0 0\n");
  snprintf(want, sizeof want, "%s:8: checksum mismatch: the manifest was changed after training", path);
  expect_read_error(dir, PROGRAM, want);
  reseal(path);
  expect_model_ok(dir);
  edit_file(path, "basis_classes 2\n", "");
  snprintf(want, sizeof want, "%s:7: checksum mismatch: the manifest was changed after training", path);
  expect_read_error(dir, PROGRAM, want);
  text = slurp(path, &n);
  write_file(path, text, (size_t)(strstr(text, "\nmanifest ") - text) + 1);
  snprintf(want, sizeof want, "%s: no 'manifest' checksum line: cut short, or written by an older npg (retrain)", path);
  expect_read_error(dir, PROGRAM, want);
  free(text);
  fresh_model(dir, "manifest_sum2");
  snprintf(path, sizeof path, "%s/manifest", dir);
  edit_file(path, "basis_classes 2\n", "manifest fnv1a64 0000000000000000\n");
  snprintf(want, sizeof want, "%s:3: the 'manifest' checksum line must be the last", path);
  expect_read_error(dir, PROGRAM, want);
}

/* Unknown metadata lines come back verbatim and in order. */
static void metadata_verbatim(void **state) {
  (void)state;
  char dir[512], path[1024];
  fresh_model(dir, "verbatim");
  snprintf(path, sizeof path, "%s/manifest", dir);
  edit_file(path, "energy 0.999\n", "energy 0.999\nnote  two  spaces, tab\there\n");
  reseal(path);
  ModelStore m;
  char err[1024];
  if (model_store_read(dir, PROGRAM, &m, ERR_OF(err, sizeof err)) != 0) fail_msg("%s", err);
  assert_int_equal(m.nmeta, 3);
  assert_string_equal(m.meta[0], "basis_classes 2");
  assert_string_equal(m.meta[2], "note  two  spaces, tab\there");
  assert_string_equal(model_store_find(&m, "note"), "two  spaces, tab\there");
  model_store_free(&m);
}

/* Messages are cut to the buffer, and no buffer at all is fine. */
static void small_error_buffers(void **state) {
  (void)state;
  char dir[512], err[8];
  ModelStore m;
  scratch_path(dir, "nowhere");
  memset(err, 'x', sizeof err);
  assert_int_equal(model_store_read(dir, PROGRAM, &m, ERR_OF(err, sizeof err)), -1);
  assert_int_equal(strlen(err), sizeof err - 1);
  assert_int_equal(model_store_read(dir, PROGRAM, &m, NULL), -1);
  ModelStore bad;
  example_model(&bad);
  free(bad.arrays[0].name);
  bad.arrays[0].name = strdup("..");
  assert_int_equal(model_store_write(dir, &bad, ERR_OF(err, sizeof err)), -1);
  assert_int_equal(model_store_write(dir, &bad, NULL), -1);
  model_store_free(&bad);
  assert_false(exists(dir));
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(fnv1a64_vectors),
      cmocka_unit_test(add_and_find),
      cmocka_unit_test(round_trip),
      cmocka_unit_test(write_replaces_model),
      cmocka_unit_test(dead_leftovers),
      cmocka_unit_test(failed_write_keeps_model),
      cmocka_unit_test(refuse_to_replace),
      cmocka_unit_test(read_errors),
      cmocka_unit_test(malformed_manifest_lines),
      cmocka_unit_test(metadata_verbatim),
      cmocka_unit_test(small_error_buffers),
  };
  return cmocka_run_group_tests(tests, make_scratch, remove_scratch);
}
