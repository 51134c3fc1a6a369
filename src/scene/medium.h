/*
 * medium.h: the coefficients of translucent materials at points of the object's rest pose
 * (undeformed mesh coordinates, scene units), shared by the diffusion pipeline and the path
 * tracer so both see the same medium. See medium.c for the patterns.
 */
#ifndef NACRE_MEDIUM_H
#define NACRE_MEDIUM_H

#include "scene/scene.h"

/* sigma_a and sigma_s (3 floats per point each, per scene unit) of material `m` at `count`
 * rest-pose points (3 floats each). A point with a NaN coordinate gets medium 1 (the material's
 * own coefficients). Deterministic; thread-safe. */
void nc_medium_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *rest_xyz,
                    size_t count, float *sigma_a, float *sigma_s);
/* Per-channel upper bounds of sigma_t = sigma_a + sigma_s over all points (majorants). */
void nc_medium_max_sigma_t(const nacre_scene *scene, const nacre_material_desc *m, float out[3]);
/* Whether the material's coefficients vary in space. */
bool nc_medium_heterogeneous(const nacre_material_desc *m);

#endif /* NACRE_MEDIUM_H */
