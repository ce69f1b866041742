/* main.c — the npgc driver. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "npg.h"
#include "npgc.h"

/* npgc emit PROG.npg [--reduced MODEL/ | --derivatives] -o FILE.c: written to
 * FILE.c.tmp.<pid>, renamed when complete. */
static int cmd_emit(int argc, char **argv) {
  const char *path = NULL, *outpath = NULL, *model_dir = NULL;
  bool derivatives = false;
  NpgOptions opt = {0};
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npgc emit");
  while (npg_args_next(&a)) {
    const char *v;
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage("emit", true);
    if ((v = npg_args_string(&a, "-o"))) outpath = v;
    else if ((v = npg_args_string(&a, "--reduced"))) model_dir = v;
    else if (npg_args_flag(&a, "--derivatives")) derivatives = true;
    else if ((v = npg_args_string(&a, "--std"))) opt.std_dir = v;
    else if ((v = npg_args_positional(&a)) && !path) path = v;
    else if (v) npgc_args_extra(&a, "program", path);
    else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, "emit");
  if (!path || !outpath) return npgc_missing("emit", !path ? "the program (PROG.npg)" : "-o FILE.c (where to write the C)");
  if (derivatives && model_dir) {
    fputs("npgc emit: --derivatives writes the full evaluator's derivatives; it does not go with --reduced\n", stderr);
    return 2;
  }
  const char *inputs[] = {path, model_dir, NULL};
  if (npgc_check_output("emit", "-o", outpath, NPGC_OUT_FILE, inputs) != 0) return 1;
  NpgProgram *p = npg_compile(path, &opt);
  if (!npg_ok(p)) {
    fputs(npg_error(p), stderr);
    npg_free(p);
    return 1;
  }
  NpgModel *m = NULL;
  if (model_dir && npgc_check_model_and_data("emit --reduced", model_dir, NULL, "-o FILE.c") != 0) {
    npg_free(p);
    return 1;
  }
  if (model_dir && npg_model_error(m = npg_model_load(p, model_dir))[0]) {
    npgc_error(npg_model_error(m));
    npg_model_free(m);
    npg_free(p);
    return 1;
  }
  char tmp[4096];
  npgc_tmp_path(tmp, sizeof tmp, outpath);
  if (npgc_make_parents(outpath, false) != 0) {
    npg_model_free(m);
    npg_free(p);
    return 1;
  }
  FILE *f = fopen(tmp, "w");
  if (!f) {
    fprintf(stderr, "npgc emit: cannot write %s: %s\n", tmp, strerror(errno));
    npg_model_free(m);
    npg_free(p);
    return 1;
  }
  char err[2048] = "";
  int rc = m ? npg_model_emit(m, f, err, sizeof err) : derivatives ? npg_emit_derivatives(p, f) : npg_emit_full(p, f);
  if (fclose(f) != 0 && rc == 0) {
    fprintf(stderr, "npgc emit: cannot write %s: %s\n", tmp, strerror(errno));
    rc = -1;
  } else if (rc != 0 && m) {
    npgc_error(err);
  } else if (rc != 0) {
    fputs(npg_error(p), stderr);
  }
  rc = npgc_commit("emit", tmp, outpath, rc);
  npg_model_free(m);
  npg_free(p);
  return rc == 0 ? 0 : 1;
}

static int run(int argc, char **argv) {
  if (argc < 2 || strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0) {
    npgc_usage_all(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const char *cmd = argv[1];
  if (strcmp(cmd, "emit") == 0) return cmd_emit(argc, argv);
  if (strcmp(cmd, "eval") == 0) return npgc_eval(argc, argv);
  if (strcmp(cmd, "plot") == 0) return npgc_plot(argc, argv);
  if (strcmp(cmd, "tune") == 0) return npgc_tune(argc, argv);
  if (strcmp(cmd, "simulate") == 0) return npgc_simulate(argc, argv);
  if (!strcmp(cmd, "train") || !strcmp(cmd, "verify") || !strcmp(cmd, "bench")) return npgc_reduce(argc, argv);
  if (strcmp(cmd, "check") != 0) {
    fprintf(stderr, "npgc: unknown command '%s' (npgc --help lists them)\n", cmd);
    return 2;
  }
  const char *path = NULL;
  bool json = false;
  NpgOptions opt = {0};
  NpgArgs a;
  npg_args_init(&a, argc, argv, 2, "npgc check");
  while (npg_args_next(&a)) {
    const char *v, *s = argv[a.i];
    if (npg_args_flag(&a, "--help") || npg_args_flag(&a, "-h")) return npgc_usage("check", true);
    if (npg_args_flag(&a, "--json")) json = true;
    else if (strncmp(s, "-d", 2) == 0 && s[2]) {
      size_t bad = strspn(s + 2, "pslb");
      if (s[2 + bad]) {
        fprintf(stderr, "npgc check: unknown dump letter '%c' in '%s' (the letters are p, s, l, b)\n", s[2 + bad], s);
        return 2;
      }
      opt.dump = s + 2, opt.dump_out = stdout;
    }
    else if ((v = npg_args_string(&a, "--std"))) opt.std_dir = v;
    else if ((v = npg_args_positional(&a)) && !path) path = v;
    else if (v) npgc_args_extra(&a, "program", path);
    else npg_args_unknown(&a);
  }
  if (a.error[0]) return npgc_args_error(&a, "check");
  if (!path) return npgc_missing("check", "the program (PROG.npg)");
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

/* A report that did not reach stdout (a full disk, a closed pipe, /dev/full)
 * is a failure of the command, whatever it computed (issue 24). */
int main(int argc, char **argv) {
  int rc = run(argc, argv);
  errno = 0;
  bool flushed = fflush(stdout) == 0;
  int saved = errno;
  if (flushed && ferror(stdout)) {
    /* an earlier write failed (a report longer than stdout's buffer) and its errno is gone: one
     * more write to the same stream finds the cause again */
    clearerr(stdout);
    fputc('\n', stdout);
    errno = 0;
    flushed = fflush(stdout) == 0;
    saved = errno;
    if (flushed) flushed = false, saved = 0;
  }
  if (!flushed || ferror(stdout)) {
    fprintf(stderr, "npgc: cannot write to standard output%s%s\n", saved ? ": " : "", saved ? strerror(saved) : "");
    return rc ? rc : 1;
  }
  return rc;
}
