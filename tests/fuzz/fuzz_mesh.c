/*
 * fuzz_mesh.c: libFuzzer target for the mesh loader (nacre_mesh_load: OBJ, ASCII and binary PLY,
 * glTF 2.0 through assimp, behind nacre's own pre-checks). The loader takes a path and assimp
 * picks its importer by extension, so the input is written to a per-process temporary file whose
 * extension comes from the content: "ply" (any case) at the start is a PLY, the binary glTF magic a .glb, a
 * '{' first (after white space) a .gltf, anything else an OBJ. A saved crash therefore reproduces
 * by copying it to a file of that extension. A mesh that loads must validate, analyse and go into
 * a scene that commits; a failure must leave the output empty with one line of message. glTF
 * inputs are also imported as scenes (nacre_scene_load_gltf) under the same rules.
 */
#include "fuzz_common.h"

/* The leaks assimp leaves behind when it throws are allocated by libstdc++'s operator new, called
 * from assimp; both are built without frame pointers, so ASan's default (frame pointer) unwinder
 * stops at operator new, the libassimp.so suppression never sees an assimp frame, and LSan reports
 * the leak as nacre's. The full unwinder finds the assimp frames; it costs this target ~15% of its
 * speed (the scene target, which reaches assimp only for the example meshes, would lose 75%). */
const char *__asan_default_options(void);
const char *__asan_default_options(void) { return "fast_unwind_on_malloc=0"; }

static const char *mesh_extension(const uint8_t *data, size_t size)
{
    /* assimp's PLY test: the first three letters, in any case. */
    if (size >= 3 && (data[0] | 0x20) == 'p' && (data[1] | 0x20) == 'l' && (data[2] | 0x20) == 'y')
        return "ply";
    if (fuzz_starts_with(data, size, "glTF", 4))
        return "glb";
    size_t i = 0;
    while (i < size && (data[i] == ' ' || data[i] == '\t' || data[i] == '\r' || data[i] == '\n'))
        i++;
    return i < size && data[i] == '{' ? "gltf" : "obj";
}

static void check_in_scene(nacre_context *ctx, const nacre_mesh_data *mesh)
{
    nacre_scene *scene = NULL;
    FUZZ_REQUIRE(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_mesh m;
    nacre_result r = nacre_scene_add_mesh(scene, mesh, &m);
    if (r == NACRE_OK) {
        nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
        nacre_material mat;
        FUZZ_REQUIRE(nacre_scene_add_material(scene, &md, &mat) == NACRE_OK);
        nacre_object_desc od = nacre_object_desc_defaults();
        od.mesh = m;
        od.material = mat;
        nacre_object obj;
        FUZZ_REQUIRE(nacre_scene_add_object(scene, &od, &obj) == NACRE_OK);
        r = nacre_scene_commit(scene, 0.0);
    }
    if (r != NACRE_OK)
        fuzz_check_failure(ctx, r);
    nacre_scene_destroy(scene);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fuzz_temp_path(path, sizeof(path), "mesh", mesh_extension(data, size));
    fuzz_write_file(path, data, size);

    nacre_context *ctx = fuzz_context();
    nacre_mesh_data mesh;
    memset(&mesh, 0xA5, sizeof(mesh)); /* the loader must clear it, also on failure */
    nacre_result r = nacre_mesh_load(ctx, path, &mesh);
    if (r == NACRE_OK) {
        FUZZ_REQUIRE(mesh.vertex_count > 0 && mesh.triangle_count > 0);
        FUZZ_REQUIRE(mesh.positions && mesh.indices && mesh.normals && mesh.tangents);
        FUZZ_REQUIRE(nacre_mesh_validate(ctx, &mesh, "fuzz") == NACRE_OK);
        nacre_mesh_info info;
        FUZZ_REQUIRE(nacre_mesh_analyze(ctx, &mesh, &info) == NACRE_OK);
        FUZZ_REQUIRE(info.vertex_count == mesh.vertex_count && info.triangle_count == mesh.triangle_count);
        check_in_scene(ctx, &mesh);
        nacre_mesh_data_free(ctx, &mesh);
    } else {
        FUZZ_REQUIRE(mesh.vertex_count == 0 && mesh.positions == NULL && mesh.indices == NULL);
        fuzz_check_failure(ctx, r);
    }
    /* glTF inputs also go through the scene importer (its own JSON and structure checks). */
    const char *ext = mesh_extension(data, size);
    if (strcmp(ext, "glb") == 0 || strcmp(ext, "gltf") == 0) {
        nacre_scene *scene = NULL;
        r = nacre_scene_load_gltf(ctx, path, NULL, &scene, NULL, NULL);
        if (r == NACRE_OK) {
            FUZZ_REQUIRE(scene != NULL && nacre_scene_object_count(scene) > 0);
            r = nacre_scene_commit(scene, 0.0);
            if (r != NACRE_OK)
                fuzz_check_failure(ctx, r);
        } else {
            FUZZ_REQUIRE(scene == NULL);
            fuzz_check_failure(ctx, r);
        }
        nacre_scene_destroy(scene);
    }
    nacre_context_destroy(ctx);
    unlink(path);
    return 0;
}
