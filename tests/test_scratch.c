/* test_scratch.c — backends/model/scratch.c: a model-layer operation's temporary memory.
 * Blocks are zeroed and distinct, a refused allocation is NULL with "out of memory" in the
 * scratch's error record (the blocks before it still released), an overflowing size is
 * refused without an allocation (unzeroed blocks too), an adopted block is the scratch's (freed with it, or at once
 * when the scratch cannot hold it), a formatted string is the scratch's (NULL with "out of memory"
 * when refused), and release empties the scratch (the sanitizers' leak check
 * is the oracle that it freed every block). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "support/failing_alloc.h"
#include "scratch.h"

static int teardown(void **state) {
  (void)state;
  failing_alloc_off();
  return 0;
}

static void zeroed_and_distinct(void **state) {
  (void)state;
  Scratch sc = SCRATCH_OF(NULL);
  unsigned char *p[8];
  for (int k = 0; k < 8; k++) {
    size_t n = (size_t)1 << (2 * k);
    p[k] = scratch_alloc(&sc, n);
    assert_non_null(p[k]);
    assert_int_equal((uintptr_t)p[k] % _Alignof(max_align_t), 0);
    for (size_t j = 0; j < n; j++) assert_int_equal(p[k][j], 0);
    memset(p[k], 0xa0 + k, n);
  }
  for (int k = 0; k < 8; k++) /* no block overwrote another */
    for (size_t j = 0; j < ((size_t)1 << (2 * k)); j++) assert_int_equal(p[k][j], 0xa0 + k);
  double *d = scratch_array(&sc, 100, sizeof(double));
  assert_non_null(d);
  assert_true(d[99] == 0);
  double *u = scratch_array_unzeroed(&sc, 100, sizeof(double)); /* a block of its own, not zeroed */
  assert_non_null(u);
  assert_int_equal((uintptr_t)u % _Alignof(max_align_t), 0);
  for (int i = 0; i < 100; i++) u[i] = i;
  assert_true(d[99] == 0 && u[99] == 99);
  scratch_release(&sc);
  assert_null(sc.head);
  assert_non_null(scratch_alloc(&sc, 0)); /* usable again, and a zero size is a block too */
  scratch_release(&sc);
}

static void refused(void **state) {
  (void)state;
  char msg[128] = "";
  Scratch sc = SCRATCH_OF(ERR_OF(msg, sizeof msg));
  failing_alloc_after(2);
  assert_non_null(scratch_alloc(&sc, 16));
  assert_non_null(scratch_array(&sc, 4, 8));
  assert_null(scratch_alloc(&sc, 24));
  failing_alloc_off();
  assert_non_null(strstr(msg, "out of memory"));
  assert_non_null(strstr(msg, "24 bytes"));
  scratch_release(&sc);
  assert_null(sc.head);
}

static void overflow(void **state) {
  (void)state;
  char msg[128] = "";
  Scratch sc = SCRATCH_OF(ERR_OF(msg, sizeof msg));
  failing_alloc_after(0); /* an overflowing size must not reach the allocator at all */
  assert_null(scratch_array(&sc, SIZE_MAX / 2, 4));
  assert_null(scratch_alloc(&sc, SIZE_MAX - 4));
  assert_int_equal(failing_alloc_calls(), 0);
  failing_alloc_off();
  assert_non_null(strstr(msg, "out of memory"));
  failing_alloc_after(0);
  assert_null(scratch_array_unzeroed(&sc, SIZE_MAX / 2, 4));
  assert_int_equal(failing_alloc_calls(), 0);
  failing_alloc_off();
  Scratch quiet = SCRATCH_OF(NULL); /* no record: the message is dropped, NULL still returned */
  assert_null(scratch_array(&quiet, SIZE_MAX, SIZE_MAX));
  scratch_release(&sc);
}

static void adopted(void **state) {
  (void)state;
  char msg[128] = "";
  Scratch sc = SCRATCH_OF(ERR_OF(msg, sizeof msg));
  assert_null(scratch_adopt(&sc, NULL)); /* a maker's failure passes through, no message added */
  assert_string_equal(msg, "");
  char *s = mem_strdup("kept until release");
  assert_ptr_equal(scratch_adopt(&sc, s), s);
  assert_string_equal(s, "kept until release");
  char *lost = mem_strdup("freed at once");
  failing_alloc_after(0);
  assert_null(scratch_adopt(&sc, lost)); /* freed: the leak check says so */
  failing_alloc_off();
  assert_non_null(strstr(msg, "out of memory"));
  scratch_release(&sc);
  assert_null(sc.head);
}

/* scratch_keep: an adopted pointer handed back survives the release (the leak check would
 * catch a double free or a leak); one not adopted, or NULL, changes nothing. */
static void kept(void **state) {
  (void)state;
  Scratch sc = SCRATCH_OF(NULL);
  char *out = scratch_adopt(&sc, mem_strdup("the operation's result"));
  char *tmp = scratch_adopt(&sc, mem_strdup("a temporary"));
  char *stranger = mem_strdup("never adopted");
  assert_ptr_equal(scratch_keep(&sc, out), out);
  assert_ptr_equal(scratch_keep(&sc, stranger), stranger);
  assert_null(scratch_keep(&sc, NULL));
  assert_non_null(tmp);
  scratch_release(&sc); /* frees tmp, not out */
  assert_string_equal(out, "the operation's result");
  free(out);
  free(stranger);
}

static void printed(void **state) {
  (void)state;
  char msg[128] = "";
  Scratch sc = SCRATCH_OF(ERR_OF(msg, sizeof msg));
  char *path = scratch_printf(&sc, "%s/%s.npy", "MODEL", "basis_u");
  assert_string_equal(path, "MODEL/basis_u.npy");
  assert_string_equal(scratch_printf(&sc, "%s", ""), "");
  assert_string_equal(msg, "");
  failing_alloc_after(0);
  assert_null(scratch_printf(&sc, "%s/manifest", "MODEL"));
  failing_alloc_off();
  assert_non_null(strstr(msg, "out of memory"));
  assert_string_equal(path, "MODEL/basis_u.npy"); /* a refusal leaves the blocks before it */
  scratch_release(&sc);
  assert_null(sc.head);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test_teardown(zeroed_and_distinct, teardown),
      cmocka_unit_test_teardown(refused, teardown),
      cmocka_unit_test_teardown(overflow, teardown),
      cmocka_unit_test_teardown(adopted, teardown),
      cmocka_unit_test_teardown(kept, teardown),
      cmocka_unit_test_teardown(printed, teardown),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
