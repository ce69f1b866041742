/* model_files.c — the model to and from MODEL/ (DESIGN §2): the manifest
 * holds the dims, the classes with their sizes and, per member, its cap,
 * energy fraction, centering, vectors kept and energy lost, which inverse
 * operators factor by Cholesky; every basis, reduced tensor, projection,
 * extern table and member spectrum is one .npy (the spectra also as CSV).
 * Member lines without "center" load as uncentered, their lost energy
 * 1 − captured. The layout is recomputed from the program (whose hash the
 * store checks, model.c) and every array's shape is checked against it,
 * naming the file. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "estimate.h"
#include "interp.h"
#include "model.h"
#include "model_store.h"
#include "scratch.h"

/* ---------------------------------------------------------------- files */

static const char *qname(const Model *m, int q) { return ((Sym *)m->prog->quantities.v[q])->name; }

/* The CSV of a member's spectrum: k, σ_k, the energy fraction lost keeping
 * the first k (malloc'd). */
static char *spectrum_csv(const RMember *mb) {
  /* the header holds the member's name, of any length; a row at most 80 bytes */
  size_t cap = 64 + strlen(mb->name) + 80 * (size_t)mb->nsv, len = 0;
  char *t = mem_malloc(cap);
  if (!t) return NULL;
  double total = 0, run = 0;
  for (long i = 0; i < mb->nsv; i++) total += mb->sv[i] * mb->sv[i];
  len += (size_t)snprintf(t + len, cap - len, "# %s: singular values of its %ssnapshots\nk,singular_value,lost\n",
                          mb->name, mb->center ? "centered " : "");
  for (long i = 0; i < mb->nsv; i++) {
    run += mb->sv[i] * mb->sv[i];
    len += (size_t)snprintf(t + len, cap - len, "%ld,%.17g,%.6e\n", i + 1, mb->sv[i],
                            total > 0 ? fmax(0, 1 - run / total) : 0.0);
  }
  return t;
}

/* 1 + the first stage of class c (with a product) whose terms take an inverse power ≤ -2
 * (model_term_inverse_power: the manifest's `productpowers C 1` line), or 0. */
static int class_inverse_power(const Model *m, int c) {
  for (int i = 0; m->classes[c].product && i < m->nstages; i++)
    for (int t = 0; m->qclass[m->stages[i].q] == c && t < m->stages[i].nterms; t++)
      if (model_term_inverse_power(&m->stages[i].terms[t])) return i + 1;
  return 0;
}

int model_save(const Model *m, const char *dir, Err *err) {
  ModelStore s;
  model_store_init(&s);
  s.program_hash = m->program_hash;
  Scratch sc = SCRATCH_OF(NULL); /* the dims line, the spectra's text */
  int bad = 0;
  /* the dims line grows with the names: a fixed buffer cut a long name and
   * the model could not be loaded (issue 24) */
  char *line = NULL;
  size_t len = 0;
  FILE *mem = open_memstream(&line, &len);
  if (mem) {
    fputs("dims", mem);
    for (int i = 0; i < m->ndims; i++) fprintf(mem, " %s=%ld", ((Sym *)m->prog->dims.v[i])->name, m->dims[i]);
  }
  int closed = mem ? fclose(mem) : -1; /* `line` is the stream's buffer even when closing failed */
  if (!scratch_adopt(&sc, line) || closed != 0) bad = -1;
  else bad |= model_store_meta(&s, "%s", line);
  bad |= model_store_meta(&s, "samples %ld", m->samples);
  /* always written, empty when none were recorded: loading requires it */
  bad |= model_store_meta(&s, "params%s%s", m->param_hashes && *m->param_hashes ? " " : "",
                          m->param_hashes ? m->param_hashes : "");
  size_t tb = 0, total = model_bytes(m, &tb);
  bad |= model_store_meta(&s, "bytes %zu tensors %zu", total, tb);
  for (int c = 0; c < m->nclasses; c++) {
    const RClass *rc = &m->classes[c];
    bad |= model_store_meta(&s, "class %d %s n %ld m %ld", c, rc->label, rc->n, rc->m);
    for (int i = 0; i < rc->nmembers; i++) {
      const RMember *mb = &rc->members[i];
      bad |= model_store_meta(&s, "member %d %s cap %d energy %.17g kept %d captured %.17g center %d lost %.17g", c,
                              mb->name, mb->cap, mb->energy, mb->kept, mb->captured, mb->center ? 1 : 0, mb->lost);
      char name[600];
      long shape[1] = {mb->nsv};
      snprintf(name, sizeof name, "spectrum_%s", mb->name);
      bad |= model_store_add(&s, name, 1, shape, mb->sv);
      char *csv = scratch_adopt(&sc, spectrum_csv(mb));
      snprintf(name, sizeof name, "spectrum_%s.csv", mb->name);
      bad |= csv ? model_store_add_text(&s, name, csv) : -1;
    }
    if (rc->streamed) { /* no basis file: its quantities' training floors instead (issue 30) */
      bad |= model_store_meta(&s, "streamed %d", c);
      for (int i = 0; i < rc->nmembers; i++)
        if (rc->members[i].q >= 0)
          bad |= model_store_meta(&s, "floor %s l2 %.17g linf %.17g", rc->members[i].name, rc->members[i].floor_l2,
                                  rc->members[i].floor_linf);
      if (rc->coef) { /* kept as coefficients of its training values: a format older builds refuse */
        char name[64];
        long shape[2] = {rc->coef_S, rc->m};
        snprintf(name, sizeof name, "coef_%d", c);
        s.format = 3;
        bad |= model_store_meta(&s, "coefficients %d samples %ld", c, rc->coef_S);
        bad |= model_store_add(&s, name, 2, shape, rc->coef);
      }
      continue;
    }
    char name[64];
    snprintf(name, sizeof name, "basis_%d", c);
    long shape[2] = {rc->n, rc->m};
    bad |= rc->B_mapped ? model_store_add_borrowed(&s, name, 2, shape, rc->B) : model_store_add(&s, name, 2, shape, rc->B);
    if (rc->D) { /* `basis u: product K0`: the dual K0 B that projects (issue 41) */
      snprintf(name, sizeof name, "dual_%d", c);
      bad |= model_store_meta(&s, "product %d %s", c, rc->product->name);
      if (rc->k0_norm1 > 0) bad |= model_store_meta(&s, "productnorm %d %.17g", c, rc->k0_norm1);
      if (class_inverse_power(m, c)) bad |= model_store_meta(&s, "productpowers %d 1", c);
      bad |= model_store_add(&s, name, 2, shape, rc->D);
    }
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      for (int k = 0; k < rt->nops; k++)
        if (rt->ops[k].spd) bad |= model_store_meta(&s, "spd %s %d %d", rs->st->sym->name, t, k);
      if (rt->proj) {
        long shape[2] = {m->classes[m->qclass[rs->q]].m, m->classes[m->qclass[rt->named_q]].m};
        bad |= model_store_add(&s, rt->proj_name, 2, shape, rt->proj);
      }
    }
  }
  FOR_TENSORS(m, x) {
    long shape[2] = {x->rows, x->cols};
    bad |= model_store_add(&s, x->name, 2, shape, x->data);
  }
  for (int i = 0; i < m->nexterns; i++) {
    const RExtern *x = &m->externs[i];
    char name[512];
    snprintf(name, sizeof name, "extern_%s_inputs", qname(m, x->q));
    long shape[2] = {x->S, x->d};
    bad |= model_store_add(&s, name, 2, shape, x->X);
    snprintf(name, sizeof name, "extern_%s_values", qname(m, x->q));
    shape[1] = m->classes[m->qclass[x->q]].m;
    bad |= model_store_add(&s, name, 2, shape, x->Z);
  }
  bad |= interp_save(m, &s);
  bad |= estimate_save(m, &s);
  if (m->greedy) bad |= model_store_meta(&s, "greedy %s", m->greedy);
  int rc = -1;
  if (bad) err_set(err, "%s: out of memory assembling the model", dir);
  else rc = model_store_write(dir, &s, err);
  model_store_free(&s);
  scratch_release(&sc);
  return rc;
}

/* A copy of array `name` of shape rows x cols out of the store; NULL with `err`. */
static double *take(const ModelStore *s, const char *dir, const char *name, long rows, long cols, Err *err) {
  const NpyArray *a = model_store_array(s, name);
  if (!a) {
    err_set(err, "%s/manifest: no array '%s': the model is incomplete", dir, name);
    return NULL;
  }
  if (a->ndim != 2 || a->shape[0] != rows || a->shape[1] != cols) {
    err_set(err, "%s/%s.npy: shape %ldx%ld, the program and the model's bases need %ldx%ld", dir, name,
            a->ndim > 0 ? a->shape[0] : 0, a->ndim > 1 ? a->shape[1] : 0, rows, cols);
    return NULL;
  }
  double *out = mem_malloc(sizeof(double) * (size_t)(rows * cols) + 1);
  if (!out) {
    err_set(err, "%s/%s.npy: out of memory", dir, name);
    return NULL;
  }
  memcpy(out, a->data, sizeof(double) * (size_t)(rows * cols));
  return out;
}

/* The class, member and spd lines of a loaded manifest against the layout
 * and the bases: 0, or -1 with `err` naming the line. */
static int check_meta(const ModelStore *s, Model *m, const char *dir, Err *err) {
  /* every quantity of a streamed class has its floor line (NaN until read; check_streamed refuses one
   * left NaN): verify prints it in place of a measured floor, and a missing one read as 0 claimed a
   * perfect basis (trial3) */
  for (int c = 0; c < m->nclasses; c++)
    for (int k = 0; m->classes[c].streamed && k < m->classes[c].nmembers; k++)
      if (m->classes[c].members[k].q >= 0) m->classes[c].members[k].floor_l2 = NAN;
  for (int i = 0; i < s->nmeta; i++) {
    const char *line = s->meta[i];
    bool ok = true;
    char name[512];
    if (strncmp(line, "class ", 6) == 0) {
      int c, used = 0;
      long n, mm;
      ok = sscanf(line, "class %d %511s n %ld m %ld%n", &c, name, &n, &mm, &used) == 4 && line[used] == 0 && c >= 0 &&
           c < m->nclasses && strcmp(name, m->classes[c].label) == 0 && n == m->classes[c].n && mm == m->classes[c].m;
    } else if (strncmp(line, "member ", 7) == 0) {
      int c, cap, kept, center = 0, used = 0;
      double energy, captured, lost = 0;
      int got = sscanf(line, "member %d %511s cap %d energy %lf kept %d captured %lf%n center %d lost %lf%n", &c, name,
                       &cap, &energy, &kept, &captured, &used, &center, &lost, &used);
      ok = (got == 6 || got == 8) && line[used] == 0 && c >= 0 && c < m->nclasses && cap >= 1 && energy > 0 &&
           energy <= 1 && kept >= 0 && captured >= 0 && captured <= 1 + 1e-9 && lost >= 0 && lost <= 1 + 1e-9 &&
           (center == 0 || center == 1);
      bool known = false;
      for (int k = 0; ok && k < m->classes[c].nmembers; k++) known |= strcmp(m->classes[c].members[k].name, name) == 0;
      ok = ok && known;
    } else if (strncmp(line, "streamed ", 9) == 0) {
      int c, used = 0;
      ok = sscanf(line, "streamed %d%n", &c, &used) == 1 && line[used] == 0 && c >= 0 && c < m->nclasses;
    } else if (strncmp(line, "floor ", 6) == 0) {
      int used = 0;
      double l2, linf;
      /* linf nan: not measured (out of core, ooc.c take_floors); l2 is a mean of ‖y − BBᵀy‖/‖y‖ ≤ 1 (a
       * projection shortens y), with the out-of-core route's rounding of about 1e-7 */
      ok = sscanf(line, "floor %511s l2 %lf linf %lf%n", name, &l2, &linf, &used) == 3 && line[used] == 0 && l2 >= 0 &&
           l2 <= 1 + 1e-6 && (isnan(linf) || (linf >= 0 && isfinite(linf)));
      bool known = false; /* a quantity of a streamed class */
      for (int c = 0; ok && c < m->nclasses; c++)
        for (int k = 0; m->classes[c].streamed && k < m->classes[c].nmembers; k++)
          known |= m->classes[c].members[k].q >= 0 && strcmp(m->classes[c].members[k].name, name) == 0;
      ok = ok && known;
      for (int c = 0; ok && c < m->nclasses; c++)
        for (int k = 0; k < m->classes[c].nmembers; k++)
          if (strcmp(m->classes[c].members[k].name, name) == 0)
            m->classes[c].members[k].floor_l2 = l2, m->classes[c].members[k].floor_linf = linf;
    } else if (strncmp(line, "spd ", 4) == 0) {
      int t, k, used = 0;
      ok = sscanf(line, "spd %511s %d %d%n", name, &t, &k, &used) == 3 && line[used] == 0;
      bool found = false;
      for (int j = 0; ok && j < m->nstages; j++) {
        const RStage *rs = &m->stages[j];
        if (strcmp(rs->st->sym->name, name) != 0 || t < 0 || t >= rs->nterms || k < 0 || k >= rs->terms[t].nops) continue;
        found = true;
      }
      ok = ok && found;
    } else {
      continue;
    }
    if (!ok) {
      err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)", dir,
              line);
      return -1;
    }
  }
  return 0;
}

/* The lines model_save always writes: a manifest without one of them is
 * damaged or forged (its checksum can be recomputed), and is refused here
 * rather than read with a default. */
static const char *const REQUIRED_LINES[] = {"dims", "samples", "params", "bytes"};

/* 0 if the manifest holds every required line, a 'class' line per class and
 * a 'member' line per member of the layout `m`; else -1 naming the first
 * missing. */
static int check_required(const ModelStore *s, const Model *m, const char *dir, Err *err) {
  for (size_t i = 0; i < sizeof REQUIRED_LINES / sizeof *REQUIRED_LINES; i++)
    if (!model_store_find(s, REQUIRED_LINES[i]))
      return err_set(err, "%s/manifest: no '%s' line: the model is damaged; retrain", dir, REQUIRED_LINES[i]);
  for (int c = 0; c < m->nclasses; c++) {
    const RClass *rc = &m->classes[c];
    for (int k = -1; k < rc->nmembers; k++) {
      char want[600];
      int n = k < 0 ? snprintf(want, sizeof want, "class %d %s ", c, rc->label)
                    : snprintf(want, sizeof want, "member %d %s ", c, rc->members[k].name);
      bool found = false;
      for (int j = 0; j < s->nmeta && !found; j++) found = strncmp(s->meta[j], want, (size_t)n) == 0;
      if (!found)
        return err_set(err, "%s/manifest: no '%.*s' line: the model is damaged; retrain", dir, n - 1, want);
    }
  }
  return 0;
}

static bool has_line(const ModelStore *s, const char *line) {
  for (int i = 0; i < s->nmeta; i++)
    if (strcmp(s->meta[i], line) == 0) return true;
  return false;
}

/* The manifest's "dims" line: the size of every dim of `prog` into dims[]. */
static int read_dims(const ModelStore *s, const Program *prog, const char *dir, long *dims, Err *err) {
  const char *d = model_store_find(s, "dims");
  if (!d) return err_set(err, "%s/manifest: no 'dims' line", dir);
  for (int i = 0; i < prog->dims.n; i++) {
    const char *name = ((Sym *)prog->dims.v[i])->name;
    size_t nl = strlen(name);
    const char *p = d;
    dims[i] = -1;
    while ((p = strstr(p, name)) != NULL) {
      if ((p == d || p[-1] == ' ') && p[nl] == '=') {
        char *end;
        errno = 0;
        dims[i] = strtol(p + nl + 1, &end, 10);
        /* every size product of the layout stays far from overflow */
        if (errno || end == p + nl + 1 || (*end && *end != ' ') || dims[i] < 0 || dims[i] > 100000000)
          return err_set(err, "%s/manifest: dim %s has no valid size in '%.100s'", dir, name, d);
        break;
      }
      p += nl;
    }
    if (dims[i] < 0) return err_set(err, "%s/manifest: no size for dim %s", dir, name);
  }
  return 0;
}

/* Class c's coefficients (RClass.coef) when its "coefficients C samples S" line says it has them:
 * coef_C.npy, S x m. 0 (also when it has none), or -1 with `err`. */
static int load_coefficients(const ModelStore *s, Model *m, int c, const char *dir, Err *err) {
  RClass *rc = &m->classes[c];
  char prefix[64];
  int n = snprintf(prefix, sizeof prefix, "coefficients %d ", c);
  for (int j = 0; j < s->nmeta; j++) {
    if (strncmp(s->meta[j], prefix, (size_t)n) != 0) continue;
    int cc, used = 0;
    long S;
    if (sscanf(s->meta[j], "coefficients %d samples %ld%n", &cc, &S, &used) != 2 || s->meta[j][used] || S < 1 ||
        S != m->samples || rc->coef)
      return err_set(err, "%s/manifest: '%.200s' does not describe this model (a damaged or forged manifest)",
                     dir, s->meta[j]);
    if (s->format < 3)
      return err_set(err, "%s/manifest: a 'coefficients' line in a model of format %d (a damaged or forged "
                     "manifest)", dir, s->format);
    char name[64];
    snprintf(name, sizeof name, "coef_%d", c);
    if (!(rc->coef = take(s, dir, name, S, rc->m, err))) return -1;
    for (long e = 0; e < S * rc->m; e++)
      if (!isfinite(rc->coef[e]))
        return err_set(err, "%s/%s.npy: holds a value that is not finite (a damaged or forged model)", dir, name);
    rc->coef_S = S;
  }
  return 0;
}

/* A class with a product (`basis u: product K0` or --basis u:product=K0,
 * issue 41): the manifest's `product C K0` names the op, which the program
 * must have (and declare, if it declares one for the class, the same), and
 * dual_C.npy holds K0 B. */
static int load_dual(const ModelStore *s, const Model *m, RClass *rc, int c, const char *dir, Err *err) {
  char name[64], prefix[64];
  snprintf(name, sizeof name, "dual_%d", c);
  snprintf(prefix, sizeof prefix, "product %d ", c);
  const char *op = NULL;
  for (int j = 0; j < s->nmeta && !op; j++)
    if (strncmp(s->meta[j], prefix, strlen(prefix)) == 0) op = s->meta[j] + strlen(prefix);
  const NpyArray *a = model_store_array(s, name);
  if (!a && !op && !rc->product) return 0;
  if (!op && rc->product)
    return err_set(err, "%s: class %s has product %s in the program but the model was trained without it: "
                   "train again", dir, rc->label, rc->product->name);
  if (!op || !a)
    return err_set(err, "%s/manifest: class %s has %s but not %s (a damaged model)", dir, rc->label,
                   op ? "a product line" : name, op ? name : "its product line");
  if (rc->product && strcmp(rc->product->name, op) != 0)
    return err_set(err, "%s/manifest: class %s was trained with product %s, the program declares product %s: "
                   "train again", dir, rc->label, op, rc->product->name);
  for (int i = 0; i < m->prog->ops.n && !rc->product; i++)
    if (strcmp(((const Sym *)m->prog->ops.v[i])->name, op) == 0) rc->product = m->prog->ops.v[i];
  if (!rc->product)
    return err_set(err, "%s/manifest: class %s was trained with product %s, which is no op of the program",
                   dir, rc->label, op);
  if (a->ndim != 2 || a->shape[0] != rc->n || a->shape[1] != rc->m)
    return err_set(err, "%s/%s.npy: wrong shape, class %s needs %ld x %ld", dir, name, rc->label, rc->n, rc->m);
  snprintf(prefix, sizeof prefix, "productnorm %d ", c); /* absent before it was stored: 0, input errors unknown */
  for (int j = 0; j < s->nmeta; j++)
    if (strncmp(s->meta[j], prefix, strlen(prefix)) == 0 &&
        !(sscanf(s->meta[j] + strlen(prefix), "%lf", &rc->k0_norm1) == 1 && rc->k0_norm1 > 0 && isfinite(rc->k0_norm1)))
      return err_set(err, "%s/manifest: class %s's productnorm line is not a positive number (a damaged model)", dir,
                     rc->label);
  for (int i = 0; i < m->nstages && !(rc->k0_norm1 > 0); i++) /* trained before model_term_coords' rows (issue 41) */
    for (int t = 0; m->qclass[m->stages[i].q] == c && t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++)
        if (model_term_coords(&m->stages[i].terms[t], k))
          return err_set(err, "%s: stage %s chains a solve after a solve or after a power above 1 in class %s (product "
                         "%s), which models trained before were reduced wrongly for (B's rows where coordinates pass, "
                         "BᵀB ≠ I): retrain", dir, m->stages[i].st->sym->name, rc->label, rc->product->name);
  snprintf(prefix, sizeof prefix, "productpowers %d 1", c);
  int i = class_inverse_power(m, c);
  for (int j = 0; i && j < s->nmeta; j++) i = strcmp(s->meta[j], prefix) == 0 ? 0 : i;
  if (i) /* trained before an inverse power's rows were model_term_coords' (issue 41) */
    return err_set(err, "%s: stage %s takes an inverse power (K^-2 and below) in class %s (product %s), which models "
                   "trained before were reduced wrongly for ((BᵀKB)^-p, BᵀB ≠ I): retrain", dir,
                   m->stages[i - 1].st->sym->name, rc->label, rc->product->name);
  return (rc->D = take(s, dir, name, rc->n, rc->m, err)) ? 0 : -1;
}

/* Every class's basis: basis_C.npy, or for a streamed class (no basis kept,
 * model.h) its size from the class line (check_meta checks that line). */
static int load_bases(const ModelStore *s, Model *m, const char *dir, Err *err) {
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    char name[64];
    snprintf(name, sizeof name, "streamed %d", c);
    if (has_line(s, name)) {
      snprintf(name, sizeof name, "class %d ", c);
      for (int j = 0; j < s->nmeta; j++)
        if (strncmp(s->meta[j], name, strlen(name)) == 0) {
          const char *mp = strstr(s->meta[j], " m ");
          rc->m = mp ? strtol(mp + 3, NULL, 10) : 0;
        }
      if (rc->m < 1 || rc->m > rc->n)
        return err_set(err, "%s/manifest: streamed class %s has no valid basis size on its class line", dir,
                       rc->label);
      rc->streamed = true;
      if (load_coefficients(s, m, c, dir, err)) return -1;
      continue;
    }
    snprintf(name, sizeof name, "basis_%d", c);
    const NpyArray *a = model_store_array(s, name);
    if (!a || a->ndim != 2 || a->shape[0] != rc->n)
      return err_set(err, "%s/%s.npy: %s, class %s needs %ld rows", dir, name, a ? "wrong shape" : "missing",
                     rc->label, rc->n);
    rc->m = a->shape[1];
    if (!(rc->B = take(s, dir, name, rc->n, rc->m, err))) return -1;
    if (load_dual(s, m, rc, c, dir, err)) return -1;
  }
  bool coef = false;
  for (int c = 0; c < m->nclasses; c++) coef |= m->classes[c].coef != NULL;
  if (s->format == 3 && !coef)
    return err_set(err, "%s/manifest: format 3 but no class kept as coefficients (a damaged or forged "
                   "manifest)", dir);
  return 0;
}

/* Only a class the rule allows is streamed: never one whose basis is read. */
static int check_streamed(const Model *m, const char *dir, Err *err) {
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].streamed && !model_class_streamable(m, c) &&
        !(m->classes[c].coef && model_class_by_coefficients(m, c)))
      return err_set(err, "%s/manifest: class %s is marked streamed, but %s (a damaged or forged manifest; retrain)", dir,
                     m->classes[c].label,
                     model_class_needed(m, c) ? "the reduced model reads its basis" : "its rows run over one dim only");
  /* check_meta left NaN where no floor line was read */
  for (int c = 0; c < m->nclasses; c++)
    for (int k = 0; m->classes[c].streamed && k < m->classes[c].nmembers; k++)
      if (m->classes[c].members[k].q >= 0 && isnan(m->classes[c].members[k].floor_l2))
        return err_set(err, "%s/manifest: no floor line for %s, a quantity of the streamed class %s (a damaged or "
                                     "forged manifest; retrain)", dir, m->classes[c].members[k].name, m->classes[c].label);
  return 0;
}

/* The members' statistics and spectra (for reports) and the operators known
 * SPD, from the "member" and "spd" lines. */
static void read_member_stats(const ModelStore *s, Model *m) {
  for (int i = 0; i < s->nmeta; i++) {
    int c, cap, kept, center = 0;
    double energy, captured, lost = -1;
    char name[512];
    int got = sscanf(s->meta[i], "member %d %511s cap %d energy %lf kept %d captured %lf center %d lost %lf", &c, name,
                     &cap, &energy, &kept, &captured, &center, &lost);
    if (got >= 6 && c >= 0 && c < m->nclasses)
      for (int k = 0; k < m->classes[c].nmembers; k++)
        if (strcmp(m->classes[c].members[k].name, name) == 0) {
          RMember *mb = &m->classes[c].members[k];
          mb->cap = cap, mb->energy = energy, mb->kept = kept, mb->captured = captured;
          mb->center = got == 8 && center != 0;
          mb->lost = got == 8 ? lost : fmax(0, 1 - captured);
          char sname[600];
          snprintf(sname, sizeof sname, "spectrum_%s", name);
          const NpyArray *a = model_store_array(s, sname);
          free(mb->sv); /* a member named twice: the last line's spectrum */
          mb->sv = NULL, mb->nsv = 0;
          if (a && a->ndim == 1 && (mb->sv = mem_malloc(sizeof(double) * (a->count + 1)))) {
            memcpy(mb->sv, a->data, sizeof(double) * a->count);
            mb->nsv = (long)a->count;
          }
        }
    char stage[512];
    int t, k;
    if (sscanf(s->meta[i], "spd %511s %d %d", stage, &t, &k) == 3)
      for (int j = 0; j < m->nstages; j++)
        if (strcmp(m->stages[j].st->sym->name, stage) == 0 && t >= 0 && t < m->stages[j].nterms && k >= 0 &&
            k < m->stages[j].terms[t].nops)
          m->stages[j].terms[t].ops[k].spd = true;
  }
}

/* The reduced tensors, the named operators' projections and the externs'
 * learned maps (inputs and values), each checked against its shape. */
static int load_arrays(const ModelStore *s, Model *m, const char *dir, Err *err) {
  model_size_tensors(m);
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      char old[512];
      snprintf(old, sizeof old, "proj_%s_t%d", rs->st->sym->name, t);
      if (!rt->proj_name && rt->named_q >= 0 && model_store_array(s, old)) /* issue 41: DᵀB = I, no projection now */
        return err_set(err, "%s/%s.npy: the model reduced stage %s's application in a product as in the 2-norm (trained "
                       "before applications in a product were projected): retrain it", dir, old, rs->st->sym->name);
      if (rt->proj_name &&
          !(rt->proj = take(s, dir, rt->proj_name, m->classes[m->qclass[rs->q]].m,
                            m->classes[m->qclass[rt->named_q]].m, err)))
        return -1;
    }
  }
  FOR_TENSORS(m, x) {
    if (!(x->data = take(s, dir, x->name, x->rows, x->cols, err))) return -1;
  }
  for (int i = 0; i < m->nexterns; i++) {
    RExtern *x = &m->externs[i];
    char name[512];
    char values[512];
    snprintf(name, sizeof name, "extern_%s_inputs", qname(m, x->q));
    snprintf(values, sizeof values, "extern_%s_values", qname(m, x->q));
    /* one row per training sample in both files: when their counts differ, the one that is not the model's
     * sample count is the damaged file (a shortened inputs file was blamed on the values) */
    const NpyArray *a = model_store_array(s, name), *z = model_store_array(s, values);
    x->S = a && a->ndim == 2 ? a->shape[0] : 0;
    if (a && z && a->ndim == 2 && z->ndim == 2 && a->shape[0] != z->shape[0]) {
      bool inputs_bad = z->shape[0] == m->samples || a->shape[0] != m->samples;
      err_set(err, "%s/%s.npy: %ld rows, but %s.npy has %ld and the model %ld training samples: the learned "
              "map of extern '%s' needs one row per training sample in both files", dir, inputs_bad ? name : values,
              (long)(inputs_bad ? a : z)->shape[0], inputs_bad ? values : name, (long)(inputs_bad ? z : a)->shape[0],
              m->samples, qname(m, x->q));
      return -1;
    }
    if (!(x->X = take(s, dir, name, x->S, x->d, err))) return -1;
    if (!(x->Z = take(s, dir, values, x->S, m->classes[m->qclass[x->q]].m, err))) return -1;
  }
  return 0;
}

/* The model of store s into *mp (its layout, then every line and array checked and read;
 * half built on failure, for the caller's model_free), dims its scratch. -1 with `err`. */
static int load_model(ModelStore *s, Program *prog, const char *dir, long *dims, Model **mp, Err *err) {
  if (read_dims(s, prog, dir, dims, err) || !(*mp = model_layout(prog, dims, err))) return -1;
  Model *m = *mp;
  if (check_required(s, m, dir, err)) return -1;
  const char *ns = model_store_find(s, "samples");
  char *end = NULL;
  m->samples = strtol(ns, &end, 10);
  if (end == ns || *end || m->samples < 1)
    return err_set(err, "%s/manifest: 'samples %s' is not a count of training samples", dir, ns);
  if (!(m->param_hashes = mem_strdup(model_store_find(s, "params"))))
    return err_set(err, "%s: out of memory loading the model", dir);
  /* every metadata line the model reads must describe this model: a line
   * it cannot use is refused, not skipped */
  if (load_bases(s, m, dir, err) || model_named_projections(m, err) || check_meta(s, m, dir, err) ||
      interp_load(m, s, dir, err) ||
      check_streamed(m, dir, err))
    return -1;
  read_member_stats(s, m);
  return load_arrays(s, m, dir, err) || estimate_load(m, s, dir, err) ? -1 : 0;
}

Model *model_load(Program *prog, const char *dir, Err *err) {
  ModelStore s;
  if (model_store_read(dir, model_program_hash(prog), &s, err) != 0) return NULL;
  Model *m = NULL;
  Scratch sc = SCRATCH_OF(NULL);
  long *dims = scratch_array(&sc, (size_t)prog->dims.n + 1, sizeof(long));
  int rc = dims ? load_model(&s, prog, dir, dims, &m, err) : err_set(err, "%s: out of memory loading the model", dir);
  scratch_release(&sc);
  model_store_free(&s);
  if (rc == 0) return m;
  model_free(m); /* the half-built model, once */
  return NULL;
}

int model_write_spectra(const Model *m, const char *dir, Err *err) {
  if (mkdir(dir, 0777) != 0 && errno != EEXIST) return err_set(err, "%s: cannot create: %s", dir, strerror(errno));
  /* a model's spectra are files its manifest vouches for: writing another
   * model's over them would leave it unloadable (issue 24) */
  char manifest[4096];
  struct stat st;
  snprintf(manifest, sizeof manifest, "%s/manifest", dir);
  if (lstat(manifest, &st) == 0)
    return err_set(err, "%s: holds a model (its manifest): refusing to write spectra into it; give a folder of "
                   "its own", dir);
  /* Every name is checked before any file is written: a folder in the place
   * of the last spectrum would otherwise leave the first ones written. */
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++)
      for (int k = 0; k < 2; k++) {
        char path[4096];
        snprintf(path, sizeof path, "%s/spectrum_%s.%s", dir, m->classes[c].members[i].name, k ? "csv" : "npy");
        if (lstat(path, &st) == 0 && !S_ISREG(st.st_mode))
          return err_set(err, "%s: is not a regular file: refusing to replace it", path);
      }
  /* Every file is written to a temporary name first and renamed only when all of them are whole: a full
   * disk leaves the folder as it was (no spectrum_x.npy of this model beside a spectrum_y.npy of the last),
   * not a partial set or a partial file (issue 38). */
  int nfiles = 0;
  for (int c = 0; c < m->nclasses; c++) nfiles += 2 * m->classes[c].nmembers;
  Scratch sc = SCRATCH_OF(NULL);
  char(*paths)[2][4096] = scratch_array(&sc, (size_t)nfiles + 1, sizeof *paths); /* [k][0] the file, [k][1] its temporary */
  int written = 0, rc = paths ? 0 : err_set(err, "%s: out of memory writing the spectra", dir);
  for (int c = 0; c < m->nclasses && !rc; c++)
    for (int i = 0; i < m->classes[c].nmembers && !rc; i++) {
      const RMember *mb = &m->classes[c].members[i];
      long shape[1] = {mb->nsv};
      for (int k = 0; k < 2 && !rc; k++) {
        char *path = paths[written][0], *tmp = paths[written][1];
        snprintf(path, 4096, "%s/spectrum_%s.%s", dir, mb->name, k ? "csv" : "npy");
        snprintf(tmp, 4096, "%s/spectrum_%s.%s.part.%ld", dir, mb->name, k ? "csv" : "npy", (long)getpid());
        if (k == 0) {
          char why[1024];
          if (npy_write(tmp, NPY_F64, 1, shape, mb->sv, why, sizeof why) != 0) {
            /* npy_write names its temporary file; the user's is `path` */
            const char *cause = strrchr(why, ':');
            rc = err_set(err, "%s: cannot write: %s", path, cause ? cause + 2 : why);
          }
        } else {
          char *csv = scratch_adopt(&sc, spectrum_csv(mb));
          FILE *f = csv ? fopen(tmp, "w") : NULL;
          errno = csv ? errno : ENOMEM;
          int ok = f && fputs(csv, f) >= 0 && fflush(f) == 0;
          int saved = errno;
          if (f && fclose(f) != 0 && ok) ok = 0, saved = errno;
          if (!ok) rc = err_set(err, "%s: cannot write: %s", path, strerror(saved ? saved : EIO));
        }
        written++;
      }
    }
  for (int k = 0; k < written && !rc; k++)
    if (rename(paths[k][1], paths[k][0]) != 0)
      rc = err_set(err, "%s: cannot replace it with %s: %s", paths[k][0], paths[k][1], strerror(errno));
  if (rc)
    for (int k = 0; k < written; k++) remove(paths[k][1]); /* those renamed already are gone from here */
  scratch_release(&sc);
  return rc;
}
