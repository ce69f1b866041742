/* corpus.c — the programs the tests check over, and random data for them (corpus.h). */
#include <dirent.h>
#include <stdio.h>
#include <string.h>

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "compile.h"
#include "corpus.h"
#include "randdata.h"

const char *const corpus_examples[] = {"examples/rational", "examples/radiosity", "examples/fluids", NULL};
const char *const corpus_all[] = {"examples/rational", "examples/radiosity", "examples/fluids", "tests/programs", NULL};

int for_each_program(const char *dir, int (*check)(const char *path, void *arg), void *arg, int *n) {
  DIR *d = opendir(dir);
  if (!d) return 0;
  int failures = 0;
  struct dirent *e;
  while ((e = readdir(d))) {
    size_t l = strlen(e->d_name);
    if (l < 5 || strcmp(e->d_name + l - 4, ".npg") != 0) continue;
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
    failures += check(path, arg);
    (*n)++;
  }
  closedir(d);
  return failures;
}

typedef struct Compiled {
  ProgramCheck check;
  void *arg;
} Compiled;

static int compiled(const char *path, void *arg) {
  const Compiled *c = arg;
  NpgOptions opt = {0};
  opt.std_dir = "stdlib";
  NpgProgram *p = npg_compile(path, &opt);
  int failures = 1;
  if (!npg_ok(p)) print_message("%s: does not compile:\n%s", path, npg_error(p));
  else failures = c->check(p, path, c->arg);
  npg_free(p);
  return failures;
}

int check_programs(const char *const *dirs, ProgramCheck check, void *arg, int *n) {
  Compiled c = {check, arg};
  int failures = 0;
  for (int i = 0; dirs[i]; i++) failures += for_each_program(dirs[i], compiled, &c, n);
  return failures;
}

static void given(RefData *d, const Program *prog, const Sym *s, long n, unsigned *seed, bool padded, GivenFn set,
                  void *user, int *npad) {
  double *v = ref_values(d, s);
  *npad += randdata_fill(&(RandData){prog, n, seed, padded}, s, v, ref_count(d, s));
  if (!set) return;
  long shape[MAX_AXES + MAX_STATIC];
  for (int a = 0; a < s->ndims; a++) shape[a] = n;
  for (int a = 0; a < s->nstatic; a++) shape[s->ndims + a] = s->shape[a];
  set(user, s, s->ndims + s->nstatic, shape, v);
}

int bind_random(RefData *d, const Program *prog, long n, unsigned seed, bool padded, GivenFn set, void *user) {
  int npad = 0;
  for (int i = 0; i < prog->params.n; i++) given(d, prog, prog->params.v[i], n, &seed, padded, set, user, &npad);
  for (int i = 0; i < prog->quantities.n; i++) {
    const Sym *s = prog->quantities.v[i];
    if (s->kind == SYM_INPUT || s->kind == SYM_EXTERN) given(d, prog, s, n, &seed, false, set, user, &npad);
  }
  return npad;
}
