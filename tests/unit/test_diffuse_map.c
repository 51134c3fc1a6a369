/*
 * test_diffuse_map.c: base colour textures of opaque materials ("diffuse_map"). A square plane
 * seen from straight above by an orthographic camera, lit straight down: its radiance is
 * diffuse × texture(uv) × (E / pi + L_env), computed here with an independent bilinear lookup and
 * compared per pixel (one pixel per texel, then 4 pixels per texel where the lookup
 * interpolates); the path tracer's mean over the plane within its noise; the scene file's
 * PNG (sRGB-decoded) through nacre_scene_load_file and back through nacre_scene_save_file; and
 * the errors: a mesh without uvs (naming the object), a diffuse_map on a translucent material.
 */
#include "test_util.h"

#include <nacre/nacre.h>

static nacre_context *ctx;

#define TEX 8
#define E_SUN 2.0f
#define L_ENV 0.25f
static const float kd[3] = {0.9f, 0.7f, 0.5f};

/* A texture of distinct colours in [0.05, 1] (no two texels alike). */
static void make_texture(nacre_image *img)
{
    CHECK(nacre_image_alloc(ctx, TEX, TEX, 3, img) == NACRE_OK);
    uint32_t s = 12345u;
    for (int i = 0; i < TEX * TEX * 3; i++) {
        s = s * 1664525u + 1013904223u;
        img->pixels[i] = 0.05f + 0.95f * (float)(s >> 8) / 16777216.0f;
    }
}

/* Bilinear, repeating lookup of channel c at (u, v) in the convention of
 * nacre_scene_add_texture (texel (x, y) centred at u = (x + .5) / w, v = 1 - (y + .5) / h). */
static double lookup(const nacre_image *t, int c, double u, double v)
{
    double fx = u * t->width - 0.5, fy = (1.0 - v) * t->height - 0.5;
    double x0 = floor(fx), y0 = floor(fy), ax = fx - x0, ay = fy - y0;
    int xa = ((int)x0 % t->width + t->width) % t->width, xb = (xa + 1) % t->width;
    int ya = ((int)y0 % t->height + t->height) % t->height, yb = (ya + 1) % t->height;
#define T(x, y) (double)t->pixels[((size_t)(y) * (size_t)t->width + (size_t)(x)) * (size_t)t->channels + (size_t)c]
    return (1 - ay) * ((1 - ax) * T(xa, ya) + ax * T(xb, ya)) + ay * ((1 - ax) * T(xa, yb) + ax * T(xb, yb));
#undef T
}

/* The plane (2 x 2, uv = ((x + 1) / 2, (1 - z) / 2)) filling a W x W orthographic view from
 * above (image right = +x, down = +z), so pixel (i, j) sits at u = (i + .5) / W,
 * v = 1 - (j + .5) / W. `map`: the diffuse_map value, or "" for none; `material_type` lets the
 * error test put the map on a translucent material. */
static char *scene_json(char *buf, size_t size, const char *map, const char *method, int w, int spp)
{
    snprintf(buf, size,
             "{\"render\": {\"method\": \"%s\", \"width\": %d, \"height\": %d, \"spp\": %d},"
             " \"camera\": {\"type\": \"orthographic\", \"position\": [0, 10, 0], \"target\": [0, 0, 0],"
             "   \"up\": [0, 0, -1], \"height\": 2},"
             " \"environment\": [%g, %g, %g],"
             " \"materials\": {\"tex\": {\"type\": \"opaque\", \"diffuse\": [%g, %g, %g], \"specular\": 0%s%s%s}},"
             " \"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0], \"irradiance\": %g,"
             "   \"angular_radius\": 0.27}],"
             " \"objects\": [{\"name\": \"floor\", \"shape\": {\"type\": \"plane\", \"size\": [2, 0, 2]},"
             "   \"material\": \"tex\"}]}",
             method, w, w, spp, L_ENV, L_ENV, L_ENV, kd[0], kd[1], kd[2], map[0] ? ", \"diffuse_map\": \"" : "",
             map, map[0] ? "\"" : "", E_SUN);
    return buf;
}

static nacre_result render_json(const char *json, nacre_image *out, nacre_scene **keep)
{
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    nacre_result r = nacre_scene_load_json(ctx, json, strlen(json), "diffuse_map.json", NACRE_TEST_TMP, &scene, &fs);
    if (r == NACRE_OK)
        r = nacre_scene_commit(scene, 0);
    if (r == NACRE_OK)
        r = nacre_render(scene, &fs.render, out, NULL);
    if (keep && r == NACRE_OK)
        *keep = scene;
    else
        nacre_scene_destroy(scene);
    return r;
}

/* Every pixel against diffuse × texture × (E / pi + L_env); returns the largest relative error. */
static double compare_pixels(const nacre_image *img, const nacre_image *tex)
{
    double worst = 0;
    const double light = E_SUN / 3.14159265358979323846 + L_ENV;
    for (int j = 0; j < img->height; j++)
        for (int i = 0; i < img->width; i++)
            for (int c = 0; c < 3; c++) {
                double u = (i + 0.5) / img->width, v = 1.0 - (j + 0.5) / img->height;
                double want = kd[c] * lookup(tex, c, u, v) * light;
                double got = img->pixels[((size_t)j * (size_t)img->width + (size_t)i) * 3 + (size_t)c];
                worst = fmax(worst, fabs(got - want) / want);
            }
    return worst;
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    char json[4096];
    nacre_image tex = {0}, decoded = {0};
    make_texture(&tex);
    /* The scene file reads a PNG (8-bit sRGB, decoded to linear) or an EXR (linear) */
    const char *exr = NACRE_TEST_TMP "/diffuse_map_tex.exr", *png = NACRE_TEST_TMP "/diffuse_map_tex.png";
    nacre_image_write_options exr_opt = {.exr_type = NACRE_EXR_FLOAT};
    CHECK(nacre_image_write(ctx, &tex, exr, &exr_opt) == NACRE_OK);
    CHECK(nacre_image_write(ctx, &tex, png, NULL) == NACRE_OK);
    CHECK(nacre_image_read(ctx, png, &decoded) == NACRE_OK);

    /* Phong, one pixel per texel (the lookups land on texel centres) and 4 per texel (bilinear) */
    for (int w = TEX; w <= 4 * TEX; w *= 4) {
        nacre_image img = {0};
        CHECK(render_json(scene_json(json, sizeof(json), "diffuse_map_tex.exr", "phong", w, 1), &img, NULL) == NACRE_OK);
        if (img.pixels) {
            double err = compare_pixels(&img, &tex);
            printf("phong %dx%d: largest relative error %.3g\n", w, w, err);
            CHECK(err < 1e-4);
        }
        nacre_image_free(ctx, &img);
    }
    /* Without the map the same scene is the plain colour: the texture is what changed it */
    {
        nacre_image img = {0};
        CHECK(render_json(scene_json(json, sizeof(json), "", "phong", TEX, 1), &img, NULL) == NACRE_OK);
        double want = kd[1] * (E_SUN / 3.14159265358979323846 + L_ENV);
        CHECK(img.pixels && fabs(img.pixels[1] - want) < 1e-4 * want);
        CHECK(img.pixels && compare_pixels(&img, &tex) > 0.1);
        nacre_image_free(ctx, &img);
    }
    /* PNG: sRGB-decoded values, the same as nacre_image_read gives */
    nacre_scene *saved = NULL;
    {
        nacre_image img = {0};
        CHECK(render_json(scene_json(json, sizeof(json), "diffuse_map_tex.png", "phong", TEX, 1), &img, &saved) == NACRE_OK);
        if (img.pixels) {
            double err = compare_pixels(&img, &decoded);
            printf("phong from PNG: largest relative error %.3g\n", err);
            CHECK(err < 1e-4);
        }
        nacre_image_free(ctx, &img);
    }
    /* Saved and loaded back: the material keeps its map (the PNG, referred to by path) */
    if (saved) {
        const char *path = NACRE_TEST_TMP "/diffuse_map_saved.json";
        CHECK(nacre_scene_save_file(saved, NULL, path) == NACRE_OK);
        nacre_scene *back = NULL;
        CHECK(nacre_scene_load_file(ctx, path, &back, NULL) == NACRE_OK);
        nacre_material m0 = {1};
        nacre_material_desc a, b;
        CHECK(nacre_scene_get_material(saved, m0, &a) == NACRE_OK);
        CHECK(back && nacre_scene_get_material(back, m0, &b) == NACRE_OK);
        CHECK(a.diffuse_map.id != 0 && b.diffuse_map.id != 0);
        nacre_image img = {0};
        nacre_render_settings rs = nacre_render_settings_defaults();
        rs.width = rs.height = TEX;
        CHECK(back && nacre_scene_commit(back, 0) == NACRE_OK && nacre_render(back, &rs, &img, NULL) == NACRE_OK);
        CHECK(img.pixels && compare_pixels(&img, &decoded) < 1e-4);
        nacre_image_free(ctx, &img);
        nacre_scene_destroy(back);
        nacre_scene_destroy(saved);
    }
#ifdef NACRE_HAVE_EMBREE
    /* The path tracer: the image mean over the plane within 4 standard errors of the analytic
     * mean (the texture's mean, which bilinear filtering over whole periods keeps), per channel */
    {
        nacre_image img = {0};
        const int w = 16, spp = 64;
        CHECK(render_json(scene_json(json, sizeof(json), "diffuse_map_tex.exr", "pathtrace", w, spp), &img, NULL) == NACRE_OK);
        for (int c = 0; img.pixels && c < 3; c++) {
            double sum = 0, sum2 = 0, want = 0;
            size_t n = (size_t)w * w;
            for (size_t p = 0; p < n; p++) {
                double x = img.pixels[p * 3 + (size_t)c];
                sum += x;
                sum2 += x * x;
            }
            for (int p = 0; p < TEX * TEX; p++)
                want += tex.pixels[p * 3 + c];
            want = want / (TEX * TEX) * kd[c] * (E_SUN / 3.14159265358979323846 + L_ENV);
            double mean = sum / (double)n;
            /* Spread of the pixels includes the texture's own; a bound above the noise */
            double se = sqrt(fmax(0.0, sum2 / (double)n - mean * mean) / (double)n);
            printf("pathtrace channel %d: mean %.5f, analytic %.5f (se bound %.5f)\n", c, mean, want, se);
            CHECK(fabs(mean - want) < 0.02 * want);
        }
        /* Per pixel too, loosely: the texture's pattern is there, not only its mean */
        if (img.pixels) {
            double err = 0, base = 0;
            for (int j = 0; j < w; j++)
                for (int i = 0; i < w; i++) {
                    double u = (i + 0.5) / w, v = 1.0 - (j + 0.5) / w;
                    double want = kd[0] * lookup(&tex, 0, u, v) * (E_SUN / 3.14159265358979323846 + L_ENV);
                    double got = img.pixels[((size_t)j * w + (size_t)i) * 3];
                    err += fabs(got - want);
                    base += want;
                }
            printf("pathtrace: mean absolute per-pixel deviation %.3f of the mean\n", err / base);
            CHECK(err / base < 0.05);
        }
        nacre_image_free(ctx, &img);
    }
#endif
    /* Errors: a mesh without uvs names the object; translucent materials have no diffuse */
    {
        nacre_scene *scene = NULL;
        CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
        float pos[9] = {0, 0, 0, 1, 0, 0, 0, 0, 1};
        uint32_t idx[3] = {0, 2, 1};
        nacre_mesh_data md = {.vertex_count = 3, .triangle_count = 1, .positions = pos, .indices = idx};
        nacre_mesh mesh;
        nacre_texture t;
        nacre_material mat;
        nacre_object obj;
        CHECK(nacre_scene_add_mesh(scene, &md, &mesh) == NACRE_OK);
        CHECK(nacre_scene_add_texture(scene, &tex, &t) == NACRE_OK);
        nacre_material_desc d = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
        d.diffuse_map = t;
        CHECK(nacre_scene_add_material(scene, &d, &mat) == NACRE_OK);
        nacre_object_desc od = nacre_object_desc_defaults();
        od.name = "no uvs here";
        od.mesh = mesh;
        od.material = mat;
        CHECK(nacre_scene_add_object(scene, &od, &obj) == NACRE_OK);
        CHECK(nacre_scene_commit(scene, 0) == NACRE_ERROR_INVALID_ARGUMENT);
        printf("expected error: %s\n", nacre_context_last_error(ctx));
        CHECK(strstr(nacre_context_last_error(ctx), "'no uvs here'") != NULL);
        CHECK(strstr(nacre_context_last_error(ctx), "uvs") != NULL);
        nacre_material_desc tr = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
        tr.diffuse_map = t;
        CHECK(nacre_scene_set_material(scene, mat, &tr) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(ctx), "diffuse_map") != NULL);
        nacre_material_desc bad = d;
        bad.diffuse_map.id = 99;
        CHECK(nacre_scene_set_material(scene, mat, &bad) == NACRE_ERROR_INVALID_ARGUMENT);
        nacre_scene_destroy(scene);

        const char *tj = "{\"materials\": {\"t\": {\"preset\": \"marble\", \"diffuse_map\": \"diffuse_map_tex.png\"}}}";
        nacre_scene *s2 = NULL;
        CHECK(nacre_scene_load_json(ctx, tj, strlen(tj), "t.json", NACRE_TEST_TMP, &s2, NULL) != NACRE_OK);
        printf("expected error: %s\n", nacre_context_last_error(ctx));
        CHECK(strstr(nacre_context_last_error(ctx), "diffuse_map") != NULL);
        nacre_scene_destroy(s2);
        const char *mj = "{\"materials\": {\"o\": {\"type\": \"opaque\", \"diffuse_map\": \"missing.png\"}}}";
        CHECK(nacre_scene_load_json(ctx, mj, strlen(mj), "m.json", NACRE_TEST_TMP, &s2, NULL) != NACRE_OK);
        printf("expected error: %s\n", nacre_context_last_error(ctx));
        CHECK(strstr(nacre_context_last_error(ctx), "diffuse_map") != NULL);
        nacre_scene_destroy(s2);
    }
    nacre_image_free(ctx, &tex);
    nacre_image_free(ctx, &decoded);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
