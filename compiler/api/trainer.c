/* trainer.c — training from C, one sample at a time (npg.h NpgTrainer).
 *
 * A running simulation hands over each sample's inputs and extern values;
 * the trainer keeps them (in memory up to a quarter of `mem`, the rest in
 * an unnamed scratch file that disappears with the trainer) and, when
 * finished, replays them through the full evaluator into train_model — the
 * code `npgc train` runs, so the same samples give the same model. Stage
 * values are never kept: training recomputes them (method of snapshots,
 * out-of-core row blocks), replaying every sample once per pass.
 *
 * The cache is compact: an extern value whose entries are mostly exactly +0
 * or 1 (ray-cast visibility: fractional only where a face is partly hidden)
 * is kept as one bit per entry plus its other entries as (index, value),
 * anything else as doubles, so a callback that is expensive is called once
 * per sample and the passes read its values back bit-exactly. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "api.h"
#include "compile.h"
#include "dist.h"
#include "lower.h"
#include "records.h"

struct NpgTrainer {
  NpgFull *f;
  const Program *prog;
  NpgTrainOptions opt;
  SampleRecords r;          /* the samples added (records.h): their inputs and externs, kept */
  bool *staged;             /* per slot of r: npg_trainer_set since the last add */
  double weight;            /* the next sample's (npg_trainer_weight; 1 after every add) */
  double *weights;          /* every sample's, in order (every rank's too); NULL while all are 1 */
  long weights_cap;
  bool broken;              /* a failure that may have left the records incomplete (or the construction's):
                               npg_trainer_clear_error keeps the error */
  uint64_t inputs_hash;     /* over ranks: of every sample's inputs, in order (every rank's too: ranks_agree) */
  bool inputs_whole;        /* greedy training's (api_trainer_inputs_whole): TrainOptions.inputs_whole */
  SnapshotCache *cache;     /* greedy training's (api_trainer_cache): TrainOptions.cache */
  char error[2048];
  Err record;               /* error as the backends' record (the records' err points here) */
  char worded[2048];        /* error in the caller's words (NpgTrainOptions.words), made by npg_trainer_error */
};

#define tfail(t, ...) error_set_first((t)->error, sizeof (t)->error, __VA_ARGS__)

static size_t half_the_ram(void) {
  size_t ram = physical_memory();
  return ram ? ram / 2 : (size_t)8 << 30;
}

bool npg_mpi_available(void) { return dist_available(); }
int npg_mpi_rank(void) { return dist_rank(); }
int npg_mpi_size(void) { return dist_size(); }

void npg_train_options_default(NpgTrainOptions *o) {
  API_REFUSE_NULL(o, NULL, 0, );
  memset(o, 0, sizeof *o);
  o->cap = 60;
  o->energy = 0.999;
  o->mem = half_the_ram();
  o->valid_holdout = -1; /* automatic: DESIGN §12 */
}

void api_trainer_inputs_whole(NpgTrainer *t) {
  if (t) t->inputs_whole = true;
}

void api_trainer_cache(NpgTrainer *t, SnapshotCache *cache) {
  if (t) t->cache = cache;
}

void api_train_options(const NpgTrainOptions *o, TrainOptions *to) {
  *to = (TrainOptions){.user = o, .dist = o->mpi, .stream = true};
}

int api_refuse_reduce_options(const NpgTrainOptions *o, const char *func, char *err, size_t errlen) {
#define REFUSE(...) api_refuse(err, errlen, func, __VA_ARGS__)
  /* the interpolated stages' and streamed bases' fields (DESIGN §12, issue 30): a NULL list of
   * names was read as one (SIGSEGV), a NaN or negative oversampling, a negative count or an empty
   * keep_bases taken for the default (trial3) */
  const char *const *lists[2] = {o->interp_stage, o->galerkin_stage};
  int counts[2] = {o->ninterp, o->ngalerkin};
  const char *names[2][2] = {{"ninterp", "interp_stage"}, {"ngalerkin", "galerkin_stage"}};
  for (int l = 0; l < 2; l++) {
    if (counts[l] < 0) return REFUSE("NpgTrainOptions.%s is %d (the number of names in %s)", names[l][0], counts[l],
                                     names[l][1]);
    if (counts[l] > 0 && !lists[l])
      return REFUSE("NpgTrainOptions.%s is %d but %s is NULL", names[l][0], counts[l], names[l][1]);
    for (int i = 0; i < counts[l]; i++)
      if (!lists[l][i]) return REFUSE("NpgTrainOptions.%s[%d] is NULL (a stage name)", names[l][1], i);
  }
  if (o->interp_oversample != 0 && !(o->interp_oversample >= 1 && isfinite(o->interp_oversample)))
    return REFUSE("NpgTrainOptions.interp_oversample is %g (entries per basis vector, at least 1; 0 for the default)",
                  o->interp_oversample);
  if (o->valid_count < 0)
    return REFUSE("NpgTrainOptions.valid_count is %ld (the number of validation samples, 0 for none)", o->valid_count);
  if (!(o->valid_holdout <= 0.5)) /* NaN too */
    return REFUSE("NpgTrainOptions.valid_holdout is %g (a fraction in (0, 0.5] of the samples, 0 for none, negative "
                  "for the automatic choice)",
                  o->valid_holdout);
  if (o->keep_bases && !o->keep_bases[0])
    return REFUSE("NpgTrainOptions.keep_bases is empty (comma-separated quantities or classes m_x, \"all\", or NULL "
                  "for none)");
  return 0;
#undef REFUSE
}

/* Options out of their documented range are refused, naming the field, not
 * replaced by a default (a cap of 0 the caller computed is a bug of theirs
 * that a default would hide). */
static int refuse_options(NpgTrainer *t, const NpgTrainOptions *o) {
#define REFUSE(...) api_refuse(t->error, sizeof t->error, "npg_trainer_new", __VA_ARGS__)
  if (o->cap <= 0) return REFUSE("NpgTrainOptions.cap is %d (a basis cap is at least 1)", o->cap);
  if (!(o->energy > 0 && o->energy <= 1))
    return REFUSE("NpgTrainOptions.energy is %g (an energy fraction is in (0, 1])", o->energy);
  if (o->mem == 0) return REFUSE("NpgTrainOptions.mem is 0 (bytes of memory for training; npg_train_options_default "
                                 "gives half the RAM)");
  if (o->words < NPG_WORDS_C || o->words > NPG_WORDS_PYTHON)
    return REFUSE("NpgTrainOptions.words is %d (NPG_WORDS_C, NPG_WORDS_NPGC or NPG_WORDS_PYTHON)", o->words);
  if (o->nbasis < 0) return REFUSE("NpgTrainOptions.nbasis is %d (the number of basis overrides)", o->nbasis);
  if (o->nbasis > 0 && (!o->basis_name || !o->basis_cap || !o->basis_energy))
    return REFUSE("NpgTrainOptions.nbasis is %d but %s is NULL", o->nbasis,
                  !o->basis_name ? "basis_name" : !o->basis_cap ? "basis_cap" : "basis_energy");
  for (int i = 0; i < o->nbasis; i++) {
    if (!o->basis_name[i]) return REFUSE("NpgTrainOptions.basis_name[%d] is NULL", i);
    if (o->basis_cap[i] != -1 && o->basis_cap[i] <= 0)
      return REFUSE("NpgTrainOptions.basis_cap[%d] (%s) is %d (at least 1, or -1 for the default)", i, o->basis_name[i],
                    o->basis_cap[i]);
    if (o->basis_energy[i] != -1 && !(o->basis_energy[i] > 0 && o->basis_energy[i] <= 1))
      return REFUSE("NpgTrainOptions.basis_energy[%d] (%s) is %g (in (0, 1], or -1 for the default)", i,
                    o->basis_name[i], o->basis_energy[i]);
    if (o->basis_center && o->basis_center[i] != -1 && o->basis_center[i] != 0 && o->basis_center[i] != 1)
      return REFUSE("NpgTrainOptions.basis_center[%d] (%s) is %d (1 on, 0 off, -1 the default)", i, o->basis_name[i],
                    o->basis_center[i]);
  }
  if (api_refuse_reduce_options(o, "npg_trainer_new", t->error, sizeof t->error) != 0) return -1;
  return 0;
#undef REFUSE
}

NpgTrainer *npg_trainer_new(NpgFull *f, const NpgTrainOptions *o) {
  NpgTrainer *t = mem_calloc(1, sizeof *t);
  if (!t) return api_refuse(NULL, 0, __func__, "out of memory"), NULL; /* what npg_trainer_error(NULL) says */
  if (o) t->opt = *o;
  else npg_train_options_default(&t->opt);
  t->weight = 1;
  t->f = f;
  t->r.mpi = t->opt.mpi;
  t->record = (Err){t->error, sizeof t->error};
  t->r.err = &t->record;
  if (!f) {
    api_refuse(t->error, sizeof t->error, __func__, "argument 'f' is NULL");
    return t;
  }
  t->broken = true; /* until constructed */
  if (refuse_options(t, &t->opt)) return t;
  if (t->opt.mpi && dist_start(ERR_OF(t->error, sizeof t->error))) return t;
  if (npg_full_error(f)[0]) {
    tfail(t, "%s", npg_full_error(f));
    return t;
  }
  const Program *prog = t->prog = full_program(f->full);
  /* the names the options give, refused now rather than after every sample was streamed */
  TrainOptions names;
  api_train_options(&t->opt, &names);
  if (prog && train_check_names((Program *)prog, &names, ERR_OF(t->error, sizeof t->error)) != 0) return t;
  t->r.slot = mem_calloc((size_t)prog->slots.n + 1, sizeof *t->r.slot);
  t->r.count = mem_calloc((size_t)prog->slots.n + 1, sizeof *t->r.count);
  t->staged = mem_calloc((size_t)prog->slots.n + 1, sizeof *t->staged);
  if (!t->r.slot || !t->r.count || !t->staged) {
    tfail(t, "out of memory");
    return t;
  }
  for (int i = 0; i < prog->slots.n; i++) {
    const Sym *s = prog->slots.v[i];
    if (s->kind == SYM_INPUT || s->kind == SYM_EXTERN) t->r.slot[t->r.nslots++] = s;
  }
  t->broken = false;
  return t;
}


const char *npg_trainer_error(const NpgTrainer *t) {
  if (!t) return api_refusal()[0] ? api_refusal() : "out of memory";
  NpgTrainer *w = (NpgTrainer *)t; /* the worded copy is a cache of t->error, made on each read */
  api_words(t->error, t->opt.words, w->worded, sizeof w->worded);
  return w->worded;
}
long npg_trainer_samples(const NpgTrainer *t) {
  API_REFUSE_NULL(t, NULL, 0, -1);
  return t->r.samples;
}

/* The argument checks of the npg_trainer_ entry points (api.h). */
#define REFUSE_NULL_T(ret) API_REFUSE_NULL(t, NULL, 0, ret)
#define REFUSE_NULL(arg, ret) API_REFUSE_NULL(arg, t->error, sizeof t->error, ret)

/* A refused sample forgotten: its staged values dropped, the evaluator's error cleared. */
int npg_trainer_clear_error(NpgTrainer *t) {
  REFUSE_NULL_T(-1);
  if (t->broken || (t->opt.mpi && dist_size() > 1)) return t->error[0] ? -1 : 0;
  if (t->staged) memset(t->staged, 0, sizeof(bool) * (size_t)t->r.nslots);
  t->weight = 1;
  npg_full_clear_error(t->f);
  full_forget_given(t->f->full);
  t->error[0] = 0;
  return 0;
}

static int slot_of(const NpgTrainer *t, const char *name) {
  for (int i = 0; i < t->r.nslots; i++)
    if (strcmp(t->r.slot[i]->name, name) == 0) return i;
  return -1;
}

int npg_trainer_set(NpgTrainer *t, const char *name, int ndim, const long *shape, const double *values) {
  REFUSE_NULL_T(-1);
  REFUSE_NULL(name, -1);
  if (t->error[0]) return -1;
  int i = slot_of(t, name);
  if (i < 0) return tfail(t, "the program has no input or extern '%s'", name);
  char from[256];
  /* Named in a message about the value ("dim N is 5 in … but 6 in input 'x' of training sample 8"). */
  snprintf(from, sizeof from, "%s '%.100s' of training sample %ld", t->r.slot[i]->kind == SYM_INPUT ? "input" : "extern",
           name, t->r.samples);
  if (npg_full_set(t->f, name, ndim, shape, values, from) != 0) return tfail(t, "%s", npg_full_error(t->f));
  t->staged[i] = true;
  return 0;
}

int npg_trainer_weight(NpgTrainer *t, double w) {
  REFUSE_NULL_T(-1);
  if (t->error[0]) return -1;
  if (!(w > 0 && isfinite(w)))
    return tfail(t, "npg_trainer_weight: the weight of training sample %ld is %g: weights must be positive and finite",
                 t->r.samples, w);
  t->weight = w;
  return 0;
}

/* Sample t->r.samples's weight kept (the array made at the first weight not 1), the next reset to 1. */
static int keep_weight(NpgTrainer *t) {
  if (t->weight != 1 && !t->weights) {
    t->weights_cap = t->r.samples + 64;
    if (!(t->weights = mem_malloc(sizeof(double) * (size_t)t->weights_cap))) return tfail(t, "out of memory");
    for (long k = 0; k < t->r.samples; k++) t->weights[k] = 1;
  }
  if (t->weights && t->r.samples == t->weights_cap) {
    double *w = mem_realloc(t->weights, sizeof(double) * (size_t)(2 * t->weights_cap));
    if (!w) return tfail(t, "out of memory");
    t->weights = w, t->weights_cap *= 2;
  }
  if (t->weights) t->weights[t->r.samples] = t->weight;
  t->weight = 1;
  return 0;
}

/* Append the values now in `g` as one sample (another rank's: counted only). */
static int record(NpgTrainer *t, const NpgFull *g) {
  /* the samples are replayed with the trainer's params: without them finish() alone said so */
  const char *unbound = full_unbound_param(t->f->full);
  if (unbound)
    return tfail(t, "training sample %ld: param '%s' is not bound (bind the params of the trainer's evaluator first)",
                 t->r.samples, unbound);
  if (keep_weight(t)) return -1;
  /* over ranks every rank sees every sample: their inputs' hash, compared by ranks_agree (ranks
   * given two data folders of the same shapes trained on a mixture of them, issue 38) */
  for (int i = 0; t->opt.mpi && i < t->r.nslots; i++) {
    size_t n = 0;
    const double *v = t->r.slot[i]->kind == SYM_INPUT ? npg_full_get(g, t->r.slot[i]->name, &n) : NULL;
    if (v) t->inputs_hash = (t->inputs_hash ^ full_hash_values(v, n)) * 0x100000001b3ull + (uint64_t)i;
  }
  if (!records_own(&t->r, t->r.samples)) {
    t->r.samples++;
    memset(t->staged, 0, sizeof(bool) * (size_t)t->r.nslots);
    return 0;
  }
  long kk = records_kept_index(&t->r, t->r.samples); /* its place among the samples this process keeps */
  if (t->r.samples == 0) { /* the first sample fixes every size */
    t->r.record = 0; /* again after a refused first sample */
    for (int i = 0; i < t->r.nslots; i++) {
      if (!npg_full_get(g, t->r.slot[i]->name, &t->r.count[i]))
        return tfail(t, "training sample 0: %s '%s' has no value", t->r.slot[i]->kind == SYM_INPUT ? "input" : "extern",
                     t->r.slot[i]->name);
      t->r.record += t->r.count[i];
    }
    free(t->r.buf), free(t->r.enc);
    t->r.buf = NULL, t->r.enc = NULL;
    t->r.mem_cap = t->opt.mem / 4;
    if (!(t->r.buf = mem_malloc(sizeof(double) * (t->r.record + 1))) ||
        !(t->r.enc = mem_malloc(sizeof(double) * t->r.record + (size_t)t->r.nslots + 1)))
      return t->broken = true, tfail(t, "out of memory");
  }
  size_t off = 0;
  for (int i = 0; i < t->r.nslots; i++) {
    size_t n = 0;
    const double *v = npg_full_get(g, t->r.slot[i]->name, &n);
    if (!v || n != t->r.count[i])
      return tfail(t, "training sample %ld: '%s' has %zu entries, sample 0 had %zu", t->r.samples, t->r.slot[i]->name,
                   v ? n : 0, t->r.count[i]);
    memcpy(t->r.buf + off, v, sizeof(double) * n);
    off += n;
  }
  if (records_store(&t->r, &t->r.rec, kk, records_encode(&t->r))) return t->broken = true, -1;
  t->r.samples++;
  memset(t->staged, 0, sizeof(bool) * (size_t)t->r.nslots);
  return 0;
}

int npg_trainer_add(NpgTrainer *t) {
  REFUSE_NULL_T(-1);
  if (t->error[0]) return -1;
  bool need_eval = false;
  for (int i = 0; i < t->r.nslots; i++) {
    if (t->staged[i]) continue;
    if (t->r.slot[i]->kind == SYM_INPUT)
      return tfail(t, "training sample %ld: input '%s' is not set", t->r.samples, t->r.slot[i]->name);
    /* without a callback the evaluator would silently reuse the previous sample's value (issue 38) */
    if (!full_has_extern_fn(t->f->full, t->r.slot[i]->name))
      return tfail(t, "training sample %ld: extern '%s' is not given and has no callback: a sample gives every input, "
                      "and every extern that has no callback (npg_full_set_extern_fn)", t->r.samples, t->r.slot[i]->name);
    need_eval = true;
  }

  /* externs not given: their callbacks fill them (for this rank's samples). They read inputs only
   * (full.h), so after the first sample no stage is evaluated: an empty demand runs the callbacks
   * alone (at radiosity's paper size a whole evaluation is a 5,000-face solve, 2 s a sample) */
  if (need_eval && records_own(&t->r, t->r.samples)) {
    Demand *d = t->r.samples > 0 ? full_demand(t->f->full) : NULL;
    if (t->r.samples > 0 && !d) return tfail(t, "%s", npg_full_error(t->f));
    if ((d ? full_eval_demand(t->f->full, t->r.samples, d) : npg_full_eval(t->f, t->r.samples)) != 0)
      return tfail(t, "%s", npg_full_error(t->f));
  }
  int rc = record(t, t->f);
  /* the staged values were this sample's: the next one's externs not staged run their callbacks */
  full_forget_given(t->f->full);
  return rc;
}

int npg_trainer_add_full(NpgTrainer *t, const NpgFull *g) {
  REFUSE_NULL_T(-1);
  REFUSE_NULL(g, -1);
  if (t->error[0]) return -1;
  if (npg_full_error(g)[0]) return tfail(t, "%s", npg_full_error(g));
  /* npg.h: an evaluator of the same program. Another program whose inputs
   * have the same names and sizes would be taken silently; the same source
   * compiled twice is the same program (its hash, as a model records it). */
  const Program *gp = full_program(g->full);
  if (!gp) return tfail(t, "npg_trainer_add_full: the evaluator has no program");
  if (gp != t->prog && model_program_hash(gp) != model_program_hash(t->prog))
    return tfail(t, "npg_trainer_add_full: the evaluator is of another program (%s) than the trainer's (%s)",
                 gp->ctx->files.n ? ((const SrcFile *)gp->ctx->files.v[0])->name : "?",
                 t->prog->ctx->files.n ? ((const SrcFile *)t->prog->ctx->files.v[0])->name : "?");
  return record(t, g);
}

int npg_trainer_dots(NpgTrainer *t, const char *name, size_t count, const double *values, double *dots) {
  REFUSE_NULL_T(-1);
  REFUSE_NULL(name, -1);
  REFUSE_NULL(values, -1);
  REFUSE_NULL(dots, -1);
  if (t->error[0]) return -1;
  int i = slot_of(t, name);
  if (i < 0) return tfail(t, "npg_trainer_dots: the program has no input or extern '%s'", name);
  if (t->r.samples == 0) return tfail(t, "npg_trainer_dots: no training samples were added");
  if (count != t->r.count[i])
    return tfail(t, "npg_trainer_dots: '%s' has %zu entries a sample, %zu were given", name, t->r.count[i], count);
  for (size_t e = 0; e < count; e++)
    if (!isfinite(values[e]))
      return tfail(t, "npg_trainer_dots: the values of '%s' hold %s at flat entry %zu", name,
                   isnan(values[e]) ? "NaN" : "an infinity", e);
  /* over ranks each rank its own samples (sample 0, which every rank keeps, on rank 0), then summed */
  bool split = t->opt.mpi && dist_size() > 1 && !t->r.all;
  for (long k = 0; k < t->r.samples; k++) {
    dots[k] = 0;
    if (!records_own(&t->r, k) || (split && k == 0 && dist_rank() != 0)) continue;
    if (records_fetch(&t->r, &t->r.rec, records_kept_index(&t->r, k)))
      return tfail(t, "npg_trainer_dots: cannot read training sample %ld back from the scratch file", k);
    size_t pos = 0;
    for (int j = 0; j < i; j++) pos = records_slot_end(&t->r, j, pos);
    dots[k] = records_dot_slot(&t->r, i, &pos, values);
  }
  if (split) dist_allreduce_sum(dots, t->r.samples);
  return 0;
}

/* The full evaluator keeps the value of every quantity of the sample it
 * evaluates, so training needs at least the largest of them in memory: a
 * quantity that alone is larger than --mem is refused, naming it, its size
 * and the budget, rather than silently exceeding --mem. */
static int check_mem(NpgTrainer *t) {
  for (int k = 0; k < t->prog->slots.n; k++) {
    const Sym *s = t->prog->slots.v[k];
    long shape[MAX_AXES + MAX_STATIC];
    int nd = api_shape(t->f->full, s, shape);
    double entries = 1;
    for (int i = 0; i < nd; i++) entries *= (double)shape[i];
    if (entries * sizeof(double) <= (double)t->opt.mem) continue;
    char need[32], have[32];
    /* an op entry named whole: the cure is in the program (issue 38) */
    bool dense_entry = s->kind == SYM_STAGE && s->introduced && s->introduced_for &&
                       s->introduced_for->kind == SYM_OP && s->nivars >= 2;
    return tfail(t, "%s '%s' alone needs %s per sample (%.4g entries), more than --mem %s%s: training holds it in "
                    "memory (the full evaluator keeps every stage of a sample), so it cannot stay within --mem; %s%s",
                 s->kind == SYM_INPUT ? "input" : s->kind == SYM_EXTERN ? "extern" : "stage", s->name,
                 bytes_text(entries * sizeof(double), need, sizeof need), entries,
                 bytes_text((double)t->opt.mem, have, sizeof have),
                 t->opt.mem == half_the_ram() ? " (the default: half of this machine's memory)" : "",
                 dense_entry ? "" : "raise --mem, or train on smaller data",
                 dense_entry ? lower_dense_entry_cure(t->prog->ctx, s) : "");
  }
  return 0;
}

/* Over ranks, every rank must be training the same problem: one program,
 * the same params, sample count, dims and options. A rank given other data
 * trained a wrong model with exit 0, or died in a collective of another
 * size with no word from npg (issue 24). Compared as the maximum and the
 * minimum over ranks of each figure (64-bit hashes as two exact 32-bit
 * halves); every rank reaches the same verdict, so all fail alike. */
static int ranks_agree(NpgTrainer *t) {
  if (!t->opt.mpi || dist_size() < 2) return 0;
  const Program *prog = t->prog;
  /* the figures: 4, then 3 + dims + 2 per param + 7 */
  int n = 0, cap = 14 + prog->dims.n + 2 * prog->params.n;
  double *v = malloc(sizeof(double) * (size_t)cap * 3);
  const char **what = calloc((size_t)cap, sizeof *what), **name = calloc((size_t)cap, sizeof *name);
  int rc = 0;
  if (!v || !what || !name) dist_abort("out of memory comparing the ranks' training problems");
  /* figure n: its value, what it is (a format of one %s, its name) */
#define FIGURE(x, w, nm) (v[n] = (double)(x), what[n] = (w), name[n] = (nm), n++)
  uint64_t h = model_program_hash(prog);
  FIGURE(h >> 32, "the program%s (its hash)", "");
  FIGURE(h & 0xffffffffu, "the program%s (its hash)", "");
  FIGURE(prog->dims.n, "the program's number of dims%s", "");
  FIGURE(prog->params.n, "the program's number of params%s", "");
  /* the lengths above agree before the rest, whose length they give, is compared */
  for (int round = 0; round < 2; round++) {
    int from = round ? 4 : 0;
    if (round) {
      FIGURE(t->r.samples, "the number of training samples%s", "");
      for (int i = 0; i < prog->dims.n; i++) {
        const char *d = ((Sym *)prog->dims.v[i])->name;
        FIGURE(npg_full_dim(t->f, d), "dim %s", d);
      }
      for (int i = 0; i < prog->params.n; i++) {
        uint64_t ph = full_param_hash(t->f->full, i, NULL);
        const char *p = ((Sym *)prog->params.v[i])->name;
        FIGURE(ph >> 32, "param '%s' (the hash of its values)", p);
        FIGURE(ph & 0xffffffffu, "param '%s' (the hash of its values)", p);
      }
      FIGURE(t->opt.cap, "--cap%s", "");
      FIGURE(t->opt.energy, "--energy%s", "");
      FIGURE(t->opt.uncentered, "--center%s", "");
      FIGURE(t->opt.joint, "--merge%s", "");
      FIGURE(t->opt.nbasis, "the number of --basis options%s", "");
      double sum = 0, moment = 0; /* the sample weights, by two sums (1 and k + 1 each when none) */
      for (long k = 0; k < t->r.samples; k++)
        sum += t->weights ? t->weights[k] : 1, moment += (double)(k + 1) * (t->weights ? t->weights[k] : 1);
      FIGURE(sum, "the sum of the sample weights%s", "");
      FIGURE(moment, "the sum of the sample weights times their sample's number%s", "");
      /* last: a rank given other shapes or params is told that, not this */
      FIGURE(t->inputs_hash >> 32, "the training samples' inputs%s (the hash of their values)", "");
      FIGURE(t->inputs_hash & 0xffffffffu, "the training samples' inputs%s (the hash of their values)", "");
    }
    int len = n - from;
    double *hi = v + cap, *lo = v + 2 * cap;
    for (int i = 0; i < len; i++) hi[i] = v[from + i], lo[i] = -v[from + i];
    dist_allreduce_max(hi, len);
    dist_allreduce_max(lo, len);
    for (int i = 0; rc == 0 && i < len; i++)
      if (hi[i] != -lo[i]) {
        char w[600];
        snprintf(w, sizeof w, what[from + i], name[from + i]);
        if (strstr(w, "hash"))
          rc = tfail(t, "the %d MPI ranks were not given the same training: %s differs between ranks (give every rank "
                        "the same program, DATA/ and options)", dist_size(), w);
        else
          rc = tfail(t, "the %d MPI ranks were not given the same training: %s is %.17g on some ranks and %.17g on "
                        "others (give every rank the same program, DATA/ and options)", dist_size(), w, -lo[i], hi[i]);
      }
    if (rc) break;
  }
#undef FIGURE
  free(what);
  free(name);
  free(v);
  return rc;
}

NpgModel *npg_trainer_finish(NpgTrainer *t, const char *model_dir) {
  REFUSE_NULL_T(NULL);
  /* over ranks the others would wait for this one in a collective: end the job */
  if (t->error[0] && t->opt.mpi && dist_size() > 1) dist_abort("%s", t->error);
  if (t->error[0]) return NULL;
  if (ranks_agree(t)) return NULL;
  if (t->r.samples == 0) {
    tfail(t, "no training samples were added");
    return NULL;
  }
  for (int i = 0; i < t->prog->dims.n; i++) {
    const char *d = ((Sym *)t->prog->dims.v[i])->name;
    if (npg_full_dim(t->f, d) == 0) {
      tfail(t, "dim %s is 0 in the training data: the quantities over it have no entries to reduce", d);
      return NULL;
    }
  }
  if (check_mem(t)) return NULL;
  /* the cache holds at most a quarter of the budget; over ranks, what it
   * holds on one process (share_samples) on every rank: the same plan */
  size_t used = t->opt.mpi && dist_size() > 1 ? records_shared_use(&t->r) : t->r.rec.used;
  if (t->error[0]) return NULL;
  NpgTrainOptions user = t->opt; /* training's budget is what the records leave; one rank reports */
  user.mem = t->opt.mem - used;
  user.progress = t->opt.progress && dist_rank() == 0;
  TrainOptions o;
  api_train_options(&user, &o);
  o.inputs_whole = t->inputs_whole;
  o.cache = t->cache;
  o.shared_prefix = model_dir; /* out of core over ranks: the basis files next to the model */
  o.weights = t->weights;
  SampleClosure valid_set = {t->opt.valid_set, t->opt.valid_user, t->f};
  SampleSource valid = {t->opt.valid_count, &valid_set, api_sample_set, NULL, NULL};
  if (t->opt.valid_count > 0 && !t->opt.valid_set) {
    tfail(t, "NpgTrainOptions: valid_count %ld validation samples but no valid_set", t->opt.valid_count);
    return NULL;
  }
  o.valid = t->opt.valid_count > 0 ? &valid : NULL;
  SampleSource src = records_source(&t->r);
  char err[2048] = "";
  Model *m = train_model((Program *)t->prog, t->f->full, &src, &o, ERR_OF(err, sizeof err));
  /* over ranks, the others wait for this one in a collective: end the job */
  if (!m && t->opt.mpi && dist_size() > 1) dist_abort("%s", err);
  if (!m) {
    tfail(t, "%s", err);
    return NULL;
  }
  NpgModel *nm = api_model_wrap(m);
  if (!nm) {
    tfail(t, "out of memory");
    return NULL;
  }
  if (model_dir && dist_rank() == 0 && npg_model_save(nm, model_dir) != 0) {
    if (t->opt.mpi && dist_size() > 1) dist_abort("%s", npg_model_error(nm));
    tfail(t, "%s", npg_model_error(nm));
    npg_model_free(nm);
    return NULL;
  }
  return nm;
}

void npg_model_train_seconds(const NpgModel *m, double seconds[4], double cpu[4]) {
  API_REFUSE_NULL(seconds, NULL, 0, );
  for (int i = 0; i < 4; i++) {
    seconds[i] = m && m->m ? m->m->phase_seconds[i] : 0;
    if (cpu) cpu[i] = m && m->m ? m->m->phase_cpu[i] : 0;
  }
}

void npg_trainer_free(NpgTrainer *t) {
  if (!t) return;
  records_free(&t->r);
  free(t->staged);
  free(t->weights);
  free(t);
}
