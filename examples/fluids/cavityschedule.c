/* cavityschedule.c — npg-fluids cavity's options and deformation schedule (cavitysim.h): the
 * default options, the frames per run for a mesh size, and the chambers' scale factors of
 * each training run and of the test at each frame (pulses that compress and re-inflate
 * chambers alone or in pairs; the test compresses in a pattern no training run has). */
#include "util.h"
#include "cavitysim.h"

#include <math.h>
#include <string.h>
#include <unistd.h>

#include "npg.h"
#include "particles.h"

void cavity_options_default(CavityOptions *o) {
  memset(o, 0, sizeof *o);
  o->spec = cavity_spec_default();
  o->frames = 0, o->runs = 14, o->particles = 10000, o->png_every = 10, o->vtk_every = 25, o->width = 800;
  o->dt = 0.01, o->nu = 5.0;
  o->mf = 64, o->mu = 128, o->mg = 5;
  o->dtol = 1e-2;
  o->projection = PROJ_AL_CHOLMOD;
  long cpus = sysconf(_SC_NPROCESSORS_ONLN);
  o->workers = cpus < 1 ? 1 : cpus > CAVITY_MAX_WORKERS ? CAVITY_MAX_WORKERS : (int)cpus;
  o->particle_threads = cpus < 1 ? 1 : cpus > PARTICLES_MAX_THREADS ? PARTICLES_MAX_THREADS : (int)cpus;
  o->sample_every = 0;
  o->buffer_bytes = (size_t)2 << 30;
  o->backend = NPG_CC;
}

int cavity_sample_every_for(int frames) { return frames <= 0 ? 1 : (frames + CAVITY_SAMPLES_PER_RUN - 1) / CAVITY_SAMPLES_PER_RUN; }

int cavity_frames_for(int cells) {
  int frames = 10 * (int)ceil(10 * cbrt(cells / 1000.0));
  return frames < 100 ? 100 : frames;
}

/* Compress and re-inflate: 1 - a sin^2(pi t / T), smooth at both ends. */
static double pulse(double a, int t, int T) {
  double s = sin(M_PI * t / T);
  return 1 - a * s * s;
}

/* Smoothstep from 0 (t = 0) to 1 (t = T). */
static double ramp(int t, int T) {
  double x = (double)t / T;
  return x * x * (3 - 2 * x);
}

void cavity_schedule(int r, int t, int T, double sigma[CAVITY_SIDES]) {
  for (int i = 0; i < CAVITY_SIDES; i++) sigma[i] = 1;
  if (r < 0) {
    /* the test, in no training run: chamber 0 compressed throughout while
     * chamber 1 expands from compressed back to its rest size */
    sigma[0] = 0.8;
    sigma[1] = 0.8 + 0.2 * ramp(t, T);
    return;
  }
  static const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
  if (r < 3) sigma[r] = pulse(0.25, t, T);                            /* one chamber, deep */
  else if (r < 6) sigma[r - 3] = pulse(0.12, t, T);                   /* one chamber, shallow */
  else if (r < 9) {                                                   /* two together */
    sigma[pairs[r - 6][0]] = pulse(0.2, t, T);
    sigma[pairs[r - 6][1]] = pulse(0.2, t, T);
  } else if (r < 12) {                                                /* two, deep and shallow */
    sigma[pairs[r - 9][0]] = pulse(0.25, t, T);
    sigma[pairs[r - 9][1]] = pulse(0.1, t, T);
  } else {                                                            /* two, overlapping in turn */
    int a = r == 12 ? 0 : 2, b = 1, L = 2 * T / 3;
    sigma[a] = t <= L ? pulse(0.15, t, L) : 1;
    sigma[b] = t >= T - L ? pulse(0.15, t - (T - L), L) : 1;
  }
}

int cavity_deform_at(const Cavity *cv, int r, int t, int T, double *g, double *seconds, char *err, size_t errlen) {
  double sigma[CAVITY_SIDES];
  cavity_schedule(r, t, T, sigma);
  double t0 = util_now();
  int rc = cavity_deform(cv, sigma, g, NULL, err, errlen);
  *seconds += util_now() - t0;
  return rc;
}
