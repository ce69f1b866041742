/* render.h — pictures of a radiosity solution from a fixed camera.
 *
 * A cutaway view: primary rays cast with Embree (two threads) against the faces that turn their front
 * to the camera (the front walls and the ceilings face away from a camera above and in
 * front of the rooms, so it looks into both rooms like into a doll's house). Each pixel
 * averages ss x ss subpixels; a subpixel shows the radiosity interpolated from the face's
 * vertices (each vertex the area-weighted mean b of the faces around it in its patch),
 * tone mapped by 1 − exp(−exposure · b) and sRGB-encoded. Error maps show per face
 * |b − b_ref| / scale on a black–red–yellow–white ramp (1 = white).
 *
 * Images are written through libpng (render_write_png); the side-by-side composite is laid
 * out and labelled with cairo and written through libpng as well. */
#ifndef RADIOSITY_RENDER_H
#define RADIOSITY_RENDER_H

#include <stddef.h>

typedef struct Camera {
  double eye[3], at[3], up[3];
  double fov_deg; /* vertical */
  int width, height, ss;
} Camera;

typedef struct Image {
  int width, height;
  unsigned char *rgb; /* width x height x 3 */
} Image;

/* What each subpixel sees for one geometry: face and barycentrics (face -1: nothing). */
typedef struct View {
  int width, height, ss;
  int *face;
  float *u, *v;
} View;

/* The camera of the two-room scene. */
void render_camera_default(Camera *c);
/* Cast the view of faces tri (F x 3) at vertices g (V x 3). 0, or -1 with err. */
int render_view(const Camera *cam, long V, long F, const double *g, const int *tri, View *view, char *err,
                size_t errlen);
void render_view_free(View *view);
/* Shade b (F values) into img (allocated here). */
int render_shade(const View *view, long V, long F, const int *tri, const double *g, const double *b, double exposure,
                 Image *img);
/* The error map of b against b_ref, per face, |b - b_ref| / scale. */
int render_error(const View *view, long F, const double *b_ref, const double *b, double scale, Image *img);
/* An exposure that maps the 90th percentile of the radiosity of the faces with rho > 0
 * to 0.6 (before sRGB encoding): bright walls keep their gradients. */
double render_exposure(long F, const double *b, const double *rho);
/* The colour scales of the two renders, for their colour bars. */
typedef enum ColorScale {
  SCALE_SHADE, /* render_shade: b -> 1 - exp(-exposure b), a warm white */
  SCALE_ERROR  /* render_error: |b - b_ref| / scale, black -> red -> yellow -> white */
} ColorScale;
/* Append below img a colour bar of `scale` with its values: b from 0 to where the tone is
 * 95 % white (SCALE_SHADE, `param` the exposure) or 0 to `param` (SCALE_ERROR, the scale
 * that is white), ticks labelled in units of b, and `label` under it. 0, or -1 when
 * out of memory (img unchanged). */
int render_add_colorbar(Image *img, ColorScale scale, double param, const char *label);
void image_free(Image *img);
int render_write_png(const char *path, const Image *img, char *err, size_t errlen);
/* n images (same height) side by side, each with its label above it, one PNG. */
int render_side_by_side(const char *path, const Image *const *imgs, const char *const *labels, int n, char *err,
                        size_t errlen);

#endif
