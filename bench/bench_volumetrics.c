/*
 * bench_volumetrics.c: `nacre bench volumetrics`: the volumetric fog passes at 1280x720 over the
 * built-in demo scene (phong) with one shadowed directional light (the demo's own, turned and
 * recoloured), four point lights, a global height fog and a box fog whose density is a 128^3
 * volume (a procedural cloud, made here so that the bench needs no file: a .vdb cloud is densified
 * at load into the same kind of grid, so the froxel stages do the same work for either). One
 * renderer across frames, as a viewer, in three sequences: the camera turns a little every frame
 * (every froxel stage and the analytic pass run: the froxel_* and fog_pass keys), the sun turns
 * (the fill is kept, the lighting and the integration rerun), and nothing moves (the lit grid is
 * kept; only apply runs). Medians of N frames per stage, in ms, and with --raymarch one frame of
 * the per-pixel march (64 steps). `--only froxel` times the first sequence alone (its stages and
 * total): a quicker measurement of the froxel pipeline for before/after comparisons.
 */
#include "bench.h"

#include "demo_scene.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { CLOUD = 128 };

/* What changes between the frames of a sequence. */
typedef enum motion { STILL, SUN_TURNS, CAMERA_TURNS } motion;

/* The scene's extra lights and fogs; the cloud's density (a soft ball with ripples) in `data`;
 * the sun's handle in *sun_out. */
static nacre_result add_volumetric_set_up(nacre_scene *scene, float *data, nacre_light *sun_out)
{
    /* The demo's one light, a shadowed sun, becomes the bench's sun: with the four point lights,
     * the set of lights (a scene of another kind gets a sun of its own). */
    nacre_light_desc sun = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    float dir[3] = {-0.4f, -1.0f, -0.3f}, sun_e[3] = {2.0f, 1.9f, 1.7f};
    memcpy(sun.direction, dir, sizeof(dir));
    memcpy(sun.strength, sun_e, sizeof(sun_e));
    nacre_light l, demo_sun = {1};
    nacre_light_desc demo;
    nacre_result r;
    if (nacre_scene_light_count(scene) == 1 && nacre_scene_get_light(scene, demo_sun, &demo) == NACRE_OK &&
        demo.type == NACRE_LIGHT_DIRECTIONAL && demo.cast_shadows) {
        *sun_out = demo_sun;
        r = nacre_scene_set_light(scene, demo_sun, &sun);
    } else {
        r = nacre_scene_add_light(scene, &sun, sun_out);
    }
    for (int i = 0; r == NACRE_OK && i < 4; i++) {
        nacre_light_desc pt = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
        float a = (float)i * 1.5707963f;
        float pos[3] = {60.0f * cosf(a), 40.0f, 60.0f * sinf(a)}, e[3] = {3000.0f, 2500.0f + 300.0f * i, 2000.0f};
        memcpy(pt.position, pos, sizeof(pos));
        memcpy(pt.strength, e, sizeof(e));
        pt.cast_shadows = false;
        r = nacre_scene_add_light(scene, &pt, &l);
    }
    nacre_fog_desc height = nacre_fog_desc_defaults(NACRE_FOG_GLOBAL);
    float ss[3] = {0.004f, 0.0045f, 0.005f};
    memcpy(height.sigma_s, ss, sizeof(ss));
    height.height_falloff = 0.03f;
    height.g = 0.3f;
    nacre_fog f;
    if (r == NACRE_OK)
        r = nacre_scene_add_fog(scene, &height, &f);
    for (int k = 0; k < CLOUD; k++)
        for (int j = 0; j < CLOUD; j++)
            for (int i = 0; i < CLOUD; i++) {
                float x = (i + 0.5f) / CLOUD * 2 - 1, y = (j + 0.5f) / CLOUD * 2 - 1, z = (k + 0.5f) / CLOUD * 2 - 1;
                float rr = sqrtf(x * x + y * y + z * z) + 0.08f * sinf(9 * x) * sinf(7 * y) * sinf(8 * z);
                data[i + CLOUD * (j + CLOUD * k)] = rr < 0.9f ? 1.0f - rr / 0.9f : 0.0f;
            }
    nacre_volume_data vd = {{CLOUD, CLOUD, CLOUD}, {-30, -20, -30}, {60.0f / (CLOUD - 1), 40.0f / (CLOUD - 1), 60.0f / (CLOUD - 1)}, data};
    nacre_volume vol;
    if (r == NACRE_OK)
        r = nacre_scene_add_volume(scene, &vd, &vol);
    nacre_fog_desc cloud = nacre_fog_desc_defaults(NACRE_FOG_BOX);
    float center[3] = {-40, 60, -20}, size[3] = {60, 40, 60}, cs[3] = {0.05f, 0.05f, 0.05f};
    memcpy(cloud.center, center, sizeof(center));
    memcpy(cloud.size, size, sizeof(size));
    memcpy(cloud.sigma_s, cs, sizeof(cs));
    cloud.pattern.type = NACRE_PATTERN_VOLUME;
    cloud.pattern.volume = vol;
    if (r == NACRE_OK)
        r = nacre_scene_add_fog(scene, &cloud, &f);
    return r;
}

/* Turn the sun (a degree about the vertical) or the camera (a tenth of a degree about the
 * vertical through its target) for frame `run`, and commit. */
static nacre_result move(nacre_scene *scene, motion m, nacre_light sun, int run)
{
    if (m == STILL)
        return NACRE_OK;
    nacre_result r;
    if (m == SUN_TURNS) {
        float a = 0.017453293f * (float)run, dir[3] = {-0.4f, -1.0f, -0.3f};
        nacre_light_desc d = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
        float sun_e[3] = {2.0f, 1.9f, 1.7f};
        d.direction[0] = dir[0] * cosf(a) - dir[2] * sinf(a);
        d.direction[1] = dir[1];
        d.direction[2] = dir[0] * sinf(a) + dir[2] * cosf(a);
        memcpy(d.strength, sun_e, sizeof(sun_e));
        r = nacre_scene_set_light(scene, sun, &d);
    } else {
        nacre_camera_desc c;
        if ((r = nacre_scene_get_camera(scene, &c)) != NACRE_OK)
            return r;
        float a = 0.0017453293f, x = c.position[0] - c.target[0], z = c.position[2] - c.target[2];
        c.position[0] = c.target[0] + x * cosf(a) - z * sinf(a);
        c.position[2] = c.target[2] + x * sinf(a) + z * cosf(a);
        r = nacre_scene_set_camera(scene, &c);
    }
    return r == NACRE_OK ? nacre_scene_commit(scene, 0.0) : r;
}

/* Medians of the stages of `runs` frames of one renderer (after one warm-up frame), the scene
 * moved before each frame as `m` says. */
static int time_frames(nacre_context *ctx, nacre_scene *scene, const nacre_render_settings *rs, int runs, motion m,
                       nacre_light sun, double *median_ms)
{
    nacre_renderer *r = NULL;
    nacre_image img = {0};
    double *samples = calloc((size_t)runs * (NACRE_STAGE_COUNT + 1), sizeof(double));
    int rc = 2;
    if (!samples || nacre_renderer_create(ctx, &r) != NACRE_OK)
        goto out;
    for (int run = -1; run < runs; run++) {
        nacre_render_stats st;
        if (move(scene, m, sun, run + 1) != NACRE_OK || nacre_renderer_render(r, scene, rs, &img, &st) != NACRE_OK) {
            rc = nc_tool_fail(ctx);
            goto out;
        }
        if (run < 0)
            continue;
        for (int s = 0; s < NACRE_STAGE_COUNT; s++)
            samples[s * runs + run] = st.stage_us[s] / 1000.0;
        samples[NACRE_STAGE_COUNT * runs + run] = st.total_us / 1000.0;
    }
    for (int s = 0; s <= NACRE_STAGE_COUNT; s++)
        median_ms[s] = nc_tool_median(samples + s * runs, runs);
    rc = 0;
out:
    free(samples);
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(r);
    return rc;
}

int nc_bench_volumetrics(bool json, int runs, bool raymarch, bool froxel_only, const uint32_t froxels[3])
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    nacre_light sun = {0};
    int rc = 2;
    float *cloud = malloc((size_t)CLOUD * CLOUD * CLOUD * sizeof(float));
    if (!cloud)
        goto out;
    if (nacre_scene_load_json(ctx, (const char *)nacre_demo_scene_json, strlen((const char *)nacre_demo_scene_json),
                              "<built-in demo>", ".", &scene, &fs) != NACRE_OK ||
        add_volumetric_set_up(scene, cloud, &sun) != NACRE_OK || nacre_scene_commit(scene, 0.0) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }
    nacre_render_settings rs = fs.render;
    rs.width = 1280;
    rs.height = 720;
    rs.method = NACRE_METHOD_PHONG;
    double froxel[NACRE_STAGE_COUNT + 1], sun_turns[NACRE_STAGE_COUNT + 1], still[NACRE_STAGE_COUNT + 1];
    double march[NACRE_STAGE_COUNT + 1] = {0}, off[NACRE_STAGE_COUNT + 1], off_still[NACRE_STAGE_COUNT + 1];
    rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
    rs.volumetrics.froxel_width = froxels[0];
    rs.volumetrics.froxel_height = froxels[1];
    rs.volumetrics.froxel_slices = froxels[2];
    if ((rc = time_frames(ctx, scene, &rs, runs, CAMERA_TURNS, sun, froxel)) != 0)
        goto out;
    if (froxel_only) {
        double st[4] = {froxel[NACRE_STAGE_FROXEL_FILL], froxel[NACRE_STAGE_FROXEL_LIGHT],
                        froxel[NACRE_STAGE_FROXEL_INTEGRATE], froxel[NACRE_STAGE_FROXEL_APPLY]};
        double sum = st[0] + st[1] + st[2] + st[3];
        if (json)
            printf("{\"bench\":\"volumetrics\",\"only\":\"froxel\",\"froxels\":[%u,%u,%u],\"threads\":%d,\"runs\":%d,"
                   "\"froxel_fill_ms\":%.3f,"
                   "\"froxel_light_ms\":%.3f,\"froxel_integrate_ms\":%.3f,\"froxel_apply_ms\":%.3f,"
                   "\"froxel_total_ms\":%.3f}\n",
                   froxels[0], froxels[1], froxels[2], nacre_context_threads(ctx), runs, st[0], st[1], st[2], st[3], sum);
        else
            printf("volumetrics, camera turning, %ux%ux%u froxels (median of %d runs, ms): froxel fill %.3f, light "
                   "%.3f, integrate %.3f, apply %.3f, total %.3f\n",
                   froxels[0], froxels[1], froxels[2], runs, st[0], st[1], st[2], st[3], sum);
        rc = 0;
        goto out;
    }
    if ((rc = time_frames(ctx, scene, &rs, runs, SUN_TURNS, sun, sun_turns)) != 0 ||
        (rc = time_frames(ctx, scene, &rs, runs, STILL, sun, still)) != 0)
        goto out;
    rs.volumetrics.mode = NACRE_VOLUMETRICS_OFF;
    if ((rc = time_frames(ctx, scene, &rs, runs, CAMERA_TURNS, sun, off)) != 0 ||
        (rc = time_frames(ctx, scene, &rs, runs, STILL, sun, off_still)) != 0)
        goto out;
    /* The march is the slow check (about a minute a frame here): one run, on request. */
    int march_runs = raymarch ? 1 : 0;
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    if (raymarch && (rc = time_frames(ctx, scene, &rs, march_runs, STILL, sun, march)) != 0)
        goto out;
    double fill = froxel[NACRE_STAGE_FROXEL_FILL], light = froxel[NACRE_STAGE_FROXEL_LIGHT],
           integ = froxel[NACRE_STAGE_FROXEL_INTEGRATE], apply = froxel[NACRE_STAGE_FROXEL_APPLY];
    double total = fill + light + integ + apply;
    const int stages[4] = {NACRE_STAGE_FROXEL_FILL, NACRE_STAGE_FROXEL_LIGHT, NACRE_STAGE_FROXEL_INTEGRATE,
                           NACRE_STAGE_FROXEL_APPLY};
    double sun_total = 0.0, still_total = 0.0;
    for (int k = 0; k < 4; k++) {
        sun_total += sun_turns[stages[k]];
        still_total += still[stages[k]];
    }
    int threads = nacre_context_threads(ctx);
    char march_ms[32] = "null";
    if (raymarch)
        snprintf(march_ms, sizeof(march_ms), "%.3f", march[NACRE_STAGE_RAYMARCH]);
    if (json) {
        printf("{\"bench\":\"volumetrics\",\"scene\":\"demo+fog\",\"method\":\"phong\",\"width\":1280,\"height\":720,"
               "\"froxels\":[%u,%u,%u],\"lights\":%u,\"fogs\":%u,\"threads\":%d,\"runs\":%d,"
               "\"froxel_fill_ms\":%.3f,\"froxel_light_ms\":%.3f,\"froxel_integrate_ms\":%.3f,"
               "\"froxel_apply_ms\":%.3f,\"froxel_total_ms\":%.3f,\"raymarch_ms\":%s,\"raymarch_runs\":%d,"
               "\"fog_pass_ms\":%.3f,\"sun_turns\":{\"froxel_light_ms\":%.3f,\"froxel_integrate_ms\":%.3f,"
               "\"froxel_apply_ms\":%.3f,\"froxel_total_ms\":%.3f},\"still\":{\"froxel_apply_ms\":%.3f,"
               "\"froxel_total_ms\":%.3f,\"fog_pass_ms\":%.3f}}\n",
               froxels[0], froxels[1], froxels[2], nacre_scene_light_count(scene), nacre_scene_fog_count(scene), threads,
               runs, fill, light, integ, apply,
               total, march_ms, march_runs, off[NACRE_STAGE_FOG], sun_turns[NACRE_STAGE_FROXEL_LIGHT],
               sun_turns[NACRE_STAGE_FROXEL_INTEGRATE], sun_turns[NACRE_STAGE_FROXEL_APPLY], sun_total,
               still[NACRE_STAGE_FROXEL_APPLY], still_total, off_still[NACRE_STAGE_FOG]);
    } else {
        printf("volumetrics: demo scene + %u lights, %u fogs (height fog, 128^3 cloud), phong, 1280x720,\n"
               "%d threads, median of %d runs (ms):\n",
               nacre_scene_light_count(scene), nacre_scene_fog_count(scene), threads, runs);
        printf("  froxel %ux%ux%u  fill %8.3f\n", froxels[0], froxels[1], froxels[2], fill);
        printf("                    light %7.3f\n", light);
        printf("                integrate %7.3f\n", integ);
        printf("                    apply %7.3f\n", apply);
        printf("                    total %7.3f\n", total);
        if (raymarch)
            printf("  raymarch 64 steps       %8.3f (median of %d)\n", march[NACRE_STAGE_RAYMARCH], march_runs);
        printf("  analytic fog pass       %8.3f\n", off[NACRE_STAGE_FOG]);
        printf("  the camera turns each frame above; the sun turns: froxel light %.3f, integrate %.3f,\n"
               "  apply %.3f, total %.3f; nothing moves: froxel total %.3f, analytic fog pass %.3f\n",
               sun_turns[NACRE_STAGE_FROXEL_LIGHT], sun_turns[NACRE_STAGE_FROXEL_INTEGRATE],
               sun_turns[NACRE_STAGE_FROXEL_APPLY], sun_total, still_total, off_still[NACRE_STAGE_FOG]);
    }
    rc = 0;
out:
    free(cloud);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return rc;
}
