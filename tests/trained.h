/* trained.h — the fixtures of the tests of the reduced model and its
 * training (test_reduced_model.c, test_premul.c, test_train.c, test_tune.c,
 * test_ooc.c, test_emit_reduced.c): a program trained on random samples in
 * memory, the radiosity room's samples, a model's mean output error.
 * Include after testutil.h. */
#ifndef NPG_TRAINED_H
#define NPG_TRAINED_H

#include "emit.h"
#include "memsamples.h"
#include "meshgen.h"
#include "randdata.h"
#include "reduced.h"
#include "train.h"

typedef struct Trained {
  NpgProgram *p;
  Program *prog;
  Full *f;
  MemSamples train;
  Model *m;
} Trained;

/* `path` (or `text` named `path`) trained on S random samples, every dim
 * of size n, caps of `cap` at energy 1: truncated, non-trivial bases. */
static inline void train(Trained *tr, const char *path, const char *text, long n, long S, int cap) {
  memset(tr, 0, sizeof *tr);
  tr->p = text ? compile_text(path, text) : compile_file(path);
  tr->prog = ir_ok(tr->p);
  tr->f = full_new(program_ir(tr->p), JIT_TCC, NULL);
  if (memsamples_fill(&tr->train, tr->prog, tr->f, n, S, 5u)) fail_msg("binding random params failed");
  SampleSource src = {S, &tr->train, memsamples_set, NULL, NULL};
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = cap;
  opt_user.energy = 1.0;
  char err[2048] = "";
  tr->m = train_model(tr->prog, tr->f, &src, &opt, ERR_OF(err, sizeof err));
  if (!tr->m) fail_msg("%s: training: %s", path, err);
}

static inline void trained_free(Trained *tr) {
  model_free(tr->m);
  memsamples_free(&tr->train);
  full_free(tr->f);
  npg_free(tr->p);
}

/* `path` trained on 12 random samples, every dim of size n, caps `cap`. */
static inline void train_small(Trained *tr, const char *path, int cap, long n) { train(tr, path, NULL, n, 12, cap); }

/* The radiosity program on the deforming room of bench/meshgen (F faces,
 * convex: visibility 1): samples at deformations t. */
typedef struct RoomSamples {
  long F, V;
  long S;
  double *g;     /* S x V x 3 */
  double *e;     /* S x F */
  double *v;     /* F x F ones */
} RoomSamples;

static inline void room_samples(RoomSamples *rs, Full *f, long F, long S, double t0, double dt) {
  memset(rs, 0, sizeof *rs);
  Mesh mesh;
  char err[256];
  if (mesh_room(F, 0.0, &mesh, err, sizeof err)) fail_msg("%s", err);
  rs->F = F;
  rs->V = mesh.V;
  rs->S = S;
  double *tri = malloc(sizeof(double) * (size_t)(3 * F)), *rho = malloc(sizeof(double) * (size_t)F);
  for (long i = 0; i < 3 * F; i++) tri[i] = mesh.tri[i];
  mesh_rho(&mesh, rho);
  long ts[2] = {F, 3}, fs[1] = {F};
  if (f && (full_set_param(f, "tri", 2, ts, tri, "tri") || full_set_param(f, "rho", 1, fs, rho, "rho")))
    fail_msg("%s", full_error(f));
  free(tri);
  free(rho);
  rs->g = malloc(sizeof(double) * (size_t)(S * rs->V * 3));
  rs->e = malloc(sizeof(double) * (size_t)(S * F));
  rs->v = malloc(sizeof(double) * (size_t)(F * F));
  for (long i = 0; i < F * F; i++) rs->v[i] = 1;
  for (long k = 0; k < S; k++) {
    Mesh mk;
    if (mesh_room(F, t0 + dt * (double)k, &mk, err, sizeof err)) fail_msg("%s", err);
    memcpy(rs->g + k * rs->V * 3, mk.g, sizeof(double) * (size_t)(rs->V * 3));
    mesh_emission(&mk, rs->e + k * F);
    unsigned seed = 17u + (unsigned)(1000.0 * (t0 + dt * (double)k));
    for (long i = 0; i < F; i++) rs->e[k * F + i] += randdata_uniform(&seed, 0.0, 0.3); /* light on every wall */
    mesh_free(&mk);
  }
  mesh_free(&mesh);
}

static inline int room_set(void *user, Full *f, long k) {
  RoomSamples *rs = user;
  long gs[2] = {rs->V, 3}, es[1] = {rs->F}, vs[2] = {rs->F, rs->F};
  return full_set(f, "g", 2, gs, rs->g + k * rs->V * 3, "g") || full_set(f, "e", 1, es, rs->e + k * rs->F, "e") ||
         full_set(f, "v", 2, vs, rs->v, "v");
}

static inline void room_free(RoomSamples *rs) {
  free(rs->g);
  free(rs->e);
  free(rs->v);
}

/* The radiosity program on the room of F faces: S training samples over deformations
 * t in [0, 1], T test samples half a step off them (every (S / T)-th step), and the
 * training samples as a sample source. */
typedef struct Room {
  NpgProgram *p;
  Program *prog;
  Full *f;
  RoomSamples train, test;
  SampleSource src;
} Room;

static inline void room_open(Room *r, long F, long S, long T) {
  r->p = compile_file("examples/radiosity/formfactors.npg");
  r->prog = ir_ok(r->p);
  r->f = full_new(program_ir(r->p), JIT_TCC, NULL);
  double step = 1.0 / (double)(S - 1);
  room_samples(&r->train, r->f, F, S, 0.0, step);
  room_samples(&r->test, NULL, F, T, 0.5 * step, (double)(S / T) * step);
  r->src = (SampleSource){r->train.S, &r->train, room_set, NULL, NULL};
}

static inline void room_close(Room *r) {
  room_free(&r->train);
  room_free(&r->test);
  full_free(r->f);
  npg_free(r->p);
}

/* Mean over the test samples of ‖y − B ŷ‖ / ‖y‖ of output `out`. */
static inline double mean_error(Program *prog, Full *f, Model *m, void *test, int (*set)(void *, Full *, long),
                                long S, const char *out) {
  char err[1024];
  Reduced *r = reduced_new(m, ERR_OF(err, sizeof err));
  assert_non_null(r);
  int qo = vec_position(&prog->quantities, find_quantity(prog, out));
  double total = 0;
  for (long k = 0; k < S; k++) {
    if (set(test, f, k) || full_eval(f, k)) fail_msg("%s", full_error(f));
    for (int q = 0; q < m->nq; q++) {
      const Sym *s = prog->quantities.v[q];
      if (s->kind == SYM_INPUT) reduced_project(r, q, full_get(f, s->name, NULL));
    }
    if (reduced_eval(r, k)) fail_msg("%s", reduced_error(r));
    size_t n;
    const double *y = full_get(f, out, &n);
    double *yl = malloc(sizeof(double) * n), num = 0, den = 0;
    reduced_lift(r, qo, yl);
    for (size_t i = 0; i < n; i++) num += (y[i] - yl[i]) * (y[i] - yl[i]), den += y[i] * y[i];
    total += sqrt(num / den);
    free(yl);
  }
  reduced_free(r);
  return total / (double)S;
}

/* A model trained with `cap`, `energy`, centered or not, within `mem`
 * bytes of snapshots (0: no limit); the test fails if training does. */
static inline Model *train_with(Program *prog, Full *f, const SampleSource *src, int cap, double energy,
                                bool uncentered, size_t mem) {
  NpgTrainOptions opt_user = {0};
  TrainOptions opt = {.user = &opt_user};
  opt_user.cap = cap;
  opt_user.energy = energy;
  opt_user.uncentered = uncentered;
  opt_user.mem = mem;
  /* `energy` for every member, those under a power too (DESIGN §12: whole by default), as --basis '*':energy=E */
  const char *every[1] = {"*"};
  int nocap[1] = {0};
  double energies[1] = {energy};
  opt_user.nbasis = 1;
  opt_user.basis_name = every;
  opt_user.basis_cap = nocap;
  opt_user.basis_energy = energies;
  char err[2048] = "";
  Model *m = train_model(prog, f, src, &opt, ERR_OF(err, sizeof err));
  if (!m) fail_msg("training: %s", err);
  return m;
}

#endif
