/* test_api.c — the whole pipeline through npg.h alone (compiled with only
 * include/ on its include path): compile, train from memory, load, reduced
 * evaluation, lifting, operators, verification; streamed training equal to
 * `npgc train`; an extern by callback equal to the extern as data; one
 * model shared by two threads; a basis in an inner product (npg_model_dual).
 *
 *     test_api NPGC RADIOSITY_DATA   (paths of the two programs, from CMake)
 */
#include <dirent.h>
#include <math.h>
#include <pthread.h>
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

static const char *npgc_path, *radiosity_data_path;
static char scratch[256];

static void run(const char *fmt, ...) {
  char cmd[4096];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(cmd, sizeof cmd, fmt, ap);
  va_end(ap);
  int rc = system(cmd);
  if (rc != 0) fprintf(stderr, "command failed (%d): %s\n", rc, cmd);
  assert_int_equal(rc, 0);
}

static NpgProgram *compile(const char *path) {
  NpgProgram *p = npg_compile(path, NULL);
  if (!npg_ok(p)) fputs(npg_error(p), stderr);
  assert_true(npg_ok(p));
  return p;
}

/* Every .npy of A is byte-identical in B (and the manifests list the same
 * files): the models are the same to the last bit. */
static void assert_same_model(const char *a, const char *b) {
  DIR *d = opendir(a);
  assert_non_null(d);
  struct dirent *e;
  int files = 0;
  while ((e = readdir(d))) {
    size_t n = strlen(e->d_name);
    if (n < 5 || strcmp(e->d_name + n - 4, ".npy") != 0) continue;
    char pa[1024], pb[1024];
    snprintf(pa, sizeof pa, "%s/%s", a, e->d_name);
    snprintf(pb, sizeof pb, "%s/%s", b, e->d_name);
    FILE *fa = fopen(pa, "rb"), *fb = fopen(pb, "rb");
    assert_non_null(fa);
    if (!fb) fail_msg("%s is missing", pb);
    int ca, cb;
    do {
      ca = fgetc(fa);
      cb = fgetc(fb);
      if (ca != cb) fail_msg("%s and %s differ", pa, pb);
    } while (ca != EOF);
    fclose(fa);
    fclose(fb);
    files++;
  }
  closedir(d);
  assert_true(files >= 2);
}

/* The float64 payload of a .npy file (version 1 header), *count entries. */
static double *npy_payload(const char *path, long *count) {
  FILE *fp = fopen(path, "rb");
  if (!fp) fail_msg("cannot open %s", path);
  unsigned char head[10];
  assert_int_equal(fread(head, 1, 10, fp), 10);
  long hlen = head[8] | head[9] << 8;
  fseek(fp, 0, SEEK_END);
  long bytes = ftell(fp) - 10 - hlen;
  fseek(fp, 10 + hlen, SEEK_SET);
  double *v = malloc((size_t)bytes + 8);
  assert_int_equal(fread(v, 1, (size_t)bytes, fp), (size_t)bytes);
  fclose(fp);
  *count = bytes / 8;
  return v;
}

/* ---------------------------------------------------------------- Eq. 3 */

static double *random_x(long S, unsigned seed) {
  double *x = malloc(sizeof(double) * (size_t)(2 * S));
  srand(seed);
  for (long k = 0; k < 2 * S; k++) x[k] = 0.5 + (double)rand() / RAND_MAX;
  return x;
}

static void eq3_pipeline(void **state) {
  (void)state;
  NpgProgram *p = compile("examples/rational/rational.npg");
  const long S = 60, shape[1] = {2};
  double *x = random_x(S, 7);
  /* the same samples on disk, for npgc train */
  char data[512], stream[512], cli[512], err[1024];
  snprintf(data, sizeof data, "%s/EQ3DATA", scratch);
  snprintf(stream, sizeof stream, "%s/EQ3STREAM", scratch);
  snprintf(cli, sizeof cli, "%s/EQ3CLI", scratch);
  run("mkdir -p %s", data);
  char path[1024];
  snprintf(path, sizeof path, "%s/x.npy", data);
  long xs[2] = {S, 2};
  assert_int_equal(npg_npy_write(path, 2, xs, x, err, sizeof err), 0);
  run("%s train examples/rational/rational.npg %s -o %s >/dev/null", npgc_path, data, cli);

  /* streamed: the simulation sets x, evaluates, hands the values over */
  NpgFull *f = npg_full_new(p, NPG_TCC);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  NpgTrainer *t = npg_trainer_new(f, &o);
  for (long k = 0; k < S; k++) {
    assert_int_equal(npg_full_set(f, "x", 1, shape, x + 2 * k, "sim"), 0);
    assert_int_equal(npg_full_eval(f, k), 0);
    assert_int_equal(npg_trainer_add_full(t, f), 0);
  }
  assert_int_equal(npg_trainer_samples(t), S);
  NpgModel *m = npg_trainer_finish(t, stream);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
  assert_same_model(stream, cli);

  /* query */
  int cy = npg_model_class_of(m, "y");
  assert_true(cy >= 0);
  NpgClassInfo ci;
  assert_int_equal(npg_model_class(m, cy, &ci), 0);
  assert_int_equal(ci.n, 2);
  assert_true(ci.nmembers >= 2); /* y and its numerator */
  NpgMemberInfo mi;
  assert_int_equal(npg_model_member(m, cy, 0, &mi), 0);
  assert_true(mi.kept >= 1 && mi.captured > 0.99);
  assert_true(npg_model_bytes(m, NULL) > 0);
  assert_int_equal(npg_model_samples(m), S);
  assert_int_equal(npg_model_class_of(m, "nosuch"), -1);

  /* a loaded model evaluates like the one in memory */
  NpgModel *loaded = npg_model_load(p, stream);
  assert_string_equal(npg_model_error(loaded), "");
  NpgReduced *r = npg_reduced_new(m), *r2 = npg_reduced_new(loaded);
  double held[2] = {1.3, 0.7}, y[2], y2[2];
  assert_int_equal(npg_reduced_set(r, "x", 2, held), 0);
  assert_int_equal(npg_reduced_eval(r, 0), 0);
  assert_int_equal(npg_reduced_lift(r, "y", y, 2), 0);
  /* reduced coordinates given directly */
  size_t mx;
  const double *xh = npg_reduced_coords(r, "x", &mx);
  assert_int_equal(npg_reduced_set_coords(r2, "x", mx, xh), 0);
  assert_int_equal(npg_reduced_eval(r2, 0), 0);
  assert_int_equal(npg_reduced_lift(r2, "y", y2, 2), 0);
  double ref[2] = {(1.3 * 0.7 + 0.7 * 0.7) / (1.3 * 1.3), 1.3 * 1.3 / (0.7 * 0.7)};
  for (int i = 0; i < 2; i++) {
    assert_true(fabs(y[i] - ref[i]) <= 1e-10 * fabs(ref[i])); /* full-rank classes: exact */
    assert_true(y[i] == y2[i]);
  }
  /* errors are reported, not crashes */
  assert_int_equal(npg_reduced_set(r2, "y", 2, held), -1);
  assert_non_null(strstr(npg_reduced_error(r2), "only inputs"));
  npg_reduced_clear_error(r2);
  assert_string_equal(npg_reduced_error(r2), "");
  assert_int_equal(npg_reduced_lift(r2, "x", y2, 3), -1);

  /* verification as a call */
  NpgFull *g = npg_full_new(p, NPG_TCC);
  char test[512];
  snprintf(test, sizeof test, "%s/EQ3TEST", scratch);
  run("mkdir -p %s", test);
  double *xt = random_x(10, 99);
  long ts[2] = {10, 2};
  snprintf(path, sizeof path, "%s/x.npy", test);
  assert_int_equal(npg_npy_write(path, 2, ts, xt, err, sizeof err), 0);
  NpgSamples *s = npg_samples_open(p, test, NULL, true, err, sizeof err);
  assert_non_null(s);
  NpgVerifyReport rep;
  assert_int_equal(npg_verify(m, g, npg_samples_count(s), npg_samples_set, s, false, &rep), 0);
  assert_int_equal(rep.samples, 10);
  bool saw_y = false;
  for (int i = 0; i < rep.nrows; i++)
    if (strcmp(rep.rows[i].name, "y") == 0) {
      saw_y = true;
      assert_true(rep.rows[i].output);
      assert_true(rep.rows[i].l2 < 1e-10);
      assert_true(rep.rows[i].floor <= rep.rows[i].l2 + 1e-15);
    }
  assert_true(saw_y);
  npg_verify_free(&rep);

  npg_samples_free(s);
  free(xt);
  npg_reduced_free(r);
  npg_reduced_free(r2);
  npg_model_free(loaded);
  npg_model_free(m);
  npg_full_free(g);
  npg_full_free(f);
  free(x);
  npg_free(p);
}

/* ---------------------------------------------------------------- radiosity: externs by data and by callback */

typedef struct VisData {
  const NpgSamples *s;
  int calls;
} VisData;

/* The ray caster's stand-in: the visibility of the sample being added. */
static int visibility(void *user, const NpgFull *f, long sample, double *out, size_t count) {
  VisData *v = user;
  size_t n;
  const double *vis = npg_samples_get(v->s, "v", sample, &n);
  if (!vis || n != count) return -1;
  memcpy(out, vis, sizeof(double) * n);
  v->calls++;
  return 0;
}

/* The same, partly hidden: some entries fractional, some -0 (neither a bit). */
static double partly(long k, size_t e, double v) {
  return (e + (size_t)k) % 7 == 0 ? 0.5 * v : (e + (size_t)k) % 11 == 0 ? -0.0 : v;
}

static int visibility_partly(void *user, const NpgFull *f, long sample, double *out, size_t count) {
  if (visibility(user, f, sample, out, count)) return -1;
  for (size_t e = 0; e < count; e++) out[e] = partly(sample, e, out[e]);
  return 0;
}

/* Every sample of s added to t with its g and e staged (v by the evaluator's callback). */
static void add_g_e(NpgTrainer *t, NpgSamples *s, const long *gs, const long *es) {
  for (long k = 0; k < npg_samples_count(s); k++) {
    assert_int_equal(npg_trainer_set(t, "g", 2, gs, npg_samples_get(s, "g", k, NULL)), 0);
    assert_int_equal(npg_trainer_set(t, "e", 1, es, npg_samples_get(s, "e", k, NULL)), 0);
    assert_int_equal(npg_trainer_add(t), 0);
  }
}

static NpgModel *radiosity_model;
static NpgProgram *radiosity_prog;

/* For a model whose v is kept as coefficients C (npg_model_coefficients) and the trainer that made
 * it: the largest difference, relative to the largest |z|, between every training sample's
 * learned-map value z_k (the npy at zpath) and Cᵀ(Xᵀv_k) (npg_trainer_dots), and the largest
 * between X C z_k = Σ_l (C z_k)_l v_l and v_k itself (`vis`: the value the callback gave for
 * the data's v, NULL: the data's). */
static double coefficients_reproduce(const NpgModel *m, NpgTrainer *t, NpgSamples *s, const char *zpath,
                                     double (*vis)(long k, size_t e, double v)) {
  int cv = npg_model_class_of(m, "v");
  NpgClassInfo vi;
  assert_int_equal(npg_model_class(m, cv, &vi), 0);
  assert_null(npg_model_basis(m, cv));
  long S = npg_samples_count(s), cs = 0, zn = 0;
  const double *C = npg_model_coefficients(m, cv, &cs);
  assert_non_null(C);
  assert_int_equal(cs, S);
  double *Z = npy_payload(zpath, &zn);
  assert_int_equal(zn, S * vi.m);
  double *vk = malloc(sizeof(double) * (size_t)vi.n), *dots = malloc(sizeof(double) * (size_t)S);
  double *w = malloc(sizeof(double) * (size_t)S), *lifted = calloc((size_t)vi.n, sizeof(double));
  double zmax = 0, worst_z = 0, worst_v = 0;
  for (long k = 0; k < S * vi.m; k++) zmax = fmax(zmax, fabs(Z[k]));
  for (long k = 0; k < S; k++) {
    const double *data = npg_samples_get(s, "v", k, NULL);
    for (long e = 0; e < vi.n; e++) vk[e] = vis ? vis(k, (size_t)e, data[e]) : data[e];
    if (npg_trainer_dots(t, "v", (size_t)vi.n, vk, dots) != 0) fail_msg("%s", npg_trainer_error(t));
    for (long j = 0; j < vi.m; j++) {
      double z = 0;
      for (long l = 0; l < S; l++) z += C[l * vi.m + j] * dots[l];
      worst_z = fmax(worst_z, fabs(z - Z[k * vi.m + j]) / zmax);
    }
    for (long l = 0; l < S; l++) {
      w[l] = 0;
      for (long j = 0; j < vi.m; j++) w[l] += C[l * vi.m + j] * Z[k * vi.m + j];
    }
    memset(lifted, 0, sizeof(double) * (size_t)vi.n);
    for (long l = 0; l < S; l++) {
      const double *vl = npg_samples_get(s, "v", l, NULL);
      for (long e = 0; e < vi.n; e++) lifted[e] += w[l] * (vis ? vis(l, (size_t)e, vl[e]) : vl[e]);
    }
    for (long e = 0; e < vi.n; e++) worst_v = fmax(worst_v, fabs(lifted[e] - vk[e]));
  }
  print_message("v kept as coefficients of its %ld training values (m %ld): z_k against Cᵀ(Xᵀv_k) %.2e (of the largest "
                "|z|), X C z_k against v_k %.2e\n", S, vi.m, worst_z, worst_v);
  free(Z), free(vk), free(dots), free(w), free(lifted);
  return fmax(worst_z, worst_v);
}

static void radiosity_pipeline(void **state) {
  (void)state;
  const char *prog = "examples/radiosity/formfactors.npg";
  char data[512], bydata[512], bycall[512], cli[512], err[1024];
  snprintf(data, sizeof data, "%s/RDATA", scratch);
  snprintf(bydata, sizeof bydata, "%s/RBYDATA", scratch);
  snprintf(bycall, sizeof bycall, "%s/RBYCALL", scratch);
  snprintf(cli, sizeof cli, "%s/RCLI", scratch);
  run("%s %s 48 16 0 1 3 >/dev/null", radiosity_data_path, data);
  run("%s train %s %s -o %s --cap 8 >/dev/null", npgc_path, prog, data, cli);
  NpgProgram *p = radiosity_prog = compile(prog);
  NpgSamples *s = npg_samples_open(p, data, NULL, true, err, sizeof err);
  if (!s) fail_msg("%s", err);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = 8;

  /* externs as data: every input and extern staged by name */
  NpgFull *f = npg_full_new(p, NPG_TCC);
  assert_int_equal(npg_full_bind_params(f, data), 0);
  NpgTrainer *t = npg_trainer_new(f, &o);
  size_t ng;
  npg_samples_get(s, "g", 0, &ng);
  long F = npg_full_dim(f, "F"), V = (long)ng / 3; /* V is bound by g, not by a param */
  assert_int_equal(npg_full_dim(f, "V"), -1);
  long gs[2] = {V, 3}, es[1] = {F}, vs[2] = {F, F};
  for (long k = 0; k < npg_samples_count(s); k++) {
    if (npg_trainer_set(t, "g", 2, gs, npg_samples_get(s, "g", k, NULL)) != 0) fail_msg("%s", npg_trainer_error(t));
    assert_int_equal(npg_trainer_set(t, "e", 1, es, npg_samples_get(s, "e", k, NULL)), 0);
    assert_int_equal(npg_trainer_set(t, "v", 2, vs, npg_samples_get(s, "v", k, NULL)), 0);
    assert_int_equal(npg_trainer_add(t), 0);
  }
  NpgModel *m = npg_trainer_finish(t, bydata);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
  npg_model_free(m);
  assert_same_model(bydata, cli);

  /* the extern by callback: called once per sample, never again on replay */
  NpgFull *fc = npg_full_new(p, NPG_TCC);
  assert_int_equal(npg_full_bind_params(fc, data), 0);
  VisData vd = {s, 0};
  assert_int_equal(npg_full_set_extern_fn(fc, "v", visibility, &vd), 0);
  t = npg_trainer_new(fc, &o);
  add_g_e(t, s, gs, es);
  assert_int_equal(vd.calls, npg_samples_count(s));
  m = npg_trainer_finish(t, bycall);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  assert_int_equal(vd.calls, npg_samples_count(s));
  npg_trainer_free(t);
  assert_same_model(bycall, cli);

  /* a budget of 160 kB: training makes many passes over the samples, the
   * cache keeps most of them in its scratch file with v one bit per entry,
   * and the callback is still called once per sample; the model is the one
   * `npgc train` makes with the same budget, to the bit, and its reduced b
   * the in-memory model's (another route to the bases: to 1e-6) */
  char smallcli[512], smallcall[512];
  snprintf(smallcli, sizeof smallcli, "%s/RSMALLCLI", scratch);
  snprintf(smallcall, sizeof smallcall, "%s/RSMALLCALL", scratch);
  run("%s train %s %s -o %s --cap 8 --mem 160k >/dev/null", npgc_path, prog, data, smallcli);
  NpgTrainOptions small = o;
  small.mem = 160000;
  vd.calls = 0;
  t = npg_trainer_new(fc, &small);
  add_g_e(t, s, gs, es);
  NpgModel *ms = npg_trainer_finish(t, smallcall);
  if (!ms) fail_msg("%s", npg_trainer_error(t));
  assert_int_equal(vd.calls, npg_samples_count(s));
  assert_same_model(smallcall, smallcli);
  /* out of core v's class is kept as coefficients C of its training values, not as a basis (issue
   * 30): B_v = X C. The cache kept v exactly: every training sample's learned-map value
   * z_k = B_vᵀ v_k (extern_v_values.npy) is Cᵀ(Xᵀv_k) from the trainer's inner products, and
   * lifts back to the ray caster's v_k, which lies in the span of B_v here (v is 1 everywhere in a
   * convex room) */
  int cv = npg_model_class_of(ms, "v");
  NpgClassInfo vi;
  assert_int_equal(npg_model_class(ms, cv, &vi), 0);
  char zpath[600];
  snprintf(zpath, sizeof zpath, "%s/extern_v_values.npy", smallcall);
  assert_true(coefficients_reproduce(ms, t, s, zpath, NULL) <= 1e-10);
  npg_trainer_free(t);

  /* visibility with partly hidden faces (fractional and -0 entries, kept
   * beside the bits): with bases of every direction (cap 16 = S, energy 1)
   * the cached values still lift back exactly. A budget of 200 kB: out of
   * core as at 160 kB (6 of 9 classes streamed, {n} among them written as
   * formed, v kept as coefficients, 11 of the 16 records of ~9.4 kB in the
   * scratch file) in 72 passes rather than 217 (`npgc train --progress`) */
  NpgFull *fp = npg_full_new(p, NPG_TCC);
  assert_int_equal(npg_full_bind_params(fp, data), 0);
  vd.calls = 0;
  assert_int_equal(npg_full_set_extern_fn(fp, "v", visibility_partly, &vd), 0);
  NpgTrainOptions every = small;
  every.cap = 16, every.energy = 1, every.mem = 200000;
  t = npg_trainer_new(fp, &every);
  add_g_e(t, s, gs, es);
  char partpath[512];
  snprintf(partpath, sizeof partpath, "%s/RPARTLY", scratch);
  NpgModel *mp = npg_trainer_finish(t, partpath);
  if (!mp) fail_msg("%s", npg_trainer_error(t));
  assert_int_equal(vd.calls, npg_samples_count(s));
  snprintf(zpath, sizeof zpath, "%s/extern_v_values.npy", partpath);
  assert_true(coefficients_reproduce(mp, t, s, zpath, partly) <= 1e-10);
  /* --keep-bases v keeps the basis itself (the old layout): a visibility that is no training
   * sample's gets the same coordinates Bᵀv as Cᵀ(Xᵀv), and the reduced b with v given is the same */
  NpgTrainOptions keep = every;
  keep.keep_bases = "v";
  NpgTrainer *tk = npg_trainer_new(fp, &keep);
  add_g_e(tk, s, gs, es);
  NpgModel *mk = npg_trainer_finish(tk, NULL);
  if (!mk) fail_msg("%s", npg_trainer_error(tk));
  npg_trainer_free(tk);
  cv = npg_model_class_of(mk, "v");
  assert_int_equal(npg_model_class(mk, cv, &vi), 0);
  const double *Bk = npg_model_basis(mk, cv), *Cp = npg_model_coefficients(mp, cv, NULL);
  assert_non_null(Bk);
  assert_null(npg_model_coefficients(mk, cv, NULL));
  double *vt = malloc(sizeof(double) * (size_t)vi.n), *dots = malloc(sizeof(double) * (size_t)npg_samples_count(s));
  double *zb = calloc((size_t)vi.m, sizeof(double)), *zc = calloc((size_t)vi.m, sizeof(double));
  const double *v5 = npg_samples_get(s, "v", 5, NULL), *g5 = npg_samples_get(s, "g", 5, NULL);
  const double *e5 = npg_samples_get(s, "e", 5, NULL);
  for (long e = 0; e < vi.n; e++) vt[e] = partly(5, (size_t)e, v5[e]) * (1 + 0.1 * sin(0.37 * (double)e));
  assert_int_equal(npg_trainer_dots(t, "v", (size_t)vi.n, vt, dots), 0);
  double zmax = 0, dz = 0;
  for (long j = 0; j < vi.m; j++) {
    for (long e = 0; e < vi.n; e++) zb[j] += Bk[e * vi.m + j] * vt[e];
    for (long l = 0; l < npg_samples_count(s); l++) zc[j] += Cp[l * vi.m + j] * dots[l];
    zmax = fmax(zmax, fabs(zb[j])), dz = fmax(dz, fabs(zb[j] - zc[j]));
  }
  print_message("a visibility of no training sample: Bᵀv against Cᵀ(Xᵀv) %.2e of the largest coordinate\n", dz / zmax);
  assert_true(dz <= 1e-10 * zmax);
  NpgReduced *rb = npg_reduced_new(mk), *rcf = npg_reduced_new(mp);
  npg_reduced_given_externs(rb, true), npg_reduced_given_externs(rcf, true);
  double *bb = malloc(sizeof(double) * (size_t)F), *bc = malloc(sizeof(double) * (size_t)F);
  assert_int_equal(npg_reduced_set(rb, "g", (size_t)(3 * V), g5) || npg_reduced_set(rb, "e", (size_t)F, e5) ||
                       npg_reduced_set(rb, "v", (size_t)vi.n, vt) || npg_reduced_eval(rb, 0) ||
                       npg_reduced_lift(rb, "b", bb, (size_t)F),
                   0);
  /* the coefficient model refuses v in full, naming the way */
  assert_int_equal(npg_reduced_set(rcf, "v", (size_t)vi.n, vt), -1);
  assert_non_null(strstr(npg_reduced_error(rcf), "npg_trainer_dots"));
  npg_reduced_clear_error(rcf);
  assert_int_equal(npg_reduced_set(rcf, "g", (size_t)(3 * V), g5) || npg_reduced_set(rcf, "e", (size_t)F, e5) ||
                       npg_reduced_set_coords(rcf, "v", (size_t)vi.m, zc) || npg_reduced_eval(rcf, 0) ||
                       npg_reduced_lift(rcf, "b", bc, (size_t)F),
                   0);
  double bmax = 0, db = 0;
  for (long i = 0; i < F; i++) bmax = fmax(bmax, fabs(bb[i])), db = fmax(db, fabs(bb[i] - bc[i]));
  assert_true(db <= 1e-10 * bmax);
  free(vt), free(dots), free(zb), free(zc), free(bb), free(bc);
  npg_reduced_free(rb), npg_reduced_free(rcf);
  npg_model_free(mk);
  npg_trainer_free(t);
  npg_model_free(mp);
  npg_full_free(fp);
  npg_model_free(ms);

  /* a missing input is named */
  t = npg_trainer_new(fc, &o);
  assert_int_equal(npg_trainer_add(t), -1);
  assert_non_null(strstr(npg_trainer_error(t), "input 'g' is not set"));
  npg_trainer_free(t);
  /* a callback for something that is not an extern is refused */
  assert_int_equal(npg_full_set_extern_fn(fc, "e", visibility, &vd), -1);
  npg_full_free(fc);
  npg_full_free(f);
  npg_samples_free(s);
  radiosity_model = m;
}

/* ---------------------------------------------------------------- one model, two threads */

typedef struct Worker {
  const NpgModel *m;
  const double *g, *e;
  long V, F, reps;
  double *b;                /* the last result */
  int rc;
} Worker;

static void *work(void *arg) {
  Worker *w = arg;
  NpgReduced *r = npg_reduced_new(w->m);
  w->rc = 0;
  for (long i = 0; i < w->reps && w->rc == 0; i++)
    if (npg_reduced_set(r, "g", (size_t)(w->V * 3), w->g) || npg_reduced_set(r, "e", (size_t)w->F, w->e) ||
        npg_reduced_eval(r, i) || npg_reduced_lift(r, "b", w->b, (size_t)w->F))
      w->rc = -1;
  npg_reduced_free(r);
  return NULL;
}

static void shared_model_threads(void **state) {
  (void)state;
  assert_non_null(radiosity_model);
  char data[512], err[1024];
  snprintf(data, sizeof data, "%s/RDATA", scratch);
  NpgSamples *s = npg_samples_open(radiosity_prog, data, NULL, false, err, sizeof err);
  size_t ng, ne;
  const double *g = npg_samples_get(s, "g", 5, &ng), *e = npg_samples_get(s, "e", 5, &ne);
  Worker one = {radiosity_model, g, e, (long)ng / 3, (long)ne, 1, calloc(ne, sizeof(double)), 0};
  work(&one);
  assert_int_equal(one.rc, 0);
  Worker w[2];
  pthread_t th[2];
  for (int i = 0; i < 2; i++) {
    w[i] = one;
    w[i].reps = 1000;
    w[i].b = calloc(ne, sizeof(double));
    assert_int_equal(pthread_create(&th[i], NULL, work, &w[i]), 0);
  }
  for (int i = 0; i < 2; i++) {
    pthread_join(th[i], NULL);
    assert_int_equal(w[i].rc, 0);
    assert_memory_equal(w[i].b, one.b, sizeof(double) * ne);
    free(w[i].b);
  }
  free(one.b);
  npg_samples_free(s);
}

/* ---------------------------------------------------------------- streamed bases (issue 30) */

/* The model radiosity_pipeline trained keeps no basis of the pair classes
 * the reduced model never reads ({s,h}: neither input, output nor extern):
 * its basis is NULL, lifting or setting h is refused naming --keep-bases,
 * its reduced coordinates still exist; v (an extern) and b (the output)
 * keep theirs, and the output lifts as before. */
static void streamed_bases(void **state) {
  (void)state;
  assert_non_null(radiosity_model);
  int ch = npg_model_class_of(radiosity_model, "h"), cv = npg_model_class_of(radiosity_model, "v");
  assert_true(ch >= 0 && cv >= 0);
  assert_null(npg_model_basis(radiosity_model, ch));
  assert_non_null(npg_model_basis(radiosity_model, cv));
  assert_non_null(npg_model_basis(radiosity_model, npg_model_class_of(radiosity_model, "b")));
  char data[512], err[1024];
  snprintf(data, sizeof data, "%s/RDATA", scratch);
  NpgSamples *s = npg_samples_open(radiosity_prog, data, NULL, false, err, sizeof err);
  assert_non_null(s);
  size_t ng, ne;
  const double *g = npg_samples_get(s, "g", 3, &ng), *e = npg_samples_get(s, "e", 3, &ne);
  NpgReduced *r = npg_reduced_new(radiosity_model);
  double *b = calloc(ne * ne, sizeof(double));
  assert_int_equal(npg_reduced_set(r, "g", ng, g), 0);
  assert_int_equal(npg_reduced_set(r, "e", ne, e), 0);
  assert_int_equal(npg_reduced_eval(r, 3), 0);
  assert_int_equal(npg_reduced_lift(r, "b", b, ne), 0);
  size_t mh = 0;
  assert_non_null(npg_reduced_coords(r, "h", &mh));
  assert_true(mh > 0);
  assert_int_equal(npg_reduced_lift(r, "h", b, ne * ne), -1);
  assert_non_null(strstr(npg_reduced_error(r), "retrain with --keep-bases h"));
  free(b);
  npg_reduced_free(r);
  npg_samples_free(s);
}

/* ---------------------------------------------------------------- sample weights */

/* The radiosity data's samples into a model, sample k of weight w(k) = 3 when k % 3 == 0, else 1:
 * given as weights (npg_trainer_weight), or by adding sample k w(k) times (`dup`); weights all 1
 * when `flat`. `mem` 0: the default budget (in memory). Cap 16: every direction (energy 1). */
static NpgModel *weighted_model(NpgSamples *s, long mem, int cap, bool dup, bool flat, NpgTrainer **keep) {
  NpgFull *f = npg_full_new(radiosity_prog, NPG_TCC);
  char data[512];
  snprintf(data, sizeof data, "%s/RDATA", scratch);
  assert_int_equal(npg_full_bind_params(f, data), 0);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = cap, o.energy = cap == 16 ? 1 : o.energy;
  if (mem) o.mem = (size_t)mem;
  NpgTrainer *t = npg_trainer_new(f, &o);
  size_t ng, ne;
  npg_samples_get(s, "g", 0, &ng);
  npg_samples_get(s, "e", 0, &ne);
  long gs[2] = {(long)ng / 3, 3}, es[1] = {(long)ne}, vs[2] = {(long)ne, (long)ne};
  /* v partly hidden (partly): v's class then has more than its mean, and out of core its
   * coefficients use the weighted directions */
  double *vis = malloc(sizeof(double) * ne * ne * (size_t)npg_samples_count(s));
  for (long k = 0; k < npg_samples_count(s); k++)
    for (size_t e = 0; e < ne * ne; e++)
      vis[k * (long)(ne * ne) + (long)e] = partly(k, e, npg_samples_get(s, "v", k, NULL)[e]);
  for (long k = 0; k < npg_samples_count(s); k++) {
    int w = flat || k % 3 ? 1 : 3;
    for (int copy = 0; copy < (dup ? w : 1); copy++) {
      if (!dup && w != 1) assert_int_equal(npg_trainer_weight(t, w), 0);
      if (npg_trainer_set(t, "g", 2, gs, npg_samples_get(s, "g", k, NULL)) ||
          npg_trainer_set(t, "e", 1, es, npg_samples_get(s, "e", k, NULL)) ||
          npg_trainer_set(t, "v", 2, vs, vis + k * (long)(ne * ne)) || npg_trainer_add(t))
        fail_msg("%s", npg_trainer_error(t));
    }
  }
  free(vis);
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  if (keep) *keep = t;
  else npg_trainer_free(t);
  npg_full_free(f);
  return m;
}

/* The largest difference between two models' reduced b over the data's samples, relative to the
 * largest |b|. */
static double reduced_b_apart(const NpgModel *a, const NpgModel *b, NpgSamples *s) {
  size_t ng, ne;
  npg_samples_get(s, "e", 0, &ne);
  double *x = malloc(sizeof(double) * ne), *y = malloc(sizeof(double) * ne), worst = 0, big = 0;
  NpgReduced *ra = npg_reduced_new(a), *rb = npg_reduced_new(b);
  for (long k = 0; k < npg_samples_count(s); k++) {
    const double *g = npg_samples_get(s, "g", k, &ng), *e = npg_samples_get(s, "e", k, NULL);
    NpgReduced *r[2] = {ra, rb};
    double *out[2] = {x, y};
    for (int i = 0; i < 2; i++) {
      assert_int_equal(npg_reduced_set(r[i], "g", ng, g), 0);
      assert_int_equal(npg_reduced_set(r[i], "e", ne, e), 0);
      if (npg_reduced_eval(r[i], k) != 0) fail_msg("%s", npg_reduced_error(r[i]));
      assert_int_equal(npg_reduced_lift(r[i], "b", out[i], ne), 0);
    }
    for (size_t e2 = 0; e2 < ne; e2++) worst = fmax(worst, fabs(x[e2] - y[e2])), big = fmax(big, fabs(x[e2]));
  }
  npg_reduced_free(ra), npg_reduced_free(rb);
  free(x), free(y);
  return worst / big;
}

/* A weight is a sample counted that many times: the models trained with weights 3 and with those
 * samples added three times give the same reduced b to rounding, in memory and out of core (where
 * v is kept as coefficients of its training values, which must still reproduce them); and the
 * weights do change the model. Bad weights are refused, naming the sample. */
static void sample_weights(void **state) {
  (void)state;
  assert_non_null(radiosity_prog);
  char data[512], err[1024];
  snprintf(data, sizeof data, "%s/RDATA", scratch);
  NpgSamples *s = npg_samples_open(radiosity_prog, data, NULL, true, err, sizeof err);
  if (!s) fail_msg("%s", err);
  long mems[2] = {0, 160000};
  for (int i = 0; i < 2; i++) {
    NpgModel *w = weighted_model(s, mems[i], 8, false, false, NULL), *d = weighted_model(s, mems[i], 8, true, false, NULL);
    NpgModel *flat = weighted_model(s, mems[i], 8, false, true, NULL);
    double same = reduced_b_apart(w, d, s), moved = reduced_b_apart(w, flat, s);
    print_message("%s: weights against duplicates %.2e, against no weights %.2e (of the largest |b|)\n",
                  mems[i] ? "out of core" : "in memory", same, moved);
    assert_true(same <= 1e-10);
    assert_true(moved >= 1e-6);
    npg_model_free(w), npg_model_free(d), npg_model_free(flat);
  }
  /* out of core with every direction, v as coefficients C of the weighted directions: z_k =
   * Cᵀ(Xᵀv_k), and X C z_k = v_k (at 200 kB: the classes streamed at 160 kB, 72 passes, not 217) */
  NpgTrainer *tw = NULL;
  NpgModel *w = weighted_model(s, 200000, 16, false, false, &tw);
  char dir[600], zpath[700];
  snprintf(dir, sizeof dir, "%s/RWEIGHTED", scratch);
  assert_int_equal(npg_model_save(w, dir), 0);
  snprintf(zpath, sizeof zpath, "%s/extern_v_values.npy", dir);
  assert_true(coefficients_reproduce(w, tw, s, zpath, partly) <= 1e-10);
  npg_trainer_free(tw);
  npg_model_free(w);
  NpgFull *f = npg_full_new(radiosity_prog, NPG_TCC);
  NpgTrainer *t = npg_trainer_new(f, NULL);
  assert_int_equal(npg_trainer_weight(t, 0), -1);
  assert_non_null(strstr(npg_trainer_error(t), "weight of training sample 0 is 0: weights must be positive and finite"));
  npg_trainer_free(t);
  t = npg_trainer_new(f, NULL);
  assert_int_equal(npg_trainer_weight(t, NAN), -1);
  assert_non_null(strstr(npg_trainer_error(t), "is nan"));
  npg_trainer_free(t);
  npg_full_free(f);
  npg_samples_free(s);
}

/* ---------------------------------------------------------------- inner products */

/* `--basis x:product=H` through NpgTrainOptions.basis_product (issue 41): the basis of x is
 * H-orthonormal, npg_model_dual gives H B, and npg_reduced_set projects by it: x̂ = BᵀHx. */
static void product_dual(void **state) {
  (void)state;
  enum { N = 10, S = 6 };
  char prog[512], dir[512];
  snprintf(prog, sizeof prog, "%s/product.npg", scratch);
  snprintf(dir, sizeof dir, "%s/PRODUCT", scratch);
  FILE *fp = fopen(prog, "w");
  assert_non_null(fp);
  fputs("dim N, W\nparam cols : int[N, W]\nparam h : real[N, W]\ninput x : real[N]\n"
        "op H[i:N, j:N] = sum(k = 0..W-1, h[i, k] * delta(j, cols[i, k]))\noutput y[i:N] = 2 * x[i]\n", fp);
  fclose(fp);
  double cols[N * 3], h[N * 3], H[N * N] = {0}, x[S][N];
  for (int i = 0; i < N; i++)
    for (int k = 0; k < 3; k++) {
      int j = i + k - 1;
      cols[i * 3 + k] = j >= 0 && j < N ? j : -1;
      h[i * 3 + k] = j < 0 || j >= N ? 0 : j == i ? 3 : -1;
      if (j >= 0 && j < N) H[i * N + j] = h[i * 3 + k];
    }
  for (int k = 0; k < S; k++)
    for (int e = 0; e < N; e++) x[k][e] = sin(0.7 * (k + 1) * e) + 0.1 * k;
  NpgProgram *p = compile(prog);
  NpgFull *f = npg_full_new(p, NPG_TCC);
  long shape[2] = {N, 3};
  assert_int_equal(npg_full_set_param(f, "cols", 2, shape, cols, "cols"), 0);
  assert_int_equal(npg_full_set_param(f, "h", 2, shape, h, "h"), 0);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  const char *names[] = {"x"}, *products[] = {"H"};
  int caps[] = {4}, centers[] = {-1};
  double energies[] = {1};
  o.nbasis = 1, o.basis_name = names, o.basis_cap = caps, o.basis_energy = energies, o.basis_center = centers;
  o.basis_product = products;
  NpgTrainer *t = npg_trainer_new(f, &o);
  long xs[1] = {N};
  for (int k = 0; k < S; k++) {
    assert_int_equal(npg_full_set(f, "x", 1, xs, x[k], "x"), 0);
    if (npg_full_eval(f, k) != 0) fail_msg("%s", npg_full_error(f));
    if (npg_trainer_add_full(t, f) != 0) fail_msg("%s", npg_trainer_error(t));
  }
  NpgModel *m = npg_trainer_finish(t, dir);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  int cx = npg_model_class_of(m, "x"), cy = npg_model_class_of(m, "y");
  NpgClassInfo ci;
  assert_int_equal(npg_model_class(m, cx, &ci), 0);
  const double *B = npg_model_basis(m, cx), *D = npg_model_dual(m, cx);
  assert_non_null(D);
  assert_null(npg_model_dual(m, cy)); /* y's basis is Euclidean */
  double worst_d = 0, worst_i = 0, worst_p = 0;
  for (long a = 0; a < ci.m; a++) /* D = H B and BᵀD = I */
    for (long b = 0; b < ci.m; b++) {
      double g = 0;
      for (long e = 0; e < N; e++) g += B[e * ci.m + a] * D[e * ci.m + b];
      worst_i = fmax(worst_i, fabs(g - (a == b)));
    }
  for (long e = 0; e < N; e++)
    for (long a = 0; a < ci.m; a++) {
      double v = 0;
      for (long j = 0; j < N; j++) v += H[e * N + j] * B[j * ci.m + a];
      worst_d = fmax(worst_d, fabs(v - D[e * ci.m + a]));
    }
  NpgReduced *r = npg_reduced_new(m);
  assert_int_equal(npg_reduced_set(r, "x", N, x[2]), 0);
  size_t mx = 0;
  const double *xh = npg_reduced_coords(r, "x", &mx);
  assert_int_equal((long)mx, ci.m);
  for (long a = 0; a < ci.m; a++) {
    double v = 0;
    for (long e = 0; e < N; e++) v += D[e * ci.m + a] * x[2][e];
    worst_p = fmax(worst_p, fabs(v - xh[a]));
  }
  print_message("product H: BᵀHB − I %.1e, D − HB %.1e, x̂ − BᵀHx %.1e\n", worst_i, worst_d, worst_p);
  assert_true(worst_i < 1e-12 && worst_d < 1e-12 && worst_p < 1e-12);
  npg_reduced_free(r);
  npg_model_free(m);
  npg_trainer_free(t);
  npg_full_free(f);
  npg_free(p);
}

/* ---------------------------------------------------------------- output operators */

static void output_operator(void **state) {
  (void)state;
  NpgProgram *p = compile("tests/programs/output_op.npg");
  const long N = 7, S = 30;
  double a[49];
  srand(3);
  for (int i = 0; i < 49; i++) a[i] = (double)rand() / RAND_MAX - 0.5;
  NpgFull *f = npg_full_new(p, NPG_TCC);
  long as[2] = {N, N}, ns[1] = {N};
  assert_int_equal(npg_full_set_param(f, "a", 2, as, a, "a"), 0);
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.cap = 4; /* truncated bases: the identity must hold anyway */
  NpgTrainer *t = npg_trainer_new(f, &o);
  double w[7], x[7];
  for (long k = 0; k < S; k++) {
    for (int i = 0; i < N; i++) w[i] = 1 + 0.3 * sin((double)(k + i)), x[i] = cos(0.7 * (double)(k * i));
    assert_int_equal(npg_trainer_set(t, "w", 1, ns, w), 0);
    assert_int_equal(npg_trainer_set(t, "x", 1, ns, x), 0);
    assert_int_equal(npg_trainer_add(t), 0);
  }
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) fail_msg("%s", npg_trainer_error(t));
  npg_trainer_free(t);
  /* reduced operator at a held-out w */
  NpgReduced *r = npg_reduced_new(m);
  for (int i = 0; i < N; i++) w[i] = 1.1 + 0.2 * cos((double)i), x[i] = 0.5;
  assert_int_equal(npg_reduced_set(r, "w", 7, w), 0);
  assert_int_equal(npg_reduced_set(r, "x", 7, x), 0);
  assert_int_equal(npg_reduced_eval(r, 0), 0);
  double Mh[64];
  long rows, cols;
  int rc_, cc_;
  assert_int_equal(npg_reduced_op(r, "K", Mh, 64, &rows, &cols, &rc_, &cc_), 0);
  /* the full operator at the lifted w, densely: B_rowᵀ M B_col */
  double wl[7];
  assert_int_equal(npg_reduced_lift(r, "w", wl, 7), 0);
  assert_int_equal(npg_full_set(f, "w", 1, ns, wl, "lifted"), 0);
  assert_int_equal(npg_full_set(f, "x", 1, ns, x, "x"), 0);
  assert_int_equal(npg_full_eval(f, 0), 0);
  NpgCsr K;
  assert_int_equal(npg_full_op(f, "K", &K), 0);
  assert_int_equal(K.rows, N);
  assert_int_equal(K.cols, N);
  assert_int_equal(K.nnz, N * N);
  double M[49] = {0};
  for (long i = 0; i < K.rows; i++)
    for (long k = K.indptr[i]; k < K.indptr[i + 1]; k++) M[i * N + K.indices[k]] = K.data[k];
  for (int i = 0; i < N; i++)
    for (int j = 0; j < N; j++) assert_true(fabs(M[i * N + j] - a[i * N + j] * wl[j]) <= 1e-15);
  NpgClassInfo rci, cci;
  npg_model_class(m, rc_, &rci);
  npg_model_class(m, cc_, &cci);
  assert_int_equal(rows, rci.m);
  assert_int_equal(cols, cci.m);
  const double *Br = npg_model_basis(m, rc_), *Bc = npg_model_basis(m, cc_);
  double worst = 0, big = 0;
  for (long i = 0; i < rows; i++)
    for (long j = 0; j < cols; j++) {
      double d = 0;
      for (int u = 0; u < N; u++)
        for (int v = 0; v < N; v++) d += Br[u * rows + i] * M[u * N + v] * Bc[v * cols + j];
      worst = fmax(worst, fabs(d - Mh[i * cols + j]));
      big = fmax(big, fabs(d));
    }
  assert_true(worst <= 1e-12 * big);
  /* errors: `out` is overwritten, so the previous operator is freed first */
  npg_csr_free(&K);
  assert_int_equal(npg_full_op(f, "y", &K), -1);
  assert_null(K.indptr);
  assert_non_null(strstr(npg_full_error(f), "'y' is not an output op"));
  npg_reduced_free(r);
  npg_model_free(m);
  npg_full_free(f);
  npg_free(p);
}

static int teardown(void **state) {
  (void)state;
  npg_model_free(radiosity_model);
  npg_free(radiosity_prog);
  run("rm -rf %s", scratch);
  return 0;
}

int main(int argc, char **argv) {
  if (argc != 3) {
    fprintf(stderr, "usage: test_api NPGC RADIOSITY_DATA\n");
    return 2;
  }
  npgc_path = argv[1];
  radiosity_data_path = argv[2];
  snprintf(scratch, sizeof scratch, "/tmp/npg_test_api_%d", (int)getpid());
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(eq3_pipeline),
      cmocka_unit_test(radiosity_pipeline),
      cmocka_unit_test(shared_model_threads),
      cmocka_unit_test(streamed_bases),
      cmocka_unit_test(sample_weights),
      cmocka_unit_test(output_operator),
      cmocka_unit_test(product_dual),
  };
  return cmocka_run_group_tests(tests, NULL, teardown);
}
