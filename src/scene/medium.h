/*
 * medium.h: the coefficients of translucent materials at points of the object's rest pose
 * (undeformed mesh coordinates, scene units), shared by the diffusion pipeline and the path
 * tracer so both see the same medium. See medium.c for the patterns.
 */
#ifndef NACRE_MEDIUM_H
#define NACRE_MEDIUM_H

#include "scene/scene.h"

/* sigma_a and sigma_s (3 floats per point each, per scene unit) of material `m` at `count`
 * rest-pose points (3 floats each). A point with a NaN (or infinite) coordinate gets medium 1
 * (the material's own coefficients). Deterministic; thread-safe; no allocation. Batches of
 * 32768 points or more run on the context's threads when called outside a parallel region.
 * `scene` supplies the volumes of VOLUME patterns (and the thread count); it may be NULL, in
 * which case a VOLUME material reads as homogeneous medium 1 and the call runs serially. */
void nc_medium_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *rest_xyz,
                    size_t count, float *sigma_a, float *sigma_s);
/* Per-channel upper bounds of sigma_t = sigma_a + sigma_s over all points (majorants). Both
 * functions describe the material's core: layers (m->layering) need the object's surface and are
 * located by the path tracer (layered/layers.h). */
void nc_medium_max_sigma_t(const nacre_scene *scene, const nacre_material_desc *m, float out[3]);
/* Whether the material's coefficients vary in space. */
bool nc_medium_heterogeneous(const nacre_material_desc *m);

/* Weight of medium 2 at one rest-pose point for RANDOM_MIX, CHECKER (0 or 1) and NOISE ([0, 1]);
 * 0 for other types and non-finite points. For tests and for callers that want the pattern. */
float nc_medium_pattern_weight(const nacre_medium_pattern *pattern, const float p[3]);
/* Trilinear density of a volume at a finite rest-pose point, clamped at the grid boundary. */
float nc_volume_density(const nc_volume_rec *volume, const float p[3]);

#endif /* NACRE_MEDIUM_H */
