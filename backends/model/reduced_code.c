/* reduced_code.c — a model described for the reduced emitter (ReducedCode,
 * backends/emit/emit_reduced.c): its stages' terms, operators and tensors
 * with their shapes and NpgReducedCtx.t slots, its classes and quantities'
 * basis sizes; and that slot order, which reduced_jit.c passes the tensors in. */
#include <stdlib.h>

#include "emit.h"
#include "reduced.h"
#include "scratch.h"

long emit_reduced_slots(const Model *m, ReducedSlot *s) {
  long n = 0;
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    long my = m->classes[m->qclass[rs->q]].m;
    for (int t = 0; t < rs->nterms; t++) {
      const RTerm *rt = &rs->terms[t];
      if (rt->named_q >= 0 && rt->proj) {
        if (s) s[n] = (ReducedSlot){NULL, rt, my, m->classes[m->qclass[rt->named_q]].m, rt->proj};
        n++;
      }
      RTERM_FOR_TENSORS(rt, x) {
        if (s) s[n] = (ReducedSlot){x, NULL, x->rows, x->cols, x->data};
        n++;
      }
    }
  }
  return n;
}

_Static_assert(RT_MAX_IN <= RC_MAX_IN, "the emitter takes every input of a reduced tensor");

/* The description's arrays, from the scratch `mem` of the emission. */
typedef struct Code {
  ReducedCode rc;
  RcStage *stages;
  RcTerm *terms;
  RcOp *ops;
  RcTensor *tensors;
  RcClass *classes;
  RcSlot *slots;
  long *qm;
  Scratch *mem;
} Code;

/* Tensor `x` into `*next`, its slot the next one. */
static void tensor(RcTensor **next, const RTensor *x, long *slot) {
  *(*next)++ = (RcTensor){x->name, x->rows, x->cols, (*slot)++, x->nin, x->in_q, x->in_mult, x->in_len};
}

/* Term `rt` into `*t`, its tensors and operators taken from `c`'s arrays at
 * *nt and *no, its slots from *slot (emit_reduced_slots' order). */
static void term(Code *c, const RTerm *rt, RcTerm *t, long at[3]) {
  long *nt = &at[0], *no = &at[1], *slot = &at[2];
  RcTensor *next = c->tensors + *nt;
  *t = (RcTerm){.named_q = rt->named_q, .proj_slot = -1, .nnum = rt->nnum, .num = next, .nops = rt->nops};
  if (rt->named_q >= 0 && rt->proj) t->proj_slot = (*slot)++;
  for (int g = 0; g < rt->nnum; g++) tensor(&next, &rt->num[g], slot);
  t->ops = c->ops + *no;
  for (int k = 0; k < rt->nops; k++) {
    const ROp *ro = &rt->ops[k];
    c->ops[*no + k] = (RcOp){ro->op, ro->spd, ro->ntensors, next};
    for (int g = 0; g < ro->ntensors; g++) tensor(&next, &ro->t[g], slot);
  }
  *no += rt->nops;
  *nt = next - c->tensors;
}

/* `m` described into `c`. 0, or -1 out of memory. */
static int describe(const Model *m, Code *c) {
  long nterms = 0, nops = 0, ntensors = 0, nslots = emit_reduced_slots(m, NULL);
  for (int i = 0; i < m->nstages; i++) nterms += m->stages[i].nterms;
  for (int i = 0; i < m->nstages; i++)
    for (int t = 0; t < m->stages[i].nterms; t++) {
      const RTerm *rt = &m->stages[i].terms[t];
      nops += rt->nops;
      RTERM_FOR_TENSORS(rt, x) ntensors++;
    }
  c->stages = scratch_array(c->mem, (size_t)m->nstages + 1, sizeof *c->stages);
  c->terms = scratch_array(c->mem, (size_t)nterms + 1, sizeof *c->terms);
  c->ops = scratch_array(c->mem, (size_t)nops + 1, sizeof *c->ops);
  c->tensors = scratch_array(c->mem, (size_t)ntensors + 1, sizeof *c->tensors);
  c->classes = scratch_array(c->mem, (size_t)m->nclasses + 1, sizeof *c->classes);
  c->slots = scratch_array(c->mem, (size_t)nslots + 1, sizeof *c->slots);
  c->qm = scratch_array(c->mem, (size_t)m->nq + 1, sizeof *c->qm);
  ReducedSlot *slots = scratch_array(c->mem, (size_t)nslots + 1, sizeof *slots);
  if (!c->stages || !c->terms || !c->ops || !c->tensors || !c->classes || !c->slots || !c->qm || !slots) return -1;
  for (int k = 0; k < m->nclasses; k++)
    c->classes[k] = (RcClass){m->classes[k].label, m->classes[k].n, m->classes[k].m};
  for (int q = 0; q < m->nq; q++) c->qm[q] = m->classes[m->qclass[q]].m;
  emit_reduced_slots(m, slots);
  for (long k = 0; k < nslots; k++) {
    const RTerm *p = slots[k].proj_of;
    c->slots[k] = (RcSlot){slots[k].t ? slots[k].t->name : p->proj_name ? p->proj_name : "proj", slots[k].rows,
                           slots[k].cols};
  }
  long at[3] = {0, 0, 0}, t0 = 0; /* tensors, operators, slots taken */
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    c->stages[i] = (RcStage){rs->st, rs->q, m->qclass[rs->q], rs->interp != NULL, rs->nterms, c->terms + t0};
    for (int t = 0; t < rs->nterms; t++) term(c, &rs->terms[t], &c->terms[t0 + t], at);
    t0 += rs->nterms;
  }
  c->rc = (ReducedCode){m->prog, m->samples, m->program_hash, m->nclasses, c->classes, m->nq, c->qm, nslots,
                        c->slots, m->nstages, c->stages};
  return 0;
}

int emit_reduced(const Model *m, FILE *out, Err *err) {
  Scratch sc = SCRATCH_OF(NULL);
  Code c = {.mem = &sc};
  int rc = describe(m, &c) ? err_set(err, "out of memory while generating the reduced evaluator")
                           : emit_reduced_code(&c.rc, out, err);
  scratch_release(&sc);
  return rc;
}
