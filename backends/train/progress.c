/* progress.c — the progress bar training and verification draw on stderr
 * (progress_show, train.h): one line redrawn in place, "what [####  ]
 * done/total", so a long pass over the samples says how far it is. Here
 * rather than in train.c because every pass draws it: the snapshots, the
 * method of snapshots, out of core (ooc.c), pre-multiplication,
 * verification (compiler/api/verify.c) and the trainer of npg.h. */
#include <stdio.h>
#include <time.h>

#include "train.h"

/* Redrawn at most ten times a second (a pass of many tiny steps would
 * otherwise spend its time drawing), and always at the first and last step. */
void progress_show(bool on, const char *what, long done, long total) {
  if (!on) return;
  static _Thread_local double last = -1;
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  double now = (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
  if (done > 1 && done < total && now - last < 0.1) return;
  last = now;
  int width = 30, fill = total > 0 ? (int)((double)done / (double)total * width) : width;
  fprintf(stderr, "\r%-28s [", what);
  for (int i = 0; i < width; i++) fputc(i < fill ? '#' : ' ', stderr);
  fprintf(stderr, "] %ld/%ld", done, total);
  if (done >= total) fputc('\n', stderr);
  fflush(stderr);
}
