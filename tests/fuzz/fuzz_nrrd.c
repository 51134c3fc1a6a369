/*
 * fuzz_nrrd.c: libFuzzer target for the NRRD volume reader (nacre_volume_load_nrrd, src/io/nrrd.c)
 * behind NACRE_PATTERN_VOLUME. The input is written to a per-process temporary .nrrd file and read
 * as channel 0, then, when that loads, as channel 1 (the reader's channel-axis path; a file without
 * a second channel must fail cleanly). A volume that loads must hold finite non-negative samples
 * with positive spacings, go into a scene and answer density lookups inside, outside and at
 * non-finite points; a failure must leave the output empty with one line of message.
 */
#include "fuzz_common.h"

#include "scene/medium.h"
#include "scene/scene.h"

#include <math.h>

static void check_volume(nacre_context *ctx, const nacre_volume_data *v)
{
    uint64_t n = 1;
    for (int a = 0; a < 3; a++) {
        FUZZ_REQUIRE(v->dims[a] >= 1);
        FUZZ_REQUIRE(isfinite(v->spacing[a]) && v->spacing[a] > 0 && isfinite(v->origin[a]));
        n *= v->dims[a];
    }
    FUZZ_REQUIRE(v->data != NULL);
    for (uint64_t i = 0; i < n; i++)
        FUZZ_REQUIRE(isfinite(v->data[i]) && v->data[i] >= 0);

    nacre_scene *scene = NULL;
    FUZZ_REQUIRE(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_volume vol;
    nacre_result r = nacre_scene_add_volume(scene, v, &vol);
    if (r == NACRE_OK) {
        const nc_volume_rec *rec = nc_scene_volume(scene, vol);
        FUZZ_REQUIRE(rec != NULL);
        /* The corners and centre of the grid, points beyond it and non-finite points. */
        for (int k = 0; k < 27 + 3; k++) {
            float p[3];
            for (int a = 0; a < 3; a++) {
                float extent = v->spacing[a] * (float)(v->dims[a] - 1);
                int step = k < 27 ? (k / (a == 0 ? 1 : a == 1 ? 3 : 9)) % 3 : -1;
                p[a] = step >= 0 ? v->origin[a] + 0.5f * (float)step * extent
                       : k == 27 ? NAN : k == 28 ? INFINITY : -3e38f;
            }
            float d = nc_volume_density(rec, p);
            FUZZ_REQUIRE(isfinite(d) && d >= rec->min_value && d <= rec->max_value);
        }
    } else {
        fuzz_check_failure(ctx, r);
    }
    nacre_scene_destroy(scene);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fuzz_temp_path(path, sizeof(path), "volume", "nrrd");
    fuzz_write_file(path, data, size);

    nacre_context *ctx = fuzz_context();
    for (uint32_t channel = 0; channel < 2; channel++) {
        nacre_volume_data v;
        memset(&v, 0xA5, sizeof(v)); /* the reader must clear it, also on failure */
        nacre_result r = nacre_volume_load_nrrd(ctx, path, channel, &v);
        if (r != NACRE_OK) {
            FUZZ_REQUIRE(v.data == NULL && v.dims[0] == 0);
            fuzz_check_failure(ctx, r);
            break;
        }
        check_volume(ctx, &v);
        nacre_volume_data_free(ctx, &v);
    }
    nacre_context_destroy(ctx);
    unlink(path);
    return 0;
}
