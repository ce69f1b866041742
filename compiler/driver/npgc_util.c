/* npgc_util.c — what every npgc command shares: its usage text, strict
 * parsing of numbers, and the checks on output paths (npgc.h). */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <dirent.h>
#include <sys/stat.h>
#include <unistd.h>

#include "npg.h"
#include "npgc.h"

typedef struct Usage {
  const char *cmd, *text;
} Usage;

static const Usage usages[] = {
    {"check",
     "usage: npgc check PROG.npg [--json] [-d<letters>] [--std=DIR]\n"
     "\n"
     "  Parse, type-check and lower PROG.npg; print its stages (kind, shape, inputs,\n"
     "  degrees, tensor orders, symbolic nonzeros), its basis classes with the reason\n"
     "  of every merge, and the reduced evaluation cost.\n"
     "  --json       the same report as JSON\n"
     "  -dLETTERS    dump the IR after stages: p parse, s check, l lower, b basis classes\n"
     "  --std=DIR    the directory holding npg/<module>.npg\n"},
    {"emit",
     "usage: npgc emit PROG.npg [--reduced MODEL/ | --derivatives] -o FILE.c [--std=DIR]\n"
     "\n"
     "  Write the generated C of the full evaluator (one function per stage) and the\n"
     "  bind-time gather checker; it compiles standalone with cc -c.\n"
     "  --reduced MODEL/  instead, the reduced evaluator of the model trained in MODEL/,\n"
     "               specialized to its sizes (the host passes the reduced tensors,\n"
     "               NpgReducedCtx in npg_abi.h)\n"
     "  --derivatives  instead, the full evaluator's forward and reverse products\n"
     "               (<stem>_npg_full_jvp, <stem>_npg_full_vjp: NpgDerivFn in npg_abi.h)\n"
     "  -o FILE.c    written to a temporary name and renamed when complete; missing\n"
     "               parent directories are created; an input of the command is refused\n"},
    {"eval",
     "usage: npgc eval PROG.npg --full DATA/ IN/ -o OUT/ [--jacobian OUT:IN]... [--jit auto|cc|tcc]\n"
     "                 [--progress] [--std=DIR]\n"
     "       npgc eval PROG.npg MODEL/ IN/ -o OUT/ [--jacobian OUT:IN]... [--sizes NAME=N,...] [--exact-roots]\n"
     "                 [--progress] [--std=DIR]\n"
     "\n"
     "  --full: evaluate the full program on every sample of IN/<input>.npy (leading\n"
     "  sample axis; params from DATA/<param>.npy, inputs and externs from IN/, else\n"
     "  DATA/) and write every output as OUT/<name>.npy; an `output op` as CSR:\n"
     "  OUT/<name>.indptr.npy, OUT/<name>.indices.npy (int64) and OUT/<name>.data.npy\n"
     "  (samples x nonzeros). A non-finite value is an error naming where it arises.\n"
     "  With MODEL/: the reduced evaluation; writes OUT/<name>.npy (lifted) and\n"
     "  OUT/<name>.reduced.npy (reduced coordinates; an output op: samples x m x m).\n"
     "  Params in IN/ must be those the model was trained with.\n"
     "  --jacobian OUT:IN  also the exact Jacobian of stage OUT by input IN at every\n"
     "               sample: OUT/jacobian_OUT_IN.npy, samples x OUT's axes x IN's axes;\n"
     "               with MODEL/, in reduced coordinates: OUT/jacobian_OUT_IN.reduced.npy,\n"
     "               samples x m_OUT x m_IN\n"
     "  --jit B      the full evaluator's compiler: auto (the default: $NPG_JIT, else\n"
     "               cc when installed, else libtcc), cc (-O3, cached), tcc; --cc = --jit cc\n"
     "  --exact-roots  roots of reduced operators by eigendecomposition\n"
     "  --sizes NAME=N,...  evaluate at smaller basis sizes, without retraining: class\n"
     "               NAME (as npgc check names it: m_u) keeps the first N vectors of\n"
     "               its basis and every tensor its leading block\n"
     "  --progress   progress on stderr even when it is not a terminal\n"
     "  -o OUT/      created with its missing parents\n"},
    {"simulate",
     "usage: npgc simulate PROG.npg DATA/ --steps T [--every K] [--model MODEL/] [--blowup F]\n"
     "                     [--newton-tol R] [--newton-max-iter N] [--newton-verbose]\n"
     "                     -o OUT/ [--jit auto|cc|tcc] [--progress] [--std=DIR]\n"
     "\n"
     "  Run the program's time step (a program with `state u` and `next u = ...`) T\n"
     "  times from each trajectory's initial states: DATA/<state>.npy holds them\n"
     "  [trajectories, ...]; every other input is held, [trajectories, ...], or given per\n"
     "  step, [trajectories, steps, ...]; params from DATA/ too. Writes every state as\n"
     "  OUT/<state>.npy, [trajectories, T/K + 1, ...]: steps 0, K, 2K, ...\n"
     "  --every K    save every K-th step (1)\n"
     "  --model MODEL/  run the reduced step instead, every state kept in reduced\n"
     "               coordinates and lifted only at the saved steps\n"
     "  --blowup F   stop when a state's energy exceeds F times its start (10; 0: only\n"
     "               a value that is not finite stops the run); the step and state named\n"
     "  --newton-tol R  a state stepped implicitly (`residual next u = ...`): each step's\n"
     "               Newton stops at |r| <= R max(|r0|, 1e-4 |u|), r0 the residual at the\n"
     "               first guess u (1e-10)\n"
     "  --newton-max-iter N  Newton's corrections per step at most (30); a step that does\n"
     "               not converge stops the run, naming the step, iteration and residual\n"
     "  --newton-verbose  |r| per Newton iteration on stderr\n"
     "  --jit B      the full evaluator's compiler: auto, cc or tcc (as npgc train)\n"
     "  --progress   progress on stderr even when it is not a terminal\n"
     "  -o OUT/      created with its missing parents; written when every trajectory ran\n"},
    {"train",
     "usage: npgc train PROG.npg DATA/ -o MODEL/ [--cap N] [--energy E] [--center on|off]\n"
     "                  [--basis NAME:cap=N,energy=E,center=on|off] [--merge concat|joint]\n"
     "                  [--mem BYTES] [--spectra DIR] [--mpi] [--jit auto|cc|tcc] [--progress] [--std=DIR]\n"
     "                  [--reduce STAGE:interp|galerkin] [--interp-oversample X] [--valid DIR|F|none]\n"
     "                  [--keep-bases NAME,...|all] [--weights FILE.npy]\n"
     "                  [--greedy POOL/ --tol E [--budget N] [--absolute]]\n"
     "\n"
     "  Run the full program on every sample of DATA/ (params, and inputs and externs\n"
     "  with a leading sample axis), build one basis per class, pre-multiply every\n"
     "  tensor, fit the learned map of every extern, write MODEL/ (a temporary folder\n"
     "  renamed when complete; missing parents are created).\n"
     "  --cap N      basis vectors per member (60, 1..1000000)\n"
     "  --energy E   energy fraction per member (0.999, in (0, 1])\n"
     "  --center     on (default): each member's basis keeps its snapshots' mean and\n"
     "               truncates the centered energy; off: the paper's uncentered rule\n"
     "  --basis NAME:cap=N,energy=E,center=on|off   NAME a quantity, a class (m_x, as\n"
     "               npgc check prints it, or m_ and any member), a numerator (y.num1)\n"
     "               or '*'; unknown names are refused; max=N is accepted for cap=N,\n"
     "               and 'cap N' as in the program's basis statement; product=OP: the\n"
     "               class orthonormal in the inner product of the SPD op OP (as the\n"
     "               statement's 'product OP')\n"
     "  --spectra DIR  every member's singular values also to DIR (.npy and CSV;\n"
     "               MODEL/ always holds them)\n"
     "  --reduce STAGE:interp   reduce STAGE by interpolation (DESIGN §12): its formula\n"
     "               evaluated exactly at selected entries, its coordinates fitted by least\n"
     "               squares; STAGE must be eligible (npgc check: every operator diagonal)\n"
     "  --interp-oversample X   entries per basis vector of an interpolated stage (32, >= 1)\n"
     "  --valid DIR  validation samples (same params): every eligible stage not named by\n"
     "               --reduce is reduced both ways and the lower output error on them kept\n"
     "               (ties: the cheaper); the choice, both errors and the reason are printed;\n"
     "               --valid F (a fraction in (0, 0.5]): every round(1/F)-th sample of DATA/\n"
     "               held out of training to validate on instead. Without --valid, when the\n"
     "               program has such a stage, no extern and DATA/ at least 30 samples, every\n"
     "               10th is held out to choose, then the model trained on all with the choice\n"
     "               fixed; --valid none: no choice, every such stage by Galerkin\n"
     "  --keep-bases NAME,...  keep these bases in MODEL/ too (quantities or classes m_x; all:\n"
     "               every basis). By default the bases the reduced model never reads (pair\n"
     "               quantities, F x F rows, that are no input, output or extern) are used in\n"
     "               training and not stored; verify then reports their training floors\n"
     "  --weights FILE.npy  one positive weight per sample of DATA/ (float64 vector): the\n"
     "               PCA counts sample k w_k times (a weighted mean and residual); floors and\n"
     "               reports stay per sample; not with --merge joint\n"
     "  --greedy POOL/  greedy training (docs/estimates.md): start from DATA/'s samples (one\n"
     "               is enough), estimate the error of every candidate of POOL/ (its inputs) by\n"
     "               the online estimate, run the full program only at the worst one, retrain;\n"
     "               until every candidate's estimated relative error is below --tol E or the\n"
     "               model holds --budget N samples (said on stderr); progress on stderr; the\n"
     "               chosen candidates in the manifest's greedy line. Inputs' bases keep every\n"
     "               direction (energy 1 unless --basis or the program sets it); raise the other\n"
     "               caps and energy (--basis u:cap=200,energy=1) so that each sample adds a vector\n"
     "  --absolute   greedy's --tol bounds the estimated absolute error (in the norm of the\n"
     "               product K0 for an output whose class has one: pyMOR's atol), not the\n"
     "               relative one\n"
     "  --merge      concat (one PCA per member, concatenated) or joint (one PCA)\n"
     "  --mem BYTES  memory for training besides one full evaluation (half the RAM; k, M, G, T: powers of 1000):\n"
     "               snapshots in memory, else the method of snapshots, else out of core by row blocks;\n"
     "               a stage that alone needs more is refused\n"
     "  --mpi        over the ranks of an MPI job (mpirun -np N npgc train ... --mpi):\n"
     "               samples and tensor rows partitioned, the same model as one\n"
     "               process; rank 0 writes MODEL/; a failed rank ends the job\n"
     "  --jit B      the full evaluator's compiler: auto (the default: $NPG_JIT, else\n"
     "               cc when installed, else libtcc), cc (-O3, cached), tcc; --cc = --jit cc\n"
     "  --progress   progress on stderr even when it is not a terminal\n"},
    {"verify",
     "usage: npgc verify PROG.npg MODEL/ TEST/ [--tol T] [--params DIR] [--jit auto|cc|tcc] [--exact] [--exact-size N]\n"
     "                   [--sizes NAME=N,...] [--progress]\n"
     "       npgc verify PROG.npg --exact [--exact-size N] [--jit auto|cc|tcc]\n"
     "\n"
     "  Evaluate full and reduced on the held-out samples of TEST/ (same params as\n"
     "  training) and report, per quantity, the relative error of the lifted reduced\n"
     "  value, the projection floor and their difference (L2 and Linf), and the stage\n"
     "  where error grows most. Exit 1 when an output's mean L2 error exceeds --tol\n"
     "  (default 1e-2) or a value is not finite.\n"
     "  --params DIR the params from DIR (the training data's, say) instead of TEST/\n"
     "  --exact      the two exactness checks (alone when MODEL/ and TEST/ are not\n"
     "               given), on random data with every dim of a small size: every stage\n"
     "               rebuilt from its tensors equals the full evaluator to 1e-12, and a\n"
     "               model with full-rank bases reproduces it to 1e-10\n"
     "  --exact-size N   that size (1..64; 6 and 4 by default)\n"
     "  --sizes NAME=N,...  evaluate at smaller basis sizes, without retraining: class\n"
     "               NAME (as npgc check names it: m_u) keeps the first N vectors of\n"
     "               its basis and every tensor its leading block\n"
     "  --jit B      the full evaluator's compiler: auto, cc or tcc (as npgc train)\n"
     "  --progress   progress on stderr even when it is not a terminal\n"},
    {"bench",
     "usage: npgc bench PROG.npg MODEL/ TEST/ [--jit auto|cc|tcc] [--threads N] [--reps N] [--params DIR]\n"
     "                  [--sizes NAME=N,...] [--exact-roots] [--steps T] [--progress]\n"
     "\n"
     "  Time the full and the reduced evaluation of every sample of TEST/, N passes\n"
     "  (3): the full evaluator (its backend named, with its compile time and whether\n"
     "  it came from the cache), the reduced one with its inputs projected and its\n"
     "  outputs lifted, and each part apart (the reduced evaluation alone: coordinates\n"
     "  in, coordinates out): medians and quartiles; the reduced evaluation alone then\n"
     "  every output's online error estimate (npg_reduced_estimate), and its ratio to\n"
     "  the evaluation alone; the speedups with and without projection and lift\n"
     "  (medians of the per-evaluation ratios); the model's memory.\n"
     "  --threads N  BLAS threads of the reduced evaluation (1)\n"
     "  --jit B      the full evaluator's compiler: auto, cc or tcc (as npgc train)\n"
     "  --params DIR the params from DIR instead of TEST/\n"
     "  --exact-roots  roots of reduced operators by eigendecomposition (the exact\n"
     "               reference) instead of the Lanczos process (to 1e-8 relative)\n"
     "  --sizes NAME=N,...  evaluate at smaller basis sizes, without retraining: class\n"
     "               NAME (as npgc check names it: m_u) keeps the first N vectors of\n"
     "               its basis and every tensor its leading block\n"
     "  --steps T    a program with state (DESIGN §15): T steps of every trajectory\n"
     "               of TEST/, the full step against the reduced step in coordinates,\n"
     "               the lift of the states, and each step's reduced evaluation then\n"
     "               every output's and next state's estimate (\"reduced + estimate\",\n"
     "               per step) against the evaluation alone\n"
     "  --progress   a progress bar on stderr even when it is not a terminal (on a\n"
     "               terminal it is always shown)\n"},
    {"plot",
     "usage: npgc plot MODEL/ -o spectra.png\n"
     "\n"
     "  Draw every member's singular values (relative to its largest, log scale) with a\n"
     "  dot where its basis was truncated.\n"},
    {"tune",
     "usage: npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/ [--max-cap N] [--center on|off]\n"
     "                 [--png FILE] [--jit auto|cc|tcc] [--reduce STAGE:interp|galerkin] [--interp-oversample X]\n"
     "                 [--keep-bases NAME,...|all] [--steps T [--every K]]\n"
     "\n"
     "  Choose every class's basis size so that every output's mean relative L2 error on\n"
     "  VALID/ (held-out samples, the same params) is under T at the least reduced cost\n"
     "  (the cost npgc check prints); one snapshot pass and one SVD per member. Prints the\n"
     "  candidates, writes the chosen model to MODEL/ and a PNG of error against cost\n"
     "  (MODEL-tune.png, or --png FILE); says when T cannot be met and which class limits it.\n"
     "  At every candidate, each stage eligible for interpolation (npgc check) and not\n"
     "  named by --reduce is reduced both ways and the lower error kept, so the sizes\n"
     "  found are those of the better reduction; the table names the stages interpolated.\n"
     "  --reduce, --interp-oversample, --keep-bases: as npgc train (by default the bases\n"
     "  the reduced model never reads are not stored)\n"
     "  --steps T    a program with state (DESIGN §15): train on the states DATA/'s full\n"
     "               rollouts of T steps visit (every K-th, --every K) and judge every\n"
     "               candidate by its reduced rollouts of T steps from VALID/'s initial\n"
     "               states: the worst state's trajectory error, not one step's\n"},
};

int npgc_usage(const char *cmd, bool help) {
  for (size_t i = 0; i < sizeof usages / sizeof usages[0]; i++)
    if (strcmp(usages[i].cmd, cmd) == 0) {
      fputs(usages[i].text, help ? stdout : stderr);
      return help ? 0 : 2;
    }
  fprintf(stderr, "npgc: unknown command '%s'\n", cmd);
  return 2;
}

void npgc_usage_all(FILE *out) {
  fputs("usage: npgc COMMAND ... (npgc COMMAND --help for its whole usage)\n"
        "Every option takes its value as --opt VALUE or --opt=VALUE; numbers are read whole.\n\n", out);
  for (size_t i = 0; i < sizeof usages / sizeof usages[0]; i++) {
    fputs(usages[i].text, out);
    fputc('\n', out);
  }
}

/* `msg` starts "FILE:LINE:COL: error: " (FILE may hold colons). */
static bool is_program_diagnostic(const char *msg) {
  const char *e = strstr(msg, ": error: ");
  if (!e || memchr(msg, '\n', (size_t)(e - msg))) return false;
  const char *p = e;
  for (int field = 0; field < 2; field++) {
    const char *digits = p;
    while (p > msg && p[-1] >= '0' && p[-1] <= '9') p--;
    if (p == digits || p == msg || p[-1] != ':') return false;
    p--;
  }
  return p > msg;
}

void npgc_error(const char *msg) {
  size_t n = strlen(msg);
  fprintf(stderr, "%s%.*s\n", is_program_diagnostic(msg) ? "" : "error: ", (int)(n && msg[n - 1] == '\n' ? n - 1 : n),
          msg);
}

bool npgc_parse_bytes(const char *s, size_t *out) {
  if (!s || !*s) return false;
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  double mul = 1;
  if (*end == 'k' || *end == 'K') mul = 1e3, end++;
  else if (*end == 'M') mul = 1e6, end++;
  else if (*end == 'G') mul = 1e9, end++;
  else if (*end == 'T') mul = 1e12, end++;
  if (errno || end == s || *end || !isfinite(v) || !(v > 0) || v * mul >= (double)SIZE_MAX) return false;
  *out = (size_t)(v * mul);
  return *out > 0;
}

int npgc_make_parents(const char *path, bool self) {
  char buf[4096];
  snprintf(buf, sizeof buf, "%s", path);
  size_t n = strlen(buf);
  while (n > 1 && buf[n - 1] == '/') buf[--n] = 0;
  if (!self) { /* the parent of `path` only */
    char *slash = strrchr(buf, '/');
    if (!slash) return 0;
    *slash = 0;
    if (!buf[0]) return 0;
  }
  for (char *p = buf + 1;; p++) {
    bool last = *p == 0;
    if (*p == '/' || last) {
      char c = *p;
      *p = 0;
      if (mkdir(buf, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "error: cannot create %s: %s\n", buf, strerror(errno));
        return -1;
      }
      struct stat st;
      if (stat(buf, &st) != 0 || !S_ISDIR(st.st_mode)) {
        fprintf(stderr, "error: %s exists and is not a directory\n", buf);
        return -1;
      }
      *p = c;
    }
    if (last) break;
  }
  return 0;
}

bool npgc_same_file(const char *a, const char *b) {
  struct stat sa, sb;
  return a && b && stat(a, &sa) == 0 && stat(b, &sb) == 0 && sa.st_dev == sb.st_dev && sa.st_ino == sb.st_ino;
}

bool npgc_inside(const char *path, const char *dir) {
  char parent[4096];
  snprintf(parent, sizeof parent, "%s", path);
  char *slash = strrchr(parent, '/');
  if (!slash) snprintf(parent, sizeof parent, ".");
  else if (slash == parent) parent[1] = 0;
  else *slash = 0;
  return npgc_same_file(parent, dir);
}

/* `path` made absolute (from the working folder) with '.', '..' and
 * repeated '/' resolved by text, into `out`; false when it does not fit. */
static bool lexical_abs(const char *path, char *out, size_t n) {
  char cwd[4096] = "";
  if (path[0] != '/' && !getcwd(cwd, sizeof cwd)) return false;
  char full[8192];
  if ((size_t)snprintf(full, sizeof full, "%s/%s", cwd, path) >= sizeof full) return false;
  size_t len = 0;
  for (char *save = NULL, *part = strtok_r(full, "/", &save); part; part = strtok_r(NULL, "/", &save)) {
    if (!strcmp(part, ".")) continue;
    if (!strcmp(part, "..")) {
      if (len > 0) /* drop the last component ("/.." is "/") */
        do len--;
        while (len > 0 && out[len] != '/');
      continue;
    }
    size_t k = strlen(part);
    if (len + 1 + k + 1 > n) return false;
    out[len] = '/';
    memcpy(out + len + 1, part, k);
    len += 1 + k;
  }
  if (len + 1 > n) return false;
  if (len == 0) out[len++] = '/';
  out[len] = 0;
  return true;
}

bool npgc_under(const char *path, const char *dir) {
  char p[4096], d[4096];
  if (!lexical_abs(path, p, sizeof p) || !lexical_abs(dir, d, sizeof d)) return false;
  size_t n = strlen(d);
  if (!strcmp(d, "/")) return true;
  return strncmp(p, d, n) == 0 && (p[n] == 0 || p[n] == '/');
}

bool npgc_newton_arg(NpgArgs *a, NpgcNewton *nw) {
  if (npg_args_double(a, "--newton-tol", 0, 1, true, &nw->tol)) return true;
  if (npg_args_int(a, "--newton-max-iter", 1, 100000, &nw->max_iter)) return true;
  if (npg_args_flag(a, "--newton-verbose")) return nw->verbose = true;
  return false;
}

void npgc_newton_full(const NpgcNewton *nw, NpgFull *f) {
  if (f && !npg_full_error(f)[0]) npg_full_set_newton(f, nw->tol, nw->max_iter, nw->verbose ? stderr : NULL);
}

void npgc_newton_reduced(const NpgcNewton *nw, NpgReduced *r) {
  if (r && !npg_reduced_error(r)[0]) npg_reduced_set_newton(r, nw->tol, nw->max_iter, nw->verbose ? stderr : NULL);
}

int npgc_args_error(const NpgArgs *a, const char *cmd) {
  fprintf(stderr, "%s (npgc %s --help for its usage)\n", a->error, cmd);
  return 2;
}

void npgc_args_extra(NpgArgs *a, const char *what, const char *first) {
  if (!a->error[0])
    snprintf(a->error, sizeof a->error, "%s: more than one %s given ('%s' and '%s')", a->prog, what, first,
             a->argv[a->i]);
}

int npgc_missing(const char *cmd, const char *what) {
  fprintf(stderr, "npgc %s: missing %s (npgc %s --help for its usage)\n", cmd, what, cmd);
  return 2;
}

/* `dir` holds an entry `name` (a file, or anything in its place). */
static bool holds(const char *dir, const char *name) {
  char path[4096];
  struct stat st;
  snprintf(path, sizeof path, "%s/%s", dir, name);
  return lstat(path, &st) == 0;
}

/* What every model folder holds (a damaged model still holds one of them,
 * and is left to the model loader to describe). */
static bool looks_like_model(const char *dir) { return holds(dir, "manifest") || holds(dir, "basis_0.npy"); }

/* `dir` holds at least one .npy file. */
static bool holds_npy(const char *dir) {
  DIR *d = opendir(dir);
  if (!d) return false;
  bool found = false;
  for (struct dirent *e; !found && (e = readdir(d));) {
    size_t n = strlen(e->d_name);
    found = n > 4 && strcmp(e->d_name + n - 4, ".npy") == 0;
  }
  closedir(d);
  return found;
}

int npgc_check_model_and_data(const char *cmd, const char *model, const char *data, const char *data_role) {
  bool model_is_model = looks_like_model(model), data_is_model = data && looks_like_model(data);
  if (!model_is_model && data_is_model) {
    fprintf(stderr, "npgc %s: %s is a model and %s is not (it has no manifest): the order is npgc %s PROG.npg MODEL/ "
                    "%s\n", cmd, data, model, cmd, data_role);
    return -1;
  }
  if (!model_is_model && holds_npy(model)) {
    fprintf(stderr, "npgc %s: %s is a data folder (it holds .npy files and no manifest), not a model: give the "
                    "folder npgc train -o wrote (npgc %s PROG.npg MODEL/ %s)\n", cmd, model, cmd, data_role);
    return -1;
  }
  return 0;
}

/* Whether directory `dir` holds a model (a file named "manifest"). */
static bool holds_model(const char *dir) {
  char path[4096];
  struct stat st;
  snprintf(path, sizeof path, "%s/manifest", dir);
  return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

int npgc_check_output(const char *cmd, const char *opt, const char *out, NpgcOutput kind, const char *const *inputs) {
  bool dir = kind != NPGC_OUT_FILE;
  struct stat st;
  for (int i = 0; inputs && inputs[i]; i++) {
    const char *in = inputs[i], *why = NULL;
    bool in_dir = stat(in, &st) == 0 && S_ISDIR(st.st_mode);
    if (npgc_same_file(out, in)) why = "would overwrite an input of the command";
    /* a file next to the inputs could be one of them (DATA/x.npy, MODEL/manifest); a folder inside a model
     * becomes part of the model */
    else if (in_dir && (!dir || holds_model(in)) && npgc_inside(out, in))
      why = "would overwrite an input of the command: it lies in a folder the command reads";
    if (why) {
      fprintf(stderr, "npgc %s: %s %s %s (%s): refusing to write there\n", cmd, opt, out, why, in);
      return -1;
    }
  }
  const char *why = NULL;
  if (lstat(out, &st) == 0) {
    if (S_ISLNK(st.st_mode)) why = "is a symbolic link: refusing to replace it (give the path it points to)";
    else if (dir && !S_ISDIR(st.st_mode)) why = "exists and is not a directory: refusing to replace it";
    else if (!dir && S_ISDIR(st.st_mode)) why = "is a directory: refusing to replace it";
    else if (!dir && !S_ISREG(st.st_mode))
      why = "is not a regular file (a FIFO, socket or device node): refusing to replace it";
    else if (kind == NPGC_OUT_DIR && holds_model(out))
      why = "holds a model: refusing to write into it (it would replace or add to the model's files); give the "
            "outputs a folder of their own";
  }
  if (why) {
    fprintf(stderr, "npgc %s: %s %s: %s\n", cmd, opt, out, why);
    return -1;
  }
  return 0;
}

void npgc_tmp_path(char *buf, size_t n, const char *out) {
  snprintf(buf, n, "%s.tmp.%ld", out, (long)getpid());
}

int npgc_commit(const char *cmd, const char *tmp, const char *out, int rc) {
  if (rc == 0 && rename(tmp, out) != 0) {
    fprintf(stderr, "npgc %s: cannot rename %s to %s: %s\n", cmd, tmp, out, strerror(errno));
    rc = -1;
  }
  if (rc != 0) remove(tmp);
  return rc;
}

bool npgc_parse_reduce(NpgTrainOptions *o, const char *s) {
  const char *colon = strrchr(s, ':');
  if (!colon || colon == s) return false;
  bool interp = strcmp(colon + 1, "interp") == 0;
  if (!interp && strcmp(colon + 1, "galerkin") != 0) return false;
  int *n = interp ? &o->ninterp : &o->ngalerkin;
  const char *const **list = interp ? &o->interp_stage : &o->galerkin_stage;
  const char **names = realloc((void *)*list, sizeof(char *) * (size_t)(*n + 1));
  if (!names) return false;
  *list = names;
  if (!(names[*n] = strndup(s, (size_t)(colon - s)))) return false;
  (*n)++;
  return true;
}

void npgc_free_reduce(NpgTrainOptions *o) {
  for (int i = 0; i < o->ninterp; i++) free((char *)o->interp_stage[i]);
  for (int i = 0; i < o->ngalerkin; i++) free((char *)o->galerkin_stage[i]);
  free((void *)o->interp_stage), free((void *)o->galerkin_stage);
  o->ninterp = o->ngalerkin = 0, o->interp_stage = o->galerkin_stage = NULL;
}
