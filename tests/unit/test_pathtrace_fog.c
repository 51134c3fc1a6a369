/*
 * test_pathtrace_fog.c: fog (participating media in open space) in the path tracer, against
 * closed forms:
 *   - absorbing box fog seen through an orthographic camera: exp(-sigma_a L) per channel, also
 *     for a rotated box (path length through the diagonal);
 *   - height fog: horizontal rays through a box, exp(-sigma_a e^(-f y) L) per row; vertical rays
 *     up through a global height fog, exp(-sigma_a e^(-f (y0 - base)) / f) (the walk must end on
 *     its own); rays down into it never come out;
 *   - single scattering (max_scatter 1) of a delta sun from above by a box fog seen sideways:
 *     sigma_s p(90 deg) E e^(-sigma_t (1 - y)) (1 - e^(-2 sigma_t)) / sigma_t per row, g = 0 and 0.5;
 *   - white furnaces: non-absorbing fog under a uniform environment gives the environment back,
 *     homogeneous, chromatic with g, with a noise pattern, with height falloff, two overlapping
 *     fogs of different g, and with a white Lambert sphere and an index-matched medium sphere
 *     inside the fog;
 *   - scene-file parsing and clean errors.
 */
#include "media_util.h"

#include <nacre/nacre.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

static nacre_context *ctx;

/* Render a scene file with the path tracer; the variance image too when asked. */
static bool render(const char *json, int32_t w, int32_t h, uint32_t spp, uint32_t max_scatter, nacre_image *img,
                   nacre_image *var)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    nacre_scene *s = media_load(ctx, json, &rs);
    if (!s)
        return false;
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = w;
    rs.height = h;
    rs.pathtrace.spp = spp;
    rs.pathtrace.seed = 11;
    rs.pathtrace.max_scatter = max_scatter;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    CHECK(nacre_image_alloc(ctx, w, h, 3, img) == NACRE_OK);
    nacre_result res = nacre_renderer_render(r, s, &rs, img, NULL);
    CHECK(res == NACRE_OK);
    if (res != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(ctx));
    if (var)
        CHECK(nacre_renderer_variance(r, var) == NACRE_OK);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
    if (res != NACRE_OK) {
        nacre_image_free(ctx, img);
        nacre_image_free(ctx, var);
    }
    return res == NACRE_OK;
}

/* Orthographic camera at z = 5 looking down -z over [-2, 2]^2, rays starting at the eye. */
#define ORTHO_Z "\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0, 5], \"target\": [0, 0, 0], " \
                "\"height\": 4, \"near\": 0.001, \"far\": 100}"

static void absorbing_boxes(void)
{
    /* Box [-1, 1]^3: rays through |x|, |y| < 1 cross 2 units. Pixels are 4 / 32 units wide. */
    const char *json = "{" ORTHO_Z ", \"environment\": 1,"
                       "\"fog\": [{\"shape\": \"box\", \"size\": 2, \"sigma_a\": [0.2, 0.5, 1.0], \"sigma_s\": 0}]}";
    nacre_image img = {0}, var = {0};
    if (!render(json, 32, 32, 64, 0, &img, &var))
        return;
    double m[3], se[3];
    media_region(&img, &var, 10, 22, 10, 22, m, se);
    const double sa[3] = {0.2, 0.5, 1.0};
    for (int c = 0; c < 3; c++) {
        printf("  box absorber c%d: %.4f +- %.4f, exact %.4f\n", c, m[c], se[c], exp(-2 * sa[c]));
        CHECK_NEAR(m[c], exp(-2 * sa[c]), 4 * se[c] + 1e-3);
    }
    media_region(&img, NULL, 0, 32, 0, 3, m, se); /* outside the box: nothing in the way */
    CHECK_NEAR(m[0], 1.0, 1e-6);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);

    /* Rotated 45 degrees about y: the central column crosses the diagonal, 2 sqrt(2). */
    json = "{" ORTHO_Z ", \"environment\": 1,"
           "\"fog\": [{\"shape\": \"box\", \"size\": 2, \"rotate\": [0, 45, 0], \"sigma_a\": 0.5, \"sigma_s\": 0}]}";
    if (!render(json, 32, 32, 256, 0, &img, &var))
        return;
    /* Columns 15 and 16 span x in [-0.125, 0.125]: the length there is 2 sqrt(2) - 2 |x|. */
    double expect = 0;
    for (int k = 0; k < 64; k++) {
        double x = -0.125 + (k + 0.5) / 64 * 0.25;
        expect += exp(-0.5 * (2 * sqrt(2.0) - 2 * fabs(x))) / 64;
    }
    media_region(&img, &var, 15, 17, 10, 22, m, se);
    printf("  rotated box absorber: %.4f +- %.4f, exact %.4f\n", m[1], se[1], expect);
    CHECK_NEAR(m[1], expect, 4 * se[1] + 1e-3);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
}

/* An ellipsoid of fog, semi-axes (1.5, 1, 1), shifted to x = 0.25: a ray at (x, y) crosses
 * 2 sqrt(1 - ((x - 0.25) / 1.5)^2 - y^2) of it. Per region, the pixels' exact mean (8 x 8
 * points per pixel) against the path tracer's; the fog pass (phong, analytic transmittance
 * at pixel centres) against the same length at each pixel's centre. */
static double ellipsoid_length(double x, double y)
{
    double u = (x - 0.25) / 1.5, r = 1.0 - u * u - y * y;
    return r > 0.0 ? 2.0 * sqrt(r) : 0.0;
}

static void absorbing_sphere(void)
{
    const char *json = "{" ORTHO_Z ", \"environment\": 1,"
                       "\"fog\": [{\"shape\": \"sphere\", \"center\": [0.25, 0, 0], \"size\": [3, 2, 2],"
                       " \"sigma_a\": [0.2, 0.5, 1.0], \"sigma_s\": 0}]}";
    const double sa[3] = {0.2, 0.5, 1.0};
    nacre_image img = {0}, var = {0};
    if (!render(json, 32, 32, 256, 0, &img, &var))
        return;
    /* Regions of 4 x 4 pixels across the ellipse, its edge included. */
    static const int regions[][2] = {{14, 14}, {18, 12}, {6, 14}, {22, 20}, {10, 8}};
    for (size_t r = 0; r < sizeof(regions) / sizeof(regions[0]); r++) {
        int x0 = regions[r][0], y0 = regions[r][1];
        double m[3], se[3], exact[3] = {0, 0, 0};
        media_region(&img, &var, x0, x0 + 4, y0, y0 + 4, m, se);
        for (int py = y0; py < y0 + 4; py++)
            for (int pxl = x0; pxl < x0 + 4; pxl++)
                for (int j = 0; j < 8; j++)
                    for (int i = 0; i < 8; i++) {
                        double x = -2.0 + (pxl + (i + 0.5) / 8) * 4.0 / 32, y = 2.0 - (py + (j + 0.5) / 8) * 4.0 / 32;
                        double L = ellipsoid_length(x, y);
                        for (int c = 0; c < 3; c++)
                            exact[c] += exp(-sa[c] * L) / (16 * 64);
                    }
        for (int c = 0; c < 3; c++) {
            if (c == 2)
                printf("  ellipsoid absorber at (%d, %d) c%d: %.4f +- %.4f, exact %.4f\n", x0, y0, c, m[c], se[c],
                       exact[c]);
            CHECK_NEAR(m[c], exact[c], 4 * se[c] + 1e-3);
        }
    }
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);

    /* The raster methods' analytic fog pass: the same ellipsoid at each pixel's centre (a far
     * away dot gives the scene its one object). */
    const char *raster = "{" ORTHO_Z ", \"environment\": 1,"
                         "\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                         "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.01}, \"material\": \"m\","
                         " \"transform\": {\"translate\": [0, -500, 0]}}],"
                         "\"fog\": [{\"shape\": \"sphere\", \"center\": [0.25, 0, 0], \"size\": [3, 2, 2],"
                         " \"sigma_a\": [0.2, 0.5, 1.0], \"sigma_s\": 0}]}";
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_json(ctx, raster, strlen(raster), "ellipsoid", NULL, &s, NULL) == NACRE_OK);
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PHONG;
    rs.width = rs.height = 32;
    nacre_image fp = {0};
    bool ok = s && nacre_scene_commit(s, 0) == NACRE_OK && nacre_render(s, &rs, &fp, NULL) == NACRE_OK;
    CHECK(ok);
    if (ok) {
        double worst = 0.0;
        for (int y = 0; y < 32; y++)
            for (int x = 0; x < 32; x++) {
                double L = ellipsoid_length(-2.0 + (x + 0.5) * 4.0 / 32, 2.0 - (y + 0.5) * 4.0 / 32);
                for (int c = 0; c < 3; c++)
                    worst = fmax(worst, fabs(media_px(&fp, x, y, c) - exp(-sa[c] * L)));
            }
        printf("  ellipsoid absorber, fog pass: largest difference to the closed form %.2g\n", worst);
        CHECK(worst < 1e-5);
    }
    nacre_image_free(ctx, &fp);
    nacre_scene_destroy(s);
}

static void height_fog(void)
{
    /* Horizontal rays through a box of height fog: sigma = 0.8 e^(-1.5 (y - 0.2)). */
    const char *json = "{" ORTHO_Z ", \"environment\": 1,"
                       "\"fog\": [{\"shape\": \"box\", \"size\": [4, 2, 2], \"sigma_a\": 0.8, \"sigma_s\": 0,"
                       "\"height_falloff\": 1.5, \"height_base\": 0.2}]}";
    nacre_image img = {0}, var = {0};
    if (!render(json, 16, 32, 256, 0, &img, &var))
        return;
    int checked = 0;
    for (int row = 9; row < 23; row += 3) {
        /* Row covers y in [2 - (row + 1) / 8, 2 - row / 8]: average the closed form over it. */
        double expect = 0;
        for (int k = 0; k < 64; k++) {
            double y = 2 - (row + (k + 0.5) / 64) / 8;
            expect += exp(-0.8 * exp(-1.5 * (y - 0.2)) * 2) / 64;
        }
        double m[3], se[3];
        media_region(&img, &var, 0, 16, row, row + 1, m, se);
        printf("  height fog row %2d: %.4f +- %.4f, exact %.4f\n", row, m[0], se[0], expect);
        CHECK_NEAR(m[0], expect, 4 * se[0] + 2e-3);
        checked++;
    }
    CHECK(checked == 5);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);

    /* Straight up from y0 = 1 through a global height fog: tau = 0.6 e^(-2 (1 - 0.5)) / 2. */
    json = "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 1, 0], \"target\": [0, 2, 0], "
           "\"up\": [0, 0, 1], \"height\": 1, \"near\": 0.001, \"far\": 100}, \"environment\": 1,"
           "\"fog\": [{\"shape\": \"global\", \"sigma_a\": 0.6, \"sigma_s\": 0, \"height_falloff\": 2, \"height_base\": 0.5}]}";
    if (!render(json, 8, 8, 256, 0, &img, &var))
        return;
    double m[3], se[3];
    media_region(&img, &var, 0, 8, 0, 8, m, se);
    double expect = exp(-0.6 * exp(-2 * (1 - 0.5)) / 2);
    printf("  height fog, looking up: %.4f +- %.4f, exact %.4f\n", m[0], se[0], expect);
    CHECK_NEAR(m[0], expect, 4 * se[0] + 1e-3);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);

    /* Straight down: the density grows without end, nothing comes back. */
    json = "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 1, 0], \"target\": [0, 0, 0], "
           "\"up\": [0, 0, 1], \"height\": 1, \"near\": 0.001, \"far\": 100}, \"environment\": 1,"
           "\"fog\": [{\"shape\": \"global\", \"sigma_a\": 0.6, \"sigma_s\": 0, \"height_falloff\": 2}]}";
    if (!render(json, 8, 8, 16, 0, &img, NULL))
        return;
    media_region(&img, NULL, 0, 8, 0, 8, m, se);
    CHECK(m[0] == 0.0);
    nacre_image_free(ctx, &img);
}

/* A delta sun straight down on the box [-1, 1]^3, seen sideways, single scattering only. */
static void single_scattering(float g)
{
    char json[1024];
    snprintf(json, sizeof(json),
             "{" ORTHO_Z ", \"environment\": 0,"
             "\"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0], \"irradiance\": 2, \"angular_radius\": 0}],"
             "\"fog\": [{\"shape\": \"box\", \"size\": 2, \"sigma_a\": 0.3, \"sigma_s\": [0.9, 0.6, 0.3], \"g\": %g}]}",
             (double)g);
    nacre_image img = {0}, var = {0};
    if (!render(json, 32, 32, 1024, 1, &img, &var))
        return;
    double p90 = (1 - g * g) / (4 * 3.14159265358979323846 * pow(1 + g * g, 1.5));
    const double ss[3] = {0.9, 0.6, 0.3};
    for (int row = 10; row < 22; row += 5) {
        double m[3], se[3];
        media_region(&img, &var, 10, 22, row, row + 1, m, se);
        for (int c = 0; c < 3; c++) {
            double st = 0.3 + ss[c], expect = 0;
            for (int k = 0; k < 64; k++) {
                double y = 2 - (row + (k + 0.5) / 64) / 8;
                expect += ss[c] * p90 * 2 * exp(-st * (1 - y)) * (1 - exp(-2 * st)) / st / 64;
            }
            if (c == 0)
                printf("  single scattering g=%.1f row %2d: %.5f +- %.5f, exact %.5f\n", (double)g, row, m[c], se[c],
                       expect);
            CHECK_NEAR(m[c], expect, 4 * se[c] + 0.005 * expect);
        }
    }
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
}

/* Perspective view into a box of fog [-1.5, 1.5]^3 under a uniform sky of 0.7. */
static void furnace(const char *name, const char *fog, const char *extra)
{
    char json[2048];
    snprintf(json, sizeof(json),
             "{\"camera\": {\"position\": [0, 0, 5], \"target\": [0, 0, 0], \"fov\": 40}, \"environment\": 0.7,"
             "\"fog\": [%s]%s}",
             fog, extra);
    nacre_image img = {0}, var = {0};
    if (!render(json, 16, 16, 64, 0, &img, &var))
        return;
    double m[3], se[3];
    media_region(&img, &var, 3, 13, 3, 13, m, se);
    printf("  furnace %-34s: %.4f %.4f %.4f (stderr %.4f) expect 0.7\n", name, m[0], m[1], m[2], se[0]);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(m[c], 0.7, 4 * se[c] + 0.005);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
}

static void furnaces(void)
{
    furnace("homogeneous", "{\"shape\": \"box\", \"size\": 3, \"sigma_a\": 0, \"sigma_s\": 2}", "");
    furnace("chromatic, g 0.6",
            "{\"shape\": \"box\", \"size\": 3, \"sigma_a\": 0, \"sigma_s\": [3, 1, 0.3], \"g\": 0.6}", "");
    furnace("noise pattern, rotated",
            "{\"shape\": \"box\", \"size\": 3, \"rotate\": [20, 30, 0], \"sigma_a\": 0, \"sigma_s\": 4,"
            "\"pattern\": {\"type\": \"noise\", \"sigma_a2\": 0, \"sigma_s2\": 0, \"cell_size\": 0.7, \"seed\": 5}}",
            "");
    furnace("height falloff",
            "{\"shape\": \"box\", \"size\": 3, \"sigma_a\": 0, \"sigma_s\": 2, \"height_falloff\": 1.2}", "");
    furnace("two fogs, g -0.5 and 0.8",
            "{\"shape\": \"box\", \"size\": 3, \"sigma_a\": 0, \"sigma_s\": [2, 1, 0.5], \"g\": -0.5},"
            "{\"shape\": \"box\", \"size\": [2, 3, 2], \"center\": [0.5, 0, 0], \"sigma_a\": 0, \"sigma_s\": [0.5, 1, 3], \"g\": 0.8}",
            "");
    furnace("white Lambert sphere inside",
            "{\"shape\": \"box\", \"size\": 3, \"sigma_a\": 0, \"sigma_s\": 1}",
            ", \"materials\": {\"white\": {\"type\": \"opaque\", \"diffuse\": 1, \"specular\": 0}},"
            "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.6}, \"material\": \"white\"}]");
    furnace("matched medium sphere inside",
            "{\"shape\": \"box\", \"size\": 3, \"sigma_a\": 0, \"sigma_s\": 1}",
            ", \"materials\": {\"m\": {\"type\": \"translucent\", \"sigma_a\": 0, \"sigma_s\": 5, \"eta\": 1}},"
            "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.6}, \"material\": \"m\"}]");
}

static void expect_error(const char *fog, const char *needle) { media_expect_fog_error(ctx, fog, needle); }

static void parsing(void)
{
    expect_error("{\"size\": 1}", "shape");
    expect_error("{\"shape\": \"cloud\"}", "shape");
    expect_error("{\"shape\": \"box\"}", "size");
    expect_error("{\"shape\": \"global\", \"size\": 2}", "size");
    expect_error("{\"shape\": \"box\", \"size\": [1, 0, 1]}", "fog[0].size");
    expect_error("{\"shape\": \"sphere\"}", "size");
    expect_error("{\"shape\": \"sphere\", \"size\": -2}", "fog[0].size");
    expect_error("{\"shape\": \"global\", \"sigma_a\": -1}", "fog[0].sigma_a");
    expect_error("{\"shape\": \"global\", \"g\": 1}", "fog[0].g");
    expect_error("{\"shape\": \"global\", \"height_falloff\": -0.1}", "height_falloff");
    expect_error("{\"shape\": \"global\", \"density\": 1}", "density");
    expect_error("{\"shape\": \"global\", \"pattern\": {\"type\": \"volume\", \"volume\": \"missing.nrrd\"}}",
                 "missing.nrrd");

    char many[4096] = "{\"fog\": [";
    for (int i = 0; i <= NACRE_MAX_FOGS; i++)
        strcat(many, i ? ",{\"shape\": \"global\"}" : "{\"shape\": \"global\"}");
    strcat(many, "]}");
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_json(ctx, many, strlen(many), "many.json", ".", &s, NULL) != NACRE_OK);
    CHECK(strstr(nacre_context_last_error(ctx), "at most") != NULL);

    /* The API: handles, counts, validation. */
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    nacre_fog_desc d = nacre_fog_desc_defaults(NACRE_FOG_BOX);
    nacre_fog f;
    CHECK(nacre_scene_add_fog(s, &d, &f) == NACRE_OK && f.id == 1);
    CHECK(nacre_scene_fog_count(s) == 1);
    d.sigma_s[1] = NAN;
    CHECK(nacre_scene_set_fog(s, f, &d) == NACRE_ERROR_INVALID_ARGUMENT);
    d.sigma_s[1] = 1;
    nacre_fog bad = {7};
    CHECK(nacre_scene_set_fog(s, bad, &d) == NACRE_ERROR_INVALID_ARGUMENT);
    d.pattern.type = NACRE_PATTERN_VOLUME;
    d.pattern.volume.id = 3;
    CHECK(nacre_scene_set_fog(s, f, &d) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "fog: pattern.volume") != NULL);
    nacre_scene_destroy(s);

    /* A sphere fog survives a save and a load. */
    const char *sphere = "{\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                         " \"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}],"
                         " \"fog\": [{\"shape\": \"sphere\", \"center\": [1, 2, 3], \"size\": [3, 2, 1], \"sigma_s\": 0.5}]}";
    s = NULL;
    CHECK(nacre_scene_load_json(ctx, sphere, strlen(sphere), "sphere.json", ".", &s, NULL) == NACRE_OK);
    char path[512];
    snprintf(path, sizeof(path), "%s/fog_sphere_saved.json", NACRE_TEST_TMP);
    CHECK(s && nacre_scene_save_file(s, NULL, path) == NACRE_OK);
    nacre_scene_destroy(s);
    s = NULL;
    CHECK(nacre_scene_load_file(ctx, path, &s, NULL) == NACRE_OK);
    nacre_fog_desc back;
    CHECK(s && nacre_scene_get_fog(s, (nacre_fog){1}, &back) == NACRE_OK && back.shape == NACRE_FOG_SPHERE &&
          back.size[0] == 3 && back.size[1] == 2 && back.size[2] == 1 && back.center[2] == 3);
    nacre_scene_destroy(s);
}


/* Single scattering of a point light in fog (what the equiangular technique samples, combined by
 * MIS with distance sampling): a box of fog [-2, 2]^3 seen by the orthographic camera, a point
 * light at (0, 3, 0) above it, nothing else. The exact radiance of a ray is the integral over z
 * of sigma_s p(theta) I / r^2 exp(-sigma_t (2 - z)) exp(-sigma_t s), s the part of the way to the
 * light inside the box; a bias in the MIS weights or in the equiangular pdf moves the mean. */
static double point_ray(double x, double y, double ss, double st, double g, double intensity)
{
    const int n = 4000;
    double sum = 0, dz = 4.0 / n;
    for (int i = 0; i < n; i++) {
        double z = 2 - (i + 0.5) * dz;
        double lx = -x, ly = 3 - y, lz = -z, r = sqrt(lx * lx + ly * ly + lz * lz);
        double cos_t = -lz / r; /* light direction vs the view ray (0, 0, -1) */
        double phase = (1 - g * g) / (4 * 3.14159265358979323846 * pow(1 + g * g - 2 * g * cos_t, 1.5));
        double inside = r * (2 - y) / (3 - y);
        sum += ss * phase * intensity / (r * r) * exp(-st * (2 - z)) * exp(-st * inside) * dz;
    }
    return sum;
}

static void point_light_in_fog(float g)
{
    char json[1024];
    snprintf(json, sizeof(json),
             "{" ORTHO_Z ", \"environment\": 0,"
             "\"lights\": [{\"type\": \"point\", \"position\": [0, 3, 0], \"intensity\": 10}],"
             "\"fog\": [{\"shape\": \"box\", \"size\": 4, \"sigma_a\": 0.05, \"sigma_s\": 0.2, \"g\": %g}]}",
             (double)g);
    nacre_image img = {0}, var = {0};
    if (!render(json, 16, 16, 256, 1, &img, &var))
        return;
    /* Central 4 x 4 pixels (x, y in [-0.5, 0.5]); the exact value averaged over each pixel. */
    double m[3], se[3], exact = 0;
    media_region(&img, &var, 6, 10, 6, 10, m, se);
    for (int py = 6; py < 10; py++)
        for (int px_ = 6; px_ < 10; px_++)
            for (int k = 0; k < 16; k++) {
                double x = -2 + (px_ + ((k % 4) + 0.5) / 4) * 0.25, y = 2 - (py + ((k / 4) + 0.5) / 4) * 0.25;
                exact += point_ray(x, y, 0.2, 0.25, g, 10) / (16 * 16);
            }
    printf("  point light in fog, g %.1f: %.5f +- %.5f, exact %.5f\n", (double)g, m[1], se[1], exact);
    CHECK_NEAR(m[1], exact, 4 * se[1] + 2e-3 * exact);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
}

int main(void)
{
    nacre_context_desc cd = {0};
    cd.threads = 2;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    parsing();
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE)) {
        printf("  skipped the renders: built without Embree\n");
        nacre_context_destroy(ctx);
        return TEST_MAIN_END();
    }
    absorbing_boxes();
    absorbing_sphere();
    height_fog();
    single_scattering(0.0f);
    single_scattering(0.5f);
    furnaces();
    point_light_in_fog(0.0f);
    point_light_in_fog(0.6f);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
