/* tunnelstep.c — the tunnel's step as data for tunnel_step.npg and tunnel_step_moving.npg
 * (see tunnelstep.h). The sparse matrices are written as padded rows (ELLPACK: a column table
 * with -1 padding and a value table), the form an npg program reads a sparse matrix in:
 * `sum(q = 0..W-1, if(col[i, q] >= 0, val[i, q] * x[col[i, q]], 0))` applies it and
 * `sum(q = 0..W-1, delta(j, col[i, q]) * val[i, q])` defines it as an operator. */
#include "tunnelstep.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"
#include "report.h"
#include "stream.h"
#include "util.h"

/* Entries (row, col, val) in assembly order, duplicates summed into padded rows. */
typedef struct Triplets {
  int n, cap;
  int *row, *col;
  double *val;
} Triplets;

typedef struct Ell {
  int nrow, width;
  long *col;   /* [nrow][width], -1 padding */
  double *val; /* [nrow][width], 0 padding */
} Ell;

static int triplet_add(Triplets *t, int row, int col, double val) {
  if (t->n == t->cap) {
    int cap = t->cap ? 2 * t->cap : 1024;
    int *r = realloc(t->row, cap * sizeof *r), *c = r ? realloc(t->col, cap * sizeof *c) : NULL;
    if (r) t->row = r;
    if (c) t->col = c;
    double *v = c ? realloc(t->val, cap * sizeof *v) : NULL;
    if (!v) return -1;
    t->val = v;
    t->cap = cap;
  }
  t->row[t->n] = row, t->col[t->n] = col, t->val[t->n++] = val;
  return 0;
}

static void triplets_free(Triplets *t) { free(t->row), free(t->col), free(t->val); }

/* The rows of `t` (nrow of them) with duplicates summed in assembly order. */
static int ell_from(const Triplets *t, int nrow, Ell *e) {
  int *start = calloc(nrow + 1, sizeof *start), *order = malloc((t->n ? t->n : 1) * sizeof *order);
  int *len = calloc(nrow ? nrow : 1, sizeof *len);
  memset(e, 0, sizeof *e);
  if (!start || !order || !len) {
    free(start), free(order), free(len);
    return -1;
  }
  for (int k = 0; k < t->n; k++) start[t->row[k] + 1]++;
  for (int i = 0; i < nrow; i++) start[i + 1] += start[i];
  int *fill = malloc((nrow ? nrow : 1) * sizeof *fill);
  if (!fill) {
    free(start), free(order), free(len);
    return -1;
  }
  memcpy(fill, start, nrow * sizeof *fill);
  for (int k = 0; k < t->n; k++) order[fill[t->row[k]]++] = k; /* stable: assembly order within a row */
  free(fill);
  /* distinct columns per row: the width */
  int width = 1;
  for (int i = 0; i < nrow; i++) {
    for (int a = start[i]; a < start[i + 1]; a++) {
      int seen = 0;
      for (int b = start[i]; b < a && !seen; b++) seen = t->col[order[b]] == t->col[order[a]];
      len[i] += !seen;
    }
    if (len[i] > width) width = len[i];
  }
  e->nrow = nrow, e->width = width;
  e->col = malloc((size_t)nrow * width * sizeof *e->col);
  e->val = calloc((size_t)nrow * width, sizeof *e->val);
  if (!e->col || !e->val) {
    free(start), free(order), free(len), free(e->col), free(e->val);
    return -1;
  }
  for (size_t k = 0; k < (size_t)nrow * width; k++) e->col[k] = -1;
  for (int i = 0; i < nrow; i++) {
    int n = 0;
    long *col = e->col + (size_t)i * width;
    double *val = e->val + (size_t)i * width;
    for (int a = start[i]; a < start[i + 1]; a++) {
      int k = order[a], q = 0;
      while (q < n && col[q] != t->col[k]) q++;
      if (q == n) col[n++] = t->col[k];
      val[q] += t->val[k];
    }
  }
  free(start), free(order), free(len);
  return 0;
}

static void ell_free(Ell *e) { free(e->col), free(e->val); }

/* Contributions listed per row, not merged (their values depend on the positions): entry k of
 * `t` is row t->row[k] and the NTAB integers tab[j][k]; out[j] [nrow][*width], -1 padding. */
enum { NTAB = 6 };
static int lists_from(const Triplets *t, int *const tab[NTAB], int ntab, int nrow, int *width, long *out[NTAB]) {
  int *len = calloc(nrow ? nrow : 1, sizeof *len), w = 1;
  if (!len) return -1;
  for (int k = 0; k < t->n; k++)
    if (++len[t->row[k]] > w) w = len[t->row[k]];
  *width = w;
  int rc = 0;
  for (int j = 0; j < ntab; j++) {
    out[j] = malloc((size_t)nrow * w * sizeof *out[j]);
    if (!out[j]) rc = -1;
    else
      for (size_t q = 0; q < (size_t)nrow * w; q++) out[j][q] = -1;
  }
  memset(len, 0, (nrow ? nrow : 1) * sizeof *len);
  for (int k = 0; k < t->n && rc == 0; k++) {
    int r = t->row[k], q = len[r]++;
    for (int j = 0; j < ntab; j++) out[j][(size_t)r * w + q] = tab[j][k];
  }
  free(len);
  return rc;
}

/* The projection's matrices at the solver's geometry: R = C^T P^T and S = C^T K C
 * (stream.c's assembly, both triangles of S), and the edges' unknowns. */
static int stream_matrices(const FullSolver *s, int *dof, Ell *R, Ell *S) {
  const FluidMesh *m = s->m;
  int ndof = stream_number_dofs(m, dof);
  Triplets tr = {0}, ts = {0};
  int rc = 0;
  for (int c = 0; c < m->nc && rc == 0; c++) {
    double Q[2][3], a[3][2];
    stream_cell_curl(m, s->g, c, Q, a);
    for (int p = 0; p < 3; p++) {
      int dp = dof[m->cell[3 * c + p]];
      if (dp < 0) continue;
      rc |= triplet_add(&tr, dp, 2 * c, Q[0][p]);
      rc |= triplet_add(&tr, dp, 2 * c + 1, Q[1][p]);
      for (int q = 0; q < 3; q++) {
        int dq = dof[m->cell[3 * c + q]];
        if (dq >= 0) rc |= triplet_add(&ts, dp, dq, (Q[0][p] * Q[0][q] + Q[1][p] * Q[1][q]) / s->ops.area[c]);
      }
    }
  }
  if (rc == 0) rc = ell_from(&tr, ndof, R);
  if (rc == 0) rc = ell_from(&ts, ndof, S);
  triplets_free(&tr), triplets_free(&ts);
  return rc ? -1 : ndof;
}

static int save_f64(const char *dir, const char *name, int ndim, const long *shape, const double *v, char *err,
                    size_t errlen);
static int save_int(const char *dir, const char *name, int ndim, const long *shape, const int *v, char *err,
                    size_t errlen);

static int save_i64(const char *dir, const char *name, int ndim, const long *shape, const long *v, char *err,
                    size_t errlen) {
  char path[8192];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  return npg_npy_write_i64(path, ndim, shape, v, err, errlen);
}

/* The moving mesh's step (tunnel_step_moving.npg): the operators are rebuilt from the
 * positions every step, so the tables say which positions each entry reads. R and S by rows
 * of contributions: cell c's vertex q adds Q[d][q] = a_{q+1}[d] - a_{q+2}[d] = (g_{q+2} -
 * g_{q+1})[d] / 2 (stream_cell_curl), so a contribution names its cell and two vertices; the
 * cells' graph Laplacian (the particular flux's system, last cell pinned) by merged rows; the
 * positions of every step g_t and g_{t+1}, given per step. */
static int dump_moving(const char *dir, const FullSolver *s, const int *dof, int ndof, const double *Sg, int T,
                       char *err, size_t errlen) {
  const FluidMesh *m = s->m;
  int C = m->nc, F = m->nf, nphi = C - 1;
  Triplets tr = {0}, ts = {0}, tl = {0}, td = {0};
  int *rt[NTAB], *st[NTAB], *dt_[NTAB] = {0};
  size_t cap = 9 * (size_t)C + 1;
  int rc = 0;
  for (int j = 0; j < NTAB; j++) {
    rt[j] = malloc(cap * sizeof *rt[j]), st[j] = malloc(cap * sizeof *st[j]), dt_[j] = malloc(cap * sizeof *dt_[j]);
    if (!rt[j] || !st[j] || !dt_[j]) rc = -1;
  }
  for (int c = 0; c < C && rc == 0; c++) {
    const int *t = m->cell + 3 * c;
    for (int p = 0; p < 3; p++) {
      int dp = dof[t[p]];
      if (dp < 0) continue;
      int n = tr.n;
      rt[0][n] = 2 * c, rt[1][n] = 2 * c + 1, rt[2][n] = t[(p + 1) % 3], rt[3][n] = t[(p + 2) % 3];
      rc |= triplet_add(&tr, dp, 0, 0);
      /* S's diagonal terms |Q_p|^2 / area apart: the squares that make it definite */
      n = td.n;
      dt_[0][n] = c, dt_[1][n] = t[(p + 1) % 3], dt_[2][n] = t[(p + 2) % 3];
      rc |= triplet_add(&td, dp, 0, 0);
      for (int q = 0; q < 3; q++) {
        int dq = dof[t[q]];
        if (dq < 0 || q == p) continue;
        n = ts.n;
        st[0][n] = dq, st[1][n] = c, st[2][n] = t[(p + 1) % 3], st[3][n] = t[(p + 2) % 3];
        st[4][n] = t[(q + 1) % 3], st[5][n] = t[(q + 2) % 3];
        rc |= triplet_add(&ts, dp, 0, 0);
      }
    }
  }
  for (int j = 0; j < F && rc == 0; j++) {
    if (m->fkind[j] != BF_INTERIOR) continue;
    int c0 = m->fcell[2 * j], c1 = m->fcell[2 * j + 1];
    if (c0 < nphi) rc |= triplet_add(&tl, c0, c0, 1);
    if (c1 < nphi) rc |= triplet_add(&tl, c1, c1, 1);
    if (c0 < nphi && c1 < nphi) rc |= triplet_add(&tl, c0, c1, -1), rc |= triplet_add(&tl, c1, c0, -1);
  }
  if (rc == 0) rc = triplet_add(&tl, nphi, nphi, 1); /* the pinned cell: phi = 0 */
  long *rl[NTAB] = {0}, *sl[NTAB] = {0}, *dl[NTAB] = {0};
  int wr = 0, ws = 0, wd = 0;
  Ell L = {0};
  if (rc == 0) rc = lists_from(&tr, rt, 4, ndof, &wr, rl);
  if (rc == 0) rc = lists_from(&ts, st, 6, ndof, &ws, sl);
  if (rc == 0) rc = lists_from(&td, dt_, 3, ndof, &wd, dl);
  if (rc == 0) rc = ell_from(&tl, C, &L);
  int *fint = malloc(F * sizeof *fint), *fc0 = malloc(F * sizeof *fc0), *fc1 = malloc(F * sizeof *fc1);
  int *ucomp = malloc(2 * (size_t)C * sizeof *ucomp);
  double *cfree = malloc(C * sizeof *cfree), *fbnd = malloc(F * sizeof *fbnd);
  size_t gv = 2 * (size_t)m->nv;
  double *gn = malloc(((size_t)T + 1) * gv * sizeof *gn);
  if (rc || !fint || !fc0 || !fc1 || !ucomp || !gn || !cfree || !fbnd) {
    rc = npg_error_set(err, errlen, "out of memory for the moving step's tables (--dump-step %s)", dir);
    goto done;
  }
  for (int j = 0; j < F; j++) {
    int interior = m->fkind[j] == BF_INTERIOR, c0 = m->fcell[2 * j], c1 = m->fcell[2 * j + 1];
    fint[j] = interior;
    fc0[j] = interior && c0 < nphi ? c0 : -1;
    fc1[j] = interior && c1 < nphi ? c1 : -1;
  }
  for (int i = 0; i < 2 * C; i++) ucomp[i] = i % 2;
  for (int c = 0; c < C; c++) cfree[c] = c < nphi;
  long c3[2] = {C, 3}, f2[2] = {F, 2}, f1[1] = {F}, u1[1] = {2 * (long)C};
  long rs[2] = {ndof, wr}, ss[2] = {ndof, ws}, ds[2] = {ndof, wd}, ls[2] = {C, L.width}, c1[1] = {C};
  const char *rname[4] = {"rx", "ry", "rv1", "rv2"}, *sname[6] = {"mcol", "mcell", "mp1", "mp2", "mq1", "mq2"};
  rc = save_int(dir, "tri", 2, c3, m->cell, err, errlen);
  if (!rc) rc = save_int(dir, "edge", 2, f2, m->face, err, errlen);
  if (!rc) rc = save_int(dir, "ucomp", 1, u1, ucomp, err, errlen);
  if (!rc) rc = save_int(dir, "fint", 1, f1, fint, err, errlen);
  for (int j = 0; j < F; j++) fbnd[j] = 1 - fint[j];
  if (!rc) rc = save_f64(dir, "fbnd", 1, f1, fbnd, err, errlen);
  if (!rc) rc = save_int(dir, "fc0", 1, f1, fc0, err, errlen);
  if (!rc) rc = save_int(dir, "fc1", 1, f1, fc1, err, errlen);
  for (int j = 0; j < 4 && !rc; j++) rc = save_i64(dir, rname[j], 2, rs, rl[j], err, errlen);
  for (int j = 0; j < 6 && !rc; j++) rc = save_i64(dir, sname[j], 2, ss, sl[j], err, errlen);
  const char *dname[3] = {"dcell", "d1", "d2"};
  for (int j = 0; j < 3 && !rc; j++) rc = save_i64(dir, dname[j], 2, ds, dl[j], err, errlen);
  if (!rc) rc = save_i64(dir, "lcol", 2, ls, L.col, err, errlen);
  if (!rc) rc = save_f64(dir, "lval", 2, ls, L.val, err, errlen);
  if (!rc) rc = save_f64(dir, "cfree", 1, c1, cfree, err, errlen);
  /* the positions of steps 0..T-1 and the ones each step moves to */
  if (!rc && T > 0) {
    long sg[4] = {1, T, m->nv, 2};
    rc = save_f64(dir, "g", 4, sg, Sg, err, errlen);
    memcpy(gn, Sg + gv, (size_t)(T - 1) * gv * sizeof *gn);
    memcpy(gn + (size_t)(T - 1) * gv, s->g, gv * sizeof *gn);
    if (!rc) rc = save_f64(dir, "gn", 4, sg, gn, err, errlen);
  }
done:
  for (int j = 0; j < NTAB; j++) free(rt[j]), free(st[j]), free(dt_[j]), free(rl[j]), free(sl[j]), free(dl[j]);
  triplets_free(&tr), triplets_free(&ts), triplets_free(&tl), triplets_free(&td);
  ell_free(&L);
  free(fint), free(fc0), free(fc1), free(ucomp), free(gn), free(cfree), free(fbnd);
  return rc ? -1 : 0;
}

static int save_f64(const char *dir, const char *name, int ndim, const long *shape, const double *v, char *err,
                    size_t errlen) {
  char path[8192];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  return npg_npy_write(path, ndim, shape, v, err, errlen);
}

static int save_int(const char *dir, const char *name, int ndim, const long *shape, const int *v, char *err,
                    size_t errlen) {
  size_t n = 1;
  for (int i = 0; i < ndim; i++) n *= (size_t)shape[i];
  long *w = malloc((n ? n : 1) * sizeof *w);
  if (!w) return npg_error_set(err, errlen, "out of memory writing %s/%s.npy", dir, name);
  for (size_t i = 0; i < n; i++) w[i] = v[i];
  char path[8192];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  int rc = npg_npy_write_i64(path, ndim, shape, w, err, errlen);
  free(w);
  return rc;
}

int tunnel_step_dump(const char *dir, const FullSolver *s, const double *Su, const double *Sf, const double *Sg, int T,
                     int moving, char *err, size_t errlen) {
  const FluidMesh *m = s->m;
  long C = m->nc, U = 2 * C, F = m->nf;
  char sub[4096];
  snprintf(sub, sizeof sub, "%s/driver", dir);
  if (report_make_dir("npg-fluids", dir) || report_make_dir("npg-fluids", sub))
    return npg_error_set(err, errlen, "--dump-step %s: could not create the folder", dir);
  int *dof = malloc(m->nv * sizeof *dof), *ucell = malloc(U * sizeof *ucell), *unbr = malloc(3 * U * sizeof *unbr);
  int *fhead = malloc(F * sizeof *fhead), *ftail = malloc(F * sizeof *ftail);
  double *pval = malloc(3 * U * sizeof *pval), *traj = malloc((size_t)(T + 1) * (U > F ? U : F) * sizeof *traj);
  Ell R = {0}, S = {0};
  int rc = -1, ndof = -1;
  if (dof && ucell && unbr && fhead && ftail && pval && traj) ndof = stream_matrices(s, dof, &R, &S);
  if (ndof < 0) {
    npg_error_set(err, errlen, "out of memory for the step's matrices (--dump-step %s)", dir);
    goto done;
  }
  for (long i = 0; i < U; i++) {
    long c = i / 2, d = i % 2;
    ucell[i] = (int)c;
    for (int k = 0; k < 3; k++) {
      int n = m->nbr[3 * c + k];
      unbr[3 * i + k] = n >= 0 ? (int)(2 * n + d) : -1;
      pval[3 * i + k] = s->ops.P.val[3 * i + k]; /* row 2c + d of P: its three edges cface[c][k] */
    }
  }
  for (long j = 0; j < F; j++) {
    int interior = m->fkind[j] == BF_INTERIOR;
    fhead[j] = interior ? dof[m->face[2 * j + 1]] : -1;
    ftail[j] = interior ? dof[m->face[2 * j]] : -1;
  }
  long c3[2] = {C, 3}, u1[1] = {U}, u3[2] = {U, 3}, f1[1] = {F}, c1[1] = {C};
  long rs[2] = {ndof, R.width}, ss[2] = {ndof, S.width};
  rc = save_int(dir, "ucell", 1, u1, ucell, err, errlen);
  if (!rc) rc = save_int(dir, "unbr", 2, u3, unbr, err, errlen);
  if (!rc) rc = save_int(dir, "cface", 2, c3, m->cface, err, errlen);
  if (!rc) rc = save_f64(dir, "csign", 2, c3, m->csign, err, errlen);
  if (!rc && !moving) rc = save_f64(dir, "area", 1, c1, s->ops.area, err, errlen);
  if (!rc) rc = save_f64(dir, "mu", 0, NULL, &s->mu, err, errlen);
  if (!rc) rc = save_f64(dir, "dt", 0, NULL, &s->dt, err, errlen);
  if (!rc && !moving) rc = save_i64(dir, "rcol", 2, rs, R.col, err, errlen);
  if (!rc && !moving) rc = save_i64(dir, "scol", 2, ss, S.col, err, errlen);
  if (!rc && !moving) rc = save_f64(dir, "rval", 2, rs, R.val, err, errlen);
  if (!rc && !moving) rc = save_f64(dir, "sval", 2, ss, S.val, err, errlen);
  if (!rc) rc = save_int(dir, "fhead", 1, f1, fhead, err, errlen);
  if (!rc) rc = save_int(dir, "ftail", 1, f1, ftail, err, errlen);
  if (!rc && !moving) rc = save_f64(dir, "pval", 2, u3, pval, err, errlen);
  if (!rc) rc = dump_moving(dir, s, dof, ndof, Sg, T, err, errlen);
  /* frame 0, one trajectory */
  if (!rc) rc = save_f64(dir, "u", 2, (long[]){1, U}, T > 0 ? Su : s->u, err, errlen);
  if (!rc) rc = save_f64(dir, "f", 2, (long[]){1, F}, T > 0 ? Sf : s->f, err, errlen);
  /* the driver's frames 0..T */
  if (!rc) {
    memcpy(traj, Su, (size_t)T * U * sizeof *traj);
    memcpy(traj + (size_t)T * U, s->u, U * sizeof *traj);
    rc = save_f64(sub, "u", 3, (long[]){1, T + 1, U}, traj, err, errlen);
  }
  if (!rc) {
    memcpy(traj, Sf, (size_t)T * F * sizeof *traj);
    memcpy(traj + (size_t)T * F, s->f, F * sizeof *traj);
    rc = save_f64(sub, "f", 3, (long[]){1, T + 1, F}, traj, err, errlen);
  }
  if (!rc)
    fprintf(stderr, "npg-fluids: the %s step's data in %s: %ld velocity entries, %ld edges, %d stream function "
                    "unknowns; the driver's %d steps in %s\n",
            moving ? "moving (tunnel_step_moving.npg)" : "fixed (tunnel_step.npg)", dir, U, F, ndof, T, sub);
done:
  free(dof), free(ucell), free(unbr), free(fhead), free(ftail), free(pval), free(traj);
  ell_free(&R), ell_free(&S);
  return rc ? -1 : 0;
}
