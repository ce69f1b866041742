/* samples.c — reading the samples of a data directory (npg.h NpgSamples):
 * every input and extern as DIR/<name>.npy with a leading sample axis,
 * checked once (float64, one sample count across files), handed to the full
 * evaluator one sample at a time. */
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "api.h"
#include "compile.h"
#include "emit.h"
#include "npy.h"

typedef struct SampleFile {
  const Sym *sym;
  NpyArray a;
  char path[4096];
} SampleFile;

typedef struct SampleSet {
  const Program *prog;
  int n;
  SampleFile *files;
  long count;               /* samples */
} SampleSet;

struct NpgSamples {
  SampleSet s;
};

static void samples_close(SampleSet *s);

static bool exists(const char *path) {
  struct stat st;
  return stat(path, &st) == 0;
}

static int samples_open(SampleSet *s, const Program *prog, const char *dir, const char *fallback, bool externs, char *err,
                 size_t errlen) {
  memset(s, 0, sizeof *s);
  s->prog = prog;
  s->count = -1;
  s->files = mem_calloc((size_t)prog->slots.n + 1, sizeof(SampleFile));
  if (!s->files) {
    snprintf(err, errlen, "out of memory");
    return -1;
  }
  const char *count_from = NULL;
  for (int i = 0; i < prog->slots.n; i++) {
    const Sym *sym = prog->slots.v[i];
    if (sym->kind != SYM_INPUT && !(externs && sym->kind == SYM_EXTERN)) continue;
    SampleFile *g = &s->files[s->n];
    g->sym = sym;
    snprintf(g->path, sizeof g->path, "%s/%s.npy", dir, sym->name);
    if (fallback && !exists(g->path)) snprintf(g->path, sizeof g->path, "%s/%s.npy", fallback, sym->name);
    if (npy_read(g->path, &g->a, err, errlen) != 0) goto fail;
    s->n++;
    if (g->a.type != NPY_F64) {
      snprintf(err, errlen, "%s: %s '%s' must be float64, the array is %s", g->path,
               sym->kind == SYM_INPUT ? "input" : "extern", sym->name, npy_type_name(g->a.type));
      goto fail;
    }
    if (g->a.ndim != sym->ndims + sym->nstatic + 1) {
      /* both shapes written out: "expected (samples, N, 3) ..., found (20, 15)" */
      char want[512], found[512];
      size_t w = (size_t)snprintf(want, sizeof want, "(samples"), f = (size_t)snprintf(found, sizeof found, "(");
      for (int d = 0; d < sym->ndims && w < sizeof want; d++)
        w += (size_t)snprintf(want + w, sizeof want - w, ", %s", sym->dims[d]->name);
      for (int d = 0; d < sym->nstatic && w < sizeof want; d++)
        w += (size_t)snprintf(want + w, sizeof want - w, ", %d", sym->shape[d]);
      for (int d = 0; d < g->a.ndim && f < sizeof found; d++)
        f += (size_t)snprintf(found + f, sizeof found - f, "%s%ld", d ? ", " : "", g->a.shape[d]);
      if (w < sizeof want) snprintf(want + w, sizeof want - w, ")");
      if (f < sizeof found) snprintf(found + f, sizeof found - f, "%s)", g->a.ndim == 1 ? "," : "");
      snprintf(err, errlen, "%s: %s '%s' needs the shape %s (a leading sample axis, then its %d ax%s), the array's "
               "shape is %s", g->path, sym->kind == SYM_INPUT ? "input" : "extern", sym->name, want,
               sym->ndims + sym->nstatic, sym->ndims + sym->nstatic == 1 ? "is" : "es", found);
      goto fail;
    }
    /* static axes are checked here, not only when a sample is set: a file of
     * no samples and a wrong shape was accepted (eval wrote nothing, exit 0) */
    for (int d = 0; d < sym->nstatic; d++)
      if (g->a.shape[1 + sym->ndims + d] != sym->shape[d]) {
        snprintf(err, errlen, "%s: axis %d of '%s' is static with size %d, but axis %d of the array (after the sample "
                              "axis) has %ld", g->path, sym->ndims + d, sym->name, sym->shape[d], 1 + sym->ndims + d,
                 g->a.shape[1 + sym->ndims + d]);
        goto fail;
      }
    /* a NaN or an infinity is named by sample and index, once, here */
    size_t per = 1;
    for (int d = 1; d < g->a.ndim; d++) per *= (size_t)g->a.shape[d];
    for (size_t e = 0; e < g->a.count; e++) {
      double v = ((const double *)g->a.data)[e];
      if (v - v == 0) continue;
      char at[256];
      size_t rest = per ? e % per : 0, o = (size_t)snprintf(at, sizeof at, "[");
      long idx[NPY_MAX_DIMS];
      for (int d = g->a.ndim - 1; d >= 1; d--) idx[d] = (long)(rest % (size_t)g->a.shape[d]), rest /= (size_t)g->a.shape[d];
      for (int d = 1; d < g->a.ndim && o < sizeof at; d++) o += (size_t)snprintf(at + o, sizeof at - o, "%s%ld", d > 1 ? ", " : "", idx[d]);
      if (o < sizeof at) snprintf(at + o, sizeof at - o, "]");
      snprintf(err, errlen, "%s: %s '%s' holds %s at sample %zu, %s", g->path, sym->kind == SYM_INPUT ? "input" : "extern",
               sym->name, v != v ? "NaN" : "an infinity", per ? e / per : 0, at);
      goto fail;
    }
    if (s->count < 0) {
      s->count = g->a.shape[0];
      count_from = g->path;
    } else if (g->a.shape[0] != s->count) {
      snprintf(err, errlen, "%s has %ld samples but %s has %ld", count_from, s->count, g->path, g->a.shape[0]);
      goto fail;
    }
  }
  if (s->count < 0) s->count = 1; /* a program without inputs: one evaluation */
  return 0;
fail:
  samples_close(s);
  return -1;
}

static const double *samples_value(const SampleSet *s, int i, long k, size_t *n) {
  const SampleFile *g = &s->files[i];
  size_t per = s->count ? g->a.count / (size_t)s->count : 0;
  if (n) *n = per;
  return (const double *)g->a.data + (size_t)k * per;
}

static int samples_set(void *user, NpgFull *f, long k) {
  SampleSet *s = user;
  for (int i = 0; i < s->n; i++) {
    const SampleFile *g = &s->files[i];
    if (npg_full_set(f, g->sym->name, g->a.ndim - 1, g->a.shape + 1, samples_value(s, i, k, NULL), g->path) != 0)
      return -1;
  }
  return 0;
}

int npg_samples_bind_dims(const NpgSamples *ns, NpgFull *f) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (!ns) {
    api_refuse(NULL, 0, __func__, "argument 's' is NULL");
    return full_fail(f->full, api_refusal());
  }
  for (int i = 0; i < ns->s.n; i++) {
    const SampleFile *g = &ns->s.files[i];
    if (full_bind_shape(f->full, g->sym->name, g->a.ndim - 1, g->a.shape + 1, g->path) != 0) return -1;
  }
  return 0;
}

/* "(S, 5, 3)": a sample axis and `n` entries of `shape`. */
static void shape_text(char *buf, size_t len, const long *shape, int n) {
  size_t o = (size_t)snprintf(buf, len, "(S");
  for (int d = 0; d < n && o < len; d++) o += (size_t)snprintf(buf + o, len - o, ", %ld", shape[d]);
  if (o < len) snprintf(buf + o, len - o, ")");
}

/* The reduced evaluation takes a sample as a flat vector: an array of the
 * right entry count but another shape (x trained as (S, 5, 3) given as
 * (S, 3, 5) or (S, 15, 1)) would be evaluated silently wrong (issue 24). */
int npg_samples_check_model(const NpgSamples *ns, const NpgModel *m, char *err, size_t errlen) {
  if (!ns || !m) {
    if (err && errlen) snprintf(err, errlen, "npg_samples_check_model: argument '%s' is NULL", ns ? "m" : "s");
    return -1;
  }
  const SampleSet *s = &ns->s;
  for (int i = 0; i < s->n; i++) {
    const SampleFile *g = &s->files[i];
    const Sym *sym = g->sym;
    long want[NPY_MAX_DIMS];
    int n = 0;
    for (int d = 0; d < sym->ndims && n < NPY_MAX_DIMS; d++) want[n++] = npg_model_dim(m, sym->dims[d]->name);
    for (int d = 0; d < sym->nstatic && n < NPY_MAX_DIMS; d++) want[n++] = sym->shape[d];
    bool same = n == g->a.ndim - 1;
    for (int d = 0; same && d < n; d++) same = want[d] == g->a.shape[d + 1];
    if (same) continue;
    char found[256], expected[256];
    shape_text(found, sizeof found, g->a.shape + 1, g->a.ndim - 1);
    shape_text(expected, sizeof expected, want, n);
    snprintf(err, errlen, "%s: %s '%s' has shape %s, the model was trained on %s", g->path,
             sym->kind == SYM_INPUT ? "input" : "extern", sym->name, found, expected);
    return -1;
  }
  return 0;
}

static void samples_close(SampleSet *s) {
  for (int i = 0; s->files && i < s->n; i++) npy_free(&s->files[i].a);
  free(s->files);
  s->files = NULL;
  s->n = 0;
}


NpgSamples *npg_samples_open(NpgProgram *p, const char *dir, const char *fallback, bool externs, char *err,
                             size_t errlen) {
  API_REFUSE_NULL(p, err, errlen, NULL);
  API_REFUSE_NULL(dir, err, errlen, NULL);
  if (!npg_ok(p)) {
    snprintf(err, errlen, "%s", npg_error(p));
    return NULL;
  }
  NpgSamples *s = mem_calloc(1, sizeof *s);
  if (!s) {
    snprintf(err, errlen, "out of memory");
    return NULL;
  }
  if (samples_open(&s->s, program_ir(p), dir, fallback, externs, err, errlen) != 0) {
    free(s);
    return NULL;
  }
  return s;
}

long npg_samples_count(const NpgSamples *s) {
  API_REFUSE_NULL(s, NULL, 0, -1);
  return s->s.count;
}

const double *npg_samples_get(const NpgSamples *s, const char *name, long k, size_t *count) {
  API_REFUSE_NULL(s, NULL, 0, NULL);
  API_REFUSE_NULL(name, NULL, 0, NULL);
  for (int i = 0; i < s->s.n; i++)
    if (strcmp(s->s.files[i].sym->name, name) == 0 && k >= 0 && k < s->s.count)
      return samples_value(&s->s, i, k, count);
  return NULL;
}

int npg_samples_set(void *samples, NpgFull *f, long k) {
  API_REFUSE_NULL(f, NULL, 0, -1);
  if (!samples) {
    api_refuse(NULL, 0, __func__, "argument 'samples' is NULL");
    return full_fail(f->full, api_refusal());
  }
  const SampleSet *s = &((NpgSamples *)samples)->s;
  if (k < 0 || k >= s->count) {
    api_refuse(NULL, 0, __func__, "argument 'k' is %ld, but the set holds %ld sample%s (0 to %ld)", k, s->count,
               s->count == 1 ? "" : "s", s->count - 1);
    return full_fail(f->full, api_refusal());
  }
  return samples_set(&((NpgSamples *)samples)->s, f, k);
}

void npg_samples_free(NpgSamples *s) {
  if (!s) return;
  samples_close(&s->s);
  free(s);
}
