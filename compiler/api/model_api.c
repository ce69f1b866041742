/* model_api.c — trained models and reduced evaluation through npg.h
 * (NpgModel, NpgReduced): loading and saving, what a model holds, inputs
 * set in full or reduced form, evaluation, lifting, and `output op`
 * operators in reduced form. */
#include <cblas.h>
#include <cblas.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include <time.h>
#include <unistd.h>

#include "api.h"
#include "estimate.h"
#include "interp.h"
#include "model_store.h"
#include "npy.h"
#include "compile.h"
#include "emit.h"

/* ---------------------------------------------------------------- helpers shared by the facade */

int api_quantity(const Program *prog, const char *name) {
  for (int i = 0; i < prog->quantities.n; i++)
    if (strcmp(((Sym *)prog->quantities.v[i])->name, name) == 0) return i;
  return -1;
}

int api_shape(const Full *f, const Sym *s, long *shape) {
  int nd = 0;
  for (int i = 0; i < s->ndims; i++) shape[nd++] = full_dim(f, s->dims[i]->name);
  for (int i = 0; i < s->nstatic; i++) shape[nd++] = s->shape[i];
  return nd;
}

int api_reduced_not_finite(const Model *m, Reduced *r, long sample, char *err, size_t errlen) {
  for (int q = 0; q < m->nq; q++) {
    const double *x = reduced_coords(r, q);
    for (long i = 0; i < m->classes[m->qclass[q]].m; i++)
      if (!isfinite(x[i])) {
        const Sym *s = m->prog->quantities.v[q];
        snprintf(err, errlen, "sample %ld: the reduced %s '%s' is not finite (coordinate %ld is %s)", sample,
                 s->kind == SYM_INPUT ? "input" : s->kind == SYM_EXTERN ? "extern" : "stage", s->name, i,
                 isnan(x[i]) ? "NaN" : "an infinity");
        return -1;
      }
  }
  return 0;
}

/* ---------------------------------------------------------------- models */

int npg_model_stage_interpolated(const NpgModel *nm, const char *stage, long *entries) {
  if (!nm || !nm->m || !stage) return -1;
  for (int i = 0; i < nm->m->nstages; i++) {
    const RStage *rs = &nm->m->stages[i];
    if (strcmp(rs->st->sym->name, stage) != 0) continue;
    if (entries) *entries = rs->interp ? rs->interp->k : 0;
    return rs->interp != NULL;
  }
  return -1;
}

void npg_model_report_reductions(const NpgModel *nm, FILE *out) {
  if (nm && nm->m && out) interp_report(nm->m, out);
}

NpgModel *api_model_wrap(Model *m) {
  NpgModel *nm = mem_calloc(1, sizeof *nm);
  if (!nm) {
    model_free(m);
    return NULL;
  }
  nm->m = m;
  return nm;
}

/* The hash of the param named `key` ("name=") in the `recorded` "name=<hex>
 * ..." of a model, or NULL. */
static const char *param_hash_at(const char *recorded, const char *key) {
  const char *at = recorded;
  while ((at = strstr(at, key)) && at != recorded && at[-1] != ' ') at++;
  return at;
}

/* A model trained through npg.h records the hash of every param it was
 * trained with, so that other params can be refused: a 'params' line that
 * lacks one is damaged (model_load refuses a manifest without the line). */
static int missing_param_hash(NpgModel *nm, const char *dir) {
  const Program *prog = nm->m->prog;
  for (int i = 0; nm->m->param_hashes && i < prog->params.n; i++) {
    const char *name = ((const Sym *)prog->params.v[i])->name;
    char key[512];
    snprintf(key, sizeof key, "%s=", name);
    if (!param_hash_at(nm->m->param_hashes, key)) {
      snprintf(nm->error, sizeof nm->error,
               "%s/manifest: no hash of param '%s' in its 'params' line: the model is damaged; retrain", dir, name);
      return -1;
    }
  }
  return 0;
}

/* `n` values of the model file DIR/`name`.npy (`name` printf'd): -1 after a
 * message naming the first that is not finite. */
__attribute__((format(printf, 5, 6))) static int finite_array(NpgModel *nm, const char *dir, const double *v, long n,
                                                              const char *name, ...) {
  for (long e = 0; v && e < n; e++)
    if (!isfinite(v[e])) {
      char file[512];
      va_list ap;
      va_start(ap, name);
      vsnprintf(file, sizeof file, name, ap);
      va_end(ap);
      snprintf(nm->error, sizeof nm->error,
               "%s/%s.npy: holds %s at flat entry %ld: a model's arrays are finite (the file is damaged; retrain)",
               dir, file, isnan(v[e]) ? "NaN" : "an infinity", e);
      return -1;
    }
  return 0;
}

/* Training refuses non-finite values, so a model never holds one: a NaN in
 * a basis or tensor would only come out as NaN results far from its cause. */
static int nonfinite_array(NpgModel *nm, const char *dir) {
  const Model *m = nm->m;
  for (int c = 0; c < m->nclasses; c++)
    if (!m->classes[c].streamed && finite_array(nm, dir, m->classes[c].B, m->classes[c].n * m->classes[c].m, "basis_%d", c)) return -1;
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].D && finite_array(nm, dir, m->classes[c].D, m->classes[c].n * m->classes[c].m, "dual_%d", c))
      return -1;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      if (rt->proj && finite_array(nm, dir, rt->proj, m->classes[m->qclass[m->stages[i].q]].m *
                                                          m->classes[m->qclass[rt->named_q]].m, "%s", rt->proj_name))
        return -1;
      RTERM_FOR_TENSORS(rt, x) {
        if (finite_array(nm, dir, x->data, x->rows * x->cols, "%s", x->name)) return -1;
      }
    }
  for (int i = 0; i < m->nexterns; i++) {
    const RExtern *x = &m->externs[i];
    const char *name = ((const Sym *)m->prog->quantities.v[x->q])->name;
    if (finite_array(nm, dir, x->X, x->S * x->d, "extern_%s_inputs", name) ||
        finite_array(nm, dir, x->Z, x->S * m->classes[m->qclass[x->q]].m, "extern_%s_values", name))
      return -1;
  }
  return 0;
}

NpgModel *npg_model_load(NpgProgram *p, const char *dir) {
  NpgModel *nm = mem_calloc(1, sizeof *nm);
  if (!nm) return api_refuse(NULL, 0, __func__, "out of memory"), NULL; /* what npg_model_error(NULL) says */
  if (!p || !dir) api_refuse(nm->error, sizeof nm->error, __func__, "argument '%s' is NULL", !p ? "p" : "dir");
  else if (!npg_ok(p)) snprintf(nm->error, sizeof nm->error, "%s", npg_error(p));
  else if (!(nm->m = model_load(program_ir(p), dir, ERR_OF(nm->error, sizeof nm->error))) && !nm->error[0])
    snprintf(nm->error, sizeof nm->error, "%s: cannot load the model", dir);
  else if (nm->m && (missing_param_hash(nm, dir) != 0 || nonfinite_array(nm, dir) != 0)) {
    model_free(nm->m);
    nm->m = NULL;
  }
  return nm;
}

const char *npg_model_error(const NpgModel *m) {
  return m ? m->error : api_refusal()[0] ? api_refusal() : "out of memory";
}

/* The argument checks of the npg_model_ entry points (api.h): the model,
 * then pointer arguments into its message (or `err` where one is given). */
#define REFUSE_NULL_M(ret) API_REFUSE_NULL(nm, NULL, 0, ret)

int npg_model_save(NpgModel *nm, const char *dir) {
  REFUSE_NULL_M(-1);
  API_REFUSE_NULL(dir, nm->error, sizeof nm->error, -1);
  if (!nm->m) return -1;
  return model_save(nm->m, dir, ERR_OF(nm->error, sizeof nm->error)) == 0 ? 0 : -1;
}

void npg_model_free(NpgModel *nm) {
  if (!nm) return;
  model_free(nm->m);
  free(nm);
}

int npg_model_nclasses(const NpgModel *nm) {
  REFUSE_NULL_M(-1);
  return nm->m ? nm->m->nclasses : 0;
}

/* One spectrum per member line of the manifest: "member C NAME cap N energy
 * E kept K captured X [center 0|1 lost L]". */
int npg_spectra_read(const char *dir, NpgSpectrum **out, int *count, char *err, size_t errlen) {
  API_REFUSE_NULL(dir, err, errlen, -1);
  API_REFUSE_NULL(out, err, errlen, -1);
  API_REFUSE_NULL(count, err, errlen, -1);
  ModelStore st;
  *out = NULL;
  *count = 0;
  if (model_store_read_any(dir, &st, ERR_OF(err, errlen)) != 0) return -1;
  NpgSpectrum *sp = mem_calloc((size_t)st.nmeta + 1, sizeof *sp);
  int n = 0, rc = sp ? 0 : -1;
  if (!sp) snprintf(err, errlen, "out of memory");
  for (int i = 0; i < st.nmeta && rc == 0; i++) {
    int c, cap, kept, center = 0;
    double energy, captured, lost;
    char name[512], aname[600];
    int got = sscanf(st.meta[i], "member %d %511s cap %d energy %lf kept %d captured %lf center %d lost %lf", &c, name,
                     &cap, &energy, &kept, &captured, &center, &lost);
    if (got < 6) continue;
    snprintf(aname, sizeof aname, "spectrum_%s", name);
    const NpyArray *a = model_store_array(&st, aname);
    if (!a || a->ndim != 1) {
      snprintf(err, errlen, "%s/manifest: member %s has no spectrum (a model trained before spectra were kept: "
                            "retrain it)", dir, name);
      rc = -1;
      break;
    }
    NpgSpectrum *x = &sp[n];
    x->member = mem_strdup(name);
    x->sigma = mem_malloc(sizeof(double) * (a->count ? a->count : 1));
    if (!x->member || !x->sigma) {
      snprintf(err, errlen, "out of memory");
      rc = -1;
    } else {
      memcpy(x->sigma, a->data, sizeof(double) * a->count);
      x->n = (long)a->count;
      x->kept = kept;
      x->cap = cap;
      x->centered = got == 8 && center;
    }
    n++;
  }
  model_store_free(&st);
  if (rc != 0) {
    npg_spectra_free(sp, n);
    return -1;
  }
  *out = sp;
  *count = n;
  return 0;
}

void npg_spectra_free(NpgSpectrum *s, int count) {
  for (int i = 0; s && i < count; i++) free(s[i].member), free(s[i].sigma);
  free(s);
}

void npg_model_report(const NpgModel *nm, FILE *out) {
  REFUSE_NULL_M();
  API_REFUSE_NULL(out, NULL, 0, );
  if (nm->m) report_training(nm->m, out);
}

int npg_model_write_spectra(const NpgModel *nm, const char *dir, char *err, size_t errlen) {
  API_REFUSE_NULL(nm, err, errlen, -1);
  API_REFUSE_NULL(dir, err, errlen, -1);
  if (!nm->m) {
    snprintf(err, errlen, "%s", nm->error);
    return -1;
  }
  return model_write_spectra(nm->m, dir, ERR_OF(err, errlen));
}

int npg_model_class(const NpgModel *nm, int c, NpgClassInfo *out) {
  REFUSE_NULL_M(-1);
  API_REFUSE_NULL(out, NULL, 0, -1);
  if (!nm->m) return -1;
  if (c < 0 || c >= nm->m->nclasses) {
    /* The message goes where npg_model_error reads it; `nm` is const only to
     * say the model is not changed (every NpgModel is allocated, never const). */
    NpgModel *w = (NpgModel *)nm;
    snprintf(w->error, sizeof w->error, "npg_model_class: class %d does not exist (the model has %d, 0..%d)", c,
             nm->m->nclasses, nm->m->nclasses - 1);
    return -1;
  }
  const RClass *rc = &nm->m->classes[c];
  *out = (NpgClassInfo){rc->label, rc->n, rc->m, rc->nmembers};
  return 0;
}

int npg_model_member(const NpgModel *nm, int c, int i, NpgMemberInfo *out) {
  REFUSE_NULL_M(-1);
  API_REFUSE_NULL(out, NULL, 0, -1);
  if (!nm->m || c < 0 || c >= nm->m->nclasses || i < 0 || i >= nm->m->classes[c].nmembers) return -1;
  const RMember *mb = &nm->m->classes[c].members[i];
  *out = (NpgMemberInfo){mb->name, mb->kept, mb->cap, mb->captured};
  return 0;
}

int npg_model_class_of(const NpgModel *nm, const char *quantity) {
  REFUSE_NULL_M(-1);
  API_REFUSE_NULL(quantity, NULL, 0, -1);
  if (!nm->m) return -1;
  int q = api_quantity(nm->m->prog, quantity);
  return q < 0 ? -1 : nm->m->qclass[q];
}

const double *npg_model_basis(const NpgModel *nm, int c) {
  REFUSE_NULL_M(NULL);
  return nm->m && c >= 0 && c < nm->m->nclasses ? nm->m->classes[c].B : NULL;
}

const double *npg_model_dual(const NpgModel *nm, int c) {
  REFUSE_NULL_M(NULL);
  return nm->m && c >= 0 && c < nm->m->nclasses ? nm->m->classes[c].D : NULL;
}

const double *npg_model_coefficients(const NpgModel *nm, int c, long *samples) {
  if (samples) *samples = 0;
  REFUSE_NULL_M(NULL);
  if (!nm->m || c < 0 || c >= nm->m->nclasses || !nm->m->classes[c].coef) return NULL;
  if (samples) *samples = nm->m->classes[c].coef_S;
  return nm->m->classes[c].coef;
}

size_t npg_model_bytes(const NpgModel *nm, size_t *tensor_bytes) {
  if (tensor_bytes) *tensor_bytes = 0;
  REFUSE_NULL_M(0);
  size_t tb = 0, total = nm->m ? model_bytes(nm->m, &tb) : 0;
  if (tensor_bytes) *tensor_bytes = tb;
  return total;
}

long npg_model_samples(const NpgModel *nm) {
  REFUSE_NULL_M(-1);
  return nm->m ? nm->m->samples : 0;
}

long npg_model_dim(const NpgModel *nm, const char *name) {
  REFUSE_NULL_M(-1);
  API_REFUSE_NULL(name, NULL, 0, -1);
  if (!nm->m) return -1;
  const Program *prog = nm->m->prog;
  for (int i = 0; i < prog->dims.n; i++)
    if (strcmp(((Sym *)prog->dims.v[i])->name, name) == 0) return nm->m->dims[i];
  return -1;
}

int npg_model_check_params(const NpgModel *nm, const NpgFull *f, char *err, size_t errlen) {
  API_REFUSE_NULL(nm, err, errlen, -1);
  API_REFUSE_NULL(f, err, errlen, -1);
  if (!full_program(f->full)) return error_set(err, errlen, "%s", npg_full_error(f));
  const char *recorded = nm->m ? nm->m->param_hashes : NULL;
  if (!recorded) return 0;
  const Program *prog = full_program(f->full);
  for (int i = 0; i < prog->params.n; i++) {
    const Sym *p = prog->params.v[i];
    char key[512];
    snprintf(key, sizeof key, "%s=", p->name);
    const char *at = recorded;
    while ((at = strstr(at, key)) && at != recorded && at[-1] != ' ') at++;
    const char *from;
    uint64_t h = full_param_hash(f->full, i, &from);
    if (!at || strtoull(at + strlen(key), NULL, 16) != h) {
      snprintf(err, errlen, "%s: param '%s' differs from the one the model was trained with: retrain, or give the "
                            "training data's params", from, p->name);
      return -1;
    }
  }
  return 0;
}

/* The param files of DIR that exist against the hashes `recorded`. */
static int check_params_dir(const Program *prog, const char *recorded, const char *dir, char *err, size_t errlen) {
  for (int i = 0; i < prog->params.n; i++) {
    const Sym *p = prog->params.v[i];
    char path[4096], key[512];
    snprintf(path, sizeof path, "%s/%s.npy", dir, p->name);
    if (access(path, F_OK) != 0) continue;
    NpyArray a;
    if (npy_read(path, &a, err, errlen) != 0) return -1;
    double *v = mem_malloc(sizeof(double) * (a.count ? a.count : 1));
    if (!v) {
      npy_free(&a);
      snprintf(err, errlen, "out of memory");
      return -1;
    }
    for (size_t e = 0; e < a.count; e++)
      v[e] = a.type == NPY_F64 ? ((double *)a.data)[e]
             : a.type == NPY_I32 ? (double)((int32_t *)a.data)[e]
                                 : (double)((int64_t *)a.data)[e];
    uint64_t h = full_hash_values(v, a.count);
    free(v);
    npy_free(&a);
    snprintf(key, sizeof key, "%s=", p->name);
    const char *at = recorded;
    while ((at = strstr(at, key)) && at != recorded && at[-1] != ' ') at++;
    if (!at || strtoull(at + strlen(key), NULL, 16) != h) {
      snprintf(err, errlen, "%s: param '%s' differs from the one the model was trained with: retrain, or give the "
                            "training data's params", path, p->name);
      return -1;
    }
  }
  return 0;
}

int npg_model_check_params_dir(const NpgModel *nm, const char *dir, char *err, size_t errlen) {
  API_REFUSE_NULL(nm, err, errlen, -1);
  API_REFUSE_NULL(dir, err, errlen, -1);
  const char *recorded = nm->m ? nm->m->param_hashes : NULL;
  return recorded ? check_params_dir(nm->m->prog, recorded, dir, err, errlen) : 0;
}

int npg_full_check_params_dir(const NpgFull *f, const char *dir, char *err, size_t errlen) {
  API_REFUSE_NULL(f, err, errlen, -1);
  API_REFUSE_NULL(dir, err, errlen, -1);
  if (!full_program(f->full)) return error_set(err, errlen, "%s", npg_full_error(f));
  char *recorded = train_param_hashes(f->full);
  if (!recorded) {
    snprintf(err, errlen, "out of memory");
    return -1;
  }
  int rc = check_params_dir(full_program(f->full), recorded, dir, err, errlen);
  free(recorded);
  return rc;
}

int npg_model_emit(const NpgModel *nm, FILE *out, char *err, size_t errlen) {
  API_REFUSE_NULL(nm, err, errlen, -1);
  API_REFUSE_NULL(out, err, errlen, -1);
  if (!nm->m) {
    snprintf(err, errlen, "%s", nm->error);
    return -1;
  }
  return emit_reduced(nm->m, out, ERR_OF(err, errlen));
}

/* ---------------------------------------------------------------- reduced evaluation */

#define rfail(r, ...) error_set_first((r)->error, sizeof (r)->error, __VA_ARGS__)

NpgReduced *npg_reduced_new(const NpgModel *nm) {
  NpgReduced *r = mem_calloc(1, sizeof *r);
  if (!r) return api_refuse(NULL, 0, __func__, "out of memory"), NULL; /* what npg_reduced_error(NULL) says */
  r->nm = nm;
  if (!nm) api_refuse(r->error, sizeof r->error, __func__, "argument 'm' is NULL");
  else if (!nm->m) rfail(r, "%s", nm->error[0] ? nm->error : "the model holds nothing");
  else if (!(r->given = mem_calloc((size_t)nm->m->nq + 1, sizeof *r->given)) ||
           !(r->in_err = mem_calloc((size_t)nm->m->nq + 1, sizeof *r->in_err)))
    rfail(r, "out of memory");
  else if (!(r->r = reduced_new(nm->m, ERR_OF(r->error, sizeof r->error))) && !r->error[0]) rfail(r, "out of memory");
  if (r->r) reduced_krylov_roots(r->r, true);
  return r;
}

NpgModel *npg_model_at_sizes(const NpgModel *nm, const char *sizes) {
  NpgModel *out = mem_calloc(1, sizeof *out);
  if (!out) return api_refuse(NULL, 0, __func__, "out of memory"), NULL;
  if (!nm) return api_refuse(out->error, sizeof out->error, __func__, "argument 'm' is NULL"), out;
  if (!nm->m) return snprintf(out->error, sizeof out->error, "%s", nm->error[0] ? nm->error : "the model holds nothing"), out;
  long *n = mem_calloc((size_t)nm->m->nclasses + 1, sizeof(long));
  if (!n) return snprintf(out->error, sizeof out->error, "out of memory"), out;
  if (model_parse_sizes(nm->m, sizes ? sizes : "", n, ERR_OF(out->error, sizeof out->error)) == 0)
    out->m = model_truncate(nm->m, n, ERR_OF(out->error, sizeof out->error));
  free(n);
  return out;
}

NpgReduced *npg_reduced_new_sizes(const NpgModel *nm, const char *sizes) {
  if (!nm || !nm->m || !sizes || !*sizes) return npg_reduced_new(nm);
  NpgModel *own = npg_model_at_sizes(nm, sizes);
  if (!own) return api_refuse(NULL, 0, __func__, "out of memory"), NULL;
  NpgReduced *r = npg_reduced_new(own);
  if (!r) return npg_model_free(own), NULL;
  r->own = own; /* r->nm: the model at those sizes */
  return r;
}

const char *npg_reduced_error(const NpgReduced *r) {
  if (!r) return api_refusal()[0] ? api_refusal() : "out of memory";
  if (r->error[0] || !r->r) return r->error;
  return reduced_error(r->r);
}

/* The evaluator's own error (an unknown name) or the one a stage recorded. */
static bool failed(const NpgReduced *r) { return npg_reduced_error(r)[0] != 0; }

/* The argument checks of the npg_reduced_ entry points (api.h). */
#define REFUSE_NULL_R(ret) API_REFUSE_NULL(r, NULL, 0, ret)
#define REFUSE_NULL(arg) API_REFUSE_NULL(arg, r->error, sizeof r->error, -1)

void npg_reduced_clear_error(NpgReduced *r) {
  REFUSE_NULL_R();
  if (!r->r) return; /* an evaluator without a model keeps its error */
  r->error[0] = 0;
  if (!r->r || !reduced_error(r->r)[0]) return;
  /* a fresh evaluator with the same coordinates */
  Model *m = r->nm->m;
  Reduced *n = reduced_new(m, ERR_OF(r->error, sizeof r->error));
  if (!n) return;
  for (int q = 0; q < m->nq; q++)
    memcpy(reduced_coords(n, q), reduced_coords(r->r, q), sizeof(double) * (size_t)m->classes[m->qclass[q]].m);
  reduced_use_given_externs(n, r->given_externs);
  reduced_krylov_roots(n, !r->exact_roots);
  reduced_free(r->r);
  r->r = n;
  r->est_fresh = false;
}

/* Quantity `name` that the caller may set: an input, or an extern when
 * externs are given. -1 after recording why not. */
static int settable(NpgReduced *r, const char *name) {
  const Model *m = r->nm->m;
  int q = api_quantity(m->prog, name);
  if (q < 0) return rfail(r, "the program has no quantity '%s'", name);
  const Sym *s = m->prog->quantities.v[q];
  if (s->kind == SYM_INPUT || (s->kind == SYM_EXTERN && r->given_externs)) return q;
  return rfail(r, "'%s' is %s: only inputs%s are set", name, s->kind == SYM_EXTERN ? "an extern" : "a stage",
               s->kind == SYM_EXTERN ? " (and externs after npg_reduced_given_externs)" : " and externs");
}

/* Why quantity `name` of streamed class `c` cannot be `what` (model.h, issue 30). */
static const char *streamed_message(const RClass *c, const char *name, const char *what) {
  static _Thread_local char msg[640];
  if (c->coef)
    snprintf(msg, sizeof msg, "'%s' cannot be %s: the basis of its class %s is kept as coefficients of its %ld training "
             "values, not whole (issue 30); give its coordinates Cᵀ(Xᵀv) with npg_reduced_set_coords (C: "
             "npg_model_coefficients; Xᵀv: npg_trainer_dots), or retrain with --keep-bases %s", name, what, c->label,
             c->coef_S, name);
  else
    snprintf(msg, sizeof msg, "'%s' cannot be %s: the basis of its class %s was streamed in training and not kept in "
             "the model (its reduced coordinates remain: npg_reduced_coords); retrain with --keep-bases %s to keep it",
             name, what, c->label, name);
  return msg;
}

/* ‖x − B x̂‖ of input q just projected (O(n m), as the projection), 0 within its roundoff
 * (64 ε √n ‖x‖): a basis that holds x is exact; NaN when out of memory. In a class with a product K0 the
 * estimates are in K0's norm: the bound √‖K0‖₁ ‖x − B x̂‖₂ ≥ ‖x − B x̂‖_K0 (K0 is not in the model; ‖K0‖₁ ≥
 * λ_max(K0) stored at training, RClass.k0_norm1), NaN off the basis in a model trained before it was stored. */
static double input_error(NpgReduced *r, int q, const RClass *c, const double *x) {
  double *y = mem_malloc(sizeof(double) * (size_t)c->n + 1);
  if (!y) return NAN;
  reduced_lift(r->r, q, y);
  double d = 0, xn = 0;
  for (long i = 0; i < c->n; i++) d += (x[i] - y[i]) * (x[i] - y[i]), xn += x[i] * x[i];
  free(y);
  d = sqrt(d);
  if (d <= 64 * DBL_EPSILON * sqrt((double)c->n) * sqrt(xn)) return 0;
  return !c->product ? d : c->k0_norm1 > 0 ? sqrt(c->k0_norm1) * d : NAN;
}

int npg_reduced_set(NpgReduced *r, const char *name, size_t count, const double *values) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(values);
  if (failed(r)) return -1;
  int q = settable(r, name);
  if (q < 0) return -1;
  const RClass *c = &r->nm->m->classes[r->nm->m->qclass[q]];
  if (c->streamed) return rfail(r, "%s", streamed_message(c, name, "projected"));
  if ((long)count != c->n)
    return rfail(r, "'%s' has %ld entries in the model, %zu were given", name, c->n, count);
  for (size_t i = 0; i < count; i++)
    if (!isfinite(values[i]))
      return rfail(r, "'%s' holds %s at flat entry %zu", name, isnan(values[i]) ? "NaN" : "an infinity", i);
  reduced_project(r->r, q, values);
  r->in_err[q] = input_error(r, q, c, values);
  r->given[q] = true;
  if (((const Sym *)r->nm->m->prog->quantities.v[q])->next) r->roll.steps = 0; /* a new rollout */
  return 0;
}

int npg_reduced_set_coords(NpgReduced *r, const char *name, size_t m, const double *coords) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(coords);
  if (failed(r)) return -1;
  int q = settable(r, name);
  if (q < 0) return -1;
  const RClass *c = &r->nm->m->classes[r->nm->m->qclass[q]];
  if ((long)m != c->m) return rfail(r, "'%s' has %ld reduced coordinates (class %s), %zu were given", name, c->m,
                                    c->label, m);
  for (size_t i = 0; i < m; i++) /* as npg_reduced_set refuses them in full (a lift returned NaN silently) */
    if (!isfinite(coords[i]))
      return rfail(r, "the coordinates of '%s' hold %s at entry %zu", name, isnan(coords[i]) ? "NaN" : "an infinity",
                   i);
  memcpy(reduced_coords(r->r, q), coords, sizeof(double) * m);
  r->in_err[q] = 0;
  r->given[q] = true;
  if (((const Sym *)r->nm->m->prog->quantities.v[q])->next) r->roll.steps = 0; /* a new rollout */
  return 0;
}

void npg_reduced_exact_roots(NpgReduced *r, bool on) {
  REFUSE_NULL_R();
  r->exact_roots = on;
  if (r->r) reduced_krylov_roots(r->r, !on);
}

void npg_reduced_given_externs(NpgReduced *r, bool on) {
  REFUSE_NULL_R();
  r->given_externs = on;
  if (r->r) reduced_use_given_externs(r->r, on);
}

int npg_reduced_eval(NpgReduced *r, long sample) {
  REFUSE_NULL_R(-1);
  if (failed(r)) return -1;
  const Model *m = r->nm->m;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = m->prog->quantities.v[q];
    if (!r->given[q] && (s->kind == SYM_INPUT || (s->kind == SYM_EXTERN && r->given_externs)))
      return rfail(r, "sample %ld: %s '%s' was never set (npg_reduced_set or npg_reduced_set_coords)", sample,
                   s->kind == SYM_INPUT ? "input" : "extern", s->name);
  }
  r->est_fresh = false;
  if (reduced_eval(r->r, sample) != 0) return -1;
  char msg[512];
  if (api_reduced_not_finite(r->nm->m, r->r, sample, msg, sizeof msg)) return rfail(r, "%s", msg);
  r->evaluated = true;
  return 0;
}

const double *npg_reduced_coords(const NpgReduced *r, const char *name, size_t *m) {
  REFUSE_NULL_R(NULL);
  API_REFUSE_NULL(name, NULL, 0, NULL);
  if (!r->r) return NULL;
  const Model *mo = r->nm->m;
  int q = api_quantity(mo->prog, name);
  if (q < 0) return NULL;
  /* Coordinates never computed are not zeros (npg_reduced_lift refuses the same). */
  if (!r->evaluated && !r->given[q]) return NULL;
  if (m) *m = (size_t)mo->classes[mo->qclass[q]].m;
  return reduced_coords(r->r, q);
}

int npg_reduced_lift(NpgReduced *r, const char *name, double *out, size_t count) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(out);
  if (failed(r)) return -1;
  const Model *m = r->nm->m;
  int q = api_quantity(m->prog, name);
  if (q < 0) return rfail(r, "the program has no quantity '%s'", name);
  if (!r->evaluated && !r->given[q])
    return rfail(r, "'%s' has no value to lift: it was not set and nothing was evaluated yet (npg_reduced_eval)", name);
  const RClass *c = &m->classes[m->qclass[q]];
  if (c->streamed) return rfail(r, "%s", streamed_message(c, name, "lifted"));
  if ((long)count != c->n) return rfail(r, "'%s' has %ld entries, a buffer of %zu was given", name, c->n, count);
  reduced_lift(r->r, q, out);
  return 0;
}

int npg_reduced_lift_many(NpgReduced *r, const char *name, size_t samples, size_t m, const double *coords,
                          double *out, size_t count) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(coords);
  REFUSE_NULL(out);
  if (failed(r)) return -1;
  const Model *mo = r->nm->m;
  int q = api_quantity(mo->prog, name);
  if (q < 0) return rfail(r, "the program has no quantity '%s'", name);
  const RClass *c = &mo->classes[mo->qclass[q]];
  if (c->streamed) return rfail(r, "%s", streamed_message(c, name, "lifted"));
  if (samples < 1 || samples > INT_MAX / 2)
    return rfail(r, "npg_reduced_lift_many: 'samples' is %zu: give 1 to %d sets of coordinates", samples, INT_MAX / 2);
  if ((long)m != c->m)
    return rfail(r, "'%s' has %ld reduced coordinates (class %s), %zu were given", name, c->m, c->label, m);
  if ((long)count != c->n) return rfail(r, "'%s' has %ld entries, a buffer of %zu per sample was given", name, c->n, count);
  for (size_t i = 0; i < samples * m; i++) /* as npg_reduced_set_coords refuses them */
    if (!isfinite(coords[i]))
      return rfail(r, "the coordinates of '%s' hold %s at sample %zu, entry %zu", name,
                   isnan(coords[i]) ? "NaN" : "an infinity", i / m, i % m);
  reduced_lift_many(mo, q, (long)samples, coords, out);
  return 0;
}

/* z = z_1 ⊗ … ⊗ z_n over the tensor's input axes (packed powers for
 * repeated inputs): the column vector its rows are contracted with. */
static int input_product(NpgReduced *r, const RTensor *t) {
  long len = 1;
  for (int j = 0; j < t->nin; j++) len *= t->in_len[j];
  if (len > r->zcap) {
    double *z = mem_realloc(r->z, sizeof(double) * (size_t)(2 * len));
    if (!z) return rfail(r, "out of memory");
    r->z = z;
    r->zcap = len;
  }
  double *z = r->z, *next = r->z + len;
  z[0] = 1;
  long have = 1;
  const Model *m = r->nm->m;
  for (int j = 0; j < t->nin; j++) {
    long mj = m->classes[m->qclass[t->in_q[j]]].m;
    const double *x = reduced_coords(r->r, t->in_q[j]);
    double *packed = NULL;
    if (t->in_mult[j] > 1) {
      if (!(packed = mem_malloc(sizeof(double) * (size_t)t->in_len[j]))) return rfail(r, "out of memory");
      sym_power(mj, t->in_mult[j], x, packed);
      x = packed;
    }
    for (long a = 0; a < have; a++)
      for (long b = 0; b < t->in_len[j]; b++) next[a * t->in_len[j] + b] = z[a] * x[b];
    have *= t->in_len[j];
    memcpy(z, next, sizeof(double) * (size_t)have);
    free(packed);
  }
  return 0;
}

int npg_reduced_op(NpgReduced *r, const char *name, double *out, size_t cap, long *rows, long *cols, int *row_class,
                   int *col_class) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(out);
  REFUSE_NULL(rows);
  REFUSE_NULL(cols);
  if (failed(r)) return -1;
  const Model *m = r->nm->m;
  const RStage *rs = NULL;
  const ROp *ro = NULL;
  for (int i = 0; i < m->nstages && !ro; i++)
    for (int t = 0; t < m->stages[i].nterms && !ro; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops && !ro; k++) {
        const ROp *x = &m->stages[i].terms[t].ops[k];
        if (x->op->kind == OPK_DECL && strcmp(x->op->op->name, name) == 0) rs = &m->stages[i], ro = x;
      }
  if (!ro) return rfail(r, "'%s' is not an operator applied in the program (an `output op` that no stage applies has "
                           "no reduced form in the model)", name);
  if (!ro->op->op->is_output) return rfail(r, "'%s' is not an output op", name);
  /* its entries read coordinates: never computed they are not zeros (npg_reduced_lift refuses the same) */
  for (int g = 0; g < ro->ntensors && !r->evaluated; g++)
    for (int j = 0; j < ro->t[g].nin; j++)
      if (!r->given[ro->t[g].in_q[j]])
        return rfail(r, "operator %s reads '%s', which has no value: it was not set and nothing was evaluated yet "
                        "(npg_reduced_eval)", name, ((Sym *)m->prog->quantities.v[ro->t[g].in_q[j]])->name);
  int c = m->qclass[rs->q];
  long my = m->classes[c].m;
  if ((size_t)(my * my) > cap) return rfail(r, "operator %s is %ld x %ld, the buffer holds %zu", name, my, my, cap);
  memset(out, 0, sizeof(double) * (size_t)(my * my));
  for (int g = 0; g < ro->ntensors; g++) {
    const RTensor *t = &ro->t[g];
    if (input_product(r, t) != 0) return -1;
    cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)t->rows, (int)t->cols, 1.0, t->data, (int)t->cols, r->z, 1, 1.0,
                out, 1);
  }
  *rows = *cols = my;
  if (row_class) *row_class = c;
  if (col_class) *col_class = c;
  return 0;
}

/* The estimates of the last evaluation, computed once; NULL with the error recorded. */
static EstimateResult *estimates(NpgReduced *r) {
  if (!r->evaluated) return rfail(r, "no estimate before an evaluation (npg_reduced_eval)"), NULL;
  if (r->est_fresh) return r->est;
  if (!r->est && !(r->est = estimate_result_new(r->nm->m))) return rfail(r, "out of memory"), NULL;
  if (estimate_eval(r->r, r->in_err, r->est)) return rfail(r, "out of memory estimating the error"), NULL;
  r->est_fresh = true;
  return r->est;
}

int npg_reduced_estimate(NpgReduced *r, const char *name, double *estimate, unsigned *flags) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  REFUSE_NULL(estimate);
  if (failed(r)) return -1;
  int q = api_quantity(r->nm->m->prog, name);
  if (q < 0) return rfail(r, "the program has no quantity '%s'", name);
  EstimateResult *e = estimates(r);
  if (!e) return -1;
  *estimate = e->err[q];
  if (flags) *flags = e->flags[q];
  return 0;
}

const char *npg_reduced_estimate_why(NpgReduced *r, const char *name) {
  REFUSE_NULL_R("");
  if (!name || failed(r)) return "";
  int q = api_quantity(r->nm->m->prog, name);
  EstimateResult *e = q >= 0 ? estimates(r) : NULL;
  return e ? e->why_q[q] : "";
}

int npg_reduced_outside(NpgReduced *r, const char *name, long *coord) {
  REFUSE_NULL_R(-1);
  REFUSE_NULL(name);
  if (failed(r)) return -1;
  const Model *m = r->nm->m;
  int q = api_quantity(m->prog, name);
  if (q < 0 || ((const Sym *)m->prog->quantities.v[q])->kind != SYM_INPUT)
    return rfail(r, "'%s' is not an input of the program", name);
  if (!r->given[q]) return rfail(r, "input '%s' was never set", name);
  return estimate_outside(m, q, reduced_coords(r->r, q), coord) ? 1 : 0;
}

void npg_reduced_free(NpgReduced *r) {
  if (!r) return;
  estimate_result_free(r->est);
  free(r->in_err);
  free(r->roll.start);
  reduced_free(r->r);
  free(r->z);
  free(r->given);
  npg_model_free(r->own);
  free(r);
}

static volatile double bandwidth_sink; /* the sums are used: the timed loops cannot be dropped */

double npg_read_bandwidth(size_t bytes, double min_seconds) {
  size_t n = bytes / sizeof(double) / 8 * 8;
  if (n < 8) n = 8;
  double *a = malloc(n * sizeof *a);
  if (!a) return 0;
  for (size_t i = 0; i < n; i++) a[i] = 1.0 / (double)(i % 97 + 1);
  double best = INFINITY, spent = 0, keep = 0;
  for (int r = 0; r < 3 || spent < min_seconds; r++) {
    struct timespec t0, t1;
    double s[8] = {0};
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (size_t i = 0; i < n; i += 8)
      for (int k = 0; k < 8; k++) s[k] += a[i + k];
    clock_gettime(CLOCK_MONOTONIC, &t1);
    double t = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    keep += s[0] + s[1] + s[2] + s[3] + s[4] + s[5] + s[6] + s[7];
    best = fmin(best, t), spent += t;
  }
  bandwidth_sink = keep;
  free(a);
  return best > 0 ? (double)(n * sizeof(double)) / best / 1e9 : 0;
}

int npg_blas_threads(int n) {
  int before = openblas_get_num_threads();
  if (n >= 1) openblas_set_num_threads(n);
  return before;
}
