/* main.c — build/npg-fluids: the fluid solver of paper §5 and its reduced twin through
 * npg.h, on the deforming periodic wind tunnel (§7.1, Fig. 5) and the deforming 3D cavity
 * (§7.2, Fig. 6, Table 1). One option table for every command; each command is a file:
 *
 *   tunnel-full   the full-space solver alone, frames, VTK, snapshots (tunnelfull.c)
 *   tunnel        Fig. 5: training, one model per basis size, full and reduced test runs (tunnel.c)
 *   cavity        Fig. 6, Table 1: training runs, the model, full and reduced test runs (cavitysim.c)
 *   mesh, cavity-mesh, cavity-projection   one part looked at alone, JSON (inspect.c)
 */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cblas.h>

#include "cavitysim.h"
#include "inspect.h"
#include "npg.h"
#include "particles.h"
#include "tunnel.h"
#include "tunnelfull.h"
#include "util.h"

/* Bounds of the sizes a command line can ask for, so that a typo (--frames
 * 1e8) is refused before it asks for terabytes: 100,000 frames of the
 * default tunnel keep 5.3 GB of samples; a million cells is 500x the
 * default mesh; a PNG 8192 pixels wide holds 200 MB. */
#define FLUIDS_MAX_FRAMES 100000
#define FLUIDS_MAX_CELLS 1000000
#define FLUIDS_MAX_PARTICLES 10000000
#define FLUIDS_MAX_WIDTH 8192

static void usage(FILE *fp) {
  fputs("usage: npg-fluids tunnel-full --out DIR [--frames N] [--cells N] [--size S]\n"
        "                  [--scale X] [--pulse A] [--period P] [--mu MU] [--cfl C] [--u0 U]\n"
        "                  [--particles N] [--png-every K] [--vtk-every K] [--width PX]\n"
        "                  [--projection stream|kkt] [--dump-step DIR]\n"
        "       npg-fluids tunnel --out DIR [--frames N] [--cells N] [--sizes 8,16,32,64,128]\n"
        "                  [--pulse A] [--period P] [--mu MU] [--cfl C] [--mg N] [--particles N]\n"
        "                  [--png-every K] [--vtk-every K] [--width PX] [--keep-models 0|1]\n"
        "       npg-fluids mesh [--cells N] [--size S]\n"
        "       npg-fluids cavity --out DIR [--cells N] [--frames N] [--runs N] [--dt DT] [--nu NU]\n"
        "                  [--mf N] [--mu N] [--mg N] [--dtol X] [--particles N] [--png-every K] [--vtk-every K]\n"
        "                  [--width PX] [--projection al|kkt] [--workers W] [--train-threads N]\n"
        "                  [--sample-every K] [--buffer-mb N] [--backend cc|tcc] [--particle-threads N]\n"
        "                  [--single-advection 0|1]\n"
        "       npg-fluids cavity-mesh [--cells N]         the cavity's mesh statistics as JSON\n"
        "       npg-fluids cavity-projection [--cells N] [--steps N] [--method kkt|al|both]\n"
        "                  the full projection timed on the cavity (JSON)\n"
        "\n"
        "tunnel-full: full-space simulation of the periodic wind tunnel (paper §5, §7.1).\n"
        "  --frames N     steps, one per frame (200)\n"
        "  --cells N      target triangle count of the gmsh mesh (2000)\n"
        "  --size S       obstacle side length at rest, tunnel height 1 (0.3)\n"
        "  --scale X      mean obstacle scale, by deforming the --size mesh (1)\n"
        "  --pulse A      obstacle scale X + A sin(2 pi t / P): 0 keeps it fixed (0.2)\n"
        "  --period P     frames per pulse (100)\n"
        "  --mu MU        viscosity of the graph Laplacian (0.002)\n"
        "  --cfl C        dt = C * mean edge length / u0 (0.25)\n"
        "  --u0 U         initial uniform velocity along the tunnel, projected (1)\n"
        "  --particles N  marker particles, ten Euler substeps per frame (3000)\n"
        "  --png-every K, --vtk-every K   output every K frames (1, 10)\n"
        "  --projection M stream: CHOLMOD on the stream function (default); kkt: UMFPACK on\n"
        "                 the KKT system (the same minimizer)\n"
        "  --dump-step DIR  the step's operators (positions per step when the obstacle pulses),\n"
        "                 frame 0 and the run's frames as .npy for examples/fluids/tunnel_step.npg\n"
        "                 (--pulse 0) or tunnel_step_moving.npg (npgc simulate)\n"
        "\n"
        "tunnel: paper Fig. 5. Full training runs with a large and a small obstacle (scales\n"
        "  1.25 and 0.75, each pulsing by A, default 0.05) streamed into npg trainers, one\n"
        "  model per basis size (--sizes: m_u; m_f = m_u / 2; --mg: cap of m_g, 5), a full\n"
        "  test run with a medium obstacle (1.0) and per frame the one-step error of every\n"
        "  model, the reduced test run of the largest model with particles; DIR/report.json,\n"
        "  DIR/plots/*.png, DIR/frames/frame_NNNN.png (full | reduced), DIR/vtk/*.vtu, *.pvd.\n"
        "  --frames N per run (300), --png-every and --vtk-every (25), --width (640)\n"
        "\n"
        "cavity: paper §7.2, Fig. 6, Table 1. The 3D cavity (a central chamber and three side\n"
        "  chambers joined by thin tunnels) tetrahedralized by gmsh (--cells, 20000); --runs full\n"
        "  training runs (14) of --frames frames each (by default 100 (cells/1000)^(1/3), at least\n"
        "  100: 260 at the default 17,300 cells) compressing and re-inflating one or\n"
        "  two side chambers, streamed into npg's trainer (caps --mf 64, --mu 128, --mg 5); the\n"
        "  test sequence (chamber 1 expanding while chamber 0 stays compressed) full and reduced,\n"
        "  --particles (10000) marker particles through the reduced flow; --dt (0.01), viscosity\n"
        "  mu = --nu (5) times the smallest cell's volume; --dtol (1e-2) the rank tolerance of the\n"
        "  reduced boundary constraints; DIR/report.json (Table 1), DIR/frames/*.png,\n"
        "  DIR/vtk/*.vtk (legacy VTK), DIR/plots/trajectory_error.png. --projection: al (default),\n"
        "  CHOLMOD on K + w D^T D with augmented Lagrangian iterations; kkt: UMFPACK on the KKT\n"
        "  system (the same minimizer). --workers W: threads running the training runs (the\n"
        "  online CPUs; 1: one run after the other); the trainer gets the same samples in the\n"
        "  same order for every W. --train-threads N: OpenBLAS's threads while training (W).\n"
        "  --sample-every K: every K-th frame of a training run is a sample (by default at most\n"
        "  120 samples per run: 1 up to 120 frames, 3 at 260, 4 at 450; the runs still take\n"
        "  every step). --buffer-mb N: bound on the samples of later runs waiting while the\n"
        "  trainer takes an earlier run's (2048). --backend: the trainer's full evaluator, compiled\n"
        "  by the system compiler (cc, default: its replays ran 2-3x faster here) or by libtcc (tcc).\n"
        "  --particle-threads N: threads advecting the particles (the online CPUs); the reduced\n"
        "  flow's particles also run on one thread, timed apart (t_pa_one_thread), and must move\n"
        "  the same bit for bit; they lift only the faces of the cells they reach (paper 6.5).\n"
        "  --single-advection 1: the reduced step keeps its advection tensor's skew parts in single\n"
        "  precision (half their bytes; the errors in report.json say what it costs; default 0).\n",
        fp);
}

/* ---------------------------------------------------------------- the option table */

/* The commands, as bits: an option row lists the commands that take it. */
enum {
  TUNNEL_FULL = 1,       /* tunnel-full */
  MESH = 2,              /* mesh: takes tunnel-full's options, reads its --cells and --size */
  TUNNEL = 4,            /* tunnel */
  CAVITY = 8,            /* cavity */
  CAVITY_MESH = 16,      /* cavity-mesh */
  CAVITY_PROJECTION = 32 /* cavity-projection */
};

static const struct {
  const char *name;
  int bit;
} commands[] = {{"tunnel-full", TUNNEL_FULL}, {"mesh", MESH},
                {"tunnel", TUNNEL},           {"cavity", CAVITY},
                {"cavity-mesh", CAVITY_MESH}, {"cavity-projection", CAVITY_PROJECTION}};

/* What every command's options are parsed into; each command reads its own part. */
typedef struct Cmdline {
  TunnelFullOptions full;   /* tunnel-full, mesh */
  TunnelOptions tunnel;
  CavityOptions cavity;
  int buffer_mb;            /* cavity --buffer-mb, -1 when not given */
  CavitySpec cavity_spec;   /* cavity-mesh, cavity-projection */
  int steps, method;        /* cavity-projection: steps; 1 kkt, 2 al, 3 both */
} Cmdline;

typedef enum OptionKind {
  OPT_INT,    /* an int in [lo, hi] */
  OPT_DOUBLE, /* a double in [lo, hi] ((lo, hi] with lo_open) */
  OPT_STRING, /* any text */
  OPT_CHOICE, /* one of `names`, stored as the matching int of `values` */
  OPT_SIZES,  /* tunnel --sizes: an increasing list of m_u */
} OptionKind;

typedef struct Option Option;
struct Option {
  const char *name;
  int commands;           /* the bits of the commands that take it */
  OptionKind kind;
  double lo, hi;
  bool lo_open;
  size_t at;              /* offsetof(Cmdline, the field) */
  const char *const *names;
  const int *values;
  /* a further check of the value read, writing its message into a->error */
  void (*check)(NpgArgs *a, const void *field);
};

/* The physical parameters every command shares, refused with the reason when
 * a run with them could only blow up or mean nothing: a negative viscosity
 * amplifies every mode (anti-diffusion); a CFL number above 1 moves the flow
 * more than an edge per step, beyond what the explicit RK4 advection step
 * can follow (measured on the default tunnel: 0.45 ran 200 frames, 0.5 was
 * not finite by frame 7). Smaller values can still be unstable (explicit
 * diffusion limits the step too): the runs stop when the energy blows up
 * (solver_check_energy). */
static void check_viscosity(NpgArgs *a, const void *field) {
  double mu = *(const double *)field;
  if (!(mu >= 0 && mu <= 10))
    snprintf(a->error, sizeof a->error, "%s: --mu %g: the viscosity is in [0, 10]%s", a->prog, mu,
             mu < 0 ? " (a negative one amplifies every mode of the flow: anti-diffusion, the run blows up)" : "");
}

static void check_cfl(NpgArgs *a, const void *field) {
  double cfl = *(const double *)field;
  if (!(cfl > 0 && cfl <= 1))
    snprintf(a->error, sizeof a->error, "%s: --cfl %g: the CFL number is in (0, 1]%s", a->prog, cfl,
             cfl > 1 ? " (above 1 the flow crosses more than an edge per step, which the explicit RK4 advection "
                       "cannot follow: the run blows up)" : "");
}

/* The rank tolerance of D̂ is relative to its largest singular value: 1 would drop every
 * constraint. */
static void check_dtol(NpgArgs *a, const void *field) {
  if (*(const double *)field >= 1) snprintf(a->error, sizeof a->error, "%s: --dtol is in [0, 1)", a->prog);
}

#define AT(field) offsetof(Cmdline, field)
#define CHOICES(...) .names = (const char *const[]){__VA_ARGS__, NULL}
#define VALUES(...) .values = (const int[]){__VA_ARGS__}
#define INT(opt, cmds, lo_, hi_, field) {.name = opt, .commands = cmds, .kind = OPT_INT, .lo = lo_, .hi = hi_, .at = AT(field)}
#define DBL(opt, cmds, lo_, hi_, open, field) DBL_CHECK(opt, cmds, lo_, hi_, open, field, NULL)
#define DBL_CHECK(opt, cmds, lo_, hi_, open, field, fn)                                                        \
  {.name = opt, .commands = cmds, .kind = OPT_DOUBLE, .lo = lo_, .hi = hi_, .lo_open = open, .at = AT(field), \
   .check = fn}
#define STR(opt, cmds, field) {.name = opt, .commands = cmds, .kind = OPT_STRING, .at = AT(field)}
/* the range is check_viscosity's or check_cfl's */
#define PHYS(opt, cmds, field, fn) DBL_CHECK(opt, cmds, -INFINITY, INFINITY, false, field, fn)
enum { TF = TUNNEL_FULL | MESH, CP = CAVITY_PROJECTION, CM = CAVITY_MESH };

static const Option options[] = {
    /* tunnel-full (and mesh, which takes the same options) */
    STR("--out", TF, full.out),
    STR("--dump-step", TUNNEL_FULL, full.dump_step),
    INT("--frames", TF, 1, FLUIDS_MAX_FRAMES, full.frames),
    INT("--cells", TF, 50, FLUIDS_MAX_CELLS, full.spec.cells),
    INT("--particles", TF, 0, FLUIDS_MAX_PARTICLES, full.particles),
    INT("--png-every", TF, 1, 1000000, full.png_every),
    INT("--vtk-every", TF, 1, 1000000, full.vtk_every),
    INT("--width", TF, 16, FLUIDS_MAX_WIDTH, full.png_width),
    DBL("--size", TF, 0, 0.9, true, full.spec.size),
    DBL("--scale", TF, 0, 10, true, full.scale),
    DBL("--pulse", TF, 0, 10, false, full.pulse),
    DBL("--period", TF, 0, 1e9, true, full.period),
    PHYS("--mu", TF, full.mu, check_viscosity),
    PHYS("--cfl", TF, full.cfl, check_cfl),
    DBL("--u0", TF, 0, 100, true, full.u0),
    {.name = "--projection", .commands = TF, .kind = OPT_CHOICE, .at = AT(full.projection), CHOICES("stream", "kkt"),
     VALUES(PROJ_STREAM_CHOLMOD, PROJ_KKT_UMFPACK)},
    /* tunnel */
    STR("--out", TUNNEL, tunnel.out),
    INT("--frames", TUNNEL, 2, FLUIDS_MAX_FRAMES, tunnel.frames),
    INT("--cells", TUNNEL, 50, FLUIDS_MAX_CELLS, tunnel.spec.cells),
    INT("--particles", TUNNEL, 0, FLUIDS_MAX_PARTICLES, tunnel.particles),
    INT("--png-every", TUNNEL, 1, 1000000, tunnel.png_every),
    INT("--vtk-every", TUNNEL, 1, 1000000, tunnel.vtk_every),
    INT("--width", TUNNEL, 16, FLUIDS_MAX_WIDTH, tunnel.width),
    INT("--mg", TUNNEL, 1, 512, tunnel.mg_cap),
    INT("--keep-models", TUNNEL, 0, 1, tunnel.keep_models),
    DBL("--pulse", TUNNEL, 0, 0.7, false, tunnel.pulse),
    DBL("--period", TUNNEL, 0, 1e9, true, tunnel.period),
    PHYS("--mu", TUNNEL, tunnel.mu, check_viscosity),
    PHYS("--cfl", TUNNEL, tunnel.cfl, check_cfl),
    {.name = "--sizes", .commands = TUNNEL, .kind = OPT_SIZES, .at = AT(tunnel)},
    /* cavity */
    STR("--out", CAVITY, cavity.out),
    DBL_CHECK("--dtol", CAVITY, 0, 1, false, cavity.dtol, check_dtol),
    INT("--cells", CAVITY, 50, FLUIDS_MAX_CELLS, cavity.spec.cells),
    INT("--frames", CAVITY, 2, FLUIDS_MAX_FRAMES, cavity.frames),
    INT("--runs", CAVITY, 0, 14, cavity.runs),
    DBL("--dt", CAVITY, 0, 10, true, cavity.dt),
    DBL("--nu", CAVITY, 0, 1e6, false, cavity.nu),
    INT("--mf", CAVITY, 2, 512, cavity.mf),
    INT("--mu", CAVITY, 6, 512, cavity.mu),
    INT("--mg", CAVITY, 1, 16, cavity.mg),
    INT("--particles", CAVITY, 0, FLUIDS_MAX_PARTICLES, cavity.particles),
    INT("--png-every", CAVITY, 1, 1000000, cavity.png_every),
    INT("--vtk-every", CAVITY, 1, 1000000, cavity.vtk_every),
    INT("--width", CAVITY, 16, FLUIDS_MAX_WIDTH, cavity.width),
    INT("--workers", CAVITY, 1, CAVITY_MAX_WORKERS, cavity.workers),
    INT("--particle-threads", CAVITY, 1, PARTICLES_MAX_THREADS, cavity.particle_threads),
    INT("--train-threads", CAVITY, 1, CAVITY_MAX_WORKERS, cavity.train_threads),
    INT("--sample-every", CAVITY, 0, FLUIDS_MAX_FRAMES, cavity.sample_every),
    INT("--single-advection", CAVITY, 0, 1, cavity.single_advection),
    INT("--buffer-mb", CAVITY, 0, 1 << 20, buffer_mb),
    {.name = "--backend", .commands = CAVITY, .kind = OPT_CHOICE, .at = AT(cavity.backend), CHOICES("cc", "tcc"), VALUES(NPG_CC, NPG_TCC)},
    {.name = "--projection", .commands = CAVITY, .kind = OPT_CHOICE, .at = AT(cavity.projection), CHOICES("al", "kkt"),
     VALUES(PROJ_AL_CHOLMOD, PROJ_KKT_UMFPACK)},
    /* cavity-mesh, cavity-projection */
    INT("--cells", CM | CP, 50, FLUIDS_MAX_CELLS, cavity_spec.cells),
    INT("--steps", CP, 1, 100000, steps),
    {.name = "--method", .commands = CP, .kind = OPT_CHOICE, .at = AT(method), CHOICES("kkt", "al", "both"), VALUES(1, 2, 3)},
};

/* tunnel --sizes 8,16,32: at most 16 increasing basis sizes in [2, 256]. */
static void parse_sizes(NpgArgs *a, const char *v, TunnelOptions *o) {
  o->nsizes = 0;
  char buf[256], err[256];
  snprintf(buf, sizeof buf, "%s", v);
  /* Split by hand: strtok would drop an empty entry ("8," or "8,,16") without a word. */
  for (char *tok = buf, *next = NULL; buf[0] && tok && !a->error[0]; tok = next) {
    long n;
    if ((next = strchr(tok, ','))) *next++ = '\0';
    if (!tok[0])
      snprintf(a->error, sizeof a->error, "%s: --sizes: entry %d is empty in '%s'", a->prog, o->nsizes + 1, v);
    else if (o->nsizes >= 16)
      snprintf(a->error, sizeof a->error, "%s: --sizes: at most 16 sizes", a->prog);
    else if (npg_parse_long(tok, 2, 256, &n, err, sizeof err) != 0)
      snprintf(a->error, sizeof a->error, "%s: --sizes: entry %d: %s", a->prog, o->nsizes + 1, err);
    else if (o->nsizes && n <= o->mu_sizes[o->nsizes - 1])
      snprintf(a->error, sizeof a->error, "%s: --sizes: %ld after %d: the sizes increase", a->prog, n,
               o->mu_sizes[o->nsizes - 1]);
    else
      o->mu_sizes[o->nsizes++] = (int)n;
  }
  if (!o->nsizes && !a->error[0]) snprintf(a->error, sizeof a->error, "%s: --sizes: an empty list", a->prog);
}

/* "PROG: --opt is a, b or c, not 'v'". */
static void choice(NpgArgs *a, const Option *opt, const char *v, int *field) {
  int n = 0;
  while (opt->names[n]) n++;
  for (int i = 0; i < n; i++)
    if (!strcmp(v, opt->names[i])) {
      *field = opt->values[i];
      return;
    }
  char list[128] = "";
  for (int i = 0; i < n; i++)
    snprintf(list + strlen(list), sizeof list - strlen(list), "%s%s", i == 0 ? "" : i == n - 1 ? " or " : ", ",
             opt->names[i]);
  snprintf(a->error, sizeof a->error, "%s: %s is %s, not '%s'", a->prog, opt->name, list, v);
}

/* The current argument read by row `opt` into `c`: false when it is not that option. */
static bool match(NpgArgs *a, const Option *opt, Cmdline *c) {
  void *field = (char *)c + opt->at;
  const char *v;
  switch (opt->kind) {
  case OPT_INT:
    if (!npg_args_int(a, opt->name, (int)opt->lo, (int)opt->hi, field)) return false;
    break;
  case OPT_DOUBLE:
    if (!npg_args_double(a, opt->name, opt->lo, opt->hi, opt->lo_open, field)) return false;
    break;
  case OPT_STRING:
    if (!(v = npg_args_string(a, opt->name))) return false;
    *(const char **)field = v;
    break;
  case OPT_CHOICE:
    if (!(v = npg_args_string(a, opt->name))) return false;
    choice(a, opt, v, field);
    break;
  case OPT_SIZES:
    if (!(v = npg_args_string(a, opt->name))) return false;
    parse_sizes(a, v, field);
    break;
  }
  if (!a->error[0] && opt->check) opt->check(a, field);
  return true;
}

/* argv[2..] of command `cmd` into `c`, each command's defaults first. 0, or 2 after
 * printing the first problem. */
static int parse(int argc, char **argv, int cmd, Cmdline *c) {
  tunnel_full_options_default(&c->full);
  tunnel_options_default(&c->tunnel);
  cavity_options_default(&c->cavity);
  c->buffer_mb = -1;
  c->cavity_spec = cavity_spec_default();
  c->steps = 3, c->method = 3;
  char prog[48];
  snprintf(prog, sizeof prog, "npg-fluids %s", argv[1]);
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, prog);
  while (npg_args_next(&a)) {
    bool matched = false;
    for (size_t i = 0; i < sizeof options / sizeof *options && !matched && !a.error[0]; i++)
      if (options[i].commands & cmd) matched = match(&a, &options[i], c);
    if (!matched && !a.error[0]) npg_args_unknown(&a);
  }
  const TunnelFullOptions *f = &c->full;
  if (!a.error[0] && (cmd & TF) && f->pulse >= f->scale)
    snprintf(a.error, sizeof a.error, "%s: --pulse %g must stay below --scale %g (the obstacle's scale X + A sin(...) "
             "would reach 0)", prog, f->pulse, f->scale);
  if (a.error[0]) {
    fprintf(stderr, "%s\n", a.error);
    return 2;
  }
  if (c->buffer_mb >= 0) c->cavity.buffer_bytes = (size_t)c->buffer_mb << 20;
  return 0;
}

static int run(int argc, char **argv) {
  if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  int cmd = 0;
  for (size_t i = 0; i < sizeof commands / sizeof *commands; i++)
    if (!strcmp(argv[1], commands[i].name)) cmd = commands[i].bit;
  if (!cmd) {
    fprintf(stderr, "npg-fluids: unknown command '%s'\n", argv[1]);
    usage(stderr);
    return 2;
  }
  /* UMFPACK's fronts are small: BLAS threads only contend (measured: the
   * projection took 29 ms a step with OpenBLAS's threads, 17 ms without) */
  openblas_set_num_threads(1);
  Cmdline c;
  if (parse(argc, argv, cmd, &c) != 0) return 2;
  switch (cmd) {
  case TUNNEL_FULL: return tunnel_full_run(&c.full);
  case MESH: return inspect_mesh(&c.full.spec);
  case TUNNEL: return tunnel_run(&c.tunnel);
  case CAVITY: return cavity_run(&c.cavity);
  case CAVITY_MESH: return inspect_cavity_mesh(&c.cavity_spec);
  default: return inspect_cavity_projection(&c.cavity_spec, c.steps, c.method);
  }
}

int main(int argc, char **argv) { return util_exit_status("npg-fluids", run(argc, argv)); }
