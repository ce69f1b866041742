/* design.h — the training design over the parameter box (paper §9: "extremal positions
 * along the axes of the configuration space and samples drawn from the space's interior").
 *
 * In the unit box t ∈ [0, 1]^9 of the geometric parameters (scene_param_at), in order:
 *   1. the middle (t = ½ everywhere);
 *   2. the 18 extremes of the axes: one parameter at 0 or 1, the others at ½;
 *   3. 32 corners: a 2^(9−4) fractional factorial (t_0..t_4 the bits of the index,
 *      t_5 = t_0⊕t_1⊕t_2, t_6 = t_1⊕t_2⊕t_3, t_7 = t_2⊕t_3⊕t_4, t_8 = t_0⊕t_3⊕t_4), which
 *      holds the all-low and all-high corners, puts every parameter at each end 16 times and
 *      every pair of parameters at all four combinations of ends (the full 512 corners
 *      would cost ten times as many ray-cast samples for directions PCA keeps anyway);
 *   4. the rest interior: the Halton sequence (bases 2, 3, 5, …, 23) on [0.02, 0.98]^9.
 * Radiances (e is an input): each sample's three opening radiances are Halton values in
 * [0.25, 2.5] (bases 29, 31, 37), the middle keeps the nominal (1, 1, 1.5). */
#ifndef RADIOSITY_DESIGN_H
#define RADIOSITY_DESIGN_H

#include "scene.h"

enum { DESIGN_STRUCTURED = 1 + 2 * SCENE_NGEOM + 32 }; /* middle, axis extremes, corners */

/* Sample k (0 .. n-1) of a design of n samples (n >= DESIGN_STRUCTURED; fewer keep its
 * first n points). */
void design_point(int k, SceneParams *p);
/* The weight in the PCA of each structured point of a design of n samples: w when w > 0;
 * w = 0 ("balanced"): where the interior points outnumber the structured ones, their count over
 * the structured ones', so both parts weigh alike (540 samples: 489/51 = 9.59); else 1. The
 * interior points weigh 1. */
double design_structured_weight(int n, double w);
/* True when p equals a point of the design of n samples (a test frame must not). */
int design_contains(int n, const SceneParams *p);

#endif
