/*
 * fuzz_scene.c: libFuzzer target for the JSON scene loader (nacre_scene_load_json, from memory,
 * the input not NUL-terminated so that a read past its end is an ASan report). Relative paths in
 * the scene resolve against examples/, so mutated scenes still reach the example meshes, depth
 * map and density volume. A scene that loads must commit (at the time its render block names)
 * and destroy; a failure must leave no scene and one line of message.
 */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    nacre_context *ctx = fuzz_context();
    nacre_scene *scene = NULL;
    nacre_scene_file_settings settings;
    nacre_result r = nacre_scene_load_json(ctx, (const char *)data, size, "fuzz.json",
                                           NACRE_SOURCE_DIR "/examples", &scene, &settings);
    if (r == NACRE_OK) {
        FUZZ_REQUIRE(scene != NULL);
        r = nacre_scene_commit(scene, settings.time);
        if (r != NACRE_OK)
            fuzz_check_failure(ctx, r);
        else if (nacre_scene_object_count(scene) > 0) {
            float lo[3], hi[3];
            FUZZ_REQUIRE(nacre_scene_bounds(scene, lo, hi) == NACRE_OK);
        }
        nacre_scene_destroy(scene);
    } else {
        FUZZ_REQUIRE(scene == NULL);
        fuzz_check_failure(ctx, r);
    }
    nacre_context_destroy(ctx);
    return 0;
}
