/* test_lower.c — the canonical form of the paper's programs (DESIGN §4,
 * paper §4.1 and Table 2), and of the splitting rules. */
#include "support/failing_alloc.h"
#include "testutil.h"

/* Paper §4.1, Eq. 3: one inverse term; the denominator [x0^2, x1^2] folded
 * into an order-4 operator tensor (row, col, x, x); an order-3 unnamed
 * numerator whose snapshots join y's class (B_n = B_y). */
static void eq3_structure(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/rational/rational.npg");
  Program *prog = ir_ok(p);
  const Stage *y = find_stage(prog, "y");
  assert_int_equal(y->kind, ST_INVERSE);
  assert_int_equal(y->nterms, 1);
  const Term *t = y->terms[0];
  assert_int_equal(t->nops, 1);
  assert_int_equal(t->ops[0].kind, OPK_DIAG);
  assert_int_equal(t->ops[0].p, -1);
  assert_int_equal(t->ops[0].q, 1);
  const TensorList *op = &t->op_tensors[0];
  assert_int_equal(op->n, 1);
  assert_int_equal(op->g[0].order, 4);
  assert_int_equal(op->g[0].ninputs, 2);
  assert_string_equal(op->g[0].inputs[0]->name, "x");
  assert_string_equal(op->g[0].inputs[1]->name, "x");
  assert_true(op->g[0].symmetric);
  assert_null(t->named_num);
  assert_int_equal(t->num_tensors.n, 1);
  assert_int_equal(t->num_tensors.g[0].order, 3);
  assert_int_equal(t->num_tensors.g[0].nmono, 3); /* x0 x1 + x1^2, x0^2 */
  /* Classes: {x}, {y}; y's class receives the numerator's snapshots. */
  assert_int_equal(prog->classes.n, 2);
  assert_int_equal(prog->merges.n, 0);
  char buf[128];
  assert_string_equal(class_of(prog, "x", buf, sizeof buf), "x");
  assert_string_equal(class_of(prog, "y", buf, sizeof buf), "y");
  const BasisClass *cy = prog->classes.v[find_quantity(prog, "y")->klass];
  assert_int_equal(cy->joiners.n, 1);
  assert_ptr_equal(((Joiner *)cy->joiners.v[0])->stage, y);
  npg_free(p);
}

/* Paper Table 2: the classes {h, s}, {p, d}, {b, e} and no other merge;
 * every tensor of order 3. Difference from the paper, by the language's
 * folding: r = if(i == j, 1, dist2(...)) also has an order-1 constant
 * vector (the i == j entries), and the operator I - E p of the final row is
 * a constant order-2 identity plus the order-3 E. */
static void radiosity_structure(void **state) {
  (void)state;
  NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
  Program *prog = ir_ok(p);
  char buf[128];
  assert_string_equal(class_of(prog, "h", buf, sizeof buf), "h,s");
  assert_string_equal(class_of(prog, "p", buf, sizeof buf), "d,p");
  assert_string_equal(class_of(prog, "b", buf, sizeof buf), "b,e");
  const char *single[] = {"g", "n", "r", "c", "v", "a"};
  for (size_t i = 0; i < sizeof single / sizeof *single; i++)
    assert_string_equal(class_of(prog, single[i], buf, sizeof buf), single[i]);
  assert_int_equal(prog->classes.n, 9); /* the paper's 9 bases (12 listed, 3 merged) */
  assert_int_equal(prog->merges.n, 3);
  for (int i = 0; i < prog->merges.n; i++) {
    const Merge *m = prog->merges.v[i];
    const char *rule = strcmp(m->a->name, "p") == 0 ? "root" : "inverse";
    if (!strstr(m->reason, rule)) fail_msg("merge %s/%s: reason '%s' does not name the %s rule", m->a->name, m->b->name, m->reason, rule);
  }
  struct { const char *stage; StageKind kind; int order; } rows[] = {
      {"n", ST_CONTRACT, 3}, {"s", ST_CONTRACT, 3}, {"r", ST_CONTRACT, 3}, {"h", ST_INVERSE, 3},
      {"c", ST_CONTRACT, 3}, {"d", ST_CONTRACT, 3}, {"a", ST_CONTRACT, 3}, {"p", ST_ROOT, 3},
      {"b", ST_INVERSE, 3},
  };
  for (size_t i = 0; i < sizeof rows / sizeof *rows; i++) {
    const Stage *st = find_stage(prog, rows[i].stage);
    if (st->kind != rows[i].kind) fail_msg("stage %s: kind %s", rows[i].stage, stage_kind_name[st->kind]);
    if (max_order(prog, st) != rows[i].order)
      fail_msg("stage %s: tensor order %d, expected %d", rows[i].stage, max_order(prog, st), rows[i].order);
  }
  assert_int_equal(find_stage(prog, "v")->kind, ST_EXTERN);
  /* h = diag(r)^-1 s: operator tensor (row, col, r); numerator is s itself. */
  const Term *h = find_stage(prog, "h")->terms[0];
  assert_string_equal(h->named_num->name, "s");
  assert_string_equal(h->op_tensors[0].g[0].inputs[0]->name, "r");
  /* p = diag(a)^(-1/2) d */
  const Term *pt = find_stage(prog, "p")->terms[0];
  assert_int_equal(pt->ops[0].p, -1);
  assert_int_equal(pt->ops[0].q, 2);
  assert_string_equal(pt->named_num->name, "d");
  /* s reads n and g once each (S: order 3, Table 2). */
  const TensorGroup *sg = &find_stage(prog, "s")->terms[0]->num_tensors.g[0];
  assert_int_equal(sg->ninputs, 2);
  assert_false(sg->symmetric);
  npg_free(p);
}

/* [a/b, c] = diag([b, 1])^-1 [a, 0] + [0, c]; [a/b, c/d] is one term with
 * the diagonal [b, d]. */
static void vector_split(void **state) {
  (void)state;
  NpgProgram *p = compile_text("v.npg",
                               "input x : real[4]\n"
                               "output y = [x[0] / x[1], x[2]]\n"
                               "output z = [x[0] / x[1], x[2] / x[3]]\n");
  Program *prog = ir_ok(p);
  const Stage *y = find_stage(prog, "y");
  assert_int_equal(y->nterms, 2);
  const Term *inv = y->terms[0]->nops ? y->terms[0] : y->terms[1];
  const Term *poly = y->terms[0]->nops ? y->terms[1] : y->terms[0];
  assert_int_equal(inv->nops, 1);
  assert_int_equal(poly->nops, 0);
  assert_int_equal(inv->ops[0].diag->comp[1].n, 1);          /* identity where it does not apply */
  assert_int_equal(inv->ops[0].diag->comp[1].m[0]->natoms, 0);
  assert_int_equal(inv->num->comp[1].n, 0);                   /* [a, 0] */
  assert_int_equal(poly->num->comp[0].n, 0);                  /* [0, c] */
  const Stage *z = find_stage(prog, "z");
  assert_int_equal(z->nterms, 1);
  assert_int_equal(z->terms[0]->nops, 1);
  npg_free(p);
}

/* 1/(a + 1/b): the divisor is not one polynomial term, so a stage y.t1 is
 * introduced for it and reported. */
static void nested_division_introduces_stage(void **state) {
  (void)state;
  NpgProgram *p = compile_text("n.npg",
                               "input x : real[2]\n"
                               "output y = 1 / (x[0] + 1 / x[1])\n");
  Program *prog = ir_ok(p);
  const Stage *t1 = find_stage(prog, "y.t1");
  assert_true(t1->sym->introduced);
  assert_int_equal(t1->kind, ST_INVERSE);
  assert_int_equal(t1->nterms, 2);  /* x0 + diag(x1)^-1 1: one stage, two terms */
  const Stage *y = find_stage(prog, "y");
  assert_int_equal(y->kind, ST_INVERSE);
  assert_string_equal(y->terms[0]->op_tensors[0].g[0].inputs[0]->name, "y.t1");
  assert_int_equal(prog->notes.n, 1);
  assert_non_null(strstr(prog->notes.v[0], "y.t1"));
  npg_free(p);
}

/* if() with a division in one branch: the operator is the identity where
 * the condition is false. A spring force k d - k L0 l2^(-1/2) d is one
 * stage of two terms (DESIGN §4). */
static void if_and_spring(void **state) {
  (void)state;
  NpgProgram *p = compile_text("s.npg",
                               "dim E\n"
                               "param k : real[E]\n"
                               "param L0 : real[E]\n"
                               "input d : real[E, 3]\n"
                               "l2[e:E] = d[e,0]^2 + d[e,1]^2 + d[e,2]^2\n"
                               "output f[e:E] = k[e] * d[e] - k[e] * L0[e] * l2[e]^(-1/2) * d[e]\n"
                               "output q[e:E] = if(e == 0, d[e,0] / l2[e], d[e,1])\n");
  Program *prog = ir_ok(p);
  const Stage *f = find_stage(prog, "f");
  assert_int_equal(f->kind, ST_ROOT);
  assert_int_equal(f->nterms, 2);
  const Stage *q = find_stage(prog, "q");
  assert_int_equal(q->nterms, 2);
  assert_int_equal(q->kind, ST_INVERSE);
  npg_free(p);
}

/* `inline c` folds a linear stage into its consumers: no basis, no stage. */
static void inline_linear(void **state) {
  (void)state;
  NpgProgram *p = compile_text("i.npg",
                               "dim V\n"
                               "input g : real[V]\n"
                               "c[v:V] = 2 * g[v]\n"
                               "inline c\n"
                               "output y[v:V] = c[v] * c[v]\n");
  Program *prog = ir_ok(p);
  assert_int_equal(prog->stages.n, 1);
  const Stage *y = find_stage(prog, "y");
  assert_string_equal(y->terms[0]->num_tensors.g[0].inputs[0]->name, "g");
  assert_int_equal(y->terms[0]->num_tensors.g[0].order, 3);
  npg_free(p);
}

/* share merges with its reason; a declared operator applied with M * x
 * merges its operand with the result. */
static void share_and_apply(void **state) {
  (void)state;
  NpgProgram *p = compile_text("a.npg",
                               "dim C\n"
                               "param L : real[C, C]\n"
                               "input u : real[C]\n"
                               "input w : real[C]\n"
                               "op A[i:C, j:C] = L[i, j]\n"
                               "output y = A * u\n"
                               "share w, y\n");
  Program *prog = ir_ok(p);
  char buf[64];
  assert_string_equal(class_of(prog, "y", buf, sizeof buf), "u,w,y");
  assert_int_equal(find_stage(prog, "y")->kind, ST_APPLY);
  assert_int_equal(prog->merges.n, 2);
  npg_free(p);
}

/* Sums with dim bounds stay symbolic; literal bounds are unrolled; like
 * monomials are combined. */
static void sums(void **state) {
  (void)state;
  NpgProgram *p = compile_text("m.npg",
                               "dim N\n"
                               "param K : real[N, N]\n"
                               "input x : real[N]\n"
                               "output y[i:N] = sum(j = 0..N-1, K[i,j] * x[j])\n"
                               "output z[i:N] = sum(k = 0..2, x[i]^2)\n");
  Program *prog = ir_ok(p);
  const Stage *y = find_stage(prog, "y");
  assert_int_equal(y->terms[0]->num->comp[0].n, 1);
  assert_int_equal(y->terms[0]->num->comp[0].m[0]->nsums, 1);
  assert_string_equal(y->terms[0]->num_tensors.g[0].nnz, "N^2");
  /* unrolled into three equal monomials, combined into 3 x[i]^2 */
  const Stage *z = find_stage(prog, "z");
  assert_int_equal(z->terms[0]->num->comp[0].n, 1);
  assert_true(z->terms[0]->num->comp[0].m[0]->coef->kind == N_NUM);
  assert_true(z->terms[0]->num->comp[0].m[0]->coef->num == 3);
  npg_free(p);
}

/* Every reachable allocation failure is reported as an error, never a crash
 * (and, under the sanitizers, never a leak). */
static void allocation_failure(void **state) {
  (void)state;
  for (int k = 0; k < 200; k++) {
    failing_alloc_after(k);
    NpgProgram *p = compile_file("examples/radiosity/formfactors.npg");
    failing_alloc_off();
    if (npg_ok(p)) {
      npg_free(p);
      assert_true(k > 0); /* the compilation allocates, and every failure before was reported */
      return;
    }
    assert_non_null(strstr(npg_error(p), "out of memory"));
    npg_free(p);
  }
  fail_msg("the compilation still fails with 200 allocations allowed");
}

/* Programs as test data: every .npg file in tests/programs states its expected
 * classes ("# expect-class: {a, b}"), stage kinds ("# expect-kind: y
 * inverse"), the nonzero counts of declared operators ("# expect-nnz: K N;
 * ≤ 8·N") and, optionally, the stages eligible for interpolation ("#
 * expect-interp: w" or "none"); all are checked here, and every class must
 * be listed. */
#include <dirent.h>
#include <stdio.h>

static int check_expectations(const char *path) {
  FILE *f = fopen(path, "r");
  if (!f) fail_msg("cannot read %s", path);
  NpgProgram *p = compile_file(path);
  Program *prog = ir_ok(p);
  int failures = 0, nclass = 0;
  char line[1024];
  while (fgets(line, sizeof line, f)) {
    char *nl = strchr(line, '\n');
    if (nl) *nl = 0;
    if (strncmp(line, "# expect-class: {", 17) == 0) {
      char want[512] = "", *q = line + 17, *end = strchr(q, '}');
      if (!end) continue;
      *end = 0;
      /* sorted, comma separated, no spaces */
      char *names[32];
      int n = 0;
      for (char *tok = strtok(q, ", "); tok && n < 32; tok = strtok(NULL, ", ")) names[n++] = tok;
      if (n == 0) continue;
      for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++)
          if (strcmp(names[j], names[i]) < 0) {
            char *t = names[i];
            names[i] = names[j];
            names[j] = t;
          }
      for (int i = 0; i < n; i++) {
        strcat(want, names[i]);
        if (i + 1 < n) strcat(want, ",");
      }
      char got[512];
      class_of(prog, names[0], got, sizeof got);
      if (strcmp(got, want) != 0) {
        print_message("%s: class of %s is {%s}, expected {%s}\n", path, names[0], got, want);
        failures++;
      }
      nclass++;
    } else if (strncmp(line, "# expect-nnz: ", 14) == 0) {
      /* "# expect-nnz: K N; ≤ 8·N": the nonzero counts of declared op K's
         tensors, in order, "≤ " where the count is an upper bound */
      char name[128];
      if (sscanf(line + 14, "%127s", name) != 1) continue;
      const char *want = line + 14 + strlen(name);
      while (*want == ' ') want++;
      char got[512] = "";
      bool found = false;
      for (int i = 0; i < prog->opdefs.n; i++) {
        const OpDef *od = prog->opdefs.v[i];
        if (strcmp(od->sym->name, name) != 0) continue;
        found = true;
        for (int g = 0; g < od->tensors.n; g++)
          snprintf(got + strlen(got), sizeof got - strlen(got), "%s%s%s", g ? "; " : "",
                   od->tensors.g[g].nnz_bound ? "≤ " : "", od->tensors.g[g].nnz);
      }
      if (!found || strcmp(got, want) != 0) {
        print_message("%s: nnz of op %s is '%s', expected '%s'\n", path, name, found ? got : "(no such op)", want);
        failures++;
      }
    } else if (strncmp(line, "# expect-interp: ", 17) == 0) {
      /* the stages eligible for interpolation, in evaluation order, or "none" */
      char got[512] = "";
      for (int i = 0; i < prog->stages.n; i++) {
        const Stage *st = prog->stages.v[i];
        if (!lower_interp_eligible(st)) continue;
        if (got[0]) strcat(got, ", ");
        strncat(got, st->sym->name, sizeof got - strlen(got) - 3);
      }
      if (strcmp(got[0] ? got : "none", line + 17) != 0) {
        print_message("%s: stages eligible for interpolation: %s, expected %s\n", path, got[0] ? got : "none",
                      line + 17);
        failures++;
      }
    } else if (strncmp(line, "# expect-kind: ", 15) == 0) {
      char name[128];
      const char *kind = NULL;
      if (sscanf(line + 15, "%127s", name) != 1) continue;
      kind = line + 15 + strlen(name);
      while (*kind == ' ') kind++;
      const Stage *st = find_stage(prog, name);
      if (strcmp(stage_kind_name[st->kind], kind) != 0) {
        print_message("%s: stage %s is %s, expected %s\n", path, name, stage_kind_name[st->kind], kind);
        failures++;
      }
    }
  }
  if (nclass && nclass != prog->classes.n) {
    print_message("%s: %d classes, but %d are listed\n", path, prog->classes.n, nclass);
    failures++;
  }
  fclose(f);
  npg_free(p);
  return failures;
}

static int expectations_cb(const char *path, void *arg) {
  (void)arg;
  return check_expectations(path);
}

static void programs_carry_expectations(void **state) {
  (void)state;
  int n = 0;
  int failures = for_each_program("tests/programs", expectations_cb, NULL, &n);
  assert_true(n >= 12);
  assert_int_equal(failures, 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(eq3_structure),
      cmocka_unit_test(radiosity_structure),
      cmocka_unit_test(vector_split),
      cmocka_unit_test(nested_division_introduces_stage),
      cmocka_unit_test(if_and_spring),
      cmocka_unit_test(inline_linear),
      cmocka_unit_test(share_and_apply),
      cmocka_unit_test(sums),
      cmocka_unit_test(allocation_failure),
      cmocka_unit_test(programs_carry_expectations),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
