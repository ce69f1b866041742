/* tunnelfull.h — npg-fluids tunnel-full: the full-space solver of paper §5 on the
 * deforming periodic wind tunnel (§7.1), with marker particles (§6.5), PNG frames, VTK
 * files and the full-space snapshots `npgc train` reads.
 *
 * Every run writes DIR/report.json (the figures), DIR/frames/frame_NNNN.png,
 * DIR/vtk/cells_NNNN.vtu and faces_NNNN.vtu with cells.pvd and faces.pvd (ParaView), and
 * DIR/data/: the params of fluids2d.npg (tri, edge, cface, csign, nbr, bface, mu) and the
 * per-frame inputs g, gdot, f, u with the induced fluxes h and the midpoint geometry gmid
 * they were evaluated at, one sample per frame (leading axis), as .npy. */
#ifndef FLUIDS_TUNNELFULL_H
#define FLUIDS_TUNNELFULL_H

#include "mesh.h"
#include "projection.h"

typedef struct TunnelFullOptions {
  const char *out;
  const char *dump_step; /* --dump-step DIR: the step as data for tunnel_step.npg or tunnel_step_moving.npg (tunnelstep.h), or NULL */
  int frames, particles, png_every, vtk_every, png_width;
  double scale, pulse, period, mu, cfl, u0;
  ProjectionMethod projection;
  TunnelSpec spec;
} TunnelFullOptions;

void tunnel_full_options_default(TunnelFullOptions *o);
/* 0, 1 after a failure (printed), 2 for a missing --out. */
int tunnel_full_run(const TunnelFullOptions *o);

#endif
