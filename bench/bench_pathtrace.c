/*
 * bench_pathtrace.c: `nacre bench pathtrace`: speed of the reference path tracer on three
 * scenes at 512x512 — a translucent sphere index matched (eta 1: NEE reaches the lights from
 * inside), the same sphere as a smooth dielectric (eta 1.3: no NEE inside; the sun is sampled
 * through the boundary, see src/pathtrace/sun_guide.c), the built-in demo, and the
 * sphere with a layered skin material (two layers over a skin core, index matched: the cost of
 * locating collisions in layers).
 *
 * Each scene renders for a fixed time budget (30 s x --runs, whole 1-spp passes); we report
 * camera paths per second and the relative MSE of the result, estimated without a reference from the per-pixel
 * variance of the mean (the estimator is unbiased, so its expected squared error is its
 * variance): rel_mse = mean(var / (L^2 + 1e-2)), the definition of nacre_image_compare. Since
 * rel_mse falls as 1/spp, the time to reach 1e-3 is extrapolated as time * rel_mse / 1e-3.
 * Heavy-tailed pixels (rare bright paths through dielectrics) are under-represented in a short
 * run's variance, so the extrapolation is optimistic for the dielectric scenes.
 */
#include "bench.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "demo_scene.h"

#define SIZE 512
#define TARGET_REL_MSE 1e-3

/* Translucent sphere (radius 10 mm, skim-milk-like medium) on a grey floor under sun and sky. */
static const char sphere_json[] =
    "{\"camera\": {\"type\": \"perspective\", \"position\": [0, 12, 45], \"target\": [0, 8, 0], \"fov\": 35},\n"
    " \"environment\": [0.35, 0.4, 0.5],\n"
    " \"materials\": {\n"
    "   \"milk\": {\"type\": \"translucent\", \"sigma_a\": [0.0014, 0.0025, 0.0142], \"sigma_s\": [0.70, 1.22, 1.90],"
    " \"g\": 0.0, \"eta\": %s},\n"
    "   \"floor\": {\"type\": \"opaque\", \"diffuse\": [0.5, 0.5, 0.5], \"specular\": [0.02, 0.02, 0.02], \"shininess\": 16}},\n"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.4, -1.0, -0.3], \"irradiance\": [3, 3, 3]}],\n"
    " \"objects\": [\n"
    "   {\"name\": \"floor\", \"shape\": {\"type\": \"plane\", \"size\": [200, 200]}, \"material\": \"floor\"},\n"
    "   {\"name\": \"sphere\", \"shape\": {\"type\": \"sphere\", \"radius\": 10}, \"material\": \"milk\","
    " \"transform\": {\"translate\": [0, 10, 0]}}]}\n";

/* The same scene with a layered material: a thin forward-scattering top layer and a skin1
 * layer over a skin2 core (constant depths, mm). */
static const char layered_json[] =
    "{\"camera\": {\"type\": \"perspective\", \"position\": [0, 12, 45], \"target\": [0, 8, 0], \"fov\": 35},\n"
    " \"environment\": [0.35, 0.4, 0.5],\n"
    " \"materials\": {\n"
    "   \"skin\": {\"preset\": \"skin2\", \"eta\": 1.0, \"layers\": ["
    "{\"sigma_a\": [0.05, 0.12, 0.3], \"sigma_s\": [4, 4, 4], \"g\": 0.8, \"depth\": 0.15},"
    " {\"preset\": \"skin1\", \"depth\": 2}]},\n"
    "   \"floor\": {\"type\": \"opaque\", \"diffuse\": [0.5, 0.5, 0.5], \"specular\": [0.02, 0.02, 0.02], \"shininess\": 16}},\n"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.4, -1.0, -0.3], \"irradiance\": [3, 3, 3]}],\n"
    " \"objects\": [\n"
    "   {\"name\": \"floor\", \"shape\": {\"type\": \"plane\", \"size\": [200, 200]}, \"material\": \"floor\"},\n"
    "   {\"name\": \"sphere\", \"shape\": {\"type\": \"sphere\", \"radius\": 10}, \"material\": \"skin\","
    " \"transform\": {\"translate\": [0, 10, 0]}}]}\n";

typedef struct bench_result {
    double seconds, samples_per_second, rel_mse, time_to_target;
    uint32_t spp;
} bench_result;

static int run_scene(nacre_context *ctx, const char *json, const char *name, double seconds, bench_result *out)
{
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    nacre_render_settings rs;
    nacre_renderer *r = NULL;
    nacre_image img = {0}, var = {0};
    int rc = 2;
    if (nacre_scene_load_json(ctx, json, strlen(json), name, ".", &scene, &fs) != NACRE_OK ||
        nacre_scene_commit(scene, fs.time) != NACRE_OK || nacre_renderer_create(ctx, &r) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }
    rs = fs.render;
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = SIZE;
    rs.height = SIZE;
    rs.pathtrace.spp = 0;
    rs.pathtrace.time_limit = seconds;
    rs.pathtrace.max_scatter = 0;
    nacre_render_stats st;
    uint64_t t0 = nc_tool_now_us();
    if (nacre_renderer_render(r, scene, &rs, &img, &st) != NACRE_OK ||
        nacre_renderer_variance(r, &var) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }
    out->seconds = (nc_tool_now_us() - t0) * 1e-6;
    out->spp = st.spp_done;
    out->samples_per_second = st.samples_per_second;
    double sum = 0;
    size_t n = (size_t)SIZE * SIZE * 3;
    for (size_t i = 0; i < n; i++)
        sum += var.pixels[i] / ((double)img.pixels[i] * img.pixels[i] + 1e-2);
    out->rel_mse = sum / (double)n;
    /* Time per pass times the passes needed for rel_mse to fall to the target. */
    out->time_to_target = out->spp > 1 ? out->seconds * out->rel_mse / TARGET_REL_MSE : -1;
    rc = 0;
out:
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(scene);
    return rc;
}

int nc_bench_pathtrace(bool json, double seconds)
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    char matched[2048], dielectric[2048];
    snprintf(matched, sizeof(matched), sphere_json, "1.0");
    snprintf(dielectric, sizeof(dielectric), sphere_json, "1.3");
    const struct {
        const char *name, *json;
    } scenes[4] = {{"sphere_matched", matched}, {"sphere_dielectric", dielectric},
                   {"demo", (const char *)nacre_demo_scene_json}, {"sphere_layered", layered_json}};
    if (!json)
        printf("path tracer, %dx%d, %d threads, %.0f s per scene; time_to_1e-3 extrapolated from the variance image\n"
               "%-18s %6s %12s %12s %16s\n",
               SIZE, SIZE, nacre_context_threads(ctx), seconds, "scene", "spp", "samples/s", "rel_mse", "time_to_1e-3_s");
    int rc = 0;
    for (int i = 0; i < 4 && rc == 0; i++) {
        bench_result b;
        memset(&b, 0, sizeof(b));
        rc = run_scene(ctx, scenes[i].json, scenes[i].name, seconds, &b);
        if (rc)
            break;
        if (json)
            printf("{\"bench\":\"pathtrace\",\"scene\":\"%s\",\"width\":%d,\"height\":%d,\"threads\":%d,\"seconds\":%.3f,"
                   "\"spp\":%u,\"samples_per_second\":%.6g,\"rel_mse\":%.6g,\"time_to_rel_mse_1e-3_s\":%.6g}\n",
                   scenes[i].name, SIZE, SIZE, nacre_context_threads(ctx), b.seconds, b.spp, b.samples_per_second,
                   b.rel_mse, b.time_to_target);
        else
            printf("%-18s %6u %12.4g %12.4g %16.4g\n", scenes[i].name, b.spp, b.samples_per_second, b.rel_mse,
                   b.time_to_target);
        fflush(stdout);
    }
    nacre_context_destroy(ctx);
    return rc;
}
