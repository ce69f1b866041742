/* samples.c — reading the samples of a data directory (samples.h). */
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "emit.h"
#include "model_store.h"
#include "samples.h"

static bool exists(const char *path) {
  struct stat st;
  return stat(path, &st) == 0;
}

int samples_open(SampleSet *s, const Program *prog, const char *dir, const char *fallback, bool externs, char *err,
                 size_t errlen) {
  memset(s, 0, sizeof *s);
  s->prog = prog;
  s->count = -1;
  s->files = calloc((size_t)prog->slots.n + 1, sizeof(SampleFile));
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
    g->slot = i;
    g->q = emit_index_of(&prog->quantities, sym);
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
      snprintf(err, errlen, "%s: expected a leading sample axis and %d ax%s for '%s', the array has %d axes", g->path,
               sym->ndims + sym->nstatic, sym->ndims + sym->nstatic == 1 ? "is" : "es", sym->name, g->a.ndim);
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

const double *samples_value(const SampleSet *s, int i, long k, size_t *n) {
  const SampleFile *g = &s->files[i];
  size_t per = s->count ? g->a.count / (size_t)s->count : 0;
  if (n) *n = per;
  return (const double *)g->a.data + (size_t)k * per;
}

int samples_set(void *user, NpgFull *f, long k) {
  SampleSet *s = user;
  for (int i = 0; i < s->n; i++) {
    const SampleFile *g = &s->files[i];
    if (npg_full_set(f, g->sym->name, g->a.ndim - 1, g->a.shape + 1, samples_value(s, i, k, NULL), g->path) != 0)
      return -1;
  }
  return 0;
}

void samples_close(SampleSet *s) {
  for (int i = 0; s->files && i < s->n; i++) npy_free(&s->files[i].a);
  free(s->files);
  s->files = NULL;
  s->n = 0;
}

static int file_hash(const char *path, uint64_t *h, char *err, size_t errlen) {
  FILE *f = fopen(path, "rb");
  if (!f) {
    snprintf(err, errlen, "%s: cannot read the param file", path);
    return -1;
  }
  *h = model_hash_init();
  char buf[1 << 16];
  size_t got;
  while ((got = fread(buf, 1, sizeof buf, f)) > 0) *h = model_hash_bytes(*h, buf, got);
  fclose(f);
  return 0;
}

char *samples_param_hashes(const Program *prog, const char *dir, char *err, size_t errlen) {
  size_t cap = 64 + (size_t)prog->params.n * 96, len = 0;
  char *out = malloc(cap);
  if (!out) return NULL;
  out[0] = 0;
  for (int i = 0; i < prog->params.n; i++) {
    const Sym *p = prog->params.v[i];
    char path[4096];
    uint64_t h;
    snprintf(path, sizeof path, "%s/%s.npy", dir, p->name);
    if (file_hash(path, &h, err, errlen)) {
      free(out);
      return NULL;
    }
    if (strlen(p->name) + len + 24 >= cap) {
      cap = cap * 2 + strlen(p->name);
      char *n = realloc(out, cap);
      if (!n) {
        free(out);
        return NULL;
      }
      out = n;
    }
    len += (size_t)sprintf(out + len, "%s%s=%016llx", len ? " " : "", p->name, (unsigned long long)h);
  }
  return out;
}

int samples_check_params(const Program *prog, const char *dir, const char *recorded, char *err, size_t errlen) {
  if (!recorded) return 0;
  for (int i = 0; i < prog->params.n; i++) {
    const Sym *p = prog->params.v[i];
    char key[512], path[4096];
    snprintf(key, sizeof key, "%s=", p->name);
    const char *at = recorded;
    while ((at = strstr(at, key)) && at != recorded && at[-1] != ' ') at++;
    snprintf(path, sizeof path, "%s/%s.npy", dir, p->name);
    uint64_t h;
    if (file_hash(path, &h, err, errlen)) return -1;
    if (!at || strtoull(at + strlen(key), NULL, 16) != h) {
      snprintf(err, errlen, "%s: param '%s' differs from the one the model was trained with: retrain, or give the "
                            "training data's params",
               path, p->name);
      return -1;
    }
  }
  return 0;
}
