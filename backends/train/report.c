/* report.c — what training and verification tell the user about the bases
 * (DESIGN §5, §7): per member the vectors kept against the cap and the
 * energy lost, in scientific notation (0.999990 cannot tell 1 − 1e-5 from
 * 1 − 1e-9), and the warnings that say what to change. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "interp.h"
#include "train.h"

/* A member that hits its cap with more than this fraction of its energy
 * lost: the cap, not the energy fraction, decided its size. */
#define REPORT_CAP_LOST 1e-3

void report_training(const Model *m, FILE *out) {
  fprintf(out, "%-24s %8s %6s  %s\n", "class", "n", "m",
          "members: kept / cap, energy lost (of the centered energy when centered)");
  for (int c = 0; c < m->nclasses; c++) {
    const RClass *rc = &m->classes[c];
    fprintf(out, "%-24s %8ld %6ld ", rc->label, rc->n, rc->m);
    for (int i = 0; i < rc->nmembers; i++) {
      const RMember *mb = &rc->members[i];
      fprintf(out, "%s %s %d/%d lost %.1e%s", i ? "," : "", mb->name, mb->kept, mb->cap, mb->lost,
              mb->center ? "" : " (uncentered)");
    }
    fputc('\n', out);
  }
  for (int c = 0; c < m->nclasses; c++)
    for (int i = 0; i < m->classes[c].nmembers; i++) {
      const RMember *mb = &m->classes[c].members[i];
      const Sym *s = mb->q >= 0 ? m->prog->quantities.v[mb->q] : NULL;
      if (s && s->state_of && s->state_of->residual == s && mb->cap == 1) continue; /* train.c: rounding */
      if (mb->kept >= mb->cap && mb->lost > REPORT_CAP_LOST)
        fprintf(out,
                "warning: %s (class %s) hit its cap %d with %.1e of its %senergy lost: raise it (--basis %s:cap=N) "
                "or accept the loss\n",
                mb->name, m->classes[c].label, mb->cap, mb->lost, mb->center ? "centered " : "", mb->name);
    }
  interp_report(m, out); /* DESIGN §12: how each eligible stage is reduced, and why */
  if (m->self_check_failure[0]) /* train.c self_check: never quietly (issue 38) */
    fprintf(out, "warning: the reduced model fails on training sample %ld, one it was trained on: %s; it will fail on "
                 "inputs like it: give what that stage reads larger bases (--basis NAME:cap=N,energy=E), or let "
                 "training choose its reduction on held-out samples (--valid F or DIR)\n",
            m->self_check_sample, m->self_check_failure);
  size_t tb, total = model_bytes(m, &tb);
  fprintf(out, "reduced tensors: %.3f MB; model with bases: %.3f MB\n", (double)tb / 1e6, (double)total / 1e6);
  double dropped = 0;
  char names[512] = "";
  size_t len = 0;
  for (int c = 0; c < m->nclasses; c++)
    if (m->classes[c].streamed) {
      dropped += 8.0 * (double)m->classes[c].n * (double)m->classes[c].m;
      if (len < sizeof names)
        len += (size_t)snprintf(names + len, sizeof names - len, "%s%s", len ? " " : "", m->classes[c].label);
    }
  if (dropped > 0) /* issue 30: what the model does not store, and how to have it */
    fprintf(out, "streamed bases, used in training and not kept: %s (%.3f MB; --keep-bases all keeps them)\n", names,
            dropped / 1e6);
}

/* The stage's input whose own error is largest: where a larger basis helps. An input whose error
 * is NaN was not measured (its basis streamed, issue 30): it is returned first, since nothing says
 * it is not the worst, and advice naming a measured one could send the user to a basis already
 * exact (trial3: "it reads x with error 2.2e-16"). */
static bool worse(const double *err, int q, int best) {
  return best < 0 || (isnan(err[q]) && !isnan(err[best])) || err[q] > err[best];
}

static int worst_read(const Model *m, const RStage *rs, const double *err) {
  int best = -1;
  for (int t = 0; t < rs->nterms; t++) {
    const RTerm *rt = &rs->terms[t];
    if (rt->named_q >= 0 && worse(err, rt->named_q, best)) best = rt->named_q;
    for (int k = -1; k < rt->nops; k++) {
      int n = k < 0 ? rt->nnum : rt->ops[k].ntensors;
      for (int g = 0; g < n; g++) {
        const RTensor *x = k < 0 ? &rt->num[g] : &rt->ops[k].t[g];
        for (int j = 0; j < x->nin; j++)
          if (worse(err, x->in_q[j], best)) best = x->in_q[j];
      }
    }
  }
  return best;
}

/* The stage computing quantity q, or NULL (an input). */
static const RStage *stage_of(const Model *m, int q) {
  for (int i = 0; i < m->nstages; i++)
    if (m->stages[i].q == q) return &m->stages[i];
  return NULL;
}

/* The member of quantity q, or NULL. */
static const RMember *member_of(const Model *m, int q) {
  const RClass *c = &m->classes[m->qclass[q]];
  for (int i = 0; i < c->nmembers; i++)
    if (c->members[i].q == q) return &c->members[i];
  return NULL;
}

/* How to give quantity q a larger basis, from why its basis was cut: at its
 * cap, raise the cap; below it, the energy fraction decided, and raising
 * the cap gives the same model again (issue 38: 10 of 60 kept, advised
 * cap=N; energy=1 took the error from 5.3 to 0.056). */
static void basis_advice(const Model *m, int q, char *buf, size_t n) {
  const char *name = ((Sym *)m->prog->quantities.v[q])->name;
  const RMember *mb = member_of(m, q);
  if (!mb) snprintf(buf, n, "--basis %s:cap=N,energy=E", name);
  else if (mb->kept >= mb->cap)
    snprintf(buf, n, "--basis %s:cap=N with N above %d (its cap: it kept %d)", name, mb->cap, mb->kept);
  else
    snprintf(buf, n, "--basis %s:energy=E with E above %.6g, up to energy=1 (its energy fraction decided: it kept %d "
                     "of a cap of %d)", name, mb->energy, mb->kept, mb->cap);
}

/* Where a stage's error comes from: follow the inputs with the largest
 * error through stages whose own basis holds their values exactly (floor
 * 0: a larger basis for them changes nothing) to the first quantity whose
 * basis is cut. */
static int error_source(const Model *m, int w, const double *err, const double *floor) {
  for (int hops = 0; w >= 0 && hops < m->nq && !(floor[w] > 0); hops++) {
    const RStage *ws = stage_of(m, w);
    int up = ws ? worst_read(m, ws, err) : -1;
    if (up < 0 || !(err[up] > 1e-12)) break;
    w = up;
  }
  return w;
}

int report_verify_warnings(const Model *m, const double *err, const double *floor, double tol, FILE *out) {
  int n = 0;
  for (int q = 0; q < m->nq; q++) {
    const Sym *s = m->prog->quantities.v[q];
    if (s->kind == SYM_INPUT && floor[q] > tol) {
      char advice[256];
      basis_advice(m, q, advice, sizeof advice);
      fprintf(out,
              "warning: input %s: its projection floor %.2e exceeds --tol %.3g: its basis cannot represent the test "
              "samples (train with more or more varied samples, or a larger basis: %s)\n",
              s->name, floor[q], tol, advice);
      n++;
    }
  }
  for (int i = 0; i < m->nstages; i++) {
    const RStage *rs = &m->stages[i];
    int q = rs->q;
    if (rs->st->kind == ST_EXTERN || !(err[q] > 3 * floor[q]) || !(err[q] > 1e-12)) continue;
    int w = worst_read(m, rs, err);
    double ratio = floor[q] > 0 ? err[q] / floor[q] : INFINITY;
    char times[32];
    if (ratio < 1000) snprintf(times, sizeof times, "%.1fx", ratio);
    else snprintf(times, sizeof times, "over 1000x");
    /* a floor of 0 (its basis holds every test value exactly, e.g. a scalar's one vector) is no
     * yardstick: no "1000x its projection floor 0" (issue 38) */
    if (floor[q] > 0)
      fprintf(out,
              "warning: stage %s: error %.2e is %s its projection floor %.2e: the reduction, not its basis, loses "
              "accuracy here",
              rs->st->sym->name, err[q], times, floor[q]);
    else
      fprintf(out,
              "warning: stage %s: error %.2e while its basis holds the test values exactly (projection floor 0): "
              "the reduction, not its basis, loses accuracy here",
              rs->st->sym->name, err[q]);
    /* its inputs at their floors and their error a tenth of its own or less: the stage's own
     * reduction is the cause (DESIGN §12), not what it reads */
    bool inputs_at_floor = w < 0 || err[w] <= 1e-12 || (err[w] <= 2 * floor[w] && err[w] <= 0.1 * err[q]);
    if (inputs_at_floor && rs->interp)
      fprintf(out, " (its inputs are at their floors and it is interpolated at %ld entries with ‖(WPB)⁺‖ %.3g: "
              "interpolate at more, npgc train --interp-oversample X, or try --reduce %s:galerkin)\n",
              rs->interp->k, rs->interp->pinv_norm, rs->st->sym->name);
    else if (inputs_at_floor && lower_interp_eligible(rs->st))
      fprintf(out, " (its inputs are at their floors and every operator of it is diagonal: reduce it by "
              "interpolation, npgc train --reduce %s:interp, or let training choose: with 30 samples or more it does "
              "unless --valid none, or give --valid DIR)\n",
              rs->st->sym->name);
    else if (w >= 0 && isnan(err[w])) { /* streamed: its error is unknown here (issue 30) */
      const char *wn = ((Sym *)m->prog->quantities.v[w])->name;
      const RStage *ws = stage_of(m, w);
      fprintf(out, " (it reads %s, whose basis was streamed in training: its error is not measured here; retrain "
              "with --keep-bases %s to see it", wn, wn);
      if (ws && !ws->interp && lower_interp_eligible(ws->st))
        fprintf(out, ", and %s may be reduced by interpolation: --reduce %s:interp, or let training choose with "
                "--valid DIR", wn, wn);
      fputs(")\n", out);
    } else if (w >= 0 && ((Sym *)m->prog->quantities.v[w])->kind == SYM_EXTERN && err[w] > 3 * floor[w]) {
      /* an extern's error above its floor is its learned map's (paper §8.3), which a larger basis
       * does not lower (trial3: "--basis v:cap=N" for v at a floor of 2e-16) */
      const char *wn = ((Sym *)m->prog->quantities.v[w])->name;
      fprintf(out, " (it reads extern %s, whose learned map has error %.2e against a floor of %.2e: train on more "
              "samples like these, or give %s's values to the reduced evaluator, npg_reduced_given_externs)\n",
              wn, err[w], floor[w], wn);
    } else if (w >= 0) {
      int src = error_source(m, w, err, floor);
      char advice[256];
      basis_advice(m, src, advice, sizeof advice);
      if (src == w)
        fprintf(out, " (it reads %s with error %.2e: a larger basis for it, %s; or name an intermediate to give it a "
                "basis, or inline one)\n",
                ((Sym *)m->prog->quantities.v[w])->name, err[w], advice);
      else
        fprintf(out, " (it reads %s with error %.2e, whose basis holds it exactly: the error comes from %s (error "
                "%.2e, projection floor %.2e): a larger basis for that, %s)\n",
                ((Sym *)m->prog->quantities.v[w])->name, err[w], ((Sym *)m->prog->quantities.v[src])->name, err[src],
                floor[src], advice);
    }
    else fputs(" (name an intermediate to give it a basis of its own, or inline one)\n", out);
    n++;
  }
  return n;
}
