/*
 * json_materials.c: the "materials" section of a JSON scene (docs/scene-format.md, "materials"
 * with "pattern" and "layers"): material types, presets, layers and depth maps, heterogeneous
 * patterns and NRRD or OpenVDB volumes, and the name table that objects look materials up in.
 * Coefficients written in the file are per scene unit; presets are per millimetre and are
 * converted with the scene's "units".
 */
#include "io/scene_json_internal.h"

#include <stdlib.h>
#include <string.h>

/* Names accepted by nacre_material_preset (listed in nacre/scene.h); used for the error message. */
static const char *const preset_names[] = {"apple", "chicken1", "chicken2", "cream", "ketchup",
                                           "marble", "potato", "skimmilk", "skin1", "skin2",
                                           "wholemilk", "jade", "aquamarine", "fish"};

/* A preset's coefficients per scene unit, or false after an error listing the valid names. */
static bool preset_per_unit(loader *ld, const char *key, const char *name, nacre_material_desc *d)
{
    if (!nacre_material_preset(name, d)) {
        const char *valid[COUNT_OF(preset_names)];
        size_t n = 0;
        nacre_material_desc probe;
        for (size_t i = 0; i < COUNT_OF(preset_names); i++)
            if (nacre_material_preset(preset_names[i], &probe))
                valid[n++] = preset_names[i];
        char buf[NAME_SHOWN_MAX + 8], list[512];
        size_t mark = nc_json_push_key(ld, key);
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown preset \"%s\" (valid: %s)",
                     nc_json_shown(name, buf, sizeof(buf)),
                     nc_json_join_names(valid, n, list, sizeof(list)));
        nc_json_pop(ld, mark);
        return false;
    }
    nacre_material_desc_per_unit(d, ld->unit_mm);
    return true;
}

/* True when `path` ends in ".vdb" (any case): OpenVDB, otherwise NRRD. */
static bool is_vdb_path(const char *path)
{
    size_t n = strlen(path);
    return n >= 4 && path[n - 4] == '.' && (path[n - 3] | 0x20) == 'v' && (path[n - 2] | 0x20) == 'd' &&
           (path[n - 1] | 0x20) == 'b';
}

/* "volume": an NRRD file, or an OpenVDB file (".vdb", its "grid"), relative to the scene file,
 * scaled by "density_scale", added to the scene; the handle goes into the pattern. */
static void load_volume(loader *ld, const cJSON *obj, nacre_medium_pattern *p)
{
    const char *rel = nc_json_get_string(ld, obj, "volume");
    int64_t channel = 0;
    nc_json_get_integer(ld, obj, "channel", 0, 255, &channel);
    const char *grid = nc_json_get_string(ld, obj, "grid");
    float scale = 1.0f;
    nc_json_get_number(ld, obj, "density_scale", R_NONNEG, &scale);
    if (ld->err || !rel)
        return;
    bool vdb = is_vdb_path(rel);
    if (vdb && nc_json_member(obj, "channel")) {
        size_t m = nc_json_push_key(ld, "channel");
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "NRRD volumes only (a .vdb file names its \"grid\")");
        nc_json_pop(ld, m);
        return;
    }
    if (!vdb && grid) {
        size_t m = nc_json_push_key(ld, "grid");
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "OpenVDB (.vdb) volumes only");
        nc_json_pop(ld, m);
        return;
    }
    size_t mark = nc_json_push_key(ld, "volume");
    char *path = nc_json_resolve_path(ld, rel);
    nacre_volume_data vol = {0};
    nacre_result r = !path ? NACRE_ERROR_OUT_OF_MEMORY
                     : vdb ? nacre_volume_load_vdb(ld->ctx, path, grid, &vol)
                           : nacre_volume_load_nrrd(ld->ctx, path, (uint32_t)channel, &vol);
    if (r == NACRE_OK) {
        size_t n = (size_t)vol.dims[0] * vol.dims[1] * vol.dims[2];
        for (size_t i = 0; i < n; i++)
            vol.data[i] *= scale;
        r = nacre_scene_add_volume(ld->scene, &vol, &p->volume);
    }
    if (r == NACRE_OK) {
        char *absolute = nc_absolute_path(ld->ctx, path);
        r = absolute ? nc_scene_set_volume_source(ld->scene, p->volume, absolute, (uint32_t)channel, scale)
                     : NACRE_ERROR_OUT_OF_MEMORY;
        nc_free(ld->ctx, absolute);
    }
    if (r == NACRE_OK && grid)
        r = nc_scene_set_volume_grid(ld->scene, p->volume, grid);
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
    nacre_volume_data_free(ld->ctx, &vol);
    nc_free(ld->ctx, path);
    nc_json_pop(ld, mark);
}

/* "pattern": heterogeneity of a translucent material (nacre_medium_pattern). Medium 2 comes
 * from "preset2" and/or "sigma_a2" + "sigma_s2" (explicit values override the preset's). */
void nc_json_parse_pattern(loader *ld, const cJSON *obj, const char *key, bool medium2_optional,
                           nacre_medium_pattern *p)
{
    static const char *const types[] = {"random_mix", "checker", "noise", "volume"};
    static const char *const mix_keys[] = {"type", "preset2", "sigma_a2", "sigma_s2", "cell_size",
                                           "fraction", "seed"};
    static const char *const checker_keys[] = {"type", "preset2", "sigma_a2", "sigma_s2", "cell_size"};
    static const char *const noise_keys[] = {"type", "preset2", "sigma_a2", "sigma_s2", "cell_size",
                                             "seed", "octaves"};
    static const char *const volume_keys[] = {"type", "volume", "channel", "grid", "density_scale", "blackbody",
                                              "kelvin_scale"};
    size_t mark = nc_json_push_key(ld, key);
    if (!nc_json_expect_object(ld, obj) || !nc_json_require(ld, obj, "type")) {
        nc_json_pop(ld, mark);
        return;
    }
    int type = nc_json_get_choice(ld, obj, "type", "pattern type", types, COUNT_OF(types));
    if (type < 0) {
        nc_json_pop(ld, mark);
        return;
    }
    memset(p, 0, sizeof(*p));
    p->type = (nacre_pattern_type)(NACRE_PATTERN_RANDOM_MIX + type);
    p->fraction = 0.5f;
    p->octaves = 4;
    switch (p->type) {
    case NACRE_PATTERN_RANDOM_MIX: nc_json_check_keys(ld, obj, mix_keys, COUNT_OF(mix_keys)); break;
    case NACRE_PATTERN_CHECKER: nc_json_check_keys(ld, obj, checker_keys, COUNT_OF(checker_keys)); break;
    case NACRE_PATTERN_NOISE: nc_json_check_keys(ld, obj, noise_keys, COUNT_OF(noise_keys)); break;
    default: nc_json_check_keys(ld, obj, volume_keys, COUNT_OF(volume_keys)); break;
    }
    if (p->type == NACRE_PATTERN_VOLUME) {
        if (nc_json_require(ld, obj, "volume"))
            load_volume(ld, obj, p);
        /* A temperature grid (a fog's emission_pattern; the scene checks where it stands). */
        nc_json_get_bool(ld, obj, "blackbody", &p->blackbody);
        if (p->blackbody) {
            p->kelvin_scale = 1.0f;
            nc_json_get_number(ld, obj, "kelvin_scale", R_POSITIVE, &p->kelvin_scale);
        } else if (!ld->err && nc_json_member(obj, "kelvin_scale")) {
            size_t m = nc_json_push_key(ld, "kelvin_scale");
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "needs \"blackbody\": true");
            nc_json_pop(ld, m);
        }
        nc_json_pop(ld, mark);
        return;
    }
    const char *preset2 = nc_json_get_string(ld, obj, "preset2");
    if (preset2) {
        nacre_material_desc m2;
        if (preset_per_unit(ld, "preset2", preset2, &m2)) {
            memcpy(p->sigma_a2, m2.sigma_a, sizeof(p->sigma_a2));
            memcpy(p->sigma_s2, m2.sigma_s, sizeof(p->sigma_s2));
        }
    } else if (!ld->err && !medium2_optional &&
               (!nc_json_member(obj, "sigma_a2") || !nc_json_member(obj, "sigma_s2"))) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "medium 2 needs \"preset2\" or both \"sigma_a2\" and \"sigma_s2\"");
    }
    nc_json_get_floats(ld, obj, "sigma_a2", 3, R_NONNEG, true, p->sigma_a2);
    nc_json_get_floats(ld, obj, "sigma_s2", 3, R_NONNEG, true, p->sigma_s2);
    if (nc_json_require(ld, obj, "cell_size"))
        nc_json_get_number(ld, obj, "cell_size", R_POSITIVE, &p->cell_size);
    nc_json_get_number(ld, obj, "fraction", R_UNIT, &p->fraction);
    int64_t v;
    if (nc_json_get_integer(ld, obj, "seed", 0, UINT32_MAX, &v))
        p->seed = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "octaves", 1, 12, &v))
        p->octaves = (uint32_t)v;
    nc_json_pop(ld, mark);
}

/* One entry of "layers": coefficients from "preset" and/or "sigma_a" + "sigma_s" (explicit
 * values override the preset's), "g", and the required "depth" (scene units). */
static void parse_layer(loader *ld, const cJSON *obj, nacre_layer *y)
{
    static const char *const keys[] = {"preset", "sigma_a", "sigma_s", "g", "depth"};
    if (!nc_json_expect_object(ld, obj) || !nc_json_require(ld, obj, "depth"))
        return;
    nc_json_check_keys(ld, obj, keys, COUNT_OF(keys));
    const char *preset = nc_json_get_string(ld, obj, "preset");
    if (!preset && !ld->err && (!nc_json_member(obj, "sigma_a") || !nc_json_member(obj, "sigma_s")))
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "a layer needs \"preset\" or both \"sigma_a\" and \"sigma_s\"");
    if (ld->err)
        return;
    nacre_material_desc d = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    d.g = 0.0f;
    if (preset && !preset_per_unit(ld, "preset", preset, &d))
        return;
    static const range g_range = {-1.0, 1.0, true, true};
    nc_json_get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    nc_json_get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    nc_json_get_number(ld, obj, "g", g_range, &d.g);
    nc_json_get_number(ld, obj, "depth", R_NONNEG, &y->depth);
    memcpy(y->sigma_a, d.sigma_a, sizeof(y->sigma_a));
    memcpy(y->sigma_s, d.sigma_s, sizeof(y->sigma_s));
    y->g = d.g;
}

/* "layers" (array, surface first) and "depth_map" (an image file relative to the scene file,
 * read as data: channel j scales layer j's depth) of a translucent material. */
static void parse_layering(loader *ld, const cJSON *obj, nacre_layering *l)
{
    const cJSON *arr = nc_json_member(obj, "layers");
    if (arr) {
        size_t mark = nc_json_push_key(ld, "layers");
        if (!cJSON_IsArray(arr)) {
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s",
                         nc_json_type_name(arr));
        } else if (cJSON_GetArraySize(arr) > NACRE_MAX_LAYERS) {
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "at most %d layers (got %d)",
                         NACRE_MAX_LAYERS, cJSON_GetArraySize(arr));
        } else {
            int i = 0;
            for (const cJSON *c = arr->child; c && !ld->err; c = c->next, i++) {
                size_t m2 = nc_json_push_index(ld, i);
                parse_layer(ld, c, &l->layers[i]);
                nc_json_pop(ld, m2);
            }
            l->count = (uint32_t)i;
        }
        nc_json_pop(ld, mark);
    }
    const char *rel = nc_json_get_string(ld, obj, "depth_map");
    if (ld->err || !rel)
        return;
    size_t mark = nc_json_push_key(ld, "depth_map");
    if (l->count == 0) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "a depth map needs \"layers\"");
        nc_json_pop(ld, mark);
        return;
    }
    char *path = nc_json_resolve_path(ld, rel);
    nacre_image img = {0};
    nacre_result r = path ? nacre_image_read_data(ld->ctx, path, &img) : NACRE_ERROR_OUT_OF_MEMORY;
    if (r == NACRE_OK)
        r = nacre_scene_add_texture(ld->scene, &img, &l->depth_map);
    if (r == NACRE_OK) {
        char *absolute = nc_absolute_path(ld->ctx, path);
        r = absolute ? nc_scene_set_texture_source(ld->scene, l->depth_map, absolute)
                     : NACRE_ERROR_OUT_OF_MEMORY;
        nc_free(ld->ctx, absolute);
    }
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
    nacre_image_free(ld->ctx, &img);
    nc_free(ld->ctx, path);
    nc_json_pop(ld, mark);
}

/* "diffuse_map" of an opaque material: a colour image relative to the scene file (PNG decoded
 * from sRGB to linear, EXR as it is) that multiplies "diffuse". */
static void parse_diffuse_map(loader *ld, const cJSON *obj, nacre_texture *out)
{
    const char *rel = nc_json_get_string(ld, obj, "diffuse_map");
    if (ld->err || !rel)
        return;
    size_t mark = nc_json_push_key(ld, "diffuse_map");
    char *path = nc_json_resolve_path(ld, rel);
    nacre_image img = {0};
    nacre_result r = path ? nacre_image_read(ld->ctx, path, &img) : NACRE_ERROR_OUT_OF_MEMORY;
    if (r == NACRE_OK)
        r = nacre_scene_add_texture(ld->scene, &img, out);
    if (r == NACRE_OK) {
        char *absolute = nc_absolute_path(ld->ctx, path);
        r = absolute ? nc_scene_set_texture_source(ld->scene, *out, absolute) : NACRE_ERROR_OUT_OF_MEMORY;
        nc_free(ld->ctx, absolute);
    }
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
    nacre_image_free(ld->ctx, &img);
    nc_free(ld->ctx, path);
    nc_json_pop(ld, mark);
}

/* `replace`: an imported material of the same name, which this entry overrides. */
static void parse_material(loader *ld, const cJSON *obj, const nacre_material *replace, nacre_material *out)
{
    static const char *const opaque_keys[] = {"type", "diffuse", "specular", "shininess", "diffuse_map"};
    static const char *const translucent_keys[] = {"type", "preset", "sigma_a", "sigma_s", "g",
                                                   "eta", "specular", "shininess", "pattern",
                                                   "layers", "depth_map", "multiple_scattering"};
    static const char *const types[] = {"opaque", "translucent"};
    if (!nc_json_expect_object(ld, obj))
        return;
    nacre_material_desc d = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    const char *preset = nc_json_get_string(ld, obj, "preset");
    int type = -1;
    if (nc_json_member(obj, "type"))
        type = nc_json_get_choice(ld, obj, "type", "material type", types, COUNT_OF(types));
    else if (!preset && !ld->err)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "missing required key \"type\" (or \"preset\")");
    if (ld->err)
        return;
    if (preset) {
        if (type == 0) {
            size_t mark = nc_json_push_key(ld, "type");
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "presets are translucent materials");
            nc_json_pop(ld, mark);
            return;
        }
        type = 1;
        if (!preset_per_unit(ld, "preset", preset, &d))
            return;
    } else {
        d = nacre_material_desc_defaults(type == 0 ? NACRE_MATERIAL_OPAQUE : NACRE_MATERIAL_TRANSLUCENT);
        /* The translucent default (jade) is per millimetre like the presets. */
        nacre_material_desc_per_unit(&d, ld->unit_mm);
    }
    if (type == 0)
        nc_json_check_keys(ld, obj, opaque_keys, COUNT_OF(opaque_keys));
    else
        nc_json_check_keys(ld, obj, translucent_keys, COUNT_OF(translucent_keys));
    static const range g_range = {-1.0, 1.0, true, true};
    nc_json_get_floats(ld, obj, "diffuse", 3, R_UNIT, true, d.diffuse);
    nc_json_get_floats(ld, obj, "specular", 3, R_UNIT, true, d.specular);
    nc_json_get_number(ld, obj, "shininess", R_NONNEG, &d.shininess);
    nc_json_get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    nc_json_get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    nc_json_get_number(ld, obj, "g", g_range, &d.g);
    nc_json_get_number(ld, obj, "eta", R_ETA, &d.eta);
    const cJSON *pattern = nc_json_member(obj, "pattern");
    if (pattern && type == 1 && !ld->err)
        nc_json_parse_pattern(ld, pattern, "pattern", false, &d.pattern);
    if (type == 1 && !ld->err)
        parse_layering(ld, obj, &d.layering);
    if (type == 1 && !ld->err && nc_json_member(obj, "multiple_scattering")) {
        static const char *const ms[] = {"none", "diffusion"};
        int v = nc_json_get_choice(ld, obj, "multiple_scattering", "multiple scattering", ms, COUNT_OF(ms));
        if (v >= 0)
            d.layering.multiple_scattering = (nacre_multiple_scattering)v;
    }
    if (type == 0 && !ld->err)
        parse_diffuse_map(ld, obj, &d.diffuse_map);
    if (ld->err)
        return;
    nacre_result r;
    if (replace) {
        *out = *replace;
        r = nacre_scene_set_material(ld->scene, *replace, &d);
    } else {
        r = nacre_scene_add_material(ld->scene, &d, out);
    }
    if (r != NACRE_OK)
        nc_json_fail_inner(ld, r);
}

static int compare_material_entries(const void *a, const void *b)
{
    return strcmp(((const material_entry *)a)->name, ((const material_entry *)b)->name);
}

void nc_json_parse_materials(loader *ld, const cJSON *obj)
{
    size_t mark = nc_json_push_key(ld, "materials");
    if (!nc_json_expect_object(ld, obj)) {
        nc_json_pop(ld, mark);
        return;
    }
    int count = cJSON_GetArraySize(obj);
    if (count > 0) {
        ld->materials = nc_calloc(ld->ctx, (size_t)count, sizeof(*ld->materials));
        if (!ld->materials)
            nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
    }
    for (const cJSON *c = obj->child; c && !ld->err && ld->material_count < (uint32_t)count;
         c = c->next) {
        size_t m2 = nc_json_push_key(ld, c->string);
        if (c->string[0] == '\0')
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "material names must not be empty");
        material_entry *e = &ld->materials[ld->material_count];
        const material_entry *imported = nc_json_find_imported(ld, c->string);
        parse_material(ld, c, imported ? &imported->handle : NULL, &e->handle);
        /* Kept by the scene so that saving it writes the same names. */
        if (!ld->err) {
            nacre_result r = nc_scene_set_material_name(ld->scene, e->handle, c->string);
            if (r != NACRE_OK)
                nc_json_fail_inner(ld, r);
        }
        if (!ld->err) {
            e->name = c->string;
            ld->material_count++;
        }
        nc_json_pop(ld, m2);
    }
    if (!ld->err && ld->material_count > 1)
        qsort(ld->materials, ld->material_count, sizeof(*ld->materials), compare_material_entries);
    nc_json_pop(ld, mark);
}

bool nc_json_find_material(const loader *ld, const char *name, nacre_material *out)
{
    material_entry key = {name, {0}};
    const material_entry *e = ld->material_count == 0 ? NULL
        : bsearch(&key, ld->materials, ld->material_count, sizeof(*ld->materials),
                  compare_material_entries);
    if (!e)
        e = nc_json_find_imported(ld, name);
    if (e)
        *out = e->handle;
    return e != NULL;
}
