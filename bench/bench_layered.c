/*
 * bench_layered.c: `nacre bench layered`, the layered method (seed 001) at 640x480 on a scene
 * file (default examples/layered.json, run from the repository's root): first the cold frame
 * per stage (every stage runs, the planes included), then, for 4, 10, 50 and 100 steps with each
 * integration, frames while the light moves (the light turns by 0.1 degree and the scene is
 * committed before every frame, so the shadow map and the march rerun, the G-buffer and the
 * planes are cached), as medians of N runs: per-stage microseconds, the frame and its frames
 * per second. The seed's table 2 gives 126 / 51 / 20 fps at 10 / 50 / 100 samples for its fish
 * at 800x600 on a GeForce 7800 GTX; those are printed beside ours for scale, not compared.
 */
#include "bench.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const nacre_stage stages[] = {NACRE_STAGE_RASTER, NACRE_STAGE_GBUFFER, NACRE_STAGE_SHADOW,
                                     NACRE_STAGE_PLANES, NACRE_STAGE_MARCH,   NACRE_STAGE_SHADE};
#define NSTAGES (sizeof(stages) / sizeof(stages[0]))

static void print_row(bool json, const char *scene, const char *what, uint32_t samples, const char *integ,
                      const double *med, double frame_us, double seed_fps)
{
    if (json) {
        printf("{\"bench\":\"layered\",\"scene\":\"%s\",\"frames\":\"%s\",\"width\":640,\"height\":480,"
               "\"samples\":%u,\"integration\":\"%s\"",
               scene, what, samples, integ);
        for (size_t k = 0; k < NSTAGES; k++)
            printf(",\"%s_us\":%.0f", nacre_stage_name(stages[k]), med[k]);
        printf(",\"frame_us\":%.0f,\"fps\":%.1f", frame_us, 1e6 / frame_us);
        if (seed_fps > 0)
            printf(",\"seed_fps_800x600_gf7800\":%.0f", seed_fps);
        printf("}\n");
        return;
    }
    printf("%-12s %7u %-9s", what, samples, integ);
    for (size_t k = 0; k < NSTAGES; k++)
        printf(" %9.0f", med[k]);
    printf(" %9.0f %7.1f", frame_us, 1e6 / frame_us);
    if (seed_fps > 0)
        printf("   (seed fish %3.0f fps)", seed_fps);
    printf("\n");
}

int nc_bench_layered(bool json, int runs, const char *scene_path)
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 1;
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    nacre_renderer *r = NULL;
    nacre_image img = {0};
    double *t = NULL;
    int rc = 1;
    if (nacre_scene_load_file(ctx, scene_path, &scene, &fs) != NACRE_OK || nacre_scene_commit(scene, fs.time) != NACRE_OK ||
        nacre_renderer_create(ctx, &r) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }
    if (nacre_scene_light_count(scene) == 0) {
        rc = nc_tool_error("bench layered: %s has no light to move", scene_path);
        goto out;
    }
    nacre_light light = {1};
    nacre_light_desc ld0;
    nacre_scene_get_light(scene, light, &ld0);
    t = malloc(sizeof(double) * (size_t)runs * (NSTAGES + 1));
    if (!t)
        goto out;
    nacre_render_settings rs = fs.render;
    rs.method = NACRE_METHOD_LAYERED;
    rs.width = 640;
    rs.height = 480;
    rs.reuse_output = true;
    if (!json) {
        printf("nacre bench layered: %s at 640x480, %d thread(s), medians of %d frames (us)\n", scene_path,
               nacre_context_threads(ctx), runs);
        printf("%-12s %7s %-9s", "frames", "samples", "integ.");
        for (size_t k = 0; k < NSTAGES; k++)
            printf(" %9s", nacre_stage_name(stages[k]));
        printf(" %9s %7s\n", "frame", "fps");
    }
    /* Cold: a new renderer per run, every stage runs. */
    for (int i = 0; i < runs; i++) {
        nacre_renderer *cold = NULL;
        nacre_render_stats st;
        if (nacre_renderer_create(ctx, &cold) != NACRE_OK || nacre_renderer_render(cold, scene, &rs, &img, &st) != NACRE_OK) {
            nacre_renderer_destroy(cold);
            rc = nc_tool_fail(ctx);
            goto out;
        }
        nacre_renderer_destroy(cold);
        for (size_t k = 0; k < NSTAGES; k++)
            t[k * (size_t)runs + (size_t)i] = (double)st.stage_us[stages[k]];
        t[NSTAGES * (size_t)runs + (size_t)i] = (double)st.total_us;
    }
    double med[NSTAGES];
    for (size_t k = 0; k < NSTAGES; k++)
        med[k] = nc_tool_median(t + k * (size_t)runs, runs);
    print_row(json, scene_path, "cold", rs.layered.samples, nacre_layered_integration_name(rs.layered.integration), med,
              nc_tool_median(t + NSTAGES * (size_t)runs, runs), 0);
    /* 4 analytic steps: closer to the converged image than 200 point samples (docs/accuracy.md) */
    static const uint32_t counts[] = {4, 10, 50, 100};
    static const double seed_fps[] = {0, 126, 51, 20};
    static const nacre_layered_integration integs[] = {NACRE_LAYERED_SAMPLES, NACRE_LAYERED_ANALYTIC};
    int frame = 0;
    for (size_t ig = 0; ig < 2; ig++)
        for (size_t c = 0; c < 4; c++) {
            rs.layered.samples = counts[c];
            rs.layered.integration = integs[ig];
            for (int i = -1; i < runs; i++) { /* one warm-up frame */
                nacre_light_desc ld = ld0;
                float a = 0.1f * (float)(++frame) * 3.14159265f / 180.0f;
                ld.direction[0] = ld0.direction[0] * cosf(a) - ld0.direction[2] * sinf(a);
                ld.direction[2] = ld0.direction[0] * sinf(a) + ld0.direction[2] * cosf(a);
                ld.position[0] = ld0.position[0] * cosf(a) - ld0.position[2] * sinf(a);
                ld.position[2] = ld0.position[0] * sinf(a) + ld0.position[2] * cosf(a);
                nacre_render_stats st;
                uint64_t t0 = nc_tool_now_us();
                if (nacre_scene_set_light(scene, light, &ld) != NACRE_OK || nacre_scene_commit(scene, fs.time) != NACRE_OK ||
                    nacre_renderer_render(r, scene, &rs, &img, &st) != NACRE_OK) {
                    rc = nc_tool_fail(ctx);
                    goto out;
                }
                uint64_t t1 = nc_tool_now_us();
                if (i < 0)
                    continue;
                for (size_t k = 0; k < NSTAGES; k++)
                    t[k * (size_t)runs + (size_t)i] = (double)st.stage_us[stages[k]];
                t[NSTAGES * (size_t)runs + (size_t)i] = (double)(t1 - t0); /* commit + render */
            }
            for (size_t k = 0; k < NSTAGES; k++)
                med[k] = nc_tool_median(t + k * (size_t)runs, runs);
            print_row(json, scene_path, "light moves", counts[c], nacre_layered_integration_name(integs[ig]), med,
                      nc_tool_median(t + NSTAGES * (size_t)runs, runs), ig == 0 ? seed_fps[c] : 0);
        }
    rc = 0;
out:
    free(t);
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return rc;
}
