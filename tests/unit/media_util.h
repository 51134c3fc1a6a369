/*
 * media_util.h: what the fog and volumetrics tests share (test_volumetrics, test_fog_emission,
 * test_pathtrace_fog): a scene from JSON committed at time 0, a render with the file's settings
 * but the method, size, volumetrics and path tracer settings given, and the mean and standard
 * error of a block of pixels. Header-only, static inline (a test uses what it needs).
 */
#ifndef NACRE_TEST_MEDIA_UTIL_H
#define NACRE_TEST_MEDIA_UTIL_H

#include "test_util.h"

#include <nacre/nacre.h>

/* The scene of `json` (named scene.json in messages), committed; its file settings in *rs. */
static inline nacre_scene *media_load(nacre_context *c, const char *json, nacre_render_settings *rs)
{
    nacre_scene *s = NULL;
    nacre_scene_file_settings fs;
    nacre_result r = nacre_scene_load_json(c, json, strlen(json), "scene.json", ".", &s, &fs);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("  %s\n", nacre_context_last_error(c));
        return NULL;
    }
    if (rs)
        *rs = fs.render;
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
    return s;
}

/* Render json with want's method, size, volumetrics and path tracer settings (the rest from the
 * file's defaults); var (if not NULL) gets the path tracer's variance of the mean. */
static inline bool media_render(nacre_context *c, const char *json, const nacre_render_settings *want,
                                nacre_image *img, nacre_image *var)
{
    nacre_render_settings rs;
    nacre_scene *s = media_load(c, json, &rs);
    if (!s)
        return false;
    rs.method = want->method;
    rs.width = want->width;
    rs.height = want->height;
    rs.volumetrics = want->volumetrics;
    rs.pathtrace = want->pathtrace;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(c, &r) == NACRE_OK);
    nacre_result res = nacre_renderer_render(r, s, &rs, img, NULL);
    CHECK(res == NACRE_OK);
    if (res != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(c));
    if (res == NACRE_OK && var)
        CHECK(nacre_renderer_variance(r, var) == NACRE_OK);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
    return res == NACRE_OK;
}

static inline float media_px(const nacre_image *img, int x, int y, int c)
{
    return img->pixels[(size_t)y * img->stride + 3 * (size_t)x + (size_t)c];
}

/* Mean and standard error (from the variance image of the mean, if any) over the pixels of rows
 * [y0, y1) and columns [x0, x1). */
static inline void media_region(const nacre_image *img, const nacre_image *var, int x0, int x1, int y0, int y1,
                                double m[3], double se[3])
{
    double s[3] = {0, 0, 0}, v[3] = {0, 0, 0};
    int n = 0;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++, n++)
            for (int c = 0; c < 3; c++) {
                s[c] += media_px(img, x, y, c);
                v[c] += var ? media_px(var, x, y, c) : 0.0;
            }
    for (int c = 0; c < 3; c++) {
        m[c] = s[c] / n;
        se[c] = sqrt(v[c]) / n;
    }
}

/* A scene whose "fog" array holds `fog` must fail to load with one line containing `needle`. */
static inline void media_expect_fog_error(nacre_context *c, const char *fog, const char *needle)
{
    char json[2048];
    snprintf(json, sizeof(json), "{\"fog\": [%s]}", fog);
    nacre_scene *s = NULL;
    nacre_scene_file_settings fs;
    nacre_result r = nacre_scene_load_json(c, json, strlen(json), "bad.json", ".", &s, &fs);
    CHECK(r != NACRE_OK && s == NULL);
    CHECK(test_error_names(c, needle));
    printf("  %s -> %s\n", fog, nacre_context_last_error(c));
    nacre_scene_destroy(s);
}

static inline nacre_render_settings media_settings(nacre_method method, nacre_volumetrics_mode mode, int w, int h)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = method;
    rs.width = w;
    rs.height = h;
    rs.volumetrics.mode = mode;
    return rs;
}

#endif /* NACRE_TEST_MEDIA_UTIL_H */
