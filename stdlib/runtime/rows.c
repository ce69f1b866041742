/* rows.c — the row kernels of NpgRt (npg_abi.h): elementwise operations
 * over one row of a loop nest, which libtcc code calls in place of its
 * innermost loop (backends/emit/cse.c, cse_emit_rows).
 *
 * CMake compiles this file at -O3 with -ffp-contract=off: -O3 so that gcc
 * vectorizes the loops (baseline SSE2, no -march=native: the library runs
 * where it was built and elsewhere; wider copies are chosen at load
 * time), no contraction so that a*b + c stays
 * two roundings, as in the scalar C the kernels replace. `restrict` is the
 * ABI's promise that `out` overlaps no input: no runtime alias checks. */
#include "runtime.h"

/* Where the ISA has wider vectors, a copy of each kernel for them, chosen
 * when the library is loaded (the build machine's ISA is not assumed). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROW_KERNEL __attribute__((target_clones("avx2", "default")))
#else
#define ROW_KERNEL
#endif

#define ROW_LOOP(expr)                                                                                                 \
  for (npg_idx k = 0; k < n; k++) out[k] = (expr)

ROW_KERNEL void rows_vv(npg_idx n, NpgRowOp op, const double *restrict x, const double *restrict y, double *restrict out) {
  switch (op) {
  case NPG_ROW_ADD: ROW_LOOP(x[k] + y[k]); break;
  case NPG_ROW_SUB: ROW_LOOP(x[k] - y[k]); break;
  case NPG_ROW_MUL: ROW_LOOP(x[k] * y[k]); break;
  case NPG_ROW_DIV: ROW_LOOP(x[k] / y[k]); break;
  default: break;
  }
}

ROW_KERNEL void rows_vs(npg_idx n, NpgRowOp op, const double *restrict x, double s, double *restrict out) {
  switch (op) {
  case NPG_ROW_ADD: ROW_LOOP(x[k] + s); break;
  case NPG_ROW_SUB: ROW_LOOP(x[k] - s); break;
  case NPG_ROW_MUL: ROW_LOOP(x[k] * s); break;
  case NPG_ROW_DIV: ROW_LOOP(x[k] / s); break;
  default: break;
  }
}

ROW_KERNEL void rows_sv(npg_idx n, NpgRowOp op, double s, const double *restrict y, double *restrict out) {
  switch (op) {
  case NPG_ROW_ADD: ROW_LOOP(s + y[k]); break;
  case NPG_ROW_SUB: ROW_LOOP(s - y[k]); break;
  case NPG_ROW_MUL: ROW_LOOP(s * y[k]); break;
  case NPG_ROW_DIV: ROW_LOOP(s / y[k]); break;
  default: break;
  }
}

ROW_KERNEL void rows_unary(npg_idx n, NpgRowOp op, const double *restrict x, double *restrict out) {
  switch (op) {
  case NPG_ROW_NEG: ROW_LOOP(-x[k]); break;
  case NPG_ROW_COPY: ROW_LOOP(x[k]); break;
  default: break;
  }
}

ROW_KERNEL void rows_fill(npg_idx n, double s, double *restrict out) { ROW_LOOP(s); }
