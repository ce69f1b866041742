/* tunnel.h — npg-fluids tunnel: paper Fig. 5 on the periodic wind tunnel.
 * Two full training simulations (a large and a small obstacle) streamed
 * into npg trainers (one model per basis size), a full test simulation
 * (a medium obstacle) with the one-step error of §7.1 per frame and basis
 * size, and a reduced test simulation (the largest basis) with marker
 * particles, side-by-side frames, VTK and report.json. */
#ifndef FLUIDS_TUNNEL_H
#define FLUIDS_TUNNEL_H

#include "mesh.h"

typedef struct TunnelOptions {
  const char *out;
  int frames, particles, png_every, vtk_every, width;
  TunnelSpec spec;
  double scale_large, scale_small, scale_test, pulse, period, mu, cfl, u0;
  int nsizes;
  int mu_sizes[16];   /* m_u per model; m_f = m_u / 2 */
  int mg_cap;
  int keep_models;    /* write each model under DIR/models/ */
} TunnelOptions;

void tunnel_options_default(TunnelOptions *o);
int tunnel_run(const TunnelOptions *o);

#endif
