/*
 * test_cli.c: the `nacre` command end to end: exit statuses, one-line errors naming the file,
 * no output left behind on failure, --stats / --json output that parses, help and version.
 */
#include "io/image_private.h"
#include "test_util.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <nacre/nacre.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#define TMP NACRE_TEST_TMP "/cli"

/* Run `nacre ARGS`, capturing stdout and stderr; returns the exit status. */
static int run(const char *args, char *out, size_t out_cap, char *err, size_t err_cap)
{
    char cmd[4096];
    snprintf(cmd, sizeof(cmd), "%s %s >%s/stdout.txt 2>%s/stderr.txt", NACRE_CLI, args, TMP, TMP);
    int st = system(cmd);
    int code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    const char *names[2] = {"stdout.txt", "stderr.txt"};
    char *bufs[2] = {out, err};
    size_t caps[2] = {out_cap, err_cap};
    for (int i = 0; i < 2; i++) {
        if (!bufs[i])
            continue;
        char path[1024];
        snprintf(path, sizeof(path), "%s/%s", TMP, names[i]);
        FILE *f = fopen(path, "rb");
        size_t n = f ? fread(bufs[i], 1, caps[i] - 1, f) : 0;
        bufs[i][n] = '\0';
        if (f)
            fclose(f);
    }
    return code;
}

static bool exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

/* Only the final file (if any) in TMP: no *.tmp* leftovers. */
static int count_temp_files(void)
{
    char cmd[1024];
    snprintf(cmd, sizeof(cmd), "ls -a %s | grep -c tmp > %s/count.txt", TMP, NACRE_TEST_TMP);
    if (system(cmd) < 0)
        return -1;
    char path[1024];
    snprintf(path, sizeof(path), "%s/count.txt", NACRE_TEST_TMP);
    FILE *f = fopen(path, "r");
    int n = -1;
    if (f) {
        if (fscanf(f, "%d", &n) != 1)
            n = -1;
        fclose(f);
    }
    return n;
}

static char out[1 << 16], err[1 << 16];

static void test_help_version(void)
{
    CHECK(run("--version", out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "nacre") != NULL);
    const char *cmds[] = {"render", "info", "compare", "bench"};
    for (int i = 0; i < 4; i++) {
        char a[64];
        snprintf(a, sizeof(a), "%s --help", cmds[i]);
        CHECK(run(a, out, sizeof(out), err, sizeof(err)) == 0);
        CHECK(strstr(out, "usage") != NULL);
        snprintf(a, sizeof(a), "%s --version", cmds[i]);
        CHECK(run(a, out, sizeof(out), err, sizeof(err)) == 0);
    }
    CHECK(run("frobnicate", out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(run("", out, sizeof(out), err, sizeof(err)) == 2);
}

static void test_render_errors(void)
{
    char args[8192], outpng[1024];
    snprintf(outpng, sizeof(outpng), "%s/out.png", TMP);
    /* Unknown flag, unknown method, bad size, bad output extension. */
    snprintf(args, sizeof(args), "render --frobnicate -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "--frobnicate") != NULL);
    snprintf(args, sizeof(args), "render --method magic -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "magic") != NULL);
    snprintf(args, sizeof(args), "render --size 0x10 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render --size 100000x10 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render --size 16384x16384 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "pixels") != NULL);
    snprintf(args, sizeof(args), "render -o %s/out.bmp", TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    /* The layered method's options out of range: exit 2, nothing written. */
    snprintf(args, sizeof(args), "render --method layered --samples 0 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "--samples") != NULL);
    snprintf(args, sizeof(args), "render --method layered --epsilon 1 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render --method layered --integration simpson -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(!exists(outpng));
    /* and the layered example renders with it */
    snprintf(args, sizeof(args), "render %s/examples/layered.json --method layered --size 40x30 --samples 4 -o %s",
             NACRE_SOURCE_DIR, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(outpng));
    remove(outpng);
    /* and with the diffusion method (its voxels average the layers) */
    snprintf(args, sizeof(args), "render %s/examples/layered.json --method diffusion --size 40x30 -o %s",
             NACRE_SOURCE_DIR, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(outpng));
    remove(outpng);
    /* Path tracing with its variance image; --variance needs the path tracer. */
    char varexr[600];
    snprintf(varexr, sizeof(varexr), "%s/var.exr", TMP);
    snprintf(args, sizeof(args), "render --method pathtrace --size 32x24 --spp 2 --variance %s -o %s --stats", varexr,
             outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(outpng) && exists(varexr));
    CHECK(strstr(out, "\"spp\":2") != NULL);
    remove(outpng);
    snprintf(args, sizeof(args), "render --method phong --variance %s -o %s", varexr, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(!exists(outpng));
    /* Slab measurement: JSON with R and T; bad values are usage errors. */
    snprintf(args, sizeof(args), "slab --albedo 0.99 --json");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"R\":0.75") != NULL);
    snprintf(args, sizeof(args), "slab --albedo 0.9 --tau 1 --method pathtrace --samples 20000 --json");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"R_stderr\"") != NULL);
    snprintf(args, sizeof(args), "slab --albedo 1.5");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "albedo") != NULL);
    snprintf(args, sizeof(args), "slab --tau -1");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);

    /* Missing scene, malformed scene (line:col), unknown key: one line naming the file. */
    snprintf(args, sizeof(args), "render %s/missing.json -o %s", TMP, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "missing.json") != NULL);
    char bad[1024];
    snprintf(bad, sizeof(bad), "%s/bad.json", TMP);
    write_file(bad, "{\n  \"camera\": {\"fov\": 40,\n  }\n");
    snprintf(args, sizeof(args), "render %s -o %s", bad, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "bad.json:") != NULL);
    CHECK(strchr(err, '\n') == err + strlen(err) - 1); /* exactly one line */
    write_file(bad, "{\"camera\": {\"fov\": 40, \"zoom\": 2}, \"objects\": []}");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "zoom") != NULL);
    CHECK(!exists(outpng));
    /* Unwritable output: error, no file, no temp file left. */
    snprintf(args, sizeof(args), "render --size 32x24 -o %s/no/such/dir/out.png", TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "out.png") != NULL);
    CHECK(count_temp_files() == 0);
}

static void test_render_ok_and_stats(void)
{
    char args[8192], outpng[1024], outexr[1024];
    snprintf(outpng, sizeof(outpng), "%s/demo.png", TMP);
    snprintf(outexr, sizeof(outexr), "%s/demo.exr", TMP);
    snprintf(args, sizeof(args), "render --size 96x54 -o %s --stats", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(outpng));
    cJSON *j = cJSON_Parse(out);
    CHECK(j != NULL);
    /* The built-in demo shows the best real-time method: diffusion, with the stat keys. */
    const char *keys[] = {"load_us",    "commit_us", "raster_us",    "gbuffer_us", "shadow_us",  "voxelize_us",
                          "tsm_us",     "inject_us", "propagate_us", "shade_us",   "write_us",   "total_us",
                          "iterations", "residual"};
    for (int i = 0; j && i < (int)(sizeof(keys) / sizeof(keys[0])); i++)
        CHECK(cJSON_IsNumber(cJSON_GetObjectItemCaseSensitive(j, keys[i])));
    cJSON *m = j ? cJSON_GetObjectItemCaseSensitive(j, "method") : NULL;
    CHECK(cJSON_IsString(m) && strcmp(m->valuestring, "diffusion") == 0);
    cJSON *sv = j ? cJSON_GetObjectItemCaseSensitive(j, "solver") : NULL;
    CHECK(cJSON_IsString(sv) && strcmp(sv->valuestring, "multigrid") == 0);
    cJSON *dims = j ? cJSON_GetObjectItemCaseSensitive(j, "voxel_dims") : NULL;
    CHECK(cJSON_IsArray(dims) && cJSON_GetArraySize(dims) == 3);
    cJSON *res = j ? cJSON_GetObjectItemCaseSensitive(j, "residual") : NULL;
    CHECK(cJSON_IsNumber(res) && res->valuedouble <= 1e-4);
    cJSON_Delete(j);
    /* The seed's solver and face source run too. */
    snprintf(args, sizeof(args), "render --size 64x36 --solver seed --source face --voxel-res 12 -o %s --stats", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"solver\":\"seed\"") != NULL);
    snprintf(args, sizeof(args), "render --method phong --size 64x36 -o %s --stats", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"method\":\"phong\"") != NULL);
    snprintf(args, sizeof(args), "render --voxel-res 0 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render %s/examples/demo.json --size 96x54 -o %s", NACRE_SOURCE_DIR, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    /* compare: an image against itself is exact. */
    snprintf(args, sizeof(args), "compare %s %s --json", outexr, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    j = cJSON_Parse(out);
    CHECK(j != NULL);
    cJSON *rmse = j ? cJSON_GetObjectItemCaseSensitive(j, "rmse") : NULL;
    CHECK(cJSON_IsNumber(rmse) && rmse->valuedouble == 0);
    cJSON_Delete(j);
    /* compare: size mismatch is an error. */
    char small[1024];
    snprintf(small, sizeof(small), "%s/small.exr", TMP);
    snprintf(args, sizeof(args), "render --size 48x27 -o %s", small);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    snprintf(args, sizeof(args), "compare %s %s", small, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "compare %s %s/nothing.exr", small, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "nothing.exr") != NULL);
}

static void test_info(void)
{
    char args[8192];
    snprintf(args, sizeof(args), "info %s/examples/meshes/suzanne.ply --json", NACRE_SOURCE_DIR);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    cJSON *j = cJSON_Parse(out);
    CHECK(j != NULL);
    if (j) {
        /* Counts from ../shared/meshes/README.md: 968 triangles, 507 vertices, 42 / 0. */
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "triangles")->valuedouble == 968);
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "vertices")->valuedouble == 507);
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "boundary_edges")->valuedouble == 42);
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "nonmanifold_edges")->valuedouble == 0);
        CHECK(cJSON_IsFalse(cJSON_GetObjectItemCaseSensitive(j, "closed")));
    }
    cJSON_Delete(j);
    snprintf(args, sizeof(args), "info %s/none.ply", TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "none.ply") != NULL);
    CHECK(run("info", out, sizeof(out), err, sizeof(err)) == 2);
}

static long file_size(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 ? (long)sb.st_size : -1;
}

static const char sphere_scene[] =
    "{\"camera\": {\"position\": [0, 0, 5], \"target\": [0, 0, 0], \"fov\": 40},\n"
    " \"materials\": {\"m\": %s},\n"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [0, 0, -1], \"irradiance\": %s}],\n"
    " \"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 1}, \"material\": \"m\"}]}\n";

/* Issue 29 items 6 and 9: an eta that made diffusion images NaN is refused by name; a half EXR
 * that cannot hold the image's values says so and suggests --exr-float. */
static void test_ranges(void)
{
    char args[8192], scene[1024], text[2048], outexr[1024];
    snprintf(scene, sizeof(scene), "%s/eta.json", TMP);
    snprintf(outexr, sizeof(outexr), "%s/eta.exr", TMP);
    const char *etas[] = {"1e-6", "1e9"};
    for (int i = 0; i < 2; i++) {
        char mat[256];
        snprintf(mat, sizeof(mat), "{\"preset\": \"marble\", \"eta\": %s}", etas[i]);
        snprintf(text, sizeof(text), sphere_scene, mat, "1");
        write_file(scene, text);
        remove(outexr);
        snprintf(args, sizeof(args), "render %s --method diffusion --size 24x24 --voxel-res 8 -o %s", scene, outexr);
        CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
        CHECK(strstr(err, "eta.json: materials.m.eta: must be in [0.3, 3]") != NULL);
        CHECK(!exists(outexr));
    }
    /* Irradiance 1e6 on a white sphere: radiance far beyond 65504. */
    snprintf(text, sizeof(text), sphere_scene, "{\"type\": \"opaque\"}", "1e6");
    snprintf(scene, sizeof(scene), "%s/bright.json", TMP);
    write_file(scene, text);
    snprintf(outexr, sizeof(outexr), "%s/bright.exr", TMP);
    snprintf(args, sizeof(args), "render %s --method phong --size 16x16 -o %s", scene, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(err, "bright.exr:") != NULL && strstr(err, "65504") != NULL && strstr(err, "--exr-float") != NULL);
    CHECK(strchr(err, '\n') == err + strlen(err) - 1);
    nacre_context *ctx = NULL;
    nacre_image img = {0};
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    CHECK(nacre_image_read(ctx, outexr, &img) == NACRE_OK);
    float most = 0;
    for (size_t i = 0; img.pixels && i < (size_t)img.width * (size_t)img.height * 3; i++) {
        CHECK(isfinite(img.pixels[i]));
        most = img.pixels[i] > most ? img.pixels[i] : most;
    }
    CHECK(most == 65504.0f);
    nacre_image_free(ctx, &img);
    snprintf(args, sizeof(args), "render %s --method phong --size 16x16 --exr-float -o %s", scene, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(err[0] == '\0');
    CHECK(nacre_image_read(ctx, outexr, &img) == NACRE_OK);
    most = 0;
    for (size_t i = 0; img.pixels && i < (size_t)img.width * (size_t)img.height * 3; i++)
        most = img.pixels[i] > most ? img.pixels[i] : most;
    CHECK(most > 65504.0f);
    nacre_image_free(ctx, &img);
    nacre_context_destroy(ctx);
}

/* Issue 29 item 10: compare with a NaN pixel used to print max_abs_err 0 and exit 0. nacre no
 * longer writes such a file, so one is made by writing a float EXR small enough to be stored
 * uncompressed and overwriting a sentinel value's bytes with a NaN. */
static void test_compare_nonfinite(void)
{
    char nan_exr[1024], ref_exr[1024], args[4096];
    snprintf(nan_exr, sizeof(nan_exr), "%s/nan.exr", TMP);
    snprintf(ref_exr, sizeof(ref_exr), "%s/ref.exr", TMP);
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    float v[6] = {1234.5678f, 0.1234567f, 98.76543f, 3.3333f, 7.654321f, 0.0271828f};
    nacre_image img = {2, 1, 3, 6, v};
    CHECK(nc_image_write_exr(ctx, &img, ref_exr, NACRE_EXR_FLOAT) == NACRE_OK);
    CHECK(nc_image_write_exr(ctx, &img, nan_exr, NACRE_EXR_FLOAT) == NACRE_OK);
    nacre_context_destroy(ctx);
    FILE *f = fopen(nan_exr, "r+b");
    CHECK(f != NULL);
    bool patched = false;
    if (f) {
        unsigned char buf[4096];
        size_t n = fread(buf, 1, sizeof(buf), f);
        for (size_t i = 0; i + 4 <= n && !patched; i++)
            if (memcmp(buf + i, &v[0], 4) == 0) {
                float nan = NAN;
                memcpy(buf + i, &nan, 4);
                patched = fseek(f, 0, SEEK_SET) == 0 && fwrite(buf, 1, n, f) == n;
            }
        fclose(f);
    }
    CHECK(patched);
    snprintf(args, sizeof(args), "compare %s %s --json", nan_exr, ref_exr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(out, "\"nonfinite_test\":1,\"nonfinite_reference\":0") != NULL);
    CHECK(strstr(out, "\"max_abs_err\":0,") != NULL); /* the five finite values agree */
    CHECK(strstr(err, "nan.exr has 1") != NULL && strstr(err, "NaN") != NULL);
    CHECK(strchr(err, '\n') == err + strlen(err) - 1);
    snprintf(args, sizeof(args), "compare %s %s", ref_exr, nan_exr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(out, "nonfinite") != NULL);
    snprintf(args, sizeof(args), "compare %s %s --json", ref_exr, ref_exr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"nonfinite_test\":0,\"nonfinite_reference\":0") != NULL);
}

/* Issue 29 item 11: an output that names an input or another output of the same run is refused
 * however it is spelled, and nothing is touched. Item 12: a scene without objects is named. */
static void test_output_collisions(void)
{
    char args[8192], mesh[1024], scene[1024], same[1024];
    snprintf(mesh, sizeof(mesh), "%s/x.ply", TMP);
    snprintf(args, sizeof(args), "cp %s/examples/meshes/suzanne.ply %s", NACRE_SOURCE_DIR, mesh);
    CHECK(system(args) == 0);
    long size = file_size(mesh);
    const char *spellings[] = {"%s/x.ply", "%s/../cli/x.ply", "%s//./x.ply"};
    for (int i = 0; i < 3; i++) {
        char o[1200];
        snprintf(o, sizeof(o), spellings[i], TMP);
        snprintf(args, sizeof(args), "voxelize %s --res 8 -o %s", mesh, o);
        CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
        CHECK(strstr(err, "same file") != NULL && strstr(err, "x.ply") != NULL);
        CHECK(strchr(err, '\n') == err + strlen(err) - 1);
        CHECK(file_size(mesh) == size);
    }
    /* Two outputs of one render that do not exist yet. */
    snprintf(same, sizeof(same), "%s/same.exr", TMP);
    remove(same);
    snprintf(args, sizeof(args), "render --method pathtrace --size 8x8 --spp 1 --variance %s -o %s/./same.exr", same,
             TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "variance output") != NULL && strstr(err, "same file") != NULL);
    CHECK(!exists(same));
    /* The scene file itself (named like an image). */
    snprintf(scene, sizeof(scene), "%s/scene.exr", TMP);
    write_file(scene, "{\"objects\": []}");
    size = file_size(scene);
    snprintf(args, sizeof(args), "render %s -o %s", scene, scene);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "same file as the scene") != NULL);
    CHECK(file_size(scene) == size);
    /* A file the scene reads (its layered material's depth map, a PNG) named as the output. */
    char map[1024], lscene[1024];
    snprintf(map, sizeof(map), "%s/map.png", TMP);
    snprintf(args, sizeof(args), "cp %s/examples/layered_depth.png %s", NACRE_SOURCE_DIR, map);
    CHECK(system(args) == 0);
    size = file_size(map);
    snprintf(lscene, sizeof(lscene), "%s/layered_in.json", TMP);
    write_file(lscene, "{\"materials\": {\"m\": {\"preset\": \"skin2\", \"depth_map\": \"map.png\",\n"
                       "  \"layers\": [{\"preset\": \"skin1\", \"depth\": 0.5}]}},\n"
                       " \"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}]}\n");
    snprintf(args, sizeof(args), "render %s --method phong --size 8x8 -o %s/./map.png", lscene, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "same file as the scene's input") != NULL && strstr(err, "map.png") != NULL);
    CHECK(file_size(map) == size);
    /* Distinct files still work. */
    snprintf(args, sizeof(args), "render %s --method phong --size 8x8 -o %s/map_render.png", lscene, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    snprintf(args, sizeof(args), "voxelize %s --res 8 -o %s/x.nrrd", mesh, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    /* A scene without objects: the message names the file. */
    snprintf(args, sizeof(args), "render %s -o %s/empty.png", scene, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "scene.exr: scene has no objects") != NULL);
}

static bool same_bytes(const char *a, const char *b)
{
    FILE *fa = fopen(a, "rb"), *fb = fopen(b, "rb");
    bool same = fa && fb;
    for (int ca = 0, cb = 0; same && ca != EOF; ) {
        ca = fgetc(fa);
        cb = fgetc(fb);
        same = ca == cb;
    }
    if (fa)
        fclose(fa);
    if (fb)
        fclose(fb);
    return same;
}

/* --save-scene writes the scene with the command line's settings; rendering the saved file alone
 * gives the same image. */
static void test_save_scene(void)
{
    char args[4096], saved[1024], a[1024], b[1024];
    snprintf(saved, sizeof(saved), "%s/saved.json", TMP);
    snprintf(a, sizeof(a), "%s/saved_a.png", TMP);
    snprintf(b, sizeof(b), "%s/saved_b.png", TMP);
    remove(saved);
    snprintf(args, sizeof(args),
             "render %s/examples/deformers.json --method phong --size 64x48 --exposure 0.75 --time 0.5 -o %s "
             "--save-scene %s",
             NACRE_SOURCE_DIR, a, saved);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(saved) && exists(a));
    snprintf(args, sizeof(args), "render %s -o %s", saved, b);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(same_bytes(a, b));
    /* The settings are the command line's, not the example's. */
    snprintf(args, sizeof(args), "render %s -o %s --stats", saved, b);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"method\":\"phong\",\"width\":64,\"height\":48") != NULL);
    /* Not over the scene itself, nor with another suffix. */
    snprintf(args, sizeof(args), "render %s --size 8x8 -o %s --save-scene %s", saved, a, saved);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "saved scene") != NULL && strstr(err, "same file as the scene") != NULL);
    snprintf(args, sizeof(args), "render --size 8x8 -o %s --save-scene %s/saved.png", a, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "use a .json file name") != NULL);
}

/* Issue 29 item 4: sizes inside the documented ranges that used to grow until the kernel killed
 * the process now end with exit 2 and one line naming what needed how much and the limit. The
 * same runs under `ulimit -v 4194304` are in tests/limits.sh (a sanitizer build cannot run
 * under ulimit -v). */
static void test_memory_limit(void)
{
    char args[4096], path[1024], obj[1024], scene[1024];
    snprintf(obj, sizeof(obj), "%s/tri.obj", TMP);
    write_file(obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    snprintf(path, sizeof(path), "%s/huge.nrrd", TMP);
    remove(path);
    /* 34 GiB of voxel sets: over half of this machine's 24 GB and of most machines'. */
    snprintf(args, sizeof(args), "voxelize %s --res 4096 -o %s", obj, path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "voxel grid 4096x4096x4096") != NULL && strstr(err, "memory limit") != NULL);
    CHECK(strchr(err, '\n') == err + strlen(err) - 1);
    CHECK(!exists(path));
    snprintf(args, sizeof(args), "voxelize %s --res 256 --memory-limit 1M -o %s", obj, path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "memory limit of 1.00 MiB") != NULL);
    snprintf(args, sizeof(args), "voxelize %s --res 64 --memory-limit 64M -o %s", obj, path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(path));

    snprintf(path, sizeof(path), "%s/mem.png", TMP);
    remove(path); /* left by the successful render at the end of a previous run */
    snprintf(args, sizeof(args), "render --voxel-res 1024 --method diffusion -o %s", path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "diffusion grid 1024^3") != NULL && strstr(err, "memory limit") != NULL);
    CHECK(!exists(path));

    /* 50 point lights: 6 faces of 2048^2 floats each, 4.7 GiB of shadow maps. */
    snprintf(scene, sizeof(scene), "%s/lights50.json", TMP);
    FILE *f = fopen(scene, "w");
    CHECK(f != NULL);
    if (f) {
        fputs("{\"render\": {\"width\": 32, \"height\": 24},\n \"lights\": [", f);
        for (int i = 0; i < 50; i++)
            fprintf(f, "%s{\"type\": \"point\", \"position\": [%d, 3, 0], \"intensity\": 1}", i ? ", " : "", i);
        fputs("],\n \"materials\": {\"m\": {\"type\": \"opaque\"}},\n"
              " \"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}]}\n", f);
        fclose(f);
    }
    snprintf(args, sizeof(args), "render %s --memory-limit 2G -o %s", scene, path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "50 shadow maps of 2048^2") != NULL && strstr(err, "memory limit of 2.00 GiB") != NULL);
    CHECK(!exists(path));

    /* A layered material's depth map: decoded and copied into the scene, both counted. */
    char png[1024];
    snprintf(png, sizeof(png), "%s/depth2k.png", TMP);
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    nacre_image img = {0};
    CHECK(nacre_image_alloc(ctx, 2048, 2048, 4, &img) == NACRE_OK);
    for (size_t i = 0; img.pixels && i < (size_t)2048 * 2048 * 4; i++)
        img.pixels[i] = (float)(i % 7) / 7.0f;
    CHECK(nc_image_write_png(ctx, &img, png, 0.0f) == NACRE_OK);
    nacre_image_free(ctx, &img);
    nacre_context_destroy(ctx);
    snprintf(scene, sizeof(scene), "%s/layered_big.json", TMP);
    f = fopen(scene, "w");
    CHECK(f != NULL);
    if (f) {
        fputs("{\"materials\": {\"m\": {\"preset\": \"skin2\", \"depth_map\": \"depth2k.png\",\n"
              "  \"layers\": [{\"preset\": \"skin1\", \"depth\": 0.5}]}},\n"
              " \"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}]}\n", f);
        fclose(f);
    }
    snprintf(args, sizeof(args), "render %s --memory-limit 48M --method phong -o %s", scene, path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "depth2k.png") != NULL && strstr(err, "memory limit of 48.0 MiB") != NULL);
    CHECK(!exists(path));
    snprintf(args, sizeof(args), "render %s --memory-limit 256M --method phong --size 16x16 -o %s", scene, path);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);

    const char *bad[] = {"0", "-5G", "4Q", "G", ""};
    for (int i = 0; i < 5; i++) {
        snprintf(args, sizeof(args), "info %s --memory-limit '%s'", obj, bad[i]);
        CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
        CHECK(strstr(err, "--memory-limit") != NULL);
    }
    snprintf(args, sizeof(args), "render --memory-limit");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
}

int main(void)
{
    mkdir(NACRE_TEST_TMP, 0755);
    mkdir(TMP, 0755);
    test_help_version();
    test_render_errors();
    test_render_ok_and_stats();
    test_info();
    test_ranges();
    test_compare_nonfinite();
    test_output_collisions();
    test_save_scene();
    test_memory_limit();
    return TEST_MAIN_END();
}
