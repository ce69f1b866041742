/* test_diagnostics.c — programs as test data (STYLE "Tests"): every bad
 * program fails with the diagnostic it carries, every good program compiles.
 *
 * tests/bad/NAME.npg holds its expectation in a comment line
 *
 *     # expect: tests/bad/NAME.npg:4:9: error: unknown name 'q'
 *
 * (the first such line counts; the text after "expect:" is trimmed of
 * surrounding blanks). The file is compiled as "tests/bad/NAME.npg" from the
 * source root, and the text must equal the first line of npg_error()
 * exactly. The rest of the diagnostic must hold a caret line (blanks, then
 * '^', optionally more '^' or '~') whose '^' stands under the column the
 * first line names (DESIGN §3: file:line:col, the source line, a caret).
 *
 * tests/programs/NAME.npg must compile.
 *
 * Each phase reports every offending file before it fails. The source root
 * is $NPG_SOURCE_DIR, else the working directory.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <dirent.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "npg.h"

enum { MIN_BAD_PROGRAMS = 30 };

static const char STD_DIR[] = "stdlib";

typedef struct NameList {
  char **names;  /* sorted file names, without the directory */
  size_t n;
} NameList;

static int by_name(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

/* The *.npg files of 'dir', sorted; an empty list when 'dir' is missing. */
static NameList list_npg(const char *dir) {
  NameList l = {0};
  size_t cap = 0;
  DIR *d = opendir(dir);
  if (!d) return l;
  struct dirent *e;
  while ((e = readdir(d))) {
    size_t len = strlen(e->d_name);
    if (len <= 4 || strcmp(e->d_name + len - 4, ".npg") != 0) continue;
    if (l.n == cap) {
      cap = cap ? 2 * cap : 64;
      l.names = realloc(l.names, cap * sizeof *l.names);
      assert_non_null(l.names);
    }
    l.names[l.n] = strdup(e->d_name);
    assert_non_null(l.names[l.n]);
    l.n++;
  }
  closedir(d);
  if (l.n) qsort(l.names, l.n, sizeof *l.names, by_name);
  return l;
}

static void free_list(NameList *l) {
  for (size_t i = 0; i < l->n; i++) free(l->names[i]);
  free(l->names);
}

static char *read_text(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f) return NULL;
  char *text = NULL;
  size_t len = 0;
  FILE *mem = open_memstream(&text, &len);
  assert_non_null(mem);
  char chunk[4096];
  size_t got;
  while ((got = fread(chunk, 1, sizeof chunk, f)) > 0) fwrite(chunk, 1, got, mem);
  fclose(f);
  fclose(mem);
  return text;
}

static bool is_blank(char c) {
  return c == ' ' || c == '\t' || c == '\r';
}

/* The text of the first "# expect: TEXT" line of 'text', trimmed; NULL if none. */
static char *expectation(const char *text) {
  for (const char *line = text; *line;) {
    const char *end = strchr(line, '\n');
    if (!end) end = line + strlen(line);
    const char *p = line;
    while (is_blank(*p)) p++;
    if (*p == '#') {
      p++;
      while (is_blank(*p)) p++;
      if (strncmp(p, "expect:", 7) == 0) {
        p += 7;
        while (p < end && is_blank(*p)) p++;
        const char *q = end;
        while (q > p && is_blank(q[-1])) q--;
        return strndup(p, (size_t)(q - p));
      }
    }
    line = *end ? end + 1 : end;
  }
  return NULL;
}

static char *first_line(const char *s) {
  return strndup(s, strcspn(s, "\n"));
}

/* The column named by the first "...:LINE:COL:" in 'diag'; 0 if none. */
static int diag_column(const char *diag) {
  for (const char *p = strchr(diag, ':'); p && p < diag + strcspn(diag, "\n");
       p = strchr(p + 1, ':')) {
    int line, col, used = 0;
    if (sscanf(p, ":%d:%d:%n", &line, &col, &used) == 2 && used > 0) return col;
  }
  return 0;
}

/* The 1-based column of the '^' of the first caret line in 'diag'; 0 if none. */
static int caret_column(const char *diag) {
  for (const char *line = diag; *line;) {
    size_t len = strcspn(line, "\n");
    size_t i = 0;
    while (i < len && (line[i] == ' ' || line[i] == '\t')) i++;
    if (i < len && line[i] == '^') {
      size_t j = i + 1;
      while (j < len && (line[j] == '^' || line[j] == '~')) j++;
      if (j == len) return (int)i + 1;
    }
    line += len;
    if (*line) line++;
  }
  return 0;
}

static NpgProgram *compile(const char *path) {
  NpgOptions opt = {0};
  opt.std_dir = STD_DIR;
  return npg_compile(path, &opt);
}

/* Everything is relative to the source root. */
static int enter_source_dir(void **state) {
  const char *dir = getenv("NPG_SOURCE_DIR");
  if (dir && *dir && chdir(dir) != 0) {
    print_error("cannot enter NPG_SOURCE_DIR=%s\n", dir);
    return -1;
  }
  return 0;
}

/* Returns the number of problems found with bad program 'path' (0 or more). */
static int check_bad_program(const char *path) {
  char *text = read_text(path);
  if (!text) {
    print_error("%s: cannot read\n", path);
    return 1;
  }
  char *want = expectation(text);
  free(text);
  if (!want) {
    print_error("%s: no '# expect: <first line of the diagnostic>' line\n", path);
    return 1;
  }

  int problems = 0;
  NpgProgram *p = compile(path);
  const char *err = npg_error(p);
  if (npg_ok(p)) {
    print_error("%s: compiled, but should fail with\n    %s\n", path, want);
    problems++;
  } else {
    char *got = first_line(err);
    if (strcmp(got, want) != 0) {
      print_error("%s: wrong diagnostic\n    expected: %s\n    got:      %s\n", path, want, got);
      problems++;
    }
    free(got);
    int caret = caret_column(err), col = diag_column(err);
    if (!caret) {
      print_error("%s: diagnostic has no caret line:\n%s\n", path, err);
      problems++;
    } else if (caret != col) {
      print_error("%s: caret under column %d, diagnostic names column %d:\n%s\n", path, caret,
                  col, err);
      problems++;
    }
  }
  npg_free(p);
  free(want);
  return problems;
}

static void test_bad_programs_fail_as_expected(void **state) {
  NameList bad = list_npg("tests/bad");
  int problems = 0;
  for (size_t i = 0; i < bad.n; i++) {
    char path[4096];
    snprintf(path, sizeof path, "tests/bad/%s", bad.names[i]);
    problems += check_bad_program(path);
  }
  size_t n = bad.n;
  free_list(&bad);
  if (n < MIN_BAD_PROGRAMS) {
    print_error("tests/bad holds %zu programs; at least %d are required\n", n,
                MIN_BAD_PROGRAMS);
    problems++;
  }
  if (problems) fail_msg("%d problem(s) with %zu bad programs (listed above)", problems, n);
}

static void test_good_programs_compile(void **state) {
  NameList good = list_npg("tests/programs");
  int failed = 0;
  for (size_t i = 0; i < good.n; i++) {
    char path[4096];
    snprintf(path, sizeof path, "tests/programs/%s", good.names[i]);
    NpgProgram *p = compile(path);
    if (!npg_ok(p)) {
      print_error("%s: does not compile:\n%s\n", path, npg_error(p));
      failed++;
    }
    npg_free(p);
  }
  size_t n = good.n;
  free_list(&good);
  if (n == 0) fail_msg("tests/programs holds no .npg programs");
  if (failed) fail_msg("%d of %zu good programs do not compile (listed above)", failed, n);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_bad_programs_fail_as_expected),
      cmocka_unit_test(test_good_programs_compile),
  };
  return cmocka_run_group_tests(tests, enter_source_dir, NULL);
}
