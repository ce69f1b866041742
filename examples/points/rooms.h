/* rooms.h — the two-room scene of examples/radiosity (paper §9, Fig. 7) as a
 * TriScene for the point solver. */
#ifndef POINTS_ROOMS_H
#define POINTS_ROOMS_H

#include <stddef.h>

#include "surfels.h"

/* The living room and bedroom of examples/common/scene.h (radiosity's scene) at its nominal
 * parameters with about `faces` triangles: every triangle with its grey
 * albedo and its emission (the window and skylight openings, radiances 1,
 * 1, 1.5) on all three channels. Radiosity is unchanged by a rigid motion
 * and a uniform scale (form factors are), so the scene is scaled by its
 * length and turned upside down (x, y, z) → (x, −y, −z) into the frame of
 * the fixed camera of render.c: the picture is a plan of the floors seen from
 * above through the ceilings (which face away from the camera and are not
 * drawn). 0, or -1 with a message in err. */
int scene_rooms(TriScene *out, long faces, char *err, size_t errlen);

#endif
