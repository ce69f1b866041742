/* samples.h — the samples of a data directory: every input and extern of a
 * program as DIR/<name>.npy with a leading sample axis (DESIGN §2), checked
 * once (float64, one sample count across files), handed to the full
 * evaluator one sample at a time. */
#ifndef NPG_SAMPLES_H
#define NPG_SAMPLES_H

#include "npy.h"
#include "reduced.h"
#include "train.h"

typedef struct SampleFile {
  const Sym *sym;
  int slot;                 /* index in Program.slots */
  int q;                    /* index in Program.quantities */
  NpyArray a;
  char path[4096];
} SampleFile;

typedef struct SampleSet {
  const Program *prog;
  int n;
  SampleFile *files;
  long count;               /* samples */
} SampleSet;

/* Open DIR/<name>.npy (else FALLBACK/<name>.npy when FALLBACK is non-NULL)
 * for every input and, when `externs`, every extern. 0, or -1 with `err`
 * naming the file. */
int samples_open(SampleSet *s, const Program *prog, const char *dir, const char *fallback, bool externs, char *err,
                 size_t errlen);
/* Sample k of file i (its values, count/samples of them). */
const double *samples_value(const SampleSet *s, int i, long k, size_t *n);
/* SampleSource callback: set every input/extern of sample k in `f`. */
int samples_set(void *user, NpgFull *f, long k);
void samples_close(SampleSet *s);

/* "name=<fnv hex> …" of the files DIR/<param>.npy, for the manifest. NULL
 * with `err` when a file cannot be read. */
char *samples_param_hashes(const Program *prog, const char *dir, char *err, size_t errlen);
/* Compare DIR's params with the hashes a model recorded: 0, or -1 naming
 * the file that differs. */
int samples_check_params(const Program *prog, const char *dir, const char *recorded, char *err, size_t errlen);

#endif
