/* animation.c — the two trajectories through the parameter box (animation.h). */
#include "animation.h"

const char *animation_name(int a) { return a == 0 ? "window" : "ceiling"; }

void animation_params(int a, double t, SceneParams *p) {
  double u[SCENE_NGEOM];
  for (int k = 0; k < SCENE_NGEOM; k++) u[k] = 0.5;
  if (a == 0) {
    u[0] = u[1] = t; /* win_living_w, win_living_h */
  } else {
    u[8] = t;        /* tilt_deg */
    u[6] = u[7] = t; /* door_w, door_h */
  }
  scene_param_at(u, p);
}
