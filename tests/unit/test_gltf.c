/*
 * test_gltf.c: glTF 2.0 import (src/io/gltf.c, json_import.c) against the files that
 * scripts/make_gltf_tests.py writes: the glTF scene renders the same image as the same scene
 * written as a nacre scene file (phong; the KHR_materials_volume sphere also by diffusion), the
 * material, light and camera mappings of docs/scene-format.md, units, a scene file's "import"
 * with overrides, the extension report, base colour textures (PNG and JPEG in a GLB, PNG beside
 * a .gltf), and malformed files through the CLI (one line, exit 2,
 * nothing written).
 */
#include "test_util.h"

#include <math.h>
#include <nacre/nacre.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>

#define DATA NACRE_SOURCE_DIR "/tests/data"
#define TMP NACRE_TEST_TMP "/gltf"

/* The constants scripts/make_gltf_tests.py wrote the files with. */
static const double att_color[3] = {0.5, 0.8, 0.6};
static const double att_dist = 0.01, ior = 1.45;
static const double sun_dir[3] = {-0.4, -1.0, -0.5}, sun_w = 2.5, sun_color[3] = {1.0, 0.95, 0.9};

static float nc_test_srgb(float v)
{
    return v <= 0.0031308f ? v * 12.92f : 1.055f * powf(v, 1.0f / 2.4f) - 0.055f;
}

static nacre_context *make_ctx(void)
{
    nacre_context_desc d = {0};
    d.threads = 2;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&d, &ctx) == NACRE_OK);
    return ctx;
}

static nacre_scene *load(nacre_context *ctx, const char *path, nacre_scene_file_settings *fs)
{
    nacre_scene *scene = NULL;
    nacre_result r = nacre_scene_load_file(ctx, path, &scene, fs);
    if (r != NACRE_OK)
        fprintf(stderr, "load %s: %s\n", path, nacre_context_last_error(ctx));
    CHECK(r == NACRE_OK);
    return scene;
}

/* Render at 160x120 by `method`; the image is the caller's. */
static nacre_image render(nacre_scene *scene, nacre_method method)
{
    nacre_image img = {0};
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = method;
    rs.width = 160;
    rs.height = 120;
    rs.diffusion.voxel_resolution = 16;
    CHECK(nacre_scene_commit(scene, 0.0) == NACRE_OK);
    CHECK(nacre_render(scene, &rs, &img, NULL) == NACRE_OK);
    return img;
}

/* Largest per-value difference relative to max(|b|, 1e-3), and the mean relative difference. */
static void compare(const nacre_image *a, const nacre_image *b, double *max_rel, double *mean_rel)
{
    *max_rel = *mean_rel = 0.0;
    CHECK(a->width == b->width && a->height == b->height && a->channels == b->channels);
    size_t n = (size_t)a->width * a->height * a->channels;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)a->pixels[i] - b->pixels[i]) / fmax(fabs((double)b->pixels[i]), 1e-3);
        *max_rel = fmax(*max_rel, d);
        *mean_rel += d / (double)n;
    }
}

/* A glTF and the same scene as a nacre scene file render the same image. */
static void test_pair_images(void)
{
    nacre_context *ctx = make_ctx();
    nacre_scene *g = load(ctx, DATA "/gltf_pair.glb", NULL);
    nacre_scene *n = load(ctx, DATA "/gltf_pair.json", NULL);
    if (!g || !n)
        goto out;
    /* The glTF has no environment: give both the pair file's. */
    const float env[3] = {0.05f, 0.05f, 0.05f};
    CHECK(nacre_scene_set_environment(g, env) == NACRE_OK);
    CHECK(nacre_scene_object_count(g) == 3 && nacre_scene_light_count(g) == 2);
    double max_rel, mean_rel;
    nacre_image a = render(g, NACRE_METHOD_PHONG), b = render(n, NACRE_METHOD_PHONG);
    compare(&a, &b, &max_rel, &mean_rel);
    printf("phong: max relative difference %.3g, mean %.3g\n", max_rel, mean_rel);
    /* Same triangles, float-rounded conversions of lights, camera and materials: a few pixels
     * on silhouettes may shift by a rounding step; the rest agree to float precision. */
    CHECK(max_rel < 2e-3 && mean_rel < 1e-5);
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    /* The KHR_materials_volume sphere is a translucent medium: diffusion sees its coefficients. */
    a = render(g, NACRE_METHOD_DIFFUSION);
    b = render(n, NACRE_METHOD_DIFFUSION);
    compare(&a, &b, &max_rel, &mean_rel);
    printf("diffusion: max relative difference %.3g, mean %.3g\n", max_rel, mean_rel);
    CHECK(max_rel < 2e-3 && mean_rel < 1e-5);
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
out:
    nacre_scene_destroy(g);
    nacre_scene_destroy(n);
    nacre_context_destroy(ctx);
}

/* examples/demo.json and its glTF (gltf_demo.json imports gltf_demo.glb in millimetres and
 * overrides jade and marble with the presets) render the same phong image: the shapes are the
 * same triangles, computed apart (nacre's float transforms and deformer against the script's
 * double ones), so silhouette pixels may differ; everything else agrees to float rounding. */
static void test_demo(void)
{
    nacre_context *ctx = make_ctx();
    nacre_scene_file_settings fa, fb;
    nacre_scene *a = load(ctx, DATA "/gltf_demo.json", &fa);
    nacre_scene *b = load(ctx, NACRE_SOURCE_DIR "/examples/demo.json", &fb);
    nacre_image ia = {0}, ib = {0};
    if (!a || !b)
        goto out;
    CHECK(nacre_scene_object_count(a) == 3 && nacre_scene_light_count(a) == 1);
    /* assimp numbers materials in the order it meets them (ground first here): the objects
     * must still get the glTF's own (object 1, the ground, uses glTF material 2). */
    nacre_object_desc od;
    CHECK(nacre_scene_get_object(a, (nacre_object){1}, &od) == NACRE_OK && od.material.id == 3);
    CHECK(nacre_scene_get_object(a, (nacre_object){2}, &od) == NACRE_OK && od.material.id == 1);
    fa.render.width = fb.render.width = 240;
    fa.render.height = fb.render.height = 135;
    CHECK(nacre_scene_commit(a, 0.0) == NACRE_OK && nacre_scene_commit(b, 0.0) == NACRE_OK);
    CHECK(nacre_render(a, &fa.render, &ia, NULL) == NACRE_OK);
    CHECK(nacre_render(b, &fb.render, &ib, NULL) == NACRE_OK);
    size_t n = (size_t)ia.width * ia.height * 3, off = 0;
    double mean = 0.0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)ia.pixels[i] - ib.pixels[i]) / fmax(fabs((double)ib.pixels[i]), 1e-3);
        mean += d / (double)n;
        off += d > 1e-3;
    }
    printf("demo: mean relative difference %.3g, %zu of %zu values off by more than 0.1%%\n", mean, off, n);
    CHECK(mean < 1e-5 && off * 1000 < n);
out:
    nacre_image_free(ctx, &ia);
    nacre_image_free(ctx, &ib);
    nacre_scene_destroy(a);
    nacre_scene_destroy(b);
    nacre_context_destroy(ctx);
}

/* Materials, lights and camera as docs/scene-format.md maps them; units. */
static void test_mapping(void)
{
    nacre_context *ctx = make_ctx();
    nacre_gltf_report rep;
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_pair.glb", NULL, &s, NULL, &rep) == NACRE_OK);
    if (!s)
        goto out;
    CHECK(nacre_scene_get_unit_mm(s) == 1000.0f);
    CHECK(rep.material_count == 3 && rep.objects == 3 && rep.lights == 2 && rep.cameras == 2);
    CHECK(strcmp(rep.materials[2], "ball") == 0 && rep.translucent[2] && !rep.translucent[0]);
    CHECK(rep.mapped_count == 5 && rep.ignored_count == 0);
    nacre_material_desc m;
    CHECK(nacre_scene_get_material(s, (nacre_material){rep.first_material + 2}, &m) == NACRE_OK);
    CHECK(m.type == NACRE_MATERIAL_TRANSLUCENT);
    for (int c = 0; c < 3; c++) {
        CHECK_NEAR(m.sigma_a[c], -log(att_color[c]) / att_dist, 1e-4 * -log(att_color[c]) / att_dist);
        CHECK_NEAR(m.sigma_s[c], 1000.0, 1e-3); /* 1 per mm, per metre */
    }
    CHECK_NEAR(m.eta, ior, 1e-6);
    CHECK_NEAR(m.specular[0], pow((ior - 1) / (ior + 1), 2), 1e-6);
    CHECK(nacre_scene_get_material(s, (nacre_material){rep.first_material}, &m) == NACRE_OK);
    CHECK(m.type == NACRE_MATERIAL_OPAQUE);
    CHECK_NEAR(m.diffuse[1], 0.5, 1e-6);
    CHECK_NEAR(m.specular[0], 0.02, 1e-6);          /* F0 0.04 x specularFactor 0.5 */
    CHECK_NEAR(m.shininess, 2.0 / pow(0.36, 2) - 2.0, 1e-3); /* roughness 0.6 */
    nacre_light_desc l;
    CHECK(nacre_scene_get_light(s, (nacre_light){1}, &l) == NACRE_OK);
    CHECK(l.type == NACRE_LIGHT_DIRECTIONAL);
    double len = sqrt(sun_dir[0] * sun_dir[0] + sun_dir[1] * sun_dir[1] + sun_dir[2] * sun_dir[2]);
    for (int c = 0; c < 3; c++) {
        CHECK_NEAR(l.direction[c], sun_dir[c] / len, 1e-5);
        CHECK_NEAR(l.strength[c], sun_w * sun_color[c], 1e-5); /* lux / 683 */
    }
    CHECK(nacre_scene_get_light(s, (nacre_light){2}, &l) == NACRE_OK);
    CHECK(l.type == NACRE_LIGHT_POINT);
    CHECK_NEAR(l.strength[0], 0.02, 1e-7);
    CHECK_NEAR(l.position[1], 0.5, 1e-6);
    nacre_camera_desc cam;
    CHECK(nacre_scene_get_camera(s, &cam) == NACRE_OK);
    CHECK_NEAR(cam.position[2], 0.75, 1e-6);
    CHECK_NEAR(cam.fov_y, 35.0, 1e-4);
    nacre_scene_destroy(s);
    s = NULL;

    /* --camera by camera name, and by node name; an unknown one fails naming it. */
    nacre_gltf_options opt = {0};
    opt.camera = "sidecam";
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_pair.glb", &opt, &s, NULL, NULL) == NACRE_OK);
    CHECK(s && nacre_scene_get_camera(s, &cam) == NACRE_OK && fabsf(cam.position[0] - 0.9f) < 1e-6f);
    nacre_scene_destroy(s);
    s = NULL;
    opt.camera = "side";
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_pair.glb", &opt, &s, NULL, NULL) == NACRE_OK);
    nacre_scene_destroy(s);
    s = NULL;
    opt.camera = "nope";
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_pair.glb", &opt, &s, NULL, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(s == NULL && strstr(nacre_context_last_error(ctx), "\"nope\"") != NULL);

    /* Millimetres: lengths x1000, coefficients / 1000. */
    opt.camera = NULL;
    opt.unit_mm = 1.0f;
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_pair.glb", &opt, &s, NULL, &rep) == NACRE_OK);
    if (s) {
        CHECK(nacre_scene_get_unit_mm(s) == 1.0f);
        CHECK(nacre_scene_get_camera(s, &cam) == NACRE_OK);
        CHECK_NEAR(cam.position[2], 750.0, 1e-3);
        CHECK(nacre_scene_get_material(s, (nacre_material){rep.first_material + 2}, &m) == NACRE_OK);
        CHECK_NEAR(m.sigma_a[0], -log(att_color[0]) / (att_dist * 1000.0), 1e-4);
        CHECK_NEAR(m.sigma_s[0], 1.0, 1e-6);
        float lo[3], hi[3];
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK && nacre_scene_bounds(s, lo, hi) == NACRE_OK);
        CHECK_NEAR(hi[0], 600.0, 1e-3);
    }
    nacre_scene_destroy(s);
out:
    nacre_context_destroy(ctx);
}

/* One root node (assimp then has no root of its own), a primitive without material, a metal, a
 * spot light, an orthographic camera, a base64 data: URI buffer. */
static void test_misc(void)
{
    nacre_context *ctx = make_ctx();
    nacre_gltf_report rep;
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_misc.gltf", NULL, &s, NULL, &rep) == NACRE_OK);
    if (!s)
        goto out;
    CHECK(rep.objects == 2 && rep.material_count == 2 && rep.lights == 1);
    CHECK(strcmp(rep.materials[0], "material0") == 0 && strcmp(rep.materials[1], "default") == 0);
    nacre_object_desc od;
    CHECK(nacre_scene_get_object(s, (nacre_object){1}, &od) == NACRE_OK);
    CHECK(od.material.id == rep.first_material && od.double_sided);
    CHECK(nacre_scene_get_object(s, (nacre_object){2}, &od) == NACRE_OK);
    CHECK(od.material.id == rep.first_material + 1 && !od.double_sided);
    nacre_material_desc m;
    CHECK(nacre_scene_get_material(s, (nacre_material){rep.first_material}, &m) == NACRE_OK);
    CHECK(m.diffuse[0] == 0.0f);                                     /* metal: no diffuse */
    CHECK_NEAR(m.specular[1], 0.6, 1e-6);                            /* its base colour */
    CHECK_NEAR(m.shininess, 30.0, 1e-3);                             /* roughness 0.5 */
    nacre_light_desc l;
    CHECK(nacre_scene_get_light(s, (nacre_light){1}, &l) == NACRE_OK);
    CHECK(l.type == NACRE_LIGHT_SPOT && l.falloff == NACRE_SPOT_FALLOFF_GLTF);
    CHECK_NEAR(l.position[1], 3.0, 1e-6);
    CHECK_NEAR(l.position[2], -2.0, 1e-6);
    CHECK_NEAR(l.direction[1], -1.0, 1e-6);
    CHECK_NEAR(l.inner_angle, 0.2 * 180.0 / 3.14159265358979, 1e-4);
    CHECK_NEAR(l.outer_angle, 0.6 * 180.0 / 3.14159265358979, 1e-4);
    CHECK_NEAR(l.strength[1], 0.5, 1e-6); /* 683 cd x 0.5 */
    nacre_camera_desc cam;
    CHECK(nacre_scene_get_camera(s, &cam) == NACRE_OK);
    CHECK(cam.projection == NACRE_ORTHOGRAPHIC);
    CHECK_NEAR(cam.ortho_height, 3.0, 1e-6);
    CHECK_NEAR(cam.position[2], 2.0, 1e-6);
    CHECK_NEAR(cam.near_clip, 0.1, 1e-6);
    CHECK_NEAR(cam.far_clip, 10.0, 1e-5);
    float lo[3], hi[3];
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK && nacre_scene_bounds(s, lo, hi) == NACRE_OK);
    CHECK_NEAR(hi[0], 2.0, 1e-6); /* node scale 2 */
    CHECK_NEAR(lo[2], -4.0, 1e-6);
    nacre_scene_destroy(s);
out:
    nacre_context_destroy(ctx);
}

static int warnings;
static char last_warning[512];
static void count_warning(void *user, nacre_log_level level, const char *msg)
{
    (void)user;
    if (level == NACRE_LOG_WARNING) {
        warnings++;
        snprintf(last_warning, sizeof(last_warning), "%s", msg);
    }
}

/* A .gltf with an external buffer; an extension nacre does not map is reported and warned. */
static void test_split_and_ignored(void)
{
    nacre_context_desc d = {0};
    d.threads = 2;
    d.log_fn = count_warning;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&d, &ctx) == NACRE_OK);
    nacre_gltf_report rep;
    nacre_scene *s = NULL;
    warnings = 0;
    CHECK(nacre_scene_load_gltf(ctx, DATA "/gltf_split.gltf", NULL, &s, NULL, &rep) == NACRE_OK);
    CHECK(rep.ignored_count == 1 && strcmp(rep.ignored[0], "KHR_materials_clearcoat") == 0);
    CHECK(warnings == 1 && strstr(last_warning, "KHR_materials_clearcoat") != NULL);
    CHECK(nacre_scene_object_count(s) == 3);
    nacre_scene_destroy(s);
    nacre_context_destroy(ctx);
}

/* Strings quoted from the file (a required extension's name, a buffer's uri) may hold newlines
 * and other control characters; the error and the warnings stay one printable line. */
static void test_control_characters(void)
{
    static const char *jsons[] = {
        "{\"asset\":{\"version\":\"2.0\"},\"extensionsRequired\":[\"KHR_x\\nline two\\u0001\"]}",
        "{\"asset\":{\"version\":\"2.0\"},\"buffers\":[{\"byteLength\":4,\"uri\":\"a\\r\\nb.bin\"}]}",
        "{\"asset\":{\"version\":\"2.0\"},\"extensionsUsed\":[\"EXT_\\n\\t\"],\"nodes\":[]}",
    };
    nacre_context_desc d = {0};
    d.threads = 2;
    d.log_fn = count_warning;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&d, &ctx) == NACRE_OK);
    char path[512];
    snprintf(path, sizeof(path), "%s/control.gltf", TMP);
    for (size_t i = 0; i < sizeof(jsons) / sizeof(jsons[0]); i++) {
        FILE *f = fopen(path, "wb");
        CHECK(f != NULL);
        if (!f)
            continue;
        fputs(jsons[i], f);
        fclose(f);
        last_warning[0] = '\0';
        nacre_scene *s = NULL;
        CHECK(nacre_scene_load_gltf(ctx, path, NULL, &s, NULL, NULL) != NACRE_OK && s == NULL);
        const char *msg = nacre_context_last_error(ctx);
        printf("control %zu: %s | warning: %s\n", i, msg, last_warning);
        CHECK(msg[0] && strcspn(msg, "\n\r\t\x01") == strlen(msg));
        CHECK(strcspn(last_warning, "\n\r\t") == strlen(last_warning));
        nacre_mesh_data m = {0};
        CHECK(nacre_mesh_load(ctx, path, &m) != NACRE_OK && m.positions == NULL);
        msg = nacre_context_last_error(ctx);
        CHECK(msg[0] && strcspn(msg, "\n\r\t\x01") == strlen(msg));
    }
    nacre_context_destroy(ctx);
}

/* "import" with a material override and the file's own lights. */
static void test_import(void)
{
    nacre_context *ctx = make_ctx();
    nacre_scene_file_settings fs;
    nacre_scene *s = load(ctx, DATA "/gltf_import.json", &fs);
    nacre_scene *g = load(ctx, DATA "/gltf_pair.glb", NULL);
    if (!s || !g)
        goto out;
    CHECK(fs.render.width == 160);
    CHECK(nacre_scene_get_unit_mm(s) == 1000.0f); /* no "units": glTF's metres */
    CHECK(nacre_scene_light_count(s) == 1);       /* "lights" replaces the glTF's */
    CHECK(nacre_scene_material_count(s) == 3);    /* the override replaced "ball" */
    nacre_material_desc m, marble;
    CHECK(nacre_material_preset("marble", &marble));
    nacre_material_desc_per_unit(&marble, 1000.0f);
    CHECK(nacre_scene_get_material(s, (nacre_material){3}, &m) == NACRE_OK);
    CHECK(memcmp(m.sigma_a, marble.sigma_a, sizeof(m.sigma_a)) == 0);
    CHECK(memcmp(m.sigma_s, marble.sigma_s, sizeof(m.sigma_s)) == 0);
    nacre_camera_desc a, b;
    CHECK(nacre_scene_get_camera(s, &a) == NACRE_OK && nacre_scene_get_camera(g, &b) == NACRE_OK);
    CHECK(memcmp(&a, &b, sizeof(a)) == 0); /* the glTF's camera, no "camera" to override it */

    /* A nacre object may use an imported material by name; an unknown import fails. */
    const char *json = "{\"import\": \"gltf_pair.glb\", \"objects\": [{\"shape\": {\"type\": \"sphere\"}, "
                       "\"material\": \"paint\"}]}";
    nacre_scene *t = NULL;
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "t.json", DATA, &t, NULL) == NACRE_OK);
    CHECK(t && nacre_scene_object_count(t) == 4);
    nacre_scene_destroy(t);
    t = NULL;
    json = "{\"import\": \"no_such.glb\"}";
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "t.json", DATA, &t, NULL) == NACRE_ERROR_IO);
    CHECK(strstr(nacre_context_last_error(ctx), "import") != NULL);
    json = "{\"import\": \"gltf_pair.json\"}";
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "t.json", DATA, &t, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
out:
    nacre_scene_destroy(s);
    nacre_scene_destroy(g);
    nacre_context_destroy(ctx);
}

/* Run `nacre ARGS`; stderr into err. */
static int run(const char *args, char *err, size_t cap)
{
    char cmd[2048];
    snprintf(cmd, sizeof(cmd), "%s %s >%s/stdout.txt 2>%s/stderr.txt", NACRE_CLI, args, TMP, TMP);
    int st = system(cmd);
    char path[1024];
    snprintf(path, sizeof(path), "%s/stderr.txt", TMP);
    FILE *f = fopen(path, "rb");
    size_t n = f ? fread(err, 1, cap - 1, f) : 0;
    err[n] = '\0';
    if (f)
        fclose(f);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static bool exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

/* Malformed files: one line naming the file and the problem, exit 2, no image. */
static void test_malformed_cli(void)
{
    static const struct { const char *file, *expect; } cases[] = {
        {"bad_truncated.glb", "truncated GLB"},
        {"bad_missing_buffer.gltf", "buffers[0]: cannot open \"no_such_buffer.bin\""},
        {"bad_accessor.gltf", "accessors[0]"},
        {"bad_required.gltf", "extensionsRequired: \"KHR_draco_mesh_compression\""},
    };
    char err[4096], args[1024], out_png[512];
    snprintf(out_png, sizeof(out_png), "%s/bad.png", TMP);
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        remove(out_png);
        snprintf(args, sizeof(args), "render %s/%s -o %s --size 32x32", DATA, cases[i].file, out_png);
        int code = run(args, err, sizeof(err));
        /* Warnings (ignored extensions) may precede the error; the error is the last line. */
        const char *last = err;
        for (const char *p = err; *p; p++)
            if (p[0] == '\n' && p[1])
                last = p + 1;
        printf("%s -> %d: %s", cases[i].file, code, last);
        CHECK(code == 2);
        CHECK(strstr(last, cases[i].file) != NULL && strstr(last, cases[i].expect) != NULL);
        CHECK(strncmp(last, "nacre: ", 7) == 0 && strchr(last, '\n') == last + strlen(last) - 1);
        CHECK(!exists(out_png));
        snprintf(args, sizeof(args), "info %s/%s --json", DATA, cases[i].file);
        CHECK(run(args, err, sizeof(err)) == 2);
    }
    /* A good file renders; --camera picks a camera; --camera needs a glTF. */
    snprintf(args, sizeof(args), "render %s/gltf_pair.glb --camera sidecam -o %s --size 32x32", DATA, out_png);
    CHECK(run(args, err, sizeof(err)) == 0 && exists(out_png));
    remove(out_png);
    snprintf(args, sizeof(args), "render %s/gltf_pair.json --camera sidecam -o %s", DATA, out_png);
    CHECK(run(args, err, sizeof(err)) == 2 && !exists(out_png));
    /* info --json: the report, and a warning per ignored extension on stderr. */
    snprintf(args, sizeof(args), "info %s/gltf_split.gltf --json", DATA);
    CHECK(run(args, err, sizeof(err)) == 0);
    CHECK(strstr(err, "warning") && strstr(err, "KHR_materials_clearcoat"));
    char path[512], buf[8192];
    snprintf(path, sizeof(path), "%s/stdout.txt", TMP);
    FILE *f = fopen(path, "rb");
    size_t n = f ? fread(buf, 1, sizeof(buf) - 1, f) : 0;
    buf[n] = '\0';
    if (f)
        fclose(f);
    CHECK(strstr(buf, "\"extensions_ignored\":[\"KHR_materials_clearcoat\"]") != NULL);
    CHECK(strstr(buf, "{\"name\":\"ball\",\"type\":\"translucent\"}") != NULL);
}

/* Base colour textures: the GLB (a PNG and a JPEG of the same texels in its BIN chunk) renders
 * as the nacre scene with "diffuse_map"s; the .gltf with the PNG as a file beside it renders the
 * same textured quad, and saving it refers to that PNG. The JPEG decodes to the PNG's texels
 * within what its quantisation at quality 100 allows. */
static void test_textured(void)
{
    nacre_context_desc d = {0};
    d.threads = 2;
    d.log_fn = count_warning;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&d, &ctx) == NACRE_OK);
    nacre_image a = {0}, b = {0}, c = {0};
    warnings = 0;
    nacre_scene *g = load(ctx, DATA "/gltf_textured.glb", NULL);
    CHECK(warnings == 0);
    {
        nacre_image png = {0}, jpg = {0};
        CHECK(nacre_image_read(ctx, DATA "/gltf_textured.png", &png) == NACRE_OK);
        CHECK(nacre_image_read(ctx, DATA "/gltf_textured.jpg", &jpg) == NACRE_OK);
        CHECK(jpg.width == 8 && jpg.height == 8 && jpg.channels == 3 && png.width == 8 && png.channels == 3);
        double worst = 1, spread = 0;
        if (jpg.pixels && png.pixels && jpg.width == png.width && jpg.height == png.height) {
            worst = 0;
            for (size_t i = 0; i < 8 * 8 * 3; i++) {
                /* Compared in sRGB code values, where JPEG's error is uniform */
                float a = nc_test_srgb(jpg.pixels[i]), b = nc_test_srgb(png.pixels[i]);
                worst = fmax(worst, fabs(a - b));
                spread = fmax(spread, fabs(b - nc_test_srgb(png.pixels[0])));
            }
        }
        printf("JPEG against PNG texels: largest difference %.4f (of 1), texel spread %.3f\n", worst, spread);
        CHECK(worst < 4.0 / 255.0 && spread > 0.5);
        nacre_image_free(ctx, &png);
        nacre_image_free(ctx, &jpg);
    }
    nacre_scene_file_settings fs;
    nacre_scene *n = load(ctx, DATA "/gltf_textured.json", &fs);
    nacre_scene *f = load(ctx, DATA "/gltf_textured.gltf", NULL);
    if (!g || !n || !f)
        goto out;
    const float env[3] = {0.1f, 0.1f, 0.1f};
    CHECK(nacre_scene_set_environment(g, env) == NACRE_OK);
    CHECK(nacre_scene_set_environment(f, env) == NACRE_OK);
    nacre_material_desc m0, m1;
    CHECK(nacre_scene_get_material(g, (nacre_material){1}, &m0) == NACRE_OK && m0.diffuse_map.id != 0);
    CHECK(nacre_scene_get_material(g, (nacre_material){2}, &m1) == NACRE_OK && m1.diffuse_map.id != 0);
    CHECK(nacre_scene_commit(g, 0) == NACRE_OK && nacre_render(g, &fs.render, &a, NULL) == NACRE_OK);
    CHECK(nacre_scene_commit(n, 0) == NACRE_OK && nacre_render(n, &fs.render, &b, NULL) == NACRE_OK);
    CHECK(nacre_scene_commit(f, 0) == NACRE_OK && nacre_render(f, &fs.render, &c, NULL) == NACRE_OK);
    double max_rel = 1, mean_rel = 1;
    if (a.pixels && b.pixels) {
        compare(&a, &b, &max_rel, &mean_rel);
        printf("textured glb: max relative difference %.3g, mean %.3g\n", max_rel, mean_rel);
        CHECK(max_rel < 2e-3 && mean_rel < 1e-5);
        /* The texture shows: the textured quad's pixels vary (8 texels across 58 pixels) */
        float lo = INFINITY, hi = 0;
        for (int x = 10; x < 50; x++) {
            float v = a.pixels[(size_t)(32 * a.width + x) * 3];
            lo = fminf(lo, v);
            hi = fmaxf(hi, v);
        }
        CHECK(hi > 2 * lo);
        /* and so does the JPEG one's (x from 70 to 128) */
        lo = INFINITY;
        hi = 0;
        for (int x = 75; x < 120; x++) {
            float v = a.pixels[(size_t)(32 * a.width + x) * 3];
            lo = fminf(lo, v);
            hi = fmaxf(hi, v);
        }
        CHECK(hi > 2 * lo);
    }
    /* The .gltf holds only the textured quad: it matches the left half */
    if (c.pixels && b.pixels) {
        double worst = 0;
        for (int y = 0; y < c.height; y++)
            for (int x = 0; x < 55; x++)
                for (int k = 0; k < 3; k++) {
                    size_t i = ((size_t)y * (size_t)c.width + (size_t)x) * 3 + (size_t)k;
                    worst = fmax(worst, fabs(c.pixels[i] - b.pixels[i]) / fmax(fabs(b.pixels[i]), 1e-3));
                }
        printf("textured gltf: max relative difference %.3g on the textured quad\n", worst);
        CHECK(worst < 2e-3);
    }
    /* Saved, the .gltf's texture is its PNG file */
    {
        char *json = NULL;
        size_t len = 0;
        mkdir(TMP, 0755);
        CHECK(nacre_scene_save_file(f, NULL, TMP "/textured_saved.json") == NACRE_OK);
        FILE *fp = fopen(TMP "/textured_saved.json", "rb");
        if (fp) {
            json = calloc(1, 1 << 16);
            len = fread(json, 1, (1 << 16) - 1, fp);
            fclose(fp);
        }
        CHECK(len > 0 && json && strstr(json, "\"diffuse_map\"") && strstr(json, "gltf_textured.png"));
        free(json);
    }
    /* The GLB's embedded texture is written as <name>_texture<id>.exr and loads back to the
     * same image */
    {
        CHECK(nacre_scene_save_file(g, NULL, TMP "/glb_saved.json") == NACRE_OK);
        struct stat st;
        CHECK(stat(TMP "/glb_saved_texture1.exr", &st) == 0);
        nacre_scene *back = load(ctx, TMP "/glb_saved.json", NULL);
        nacre_image e = {0};
        if (back && nacre_scene_commit(back, 0) == NACRE_OK && nacre_render(back, &fs.render, &e, NULL) == NACRE_OK &&
            a.pixels) {
            compare(&e, &a, &max_rel, &mean_rel);
            printf("textured glb saved and loaded: max relative difference %.3g\n", max_rel);
            CHECK(max_rel < 1e-5);
        } else {
            CHECK(!"saved textured glb renders");
        }
        nacre_image_free(ctx, &e);
        nacre_scene_destroy(back);
    }
out:
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    nacre_image_free(ctx, &c);
    nacre_scene_destroy(g);
    nacre_scene_destroy(n);
    nacre_scene_destroy(f);
    nacre_context_destroy(ctx);
}

/* KHR_materials_volume's thickness texture as a one-layer depth map, only when asked
 * (nacre_gltf_options.thickness_layer, "import": {"thickness": "layer"}, --thickness-layer): the
 * material as docs/scene-format.md says (checked field by field), and the same images as
 * gltf_thickness.json, which writes that layer by hand with the texture's G copied into R. */
static nacre_scene *load_gltf(nacre_context *ctx, const char *path, bool thickness_layer)
{
    nacre_scene *scene = NULL;
    nacre_result r = nacre_scene_load_gltf(ctx, path, &(nacre_gltf_options){.thickness_layer = thickness_layer},
                                           &scene, NULL, NULL);
    if (r != NACRE_OK)
        fprintf(stderr, "load %s: %s\n", path, nacre_context_last_error(ctx));
    CHECK(r == NACRE_OK);
    return scene;
}

static void test_thickness(void)
{
    nacre_context *ctx = make_ctx();
    nacre_scene *plain = load_gltf(ctx, DATA "/gltf_thickness.glb", false);
    nacre_scene *g = load_gltf(ctx, DATA "/gltf_thickness.glb", true);
    nacre_scene *n = load(ctx, DATA "/gltf_thickness.json", NULL);
    nacre_scene *t = NULL;
    if (!plain || !g || !n)
        goto out;
    nacre_material_desc mp, mg;
    CHECK(nacre_scene_get_material(plain, (nacre_material){1}, &mp) == NACRE_OK);
    CHECK(nacre_scene_get_material(g, (nacre_material){1}, &mg) == NACRE_OK);
    CHECK(mp.type == NACRE_MATERIAL_TRANSLUCENT && mp.layering.count == 0);
    CHECK(mg.type == NACRE_MATERIAL_TRANSLUCENT && mg.layering.count == 1 && mg.layering.depth_map.id != 0);
    CHECK(fabsf(mg.layering.layers[0].depth - 0.03f) < 1e-7f); /* thicknessFactor, metres */
    for (int c = 0; c < 3; c++) {
        float sa = (float)(-log(att_color[c]) / 0.05);
        CHECK(fabsf(mg.layering.layers[0].sigma_a[c] - sa) < 1e-4f * sa && fabsf(mg.sigma_a[c] - sa) < 1e-4f * sa);
        CHECK(mg.layering.layers[0].sigma_s[c] == 1000.0f && fabsf(mg.sigma_s[c] - 10.0f) < 1e-5f);
        CHECK(mp.sigma_s[c] == 1000.0f);
    }
    nacre_method methods[] = {NACRE_METHOD_PHONG, NACRE_METHOD_LAYERED, NACRE_METHOD_DIFFUSION};
    const char *names[] = {"phong", "layered", "diffusion"};
    for (int k = 0; k < 3; k++) {
        double max_rel, mean_rel;
        nacre_image a = render(g, methods[k]), b = render(n, methods[k]), c = render(plain, methods[k]);
        compare(&a, &b, &max_rel, &mean_rel);
        double dmax, dmean;
        compare(&c, &b, &dmax, &dmean);
        printf("thickness layer, %s: max relative difference %.3g, mean %.3g (without the layer: mean %.3g)\n",
               names[k], max_rel, mean_rel, dmean);
        CHECK(max_rel < 2e-3 && mean_rel < 1e-5);
        CHECK(dmean > 0.01); /* the layer matters (phong: it shades the core, which scatters less) */
        nacre_image_free(ctx, &a);
        nacre_image_free(ctx, &b);
        nacre_image_free(ctx, &c);
    }
    /* The path tracer, same seed: the same paths. */
    {
        nacre_render_settings rs = nacre_render_settings_defaults();
        rs.method = NACRE_METHOD_PATHTRACE;
        rs.width = 40;
        rs.height = 30;
        rs.pathtrace.spp = 16;
        nacre_image a = {0}, b = {0};
        CHECK(nacre_scene_commit(g, 0) == NACRE_OK && nacre_scene_commit(n, 0) == NACRE_OK);
        CHECK(nacre_render(g, &rs, &a, NULL) == NACRE_OK && nacre_render(n, &rs, &b, NULL) == NACRE_OK);
        /* Paths part ways at the first float rounding that differs (vertex data from two
         * files), so the images agree in their totals within the noise, not per pixel. */
        double sa = 0, sb = 0;
        for (size_t i = 0; i < (size_t)a.width * a.height * 3; i++)
            sa += a.pixels[i], sb += b.pixels[i];
        printf("thickness layer, pathtrace: image totals %.5g and %.5g (ratio %.4f)\n", sa, sb, sa / sb);
        CHECK(fabs(sa / sb - 1) < 0.02);
        nacre_image_free(ctx, &a);
        nacre_image_free(ctx, &b);
    }
    /* Scene files: the object form of "import". */
    const char *json = "{\"import\": {\"file\": \"gltf_thickness.glb\", \"thickness\": \"layer\"}}";
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "t.json", DATA, &t, NULL) == NACRE_OK);
    nacre_material_desc m;
    CHECK(t && nacre_scene_get_material(t, (nacre_material){1}, &m) == NACRE_OK && m.layering.count == 1);
    nacre_scene_destroy(t);
    t = NULL;
    json = "{\"import\": {\"file\": \"gltf_thickness.glb\", \"thickness\": \"ignore\"}}";
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "t.json", DATA, &t, NULL) == NACRE_OK);
    CHECK(t && nacre_scene_get_material(t, (nacre_material){1}, &m) == NACRE_OK && m.layering.count == 0);
    nacre_scene_destroy(t);
    t = NULL;
    static const struct {
        const char *json, *want;
    } bad[] = {
        {"{\"import\": {\"file\": \"gltf_thickness.glb\", \"thickness\": \"shell\"}}",
         "t.json: import.thickness: unknown thickness mapping \"shell\" (valid: ignore, layer)"},
        {"{\"import\": {\"thickness\": \"layer\"}}", "t.json: import: missing required key \"file\""},
        {"{\"import\": {\"file\": \"gltf_thickness.glb\", \"thick\": \"layer\"}}", "import"},
        {"{\"import\": {\"file\": 3}}", "t.json: import.file: expected a string"},
        {"{\"import\": [\"gltf_thickness.glb\"]}", "t.json: import: expected a string"},
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        CHECK(nacre_scene_load_json(ctx, bad[i].json, strlen(bad[i].json), "t.json", DATA, &t, NULL) ==
              NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(t == NULL);
        if (!strstr(nacre_context_last_error(ctx), bad[i].want))
            printf("bad import %zu: got \"%s\"\n", i, nacre_context_last_error(ctx));
        CHECK(strstr(nacre_context_last_error(ctx), bad[i].want) != NULL);
    }
    /* The CLI: the option needs a glTF. */
    char args[1024], err[4096];
    snprintf(args, sizeof(args), "render %s/gltf_thickness.json --thickness-layer -o %s/th.png", DATA, TMP);
    CHECK(run(args, err, sizeof(err)) == 2);
    CHECK(strstr(err, "--thickness-layer") != NULL);
    snprintf(args, sizeof(args), "info %s/gltf_thickness.glb --thickness-layer --json", DATA);
    CHECK(run(args, err, sizeof(err)) == 0);
out:
    nacre_scene_destroy(plain);
    nacre_scene_destroy(g);
    nacre_scene_destroy(n);
    nacre_context_destroy(ctx);
}

int main(void)
{
    mkdir(NACRE_TEST_TMP, 0755);
    mkdir(TMP, 0755);
    test_pair_images();
    test_demo();
    test_mapping();
    test_misc();
    test_split_and_ignored();
    test_control_characters();
    test_textured();
    test_import();
    test_thickness();
    test_malformed_cli();
    return TEST_MAIN_END();
}
