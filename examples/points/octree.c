/* octree.c — adaptive octree build (octree.h). */
#define _GNU_SOURCE /* qsort_r */
#include "octree.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int octant_of(const Surfels *s, long i, const double c[3]) {
  return (s->x[i] > c[0]) | ((s->y[i] > c[1]) << 1) | ((s->z[i] > c[2]) << 2);
}

/* The orientation group of a normal: its dominant axis and that
 * component's sign (±x ±y ±z: 0..5). */
static int group_of(const Surfels *s, long i) {
  double a[3] = {fabs(s->nx[i]), fabs(s->ny[i]), fabs(s->nz[i])}, v[3] = {s->nx[i], s->ny[i], s->nz[i]};
  int k = a[0] >= a[1] && a[0] >= a[2] ? 0 : a[1] >= a[2] ? 1 : 2;
  return 2 * k + (v[k] < 0);
}

/* Move the points [start, start+count) into the order of their key (an
 * octant of the cube centred at `c`, or with `c` NULL the orientation
 * group), through the scratch arrays, and return the key counts in `cnt`. */
static void partition(Surfels *s, long *perm, long start, long count, const double *c, long cnt[8], long *order,
                      double *dtmp, int *itmp, long *ltmp) {
  long first[8];
  memset(cnt, 0, sizeof(long) * 8);
  for (long i = start; i < start + count; i++) itmp[i - start] = c ? octant_of(s, i, c) : group_of(s, i);
  for (long i = start; i < start + count; i++) cnt[itmp[i - start]]++;
  first[0] = 0;
  for (int o = 1; o < 8; o++) first[o] = first[o - 1] + cnt[o - 1];
  for (long i = start; i < start + count; i++) order[first[itmp[i - start]]++] = i;
  double *cols[] = {s->x, s->y, s->z, s->nx, s->ny, s->nz, s->w};
  for (size_t k = 0; k < sizeof cols / sizeof *cols; k++) {
    for (long j = 0; j < count; j++) dtmp[j] = cols[k][order[j]];
    memcpy(cols[k] + start, dtmp, sizeof(double) * (size_t)count);
  }
  double *rgb[] = {s->rho, s->e};
  for (int k = 0; k < 2; k++)
    for (int ch = 0; ch < 3; ch++) {
      for (long j = 0; j < count; j++) dtmp[j] = rgb[k][3 * order[j] + ch];
      for (long j = 0; j < count; j++) rgb[k][3 * (start + j) + ch] = dtmp[j];
    }
  for (long j = 0; j < count; j++) itmp[j] = s->tri[order[j]];
  memcpy(s->tri + start, itmp, sizeof(int) * (size_t)count);
  for (long j = 0; j < count; j++) ltmp[j] = perm[order[j]];
  memcpy(perm + start, ltmp, sizeof(long) * (size_t)count);
}

static void node_bounds(const Surfels *s, OctNode *nd) {
  double sum[3] = {0, 0, 0};
  for (int k = 0; k < 3; k++) nd->lo[k] = INFINITY, nd->hi[k] = -INFINITY;
  for (long i = nd->start; i < nd->start + nd->count; i++) {
    double p[3] = {s->x[i], s->y[i], s->z[i]};
    for (int k = 0; k < 3; k++) {
      if (p[k] < nd->lo[k]) nd->lo[k] = p[k];
      if (p[k] > nd->hi[k]) nd->hi[k] = p[k];
    }
    sum[0] += s->nx[i], sum[1] += s->ny[i], sum[2] += s->nz[i];
  }
  double len = sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
  if (len < 1e-12) sum[0] = 1, sum[1] = sum[2] = 0, len = 1;
  double maxdev = 0;
  for (int k = 0; k < 3; k++) nd->axis[k] = sum[k] / len;
  for (long i = nd->start; i < nd->start + nd->count; i++) {
    double d0 = s->nx[i] - nd->axis[0], d1 = s->ny[i] - nd->axis[1], d2 = s->nz[i] - nd->axis[2];
    double dev = d0 * d0 + d1 * d1 + d2 * d2;
    if (dev > maxdev) maxdev = dev;
  }
  nd->spread = sqrt(maxdev);
}

static int by_first_point(const void *a, const void *b, void *nodes) {
  const OctNode *nd = nodes;
  long sa = nd[*(const int *)a].start, sb = nd[*(const int *)b].start;
  return (sa > sb) - (sa < sb);
}

int octree_build(Surfels *s, int leaf_size, Octree *t) {
  memset(t, 0, sizeof *t);
  long n = s->n;
  if (leaf_size < 1) leaf_size = 1;
  t->leaf_size = leaf_size;
  int cap = 1024;
  t->node = malloc(sizeof(OctNode) * (size_t)cap);
  t->perm = malloc(sizeof(long) * (size_t)n);
  long *order = malloc(sizeof(long) * (size_t)n), *ltmp = malloc(sizeof(long) * (size_t)n);
  double *dtmp = malloc(sizeof(double) * (size_t)n);
  int *itmp = malloc(sizeof(int) * (size_t)n);
  if (!t->node || !t->perm || !order || !ltmp || !dtmp || !itmp) goto oom;
  for (long i = 0; i < n; i++) t->perm[i] = i;

  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (long i = 0; i < n; i++) {
    double p[3] = {s->x[i], s->y[i], s->z[i]};
    for (int k = 0; k < 3; k++) lo[k] = fmin(lo[k], p[k]), hi[k] = fmax(hi[k], p[k]);
  }
  OctNode *root = &t->node[0];
  memset(root, 0, sizeof *root);
  double half = 0;
  for (int k = 0; k < 3; k++) root->c[k] = 0.5 * (lo[k] + hi[k]), half = fmax(half, 0.5 * (hi[k] - lo[k]));
  root->h = half * (1 + 1e-9) + 1e-300;
  root->parent = -1, root->start = 0, root->count = n;
  root->nchild = 0;
  t->nnode = 1;

  /* the root stands for the orientation groups: each is an octree of its
   * own over the same root cube, so cubes of one level line up across
   * groups and the points of one cube face one way (fmm.c's facing test) */
  long gcnt[8];
  partition(s, t->perm, 0, n, NULL, gcnt, order, dtmp, itmp, ltmp);
  t->grouped = 1;
  for (int o = 0; o < 8; o++) root->child[o] = -1;
  long at0 = 0;
  for (int g = 0; g < 6; g++) {
    if (gcnt[g] == 0) continue;
    OctNode *gr = &t->node[t->nnode];
    *gr = t->node[0];
    gr->parent = 0, gr->start = at0, gr->count = gcnt[g], gr->level = 0;
    at0 += gcnt[g];
    t->node[0].child[g] = t->nnode++;
    t->node[0].nchild++;
  }

  for (int q = 1; q < t->nnode; q++) { /* breadth first: q walks the queue the array is */
    OctNode nd = t->node[q];
    for (int o = 0; o < 8; o++) t->node[q].child[o] = -1;
    t->node[q].nchild = 0;
    if (nd.count <= leaf_size || nd.level >= 30) continue;
    long cnt[8];
    partition(s, t->perm, nd.start, nd.count, nd.c, cnt, order, dtmp, itmp, ltmp);
    long at = nd.start;
    for (int o = 0; o < 8; o++) {
      if (cnt[o] == 0) continue;
      if (t->nnode == cap) {
        cap *= 2;
        OctNode *g = realloc(t->node, sizeof(OctNode) * (size_t)cap);
        if (!g) goto oom;
        t->node = g;
      }
      OctNode *ch = &t->node[t->nnode];
      memset(ch, 0, sizeof *ch);
      ch->h = 0.5 * nd.h;
      for (int k = 0; k < 3; k++) ch->c[k] = nd.c[k] + ((o >> k) & 1 ? ch->h : -ch->h);
      ch->level = nd.level + 1, ch->parent = q, ch->start = at, ch->count = cnt[o];
      at += cnt[o];
      t->node[q].child[o] = t->nnode++;
      t->node[q].nchild++;
    }
  }
  /* levels, leaves in point order, bounds and normal cones */
  t->depth = t->node[t->nnode - 1].level;
  t->level_first = malloc(sizeof(int) * (size_t)(t->depth + 2));
  t->leaf = malloc(sizeof(int) * (size_t)t->nnode);
  if (!t->level_first || !t->leaf) goto oom;
  for (int l = 0, q = 0; l <= t->depth + 1; l++) {
    while (q < t->nnode && t->node[q].level < l) q++;
    t->level_first[l] = q;
  }
  for (int q = 0; q < t->nnode; q++) {
    node_bounds(s, &t->node[q]);
    if (octree_is_leaf(&t->node[q])) t->leaf[t->nleaf++] = q;
  }
  /* leaves in point order: a leaf's points follow those of every leaf
   * before it, so sorting by first point orders them */
  qsort_r(t->leaf, (size_t)t->nleaf, sizeof(int), by_first_point, t->node);
  for (int q = 0; q < t->nnode; q++) t->node[q].nleaf = 0, t->node[q].leaf_first = -1;
  for (int a = 0; a < t->nleaf; a++)
    for (int q = t->leaf[a]; q >= 0; q = t->node[q].parent) {
      if (t->node[q].leaf_first < 0) t->node[q].leaf_first = a;
      t->node[q].nleaf++;
    }
  free(order), free(ltmp), free(dtmp), free(itmp);
  return 0;
oom:
  free(order), free(ltmp), free(dtmp), free(itmp);
  octree_free(t);
  return -1;
}

void octree_free(Octree *t) {
  free(t->node), free(t->leaf), free(t->level_first), free(t->perm);
  memset(t, 0, sizeof *t);
}
