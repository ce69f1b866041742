/* train.c — training a reduced model (DESIGN §5; paper §8.2–§8.3):
 *
 *   0. the layout, and every member's cap, energy fraction and centering
 *      (defaults, the program's `basis` statements, --basis);
 *   1. snapshots: the full evaluator on every training sample; every
 *      quantity's value and, for every operator term with an unnamed
 *      numerator, the numerator's value (it joins the result's class:
 *      DESIGN §4, "a numerator lives in the result's basis");
 *   2. one orthonormal basis per class: a PCA per member (centered by
 *      default: pca.c), concatenated and re-orthonormalized, or with
 *      --merge joint one PCA of the unit-scaled member blocks;
 *   3. pre-multiplication of every tensor (premul.c);
 *   4. the learned map of every extern (paper §8.3): the training samples'
 *      reduced inputs and reduced values.
 *
 * train_model below is that list, one call a step, each phase timed. The
 * tune sample set (train_set.c) runs 0–1 and every member's PCA once, then
 * builds models of any caps from truncations of those bases, steps 2–4
 * only. Elsewhere: the method of snapshots (snapshots.c), --merge joint
 * (joint.c), out of core (ooc.c), over MPI ranks (dist_train.c), the
 * progress bar (progress.c).
 */
#include <cblas.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "dist.h"
#include "interp.h"
#include "reduced.h"
#include "train.h"
#include "train_steps.h"

/* ---------------------------------------------------------------- fields through the builders */

typedef struct FieldSum {
  const double *in[16];  /* the values of the tensor's inputs, in its input order */
  double *out;
  long n;
} FieldSum;

static int sum_entry(void *user, npg_idx row, npg_idx col, int nin, const npg_idx *in, double coef) {
  FieldSum *s = user;
  (void)col;
  if (row < 0 || row >= s->n) return -1;
  double v = coef;
  for (int i = 0; i < nin; i++) v *= s->in[i][in[i]];
  s->out[row] += v;
  return 0;
}

/* out[0..n) = the field whose tensors are `ts` (builders named in `ts`),
 * evaluated on the current values of the evaluator. */
static int field_value(Full *f, const RTensor *ts, int nt, double *out, long n, char *err, size_t errlen) {
  memset(out, 0, sizeof(double) * (size_t)n);
  for (int g = 0; g < nt; g++) {
    FieldSum s = {{0}, out, n};
    for (int i = 0; i < ts[g].group->ninputs; i++) s.in[i] = full_get(f, ts[g].group->inputs[i]->name, NULL);
    NpgSink sink = {&s, sum_entry, 0, 1, 0, 0}; /* every row */
    if (full_build(f, ts[g].builder, &sink) != 0) return error_set(err, errlen, "%s", full_error(f));
  }
  return 0;
}

/* ---------------------------------------------------------------- options */

/* Whether override `name` (--basis NAME:...) names member `mb` of class
 * `c`, and how specifically: 0 not at all, 1 '*', 2 its class (m_f as
 * `npgc check` prints it, or its label {f,g}), 3 the member itself (a
 * quantity, or a numerator f.num1). */
static int override_level(const RClass *c, const RMember *mb, const char *name) {
  if (strcmp(name, mb->name) == 0) return 3;
  if (strcmp(name, c->label) == 0 || (c->bc->size_name && strcmp(name, c->bc->size_name) == 0)) return 2;
  /* m_<any member>, as the language's `basis m_q:` takes it (the class of q) */
  for (int k = 0; strncmp(name, "m_", 2) == 0 && k < c->nmembers; k++)
    if (strcmp(name + 2, c->members[k].name) == 0) return 2;
  return strcmp(name, "*") == 0 ? 1 : 0;
}

/* Every --basis name must name something: a misspelt one would silently
 * train with the defaults. */
static int check_overrides(const Model *m, const TrainOptions *opt, char *err, size_t errlen) {
  for (int i = 0; i < opt->noverride; i++) {
    bool found = false;
    for (int c = 0; c < m->nclasses && !found; c++)
      for (int k = 0; k < m->classes[c].nmembers && !found; k++)
        found = override_level(&m->classes[c], &m->classes[c].members[k], opt->override_name[i]) > 0;
    if (found) continue;
    char list[1024] = "";
    size_t len = 0;
    for (int c = 0; c < m->nclasses && len < sizeof list; c++) {
      const RClass *rc = &m->classes[c];
      len += (size_t)snprintf(list + len, sizeof list - len, "%s%s (", c ? "; " : "", rc->bc->size_name);
      for (int k = 0; k < rc->nmembers && len < sizeof list; k++)
        len += (size_t)snprintf(list + len, sizeof list - len, "%s%s", k ? ", " : "", rc->members[k].name);
      if (len < sizeof list) len += (size_t)snprintf(list + len, sizeof list - len, ")");
    }
    return error_set(err, errlen,
                     "--basis %s: no quantity, class or numerator of that name; classes (members): %s, or '*' for all",
                     opt->override_name[i], list);
  }
  return 0;
}

/* A member's cap, energy and centering: the defaults (energy 1 for a
 * quantity under a power, `powered`, whatever the default energy), then the
 * program's `basis` statements, then --basis from the least specific to the
 * most. */
static void member_options(const Model *m, const RClass *c, RMember *mb, const TrainOptions *opt,
                           const bool *powered) {
  mb->cap = opt->cap > 0 ? opt->cap : 60;
  mb->energy = powered && mb->q >= 0 && powered[mb->q] ? 1 : opt->energy > 0 ? opt->energy : 0.999;
  mb->center = !opt->uncentered;
  const BasisClass *bc = c->bc;
  if (bc->basis_max > 0) mb->cap = bc->basis_max;
  if (bc->basis_energy > 0) mb->energy = bc->basis_energy;
  if (bc->basis_center >= 0) mb->center = bc->basis_center;
  if (mb->q >= 0) {
    const Sym *s = m->prog->quantities.v[mb->q];
    if (s->basis_max > 0) mb->cap = s->basis_max;
    if (s->basis_energy > 0) mb->energy = s->basis_energy;
    if (s->basis_center >= 0) mb->center = s->basis_center;
  }
  bool named = false; /* a cap for this member by its own name */
  for (int level = 1; level <= 3; level++)
    for (int i = 0; i < opt->noverride; i++) {
      if (override_level(c, mb, opt->override_name[i]) != level) continue;
      if (opt->override_cap[i] > 0) mb->cap = opt->override_cap[i], named |= level == 3;
      if (opt->override_energy[i] > 0) mb->energy = opt->override_energy[i];
      if (opt->override_center && opt->override_center[i] >= 0) mb->center = opt->override_center[i];
    }
  /* An implicit step's residual is zero at every solved step up to Newton's tolerance: its
   * snapshots are rounding, whose directions would only grow the state's class (measured: 78
   * vectors instead of 19 on bench/implicit_burgers_step.py). One vector (the mean, or the
   * leading one uncentered) unless the program or --basis gives it a cap by its name. */
  const Sym *s = mb->q >= 0 ? m->prog->quantities.v[mb->q] : NULL;
  if (s && s->state_of && s->state_of->residual == s && s->basis_max <= 0 && !named) mb->cap = 1;
}

/* Every class's product (issue 41): the program's (`basis u: product K0`),
 * then --basis NAME:product=K0 from the least specific name to the most; an
 * op of the program, square over one set of dims (its size is checked with
 * the class's in product.c). */
static int class_products(Model *m, const TrainOptions *opt, char *err, size_t errlen) {
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    int best = 0;
    for (int i = 0; opt->override_product && i < opt->noverride; i++) {
      const char *name = opt->override_product[i];
      int level = 0;
      for (int k = 0; name && k < rc->nmembers; k++) {
        int l = override_level(rc, &rc->members[k], opt->override_name[i]);
        level = l > level ? l : level;
      }
      if (!name || level == 0 || level < best) continue;
      const Sym *op = NULL;
      for (int j = 0; j < m->prog->ops.n && !op; j++)
        if (strcmp(((const Sym *)m->prog->ops.v[j])->name, name) == 0) op = m->prog->ops.v[j];
      bool square = op && op->nivars == 2 * op->nrow;
      for (int a = 0; square && a < op->nrow; a++) square = op->ivars[a]->range == op->ivars[op->nrow + a]->range;
      if (!op || !square)
        return error_set(err, errlen, "--basis %s:product=%s: %s", opt->override_name[i], name,
                         !op ? "the program has no op of that name (the product is an SPD op of the program)"
                             : "not a square operator (its rows and columns must run over the same dims)");
      rc->product = op, best = level;
    }
  }
  return 0;
}

/* ---------------------------------------------------------------- training */

void train_free_snapshots(Model *m, Snapshots *sn) {
  for (int c = 0; c < m->nclasses; c++) {
    for (int i = 0; i < m->classes[c].nmembers; i++) {
      if (sn->X && sn->X[c]) free(sn->X[c][i]);
      if (sn->U && sn->U[c]) free(sn->U[c][i]);
    }
    if (sn->X) free(sn->X[c]);
    if (sn->U) free(sn->U[c]);
    if (sn->k) free(sn->k[c]);
  }
  free(sn->X);
  free(sn->U);
  free(sn->k);
}

/* Visit every diagonal operator (stage, term, op). */
#define FOR_DIAG_OPS(m, rs, rt, ro)                                                   \
  for (int i_ = 0; i_ < (m)->nstages; i_++)                                           \
    for (RStage *rs = &(m)->stages[i_]; rs; rs = NULL)                                \
      for (int t_ = 0; t_ < rs->nterms; t_++)                                         \
        for (RTerm *rt = &rs->terms[t_]; rt; rt = NULL)                               \
          for (int k_ = 0; k_ < rt->nops; k_++)                                       \
            for (ROp *ro = &rt->ops[k_]; ro && ro->op->kind == OPK_DIAG; ro = NULL)

void train_mark_spd(Model *m) {
  FOR_DIAG_OPS(m, rs, rt, ro) ro->spd = true;
}

static RTerm *joiner_term(Model *m, const Joiner *j) {
  for (int i = 0; i < m->nstages; i++)
    if (m->stages[i].st == j->stage) return &m->stages[i].terms[j->term];
  return NULL;
}


/* Set and evaluate training sample k. */
int train_eval_sample(const SampleSource *src, Full *f, long k, char *err, size_t errlen) {
  if (src->set(src->user, f, k) != 0 || full_eval(f, k) != 0) return error_set(err, errlen, "%s", full_error(f));
  return 0;
}

/* The current value of a class member (a quantity, or an unnamed numerator
 * through its builders) at sample k into out[0..n); refused when not
 * finite, since a basis of it would be meaningless (and the SVD would fail
 * without saying why). */
int train_member_value(Model *m, Full *f, const RMember *mb, long k, long n, double *out, char *err,
                       size_t errlen) {
  if (mb->q >= 0) {
    memcpy(out, full_get(f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL), sizeof(double) * (size_t)n);
  } else {
    RTerm *rt = joiner_term(m, mb->joiner);
    if (!rt) return error_set(err, errlen, "a numerator without its term (a bug in npg)");
    if (field_value(f, rt->num, rt->nnum, out, n, err, errlen)) return -1;
  }
  for (long e = 0; e < n; e++)
    if (!isfinite(out[e])) {
      /* name where the NaN arises (the first quantity in evaluation order
       * holding one), not the member that happened to be looked at */
      const Sym *s;
      char at[256], cause[512];
      double v;
      if (full_first_nonfinite(f, &s, at, sizeof at, &v, cause, sizeof cause))
        return error_set(err, errlen, "training sample %ld: %s is not finite (%s%s is %s): %s%s%s", k, s->name,
                         s->name, at, isnan(v) ? "NaN" : v > 0 ? "inf" : "-inf",
                         cause[0] ? "the sample makes it undefined (" : "",
                         cause[0] ? cause : "the sample makes it undefined (a division by zero or a root of a negative "
                                            "number in the program?)", cause[0] ? ")" : "");
      return error_set(err, errlen,
                       "training sample %ld: %s is not finite (entry %ld is %g): the sample makes it undefined (a "
                       "division by zero or a root of a negative number in the program?)",
                       k, mb->name, e, out[e]);
    }
  return 0;
}

/* A diagonal operator stays marked SPD while every training diagonal seen is
 * positive (then BᵀDB is SPD for every basis: Cholesky). */
int train_check_spd(Model *m, Full *f, double *tmp, char *err, size_t errlen) {
  FOR_DIAG_OPS(m, rs, rt, ro) {
    if (!ro->spd) continue;
    long n = m->classes[m->qclass[rs->q]].n;
    if (field_value(f, ro->t, ro->ntensors, tmp, n, err, errlen)) return -1;
    for (long e = 0; e < n && ro->spd; e++)
      if (!(tmp[e] > 0)) ro->spd = false;
  }
  return 0;
}

/* Record a member's PCA (its size, lost energy and spectrum). */
static void take_pca(RMember *mb, PcaMember *p) {
  mb->kept = p->k;
  mb->lost = p->lost;
  mb->captured = 1 - p->lost;
  free(mb->sv);
  mb->sv = p->sv;
  mb->nsv = p->nsv;
  p->sv = NULL;
}

/* The class basis by the paper's way (§6.1, §9): one PCA per member, the
 * member bases concatenated and re-orthonormalized. X[i]: member i's
 * snapshots, n x S column-major; `pre` (over ranks): the members' PCAs
 * already made (dist_member_pcas), taken over. */
int train_member_bases(RClass *rc, long S, double *const *X, const double *w, PcaMember *pre, char *err, size_t errlen) {
  double **U = mem_calloc((size_t)rc->nmembers + 1, sizeof(double *));
  int *kk = mem_calloc((size_t)rc->nmembers + 1, sizeof(int)), rc_ok = U && kk ? 0 : -1;
  for (int i = 0; i < rc->nmembers && rc_ok == 0; i++) {
    RMember *mb = &rc->members[i];
    PcaMember p;
    if (pre) p = pre[i], memset(&pre[i], 0, sizeof pre[i]);
    else rc_ok = pca_basis(rc->n, S, X[i], mb->cap, mb->energy, mb->center, w, &p, err, errlen);
    if (rc_ok) break;
    U[i] = p.U;
    kk[i] = p.k;
    take_pca(mb, &p);
  }
  if (rc_ok == 0) rc_ok = pca_merge(rc->n, rc->nmembers, U, kk, &rc->B, &rc->m, err, errlen);
  for (int i = 0; U && i < rc->nmembers; i++) free(U[i]);
  free(U);
  free(kk);
  return rc_ok;
}

/* Whether --keep-bases `list` (comma-separated) names class `c` (a member
 * or the class, as --basis names them); *unknown set to the first name
 * that names nothing (NULL: none). "all" names every class. */
static bool keep_named(const Model *m, const char *list, int c, char *unknown, size_t ulen) {
  bool kept = false;
  for (const char *p = list; p && *p;) {
    size_t len = strcspn(p, ",");
    char name[256];
    snprintf(name, sizeof name, "%.*s", (int)(len < sizeof name ? len : sizeof name - 1), p);
    bool any = strcmp(name, "all") == 0;
    kept |= any;
    for (int k = 0; k < m->nclasses; k++)
      for (int i = 0; i < m->classes[k].nmembers; i++) {
        int level = override_level(&m->classes[k], &m->classes[k].members[i], name);
        any |= level >= 2;
        kept |= level >= 2 && k == c;
      }
    if (!any && unknown && !unknown[0]) snprintf(unknown, ulen, "%s", name);
    p += len + (p[len] == ',');
  }
  return kept;
}

static bool named_in(const char *const *names, int n, const char *name);

/* The model's layout for the dims sample 0 binds, with every member's
 * options set and the --basis names checked. NULL with `err`. */
Model *train_begin(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen) {
  if (src->count < 1) {
    error_set(err, errlen, "no training samples");
    return NULL;
  }
  if (src->set(src->user, f, 0) != 0 || full_eval(f, 0) != 0) { /* sample 0 binds every dim */
    error_set(err, errlen, "%s", full_error(f));
    return NULL;
  }
  long *dims = mem_calloc((size_t)prog->dims.n + 1, sizeof(long));
  if (!dims) return error_set(err, errlen, "out of memory"), NULL;
  for (int i = 0; i < prog->dims.n; i++) dims[i] = full_dim_size(f, i);
  Model *m = model_layout(prog, dims, err, errlen);
  free(dims);
  if (!m) return NULL;
  m->samples = src->count;
  bool *powered = lower_under_powers(m->prog);
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++)
      member_options(m, &m->classes[c], &m->classes[c].members[i], opt, powered);
  free(powered);
  if (class_products(m, opt, err, errlen)) {
    model_free(m);
    return NULL;
  }
  char unknown[256] = ""; /* a misspelt --keep-bases name is refused before training, not after */
  if (m->nclasses > 0) keep_named(m, opt->keep_bases, 0, unknown, sizeof unknown);
  if (unknown[0])
    error_set(err, errlen, "--keep-bases %s: no quantity or class of that name (a quantity, a class m_x, or all)",
              unknown);
  if (unknown[0] || check_overrides(m, opt, err, errlen)) {
    model_free(m);
    return NULL;
  }
  return m;
}

int train_check_names(Program *prog, const TrainOptions *opt, char *err, size_t errlen) {
  /* classes and stages do not depend on the dims' sizes: the layout at size 1 names them all */
  long *dims = mem_calloc((size_t)prog->dims.n + 1, sizeof(long));
  if (!dims) return error_set(err, errlen, "out of memory");
  for (int i = 0; i < prog->dims.n; i++) dims[i] = 1;
  Model *m = model_layout(prog, dims, err, errlen);
  free(dims);
  if (!m) return -1;
  char unknown[256] = "";
  int rc = 0;
  if (m->nclasses > 0) keep_named(m, opt->keep_bases, 0, unknown, sizeof unknown);
  if (unknown[0])
    rc = error_set(err, errlen, "--keep-bases %s: no quantity or class of that name (a quantity, a class m_x, or all)",
                   unknown);
  if (rc == 0) rc = check_overrides(m, opt, err, errlen);
  if (rc == 0) rc = class_products(m, opt, err, errlen);
  for (int l = 0; l < 2 && rc == 0; l++) {
    const char *const *names = l ? opt->galerkin_stage : opt->interp_stage;
    for (int j = 0; j < (l ? opt->ngalerkin : opt->ninterp) && rc == 0; j++) {
      int i = 0;
      while (i < m->nstages && strcmp(m->stages[i].st->sym->name, names[j]) != 0) i++;
      if (i == m->nstages)
        rc = error_set(err, errlen, "--reduce %s:%s: the program has no stage '%s'", names[j],
                       l ? "galerkin" : "interp", names[j]);
      else if (!l && !lower_interp_eligible(m->stages[i].st))
        rc = error_set(err, errlen, "--reduce %s:interp: stage %s cannot be interpolated: %s", names[j], names[j],
                       m->stages[i].st->kind == ST_INVERSE || m->stages[i].st->kind == ST_ROOT
                           ? "one of its operators is a declared op, not diagonal (npgc check says which stages can)"
                           : "it applies no diagonal operator (npgc check says which stages can)");
      else if (l && named_in(opt->interp_stage, opt->ninterp, names[j]))
        rc = error_set(err, errlen, "stage %s is forced both to interpolation and to Galerkin", names[j]);
    }
  }
  model_free(m);
  return rc;
}

int train_fail_hook(const TrainOptions *opt, long k, char *err, size_t errlen) {
  if (!opt->dist || k != dist_rank() || !dist_fail_here()) return 0;
  return error_set(err, errlen, "training sample %ld: NPG_MPI_FAIL_RANK=%d: this rank stops after its first sample (a test hook)",
                   k, dist_rank());
}

/* Room for every member's snapshots of S samples (sn->X, none with
 * `gram`) and for their bases by the method of snapshots (sn->U, sn->k).
 * 0, or -1 when out of memory (what was allocated left to train_free_snapshots). */
static int snapshots_alloc(Model *m, Snapshots *sn, long S, bool gram) {
  sn->S = S;
  if (!(sn->X = mem_calloc((size_t)m->nclasses + 1, sizeof(double **))) ||
      !(sn->U = mem_calloc((size_t)m->nclasses + 1, sizeof(double **))) ||
      !(sn->k = mem_calloc((size_t)m->nclasses + 1, sizeof(int *))))
    return -1;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(sn->X[c] = mem_calloc((size_t)rc->nmembers, sizeof(double *))) ||
        !(sn->U[c] = mem_calloc((size_t)rc->nmembers, sizeof(double *))) || !(sn->k[c] = mem_calloc((size_t)rc->nmembers, sizeof(int))))
      return -1;
    for (int i = 0; !gram && i < rc->nmembers; i++)
      if (!(sn->X[c][i] = mem_malloc(sizeof(double) * (size_t)rc->n * (size_t)S))) return -1;
  }
  return 0;
}

/* Every member's snapshots into sn->X, the SPD marks checked on every
 * sample. Over ranks (opt->dist): rank r takes the samples k ≡ r (mod N),
 * then the columns are gathered on every rank (a rank that fails returns
 * here, before the gather: its caller ends the job). Sample 0 is already
 * evaluated (train_begin). `tmp`: room for the largest class. */
static int snapshots_in_memory(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, Snapshots *sn,
                               double *tmp, char *err, size_t errlen) {
  long S = sn->S;
  int rc = 0, rank = opt->dist ? dist_rank() : 0, N = opt->dist ? dist_size() : 1;
  for (long k = rank; rc == 0 && k < S; k += N) {
    if (k > 0 && train_eval_sample(src, f, k, err, errlen)) rc = -1;
    for (int c = 0; rc == 0 && c < m->nclasses; c++) {
      RClass *cl = &m->classes[c];
      for (int i = 0; rc == 0 && i < cl->nmembers; i++)
        rc = train_member_value(m, f, &cl->members[i], k, cl->n, sn->X[c][i] + (size_t)k * (size_t)cl->n, err, errlen);
    }
    if (rc == 0) rc = train_check_spd(m, f, tmp, err, errlen);
    if (rc == 0) rc = train_fail_hook(opt, k, err, errlen);
    progress_show(opt->progress, "snapshots", k + 1, S);
  }
  if (rc == 0 && N > 1 && (rc = dist_gather_snapshots(m, sn->X, S, err, errlen)) == 0) {
    dist_and_spd(m);
    progress_show(opt->progress, "snapshots", S, S); /* every rank's are in */
  }
  return rc;
}

size_t train_snapshot_bytes(const Model *m, long S) {
  size_t need = 0;
  for (int c = 0; c < m->nclasses; c++)
    need += sizeof(double) * (size_t)m->classes[c].n * (size_t)S * (size_t)m->classes[c].nmembers;
  return need;
}

/* Step 1: every member's snapshots in memory (sn->X), or, when they need
 * more than opt->mem, their bases by the method of snapshots (sn->U, sn->k;
 * *gram set). Marks which diagonal operators stay SPD. */
int train_take_snapshots(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, Snapshots *sn,
                         bool *gram, char *err, size_t errlen) {
  long S = src->count, maxn = 1;
  size_t need = train_snapshot_bytes(m, S);
  for (int c = 0; c < m->nclasses; c++) maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
  *gram = opt->mem && need > opt->mem;
  if (*gram && opt->dist && dist_size() > 1)
    return error_set(err, errlen,
                     "the snapshots need %.3g GB, more than --mem %.3g GB: training over MPI ranks keeps them in "
                     "memory (the method of snapshots runs on one process): raise --mem",
                     (double)need / 1e9, (double)opt->mem / 1e9);
  if (*gram && opt->weights)
    return error_set(err, errlen,
                     "the snapshots need %.3g GB, more than --mem %.3g GB, and sample weights are not implemented in the "
                     "method of snapshots: raise --mem to keep them in memory", (double)need / 1e9, (double)opt->mem / 1e9);
  if (*gram && opt->joint)
    return error_set(err, errlen,
                     "the snapshots need %.3g GB, more than --mem %.3g GB, and --merge joint needs them in memory: raise "
                     "--mem or use --merge concat (the method of snapshots)",
                     (double)need / 1e9, (double)opt->mem / 1e9);
  double *tmp = mem_malloc(sizeof(double) * (size_t)(maxn > S ? maxn : S));
  if (!tmp || snapshots_alloc(m, sn, S, *gram)) {
    free(tmp);
    return error_set(err, errlen, "out of memory for the snapshots of %ld samples", S);
  }
  train_mark_spd(m);
  int rc = *gram ? train_snapshot_bases(m, f, src, opt, sn->U, sn->k, tmp, err, errlen)
                 : snapshots_in_memory(m, f, src, opt, sn, tmp, err, errlen);
  free(tmp);
  return rc;
}

/* A class basis completed to full rank (convergence tests: the PCA
 * directions first, then the rest of the space), and one direction for a
 * class whose every snapshot is zero (lifting gives 0). */
int train_complete_basis(RClass *rc, bool full_rank, char *err, size_t errlen) {
  if (full_rank && rc->m < rc->n) {
    double *eye = mem_calloc((size_t)(rc->n * rc->n), sizeof(double)), *B = NULL;
    double *parts[2] = {rc->B, eye};
    int ks[2] = {(int)rc->m, (int)rc->n};
    if (!eye) return error_set(err, errlen, "out of memory completing the basis of class %s", rc->label);
    for (long e = 0; e < rc->n; e++) eye[e * rc->n + e] = 1;
    int mm = 0, rc_ok = pca_in_order(rc->n, 2, parts, ks, &B, &mm, err, errlen); /* the PCA directions first */
    rc->m = mm;
    free(eye);
    if (rc_ok != 0) return -1;
    free(rc->B);
    rc->B = B;
  }
  if (rc->m == 0) {
    free(rc->B);
    if (!(rc->B = mem_calloc((size_t)rc->n, sizeof(double)))) return error_set(err, errlen, "out of memory");
    rc->B[0] = 1;
    rc->m = 1;
  }
  if (!rc->B_mapped && pca_fix_signs(rc->n, rc->m, rc->B)) return error_set(err, errlen, "out of memory");
  return 0;
}

/* Step 2: one basis per class (DESIGN §5), sized into the tensors. */
static int build_bases(Model *m, Full *f, const Snapshots *sn, bool gram, const TrainOptions *opt, char *err,
                       size_t errlen) {
  /* over ranks: the members' PCAs shared out, each made on one rank */
  PcaMember **pre = NULL;
  if (opt->dist && dist_size() > 1 && !gram && !opt->joint &&
      dist_member_pcas(m, sn->S, sn->X, opt->weights, &pre, err, errlen))
    return -1;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    int rc_ok = 0;
    if (rc->product) { /* issue 41: BᵀK0B = I, a transform around the members' PCAs (product.c) */
      const char *why = gram ? "the snapshots do not fit in --mem (raise it)"
                        : opt->joint && rc->nmembers > 1 ? "--merge joint (use --merge concat)"
                        : pre ? "training over MPI ranks" : NULL;
      if (why) {
        dist_free_pcas(m, pre);
        return error_set(err, errlen, "basis %s: product %s is not implemented with %s", rc->bc->size_name,
                         rc->product->name, why);
      }
      if (train_product_basis(m, f, rc, sn->S, sn->X[c], opt->weights, opt->full_rank, err, errlen))
        return dist_free_pcas(m, pre), -1;
      continue;
    }
    if (opt->joint && rc->nmembers > 1) rc_ok = train_joint_basis(rc, sn->S, sn->X[c], err, errlen);
    else if (gram) rc_ok = pca_merge(rc->n, rc->nmembers, sn->U[c], sn->k[c], &rc->B, &rc->m, err, errlen);
    else rc_ok = train_member_bases(rc, sn->S, sn->X[c], opt->weights, pre ? pre[c] : NULL, err, errlen);
    if (rc_ok != 0) {
      dist_free_pcas(m, pre);
      if (!err[0]) error_set(err, errlen, "out of memory building the basis of class %s", rc->label);
      return -1;
    }
    if (train_complete_basis(rc, opt->full_rank, err, errlen)) return dist_free_pcas(m, pre), -1;
  }
  dist_free_pcas(m, pre);
  model_size_tensors(m);
  return 0;
}

/* Training's phases, as Model.phase_seconds and phase_cpu index them. */
enum { PHASE_SNAPSHOTS, PHASE_BASES, PHASE_PREMULTIPLY, PHASE_EXTERNS };

/* The wall and CPU (this process's threads) seconds since t0[0], t0[1]
 * into sec[0], cpu[0]; t0 moved to now. */
static void phase_time(struct timespec t0[2], double *sec, double *cpu) {
  struct timespec t[2];
  clock_gettime(CLOCK_MONOTONIC, &t[0]);
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t[1]);
  *sec = (double)(t[0].tv_sec - t0[0].tv_sec) + 1e-9 * (double)(t[0].tv_nsec - t0[0].tv_nsec);
  *cpu = (double)(t[1].tv_sec - t0[1].tv_sec) + 1e-9 * (double)(t[1].tv_nsec - t0[1].tv_nsec);
  t0[0] = t[0], t0[1] = t[1];
}

/* The phase timer: `clock` (wall, CPU) set to now. */
static void phase_start(struct timespec clock[2]) {
  clock_gettime(CLOCK_MONOTONIC, &clock[0]);
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &clock[1]);
}

/* Phase `phase` of training `m` ends now: its seconds since `clock` kept,
 * and the next phase timed from now. */
static void phase_end(struct timespec clock[2], Model *m, int phase) {
  phase_time(clock, &m->phase_seconds[phase], &m->phase_cpu[phase]);
}

/* Step 3: the projections between classes and every tensor pre-multiplied.
 * Over ranks, with progress on, rank 0 says how long its own rows took and
 * how long the sums over ranks (the wait for the slowest rank included). */
int train_premultiply_all(Model *m, Full *f, bool progress, bool dist, char *err, size_t errlen) {
  long ntensors = 0, done = 0;
  int rank = dist ? dist_rank() : 0, N = dist ? dist_size() : 1;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      ntensors += rt->nnum;
      for (int k = 0; k < rt->nops; k++) ntensors += rt->ops[k].ntensors;
    }
  double flops = 0, own[2] = {0, 0}, sum[2] = {0, 0}, d[2];
  struct timespec t0[2] = {{0}};
  phase_time(t0, &d[0], &d[1]);
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    RClass *cy = &m->classes[m->qclass[rs->q]];
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      if (rt->proj_name) {
        RClass *cw = &m->classes[m->qclass[rt->named_q]];
        if (!(rt->proj = mem_malloc(sizeof(double) * (size_t)(cy->m * cw->m))))
          return error_set(err, errlen, "out of memory while training");
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)cy->m, (int)cw->m, (int)cy->n, 1.0,
                    rt->nops ? cy->B : model_projector(cy), (int)cy->m, cw->B, (int)cw->m, 0.0, rt->proj, (int)cw->m);
      }
      RTERM_FOR_TENSORS(rt, x) {
        if (x->data) { /* pre-multiplied out of core by the streamed bases (stream.c) */
          x->premul_seconds = NAN;
          progress_show(progress, "pre-multiplication", ++done, ntensors);
          phase_time(t0, &d[0], &d[1]);
          continue;
        }
        /* over ranks: every rank its share of the rows, summed on all */
        phase_time(t0, &d[0], &d[1]); /* from here: this tensor's own time */
        /* a term that applies operators is reduced by Galerkin (BᵀMB, Bᵀw); one that does not is
         * projected (with a product, the K0-projection Dᵀ: issue 41) */
        const double *row = rt->nops ? cy->B : model_projector(cy);
        if (premultiply_part(m, f, x, row, cy->n, cy->m, rank, N, &flops, err, errlen)) return -1;
        phase_time(t0, &d[0], &d[1]);
        own[0] += d[0], own[1] += d[1];
        x->premul_seconds = d[0];
        if (N > 1) dist_allreduce_sum(x->data, x->rows * x->cols);
        phase_time(t0, &d[0], &d[1]);
        sum[0] += d[0], sum[1] += d[1];
        x->premul_seconds += d[0];
        progress_show(progress, "pre-multiplication", ++done, ntensors);
      }
    }
  }
  if (progress && N > 1)
    fprintf(stderr, "pre-multiplication over ranks: %.2f s (%.2f s CPU) this rank's rows, %.2f s (%.2f s CPU) summing "
            "the tensors\n", own[0], own[1], sum[0], sum[1]);
  return 0;
}

bool train_keeps_basis(const Model *m, const TrainOptions *opt, int c) {
  return !opt->stream || keep_named(m, opt->keep_bases, c, NULL, 0);
}

/* Issue 30: the classes whose bases are streamed — used in training, then
 * dropped (train_drop_bases) — marked once the reduction of every stage is
 * chosen (an interpolated stage's class is needed): the streamable ones
 * (model_class_streamable) --keep-bases does not name. */
bool train_mark_streamed(Model *m, const TrainOptions *opt) {
  bool any = false; /* whose floors are still to be taken */
  for (int c = 0; c < m->nclasses; c++) { /* the names were checked by train_begin; out of core kept as coefficients */
    m->classes[c].streamed =
        (!train_keeps_basis(m, opt, c) && model_class_streamable(m, c)) || m->classes[c].coef_S > 0;
    any |= m->classes[c].streamed && !m->classes[c].floors_known;
  }
  return any;
}

/* Sample k's projection floors (model_projection_floor) of every quantity
 * of a streamed class, added to their means over the S samples: verify
 * reports them in place of the held-out floors it cannot measure without
 * the basis. `gram`: the values are the evaluator's (the sample just
 * evaluated), else the snapshots'. */
void train_take_floors(Model *m, Full *f, const Snapshots *sn, bool gram, long k, long S, double *proj, double *y) {
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; m->classes[c].streamed && !m->classes[c].floors_known && i < m->classes[c].nmembers; i++) {
      RMember *mb = &m->classes[c].members[i];
      if (mb->q < 0) continue; /* a numerator is no quantity verify reports */
      const double *val = gram ? full_get(f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL)
                               : sn->X[c][i] + (size_t)k * (size_t)m->classes[c].n;
      double fl[2];
      model_projection_floor(&m->classes[c], val, proj, y, fl);
      mb->floor_l2 += fl[0] / (double)S, mb->floor_linf += fl[1] / (double)S;
    }
}

/* Step 5: the streamed classes' bases dropped (their floors taken). */
void train_drop_bases(Model *m) {
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!rc->streamed) continue;
    if (rc->B_mapped) munmap(rc->B, rc->B_mapped);
    else free(rc->B);
    rc->B = NULL, rc->B_mapped = 0;
    free(rc->train_coords);
    rc->train_coords = NULL;
  }
}

static int fit_externs_floors(Model *m, Full *f, const SampleSource *src, const Snapshots *sn, bool gram, int nx,
                              bool floors, double *proj, double *y, bool progress, bool dist, char *err, size_t errlen);

/* Step 4: with `externs` every extern's learned map (paper §8.3): the
 * training samples' reduced inputs and values, from the snapshots or, after
 * the method of snapshots, recomputed; with `floors`, in the same pass the
 * streamed classes' training floors (train_take_floors). */
int train_fit_externs(Model *m, Full *f, const SampleSource *src, const Snapshots *sn, bool gram, bool externs, bool floors,
                      bool progress, bool dist, char *err, size_t errlen) {
  long maxn = 1, maxm = 1;
  for (int c = 0; floors && c < m->nclasses; c++)
    if (m->classes[c].streamed && !m->classes[c].floors_known)
      maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn, maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  double *y = floors ? malloc(sizeof(double) * (size_t)maxn) : NULL, *proj = floors ? malloc(sizeof(double) * (size_t)maxm) : NULL;
  int rc = floors && (!y || !proj) ? error_set(err, errlen, "out of memory measuring the training floors")
                                     : fit_externs_floors(m, f, src, sn, gram, externs ? m->nexterns : 0, floors, proj, y,
                                                          progress, dist, err, errlen);
  free(y);
  free(proj);
  return rc;
}

static int fit_externs_floors(Model *m, Full *f, const SampleSource *src, const Snapshots *sn, bool gram, int nx,
                              bool floors, double *proj, double *y, bool progress, bool dist, char *err, size_t errlen) {
  long S = src->count;
  /* recomputed over ranks (out of core): rank r its samples k ≡ r (mod N),
   * the others' rows zero, then summed */
  int N = gram && dist ? dist_size() : 1, rank = N > 1 ? dist_rank() : 0;
  for (int i = 0; i < nx; i++) {
    RExtern *x = &m->externs[i];
    long mz = m->classes[m->qclass[x->q]].m;
    x->S = S;
    if (!(x->X = mem_calloc((size_t)(S * x->d + 1), sizeof(double))) || !(x->Z = mem_calloc((size_t)(S * mz) + 1, sizeof(double))))
      return error_set(err, errlen, "out of memory while training");
  }
  /* an extern's map reads only what a sample gives (its inputs and externs are the program's own):
   * setting the sample is enough, no evaluation (at the paper's size each is a 5,000-face solve) */
  bool given_only = !floors;
  for (int i = 0; i < nx; i++)
    for (int j = 0; j <= m->externs[i].nin; j++) {
      const Sym *s = m->prog->quantities.v[j < m->externs[i].nin ? m->externs[i].in_q[j] : m->externs[i].q];
      given_only &= s->kind == SYM_INPUT || s->kind == SYM_EXTERN;
    }
  for (long k = rank; k < S && (nx > 0 || floors); k += N) {
    if (gram && given_only && src->set(src->user, f, k) != 0) return error_set(err, errlen, "%s", full_error(f));
    if (gram && !given_only && train_eval_sample(src, f, k, err, errlen)) return -1; /* recompute: no snapshot was kept */
    for (int i = 0; i < nx; i++) {
      RExtern *x = &m->externs[i];
      long mz = m->classes[m->qclass[x->q]].m, off = 0;
      for (int j = 0; j <= x->nin; j++) {
        int q = j < x->nin ? x->in_q[j] : x->q;
        RClass *rc = &m->classes[m->qclass[q]];
        const double *val = full_get(f, ((Sym *)m->prog->quantities.v[q])->name, NULL);
        if (!gram) {
          int mi = 0;
          while (rc->members[mi].q != q) mi++;
          val = sn->X[m->qclass[q]][mi] + (size_t)k * (size_t)rc->n;
        }
        double *dst = j < x->nin ? x->X + k * x->d + off : x->Z + k * mz;
        if (!rc->B && rc->train_coords) /* kept as coefficients: its coordinates from the basis passes */
          memcpy(dst, rc->train_coords + k * rc->m, sizeof(double) * (size_t)rc->m);
        else cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)rc->m, 1.0, model_projector(rc), (int)rc->m, val, 1,
                         0.0, dst, 1);
        if (j < x->nin) off += rc->m;
      }
    }
    if (floors) train_take_floors(m, f, sn, gram, k, S, proj, y);
    if (gram) progress_show(progress, floors ? "extern samples, floors" : "extern samples", k + 1, S);
  }
  if (gram && given_only) full_forget_given(f); /* set, never evaluated: callbacks as before */
  for (int i = 0; N > 1 && i < nx; i++) {
    RExtern *x = &m->externs[i];
    dist_allreduce_sum(x->X, S * x->d);
    dist_allreduce_sum(x->Z, S * m->classes[m->qclass[x->q]].m);
  }
  for (int c = 0; N > 1 && floors && c < m->nclasses; c++) /* every rank's samples' floors summed */
    for (int i = 0; m->classes[c].streamed && !m->classes[c].floors_known && i < m->classes[c].nmembers; i++) {
      dist_allreduce_sum(&m->classes[c].members[i].floor_l2, 1);
      dist_allreduce_sum(&m->classes[c].members[i].floor_linf, 1);
    }
  return 0;
}

/* Step 3b: the stages opt->interp_stage names made interpolated, and with
 * validation samples every other eligible stage reduced the way that
 * measures better there (DESIGN §12). */
static bool named_in(const char *const *names, int n, const char *name) {
  for (int j = 0; j < n; j++)
    if (strcmp(names[j], name) == 0) return true;
  return false;
}

int train_interpolate_stages(Model *m, Full *f, const TrainOptions *opt, char *err, size_t errlen) {
  double over = opt->interp_oversample > 0 ? opt->interp_oversample : TRAIN_INTERP_OVERSAMPLE;
  /* the program's `basis w: reduce interp`, unless the command line says galerkin */
  for (int i = 0; i < m->nstages; i++) {
    const Sym *s = m->stages[i].st->sym;
    if (s->reduce != STAGE_REDUCE_INTERP || named_in(opt->galerkin_stage, opt->ngalerkin, s->name) ||
        named_in(opt->interp_stage, opt->ninterp, s->name))
      continue;
    if (interp_train_stage(m, f, i, over, err, errlen)) return -1;
    m->stages[i].choice_reason = interp_reasons[INTERP_FORCED];
  }
  for (int j = 0; j < opt->ninterp; j++) {
    int i = 0;
    while (i < m->nstages && strcmp(m->stages[i].st->sym->name, opt->interp_stage[j]) != 0) i++;
    if (i == m->nstages)
      return error_set(err, errlen, "--reduce %s:interp: the program has no stage '%s'", opt->interp_stage[j],
                       opt->interp_stage[j]);
    if (interp_train_stage(m, f, i, over, err, errlen)) return -1;
    m->stages[i].choice_reason = interp_reasons[INTERP_FORCED];
    if (opt->progress)
      fprintf(stderr, "stage %s interpolated: %ld of %ld entries (m %ld), ‖(WPB)⁺‖ %.3g\n", opt->interp_stage[j],
              m->stages[i].interp->k, m->classes[m->qclass[m->stages[i].q]].n, m->stages[i].interp->m,
              m->stages[i].interp->pinv_norm);
  }
  for (int j = 0; j < opt->ngalerkin; j++) {
    int i = 0;
    while (i < m->nstages && strcmp(m->stages[i].st->sym->name, opt->galerkin_stage[j]) != 0) i++;
    if (i == m->nstages)
      return error_set(err, errlen, "--reduce %s:galerkin: the program has no stage '%s'", opt->galerkin_stage[j],
                       opt->galerkin_stage[j]);
    if (named_in(opt->interp_stage, opt->ninterp, opt->galerkin_stage[j]))
      return error_set(err, errlen, "stage %s is forced both to interpolation and to Galerkin", opt->galerkin_stage[j]);
  }
  return opt->valid ? tune_choose_reductions(m, f, opt->valid, opt, err, errlen) : 0;
}

/* Steps 1–2: the bases, from snapshots in memory, by the method of
 * snapshots, or out of core when the bases exceed opt->mem (ooc.c; then,
 * as after the method of snapshots, *gram: no snapshot is kept). Ends the
 * phase of the snapshots (out of core: the snapshots and the bases are one
 * step, timed as snapshots). */
static int bases(Model *m, Full *f, const SampleSource *src, const TrainOptions *opt, Snapshots *sn, bool *gram,
                 struct timespec clock[2], char *err, size_t errlen) {
  if (ooc_needed(m, opt, src->count)) {
    for (int c = 0; c < m->nclasses; c++)
      if (m->classes[c].product)
        return error_set(err, errlen, "basis %s: product %s is not implemented out of core (the bases exceed --mem: "
                         "raise it)", m->classes[c].bc->size_name, m->classes[c].product->name);
    *gram = true;
    train_mark_streamed(m, opt); /* their floors taken in the passes (the choice is made again after interpolation) */
    if (ooc_bases(m, f, src, opt, err, errlen)) return -1;
    phase_end(clock, m, PHASE_SNAPSHOTS);
    return 0;
  }
  if (train_take_snapshots(m, f, src, opt, sn, gram, err, errlen)) return -1;
  phase_end(clock, m, PHASE_SNAPSHOTS);
  return build_bases(m, f, sn, *gram, opt, err, errlen);
}

/* Step 5: the model trained evaluated on three of its own training samples
 * (the first, the middle and the last). Without held-out samples nothing
 * else runs it before the user does: a Galerkin root whose reduced
 * operator was indefinite at every input trained "fine" and then failed
 * every evaluation (issue 38). A failure is kept for the report
 * (report_training warns); training itself succeeds. Not over ranks: a
 * rank holds only its own samples; not with externs: setting a sample again
 * may call an extern's callback again, which runs once per sample (the
 * radiosity visibility: seconds a sample). */
static void self_check(Model *m, Full *f, const SampleSource *src) {
  m->self_check_sample = -1;
  char err[600];
  Reduced *r = src->count > 0 && m->nexterns == 0 ? reduced_new(m, err, sizeof err) : NULL;
  if (!r) return;
  long pick[3] = {0, src->count / 2, src->count - 1};
  for (int i = 0; i < 3 && m->self_check_sample < 0; i++) {
    long k = pick[i];
    if (i > 0 && k == pick[i - 1]) continue;
    if (src->set(src->user, f, k) != 0) break;
    bool ok = true;
    for (int q = 0; q < m->nq && ok; q++) {
      const Sym *s = m->prog->quantities.v[q];
      if (s->kind != SYM_INPUT) continue;
      size_t n = 0;
      const double *v = full_get(f, s->name, &n);
      if (!v || (long)n != m->classes[m->qclass[q]].n) ok = false;
      else reduced_project(r, q, v);
    }
    if (ok && reduced_eval(r, k) != 0) {
      m->self_check_sample = k;
      snprintf(m->self_check_failure, sizeof m->self_check_failure, "%.590s", reduced_error(r));
    }
  }
  reduced_free(r);
}

/* Training as named steps (DESIGN §5), each phase's wall and CPU time kept. */
Model *train_model(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen) {
  Snapshots sn = {0};
  bool gram = false;
  struct timespec clock[2];
  err[0] = 0;
  /* the weights themselves are checked where they are given (npg_trainer_weight) */
  if (opt->weights && opt->joint) {
    error_set(err, errlen, "sample weights are not implemented with --merge joint: use --merge concat");
    return NULL;
  }
  phase_start(clock);
  Model *m = train_begin(prog, f, src, opt, err, errlen);
  if (!m) goto fail;
  if (bases(m, f, src, opt, &sn, &gram, clock, err, errlen)) goto fail;
  phase_end(clock, m, PHASE_BASES);
  if (train_premultiply_all(m, f, opt->progress, opt->dist, err, errlen)) goto fail;
  /* the choice on validation samples (DESIGN §12) measures the reduced model, its externs' learned
   * maps included: with both, they are fitted first (they read the bases, not the reductions), and
   * the streamed classes' floors, known only once the choice is made, take a pass of their own */
  bool externs_first = opt->valid && m->nexterns > 0;
  if (externs_first && train_fit_externs(m, f, src, &sn, gram, true, false, opt->progress, opt->dist, err, errlen)) goto fail;
  if (train_interpolate_stages(m, f, opt, err, errlen)) goto fail;
  if (train_estimates(m, f, src, opt, err, errlen)) goto fail;
  phase_end(clock, m, PHASE_PREMULTIPLY);
  bool floors = train_mark_streamed(m, opt); /* the reductions chosen: which bases are streamed is known */
  if ((!externs_first || floors) &&
      train_fit_externs(m, f, src, &sn, gram, !externs_first, floors, opt->progress, opt->dist, err, errlen))
    goto fail;
  train_drop_bases(m);
  phase_end(clock, m, PHASE_EXTERNS);
  if (opt->progress)
    fprintf(stderr, "training phases: snapshots %.2f s, bases %.2f s (%s), pre-multiplication %.2f s, externs %.2f s\n",
            m->phase_seconds[PHASE_SNAPSHOTS], m->phase_seconds[PHASE_BASES],
            ooc_needed(m, opt, src->count) ? "out of core, with the snapshots" : gram ? "method of snapshots" : "in memory",
            m->phase_seconds[PHASE_PREMULTIPLY], m->phase_seconds[PHASE_EXTERNS]);
  train_free_snapshots(m, &sn);
  m->self_check_sample = -1;
  if (!opt->dist) self_check(m, f, src);
  return m;
fail:
  if (m) train_free_snapshots(m, &sn);
  model_free(m);
  /* the steps name what failed; a helper that only returned NULL ran out of memory */
  if (!err[0]) error_set(err, errlen, "out of memory during training");
  return NULL;
}
