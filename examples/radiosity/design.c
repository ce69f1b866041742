/* design.c — the training design (design.h). */
#include "design.h"

#include <math.h>
#include <string.h>

static const int primes[SCENE_NGEOM + 3] = {2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37};

/* The radical inverse of i in base b: digit j of i becomes digit -j-1 of the result. */
static double halton(long i, int b) {
  double f = 1, r = 0;
  for (; i > 0; i /= b) f /= b, r += f * (double)(i % b);
  return r;
}

void design_point(int k, SceneParams *p) {
  double t[SCENE_NGEOM];
  for (int a = 0; a < SCENE_NGEOM; a++) t[a] = 0.5;
  int j = k;
  if (j == 0) {
    /* the middle */
  } else if ((j -= 1) < 2 * SCENE_NGEOM) {
    t[j / 2] = j % 2;
  } else if ((j -= 2 * SCENE_NGEOM) < 32) {
    int b[5];
    for (int a = 0; a < 5; a++) b[a] = (j >> a) & 1;
    for (int a = 0; a < 5; a++) t[a] = b[a];
    t[5] = b[0] ^ b[1] ^ b[2];
    t[6] = b[1] ^ b[2] ^ b[3];
    t[7] = b[2] ^ b[3] ^ b[4];
    t[8] = b[0] ^ b[3] ^ b[4];
  } else {
    j -= 32;
    for (int a = 0; a < SCENE_NGEOM; a++) t[a] = 0.02 + 0.96 * halton(j + 1, primes[a]);
  }
  scene_param_at(t, p);
  if (k > 0) {
    p->rad_living = 0.25 + 2.25 * halton(k, primes[SCENE_NGEOM]);
    p->rad_bed = 0.25 + 2.25 * halton(k, primes[SCENE_NGEOM + 1]);
    p->rad_sky = 0.25 + 2.25 * halton(k, primes[SCENE_NGEOM + 2]);
  }
}

double design_structured_weight(int n, double w) {
  if (w > 0) return w;
  return n > 2 * DESIGN_STRUCTURED ? (double)(n - DESIGN_STRUCTURED) / DESIGN_STRUCTURED : 1;
}

int design_contains(int n, const SceneParams *p) {
  for (int k = 0; k < n; k++) {
    SceneParams q;
    design_point(k, &q);
    if (!memcmp(&q, p, sizeof q)) return 1;
  }
  return 0;
}
