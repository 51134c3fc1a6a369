/*
 * json_import.c: the "import" key of a JSON scene (docs/scene-format.md, "import"): a glTF 2.0
 * file (src/io/gltf.c) whose meshes, materials, lights and camera become part of the scene. The
 * file's own sections then override it: a material of the same name replaces the imported one,
 * "lights" replaces all imported lights, "camera" the imported camera. Without "units" the scene
 * takes glTF's metres; with it, the glTF is converted into the scene's unit.
 */
#include "io/gltf.h"
#include "io/scene_json_internal.h"

#include <string.h>

void nc_json_parse_import(loader *ld, const cJSON *root, bool has_units)
{
    /* "import": "model.glb", or {"file": "model.glb", "thickness": "layer" | "ignore"} */
    const cJSON *spec = nc_json_member(root, "import");
    if (!spec)
        return;
    bool thickness_layer = false;
    const char *rel = NULL;
    size_t mark = nc_json_push_key(ld, "import");
    if (cJSON_IsObject(spec)) {
        static const char *const keys[] = {"file", "thickness"};
        static const char *const thickness[] = {"ignore", "layer"};
        nc_json_check_keys(ld, spec, keys, 2);
        if (nc_json_require(ld, spec, "file"))
            rel = nc_json_get_string(ld, spec, "file");
        thickness_layer = nc_json_get_choice(ld, spec, "thickness", "thickness mapping", thickness, 2) == 1;
    } else {
        nc_json_pop(ld, mark);
        rel = nc_json_get_string(ld, root, "import");
        mark = nc_json_push_key(ld, "import");
    }
    if (!rel || ld->err) {
        nc_json_pop(ld, mark);
        return;
    }
    if (!nc_gltf_is_path(rel)) {
        char buf[NAME_SHOWN_MAX + 8];
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "\"%s\": expected a .gltf or .glb file",
                     nc_json_shown(rel, buf, sizeof(buf)));
        nc_json_pop(ld, mark);
        return;
    }
    if (!has_units) {
        ld->unit_mm = 1000.0f;
        nacre_result r = nacre_scene_set_unit_mm(ld->scene, ld->unit_mm);
        if (r != NACRE_OK)
            nc_json_fail_inner(ld, r);
    }
    char *path = nc_json_resolve_path(ld, rel);
    nacre_gltf_report *rep = nc_alloc(ld->ctx, sizeof(*rep));
    if (!path || !rep) {
        nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
        goto out;
    }
    nacre_gltf_options opt = {0};
    opt.unit_mm = ld->unit_mm;
    opt.skip_lights = nc_json_member(root, "lights") != NULL;
    opt.skip_camera = nc_json_member(root, "camera") != NULL;
    opt.thickness_layer = thickness_layer;
    nacre_result r = nc_gltf_import(ld->scene, path, &opt, rep);
    if (r != NACRE_OK) {
        nc_json_fail_inner(ld, r);
        goto out;
    }
    if (rep->material_count > 0) {
        ld->imported = nc_calloc(ld->ctx, rep->material_count, sizeof(*ld->imported));
        if (!ld->imported) {
            nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
            goto out;
        }
    }
    for (uint32_t i = 0; i < rep->material_count; i++) {
        nacre_material h = {rep->first_material + i};
        const char *name = nc_scene_material_name(ld->scene, h);
        size_t n = name ? strlen(name) : 0;
        char *copy = nc_alloc(ld->ctx, n + 1);
        if (!copy) {
            nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
            goto out;
        }
        memcpy(copy, name ? name : "", n + 1);
        ld->imported[ld->imported_count++] = (material_entry){copy, h};
    }
out:
    nc_free(ld->ctx, rep);
    nc_free(ld->ctx, path);
    nc_json_pop(ld, mark);
}

const material_entry *nc_json_find_imported(const loader *ld, const char *name)
{
    for (uint32_t i = 0; i < ld->imported_count; i++)
        if (strcmp(ld->imported[i].name, name) == 0)
            return &ld->imported[i];
    return NULL;
}
