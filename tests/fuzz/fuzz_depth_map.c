/*
 * fuzz_depth_map.c: libFuzzer target for layered depth maps (the RGBA "subsurface texture" of a
 * layered material, examples/layered.json). The input is the map file: written to a per-process
 * temporary .png (PNG signature) or .exr, read as data the way the scene loader reads
 * "depth_map" (nacre_image_read_data), added as a texture to a scene whose layered material has
 * one layer per channel (up to NACRE_MAX_LAYERS) on a sphere with uvs, which must commit. The
 * layer stack is then resolved and queried (src/layered/layers.c) at texel centres, seams,
 * huge and non-finite uvs and depths on both sides of every layer's range.
 */
#include "fuzz_common.h"

#include "layered/layers.h"
#include "scene/scene.h"

#include <math.h>

static void check_stack(const nacre_scene *scene, const nacre_layering *layering)
{
    nc_layer_stack stack;
    nc_layers_init(scene, layering, &stack);
    FUZZ_REQUIRE(stack.map != NULL && stack.count == layering->count);
    for (uint32_t j = 0; j < stack.count; j++)
        FUZZ_REQUIRE(stack.lo[j] <= stack.hi[j] && (j == 0 || stack.hi[j - 1] <= stack.hi[j]));

    static const float uvs[] = {0.0f, 0.5f, 1.0f, 0.999999f, -0.25f, 1e-30f, 7.5f, -1e30f, 3e38f,
                                NAN, INFINITY, -INFINITY};
    const size_t nuv = sizeof(uvs) / sizeof(uvs[0]);
    float deepest = stack.count ? stack.hi[stack.count - 1] : 0.0f;
    for (size_t a = 0; a < nuv; a++)
        for (size_t b = 0; b < nuv; b += 3) {
            float u = uvs[a], v = uvs[(a + b) % nuv];
            for (int c = 0; c < stack.map->channels; c++) {
                float t = nc_texture_sample(stack.map, c, u, v);
                FUZZ_REQUIRE(t >= stack.map->min_value[c] * (1 - 1e-6f) - 1e-30f &&
                             t <= stack.map->max_value[c] * (1 + 1e-6f) + 1e-30f);
            }
            const float depths[] = {0.0f, 0.5f * deepest, deepest, 2.0f * deepest + 1.0f, NAN};
            for (size_t k = 0; k < sizeof(depths) / sizeof(depths[0]); k++) {
                uint32_t layer = nc_layers_find(&stack, depths[k], u, v);
                FUZZ_REQUIRE(layer <= stack.count);
            }
        }
    for (uint32_t j = 0; j <= stack.count; j++) {
        float top = j == 0 ? 0.0f : stack.lo[j - 1];
        FUZZ_REQUIRE(nc_layers_touching(&stack, top, top) != 0);
    }
}

static void check_map(nacre_context *ctx, const nacre_image *img)
{
    nacre_scene *scene = NULL;
    FUZZ_REQUIRE(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    nacre_layering *l = &md.layering;
    nacre_result r = nacre_scene_add_texture(scene, img, &l->depth_map);
    if (r != NACRE_OK) {
        /* Negative or non-finite samples (possible in an EXR) are refused here. */
        fuzz_check_failure(ctx, r);
        nacre_scene_destroy(scene);
        return;
    }
    static const float depth[NACRE_MAX_LAYERS] = {0.15f, 1.2f, 0.6f, 3.0f};
    l->count = img->channels < NACRE_MAX_LAYERS ? (uint32_t)img->channels : NACRE_MAX_LAYERS;
    for (uint32_t j = 0; j < l->count; j++) {
        for (int c = 0; c < 3; c++) {
            l->layers[j].sigma_a[c] = 0.1f * (float)(j + 1);
            l->layers[j].sigma_s[c] = 2.0f;
        }
        l->layers[j].depth = depth[j];
    }
    nacre_material mat;
    FUZZ_REQUIRE(nacre_scene_add_material(scene, &md, &mat) == NACRE_OK);

    /* A coarse sphere: the commit checks the material against a mesh with uvs. */
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sd.segments = 8;
    sd.rings = 4;
    nacre_mesh_data sphere = {0};
    FUZZ_REQUIRE(nacre_mesh_make_shape(ctx, &sd, &sphere) == NACRE_OK);
    nacre_mesh mesh;
    FUZZ_REQUIRE(nacre_scene_add_mesh(scene, &sphere, &mesh) == NACRE_OK);
    nacre_mesh_data_free(ctx, &sphere);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    nacre_object obj;
    FUZZ_REQUIRE(nacre_scene_add_object(scene, &od, &obj) == NACRE_OK);
    FUZZ_REQUIRE(nacre_scene_commit(scene, 0.0) == NACRE_OK);

    check_stack(scene, l);
    nacre_scene_destroy(scene);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fuzz_temp_path(path, sizeof(path), "depth", fuzz_image_extension(data, size));
    fuzz_write_file(path, data, size);

    nacre_context *ctx = fuzz_context();
    nacre_image img;
    memset(&img, 0xA5, sizeof(img)); /* the reader must clear it, also on failure */
    nacre_result r = nacre_image_read_data(ctx, path, &img);
    if (r == NACRE_OK) {
        check_map(ctx, &img);
        nacre_image_free(ctx, &img);
    } else {
        FUZZ_REQUIRE(img.pixels == NULL && img.width == 0);
        fuzz_check_failure(ctx, r);
    }
    nacre_context_destroy(ctx);
    unlink(path);
    return 0;
}
