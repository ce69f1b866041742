/* main.c — the npgc driver. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "compile.h"
#include "npg.h"
#include "reduced.h"
#include "train.h"

static void usage(FILE *out) {
  fputs("usage: npgc check PROG.npg [--json] [-d<letters>]\n"
        "\n"
        "  check   parse, type-check and lower PROG.npg; print its stages (kind, shape,\n"
        "          inputs, degrees, tensor orders, symbolic nonzeros), its basis classes\n"
        "          with the reason of every merge, and the reduced evaluation cost.\n"
        "  --json  the same report as JSON.\n"
        "  -dLETTERS  dump the IR after stages: p parse, s check, l lower, b basis classes.\n"
        "\n"
        "       npgc emit PROG.npg [--reduced MODEL/] -o FILE.c\n"
        "       npgc eval PROG.npg --full DATA/ IN/ -o OUT/ [--cc]\n"
        "       npgc train PROG.npg DATA/ -o MODEL/ [--cap N] [--energy E] [--basis NAME:cap=N,energy=E]\n"
        "                  [--merge concat|joint] [--mem BYTES] [--cc]\n"
        "       npgc eval PROG.npg MODEL/ IN/ -o OUT/\n"
        "       npgc verify PROG.npg MODEL/ TEST/ [--tol T] [--cc] [--exact] [--exact-size N]\n"
        "       npgc verify PROG.npg --exact [--exact-size N] [--cc]\n"
        "       npgc bench PROG.npg MODEL/ TEST/ [--cc]\n"
        "\n"
        "  emit    write the generated C of the full evaluator (one function per stage)\n"
        "          and the bind-time gather checker; it compiles standalone with cc -c.\n"
        "  --reduced MODEL/  instead, the reduced evaluator of the model trained in MODEL/,\n"
        "          specialized to its sizes; the host passes the reduced tensors\n"
        "          (NpgReducedCtx in npg_abi.h).\n"
        "\n"
        "  eval    --full: evaluate the full program on every sample of IN/<input>.npy\n"
        "          (leading sample axis; params from DATA/<param>.npy) and write every\n"
        "          output as OUT/<name>.npy. --cc compiles with the system compiler at -O3.\n"
        "          With MODEL/: the reduced evaluation; writes OUT/<name>.npy (lifted) and\n"
        "          OUT/<name>.reduced.npy (reduced coordinates) for every output.\n"
        "\n"
        "  train   run the full program on every sample of DATA/ (params, inputs and\n"
        "          externs with a leading sample axis), build one basis per class (PCA\n"
        "          per member: energy 0.999 and cap 60 by default), pre-multiply every\n"
        "          tensor, fit the learned map of every extern, write MODEL/.\n"
        "\n"
        "  verify  evaluate full and reduced on the held-out samples of TEST/ (which\n"
        "          holds the same params) and report, per quantity, the relative error\n"
        "          of the lifted reduced value, the projection floor and their\n"
        "          difference (L2 and Linf); exit 1 when an output's mean L2 error\n"
        "          exceeds --tol (default 1e-2).\n"
        "  --exact the two exactness checks of the design (alone when MODEL/ and\n"
        "          TEST/ are not given), on random data with every dim of a small size\n"
        "          (--exact-size N; 6 and 4 by default): every stage rebuilt from its\n"
        "          tensors equals the full evaluator to 1e-12, and a model with\n"
        "          full-rank bases reproduces it to 1e-10. Exit 1 when one fails.\n"
        "\n"
        "  bench   full vs reduced time per evaluation, speedup, reduced model memory.\n",
        out);
}

/* npgc emit PROG.npg [--reduced MODEL/] -o FILE.c: written to FILE.c.tmp,
 * renamed when complete. */
static int cmd_emit(int argc, char **argv) {
  const char *path = NULL, *outpath = NULL, *model_dir = NULL;
  NpgOptions opt = {0};
  for (int i = 2; i < argc; i++) {
    if (strcmp(argv[i], "-o") == 0 && i + 1 < argc) outpath = argv[++i];
    else if (strcmp(argv[i], "--reduced") == 0 && i + 1 < argc) model_dir = argv[++i];
    else if (strncmp(argv[i], "--std=", 6) == 0) opt.std_dir = argv[i] + 6;
    else if (argv[i][0] == '-') {
      fprintf(stderr, "npgc emit: unknown option '%s'\n", argv[i]);
      return 2;
    } else path = argv[i];
  }
  if (!path || !outpath) {
    fprintf(stderr, "usage: npgc emit PROG.npg [--reduced MODEL/] -o FILE.c\n");
    return 2;
  }
  NpgProgram *p = npg_compile(path, &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  char err[2048] = "";
  Model *m = NULL;
  if (model_dir && !(m = model_load(npg_program_ir(p), model_dir, err, sizeof err))) {
    fprintf(stderr, "error: %s\n", err);
    npg_free(p);
    return 1;
  }
  char tmp[4096];
  snprintf(tmp, sizeof tmp, "%s.tmp", outpath);
  FILE *f = fopen(tmp, "w");
  if (!f) {
    fprintf(stderr, "npgc emit: cannot write %s: %s\n", tmp, strerror(errno));
    model_free(m);
    npg_free(p);
    return 1;
  }
  int rc = m ? emit_reduced(m, f, err, sizeof err) : npg_emit_full(p, f);
  if (fclose(f) != 0 && rc == 0) {
    fprintf(stderr, "npgc emit: cannot write %s: %s\n", tmp, strerror(errno));
    rc = -1;
  } else if (rc != 0 && m) {
    fprintf(stderr, "error: %s\n", err);
  } else if (rc != 0) {
    fputs(npg_error(p), stderr);
  }
  if (rc == 0 && rename(tmp, outpath) != 0) {
    fprintf(stderr, "npgc emit: cannot rename %s to %s: %s\n", tmp, outpath, strerror(errno));
    rc = -1;
  }
  if (rc != 0) remove(tmp);
  model_free(m);
  npg_free(p);
  return rc == 0 ? 0 : 1;
}

int main(int argc, char **argv) {
  if (argc < 2 || strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const char *cmd = argv[1];
  if (strcmp(cmd, "emit") == 0) return cmd_emit(argc, argv);
  if (strcmp(cmd, "eval") == 0) return npgc_eval(argc, argv);
  if (!strcmp(cmd, "train") || !strcmp(cmd, "verify") || !strcmp(cmd, "bench")) return npgc_reduce(argc, argv);
  if (strcmp(cmd, "check") != 0) {
    fprintf(stderr, "npgc: unknown command '%s'\n", cmd);
    usage(stderr);
    return 2;
  }
  const char *path = NULL;
  bool json = false;
  NpgOptions opt = {0};
  for (int i = 2; i < argc; i++) {
    if (strcmp(argv[i], "--json") == 0) json = true;
    else if (strncmp(argv[i], "-d", 2) == 0 && argv[i][2]) opt.dump = argv[i] + 2, opt.dump_out = stdout;
    else if (strncmp(argv[i], "--std=", 6) == 0) opt.std_dir = argv[i] + 6;
    else if (argv[i][0] == '-' && argv[i][1]) {
      fprintf(stderr, "npgc: unknown option '%s'\n", argv[i]);
      return 2;
    } else if (path) {
      fprintf(stderr, "npgc: more than one program given ('%s' and '%s')\n", path, argv[i]);
      return 2;
    } else path = argv[i];
  }
  if (!path) {
    fprintf(stderr, "npgc: check needs a program\n");
    return 2;
  }
  NpgProgram *p = npg_compile(path, &opt);
  int rc = 0;
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    rc = 1;
  } else {
    npg_report(p, stdout, json);
  }
  npg_free(p);
  return rc;
}
