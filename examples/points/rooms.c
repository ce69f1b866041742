/* rooms.c — rooms.h: examples/radiosity's scene, converted. */
#include "rooms.h"

#include <stdio.h>
#include <stdlib.h>

#include "scene.h" /* the two rooms (examples/common) */

int scene_rooms(TriScene *out, long faces, char *err, size_t errlen) {
  Scene s;
  if (scene_new(faces, NULL, &s, err, errlen) != 0) return -1;
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (long v = 0; v < s.V; v++)
    for (int a = 0; a < 3; a++) {
      double x = s.g[3 * v + a];
      lo[a] = x < lo[a] ? x : lo[a];
      hi[a] = x > hi[a] ? x : hi[a];
    }
  double len = hi[0] - lo[0] > hi[1] - lo[1] ? hi[0] - lo[0] : hi[1] - lo[1];
  out->nv = (int)s.V, out->nt = (int)s.F;
  out->v = malloc(sizeof(double) * 3 * (size_t)s.V);
  out->tri = malloc(sizeof(int) * 3 * (size_t)s.F);
  out->albedo = malloc(sizeof(double) * 3 * (size_t)s.F);
  out->emission = malloc(sizeof(double) * 3 * (size_t)s.F);
  if (!out->v || !out->tri || !out->albedo || !out->emission) {
    triscene_free(out);
    scene_free(&s);
    snprintf(err, errlen, "out of memory for the two-room scene of %ld faces", faces);
    return -1;
  }
  double ymid = 0.5 * (lo[1] + hi[1]);
  for (long v = 0; v < s.V; v++) { /* (x, y, z) → (x, −y, −z), scaled, centred in the camera's view */
    out->v[3 * v + 0] = (s.g[3 * v + 0] - lo[0]) / len;
    out->v[3 * v + 1] = 0.5 - (s.g[3 * v + 1] - ymid) / len;
    out->v[3 * v + 2] = (hi[2] - s.g[3 * v + 2]) / len;
  }
  for (long f = 0; f < s.F; f++)
    for (int c = 0; c < 3; c++) {
      out->tri[3 * f + c] = s.tri[3 * f + c];
      out->albedo[3 * f + c] = s.rho[f];
      out->emission[3 * f + c] = s.e[f];
    }
  scene_free(&s);
  return 0;
}
