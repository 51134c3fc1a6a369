/*
 * bench_particles.c: `nacre bench particles`: the smoke plume of examples/particles.json with
 * 10k and 100k particles alive (emission rate 2500 and 25000 per second, 4 s lifetime, t = 5 s),
 * and 10k small particles (R from 1 growing by 0.25 per second instead of from 4 by 3, which
 * look like sparse dust), per stage: simulate (nc_particles_simulate), splat into 128^3 (nc_particles_splat, scratch
 * reused as between frames), commit (both, plus the fog the grid becomes), and the post pass of
 * the raster methods at 1280x720 drawing them as volumetric billboards and as sorted sprites
 * (stage "particles" of a phong frame whose other stages are cached), and the voxelized frame:
 * the same phong frame drawing the grid through the froxel pass (160x90x64, `--particles voxel
 * --volumetrics froxel`; stage "march" = froxel fill + light + integrate + apply), "voxel_frame"
 * = simulate + splat + march. Median of --runs runs after one warm-up, in ms.
 * The splat's cost is the cells the particles write (the mean kernel footprint in grid cells,
 * "cells", and the cells written, fewer where large particles go to the coarse level), the
 * passes' the pixels they cover.
 * Then the blob of examples/particles_iso.json (300 particles, 96^3) drawn as voxels by the
 * ray-march pass at 1280x720 (48 steps), without and with its isosurface (stage "raymarch").
 * Targets (2 cores): splat of 10k particles into 128^3 under 2 ms; billboards of 10k under 10 ms;
 * the voxelized frame of 10k under 10 ms. `only` (NULL: all) keeps the cases whose name
 * (smoke10k, smoke100k, dust10k, iso) contains it.
 */
#include "bench.h"

#include "particles/particles.h"

#include <nacre/nacre.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char scene_fmt[] =
    "{\"units\": \"mm\","
    " \"camera\": {\"type\": \"perspective\", \"position\": [0, 70, 260], \"target\": [0, 60, 0], \"fov\": 40},"
    " \"environment\": [0.10, 0.12, 0.16],"
    " \"materials\": {\"ground\": {\"type\": \"opaque\", \"diffuse\": [0.55, 0.5, 0.45]}},"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.5, -0.8, -0.35], \"irradiance\": [3.0, 2.8, 2.5]}],"
    " \"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": [600, 600]}, \"material\": \"ground\"}],"
    " \"particles\": [{\"shape\": \"sphere\", \"center\": [0, 6, 0], \"emit_radius\": 5, \"rate\": %d,"
    " \"lifetime\": 4, \"velocity\": [0, 45, 0], \"spread\": 18, \"speed_jitter\": 0.3, \"gravity\": [3, 6, 0],"
    " \"drag\": 0.35, \"radius\": %g, \"radius_jitter\": 0.3, \"radius_rate\": %g, \"fade\": 0.9, \"seed\": 7,"
    " \"sigma_a\": 0.0004, \"sigma_s\": [0.004, 0.004, 0.0042], \"g\": 0.2}]}";

static const char iso_fmt[] =
    "{\"units\": \"mm\","
    " \"camera\": {\"type\": \"perspective\", \"position\": [0, 28, 70], \"target\": [0, 12, 0], \"fov\": 38},"
    " \"environment\": [0.10, 0.12, 0.16],"
    " \"materials\": {\"ground\": {\"type\": \"opaque\", \"diffuse\": [0.55, 0.5, 0.45]}},"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [0.7, -0.45, -0.3], \"irradiance\": [4, 3.7, 3.3]}],"
    " \"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": [200, 200]}, \"material\": \"ground\"}],"
    " \"particles\": [{\"shape\": \"sphere\", \"center\": [0, 14, 0], \"emit_radius\": 9, \"rate\": 300,"
    " \"lifetime\": 1, \"velocity\": [0, 0, 0], \"spread\": 0, \"radius\": 5, \"radius_jitter\": 0.4, \"seed\": 3,"
    " \"sigma_a\": [0.001, 0.008, 0.03], \"sigma_s\": [0.06, 0.05, 0.035], \"g\": 0.2, \"grid_resolution\": 96%s}]}";

#define NCOL 11 /* simulate, splat, commit, billboards, sprites, march, voxel frame, march stages */

static double median_of(double *v, int n) { return nc_tool_median(v, n); }

/* The ray-march pass over the blob, without and with its isosurface: medians in ms. */
static int bench_iso(nacre_context *ctx, bool json, int runs, double *t)
{
    double med[2];
    for (int k = 0; k < 2; k++) {
        char text[2048];
        snprintf(text, sizeof(text), iso_fmt, k ? ", \"isosurface\": {\"density\": 1.5, \"ior\": 1.4}" : "");
        nacre_scene *scene = NULL;
        nacre_renderer *renderer = NULL;
        nacre_image img = {0};
        nacre_result r = nacre_scene_load_json(ctx, text, strlen(text), "bench_particles_iso", NULL, &scene, NULL);
        if (r == NACRE_OK)
            r = nacre_scene_commit(scene, 1.0);
        if (r == NACRE_OK)
            r = nacre_renderer_create(ctx, &renderer);
        nacre_render_settings rs = nacre_render_settings_defaults();
        rs.method = NACRE_METHOD_PHONG;
        rs.width = 1280;
        rs.height = 720;
        rs.particles = NACRE_PARTICLES_DRAW_VOXEL;
        rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
        rs.volumetrics.raymarch_steps = 48;
        for (int i = -1; i < runs && r == NACRE_OK; i++) {
            nacre_render_stats st;
            r = nacre_renderer_render(renderer, scene, &rs, &img, &st);
            t[i < 0 ? 0 : i] = (double)st.stage_us[NACRE_STAGE_RAYMARCH] / 1000.0;
        }
        nacre_image_free(ctx, &img);
        nacre_renderer_destroy(renderer);
        nacre_scene_destroy(scene);
        if (r != NACRE_OK)
            return nc_tool_fail(ctx);
        med[k] = median_of(t, runs);
    }
    if (json)
        printf("{\"bench\":\"particles_iso\",\"particles\":300,\"grid\":96,\"width\":1280,\"height\":720,"
               "\"steps\":48,\"threads\":%d,\"runs\":%d,\"raymarch_ms\":%.3f,\"raymarch_iso_ms\":%.3f}\n",
               nacre_context_threads(ctx), runs, med[0], med[1]);
    else
        printf("isosurface blob (300 particles, 96^3), ray march at 1280x720, 48 steps: %.3f ms without, %.3f ms "
               "with the surface\n", med[0], med[1]);
    return 0;
}

int nc_bench_particles(bool json, int runs, const char *only)
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    int rc = 2;
    double *t = calloc((size_t)runs * NCOL, sizeof(double));
    if (!t)
        goto out;
    if (!json)
        printf("particles: smoke plume, t = 5 s, grid 128^3, passes at 1280x720, %d threads, median of %d runs (ms)\n"
               "%-10s %-6s %8s %10s %10s %10s %12s %10s %10s %12s\n",
               nacre_context_threads(ctx), runs, "particles", "size", "cells", "simulate", "splat", "commit", "billboards",
               "sprites", "march", "voxel_frame");
    static const struct {
        int rate;
        double radius, radius_rate;
        const char *label, *name;
    } cases[] = {{2500, 4, 3, "smoke", "smoke10k"}, {25000, 4, 3, "smoke", "smoke100k"}, {2500, 1, 0.25, "dust", "dust10k"}};
    rc = 0;
    for (int k = 0; k < 3; k++) {
        if (only && !strstr(cases[k].name, only))
            continue;
        char text[2048];
        snprintf(text, sizeof(text), scene_fmt, cases[k].rate, cases[k].radius, cases[k].radius_rate);
        nacre_scene *scene = NULL;
        nacre_renderer *renderer = NULL;
        nacre_image img = {0};
        nc_particle_set set = {0};
        nc_particle_grid grid = {0};
        if (nacre_scene_load_json(ctx, text, strlen(text), "bench_particles", NULL, &scene, NULL) != NACRE_OK ||
            nacre_renderer_create(ctx, &renderer) != NACRE_OK) {
            nacre_scene_destroy(scene);
            rc = nc_tool_fail(ctx);
            goto out;
        }
        nacre_particles_desc d;
        nacre_scene_get_particles(scene, (nacre_particles){1}, &d);
        nacre_render_settings rs = nacre_render_settings_defaults();
        rs.method = NACRE_METHOD_PHONG;
        rs.width = 1280;
        rs.height = 720;
        nacre_result r = NACRE_OK;
        for (int i = -1; i < runs && r == NACRE_OK; i++) {
            double *row = t + NCOL * (size_t)(i < 0 ? 0 : i);
            uint64_t t0 = nc_tool_now_us();
            r = nc_particles_simulate(ctx, &d, 5.0, &set);
            uint64_t t1 = nc_tool_now_us();
            if (r == NACRE_OK)
                r = nc_particles_splat(ctx, &set, 128, &grid);
            uint64_t t2 = nc_tool_now_us();
            /* Another time each run, so that the commit simulates and splats again. */
            if (r == NACRE_OK)
                r = nacre_scene_commit(scene, 5.0 + 1e-3 * (i + 2));
            uint64_t t3 = nc_tool_now_us();
            row[0] = (double)(t1 - t0) / 1000.0;
            row[1] = (double)(t2 - t1) / 1000.0;
            row[2] = (double)(t3 - t2) / 1000.0;
            for (int p = 0; p < 2 && r == NACRE_OK; p++) {
                nacre_render_stats st;
                rs.particles = p == 0 ? NACRE_PARTICLES_DRAW_BILLBOARDS : NACRE_PARTICLES_DRAW_SPRITES;
                r = nacre_renderer_render(renderer, scene, &rs, &img, &st);
                row[3 + p] = (double)st.stage_us[NACRE_STAGE_PARTICLES] / 1000.0;
            }
            if (r == NACRE_OK) {
                nacre_render_stats st;
                rs.particles = NACRE_PARTICLES_DRAW_VOXEL;
                rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
                r = nacre_renderer_render(renderer, scene, &rs, &img, &st);
                rs.volumetrics.mode = NACRE_VOLUMETRICS_OFF;
                row[5] = (double)(st.stage_us[NACRE_STAGE_FROXEL_FILL] + st.stage_us[NACRE_STAGE_FROXEL_LIGHT] +
                                  st.stage_us[NACRE_STAGE_FROXEL_INTEGRATE] + st.stage_us[NACRE_STAGE_FROXEL_APPLY]) /
                         1000.0;
                row[6] = row[0] + row[1] + row[5];
                const nacre_stage ms[4] = {NACRE_STAGE_FROXEL_FILL, NACRE_STAGE_FROXEL_LIGHT,
                                           NACRE_STAGE_FROXEL_INTEGRATE, NACRE_STAGE_FROXEL_APPLY};
                for (int m = 0; m < 4; m++)
                    row[7 + m] = (double)st.stage_us[ms[m]] / 1000.0;
            }
        }
        uint32_t alive = nacre_scene_particles_alive(scene, (nacre_particles){1});
        double cells = 0.0, written = 0.0;
        for (uint32_t i = 0; i < set.count && grid.range; i++) {
            const int32_t *rg = grid.range + 6 * (size_t)i;
            double c = (double)(rg[1] - rg[0] + 1) * (rg[3] - rg[2] + 1) * (rg[5] - rg[4] + 1);
            written += c;
            cells += c * (double)(1u << (3 * grid.level[i])); /* a level-l cell is 8^l of the grid's */
        }
        cells /= set.count ? set.count : 1;
        written /= set.count ? set.count : 1;
        if (r != NACRE_OK) {
            rc = nc_tool_fail(ctx);
        } else {
            double med[NCOL], col[10000];
            for (int s = 0; s < NCOL; s++) {
                for (int i = 0; i < runs; i++)
                    col[i] = t[NCOL * (size_t)i + (size_t)s];
                med[s] = median_of(col, runs);
            }
            if (json)
                printf("{\"bench\":\"particles\",\"particles\":%u,\"size\":\"%s\",\"cells_per_particle\":%.0f,"
                       "\"cells_written_per_particle\":%.0f,"
                       "\"grid\":128,\"width\":1280,\"height\":720,\"threads\":%d,\"runs\":%d,\"simulate_ms\":%.3f,"
                       "\"splat_ms\":%.3f,\"commit_ms\":%.3f,\"billboards_ms\":%.3f,\"sprites_ms\":%.3f,"
                       "\"march_ms\":%.3f,\"voxel_frame_ms\":%.3f,\"march_stages_ms\":{\"fill\":%.3f,"
                       "\"light\":%.3f,\"integrate\":%.3f,\"apply\":%.3f}}\n",
                       alive, cases[k].label, cells, written, nacre_context_threads(ctx), runs, med[0], med[1], med[2], med[3],
                       med[4], med[5], med[6], med[7], med[8], med[9], med[10]);
            else
                printf("%-10u %-6s %8.0f %10.3f %10.3f %10.3f %12.3f %10.3f %10.3f %12.3f\n", alive, cases[k].label,
                       cells, med[0], med[1], med[2], med[3], med[4], med[5], med[6]);
            rc = 0;
        }
        nc_particle_set_free(ctx, &set);
        nc_particle_grid_free(ctx, &grid);
        nacre_image_free(ctx, &img);
        nacre_renderer_destroy(renderer);
        nacre_scene_destroy(scene);
        if (rc != 0)
            goto out;
    }
    if (!only || strstr("iso", only))
        rc = bench_iso(ctx, json, runs, t);
out:
    free(t);
    nacre_context_destroy(ctx);
    return rc;
}
