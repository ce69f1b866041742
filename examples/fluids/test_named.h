/* test_named.h — the fluids tests' main: run the test named by argv[1]
 * (its function's name without "test_", as ctest calls it), or all. */
#ifndef FLUIDS_TEST_NAMED_H
#define FLUIDS_TEST_NAMED_H

#include <stdio.h>
#include <string.h>

static int run_named_tests(const char *prog, int argc, char **argv, const struct CMUnitTest *all, int n) {
  int rc = 0, ran = 0;
  for (int i = 0; i < n; i++) {
    const char *name = all[i].name;
    if (strncmp(name, "test_", 5) == 0) name += 5;
    if (argc > 1 && strcmp(argv[1], name) != 0) continue;
    rc |= _cmocka_run_group_tests(name, all + i, 1, NULL, NULL);
    ran++;
  }
  if (!ran) {
    fprintf(stderr, "%s: no test named '%s'\n", prog, argv[1]);
    return 2;
  }
  return rc;
}

#endif
