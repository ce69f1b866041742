/* joint.c — a class basis by one joint PCA (--merge joint, DESIGN §5), the
 * alternative to the paper's way (§6.1, §9: one PCA per member,
 * concatenated and re-orthonormalized: train_member_bases in train.c).
 * The members' snapshot blocks, each scaled to unit norm so that no member
 * outweighs another by its units, make one snapshot matrix; its PCA is the
 * class basis. Needs every snapshot in memory (train.c refuses it under
 * the method of snapshots). */
#include <cblas.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scratch.h"
#include "train.h"
#include "train_steps.h"

/* --merge joint (DESIGN §5): one PCA of the members' snapshot blocks, each
 * scaled to unit norm first; centered (when the first member is), each
 * block minus its own mean, and the class basis the orthonormalization of
 * [μ_1 … μ_r, U_c], at most Σ cap vectors. Every member reports the joint
 * PCA. */
int train_joint_basis(RClass *rc, long S, double *const *X, Err *err) {
  size_t n = (size_t)rc->n * (size_t)S;
  int r = rc->nmembers, cap = 0, rc_ok = -1;
  bool center = rc->members[0].center;
  double energy = 1;
  Scratch sc = SCRATCH_OF(err);
  double *J = scratch_array(&sc, n * (size_t)r, sizeof(double));
  double *mu = scratch_array(&sc, (size_t)(rc->n * r + 1), sizeof(double));
  double **parts = scratch_array(&sc, (size_t)r + 1, sizeof(double *));
  int *ks = scratch_array(&sc, (size_t)r + 1, sizeof(int));
  PcaMember p = {0}; /* the joint PCA, its report copied to every member */
  bool room = J && mu && parts && ks;
  for (int i = 0; room && i < r; i++) {
    double *Ji = J + (size_t)i * n, *mi = mu + (size_t)i * (size_t)rc->n;
    memcpy(Ji, X[i], sizeof(double) * n);
    if (center) {
      pca_mean(rc->n, S, X[i], mi);
      for (long s = 0; s < S; s++) cblas_daxpy((int)rc->n, -1.0, mi, 1, Ji + s * rc->n, 1);
    }
    double nrm = cblas_dnrm2((int)n, Ji, 1);
    if (nrm > 0) cblas_dscal((int)n, 1 / nrm, Ji, 1);
    cap += rc->members[i].cap;
    energy = fmin(energy, rc->members[i].energy);
    parts[i] = mi;
    ks[i] = 1;
  }
  if (center) cap = cap > r ? cap - r : 0;
  if (!room || pca_basis(rc->n, S * r, J, &(PcaRule){.cap = cap, .energy = energy}, &p, err)) rc_ok = -1;
  else if (center) {
    parts[r] = p.U;
    ks[r] = p.k;
    int mm = 0;
    rc_ok = pca_in_order(rc->n, (PcaBlocks){r + 1, parts, ks}, &rc->B, &mm, err);
    rc->m = mm;
  } else {
    rc_ok = pca_merge(rc->n, (PcaBlocks){1, &p.U, &p.k}, &rc->B, &rc->m, err);
  }
  for (int i = 0; rc_ok == 0 && i < r; i++) {
    RMember *mb = &rc->members[i];
    mb->kept = (int)rc->m;
    mb->lost = p.lost;
    mb->captured = 1 - p.lost;
    free(mb->sv); /* replaced by the joint spectrum */
    mb->nsv = p.nsv;
    if ((mb->sv = mem_malloc(sizeof(double) * (size_t)(p.nsv + 1)))) memcpy(mb->sv, p.sv, sizeof(double) * (size_t)p.nsv);
    else rc_ok = -1;
  }
  pca_member_free(&p);
  scratch_release(&sc);
  return rc_ok;
}
