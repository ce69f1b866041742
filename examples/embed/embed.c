/* embed.c — the smallest complete use of libnpg: a mass–spring cloth whose whole time step is
 * the program cloth.npg (examples/embed/README.md).
 *
 * 1. The full model: three rollouts under different winds, each run by npg's full step and
 *    streamed into a trainer as it happens (npg_trainer_add_trajectory: every 4th state, no
 *    files).
 * 2. The trainer builds the reduced model (bases, pre-multiplied tensors).
 * 3. A new wind: the full and the reduced rollouts from the same start, the reduced one in
 *    reduced coordinates (npg_reduced_simulate), its positions lifted only at the saved frames;
 *    the program prints how far the reduced trajectory drifts and how long each step took.
 *
 *     embed [N] [STEPS] [ENERGY] [CAP]   (an N x N cloth, 16; 400 steps; PCA energy 0.999; cap 60)
 *
 * Only npg.h is included; the build links libnpg as any user's program. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "npg.h"

typedef struct Cloth {
  long n, V, E;
  long *edge;               /* E x 2 */
  double *L0, *inc, *sgn;   /* inc as doubles: npg_full_set_param takes whole numbers */
  double *pin, *modes;      /* V; V x 3 */
  double *x, *v;            /* V x 3: the initial state */
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
  c->pin = malloc(sizeof(double) * (size_t)c->V);
  c->modes = malloc(sizeof(double) * (size_t)(3 * c->V));
  if (!c->edge || !c->L0 || !c->inc || !c->sgn || !c->x || !c->v || !c->pin || !c->modes) return -1;
  for (long a = 0; a < c->V; a++) { /* the two top corners pinned; the gust's modes 1, cos 0.2a, sin 0.2a */
    c->pin[a] = a == 0 || a == n - 1 ? 0 : 1;
    c->modes[3 * a] = 1, c->modes[3 * a + 1] = cos(0.2 * (double)a), c->modes[3 * a + 2] = sin(0.2 * (double)a);
  }
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
  free(c->edge), free(c->L0), free(c->inc), free(c->sgn), free(c->x), free(c->v), free(c->pin), free(c->modes);
}

/* The step's constants: dt shrinks with the spacing (the springs stiffen as 1/h), mass 1/V. */
static double step_dt(long n) { return 2e-3 * 16.0 / (double)n; }

static int bind(NpgFull *f, const Cloth *c, double k) {
  double *edge = malloc(sizeof(double) * (size_t)(2 * c->E));
  if (!edge) return -1;
  for (long i = 0; i < 2 * c->E; i++) edge[i] = (double)c->edge[i];
  long es[2] = {c->E, 2}, ls[1] = {c->E}, vs[2] = {c->V, 4};
  int rc = npg_full_set_param(f, "edge", 2, es, edge, "edge") || npg_full_set_param(f, "L0", 1, ls, c->L0, "L0") ||
           npg_full_set_param(f, "inc", 2, vs, c->inc, "inc") || npg_full_set_param(f, "sgn", 2, vs, c->sgn, "sgn") ||
           npg_full_set_param(f, "k", 0, NULL, &k, "k");
  double dt = step_dt(c->n), mass = 1.0 / (double)c->V, damping = 0.02;
  long ms[2] = {c->V, 3}, ps[1] = {c->V};
  rc = rc || npg_full_set_param(f, "pin", 1, ps, c->pin, "pin") || npg_full_set_param(f, "modes", 2, ms, c->modes, "modes") ||
       npg_full_set_param(f, "dt", 0, NULL, &dt, "dt") || npg_full_set_param(f, "mass", 0, NULL, &mass, "mass") ||
       npg_full_set_param(f, "damping", 0, NULL, &damping, "damping");
  free(edge);
  return rc ? -1 : 0;
}

/* The wind's mode weights at step s: wind · (1 + 0.5 sin(3t + 0.2a)) along y, t = s dt. */
static void gust(double wind, long s, long n, double w[3]) {
  double t = step_dt(n) * (double)s;
  w[0] = wind, w[1] = 0.5 * wind * sin(3 * t), w[2] = 0.5 * wind * cos(3 * t);
}

typedef struct Run {
  NpgFull *f;
  NpgReduced *r;
  double wind;
  long n;
  size_t nx;
  double *frames;           /* saved positions, full run: (frames) x nx */
  double *lifted;           /* scratch: one lifted frame */
  long every;
  double worst;             /* the reduced run: the largest vertex distance at a saved frame */
} Run;

static int set_wind(void *user, long s) {
  Run *u = user;
  double w[3];
  gust(u->wind, s, u->n, w);
  long three = 3;
  return u->r ? npg_reduced_set(u->r, "wind", 3, w) : npg_full_set(u->f, "wind", 1, &three, w, "wind");
}

static int save_full(void *user, long s) {
  Run *u = user;
  memcpy(u->frames + (size_t)(s / u->every) * u->nx, npg_full_get(u->f, "x", NULL), sizeof(double) * u->nx);
  return 0;
}

static int compare_reduced(void *user, long s) {
  Run *u = user;
  if (npg_reduced_lift(u->r, "x", u->lifted, u->nx) != 0) return -1;
  const double *full = u->frames + (size_t)(s / u->every) * u->nx;
  double d = 0;
  for (size_t i = 0; i < u->nx; i++) d = fmax(d, fabs(full[i] - u->lifted[i]));
  u->worst = fmax(u->worst, d);
  if (s > 0) printf("step %5ld: largest vertex distance full vs reduced %.3e (cloth width 1)\n", s, d);
  return 0;
}

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int fail(const char *what, const char *msg) {
  fprintf(stderr, "embed: %s: %s\n", what, msg);
  return 1;
}

int main(int argc, char **argv) {
  long n = 16, steps = 400, cap = 60;
  double energy = 0.999;
  char err[256] = "more than four given";
  /* npg.h's strict numbers: "16x" or "1e3" are refused, not read as 16 or 1 */
  const char *bad = argc > 5 ? "arguments" : NULL;
  if (!bad && argc > 1 && npg_parse_long(argv[1], 3, 200, &n, err, sizeof err) != 0) bad = "N";
  if (!bad && argc > 2 && npg_parse_long(argv[2], 10, 100000, &steps, err, sizeof err) != 0) bad = "STEPS";
  if (!bad && argc > 3 && npg_parse_double(argv[3], 0, 1, true, &energy, err, sizeof err) != 0) bad = "ENERGY";
  if (!bad && argc > 4 && npg_parse_long(argv[4], 1, 100000, &cap, err, sizeof err) != 0) bad = "CAP";
  if (bad) {
    fprintf(stderr, "embed: %s: %s\nusage: embed [N 3..200] [STEPS 10..100000] [ENERGY (0, 1]] [CAP 1..100000]\n", bad,
            err);
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
  long every = steps / 5;
  Run run = {.f = f, .n = n, .nx = nx, .every = every};
  run.frames = malloc(sizeof(double) * nx * (size_t)(steps / every + 1));
  run.lifted = malloc(sizeof(double) * nx);
  if (!run.frames || !run.lifted) return fail("cloth", "out of memory");

  /* 1. full rollouts under three winds, every 4th state streamed into the trainer */
  NpgTrainOptions o;
  npg_train_options_default(&o);
  o.energy = energy;
  o.cap = (int)cap;
  NpgTrainer *t = npg_trainer_new(f, &o);
  const double winds[3] = {0, 4, 8};
  NpgRollout train = {.steps = steps, .every = 4, .before_step = set_wind, .user = &run};
  for (int w = 0; w < 3; w++) {
    run.wind = winds[w];
    if (npg_full_set(f, "x", 2, xs, c.x, "rest") || npg_full_set(f, "v", 2, xs, c.v, "rest") ||
        npg_trainer_add_trajectory(t, f, w, &train) != 0)
      return fail("training run", npg_trainer_error(t)[0] ? npg_trainer_error(t) : npg_full_error(f));
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

  /* 2. a wind not trained on: the full rollout, then the reduced one in coordinates */
  run.wind = 6.0;
  NpgRollout full = {.steps = steps, .every = every, .before_step = set_wind, .at_save = save_full, .user = &run};
  if (npg_full_set(f, "x", 2, xs, c.x, "rest") || npg_full_set(f, "v", 2, xs, c.v, "rest")) return fail("full run", npg_full_error(f));
  double t0 = now();
  if (npg_full_simulate(f, 0, &full) != 0) return fail("full run", npg_full_error(f));
  double t1 = now();
  run.r = npg_reduced_new(m);
  NpgRollout reduced = {.steps = steps, .every = every, .before_step = set_wind, .at_save = compare_reduced, .user = &run};
  if (npg_reduced_set(run.r, "x", nx, c.x) || npg_reduced_set(run.r, "v", nx, c.v)) return fail("reduced run", npg_reduced_error(run.r));
  double t2 = now();
  if (npg_reduced_simulate(run.r, 0, &reduced) != 0) return fail("reduced run", npg_reduced_error(run.r));
  double t3 = now();
  printf("over %ld steps: largest vertex distance %.3e at the saved frames; per step: full %.3e s, reduced %.3e s "
         "(in coordinates, 6 frames lifted)\n", steps, run.worst, (t1 - t0) / (double)steps, (t3 - t2) / (double)steps);
  npg_reduced_free(run.r);
  npg_model_free(m);
  free(run.frames);
  free(run.lifted);
  cloth_free(&c);
  npg_full_free(f);
  npg_free(p);
  return 0;
}
