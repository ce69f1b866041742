/* gen_data.c — samples for examples/radiosity/formfactors.npg on the
 * deforming room of examples/common/meshgen (a closed, convex triangulated box whose
 * far wall moves out and whose ceiling tilts with a parameter t in [0, 1]):
 *
 *     radiosity_data OUTDIR F SAMPLES T0 T1 SEED
 *
 * writes OUTDIR/tri.npy (int64 [F,3]) and rho.npy ([F]) — the params, fixed
 * topology — and, per sample k at t = T0 + (T1 - T0) k / (SAMPLES - 1):
 * g.npy ([S,V,3] vertex positions), e.npy ([S,F] emission: the ceiling
 * light plus a dim light of random strength on each of the six walls, from
 * SEED) and v.npy
 * ([S,F,F] visibility: 1, the room is convex). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "meshgen.h"
#include "npg.h"
#include "util.h"

/* DIR/NAME.npy: float64 `data`, or int64 `idata` when `data` is NULL. */
static int write(const char *dir, const char *name, int nd, const long *shape, const double *data, const long *idata) {
  char path[4096], err[1024];
  snprintf(path, sizeof path, "%s/%s.npy", dir, name);
  if ((data ? npg_npy_write(path, nd, shape, data, err, sizeof err)
            : npg_npy_write_i64(path, nd, shape, idata, err, sizeof err)) != 0) {
    fprintf(stderr, "radiosity_data: %s\n", err);
    return -1;
  }
  return 0;
}

int main(int argc, char **argv) {
  if (argc != 7) {
    fprintf(stderr, "usage: %s OUTDIR F SAMPLES T0 T1 SEED\n", argv[0]);
    return 2;
  }
  long F, S, seed_l;
  double t0, t1;
  char err[1024];
  const char *what = "F";
  if (npg_parse_long(argv[2], 12, 100000, &F, err, sizeof err) != 0 || (what = "SAMPLES",
      npg_parse_long(argv[3], 1, 100000, &S, err, sizeof err) != 0) || (what = "T0",
      npg_parse_double(argv[4], 0, 1, false, &t0, err, sizeof err) != 0) || (what = "T1",
      npg_parse_double(argv[5], 0, 1, false, &t1, err, sizeof err) != 0) || (what = "SEED",
      npg_parse_long(argv[6], 0, 4294967295L, &seed_l, err, sizeof err) != 0)) {
    fprintf(stderr, "%s: %s: %s\n", argv[0], what, err);
    return 2;
  }
  unsigned seed = (unsigned)seed_l;
  if (F % 2) {
    fprintf(stderr, "%s: F: %ld is odd (the room's faces come in pairs: an even count, 12..100000)\n", argv[0], F);
    return 2;
  }
  if ((double)S * (double)F * (double)F > 4e8) {
    fprintf(stderr, "%s: SAMPLES * F^2 visibility entries exceed 4e8 (3.2 GB)\n", argv[0]);
    return 2;
  }
  if (util_make_dirs(argv[1], err, sizeof err) != 0) {
    fprintf(stderr, "%s: %s\n", argv[0], err);
    return 1;
  }
  Mesh mesh;
  if (mesh_room(F, t0, &mesh, err, sizeof err) != 0) {
    fprintf(stderr, "%s: %s\n", argv[0], err);
    return 1;
  }
  long V = mesh.V;
  long *tri = malloc(sizeof(long) * (size_t)(3 * F));
  double *rho = malloc(sizeof(double) * (size_t)F), *g = malloc(sizeof(double) * (size_t)(S * V * 3));
  double *e = malloc(sizeof(double) * (size_t)(S * F)), *v = malloc(sizeof(double) * (size_t)(S * F * F));
  int rc = 1;
  if (!tri || !rho || !g || !e || !v) {
    fprintf(stderr, "%s: out of memory\n", argv[0]);
    goto done;
  }
  for (long i = 0; i < 3 * F; i++) tri[i] = mesh.tri[i];
  mesh_rho(&mesh, rho);
  for (long k = 0; k < S; k++) {
    Mesh mk;
    double t = S > 1 ? t0 + (t1 - t0) * (double)k / (double)(S - 1) : t0;
    if (mesh_room(F, t, &mk, err, sizeof err) != 0) {
      fprintf(stderr, "%s: %s\n", argv[0], err);
      goto done;
    }
    memcpy(g + k * V * 3, mk.g, sizeof(double) * (size_t)(V * 3));
    mesh_emission(&mk, e + k * F);
    double wall[6];
    for (int w = 0; w < 6; w++) {
      seed = seed * 1103515245u + 12345u;
      wall[w] = 0.3 * ((seed >> 8) & 0xffffff) / (double)0x1000000;
    }
    for (long i = 0; i < F; i++) {
      int w = mesh_face_wall(&mk, i);
      e[k * F + i] += w >= 0 && w < 6 ? wall[w] : 0;
    }
    mesh_free(&mk);
  }
  for (long i = 0; i < S * F * F; i++) v[i] = 1;
  long st[2] = {F, 3}, sr[1] = {F}, sg[3] = {S, V, 3}, se[2] = {S, F}, sv[3] = {S, F, F};
  if (write(argv[1], "tri", 2, st, NULL, tri) || write(argv[1], "rho", 1, sr, rho, NULL) ||
      write(argv[1], "g", 3, sg, g, NULL) || write(argv[1], "e", 2, se, e, NULL) || write(argv[1], "v", 3, sv, v, NULL))
    goto done;
  rc = 0;
done:
  mesh_free(&mesh);
  free(tri), free(rho), free(g), free(e), free(v);
  return rc;
}
