/* truncate.c — a model at smaller basis sizes, without retraining (issue 41;
 * DESIGN §16).
 *
 * Class c keeps the first m'_c columns of its basis, B'_c = B_c[:, :m'_c].
 * A reduced tensor is a full tensor contracted with its output's and its
 * inputs' bases, T̂[r, a_1 … a_j] = Σ T[i, e_1 …] B_y[i, r] B_1[e_1, a_1] …,
 * so in the bases B' it is the block of the entries whose every basis index
 * is below the new sizes: the leading rows and columns of a plain axis, and
 * of a packed symmetric one (x ⊗ x, or the upper triangle of BᵀMB) the
 * multi-indices within (sym_leading). A product's dual K0B (issue 41) keeps
 * its leading columns as the basis does. Projections B_yᵀB_w, an extern's
 * table of reduced inputs and values, and a class kept as coefficients keep
 * their leading columns likewise. No entry is recomputed: the result equals
 * pre-multiplying by B' to rounding, and training at a cap of m' wherever
 * the first m' vectors are what that cap keeps. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "interp.h"
#include "model.h"
#include "scratch.h"

/* The old places of the new coordinates of an axis of a basis of m cut to
 * m2, the input repeated k times (k 1: the first m2). malloc'd, NULL when
 * out of memory. */
static long *axis_map(long m, int k, long m2) {
  long len = sym_len(m2, k), *map = mem_malloc(sizeof(long) * (size_t)(len + 1));
  if (!map) return NULL;
  if (k == 1)
    for (long a = 0; a < m2; a++) map[a] = a;
  else sym_leading(m, k, m2, map);
  return map;
}

/* t (laid out for m's sizes by model_size_tensors) the leading block of s
 * (of src), whose output class had my0 vectors (now my1). */
static int cut_tensor(const Model *src, const Model *m, const RTensor *s, RTensor *t, long my0, long my1) {
  long *amap[RT_MAX_IN] = {0}, stride[RT_MAX_IN], idx[RT_MAX_IN] = {0};
  if (!(t->data = mem_malloc(sizeof(double) * (size_t)(t->rows * t->cols + 1)))) return -1;
  Scratch sc = SCRATCH_OF(NULL); /* the maps of rows and axes */
  long *rmap = t->kind == RT_DIAG ? scratch_adopt(&sc, axis_map(my0, 2, my1))
                                  : scratch_array(&sc, (size_t)t->rows + 1, sizeof(long));
  if (rmap && t->kind != RT_DIAG)
    for (long r = 0; r < t->rows; r++) rmap[r] = t->kind == RT_NUM ? r : (r / my1) * my0 + r % my1; /* RT_DECL */
  int rc = rmap ? 0 : -1;
  for (int j = s->nin - 1; j >= 0 && rc == 0; j--) {
    long m0 = src->classes[src->qclass[s->in_q[j]]].m, m1 = m->classes[m->qclass[s->in_q[j]]].m;
    stride[j] = j == s->nin - 1 ? 1 : stride[j + 1] * s->in_len[j + 1];
    if (!(amap[j] = scratch_adopt(&sc, axis_map(m0, s->in_mult[j], m1)))) rc = -1;
  }
  for (long c = 0; rc == 0 && c < t->cols; c++) {
    long old = 0;
    for (int j = 0; j < s->nin; j++) old += amap[j][idx[j]] * stride[j];
    for (long r = 0; r < t->rows; r++) t->data[r * t->cols + c] = s->data[rmap[r] * s->cols + old];
    for (int j = s->nin - 1; j >= 0 && ++idx[j] == t->in_len[j]; j--) idx[j] = 0; /* the last axis fastest */
  }
  scratch_release(&sc);
  return rc;
}

static RInterp *copy_interp(const Model *src, const Model *m, const RStage *rs, const RInterp *s);

/* A copy of src's check table `s` (after a fit of kfit entries) for stage rs of m, its basis rows
 * (the stage's and each read's) cut to their first m columns of m's classes. NULL out of memory. */
static RInterp *copy_check(const Model *src, const Model *m, const RStage *rs, const RInterp *s, long kfit) {
  long m0 = src->classes[src->qclass[rs->q]].m, m1 = m->classes[m->qclass[rs->q]].m, len = 0;
  for (long r = 0; r < s->nreads; r++) len += m->classes[m->qclass[s->read_q[r]]].m;
  RInterp *ck = copy_interp(src, m, rs, s);
  if (!ck) return NULL;
  bool ok = (ck->brows = mem_malloc(sizeof(double) * (size_t)((kfit + s->k) * m1 + 1))) &&
            (ck->read_rows = mem_malloc(sizeof(double) * (size_t)(len + 1)));
  for (long r = 0; ok && r < kfit + s->k; r++) memcpy(ck->brows + r * m1, s->brows + r * m0, sizeof(double) * (size_t)m1);
  for (long r = 0, a = 0, b = 0; ok && r < s->nreads; r++) {
    long ma = src->classes[src->qclass[s->read_q[r]]].m, mb = m->classes[m->qclass[s->read_q[r]]].m;
    memcpy(ck->read_rows + b, s->read_rows + a, sizeof(double) * (size_t)mb);
    a += ma, b += mb;
  }
  if (ok && interp_pack(m, rs, ck) == 0) return ck;
  interp_free(ck); /* the half-built table, once */
  return NULL;
}

/* A copy of interpolated stage `s`'s fit for stage rs of m (its class the
 * same size), its packed tables rebuilt for m's bases. NULL out of memory. */
static RInterp *copy_interp(const Model *src, const Model *m, const RStage *rs, const RInterp *s) {
  RInterp *ip = mem_calloc(1, sizeof *ip);
  if (!ip) return NULL;
  ip->k = s->k, ip->m = s->m, ip->pinv_norm = s->pinv_norm, ip->nreads = s->nreads, ip->nmono = s->nmono;
  ip->rows = mem_malloc(sizeof(long) * (size_t)(s->k + 1));
  ip->pinv = mem_malloc(sizeof(double) * (size_t)(s->m * s->k + 1));
  ip->read_q = mem_malloc(sizeof(int) * (size_t)(s->nreads + 1));
  ip->read_e = mem_malloc(sizeof(long) * (size_t)(s->nreads + 1));
  ip->mono = mem_malloc(sizeof(RInterpMono) * (size_t)(s->nmono + 1));
  if (s->weight && (ip->weight = mem_malloc(sizeof(double) * (size_t)(s->k + 1))))
    memcpy(ip->weight, s->weight, sizeof(double) * (size_t)s->k);
  bool ok = ip->rows && ip->pinv && ip->read_q && ip->read_e && ip->mono && (!s->weight || ip->weight);
  if (ok) {
    memcpy(ip->rows, s->rows, sizeof(long) * (size_t)s->k);
    memcpy(ip->pinv, s->pinv, sizeof(double) * (size_t)(s->m * s->k));
    memcpy(ip->read_q, s->read_q, sizeof(int) * (size_t)s->nreads);
    memcpy(ip->read_e, s->read_e, sizeof(long) * (size_t)s->nreads);
    memcpy(ip->mono, s->mono, sizeof(RInterpMono) * (size_t)s->nmono);
  }
  if (ok && s->check) ok = (ip->check = copy_check(src, m, rs, s->check, s->k)) != NULL;
  if (ok && interp_pack(m, rs, ip) == 0) return ip;
  interp_free(ip); /* the half-built table, once */
  return NULL;
}

/* Class c of m: the first m->classes[c].m columns of src's, the members'
 * reports copied. */
static int cut_class(const RClass *s, RClass *t) {
  long m0 = s->m, m1 = t->m;
  t->streamed = s->streamed, t->floors_known = s->floors_known, t->coef_S = s->coef_S;
  for (int i = 0; i < t->nmembers; i++) {
    RMember *a = &t->members[i];
    const RMember *b = &s->members[i];
    a->cap = b->cap, a->energy = b->energy, a->center = b->center, a->kept = b->kept;
    a->captured = b->captured, a->lost = b->lost, a->floor_l2 = b->floor_l2, a->floor_linf = b->floor_linf;
    a->nsv = b->nsv;
    if (b->sv && !(a->sv = mem_malloc(sizeof(double) * (size_t)(b->nsv + 1)))) return -1;
    if (b->sv) memcpy(a->sv, b->sv, sizeof(double) * (size_t)b->nsv);
  }
  if (s->B) {
    if (!(t->B = mem_malloc(sizeof(double) * (size_t)(s->n * m1 + 1)))) return -1;
    for (long e = 0; e < s->n; e++) memcpy(t->B + e * m1, s->B + e * m0, sizeof(double) * (size_t)m1);
  }
  t->product = s->product, t->k0_norm1 = s->k0_norm1;
  if (s->D) { /* a product's dual K0 B: its leading columns are K0 B' */
    if (!(t->D = mem_malloc(sizeof(double) * (size_t)(s->n * m1 + 1)))) return -1;
    for (long e = 0; e < s->n; e++) memcpy(t->D + e * m1, s->D + e * m0, sizeof(double) * (size_t)m1);
  }
  if (s->coef) {
    if (!(t->coef = mem_malloc(sizeof(double) * (size_t)(s->coef_S * m1 + 1)))) return -1;
    for (long k = 0; k < s->coef_S; k++) memcpy(t->coef + k * m1, s->coef + k * m0, sizeof(double) * (size_t)m1);
  }
  return 0;
}

/* Stage i of m from src's: tensors, projections, operator marks, fit. */
static int cut_stage(const Model *src, Model *m, int i, Err *err) {
  const RStage *s = &src->stages[i];
  RStage *t = &m->stages[i];
  int c = m->qclass[t->q];
  long my0 = src->classes[c].m, my1 = m->classes[c].m;
  t->choice_err[0] = s->choice_err[0], t->choice_err[1] = s->choice_err[1], t->choice_reason = s->choice_reason;
  if (s->interp) {
    if (my1 != my0)
      return err_set(err, "class %s: stage '%s' is interpolated, its fit made for all %ld vectors of its "
                     "class; keep its size, or retrain at the smaller cap (--basis %s:cap=%ld)",
                     m->classes[c].bc->size_name, s->st->sym->name, my0, m->classes[c].bc->size_name, my1);
    if (!(t->interp = copy_interp(src, m, t, s->interp))) return err_set(err, "out of memory");
  }
  if (s->check && !(t->check = copy_check(src, m, t, s->check, 0))) return err_set(err, "out of memory");
  for (int k = 0; k < t->nterms; k++) {
    const RTerm *a = &s->terms[k];
    RTerm *b = &t->terms[k];
    for (int o = 0; o < b->nops; o++) b->ops[o].spd = a->ops[o].spd;
    if (a->proj) { /* B_yᵀB_w, m_y x m_w row-major */
      if (!b->proj_name && !(b->proj_name = mem_strdup(a->proj_name))) return err_set(err, "out of memory");
      long w0 = src->classes[src->qclass[a->named_q]].m, w1 = m->classes[m->qclass[a->named_q]].m;
      if (!(b->proj = mem_malloc(sizeof(double) * (size_t)(my1 * w1 + 1)))) return err_set(err, "out of memory");
      for (long r = 0; r < my1; r++) memcpy(b->proj + r * w1, a->proj + r * w0, sizeof(double) * (size_t)w1);
    }
    for (int g = -1; g < a->nops; g++)
      for (int j = 0; j < (g < 0 ? a->nnum : a->ops[g].ntensors); j++)
        if (cut_tensor(src, m, g < 0 ? &a->num[j] : &a->ops[g].t[j], g < 0 ? &b->num[j] : &b->ops[g].t[j], my0, my1))
          return err_set(err, "out of memory");
  }
  return 0;
}

/* Extern x of m: its table's leading columns, per input block and of its values. */
static int cut_extern(const Model *src, Model *m, int i) {
  const RExtern *s = &src->externs[i];
  RExtern *t = &m->externs[i];
  long z0 = src->classes[src->qclass[s->q]].m, z1 = m->classes[m->qclass[t->q]].m;
  t->S = s->S;
  t->X = mem_malloc(sizeof(double) * (size_t)(s->S * t->d + 1));
  t->Z = mem_malloc(sizeof(double) * (size_t)(s->S * z1 + 1));
  if (!t->X || !t->Z) return -1;
  for (long k = 0; k < s->S; k++) {
    for (int j = 0, o0 = 0, o1 = 0; j < s->nin; j++) {
      long a0 = src->classes[src->qclass[s->in_q[j]]].m, a1 = m->classes[m->qclass[s->in_q[j]]].m;
      memcpy(t->X + k * t->d + o1, s->X + k * s->d + o0, sizeof(double) * (size_t)a1);
      o0 += (int)a0, o1 += (int)a1;
    }
    memcpy(t->Z + k * z1, s->Z + k * z0, sizeof(double) * (size_t)z1);
  }
  return 0;
}

static int truncate_oom(Err *err) { return err_set(err, "out of memory making the model at smaller sizes"); }

/* m (laid out and sized) the leading blocks of src: bases, stages, externs. -1 with `err`. */
static int cut_model(const Model *src, Model *m, Err *err) {
  if (src->param_hashes && !(m->param_hashes = mem_strdup(src->param_hashes))) return truncate_oom(err);
  for (int c = 0; c < m->nclasses; c++)
    if (cut_class(&src->classes[c], &m->classes[c])) return truncate_oom(err);
  for (int i = 0; i < m->nstages; i++)
    if (cut_stage(src, m, i, err)) return -1;
  for (int i = 0; i < m->nexterns; i++)
    if (cut_extern(src, m, i)) return truncate_oom(err);
  return 0;
}

Model *model_truncate(const Model *src, const long *sizes, Err *err) {
  for (int c = 0; c < src->nclasses; c++)
    if (sizes[c] > src->classes[c].m || (sizes[c] == 0 && src->classes[c].m > 0))
      return err_set(err, "class %s has %ld basis vectors: a size of %ld is not between 1 and %ld",
                     src->classes[c].bc->size_name, src->classes[c].m, sizes[c], src->classes[c].m),
             NULL;
  Model *m = model_layout(src->prog, src->dims, err);
  if (!m) return NULL;
  for (int c = 0; c < m->nclasses; c++) m->classes[c].m = sizes[c] < 0 ? src->classes[c].m : sizes[c];
  model_size_tensors(m);
  m->samples = src->samples;
  m->self_check_sample = -1;
  if (cut_model(src, m, err) == 0) return m;
  model_free(m); /* the half-built model, once */
  return NULL;
}

/* Whether NAME names class c (--basis's names for a class, or a member). */
static bool names_class(const RClass *c, const char *name) {
  if (strcmp(name, c->label) == 0 || (c->bc->size_name && strcmp(name, c->bc->size_name) == 0)) return true;
  for (int k = 0; k < c->nmembers; k++)
    if (strcmp(name, c->members[k].name) == 0 || (strncmp(name, "m_", 2) == 0 && strcmp(name + 2, c->members[k].name) == 0))
      return true;
  return false;
}

int model_parse_sizes(const Model *m, const char *spec, long *sizes, Err *err) {
  for (int c = 0; c < m->nclasses; c++) sizes[c] = -1;
  const char *p = spec;
  while (*p) {
    const char *end = strchr(p, ','), *eq = strchr(p, '=');
    size_t len = end ? (size_t)(end - p) : strlen(p);
    char name[256];
    if (!eq || eq >= p + len || (size_t)(eq - p) >= sizeof name || eq == p)
      return err_set(err, "--sizes '%.*s': expected NAME=N (a class as `npgc check` names it, e.g. m_u)",
                     (int)len, p);
    memcpy(name, p, (size_t)(eq - p));
    name[eq - p] = 0;
    char *num_end;
    long v = strtol(eq + 1, &num_end, 10);
    if (num_end == eq + 1 || num_end != p + len || v < 1)
      return err_set(err, "--sizes %s: '%.*s' is not a whole number of at least 1", name,
                     (int)(p + len - eq - 1), eq + 1);
    int found = -1;
    for (int c = 0; c < m->nclasses && found < 0; c++)
      if (names_class(&m->classes[c], name)) found = c;
    if (found < 0) {
      char list[1024] = "";
      size_t at = 0;
      for (int c = 0; c < m->nclasses && at < sizeof list; c++)
        at += (size_t)snprintf(list + at, sizeof list - at, "%s%s %s", c ? ", " : "", m->classes[c].bc->size_name,
                               m->classes[c].label);
      return err_set(err, "--sizes %s: no class of that name; the classes: %s", name, list);
    }
    if (v > m->classes[found].m)
      return err_set(err, "--sizes %s=%ld: class %s has %ld basis vectors: give at most that (a smaller "
                     "size needs no retraining, a larger one does)", name, v, m->classes[found].bc->size_name,
                     m->classes[found].m);
    sizes[found] = v;
    p += len + (end ? 1 : 0);
  }
  return 0;
}
