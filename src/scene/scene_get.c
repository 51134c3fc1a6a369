/*
 * scene_get.c: reading back a scene's descs (camera, lights, materials, objects, unit), so that
 * an editor such as `nacre view` can change one field of what a scene file set and store the
 * desc again without keeping its own copy of the scene.
 */
#include "scene/scene.h"

uint32_t nacre_scene_material_count(const nacre_scene *s) { return s ? s->material_count : 0; }

nacre_result nacre_scene_get_camera(const nacre_scene *s, nacre_camera_desc *out)
{
    if (!s || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    *out = s->has_camera ? s->camera : nacre_camera_desc_defaults();
    return NACRE_OK;
}

nacre_result nacre_scene_get_light(const nacre_scene *s, nacre_light light, nacre_light_desc *out)
{
    if (!s || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (light.id < 1 || light.id > s->light_count)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "light %u: no such light (the scene has %u)",
                       light.id, s->light_count);
    *out = s->lights[light.id - 1].desc;
    return NACRE_OK;
}

nacre_result nacre_scene_get_fog(const nacre_scene *s, nacre_fog fog, nacre_fog_desc *out)
{
    if (!s || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (fog.id < 1 || fog.id > nc_scene_user_fogs(s))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog %u: no such fog (the scene has %u)", fog.id,
                       nc_scene_user_fogs(s));
    *out = s->fogs[fog.id - 1].desc;
    return NACRE_OK;
}

nacre_result nacre_scene_get_material(const nacre_scene *s, nacre_material material, nacre_material_desc *out)
{
    if (!s || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    const nacre_material_desc *d = nc_scene_material(s, material);
    if (!d)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "material %u: no such material (the scene has %u)",
                       material.id, s->material_count);
    *out = *d;
    return NACRE_OK;
}

nacre_result nacre_scene_get_object(const nacre_scene *s, nacre_object object, nacre_object_desc *out)
{
    if (!s || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (object.id < 1 || object.id > s->object_count)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "object %u: no such object (the scene has %u)",
                       object.id, s->object_count);
    *out = s->objects[object.id - 1].desc;
    return NACRE_OK;
}

float nacre_scene_get_unit_mm(const nacre_scene *s) { return s ? s->unit_mm : 1.0f; }
