/*
 * json_fog.c: the "fog" section of a JSON scene (docs/scene-format.md, "fog"): participating
 * media in open space, global, in a box or in a sphere (ellipsoid), optionally heterogeneous through a "pattern" (read by
 * json_materials.c), emitting as that pattern or as its own "emission_pattern". Coefficients are per scene unit, positions in scene units.
 */
#include "io/scene_json_internal.h"

/* "fog": participating media in open space (nacre_fog_desc). */
void nc_json_parse_fog(loader *ld, const cJSON *obj)
{
    static const char *const shapes[] = {"global", "box", "sphere"};
    static const char *const keys[] = {"shape", "center", "size", "rotate", "sigma_a", "sigma_s", "g",
                                       "height_falloff", "height_base", "pattern", "emission",
                                       "emission_pattern"};
    if (!nc_json_expect_object(ld, obj) || !nc_json_require(ld, obj, "shape"))
        return;
    int shape = nc_json_get_choice(ld, obj, "shape", "fog shape", shapes, COUNT_OF(shapes));
    if (shape < 0)
        return;
    nacre_fog_desc d = nacre_fog_desc_defaults(shape == 0 ? NACRE_FOG_GLOBAL : shape == 1 ? NACRE_FOG_BOX : NACRE_FOG_SPHERE);
    nc_json_check_keys(ld, obj, keys, COUNT_OF(keys));
    if (shape != 0)
        nc_json_require(ld, obj, "size");
    if (!ld->err && shape == 0 && nc_json_member(obj, "size"))
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "\"size\" applies to box and sphere fogs only");
    static const range g_range = {-1.0, 1.0, true, true};
    nc_json_get_floats(ld, obj, "center", 3, R_FINITE, false, d.center);
    nc_json_get_floats(ld, obj, "size", 3, R_POSITIVE, true, d.size);
    nc_json_get_floats(ld, obj, "rotate", 3, R_FINITE, false, d.rotate);
    nc_json_get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    nc_json_get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    nc_json_get_floats(ld, obj, "emission", 3, R_NONNEG, true, d.emission);
    nc_json_get_number(ld, obj, "g", g_range, &d.g);
    nc_json_get_number(ld, obj, "height_falloff", R_NONNEG, &d.height_falloff);
    nc_json_get_number(ld, obj, "height_base", R_FINITE, &d.height_base);
    const cJSON *pattern = nc_json_member(obj, "pattern");
    if (pattern && !ld->err)
        nc_json_parse_pattern(ld, pattern, "pattern", false, &d.pattern);
    const cJSON *em_pattern = nc_json_member(obj, "emission_pattern");
    if (em_pattern && !ld->err)
        nc_json_parse_pattern(ld, em_pattern, "emission_pattern", true, &d.emission_pattern);
    if (ld->err)
        return;
    nacre_fog handle;
    nacre_result r = nacre_scene_add_fog(ld->scene, &d, &handle);
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
}
