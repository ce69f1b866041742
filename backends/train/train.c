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
 * train_steps below is that list, each step a function of the training
 * context (Train, train_steps.h: the program, the evaluator, the samples,
 * the options, the model, the snapshots, the error record), each phase
 * timed; train_model around it holds training's policy: the weights
 * scaled, the params' hashes, samples held out to choose the reductions
 * on and the model trained again with the choice fixed. The tune sample
 * set (train_set.c) runs 0–1 and every member's PCA once, then builds
 * models of any caps from truncations of those bases, steps 2–4 only. Elsewhere: the method of snapshots (snapshots.c), --merge joint
 * (joint.c), out of core (ooc.c), over MPI ranks (dist_train.c), the
 * progress bar (progress.c).
 */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "dist.h"
#include "interp.h"
#include "reduced.h"
#include "scratch.h"
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
static int field_value(Full *f, const RTensor *ts, int nt, double *out, long n, Err *err) {
  memset(out, 0, sizeof(double) * (size_t)n);
  for (int g = 0; g < nt; g++) {
    FieldSum s = {{0}, out, n};
    for (int i = 0; i < ts[g].group->ninputs; i++) s.in[i] = full_get(f, ts[g].group->inputs[i]->name, NULL);
    NpgSink sink = {&s, sum_entry, 0, 1, 0, 0}; /* every row */
    if (full_build(f, ts[g].builder, &sink) != 0) return err_set(err, "%s", full_error(f));
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
static int check_overrides(const Model *m, const TrainOptions *opt, Err *err) {
  for (int i = 0; i < opt->user->nbasis; i++) {
    bool found = false;
    for (int c = 0; c < m->nclasses && !found; c++)
      for (int k = 0; k < m->classes[c].nmembers && !found; k++)
        found = override_level(&m->classes[c], &m->classes[c].members[k], opt->user->basis_name[i]) > 0;
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
    return err_set(err,
                   "--basis %s: no quantity, class or numerator of that name; classes (members): %s, or '*' for all",
                   opt->user->basis_name[i], list);
  }
  return 0;
}

/* A member's cap, energy and centering: the defaults (energy 1 for a
 * quantity under a power, `powered`, whatever the default energy, and for
 * an input with `inputs_whole`, greedy training's), then the
 * program's `basis` statements, then --basis from the least specific to the
 * most. */
static void member_options(const Model *m, const RClass *c, RMember *mb, const TrainOptions *opt,
                           const bool *powered) {
  mb->cap = opt->user->cap > 0 ? opt->user->cap : 60;
  mb->energy = powered && mb->q >= 0 && powered[mb->q] ? 1 : opt->user->energy > 0 ? opt->user->energy : 0.999;
  if (opt->inputs_whole && mb->q >= 0 && ((const Sym *)m->prog->quantities.v[mb->q])->kind == SYM_INPUT) mb->energy = 1;
  mb->center = !opt->user->uncentered;
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
    for (int i = 0; i < opt->user->nbasis; i++) {
      if (override_level(c, mb, opt->user->basis_name[i]) != level) continue;
      if (opt->user->basis_cap[i] > 0) mb->cap = opt->user->basis_cap[i], named |= level == 3;
      if (opt->user->basis_energy[i] > 0) mb->energy = opt->user->basis_energy[i];
      if (opt->user->basis_center && opt->user->basis_center[i] >= 0) mb->center = opt->user->basis_center[i];
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
static int class_products(Model *m, const TrainOptions *opt, Err *err) {
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    int best = 0;
    for (int i = 0; opt->user->basis_product && i < opt->user->nbasis; i++) {
      const char *name = opt->user->basis_product[i];
      int level = 0;
      for (int k = 0; name && k < rc->nmembers; k++) {
        int l = override_level(rc, &rc->members[k], opt->user->basis_name[i]);
        level = l > level ? l : level;
      }
      if (!name || level == 0 || level < best) continue;
      const Sym *op = NULL;
      for (int j = 0; j < m->prog->ops.n && !op; j++)
        if (strcmp(((const Sym *)m->prog->ops.v[j])->name, name) == 0) op = m->prog->ops.v[j];
      bool square = op && op->nivars == 2 * op->nrow;
      for (int a = 0; square && a < op->nrow; a++) square = op->ivars[a]->range == op->ivars[op->nrow + a]->range;
      if (!op || !square)
        return err_set(err, "--basis %s:product=%s: %s", opt->user->basis_name[i], name,
                       !op ? "the program has no op of that name (the product is an SPD op of the program)"
                           : "not a square operator (its rows and columns must run over the same dims)");
      rc->product = op, best = level;
    }
  }
  return 0;
}

/* ---------------------------------------------------------------- training */

/* The current step's scratch, reporting into the context's error record (a
 * context made by designated initializers starts with an empty Scratch of no record). */
static Scratch *step_scratch(Train *t) {
  t->scratch.err = t->err;
  return &t->scratch;
}

void *train_scratch(Train *t, size_t bytes) { return scratch_alloc(step_scratch(t), bytes); }

void train_scratch_free(Train *t) { scratch_release(&t->scratch); }

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

/* The SPD marks of the diagonal operators into spd[] (`apply`: from it), in FOR_DIAG_OPS order;
 * their number (spd NULL: counted only). */
static int spd_marks(Model *m, bool *spd, bool apply) {
  int j = 0;
  FOR_DIAG_OPS(m, rs, rt, ro) {
    if (spd && apply) ro->spd = spd[j];
    else if (spd) spd[j] = ro->spd;
    j++;
  }
  return j;
}

static RTerm *joiner_term(Model *m, const Joiner *j) {
  for (int i = 0; i < m->nstages; i++)
    if (m->stages[i].st == j->stage) return &m->stages[i].terms[j->term];
  return NULL;
}


/* Set and evaluate training sample k. */
int train_eval_sample(const SampleSource *src, Full *f, long k, Err *err) {
  if (src->set(src->user, f, k) != 0 || full_eval(f, k) != 0) return err_set(err, "%s", full_error(f));
  return 0;
}

/* The current value of a class member (a quantity, or an unnamed numerator
 * through its builders) at sample k into out[0..n); refused when not
 * finite, since a basis of it would be meaningless (and the SVD would fail
 * without saying why). */
int train_member_value(Train *t, const RMember *mb, long k, long n, double *out) {
  Model *m = t->m;
  Full *f = t->f;
  Err *err = t->err;
  if (mb->q >= 0) {
    memcpy(out, full_get(f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL), sizeof(double) * (size_t)n);
  } else {
    RTerm *rt = joiner_term(m, mb->joiner);
    if (!rt) return err_set(err, "a numerator without its term (a bug in npg)");
    if (field_value(f, rt->num, rt->nnum, out, n, err)) return -1;
  }
  for (long e = 0; e < n; e++)
    if (!isfinite(out[e])) {
      /* name where the NaN arises (the first quantity in evaluation order
       * holding one), not the member that happened to be looked at */
      const Sym *s;
      char at[256], cause[512];
      double v;
      if (full_first_nonfinite(f, &s, at, sizeof at, &v, cause, sizeof cause))
        return err_set(err, "training sample %ld: %s is not finite (%s%s is %s): %s%s%s", k, s->name, s->name, at,
                       isnan(v) ? "NaN"
                       : v > 0  ? "inf"
                                : "-inf",
                       cause[0] ? "the sample makes it undefined (" : "",
                       cause[0] ? cause
                                : "the sample makes it undefined (a division by zero or a root of a negative "
                                  "number in the program?)",
                       cause[0] ? ")" : "");
      return err_set(err,
                     "training sample %ld: %s is not finite (entry %ld is %g): the sample makes it undefined (a "
                     "division by zero or a root of a negative number in the program?)",
                     k, mb->name, e, out[e]);
    }
  return 0;
}

/* A diagonal operator stays marked SPD while every training diagonal seen is
 * positive (then BᵀDB is SPD for every basis: Cholesky). */
int train_check_spd(Train *t, double *tmp) {
  Model *m = t->m;
  FOR_DIAG_OPS(m, rs, rt, ro) {
    if (!ro->spd) continue;
    long n = m->classes[m->qclass[rs->q]].n;
    if (field_value(t->f, ro->t, ro->ntensors, tmp, n, t->err)) return -1;
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
int train_member_bases(RClass *rc, long S, double *const *X, const double *w, PcaMember *pre, Err *err) {
  Scratch sc = SCRATCH_OF(err);
  double **U = scratch_array(&sc, (size_t)rc->nmembers + 1, sizeof(double *));
  int *kk = scratch_array(&sc, (size_t)rc->nmembers + 1, sizeof(int)), rc_ok = U && kk ? 0 : -1;
  for (int i = 0; i < rc->nmembers && rc_ok == 0; i++) {
    RMember *mb = &rc->members[i];
    PcaMember p;
    if (pre) p = pre[i], memset(&pre[i], 0, sizeof pre[i]);
    else rc_ok = pca_basis(rc->n, S, X[i], &(PcaRule){mb->cap, mb->energy, mb->center, w}, &p, err);
    if (rc_ok) break;
    kk[i] = p.k;
    take_pca(mb, &p);
    if (!(U[i] = scratch_adopt(&sc, p.U))) rc_ok = -1; /* the member's basis, until merged */
  }
  if (rc_ok == 0) rc_ok = pca_merge(rc->n, (PcaBlocks){rc->nmembers, U, kk}, &rc->B, &rc->m, err);
  scratch_release(&sc);
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

/* A root (p/q, q > 1) in a class with a product is refused (issue 41), and so is a diagonal operator to a power ≤ -2,
 * unless --reduce names the stage interp (diagonal operators only). A root's Galerkin value on B's span is B f(RᵀMB) ĉ (R = B (BᵀB)⁻¹), f of
 * an operator similar to the symmetric (BᵀB)^-½ BᵀMB (BᵀB)^-½ but not symmetric itself, which the reduced code's
 * symmetric root cannot take; a diagonal operator's reduced matrix is stored packed symmetric, so it cannot take the
 * rows R that pass coordinates between its solves (model_term_coords); and the 2-norm's (BᵀMB)^α Bᵀw, (BᵀDB)^-p Bᵀw
 * are no approximation there (BᵀB ≠ I: 100% off and more on the test's data). */
static int product_powers(const Model *m, const TrainOptions *opt, Err *err) {
  for (int i = 0; i < m->nstages; i++) {
    const RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
    const char *name = m->stages[i].st->sym->name;
    if (!rc->product || named_in(opt->user->interp_stage, opt->user->ninterp, name)) continue;
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = 0; k < m->stages[i].terms[t].nops; k++) {
        const OpPow *o = m->stages[i].terms[t].ops[k].op;
        bool root = o->q != 1;
        if (root || (o->kind == OPK_DIAG && o->p <= -2))
          return err_set(err, "stage %s: %s (power %ld/%ld) in class %s, orthonormal in the product %s, has no "
                         "Galerkin reduction in npg (%s; the 2-norm's reduction is no approximation where BᵀB ≠ I): "
                         "drop the product from the basis of %s (a stage of diagonal operators only may instead be "
                         "interpolated: --reduce %s:interp)", name, root ? "a root" : "a diagonal operator's inverse "
                         "power", o->p, o->q, rc->label, rc->product->name,
                         root ? "its reduced operator (BᵀB)⁻¹BᵀMB is not symmetric"
                              : "its packed symmetric reduced matrix cannot pass coordinates between its solves",
                         name, name);
      }
  }
  return 0;
}

/* The model's layout for the dims sample 0 binds, with every member's
 * options set and the --basis names checked (t->m). */
int train_begin(Train *t) {
  const TrainOptions *opt = t->opt;
  Program *prog = t->prog;
  if (t->src->count < 1) return err_set(t->err, "no training samples");
  if (t->src->set(t->src->user, t->f, 0) != 0) return err_set(t->err, "%s", full_error(t->f)); /* it binds every dim */
  t->sample0_set_only = snapshot_cache_begin(t); /* the cache's pass evaluates it if it does not hold it */
  if (!t->sample0_set_only && full_eval(t->f, 0) != 0) return err_set(t->err, "%s", full_error(t->f));
  long *dims = train_scratch(t, sizeof(long) * ((size_t)prog->dims.n + 1));
  if (!dims) return -1;
  for (int i = 0; i < prog->dims.n; i++) dims[i] = full_dim_size(t->f, i);
  Model *m = t->m = model_layout(prog, dims, t->err);
  if (!m) return -1;
  m->samples = t->src->count;
  bool *marked = lower_under_powers(m->prog), *powered = scratch_adopt(step_scratch(t), marked);
  if (marked && !powered) return -1;
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++)
      member_options(m, &m->classes[c], &m->classes[c].members[i], opt, powered);
  if (class_products(m, opt, t->err) || product_powers(m, opt, t->err) || model_named_projections(m, t->err))
    return -1;
  char unknown[256] = ""; /* a misspelt --keep-bases name is refused before training, not after */
  if (m->nclasses > 0) keep_named(m, opt->user->keep_bases, 0, unknown, sizeof unknown);
  if (unknown[0])
    return err_set(t->err, "--keep-bases %s: no quantity or class of that name (a quantity, a class m_x, or all)",
                   unknown);
  return check_overrides(m, opt, t->err);
}

int train_check_names(Program *prog, const TrainOptions *opt, Err *err) {
  /* classes and stages do not depend on the dims' sizes: the layout at size 1 names them all */
  Scratch sc = SCRATCH_OF(err);
  long *dims = scratch_array(&sc, (size_t)prog->dims.n + 1, sizeof(long));
  for (int i = 0; dims && i < prog->dims.n; i++) dims[i] = 1;
  Model *m = dims ? model_layout(prog, dims, err) : NULL;
  scratch_release(&sc);
  if (!m) return -1;
  char unknown[256] = "";
  int rc = 0;
  if (m->nclasses > 0) keep_named(m, opt->user->keep_bases, 0, unknown, sizeof unknown);
  if (unknown[0])
    rc = err_set(err, "--keep-bases %s: no quantity or class of that name (a quantity, a class m_x, or all)", unknown);
  if (rc == 0) rc = check_overrides(m, opt, err);
  if (rc == 0) rc = class_products(m, opt, err);
  for (int l = 0; l < 2 && rc == 0; l++) {
    const char *const *names = l ? opt->user->galerkin_stage : opt->user->interp_stage;
    for (int j = 0; j < (l ? opt->user->ngalerkin : opt->user->ninterp) && rc == 0; j++) {
      int i = 0;
      while (i < m->nstages && strcmp(m->stages[i].st->sym->name, names[j]) != 0) i++;
      if (i == m->nstages)
        rc = err_set(err, "--reduce %s:%s: the program has no stage '%s'", names[j], l ? "galerkin" : "interp",
                     names[j]);
      else if (!l && !lower_interp_eligible(m->stages[i].st))
        rc = err_set(err, "--reduce %s:interp: stage %s cannot be interpolated: %s", names[j], names[j],
                     m->stages[i].st->kind == ST_INVERSE || m->stages[i].st->kind == ST_ROOT
                         ? "one of its operators is a declared op, not diagonal (npgc check says which stages can)"
                         : "it applies no diagonal operator (npgc check says which stages can)");
      else if (l && named_in(opt->user->interp_stage, opt->user->ninterp, names[j]))
        rc = err_set(err, "stage %s is forced both to interpolation and to Galerkin", names[j]);
    }
  }
  model_free(m);
  return rc;
}

int train_fail_hook(const Train *t, long k) {
  if (!t->opt->dist || k != dist_rank() || !dist_fail_here()) return 0;
  return err_set(t->err,
                 "training sample %ld: NPG_MPI_FAIL_RANK=%d: this rank stops after its first sample (a test hook)", k,
                 dist_rank());
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

/* Sample k's SPD marks checked (train_check_spd); with the cache, checked alone as well (every
 * mark set first, then and-ed with those before: the same marks) and noted with its snapshots.
 * `before`: room for the marks. */
static int check_spd_noted(Train *t, double *tmp, bool *before, long k) {
  if (!snapshot_cache_usable(t)) return train_check_spd(t, tmp);
  int nspd = spd_marks(t->m, before, false);
  train_mark_spd(t->m);
  if (train_check_spd(t, tmp)) return -1;
  bool *own = before + nspd;
  spd_marks(t->m, own, false);
  snapshot_cache_note(t, k, own, nspd);
  for (int j = 0; j < nspd; j++) own[j] = own[j] && before[j];
  spd_marks(t->m, own, true);
  return 0;
}

/* Every member's snapshots into sn->X, the SPD marks checked on every
 * sample. Over ranks (opt->dist): rank r takes the samples k ≡ r (mod N),
 * then the columns are gathered on every rank (a rank that fails returns
 * here, before the gather: its caller ends the job). Sample 0 is already
 * evaluated (train_begin). `tmp`: room for the largest class. */
static int snapshots_in_memory(Train *t, double *tmp) {
  Model *m = t->m;
  const TrainOptions *opt = t->opt;
  long S = t->sn.S;
  int rc = 0, rank = opt->dist ? dist_rank() : 0, N = opt->dist ? dist_size() : 1, nspd = spd_marks(m, NULL, false);
  bool *spd = train_scratch(t, sizeof(bool) * (size_t)(2 * nspd + 1));
  if (!spd) return -1;
  spd_marks(m, spd, false);
  snapshot_cache_take(t, spd, nspd); /* the snapshots and marks of the samples it holds */
  spd_marks(m, spd, true);
  long last = rank < S ? rank + (S - 1 - rank) / N * N : -1; /* this rank's last sample */
  for (long k = rank; rc == 0 && k < S; k += N) {
    /* the last sample evaluated though kept: the evaluator ends on its values, as without the cache */
    bool kept = snapshot_cache_kept(t, k) && k != last;
    if (!kept && (k > 0 || t->sample0_set_only) && train_eval_sample(t->src, t->f, k, t->err)) rc = -1;
    for (int c = 0; rc == 0 && !kept && c < m->nclasses; c++) {
      RClass *cl = &m->classes[c];
      for (int i = 0; rc == 0 && i < cl->nmembers; i++)
        rc = train_member_value(t, &cl->members[i], k, cl->n, t->sn.X[c][i] + (size_t)k * (size_t)cl->n);
    }
    if (rc == 0 && !kept) rc = check_spd_noted(t, tmp, spd, k);
    if (rc == 0) rc = train_fail_hook(t, k);
    progress_show(opt->user->progress, "snapshots", k + 1, S);
  }
  if (rc == 0 && N > 1 && (rc = dist_gather_snapshots(m, t->sn.X, S, t->err)) == 0) {
    dist_and_spd(m);
    progress_show(opt->user->progress, "snapshots", S, S); /* every rank's are in */
  }
  return rc;
}

size_t train_snapshot_bytes(const Model *m, long S) {
  size_t need = 0;
  for (int c = 0; c < m->nclasses; c++)
    need += sizeof(double) * (size_t)m->classes[c].n * (size_t)S * (size_t)m->classes[c].nmembers;
  return need;
}

/* Sample 0 evaluated when train_begin only set it (the cache held it) but a route that keeps no
 * snapshot follows: what it finds in the evaluator is what it found without the cache. */
static int evaluate_sample0(Train *t) {
  if (!t->sample0_set_only) return 0;
  t->sample0_set_only = false;
  return train_eval_sample(t->src, t->f, 0, t->err);
}

/* Step 1: every member's snapshots in memory (t->sn.X), or, when they need
 * more than opt->user->mem, their bases by the method of snapshots (t->sn.U,
 * t->sn.k; t->gram set). Marks which diagonal operators stay SPD. */
int train_take_snapshots(Train *t) {
  Model *m = t->m;
  const TrainOptions *opt = t->opt;
  long S = t->src->count, maxn = 1;
  size_t need = train_snapshot_bytes(m, S);
  for (int c = 0; c < m->nclasses; c++) maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
  bool gram = t->gram = opt->user->mem && need > opt->user->mem;
  if (gram && opt->dist && dist_size() > 1)
    return err_set(t->err,
                   "the snapshots need %.3g GB, more than --mem %.3g GB: training over MPI ranks keeps them in "
                   "memory (the method of snapshots runs on one process): raise --mem",
                   (double)need / 1e9, (double)opt->user->mem / 1e9);
  if (gram && opt->weights)
    return err_set(t->err,
                   "the snapshots need %.3g GB, more than --mem %.3g GB, and sample weights are not implemented in the "
                   "method of snapshots: raise --mem to keep them in memory",
                   (double)need / 1e9, (double)opt->user->mem / 1e9);
  if (gram && opt->user->joint)
    return err_set(t->err,
                   "the snapshots need %.3g GB, more than --mem %.3g GB, and --merge joint needs them in memory: raise "
                   "--mem or use --merge concat (the method of snapshots)",
                   (double)need / 1e9, (double)opt->user->mem / 1e9);
  double *tmp = train_scratch(t, sizeof(double) * (size_t)(maxn > S ? maxn : S));
  if (!tmp || snapshots_alloc(m, &t->sn, S, gram))
    return err_set(t->err, "out of memory for the snapshots of %ld samples", S);
  if (gram && evaluate_sample0(t)) return -1;
  train_mark_spd(m);
  return gram ? train_snapshot_bases(t, tmp) : snapshots_in_memory(t, tmp);
}

/* A class basis completed to full rank (convergence tests: the PCA
 * directions first, then the rest of the space), and one direction for a
 * class whose every snapshot is zero (lifting gives 0). */
int train_complete_basis(RClass *rc, bool full_rank, Err *err) {
  if (full_rank && rc->m < rc->n) {
    Scratch sc = SCRATCH_OF(err);
    double *eye = scratch_array(&sc, (size_t)(rc->n * rc->n), sizeof(double)), *B = NULL;
    double *parts[2] = {rc->B, eye};
    int ks[2] = {(int)rc->m, (int)rc->n}, mm = (int)rc->m;
    int rc_ok = eye ? 0 : err_set(err, "out of memory completing the basis of class %s", rc->label);
    for (long e = 0; eye && e < rc->n; e++) eye[e * rc->n + e] = 1;
    if (eye) rc_ok = pca_in_order(rc->n, (PcaBlocks){2, parts, ks}, &B, &mm, err); /* the PCA directions first */
    rc->m = mm;
    scratch_release(&sc);
    if (rc_ok != 0) return -1;
    free(rc->B); /* replaced by its completion */
    rc->B = B;
  }
  if (rc->m == 0) {
    free(rc->B); /* replaced by one direction */
    if (!(rc->B = mem_calloc((size_t)rc->n, sizeof(double)))) return err_set(err, "out of memory");
    rc->B[0] = 1;
    rc->m = 1;
  }
  if (!rc->B_mapped && pca_fix_signs(rc->n, rc->m, rc->B)) return err_set(err, "out of memory");
  return 0;
}

/* Class `rc`'s basis from the snapshots (`pre`: its members' PCAs made over ranks, or NULL). */
static int class_basis(Train *t, RClass *rc, PcaMember *pre, bool over_ranks) {
  const Snapshots *sn = &t->sn;
  const TrainOptions *opt = t->opt;
  bool gram = t->gram;
  Err *err = t->err;
  int c = (int)(rc - t->m->classes), rc_ok = 0;
  if (rc->product) { /* issue 41: BᵀK0B = I, a transform around the members' PCAs (product.c) */
    const char *why = gram ? "the snapshots do not fit in --mem (raise it)"
                      : opt->user->joint && rc->nmembers > 1 ? "--merge joint (use --merge concat)"
                      : over_ranks ? "training over MPI ranks" : NULL;
    if (why)
      return err_set(err, "basis %s: product %s is not implemented with %s", rc->bc->size_name, rc->product->name, why);
    return train_product_basis(t->m, t->f, rc, &(ClassSnapshots){sn->S, sn->X[c], opt->weights}, opt->full_rank, err);
  }
  if (opt->user->joint && rc->nmembers > 1) rc_ok = train_joint_basis(rc, sn->S, sn->X[c], err);
  else if (gram) rc_ok = pca_merge(rc->n, (PcaBlocks){rc->nmembers, sn->U[c], sn->k[c]}, &rc->B, &rc->m, err);
  else rc_ok = train_member_bases(rc, sn->S, sn->X[c], opt->weights, pre, err);
  if (rc_ok != 0) return err_set_first(err, "out of memory building the basis of class %s", rc->label);
  return train_complete_basis(rc, opt->full_rank, err);
}

/* Step 2: one basis per class (DESIGN §5), sized into the tensors. */
static int build_bases(Train *t) {
  Model *m = t->m;
  const TrainOptions *opt = t->opt;
  /* over ranks: the members' PCAs shared out, each made on one rank */
  PcaMember **pre = NULL;
  if (opt->dist && dist_size() > 1 && !t->gram && !opt->user->joint &&
      dist_member_pcas(m, t->sn.S, t->sn.X, opt->weights, &pre, t->err))
    return -1;
  int rc = 0;
  for (int c = 0; rc == 0 && c < m->nclasses; c++) rc = class_basis(t, &m->classes[c], pre ? pre[c] : NULL, pre != NULL);
  dist_free_pcas(m, pre);
  if (rc == 0) model_size_tensors(m);
  return rc;
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

/* rc->R = B (BᵀB)⁻¹ (model_term_coords): Rᵀ = (BᵀB)⁻¹ Bᵀ by BᵀB's Cholesky factor. 0, or -1 (out of memory, or
 * BᵀB not positive definite: B's columns dependent). */
static int coords_rows(RClass *rc) {
  long n = rc->n, m = rc->m;
  Scratch sc = SCRATCH_OF(NULL);
  double *G = scratch_array(&sc, (size_t)(m * m), sizeof(double));
  double *R = scratch_adopt(&sc, mem_malloc(sizeof(double) * (size_t)(n * m) + 1)); /* kept: the class owns it */
  int out = G && R ? 0 : -1;
  if (out == 0) {
    cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)m, (int)m, (int)n, 1.0, rc->B, (int)m, rc->B, (int)m,
                0.0, G, (int)m);
    memcpy(R, rc->B, sizeof(double) * (size_t)(n * m)); /* row-major n x m: column-major Bᵀ, m x n */
    out = LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'U', (int)m, G, (int)m) ||
          LAPACKE_dpotrs(LAPACK_COL_MAJOR, 'U', (int)m, (int)n, G, (int)m, R, (int)m) ? -1 : 0;
  }
  if (out == 0) rc->R = scratch_keep(&sc, R);
  scratch_release(&sc);
  return out;
}

/* RClass.R of every class with a product whose terms pass coordinates to a solve (model_term_coords). 0, or -1 with
 * `err`. */
static int train_coords_rows(Model *m, Err *err) {
  for (int i = 0; i < m->nstages; i++) {
    RClass *rc = &m->classes[m->qclass[m->stages[i].q]];
    for (int t = 0; t < m->stages[i].nterms; t++)
      for (int k = -1; rc->D && rc->B && !rc->R && k < m->stages[i].terms[t].nops; k++)
        if (model_term_coords(&m->stages[i].terms[t], k) && coords_rows(rc))
          return err_set(err, "class %s: out of memory, or its basis's Gram matrix BᵀB is singular, for the rows of "
                         "stage %s's solve", rc->label, m->stages[i].st->sym->name);
  }
  return 0;
}

/* Step 3: the projections between classes and every tensor pre-multiplied.
 * Over ranks, with progress on, rank 0 says how long its own rows took and
 * how long the sums over ranks (the wait for the slowest rank included). */
int train_premultiply_all(Train *tr) {
  Model *m = tr->m;
  bool progress = tr->opt->user->progress, dist = tr->opt->dist;
  long ntensors = 0, done = 0;
  int rank = dist ? dist_rank() : 0, N = dist ? dist_size() : 1;
  if (train_coords_rows(m, tr->err)) return -1;
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
          return err_set(tr->err, "out of memory while training");
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)cy->m, (int)cw->m, (int)cy->n, 1.0,
                    model_term_rows(cy, rt, -1), (int)cy->m, cw->B, (int)cw->m, 0.0,
                    rt->proj, (int)cw->m);
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
        /* a term that solves is reduced by Galerkin (BᵀMB, Bᵀw); a projection and an operator's application are
         * projected (with a product, the K0-projection Dᵀ: issue 41; model_term_projects) */
        const double *row = model_tensor_rows(cy, rt, x);
        if (premultiply(m, tr->f, x, &(PremulOut){.By = row, .Bcol = cy->B, .ny = cy->n, .my = cy->m, .part = rank, .nparts = N},
                        &flops, tr->err))
          return -1;
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
  return !opt->stream || keep_named(m, opt->user->keep_bases, c, NULL, 0);
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
 * the basis. With t->gram the values are the evaluator's (the sample
 * just evaluated), else the snapshots'. */
void train_take_floors(const Train *t, long k, double *proj, double *y) {
  Model *m = t->m;
  const Snapshots *sn = &t->sn;
  long S = t->src->count;
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; m->classes[c].streamed && !m->classes[c].floors_known && i < m->classes[c].nmembers; i++) {
      RMember *mb = &m->classes[c].members[i];
      if (mb->q < 0) continue; /* a numerator is no quantity verify reports */
      const double *val = t->gram ? full_get(t->f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL)
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

static int fit_externs_floors(Train *t, int nx, bool floors, double *proj, double *y);

/* Step 4: with `externs` every extern's learned map (paper §8.3): the
 * training samples' reduced inputs and values, from the snapshots or, after
 * the method of snapshots, recomputed; with `floors`, in the same pass the
 * streamed classes' training floors (train_take_floors). */
int train_fit_externs(Train *t, bool externs, bool floors) {
  Model *m = t->m;
  long maxn = 1, maxm = 1;
  for (int c = 0; floors && c < m->nclasses; c++)
    if (m->classes[c].streamed && !m->classes[c].floors_known)
      maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn, maxm = m->classes[c].m > maxm ? m->classes[c].m : maxm;
  double *y = floors ? train_scratch(t, sizeof(double) * (size_t)maxn) : NULL;
  double *proj = floors ? train_scratch(t, sizeof(double) * (size_t)maxm) : NULL;
  if (floors && (!y || !proj)) return err_set(t->err, "out of memory measuring the training floors");
  return fit_externs_floors(t, externs ? m->nexterns : 0, floors, proj, y);
}

static int fit_externs_floors(Train *t, int nx, bool floors, double *proj, double *y) {
  Model *m = t->m;
  Full *f = t->f;
  const SampleSource *src = t->src;
  const Snapshots *sn = &t->sn;
  bool gram = t->gram, dist = t->opt->dist;
  long S = src->count;
  /* recomputed over ranks (out of core): rank r its samples k ≡ r (mod N),
   * the others' rows zero, then summed */
  int N = gram && dist ? dist_size() : 1, rank = N > 1 ? dist_rank() : 0;
  for (int i = 0; i < nx; i++) {
    RExtern *x = &m->externs[i];
    long mz = m->classes[m->qclass[x->q]].m;
    x->S = S;
    if (!(x->X = mem_calloc((size_t)(S * x->d + 1), sizeof(double))) || !(x->Z = mem_calloc((size_t)(S * mz) + 1, sizeof(double))))
      return err_set(t->err, "out of memory while training");
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
    if (gram && given_only && src->set(src->user, f, k) != 0) return err_set(t->err, "%s", full_error(f));
    if (gram && !given_only && train_eval_sample(src, f, k, t->err)) return -1; /* recompute: no snapshot was kept */
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
    if (floors) train_take_floors(t, k, proj, y);
    if (gram) progress_show(t->opt->user->progress, floors ? "extern samples, floors" : "extern samples", k + 1, S);
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

/* Step 3b: the stages opt->user->interp_stage names made interpolated, and with
 * validation samples every other eligible stage reduced the way that
 * measures better there (DESIGN §12). */
static bool named_in(const char *const *names, int n, const char *name) {
  for (int j = 0; j < n; j++)
    if (strcmp(names[j], name) == 0) return true;
  return false;
}

int train_interpolate_stages(Model *m, Full *f, const TrainOptions *opt, Err *err) {
  double over = opt->user->interp_oversample > 0 ? opt->user->interp_oversample : TRAIN_INTERP_OVERSAMPLE;
  /* the program's `basis w: reduce interp`, unless the command line says galerkin */
  for (int i = 0; i < m->nstages; i++) {
    const Sym *s = m->stages[i].st->sym;
    if (s->reduce != STAGE_REDUCE_INTERP || named_in(opt->user->galerkin_stage, opt->user->ngalerkin, s->name) ||
        named_in(opt->user->interp_stage, opt->user->ninterp, s->name))
      continue;
    if (interp_train_stage(m, f, i, over, err)) return -1;
    m->stages[i].choice_reason = interp_reasons[INTERP_FORCED];
  }
  for (int j = 0; j < opt->user->ninterp; j++) {
    int i = 0;
    while (i < m->nstages && strcmp(m->stages[i].st->sym->name, opt->user->interp_stage[j]) != 0) i++;
    if (i == m->nstages)
      return err_set(err, "--reduce %s:interp: the program has no stage '%s'", opt->user->interp_stage[j],
                     opt->user->interp_stage[j]);
    if (interp_train_stage(m, f, i, over, err)) return -1;
    m->stages[i].choice_reason = interp_reasons[INTERP_FORCED];
    if (opt->user->progress)
      fprintf(stderr, "stage %s interpolated: %ld of %ld entries (m %ld), ‖(WPB)⁺‖ %.3g\n", opt->user->interp_stage[j],
              m->stages[i].interp->k, m->classes[m->qclass[m->stages[i].q]].n, m->stages[i].interp->m,
              m->stages[i].interp->pinv_norm);
  }
  for (int j = 0; j < opt->user->ngalerkin; j++) {
    int i = 0;
    while (i < m->nstages && strcmp(m->stages[i].st->sym->name, opt->user->galerkin_stage[j]) != 0) i++;
    if (i == m->nstages)
      return err_set(err, "--reduce %s:galerkin: the program has no stage '%s'", opt->user->galerkin_stage[j],
                     opt->user->galerkin_stage[j]);
    if (named_in(opt->user->interp_stage, opt->user->ninterp, opt->user->galerkin_stage[j]))
      return err_set(err, "stage %s is forced both to interpolation and to Galerkin", opt->user->galerkin_stage[j]);
  }
  return opt->valid ? tune_choose_reductions(m, f, opt->valid, opt, err) : 0;
}

/* Steps 1–2: the bases, from snapshots in memory, by the method of
 * snapshots, or out of core when the bases exceed opt->user->mem (ooc.c; then,
 * as after the method of snapshots, *gram: no snapshot is kept). Ends the
 * phase of the snapshots (out of core: the snapshots and the bases are one
 * step, timed as snapshots). */
static int bases(Train *t) {
  Model *m = t->m;
  if (ooc_needed(m, t->opt, t->src->count)) {
    for (int c = 0; c < m->nclasses; c++)
      if (m->classes[c].product)
        return err_set(t->err,
                       "basis %s: product %s is not implemented out of core (the bases exceed "
                       "--mem: raise it)",
                       m->classes[c].bc->size_name, m->classes[c].product->name);
    t->gram = true;
    train_mark_streamed(m, t->opt); /* their floors taken in the passes (the choice is made again after interpolation) */
    if (evaluate_sample0(t) || ooc_bases(t)) return -1;
    phase_end(t->clock, m, PHASE_SNAPSHOTS);
    return 0;
  }
  if (train_take_snapshots(t)) return -1;
  phase_end(t->clock, m, PHASE_SNAPSHOTS);
  return build_bases(t);
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
static void self_check(Train *t) {
  Model *m = t->m;
  Full *f = t->f;
  const SampleSource *src = t->src;
  m->self_check_sample = -1;
  if (t->opt->dist) return;
  char err[600];
  Reduced *r = src->count > 0 && m->nexterns == 0 ? reduced_new(m, ERR_OF(err, sizeof err)) : NULL;
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

/* The steps of train_model after the bases, each a function of the context. */
static int premultiply_tensors(Train *t) {
  phase_end(t->clock, t->m, PHASE_BASES);
  return train_premultiply_all(t);
}

/* The choice on validation samples (DESIGN §12) measures the reduced model, its externs' learned
 * maps included: with both, they are fitted first (they read the bases, not the reductions), and
 * the streamed classes' floors, known only once the choice is made, take a pass of their own. */
static bool externs_first(const Train *t) { return t->opt->valid && t->m->nexterns > 0; }

static int fit_externs_for_choice(Train *t) { return externs_first(t) ? train_fit_externs(t, true, false) : 0; }

/* Step 3b and the online estimate's tables. */
static int reductions(Train *t) {
  if (train_interpolate_stages(t->m, t->f, t->opt, t->err) || train_estimates(t->m, t->f, t->src, t->opt, t->err))
    return -1;
  phase_end(t->clock, t->m, PHASE_PREMULTIPLY);
  return 0;
}

/* Step 4 (what fit_externs_for_choice left) and 5: the streamed bases dropped. */
static int externs_and_floors(Train *t) {
  bool floors = train_mark_streamed(t->m, t->opt); /* the reductions chosen: which bases are streamed is known */
  if ((!externs_first(t) || floors) && train_fit_externs(t, !externs_first(t), floors)) return -1;
  train_drop_bases(t->m);
  phase_end(t->clock, t->m, PHASE_EXTERNS);
  return 0;
}

static int report_phases(Train *t) {
  const Model *m = t->m;
  if (t->opt->user->progress)
    fprintf(stderr, "training phases: snapshots %.2f s, bases %.2f s (%s), pre-multiplication %.2f s, externs %.2f s\n",
            m->phase_seconds[PHASE_SNAPSHOTS], m->phase_seconds[PHASE_BASES],
            ooc_needed(m, t->opt, t->src->count) ? "out of core, with the snapshots"
            : t->gram                             ? "method of snapshots"
                                                  : "in memory",
            m->phase_seconds[PHASE_PREMULTIPLY], m->phase_seconds[PHASE_EXTERNS]);
  snapshot_cache_keep(t); /* this training's snapshots kept for the next (greedy training) */
  train_free_snapshots(t->m, &t->sn);
  self_check(t);
  return 0;
}

static int refuse_options(Train *t) {
  /* the weights themselves are checked where they are given (npg_trainer_weight) */
  if (t->opt->weights && t->opt->user->joint)
    return err_set(t->err, "sample weights are not implemented with --merge joint: use --merge concat");
  phase_start(t->clock);
  return 0;
}

/* Training's table of contents (DESIGN §5): every step a function of the
 * context, in order; each phase's wall and CPU time kept. */
static int (*const train_steps[])(Train *) = {
    refuse_options,          /* 0. what the options cannot combine */
    train_begin,             /* 0. the layout, every member's options */
    bases,                   /* 1–2. snapshots (or the method of snapshots, or out of core) and bases */
    premultiply_tensors,     /* 3. every tensor pre-multiplied */
    fit_externs_for_choice,  /* 4. the externs' maps, when the choice below measures them */
    reductions,              /* 3b. interpolated stages, the choice on validation samples, the estimate's tables */
    externs_and_floors,      /* 4–5. the externs' maps, the streamed classes' floors, their bases dropped */
    report_phases,           /* the phases' times; the model checked on three of its samples */
};

static Model *train_run(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err) {
  Train t = {.prog = prog, .f = f, .src = src, .opt = opt, .err = err};
  if (err_held(err)) err->msg[0] = 0;
  for (size_t i = 0; i < sizeof train_steps / sizeof *train_steps; i++) {
    int rc = train_steps[i](&t);
    train_scratch_free(&t);
    if (rc) {
      if (t.m) train_free_snapshots(t.m, &t.sn);
      model_free(t.m);
      /* the steps name what failed; a helper that only returned NULL ran out of memory */
      err_set_first(err, "out of memory during training");
      return NULL;
    }
  }
  return t.m;
}

/* ---------------------------------------------------------------- the params, the hold-out and the weights */

char *train_param_hashes(const Full *f) {
  const Program *prog = full_program(f);
  size_t cap = 1, len = 0;
  for (int i = 0; i < prog->params.n; i++) cap += strlen(((Sym *)prog->params.v[i])->name) + 19;
  char *out = mem_malloc(cap);
  if (!out) return NULL;
  out[0] = 0;
  for (int i = 0; i < prog->params.n; i++)
    len += (size_t)snprintf(out + len, cap - len, "%s%s=%016llx", i ? " " : "", ((Sym *)prog->params.v[i])->name,
                            (unsigned long long)full_param_hash(f, i, NULL));
  return out;
}

const char *train_param_changed(const Full *f, const char *before, bool *oom) {
  Scratch sc = SCRATCH_OF(NULL);
  const char *after = scratch_adopt(&sc, train_param_hashes(f));
  *oom = !after;
  if (!after) return NULL;
  const Program *prog = full_program(f);
  const char *changed = NULL, *a = before, *b = after;
  /* "name=hash" per param, space-separated, in the program's order in both */
  for (int i = 0; i < prog->params.n && !changed; i++) {
    size_t la = strcspn(a, " "), lb = strcspn(b, " ");
    if (la != lb || strncmp(a, b, la) != 0) changed = ((Sym *)prog->params.v[i])->name;
    a += la + (a[la] == ' '), b += lb + (b[lb] == ' ');
  }
  scratch_release(&sc);
  return changed;
}


/* Held-out validation (NpgTrainOptions.valid_holdout, DESIGN §12): every
 * stride-th sample (k % stride == stride - 1) validates, the others train;
 * interleaved, so both cover a simulation's whole run. */
typedef struct Holdout {
  const SampleSource *all;
  long stride;
} Holdout;

static long training_index(const Holdout *h, long j) { return j + j / (h->stride - 1); }

static int holdout_training(void *user, Full *f, long j) {
  const Holdout *h = user;
  return h->all->set(h->all->user, f, training_index(h, j));
}

static int holdout_training_part(void *user, Full *f, long j, const Demand *d) {
  const Holdout *h = user;
  return h->all->set_part(h->all->user, f, training_index(h, j), d);
}

static int holdout_held(void *user, Full *f, long j) {
  const Holdout *h = user;
  return h->all->set(h->all->user, f, j * h->stride + h->stride - 1);
}

/* The fraction held out: opt->user->valid_holdout, or when negative (automatic) 1/TRAIN_HOLDOUT_STRIDE
 * where a stage's reduction is open to a choice (else 0: the model is as before). -1 with `err`
 * when it cannot be held out. */
static double holdout_fraction(Program *prog, const SampleSource *src, const TrainOptions *opt, Err *err) {
  double F = opt->user->valid_holdout;
  if (F < 0)
    F = !opt->valid && !opt->dist && src->count >= TRAIN_HOLDOUT_MIN &&
                interp_open_choices(prog, opt->user->ninterp, opt->user->interp_stage, opt->user->ngalerkin,
                                    opt->user->galerkin_stage) > 0
            ? 1.0 / TRAIN_HOLDOUT_STRIDE
            : 0;
  if (F != 0 && (!(F > 0 && F <= 0.5) || opt->valid || opt->dist))
    return err_set(err, "--valid %g (NpgTrainOptions.valid_holdout): %s", F,
                   !(F > 0 && F <= 0.5) ? "must be in (0, 0.5]"
                   : opt->dist ? "not over MPI ranks (give a folder of validation samples instead, --valid DIR)"
                               : "validation samples are given as well");
  long stride = F != 0 ? lround(1 / F) : 0;
  if (F != 0 && src->count / stride < 1)
    return err_set(err,
                   "--valid %g (NpgTrainOptions.valid_holdout) holds out one sample in %ld, none of %ld: "
                   "give a fraction of at least %.3g, or more samples",
                   F, stride, src->count, 1.0 / (double)src->count);
  return F;
}

/* The weights divided by the largest (over every rank): only their ratios
 * count, and 20 weights of 1.5e308 overflowed their sum to infinity, lost
 * a basis vector and were refused out of core as "snapshot values beyond
 * 1e154". Scaled so, equal weights give the model of weights 1, bit for
 * bit. From `sc`; NULL when out of memory. */
static double *scale_weights(Scratch *sc, const double *weights, long S, bool dist) {
  double *w = scratch_array(sc, (size_t)S, sizeof(double)), big = 0;
  if (!w) return NULL;
  for (long k = 0; k < S; k++) big = fmax(big, weights[k]);
  if (dist) dist_allreduce_max(&big, 1);
  for (long k = 0; k < S; k++) w[k] = weights[k] / big;
  return w;
}

/* Training's policy around its steps: the weights scaled, the samples held out to choose the
 * reductions on, and after the automatic choice the model trained again on every sample. */
Model *train_model(Program *prog, Full *f, const SampleSource *src, const TrainOptions *opt, Err *err) {
  if (err_held(err)) err->msg[0] = 0;
  double F = holdout_fraction(prog, src, opt, err);
  if (F < 0) return NULL;
  Holdout hold = {src, F != 0 ? lround(1 / F) : 0};
  long nheld = F != 0 ? src->count / hold.stride : 0;
  SampleSource training = *src, held = {nheld, &hold, holdout_held, NULL, NULL};
  NpgTrainOptions user = *opt->user; /* the fraction decided: none again in train_run or the retraining */
  user.valid_holdout = 0;
  TrainOptions o = *opt;
  o.user = &user;
  if (F != 0) {
    training = (SampleSource){src->count - nheld, &hold, holdout_training, src->set_part ? holdout_training_part : NULL,
                              NULL};
    o.valid = &held; /* the cache finds the samples by their hashes, however numbered */
  }
  Scratch sc = SCRATCH_OF(err);
  double *w = opt->weights ? scale_weights(&sc, opt->weights, src->count, opt->dist) : NULL;
  /* the training samples' weights (of those left when some are held out) */
  double *train_w = w && F != 0 ? scratch_array(&sc, (size_t)training.count, sizeof(double)) : NULL;
  if ((opt->weights && !w) || (w && F != 0 && !train_w))
    return scratch_release(&sc), err_set(err, "out of memory"), NULL;
  for (long j = 0; train_w && j < training.count; j++) train_w[j] = w[training_index(&hold, j)];
  o.weights = train_w ? train_w : w;
  /* the params the samples are set with, recorded before any validation sample is set: one that
   * sets a param would otherwise leave its hash in the model (trial3) */
  char *params = train_param_hashes(f);
  Model *m = params ? train_run(prog, f, &training, &o, err) : NULL;
  /* the automatic choice made, every sample trains the model (DESIGN §12) */
  o.weights = w;
  o.valid = opt->valid;
  if (m && F != 0 && opt->user->valid_holdout < 0) m = interp_train_with_choice(prog, f, src, &o, m, err);
  scratch_release(&sc);
  bool oom = !params;
  const char *changed = m ? train_param_changed(f, params, &oom) : NULL;
  if (oom || changed) {
    if (oom) err_set(err, "out of memory");
    else
      err_set(err,
              "NpgTrainOptions.valid_set changed param '%s': a validation sample holds inputs and "
              "externs only (the params are the trainer's)",
              changed);
    model_free(m);
    m = NULL;
  }
  if (m) { /* the model takes the hashes; what it held before goes */
    char *before = m->param_hashes;
    m->param_hashes = params, params = before;
  }
  free(params);
  return m;
}
