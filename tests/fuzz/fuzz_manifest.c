/* fuzz_manifest.c — libFuzzer target for the model manifest parser
 * (backends/model/model_store.c model_store_read) and what loads a model on top
 * of it (npg_model_load, then a reduced evaluation).
 *
 * Each input becomes the `manifest` of a per-process model folder under
 * /dev/shm that holds valid arrays: those of the model in $NPG_FUZZ_MODEL
 * (scripts/test.sh trains examples/rational/rational.npg into it and seeds
 * the corpus with its manifest), else two small arrays of its own. The
 * program is $NPG_FUZZ_PROGRAM (default examples/rational/rational.npg,
 * from the repository root), so a manifest naming its hash goes all the way
 * through loading.
 *
 * Checked on every input, as model_store.h promises: a failed read leaves
 * the store empty and a message naming a file of the folder; a manifest
 * that reads writes back (model_store_write) and reads back to the same
 * lines and arrays; loading and evaluating never crash, and fail with a
 * message or succeed without one.
 */
#define _GNU_SOURCE

#include <dirent.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "compile.h"
#include "model_store.h"
#include "npg.h"
#include "model.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static char dir[128], copy_dir[160], manifest[200];
static NpgProgram *program;
static uint64_t program_hash;

static void check(int ok, const char *what) {
  if (!ok) {
    fprintf(stderr, "model_store.h contract broken: %s\n", what);
    abort();
  }
}

/* Remove a folder of plain files. */
static void remove_dir(const char *path) {
  DIR *d = opendir(path);
  if (!d) return;
  struct dirent *e;
  char file[512];
  while ((e = readdir(d)))
    if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
      snprintf(file, sizeof file, "%s/%s", path, e->d_name);
      unlink(file);
    }
  closedir(d);
  rmdir(path);
}

static void cleanup(void) {
  remove_dir(dir);
  remove_dir(copy_dir);
  npg_free(program);
}

/* Copy every .npy of `from` into `to`; the number copied. */
static int copy_arrays(const char *from, const char *to) {
  DIR *d = opendir(from);
  if (!d) return 0;
  int n = 0;
  struct dirent *e;
  while ((e = readdir(d))) {
    size_t len = strlen(e->d_name);
    if (len < 5 || strcmp(e->d_name + len - 4, ".npy") != 0) continue;
    char src[512], dst[512], buf[1 << 16];
    snprintf(src, sizeof src, "%s/%s", from, e->d_name);
    snprintf(dst, sizeof dst, "%s/%s", to, e->d_name);
    FILE *in = fopen(src, "rb"), *out = fopen(dst, "wb");
    if (!in || !out) abort();
    size_t got;
    while ((got = fread(buf, 1, sizeof buf, in)) > 0) fwrite(buf, 1, got, out);
    fclose(in);
    if (fclose(out) != 0) abort();
    n++;
  }
  closedir(d);
  return n;
}

static void setup(void) {
  snprintf(dir, sizeof dir, "/dev/shm/npg_fuzz_manifest.%ld", (long)getpid());
  snprintf(copy_dir, sizeof copy_dir, "%s.copy", dir);
  snprintf(manifest, sizeof manifest, "%s/manifest", dir);
  remove_dir(dir);
  remove_dir(copy_dir);
  if (mkdir(dir, 0700) != 0) abort();
  atexit(cleanup);
  const char *prog = getenv("NPG_FUZZ_PROGRAM");
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  program = npg_compile(prog && *prog ? prog : "examples/rational/rational.npg", &opt);
  if (!npg_ok(program)) {
    fprintf(stderr, "fuzz_manifest: %s", npg_error(program));
    abort();
  }
  program_hash = model_program_hash(program_ir(program));
  const char *model = getenv("NPG_FUZZ_MODEL");
  if (!model || !*model || copy_arrays(model, dir) == 0) { /* two small arrays of our own */
    double v[6] = {1, 2, 3, 4, 5, 6};
    long s23[2] = {2, 3}, s3[1] = {3};
    char path[256], err[256];
    snprintf(path, sizeof path, "%s/a.npy", dir);
    if (npy_write(path, NPY_F64, 2, s23, v, err, sizeof err)) abort();
    snprintf(path, sizeof path, "%s/b.npy", dir);
    if (npy_write(path, NPY_F64, 1, s3, v, err, sizeof err)) abort();
  }
}

static int same_store(const ModelStore *a, const ModelStore *b) {
  if (a->program_hash != b->program_hash || a->nmeta != b->nmeta || a->narrays != b->narrays) return 0;
  for (int i = 0; i < a->nmeta; i++)
    if (strcmp(a->meta[i], b->meta[i]) != 0) return 0;
  for (int i = 0; i < a->narrays; i++) {
    const NpyArray *x = &a->arrays[i].a, *y = &b->arrays[i].a;
    if (strcmp(a->arrays[i].name, b->arrays[i].name) != 0 || x->ndim != y->ndim || x->count != y->count ||
        memcmp(x->shape, y->shape, sizeof x->shape[0] * (size_t)x->ndim) != 0 ||
        memcmp(x->data, y->data, sizeof(double) * x->count) != 0)
      return 0;
  }
  return 1;
}

/* Load the folder as a model of the program and evaluate it once, as npgc
 * eval would: a damaged model must fail with a message, never crash. */
static void load_and_evaluate(void) {
  NpgModel *m = npg_model_load(program, dir);
  int loaded = npg_model_error(m)[0] == '\0';
  if (loaded) {
    NpgReduced *r = npg_reduced_new(m);
    if (r && !npg_reduced_error(r)[0]) {
      double x[2] = {1.5, 0.75};
      npg_reduced_set(r, "x", 2, x);
      if (npg_reduced_eval(r, 0) != 0) check(npg_reduced_error(r)[0] != '\0', "a failed evaluation says why");
    }
    npg_reduced_free(r);
  }
  npg_model_free(m);
}

/* The manifest `data` of `size` bytes, read, written back and loaded. */
static void one_manifest(const uint8_t *data, size_t size) {
  int fd = open(manifest, O_WRONLY | O_CREAT | O_TRUNC, 0600);
  if (fd < 0 || write(fd, data, size) != (ssize_t)size || close(fd) != 0) abort();

  ModelStore m;
  char err[1024];
  if (model_store_read(dir, program_hash, &m, ERR_OF(err, sizeof err)) != 0) {
    check(m.nmeta == 0 && m.narrays == 0 && m.meta == NULL && m.arrays == NULL, "a failed read leaves it empty");
    check(strncmp(err, dir, strlen(dir)) == 0, "a failure names a file of the folder");
    return;
  }
  check(err[0] == '\0', "a successful read leaves no message");
  /* a manifest that reads writes back, and reads back the same */
  ModelStore back;
  check(model_store_write(copy_dir, &m, ERR_OF(err, sizeof err)) == 0, "what was read writes back");
  check(model_store_read(copy_dir, program_hash, &back, ERR_OF(err, sizeof err)) == 0, "what was written reads back");
  check(same_store(&m, &back), "what reads back is what was read");
  model_store_free(&back);
  model_store_free(&m);
  load_and_evaluate();
}

/* Each input twice: as it is, and sealed as a forger would seal it — its
 * last line replaced by the checksum of the lines before it — so that
 * mutations reach what lies behind the manifest's own checksum. */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (!program) setup();
  one_manifest(data, size);
  size_t body = size;
  while (body > 0 && data[body - 1] == '\n') body--;
  while (body > 0 && data[body - 1] != '\n') body--;
  if (body == 0) body = size; /* one line (or none): all of it is the body */
  uint8_t *sealed = malloc(body + 64);
  if (!sealed) abort();
  memcpy(sealed, data, body);
  if (body > 0 && sealed[body - 1] != '\n') sealed[body++] = '\n';
  char seal[64];
  int n = snprintf(seal, sizeof seal, "manifest fnv1a64 %016llx\n",
                   (unsigned long long)model_hash_bytes(model_hash_init(), sealed, body));
  memcpy(sealed + body, seal, (size_t)n);
  one_manifest(sealed, body + (size_t)n);
  free(sealed);
  return 0;
}
