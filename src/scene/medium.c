/*
 * medium.c: coefficients of translucent materials at rest-pose points (homogeneous only for
 * now; the patterns of nacre_medium_pattern follow).
 */
#include "scene/medium.h"

void nc_medium_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *rest_xyz,
                    size_t count, float *sigma_a, float *sigma_s)
{
    (void)scene, (void)rest_xyz;
    for (size_t i = 0; i < count; i++)
        for (int c = 0; c < 3; c++) {
            sigma_a[3 * i + c] = m->sigma_a[c];
            sigma_s[3 * i + c] = m->sigma_s[c];
        }
}

void nc_medium_max_sigma_t(const nacre_scene *scene, const nacre_material_desc *m, float out[3])
{
    (void)scene;
    for (int c = 0; c < 3; c++)
        out[c] = m->sigma_a[c] + m->sigma_s[c];
}

bool nc_medium_heterogeneous(const nacre_material_desc *m) { return m->pattern.type != NACRE_PATTERN_NONE; }
