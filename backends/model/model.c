/* model.c — the reduced model: its layout derived from the stage program,
 * its size and program hash (the model to and from MODEL/: model_files.c). */
#include <errno.h>
#include <cblas.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "emit.h"
#include "interp.h"
#include "model.h"
#include "model_store.h"

/* ---------------------------------------------------------------- layout */

static long quantity_count(const Program *prog, const long *dims, const Sym *s) {
  long n = 1;
  for (int i = 0; i < s->ndims; i++) n *= dims[vec_position(&prog->dims, s->dims[i])];
  for (int i = 0; i < s->nstatic; i++) n *= s->shape[i];
  return n;
}

static char *dupf(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static char *dupf(const char *fmt, ...) {
  char buf[1024];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  return mem_strdup(buf);
}

/* File stems keep [A-Za-z0-9_.-]. */
static char *file_stem(char *s) {
  for (char *c = s; c && *c; c++)
    if (!((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') || *c == '_' ||
          *c == '.' || *c == '-'))
      *c = '_';
  return s;
}

/* The distinct inputs of a tensor group (its sorted multiset in runs). */
static bool tensor_inputs(const Program *prog, const TensorGroup *g, RTensor *t) {
  t->group = g;
  t->nin = 0;
  for (int i = 0; i < g->ninputs; i++) {
    int q = vec_position(&prog->quantities, g->inputs[i]);
    if (q < 0) return false;
    if (t->nin > 0 && t->in_q[t->nin - 1] == q) {
      t->in_mult[t->nin - 1]++;
      continue;
    }
    t->in_q[t->nin] = q;
    t->in_mult[t->nin] = 1;
    t->nin++;
  }
  return true;
}

static char *class_label(const BasisClass *bc) {
  size_t len = 3;
  for (int i = 0; i < bc->members.n; i++) len += strlen(((Sym *)bc->members.v[i])->name) + 1;
  char *s = mem_malloc(len);
  if (!s) return NULL;
  strcpy(s, "{");
  for (int i = 0; i < bc->members.n; i++) {
    if (i) strcat(s, ",");
    strcat(s, ((Sym *)bc->members.v[i])->name);
  }
  strcat(s, "}");
  return s;
}

static int layout_oom(Err *err) { return err_set(err, "out of memory while laying out the reduced model"); }
static int layout_nobasis(Err *err) { return err_set(err, "a tensor reads a quantity without a basis (a bug in npg)"); }

/* The classes of the layout: their labels, sizes and members. -1 with `err`. */
static int layout_classes(Model *m, Program *prog, const long *dims, Err *err) {
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    const BasisClass *bc = prog->classes.v[c];
    rc->bc = bc;
    rc->product = bc->product;
    if (!(rc->label = class_label(bc))) return layout_oom(err);
    rc->n = quantity_count(prog, dims, bc->members.v[0]);
    rc->nmembers = bc->members.n + bc->joiners.n;
    if (!(rc->members = mem_calloc((size_t)rc->nmembers, sizeof(RMember)))) return layout_oom(err);
    for (int i = 0; i < bc->members.n; i++) {
      const Sym *s = bc->members.v[i];
      rc->members[i].q = vec_position(&prog->quantities, s);
      if (!(rc->members[i].name = mem_strdup(s->name))) return layout_oom(err);
      if (quantity_count(prog, dims, s) != rc->n)
        return err_set(err, "class %s: '%s' has %ld entries but '%s' has %ld", rc->label, s->name,
                       quantity_count(prog, dims, s), ((Sym *)bc->members.v[0])->name, rc->n);
    }
    for (int j = 0; j < bc->joiners.n; j++) {
      const Joiner *jn = bc->joiners.v[j];
      RMember *mb = &rc->members[bc->members.n + j];
      mb->q = -1;
      mb->joiner = jn;
      if (!(mb->name = dupf("%s.num%d", jn->stage->sym->name, jn->term + 1))) return layout_oom(err);
    }
  }
  return 0;
}

/* Term t of stage rs (its Stage rs->st, its quantity rs->q) into rs->terms[t]: its numerator and
 * operators' tensors. -1 with `err`. */
static int layout_term(Model *m, Program *prog, const RStage *rs, int t, Err *err) {
  const Stage *st = rs->st;
  RTerm *rt = &rs->terms[t];
  const Term *tm = st->terms[t];
  const char *sn = st->sym->name;
  rt->term = tm;
  rt->named_q = -1;
  if (tm->named_num) {
    rt->named_q = vec_position(&prog->quantities, tm->named_num);
    if (m->qclass[rt->named_q] != m->qclass[rs->q] && !(rt->proj_name = file_stem(dupf("proj_%s_t%d", sn, t))))
      return layout_oom(err);
  } else {
    rt->nnum = tm->num_tensors.n;
    if (!(rt->num = mem_calloc((size_t)rt->nnum + 1, sizeof(RTensor)))) return layout_oom(err);
    for (int g = 0; g < rt->nnum; g++) {
      RTensor *rtn = &rt->num[g];
      rtn->kind = RT_NUM;
      if (!tensor_inputs(prog, &tm->num_tensors.g[g], rtn)) return layout_nobasis(err);
      rtn->name = file_stem(dupf("t_%s_t%d_f0_g%d", sn, t, g));
      rtn->builder = mem_strdup(emit_builder_name(prog->ctx, prog, st, t, 0, g, NULL));
      if (!rtn->name || !rtn->builder) return layout_oom(err);
    }
  }
  rt->nops = tm->nops;
  if (!(rt->ops = mem_calloc((size_t)tm->nops + 1, sizeof(ROp)))) return layout_oom(err);
  for (int k = 0; k < tm->nops; k++) {
    ROp *ro = &rt->ops[k];
    const OpPow *op = &tm->ops[k];
    ro->op = op;
    const TensorList *tl = op->kind == OPK_DIAG ? &tm->op_tensors[k] : &op->op->opdef->tensors;
    ro->ntensors = tl->n;
    if (!(ro->t = mem_calloc((size_t)tl->n + 1, sizeof(RTensor)))) return layout_oom(err);
    for (int g = 0; g < tl->n; g++) {
      RTensor *rtn = &ro->t[g];
      rtn->kind = op->kind == OPK_DIAG ? RT_DIAG : RT_DECL;
      if (!tensor_inputs(prog, &tl->g[g], rtn)) return layout_nobasis(err);
      rtn->name = file_stem(dupf("t_%s_t%d_op%d_g%d", sn, t, k + 1, g));
      rtn->builder = mem_strdup(op->kind == OPK_DIAG ? emit_builder_name(prog->ctx, prog, st, t, k + 1, g, NULL)
                                                 : emit_builder_name(prog->ctx, prog, NULL, 0, 0, g, op->op));
      if (!rtn->name || !rtn->builder) return layout_oom(err);
    }
  }
  return 0;
}

/* The stages of the layout: their quantities, externs' inputs, terms. -1 with `err`. */
static int layout_stages(Model *m, Program *prog, Err *err) {
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    const Stage *st = prog->stages.v[i];
    rs->st = st;
    rs->q = vec_position(&prog->quantities, st->sym);
    if (rs->q < 0) return err_set(err, "stage '%s' has no basis (a bug in npg)", st->sym->name);
    if (st->kind == ST_EXTERN) {
      RExtern *x = &m->externs[m->nexterns++];
      x->q = rs->q;
      for (int k = 0; k < st->sym->nof && x->nin < RT_MAX_IN; k++)
        x->in_q[x->nin++] = vec_position(&prog->quantities, st->sym->of[k]);
      continue;
    }
    rs->nterms = st->nterms;
    if (!(rs->terms = mem_calloc((size_t)st->nterms + 1, sizeof(RTerm)))) return layout_oom(err);
    for (int t = 0; t < st->nterms; t++)
      if (layout_term(m, prog, rs, t, err)) return -1;
  }
  return 0;
}

const double *model_tensor_rows(const RClass *rc, const RTerm *rt, const RTensor *x) {
  int k = -1;
  for (int o = 0; o < rt->nops; o++)
    if (x >= rt->ops[o].t && x < rt->ops[o].t + rt->ops[o].ntensors) k = o;
  return model_term_rows(rc, rt, k);
}

int model_named_projections(Model *m, Err *err) {
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      const RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
      /* in its own class, projected by Dᵀ (model_term_projects) w's coordinates are exact: DᵀB = I */
      if (rt->named_q < 0 || rt->proj_name || model_term_projects(rt, -1) || !rc->product) continue;
      if (!(rt->proj_name = file_stem(dupf("proj_%s_t%d", m->stages[i].st->sym->name, t)))) return layout_oom(err);
    }
  return 0;
}

/* layout_classes and layout_stages name the builders in the program's arena (emit_builder_name), whose
 * out of memory longjmps to ctx->on_error — the compile's jump buffer, long gone by training: armed here,
 * so that a failure returns -1 with "out of memory" and leaves the program's state as it was. */
static int layout_parts(Model *m, Program *prog, const long *dims, Err *err) {
  Ctx *ctx = prog->ctx;
  jmp_buf here, *outer = ctx->on_error;
  char *msg = ctx->msg;
  bool failed = ctx->failed;
  int rc;
  ctx->on_error = &here;
  if (setjmp(here) == 0) rc = layout_classes(m, prog, dims, err) || layout_stages(m, prog, err) ? -1 : 0;
  else rc = layout_oom(err), ctx->msg = msg, ctx->failed = failed;
  ctx->on_error = outer;
  return rc;
}

Model *model_layout(Program *prog, const long *dims, Err *err) {
  Model *m = mem_calloc(1, sizeof *m);
  if (!m) return layout_oom(err), NULL;
  m->prog = prog;
  m->program_hash = model_program_hash(prog);
  m->ndims = prog->dims.n;
  m->dims = mem_calloc((size_t)m->ndims + 1, sizeof(long));
  m->nq = prog->quantities.n;
  m->qclass = mem_calloc((size_t)m->nq + 1, sizeof(int));
  m->nclasses = prog->classes.n;
  m->classes = mem_calloc((size_t)m->nclasses + 1, sizeof(RClass));
  m->nstages = prog->stages.n;
  m->stages = mem_calloc((size_t)m->nstages + 1, sizeof(RStage));
  m->externs = mem_calloc((size_t)prog->externs.n + 1, sizeof(RExtern));
  int rc = m->dims && m->qclass && m->classes && m->stages && m->externs ? 0 : layout_oom(err);
  if (rc == 0) {
    for (int i = 0; i < m->ndims; i++) m->dims[i] = dims[i];
    for (int q = 0; q < m->nq; q++) m->qclass[q] = ((Sym *)prog->quantities.v[q])->klass;
    rc = layout_parts(m, prog, dims, err);
  }
  if (rc == 0) return m;
  model_free(m); /* the half-built model, once */
  return NULL;
}

static void free_tensor(RTensor *t) {
  free(t->name);
  free(t->builder);
  free(t->data);
}

void model_free(Model *m) {
  if (!m) return;
  for (int c = 0; m->classes && c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    free(rc->label);
    if (rc->B_mapped) munmap(rc->B, rc->B_mapped);
    else free(rc->B);
    free(rc->D);
    free(rc->R);
    free(rc->coef);
    free(rc->train_coords);
    for (int i = 0; rc->members && i < rc->nmembers; i++) free(rc->members[i].name), free(rc->members[i].sv);
    free(rc->members);
  }
  for (int i = 0; m->stages && i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    for (int t = 0; rs->terms && t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      for (int g = 0; rt->num && g < rt->nnum; g++) free_tensor(&rt->num[g]);
      free(rt->num);
      free(rt->proj);
      free(rt->proj_name);
      for (int k = 0; rt->ops && k < rt->nops; k++) {
        for (int g = 0; rt->ops[k].t && g < rt->ops[k].ntensors; g++) free_tensor(&rt->ops[k].t[g]);
        free(rt->ops[k].t);
      }
      free(rt->ops);
      free(rt->est_G);
      free(rt->est_theta);
      free(rt->est_opc);
    }
    free(rs->terms);
    interp_free(rs->interp);
    interp_free(rs->check);
  }
  for (int i = 0; m->externs && i < m->nexterns; i++) {
    free(m->externs[i].X);
    free(m->externs[i].Z);
  }
  free(m->externs);
  for (int q = 0; m->in_range && q < m->nq; q++) free(m->in_range[q]);
  free(m->in_range);
  free(m->greedy);
  free(m->stages);
  free(m->classes);
  free(m->qclass);
  free(m->dims);
  free(m->param_hashes);
  free(m);
}

static long qm(const Model *m, int q) { return m->classes[m->qclass[q]].m; }

void model_size_tensors(Model *m) {
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    long my = qm(m, rs->q);
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      RTERM_FOR_TENSORS(rt, x) {
        x->rows = x->kind == RT_NUM ? my : x->kind == RT_DIAG ? my * (my + 1) / 2 : my * my;
        x->cols = 1;
        for (int j = 0; j < x->nin; j++) {
          x->in_len[j] = sym_len(qm(m, x->in_q[j]), x->in_mult[j]);
          x->cols *= x->in_len[j];
        }
      }
    }
  }
  for (int i = 0; i < m->nexterns; i++) {
    RExtern *x = &m->externs[i];
    x->d = 0;
    for (int j = 0; j < x->nin; j++) x->d += qm(m, x->in_q[j]);
  }
}

/* model_class_needed, an extern's class counted needed or not (`externs`). */
static bool needed(const Model *m, int c, bool externs) {
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = m->prog->quantities.v[q];
    if (m->qclass[q] == c && (s->kind == SYM_INPUT || (externs && s->kind == SYM_EXTERN) || s->is_output)) return true;
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    if (rs->interp) {
      if (m->qclass[rs->q] == c) return true;
      for (long r = 0; r < rs->interp->nreads; r++)
        if (m->qclass[rs->interp->read_q[r]] == c) return true;
    }
    for (int t = 0; t < rs->nterms; t++)
      for (int k = 0; k < rs->terms[t].nops; k++) {
        const ROp *ro = &rs->terms[t].ops[k];
        if (ro->op->kind == OPK_DECL && ro->op->op->is_output && m->qclass[rs->q] == c) return true;
      }
  }
  return false;
}

bool model_class_needed(const Model *m, int c) { return needed(m, c, true); }

bool model_class_by_coefficients(const Model *m, int c) {
  const RClass *rc = &m->classes[c];
  if (rc->nmembers != 1 || rc->members[0].q < 0 || needed(m, c, false)) return false;
  const Sym *s = m->prog->quantities.v[rc->members[0].q];
  return s->kind == SYM_EXTERN && s->ndims >= 2;
}

bool model_class_streamable(const Model *m, int c) {
  if (model_class_needed(m, c)) return false;
  const RClass *rc = &m->classes[c];
  for (int i = 0; i < rc->nmembers; i++) {
    const RMember *mb = &rc->members[i];
    const Sym *s = mb->q >= 0 ? m->prog->quantities.v[mb->q] : mb->joiner->stage->sym;
    if (s->ndims >= 2) return true;
  }
  return false;
}

void model_projection_floor(const RClass *rc, const double *full, double *proj, double *y, double out[2]) {
  double big = 0, ny = 0, f2 = 0, finf = 0;
  for (long e = 0; e < rc->n; e++) big = fmax(big, fabs(full[e]));
  double unit = big > 0 && isfinite(big) ? 1 / big : 1;
  if (!isfinite(unit)) unit = 1; /* subnormal data: 1/big overflows; their squares are lost anyway */
  /* with a product, the K0-projection (BᵀK0 = Dᵀ) */
  cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)rc->m, 1.0, model_projector(rc), (int)rc->m, full, 1, 0.0,
              proj, 1);
  cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)rc->n, (int)rc->m, 1.0, rc->B, (int)rc->m, proj, 1, 0.0, y, 1);
  for (long e = 0; e < rc->n; e++) {
    double d = (full[e] - y[e]) * unit, v = full[e] * unit;
    ny += v * v;
    f2 += d * d;
    finf = fmax(finf, fabs(full[e] - y[e]));
  }
  out[0] = ny > 0 ? sqrt(f2 / ny) : sqrt(f2);
  out[1] = big > 0 ? finf / big : finf;
}

size_t model_bytes(const Model *m, size_t *tensor_bytes) {
  size_t total = 0, tb = 0;
  for (int c = 0; c < m->nclasses; c++)
    if (!m->classes[c].streamed) total += sizeof(double) * (size_t)(m->classes[c].n * m->classes[c].m);
    else if (m->classes[c].coef) total += sizeof(double) * (size_t)(m->classes[c].coef_S * m->classes[c].m);
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      RTERM_FOR_TENSORS(rt, x) {
        tb += sizeof(double) * (size_t)(x->rows * x->cols);
      }
      if (rt->proj) tb += sizeof(double) * (size_t)(qm(m, rs->q) * qm(m, rt->named_q));
    }
    if (rs->interp)
      tb += sizeof(double) * (size_t)(rs->interp->k * (rs->interp->m + 1)) +
            sizeof(RInterpMono) * (size_t)rs->interp->nmono + (sizeof(int) + sizeof(long)) * (size_t)rs->interp->nreads;
  }
  for (int i = 0; i < m->nexterns; i++)
    total += sizeof(double) * (size_t)(m->externs[i].S * (m->externs[i].d + qm(m, m->externs[i].q)));
  if (tensor_bytes) *tensor_bytes = tb;
  return total + tb;
}

uint64_t model_program_hash(const Program *prog) {
  uint64_t h = 1469598103934665603ull;
  for (int i = 0; i < prog->ctx->files.n; i++) {
    const SrcFile *f = prog->ctx->files.v[i];
    for (size_t k = 0; k < f->len; k++) {
      h ^= (unsigned char)f->text[k];
      h *= 1099511628211ull;
    }
    h ^= 0xff;
    h *= 1099511628211ull;
  }
  return h;
}
