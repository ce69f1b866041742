/* animation.h — the two parameter trajectories of the example (paper §9, Fig. 8):
 *   "window":  the living-room window grows from the smallest to the largest of the box
 *              (width and height together), everything else nominal;
 *   "ceiling": the living-room ceiling tilts from 0 to 15 degrees while the door opens
 *              from the narrowest and lowest to the widest and highest.
 * Frame k of K is at t = k / (K - 1). */
#ifndef RADIOSITY_ANIMATION_H
#define RADIOSITY_ANIMATION_H

#include "scene.h"

enum { ANIM_COUNT = 2 };

const char *animation_name(int a);
/* The parameters of animation a at t in [0, 1]. */
void animation_params(int a, double t, SceneParams *p);

#endif
