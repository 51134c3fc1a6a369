/*
 * lights.h: the angular profile of a spot light, one definition for every method (the phong and
 * diffusion shading passes, the translucent shadow maps and the path tracer), so a spot lights a
 * scene the same way whichever method renders it. docs/scene-format.md ("Spot falloff") gives
 * the formulas with their sources.
 *
 * Arguments: c = cos of the angle between the spot's axis and the direction from the light to
 * the point lit; co, ci = cos of the outer and inner half-angles (co <= ci: the scene checks
 * inner <= outer). The callers compute the cosines of the half-angles once per light.
 */
#ifndef NACRE_SCENE_LIGHTS_H
#define NACRE_SCENE_LIGHTS_H

#include <nacre/scene.h>

#include "core/simd.h"

/* The factor (in [0, 1]) that multiplies a spot light's intensity in direction c.
 * - SMOOTH (default): a Hermite step in cos from the outer to the inner cone, 1 inside;
 * - CYCLES: Blender Cycles 2.8-3.x, c times that step (its spot_blend maps to the inner cone);
 * - GLTF: KHR_lights_punctual's sample, clamp((c - co) / (ci - co), 0, 1)^2.
 * ci <= co (inner = outer) is a hard cone for each: 1 (CYCLES: c) inside, 0 outside. Written with
 * the same operations in the same order as the 8-lane form below: both round alike (and the
 * SMOOTH branch as the three copies it replaced, so images did not change). */
static inline float nc_spot_falloff(nacre_spot_falloff falloff, float c, float co, float ci)
{
    if (c <= co)
        return 0.0f;
    float t = c >= ci || ci <= co ? 1.0f : (c - co) / (ci - co);
    switch (falloff) {
    case NACRE_SPOT_FALLOFF_CYCLES:
        return c * (t * t * (3.0f - 2.0f * t));
    case NACRE_SPOT_FALLOFF_GLTF:
        return t * t;
    case NACRE_SPOT_FALLOFF_SMOOTH:
    default:
        return c >= ci || ci <= co ? 1.0f : t * t * (3.0f - 2.0f * t);
    }
}

/* nc_spot_falloff on 8 lanes (the phong pass's batches); `hard` is all ones when ci <= co. */
static inline nc_v8f nc_spot_falloff8(nacre_spot_falloff falloff, nc_v8f c, float co, float ci, nc_v8i hard)
{
    const nc_v8f zero = {0}, one = nc_v8_splat(1.0f);
    const nc_v8f t = (c - co) / (ci - co);
    const nc_v8f smooth = t * t * (3.0f - 2.0f * t);
    const nc_v8i full = (c >= ci) | hard;
    nc_v8f f;
    switch (falloff) {
    case NACRE_SPOT_FALLOFF_CYCLES:
        f = c * nc_v8_sel(full, one, smooth);
        break;
    case NACRE_SPOT_FALLOFF_GLTF:
        f = nc_v8_sel(full, one, t * t);
        break;
    case NACRE_SPOT_FALLOFF_SMOOTH:
    default:
        f = nc_v8_sel(full, one, smooth);
        break;
    }
    return nc_v8_sel(c <= co, zero, f);
}

#endif /* NACRE_SCENE_LIGHTS_H */
