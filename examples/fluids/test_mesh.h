/* test_mesh.h — what the fluids tests use to tell that two meshes are the
 * same up to numbering: the vertex map their rest positions define, and
 * cells or faces as sorted vertex sets. */
#ifndef FLUIDS_TEST_MESH_H
#define FLUIDS_TEST_MESH_H

#include <stdlib.h>
#include <string.h>

#include "mesh.h"

typedef struct MeshPoint {
  double x[3];
  int v;
} MeshPoint;

static int cmp_mesh_point(const void *pa, const void *pb) {
  const MeshPoint *a = pa, *b = pb;
  for (int d = 0; d < 3; d++)
    if (a->x[d] != b->x[d]) return a->x[d] < b->x[d] ? -1 : 1;
  return 0;
}

/* to_a[v]: the vertex of a at b's vertex v's rest position (a and b hold
 * the same distinct points, asserted). */
static int *vertex_map(const FluidMesh *a, const FluidMesh *b) {
  assert_int_equal(a->nv, b->nv);
  int nv = a->nv, dim = a->dim, *to_a = malloc(nv * sizeof *to_a);
  MeshPoint *pa = calloc(nv, sizeof *pa), *pb = calloc(nv, sizeof *pb);
  for (int v = 0; v < nv; v++) {
    pa[v].v = pb[v].v = v;
    memcpy(pa[v].x, a->g0 + dim * v, dim * sizeof(double)), memcpy(pb[v].x, b->g0 + dim * v, dim * sizeof(double));
  }
  qsort(pa, nv, sizeof *pa, cmp_mesh_point), qsort(pb, nv, sizeof *pb, cmp_mesh_point);
  for (int i = 0; i < nv; i++) {
    assert_memory_equal(pa[i].x, pb[i].x, sizeof pa[i].x);
    assert_true(i == 0 || cmp_mesh_point(pa + i - 1, pa + i) < 0); /* distinct points: the map is one to one */
    to_a[pb[i].v] = pa[i].v;
  }
  free(pa), free(pb);
  return to_a;
}

static int cmp_int5(const void *pa, const void *pb) { return memcmp(pa, pb, 5 * sizeof(int)); }

/* n items (cells or faces) of `width` (at most 4) vertices as rows of five
 * ints: the vertices mapped by `to` (NULL: as they are) and sorted, -1 in
 * the unused places, then tag[i] (0 when tag is NULL); the rows sorted
 * (memcmp order: a total order, all that comparing two lists needs). */
static int *vertex_sets(const int *items, int n, int width, const int *to, const int *tag) {
  int *s = malloc(5 * (size_t)n * sizeof *s);
  for (int i = 0; i < n; i++) {
    int *x = s + 5 * i;
    for (int q = 0; q < 4; q++) x[q] = q < width ? (to ? to[items[width * i + q]] : items[width * i + q]) : -1;
    x[4] = tag ? tag[i] : 0;
    for (int a = 0; a < width; a++)
      for (int b = a + 1; b < width; b++)
        if (x[b] < x[a]) {
          int t = x[a];
          x[a] = x[b], x[b] = t;
        }
  }
  qsort(s, n, 5 * sizeof *s, cmp_int5);
  return s;
}

/* b's items are a's (through the vertex map to_a), as sets. */
static void assert_same_sets(const int *ia, const int *ib, int n, int width, const int *to_a, const int *tag_a,
                             const int *tag_b) {
  int *sa = vertex_sets(ia, n, width, NULL, tag_a), *sb = vertex_sets(ib, n, width, to_a, tag_b);
  assert_memory_equal(sa, sb, 5 * (size_t)n * sizeof *sa);
  free(sa), free(sb);
}

#endif
