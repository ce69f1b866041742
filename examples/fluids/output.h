/* output.h — what people look at: PNG frames (libpng) of the velocity
 * magnitude with the marker particles, and VTK XML (.vtu) files of the mesh,
 * cell velocities and face fluxes for ParaView, tied into a time series by a
 * .pvd collection. Every function returns 0, or -1 with "<path>: <problem>"
 * in `err`. */
#ifndef FLUIDS_OUTPUT_H
#define FLUIDS_OUTPUT_H

#include <stddef.h>

#include "mesh.h"
#include "particles.h"

/* The frame: cells coloured by |u| (0 .. vmax, clamped), obstacle and outside
 * grey, particles as dots (white or orange by tag; NULL for none), `width`
 * pixels across the tunnel length, height from the current geometry. */
int output_png(const char *path, const FluidMesh *m, const double *g, const double *u, const Particles *p, double vmax,
               int width, char *err, size_t errlen);
/* Cells (triangles) with cell data velocity (3 components, z = 0), speed
 * and area. */
int output_vtu_cells(const char *path, const FluidMesh *m, const double *g, const double *u, char *err, size_t errlen);
/* Faces (edges, as lines) with cell data flux f, induced flux h and kind
 * (0 interior, 1 wall, 2 obstacle). */
int output_vtu_faces(const char *path, const FluidMesh *m, const double *g, const double *f, const double *h, char *err,
                     size_t errlen);
/* 3D: the tetrahedra with cell data velocity and speed as a legacy .vtk
 * file (ASCII; ParaView opens a numbered series as one time series). */
int output_vtk_tets(const char *path, const FluidMesh *m, const double *g, const double *u, char *err, size_t errlen);
/* 3D: the particles as 2x2 point splats (white or orange by tag, darker
 * farther away, nearest in front) and the boundary's vertices as grey dots,
 * through a perspective camera looking down at the origin at 55 degrees;
 * `extent` is the scene's radius, `width` the image width (height 3/4 of it). */
int output_png_points(const char *path, const FluidMesh *m, const double *g, const Particles *p, double extent, int width,
                      char *err, size_t errlen);
/* Whether frame t of frames 0 .. last is written when output is asked every
 * `every` frames: the multiples of `every`, and always the last frame, so a
 * run ends on a picture whatever its length (one rule for every command). */
int output_frame_due(int t, int last, int every);
/* A .pvd collection: `n` datasets files[i] at times[i]. */
int output_pvd(const char *path, int n, const char *const *files, const double *times, char *err, size_t errlen);

#endif
