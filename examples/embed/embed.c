/* embed.c — the smallest complete use of libnpg: a mass–spring cloth in C
 * (examples/embed/README.md).
 *
 * 1. The full model: every step evaluates cloth.npg's spring forces with
 *    npg's full evaluator and integrates them; each step's state is handed
 *    to a trainer as it happens (no files).
 * 2. The trainer builds the reduced model (bases, pre-multiplied tensors).
 * 3. A new run (another wind) steps the full and the reduced model side by
 *    side from the same start; the program prints how far the reduced
 *    trajectory drifts from the full one.
 *
 *     embed [N] [STEPS] [ENERGY]   (an N x N cloth, 16, 400 steps, PCA energy 0.999)
 *
 * Only npg.h is included; the build links libnpg as any user's program. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"

typedef struct Cloth {
  long n, V, E;
  long *edge;               /* E x 2 */
  double *L0, *inc, *sgn;   /* inc as doubles: npg_full_set_param takes whole numbers */
  double *x, *v, *f;        /* V x 3 */
} Cloth;

/* An n x n grid of unit spacing 1/(n-1) hanging in the x–z plane, springs
 * along rows and columns. */
static int cloth_new(Cloth *c, long n) {
  memset(c, 0, sizeof *c);
  c->n = n;
  c->V = n * n;
  c->E = 2 * n * (n - 1);
  c->edge = malloc(sizeof(long) * (size_t)(2 * c->E));
  c->L0 = malloc(sizeof(double) * (size_t)c->E);
  c->inc = malloc(sizeof(double) * (size_t)(4 * c->V));
  c->sgn = calloc((size_t)(4 * c->V), sizeof(double));
  c->x = malloc(sizeof(double) * (size_t)(3 * c->V));
  c->v = calloc((size_t)(3 * c->V), sizeof(double));
  c->f = malloc(sizeof(double) * (size_t)(3 * c->V));
  if (!c->edge || !c->L0 || !c->inc || !c->sgn || !c->x || !c->v || !c->f) return -1;
  double h = 1.0 / (double)(n - 1);
  long e = 0;
  int *deg = calloc((size_t)c->V, sizeof(int));
  if (!deg) return -1;
  for (long i = 0; i < 4 * c->V; i++) c->inc[i] = -1;
  for (long r = 0; r < n; r++)
    for (long q = 0; q < n; q++) {
      long a = r * n + q;
      c->x[3 * a] = (double)q * h, c->x[3 * a + 1] = 0, c->x[3 * a + 2] = -(double)r * h;
      for (int dir = 0; dir < 2; dir++) {
        long b = dir == 0 ? (q + 1 < n ? a + 1 : -1) : (r + 1 < n ? a + n : -1);
        if (b < 0) continue;
        c->edge[2 * e] = a, c->edge[2 * e + 1] = b, c->L0[e] = h;
        c->inc[4 * a + deg[a]] = (double)e, c->sgn[4 * a + deg[a]++] = 1;
        c->inc[4 * b + deg[b]] = (double)e, c->sgn[4 * b + deg[b]++] = -1;
        e++;
      }
    }
  free(deg);
  return 0;
}

static void cloth_free(Cloth *c) {
  free(c->edge), free(c->L0), free(c->inc), free(c->sgn), free(c->x), free(c->v), free(c->f);
}

static int bind(NpgFull *f, const Cloth *c, double k) {
  double *edge = malloc(sizeof(double) * (size_t)(2 * c->E));
  if (!edge) return -1;
  for (long i = 0; i < 2 * c->E; i++) edge[i] = (double)c->edge[i];
  long es[2] = {c->E, 2}, ls[1] = {c->E}, vs[2] = {c->V, 4};
  int rc = npg_full_set_param(f, "edge", 2, es, edge, "edge") || npg_full_set_param(f, "L0", 1, ls, c->L0, "L0") ||
           npg_full_set_param(f, "inc", 2, vs, c->inc, "inc") || npg_full_set_param(f, "sgn", 2, vs, c->sgn, "sgn") ||
           npg_full_set_param(f, "k", 0, NULL, &k, "k");
  free(edge);
  return rc ? -1 : 0;
}

/* One semi-implicit Euler step under the spring forces c->f, gravity, a
 * wind along y and damping; the top row's two corners are pinned. */
static void step(Cloth *c, double wind, double t) {
  const double dt = 2e-3, mass = 1.0 / (double)c->V, damping = 0.02;
  for (long a = 0; a < c->V; a++) {
    if (a == 0 || a == c->n - 1) continue;
    double gust = wind * (1 + 0.5 * sin(3 * t + 0.2 * (double)a));
    double acc[3] = {c->f[3 * a] / mass, c->f[3 * a + 1] / mass + gust, c->f[3 * a + 2] / mass - 9.81};
    for (int d = 0; d < 3; d++) {
      c->v[3 * a + d] = (1 - damping) * c->v[3 * a + d] + dt * acc[d];
      c->x[3 * a + d] += dt * c->v[3 * a + d];
    }
  }
}

static int fail(const char *what, const char *msg) {
  fprintf(stderr, "embed: %s: %s\n", what, msg);
  return 1;
}

int main(int argc, char **argv) {
  long n = 16, steps = 400;
  double energy = 0.999;
  char err[256] = "more than three given";
  /* npg.h's strict numbers: "16x" or "1e3" are refused, not read as 16 or 1 */
  const char *bad = argc > 4 ? "arguments" : NULL;
  if (!bad && argc > 1 && npg_parse_long(argv[1], 3, 200, &n, err, sizeof err) != 0) bad = "N";
  if (!bad && argc > 2 && npg_parse_long(argv[2], 10, 100000, &steps, err, sizeof err) != 0) bad = "STEPS";
  if (!bad && argc > 3 && npg_parse_double(argv[3], 0, 1, true, &energy, err, sizeof err) != 0) bad = "ENERGY";
  if (bad) {
    fprintf(stderr, "embed: %s: %s\nusage: embed [N 3..200] [STEPS 10..100000] [ENERGY (0, 1]]\n", bad, err);
    return 2;
  }
  const double k = 200.0;
  NpgProgram *p = npg_compile("examples/embed/cloth.npg", NULL);
  if (!npg_ok(p)) return fail("compile", npg_error(p));
  NpgFull *f = npg_full_new(p, NPG_TCC);
  Cloth c;
  if (cloth_new(&c, n) != 0) return fail("cloth", "out of memory");
  if (npg_full_error(f)[0] || bind(f, &c, k) != 0) return fail("full evaluator", npg_full_error(f));
  long xs[2] = {c.V, 3};
  size_t nx = (size_t)(3 * c.V);

  /* 1. full simulations under three winds, streamed into the trainer */
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.energy = energy;
  NpgTrainer *t = npg_trainer_new(f, &o);
  const double winds[3] = {0, 4, 8};
  for (int w = 0; w < 3; w++) {
    Cloth run;
    if (cloth_new(&run, n) != 0) return fail("cloth", "out of memory");
    for (long s = 0; s < steps; s++) {
      if (npg_full_set(f, "x", 2, xs, run.x, "simulation") || npg_full_eval(f, s))
        return fail("full step", npg_full_error(f));
      memcpy(run.f, npg_full_get(f, "force", NULL), sizeof(double) * nx);
      if (s % 4 == 0 && npg_trainer_add_full(t, f) != 0) return fail("trainer", npg_trainer_error(t));
      step(&run, winds[w], 0.002 * (double)s);
    }
    cloth_free(&run);
  }
  NpgModel *m = npg_trainer_finish(t, NULL);
  if (!m) return fail("training", npg_trainer_error(t));
  printf("trained on %ld states of a %ld x %ld cloth (%ld springs):", npg_trainer_samples(t), n, n, c.E);
  for (int i = 0; i < npg_model_nclasses(m); i++) {
    NpgClassInfo ci;
    npg_model_class(m, i, &ci);
    printf(" %s %ld/%ld", ci.label, ci.m, ci.n);
  }
  printf("\n");
  npg_trainer_free(t);

  /* 2. a wind not trained on: full and reduced side by side */
  NpgReduced *r = npg_reduced_new(m);
  Cloth full, red;
  if (cloth_new(&full, n) || cloth_new(&red, n)) return fail("cloth", "out of memory");
  double worst = 0, worst_force = 0, largest_force = 0;
  for (long s = 0; s < steps; s++) {
    if (npg_full_set(f, "x", 2, xs, full.x, "full run") || npg_full_eval(f, s))
      return fail("full step", npg_full_error(f));
    memcpy(full.f, npg_full_get(f, "force", NULL), sizeof(double) * nx);
    if (npg_reduced_set(r, "x", nx, red.x) || npg_reduced_eval(r, s) || npg_reduced_lift(r, "force", red.f, nx))
      return fail("reduced step", npg_reduced_error(r));
    step(&full, 6.0, 0.002 * (double)s);
    step(&red, 6.0, 0.002 * (double)s);
    double d = 0, fd = 0, fn = 0;
    for (size_t i = 0; i < nx; i++) d = fmax(d, fabs(full.x[i] - red.x[i]));
    for (size_t i = 0; i < nx; i++) fd += (full.f[i] - red.f[i]) * (full.f[i] - red.f[i]), fn += full.f[i] * full.f[i];
    worst = fmax(worst, d);
    worst_force = fmax(worst_force, sqrt(fd)); /* relative to the largest force of the run, below */
    largest_force = fmax(largest_force, sqrt(fn));
    if ((s + 1) % (steps / 5) == 0)
      printf("step %5ld: largest vertex distance full vs reduced %.3e (cloth width 1)\n", s + 1, d);
  }
  printf("over %ld steps: largest vertex distance %.3e; largest force difference %.3e of the largest force\n", steps,
         worst, worst_force / fmax(largest_force, 1e-300));
  npg_reduced_free(r);
  npg_model_free(m);
  cloth_free(&full);
  cloth_free(&red);
  cloth_free(&c);
  npg_full_free(f);
  npg_free(p);
  return 0;
}
