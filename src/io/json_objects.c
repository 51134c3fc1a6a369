/*
 * json_objects.c: the "objects" section of a JSON scene (docs/scene-format.md, "objects" with
 * "mesh", "shape", "transform" and "deformers"): mesh files (each loaded once), generated
 * shapes, transforms and deformers. Lengths are in scene units, angles in degrees.
 */
#include "io/scene_json_internal.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SHAPE_VERTICES_MAX (1u << 22)
#define SHAPE_SEGMENTS_MAX 4096u

/* ------------------------------------------------------------------------------------------ */
/* Objects: meshes, shapes, transforms, deformers                                             */
/* ------------------------------------------------------------------------------------------ */

static mesh_entry *new_mesh_entry(loader *ld)
{
    if (ld->mesh_count == ld->mesh_capacity) {
        uint32_t cap = ld->mesh_capacity ? ld->mesh_capacity * 2 : 8;
        mesh_entry *grown = nc_realloc(ld->ctx, ld->meshes, ld->mesh_count * sizeof(*grown),
                                       cap * sizeof(*grown));
        if (!grown) {
            nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
            return NULL;
        }
        ld->meshes = grown;
        ld->mesh_capacity = cap;
    }
    mesh_entry *e = &ld->meshes[ld->mesh_count];
    memset(e, 0, sizeof(*e));
    return e;
}

/* Hand generated or loaded data to the scene (which copies it) and free ours. */
static bool add_mesh_data(loader *ld, nacre_mesh_data *data, nacre_mesh *out)
{
    nacre_result r = nacre_scene_add_mesh(ld->scene, data, out);
    nacre_mesh_data_free(ld->ctx, data);
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
    return r == NACRE_OK;
}

/* The same file named twice (after resolving against the scene's folder) is loaded once. */
static bool load_mesh(loader *ld, const char *rel, nacre_mesh *out)
{
    size_t mark = nc_json_push_key(ld, "mesh");
    char *path = nc_json_resolve_path(ld, rel);
    bool ok = false;
    if (!path) {
        nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
        goto out;
    }
    for (uint32_t i = 0; i < ld->mesh_count; i++)
        if (ld->meshes[i].path && strcmp(ld->meshes[i].path, path) == 0) {
            *out = ld->meshes[i].handle;
            ok = true;
            goto out_free_path;
        }
    /* Check first so that the message names the scene field and the path as written. */
    FILE *f = fopen(path, "rb");
    if (!f) {
        char reason[128] = "cannot open";
        int e = errno;
        if (strerror_r(e, reason, sizeof(reason)) != 0)
            snprintf(reason, sizeof(reason), "error %d", e);
        char buf[NAME_SHOWN_MAX + 8];
        if (strcmp(rel, path) == 0)
            nc_json_fail(ld, NACRE_ERROR_IO, "cannot open mesh file \"%s\": %s",
                         nc_json_shown(rel, buf, sizeof(buf)), reason);
        else
            nc_json_fail(ld, NACRE_ERROR_IO, "cannot open mesh file \"%s\" (%s): %s",
                         nc_json_shown(rel, buf, sizeof(buf)), path, reason);
        goto out_free_path;
    }
    fclose(f);
    nacre_mesh_data data = {0};
    nacre_result r = nacre_mesh_load(ld->ctx, path, &data);
    if (r != NACRE_OK) {
        nacre_mesh_data_free(ld->ctx, &data);
        nc_json_fail_inner(ld, r);
        goto out_free_path;
    }
    mesh_entry *e = new_mesh_entry(ld);
    if (!e) {
        nacre_mesh_data_free(ld->ctx, &data);
        goto out_free_path;
    }
    if (!add_mesh_data(ld, &data, out))
        goto out_free_path;
    /* The scene remembers the file so that saving it refers to the file again. */
    char *absolute = nc_absolute_path(ld->ctx, path);
    nacre_result rs = absolute ? nc_scene_set_mesh_source(ld->scene, *out, absolute, NULL)
                               : NACRE_ERROR_OUT_OF_MEMORY;
    nc_free(ld->ctx, absolute);
    if (rs != NACRE_OK) {
        nc_json_fail_inner(ld, rs);
        goto out_free_path;
    }
    e->path = path;
    e->handle = *out;
    ld->mesh_count++;
    ok = true;
    goto out;
out_free_path:
    nc_free(ld->ctx, path);
out:
    nc_json_pop(ld, mark);
    return ok;
}

static bool same_shape(const nacre_shape_desc *a, const nacre_shape_desc *b)
{
    return a->type == b->type && a->radius == b->radius && a->minor_radius == b->minor_radius &&
           a->size[0] == b->size[0] && a->size[1] == b->size[1] && a->size[2] == b->size[2] &&
           a->segments == b->segments && a->rings == b->rings;
}

static void parse_plane_size(loader *ld, const cJSON *obj, nacre_shape_desc *d)
{
    const cJSON *item = nc_json_member(obj, "size");
    if (!item || ld->err)
        return;
    size_t mark = nc_json_push_key(ld, "size");
    float v[3];
    if (cJSON_IsArray(item) && cJSON_GetArraySize(item) == 2) {
        if (nc_json_read_floats(ld, item, 2, R_POSITIVE, false, v)) {
            d->size[0] = v[0];
            d->size[2] = v[1];
        }
    } else if (cJSON_IsArray(item) && cJSON_GetArraySize(item) == 3) {
        /* Allow the middle entry so a box size can be reused; a plane has no height. */
        if (nc_json_read_floats(ld, item, 3, R_NONNEG, false, v)) {
            int bad = v[0] <= 0.0f ? 0 : v[1] != 0.0f ? 1 : v[2] <= 0.0f ? 2 : -1;
            if (bad >= 0) {
                size_t m2 = nc_json_push_index(ld, bad);
                nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                             bad == 1 ? "must be 0 (a plane is flat)"
                                      : "must be positive and finite (got 0)");
                nc_json_pop(ld, m2);
            } else {
                d->size[0] = v[0];
                d->size[2] = v[2];
            }
        }
    } else if (cJSON_IsNumber(item)) {
        if (nc_json_read_floats(ld, item, 1, R_POSITIVE, true, v))
            d->size[0] = d->size[2] = v[0];
    } else if (cJSON_IsArray(item)) {
        int n = cJSON_GetArraySize(item);
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "expected [width, depth] or [width, 0, depth], got %d element%s", n, n == 1 ? "" : "s");
    } else {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "expected [width, depth], [width, 0, depth] or a number, got %s",
                     nc_json_type_name(item));
    }
    nc_json_pop(ld, mark);
}

static bool make_shape(loader *ld, const cJSON *obj, nacre_mesh *out)
{
    static const char *const types[] = {"sphere", "box", "plane", "torus"};
    static const char *const sphere_keys[] = {"type", "radius", "segments", "rings"};
    static const char *const box_keys[] = {"type", "size", "segments"};
    static const char *const torus_keys[] = {"type", "radius", "minor_radius", "segments", "rings"};
    static const nacre_shape_type kinds[] = {NACRE_SHAPE_SPHERE, NACRE_SHAPE_BOX, NACRE_SHAPE_PLANE,
                                             NACRE_SHAPE_TORUS};
    size_t mark = nc_json_push_key(ld, "shape");
    bool ok = false;
    if (!nc_json_expect_object(ld, obj) || !nc_json_require(ld, obj, "type"))
        goto out;
    int type = nc_json_get_choice(ld, obj, "type", "shape type", types, COUNT_OF(types));
    if (type < 0)
        goto out;
    nacre_shape_desc d = nacre_shape_desc_defaults(kinds[type]);
    int64_t v;
    uint32_t min_segments = 1, min_rings = 2;
    switch (kinds[type]) {
    case NACRE_SHAPE_SPHERE:
        nc_json_check_keys(ld, obj, sphere_keys, COUNT_OF(sphere_keys));
        nc_json_get_number(ld, obj, "radius", R_POSITIVE, &d.radius);
        min_segments = 3;
        break;
    case NACRE_SHAPE_BOX:
        nc_json_check_keys(ld, obj, box_keys, COUNT_OF(box_keys));
        nc_json_get_floats(ld, obj, "size", 3, R_POSITIVE, true, d.size);
        break;
    case NACRE_SHAPE_PLANE:
        nc_json_check_keys(ld, obj, box_keys, COUNT_OF(box_keys));
        parse_plane_size(ld, obj, &d);
        break;
    case NACRE_SHAPE_TORUS:
        nc_json_check_keys(ld, obj, torus_keys, COUNT_OF(torus_keys));
        nc_json_get_number(ld, obj, "radius", R_POSITIVE, &d.radius);
        nc_json_get_number(ld, obj, "minor_radius", R_POSITIVE, &d.minor_radius);
        min_segments = 3;
        min_rings = 3;
        if (!ld->err && d.minor_radius >= d.radius) {
            size_t m2 = nc_json_push_key(ld, "minor_radius");
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                         "must be smaller than radius (%g), or the torus intersects itself",
                         d.radius);
            nc_json_pop(ld, m2);
        }
        break;
    }
    if (nc_json_get_integer(ld, obj, "segments", min_segments, SHAPE_SEGMENTS_MAX, &v))
        d.segments = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "rings", min_rings, SHAPE_SEGMENTS_MAX, &v))
        d.rings = (uint32_t)v;
    if (ld->err)
        goto out;
    /* Bound the memory a few typed digits can ask for. */
    uint64_t s = d.segments + 1u, rg = d.rings + 1u;
    uint64_t vertices = kinds[type] == NACRE_SHAPE_BOX ? 6 * s * s
                        : kinds[type] == NACRE_SHAPE_PLANE ? s * s : s * rg;
    if (vertices > SHAPE_VERTICES_MAX) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "too finely subdivided (about %llu vertices; at most %u)",
                     (unsigned long long)vertices, SHAPE_VERTICES_MAX);
        goto out;
    }
    for (uint32_t i = 0; i < ld->mesh_count; i++)
        if (!ld->meshes[i].path && same_shape(&ld->meshes[i].shape, &d)) {
            *out = ld->meshes[i].handle;
            ok = true;
            goto out;
        }
    mesh_entry *e = new_mesh_entry(ld);
    if (!e)
        goto out;
    nacre_mesh_data data = {0};
    nacre_result r = nacre_mesh_make_shape(ld->ctx, &d, &data);
    if (r != NACRE_OK) {
        nacre_mesh_data_free(ld->ctx, &data);
        nc_json_fail_inner(ld, r);
        goto out;
    }
    if (!add_mesh_data(ld, &data, out))
        goto out;
    if ((r = nc_scene_set_mesh_source(ld->scene, *out, NULL, &d)) != NACRE_OK) {
        nc_json_fail_inner(ld, r);
        goto out;
    }
    e->shape = d;
    e->handle = *out;
    ld->mesh_count++;
    ok = true;
out:
    nc_json_pop(ld, mark);
    return ok;
}

static void parse_transform(loader *ld, const cJSON *obj, nacre_transform *t)
{
    static const char *const keys[] = {"translate", "rotate", "scale"};
    size_t mark = nc_json_push_key(ld, "transform");
    if (nc_json_expect_object(ld, obj) && nc_json_check_keys(ld, obj, keys, COUNT_OF(keys))) {
        nc_json_get_floats(ld, obj, "translate", 3, R_FINITE, false, t->translate);
        nc_json_get_floats(ld, obj, "rotate", 3, R_FINITE, false, t->rotate);
        nc_json_get_floats(ld, obj, "scale", 3, R_POSITIVE, true, t->scale);
    }
    nc_json_pop(ld, mark);
}

static void parse_deformer(loader *ld, const cJSON *obj, nacre_deformer *out)
{
    static const char *const types[] = {"scale", "twist", "bend"};
    static const nacre_deformer_type kinds[] = {NACRE_DEFORM_SCALE, NACRE_DEFORM_TWIST,
                                                NACRE_DEFORM_BEND};
    static const char *const scale_keys[] = {"type", "scale", "scale_rate", "center"};
    static const char *const twist_keys[] = {"type", "axis", "angle", "angle_rate", "length",
                                             "center"};
    static const char *const bend_keys[] = {"type", "axis", "direction", "angle", "angle_rate",
                                            "length", "center"};
    if (!nc_json_expect_object(ld, obj) || !nc_json_require(ld, obj, "type"))
        return;
    int type = nc_json_get_choice(ld, obj, "type", "deformer type", types, COUNT_OF(types));
    if (type < 0)
        return;
    nacre_deformer d = nacre_deformer_defaults(kinds[type]);
    if (type == 0)
        nc_json_check_keys(ld, obj, scale_keys, COUNT_OF(scale_keys));
    else if (type == 1)
        nc_json_check_keys(ld, obj, twist_keys, COUNT_OF(twist_keys));
    else
        nc_json_check_keys(ld, obj, bend_keys, COUNT_OF(bend_keys));
    nc_json_get_floats(ld, obj, "center", 3, R_FINITE, false, d.center);
    nc_json_get_floats(ld, obj, "scale", 3, R_POSITIVE, true, d.scale);
    nc_json_get_floats(ld, obj, "scale_rate", 3, R_FINITE, true, d.scale_rate);
    nc_json_get_direction(ld, obj, "axis", true, d.axis);
    nc_json_get_direction(ld, obj, "direction", true, d.direction);
    nc_json_get_number(ld, obj, "angle", R_FINITE, &d.angle);
    nc_json_get_number(ld, obj, "angle_rate", R_FINITE, &d.angle_rate);
    nc_json_get_number(ld, obj, "length", R_POSITIVE, &d.length);
    if (!ld->err && type == 2 && nc_json_sin_between(d.axis, d.direction) < 1e-3) {
        size_t mark = nc_json_push_key(ld, "direction");
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be parallel to axis");
        nc_json_pop(ld, mark);
    }
    *out = d;
}

static void parse_deformers(loader *ld, const cJSON *arr, nacre_object_desc *d)
{
    size_t mark = nc_json_push_key(ld, "deformers");
    if (!cJSON_IsArray(arr)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s",
                     nc_json_type_name(arr));
    } else if (cJSON_GetArraySize(arr) > NACRE_MAX_DEFORMERS) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "at most %d deformers per object (got %d)",
                     NACRE_MAX_DEFORMERS, cJSON_GetArraySize(arr));
    } else {
        int i = 0;
        for (const cJSON *c = arr->child; c && !ld->err; c = c->next, i++) {
            size_t m2 = nc_json_push_index(ld, i);
            parse_deformer(ld, c, &d->deformers[i]);
            nc_json_pop(ld, m2);
        }
        d->deformer_count = (uint32_t)i;
    }
    nc_json_pop(ld, mark);
}

void nc_json_parse_object(loader *ld, const cJSON *obj)
{
    static const char *const keys[] = {"name", "mesh", "shape", "material", "transform",
                                       "deformers", "shadows", "double_sided"};
    if (!nc_json_expect_object(ld, obj) || !nc_json_check_keys(ld, obj, keys, COUNT_OF(keys)))
        return;
    nacre_object_desc d = nacre_object_desc_defaults();
    const char *name = nc_json_get_string(ld, obj, "name");
    const cJSON *mesh = nc_json_member(obj, "mesh");
    const cJSON *shape = nc_json_member(obj, "shape");
    if (!ld->err && mesh && shape)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "give \"mesh\" or \"shape\", not both");
    else if (!ld->err && !mesh && !shape)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "missing required key \"mesh\" or \"shape\"");
    const char *mesh_path = mesh ? nc_json_get_string(ld, obj, "mesh") : NULL;
    nc_json_require(ld, obj, "material");
    const char *material = nc_json_get_string(ld, obj, "material");
    if (material && !nc_json_find_material(ld, material, &d.material)) {
        const char *names[8];
        uint32_t n = ld->material_count < 8 ? ld->material_count : 8;
        for (uint32_t i = 0; i < n; i++)
            names[i] = ld->materials[i].name;
        char buf[NAME_SHOWN_MAX + 8], list[512];
        size_t mark = nc_json_push_key(ld, "material");
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown material \"%s\" (defined: %s%s)",
                     nc_json_shown(material, buf, sizeof(buf)),
                     n ? nc_json_join_names(names, n, list, sizeof(list)) : "none",
                     ld->material_count > n ? ", ..." : "");
        nc_json_pop(ld, mark);
    }
    const cJSON *transform = nc_json_member(obj, "transform");
    if (transform)
        parse_transform(ld, transform, &d.transform);
    const cJSON *deformers = nc_json_member(obj, "deformers");
    if (deformers)
        parse_deformers(ld, deformers, &d);
    nc_json_get_bool(ld, obj, "shadows", &d.cast_shadows);
    nc_json_get_bool(ld, obj, "double_sided", &d.double_sided);
    /* Geometry last: every cheap check has passed before a file is read. */
    if (ld->err)
        return;
    if (mesh_path ? !load_mesh(ld, mesh_path, &d.mesh) : !make_shape(ld, shape, &d.mesh))
        return;
    d.name = name;
    nacre_object handle;
    nacre_result r = nacre_scene_add_object(ld->scene, &d, &handle);
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
}
