/*
 * json_camera_lights.c: the "camera", "environment" and "lights" sections of a JSON scene
 * (docs/scene-format.md, "camera", "environment" and "lights"). Positions are in scene units,
 * angles in degrees as written in the file, colours and intensities as the C API takes them.
 */
#include "io/scene_json_internal.h"

void nc_json_parse_environment(loader *ld, const cJSON *item)
{
    size_t mark = nc_json_push_key(ld, "environment");
    float radiance[3];
    if (nc_json_read_floats(ld, item, 3, R_NONNEG, true, radiance)) {
        nacre_result r = nacre_scene_set_environment(ld->scene, radiance);
        if (r != NACRE_OK)
            nc_json_fail_inner(ld, r);
    }
    nc_json_pop(ld, mark);
}

void nc_json_parse_camera(loader *ld, const cJSON *obj)
{
    static const char *const keys[] = {"type", "position", "target", "up", "fov", "height",
                                       "near", "far"};
    static const char *const types[] = {"perspective", "orthographic"};
    size_t mark = nc_json_push_key(ld, "camera");
    if (!nc_json_expect_object(ld, obj) || !nc_json_check_keys(ld, obj, keys, COUNT_OF(keys))) {
        nc_json_pop(ld, mark);
        return;
    }
    nacre_camera_desc d = nacre_camera_desc_defaults();
    int type = nc_json_get_choice(ld, obj, "type", "camera type", types, COUNT_OF(types));
    if (type >= 0)
        d.projection = type == 0 ? NACRE_PERSPECTIVE : NACRE_ORTHOGRAPHIC;
    nc_json_get_floats(ld, obj, "position", 3, R_FINITE, false, d.position);
    nc_json_get_floats(ld, obj, "target", 3, R_FINITE, false, d.target);
    nc_json_get_direction(ld, obj, "up", false, d.up);
    static const range fov_range = {0.0, 180.0, true, true};
    nc_json_get_number(ld, obj, "fov", fov_range, &d.fov_y);
    nc_json_get_number(ld, obj, "height", R_POSITIVE, &d.ortho_height);
    nc_json_get_number(ld, obj, "near", R_NONNEG, &d.near_clip);
    nc_json_get_number(ld, obj, "far", R_NONNEG, &d.far_clip);
    if (!ld->err) {
        float view[3] = {d.target[0] - d.position[0], d.target[1] - d.position[1],
                         d.target[2] - d.position[2]};
        if (!nc_json_nonzero3(view)) {
            size_t m2 = nc_json_push_key(ld, "target");
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must differ from camera.position");
            nc_json_pop(ld, m2);
        } else if (nc_json_nonzero3(d.up) && nc_json_sin_between(view, d.up) < 1e-6) {
            size_t m2 = nc_json_push_key(ld, "up");
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                         "must not be parallel to the view direction");
            nc_json_pop(ld, m2);
        } else if (d.far_clip > 0.0f && d.far_clip <= d.near_clip) {
            size_t m2 = nc_json_push_key(ld, "far");
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                         "must be greater than near (or 0: automatic)");
            nc_json_pop(ld, m2);
        }
    }
    if (!ld->err) {
        nacre_result r = nacre_scene_set_camera(ld->scene, &d);
        if (r != NACRE_OK)
            nc_json_fail_inner(ld, r);
    }
    nc_json_pop(ld, mark);
}
void nc_json_parse_light(loader *ld, const cJSON *obj)
{
    static const char *const types[] = {"directional", "point", "spot"};
    static const char *const directional_keys[] = {"type", "direction", "irradiance", "strength",
                                                   "angular_radius", "shadows"};
    static const char *const point_keys[] = {"type", "position", "intensity", "strength", "radius",
                                             "shadows"};
    static const char *const spot_keys[] = {"type", "position", "direction", "intensity",
                                            "strength", "inner_angle", "outer_angle", "falloff",
                                            "radius", "shadows"};
    if (!nc_json_expect_object(ld, obj) || !nc_json_require(ld, obj, "type"))
        return;
    int type = nc_json_get_choice(ld, obj, "type", "light type", types, COUNT_OF(types));
    if (type < 0)
        return;
    static const nacre_light_type kinds[] = {NACRE_LIGHT_DIRECTIONAL, NACRE_LIGHT_POINT,
                                             NACRE_LIGHT_SPOT};
    nacre_light_desc d = nacre_light_desc_defaults(kinds[type]);
    const char *strength_key = type == 0 ? "irradiance" : "intensity";
    if (type == 0)
        nc_json_check_keys(ld, obj, directional_keys, COUNT_OF(directional_keys));
    else if (type == 1)
        nc_json_check_keys(ld, obj, point_keys, COUNT_OF(point_keys));
    else
        nc_json_check_keys(ld, obj, spot_keys, COUNT_OF(spot_keys));
    if (type != 1)
        nc_json_require(ld, obj, "direction");
    if (type != 0)
        nc_json_require(ld, obj, "position");
    if (!ld->err && nc_json_member(obj, strength_key) && nc_json_member(obj, "strength"))
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "give \"%s\" or \"strength\", not both", strength_key);
    nc_json_get_direction(ld, obj, "direction", false, d.direction);
    nc_json_get_floats(ld, obj, "position", 3, R_FINITE, false, d.position);
    nc_json_get_floats(ld, obj, strength_key, 3, R_NONNEG, true, d.strength);
    nc_json_get_floats(ld, obj, "strength", 3, R_NONNEG, true, d.strength);
    static const range angular_range = {0.0, 90.0, false, true};
    nc_json_get_number(ld, obj, "angular_radius", angular_range, &d.angular_radius);
    nc_json_get_number(ld, obj, "radius", R_NONNEG, &d.radius);
    /* Half-angles: a cone of 90 degrees or more has no well-defined shadow frustum. */
    static const range inner_range = {0.0, 90.0, false, true};
    static const range outer_range = {0.0, 90.0, true, true};
    nc_json_get_number(ld, obj, "inner_angle", inner_range, &d.inner_angle);
    nc_json_get_number(ld, obj, "outer_angle", outer_range, &d.outer_angle);
    nc_json_get_bool(ld, obj, "shadows", &d.cast_shadows);
    /* In the order of nacre_spot_falloff; an unknown name fails listing these. */
    static const char *const falloffs[] = {"smooth", "cycles", "gltf"};
    if (type == 2 && nc_json_member(obj, "falloff")) {
        int f = nc_json_get_choice(ld, obj, "falloff", "spot falloff", falloffs, COUNT_OF(falloffs));
        if (f >= 0)
            d.falloff = (nacre_spot_falloff)f;
    }
    if (!ld->err && type == 2 && d.inner_angle > d.outer_angle)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "inner_angle (%g) must not exceed outer_angle (%g)", d.inner_angle,
                     d.outer_angle);
    if (ld->err)
        return;
    nacre_light handle;
    nacre_result r = nacre_scene_add_light(ld->scene, &d, &handle);
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
}
