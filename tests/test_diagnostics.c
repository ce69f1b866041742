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

/* The line and column named by the first "...:LINE:COL:" in 'diag'; 0 if none. */
static int diag_position(const char *diag, int *line_out) {
  for (const char *p = strchr(diag, ':'); p && p < diag + strcspn(diag, "\n");
       p = strchr(p + 1, ':')) {
    int line, col, used = 0;
    if (sscanf(p, ":%d:%d:%n", &line, &col, &used) == 2 && used > 0) {
      *line_out = line;
      return col;
    }
  }
  return 0;
}

static bool utf8_continuation(char c) { return ((unsigned char)c & 0xC0) == 0x80; }

/* The source line echoed in 'diag' (the line above its first caret line),
 * and the 0-based character index of the '^' (tabs and the blanks before it
 * count one each); -1 without a caret line. */
static int caret_index(const char *diag, const char **echo, size_t *echo_len) {
  const char *prev = NULL;
  size_t prev_len = 0;
  for (const char *line = diag; *line;) {
    size_t len = strcspn(line, "\n");
    size_t i = 0;
    while (i < len && (line[i] == ' ' || line[i] == '\t')) i++;
    if (i < len && line[i] == '^' && prev) {
      size_t j = i + 1;
      while (j < len && (line[j] == '^' || line[j] == '~')) j++;
      if (j == len) {
        *echo = prev, *echo_len = prev_len;
        return (int)i;
      }
    }
    prev = line, prev_len = len;
    line += len;
    if (*line) line++;
  }
  return -1;
}

/* NULL when the caret of 'diag' stands under the character of the echoed
 * line that is the one at the column the diagnostic names in 'source' (or
 * just past the echo's end when the column is past the line's end); else
 * what is wrong. The echo may be a window of the line, "…" marking a cut. */
static const char *caret_problem(const char *diag, const char *source) {
  int line = 0, col = diag_position(diag, &line);
  const char *echo;
  size_t echo_len;
  int idx = caret_index(diag, &echo, &echo_len);
  if (idx < 0) return "no caret line";
  if (col < 1 || line < 1) return "no line:col";
  const char *src = source;
  for (int l = 1; l < line && src; l++) src = strchr(src, '\n'), src = src ? src + 1 : NULL;
  if (!src) return "the line it names is not in the file";
  size_t src_len = strcspn(src, "\r\n");
  /* the echo's character at index idx */
  size_t k = 0;
  for (int c = 0; k < echo_len; c++) {
    if (c == idx) break;
    k++;
    while (k < echo_len && utf8_continuation(echo[k])) k++;
  }
  if ((size_t)col - 1 >= src_len) return k == echo_len ? NULL : "caret not just past the end of the line";
  if (k == echo_len) return "caret past the end of the echoed line";
  size_t n = 1;
  while (k + n < echo_len && utf8_continuation(echo[k + n])) n++;
  const char *want = src + col - 1;
  bool printable = (unsigned char)*want >= 32 || *want == '\t';
  if (printable ? strncmp(echo + k, want, n) != 0 : echo[k] != '?') return "caret under another character";
  return NULL;
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
    char *source = read_text(path);
    const char *why = caret_problem(err, source ? source : "");
    if (why) {
      print_error("%s: %s:\n%s\n", path, why, err);
      problems++;
    }
    free(source);
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

/* Write 'text' to a fresh file; its path (static storage). */
static const char *write_temp(const char *text) {
  static char path[256];
  const char *t = getenv("TMPDIR");
  snprintf(path, sizeof path, "%s/npg-diag-XXXXXX.npg", t && *t ? t : "/tmp");
  int fd = mkstemps(path, 4);
  assert_true(fd >= 0);
  FILE *f = fdopen(fd, "w");
  assert_non_null(f);
  fputs(text, f);
  fclose(f);
  return path;
}

/* Whether the n bytes at s are whole UTF-8 characters. */
static bool whole_utf8(const char *s, size_t n) {
  for (size_t i = 0; i < n;) {
    unsigned char c = (unsigned char)s[i];
    size_t len = c < 0x80 ? 1 : c >= 0xF0 ? 4 : c >= 0xE0 ? 3 : c >= 0xC0 ? 2 : 0;
    if (!len || i + len > n) return false;
    for (size_t k = 1; k < len; k++)
      if (!utf8_continuation(s[i + k])) return false;
    i += len;
  }
  return true;
}

/* A 125 KB one-line program: the diagnostic shows a window of the line
 * around the column with its cuts marked "…", whole UTF-8 characters, the
 * caret under the right character. */
static void test_long_line_window(void **state) {
  (void)state;
  struct {
    int before;          /* blanks before the fault */
    const char *fault;   /* what the diagnostic is about */
    int after;           /* blanks after it */
    const char *comment; /* a comment of 30,000 of these after the line, or none */
    const char *expect;
    int cuts;            /* "…" marks expected */
  } cases[] = {
      {0, "nosuch", 0, NULL, "unknown name 'nosuch'", 0},           /* short: the whole line */
      {0, "nosuch", 0, "ab", "unknown name 'nosuch'", 1},           /* at the start of a long line */
      {60000, "nosuch", 60000, NULL, "unknown name 'nosuch'", 2},   /* in the middle */
      {120000, "nosuch", 0, NULL, "unknown name 'nosuch'", 1},      /* at the end */
      {0, "nosuch", 0, "é", "unknown name 'nosuch'", 1},            /* a cut among multibyte characters */
      {60000, "é", 0, "é", "", 2},                                  /* the fault is a multibyte character */
  };
  for (size_t c = 0; c < sizeof cases / sizeof *cases; c++) {
    size_t cap = 256 + (size_t)cases[c].before + (size_t)cases[c].after + 30000 * 4, len = 0;
    char *text = malloc(cap);
    assert_non_null(text);
    len += (size_t)snprintf(text + len, cap - len, "input x : real[2]\noutput y = x[0] + %*s%s%*s + x[1]",
                            cases[c].before, "", cases[c].fault, cases[c].after, "");
    if (cases[c].comment) {
      len += (size_t)snprintf(text + len, cap - len, " #");
      for (int i = 0; i < 30000; i++) len += (size_t)snprintf(text + len, cap - len, "%s", cases[c].comment);
    }
    len += (size_t)snprintf(text + len, cap - len, "\n");
    const char *path = write_temp(text);
    NpgProgram *p = compile(path);
    assert_false(npg_ok(p));
    const char *err = npg_error(p);
    const char *why = caret_problem(err, text);
    if (why) fail_msg("case %zu: %s:\n%.2000s", c, why, err);
    if (!strstr(err, cases[c].expect)) fail_msg("case %zu: no '%s' in\n%.2000s", c, cases[c].expect, err);
    int cuts = 0;
    for (const char *q = err; (q = strstr(q, "…")); q++) cuts++;
    if (cuts != cases[c].cuts) fail_msg("case %zu: %d cut marks, expected %d:\n%.2000s", c, cuts, cases[c].cuts, err);
    if (strlen(err) > 400) fail_msg("case %zu: a diagnostic of %zu bytes", c, strlen(err));
    if (!whole_utf8(err, strlen(err))) fail_msg("case %zu: a character cut in two:\n%s", c, err);
    npg_free(p);
    unlink(path);
    free(text);
  }
}

/* Old Mac line endings (CR alone): the diagnostic echoes the line it names,
 * not the first line of the file, and the caret stands under the fault. The
 * CRLF case is tests/bad/crlf_unknown_name.npg. (issue 24) */
static void test_cr_only_caret(void **state) {
  (void)state;
  const char *path = write_temp("# c\rinput x : real[2]\routput y = [x[0] * q, x[1]]\r");
  NpgProgram *p = compile(path);
  assert_false(npg_ok(p));
  const char *err = npg_error(p);
  const char *nl = strchr(err, '\n');
  assert_non_null(nl);
  if (strncmp(nl + 1, "output y = [x[0] * q, x[1]]\n                   ^\n", 48) != 0)
    fail_msg("wrong echo or caret:\n%s", err);
  assert_non_null(strstr(err, ":3:20: error: unknown name 'q'"));
  npg_free(p);
  unlink(path);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_bad_programs_fail_as_expected),
      cmocka_unit_test(test_good_programs_compile),
      cmocka_unit_test(test_long_line_window),
      cmocka_unit_test(test_cr_only_caret),
  };
  return cmocka_run_group_tests(tests, enter_source_dir, NULL);
}
