/*
 * test_vdb.c: OpenVDB volumes (nacre_volume_load_vdb, src/io/vdb.c + vdb_read.cpp) against the
 * files of scripts/make_vdb_tests.py (tests/data/vdb_*):
 *   - the "density" grid of vdb_field.vdb holds the script's linear field on a non-uniform,
 *     translated transform: every sample and the placement match it, the one-voxel background
 *     padding included; grid selection by name;
 *   - the same cloud from vdb_cloud.vdb and from its NRRD twin: identical densities at random
 *     points through the scene, and identical path-traced images of a fog box and a material;
 *   - scene files: "grid", errors for "grid" on NRRD and "channel" on .vdb, save and reload;
 *   - bad input (missing, truncated, not a .vdb, no float grid, a vector grid, a level
 *     set, a rotated transform, a negative voxel, over the memory limit): one error naming the
 *     file, no data, no crash.
 * Built without OpenVDB, only the "built without OpenVDB" error is checked.
 */
#include "test_util.h"

#include "io/vdb.h"
#include "scene/medium.h"
#include "scene/scene.h"

#include <nacre/nacre.h>

#define DATA NACRE_SOURCE_DIR "/tests/data"
#define TMP NACRE_TEST_TMP

static nacre_context *ctx;

/* The script's field, its index box and transform. */
static const int field_min[3] = {2, 1, 0}, field_max[3] = {6, 4, 2};
static const double field_scale[3] = {0.25, 0.5, 0.125}, field_translate[3] = {1.0, -2.0, 0.5};

static float field(int i, int j, int k) { return (float)(0.5 + 0.1 * i - 0.05 * j + 0.02 * k); }

static bool error_has(const char *a, const char *b)
{
    const char *msg = nacre_context_last_error(ctx);
    bool ok = strstr(msg, a) != NULL && (!b || strstr(msg, b) != NULL);
    if (!ok)
        printf("  unexpected message: %s\n", msg);
    return ok;
}

static void field_grid(void)
{
    nacre_volume_data v = {0};
    nacre_result r = nacre_volume_load_vdb(ctx, DATA "/vdb_field.vdb", NULL, &v);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("  %s\n", nacre_context_last_error(ctx));
        return;
    }
    int bad = 0;
    for (int a = 0; a < 3; a++) {
        CHECK(v.dims[a] == (uint32_t)(field_max[a] - field_min[a] + 3));
        CHECK(v.spacing[a] == (float)field_scale[a]);
        CHECK_NEAR(v.origin[a], field_translate[a] + field_scale[a] * (field_min[a] - 1), 1e-6);
    }
    for (uint32_t k = 0; k < v.dims[2]; k++)
        for (uint32_t j = 0; j < v.dims[1]; j++)
            for (uint32_t i = 0; i < v.dims[0]; i++) {
                int x = field_min[0] - 1 + (int)i, y = field_min[1] - 1 + (int)j, z = field_min[2] - 1 + (int)k;
                bool inside = x >= field_min[0] && x <= field_max[0] && y >= field_min[1] && y <= field_max[1] &&
                              z >= field_min[2] && z <= field_max[2];
                float want = inside ? field(x, y, z) : 0.0f;
                bad += v.data[i + v.dims[0] * (j + v.dims[1] * k)] != want;
            }
    CHECK(bad == 0);
    printf("vdb field: %ux%ux%u samples, origin (%g, %g, %g), %d differ from the generating function\n", v.dims[0],
           v.dims[1], v.dims[2], (double)v.origin[0], (double)v.origin[1], (double)v.origin[2], bad);
    nacre_volume_data_free(ctx, &v);

    /* By name: the 2^3 box of 7s at the origin. */
    CHECK(nacre_volume_load_vdb(ctx, DATA "/vdb_field.vdb", "temperature", &v) == NACRE_OK);
    CHECK(v.dims[0] == 4 && v.dims[1] == 4 && v.dims[2] == 4);
    CHECK(v.data && v.data[1 + 4 * (1 + 4 * 1)] == 7.0f && v.data[0] == 0.0f);
    CHECK_NEAR(v.origin[0], field_translate[0] - field_scale[0], 1e-6);
    nacre_volume_data_free(ctx, &v);
}

/* One failing load: the result, no data, and a message that names the file and `what`. */
static void expect_error(const char *path, const char *grid, nacre_result code, const char *what)
{
    nacre_volume_data v = {0};
    nacre_result r = nacre_volume_load_vdb(ctx, path, grid, &v);
    CHECK(r == code);
    CHECK(v.data == NULL && v.dims[0] == 0);
    CHECK(error_has(path, what));
    if (r != code)
        printf("  %s: result %d, expected %d\n", path, (int)r, (int)code);
    nacre_volume_data_free(ctx, &v);
}

static void bad_grids(void)
{
    expect_error(DATA "/vdb_field.vdb", "velocity", NACRE_ERROR_UNSUPPORTED, "grid 'velocity': holds vec3s");
    expect_error(DATA "/vdb_field.vdb", "nope", NACRE_ERROR_INVALID_ARGUMENT, "grid 'nope': not in the file");
    expect_error(DATA "/vdb_vector.vdb", NULL, NACRE_ERROR_UNSUPPORTED, "no float grid");
    expect_error(DATA "/vdb_rotated.vdb", NULL, NACRE_ERROR_UNSUPPORTED, "rotated or sheared");
    expect_error(DATA "/vdb_levelset.vdb", NULL, NACRE_ERROR_UNSUPPORTED, "level set");
    expect_error(DATA "/vdb_negative.vdb", NULL, NACRE_ERROR_PARSE, "voxel (1, 2, 0) is -0.5");
    expect_error(DATA "/no_such_file.vdb", NULL, NACRE_ERROR_IO, "cannot open");
    expect_error(DATA "/vdb_cloud.nrrd", NULL, NACRE_ERROR_PARSE, "not a readable OpenVDB file");

    /* The densified cloud (10^3 floats) does not fit in 1 KiB more than the context holds. */
    nacre_context *small = NULL;
    CHECK(nacre_context_create(NULL, &small) == NACRE_OK);
    CHECK(nacre_context_set_memory_limit(small, nacre_context_memory_used(small) + 1024) == NACRE_OK);
    nacre_volume_data v = {0};
    CHECK(nacre_volume_load_vdb(small, DATA "/vdb_cloud.vdb", NULL, &v) == NACRE_ERROR_OUT_OF_MEMORY);
    CHECK(strstr(nacre_context_last_error(small), "densified to 10x10x10") != NULL);
    CHECK(strstr(nacre_context_last_error(small), "over the memory limit") != NULL);
    CHECK(v.data == NULL);
    nacre_context_destroy(small);
}

/* Cut files, at every length in a spread: one error each, never a crash or a hang. (Corrupted
 * block sizes make OpenVDB ask for impossible allocations, which end as std::bad_alloc and an
 * error in normal builds but abort under AddressSanitizer, so random corruption is not run
 * here.) */
static void truncated(void)
{
    FILE *f = fopen(DATA "/vdb_cloud.vdb", "rb");
    CHECK(f != NULL);
    if (!f)
        return;
    static uint8_t bytes[1 << 16];
    size_t n = fread(bytes, 1, sizeof(bytes), f);
    fclose(f);
    CHECK(n > 1000 && n < sizeof(bytes));
    const char *path = TMP "/broken.vdb";
    int failed = 0, cases = 0;
    for (size_t len = 0; len < n; len += len < 64 ? 7 : len / 5 + 1) {
        FILE *o = fopen(path, "wb");
        fwrite(bytes, 1, len, o);
        fclose(o);
        nacre_volume_data v = {0};
        nacre_result r = nacre_volume_load_vdb(ctx, path, NULL, &v);
        cases++;
        failed += r != NACRE_OK && v.data == NULL && strstr(nacre_context_last_error(ctx), path) != NULL;
        nacre_volume_data_free(ctx, &v);
    }
    CHECK(failed == cases);
    printf("vdb: %d of %d truncated files refused (last: %s)\n", failed, cases, nacre_context_last_error(ctx));
}

#define CLOUD_SCENE(file, grid)                                                                           \
    "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0.45, 3], \"target\": [0, 0.45, 0], "    \
    "\"height\": 1.1, \"near\": 0.01, \"far\": 10}, \"environment\": 0.5,"                                   \
    "\"lights\": [{\"type\": \"directional\", \"direction\": [-0.3, -1, -0.4], \"irradiance\": 2}],"       \
    "\"materials\": {\"m\": {\"type\": \"translucent\", \"sigma_a\": 0.5, \"sigma_s\": 5, \"eta\": 1,"                                \
    "  \"pattern\": {\"type\": \"volume\", \"volume\": \"" file "\"" grid "}}},"                          \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.3}, \"material\": \"m\","              \
    "  \"transform\": {\"translate\": [0.5, 0.2, 0]}}],"                                                    \
    "\"fog\": [{\"shape\": \"box\", \"center\": [-0.1, 0.45, 0], \"size\": 1, \"sigma_a\": 0.5, "           \
    "  \"sigma_s\": 4, \"pattern\": {\"type\": \"volume\", \"volume\": \"" file "\"" grid "}}]}"

static nacre_scene *load(const char *json)
{
    nacre_scene *s = NULL;
    nacre_scene_file_settings fs;
    nacre_result r = nacre_scene_load_json(ctx, json, strlen(json), "cloud.json", DATA, &s, &fs);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("  %s\n", nacre_context_last_error(ctx));
        return NULL;
    }
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
    return s;
}

static bool render(nacre_scene *s, nacre_image *img)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = 24;
    rs.height = 24;
    rs.pathtrace.spp = 8;
    rs.pathtrace.seed = 5;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    CHECK(nacre_image_alloc(ctx, rs.width, rs.height, 3, img) == NACRE_OK);
    nacre_result res = nacre_renderer_render(r, s, &rs, img, NULL);
    if (res != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(ctx));
    nacre_renderer_destroy(r);
    return res == NACRE_OK;
}

static void cloud_vdb_vs_nrrd(void)
{
    nacre_scene *sv = load(CLOUD_SCENE("vdb_cloud.vdb", ", \"grid\": \"density\""));
    nacre_scene *sn = load(CLOUD_SCENE("vdb_cloud.nrrd", ""));
    if (!sv || !sn) {
        nacre_scene_destroy(sv);
        nacre_scene_destroy(sn);
        return;
    }
    /* The fog's volume (handle 2: the material's came first) at random points around it. */
    nacre_volume h = {2};
    const nc_volume_rec *a = nc_scene_volume(sv, h), *b = nc_scene_volume(sn, h);
    CHECK(a && b && a->dims[0] == b->dims[0] && a->dims[1] == b->dims[1] && a->dims[2] == b->dims[2]);
    int differ = 0;
    double peak = 0.0;
    uint32_t seed = 7;
    for (int i = 0; i < 20000 && a && b; i++) {
        float p[3];
        for (int c = 0; c < 3; c++) {
            seed = seed * 1664525u + 1013904223u;
            p[c] = -0.6f + 1.2f * (float)(seed >> 8) / 16777216.0f + (c == 1 ? 0.45f : 0.0f);
        }
        float da = nc_volume_density(a, p), db = nc_volume_density(b, p);
        differ += da != db;
        peak = fmax(peak, da);
    }
    CHECK(differ == 0);
    CHECK(peak > 1.0);
    nacre_image iv = {0}, in = {0};
    if (render(sv, &iv) && render(sn, &in)) {
        double mean = 0.0, maxdiff = 0.0;
        for (size_t i = 0; i < (size_t)iv.height * iv.stride; i++) {
            mean += iv.pixels[i];
            maxdiff = fmax(maxdiff, fabs((double)iv.pixels[i] - (double)in.pixels[i]));
        }
        mean /= (double)iv.height * iv.stride;
        printf("vdb vs nrrd cloud: %d of 20000 densities differ; path tracer 24x24 at 8 spp: mean %.4f, "
               "largest pixel difference %g\n", differ, mean, maxdiff);
        CHECK(maxdiff == 0.0);
        CHECK(mean > 0.0);
    }
    nacre_image_free(ctx, &iv);
    nacre_image_free(ctx, &in);
    nacre_scene_destroy(sv);
    nacre_scene_destroy(sn);
}

static void scene_files(void)
{
    const char *bad_grid = CLOUD_SCENE("vdb_cloud.nrrd", ", \"grid\": \"density\"");
    const char *bad_channel = CLOUD_SCENE("vdb_cloud.vdb", ", \"channel\": 0");
    const char *missing = CLOUD_SCENE("vdb_cloud.vdb", ", \"grid\": \"smoke\"");
    nacre_scene *s = NULL;
    nacre_scene_file_settings fs;
    CHECK(nacre_scene_load_json(ctx, bad_grid, strlen(bad_grid), "cloud.json", DATA, &s, &fs) != NACRE_OK);
    CHECK(s == NULL && error_has("grid", "OpenVDB (.vdb) volumes only"));
    CHECK(nacre_scene_load_json(ctx, bad_channel, strlen(bad_channel), "cloud.json", DATA, &s, &fs) != NACRE_OK);
    CHECK(s == NULL && error_has("channel", "NRRD volumes only"));
    CHECK(nacre_scene_load_json(ctx, missing, strlen(missing), "cloud.json", DATA, &s, &fs) != NACRE_OK);
    CHECK(s == NULL && error_has("vdb_cloud.vdb: grid 'smoke': not in the file", "'density' (float)"));

    /* Saved and read back: the grid is kept, and so are the densities. */
    s = load(CLOUD_SCENE("vdb_cloud.vdb", ", \"grid\": \"density\", \"density_scale\": 0.5"));
    if (!s)
        return;
    char *json = NULL;
    size_t len = 0;
    CHECK(nacre_scene_save_json(s, NULL, TMP, &json, &len) == NACRE_OK);
    CHECK(json && strstr(json, "\"grid\":") && strstr(json, "vdb_cloud.vdb") && !strstr(json, "\"channel\""));
    nacre_scene *back = NULL;
    CHECK(json && nacre_scene_load_json(ctx, json, len, "saved.json", TMP, &back, &fs) == NACRE_OK);
    if (back) {
        const nc_volume_rec *a = nc_scene_volume(s, (nacre_volume){2}), *b = nc_scene_volume(back, (nacre_volume){2});
        size_t n = (size_t)a->dims[0] * a->dims[1] * a->dims[2];
        CHECK(b && b->dims[0] == a->dims[0] && memcmp(a->data, b->data, n * sizeof(float)) == 0);
        CHECK(b && b->source_grid && strcmp(b->source_grid, "density") == 0);
    }
    nacre_scene_destroy(back);
    nacre_free(ctx, json);
    nacre_scene_destroy(s);
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    if (!nc_vdb_available()) {
        nacre_volume_data v = {0};
        CHECK(nacre_volume_load_vdb(ctx, DATA "/vdb_field.vdb", NULL, &v) == NACRE_ERROR_UNSUPPORTED);
        CHECK(error_has("built without OpenVDB", NULL));
        printf("vdb: built without OpenVDB; only the error is checked\n");
    } else {
        field_grid();
        bad_grids();
        truncated();
        cloud_vdb_vs_nrrd();
        scene_files();
    }
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
