/* train.c — training a reduced model (DESIGN §5; paper §8.2–§8.3):
 *
 *   1. snapshots: the full evaluator on every training sample; every
 *      quantity's value and, for every operator term with an unnamed
 *      numerator, the numerator's value (it joins the result's class:
 *      DESIGN §4, "a numerator lives in the result's basis");
 *   2. one orthonormal basis per class: a PCA per member (energy fraction
 *      and cap per member), concatenated and re-orthonormalized, or with
 *      --merge joint one PCA of the unit-scaled member blocks;
 *   3. pre-multiplication of every tensor (premul.c);
 *   4. the learned map of every extern (paper §8.3): the training samples'
 *      reduced inputs and reduced values.
 *
 * train_model() is those steps in order (take_snapshots, build_bases,
 * premultiply_tensors, fit_externs), after lay_out binds the dims.
 */
#include <cblas.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "emit.h"
#include "train.h"

void progress_show(bool on, const char *what, long done, long total) {
  if (!on) return;
  int width = 30, fill = total > 0 ? (int)((double)done / (double)total * width) : width;
  fprintf(stderr, "\r%-28s [", what);
  for (int i = 0; i < width; i++) fputc(i < fill ? '#' : ' ', stderr);
  fprintf(stderr, "] %ld/%ld", done, total);
  if (done >= total) fputc('\n', stderr);
  fflush(stderr);
}


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
static int field_value(NpgFull *f, const RTensor *ts, int nt, double *out, long n, char *err, size_t errlen) {
  memset(out, 0, sizeof(double) * (size_t)n);
  for (int g = 0; g < nt; g++) {
    FieldSum s = {{0}, out, n};
    for (int i = 0; i < ts[g].group->ninputs; i++) s.in[i] = npg_full_get(f, ts[g].group->inputs[i]->name, NULL);
    NpgSink sink = {&s, sum_entry};
    if (full_build(f, ts[g].builder, &sink) != 0) return npg_fail(err, errlen, "%s", npg_full_error(f));
  }
  return 0;
}

/* ---------------------------------------------------------------- options */

static void member_options(const Model *m, const RClass *c, RMember *mb, const TrainOptions *opt) {
  mb->cap = opt->cap > 0 ? opt->cap : 60;
  mb->energy = opt->energy > 0 ? opt->energy : 0.999;
  const BasisClass *bc = c->bc;
  if (bc->basis_max > 0) mb->cap = bc->basis_max;
  if (bc->basis_energy > 0) mb->energy = bc->basis_energy;
  const char *name = mb->name;
  if (mb->q >= 0) {
    const Sym *s = m->prog->quantities.v[mb->q];
    if (s->basis_max > 0) mb->cap = s->basis_max;
    if (s->basis_energy > 0) mb->energy = s->basis_energy;
    name = s->name;
  }
  for (int i = 0; i < opt->noverride; i++)
    if (strcmp(opt->override_name[i], name) == 0 || strcmp(opt->override_name[i], "*") == 0) {
      if (opt->override_cap[i] > 0) mb->cap = opt->override_cap[i];
      if (opt->override_energy[i] > 0) mb->energy = opt->override_energy[i];
    }
}

/* ---------------------------------------------------------------- training */

typedef struct Snapshots {
  long S;
  double ***X;      /* [class][member] n x S column-major (NULL: method of snapshots) */
  double ***U;      /* [class][member] its PCA basis, n x k row-major (method of snapshots) */
  int **k;
} Snapshots;

static void free_snapshots(Model *m, Snapshots *sn) {
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

static RTerm *joiner_term(Model *m, const Joiner *j) {
  for (int i = 0; i < m->nstages; i++)
    if (m->stages[i].st == j->stage) return &m->stages[i].terms[j->term];
  return NULL;
}


/* Set and evaluate training sample k. */
static int eval_sample(const SampleSource *src, NpgFull *f, long k, char *err, size_t errlen) {
  if (src->set(src->user, f, k) != 0 || npg_full_eval(f, k) != 0) return npg_fail(err, errlen, "%s", npg_full_error(f));
  return 0;
}

/* The current value of a class member (a quantity, or an unnamed numerator
 * through its builders) at sample k into out[0..n); refused when not
 * finite, since a basis of it would be meaningless (and the SVD would fail
 * without saying why). */
static int member_value(Model *m, NpgFull *f, const RMember *mb, long k, long n, double *out, char *err,
                        size_t errlen) {
  if (mb->q >= 0) {
    memcpy(out, npg_full_get(f, ((Sym *)m->prog->quantities.v[mb->q])->name, NULL), sizeof(double) * (size_t)n);
  } else {
    RTerm *rt = joiner_term(m, mb->joiner);
    if (!rt) return npg_fail(err, errlen, "a numerator without its term (a bug in npg)");
    if (field_value(f, rt->num, rt->nnum, out, n, err, errlen)) return -1;
  }
  for (long e = 0; e < n; e++)
    if (!isfinite(out[e]))
      return npg_fail(err, errlen,
                      "training sample %ld: %s is not finite (entry %ld is %g): the sample makes it undefined (a "
                      "division by zero or a root of a negative number in the program?)",
                      k, mb->name, e, out[e]);
  return 0;
}

/* A diagonal operator stays marked SPD while every training diagonal seen is
 * positive (then BᵀDB is SPD for every basis: Cholesky). */
static int check_spd(Model *m, NpgFull *f, double *tmp, char *err, size_t errlen) {
  FOR_DIAG_OPS(m, rs, rt, ro) {
    if (!ro->spd) continue;
    long n = m->classes[m->qclass[rs->q]].n;
    if (field_value(f, ro->t, ro->ntensors, tmp, n, err, errlen)) return -1;
    for (long e = 0; e < n && ro->spd; e++)
      if (!(tmp[e] > 0)) ro->spd = false;
  }
  return 0;
}

/* The method of snapshots (DESIGN §5), for snapshots that do not fit in
 * `mem`: no snapshot matrix is held whole. Pass 1 builds every member's
 * S x S Gram matrix G = XᵀX holding a block of b samples at a time and
 * recomputing the later samples against it (one pass when the budget holds
 * half the samples, S/b passes in general); the eigenvectors of G give the
 * basis U = X V Λ^(-1/2), formed in pass 2 by recomputing every sample once
 * and adding its rank-one contribution. U[c][i], kk[c][i] per member. */
static int snapshot_bases(Model *m, NpgFull *f, const SampleSource *src, const TrainOptions *opt, double ***U,
                          int **kk, double *tmp, char *err, size_t errlen) {
  long S = src->count, per = 0;
  for (int c = 0; c < m->nclasses; c++) per += m->classes[c].n * m->classes[c].nmembers;
  long b = (long)(opt->mem / 2 / sizeof(double) / (size_t)(per ? per : 1));
  if (b < 1) b = 1;
  if (b > S) b = S;
  int rc = -1;
  double ***G = calloc((size_t)m->nclasses + 1, sizeof(double **)), ***H = calloc((size_t)m->nclasses + 1, sizeof(double **));
  double *lam = malloc(sizeof(double) * (size_t)S);
  if (!G || !H || !lam) goto oom;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(G[c] = calloc((size_t)rc->nmembers, sizeof(double *))) || !(H[c] = calloc((size_t)rc->nmembers, sizeof(double *))))
      goto oom;
    for (int i = 0; i < rc->nmembers; i++)
      if (!(G[c][i] = calloc((size_t)(S * S), sizeof(double))) ||
          !(H[c][i] = malloc(sizeof(double) * (size_t)(rc->n * b))))
        goto oom;
  }
  long passes = (S + b - 1) / b, done = 0, work = 0;
  for (long i0 = 0; i0 < S; i0 += b) work += S - i0;
  for (long i0 = 0; i0 < S; i0 += b) {
    long i1 = i0 + b < S ? i0 + b : S, nb = i1 - i0;
    for (long k = i0; k < S; k++) {
      if (eval_sample(src, f, k, err, errlen)) goto done;
      if (k < i1 && check_spd(m, f, tmp, err, errlen)) goto done;
      for (int c = 0; c < m->nclasses; c++) {
        RClass *rc = &m->classes[c];
        for (int i = 0; i < rc->nmembers; i++) {
          double *x = k < i1 ? H[c][i] + (k - i0) * rc->n : tmp;
          if (member_value(m, f, &rc->members[i], k, rc->n, x, err, errlen)) goto done;
          if (k < i1) continue;
          /* G[I, k] = X_Iᵀ x_k */
          double *g = lam;
          cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)nb, (int)rc->n, 1.0, H[c][i], (int)rc->n, x, 1, 0.0, g, 1);
          for (long a = 0; a < nb; a++) G[c][i][(i0 + a) * S + k] = G[c][i][k * S + i0 + a] = g[a];
        }
      }
      progress_show(opt->progress, passes > 1 ? "snapshots (Gram, recomputing)" : "snapshots (Gram)", ++done, work);
    }
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) { /* G[I, I] = X_Iᵀ X_I */
        double *gi = G[c][i] + i0 * S + i0;
        cblas_dgemm(CblasRowMajor, CblasNoTrans, CblasTrans, (int)nb, (int)nb, (int)rc->n, 1.0, H[c][i], (int)rc->n,
                    H[c][i], (int)rc->n, 0.0, gi, (int)S);
      }
    }
  }
  /* eigenvectors of every Gram matrix: the coefficients of the basis */
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    for (int i = 0; i < rc->nmembers; i++) {
      RMember *mb = &rc->members[i];
      lapack_int info = LAPACKE_dsyevd(LAPACK_ROW_MAJOR, 'V', 'U', (lapack_int)S, G[c][i], (lapack_int)S, lam);
      if (info != 0) {
        npg_fail(err, errlen, "class %s, member %s: eigendecomposition of the Gram matrix failed (LAPACK info %d)",
              rc->label, mb->name, (int)info);
        goto done;
      }
      double total = 0, run = 0;
      for (long a = 0; a < S; a++) total += fmax(lam[a], 0);
      int k = 0;
      mb->captured = 1;
      if (total > 0) {
        while (k < S && k < mb->cap && lam[S - 1 - k] > 1e-20 * lam[S - 1]) {
          run += lam[S - 1 - k];
          k++;
          if (run >= mb->energy * total) break;
        }
        mb->captured = run / total;
      }
      mb->kept = kk[c][i] = k;
      /* column a of W = V[:, S-1-a] / sqrt(λ), kept in G's place (S x k) */
      for (long s2 = 0; s2 < S; s2++) {
        double *row = G[c][i] + s2 * S;
        for (int a = 0; a < k; a++) tmp[a] = row[S - 1 - a] / sqrt(lam[S - 1 - a]);
        memcpy(row, tmp, sizeof(double) * (size_t)k);
      }
      if (!(U[c][i] = calloc((size_t)(rc->n * (k ? k : 1)), sizeof(double)))) goto oom;
    }
  }
  /* pass 2: U += x_s ⊗ W[s, :] */
  for (long k = 0; k < S; k++) {
    if (eval_sample(src, f, k, err, errlen)) goto done;
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++) {
        if (!kk[c][i]) continue;
        if (member_value(m, f, &rc->members[i], k, rc->n, tmp, err, errlen)) goto done;
        cblas_dger(CblasRowMajor, (int)rc->n, kk[c][i], 1.0, tmp, 1, G[c][i] + k * S, 1, U[c][i], kk[c][i]);
      }
    }
    progress_show(opt->progress, "snapshots (basis)", k + 1, S);
  }
  rc = 0;
  goto done;
oom:
  npg_fail(err, errlen, "out of memory for the Gram matrices of %ld samples", S);
done:
  for (int c = 0; c < m->nclasses; c++) {
    for (int i = 0; G && G[c] && i < m->classes[c].nmembers; i++) free(G[c][i]);
    for (int i = 0; H && H[c] && i < m->classes[c].nmembers; i++) free(H[c][i]);
    if (G) free(G[c]);
    if (H) free(H[c]);
  }
  free(G);
  free(H);
  free(lam);
  return rc;
}

/* One training run: what every step reads and fills. */
typedef struct Training {
  Program *prog;
  NpgFull *f;
  const SampleSource *src;
  const TrainOptions *opt;
  char *err;
  size_t errlen;
  long S;           /* training samples */
  Model *m;         /* the model being trained (owned until returned) */
  Snapshots sn;
  bool gram;        /* the method of snapshots: the snapshots exceed opt->mem */
  double *tmp;      /* scratch of max(n, S) doubles */
} Training;

static int out_of_memory(Training *tr) { return npg_fail(tr->err, tr->errlen, "out of memory while training"); }

/* Sample 0 binds every dim; the model's layout at those sizes. */
static int lay_out(Training *tr) {
  Program *prog = tr->prog;
  if (tr->S < 1) return npg_fail(tr->err, tr->errlen, "no training samples");
  if (tr->src->set(tr->src->user, tr->f, 0) != 0 || npg_full_eval(tr->f, 0) != 0)
    return npg_fail(tr->err, tr->errlen, "%s", npg_full_error(tr->f));
  long *dims = calloc((size_t)prog->dims.n + 1, sizeof(long));
  if (!dims) return -1;
  for (int i = 0; i < prog->dims.n; i++) dims[i] = full_dim_size(tr->f, i);
  tr->m = model_layout(prog, dims, tr->err, tr->errlen);
  free(dims);
  if (!tr->m) return -1;
  tr->m->samples = tr->S;
  return 0;
}

/* 1. snapshots: every member's value on every sample, held whole, or
 * (beyond opt->mem) folded into per-member bases by the method of
 * snapshots. */
static int take_snapshots(Training *tr) {
  Model *m = tr->m;
  const TrainOptions *opt = tr->opt;
  Snapshots *sn = &tr->sn;
  long S = tr->S;
  size_t need = 0;
  long maxn = 1;
  for (int c = 0; c < m->nclasses; c++) {
    need += sizeof(double) * (size_t)m->classes[c].n * (size_t)S * (size_t)m->classes[c].nmembers;
    maxn = m->classes[c].n > maxn ? m->classes[c].n : maxn;
    for (int i = 0; i < m->classes[c].nmembers; i++) member_options(m, &m->classes[c], &m->classes[c].members[i], opt);
  }
  tr->gram = opt->mem && need > opt->mem;
  if (tr->gram && opt->joint)
    return npg_fail(tr->err, tr->errlen,
                    "the snapshots need %.3g GB, more than --mem %.3g GB, and --merge joint needs them in memory: raise "
                    "--mem or use --merge concat (the method of snapshots)",
                    (double)need / 1e9, (double)opt->mem / 1e9);
  sn->S = S;
  if (!(sn->X = calloc((size_t)m->nclasses + 1, sizeof(double **)))) return out_of_memory(tr);
  if (!(sn->U = calloc((size_t)m->nclasses + 1, sizeof(double **))) ||
      !(sn->k = calloc((size_t)m->nclasses + 1, sizeof(int *))))
    return out_of_memory(tr);
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (!(sn->X[c] = calloc((size_t)rc->nmembers, sizeof(double *))) ||
        !(sn->U[c] = calloc((size_t)rc->nmembers, sizeof(double *))) ||
        !(sn->k[c] = calloc((size_t)rc->nmembers, sizeof(int))))
      return out_of_memory(tr);
    for (int i = 0; !tr->gram && i < rc->nmembers; i++)
      if (!(sn->X[c][i] = malloc(sizeof(double) * (size_t)rc->n * (size_t)S))) return out_of_memory(tr);
  }
  if (!(tr->tmp = malloc(sizeof(double) * (size_t)(maxn > S ? maxn : S)))) return out_of_memory(tr);
  FOR_DIAG_OPS(m, rs, rt, ro) ro->spd = true;
  if (tr->gram) return snapshot_bases(m, tr->f, tr->src, opt, sn->U, sn->k, tr->tmp, tr->err, tr->errlen);
  for (long k = 0; k < S; k++) {
    if (k > 0 && eval_sample(tr->src, tr->f, k, tr->err, tr->errlen)) return -1;
    for (int c = 0; c < m->nclasses; c++) {
      RClass *rc = &m->classes[c];
      for (int i = 0; i < rc->nmembers; i++)
        if (member_value(m, tr->f, &rc->members[i], k, rc->n, sn->X[c][i] + (size_t)k * (size_t)rc->n, tr->err,
                         tr->errlen))
          return -1;
    }
    if (check_spd(m, tr->f, tr->tmp, tr->err, tr->errlen)) return -1;
    progress_show(opt->progress, "snapshots", k + 1, S);
  }
  return 0;
}

/* The PCA of class c from the snapshots: one PCA of the members' blocks,
 * each scaled to unit norm (--merge joint, DESIGN §5), the members' bases
 * of the method of snapshots merged, or a PCA per member merged. */
static int class_pca(Training *tr, int c) {
  RClass *rc = &tr->m->classes[c];
  const Snapshots *sn = &tr->sn;
  long S = tr->S;
  char *err = tr->err;
  size_t errlen = tr->errlen;
  double **U = calloc((size_t)rc->nmembers + 1, sizeof(double *));
  int *kk = calloc((size_t)rc->nmembers + 1, sizeof(int));
  int rc_ok = U && kk ? 0 : -1;
  if (rc_ok == 0 && tr->opt->joint && rc->nmembers > 1) {
    size_t n = (size_t)rc->n * (size_t)S;
    double *J = malloc(sizeof(double) * n * (size_t)rc->nmembers);
    int cap = 0;
    double energy = 1;
    if (!J) rc_ok = -1;
    for (int i = 0; J && i < rc->nmembers; i++) {
      double nrm = cblas_dnrm2((int)n, sn->X[c][i], 1);
      for (size_t e = 0; e < n; e++) J[(size_t)i * n + e] = nrm > 0 ? sn->X[c][i][e] / nrm : 0;
      cap += rc->members[i].cap;
      energy = fmin(energy, rc->members[i].energy);
    }
    double captured = 0;
    if (J) rc_ok = pca_member(rc->n, S * rc->nmembers, J, cap, energy, &U[0], &kk[0], &captured, err, errlen);
    free(J);
    for (int i = 0; i < rc->nmembers; i++) {
      rc->members[i].kept = kk[0];
      rc->members[i].captured = captured;
    }
    if (rc_ok == 0) rc_ok = pca_merge(rc->n, 1, U, kk, &rc->B, &rc->m, err, errlen);
  } else if (rc_ok == 0 && tr->gram) {
    rc_ok = pca_merge(rc->n, rc->nmembers, sn->U[c], sn->k[c], &rc->B, &rc->m, err, errlen);
  } else if (rc_ok == 0) {
    for (int i = 0; i < rc->nmembers && rc_ok == 0; i++) {
      RMember *mb = &rc->members[i];
      rc_ok = pca_member(rc->n, S, sn->X[c][i], mb->cap, mb->energy, &U[i], &kk[i], &mb->captured, err, errlen);
      mb->kept = kk[i];
    }
    if (rc_ok == 0) rc_ok = pca_merge(rc->n, rc->nmembers, U, kk, &rc->B, &rc->m, err, errlen);
  }
  for (int i = 0; U && i < rc->nmembers; i++) free(U[i]);
  free(U);
  free(kk);
  if (rc_ok != 0 && !err[0]) npg_fail(err, errlen, "out of memory building the basis of class %s", rc->label);
  return rc_ok;
}

/* 2. one orthonormal basis per class; then every tensor's size. */
static int build_bases(Training *tr) {
  Model *m = tr->m;
  for (int c = 0; c < m->nclasses; c++) {
    RClass *rc = &m->classes[c];
    if (class_pca(tr, c) != 0) return -1;
    if (tr->opt->full_rank && rc->m < rc->n) {
      /* the PCA directions first, then the rest of the space */
      double *eye = calloc((size_t)(rc->n * rc->n), sizeof(double)), *B = NULL;
      double *parts[2] = {rc->B, eye};
      int ks[2] = {(int)rc->m, (int)rc->n};
      if (!eye) return out_of_memory(tr);
      for (long e = 0; e < rc->n; e++) eye[e * rc->n + e] = 1;
      int rc_ok = pca_merge(rc->n, 2, parts, ks, &B, &rc->m, tr->err, tr->errlen);
      free(eye);
      if (rc_ok != 0) return -1;
      free(rc->B);
      rc->B = B;
    }
    if (rc->m == 0) { /* every snapshot zero: one direction keeps the sizes non-empty; lifting gives 0 */
      free(rc->B);
      if (!(rc->B = calloc((size_t)rc->n, sizeof(double)))) return out_of_memory(tr);
      rc->B[0] = 1;
      rc->m = 1;
    }
  }
  model_size_tensors(m);
  return 0;
}

/* 3. projections between classes and pre-multiplication of every tensor. */
static int premultiply_tensors(Training *tr) {
  Model *m = tr->m;
  long ntensors = 0, done = 0;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      RTerm *rt = &m->stages[i].terms[t];
      ntensors += rt->nnum;
      for (int k = 0; k < rt->nops; k++) ntensors += rt->ops[k].ntensors;
    }
  double flops = 0;
  for (int i = 0; i < m->nstages; i++) {
    RStage *rs = &m->stages[i];
    RClass *cy = &m->classes[m->qclass[rs->q]];
    for (int t = 0; t < rs->nterms; t++) {
      RTerm *rt = &rs->terms[t];
      if (rt->proj_name) {
        RClass *cw = &m->classes[m->qclass[rt->named_q]];
        if (!(rt->proj = malloc(sizeof(double) * (size_t)(cy->m * cw->m)))) return out_of_memory(tr);
        cblas_dgemm(CblasRowMajor, CblasTrans, CblasNoTrans, (int)cy->m, (int)cw->m, (int)cy->n, 1.0, cy->B,
                    (int)cy->m, cw->B, (int)cw->m, 0.0, rt->proj, (int)cw->m);
      }
      RTERM_FOR_TENSORS(rt, x) {
        if (premultiply(m, tr->f, x, cy->B, cy->n, cy->m, &flops, tr->err, tr->errlen)) return -1;
        progress_show(tr->opt->progress, "pre-multiplication", ++done, ntensors);
      }
    }
  }
  return 0;
}

/* 4. externs: reduced training inputs and values (paper §8.3), from the
 * snapshots, or recomputed per sample when none was kept. */
static int fit_externs(Training *tr) {
  Model *m = tr->m;
  long S = tr->S;
  for (int i = 0; i < m->nexterns; i++) {
    RExtern *x = &m->externs[i];
    long mz = m->classes[m->qclass[x->q]].m;
    x->S = S;
    if (!(x->X = malloc(sizeof(double) * (size_t)(S * x->d + 1))) || !(x->Z = malloc(sizeof(double) * (size_t)(S * mz))))
      return out_of_memory(tr);
  }
  for (long k = 0; k < S && m->nexterns > 0; k++) {
    if (tr->gram && eval_sample(tr->src, tr->f, k, tr->err, tr->errlen)) return -1;
    for (int i = 0; i < m->nexterns; i++) {
      RExtern *x = &m->externs[i];
      long mz = m->classes[m->qclass[x->q]].m, off = 0;
      for (int j = 0; j <= x->nin; j++) {
        int q = j < x->nin ? x->in_q[j] : x->q;
        RClass *rc = &m->classes[m->qclass[q]];
        const double *val = npg_full_get(tr->f, ((Sym *)tr->prog->quantities.v[q])->name, NULL);
        if (!tr->gram) {
          int mi = 0;
          while (rc->members[mi].q != q) mi++;
          val = tr->sn.X[m->qclass[q]][mi] + (size_t)k * (size_t)rc->n;
        }
        double *dst = j < x->nin ? x->X + k * x->d + off : x->Z + k * mz;
        cblas_dgemv(CblasRowMajor, CblasTrans, (int)rc->n, (int)rc->m, 1.0, rc->B, (int)rc->m, val, 1, 0.0, dst, 1);
        if (j < x->nin) off += rc->m;
      }
    }
    if (tr->gram) progress_show(tr->opt->progress, "extern samples", k + 1, S);
  }
  return 0;
}

Model *train_model(Program *prog, NpgFull *f, const SampleSource *src, const TrainOptions *opt, char *err,
                   size_t errlen) {
  err[0] = 0;
  Training tr = {.prog = prog, .f = f, .src = src, .opt = opt, .err = err, .errlen = errlen, .S = src->count};
  int rc = lay_out(&tr);
  if (rc == 0) rc = take_snapshots(&tr);
  if (rc == 0) rc = build_bases(&tr);
  if (rc == 0) rc = premultiply_tensors(&tr);
  if (rc == 0) rc = fit_externs(&tr);
  free(tr.tmp);
  if (tr.m) free_snapshots(tr.m, &tr.sn);
  if (rc != 0) {
    model_free(tr.m);
    return NULL;
  }
  return tr.m;
}
